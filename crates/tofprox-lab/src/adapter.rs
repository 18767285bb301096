//! Bridges to the other crates: a `tofprox_format::Recording` becomes a
//! [`Dataset`], a `tofprox_model::ModelConfig` becomes a [`LabSpec`], and a
//! fitted effect is written back into a model file.
use std::collections::BTreeMap;
use std::path::Path;

use tofprox_format::Recording;
use tofprox_model::ModelConfig;
use tofprox_model::ids::{self, EffectId, ParamId};

use crate::data::{Capture, Dataset};
use crate::error::{ErrorKind, LabError};
use crate::fit::{EffectFit, LabModel, LabSpec, Prepared};
use crate::signatures::{MAX_HARMONIC, SIGNATURE_IDS};

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

/// Highest harmonic the model file describes (1 when waveform_harmonics is off).
pub fn harmonic_order(m: &ModelConfig) -> usize {
    if !m.is_enabled(ids::waveform_harmonics::ID) {
        return 1;
    }
    if m.waveforms().is_some() {
        return MAX_HARMONIC;
    }
    (2..=MAX_HARMONIC)
        .rev()
        .find(|h| ids::harmonic(*h).is_some_and(|(rel, _)| m.get(rel).abs() > 0.0))
        .unwrap_or(1)
}

/// Which parts of the lab model are free, from the model's enabled effects.
pub fn spec_from_model(m: &ModelConfig) -> LabSpec {
    LabSpec {
        harmonic_order: harmonic_order(m),
        per_pixel_offset: m.is_enabled(ids::fpn_offset::ID) || m.is_enabled(ids::adc_offset::ID),
        per_pixel_gain: m.is_enabled(ids::prnu::ID),
        per_pixel_phase: m.is_enabled(ids::fppn::ID),
        effects: SIGNATURE_IDS
            .iter()
            .filter_map(|id| EffectId::parse(id))
            .filter(|id| *id != ids::waveform_harmonics::ID && m.is_enabled(*id))
            .map(|id| id.as_str().to_string())
            .collect(),
        held: Vec::new(),
        dark_doubling_k: m.get(ids::dark_current::DOUBLING_C),
        shapes: crate::shape::spec_shapes(m, code_per_e(m)),
    }
}

