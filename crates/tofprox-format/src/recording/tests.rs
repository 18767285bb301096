use super::*;
use crate::npy;
use ndarray::Array3;
use proptest::prelude::*;
use std::time::Duration;

fn sensor() -> SensorGeometry {
    SensorGeometry {
        rows: 4,
        cols: 5,
        roi_origin: [10, 20],
        full_rows: 172,
        full_cols: 224,
        adc_bits: 12,
        modulation_hz: 80e6,
    }
}

fn spec(phases: &[f64], illumination: bool) -> CaptureSpec {
    let mut conditions = BTreeMap::new();
    conditions.insert("distance_m".to_string(), 0.35);
    conditions.insert("my_custom_key".to_string(), -1.5);
    CaptureSpec {
        phases_deg: phases.to_vec(),
        exposure_us: 500.0,
        illumination,
        averaged: 16,
        timestamp_ns: Some(123),
        conditions,
    }
}

/// Deterministic content for capture `seed`.
fn frames_f32(k: usize, seed: usize) -> Array3<f32> {
    Array3::from_shape_fn((k, 4, 5), |(a, r, c)| {
        ((seed * 131 + a * 17 + r * 5 + c) % 4000) as f32 + 0.25
    })
}

fn make_rec(dir: &Path) -> Recording {
    let mut w = RecordingWriter::create(dir, sensor(), Some("test rec".into())).unwrap();
    w.append(
        spec(&[0.0, 90.0, 180.0, 270.0], true),
        &RawFrames::F32(frames_f32(4, 0)),
    )
    .unwrap();
    let u = Array3::from_shape_fn((2, 4, 5), |(a, r, c)| (2048 + a * 3 + r + c) as u16);
    w.append(spec(&[0.0, 90.0], true), &RawFrames::U16(u))
        .unwrap();
    let d = Array3::from_elem((4, 4, 5), 2047.5f64);
    w.append(spec(&[0.0, 90.0, 180.0, 270.0], false), &RawFrames::F64(d))
        .unwrap();
    w.finish().unwrap();
    Recording::open(dir).unwrap()
}

#[test]
fn roundtrip_all_dtypes() {
    let t = tempfile::tempdir().unwrap();
    let rec = make_rec(t.path());
    assert_eq!(rec.sensor(), &sensor());
    assert_eq!(rec.description(), Some("test rec"));
    assert_eq!(rec.captures().len(), 3);
    assert_eq!(rec.captures()[0].frames, "frames/000000.npy");
    assert_eq!(rec.captures()[1].frames, "frames/000001.npy");
    assert_eq!(rec.captures()[0].conditions["my_custom_key"], -1.5);
    assert_eq!(rec.captures()[0].timestamp_ns, Some(123));
    assert!(!rec.captures()[2].illumination);
    assert_eq!(rec.load(0).unwrap(), RawFrames::F32(frames_f32(4, 0)));
    assert_eq!(rec.load(1).unwrap().dtype(), Dtype::U16);
    assert_eq!(rec.load(2).unwrap().dim(), (4, 4, 5));
    assert_eq!(rec.dtype(2), Some(Dtype::F64));
    assert!(rec.load(3).is_err());
}

#[test]
fn issue_example_parses_with_defaults_and_integer_numbers() {
    let t = tempfile::tempdir().unwrap();
    let text = r#"
format = "tofprox-recording"
version = 1

[sensor]
rows = 4
cols = 5
adc_bits = 12
modulation_hz = 80000000

[[capture]]
frames = "frames/a.npy"
phases_deg = [0, 90]
exposure_us = 500
illumination = true
averaged = 1
[capture.conditions]
distance_m = 1
temperature_c = 30.0
anything_else = 7
"#;
    fs::write(t.path().join(RECORDING_TOML), text).unwrap();
    fs::create_dir(t.path().join("frames")).unwrap();
    let a = Array3::<u16>::from_elem((2, 4, 5), 2048);
    fs::write(t.path().join("frames/a.npy"), npy::encode_u16(&a)).unwrap();
    let rec = Recording::open(t.path()).unwrap();
    let s = rec.sensor();
    assert_eq!((s.roi_origin, s.full_rows, s.full_cols), ([0, 0], 4, 5));
    assert_eq!(s.modulation_hz, 80e6);
    let c = &rec.captures()[0];
    assert_eq!(c.phases_deg, vec![0.0, 90.0]);
    assert_eq!(c.conditions["anything_else"], 7.0);
    assert_eq!(c.distance_m(), Some(1.0));
    assert!(c.starts_two_phase() && !c.is_four_phase());
    assert_eq!(rec.description(), None);
}

