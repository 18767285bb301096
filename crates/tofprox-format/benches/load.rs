//! How fast recordings are read (the daemon's replay source and `tofprox
//! process` read one capture per frame): full-array 4-phase captures,
//! 224×172, uint16 and float32.
//!
//! `cargo bench -p tofprox-format --bench load`

use std::collections::BTreeMap;

use divan::Bencher;
use ndarray::Array3;
use tofprox_core::SensorGeometry;
use tofprox_format::{CaptureSpec, RawFrames, Recording, RecordingWriter, npy};

fn main() {
    divan::main();
}

fn frames_u16() -> Array3<u16> {
    Array3::from_shape_fn((4, 172, 224), |(k, r, c)| {
        (2048 + (k * 7 + r * 3 + c) % 1500) as u16
    })
}

fn spec() -> CaptureSpec {
    CaptureSpec {
        phases_deg: vec![0.0, 90.0, 180.0, 270.0],
        exposure_us: 500.0,
        illumination: true,
        averaged: 1,
        timestamp_ns: None,
        conditions: BTreeMap::new(),
    }
}

/// Decode one full-array 4-phase uint16 capture from memory (header parse + copy).
#[divan::bench]
fn decode_u16_full_frame(b: Bencher) {
    let bytes = npy::encode_u16(&frames_u16());
    b.bench(|| npy::decode(divan::black_box(&bytes)));
}

/// `Recording::load` of one capture from disk (page cache): read, decode, validate values.
#[divan::bench(args = ["u16", "f32"])]
fn load_full_frame(b: Bencher, dtype: &str) {
    let t = tempfile::tempdir().expect("tempdir");
    let mut w = RecordingWriter::create(t.path(), SensorGeometry::full(172, 224, 12, 80e6), None)
        .expect("create");
    let f = match dtype {
        "u16" => RawFrames::U16(frames_u16()),
        _ => RawFrames::F32(frames_u16().mapv(f32::from)),
    };
    w.append(spec(), &f).expect("append");
    w.finish().expect("finish");
    let rec = Recording::open(t.path()).expect("open");
    b.bench(|| rec.load(divan::black_box(0)));
}

/// Crash-safe append of one full-array uint16 capture (two fsyncs + renames).
#[divan::bench(sample_count = 20)]
fn append_full_frame_u16(b: Bencher) {
    let t = tempfile::tempdir().expect("tempdir");
    let mut w = RecordingWriter::create(t.path(), SensorGeometry::full(172, 224, 12, 80e6), None)
        .expect("create");
    let f = RawFrames::U16(frames_u16());
    b.bench_local(|| w.append(spec(), &f));
}
