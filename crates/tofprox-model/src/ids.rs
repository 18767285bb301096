//! Typed identifiers of the catalogue's effects and parameters.
//!
//! The model's code names an effect or a parameter through these constants
//! (`m.get(adc_gain::GAIN_ERROR_PCT_FSR)`, `m.is_enabled(vcsel_droop::ID)`), so a misspelt
//! identifier does not compile; a test checks that every constant names an entry of
//! `catalogue::catalogue()` (the registry `effects::REGISTRY`) (or of `catalogue::SENSOR_PARAMS`) and that every
//! catalogue entry has a constant. Strings from outside (model files, the command line) are
//! checked against the catalogue when they are read (`ModelConfig::set_param`, model loading).

use std::fmt;

/// An effect of the catalogue (`[effects.<id>]` in a model file).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct EffectId(&'static str);

impl EffectId {
    /// The id as in model files.
    pub const fn as_str(self) -> &'static str {
        self.0
    }
    /// The effect a string from outside (a model file, the command line, a
    /// report) names, if any.
    pub fn parse(id: &str) -> Option<Self> {
        ALL_EFFECTS.iter().copied().find(|e| e.0 == id)
    }
}

impl fmt::Display for EffectId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.0)
    }
}

/// A parameter: its section (an effect id, or `sensor` for the always-on sensor constants) and
/// its name (`[effects.<section>] <name> = …`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ParamId {
    section: &'static str,
    name: &'static str,
}

impl ParamId {
    /// The section: an effect id or `sensor`.
    pub const fn section(self) -> &'static str {
        self.section
    }
    /// The parameter's name.
    pub const fn name(self) -> &'static str {
        self.name
    }
}

impl fmt::Display for ParamId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.section == sensor::SECTION {
            write!(f, "{}.{}", self.section, self.name)
        } else {
            write!(f, "effects.{}.{}", self.section, self.name)
        }
    }
}

