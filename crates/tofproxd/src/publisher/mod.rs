//! Where the loop's results go: the [`Publisher`] seam and the one task that feeds every
//! publisher ([`run_publishers`]).
//!
//! The loop sends [`Event`]s (status fragments, depth frames) over the bounded channel of
//! [`crate::hub::event_channel`]; [`run_publishers`] applies each to the [`Hub`] and hands what
//! the clients see — a [`StatusChange`] (the public [`Status`] before and after) or a
//! [`DepthMessage`] — to each publisher in turn, in the hub's vocabulary only. The
//! publishers:
//!
//! | `publisher =` | publishers | module |
//! |---|---|---|
//! | `dbus` | `org.tofprox.Proximity1` (+ `net.hadess.SensorProxy` with `[dbus] iio_sensor_proxy_compat`) | [`dbus`] |
//! | `input` | the D-Bus one, and Near as a uinput switch | [`dbus`], the crate's `input` |
//! | `socket` | JSON Lines on a Unix socket, no D-Bus at all | [`socket`], its schema [`jsonl`] |
//!
//! A new publisher implements [`Publisher`] and is added where `run::Daemon` builds the list;
//! nothing here changes.

pub mod dbus;
pub mod jsonl;
pub mod socket;

use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::mpsc;

use crate::hub::{DepthMessage, Event, Hub, Status};

/// What the clients see changed by one event: the public status (see [`Hub::status`])
/// before and after it.
#[derive(Debug, Clone, Copy)]
pub struct StatusChange<'a> {
    /// Before the event.
    pub before: &'a Status,
    /// After the event.
    pub after: &'a Status,
}

impl StatusChange<'_> {
    /// The event changed `Near`.
    pub fn near_changed(&self) -> bool {
        self.before.near != self.after.near
    }

    /// The event carries a valid reading the clients see (counted in their view).
    pub fn reading(&self) -> bool {
        self.after.valid_readings != self.before.valid_readings
    }
}

/// A publisher failed to deliver something (logged by [`run_publishers`]; the loop goes on).
#[derive(Debug, thiserror::Error)]
#[error("{publisher} publisher: {source}")]
pub struct PublishError {
    /// Which publisher ([`Publisher::name`]).
    pub publisher: &'static str,
    /// What failed (a D-Bus emit, a uinput write).
    #[source]
    pub source: Box<dyn std::error::Error + Send + Sync>,
}

impl PublishError {
    /// An error of `publisher`.
    pub fn new(
        publisher: &'static str,
        source: impl Into<Box<dyn std::error::Error + Send + Sync>>,
    ) -> Self {
        Self {
            publisher,
            source: source.into(),
        }
    }
}

/// Somewhere the loop's results go. Called from the one publishing task, in the order the
/// loop produced them; a publisher must not block for long (a slow client is its own
/// business: it queues or drops, never holds up the others or the loop).
#[async_trait::async_trait]
pub trait Publisher: Send {
    /// Its name in logs and errors (`"dbus"`, `"input"`, `"socket"`).
    fn name(&self) -> &'static str;

    /// What the clients see changed (also called when nothing visible changed, with
    /// `before == after`, after a claim came or went).
    async fn status(&mut self, change: StatusChange<'_>) -> Result<(), PublishError>;

    /// A depth frame, only while depth is claimed, at most `dbus.depth_max_hz`. Publishers
    /// that do not carry depth keep the default (nothing).
    async fn depth(&mut self, _frame: &DepthMessage) -> Result<(), PublishError> {
        Ok(())
    }
}

/// The publishers a daemon feeds, in order.
pub type Publishers = Vec<Box<dyn Publisher>>;

/// Hand a status change to every publisher (errors logged).
async fn publish_status(publishers: &mut Publishers, before: &Status, after: &Status) {
    for p in publishers.iter_mut() {
        if let Err(e) = p.status(StatusChange { before, after }).await {
            tracing::warn!("{e}");
        }
    }
}

/// The publishing task: applies loop events to the hub and hands what changed to every
/// publisher. Runs until the event channel closes (the loop thread, its only sender, has
/// ended), then drops the publishers. The channel is bounded ([`crate::hub::event_channel`]):
/// while this task is behind, the loop waits to send status updates and drops depth frames.
pub async fn run_publishers(
    hub: Arc<Hub>,
    mut events: mpsc::Receiver<Event>,
    mut publishers: Publishers,
    depth_max_hz: f64,
) {
    // PowerEstimateMw: at most one change per second, carried by the cycle's own update (no
    // timer of its own: no extra wake-up between cycles).
    let mut last_power_emit: Option<Instant> = None;
    let mut last_depth: Option<Instant> = None;
    let depth_interval = Duration::from_secs_f64(1.0 / depth_max_hz.max(0.001));
    let mut demand = hub.subscribe_demand();
    loop {
        let ev = tokio::select! {
            ev = events.recv() => ev,
            // a claim came or went: what clients see may change without a cycle (a depth
            // claim left alone shows the loop stopped, `Hub::update`)
            Ok(()) = demand.changed() => {
                let (before, after) = hub.update(|_| {});
                publish_status(&mut publishers, &before, &after).await;
                continue;
            }
        };
        let Some(ev) = ev else { break };
        match ev {
            Event::Depth(d) => {
                if !hub.demand().depth {
                    continue;
                }
                let now = Instant::now();
                if last_depth.is_some_and(|t| now.duration_since(t) < depth_interval) {
                    continue;
                }
                last_depth = Some(now);
                for p in publishers.iter_mut() {
                    if let Err(e) = p.depth(&d).await {
                        tracing::warn!("{e}");
                    }
                }
            }
            Event::Energy(total_mj) => hub.set_energy(total_mj),
            Event::Status(u) => {
                let (before, mut after) = hub.apply(&u);
                if let Some(p) = u.power_mw
                    && p != after.power_mw
                {
                    let now = Instant::now();
                    if last_power_emit
                        .is_none_or(|t| now.duration_since(t) >= Duration::from_secs(1))
                    {
                        after = hub.update(|s| s.power_mw = p).1;
                        last_power_emit = Some(now);
                    }
                }
                publish_status(&mut publishers, &before, &after).await;
                if u.valid_reading {
                    hub.note_valid_reading();
                }
            }
        }
    }
}
