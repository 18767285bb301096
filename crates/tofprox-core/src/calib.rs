//! Calibration extraction: offset/FPN (2.3.1.3, 3.3.7.1, 4.3.2.1), wiggling LUT (3.3.6, 3.3.7.2,
//! 4.3.2.2) and fixed-pattern phase noise (2.3.1.4).
//!
//! The order in which the pipeline applies them: offset (per raw image) → phase → wiggling LUT
//! (includes the global delay) → FPPN (per-pixel residual after that LUT) → depth.
//!
//! The order of extraction (thesis 5.1.3, `docs/calibration.md`): lens ([`crate::camera`]) →
//! offset → wiggling → FPPN. With the lens known ([`ExtractionOptions::rays`]), the extractions compare each
//! pixel with its own ray length to the flat target, so the FPPN map is the electrical per-pixel
//! delay only, not the lens geometry.

use crate::camera::{Plane, RayGrid};
use crate::phasor::{self, Quadrature, wrap_phase, wrap_to_pi};
use crate::sensor::{adc_max_code, adc_mid_code, validate_adc_bits, validate_modulation_hz};
use crate::{Algorithm, CoreError};
use ndarray::{Array1, Array2, ArrayView3, Axis};
use std::f64::consts::TAU;

/// Per-pixel dark level (FPN, thesis 2.3.1.3 / 3.3.7.1).
#[derive(Debug, Clone, PartialEq)]
pub struct OffsetCalibration {
    /// Per-pixel dark level in ADC codes **including** the mid code (≈ 2048 for 12 bit), shape
    /// `(rows, cols)`. The pipeline subtracts it from every raw image (eq. 3.4 inverted).
    pub dark_lsb: Array2<f32>,
}

/// Wiggling-correction lookup table (3.3.7.2), one per algorithm.
#[derive(Debug, Clone, PartialEq)]
pub struct WigglingLut {
    /// The algorithm whose measured phase this table corrects (2- and 4-phase differ, 3.3.7.2).
    pub algorithm: Algorithm,
    /// Correction over the MEASURED phase: bin `i` holds the correction at measured phase
    /// `2π i / N` (`N = len`). Values are continuous along the table (not wrapped, so linear
    /// interpolation across ±π is safe); `corrected = wrap(measured - correction(measured))`
    /// with linear periodic interpolation. Includes the global delay (anchored by `distance_m`).
    pub correction_rad: Array1<f32>,
}

/// Fixed pattern phase noise (2.3.1.4): per-pixel phase offset.
#[derive(Debug, Clone, PartialEq)]
pub struct FppnMap {
    /// Per-pixel phase deviation in radians, shape `(rows, cols)`, subtracted after the wiggling
    /// correction. **Absolute with respect to the wiggling LUT it was extracted with**: it is what
    /// remains of each pixel's phase error after that LUT. Because the LUT is anchored on the
    /// centre region and holds the global delay, the map's median over the centre is ≈ 0, i.e. it
    /// is the pixel-to-pixel deviation; it is not re-centred, so LUT + map together are exact for
    /// every pixel. Use it only with the same LUT (without a LUT it also carries the global delay).
    pub phase_offset_rad: Array2<f32>,
}

impl WigglingLut {
    /// Number of bins.
    pub fn len(&self) -> usize {
        self.correction_rad.len()
    }

    /// True when the table has no bins (never true for an extracted table).
    pub fn is_empty(&self) -> bool {
        self.correction_rad.is_empty()
    }

    /// Checks the table is usable: at least 2 bins and all values finite.
    pub fn validate(&self) -> Result<(), CoreError> {
        if self.correction_rad.len() < 2 {
            return Err(CoreError::Calibration(format!(
                "wiggling LUT needs at least 2 bins, has {}",
                self.correction_rad.len()
            )));
        }
        if self.correction_rad.iter().any(|v| !v.is_finite()) {
            return Err(CoreError::Calibration(
                "wiggling LUT contains non-finite values".into(),
            ));
        }
        Ok(())
    }

