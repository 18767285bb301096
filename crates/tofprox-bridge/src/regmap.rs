//! The sensor's register map, loaded from a file in `config/sensor/`.
//!
//! The addresses and values of the real IRS1645 are in Infineon's
//! datasheet, which is not public. The shipped map
//! (`config/sensor/emulated-irs1645.toml`) describes the **emulated** sensor;
//! a user with the datasheet writes a map of the same shape for the real
//! part. Nothing in the driver hard-codes an address.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{BridgeError, ErrorKind};
use crate::flash;

/// The map shipped for the emulated device (same text as
/// `config/sensor/emulated-irs1645.toml`).
pub const EMULATED_MAP_TOML: &str = include_str!("../../../config/sensor/emulated-irs1645.toml");

/// Largest pixel array a sensor map may describe (4096 × 4096).
pub const MAX_PIXELS: u32 = 1 << 24;

pub use crate::flash::RegWrite;

/// Sensor geometry and I2C identity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorSection {
    /// Human-readable name of this map.
    pub name: String,
    /// 7-bit I2C address.
    pub i2c_address: u8,
    /// Full array rows.
    pub rows: u16,
    /// Full array columns.
    pub cols: u16,
    /// ADC resolution; pixel words above `2^adc_bits - 1` are corrupt.
    pub adc_bits: u8,
    /// Modulation frequency of the use cases, Hz.
    pub modulation_hz: f64,
    /// Register holding the chip id (read after reset to see it is alive).
    pub chip_id_register: u16,
    /// Expected chip id value.
    pub chip_id_value: u16,
    /// Every frame starts with one status line (see `docs/protocol.md`):
    /// magic, frame counter, raw index, window, exposure, phase, CRC-32.
    pub status_line: bool,
    /// Zero padding allowed after a frame up to a multiple of this many bytes.
    #[serde(default = "one")]
    pub pad_align: usize,
}

fn one() -> usize {
    1
}

impl SensorSection {
    /// The full array this map describes, as every crate describes a sensor.
    pub fn geometry(&self) -> tofprox_core::SensorGeometry {
        tofprox_core::SensorGeometry::full(
            usize::from(self.rows),
            usize::from(self.cols),
            self.adc_bits,
            self.modulation_hz,
        )
    }
}

/// Fixed register sequences.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sequences {
    /// Minimum start-up configuration (clocks, PLL, interface) written over
    /// I2C after every reset, before loading from flash (thesis 3.5.3).
    #[serde(deserialize_with = "tofprox_core::serde_exact::vec_of_arrays")]
    pub minimum: Vec<RegWrite>,
    /// The full configuration image stored in flash (written when the
    /// flash is empty or corrupt, loaded by the load command every cycle).
    #[serde(deserialize_with = "tofprox_core::serde_exact::vec_of_arrays")]
    pub flash_image: Vec<RegWrite>,
    /// Start the measurement (sequencer on).
    #[serde(deserialize_with = "tofprox_core::serde_exact::vec_of_arrays")]
    pub start_measurement: Vec<RegWrite>,
    /// Stop the measurement.
    #[serde(deserialize_with = "tofprox_core::serde_exact::vec_of_arrays")]
    pub stop_measurement: Vec<RegWrite>,
}

/// The imager bring-up after the PLL registers (`sequences.minimum`), as the public record gives
/// it for IRS16x5 parts (Infineon's Strata SDK; `docs/bridge.md`, "Public facts"): reset pulsed
/// low, the PLL registers, wait for the PLL, the imager state machine's `CTRL` then `EN`, wait.
/// The order, the addresses and the waits are public; the values written are the map's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BringUp {
    /// Shortest low pulse on the (open-drain) reset pin that resets the sensor, µs.
    pub reset_low_us: u64,
    /// Wait after the PLL registers before `ctrl`, µs (the PLL settles).
    pub pll_settle_us: u64,
    /// The imager state machine's `CTRL` write, written first.
    #[serde(deserialize_with = "tofprox_core::serde_exact::array")]
    pub ctrl: RegWrite,
    /// The imager state machine's `EN` write, written after `ctrl`.
    #[serde(deserialize_with = "tofprox_core::serde_exact::array")]
    pub en: RegWrite,
    /// Wait after `en` before the measurement may start, µs.
    pub enable_settle_us: u64,
}

