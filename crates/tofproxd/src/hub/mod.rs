//! The daemon's domain state, apart from any bus: the service [`State`], what clients
//! [`Claim`] (per unique bus name) and the [`Demand`] that follows, the [`Status`] the
//! properties show, and the [`Event`]s the loop sends to the publisher. The zbus adapter
//! (`service`) and the publisher (`publisher`) are thin layers over the [`Hub`]; the
//! controller only speaks this vocabulary.

mod events;
mod status;
#[cfg(test)]
mod tests;
mod waiting;

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::sync::watch;

use crate::config::Config;

pub use events::{DepthMessage, EVENT_CAPACITY, Event, EventSender, StatusUpdate, event_channel};
pub use status::{Claim, Demand, Reason, State, Status};
pub use waiting::{FirstReading, MAX_WAITING, MAX_WAITING_PER_CLIENT, OwnedWaitSlot};

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
