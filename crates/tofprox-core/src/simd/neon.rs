//! [`Lanes`] on aarch64 Advanced SIMD (NEON): two `float32x4_t` per step (eight pixels, so the
//! narrowing stores of `u16` depth and `u8` flags are whole registers, and the two halves give
//! the core independent work).
//!
//! # Safety
//! NEON is part of the aarch64 baseline (`aarch64-unknown-linux-gnu` enables it) and
//! [`super::SimdLevel::Neon`] is only selected after `is_aarch64_feature_detected!("neon")`;
//! values of these types are only created inside the kernel instantiated for that level. That is
//! the invariant the `unsafe` blocks rely on for the feature; every load and store goes through
//! an array reference of exactly the size it reads or writes. The wiggling table has no
//! gather instruction on NEON: eight scalar 64-bit loads, de-interleaved into value and slope by
//! `vld2q_f32`.
#![allow(unsafe_code)]

use super::{LANES, LUT_BINS, Lanes, Lut, ROUND_MAGIC, ROUND_MASK};
use std::arch::aarch64::*;

/// Eight `f32` in two NEON registers (lanes 0–3, 4–7).
#[derive(Debug, Clone, Copy)]
pub(crate) struct F32x4x2(float32x4_t, float32x4_t);

/// Eight `u32` (masks are all-ones / all-zeros lanes).
#[derive(Debug, Clone, Copy)]
pub(crate) struct U32x4x2(uint32x4_t, uint32x4_t);

#[inline(always)]
fn f2(a: F32x4x2, b: F32x4x2, f: impl Fn(float32x4_t, float32x4_t) -> float32x4_t) -> F32x4x2 {
    F32x4x2(f(a.0, b.0), f(a.1, b.1))
}

#[inline(always)]
fn m2(a: F32x4x2, b: F32x4x2, f: impl Fn(float32x4_t, float32x4_t) -> uint32x4_t) -> U32x4x2 {
    U32x4x2(f(a.0, b.0), f(a.1, b.1))
}

#[inline(always)]
fn u2(a: U32x4x2, b: U32x4x2, f: impl Fn(uint32x4_t, uint32x4_t) -> uint32x4_t) -> U32x4x2 {
    U32x4x2(f(a.0, b.0), f(a.1, b.1))
}

impl Lanes for F32x4x2 {
    type Mask = U32x4x2;
    type Int = U32x4x2;

