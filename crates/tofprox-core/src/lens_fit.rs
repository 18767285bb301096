//! The lens calibration: the intrinsics fit from a flat-wall sweep (thesis 5.1.3) — of
//! correlation captures, or of 4-phase walls corrected by a wiggling table, or jointly with the
//! wiggling table of a correlation capture —, with standard errors and the refusal of data that
//! cannot pin the lens. The lens itself, its rays and the ray factors a sweep measures are
//! [`crate::camera`]'s; the least squares are [`crate::lsq`]'s.

use crate::CoreError;
use crate::calib::WigglingLut;
use crate::camera::{Distortion, Intrinsics, RayGrid, ray_factors_from_sweep};
use crate::lsq::{Normal, Stop, fit_residuals, solve_spd};
use ndarray::{Array2, ArrayView2, ArrayView3};

/// One capture of the lens calibration's sweep: a flat target perpendicular to the optical axis
/// at `distance_m`, raw codes `(N, rows, cols)` at `phases_deg` (N ≥ 4 equally spaced over the
/// full circle; 8 or more make the sweep free of the 3rd-harmonic wiggling that 4 phases leave).
#[derive(Debug, Clone, Copy)]
pub struct SweepCapture<'a> {
    /// Perpendicular distance of the target, metres.
    pub distance_m: f64,
    /// Raw codes `(N, rows, cols)`.
    pub raw: ArrayView3<'a, f64>,
    /// Phase shift of each raw image, degrees.
    pub phases_deg: &'a [f64],
}

/// Fewest equally spaced phases whose N-phase DFT keeps the correlation's 3rd and 5th harmonics
/// out of the first: harmonic `k` aliases onto the first when `k ≡ ±1 (mod N)` (thesis 3.2.2,
/// 3.3.6), so 4 phases fold the 3rd and 5th in (the wiggling) and 8 or more leave the
/// first-harmonic phase shaped by the geometry alone.
pub const MIN_HARMONIC_FREE_PHASES: usize = 8;

/// How the phases of a lens-calibration sweep are freed of the wiggling (the 3rd and 5th
/// harmonics of the correlation, thesis 3.3.6) before the lens is fitted to them: a lens fitted to
/// phases that still hold the wiggling absorbs it.
#[derive(Debug, Clone, Copy)]
pub enum SweepPhase<'a> {
    /// The first harmonic of correlation captures (≥ [`MIN_HARMONIC_FREE_PHASES`] equally spaced
    /// phases): free of the wiggling by construction.
    FirstHarmonic,
    /// The 4-phase phase (eq. 2.3) of the images at 0°, 90°, 180°, 270° corrected by this 4-phase
    /// wiggling table (3.3.7.2); every capture must hold those four images.
    WigglingCorrected(&'a WigglingLut),
}

