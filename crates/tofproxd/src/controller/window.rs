//! Monitor: the cover window's online estimate (`policy::window`) from the readings that see
//! only the window; [`window_view`] is what it reads of the frame, taken by `measure`.

use tofprox_core::crosstalk::{phasor_points_at_window, residual_ratio};
use tofprox_core::phasor::distance_to_phase_rad;
use tofprox_core::pipeline::{Calibration, DepthFrame};
use tofprox_core::proximity::Roi;

use crate::config::Mode;
use crate::policy::WindowObservation;
use crate::source::{FrameSource, RawCycle};

use super::Controller;
use super::measure::Measurement;

/// How far from the cover window (m) the ROI's summed phasor may point for a far reading to
/// count as "only the window returns" for the smudge monitor (a few cm: the depth noise of a
/// weak residual; a real target this close to a multiple of the unambiguous range is the
/// documented limit of one frequency).
const WINDOW_TOLERANCE_M: f64 = 0.05;

/// What the monitor reads of a processed frame.
#[derive(Debug, Clone, Copy)]
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
    WindowView {
        points_at_window: phasor_points_at_window(frame, roi, tolerance_rad),
        residual_ratio: (used.crosstalk.as_ref())
            .and_then(|x| residual_ratio(frame, x, captured, roi, cycle.exposure_us)),
    }
}

impl<S: FrameSource> Controller<S> {
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
