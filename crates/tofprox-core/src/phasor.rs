//! Scalar phasor math of the thesis (section 2.2.1, eqs. 2.2–2.9), `f64`, pure.
//!
//! Convention: `u_k = code_k - offset = A cos(phi - theta_k)` (see the crate docs), so the complex
//! phasor is `z = u0 + i u90` and `phi = arg z` wrapped to `[0, 2π)`.

use crate::{CoreError, SPEED_OF_LIGHT_M_PER_S};
use std::f64::consts::{PI, TAU};

/// Wraps any phase into `[0, 2π)`. Non-finite input gives NaN.
pub fn wrap_phase(phase_rad: f64) -> f64 {
    if !phase_rad.is_finite() {
        return f64::NAN;
    }
    let w = phase_rad.rem_euclid(TAU);
    // rem_euclid can round up to exactly TAU for tiny negative inputs.
    if w >= TAU { 0.0 } else { w }
}

/// Wraps any phase difference into `(-π, π]`. Non-finite input gives NaN.
pub fn wrap_to_pi(phase_rad: f64) -> f64 {
    let w = wrap_phase(phase_rad);
    if w > PI { w - TAU } else { w }
}

/// 2-phase phase, eq. 2.2: `atan2(u90, u0)` in `[0, 2π)` (`u` offset-corrected).
pub fn phase_2phase(u0: f64, u90: f64) -> f64 {
    wrap_phase(u90.atan2(u0)) // eq. 2.2
}

/// 4-phase phase, eq. 2.3: `atan2(u90 - u270, u0 - u180)` in `[0, 2π)`.
pub fn phase_4phase(u0: f64, u90: f64, u180: f64, u270: f64) -> f64 {
    wrap_phase((u90 - u270).atan2(u0 - u180)) // eq. 2.3
}

/// 2-phase amplitude `|z| = sqrt(u0² + u90²)` (the 2-phase form of eq. 2.4; equals `A`).
pub fn amplitude_2phase(u0: f64, u90: f64) -> f64 {
    u0.hypot(u90)
}

/// 4-phase amplitude, eq. 2.4: `sqrt((u90-u270)² + (u0-u180)²) / 2` (equals `A`).
pub fn amplitude_4phase(u0: f64, u90: f64, u180: f64, u270: f64) -> f64 {
    (u90 - u270).hypot(u0 - u180) / 2.0 // eq. 2.4
}

/// Intensity, eq. 2.5 exactly as printed in the thesis: `(u0 + u90 - u180 - u270) / 4`.
///
/// Note: with the convention `u_k = B + A cos(phi - theta_k)` the background `B` cancels in this
/// expression; the mean of the four samples, `(u0+u90+u180+u270)/4`, is what recovers `B`.
pub fn intensity_4phase(u0: f64, u90: f64, u180: f64, u270: f64) -> f64 {
    (u0 + u90 - u180 - u270) / 4.0 // eq. 2.5
}

/// N-phase phase and amplitude by a single-bin DFT for any equally spaced full-circle phase set
/// (`N ≥ 3`, any order, any start): `z = Σ u_k e^{i θ_k}`, `phi = arg z ∈ [0, 2π)`, `A = 2|z|/N`.
///
/// For `N = 4` at `[0, 90, 180, 270]°` this is exactly eq. 2.3 / 2.4. A common offset cancels for
/// every `N ≥ 2`; harmonics up to order `N - 2` cancel. Returns `None` when the lengths differ,
/// `N < 3`, any value is non-finite, or the phases are not an equally spaced full circle.
pub fn nphase(samples: &[f64], phases_rad: &[f64]) -> Option<(f64, f64)> {
    if samples.len() != phases_rad.len() || samples.len() < 3 {
        return None;
    }
    if samples.iter().chain(phases_rad).any(|v| !v.is_finite()) {
        return None;
    }
    if !is_equally_spaced_circle(phases_rad) {
        return None;
    }
    let (mut re, mut im) = (0.0, 0.0);
    for (&u, &th) in samples.iter().zip(phases_rad) {
        re += u * th.cos();
        im += u * th.sin();
    }
    let n = samples.len() as f64;
    Some((wrap_phase(im.atan2(re)), 2.0 * re.hypot(im) / n))
}

