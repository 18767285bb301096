//! Raw frame layout inside a reassembled frame (pure, no I/O): an optional
//! status line followed by `rows × cols` little-endian 16-bit pixel words
//! with `adc_bits` significant bits.

/// First word of a status line.
pub const STATUS_MAGIC: u16 = 0x5354;
/// Words of the status line that carry data (the rest must be zero).
pub const STATUS_WORDS: usize = 10;

/// The status line the sensor puts before the pixel rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StatusLine {
    /// Frame counter since the measurement started (wraps).
    pub frame_counter: u16,
    /// Index of this raw image within the measurement (0-based).
    pub raw_index: u16,
    /// First row of the window.
    pub row0: u16,
    /// Rows in the frame.
    pub rows: u16,
    /// Exposure register value used.
    pub exposure_reg: u16,
    /// Phase register value used.
    pub phase_reg: u16,
    /// Illumination on.
    pub illumination: bool,
    /// CRC-32 (IEEE) of the pixel bytes.
    pub crc32: u32,
}

impl StatusLine {
    /// Encode into `line` (one row of `cols` words as bytes, zero filled).
    pub fn encode(&self, line: &mut [u8]) {
        line.fill(0);
        let words = [
            STATUS_MAGIC,
            self.frame_counter,
            self.raw_index,
            self.row0,
            self.rows,
            self.exposure_reg,
            self.phase_reg,
            u16::from(self.illumination),
            (self.crc32 & 0xFFFF) as u16,
            (self.crc32 >> 16) as u16,
        ];
        for (dst, w) in line.chunks_exact_mut(2).zip(words) {
            dst.copy_from_slice(&w.to_le_bytes());
        }
    }

    /// Decode a status line; `None` if the magic or the zero tail is wrong.
    pub fn decode(line: &[u8]) -> Option<StatusLine> {
        let w = |i: usize| -> Option<u16> {
            let b = line.get(2 * i..2 * i + 2)?;
            Some(u16::from_le_bytes([b[0], b[1]]))
        };
        if w(0)? != STATUS_MAGIC || line.len() < 2 * STATUS_WORDS {
            return None;
        }
        if line[2 * STATUS_WORDS..].iter().any(|&b| b != 0) {
            return None;
        }
        let illum = w(7)?;
        if illum > 1 {
            return None;
        }
        Some(StatusLine {
            frame_counter: w(1)?,
            raw_index: w(2)?,
            row0: w(3)?,
            rows: w(4)?,
            exposure_reg: w(5)?,
            phase_reg: w(6)?,
            illumination: illum == 1,
            crc32: u32::from(w(8)?) | (u32::from(w(9)?) << 16),
        })
    }
}

/// Why a reassembled frame's content is rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ContentError {
    /// Frame size differs from the layout.
    Size,
    /// Status line missing or malformed.
    StatusLine,
    /// Pixel CRC mismatch.
    Checksum,
    /// A pixel word has bits above `adc_bits`.
    PixelRange,
}

/// Validate a frame and copy its pixels into `out` (`rows × cols` words).
/// Returns the status line, if the layout has one.
pub fn decode_frame(
    frame: &[u8],
    cols: usize,
    rows: usize,
    adc_bits: u8,
    status_line: bool,
    out: &mut [u16],
) -> Result<Option<StatusLine>, ContentError> {
    let line_bytes = cols * 2;
    let head = if status_line { line_bytes } else { 0 };
    if frame.len() != head + rows * line_bytes || out.len() != rows * cols {
        return Err(ContentError::Size);
    }
    let (line, pixels) = frame.split_at(head);
    let status = if status_line {
        let s = StatusLine::decode(line).ok_or(ContentError::StatusLine)?;
        if crc32fast::hash(pixels) != s.crc32 {
            return Err(ContentError::Checksum);
        }
        Some(s)
    } else {
        None
    };
    // the map's adc_bits is validated to at most 16 bits: the rail fits in u16
    let limit = u16::try_from(tofprox_core::sensor::adc_max_code(adc_bits)).unwrap_or(u16::MAX);
    // one pass: the words and their OR (a bit above the ADC's range in any word)
    if crate::pixels::unpack_raw16_line(pixels, out) & !limit != 0 {
        return Err(ContentError::PixelRange);
    }
    Ok(status)
}

/// Build a frame (status line + pixels) from pixel words; the CRC in
/// `status` is filled in.
pub fn encode_frame(pixels: &[u16], cols: usize, status: Option<StatusLine>) -> Vec<u8> {
    let head = if status.is_some() { cols * 2 } else { 0 };
    let mut out = vec![0u8; head + pixels.len() * 2];
    for (dst, v) in out[head..].chunks_exact_mut(2).zip(pixels) {
        dst.copy_from_slice(&v.to_le_bytes());
    }
    if let Some(mut s) = status {
        s.crc32 = crc32fast::hash(&out[head..]);
        let (line, _) = out.split_at_mut(head);
        s.encode(line);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn st() -> StatusLine {
        StatusLine {
            frame_counter: 7,
            raw_index: 1,
            row0: 10,
            rows: 2,
            exposure_reg: 250,
            phase_reg: 6,
            illumination: true,
            crc32: 0,
        }
    }

    #[test]
    fn frame_round_trip() {
        let px: Vec<u16> = (0..24).map(|i| i * 100).collect();
        let f = encode_frame(&px, 12, Some(st()));
        assert_eq!(f.len(), 12 * 2 + 24 * 2);
        assert_eq!(&f[..6], &[0x54, 0x53, 7, 0, 1, 0]);
        let mut out = vec![0u16; 24];
        let s = decode_frame(&f, 12, 2, 12, true, &mut out)
            .unwrap()
            .unwrap();
        assert_eq!(out, px);
        assert_eq!(
            (s.raw_index, s.row0, s.rows, s.exposure_reg),
            (1, 10, 2, 250)
        );
    }

    #[test]
    fn corrupt_content_rejected() {
        let px: Vec<u16> = (0..24).map(|i| i * 100).collect();
        let f = encode_frame(&px, 12, Some(st()));
        let mut out = vec![0u16; 24];
        let mut g = f.clone();
        g[30] ^= 1;
        assert_eq!(
            decode_frame(&g, 12, 2, 12, true, &mut out),
            Err(ContentError::Checksum)
        );
        let mut g = f.clone();
        g[0] = 0;
        assert_eq!(
            decode_frame(&g, 12, 2, 12, true, &mut out),
            Err(ContentError::StatusLine)
        );
        assert_eq!(
            decode_frame(&f[..40], 12, 2, 12, true, &mut out),
            Err(ContentError::Size)
        );
        let bad: Vec<u16> = (0..24).map(|i| if i == 5 { 0x1000 } else { 0 }).collect();
        let g = encode_frame(&bad, 12, None);
        assert_eq!(
            decode_frame(&g, 12, 2, 12, false, &mut out),
            Err(ContentError::PixelRange)
        );
    }
}
