//! [`Simd`] on aarch64 Advanced SIMD (NEON): two `float32x4_t` per step (eight pixels, so the
//! narrowing stores of `u16` depth and `u8` flags are whole registers, and the two halves give
//! the core independent work), and the token [`Neon`].
//!
//! # Safety
//! A NEON intrinsic may only run where the CPU has NEON (part of the aarch64 baseline; Rust still
//! asks for the proof). Every method here takes `self: Neon`, which only [`Neon::detect`] makes,
//! after `is_aarch64_feature_detected!("neon")` confirmed it (the private field keeps any other
//! code from making one): the proof each `unsafe` block below relies on for the feature.
//! Register-only operations go through the `neon!` macro, which demands the token by type; loads
//! and stores have their own `unsafe` block whose SAFETY comment gives the bounds of that access.
//! The wiggling table has no gather instruction on NEON: eight scalar 64-bit loads,
//! de-interleaved into value and slope by `vld2q_f32`.
#![allow(unsafe_code)]

use super::{LANES, LUT_BINS, Lut, ROUND_MAGIC, ROUND_MASK, Simd};
use std::arch::aarch64::*;

/// Proof that this CPU has NEON (zero-sized; made only by [`Neon::detect`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Neon {
    _detected: (),
}

impl Neon {
    /// `Some` if the CPU has NEON (every aarch64 Linux CPU does).
    pub(crate) fn detect() -> Option<Neon> {
        std::arch::is_aarch64_feature_detected!("neon").then_some(Neon { _detected: () })
    }
}

/// Evaluates `$body`, register intrinsics only (no memory access), given `$token: Neon`.
macro_rules! neon {
    ($token:expr, $body:expr) => {{
        let _proof: Neon = $token;
        // SAFETY: `_proof` is a `Neon`, which exists only after `Neon::detect` saw NEON on this
        // CPU: the one requirement of register intrinsics (no memory is touched).
        unsafe { $body }
    }};
}

/// Eight `f32` in two NEON registers (lanes 0–3, 4–7).
#[derive(Debug, Clone, Copy)]
pub(crate) struct F32x4x2(float32x4_t, float32x4_t);

/// Eight `u32` (masks are all-ones / all-zeros lanes).
#[derive(Debug, Clone, Copy)]
pub(crate) struct U32x4x2(uint32x4_t, uint32x4_t);

impl Simd for Neon {
    type F32 = F32x4x2;
    type Mask = U32x4x2;
    type Int = U32x4x2;

