//! End-to-end tests of `tofprox info`, `calibrate` and `process` on the
//! shipped example recording, and of every kind of bad input (exit code 2,
//! a message naming the file/key, never a panic).

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use ndarray::Array3;
use tofprox_format::{CalibPart, Recording, npy};

mod common;
use common::copy_dir;

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_tofprox")
}

/// The repository root (holds `examples/recording` and `calib/example`).
fn repo() -> PathBuf {
    if let Ok(p) = std::env::var("TOFPROX_REPO_ROOT") {
        return PathBuf::from(p);
    }
    let mut d = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    loop {
        if d.join("examples/recording/recording.toml").is_file() {
            return d;
        }
        if !d.pop() {
            panic!(
                "cannot find the repository root above {}",
                env!("CARGO_MANIFEST_DIR")
            );
        }
    }
}

fn example_rec() -> PathBuf {
    repo().join("examples/recording")
}

fn run(args: &[&str]) -> Output {
    Command::new(bin())
        .args(args)
        .current_dir(repo())
        .output()
        .expect("run tofprox")
}

/// `tofprox calibrate <what> examples/recording --out <out> <extra…>`.
fn calibrate(what: &str, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["calibrate", what, "examples/recording", "--out", p(out)];
    args.extend_from_slice(extra);
    run(&args)
}

fn p(path: &Path) -> &str {
    path.to_str().expect("utf-8 path")
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn assert_ok(o: &Output) {
    assert!(
        o.status.success(),
        "exit {:?}\nstdout:\n{}\nstderr:\n{}",
        o.status.code(),
        stdout(o),
        stderr(o)
    );
}

/// Exit code 2, one `error:` message containing every needle, no panic.
fn assert_bad(o: &Output, needles: &[&str]) {
    let err = stderr(o);
    assert_eq!(
        o.status.code(),
        Some(2),
        "stderr:\n{err}\nstdout:\n{}",
        stdout(o)
    );
    assert!(!err.contains("panicked"), "panic: {err}");
    assert!(err.contains("error: "), "{err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks {n:?}:\n{err}");
    }
}

/// A private copy of the example recording.
fn rec_copy(t: &tempfile::TempDir) -> PathBuf {
    let d = t.path().join("rec");
    copy_dir(&example_rec(), &d);
    d
}

fn edit(path: &Path, from: &str, to: &str) {
    let text = fs::read_to_string(path).unwrap();
    assert!(text.contains(from), "{from:?} not in {}", path.display());
    fs::write(path, text.replacen(from, to, 1)).unwrap();
}

/// `tofprox process <rec> --calib <calib> --algo <algo> --out <out> <extra…>`.
fn process(rec: &str, calib: &str, algo: &str, out: &str, extra: &[&str]) -> Output {
    let mut args = vec![
        "process", rec, "--calib", calib, "--algo", algo, "--out", out,
    ];
    args.extend_from_slice(extra);
    run(&args)
}

/// `tofprox info <path>` succeeds and its text names every needle.
fn info_text_has(path: &Path, needles: &[&str]) {
    let o = run(&["info", p(path)]);
    assert_ok(&o);
    let s = stdout(&o);
    for n in needles {
        assert!(s.contains(n), "info lacks {n:?}:\n{s}");
    }
}

/// `tofprox info <path> --json` succeeds; its JSON.
fn info_json(path: &Path) -> serde_json::Value {
    let o = run(&["info", p(path), "--json"]);
    assert_ok(&o);
    serde_json::from_str(&stdout(&o)).unwrap()
}

#[test]
fn info_summarises_the_example() {
    info_text_has(
        &example_rec(),
        &[
            "captures    8",
            "correlation-24 ×1",
            "4phase ×5",
            "dark 4phase ×1",
            "2phase ×1",
            "500 µs ×8",
            "distance_m      7 capture(s): 0.25, 0.33, 0.4, 0.5, 0.55, 0.7, 0.9",
            "saturation  0.00 %",
            "16×16 window at (row 78, col 104) of a 172×224 array",
        ],
    );
    let v = info_json(&example_rec());
    assert_eq!(v["captures"], 8);
    assert_eq!(v["by_mode"]["4phase"], 5);
    assert_eq!(v["by_illumination"]["off"], 1);
    assert_eq!(v["sensor"]["adc_bits"], 12);
    assert_eq!(v["per_capture"].as_array().unwrap().len(), 8);
    assert_eq!(v["per_capture"][1]["mode"], "correlation-24");
    assert_eq!(v["saturated_fraction"], 0.0);
}

#[test]
fn info_reports_saturation_share() {
    let t = tempfile::tempdir().unwrap();
    let rec = rec_copy(&t);
    // saturate a quarter of the pixels of the 2-phase u16 capture
    let r = Recording::open(&rec).unwrap();
    let tofprox_format::RawFrames::U16(mut a) = r.load(7).unwrap() else {
        panic!("capture 7 is uint16")
    };
    for row in 0..8 {
        for col in 0..8 {
            a[[1, row, col]] = 4095;
        }
    }
    fs::write(rec.join("frames/000007.npy"), npy::encode_u16(&a)).unwrap();
    let v = info_json(&rec);
    assert_eq!(v["per_capture"][7]["saturated_fraction"], 0.25);
    let total = v["saturated_fraction"].as_f64().unwrap();
    assert!((total - 0.25 / 8.0).abs() < 1e-12, "{total}");
}

