//! The daemon's domain state, apart from any bus: the service [`State`], what clients
//! [`Claim`] (per unique bus name) and the [`Demand`] that follows, the [`Status`] the
//! properties show, and the [`Event`]s the loop sends to the publisher. The zbus adapter
//! (`service`) and the publisher (`publisher`) are thin layers over the [`Hub`]; the
//! controller only speaks this vocabulary.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::sync::{mpsc, watch};

use crate::config::{Config, Mode};

/// Service state (the `State` property).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// Sensor held in reset (no claim).
    Off,
    /// Claimed, no valid reading yet.
    Starting,
    /// Readings flowing.
    Running,
    /// The last cycle failed; retrying.
    Error,
    /// Several cycles in a row failed (device gone?); retrying.
    Unavailable,
}

impl State {
    /// The property string.
    pub fn as_str(self) -> &'static str {
        match self {
            State::Off => "off",
            State::Starting => "starting",
            State::Running => "running",
            State::Error => "error",
            State::Unavailable => "unavailable",
        }
    }
}

/// What the clients currently want from the loop.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Demand {
    /// Someone claims proximity (native or compat).
    pub proximity: bool,
    /// Someone claims depth frames.
    pub depth: bool,
}

impl Demand {
    /// Whether the loop must run.
    pub fn any(self) -> bool {
        self.proximity || self.depth
    }
}

/// Everything the properties show.
#[derive(Debug, Clone, PartialEq)]
pub struct Status {
    /// `HasSensor`.
    pub has_sensor: bool,
    /// `State`.
    pub state: State,
    /// `Near`.
    pub near: bool,
    /// `NearChangedNs`: `CLOCK_BOOTTIME` (ns) of the capture whose reading last changed `Near`
    /// (0 = unchanged since the daemon started).
    pub near_changed_ns: u64,
    /// `ReadingTimestampNs`: `CLOCK_BOOTTIME` (ns) of the capture of the last valid reading
    /// (0 = none yet).
    pub reading_ns: u64,
    /// `DistanceMm` (0 = unknown).
    pub distance_mm: u32,
    /// `NearThresholdMm`.
    pub near_threshold_mm: u32,
    /// `FarThresholdMm`.
    pub far_threshold_mm: u32,
    /// `Mode`.
    pub mode: Mode,
    /// `RateHz`.
    pub rate_hz: f64,
    /// `PowerEstimateMw`.
    pub power_mw: f64,
    /// `GetStatus()["EnergyMj"]`: the modelled energy of the cycles counted in `cycles`
    /// since the daemon started (mJ; the energy meter's total, each cycle with the sleep
    /// after it).
    pub energy_mj: f64,
    /// `LastError`.
    pub last_error: String,
    /// Exposure per raw image (µs).
    pub exposure_us: f64,
    /// Cycles run.
    pub cycles: u64,
    /// Valid readings.
    pub valid_readings: u64,
    /// Failed cycles.
    pub errors: u64,
    /// Backend description.
    pub backend: String,
    /// How near readings are checked for plausibility (thesis 2.2.1): `"calibrated"` (the
    /// calibration's amplitude scale), `"nominal"` (no amplitude calibration: the config's
    /// nominal scale), `""` before the first cycle.
    pub amplitude_check: &'static str,
    /// The rule that decided the last reading (or released a held Near).
    pub reason: Reason,
}

/// Which rule decided a reading (`GetStatus()["Reason"]`; issue 34, for issue 37's
/// `tofprox monitor --json` rows).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Reason {
    /// No reading yet.
    #[default]
    None,
    /// The ROI statistic against the thresholds (near at once, far after the debounce).
    Distance,
    /// Nothing in range: no pixel returned enough light for a target (far).
    NothingInRange,
    /// Every code on a rail from the sensor's own return: something too close to measure.
    Saturated,
    /// A dim near candidate unwrapped beyond `far_mm` at the second frequency (far).
    SecondFrequency,
    /// A presence probe saw no change: the last reading stands.
    Probe,
    /// Something pressed on the cover window (its return jumped while near): near.
    OnTheWindow,
    /// Near released: no valid reading for `loop.near_hold_ms`.
    HoldExpired,
    /// The loop stopped (no claim).
    Stopped,
}

