//! The instruction sets the per-pixel kernel runs with, and the eight-lane vector abstraction it
//! is written against once.
//!
//! [`crate::pipeline`]'s kernel is one generic function over [`Lanes`]; each instruction set
//! implements `Lanes` ([`generic`] with plain arrays, `avx2` with `__m256`, `neon` with two
//! `float32x4_t`). Every operation is the IEEE-754 single-precision operation of its name — no
//! fused multiply-add, no reciprocal estimates — so all levels give **bit-identical** results on
//! finite input (the equivalence tests assert exact equality). Where lanes hold NaN (only for
//! pixels already flagged non-finite, whose outputs are replaced by 0) the instruction sets may
//! differ in the intermediate NaN payload; the outputs do not.

use crate::CoreError;
use std::fmt;
use std::str::FromStr;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;
pub(crate) mod generic;
#[cfg(target_arch = "aarch64")]
pub(crate) mod neon;

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
/// supports at run time; [`crate::pipeline::Pipeline::set_simd_level`] can force another
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

    /// Whether this CPU can run the level (checked at run time).
    pub fn is_supported(self) -> bool {
        match self {
            SimdLevel::Generic => true,
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx2 => {
                std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
            }
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => {
                use std::arch::is_x86_feature_detected as has;
                SimdLevel::Avx2.is_supported()
                    && has!("avx512f")
                    && has!("avx512bw")
                    && has!("avx512vl")
                    && has!("avx512dq")
            }
            #[cfg(target_arch = "aarch64")]
            SimdLevel::Neon => std::arch::is_aarch64_feature_detected!("neon"),
            #[allow(unreachable_patterns)] // every level is matched on some architecture
            _ => false,
        }
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

/// Eight `f32` lanes and the operations the per-pixel kernel needs (see the module docs: each is
/// the exact IEEE-754 operation, so every implementation gives the same bits).
///
/// `Mask` holds one boolean per lane; `Int` one `u32` per lane. Nominally `pub` only so the sealed
/// `RawSample` loader can name it; the module is private.
pub trait Lanes: Copy {
    /// Per-lane booleans.
    type Mask: Copy;
    /// Per-lane `u32`.
    type Int: Copy;

    fn splat(v: f32) -> Self;
    fn load(a: &[f32; LANES]) -> Self;
    /// Exact conversion of `u16` codes.
    fn from_u16(a: &[u16; LANES]) -> Self;
    /// Round-to-nearest conversion of `f64` codes (as `as f32`).
    fn from_f64(a: &[f64; LANES]) -> Self;
    fn store(self, out: &mut [f32; LANES]);

    fn add(self, b: Self) -> Self;
    fn sub(self, b: Self) -> Self;
    fn mul(self, b: Self) -> Self;
    fn div(self, b: Self) -> Self;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    /// `if self < b { self } else { b }` (equal to `f32::min` unless a lane is NaN).
    fn min(self, b: Self) -> Self;
    /// `if self > b { self } else { b }` (equal to `f32::max` unless a lane is NaN).
    fn max(self, b: Self) -> Self;

    fn lt(self, b: Self) -> Self::Mask;
    fn le(self, b: Self) -> Self::Mask;
    /// `|self| < ∞` (false for NaN).
    fn is_finite(self) -> Self::Mask;
    /// `m ? a : b` per lane.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
    fn or(a: Self::Mask, b: Self::Mask) -> Self::Mask;
    fn and(a: Self::Mask, b: Self::Mask) -> Self::Mask;
    fn not(a: Self::Mask) -> Self::Mask;
    fn xor(a: Self::Mask, b: Self::Mask) -> Self::Mask;
    /// `m ? −a : a` (a sign flip, exact).
    fn neg_where(m: Self::Mask, a: Self) -> Self;
    /// All lanes true.
    fn all_true() -> Self::Mask;

    /// `(self + ROUND_MAGIC).to_bits() & ROUND_MASK`: `round(self)` for `0 ≤ self < 2^22`.
    fn round_low22(self) -> Self::Int;
    /// `i as i32 as f32` (exact for `i < 2^22`).
    fn int_to_f32(i: Self::Int) -> Self;
    /// `bit` where the mask is true, else 0.
    fn bits(m: Self::Mask, bit: u32) -> Self::Int;
    fn or_int(a: Self::Int, b: Self::Int) -> Self::Int;
    /// `i == 0` per lane.
    fn int_is_zero(i: Self::Int) -> Self::Mask;
    /// `i & bit != 0` per lane (`bit` a power of two).
    fn has_bit(i: Self::Int, bit: u32) -> Self::Mask;
    fn load_int(a: &[u32; LANES]) -> Self::Int;
    fn store_int(i: Self::Int, out: &mut [u32; LANES]);

    /// Value and slope of the phase table at `idx & (LUT_BINS − 1)` (the indices are read
    /// from memory: the kernel stored them in pass 1, and every level loads them as scalars).
    fn lut(lut: &Lut, idx: &[u32; LANES]) -> (Self, Self);
    /// `out = valid ? max(mm, 1) as u16 : 0` (mm < 2^22).
    fn store_mm(mm: Self::Int, valid: Self::Mask, out: &mut [u16; LANES]);
    /// `out = flags as u8`.
    fn store_flags(flags: Self::Int, out: &mut [u8; LANES]);
}
