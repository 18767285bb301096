//! Bridges to the other crates: a `tofprox_format::Recording` becomes a
//! [`Dataset`], a `tofprox_model::ModelConfig` becomes a [`LabSpec`], and a
//! fitted effect is written back into a model file.
use std::collections::BTreeMap;
use std::path::Path;

use tofprox_format::Recording;
use tofprox_model::ModelConfig;

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
    if !m.is_enabled(tofprox_model::ids::waveform_harmonics::ID) {
        return 1;
    }
    if m.waveforms().is_some() {
        return MAX_HARMONIC;
    }
    (2..=MAX_HARMONIC)
        .rev()
        .find(|h| tofprox_model::ids::harmonic(*h).is_some_and(|(rel, _)| m.get(rel).abs() > 0.0))
        .unwrap_or(1)
}

/// Which parts of the lab model are free, from the model's enabled effects.
pub fn spec_from_model(m: &ModelConfig) -> LabSpec {
    LabSpec {
        harmonic_order: harmonic_order(m),
        per_pixel_offset: m.is_enabled(tofprox_model::ids::fpn_offset::ID)
            || m.is_enabled(tofprox_model::ids::adc_offset::ID),
        per_pixel_gain: m.is_enabled(tofprox_model::ids::prnu::ID),
        per_pixel_phase: m.is_enabled(tofprox_model::ids::fppn::ID),
        effects: SIGNATURE_IDS
            .iter()
            .filter(|id| **id != "waveform_harmonics" && m.effect(id).is_some_and(|e| e.enabled))
            .map(|s| s.to_string())
            .collect(),
        held: Vec::new(),
    }
}

