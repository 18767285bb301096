//! Radiometry of the returned signal: how bright a real target at a given distance can be
//! (thesis 2.2.1: the return of a target at distance `d` falls as `1/d²`).
//!
//! For a diffuse (Lambertian) target of reflectivity `ρ` that fills a pixel's field of view at
//! radial distance `d`, the correlated amplitude the pixel measures (eq. 2.4, in LSB) is
//!
//! ```text
//! A = K · ρ · t_exp / d²
//! ```
//!
//! `K` (LSB·m²/µs, one value per pixel) holds the illumination power and pattern, the optics
//! (vignetting), the pixel's demodulation contrast and responsivity and the ADC gain. It is
//! calibrated once from a capture of a flat target at a known distance and reflectivity — the
//! wiggling (correlation) capture that every calibration already takes ([`AmplitudeScale::extract`]).
//!
//! The law is what keeps a phase that wrapped around the unambiguous range (eq. 2.7) from
//! reading as a target at a few centimetres: a wall at `d_u + d` returns `((d_u + d)/d)²` times
//! less than the same wall at `d`, far less than any target of reflectivity above a floor
//! (2 %, darker than black velvet paper) at `d`. [`flag_implausible_near`] flags such pixels.
//! With the floor `ρ_min`, a near reading at `d` and a wrapped one of a perfect reflector
//! (`ρ = 1`) at `d + d_u` can only be confused when `(d + d_u)/d ≤ 1/√ρ_min`, i.e. for
//! `d ≥ d_u / (1/√ρ_min − 1)` (309 mm at 80 MHz and 2 %): below that the decision is
//! physically unambiguous with a single modulation frequency.

use ndarray::{Array2, ArrayView2, ArrayView3, Zip};

use crate::CoreError;
use crate::frame::{DepthFrame, FLAG_IMPLAUSIBLE, FLAG_INVALID, FLAG_SATURATED, Roi};
use crate::pipeline::RawSample;

/// Darkest target reflectivity a proximity reading must still see (2 %: black velvet paper;
/// black cards and dark hair are ≥ 5 %).
pub const DEFAULT_REFLECTIVITY_FLOOR: f64 = 0.02;

/// Reflectivity assumed for the calibration target when its capture does not say: a perfect
/// diffuse reflector. This is the safe side for a calibration the scale is *derived* from: it
/// makes `K` a lower bound of the true scale, so a real target above the floor is never
/// rejected; a wrapped bright wall is still rejected unless the calibration target was darker
/// than `ρ_min · ((d_u + d)/(d + δ))²` (≈ 13 % at 100 mm, 80 MHz, 2 %) — no calibration target is.
pub const DEFAULT_CALIBRATION_REFLECTIVITY: f64 = 1.0;

/// Uncertainty of a measured depth used by the plausibility test (m): the near hypothesis is
/// tested at `d + δ`, so a target whose depth reads short by up to δ (calibration residual,
/// parallax at a few centimetres, multipath) is never rejected.
pub const DEFAULT_DEPTH_UNCERTAINTY_M: f64 = 0.03;

/// The background light's level in the raw images: the mean of (up to) the first four raw
/// images over `roi` (clipped to them) above the dark level `dark_lsb` (codes). The
/// correlated signal cancels in the sum of images a half period apart, so this is the
/// uncorrelated light the 4-phase evaluation removes (eq. 2.3) and the 2-phase one does not
/// (eq. 2.2) — thesis 5.1.2.3. 0 for an empty region.
pub fn common_mode_lsb<T: RawSample>(frames: ArrayView3<'_, T>, roi: Roi, dark_lsb: f32) -> f32 {
    let (_, rows, cols) = frames.dim();
    let (r, c) = roi.ranges_in((rows, cols));
    let mut sum = 0.0f64;
    let mut n = 0usize;
    for img in frames.axis_iter(ndarray::Axis(0)).take(4) {
        for &x in img.slice(ndarray::s![r.clone(), c.clone()]).iter() {
            sum += f64::from(x.to_f32());
            n += 1;
        }
    }
    if n == 0 {
        0.0
    } else {
        (sum / n as f64) as f32 - dark_lsb
    }
}

