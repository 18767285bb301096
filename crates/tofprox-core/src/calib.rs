//! Calibration extraction: offset/FPN (2.3.1.3, 3.3.7.1, 4.3.2.1), wiggling LUT (3.3.6, 3.3.7.2,
//! 4.3.2.2) and fixed-pattern phase noise (2.3.1.4).
//!
//! The order in which the pipeline applies them: offset (per raw image) → phase → wiggling LUT
//! (includes the global delay) → FPPN (pure per-pixel deviation, median-centred) → depth.

use crate::phasor::{self, wrap_phase, wrap_to_pi};
use crate::{Algorithm, CoreError};
use ndarray::{Array1, Array2, ArrayView3, Axis};
use std::f64::consts::{FRAC_PI_2, TAU};

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
    /// correction. Median-centred (median over the array is 0): the global delay lives in the
    /// wiggling LUT, this map holds only the pixel-to-pixel deviation.
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
        c0 + (c1 - c0) * frac
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
#[allow(clippy::too_many_arguments)]
pub fn extract_wiggling(
    correlation: ArrayView3<f64>,
    phases_deg: &[f64],
    offset: Option<&OffsetCalibration>,
    distance_m: f64,
    modulation_hz: f64,
    adc_bits: u8,
    algorithm: Algorithm,
    lut_size: usize,
) -> Result<WigglingLut, CoreError> {
    let _ = (
        correlation,
        phases_deg,
        offset,
        distance_m,
        modulation_hz,
        adc_bits,
        algorithm,
        lut_size,
    );
    let _ = (wrap_to_pi(0.0), FRAC_PI_2, phasor::wrap_phase(0.0));
    Err(CoreError::Calibration(
        "extract_wiggling: implementation in progress".into(),
    ))
}

/// Extracts the fixed-pattern phase noise (2.3.1.4) from a flat-target capture at known
/// `distance_m` (`capture`: `(K, rows, cols)` raw codes at `phases_deg`, which must contain the
/// images the `algorithm` needs: 0°, 90° (and 180°, 270°)).
///
/// Per pixel: offset correction, phase with `algorithm`, wiggling correction with `wiggling` (if
/// given), deviation `wrap_to_pi(corrected - 4π f d / c)`. The map is then **median-centred**
/// (the median deviation over all valid pixels is subtracted), so it holds only the
/// pixel-to-pixel deviation; the global delay belongs to the wiggling LUT. Pixels that are
/// saturated, non-finite or without signal get 0.
#[allow(clippy::too_many_arguments)]
pub fn extract_fppn(
    capture: ArrayView3<f64>,
    phases_deg: &[f64],
    offset: Option<&OffsetCalibration>,
    wiggling: Option<&WigglingLut>,
    distance_m: f64,
    modulation_hz: f64,
    adc_bits: u8,
    algorithm: Algorithm,
) -> Result<FppnMap, CoreError> {
    let _ = (
        capture,
        phases_deg,
        offset,
        wiggling,
        distance_m,
        modulation_hz,
        adc_bits,
        algorithm,
    );
    Err(CoreError::Calibration(
        "extract_fppn: implementation in progress".into(),
    ))
}