    /// Correction (radians) at a measured phase, linear periodic interpolation between bins.
    /// NaN for non-finite input or an empty table.
    pub fn correction_at(&self, measured_rad: f64) -> f64 {
        let n = self.correction_rad.len();
        if n == 0 || !measured_rad.is_finite() {
            return f64::NAN;
        }
        let x = wrap_phase(measured_rad) / TAU * n as f64;
        let i0 = (x.floor() as usize).min(n - 1);
        let frac = x - i0 as f64;
        let c0 = self.correction_rad[i0] as f64;
        let c1 = self.correction_rad[(i0 + 1) % n] as f64;
        // Difference wrapped so tables stored wrapped to (−π, π] interpolate correctly too.
        c0 + wrap_to_pi(c1 - c0) * frac
    }

    /// Applies the table: `wrap(measured - correction(measured))`, in `[0, 2π)`.
    pub fn correct(&self, measured_rad: f64) -> f64 {
        wrap_phase(measured_rad - self.correction_at(measured_rad))
    }
}

/// Extracts the per-pixel dark level from a dark capture `(K, rows, cols)` (illumination off):
/// the mean over the `K` images (thesis 4.3.2.1).
///
/// Errors on an empty capture or any non-finite value.
pub fn extract_offset(dark: ArrayView3<f64>) -> Result<OffsetCalibration, CoreError> {
    let (k, rows, cols) = dark.dim();
    if k == 0 || rows == 0 || cols == 0 {
        return Err(CoreError::shape(
            "dark capture",
            "(K ≥ 1, rows ≥ 1, cols ≥ 1)",
            format!("{:?}", dark.dim()),
        ));
    }
    if dark.iter().any(|v| !v.is_finite()) {
        return Err(CoreError::InvalidData(
            "dark capture contains non-finite values".into(),
        ));
    }
    let mean = dark
        .mean_axis(Axis(0))
        .ok_or_else(|| CoreError::InvalidData("empty dark capture".into()))?;
    Ok(OffsetCalibration {
        dark_lsb: mean.mapv(|v| v as f32),
    })
}

/// What a wiggling or FPPN extraction knows besides the capture's raw codes: the evaluation it
/// is for, the capture's phase shifts, the flat target's distance, the sensor's modulation and
/// ADC — and, each optional, the corrections it is made through: the dark frame ([`offset`]),
/// the wiggling table (FPPN only, [`wiggling`]), the lens ([`rays`], thesis 5.1.3), the sensor's
/// 2-phase pair ([`quadrature`]) and the table's size (wiggling only, [`lut_size`]).
///
/// ```
/// # use tofprox_core::{Algorithm, calib::ExtractionOptions};
/// # let phases: Vec<f64> = (0..24).map(|i| 15.0 * f64::from(i)).collect();
/// let options = ExtractionOptions::new(Algorithm::TwoPhase, &phases, 0.5, 80e6, 12).lut_size(256);
/// # let _ = options;
/// ```
///
/// [`offset`]: ExtractionOptions::offset
/// [`wiggling`]: ExtractionOptions::wiggling
/// [`rays`]: ExtractionOptions::rays
/// [`quadrature`]: ExtractionOptions::quadrature
/// [`lut_size`]: ExtractionOptions::lut_size
#[derive(Debug, Clone, Copy)]
pub struct ExtractionOptions<'a> {
    algorithm: Algorithm,
    phases_deg: &'a [f64],
    distance_m: f64,
    modulation_hz: f64,
    adc_bits: u8,
    offset: Option<&'a OffsetCalibration>,
    wiggling: Option<&'a WigglingLut>,
    rays: Option<&'a RayGrid>,
    quadrature: Quadrature,
    lut_size: usize,
}

/// Bins of a wiggling table unless [`ExtractionOptions::lut_size`] says otherwise.
pub const DEFAULT_LUT_SIZE: usize = 256;

