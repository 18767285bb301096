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
