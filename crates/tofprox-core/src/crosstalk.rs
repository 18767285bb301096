//! Cover-window crosstalk: extraction, compensation constants and change detection.
//!
//! The cover window in front of emitter and lens reflects part of the illumination straight
//! back into the pixels. Every return adds its phasor to the raw images (2.2.1, eq. 2.2/2.3); the
//! window's return does not depend on the scene and scales with exposure and illumination power,
//! so per pixel and raw image it is a constant rate of ADC codes per µs of exposure. Measured once
//! with nothing in range ([`extract_crosstalk`]), it is subtracted from the raw codes before phase
//! and amplitude (the pipeline's offset stage, its `Calibration::crosstalk`) — the
//! stray-light correction step of the thesis's processing chain (3.1, fig. 3.1).
//!
//! A smudge on the window changes the crosstalk after calibration. What is left after the
//! compensation then shows up in readings with nothing in range as a phasor at ≈ zero distance;
//! [`residual_ratio`] measures it relative to the calibrated crosstalk and [`CrosstalkMonitor`]
//! turns a persistent change into a typed [`CrosstalkStatus`].

use crate::calib::OffsetCalibration;
use crate::frame::{
    DepthFrame, FLAG_IMPLAUSIBLE, FLAG_INVALID, FLAG_NON_FINITE, FLAG_SATURATED, Roi,
};
use crate::{Algorithm, CoreError};
use ndarray::{Array3, ArrayView3, Axis};
use num_complex::Complex64;
use std::f64::consts::TAU;

/// Phase shifts (degrees) of the raw images a [`CrosstalkCalibration`] holds, in order: the
/// images the 2-phase (first two) and 4-phase evaluations use.
pub const CROSSTALK_PHASES_DEG: [f64; 4] = [0.0, 90.0, 180.0, 270.0];

/// Per-pixel cover-window crosstalk of each raw image, in ADC codes per µs of exposure.
#[derive(Debug, Clone, PartialEq)]
pub struct CrosstalkCalibration {
    /// Shape `(4, rows, cols)`: the code the window's return adds to the raw image at
    /// [`CROSSTALK_PHASES_DEG`]`[k]`, per µs of exposure, above the dark level.
    pub lsb_per_us: Array3<f32>,
}

/// One capture with nothing in range, for [`extract_crosstalk`].
#[derive(Debug, Clone, Copy)]
pub struct CrosstalkCapture<'a> {
    /// Raw codes `(K, rows, cols)`, illuminated.
    pub codes: ArrayView3<'a, f64>,
    /// Phase shift of each raw image, degrees.
    pub phases_deg: &'a [f64],
    /// Exposure per raw image, µs.
    pub exposure_us: f64,
}

fn same_phase(a: f64, b: f64) -> bool {
    let d = (a - b).rem_euclid(360.0);
    a.is_finite() && d.min(360.0 - d) < 1e-6
}

