//! Layer 2b: UVC-style payload headers and frame reassembly (pure, no I/O).
//!
//! Every bulk transfer carries one payload: a header (UVC 1.5, 2.4.3.3) and
//! image bytes. A frame is the concatenation of the payloads sharing one
//! frame id (FID), closed by the end-of-frame (EOF) bit. The
//! [`Reassembler`] delivers a frame only when it is complete and valid;
//! everything else is dropped and counted in [`ReassemblyStats`].

use serde::Serialize;

/// Header bit: frame id (toggles every frame).
pub const BFH_FID: u8 = 0x01;
/// Header bit: end of frame.
pub const BFH_EOF: u8 = 0x02;
/// Header bit: presentation time stamp (4 bytes) present.
pub const BFH_PTS: u8 = 0x04;
/// Header bit: source clock reference (6 bytes) present.
pub const BFH_SCR: u8 = 0x08;
/// Header bit: reserved, must be 0.
pub const BFH_RES: u8 = 0x10;
/// Header bit: still image.
pub const BFH_STI: u8 = 0x20;
/// Header bit: the device reports an error in this payload.
pub const BFH_ERR: u8 = 0x40;
/// Header bit: end of header (always set: one header per payload).
pub const BFH_EOH: u8 = 0x80;

/// Length of the full header with PTS and SCR (what the CX3 sends).
pub const FULL_HEADER_LEN: usize = 12;

/// A parsed payload header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PayloadHeader {
    /// Header length in bytes (data starts here).
    pub len: usize,
    /// Frame id bit.
    pub fid: bool,
    /// End of frame.
    pub eof: bool,
    /// Presentation time stamp (device clock), when present.
    pub pts: Option<u32>,
    /// Source clock reference: (system time clock, 1 kHz SOF counter).
    pub scr: Option<(u32, u16)>,
    /// Still-image bit.
    pub still: bool,
}

/// Why a payload header is invalid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum HeaderError {
    /// Payload shorter than 2 bytes.
    TooShort,
    /// bHeaderLength smaller than 2 or beyond the payload.
    BadLength,
    /// bHeaderLength disagrees with the PTS/SCR bits.
    LengthMismatch,
    /// EOH clear or reserved bit set.
    BadBits,
    /// The device flagged an error (ERR bit).
    DeviceError,
}

impl std::fmt::Display for HeaderError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            HeaderError::TooShort => "payload shorter than a header",
            HeaderError::BadLength => "header length outside the payload",
            HeaderError::LengthMismatch => "header length disagrees with its PTS/SCR bits",
            HeaderError::BadBits => "end-of-header clear or reserved bit set",
            HeaderError::DeviceError => "device reported an error (ERR bit)",
        })
    }
}

impl std::fmt::Display for DropReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DropReason::BadHeader(h) => write!(f, "bad payload header: {h}"),
            DropReason::Torn => f.write_str("torn (frame id toggled before end of frame)"),
            DropReason::Short => f.write_str("short (end of frame before the expected size)"),
            DropReason::Oversize => f.write_str("oversize (more data than the frame size)"),
            DropReason::BadPadding => f.write_str("non-zero padding after the frame"),
            DropReason::Stray => f.write_str("stray payload of an already completed frame"),
        }
    }
}