/// Expected amplitude (LSB) of a target of `reflectivity` at `distance_m` (thesis 2.2.1,
/// `A = K·ρ·t/d²`). Non-positive distances give `+∞` (a target at the sensor saturates).
pub fn expected_amplitude_lsb(
    scale_lsb_m2_per_us: f64,
    reflectivity: f64,
    exposure_us: f64,
    distance_m: f64,
) -> f64 {
    if distance_m <= 0.0 {
        return f64::INFINITY;
    }
    scale_lsb_m2_per_us * reflectivity * exposure_us / (distance_m * distance_m)
}

/// The scale `K = A·d²/(ρ·t)` (LSB·m²/µs) from one measured amplitude (the law above, solved
/// for `K`).
pub fn scale_from_amplitude(
    amplitude_lsb: f64,
    reflectivity: f64,
    exposure_us: f64,
    distance_m: f64,
) -> f64 {
    amplitude_lsb * distance_m * distance_m / (reflectivity * exposure_us)
}

/// Per-pixel amplitude scale `K` (LSB·m²/µs) of one sensor.
#[derive(Debug, Clone, PartialEq)]
pub struct AmplitudeScale {
    /// `K` per pixel, `(rows, cols)`, finite and ≥ 0.
    pub lsb_m2_per_us: Array2<f32>,
}

impl AmplitudeScale {
    /// Extract `K` from an N-phase correlation capture `(N, rows, cols)` (N ≥ 3 equally spaced
    /// phases, e.g. the 24 × 15° wiggling capture) of a flat target at radial `distance_m` with
    /// `reflectivity`, exposed `exposure_us` per image. The first-harmonic amplitude of the
    /// N-phase DFT (eq. 2.4 generalised, offset-free) is the `A` of the law.
    pub fn extract(
        samples: ArrayView3<f64>,
        phases_deg: &[f64],
        exposure_us: f64,
        distance_m: f64,
        reflectivity: f64,
    ) -> Result<Self, CoreError> {
        for (name, v) in [
            ("exposure_us", exposure_us),
            ("distance_m", distance_m),
            ("reflectivity", reflectivity),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(CoreError::param(
                    name,
                    format!("must be finite and > 0, got {v}"),
                ));
            }
        }
        if reflectivity > 1.0 {
            return Err(CoreError::param(
                "reflectivity",
                format!("a diffuse target reflects at most everything (≤ 1), got {reflectivity}"),
            ));
        }
        let (_, amplitude) = crate::phasor::nphase_frame(samples, phases_deg)?;
        if !amplitude.iter().any(|&a| a >= 0.5) {
            return Err(CoreError::InvalidData(
                "the capture has no signal: every pixel's amplitude is below half an LSB".into(),
            ));
        }
        let k = amplitude.mapv(|a| {
            if a.is_finite() {
                scale_from_amplitude(a, reflectivity, exposure_us, distance_m) as f32
            } else {
                0.0
            }
        });
        Ok(Self { lsb_m2_per_us: k })
    }

    /// The same `K` for every pixel of a `rows × cols` frame.
    pub fn uniform(rows: usize, cols: usize, lsb_m2_per_us: f32) -> Self {
        Self {
            lsb_m2_per_us: Array2::from_elem((rows, cols), lsb_m2_per_us.max(0.0)),
        }
    }
}

/// Parameters of [`flag_implausible_near`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NearPlausibility {
    /// Darkest reflectivity a real target may have ([`DEFAULT_REFLECTIVITY_FLOOR`]).
    pub reflectivity_floor: f64,
    /// Depth uncertainty δ (m) ([`DEFAULT_DEPTH_UNCERTAINTY_M`]).
    pub depth_uncertainty_m: f64,
    /// Only depths below this (m) are tested (the readings that can make or hold a near).
    pub check_below_m: f64,
}

