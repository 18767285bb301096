//! The judging data, reproduced: an independent simulation of a phone's scenes
//! (`tests/independent/phone_sim.py`: numpy, its own sensor — 60 MHz, a low-passed square
//! correlation, cos⁴ falloff, Poisson shot noise per tap, a cover window, fabric pressed on
//! it in the pockets) writes version-1 recordings (full 224×172 array, 2-phase single
//! acquisitions at 10 Hz) with dark, 24-phase and nothing-in-range (sky) captures beside them.
//! `tofprox calibrate fpn` → `crosstalk` → `wiggling` (docs/calibration.md's order for a
//! phone) make the calibration from those captures alone; each scene is replayed through the daemon's loop
//! (`Controller` on the replay source) with the shipped defaults (`config/tofproxd.toml`).
//! Scored against the truth the simulation wrote per capture (`conditions.truth_near`).

mod common;
use common::repo;

use std::path::{Path, PathBuf};
use std::process::Command;

use tofprox_format::Recording;
use tofproxd::backends::ReplaySource;
use tofproxd::config::{Backend, Config};
use tofproxd::controller::Controller;

/// What one replayed scene gave.
#[derive(Debug)]
struct Replayed {
    name: String,
    captures: usize,
    readings: usize,
    /// Near published at a capture whose truth had been far for the whole far debounce.
    false_near: Vec<usize>,
    /// Near not published although the truth had been near for > 100 ms + 2 periods.
    missed_near: Vec<usize>,
    near_captures: usize,
    truth_near_captures: usize,
}

fn replay(dir: &Path, calib: &Path) -> Replayed {
    let mut cfg = Config::load(&repo().join("config/tofproxd.toml")).expect("shipped config");
    cfg.backend = Backend::Replay;
    cfg.replay.recording = Some(dir.to_path_buf());
    cfg.processing.calibration = Some(calib.to_path_buf());
    let truth: Vec<f64> = Recording::open(dir)
        .expect("recording")
        .captures()
        .iter()
        .map(|c| c.conditions.get("truth_near").copied().expect("truth_near"))
        .collect();
    let source = ReplaySource::open(dir, false).expect("replay source");
    let calibrations = tofproxd::calibration::load_for(&cfg, &source).expect("calibration fits");
    let debounce = cfg.proximity.far_debounce as usize;
    let mut ctl = Controller::new(cfg, source, calibrations).expect("controller");
    let mut r = Replayed {
        name: dir.file_name().unwrap().to_string_lossy().into_owned(),
        captures: truth.len(),
        readings: 0,
        false_near: Vec::new(),
        missed_near: Vec::new(),
        near_captures: 0,
        truth_near_captures: truth.iter().filter(|&&t| t == 1.0).count(),
    };
    // Android's allowance at 10 Hz: 100 ms + 2 sample periods = 3 captures after entering
    let allowance = 3;
    for i in 0.. {
        let out = ctl.step(false);
        if out.end_of_data {
            break;
        }
        assert!(i < truth.len(), "more cycles than captures");
        r.readings += usize::from(out.valid);
        r.near_captures += usize::from(out.near);
        let far_for = |n: usize| i >= n && truth[i - n..=i].iter().all(|&t| t == 0.0);
        let near_for = |n: usize| i >= n && truth[i - n..=i].iter().all(|&t| t == 1.0);
        if out.near && far_for(debounce + 1) {
            r.false_near.push(i);
        }
        if !out.near && near_for(allowance) {
            r.missed_near.push(i);
        }
    }
    r
}

#[test]
fn independent_phone_simulation_replays_without_false_or_missed_near() {
    let Some(python) = tofprox_testkit::require_python("import numpy", "python3-numpy") else {
        return;
    };
    let tmp = tempfile::tempdir().expect("tempdir");
    let sim = tmp.path().join("sim");
    let st = Command::new(&python)
        .arg(repo().join("tests/independent/phone_sim.py"))
        .arg(&sim)
        .args(["--seconds", "4", "--seed", "11"])
        .status()
        .expect("run phone_sim.py");
    assert!(st.success(), "phone_sim.py failed");

    let cal = tmp.path().join("cal");
    let cal_rec = sim.join("calibration");
    for part in ["fpn", "crosstalk", "wiggling"] {
        let out = common::run(&[
            "calibrate",
            part,
            cal_rec.to_str().unwrap(),
            "--out",
            cal.to_str().unwrap(),
        ]);
        assert!(
            out.status.success(),
            "calibrate {part}: {}",
            common::text(&out.stderr)
        );
    }

    let mut scenes: Vec<PathBuf> = std::fs::read_dir(sim.join("scenes"))
        .expect("scenes")
        .map(|e| e.expect("entry").path())
        .collect();
    scenes.sort();
    assert!(scenes.len() >= 12, "{} scenes", scenes.len());
    let mut bad = Vec::new();
    for dir in &scenes {
        let r = replay(dir, &cal);
        eprintln!("{r:?}");
        let hand_like = r.truth_near_captures > 0;
        let ok = r.false_near.is_empty()
            && r.missed_near.is_empty()
            // nothing in range and far scenes are readings (State running), not silence
            && r.readings * 10 >= r.captures * 9
            && (hand_like || r.near_captures == 0)
            && (!hand_like || r.near_captures > 0);
        if !ok {
            bad.push(format!("{}: {r:?}", r.name));
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}