/// Write `rec` then apply `edit` to recording.toml and return the open error.
fn open_err_after(edit: impl FnOnce(&str) -> String) -> FormatError {
    let t = tempfile::tempdir().unwrap();
    make_rec(t.path());
    let p = t.path().join(RECORDING_TOML);
    let text = fs::read_to_string(&p).unwrap();
    let new = edit(&text);
    assert_ne!(new, text, "edit did not change the file");
    fs::write(&p, new).unwrap();
    let e = Recording::open(t.path()).unwrap_err();
    assert!(e.to_string().contains("recording.toml"), "{e}");
    e
}

#[test]
fn toml_errors_name_the_key() {
    let e = open_err_after(|t| t.replace("averaged = 16\n", "averaged = 16\nbogus_key = 1\n"));
    assert_eq!(e.kind(), ErrorKind::UnknownKey);
    assert!(e.to_string().contains("bogus_key"), "{e}");
    assert_eq!(e.key_name(), Some("capture[0].bogus_key"));
    let e = open_err_after(|t| {
        t.replacen(
            "illumination = false\n",
            "illumination = false\nbogus2 = 1\n",
            1,
        )
    });
    assert_eq!(e.key_name(), Some("capture[2].bogus2"), "{e}");

    let e = open_err_after(|t| t.replace("[sensor]\n", "[sensor]\nlens = 3\n"));
    assert!(e.to_string().contains("lens"), "{e}");
    assert_eq!(e.key_name(), Some("sensor.lens"));

    let e = open_err_after(|t| t.replace("version = 3\n", "version = 3\nextra = \"x\"\n"));
    assert!(e.to_string().contains("extra"), "{e}");

    let e = open_err_after(|t| t.replace("adc_bits = 12\n", ""));
    assert_eq!(e.kind(), ErrorKind::MissingKey);
    assert!(e.to_string().contains("adc_bits"), "{e}");
    assert_eq!(e.key_name(), Some("sensor.adc_bits"));

    let e = open_err_after(|t| t.replacen("exposure_us = 500.0\n", "", 1));
    assert!(e.to_string().contains("exposure_us"), "{e}");

    let e = open_err_after(|t| t.replace("version = 3", "version = 4"));
    assert_eq!(e.kind(), ErrorKind::Unsupported);
    assert_eq!(e.key_name(), Some("version"));
    assert!(e.to_string().contains("reads version 1 or 2 or 3"), "{e}");

    // version 2 says which kind of recording it is; version 1 did not
    let e = open_err_after(|t| t.replace("kind = \"raw\"\n", ""));
    assert_eq!(e.kind(), ErrorKind::MissingKey);
    assert_eq!(e.key_name(), Some("kind"));
    let e = open_err_after(|t| t.replace("version = 3", "version = 1"));
    assert_eq!(e.kind(), ErrorKind::UnknownKey);
    assert_eq!(e.key_name(), Some("kind"));

    let e = open_err_after(|t| t.replace("\"tofprox-recording\"", "\"something-else\""));
    assert_eq!(e.kind(), ErrorKind::Unsupported);
    assert_eq!(e.key_name(), Some("format"));

    let e = open_err_after(|t| t.replace("format = \"tofprox-recording\"\n", ""));
    assert_eq!(e.key_name(), Some("format"));

    let e = open_err_after(|t| t.replace("adc_bits = 12", "adc_bits = 17"));
    assert_eq!(e.key_name(), Some("sensor.adc_bits"));

    let e = open_err_after(|t| t.replace("modulation_hz = 80000000.0", "modulation_hz = -1.0"));
    assert_eq!(e.key_name(), Some("sensor.modulation_hz"));

    let e = open_err_after(|t| t.replace("full_rows = 172", "full_rows = 12"));
    assert_eq!(e.key_name(), Some("sensor.full_rows"));

    let e = open_err_after(|t| t.replacen("averaged = 16", "averaged = 0", 2));
    assert_eq!(e.key_name(), Some("capture[0].averaged"));

    let e = open_err_after(|t| t.replacen("my_custom_key = -1.5", "my_custom_key = \"text\"", 1));
    assert_eq!(e.kind(), ErrorKind::Syntax);
    assert!(e.to_string().contains("my_custom_key"), "{e}");
    // the key path of the value itself (serde_path_to_error), not only its table
    assert_eq!(
        e.key_name(),
        Some("capture[0].conditions.my_custom_key"),
        "{e}"
    );

    let e = open_err_after(|t| t.replacen("distance_m = 0.35", "distance_m = nan", 1));
    assert_eq!(e.key_name(), Some("capture[0].conditions.distance_m"));

    let e = open_err_after(|t| t.replacen("distance_m = 0.35", "distance_m = -0.35", 1));
    assert_eq!(e.key_name(), Some("capture[0].conditions.distance_m"));

    let e = open_err_after(|t| t.replace("frames/000001.npy", "../000001.npy"));
    assert_eq!(e.key_name(), Some("capture[1].frames"));

    let e = open_err_after(|t| t.replace("frames/000001.npy", "frames/000000.npy"));
    assert!(e.to_string().contains("already used"), "{e}");

    let e = open_err_after(|t| {
        t.replacen(
            "phases_deg = [0.0, 90.0, 180.0, 270.0]",
            "phases_deg = []",
            1,
        )
    });
    assert_eq!(e.key_name(), Some("capture[0].phases_deg"));

    let e = open_err_after(|t| format!("{t}\n[[[broken"));
    assert_eq!(e.kind(), ErrorKind::Syntax);
}

