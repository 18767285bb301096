//! [`Simd`] in portable code: eight-element arrays with element-wise loops, which the compiler
//! vectorises for the target's baseline (SSE2 on x86-64, NEON on aarch64). This is the reference
//! the other levels are tested against.

use super::{LANES, LUT_BINS, Lut, ROUND_MAGIC, ROUND_MASK, Simd};

/// The portable instruction set's token: every CPU has it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Portable;

#[inline(always)]
fn zip(a: [f32; LANES], b: [f32; LANES], f: impl Fn(f32, f32) -> f32) -> [f32; LANES] {
    std::array::from_fn(|i| f(a[i], b[i]))
}

#[inline(always)]
fn cmp(a: [f32; LANES], b: [f32; LANES], f: impl Fn(f32, f32) -> bool) -> [bool; LANES] {
    std::array::from_fn(|i| f(a[i], b[i]))
}

#[inline(always)]
fn zip_mask(a: [bool; LANES], b: [bool; LANES], f: impl Fn(bool, bool) -> bool) -> [bool; LANES] {
    std::array::from_fn(|i| f(a[i], b[i]))
}

impl Simd for Portable {
    type F32 = [f32; LANES];
    type Mask = [bool; LANES];
    type Int = [u32; LANES];

    #[inline(always)]
    fn splat(self, v: f32) -> Self::F32 {
        [v; LANES]
    }
    #[inline(always)]
    fn load(self, a: &[f32; LANES]) -> Self::F32 {
        *a
    }
    #[inline(always)]
    fn load_u16(self, a: &[u16; LANES]) -> Self::F32 {
        a.map(f32::from)
    }
    #[inline(always)]
    fn load_f64(self, a: &[f64; LANES]) -> Self::F32 {
        a.map(|v| v as f32)
    }
    #[inline(always)]
    fn store(self, v: Self::F32, out: &mut [f32; LANES]) {
        *out = v;
    }
    #[inline(always)]
    fn add(self, a: Self::F32, b: Self::F32) -> Self::F32 {
        zip(a, b, |x, y| x + y)
    }
    #[inline(always)]
    fn sub(self, a: Self::F32, b: Self::F32) -> Self::F32 {
        zip(a, b, |x, y| x - y)
    }
    #[inline(always)]
    fn mul(self, a: Self::F32, b: Self::F32) -> Self::F32 {
        zip(a, b, |x, y| x * y)
    }
    #[inline(always)]
    fn div(self, a: Self::F32, b: Self::F32) -> Self::F32 {
        zip(a, b, |x, y| x / y)
    }
    #[inline(always)]
    fn sqrt(self, a: Self::F32) -> Self::F32 {
        a.map(f32::sqrt)
    }
    #[inline(always)]
    fn abs(self, a: Self::F32) -> Self::F32 {
        a.map(f32::abs)
    }
    #[inline(always)]
    fn min(self, a: Self::F32, b: Self::F32) -> Self::F32 {
        zip(a, b, |x, y| if x < y { x } else { y })
    }
    #[inline(always)]
    fn max(self, a: Self::F32, b: Self::F32) -> Self::F32 {
        zip(a, b, |x, y| if x > y { x } else { y })
    }
    #[inline(always)]
    fn lt(self, a: Self::F32, b: Self::F32) -> Self::Mask {
        cmp(a, b, |x, y| x < y)
    }
    #[inline(always)]
    fn le(self, a: Self::F32, b: Self::F32) -> Self::Mask {
        cmp(a, b, |x, y| x <= y)
    }
    #[inline(always)]
    fn is_finite(self, a: Self::F32) -> Self::Mask {
        a.map(f32::is_finite)
    }
    #[inline(always)]
    fn select(self, m: Self::Mask, a: Self::F32, b: Self::F32) -> Self::F32 {
        std::array::from_fn(|i| if m[i] { a[i] } else { b[i] })
    }
    #[inline(always)]
    fn or(self, a: Self::Mask, b: Self::Mask) -> Self::Mask {
        zip_mask(a, b, |x, y| x | y)
    }
    #[inline(always)]
    fn and(self, a: Self::Mask, b: Self::Mask) -> Self::Mask {
        zip_mask(a, b, |x, y| x & y)
    }
    #[inline(always)]
    fn not(self, a: Self::Mask) -> Self::Mask {
        a.map(|v| !v)
    }
    #[inline(always)]
    fn round_low22(self, a: Self::F32) -> Self::Int {
        a.map(|v| (v + ROUND_MAGIC).to_bits() & ROUND_MASK)
    }
    #[inline(always)]
    fn int_to_f32(self, i: Self::Int) -> Self::F32 {
        i.map(|v| v as i32 as f32)
    }
    #[inline(always)]
    fn bits(self, m: Self::Mask, bit: u32) -> Self::Int {
        m.map(|v| if v { bit } else { 0 })
    }
    #[inline(always)]
    fn or_int(self, a: Self::Int, b: Self::Int) -> Self::Int {
        std::array::from_fn(|i| a[i] | b[i])
    }
    #[inline(always)]
    fn int_is_zero(self, i: Self::Int) -> Self::Mask {
        i.map(|v| v == 0)
    }
    #[inline(always)]
    fn has_bit(self, i: Self::Int, bit: u32) -> Self::Mask {
        i.map(|v| v & bit != 0)
    }
    #[inline(always)]
    fn load_int(self, a: &[u32; LANES]) -> Self::Int {
        *a
    }
    #[inline(always)]
    fn store_int(self, i: Self::Int, out: &mut [u32; LANES]) {
        *out = i;
    }
    #[inline(always)]
    fn lut(self, lut: &Lut, idx: &[u32; LANES]) -> (Self::F32, Self::F32) {
        let w = idx.map(|i| lut[i as usize & (LUT_BINS - 1)]);
        (
            w.map(|w| f32::from_bits(w as u32)),
            w.map(|w| f32::from_bits((w >> 32) as u32)),
        )
    }
    #[inline(always)]
    fn store_mm(self, mm: Self::Int, valid: Self::Mask, out: &mut [u16; LANES]) {
        for i in 0..LANES {
            out[i] = if valid[i] { mm[i].max(1) as u16 } else { 0 };
        }
    }
    #[inline(always)]
    fn store_flags(self, flags: Self::Int, out: &mut [u8; LANES]) {
        *out = flags.map(|f| f as u8);
    }
}
