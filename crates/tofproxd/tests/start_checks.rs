//! `tofproxd --check-config` runs every check the start runs, and the start refuses what it
//! cannot serve, naming the file and key (exit 2): a missing replay or calibration
//! directory, a calibration for another window, an unknown key in `[emulated.device]`, an
//! ROI outside the sensor. A relative emulated-device path is resolved once, against the
//! config file's directory, whatever the working directory.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

const EMULATED: &str = r#"
backend = "emulated"
[emulated]
seed = 1
"#;

/// Write `text` as `cfg/x.toml` under a fresh directory; run `tofproxd --check-config` from
/// that directory with the relative path `cfg/x.toml`.
fn check(text: &str, extra: &[(&str, &str)]) -> (tempfile::TempDir, Output) {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::create_dir_all(dir.path().join("cfg/emulated")).expect("mkdir");
    std::fs::write(dir.path().join("cfg/x.toml"), text).expect("write config");
    for (name, body) in extra {
        let path = dir.path().join("cfg").join(name);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).expect("mkdir");
        }
        std::fs::write(path, body).expect("write file");
    }
    let out = Command::new(env!("CARGO_BIN_EXE_tofproxd"))
        .args(["--config", "cfg/x.toml", "--check-config"])
        .current_dir(dir.path())
        .output()
        .expect("run tofproxd");
    (dir, out)
}

fn refused(out: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} not named in: {err}");
    }
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn relative_device_path_resolves_once_against_the_config_directory() {
    let cfg = format!("{EMULATED}device = \"emulated/hand.toml\"\n");
    let (_d, out) = check(
        &cfg,
        &[(
            "emulated/hand.toml",
            "[scene]\nkind = \"hand\"\nwall_distance_m = 1.0\n",
        )],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("cfg/x.toml: ok"));
}

#[test]
fn unknown_key_in_the_emulated_device_table_is_named() {
    let cfg = format!("{EMULATED}[emulated.device]\nframe_source = \"ideal\"\nbogus_key = 1\n");
    let (_d, out) = check(&cfg, &[]);
    refused(&out, &["cfg/x.toml", "emulated.device", "bogus_key"]);
    // the same in a device file names the file
    let cfg = format!("{EMULATED}device = \"emulated/typo.toml\"\n");
    let (_d, out) = check(
        &cfg,
        &[("emulated/typo.toml", "frame_sourse = \"ideal\"\n")],
    );
    refused(&out, &["typo.toml", "frame_sourse"]);
}

#[test]
fn missing_replay_and_calibration_directories_are_refused() {
    let (_d, out) = check(
        "backend = \"replay\"\n[replay]\nrecording = \"no-such-recording\"\n",
        &[],
    );
    refused(&out, &["cfg/x.toml", "no-such-recording"]);
    let cfg = format!(
        "{EMULATED}[emulated.device]\nframe_source = \"ideal\"\n[processing]\ncalibration = \"no-such-set\"\n"
    );
    // [processing] after [emulated.device] is a new table: fine in TOML
    let (_d, out) = check(&cfg, &[]);
    refused(&out, &["cfg/x.toml", "no-such-set"]);
}

#[test]
fn calibration_for_another_window_is_refused() {
    // calib/example is a 16x16 window; the daemon needs a full-array set
    let example = repo().join("calib/example");
    let cfg = format!(
        "{EMULATED}[processing]\ncalibration = \"{}\"\n[emulated.device]\nframe_source = \"ideal\"\n",
        example.display()
    );
    let (_d, out) = check(&cfg, &[]);
    refused(&out, &["cfg/x.toml", "calibration", "16×16", "valid_for"]);
}

