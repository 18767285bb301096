//! End-to-end tests of `tofprox device probe` and `tofprox device capture`
//! (emulated device; this machine has no USB stack and no CX3).

use std::process::Output;

use tofprox_format::{RawFrames, Recording};

mod common;
use common::{repo_file, run, text};

/// `tofprox device capture <args…> --out <out>`.
fn capture(out: &std::path::Path, args: &[&str]) -> Output {
    let mut all = vec!["device", "capture"];
    all.extend_from_slice(args);
    all.extend(["--out", out.to_str().unwrap()]);
    run(&all)
}

/// `tofprox device capture --emulated <args…> --out <out>` succeeds; the
/// recording it wrote.
fn emulated_capture(out: &std::path::Path, args: &[&str]) -> Recording {
    let mut all = vec!["--emulated"];
    all.extend_from_slice(args);
    let o = capture(out, &all);
    assert!(o.status.success(), "{}", text(&o.stderr));
    Recording::open(out).unwrap()
}

#[test]
fn probe_without_device_says_so_clearly() {
    let o = run(&["device", "probe", "--vid", "04b4", "--pid", "00c3"]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    assert!(text(&o.stdout).contains("no matching device found (USB 04b4:00c3)"));
    assert!(!text(&o.stderr).contains("panicked"));
    let o = run(&["device", "probe", "--json"]);
    assert_eq!(o.status.code(), Some(1));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["devices"], serde_json::json!([]));
}

#[test]
fn capture_on_real_hardware_without_device_is_a_clean_error() {
    let dir = tempfile_dir();
    let out = dir.join("rec");
    let o = capture(&out, &["--mode", "2phase", "--exposure-us", "300"]);
    assert_eq!(o.status.code(), Some(2));
    let e = text(&o.stderr);
    assert!(
        e.starts_with("error: ") && e.contains("no matching device found"),
        "{e}"
    );
    assert!(!out.join("recording.toml").exists());
}

