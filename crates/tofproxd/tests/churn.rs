//! Demand settles (issue 34): one unprivileged connection sends 20,000
//! ClaimProximity/ReleaseProximity pairs with `NO_REPLY_EXPECTED` and leaves; the loop acts
//! on the latest demand only, runs no cycle without a claim and is off within one cycle of
//! the churn's end; a client claiming meanwhile still gets the right Near. Over a private
//! `dbus-daemon` (tofprox-testkit's `PrivateBus`), the real `Daemon` in process with a
//! scripted source whose cycles are counted.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use tofprox_core::SensorGeometry;
use tofprox_testkit::bus::PrivateBus;
use tofproxd::client::ProximityProxy;
use tofproxd::config::Config;
use tofproxd::controller::{Controller, ModeCalibrations};
use tofproxd::run::{BusChoice, Daemon, connect};
use tofproxd::source::{CycleRequest, FrameSource, RawCycle, ScriptedSource, SourceError, Step};

/// A scripted source that counts the readings' captures it is asked for.
struct Counted {
    inner: ScriptedSource,
    cycles: Arc<AtomicU64>,
}

impl FrameSource for Counted {
    fn cycle(&mut self, req: &CycleRequest) -> Result<RawCycle, SourceError> {
        // a reading's own capture (a second-frequency capture confirming a near onset is
        // part of its reading)
        if req.modulation_hz.is_none() {
            self.cycles.fetch_add(1, Ordering::SeqCst);
        }
        self.inner.cycle(req)
    }
    fn power_off(&mut self) -> Result<(), SourceError> {
        self.inner.power_off()
    }
    fn supports_row_window(&self) -> bool {
        self.inner.supports_row_window()
    }
    fn supports_mode_switch(&self) -> bool {
        self.inner.supports_mode_switch()
    }
    fn sensor(&self) -> SensorGeometry {
        self.inner.sensor()
    }
    fn describe(&self) -> String {
        "scripted (counted)".into()
    }
}

const RATE_HZ: f64 = 20.0;
const PAIRS: usize = 20_000;

fn config() -> Config {
    let mut cfg = Config::default();
    cfg.loop_.rate_hz = RATE_HZ;
    cfg.loop_.fast_rate_hz = RATE_HZ;
    cfg.loop_.slow_rate_hz = RATE_HZ;
    cfg.loop_.first_reading_timeout_ms = 2000;
    cfg.ambient.enabled = false;
    cfg
}

/// 20,000 claim/release pairs, each call `NO_REPLY_EXPECTED`, then the connection leaves.
async fn churn(address: &str) {
    let conn = connect(&BusChoice::Address(address.into()))
        .await
        .expect("churn connection");
    for _ in 0..PAIRS {
        for member in ["ClaimProximity", "ReleaseProximity"] {
            let msg = zbus::Message::method_call("/org/tofprox/Proximity1", member)
                .destination("org.tofprox.Proximity1")
                .interface("org.tofprox.Proximity1")
                .with_flags(zbus::message::Flags::NO_REPLY_EXPECTED)
                .build(&())
                .expect("message");
            conn.send(&msg).await.expect("send");
        }
    }
    // a last release with a reply: the daemon has handled every call before it
    ProximityProxy::builder(&conn)
        .build()
        .await
        .expect("proxy")
        .release_proximity()
        .await
        .expect("fence");
    conn.close().await.expect("leave");
}

/// The loop's cycles so far (`GetStatus()["Cycles"]`: one per reading, whatever captures it
/// took).
async fn loop_cycles(p: &ProximityProxy<'_>) -> u64 {
    let status = p.get_status().await.expect("GetStatus");
    status
        .get("Cycles")
        .and_then(|v| u64::try_from(v).ok())
        .expect("Cycles")
}

