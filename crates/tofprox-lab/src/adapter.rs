//! Bridges to the other crates: a `tofprox_format::Recording` becomes a
//! [`Dataset`], a `tofprox_model::ModelConfig` becomes a [`LabSpec`], and a
//! fitted effect is written back into a model file.
use std::collections::BTreeMap;
use std::path::Path;

use tofprox_format::Recording;
use tofprox_model::ModelConfig;

use crate::data::{Capture, Dataset};
use crate::error::{ErrorKind, LabError};
use crate::fit::{LabModel, LabSpec, Prepared};
use crate::signatures::{MAX_HARMONIC, SIGNATURE_IDS};

/// Load every capture of a recording (codes as f64).
pub fn load_recording(dir: &Path) -> Result<Dataset, LabError> {
    let rec = Recording::open(dir).map_err(|e| {
        LabError::new(
            ErrorKind::Io,
            format!("cannot open recording {}: {e}", dir.display()),
        )
    })?;
    dataset_from_recording(&rec)
}

/// Every capture of an opened recording as a [`Dataset`] (codes as f64).
pub fn dataset_from_recording(rec: &Recording) -> Result<Dataset, LabError> {
    let s = rec.sensor();
    let mut captures = Vec::with_capacity(rec.captures().len());
    for (i, meta) in rec.captures().iter().enumerate() {
        let frames = rec
            .load(i)
            .map_err(|e| {
                LabError::new(ErrorKind::Io, format!("capture {i} ({}): {e}", meta.frames))
            })?
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

/// Highest harmonic the model file describes (1 when waveform_harmonics is off).
pub fn harmonic_order(m: &ModelConfig) -> usize {
    if !m.is_enabled("waveform_harmonics") {
        return 1;
    }
    if m.waveforms().is_some() {
        return MAX_HARMONIC;
    }
    (2..=MAX_HARMONIC)
        .rev()
        .find(|h| {
            m.param("waveform_harmonics", &format!("h{h}_rel"))
                .is_some_and(|v| v.abs() > 0.0)
        })
        .unwrap_or(1)
}

/// Which parts of the lab model are free, from the model's enabled effects.
pub fn spec_from_model(m: &ModelConfig) -> LabSpec {
    LabSpec {
        harmonic_order: harmonic_order(m),
        per_pixel_offset: m.is_enabled("fpn_offset") || m.is_enabled("adc_offset"),
        per_pixel_gain: m.is_enabled("prnu"),
        per_pixel_phase: m.is_enabled("fppn"),
        effects: SIGNATURE_IDS
            .iter()
            .filter(|id| **id != "waveform_harmonics" && m.is_enabled(id))
            .map(|s| s.to_string())
            .collect(),
    }
}

/// Enable `effect` in `m` and write the fitted values where the lab's
/// parameters map onto the model's; returns notes about what was not mapped.
pub fn write_effect(
    m: &mut ModelConfig,
    effect: &str,
    params: &BTreeMap<String, f64>,
    model: &LabModel,
    prep: &Prepared,
) -> Result<Vec<String>, LabError> {
    m.set_enabled(effect, true).map_err(|e| {
        LabError::new(
            ErrorKind::InvalidModel,
            format!("cannot enable `{effect}`: {e}"),
        )
    })?;
    let mut notes = Vec::new();
    let mut set = |m: &mut ModelConfig, name: &str, v: f64| {
        if let Err(e) = m.set_param(effect, name, v) {
            notes.push(format!(
                "{effect}.{name} = {v:.6} not written ({e}); kept {:?}",
                m.param(effect, name)
            ));
        }
    };
    let g = |k: &str| params.get(k).copied();
    match effect {
        "vcsel_droop" => {
            if let (Some(rate), Some(lt), Some(beta)) = (g("droop_rate"), g("ln_tau"), g("exposure_power")) {
                let tau = lt.exp();
                if (beta - 1.0).abs() < 0.25 {
                    set(m, "tau_us", tau * 1000.0);
                    set(m, "droop_rel", rate * tau);
                } else {
                    notes.push(format!("droop scales with exposure^{beta:.2}, the model's with exposure: droop_rel/tau_us left at typical"));
                }
            }
        }
        "temperature_drift" => {
            if let Some(v) = g("phase_rad_per_k") {
                set(m, "phase_mrad_per_k", v * 1000.0);
            }
            if let Some(v) = g("gain_per_k") {
                set(m, "gain_rel_per_k", v);
            }
            set(m, "reference_c", prep.temp_ref);
        }
        "adc_inl" => {
            if let Some(v) = g("inl_bow_lsb") {
                set(m, "inl_lsb", v);
            }
        }
        "amplitude_phase_error" => {
            if let Some(v) = g("phase0_rad") {
                set(m, "max_rad", v);
            }
            notes.push("reference_e left at typical: the lab fits the reference amplitude in LSB (ln_reference_lsb)".into());
        }
        "multipath" => {
            if let (Some(c), Some(s)) = (g("ratio_cos"), g("ratio_sin")) {
                set(m, "relative_amplitude", c.hypot(s));
            }
            if let Some(l) = g("extra_path_m") {
                set(m, "extra_path_m", 2.0 * l.abs());
            }
        }
        "waveform_harmonics" => {
            for (i, gm) in model.waveform.gamma.iter().enumerate().skip(1) {
                let h = i + 1;
                set(m, &format!("h{h}_rel"), gm[0].hypot(gm[1]));
                set(m, &format!("h{h}_phase_deg"), gm[1].atan2(gm[0]).to_degrees());
            }
        }
        _ => notes.push(format!(
            "{effect}: the lab's parameters are in measurement units (see --json params); the model file keeps its typical values"
        )),
    }
    Ok(notes)
}
