//! Speed of the daemon (targets of docs/daemon.md):
//! - CPU per cycle ≤ 2 ms (2-phase, full 224×172 frame), excluding sleeps:
//!   `controller_cycle_2phase_full_frame` (the daemon's own work: checks, processing,
//!   detector, decisions, energy) and `emulated_stack_cycle_2phase_full_frame` (the same
//!   plus the bridge driver and the emulated device on a virtual clock).
//! - frame complete → PropertiesChanged on the bus < 2 ms: `frame_to_properties_changed`
//!   (publisher event → signal received by a second connection through a real
//!   dbus-daemon; skipped if dbus-daemon is absent).
//!
//! Run: `cargo bench -p tofproxd --bench daemon`
//! RSS and timer wake-ups are measured on the running binary: `benches/wakeups.sh`.

use std::sync::Arc;

use divan::Bencher;
use tofproxd::config::{Config, Mode};
use tofproxd::controller::{Controller, ModeCalibrations};
use tofproxd::energy::CycleTimings;
use tofproxd::source::{CycleRequest, FrameSource, RawCycle, RawImages, SourceError, synth_frames};

const ROWS: usize = 172;
const COLS: usize = 224;

fn main() {
    divan::main();
}

/// Hands out a prebuilt full frame (the bridge's cost is benchmarked by the bridge).
struct FixedSource {
    cycle: RawCycle,
}

impl FrameSource for FixedSource {
    fn cycle(&mut self, _req: &CycleRequest) -> Result<RawCycle, SourceError> {
        Ok(self.cycle.clone())
    }
    fn power_off(&mut self) -> Result<(), SourceError> {
        Ok(())
    }
    fn supports_row_window(&self) -> bool {
        false
    }
    fn sensor(&self) -> tofprox_core::SensorGeometry {
        self.cycle.geometry.full_array()
    }
    fn describe(&self) -> String {
        "fixed".into()
    }
}

fn full_frame_config() -> Config {
    let mut cfg = Config::default();
    cfg.readout.partial = false;
    cfg.ambient.probe_every = 1_000_000;
    cfg
}

#[divan::bench]
fn controller_cycle_2phase_full_frame(b: Bencher) {
    let (frames, phases_deg) = synth_frames(Mode::TwoPhase, ROWS, COLS, 600.0, 300.0, 0.0, 80e6);
    let cycle = RawCycle {
        frames: RawImages::U16(frames),
        phases_deg,
        exposure_us: 100.0,
        geometry: tofprox_core::SensorGeometry::full(ROWS, COLS, 12, 80e6),
        timings: Some(CycleTimings::default()),
    };
    let mut ctl = Controller::new(
        full_frame_config(),
        FixedSource { cycle },
        ModeCalibrations::default(),
    )
    .expect("controller");
    ctl.step(false);
    b.bench_local(|| divan::black_box(ctl.step(false).valid));
}

#[divan::bench]
fn emulated_stack_cycle_2phase_full_frame(b: Bencher) {
    use tofprox_bridge::emulated::FrameSource as Synth;
    use tofprox_bridge::{Clock, EmulatedConfig, VirtualClock};
    let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
    let dev_cfg = EmulatedConfig {
        frame_source: Synth::Ideal,
        ..EmulatedConfig::default()
    };
    let src =
        tofproxd::backends::emulated::bridge_source(dev_cfg, clock, 1, "bench").expect("stack");
    let mut ctl =
        Controller::new(full_frame_config(), src, ModeCalibrations::default()).expect("controller");
    ctl.step(false);
    b.bench_local(|| divan::black_box(ctl.step(false).valid));
}

#[divan::bench(sample_count = 200)]
fn frame_to_properties_changed(b: Bencher) {
    use std::io::BufRead;
    use tofproxd::hub::{Event, Hub, StatusUpdate};
    use tofproxd::service::{OBJECT_PATH, Proximity, next_item};
    let Ok(mut bus) = std::process::Command::new("dbus-daemon")
        .args(["--session", "--print-address", "--nofork"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
    else {
        eprintln!("dbus-daemon not installed: frame_to_properties_changed skipped");
        return;
    };
    let mut addr = String::new();
    std::io::BufReader::new(bus.stdout.take().expect("stdout"))
        .read_line(&mut addr)
        .expect("address");
    let addr = addr.trim().to_string();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("rt");
    let cfg = Config::default();
    let (tx, mut rx, _keep) = rt.block_on(async {
        let server = zbus::connection::Builder::address(addr.as_str())
            .build()
            .await
            .expect("server");
        let (hub, demand) = Hub::new(&cfg, "bench".into());
        server
            .object_server()
            .at(OBJECT_PATH, Proximity::new(hub.clone()))
            .await
            .expect("serve");
        server
            .request_name("org.tofprox.Proximity1")
            .await
            .expect("name");
        let (tx, erx) = tokio::sync::mpsc::channel(tofproxd::hub::EVENT_CAPACITY);
        let dbus =
            tofproxd::publisher::dbus::DbusPublisher::new(server.clone(), hub.clone(), false);
        tokio::spawn(tofproxd::publisher::run_publishers(
            hub.clone(),
            erx,
            vec![Box::new(dbus)],
            5.0,
        ));
        let client = zbus::connection::Builder::address(addr.as_str())
            .build()
            .await
            .expect("client");
        let proxy = zbus::fdo::PropertiesProxy::builder(&client)
            .destination("org.tofprox.Proximity1")
            .path(OBJECT_PATH)
            .build()
            .await
            .expect("proxy");
        let rx = proxy.receive_properties_changed().await.expect("match");
        (tx, rx, (server, client, proxy, hub, demand))
    });
    let mut near = false;
    b.bench_local(|| {
        near = !near;
        rt.block_on(async {
            tx.send(Event::Status(StatusUpdate {
                near: Some(near),
                valid_reading: true,
                ..StatusUpdate::default()
            }))
            .await
            .expect("send");
            next_item(&mut rx).await.expect("signal");
        })
    });
    let _ = bus.kill();
    let _ = bus.wait();
}
