//! End-to-end tests of `tofprox device probe` and `tofprox device capture`
//! (emulated device; this machine has no USB stack and no CX3).

use std::process::Output;

use tofprox_format::{RawFrames, Recording};

mod common;
use common::{run, text};

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