#[test]
fn roi_outside_the_sensor_is_refused_naming_the_key() {
    let cfg = format!(
        "{EMULATED}[proximity]\nroi = [170, 0, 20, 20]\n[emulated.device]\nframe_source = \"ideal\"\n"
    );
    let (_d, out) = check(&cfg, &[]);
    refused(&out, &["cfg/x.toml", "proximity.roi"]);
    let cfg = format!(
        "{EMULATED}[proximity]\nroi = [76, 102, 20, 20]\n[emulated.device]\nframe_source = \"ideal\"\n"
    );
    let (_d, out) = check(&cfg, &[]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn roi_with_extra_elements_is_refused() {
    let cfg = format!(
        "{EMULATED}[proximity]\nroi = [10, 10, 20, 20, \"junk\", {{x = 1}}]\n[emulated.device]\nframe_source = \"ideal\"\n"
    );
    let (_d, out) = check(&cfg, &[]);
    refused(&out, &["cfg/x.toml", "roi"]);
    let cfg = format!(
        "{EMULATED}[proximity]\nroi = [10, 10, 20, 20, 30]\n[emulated.device]\nframe_source = \"ideal\"\n"
    );
    let (_d, out) = check(&cfg, &[]);
    refused(&out, &["cfg/x.toml", "roi", "exactly 4 elements"]);
}

/// Run `tofproxd --check-config` on `config` (a path that may be a special file), bounded in
/// time: a read that blocked on a FIFO would hang the check.
fn check_path(config: &Path) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_tofproxd"))
        .arg("--config")
        .arg(config)
        .arg("--check-config")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run tofproxd");
    let t0 = std::time::Instant::now();
    while child.try_wait().expect("wait").is_none() {
        if t0.elapsed() > std::time::Duration::from_secs(20) {
            let _ = child.kill();
            panic!("tofproxd --check-config {} hung", config.display());
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.wait_with_output().expect("output")
}

fn mkfifo(path: &Path) {
    let st = Command::new("mkfifo").arg(path).status().expect("mkfifo");
    assert!(st.success());
}

/// A config, or the `[emulated] device` file it names, that is a FIFO, `/dev/zero` behind
/// a symlink or larger than the limit is refused at once, naming the file.
#[test]
fn special_or_huge_config_files_are_refused_without_reading_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fifo = dir.path().join("fifo.toml");
    mkfifo(&fifo);
    let zero = dir.path().join("zero.toml");
    std::os::unix::fs::symlink("/dev/zero", &zero).expect("symlink");
    let huge = dir.path().join("huge.toml");
    let f = std::fs::File::create(&huge).expect("create");
    f.set_len(tofprox_format::limits::MAX_TOML_BYTES + 1)
        .expect("sparse file");
    for (path, needle) in [
        (&fifo, "a FIFO"),
        (&zero, "character device"),
        (&huge, "more than the limit"),
    ] {
        refused(&check_path(path), &[&path.display().to_string(), needle]);
        // the same file as the emulated device file
        let cfg = dir.path().join("x.toml");
        std::fs::write(&cfg, format!("{EMULATED}device = \"{}\"\n", path.display()))
            .expect("write config");
        refused(&check_path(&cfg), &[&path.display().to_string(), needle]);
    }
}

/// The daemon applies the one validity check `tofprox process` applies: a set made at 60 MHz
/// is refused on the 80 MHz sensor, naming both frequencies (issue 21).
#[test]
fn calibration_for_another_modulation_frequency_is_refused() {
    let (full_rows, full_cols) = (172, 224);
    let set = format!(
        "format = \"tofprox-calibration\"\nversion = 1\nupdated = \"2026-11-25T00:00:00Z\"\n\n[valid_for]\nrows = {full_rows}\ncols = {full_cols}\nroi_origin = [0, 0]\nfull_rows = {full_rows}\nfull_cols = {full_cols}\nadc_bits = 12\nmodulation_hz = 60000000.0\n"
    );
    let cfg = format!(
        "{EMULATED}[processing]\ncalibration = \"calib60\"\n[emulated.device]\nframe_source = \"ideal\"\n"
    );
    let (_d, out) = check(&cfg, &[("calib60/calibration.toml", &set)]);
    refused(
        &out,
        &["calib60", "modulation_hz", "60000000 Hz", "80000000 Hz"],
    );
    // the same set at 80 MHz passes every check
    let ok = set.replace("60000000.0", "80000000.0");
    let (_d, out) = check(&cfg, &[("calib60/calibration.toml", &ok)]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The installed configuration (`config/tofproxd.toml` → `/etc/tofprox/tofproxd.toml`) requires
/// the module's factory calibration: with its directory empty (a module not yet calibrated) the
/// start refuses, naming the directory and saying how to calibrate; with the emulated sensor's
/// set there (same array) it passes.
#[test]
fn shipped_configuration_refuses_an_uncalibrated_module_saying_how_to_calibrate() {
    let shipped = std::fs::read_to_string(repo().join("config/tofproxd.toml")).expect("shipped");
    let line = "calibration = \"/var/lib/tofprox/calib\"";
    assert!(
        shipped.contains(line),
        "the shipped file points at /var/lib/tofprox/calib"
    );
    assert!(shipped.contains("require_calibration = true"));
    let text = shipped.replace(line, "calibration = \"calib\"");
    let (dir, out) = check(&text, &[]);
    std::fs::create_dir_all(dir.path().join("cfg/calib")).expect("mkdir");
    let out_empty = check_path(&dir.path().join("cfg/x.toml"));
    refused(
        &out_empty,
        &["cfg/calib", "has not been calibrated", "tofprox calibrate"],
    );
    // (before the directory existed: refused too, the same way)
    refused(&out, &["has not been calibrated"]);
    for entry in std::fs::read_dir(repo().join("calib/emulated")).expect("calib/emulated") {
        let p = entry.expect("entry").path();
        if p.extension().is_some_and(|e| e == "npy") || p.ends_with("calibration.toml") {
            std::fs::copy(
                &p,
                dir.path().join("cfg/calib").join(p.file_name().unwrap()),
            )
            .expect("copy the set");
        }
    }
    let ok = check_path(&dir.path().join("cfg/x.toml"));
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
}

/// `--check-config` runs the start's refusal of the compatibility mode beside an installed
/// iio-sensor-proxy too (a configuration it accepts is one the daemon starts with), and the
/// refusal names the key that decides "installed".
#[test]
fn check_config_refuses_compat_beside_an_installed_iio_sensor_proxy() {
    let root = tempfile::tempdir().expect("tempdir");
    let binary = root.path().join("usr/libexec/iio-sensor-proxy");
    std::fs::create_dir_all(binary.parent().unwrap()).expect("mkdir");
    std::fs::write(&binary, b"").expect("write");
    let cfg = format!(
        "{EMULATED}[dbus]\niio_sensor_proxy_compat = true\niio_sensor_proxy_paths = [{:?}]\n",
        binary.display().to_string()
    );
    let (_d, out) = check(&cfg, &[]);
    refused(
        &out,
        &[
            &format!("iio-sensor-proxy is installed ({})", binary.display()),
            "iio_sensor_proxy_paths",
            "publisher = \"input\"",
        ],
    );
    // the same file with nothing installed at those paths passes
    let cfg = cfg.replace(
        &binary.display().to_string(),
        "/nonexistent/iio-sensor-proxy",
    );
    let (_d, out) = check(&cfg, &[]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
