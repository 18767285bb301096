//! `tofprox monitor --json` against tofproxd on the emulated hand (a private bus from
//! `dbus-run-session`): every stdout line is one JSON object (JSON Lines), the first is the
//! first reading (the wall at 1 m), then the hand's near and far changes with distances on
//! the right side of the thresholds; the wait for the first reading is said in words.
use std::process::Command;

mod common;
use common::text;

#[test]
fn monitor_json_lines_parse_and_follow_the_hand() {
    let Some(_) = tofprox_testkit::require_program("dbus-run-session", "dbus-daemon") else {
        return;
    };
    // the demo's configuration with a faster hand (approach and leave every 4 s, not 12 s)
    let dir = tempfile::tempdir().unwrap();
    let demo = std::fs::read_to_string(common::repo().join("config/tofproxd-emulated.toml"))
        .unwrap()
        .replace(
            "calibration = \"../calib/emulated\"",
            &format!("calibration = {:?}", common::repo_file("calib/emulated")),
        )
        .replace("period_s = 12.0", "period_s = 4.0");
    assert!(demo.contains("period_s = 4.0") && demo.contains("calib/emulated"));
    let cfg = dir.path().join("fast-hand.toml");
    std::fs::write(&cfg, demo).unwrap();
    let script = format!(
        "tofproxd --config '{}' --bus session 2>/dev/null & \
         tofprox monitor --bus session --json --seconds 4; kill %1",
        cfg.display()
    );
    let out = Command::new("dbus-run-session")
        .args(["--", "bash", "-c", &script])
        .env("PATH", common::path_with_bins())
        .output()
        .expect("dbus-run-session");
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(stderr.contains("waiting for the first reading"), "{stderr}");
    let events: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l:?}\n{stderr}")))
        .collect();
    assert!(events.len() >= 3, "{stdout}\n{stderr}");
    let first = &events[0];
    assert_eq!(first["event"], "first_reading", "{stdout}");
    assert_eq!(first["near"], false);
    let wall_mm = first["distance_mm"]
        .as_u64()
        .expect("the wall is a distance");
    assert!((950..=1020).contains(&wall_mm), "wall at 1 m: {wall_mm}");
    assert_eq!(first["distance"], format!("distance {wall_mm} mm"));
    // every row says which rule decided it: the wall by its distance
    assert_eq!(first["reason"], "distance", "{first}");
    // demo thresholds: near ≤ 150 mm, far ≥ 200 mm
    let near = events
        .iter()
        .find(|e| e["near"] == true)
        .unwrap_or_else(|| panic!("no near: {stdout}"));
    assert_eq!(near["event"], "near_changed");
    assert!(
        near["distance_mm"].as_u64().is_some_and(|d| d <= 150),
        "{near}"
    );
    let t_near = near["t_s"].as_f64().unwrap();
    let far = events
        .iter()
        .find(|e| e["near"] == false && e["t_s"].as_f64().unwrap() > t_near)
        .unwrap_or_else(|| panic!("no far after near: {stdout}"));
    // far: at or beyond the far threshold, or a valid reading with nothing in range (the
    // u32::MAX value, given in words with a null distance)
    match far["distance_mm"].as_u64() {
        Some(d) => assert!(d >= 200, "{far}"),
        None => assert_eq!(far["distance"], "nothing in range", "{far}"),
    }
    // the hand near by its distance (or by a saturated frame at contact); far by its distance
    // or by nothing in range
    assert!(
        ["distance", "saturated"].contains(&near["reason"].as_str().unwrap_or("")),
        "{near}"
    );
    assert!(
        ["distance", "nothing_in_range", "hold_expired"]
            .contains(&far["reason"].as_str().unwrap_or("")),
        "{far}"
    );
    // times rise; nothing printed as a raw special value
    assert!(
        events
            .windows(2)
            .all(|w| w[0]["t_s"].as_f64() <= w[1]["t_s"].as_f64())
    );
    assert!(!stdout.contains("4294967295"), "{stdout}");
}