/// Extracts the crosstalk from illuminated captures with nothing in range (a black absorber, the
/// sky, a room much farther than the illumination reaches).
///
/// Per pixel and phase θ ∈ [`CROSSTALK_PHASES_DEG`]: `u = code − dark` (the offset's dark frame,
/// or the mid code `2^(adc_bits−1)` without one) of every image taken at θ, fitted through the
/// origin over the exposures, `b = Σ t·u / Σ t²` (the window's return is ∝ exposure). An image at
/// θ + 180° stands in for a missing θ with its sign flipped (the correlation's fundamental and odd
/// harmonics are antisymmetric: `C(x + π) = −C(x)`), so 2-phase captures `[0°, 90°]` suffice.
///
/// Errors: no captures, shapes that differ, a non-positive exposure, non-finite codes, a code at
/// a rail (something in range saturates: not a crosstalk capture), or neither θ nor θ + 180° for
/// some θ.
pub fn extract_crosstalk(
    captures: &[CrosstalkCapture<'_>],
    offset: Option<&OffsetCalibration>,
    adc_bits: u8,
) -> Result<CrosstalkCalibration, CoreError> {
    let first = captures
        .first()
        .ok_or_else(|| CoreError::InvalidData("no crosstalk capture".into()))?;
    let (_, rows, cols) = first.codes.dim();
    if !(1..=16).contains(&adc_bits) {
        return Err(CoreError::param(
            "adc_bits",
            format!("must be 1..=16, got {adc_bits}"),
        ));
    }
    let rail = f64::from((1u32 << adc_bits) - 1);
    let mid = f64::from(1u32 << (adc_bits - 1));
    if let Some(o) = offset
        && o.dark_lsb.dim() != (rows, cols)
    {
        return Err(CoreError::shape(
            "offset calibration",
            format!("({rows}, {cols})"),
            format!("{:?}", o.dark_lsb.dim()),
        ));
    }
    // Σ t·u and Σ t² per phase slot; u enters with the sign of its slot (θ or θ + 180°)
    let mut num = Array3::<f64>::zeros((4, rows, cols));
    let mut den = [0.0f64; 4];
    for c in captures {
        let (k, r, cc) = c.codes.dim();
        if (r, cc) != (rows, cols) || k != c.phases_deg.len() || k == 0 {
            return Err(CoreError::shape(
                "crosstalk capture",
                format!("(K = {} phases, {rows}, {cols})", c.phases_deg.len()),
                format!("{:?}", c.codes.dim()),
            ));
        }
        if !(c.exposure_us.is_finite() && c.exposure_us > 0.0) {
            return Err(CoreError::param(
                "exposure_us",
                format!("must be finite and > 0, got {}", c.exposure_us),
            ));
        }
        if let Some(v) = c.codes.iter().find(|v| !v.is_finite()) {
            return Err(CoreError::InvalidData(format!(
                "crosstalk capture holds {v}"
            )));
        }
        if c.codes.iter().any(|&v| v <= 0.0 || v >= rail) {
            return Err(CoreError::InvalidData(
                "crosstalk capture has codes at a rail: something in range saturates (captures for the crosstalk need nothing in range)".into(),
            ));
        }
        let t = c.exposure_us;
        for (img, &ph) in c.codes.axis_iter(Axis(0)).zip(c.phases_deg) {
            for (slot, &want) in CROSSTALK_PHASES_DEG.iter().enumerate() {
                let sign = if same_phase(ph, want) {
                    1.0
                } else if same_phase(ph, want + 180.0) {
                    -1.0
                } else {
                    continue;
                };
                let mut acc = num.index_axis_mut(Axis(0), slot);
                match offset {
                    Some(o) => ndarray::Zip::from(&mut acc)
                        .and(&img)
                        .and(&o.dark_lsb)
                        .for_each(|a, &v, &d| *a += sign * t * (v - f64::from(d))),
                    None => acc.zip_mut_with(&img, |a, &v| *a += sign * t * (v - mid)),
                }
                den[slot] += t * t;
            }
        }
    }
    let mut out = Array3::<f32>::zeros((4, rows, cols));
    for (slot, d) in den.iter().enumerate() {
        if *d <= 0.0 {
            let phases: Vec<f64> = captures
                .iter()
                .flat_map(|c| c.phases_deg.iter().copied())
                .collect();
            return Err(CoreError::InvalidPhases {
                phases_deg: phases,
                reason: format!(
                    "the crosstalk needs images at {}° or {}°",
                    CROSSTALK_PHASES_DEG[slot],
                    CROSSTALK_PHASES_DEG[slot] + 180.0
                ),
            });
        }
        out.index_axis_mut(Axis(0), slot)
            .zip_mut_with(&num.index_axis(Axis(0), slot), |o, &n| {
                *o = (n / d) as f32;
            });
    }
    Ok(CrosstalkCalibration { lsb_per_us: out })
}

impl CrosstalkCalibration {
    /// Checks the shape `(4, rows, cols)` and that every value is finite.
    pub fn validate(&self, rows: usize, cols: usize) -> Result<(), CoreError> {
        if self.lsb_per_us.dim() != (4, rows, cols) {
            return Err(CoreError::shape(
                "crosstalk calibration (lsb_per_us)",
                format!("(4, {rows}, {cols})"),
                format!("{:?}", self.lsb_per_us.dim()),
            ));
        }
        if self.lsb_per_us.iter().any(|v| !v.is_finite()) {
            return Err(CoreError::Calibration(
                "crosstalk calibration contains non-finite values".into(),
            ));
        }
        Ok(())
    }

    /// The crosstalk code per µs of pixel `(row, col)` in a raw image at phase shift `theta_deg`:
    /// the stored value at 0°/90°/180°/270°, elsewhere the first harmonic through them,
    /// `c + x cos θ + y sin θ` with `x = (v0 − v180)/2`, `y = (v90 − v270)/2`, `c` their mean.
    pub fn lsb_per_us_at(&self, theta_deg: f64, row: usize, col: usize) -> f64 {
        let v = |k: usize| f64::from(self.lsb_per_us.get((k, row, col)).copied().unwrap_or(0.0));
        if let Some(k) = CROSSTALK_PHASES_DEG
            .iter()
            .position(|&p| same_phase(theta_deg, p))
        {
            return v(k);
        }
        let (x, y) = (0.5 * (v(0) - v(2)), 0.5 * (v(1) - v(3)));
        let c = 0.25 * (v(0) + v(1) + v(2) + v(3));
        let th = theta_deg.to_radians();
        c + x * th.cos() + y * th.sin()
    }

    /// Subtract the crosstalk of a capture `(K, rows, cols)` taken at `phases_deg` with
    /// `exposure_us` (before extracting wiggling or FPPN from a capture behind the window).
    ///
    /// At the stored phase shifts (0°/90°/180°/270°: 2- and 4-phase captures) the stored value
    /// is exact. A correlation capture (N ≥ 8 equally spaced steps, N a multiple of 4) is
    /// compensated at every step with every harmonic it resolves
    /// ([`Self::subtract_from_correlation`]); other shifts take the first harmonic through the
    /// stored values ([`Self::lsb_per_us_at`]).
    pub fn subtract_from(
        &self,
        mut codes: ndarray::ArrayViewMut3<'_, f64>,
        phases_deg: &[f64],
        exposure_us: f64,
    ) -> Result<(), CoreError> {
        let (k, rows, cols) = codes.dim();
        if k != phases_deg.len() {
            return Err(CoreError::shape(
                "capture",
                format!("({} phases, rows, cols)", phases_deg.len()),
                format!("{:?}", codes.dim()),
            ));
        }
        self.validate(rows, cols)?;
        if let Some(order) = correlation_order(phases_deg) {
            self.subtract_from_correlation(codes, &order, exposure_us);
            return Ok(());
        }
        for (mut img, &th) in codes.axis_iter_mut(Axis(0)).zip(phases_deg) {
            for ((r, c), v) in img.indexed_iter_mut() {
                *v -= self.lsb_per_us_at(th, r, c) * exposure_us;
            }
        }
        Ok(())
    }

    /// The crosstalk of a correlation capture, every harmonic, at every step (`order[j]`: the
    /// image at step `j`, phase `2π j / N`).
    ///
    /// The window's return and the target's are the same illumination correlated with the same
    /// demodulation (thesis 2.1.2, eq. 2.1): the capture's harmonics are `U_n = T_n (1 + q_n)`
    /// with the target's `T_n` and `q_n = r·w^n` (`r` the window-to-target amplitude ratio,
    /// `w = e^{−i(φ_w − φ_t)}` their phase difference), so the window's own harmonics are
    /// `X_n = U_n q_n / (1 + q_n)` whatever the correlation's shape. The four stored images fix
    /// `q`: their 4-point transform at 90° is `Σ_{n ≡ 1 (mod 4)} X_n`, solved for `q_1` by a
    /// fixed point started at the first harmonic alone; their mean fixes the offset
    /// (`Σ_{n ≡ 0 (mod 4)} X_n`). Without a target (`U_1 = X_1`) everything but the offset is
    /// the window's.
    pub fn subtract_from_correlation(
        &self,
        mut codes: ndarray::ArrayViewMut3<'_, f64>,
        order: &[usize],
        exposure_us: f64,
    ) {
        let n = order.len();
        let (_, rows, cols) = codes.dim();
        let twiddle: Vec<Complex64> = (0..n)
            .map(|j| Complex64::from_polar(1.0, -TAU * j as f64 / n as f64))
            .collect();
        let mut u = vec![0.0f64; n];
        for r in 0..rows {
            for c in 0..cols {
                for (j, &k) in order.iter().enumerate() {
                    u[j] = codes[(k, r, c)];
                }
                let v = |slot: usize| f64::from(self.lsb_per_us[(slot, r, c)]) * exposure_us;
                let stored = [v(0), v(1), v(2), v(3)];
                let x = window_steps(&u, &stored, &twiddle);
                for (j, &k) in order.iter().enumerate() {
                    codes[(k, r, c)] -= x[j];
                }
            }
        }
    }

    /// The crosstalk phasor `(x, y)` per µs of pixel `i` (row-major) as the pipeline's
    /// `algorithm` sees it: 2-phase `(u0, u90)`, 4-phase `((u0 − u180)/2, (u90 − u270)/2)` — so
    /// its length is in the units of [`DepthFrame::amplitude_lsb`] per µs (eq. 2.4).
    pub fn phasor_per_us(&self, algorithm: Algorithm, row: usize, col: usize) -> (f32, f32) {
        let v = |k: usize| self.lsb_per_us.get((k, row, col)).copied().unwrap_or(0.0);
        match algorithm {
            Algorithm::TwoPhase => (v(0), v(1)),
            Algorithm::FourPhase => (0.5 * (v(0) - v(2)), 0.5 * (v(1) - v(3))),
        }
    }

    /// Mean crosstalk amplitude over `roi` of a `rows × cols` frame at `exposure_us`, in the
    /// units of [`DepthFrame::amplitude_lsb`] (0 for an empty ROI).
    pub fn mean_amplitude_lsb(&self, algorithm: Algorithm, roi: Roi, exposure_us: f64) -> f32 {
        let (_, rows, cols) = self.lsb_per_us.dim();
        let r = roi.resolve(rows, cols);
        let (mut sum, mut n) = (0.0f64, 0usize);
        for row in r.row0..r.row0 + r.rows {
            for col in r.col0..r.col0 + r.cols {
                let (x, y) = self.phasor_per_us(algorithm, row, col);
                sum += f64::from(x.hypot(y));
                n += 1;
            }
        }
        if n == 0 {
            0.0
        } else {
            (sum / n as f64 * exposure_us) as f32
        }
    }
}

/// The image order of a correlation capture: `order[j]` is the image at step `2π j / N`, when
/// `phases_deg` are N ≥ 8 equally spaced steps from 0° with 4 | N (the stored 0°/90°/180°/270°
/// are steps of it); `None` otherwise.
fn correlation_order(phases_deg: &[f64]) -> Option<Vec<usize>> {
    let n = phases_deg.len();
    if n < 8 || !n.is_multiple_of(4) {
        return None;
    }
    let mut order = vec![usize::MAX; n];
    for (k, &p) in phases_deg.iter().enumerate() {
        let j = (0..n).find(|&j| same_phase(p, 360.0 * j as f64 / n as f64))?;
        if order[j] != usize::MAX {
            return None;
        }
        order[j] = k;
    }
    Some(order)
}

/// The window's code at every step of one pixel's correlation `u` (N steps, `twiddle[j] =
/// e^{−2πij/N}`), from the window's codes `stored` at 0°/90°/180°/270° at the same exposure
/// ([`CrosstalkCalibration::subtract_from_correlation`] has the physics).
fn window_steps(u: &[f64], stored: &[f64; 4], twiddle: &[Complex64]) -> Vec<f64> {
    let n = u.len();
    let half = n / 2;
    // U_n for n in (−N/2, N/2], index n mod N
    let big_u: Vec<Complex64> = (0..n)
        .map(|h| {
            u.iter()
                .enumerate()
                .map(|(j, &x)| twiddle[(h * j) % n] * x)
                .sum::<Complex64>()
                / n as f64
        })
        .collect();
    let harmonic = |h: isize| big_u[h.rem_euclid(n as isize) as usize];
    // the stored images' 4-point transform: bin 1 = Σ_{n ≡ 1 (4)} X_n, bin 0 = Σ_{n ≡ 0 (4)} X_n
    let m1 = Complex64::new(stored[0] - stored[2], -(stored[1] - stored[3])) / 4.0;
    let m0 = stored.iter().sum::<f64>() / 4.0;
    let hs: Vec<isize> = (1 - half as isize..=half as isize).collect();
    let class1: Vec<isize> = hs
        .iter()
        .copied()
        .filter(|h| h.rem_euclid(4) == 1)
        .collect();
    let share = |q1: Complex64, h: isize| {
        let (r, w) = (q1.norm(), q1 / q1.norm());
        let q = w.powi(h as i32) * r;
        q / (q + 1.0)
    };
    // fixed point for q_1: Σ_{n ≡ 1 (4)} U_n q_n/(1+q_n) = M_1
    let u1 = harmonic(1);
    let mut q1 = m1 / (u1 - m1);
    for _ in 0..50 {
        if !(q1.is_finite() && q1.norm() > 0.0) {
            break;
        }
        let rest: Complex64 = class1
            .iter()
            .filter(|&&h| h != 1)
            .map(|&h| harmonic(h) * share(q1, h))
            .sum();
        let t = m1 - rest;
        let next = t / (u1 - t);
        let done = (next - q1).norm() <= 1e-12 * q1.norm();
        q1 = next;
        if done {
            break;
        }
    }
    let window_only = !(q1.is_finite() && q1.norm() > 0.0);
    let x_of = |h: isize| {
        if window_only {
            harmonic(h)
        } else {
            harmonic(h) * share(q1, h)
        }
    };
    let mut x: Vec<Complex64> = hs
        .iter()
        .map(|&h| {
            if h == 0 {
                Complex64::new(0.0, 0.0)
            } else {
                x_of(h)
            }
        })
        .collect();
    // the offset: the stored mean less the other harmonics it aliases (n ≡ 0 mod 4)
    let aliased0: f64 = hs
        .iter()
        .zip(&x)
        .filter(|(h, _)| h.rem_euclid(4) == 0 && **h != 0)
        .map(|(_, v)| v.re)
        .sum();
    if let Some(i) = hs.iter().position(|&h| h == 0) {
        x[i] = Complex64::new(m0 - aliased0, 0.0);
    }
    (0..n)
        .map(|j| {
            hs.iter()
                .zip(&x)
                .map(|(&h, v)| (v * twiddle[(h.rem_euclid(n as isize) as usize * j) % n].conj()).re)
                .sum()
        })
        .collect()
}

/// The crosstalk left in a frame, relative to the calibrated one: `Σ A cos φ / Σ |X| t` over the
/// ROI's unsaturated, finite pixels, with `A`, `φ` the frame's amplitude and corrected phase and
/// `|X| t` the calibrated crosstalk amplitude at `exposure_us`.
///
/// With a wiggling table (which holds the global delay of driver and cabling, 3.3.7.2) the
/// pipeline maps the window's return to ≈ zero distance (phase ≈ 4π f d_w / c ≈ 0), so what
/// remains of it after compensation projects fully onto `cos φ` (without one the global delay
/// stays in φ and the ratio shrinks by `cos φ_delay`): ≈ 0 with the window as
/// calibrated, ≈ 1 when a smudge has doubled the crosstalk, ≈ −0.5 when the crosstalk halved.
/// **Only meaningful for readings with nothing in range**: a target adds `A_t cos φ_t` (a wall
/// beyond the range whose phase wraps to a few cm looks like crosstalk). `None` when the ROI has
/// no usable pixel or the calibrated crosstalk is zero there.
pub fn residual_ratio(
    frame: &DepthFrame,
    calibration: &CrosstalkCalibration,
    algorithm: Algorithm,
    roi: Roi,
    exposure_us: f64,
) -> Option<f32> {
    RoiPhasorSums::of(frame, roi, Some((calibration, algorithm, exposure_us))).residual_ratio()
}

/// Whether the ROI's light comes from the cover window alone: the sum of its unsaturated
/// pixels' phasors `Σ A·e^{iφ}` (eq. 2.2/2.3, after the compensation) points at the window,
/// `|arg| ≤ tolerance_rad` (e.g. the phase of a few cm, [`crate::phasor::distance_to_phase_rad`]).
/// A changed window leaves exactly such a residual (its phase is the window's ≈ 0, whatever its
/// size); a target at range `d` points at `4π f d / c` instead. Use it beside "nothing in range"
/// to pick the readings [`residual_ratio`] is meaningful for: a residual large enough to be a
/// valid depth reads ≈ 0 mm or, with noise pushing the phase below 0, just under the unambiguous
/// range — either way its phasor points at 0. A target within `tolerance` of a multiple of the
/// unambiguous range is indistinguishable from it with one frequency (a documented limit).
/// `false` when the ROI has no usable pixel.
pub fn phasor_points_at_window(frame: &DepthFrame, roi: Roi, tolerance_rad: f64) -> bool {
    RoiPhasorSums::of(frame, roi, None).points_at_window(tolerance_rad)
}

/// The sums over the ROI's unsaturated, finite pixels that [`phasor_points_at_window`] and
/// [`residual_ratio`] read, taken in one pass (each pixel's `cos φ`, `sin φ` once): the summed
/// phasor `Σ A·e^{iφ}` (eq. 2.2/2.3) and, with a crosstalk calibration, `Σ |X| t`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RoiPhasorSums {
    /// `Σ A cos φ` (LSB).
    re_lsb: f64,
    /// `Σ A sin φ` (LSB).
    im_lsb: f64,
    /// `Σ |X| t` (LSB); 0 without a usable calibration.
    reference_lsb: f64,
}

