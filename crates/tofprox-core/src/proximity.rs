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
use crate::pipeline::{DepthFrame, FLAG_IMPLAUSIBLE, FLAG_LOW_AMPLITUDE, FLAG_SATURATED};
use ndarray::s;

/// Fraction of saturated ROI pixels that on its own means "near".
pub const SATURATED_NEAR_FRACTION: f32 = 0.25;

/// Default percentile (0..=1) of valid depth used as the ROI statistic.
pub const DEFAULT_PERCENTILE: f32 = 0.10;

/// Region of interest in frame pixel coordinates. `rows == 0 || cols == 0` means "auto": the
/// central half of the frame in each dimension (this is the [`Default`]). A ROI extending past the
/// frame is clipped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Roi {
    /// First row.
    pub row0: usize,
    /// First column.
    pub col0: usize,
    /// Number of rows (0 = auto).
    pub rows: usize,
    /// Number of columns (0 = auto).
    pub cols: usize,
}

impl Roi {
    /// The central part of a `frame_rows × frame_cols` frame covering `fraction` (0..=1) of each
    /// dimension (at least one pixel).
    pub fn centered(frame_rows: usize, frame_cols: usize, fraction: f64) -> Roi {
        let f = if fraction.is_finite() {
            fraction.clamp(0.0, 1.0)
        } else {
            0.5
        };
        let rows = ((frame_rows as f64 * f).round() as usize).clamp(1.min(frame_rows), frame_rows);
        let cols = ((frame_cols as f64 * f).round() as usize).clamp(1.min(frame_cols), frame_cols);
        Roi {
            row0: (frame_rows - rows) / 2,
            col0: (frame_cols - cols) / 2,
            rows,
            cols,
        }
    }

    /// The concrete ROI for a frame: "auto" resolved to the central half, then clipped to the frame.
    /// May be empty (0 rows or cols) if the ROI lies entirely outside.
    pub fn resolve(&self, frame_rows: usize, frame_cols: usize) -> Roi {
        if self.rows == 0 || self.cols == 0 {
            return Roi::centered(frame_rows, frame_cols, 0.5);
        }
        let row0 = self.row0.min(frame_rows);
        let col0 = self.col0.min(frame_cols);
        Roi {
            row0,
            col0,
            rows: self.rows.min(frame_rows - row0),
            cols: self.cols.min(frame_cols - col0),
        }
    }
}

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
    scratch: Vec<u16>,
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

    /// Feeds one frame. Allocation-free after the first frame of a given ROI size.
    pub fn update(&mut self, frame: &DepthFrame) -> ProximityReading {
        // Malformed frames (flags and depth of different shapes) are read on their common part.
        let (dr, dc) = frame.depth_mm.dim();
        let (fr, fc) = frame.flags.dim();
        let roi = self.cfg.roi.resolve(dr.min(fr), dc.min(fc));
        let total = roi.rows * roi.cols;
        // Per ROI pixel a key: its depth (mm) when valid, else 0 (reused buffer: allocates only
        // when the ROI grows). One vectorisable pass.
        self.scratch.clear();
        self.scratch.resize(total, 0);
        let mut saturated = 0usize;
        let mut no_return = 0usize;
        let rows = roi.row0..roi.row0 + roi.rows;
        let cols = roi.col0..roi.col0 + roi.cols;
        let flags = frame.flags.slice(s![rows.clone(), cols.clone()]);
        let depth = frame.depth_mm.slice(s![rows, cols]);
        let keys_rows = self.scratch.chunks_exact_mut(roi.cols.max(1));
        for ((frow, drow), keys) in flags.rows().into_iter().zip(depth.rows()).zip(keys_rows) {
            for ((k, &f), &mm) in keys.iter_mut().zip(frow.iter()).zip(drow.iter()) {
                saturated += usize::from(f & FLAG_SATURATED != 0);
                no_return += usize::from(
                    f & FLAG_SATURATED == 0 && f & (FLAG_LOW_AMPLITUDE | FLAG_IMPLAUSIBLE) != 0,
                );
                *k = if f == 0 { mm } else { 0 };
            }
        }
        let valid = count_in(&self.scratch, 1, u16::MAX);
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
            Some(u32::from(nearest_rank_mm(&self.scratch, rank)))
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

/// Number of keys in `lo..=hi` (`lo ≥ 1`). Counted in `u16` lanes per block of 4096 keys so the
/// loop vectorises (16 keys per AVX2 compare) instead of widening every comparison to `usize`.
fn count_in(keys: &[u16], lo: u16, hi: u16) -> usize {
    let width = hi.wrapping_sub(lo);
    let mut total = 0;
    for block in keys.chunks(4096) {
        let (vectors, rest) = block.as_chunks::<16>();
        let mut acc = [0u16; 16];
        for v in vectors {
            for (a, &k) in acc.iter_mut().zip(v) {
                // k in lo..=hi ⟺ k − lo (wrapping) ≤ hi − lo.
                *a += u16::from(k.wrapping_sub(lo) <= width);
            }
        }
        total += acc.iter().map(|&a| usize::from(a)).sum::<usize>();
        total += rest
            .iter()
            .filter(|&&k| k.wrapping_sub(lo) <= width)
            .count();
    }
    total
}

/// The `rank`-th smallest (1-based, `1 ≤ rank ≤` number of non-zero keys) of the non-zero keys:
/// a radix selection — a histogram of the high byte finds the bucket holding the rank, a
/// histogram of the low byte inside that bucket finds the value (two passes, no sort, no copy).
fn nearest_rank_mm(keys: &[u16], rank: usize) -> u16 {
    let mut hist = [0u32; 256];
    for &k in keys {
        hist[usize::from(k >> 8)] += 1;
    }
    hist[0] -= keys.iter().filter(|&&k| k == 0).count() as u32; // zeros are invalid pixels
    let (hi, before) = bucket_of(&hist, rank);
    let mut hist = [0u32; 256];
    for &k in keys {
        if usize::from(k >> 8) == hi && k != 0 {
            hist[usize::from(k & 0xFF)] += 1;
        }
    }
    let (lo, _) = bucket_of(&hist, rank - before);
    ((hi << 8) | lo) as u16
}

/// The bucket where the running count reaches `rank` (1-based), and the count before it.
fn bucket_of(hist: &[u32; 256], rank: usize) -> (usize, usize) {
    let mut seen = 0usize;
    for (b, &c) in hist.iter().enumerate() {
        if seen + c as usize >= rank {
            return (b, seen);
        }
        seen += c as usize;
    }
    (255, seen)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_matches_a_sort() {
        // Keys with zeros (invalid), duplicates, both ends of the u16 range; every rank.
        let mut state = 0x2545_f491_u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        for len in [1usize, 7, 16, 17, 300, 5000] {
            let keys: Vec<u16> = (0..len)
                .map(|i| match next() % 7 {
                    0 => 0,
                    1 => u16::MAX,
                    2 => 1,
                    _ => (next() % 3000) as u16 + (i % 2) as u16 * 40_000,
                })
                .collect();
            let mut valid: Vec<u16> = keys.iter().copied().filter(|&k| k != 0).collect();
            valid.sort_unstable();
            assert_eq!(count_in(&keys, 1, u16::MAX), valid.len());
            for rank in 1..=valid.len() {
                assert_eq!(
                    nearest_rank_mm(&keys, rank),
                    valid[rank - 1],
                    "len {len} rank {rank}"
                );
            }
        }
    }
}
