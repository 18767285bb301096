//! The loop → publisher channel: the [`Event`]s and the bounded [`EventSender`].

use tokio::sync::mpsc;

use super::{Reason, State};
use crate::config::Mode;

/// A depth frame to publish.
#[derive(Debug, Clone)]
pub struct DepthMessage {
    /// Capture time: `CLOCK_BOOTTIME` (ns) when the frames were in ([`crate::boottime`]).
    pub timestamp_ns: u64,
    /// Columns.
    pub width: u16,
    /// Rows.
    pub height: u16,
    /// depth (mm) as little-endian u16.
    pub depth_le: Vec<u8>,
    /// amplitude (LSB, saturating) as little-endian u16.
    pub amplitude_le: Vec<u8>,
}

/// What the loop reports to the publisher.
#[derive(Debug, Clone)]
pub enum Event {
    /// Apply a status change (the closure-free form: a full new status fragment).
    Status(StatusUpdate),
    /// A depth frame (sent only while a depth claim is held).
    Depth(DepthMessage),
    /// The energy meter's total since start after a cycle (mJ; [`crate::hub::Status::energy_mj`]).
    Energy(f64),
}

/// A status fragment from the loop.
#[derive(Debug, Clone, Default)]
pub struct StatusUpdate {
    /// New state.
    pub state: Option<State>,
    /// New near.
    pub near: Option<bool>,
    /// `CLOCK_BOOTTIME` (ns, [`crate::boottime`]) of the capture this update comes from (of
    /// the moment of the decision for an update without one: a stop, a failed cycle).
    pub timestamp_ns: Option<u64>,
    /// New distance (0 = unknown).
    pub distance_mm: Option<u32>,
    /// New mode.
    pub mode: Option<Mode>,
    /// New rate.
    pub rate_hz: Option<f64>,
    /// New power estimate (the publisher limits updates to 1 Hz).
    pub power_mw: Option<f64>,
    /// New last error.
    pub last_error: Option<String>,
    /// New exposure.
    pub exposure_us: Option<f64>,
    /// New has_sensor.
    pub has_sensor: Option<bool>,
    /// How near readings are checked (see [`crate::hub::Status::amplitude_check`]).
    pub amplitude_check: Option<&'static str>,
    /// The rule that decided this update's reading.
    pub reason: Option<Reason>,
    /// This update carries a valid reading.
    pub valid_reading: bool,
    /// This update is one completed cycle (counts).
    pub cycle: bool,
    /// This update is a failed cycle.
    pub error: bool,
}

/// Capacity of the loop → publisher channel (events: about two per cycle).
pub const EVENT_CAPACITY: usize = 32;

/// The loop → publisher channel, bounded at [`EVENT_CAPACITY`]; the loop's end is the
/// [`EventSender`], the publisher's the receiver.
pub fn event_channel() -> (EventSender, mpsc::Receiver<Event>) {
    let (tx, rx) = mpsc::channel(EVENT_CAPACITY);
    (
        EventSender {
            tx,
            dropped_depth: 0,
        },
        rx,
    )
}

/// The loop's end of the bounded event channel. When the publisher falls behind (a slow
/// or stalled bus):
/// - a status update is never dropped or merged (it carries Near transitions and the
///   counters): the loop waits for room — backpressure, the loop runs no faster than its
///   readings can be published, and memory stays bounded;
/// - a depth frame is dropped once half the channel is taken, so frames for a slow
///   reader never fill the room status updates need and never make the loop wait (the
///   publisher rate-limits them to `dbus.depth_max_hz` anyway).
///
/// Called from the loop thread only (blocking; never from inside the tokio runtime).
#[derive(Debug)]
pub struct EventSender {
    tx: mpsc::Sender<Event>,
    dropped_depth: u64,
}

impl EventSender {
    /// Send a status update, waiting for room if the channel is full. A closed channel
    /// (the publisher has ended: shutting down) drops it.
    pub fn status(&self, update: StatusUpdate) {
        let _ = self.tx.blocking_send(Event::Status(update));
    }

    /// Send the energy meter's total (mJ) unless half the channel is taken: a total, so the
    /// next one carries a dropped one's energy too, and the loop never waits for it.
    pub fn energy(&self, total_mj: f64) {
        if self.tx.capacity() > EVENT_CAPACITY / 2 {
            let _ = self.tx.try_send(Event::Energy(total_mj));
        }
    }

    /// Send a depth frame unless half the channel is taken; returns whether it was sent.
    pub fn depth(&mut self, frame: DepthMessage) -> bool {
        let sent = self.tx.capacity() > EVENT_CAPACITY / 2
            && self.tx.try_send(Event::Depth(frame)).is_ok();
        if !sent {
            self.dropped_depth += 1;
            tracing::debug!(
                "publisher behind: depth frame dropped ({} so far)",
                self.dropped_depth
            );
        }
        sent
    }

    /// Depth frames dropped so far because the publisher was behind.
    pub fn dropped_depth(&self) -> u64 {
        self.dropped_depth
    }
}
