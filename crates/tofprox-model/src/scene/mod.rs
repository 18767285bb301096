//! Scenes: a flat wall, a per-pixel depth/reflectivity map, a surface pressed on the cover
//! window, and scripted scenes over time (`script`): a hand, a face, a card, a plane filling
//! the view (pocket fabric, pressed on the window or not), a table top seen at grazing
//! incidence, with approach, press, sway, swipe or static motion in front of a wall;
//! [`phone_scenes`] names the scenes a phone meets (`catalogue`), each with its ground truth
//! ("near expected?") over time (`phone`); [`CoverWindow`] the window they sit behind.

use ndarray::Array2;

use crate::error::ModelError;

mod catalogue;
mod cover_window;
mod phone;
mod script;

pub use catalogue::phone_scenes;
pub use cover_window::{COVER_WINDOW_EFFECT, CoverWindow};
pub use phone::{Expect, NEAR_TRUTH_SHARE, PhoneScene, reflectivity};
pub use script::{Motion, ObjectPose, SceneScript, ScriptKind};

/// What the sensor looks at during one capture.
#[derive(Debug, Clone, PartialEq)]
pub enum Scene {
    /// A flat wall facing the camera. Without a `[camera]` in the model every pixel sees the
    /// radial distance `distance_m` (no lens geometry); with one, `distance_m` is the wall's
    /// perpendicular distance and each pixel sees it along its ray, `distance_m / cos θ`.
    FlatWall {
        /// Distance in metres (radial without a lens, perpendicular with one).
        distance_m: f64,
        /// Diffuse reflectivity (1 = white wall).
        reflectivity: f64,
    },
    /// Per-pixel radial distance (along each pixel's ray, with or without a lens) and
    /// reflectivity, shaped like the window or like
    /// the full array (then the window is cut out at `roi_origin`).
    DepthMap {
        /// Radial distance per pixel in metres.
        distance_m: Array2<f64>,
        /// Reflectivity per pixel.
        reflectivity: Array2<f64>,
    },
    /// A diffuse (Lambertian) surface pressed on the cover window's outer face over the whole
    /// view: pocket fabric. Nothing beyond it is seen; its light returns by the window's own
    /// path, at the window's phase, added to the window's crosstalk (the contact law of
    /// `cover_window_crosstalk`, [`crate::effects::cover_window_crosstalk::on_glass_return_rel`]).
    /// Without that effect enabled it returns nothing.
    OnWindow {
        /// Diffuse reflectivity of the surface (0–1).
        reflectivity: f64,
    },
}

/// Smallest distance the model accepts (the optics are meaningless closer).
pub const MIN_DISTANCE_M: f64 = 0.005;
/// Largest distance the model accepts.
pub const MAX_DISTANCE_M: f64 = 1000.0;
/// Largest reflectivity (retro-reflectors exceed 1).
pub const MAX_REFLECTIVITY: f64 = 2000.0;

pub(super) fn check_value(what: &str, d: f64, r: f64) -> Result<(), ModelError> {
    if !(d.is_finite() && (MIN_DISTANCE_M..=MAX_DISTANCE_M).contains(&d)) {
        return Err(ModelError::invalid(format!(
            "scene: {what}distance_m = {d} outside the allowed range [{MIN_DISTANCE_M}, {MAX_DISTANCE_M}] m"
        )));
    }
    if !(r.is_finite() && (0.0..=MAX_REFLECTIVITY).contains(&r)) {
        return Err(ModelError::invalid(format!(
            "scene: {what}reflectivity = {r} outside the allowed range [0, {MAX_REFLECTIVITY}]"
        )));
    }
    Ok(())
}

impl Scene {
    /// A flat wall.
    pub fn wall(distance_m: f64, reflectivity: f64) -> Self {
        Scene::FlatWall {
            distance_m,
            reflectivity,
        }
    }

    /// Check all values are physical.
    pub fn validate(&self) -> Result<(), ModelError> {
        match self {
            Scene::FlatWall {
                distance_m,
                reflectivity,
            } => check_value("", *distance_m, *reflectivity),
            Scene::DepthMap {
                distance_m,
                reflectivity,
            } => {
                if distance_m.dim() != reflectivity.dim() {
                    return Err(ModelError::invalid(format!(
                        "scene: distance map {:?} and reflectivity map {:?} differ in shape",
                        distance_m.dim(),
                        reflectivity.dim()
                    )));
                }
                for ((idx, &d), &r) in distance_m.indexed_iter().zip(reflectivity.iter()) {
                    check_value(&format!("pixel {idx:?} "), d, r)?;
                }
                Ok(())
            }
            Scene::OnWindow { reflectivity } => {
                if !(reflectivity.is_finite() && (0.0..=1.0).contains(reflectivity)) {
                    return Err(ModelError::invalid(format!(
                        "scene: reflectivity = {reflectivity} of the surface on the window outside [0, 1] (a diffuse surface)"
                    )));
                }
                Ok(())
            }
        }
    }

    /// The reflectivity of the surface pressed on the cover window, `None` when there is none.
    pub fn on_window_reflectivity(&self) -> Option<f64> {
        match self {
            Scene::OnWindow { reflectivity } => Some(*reflectivity),
            Scene::FlatWall { .. } | Scene::DepthMap { .. } => None,
        }
    }
}
