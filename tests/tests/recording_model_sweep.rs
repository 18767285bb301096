//! The whole file path of a calibration, with data from the physical model:
//! simulate a distance sweep (baseline model: non-sinusoidal correlation,
//! FPN, FPPN, global delay, noise) → write it as a version 1 recording →
//! read it back → extract offset + wiggling + FPPN with the calibration
//! workflow (`tofprox_format::extract`, what `tofprox calibrate` runs) → save and reload the
//! calibration set (checksums) → process every capture with the pipeline.
//! Calibrated 2- and 4-phase depth must be within 1 cm of the ground truth
//! (thesis 5.1.2.2); uncalibrated 2-phase must be far off (fig. 3.7).

use ndarray::{Axis, s};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tofprox_core::Algorithm;
use tofprox_core::pipeline::{Calibration, Pipeline, PipelineConfig};
use tofprox_format::{
    CalibPart, CalibrationSet, Extract, ExtractOptions, RawFrames, Recording, RecordingWriter,
    extract,
};
use tofprox_model::{CaptureRequest, ModelConfig, Scene, SensorGeometry, Simulator};
use tofprox_testkit::capture_spec;

const DISTANCES_M: [f64; 6] = [0.15, 0.3, 0.45, 0.6, 0.8, 1.0];

#[test]
fn model_sweep_through_files_calibrates_below_1_cm() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("sweep");
    let geometry = SensorGeometry {
        rows: 12,
        cols: 12,
        roi_origin: [80, 106],
        full_rows: 172,
        full_cols: 224,
        adc_bits: 12,
        modulation_hz: 80e6,
    };
    let sim = Simulator::new(&ModelConfig::baseline(), geometry, 7).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let sensor = geometry;
    let exposure_us = 300.0;
    let wall = |d: f64| Scene::FlatWall {
        distance_m: d,
        reflectivity: 0.9,
    };

    // --- record -----------------------------------------------------------
    let mut w = RecordingWriter::create(&dir, sensor, Some("model sweep".into())).unwrap();
    let mut dark = CaptureRequest::dark(4, exposure_us);
    dark.averaged = 32;
    let x = sim.capture(&wall(1.0), &dark, &mut rng).unwrap();
    w.append(capture_spec(&dark, None), &RawFrames::F64(x))
        .unwrap();
    let mut corr = CaptureRequest::correlation24(exposure_us);
    corr.averaged = 64;
    let x = sim.capture(&wall(0.5), &corr, &mut rng).unwrap();
    w.append(capture_spec(&corr, Some(0.5)), &RawFrames::F64(x))
        .unwrap();
    let mut four = CaptureRequest::four_phase(exposure_us);
    four.averaged = 16;
    for d in DISTANCES_M {
        let x = sim.capture(&wall(d), &four, &mut rng).unwrap();
        w.append(
            capture_spec(&four, Some(d)),
            &RawFrames::F32(x.mapv(|v| v as f32)),
        )
        .unwrap();
    }
    w.finish().unwrap();

    // --- read back and calibrate -------------------------------------------
    let rec = Recording::open(&dir).unwrap();
    assert_eq!(rec.captures().len(), 2 + DISTANCES_M.len());
    // the workflow `tofprox calibrate` runs: fpn → wiggling (+ amplitude) → fppn
    let mut set = CalibrationSet::new(rec.sensor());
    let mut notes = Vec::new();
    for (what, capture) in [
        (Extract::Offset, None),
        (Extract::Wiggling, None),
        (Extract::Fppn, Some(3)),
    ] {
        let opts = ExtractOptions {
            capture,
            lut_size: 256,
            tool: "recording_model_sweep".into(),
        };
        let done = extract(&rec, &mut set, &what, &opts, &mut |n| {
            notes.push(n.to_string())
        })
        .unwrap_or_else(|e| panic!("{what:?}: {e}"));
        assert!(
            done.dropped.is_empty(),
            "{what:?} dropped {:?}",
            done.dropped
        );
    }
    assert_eq!(
        set.sources[&CalibPart::Offset].captures,
        vec![0],
        "the one dark capture"
    );
    assert_eq!(set.sources[&CalibPart::Wiggling4Phase].captures, vec![1]);
    assert_eq!(set.sources[&CalibPart::Fppn].captures, vec![3]);
    // every earlier part was there when the next was extracted; only the lens was missing
    assert!(
        notes.iter().all(|n| n.contains("no lens intrinsics")),
        "{notes:?}"
    );
    let cdir = t.path().join("calib");
    set.save(&cdir).unwrap();
    let set = CalibrationSet::load(&cdir).unwrap();
    set.check_compatible(rec.sensor()).unwrap();

    // --- process -------------------------------------------------------------
    let run = |alg: Algorithm, calibration: Calibration| -> Vec<f64> {
        let cfg = PipelineConfig {
            algorithm: alg,
            modulation_hz: sensor.modulation_hz,
            adc_bits: sensor.adc_bits,
            ..PipelineConfig::default()
        };
        let mut p = Pipeline::new(sensor.rows, sensor.cols, cfg, calibration).unwrap();
        (2..rec.captures().len())
            .map(|i| {
                let RawFrames::F32(raw) = rec.load(i).unwrap() else {
                    panic!("capture {i} is float32")
                };
                let n = alg.raw_images();
                let f = p.process(raw.slice(s![..n, .., ..])).unwrap();
                assert!(
                    f.valid_fraction() > 0.9,
                    "{alg} capture {i}: valid {}",
                    f.valid_fraction()
                );
                f.median_valid_depth_m().unwrap() - rec.captures()[i].distance_m().unwrap()
            })
            .collect()
    };
    for alg in Algorithm::ALL {
        let errs = run(alg, set.to_pipeline_calibration(alg));
        eprintln!("calibrated {alg} errors (m): {errs:?}");
        for (d, e) in DISTANCES_M.iter().zip(&errs) {
            assert!(
                e.abs() < 0.01,
                "calibrated {alg} at {d} m: error {:.1} mm ({errs:?})",
                e * 1000.0
            );
        }
    }
    let raw = run(Algorithm::TwoPhase, Calibration::default());
    eprintln!("uncalibrated 2phase errors (m): {raw:?}");
    let worst = raw.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    assert!(
        worst > 0.05,
        "uncalibrated 2-phase should be unusable, worst error {:.1} mm",
        worst * 1000.0
    );
    // the dark capture really carries FPN of the thesis's order (σ ≈ 34 LSB)
    let dark = rec.load(0).unwrap().to_f64();
    let sd = dark.mean_axis(Axis(0)).unwrap().std(0.0);
    assert!(sd > 10.0, "FPN σ {sd} LSB");
}