/// The model file's own physics as lab parameters (the inverse of
/// [`write_effect`]) for `compare --hold-effects`: every enabled effect whose
/// parameters map onto the lab's law is held at the file's values. Returns the
/// spec and notes naming the effects that are fitted freely instead.
pub fn spec_holding_model(m: &ModelConfig, prep: &Prepared) -> (LabSpec, Vec<String>) {
    let mut spec = spec_from_model(m);
    let mut notes = Vec::new();
    for id in spec.effects.clone() {
        match EffectId::parse(&id).and_then(|e| held_params(e, m, prep)) {
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

/// The lab's (lin, nl) of effect `id` at the model file's values, where they
/// map onto the lab's law.
fn held_params(id: EffectId, m: &ModelConfig, prep: &Prepared) -> Option<(Vec<f64>, Vec<f64>)> {
    let g = |p: ParamId| m.get(p);
    // 0 when the file has no conversion gain (NaN.max(0) is 0)
    let lsb_per_e = code_per_e(m).max(0.0);
    if let Some(s) = m.shape(id) {
        return crate::shape::held_shape(id, s, lsb_per_e, prep.temp_ref)
            .map(|(_, lin, nl)| (lin, nl));
    }
    match id {
        ids::vcsel_droop::ID => {
            use ids::vcsel_droop as p;
            let tau = (g(p::TAU_US) / 1000.0).max(1e-12);
            let nl = vec![tau.ln(), g(p::EXPOSURE_POWER), g(p::FIRST_IMAGE_INDEX)];
            Some((vec![g(p::DROOP_REL) / tau], nl))
        }
        ids::amplitude_phase_error::ID if lsb_per_e > 0.0 => {
            use ids::amplitude_phase_error as p;
            let nl = vec![
                g(p::MAX_RAD),
                (g(p::REFERENCE_E) * lsb_per_e).max(1e-12).ln(),
                g(p::SHAPE).max(1e-6).ln(),
            ];
            Some((Vec::new(), nl))
        }
        ids::temperature_drift::ID => Some(held_drift(m, prep)),
        ids::adc_inl::ID => Some((vec![g(ids::adc_inl::INL_LSB)], Vec::new())),
        // the signature's parameters are the model file's
        ids::multipath::ID => Some((
            vec![g(ids::multipath::RELATIVE_AMPLITUDE)],
            vec![g(ids::multipath::EXTRA_PATH_M)],
        )),
        // the inverse of write_effect's mapping (SbiUnits); nl = [ln q0,
        // (ln κ when the ambient light varies), clamp share]
        ids::sbi_asymmetry::ID => SbiUnits::from_model(m, prep).map(|u| {
            use ids::sbi_asymmetry as p;
            let mut nl = vec![(g(p::THRESHOLD_E) / u.e_per_unit).max(1e-300).ln()];
            if prep.ambient_varies {
                nl.push(u.kappa().ln());
            }
            nl.push(g(p::CLAMP_SHARE));
            (vec![-g(p::MISMATCH_REL) * u.e_per_unit * u.lsb_per_e], nl)
        }),
        ids::tap_gain_mismatch::ID => Some(held_tap_gain(m, prep, lsb_per_e)),
        _ => None,
    }
}

/// The temperature drift about the lab's reference T_l instead of the file's
/// T_r (δ = T_l − T_r): k(u + δ) + k2(u + δ)² = const + (k + 2k2δ)u + k2u²;
/// the constant phase shifts the per-pixel phase (refitted), the constant
/// gain c0 the per-pixel gain: 1 + G(u + δ) = (1 + c0)·(1 + G′(u)) with G′'s
/// coefficients divided by 1 + c0. The lab's law is the full one:
/// nl = phase, lin = gain.
fn held_drift(m: &ModelConfig, prep: &Prepared) -> (Vec<f64>, Vec<f64>) {
    use ids::temperature_drift as p;
    let d = prep.temp_ref - m.get(p::REFERENCE_C);
    let (k, k2) = (
        m.get(p::PHASE_MRAD_PER_K) * 1e-3,
        m.get(p::PHASE_MRAD_PER_K2) * 1e-3,
    );
    let (kg, kg2) = (m.get(p::GAIN_REL_PER_K), m.get(p::GAIN_REL_PER_K2));
    let c0 = (1.0 + kg * d + kg2 * d * d).max(1e-9);
    (
        vec![(kg + 2.0 * kg2 * d) / c0, kg2 / c0],
        vec![k + 2.0 * k2 * d, k2],
    )
}

/// The tap gain mismatch as the lab's lin: s = ε·peak/(2·contrast) (see
/// [`write_effect`]); the lab's C has fundamental 1, the model's peak 1:
/// peak_lab = 1/|a₁|. With varying ambient light also ε/2 · 2·N_ambient per
/// tap, in LSB per klux·ms.
fn held_tap_gain(m: &ModelConfig, prep: &Prepared, lsb_per_e: f64) -> (Vec<f64>, Vec<f64>) {
    let c = tofprox_model::effects::optical::Correlation::from_model(m);
    let a1 = c
        .coefficients()
        .get(1)
        .map_or(1.0, |(a, b)| a.hypot(*b))
        .max(1e-9);
    let eps = m.get(ids::tap_gain_mismatch::MISMATCH_REL);
    let mut lin = vec![eps / (a1 * 2.0 * contrast(m).max(1e-9))];
    if prep.ambient_varies {
        let amb = if m.is_enabled(ids::ambient_light::ID) {
            m.get(ids::ambient_light::E_PER_US_PER_KLUX)
        } else {
            0.0
        };
        lin.push(eps * amb * 1000.0 * lsb_per_e);
    }
    (lin, Vec::new())
}

/// The demodulation contrast K of the model file (1 when the effect is off).
fn contrast(m: &ModelConfig) -> f64 {
    if m.is_enabled(ids::demodulation_contrast::ID) {
        m.get(ids::demodulation_contrast::CONTRAST)
    } else {
        1.0
    }
}

/// Writes fitted values into a model file, collecting a note for every value
/// the file's range refuses.
struct Writer<'a> {
    m: &'a mut ModelConfig,
    notes: Vec<String>,
}

impl Writer<'_> {
    fn set(&mut self, p: ParamId, v: f64) {
        if let Err(e) = self.m.set(p, v) {
            self.notes.push(format!(
                "{p} = {v:.6} not written ({e}); kept {:?}",
                self.m.param(p.section(), p.name())
            ));
        }
    }
    /// `v` clamped into the parameter's range (the lab's law holds it there).
    fn set_in_range(&mut self, p: ParamId, v: f64) {
        let v = tofprox_model::catalogue::param_info(p).map_or(v, |i| v.clamp(i.min, i.max));
        self.set(p, v);
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
    let mut w = Writer {
        m,
        notes: Vec::new(),
    };
    let g = |k: &str| params.get(k).copied();
    let id = EffectId::parse(effect);
    // the chosen form: a shape (its knots in the lab's spec), else the
    // parametric law — never both in the file
    let shape = model.spec.shapes.get(effect).and_then(|knots| {
        let fit = model.effects.iter().find(|e| e.id == effect)?;
        crate::shape::model_shape(effect, knots, fit, code_per_e(w.m), prep.temp_ref)
    });
    if let Some(id) =
        id.filter(|id| tofprox_model::effects::shape::shape_law(id.as_str()).is_some())
    {
        if let Err(e) = w.m.set_shape(id, shape.clone()) {
            w.notes.push(format!("{effect}: shape not written ({e})"));
        }
        if shape.is_some() {
            return Ok(w.notes);
        }
    }
    match id {
        Some(ids::vcsel_droop::ID) => write_droop(&mut w, &g),
        Some(ids::temperature_drift::ID) => {
            use ids::temperature_drift as p;
            if let Some(v) = g("phase_rad_per_k") {
                w.set(p::PHASE_MRAD_PER_K, v * 1000.0);
            }
            if let Some(v) = g("gain_per_k") {
                w.set(p::GAIN_REL_PER_K, v);
            }
            // second order: fitted when the recording has ≥ 3 temperatures,
            // else the linear law (0)
            w.set(p::PHASE_MRAD_PER_K2, g("phase_rad_per_k2").unwrap_or(0.0) * 1000.0);
            w.set(p::GAIN_REL_PER_K2, g("gain_per_k2").unwrap_or(0.0));
            w.set(p::REFERENCE_C, prep.temp_ref);
        }
        Some(ids::adc_inl::ID) => {
            if let Some(v) = g("inl_bow_lsb") {
                w.set(ids::adc_inl::INL_LSB, v);
            }
        }
        Some(ids::amplitude_phase_error::ID) => write_amp_phase(&mut w, &g),
        Some(ids::tap_gain_mismatch::ID) => {
            // Δ = ε/2 · total charge; the lab's A is the fundamental amplitude,
            // total = A · peak(C)/contrast (C with fundamental 1)
            if let Some(sh) = g("signal_share") {
                let (k, peak) = (contrast(w.m), model.waveform.peak());
                w.set(ids::tap_gain_mismatch::MISMATCH_REL, 2.0 * sh * k / peak);
            }
        }
        Some(ids::multipath::ID) => {
            // the signature's parameters are the model file's
            for p in [ids::multipath::RELATIVE_AMPLITUDE, ids::multipath::EXTRA_PATH_M] {
                if let Some(v) = g(p.name()) {
                    w.set(p, v.abs());
                }
            }
        }
        Some(ids::waveform_harmonics::ID) => {
            for (i, gm) in model.waveform.gamma.iter().enumerate().skip(1) {
                if let Some((rel, phase)) = ids::harmonic(i + 1) {
                    w.set(rel, gm[0].hypot(gm[1]));
                    w.set(phase, gm[1].atan2(gm[0]).to_degrees());
                }
            }
        }
        Some(ids::sbi_asymmetry::ID) => write_sbi(&mut w, &g, prep),
        _ => w.notes.push(format!(
            "{effect}: the lab's parameters are in measurement units (see --json params); the model file keeps its typical values"
        )),
    }
    Ok(w.notes)
}

/// `vcsel_droop`: the lab fits the model's law with τ in ms^β: τ_us = 1000·τ.
fn write_droop(w: &mut Writer<'_>, g: &dyn Fn(&str) -> Option<f64>) {
    use ids::vcsel_droop as p;
    if let (Some(rate), Some(lt)) = (g("droop_rate"), g("ln_tau")) {
        let tau = lt.exp();
        w.set(p::TAU_US, tau * 1000.0);
        w.set(p::DROOP_REL, rate * tau);
    }
    if let Some(beta) = g("exposure_power") {
        w.set(p::EXPOSURE_POWER, beta.clamp(0.0, 2.0));
    }
    if let Some(k0) = g("first_image_index") {
        w.set(p::FIRST_IMAGE_INDEX, k0.clamp(0.0, 8.0));
    }
}

/// `amplitude_phase_error`: the lab's law holds φ0 and n in the file's ranges
/// (clamped there, so written clamped: exp(ln 10) is 10 + 2 ulp); the lab's
/// amplitude is in codes, the model's in electrons of the differential
/// amplitude: A[codes] = A[e]·code_per_e.
fn write_amp_phase(w: &mut Writer<'_>, g: &dyn Fn(&str) -> Option<f64>) {
    use ids::amplitude_phase_error as p;
    if let Some(v) = g("phase0_rad") {
        w.set_in_range(p::MAX_RAD, v);
    }
    if let Some(v) = g("ln_shape") {
        w.set_in_range(p::SHAPE, v.exp());
    }
    let lsb_per_e = code_per_e(w.m);
    if let Some(v) = g("ln_reference_lsb")
        && lsb_per_e > 0.0
    {
        w.set(p::REFERENCE_E, v.exp() / lsb_per_e);
    }
}

/// `sbi_asymmetry`: the lab's tap charges are in its own unit (see
/// `SbiUnits`); in electrons: threshold_e = q0·u, and the differential error
/// m_lab·N_inj[unit] = −m·N_inj[e]·lsb_per_e gives m = −m_lab/(u·lsb_per_e).
/// With varying ambient light the fit also measured the model's ambient
/// responsivity, written too.
fn write_sbi(w: &mut Writer<'_>, g: &dyn Fn(&str) -> Option<f64>, prep: &Prepared) {
    use ids::sbi_asymmetry as p;
    let kappa = g("ln_signal_weight").map(f64::exp);
    let Some(units) = SbiUnits::from_fit(w.m, prep, kappa) else {
        w.notes.push(format!(
            "{}: the model file has no conversion gain (sensor.lsb_per_ke) or no fitted signal weight; the model file keeps its typical values",
            ids::sbi_asymmetry::ID
        ));
        return;
    };
    if let Some(lq0) = g("ln_threshold") {
        w.set(p::THRESHOLD_E, lq0.exp() * units.e_per_unit);
    }
    if let Some(ml) = g("mismatch_lsb_per_unit") {
        w.set(p::MISMATCH_REL, -ml / (units.e_per_unit * units.lsb_per_e));
    }
    if let Some(v) = g("clamp_share") {
        w.set(p::CLAMP_SHARE, v.clamp(0.0, 1.0));
    }
    let Some(v) = units.ambient_e_per_us_per_klux() else {
        return;
    };
    // the SBI fit measured how many electrons a klux·ms of background adds per
    // signal electron: that is the model's ambient responsivity
    let p = ids::ambient_light::E_PER_US_PER_KLUX;
    if let Err(e) =
        w.m.enable(ids::ambient_light::ID, true)
            .and_then(|()| w.m.set(p, v))
    {
        w.notes.push(format!(
            "{p} = {v:.6} not written ({e}); kept {:?}",
            w.m.param(p.section(), p.name())
        ));
    } else {
        w.notes.push(format!(
            "{p} = {v:.6} e-/us/klux written too: the SBI fit's background charge per signal charge, which the written threshold and mismatch are scaled with; it is determined only where background light is a sizeable part of the tap charges at the threshold (with little background the fit trades it against the threshold): check it against an independent measurement before simulating noise with it"
        ));
    }
}

/// Output codes per electron of differential charge — the unit the lab's
/// "LSB" are in: the conversion gain (`sensor.lsb_per_ke` / 1000) times the
/// converter's slope (eq. 3.2, [`tofprox_model::effects::adc::gain_factor`]).
/// NaN when the file has no conversion gain.
fn code_per_e(m: &ModelConfig) -> f64 {
    m.get(ids::sensor::LSB_PER_KE) * 1e-3 * tofprox_model::effects::adc::gain_factor(m)
}

/// The unit of the lab's SBI tap charges in the model's electrons (the
/// `sbi_asymmetry` signature: N = B + κ·A(g ± C)/100 with B in klux·ms and A
/// the fundamental amplitude in LSB; the model: signal electrons per tap
/// A/lsb_per_e·(g ± C)/2 for the lab's contrast 0.8, background
/// e_per_us_per_klux·klux·µs). With ambient light varying, one unit is a
/// klux·ms of background, u = 1000·e_per_us_per_klux electrons, and κ ties it to
/// the signal: κ/100 = 1/(lsb_per_e·u). Without, κ = 1 and u = 100/lsb_per_e.
#[derive(Debug, Clone, Copy)]
struct SbiUnits {
    /// Electrons per lab unit of tap charge.
    e_per_unit: f64,
    /// Codes per electron of differential charge ([`code_per_e`]).
    lsb_per_e: f64,
    /// One unit is a klux·ms of background (the ambient light varies).
    ambient: bool,
}

impl SbiUnits {
    /// [`code_per_e`], if finite and positive.
    fn lsb_per_e(m: &ModelConfig) -> Option<f64> {
        Some(code_per_e(m)).filter(|v| v.is_finite() && *v > 0.0)
    }
    /// From a fit: κ (`ln_signal_weight`) when the ambient light varies.
    fn from_fit(m: &ModelConfig, prep: &Prepared, kappa: Option<f64>) -> Option<Self> {
        let lsb_per_e = Self::lsb_per_e(m)?;
        if prep.ambient_varies {
            let k = kappa.filter(|k| k.is_finite() && *k > 0.0)?;
            let u = 100.0 / (k * lsb_per_e);
            Some(Self {
                e_per_unit: u,
                lsb_per_e,
                ambient: true,
            })
        } else {
            Some(Self {
                e_per_unit: 100.0 / lsb_per_e,
                lsb_per_e,
                ambient: false,
            })
        }
    }
    /// From the model file: its ambient responsivity when the ambient light
    /// varies (ambient_light must be enabled for the background to reach the
    /// taps).
    fn from_model(m: &ModelConfig, prep: &Prepared) -> Option<Self> {
        let lsb_per_e = Self::lsb_per_e(m)?;
        let u = if prep.ambient_varies {
            if !m.is_enabled(ids::ambient_light::ID) {
                return None;
            }
            1000.0 * m.get(ids::ambient_light::E_PER_US_PER_KLUX)
        } else {
            100.0 / lsb_per_e
        };
        (u.is_finite() && u > 0.0).then_some(Self {
            e_per_unit: u,
            lsb_per_e,
            ambient: prep.ambient_varies,
        })
    }
    /// The model's ambient responsivity these units imply (ambient light
    /// varying): one unit is a klux·ms, u = 1000·e_per_us_per_klux.
    fn ambient_e_per_us_per_klux(&self) -> Option<f64> {
        self.ambient.then_some(self.e_per_unit / 1000.0)
    }
    /// κ of the lab's law for these units (1 without varying ambient light).
    fn kappa(&self) -> f64 {
        100.0 / (self.lsb_per_e * self.e_per_unit)
    }
}

/// The model file's text with the `enabled` flag and the parameters of the
/// effects `ids` set to `m`'s values, and of every other effect whose values
/// in `m` differ from the file's (an effect's fit may measure a neighbour's
/// parameter: the SBI fit the ambient responsivity); everything else —
/// comments, order, other tables — is kept as the user wrote it.
pub fn update_model_text(
    original: &str,
    m: &ModelConfig,
    ids: &[String],
) -> Result<String, LabError> {
    use toml_edit::{DocumentMut, Item, Value};
    let bad = |why: String| LabError::new(ErrorKind::InvalidModel, why);
    let before = ModelConfig::from_toml_str(original).ok();
    let differs = |id: &str| {
        before.as_ref().is_some_and(|b| {
            b.effect(id).map(|e| (e.enabled, &e.shape))
                != m.effect(id).map(|e| (e.enabled, &e.shape))
                || tofprox_model::catalogue::effect(id).is_some_and(|info| {
                    info.params
                        .iter()
                        .any(|p| b.param(id, p.name) != m.param(id, p.name))
                })
        })
    };
    let mut ids: Vec<&str> = ids.iter().map(String::as_str).collect();
    for info in tofprox_model::catalogue() {
        if !ids.contains(&info.id) && differs(info.id) {
            ids.push(info.id);
        }
    }
    let mut doc: DocumentMut = original
        .parse()
        .map_err(|e| bad(format!("model file is not valid TOML: {e}")))?;
    let effects = doc
        .entry("effects")
        .or_insert(toml_edit::table())
        .as_table_mut()
        .ok_or_else(|| bad("`effects` in the model file is not a table".into()))?;
    effects.set_implicit(true);
    // a new value keeps the old one's surrounding whitespace and comment
    let set = |t: &mut toml_edit::Table, key: &str, v: Value| match t.get_mut(key) {
        Some(Item::Value(old)) => {
            let decor = old.decor().clone();
            *old = v;
            *old.decor_mut() = decor;
        }
        _ => {
            t.insert(key, Item::Value(v));
        }
    };
    for id in ids {
        let info = tofprox_model::catalogue::effect(id).ok_or_else(|| {
            LabError::new(ErrorKind::UnknownEffect, format!("unknown effect `{id}`"))
        })?;
        let t = effects
            .entry(id)
            .or_insert(toml_edit::table())
            .as_table_mut()
            .ok_or_else(|| bad(format!("`effects.{id}` in the model file is not a table")))?;
        set(
            t,
            "enabled",
            Value::from(m.effect(id).is_some_and(|e| e.enabled)),
        );
        for p in info.params {
            if let Some(v) = m.param(id, p.name) {
                set(t, p.name, Value::from(v));
            }
        }
        write_shape_keys(t, id, m.effect(id).and_then(|e| e.shape.as_ref()), &set);
    }
    Ok(doc.to_string())
}

/// The shape form's keys of `[effects.<id>]`: its knots and curves when
/// `shape` is given, none of them when not (the parametric form).
fn write_shape_keys(
    t: &mut toml_edit::Table,
    id: &str,
    shape: Option<&tofprox_model::effects::shape::EffectShape>,
    set: &dyn Fn(&mut toml_edit::Table, &str, toml_edit::Value),
) {
    let Some(law) = tofprox_model::effects::shape::shape_law(id) else {
        return;
    };
    let array = |v: &[f64]| toml_edit::Value::Array(v.iter().copied().collect());
    match shape {
        Some(sh) => {
            set(t, law.driver, array(&sh.knots));
            for c in law.curves {
                match sh.curves.iter().find(|(k, _)| k == c) {
                    Some((_, v)) => set(t, c, array(v)),
                    None => {
                        t.remove(c);
                    }
                }
            }
        }
        None => {
            for k in std::iter::once(law.driver).chain(law.curves.iter().copied()) {
                t.remove(k);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn update_keeps_comments_and_sets_fitted_values() {
        let text = "# my sensor\ndescription = \"bench unit 3\"\n\n[effects.vcsel_droop]\n\
                    enabled = false  # off until measured\ndroop_rel = 0.03\n";
        let mut m = ModelConfig::from_toml_str(text).unwrap();
        m.enable(ids::vcsel_droop::ID, true).unwrap();
        m.set(ids::vcsel_droop::DROOP_REL, 0.071).unwrap();
        m.enable(ids::adc_inl::ID, true).unwrap();
        m.set(ids::adc_inl::INL_LSB, -3.5).unwrap();
        let out = update_model_text(
            text,
            &m,
            &[
                ids::vcsel_droop::ID.as_str().into(),
                ids::adc_inl::ID.as_str().into(),
            ],
        )
        .unwrap();
        assert!(out.starts_with("# my sensor\n"), "{out}");
        assert!(
            out.contains("enabled = true  # off until measured"),
            "{out}"
        );
        let back = ModelConfig::from_toml_str(&out).unwrap();
        assert_eq!(back.get(ids::vcsel_droop::DROOP_REL), 0.071);
        assert!(back.is_enabled(ids::vcsel_droop::ID) && back.is_enabled(ids::adc_inl::ID));
        assert_eq!(back.get(ids::adc_inl::INL_LSB), -3.5);
        assert!(update_model_text("[effects", &m, &[]).is_err());
    }

    #[test]
    fn update_writes_the_chosen_form_only() {
        use tofprox_model::effects::shape::{DRIFT_PHASE_RAD, EffectShape};
        let id = ids::temperature_drift::ID;
        let text = "[effects.temperature_drift]\nenabled = true  # measured\n\
                    phase_mrad_per_k = 2.0\n";
        let mut m = ModelConfig::from_toml_str(text).unwrap();
        let shape = EffectShape {
            knots: vec![10.0, 25.0, 45.0],
            curves: vec![(DRIFT_PHASE_RAD, vec![-0.1, 0.0, 0.3])],
        };
        m.set_shape(id, Some(shape.clone())).unwrap();
        let out = update_model_text(text, &m, &[id.as_str().into()]).unwrap();
        assert!(out.contains("enabled = true  # measured"), "{out}");
        let back = ModelConfig::from_toml_str(&out).unwrap();
        assert_eq!(back.shape(id), Some(&shape));
        // back to the parametric form: the shape's keys go
        let mut p = back.clone();
        p.set_shape(id, None).unwrap();
        let out2 = update_model_text(&out, &p, &[id.as_str().into()]).unwrap();
        assert!(!out2.contains("shape_"), "{out2}");
        assert_eq!(ModelConfig::from_toml_str(&out2).unwrap().shape(id), None);
        // a shape the model refuses is never set
        let bad = EffectShape {
            knots: vec![10.0, 25.0],
            curves: vec![(DRIFT_PHASE_RAD, vec![0.0])],
        };
        assert!(m.set_shape(id, Some(bad)).is_err());
    }
}
