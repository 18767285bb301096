//! Scenes: a flat wall, a per-pixel depth/reflectivity map, and scripted scenes
//! over time (a hand approaching and leaving in front of a wall, a face).

use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::error::ModelError;

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
}

/// Smallest distance the model accepts (the optics are meaningless closer).
pub const MIN_DISTANCE_M: f64 = 0.005;
/// Largest distance the model accepts.
pub const MAX_DISTANCE_M: f64 = 1000.0;
/// Largest reflectivity (retro-reflectors exceed 1).
pub const MAX_REFLECTIVITY: f64 = 10.0;

fn check_value(what: &str, d: f64, r: f64) -> Result<(), ModelError> {
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
        }
    }
}

/// Which scripted scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ScriptKind {
    /// A static wall.
    Wall,
    /// A hand approaching to `near_m` and leaving again in front of the wall, looping.
    Hand,
    /// A face-sized object at `face_distance_m` in front of the wall (slight sway).
    Face,
}

/// A scene scripted over time, for the emulated sensor and `tofprox sim scene`.
/// Serde-configurable (embed it as a table in device/daemon configs):
/// ```toml
/// kind = "hand"
/// wall_distance_m = 1.0
/// near_m = 0.05
/// period_s = 8.0
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneScript {
    /// Scene kind.
    pub kind: ScriptKind,
    /// Distance of the background wall.
    pub wall_distance_m: f64,
    /// Reflectivity of the wall.
    pub wall_reflectivity: f64,
    /// Reflectivity of the hand or face (skin at 850-940 nm ≈ 0.5).
    pub object_reflectivity: f64,
    /// Closest approach of the hand.
    pub near_m: f64,
    /// Where the hand appears and disappears.
    pub far_m: f64,
    /// Distance of the face.
    pub face_distance_m: f64,
    /// Loop period of the hand motion (≤ 20 s) and face sway.
    pub period_s: f64,
    /// Horizontal field of view of the lens (sets the objects' size in pixels).
    pub fov_deg: f64,
    /// Rows of the full array the maps are generated for.
    pub full_rows: usize,
    /// Columns of the full array.
    pub full_cols: usize,
}

impl Default for SceneScript {
    fn default() -> Self {
        Self {
            kind: ScriptKind::Hand,
            wall_distance_m: 1.0,
            wall_reflectivity: 0.8,
            object_reflectivity: 0.5,
            near_m: 0.05,
            far_m: 0.6,
            face_distance_m: 0.2,
            period_s: 8.0,
            fov_deg: 60.0,
            full_rows: 172,
            full_cols: 224,
        }
    }
}

/// Half width of a palm.
const HAND_RADIUS_M: f64 = 0.045;
/// Half axes of a face (width, height).
const FACE_HALF_AXES_M: (f64, f64) = (0.075, 0.11);

impl SceneScript {
    /// The default hand script.
    pub fn hand() -> Self {
        Self::default()
    }
    /// A face at 20 cm.
    pub fn face() -> Self {
        Self {
            kind: ScriptKind::Face,
            ..Self::default()
        }
    }
    /// A static wall.
    pub fn wall(distance_m: f64) -> Self {
        Self {
            kind: ScriptKind::Wall,
            wall_distance_m: distance_m,
            ..Self::default()
        }
    }