impl RoiPhasorSums {
    /// The sums over `roi` of `frame`; `crosstalk`: the calibration, the frame's algorithm and
    /// exposure (µs) — ignored when its shape is not the frame's or the exposure is not finite.
    pub fn of(
        frame: &DepthFrame,
        roi: Roi,
        crosstalk: Option<(&CrosstalkCalibration, Algorithm, f64)>,
    ) -> Self {
        let (rows, cols) = frame.dim();
        let crosstalk =
            crosstalk.filter(|(x, _, t)| x.lsb_per_us.dim() == (4, rows, cols) && t.is_finite());
        let mut s = RoiPhasorSums::default();
        for (row, col, a, ph) in usable_phasors(frame, roi) {
            s.re_lsb += a * ph.cos();
            s.im_lsb += a * ph.sin();
            if let Some((x, algorithm, exposure_us)) = crosstalk {
                let (x, y) = x.phasor_per_us(algorithm, row, col);
                s.reference_lsb += f64::from(x.hypot(y)) * exposure_us;
            }
        }
        s
    }

    /// The summed phasor points at the window: `|arg| ≤ tolerance_rad` ([`phasor_points_at_window`]).
    pub fn points_at_window(&self, tolerance_rad: f64) -> bool {
        self.re_lsb > 0.0 && self.im_lsb.atan2(self.re_lsb).abs() <= tolerance_rad
    }

