//! [`Lanes`] on x86-64 AVX2: one `__m256` per step.
//!
//! # Safety
//! The intrinsics need AVX2 (and the kernel is compiled with FMA too, although no fused operation
//! is used). Values of [`F32x8`] are only created inside the pipeline's `kernel_avx2` /
//! `kernel_avx512`, which are `#[target_feature(enable = "avx2,fma")]` functions called only after
//! [`super::SimdLevel::is_supported`] confirmed the features at run time; every method is
//! `#[inline(always)]` into those functions. This is the invariant each `unsafe` block below
//! relies on for the feature requirement; pointer accesses are justified where they occur.
#![allow(unsafe_code)]

use super::{LANES, LUT_BINS, Lanes, Lut, ROUND_MAGIC, ROUND_MASK};
use std::arch::x86_64::*;

/// Eight `f32` in one AVX register.
#[derive(Debug, Clone, Copy)]
pub(crate) struct F32x8(__m256);

/// Per-lane mask: all-ones or all-zeros `f32` lanes (the `cmpps` result).
#[derive(Debug, Clone, Copy)]
pub(crate) struct M8(__m256);

/// Eight `u32`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct I8(__m256i);

impl Lanes for F32x8 {
    type Mask = M8;
    type Int = I8;

    #[inline(always)]
    fn splat(v: f32) -> Self {
        // SAFETY: AVX is available (module invariant).
        F32x8(unsafe { _mm256_set1_ps(v) })
    }
    #[inline(always)]
    fn load(a: &[f32; LANES]) -> Self {
        // SAFETY: module invariant; `a` is 8 readable f32 (unaligned load).
        F32x8(unsafe { _mm256_loadu_ps(a.as_ptr()) })
    }
    #[inline(always)]
    fn from_u16(a: &[u16; LANES]) -> Self {
        // SAFETY: module invariant; `a` is 16 readable bytes (unaligned load).
        F32x8(unsafe {
            let v = _mm_loadu_si128(a.as_ptr().cast::<__m128i>());
            _mm256_cvtepi32_ps(_mm256_cvtepu16_epi32(v))
        })
    }
    #[inline(always)]
    fn from_f64(a: &[f64; LANES]) -> Self {
        // SAFETY: module invariant; `a` is 8 readable f64, read as two unaligned halves.
        F32x8(unsafe {
            let lo = _mm256_cvtpd_ps(_mm256_loadu_pd(a.as_ptr()));
            let hi = _mm256_cvtpd_ps(_mm256_loadu_pd(a.as_ptr().add(4)));
            _mm256_set_m128(hi, lo)
        })
    }
    #[inline(always)]
    fn store(self, out: &mut [f32; LANES]) {
        // SAFETY: module invariant; `out` is 8 writable f32 (unaligned store).
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), self.0) }
    }
    #[inline(always)]
    fn add(self, b: Self) -> Self {
        // SAFETY: module invariant.
        F32x8(unsafe { _mm256_add_ps(self.0, b.0) })
    }
    #[inline(always)]
    fn sub(self, b: Self) -> Self {
        // SAFETY: module invariant.
        F32x8(unsafe { _mm256_sub_ps(self.0, b.0) })
    }
    #[inline(always)]
    fn mul(self, b: Self) -> Self {
        // SAFETY: module invariant.
        F32x8(unsafe { _mm256_mul_ps(self.0, b.0) })
    }
    #[inline(always)]
    fn div(self, b: Self) -> Self {
        // SAFETY: module invariant.
        F32x8(unsafe { _mm256_div_ps(self.0, b.0) })
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        // SAFETY: module invariant.
        F32x8(unsafe { _mm256_sqrt_ps(self.0) })
    }
    #[inline(always)]
    fn abs(self) -> Self {
        // SAFETY: module invariant.
        F32x8(unsafe { _mm256_andnot_ps(_mm256_set1_ps(-0.0), self.0) })
    }
    #[inline(always)]
    fn min(self, b: Self) -> Self {
        // `minps(a, b)` is `a < b ? a : b`, the trait's definition.
        // SAFETY: module invariant.
        F32x8(unsafe { _mm256_min_ps(self.0, b.0) })
    }
    #[inline(always)]
    fn max(self, b: Self) -> Self {
        // SAFETY: module invariant.
        F32x8(unsafe { _mm256_max_ps(self.0, b.0) })
    }
    #[inline(always)]
    fn lt(self, b: Self) -> M8 {
        // SAFETY: module invariant.
        M8(unsafe { _mm256_cmp_ps::<_CMP_LT_OQ>(self.0, b.0) })
    }
    #[inline(always)]
    fn le(self, b: Self) -> M8 {
        // SAFETY: module invariant.
        M8(unsafe { _mm256_cmp_ps::<_CMP_LE_OQ>(self.0, b.0) })
    }
    #[inline(always)]
    fn is_finite(self) -> M8 {
        self.abs().lt(F32x8::splat(f32::INFINITY))
    }
    #[inline(always)]
    fn select(m: M8, a: Self, b: Self) -> Self {
        // SAFETY: module invariant.
        F32x8(unsafe { _mm256_blendv_ps(b.0, a.0, m.0) })
    }
    #[inline(always)]
    fn or(a: M8, b: M8) -> M8 {
        // SAFETY: module invariant.
        M8(unsafe { _mm256_or_ps(a.0, b.0) })
    }
    #[inline(always)]
    fn and(a: M8, b: M8) -> M8 {
        // SAFETY: module invariant.
        M8(unsafe { _mm256_and_ps(a.0, b.0) })
    }
    #[inline(always)]
    fn not(a: M8) -> M8 {
        // SAFETY: module invariant.
        M8(unsafe { _mm256_xor_ps(a.0, _mm256_castsi256_ps(_mm256_set1_epi32(-1))) })
    }
    #[inline(always)]
    fn xor(a: M8, b: M8) -> M8 {
        // SAFETY: module invariant.
        M8(unsafe { _mm256_xor_ps(a.0, b.0) })
    }
    #[inline(always)]
    fn neg_where(m: M8, a: Self) -> Self {
        // SAFETY: module invariant.
        F32x8(unsafe { _mm256_xor_ps(a.0, _mm256_and_ps(m.0, _mm256_set1_ps(-0.0))) })
    }
    #[inline(always)]
    fn all_true() -> M8 {
        // SAFETY: module invariant.
        M8(unsafe { _mm256_castsi256_ps(_mm256_set1_epi32(-1)) })
    }
    #[inline(always)]
    fn round_low22(self) -> I8 {
        // SAFETY: module invariant.
        I8(unsafe {
            let v = _mm256_castps_si256(_mm256_add_ps(self.0, _mm256_set1_ps(ROUND_MAGIC)));
            _mm256_and_si256(v, _mm256_set1_epi32(ROUND_MASK as i32))
        })
    }
    #[inline(always)]
    fn int_to_f32(i: I8) -> Self {
        // SAFETY: module invariant.
        F32x8(unsafe { _mm256_cvtepi32_ps(i.0) })
    }
    #[inline(always)]
    fn bits(m: M8, bit: u32) -> I8 {
        // SAFETY: module invariant.
        I8(unsafe { _mm256_and_si256(_mm256_castps_si256(m.0), _mm256_set1_epi32(bit as i32)) })
    }
    #[inline(always)]
    fn or_int(a: I8, b: I8) -> I8 {
        // SAFETY: module invariant.
        I8(unsafe { _mm256_or_si256(a.0, b.0) })
    }
    #[inline(always)]
    fn int_is_zero(i: I8) -> M8 {
        // SAFETY: module invariant.
        M8(unsafe { _mm256_castsi256_ps(_mm256_cmpeq_epi32(i.0, _mm256_setzero_si256())) })
    }
    #[inline(always)]
    fn has_bit(i: I8, bit: u32) -> M8 {
        // SAFETY: module invariant.
        M8(unsafe {
            let b = _mm256_set1_epi32(bit as i32);
            _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(i.0, b), b))
        })
    }
    #[inline(always)]
    fn load_int(a: &[u32; LANES]) -> I8 {
        // SAFETY: module invariant; `a` is 32 readable bytes (unaligned load).
        I8(unsafe { _mm256_loadu_si256(a.as_ptr().cast::<__m256i>()) })
    }
    #[inline(always)]
    fn store_int(i: I8, out: &mut [u32; LANES]) {
        // SAFETY: module invariant; `out` is 32 writable bytes (unaligned store).
        unsafe { _mm256_storeu_si256(out.as_mut_ptr().cast::<__m256i>(), i.0) }
    }
    #[inline(always)]
    fn lut(lut: &Lut, idx: &[u32; LANES]) -> (Self, Self) {
        // Eight scalar 64-bit loads (value | slope << 32) paired into registers, then
        // de-interleaved by one shuffle each. On Zen 3 this beats two `vpgatherdq` (measured).
        // The mask keeps every index < LUT_BINS, so the indexing cannot fail.
        let w = |k: usize| lut[idx[k] as usize & (LUT_BINS - 1)] as i64;
        // SAFETY: module invariant (register operations only).
        unsafe {
            // Pixels 0, 1, 4, 5 and 2, 3, 6, 7: `shufps` works within 128-bit halves, so this
            // order puts every lane in place without a cross-half permute.
            let g0 = _mm256_set_epi64x(w(5), w(4), w(1), w(0));
            let g1 = _mm256_set_epi64x(w(7), w(6), w(3), w(2));
            let (g0, g1) = (_mm256_castsi256_ps(g0), _mm256_castsi256_ps(g1));
            // [v0 s0 v1 s1 | v4 s4 v5 s5], [v2 s2 v3 s3 | v6 s6 v7 s7] → [v0 v1 v2 v3 | v4 …].
            let v = _mm256_shuffle_ps::<0b10_00_10_00>(g0, g1);
            let s = _mm256_shuffle_ps::<0b11_01_11_01>(g0, g1);
            (F32x8(v), F32x8(s))
        }
    }
    #[inline(always)]
    fn store_mm(mm: I8, valid: M8, out: &mut [u16; LANES]) {
        // SAFETY: module invariant; `out` is 16 writable bytes (unaligned store).
        unsafe {
            let v = _mm256_max_epu32(mm.0, _mm256_set1_epi32(1));
            let v = _mm256_and_si256(v, _mm256_castps_si256(valid.0));
            // mm ≤ 65535 where valid, so the saturating pack is exact.
            let p = _mm_packus_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
            _mm_storeu_si128(out.as_mut_ptr().cast::<__m128i>(), p);
        }
    }
    #[inline(always)]
    fn store_flags(flags: I8, out: &mut [u8; LANES]) {
        // SAFETY: module invariant; `out` is 8 writable bytes (unaligned 64-bit store).
        unsafe {
            let v = flags.0;
            // flags < 256: both packs are exact.
            let p = _mm_packus_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
            let b = _mm_packus_epi16(p, p);
            _mm_storel_epi64(out.as_mut_ptr().cast::<__m128i>(), b);
        }
    }
}
