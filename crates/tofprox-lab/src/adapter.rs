//! Bridges to the other crates: a `tofprox_format::Recording` becomes a
//! [`Dataset`] and a `tofprox_model::ModelConfig` becomes a [`LabSpec`]. What
//! each effect's model-file parameters mean to the lab is its module's in
//! [`crate::signatures`]; editing the model file's text is [`crate::model_file`]'s.
use std::path::Path;
use tofprox_model::effects;

use tofprox_format::Recording;
use tofprox_model::ModelConfig;
use tofprox_model::ids::EffectId;

use crate::data::{Capture, Dataset};
use crate::error::LabError;
use crate::prepared::Prepared;
use crate::signatures::{SIGNATURE_IDS, harmonic_order, held_params, waveform_effect};
use crate::spec::{EffectFit, LabSpec};

/// The conditions the lab model uses by meaning; every other numeric key of
/// `[capture.conditions]` except the bookkeeping ones
/// (`tofprox_format::is_bookkeeping_condition`) is kept by name in [`Capture::extra`].
pub const KNOWN_CONDITIONS: &[&str] = &[
    "distance_m",
    "reflectivity",
    "ambient_klux",
    "temperature_c",
];

/// Load every capture of a recording (codes as f64).
pub fn load_recording(dir: &Path) -> Result<Dataset, LabError> {
    let rec = Recording::open(dir)
        .map_err(|e| LabError::format(format!("cannot open recording {}", dir.display()), e))?;
    dataset_from_recording(&rec)
}

/// Every capture of an opened recording as a [`Dataset`] (codes as f64).
pub fn dataset_from_recording(rec: &Recording) -> Result<Dataset, LabError> {
    let s = rec.sensor();
    let mut captures = Vec::with_capacity(rec.captures().len());
    for (i, meta) in rec.captures().iter().enumerate() {
        let frames = rec
            .load(i)
            .map_err(|e| LabError::format(format!("capture {i} ({})", meta.frames), e))?
            .to_f64();
        let cond = |k: &str| meta.conditions.get(k).copied();
        captures.push(Capture {
            phases_deg: meta.phases_deg.clone(),
            exposure_us: meta.exposure_us,
            illumination: meta.illumination,
            averaged: meta.averaged,
            distance_m: cond("distance_m"),
            reflectivity: cond("reflectivity").unwrap_or(1.0),
            ambient_klux: cond("ambient_klux").unwrap_or(0.0),
            temperature_c: cond("temperature_c"),
            // bookkeeping keys (`repeat`, `timestamp_*` …) are not conditions:
            // captures differing only in them are repeats (docs/recording-format.md)
            extra: meta
                .physical_conditions()
                .filter(|(k, _)| !KNOWN_CONDITIONS.contains(k))
                .map(|(k, v)| (k.to_string(), v))
                .collect(),
            frames,
        });
    }
    let ds = Dataset {
        sensor: *s,
        captures,
    };
    ds.validate()?;
    Ok(ds)
}

/// Which parts of the lab model are free, from the model's enabled effects.
pub fn spec_from_model(m: &ModelConfig) -> LabSpec {
    LabSpec {
        harmonic_order: harmonic_order(m),
        per_pixel_offset: m.is_enabled(effects::fpn_offset::ID)
            || m.is_enabled(effects::adc_offset::ID),
        per_pixel_gain: m.is_enabled(effects::prnu::ID),
        per_pixel_phase: m.is_enabled(effects::fppn::ID),
        effects: SIGNATURE_IDS
            .iter()
            .filter_map(|id| EffectId::parse(id))
            .filter(|id| waveform_effect(id.as_str()).is_none() && m.is_enabled(*id))
            .map(|id| id.as_str().to_string())
            .chain(m.user_effects().iter().map(|u| u.name.clone()))
            .collect(),
        held: Vec::new(),
        holds: std::collections::BTreeMap::new(),
        dark_doubling_k: m.get(effects::dark_current::DOUBLING_C),
        shapes: crate::shape::spec_shapes(m, crate::signatures::code_per_e(m)),
        user_effects: m.user_effects().to_vec(),
    }
}

/// The model file's own physics as lab parameters (the inverse of
/// [`crate::signatures::write_effect`]) for `compare --hold-effects`: every enabled effect whose
/// parameters map onto the lab's law is held at the file's values. Returns the
/// spec and notes naming the effects that are fitted freely instead.
pub fn spec_holding_model(m: &ModelConfig, prep: &Prepared) -> (LabSpec, Vec<String>) {
    let mut spec = spec_from_model(m);
    let mut notes = Vec::new();
    for id in spec.effects.clone() {
        // a user effect is held at the file's values (crate::user)
        if let Some(u) = spec.user_effects.iter().find(|u| u.name == id) {
            let held = crate::user::held_user(u);
            spec.held.push(held);
            continue;
        }
        match held_params(&id, m, prep) {
            Some((lin, nl)) => spec.held.push(EffectFit {
                id: id.clone(),
                lin,
                nl,
            }),
            None => notes.push(format!(
                "{id}: its parameters do not map onto the lab's law here; fitted freely"
            )),
        }
    }
    (spec, notes)
}