/// [`nphase`] for every pixel of a capture `(N, rows, cols)` (offset-corrected or raw codes: the
/// common offset cancels), `phases_deg` equally spaced over the full circle, `N ≥ 3`.
/// Returns `(phase_rad, amplitude)` arrays of shape `(rows, cols)`; non-finite pixels give NaN.
pub fn nphase_frame(
    samples: ndarray::ArrayView3<f64>,
    phases_deg: &[f64],
) -> Result<(ndarray::Array2<f64>, ndarray::Array2<f64>), CoreError> {
    let (n, rows, cols) = samples.dim();
    if n != phases_deg.len() || n < 3 {
        return Err(CoreError::ShapeMismatch {
            what: "N-phase capture",
            expected: format!("(N ≥ 3 matching {} phases, rows, cols)", phases_deg.len()),
            got: format!("{:?}", samples.dim()),
        });
    }
    let phases_rad: Vec<f64> = phases_deg.iter().map(|p| p.to_radians()).collect();
    if !is_equally_spaced_circle(&phases_rad) {
        return Err(CoreError::InvalidPhases {
            phases_deg: phases_deg.to_vec(),
            reason: "N-phase evaluation needs equally spaced phase shifts over the full circle"
                .into(),
        });
    }
    let mut re = ndarray::Array2::<f64>::zeros((rows, cols));
    let mut im = ndarray::Array2::<f64>::zeros((rows, cols));
    for (img, th) in samples.outer_iter().zip(&phases_rad) {
        let (c, s) = (th.cos(), th.sin());
        ndarray::Zip::from(&mut re)
            .and(&mut im)
            .and(&img)
            .for_each(|r, i, &u| {
                *r += u * c;
                *i += u * s;
            });
    }
    let scale = 2.0 / n as f64;
    let phase = ndarray::Zip::from(&re)
        .and(&im)
        .map_collect(|&r, &i| wrap_phase(i.atan2(r)));
    let amplitude = ndarray::Zip::from(&re)
        .and(&im)
        .map_collect(|&r, &i| scale * r.hypot(i));
    Ok((phase, amplitude))
}

/// True when `phases_rad` (any order) is `{θ0 + 2πj/N, j = 0..N}` within 1e-6 rad.
pub fn is_equally_spaced_circle(phases_rad: &[f64]) -> bool {
    let n = phases_rad.len();
    if n < 2 || phases_rad.iter().any(|p| !p.is_finite()) {
        return false;
    }
    let first = phases_rad[0];
    let step = TAU / n as f64;
    let mut seen = vec![false; n];
    for &p in phases_rad {
        let rel = wrap_phase(p - first) / step;
        let j = rel.round();
        if (rel - j).abs() * step > 1e-6 {
            return false;
        }
        let j = (j as usize) % n;
        if seen[j] {
            return false;
        }
        seen[j] = true;
    }
    true
}

/// Phase to distance, eq. 2.6: `d = c / (2 f) · φ / 2π`.
pub fn phase_to_distance_m(phase_rad: f64, modulation_hz: f64) -> f64 {
    SPEED_OF_LIGHT_M_PER_S / (2.0 * modulation_hz) * phase_rad / TAU // eq. 2.6
}

/// Distance to phase (eq. 2.6 inverted): `φ = 4π f d / c` (not wrapped).
pub fn distance_to_phase_rad(distance_m: f64, modulation_hz: f64) -> f64 {
    2.0 * TAU * modulation_hz * distance_m / SPEED_OF_LIGHT_M_PER_S
}

/// Unambiguous range, eq. 2.7: `d_u = c / (2 f)` (1.874 m at 80 MHz).
pub fn unambiguous_range_m(modulation_hz: f64) -> f64 {
    SPEED_OF_LIGHT_M_PER_S / (2.0 * modulation_hz) // eq. 2.7
}

/// Extended unambiguous range of two frequencies, eq. 2.8: `c / (2 |f1 - f2|)`.
///
/// Returns infinity when `f1 == f2` (no extension possible, caller must check).
pub fn extended_unambiguous_range_m(f1_hz: f64, f2_hz: f64) -> f64 {
    SPEED_OF_LIGHT_M_PER_S / (2.0 * (f1_hz - f2_hz).abs()) // eq. 2.8
}

