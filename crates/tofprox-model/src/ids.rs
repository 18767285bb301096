//! The types of the catalogue's typed identifiers, [`EffectId`] and [`ParamId`], the
//! `sensor` constants, and the macro an effect module declares its own with
//! (`effect_ids!`: `effects::vcsel_droop::ID`, `effects::adc_gain::GAIN_ERROR_PCT_FSR`).
//!
//! The model's code names an effect or a parameter through those constants
//! (`m.get(adc_gain::GAIN_ERROR_PCT_FSR)`, `m.is_enabled(vcsel_droop::ID)`), so a misspelt
//! identifier does not compile; a test checks every registry entry's parameters against its
//! catalogue entry (`effects::REGISTRY`). Strings from outside (model files, the command
//! line) are checked against the catalogue when they are read (`EffectId::parse`,
//! `ModelConfig::set_param`, model loading).

use std::fmt;

/// An effect of the catalogue (`[effects.<id>]` in a model file).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct EffectId(&'static str);

impl EffectId {
    /// The id as in model files.
    pub const fn as_str(self) -> &'static str {
        self.0
    }
    /// The id of an effect module (through [`effect_ids`], so only the crate makes one).
    pub(crate) const fn new(id: &'static str) -> Self {
        Self(id)
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
    /// A parameter of section `section` (through [`effect_ids`], so only the crate makes one).
    pub(crate) const fn new(section: &'static str, name: &'static str) -> Self {
        Self { section, name }
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

/// An effect module's typed ids, declared in the module itself (its one home): `ID` and a
/// constant per parameter (`effects::vcsel_droop::DROOP_REL`); the effect's id is the module's
/// name. `effects::Effect::id` and its catalogue entry use them, and a test checks every
/// registry entry's parameters against its catalogue entry.
macro_rules! effect_ids {
    ($effect:ident { $($param:ident = $name:literal),* $(,)? }) => {
        /// The effect's id.
        pub const ID: $crate::ids::EffectId = $crate::ids::EffectId::new(stringify!($effect));
        $(
            #[doc = concat!("`[effects.", stringify!($effect), "] ", $name, "`")]
            pub const $param: $crate::ids::ParamId =
                $crate::ids::ParamId::new(stringify!($effect), $name);
        )*
    };
}
pub(crate) use effect_ids;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::catalogue::SENSOR_PARAMS;

    #[test]
    fn the_sensor_constants_are_the_catalogue_s() {
        let sensor: Vec<&str> = sensor::ALL.iter().map(|p| p.name()).collect();
        let sensor_cat: Vec<&str> = SENSOR_PARAMS.iter().map(|p| p.name).collect();
        assert_eq!(sensor, sensor_cat);
        assert_eq!(sensor::LSB_PER_KE.to_string(), "sensor.lsb_per_ke");
        assert_eq!(
            ParamId::new("vcsel_droop", "tau_us").to_string(),
            "effects.vcsel_droop.tau_us"
        );
    }
}
