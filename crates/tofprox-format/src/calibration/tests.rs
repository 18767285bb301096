use super::*;
use ndarray::Array2;

fn sensor() -> SensorGeometry {
    SensorGeometry {
        rows: 3,
        cols: 4,
        roi_origin: [5, 6],
        full_rows: 172,
        full_cols: 224,
        adc_bits: 12,
        modulation_hz: 80e6,
    }
}

fn src(name: &str) -> PartSource {
    PartSource {
        recording: name.into(),
        recording_description: Some("desc".into()),
        captures: vec![0, 2],
        distance_m: Some(0.5),
        reflectivity: None,
        exposure_us: None,
        created: now_rfc3339(),
        tool: "test".into(),
    }
}

fn offset(v: f32) -> OffsetCalibration {
    OffsetCalibration {
        dark_lsb: Array2::from_shape_fn((3, 4), |(r, c)| v + (r * 4 + c) as f32),
    }
}

fn lut(alg: Algorithm, n: usize, scale: f32) -> WigglingLut {
    WigglingLut {
        algorithm: alg,
        correction_rad: Array1::from_shape_fn(n, |i| scale * (i as f32 * 0.1).sin() + 0.3),
    }
}

fn fppn() -> FppnMap {
    FppnMap {
        phase_offset_rad: Array2::from_shape_fn((3, 4), |(r, c)| 0.01 * (r as f32 - c as f32)),
    }
}

fn lens(fx_px: f64) -> tofprox_core::camera::Intrinsics {
    tofprox_core::camera::Intrinsics {
        fx_px,
        distortion: tofprox_core::camera::Distortion {
            k1: -0.125,
            ..Default::default()
        },
        ..tofprox_core::camera::Intrinsics::pinhole_from_fov(172, 224, 62.0).unwrap()
    }
}

fn full_set() -> CalibrationSet {
    let mut s = CalibrationSet::new(&sensor());
    assert!(
        s.set_intrinsics(lens(186.5), src("sweep"))
            .unwrap()
            .is_empty()
    );
    assert!(
        s.set_offset(offset(2000.0), src("dark"))
            .unwrap()
            .is_empty()
    );
    s.set_wiggling(lut(Algorithm::TwoPhase, 64, 0.05), src("corr"))
        .unwrap();
    s.set_wiggling(lut(Algorithm::FourPhase, 64, 0.02), src("corr"))
        .unwrap();
    s.set_fppn(fppn(), src("flat")).unwrap();
    s.set_fppn_for(Algorithm::TwoPhase, fppn2(), src("flat"))
        .unwrap();
    let amp_src = PartSource {
        reflectivity: Some(0.8),
        exposure_us: Some(500.0),
        ..src("corr")
    };
    s.set_amplitude(amplitude(), amp_src).unwrap();
    s
}

fn amplitude() -> AmplitudeScale {
    AmplitudeScale {
        lsb_m2_per_us: Array2::from_shape_fn((3, 4), |(r, c)| 1.5 + 0.01 * (r * 4 + c) as f32),
    }
}

fn fppn2() -> FppnMap {
    FppnMap {
        phase_offset_rad: Array2::from_shape_fn((3, 4), |(r, c)| 0.02 * (c as f32 - r as f32)),
    }
}

#[test]
fn save_load_roundtrip() {
    let t = tempfile::tempdir().unwrap();
    let s = full_set();
    s.save(t.path()).unwrap();
    let l = CalibrationSet::load(t.path()).unwrap();
    assert_eq!(l.offset(), s.offset());
    assert_eq!(l.intrinsics(), s.intrinsics());
    assert_eq!(l.intrinsics().map(|k| k.fx_px), Some(186.5));
    assert_eq!(l.rays().unwrap().unwrap().dim(), (3, 4));
    assert_eq!(
        l.wiggling(Algorithm::TwoPhase),
        s.wiggling(Algorithm::TwoPhase)
    );
    assert_eq!(
        l.wiggling(Algorithm::FourPhase),
        s.wiggling(Algorithm::FourPhase)
    );
    assert_eq!(l.fppn(Algorithm::FourPhase), s.fppn(Algorithm::FourPhase));
    assert_eq!(l.fppn(Algorithm::TwoPhase), s.fppn(Algorithm::TwoPhase));
    assert_eq!(l.amplitude(), s.amplitude());
    assert_eq!(l.sources[&CalibPart::Amplitude].reflectivity, Some(0.8));
    assert_eq!(l.sources[&CalibPart::Amplitude].exposure_us, Some(500.0));
    assert_eq!(l.validity, s.validity);
    assert_eq!(l.sources[&CalibPart::Fppn].captures, vec![0, 2]);
    assert_eq!(l.sources[&CalibPart::Wiggling2Phase].distance_m, Some(0.5));
    let without_crosstalk: Vec<CalibPart> = CalibPart::ALL
        .into_iter()
        .filter(|p| *p != CalibPart::Crosstalk)
        .collect();
    assert_eq!(l.parts(), without_crosstalk);
    let c = l.to_pipeline_calibration(Algorithm::TwoPhase);
    assert_eq!(c.wiggling.unwrap().algorithm, Algorithm::TwoPhase);
    assert_eq!(
        c.fppn.as_ref(),
        Some(&fppn2()),
        "2-phase uses its own FPPN map"
    );
    assert!(c.offset.is_some());
    let c = l.to_pipeline_calibration(Algorithm::FourPhase);
    assert_eq!(c.fppn.as_ref(), Some(&fppn()));
    assert_eq!(c.wiggling.unwrap().algorithm, Algorithm::FourPhase);
    let text = fs::read_to_string(t.path().join(CALIBRATION_TOML)).unwrap();
    assert!(text.contains("sha256"), "{text}");
    assert!(text.contains("lut_size = 64"), "{text}");
}

