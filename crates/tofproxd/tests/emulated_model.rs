//! The emulated demo end to end, in-process: `config/tofproxd-emulated.toml`
//! (frames from the physical model, the shipped factory calibration
//! `calib/emulated/`) through the loop controller on a virtual clock. The 1 m
//! wall must read ~1 m in 2-phase mode, the scripted hand must give near and
//! far, and the 2-vs-4-phase check must not push the loop into 4-phase.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use tofprox_bridge::{Clock, VirtualClock};
use tofproxd::backends::emulated::{bridge_source, device_config};
use tofproxd::calibration::load_for;
use tofproxd::config::{Config, Mode};
use tofproxd::controller::Controller;

fn demo_config() -> (Config, PathBuf) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/tofproxd-emulated.toml");
    let cfg = Config::load(&path).expect("config/tofproxd-emulated.toml loads");
    let base = path.parent().expect("config dir").to_path_buf();
    (cfg, base)
}

/// One reading: virtual time at the cycle's start and end, what the loop published.
struct Reading {
    t_start_s: f64,
    t_end_s: f64,
    distance_mm: Option<u32>,
    near: bool,
    mode: Mode,
    captured: Option<Mode>,
}

fn table(readings: &[Reading], scene: &tofprox_model::SceneScript) -> String {
    let mut t = String::new();
    for r in readings {
        t.push_str(&format!(
            "{:6.2}s truth {:4.0} mm  read {:?}  near {}  mode {:?}  captured {:?}\n",
            r.t_start_s,
            1e3 * scene.centre_distance_m(r.t_start_s),
            r.distance_mm,
            r.near,
            r.mode,
            r.captured
        ));
    }
    t
}

#[test]
fn demo_model_frames_with_shipped_calibration() {
    let (cfg, base) = demo_config();
    assert_eq!(cfg.processing.mode, Mode::TwoPhase);
    let dev_cfg = device_config(&cfg, &base).expect("emulated device config");
    assert_eq!(
        dev_cfg.frame_source,
        tofprox_bridge::emulated::FrameSource::Model,
        "the demo must run on model frames"
    );
    assert!(
        dev_cfg.ambient_klux < 1.0,
        "this test is about low ambient light (2-phase must stay the mode)"
    );
    let scene = dev_cfg.scene.clone();
    let wall_mm = 1e3 * scene.wall_distance_m;
    let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
    let source = bridge_source(
        dev_cfg,
        clock.clone(),
        cfg.emulated.seed,
        "emulated (model)",
    )
    .expect("emulated stack");
    let calib = load_for(&cfg, &source).expect("calib/emulated loads for the demo");
    assert!(
        calib.two_phase.offset.is_some() && calib.two_phase.wiggling.is_some(),
        "the demo's calibration must hold offset + 2-phase wiggling"
    );
    let mut ctl = Controller::new(cfg.clone(), source, calib).expect("controller");

    // One hand period (approach, hold at 5 cm, leave) plus the wall-only
    // stretch after it: ~90 cycles of model frames, well under a second.
    let end_s = scene.period_s * 1.1;
    let mut readings = Vec::new();
    while clock.now().as_secs_f64() < end_s {
        let t_start_s = clock.now().as_secs_f64();
        let out = ctl.step(false);
        assert!(out.error.is_none(), "cycle failed: {:?}", out.error);
        readings.push(Reading {
            t_start_s,
            t_end_s: clock.now().as_secs_f64(),
            distance_mm: out.distance_mm,
            near: out.near,
            mode: ctl.mode(),
            captured: out.captured_mode,
        });
        clock.sleep(out.sleep);
    }
    let t = table(&readings, &scene);
    eprint!("{t}");

    // 2-phase stays the mode: the 4-phase probes agree with 2-phase, so the
    // 2-vs-4 discrepancy check does not switch at low ambient light.
    assert!(
        readings.iter().all(|r| r.mode == Mode::TwoPhase),
        "the loop left 2-phase mode:\n{t}"
    );
    assert!(
        readings.iter().any(|r| r.captured == Some(Mode::FourPhase)),
        "no 4-phase probe ran (the check above would be vacuous):\n{t}"
    );

    // The wall at 1 m (nothing in front during the whole cycle) reads ~1 m.
    // The reading is the ROI's 10th percentile, so pixel noise pulls it a
    // little short; uncalibrated 2-phase read ~0.2 m here.
    let wall: Vec<u32> = readings
        .iter()
        .filter(|r| {
            scene.object_distance_m(r.t_start_s).is_none()
                && scene.object_distance_m(r.t_end_s).is_none()
        })
        .filter_map(|r| r.distance_mm)
        .collect();
    assert!(wall.len() >= 10, "too few wall readings:\n{t}");
    for d in &wall {
        assert!(
            (f64::from(*d) - wall_mm).abs() <= 30.0,
            "wall at {wall_mm} mm read as {d} mm:\n{t}"
        );
    }

    // The hand: close readings follow the scripted distance while it fills the ROI.
    for r in &readings {
        let (a, b) = (
            1e3 * scene.centre_distance_m(r.t_start_s),
            1e3 * scene.centre_distance_m(r.t_end_s),
        );
        if let Some(d) = r.distance_mm
            && a.max(b) < 400.0
        {
            let d = f64::from(d);
            assert!(
                d >= a.min(b) - 20.0 && d <= a.max(b) + 20.0,
                "hand at {a:.0}..{b:.0} mm read as {d} mm:\n{t}"
            );
        }
    }
    // Near while the hand is well inside near_mm, far again once it has left:
    // exactly one near episode.
    let near_mm = f64::from(cfg.proximity.near_mm);
    let far_mm = f64::from(cfg.proximity.far_mm);
    for r in &readings {
        let truth_max = 1e3
            * scene
                .centre_distance_m(r.t_start_s)
                .max(scene.centre_distance_m(r.t_end_s));
        if truth_max < near_mm - 30.0 {
            assert!(r.near, "not near at {truth_max:.0} mm:\n{t}");
        }
    }
    let debounce = cfg.proximity.far_debounce as usize + 1;
    for (i, r) in readings.iter().enumerate().skip(debounce) {
        let all_far = readings[i - debounce..=i].iter().all(|q| {
            1e3 * scene
                .centre_distance_m(q.t_start_s)
                .min(scene.centre_distance_m(q.t_end_s))
                > far_mm + 50.0
        });
        if all_far {
            assert!(
                !r.near,
                "near at {:.2}s with the hand far:\n{t}",
                r.t_start_s
            );
        }
    }
    let entries = readings
        .windows(2)
        .filter(|w| !w[0].near && w[1].near)
        .count();
    assert_eq!(entries, 1, "expected one near episode:\n{t}");
    assert!(
        !readings.last().is_some_and(|r| r.near),
        "still near at the end:\n{t}"
    );
}