impl Reason {
    /// The name published.
    pub fn as_str(self) -> &'static str {
        match self {
            Reason::None => "",
            Reason::Distance => "distance",
            Reason::NothingInRange => "nothing_in_range",
            Reason::Saturated => "saturated",
            Reason::SecondFrequency => "second_frequency",
            Reason::Probe => "probe_unchanged",
            Reason::OnTheWindow => "on_the_window",
            Reason::HoldExpired => "hold_expired",
            Reason::Stopped => "stopped",
        }
    }
}

/// What a client can claim (each held per unique bus name).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Claim {
    /// Native proximity (`ClaimProximity` on `org.tofprox.Proximity1`).
    Proximity,
    /// Depth frames (`ClaimDepth`).
    Depth,
    /// Proximity through the iio-sensor-proxy compatible interface.
    CompatProximity,
}

/// One client's claims.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct ClientClaims {
    proximity: bool,
    depth: bool,
    compat_proximity: bool,
}

impl ClientClaims {
    fn any(self) -> bool {
        self.proximity || self.depth || self.compat_proximity
    }

    fn slot(&mut self, claim: Claim) -> &mut bool {
        match claim {
            Claim::Proximity => &mut self.proximity,
            Claim::Depth => &mut self.depth,
            Claim::CompatProximity => &mut self.compat_proximity,
        }
    }
}

struct HubInner {
    /// What the loop reports.
    status: Status,
    /// What clients see ([`Hub::status`]): `status` while someone claims proximity or no one
    /// claims depth; while only depth is claimed, what a client would see with no claim at
    /// all (see [`Hub::update`]).
    public: Status,
    /// Cycles, valid readings and errors run for depth claims alone (left out of `public`).
    hidden_counts: [u64; 3],
    /// The energy of those cycles (mJ).
    hidden_energy_mj: f64,
    claims: BTreeMap<String, ClientClaims>,
    /// A valid reading exists since the loop last started.
    have_reading: bool,
    /// Claims parked waiting for a first reading, per client (bounded: [`MAX_WAITING_PER_CLIENT`]).
    waiting: BTreeMap<String, usize>,
    /// Their sum (bounded: [`MAX_WAITING`]).
    waiting_total: usize,
}

/// Most claim calls of one client parked at once waiting for a first reading; further ones
/// are answered at once (claim held, no wait).
pub const MAX_WAITING_PER_CLIENT: usize = 4;
/// Most claim calls of all clients parked at once waiting for a first reading.
pub const MAX_WAITING: usize = 64;

/// How a claim call's wait for the first reading ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FirstReading {
    /// A valid reading exists (at once or after waiting).
    Ready,
    /// None within `loop.first_reading_timeout_ms`.
    TimedOut,
    /// Not waited for: the caller's or everyone's waiting claims are at their bound.
    NotWaited,
}

/// A parked claim call; the slot is given back when dropped.
struct WaitSlot<'a> {
    hub: &'a Hub,
    client: &'a str,
}

impl Drop for WaitSlot<'_> {
    fn drop(&mut self) {
        self.hub.give_back_slot(self.client);
    }
}

/// A waiting slot held by a task of its own: the deferred reply of a claim call
/// (`service::ClaimWaits`), which waits off the dispatcher. Given back when dropped.
pub struct OwnedWaitSlot {
    hub: Arc<Hub>,
    client: String,
}

impl Drop for OwnedWaitSlot {
    fn drop(&mut self) {
        self.hub.give_back_slot(&self.client);
    }
}

