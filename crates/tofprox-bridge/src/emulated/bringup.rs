//! The emulated sensor's view of its bring-up: what reached its pins and registers when (the
//! [`BusTrace`] of the current cycle), and whether the bring-up of the register map's
//! `[bring_up]` was followed — the public record's order and waits (`docs/bridge.md`, "Public
//! facts"): reset low long enough, the PLL registers, the PLL settled before `CTRL`, `CTRL`
//! before `EN`, the imager settled before the measurement starts. A violation is recorded and
//! the sensor refuses to measure, so the driver's cycle fails and a test sees why.

use std::time::Duration;

use serde::Serialize;

use crate::regmap::{BringUp, RegWrite};

/// Most events one cycle's trace keeps (writing the flash adds ~140 register writes per 256-byte
/// page: the SPI TX window, its length and trigger).
pub const TRACE_CAP: usize = 8192;

/// What reached the sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum BusEvent {
    /// The reset pin commanded low (the pin is open-drain: low is driven).
    ResetLow,
    /// The reset pin released (pulled high).
    ResetReleased,
    /// One register write (a burst is one event per register).
    Write {
        /// Register address.
        reg: u16,
        /// Value written.
        value: u16,
    },
}

/// One event and the clock time it reached the sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct TraceEvent {
    /// Clock time.
    pub at: Duration,
    /// The event.
    pub event: BusEvent,
}

/// The events of the current cycle: from the last reset-low command before the release to
/// now, at most [`TRACE_CAP`].
pub type BusTrace = Vec<TraceEvent>;

/// Bring-up state of the emulated imager, reset by every reset release.
#[derive(Debug, Default)]
pub(crate) struct BringUpMonitor {
    spec: Option<BringUp>,
    pll_registers: Vec<u16>,
    /// Reset physically low since (None: since power-on).
    low_since: Option<Duration>,
    pll_at: Option<Duration>,
    ctrl_at: Option<Duration>,
    en_at: Option<Duration>,
    violations: Vec<String>,
    trace: BusTrace,
}

fn us(d: Duration) -> u128 {
    d.as_micros()
}

impl BringUpMonitor {
    /// A monitor of `spec` (None: nothing is checked, the trace is still kept) after the PLL
    /// registers `minimum`.
    pub(crate) fn new(spec: Option<BringUp>, minimum: &[RegWrite]) -> Self {
        BringUpMonitor {
            spec,
            pll_registers: minimum.iter().map(|[r, _]| *r).collect(),
            ..Self::default()
        }
    }

    fn record(&mut self, at: Duration, event: BusEvent) {
        if self.trace.len() < TRACE_CAP {
            self.trace.push(TraceEvent { at, event });
        }
    }

    fn violation(&mut self, why: String) {
        tracing::warn!("emulated sensor: bring-up out of order: {why}");
        self.violations.push(why);
    }

    /// The reset pin commanded low (also when it already is).
    pub(crate) fn reset_commanded(&mut self, now: Duration) {
        self.record(now, BusEvent::ResetLow);
    }

    /// The sensor entered reset (reset pulled low while running, or power lost).
    pub(crate) fn entered_reset(&mut self, now: Duration) {
        self.low_since = Some(now);
    }

    /// The reset pin released: a new cycle. The trace restarts at the last reset-low command.
    pub(crate) fn released(&mut self, now: Duration) {
        let last_low = self
            .trace
            .iter()
            .rev()
            .find(|e| e.event == BusEvent::ResetLow)
            .copied();
        self.trace.clear();
        self.trace.extend(last_low);
        self.record(now, BusEvent::ResetReleased);
        (self.pll_at, self.ctrl_at, self.en_at) = (None, None, None);
        self.violations.clear();
        let (Some(b), Some(since)) = (&self.spec, self.low_since) else {
            return;
        };
        let low = now.saturating_sub(since);
        if low < Duration::from_micros(b.reset_low_us) {
            let want = b.reset_low_us;
            self.violation(format!(
                "reset released after {} µs low, the imager needs {want} µs",
                us(low)
            ));
        }
    }

    /// A register write reached the sensor.
    pub(crate) fn write(&mut self, now: Duration, reg: u16, value: u16) {
        self.record(now, BusEvent::Write { reg, value });
        if self.pll_registers.contains(&reg) {
            self.pll_at = Some(now);
        }
        let Some(b) = self.spec.clone() else {
            return;
        };
        if [reg, value] == b.ctrl {
            self.ctrl_at = Some(now);
            match self.pll_at {
                None => self.violation(format!("CTRL ({reg:#06x}) before the PLL registers")),
                Some(t) if now < t + Duration::from_micros(b.pll_settle_us) => {
                    self.violation(format!(
                        "CTRL ({reg:#06x}) {} µs after the PLL registers, before the PLL settled ({} µs)",
                        us(now - t),
                        b.pll_settle_us
                    ))
                }
                Some(_) => {}
            }
        } else if [reg, value] == b.en {
            self.en_at = Some(now);
            if self.ctrl_at.is_none() {
                self.violation(format!("EN ({reg:#06x}) before CTRL ({:#06x})", b.ctrl[0]));
            }
        }
    }

    /// The measurement is asked to start: false (recorded) when the imager is not enabled and
    /// settled, or the bring-up of this cycle was out of order.
    pub(crate) fn may_measure(&mut self, now: Duration) -> bool {
        let Some(b) = self.spec.clone() else {
            return true;
        };
        match self.en_at {
            None => self.violation(format!(
                "measurement started with the imager not enabled (EN {:#06x} not written)",
                b.en[0]
            )),
            Some(t) if now < t + Duration::from_micros(b.enable_settle_us) => {
                self.violation(format!(
                    "measurement started {} µs after EN, before the imager settled ({} µs)",
                    us(now - t),
                    b.enable_settle_us
                ))
            }
            Some(_) => {}
        }
        self.violations.is_empty()
    }

    /// The violations of the current cycle.
    pub(crate) fn violations(&self) -> &[String] {
        &self.violations
    }

    /// The trace of the current cycle.
    pub(crate) fn trace(&self) -> &[TraceEvent] {
        &self.trace
    }
}
