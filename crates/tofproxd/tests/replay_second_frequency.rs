//! Issue 21 item 2: a recording (format version 3) whose captures carry the images the device
//! took in the same cycle at a second modulation frequency, replayed through the daemon loop.
//! The frames are made here with physics independent of the project's model and pipeline: a
//! square-wave emitter correlated with a square-wave demodulation gives a *triangular*
//! correlation (not the pipeline's cosine), the return falls as `ρ·t/d²` with this test's own
//! constant, and the read noise is a fixed pseudo-random ±2 LSB.
//!
//! A retroreflector (1000× a white wall) over a third of the ROI just beyond the unambiguous
//! range (1.874 m at 80 MHz) wraps to a few centimetres as bright as a hand: the second
//! frequency shows it is far (0 false near). A hand at 5 cm with second-frequency images still
//! reads Near; the same retroreflector without second-frequency images (a version 2 file)
//! reads Near — the amplitude test alone cannot tell.

use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::Path;

use ndarray::Array3;
use tofprox_core::SensorGeometry;
use tofprox_format::{CaptureSpec, RawFrames, RecordingWriter, SecondFrequencyFrames};
use tofproxd::backends::ReplaySource;
use tofproxd::config::Config;
use tofproxd::controller::{Controller, ModeCalibrations};

const ROWS: usize = 24;
const COLS: usize = 32;
const F1_HZ: f64 = 80e6;
const F2_HZ: f64 = 70e6;
const C_M_PER_S: f64 = 299_792_458.0;
const EXPOSURE_US: f64 = 20.0;
/// Peak of the triangular correlation per `ρ·t/d²` (LSB·m²/µs) — this test's own sensor.
const PEAK_LSB_M2_PER_US: f64 = 0.12;

/// Triangle wave of period 2π, 1 at 0, −1 at π: the correlation of two square waves.
fn triangle(x: f64) -> f64 {
    let u = x.rem_euclid(2.0 * PI) / PI; // 0..2
    if u <= 1.0 {
        1.0 - 2.0 * u
    } else {
        2.0 * u - 3.0
    }
}

/// Raw codes `(2, rows, cols)` at shifts 0°, 90° of a scene given per pixel as
/// (distance m, reflectivity), modulated at `f_hz`.
fn frames(scene: impl Fn(usize, usize) -> (f64, f64), f_hz: f64, seed: &mut u64) -> Array3<u16> {
    let mut a = Array3::<u16>::zeros((2, ROWS, COLS));
    for ((k, r, c), v) in a.indexed_iter_mut() {
        let (d, rho) = scene(r, c);
        let delay_rad = 2.0 * PI * f_hz * (2.0 * d / C_M_PER_S);
        let peak = PEAK_LSB_M2_PER_US * rho * EXPOSURE_US / (d * d);
        let theta = PI / 2.0 * k as f64;
        *seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        let noise = ((*seed >> 33) % 5) as f64 - 2.0;
        let code = 2048.0 + peak * triangle(delay_rad - theta) + noise;
        *v = code.round().clamp(0.0, 4095.0) as u16;
    }
    a
}

/// A third of the daemon's ROI (the central half: rows 6..18, cols 8..24) — its left third,
/// cols 8..13 — is a target at `target_m` of `rho`; everything else a dark wall at 6 m.
fn band(target_m: f64, rho: f64) -> impl Fn(usize, usize) -> (f64, f64) {
    move |_r, c| {
        if (8..13).contains(&c) {
            (target_m, rho)
        } else {
            (6.0, 0.08)
        }
    }
}

/// A hand over the whole ROI at `distance_m`, the dark wall around it.
fn hand(distance_m: f64) -> impl Fn(usize, usize) -> (f64, f64) {
    move |r, c| {
        if (4..20).contains(&r) && (6..26).contains(&c) {
            (distance_m, 0.5)
        } else {
            (6.0, 0.08)
        }
    }
}

