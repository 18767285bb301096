//! Layer 2c: pixel encodings of raw phase images as real cameras deliver them (pure, no I/O).
//!
//! Public facts these follow (docs/bridge.md, "Public facts and our inventions"):
//! - **RAW12** as MIPI CSI-2 packs it (V4L2 `Y12P`/`SBGGR12P`): two pixels in three bytes,
//!   `B0 = P0[11:4]`, `B1 = P1[11:4]`, `B2 = P1[3:0] << 4 | P0[3:0]`; a line holds an even number
//!   of pixels and may be padded to a stride.
//! - **RAW16** (V4L2 `Y12`/`Y16`): one little-endian 16-bit word per pixel, the 12 (or
//!   `adc_bits`) bits of the code in the low bits, the rest zero.
//! - **Stacked phase images**: a REAL3 V4L2 driver (IRS1125) delivers all raw images of a
//!   sequence in one buffer, stacked vertically (image `k` is rows `k·rows .. (k+1)·rows`).
//!
//! The CX3 path of the emulated device uses RAW16 (`frame.rs`); these decoders let a capture
//! of a real camera's stream, in either packing, become a recording (`tofprox device decode`).

use ndarray::Array3;
use serde::{Deserialize, Serialize};
use tofprox_format::limits::{MAX_PIXELS, MAX_SIDE_PIXELS};

/// How pixel codes are packed in a line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PixelPacking {
    /// MIPI CSI-2 RAW12: two pixels in three bytes.
    Raw12,
    /// One little-endian 16-bit word per pixel, code in the low bits.
    Raw16,
}

impl PixelPacking {
    /// Bytes of one line of `cols` pixels, without stride padding.
    pub fn line_bytes(self, cols: usize) -> usize {
        match self {
            PixelPacking::Raw12 => cols / 2 * 3,
            PixelPacking::Raw16 => cols * 2,
        }
    }
}

impl std::str::FromStr for PixelPacking {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "raw12" => Ok(PixelPacking::Raw12),
            "raw16" => Ok(PixelPacking::Raw16),
            _ => Err(format!("unknown pixel packing {s:?} (raw12 or raw16)")),
        }
    }
}

/// The layout of one buffer: `images` stacked images of `rows × cols` pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BufferLayout {
    /// Pixel packing.
    pub packing: PixelPacking,
    /// Pixels per line.
    pub cols: usize,
    /// Lines per image.
    pub rows: usize,
    /// Raw images stacked in the buffer (1 for one image per buffer).
    pub images: usize,
    /// Bytes from one line's start to the next (`None`: no padding).
    pub stride_bytes: Option<usize>,
    /// ADC resolution: a code above `2^adc_bits − 1` is an error (RAW16 only; RAW12 holds 12).
    pub adc_bits: u8,
}

/// Most raw images stacked in one buffer (a 4-phase capture at two frequencies holds 8).
pub const MAX_STACKED_IMAGES: usize = 64;
/// Longest line stride, bytes (a 4096-pixel RAW16 line is 8 KiB; V4L2 strides stay near it).
pub const MAX_STRIDE_BYTES: usize = 1 << 16;
/// Largest buffer a layout may describe, bytes: every size is checked against it before any
/// allocation is made from it.
pub const MAX_BUFFER_BYTES: usize = 1 << 28;

impl BufferLayout {
    fn stride(&self) -> usize {
        self.stride_bytes
            .unwrap_or_else(|| self.packing.line_bytes(self.cols))
    }

    /// Bytes of the whole buffer (saturating: a layout that [`BufferLayout::validate`] refuses
    /// may give `usize::MAX`, never an overflow).
    pub fn buffer_bytes(&self) -> usize {
        self.validate().unwrap_or(usize::MAX)
    }

    /// Check the layout on its own, before anything is sized from it: non-zero sides of at most
    /// [`MAX_SIDE_PIXELS`] and [`MAX_PIXELS`] per image, at most [`MAX_STACKED_IMAGES`], a
    /// stride of a whole line and at most [`MAX_STRIDE_BYTES`], an ADC of 1–16 bits, and a
    /// buffer of at most [`MAX_BUFFER_BYTES`]. Returns the buffer's size in bytes.
    pub fn validate(&self) -> Result<usize, PixelError> {
        if self.cols == 0 || self.rows == 0 || self.images == 0 {
            return Err(PixelError::Layout("zero rows, columns or images"));
        }
        if self.cols > MAX_SIDE_PIXELS || self.rows > MAX_SIDE_PIXELS {
            return Err(PixelError::Layout(
                "rows and columns are at most 4096 (limits::MAX_SIDE_PIXELS)",
            ));
        }
        if self.rows * self.cols > MAX_PIXELS {
            return Err(PixelError::Layout(
                "an image holds at most 2^20 pixels (limits::MAX_PIXELS)",
            ));
        }
        if self.images > MAX_STACKED_IMAGES {
            return Err(PixelError::Layout("at most 64 stacked images"));
        }
        if self.packing == PixelPacking::Raw12 && !self.cols.is_multiple_of(2) {
            return Err(PixelError::Layout(
                "RAW12 lines hold an even number of pixels",
            ));
        }
        if !(1..=16).contains(&self.adc_bits) {
            return Err(PixelError::Layout("adc_bits must be 1..=16"));
        }
        let stride = self.stride();
        if stride < self.packing.line_bytes(self.cols) {
            return Err(PixelError::Layout("stride shorter than a line"));
        }
        if stride > MAX_STRIDE_BYTES {
            return Err(PixelError::Layout("stride above 65536 bytes"));
        }
        // each factor is bounded above, so the product fits; checked all the same
        stride
            .checked_mul(self.rows)
            .and_then(|b| b.checked_mul(self.images))
            .filter(|&b| b <= MAX_BUFFER_BYTES)
            .ok_or(PixelError::Layout("a buffer of more than 256 MiB"))
    }
}