/// Replace capture `i`'s frames file with `bytes` and return the first error
/// of open + load.
fn file_err(i: usize, bytes: Vec<u8>) -> FormatError {
    let t = tempfile::tempdir().unwrap();
    let rec = make_rec(t.path());
    let p = rec.frames_path(i).unwrap();
    fs::write(&p, bytes).unwrap();
    let e = match Recording::open(t.path()) {
        Err(e) => e,
        Ok(r) => r.load(i).unwrap_err(),
    };
    assert!(
        e.to_string().contains(&format!("{:06}.npy", i)),
        "error does not name the file: {e}"
    );
    assert_eq!(
        e.key_name(),
        Some(format!("capture[{i}].frames").as_str()),
        "{e}"
    );
    e
}

#[test]
fn frame_file_errors_name_file_and_key() {
    let good = npy::encode_f32(&frames_f32(4, 0));
    let e = file_err(0, good[..good.len() - 10].to_vec());
    assert!(e.message().contains("truncated"), "{e}");

    let e = file_err(0, npy::encode_f32(&frames_f32(2, 0)));
    assert!(e.message().contains("phases_deg lists 4"), "{e}");

    let e = file_err(0, npy::encode_f32(&Array3::<f32>::zeros((4, 5, 4))));
    assert!(e.message().contains("sensor window is 4×5"), "{e}");

    let e = file_err(0, npy::encode_f32(&ndarray::Array2::<f32>::zeros((4, 20))));
    assert!(e.message().contains("3 dimensions"), "{e}");

    let s = npy::tests::replace_bytes(
        &npy::encode_u16(&Array3::<u16>::zeros((4, 4, 5))),
        b"<u2",
        b"<i2",
    );
    let e = file_err(0, s);
    assert!(e.message().contains("'<i2'"), "{e}");

    let mut nan = frames_f32(4, 0);
    nan[[2, 1, 3]] = f32::NAN;
    let e = file_err(0, npy::encode_f32(&nan));
    assert!(
        e.message().contains("NaN") && e.message().contains("image 2"),
        "{e}"
    );

    let mut inf = frames_f32(4, 0).mapv(f64::from);
    inf[[0, 0, 0]] = f64::INFINITY;
    let e = file_err(0, npy::encode_f64(&inf));
    assert!(e.message().contains("inf"), "{e}");

    let mut big = Array3::<u16>::from_elem((2, 4, 5), 100);
    big[[1, 3, 4]] = 4096;
    let e = file_err(1, npy::encode_u16(&big));
    assert!(e.message().contains("4096 exceeds"), "{e}");

    let e = file_err(1, b"garbage".to_vec());
    assert_eq!(e.kind(), ErrorKind::Npy);

    // missing file
    let t = tempfile::tempdir().unwrap();
    let rec = make_rec(t.path());
    fs::remove_file(rec.frames_path(1).unwrap()).unwrap();
    let e = Recording::open(t.path()).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Io);
    assert!(e.to_string().contains("000001.npy"), "{e}");
    assert_eq!(e.key_name(), Some("capture[1].frames"));

    // not a recording at all
    let e = Recording::open(&t.path().join("nope")).unwrap_err();
    assert!(e.to_string().contains("nope"), "{e}");
}