impl<'a> ExtractionOptions<'a> {
    /// For `algorithm`, a capture at `phases_deg` of a flat target at `distance_m`
    /// (perpendicular to the optical axis), of a sensor at `modulation_hz` with `adc_bits`;
    /// no dark frame (the mid code is subtracted), no wiggling table, no lens, the standard
    /// 2-phase pair, [`DEFAULT_LUT_SIZE`] bins.
    pub fn new(
        algorithm: Algorithm,
        phases_deg: &'a [f64],
        distance_m: f64,
        modulation_hz: f64,
        adc_bits: u8,
    ) -> Self {
        Self {
            algorithm,
            phases_deg,
            distance_m,
            modulation_hz,
            adc_bits,
            offset: None,
            wiggling: None,
            rays: None,
            quadrature: Quadrature::STANDARD,
            lut_size: DEFAULT_LUT_SIZE,
        }
    }

    /// The dark frame to subtract (`None`: the mid code `2^(adc_bits-1)`).
    pub fn offset(mut self, offset: impl Into<Option<&'a OffsetCalibration>>) -> Self {
        self.offset = offset.into();
        self
    }

    /// FPPN: the wiggling table the phases are corrected with first (not used by the
    /// wiggling extraction).
    pub fn wiggling(mut self, wiggling: impl Into<Option<&'a WigglingLut>>) -> Self {
        self.wiggling = wiggling.into();
        self
    }

    /// After lens correction (thesis 5.1.3): the window's rays, so each pixel sees the flat
    /// target at its ray length `d / cos θ` ([`RayGrid::ray_lengths_m`]), not at `d`.
    /// Wiggling: each pixel's correlation is shifted back by its geometric phase excess
    /// `Δφ = 4πf (len − d) / c` (Fourier coefficient `X_h · e^{i h Δφ}`) before the median
    /// over the centre, so the table is the correlation of an on-axis pixel at `d` and holds
    /// the global delay without the lens geometry. FPPN: each pixel's expected phase is that
    /// of its own ray, `4πf · d / (c cos θ)`, so the map holds only the electrical per-pixel
    /// delay — without rays it also stores the lens geometry (decimetres at the corners of a
    /// wide lens) as if it were phase noise.
    pub fn rays(mut self, rays: impl Into<Option<&'a RayGrid>>) -> Self {
        self.rays = rays.into();
        self
    }

    /// The sensor's 2-phase pair (e.g. `[0°, 270°]` for one that shifts its illumination,
    /// [`crate::phasor::PhaseConvention`]): with harmonics in the correlation,
    /// `g(φ − 270°) ≠ −g(φ − 90°)`, so the 2-phase wiggling depends on which pair the sensor
    /// takes (eq. 2.2 with the signs of [`Quadrature`]); an FPPN capture must hold those
    /// shifts. 4-phase is the same for every quadrature (eq. 2.3 uses all four).
    pub fn quadrature(mut self, quadrature: Quadrature) -> Self {
        self.quadrature = quadrature;
        self
    }

    /// Wiggling: the number of bins over the measured phase (≥ 8).
    pub fn lut_size(mut self, lut_size: usize) -> Self {
        self.lut_size = lut_size;
        self
    }
}

