//! Property tests of payload parsing and frame reassembly.

use proptest::prelude::*;
use tofprox_bridge::uvc::{FrameSpec, Push, Reassembler, parse_header, split_frame};

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Arbitrary byte streams cut into arbitrary payloads: never a panic,
    /// every delivered frame has exactly the frame size, counters agree.
    #[test]
    fn arbitrary_streams_never_panic(
        stream in proptest::collection::vec(any::<u8>(), 0..4096),
        cuts in proptest::collection::vec(0usize..600, 1..40),
        frame_bytes in 1usize..512,
        pad_align in 1usize..32,
    ) {
        let mut r = Reassembler::new(FrameSpec { frame_bytes, pad_align });
        let mut delivered = 0u64;
        let mut at = 0;
        for c in cuts.iter().cycle().take(400) {
            if at >= stream.len() { break; }
            let end = (at + c).min(stream.len());
            let _ = parse_header(&stream[at..end]);
            if let Push::Frame(f) = r.push(&stream[at..end]) {
                prop_assert_eq!(f.len(), frame_bytes);
                delivered += 1;
            }
            at = end;
        }
        let s = r.stats();
        prop_assert_eq!(s.frames_ok, delivered);
        prop_assert_eq!(s.frames_dropped, s.bad_header + s.torn + s.short + s.oversize + s.bad_padding + s.stray);
    }

    /// Valid frames with at most one structural mutation each (payload
    /// dropped, truncated, duplicated, or a header byte changed): every
    /// delivered frame is byte-identical to one of the originals.
    #[test]
    fn mutations_never_deliver_a_wrong_frame(
        n_frames in 1usize..6,
        frame_bytes in 8usize..400,
        payload_max in 14usize..120,
        mutations in proptest::collection::vec((0u8..5, any::<u16>(), any::<u8>()), 6),
    ) {
        let frames: Vec<Vec<u8>> = (0..n_frames)
            .map(|f| (0..frame_bytes).map(|i| (i * 31 + f * 17 + 1) as u8).collect())
            .collect();
        let mut stream: Vec<Vec<u8>> = Vec::new();
        for (f, data) in frames.iter().enumerate() {
            let mut ps = split_frame(data, f % 2 == 1, f as u32, payload_max);
            let (kind, pick, val) = mutations[f];
            let j = usize::from(pick) % ps.len();
            match kind {
                1 => { ps.remove(j); }
                2 => { let l = ps[j].len(); ps[j].truncate(l - 1 - usize::from(val) % (l - 12).max(1)); }
                3 => { let d = ps[j].clone(); ps.insert(j, d); }
                4 => { ps[j][usize::from(val) % 12] ^= 1 << (pick % 8); }
                _ => {}
            }
            stream.extend(ps);
        }
        let mut r = Reassembler::new(FrameSpec { frame_bytes, pad_align: 1 });
        let mut got = 0;
        for p in &stream {
            if let Push::Frame(f) = r.push(p) {
                prop_assert!(frames.iter().any(|o| o.as_slice() == f), "delivered a frame that was never sent");
                got += 1;
            }
        }
        if mutations.iter().take(n_frames).all(|m| m.0 == 0) {
            prop_assert_eq!(got, n_frames);
        }
    }
}
