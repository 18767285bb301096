//! Partial read-out (thesis 3.1.2: the read-out energy is proportional to the rows read):
//! read only the rows of the ROI plus `readout.margin_rows`, aligned to what the source
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
        let m = usize::from(self.cfg.margin_rows);
        let align = usize::from(obs.align_rows.max(1));
        let row0 = roi.row0.saturating_sub(m) / align * align;
        let end = (roi.row0 + roi.rows + m).div_ceil(align) * align;
        let end = if end > obs.full_rows {
            obs.full_rows / align * align
        } else {
            end
        };
        match (u16::try_from(row0), u16::try_from(end.saturating_sub(row0))) {
            (Ok(row0), Ok(rows)) if rows > 0 && usize::from(rows) < obs.full_rows => {
                Some(RowWindow { row0, rows })
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
        });
        assert_eq!(off.next(obs(30, 60, 1)), None);
        let mut r = ReadoutWindow::new(ReadoutConfig {
            partial: true,
            margin_rows: 2,
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
}
