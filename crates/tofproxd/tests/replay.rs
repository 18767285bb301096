//! Replay of a version 1 recording feeds the same loop as live frames and gives
//! exactly the same near/far sequence on every run (in-process and over D-Bus).

use std::collections::BTreeMap;
use std::path::Path;

use tofprox_core::SensorGeometry;
use tofprox_format::{CaptureSpec, RawFrames, RecordingWriter};
use tofproxd::backends::ReplaySource;
use tofproxd::config::{Config, Mode};
use tofproxd::controller::{Controller, ModeCalibrations};
use tofproxd::source::synth_frames;

const ROWS: usize = 24;
const COLS: usize = 32;
const MOD_HZ: f64 = 60e6;

/// A hand approaching to 6 cm and leaving, twice, partly in 4-phase captures.
fn script() -> Vec<(f64, Mode)> {
    let mut v = Vec::new();
    for round in 0..2 {
        for d in [
            900.0, 900.0, 700.0, 450.0, 250.0, 120.0, 60.0, 60.0, 60.0, 90.0, 200.0, 400.0, 700.0,
            900.0, 900.0,
        ] {
            let mode = if round == 1 && d < 100.0 {
                Mode::FourPhase
            } else {
                Mode::TwoPhase
            };
            v.push((d, mode));
        }
    }
    v
}

fn write_recording(dir: &Path) {
    let mut w = RecordingWriter::create(
        dir,
        SensorGeometry::full(ROWS, COLS, 12, MOD_HZ),
        Some("replay test".into()),
    )
    .expect("create recording");
    for (i, (d, mode)) in script().into_iter().enumerate() {
        let (frames, phases) = synth_frames(mode, ROWS, COLS, d, 400.0, 0.0, MOD_HZ);
        let mut conditions = BTreeMap::new();
        conditions.insert("distance_m".to_string(), d / 1e3);
        w.append(
            CaptureSpec {
                phases_deg: phases,
                exposure_us: 100.0,
                illumination: true,
                averaged: 1,
                timestamp_ns: Some(i as u64 * 100_000_000),
                conditions,
            },
            &RawFrames::U16(frames),
        )
        .expect("append");
    }
    w.finish().expect("finish recording");
}

fn run_once(rec: &Path) -> Vec<(bool, Option<u32>)> {
    let cfg = Config::replay_as_fast_as_possible(rec);
    let src = ReplaySource::open(rec, false).expect("open replay");
    let mut ctl = Controller::new(cfg, src, ModeCalibrations::default()).expect("controller");
    let mut seq = Vec::new();
    for _ in 0..1000 {
        let o = ctl.step(false);
        if o.end_of_data {
            break;
        }
        assert!(o.error.is_none(), "{:?}", o.error);
        assert_eq!(o.sleep, std::time::Duration::ZERO, "as fast as possible");
        seq.push((o.near, o.distance_mm));
    }
    seq
}

#[test]
fn replay_is_deterministic_and_follows_the_recording() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    write_recording(&rec);
    let a = run_once(&rec);
    let b = run_once(&rec);
    assert_eq!(a, b, "same near/far sequence on every run");
    assert_eq!(a.len(), script().len());
    // distances follow the recording (ideal frames: within a few mm)
    for ((_, got), (want, _)) in a.iter().zip(script()) {
        let got = got.expect("valid reading") as f64;
        assert!((got - want).abs() < 15.0, "{got} vs {want}");
    }
    // near entered at once at 60 mm, left after the far debounce (3 readings above far_mm)
    let nears: Vec<bool> = a.iter().map(|(n, _)| *n).collect();
    let first_near = nears.iter().position(|&n| n).expect("near seen");
    assert_eq!(
        first_near, 6,
        "near at the first 60 mm reading (near_mm = 100): {nears:?}"
    );
    // far published only after 3 consecutive readings ≥ far_mm (150): 200, 400, 700 → index 12
    let first_far_again = nears[first_near..]
        .iter()
        .position(|&n| !n)
        .map(|i| i + first_near);
    assert_eq!(first_far_again, Some(12), "{nears:?}");
}

