//! The per-pixel kernel (module docs of [`super`], *Speed*): written once against eight-lane
//! operations and compiled per instruction set; two short passes per block of pixels.

use super::KernelParams;
use super::sample::RawSample;
use super::table::{OCTANT_NEG_X, OCTANT_NEG_Y, OCTANT_SWAP};
use crate::frame::{FLAG_INVALID, FLAG_LOW_AMPLITUDE, FLAG_NON_FINITE, FLAG_SATURATED};
use crate::simd::{LANES, LUT_T_BINS, Lut, Simd};
use std::f32::consts::TAU;

pub(super) struct Outputs<'a> {
    pub(super) phase: &'a mut [f32],
    pub(super) amp: &'a mut [f32],
    pub(super) depth_m: &'a mut [f32],
    pub(super) depth_mm: &'a mut [u16],
    pub(super) flags: &'a mut [u8],
}

pub(super) struct Tables<'a> {
    pub(super) dark: &'a [f32],
    /// `None` when there is no FPPN map (the kernel then skips the per-pixel load).
    pub(super) fppn: Option<&'a [f32]>,
    pub(super) lut: &'a Lut,
}

/// The kernel with AVX-512 available to the code generator (masks, 32 registers) on the AVX2
/// lanes; `_proof` shows the CPU has the features this function is compiled for.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq,avx2,fma")]
pub(super) fn kernel_avx512<T: RawSample>(
    proof: crate::simd::avx2::Avx512,
    raw: [&[T]; 4],
    four: bool,
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
) {
    kernel_dispatch(proof.avx2(), raw, four, n, p, t, out)
}

/// The kernel compiled for AVX2 and FMA (no fused operation is used: see the module docs);
/// `proof` shows the CPU has them.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(super) fn kernel_avx2<T: RawSample>(
    proof: crate::simd::avx2::Avx2,
    raw: [&[T]; 4],
    four: bool,
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
) {
    kernel_dispatch(proof, raw, four, n, p, t, out)
}

#[inline(always)]
pub(super) fn kernel_dispatch<S: Simd, T: RawSample>(
    s: S,
    raw: [&[T]; 4],
    four: bool,
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
) {
    match (four, t.fppn.is_some()) {
        (true, true) => kernel::<S, T, true, true>(s, raw, n, p, t, out),
        (true, false) => kernel::<S, T, true, false>(s, raw, n, p, t, out),
        (false, true) => kernel::<S, T, false, true>(s, raw, n, p, t, out),
        (false, false) => kernel::<S, T, false, false>(s, raw, n, p, t, out),
    }
}

/// Steps of [`LANES`] pixels per block: the block's intermediates (4 kB) stay in L1 between the
/// two passes.
const BLOCK_STEPS: usize = 32;

/// Pass-1 → pass-2 intermediates of one block.
struct Scratch {
    /// Phase-table bin and fraction.
    idx: [[u32; LANES]; BLOCK_STEPS],
    fr: [[f32; LANES]; BLOCK_STEPS],
    /// Flags known after pass 1: saturated, low amplitude, non-finite.
    status: [[u32; LANES]; BLOCK_STEPS],
}