/// Poll `State` until it reads `want` (up to `within`), returning when it did.
async fn wait_state(p: &ProximityProxy<'_>, want: &str, within: Duration) -> Instant {
    let deadline = Instant::now() + within;
    loop {
        let now = Instant::now();
        if p.state().await.expect("State") == want {
            return now;
        }
        assert!(now < deadline, "State never became {want:?}");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

#[test]
fn a_churn_of_claims_settles_within_one_cycle_and_a_real_claim_gets_near() {
    let Some(bus) = PrivateBus::session() else {
        return;
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let cfg = config();
        let cycles = Arc::new(AtomicU64::new(0));
        // a hand at 50 mm all the time: every reading is Near
        let source = Counted {
            inner: ScriptedSource::new(24, 32, vec![Step::target(50.0); 4]),
            cycles: cycles.clone(),
        };
        let ctl = Controller::new(cfg.clone(), source, ModeCalibrations::default()).unwrap();
        let server = connect(&BusChoice::Address(bus.address().into()))
            .await
            .unwrap();
        let daemon = Daemon::start(server, &cfg, ctl).await.expect("daemon");
        let watcher = connect(&BusChoice::Address(bus.address().into()))
            .await
            .unwrap();
        let p = ProximityProxy::builder(&watcher).build().await.unwrap();
        let period = Duration::from_secs_f64(1.0 / RATE_HZ);

        // 0. the loop's own pace with one steady claim (the scripted source's modelled
        //    cycle time is part of each period, so it is measured, not assumed)
        let steady = connect(&BusChoice::Address(bus.address().into()))
            .await
            .unwrap();
        let sp = ProximityProxy::builder(&steady).build().await.unwrap();
        sp.claim_proximity().await.expect("claim");
        let (n0, s0) = (cycles.load(Ordering::SeqCst), Instant::now());
        tokio::time::sleep(Duration::from_secs(1)).await;
        let steady_hz = (cycles.load(Ordering::SeqCst) - n0) as f64 / s0.elapsed().as_secs_f64();
        sp.release_proximity().await.expect("release");
        wait_state(&p, "off", Duration::from_secs(5)).await;
        drop(sp);
        steady.close().await.unwrap();
        let n_before = cycles.load(Ordering::SeqCst);
        let readings_before = loop_cycles(&p).await;

        // 1. the churn alone: the daemon ends off, and stays off
        let t0 = Instant::now();
        churn(bus.address()).await;
        let sent = Instant::now();
        let n_end = cycles.load(Ordering::SeqCst);
        let off_at = wait_state(&p, "off", Duration::from_secs(30)).await;
        let n_off = cycles.load(Ordering::SeqCst);
        assert!(
            n_off - n_end <= 1,
            "{} cycles after the churn ended: at most one",
            n_off - n_end
        );
        // captures (a near onset after each restart may take its confirmation capture, part of
        // the same reading) and the loop's cycles (readings), which the rate bounds
        let churned = n_off - n_before;
        let churn_readings = loop_cycles(&p).await - readings_before;
        eprintln!(
            "churn: {PAIRS} pairs sent in {:?}, off {:?} later, {churned} captures in \
             {churn_readings} cycles meanwhile (steady claim: {steady_hz:.1} captures/s)",
            sent - t0,
            off_at - sent
        );
        tokio::time::sleep(10 * period).await;
        assert_eq!(
            cycles.load(Ordering::SeqCst),
            n_off,
            "no cycle runs without a claim"
        );
        assert!(
            steady_hz > 0.5 * RATE_HZ,
            "the steady claim ran: {steady_hz}"
        );
        // the loop sleeps the period less the reading's modelled time: the scripted source's
        // 1 + 10 ms start-up and flash, 2 × 2.5 ms read-out, 2 × ≤ 0.1 ms exposure — twice for
        // a reading whose near onset (each restart's first reading here) is confirmed by a
        // second-frequency capture. The scripted source spends none of it on the wall clock,
        // so on the wall clock such readings come 17.6 ms apart, in the model's time 50 ms.
        let min_sleep_s = 1.0 / RATE_HZ - 2.0 * 16.2e-3;
        let allowed = ((off_at - t0).as_secs_f64() / min_sleep_s * 1.2).ceil() as u64 + 2;
        assert!(
            churn_readings <= allowed,
            "{churn_readings} cycles in {:?}: never faster than the rate ({allowed})",
            off_at - t0
        );
        let status = p.get_status().await.unwrap();
        let clients = status
            .get("Clients")
            .map(|v| u32::try_from(v).unwrap_or(99));
        assert_eq!(clients, Some(0), "the leaving connection holds no claim");

        // 2. a client claims during a second churn: it gets the right Near, and keeps it
        let claimer = connect(&BusChoice::Address(bus.address().into()))
            .await
            .unwrap();
        let c = ProximityProxy::builder(&claimer).build().await.unwrap();
        let address = bus.address().to_string();
        let second = tokio::spawn(async move { churn(&address).await });
        c.claim_proximity().await.expect("claim");
        assert!(c.near().await.unwrap(), "the hand at 50 mm is near");
        second.await.unwrap();
        tokio::time::sleep(5 * period).await;
        assert_eq!(
            c.state().await.unwrap(),
            "running",
            "the real claim is held"
        );
        assert!(c.near().await.unwrap(), "still near after the churn left");

        // 3. released: off within one cycle
        let before = cycles.load(Ordering::SeqCst);
        c.release_proximity().await.expect("release");
        let released = Instant::now();
        let off_at = wait_state(&c, "off", Duration::from_secs(5)).await;
        let after = cycles.load(Ordering::SeqCst);
        assert!(
            after - before <= 1,
            "{} cycles after the release",
            after - before
        );
        assert!(
            off_at - released <= 2 * period + Duration::from_millis(200),
            "off {:?} after the release",
            off_at - released
        );
        daemon.shutdown().await;
    });
}
