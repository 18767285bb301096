//! The calibration station on the emulated module (feature `emulated`): the shipped station
//! files with a 16-row read-out window (fast), the module and phone lines, a faulty window.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use tofprox_bridge::{EmulatedConfig, VirtualClock};
use tofprox_format::npy::{self, NpyArray};
use tofprox_format::{CalibrationSet, Recording};
use tofprox_station::{EmulatedFixture, Line, Report, Station, StationError, run_station};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The shipped station file with a small read-out window (fast).
fn station(name: &str) -> (Station, PathBuf) {
    let path = repo().join("config/station").join(name);
    let mut s = Station::load(&path).unwrap();
    s.module.rows = Some([78, 16]);
    s.validate(&path).unwrap();
    (s, path)
}

fn run(line: Line, name: &str, device: EmulatedConfig, out: &Path) -> Report {
    let (s, path) = station(name);
    let mut fixture = EmulatedFixture::new(device, 1, Arc::new(VirtualClock::new()));
    run_station(&s, line, &path, &mut fixture, out).unwrap()
}

fn phone_device() -> EmulatedConfig {
    EmulatedConfig::load(&repo().join("calib/phone/wall-1m.toml")).unwrap()
}

fn figure(r: &Report, part: &str, figure: &str) -> f64 {
    r.checks
        .iter()
        .find(|c| c.part == part && c.figure.starts_with(figure))
        .unwrap_or_else(|| panic!("no {part} {figure} in {:?}", r.checks))
        .value
}

/// σ over the pixels of the averaged dark image the station recorded, computed here from the
/// recording's raw file (not through the extraction).
fn dark_sigma_from_recording(out: &Path) -> f64 {
    let dir = out.join("recordings/dark");
    let rec = Recording::open(&dir).unwrap();
    assert_eq!(rec.captures().len(), 1);
    let a = npy::read(&dir.join("frames/000000.npy"), Some(&dir)).unwrap();
    let NpyArray::F32(a) = a else {
        panic!("averaged frames are float32")
    };
    let v: Vec<f64> = a.iter().map(|&x| f64::from(x)).collect();
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
}

#[test]
fn emulated_module_passes_and_reads_the_check_wall() {
    let t = tempfile::tempdir().unwrap();
    let r = run(
        Line::Module,
        "module.toml",
        EmulatedConfig::default(),
        t.path(),
    );
    assert!(r.passed, "{:#?}", r.checks);
    assert!(r.complete && r.failed_parts().is_empty());
    let set = CalibrationSet::load(&t.path().join("calib")).unwrap();
    assert!(set.is_complete());
    assert!(
        set.crosstalk().is_none(),
        "a bare module has no window part"
    );
    // the check wall at 0.5 m within the documented 10 mm, both algorithms
    assert_eq!(r.check_readings.len(), 2);
    for c in &r.check_readings {
        let e = c.error_mm.unwrap();
        assert!(e.abs() < 2.0, "{:?} check error {e} mm", c.algorithm);
        assert!((c.median_depth_m.unwrap() - 0.5).abs() < 0.002);
        assert!(c.valid_fraction > 0.99);
    }
    // the FPN σ the station reports is that of the dark image it recorded (emulated: 34 LSB)
    let fpn = figure(&r, "offset", "FPN σ");
    let independent = dark_sigma_from_recording(t.path());
    assert!(
        (fpn - independent).abs() < 0.01 * independent,
        "{fpn} vs {independent}"
    );
    assert!((25.0..45.0).contains(&fpn), "{fpn}");
    assert!((5.0..30.0).contains(&figure(&r, "wiggling_2phase", "wiggling")));
    assert!((0.05..0.15).contains(&figure(&r, "amplitude", "median K")));
    assert_eq!(figure(&r, "offset", "hot pixels"), 0.0);
    // steps in the documented order, each within the eye-safe exposure, device time counted
    let steps: Vec<&str> = r.steps.iter().map(|s| s.step.as_str()).collect();
    assert_eq!(steps, ["dark", "wiggling", "fppn", "check"]);
    assert!(
        r.steps
            .iter()
            .all(|s| s.exposure_us <= 500.0 && s.device_s > 0.0)
    );
    let sum: f64 = r.steps.iter().map(|s| s.device_s).sum();
    assert!(
        r.device_s >= sum - 1e-9 && r.device_s > 0.1,
        "{} {sum}",
        r.device_s
    );
    // the reports
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(t.path().join("report.json")).unwrap())
            .unwrap();
    assert_eq!(json["passed"], true);
    assert_eq!(json["checks"].as_array().unwrap().len(), r.checks.len());
    let html = std::fs::read_to_string(t.path().join("report.html")).unwrap();
    assert!(html.contains("PASS") && html.contains("<svg") && !html.contains("<script"));
}

