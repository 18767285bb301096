//! The catalogue's types and look-ups: what an effect's entry holds (its id,
//! its physics, the thesis reference, its residual signature, its parameters
//! with units, typical value and physical range, what it acts on, which capture
//! conditions drive it and whether it cancels in the 4-phase algorithm).
//!
//! Ids and parameter names are spelled once, in [`crate::ids`]; each effect's
//! entry and its laws live in its own module under [`crate::effects`], listed
//! once in [`effects::REGISTRY`]. [`catalogue()`] is that registry's entries: the
//! one list the simulator's configuration, the config validation, `tofprox model
//! effects`, the docs and the lab (`tofprox_lab`: which effects it fits, their
//! drivers, 2- vs 4-phase) read.

use std::sync::LazyLock;

use serde::Serialize;

use crate::effects;
use crate::ids::{self, ParamId};

/// What an effect changes in the signal chain (2.2–3.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ActsOn {
    /// The signal electrons of a return (their number, or a second return).
    Signal,
    /// The shape of the correlation C(φ − θ).
    Correlation,
    /// The signal phasor's gain and phase: the lab applies it to amplitude and
    /// phase rather than adding codes.
    Phasor,
    /// Electrons common to both taps (background, dark current).
    TapCharge,
    /// The differential charge of the two taps directly.
    Differential,
    /// A code offset of the read-out.
    Offset,
    /// The ADC's transfer function.
    Adc,
    /// Noise only: the expected codes do not change.
    Noise,
}

/// A capture condition (or a quantity of a sample) an effect varies with; the
/// lab advises on a condition one effect varies with and another does not.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Driver {
    /// The signal amplitude (reflectivity, distance, exposure).
    Amplitude,
    /// `exposure_us`.
    ExposureUs,
    /// `ambient_klux`.
    AmbientKlux,
    /// `temperature_c`.
    TemperatureC,
    /// The raw image's index in the acquisition.
    ImageIndex,
    /// The phase φ − θ of a raw image.
    Phase,
    /// `distance_m`.
    DistanceM,
    /// The output code of the ADC.
    AdcCode,
}

impl ActsOn {
    /// The name as in `tofprox model effects` and its JSON.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Signal => "signal",
            Self::Correlation => "correlation",
            Self::Phasor => "phasor",
            Self::TapCharge => "tap_charge",
            Self::Differential => "differential",
            Self::Offset => "offset",
            Self::Adc => "adc",
            Self::Noise => "noise",
        }
    }
}

impl Driver {
    /// The name as a recording's condition key or the lab's quantity.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Amplitude => "amplitude",
            Self::ExposureUs => "exposure_us",
            Self::AmbientKlux => "ambient_klux",
            Self::TemperatureC => "temperature_c",
            Self::ImageIndex => "image_index",
            Self::Phase => "phase",
            Self::DistanceM => "distance_m",
            Self::AdcCode => "adc_code",
        }
    }
}

/// One parameter of an effect.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ParamInfo {
    /// Key in the model file (`[effects.<id>] <name> = value`).
    pub name: &'static str,
    /// Physical unit ("" for dimensionless).
    pub unit: &'static str,
    /// Typical value (thesis value where the thesis gives one).
    pub typical: f64,
    /// Smallest physically meaningful value (inclusive).
    pub min: f64,
    /// Largest physically meaningful value (inclusive).
    pub max: f64,
    /// One-line meaning.
    pub doc: &'static str,
}

/// One effect of the catalogue.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct EffectInfo {
    /// Stable id, used as `[effects.<id>]` in model files.
    pub id: &'static str,
    /// Short title.
    pub title: &'static str,
    /// One paragraph of physics with the equation used.
    pub explanation: &'static str,
    /// Where the thesis treats it.
    pub thesis_ref: &'static str,
    /// What the effect looks like in a residual (measured − model).
    pub signature: &'static str,
    /// Parameters with units, typical values and ranges.
    pub params: &'static [ParamInfo],
    /// Enabled in `config/model/baseline.toml` (what a usual calibration covers).
    pub in_baseline: bool,
    /// What it changes in the signal chain.
    pub acts_on: ActsOn,
    /// The conditions its residual varies with.
    pub drivers: &'static [Driver],
    /// Its residual is common to the raw images and cancels in the 4-phase
    /// algorithm (0° − 180°), not in 2-phase (5.1.2.3, eq. 3.4).
    pub cancels_in_four_phase: bool,
}

