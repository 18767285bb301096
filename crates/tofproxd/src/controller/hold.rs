//! Near held over cycles without a reading (a failure, a frame without data), bounded by the
//! time since the last valid reading (`loop.near_hold_ms`) on the source's clock; and the
//! failure path of a cycle.

use std::time::Duration;

use crate::boottime::boottime_ns;
use crate::hub::{Reason, State, StatusUpdate};
use crate::source::{FrameSource, SourceError, SourceErrorKind};

use super::{Controller, StepOutcome};

/// The time since the last valid reading (the bound on holding Near, `loop.near_hold_ms`): on
/// the source's clock when it has one, so every cycle counts with its whole duration — a
/// failing one too (a transfer timeout, a reset that hangs) —, else the sleeps plus the
/// cycles' measured state durations since that reading.
#[derive(Debug, Default)]
pub(super) struct SinceValid {
    /// The source's clock at the last valid reading.
    reading_at: Option<Duration>,
    /// Sleeps and cycle durations counted since (sources without a clock).
    counted: Duration,
}

impl SinceValid {
    /// A valid reading now.
    pub(super) fn reading(&mut self, now: Option<Duration>) {
        self.reading_at = now;
        self.counted = Duration::ZERO;
    }
    /// Time passed (a sleep, a cycle's state durations), for sources without a clock.
    pub(super) fn count(&mut self, d: Duration) {
        self.counted += d;
    }
    /// Time since the last valid reading.
    pub(super) fn elapsed(&self, now: Option<Duration>) -> Duration {
        match (now, self.reading_at) {
            (Some(now), Some(at)) => now.saturating_sub(at),
            _ => self.counted,
        }
    }
}

/// The longest of the last few cycles (each from its start to its end, failing ones too): what
/// the next attempt may take before it can release a held Near, so the release never comes
/// after `loop.near_hold_ms` (issue 34: 1,018 ms were seen on the daemon's own clock).
#[derive(Debug, Default)]
pub(super) struct RecentCycles {
    took: [Duration; 8],
    next: usize,
}

impl RecentCycles {
    pub(super) fn note(&mut self, d: Duration) {
        self.took[self.next] = d;
        self.next = (self.next + 1) % self.took.len();
    }
    pub(super) fn longest(&self) -> Duration {
        self.took.iter().copied().max().unwrap_or_default()
    }
}

/// Time from the hold decision to the release being published (the status event, the
/// publisher, the bus): our margin, so the release is on the bus within `loop.near_hold_ms`.
const HOLD_PUBLISH_MARGIN: Duration = Duration::from_millis(20);

impl<S: FrameSource> Controller<S> {
    fn state_before_fail(&self) -> State {
        self.prev_state
    }

    pub(super) fn fail(&mut self, err: SourceError) -> StepOutcome {
        self.consecutive_failures += 1;
        let state = if err.kind() == SourceErrorKind::Disconnected
            || self.consecutive_failures >= self.cfg.loop_.unavailable_after
        {
            State::Unavailable
        } else {
            State::Error
        };
        self.prev_state = self.state;
        self.state = state;
        self.last_error = err.to_string();
        if state == State::Unavailable && self.state_before_fail() != State::Unavailable {
            tracing::warn!(
                "sensor unavailable ({} failed cycles in a row): {err}",
                self.consecutive_failures
            );
        } else {
            tracing::info!(
                "cycle failed ({} in a row): {err}",
                self.consecutive_failures
            );
        }
        let sleep = Duration::from_millis(self.cfg.loop_.retry_ms);
        let near_update = self.no_reading(sleep);
        self.last_sleep = sleep;
        StepOutcome {
            update: StatusUpdate {
                state: Some(state),
                near: near_update,
                timestamp_ns: Some(boottime_ns()),
                last_error: Some(self.last_error.clone()),
                has_sensor: Some(err.kind() != SourceErrorKind::Disconnected),
                reason: near_update.map(|_| Reason::HoldExpired),
                cycle: true,
                error: true,
                ..StatusUpdate::default()
            },
            sleep,
            end_of_data: err.kind() == SourceErrorKind::EndOfData,
            near: self.near,
            error: Some(err),
            ..StepOutcome::default()
        }
    }

    /// A cycle without a reading (failed, or no data in it) carries no information: Near is
    /// held, but only while the whole time since the last valid reading — failing cycles,
    /// their retries and the sleep before the next attempt included — stays below
    /// `loop.near_hold_ms`; a Near the next reading could only confirm after that bound is
    /// released now (never held for ever). Returns the new Near when it changed.
    pub(super) fn no_reading(&mut self, next_sleep: Duration) -> Option<bool> {
        let since = self.since_valid.elapsed(self.source.now());
        let bound = Duration::from_millis(self.cfg.loop_.near_hold_ms);
        // the next attempt ends after the sleep and a cycle as long as the recent ones
        let next_attempt = next_sleep + self.recent.longest() + HOLD_PUBLISH_MARGIN;
        if self.near && since + next_attempt >= bound {
            tracing::info!(
                "no valid reading for {} ms (next attempt after {} ms more): Near released",
                since.as_millis(),
                next_sleep.as_millis()
            );
            self.near = false;
            if let Some((_, d)) = &mut self.detector {
                d.reset();
            }
            return Some(false);
        }
        None
    }
}