fn json_lines(o: &Output) -> Vec<serde_json::Value> {
    stdout(o)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect()
}

/// Process with `calib` and return (index, median error m, valid fraction) per capture.
fn process_errors(calib: Option<&Path>, algo: &str, out: &Path) -> Vec<(u64, f64, f64)> {
    let rec = Recording::open(&example_rec()).unwrap();
    let mut args = vec![
        "process",
        "examples/recording",
        "--algo",
        algo,
        "--out",
        p(out),
        "--json",
    ];
    if let Some(c) = calib {
        args.extend(["--calib", p(c)]);
    }
    let o = run(&args);
    assert_ok(&o);
    json_lines(&o)
        .iter()
        .map(|v| {
            let keys: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
            assert_eq!(
                keys,
                [
                    "depth_kind",
                    "distance_m",
                    "error_mm",
                    "index",
                    "median_depth_m",
                    "process_us",
                    "valid_fraction"
                ]
            );
            let i = v["index"].as_u64().unwrap();
            let truth = rec.captures()[i as usize].distance_m().unwrap();
            assert!(v["process_us"].as_f64().unwrap() > 0.0);
            let m = v["median_depth_m"].as_f64().unwrap_or(f64::NAN);
            (i, m - truth, v["valid_fraction"].as_f64().unwrap())
        })
        .collect()
}

#[test]
fn calibrate_then_process_is_within_1_cm() {
    let t = tempfile::tempdir().unwrap();
    let calib = t.path().join("calib");
    for what in ["fpn", "wiggling", "fppn"] {
        let o = calibrate(what, &calib, &[]);
        assert_ok(&o);
    }
    let set = tofprox_format::CalibrationSet::load(&calib).unwrap();
    assert_eq!(
        set.parts(),
        module_parts(),
        "one set with every part but the lens and the cover window's crosstalk"
    );
    for (algo, n) in [("2phase", 6), ("4phase", 5)] {
        let out = t.path().join(algo);
        let errs = process_errors(Some(&calib), algo, &out);
        assert_eq!(errs.len(), n, "{algo}: {errs:?}");
        for (i, e, valid) in &errs {
            assert!(
                e.abs() < 0.01,
                "{algo} capture {i}: error {:.1} mm",
                e * 1000.0
            );
            assert!(*valid > 0.95, "{algo} capture {i}: valid {valid}");
        }
        // outputs: depth (u16 mm), amplitude (f32), PNG preview per capture
        let (i, e, _) = errs[0];
        let d = npy::decode(&fs::read(out.join(format!("{i:06}_depth_mm.npy"))).unwrap()).unwrap();
        let npy::NpyArray::U16(d) = d else {
            panic!("depth is not uint16")
        };
        assert_eq!(d.shape(), &[16, 16]);
        let truth_mm = (e + Recording::open(&example_rec()).unwrap().captures()[i as usize]
            .distance_m()
            .unwrap())
            * 1000.0;
        let mut v: Vec<u16> = d.iter().copied().collect();
        v.sort_unstable();
        assert!(
            (f64::from(v[128]) - truth_mm).abs() < 3.0,
            "{} vs {truth_mm}",
            v[128]
        );
        let a =
            npy::decode(&fs::read(out.join(format!("{i:06}_amplitude_lsb.npy"))).unwrap()).unwrap();
        assert!(matches!(a, npy::NpyArray::F32(ref a) if a.iter().all(|x| *x > 10.0)));
        let png = fs::read(out.join(format!("{i:06}_depth.png"))).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    }
    // the shipped calibration gives the same quality
    let shipped = repo().join("calib/example");
    for algo in ["2phase", "4phase"] {
        for (i, e, _) in process_errors(Some(&shipped), algo, &t.path().join("shipped")) {
            assert!(
                e.abs() < 0.01,
                "calib/example {algo} capture {i}: error {:.1} mm",
                e * 1000.0
            );
        }
    }
    // without calibration the 2-phase depth is unusable (FPN + delay + wiggling)
    let raw = process_errors(None, "2phase", &t.path().join("raw"));
    assert!(raw.iter().all(|(_, e, _)| e.abs() > 0.05), "{raw:?}");
}

