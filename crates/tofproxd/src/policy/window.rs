//! A cover window that changes (issue 21 item 3): the window's crosstalk is estimated online,
//! compensated at its current estimate, and a near reading needs light the window cannot give.
//!
//! The window reflects part of the illumination back from millimetres away: per pixel a phasor
//! `s·X·t` (the calibrated crosstalk `X` per µs, thesis 3.1 stray-light step; eq. 2.2/2.3 add it
//! to every raw image). A smudge changes `s` (1 at calibration). The pipeline subtracts
//! `ŝ·X·t` with the current estimate `ŝ` ([`WindowTracker::scale`]), so the window leaves
//! `(s − ŝ)·X·t` in each pixel, at zero distance.
//!
//! **Learning.** A reading that sees only the window — valid, far, no near candidate (the
//! detector's statistic counting every valid pixel lies at or beyond `far_mm`), no aliased far
//! target found by the second frequency, and nothing in range or an ROI phasor that points at
//! the window — measures `r = (s − ŝ)` as the residual ratio
//! ([`tofprox_core::crosstalk::residual_ratio`]); the monitor averages `ŝ − 1 + r`, the change
//! since calibration (exponential average over 8 such readings), and `ŝ = 1 + average`,
//! bounded to `0..=`[`MAX_WINDOW_SCALE`]. Nothing is learned while a near candidate is present,
//! so a target is never taken for the window.
//!
//! **The rule (near never sticks).** A pixel near enough to make or hold Near counts only when
//! its amplitude exceeds [`WINDOW_CHANGE_BOUND`]` · |X|·t`
//! ([`tofprox_core::crosstalk::flag_window_explained`]). When the target has left, every pixel
//! holds the window's residual plus the return of what lies beyond `far_mm`; while the window
//! changed by less than the bound since the estimate (`|s − ŝ|·|X| + A_far < bound·|X|`),
//! no pixel counts as near, the readings are far, Near is released after `far_debounce`
//! readings, and the estimate learns the change from the next reading. A real target counts
//! when its own return exceeds the bound's light plus the residual: at the bound of 1.5, dark
//! hair (6 %) behind the 13× window of the scene bench from ≈ 8 cm, behind the typical window
//! at every distance below `far_mm`. Window-explained pixels count as pixels without a return
//! for auto-exposure, which lengthens the exposure instead of keeping it short for the window.

use tofprox_core::crosstalk::{CrosstalkMonitor, CrosstalkStatus};

/// The largest change of the window's return, in units of its calibrated crosstalk, between
/// two readings that see only the window, for which near is guaranteed never to stick: a
/// window doubling (+1, the smudge ×2) while a target stays, with half the calibrated
/// crosstalk left for the far scene's return and noise.
pub const WINDOW_CHANGE_BOUND: f32 = 1.5;

/// The largest crosstalk estimate, relative to the calibrated one (a window 4× as strong as
/// calibrated; beyond it the monitor reports the change and the compensation stays here).
pub const MAX_WINDOW_SCALE: f32 = 4.0;

/// One reading as the tracker sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowObservation {
    /// The reading is valid.
    pub valid: bool,
    /// The detector says near.
    pub near: bool,
    /// Pixels near enough to make or hold Near are present (the statistic lies below `far_mm`).
    pub near_candidates: bool,
    /// The second frequency found an aliased far target in this cycle.
    pub aliased_far: bool,
    /// Only the window returns light: nothing in range, or the ROI phasor points at the window.
    pub window_only: bool,
    /// The compensated residual relative to the calibrated crosstalk
    /// ([`tofprox_core::crosstalk::residual_ratio`]); `None` without a crosstalk calibration.
    pub residual_ratio: Option<f32>,
}

/// The online estimate of the window's crosstalk and the verdict on it.
#[derive(Debug, Clone, Default)]
pub struct WindowTracker {
    monitor: CrosstalkMonitor,
}

impl WindowTracker {
    /// The factor the pipeline compensates the calibrated crosstalk with (`ŝ`, 1 before any
    /// reading that saw only the window).
    pub fn scale(&self) -> f32 {
        self.monitor.suggested_scale().clamp(0.0, MAX_WINDOW_SCALE)
    }