/// Result of [`dual_frequency_distance`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DualFrequencyResult {
    /// Extended distance: the amplitude-weighted fusion (eq. 2.9) of both unwrapped distances.
    pub distance_m: f64,
    /// Unwrapped distance of frequency 1 (`d1 + n1 · d_u1`).
    pub distance1_m: f64,
    /// Unwrapped distance of frequency 2 (`d2 + n2 · d_u2`).
    pub distance2_m: f64,
    /// Number of whole unambiguous ranges added to frequency 1's distance.
    pub wraps1: u32,
    /// Number of whole unambiguous ranges added to frequency 2's distance.
    pub wraps2: u32,
    /// `|distance1_m - distance2_m|` of the chosen pair (consistency; small for a good solution).
    pub residual_m: f64,
}

/// Dual-frequency range extension (section 2.2.1, eq. 2.8 and fig. 2.3): adds whole unambiguous
/// ranges to both wrapped distances until they agree, searching all candidates below the extended
/// range `c / (2|f1 - f2|)` (or `max_range_m` if smaller) and choosing the pair with the smallest
/// disagreement; the two unwrapped distances are then fused with eq. 2.9 using the amplitudes.
///
/// Errors on non-finite or non-positive inputs, equal frequencies, or more than 10 000 candidates.
pub fn dual_frequency_distance(
    phase1_rad: f64,
    amplitude1: f64,
    f1_hz: f64,
    phase2_rad: f64,
    amplitude2: f64,
    f2_hz: f64,
    max_range_m: Option<f64>,
) -> Result<DualFrequencyResult, CoreError> {
    for (name, v) in [("f1_hz", f1_hz), ("f2_hz", f2_hz)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(CoreError::param(
                name,
                format!("must be finite and > 0, got {v}"),
            ));
        }
    }
    for (name, v) in [
        ("phase1_rad", phase1_rad),
        ("phase2_rad", phase2_rad),
        ("amplitude1", amplitude1),
        ("amplitude2", amplitude2),
    ] {
        if !v.is_finite() || (name.starts_with("amp") && v < 0.0) {
            return Err(CoreError::param(
                name,
                format!("must be finite (amplitude ≥ 0), got {v}"),
            ));
        }
    }
    if f1_hz == f2_hz {
        return Err(CoreError::param(
            "f2_hz",
            "must differ from f1_hz for range extension (eq. 2.8)",
        ));
    }
    let ext = extended_unambiguous_range_m(f1_hz, f2_hz); // eq. 2.8
    let limit = match max_range_m {
        Some(m) if m.is_finite() && m > 0.0 => m.min(ext),
        Some(m) => {
            return Err(CoreError::param(
                "max_range_m",
                format!("must be finite and > 0, got {m}"),
            ));
        }
        None => ext,
    };
    let du1 = unambiguous_range_m(f1_hz);
    let du2 = unambiguous_range_m(f2_hz);
    let d1 = phase_to_distance_m(wrap_phase(phase1_rad), f1_hz);
    let d2 = phase_to_distance_m(wrap_phase(phase2_rad), f2_hz);
    let n1_max = ((limit - d1) / du1).ceil().max(0.0);
    let n2_max = ((limit - d2) / du2).ceil().max(0.0);
    if n1_max > 10_000.0 || n2_max > 10_000.0 {
        return Err(CoreError::param(
            "max_range_m",
            "search would exceed 10 000 wraps; limit the range",
        ));
    }
    let mut best: Option<(f64, u32, u32)> = None;
    for n1 in 0..=(n1_max as u32) {
        let c1 = d1 + n1 as f64 * du1;
        if n1 > 0 && c1 >= limit {
            break; // beyond the extended range: aliases of a nearer solution
        }
        // Nearest candidates of frequency 2 to c1.
        let n2 = ((c1 - d2) / du2).round().clamp(0.0, n2_max) as u32;
        for n2c in [n2.saturating_sub(1), n2, n2 + 1] {
            let c2 = d2 + n2c as f64 * du2;
            let r = (c1 - c2).abs();
            // Strictly better by more than rounding noise: ties keep the nearer solution.
            if best.is_none_or(|(br, _, _)| r < br - 1e-9) {
                best = Some((r, n1, n2c));
            }
        }
    }
    let (residual_m, wraps1, wraps2) =
        best.ok_or_else(|| CoreError::InvalidData("no dual-frequency candidate".into()))?;
    let distance1_m = d1 + wraps1 as f64 * du1;
    let distance2_m = d2 + wraps2 as f64 * du2;
    let distance_m = weighted_distance_m(
        distance1_m,
        amplitude1,
        f1_hz,
        distance2_m,
        amplitude2,
        f2_hz,
    )
    .unwrap_or(0.5 * (distance1_m + distance2_m));
    Ok(DualFrequencyResult {
        distance_m,
        distance1_m,
        distance2_m,
        wraps1,
        wraps2,
        residual_m,
    })
}

