//! `backend = "v4l2"` over the fake V4L2 device (ioctl level, `tofprox-bridge` feature
//! `v4l2-fake`): full cycles through the controller and the daemon on a private bus, and the
//! failures a real driver gives — a device vanishing mid-stream, a wrong format — as clear
//! errors naming the device, never a reading.
//!
//! The scene's physics is written here, independently of the pipeline: a square-wave
//! modulation's **triangular** correlation (the pipeline assumes a sinusoid, so its 4-phase
//! reading wiggles by up to ~21 mm at 80 MHz: `atan2(1/4, 3/4)` against π/8 — a 60 mm hand
//! reads 43 mm) and the
//! return falling as `1/d²` (thesis 2.2.1) with the nominal amplitude scale.

use std::f64::consts::PI;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use ndarray::Array3;
use tofprox_bridge::v4l2::PixelFormat;
use tofprox_bridge::v4l2::fake::{
    FakeControl, FakeDevice, FakeScene, FakeSpec, FakeV4l2, SceneRequest,
};
use tofprox_bridge::{Clock, VirtualClock};
use tofproxd::backends::v4l2::V4l2Source;
use tofproxd::client::ProximityProxy;
use tofproxd::config::{Backend, Config};
use tofproxd::controller::{Controller, ModeCalibrations};
use tofproxd::run::Daemon;
use tofproxd::source::SourceErrorKind;

const ROWS: u32 = 12;
const COLS: u32 = 16;
const C_M_PER_S: f64 = 299_792_458.0;

/// A hand approaching to 6 cm and leaving, in front of a wall at 0.9 m (one entry per cycle).
const SCRIPT_MM: [f64; 15] = [
    900.0, 900.0, 900.0, 700.0, 450.0, 250.0, 160.0, 60.0, 60.0, 60.0, 80.0, 200.0, 400.0, 700.0,
    900.0,
];

/// The correlation of square-wave illumination with a square-wave demodulation: a triangle
/// of period 2π, 1 at 0 and −1 at ±π.
fn triangle(psi: f64) -> f64 {
    let x = psi.rem_euclid(2.0 * PI);
    let x = if x > PI { 2.0 * PI - x } else { x };
    1.0 - 2.0 * x / PI
}

/// What the scene saw, per sequence: (exposure control µs, modulation control MHz).
type Seen = Arc<Mutex<Vec<(i32, i32)>>>;

struct Hand {
    cycle: usize,
    seen: Seen,
}

impl FakeScene for Hand {
    fn images(&mut self, req: &SceneRequest) -> Array3<u16> {
        let exposure_us = req.controls["Exposure"];
        let f_mhz = req.controls["Modulation Frequency"];
        self.seen.lock().unwrap().push((exposure_us, f_mhz));
        if f_mhz == 80 {
            self.cycle += 1; // a second-frequency capture shows the same moment again
        }
        let d_m = SCRIPT_MM[(self.cycle - 1).min(SCRIPT_MM.len() - 1)] / 1e3;
        // round trip 2d at f: phase 2π f 2d / c; amplitude K t / d² (white target), capped
        let phase = 2.0 * PI * f64::from(f_mhz) * 1e6 * 2.0 * d_m / C_M_PER_S;
        let amplitude = (0.09 * f64::from(exposure_us) / (d_m * d_m)).min(1500.0);
        let phases = [0.0, 90.0, 180.0, 270.0f64];
        Array3::from_shape_fn((req.images, req.rows, req.cols), |(k, _, _)| {
            let code = 2048.0 + amplitude * triangle(phase - phases[k].to_radians());
            code.round() as u16
        })
    }
}

fn fake_device(format: PixelFormat, clock: Arc<dyn Clock>, seen: Seen) -> FakeDevice {
    let spec = FakeSpec {
        format,
        cols: COLS,
        rows: ROWS,
        images: 4,
        pad_bytes: 0,
        adc_bits: 12,
        controls: vec![
            FakeControl::integer(0x0098_0911, "Exposure", 10..=2000, 1000),
            FakeControl::integer(0x009a_0990, "Modulation Frequency", 10..=100, 80),
        ],
        frame_time: Duration::from_millis(12),
    };
    FakeDevice::new(spec, Box::new(Hand { cycle: 0, seen }), clock)
}

