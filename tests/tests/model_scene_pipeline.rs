//! The model's scripted hand scene through the depth pipeline: the emulated
//! sensor (and the daemon's tests) rely on `SceneScript` + `Simulator` producing
//! raw frames whose depth follows the script.

use ndarray::s;
use rand::SeedableRng;
use rand::rngs::SmallRng;
use tofprox_core::Algorithm;
use tofprox_core::calib::extract_offset;
use tofprox_core::pipeline::{Calibration, Pipeline, PipelineConfig};
use tofprox_model::{CaptureRequest, ModelConfig, Scene, SceneScript, SensorGeometry, Simulator};

#[test]
fn hand_script_depth_follows_the_script_and_close_range_saturates() {
    // baseline model without the global delay/FPPN (those need the wiggling/FPPN calibration)
    let mut model = ModelConfig::baseline();
    model.set_enabled("fppn", false).unwrap();
    let g = SensorGeometry::irs1645().window(80, 106, 12, 12).unwrap();
    let sim = Simulator::new(&model, g, 21).unwrap();
    let mut rng = SmallRng::seed_from_u64(5);
    let exposure_us = 300.0;
    // offset calibration from a dark capture (2.3.1.3)
    let mut dark = CaptureRequest::dark(4, exposure_us);
    dark.averaged = 16;
    let dark = sim
        .capture(&Scene::wall(1.0, 1.0), &dark, &mut rng)
        .unwrap();
    let calibration = Calibration {
        crosstalk: None,
        offset: Some(extract_offset(dark.view()).unwrap()),
        wiggling: None,
        fppn: None,
    };
    let cfg = PipelineConfig {
        algorithm: Algorithm::FourPhase,
        ..PipelineConfig::default()
    };
    let mut p = Pipeline::new(g.rows, g.cols, cfg, calibration).unwrap();

    let script = SceneScript::hand();
    let (mut checked, mut saturated) = (0, 0);
    for i in 0..80 {
        let t = script.period_s * i as f64 / 80.0;
        let truth = script.centre_distance_m(t);
        let raw = sim
            .capture_u16(
                &script.at(t),
                &CaptureRequest::four_phase(exposure_us),
                &mut rng,
            )
            .unwrap();
        let f = p.process(raw.view()).unwrap();
        let centre = f.depth_m.slice(s![4..8, 4..8]);
        let flags = f.flags.slice(s![4..8, 4..8]);
        if truth < 0.12 {
            // a hand at a few cm overdrives the ADC: flagged, never a wrong reading
            if flags.iter().all(|&fl| fl & 1 != 0) {
                saturated += 1;
            }
            continue;
        }
        let mean: f64 = centre.iter().map(|&d| f64::from(d)).sum::<f64>() / centre.len() as f64;
        assert!(
            (mean - truth).abs() < 0.03,
            "t = {t:.2} s: depth {mean:.3} m, truth {truth:.3} m"
        );
        checked += 1;
    }
    assert!(checked > 40, "checked {checked} frames");
    assert!(saturated > 0, "close range never saturated");
}
