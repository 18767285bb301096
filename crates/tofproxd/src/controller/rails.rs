//! Saturation is evidence ([`SaturationCheck`](crate::policy::SaturationCheck)): a frame with
//! every code on a rail is the sensor's own near return, to be confirmed, or no data.

use crate::config::Mode;
use crate::hub::{Reason, StatusUpdate};
use crate::policy::{
    ExposureObservation, RailsDecision, RailsObservation, rails_point_at_zero_distance,
};
use crate::source::{FrameSource, RawCycle, RawImages};

use super::{Controller, StepOutcome};

impl<S: FrameSource> Controller<S> {
    /// Saturation is evidence ([`SaturationCheck`]): whether an all-rails frame is the sensor's
    /// own return from something too close to measure (near), to be confirmed first, or no data.
    pub(super) fn rails_decision(&mut self, cycle: &RawCycle, captured: Mode) -> RailsDecision {
        let g = cycle.geometry;
        let roi = self.roi_of(g);
        let lut = self.calib.full.for_mode(captured).wiggling.as_ref();
        let max = g.max_code() as f32;
        let ph = &cycle.phases_deg;
        let return_pattern = match &cycle.frames {
            RawImages::U16(a) => rails_point_at_zero_distance(a.view(), ph, roi, max, lut),
            RawImages::F32(a) => rails_point_at_zero_distance(a.view(), ph, roi, max, lut),
        };
        let decision = self.saturation.next(RailsObservation {
            captured,
            return_pattern,
            source_can_confirm: self.source.supports_mode_switch(),
            bright_background: self
                .ambient_lsb
                .is_some_and(|a| a > self.cfg.ambient.high_lsb),
        });
        tracing::debug!("every code on a rail: {decision:?}");
        decision
    }

    /// Every code of every raw image on a rail and not a near return: a dead/garbage frame,
    /// light without modulation, or a saturated 2-phase frame awaiting its confirmation.
    /// Such a frame carries no data: it never reaches the detector (it would read as saturated
    /// = near), Near is only held (bounded by `loop.near_hold_ms`), and the exposure is
    /// shortened so a real target becomes measurable in the next cycle.
    pub(super) fn rails_cycle(&mut self, cycle: &RawCycle) -> StepOutcome {
        self.exposure.next(ExposureObservation::Rails);
        let energy = self.energy.next(
            self.observe(cycle, self.rate.rate_hz())
                .with_cpu(self.reading_cpu()),
        );
        let sleep = energy.sleep;
        let near_update = self.no_reading(sleep);
        self.last_sleep = sleep;
        tracing::debug!("frame without usable codes (all on the rails): no reading");
        StepOutcome {
            update: StatusUpdate {
                near: near_update,
                exposure_us: Some(self.exposure.exposure_us()),
                power_mw: Some(energy.average_mw),
                reason: near_update.map(|_| Reason::HoldExpired),
                cycle: true,
                ..StatusUpdate::default()
            },
            sleep,
            near: self.near,
            ..StepOutcome::default()
        }
    }
}