/// Extracts a wiggling LUT from an N-phase correlation capture (thesis 3.3.6 / 3.3.7.2 / 4.3.2.2).
///
/// * `correlation`: `(N, rows, cols)` raw codes, `N ≥ 4` images at equally spaced `phases_deg`
///   (normally 24 at 15°), flat target at the known `distance_m`.
/// * `offset`: dark frame to subtract; without one the mid code `2^(adc_bits-1)` is subtracted.
/// * `algorithm`: which evaluation the table is for (2- and 4-phase tables differ).
/// * `lut_size`: number of bins over the measured phase (≥ 8).
///
/// Method: per pixel of the central region (the middle half of rows and columns), the captured
/// correlation `g(θ) = C(Φ0 - θ)` is Fourier-upsampled (exact trigonometric interpolation of the N
/// samples), normalised by its fundamental amplitude, and the per-coefficient median over the
/// region is taken (robust against noisy, saturated or defective pixels). A target at total phase
/// `Φ0 - s` would give raw values `g(s), g(s + 90°), …`: its measured phase `m(s)` is evaluated with
/// the algorithm (the correlation read at 90° shifts, as in the thesis), its true phase is
/// `φ0 - s` with `φ0 = 4π f d0 / c`, and `correction = m - true` (continuous). The monotone map
/// `s → m(s)` is inverted by linear interpolation to tabulate the correction over measured-phase
/// bins. Anchoring to `φ0` puts the global delay of driver and cabling into the table.
///
/// The capture's phases, distance, sensor and corrections are `options`'s ([`ExtractionOptions`]).
pub fn extract_wiggling(
    correlation: ArrayView3<f64>,
    options: &ExtractionOptions<'_>,
) -> Result<WigglingLut, CoreError> {
    let ExtractionOptions {
        algorithm,
        phases_deg,
        distance_m,
        modulation_hz,
        adc_bits,
        offset,
        rays,
        quadrature,
        lut_size,
        wiggling: _,
    } = *options;
    let (_, rows, cols) = correlation.dim();
    check_common(distance_m, modulation_hz, adc_bits)?;
    let excess = geometric_excess_rad(rays, rows, cols, distance_m, modulation_hz)?;
    let phases_rad = check_correlation_capture(correlation, phases_deg, lut_size)?;
    check_offset(offset, rows, cols)?;
    let coeffs = centre_correlation_coefficients(
        correlation,
        &phases_rad,
        offset,
        excess.as_ref(),
        adc_bits,
    )?;
    // Upsampled correlation on a grid of U points (U multiple of 4 so 90° is an index offset U/4,
    // as in the thesis' index-offset reading of the correlation).
    let upsampled = (4 * lut_size).max(2048).div_ceil(4) * 4;
    let measured = measured_phase_over_shift(&coeffs, upsampled, algorithm, quadrature);
    let mu = unwrap_one_turn(&measured, algorithm)?;
    // correction(measured) = measured − true, with true = φ0 − s (continuous along s).
    let phi0 = phasor::distance_to_phase_rad(distance_m, modulation_hz);
    let corr: Vec<f64> = (0..=upsampled)
        .map(|j| mu[j] - (phi0 - TAU * j as f64 / upsampled as f64))
        .collect();
    let table = tabulate_over_measured_phase(&mu, &corr, lut_size);
    // Common 2π shift so the first bin lies in (−π, π]; the table stays continuous.
    let shift = table[0] - wrap_to_pi(table[0]);
    let lut = WigglingLut {
        algorithm,
        correction_rad: Array1::from_iter(table.iter().map(|v| (v - shift) as f32)),
    };
    lut.validate()?;
    Ok(lut)
}

/// A correlation capture's shape (`(N ≥ 4, rows ≥ 1, cols ≥ 1)`, N matching the phases), its
/// phase shifts (equally spaced over the full circle, returned in radians) and the LUT size.
fn check_correlation_capture(
    correlation: ArrayView3<f64>,
    phases_deg: &[f64],
    lut_size: usize,
) -> Result<Vec<f64>, CoreError> {
    let (n, rows, cols) = correlation.dim();
    if n < 4 || n != phases_deg.len() {
        return Err(CoreError::shape(
            "correlation capture",
            format!("(N ≥ 4 matching {} phases, rows, cols)", phases_deg.len()),
            format!("{:?}", correlation.dim()),
        ));
    }
    if rows == 0 || cols == 0 {
        return Err(CoreError::shape(
            "correlation capture",
            "rows ≥ 1 and cols ≥ 1",
            format!("{:?}", correlation.dim()),
        ));
    }
    let phases_rad: Vec<f64> = phases_deg.iter().map(|p| p.to_radians()).collect();
    if !phasor::is_equally_spaced_circle(&phases_rad) {
        return Err(CoreError::InvalidPhases {
            phases_deg: phases_deg.to_vec(),
            reason:
                "a correlation capture needs N ≥ 4 equally spaced phase shifts over the full circle"
                    .into(),
        });
    }
    if !(8..=1 << 20).contains(&lut_size) {
        return Err(CoreError::param(
            "lut_size",
            format!("must be in 8..=1048576, got {lut_size}"),
        ));
    }
    Ok(phases_rad)
}

