//! One module per physical effect, each implementing [`Effect`], listed once in
//! [`REGISTRY`] (the way a board-support registry lists its targets): the
//! effect's catalogue entry (typed parameters with units and ranges, what it
//! acts on, which conditions drive it, its physics and thesis reference) beside
//! the forward law(s) the simulator and the lab call.
//!
//! Effects drawn or applied together share a module where splitting would be
//! artificial: [`fixed_pattern`] (`prnu`, `fppn`, `fpn_offset`: per-pixel
//! patterns drawn once from one seed) and [`noise`] (`shot_noise`, `read_noise`,
//! `ktc_noise`: no law on expected codes, only variances the simulator sums).
//!
//! An effect on the converter's codes carries its law with it ([`Effect::code_law`]):
//! the converter and the lab apply it from there, so adding one (such as
//! [`adc_sar_mismatch`]) is its module and its line here.
//!
//! Shared machinery of several effects: [`correlation`] (the correlation
//! waveform of `demodulation_contrast` and `waveform_harmonics`), [`pixel`] (a
//! pixel's parameters resolved from the model), [`adc`] (the ADC transfer the
//! `adc_*` effects and `quantization` make up) and [`shape`] (the monotone shape
//! form of `amplitude_phase_error`, `temperature_drift`, `sbi_asymmetry` and
//! `vcsel_droop`).

use crate::entry::EffectInfo;
use crate::ids::{EffectId, ParamId};

/// An effect module's registry entry: the unit struct `$name` implementing
/// [`Effect`] with the module's catalogue entry `$info` and the id
/// `ids::$id::ID`.
/// With `code_law = $law`, the effect also carries a law on the converter's codes
/// ([`Effect::code_law`]), which the converter and the lab apply without code of their own.
macro_rules! effect {
    ($name:ident, $info:ident, $id:ident $(, code_law = $law:expr)?) => {
        #[doc = concat!("The effect `", stringify!($id), "` in [`crate::effects::REGISTRY`].")]
        pub struct $name;

        impl $crate::effects::Effect for $name {
            fn info(&self) -> &'static $crate::entry::EffectInfo {
                &$info
            }
            fn id(&self) -> $crate::ids::EffectId {
                $crate::ids::$id::ID
            }
            $(
                fn code_law(&self) -> Option<&'static dyn $crate::effects::CodeLaw> {
                    Some(&$law)
                }
            )?
        }
    };
}

pub mod adc;
pub mod adc_dnl;
pub mod adc_gain;
pub mod adc_inl;
pub mod adc_offset;
pub mod adc_sar_mismatch;
pub mod ambient_light;
pub mod amplitude_phase_error;
pub mod correlation;
pub mod cover_window_crosstalk;
pub mod dark_current;
pub mod demodulation_contrast;
pub mod fixed_pattern;
pub mod multipath;
pub mod noise;
pub mod pixel;
pub mod quantization;
pub mod sbi_asymmetry;
pub mod shape;
pub mod signal_falloff;
pub mod tap_gain_mismatch;
pub mod temperature_drift;
pub mod user;
pub mod vcsel_droop;
pub mod waveform_harmonics;

/// A physical effect of the model: its id and its catalogue entry.
pub trait Effect: Sync {
    /// Its catalogue entry: physics, thesis reference, residual signature,
    /// parameters (units, typical value, range), what it acts on, its drivers.
    fn info(&self) -> &'static EffectInfo;
    /// Its id (`[effects.<id>]` in a model file).
    fn id(&self) -> EffectId;
    /// Its law on the converter's output codes, if it has one: then the converter
    /// ([`adc::Adc`]) applies it and the lab fits it (`tofprox_lab`'s code-law signature)
    /// from this one law, so such an effect is its module and nothing else.
    fn code_law(&self) -> Option<&'static dyn CodeLaw> {
        None
    }
}

/// A law on the converter's codes, linear in its parameters (the converter stage of 3.2.1):
/// Δcode(k) = Σ_j p_j · b_j(k) for k the ideal output code (0 … 2^N − 1) of an N-bit
/// converter, p_j the values of [`CodeLaw::params`] in LSB.
pub trait CodeLaw: Sync {
    /// Its parameters (each in LSB), in the order of [`CodeLaw::basis`]'s outputs.
    fn params(&self) -> &'static [ParamId];
    /// b_j(k) for every parameter j into `out` (of length `params().len()`).
    fn basis(&self, code: u32, bits: u8, out: &mut [f64]);
}

/// Every effect of the model, in signal-chain order (the order of
/// `tofprox model effects`, model files and `tofprox_model::catalogue()`).
pub static REGISTRY: &[&dyn Effect] = &[
    &signal_falloff::SignalFalloff,
    &demodulation_contrast::DemodulationContrast,
    &waveform_harmonics::WaveformHarmonics,
    &multipath::Multipath,
    &cover_window_crosstalk::CoverWindowCrosstalk,
    &vcsel_droop::VcselDroop,
    &fixed_pattern::Prnu,
    &fixed_pattern::Fppn,
    &amplitude_phase_error::AmplitudePhaseError,
    &temperature_drift::TemperatureDrift,
    &ambient_light::AmbientLight,
    &dark_current::DarkCurrent,
    &sbi_asymmetry::SbiAsymmetry,
    &tap_gain_mismatch::TapGainMismatch,
    &fixed_pattern::FpnOffset,
    &adc_gain::AdcGain,
    &adc_offset::AdcOffset,
    &adc_inl::AdcInl,
    &adc_dnl::AdcDnl,
    &adc_sar_mismatch::AdcSarMismatch,
    &quantization::Quantization,
    &noise::ShotNoise,
    &noise::ReadNoise,
    &noise::KtcNoise,
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_registry_entry_is_its_id_once_in_ids_order() {
        let ids: Vec<EffectId> = REGISTRY.iter().map(|e| e.id()).collect();
        assert_eq!(ids, crate::ids::ALL_EFFECTS);
        for e in REGISTRY {
            assert_eq!(e.info().id, e.id().as_str());
        }
    }

    /// The README's effect count is the registry's (issue 37: a newcomer read 22 where
    /// `tofprox model effects` listed 23).
    #[test]
    fn the_readme_states_the_registry_s_effect_count() {
        let readme =
            std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../README.md"))
                .expect("README.md");
        let at = readme
            .find(" switchable")
            .expect("README.md states \"N switchable effects\"");
        let digits: String = readme[..at]
            .chars()
            .rev()
            .take_while(char::is_ascii_digit)
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        let count: usize = digits.parse().expect("a number before \"switchable\"");
        assert_eq!(count, REGISTRY.len(), "README.md's effect count");
    }
}
