//! Scripted scenes over time: the object (hand, face, card, finger, a plane filling the
//! view, a table edge, a band), how it moves, and the scene it makes at an instant.

use ndarray::Array2;
use serde::{Deserialize, Serialize};

use super::{MAX_DISTANCE_M, MIN_DISTANCE_M, Scene, check_value};
use crate::error::ModelError;

/// Which scripted scene (the object in front of the wall; [`Motion`] says how it moves).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ScriptKind {
    /// A static wall (or ceiling) only.
    Wall,
    /// A hand (disc of 4.5 cm radius); by default approaching to `near_m` and leaving again.
    Hand,
    /// A face/head-sized ellipse (15 × 22 cm); by default at `face_distance_m` with a slight sway.
    Face,
    /// A flat card (20 × 25 cm, e.g. an 18 % grey or a black card); by default approaching like the hand.
    Card,
    /// A finger (1.6 cm wide, 10 cm long, upright across the optical axis); by default
    /// approaching like the hand.
    Finger,
    /// A surface filling the whole field of view (pocket fabric, a table the phone lies
    /// face down on); by default approaching like the hand.
    Plane,
    /// A table top `near_m` below the optical axis, seen at grazing incidence up to its
    /// edge at `far_m` (horizontal distance); the wall beyond. Static.
    TableEdge,
    /// A vertical band at `near_m` over every row, covering the left third of the central
    /// half of the field of view (a third of the daemon's default ROI): a safety vest or a
    /// retroreflective sign seen past the phone. Static.
    Band,
}

/// How the object of a [`SceneScript`] moves (one cycle per `period_s`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Motion {
    /// At its distance all the time (`face_distance_m` for a face, else `near_m`).
    Static,
    /// Absent for 15 % of the period, approaches from `far_m` to `near_m` (30 %), stays
    /// (15 %), leaves to `far_m` (25 %), absent again (15 %); smooth (cosine) ramps.
    Approach,
    /// ±1 cm sinusoidal sway around its distance.
    Sway,
    /// Crosses the field of view sideways at `near_m` with `swipe_m_per_s`, once per
    /// period, starting at 20 % of it.
    Swipe,
    /// Into a pocket and out again (a [`ScriptKind::Plane`] only): absent for 10 % of the
    /// period, approaches from `far_m` to `near_m` (20 %), pressed on the cover window
    /// (distance 0, [`Scene::OnWindow`]: 45 %), lifted to `near_m` and gone to `far_m`
    /// (15 %), absent again (10 %); smooth (cosine) ramps.
    Press,
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
    /// How the object moves; unset: the kind's own (hand, card, plane: approach;
    /// face: sway; wall, table edge: static).
    pub motion: Option<Motion>,
    /// Lateral speed of a swipe (a fast hand swipe is 1–2 m/s).
    pub swipe_m_per_s: f64,
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
            motion: None,
            swipe_m_per_s: 1.5,
        }
    }
}

/// Half width of a palm.
const HAND_RADIUS_M: f64 = 0.045;
/// Half axes of a face (width, height).
const FACE_HALF_AXES_M: (f64, f64) = (0.075, 0.11);
/// Half axes of a card (20 × 25 cm test card).
const CARD_HALF_AXES_M: (f64, f64) = (0.10, 0.125);
/// Half axes of a finger (1.6 cm wide, 10 cm long).
const FINGER_HALF_AXES_M: (f64, f64) = (0.008, 0.05);