/// The correlation's Fourier coefficients over the centre region, normalised to the
/// fundamental and shifted back to the on-axis ray by the geometric `excess` phase: per pixel
/// X_h = (1/N) Σ_k g_k e^{-i h θ_k}, h = 0..=H (Nyquist term dropped for even N), so that
/// g(θ) = X_0 + Σ_h 2 Re(X_h e^{i h θ}) interpolates the captured correlation; combined by the
/// per-coefficient median (3.3.6 used the centre pixel).
fn centre_correlation_coefficients(
    correlation: ArrayView3<f64>,
    phases_rad: &[f64],
    offset: Option<&OffsetCalibration>,
    excess: Option<&Array2<f64>>,
    adc_bits: u8,
) -> Result<Vec<(f64, f64)>, CoreError> {
    let (n, rows, cols) = correlation.dim();
    let mid = f64::from(adc_mid_code(adc_bits));
    let max_code = f64::from(adc_max_code(adc_bits));
    let harmonics = (n - 1) / 2;
    let (r0, r1) = centre_range(rows);
    let (c0, c1) = centre_range(cols);
    let mut per_coeff: Vec<Vec<f64>> = vec![Vec::new(); 2 * (harmonics + 1)];
    let mut samples = vec![0.0; n];
    let basis = dft_basis(phases_rad, harmonics);
    for r in r0..r1 {
        for c in c0..c1 {
            let dark = offset.map_or(mid, |o| o.dark_lsb[(r, c)] as f64);
            let mut ok = true;
            for (k, s) in samples.iter_mut().enumerate() {
                let code = correlation[(k, r, c)];
                ok &= code.is_finite() && code > 0.0 && code < max_code;
                *s = code - dark;
            }
            if !ok {
                continue;
            }
            let coeffs = dft_coefficients(&samples, &basis);
            let fundamental = coeffs[1].0.hypot(coeffs[1].1);
            // Pixels without a usable fundamental (dead / dark) carry no wiggling information.
            if !(fundamental.is_finite() && fundamental > 0.5) {
                continue;
            }
            // Shift the pixel's correlation back to the on-axis ray: X_h · e^{i h Δφ}.
            let delta = excess.map_or(0.0, |e| e[(r, c)]);
            for (h, (re, im)) in coeffs.iter().enumerate() {
                let (s, co) = (h as f64 * delta).sin_cos();
                per_coeff[2 * h].push((re * co - im * s) / fundamental);
                per_coeff[2 * h + 1].push((re * s + im * co) / fundamental);
            }
        }
    }
    if per_coeff[0].is_empty() {
        return Err(CoreError::InvalidData(format!(
            "correlation capture: no usable pixel in the centre region rows {r0}..{r1}, cols {c0}..{c1} \
             (all saturated, non-finite or without signal)"
        )));
    }
    Ok((0..=harmonics)
        .map(|h| {
            (
                median(&mut per_coeff[2 * h]),
                median(&mut per_coeff[2 * h + 1]),
            )
        })
        .collect())
}

/// The phase `algorithm` measures for a target at total phase Φ0 − s_j, at each of the
/// `upsampled` shifts s_j of the interpolated correlation `coeffs` (its raw values are
/// g(s_j + θ_k); the 2-phase pair's canonical shifts from `quadrature`: in-phase at 0° or
/// 180°, quadrature at 90° or 270°).
fn measured_phase_over_shift(
    coeffs: &[(f64, f64)],
    upsampled: usize,
    algorithm: Algorithm,
    quadrature: Quadrature,
) -> Vec<f64> {
    let grid: Vec<f64> = (0..upsampled)
        .map(|j| eval_trig(coeffs, TAU * j as f64 / upsampled as f64))
        .collect();
    let q = upsampled / 4;
    let at = |j: usize| grid[j % upsampled];
    let (ja, sx) = if quadrature.x_sign < 0 {
        (2 * q, -1.0)
    } else {
        (0, 1.0)
    };
    let (jb, sy) = if quadrature.y_sign < 0 {
        (3 * q, -1.0)
    } else {
        (q, 1.0)
    };
    (0..upsampled)
        .map(|j| match algorithm {
            Algorithm::TwoPhase => phasor::phase_2phase(sx * at(j + ja), sy * at(j + jb)), // eq. 2.2
            Algorithm::FourPhase => {
                phasor::phase_4phase(at(j), at(j + q), at(j + 2 * q), at(j + 3 * q))
            } // eq. 2.3
        })
        .collect()
}

