//! [`Simd`] on x86-64 AVX2: one `__m256` per step, and the tokens [`Avx2`] and [`Avx512`].
//!
//! # Safety
//! An AVX2 intrinsic may only run where the CPU has AVX2. Every method here takes `self: Avx2`,
//! which only [`Avx2::detect`] makes, after `is_x86_feature_detected!` confirmed AVX2 and FMA at
//! run time (the private field keeps any other code from making one): that is the proof each
//! `unsafe` block below relies on for the feature. Register-only operations go through the
//! `avx2!` macro, which demands the token by type; loads and stores have their own `unsafe`
//! block whose SAFETY comment gives the bounds of that access.
#![allow(unsafe_code)]

use super::{LANES, LUT_BINS, Lut, ROUND_MAGIC, ROUND_MASK, Simd};
use std::arch::x86_64::*;

/// Proof that this CPU has AVX2 and FMA (zero-sized; made only by [`Avx2::detect`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Avx2 {
    _detected: (),
}

impl Avx2 {
    /// `Some` only if the CPU reports AVX2 and FMA.
    pub(crate) fn detect() -> Option<Avx2> {
        (is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"))
            .then_some(Avx2 { _detected: () })
    }
}

/// Proof that this CPU has AVX-512 F/BW/VL/DQ as well as AVX2 and FMA (made only by
/// [`Avx512::detect`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Avx512 {
    avx2: Avx2,
}

impl Avx512 {
    /// `Some` only if the CPU reports AVX2, FMA and AVX-512 F/BW/VL/DQ.
    pub(crate) fn detect() -> Option<Avx512> {
        let avx2 = Avx2::detect()?;
        let avx512 = is_x86_feature_detected!("avx512f")
            && is_x86_feature_detected!("avx512bw")
            && is_x86_feature_detected!("avx512vl")
            && is_x86_feature_detected!("avx512dq");
        avx512.then_some(Avx512 { avx2 })
    }

    /// The AVX2 proof it contains.
    pub(crate) fn avx2(self) -> Avx2 {
        self.avx2
    }
}

/// Evaluates `$body`, register intrinsics only (no memory access), given `$token: Avx2`.
macro_rules! avx2 {
    ($token:expr, $body:expr) => {{
        let _proof: Avx2 = $token;
        // SAFETY: `_proof` is an `Avx2`, which exists only after `Avx2::detect` saw AVX2 and
        // FMA on this CPU: the one requirement of register intrinsics (no memory is touched).
        unsafe { $body }
    }};
}

/// Eight `f32` in one AVX register.
#[derive(Debug, Clone, Copy)]
pub(crate) struct F32x8(__m256);

/// Per-lane mask: all-ones or all-zeros `f32` lanes (the `cmpps` result).
#[derive(Debug, Clone, Copy)]
pub(crate) struct M8(__m256);

/// Eight `u32`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct I8(__m256i);

impl Simd for Avx2 {
    type F32 = F32x8;
    type Mask = M8;
    type Int = I8;