fn config(format: PixelFormat) -> Config {
    let text = format!(
        "backend = \"v4l2\"\n\
         [loop]\nrate_hz = 50.0\nfast_rate_hz = 50.0\nslow_rate_hz = 50.0\nretry_ms = 10\n\
         first_reading_timeout_ms = 2000\n\
         [ambient]\nenabled = false\n[exposure]\ninitial_us = 80.0\n\
         [v4l2]\ndevice = \"/dev/video-tof\"\npixel_format = \"{format:?}\"\n\
         width = {COLS}\nrows = {ROWS}\nimages = 4\nphases_deg = [0.0, 90.0, 180.0, 270.0]\n\
         modulation_hz = 80e6\nexposure_controls = [\"Exposure\"]\n\
         modulation_control = \"Modulation Frequency\"\nmodulation_hz_per_unit = 1e6\n"
    );
    Config::parse(&text, Path::new("v4l2.toml")).expect("config")
}

fn source(cfg: &Config, dev: &FakeDevice, clock: Arc<dyn Clock>) -> V4l2Source<FakeV4l2> {
    let dev = dev.clone();
    let open = Box::new(move |_: &Path| dev.open());
    V4l2Source::new(cfg.v4l2.clone(), open, clock)
}

#[test]
fn full_cycles_follow_the_scene_through_the_drivers_controls() {
    let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
    let seen = Seen::default();
    let cfg = config(PixelFormat::Y12);
    let dev = fake_device(PixelFormat::Y12, clock.clone(), seen.clone());
    let handle = dev.handle();
    let src = source(&cfg, &dev, clock);
    let mut ctl = Controller::new(cfg.clone(), src, ModeCalibrations::default()).expect("ctl");
    let mut readings = Vec::new();
    for _ in 0..SCRIPT_MM.len() {
        let o = ctl.step(false);
        assert!(o.error.is_none(), "{:?}", o.error);
        assert!(
            o.update.power_mw.is_some_and(|p| p > 0.0),
            "energy accounted"
        );
        // the exposure went through the driver's control (the fake's starts at 1000 µs)
        assert_eq!(o.update.exposure_us, Some(80.0));
        readings.push((o.near, o.distance_mm.expect("a reading")));
    }
    for ((_, got), want) in readings.iter().zip(SCRIPT_MM) {
        let got = f64::from(*got);
        assert!(
            (got - want).abs() < 30.0,
            "read {got} mm of a target at {want} mm"
        );
    }
    let near: Vec<bool> = readings.iter().map(|r| r.0).collect();
    // near at the first reading ≤ near_mm (60 mm, cycle 7), far after 3 readings ≥ far_mm
    // (200, 400, 700 mm: cycle 13)
    let want: Vec<bool> = (0..SCRIPT_MM.len()).map(|i| (7..13).contains(&i)).collect();
    assert_eq!(near, want);
    let seen = seen.lock().unwrap().clone();
    // the dim near candidates were confirmed at the second frequency (70 MHz) through the
    // driver's control; every capture at the exposure the loop asked for (`initial_us`,
    // auto-exposure had no reason to move it: nothing saturated, the wall bright enough)
    assert!(seen.iter().any(|s| s.1 == 70), "{seen:?}");
    assert!(seen.iter().all(|s| s.1 == 70 || s.1 == 80), "{seen:?}");
    assert!(seen.iter().all(|s| s.0 == 80), "{seen:?}");
    // one stream per capture: stream off between cycles
    let n = u32::try_from(seen.len()).unwrap();
    assert_eq!(handle.stream_calls(), (n, n));
}