/// Per-raw-image registers: raw image `k` uses `base + k`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawImageRegs {
    /// Exposure register of raw image 0.
    pub exposure_base: u16,
    /// Exposure LSB, microseconds.
    pub exposure_lsb_us: f64,
    /// Smallest allowed exposure, µs.
    pub exposure_min_us: f64,
    /// Largest allowed exposure, µs (eye safety / saturation).
    pub exposure_max_us: f64,
    /// Phase-step register of raw image 0.
    pub phase_base: u16,
    /// Phase step LSB, degrees.
    pub phase_lsb_deg: f64,
    /// Illumination-enable register of raw image 0 (1 = VCSEL on).
    pub illumination_base: u16,
    /// Register holding the number of raw images per measurement.
    pub count_register: u16,
    /// Most raw images per measurement.
    pub max_count: u16,
}

/// Optional row window for partial read-out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RowWindowRegs {
    /// First row register.
    pub row0_register: u16,
    /// Row count register (0 = full array).
    pub rows_register: u16,
    /// Window start and size must be multiples of this.
    pub align: u16,
    /// First column register, where the sequencer reads a column window too (absent: whole
    /// rows only).
    #[serde(default)]
    pub col0_register: Option<u16>,
    /// Column count register (0 = every column).
    #[serde(default)]
    pub cols_register: Option<u16>,
    /// Column window start and size must be multiples of this (0 is taken as 1).
    #[serde(default)]
    pub col_align: u16,
    /// Row step register, where the sequencer skips rows (every n-th row of the window read;
    /// 0 or 1 = every row; absent: every row only).
    #[serde(default)]
    pub row_step_register: Option<u16>,
    /// The largest row step the sequencer takes.
    #[serde(default)]
    pub max_row_step: u16,
}

impl RowWindowRegs {
    /// The column registers, when the sequencer reads column windows.
    pub fn column_registers(&self) -> Option<(u16, u16)> {
        self.col0_register.zip(self.cols_register)
    }

    /// The largest row step the sequencer takes (1: it reads every row).
    pub fn row_step_max(&self) -> u16 {
        self.row_step_register
            .map_or(1, |_| self.max_row_step.max(1))
    }
}

/// Optional modulation-frequency select: the sensor's PLL offers a few frequencies; a second
/// one disambiguates the range (thesis 2.2.1, eq. 2.8). Absent: only `sensor.modulation_hz`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModulationRegs {
    /// Register selecting the frequency: value = frequency / `lsb_hz`.
    pub register: u16,
    /// Frequency step of the register (Hz).
    pub lsb_hz: f64,
    /// Frequencies the sensor offers (Hz); `sensor.modulation_hz` must be one of them.
    pub frequencies_hz: Vec<f64>,
}

/// Flash load command and status.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlashRegs {
    /// Register the load command is written to.
    pub load_register: u16,
    /// Value that triggers "load configuration from flash".
    pub load_value: u16,
    /// Register with the load status.
    pub status_register: u16,
    /// Status: load in progress.
    pub status_busy: u16,
    /// Status: configuration loaded and its checksum matched.
    pub status_ok: u16,
    /// Status: flash erased (no image).
    pub status_empty: u16,
    /// Status: image present but corrupt (magic/length/checksum).
    pub status_corrupt: u16,
    /// Flash byte address of the configuration image.
    pub image_address: u32,
}

/// SPI-forwarding registers: the sensor clocks the TX window out on its SPI
/// bus to the flash and captures the answer in the RX window.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpiRegs {
    /// First TX window register (2 bytes per register, big-endian).
    pub tx_base: u16,
    /// First RX window register.
    pub rx_base: u16,
    /// Size of each window, bytes (even).
    pub window_bytes: u16,
    /// Register: number of bytes to transfer.
    pub length_register: u16,
    /// Register: write 1 to start the transfer.
    pub trigger_register: u16,
    /// Register: bit 0 set while the transfer runs.
    pub busy_register: u16,
    /// Flash page size, bytes (page program limit).
    pub page_bytes: u32,
    /// Flash erase sector size, bytes.
    pub sector_bytes: u32,
}

