//! Captures of a camera's USB stream, as Linux `usbmon` records them (pure, no I/O).
//!
//! Two forms (facts from the kernel's `Documentation/usb/usbmon.rst` and libpcap's link types):
//! - **pcap / pcapng** files written by `tcpdump -i usbmonN -w f.pcap` or Wireshark: each packet
//!   is a `usbmon_packet` header (link type 220 `USB_LINUX_MMAPPED`, 64 bytes; or 189
//!   `USB_LINUX`, 48 bytes) followed by the transfer's data, all of it when the snap length
//!   allows.
//! - **usbmon text** (`cat /sys/kernel/debug/usb/usbmon/1u`): one line per event; the kernel
//!   shows at most 32 bytes of a transfer's data, so a text capture only carries whole payloads
//!   that short. Longer ones are refused as truncated (never decoded from a part).
//!
//! Only completed bulk-IN transfers (`C`, bulk, direction in, status 0) are kept: they carry the
//! video payloads. Headers are read little-endian (the byte order of x86-64 and ARM hosts); a
//! big-endian capture is refused.

use pcap_file::pcap::PcapReader;
use pcap_file::pcapng::{Block, PcapNgReader};

/// One completed bulk-IN transfer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BulkIn {
    /// Capture time, ns since the capture's epoch.
    pub time_ns: u64,
    /// USB bus number.
    pub bus: u16,
    /// Device address on the bus.
    pub device: u8,
    /// Endpoint address (bit 7 set: IN).
    pub endpoint: u8,
    /// The transfer's data, complete.
    pub data: Vec<u8>,
}

/// Why a capture cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// Neither pcap, pcapng nor usbmon text.
    #[error("not a pcap, pcapng or usbmon text capture")]
    UnknownFormat,
    /// The pcap/pcapng container is broken.
    #[error("pcap: {0}")]
    Pcap(#[from] pcap_file::PcapError),
    /// A link type that is not a usbmon capture.
    #[error("link type {0} is not a Linux usbmon capture (189 or 220)")]
    LinkType(u32),
    /// A big-endian capture.
    #[error("big-endian capture: not supported")]
    BigEndian,
    /// A record shorter than its header says.
    #[error("record {record}: {reason}")]
    Record {
        /// Index of the record (packet or line, from 0).
        record: usize,
        /// What is wrong.
        reason: String,
    },
    /// A bulk-IN transfer whose data was not captured whole.
    #[error(
        "record {record}: {captured} of {length} data bytes captured (snap length too short, \
         or usbmon's text interface, which shows at most 32 bytes: capture with \
         `tcpdump -i usbmonN -s 0 -w file.pcap` or Wireshark)"
    )]
    Truncated {
        /// Index of the record.
        record: usize,
        /// Bytes captured.
        captured: usize,
        /// Bytes transferred.
        length: usize,
    },
}

/// Largest capture file read, bytes (`tofprox device decode` reads it through the bounded
/// reader, `tofprox_format::limits::read_bounded`).
pub const MAX_CAPTURE_BYTES: u64 = 1 << 30;

const LINKTYPE_USB_LINUX: u32 = 189;
const LINKTYPE_USB_LINUX_MMAPPED: u32 = 220;
const XFER_BULK: u8 = 3;

/// Read a capture in any supported form (detected from its first bytes).
pub fn read_capture(bytes: &[u8]) -> Result<Vec<BulkIn>, CaptureError> {
    match bytes.get(..4) {
        Some([0xd4, 0xc3, 0xb2, 0xa1] | [0x4d, 0x3c, 0xb2, 0xa1]) => read_pcap(bytes),
        Some([0xa1, 0xb2, 0xc3, 0xd4] | [0xa1, 0xb2, 0x3c, 0x4d]) => Err(CaptureError::BigEndian),
        Some([0x0a, 0x0d, 0x0d, 0x0a]) => read_pcapng(bytes),
        _ => match std::str::from_utf8(bytes) {
            Ok(text) if !text.trim().is_empty() => read_text(text),
            _ => Err(CaptureError::UnknownFormat),
        },
    }
}