fn tempfile_dir() -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!(
        "tofprox-cli-device-{}-{}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos()
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn emulated_capture_writes_a_version_1_recording() {
    let dir = tempfile_dir();
    let out = dir.join("rec2");
    let rec = emulated_capture(
        &out,
        &["--mode", "2phase", "--exposure-us", "300", "--count", "2"],
    );
    assert_eq!((rec.sensor().rows, rec.sensor().cols), (172, 224));
    assert_eq!(rec.captures().len(), 2);
    let c = &rec.captures()[0];
    assert_eq!(c.phases_deg, vec![0.0, 90.0]);
    assert_eq!(c.exposure_us, 300.0);
    assert_eq!(c.conditions.get("distance_m"), Some(&1.0));
    match rec.load(1).unwrap() {
        RawFrames::U16(a) => {
            assert_eq!(a.dim(), (2, 172, 224));
            assert!(a.iter().all(|&v| v < 4096));
        }
        other => panic!("expected u16 frames, got {:?}", other.dim()),
    }

    // grey image becomes its own dark capture; the window shrinks the frames
    let out = dir.join("rec4");
    let rec = emulated_capture(
        &out,
        &[
            "--mode",
            "4phase-grey",
            "--exposure-us",
            "200",
            "--rows",
            "40,20",
        ],
    );
    assert_eq!((rec.sensor().rows, rec.sensor().roi_origin), (20, [40, 0]));
    let caps = rec.captures();
    assert_eq!(caps.len(), 2);
    assert_eq!((caps[0].phases_deg.len(), caps[0].illumination), (4, true));
    assert_eq!((caps[1].phases_deg.len(), caps[1].illumination), (1, false));

    // bad input: exit 2 with a message, never a panic
    for bad in [
        vec!["--rows", "41,20"],
        vec!["--rows", "x"],
        vec!["--exposure-us", "1e9"],
        vec!["--mode", "3phase"],
    ] {
        let mut args = vec!["--emulated", "--mode", "2phase", "--exposure-us", "300"];
        args.extend(bad.iter().copied());
        let o = capture(&dir.join("bad"), &args);
        assert_eq!(o.status.code(), Some(2), "{bad:?}: {}", text(&o.stderr));
        assert!(!text(&o.stderr).contains("panicked"));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn register_peek_and_poke_on_the_emulated_device() {
    let o = run(&["device", "reg", "--emulated", "read", "a0a4", "--json"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v[0]["register"], 0xA0A4);
    assert_eq!(v[0]["value"], 0x1645);
    let o = run(&[
        "device",
        "reg",
        "--emulated",
        "--addr",
        "22",
        "read",
        "a0a4",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr).contains("did not acknowledge"),
        "{}",
        text(&o.stderr)
    );
    let o = run(&[
        "device",
        "reg",
        "--emulated",
        "read",
        "ffff",
        "--count",
        "2",
    ]);
    assert_eq!(o.status.code(), Some(2));
    // a count that overflows the register range is refused, not a panic
    let o = run(&[
        "device",
        "reg",
        "--emulated",
        "read",
        "a0a4",
        "--count",
        &usize::MAX.to_string(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(
        text(&o.stderr).contains("stay below 0x10000"),
        "{}",
        text(&o.stderr)
    );
    let o = run(&["device", "reset", "hold"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("no matching device found"));
}

#[test]
fn flash_status_and_write_on_a_persisted_emulated_flash() {
    let dir = tempfile_dir();
    let cfg = dir.join("emu.toml");
    std::fs::write(
        &cfg,
        format!(
            "flash_file = {:?}\nframe_source = \"ideal\"\n",
            dir.join("flash.bin")
        ),
    )
    .unwrap();
    let c = cfg.to_str().unwrap();
    let o = run(&["device", "flash", "--emulated", "--config", c, "status"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        text(&o.stdout).contains("no configuration image"),
        "{}",
        text(&o.stdout)
    );
    let o = run(&["device", "flash", "--emulated", "--config", c, "write"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stdout).contains("verified"));
    let o = run(&["device", "flash", "--emulated", "--config", c, "status"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stdout).contains("valid configuration image"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// The phone's factory calibration with the cover window, end to end through the CLI:
/// captures with nothing in range → `calibrate crosstalk` → the set holds it keyed and
/// checksummed → `process` compensates it and reports what is left (a smudge: ≈ +1);
/// a crosstalk of another window is refused.
#[test]
fn crosstalk_calibration_compensates_the_window_and_reports_a_smudge() {
    let dir = tempfile_dir();
    let empty = repo_file("calib/phone/empty.toml");
    let window = |name: &str, args: &[&str]| {
        let mut all = vec!["--rows", "80,8", "--exposure-us", "500"];
        all.extend_from_slice(args);
        emulated_capture(&dir.join(name), &all);
        dir.join(name).display().to_string()
    };
    let dark = window(
        "dark",
        &["--config", &empty, "--mode", "4phase-grey", "--count", "8"],
    );
    let none = window(
        "none",
        &[
            "--config",
            &empty,
            "--mode",
            "4phase",
            "--count",
            "4",
            "--condition",
            "no_target=1",
        ],
    );
    // the wiggling table holds the global delay: with it the window's return lands at ≈ 0 mm
    let wall = repo_file("calib/phone/wall-1m.toml");
    let corr = dir.join("corr");
    emulated_capture(
        &corr,
        &[
            "--rows",
            "80,8",
            "--exposure-us",
            "2000",
            "--config",
            &wall,
            "--mode",
            "correlation24",
        ],
    );
    let corr = corr.display().to_string();
    let cal = dir.join("cal").display().to_string();
    for (what, rec) in [("fpn", &dark), ("crosstalk", &none), ("wiggling", &corr)] {
        let o = run(&["calibrate", what, rec, "--out", &cal]);
        assert!(o.status.success(), "{what}: {}", text(&o.stderr));
    }
    let o = run(&["info", &cal, "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let x = &v["parts"]["crosstalk"];
    assert_eq!(x["sha256"].as_str().map(str::len), Some(64), "{v}");
    // typical window: 20 e-/µs × K 0.8 × 3 LSB/ke ≈ 0.048 LSB/µs (× PRNU/vignetting)
    let mean_abs = x["max"].as_f64().unwrap().max(-x["min"].as_f64().unwrap());
    assert!((0.02..0.1).contains(&mean_abs), "{x}");

    // the same window, nothing in range, and the window smudged (crosstalk doubled)
    let smudged_cfg = dir.join("smudged.toml");
    std::fs::write(
        &smudged_cfg,
        std::fs::read_to_string(&empty)
            .unwrap()
            .replace("smudge_rel = 0.0", "smudge_rel = 1.0")
            .replace("\"../../config/", &format!("\"{}/", repo_file("config"))),
    )
    .unwrap();
    let smudged = window(
        "smudged",
        &[
            "--config",
            smudged_cfg.to_str().unwrap(),
            "--mode",
            "2phase",
            "--count",
            "2",
        ],
    );
    let clean = window(
        "clean",
        &["--config", &empty, "--mode", "2phase", "--count", "2"],
    );
    let residual = |rec: &str| -> Vec<f64> {
        let o = run(&[
            "process",
            rec,
            "--calib",
            &cal,
            "--algo",
            "2phase",
            "--json",
            "--out",
            &dir.join("out").display().to_string(),
        ]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        text(&o.stdout)
            .lines()
            .map(|l| {
                serde_json::from_str::<serde_json::Value>(l).unwrap()["crosstalk_residual"]
                    .as_f64()
                    .unwrap()
            })
            .collect()
    };
    assert!(
        residual(&clean).iter().all(|r| r.abs() < 0.2),
        "{:?}",
        residual(&clean)
    );
    assert!(
        residual(&smudged).iter().all(|r| (r - 1.0).abs() < 0.2),
        "{:?}",
        residual(&smudged)
    );

    // a crosstalk from another window of the array is refused for this set
    let other = dir.join("other");
    let mut all = vec!["--rows", "40,8", "--exposure-us", "500"];
    all.extend_from_slice(&[
        "--config",
        &empty,
        "--mode",
        "4phase",
        "--condition",
        "no_target=1",
    ]);
    emulated_capture(&other, &all);
    let o = run(&[
        "calibrate",
        "crosstalk",
        other.to_str().unwrap(),
        "--out",
        &cal,
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr).contains("roi_origin"),
        "{}",
        text(&o.stderr)
    );
}
