//! Near/far proximity detector on top of a [`DepthFrame`] (thesis 3.5: the low-power proximity
//! use case).
//!
//! Per frame, inside the region of interest:
//! - the statistic is the **10th percentile of valid `depth_mm`** (nearest-rank). A low percentile
//!   reacts to an object covering only part of the ROI (a hand in front of a wall) while ignoring a
//!   few outlier pixels (flying pixels, noise); see [`NearFarDetector::with_percentile`];
//! - if the valid fraction is below `min_valid_fraction` the frame has no usable depth: it counts as
//!   **near** when saturated pixels make up at least half of the ROI's invalid pixels (something is
//!   too close / too bright), otherwise as **far**; it is a *reading* (`no_target`: nothing in
//!   range) when pixels without a usable return — amplitude too low, or a near depth no real
//!   target could return ([`FLAG_IMPLAUSIBLE`], see [`crate::radiometry`]) — make up at least half
//!   of the invalid pixels, and no reading otherwise (non-finite or otherwise broken data);
//! - independently, a saturated fraction of the ROI of at least 25 % counts as near.
//!
//! State machine (starts and resets to far): far → near immediately at a near reading
//! (`statistic ≤ near_mm` or saturated); near → far only after `far_debounce` consecutive far
//! readings (`statistic ≥ far_mm` or no target). Readings between the thresholds keep the state
//! (hysteresis) and reset the debounce counter. `changed` is true only on a transition.

use crate::CoreError;
pub use crate::frame::Roi;
use crate::frame::{DepthFrame, FLAG_IMPLAUSIBLE, FLAG_LOW_AMPLITUDE, FLAG_SATURATED};
#[cfg(target_arch = "x86_64")]
use crate::simd::avx2::Avx2;
use ndarray::s;

/// Fraction of saturated ROI pixels that on its own means "near".
pub const SATURATED_NEAR_FRACTION: f32 = 0.25;

/// Default percentile (0..=1) of valid depth used as the ROI statistic.
pub const DEFAULT_PERCENTILE: f32 = 0.10;

/// Near/far detector configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NearFarConfig {
    /// A statistic at or below this is "near" (mm).
    pub near_mm: u32,
    /// A statistic at or above this is "far" (mm); must be ≥ `near_mm` (the gap is the hysteresis).
    pub far_mm: u32,
    /// Region of interest (default: central half).
    pub roi: Roi,
    /// Consecutive far readings needed to switch near → far (0 is treated as 1).
    pub far_debounce: u32,
    /// Minimum fraction (0..=1) of valid ROI pixels for a depth statistic.
    pub min_valid_fraction: f32,
}

impl Default for NearFarConfig {
    fn default() -> Self {
        NearFarConfig {
            near_mm: 250,
            far_mm: 350,
            roi: Roi::default(),
            far_debounce: 3,
            min_valid_fraction: 0.1,
        }
    }
}

/// One detector output.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProximityReading {
    /// Current (debounced) state.
    pub near: bool,
    /// The ROI statistic (mm) when there was enough valid depth, else `None`.
    pub distance_mm: Option<u32>,
    /// True only when `near` changed with this frame.
    pub changed: bool,
    /// Fraction of ROI pixels with valid depth.
    pub valid_fraction: f32,
    /// Nothing in range: no depth statistic and no saturation, because the ROI's pixels saw no
    /// usable return (low amplitude or implausible near depth). A valid far reading.
    pub no_target: bool,
}

/// Near/far detector with hysteresis and far debounce (see the module docs).
#[derive(Debug, Clone)]
pub struct NearFarDetector {
    cfg: NearFarConfig,
    percentile: f32,
    near: bool,
    far_count: u32,
    /// Per ROI pixel its selection key ([`key_of_mm`] of a valid depth, else `INVALID_KEY`).
    scratch: Vec<i16>,
    kernel: KeyKernel,
}