    /// The verdict since calibration (the monitor's, over the total change `ŝ − 1 + r`).
    pub fn status(&self) -> CrosstalkStatus {
        self.monitor.status()
    }

    /// Learns from a reading that saw only the window (see the module docs); returns the new
    /// status when this reading changed the verdict to `Changed`.
    pub fn next(&mut self, obs: WindowObservation) -> Option<CrosstalkStatus> {
        let learnable = obs.valid
            && !obs.near
            && !obs.near_candidates
            && !obs.aliased_far
            && obs.window_only;
        let r = obs.residual_ratio.filter(|_| learnable)?;
        let was = self.monitor.status();
        // the change since calibration, within the estimate's bounds
        let change = (self.scale() - 1.0 + r).clamp(-1.0, MAX_WINDOW_SCALE - 1.0);
        let now = self.monitor.update(change);
        let became = matches!(now, CrosstalkStatus::Changed { .. })
            && !matches!(was, CrosstalkStatus::Changed { .. });
        became.then_some(now)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn only_window(residual_ratio: f32) -> WindowObservation {
        WindowObservation {
            valid: true,
            near: false,
            near_candidates: false,
            aliased_far: false,
            window_only: true,
            residual_ratio: Some(residual_ratio),
        }
    }

    /// A window whose true return is `s` × calibrated: each reading measures `s − ŝ` at the
    /// estimate in use (what the compensation leaves), and the estimate converges to `s`.
    #[test]
    fn the_estimate_follows_a_smudged_window_and_reports_it() {
        let mut w = WindowTracker::default();
        assert_eq!(w.scale(), 1.0);
        let s_true = 2.0f32;
        let mut became = 0;
        for _ in 0..40 {
            if w.next(only_window(s_true - w.scale())).is_some() {
                became += 1;
            }
        }
        assert!((w.scale() - s_true).abs() < 1e-3, "{}", w.scale());
        assert_eq!(became, 1, "reported once");
        match w.status() {
            CrosstalkStatus::Changed { residual_ratio } => {
                assert!((residual_ratio - 1.0).abs() < 1e-3, "{residual_ratio}")
            }
            s => panic!("{s:?}"),
        }
        // cleaned again: back to the calibrated crosstalk, as calibrated
        for _ in 0..80 {
            w.next(only_window(1.0 - w.scale()));
        }
        assert!((w.scale() - 1.0).abs() < 1e-3, "{}", w.scale());
        assert!(matches!(w.status(), CrosstalkStatus::AsCalibrated { .. }));
    }

    /// Nothing is learned while a target may be in front: near, near candidates, an aliased
    /// far target, light that does not point at the window, an invalid reading.
    #[test]
    fn nothing_is_learned_with_a_near_candidate_or_a_target() {
        let mut w = WindowTracker::default();
        let blocked = [
            WindowObservation {
                near: true,
                ..only_window(3.0)
            },
            WindowObservation {
                near_candidates: true,
                ..only_window(3.0)
            },
            WindowObservation {
                aliased_far: true,
                ..only_window(3.0)
            },
            WindowObservation {
                window_only: false,
                ..only_window(3.0)
            },
            WindowObservation {
                valid: false,
                ..only_window(3.0)
            },
            WindowObservation {
                residual_ratio: None,
                ..only_window(3.0)
            },
        ];
        for o in blocked {
            for _ in 0..20 {
                assert_eq!(w.next(o), None);
            }
            assert_eq!(w.scale(), 1.0, "{o:?}");
            assert_eq!(w.status(), CrosstalkStatus::Unknown);
        }
    }

    /// The estimate is bounded: a residual no window can leave is not followed past
    /// `MAX_WINDOW_SCALE`, nor below no crosstalk at all.
    #[test]
    fn the_estimate_is_bounded() {
        let mut w = WindowTracker::default();
        for _ in 0..50 {
            w.next(only_window(100.0));
        }
        assert_eq!(w.scale(), MAX_WINDOW_SCALE);
        let mut w = WindowTracker::default();
        for _ in 0..50 {
            w.next(only_window(-100.0));
        }
        assert_eq!(w.scale(), 0.0);
    }
}