    /// `Σ A cos φ / Σ |X| t` ([`residual_ratio`]); `None` without a calibration or a usable pixel.
    pub fn residual_ratio(&self) -> Option<f32> {
        (self.reference_lsb > 0.0).then(|| (self.re_lsb / self.reference_lsb) as f32)
    }
}

/// Near pixels the cover window alone can explain (issue 21: a window that changes). The
/// pipeline subtracts `ŝ·X·t` (the calibrated crosstalk `X` per µs, eq. 2.2/2.3 applied to the
/// raw codes, times the current estimate `ŝ`); the window's true return is `s·X·t`, so what
/// the window leaves in a pixel is the phasor `(s − ŝ)·X·t`, of amplitude `|s − ŝ|·|X|·t`. A
/// valid, unsaturated pixel whose depth is below `check_below_m` and whose amplitude is at most
/// `bound·|X|·t` carries no light the window could not give while `|s − ŝ| ≤ bound`: it is
/// flagged [`FLAG_IMPLAUSIBLE`] | [`FLAG_INVALID`] with depth 0, like a wrapped phase
/// ([`crate::radiometry::flag_implausible_near`]). Returns how many pixels of `roi` were
/// flagged; a calibration of another shape flags nothing.
pub fn flag_window_explained(
    frame: &mut DepthFrame,
    calibration: &CrosstalkCalibration,
    algorithm: Algorithm,
    roi: Roi,
    exposure_us: f64,
    bound: f32,
    check_below_m: f32,
) -> usize {
    let (rows, cols) = frame.dim();
    if calibration.lsb_per_us.dim() != (4, rows, cols) || !exposure_us.is_finite() {
        return 0;
    }
    let r = roi.resolve(rows, cols);
    let per_us = bound.max(0.0) * exposure_us.max(0.0) as f32;
    let mut n = 0usize;
    for row in 0..rows {
        for col in 0..cols {
            let i = [row, col];
            if frame.flags[i] & (FLAG_INVALID | FLAG_SATURATED) != 0
                || frame.depth_m[i] >= check_below_m
            {
                continue;
            }
            let (x, y) = calibration.phasor_per_us(algorithm, row, col);
            if frame.amplitude_lsb[i] <= per_us * x.hypot(y) {
                frame.flags[i] |= FLAG_IMPLAUSIBLE | FLAG_INVALID;
                frame.depth_mm[i] = 0;
                frame.depth_m[i] = 0.0;
                let inside = (r.row0..r.row0 + r.rows).contains(&row)
                    && (r.col0..r.col0 + r.cols).contains(&col);
                n += usize::from(inside);
            }
        }
    }
    n
}

