//! Guards the shipped factory calibration of the emulated sensor
//! (`calib/emulated/`) against drift: it was captured from the emulated device
//! (model + seed of `config/tofproxd-emulated.toml`). When the model's
//! defaults, the model file or the seed change, the emulated sensor is another
//! sensor and these checks fail with how to regenerate the set.
//!
//! The checks use the model's noise-free expected codes (no device, fast):
//! the dark frame must match the calibration's offset (FPN), and a wall at a
//! distance other than the calibration's 1 m must read right with the set
//! (wiggling incl. global delay, FPPN) in 2- and 4-phase.

use std::path::{Path, PathBuf};

use ndarray::{Array2, s};
use tofprox_bridge::EmulatedConfig as DeviceConfig;
use tofprox_core::Algorithm;
use tofprox_core::pipeline::{Pipeline, PipelineConfig};
use tofprox_format::CalibrationSet;
use tofprox_model::{CaptureRequest, ModelConfig, Scene, SensorGeometry, Simulator};
use tofproxd::backends::emulated::device_config;
use tofproxd::config::Config;

const REGENERATE: &str = "calib/emulated/ no longer matches the emulated sensor of \
config/tofproxd-emulated.toml (model defaults, model file or [emulated] seed changed). \
Regenerate it from the repository root with `calib/emulated/make.sh` (SEED=<seed> if the \
seed changed; see calib/emulated/README.md), then run `cargo test -p tofproxd --test \
emulated_calibration --test emulated_model` and commit calib/emulated/";

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn model_of(dev: &DeviceConfig) -> ModelConfig {
    match &dev.model {
        Some(p) => ModelConfig::load(p).expect("model file of the emulated device"),
        None => ModelConfig::baseline(),
    }
}

/// The daemon's emulated sensor: model, geometry, seed.
fn daemon_sensor() -> (ModelConfig, SensorGeometry, u64) {
    let path = repo().join("config/tofproxd-emulated.toml");
    let cfg = Config::load(&path).expect("config/tofproxd-emulated.toml");
    let base = path.parent().expect("config dir");
    let dev = device_config(&cfg, base).expect("emulated device config");
    let s = dev.sensor_map().expect("sensor map").sensor;
    (model_of(&dev), s.geometry(), cfg.emulated.seed)
}

fn shipped() -> CalibrationSet {
    CalibrationSet::load(&repo().join("calib/emulated"))
        .unwrap_or_else(|e| panic!("loading calib/emulated: {e}\n{REGENERATE}"))
}

#[test]
fn calibration_device_is_the_daemons_sensor() {
    // make.sh captures with calib/emulated/wall-1m.toml: it must describe the same
    // sensor (model and register map) as the daemon's emulated device.
    let (model, geom, _) = daemon_sensor();
    let cal_dev = DeviceConfig::load(&repo().join("calib/emulated/wall-1m.toml"))
        .expect("calib/emulated/wall-1m.toml");
    assert_eq!(
        model_of(&cal_dev).to_toml_string(),
        model.to_toml_string(),
        "calib/emulated/wall-1m.toml and config/tofproxd-emulated.toml use different models"
    );
    let s = cal_dev.sensor_map().expect("sensor map").sensor;
    assert_eq!(
        s.geometry(),
        geom,
        "calib/emulated/wall-1m.toml and config/tofproxd-emulated.toml use different sensors"
    );
}

#[test]
fn shipped_offset_matches_the_emulated_dark_frame() {
    let (model, geom, seed) = daemon_sensor();
    let set = shipped();
    set.check_compatible(&geom)
        .unwrap_or_else(|e| panic!("{e}\n{REGENERATE}"));
    let offset = set
        .offset()
        .unwrap_or_else(|| panic!("calib/emulated has no offset\n{REGENERATE}"));
    let sim = Simulator::new(&model, geom, seed).expect("simulator");
    let dark = sim
        .expected(
            &Scene::wall(1.0, 0.6),
            &CaptureRequest {
                phases_deg: vec![0.0],
                exposure_us: 250.0,
                illumination: false,
                averaged: 1,
                ambient_klux: 0.0,
                temperature_c: 25.0,
                conditions: Default::default(),
            },
        )
        .expect("expected dark frame");
    let dark = dark.slice(s![0, .., ..]);
    assert_eq!(dark.dim(), offset.dark_lsb.dim(), "{REGENERATE}");
    let mut diff: Vec<f64> = dark
        .iter()
        .zip(offset.dark_lsb.iter())
        .map(|(e, o)| (e - f64::from(*o)).abs())
        .collect();
    diff.sort_by(f64::total_cmp);
    let median = diff[diff.len() / 2];
    let p99 = diff[diff.len() * 99 / 100];
    // 16 averaged dark frames: ~0.3 LSB noise + quantisation; the FPN itself is ~35 LSB σ.
    assert!(
        median < 0.6 && p99 < 2.0,
        "offset differs from the emulated sensor's dark frame: median |Δ| {median:.2} LSB, \
         99th percentile {p99:.2} LSB\n{REGENERATE}"
    );
}

fn median_depth_m(
    set: &CalibrationSet,
    algorithm: Algorithm,
    raw: ndarray::ArrayView3<'_, f64>,
    geom: &SensorGeometry,
) -> f64 {
    let cfg = PipelineConfig {
        algorithm,
        modulation_hz: geom.modulation_hz,
        adc_bits: geom.adc_bits,
        min_amplitude_lsb: 8.0,
    };
    let mut p = Pipeline::new(
        geom.rows,
        geom.cols,
        cfg,
        set.to_pipeline_calibration(algorithm),
    )
    .expect("pipeline");
    let f = p.process(raw).expect("processing");
    let d: &Array2<f32> = &f.depth_m;
    let mut v: Vec<f32> = d
        .iter()
        .zip(f.depth_mm.iter())
        .filter(|(_, mm)| **mm != 0)
        .map(|(m, _)| *m)
        .collect();
    assert!(v.len() > d.len() / 2, "most pixels invalid\n{REGENERATE}");
    v.sort_by(f32::total_cmp);
    f64::from(v[v.len() / 2])
}

#[test]
fn shipped_calibration_reads_the_emulated_wall_right() {
    let (model, geom, seed) = daemon_sensor();
    let set = shipped();
    let sim = Simulator::new(&model, geom, seed).expect("simulator");
    // Distances other than the calibration's 1 m exercise the wiggling table
    // over the phase circle (80 MHz: 1.87 m unambiguous range).
    for distance_m in [0.3, 0.7, 1.3] {
        let raw = sim
            .expected(
                &Scene::wall(distance_m, 0.6),
                &CaptureRequest {
                    phases_deg: vec![0.0, 90.0, 180.0, 270.0],
                    exposure_us: 500.0,
                    illumination: true,
                    averaged: 1,
                    ambient_klux: 0.0,
                    temperature_c: 25.0,
                    conditions: Default::default(),
                },
            )
            .expect("expected wall capture");
        for (algorithm, view) in [
            (Algorithm::TwoPhase, raw.slice(s![0..2, .., ..])),
            (Algorithm::FourPhase, raw.view()),
        ] {
            let got = median_depth_m(&set, algorithm, view, &geom);
            let err_mm = 1e3 * (got - distance_m);
            // Residual of a good set: a few mm (calibration capture noise).
            assert!(
                err_mm.abs() < 10.0,
                "{algorithm} with calib/emulated reads a wall at {distance_m} m as {got:.4} m \
                 ({err_mm:+.1} mm)\n{REGENERATE}"
            );
        }
    }
}