#[test]
fn replacing_a_part_drops_what_depended_on_it() {
    let mut s = full_set();
    // a new 2-phase table drops only the 2-phase FPPN map
    let d = s
        .set_wiggling(lut(Algorithm::TwoPhase, 32, 0.04), src("c2"))
        .unwrap();
    assert_eq!(d, vec![CalibPart::Fppn2Phase]);
    assert!(s.fppn(Algorithm::FourPhase).is_some());
    // without its own map, 2-phase falls back to the 4-phase one
    assert_eq!(
        s.to_pipeline_calibration(Algorithm::TwoPhase).fppn.as_ref(),
        Some(&fppn())
    );
    s.set_fppn_for(Algorithm::TwoPhase, fppn2(), src("flat"))
        .unwrap();
    // a new 4-phase table invalidates the 4-phase FPPN map only
    let d = s
        .set_wiggling(lut(Algorithm::FourPhase, 32, 0.01), src("c2"))
        .unwrap();
    assert_eq!(d, vec![CalibPart::Fppn]);
    s.set_fppn(fppn(), src("flat")).unwrap();
    // a new offset invalidates everything downstream
    let d = s.set_offset(offset(1990.0), src("dark2")).unwrap();
    assert_eq!(
        d,
        vec![
            CalibPart::Wiggling2Phase,
            CalibPart::Wiggling4Phase,
            CalibPart::Fppn,
            CalibPart::Fppn2Phase
        ]
    );
    // the lens does not depend on the offset
    assert_eq!(
        s.parts(),
        vec![
            CalibPart::Intrinsics,
            CalibPart::Offset,
            CalibPart::Amplitude
        ]
    );
    // saving removes the dropped arrays' files
    let t = tempfile::tempdir().unwrap();
    full_set().save(t.path()).unwrap();
    assert!(t.path().join("fppn.npy").exists());
    s.save(t.path()).unwrap();
    assert!(!t.path().join("fppn.npy").exists());
    assert_eq!(
        CalibrationSet::load(t.path()).unwrap().parts(),
        vec![
            CalibPart::Intrinsics,
            CalibPart::Offset,
            CalibPart::Amplitude
        ]
    );
}

#[test]
fn checksum_mismatch_is_refused() {
    let t = tempfile::tempdir().unwrap();
    full_set().save(t.path()).unwrap();
    let p = t.path().join("wiggling_4phase.npy");
    let mut b = fs::read(&p).unwrap();
    let n = b.len();
    b[n - 1] ^= 0x01;
    fs::write(&p, b).unwrap();
    let e = CalibrationSet::load(t.path()).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Checksum);
    assert_eq!(e.key_name(), Some("wiggling_4phase.sha256"));
    assert!(e.to_string().contains("wiggling_4phase.npy"), "{e}");
}

#[test]
fn amplitude_part_is_checksummed_and_must_be_non_negative() {
    let t = tempfile::tempdir().unwrap();
    full_set().save(t.path()).unwrap();
    let p = t.path().join("amplitude.npy");
    let mut b = fs::read(&p).unwrap();
    let n = b.len();
    b[n - 1] ^= 0x01;
    fs::write(&p, b).unwrap();
    let e = CalibrationSet::load(t.path()).unwrap_err();
    assert_eq!(e.key_name(), Some("amplitude.sha256"), "{e}");
    let mut s = full_set();
    let bad = AmplitudeScale {
        lsb_m2_per_us: Array2::from_elem((3, 4), -1.0),
    };
    let e = s.set_amplitude(bad, src("corr")).unwrap_err();
    assert_eq!(e.key_name(), Some("amplitude"), "{e}");
    // a new offset keeps the amplitude scale (it depends on nothing)
    s.set_offset(offset(1990.0), src("dark2")).unwrap();
    assert!(s.amplitude().is_some());
}