#[test]
fn calibrate_merges_and_drops_stale_parts() {
    let t = tempfile::tempdir().unwrap();
    let calib = t.path().join("c");
    assert_ok(&calibrate("fpn", &calib, &[]));
    let o = calibrate("wiggling", &calib, &["--lut-size", "64"]);
    assert_ok(&o);
    assert!(
        stdout(&o).contains("set now holds: offset, wiggling_2phase, wiggling_4phase"),
        "{}",
        stdout(&o)
    );
    let text = fs::read_to_string(calib.join("calibration.toml")).unwrap();
    assert!(text.contains("lut_size = 64"), "{text}");
    // a new offset invalidates the wiggling tables extracted with the old one
    let o = calibrate("fpn", &calib, &["--capture", "0"]);
    assert_ok(&o);
    // same data gives the same offset: nothing is dropped
    assert!(!stderr(&o).contains("dropped"), "{}", stderr(&o));
    // --calib reads from one set and writes another
    let other = t.path().join("other");
    let o = calibrate("fppn", &other, &["--calib", p(&calib)]);
    assert_ok(&o);
    assert_eq!(
        tofprox_format::CalibrationSet::load(&other)
            .unwrap()
            .parts(),
        module_parts()
    );
    // the source set is untouched: offset, both wiggling tables and the amplitude scale that
    // `calibrate wiggling` extracts from the same correlation capture (thesis 2.2.1)
    let mut source_parts = tofprox_format::CalibrationSet::load(&calib)
        .unwrap()
        .parts();
    source_parts.sort_by_key(|part| part.name());
    assert_eq!(
        source_parts,
        vec![
            CalibPart::Amplitude,
            CalibPart::Offset,
            CalibPart::Wiggling2Phase,
            CalibPart::Wiggling4Phase
        ]
    );
    // new wiggling tables make both FPPN maps stale: they are dropped with a note
    let o = calibrate("wiggling", &other, &["--lut-size", "128"]);
    assert_ok(&o);
    assert!(stderr(&o).contains("dropped fppn"), "{}", stderr(&o));
    assert!(stderr(&o).contains("dropped fppn_2phase"), "{}", stderr(&o));
    assert_eq!(
        tofprox_format::CalibrationSet::load(&other)
            .unwrap()
            .parts(),
        vec![
            CalibPart::Offset,
            CalibPart::Wiggling2Phase,
            CalibPart::Wiggling4Phase,
            CalibPart::Amplitude
        ]
    );
    assert!(!other.join("fppn.npy").exists());
}

#[test]
fn calibrate_refuses_unsuitable_captures() {
    let o = calibrate("wiggling", Path::new("/nonexistent/x"), &["--capture", "2"]);
    assert_bad(&o, &["--capture 2", "correlation"]);
    let o = calibrate("fpn", Path::new("/nonexistent/x"), &["--capture", "3"]);
    assert_bad(&o, &["--capture 3", "illumination"]);
    let o = calibrate("fppn", Path::new("/nonexistent/x"), &["--capture", "99"]);
    assert_bad(&o, &["--capture 99"]);
    let t = tempfile::tempdir().unwrap();
    let rec = rec_copy(&t);
    // no ground truth: the wiggling table cannot be anchored
    let toml = rec.join("recording.toml");
    let text = fs::read_to_string(&toml)
        .unwrap()
        .replace("distance_m = 0.5\n", "");
    fs::write(&toml, text).unwrap();
    let o = run(&[
        "calibrate",
        "wiggling",
        p(&rec),
        "--out",
        p(&t.path().join("c")),
    ]);
    assert_bad(&o, &["distance_m"]);
    assert!(!t.path().join("c").exists(), "nothing written on error");
}

// ------------------------------------------------------------ bad input

/// Run `info` and `process` (2phase: reads captures 2..=7) on a broken copy
/// of the example; both must fail cleanly.
fn broken(mutate: impl FnOnce(&Path), needles: &[&str]) {
    let t = tempfile::tempdir().unwrap();
    let rec = rec_copy(&t);
    mutate(&rec);
    assert_bad(&run(&["info", p(&rec)]), needles);
    let out = t.path().join("out");
    let calib = repo().join("calib/example");
    assert_bad(
        &process(p(&rec), p(&calib), "2phase", p(&out), &[]),
        needles,
    );
}

#[test]
fn bad_frames_files() {
    // truncated
    broken(
        |r| {
            let f = r.join("frames/000003.npy");
            let b = fs::read(&f).unwrap();
            fs::write(&f, &b[..b.len() - 100]).unwrap();
        },
        &["000003.npy", "capture[3].frames", "truncated"],
    );
    // wrong dtype (int16)
    broken(
        |r| {
            let f = r.join("frames/000002.npy");
            let b = npy::encode_u16(&Array3::<u16>::zeros((4, 16, 16)));
            let s = b.windows(3).position(|w| w == b"<u2").unwrap();
            let mut b = b.clone();
            b[s..s + 3].copy_from_slice(b"<i2");
            fs::write(f, b).unwrap();
        },
        &["000002.npy", "'<i2'"],
    );
    // NaN in a float capture
    broken(
        |r| {
            let mut a = Array3::<f32>::from_elem((4, 16, 16), 2048.0);
            a[[1, 2, 3]] = f32::NAN;
            fs::write(r.join("frames/000004.npy"), npy::encode_f32(&a)).unwrap();
        },
        &["000004.npy", "NaN", "image 1, pixel (row 2, col 3)"],
    );
    // mismatched shape
    broken(
        |r| {
            let a = Array3::<f32>::from_elem((4, 16, 15), 2048.0);
            fs::write(r.join("frames/000005.npy"), npy::encode_f32(&a)).unwrap();
        },
        &["000005.npy", "(4, 16, 15)", "16×16"],
    );
    // missing frames file
    broken(
        |r| fs::remove_file(r.join("frames/000006.npy")).unwrap(),
        &["000006.npy", "capture[6].frames"],
    );
    // code above 2^adc_bits - 1 in the uint16 capture
    broken(
        |r| {
            let a = Array3::<u16>::from_elem((2, 16, 16), 5000);
            fs::write(r.join("frames/000007.npy"), npy::encode_u16(&a)).unwrap();
        },
        &["000007.npy", "5000 exceeds"],
    );
    // random bytes
    broken(
        |r| fs::write(r.join("frames/000002.npy"), b"\x93NUMPY\x01\x00garbage").unwrap(),
        &["000002.npy"],
    );
}

