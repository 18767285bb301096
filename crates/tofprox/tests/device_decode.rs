//! `tofprox device decode` (issue 27): synthetic usbmon captures built here from known frames —
//! the pixel packing, UVC payload headers and pcap/pcapng containers written byte by byte from
//! their public specifications (not with the code under test) — decode to exactly those frames.

use ndarray::Array3;
use tofprox_format::{RawFrames, Recording};

mod common;
use common::{run, text};

const ROWS: usize = 4;
const COLS: usize = 6;

/// Known raw images of capture `c`: `(4, ROWS, COLS)` 12-bit codes.
fn truth(c: usize) -> Array3<u16> {
    Array3::from_shape_fn((4, ROWS, COLS), |(k, r, x)| {
        ((c * 1237 + k * 401 + r * 53 + x * 7 + 2048) % 4096) as u16
    })
}

/// MIPI CSI-2 RAW12: B0 = P0[11:4], B1 = P1[11:4], B2 = P1[3:0] << 4 | P0[3:0].
fn raw12(codes: &Array3<u16>) -> Vec<u8> {
    let flat: Vec<u16> = codes.iter().copied().collect();
    flat.chunks(2)
        .flat_map(|p| {
            [
                (p[0] >> 4) as u8,
                (p[1] >> 4) as u8,
                ((p[1] & 15) << 4 | (p[0] & 15)) as u8,
            ]
        })
        .collect()
}

/// UVC payloads of one frame: 2-byte headers (EOH | EOF on the last | FID), ≤ 16 data bytes.
fn payloads(frame: &[u8], fid: bool) -> Vec<Vec<u8>> {
    let chunks: Vec<&[u8]> = frame.chunks(16).collect();
    let n = chunks.len();
    chunks
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let bits = 0x80 | u8::from(fid) | if i + 1 == n { 0x02 } else { 0 };
            let mut p = vec![2, bits];
            p.extend_from_slice(c);
            p
        })
        .collect()
}

/// A Linux `usbmon_packet` (64-byte mmapped header, little-endian) of a completed bulk-IN
/// transfer on bus 3, device 7, endpoint 0x82.
fn usbmon_packet(t_us: u64, data: &[u8]) -> Vec<u8> {
    let mut h = vec![0u8; 64];
    h[8] = b'C';
    h[9] = 3; // bulk
    h[10] = 0x82;
    h[11] = 7;
    h[12..14].copy_from_slice(&3u16.to_le_bytes());
    h[16..24].copy_from_slice(&(t_us / 1_000_000).to_le_bytes());
    h[24..28].copy_from_slice(&((t_us % 1_000_000) as u32).to_le_bytes());
    h[32..36].copy_from_slice(&(data.len() as u32).to_le_bytes());
    h[36..40].copy_from_slice(&(data.len() as u32).to_le_bytes());
    h.extend_from_slice(data);
    h
}

fn packets() -> Vec<(u64, Vec<u8>)> {
    let mut out = Vec::new();
    for c in 0..3 {
        for p in payloads(&raw12(&truth(c)), c % 2 == 1) {
            let t_us = 5_000_000 + 33_000 * c as u64 + out.len() as u64;
            out.push((t_us, usbmon_packet(t_us, &p)));
        }
    }
    out
}

fn pcap() -> Vec<u8> {
    let mut f = Vec::new();
    for w in [0xa1b2_c3d4u32, 0x0004_0002, 0, 0, 65_535, 220] {
        f.extend_from_slice(&w.to_le_bytes());
    }
    for (t_us, p) in packets() {
        for w in [
            (t_us / 1_000_000) as u32,
            (t_us % 1_000_000) as u32,
            p.len() as u32,
            p.len() as u32,
        ] {
            f.extend_from_slice(&w.to_le_bytes());
        }
        f.extend_from_slice(&p);
    }
    f
}

fn pcapng() -> Vec<u8> {
    let block = |kind: u32, body: &[u8]| {
        let len = (12 + body.len().div_ceil(4) * 4) as u32;
        let mut b = kind.to_le_bytes().to_vec();
        b.extend_from_slice(&len.to_le_bytes());
        b.extend_from_slice(body);
        b.resize(len as usize - 4, 0);
        b.extend_from_slice(&len.to_le_bytes());
        b
    };
    let mut shb = 0x1a2b_3c4du32.to_le_bytes().to_vec();
    shb.extend_from_slice(&[1, 0, 0, 0]);
    shb.extend_from_slice(&(-1i64).to_le_bytes());
    let mut idb = 220u16.to_le_bytes().to_vec();
    idb.extend_from_slice(&[0, 0]);
    idb.extend_from_slice(&0u32.to_le_bytes());
    let mut f = block(0x0a0d_0d0a, &shb);
    f.extend(block(1, &idb));
    for (t_us, p) in packets() {
        let mut epb = 0u32.to_le_bytes().to_vec();
        epb.extend_from_slice(&((t_us >> 32) as u32).to_le_bytes());
        epb.extend_from_slice(&(t_us as u32).to_le_bytes());
        epb.extend_from_slice(&(p.len() as u32).to_le_bytes());
        epb.extend_from_slice(&(p.len() as u32).to_le_bytes());
        epb.extend_from_slice(&p);
        f.extend(block(6, &epb));
    }
    f
}