#[test]
fn writer_validates_before_touching_disk() {
    let t = tempfile::tempdir().unwrap();
    let mut w = RecordingWriter::create(t.path(), sensor(), None).unwrap();
    let e = w
        .append(spec(&[0.0, 90.0], true), &RawFrames::F32(frames_f32(4, 0)))
        .unwrap_err();
    assert_eq!(e.key_name(), Some("capture[0].frames"));
    let mut bad = frames_f32(2, 0);
    bad[[0, 0, 0]] = -3.0;
    assert!(
        w.append(spec(&[0.0, 90.0], true), &RawFrames::F32(bad))
            .is_err()
    );
    let mut s = spec(&[0.0, 90.0], true);
    s.exposure_us = f64::NAN;
    let e = w.append(s, &RawFrames::F32(frames_f32(2, 0))).unwrap_err();
    assert_eq!(e.key_name(), Some("capture[0].exposure_us"));
    assert!(w.is_empty());
    assert_eq!(Recording::inspect(t.path()).unwrap().captures().len(), 0);
    w.finish().unwrap();
    assert_eq!(Recording::open(t.path()).unwrap().captures().len(), 0);
    assert_eq!(fs::read_dir(t.path().join("frames")).unwrap().count(), 0);
    // a second create on the same directory is refused
    let e = RecordingWriter::create(t.path(), sensor(), None).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::AlreadyExists);
    let mut bad_sensor = sensor();
    bad_sensor.rows = 0;
    let t2 = tempfile::tempdir().unwrap();
    assert_eq!(
        RecordingWriter::create(t2.path(), bad_sensor, None)
            .unwrap_err()
            .key_name(),
        Some("sensor.rows")
    );
}

#[test]
fn leftovers_of_a_crash_are_ignored_and_cleaned() {
    let t = tempfile::tempdir().unwrap();
    make_rec(t.path());
    // A writer killed mid-append leaves: a partial temp npy, a complete but
    // unreferenced npy, and a half-written recording.toml.tmp.
    let good = npy::encode_f32(&frames_f32(4, 9));
    fs::write(t.path().join("frames/000003.npy.tmp"), &good[..50]).unwrap();
    fs::write(t.path().join("frames/000003.npy"), &good[..good.len() / 2]).unwrap();
    fs::write(
        t.path().join("recording.toml.tmp"),
        "format = \"tofprox-rec",
    )
    .unwrap();
    let rec = Recording::open(t.path()).unwrap();
    assert_eq!(rec.captures().len(), 3);
    for i in 0..3 {
        rec.load(i).unwrap();
    }
    let mut w = RecordingWriter::open_append(t.path()).unwrap();
    assert!(!t.path().join("recording.toml.tmp").exists());
    assert!(!t.path().join("frames/000003.npy.tmp").exists());
    assert_eq!(w.len(), 3);
    let i = w
        .append(
            spec(&[0.0, 90.0, 180.0, 270.0], true),
            &RawFrames::F32(frames_f32(4, 3)),
        )
        .unwrap();
    assert_eq!(i, 3);
    // appending: incomplete until finished
    assert_eq!(
        Recording::open(t.path()).unwrap_err().kind(),
        ErrorKind::Incomplete
    );
    w.finish().unwrap();
    let rec = Recording::open(t.path()).unwrap();
    assert_eq!(rec.captures().len(), 4);
    assert_eq!(rec.load(3).unwrap(), RawFrames::F32(frames_f32(4, 3)));
    assert_eq!(rec.description(), Some("test rec"));
}

const CHILD_ENV: &str = "TOFPROX_FORMAT_TEST_WRITER_DIR";

