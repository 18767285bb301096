//! The cover window: an object pressed on it is near (`policy::window`, the pocket), else its
//! online estimate (the monitor) from the readings that see only the window; [`window_view`]
//! is what both read of the frame, taken by `measure`.

use std::time::Duration;

use tofprox_core::crosstalk::RoiPhasorSums;
use tofprox_core::phasor::distance_to_phase_rad;
use tofprox_core::pipeline::{Calibration, DepthFrame};
use tofprox_core::proximity::Roi;

use crate::config::Mode;
use crate::policy::WindowObservation;
use crate::policy::window::{GlassObservation, object_on_the_window};
use crate::source::{FrameSource, RawCycle};

use super::Controller;
use super::measure::Measurement;

/// How far from the cover window (m) the ROI's summed phasor may point for a far reading to
/// count as "only the window returns" for the smudge monitor (a few cm: the depth noise of a
/// weak residual; a real target this close to a multiple of the unambiguous range is the
/// documented limit of one frequency).
const WINDOW_TOLERANCE_M: f64 = 0.05;

/// What the monitor reads of a processed frame (`Default`: nothing read, the monitor learns
/// nothing from it).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct WindowView {
    /// The ROI's summed phasor points at the window (within [`WINDOW_TOLERANCE_M`]).
    points_at_window: bool,
    /// The compensated residual relative to the calibrated crosstalk (`None` without one).
    residual_ratio: Option<f32>,
}

/// The monitor's view of `frame` (processed from `cycle` in mode `captured` with the
/// calibration `used`) over `roi`.
pub(super) fn window_view(
    frame: &DepthFrame,
    used: &Calibration,
    captured: Mode,
    roi: Roi,
    cycle: &RawCycle,
) -> WindowView {
    let tolerance_rad = distance_to_phase_rad(WINDOW_TOLERANCE_M, cycle.geometry.modulation_hz);
    // one pass over the ROI's phasors for both
    let crosstalk = (used.crosstalk.as_ref()).map(|x| (x, captured, cycle.exposure_us));
    let sums = RoiPhasorSums::of(frame, roi, crosstalk);
    WindowView {
        points_at_window: sums.points_at_window(tolerance_rad),
        residual_ratio: sums.residual_ratio(),
    }
}

impl<S: FrameSource> Controller<S> {
    /// An object on the glass (`policy::window`, issue 34: the pocket): while armed — Near
    /// published, or a near candidate within `loop.near_hold_ms` — a reading that is not near
    /// but whose ROI light points at the window with a residual above the tracked estimate by
    /// more than `ON_THE_WINDOW_BOUND` is near (`DistanceMm` 0: on the glass), so the monitor
    /// does not learn from it.
    pub(super) fn judge_on_the_window(&mut self, m: &mut Measurement) {
        let hold = Duration::from_millis(self.cfg.loop_.near_hold_ms);
        let since_reading = self.since_valid.elapsed(self.source.now());
        let armed =
            self.near || (self.candidate_age).is_some_and(|age| age + since_reading <= hold);
        if m.valid {
            let far_mm = self.cfg.proximity.far_mm;
            let candidate = m.reading.near || m.reading.distance_mm.is_some_and(|d| d < far_mm);
            self.candidate_age = match candidate {
                true => Some(Duration::ZERO),
                false => self.candidate_age.map(|age| age + since_reading),
            };
        }
        if m.reading.near {
            return;
        }
        let on = object_on_the_window(GlassObservation {
            armed,
            points_at_window: m.window.points_at_window,
            aliased_far: m.aliased_far,
            residual_ratio: m.window.residual_ratio,
        });
        if on {
            m.reading.near = true;
            m.reading.no_target = false;
            m.reading.distance_mm = None;
            m.valid = true;
            m.on_the_window = true;
        }
    }

    /// Monitor: with nothing in range only the cover window returns light; what is left of it
    /// after the compensation says whether the window changed since the estimate (a smudge).
    /// The online estimate (`policy::window`) learns from those readings — valid, no near
    /// candidate, no far target found at the second frequency, and nothing in range or the
    /// ROI's light pointing at the window (a residual big enough to be a depth: ≈ 0 mm or
    /// wrapped just under the range) — never with a near candidate.
    pub(super) fn monitor_window(&mut self, m: &Measurement) {
        let far_mm = self.cfg.proximity.far_mm;
        let became = self.window.next(WindowObservation {
            valid: m.valid,
            near: m.reading.near,
            near_candidates: m.reading.distance_mm.is_some_and(|d| d < far_mm),
            aliased_far: m.aliased_far,
            points_at_window: m.window.points_at_window,
            no_target: m.reading.no_target,
            window_explained: m.window_explained,
            residual_ratio: m.window.residual_ratio,
        });
        if let Some(now) = became {
            tracing::warn!("{}", now.message());
        }
    }
}
