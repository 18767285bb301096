//! The instruction sets the per-pixel kernel runs with, the tokens that prove a CPU has them,
//! and the eight-lane vector operations the kernel is written against once.
//!
//! # One style: a token proves the CPU feature
//! Each instruction set has a zero-sized token that can only be made where the CPU has it:
//! [`Portable`] (always), `avx2::Avx2` and `avx2::Avx512` (`detect()` returns `Some` only when
//! the CPU reports the features at run time), `neon::Neon` (`detect()`: NEON, the aarch64
//! baseline, confirmed at run time). The token implements [`Simd`], so every vector operation is
//! a method of the proof (`s.add(a, b)`): an `unsafe` intrinsic call inside is sound by
//! construction, and its SAFETY comment only has to argue the memory access, if any. The
//! `#[target_feature]` entry points of a kernel (`pipeline::kernel::kernel_avx2`, the ROI pass of
//! `proximity`) take their token as an argument, so the one `unsafe` call into each names the
//! proof it relies on.
//!
//! The pipeline's kernel is one generic function over [`Simd`] ([`Portable`] with plain
//! arrays, `Avx2` with `__m256`, `Neon` with two `float32x4_t`). Every operation is the IEEE-754
//! single-precision operation of its name — no fused multiply-add, no reciprocal estimates — so
//! all levels give **bit-identical** results on finite input (the equivalence tests assert exact
//! equality). Where lanes hold NaN (only for pixels already flagged non-finite, whose outputs are
//! replaced by 0) the instruction sets may differ in the intermediate NaN payload; the outputs do
//! not.

use crate::CoreError;
pub(crate) use portable::Portable;
use std::fmt;
use std::str::FromStr;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;
#[cfg(target_arch = "aarch64")]
pub(crate) mod neon;
mod portable;

/// Lanes per vector step of the kernel (one `__m256` on AVX2, two `float32x4_t` on NEON).
pub(crate) const LANES: usize = 8;

/// Bins per octant of the pipeline's phase table, over `t = min(|x|, |y|) / max(|x|, |y|)` in
/// `[0, 1]` (power of two: `t · LUT_T_BINS` is exact).
pub(crate) const LUT_T_BINS: usize = 512;

/// Bins of the pipeline's phase table: eight octants of [`LUT_T_BINS`] (power of two so the
/// index is a mask; 32 kB, the L1 data cache of the CPUs it targets).
pub(crate) const LUT_BINS: usize = 8 * LUT_T_BINS;

/// The phase table as the kernel reads it: per bin `value | slope << 32` (f32 bits), so one
/// 64-bit load fetches both.
pub(crate) type Lut = [u64; LUT_BINS];

/// 1.5 · 2^23: `(x + ROUND_MAGIC).to_bits() & 0x3F_FFFF` is `round(x)` for `0 ≤ x < 2^22`
/// (float→integer without a saturating cast, which does not vectorise).
pub(crate) const ROUND_MAGIC: f32 = 12_582_912.0;

/// Mask of the low 22 mantissa bits that hold the rounded integer after adding [`ROUND_MAGIC`].
pub(crate) const ROUND_MASK: u32 = 0x3F_FFFF;

/// Instruction set of the per-pixel kernel. [`SimdLevel::detect`] picks the best one the CPU
/// supports at run time; the pipeline's `Pipeline::set_simd_level` can force another
/// supported one (benchmarks, equivalence tests). Serialised as `"generic"`, `"avx2"`,
/// `"avx512"`, `"neon"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SimdLevel {
    /// Portable code (plain arrays the compiler vectorises for the target's baseline).
    Generic,
    /// x86-64 with AVX2 and FMA: `__m256` intrinsics.
    Avx2,
    /// x86-64 with AVX-512 F/BW/VL/DQ: the AVX2 kernel compiled with AVX-512 enabled.
    Avx512,
    /// aarch64 Advanced SIMD (NEON, part of the aarch64 baseline): `float32x4_t` intrinsics.
    Neon,
}