/// Parse the header at the start of `payload`.
pub fn parse_header(payload: &[u8]) -> Result<PayloadHeader, HeaderError> {
    let (&hle, rest) = payload.split_first().ok_or(HeaderError::TooShort)?;
    let &bfh = rest.first().ok_or(HeaderError::TooShort)?;
    let len = usize::from(hle);
    if len < 2 || len > payload.len() {
        return Err(HeaderError::BadLength);
    }
    if bfh & BFH_EOH == 0 || bfh & BFH_RES != 0 {
        return Err(HeaderError::BadBits);
    }
    let has_pts = bfh & BFH_PTS != 0;
    let has_scr = bfh & BFH_SCR != 0;
    let want = 2 + if has_pts { 4 } else { 0 } + if has_scr { 6 } else { 0 };
    if len != want {
        return Err(HeaderError::LengthMismatch);
    }
    if bfh & BFH_ERR != 0 {
        return Err(HeaderError::DeviceError);
    }
    let mut at = 2;
    let u32_at = |at: &mut usize| -> Option<u32> {
        let b = payload.get(*at..*at + 4)?;
        *at += 4;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let pts = if has_pts { u32_at(&mut at) } else { None };
    let scr = if has_scr {
        let stc = u32_at(&mut at);
        let sof = payload
            .get(at..at + 2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]));
        stc.zip(sof)
    } else {
        None
    };
    Ok(PayloadHeader {
        len,
        fid: bfh & BFH_FID != 0,
        eof: bfh & BFH_EOF != 0,
        pts,
        scr,
        still: bfh & BFH_STI != 0,
    })
}

/// Write a full 12-byte header (PTS + SCR) into `out[..12]`.
pub fn write_header(
    out: &mut [u8; FULL_HEADER_LEN],
    fid: bool,
    eof: bool,
    pts: u32,
    scr: (u32, u16),
) {
    out[0] = FULL_HEADER_LEN as u8;
    out[1] =
        BFH_EOH | BFH_PTS | BFH_SCR | if fid { BFH_FID } else { 0 } | if eof { BFH_EOF } else { 0 };
    out[2..6].copy_from_slice(&pts.to_le_bytes());
    out[6..10].copy_from_slice(&scr.0.to_le_bytes());
    out[10..12].copy_from_slice(&scr.1.to_le_bytes());
}

/// Split `frame` into payloads of at most `max_payload` bytes (header
/// included), as the bridge firmware does. The last one carries EOF.
pub fn split_frame(frame: &[u8], fid: bool, pts: u32, max_payload: usize) -> Vec<Vec<u8>> {
    let chunk = max_payload.saturating_sub(FULL_HEADER_LEN).max(1);
    let n = frame.len().div_ceil(chunk).max(1);
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let start = (i * chunk).min(frame.len());
        let end = ((i + 1) * chunk).min(frame.len());
        let mut h = [0u8; FULL_HEADER_LEN];
        write_header(&mut h, fid, i + 1 == n, pts, (pts, (i & 0x7FF) as u16));
        let mut p = Vec::with_capacity(FULL_HEADER_LEN + end - start);
        p.extend_from_slice(&h);
        p.extend_from_slice(&frame[start..end]);
        out.push(p);
    }
    out
}

/// How a frame must look to be delivered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameSpec {
    /// Exact frame size in bytes (status line + pixel rows).
    pub frame_bytes: usize,
    /// Zero padding allowed after the frame, up to the next multiple of
    /// this many bytes (1 = no padding).
    pub pad_align: usize,
}

/// Why a frame was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DropReason {
    /// A payload of the frame had an invalid header.
    BadHeader(HeaderError),
    /// The frame id toggled before the end of frame (payloads lost or out of
    /// order).
    Torn,
    /// End of frame before the expected size.
    Short,
    /// More bytes than the frame size plus allowed padding.
    Oversize,
    /// Padding bytes after the frame are not zero.
    BadPadding,
    /// Payload with the frame id of the frame just completed (duplicate or
    /// out of order).
    Stray,
}

/// Counters of the reassembler (monotonic).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct ReassemblyStats {
    /// Payloads seen.
    pub payloads: u64,
    /// Frames delivered.
    pub frames_ok: u64,
    /// Frames dropped (sum of the reasons below).
    pub frames_dropped: u64,
    /// Dropped for a bad header.
    pub bad_header: u64,
    /// Dropped as torn.
    pub torn: u64,
    /// Dropped as short.
    pub short: u64,
    /// Dropped as oversize.
    pub oversize: u64,
    /// Dropped for bad padding.
    pub bad_padding: u64,
    /// Stray payloads discarded.
    pub stray: u64,
}