/// Amplitude- and frequency-weighted fusion of two distances, eq. 2.9:
/// `d = d1 · A1 f1 / (A1 f1 + A2 f2) + d2 · A2 f2 / (A1 f1 + A2 f2)`.
///
/// `None` when the weight sum is zero or any input is non-finite.
pub fn weighted_distance_m(
    d1_m: f64,
    a1: f64,
    f1_hz: f64,
    d2_m: f64,
    a2: f64,
    f2_hz: f64,
) -> Option<f64> {
    let w1 = a1 * f1_hz;
    let w2 = a2 * f2_hz;
    let s = w1 + w2;
    let d = d1_m * w1 / s + d2_m * w2 / s; // eq. 2.9
    (s > 0.0 && d.is_finite()).then_some(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_edges() {
        assert_eq!(wrap_phase(0.0), 0.0);
        assert_eq!(wrap_phase(TAU), 0.0);
        assert!(wrap_phase(-1e-300) < TAU);
        assert!((wrap_phase(-0.5) - (TAU - 0.5)).abs() < 1e-15);
        assert!((wrap_to_pi(PI + 0.1) - (-PI + 0.1)).abs() < 1e-12);
        assert_eq!(wrap_to_pi(PI), PI);
        assert!(wrap_phase(f64::NAN).is_nan());
    }
}

/// The signal a raw image's phase shift `θ_k` is applied to (a recording's
/// `[sensor] phase_shift_applies_to`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ShiftedSignal {
    /// The demodulation (pixel gate) signal is delayed by `θ_k`: `u_k ∝ cos(φ − θ_k)` (2.2.1,
    /// the thesis's and tofprox's own convention).
    #[default]
    Demodulation,
    /// The illumination is delayed by `θ_k`; the return then arrives `φ + θ_k` after the gate:
    /// `u_k ∝ cos(φ + θ_k)`.
    Illumination,
}

/// How a raw image's recorded phase shift relates to the measured phase: the shifted signal and
/// the sign of the differential code (`+1`: `u = N_A − N_B` rises with the correlation, eq. 2.1;
/// `−1`: the read-out reports `N_B − N_A`). tofprox's canonical form is
/// `u_k = A·cos(φ − θ_k)` (demodulation, `+1`): every other convention is a relabelling of the
/// shifts, [`PhaseConvention::canonical_deg`] — the data are never changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PhaseConvention {
    /// Which signal `θ_k` delays.
    pub shifted: ShiftedSignal,
    /// `+1` or `−1`: sign of the differential code relative to the correlation.
    pub sign: i8,
}

impl Default for PhaseConvention {
    fn default() -> Self {
        PhaseConvention::CANONICAL
    }
}

impl PhaseConvention {
    /// tofprox's convention: demodulation shifted, `u = N_A − N_B`.
    pub const CANONICAL: PhaseConvention = PhaseConvention {
        shifted: ShiftedSignal::Demodulation,
        sign: 1,
    };

    /// Checks `sign ∈ {+1, −1}`.
    pub fn validate(&self) -> Result<(), crate::CoreError> {
        if self.sign == 1 || self.sign == -1 {
            Ok(())
        } else {
            Err(crate::CoreError::param(
                "phase_sign",
                format!("must be 1 or -1, got {}", self.sign),
            ))
        }
    }

    /// Whether this is the canonical convention.
    pub fn is_canonical(&self) -> bool {
        *self == PhaseConvention::CANONICAL
    }