#[test]
fn bad_recording_toml() {
    let toml = |r: &Path| r.join("recording.toml");
    // one edit of the example's recording.toml, then `broken`
    let broken_toml =
        |from: &str, to: &str, needles: &[&str]| broken(|r| edit(&toml(r), from, to), needles);
    broken_toml(
        "adc_bits = 12\n",
        "",
        &["recording.toml", "missing field `adc_bits`"],
    );
    broken_toml(
        "averaged = 64\n",
        "averaged = 64\ngain = 2\n",
        &["recording.toml", "unknown field `gain`"],
    );
    broken_toml(
        "format = \"tofprox-recording\"",
        "format = \"something\"",
        &["recording.toml", "format", "not a tofprox recording"],
    );
    broken_toml(
        "version = 1",
        "version = 4",
        &["recording.toml", "version", "version 4 is not supported"],
    );
    broken_toml(
        "phases_deg = [0.0, 90.0]\n",
        "phases_deg = [0.0, 90.0, 180.0, 270.0]\n",
        &["000007.npy", "capture[7].frames", "phases_deg lists 4"],
    );
    broken_toml(
        "rows = 16",
        "rows = 8",
        &["000000.npy", "sensor window is 8×16"],
    );
    broken_toml(
        "adc_bits = 12",
        "adc_bits = 40",
        &["recording.toml", "sensor.adc_bits"],
    );
    broken_toml(
        "distance_m = 0.5",
        "distance_m = \"far\"",
        &["recording.toml", "distance_m"],
    );
    broken(
        |r| fs::write(toml(r), "this is [not toml").unwrap(),
        &["recording.toml"],
    );
    broken(|r| fs::remove_file(toml(r)).unwrap(), &["recording.toml"]);
    assert_bad(
        &run(&["info", "/nonexistent/recording"]),
        &["/nonexistent/recording"],
    );
}

#[test]
fn bad_calibration() {
    let t = tempfile::tempdir().unwrap();
    let calib = t.path().join("calib");
    copy_dir(&repo().join("calib/example"), &calib);
    let out = t.path().join("out");
    let process_copy = |rec: &Path, algo: &str| process(p(rec), p(&calib), algo, p(&out), &[]);
    // checksum mismatch: one flipped bit in an array
    let f = calib.join("wiggling_2phase.npy");
    let mut b = fs::read(&f).unwrap();
    let n = b.len();
    b[n - 5] ^= 0x10;
    fs::write(&f, &b).unwrap();
    assert_bad(
        &process_copy(&example_rec(), "2phase"),
        &[
            "wiggling_2phase.npy",
            "wiggling_2phase.sha256",
            "SHA-256 mismatch",
        ],
    );
    b[n - 5] ^= 0x10;
    fs::write(&f, &b).unwrap();
    assert_ok(&process_copy(&example_rec(), "2phase"));

    // data of another modulation frequency / window / ADC
    let rec = t.path().join("rec");
    copy_dir(&example_rec(), &rec);
    let toml = rec.join("recording.toml");
    edit(
        &toml,
        "modulation_hz = 80000000.0",
        "modulation_hz = 60000000.0",
    );
    assert_bad(
        &process_copy(&rec, "4phase"),
        &[
            "calibration.toml",
            "modulation_hz",
            "80000000 Hz",
            "60000000 Hz",
        ],
    );
    edit(
        &toml,
        "modulation_hz = 60000000.0",
        "modulation_hz = 80000000.0",
    );
    edit(&toml, "roi_origin = [78, 104]", "roi_origin = [0, 0]");
    assert_bad(
        &process_copy(&rec, "4phase"),
        &["calibration.toml", "roi_origin"],
    );
    edit(&toml, "roi_origin = [0, 0]", "roi_origin = [78, 104]");
    edit(&toml, "adc_bits = 12", "adc_bits = 14");
    assert_bad(&process_copy(&rec, "4phase"), &["adc_bits"]);
    // adding to an incompatible set is refused too
    assert_bad(
        &run(&["calibrate", "fpn", p(&rec), "--out", p(&calib)]),
        &["calibration.toml", "adc_bits"],
    );

    // broken calibration.toml
    let ct = calib.join("calibration.toml");
    edit(&ct, "lut_size = 256", "lut_size = 128");
    assert_bad(
        &process_copy(&example_rec(), "2phase"),
        &["calibration.toml", "wiggling_2phase.lut_size"],
    );
    edit(&ct, "lut_size = 128", "lut_size = 256");
    edit(&ct, "[valid_for]\n", "[valid_for]\ntemperature_c = 30\n");
    assert_bad(
        &process_copy(&example_rec(), "2phase"),
        &["calibration.toml", "unknown field `temperature_c`"],
    );
    assert_bad(
        &process(
            "examples/recording",
            "/nonexistent/calib",
            "2phase",
            p(&out),
            &[],
        ),
        &["/nonexistent/calib"],
    );
}

