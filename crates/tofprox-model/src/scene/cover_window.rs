//! The cover window in front of emitter and lens, as a scene sets it.

use serde::{Deserialize, Serialize};

use crate::error::ModelError;

/// The cover window in front of emitter and lens: the scene-side settings of the
/// `cover_window_crosstalk` effect (clean or smudged). Serde-configurable
/// (`[cover_window]` of the emulated device):
/// ```toml
/// e_per_us = 20.0          # clean-window crosstalk, e-/µs (both taps)
/// smudge_rel = 1.0         # a smudge doubling it
/// window_distance_mm = 3.0
/// gradient_rel = 0.5
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CoverWindow {
    /// Crosstalk electrons per µs of exposure of the clean window (both taps).
    pub e_per_us: f64,
    /// Extra crosstalk of a smudge relative to the clean window (1 = doubled).
    pub smudge_rel: f64,
    /// Distance of the reflecting surface from the sensor, mm.
    pub window_distance_mm: f64,
    /// Relative change across the columns of the full array.
    pub gradient_rel: f64,
}

/// Catalogue id of the effect a [`CoverWindow`] sets.
pub const COVER_WINDOW_EFFECT: &str = crate::effects::cover_window_crosstalk::ID.as_str();

impl Default for CoverWindow {
    /// The catalogue's typical clean window.
    fn default() -> Self {
        let typical = |name: &str| {
            crate::catalogue::effect(COVER_WINDOW_EFFECT)
                .and_then(|e| e.param(name))
                .map_or(0.0, |p| p.typical)
        };
        CoverWindow {
            e_per_us: typical("e_per_us"),
            smudge_rel: 0.0,
            window_distance_mm: typical("window_distance_mm"),
            gradient_rel: typical("gradient_rel"),
        }
    }
}

impl CoverWindow {
    /// The typical window with a smudge that multiplies its crosstalk by `1 + smudge_rel`.
    pub fn smudged(smudge_rel: f64) -> Self {
        CoverWindow {
            smudge_rel,
            ..Self::default()
        }
    }

    /// Enable `cover_window_crosstalk` in `model` with these parameters (range-checked:
    /// the error names the parameter and its physical range).
    pub fn apply(&self, model: &mut crate::ModelConfig) -> Result<(), ModelError> {
        model.set_enabled(COVER_WINDOW_EFFECT, true)?;
        for (name, v) in [
            ("e_per_us", self.e_per_us),
            ("smudge_rel", self.smudge_rel),
            ("window_distance_mm", self.window_distance_mm),
            ("gradient_rel", self.gradient_rel),
        ] {
            model.set_param(COVER_WINDOW_EFFECT, name, v)?;
        }
        Ok(())
    }
}
