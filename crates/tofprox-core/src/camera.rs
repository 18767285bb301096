//! The camera as it is built: a pinhole lens with Brown–Conrady distortion (thesis 5.1.3: "it is
//! necessary to apply FPPN compensation after lens-corrections").
//!
//! Every pixel of a ToF camera looks along its own ray. The phase measures the **radial** distance
//! along that ray (eq. 2.6: the light travels from the illumination to the surface point and back
//! to the pixel), so a flat wall at distance `d` in front of the camera is seen at `d / cos θ` by
//! a pixel whose ray makes the angle `θ` with the optical axis. This module turns pixels into rays
//! and radial distances into Z depth and points.
//!
//! # Conventions (those of OpenCV, so datasheet and OpenCV calibrations load unchanged)
//! * Camera frame: `X` right (increasing column), `Y` down (increasing row), `Z` along the optical
//!   axis, metres.
//! * Pixel coordinates `(u, v) = (column, row)` of the **full array** (not of a read-out window),
//!   the centre of pixel `(row 0, col 0)` at `(0, 0)`.
//! * Projection of a point `(X, Y, Z)`: normalised `x = X/Z`, `y = Y/Z`; `r² = x² + y²`;
//!   `x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²)`,
//!   `y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y`;
//!   `u = fx x_d + cx`, `v = fy y_d + cy`.
//! * Undistortion (pixel → ray) inverts the distortion by fixed-point iteration (as OpenCV's
//!   `undistortPoints`, with Newton's method as the fallback where that map does not contract) until `|distort(x, y) − (x_d, y_d)| <` [`UNDISTORT_TOLERANCE`] (normalised
//!   units: 1e-12 is ~1e-10 px for focal lengths of a few hundred pixels), at most
//!   [`UNDISTORT_MAX_ITERATIONS`] steps; a pixel whose distortion cannot be inverted (a lens model
//!   outside its valid field) is an error, never a silently wrong ray.

use crate::CoreError;
use ndarray::{Array2, Array3, ArrayView2};
use serde::{Deserialize, Serialize};

/// Convergence tolerance of the undistortion, in normalised image units (see the module docs).
pub const UNDISTORT_TOLERANCE: f64 = 1e-12;
/// Most fixed-point steps the undistortion takes before it reports the pixel as not invertible.
pub const UNDISTORT_MAX_ITERATIONS: usize = 200;

/// Brown–Conrady lens distortion, coefficients exactly as OpenCV defines them (radial `k1, k2,
/// k3`, tangential `p1, p2`; see the module docs). All zero: an ideal pinhole.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Distortion {
    /// Radial coefficient of `r²`.
    pub k1: f64,
    /// Radial coefficient of `r⁴`.
    pub k2: f64,
    /// Radial coefficient of `r⁶`.
    pub k3: f64,
    /// First tangential coefficient (decentring).
    pub p1: f64,
    /// Second tangential coefficient (decentring).
    pub p2: f64,
}