fn read_pcap(bytes: &[u8]) -> Result<Vec<BulkIn>, CaptureError> {
    let mut r = PcapReader::new(bytes)?;
    let link = u32::from(r.header().datalink);
    let mut out = Vec::new();
    let mut record = 0;
    while let Some(p) = r.next_packet() {
        let p = p?;
        if let Some(t) = parse_usbmon(record, link, &p.data)? {
            out.push(t);
        }
        record += 1;
    }
    Ok(out)
}

fn read_pcapng(bytes: &[u8]) -> Result<Vec<BulkIn>, CaptureError> {
    let mut r = PcapNgReader::new(bytes)?;
    if r.section().endianness == pcap_file::Endianness::Big {
        return Err(CaptureError::BigEndian);
    }
    let mut links = Vec::new();
    let mut out = Vec::new();
    let mut record = 0;
    while let Some(b) = r.next_block() {
        match b? {
            Block::InterfaceDescription(idb) => links.push(u32::from(idb.linktype)),
            Block::EnhancedPacket(epb) => {
                let link = links
                    .get(epb.interface_id as usize)
                    .copied()
                    .ok_or_else(|| CaptureError::Record {
                        record,
                        reason: format!("packet of undeclared interface {}", epb.interface_id),
                    })?;
                if let Some(t) = parse_usbmon(record, link, &epb.data)? {
                    out.push(t);
                }
                record += 1;
            }
            _ => {}
        }
    }
    Ok(out)
}

fn le_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// One `usbmon_packet` (header + data): `Some` for a completed bulk-IN transfer.
fn parse_usbmon(record: usize, link: u32, b: &[u8]) -> Result<Option<BulkIn>, CaptureError> {
    let head = match link {
        LINKTYPE_USB_LINUX_MMAPPED => 64,
        LINKTYPE_USB_LINUX => 48,
        other => return Err(CaptureError::LinkType(other)),
    };
    if b.len() < head {
        let reason = format!(
            "{} bytes, shorter than the {head}-byte usbmon header",
            b.len()
        );
        return Err(CaptureError::Record { record, reason });
    }
    let (event, xfer, ep, device) = (b[8], b[9], b[10], b[11]);
    let status = le_u32(b, 28) as i32;
    if event != b'C' || xfer != XFER_BULK || ep & 0x80 == 0 || status != 0 {
        return Ok(None);
    }
    let bus = u16::from_le_bytes([b[12], b[13]]);
    let secs = u64::from_le_bytes(b[16..24].try_into().unwrap_or_default());
    let usecs = u64::from(le_u32(b, 24));
    let (length, captured) = (le_u32(b, 32) as usize, le_u32(b, 36) as usize);
    let data = &b[head..];
    if captured < length || data.len() < length {
        let captured = captured.min(data.len());
        return Err(CaptureError::Truncated {
            record,
            captured,
            length,
        });
    }
    Ok(Some(BulkIn {
        time_ns: secs
            .saturating_mul(1_000_000_000)
            .saturating_add(usecs.saturating_mul(1000)),
        bus,
        device,
        endpoint: ep,
        data: data[..length].to_vec(),
    }))
}

/// usbmon text (`1u` or `1t`): `tag timestamp_us event address status length [= words…]`.
fn read_text(text: &str) -> Result<Vec<BulkIn>, CaptureError> {
    let mut out = Vec::new();
    for (record, line) in text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
    {
        if let Some(t) =
            parse_text_line(line).map_err(|reason| CaptureError::Record { record, reason })?
        {
            if t.1 < t.0.data.len() || t.0.data.len() < t.1 {
                return Err(CaptureError::Truncated {
                    record,
                    captured: t.0.data.len(),
                    length: t.1,
                });
            }
            out.push(t.0);
        }
    }
    Ok(out)
}