/// A use case: the raw images of one measurement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UseCase {
    /// Phase of each raw image, degrees.
    pub phases_deg: Vec<f64>,
    /// Illumination per raw image (default: all on). A grey image is off.
    #[serde(default)]
    pub illumination: Option<Vec<bool>>,
    /// Extra registers of the use case (written after the flash load).
    #[serde(default, deserialize_with = "tofprox_core::serde_exact::vec_of_arrays")]
    pub registers: Vec<RegWrite>,
}

impl UseCase {
    /// The use case reduced to its raw image `k` alone (a presence probe), `None` when it has
    /// no such image.
    pub fn only_image(&self, k: usize) -> Option<UseCase> {
        let phase = *self.phases_deg.get(k)?;
        Some(UseCase {
            phases_deg: vec![phase],
            illumination: Some(vec![self.illuminated(k)]),
            registers: self.registers.clone(),
        })
    }

    /// Illumination of raw image `k`.
    pub fn illuminated(&self, k: usize) -> bool {
        self.illumination
            .as_ref()
            .and_then(|v| v.get(k).copied())
            .unwrap_or(true)
    }
}

/// The whole register map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorMap {
    /// Geometry and identity.
    pub sensor: SensorSection,
    /// Fixed sequences.
    pub sequences: Sequences,
    /// The imager bring-up after the PLL registers (absent: none, the minimum configuration
    /// is the whole bring-up).
    #[serde(default)]
    pub bring_up: Option<BringUp>,
    /// Per-raw-image registers.
    pub raw: RawImageRegs,
    /// Row window (absent: the sensor reads the full array only).
    #[serde(default)]
    pub row_window: Option<RowWindowRegs>,
    /// Modulation-frequency select (absent: one frequency only).
    #[serde(default)]
    pub modulation: Option<ModulationRegs>,
    /// Flash load command/status.
    pub flash: FlashRegs,
    /// SPI forwarding.
    pub spi: SpiRegs,
    /// Use cases by name: `2phase`, `4phase`, `4phase-grey`, `correlation24`.
    pub use_cases: BTreeMap<String, UseCase>,
}

impl SensorMap {
    /// Parse and validate map text; `origin` names the file in errors.
    pub fn from_toml_str(s: &str, origin: &str) -> Result<Self, BridgeError> {
        let m: SensorMap = toml::from_str(s).map_err(|e| {
            BridgeError::with_source(ErrorKind::Config, format!("sensor map {origin}"), e)
        })?;
        m.validate()
            .map_err(|e| e.context_prefix(format!("sensor map {origin}")))?;
        Ok(m)
    }

    /// Load a map file.
    pub fn load(path: &Path) -> Result<Self, BridgeError> {
        let s = crate::error::read_config_text(path).map_err(|e| e.context_prefix("sensor map"))?;
        Self::from_toml_str(&s, &path.display().to_string())
    }

    /// The shipped map of the emulated sensor.
    pub fn emulated() -> Self {
        // The embedded file is covered by a test; a parse failure here is a
        // build defect, reported as the documented fallback error path.
        match Self::from_toml_str(EMULATED_MAP_TOML, "emulated-irs1645.toml (built in)") {
            Ok(m) => m,
            Err(e) => {
                tracing::error!("built-in sensor map invalid: {e}");
                Self::minimal_fallback()
            }
        }
    }

    fn minimal_fallback() -> Self {
        // Never reached when the shipped file is valid (tested); kept so
        // `emulated()` cannot panic.
        SensorMap {
            sensor: SensorSection {
                name: "fallback".into(),
                i2c_address: 0x3D,
                rows: 172,
                cols: 224,
                adc_bits: 12,
                modulation_hz: 80e6,
                chip_id_register: 0xA0A4,
                chip_id_value: 0x1645,
                status_line: true,
                pad_align: 1,
            },
            sequences: Sequences {
                minimum: vec![],
                flash_image: vec![[0x9100, 1]],
                start_measurement: vec![[0x9400, 1]],
                stop_measurement: vec![[0x9400, 0]],
            },
            raw: RawImageRegs {
                exposure_base: 0x9000,
                exposure_lsb_us: 1.0,
                exposure_min_us: 10.0,
                exposure_max_us: 4000.0,
                phase_base: 0x9020,
                phase_lsb_deg: 15.0,
                illumination_base: 0x9040,
                count_register: 0x9060,
                max_count: 24,
            },
            bring_up: None,
            row_window: None,
            modulation: None,
            flash: FlashRegs {
                load_register: 0xA000,
                load_value: 1,
                status_register: 0xA001,
                status_busy: 1,
                status_ok: 2,
                status_empty: 3,
                status_corrupt: 4,
                image_address: 0,
            },
            spi: SpiRegs {
                tx_base: 0xA100,
                rx_base: 0xA200,
                window_bytes: 264,
                length_register: 0xA010,
                trigger_register: 0xA011,
                busy_register: 0xA012,
                page_bytes: 256,
                sector_bytes: 4096,
            },
            use_cases: BTreeMap::new(),
        }
    }