fn write(dir: &Path, scene: impl Fn(usize, usize) -> (f64, f64), second: bool, n: usize) {
    let mut w = RecordingWriter::create(
        dir,
        SensorGeometry::full(ROWS, COLS, 12, F1_HZ),
        Some("independent square-wave ToF".into()),
    )
    .expect("create");
    let mut seed = 7u64;
    for i in 0..n {
        let f1 = frames(&scene, F1_HZ, &mut seed);
        let f2 = SecondFrequencyFrames {
            modulation_hz: F2_HZ,
            phases_deg: vec![0.0, 90.0],
            frames: RawFrames::U16(frames(&scene, F2_HZ, &mut seed)),
        };
        let spec = CaptureSpec {
            phases_deg: vec![0.0, 90.0],
            exposure_us: EXPOSURE_US,
            illumination: true,
            averaged: 1,
            timestamp_ns: Some(i as u64 * 100_000_000),
            conditions: BTreeMap::new(),
        };
        w.append_with_second(spec, &RawFrames::U16(f1), second.then_some(&f2))
            .expect("append");
    }
    w.finish().expect("finish");
}

/// Near of every reading of the replay.
fn replay(rec: &Path) -> Vec<bool> {
    let cfg = Config::replay_as_fast_as_possible(rec);
    let src = ReplaySource::open(rec, false).expect("open replay");
    let mut ctl = Controller::new(cfg, src, ModeCalibrations::default()).expect("controller");
    let mut near = Vec::new();
    loop {
        let o = ctl.step(false);
        if o.end_of_data {
            break;
        }
        assert!(o.error.is_none() && o.valid, "{o:?}");
        near.push(o.near);
    }
    near
}

#[test]
fn a_retroreflector_beyond_the_range_reads_far_a_near_hand_near() {
    let dir = tempfile::tempdir().unwrap();
    for d in [1.90, 1.95] {
        let rec = dir.path().join(format!("retro{d}"));
        write(&rec, band(d, 1000.0 * 0.9), true, 6);
        let near = replay(&rec);
        assert_eq!(near.len(), 6);
        assert!(near.iter().all(|n| !n), "{d} m: 0 false near, got {near:?}");
    }
    let rec = dir.path().join("hand");
    write(&rec, hand(0.05), true, 4);
    assert_eq!(replay(&rec), [true; 4], "a hand at 5 cm is confirmed");

    // without second-frequency images: one frequency, the amplitude test alone — near
    let rec = dir.path().join("retro-one-frequency");
    write(&rec, band(1.92, 1000.0 * 0.9), false, 3);
    assert!(replay(&rec).iter().all(|&n| n), "one frequency cannot tell");
}

#[test]
fn the_second_frequency_images_are_in_the_documented_file() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    write(&rec, hand(0.05), true, 1);
    let text = std::fs::read_to_string(rec.join("recording.toml")).unwrap();
    assert!(text.contains("version = 3"), "{text}");
    assert!(text.contains("[capture.second_frequency]"), "{text}");
    let r = tofprox_format::Recording::open(&rec).expect("reads back");
    let s = r.captures()[0].second_frequency.as_ref().expect("second");
    assert_eq!(
        (s.modulation_hz, s.phases_deg.as_slice()),
        (F2_HZ, &[0.0, 90.0][..])
    );
    let f2 = r.load_second_frequency(0).unwrap().expect("images");
    assert_eq!(f2.dim(), (2, ROWS, COLS));

    // strict: an unknown key below it, a version 2 file with it, and the sensor's own
    // frequency are refused with the key named
    let edit = |from: &str, to: &str| {
        let bad = dir.path().join(format!("bad{}", to.len()));
        std::fs::create_dir_all(bad.join("frames")).unwrap();
        for f in std::fs::read_dir(rec.join("frames")).unwrap() {
            let f = f.unwrap().path();
            std::fs::copy(&f, bad.join("frames").join(f.file_name().unwrap())).unwrap();
        }
        std::fs::write(bad.join("recording.toml"), text.replacen(from, to, 1)).unwrap();
        tofprox_format::Recording::open(&bad)
            .unwrap_err()
            .to_string()
    };
    let e = edit(
        "modulation_hz = 70000000.0",
        "modulation_hz = 70000000.0\nextra = 1",
    );
    assert!(
        e.contains("capture[0].second_frequency") || e.contains("extra"),
        "{e}"
    );
    let e = edit("version = 3", "version = 2");
    assert!(
        e.contains("capture[0].second_frequency") && e.contains("version 3"),
        "{e}"
    );
    let e = edit("modulation_hz = 70000000.0", "modulation_hz = 80000000.0");
    assert!(
        e.contains("capture[0].second_frequency.modulation_hz"),
        "{e}"
    );
}