/// Unwrap the measured phase along the shift: it must decrease monotonically by exactly one
/// turn (`U + 1` values, the last one turn below the first).
fn unwrap_one_turn(measured: &[f64], algorithm: Algorithm) -> Result<Vec<f64>, CoreError> {
    let upsampled = measured.len();
    let mut mu = Vec::with_capacity(upsampled + 1);
    mu.push(measured[0]);
    for j in 1..=upsampled {
        let prev = mu[j - 1];
        let step = wrap_to_pi(measured[j % upsampled] - measured[j - 1]);
        if step.is_nan() || step >= 0.0 {
            return Err(CoreError::Calibration(format!(
                "{algorithm} measured phase is not monotone over the correlation (at shift {:.2}°): \
                 correlation too distorted or too noisy for a wiggling LUT",
                360.0 * j as f64 / upsampled as f64
            )));
        }
        mu.push(prev + step);
    }
    if (mu[upsampled] - (mu[0] - TAU)).abs() > 1e-6 {
        return Err(CoreError::Calibration(
            "measured phase does not wind exactly once over the correlation".into(),
        ));
    }
    Ok(mu)
}

/// Invert the monotone map s → m(s) by linear interpolation: the correction `corr` tabulated
/// over `lut_size` bins of measured phase (`mu` strictly decreasing over one turn).
fn tabulate_over_measured_phase(mu: &[f64], corr: &[f64], lut_size: usize) -> Vec<f64> {
    let upsampled = mu.len() - 1;
    (0..lut_size)
        .map(|i| {
            let p = TAU * i as f64 / lut_size as f64;
            // Representative of p in (mu_U, mu_0].
            let qv = p - TAU * ((p - mu[0]) / TAU).ceil();
            // First index with mu[j] < qv (mu is strictly decreasing).
            let j1 = mu.partition_point(|&m| m >= qv).clamp(1, upsampled);
            let j0 = j1 - 1;
            let t = (mu[j0] - qv) / (mu[j0] - mu[j1]);
            corr[j0] + (corr[j1] - corr[j0]) * t
        })
        .collect()
}