    #[inline(always)]
    fn splat(self, v: f32) -> F32x8 {
        F32x8(avx2!(self, _mm256_set1_ps(v)))
    }
    #[inline(always)]
    fn load(self, a: &[f32; LANES]) -> F32x8 {
        // SAFETY: AVX2 by `self`; `a` is 8 f32 = the 32 bytes `loadu` reads (no alignment needed).
        F32x8(unsafe { _mm256_loadu_ps(a.as_ptr()) })
    }
    #[inline(always)]
    fn load_u16(self, a: &[u16; LANES]) -> F32x8 {
        // SAFETY: AVX2 by `self`; `a` is 8 u16 = the 16 bytes `loadu` reads (no alignment needed).
        let v = unsafe { _mm_loadu_si128(a.as_ptr().cast::<__m128i>()) };
        F32x8(avx2!(self, _mm256_cvtepi32_ps(_mm256_cvtepu16_epi32(v))))
    }
    #[inline(always)]
    fn load_f64(self, a: &[f64; LANES]) -> F32x8 {
        let (lo, hi) = a.split_at(4);
        // SAFETY: AVX2 by `self`; `lo` and `hi` are 4 f64 each = the 32 bytes each `loadu`
        // reads (no alignment needed).
        let (lo, hi) = unsafe { (_mm256_loadu_pd(lo.as_ptr()), _mm256_loadu_pd(hi.as_ptr())) };
        F32x8(avx2!(
            self,
            _mm256_set_m128(_mm256_cvtpd_ps(hi), _mm256_cvtpd_ps(lo))
        ))
    }
    #[inline(always)]
    fn store(self, v: F32x8, out: &mut [f32; LANES]) {
        // SAFETY: AVX2 by `self`; `out` is 8 f32 = the 32 bytes `storeu` writes (unaligned).
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v.0) }
    }
    #[inline(always)]
    fn add(self, a: F32x8, b: F32x8) -> F32x8 {
        F32x8(avx2!(self, _mm256_add_ps(a.0, b.0)))
    }
    #[inline(always)]
    fn sub(self, a: F32x8, b: F32x8) -> F32x8 {
        F32x8(avx2!(self, _mm256_sub_ps(a.0, b.0)))
    }
    #[inline(always)]
    fn mul(self, a: F32x8, b: F32x8) -> F32x8 {
        F32x8(avx2!(self, _mm256_mul_ps(a.0, b.0)))
    }
    #[inline(always)]
    fn div(self, a: F32x8, b: F32x8) -> F32x8 {
        F32x8(avx2!(self, _mm256_div_ps(a.0, b.0)))
    }
    #[inline(always)]
    fn sqrt(self, a: F32x8) -> F32x8 {
        F32x8(avx2!(self, _mm256_sqrt_ps(a.0)))
    }
    #[inline(always)]
    fn abs(self, a: F32x8) -> F32x8 {
        F32x8(avx2!(self, _mm256_andnot_ps(_mm256_set1_ps(-0.0), a.0)))
    }
    #[inline(always)]
    fn min(self, a: F32x8, b: F32x8) -> F32x8 {
        // `minps(a, b)` is `a < b ? a : b`, the trait's definition.
        F32x8(avx2!(self, _mm256_min_ps(a.0, b.0)))
    }
    #[inline(always)]
    fn max(self, a: F32x8, b: F32x8) -> F32x8 {
        F32x8(avx2!(self, _mm256_max_ps(a.0, b.0)))
    }
    #[inline(always)]
    fn lt(self, a: F32x8, b: F32x8) -> M8 {
        M8(avx2!(self, _mm256_cmp_ps::<_CMP_LT_OQ>(a.0, b.0)))
    }
    #[inline(always)]
    fn le(self, a: F32x8, b: F32x8) -> M8 {
        M8(avx2!(self, _mm256_cmp_ps::<_CMP_LE_OQ>(a.0, b.0)))
    }
    #[inline(always)]
    fn select(self, m: M8, a: F32x8, b: F32x8) -> F32x8 {
        F32x8(avx2!(self, _mm256_blendv_ps(b.0, a.0, m.0)))
    }
    #[inline(always)]
    fn or(self, a: M8, b: M8) -> M8 {
        M8(avx2!(self, _mm256_or_ps(a.0, b.0)))
    }
    #[inline(always)]
    fn and(self, a: M8, b: M8) -> M8 {
        M8(avx2!(self, _mm256_and_ps(a.0, b.0)))
    }
    #[inline(always)]
    fn not(self, a: M8) -> M8 {
        M8(avx2!(
            self,
            _mm256_xor_ps(a.0, _mm256_castsi256_ps(_mm256_set1_epi32(-1)))
        ))
    }
    #[inline(always)]
    fn round_low22(self, a: F32x8) -> I8 {
        I8(avx2!(self, {
            let v = _mm256_castps_si256(_mm256_add_ps(a.0, _mm256_set1_ps(ROUND_MAGIC)));
            _mm256_and_si256(v, _mm256_set1_epi32(ROUND_MASK as i32))
        }))
    }
    #[inline(always)]
    fn int_to_f32(self, i: I8) -> F32x8 {
        F32x8(avx2!(self, _mm256_cvtepi32_ps(i.0)))
    }
    #[inline(always)]
    fn bits(self, m: M8, bit: u32) -> I8 {
        I8(avx2!(
            self,
            _mm256_and_si256(_mm256_castps_si256(m.0), _mm256_set1_epi32(bit as i32))
        ))
    }
    #[inline(always)]
    fn or_int(self, a: I8, b: I8) -> I8 {
        I8(avx2!(self, _mm256_or_si256(a.0, b.0)))
    }
    #[inline(always)]
    fn int_is_zero(self, i: I8) -> M8 {
        M8(avx2!(
            self,
            _mm256_castsi256_ps(_mm256_cmpeq_epi32(i.0, _mm256_setzero_si256()))
        ))
    }
    #[inline(always)]
    fn has_bit(self, i: I8, bit: u32) -> M8 {
        M8(avx2!(self, {
            let b = _mm256_set1_epi32(bit as i32);
            _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(i.0, b), b))
        }))
    }
    #[inline(always)]
    fn load_int(self, a: &[u32; LANES]) -> I8 {
        // SAFETY: AVX2 by `self`; `a` is 8 u32 = the 32 bytes `loadu` reads (no alignment needed).
        I8(unsafe { _mm256_loadu_si256(a.as_ptr().cast::<__m256i>()) })
    }
    #[inline(always)]
    fn store_int(self, i: I8, out: &mut [u32; LANES]) {
        // SAFETY: AVX2 by `self`; `out` is 8 u32 = the 32 bytes `storeu` writes (unaligned).
        unsafe { _mm256_storeu_si256(out.as_mut_ptr().cast::<__m256i>(), i.0) }
    }
    #[inline(always)]
    fn lut(self, lut: &Lut, idx: &[u32; LANES]) -> (F32x8, F32x8) {
        // Eight scalar 64-bit loads (value | slope << 32) paired into registers, then
        // de-interleaved by one shuffle each. On Zen 3 this beats two `vpgatherdq` (measured).
        // The mask keeps every index < LUT_BINS, so the indexing cannot fail.
        let w = |k: usize| lut[idx[k] as usize & (LUT_BINS - 1)] as i64;
        // Pixels 0, 1, 4, 5 and 2, 3, 6, 7: `shufps` works within 128-bit halves, so this
        // order puts every lane in place without a cross-half permute.
        let (w0, w1, w2, w3, w4, w5, w6, w7) = (w(0), w(1), w(2), w(3), w(4), w(5), w(6), w(7));
        avx2!(self, {
            let g0 = _mm256_castsi256_ps(_mm256_set_epi64x(w5, w4, w1, w0));
            let g1 = _mm256_castsi256_ps(_mm256_set_epi64x(w7, w6, w3, w2));
            // [v0 s0 v1 s1 | v4 s4 v5 s5], [v2 s2 v3 s3 | v6 s6 v7 s7] → [v0 v1 v2 v3 | v4 …].
            let v = _mm256_shuffle_ps::<0b10_00_10_00>(g0, g1);
            let s = _mm256_shuffle_ps::<0b11_01_11_01>(g0, g1);
            (F32x8(v), F32x8(s))
        })
    }
    #[inline(always)]
    fn store_mm(self, mm: I8, valid: M8, out: &mut [u16; LANES]) {
        let packed = avx2!(self, {
            let v = _mm256_max_epu32(mm.0, _mm256_set1_epi32(1));
            let v = _mm256_and_si256(v, _mm256_castps_si256(valid.0));
            // mm ≤ 65535 where valid, so the saturating pack is exact.
            _mm_packus_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v))
        });
        // SAFETY: AVX2 by `self`; `out` is 8 u16 = the 16 bytes `storeu` writes (unaligned).
        unsafe { _mm_storeu_si128(out.as_mut_ptr().cast::<__m128i>(), packed) }
    }
    #[inline(always)]
    fn store_flags(self, flags: I8, out: &mut [u8; LANES]) {
        let packed = avx2!(self, {
            let v = flags.0;
            // flags < 256: both packs are exact.
            let p = _mm_packus_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
            _mm_packus_epi16(p, p)
        });
        // SAFETY: AVX2 by `self`; `out` is 8 u8 = the 8 bytes `storel_epi64` writes (its low
        // 64 bits; unaligned).
        unsafe { _mm_storel_epi64(out.as_mut_ptr().cast::<__m128i>(), packed) }
    }
}