    /// Check ranges (period ≤ 20 s, distances ordered).
    pub fn validate(&self) -> Result<(), ModelError> {
        check_value("wall ", self.wall_distance_m, self.wall_reflectivity)?;
        check_value("object ", self.near_m, self.object_reflectivity)?;
        check_value("far ", self.far_m, self.object_reflectivity)?;
        check_value("face ", self.face_distance_m, self.object_reflectivity)?;
        if self.near_m >= self.far_m || self.far_m >= self.wall_distance_m {
            return Err(ModelError::invalid(format!(
                "scene script: need near_m < far_m < wall_distance_m, got {} / {} / {}",
                self.near_m, self.far_m, self.wall_distance_m
            )));
        }
        if self.kind == ScriptKind::Face && self.face_distance_m >= self.wall_distance_m {
            return Err(ModelError::invalid(
                "scene script: face_distance_m must be in front of the wall",
            ));
        }
        if !(self.period_s.is_finite() && (0.1..=20.0).contains(&self.period_s)) {
            return Err(ModelError::invalid(format!(
                "scene script: period_s = {} outside the allowed range [0.1, 20] s",
                self.period_s
            )));
        }
        if !(self.fov_deg.is_finite() && (5.0..=170.0).contains(&self.fov_deg)) {
            return Err(ModelError::invalid(format!(
                "scene script: fov_deg = {} outside the allowed range [5, 170] deg",
                self.fov_deg
            )));
        }
        if !(1..=8192).contains(&self.full_rows) || !(1..=8192).contains(&self.full_cols) {
            return Err(ModelError::invalid(
                "scene script: full array size outside [1, 8192]",
            ));
        }
        Ok(())
    }

    /// Distance of the scripted object (hand/face) at time `t_s`, `None` when only the wall is seen.
    pub fn object_distance_m(&self, t_s: f64) -> Option<f64> {
        let p = self.period_s.max(1e-3);
        let u = (t_s / p).rem_euclid(1.0);
        match self.kind {
            ScriptKind::Wall => None,
            ScriptKind::Face => {
                Some(self.face_distance_m + 0.01 * (std::f64::consts::TAU * u).sin())
            }
            ScriptKind::Hand => {
                let smooth = |x: f64| 0.5 - 0.5 * (std::f64::consts::PI * x.clamp(0.0, 1.0)).cos();
                let (near, far) = (self.near_m, self.far_m);
                match u {
                    u if u < 0.15 => None,
                    u if u < 0.45 => Some(far + (near - far) * smooth((u - 0.15) / 0.30)),
                    u if u < 0.60 => Some(near),
                    u if u < 0.85 => Some(near + (far - near) * smooth((u - 0.60) / 0.25)),
                    _ => None,
                }
            }
        }
    }

    /// Distance seen by the centre pixel at `t_s` (object if present, else the wall).
    pub fn centre_distance_m(&self, t_s: f64) -> f64 {
        self.object_distance_m(t_s).unwrap_or(self.wall_distance_m)
    }

    /// The scene at time `t_s`: a full-array depth map, or a flat wall when nothing is in front.
    pub fn at(&self, t_s: f64) -> Scene {
        let Some(z) = self.object_distance_m(t_s) else {
            return Scene::wall(self.wall_distance_m, self.wall_reflectivity);
        };
        let (rows, cols) = (self.full_rows.max(1), self.full_cols.max(1));
        // pinhole focal length in pixels from the horizontal field of view
        let f_px = (cols as f64 / 2.0) / (self.fov_deg.to_radians() / 2.0).tan().max(1e-6);
        let (half_w, half_h) = match self.kind {
            ScriptKind::Face => FACE_HALF_AXES_M,
            _ => (HAND_RADIUS_M, HAND_RADIUS_M),
        };
        let (rx, ry) = (f_px * half_w / z, f_px * half_h / z);
        let (cr, cc) = ((rows as f64 - 1.0) / 2.0, (cols as f64 - 1.0) / 2.0);
        let mut distance_m = Array2::from_elem((rows, cols), self.wall_distance_m);
        let mut reflectivity = Array2::from_elem((rows, cols), self.wall_reflectivity);
        for ((r, c), d) in distance_m.indexed_iter_mut() {
            let (dy, dx) = ((r as f64 - cr) / ry, (c as f64 - cc) / rx);
            if dx * dx + dy * dy <= 1.0 {
                *d = z;
                if let Some(v) = reflectivity.get_mut((r, c)) {
                    *v = self.object_reflectivity;
                }
            }
        }
        Scene::DepthMap {
            distance_m,
            reflectivity,
        }
    }
}