#[test]
fn absurd_amplitude_scales_are_refused_when_set_and_when_loaded() {
    // issue 12 item 7: K = 1e30 LSB·m²/µs is finite but no sensor's
    let absurd = Array2::from_shape_fn((3, 4), |(r, c)| if (r, c) == (1, 2) { 1e30 } else { 0.09 });
    let e = full_set()
        .set_amplitude(
            AmplitudeScale {
                lsb_m2_per_us: absurd.clone(),
            },
            src("corr"),
        )
        .unwrap_err();
    assert_eq!(e.key_name(), Some("amplitude"), "{e}");
    assert!(e.to_string().contains("physical range"), "{e}");
    // on disk, with a checksum that matches: refused by the range, not the checksum
    let t = tempfile::tempdir().unwrap();
    full_set().save(t.path()).unwrap();
    let bytes = crate::npy::encode_f32(&absurd.into_dyn());
    fs::write(t.path().join("amplitude.npy"), &bytes).unwrap();
    let toml = t.path().join("calibration.toml");
    let text = fs::read_to_string(&toml).unwrap();
    let old_sum = sha256_hex(&full_set().part_bytes(CalibPart::Amplitude).unwrap());
    assert!(text.contains(&old_sum));
    fs::write(&toml, text.replace(&old_sum, &sha256_hex(&bytes))).unwrap();
    let e = CalibrationSet::load(t.path()).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Invalid, "{e}");
    assert_eq!(e.key_name(), Some("amplitude"), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("amplitude.npy") && msg.contains("element 6"),
        "{msg}"
    );
    // the shipped sets stay inside the range
    for set in ["calib/emulated", "calib/phone"] {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../..")
            .join(set);
        CalibrationSet::load(&dir).unwrap_or_else(|e| panic!("{set}: {e}"));
    }
}

#[test]
fn stale_dependency_in_file_is_refused() {
    let t = tempfile::tempdir().unwrap();
    full_set().save(t.path()).unwrap();
    // someone swaps in an offset of another extraction, with a matching checksum
    let mut other = CalibrationSet::new(&sensor());
    other.set_offset(offset(1500.0), src("x")).unwrap();
    let bytes = npy::encode_f32(&offset(1500.0).dark_lsb);
    fs::write(t.path().join("offset.npy"), &bytes).unwrap();
    let p = t.path().join(CALIBRATION_TOML);
    let text = fs::read_to_string(&p).unwrap();
    let old = full_set().checksum(CalibPart::Offset).unwrap();
    let new = other.checksum(CalibPart::Offset).unwrap();
    // replace only the [offset] table's sha256 (its first occurrence)
    let text = text.replacen(
        &format!("sha256 = \"{old}\""),
        &format!("sha256 = \"{new}\""),
        1,
    );
    fs::write(&p, text).unwrap();
    let e = CalibrationSet::load(t.path()).unwrap_err();
    assert!(e.to_string().contains("different offset"), "{e}");
}

fn load_err_after(edit: impl FnOnce(&str) -> String) -> FormatError {
    let t = tempfile::tempdir().unwrap();
    full_set().save(t.path()).unwrap();
    let p = t.path().join(CALIBRATION_TOML);
    let text = fs::read_to_string(&p).unwrap();
    let new = edit(&text);
    assert_ne!(new, text);
    fs::write(&p, new).unwrap();
    let e = CalibrationSet::load(t.path()).unwrap_err();
    assert!(
        e.to_string().contains("calibration.toml") || e.to_string().contains(".npy"),
        "{e}"
    );
    e
}