/// The whole frame in blocks of [`BLOCK_STEPS`] steps of [`LANES`] pixels, two passes per block:
/// pass 1 (validity, offset, amplitude, phase, table position) and pass 2 (table lookup,
/// corrections, wrap, depth, flags). Each pass is a short loop whose iterations are independent,
/// so the core overlaps several of them (one fused pass is a single long dependency chain —
/// division, polynomial, gather — and runs at its latency). The last `n % LANES` pixels go
/// through the same steps on padded copies, so every pixel is computed by the same instructions.
#[inline(always)]
fn kernel<S: Simd, T: RawSample, const FOUR: bool, const FPPN: bool>(
    s: S,
    raw: [&[T]; 4],
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
) {
    let n = n
        .min(raw[0].len())
        .min(raw[1].len())
        .min(t.dark.len())
        .min(out.phase.len())
        .min(out.amp.len())
        .min(out.depth_m.len())
        .min(out.depth_mm.len())
        .min(out.flags.len());
    let n = if FOUR {
        n.min(raw[2].len()).min(raw[3].len())
    } else {
        n
    };
    let fppn = t.fppn.unwrap_or(t.dark);
    let n = n.min(fppn.len());
    // Unused inputs (images 2, 3 in 2-phase; FPPN without a map) alias used ones: never read.
    let (r2, r3) = if FOUR {
        (raw[2], raw[3])
    } else {
        (raw[0], raw[1])
    };
    let (r0, r0t) = raw[0][..n].as_chunks::<LANES>();
    let (r1, r1t) = raw[1][..n].as_chunks::<LANES>();
    let (r2, r2t) = r2[..n].as_chunks::<LANES>();
    let (r3, r3t) = r3[..n].as_chunks::<LANES>();
    let (dk, dkt) = t.dark[..n].as_chunks::<LANES>();
    let (fp, fpt) = fppn[..n].as_chunks::<LANES>();
    let (ph, pht) = out.phase[..n].as_chunks_mut::<LANES>();
    let (am, amt) = out.amp[..n].as_chunks_mut::<LANES>();
    let (dm, dmt) = out.depth_m[..n].as_chunks_mut::<LANES>();
    let (mm, mmt) = out.depth_mm[..n].as_chunks_mut::<LANES>();
    let (fl, flt) = out.flags[..n].as_chunks_mut::<LANES>();
    let mut sc = Scratch {
        idx: [[0; LANES]; BLOCK_STEPS],
        fr: [[0.0; LANES]; BLOCK_STEPS],
        status: [[0; LANES]; BLOCK_STEPS],
    };
    let b = BLOCK_STEPS;
    let ins = r0
        .chunks(b)
        .zip(r1.chunks(b))
        .zip(r2.chunks(b))
        .zip(r3.chunks(b));
    let ins = ins
        .zip(dk.chunks(b))
        .zip(fp.chunks(b))
        .zip(am.chunks_mut(b));
    let outs = ph.chunks_mut(b).zip(dm.chunks_mut(b)).zip(mm.chunks_mut(b));
    for (((((((r0, r1), r2), r3), dk), fp), am), ((ph, dm), mm), fl) in ins
        .zip(outs)
        .zip(fl.chunks_mut(b))
        .map(|((i, o), f)| (i, o, f))
    {
        // Pass 1.
        let pass1 = r0.iter().zip(r1).zip(r2).zip(r3).zip(dk).zip(am);
        let scr = sc.idx.iter_mut().zip(&mut sc.fr).zip(&mut sc.status);
        for ((((((a0, a1), a2), a3), dk), am), ((idx, fr), st)) in pass1.zip(scr) {
            front::<S, T, FOUR>(s, [a0, a1, a2, a3], dk, p, am, idx, fr, st);
        }
        // Pass 2.
        let scr = sc.idx.iter().zip(&sc.fr).zip(&sc.status);
        let pass2 = fp
            .iter()
            .zip(ph.iter_mut())
            .zip(dm.iter_mut())
            .zip(mm.iter_mut());
        for (((((fp, ph), dm), mm), fl), ((idx, fr), st)) in pass2.zip(fl.iter_mut()).zip(scr) {
            back::<S, FPPN>(
                s,
                idx,
                fr,
                st,
                fp,
                p,
                t.lut,
                T::ALWAYS_FINITE,
                [ph, dm],
                mm,
                fl,
            );
        }
    }
    // The tail: padded with the first tail sample (any value: the padding lanes are dropped).
    let Some(&fill) = r0t.first() else {
        return;
    };
    let raw_pad = [r0t, r1t, r2t, r3t].map(|s| pad(s, fill));
    let (dk_pad, fp_pad) = (pad(dkt, 0.0), pad(fpt, 0.0));
    let (mut ph, mut am, mut dm) = ([0f32; LANES], [0f32; LANES], [0f32; LANES]);
    let (mut mm, mut fl) = ([0u16; LANES], [0u8; LANES]);
    let r = [&raw_pad[0], &raw_pad[1], &raw_pad[2], &raw_pad[3]];
    let (idx, fr, st) = (&mut sc.idx[0], &mut sc.fr[0], &mut sc.status[0]);
    front::<S, T, FOUR>(s, r, &dk_pad, p, &mut am, idx, fr, st);
    let fin = T::ALWAYS_FINITE;
    back::<S, FPPN>(
        s,
        idx,
        fr,
        st,
        &fp_pad,
        p,
        t.lut,
        fin,
        [&mut ph, &mut dm],
        &mut mm,
        &mut fl,
    );
    unpad(pht, &ph);
    unpad(amt, &am);
    unpad(dmt, &dm);
    unpad(mmt, &mm);
    unpad(flt, &fl);
}