/// Over D-Bus: the daemon binary replays the recording; an independent client sees the
/// same sequence of Near changes twice.
#[test]
fn replay_over_dbus_gives_the_same_sequence_every_run() {
    use std::process::{Command, Stdio};
    let Some(_) = tofprox_testkit::require_program("busctl", "systemd") else {
        return;
    };
    let Some(python) = tofprox_testkit::require_python(
        "import dbus; from gi.repository import GLib",
        "python3-dbus python3-gi",
    ) else {
        return;
    };
    let Some(bus) = tofprox_testkit::PrivateBus::session() else {
        return;
    };
    let addr = bus.address().to_string();
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    write_recording(&rec);
    let cfg_path = dir.path().join("replay.toml");
    std::fs::write(
        &cfg_path,
        format!(
            "backend = \"replay\"\n[replay]\nrecording = \"{}\"\nrealtime = false\n[exposure]\nauto = false\n",
            rec.display()
        ),
    )
    .unwrap();
    let client_py = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/dbus/client.py");
    let mut runs = Vec::new();
    for _ in 0..2 {
        let mut d = Command::new(env!("CARGO_BIN_EXE_tofproxd"))
            .arg("--config")
            .arg(&cfg_path)
            .args(["--bus", &addr])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        // wait for the name
        let t0 = std::time::Instant::now();
        loop {
            let out = Command::new("busctl")
                .arg(format!("--address={addr}"))
                .args([
                    "call",
                    "org.freedesktop.DBus",
                    "/org/freedesktop/DBus",
                    "org.freedesktop.DBus",
                ])
                .args(["NameHasOwner", "s", "org.tofprox.Proximity1"])
                .output()
                .unwrap();
            if String::from_utf8_lossy(&out.stdout).trim() == "b true" {
                break;
            }
            assert!(t0.elapsed().as_secs() < 20, "daemon did not start");
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        let out = Command::new(&python)
            .arg(&client_py)
            .args(["native", "--timeout", "3", "--address", &addr])
            .output()
            .unwrap();
        let _ = d.kill();
        let _ = d.wait();
        let seq: Vec<String> = String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .filter(|v| v["event"] == "changed")
            .filter_map(|v| v["props"].get("Near").map(|n| n.to_string()))
            .collect();
        runs.push(seq);
    }
    drop(bus);
    assert!(
        runs[0].iter().any(|n| n == "true"),
        "near seen over D-Bus: {:?}",
        runs[0]
    );
    assert_eq!(runs[0], runs[1], "same Near sequence on every run");
}

/// Replay of an averaged (float) recording processes the recording's own numbers: the depth
/// the daemon publishes equals what `tofprox process` computes from the same file (the core
/// pipeline on the f32 frames) — and differs from what rounding the codes to u16 would give.
#[test]
fn replay_of_an_averaged_recording_keeps_the_floats() {
    use tofprox_core::Algorithm;
    use tofprox_core::pipeline::{Calibration, Pipeline, PipelineConfig};
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("avg");
    let mut w = RecordingWriter::create(&rec, SensorGeometry::full(ROWS, COLS, 12, MOD_HZ), None)
        .expect("create recording");
    // an averaged capture of a weak target: codes with fractions
    let phi = tofprox_core::phasor::distance_to_phase_rad(0.6, MOD_HZ);
    let frames = ndarray::Array3::from_shape_fn((2, ROWS, COLS), |(k, r, c)| {
        let th = if k == 0 {
            0.0
        } else {
            std::f64::consts::FRAC_PI_2
        };
        let a = 11.3 + 0.37 * (r * COLS + c) as f64 / (ROWS * COLS) as f64;
        (2048.0 + a * (phi - th).cos()) as f32
    });
    w.append(
        CaptureSpec {
            phases_deg: vec![0.0, 90.0],
            exposure_us: 100.0,
            illumination: true,
            averaged: 64,
            timestamp_ns: Some(0),
            conditions: BTreeMap::new(),
        },
        &RawFrames::F32(frames.clone()),
    )
    .expect("append");
    w.finish().expect("finish recording");
    let cfg = Config::replay_as_fast_as_possible(&rec);
    let pcfg = PipelineConfig {
        algorithm: Algorithm::TwoPhase,
        modulation_hz: MOD_HZ,
        adc_bits: 12,
        min_amplitude_lsb: cfg.processing.min_amplitude_lsb,
    };
    let src = ReplaySource::open(&rec, false).expect("open replay");
    let mut ctl = Controller::new(cfg, src, ModeCalibrations::default()).expect("controller");
    let out = ctl.step(true);
    assert!(out.error.is_none(), "{:?}", out.error);
    let published: Vec<u16> = out
        .depth
        .expect("depth frame")
        .depth_le
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    let mut p = Pipeline::new(ROWS, COLS, pcfg, Calibration::default()).expect("pipeline");
    let process: Vec<u16> = p
        .process(frames.view())
        .expect("process")
        .depth_mm
        .iter()
        .copied()
        .collect();
    assert_eq!(
        published, process,
        "replay = tofprox process on the same file"
    );
    let rounded = frames.mapv(|v| v.round() as u16);
    let as_u16: Vec<u16> = p
        .process(rounded.view())
        .expect("process")
        .depth_mm
        .iter()
        .copied()
        .collect();
    assert_ne!(
        published, as_u16,
        "rounding to codes would change the depth"
    );
}
