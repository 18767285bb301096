//! What a catalogue entry holds (a leaf module: the effects' modules build their
//! entries from these types, the look-ups of `catalogue` read them): an
//! effect's id, its physics, the thesis reference, its residual signature, its
//! parameters with units, typical value and physical range, what it acts on, which
//! capture conditions drive it and whether it cancels in the 4-phase algorithm
//! (thesis 2.2–3.2); and the always-present sensor constants.

use serde::Serialize;

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