impl OwnedWaitSlot {
    /// Wait (bounded by `loop.first_reading_timeout_ms`) until a valid reading exists since
    /// the loop started, holding this slot; then give it back.
    pub async fn wait_first_reading(self) -> FirstReading {
        let mut rx = self.hub.reading_tx.subscribe();
        if self.hub.lock().have_reading {
            return FirstReading::Ready;
        }
        let start = *rx.borrow_and_update();
        let timeout = self.hub.first_reading_timeout;
        match tokio::time::timeout(timeout, rx.wait_for(|n| *n != start)).await {
            Ok(_) => FirstReading::Ready,
            Err(_) => FirstReading::TimedOut,
        }
    }
}

/// Shared between the D-Bus interfaces, the publisher and the loop.
pub struct Hub {
    inner: Mutex<HubInner>,
    demand_tx: watch::Sender<Demand>,
    /// Incremented on every valid reading.
    reading_tx: watch::Sender<u64>,
    first_reading_timeout: Duration,
}

/// Claim counts (for `GetStatus` and leak checks).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ClaimCounts {
    /// Clients with any claim.
    pub clients: u32,
    /// Clients with a proximity claim (native or compat).
    pub proximity_clients: u32,
    /// Proximity claims (native).
    pub proximity: u32,
    /// Depth claims.
    pub depth: u32,
    /// Compat proximity claims.
    pub compat_proximity: u32,
}

impl Hub {
    /// New hub for `cfg`, with the demand receiver for the loop.
    pub fn new(cfg: &Config, backend: String) -> (Arc<Self>, watch::Receiver<Demand>) {
        let (demand_tx, demand_rx) = watch::channel(Demand::default());
        let (reading_tx, _) = watch::channel(0u64);
        let status = Status {
            has_sensor: true,
            state: State::Off,
            near: false,
            near_changed_ns: 0,
            reading_ns: 0,
            distance_mm: 0,
            near_threshold_mm: cfg.proximity.near_mm,
            far_threshold_mm: cfg.proximity.far_mm,
            mode: cfg.processing.mode,
            rate_hz: 0.0,
            power_mw: 0.0,
            energy_mj: 0.0,
            last_error: String::new(),
            exposure_us: cfg.exposure.initial_us,
            cycles: 0,
            valid_readings: 0,
            errors: 0,
            backend,
            amplitude_check: "",
            reason: Reason::None,
        };
        let hub = Arc::new(Self {
            inner: Mutex::new(HubInner {
                public: status.clone(),
                hidden_counts: [0; 3],
                hidden_energy_mj: 0.0,
                status,
                claims: BTreeMap::new(),
                have_reading: false,
                waiting: BTreeMap::new(),
                waiting_total: 0,
            }),
            demand_tx,
            reading_tx,
            first_reading_timeout: Duration::from_millis(cfg.loop_.first_reading_timeout_ms),
        });
        (hub, demand_rx)
    }