/// Why a buffer cannot be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PixelError {
    /// The buffer's size differs from its layout's.
    #[error("buffer of {got} bytes, the layout needs {expected}")]
    Size {
        /// Bytes the layout needs.
        expected: usize,
        /// Bytes given.
        got: usize,
    },
    /// The layout itself is impossible.
    #[error("impossible layout: {0}")]
    Layout(&'static str),
    /// A code above the ADC's range (padding bits not zero: wrong packing or a broken transfer).
    #[error("pixel {index} holds {value}, above the {adc_bits}-bit range")]
    Range {
        /// Index of the pixel in the buffer.
        index: usize,
        /// The code.
        value: u16,
        /// The ADC resolution.
        adc_bits: u8,
    },
}

fn check_layout(l: &BufferLayout, got: usize) -> Result<(), PixelError> {
    let expected = l.validate()?;
    if got != expected {
        return Err(PixelError::Size { expected, got });
    }
    Ok(())
}

/// Unpack one line of RAW12 (`B0 = P0[11:4]`, `B1 = P1[11:4]`, `B2 = P1[3:0]<<4 | P0[3:0]`).
fn unpack_raw12_line(line: &[u8], out: &mut [u16]) {
    for (b, p) in line.chunks_exact(3).zip(out.chunks_exact_mut(2)) {
        p[0] = (u16::from(b[0]) << 4) | u16::from(b[2] & 0x0F);
        p[1] = (u16::from(b[1]) << 4) | u16::from(b[2] >> 4);
    }
}

/// Unpack little-endian 16-bit words (RAW16); also the CX3 frame path's (`frame.rs`). Returns
/// the OR of every word, so a caller checks the code range without a second pass.
pub(crate) fn unpack_raw16_line(line: &[u8], out: &mut [u16]) -> u16 {
    let mut all = 0u16;
    for (b, p) in line.chunks_exact(2).zip(out.iter_mut()) {
        *p = u16::from_le_bytes([b[0], b[1]]);
        all |= *p;
    }
    all
}

/// Decode a buffer into `(images, rows, cols)` codes, checking its size and every code's range.
pub fn decode_buffer(buf: &[u8], layout: &BufferLayout) -> Result<Array3<u16>, PixelError> {
    check_layout(layout, buf.len())?;
    let (rows_total, cols) = (layout.rows * layout.images, layout.cols);
    let line_bytes = layout.packing.line_bytes(cols);
    let mut out = Array3::<u16>::zeros((layout.images, layout.rows, cols));
    let codes = out
        .as_slice_mut()
        .ok_or(PixelError::Layout("non-contiguous output"))?;
    for (r, line) in buf
        .chunks_exact(layout.stride())
        .take(rows_total)
        .enumerate()
    {
        let dst = &mut codes[r * cols..(r + 1) * cols];
        match layout.packing {
            PixelPacking::Raw12 => unpack_raw12_line(&line[..line_bytes], dst),
            PixelPacking::Raw16 => {
                unpack_raw16_line(&line[..line_bytes], dst);
            }
        }
    }
    let max =
        u16::try_from(tofprox_core::sensor::adc_max_code(layout.adc_bits)).unwrap_or(u16::MAX);
    if let Some((index, &value)) = codes.iter().enumerate().find(|(_, v)| **v > max) {
        return Err(PixelError::Range {
            index,
            value,
            adc_bits: layout.adc_bits,
        });
    }
    Ok(out)
}

