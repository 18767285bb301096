//! Partial read-out (thesis 3.1.2: fewer active ADCs and current sources, less data): read
//! only the rows of the ROI plus `readout.margin_rows` and, where the source's sequencer reads
//! a column window, only its columns plus `readout.margin_cols`, aligned to what the source
//! accepts; full frames when partial read-out is off, unsupported, or was refused once.

use tofprox_core::proximity::Roi;

use crate::config::ReadoutConfig;
use crate::source::RowWindow;

/// What the window is computed from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReadoutObservation {
    /// Rows of the full array.
    pub full_rows: usize,
    /// The ROI in full-frame coordinates.
    pub roi: Roi,
    /// The source reads row windows at all.
    pub source_supports: bool,
    /// Row alignment the source needs (row0 and rows multiples of it; 0 is taken as 1).
    pub align_rows: u16,
    /// Columns of the full array.
    pub full_cols: usize,
    /// Column alignment of the source's column window (`None`: whole rows only).
    pub align_cols: Option<u16>,
    /// Read every `row_step`-th row (0 or 1: every row; `ReadoutConfig::row_step_for`): the
    /// window then starts on a row the step reads, so its rows are rows of the stepped array.
    pub row_step: u16,
}

/// `first..first + len` widened by `margin`, aligned outwards to `align`, clipped to the last
/// aligned index of `full`: `(first, len)`.
fn span(first: usize, len: usize, margin: usize, align: usize, full: usize) -> (usize, usize) {
    let start = first.saturating_sub(margin) / align * align;
    let end = (first + len + margin).div_ceil(align) * align;
    let end = if end > full {
        full / align * align
    } else {
        end
    };
    (start, end.saturating_sub(start))
}

/// `roi` (in a window's coordinates) in the coordinates of the rows read when every
/// `step`-th row of the window is read (a reading of the stepped array, a probe): rows
/// `0, step, 2·step, …` become `0, 1, 2, …`.
pub fn stepped_roi(roi: Roi, step: usize) -> Roi {
    let step = step.max(1);
    let row0 = roi.row0.div_ceil(step);
    let end = (roi.row0 + roi.rows).div_ceil(step);
    Roi {
        row0,
        rows: end.saturating_sub(row0),
        ..roi
    }
}

/// The least common multiple of two alignments (both ≥ 1).
fn lcm(a: usize, b: usize) -> usize {
    let (mut x, mut y) = (a, b);
    while y != 0 {
        (x, y) = (y, x % y);
    }
    a / x.max(1) * b
}

/// The read-out window policy.
#[derive(Debug, Clone)]
pub struct ReadoutWindow {
    cfg: ReadoutConfig,
    refused: bool,
}

impl ReadoutWindow {
    /// New policy.
    pub fn new(cfg: ReadoutConfig) -> Self {
        Self {
            cfg,
            refused: false,
        }
    }

    /// The source refused a window: full frames from now on.
    pub fn refused_by_source(&mut self) {
        self.refused = true;
    }