    /// Range and consistency checks; errors name the key.
    pub fn validate(&self) -> Result<(), BridgeError> {
        self.validate_sensor()?;
        self.validate_raw()?;
        self.validate_spi_flash()?;
        let s = &self.sensor;
        let bad = |k: &str, why: String| Err(BridgeError::config(format!("{k}: {why}")));
        if let Some(w) = &self.row_window
            && (w.align == 0 || !s.rows.is_multiple_of(w.align))
        {
            return bad("row_window.align", "must divide sensor.rows".into());
        }
        if let Some(m) = &self.modulation {
            validate_modulation(m, s.modulation_hz).or_else(|why| bad("modulation", why))?;
        }
        if let Some(b) = &self.bring_up {
            validate_bring_up(b, &self.sequences.minimum).or_else(|why| bad("bring_up", why))?;
        }
        self.validate_use_cases()
    }

    /// `[sensor]`: address, array size, status line, ADC and modulation, padding.
    fn validate_sensor(&self) -> Result<(), BridgeError> {
        let s = &self.sensor;
        let bad = |k: &str, why: String| Err(BridgeError::config(format!("{k}: {why}")));
        if s.i2c_address > 0x7F {
            return bad(
                "sensor.i2c_address",
                format!("{:#x} is not 7-bit", s.i2c_address),
            );
        }
        if s.rows == 0 || s.cols == 0 {
            return bad("sensor.rows/cols", "must be > 0".into());
        }
        // frame buffers are sized from these: refuse what no ToF array has
        // (the IRS1645 is 172 × 224) instead of failing to allocate gigabytes
        if u32::from(s.rows) * u32::from(s.cols) > MAX_PIXELS {
            return bad(
                "sensor.rows/cols",
                format!(
                    "{} × {} pixels, at most {MAX_PIXELS} (a 4096 × 4096 array)",
                    s.rows, s.cols
                ),
            );
        }
        if s.status_line && s.cols < 10 {
            return bad("sensor.status_line", "needs at least 10 columns".into());
        }
        // ADC and modulation: the one check every sensor geometry gets
        if let Err(e) = s.geometry().validate() {
            return match e {
                tofprox_core::CoreError::InvalidParameter { name, reason } => {
                    bad(&format!("sensor.{name}"), reason)
                }
                other => bad("sensor", other.to_string()),
            };
        }
        if s.pad_align == 0 || s.pad_align > 65536 {
            return bad("sensor.pad_align", "must be in 1..=65536".into());
        }
        Ok(())
    }

    /// `[raw]`: exposure and phase steps, register blocks of the raw images.
    fn validate_raw(&self) -> Result<(), BridgeError> {
        let bad = |k: &str, why: String| Err(BridgeError::config(format!("{k}: {why}")));
        let r = &self.raw;
        if !(r.exposure_lsb_us.is_finite() && r.exposure_lsb_us > 0.0) {
            return bad("raw.exposure_lsb_us", "must be > 0".into());
        }
        if !(r.exposure_min_us > 0.0
            && r.exposure_min_us <= r.exposure_max_us
            && r.exposure_max_us / r.exposure_lsb_us <= f64::from(u16::MAX))
        {
            return bad(
                "raw.exposure_min_us/exposure_max_us",
                "need 0 < min <= max and max/lsb <= 65535".into(),
            );
        }
        if !(r.phase_lsb_deg.is_finite() && r.phase_lsb_deg > 0.0) {
            return bad("raw.phase_lsb_deg", "must be > 0".into());
        }
        if r.max_count == 0 || r.max_count > 64 {
            return bad("raw.max_count", "must be in 1..=64".into());
        }
        for (k, base) in [
            ("raw.exposure_base", r.exposure_base),
            ("raw.phase_base", r.phase_base),
            ("raw.illumination_base", r.illumination_base),
        ] {
            if u32::from(base) + u32::from(r.max_count) > 0x1_0000 {
                return bad(
                    k,
                    format!("{base:#06x} + max_count runs past register 0xffff"),
                );
            }
        }
        Ok(())
    }