impl SimdLevel {
    /// Every level, in a fixed order.
    pub const ALL: [SimdLevel; 4] = [
        SimdLevel::Generic,
        SimdLevel::Avx2,
        SimdLevel::Avx512,
        SimdLevel::Neon,
    ];

    /// The canonical string.
    pub fn as_str(self) -> &'static str {
        match self {
            SimdLevel::Generic => "generic",
            SimdLevel::Avx2 => "avx2",
            SimdLevel::Avx512 => "avx512",
            SimdLevel::Neon => "neon",
        }
    }

    /// Whether this CPU can run the level (checked at run time, by the level's token).
    pub fn is_supported(self) -> bool {
        Isa::of(self).is_some()
    }

    /// The best level this CPU supports.
    pub fn detect() -> SimdLevel {
        [SimdLevel::Avx512, SimdLevel::Avx2, SimdLevel::Neon]
            .into_iter()
            .find(|l| l.is_supported())
            .unwrap_or(SimdLevel::Generic)
    }

    /// The levels this CPU supports, [`SimdLevel::Generic`] first.
    pub fn supported() -> impl Iterator<Item = SimdLevel> {
        SimdLevel::ALL.into_iter().filter(|l| l.is_supported())
    }
}

impl fmt::Display for SimdLevel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for SimdLevel {
    type Err = CoreError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        SimdLevel::ALL
            .into_iter()
            .find(|l| l.as_str() == s.trim().to_ascii_lowercase())
            .ok_or_else(|| {
                CoreError::param(
                    "simd_level",
                    format!("unknown level {s:?}, expected generic, avx2, avx512 or neon"),
                )
            })
    }
}

/// An instruction set the kernel can run with, held as the proof that this CPU has it.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Isa {
    /// [`SimdLevel::Generic`].
    Portable(Portable),
    /// [`SimdLevel::Avx2`].
    #[cfg(target_arch = "x86_64")]
    Avx2(avx2::Avx2),
    /// [`SimdLevel::Avx512`].
    #[cfg(target_arch = "x86_64")]
    Avx512(avx2::Avx512),
    /// [`SimdLevel::Neon`].
    #[cfg(target_arch = "aarch64")]
    Neon(neon::Neon),
}

impl Isa {
    /// The level's token, if this CPU has the level.
    pub(crate) fn of(level: SimdLevel) -> Option<Isa> {
        match level {
            SimdLevel::Generic => Some(Isa::Portable(Portable)),
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx2 => avx2::Avx2::detect().map(Isa::Avx2),
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => avx2::Avx512::detect().map(Isa::Avx512),
            #[cfg(target_arch = "aarch64")]
            SimdLevel::Neon => neon::Neon::detect().map(Isa::Neon),
            #[allow(unreachable_patterns)] // every level is matched on some architecture
            _ => None,
        }
    }

    /// The best instruction set this CPU has.
    pub(crate) fn detect() -> Isa {
        Isa::of(SimdLevel::detect()).unwrap_or(Isa::Portable(Portable))
    }

    /// Its level.
    pub(crate) fn level(self) -> SimdLevel {
        match self {
            Isa::Portable(_) => SimdLevel::Generic,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2(_) => SimdLevel::Avx2,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512(_) => SimdLevel::Avx512,
            #[cfg(target_arch = "aarch64")]
            Isa::Neon(_) => SimdLevel::Neon,
        }
    }
}

/// Eight `f32` lanes and the operations the per-pixel kernel needs, implemented by an
/// instruction set's token (module docs): holding `self` proves the CPU can run them. Each is
/// the exact IEEE-754 operation, so every implementation gives the same bits.
///
/// `F32` holds eight `f32`, `Mask` one boolean per lane, `Int` one `u32` per lane. Nominally
/// `pub` only so the sealed `RawSample` loader can name it; the module is private.
pub trait Simd: Copy {
    /// Eight `f32`.
    type F32: Copy;
    /// Per-lane booleans.
    type Mask: Copy;
    /// Per-lane `u32`.
    type Int: Copy;