/// Flag every valid pixel whose depth `d` is below `check_below_m` but whose amplitude is below
/// what a target of the floor reflectivity at `d + δ` returns (`K·ρ_min·t/(d + δ)²`): no real
/// target is there — the phase wrapped (a far bright target, eq. 2.7) or it is stray light.
/// Such pixels get [`FLAG_IMPLAUSIBLE`] | [`FLAG_INVALID`] and depth 0. Saturated pixels are left
/// alone (a target too close to measure). `scale` is `K` of the frame's pixels. Returns the
/// number of pixels flagged; a scale of another shape flags nothing and returns `None`.
pub fn flag_implausible_near(
    frame: &mut DepthFrame,
    scale: ArrayView2<f32>,
    exposure_us: f64,
    p: &NearPlausibility,
) -> Option<usize> {
    if scale.dim() != frame.dim() {
        return None;
    }
    let rho_t = (p.reflectivity_floor * exposure_us.max(0.0)) as f32;
    let delta = p.depth_uncertainty_m.max(0.0) as f32;
    let below = p.check_below_m as f32;
    let mut n = 0usize;
    Zip::from(&mut frame.flags)
        .and(&mut frame.depth_mm)
        .and(&mut frame.depth_m)
        .and(&frame.amplitude_lsb)
        .and(scale)
        .for_each(|f, mm, m, &a, &k| {
            if *f & (FLAG_INVALID | FLAG_SATURATED) != 0 || *m >= below {
                return;
            }
            let d = *m + delta;
            if a < k * rho_t / (d * d) {
                *f |= FLAG_IMPLAUSIBLE | FLAG_INVALID;
                *mm = 0;
                *m = 0.0;
                n += 1;
            }
        });
    Some(n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phasor::unambiguous_range_m;
    use ndarray::Array3;

    /// Two images a half period apart over a 2×2 region: their correlated parts cancel, the
    /// mean above the dark level is the background (40 LSB), pixels outside do not count.
    #[test]
    fn the_common_mode_is_the_background_above_the_dark_level() {
        let mut raw = Array3::<u16>::from_elem((2, 3, 3), 9000);
        for r in 0..2 {
            for c in 0..2 {
                let signal = 10 * (r * 2 + c) as u16;
                raw[[0, r, c]] = 2048 + 40 + signal;
                raw[[1, r, c]] = 2048 + 40 - signal;
            }
        }
        let roi = Roi {
            row0: 0,
            col0: 0,
            rows: 2,
            cols: 2,
        };
        assert_eq!(common_mode_lsb(raw.view(), roi, 2048.0), 40.0);
        let outside = Roi { row0: 5, ..roi };
        assert_eq!(common_mode_lsb(raw.view(), outside, 2048.0), 0.0);
    }

    #[test]
    fn law_and_its_inverse() {
        let a = expected_amplitude_lsb(2.0, 0.5, 100.0, 0.5);
        assert!((a - 400.0).abs() < 1e-9, "{a}");
        let k = scale_from_amplitude(a, 0.5, 100.0, 0.5);
        assert!((k - 2.0).abs() < 1e-12);
        assert!(expected_amplitude_lsb(2.0, 0.5, 100.0, 0.0).is_infinite());
        // 1/d²: twice the distance, a quarter of the amplitude
        let ratio =
            expected_amplitude_lsb(1.0, 1.0, 1.0, 0.2) / expected_amplitude_lsb(1.0, 1.0, 1.0, 0.4);
        assert!((ratio - 4.0).abs() < 1e-12);
    }

    #[test]
    fn unambiguous_below_309_mm_at_80_mhz() {
        let du = unambiguous_range_m(80e6);
        let limit = du / (1.0 / DEFAULT_REFLECTIVITY_FLOOR.sqrt() - 1.0);
        assert!((limit - 0.309).abs() < 0.001, "{limit}");
    }

    fn synth(amplitude: f64, phases: &[f64]) -> Array3<f64> {
        tofprox_testkit::frames::ideal_codes(0.7, amplitude, 2048.0, (3, 4), phases)
    }

    #[test]
    fn extract_from_a_correlation_capture() {
        let phases: Vec<f64> = (0..24).map(|i| 15.0 * f64::from(i)).collect();
        // K = 2 LSB m²/µs, ρ 0.8, 500 µs at 1 m → A = 800 LSB
        let s = synth(800.0, &phases);
        let k = AmplitudeScale::extract(s.view(), &phases, 500.0, 1.0, 0.8).expect("extract");
        assert!(
            k.lsb_m2_per_us.iter().all(|&v| (v - 2.0).abs() < 1e-4),
            "{k:?}"
        );
        assert!(AmplitudeScale::extract(s.view(), &phases, 500.0, 1.0, 1.5).is_err());
        assert!(AmplitudeScale::extract(s.view(), &phases, 0.0, 1.0, 0.8).is_err());
        let flat = synth(0.0, &phases);
        assert!(AmplitudeScale::extract(flat.view(), &phases, 500.0, 1.0, 0.8).is_err());
    }

    fn frame(depth_m: f32, amplitude: f32, flags: u8) -> DepthFrame {
        let mut f = DepthFrame::zeros(2, 2);
        f.depth_m.fill(depth_m);
        f.depth_mm.fill((depth_m * 1000.0) as u16);
        f.amplitude_lsb.fill(amplitude);
        f.flags.fill(flags);
        f
    }

    #[test]
    fn wrapped_wall_is_flagged_a_dark_near_card_is_not() {
        let (k, t) = (2.0f64, 100.0f64);
        let du = unambiguous_range_m(80e6);
        let p = NearPlausibility {
            reflectivity_floor: DEFAULT_REFLECTIVITY_FLOOR,
            depth_uncertainty_m: DEFAULT_DEPTH_UNCERTAINTY_M,
            check_below_m: 0.15,
        };
        let scale = Array2::from_elem((2, 2), k as f32);
        // a perfect reflector just beyond the range reads 76 mm
        let d = 1.95 - du;
        let a = expected_amplitude_lsb(k, 1.0, t, 1.95) as f32;
        let mut f = frame(d as f32, a, 0);
        assert_eq!(flag_implausible_near(&mut f, scale.view(), t, &p), Some(4));
        assert!(
            f.flags
                .iter()
                .all(|&x| x & FLAG_IMPLAUSIBLE != 0 && x & FLAG_INVALID != 0)
        );
        assert!(f.depth_mm.iter().all(|&x| x == 0));
        // a 5 % black card at 76 mm is far brighter
        let a = expected_amplitude_lsb(k, 0.05, t, d) as f32;
        let mut f = frame(d as f32, a, 0);
        assert_eq!(flag_implausible_near(&mut f, scale.view(), t, &p), Some(0));
        // a 2 % target at the floor reading δ short is kept
        let a = expected_amplitude_lsb(k, 0.02, t, 0.10 + 0.03) as f32;
        let mut f = frame(0.10, a * 1.001, 0);
        assert_eq!(flag_implausible_near(&mut f, scale.view(), t, &p), Some(0));
        // saturated pixels and depths beyond the check are left alone
        let mut f = frame(0.05, 0.0, FLAG_SATURATED);
        assert_eq!(flag_implausible_near(&mut f, scale.view(), t, &p), Some(0));
        let mut f = frame(0.5, 0.1, 0);
        assert_eq!(flag_implausible_near(&mut f, scale.view(), t, &p), Some(0));
        // a scale of another shape is refused
        let mut f = frame(0.05, 0.1, 0);
        assert_eq!(
            flag_implausible_near(&mut f, Array2::zeros((3, 3)).view(), t, &p),
            None
        );
    }
}