/// Not a test on its own: the body of the child process that
/// `writer_killed_at_random_moments` starts and kills.
#[test]
#[ignore = "run as a child process by writer_killed_at_random_moments"]
fn child_writer_loop() {
    let Ok(dir) = std::env::var(CHILD_ENV) else {
        return;
    };
    let dir = PathBuf::from(dir);
    let mut w = if dir.join(RECORDING_TOML).exists() {
        RecordingWriter::open_append(&dir).unwrap()
    } else {
        RecordingWriter::create(&dir, sensor(), Some("killed".into())).unwrap()
    };
    loop {
        let n = w.len();
        w.append(
            spec(&[0.0, 90.0, 180.0, 270.0], true),
            &RawFrames::F32(frames_f32(4, n)),
        )
        .unwrap();
    }
}

#[test]
fn writer_killed_at_random_moments() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("rec");
    let exe = std::env::current_exe().unwrap();
    let mut rng = 0x9e37_79b9_7f4a_7c15u64;
    let mut last = 0usize;
    for round in 0..6 {
        let mut child = std::process::Command::new(&exe)
            .args([
                "--exact",
                "recording::tests::child_writer_loop",
                "--ignored",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(CHILD_ENV, &dir)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        // wait for the recording to exist (child started), then a random delay
        let t0 = std::time::Instant::now();
        while !dir.join(RECORDING_TOML).exists() && t0.elapsed() < Duration::from_secs(20) {
            std::thread::sleep(Duration::from_millis(2));
        }
        if round == 5 {
            // last round: let the child complete a new capture first, so the
            // final check does not depend on how fast this machine's fsync is
            let has_new = |n: usize| {
                fs::read_to_string(dir.join(RECORDING_TOML))
                    .map(|t| t.matches("[[capture]]").count() > n)
                    .unwrap_or(false)
            };
            while !has_new(last) && t0.elapsed() < Duration::from_secs(20) {
                std::thread::sleep(Duration::from_millis(2));
            }
        }
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        std::thread::sleep(Duration::from_millis(5 + rng % 60));
        child.kill().unwrap();
        child.wait().unwrap();
        // killed part-way: refused by `open`, flagged by `inspect`, every capture it lists whole
        let e = Recording::open(&dir).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Incomplete, "round {round}: {e}");
        let rec = Recording::inspect(&dir).unwrap_or_else(|e| panic!("round {round}: {e}"));
        assert!(!rec.is_complete());
        let n = rec.captures().len();
        assert!(n >= last, "round {round}: captures went from {last} to {n}");
        for i in 0..n {
            assert_eq!(
                rec.load(i).unwrap(),
                RawFrames::F32(frames_f32(4, i)),
                "round {round}, capture {i}"
            );
        }
        last = n;
    }
    assert!(last > 0, "the child never completed a capture");
}

/// One recording per property test, made once (its frames never change;
/// each case rewrites only the file under test).
fn shared_rec(
    cell: &'static std::sync::OnceLock<(tempfile::TempDir, String)>,
) -> &'static (tempfile::TempDir, String) {
    cell.get_or_init(|| {
        let t = tempfile::tempdir().unwrap();
        make_rec(t.path());
        let text = fs::read_to_string(t.path().join(RECORDING_TOML)).unwrap();
        (t, text)
    })
}

static TOML_EDITS: std::sync::OnceLock<(tempfile::TempDir, String)> = std::sync::OnceLock::new();
static FRAME_BYTES: std::sync::OnceLock<(tempfile::TempDir, String)> = std::sync::OnceLock::new();

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]
    /// Random edits of a valid recording.toml: open either succeeds or
    /// returns an error naming recording.toml; never panics.
    #[test]
    fn random_toml_edits_never_panic(
        pos in 0usize..2000,
        len in 0usize..40,
        insert in "[a-z0-9_=\\[\\]\". \n-]{0,12}",
    ) {
        let (t, text) = shared_rec(&TOML_EDITS);
        let start = pos % (text.len() + 1);
        let end = (start + len).min(text.len());
        let (start, end) = (text.floor_char_boundary(start), text.floor_char_boundary(end));
        let new = format!("{}{}{}", &text[..start], insert, &text[end..]);
        fs::write(t.path().join(RECORDING_TOML), &new).unwrap();
        match Recording::open(t.path()) {
            Ok(rec) => {
                for i in 0..rec.captures().len() {
                    let _ = rec.load(i);
                }
            }
            Err(e) => prop_assert!(e.to_string().contains("recording.toml") || e.to_string().contains(".npy"), "{}", e),
        }
    }

    /// Random bytes as a frames file: open/load fail with the file named.
    #[test]
    fn random_frames_file_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let (t, _) = shared_rec(&FRAME_BYTES);
        fs::write(t.path().join("frames/000001.npy"), &bytes).unwrap();
        let r = Recording::open(t.path()).and_then(|r| r.load(1));
        let e = r.unwrap_err();
        prop_assert!(e.to_string().contains("000001.npy"), "{}", e);
    }
}