impl NearFarDetector {
    /// Validates the configuration (`near_mm ≤ far_mm`, `far_mm ≤ 65535`,
    /// `min_valid_fraction ∈ [0, 1]`).
    pub fn new(cfg: NearFarConfig) -> Result<Self, CoreError> {
        if cfg.near_mm > cfg.far_mm {
            return Err(CoreError::param(
                "near_mm",
                format!(
                    "near_mm ({}) must be ≤ far_mm ({})",
                    cfg.near_mm, cfg.far_mm
                ),
            ));
        }
        if cfg.far_mm > u16::MAX as u32 {
            return Err(CoreError::param(
                "far_mm",
                format!("must be ≤ 65535, got {}", cfg.far_mm),
            ));
        }
        if !(0.0..=1.0).contains(&cfg.min_valid_fraction) {
            return Err(CoreError::param(
                "min_valid_fraction",
                format!("must be in [0, 1], got {}", cfg.min_valid_fraction),
            ));
        }
        Ok(NearFarDetector {
            cfg,
            percentile: DEFAULT_PERCENTILE,
            near: false,
            far_count: 0,
            scratch: Vec::new(),
            kernel: KeyKernel::detect(),
        })
    }

    /// Uses another percentile (0..=1, 0.5 = median) of valid ROI depth as the statistic.
    pub fn with_percentile(mut self, percentile: f32) -> Result<Self, CoreError> {
        if !(0.0..=1.0).contains(&percentile) {
            return Err(CoreError::param(
                "percentile",
                format!("must be in [0, 1], got {percentile}"),
            ));
        }
        self.percentile = percentile;
        Ok(self)
    }

    /// The configuration.
    pub fn config(&self) -> &NearFarConfig {
        &self.cfg
    }

    /// Current state.
    pub fn is_near(&self) -> bool {
        self.near
    }

    /// Back to the initial state (far, debounce counter cleared).
    pub fn reset(&mut self) {
        self.near = false;
        self.far_count = 0;
    }

    /// Whether `frame` holds pixels that make or hold a near reading: the statistic the next
    /// [`NearFarDetector::update`] would take (the percentile's nearest rank of the ROI's valid
    /// depths, with at least `min_valid_fraction` of them) lies below `far_mm`. Saturation is
    /// not counted. Changes no state.
    pub fn statistic_below_far(&self, frame: &DepthFrame) -> bool {
        let (dr, dc) = frame.depth_mm.dim();
        let (fr, fc) = frame.flags.dim();
        let roi = self.cfg.roi.resolve(dr.min(fr), dc.min(fc));
        let rows = roi.row0..roi.row0 + roi.rows;
        let cols = roi.col0..roi.col0 + roi.cols;
        let flags = frame.flags.slice(s![rows.clone(), cols.clone()]);
        let depth = frame.depth_mm.slice(s![rows, cols]);
        let (mut valid, mut below) = (0usize, 0usize);
        for (&f, &mm) in flags.iter().zip(depth.iter()) {
            let ok = f == 0 && mm != 0;
            valid += usize::from(ok);
            below += usize::from(ok && u32::from(mm) < self.cfg.far_mm);
        }
        let total = roi.rows * roi.cols;
        if valid == 0 || (valid as f32) < self.cfg.min_valid_fraction * total as f32 {
            return false;
        }
        let rank = ((self.percentile * valid as f32).ceil() as usize).clamp(1, valid);
        below >= rank
    }