/// Encode `(images, rows, cols)` codes into a buffer of `layout` (padding bytes zero). The
/// inverse of [`decode_buffer`], used by the emulated paths and to build test captures.
pub fn encode_buffer(codes: &Array3<u16>, layout: &BufferLayout) -> Result<Vec<u8>, PixelError> {
    let (k, rows, cols) = codes.dim();
    if (k, rows, cols) != (layout.images, layout.rows, layout.cols) {
        return Err(PixelError::Layout("codes' shape differs from the layout"));
    }
    let mut buf = vec![0u8; layout.validate()?];
    let stride = layout.stride();
    for (r, line) in codes.rows().into_iter().enumerate() {
        let dst = &mut buf[r * stride..];
        for (c, &v) in line.iter().enumerate() {
            match layout.packing {
                PixelPacking::Raw12 => {
                    let (g, odd) = (c / 2 * 3, c % 2 == 1);
                    dst[g + usize::from(odd)] = (v >> 4) as u8;
                    let low = (v & 0x0F) as u8;
                    dst[g + 2] |= if odd { low << 4 } else { low };
                }
                PixelPacking::Raw16 => dst[2 * c..2 * c + 2].copy_from_slice(&v.to_le_bytes()),
            }
        }
    }
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout(packing: PixelPacking, cols: usize, rows: usize, images: usize) -> BufferLayout {
        BufferLayout {
            packing,
            cols,
            rows,
            images,
            stride_bytes: None,
            adc_bits: 12,
        }
    }

    #[test]
    fn raw12_known_answer() {
        // P0 = 0xABC, P1 = 0x123 → B0 = 0xAB, B1 = 0x12, B2 = 0x3 << 4 | 0xC = 0x3C
        let buf = [0xAB, 0x12, 0x3C, 0xFF, 0x00, 0x0F];
        let codes = decode_buffer(&buf, &layout(PixelPacking::Raw12, 4, 1, 1)).unwrap();
        assert_eq!(codes.as_slice().unwrap(), &[0xABC, 0x123, 0xFFF, 0x000]);
    }

    #[test]
    fn raw16_known_answer_and_range() {
        let buf = [0xBC, 0x0A, 0x23, 0x01];
        let codes = decode_buffer(&buf, &layout(PixelPacking::Raw16, 2, 1, 1)).unwrap();
        assert_eq!(codes.as_slice().unwrap(), &[0xABC, 0x123]);
        // 0x1ABC has a bit above 12: a wrong packing, not a code
        let err = decode_buffer(&[0xBC, 0x1A, 0, 0], &layout(PixelPacking::Raw16, 2, 1, 1));
        assert_eq!(
            err.unwrap_err(),
            PixelError::Range {
                index: 0,
                value: 0x1ABC,
                adc_bits: 12
            }
        );
    }

    #[test]
    fn stacked_images_with_stride_round_trip() {
        let mut l = layout(PixelPacking::Raw12, 6, 3, 4);
        l.stride_bytes = Some(16); // 9 bytes of pixels, 7 of padding per line
        let codes = Array3::from_shape_fn((4, 3, 6), |(k, r, c)| {
            ((k * 1000 + r * 37 + c * 311) % 4096) as u16
        });
        let buf = encode_buffer(&codes, &l).unwrap();
        assert_eq!(buf.len(), 16 * 3 * 4);
        // image 2, row 1 starts at line 2·3 + 1 = 7: pixel 0 = (2000 + 37) % 4096 = 0x7F5
        assert_eq!(buf[7 * 16], 0x7F);
        assert_eq!(decode_buffer(&buf, &l).unwrap(), codes);
    }

    /// Issue 35 N5: a huge side or stride was multiplied unchecked and sized an allocation
    /// ("capacity overflow"); every such layout is now refused before anything is allocated.
    #[test]
    fn huge_layouts_are_refused_before_any_allocation() {
        let mut huge_cols = layout(PixelPacking::Raw16, 4_611_686_018_427_387_904, 4, 1);
        let mut huge_stride = layout(PixelPacking::Raw16, 6, 4, 1);
        huge_stride.stride_bytes = Some(usize::MAX);
        let mut too_many = layout(PixelPacking::Raw12, 4096, 4096, 1);
        let stacked = layout(PixelPacking::Raw16, 1024, 1024, 65);
        for l in [huge_cols, huge_stride, too_many, stacked] {
            assert!(matches!(l.validate(), Err(PixelError::Layout(_))), "{l:?}");
            assert!(matches!(
                decode_buffer(&[0; 64], &l),
                Err(PixelError::Layout(_))
            ));
            let codes = Array3::<u16>::zeros((1, 1, 2));
            assert!(encode_buffer(&codes, &l).is_err());
            assert_eq!(l.buffer_bytes(), usize::MAX);
        }
        huge_cols.cols = 6;
        assert_eq!(huge_cols.validate(), Ok(6 * 2 * 4));
        too_many.rows = 256; // 4096 × 256 = 2^20 pixels, RAW12: 6144 bytes a line
        assert_eq!(too_many.validate(), Ok(6144 * 256));
    }

    #[test]
    fn impossible_layouts_and_sizes_are_errors() {
        let l = layout(PixelPacking::Raw12, 3, 1, 1);
        assert!(matches!(
            decode_buffer(&[0; 4], &l),
            Err(PixelError::Layout(_))
        ));
        let l = layout(PixelPacking::Raw16, 4, 2, 1);
        assert_eq!(
            decode_buffer(&[0; 15], &l).unwrap_err(),
            PixelError::Size {
                expected: 16,
                got: 15
            }
        );
    }
}