    /// The canonical shift (degrees, in `[0, 360)`) of a raw image recorded with shift
    /// `label_deg` in this convention: the `θ_c` with `u = A·cos(φ − θ_c)`.
    /// Illumination: `cos(φ + θ) = cos(φ − (−θ))`, so `θ_c = −θ`; sign `−1`:
    /// `−cos(φ − θ) = cos(φ − (θ + 180°))`, so `θ_c = θ + 180°`.
    pub fn canonical_deg(&self, label_deg: f64) -> f64 {
        let t = match self.shifted {
            ShiftedSignal::Demodulation => label_deg,
            ShiftedSignal::Illumination => -label_deg,
        };
        let t = if self.sign < 0 { t + 180.0 } else { t };
        // (+ 0.0: a −0° label is written as 0°)
        t.rem_euclid(360.0) + 0.0
    }

    /// The label (degrees, in `[0, 360)`) a raw image of canonical shift `canonical_deg` carries
    /// in this convention (the inverse of [`PhaseConvention::canonical_deg`]).
    pub fn label_deg(&self, canonical_deg: f64) -> f64 {
        let t = if self.sign < 0 {
            canonical_deg - 180.0
        } else {
            canonical_deg
        };
        let t = match self.shifted {
            ShiftedSignal::Demodulation => t,
            ShiftedSignal::Illumination => -t,
        };
        // (+ 0.0: a −0° label is written as 0°)
        t.rem_euclid(360.0) + 0.0
    }
}

/// How far (degrees, modulo 360°) a recorded phase shift may lie from a nominal one and still
/// be that shift: `1e-3°`. Shifts reach tofprox through text, f32 radians and register LSB
/// products (a `π/2` stored as f32 radians is `90.0000025°`); `1e-3°` is `0.07 mm` at 60 MHz,
/// far below any depth the sensor resolves, and far below the smallest register step
/// (`360°/4096 ≈ 0.088°`) a deliberately different shift would have.
pub const SHIFT_TOLERANCE_DEG: f64 = 1e-3;

/// Whether shifts `a_deg` and `b_deg` are the same modulo 360° within
/// [`SHIFT_TOLERANCE_DEG`] (false for non-finite shifts).
pub fn same_shift_deg(a_deg: f64, b_deg: f64) -> bool {
    let d = (a_deg - b_deg).rem_euclid(360.0);
    d.min(360.0 - d) < SHIFT_TOLERANCE_DEG
}

/// Signs of the in-phase and quadrature parts of eqs. 2.2/2.3 for raw images whose canonical
/// shifts are `[a, b]` (2-phase) or `[a, b, a + 180°, b + 180°]` (4-phase) with `a ∈ {0°, 180°}`
/// and `b ∈ {90°, 270°}`: `x = s_x·u_a` (or `s_x·(u_a − u_{a+180})`), `y = s_y·u_b` (…), then
/// `φ = atan2(y, x)`. `u_180 = −u_0` and `u_270 = −u_90` for `u = A·cos(φ − θ)`, so a pair such as
/// `[0°, 270°]` (a `[0°, 90°]` capture of a sensor shifting its illumination) is eq. 2.2 with
/// `s_y = −1`. `[0°, 90°]` is `s_x = s_y = +1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Quadrature {
    /// `+1` when the in-phase image is at 0°, `−1` at 180°.
    pub x_sign: i8,
    /// `+1` when the quadrature image is at 90°, `−1` at 270°.
    pub y_sign: i8,
}

impl Default for Quadrature {
    fn default() -> Self {
        Quadrature::STANDARD
    }
}

impl Quadrature {
    /// Images at `[0°, 90°(, 180°, 270°)]`.
    pub const STANDARD: Quadrature = Quadrature {
        x_sign: 1,
        y_sign: 1,
    };

    /// The quadrature of raw images with canonical shifts `canonical_deg` for `algorithm`
    /// (its first 2 or 4 shifts are used), or `None` when they are not such a set.
    pub fn of_canonical(canonical_deg: &[f64], algorithm: crate::Algorithm) -> Option<Quadrature> {
        let n = algorithm.raw_images();
        let p = canonical_deg.get(..n)?;
        let near = same_shift_deg;
        let x_sign = if near(p[0], 0.0) {
            1
        } else if near(p[0], 180.0) {
            -1
        } else {
            return None;
        };
        let y_sign = if near(p[1], 90.0) {
            1
        } else if near(p[1], 270.0) {
            -1
        } else {
            return None;
        };
        if n == 4 && !(near(p[2], p[0] + 180.0) && near(p[3], p[1] + 180.0)) {
            return None;
        }
        Some(Quadrature { x_sign, y_sign })
    }
}
