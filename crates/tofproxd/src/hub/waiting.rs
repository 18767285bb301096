//! Claim calls parked until the first reading: the bounded waiting slots of the [`Hub`].

use std::sync::Arc;

use super::Hub;

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

impl Hub {
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
}