    /// Feeds one frame. Allocation-free after the first frame of a given ROI size.
    pub fn update(&mut self, frame: &DepthFrame) -> ProximityReading {
        // Malformed frames (flags and depth of different shapes) are read on their common part.
        let (dr, dc) = frame.depth_mm.dim();
        let (fr, fc) = frame.flags.dim();
        let roi = self.cfg.roi.resolve(dr.min(fr), dc.min(fc));
        let total = roi.rows * roi.cols;
        // One pass over the ROI: the counts, and per pixel a key (its depth when valid) in a
        // reused buffer (allocates only when the ROI grows).
        self.scratch.clear();
        self.scratch.resize(total, INVALID_KEY);
        let tally = match (frame.flags.as_slice(), frame.depth_mm.as_slice()) {
            (Some(flags), Some(depth)) => {
                let rows = RoiRows {
                    flags,
                    flags_stride: fc,
                    depth,
                    depth_stride: dc,
                    roi,
                };
                self.kernel.tally(&rows, &mut self.scratch)
            }
            // Frames built with another memory order: the same pass through ndarray's iterators.
            _ => {
                let rows = roi.row0..roi.row0 + roi.rows;
                let cols = roi.col0..roi.col0 + roi.cols;
                let flags = frame.flags.slice(s![rows.clone(), cols.clone()]);
                let depth = frame.depth_mm.slice(s![rows, cols]);
                let mut tally = Tally::default();
                for (f, (d, keys)) in flags.iter().zip(depth.iter().zip(&mut self.scratch)) {
                    tally_pixels(
                        std::iter::once((f, d)),
                        std::slice::from_mut(keys),
                        &mut tally,
                    );
                }
                tally
            }
        };
        let Tally {
            saturated,
            no_return,
            valid,
            ..
        } = tally;
        let valid_fraction = if total == 0 {
            0.0
        } else {
            valid as f32 / total as f32
        };
        let saturated_fraction = if total == 0 {
            0.0
        } else {
            saturated as f32 / total as f32
        };
        let invalid = total - valid.min(total);

        let enough = total > 0 && valid > 0 && valid_fraction >= self.cfg.min_valid_fraction;
        let distance_mm = if enough {
            let rank = ((self.percentile * valid as f32).ceil() as usize).clamp(1, valid);
            Some(u32::from(self.kernel.nearest_rank_mm(
                &self.scratch,
                rank,
                &tally,
            )))
        } else {
            None
        };
        let saturated_near = saturated_fraction >= SATURATED_NEAR_FRACTION
            || (!enough && saturated > 0 && 2 * saturated >= invalid);
        let no_target = total > 0 && !enough && !saturated_near && 2 * no_return >= invalid;
        let reading_near = saturated_near || distance_mm.is_some_and(|d| d <= self.cfg.near_mm);
        let reading_far = !reading_near && distance_mm.is_none_or(|d| d >= self.cfg.far_mm);

        let was_near = self.near;
        if reading_near {
            self.near = true;
            self.far_count = 0;
        } else if reading_far {
            if self.near {
                self.far_count = self.far_count.saturating_add(1);
                if self.far_count >= self.cfg.far_debounce.max(1) {
                    self.near = false;
                    self.far_count = 0;
                }
            }
        } else {
            // Between the thresholds: hysteresis keeps the state, debounce restarts.
            self.far_count = 0;
        }
        ProximityReading {
            near: self.near,
            distance_mm,
            changed: self.near != was_near,
            valid_fraction,
            no_target,
        }
    }
}

/// Key of a pixel without a valid depth: not below any valid key, and never counted by the
/// selection (which only compares with values below the largest valid key).
const INVALID_KEY: i16 = i16::MAX;

/// The selection key of a valid depth (1..=65535 mm): `mm − 32768` as `i16`, so that the signed
/// 16-bit compare every SIMD baseline has (SSE2 `pcmpgtw`, NEON `cmgt`) orders depths.
#[inline(always)]
fn key_of_mm(mm: u16) -> i16 {
    (mm ^ 0x8000) as i16
}

/// The depth (mm) of a key from [`key_of_mm`].
fn mm_of_key(key: i16) -> u16 {
    (key as u16) ^ 0x8000
}

/// What the ROI pass counts.
#[derive(Debug, Clone, Copy)]
struct Tally {
    saturated: usize,
    /// Not saturated, and low amplitude or an implausible near depth: no usable return.
    no_return: usize,
    /// Flags 0 and a non-zero depth.
    valid: usize,
    /// Smallest and largest valid key (`INVALID_KEY` and `i16::MIN` when nothing is valid).
    min_key: i16,
    max_key: i16,
}

impl Default for Tally {
    fn default() -> Self {
        Tally {
            saturated: 0,
            no_return: 0,
            valid: 0,
            min_key: INVALID_KEY,
            max_key: i16::MIN,
        }
    }
}

/// The ROI pass over at most `u16::MAX` pixels `(flags, depth_mm)`: a key per pixel into `keys`,
/// the counts and the valid keys' range into `t`. One branch-free loop with `u16` / `i16`
/// reductions, which the compiler vectorises when the pixels come from slices.
#[inline(always)]
fn tally_pixels<'a>(
    pixels: impl Iterator<Item = (&'a u8, &'a u16)>,
    keys: &mut [i16],
    t: &mut Tally,
) {
    let (mut saturated, mut no_return, mut valid) = (0u16, 0u16, 0u16);
    let (mut min_key, mut max_key) = (INVALID_KEY, i16::MIN);
    for ((&f, &mm), key) in pixels.zip(keys.iter_mut()) {
        let sat = f & FLAG_SATURATED != 0;
        let ok = (f == 0) & (mm != 0);
        saturated += u16::from(sat);
        no_return += u16::from(!sat & (f & (FLAG_LOW_AMPLITUDE | FLAG_IMPLAUSIBLE) != 0));
        valid += u16::from(ok);
        let k = key_of_mm(mm);
        *key = if ok { k } else { INVALID_KEY };
        min_key = min_key.min(*key);
        max_key = max_key.max(if ok { k } else { i16::MIN });
    }
    t.saturated += usize::from(saturated);
    t.no_return += usize::from(no_return);
    t.valid += usize::from(valid);
    t.min_key = t.min_key.min(min_key);
    t.max_key = t.max_key.max(max_key);
}