#[test]
fn toml_errors_name_the_key() {
    let e = load_err_after(|t| t.replace("version = 1", "version = 7"));
    assert_eq!(e.key_name(), Some("version"));
    let e = load_err_after(|t| t.replace("tofprox-calibration", "tofprox-recording"));
    assert_eq!(e.key_name(), Some("format"));
    let e = load_err_after(|t| t.replace("[valid_for]\n", "[valid_for]\nlens = 1\n"));
    assert!(e.to_string().contains("lens"), "{e}");
    let e = load_err_after(|t| t.replacen("lut_size = 64", "lut_size = 65", 1));
    assert_eq!(e.key_name(), Some("wiggling_2phase.lut_size"));
    let e = load_err_after(|t| t.replacen("adc_bits = 12\n", "", 1));
    assert_eq!(e.kind(), ErrorKind::MissingKey);
    assert!(e.to_string().contains("adc_bits"), "{e}");
    let e = load_err_after(|t| t.replacen("file = \"offset.npy\"", "file = \"../x.npy\"", 1));
    assert_eq!(e.key_name(), Some("offset.file"));
}

#[test]
fn missing_array_file_names_it() {
    let t = tempfile::tempdir().unwrap();
    full_set().save(t.path()).unwrap();
    fs::remove_file(t.path().join("fppn.npy")).unwrap();
    let e = CalibrationSet::load(t.path()).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Io);
    assert!(e.to_string().contains("fppn.npy"), "{e}");
}

#[test]
fn incompatible_data_is_refused_with_reason() {
    let t = tempfile::tempdir().unwrap();
    full_set().save(t.path()).unwrap();
    let s = CalibrationSet::load(t.path()).unwrap();
    s.check_compatible(&sensor()).unwrap();
    let mut other = sensor();
    other.modulation_hz = 60e6;
    let e = s.check_compatible(&other).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Incompatible);
    assert!(e.to_string().contains("modulation_hz"), "{e}");
    assert!(e.to_string().contains("calibration.toml"), "{e}");
    let mut other = sensor();
    other.adc_bits = 10;
    assert!(
        s.check_compatible(&other)
            .unwrap_err()
            .to_string()
            .contains("adc_bits")
    );
    let mut other = sensor();
    other.roi_origin = [0, 0];
    assert!(
        s.check_compatible(&other)
            .unwrap_err()
            .to_string()
            .contains("roi_origin")
    );
    let mut other = sensor();
    other.rows = 4;
    other.full_rows = 200;
    let msg = s.check_compatible(&other).unwrap_err().to_string();
    assert!(
        msg.contains("window size") && msg.contains("full array"),
        "{msg}"
    );
}

#[test]
fn wrong_shapes_are_refused_when_building() {
    let mut s = CalibrationSet::new(&sensor());
    let bad = OffsetCalibration {
        dark_lsb: Array2::zeros((4, 3)),
    };
    assert_eq!(
        s.set_offset(bad, src("x")).unwrap_err().key_name(),
        Some("offset")
    );
    let nan = FppnMap {
        phase_offset_rad: Array2::from_elem((3, 4), f32::NAN),
    };
    assert!(s.set_fppn(nan, src("x")).is_err());
    let empty = WigglingLut {
        algorithm: Algorithm::TwoPhase,
        correction_rad: Array1::zeros(1),
    };
    assert!(s.set_wiggling(empty, src("x")).is_err());
}

#[test]
fn rfc3339_known_dates() {
    assert_eq!(rfc3339_from_unix(0), "1970-01-01T00:00:00Z");
    assert_eq!(rfc3339_from_unix(951_782_400), "2000-02-29T00:00:00Z");
    assert_eq!(rfc3339_from_unix(1_700_000_000), "2023-11-14T22:13:20Z");
}

#[test]
fn replacing_the_lens_drops_what_was_extracted_through_it() {
    let mut s = full_set();
    // The same lens again: nothing changes.
    assert!(
        s.set_intrinsics(lens(186.5), src("sweep"))
            .unwrap()
            .is_empty()
    );
    let dropped = s.set_intrinsics(lens(190.0), src("sweep2")).unwrap();
    assert_eq!(
        dropped,
        vec![
            CalibPart::Wiggling2Phase,
            CalibPart::Wiggling4Phase,
            CalibPart::Fppn,
            CalibPart::Fppn2Phase
        ]
    );
    assert!(s.offset().is_some());
    // A lens that folds over inside the window is refused.
    let folding = tofprox_core::camera::Intrinsics {
        fx_px: 20.0,
        fy_px: 20.0,
        distortion: tofprox_core::camera::Distortion {
            k1: -2.0,
            ..Default::default()
        },
        ..lens(186.5)
    };
    let e = s.set_intrinsics(folding, src("bad")).unwrap_err();
    assert!(e.to_string().contains("intrinsics"), "{e}");
}

fn crosstalk(v: f32) -> CrosstalkCalibration {
    CrosstalkCalibration {
        lsb_per_us: ndarray::Array3::from_shape_fn((4, 3, 4), |(k, r, c)| {
            v * [1.0, 0.3, -1.0, -0.3][k] * (1.0 + 0.1 * (r + c) as f32)
        }),
    }
}

