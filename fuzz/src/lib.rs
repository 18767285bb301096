//! The bodies of the fuzz targets (`fuzz_targets/*.rs` call them; the corpora in `corpus/`
//! are replayed through the same functions by `cargo test`:
//! `crates/tofprox-bridge/tests/fuzz_corpus.rs`). Each takes any bytes and must never panic,
//! hang or allocate by a size the bytes merely claim; the invariants each checks are in its
//! doc. Harness: libFuzzer (`libfuzzer-sys`), built on STABLE Rust by `fuzz/run.sh` (the
//! coverage flags cargo-fuzz passes with `--sanitizer none`; README of fuzz/).

use std::path::Path;

use tofprox_bridge::decode::{StreamSpec, decode_stream};
use tofprox_bridge::frame::{StatusLine, decode_frame, encode_frame};
use tofprox_bridge::pixels::{
    BufferLayout, PixelError, PixelPacking, decode_buffer, encode_buffer,
};
use tofprox_bridge::usbcap::{busiest_endpoint, read_capture};
use tofprox_bridge::uvc::{FrameSpec, Push, Reassembler, parse_header, split_frame};
use tofprox_format::npy::{self, NpyArray};
use tofprox_format::validate_recording_toml;

/// The usbmon reader (pcap, pcapng, text — issue 35 N1): any bytes give transfers or an
/// error; every transfer kept is a completed bulk-IN one whose data was captured whole.
pub fn usbcap(data: &[u8]) {
    if let Ok(t) = read_capture(data) {
        assert!(t.iter().all(|x| x.endpoint & 0x80 != 0));
        let _ = busiest_endpoint(&t);
    }
}

/// A layout from the first 10 bytes (sides up to 2^16 and strides up to 2^24, far beyond
/// the limits: issue 35 N5).
fn layout(head: &[u8]) -> Option<BufferLayout> {
    let &[p, c0, c1, r0, r1, i, s0, s1, s2, a] = head.get(..10)? else {
        return None;
    };
    let stride = u32::from_le_bytes([s0, s1, s2, 0]) as usize;
    Some(BufferLayout {
        packing: if p % 2 == 0 {
            PixelPacking::Raw12
        } else {
            PixelPacking::Raw16
        },
        cols: usize::from(u16::from_le_bytes([c0, c1])),
        rows: usize::from(u16::from_le_bytes([r0, r1])),
        images: usize::from(i),
        stride_bytes: (p & 2 != 0).then_some(stride),
        adc_bits: a % 20,
    })
}

/// The pixel decoders (the first 10 bytes choose the layout, the rest is the buffer): a
/// decoded buffer re-encodes to a buffer that decodes to the same codes (padding and unused
/// bits aside), a size error names the size the checked layout needs, and nothing is
/// allocated before the layout is checked.
pub fn pixels(data: &[u8]) {
    let Some(l) = layout(data) else { return };
    let buf = &data[10..];
    match decode_buffer(buf, &l) {
        Ok(codes) => {
            let again = encode_buffer(&codes, &l).expect("a decodable layout encodes");
            assert_eq!(again.len(), buf.len());
            assert_eq!(
                decode_buffer(&again, &l).expect("re-encoded decodes"),
                codes
            );
        }
        Err(PixelError::Size { expected, got }) => {
            assert_eq!((l.validate(), got), (Ok(expected), buf.len()));
        }
        Err(PixelError::Layout(_)) => assert!(l.validate().is_err()),
        Err(PixelError::Range { index, .. }) => assert!(index < l.rows * l.cols * l.images),
    }
}

/// `tofprox device decode` without the file: the first 10 bytes choose the layout (as
/// [`pixels`]), the 11th the mode and the status line, the rest is the capture.
pub fn device_decode(data: &[u8]) {
    let (Some(l), Some(&m)) = (layout(data), data.get(10)) else {
        return;
    };
    let Ok(transfers) = read_capture(&data[11..]) else {
        return;
    };
    let spec = StreamSpec {
        layout: l,
        status_line: m & 1 != 0,
        images_per_capture: if m & 2 != 0 { 4 } else { 2 },
        endpoint: None,
    };
    if let Ok(d) = decode_stream(&transfers, &spec) {
        for c in &d.captures {
            assert_eq!(c.frames.dim(), (spec.images_per_capture, l.rows, l.cols));
        }
    }
}

/// The bounded `.npy` decoder every frames file and calibration array goes through: any bytes
/// give an array or an error, never a panic, and the decoder never allocates more than the
/// input's size. A decoded array re-encodes to a file that decodes to the same array.
pub fn npy(data: &[u8]) {
    let Ok(a) = npy::decode(data) else { return };
    let bytes = match &a {
        NpyArray::U16(x) => npy::encode_u16(x),
        NpyArray::F32(x) => npy::encode_f32(x),
        NpyArray::F64(x) => npy::encode_f64(x),
    };
    let b = npy::decode(&bytes).expect("a re-encoded array decodes");
    match (&a, &b) {
        (NpyArray::U16(x), NpyArray::U16(y)) => assert_eq!(x, y),
        // bit patterns: NaN payloads must survive too
        (NpyArray::F32(x), NpyArray::F32(y)) => {
            assert_eq!(x.shape(), y.shape());
            assert!(x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits()));
        }
        (NpyArray::F64(x), NpyArray::F64(y)) => {
            assert_eq!(x.shape(), y.shape());
            assert!(x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits()));
        }
        _ => panic!("dtype changed on re-encoding"),
    }
}