#[test]
fn process_refuses_what_it_cannot_process() {
    let t = tempfile::tempdir().unwrap();
    let rec = rec_copy(&t);
    // keep only the dark capture and the 2-phase one
    let toml = rec.join("recording.toml");
    let text = fs::read_to_string(&toml).unwrap();
    let parts: Vec<&str> = text.split("[[capture]]").collect();
    let kept = format!("{}[[capture]]{}[[capture]]{}", parts[0], parts[1], parts[8]);
    fs::write(&toml, kept).unwrap();
    let o = process(
        p(&rec),
        "calib/example",
        "4phase",
        p(&t.path().join("o")),
        &[],
    );
    assert_bad(
        &o,
        &["no illuminated capture that can be processed as 4phase"],
    );
    let o = process(
        p(&rec),
        "calib/example",
        "2phase",
        p(&t.path().join("o")),
        &["--json"],
    );
    assert_ok(&o);
    let lines = json_lines(&o);
    assert_eq!(lines.len(), 1);
    assert_eq!(lines[0]["index"], 1);
    // the correlation capture is skipped with a note on stderr
    let o = process(
        "examples/recording",
        "calib/example",
        "4phase",
        p(&t.path().join("o2")),
        &["--json"],
    );
    assert_ok(&o);
    assert!(stderr(&o).contains("skipping capture 1"), "{}", stderr(&o));
    assert!(stderr(&o).contains("skipping capture 7"), "{}", stderr(&o));
    let bad_algo = run(&[
        "process",
        "examples/recording",
        "--algo",
        "3phase",
        "--out",
        p(&t.path().join("o3")),
    ]);
    assert_eq!(bad_algo.status.code(), Some(2));
    assert!(!stderr(&bad_algo).contains("panicked"));
}

#[test]
fn info_on_a_calibration_set() {
    let calib = repo().join("calib/example");
    info_text_has(
        &calib,
        &[
            "checksums verified",
            "16×16 window at (row 78, col 104) of a 172×224 array, 12-bit ADC, 80 MHz",
            "offset           dark level",
            "wiggling_2phase",
            "256 bins",
            "fppn_2phase",
            "from examples/recording captures [1] at 0.5 m",
        ],
    );
    let v = info_json(&calib);
    assert_eq!(v["valid_for"]["adc_bits"], 12);
    // complete: offset, both wiggling tables, both FPPN maps and the amplitude scale
    assert_eq!(v["parts"].as_object().unwrap().len(), 6);
    assert_eq!(v["complete"], true);
    // the FPN of the example is σ ≈ 34 LSB around the mid code
    let sd = v["parts"]["offset"]["std"].as_f64().unwrap();
    assert!((25.0..45.0).contains(&sd), "{sd}");
    // a damaged set is refused
    let t = tempfile::tempdir().unwrap();
    let c = t.path().join("c");
    copy_dir(&calib, &c);
    fs::write(c.join("fppn.npy"), b"\x93NUMPY").unwrap();
    assert_bad(&run(&["info", p(&c)]), &["fppn.npy", "fppn.sha256"]);
}

// ---------------------------------------------------------------- hostile inputs (bounded reads)

