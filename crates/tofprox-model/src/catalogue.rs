//! The catalogue's look-ups: an effect's entry by id, a parameter's description
//! and typical value, the registry's entries in order, "did you mean". What an
//! entry holds is [`crate::entry`] (re-exported here).
//!
//! Ids and parameter names are spelled once, in [`crate::ids`]; each effect's
//! entry and its laws live in its own module under [`crate::effects`], listed
//! once in [`effects::REGISTRY`]. [`catalogue()`] is that registry's entries: the
//! one list the simulator's configuration, the config validation, `tofprox model
//! effects`, the docs and the lab (`tofprox_lab`: which effects it fits, their
//! drivers, 2- vs 4-phase) read.

use std::sync::LazyLock;

use crate::effects;
use crate::ids::ParamId;

pub use crate::entry::{ActsOn, Driver, EffectInfo, ParamInfo, SENSOR_PARAMS, SENSOR_SECTION};

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
            Some(effects::vcsel_droop::ID.as_str())
        );
        assert_eq!(
            closest("adcinl", ids()),
            Some(effects::adc_inl::ID.as_str())
        );
        assert_eq!(
            closest("quantisation", ids()),
            Some(effects::quantization::ID.as_str())
        );
        assert_eq!(closest("banana", ids()), None);
    }
}