/// Extracts the fixed-pattern phase noise (2.3.1.4) from a flat-target capture at known
/// `distance_m` (`capture`: `(K, rows, cols)` raw codes at `phases_deg`, which must contain the
/// images the `algorithm` needs: 0°, 90° (and 180°, 270°)).
///
/// Per pixel: offset correction, phase with `algorithm`, wiggling correction with `wiggling` (if
/// given), deviation `wrap_to_pi(corrected - 4π f d / c)`. The map is **absolute** with respect to
/// the given LUT (not re-centred): the global delay belongs to the wiggling LUT, so with an
/// anchored LUT the map is the pure per-pixel deviation (median over the centre ≈ 0), and LUT + map
/// are consistent for every pixel (re-centring on the whole-array median would re-introduce a
/// global offset whenever the array median differs from the centre's). Pixels that are saturated,
/// non-finite or without signal get 0.
///
/// The capture's phases, distance, sensor and corrections are `options`'s ([`ExtractionOptions`]; its
/// `lut_size` is not used).
pub fn extract_fppn(
    capture: ArrayView3<f64>,
    options: &ExtractionOptions<'_>,
) -> Result<FppnMap, CoreError> {
    let ExtractionOptions {
        algorithm,
        phases_deg,
        distance_m,
        modulation_hz,
        adc_bits,
        offset,
        wiggling,
        rays,
        quadrature,
        lut_size: _,
    } = *options;
    let (k, rows, cols) = capture.dim();
    check_common(distance_m, modulation_hz, adc_bits)?;
    let excess = geometric_excess_rad(rays, rows, cols, distance_m, modulation_hz)?;
    if k != phases_deg.len() || rows == 0 || cols == 0 {
        return Err(CoreError::shape(
            "FPPN capture",
            format!("({} phases, rows ≥ 1, cols ≥ 1)", phases_deg.len()),
            format!("{:?}", capture.dim()),
        ));
    }
    check_offset(offset, rows, cols)?;
    if let Some(w) = wiggling {
        if w.algorithm != algorithm {
            return Err(CoreError::Calibration(format!(
                "wiggling LUT is for {} but FPPN extraction uses {algorithm}",
                w.algorithm
            )));
        }
        w.validate()?;
    }
    let idx = quadrature_indices(phases_deg, algorithm, quadrature)?;
    let used = algorithm.raw_images();
    let (sx, sy) = (f64::from(quadrature.x_sign), f64::from(quadrature.y_sign));
    let mid = f64::from(adc_mid_code(adc_bits));
    let max_code = f64::from(adc_max_code(adc_bits));
    let phi_true = wrap_phase(phasor::distance_to_phase_rad(distance_m, modulation_hz));
    let mut deviation = Array2::<f64>::from_elem((rows, cols), f64::NAN);
    for r in 0..rows {
        for c in 0..cols {
            let dark = offset.map_or(mid, |o| o.dark_lsb[(r, c)] as f64);
            let mut u = [0.0; 4];
            let mut ok = true;
            for (slot, &ki) in u.iter_mut().zip(&idx).take(used) {
                let code = capture[(ki, r, c)];
                ok &= code.is_finite() && code > 0.0 && code < max_code;
                *slot = code - dark;
            }
            if !ok {
                continue;
            }
            let (measured, amplitude) = match algorithm {
                Algorithm::TwoPhase => (
                    phasor::phase_2phase(sx * u[0], sy * u[1]),
                    phasor::amplitude_2phase(u[0], u[1]),
                ),
                Algorithm::FourPhase => (
                    phasor::phase_4phase(sx * u[0], sy * u[1], sx * u[2], sy * u[3]),
                    phasor::amplitude_4phase(u[0], u[1], u[2], u[3]),
                ),
            };
            if amplitude.is_nan() || amplitude <= 1.0 {
                continue;
            }
            let corrected = wiggling.map_or(measured, |w| w.correct(measured));
            let expected = phi_true + excess.as_ref().map_or(0.0, |e| e[(r, c)]);
            deviation[(r, c)] = wrap_to_pi(corrected - expected);
        }
    }
    if !deviation.iter().any(|v| v.is_finite()) {
        return Err(CoreError::InvalidData(
            "FPPN capture: no usable pixel (all saturated, non-finite or without signal)".into(),
        ));
    }
    Ok(FppnMap {
        phase_offset_rad: deviation.mapv(|v| if v.is_finite() { v as f32 } else { 0.0 }),
    })
}

/// Per-pixel geometric phase excess `4πf (len − d) / c` of a flat target at `distance_m`
/// perpendicular to the optical axis, `len` the pixel's ray length (`None` without rays).
fn geometric_excess_rad(
    rays: Option<&RayGrid>,
    rows: usize,
    cols: usize,
    distance_m: f64,
    modulation_hz: f64,
) -> Result<Option<Array2<f64>>, CoreError> {
    let Some(rays) = rays else {
        return Ok(None);
    };
    if rays.dim() != (rows, cols) {
        return Err(CoreError::shape(
            "lens rays",
            format!("({rows}, {cols})"),
            format!("{:?}", rays.dim()),
        ));
    }
    let lengths = rays.ray_lengths_m(&Plane::fronto_parallel(distance_m));
    if let Some(((r, c), _)) = lengths.indexed_iter().find(|(_, v)| !v.is_finite()) {
        return Err(CoreError::Calibration(format!(
            "the ray of pixel (row {r}, col {c}) does not reach a target in front of the camera"
        )));
    }
    Ok(Some(lengths.mapv(|len| {
        phasor::distance_to_phase_rad(len - distance_m, modulation_hz)
    })))
}

fn check_common(distance_m: f64, modulation_hz: f64, adc_bits: u8) -> Result<(), CoreError> {
    if !(distance_m.is_finite() && distance_m >= 0.0) {
        return Err(CoreError::param(
            "distance_m",
            format!("must be finite and ≥ 0, got {distance_m}"),
        ));
    }
    validate_modulation_hz(modulation_hz)?;
    validate_adc_bits(adc_bits)
}