impl ReassemblyStats {
    fn count(&mut self, r: DropReason) {
        self.frames_dropped += 1;
        match r {
            DropReason::BadHeader(_) => self.bad_header += 1,
            DropReason::Torn => self.torn += 1,
            DropReason::Short => self.short += 1,
            DropReason::Oversize => self.oversize += 1,
            DropReason::BadPadding => self.bad_padding += 1,
            DropReason::Stray => self.stray += 1,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Waiting for the first payload of a frame; `Some(fid)` = the id of the
    /// last completed/discarded frame, which must not continue.
    Idle(Option<bool>),
    /// Collecting payloads of frame `fid`.
    Collecting(bool),
    /// Discarding the rest of frame `fid` after an error.
    Discarding(bool),
}

/// Result of feeding one payload.
#[derive(Debug, PartialEq, Eq)]
pub enum Push<'a> {
    /// Frame not complete yet.
    Pending,
    /// A complete, valid frame (exactly `frame_bytes`, padding stripped).
    Frame(&'a [u8]),
    /// A frame (or stray payload) was dropped for this reason. A new frame
    /// may have started with this payload.
    Dropped(DropReason),
}

/// Reassembles frames from payloads. Allocation-free in steady state (one
/// buffer of `frame_bytes + pad_align`).
#[derive(Debug, Clone)]
pub struct Reassembler {
    spec: FrameSpec,
    buf: Vec<u8>,
    state: State,
    stats: ReassemblyStats,
}

impl Reassembler {
    /// A reassembler for frames of `spec`.
    pub fn new(spec: FrameSpec) -> Self {
        let spec = FrameSpec {
            frame_bytes: spec.frame_bytes,
            pad_align: spec.pad_align.max(1),
        };
        Reassembler {
            buf: Vec::with_capacity(spec.frame_bytes + spec.pad_align),
            spec,
            state: State::Idle(None),
            stats: ReassemblyStats::default(),
        }
    }

    /// The frame spec.
    pub fn spec(&self) -> FrameSpec {
        self.spec
    }

    /// Change the expected frame (e.g. a new row window); drops any partial
    /// frame silently (not counted) and forgets the FID history.
    pub fn reset(&mut self, spec: FrameSpec) {
        self.spec = FrameSpec {
            frame_bytes: spec.frame_bytes,
            pad_align: spec.pad_align.max(1),
        };
        self.buf.clear();
        self.buf
            .reserve(self.spec.frame_bytes + self.spec.pad_align);
        self.state = State::Idle(None);
    }

    /// Counters so far.
    pub fn stats(&self) -> ReassemblyStats {
        self.stats
    }

    fn max_len(&self) -> usize {
        self.spec.frame_bytes.div_ceil(self.spec.pad_align) * self.spec.pad_align
    }

    fn drop_frame(&mut self, fid: bool, r: DropReason) -> Push<'_> {
        self.buf.clear();
        self.state = State::Discarding(fid);
        self.stats.count(r);
        Push::Dropped(r)
    }

    /// Feed one payload (one bulk transfer).
    pub fn push(&mut self, payload: &[u8]) -> Push<'_> {
        self.stats.payloads += 1;
        let h = match parse_header(payload) {
            Ok(h) => h,
            Err(e) => {
                // We cannot trust its FID: whatever frame is in flight is
                // lost; discard until the FID toggles.
                let fid = match self.state {
                    State::Collecting(f) | State::Discarding(f) => f,
                    State::Idle(Some(f)) => f,
                    State::Idle(None) => {
                        // Nothing in flight and no history: drop counted,
                        // then resynchronise on the next good header.
                        self.stats.count(DropReason::BadHeader(e));
                        return Push::Dropped(DropReason::BadHeader(e));
                    }
                };
                if matches!(self.state, State::Discarding(_)) {
                    return Push::Pending;
                }
                return self.drop_frame(fid, DropReason::BadHeader(e));
            }
        };
        let data = payload.get(h.len..).unwrap_or(&[]);
        let mut torn = false;
        match self.state {
            State::Collecting(f) if f == h.fid => {}
            State::Collecting(_) => {
                // FID toggled mid-frame: the old frame is torn; this payload
                // starts the next one.
                torn = true;
                self.stats.count(DropReason::Torn);
                self.buf.clear();
                self.state = State::Collecting(h.fid);
            }
            State::Discarding(f) | State::Idle(Some(f)) if f == h.fid => {
                if matches!(self.state, State::Idle(_)) {
                    self.stats.count(DropReason::Stray);
                    self.state = State::Discarding(f);
                    return Push::Dropped(DropReason::Stray);
                }
                if h.eof {
                    self.state = State::Idle(Some(f));
                }
                return Push::Pending;
            }
            State::Discarding(_) | State::Idle(_) => {
                self.buf.clear();
                self.state = State::Collecting(h.fid);
            }
        }
        if self.buf.len() + data.len() > self.max_len() {
            return self.drop_frame(h.fid, DropReason::Oversize);
        }
        self.buf.extend_from_slice(data);
        if !h.eof {
            return if torn {
                Push::Dropped(DropReason::Torn)
            } else {
                Push::Pending
            };
        }
        self.state = State::Idle(Some(h.fid));
        let n = self.spec.frame_bytes;
        if self.buf.len() < n {
            self.buf.clear();
            self.stats.count(DropReason::Short);
            return Push::Dropped(DropReason::Short);
        }
        if self
            .buf
            .get(n..)
            .is_some_and(|pad| pad.iter().any(|&b| b != 0))
        {
            self.buf.clear();
            self.stats.count(DropReason::BadPadding);
            return Push::Dropped(DropReason::BadPadding);
        }
        // (A torn predecessor was counted above; this payload alone formed a
        // complete, valid frame, which is delivered.)
        self.stats.frames_ok += 1;
        self.buf.truncate(n);
        let out: &[u8] = &self.buf;
        Push::Frame(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(n: usize, seed: u8) -> Vec<u8> {
        (0..n)
            .map(|i| (i as u8).wrapping_mul(7).wrapping_add(seed))
            .collect()
    }

    fn spec(n: usize) -> FrameSpec {
        FrameSpec {
            frame_bytes: n,
            pad_align: 1,
        }
    }

    #[test]
    fn header_round_trip() {
        let mut h = [0u8; 12];
        write_header(&mut h, true, true, 0xDEADBEEF, (7, 9));
        assert_eq!(h, [12, 0x8F, 0xEF, 0xBE, 0xAD, 0xDE, 7, 0, 0, 0, 9, 0]);
        let p = parse_header(&h).unwrap();
        assert!(p.fid && p.eof);
        assert_eq!(p.pts, Some(0xDEADBEEF));
        assert_eq!(p.scr, Some((7, 9)));
        assert_eq!(p.len, 12);
    }

    #[test]
    fn header_errors() {
        assert_eq!(parse_header(&[]), Err(HeaderError::TooShort));
        assert_eq!(parse_header(&[2]), Err(HeaderError::TooShort));
        assert_eq!(parse_header(&[13, 0x8C, 0, 0]), Err(HeaderError::BadLength));
        assert_eq!(parse_header(&[1, 0x80]), Err(HeaderError::BadLength));
        assert_eq!(parse_header(&[2, 0x00]), Err(HeaderError::BadBits));
        assert_eq!(parse_header(&[2, 0x90]), Err(HeaderError::BadBits));
        assert_eq!(
            parse_header(&[2, 0x84, 0, 0, 0, 0]),
            Err(HeaderError::LengthMismatch)
        );
        assert_eq!(parse_header(&[2, 0xC0]), Err(HeaderError::DeviceError));
        let ok = parse_header(&[6, 0x86, 1, 0, 0, 0, 0xAA]).unwrap();
        assert_eq!((ok.len, ok.pts, ok.eof), (6, Some(1), true));
        assert!(parse_header(&[2, 0x80]).is_ok());
    }

    #[test]
    fn frames_reassemble_across_payloads() {
        let f0 = frame(1000, 1);
        let f1 = frame(1000, 2);
        let mut r = Reassembler::new(spec(1000));
        let mut got = Vec::new();
        for (i, f) in [&f0, &f1].iter().enumerate() {
            for p in split_frame(f, i % 2 == 1, 5, 300) {
                if let Push::Frame(x) = r.push(&p) {
                    got.push(x.to_vec());
                }
            }
        }
        assert_eq!(got, vec![f0, f1]);
        assert_eq!(r.stats().frames_ok, 2);
        assert_eq!(r.stats().frames_dropped, 0);
    }

    #[test]
    fn short_frame_dropped() {
        let mut r = Reassembler::new(spec(1000));
        let ps = split_frame(&frame(900, 0), false, 0, 300);
        let mut last = Push::Pending;
        for p in &ps {
            last = r.push(p);
            if let Push::Frame(_) = last {
                panic!("short frame delivered");
            }
        }
        assert_eq!(last, Push::Dropped(DropReason::Short));
        assert_eq!(r.stats().short, 1);
    }

    #[test]
    fn torn_frame_dropped_and_next_delivered() {
        let mut r = Reassembler::new(spec(1000));
        let a = split_frame(&frame(1000, 1), false, 0, 300);
        let b = split_frame(&frame(1000, 2), true, 0, 300);
        // first two payloads of a, then all of b
        assert_eq!(r.push(&a[0]), Push::Pending);
        assert_eq!(r.push(&a[1]), Push::Pending);
        assert_eq!(r.push(&b[0]), Push::Dropped(DropReason::Torn));
        let mut delivered = None;
        for p in &b[1..] {
            if let Push::Frame(x) = r.push(p) {
                delivered = Some(x.to_vec());
            }
        }
        assert_eq!(delivered, Some(frame(1000, 2)));
        assert_eq!(r.stats().torn, 1);
    }

    #[test]
    fn bad_header_mid_frame_drops_until_fid_toggles() {
        let mut r = Reassembler::new(spec(1000));
        let mut a = split_frame(&frame(1000, 1), false, 0, 300);
        a[1][1] |= BFH_ERR;
        let b = split_frame(&frame(1000, 2), true, 0, 300);
        let mut frames = 0;
        let mut drops = 0;
        for p in a.iter().chain(b.iter()) {
            match r.push(p) {
                Push::Frame(x) => {
                    assert_eq!(x, &frame(1000, 2)[..]);
                    frames += 1;
                }
                Push::Dropped(_) => drops += 1,
                Push::Pending => {}
            }
        }
        assert_eq!((frames, drops), (1, 1));
        assert_eq!(r.stats().bad_header, 1);
    }

    #[test]
    fn oversize_and_padding() {
        let mut r = Reassembler::new(FrameSpec {
            frame_bytes: 10,
            pad_align: 16,
        });
        // 10 bytes + 6 zero padding is fine
        let mut f = frame(10, 3);
        f.extend_from_slice(&[0; 6]);
        let p = split_frame(&f, false, 0, 64);
        assert_eq!(r.push(&p[0]), Push::Frame(&frame(10, 3)[..]));
        // non-zero padding
        let mut g = frame(10, 3);
        g.extend_from_slice(&[0, 0, 1]);
        let p = split_frame(&g, true, 0, 64);
        assert_eq!(r.push(&p[0]), Push::Dropped(DropReason::BadPadding));
        // 17 bytes: oversize
        let p = split_frame(&frame(17, 0), false, 0, 64);
        assert_eq!(r.push(&p[0]), Push::Dropped(DropReason::Oversize));
    }

    #[test]
    fn repeated_fid_after_eof_is_stray() {
        let mut r = Reassembler::new(spec(8));
        let p = split_frame(&frame(8, 0), false, 0, 64);
        assert!(matches!(r.push(&p[0]), Push::Frame(_)));
        assert_eq!(r.push(&p[0]), Push::Dropped(DropReason::Stray));
        let q = split_frame(&frame(8, 1), true, 0, 64);
        assert!(matches!(r.push(&q[0]), Push::Frame(_)));
    }
}