/// The ROI's rows in two standard-layout arrays (`roi` resolved within both).
struct RoiRows<'a> {
    flags: &'a [u8],
    flags_stride: usize,
    depth: &'a [u16],
    depth_stride: usize,
    roi: Roi,
}

/// The ROI pass over contiguous rows: `keys` holds `roi.rows × roi.cols` keys.
#[inline(always)]
fn tally_rows(rows: &RoiRows<'_>, keys: &mut [i16]) -> Tally {
    let roi = rows.roi;
    let mut t = Tally::default();
    let piece = usize::from(u16::MAX); // the counts are `u16` lanes
    for (r, keys) in (roi.row0..).zip(keys.chunks_exact_mut(roi.cols.max(1))) {
        let row = |stride: usize| r * stride + roi.col0..r * stride + roi.col0 + roi.cols;
        // In range (the ROI is resolved within both arrays); `get` keeps a bad stride harmless.
        let f = rows.flags.get(row(rows.flags_stride)).unwrap_or_default();
        let d = rows.depth.get(row(rows.depth_stride)).unwrap_or_default();
        for ((f, d), k) in f
            .chunks(piece)
            .zip(d.chunks(piece))
            .zip(keys.chunks_mut(piece))
        {
            tally_pixels(f.iter().zip(d), k, &mut t);
        }
    }
    t
}

/// The instruction set the ROI pass and the counting passes run with: the portable code (SSE2 on
/// x86-64, NEON on aarch64, both baselines) or, where the CPU has it, AVX2 (16 keys per compare
/// instead of 8), held as its proof, the pipeline's [`Avx2`] token (`simd`'s module docs): the
/// counting passes are the portable code compiled for AVX2, the ROI pass is written with AVX2
/// intrinsics. Both give the same result (tested).
#[derive(Debug, Clone, Copy)]
enum KeyKernel {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2(Avx2),
}

impl KeyKernel {
    fn detect() -> KeyKernel {
        #[cfg(target_arch = "x86_64")]
        if let Some(proof) = Avx2::detect() {
            return KeyKernel::Avx2(proof);
        }
        KeyKernel::Portable
    }

    fn tally(self, rows: &RoiRows<'_>, keys: &mut [i16]) -> Tally {
        match self {
            KeyKernel::Portable => tally_rows(rows, keys),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `avx2::tally_rows` needs AVX2: `proof` is an `Avx2`, which only
            // `Avx2::detect` makes after the CPU reported AVX2 and FMA.
            #[allow(unsafe_code)]
            KeyKernel::Avx2(proof) => unsafe { avx2::tally_rows(proof, rows, keys) },
        }
    }

    fn nearest_rank_mm(self, keys: &[i16], rank: usize, t: &Tally) -> u16 {
        match self {
            KeyKernel::Portable => nearest_rank_mm(keys, rank, t),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `avx2::nearest_rank_mm` needs AVX2: `proof` is an `Avx2` (as in `tally`).
            #[allow(unsafe_code)]
            KeyKernel::Avx2(proof) => unsafe { avx2::nearest_rank_mm(proof, keys, rank, t) },
        }
    }
}