/// Where the scripted object is at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectPose {
    /// Distance along the optical axis, m.
    pub distance_m: f64,
    /// Lateral offset of its centre from the optical axis (columns direction), m.
    pub lateral_m: f64,
}

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
        let motion = self.motion();
        let uses_near_far = matches!(self.kind, ScriptKind::TableEdge)
            || (self.kind != ScriptKind::Wall
                && matches!(motion, Motion::Approach | Motion::Press));
        if uses_near_far && (self.near_m >= self.far_m || self.far_m >= self.wall_distance_m) {
            return Err(ModelError::invalid(format!(
                "scene script: need near_m < far_m < wall_distance_m, got {} / {} / {}",
                self.near_m, self.far_m, self.wall_distance_m
            )));
        }
        if self.kind != ScriptKind::Wall && self.object_base_m() >= self.wall_distance_m {
            return Err(ModelError::invalid(format!(
                "scene script: the object ({} m) must be in front of the wall ({} m)",
                self.object_base_m(),
                self.wall_distance_m
            )));
        }
        if motion == Motion::Press && self.kind != ScriptKind::Plane {
            return Err(ModelError::invalid(format!(
                "scene script: only a plane filling the view can be pressed on the window, not a {:?}",
                self.kind
            )));
        }
        if motion == Motion::Press && self.object_reflectivity > 1.0 {
            return Err(ModelError::invalid(format!(
                "scene script: object_reflectivity = {} of a surface pressed on the window outside [0, 1] (a diffuse surface)",
                self.object_reflectivity
            )));
        }
        if !(self.swipe_m_per_s.is_finite() && (0.01..=20.0).contains(&self.swipe_m_per_s)) {
            return Err(ModelError::invalid(format!(
                "scene script: swipe_m_per_s = {} outside the allowed range [0.01, 20] m/s",
                self.swipe_m_per_s
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

    /// The motion in effect (the configured one, else the kind's own).
    pub fn motion(&self) -> Motion {
        self.motion.unwrap_or(match self.kind {
            ScriptKind::Wall | ScriptKind::TableEdge | ScriptKind::Band => Motion::Static,
            ScriptKind::Face => Motion::Sway,
            ScriptKind::Hand | ScriptKind::Card | ScriptKind::Finger | ScriptKind::Plane => {
                Motion::Approach
            }
        })
    }

    /// The object's resting distance: `face_distance_m` for a face, else `near_m`.
    fn object_base_m(&self) -> f64 {
        match self.kind {
            ScriptKind::Face => self.face_distance_m,
            _ => self.near_m,
        }
    }

    /// Half axes (columns, rows direction) of the object, m; `None` when it fills the view.
    fn half_axes_m(&self) -> Option<(f64, f64)> {
        match self.kind {
            ScriptKind::Face => Some(FACE_HALF_AXES_M),
            ScriptKind::Card => Some(CARD_HALF_AXES_M),
            ScriptKind::Finger => Some(FINGER_HALF_AXES_M),
            ScriptKind::Hand => Some((HAND_RADIUS_M, HAND_RADIUS_M)),
            ScriptKind::Wall | ScriptKind::Plane | ScriptKind::TableEdge | ScriptKind::Band => None,
        }
    }

    /// Pinhole focal length in pixels from the horizontal field of view.
    fn focal_px(&self) -> f64 {
        (self.full_cols.max(1) as f64 / 2.0) / (self.fov_deg.to_radians() / 2.0).tan().max(1e-6)
    }

    /// Where the scripted object is at `t_s`, `None` when it is out of view (or there is none);
    /// at distance 0 it is pressed on the cover window ([`Motion::Press`]).
    pub fn object_pose(&self, t_s: f64) -> Option<ObjectPose> {
        if matches!(self.kind, ScriptKind::Wall | ScriptKind::TableEdge) {
            return None;
        }
        let p = self.period_s.max(1e-3);
        let u = (t_s / p).rem_euclid(1.0);
        let base = self.object_base_m();
        let at = |distance_m: f64| {
            Some(ObjectPose {
                distance_m,
                lateral_m: 0.0,
            })
        };
        match self.motion() {
            Motion::Static => at(base),
            Motion::Sway => {
                at((base + 0.01 * (std::f64::consts::TAU * u).sin()).max(MIN_DISTANCE_M))
            }
            Motion::Approach => {
                let smooth = |x: f64| 0.5 - 0.5 * (std::f64::consts::PI * x.clamp(0.0, 1.0)).cos();
                let (near, far) = (self.near_m, self.far_m);
                match u {
                    u if u < 0.15 => None,
                    u if u < 0.45 => at(far + (near - far) * smooth((u - 0.15) / 0.30)),
                    u if u < 0.60 => at(near),
                    u if u < 0.85 => at(near + (far - near) * smooth((u - 0.60) / 0.25)),
                    _ => None,
                }
            }
            Motion::Press => {
                let smooth = |x: f64| 0.5 - 0.5 * (std::f64::consts::PI * x.clamp(0.0, 1.0)).cos();
                let (near, far) = (self.near_m, self.far_m);
                match u {
                    u if u < 0.10 => None,
                    u if u < 0.30 => at(far + (near - far) * smooth((u - 0.10) / 0.20)),
                    u if u < 0.75 => at(0.0),
                    u if u < 0.90 => at(near + (far - near) * smooth((u - 0.75) / 0.15)),
                    _ => None,
                }
            }
            Motion::Swipe => {
                // enters at the left edge of the field at 20 % of the period
                let half_field = base * self.fov_half_tan();
                let half_obj = self.half_axes_m().map_or(half_field, |a| a.0);
                let span = half_field + half_obj;
                let x = -span + self.swipe_m_per_s * (t_s.rem_euclid(p) - 0.2 * p);
                (x.abs() < span).then_some(ObjectPose {
                    distance_m: base,
                    lateral_m: x,
                })
            }
        }
    }

    fn fov_half_tan(&self) -> f64 {
        (self.fov_deg.to_radians() / 2.0).tan()
    }

    /// Distance of the scripted object at time `t_s`, `None` when only the wall is seen.
    pub fn object_distance_m(&self, t_s: f64) -> Option<f64> {
        self.object_pose(t_s).map(|o| o.distance_m)
    }

    /// Radial distances seen by the pixels of the central `roi_fraction` of the field
    /// of view (each dimension) at `t_s`.
    pub fn roi_distances_m(&self, t_s: f64, roi_fraction: f64) -> Vec<f64> {
        let (rows, cols) = (self.full_rows.max(1), self.full_cols.max(1));
        let f = roi_fraction.clamp(0.0, 1.0);
        let (r0, r1) = (
            ((1.0 - f) / 2.0 * rows as f64) as usize,
            ((1.0 + f) / 2.0 * rows as f64).ceil() as usize,
        );
        let (c0, c1) = (
            ((1.0 - f) / 2.0 * cols as f64) as usize,
            ((1.0 + f) / 2.0 * cols as f64).ceil() as usize,
        );
        self.window_distances_m(t_s, r0..r1, c0..c1)
    }

    /// Radial distances seen by the full-array pixels `rows × cols` at `t_s` (ranges are
    /// clipped to the array).
    pub fn window_distances_m(
        &self,
        t_s: f64,
        rows: std::ops::Range<usize>,
        cols: std::ops::Range<usize>,
    ) -> Vec<f64> {
        let (n_rows, n_cols) = (self.full_rows.max(1), self.full_cols.max(1));
        let pose = self.object_pose(t_s);
        let mut out = Vec::new();
        for r in rows.start..rows.end.min(n_rows) {
            for c in cols.start.min(n_cols)..cols.end.min(n_cols) {
                out.push(self.pixel_at(pose, r, c).0);
            }
        }
        out
    }

    /// Distance seen by the centre pixel at `t_s` (object if present there, else the wall).
    pub fn centre_distance_m(&self, t_s: f64) -> f64 {
        let (rows, cols) = (self.full_rows.max(1), self.full_cols.max(1));
        self.pixel(t_s, rows / 2, cols / 2).0
    }

    /// What full-array pixel `(r, c)` sees at `t_s`: radial distance, effective
    /// reflectivity, and whether that is the object (not the wall).
    fn pixel(&self, t_s: f64, r: usize, c: usize) -> (f64, f64, bool) {
        self.pixel_at(self.object_pose(t_s), r, c)
    }

    /// [`Self::pixel`] with the object's pose already known.
    fn pixel_at(&self, pose: Option<ObjectPose>, r: usize, c: usize) -> (f64, f64, bool) {
        let wall = (self.wall_distance_m, self.wall_reflectivity, false);
        let (rows, cols) = (self.full_rows.max(1), self.full_cols.max(1));
        let f_px = self.focal_px();
        let (cr, cc) = ((rows as f64 - 1.0) / 2.0, (cols as f64 - 1.0) / 2.0);
        let (y, x) = ((r as f64 - cr) / f_px, (c as f64 - cc) / f_px);
        if self.kind == ScriptKind::TableEdge {
            // the table top lies near_m below the axis (rows below the centre look down):
            // the ray (x, y, 1) meets it at depth z = h / y; radial range z·√(1+x²+y²).
            // A Lambertian surface returns ρ cos θ_i / d² (2.2.1), cos θ_i = y / √(1+x²+y²).
            if y <= 0.0 {
                return wall;
            }
            let z = self.near_m / y;
            if z > self.far_m {
                return wall;
            }
            let norm = (1.0 + x * x + y * y).sqrt();
            return (z * norm, self.object_reflectivity * y / norm, true);
        }
        let Some(pose) = pose else {
            return wall;
        };
        let z = pose.distance_m;
        // the band: x from the left edge of the central half of the view, a third of it wide
        let half_roi = self.fov_half_tan() / 2.0;
        let inside = match self.half_axes_m() {
            None if self.kind == ScriptKind::Band => (-half_roi..=-half_roi / 3.0).contains(&x),
            None => true,
            Some((half_w, half_h)) => {
                let (dx, dy) = ((x * z - pose.lateral_m) / half_w, y * z / half_h);
                dx * dx + dy * dy <= 1.0
            }
        };
        if inside {
            (z, self.object_reflectivity, true)
        } else {
            wall
        }
    }

    /// The scene at time `t_s`: a full-array depth map, a flat wall when nothing is in front,
    /// or the surface pressed on the cover window.
    pub fn at(&self, t_s: f64) -> Scene {
        match self.object_pose(t_s) {
            None if self.kind != ScriptKind::TableEdge => {
                return Scene::wall(self.wall_distance_m, self.wall_reflectivity);
            }
            Some(p) if p.distance_m <= 0.0 => {
                return Scene::OnWindow {
                    reflectivity: self.object_reflectivity,
                };
            }
            _ => {}
        }
        let (rows, cols) = (self.full_rows.max(1), self.full_cols.max(1));
        let mut distance_m = Array2::from_elem((rows, cols), self.wall_distance_m);
        let mut reflectivity = Array2::from_elem((rows, cols), self.wall_reflectivity);
        let pose = self.object_pose(t_s);
        for ((r, c), d) in distance_m.indexed_iter_mut() {
            let (dist, refl, _) = self.pixel_at(pose, r, c);
            *d = dist.clamp(MIN_DISTANCE_M, MAX_DISTANCE_M);
            if let Some(v) = reflectivity.get_mut((r, c)) {
                *v = refl;
            }
        }
        Scene::DepthMap {
            distance_m,
            reflectivity,
        }
    }
}

impl SceneScript {
    /// This script with another motion.
    pub fn with_motion(self, motion: Motion) -> Self {
        SceneScript {
            motion: Some(motion),
            ..self
        }
    }
}