impl Distortion {
    /// The five coefficients in OpenCV's order `[k1, k2, p1, p2, k3]`.
    pub fn opencv_order(&self) -> [f64; 5] {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// Applies the distortion to normalised undistorted coordinates `(x, y)` → `(x_d, y_d)`.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// Jacobian `∂(x_d, y_d) / ∂(x, y)` of [`Distortion::distort`].
    fn jacobian(&self, x: f64, y: f64) -> [[f64; 2]; 2] {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        // d radial / d(r²)
        let dradial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let (p1, p2) = (self.p1, self.p2);
        [
            [
                radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x,
                2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y,
            ],
            [
                2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y,
                radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x,
            ],
        ]
    }

    /// A solution of the undistortion is the lens's only where the distortion still maps the
    /// plane one-to-one: positive radial factor and Jacobian determinant (inside the fold).
    fn on_invertible_branch(&self, x: f64, y: f64) -> Result<(f64, f64), CoreError> {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let [[a, b], [c, d]] = self.jacobian(x, y);
        if radial > 0.0 && a * d - b * c > 0.0 {
            Ok((x, y))
        } else {
            Err(CoreError::InvalidData(format!(
                "lens distortion {:?} folds over at normalised radius {:.4}: no unique ray",
                self.opencv_order(),
                r2.sqrt()
            )))
        }
    }

    /// Inverts [`Distortion::distort`] by fixed-point iteration `x ← (x_d − Δ_tangential(x)) /
    /// radial(x)` starting at `(x_d, y_d)`; converged when the forward residual is below
    /// [`UNDISTORT_TOLERANCE`]; when that map is not contracting (strong distortion far out),
    /// Newton's method on the analytic Jacobian takes over. Errors when neither converges (the
    /// point lies where the polynomial is not invertible) or the input is not finite.
    pub fn undistort(&self, xd: f64, yd: f64) -> Result<(f64, f64), CoreError> {
        if !(xd.is_finite() && yd.is_finite()) {
            return Err(CoreError::param(
                "normalised point",
                format!("must be finite, got ({xd}, {yd})"),
            ));
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            let (fx, fy) = self.distort(x, y);
            if (fx - xd).hypot(fy - yd) < UNDISTORT_TOLERANCE {
                return self.on_invertible_branch(x, y);
            }
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
            let dx = 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
            let dy = self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
            if !(radial.is_finite() && radial > 0.0) {
                break;
            }
            (x, y) = ((xd - dx) / radial, (yd - dy) / radial);
        }
        // Strong distortion can make the fixed-point map expansive; Newton's method on the
        // analytic Jacobian of `distort` converges wherever the distortion is locally invertible.
        let (mut x, mut y) = (xd, yd);
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex.hypot(ey) < UNDISTORT_TOLERANCE {
                return self.on_invertible_branch(x, y);
            }
            let [[a, b], [c, d]] = self.jacobian(x, y);
            let det = a * d - b * c;
            if !(det.is_finite() && det.abs() > 1e-12) {
                break;
            }
            (x, y) = (x - (d * ex - b * ey) / det, y - (a * ey - c * ex) / det);
        }
        Err(CoreError::InvalidData(format!(
            "lens distortion {:?} cannot be inverted at normalised point ({xd:.4}, {yd:.4}) \
             (fixed-point iteration did not converge to {UNDISTORT_TOLERANCE:e} in \
             {UNDISTORT_MAX_ITERATIONS} steps)",
            self.opencv_order()
        )))
    }
}

/// Pinhole intrinsics plus distortion, in **full-array** pixel coordinates (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Intrinsics {
    /// Focal length along columns, pixels.
    pub fx_px: f64,
    /// Focal length along rows, pixels.
    pub fy_px: f64,
    /// Principal point, column (full-array pixel coordinate).
    pub cx_px: f64,
    /// Principal point, row (full-array pixel coordinate).
    pub cy_px: f64,
    /// Lens distortion (all zero when omitted).
    #[serde(default)]
    pub distortion: Distortion,
}

impl Intrinsics {
    /// An ideal pinhole (no distortion, square pixels) centred on a `full_rows × full_cols` array
    /// whose horizontal field of view (edge to edge of the outer pixel centres ±½ px) is
    /// `hfov_deg`: `fx = fy = (cols / 2) / tan(hfov / 2)`, principal point at the array centre.
    pub fn pinhole_from_fov(
        full_rows: usize,
        full_cols: usize,
        hfov_deg: f64,
    ) -> Result<Self, CoreError> {
        if !(hfov_deg.is_finite() && hfov_deg > 0.0 && hfov_deg < 180.0) {
            return Err(CoreError::param(
                "hfov_deg",
                format!("must be in (0, 180), got {hfov_deg}"),
            ));
        }
        let f = (full_cols as f64 / 2.0) / (hfov_deg.to_radians() / 2.0).tan();
        let k = Intrinsics {
            fx_px: f,
            fy_px: f,
            cx_px: (full_cols as f64 - 1.0) / 2.0,
            cy_px: (full_rows as f64 - 1.0) / 2.0,
            distortion: Distortion::default(),
        };
        k.validate()?;
        Ok(k)
    }