/// `(row, col, A, φ)` of the ROI's pixels that are neither saturated nor non-finite: amplitude
/// (LSB) and corrected phase (rad) as the frame holds them, row by row.
fn usable_phasors(frame: &DepthFrame, roi: Roi) -> impl Iterator<Item = (usize, usize, f64, f64)> {
    let (rows, cols) = frame.dim();
    let r = roi.resolve(rows, cols);
    (r.row0..r.row0 + r.rows)
        .flat_map(move |row| (r.col0..r.col0 + r.cols).map(move |col| (row, col)))
        .filter_map(move |(row, col)| {
            let flags = frame
                .flags
                .get((row, col))
                .copied()
                .unwrap_or(FLAG_NON_FINITE);
            (flags & (FLAG_SATURATED | FLAG_NON_FINITE) == 0).then(|| {
                let a = frame.amplitude_lsb.get((row, col)).copied().unwrap_or(0.0);
                let ph = frame.phase_rad.get((row, col)).copied().unwrap_or(0.0);
                (row, col, f64::from(a), f64::from(ph))
            })
        })
}

/// What [`CrosstalkMonitor`] concludes about the cover window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CrosstalkStatus {
    /// No crosstalk calibration: nothing is compensated, nothing monitored.
    Uncalibrated,
    /// Too few readings with nothing in range yet.
    Unknown,
    /// The crosstalk is as calibrated (`residual_ratio`: the smoothed residual / calibrated).
    AsCalibrated {
        /// Smoothed residual relative to the calibrated crosstalk.
        residual_ratio: f32,
    },
    /// The crosstalk changed since calibration: above +threshold a smudge or a new cover (more
    /// crosstalk), below −threshold a cleaned window (less). Recalibrate
    /// (`tofprox calibrate crosstalk`) or clean the window.
    Changed {
        /// Smoothed residual relative to the calibrated crosstalk (+1: doubled).
        residual_ratio: f32,
    },
}

