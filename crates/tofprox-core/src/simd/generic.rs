//! Portable [`Lanes`]: eight-element arrays with element-wise loops, which the compiler
//! vectorises for the target's baseline (SSE2 on x86-64, NEON on aarch64). This is the reference
//! the other levels are tested against.

use super::{LANES, LUT_BINS, Lanes, Lut, ROUND_MAGIC, ROUND_MASK};

/// Eight `f32` in an array.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Arr(pub(crate) [f32; LANES]);

#[inline(always)]
fn map(a: Arr, f: impl Fn(f32) -> f32) -> Arr {
    Arr(a.0.map(f))
}

#[inline(always)]
fn zip(a: Arr, b: Arr, f: impl Fn(f32, f32) -> f32) -> Arr {
    Arr(std::array::from_fn(|i| f(a.0[i], b.0[i])))
}

#[inline(always)]
fn cmp(a: Arr, b: Arr, f: impl Fn(f32, f32) -> bool) -> [bool; LANES] {
    std::array::from_fn(|i| f(a.0[i], b.0[i]))
}

impl Lanes for Arr {
    type Mask = [bool; LANES];
    type Int = [u32; LANES];

    #[inline(always)]
    fn splat(v: f32) -> Self {
        Arr([v; LANES])
    }
    #[inline(always)]
    fn load(a: &[f32; LANES]) -> Self {
        Arr(*a)
    }
    #[inline(always)]
    fn from_u16(a: &[u16; LANES]) -> Self {
        Arr(a.map(f32::from))
    }
    #[inline(always)]
    fn from_f64(a: &[f64; LANES]) -> Self {
        Arr(a.map(|v| v as f32))
    }
    #[inline(always)]
    fn store(self, out: &mut [f32; LANES]) {
        *out = self.0;
    }
    #[inline(always)]
    fn add(self, b: Self) -> Self {
        zip(self, b, |x, y| x + y)
    }
    #[inline(always)]
    fn sub(self, b: Self) -> Self {
        zip(self, b, |x, y| x - y)
    }
    #[inline(always)]
    fn mul(self, b: Self) -> Self {
        zip(self, b, |x, y| x * y)
    }
    #[inline(always)]
    fn div(self, b: Self) -> Self {
        zip(self, b, |x, y| x / y)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        map(self, f32::sqrt)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        map(self, f32::abs)
    }
    #[inline(always)]
    fn min(self, b: Self) -> Self {
        zip(self, b, |x, y| if x < y { x } else { y })
    }
    #[inline(always)]
    fn max(self, b: Self) -> Self {
        zip(self, b, |x, y| if x > y { x } else { y })
    }
    #[inline(always)]
    fn lt(self, b: Self) -> Self::Mask {
        cmp(self, b, |x, y| x < y)
    }
    #[inline(always)]
    fn le(self, b: Self) -> Self::Mask {
        cmp(self, b, |x, y| x <= y)
    }
    #[inline(always)]
    fn is_finite(self) -> Self::Mask {
        self.0.map(f32::is_finite)
    }
    #[inline(always)]
    fn select(m: Self::Mask, a: Self, b: Self) -> Self {
        Arr(std::array::from_fn(|i| if m[i] { a.0[i] } else { b.0[i] }))
    }
    #[inline(always)]
    fn or(a: Self::Mask, b: Self::Mask) -> Self::Mask {
        std::array::from_fn(|i| a[i] | b[i])
    }
    #[inline(always)]
    fn and(a: Self::Mask, b: Self::Mask) -> Self::Mask {
        std::array::from_fn(|i| a[i] & b[i])
    }
    #[inline(always)]
    fn not(a: Self::Mask) -> Self::Mask {
        a.map(|v| !v)
    }
    #[inline(always)]
    fn xor(a: Self::Mask, b: Self::Mask) -> Self::Mask {
        std::array::from_fn(|i| a[i] ^ b[i])
    }
    #[inline(always)]
    fn neg_where(m: Self::Mask, a: Self) -> Self {
        Arr(std::array::from_fn(|i| if m[i] { -a.0[i] } else { a.0[i] }))
    }
    #[inline(always)]
    fn all_true() -> Self::Mask {
        [true; LANES]
    }
    #[inline(always)]
    fn round_low22(self) -> Self::Int {
        self.0.map(|v| (v + ROUND_MAGIC).to_bits() & ROUND_MASK)
    }
    #[inline(always)]
    fn int_to_f32(i: Self::Int) -> Self {
        Arr(i.map(|v| v as i32 as f32))
    }
    #[inline(always)]
    fn bits(m: Self::Mask, bit: u32) -> Self::Int {
        m.map(|v| if v { bit } else { 0 })
    }
    #[inline(always)]
    fn or_int(a: Self::Int, b: Self::Int) -> Self::Int {
        std::array::from_fn(|i| a[i] | b[i])
    }
    #[inline(always)]
    fn int_is_zero(i: Self::Int) -> Self::Mask {
        i.map(|v| v == 0)
    }
    #[inline(always)]
    fn has_bit(i: Self::Int, bit: u32) -> Self::Mask {
        i.map(|v| v & bit != 0)
    }
    #[inline(always)]
    fn load_int(a: &[u32; LANES]) -> Self::Int {
        *a
    }
    #[inline(always)]
    fn store_int(i: Self::Int, out: &mut [u32; LANES]) {
        *out = i;
    }
    #[inline(always)]
    fn lut(lut: &Lut, idx: &[u32; LANES]) -> (Self, Self) {
        let w = idx.map(|i| lut[i as usize & (LUT_BINS - 1)]);
        (
            Arr(w.map(|w| f32::from_bits(w as u32))),
            Arr(w.map(|w| f32::from_bits((w >> 32) as u32))),
        )
    }
    #[inline(always)]
    fn store_mm(mm: Self::Int, valid: Self::Mask, out: &mut [u16; LANES]) {
        for i in 0..LANES {
            out[i] = if valid[i] { mm[i].max(1) as u16 } else { 0 };
        }
    }
    #[inline(always)]
    fn store_flags(flags: Self::Int, out: &mut [u8; LANES]) {
        *out = flags.map(|f| f as u8);
    }
}