/// The first `s.len() ≤ LANES` lanes from `s`, the rest `fill`.
#[inline(always)]
fn pad<X: Copy>(s: &[X], fill: X) -> [X; LANES] {
    let mut a = [fill; LANES];
    for (d, v) in a.iter_mut().zip(s) {
        *d = *v;
    }
    a
}

/// Copies the first `d.len() ≤ LANES` lanes back.
#[inline(always)]
fn unpad<X: Copy>(d: &mut [X], s: &[X; LANES]) {
    for (d, v) in d.iter_mut().zip(s) {
        *d = *v;
    }
}

/// Pass 1 on [`LANES`] pixels: raw validity, offset correction, amplitude (final output) and
/// phase-table position. Compares and selects only, no branches; `raw[2..4]` are read only when
/// `FOUR`.
#[allow(clippy::too_many_arguments)] // the step's inputs and outputs, each one array
#[inline(always)]
fn front<S: Simd, T: RawSample, const FOUR: bool>(
    s: S,
    raw: [&[T; LANES]; 4],
    dark: &[f32; LANES],
    p: &KernelParams,
    amp_out: &mut [f32; LANES],
    idx_out: &mut [u32; LANES],
    fr_out: &mut [f32; LANES],
    status_out: &mut [u32; LANES],
) {
    let a0 = T::load_lanes(s, raw[0]);
    let a1 = T::load_lanes(s, raw[1]);
    // Saturation on the RAW codes: any used image at a rail (≤ 0 or ≥ 2^bits − 1).
    let (mut lo, mut hi) = (s.min(a0, a1), s.max(a0, a1));
    let (x, y, amp);
    if FOUR {
        let a2 = T::load_lanes(s, raw[2]);
        let a3 = T::load_lanes(s, raw[3]);
        lo = s.min(lo, s.min(a2, a3));
        hi = s.max(hi, s.max(a2, a3));
        // eq. 2.3: the per-pixel offset cancels in the differences.
        x = s.sub(a0, a2);
        y = s.sub(a1, a3);
        let norm = s.sqrt(s.add(s.mul(x, x), s.mul(y, y)));
        amp = s.mul(s.splat(0.5), norm); // eq. 2.4
    } else {
        // Offset correction (4.3.3.1), then eq. 2.2.
        let d = s.load(dark);
        x = s.sub(a0, d);
        y = s.sub(a1, d);
        amp = s.sqrt(s.add(s.mul(x, x), s.mul(y, y))); // |z|, the 2-phase form of eq. 2.4
    }
    let sat = s.or(s.le(lo, s.splat(0.0)), s.le(s.splat(p.rail_hi), hi));
    let low = s.lt(amp, s.splat(p.min_amp));
    let mut status = s.or_int(
        s.bits(sat, FLAG_SATURATED.into()),
        s.bits(low, FLAG_LOW_AMPLITUDE.into()),
    );
    if T::ALWAYS_FINITE {
        s.store(amp, amp_out);
    } else {
        // Non-finite raw values (or an offset-corrected value beyond f32) make x or y non-finite.
        let finite = s.and(s.is_finite(x), s.is_finite(y));
        status = s.or_int(status, s.bits(s.not(finite), FLAG_NON_FINITE.into()));
        s.store(s.select(finite, amp, s.splat(0.0)), amp_out);
    }
    s.store_int(status, status_out);
    // The signs place the images' canonical shifts (`Quadrature`): multiplying by ±1 is exact,
    // so every level still agrees to the bit.
    let (x, y) = (s.mul(x, s.splat(p.x_sign)), s.mul(y, s.splat(p.y_sign)));
    // Phase-table position (module docs): octant bits and t = min/max of |x|, |y| in [0, 1].
    let (ax, ay) = (s.abs(x), s.abs(y));
    // max == 0 only at the origin; divide by a tiny positive instead (gives t = 0).
    let t = s.div(
        s.min(ax, ay),
        s.max(s.max(ax, ay), s.splat(f32::MIN_POSITIVE)),
    );
    let zero = s.splat(0.0);
    let octant = s.or_int(
        s.or_int(
            s.bits(s.lt(ax, ay), OCTANT_SWAP),
            s.bits(s.lt(x, zero), OCTANT_NEG_X),
        ),
        s.bits(s.lt(y, zero), OCTANT_NEG_Y),
    );
    // Bin and fraction: `tf − 0.5` rounded is floor(tf) (a tie gives k − 1 with fr = 1: the same
    // interpolated value); tf = 512 (t = 1) is bin 511 with fr = 1. A NaN t gives an index the
    // lookup masks into range.
    let tf = s.mul(t, s.splat(LUT_T_BINS as f32)); // exact: a power of two
    let top = s.min(tf, s.splat(LUT_T_BINS as f32 - 0.5));
    let k = s.round_low22(s.sub(top, s.splat(0.5)));
    s.store_int(s.or_int(k, octant), idx_out);
    s.store(s.sub(tf, s.int_to_f32(k)), fr_out);
}