/// One text line: `Some((transfer, data length))` for a completed bulk-IN transfer.
fn parse_text_line(line: &str) -> Result<Option<(BulkIn, usize)>, String> {
    let w: Vec<&str> = line.split_whitespace().collect();
    if w.len() < 6 {
        return Err(format!("{} words, a usbmon event has at least 6", w.len()));
    }
    let time_us: u64 = w[1].parse().map_err(|_| format!("timestamp {:?}", w[1]))?;
    // address: "Bi:1:002:2" (1u) or "Bi:002:2" (1t): type+direction, [bus,] device, endpoint
    let a: Vec<&str> = w[3].split(':').collect();
    if w[2] != "C" || a.first() != Some(&"Bi") || w[4] != "0" {
        return Ok(None);
    }
    let num = |s: &str| s.parse::<u16>().map_err(|_| format!("address {:?}", w[3]));
    let (bus, device, ep) = match a.as_slice() {
        [_, bus, dev, ep] => (num(bus)?, num(dev)?, num(ep)?),
        [_, dev, ep] => (0, num(dev)?, num(ep)?),
        _ => return Err(format!("address {:?}", w[3])),
    };
    let length: usize = w[5]
        .parse()
        .map_err(|_| format!("data length {:?}", w[5]))?;
    let mut data = Vec::with_capacity(length.min(32));
    if w.get(6) == Some(&"=") {
        for word in &w[7..] {
            parse_hex_word(word, &mut data).ok_or_else(|| format!("data word {word:?}"))?;
        }
    }
    let endpoint = u8::try_from(ep).map_err(|_| format!("endpoint {ep}"))? | 0x80;
    let device = u8::try_from(device).map_err(|_| format!("device {device}"))?;
    let transfer = BulkIn {
        time_ns: time_us.saturating_mul(1000),
        bus,
        device,
        endpoint,
        data,
    };
    Ok(Some((transfer, length)))
}

/// One data word of hex digit pairs (`0c8d0102`) appended to `out`; `None` for an odd count or
/// any byte that is not an ASCII hex digit (worked on bytes: a multi-byte character is refused,
/// never sliced through).
fn parse_hex_word(word: &str, out: &mut Vec<u8>) -> Option<()> {
    let b = word.as_bytes();
    if !b.len().is_multiple_of(2) {
        return None;
    }
    let digit = |c: u8| {
        char::from(c)
            .to_digit(16)
            .and_then(|d| u8::try_from(d).ok())
    };
    for pair in b.chunks_exact(2) {
        out.push(digit(pair[0])? << 4 | digit(pair[1])?);
    }
    Some(())
}

