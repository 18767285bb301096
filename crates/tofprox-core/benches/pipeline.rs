//! Speed of the per-frame pipeline on a full IRS1645 frame (224 × 172), one core.
//!
//! Targets: the full 2-phase pipeline (offset correction, phase, wiggling correction, amplitude,
//! validity, depth mm) ≤ 50 µs and ≥ 40× numpy on an AVX2 machine (`benches/compare.sh`);
//! the near/far update ≤ 10 µs.
//!
//! Run: `cargo bench -p tofprox-core --bench pipeline`

use divan::Bencher;
use ndarray::{Array1, Array2, Array3};
use tofprox_core::calib::{FppnMap, OffsetCalibration, WigglingLut};
use tofprox_core::pipeline::{Calibration, Pipeline, PipelineConfig};
use tofprox_core::proximity::{NearFarConfig, NearFarDetector};
use tofprox_core::{Algorithm, SimdLevel};

const ROWS: usize = 172;
const COLS: usize = 224;

fn main() {
    divan::main();
}

/// Deterministic full frame: per-pixel FPN, phases over the whole circle, a few saturated pixels.
fn raw_frame(k: usize) -> Array3<u16> {
    Array3::from_shape_fn((k, ROWS, COLS), |(i, r, c)| {
        let fpn = ((r * 7919 + c * 104_729) % 97) as f64 - 48.0;
        let phi = (r * COLS + c) as f64 * 0.000_37;
        let amp = 200.0 + ((r + c) % 50) as f64 * 20.0;
        let v = 2048.0 + fpn + amp * (phi - i as f64 * std::f64::consts::FRAC_PI_2).cos();
        if (r * COLS + c).is_multiple_of(1009) {
            4095
        } else {
            v.round().clamp(0.0, 4095.0) as u16
        }
    })
}

fn pipeline(algorithm: Algorithm, with_fppn: bool) -> Pipeline {
    let calibration = Calibration {
        crosstalk: None,
        offset: Some(OffsetCalibration {
            dark_lsb: Array2::from_shape_fn((ROWS, COLS), |(r, c)| {
                2048.0 + ((r * 7919 + c * 104_729) % 97) as f32 - 48.0
            }),
        }),
        wiggling: Some(WigglingLut {
            algorithm,
            correction_rad: Array1::from_shape_fn(360, |i| {
                0.35 + 0.03 * (3.0 * i as f32 * std::f32::consts::TAU / 360.0).sin()
            }),
        }),
        fppn: with_fppn.then(|| FppnMap {
            phase_offset_rad: Array2::from_shape_fn((ROWS, COLS), |(r, c)| {
                0.001 * ((r + 3 * c) % 11) as f32
            }),
        }),
    };
    let config = PipelineConfig {
        algorithm,
        ..PipelineConfig::default()
    };
    Pipeline::new(ROWS, COLS, config, calibration).expect("pipeline")
}

/// The target: full 2-phase pipeline, u16 raw codes, offset + wiggling.
#[divan::bench]
fn process_2phase_u16(bencher: Bencher) {
    let raw = raw_frame(2);
    let mut p = pipeline(Algorithm::TwoPhase, false);
    bencher.bench_local(|| {
        let f = p.process(divan::black_box(raw.view())).expect("process");
        divan::black_box(f.depth_mm[(86, 112)]);
    });
}

/// The 2-phase pipeline on every kernel level this CPU supports (generic, avx2, avx512 / neon):
/// what `benches/compare.sh` sets beside numpy.
#[divan::bench(args = SimdLevel::supported().collect::<Vec<_>>())]
fn process_2phase_u16_level(bencher: Bencher, level: SimdLevel) {
    let raw = raw_frame(2);
    let mut p = pipeline(Algorithm::TwoPhase, false);
    p.set_simd_level(level).expect("a supported level");
    bencher.bench_local(|| {
        let f = p.process(divan::black_box(raw.view())).expect("process");
        divan::black_box(f.depth_mm[(86, 112)]);
    });
}

/// Same plus the FPPN map.
#[divan::bench]
fn process_2phase_u16_fppn(bencher: Bencher) {
    let raw = raw_frame(2);
    let mut p = pipeline(Algorithm::TwoPhase, true);
    bencher.bench_local(|| {
        let f = p.process(divan::black_box(raw.view())).expect("process");
        divan::black_box(f.depth_mm[(86, 112)]);
    });
}

/// 4-phase, u16.
#[divan::bench]
fn process_4phase_u16(bencher: Bencher) {
    let raw = raw_frame(4);
    let mut p = pipeline(Algorithm::FourPhase, false);
    bencher.bench_local(|| {
        let f = p.process(divan::black_box(raw.view())).expect("process");
        divan::black_box(f.depth_mm[(86, 112)]);
    });
}

/// 2-phase from averaged f64 codes.
#[divan::bench]
fn process_2phase_f64(bencher: Bencher) {
    let raw = raw_frame(2).mapv(|v| v as f64);
    let mut p = pipeline(Algorithm::TwoPhase, false);
    bencher.bench_local(|| {
        let f = p.process(divan::black_box(raw.view())).expect("process");
        divan::black_box(f.depth_mm[(86, 112)]);
    });
}

/// Near/far detector update on the default ROI (central half: 86 × 112 pixels).
#[divan::bench]
fn near_far_update(bencher: Bencher) {
    let raw = raw_frame(2);
    let mut p = pipeline(Algorithm::TwoPhase, false);
    let frame = p.process(raw.view()).expect("process").clone();
    let mut d = NearFarDetector::new(NearFarConfig::default()).expect("detector");
    bencher.bench_local(|| divan::black_box(d.update(divan::black_box(&frame))));
}

/// Per-pixel cost versus frame size (the recording windows are small; the full frame is the
/// target): `rows` of the full 224-column width.
#[divan::bench(args = [8, 43, 172])]
fn process_2phase_u16_rows(bencher: Bencher, rows: usize) {
    let full = raw_frame(2);
    let raw = full.slice(ndarray::s![.., ..rows, ..]).to_owned();
    let config = PipelineConfig::default();
    let calibration = Calibration {
        crosstalk: None,
        offset: Some(OffsetCalibration {
            dark_lsb: Array2::from_elem((rows, COLS), 2048.0),
        }),
        wiggling: Some(WigglingLut {
            algorithm: Algorithm::TwoPhase,
            correction_rad: Array1::from_elem(360, 0.35),
        }),
        fppn: None,
    };
    let mut p = Pipeline::new(rows, COLS, config, calibration).expect("pipeline");
    bencher
        .counter(divan::counter::ItemsCount::new(rows * COLS))
        .bench_local(|| {
            let f = p.process(divan::black_box(raw.view())).expect("process");
            divan::black_box(f.depth_mm[(0, 0)]);
        });
}