impl CrosstalkStatus {
    /// A one-line description for logs and the daemon's `LastError`/status.
    pub fn message(&self) -> String {
        match self {
            CrosstalkStatus::Uncalibrated => "no crosstalk calibration".into(),
            CrosstalkStatus::Unknown => "crosstalk not checked yet".into(),
            CrosstalkStatus::AsCalibrated { residual_ratio } => format!(
                "cover-window crosstalk as calibrated (residual {:+.0} %)",
                100.0 * residual_ratio
            ),
            CrosstalkStatus::Changed { residual_ratio } => format!(
                "cover-window crosstalk changed by {:+.0} % since calibration ({}); clean the window or run `tofprox calibrate crosstalk`",
                100.0 * residual_ratio,
                if *residual_ratio > 0.0 {
                    "smudged or another cover"
                } else {
                    "cleaner than when calibrated"
                }
            ),
        }
    }
}

/// Turns per-reading [`residual_ratio`]s (of readings with nothing in range) into a status: an
/// exponential average with weight `1/readings`, [`CrosstalkStatus::Changed`] once the average's
/// magnitude reaches `threshold`, back to [`CrosstalkStatus::AsCalibrated`] below `threshold / 2`
/// (hysteresis), [`CrosstalkStatus::Unknown`] before `readings` updates.
#[derive(Debug, Clone)]
pub struct CrosstalkMonitor {
    threshold: f32,
    readings: u32,
    seen: u32,
    average: f32,
    changed: bool,
}

/// Default relative change that counts as "changed" (a smudge doubling the crosstalk gives 1).
pub const DEFAULT_CHANGE_THRESHOLD: f32 = 0.5;
/// Default number of readings averaged.
pub const DEFAULT_MONITOR_READINGS: u32 = 8;

impl Default for CrosstalkMonitor {
    fn default() -> Self {
        CrosstalkMonitor::new(DEFAULT_CHANGE_THRESHOLD, DEFAULT_MONITOR_READINGS)
    }
}

impl CrosstalkMonitor {
    /// A monitor with the given threshold (> 0; non-finite or ≤ 0 takes the default) and
    /// averaging length (0 is treated as 1).
    pub fn new(threshold: f32, readings: u32) -> Self {
        CrosstalkMonitor {
            threshold: if threshold.is_finite() && threshold > 0.0 {
                threshold
            } else {
                DEFAULT_CHANGE_THRESHOLD
            },
            readings: readings.max(1),
            seen: 0,
            average: 0.0,
            changed: false,
        }
    }

    /// Feed the residual ratio of one reading with nothing in range (non-finite values are
    /// ignored); returns the status after it.
    pub fn update(&mut self, residual_ratio: f32) -> CrosstalkStatus {
        if residual_ratio.is_finite() {
            self.seen = self.seen.saturating_add(1);
            let w = 1.0 / self.seen.min(self.readings) as f32;
            self.average += w * (residual_ratio - self.average);
            if self.seen >= self.readings {
                let m = self.average.abs();
                if m >= self.threshold {
                    self.changed = true;
                } else if m < 0.5 * self.threshold {
                    self.changed = false;
                }
            }
        }
        self.status()
    }

    /// The current status.
    pub fn status(&self) -> CrosstalkStatus {
        if self.seen < self.readings {
            CrosstalkStatus::Unknown
        } else if self.changed {
            CrosstalkStatus::Changed {
                residual_ratio: self.average,
            }
        } else {
            CrosstalkStatus::AsCalibrated {
                residual_ratio: self.average,
            }
        }
    }

