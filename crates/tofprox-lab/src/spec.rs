//! What the lab fits: which parts of the lab model are free ([`LabSpec`]) and
//! one effect's fitted values ([`EffectFit`]). A leaf of the lab.

use serde::Serialize;

/// Which parts of the lab model are free, from the model file's enabled effects.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LabSpec {
    /// Highest harmonic of the correlation waveform that is fitted (1 = sinusoid).
    pub harmonic_order: usize,
    /// Fit an offset per pixel (fpn_offset/adc_offset); otherwise one global offset.
    pub per_pixel_offset: bool,
    /// Fit a gain per pixel (prnu); otherwise one global gain.
    pub per_pixel_gain: bool,
    /// Fit a phase offset per pixel (fppn); otherwise one global delay.
    pub per_pixel_phase: bool,
    /// Catalogue effects with a lab signature that the model enables.
    pub effects: Vec<String>,
    /// Effects whose parameters are held at these values (`compare
    /// --hold-effects`: the model file's physics); only the per-pixel and
    /// per-unit parameters are fitted around them.
    pub held: Vec<EffectFit>,
    /// Effects fitted with some of their parameters held (`lab add --hold`,
    /// [`crate::hold`]): per parameter, in `lin` then `nl` order, the value it is held at.
    pub holds: std::collections::BTreeMap<String, crate::hold::HoldMask>,
    /// The dark current's doubling ΔT₂ in K (`dark_current.doubling_c` of the
    /// model file; the registry's typical value by default).
    pub dark_doubling_k: f64,
    /// Effects whose law is the shape form (`crate::shape`): their knots in
    /// the lab's driver units (amplitude: LSB; temperature: °C).
    pub shapes: std::collections::BTreeMap<String, Vec<f64>>,
    /// The model's user effects (`crate::user`), fitted like the enabled
    /// effects: their names are in `effects`.
    pub user_effects: Vec<tofprox_model::effects::user::UserEffect>,
}

impl Default for LabSpec {
    fn default() -> Self {
        Self {
            harmonic_order: 1,
            per_pixel_offset: true,
            per_pixel_gain: true,
            per_pixel_phase: true,
            effects: Vec::new(),
            held: Vec::new(),
            holds: std::collections::BTreeMap::new(),
            dark_doubling_k: tofprox_model::catalogue::typical(
                tofprox_model::effects::dark_current::DOUBLING_C,
            ),
            shapes: std::collections::BTreeMap::new(),
            user_effects: Vec::new(),
        }
    }
}

/// Fitted parameters of one effect signature: linear and non-linear parts.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EffectFit {
    /// Catalogue id of the effect.
    pub id: String,
    /// Linear coefficients (see [`crate::signatures::Signature::lin_names`]).
    pub lin: Vec<f64>,
    /// Non-linear parameters (see [`crate::signatures::Signature::nl_names`]).
    pub nl: Vec<f64>,
}