    fn lock(&self) -> MutexGuard<'_, HubInner> {
        // A poisoned lock only means a panic elsewhere while holding it; the data is plain values.
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Snapshot of the status clients see (properties, `GetStatus`, the unit's STATUS line):
    /// nothing in it shows a depth claim (see [`Hub::update`]).
    pub fn status(&self) -> Status {
        self.lock().public.clone()
    }

    /// A receiver of demand changes (the publisher re-publishes the status on each).
    pub fn subscribe_demand(&self) -> watch::Receiver<Demand> {
        self.demand_tx.subscribe()
    }

    /// Claim counts.
    pub fn claim_counts(&self) -> ClaimCounts {
        let g = self.lock();
        let mut c = ClaimCounts::default();
        for cl in g.claims.values() {
            c.clients += 1;
            c.proximity_clients += u32::from(cl.proximity || cl.compat_proximity);
            c.proximity += u32::from(cl.proximity);
            c.depth += u32::from(cl.depth);
            c.compat_proximity += u32::from(cl.compat_proximity);
        }
        c
    }

    /// Current demand.
    pub fn demand(&self) -> Demand {
        *self.demand_tx.borrow()
    }

    fn recompute_demand(&self, g: &HubInner) {
        let d = Demand {
            proximity: g.claims.values().any(|c| c.proximity || c.compat_proximity),
            depth: g.claims.values().any(|c| c.depth),
        };
        self.demand_tx.send_if_modified(|cur| {
            if *cur != d {
                *cur = d;
                true
            } else {
                false
            }
        });
    }

    /// Set (`held = true`) or clear one claim of `client`; a client without any claim left is
    /// forgotten. The demand is recomputed. Returns whether `client` held no claim before.
    pub fn set_claim(&self, client: &str, claim: Claim, held: bool) -> bool {
        let mut g = self.lock();
        let new = !g.claims.contains_key(client);
        let entry = g.claims.entry(client.to_string()).or_default();
        *entry.slot(claim) = held;
        if !entry.any() {
            g.claims.remove(client);
        }
        self.recompute_demand(&g);
        new
    }

    /// Drop every claim of a client (it left the bus).
    pub fn client_gone(&self, client: &str) -> bool {
        let mut g = self.lock();
        let had = g.claims.remove(client).is_some();
        if had {
            self.recompute_demand(&g);
        }
        had
    }

    /// Names of clients holding claims.
    pub fn clients(&self) -> Vec<String> {
        self.lock().claims.keys().cloned().collect()
    }

    /// Unique names of the clients holding a depth claim (the only receivers of depth frames).
    pub fn depth_claimers(&self) -> Vec<String> {
        let g = self.lock();
        g.claims
            .iter()
            .filter(|(_, c)| c.depth)
            .map(|(n, _)| n.clone())
            .collect()
    }

    /// Wait (bounded by `loop.first_reading_timeout_ms`) until a valid reading exists since
    /// the loop started. At most [`MAX_WAITING_PER_CLIENT`] calls of one `client` and
    /// [`MAX_WAITING`] of all clients wait at once; any further call returns at once
    /// ([`FirstReading::NotWaited`]), so a flood of claims parks a bounded number of tasks.
    pub async fn wait_first_reading(&self, client: &str) -> FirstReading {
        let mut rx = self.reading_tx.subscribe();
        let Some(_slot) = self.wait_slot(client) else {
            return FirstReading::NotWaited;
        };
        if self.lock().have_reading {
            return FirstReading::Ready;
        }
        let start = *rx.borrow_and_update();
        match tokio::time::timeout(self.first_reading_timeout, rx.wait_for(|n| *n != start)).await {
            Ok(_) => FirstReading::Ready,
            Err(_) => FirstReading::TimedOut,
        }
    }

    /// Take one of the bounded waiting slots for `client`, if one is free.
    fn wait_slot<'a>(&'a self, client: &'a str) -> Option<WaitSlot<'a>> {
        // `then`, not `then_some`: a slot not taken must never exist (its drop gives one back)
        self.take_slot(client)
            .then(|| WaitSlot { hub: self, client })
    }

    /// [`Hub::wait_first_reading`]'s slot for a task of its own (taken here, before the task
    /// exists, so no more tasks than slots ever wait); `None` when the caller's or everyone's
    /// waiting claims are at their bound.
    pub fn take_wait_slot(self: &Arc<Self>, client: &str) -> Option<OwnedWaitSlot> {
        self.take_slot(client).then(|| OwnedWaitSlot {
            hub: self.clone(),
            client: client.to_string(),
        })
    }

    fn take_slot(&self, client: &str) -> bool {
        let mut g = self.lock();
        let mine = g.waiting.get(client).copied().unwrap_or(0);
        if g.waiting_total >= MAX_WAITING || mine >= MAX_WAITING_PER_CLIENT {
            return false;
        }
        g.waiting_total += 1;
        *g.waiting.entry(client.to_string()).or_default() += 1;
        true
    }

    fn give_back_slot(&self, client: &str) {
        let mut g = self.lock();
        g.waiting_total -= 1;
        if let Some(n) = g.waiting.get_mut(client) {
            *n -= 1;
            if *n == 0 {
                g.waiting.remove(client);
            }
        }
    }

    /// Claim calls parked waiting for a first reading (all clients).
    pub fn waiting_claims(&self) -> usize {
        self.lock().waiting_total
    }

    /// Apply a change to the status; returns the status clients see before and after it.
    ///
    /// While depth is claimed and proximity is not, clients see what they would see with no
    /// claim at all: the loop stopped (`off`, not near, distance 0, rate 0) and every other
    /// value held as it was; the cycles run meanwhile are not counted in what they see.
    pub fn update(&self, f: impl FnOnce(&mut Status)) -> (Status, Status) {
        let mut g = self.lock();
        let counts = |s: &Status| [s.cycles, s.valid_readings, s.errors];
        let counts_before = counts(&g.status);
        let energy_before = g.status.energy_mj;
        let near_before = g.status.near;
        f(&mut g.status);
        if g.status.state == State::Off || g.status.state == State::Starting {
            g.have_reading = false;
        }
        let before = g.public.clone();
        let d = self.demand();
        if d.proximity || !d.depth {
            let mut public = g.status.clone();
            public.cycles -= g.hidden_counts[0];
            public.valid_readings -= g.hidden_counts[1];
            public.errors -= g.hidden_counts[2];
            public.energy_mj -= g.hidden_energy_mj;
            // The times clients see are of what they saw: a reading counted for them, a Near
            // change of theirs (one shown only now, after a depth claim alone, is stamped now).
            if g.status.valid_readings == counts_before[1] {
                public.reading_ns = before.reading_ns;
            }
            public.near_changed_ns = match (public.near != before.near, near_before != public.near)
            {
                (false, _) => before.near_changed_ns,
                (true, true) => g.status.near_changed_ns,
                (true, false) => crate::boottime::boottime_ns(),
            };
            g.public = public;
        } else {
            let counts_after = counts(&g.status);
            g.hidden_energy_mj += g.status.energy_mj - energy_before;
            for (h, (a, b)) in g
                .hidden_counts
                .iter_mut()
                .zip(counts_after.iter().zip(counts_before))
            {
                *h += a - b;
            }
            let p = &mut g.public;
            (p.state, p.near, p.distance_mm, p.rate_hz) = (State::Off, false, 0, 0.0);
        }
        (before, g.public.clone())
    }

    /// Apply a status fragment from the loop (counters counted, `power_mw` left to the
    /// publisher's rate limit); returns the status before and after it.
    pub fn apply(&self, u: &StatusUpdate) -> (Status, Status) {
        self.update(|s| {
            if let Some(v) = u.state {
                s.state = v;
            }
            if let Some(v) = u.near {
                if v != s.near {
                    s.near_changed_ns = u.timestamp_ns.unwrap_or(s.near_changed_ns);
                }
                s.near = v;
            }
            if u.valid_reading
                && let Some(t) = u.timestamp_ns
            {
                s.reading_ns = t;
            }
            if let Some(v) = u.distance_mm {
                s.distance_mm = v;
            }
            if let Some(v) = u.mode {
                s.mode = v;
            }
            if let Some(v) = u.rate_hz {
                s.rate_hz = v;
            }
            if let Some(v) = &u.last_error {
                s.last_error.clone_from(v);
            }
            if let Some(v) = u.exposure_us {
                s.exposure_us = v;
            }
            if let Some(v) = u.has_sensor {
                s.has_sensor = v;
            }
            if let Some(v) = u.amplitude_check {
                s.amplitude_check = v;
            }
            if let Some(v) = u.reason {
                s.reason = v;
            }
            if u.cycle {
                s.cycles += 1;
            }
            if u.error {
                s.errors += 1;
            }
            if u.valid_reading {
                s.valid_readings += 1;
            }
        })
    }

    /// The energy meter's total since start (mJ, [`Status::energy_mj`]); what clients see
    /// leaves out the energy of cycles run for a depth claim alone, as `cycles` does.
    pub fn set_energy(&self, total_mj: f64) {
        self.update(|s| s.energy_mj = total_mj);
    }

    /// Note a valid reading (wakes waiting claimers).
    pub fn note_valid_reading(&self) {
        self.lock().have_reading = true;
        self.reading_tx.send_modify(|n| *n = n.wrapping_add(1));
    }
}

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
    /// The energy meter's total since start after a cycle (mJ; [`Status::energy_mj`]).
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
    /// How near readings are checked (see [`Status::amplitude_check`]).
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

#[cfg(test)]
mod tests {
    use super::*;

