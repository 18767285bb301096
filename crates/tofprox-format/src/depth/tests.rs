use std::fs;

use ndarray::Array2;

use super::*;
use crate::{Recording, recording_kind};

fn depth(v: u16) -> Array2<u16> {
    Array2::from_shape_fn((3, 4), |(r, c)| v + (r * 4 + c) as u16)
}

fn size() -> DepthImageSize {
    DepthImageSize { rows: 3, cols: 4 }
}

fn written(dir: &Path) {
    let mut w =
        DepthRecordingWriter::create(dir, size(), Some("from tofproxd".into()), false).unwrap();
    w.append(Some(7), &depth(250), Some(&depth(900))).unwrap();
    w.append(None, &depth(0), None).unwrap();
}

#[test]
fn a_depth_recording_is_read_as_depth() {
    let t = tempfile::tempdir().unwrap();
    written(t.path());
    assert_eq!(recording_kind(t.path()).unwrap(), RecordingKind::Depth);
    let text = fs::read_to_string(t.path().join(RECORDING_TOML)).unwrap();
    assert!(
        text.contains("version = 3") && text.contains("kind = \"depth\""),
        "{text}"
    );
    let rec = DepthRecording::open(t.path()).unwrap();
    assert_eq!(rec.size(), size());
    assert_eq!(rec.description(), Some("from tofproxd"));
    assert_eq!(rec.captures().len(), 2);
    assert_eq!(rec.captures()[0].timestamp_ns, Some(7));
    assert_eq!(rec.load_depth_mm(0).unwrap(), depth(250));
    assert_eq!(rec.load_amplitude_lsb(0).unwrap(), Some(depth(900)));
    assert_eq!(rec.load_depth_mm(1).unwrap(), depth(0));
    assert_eq!(rec.load_amplitude_lsb(1).unwrap(), None);
    assert!(rec.load_depth_mm(2).is_err());
}

#[test]
fn the_raw_reader_refuses_a_depth_recording_naming_file_and_kind() {
    let t = tempfile::tempdir().unwrap();
    written(t.path());
    let e = Recording::open(t.path()).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Unsupported);
    assert_eq!(e.key_name(), Some("kind"));
    assert_eq!(e.path(), Some(t.path().join(RECORDING_TOML).as_path()));
    assert!(e.to_string().contains("depth recording"), "{e}");
}

#[test]
fn the_depth_reader_refuses_a_raw_recording() {
    let t = tempfile::tempdir().unwrap();
    let sensor = tofprox_core::SensorGeometry::full(3, 4, 12, 80e6);
    crate::RecordingWriter::create(t.path(), sensor, None).unwrap();
    assert_eq!(recording_kind(t.path()).unwrap(), RecordingKind::Raw);
    let e = DepthRecording::open(t.path()).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Unsupported);
    assert_eq!(e.key_name(), Some("kind"));
}

fn open_err_after(edit: impl Fn(&str) -> String) -> FormatError {
    let t = tempfile::tempdir().unwrap();
    written(t.path());
    let p = t.path().join(RECORDING_TOML);
    let text = fs::read_to_string(&p).unwrap();
    let edited = edit(&text);
    assert_ne!(edited, text, "the edit changed nothing");
    fs::write(&p, edited).unwrap();
    DepthRecording::open(t.path()).unwrap_err()
}

#[test]
fn bad_depth_headers_name_the_key() {
    let e = open_err_after(|t| t.replace("kind = \"depth\"\n", ""));
    assert_eq!(e.kind(), ErrorKind::MissingKey);
    assert_eq!(e.key_name(), Some("kind"));

    let e = open_err_after(|t| t.replace("kind = \"depth\"", "kind = \"cine\""));
    assert_eq!(e.key_name(), Some("kind"));

    // version 1 had no kind: a depth recording cannot claim it
    let e = open_err_after(|t| t.replace("version = 3", "version = 1"));
    assert_eq!(e.kind(), ErrorKind::UnknownKey);
    assert_eq!(e.key_name(), Some("kind"));

    let e = open_err_after(|t| t.replace("cols = 4", "cols = 5"));
    assert_eq!(e.key_name(), Some("capture[0].depth_mm"), "{e}");
    assert!(e.to_string().contains("[depth]"), "{e}");

    let e = open_err_after(|t| t.replace("cols = 4", "cols = 5000"));
    assert_eq!(e.kind(), ErrorKind::Limit);
    assert_eq!(e.key_name(), Some("depth.cols"));

    let e = open_err_after(|t| t.replace("rows = 3", "rows = 0"));
    assert_eq!(e.key_name(), Some("depth.rows"));

    let e = open_err_after(|t| t.replace("timestamp_ns = 7", "timestamp_ns = 7\nexposure_us = 1"));
    assert_eq!(e.kind(), ErrorKind::UnknownKey);
    assert_eq!(e.key_name(), Some("capture[0].exposure_us"), "{e}");

    let e = open_err_after(|t| {
        t.replace(
            "frames/000001_depth_mm.npy",
            "frames/./000000_amplitude_lsb.npy",
        )
    });
    assert_eq!(e.key_name(), Some("capture[1].depth_mm"), "{e}");

    let e = open_err_after(|t| t.replace("frames/000001_depth_mm.npy", "../outside.npy"));
    assert_eq!(e.key_name(), Some("capture[1].depth_mm"), "{e}");
}

#[test]
fn a_raw_frames_file_is_not_a_depth_image() {
    let t = tempfile::tempdir().unwrap();
    written(t.path());
    let f = t.path().join("frames/000001_depth_mm.npy");
    fs::write(&f, npy::encode_f32(&Array2::<f32>::zeros((3, 4)))).unwrap();
    let e = DepthRecording::open(t.path()).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Npy);
    assert_eq!(e.key_name(), Some("capture[1].depth_mm"));
}

#[test]
fn the_writer_refuses_a_wrong_size_and_keeps_the_recording() {
    let t = tempfile::tempdir().unwrap();
    let mut w = DepthRecordingWriter::create(t.path(), size(), None, false).unwrap();
    w.append(None, &depth(1), None).unwrap();
    let e = w
        .append(None, &depth(1), Some(&Array2::zeros((4, 3))))
        .unwrap_err();
    assert_eq!(e.key_name(), Some("capture[1].amplitude_lsb"));
    assert_eq!(w.len(), 1);
    assert_eq!(DepthRecording::open(t.path()).unwrap().captures().len(), 1);
    // an existing recording is not overwritten unless asked
    let e = DepthRecordingWriter::create(t.path(), size(), None, false).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::AlreadyExists);
    let w = DepthRecordingWriter::create(t.path(), size(), None, true).unwrap();
    assert!(w.is_empty());
    assert!(
        DepthRecording::open(t.path())
            .unwrap()
            .captures()
            .is_empty()
    );
}

#[test]
fn a_header_is_validated_on_its_own() {
    let t = tempfile::tempdir().unwrap();
    written(t.path());
    let p = t.path().join(RECORDING_TOML);
    let text = fs::read_to_string(&p).unwrap();
    let check = crate::validate_recording_toml;
    assert_eq!(check(&p, &text).unwrap(), RecordingKind::Depth);
    // the frames files are not read: a header naming missing files is still a valid header
    fs::remove_dir_all(t.path().join(FRAMES_DIR)).unwrap();
    assert_eq!(check(&p, &text).unwrap(), RecordingKind::Depth);
    let e = check(&p, &text.replace("rows = 3", "rows = 9000")).unwrap_err();
    assert_eq!(e.key_name(), Some("depth.rows"));
}