#[test]
fn crosstalk_part_roundtrips_checksummed_and_refuses_other_setups() {
    let t = tempfile::tempdir().unwrap();
    let mut s = full_set();
    assert!(
        s.set_crosstalk(crosstalk(0.05), src("empty"))
            .unwrap()
            .is_empty(),
        "wiggling/FPPN extracted without a crosstalk (a module calibrated before it was built in) stay"
    );
    s.save(t.path()).unwrap();
    let l = CalibrationSet::load(t.path()).unwrap();
    assert_eq!(l.crosstalk(), s.crosstalk());
    assert!(l.parts().contains(&CalibPart::Crosstalk));
    assert_eq!(
        l.to_pipeline_calibration(Algorithm::TwoPhase).crosstalk,
        s.crosstalk().cloned()
    );
    let text = fs::read_to_string(t.path().join(CALIBRATION_TOML)).unwrap();
    assert!(
        text.contains("[crosstalk]") && text.contains("shape = [4, 3, 4]"),
        "{text}"
    );
    // the set's validity covers it: another frequency or window is refused
    for edit in [
        |s: &mut SensorGeometry| s.modulation_hz = 60e6,
        |s: &mut SensorGeometry| s.roi_origin = [0, 0],
        |s: &mut SensorGeometry| s.adc_bits = 10,
    ] {
        let mut other = sensor();
        edit(&mut other);
        let e = l.check_compatible(&other).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Incompatible, "{e}");
    }
    // a crosstalk of another window size is refused when building, naming the part
    let mut s2 = CalibrationSet::new(&sensor());
    let bad = CrosstalkCalibration {
        lsb_per_us: ndarray::Array3::zeros((4, 4, 3)),
    };
    let e = s2.set_crosstalk(bad, src("x")).unwrap_err();
    assert_eq!(e.key_name(), Some("crosstalk"), "{e}");
    // a modified array is refused by its checksum
    let f = t.path().join("crosstalk.npy");
    let mut bytes = fs::read(&f).unwrap();
    let n = bytes.len();
    bytes[n - 1] ^= 0x40;
    fs::write(&f, bytes).unwrap();
    let e = CalibrationSet::load(t.path()).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Checksum, "{e}");
}

#[test]
fn parts_extracted_with_a_crosstalk_are_dropped_when_it_is_replaced() {
    let mut s = CalibrationSet::new(&sensor());
    s.set_offset(offset(2000.0), src("dark")).unwrap();
    s.set_crosstalk(crosstalk(0.05), src("empty")).unwrap();
    s.set_wiggling(lut(Algorithm::TwoPhase, 64, 0.05), src("corr"))
        .unwrap();
    s.set_fppn_for(Algorithm::TwoPhase, fppn2(), src("flat"))
        .unwrap();
    // a new offset drops the crosstalk (extracted against the old dark frame) and what follows
    let mut o = s.clone();
    let dropped = o.set_offset(offset(2001.0), src("dark2")).unwrap();
    assert!(dropped.contains(&CalibPart::Crosstalk), "{dropped:?}");
    // a new crosstalk drops the wiggling and FPPN extracted with the old one subtracted
    let dropped = s.set_crosstalk(crosstalk(0.1), src("empty2")).unwrap();
    assert_eq!(
        dropped,
        vec![CalibPart::Wiggling2Phase, CalibPart::Fppn2Phase]
    );
    // and a file whose wiggling names another crosstalk is refused naming it
    let t = tempfile::tempdir().unwrap();
    let mut s = CalibrationSet::new(&sensor());
    s.set_offset(offset(2000.0), src("dark")).unwrap();
    s.set_crosstalk(crosstalk(0.05), src("empty")).unwrap();
    s.set_wiggling(lut(Algorithm::TwoPhase, 64, 0.05), src("corr"))
        .unwrap();
    s.save(t.path()).unwrap();
    let p = t.path().join(CALIBRATION_TOML);
    let text = fs::read_to_string(&p).unwrap();
    let sum = s.checksum(CalibPart::Crosstalk).unwrap();
    let i = text.find("[wiggling_2phase]").unwrap();
    let (head, tail) = text.split_at(i);
    fs::write(
        &p,
        format!("{head}{}", tail.replacen(&sum, &"0".repeat(64), 1)),
    )
    .unwrap();
    let e = CalibrationSet::load(t.path()).unwrap_err();
    assert!(e.to_string().contains("crosstalk"), "{e}");
}