/// `run` that fails the test instead of hanging: the process is killed after 60 s.
fn run_bounded(args: &[&str]) -> Output {
    let mut child = Command::new(bin())
        .args(args)
        .current_dir(repo())
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run tofprox");
    let t0 = std::time::Instant::now();
    while child.try_wait().expect("wait").is_none() {
        if t0.elapsed() > std::time::Duration::from_secs(60) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("tofprox {args:?} did not finish within 60 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.wait_with_output().expect("output")
}

fn mkfifo(path: &Path) {
    let _ = fs::remove_file(path);
    let st = Command::new("mkfifo").arg(path).status().expect("mkfifo");
    assert!(st.success());
}

/// A private copy of the shipped calibration set.
fn calib_copy(t: &tempfile::TempDir) -> PathBuf {
    let d = t.path().join("cal");
    copy_dir(&repo().join("calib/example"), &d);
    d
}

#[test]
fn a_device_or_oversized_header_is_refused_not_read_whole() {
    let t = tempfile::tempdir().unwrap();
    let rec = rec_copy(&t);
    let toml = rec.join("recording.toml");
    fs::remove_file(&toml).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &toml).unwrap();
    assert_bad(
        &run_bounded(&["info", p(&rec)]),
        &["recording.toml", "character device"],
    );
    // a header above the documented limit (4 MiB)
    fs::remove_file(&toml).unwrap();
    fs::copy(example_rec().join("recording.toml"), &toml).unwrap();
    let mut text = fs::read_to_string(&toml).unwrap();
    text.push_str(&format!("# {}\n", "x".repeat(5 << 20)));
    fs::write(&toml, text).unwrap();
    assert_bad(
        &run_bounded(&["info", p(&rec)]),
        &["recording.toml", "limit of 4194304 bytes"],
    );
}

#[test]
fn a_long_description_and_too_many_captures_are_refused() {
    let t = tempfile::tempdir().unwrap();
    let rec = rec_copy(&t);
    let toml = rec.join("recording.toml");
    let text = fs::read_to_string(&toml).unwrap();
    let long = format!("description = \"{}\"\n", "d".repeat(100_000));
    let body: String = text
        .lines()
        .filter(|l| !l.starts_with("description"))
        .map(|l| format!("{l}\n"))
        .collect();
    let (head, rest) = body.split_once("[sensor]").unwrap();
    fs::write(&toml, format!("{head}{long}[sensor]{rest}")).unwrap();
    assert_bad(
        &run_bounded(&["info", p(&rec)]),
        &["recording.toml", "description", "limit"],
    );
    // 33 000 captures (limit 32 768) in < 4 MiB: refused before any frames file is looked at
    let mut many = format!(
        "{head}[sensor]{}",
        rest.split("[[capture]]").next().unwrap()
    );
    for i in 0..33_000 {
        many.push_str(&format!(
            "[[capture]]\nframes=\"f/{i}.npy\"\nphases_deg=[0]\nexposure_us=1\nillumination=false\naveraged=1\n"
        ));
    }
    assert!(many.len() < 4 << 20);
    fs::write(&toml, many).unwrap();
    assert_bad(
        &run_bounded(&["info", p(&rec)]),
        &[
            "recording.toml",
            "capture",
            "33000 captures, more than the limit of 32768",
        ],
    );
}

#[test]
fn fifos_are_refused_without_hanging() {
    let t = tempfile::tempdir().unwrap();
    let rec = rec_copy(&t);
    mkfifo(&rec.join("frames/000002.npy"));
    assert_bad(
        &run_bounded(&["info", p(&rec)]),
        &["frames/000002.npy", "capture[2].frames", "a FIFO"],
    );
    let rec2 = t.path().join("rec2");
    copy_dir(&example_rec(), &rec2);
    mkfifo(&rec2.join("recording.toml"));
    assert_bad(
        &run_bounded(&["info", p(&rec2)]),
        &["recording.toml", "a FIFO"],
    );
    let cal = calib_copy(&t);
    mkfifo(&cal.join("offset.npy"));
    assert_bad(
        &run_bounded(&["info", p(&cal)]),
        &["offset.npy", "offset", "a FIFO"],
    );
}

#[test]
fn symlinks_out_of_the_recording_or_set_are_refused() {
    let t = tempfile::tempdir().unwrap();
    // the frames directory is a symlink to outside
    let rec = rec_copy(&t);
    let outside = t.path().join("elsewhere");
    fs::rename(rec.join("frames"), &outside).unwrap();
    std::os::unix::fs::symlink(&outside, rec.join("frames")).unwrap();
    assert_bad(
        &run_bounded(&["info", p(&rec)]),
        &["frames/000000.npy", "capture[0].frames", "outside"],
    );
    // one frames file is a symlink to outside
    let rec2 = t.path().join("rec2");
    copy_dir(&example_rec(), &rec2);
    let f = rec2.join("frames/000001.npy");
    fs::rename(&f, t.path().join("stolen.npy")).unwrap();
    std::os::unix::fs::symlink(t.path().join("stolen.npy"), &f).unwrap();
    assert_bad(
        &run_bounded(&["info", p(&rec2)]),
        &["frames/000001.npy", "capture[1].frames", "outside"],
    );
    // a calibration array that is a symlink to outside
    let cal = calib_copy(&t);
    fs::rename(cal.join("fppn.npy"), t.path().join("fppn.npy")).unwrap();
    std::os::unix::fs::symlink(t.path().join("fppn.npy"), cal.join("fppn.npy")).unwrap();
    assert_bad(
        &run_bounded(&["info", p(&cal)]),
        &["fppn.npy", "fppn", "outside"],
    );
}

/// A frames file that is a hard link of another capture's (same device and inode) is
/// refused like a symlinked duplicate.
#[test]
fn a_hard_linked_duplicate_capture_is_refused() {
    let t = tempfile::tempdir().unwrap();
    let rec = rec_copy(&t);
    fs::remove_file(rec.join("frames/000003.npy")).unwrap();
    fs::hard_link(rec.join("frames/000002.npy"), rec.join("frames/000003.npy")).unwrap();
    assert_bad(
        &run_bounded(&["info", p(&rec)]),
        &["capture[3].frames", "is the same file as capture[2].frames"],
    );
}

/// Outputs never follow a planted link: `process --out DIR` into a directory holding
/// `000000_depth_mm.npy -> ../victim`, and `calibrate fpn --out SET` with a planted
/// `SET/offset.npy.tmp -> victim`, leave the victim as it was; the link is replaced by the
/// output and the set loads.
#[test]
fn writers_replace_planted_links_without_following_them() {
    let t = tempfile::tempdir().unwrap();
    let victim = t.path().join("victim");
    fs::write(&victim, b"precious").unwrap();
    let out = t.path().join("out");
    fs::create_dir(&out).unwrap();
    // a link at every capture's output names (capture 0, a dark one, is not processed)
    let planted: Vec<String> = (0..8)
        .flat_map(|i| [format!("{i:06}_depth_mm.npy"), format!("{i:06}_depth.png")])
        .collect();
    for name in &planted {
        std::os::unix::fs::symlink("../victim", out.join(name)).unwrap();
    }
    let calib = t.path().join("cal");
    assert_ok(&calibrate("fpn", &calib, &[]));
    std::os::unix::fs::symlink(&victim, calib.join("offset.npy.tmp")).unwrap();
    assert_ok(&calibrate("fpn", &calib, &[]));
    assert_eq!(
        fs::read(&victim).unwrap(),
        b"precious",
        "calibrate wrote through the link"
    );
    info_text_has(&calib, &["offset"]);
    assert_ok(&process(
        "examples/recording",
        p(&calib),
        "4phase",
        p(&out),
        &[],
    ));
    assert_eq!(
        fs::read(&victim).unwrap(),
        b"precious",
        "process wrote through the link"
    );
    let replaced = planted
        .iter()
        .filter(|name| fs::symlink_metadata(out.join(name)).unwrap().is_file())
        .count();
    assert!(
        replaced >= 2,
        "the outputs replaced the planted links ({replaced})"
    );
}

#[test]
fn duplicate_captures_are_found_through_dot_and_double_slash() {
    let t = tempfile::tempdir().unwrap();
    for alias in ["frames/./000002.npy", "frames//000002.npy"] {
        let rec = rec_copy(&t);
        edit(
            &rec.join("recording.toml"),
            "frames = \"frames/000003.npy\"",
            &format!("frames = \"{alias}\""),
        );
        assert_bad(
            &run_bounded(&["info", p(&rec)]),
            &["recording.toml", "capture[3].frames", "already used"],
        );
        fs::remove_dir_all(&rec).unwrap();
    }
}

#[test]
fn a_huge_sensor_window_is_refused_before_anything_is_allocated() {
    let t = tempfile::tempdir().unwrap();
    let rec = t.path().join("huge");
    fs::create_dir(&rec).unwrap();
    fs::write(
        rec.join("recording.toml"),
        "format = \"tofprox-recording\"\nversion = 1\n[sensor]\nrows = 8192\ncols = 8192\nadc_bits = 12\nmodulation_hz = 80e6\n",
    )
    .unwrap();
    let out = t.path().join("out");
    assert_bad(
        &run_bounded(&["process", p(&rec), "--algo", "4phase", "--out", p(&out)]),
        &[
            "recording.toml",
            // the documented limits are checked before the geometry's own rules
            "sensor.rows",
            "8192 is more than the limit of 4096",
        ],
    );
}

#[test]
fn absurd_phase_tables_are_refused() {
    use tofprox_core::calib::WigglingLut;
    let t = tempfile::tempdir().unwrap();
    let mut set = tofprox_format::CalibrationSet::load(&repo().join("calib/example")).unwrap();
    set.set_wiggling(
        WigglingLut {
            algorithm: tofprox_core::Algorithm::TwoPhase,
            correction_rad: ndarray::Array1::from_elem(256, 1e30),
        },
        Default::default(),
    )
    .unwrap();
    let cal = t.path().join("cal");
    set.save(&cal).unwrap();
    assert_bad(
        &run_bounded(&["info", p(&cal)]),
        &[
            "wiggling_2phase.npy",
            "wiggling_2phase",
            "beyond one period",
        ],
    );
}

#[test]
fn dependency_checksums_are_required_and_compare_in_any_case() {
    let t = tempfile::tempdir().unwrap();
    let cal = calib_copy(&t);
    let toml = cal.join("calibration.toml");
    let original = fs::read_to_string(&toml).unwrap();
    // deleting the dependency checksums must not switch the staleness check off
    let stripped: String = original
        .lines()
        .filter(|l| !l.starts_with("offset_sha256"))
        .map(|l| format!("{l}\n"))
        .collect();
    fs::write(&toml, stripped).unwrap();
    assert_bad(
        &run_bounded(&["info", p(&cal)]),
        &[
            "calibration.toml",
            "wiggling_2phase.offset_sha256",
            "missing",
        ],
    );
    // upper-case hex digests are the same digests
    let upper: String = original
        .lines()
        .map(|l| match l.split_once(" = \"") {
            Some((k, v)) if k.ends_with("sha256") => format!("{k} = \"{}", v.to_uppercase()),
            _ => l.to_string(),
        })
        .map(|l| format!("{l}\n"))
        .collect();
    fs::write(&toml, upper).unwrap();
    let o = run_bounded(&["info", p(&cal)]);
    assert_ok(&o);
}

/// Every part but `intrinsics` and `crosstalk`: what the example recording gives.
fn module_parts() -> Vec<CalibPart> {
    // the example has no lens sweep (`calibrate intrinsics`) and no capture with nothing in
    // range (`calibrate crosstalk`)
    CalibPart::ALL
        .into_iter()
        .filter(|p| !matches!(p, CalibPart::Crosstalk | CalibPart::Intrinsics))
        .collect()
}

/// What `tofprox record` writes: a depth recording (format version 2, `kind = "depth"`), read
/// as depth by `info` and refused by every command that needs raw phase images, naming the
/// file and the key.
#[test]
fn a_depth_recording_is_read_as_depth_and_refused_by_raw_commands() {
    use tofprox_format::{DepthImageSize, DepthRecordingWriter};
    let t = tempfile::tempdir().unwrap();
    let rec = t.path().join("depth");
    let size = DepthImageSize { rows: 4, cols: 6 };
    let mut w = DepthRecordingWriter::create(&rec, size, None, false).unwrap();
    for (i, mm) in [250u16, 260, 0].into_iter().enumerate() {
        let d = ndarray::Array2::from_elem((4, 6), mm);
        let amp = ndarray::Array2::from_elem((4, 6), 900u16);
        w.append(Some(1_000_000_000 + 100_000_000 * i as u64), &d, Some(&amp))
            .unwrap();
    }
    w.finish().unwrap();
    let o = run(&["info", p(&rec), "--json"]);
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(stdout(&o).trim()).unwrap();
    assert_eq!(v["kind"], "depth");
    assert_eq!(v["captures"], 3);
    assert_eq!(v["depth"]["cols"], 6);
    assert_eq!(v["per_capture"][0]["median_depth_mm"], 250);
    assert_eq!(v["per_capture"][2]["valid_fraction"], 0.0);
    assert!((v["rate_hz"].as_f64().unwrap() - 10.0).abs() < 1e-9, "{v}");
    let o = run(&["info", p(&rec)]);
    assert_ok(&o);
    assert!(stdout(&o).contains("depth images"), "{}", stdout(&o));

    let toml = format!("{}", rec.join("recording.toml").display());
    let calib = t.path().join("calib");
    let o = run(&["calibrate", "fpn", p(&rec), "--out", p(&calib)]);
    assert_bad(&o, &[&toml, "kind", "depth recording"]);
    assert!(!calib.exists(), "nothing written");
    let out = t.path().join("out");
    let o = run(&["process", p(&rec), "--algo", "4phase", "--out", p(&out)]);
    assert_bad(&o, &[&toml, "kind", "depth recording"]);
    let o = run(&[
        "lab",
        "compare",
        p(&rec),
        "--model",
        "config/model/baseline.toml",
    ]);
    assert_bad(&o, &[&toml, "kind", "depth recording"]);
}

/// A raw recording of 2×3 pixels: one 2-phase capture of mid codes, with second-frequency
/// images at 60 MHz, written and finished (`finish: false` leaves it as a writer killed
/// part-way does).
fn second_frequency_rec(dir: &Path, finish: bool) {
    use tofprox_core::SensorGeometry;
    use tofprox_format::{CaptureSpec, RawFrames, RecordingWriter, SecondFrequencyFrames};
    let mut w = RecordingWriter::create(dir, SensorGeometry::full(2, 3, 12, 80e6), None).unwrap();
    let spec = CaptureSpec {
        phases_deg: vec![0.0, 90.0],
        exposure_us: 500.0,
        illumination: true,
        averaged: 4,
        timestamp_ns: None,
        conditions: Default::default(),
    };
    let f = RawFrames::F32(Array3::from_elem((2, 2, 3), 2048.5f32));
    let second = SecondFrequencyFrames {
        modulation_hz: 60e6,
        phases_deg: vec![0.0, 90.0],
        frames: f.clone(),
    };
    w.append_with_second(spec, &f, Some(&second)).unwrap();
    if finish {
        w.finish().unwrap();
    }
}

/// Issue 35 W5: `tofprox info` checks the second-frequency images as the daemon's replay
/// does: NaN, an infinity or a code above the ADC's range there is refused, naming the file
/// and the key (it was accepted).
#[test]
fn info_refuses_bad_second_frequency_images() {
    let t = tempfile::tempdir().unwrap();
    for (name, bad) in [("nan", f32::NAN), ("inf", f32::INFINITY), ("range", 5000.0)] {
        let rec = t.path().join(name);
        second_frequency_rec(&rec, true);
        assert_ok(&run(&["info", p(&rec)]));
        let second = Recording::open(&rec).unwrap().captures()[0]
            .second_frequency
            .clone()
            .unwrap();
        let mut a = Array3::from_elem((2, 2, 3), 2048.5f32);
        a[[1, 1, 2]] = bad;
        fs::write(rec.join(&second.frames), npy::encode_f32(&a)).unwrap();
        let o = run(&["info", p(&rec)]);
        assert_bad(&o, &["capture[0].second_frequency.frames"]);
        assert!(
            stderr(&o).contains(&second.frames),
            "{name}: {}",
            stderr(&o)
        );
    }
}

/// Issue 35 W1: a recording whose writer did not finish is flagged by `tofprox info` (text,
/// JSON, stderr) and refused by processing with a clear error; finished, it is complete.
#[test]
fn an_unfinished_recording_is_flagged_by_info_and_refused_by_process() {
    let t = tempfile::tempdir().unwrap();
    let rec = t.path().join("killed");
    second_frequency_rec(&rec, false);
    let o = run(&["info", p(&rec)]);
    assert_ok(&o);
    assert!(stdout(&o).contains("complete    NO"), "{}", stdout(&o));
    assert!(
        stderr(&o).contains("INCOMPLETE recording"),
        "{}",
        stderr(&o)
    );
    assert_eq!(info_json(&rec)["complete"], false);
    let out = t.path().join("out");
    let o = run(&["process", p(&rec), "--algo", "2phase", "--out", p(&out)]);
    assert_bad(&o, &["is incomplete", "1 capture(s) written whole"]);
    let done = t.path().join("done");
    second_frequency_rec(&done, true);
    assert_eq!(info_json(&done)["complete"], true);
    assert!(stdout(&run(&["info", p(&done)])).contains("complete    yes"));
}