    /// Checks every value is finite and the focal lengths are positive.
    pub fn validate(&self) -> Result<(), CoreError> {
        for (name, v) in [("fx_px", self.fx_px), ("fy_px", self.fy_px)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(CoreError::param(
                    name,
                    format!("must be finite and > 0, got {v}"),
                ));
            }
        }
        let d = &self.distortion;
        for (name, v) in [
            ("cx_px", self.cx_px),
            ("cy_px", self.cy_px),
            ("k1", d.k1),
            ("k2", d.k2),
            ("k3", d.k3),
            ("p1", d.p1),
            ("p2", d.p2),
        ] {
            if !v.is_finite() {
                return Err(CoreError::param(name, format!("must be finite, got {v}")));
            }
        }
        Ok(())
    }

    /// Projects a camera-frame point (metres, `Z > 0`) to full-array pixel coordinates
    /// `(u, v) = (column, row)`. `None` for points at or behind the camera plane.
    pub fn project(&self, point: [f64; 3]) -> Option<(f64, f64)> {
        let [x, y, z] = point;
        if !(z > 0.0 && x.is_finite() && y.is_finite() && z.is_finite()) {
            return None;
        }
        let (xd, yd) = self.distortion.distort(x / z, y / z);
        Some((self.fx_px * xd + self.cx_px, self.fy_px * yd + self.cy_px))
    }

    /// Normalised undistorted image coordinates `(x, y) = (X/Z, Y/Z)` of full-array pixel
    /// coordinates `(u, v)`.
    pub fn undistort_pixel(&self, u: f64, v: f64) -> Result<(f64, f64), CoreError> {
        self.distortion
            .undistort((u - self.cx_px) / self.fx_px, (v - self.cy_px) / self.fy_px)
    }

    /// Unit ray (camera frame) seen by full-array pixel coordinates `(u, v) = (column, row)`.
    pub fn ray(&self, u: f64, v: f64) -> Result<[f64; 3], CoreError> {
        let (x, y) = self.undistort_pixel(u, v)?;
        let n = (x * x + y * y + 1.0).sqrt();
        Ok([x / n, y / n, 1.0 / n])
    }

    /// The unit rays of a read-out window: `rows × cols` pixels whose first pixel is full-array
    /// `(row0, col0)`.
    pub fn rays(
        &self,
        row0: usize,
        col0: usize,
        rows: usize,
        cols: usize,
    ) -> Result<RayGrid, CoreError> {
        self.validate()?;
        let mut dirs = Array3::<f64>::zeros((rows, cols, 3));
        for r in 0..rows {
            for c in 0..cols {
                let d = self.ray((col0 + c) as f64, (row0 + r) as f64)?;
                for (i, v) in d.into_iter().enumerate() {
                    dirs[(r, c, i)] = v;
                }
            }
        }
        Ok(RayGrid { dirs })
    }
}

/// A plane `n · X = distance_m` in the camera frame (`n` a unit normal pointing away from the
/// camera, so `distance_m > 0` is the plane's perpendicular distance from the optical centre).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: [f64; 3],
    /// Perpendicular distance from the optical centre, metres.
    pub distance_m: f64,
}

impl Plane {
    /// A plane perpendicular to the optical axis at `distance_m` (a wall faced square on).
    pub fn fronto_parallel(distance_m: f64) -> Self {
        Plane {
            normal: [0.0, 0.0, 1.0],
            distance_m,
        }
    }

    /// Length along the unit ray `dir` from the optical centre to this plane: `d / (n · dir)`;
    /// `None` when the ray is parallel to or points away from the plane.
    pub fn ray_length_m(&self, dir: [f64; 3]) -> Option<f64> {
        let c = dot(self.normal, dir);
        let t = self.distance_m / c;
        (c > 1e-12 && t.is_finite() && t > 0.0).then_some(t)
    }

