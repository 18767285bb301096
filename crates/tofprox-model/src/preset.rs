//! The shipped model files `config/model/{baseline,full,ideal}.toml`, generated from the
//! registry: each is its preset's model ([`ModelConfig::baseline`], [`ModelConfig::full`],
//! [`ModelConfig::ideal`]) written by [`ModelConfig::to_toml_string`] under a fixed header,
//! so a new effect's section appears in them without an edit of its own
//! (`tofprox model preset full > config/model/full.toml`; a test checks the shipped files).

use crate::config::ModelConfig;

/// A model preset with a shipped file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Preset {
    /// What a usual calibration covers (`EffectInfo::in_baseline`).
    Baseline,
    /// Every effect of the registry with its typical parameters.
    Full,
    /// Every effect off: the ideal sinusoidal sensor of eq. 2.2/2.3.
    Ideal,
}

impl Preset {
    /// Every preset.
    pub const ALL: [Preset; 3] = [Preset::Baseline, Preset::Full, Preset::Ideal];

    /// Its name, as in `config/model/<name>.toml`.
    pub const fn name(self) -> &'static str {
        match self {
            Preset::Baseline => "baseline",
            Preset::Full => "full",
            Preset::Ideal => "ideal",
        }
    }

    /// The preset a name means, if any.
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.name() == name)
    }

    /// Its model.
    pub fn model(self) -> ModelConfig {
        match self {
            Preset::Baseline => ModelConfig::baseline(),
            Preset::Full => ModelConfig::full(),
            Preset::Ideal => ModelConfig::ideal(),
        }
    }

    /// The text of its shipped model file.
    pub fn file_text(self) -> String {
        let name = self.name();
        format!(
            "# tofprox model file ({name}), generated from the effect registry:\n\
             # `tofprox model preset {name} > config/model/{name}.toml`.\n\
             # One [effects.<id>] table per catalogue effect; `tofprox model effects`\n\
             # explains each, `tofprox model show` validates.\n{}",
            self.model().to_toml_string()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_preset_file_parses_back_to_its_model() {
        for p in Preset::ALL {
            let back = ModelConfig::from_toml_str(&p.file_text()).unwrap();
            assert_eq!(back.enabled_effects(), p.model().enabled_effects(), "{p:?}");
            assert_eq!(Preset::parse(p.name()), Some(p));
        }
        assert_eq!(Preset::parse("fulll"), None);
        assert_eq!(Preset::Ideal.model().enabled_effects().len(), 0);
    }
}