/// The ROI pass with AVX2 intrinsics, and the portable selection compiled with AVX2 enabled.
/// Both entry points take the [`Avx2`] token that proves the CPU has AVX2; inside these
/// `#[target_feature]` functions the register intrinsics are safe calls, and only the loads and
/// stores are `unsafe`, each with the bounds of its access.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{
        FLAG_IMPLAUSIBLE, FLAG_LOW_AMPLITUDE, FLAG_SATURATED, INVALID_KEY, RoiRows, Tally,
    };
    use crate::frame::FLAG_INVALID;
    use crate::simd::avx2::Avx2;
    use std::arch::x86_64::*;

    /// Pixels per block: 16 `u16` lanes of one AVX2 vector.
    const LANES: usize = 16;

    /// Per-lane counts and key range, kept in registers across the ROI's rows (the portable
    /// pass reduces them per row, and runs a row's last `cols mod 16` pixels scalar: on Zen 1 that
    /// per-row work costs about as much as the vector loop for an 86-pixel row).
    struct Counters {
        saturated: __m256i,
        no_return: __m256i,
        valid: __m256i,
        min_key: __m256i,
        max_key: __m256i,
        /// Blocks since the last flush (each adds at most 1 to a lane's `u16` counts).
        blocks: u16,
    }

    impl Counters {
        #[target_feature(enable = "avx2")]
        fn new() -> Counters {
            Counters {
                saturated: _mm256_setzero_si256(),
                no_return: _mm256_setzero_si256(),
                valid: _mm256_setzero_si256(),
                min_key: _mm256_set1_epi16(INVALID_KEY),
                max_key: _mm256_set1_epi16(i16::MIN),
                blocks: 0,
            }
        }

        /// 16 pixels, the rules of [`super::tally_pixels`] with lane masks (all ones = true).
        #[inline]
        #[target_feature(enable = "avx2")]
        fn block(
            &mut self,
            t: &mut Tally,
            f: &[u8; LANES],
            d: &[u16; LANES],
            k: &mut [i16; LANES],
        ) {
            if self.blocks == u16::MAX {
                self.flush(t);
            }
            self.blocks += 1;
            // SAFETY: AVX2 is enabled here; `f` is 16 u8 = the 16 bytes `_mm_loadu_si128` reads and
            // `d` 16 u16 = the 32 bytes `_mm256_loadu_si256` reads (both without alignment).
            #[allow(unsafe_code)]
            let (f, mm) = unsafe {
                (
                    _mm256_cvtepu8_epi16(_mm_loadu_si128(f.as_ptr().cast())),
                    _mm256_loadu_si256(d.as_ptr().cast()),
                )
            };
            let zero = _mm256_setzero_si256();
            let ones = _mm256_set1_epi16(-1);
            let sat_bit = _mm256_set1_epi16(i16::from(FLAG_SATURATED));
            let sat = _mm256_cmpeq_epi16(_mm256_and_si256(f, sat_bit), sat_bit);
            let return_bits = _mm256_set1_epi16(i16::from(FLAG_LOW_AMPLITUDE | FLAG_IMPLAUSIBLE));
            let returned = _mm256_cmpeq_epi16(_mm256_and_si256(f, return_bits), zero);
            // Neither saturated nor without a "no return" flag: `!sat & (f & bits != 0)`.
            let no_return = _mm256_andnot_si256(_mm256_or_si256(sat, returned), ones);
            // `f == 0 && mm != 0`.
            let ok = _mm256_andnot_si256(_mm256_cmpeq_epi16(mm, zero), _mm256_cmpeq_epi16(f, zero));
            // Masks are −1 per true lane: subtracting counts them.
            self.saturated = _mm256_sub_epi16(self.saturated, sat);
            self.no_return = _mm256_sub_epi16(self.no_return, no_return);
            self.valid = _mm256_sub_epi16(self.valid, ok);
            // `key_of_mm`: flip the top bit.
            let key = _mm256_xor_si256(mm, _mm256_set1_epi16(i16::MIN));
            let stored = _mm256_blendv_epi8(_mm256_set1_epi16(INVALID_KEY), key, ok);
            // SAFETY: AVX2 is enabled here; `k` is 16 i16 = the 32 bytes `storeu` writes (unaligned).
            #[allow(unsafe_code)]
            unsafe {
                _mm256_storeu_si256(k.as_mut_ptr().cast(), stored)
            };
            self.min_key = _mm256_min_epi16(self.min_key, stored);
            let for_max = _mm256_blendv_epi8(_mm256_set1_epi16(i16::MIN), key, ok);
            self.max_key = _mm256_max_epi16(self.max_key, for_max);
        }

        /// Adds the lanes into `t` and clears the counts (the key range is kept: it only narrows).
        #[target_feature(enable = "avx2")]
        fn flush(&mut self, t: &mut Tally) {
            let lanes = |v: __m256i| -> [u16; LANES] {
                let mut a = [0u16; LANES];
                // SAFETY: AVX2 is enabled here; `a` is 16 u16 = the 32 bytes `storeu` writes
                // (unaligned).
                #[allow(unsafe_code)]
                unsafe {
                    _mm256_storeu_si256(a.as_mut_ptr().cast(), v)
                };
                a
            };
            let sum = |v: __m256i| lanes(v).iter().map(|&c| usize::from(c)).sum::<usize>();
            t.saturated += sum(self.saturated);
            t.no_return += sum(self.no_return);
            t.valid += sum(self.valid);
            t.min_key = lanes(self.min_key)
                .iter()
                .fold(t.min_key, |m, &k| m.min(k as i16));
            t.max_key = lanes(self.max_key)
                .iter()
                .fold(t.max_key, |m, &k| m.max(k as i16));
            self.saturated = _mm256_setzero_si256();
            self.no_return = _mm256_setzero_si256();
            self.valid = _mm256_setzero_si256();
            self.blocks = 0;
        }
    }

    /// The ROI pass of [`super::tally_rows`] with AVX2 intrinsics: each row in blocks of 16
    /// pixels, its last partial block padded with pixels that count as nothing (flags
    /// [`FLAG_INVALID`] only: not valid, not saturated, no "no return" flag; only the real keys
    /// are kept). Same keys and [`Tally`] as the portable pass (tested).
    #[target_feature(enable = "avx2")]
    pub(super) fn tally_rows(_proof: Avx2, rows: &RoiRows<'_>, keys: &mut [i16]) -> Tally {
        let roi = rows.roi;
        let mut t = Tally::default();
        let mut lanes = Counters::new();
        for (r, keys) in (roi.row0..).zip(keys.chunks_exact_mut(roi.cols.max(1))) {
            let row = |stride: usize| r * stride + roi.col0..r * stride + roi.col0 + roi.cols;
            // In range (the ROI is resolved within both arrays); `get` keeps a bad stride harmless.
            let f = rows.flags.get(row(rows.flags_stride)).unwrap_or_default();
            let d = rows.depth.get(row(rows.depth_stride)).unwrap_or_default();
            let n = f.len().min(d.len()).min(keys.len());
            let (f_blocks, f_rest) = f[..n].as_chunks::<LANES>();
            let (d_blocks, d_rest) = d[..n].as_chunks::<LANES>();
            let (k_blocks, k_rest) = keys[..n].as_chunks_mut::<LANES>();
            for ((f, d), k) in f_blocks.iter().zip(d_blocks).zip(k_blocks) {
                lanes.block(&mut t, f, d, k);
            }
            if !f_rest.is_empty() {
                let m = f_rest.len().min(d_rest.len()).min(k_rest.len());
                let mut f_pad = [FLAG_INVALID; LANES];
                let mut d_pad = [0u16; LANES];
                let mut k_pad = [INVALID_KEY; LANES];
                f_pad[..m].copy_from_slice(&f_rest[..m]);
                d_pad[..m].copy_from_slice(&d_rest[..m]);
                lanes.block(&mut t, &f_pad, &d_pad, &mut k_pad);
                k_rest[..m].copy_from_slice(&k_pad[..m]);
            }
        }
        lanes.flush(&mut t);
        t
    }

    #[target_feature(enable = "avx2")]
    pub(super) fn nearest_rank_mm(_proof: Avx2, keys: &[i16], rank: usize, t: &Tally) -> u16 {
        super::nearest_rank_mm(keys, rank, t)
    }
}

