//! Policies: the decisions for the next cycle, each by its own unit of [`crate::policy`].

use crate::policy::{EnergyDecision, ExposureObservation, RateObservation};
use crate::source::{FrameSource, RawCycle};

use super::Controller;
use super::measure::Measurement;

impl<S: FrameSource> Controller<S> {
    /// Policies: the decisions for the next cycle in their fixed order — ambient switch
    /// (4-phase frames), exposure, rate, energy account (whose sleep follows the new rate; a
    /// second-frequency capture is counted with its cycle).
    pub(super) fn decide_next(&mut self, cycle: &RawCycle, m: &Measurement) -> EnergyDecision {
        if let Some(obs) = m.ambient {
            self.ambient.next(obs);
        }
        // the window's return is no target: its pixels count as pixels without a return
        let roi_px = (m.roi.rows * m.roi.cols).max(1) as f32;
        self.exposure.next(ExposureObservation::Roi {
            saturated_fraction: m.stats.saturated_fraction.max(m.saturated_f2),
            low_amplitude_fraction: m.stats.low_amplitude_fraction
                + m.window_explained as f32 / roi_px,
            saturated_when_longer: m.saturated_when_longer,
        });
        self.rate.next(RateObservation {
            near: m.reading.near,
            distance_mm: m.reading.distance_mm,
            no_target: m.valid && m.reading.no_target,
        });
        let rate_hz = self.rate.rate_hz();
        self.energy.next_with(
            self.observe(cycle, rate_hz).with_cpu(self.reading_cpu()),
            m.second.as_ref().map(|c2| self.observe(c2, rate_hz)),
        )
    }
}