/// The dark frame (if any) matches `rows × cols` and is finite.
pub(crate) fn check_offset(
    offset: Option<&OffsetCalibration>,
    rows: usize,
    cols: usize,
) -> Result<(), CoreError> {
    if let Some(o) = offset {
        if o.dark_lsb.dim() != (rows, cols) {
            return Err(CoreError::shape(
                "offset calibration (dark_lsb)",
                format!("({rows}, {cols})"),
                format!("{:?}", o.dark_lsb.dim()),
            ));
        }
        if o.dark_lsb.iter().any(|v| !v.is_finite()) {
            return Err(CoreError::Calibration(
                "offset calibration contains non-finite values".into(),
            ));
        }
    }
    Ok(())
}

/// Indices of the images at 0°, 90° (, 180°, 270°) within `phases_deg` (first match, within
/// [`crate::phasor::SHIFT_TOLERANCE_DEG`] modulo 360°). For 2-phase the last two slots are 0 and unused.
pub fn algorithm_indices(
    phases_deg: &[f64],
    algorithm: Algorithm,
) -> Result<[usize; 4], CoreError> {
    quadrature_indices(phases_deg, algorithm, Quadrature::STANDARD)
}

/// [`algorithm_indices`] for the images of `quadrature`: in-phase at 0° (180° when
/// `x_sign < 0`), quadrature at 90° (270°), then the two opposite ones (4-phase).
pub fn quadrature_indices(
    phases_deg: &[f64],
    algorithm: Algorithm,
    quadrature: Quadrature,
) -> Result<[usize; 4], CoreError> {
    let a = if quadrature.x_sign < 0 { 180.0 } else { 0.0 };
    let b = if quadrature.y_sign < 0 { 270.0 } else { 90.0 };
    let wanted = [a, b, (a + 180.0) % 360.0, (b + 180.0) % 360.0];
    let mut out = [0usize; 4];
    for (slot, want) in out.iter_mut().zip(&wanted[..algorithm.raw_images()]) {
        *slot = phases_deg
            .iter()
            .position(|p| crate::phasor::same_shift_deg(*p, *want))
            .ok_or_else(|| CoreError::InvalidPhases {
                phases_deg: phases_deg.to_vec(),
                reason: format!("{algorithm} needs an image at {want}°"),
            })?;
    }
    Ok(out)
}

/// Central half `[start, start + max(n/2, 1))` of an axis of length `n ≥ 1`.
fn centre_range(n: usize) -> (usize, usize) {
    let len = (n / 2).max(1);
    let start = (n - len) / 2;
    (start, start + len)
}

/// DFT basis `(cos hθ_k, sin hθ_k) / N` for `h = 0..=harmonics`, row-major by `h`.
fn dft_basis(phases_rad: &[f64], harmonics: usize) -> Vec<(f64, f64)> {
    let n = phases_rad.len() as f64;
    (0..=harmonics)
        .flat_map(|h| {
            phases_rad
                .iter()
                .map(move |&th| ((h as f64 * th).cos() / n, (h as f64 * th).sin() / n))
        })
        .collect()
}

/// `X_h = (1/N) Σ_k g_k e^{-i h θ_k}` for every `h` of `basis` (see [`dft_basis`]), as (re, im).
fn dft_coefficients(samples: &[f64], basis: &[(f64, f64)]) -> Vec<(f64, f64)> {
    basis
        .chunks(samples.len().max(1))
        .map(|row| {
            let (mut re, mut im) = (0.0, 0.0);
            for (&g, &(c, s)) in samples.iter().zip(row) {
                re += g * c;
                im -= g * s;
            }
            (re, im)
        })
        .collect()
}

/// Trigonometric interpolant `g(θ) = X_0 + Σ_{h≥1} 2 Re(X_h e^{i h θ})`.
fn eval_trig(coeffs: &[(f64, f64)], theta: f64) -> f64 {
    let mut g = coeffs.first().map_or(0.0, |c| c.0);
    for (h, &(re, im)) in coeffs.iter().enumerate().skip(1) {
        let a = h as f64 * theta;
        g += 2.0 * (re * a.cos() - im * a.sin());
    }
    g
}

/// Median (mean of the two middle values for even length); NaN for empty input.
fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_unstable_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}