#[test]
fn a_vanished_device_is_an_error_naming_it_and_reopened_when_back() {
    let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
    let mut cfg = config(PixelFormat::Y12);
    cfg.proximity.second_modulation_hz = 0.0;
    let dev = fake_device(PixelFormat::Y12, clock.clone(), Seen::default());
    let handle = dev.handle();
    let mut ctl = Controller::new(
        cfg.clone(),
        source(&cfg, &dev, clock),
        ModeCalibrations::default(),
    )
    .expect("ctl");
    handle.vanish_after(2);
    for _ in 0..2 {
        assert!(ctl.step(false).error.is_none());
    }
    for call in ["VIDIOC_DQBUF", "open"] {
        // mid-stream, then at the reopen
        let o = ctl.step(false);
        let e = o.error.expect("the vanished device fails the cycle");
        assert_eq!(e.kind(), SourceErrorKind::Disconnected);
        let msg = e.to_string();
        assert!(msg.contains(&format!("/dev/video-tof: {call}")), "{msg}");
        assert!(
            !o.valid && o.distance_mm.is_none(),
            "no reading from a failed cycle"
        );
    }
    handle.replug();
    let o = ctl.step(false);
    assert!(o.error.is_none() && o.valid, "{:?}", o.error);
}

#[test]
fn a_wrong_format_is_an_error_naming_the_device_and_both_formats() {
    let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
    let cfg = config(PixelFormat::Y12);
    // the driver delivers packed RAW12 where the config expects Y12 words
    let dev = fake_device(PixelFormat::Y12P, clock.clone(), Seen::default());
    let mut ctl = Controller::new(
        cfg.clone(),
        source(&cfg, &dev, clock),
        ModeCalibrations::default(),
    )
    .expect("ctl");
    let o = ctl.step(false);
    let e = o.error.expect("refused");
    assert_eq!(e.kind(), SourceErrorKind::Unsupported);
    let msg = e.to_string();
    assert!(msg.contains("/dev/video-tof: asked Y12 16x48"), "{msg}");
    assert!(msg.contains("the driver gives Y12P 16x48"), "{msg}");
    assert!(!o.valid && !o.near);
}

#[test]
fn config_keys_are_checked_and_unknown_ones_refused() {
    let base = "backend = \"v4l2\"\n[v4l2]\n";
    let e = Config::parse(&format!("{base}stacked = 4\n"), Path::new("x.toml")).unwrap_err();
    assert!(e.to_string().contains("unknown field `stacked`"), "{e}");
    let e = Config::parse(&format!("{base}images = 2\n"), Path::new("x.toml")).unwrap_err();
    assert!(
        e.to_string()
            .contains("v4l2.phases_deg: 4 phases from image 0 of 2"),
        "{e}"
    );
    let e = Config::parse(
        &format!("{base}pixel_format = \"YUYV\"\n"),
        Path::new("x.toml"),
    );
    assert!(e.unwrap_err().to_string().contains("pixel_format"));
    let cfg = Config::parse(base, Path::new("x.toml")).expect("defaults");
    assert_eq!(cfg.backend, Backend::V4l2);
    assert_eq!(cfg.v4l2.device, Path::new("/dev/video0"));
}

/// The daemon over the fake on a private bus: a client claims, and sees Near rise and fall
/// with the hand.
#[test]
fn the_daemon_publishes_near_and_far_on_a_private_bus() {
    let Some(bus) = tofprox_testkit::PrivateBus::session() else {
        return;
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
        let cfg = config(PixelFormat::Y12P);
        let dev = fake_device(PixelFormat::Y12P, clock.clone(), Seen::default());
        let ctl = Controller::new(
            cfg.clone(),
            source(&cfg, &dev, clock),
            ModeCalibrations::default(),
        )
        .expect("ctl");
        let connect = || async {
            zbus::connection::Builder::address(bus.address())
                .build()
                .await
                .unwrap()
        };
        let daemon = Daemon::start(connect().await, &cfg, ctl)
            .await
            .expect("daemon");
        let client = connect().await;
        let p = ProximityProxy::builder(&client).build().await.unwrap();
        let mut changes = p.receive_near_changed().await;
        p.claim_proximity().await.unwrap();
        let mut seen = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(10);
        while seen.len() < 3 && Instant::now() < deadline {
            if let Ok(Some(c)) = tokio::time::timeout(
                Duration::from_secs(2),
                tofproxd::service::next_item(&mut changes),
            )
            .await
            {
                seen.push(c.get().await.unwrap());
            }
        }
        assert_eq!(seen, vec![false, true, false], "initial, near, far");
        assert!(
            p.get_status().await.unwrap()["Backend"]
                .to_string()
                .contains("/dev/video-tof")
        );
        p.release_proximity().await.unwrap();
        daemon.shutdown().await;
    });
}