/// One module per effect: `ID` and a constant per parameter; the module's name is the id.
macro_rules! effect_ids {
    ($( $(#[$doc:meta])* $effect:ident { $($param:ident = $name:literal),* $(,)? } )*) => {
        $(
            $(#[$doc])*
            pub mod $effect {
                #[allow(unused_imports)]
                use super::{EffectId, ParamId};
                /// The effect.
                pub const ID: EffectId = EffectId(stringify!($effect));
                $(
                    #[doc = concat!("`[effects.", stringify!($effect), "] ", $name, "`")]
                    pub const $param: ParamId = ParamId { section: stringify!($effect), name: $name };
                )*
            }
        )*
        /// Every effect, in catalogue order.
        pub const ALL_EFFECTS: &[EffectId] = &[$($effect::ID),*];
        /// Every named effect parameter constant.
        pub const ALL_EFFECT_PARAMS: &[ParamId] = &[$($($effect::$param,)*)*];
    };
}

/// The always-on sensor constants (`[sensor]` in a model file).
pub mod sensor {
    use super::ParamId;
    /// The section's name.
    pub const SECTION: &str = "sensor";
    /// `[sensor] signal_e_per_us`
    pub const SIGNAL_E_PER_US: ParamId = ParamId {
        section: SECTION,
        name: "signal_e_per_us",
    };
    /// `[sensor] lsb_per_ke`
    pub const LSB_PER_KE: ParamId = ParamId {
        section: SECTION,
        name: "lsb_per_ke",
    };
    /// Both.
    pub const ALL: &[ParamId] = &[SIGNAL_E_PER_US, LSB_PER_KE];
}

const fn harmonic_param(name: &'static str) -> ParamId {
    ParamId {
        section: waveform_harmonics::ID.as_str(),
        name,
    }
}

/// `waveform_harmonics` amplitudes relative to the fundamental, `h2_rel … h9_rel`.
pub const HARMONIC_REL: [ParamId; 8] = [
    harmonic_param("h2_rel"),
    harmonic_param("h3_rel"),
    harmonic_param("h4_rel"),
    harmonic_param("h5_rel"),
    harmonic_param("h6_rel"),
    harmonic_param("h7_rel"),
    harmonic_param("h8_rel"),
    harmonic_param("h9_rel"),
];

/// `waveform_harmonics` phases, `h2_phase_deg … h9_phase_deg`.
pub const HARMONIC_PHASE_DEG: [ParamId; 8] = [
    harmonic_param("h2_phase_deg"),
    harmonic_param("h3_phase_deg"),
    harmonic_param("h4_phase_deg"),
    harmonic_param("h5_phase_deg"),
    harmonic_param("h6_phase_deg"),
    harmonic_param("h7_phase_deg"),
    harmonic_param("h8_phase_deg"),
    harmonic_param("h9_phase_deg"),
];

/// Harmonic `n` (2..=9) of `waveform_harmonics`: amplitude relative to the fundamental
/// (`h<n>_rel`) and phase (`h<n>_phase_deg`); `None` outside 2..=9.
pub fn harmonic(n: usize) -> Option<(ParamId, ParamId)> {
    let i = n.checked_sub(2)?;
    Some((*HARMONIC_REL.get(i)?, *HARMONIC_PHASE_DEG.get(i)?))
}

effect_ids! {
    /// Reflected signal vs distance.
    signal_falloff { EXPONENT = "exponent" }
    /// Demodulation contrast.
    demodulation_contrast { CONTRAST = "contrast" }
    /// Non-sinusoidal correlation (wiggling).
    /// Parameters by harmonic: [`harmonic`].
    waveform_harmonics {}
    /// Multipath return.
    multipath { RELATIVE_AMPLITUDE = "relative_amplitude", EXTRA_PATH_M = "extra_path_m" }
    /// Cover-window crosstalk.
    cover_window_crosstalk { E_PER_US = "e_per_us", SMUDGE_REL = "smudge_rel", WINDOW_DISTANCE_MM = "window_distance_mm", GRADIENT_REL = "gradient_rel" }
    /// VCSEL power droop over successive raw images.
    vcsel_droop { DROOP_REL = "droop_rel", TAU_US = "tau_us", EXPOSURE_POWER = "exposure_power", FIRST_IMAGE_INDEX = "first_image_index" }
    /// Photo-response non-uniformity incl. vignetting.
    prnu { SIGMA_REL = "sigma_rel", VIGNETTING_REL = "vignetting_rel" }
    /// Fixed-pattern phase noise and global delay.
    fppn { GLOBAL_DELAY_NS = "global_delay_ns", COLUMN_DELAY_PS = "column_delay_ps", PIXEL_SIGMA_PS = "pixel_sigma_ps" }
    /// Amplitude-dependent phase error.
    amplitude_phase_error { MAX_RAD = "max_rad", REFERENCE_E = "reference_e", SHAPE = "shape" }
    /// Temperature drift of phase and gain.
    temperature_drift { PHASE_MRAD_PER_K = "phase_mrad_per_k", GAIN_REL_PER_K = "gain_rel_per_k", PHASE_MRAD_PER_K2 = "phase_mrad_per_k2", GAIN_REL_PER_K2 = "gain_rel_per_k2", REFERENCE_C = "reference_c" }
    /// Uncorrelated background light.
    ambient_light { E_PER_US_PER_KLUX = "e_per_us_per_klux" }
    /// Dark current and its shot noise.
    dark_current { E_PER_US = "e_per_us", DOUBLING_C = "doubling_c" }
    /// SBI circuit with mismatch.
    sbi_asymmetry { THRESHOLD_E = "threshold_e", MISMATCH_REL = "mismatch_rel", CLAMP_SHARE = "clamp_share" }
    /// Tap gain mismatch (A/B).
    tap_gain_mismatch { MISMATCH_REL = "mismatch_rel" }
    /// Fixed-pattern offset (FPN) of the read-out.
    fpn_offset { ADC_CHANNEL_SIGMA_LSB = "adc_channel_sigma_lsb", COLUMN_SIGMA_LSB = "column_sigma_lsb", PIXEL_SIGMA_LSB = "pixel_sigma_lsb", COLUMN_LINE_LSB = "column_line_lsb", MEAN_LSB = "mean_lsb" }
    /// ADC gain error.
    adc_gain { GAIN_ERROR_PCT_FSR = "gain_error_pct_fsr" }
    /// ADC offset error.
    adc_offset { OFFSET_LSB = "offset_lsb" }
    /// ADC integral non-linearity.
    adc_inl { INL_LSB = "inl_lsb" }
    /// ADC differential non-linearity.
    adc_dnl { DNL_LSB = "dnl_lsb" }
    /// SAR capacitor-weight mismatch of the top four bits.
    adc_sar_mismatch { MSB_LSB = "msb_lsb", MSB1_LSB = "msb1_lsb", MSB2_LSB = "msb2_lsb", MSB3_LSB = "msb3_lsb" }
    /// Quantisation to integer codes.
    quantization {  }
    /// Photon shot noise.
    shot_noise { EXCESS_NOISE_FACTOR = "excess_noise_factor" }
    /// Read-out noise.
    read_noise { SIGMA_LSB = "sigma_lsb" }
    /// Reset (kTC) noise.
    ktc_noise { C_INT_FF = "c_int_ff" }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::catalogue::{SENSOR_PARAMS, catalogue, effect};

    #[test]
    fn every_constant_names_a_catalogue_entry_and_back() {
        let ids: Vec<&str> = ALL_EFFECTS.iter().map(|e| e.as_str()).collect();
        let cat: Vec<&str> = catalogue().iter().map(|e| e.id).collect();
        assert_eq!(ids, cat, "ids.rs and the catalogue list different effects");
        let mut named = ALL_EFFECT_PARAMS.to_vec();
        named.extend((2..=9).flat_map(|n| {
            let (r, p) = harmonic(n).unwrap();
            [r, p]
        }));
        for p in &named {
            let info = effect(p.section()).unwrap_or_else(|| panic!("{p}: no such effect"));
            assert!(info.param(p.name()).is_some(), "{p}: not in the catalogue");
        }
        let n_cat: usize = catalogue().iter().map(|e| e.params.len()).sum();
        assert_eq!(named.len(), n_cat, "a catalogue parameter has no constant");
        let sensor: Vec<&str> = sensor::ALL.iter().map(|p| p.name()).collect();
        let sensor_cat: Vec<&str> = SENSOR_PARAMS.iter().map(|p| p.name).collect();
        assert_eq!(sensor, sensor_cat);
        assert!(harmonic(1).is_none() && harmonic(10).is_none());
        assert_eq!(EffectId::parse("vcsel_droop"), Some(vcsel_droop::ID));
        assert_eq!(EffectId::parse("vcsel_drop"), None);
    }
}
