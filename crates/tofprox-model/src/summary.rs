//! What a model file sets, effect by effect: the content `tofprox model show --json` prints and
//! Python's `tofprox.Model` holds.

use std::collections::BTreeMap;

use serde::Serialize;

use crate::ModelConfig;
use crate::catalogue::{SENSOR_PARAMS, catalogue};

/// One catalogue effect in a model file: switched on or not, and the parameters the file sets.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EffectState {
    /// Whether the file switches the effect on.
    pub enabled: bool,
    /// Parameter name → value (in the catalogue's unit).
    pub params: BTreeMap<String, f64>,
}

/// A model file's description, sensor parameters and every catalogue effect's state (fields in
/// the JSON's key order).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModelSummary {
    /// The file's description.
    pub description: Option<String>,
    /// Effect id → state, for every effect of the catalogue.
    pub effects: BTreeMap<String, EffectState>,
    /// Whether the correlation comes from measured illumination/modulation waveforms.
    pub measured_waveforms: bool,
    /// `[sensor]` parameter → value, for those the file sets.
    pub sensor: BTreeMap<String, f64>,
    /// The file's user effects (`[[user_effects]]`, `effects::user`), in file order.
    pub user_effects: Vec<crate::effects::user::UserEffect>,
}

impl ModelSummary {
    /// The summary of `m`.
    pub fn of(m: &ModelConfig) -> Self {
        let effects = catalogue()
            .iter()
            .map(|e| {
                let params = e
                    .params
                    .iter()
                    .filter_map(|p| m.param(e.id, p.name).map(|v| (p.name.to_string(), v)))
                    .collect();
                let enabled = m.effect(e.id).is_some_and(|s| s.enabled);
                (e.id.to_string(), EffectState { enabled, params })
            })
            .collect();
        let sensor = SENSOR_PARAMS
            .iter()
            .filter_map(|p| m.param("sensor", p.name).map(|v| (p.name.to_string(), v)))
            .collect();
        ModelSummary {
            description: m.description.clone(),
            effects,
            measured_waveforms: m.waveforms().is_some(),
            sensor,
            user_effects: m.user_effects().to_vec(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_summary_lists_every_effect_and_what_the_file_enables() {
        let m = ModelConfig::ideal();
        let s = ModelSummary::of(&m);
        assert_eq!(s.effects.len(), catalogue().len());
        let on: Vec<&str> = s
            .effects
            .iter()
            .filter(|(_, st)| st.enabled)
            .map(|(id, _)| id.as_str())
            .collect();
        assert_eq!(on, {
            let mut v = m.enabled_effects();
            v.sort_unstable();
            v
        });
    }
}