    fn hub() -> Arc<Hub> {
        Hub::new(&Config::default(), "test".into()).0
    }

    fn depth(timestamp_ns: u64) -> DepthMessage {
        DepthMessage {
            timestamp_ns,
            width: 1,
            height: 1,
            depth_le: vec![0, 0],
            amplitude_le: vec![0, 0],
        }
    }

    #[test]
    fn depth_frames_take_at_most_half_the_channel_and_status_still_gets_through() {
        let (mut tx, mut rx) = event_channel();
        let sent = (0..EVENT_CAPACITY as u64)
            .filter(|&t| tx.depth(depth(t)))
            .count();
        assert_eq!(sent, EVENT_CAPACITY / 2);
        assert_eq!(tx.dropped_depth(), (EVENT_CAPACITY / 2) as u64);
        // The other half is room for status updates, none of them dropped.
        for n in 0..EVENT_CAPACITY / 2 {
            tx.status(StatusUpdate {
                rate_hz: Some(n as f64),
                ..StatusUpdate::default()
            });
        }
        let mut depth_ts = Vec::new();
        let mut rates = Vec::new();
        while let Ok(ev) = rx.try_recv() {
            match ev {
                Event::Depth(d) => depth_ts.push(d.timestamp_ns),
                Event::Status(u) => rates.extend(u.rate_hz),
                Event::Energy(_) => {}
            }
        }
        assert_eq!(
            depth_ts,
            (0..(EVENT_CAPACITY / 2) as u64).collect::<Vec<_>>()
        );
        let expected: Vec<f64> = (0..EVENT_CAPACITY / 2).map(|n| n as f64).collect();
        assert_eq!(rates, expected, "every status update, in order");
        // Drained: depth frames are accepted again.
        assert!(tx.depth(depth(99)));
    }