    /// Signed distance of a point from the plane (positive beyond it).
    pub fn signed_distance_m(&self, p: [f64; 3]) -> f64 {
        dot(self.normal, p) - self.distance_m
    }

    /// Least-squares plane through `points` (total least squares: the normal is the eigenvector
    /// of the smallest eigenvalue of the points' covariance) and the RMS of the perpendicular
    /// residuals. Errors with fewer than 3 finite points or when they are collinear.
    pub fn fit(points: &[[f64; 3]]) -> Result<(Plane, f64), CoreError> {
        let pts: Vec<[f64; 3]> = points
            .iter()
            .copied()
            .filter(|p| p.iter().all(|v| v.is_finite()))
            .collect();
        if pts.len() < 3 {
            return Err(CoreError::InvalidData(format!(
                "plane fit needs at least 3 finite points, got {}",
                pts.len()
            )));
        }
        let n = pts.len() as f64;
        let mut mean = [0.0; 3];
        for p in &pts {
            for i in 0..3 {
                mean[i] += p[i] / n;
            }
        }
        let mut cov = [[0.0; 3]; 3];
        for p in &pts {
            let d = [p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]];
            for i in 0..3 {
                for j in 0..3 {
                    cov[i][j] += d[i] * d[j] / n;
                }
            }
        }
        let (values, vectors) = symmetric_eigen3(cov);
        let order = {
            let mut o = [0usize, 1, 2];
            o.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
            o
        };
        if values[order[1]] <= 1e-18 * values[order[2]].max(1e-300) {
            return Err(CoreError::InvalidData(
                "plane fit: the points are collinear".into(),
            ));
        }
        let mut normal = [
            vectors[0][order[0]],
            vectors[1][order[0]],
            vectors[2][order[0]],
        ];
        let mut distance_m = dot(normal, mean);
        if distance_m < 0.0 {
            normal = normal.map(|v| -v);
            distance_m = -distance_m;
        }
        let plane = Plane { normal, distance_m };
        let rms = (pts
            .iter()
            .map(|p| plane.signed_distance_m(*p).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        Ok((plane, rms))
    }
}

/// The unit rays of a read-out window, `(rows, cols, 3)`, from [`Intrinsics::rays`].
#[derive(Debug, Clone, PartialEq)]
pub struct RayGrid {
    /// Unit direction per pixel, `(rows, cols, [x, y, z])`.
    pub dirs: Array3<f64>,
}

impl RayGrid {
    /// `(rows, cols)`.
    pub fn dim(&self) -> (usize, usize) {
        let (r, c, _) = self.dirs.dim();
        (r, c)
    }

    /// The unit ray of window pixel `(row, col)` (`None` outside the window).
    pub fn dir(&self, row: usize, col: usize) -> Option<[f64; 3]> {
        let (r, c) = self.dim();
        (row < r && col < c).then(|| {
            [
                self.dirs[(row, col, 0)],
                self.dirs[(row, col, 1)],
                self.dirs[(row, col, 2)],
            ]
        })
    }

    /// `cos θ` per pixel: the ray's component along the optical axis (`Z / radial`).
    pub fn cos_theta(&self) -> Array2<f64> {
        let (r, c) = self.dim();
        Array2::from_shape_fn((r, c), |(i, j)| self.dirs[(i, j, 2)])
    }

    /// Ray length from the optical centre to `plane` per pixel (radial distance a ToF pixel
    /// measures, eq. 2.6): `d / cos θ` for a fronto-parallel plane. NaN where the ray misses it.
    pub fn ray_lengths_m(&self, plane: &Plane) -> Array2<f64> {
        let (r, c) = self.dim();
        Array2::from_shape_fn((r, c), |(i, j)| {
            self.dir(i, j)
                .and_then(|d| plane.ray_length_m(d))
                .unwrap_or(f64::NAN)
        })
    }