    /// `[spi]`, `[flash]` and the sequences: windows, page/sector sizes, the image's extent.
    fn validate_spi_flash(&self) -> Result<(), BridgeError> {
        let bad = |k: &str, why: String| Err(BridgeError::config(format!("{k}: {why}")));
        for (k, base) in [
            ("spi.tx_base", self.spi.tx_base),
            ("spi.rx_base", self.spi.rx_base),
        ] {
            if u32::from(base) + u32::from(self.spi.window_bytes) / 2 > 0x1_0000 {
                return bad(k, format!("{base:#06x} + window runs past register 0xffff"));
            }
        }
        if self.sequences.flash_image.is_empty() {
            return bad("sequences.flash_image", "must not be empty".into());
        }
        if self.sequences.start_measurement.is_empty() || self.sequences.stop_measurement.is_empty()
        {
            return bad(
                "sequences.start_measurement/stop_measurement",
                "must not be empty".into(),
            );
        }
        let p = &self.spi;
        if p.window_bytes < 8 || !p.window_bytes.is_multiple_of(2) {
            return bad("spi.window_bytes", "must be even and >= 8".into());
        }
        if p.page_bytes == 0 || p.sector_bytes == 0 || !p.sector_bytes.is_multiple_of(p.page_bytes)
        {
            return bad(
                "spi.page_bytes/sector_bytes",
                "sector must be a multiple of page".into(),
            );
        }
        if !self.flash.image_address.is_multiple_of(p.sector_bytes) {
            return bad("flash.image_address", "must be sector aligned".into());
        }
        // the image header counts pairs in a u16, and SPI NOR commands carry
        // 3-byte addresses: a larger image or address would be written truncated
        let pairs = self.sequences.flash_image.len();
        if pairs > usize::from(u16::MAX) {
            return bad(
                "sequences.flash_image",
                format!("{pairs} register writes, the image holds at most 65535"),
            );
        }
        let image_end =
            u64::from(self.flash.image_address) + (flash::HEADER_BYTES + 4 * pairs) as u64;
        if image_end > 1 << 24 {
            return bad(
                "flash.image_address",
                format!(
                    "{:#x}: the image would end at {image_end:#x}, past the 24-bit SPI address space",
                    self.flash.image_address
                ),
            );
        }
        Ok(())
    }

    /// `[use_cases.*]`: raw image counts, illumination lists, phases.
    fn validate_use_cases(&self) -> Result<(), BridgeError> {
        let r = &self.raw;
        let bad = |k: &str, why: String| Err(BridgeError::config(format!("{k}: {why}")));
        for (name, uc) in &self.use_cases {
            let k = uc.phases_deg.len();
            if k == 0 || k > usize::from(r.max_count) {
                return bad(
                    &format!("use_cases.{name}.phases_deg"),
                    format!("{k} raw images, allowed 1..={}", r.max_count),
                );
            }
            if let Some(il) = &uc.illumination
                && il.len() != k
            {
                return bad(
                    &format!("use_cases.{name}.illumination"),
                    format!("{} entries for {k} raw images", il.len()),
                );
            }
            for ph in &uc.phases_deg {
                if !(ph.is_finite() && (0.0..360.0).contains(ph)) {
                    return bad(
                        &format!("use_cases.{name}.phases_deg"),
                        format!("{ph} not in [0, 360)"),
                    );
                }
            }
        }
        Ok(())
    }