    /// `v` in every lane.
    fn splat(self, v: f32) -> Self::F32;
    /// Eight `f32` from memory.
    fn load(self, a: &[f32; LANES]) -> Self::F32;
    /// Exact conversion of `u16` codes.
    fn load_u16(self, a: &[u16; LANES]) -> Self::F32;
    /// Round-to-nearest conversion of `f64` codes (as `as f32`).
    fn load_f64(self, a: &[f64; LANES]) -> Self::F32;
    /// Eight `f32` to memory.
    fn store(self, v: Self::F32, out: &mut [f32; LANES]);

    /// `a + b`.
    fn add(self, a: Self::F32, b: Self::F32) -> Self::F32;
    /// `a − b`.
    fn sub(self, a: Self::F32, b: Self::F32) -> Self::F32;
    /// `a · b`.
    fn mul(self, a: Self::F32, b: Self::F32) -> Self::F32;
    /// `a / b`.
    fn div(self, a: Self::F32, b: Self::F32) -> Self::F32;
    /// `√a`.
    fn sqrt(self, a: Self::F32) -> Self::F32;
    /// `|a|`.
    fn abs(self, a: Self::F32) -> Self::F32;
    /// `if a < b { a } else { b }` (equal to `f32::min` unless a lane is NaN).
    fn min(self, a: Self::F32, b: Self::F32) -> Self::F32;
    /// `if a > b { a } else { b }` (equal to `f32::max` unless a lane is NaN).
    fn max(self, a: Self::F32, b: Self::F32) -> Self::F32;

    /// `a < b` (false for NaN).
    fn lt(self, a: Self::F32, b: Self::F32) -> Self::Mask;
    /// `a ≤ b` (false for NaN).
    fn le(self, a: Self::F32, b: Self::F32) -> Self::Mask;
    /// `|a| < ∞` (false for NaN).
    fn is_finite(self, a: Self::F32) -> Self::Mask {
        let inf = self.splat(f32::INFINITY);
        self.lt(self.abs(a), inf)
    }
    /// `m ? a : b` per lane.
    fn select(self, m: Self::Mask, a: Self::F32, b: Self::F32) -> Self::F32;
    /// `a | b` per lane.
    fn or(self, a: Self::Mask, b: Self::Mask) -> Self::Mask;
    /// `a & b` per lane.
    fn and(self, a: Self::Mask, b: Self::Mask) -> Self::Mask;
    /// `!a` per lane.
    fn not(self, a: Self::Mask) -> Self::Mask;

    /// `(a + ROUND_MAGIC).to_bits() & ROUND_MASK`: `round(a)` for `0 ≤ a < 2^22`.
    fn round_low22(self, a: Self::F32) -> Self::Int;
    /// `i as i32 as f32` (exact for `i < 2^22`).
    fn int_to_f32(self, i: Self::Int) -> Self::F32;
    /// `bit` where the mask is true, else 0.
    fn bits(self, m: Self::Mask, bit: u32) -> Self::Int;
    /// `a | b` per lane.
    fn or_int(self, a: Self::Int, b: Self::Int) -> Self::Int;
    /// `i == 0` per lane.
    fn int_is_zero(self, i: Self::Int) -> Self::Mask;
    /// `i & bit != 0` per lane (`bit` a power of two).
    fn has_bit(self, i: Self::Int, bit: u32) -> Self::Mask;
    /// Eight `u32` from memory.
    fn load_int(self, a: &[u32; LANES]) -> Self::Int;
    /// Eight `u32` to memory.
    fn store_int(self, i: Self::Int, out: &mut [u32; LANES]);

    /// Value and slope of the phase table at `idx & (LUT_BINS − 1)` (the indices are read
    /// from memory: the kernel stored them in pass 1, and every level loads them as scalars).
    fn lut(self, lut: &Lut, idx: &[u32; LANES]) -> (Self::F32, Self::F32);
    /// `out = valid ? max(mm, 1) as u16 : 0` (mm < 2^22).
    fn store_mm(self, mm: Self::Int, valid: Self::Mask, out: &mut [u16; LANES]);
    /// `out = flags as u8`.
    fn store_flags(self, flags: Self::Int, out: &mut [u8; LANES]);
}
