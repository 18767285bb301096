//! Branch-free single-precision helpers for the vectorised pipeline.

use crate::simd::Lanes;
use crate::simd::generic::Arr;
use std::f32::consts::{FRAC_PI_2, PI, TAU};

/// Documented worst-case absolute error of [`fast_atan2_f32`] against `f64::atan2`, radians
/// (measured: about 1e-5 rad in the polynomial, plus f32 rounding; asserted by the tests).
/// 1e-4 rad is 0.06 mm of depth at 80 MHz.
pub const FAST_ATAN2_MAX_ERROR_RAD: f32 = 1e-4;

// Odd minimax polynomial for atan(t), t in [0, 1] (6 terms, |error| ≈ 1e-5 rad).
const A1: f32 = 0.999_977_26;
const A3: f32 = -0.332_623_47;
const A5: f32 = 0.193_543_46;
const A7: f32 = -0.116_432_87;
const A9: f32 = 0.052_653_32;
const A11: f32 = -0.011_721_2;

/// Fast `atan2(y, x)` mapped to `[0, 2π)` (eq. 2.2 needs the full-circle angle).
///
/// Absolute error at most [`FAST_ATAN2_MAX_ERROR_RAD`]. `atan2(0, 0)` returns 0. Non-finite
/// inputs give an unspecified (possibly NaN) result. (The pipeline does not use it: its kernel
/// reads the phase, with the wiggling correction, from a table over the octant and
/// `min/max(|x|, |y|)`; see [`crate::pipeline`].)
#[inline]
pub fn fast_atan2_f32(y: f32, x: f32) -> f32 {
    atan2_lanes(Arr::splat(y), Arr::splat(x)).0[0]
}

/// [`fast_atan2_f32`] on eight lanes (any [`Lanes`] implementation): branch-free (compares and selects only), one division,
/// a degree-11 odd polynomial, no fused multiply-add (so every instruction set rounds alike).
///
/// Written for a short dependency chain (the kernel is latency-bound otherwise): the polynomial
/// by Estrin's scheme (three independent pairs), and the octant mapping as one addition
/// `base ± atan(mn/mx)` whose base and sign come from compares of the inputs, off the chain.
#[inline(always)]
pub(crate) fn atan2_lanes<L: Lanes>(y: L, x: L) -> L {
    let ax = x.abs();
    let ay = y.abs();
    let mx = ax.max(ay);
    let mn = ax.min(ay);
    // mx == 0 only for the origin; divide by a tiny positive instead (gives t = 0).
    let t = mn.div(mx.max(L::splat(f32::MIN_POSITIVE)));
    let u = t.mul(t);
    let u2 = u.mul(u);
    let pair = |lo: f32, hi: f32| L::splat(hi).mul(u).add(L::splat(lo));
    let (q0, q1, q2) = (pair(A1, A3), pair(A5, A7), pair(A9, A11));
    let p = q0.add(u2.mul(q1.add(u2.mul(q2))));
    let a = p.mul(t); // atan(mn/mx) in [0, π/4]
    // Octant: swap (|y| > |x|) gives π/2 − a; then x < 0 reflects to π − ·; then y < 0 to 2π − ·.
    let zero = L::splat(0.0);
    let swap = ax.lt(ay);
    let (neg_x, neg_y) = (x.lt(zero), y.lt(zero));
    let base = L::select(swap, L::splat(FRAC_PI_2), zero);
    let base = L::select(neg_x, L::splat(PI).sub(base), base);
    let tau = L::splat(TAU);
    let base = L::select(neg_y, tau.sub(base), base);
    let minus = L::xor(L::xor(swap, neg_x), neg_y);
    let a = base.add(L::neg_where(minus, a));
    // 2π − (tiny) rounds to 2π; fold into [0, 2π).
    L::select(tau.le(a), a.sub(tau), a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_atan2_error_bound_dense_circle_and_radii() {
        let mut worst = 0.0f64;
        for r in [1e-3f64, 0.5, 1.0, 37.0, 2048.0, 1e6] {
            for i in 0..20_000 {
                let ang = std::f64::consts::TAU * (i as f64) / 20_000.0;
                let (y, x) = ((r * ang.sin()) as f32, (r * ang.cos()) as f32);
                let reference = (y as f64).atan2(x as f64).rem_euclid(std::f64::consts::TAU);
                let got = fast_atan2_f32(y, x) as f64;
                assert!(
                    (0.0..std::f64::consts::TAU).contains(&got),
                    "{got} out of [0, 2π)"
                );
                let mut d = (got - reference).abs();
                d = d.min(std::f64::consts::TAU - d); // circular distance
                worst = worst.max(d);
            }
        }
        assert!(
            worst <= FAST_ATAN2_MAX_ERROR_RAD as f64,
            "worst error {worst}"
        );
    }

    #[test]
    fn fast_atan2_axes_and_origin() {
        assert_eq!(fast_atan2_f32(0.0, 0.0), 0.0);
        assert!((fast_atan2_f32(0.0, 1.0)).abs() < 1e-6);
        assert!((fast_atan2_f32(1.0, 0.0) - FRAC_PI_2).abs() < 1e-6);
        assert!((fast_atan2_f32(0.0, -1.0) - PI).abs() < 1e-6);
        assert!((fast_atan2_f32(-1.0, 0.0) - 1.5 * PI).abs() < 1e-6);
        assert!(fast_atan2_f32(-0.0, 1.0) < TAU);
    }
}
