//! The driver's configuration: waits and policies ([`DriverTiming`]), the
//! resolved [`DriverConfig`], and the TOML files it is read from
//! ([`DriverConfigFile`], [`DeviceConfigFile`]; `docs/bridge.md`).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{BridgeError, ErrorKind};
use crate::protocol::ProtocolConfig;
use crate::regmap::SensorMap;

/// Driver waits and policies. Every wait is bounded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriverTiming {
    /// Reset held low before release, µs (at least the map's `bring_up.reset_low_us`; the
    /// public record pulses the IRS16x5's open-drain reset ~2 µs).
    pub reset_low_us: u64,
    /// Sleep after reset release before the first chip-id read, µs.
    pub startup_delay_us: u64,
    /// Give up on the chip id after this long (→ `ResetStuck`), ms.
    pub startup_timeout_ms: u64,
    /// Sleep between status polls, µs.
    pub poll_interval_us: u64,
    /// Flash load must finish in this time, ms.
    pub flash_load_timeout_ms: u64,
    /// One sector erase must finish in this time, ms.
    pub flash_erase_timeout_ms: u64,
    /// One page program must finish in this time, ms.
    pub flash_program_timeout_ms: u64,
    /// One SPI forwarding transfer must finish in this time, ms.
    pub spi_timeout_ms: u64,
    /// Write the flash image when it is missing or corrupt (thesis 4.10).
    pub write_flash_if_missing: bool,
    /// Extra measurements to try within a cycle after a dropped frame
    /// (0: the cycle fails with `CorruptFrame`).
    pub frame_retries: u32,
}

impl Default for DriverTiming {
    fn default() -> Self {
        DriverTiming {
            reset_low_us: 2,
            startup_delay_us: 1000,
            startup_timeout_ms: 20,
            poll_interval_us: 200,
            flash_load_timeout_ms: 50,
            flash_erase_timeout_ms: 500,
            flash_program_timeout_ms: 10,
            spi_timeout_ms: 5,
            write_flash_if_missing: true,
            frame_retries: 0,
        }
    }
}

/// Driver configuration: protocol, register map, waits.
#[derive(Debug, Clone, PartialEq)]
pub struct DriverConfig {
    /// Bridge protocol.
    pub protocol: ProtocolConfig,
    /// Register map.
    pub map: SensorMap,
    /// Waits and policies.
    pub timing: DriverTiming,
}

/// The file form of [`DriverConfig`] (`[driver]` table or a file).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriverConfigFile {
    /// Register map file, relative to the config file (default: the
    /// built-in emulated map).
    #[serde(default)]
    pub sensor_map: Option<PathBuf>,
    /// Bridge protocol.
    #[serde(default)]
    pub protocol: ProtocolConfig,
    /// Waits and policies.
    #[serde(default)]
    pub timing: DriverTiming,
}

impl DriverConfigFile {
    /// Resolve into a [`DriverConfig`]; relative map paths are taken from
    /// `base_dir`.
    pub fn resolve(&self, base_dir: &Path) -> Result<DriverConfig, BridgeError> {
        let map = match &self.sensor_map {
            Some(p) => SensorMap::load(&base_dir.join(p))?,
            None => SensorMap::emulated(),
        };
        let c = DriverConfig {
            protocol: self.protocol.clone(),
            map,
            timing: self.timing.clone(),
        };
        c.validate()?;
        Ok(c)
    }
}

impl DriverConfig {
    /// The built-in emulated map with default protocol and waits.
    pub fn emulated_default() -> Self {
        DriverConfig {
            protocol: ProtocolConfig::default(),
            map: SensorMap::emulated(),
            timing: DriverTiming::default(),
        }
    }

    /// Range checks of everything.
    pub fn validate(&self) -> Result<(), BridgeError> {
        self.protocol.validate()?;
        self.map.validate()?;
        let t = &self.timing;
        if t.poll_interval_us == 0 {
            return Err(BridgeError::config("timing.poll_interval_us must be > 0"));
        }
        if let Some(b) = &self.map.bring_up
            && t.reset_low_us < b.reset_low_us
        {
            return Err(BridgeError::config(format!(
                "timing.reset_low_us = {} is shorter than the sensor's reset pulse, bring_up.reset_low_us = {}",
                t.reset_low_us, b.reset_low_us
            )));
        }
        let words = usize::from(self.map.spi.window_bytes) / 2;
        if words > usize::from(u16::MAX) - usize::from(self.map.spi.tx_base) {
            return Err(BridgeError::config(
                "spi.window_bytes runs past register 0xffff",
            ));
        }
        Ok(())
    }
}

/// A real-hardware device file (`config/sensor/device.toml`): which USB
/// device, and the driver settings.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeviceConfigFile {
    /// USB device selection.
    pub usb: crate::usb::UsbSelector,
    /// Driver (register map, protocol, waits).
    pub driver: DriverConfigFile,
}

impl DeviceConfigFile {
    /// Load a device file; returns it with the resolved driver config.
    pub fn load(path: &Path) -> Result<(Self, DriverConfig), BridgeError> {
        let f: DeviceConfigFile = read_toml(path, "device config")?;
        let d = f.driver.resolve_beside(path)?;
        Ok((f, d))
    }
}

impl DriverConfigFile {
    /// Load a driver file (the `[driver]` table's keys at top level) and resolve
    /// it; a relative register map path is taken from the file's directory.
    pub fn load(path: &Path) -> Result<DriverConfig, BridgeError> {
        read_toml::<DriverConfigFile>(path, "driver config")?.resolve_beside(path)
    }

    /// [`Self::resolve`] relative to the directory of the file at `path`, errors
    /// prefixed with that path.
    fn resolve_beside(&self, path: &Path) -> Result<DriverConfig, BridgeError> {
        let base = path.parent().unwrap_or(Path::new("."));
        self.resolve(base)
            .map_err(|e| e.context_prefix(path.display()))
    }
}

/// Read and parse a TOML config file (`what` names it in the error).
fn read_toml<T: serde::de::DeserializeOwned>(path: &Path, what: &str) -> Result<T, BridgeError> {
    let s = crate::error::read_config_text(path)?;
    toml::from_str(&s).map_err(|e| {
        BridgeError::with_source(ErrorKind::Config, format!("{what} {}", path.display()), e)
    })
}