/// The bulk-IN endpoint `(bus, device, endpoint)` that carried the most bytes: the video stream.
pub fn busiest_endpoint(transfers: &[BulkIn]) -> Option<(u16, u8, u8)> {
    let mut bytes = std::collections::BTreeMap::<(u16, u8, u8), usize>::new();
    for t in transfers {
        *bytes.entry((t.bus, t.device, t.endpoint)).or_default() += t.data.len();
    }
    bytes.into_iter().max_by_key(|(_, n)| *n).map(|(k, _)| k)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A classic pcap of link type 220 written byte by byte from the kernel's
    /// `struct usbmon_packet` layout (not through the reader under test).
    /// (event, transfer type, endpoint, status, captured data, transfer length)
    type Record<'a> = (u8, u8, u8, i32, &'a [u8], u32);

    fn pcap(records: &[Record]) -> Vec<u8> {
        let mut f = Vec::new();
        f.extend_from_slice(&0xa1b2_c3d4u32.to_le_bytes());
        f.extend_from_slice(&2u16.to_le_bytes());
        f.extend_from_slice(&4u16.to_le_bytes());
        f.extend_from_slice(&[0; 8]); // thiszone, sigfigs
        f.extend_from_slice(&262_144u32.to_le_bytes());
        f.extend_from_slice(&LINKTYPE_USB_LINUX_MMAPPED.to_le_bytes());
        for (i, (event, xfer, ep, status, data, length)) in records.iter().enumerate() {
            let mut h = vec![0u8; 64];
            h[8] = *event;
            h[9] = *xfer;
            h[10] = *ep;
            h[11] = 5; // device
            h[12..14].copy_from_slice(&2u16.to_le_bytes());
            h[16..24].copy_from_slice(&(100u64 + i as u64).to_le_bytes());
            h[24..28].copy_from_slice(&250u32.to_le_bytes());
            h[28..32].copy_from_slice(&status.to_le_bytes());
            h[32..36].copy_from_slice(&length.to_le_bytes());
            h[36..40].copy_from_slice(&(data.len() as u32).to_le_bytes());
            h.extend_from_slice(data);
            f.extend_from_slice(&(100u32 + i as u32).to_le_bytes());
            f.extend_from_slice(&0u32.to_le_bytes());
            f.extend_from_slice(&(h.len() as u32).to_le_bytes());
            f.extend_from_slice(&(h.len() as u32).to_le_bytes());
            f.extend_from_slice(&h);
        }
        f
    }

    #[test]
    fn pcap_keeps_completed_bulk_in_only() {
        let f = pcap(&[
            (b'S', 3, 0x81, -115, &[], 512),   // submission
            (b'C', 3, 0x81, 0, &[1, 2, 3], 3), // the one to keep
            (b'C', 2, 0x80, 0, &[9], 1),       // control
            (b'C', 3, 0x02, 0, &[7], 1),       // bulk OUT
            (b'C', 3, 0x81, -71, &[], 0),      // protocol error
        ]);
        let t = read_capture(&f).unwrap();
        assert_eq!(t.len(), 1);
        assert_eq!(
            t[0],
            BulkIn {
                time_ns: 101_000_250_000,
                bus: 2,
                device: 5,
                endpoint: 0x81,
                data: vec![1, 2, 3]
            }
        );
    }

    #[test]
    fn truncated_data_is_refused() {
        let f = pcap(&[(b'C', 3, 0x81, 0, &[1, 2], 1024)]);
        let e = read_capture(&f).unwrap_err();
        assert!(matches!(
            e,
            CaptureError::Truncated {
                record: 0,
                captured: 2,
                length: 1024
            }
        ));
    }

    #[test]
    fn usbmon_text_lines() {
        let text = "\
ffff9a0b 3575914555 S Bi:2:005:1 -115 512 <
ffff9a0b 3575914560 C Bi:2:005:1 0 6 = 0c8d0102 0304
ffff9a0c 3575914570 C Bo:2:005:2 0 4 >
";
        let t = read_capture(text.as_bytes()).unwrap();
        assert_eq!(t.len(), 1);
        assert_eq!(t[0].data, vec![0x0c, 0x8d, 1, 2, 3, 4]);
        assert_eq!((t[0].bus, t[0].device, t[0].endpoint), (2, 5, 0x81));
        assert_eq!(t[0].time_ns, 3_575_914_560_000);
        // the text interface cut the data: refused
        let cut = "ffff9a0b 3575914560 C Bi:2:005:1 0 1024 = 0c8d0102 03040506\n";
        assert!(matches!(
            read_capture(cut.as_bytes()),
            Err(CaptureError::Truncated { length: 1024, .. })
        ));
    }

    /// Issue 35 N1: a non-ASCII byte inside a data word was sliced through (a panic); every
    /// malformed word is now a record error naming the line.
    #[test]
    fn text_data_words_that_are_not_hex_are_record_errors() {
        for line in [
            "ffff 1 C Bi:3:007:2 0 2 = a\u{e9}b\n",
            "ffff 1 C Bi:3:007:2 0 2 = \u{e9}\u{e9}\n",
            "ffff 1 C Bi:3:007:2 0 1 = 0\n",
            "ffff 1 C Bi:3:007:2 0 1 = +1\n",
            "ffff 1 C Bi:3:007:2 0 1 = 0x\n",
        ] {
            let e = read_capture(line.as_bytes()).unwrap_err();
            assert!(
                matches!(&e, CaptureError::Record { record: 0, reason } if reason.starts_with("data word")),
                "{line:?}: {e}"
            );
        }
        // the exact bytes of the reproduction (0xc3 0xa9 = 'é' in UTF-8)
        let repro = b"ffff 1 C Bi:3:007:2 0 2 = a\xc3\xa9b\n";
        assert!(matches!(
            read_capture(repro),
            Err(CaptureError::Record { record: 0, .. })
        ));
        // upper-case hex is hex
        let t = read_capture(b"ffff 1 C Bi:3:007:2 0 2 = ABcd\n").unwrap();
        assert_eq!(t[0].data, vec![0xab, 0xcd]);
    }

    /// Timestamps at the top of their range saturate instead of overflowing.
    #[test]
    fn huge_timestamps_saturate() {
        let t = read_capture(b"ffff 18446744073709551615 C Bi:3:007:2 0 1 = 01\n").unwrap();
        assert_eq!(t[0].time_ns, u64::MAX);
    }

    #[test]
    fn strangers_are_refused() {
        assert!(matches!(
            read_capture(&[0xff, 0, 1, 2, 3]),
            Err(CaptureError::UnknownFormat)
        ));
        assert!(matches!(
            read_capture(b"hello world"),
            Err(CaptureError::Record { record: 0, .. })
        ));
    }
}
