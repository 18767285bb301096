//! The pipeline's output and the regions of it that its readers look at: [`DepthFrame`] with its
//! per-pixel flags, and [`Roi`]. Its own module, below `pipeline`, `proximity`, `crosstalk` and
//! `radiometry`, which all read frames (it imports none of them, so none of them import each
//! other for it).

use std::ops::Range;

use ndarray::{Array2, ArrayView2, s};

/// Flag bit: at least one used raw image of the pixel is at a rail (0 or `2^bits − 1`).
pub const FLAG_SATURATED: u8 = 1 << 0;
/// Flag bit: amplitude below [`crate::pipeline::PipelineConfig::min_amplitude_lsb`].
pub const FLAG_LOW_AMPLITUDE: u8 = 1 << 1;
/// Flag bit: depth invalid (set whenever any other flag is set, or the depth is out of range).
pub const FLAG_INVALID: u8 = 1 << 2;
/// Flag bit: a used raw value is NaN or infinite.
pub const FLAG_NON_FINITE: u8 = 1 << 3;
/// Flag bit: a near depth whose amplitude no real target there could return (a wrapped phase or
/// stray light; set by [`crate::radiometry::flag_implausible_near`], never by the pipeline).
pub const FLAG_IMPLAUSIBLE: u8 = 1 << 4;

/// Output of one [`crate::pipeline::Pipeline::process`] call, all arrays `(rows, cols)`.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthFrame {
    /// **Radial** distance in metres (eq. 2.6: the length of the pixel's ray to the surface, not
    /// Z depth); 0 where invalid, never NaN.
    pub depth_m: Array2<f32>,
    /// Radial distance in millimetres ([`depth_m_to_mm`]); 0 = invalid.
    pub depth_mm: Array2<u16>,
    /// Amplitude in LSB (eq. 2.4 / `|z|`); 0 where the input was non-finite.
    pub amplitude_lsb: Array2<f32>,
    /// Corrected phase in `[0, 2π)`; 0 where the input was non-finite.
    pub phase_rad: Array2<f32>,
    /// Per-pixel flags: [`FLAG_SATURATED`], [`FLAG_LOW_AMPLITUDE`], [`FLAG_INVALID`], [`FLAG_NON_FINITE`], [`FLAG_IMPLAUSIBLE`].
    pub flags: Array2<u8>,
}

impl DepthFrame {
    /// A zeroed frame (every pixel `depth_mm = 0`, flags 0).
    pub fn zeros(rows: usize, cols: usize) -> Self {
        DepthFrame {
            depth_m: Array2::zeros((rows, cols)),
            depth_mm: Array2::zeros((rows, cols)),
            amplitude_lsb: Array2::zeros((rows, cols)),
            phase_rad: Array2::zeros((rows, cols)),
            flags: Array2::zeros((rows, cols)),
        }
    }

    /// `(rows, cols)`.
    pub fn dim(&self) -> (usize, usize) {
        self.depth_mm.dim()
    }

    /// Whether pixel `(row, col)` has a valid depth (`false` outside the frame).
    pub fn is_valid(&self, row: usize, col: usize) -> bool {
        self.flags
            .get((row, col))
            .is_some_and(|f| f & FLAG_INVALID == 0)
    }

    /// Fraction of pixels with valid depth (0 for an empty frame).
    pub fn valid_fraction(&self) -> f32 {
        let n = self.flags.len();
        if n == 0 {
            return 0.0;
        }
        self.flags
            .iter()
            .filter(|&&f| f & FLAG_INVALID == 0)
            .count() as f32
            / n as f32
    }

    /// Median of valid `depth_m` (metres, radial) over the whole frame, `None` if nothing is
    /// valid. Allocates (not for the hot path).
    pub fn median_valid_depth_m(&self) -> Option<f64> {
        median_valid_m(self.depth_m.view(), self.flags.view())
    }

    /// Saturated and low-amplitude fractions of `roi` (clipped to the frame; 0 for an empty
    /// region): what auto-exposure reads.
    pub fn roi_stats(&self, roi: Roi) -> RoiStats {
        let v = {
            let (r, c) = roi.ranges_in(self.dim());
            self.flags.slice(s![r, c])
        };
        let n = v.len().max(1) as f32;
        let sat = v.iter().filter(|&&x| x & FLAG_SATURATED != 0).count() as f32;
        let low = v
            .iter()
            .filter(|&&x| x & FLAG_LOW_AMPLITUDE != 0 && x & FLAG_SATURATED == 0)
            .count() as f32;
        RoiStats {
            saturated_fraction: sat / n,
            low_amplitude_fraction: low / n,
        }
    }