    #[inline(always)]
    fn splat(self, v: f32) -> F32x4x2 {
        neon!(self, F32x4x2(vdupq_n_f32(v), vdupq_n_f32(v)))
    }
    #[inline(always)]
    fn load(self, a: &[f32; LANES]) -> F32x4x2 {
        let (lo, hi) = a.split_at(4);
        // SAFETY: NEON by `self`; `lo` and `hi` are 4 f32 each = the 16 bytes each `vld1q`
        // reads (f32 alignment, which the slices have).
        unsafe { F32x4x2(vld1q_f32(lo.as_ptr()), vld1q_f32(hi.as_ptr())) }
    }
    #[inline(always)]
    fn load_u16(self, a: &[u16; LANES]) -> F32x4x2 {
        // SAFETY: NEON by `self`; `a` is 8 u16 = the 16 bytes `vld1q_u16` reads (u16 alignment).
        let v = unsafe { vld1q_u16(a.as_ptr()) };
        neon!(
            self,
            F32x4x2(
                vcvtq_f32_u32(vmovl_u16(vget_low_u16(v))),
                vcvtq_f32_u32(vmovl_high_u16(v)),
            )
        )
    }
    #[inline(always)]
    fn load_f64(self, a: &[f64; LANES]) -> F32x4x2 {
        let (lo, hi) = a.split_at(4);
        let (q0, q1, q2, q3) = (&lo[..2], &lo[2..], &hi[..2], &hi[2..]);
        // SAFETY: NEON by `self`; `q0`…`q3` are 2 f64 each = the 16 bytes each `vld1q_f64`
        // reads (f64 alignment).
        let v = unsafe { [q0, q1, q2, q3].map(|q| vld1q_f64(q.as_ptr())) };
        neon!(
            self,
            F32x4x2(
                vcvt_high_f32_f64(vcvt_f32_f64(v[0]), v[1]),
                vcvt_high_f32_f64(vcvt_f32_f64(v[2]), v[3]),
            )
        )
    }
    #[inline(always)]
    fn store(self, v: F32x4x2, out: &mut [f32; LANES]) {
        let (lo, hi) = out.split_at_mut(4);
        // SAFETY: NEON by `self`; `lo` and `hi` are 4 f32 each = the 16 bytes each `vst1q`
        // writes (f32 alignment).
        unsafe {
            vst1q_f32(lo.as_mut_ptr(), v.0);
            vst1q_f32(hi.as_mut_ptr(), v.1);
        }
    }
    #[inline(always)]
    fn add(self, a: F32x4x2, b: F32x4x2) -> F32x4x2 {
        neon!(self, F32x4x2(vaddq_f32(a.0, b.0), vaddq_f32(a.1, b.1)))
    }
    #[inline(always)]
    fn sub(self, a: F32x4x2, b: F32x4x2) -> F32x4x2 {
        neon!(self, F32x4x2(vsubq_f32(a.0, b.0), vsubq_f32(a.1, b.1)))
    }
    #[inline(always)]
    fn mul(self, a: F32x4x2, b: F32x4x2) -> F32x4x2 {
        neon!(self, F32x4x2(vmulq_f32(a.0, b.0), vmulq_f32(a.1, b.1)))
    }
    #[inline(always)]
    fn div(self, a: F32x4x2, b: F32x4x2) -> F32x4x2 {
        neon!(self, F32x4x2(vdivq_f32(a.0, b.0), vdivq_f32(a.1, b.1)))
    }
    #[inline(always)]
    fn sqrt(self, a: F32x4x2) -> F32x4x2 {
        neon!(self, F32x4x2(vsqrtq_f32(a.0), vsqrtq_f32(a.1)))
    }
    #[inline(always)]
    fn abs(self, a: F32x4x2) -> F32x4x2 {
        neon!(self, F32x4x2(vabsq_f32(a.0), vabsq_f32(a.1)))
    }
    #[inline(always)]
    fn min(self, a: F32x4x2, b: F32x4x2) -> F32x4x2 {
        // `a < b ? a : b` exactly (fmin differs for NaN and for −0 vs +0).
        self.select(self.lt(a, b), a, b)
    }
    #[inline(always)]
    fn max(self, a: F32x4x2, b: F32x4x2) -> F32x4x2 {
        self.select(self.lt(b, a), a, b)
    }
    #[inline(always)]
    fn lt(self, a: F32x4x2, b: F32x4x2) -> U32x4x2 {
        neon!(self, U32x4x2(vcltq_f32(a.0, b.0), vcltq_f32(a.1, b.1)))
    }
    #[inline(always)]
    fn le(self, a: F32x4x2, b: F32x4x2) -> U32x4x2 {
        neon!(self, U32x4x2(vcleq_f32(a.0, b.0), vcleq_f32(a.1, b.1)))
    }
    #[inline(always)]
    fn select(self, m: U32x4x2, a: F32x4x2, b: F32x4x2) -> F32x4x2 {
        neon!(
            self,
            F32x4x2(vbslq_f32(m.0, a.0, b.0), vbslq_f32(m.1, a.1, b.1))
        )
    }
    #[inline(always)]
    fn or(self, a: U32x4x2, b: U32x4x2) -> U32x4x2 {
        neon!(self, U32x4x2(vorrq_u32(a.0, b.0), vorrq_u32(a.1, b.1)))
    }
    #[inline(always)]
    fn and(self, a: U32x4x2, b: U32x4x2) -> U32x4x2 {
        neon!(self, U32x4x2(vandq_u32(a.0, b.0), vandq_u32(a.1, b.1)))
    }
    #[inline(always)]
    fn not(self, a: U32x4x2) -> U32x4x2 {
        neon!(self, U32x4x2(vmvnq_u32(a.0), vmvnq_u32(a.1)))
    }
    #[inline(always)]
    fn round_low22(self, a: F32x4x2) -> U32x4x2 {
        let r = self.add(a, self.splat(ROUND_MAGIC));
        neon!(self, {
            let m = vdupq_n_u32(ROUND_MASK);
            U32x4x2(
                vandq_u32(vreinterpretq_u32_f32(r.0), m),
                vandq_u32(vreinterpretq_u32_f32(r.1), m),
            )
        })
    }
    #[inline(always)]
    fn int_to_f32(self, i: U32x4x2) -> F32x4x2 {
        neon!(
            self,
            F32x4x2(
                vcvtq_f32_s32(vreinterpretq_s32_u32(i.0)),
                vcvtq_f32_s32(vreinterpretq_s32_u32(i.1)),
            )
        )
    }
    #[inline(always)]
    fn bits(self, m: U32x4x2, bit: u32) -> U32x4x2 {
        neon!(self, {
            let b = vdupq_n_u32(bit);
            U32x4x2(vandq_u32(m.0, b), vandq_u32(m.1, b))
        })
    }
    #[inline(always)]
    fn or_int(self, a: U32x4x2, b: U32x4x2) -> U32x4x2 {
        self.or(a, b)
    }
    #[inline(always)]
    fn int_is_zero(self, i: U32x4x2) -> U32x4x2 {
        neon!(self, U32x4x2(vceqzq_u32(i.0), vceqzq_u32(i.1)))
    }
    #[inline(always)]
    fn has_bit(self, i: U32x4x2, bit: u32) -> U32x4x2 {
        neon!(self, {
            let b = vdupq_n_u32(bit);
            U32x4x2(vtstq_u32(i.0, b), vtstq_u32(i.1, b))
        })
    }
    #[inline(always)]
    fn load_int(self, a: &[u32; LANES]) -> U32x4x2 {
        let (lo, hi) = a.split_at(4);
        // SAFETY: NEON by `self`; `lo` and `hi` are 4 u32 each = the 16 bytes each `vld1q`
        // reads (u32 alignment).
        unsafe { U32x4x2(vld1q_u32(lo.as_ptr()), vld1q_u32(hi.as_ptr())) }
    }
    #[inline(always)]
    fn store_int(self, i: U32x4x2, out: &mut [u32; LANES]) {
        let (lo, hi) = out.split_at_mut(4);
        // SAFETY: NEON by `self`; `lo` and `hi` are 4 u32 each = the 16 bytes each `vst1q`
        // writes (u32 alignment).
        unsafe {
            vst1q_u32(lo.as_mut_ptr(), i.0);
            vst1q_u32(hi.as_mut_ptr(), i.1);
        }
    }
    #[inline(always)]
    fn lut(self, lut: &Lut, idx: &[u32; LANES]) -> (F32x4x2, F32x4x2) {
        // The mask keeps every index < LUT_BINS, so the indexing cannot fail.
        let w: [u64; LANES] = idx.map(|i| lut[i as usize & (LUT_BINS - 1)]);
        let (lo, hi) = w.split_at(4);
        // SAFETY: NEON by `self`; `lo` and `hi` are 4 u64 = 8 f32 = the 32 bytes each `vld2q_f32`
        // reads (u64 alignment exceeds the f32 it needs).
        let (a, b) = unsafe {
            (
                vld2q_f32(lo.as_ptr().cast::<f32>()),
                vld2q_f32(hi.as_ptr().cast::<f32>()),
            )
        };
        (F32x4x2(a.0, b.0), F32x4x2(a.1, b.1))
    }
    #[inline(always)]
    fn store_mm(self, mm: U32x4x2, valid: U32x4x2, out: &mut [u16; LANES]) {
        let p = neon!(self, {
            let one = vdupq_n_u32(1);
            let lo = vandq_u32(vmaxq_u32(mm.0, one), valid.0);
            let hi = vandq_u32(vmaxq_u32(mm.1, one), valid.1);
            // mm ≤ 65535 where valid, so the narrowing is exact.
            vcombine_u16(vmovn_u32(lo), vmovn_u32(hi))
        });
        // SAFETY: NEON by `self`; `out` is 8 u16 = the 16 bytes `vst1q_u16` writes (u16 alignment).
        unsafe { vst1q_u16(out.as_mut_ptr(), p) }
    }
    #[inline(always)]
    fn store_flags(self, flags: U32x4x2, out: &mut [u8; LANES]) {
        let p = neon!(
            self,
            vmovn_u16(vcombine_u16(vmovn_u32(flags.0), vmovn_u32(flags.1)))
        );
        // SAFETY: NEON by `self`; `out` is 8 u8 = the 8 bytes `vst1_u8` writes.
        unsafe { vst1_u8(out.as_mut_ptr(), p) }
    }
}