    #[inline(always)]
    fn splat(v: f32) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { F32x4x2(vdupq_n_f32(v), vdupq_n_f32(v)) }
    }
    #[inline(always)]
    fn load(a: &[f32; LANES]) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { F32x4x2(vld1q_f32(a.as_ptr()), vld1q_f32(a.as_ptr().add(4))) }
    }
    #[inline(always)]
    fn from_u16(a: &[u16; LANES]) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            let v = { vld1q_u16(a.as_ptr()) };
            F32x4x2(
                vcvtq_f32_u32(vmovl_u16(vget_low_u16(v))),
                vcvtq_f32_u32(vmovl_high_u16(v)),
            )
        }
    }
    #[inline(always)]
    fn from_f64(a: &[f64; LANES]) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            let v = { [0, 2, 4, 6].map(|i| vld1q_f64(a.as_ptr().add(i))) };
            F32x4x2(
                vcvt_high_f32_f64(vcvt_f32_f64(v[0]), v[1]),
                vcvt_high_f32_f64(vcvt_f32_f64(v[2]), v[3]),
            )
        }
    }
    #[inline(always)]
    fn store(self, out: &mut [f32; LANES]) {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            {
                vst1q_f32(out.as_mut_ptr(), self.0);
                vst1q_f32(out.as_mut_ptr().add(4), self.1);
            }
        }
    }
    #[inline(always)]
    fn add(self, b: Self) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { f2(self, b, |p, q| vaddq_f32(p, q)) }
    }
    #[inline(always)]
    fn sub(self, b: Self) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { f2(self, b, |p, q| vsubq_f32(p, q)) }
    }
    #[inline(always)]
    fn mul(self, b: Self) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { f2(self, b, |p, q| vmulq_f32(p, q)) }
    }
    #[inline(always)]
    fn div(self, b: Self) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { f2(self, b, |p, q| vdivq_f32(p, q)) }
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { F32x4x2(vsqrtq_f32(self.0), vsqrtq_f32(self.1)) }
    }
    #[inline(always)]
    fn abs(self) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { F32x4x2(vabsq_f32(self.0), vabsq_f32(self.1)) }
    }
    #[inline(always)]
    fn min(self, b: Self) -> Self {
        // `a < b ? a : b` exactly (fmin differs for NaN and for −0 vs +0).
        Self::select(self.lt(b), self, b)
    }
    #[inline(always)]
    fn max(self, b: Self) -> Self {
        Self::select(b.lt(self), self, b)
    }
    #[inline(always)]
    fn lt(self, b: Self) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { m2(self, b, |p, q| vcltq_f32(p, q)) }
    }
    #[inline(always)]
    fn le(self, b: Self) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { m2(self, b, |p, q| vcleq_f32(p, q)) }
    }
    #[inline(always)]
    fn is_finite(self) -> U32x4x2 {
        self.abs().lt(Self::splat(f32::INFINITY))
    }
    #[inline(always)]
    fn select(m: U32x4x2, a: Self, b: Self) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { F32x4x2(vbslq_f32(m.0, a.0, b.0), vbslq_f32(m.1, a.1, b.1)) }
    }
    #[inline(always)]
    fn or(a: U32x4x2, b: U32x4x2) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { u2(a, b, |p, q| vorrq_u32(p, q)) }
    }
    #[inline(always)]
    fn and(a: U32x4x2, b: U32x4x2) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { u2(a, b, |p, q| vandq_u32(p, q)) }
    }
    #[inline(always)]
    fn not(a: U32x4x2) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { U32x4x2(vmvnq_u32(a.0), vmvnq_u32(a.1)) }
    }
    #[inline(always)]
    fn xor(a: U32x4x2, b: U32x4x2) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { u2(a, b, |p, q| veorq_u32(p, q)) }
    }
    #[inline(always)]
    fn neg_where(m: U32x4x2, a: Self) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            let sign = vdupq_n_u32(0x8000_0000);
            let flip = |m: uint32x4_t, a: float32x4_t| {
                vreinterpretq_f32_u32(veorq_u32(vreinterpretq_u32_f32(a), vandq_u32(m, sign)))
            };
            F32x4x2(flip(m.0, a.0), flip(m.1, a.1))
        }
    }
    #[inline(always)]
    fn all_true() -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { U32x4x2(vdupq_n_u32(u32::MAX), vdupq_n_u32(u32::MAX)) }
    }
    #[inline(always)]
    fn round_low22(self) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            let m = vdupq_n_u32(ROUND_MASK);
            let r = self.add(Self::splat(ROUND_MAGIC));
            U32x4x2(
                vandq_u32(vreinterpretq_u32_f32(r.0), m),
                vandq_u32(vreinterpretq_u32_f32(r.1), m),
            )
        }
    }
    #[inline(always)]
    fn int_to_f32(i: U32x4x2) -> Self {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            F32x4x2(
                vcvtq_f32_s32(vreinterpretq_s32_u32(i.0)),
                vcvtq_f32_s32(vreinterpretq_s32_u32(i.1)),
            )
        }
    }
    #[inline(always)]
    fn bits(m: U32x4x2, bit: u32) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            let b = vdupq_n_u32(bit);
            U32x4x2(vandq_u32(m.0, b), vandq_u32(m.1, b))
        }
    }
    #[inline(always)]
    fn or_int(a: U32x4x2, b: U32x4x2) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { u2(a, b, |p, q| vorrq_u32(p, q)) }
    }
    #[inline(always)]
    fn int_is_zero(i: U32x4x2) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { U32x4x2(vceqzq_u32(i.0), vceqzq_u32(i.1)) }
    }
    #[inline(always)]
    fn has_bit(i: U32x4x2, bit: u32) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            let b = vdupq_n_u32(bit);
            U32x4x2(vtstq_u32(i.0, b), vtstq_u32(i.1, b))
        }
    }
    #[inline(always)]
    fn load_int(a: &[u32; LANES]) -> U32x4x2 {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe { U32x4x2(vld1q_u32(a.as_ptr()), vld1q_u32(a.as_ptr().add(4))) }
    }
    #[inline(always)]
    fn store_int(i: U32x4x2, out: &mut [u32; LANES]) {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            {
                vst1q_u32(out.as_mut_ptr(), i.0);
                vst1q_u32(out.as_mut_ptr().add(4), i.1);
            }
        }
    }
    #[inline(always)]
    fn lut(lut: &Lut, i: &[u32; LANES]) -> (Self, Self) {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            // The mask keeps every index < LUT_BINS, so the indexing cannot fail.
            let w: [u64; LANES] = i.map(|i| lut[i as usize & (LUT_BINS - 1)]);
            let (a, b) = {
                let p = w.as_ptr().cast::<f32>();
                (vld2q_f32(p), vld2q_f32(p.add(8)))
            };
            (F32x4x2(a.0, b.0), F32x4x2(a.1, b.1))
        }
    }
    #[inline(always)]
    fn store_mm(mm: U32x4x2, valid: U32x4x2, out: &mut [u16; LANES]) {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            let one = vdupq_n_u32(1);
            let lo = vandq_u32(vmaxq_u32(mm.0, one), valid.0);
            let hi = vandq_u32(vmaxq_u32(mm.1, one), valid.1);
            // mm ≤ 65535 where valid, so the narrowing is exact.
            let p = vcombine_u16(vmovn_u32(lo), vmovn_u32(hi));
            vst1q_u16(out.as_mut_ptr(), p)
        }
    }
    #[inline(always)]
    fn store_flags(flags: U32x4x2, out: &mut [u8; LANES]) {
        // SAFETY: NEON is available (module invariant); pointer accesses stay inside
        // the array references passed in.
        unsafe {
            let p = vcombine_u16(vmovn_u32(flags.0), vmovn_u32(flags.1));
            vst1_u8(out.as_mut_ptr(), vmovn_u16(p))
        }
    }
}