    fn check_shape(&self, what: &'static str, got: (usize, usize)) -> Result<(), CoreError> {
        if got != self.dim() {
            return Err(CoreError::shape(
                what,
                format!("{:?}", self.dim()),
                format!("{got:?}"),
            ));
        }
        Ok(())
    }

    /// Z depth (distance along the optical axis) from radial distance: `Z = radial · cos θ`,
    /// written into `z_m` (same shape). A radial distance of 0 (the pipeline's "invalid") stays 0.
    pub fn radial_to_z_into(
        &self,
        radial_m: ArrayView2<f32>,
        z_m: &mut Array2<f32>,
    ) -> Result<(), CoreError> {
        self.check_shape("radial depth", radial_m.dim())?;
        self.check_shape("Z depth output", z_m.dim())?;
        for ((idx, z), &d) in z_m.indexed_iter_mut().zip(radial_m.iter()) {
            *z = (d as f64 * self.dirs[(idx.0, idx.1, 2)]) as f32;
        }
        Ok(())
    }

    /// Z depth from radial distance (allocating form of [`RayGrid::radial_to_z_into`]).
    pub fn radial_to_z(&self, radial_m: ArrayView2<f32>) -> Result<Array2<f32>, CoreError> {
        let mut z = Array2::zeros(radial_m.dim());
        self.radial_to_z_into(radial_m, &mut z)?;
        Ok(z)
    }

