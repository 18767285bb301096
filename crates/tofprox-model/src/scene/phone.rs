//! The scenes a phone meets: their ground truth over time (`PhoneScene`, `Expect`) and
//! the reflectivities they use.

use serde::Serialize;

use super::{CoverWindow, SceneScript};

/// Ground truth of a proximity reading at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Expect {
    /// At least half of the ROI sees something at or within the near threshold.
    Near,
    /// Every ROI pixel sees something at or beyond the far threshold (or nothing).
    Far,
    /// Between the thresholds, or partly covered: either answer is right.
    Either,
}

/// A named scene a phone meets, for the scene bench: script, light, cover window,
/// how long to run it, and the ground truth over time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhoneScene {
    /// Stable name (`[a-z0-9_]`), for listing and selecting scenes.
    pub name: &'static str,
    /// One line: what it is and why it is hard.
    pub description: &'static str,
    /// Object, wall and motion.
    pub script: SceneScript,
    /// Background light (sunlight ≈ 30–100 klux).
    pub ambient_klux: f64,
    /// The cover window in front of the sensor (clean unless the scene says smudged).
    pub cover_window: CoverWindow,
    /// The window the sensor's crosstalk was calibrated behind (clean): the typical one
    /// unless the scene says `strong`.
    pub calibrated_window: CoverWindow,
    /// How long to run the scene (one period of its motion).
    pub duration_s: f64,
}

/// Share of ROI pixels at or within the near threshold that makes "near" the truth.
pub const NEAR_TRUTH_SHARE: f64 = 0.5;

impl PhoneScene {
    /// The ground truth at `t_s` for a detector with thresholds `near_m` / `far_m` over
    /// the central `roi_fraction` of the field of view (each dimension; the daemon's
    /// default ROI is the central half): [`Expect::Near`] when at least
    /// [`NEAR_TRUTH_SHARE`] of the ROI sees something within `near_m`, [`Expect::Far`]
    /// when all of it sees `far_m` or more, [`Expect::Either`] otherwise. Ranges are the
    /// true radial distances: a wall beyond the unambiguous range is far.
    pub fn expect(&self, t_s: f64, near_m: f64, far_m: f64, roi_fraction: f64) -> Expect {
        Self::expect_from(
            &self.script.roi_distances_m(t_s, roi_fraction),
            near_m,
            far_m,
        )
    }

    /// [`Self::expect`] over an explicit ROI of the full array (`rows × cols`, e.g. the
    /// daemon's configured `proximity.roi`).
    pub fn expect_in(
        &self,
        t_s: f64,
        near_m: f64,
        far_m: f64,
        rows: std::ops::Range<usize>,
        cols: std::ops::Range<usize>,
    ) -> Expect {
        Self::expect_from(
            &self.script.window_distances_m(t_s, rows, cols),
            near_m,
            far_m,
        )
    }

    fn expect_from(d: &[f64], near_m: f64, far_m: f64) -> Expect {
        if d.is_empty() {
            return Expect::Either;
        }
        let near = d.iter().filter(|&&x| x <= near_m).count() as f64 / d.len() as f64;
        if near >= NEAR_TRUTH_SHARE {
            Expect::Near
        } else if d.iter().all(|&x| x >= far_m) {
            Expect::Far
        } else {
            Expect::Either
        }
    }
}

/// Reflectivities at 850–940 nm used by [`phone_scenes`](super::phone_scenes).
pub mod reflectivity {
    /// White wall or ceiling paint (the thesis's white wall, 5.1).
    pub const WHITE: f64 = 0.9;
    /// Dark wall (dark grey/black paint, wood).
    pub const DARK_WALL: f64 = 0.08;
    /// Skin (palm, face).
    pub const SKIN: f64 = 0.5;
    /// Black card (the usual "black" proximity test target).
    pub const BLACK_CARD: f64 = 0.05;
    /// 18 % grey card (the usual proximity test target).
    pub const GREY_CARD: f64 = 0.18;
    /// Dark (black) hair.
    pub const DARK_HAIR: f64 = 0.06;
    /// Dark pocket fabric (denim, lining).
    pub const DARK_FABRIC: f64 = 0.1;
    /// A dark pocket lining (black cotton or polyester: 2–5 % at 850–940 nm, our assumption
    /// for dyes that absorb in the near infrared).
    pub const DARK_LINING: f64 = 0.03;
    /// Light fabric (white or beige cotton: 40–60 %, our assumption).
    pub const LIGHT_FABRIC: f64 = 0.5;
    /// Wooden table top.
    pub const TABLE: f64 = 0.3;
    /// A safety vest (20–40× a white wall).
    pub const SAFETY_VEST: f64 = 30.0 * WHITE;
    /// Retroreflective tape at a phone's observation angle (illumination beside the lens):
    /// ~1000× a white wall.
    pub const RETROREFLECTIVE_TAPE: f64 = 1000.0 * WHITE;
}
