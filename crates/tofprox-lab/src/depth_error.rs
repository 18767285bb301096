//! How much of a comparison's depth error is systematic: its depth RMS error
//! ([`crate::diagnose::Rms`]) split into the noise floor the noise model predicts for the
//! same pixels and what is left above it (docs/lab.md, "How much of the depth error is
//! systematic").
//!
//! The noise floor propagates each raw code's noise σ_k (the fit's weights, 1/σ²) through
//! the phase estimate at the model's ideal codes u_k, to first order: for φ = atan2(y, x),
//! var φ = (y²·σx² + x²·σy²) / (x² + y²)², with x = u₀, y = u₉₀ (eq. 2.2) or
//! x = u₀ − u₁₈₀, y = u₉₀ − u₂₇₀ and σx² = σ₀² + σ₁₈₀², σy² = σ₉₀² + σ₂₇₀² (eq. 2.3). A
//! pixel's variance is capped at π²/3, that of a phase spread evenly over (−π, π] (where
//! the first order no longer holds: our assumption). Then
//! noise² = mean of var φ · (mm per rad)² over the pixels the depth RMS is taken over, and
//! systematic² = max(rms² − noise², 0), its share systematic² / rms².
use serde::Serialize;

use crate::arrays::depth_images;
use crate::{Comparison, Prepared};
use tofprox_core::Algorithm;

/// One algorithm's depth RMS error split into noise and systematic part (mm).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct DepthErrorSplit {
    /// The depth RMS error (the comparison's `rms.depth_*_mm`).
    pub rms_mm: f64,
    /// The noise floor: the RMS the noise model alone predicts for the same pixels.
    pub noise_mm: f64,
    /// √max(rms² − noise², 0): the part above the noise, the model's systematic error.
    pub systematic_mm: f64,
    /// systematic² / rms²: the share of the mean squared depth error that is systematic.
    pub systematic_share: f64,
}

impl DepthErrorSplit {
    fn of(rms_mm: f64, noise_mm: f64) -> Self {
        let sys2 = (rms_mm * rms_mm - noise_mm * noise_mm).max(0.0);
        Self {
            rms_mm,
            noise_mm,
            systematic_mm: sys2.sqrt(),
            systematic_share: sys2 / (rms_mm * rms_mm),
        }
    }
}

/// The split for 2-phase and 4-phase depth.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct DepthSplit {
    /// 2-phase (eq. 2.2).
    pub two_phase: DepthErrorSplit,
    /// 4-phase (eq. 2.3).
    pub four_phase: DepthErrorSplit,
}

/// The variance (rad²) of atan2(y, x) from those of x and y, to first order, capped at
/// π²/3.
fn phase_var(x: f64, y: f64, var_x: f64, var_y: f64) -> f64 {
    let r2 = x * x + y * y;
    let cap = std::f64::consts::PI.powi(2) / 3.0;
    if r2 > 0.0 {
        ((y * y * var_x + x * x * var_y) / (r2 * r2)).min(cap)
    } else {
        cap
    }
}

/// The split of `cmp`'s depth RMS errors: the noise floor over the pixels
/// [`crate::diagnose::depth_residuals`] takes them over (illuminated, used captures with a
/// distance, pixels the model does not saturate).
pub fn depth_split(prep: &Prepared, cmp: &Comparison) -> DepthSplit {
    let model = &cmp.model;
    let (mut v2, mut n2, mut v4, mut n4) = (0.0, 0usize, 0.0, 0usize);
    for (c, cap) in prep.caps.iter().enumerate() {
        if cap.distance_m.is_none() || !cap.used {
            continue;
        }
        let Some((alg, at)) = depth_images(cap) else {
            continue;
        };
        for p in 0..prep.npix {
            if model.sat[c * prep.npix + p] {
                continue;
            }
            // the model's ideal codes and their noise variances at the four images
            let mut u = [0.0; 4];
            let mut var = [0.0; 4];
            for (i, &k) in at.iter().enumerate() {
                let r = model.rec(prep, c, k, p);
                u[i] = r.x - model.offset[p];
                var[i] = 1.0 / r.w;
            }
            v2 += phase_var(u[0], u[1], var[0], var[1]);
            n2 += 1;
            if alg == Algorithm::FourPhase {
                v4 += phase_var(u[0] - u[2], u[1] - u[3], var[0] + var[2], var[1] + var[3]);
                n4 += 1;
            }
        }
    }
    let mmr = prep.mm_per_rad();
    let floor = |v: f64, n: usize| {
        if n > 0 {
            (v / n as f64).sqrt() * mmr
        } else {
            f64::NAN
        }
    };
    DepthSplit {
        two_phase: DepthErrorSplit::of(cmp.rms.depth_2phase_mm, floor(v2, n2)),
        four_phase: DepthErrorSplit::of(cmp.rms.depth_4phase_mm, floor(v4, n4)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first-order variance of atan2 against a Monte-Carlo of the angle itself, for a
    /// phasor at 50 LSB with unequal noise on its two axes.
    #[test]
    fn phase_variance_is_the_first_order_spread_of_the_angle() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let (x, y, sx, sy) = (30.0, 40.0, 2.0, 3.0);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = 200_000;
        let phi0 = f64::atan2(y, x);
        let mut s = 0.0;
        for _ in 0..n {
            let (gx, gy): (f64, f64) = (
                StandardNormal.sample(&mut rng),
                StandardNormal.sample(&mut rng),
            );
            let d = f64::atan2(y + sy * gy, x + sx * gx) - phi0;
            s += d * d;
        }
        let mc = s / n as f64;
        let lin = phase_var(x, y, sx * sx, sy * sy);
        // (40²·4 + 30²·9) / 50⁴ = 14500 / 6.25e6
        assert!((lin - 14_500.0 / 6.25e6).abs() < 1e-15);
        assert!(
            (mc / lin - 1.0).abs() < 0.02,
            "Monte-Carlo {mc} vs first order {lin}"
        );
        // no signal: the variance of an even spread, not infinity
        assert!((phase_var(0.0, 0.0, 1.0, 1.0) - std::f64::consts::PI.powi(2) / 3.0).abs() < 1e-15);
    }

    #[test]
    fn the_systematic_part_is_what_the_noise_does_not_explain() {
        let s = DepthErrorSplit::of(5.0, 3.0);
        assert!((s.systematic_mm - 4.0).abs() < 1e-12);
        assert!((s.systematic_share - 16.0 / 25.0).abs() < 1e-12);
        // an rms below the noise floor: nothing systematic
        let s = DepthErrorSplit::of(2.0, 3.0);
        assert_eq!((s.systematic_mm, s.systematic_share), (0.0, 0.0));
    }
}