/// The model file's own physics as lab parameters (the inverse of
/// [`write_effect`]) for `compare --hold-effects`: every enabled effect whose
/// parameters map onto the lab's law is held at the file's values. Returns the
/// spec and notes naming the effects that are fitted freely instead.
pub fn spec_holding_model(m: &ModelConfig, prep: &Prepared) -> (LabSpec, Vec<String>) {
    let mut spec = spec_from_model(m);
    let mut notes = Vec::new();
    let g = |id: &str, name: &str| m.param(id, name).unwrap_or(0.0);
    // 0 when the file has no conversion gain (NaN.max(0) is 0)
    let lsb_per_e = code_per_e(m).max(0.0);
    for id in spec.effects.clone() {
        let fit = match id.as_str() {
            "vcsel_droop" => {
                let tau = g(&id, "tau_us") / 1000.0;
                Some((
                    vec![g(&id, "droop_rel") / tau.max(1e-12)],
                    vec![
                        tau.max(1e-12).ln(),
                        g(&id, "exposure_power"),
                        g(&id, "first_image_index"),
                    ],
                ))
            }
            "amplitude_phase_error" if lsb_per_e > 0.0 => Some((
                Vec::new(),
                vec![
                    g(&id, "max_rad"),
                    (g(&id, "reference_e") * lsb_per_e).max(1e-12).ln(),
                    g(&id, "shape").max(1e-6).ln(),
                ],
            )),
            // about the lab's reference T_l instead of the file's T_r
            // (δ = T_l − T_r): k(u + δ) + k2(u + δ)² = const + (k + 2k2δ)u + k2u²;
            // the constant phase shifts the per-pixel phase (refitted), the
            // constant gain c0 the per-pixel gain: 1 + G(u + δ) =
            // (1 + c0)·(1 + G′(u)) with G′'s coefficients divided by 1 + c0.
            // The lab's law is the full one: nl = phase, lin = gain.
            "temperature_drift" => {
                let d = prep.temp_ref - g(&id, "reference_c");
                let (k, k2) = (
                    g(&id, "phase_mrad_per_k") * 1e-3,
                    g(&id, "phase_mrad_per_k2") * 1e-3,
                );
                let (kg, kg2) = (g(&id, "gain_rel_per_k"), g(&id, "gain_rel_per_k2"));
                let c0 = (1.0 + kg * d + kg2 * d * d).max(1e-9);
                Some((
                    vec![(kg + 2.0 * kg2 * d) / c0, kg2 / c0],
                    vec![k + 2.0 * k2 * d, k2],
                ))
            }
            "adc_inl" => Some((vec![g(&id, "inl_lsb")], Vec::new())),
            // the inverse of write_effect's mapping (SbiUnits); nl = [ln q0,
            // (ln κ when the ambient light varies), clamp share]
            "sbi_asymmetry" => SbiUnits::from_model(m, prep).map(|u| {
                let mut nl = vec![(g(&id, "threshold_e") / u.e_per_unit).max(1e-300).ln()];
                if prep.ambient_varies {
                    nl.push(u.kappa().ln());
                }
                nl.push(g(&id, "clamp_share"));
                (
                    vec![-g(&id, "mismatch_rel") * u.e_per_unit * u.lsb_per_e],
                    nl,
                )
            }),
            "tap_gain_mismatch" => {
                // s = ε·peak/(2·contrast) (see write_effect); the lab's C has
                // fundamental 1, the model's peak 1: peak_lab = 1/|a₁|
                let c = tofprox_model::effects::optical::Correlation::from_model(m);
                let a1 = c
                    .coefficients()
                    .get(1)
                    .map_or(1.0, |(a, b)| a.hypot(*b))
                    .max(1e-9);
                let contrast = if m.is_enabled(tofprox_model::ids::demodulation_contrast::ID) {
                    g("demodulation_contrast", "contrast")
                } else {
                    1.0
                };
                let eps = g(&id, "mismatch_rel");
                let mut lin = vec![eps / (a1 * 2.0 * contrast.max(1e-9))];
                if prep.ambient_varies {
                    // ε/2 · 2·N_ambient per tap, in LSB per klux·ms
                    let amb = if m.is_enabled(tofprox_model::ids::ambient_light::ID) {
                        g("ambient_light", "e_per_us_per_klux")
                    } else {
                        0.0
                    };
                    lin.push(eps * amb * 1000.0 * lsb_per_e);
                }
                Some((lin, Vec::new()))
            }
            _ => None,
        };
        match fit {
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
    // the ambient responsivity the SBI fit measured (written after the match)
    let mut ambient = None;
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
            // the lab fits the model's law with τ in ms^β: τ_us = 1000·τ
            if let (Some(rate), Some(lt)) = (g("droop_rate"), g("ln_tau")) {
                let tau = lt.exp();
                set(m, "tau_us", tau * 1000.0);
                set(m, "droop_rel", rate * tau);
            }
            if let Some(beta) = g("exposure_power") {
                set(m, "exposure_power", beta.clamp(0.0, 2.0));
            }
            if let Some(k0) = g("first_image_index") {
                set(m, "first_image_index", k0.clamp(0.0, 8.0));
            }
        }
        "temperature_drift" => {
            if let Some(v) = g("phase_rad_per_k") {
                set(m, "phase_mrad_per_k", v * 1000.0);
            }
            if let Some(v) = g("gain_per_k") {
                set(m, "gain_rel_per_k", v);
            }
            // second order: fitted when the recording has ≥ 3 temperatures,
            // else the linear law (0)
            set(
                m,
                "phase_mrad_per_k2",
                g("phase_rad_per_k2").unwrap_or(0.0) * 1000.0,
            );
            set(m, "gain_rel_per_k2", g("gain_per_k2").unwrap_or(0.0));
            set(m, "reference_c", prep.temp_ref);
        }
        "adc_inl" => {
            if let Some(v) = g("inl_bow_lsb") {
                set(m, "inl_lsb", v);
            }
        }
        "amplitude_phase_error" => {
            // the lab's law holds φ0 and n in the file's ranges (clamped
            // there, so written clamped: exp(ln 10) is 10 + 2 ulp)
            let in_range = |name: &str, v: f64| {
                tofprox_model::catalogue::effect(effect)
                    .and_then(|e| e.param(name))
                    .map_or(v, |p| v.clamp(p.min, p.max))
            };
            if let Some(v) = g("phase0_rad") {
                set(m, "max_rad", in_range("max_rad", v));
            }
            if let Some(v) = g("ln_shape") {
                set(m, "shape", in_range("shape", v.exp()));
            }
            // the lab's amplitude is in codes; the model's in electrons of the
            // differential amplitude: A[codes] = A[e]·code_per_e
            let lsb_per_e = code_per_e(m);
            if let Some(v) = g("ln_reference_lsb")
                && lsb_per_e > 0.0
            {
                set(m, "reference_e", v.exp() / lsb_per_e);
            }
        }
        "tap_gain_mismatch" => {
            // Δ = ε/2 · total charge; the lab's A is the fundamental amplitude,
            // total = A · peak(C)/contrast (C with fundamental 1)
            let peak = (0..360)
                .map(|i| model.waveform.eval(f64::from(i).to_radians()).0)
                .fold(1.0f64, f64::max);
            let contrast = if m.is_enabled(tofprox_model::ids::demodulation_contrast::ID) {
                m.param("demodulation_contrast", "contrast").unwrap_or(1.0)
            } else {
                1.0
            };
            if let Some(sh) = g("signal_share") {
                set(m, "mismatch_rel", 2.0 * sh * contrast / peak);
            }
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
        "sbi_asymmetry" => {
            // the lab's tap charges are in its own unit (see `SbiUnits`); in
            // electrons: threshold_e = q0·u, and the differential error
            // m_lab·N_inj[unit] = −m·N_inj[e]·lsb_per_e gives m = −m_lab/(u·lsb_per_e)
            let kappa = g("ln_signal_weight").map(f64::exp);
            match SbiUnits::from_fit(m, prep, kappa) {
                Some(units) => {
                    if let Some(lq0) = g("ln_threshold") {
                        set(m, "threshold_e", lq0.exp() * units.e_per_unit);
                    }
                    if let Some(ml) = g("mismatch_lsb_per_unit") {
                        set(
                            m,
                            "mismatch_rel",
                            -ml / (units.e_per_unit * units.lsb_per_e),
                        );
                    }
                    if let Some(v) = g("clamp_share") {
                        set(m, "clamp_share", v.clamp(0.0, 1.0));
                    }
                    ambient = units.ambient_e_per_us_per_klux();
                }
                None => notes.push(format!(
                    "{effect}: the model file has no conversion gain (sensor.lsb_per_ke) or no fitted signal weight; the model file keeps its typical values"
                )),
            }
        }
        _ => notes.push(format!(
            "{effect}: the lab's parameters are in measurement units (see --json params); the model file keeps its typical values"
        )),
    }
    if let Some(v) = ambient {
        // the SBI fit measured how many electrons a klux·ms of background
        // adds per signal electron: that is the model's ambient responsivity
        let p = tofprox_model::ids::ambient_light::E_PER_US_PER_KLUX;
        if let Err(e) = m
            .set_enabled(p.section(), true)
            .and_then(|()| m.set_param(p.section(), p.name(), v))
        {
            notes.push(format!(
                "{p} = {v:.6} not written ({e}); kept {:?}",
                m.param(p.section(), p.name())
            ));
        } else {
            notes.push(format!(
                "{p} = {v:.6} e-/us/klux written too: the SBI fit's background charge per signal charge, which the written threshold and mismatch are scaled with; it is determined only where background light is a sizeable part of the tap charges at the threshold (with little background the fit trades it against the threshold): check it against an independent measurement before simulating noise with it"
            ));
        }
    }
    Ok(notes)
}

/// Output codes per electron of differential charge — the unit the lab's
/// "LSB" are in: the conversion gain (`sensor.lsb_per_ke` / 1000) times the
/// converter's slope (eq. 3.2, [`tofprox_model::effects::adc::gain_factor`]).
/// NaN when the file has no conversion gain.
fn code_per_e(m: &ModelConfig) -> f64 {
    m.get(tofprox_model::ids::sensor::LSB_PER_KE)
        * 1e-3
        * tofprox_model::effects::adc::gain_factor(m)
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
            if !m.is_enabled(tofprox_model::ids::ambient_light::ID) {
                return None;
            }
            1000.0 * m.get(tofprox_model::ids::ambient_light::E_PER_US_PER_KLUX)
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
            b.effect(id).map(|e| e.enabled) != m.effect(id).map(|e| e.enabled)
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
    }
    Ok(doc.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn update_keeps_comments_and_sets_fitted_values() {
        let text = "# my sensor\ndescription = \"bench unit 3\"\n\n[effects.vcsel_droop]\n\
                    enabled = false  # off until measured\ndroop_rel = 0.03\n";
        let mut m = ModelConfig::from_toml_str(text).unwrap();
        m.set_enabled("vcsel_droop", true).unwrap();
        m.set_param("vcsel_droop", "droop_rel", 0.071).unwrap();
        m.set_enabled("adc_inl", true).unwrap();
        m.set_param("adc_inl", "inl_lsb", -3.5).unwrap();
        let out = update_model_text(text, &m, &["vcsel_droop".into(), "adc_inl".into()]).unwrap();
        assert!(out.starts_with("# my sensor\n"), "{out}");
        assert!(
            out.contains("enabled = true  # off until measured"),
            "{out}"
        );
        let back = ModelConfig::from_toml_str(&out).unwrap();
        assert_eq!(back.param("vcsel_droop", "droop_rel"), Some(0.071));
        assert!(
            back.is_enabled(tofprox_model::ids::vcsel_droop::ID)
                && back.is_enabled(tofprox_model::ids::adc_inl::ID)
        );
        assert_eq!(back.param("adc_inl", "inl_lsb"), Some(-3.5));
        assert!(update_model_text("[effects", &m, &[]).is_err());
    }
}