/// Number of keys greater than `v`: one signed 16-bit compare and one subtraction per vector
/// (`u16` reductions over pieces of at most `u16::MAX` keys).
#[inline(always)]
fn count_above(keys: &[i16], v: i16) -> usize {
    keys.chunks(usize::from(u16::MAX))
        .map(|b| usize::from(b.iter().fold(0u16, |a, &k| a + u16::from(k > v))))
        .sum()
}

/// The `rank`-th smallest (1-based, `1 ≤ rank ≤ t.valid`) valid depth (mm): a search on the
/// value over the valid keys' range `[t.min_key, t.max_key]`, each step one vectorised counting
/// pass over the keys (the keys stay in L1). No sort, no histogram (whose same-bin increments
/// serialise on a smooth depth image), no copy. Only values below `t.max_key` are compared, so
/// invalid keys (`INVALID_KEY`) are never counted as at or below one.
///
/// The probes are safeguarded interpolation (regula falsi on the counts, Perl, Itai & Avni 1978,
/// "Interpolation search — a log log N search", CACM 21(7)): a depth image's counts grow smoothly
/// with the value, so a linear estimate between the bracket's counts lands near the answer: 7
/// passes on the bench frame, where bisection needs ⌈log₂ of the ROI's depth span⌉ = 11. Every
/// probe lies inside the bracket, so the result is exactly bisection's; an interpolation probe
/// that does not halve the bracket is followed by a bisection probe, so the worst case is about
/// twice bisection's (≤ 2 × 16 passes).
#[inline(always)]
fn nearest_rank_mm(keys: &[i16], rank: usize, t: &Tally) -> u16 {
    let (mut lo, mut hi) = (i32::from(t.min_key), i32::from(t.max_key));
    // Counts of valid keys `< lo` and `≤ hi` (all valid keys are ≤ max_key).
    let (mut below_lo, mut at_or_below_hi) = (0usize, t.valid);
    let mut bisect = false;
    // Invariant: the answer is in lo..=hi, `below_lo < rank ≤ at_or_below_hi`.
    while lo < hi {
        let span = hi - lo;
        let mid = if bisect {
            lo + span / 2
        } else {
            // Where the linear estimate puts the `rank`-th key, rounded down; in lo..hi.
            let frac = (rank - below_lo) as f64 / (at_or_below_hi - below_lo).max(1) as f64;
            let est = lo + (frac * f64::from(span + 1)) as i32 - 1;
            est.clamp(lo, hi - 1)
        }; // < hi ≤ i16::MAX
        let at_or_below = keys.len() - count_above(keys, mid as i16);
        if at_or_below >= rank {
            hi = mid;
            at_or_below_hi = at_or_below;
        } else {
            lo = mid + 1;
            below_lo = at_or_below;
        }
        // Bisect next unless this probe at least halved the bracket.
        bisect = !bisect && 2 * (hi - lo) > span;
    }
    mm_of_key(lo as i16)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::FLAG_INVALID;

    /// A one-row ROI over all of `flags` and `depth` (the same length).
    fn one_row<'a>(flags: &'a [u8], depth: &'a [u16]) -> RoiRows<'a> {
        RoiRows {
            flags,
            flags_stride: flags.len(),
            depth,
            depth_stride: depth.len(),
            roi: Roi {
                row0: 0,
                col0: 0,
                rows: 1,
                cols: depth.len(),
            },
        }
    }

    #[test]
    fn roi_pass_and_nearest_rank_match_a_sort() {
        // Flags of every kind, valid depths 0 (not valid), 1 and 65535 (both ends of the range),
        // duplicates; lengths around the vector width and past a counter flush; every rank (a
        // sample of them for the longest).
        let mut state = 0x2545_f491_u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        for len in [1usize, 7, 16, 17, 300, 5000, 70_000] {
            let flags: Vec<u8> = (0..len)
                .map(|_| match next() % 9 {
                    0 => FLAG_SATURATED | FLAG_INVALID,
                    1 => FLAG_LOW_AMPLITUDE | FLAG_INVALID,
                    2 => FLAG_IMPLAUSIBLE | FLAG_INVALID,
                    3 => FLAG_SATURATED | FLAG_LOW_AMPLITUDE | FLAG_INVALID,
                    _ => 0,
                })
                .collect();
            let depth: Vec<u16> = (0..len)
                .map(|i| match next() % 11 {
                    0 => 0,
                    1 => u16::MAX,
                    2 => 1,
                    _ => (next() % 3000) as u16 + (i % 2) as u16 * 40_000,
                })
                .collect();
            let rows = one_row(&flags, &depth);
            let mut keys = vec![0i16; len];
            let t = KeyKernel::Portable.tally(&rows, &mut keys);
            let mut valid: Vec<u16> = flags
                .iter()
                .zip(&depth)
                .filter(|&(&f, &d)| f == 0 && d != 0)
                .map(|(_, &d)| d)
                .collect();
            valid.sort_unstable();
            let saturated = flags.iter().filter(|&&f| f & FLAG_SATURATED != 0).count();
            let no_return = flags
                .iter()
                .filter(|&&f| {
                    f & FLAG_SATURATED == 0 && f & (FLAG_LOW_AMPLITUDE | FLAG_IMPLAUSIBLE) != 0
                })
                .count();
            assert_eq!(
                (t.valid, t.saturated, t.no_return),
                (valid.len(), saturated, no_return),
                "len {len}"
            );
            let step = (valid.len() / 500).max(1);
            let last = (!valid.is_empty()).then_some(valid.len());
            for rank in (1..=valid.len()).step_by(step).chain(last) {
                assert_eq!(
                    KeyKernel::Portable.nearest_rank_mm(&keys, rank, &t),
                    valid[rank - 1],
                    "len {len} rank {rank}"
                );
            }
            // The detected kernel (AVX2 where the CPU has it) gives the same keys and ranks.
            let kernel = KeyKernel::detect();
            let mut keys_detected = vec![0i16; len];
            let td = kernel.tally(&rows, &mut keys_detected);
            assert_eq!(keys_detected, keys, "{kernel:?} len {len}");
            assert_eq!(
                (td.valid, td.saturated, td.no_return, td.min_key, td.max_key),
                (t.valid, t.saturated, t.no_return, t.min_key, t.max_key)
            );
            for rank in (1..=valid.len()).step_by(step).chain(last) {
                assert_eq!(
                    kernel.nearest_rank_mm(&keys, rank, &t),
                    valid[rank - 1],
                    "{kernel:?} len {len} rank {rank}"
                );
            }
        }
    }

    #[test]
    fn multi_row_roi_pass_with_tails_and_a_counter_flush() {
        // More than `u16::MAX` blocks of 16 (the AVX2 pass flushes its lane counts), rows with a
        // stride past the ROI, an offset column and a partial last block per row.
        let (frame_rows, stride) = (1100usize, 1003usize);
        let mut state = 0x9e37_79b9_u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        let flags: Vec<u8> = (0..frame_rows * stride)
            .map(|_| match next() % 7 {
                0 => FLAG_SATURATED | FLAG_INVALID,
                1 => FLAG_LOW_AMPLITUDE | FLAG_INVALID,
                2 => FLAG_IMPLAUSIBLE | FLAG_INVALID,
                _ => 0,
            })
            .collect();
        let depth: Vec<u16> = (0..frame_rows * stride)
            .map(|_| match next() % 13 {
                0 => 0,
                1 => u16::MAX,
                _ => (next() % 5000) as u16 + 1,
            })
            .collect();
        let roi = Roi {
            row0: 3,
            col0: 5,
            rows: 1090,
            cols: 997,
        };
        assert!(roi.rows * roi.cols > 16 * usize::from(u16::MAX));
        let rows = RoiRows {
            flags: &flags,
            flags_stride: stride,
            depth: &depth,
            depth_stride: stride,
            roi,
        };
        let mut keys = vec![0i16; roi.rows * roi.cols];
        let t = KeyKernel::Portable.tally(&rows, &mut keys);
        let (mut valid, mut saturated) = (0usize, 0usize);
        for r in roi.row0..roi.row0 + roi.rows {
            for c in roi.col0..roi.col0 + roi.cols {
                let (f, d) = (flags[r * stride + c], depth[r * stride + c]);
                valid += usize::from(f == 0 && d != 0);
                saturated += usize::from(f & FLAG_SATURATED != 0);
            }
        }
        assert_eq!((t.valid, t.saturated), (valid, saturated));
        let kernel = KeyKernel::detect();
        let mut keys_detected = vec![0i16; keys.len()];
        let td = kernel.tally(&rows, &mut keys_detected);
        assert!(keys_detected == keys, "{kernel:?} keys differ");
        assert_eq!(
            (td.valid, td.saturated, td.no_return, td.min_key, td.max_key),
            (t.valid, t.saturated, t.no_return, t.min_key, t.max_key),
            "{kernel:?}"
        );
    }

    #[test]
    fn nearest_rank_on_skewed_depths_matches_a_sort() {
        // Distributions where interpolation probes land far from the answer: one value, the two
        // ends of the range, powers of two, a ramp, a dense cluster with far outliers.
        let mut state = 0x1234_5678_u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        let len = 3000usize;
        let cases: Vec<Vec<u16>> = vec![
            vec![777; len],
            (0..len)
                .map(|i| if i % 5 == 0 { 1 } else { u16::MAX })
                .collect(),
            (0..len).map(|_| 1u16 << (next() % 16)).collect(),
            (0..len).map(|i| i as u16 + 1).collect(),
            (0..len)
                .map(|i| match i % 97 {
                    0 => 1,
                    1 => 65_000,
                    _ => 20_000 + (next() % 4) as u16,
                })
                .collect(),
        ];
        for depth in cases {
            let flags = vec![0u8; len];
            let rows = one_row(&flags, &depth);
            let mut sorted = depth.clone();
            sorted.sort_unstable();
            for kernel in [KeyKernel::Portable, KeyKernel::detect()] {
                let mut keys = vec![0i16; len];
                let t = kernel.tally(&rows, &mut keys);
                for rank in (1..=len).step_by(7).chain([len]) {
                    assert_eq!(
                        kernel.nearest_rank_mm(&keys, rank, &t),
                        sorted[rank - 1],
                        "{kernel:?} rank {rank} of {:?}",
                        &depth[..4]
                    );
                }
            }
        }
    }
}
