//! The configuration image stored in the SPI flash, and the SPI NOR command
//! bytes the driver forwards through the sensor (pure, no I/O).
//!
//! Image layout (big-endian, see `docs/protocol.md`):
//! `"TFCF"` magic, version u16 = 1, count u16, CRC-32 (IEEE) u32 of the
//! pairs, then `count` × (register u16, value u16).

/// One register write: `[register, value]` (the register map's sequences and the flash image
/// are lists of them; defined here, the lower of the two, and re-exported by `regmap`).
pub type RegWrite = [u16; 2];

/// Image magic.
pub const MAGIC: [u8; 4] = *b"TFCF";
/// Image format version.
pub const VERSION: u16 = 1;
/// Header bytes before the pairs.
pub const HEADER_BYTES: usize = 12;

/// SPI NOR: write enable.
pub const CMD_WREN: u8 = 0x06;
/// SPI NOR: read status register 1 (bit 0 = write in progress).
pub const CMD_RDSR: u8 = 0x05;
/// SPI NOR: read data (3-byte address).
pub const CMD_READ: u8 = 0x03;
/// SPI NOR: page program (3-byte address, up to one page).
pub const CMD_PP: u8 = 0x02;
/// SPI NOR: 4 KiB sector erase (3-byte address).
pub const CMD_SE: u8 = 0x20;
/// Status register bit: write in progress.
pub const SR_WIP: u8 = 0x01;
/// Status register bit: write enable latch.
pub const SR_WEL: u8 = 0x02;

/// Why an image does not parse.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageError {
    /// The area is erased (all 0xFF header).
    Empty,
    /// Magic, version, length or checksum wrong.
    Corrupt,
}

/// Encode register writes as a flash image.
pub fn encode_image(writes: &[RegWrite]) -> Vec<u8> {
    let mut pairs = Vec::with_capacity(writes.len() * 4);
    for [r, v] in writes {
        pairs.extend_from_slice(&r.to_be_bytes());
        pairs.extend_from_slice(&v.to_be_bytes());
    }
    let mut out = Vec::with_capacity(HEADER_BYTES + pairs.len());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&VERSION.to_be_bytes());
    let count = u16::try_from(writes.len()).unwrap_or(u16::MAX);
    out.extend_from_slice(&count.to_be_bytes());
    out.extend_from_slice(&crc32fast::hash(&pairs).to_be_bytes());
    out.extend_from_slice(&pairs);
    out
}

/// Total image length announced by a header, if the header is plausible.
pub fn image_len(header: &[u8]) -> Option<usize> {
    if header.len() < HEADER_BYTES || header[..4] != MAGIC {
        return None;
    }
    let count = usize::from(u16::from_be_bytes([header[6], header[7]]));
    Some(HEADER_BYTES + 4 * count)
}

/// Parse an image from flash contents starting at the image address.
pub fn parse_image(flash: &[u8]) -> Result<Vec<RegWrite>, ImageError> {
    let head = flash.get(..HEADER_BYTES).ok_or(ImageError::Corrupt)?;
    if head.iter().all(|&b| b == 0xFF) {
        return Err(ImageError::Empty);
    }
    if head[..4] != MAGIC || u16::from_be_bytes([head[4], head[5]]) != VERSION {
        return Err(ImageError::Corrupt);
    }
    let len = image_len(head).ok_or(ImageError::Corrupt)?;
    let pairs = flash.get(HEADER_BYTES..len).ok_or(ImageError::Corrupt)?;
    let crc = u32::from_be_bytes([head[8], head[9], head[10], head[11]]);
    if crc32fast::hash(pairs) != crc {
        return Err(ImageError::Corrupt);
    }
    Ok(pairs
        .chunks_exact(4)
        .map(|c| {
            [
                u16::from_be_bytes([c[0], c[1]]),
                u16::from_be_bytes([c[2], c[3]]),
            ]
        })
        .collect())
}

/// Command bytes with a 24-bit address.
pub fn cmd_addr(cmd: u8, addr: u32) -> [u8; 4] {
    let a = addr.to_be_bytes();
    [cmd, a[1], a[2], a[3]]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_round_trip_and_golden_header() {
        let w = [[0x9000, 1000], [0x9001, 0xBEEF]];
        let img = encode_image(&w);
        assert_eq!(&img[..8], b"TFCF\x00\x01\x00\x02");
        assert_eq!(
            &img[12..],
            &[0x90, 0x00, 0x03, 0xE8, 0x90, 0x01, 0xBE, 0xEF]
        );
        assert_eq!(image_len(&img), Some(img.len()));
        let mut flash = img.clone();
        flash.extend_from_slice(&[0xFF; 100]);
        assert_eq!(parse_image(&flash).unwrap(), w.to_vec());
    }

    #[test]
    fn empty_and_corrupt_images() {
        assert_eq!(parse_image(&[0xFF; 64]), Err(ImageError::Empty));
        let mut img = encode_image(&[[1, 2]]);
        img[13] ^= 0x40;
        assert_eq!(parse_image(&img), Err(ImageError::Corrupt));
        let img = encode_image(&[[1, 2]]);
        assert_eq!(parse_image(&img[..14]), Err(ImageError::Corrupt));
        assert_eq!(parse_image(&[0u8; 4]), Err(ImageError::Corrupt));
    }

    #[test]
    fn command_bytes() {
        assert_eq!(cmd_addr(CMD_SE, 0x012345), [0x20, 0x01, 0x23, 0x45]);
        assert_eq!(cmd_addr(CMD_PP, 0x100), [0x02, 0x00, 0x01, 0x00]);
    }
}