    /// The rows to read next (`None`: the full frame).
    pub fn next(&mut self, obs: ReadoutObservation) -> Option<RowWindow> {
        if self.refused || !self.cfg.partial || !obs.source_supports || obs.full_rows == 0 {
            return None;
        }
        let roi = obs.roi;
        let step = obs.row_step.max(1);
        let align = lcm(usize::from(obs.align_rows.max(1)), usize::from(step));
        let m = usize::from(self.cfg.margin_rows);
        let (row0, rows) = span(roi.row0, roi.rows, m, align, obs.full_rows);
        let (col0, cols) = match obs.align_cols {
            Some(a) if obs.full_cols > 0 => {
                let mc = usize::from(self.cfg.margin_cols);
                let (c0, n) = span(roi.col0, roi.cols, mc, usize::from(a.max(1)), obs.full_cols);
                if n > 0 && n < obs.full_cols {
                    (c0, n)
                } else {
                    (0, 0)
                }
            }
            _ => (0, 0),
        };
        let fields = (
            u16::try_from(row0),
            u16::try_from(rows),
            u16::try_from(col0),
            u16::try_from(cols),
        );
        match fields {
            (Ok(row0), Ok(rows), Ok(col0), Ok(cols))
                if rows > 0 && (usize::from(rows) < obs.full_rows || cols > 0) =>
            {
                Some(RowWindow {
                    row0,
                    rows,
                    col0,
                    cols,
                    row_step: if step > 1 { step } else { 0 },
                })
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs(row0: usize, rows: usize, align_rows: u16) -> ReadoutObservation {
        ReadoutObservation {
            full_rows: 120,
            roi: Roi {
                row0,
                col0: 40,
                rows,
                cols: 80,
            },
            source_supports: true,
            align_rows,
            full_cols: 160,
            align_cols: None,
            row_step: 0,
        }
    }

    fn window(w: Option<RowWindow>) -> Option<(u16, u16)> {
        w.map(|w| (w.row0, w.rows))
    }

    #[test]
    fn roi_rows_plus_margin_aligned() {
        let mut r = ReadoutWindow::new(ReadoutConfig {
            partial: true,
            margin_rows: 2,
            margin_cols: 0,
            row_step: 1,
        });
        assert_eq!(window(r.next(obs(30, 60, 1))), Some((28, 64)));
        assert_eq!(
            window(r.next(obs(30, 60, 8))),
            Some((24, 72)),
            "28→24, 92→96"
        );
        assert_eq!(
            window(r.next(obs(0, 120, 1))),
            None,
            "the whole array: full frame"
        );
        assert_eq!(
            window(r.next(obs(100, 20, 16))),
            Some((96, 16)),
            "end clipped to the last aligned row"
        );
    }

    #[test]
    fn full_frames_when_off_unsupported_or_refused() {
        let mut off = ReadoutWindow::new(ReadoutConfig {
            partial: false,
            margin_rows: 2,
            margin_cols: 0,
            row_step: 1,
        });
        assert_eq!(off.next(obs(30, 60, 1)), None);
        let mut r = ReadoutWindow::new(ReadoutConfig {
            partial: true,
            margin_rows: 2,
            margin_cols: 0,
            row_step: 1,
        });
        let unsupported = ReadoutObservation {
            source_supports: false,
            ..obs(30, 60, 1)
        };
        assert_eq!(r.next(unsupported), None);
        assert!(r.next(obs(30, 60, 1)).is_some());
        r.refused_by_source();
        assert_eq!(
            r.next(obs(30, 60, 1)),
            None,
            "refused once: full frames for good"
        );
    }

    /// Where the sequencer reads a column window, the window is the ROI's columns too (with
    /// the margin, aligned outwards); whole rows where it cannot.
    #[test]
    fn columns_around_the_roi_where_the_source_reads_them() {
        let mut r = ReadoutWindow::new(ReadoutConfig {
            partial: true,
            margin_rows: 2,
            margin_cols: 3,
            row_step: 1,
        });
        let with_cols = ReadoutObservation {
            align_cols: Some(8),
            ..obs(30, 60, 1)
        };
        // ROI columns 40..120, ±3 → 37..123, aligned to 8 → 32..128
        let w = r.next(with_cols).expect("a window");
        assert_eq!((w.row0, w.rows, w.col0, w.cols), (28, 64, 32, 96));
        let full_width_roi = ReadoutObservation {
            roi: Roi {
                row0: 30,
                col0: 0,
                rows: 60,
                cols: 160,
            },
            ..with_cols
        };
        let w = r.next(full_width_roi).expect("rows only");
        assert_eq!((w.col0, w.cols), (0, 0), "every column: whole rows");
        let w = r.next(obs(30, 60, 1)).expect("rows only");
        assert_eq!(w.cols, 0, "no column window where the source has none");
    }

    /// A stepped read starts on a row the step reads: row0 aligned to lcm(align, step), the
    /// step carried in the window; step 1 (or 0) reads every row.
    #[test]
    fn a_stepped_window_starts_on_a_stepped_row() {
        let mut r = ReadoutWindow::new(ReadoutConfig::default());
        let stepped = |row0, align, row_step| ReadoutObservation {
            row_step,
            ..obs(row0, 60, align)
        };
        let w = r.next(stepped(31, 1, 2)).expect("a window");
        assert_eq!((w.row0, w.rows, w.row_step, w.rows_read()), (28, 66, 2, 33));
        let w = r.next(stepped(31, 4, 3)).expect("a window");
        assert_eq!((w.row0 % 12, w.row_step), (0, 3), "lcm(4, 3) = 12");
        let w = r.next(stepped(31, 1, 1)).expect("a window");
        assert_eq!((w.row0, w.row_step), (29, 0), "every row");
        assert_eq!((lcm(4, 6), lcm(1, 2), lcm(8, 2)), (12, 2, 8));
    }
}