    /// The use case `name`.
    pub fn use_case(&self, name: &str) -> Result<&UseCase, BridgeError> {
        self.use_cases.get(name).ok_or_else(|| {
            BridgeError::config(format!(
                "sensor map {} has no use case {name:?} (has: {})",
                self.sensor.name,
                self.use_cases
                    .keys()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })
    }

    /// Bytes of one frame with `rows` pixel rows (status line included).
    pub fn frame_bytes(&self, rows: usize) -> usize {
        self.frame_bytes_of(rows, usize::from(self.sensor.cols))
    }

    /// Bytes of one raw frame of `rows` × `cols` (a column window; the status line is as wide
    /// as the rows).
    pub fn frame_bytes_of(&self, rows: usize, cols: usize) -> usize {
        (rows + usize::from(self.sensor.status_line)) * cols * 2
    }

    /// Exposure register value for `exposure_us` (rounded to the LSB).
    pub fn exposure_to_reg(&self, exposure_us: f64) -> Result<u16, BridgeError> {
        let r = &self.raw;
        if !exposure_us.is_finite()
            || exposure_us < r.exposure_min_us
            || exposure_us > r.exposure_max_us
        {
            return Err(BridgeError::config(format!(
                "exposure {exposure_us} µs outside {}..={} µs (raw.exposure_min_us/max_us)",
                r.exposure_min_us, r.exposure_max_us
            )));
        }
        let v = (exposure_us / r.exposure_lsb_us).round();
        Ok(v.clamp(1.0, f64::from(u16::MAX)) as u16)
    }

    /// The register write selecting `modulation_hz` (`None`: `sensor.modulation_hz`) and the
    /// frequency it selects; `None` for a map without a modulation select asked for its own
    /// frequency. A frequency the map does not offer is a configuration error.
    pub fn modulation_write(
        &self,
        modulation_hz: Option<f64>,
    ) -> Result<Option<(RegWrite, f64)>, BridgeError> {
        let f = modulation_hz.unwrap_or(self.sensor.modulation_hz);
        let offered = |m: &ModulationRegs| m.frequencies_hz.iter().any(|&o| (o - f).abs() < 1.0);
        match &self.modulation {
            Some(m) if offered(m) => {
                let v = (f / m.lsb_hz).round().clamp(0.0, f64::from(u16::MAX)) as u16;
                Ok(Some(([m.register, v], f64::from(v) * m.lsb_hz)))
            }
            None if (f - self.sensor.modulation_hz).abs() < 1.0 => Ok(None),
            _ => Err(BridgeError::config(format!(
                "sensor map {} offers no {f} Hz modulation ([modulation] frequencies_hz)",
                self.sensor.name
            ))),
        }
    }

    /// Phase register value for `phase_deg`.
    pub fn phase_to_reg(&self, phase_deg: f64) -> u16 {
        (phase_deg / self.raw.phase_lsb_deg)
            .round()
            .clamp(0.0, f64::from(u16::MAX)) as u16
    }
}

/// The checks of a `[modulation]` section: a positive step, at most 16 frequencies, each valid
/// and a whole number of steps within 16 bits, the sensor's own among them.
fn validate_modulation(m: &ModulationRegs, own_hz: f64) -> Result<(), String> {
    if !(m.lsb_hz.is_finite() && m.lsb_hz > 0.0) {
        return Err(format!("lsb_hz = {} must be > 0", m.lsb_hz));
    }
    if m.frequencies_hz.is_empty() || m.frequencies_hz.len() > 16 {
        return Err("frequencies_hz: 1 to 16 frequencies".into());
    }
    for &f in &m.frequencies_hz {
        tofprox_core::sensor::validate_modulation_hz(f).map_err(|e| e.to_string())?;
        let v = f / m.lsb_hz;
        if (v - v.round()).abs() > 1e-6 || v.round() > f64::from(u16::MAX) || v.round() < 1.0 {
            return Err(format!(
                "{f} Hz is not a 16-bit multiple of lsb_hz {}",
                m.lsb_hz
            ));
        }
    }
    if !m.frequencies_hz.iter().any(|&f| (f - own_hz).abs() < 1.0) {
        return Err(format!(
            "frequencies_hz must include sensor.modulation_hz {own_hz}"
        ));
    }
    Ok(())
}

/// The checks of a `[bring_up]` section: waits up to 1 s, a reset pulse of 1 µs to 1 s, `ctrl`
/// and `en` two registers apart from the PLL registers they follow.
fn validate_bring_up(b: &BringUp, minimum: &[RegWrite]) -> Result<(), String> {
    for (k, v, least) in [
        ("reset_low_us", b.reset_low_us, 1),
        ("pll_settle_us", b.pll_settle_us, 0),
        ("enable_settle_us", b.enable_settle_us, 0),
    ] {
        if !(least..=1_000_000).contains(&v) {
            return Err(format!("{k} = {v} outside {least}..=1000000 µs"));
        }
    }
    let (ctrl, en) = (b.ctrl[0], b.en[0]);
    if ctrl == en {
        return Err(format!("ctrl and en are both register {ctrl:#06x}"));
    }
    if let Some([r, _]) = minimum.iter().find(|[r, _]| *r == ctrl || *r == en) {
        return Err(format!(
            "register {r:#06x} is both a PLL register (sequences.minimum) and ctrl/en"
        ));
    }
    Ok(())
}

/// Group consecutive-register writes into bursts `(first, values)`.
pub fn bursts(writes: &[RegWrite]) -> Vec<(u16, Vec<u16>)> {
    let mut out: Vec<(u16, Vec<u16>)> = Vec::new();
    for &[reg, val] in writes {
        if let Some((first, vals)) = out.last_mut()
            && usize::from(*first) + vals.len() == usize::from(reg)
        {
            vals.push(val);
            continue;
        }
        out.push((reg, vec![val]));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_map_parses_and_has_all_use_cases() {
        let m = SensorMap::from_toml_str(EMULATED_MAP_TOML, "shipped").unwrap();
        for uc in ["2phase", "4phase", "4phase-grey", "correlation24"] {
            m.use_case(uc).unwrap();
        }
        assert_eq!(m.use_case("correlation24").unwrap().phases_deg.len(), 24);
        assert!(!m.use_case("4phase-grey").unwrap().illuminated(4));
        assert_eq!(m, SensorMap::emulated());
        assert_eq!(m.frame_bytes(172), 173 * 224 * 2);
    }

    #[test]
    fn unknown_keys_and_bad_values_rejected() {
        let bad = EMULATED_MAP_TOML.replace("adc_bits = 12", "adc_bits = 12\nadc_bitz = 3");
        let e = SensorMap::from_toml_str(&bad, "x").unwrap_err();
        assert!(format!("{e:#}").contains("adc_bitz") || format!("{:?}", e).contains("adc_bitz"));
        let bad = EMULATED_MAP_TOML.replace("phase_base = 0x9020", "phase_base = 0xFFF0");
        let e = SensorMap::from_toml_str(&bad, "x").unwrap_err();
        assert!(e.to_string().contains("raw.phase_base"), "{e}");
        let bad = EMULATED_MAP_TOML.replace("rx_base = 0xA200", "rx_base = 0xFFA0");
        let e = SensorMap::from_toml_str(&bad, "x").unwrap_err();
        assert!(e.to_string().contains("spi.rx_base"), "{e}");
        let bad = EMULATED_MAP_TOML.replace("adc_bits = 12", "adc_bits = 0");
        let e = SensorMap::from_toml_str(&bad, "x").unwrap_err();
        assert!(e.to_string().contains("sensor.adc_bits"), "{e}");
        let bad = EMULATED_MAP_TOML.replace("cols = 224", "cols = 65535");
        let bad = bad.replace("rows = 172", "rows = 65535");
        let e = SensorMap::from_toml_str(&bad, "x").unwrap_err();
        assert!(e.to_string().contains("sensor.rows/cols"), "{e}");
        // SPI NOR addresses are 24 bit: an image at 16 MiB cannot be addressed
        let bad =
            EMULATED_MAP_TOML.replace("image_address = 0x000000", "image_address = 0x1000000");
        let e = SensorMap::from_toml_str(&bad, "x").unwrap_err();
        assert!(e.to_string().contains("24-bit SPI address"), "{e}");
        let ok = EMULATED_MAP_TOML.replace("image_address = 0x000000", "image_address = 0x001000");
        SensorMap::from_toml_str(&ok, "x").unwrap();
    }

    #[test]
    fn exposure_and_phase_conversion() {
        let m = SensorMap::emulated();
        assert_eq!(m.exposure_to_reg(250.0).unwrap(), 250);
        assert!(m.exposure_to_reg(1e9).is_err());
        assert!(m.exposure_to_reg(f64::NAN).is_err());
        assert_eq!(m.phase_to_reg(90.0), 6);
    }

    #[test]
    fn bursts_group_consecutive() {
        let b = bursts(&[[1, 10], [2, 11], [3, 12], [7, 1], [8, 2], [4, 0]]);
        assert_eq!(
            b,
            vec![(1, vec![10, 11, 12]), (7, vec![1, 2]), (4, vec![0])]
        );
    }
}