/// The `recording.toml` reader (both kinds: raw and depth, format versions 1–3, the v3
/// `[capture.second_frequency]` tables included): any text gives a kind or a `FormatError`
/// naming the file, never a panic, and never allocates by a size the text merely claims
/// (window sizes and capture counts are bounded before anything is sized). A valid header
/// stays valid when its own validation is run again.
pub fn recording_header(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("REC/recording.toml");
    match validate_recording_toml(path, text) {
        Ok(kind) => assert_eq!(validate_recording_toml(path, text).ok(), Some(kind)),
        Err(e) => assert_eq!(e.path(), Some(path), "{e}"),
    }
}

/// Payload header parsing, frame reassembly and frame content decoding.
///
/// Raw mode (first byte even): the input's first bytes choose the frame geometry and how the
/// rest is cut into payloads; must never panic and a delivered frame always has exactly the
/// expected size.
///
/// Structured mode (first byte odd): valid frames (status line + CRC) are built, split into
/// payloads, and mutated as the input says (drop, truncate, duplicate, swap, flip any byte).
/// Invariant: every frame that passes the reassembler **and** the content check is
/// byte-identical to a frame that was sent.
pub fn reassembly(data: &[u8]) {
    let [mode, cols, rows, pad, cut, rest @ ..] = data else {
        return;
    };
    let cols = usize::from(*cols % 32) + 10;
    let rows = usize::from(*rows % 8) + 1;
    let frame_bytes = (rows + 1) * cols * 2;
    if mode % 2 == 0 {
        let pad_align = usize::from(*pad % 32) + 1;
        let cut = usize::from(*cut) + 2;
        let mut r = Reassembler::new(FrameSpec {
            frame_bytes,
            pad_align,
        });
        let mut out = vec![0u16; rows * cols];
        for payload in rest.chunks(cut) {
            let _ = parse_header(payload);
            if let Push::Frame(f) = r.push(payload) {
                assert_eq!(f.len(), frame_bytes);
                let _ = decode_frame(f, cols, rows, 12, true, &mut out);
            }
        }
        return;
    }
    // structured
    let n_frames = usize::from(*pad % 4) + 1;
    let payload_max = usize::from(*cut % 96) + 14;
    let sent: Vec<Vec<u16>> = (0..n_frames)
        .map(|f| {
            (0..rows * cols)
                .map(|i| ((i * 7 + f * 131) % 4096) as u16)
                .collect()
        })
        .collect();
    let mut payloads: Vec<Vec<u8>> = Vec::new();
    for (f, px) in sent.iter().enumerate() {
        let st = StatusLine {
            frame_counter: f as u16,
            raw_index: f as u16,
            row0: 0,
            rows: rows as u16,
            exposure_reg: 100,
            phase_reg: 0,
            illumination: true,
            crc32: 0,
        };
        payloads.extend(split_frame(
            &encode_frame(px, cols, Some(st)),
            f % 2 == 1,
            0,
            payload_max,
        ));
    }
    for op in rest.chunks_exact(3) {
        if payloads.is_empty() {
            break;
        }
        let i = usize::from(op[1]) % payloads.len();
        match op[0] % 5 {
            0 => {
                payloads.remove(i);
            }
            1 => {
                let l = payloads[i].len();
                payloads[i].truncate(l.saturating_sub(usize::from(op[2]) + 1));
            }
            2 => {
                let d = payloads[i].clone();
                payloads.insert(i, d);
            }
            3 => {
                let j = usize::from(op[2]) % payloads.len();
                payloads.swap(i, j);
            }
            _ => {
                let l = payloads[i].len();
                if l > 0 {
                    let at = usize::from(op[2]) % l;
                    payloads[i][at] ^= 1 << (op[1] % 8);
                }
            }
        }
    }
    let mut r = Reassembler::new(FrameSpec {
        frame_bytes,
        pad_align: 1,
    });
    let mut out = vec![0u16; rows * cols];
    for p in &payloads {
        if let Push::Frame(f) = r.push(p) {
            assert_eq!(f.len(), frame_bytes);
            if let Ok(Some(st)) = decode_frame(f, cols, rows, 12, true, &mut out) {
                // CRC-32 can in principle collide; with these sizes and
                // structured mutations a collision would be a real finding.
                assert!(
                    sent.iter().any(|s| s == &out),
                    "a frame passed every check but was never sent (status {st:?})"
                );
            }
        }
    }
}
