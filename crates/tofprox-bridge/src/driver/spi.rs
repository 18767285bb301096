//! The SPI-flash part of the driver (thesis 3.5.3, listing 4.11): the sensor
//! loads its configuration from the flash behind its SPI master; the driver
//! issues the load, and writes the image (`crate::flash`) when it is missing or
//! corrupt, through the sensor's SPI registers.

use std::time::Duration;

use super::{SensorDriver, ms};
use crate::error::{BridgeError, ErrorKind, ResultExt};
use crate::flash;
use crate::transport::UsbTransport;

impl<T: UsbTransport> SensorDriver<T> {
    /// Issue the flash load command and wait for its status.
    pub(super) fn load_from_flash(&mut self) -> Result<(), BridgeError> {
        let f = self.cfg.map.flash.clone();
        self.write_reg(f.load_register, f.load_value)
            .ctx(|| "flash load command")?;
        let v = self.poll_reg(
            f.status_register,
            ms(self.cfg.timing.flash_load_timeout_ms),
            "flash load",
            |v| v != f.status_busy,
        )?;
        if v == f.status_ok {
            Ok(())
        } else if v == f.status_empty {
            Err(BridgeError::new(
                ErrorKind::FlashEmpty,
                "flash holds no configuration image",
            ))
        } else if v == f.status_corrupt {
            Err(BridgeError::new(
                ErrorKind::FlashCorrupt,
                "flash configuration image is corrupt (checksum)",
            ))
        } else {
            Err(BridgeError::new(
                ErrorKind::Protocol,
                format!("flash load status {v:#06x} unknown"),
            ))
        }
    }

    /// One SPI transfer through the forwarding registers; returns the bytes
    /// clocked in (same length as `tx`) if `want_rx`.
    pub(super) fn spi_transfer(
        &mut self,
        tx: &[u8],
        want_rx: bool,
    ) -> Result<Vec<u8>, BridgeError> {
        let s = self.cfg.map.spi.clone();
        if tx.is_empty() || tx.len() > usize::from(s.window_bytes) {
            return Err(BridgeError::config(format!(
                "SPI transfer of {} bytes exceeds the {}-byte window",
                tx.len(),
                s.window_bytes
            )));
        }
        let words: Vec<u16> = tx
            .chunks(2)
            .map(|c| u16::from_be_bytes([c[0], c.get(1).copied().unwrap_or(0)]))
            .collect();
        let addr = self.addr();
        self.cx3
            .i2c_write(&mut self.transport, addr, s.tx_base, &words)?;
        let len = u16::try_from(tx.len()).unwrap_or(u16::MAX);
        self.write_reg(s.length_register, len)?;
        self.write_reg(s.trigger_register, 1)?;
        self.poll_reg(
            s.busy_register,
            ms(self.cfg.timing.spi_timeout_ms),
            "SPI forwarding",
            |v| v & 1 == 0,
        )?;
        if !want_rx {
            return Ok(Vec::new());
        }
        let rx = self
            .cx3
            .i2c_read(&mut self.transport, addr, s.rx_base, words.len())?;
        let mut out = Vec::with_capacity(tx.len());
        for w in rx {
            out.extend_from_slice(&w.to_be_bytes());
        }
        out.truncate(tx.len());
        Ok(out)
    }

    pub(super) fn spi_wait_ready(
        &mut self,
        timeout: Duration,
        what: &str,
    ) -> Result<(), BridgeError> {
        self.poll_until(
            timeout,
            |d| {
                let rx = d.spi_transfer(&[flash::CMD_RDSR, 0], true)?;
                let sr = rx.get(1).copied().unwrap_or(0xFF);
                Ok(if sr & flash::SR_WIP == 0 {
                    Ok(())
                } else {
                    Err(sr)
                })
            },
            |sr| {
                BridgeError::new(
                    ErrorKind::Timeout,
                    format!("{what}: flash still busy (status {sr:#04x}) after {timeout:?}"),
                )
            },
        )
    }

    /// Write the full configuration image to flash through the SPI
    /// forwarding registers: erase, page program, busy poll, read-back
    /// verify with CRC-32.
    pub(super) fn write_flash(&mut self) -> Result<(), BridgeError> {
        let image = flash::encode_image(&self.cfg.map.sequences.flash_image);
        let base = self.cfg.map.flash.image_address;
        let s = self.cfg.map.spi.clone();
        let t = self.cfg.timing.clone();
        let len =
            u32::try_from(image.len()).map_err(|_| BridgeError::config("flash image too large"))?;
        // erase
        let mut sector = base;
        while sector < base + len {
            self.spi_transfer(&[flash::CMD_WREN], false)?;
            self.spi_transfer(&flash::cmd_addr(flash::CMD_SE, sector), false)?;
            self.spi_wait_ready(
                ms(t.flash_erase_timeout_ms),
                &format!("erase sector {sector:#08x}"),
            )?;
            sector += s.sector_bytes;
        }
        // program, never crossing a page or the window
        let max_data = u32::from(s.window_bytes) - 4;
        let mut off = 0u32;
        while off < len {
            let addr = base + off;
            let page_left = s.page_bytes - addr % s.page_bytes;
            let n = page_left.min(max_data).min(len - off);
            let mut tx = flash::cmd_addr(flash::CMD_PP, addr).to_vec();
            tx.extend_from_slice(&image[off as usize..(off + n) as usize]);
            self.spi_transfer(&[flash::CMD_WREN], false)?;
            self.spi_transfer(&tx, false)?;
            self.spi_wait_ready(
                ms(t.flash_program_timeout_ms),
                &format!("program {addr:#08x}"),
            )?;
            off += n;
        }
        // verify
        let mut back = Vec::with_capacity(image.len());
        let mut off = 0u32;
        while off < len {
            let n = max_data.min(len - off);
            let mut tx = flash::cmd_addr(flash::CMD_READ, base + off).to_vec();
            tx.resize(4 + n as usize, 0);
            let rx = self.spi_transfer(&tx, true)?;
            back.extend_from_slice(rx.get(4..).unwrap_or(&[]));
            off += n;
        }
        let (want, got) = (crc32fast::hash(&image), crc32fast::hash(&back));
        if back.len() != image.len() || want != got {
            return Err(BridgeError::new(
                ErrorKind::FlashCorrupt,
                format!("flash verify failed: CRC-32 {got:#010x}, written {want:#010x}"),
            ));
        }
        self.stats.flash_writes += 1;
        Ok(())
    }
}
