//! The kernel's phase table (module docs of [`super`], *Phase table*): `atan2` by octant and
//! `t = min/max`, with the wiggling correction folded in.

use crate::calib::WigglingLut;
use crate::phasor::{self, wrap_to_pi};
use crate::simd::{LUT_BINS, LUT_T_BINS, Lut};
use std::f32::consts::TAU;

/// Octant bits of a phase-table index (above the `t` bin): `|y| > |x|`, `x < 0`, `y < 0`.
pub(super) const OCTANT_SWAP: u32 = LUT_T_BINS as u32;
pub(super) const OCTANT_NEG_X: u32 = 2 * LUT_T_BINS as u32;
pub(super) const OCTANT_NEG_Y: u32 = 4 * LUT_T_BINS as u32;

/// The phase (eqs. 2.2 / 2.3, `[0, 2π)`) of the octant bits `octant` (a multiple of
/// [`LUT_T_BINS`]) and `t = min(|x|, |y|) / max(|x|, |y|)`.
fn octant_phase_rad(octant: u32, t: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI, TAU};
    let a = t.atan();
    let a = if octant & OCTANT_SWAP != 0 {
        FRAC_PI_2 - a
    } else {
        a
    };
    let a = if octant & OCTANT_NEG_X != 0 {
        PI - a
    } else {
        a
    };
    let a = if octant & OCTANT_NEG_Y != 0 {
        TAU - a
    } else {
        a
    };
    phasor::wrap_phase(a)
}

/// The kernel's phase table (module docs, *Phase table*): per octant and `t` bin the corrected
/// phase `wrap(φ − LUT(φ))` in `[0, 2π)` (just `φ` without a wiggling table) at the bin's start,
/// and its change to the next bin wrapped to `(−π, π]`, computed in `f64`.
pub(super) fn phase_table(wiggling: Option<&WigglingLut>) -> Box<Lut> {
    let corrected = |octant: u32, k: usize| {
        let phi = octant_phase_rad(octant, k as f64 / LUT_T_BINS as f64);
        wiggling.map_or(phi, |w| w.correct(phi))
    };
    let mut lut = Box::new([0u64; LUT_BINS]);
    // each bin's start is the previous bin's end: one evaluation per bin edge
    let mut next = 0.0;
    for (j, entry) in lut.iter_mut().enumerate() {
        let (octant, k) = ((j & !(LUT_T_BINS - 1)) as u32, j & (LUT_T_BINS - 1));
        let v = if k == 0 { corrected(octant, 0) } else { next };
        next = corrected(octant, k + 1);
        // An f64 just below 2π rounds to 2π in f32; keep the value in [0, 2π).
        let value = match v as f32 {
            v32 if v32 >= TAU => 0.0,
            v32 => v32,
        };
        let slope = wrap_to_pi(next - f64::from(value)) as f32;
        *entry = u64::from(value.to_bits()) | (u64::from(slope.to_bits()) << 32);
    }
    lut
}