    #[test]
    fn claims_drive_demand_and_are_forgotten_when_released() {
        let h = hub();
        h.set_claim(":1.1", Claim::Proximity, true);
        h.set_claim(":1.2", Claim::Depth, true);
        assert_eq!(
            h.demand(),
            Demand {
                proximity: true,
                depth: true
            }
        );
        assert_eq!(h.depth_claimers(), vec![":1.2".to_string()]);
        h.set_claim(":1.2", Claim::Depth, false);
        assert_eq!(
            h.clients(),
            vec![":1.1".to_string()],
            "no claim left: forgotten"
        );
        assert!(!h.demand().depth);
        assert!(h.client_gone(":1.1"));
        assert!(!h.client_gone(":1.1"), "already gone");
        assert!(!h.demand().any());
        assert_eq!(h.claim_counts(), ClaimCounts::default());
    }

    #[test]
    fn compat_claim_counts_as_proximity_demand() {
        let h = hub();
        h.set_claim(":1.7", Claim::CompatProximity, true);
        assert!(h.demand().proximity);
        let c = h.claim_counts();
        assert_eq!((c.clients, c.proximity, c.compat_proximity), (1, 0, 1));
        assert_eq!(c.proximity_clients, 1);
        assert!(h.depth_claimers().is_empty());
        h.set_claim(":1.8", Claim::Depth, true);
        let c = h.claim_counts();
        assert_eq!((c.clients, c.proximity_clients, c.depth), (2, 1, 1));
        assert_eq!(h.depth_claimers(), vec![":1.8".to_string()]);
    }

