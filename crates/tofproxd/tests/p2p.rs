//! Service logic over an in-memory socket pair (zbus p2p, no bus daemon): the real
//! `Daemon` (loop thread, publisher, interface) driven by a scripted source.

use std::os::unix::net::UnixStream;
use std::time::{Duration, Instant};

use tofproxd::client::ProximityProxy;
use tofproxd::config::Config;
use tofproxd::controller::{Controller, ModeCalibrations};
use tofproxd::input::{InputEvent, RecordingDevice, SwitchDevice};
use tofproxd::run::Daemon;
use tofproxd::service::next_item;
use tofproxd::source::{ScriptedSource, SourceErrorKind, Step};

fn fast_config() -> Config {
    let mut cfg = Config::default();
    cfg.loop_.rate_hz = 50.0;
    cfg.loop_.fast_rate_hz = 50.0;
    cfg.loop_.slow_rate_hz = 50.0;
    cfg.loop_.retry_ms = 10;
    cfg.loop_.first_reading_timeout_ms = 300;
    cfg.ambient.enabled = false;
    cfg
}

async fn pair(cfg: &Config, steps: Vec<Step>) -> (Daemon, zbus::Connection) {
    pair_with_input(cfg, steps, None).await
}

/// A daemon with the input publisher's device given (`None`: D-Bus only) and its client.
async fn pair_with_input(
    cfg: &Config,
    steps: Vec<Step>,
    input: Option<Box<dyn SwitchDevice>>,
) -> (Daemon, zbus::Connection) {
    let (a, b) = UnixStream::pair().expect("socketpair");
    let guid = zbus::Guid::generate();
    let server = zbus::connection::Builder::unix_stream(a)
        .server(guid)
        .p2p()
        .build();
    let client = zbus::connection::Builder::unix_stream(b).p2p().build();
    let (server, client) = tokio::join!(server, client);
    let ctl = Controller::new(
        cfg.clone(),
        ScriptedSource::new(24, 32, steps),
        ModeCalibrations::default(),
    )
    .expect("controller");
    let daemon = Daemon::start_with_input(server.expect("server"), cfg, ctl, input)
        .await
        .expect("daemon");
    (daemon, client.expect("client"))
}

fn rt() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

#[test]
fn claim_waits_for_a_reading_then_near_and_far_change_once_each() {
    rt().block_on(async {
        let mut steps = vec![Step::target(800.0); 3];
        steps.extend(vec![Step::target(50.0); 3]);
        steps.extend(vec![Step::target(800.0); 200]);
        let (daemon, client) = pair(&fast_config(), steps).await;
        let p = ProximityProxy::builder(&client).build().await.unwrap();
        assert_eq!(p.state().await.unwrap(), "off", "no claim: sensor off");
        let mut changes = p.receive_near_changed().await;
        p.claim_proximity().await.unwrap();
        assert_eq!(
            p.state().await.unwrap(),
            "running",
            "claim returns after the first valid reading"
        );
        let mut seen = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(5);
        while seen.len() < 3 && Instant::now() < deadline {
            if let Ok(Some(c)) =
                tokio::time::timeout(Duration::from_secs(2), next_item(&mut changes)).await
            {
                seen.push(c.get().await.unwrap());
            }
        }
        // initial value, then near, then far
        assert_eq!(seen, vec![false, true, false]);
        let s = p.get_status().await.unwrap();
        assert_eq!(u32::try_from(&s["ProximityClaims"]).unwrap(), 1);
        let energy_mj = |s: &std::collections::HashMap<String, zbus::zvariant::OwnedVariant>| {
            f64::try_from(&s[tofproxd::service::ENERGY_MJ_KEY]).unwrap()
        };
        let running_mj = energy_mj(&s);
        assert!(
            running_mj > 0.0,
            "the cycles so far cost energy: {running_mj}"
        );
        p.release_proximity().await.unwrap();
        let t0 = Instant::now();
        while p.state().await.unwrap() != "off" {
            assert!(
                t0.elapsed() < Duration::from_secs(2),
                "release stops the loop"
            );
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        // stopped: the total stands (no cycle, no energy)
        tokio::time::sleep(Duration::from_millis(100)).await;
        let stopped_mj = energy_mj(&p.get_status().await.unwrap());
        assert!(stopped_mj >= running_mj);
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert_eq!(energy_mj(&p.get_status().await.unwrap()), stopped_mj);
        daemon.shutdown().await;
    });
}

#[test]
fn claim_wait_is_bounded_and_failures_show_in_state() {
    rt().block_on(async {
        let (daemon, client) =
            pair(&fast_config(), vec![Step::Fail(SourceErrorKind::Timeout)]).await;
        let p = ProximityProxy::builder(&client).build().await.unwrap();
        let t0 = Instant::now();
        p.claim_proximity().await.unwrap();
        let waited = t0.elapsed();
        assert!(
            waited >= Duration::from_millis(250) && waited < Duration::from_secs(2),
            "{waited:?}"
        );
        let state = p.state().await.unwrap();
        assert!(state == "error" || state == "unavailable", "{state}");
        assert!(p.last_error().await.unwrap().contains("timeout"));
        assert!(!p.near().await.unwrap());
        daemon.shutdown().await;
    });
}

/// The input publisher: with no claim held the loop runs, and each Near change reaches the
/// device as exactly EV_SW SW_FRONT_PROXIMITY (1 near, 0 far) then EV_SYN SYN_REPORT — the
/// numbers of linux/input-event-codes.h written out here — and nothing else.
#[test]
fn input_publisher_writes_each_near_change_as_a_switch_report_without_a_claim() {
    rt().block_on(async {
        let mut steps = vec![Step::target(800.0); 3];
        steps.extend(vec![Step::target(50.0); 3]);
        steps.extend(vec![Step::target(800.0); 200]);
        let seen = RecordingDevice::default();
        let device = Box::new(seen.clone());
        let (daemon, client) = pair_with_input(&fast_config(), steps, Some(device)).await;
        let p = ProximityProxy::builder(&client).build().await.unwrap();
        let t0 = Instant::now();
        while seen.events().len() < 4 {
            assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", seen.events());
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        let ev = |kind, code, value| InputEvent { kind, code, value };
        let syn = ev(0, 0, 0);
        assert_eq!(seen.events(), vec![ev(5, 11, 1), syn, ev(5, 11, 0), syn]);
        assert_eq!(
            p.state().await.unwrap(),
            "running",
            "no claim, loop running"
        );
        let s = p.get_status().await.unwrap();
        assert_eq!(u32::try_from(&s["ProximityClaims"]).unwrap(), 0);
        assert!(
            p.near_changed_ns().await.unwrap() > 0,
            "the far change is stamped"
        );
        daemon.shutdown().await;
    });
}