    /// Camera-frame points `radial · ray`, `(rows, cols, 3)` metres; pixels with radial 0 or a
    /// non-finite radial distance (the pipeline's "invalid") are `(0, 0, 0)`.
    pub fn points(&self, radial_m: ArrayView2<f32>) -> Result<Array3<f32>, CoreError> {
        self.check_shape("radial depth", radial_m.dim())?;
        let mut out = Array3::<f32>::zeros(self.dirs.dim());
        for ((r, c), &d) in radial_m.indexed_iter() {
            if d > 0.0 && d.is_finite() {
                for i in 0..3 {
                    out[(r, c, i)] = (d as f64 * self.dirs[(r, c, i)]) as f32;
                }
            }
        }
        Ok(out)
    }
}

/// Per-pixel **ray factor** `L = ∂radial / ∂d` from a sweep of a flat target perpendicular to
/// the optical axis at known distances `d_i` (the lens calibration's measurement: the wall is flat,
/// the rays are not). `sweep` holds `(d_i, phase_i)` with `phase_i` the measured phase per pixel
/// (NaN where invalid), all of one shape.
///
/// Per pixel, `radial_i = L · d_i + b` with `L = 1 / cos θ` (the ray's length per metre of
/// perpendicular distance) and `b` every distance-independent term (global and per-pixel delay,
/// thesis 2.3.1.4): the phases are unwrapped along the sorted sweep (consecutive targets must be
/// less than half the unambiguous range apart along every ray), converted with eq. 2.6 and fitted
/// by a straight line; the slope is `L`, the intercept is left to the per-pixel phase calibration.
/// Pixels with fewer than 3 valid captures are NaN. Errors on mismatched shapes, fewer than 3
/// captures, non-positive distances or fewer than 3 distinct distances.
pub fn ray_factors_from_sweep(
    sweep: &[(f64, ArrayView2<f64>)],
    modulation_hz: f64,
) -> Result<Array2<f64>, CoreError> {
    if !(modulation_hz.is_finite() && modulation_hz > 0.0) {
        return Err(CoreError::param(
            "modulation_hz",
            format!("must be finite and > 0, got {modulation_hz}"),
        ));
    }
    let Some((_, first)) = sweep.first() else {
        return Err(CoreError::InvalidData(
            "lens calibration: the sweep is empty".into(),
        ));
    };
    let dim = first.dim();
    let mut order: Vec<usize> = (0..sweep.len()).collect();
    for (d, phase) in sweep {
        if !(d.is_finite() && *d > 0.0) {
            return Err(CoreError::param(
                "distance_m",
                format!("sweep distances must be finite and > 0, got {d}"),
            ));
        }
        if phase.dim() != dim {
            return Err(CoreError::shape(
                "sweep phase image",
                format!("{dim:?}"),
                format!("{:?}", phase.dim()),
            ));
        }
    }
    order.sort_by(|&a, &b| sweep[a].0.total_cmp(&sweep[b].0));
    let distinct = order
        .windows(2)
        .filter(|w| sweep[w[1]].0 - sweep[w[0]].0 > 1e-6)
        .count()
        + 1;
    if distinct < 3 {
        return Err(CoreError::InvalidData(format!(
            "lens calibration needs a flat target at ≥ 3 distinct distances, got {distinct}"
        )));
    }
    let m_per_rad = crate::phasor::unambiguous_range_m(modulation_hz) / std::f64::consts::TAU;
    let mut out = Array2::<f64>::from_elem(dim, f64::NAN);
    let mut d = Vec::with_capacity(sweep.len());
    let mut radial = Vec::with_capacity(sweep.len());
    for ((r, c), o) in out.indexed_iter_mut() {
        d.clear();
        radial.clear();
        let mut prev: Option<f64> = None;
        for &i in &order {
            let (di, ph) = (sweep[i].0, sweep[i].1[(r, c)]);
            if !ph.is_finite() {
                continue;
            }
            let unwrapped = match prev {
                None => ph,
                Some(p) => p + crate::phasor::wrap_to_pi(ph - p),
            };
            prev = Some(unwrapped);
            d.push(di);
            radial.push(unwrapped * m_per_rad);
        }
        if d.len() >= 3 {
            let n = d.len() as f64;
            let (md, mr) = (d.iter().sum::<f64>() / n, radial.iter().sum::<f64>() / n);
            let sxx: f64 = d.iter().map(|x| (x - md).powi(2)).sum();
            let sxy: f64 = d
                .iter()
                .zip(&radial)
                .map(|(x, y)| (x - md) * (y - mr))
                .sum();
            if sxx > 0.0 {
                *o = sxy / sxx;
            }
        }
    }
    Ok(out)
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Eigen-decomposition of a symmetric 3×3 matrix by cyclic Jacobi rotations: eigenvalues and the
/// matrix whose **columns** are the eigenvectors.
fn symmetric_eigen3(mut a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..64 {
        let off = a[0][1].powi(2) + a[0][2].powi(2) + a[1][2].powi(2);
        let scale = a[0][0].powi(2) + a[1][1].powi(2) + a[2][2].powi(2);
        if off <= 1e-30 * scale.max(1e-300) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // A ← Jᵀ A J with the rotation J in the (p, q) plane.
            for row in a.iter_mut() {
                let (akp, akq) = (row[p], row[q]);
                row[p] = c * akp - s * akq;
                row[q] = s * akp + c * akq;
            }
            let (row_p, row_q) = (a[p], a[q]);
            for k in 0..3 {
                a[p][k] = c * row_p[k] - s * row_q[k];
                a[q][k] = s * row_p[k] + c * row_q[k];
            }
            for row in v.iter_mut() {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2]], v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eigen3_recovers_a_known_decomposition() {
        // diag(1, 2, 5) rotated: eigenvalues must come back.
        let m = [[2.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 5.0]];
        let (vals, vecs) = symmetric_eigen3(m);
        let mut sorted = vals;
        sorted.sort_by(f64::total_cmp);
        assert!((sorted[0] - 1.0).abs() < 1e-12 && (sorted[1] - 3.0).abs() < 1e-12);
        assert!((sorted[2] - 5.0).abs() < 1e-12);
        for (k, &lambda) in vals.iter().enumerate() {
            let e = [vecs[0][k], vecs[1][k], vecs[2][k]];
            for (i, row) in m.iter().enumerate() {
                assert!((dot(*row, e) - lambda * e[i]).abs() < 1e-10);
            }
        }
    }
}