    /// A flood of claim calls parks at most the per-client and the global bound; the rest
    /// return at once, and every slot is given back when its call ends.
    #[tokio::test]
    async fn waiting_claims_are_bounded_per_client_and_in_total() {
        let h = hub();
        let mut parked = Vec::new();
        let mut not_waited = 0;
        // 25 clients × 8 calls: the first 16 park 4 each (per-client bound), then the
        // global bound of 64 is reached.
        for i in 0..200 {
            let client = format!(":1.{}", i / 8);
            let h2 = h.clone();
            let mut call = Box::pin(async move { h2.wait_first_reading(&client).await });
            // Poll once: a call that waits stays pending, one over a bound is answered.
            match futures_poll_once(&mut call).await {
                Some(r) => {
                    assert_eq!(r, FirstReading::NotWaited);
                    not_waited += 1;
                }
                None => parked.push(call),
            }
        }
        assert_eq!(parked.len(), MAX_WAITING, "global bound");
        assert_eq!(h.waiting_claims(), MAX_WAITING);
        assert_eq!(not_waited, 200 - MAX_WAITING);
        assert_eq!(h.lock().waiting.len(), MAX_WAITING / MAX_WAITING_PER_CLIENT);
        h.note_valid_reading();
        for call in parked {
            assert_eq!(call.await, FirstReading::Ready);
        }
        assert_eq!(h.waiting_claims(), 0, "slots given back");
        assert_eq!(h.wait_first_reading(":1.99").await, FirstReading::Ready);
    }

    #[tokio::test]
    async fn a_waiting_claim_times_out_and_frees_its_slot() {
        let mut cfg = Config::default();
        cfg.loop_.first_reading_timeout_ms = 20;
        let h = Hub::new(&cfg, "test".into()).0;
        let calls: Vec<_> = (0..MAX_WAITING_PER_CLIENT)
            .map(|_| {
                let h2 = h.clone();
                tokio::spawn(async move { h2.wait_first_reading(":1.5").await })
            })
            .collect();
        tokio::task::yield_now().await;
        assert_eq!(h.waiting_claims(), MAX_WAITING_PER_CLIENT);
        assert_eq!(
            h.wait_first_reading(":1.5").await,
            FirstReading::NotWaited,
            "per-client bound"
        );
        assert_eq!(h.wait_first_reading(":1.6").await, FirstReading::TimedOut);
        for c in calls {
            assert_eq!(c.await.unwrap(), FirstReading::TimedOut);
        }
        assert_eq!(h.waiting_claims(), 0);
    }

    /// Poll a future once: `Some(output)` if it finished.
    async fn futures_poll_once<F: std::future::Future + Unpin>(f: &mut F) -> Option<F::Output> {
        std::future::poll_fn(|cx| {
            std::task::Poll::Ready(match std::pin::Pin::new(&mut *f).poll(cx) {
                std::task::Poll::Ready(v) => Some(v),
                std::task::Poll::Pending => None,
            })
        })
        .await
    }

    /// `EnergyMj` is the meter's total of the cycles clients see: the energy of cycles run for
    /// a depth claim alone is left out, as they are of `Cycles`.
    #[test]
    fn the_energy_total_leaves_out_cycles_run_for_a_depth_claim_alone() {
        let h = hub();
        h.set_claim(":1.1", Claim::Proximity, true);
        h.set_energy(10.0);
        assert_eq!(h.status().energy_mj, 10.0);
        // the proximity client goes, a depth client alone: 15 mJ of its cycles stay hidden
        h.set_claim(":1.1", Claim::Proximity, false);
        h.set_claim(":1.2", Claim::Depth, true);
        h.set_energy(25.0);
        assert_eq!(h.status().energy_mj, 10.0);
        h.set_claim(":1.3", Claim::Proximity, true);
        h.set_energy(31.0);
        assert_eq!(
            h.status().energy_mj,
            16.0,
            "10 mJ, then 6 mJ of the proximity claim's"
        );
    }

