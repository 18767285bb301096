//! One module per physical effect, each implementing [`Effect`] and entering itself
//! into [`REGISTRY`] (the way a board-support registry lists its targets, here without
//! a list: each module's `effect!` places an [`Entry`] in a `linkme` distributed slice,
//! and `automod` makes every file of this directory a module): the effect's typed ids
//! (`effect_ids!`), its catalogue entry (typed parameters with units and ranges, what it
//! acts on, which conditions drive it, its physics and thesis reference) beside the
//! forward law(s) the simulator and the lab call, and its shape form if it has one.
//!
//! Effects drawn or applied together share a module where splitting would be
//! artificial: [`fixed_pattern`] (`prnu`, `fppn`, `fpn_offset`: per-pixel
//! patterns drawn once from one seed) and [`noise`] (`shot_noise`, `read_noise`,
//! `ktc_noise`: no law on expected codes, only variances the simulator sums).
//!
//! An effect on the converter's codes carries its law with it ([`Effect::code_law`]):
//! the converter and the lab apply it from there, so adding one (such as
//! [`adc_sar_mismatch`]) is its module alone.
//!
//! Shared machinery of several effects: [`correlation`] (the correlation
//! waveform of `demodulation_contrast` and `waveform_harmonics`), [`pixel`] (a
//! pixel's parameters resolved from the model), [`adc`] (the ADC transfer the
//! `adc_*` effects and `quantization` make up) and [`shape`] (the monotone shape
//! form of `amplitude_phase_error`, `temperature_drift`, `sbi_asymmetry` and
//! `vcsel_droop`).

use std::sync::LazyLock;

use crate::entry::EffectInfo;
use crate::ids::{EffectId, ParamId};

/// An effect module's registry entry: the unit struct `$name` implementing
/// [`Effect`] with the module's catalogue entry `$info` and its id `$id` (the module's
/// `effect_ids!`), entered into [`REGISTRY`] at position `$chain` of the signal chain.
/// With `shape = $shape`, the effect has a shape form ([`Effect::shape_law`]); with
/// `code_law = $law`, the effect also carries a law on the converter's codes
/// ([`Effect::code_law`]), which the converter and the lab apply without code of their own.
macro_rules! effect {
    ($name:ident, $info:ident, $id:path, chain = $chain:literal
        $(, shape = $shape:expr)? $(, code_law = $law:expr)?) => {
        #[doc = concat!("The effect `", stringify!($name), "` in [`crate::effects::REGISTRY`].")]
        pub struct $name;

        impl $crate::effects::Effect for $name {
            fn info(&self) -> &'static $crate::entry::EffectInfo {
                &$info
            }
            fn id(&self) -> $crate::ids::EffectId {
                $id
            }
            $(
                fn shape_law(&self) -> Option<&'static $crate::effects::shape::ShapeLaw> {
                    Some(&$shape)
                }
            )?
            $(
                fn code_law(&self) -> Option<&'static dyn $crate::effects::CodeLaw> {
                    Some(&$law)
                }
            )?
        }

        // SAFETY (the `link_section` linkme places the entry in): the section holds only
        // `Entry` statics of this crate's `ENTRIES`, which reads them as one slice.
        #[allow(unsafe_code)]
        const _: () = {
            #[linkme::distributed_slice($crate::effects::ENTRIES)]
            static ENTRY: $crate::effects::Entry = $crate::effects::Entry {
                chain: $chain,
                effect: &$name,
            };
        };
    };
}

// Every file of this directory is a module (`automod`): an effect's file is all it takes.
// The two files of several effects each hold their effects' ids in a child module.
automod::dir!(pub "src/effects");

pub use fixed_pattern::{fpn_offset, fppn, prnu};
pub use noise::{ktc_noise, read_noise, shot_noise};

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
    /// Its shape form, if it has one: the keys of its law as a monotone shape of its driver
    /// ([`shape`]), which model files, the simulator and the lab's form choice use.
    fn shape_law(&self) -> Option<&'static shape::ShapeLaw> {
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

/// An effect's place in the registry: its position in the signal chain (the order of
/// [`REGISTRY`]; unique, a test checks) and the effect. Each effect module enters its own
/// (`effect!`), so the registry lists every module without a list of its own.
pub struct Entry {
    /// Position in the signal chain (3.2.1: light, pixel, converter, noise), unique.
    pub chain: u16,
    /// The effect.
    pub effect: &'static dyn Effect,
}

/// Every module's [`Entry`], in link order (a distributed slice, `linkme`).
// SAFETY (the `link_section`s linkme declares): linkme's own section bounds delimit the
// slice, and only `effect!` entries of type `Entry` are placed there.
#[allow(unsafe_code)]
#[linkme::distributed_slice]
pub static ENTRIES: [Entry];

/// Every effect of the model, in signal-chain order (the order of
/// `tofprox model effects`, model files and `tofprox_model::catalogue()`).
pub static REGISTRY: LazyLock<Vec<&'static dyn Effect>> = LazyLock::new(|| {
    let mut entries: Vec<&Entry> = ENTRIES.iter().collect();
    entries.sort_by_key(|e| e.chain);
    entries.into_iter().map(|e| e.effect).collect()
});

impl EffectId {
    /// The effect a string from outside (a model file, the command line, a
    /// report) names, if any.
    pub fn parse(id: &str) -> Option<Self> {
        REGISTRY.iter().map(|e| e.id()).find(|e| e.as_str() == id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_registry_entry_is_its_id_once_at_its_own_chain_position() {
        let mut chain: Vec<u16> = ENTRIES.iter().map(|e| e.chain).collect();
        chain.sort_unstable();
        chain.dedup();
        assert_eq!(
            chain.len(),
            ENTRIES.len(),
            "two effects at one chain position"
        );
        let mut ids: Vec<&str> = REGISTRY.iter().map(|e| e.id().as_str()).collect();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(ids.len(), REGISTRY.len(), "two effects with one id");
        for e in REGISTRY.iter() {
            let info = e.info();
            assert_eq!(info.id, e.id().as_str());
            assert_eq!(EffectId::parse(info.id), Some(e.id()));
        }
        assert_eq!(EffectId::parse("vcsel_drop"), None);
        // the signal chain: light, pixel, converter, noise (3.2.1)
        let first_last = [REGISTRY[0].id(), REGISTRY[REGISTRY.len() - 1].id()];
        assert_eq!(first_last, [signal_falloff::ID, ktc_noise::ID]);
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
