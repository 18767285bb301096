//! Scenes: a flat wall, a per-pixel depth/reflectivity map, and scripted scenes
//! over time: a hand, a face, a card, a plane filling the view (pocket fabric), a
//! table top seen at grazing incidence, with approach, sway, swipe or static
//! motion in front of a wall; [`phone_scenes`] names the scenes a phone meets,
//! each with its ground truth ("near expected?") over time.

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
pub const MAX_REFLECTIVITY: f64 = 2000.0;

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
            || (self.kind != ScriptKind::Wall && motion == Motion::Approach);
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

    /// Where the scripted object is at `t_s`, `None` when it is out of view (or there is none).
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

    /// The scene at time `t_s`: a full-array depth map, or a flat wall when nothing is in front.
    pub fn at(&self, t_s: f64) -> Scene {
        if self.kind != ScriptKind::TableEdge && self.object_pose(t_s).is_none() {
            return Scene::wall(self.wall_distance_m, self.wall_reflectivity);
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
pub const COVER_WINDOW_EFFECT: &str = crate::ids::cover_window_crosstalk::ID.as_str();

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

/// Reflectivities at 850–940 nm used by [`phone_scenes`].
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
    /// Wooden table top.
    pub const TABLE: f64 = 0.3;
    /// A safety vest (20–40× a white wall).
    pub const SAFETY_VEST: f64 = 30.0 * WHITE;
    /// Retroreflective tape at a phone's observation angle (illumination beside the lens):
    /// ~1000× a white wall.
    pub const RETROREFLECTIVE_TAPE: f64 = 1000.0 * WHITE;
}

/// The scenes a phone meets, with stable names, for near/far thresholds `near_m` /
/// `far_m` (the threshold scenes are placed relative to them; tofproxd's defaults are
/// 0.10 / 0.15 m). Every scene has the typical clean cover window unless its name
/// says `smudged` (crosstalk doubled); ambient light is 0 unless it says `klux`.
/// The catalogue is the table `PHONE_SCENES` (one row per scene).
pub fn phone_scenes(near_m: f64, far_m: f64) -> Vec<PhoneScene> {
    PHONE_SCENES
        .iter()
        .map(|row| row.scene(near_m, far_m))
        .collect()
}

/// What a catalogue scene puts in front of the phone ([`Setup::script`] builds its
/// [`SceneScript`]).
#[derive(Debug, Clone, Copy)]
enum Setup {
    /// Only a wall (or ceiling).
    Wall { distance_m: f64, reflectivity: f64 },
    /// A [`ScriptKind::Band`] at `distance_m` before a dark wall at 6 m.
    Band { distance_m: f64, reflectivity: f64 },
    /// An object coming from 0.6 m to `closest` before a mid-grey wall at 1.5 m; `motion`
    /// unset: the kind's own.
    Object {
        kind: ScriptKind,
        reflectivity: f64,
        closest: Closest,
        motion: Option<Motion>,
    },
    /// A skin face at `distance_m`, swaying ±1 cm.
    FaceAt { distance_m: f64 },
    /// Dark fabric over the whole view sliding down to 1 cm, the fabric behind at 0.5 m.
    Pocket,
    /// A table top 4 cm below the axis up to its edge at 0.3 m, a wall at 2 m beyond.
    TableEdge,
}

/// The closest approach of a catalogue object.
#[derive(Debug, Clone, Copy)]
enum Closest {
    /// A distance (m).
    M(f64),
    /// This multiple of the near threshold.
    NearThreshold(f64),
    /// This multiple of the far threshold.
    FarThreshold(f64),
}

/// The cover window of a catalogue scene and the one it was calibrated behind.
#[derive(Debug, Clone, Copy)]
enum Window {
    /// The typical window, clean, calibrated clean.
    Clean,
    /// The typical window smudged ×2 (crosstalk doubled), calibrated clean.
    Smudged,
    /// A strong window (13× the typical one: ≈ the return of a white target at 0.39 m),
    /// calibrated behind it clean.
    Strong,
    /// The strong window smudged ×2, calibrated behind it clean.
    StrongSmudged,
}

/// How long a catalogue scene runs.
#[derive(Debug, Clone, Copy)]
enum Span {
    /// One approach period ([`SceneScript::default`]'s `period_s`).
    Approach,
    /// A static scene: 4 s.
    Static,
    /// A band scene: 12 s, long enough for a false near to count after the far debounce
    /// at the slowest rate.
    Band,
    /// Seconds.
    Seconds(f64),
}

/// One row of the catalogue.
#[derive(Debug, Clone, Copy)]
struct SceneRow {
    name: &'static str,
    description: &'static str,
    setup: Setup,
    ambient_klux: f64,
    window: Window,
    span: Span,
}

impl SceneRow {
    /// The scene of this row for near/far thresholds `near_m` / `far_m`.
    fn scene(&self, near_m: f64, far_m: f64) -> PhoneScene {
        let clean = CoverWindow::default();
        let strong = CoverWindow {
            e_per_us: 13.0 * clean.e_per_us,
            ..clean
        };
        let (cover_window, calibrated_window) = match self.window {
            Window::Clean => (clean, clean),
            Window::Smudged => (CoverWindow::smudged(1.0), clean),
            Window::Strong => (strong, strong),
            Window::StrongSmudged => (
                CoverWindow {
                    smudge_rel: 1.0,
                    ..strong
                },
                strong,
            ),
        };
        let duration_s = match self.span {
            Span::Approach => SceneScript::default().period_s,
            Span::Static => 4.0,
            Span::Band => 12.0,
            Span::Seconds(s) => s,
        };
        PhoneScene {
            name: self.name,
            description: self.description,
            script: self.setup.script(near_m, far_m),
            ambient_klux: self.ambient_klux,
            cover_window,
            calibrated_window,
            duration_s,
        }
    }
}

impl Setup {
    /// The scene's script for near/far thresholds `near_m` / `far_m`.
    fn script(self, near_m: f64, far_m: f64) -> SceneScript {
        let base = SceneScript::default();
        let object = |kind, object_reflectivity, near_m| SceneScript {
            kind,
            object_reflectivity,
            near_m,
            far_m: 0.6,
            wall_distance_m: 1.5,
            wall_reflectivity: 0.5,
            ..base.clone()
        };
        match self {
            Setup::Wall {
                distance_m,
                reflectivity,
            } => SceneScript {
                wall_reflectivity: reflectivity,
                ..SceneScript::wall(distance_m)
            },
            Setup::Band {
                distance_m,
                reflectivity,
            } => SceneScript {
                kind: ScriptKind::Band,
                object_reflectivity: reflectivity,
                near_m: distance_m,
                far_m: distance_m + 0.5,
                wall_distance_m: 6.0,
                wall_reflectivity: reflectivity::DARK_WALL,
                ..base
            },
            Setup::Object {
                kind,
                reflectivity,
                closest,
                motion,
            } => {
                let closest_m = match closest {
                    Closest::M(d) => d,
                    Closest::NearThreshold(k) => k * near_m,
                    Closest::FarThreshold(k) => k * far_m,
                };
                SceneScript {
                    motion,
                    ..object(kind, reflectivity, closest_m)
                }
            }
            Setup::FaceAt { distance_m } => SceneScript {
                face_distance_m: distance_m,
                ..object(ScriptKind::Face, reflectivity::SKIN, 0.05)
            }
            .with_motion(Motion::Sway),
            Setup::Pocket => SceneScript {
                wall_reflectivity: reflectivity::DARK_FABRIC,
                wall_distance_m: 0.5,
                far_m: 0.3,
                ..object(ScriptKind::Plane, reflectivity::DARK_FABRIC, 0.01)
            },
            Setup::TableEdge => SceneScript {
                kind: ScriptKind::TableEdge,
                object_reflectivity: reflectivity::TABLE,
                near_m: 0.04,
                far_m: 0.3,
                wall_distance_m: 2.0,
                wall_reflectivity: 0.5,
                ..base
            },
        }
    }
}

/// A wall (or ceiling) row of the catalogue: no ambient light, the clean window, 4 s.
const fn wall_row(
    name: &'static str,
    description: &'static str,
    distance_m: f64,
    reflectivity: f64,
) -> SceneRow {
    SceneRow {
        name,
        description,
        setup: Setup::Wall {
            distance_m,
            reflectivity,
        },
        ambient_klux: 0.0,
        window: Window::Clean,
        span: Span::Static,
    }
}

/// An object row of the catalogue: no ambient light, the clean window, one approach period.
const fn object_row(
    name: &'static str,
    description: &'static str,
    kind: ScriptKind,
    reflectivity: f64,
    closest: Closest,
    motion: Option<Motion>,
) -> SceneRow {
    SceneRow {
        name,
        description,
        setup: Setup::Object {
            kind,
            reflectivity,
            closest,
            motion,
        },
        ambient_klux: 0.0,
        window: Window::Clean,
        span: Span::Approach,
    }
}

/// A hand approaching to 5 cm, the row's light and window: one approach period.
const fn hand_05cm(
    name: &'static str,
    description: &'static str,
    ambient_klux: f64,
    window: Window,
) -> SceneRow {
    SceneRow {
        ambient_klux,
        window,
        ..object_row(
            name,
            description,
            ScriptKind::Hand,
            reflectivity::SKIN,
            Closest::M(0.05),
            None,
        )
    }
}

/// The catalogue [`phone_scenes`] builds its scenes from, in its order.
const PHONE_SCENES: &[SceneRow] = {
    use Closest::*;
    use ScriptKind::*;
    use reflectivity::*;
    &[
        wall_row(
            "nothing_in_range",
            "nothing within 30 m (open space, sky): no return but the cover window's",
            30.0,
            0.2,
        ),
        wall_row(
            "ceiling_white_030cm",
            "white ceiling at 0.3 m (a low shelf)",
            0.3,
            WHITE,
        ),
        wall_row("ceiling_white_100cm", "white ceiling at 1 m", 1.0, WHITE),
        wall_row(
            "ceiling_white_195cm",
            "white ceiling at 1.95 m, just beyond the unambiguous range c/2f = 1.874 m: its phase wraps to ≈ 8 cm",
            1.95,
            WHITE,
        ),
        wall_row(
            "ceiling_white_250cm",
            "white ceiling at 2.5 m (wraps to ≈ 63 cm)",
            2.5,
            WHITE,
        ),
        wall_row(
            "wall_white_380cm",
            "white wall at 3.8 m, just beyond twice the range (wraps to ≈ 5 cm)",
            3.8,
            WHITE,
        ),
        wall_row(
            "wall_white_400cm",
            "white wall at 4 m (wraps to ≈ 25 cm, weak)",
            4.0,
            WHITE,
        ),
        SceneRow {
            setup: Setup::Band {
                distance_m: 1.90,
                reflectivity: RETROREFLECTIVE_TAPE,
            },
            span: Span::Band,
            ..wall_row(
                "retroreflector_tape_190cm",
                "retroreflective tape (1000× a white wall) over a third of the ROI at 1.90 m, just beyond the unambiguous range: wraps to ≈ 3 cm as bright as a hand, saturates at the second frequency at the start exposure",
                0.0,
                0.0,
            )
        },
        SceneRow {
            setup: Setup::Band {
                distance_m: 1.95,
                reflectivity: RETROREFLECTIVE_TAPE,
            },
            span: Span::Band,
            ..wall_row(
                "retroreflector_tape_195cm",
                "retroreflective tape (1000×) over a third of the ROI at 1.95 m (wraps to ≈ 8 cm)",
                0.0,
                0.0,
            )
        },
        SceneRow {
            setup: Setup::Band {
                distance_m: 3.80,
                reflectivity: RETROREFLECTIVE_TAPE,
            },
            span: Span::Band,
            ..wall_row(
                "retroreflector_tape_380cm",
                "retroreflective tape (1000×) over a third of the ROI at 3.8 m, just beyond twice the range (wraps to ≈ 5 cm)",
                0.0,
                0.0,
            )
        },
        SceneRow {
            setup: Setup::Band {
                distance_m: 1.92,
                reflectivity: SAFETY_VEST,
            },
            span: Span::Band,
            ..wall_row(
                "safety_vest_192cm",
                "a safety vest (30× a white wall) over a third of the ROI at 1.92 m (wraps to ≈ 5 cm)",
                0.0,
                0.0,
            )
        },
        SceneRow {
            setup: Setup::Band {
                distance_m: 3.80,
                reflectivity: SAFETY_VEST,
            },
            span: Span::Band,
            ..wall_row(
                "safety_vest_380cm",
                "a safety vest (30×) over a third of the ROI at 3.8 m",
                0.0,
                0.0,
            )
        },
        wall_row(
            "ceiling_dark_030cm",
            "dark ceiling at 0.3 m",
            0.3,
            DARK_WALL,
        ),
        wall_row("wall_dark_100cm", "dark wall at 1 m", 1.0, DARK_WALL),
        wall_row(
            "ceiling_dark_195cm",
            "dark ceiling at 1.95 m (wraps, weak: the window crosstalk dominates)",
            1.95,
            DARK_WALL,
        ),
        wall_row(
            "wall_dark_400cm",
            "dark wall at 4 m (weaker than the window crosstalk)",
            4.0,
            DARK_WALL,
        ),
        hand_05cm(
            "hand_approach_05cm",
            "a hand approaching to 5 cm and leaving",
            0.0,
            Window::Clean,
        ),
        object_row(
            "hand_approach_03cm_saturating",
            "a hand approaching to 3 cm: the ROI saturates",
            Hand,
            SKIN,
            M(0.03),
            None,
        ),
        object_row(
            "face_dark_hair_02cm",
            "a head with dark hair (6 %) approaching to 2 cm (a call, hair against the sensor)",
            Face,
            DARK_HAIR,
            M(0.02),
            Some(Motion::Approach),
        ),
        object_row(
            "face_dark_hair_05cm",
            "a head with dark hair (6 %) approaching to 5 cm",
            Face,
            DARK_HAIR,
            M(0.05),
            Some(Motion::Approach),
        ),
        SceneRow {
            setup: Setup::FaceAt { distance_m: 0.2 },
            span: Span::Static,
            ..wall_row(
                "face_20cm",
                "a face at 20 cm, swaying ±1 cm (reading the screen up close): far",
                0.0,
                0.0,
            )
        },
        SceneRow {
            setup: Setup::FaceAt { distance_m: 0.3 },
            span: Span::Static,
            ..wall_row(
                "face_30cm",
                "a face at 30 cm, swaying ±1 cm (reading the screen): far",
                0.0,
                0.0,
            )
        },
        object_row(
            "black_card_02cm",
            "a black card (5 %) approaching to 2 cm",
            Card,
            BLACK_CARD,
            M(0.02),
            None,
        ),
        object_row(
            "black_card_05cm",
            "a black card (5 %) approaching to 5 cm",
            Card,
            BLACK_CARD,
            M(0.05),
            None,
        ),
        SceneRow {
            span: Span::Seconds(10.0),
            ..object_row(
                "cheek_pressed_10s",
                "a cheek pressed on the window for 10 s (a call): every code saturates even at the shortest exposure",
                Plane,
                SKIN,
                M(MIN_DISTANCE_M),
                Some(Motion::Static),
            )
        },
        object_row(
            "finger_third_of_field_04cm",
            "a finger approaching to 4 cm upright across the axis: it covers a third of the field's width (two thirds of the ROI)",
            Finger,
            SKIN,
            M(0.04),
            None,
        ),
        object_row(
            "grey_card_near_threshold",
            "an 18 % grey card approaching to 0.9 × the near threshold: switches to near",
            Card,
            GREY_CARD,
            NearThreshold(0.9),
            None,
        ),
        SceneRow {
            span: Span::Static,
            ..object_row(
                "grey_card_beyond_far",
                "an 18 % grey card held at 1.2 × the far threshold: stays far",
                Card,
                GREY_CARD,
                FarThreshold(1.2),
                Some(Motion::Static),
            )
        },
        SceneRow {
            setup: Setup::Pocket,
            ..hand_05cm(
                "pocket",
                "sliding into a pocket: dark fabric (10 %) over the whole view down to 1 cm, everything dark",
                0.0,
                Window::Clean,
            )
        },
        SceneRow {
            setup: Setup::TableEdge,
            ..wall_row(
                "table_edge",
                "standing in a stand at a table's edge: the table top 4 cm below the axis at grazing incidence (≥ 18 cm in the ROI) up to its edge at 0.3 m, a wall at 2 m beyond",
                0.0,
                0.0,
            )
        },
        SceneRow {
            span: Span::Static,
            ..object_row(
                "swipe_fast",
                "a hand swiping across the view at 5 cm with 1.5 m/s (≈ 0.1 s in view)",
                Hand,
                SKIN,
                M(0.05),
                Some(Motion::Swipe),
            )
        },
        SceneRow {
            ambient_klux: 30.0,
            ..wall_row(
                "sunlight_far_30klux",
                "30 klux of sunlight on a far scene (grass/ground at 1.2 m)",
                1.2,
                0.3,
            )
        },
        SceneRow {
            ambient_klux: 100.0,
            ..wall_row(
                "sunlight_far_100klux",
                "100 klux of direct sunlight on a far scene (ground at 1.2 m)",
                1.2,
                0.3,
            )
        },
        hand_05cm(
            "sunlight_hand_30klux",
            "a hand approaching to 5 cm in 30 klux",
            30.0,
            Window::Clean,
        ),
        hand_05cm(
            "sunlight_hand_100klux",
            "a hand approaching to 5 cm in 100 klux of direct sunlight",
            100.0,
            Window::Clean,
        ),
        SceneRow {
            window: Window::Smudged,
            ..wall_row(
                "window_smudged_nothing_in_range",
                "smudged cover window (crosstalk doubled after calibration), nothing in range",
                30.0,
                0.2,
            )
        },
        SceneRow {
            window: Window::Smudged,
            ..wall_row(
                "window_smudged_ceiling_195cm",
                "smudged cover window, white ceiling at 1.95 m",
                1.95,
                WHITE,
            )
        },
        hand_05cm(
            "window_smudged_hand_approach_05cm",
            "smudged cover window, a hand approaching to 5 cm",
            0.0,
            Window::Smudged,
        ),
        hand_05cm(
            "window_strong_hand_approach_05cm",
            "a strong cover window (13× typical) calibrated behind it, a hand approaching to 5 cm",
            0.0,
            Window::Strong,
        ),
        SceneRow {
            window: Window::StrongSmudged,
            ..object_row(
                "window_strong_smudged_dark_hair_05cm",
                "the strong window (13× typical, calibrated clean) smudged ×2, a head with dark hair (6 %) approaching to 5 cm and leaving",
                Face,
                DARK_HAIR,
                M(0.05),
                Some(Motion::Approach),
            )
        },
        SceneRow {
            window: Window::Smudged,
            ..object_row(
                "window_smudged_black_card_05cm",
                "smudged cover window, a black card approaching to 5 cm",
                Card,
                BLACK_CARD,
                M(0.05),
                None,
            )
        },
    ]
};

impl SceneScript {
    /// This script with another motion.
    pub fn with_motion(self, motion: Motion) -> Self {
        SceneScript {
            motion: Some(motion),
            ..self
        }
    }
}