    /// A depth claim alone shows nothing in the public status: the loop runs, but clients see
    /// it off, with no reading and the counters held; a proximity claim shows the loop again,
    /// with only its own cycles counted.
    #[test]
    fn a_depth_claim_alone_is_not_visible_in_the_status() {
        let h = hub();
        let running = StatusUpdate {
            state: Some(State::Running),
            near: Some(true),
            timestamp_ns: Some(77),
            distance_mm: Some(120),
            rate_hz: Some(4.0),
            cycle: true,
            valid_reading: true,
            ..StatusUpdate::default()
        };
        h.set_claim(":1.1", Claim::Depth, true);
        let (before, after) = h.apply(&running);
        assert_eq!(before, after, "nothing changes for clients");
        assert_eq!(
            (after.state, after.near, after.distance_mm, after.rate_hz),
            (State::Off, false, 0, 0.0)
        );
        assert_eq!((after.cycles, after.valid_readings), (0, 0));
        assert_eq!(
            (after.reading_ns, after.near_changed_ns),
            (0, 0),
            "no reading time either"
        );
        h.set_claim(":1.2", Claim::Proximity, true);
        // shown at the claim, Near is stamped then, not with the hidden reading's time
        let t_claim = crate::boottime::boottime_ns();
        let (_, shown) = h.update(|_| {});
        assert!(shown.near && shown.near_changed_ns >= t_claim, "{shown:?}");
        assert_eq!(
            shown.reading_ns, 0,
            "the hidden reading's time stays hidden"
        );
        let (_, after) = h.apply(&running);
        assert_eq!(
            (after.state, after.near, after.distance_mm, after.rate_hz),
            (State::Running, true, 120, 4.0)
        );
        assert_eq!(
            (after.cycles, after.valid_readings),
            (1, 1),
            "own cycles only"
        );
        assert_eq!(
            (after.reading_ns, after.near_changed_ns),
            (77, shown.near_changed_ns),
            "a reading of its own shows its time; Near did not change"
        );
        // the proximity claim goes, the depth claim stays: seen stopped at once
        h.set_claim(":1.2", Claim::Proximity, false);
        let (before, after) = h.update(|_| {});
        assert_eq!(before.state, State::Running);
        assert_eq!(
            (after.state, after.rate_hz, after.cycles),
            (State::Off, 0.0, 1)
        );
    }

    /// A Near change takes the time of the capture that changed it; a reading that leaves
    /// Near as it was moves only the reading's time; an update without a valid reading
    /// moves neither.
    #[test]
    fn near_changes_and_readings_carry_their_capture_time() {
        let h = hub();
        let reading = |near: bool, t: u64| StatusUpdate {
            near: Some(near),
            timestamp_ns: Some(t),
            valid_reading: true,
            cycle: true,
            ..StatusUpdate::default()
        };
        let (_, s) = h.apply(&reading(false, 1_000));
        assert_eq!(
            (s.near_changed_ns, s.reading_ns),
            (0, 1_000),
            "far stays far"
        );
        let (_, s) = h.apply(&reading(true, 2_000));
        assert_eq!(
            (s.near, s.near_changed_ns, s.reading_ns),
            (true, 2_000, 2_000)
        );
        let (_, s) = h.apply(&reading(true, 3_000));
        assert_eq!((s.near_changed_ns, s.reading_ns), (2_000, 3_000));
        let (_, s) = h.apply(&StatusUpdate {
            error: true,
            timestamp_ns: Some(4_000),
            ..StatusUpdate::default()
        });
        assert_eq!((s.near_changed_ns, s.reading_ns), (2_000, 3_000));
        let (_, s) = h.apply(&reading(false, 5_000));
        assert_eq!(
            (s.near, s.near_changed_ns, s.reading_ns),
            (false, 5_000, 5_000)
        );
    }

    #[test]
    fn apply_counts_and_leaves_power_to_the_publisher() {
        let h = hub();
        let (before, after) = h.apply(&StatusUpdate {
            state: Some(State::Running),
            near: Some(true),
            power_mw: Some(3.0),
            cycle: true,
            valid_reading: true,
            ..StatusUpdate::default()
        });
        assert_eq!(before.state, State::Off);
        assert_eq!(after.state, State::Running);
        assert!(after.near);
        assert_eq!(
            (after.cycles, after.valid_readings, after.errors),
            (1, 1, 0)
        );
        assert_eq!(
            after.power_mw, 0.0,
            "power is rate-limited by the publisher"
        );
    }
}