/// Issue 12 item 5: extra array elements are refused, not dropped (`[sensor]` here,
/// `valid_for` of a calibration set shares the type).
#[test]
fn roi_origin_has_exactly_two_elements() {
    for bad in [
        "roi_origin = [10, 20, 99, \"junk\", {x = 1}]",
        "roi_origin = [10, 20, 99]",
        "roi_origin = [10]",
    ] {
        let e = open_err_after(|t| t.replace("roi_origin = [10, 20]", bad));
        let key = e.key_name().unwrap_or_default();
        assert!(key.starts_with("sensor.roi_origin"), "{bad}: {e}");
    }
}

/// The phase convention's keys in `[sensor]`: a value other than the documented ones is
/// refused naming the key; elsewhere the keys are unknown keys.
#[test]
fn phase_convention_keys_are_checked() {
    for (bad, key) in [
        ("phase_sign = 2", "sensor.phase_sign"),
        ("phase_sign = \"-1\"", "sensor.phase_sign"),
        (
            "phase_shift_applies_to = \"light\"",
            "sensor.phase_shift_applies_to",
        ),
    ] {
        let e = open_err_after(|t| {
            t.replace(
                "roi_origin = [10, 20]",
                &format!("roi_origin = [10, 20]\n{bad}"),
            )
        });
        assert_eq!(e.key_name(), Some(key), "{bad}: {e}");
    }
    let e = open_err_after(|t| format!("phase_sign = -1\n{t}"));
    assert_eq!(e.kind(), ErrorKind::UnknownKey, "{e}");
}

/// Issue 35 W1: a recording is complete only once its writer finished; one killed, failed or
/// dropped part-way is refused by `open` with a clear error and flagged by `inspect`, and an
/// old recording (no mark: versions 1–3 as written before the mark existed) is complete.
#[test]
fn only_a_finished_recording_is_complete() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("rec");
    let mut w = RecordingWriter::create(&dir, sensor(), None).unwrap();
    assert!(dir.join(crate::INCOMPLETE_MARKER).is_file());
    w.append(spec(&[0.0, 90.0], true), &RawFrames::F32(frames_f32(2, 0)))
        .unwrap();
    drop(w);
    let e = Recording::open(&dir).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Incomplete);
    let msg = e.to_string();
    assert!(
        msg.contains("is incomplete") && msg.contains("1 capture(s)"),
        "{msg}"
    );
    let rec = Recording::inspect(&dir).unwrap();
    assert!(!rec.is_complete());
    assert_eq!(rec.load(0).unwrap(), RawFrames::F32(frames_f32(2, 0)));
    // continuing and finishing makes it complete
    let mut w = RecordingWriter::open_append(&dir).unwrap();
    w.append(spec(&[0.0, 90.0], true), &RawFrames::F32(frames_f32(2, 1)))
        .unwrap();
    w.finish().unwrap();
    let rec = Recording::open(&dir).unwrap();
    assert!(rec.is_complete());
    assert_eq!(rec.captures().len(), 2);
    assert!(!dir.join(crate::INCOMPLETE_MARKER).exists());
    // a mark of any file type counts (a directory of that name too)
    fs::create_dir(dir.join(crate::INCOMPLETE_MARKER)).unwrap();
    assert_eq!(
        Recording::open(&dir).unwrap_err().kind(),
        ErrorKind::Incomplete
    );
    fs::remove_dir(dir.join(crate::INCOMPLETE_MARKER)).unwrap();
    // the shipped example (a version 1 recording without the mark) is complete
    let ex = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/recording");
    assert!(Recording::open(&ex).unwrap().is_complete());
}