    /// Median of the non-zero `depth_mm` over `roi` (clipped to the frame; the upper median of
    /// an even count), `None` when none is valid. Allocates (not for the hot path).
    pub fn roi_median_mm(&self, roi: Roi) -> Option<f64> {
        let v = {
            let (r, c) = roi.ranges_in(self.dim());
            self.depth_mm.slice(s![r, c])
        };
        let mut vals: Vec<u16> = v.iter().copied().filter(|&d| d != 0).collect();
        if vals.is_empty() {
            return None;
        }
        let mid = vals.len() / 2;
        let (_, m, _) = vals.select_nth_unstable(mid);
        Some(f64::from(*m))
    }
}

/// Flag fractions over a region of a frame ([`DepthFrame::roi_stats`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoiStats {
    /// Pixels with [`FLAG_SATURATED`].
    pub saturated_fraction: f32,
    /// Pixels with [`FLAG_LOW_AMPLITUDE`] and not saturated.
    pub low_amplitude_fraction: f32,
}

/// Median of `depth_m` over the pixels whose `flags` have no [`FLAG_INVALID`] (any depth of a
/// frame: radial, or Z from [`crate::camera::RayGrid::radial_to_z`]), `None` if nothing is
/// valid or the shapes differ. Allocates (not for the hot path).
pub fn median_valid_m(depth_m: ArrayView2<f32>, flags: ArrayView2<u8>) -> Option<f64> {
    if depth_m.dim() != flags.dim() {
        return None;
    }
    let mut v: Vec<f32> = depth_m
        .iter()
        .zip(flags.iter())
        .filter(|(_, f)| **f & FLAG_INVALID == 0)
        .map(|(d, _)| *d)
        .collect();
    if v.is_empty() {
        return None;
    }
    v.sort_unstable_by(f32::total_cmp);
    let n = v.len();
    let m = if n % 2 == 1 {
        v[n / 2] as f64
    } else {
        0.5 * (v[n / 2 - 1] as f64 + v[n / 2] as f64)
    };
    Some(m)
}

/// A valid depth in metres as the frame's `u16` millimetres: `d · 1000` rounded (ties to even,
/// as the kernel), at least 1 mm;
/// 0 (invalid) for a depth that is not finite and positive or beyond 65 535 mm. The scalar form
/// of what the kernel stores (step 7 of the module docs), for depths derived from a frame (Z).
pub fn depth_m_to_mm(depth_m: f32) -> u16 {
    let mm = depth_m * 1000.0;
    if depth_m > 0.0 && mm < 65_535.5 {
        (mm.round_ties_even() as u16).max(1)
    } else {
        0
    }
}

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

    /// The ROI's rows and columns on a `(rows, cols)` array, clipped to it (empty when it lies
    /// outside; "auto" is not resolved: see [`Roi::resolve`]).
    pub fn ranges_in(&self, (rows, cols): (usize, usize)) -> (Range<usize>, Range<usize>) {
        let end = |o: usize, n: usize, full: usize| o.saturating_add(n).min(full);
        (
            self.row0.min(rows)..end(self.row0, self.rows, rows),
            self.col0.min(cols)..end(self.col0, self.cols, cols),
        )
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4×4 frame, flags and depths set pixel by pixel, read over its central 2×2 and over
    /// regions that leave it.
    #[test]
    fn roi_statistics_count_the_regions_pixels_only() {
        let mut f = DepthFrame::zeros(4, 4);
        f.flags[[1, 1]] = FLAG_SATURATED | FLAG_INVALID;
        f.flags[[1, 2]] = FLAG_SATURATED | FLAG_LOW_AMPLITUDE | FLAG_INVALID;
        f.flags[[2, 1]] = FLAG_LOW_AMPLITUDE | FLAG_INVALID;
        f.flags[[0, 0]] = FLAG_LOW_AMPLITUDE | FLAG_INVALID; // outside the region
        let centre = Roi {
            row0: 1,
            col0: 1,
            rows: 2,
            cols: 2,
        };
        let st = f.roi_stats(centre);
        assert_eq!(st.saturated_fraction, 0.5);
        assert_eq!(
            st.low_amplitude_fraction, 0.25,
            "a saturated pixel is not also weak"
        );
        f.depth_mm[[1, 1]] = 300;
        f.depth_mm[[2, 2]] = 500;
        f.depth_mm[[2, 1]] = 400;
        f.depth_mm[[3, 3]] = 10; // outside
        assert_eq!(f.roi_median_mm(centre), Some(400.0));
        let outside = Roi {
            row0: 9,
            col0: 0,
            rows: 2,
            cols: 2,
        };
        assert_eq!(f.roi_median_mm(outside), None);
        assert_eq!(f.roi_stats(outside).saturated_fraction, 0.0);
        let past_the_edge = Roi {
            row0: 3,
            col0: 3,
            rows: usize::MAX,
            cols: 5,
        };
        assert_eq!(f.roi_median_mm(past_the_edge), Some(10.0));
    }
}