    /// The crosstalk scale that would cancel the residual: `1 + average` (for
    /// the pipeline's `Pipeline::set_crosstalk_scale` when the application chooses to
    /// tolerate a changed window instead of only reporting it); 1 before any reading.
    pub fn suggested_scale(&self) -> f32 {
        (1.0 + self.average).max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    /// A frame whose every pixel has amplitude `a` and phase `ph` (wrapped into [0, 2π) as the
    /// pipeline does).
    fn uniform_frame(a: f32, ph: f32) -> DepthFrame {
        let mut f = DepthFrame::zeros(4, 6);
        f.amplitude_lsb.fill(a);
        f.phase_rad.fill(ph.rem_euclid(std::f32::consts::TAU));
        f
    }

    #[test]
    fn the_window_residual_points_at_zero_phase_a_target_does_not() {
        let roi = Roi::centered(4, 6, 1.0);
        let tol = crate::phasor::distance_to_phase_rad(0.05, 80e6);
        // a residual at ≈ 0 mm, also with noise pushing it below 0 (reads just under d_u)
        assert!(phasor_points_at_window(
            &uniform_frame(20.0, 0.02),
            roi,
            tol
        ));
        assert!(phasor_points_at_window(
            &uniform_frame(20.0, -0.05),
            roi,
            tol
        ));
        // a wall at 1 m (φ = 3.35 rad at 80 MHz) or 30 cm does not
        for d in [1.0, 0.3] {
            let ph = crate::phasor::distance_to_phase_rad(d, 80e6) as f32;
            assert!(
                !phasor_points_at_window(&uniform_frame(20.0, ph), roi, tol),
                "{d} m"
            );
        }
        // saturated pixels are left out: nothing usable, no verdict
        let mut f = uniform_frame(20.0, 0.0);
        f.flags.fill(FLAG_SATURATED);
        assert!(!phasor_points_at_window(&f, roi, tol));
    }

    #[test]
    fn monitor_reports_a_persistent_change_with_hysteresis() {
        let mut m = CrosstalkMonitor::new(0.5, 4);
        assert_eq!(m.update(0.02), CrosstalkStatus::Unknown);
        for _ in 0..3 {
            m.update(0.0);
        }
        assert!(matches!(m.status(), CrosstalkStatus::AsCalibrated { .. }));
        // a smudge doubles the crosstalk: residual ≈ 1
        let mut s = m.status();
        for _ in 0..8 {
            s = m.update(1.0);
        }
        let CrosstalkStatus::Changed { residual_ratio } = s else {
            panic!("{s:?}");
        };
        assert!(residual_ratio > 0.9);
        assert!((m.suggested_scale() - 2.0).abs() < 0.1);
        // one clean reading does not clear it; a cleaned window does, eventually
        assert!(matches!(m.update(0.0), CrosstalkStatus::Changed { .. }));
        for _ in 0..20 {
            s = m.update(0.0);
        }
        assert!(matches!(s, CrosstalkStatus::AsCalibrated { .. }), "{s:?}");
        assert!(m.update(f32::NAN) == s, "NaN ignored");
    }

    /// A correlation written here, not through the model: a low-passed square wave's
    /// correlation, odd harmonics falling as 1/n² with a lag growing with n (a slow edge).
    fn independent_correlation(x: f64) -> f64 {
        [1.0, 3.0, 5.0, 7.0, 9.0]
            .iter()
            .map(|&n: &f64| (n * x - 0.12 * n).cos() / (n * n))
            .sum()
    }

    /// Issue 21: a window 40× the typical one (the typical window returns as much as a white
    /// target at 1.4 m) behind a correlation capture of a white wall at 1 m is compensated at
    /// every phase step, every harmonic: what is left is the wall alone within 1e-6 of its
    /// amplitude. The first harmonic alone leaves the window's 3rd and 5th in it.
    #[test]
    fn a_window_40x_typical_is_compensated_at_every_step_of_a_correlation() {
        let (f, c) = (80e6, 299_792_458.0);
        let phase = |d: f64| 4.0 * std::f64::consts::PI * f * d / c + 0.8; // + global delay
        let (d_wall, d_window) = (1.0, 0.003);
        // amplitudes per µs: wall ρ = 0.9 at 1 m; typical window = ρ 1 at 1.4 m, × 40
        let (a_wall, a_window) = (0.9 / (d_wall * d_wall), 40.0 / (1.4f64 * 1.4));
        let code = |a: f64, d: f64, th_deg: f64, t: f64| {
            a * t * independent_correlation(phase(d) - th_deg.to_radians())
        };
        let t_cal = 500.0;
        let dark = 30000.0; // mid code of a 16-bit ADC: the window's codes stay off the rails
        // the crosstalk calibration: 4-phase capture of the window alone
        let empty = Array3::from_shape_fn((4, 1, 1), |(k, _, _)| {
            dark + code(a_window, d_window, 90.0 * k as f64, t_cal)
        });
        let off = OffsetCalibration {
            dark_lsb: Array2::from_elem((1, 1), dark as f32),
        };
        let x = extract_crosstalk(
            &[CrosstalkCapture {
                codes: empty.view(),
                phases_deg: &CROSSTALK_PHASES_DEG,
                exposure_us: t_cal,
            }],
            Some(&off),
            16,
        )
        .unwrap();
        // a 24-step correlation capture of the wall behind the window, in shuffled order
        let t = 2000.0;
        let phases: Vec<f64> = (0..24).map(|j| f64::from((j * 7) % 24) * 15.0).collect();
        let capture = Array3::from_shape_fn((24, 1, 1), |(k, _, _)| {
            code(a_wall, d_wall, phases[k], t) + code(a_window, d_window, phases[k], t)
        });
        let mut got = capture.clone();
        x.subtract_from(got.view_mut(), &phases, t).unwrap();
        let scale = a_wall * t;
        for (k, &th) in phases.iter().enumerate() {
            let want = code(a_wall, d_wall, th, t);
            let err = (got[(k, 0, 0)] - want).abs() / scale;
            assert!(
                err < 1e-6,
                "step {th}°: residual {err:e} of the wall's amplitude"
            );
        }
        // the first harmonic alone is far off (what the issue measured)
        let worst_first = phases
            .iter()
            .enumerate()
            .map(|(k, &th)| {
                let left = capture[(k, 0, 0)] - x.lsb_per_us_at(th, 0, 0) * t;
                (left - code(a_wall, d_wall, th, t)).abs() / scale
            })
            .fold(0.0f64, f64::max);
        assert!(worst_first > 0.05, "first harmonic only: {worst_first}");
        // 2-/4-phase captures keep the stored values exactly
        let mut four = Array3::from_elem((4, 1, 1), 0.0);
        x.subtract_from(four.view_mut(), &CROSSTALK_PHASES_DEG, t)
            .unwrap();
        for k in 0..4 {
            let want = -f64::from(x.lsb_per_us[(k, 0, 0)]) * t;
            assert!((four[(k, 0, 0)] - want).abs() < 1e-9);
        }
    }

    #[test]
    fn extraction_fits_the_rate_through_the_origin_and_fills_opposite_phases() {
        // one pixel, crosstalk 0.06 / 0.02 LSB/µs at 0° / 90° above a dark level of 2000
        let dark = OffsetCalibration {
            dark_lsb: Array2::from_elem((1, 1), 2000.0),
        };
        let cap = |t: f64| {
            Array3::from_shape_vec((2, 1, 1), vec![2000.0 + 0.06 * t, 2000.0 + 0.02 * t]).unwrap()
        };
        let (a, b) = (cap(100.0), cap(400.0));
        let caps = [
            CrosstalkCapture {
                codes: a.view(),
                phases_deg: &[0.0, 90.0],
                exposure_us: 100.0,
            },
            CrosstalkCapture {
                codes: b.view(),
                phases_deg: &[360.0, 90.0],
                exposure_us: 400.0,
            },
        ];
        let x = extract_crosstalk(&caps, Some(&dark), 12).unwrap();
        let v: Vec<f32> = x.lsb_per_us.iter().copied().collect();
        for (got, want) in v.iter().zip([0.06f32, 0.02, -0.06, -0.02]) {
            assert!((got - want).abs() < 1e-6, "{v:?}");
        }
        assert_eq!(
            x.phasor_per_us(Algorithm::FourPhase, 0, 0),
            x.phasor_per_us(Algorithm::TwoPhase, 0, 0)
        );
        // between the stored phases: the first harmonic A cos(φ − θ) through them
        let (amp, phi) = (0.06f64.hypot(0.02), 0.02f64.atan2(0.06));
        for th in [15.0f64, 135.0, 300.0] {
            let want = amp * (phi - th.to_radians()).cos();
            assert!((x.lsb_per_us_at(th, 0, 0) - want).abs() < 1e-6);
        }
        // a saturated capture is not a crosstalk capture; a missing 90°/270° is named
        let sat = Array3::from_elem((2, 1, 1), 4095.0);
        let e = extract_crosstalk(
            &[CrosstalkCapture {
                codes: sat.view(),
                phases_deg: &[0.0, 90.0],
                exposure_us: 1.0,
            }],
            None,
            12,
        )
        .unwrap_err();
        assert!(e.to_string().contains("rail"), "{e}");
        let e = extract_crosstalk(
            &[CrosstalkCapture {
                codes: a.view(),
                phases_deg: &[0.0, 180.0],
                exposure_us: 1.0,
            }],
            None,
            12,
        )
        .unwrap_err();
        assert!(e.to_string().contains("90°"), "{e}");
    }

    /// The window rule on frames composed as phasor sums, written here: each pixel holds the
    /// window's residual `δ·X·t` (phase 0: the window is millimetres away) plus, optionally, a
    /// diffuse target at `d` (phase `4π f d / c`, amplitude `K ρ t / d²`), the sum's modulus and
    /// argument as the pipeline would report them.
    #[test]
    fn the_window_explains_its_own_residual_and_no_real_near_target() {
        const C: f64 = 299_792_458.0;
        let (rows, cols, t_us, f_hz) = (3usize, 4usize, 100.0f64, 80e6);
        // crosstalk 0.2..0.5 LSB/µs along the columns (stronger at the emitter side), all at 0°
        let mut x = CrosstalkCalibration {
            lsb_per_us: Array3::zeros((4, rows, cols)),
        };
        for col in 0..cols {
            let v = 0.2 + 0.1 * col as f32;
            x.lsb_per_us.slice_mut(ndarray::s![0, .., col]).fill(v);
            x.lsb_per_us.slice_mut(ndarray::s![2, .., col]).fill(-v);
        }
        let frame = |delta: f64, target: Option<(f64, f64)>| {
            let mut f = DepthFrame::zeros(rows, cols);
            for ((r, c), a) in f.amplitude_lsb.indexed_iter_mut() {
                let xw = delta * (0.2 + 0.1 * c as f64) * t_us;
                let (mut re, mut im) = (xw, 0.0);
                if let Some((d, rho)) = target {
                    let ph = 4.0 * std::f64::consts::PI * f_hz * d / C;
                    let at = 0.09 * rho * t_us / (d * d);
                    re += at * ph.cos();
                    im += at * ph.sin();
                }
                *a = re.hypot(im) as f32;
                let ph = im.atan2(re).rem_euclid(TAU);
                let d = ph * C / (4.0 * std::f64::consts::PI * f_hz);
                f.phase_rad[[r, c]] = ph as f32;
                f.depth_m[[r, c]] = d as f32;
                f.depth_mm[[r, c]] = (d * 1e3).round() as u16;
            }
            f
        };
        let roi = Roi::centered(rows, cols, 1.0);
        let flag = |f: &mut DepthFrame| {
            flag_window_explained(f, &x, Algorithm::FourPhase, roi, t_us, 1.5, 0.15)
        };
        // the window doubled since the estimate (δ = 1): every pixel is the window's, released
        let mut only_window = frame(1.0, None);
        assert_eq!(flag(&mut only_window), rows * cols);
        assert!(only_window.flags.iter().all(|&f| f & FLAG_IMPLAUSIBLE != 0));
        assert!(only_window.depth_mm.iter().all(|&d| d == 0));
        // dark hair (6 %) at 5 cm behind the same residual: K ρ t / d² = 216 LSB of its own
        // against a bound of at most 1.5 · 0.5 LSB/µs · 100 µs = 75 LSB: every pixel is kept
        let mut hair = frame(1.0, Some((0.05, 0.06)));
        assert_eq!(flag(&mut hair), 0);
        assert!(
            hair.depth_mm.iter().all(|&d| (30..60).contains(&d)),
            "{:?}",
            hair.depth_mm
        );
        // a saturated pixel is never touched
        let mut sat = frame(1.0, None);
        sat.flags[[0, 0]] = FLAG_SATURATED;
        assert_eq!(flag(&mut sat), rows * cols - 1);
        assert_eq!(sat.flags[[0, 0]], FLAG_SATURATED);
        // another shape of calibration flags nothing
        let mut other = DepthFrame::zeros(2, 2);
        assert_eq!(
            flag_window_explained(&mut other, &x, Algorithm::FourPhase, roi, t_us, 1.5, 0.15),
            0
        );
    }
}
