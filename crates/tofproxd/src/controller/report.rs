//! Report: a reading as the published status (the [`crate::hub`] vocabulary).

use tofprox_core::crosstalk::CrosstalkStatus;
use tofprox_core::pipeline::DepthFrame;
use tofprox_core::proximity::ProximityReading;

use crate::config::Mode;
use crate::hub::{DepthMessage, Reason, State, StatusUpdate};
use crate::policy::EnergyDecision;
use crate::source::FrameSource;

use super::measure::Measurement;
use super::{Controller, DISTANCE_BEYOND_RANGE_MM, StepOutcome};

impl<S: FrameSource> Controller<S> {
    /// Report: a valid reading becomes the published Near and state, the failure count and
    /// the time since the last valid reading restart, `LastError` clears — or names the
    /// changed cover window while it lasts.
    pub(super) fn report(
        &mut self,
        m: Measurement,
        energy: EnergyDecision,
        captured: Mode,
    ) -> StepOutcome {
        self.consecutive_failures = 0;
        self.last_sleep = energy.sleep;
        if m.valid {
            self.since_valid.reading(self.source.now());
            self.near = m.reading.near;
            self.state = State::Running;
        }
        let note = match self.window.status() {
            s @ CrosstalkStatus::Changed { .. } => s.message(),
            _ => String::new(),
        };
        let last_error_changed = self.last_error != note;
        self.last_error = note;
        StepOutcome {
            update: StatusUpdate {
                state: Some(self.state),
                near: m.valid.then_some(self.near),
                // the capture's time, set by `step` (the frames were in)
                timestamp_ns: None,
                distance_mm: Some(shown_distance_mm(&m.reading, self.cfg.proximity.far_mm)),
                mode: Some(self.ambient.mode()),
                rate_hz: Some(self.rate.rate_hz()),
                power_mw: Some(energy.average_mw),
                last_error: last_error_changed.then(|| self.last_error.clone()),
                exposure_us: Some(self.exposure.exposure_us()),
                has_sensor: Some(true),
                amplitude_check: Some(if self.calib.full.amplitude.is_some() {
                    "calibrated"
                } else {
                    "nominal"
                }),
                reason: m.valid.then(|| reading_reason(&m)),
                valid_reading: m.valid,
                cycle: true,
                error: false,
            },
            depth: m.depth,
            sleep: energy.sleep,
            error: None,
            near: self.near,
            distance_mm: m.reading.distance_mm,
            valid: m.valid,
            end_of_data: false,
            captured_mode: Some(captured),
        }
    }
}

/// The rule that decided a valid reading.
fn reading_reason(m: &Measurement) -> Reason {
    if m.on_the_window {
        Reason::OnTheWindow
    } else if m.reading.near && m.stats.saturated_fraction >= 0.5 {
        Reason::Saturated
    } else if m.reading.no_target {
        Reason::NothingInRange
    } else if m.aliased_far && !m.reading.near {
        Reason::SecondFrequency
    } else {
        Reason::Distance
    }
}

/// The published `DistanceMm` of a reading: near from saturation (target too close/bright to
/// measure) publishes "unknown" (0) — the statistic of the remaining valid pixels is the
/// background, not the target —; nothing in range [`DISTANCE_BEYOND_RANGE_MM`].
pub(super) fn shown_distance_mm(reading: &ProximityReading, far_mm: u32) -> u32 {
    match reading.distance_mm {
        Some(d) if reading.near && d >= far_mm => 0,
        Some(d) => d,
        None if reading.no_target && !reading.near => DISTANCE_BEYOND_RANGE_MM,
        None => 0,
    }
}

pub(super) fn depth_message(f: &DepthFrame, timestamp_ns: u64) -> DepthMessage {
    let (rows, cols) = f.dim();
    let mut depth_le = Vec::with_capacity(rows * cols * 2);
    for &d in f.depth_mm.iter() {
        depth_le.extend_from_slice(&d.to_le_bytes());
    }
    let mut amplitude_le = Vec::with_capacity(rows * cols * 2);
    for &a in f.amplitude_lsb.iter() {
        let a = if a.is_finite() {
            a.round().clamp(0.0, 65535.0) as u16
        } else {
            0
        };
        amplitude_le.extend_from_slice(&a.to_le_bytes());
    }
    DepthMessage {
        timestamp_ns,
        width: u16::try_from(cols).unwrap_or(u16::MAX),
        height: u16::try_from(rows).unwrap_or(u16::MAX),
        depth_le,
        amplitude_le,
    }
}