/// Pass 2 on [`LANES`] pixels: corrected phase from the phase table (linear interpolation), FPPN,
/// wrap, depth, flags. `fppn` is read only when `FPPN`; `finite` says pass 1 saw only finite
/// values (`u16` input), so the non-finite selects are skipped.
#[allow(clippy::too_many_arguments)] // the step's inputs and outputs, each one array
#[inline(always)]
fn back<S: Simd, const FPPN: bool>(
    s: S,
    idx: &[u32; LANES],
    fr: &[f32; LANES],
    status: &[u32; LANES],
    fppn: &[f32; LANES],
    p: &KernelParams,
    lut: &Lut,
    finite: bool,
    [phase_out, depth_m_out]: [&mut [f32; LANES]; 2],
    depth_mm_out: &mut [u16; LANES],
    flags_out: &mut [u8; LANES],
) {
    // eq. 2.2 / 2.3 with the wiggling correction (3.3.7.2 / 4.3.3.3), by the phase table.
    let (value, slope) = s.lut(lut, idx);
    let mut ph = s.add(value, s.mul(slope, s.load(fr)));
    if FPPN {
        ph = s.sub(ph, s.load(fppn)); // 2.3.1.4
    }
    // Wrap into [0, 2π): value in [0, 2π), |slope · fr| ≤ π, FPPN in (−π, π], so ph is in
    // [−2π, 4π): one step up, then one down (which also folds a sum that rounded up to 2π).
    let zero = s.splat(0.0);
    let tau = s.splat(TAU);
    ph = s.select(s.lt(ph, zero), s.add(ph, tau), ph);
    ph = s.select(s.le(tau, ph), s.sub(ph, tau), ph);

    let d = s.mul(ph, s.splat(p.rad_to_m)); // eq. 2.6
    let d_mm = s.mul(d, s.splat(1000.0));
    let in_range = s.lt(d_mm, s.splat(65_535.5)); // false for NaN
    let status = s.load_int(status);
    let ok = s.and(s.int_is_zero(status), in_range);
    let flags = s.or_int(status, s.bits(s.not(ok), FLAG_INVALID.into()));
    s.store_flags(flags, flags_out);
    // round(d · 1000) by the mantissa trick; ≥ 1 mm when valid.
    s.store_mm(s.round_low22(d_mm), ok, depth_mm_out);
    s.store(s.select(ok, d, zero), depth_m_out);
    if finite {
        s.store(ph, phase_out);
    } else {
        let finite = s.not(s.has_bit(status, FLAG_NON_FINITE.into()));
        s.store(s.select(finite, ph, zero), phase_out);
    }
}