/// The lens calibration from raw captures (`tofprox calibrate intrinsics`): per capture (each
/// with ≥ [`MIN_HARMONIC_FREE_PHASES`] equally spaced phases, refused otherwise) the
/// N-phase phase ([`crate::phasor::nphase_frame`], offsets cancel) with pixels that touch a rail
/// (`≤ 0` or `≥ 2^adc_bits − 1`) or whose amplitude is below `min_amplitude_lsb` left out, then
/// [`ray_factors_from_sweep`] and [`fit_intrinsics`] for the window at full-array `(row0, col0)`.
pub fn calibrate_intrinsics(
    sweep: &[SweepCapture<'_>],
    adc_bits: u8,
    modulation_hz: f64,
    min_amplitude_lsb: f64,
    row0: usize,
    col0: usize,
) -> Result<IntrinsicsFit, CoreError> {
    let sensor = SweepSensor {
        adc_bits,
        modulation_hz,
        min_amplitude_lsb,
        origin: [row0, col0],
    };
    fit_sweep(sweep, SweepPhase::FirstHarmonic, &sensor)
}

/// What the lens fit needs to know of the sensor: ADC resolution (rails), modulation frequency
/// (eq. 2.6), the amplitude below which a pixel is left out, the window's full-array origin.
struct SweepSensor {
    adc_bits: u8,
    modulation_hz: f64,
    min_amplitude_lsb: f64,
    origin: [usize; 2],
}

/// [`ray_factors_from_sweep`] and [`fit_intrinsics`] on the sweep's phases, freed of the wiggling
/// as `how` says ([`sweep_phase`]).
fn fit_sweep(
    sweep: &[SweepCapture<'_>],
    how: SweepPhase<'_>,
    sensor: &SweepSensor,
) -> Result<IntrinsicsFit, CoreError> {
    crate::sensor::validate_adc_bits(sensor.adc_bits)?;
    let max_code = f64::from(crate::sensor::adc_max_code(sensor.adc_bits));
    let phases = sweep
        .iter()
        .map(|cap| {
            Ok((
                cap.distance_m,
                sweep_phase(cap, how, max_code, sensor.min_amplitude_lsb)?,
            ))
        })
        .collect::<Result<Vec<_>, CoreError>>()?;
    let views: Vec<_> = phases.iter().map(|(d, p)| (*d, p.view())).collect();
    let factors = ray_factors_from_sweep(&views, sensor.modulation_hz)?;
    fit_intrinsics(factors.view(), sensor.origin[0], sensor.origin[1])
}

/// Per-pixel phase of one sweep capture freed of the wiggling as `how` says; NaN where one of the
/// images used touches a rail (`≤ 0` or `≥ max_code`) or the amplitude is below
/// `min_amplitude_lsb`.
fn sweep_phase(
    cap: &SweepCapture<'_>,
    how: SweepPhase<'_>,
    max_code: f64,
    min_amplitude_lsb: f64,
) -> Result<Array2<f64>, CoreError> {
    let images: Vec<usize> = match how {
        SweepPhase::FirstHarmonic if cap.phases_deg.len() < MIN_HARMONIC_FREE_PHASES => {
            return Err(CoreError::InvalidData(format!(
                "lens calibration: the capture at {} m has {} phases; only captures with ≥ \
                 {MIN_HARMONIC_FREE_PHASES} equally spaced phases (a correlation capture) give a \
                 first-harmonic phase free of the wiggling (3rd/5th harmonics, thesis 3.3.6), \
                 which the lens would otherwise absorb",
                cap.distance_m,
                cap.phases_deg.len()
            )));
        }
        SweepPhase::FirstHarmonic => (0..cap.phases_deg.len()).collect(),
        SweepPhase::WigglingCorrected(lut) => quadrature_images(cap, lut)?.to_vec(),
    };
    let raw = cap.raw.select(ndarray::Axis(0), &images);
    let phases_deg: Vec<f64> = images.iter().map(|&k| cap.phases_deg[k]).collect();
    let (mut phase, amplitude) = crate::phasor::nphase_frame(raw.view(), &phases_deg)?;
    for ((r, c), p) in phase.indexed_iter_mut() {
        let clipped = raw
            .slice(ndarray::s![.., r, c])
            .iter()
            .any(|v| !(*v > 0.0 && *v < max_code));
        *p = match how {
            _ if clipped || amplitude[(r, c)] < min_amplitude_lsb => f64::NAN,
            SweepPhase::FirstHarmonic => *p,
            SweepPhase::WigglingCorrected(lut) => lut.correct(*p),
        };
    }
    Ok(phase)
}

/// Indices of the images at 0°, 90°, 180°, 270° of a capture (those of eq. 2.3), for the 4-phase
/// table `lut`; an error naming what is missing otherwise.
fn quadrature_images(cap: &SweepCapture<'_>, lut: &WigglingLut) -> Result<[usize; 4], CoreError> {
    if lut.algorithm != crate::Algorithm::FourPhase {
        return Err(CoreError::param(
            "wiggling",
            format!(
                "the lens fit corrects 4-phase walls and needs the 4phase table, got {}",
                lut.algorithm
            ),
        ));
    }
    let find = |want: f64| {
        cap.phases_deg.iter().position(|p| {
            let diff = (p - want).rem_euclid(360.0);
            diff.min(360.0 - diff) < 1e-6
        })
    };
    match [find(0.0), find(90.0), find(180.0), find(270.0)] {
        [Some(a), Some(b), Some(c), Some(d)] => Ok([a, b, c, d]),
        _ => Err(CoreError::InvalidData(format!(
            "lens calibration: the capture at {} m has no images at 0°, 90°, 180° and 270° \
             (phases {:?}°), which the 4-phase wiggling correction needs",
            cap.distance_m, cap.phases_deg
        ))),
    }
}

/// Passes of [`calibrate_intrinsics_with_wiggling`] at most: each re-extracts the wiggling table
/// through the lens of the previous one.
pub const JOINT_LENS_MAX_PASSES: usize = 4;

/// Bins of the 4-phase table [`calibrate_intrinsics_with_wiggling`] corrects the walls with: its
/// linear interpolation errs by `(2π h / bins)² / 8` of harmonic `h`'s amplitude, 2 µrad for a
/// 5th harmonic of 30 mrad (0.6 µm at 80 MHz), against 0.06 mrad with the pipeline's 256 bins —
/// which the lens would absorb. The table is the fit's own and is not stored.
pub const JOINT_LENS_LUT_SIZE: usize = 4096;

/// Result of [`calibrate_intrinsics_with_wiggling`].
#[derive(Debug, Clone, PartialEq)]
pub struct JointLensFit {
    /// The lens of the last pass, with its standard errors.
    pub fit: IntrinsicsFit,
    /// The 4-phase wiggling table the walls were corrected with in the last pass (through the
    /// lens of the pass before).
    pub wiggling: WigglingLut,
    /// Passes taken (table → lens, then table through that lens → lens, …).
    pub passes: usize,
    /// Largest change of a lens value in the last pass, in units of its standard error (the
    /// passes stop below 0.1).
    pub last_change_se: f64,
}

/// The lens from 4-phase walls when correlation captures exist at fewer than 3 distances (issue
/// 25): the wiggling table and the lens fitted jointly, by alternation. The 4-phase wiggling
/// table ([`crate::calib::extract_wiggling`] with the rays, thesis 3.3.7.2) is extracted from the
/// `correlation` capture, at first without a lens (the centre region's median: its pixels are
/// nearly on-axis), and corrects the 4-phase phase of every capture of `sweep` (their images at
/// 0°, 90°, 180°, 270°; the correlation capture may be one of them); the lens is fitted to those
/// phases ([`ray_factors_from_sweep`], [`fit_intrinsics`]); the table is extracted again through
/// that lens's rays and the lens fitted again, until no lens value moves by 0.1 of its standard
/// error (at most [`JOINT_LENS_MAX_PASSES`] passes). The table's anchoring (global delay) is one
/// constant for every capture, so it falls into each pixel's intercept, not its ray factor.
///
/// `sensor` is the window the captures were read from. Errors as [`calibrate_intrinsics`] (e.g.
/// walls at fewer than 3 distinct distances), and when the table cannot be extracted or a capture
/// lacks the four images.
pub fn calibrate_intrinsics_with_wiggling(
    correlation: &SweepCapture<'_>,
    sweep: &[SweepCapture<'_>],
    sensor: &crate::sensor::SensorGeometry,
    min_amplitude_lsb: f64,
) -> Result<JointLensFit, CoreError> {
    let fit_sensor = SweepSensor {
        adc_bits: sensor.adc_bits,
        modulation_hz: sensor.modulation_hz,
        min_amplitude_lsb,
        origin: sensor.roi_origin,
    };
    let (_, rows, cols) = correlation.raw.dim();
    let mut rays: Option<RayGrid> = None;
    let mut previous: Option<IntrinsicsFit> = None;
    let mut passes = 0;
    loop {
        passes += 1;
        let wiggling = crate::calib::extract_wiggling(
            correlation.raw,
            &crate::calib::ExtractionOptions::new(
                crate::Algorithm::FourPhase,
                correlation.phases_deg,
                correlation.distance_m,
                sensor.modulation_hz,
                sensor.adc_bits,
            )
            .rays(rays.as_ref())
            .lut_size(JOINT_LENS_LUT_SIZE),
        )?;
        let fit = fit_sweep(sweep, SweepPhase::WigglingCorrected(&wiggling), &fit_sensor)?;
        let last_change_se = previous.map_or(f64::INFINITY, |p| largest_change_se(&p, &fit));
        if last_change_se < 0.1 || passes == JOINT_LENS_MAX_PASSES {
            return Ok(JointLensFit {
                fit,
                wiggling,
                passes,
                last_change_se,
            });
        }
        let [row0, col0] = sensor.roi_origin;
        rays = Some(fit.intrinsics.rays(row0, col0, rows, cols)?);
        previous = Some(fit);
    }
}

/// Largest change of a fitted lens value between two fits, in units of the new fit's standard
/// error of that value (`k3` is held and never changes).
fn largest_change_se(before: &IntrinsicsFit, after: &IntrinsicsFit) -> f64 {
    let values = |k: &Intrinsics| {
        let d = k.distortion;
        [k.fx_px, k.fy_px, k.cx_px, k.cy_px, d.k1, d.k2, d.p1, d.p2]
    };
    let (a, b, se) = (
        values(&before.intrinsics),
        values(&after.intrinsics),
        values(&after.standard_errors),
    );
    (0..a.len())
        .map(|j| (b[j] - a[j]).abs() / se[j])
        .fold(0.0, f64::max)
}

/// Result of [`fit_intrinsics`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntrinsicsFit {
    /// The fitted intrinsics and distortion.
    pub intrinsics: Intrinsics,
    /// RMS of the ray-factor residual over the pixels used (dimensionless; `× d` is metres).
    pub rms_ray_factor: f64,
    /// Standard error of each fitted value, in the same fields (`k3` is held at 0: its error is
    /// 0): `σ_j = √(s² (JᵀJ)⁻¹_jj)` with `J` the Jacobian of the ray-factor residuals at the
    /// fit and `s²` the residual variance per degree of freedom.
    pub standard_errors: Intrinsics,
    /// Pixels used.
    pub pixels: usize,
    /// Levenberg–Marquardt iterations taken.
    pub iterations: usize,
}

/// Fits pinhole intrinsics and Brown–Conrady distortion to a window's ray factors (from
/// [`ray_factors_from_sweep`]; the window's first pixel is full-array `(row0, col0)`).
///
/// Model: `L(u, v) = √(1 + x² + y²)` with `(x, y)` the undistorted normalised coordinates of pixel
/// `(u, v)` ([`Intrinsics::undistort_pixel`]). Start: the no-distortion closed form
/// `L² − 1 = ((u − cx)/fx)² + ((v − cy)/fy)²`, a linear least-squares fit of
/// `A u² + B v² + C u + D v + E`; then Levenberg–Marquardt with a
/// numerical Jacobian over `fx, fy, cx, cy, k1, k2, p1, p2` (`k3` is held at 0, as OpenCV's
/// `CALIB_FIX_K3` for lenses that are not fisheyes; a datasheet may still supply it). Assumes the target is perpendicular to the optical axis (a tilt would read
/// as a principal-point shift). The window must see a good part of the field: the distortion is
/// only determined where there are pixels. Errors with fewer than 50 finite ray factors or when
/// the start cannot be formed (no curvature: the window is too small or the data is not a lens).
pub fn fit_intrinsics(
    ray_factor: ArrayView2<f64>,
    row0: usize,
    col0: usize,
) -> Result<IntrinsicsFit, CoreError> {
    // Observations (u, v, L), subsampled to ≤ ~12 000 pixels on a regular grid.
    let (rows, cols) = ray_factor.dim();
    let stride = ((rows * cols) as f64 / 12_000.0).sqrt().ceil().max(1.0) as usize;
    let mut obs: Vec<(f64, f64, f64)> = Vec::new();
    for r in (0..rows).step_by(stride) {
        for c in (0..cols).step_by(stride) {
            let l = ray_factor[(r, c)];
            // Physically L ≥ 1 (a ray is never shorter than the axis); far outside is a
            // mis-measured pixel (unwrap error, defect), not geometry.
            if l.is_finite() && (0.9..=10.0).contains(&l) {
                obs.push(((col0 + c) as f64, (row0 + r) as f64, l));
            }
        }
    }
    if obs.len() < 50 {
        return Err(CoreError::InvalidData(format!(
            "lens calibration: only {} pixels with a usable ray factor (need ≥ 50)",
            obs.len()
        )));
    }
    // Closed-form start (no distortion).
    let mut ata = Normal::zeros(5);
    for &(u, v, l) in &obs {
        ata.add(&[u * u, v * v, u, v, 1.0], l * l - 1.0, 1.0);
    }
    ata.symmetrize();
    let Some(&[a, b, c, d, _]) = solve_spd(&ata.jtj, &ata.jtr).as_deref() else {
        return Err(CoreError::InvalidData(
            "lens calibration: the ray factors are degenerate".into(),
        ));
    };
    if !(a > 0.0 && b > 0.0) {
        return Err(CoreError::InvalidData(format!(
            "lens calibration: the ray factors do not grow away from a centre (curvature {a:.3e}, \
             {b:.3e}): the window is too small or the sweep is not of a flat target"
        )));
    }
    let start = [
        1.0 / a.sqrt(),
        1.0 / b.sqrt(),
        -c / (2.0 * a),
        -d / (2.0 * b),
        0.0,
        0.0,
        0.0,
        0.0,
    ];
    // [fx, fy, cx, cy, k1, k2, p1, p2]; k3 stays 0 (OpenCV's CALIB_FIX_K3 advice for lenses that
    // are not fisheyes: over a field of normalised radius ≲ 1 the r⁶ term trades off against k1
    // and k2 and lets noise fold the polynomial inside the field).
    let to_intrinsics = |p: &[f64]| Intrinsics {
        fx_px: p[0],
        fy_px: p[1],
        cx_px: p[2],
        cy_px: p[3],
        distortion: Distortion {
            k1: p[4],
            k2: p[5],
            k3: 0.0,
            p1: p[6],
            p2: p[7],
        },
    };
    let f0 = start[0];
    let step = [
        1e-4 * f0,
        1e-4 * f0,
        1e-4 * f0,
        1e-4 * f0,
        1e-5,
        1e-5,
        1e-6,
        1e-6,
    ];
    // Stage 1, forward (never folds): a pixel whose ray factor says its undistorted radius is
    // ρ = √(L² − 1) must distort onto its own normalised position; the ray's direction is taken
    // from that position (exact without tangential terms, which stage 2 then refines).
    let forward = |p: &[f64], out: &mut Vec<f64>| -> bool {
        out.clear();
        let k = to_intrinsics(p);
        if k.validate().is_err() {
            return false;
        }
        for &(u, v, l) in &obs {
            let (xd, yd) = ((u - k.cx_px) / k.fx_px, (v - k.cy_px) / k.fy_px);
            let rd = xd.hypot(yd);
            let rho = (l * l - 1.0).max(0.0).sqrt();
            let (x, y) = if rd > 0.0 {
                (rho * xd / rd, rho * yd / rd)
            } else {
                (0.0, 0.0)
            };
            let (px, py) = k.distortion.distort(x, y);
            out.push(px - xd);
            out.push(py - yd);
        }
        true
    };
    let first = fit_residuals(forward, &start, &step, LENS_STOP).map_err(|_| {
        CoreError::InvalidData(format!(
            "lens calibration: the start is not a usable lens (closed-form start {start:?})"
        ))
    })?;
    // Stage 2, the model itself: L(u, v) = √(1 + x² + y²) of the undistorted pixel.
    let inverse = |p: &[f64], out: &mut Vec<f64>| -> bool {
        out.clear();
        let k = to_intrinsics(p);
        if k.validate().is_err() {
            return false;
        }
        for &(u, v, l) in &obs {
            match k.undistort_pixel(u, v) {
                Ok((x, y)) => out.push((1.0 + x * x + y * y).sqrt() - l),
                Err(_) => return false,
            }
        }
        true
    };
    let second = fit_residuals(inverse, &first.params, &step, LENS_STOP).map_err(|_| {
        CoreError::InvalidData(format!(
            "lens calibration: the distortion cannot be inverted at the forward stage's fit {:?}",
            to_intrinsics(&first.params)
        ))
    })?;
    let (p, cost) = (second.params, second.chi2);
    let intrinsics = to_intrinsics(&p);
    intrinsics.validate()?;
    let dof = obs.len().saturating_sub(8).max(1) as f64;
    let sigma = standard_errors(&p, &step, cost / dof, inverse)?;
    Ok(IntrinsicsFit {
        intrinsics,
        standard_errors: to_intrinsics(&sigma),
        rms_ray_factor: (cost / obs.len() as f64).sqrt(),
        pixels: obs.len(),
        iterations: first.iterations + second.iterations,
    })
}

/// When the lens fit's Levenberg–Marquardt stops: the cost (squared ray-factor or normalised
/// coordinate residuals) has no noise scale, so convergence is relative.
const LENS_STOP: Stop = Stop {
    max_iter: 200,
    tol_chi2: 0.0,
    rel_chi2: 1e-12,
};

/// Names of the lens fit's parameters, in the order of its parameter vector.
const LENS_PARAMETERS: [&str; 8] = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"];

/// Standard errors `σ_j = √(s² (JᵀJ)⁻¹_jj)` of a least-squares fit at `p` (residual variance
/// `s²` per degree of freedom). Refuses a design that cannot pin every parameter: `JᵀJ` scaled to
/// unit diagonal that is singular, or whose inverse has a diagonal entry (variance inflation
/// factor) above 1e10, means some combination of parameters leaves the residuals unchanged (rank
/// deficient: e.g. a window too small to see the distortion).
fn standard_errors(
    p: &[f64],
    step: &[f64],
    variance: f64,
    residuals: impl Fn(&[f64], &mut Vec<f64>) -> bool,
) -> Result<Vec<f64>, CoreError> {
    let n = p.len();
    let jtj = Normal::numerical(p, step, &residuals)
        .ok_or_else(|| {
            CoreError::InvalidData(
                "lens calibration: the distortion cannot be inverted near the fit".into(),
            )
        })?
        .jtj;
    let scale: Vec<f64> = (0..n).map(|j| jtj[j * n + j].sqrt()).collect();
    let unpinned = |j: usize| {
        CoreError::InvalidData(format!(
            "lens calibration: the data cannot pin {} (rank-deficient design: the ray factors do \
             not change with it independently of the other parameters); record the flat target \
             over the whole array at ≥ 3 distinct distances",
            LENS_PARAMETERS.get(j).copied().unwrap_or("a parameter")
        ))
    };
    if let Some(j) = (0..n).find(|&j| !(scale[j] > 0.0 && scale[j].is_finite())) {
        return Err(unpinned(j));
    }
    let corr: Vec<f64> = (0..n * n)
        .map(|i| jtj[i] / (scale[i / n] * scale[i % n]))
        .collect();
    let mut sigma = vec![0.0; n];
    for j in 0..n {
        let mut e = vec![0.0; n];
        e[j] = 1.0;
        let col = solve_spd(&corr, &e).ok_or_else(|| unpinned(j))?;
        // (JᵀJ)⁻¹_jj = C⁻¹_jj / scale_j²; a tiny or negative value means a near-null direction
        if !(col[j] > 0.0 && col[j] < 1e10) {
            return Err(unpinned(j));
        }
        sigma[j] = (variance * col[j]).sqrt() / scale[j];
    }
    Ok(sigma)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standard_errors_of_a_straight_line_match_the_textbook() {
        // y = a + b x with a known residual pattern: σ_b = s / √Σ(x − x̄)², σ_a = s √(Σx²/(n Σ(x − x̄)²))
        let xs: Vec<f64> = (0..20).map(|i| i as f64 * 0.5).collect();
        let ys: Vec<f64> = xs
            .iter()
            .enumerate()
            .map(|(i, x)| 1.0 + 2.0 * x + if i % 2 == 0 { 0.1 } else { -0.1 })
            .collect();
        let line = |p: &[f64], out: &mut Vec<f64>| {
            out.clear();
            out.extend(xs.iter().zip(&ys).map(|(x, y)| p[0] + p[1] * x - y));
            true
        };
        let fit = fit_residuals(line, &[0.0, 0.0], &[1e-6, 1e-6], LENS_STOP).unwrap();
        let (p, cost) = (fit.params, fit.chi2);
        let n = xs.len() as f64;
        let s2 = cost / (n - 2.0);
        let mean = xs.iter().sum::<f64>() / n;
        let sxx: f64 = xs.iter().map(|x| (x - mean).powi(2)).sum();
        let sx2: f64 = xs.iter().map(|x| x * x).sum();
        let se = standard_errors(&p, &[1e-6, 1e-6], s2, line).unwrap();
        assert!((se[1] / (s2 / sxx).sqrt() - 1.0).abs() < 1e-6, "{se:?}");
        assert!(
            (se[0] / (s2 * sx2 / (n * sxx)).sqrt() - 1.0).abs() < 1e-6,
            "{se:?}"
        );
    }

    #[test]
    fn standard_errors_refuse_a_parameter_the_data_cannot_pin() {
        // the residuals depend on p0 + p1 only: the design is rank deficient
        let sum = |p: &[f64], out: &mut Vec<f64>| {
            out.clear();
            out.extend((0..10).map(|i| p[0] + p[1] - f64::from(i)));
            true
        };
        let err = standard_errors(&[1.0, 2.0], &[1e-6, 1e-6], 1.0, sum).unwrap_err();
        assert!(err.to_string().contains("cannot pin"), "{err}");
        // and one that does not act at all
        let none = |p: &[f64], out: &mut Vec<f64>| {
            out.clear();
            out.extend((0..10).map(|i| p[0] - f64::from(i)));
            true
        };
        let err = standard_errors(&[1.0, 2.0], &[1e-6, 1e-6], 1.0, none).unwrap_err();
        assert!(err.to_string().contains("cannot pin fy"), "{err}");
    }
}