#[test]
fn phone_line_measures_the_window_and_a_window_three_times_the_limit_fails_crosstalk() {
    let t = tempfile::tempdir().unwrap();
    let clean = run(
        Line::Phone,
        "phone.toml",
        phone_device(),
        &t.path().join("clean"),
    );
    assert!(clean.passed, "{:#?}", clean.checks);
    let steps: Vec<&str> = clean.steps.iter().map(|s| s.step.as_str()).collect();
    assert_eq!(steps, ["dark", "crosstalk", "wiggling", "fppn", "check"]);
    let xt = figure(&clean, "crosstalk", "cover-window");
    // the model's typical window, 20 e⁻/µs: 0.047 LSB/µs (docs/calibration.md)
    assert!((0.040..0.055).contains(&xt), "{xt}");
    for c in &clean.check_readings {
        assert!(c.error_mm.unwrap().abs() < 2.0, "{c:?}");
    }
    // a window 3× the limit: the return is proportional to e_per_us
    let (s, _) = station("phone.toml");
    let limit = s.limits.crosstalk_lsb_per_us.unwrap();
    let mut dev = phone_device();
    let w = dev.cover_window.as_mut().unwrap();
    w.e_per_us *= 3.0 * limit / xt;
    let bad = run(Line::Phone, "phone.toml", dev, &t.path().join("bad"));
    assert!(!bad.passed);
    assert_eq!(bad.failed_parts(), ["crosstalk"], "{:#?}", bad.checks);
    let xt_bad = figure(&bad, "crosstalk", "cover-window");
    assert!(
        (xt_bad / limit - 3.0).abs() < 0.15,
        "{xt_bad} vs limit {limit}"
    );
    let html = std::fs::read_to_string(t.path().join("bad/report.html")).unwrap();
    assert!(html.contains("FAIL: crosstalk"));
}

#[test]
fn station_files_are_checked() {
    let path = repo().join("config/station/module.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let err = |t: String| Station::parse(&t, &path).unwrap_err().to_string();
    // unknown keys are refused, naming the key
    let e = err(text.replace("[limits]", "[limits]\nfpn_sigma = 3.0"));
    assert!(e.contains("limits") && e.contains("fpn_sigma"), "{e}");
    // an exposure beyond the eye-safe limit
    let at = text.find("[captures.fppn]").unwrap();
    let long = format!(
        "{}{}",
        &text[..at],
        text[at..].replacen("exposure_us = 500.0", "exposure_us = 4000.0", 1)
    );
    let e = err(long);
    assert!(
        e.contains("captures.fppn.exposure_us") && e.contains("eye safety"),
        "{e}"
    );
    // a target that does not fill the field of view
    let e = err(text.replace("size_m = [1.5, 1.1]", "size_m = [1.0, 0.8]"));
    assert!(
        e.contains("targets.wall.size_m") && e.contains("field of view"),
        "{e}"
    );
    // the line asked must be the station's
    let s = Station::parse(&text, &path).unwrap();
    let t = tempfile::tempdir().unwrap();
    let mut f = EmulatedFixture::new(EmulatedConfig::default(), 1, Arc::new(VirtualClock::new()));
    let e = run_station(&s, Line::Phone, &path, &mut f, t.path()).unwrap_err();
    assert!(matches!(e, StationError::LineMismatch { .. }), "{e}");
    // the phone line needs its absorber
    let phone = std::fs::read_to_string(repo().join("config/station/phone.toml")).unwrap();
    let cut = phone.replace("[targets.absorber]", "[unused]");
    assert!(err(cut).contains("unused"));
}

#[test]
fn a_read_out_with_three_times_the_fixed_pattern_fails_the_offset() {
    // the baseline model with the pixels' dark-level spread tripled (29 → 90 LSB)
    let t = tempfile::tempdir().unwrap();
    let model = std::fs::read_to_string(repo().join("config/model/baseline.toml"))
        .unwrap()
        .replace("pixel_sigma_lsb = 29.0", "pixel_sigma_lsb = 90.0");
    let path = t.path().join("noisy-readout.toml");
    std::fs::write(&path, model).unwrap();
    let dev = EmulatedConfig {
        model: Some(path),
        ..EmulatedConfig::default()
    };
    let r = run(Line::Module, "module.toml", dev, &t.path().join("out"));
    assert_eq!(r.failed_parts(), ["offset"], "{:#?}", r.checks);
    let fpn = figure(&r, "offset", "FPN σ");
    let independent = dark_sigma_from_recording(&t.path().join("out"));
    assert!((fpn - independent).abs() < 0.01 * independent);
    // √(8² + 15² + 90² + …) ≈ 92 LSB against the limit of 60
    assert!((80.0..105.0).contains(&fpn), "{fpn}");
    // the depth is still right: the offset is subtracted, the module is out of spec
    for c in &r.check_readings {
        assert!(c.error_mm.unwrap().abs() < 2.0, "{c:?}");
    }
}