impl EffectInfo {
    /// Parameter description by name.
    pub fn param(&self, name: &str) -> Option<&'static ParamInfo> {
        self.params.iter().find(|p| p.name == name)
    }
}

/// A parameter description (the effects' modules build their entries with it).
pub(crate) const fn param(
    id: ParamId,
    unit: &'static str,
    typical: f64,
    min: f64,
    max: f64,
    doc: &'static str,
) -> ParamInfo {
    ParamInfo {
        name: id.name(),
        unit,
        typical,
        min,
        max,
        doc,
    }
}

/// Section name of the always-on sensor constants (`[sensor]` in a model file).
pub const SENSOR_SECTION: &str = ids::sensor::SECTION;

/// Always-present sensor constants (not effects; `[sensor]` in a model file).
pub static SENSOR_PARAMS: &[ParamInfo] = &[
    param(
        ids::sensor::SIGNAL_E_PER_US,
        "e-/us",
        40.0,
        1e-3,
        1e6,
        "photo-electrons per µs of exposure (both taps) from a reflectivity-1 target at 1 m at nominal optical power",
    ),
    param(
        ids::sensor::LSB_PER_KE,
        "LSB/ke-",
        3.0,
        1e-3,
        1e4,
        "conversion gain of the differential read-out: ADC codes per 1000 electrons of tap difference",
    ),
];

/// Look up an effect by id.
pub fn effect(id: &str) -> Option<&'static EffectInfo> {
    catalogue().iter().find(|e| e.id == id)
}

/// The parameter's description (units, typical value, range); `None` for a
/// constant of no entry (none: ids::tests).
pub fn param_info(p: ParamId) -> Option<&'static ParamInfo> {
    if p.section() == SENSOR_SECTION {
        SENSOR_PARAMS.iter().find(|i| i.name == p.name())
    } else {
        effect(p.section())?.param(p.name())
    }
}

/// The parameter's typical value. Every [`ParamId`] names a registry parameter
/// (checked by the tests of [`crate::ids`]), so this never misses; were it to,
/// the value is NaN, as in [`crate::ModelConfig::get`].
pub fn typical(p: ParamId) -> f64 {
    param_info(p).map_or(f64::NAN, |i| i.typical)
}

/// The entries of [`effects::REGISTRY`], in its (signal-chain) order.
static CATALOGUE: LazyLock<Vec<EffectInfo>> =
    LazyLock::new(|| effects::REGISTRY.iter().map(|e| *e.info()).collect());

/// The catalogue of effects: the entries of the registry, in signal-chain order.
pub fn catalogue() -> &'static [EffectInfo] {
    &CATALOGUE
}

/// The candidate a misspelled name most likely meant ("did you mean"): the closest by
/// Jaro–Winkler similarity, if it is close enough (≥ 0.8; `vcsel_drop` → `vcsel_droop`).
pub fn closest<'a>(given: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    candidates
        .into_iter()
        .map(|c| (strsim::jaro_winkler(given, c), c))
        .filter(|(score, _)| *score >= 0.8)
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, c)| c)
}

#[cfg(test)]
mod closest_tests {
    use super::*;

    #[test]
    fn misspelled_effects_find_their_id_and_strangers_find_none() {
        let ids = || catalogue().iter().map(|e| e.id);
        assert_eq!(
            closest("vcsel_drop", ids()),
            Some(ids::vcsel_droop::ID.as_str())
        );
        assert_eq!(closest("adcinl", ids()), Some(ids::adc_inl::ID.as_str()));
        assert_eq!(
            closest("quantisation", ids()),
            Some(ids::quantization::ID.as_str())
        );
        assert_eq!(closest("banana", ids()), None);
    }
}