fn decode(capture: &std::path::Path, out: &std::path::Path) -> std::process::Output {
    let (rows, cols) = (ROWS.to_string(), COLS.to_string());
    run(&[
        "device",
        "decode",
        capture.to_str().unwrap(),
        "--mode",
        "4phase",
        "--rows",
        &rows,
        "--cols",
        &cols,
        "--packing",
        "raw12",
        "--stacked",
        "--modulation-hz",
        "80e6",
        "--exposure-us",
        "250",
        "--out",
        out.to_str().unwrap(),
        "--json",
    ])
}

#[test]
fn pcap_and_pcapng_captures_decode_to_the_frames_that_made_them() {
    let dir = tempfile::tempdir().unwrap();
    for (name, bytes) in [("cap.pcap", pcap()), ("cap.pcapng", pcapng())] {
        let cap = dir.path().join(name);
        std::fs::write(&cap, bytes).unwrap();
        let out = dir.path().join(format!("rec-{name}"));
        let o = decode(&cap, &out);
        assert!(o.status.success(), "{name}: {}", text(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["captures"], 3, "{v}");
        assert_eq!(v["endpoint"], serde_json::json!([3, 7, 130]));
        let rec = Recording::open(&out).unwrap();
        assert_eq!(rec.captures().len(), 3);
        for c in 0..3 {
            let RawFrames::U16(f) = rec.load(c).unwrap() else {
                panic!("{name}: capture {c} is not uint16")
            };
            assert_eq!(f, truth(c), "{name}: capture {c}");
            assert_eq!(rec.captures()[c].phases_deg, vec![0.0, 90.0, 180.0, 270.0]);
        }
        // RAW12 decoded as RAW16 cannot pass for codes: a clear error, nothing written
        let wrong = dir.path().join(format!("wrong-{name}"));
        let mut args = vec![
            "device",
            "decode",
            cap.to_str().unwrap(),
            "--mode",
            "4phase",
        ];
        args.extend([
            "--rows",
            "4",
            "--cols",
            "6",
            "--stacked",
            "--modulation-hz",
            "80e6",
        ]);
        args.extend(["--exposure-us", "250", "--out", wrong.to_str().unwrap()]);
        let o = run(&args);
        assert_eq!(o.status.code(), Some(2), "{name}");
        assert!(
            text(&o.stderr).contains("no complete capture"),
            "{}",
            text(&o.stderr)
        );
        assert!(!wrong.join("recording.toml").exists());
    }
}

/// `device decode CAPTURE` with the reproduction's arguments and extra ones; killed after 20 s
/// (a FIFO once hung it), so a regression fails instead of hanging the suite.
fn decode_with(capture: &str, out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_tofprox"));
    cmd.args(["device", "decode", capture, "--mode", "4phase"])
        .args(["--modulation-hz", "80e6", "--exposure-us", "250"])
        .arg("--out")
        .arg(out)
        .args(extra)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
    let mut child = cmd.spawn().unwrap();
    let t0 = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > std::time::Duration::from_secs(20) {
            child.kill().unwrap();
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// Issue 35 N1: a non-ASCII byte in a text capture's data word panicked (exit 101); it is a
/// clear error naming the record.
#[test]
fn a_non_ascii_data_word_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let cap = dir.path().join("x.txt");
    std::fs::write(&cap, b"ffff 1 C Bi:3:007:2 0 2 = a\xc3\xa9b\n").unwrap();
    let out = dir.path().join("o");
    let o = decode_with(cap.to_str().unwrap(), &out, &["--rows", "4", "--cols", "6"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(
        text(&o.stderr).contains("record 0: data word"),
        "{}",
        text(&o.stderr)
    );
    assert!(!out.join("recording.toml").exists());
}

/// Issue 35 N2: the capture goes through the bounded reader: a FIFO, `/dev/zero` and
/// `/dev/urandom` are refused at once (they hung or were read until out of memory).
#[test]
fn special_files_are_refused_without_reading_them() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("cap.fifo");
    let st = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(st.success());
    for (cap, what) in [
        (fifo.to_str().unwrap(), "a FIFO"),
        ("/dev/zero", "a character device"),
        ("/dev/urandom", "a character device"),
    ] {
        let t0 = std::time::Instant::now();
        let o = decode_with(cap, &dir.path().join("o"), &["--rows", "4", "--cols", "6"]);
        assert!(t0.elapsed() < std::time::Duration::from_secs(10), "{cap}");
        assert_eq!(o.status.code(), Some(2), "{cap}: {}", text(&o.stderr));
        assert!(text(&o.stderr).contains(what), "{cap}: {}", text(&o.stderr));
    }
}

/// Issue 35 N5: `--cols 2^62` and `--stride-bytes 2^64−1` panicked with "capacity overflow";
/// the geometry and layout are refused before anything is read or allocated.
#[test]
fn huge_geometry_and_stride_are_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    let cap = dir.path().join("cap.pcap");
    std::fs::write(&cap, pcap()).unwrap();
    let c = cap.to_str().unwrap();
    for (extra, says) in [
        (
            &["--rows", "4", "--cols", "4611686018427387904"][..],
            "array has more than",
        ),
        (
            &["--rows", "4611686018427387904", "--cols", "6"][..],
            "array has more than",
        ),
        (
            &[
                "--rows",
                "4",
                "--cols",
                "6",
                "--stride-bytes",
                "18446744073709551615",
            ][..],
            "stride above",
        ),
    ] {
        let o = decode_with(c, &dir.path().join("o"), extra);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {}", text(&o.stderr));
        assert!(
            text(&o.stderr).contains(says),
            "{extra:?}: {}",
            text(&o.stderr)
        );
    }
}
