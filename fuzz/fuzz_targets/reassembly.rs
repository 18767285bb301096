//! Fuzz payload header parsing, frame reassembly and frame content
//! decoding: the input's first bytes choose the frame geometry and how the
//! rest is cut into payloads. Must never panic; a delivered frame always has
//! exactly the expected size.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tofprox_bridge::frame::decode_frame;
use tofprox_bridge::uvc::{FrameSpec, Push, Reassembler, parse_header};

fuzz_target!(|data: &[u8]| {
    let [cols, rows, pad, cut, rest @ ..] = data else { return };
    let cols = usize::from(*cols % 32) + 10;
    let rows = usize::from(*rows % 8) + 1;
    let frame_bytes = (rows + 1) * cols * 2;
    let pad_align = usize::from(*pad % 32) + 1;
    let cut = usize::from(*cut) + 2;
    let mut r = Reassembler::new(FrameSpec { frame_bytes, pad_align });
    let mut out = vec![0u16; rows * cols];
    for payload in rest.chunks(cut) {
        let _ = parse_header(payload);
        if let Push::Frame(f) = r.push(payload) {
            assert_eq!(f.len(), frame_bytes);
            let _ = decode_frame(f, cols, rows, 12, true, &mut out);
        }
    }
});
