//! Configuration of the emulated device (`config/emulated/*.toml`, or a
//! table inside the daemon's config).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use tofprox_model::{CoverWindow, SceneScript};

use crate::error::{BridgeError, ErrorKind};
use crate::protocol::ProtocolConfig;
use crate::regmap::SensorMap;

/// Timing model of the emulated sensor and flash (all on the injected clock).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TimingModel {
    /// Reset release until the sensor answers on I2C, µs.
    pub startup_us: f64,
    /// Flash configuration load: fixed part, µs.
    pub config_load_base_us: f64,
    /// Flash configuration load: per register of the image, µs.
    pub config_load_per_register_us: f64,
    /// Start of measurement until the first exposure begins, µs.
    pub measurement_start_us: f64,
    /// Read-out time per row of a raw frame, µs.
    pub readout_per_row_us: f64,
    /// SPI forwarding bit rate, bit/s.
    pub spi_bit_rate_hz: f64,
    /// SPI NOR sector erase time, µs.
    pub flash_sector_erase_us: f64,
    /// SPI NOR page program time, µs.
    pub flash_page_program_us: f64,
    /// After an unplug, the device is back after this long, ms.
    pub replug_after_ms: f64,
}

impl Default for TimingModel {
    fn default() -> Self {
        TimingModel {
            startup_us: 800.0,
            config_load_base_us: 300.0,
            config_load_per_register_us: 2.0,
            measurement_start_us: 50.0,
            readout_per_row_us: 8.0,
            spi_bit_rate_hz: 20e6,
            flash_sector_erase_us: 30_000.0,
            flash_page_program_us: 700.0,
            replug_after_ms: 0.0,
        }
    }
}

impl TimingModel {
    fn validate(&self) -> Result<(), BridgeError> {
        let fields = [
            ("startup_us", self.startup_us),
            ("config_load_base_us", self.config_load_base_us),
            (
                "config_load_per_register_us",
                self.config_load_per_register_us,
            ),
            ("measurement_start_us", self.measurement_start_us),
            ("readout_per_row_us", self.readout_per_row_us),
            ("flash_sector_erase_us", self.flash_sector_erase_us),
            ("flash_page_program_us", self.flash_page_program_us),
            ("replug_after_ms", self.replug_after_ms),
        ];
        for (k, v) in fields {
            if !(v.is_finite() && (0.0..=60e6).contains(&v)) {
                return Err(BridgeError::config(format!(
                    "timing.{k} = {v} out of range 0..=6e7"
                )));
            }
        }
        if !(self.spi_bit_rate_hz.is_finite() && self.spi_bit_rate_hz >= 1e3) {
            return Err(BridgeError::config(
                "timing.spi_bit_rate_hz must be >= 1000",
            ));
        }
        Ok(())
    }
}

/// Where the emulated frames come from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FrameSource {
    /// The physical model (tofprox-model `Simulator`), `model` file or the
    /// model's baseline.
    #[default]
    Model,
    /// The fast ideal sinusoid (column offsets, small noise): for long soak
    /// runs where frame realism does not matter.
    Ideal,
}

/// Kinds of injectable faults.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// The device disappears from the bus mid-cycle (back after
    /// `replug_after_ms`).
    Unplug,
    /// A control transfer times out.
    ControlTimeout,
    /// The bulk endpoint stalls (until cleared).
    Stall,
    /// An I2C transaction is not acknowledged.
    I2cNak,
    /// A payload is corrupted (device error bit, broken header, or a flipped
    /// data bit).
    CorruptPayload,
    /// A payload is cut short.
    ShortPayload,
    /// Two payloads arrive swapped.
    OutOfOrder,
    /// The flash image is erased before the cycle.
    FlashEmpty,
    /// A byte of the flash image is flipped before the cycle.
    FlashCorrupt,
    /// The sensor does not come out of reset this cycle.
    ResetStuck,
}

impl FaultKind {
    /// Every fault kind.
    pub const ALL: [FaultKind; 10] = [
        FaultKind::Unplug,
        FaultKind::ControlTimeout,
        FaultKind::Stall,
        FaultKind::I2cNak,
        FaultKind::CorruptPayload,
        FaultKind::ShortPayload,
        FaultKind::OutOfOrder,
        FaultKind::FlashEmpty,
        FaultKind::FlashCorrupt,
        FaultKind::ResetStuck,
    ];
}

/// One fault's switch: a probability per cycle and/or one-shot cycles.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FaultSpec {
    /// Probability per cycle (0..=1).
    pub probability: f64,
    /// Inject exactly at these cycle numbers (1-based: the n-th reset
    /// release).
    pub at_cycles: Vec<u64>,
}

/// All fault switches (each defaults to off).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FaultConfig {
    /// Unplug/replug.
    pub unplug: FaultSpec,
    /// Control-transfer timeout.
    pub control_timeout: FaultSpec,
    /// Endpoint stall.
    pub stall: FaultSpec,
    /// I2C NAK.
    pub i2c_nak: FaultSpec,
    /// Corrupted payload.
    pub corrupt_payload: FaultSpec,
    /// Short payload.
    pub short_payload: FaultSpec,
    /// Out-of-order payloads.
    pub out_of_order: FaultSpec,
    /// Flash erased.
    pub flash_empty: FaultSpec,
    /// Flash image corrupted.
    pub flash_corrupt: FaultSpec,
    /// Sensor stuck in reset.
    pub reset_stuck: FaultSpec,
}

impl FaultConfig {
    /// Every fault with the same per-cycle probability `p / 10`, so that on
    /// average a fraction `p` of cycles sees one fault (soak tests).
    pub fn uniform(p: f64) -> Self {
        let mut c = FaultConfig::default();
        for k in FaultKind::ALL {
            c.spec_mut(k).probability = (p / FaultKind::ALL.len() as f64).clamp(0.0, 1.0);
        }
        c
    }

    /// The switch of `kind`.
    pub fn spec(&self, kind: FaultKind) -> &FaultSpec {
        match kind {
            FaultKind::Unplug => &self.unplug,
            FaultKind::ControlTimeout => &self.control_timeout,
            FaultKind::Stall => &self.stall,
            FaultKind::I2cNak => &self.i2c_nak,
            FaultKind::CorruptPayload => &self.corrupt_payload,
            FaultKind::ShortPayload => &self.short_payload,
            FaultKind::OutOfOrder => &self.out_of_order,
            FaultKind::FlashEmpty => &self.flash_empty,
            FaultKind::FlashCorrupt => &self.flash_corrupt,
            FaultKind::ResetStuck => &self.reset_stuck,
        }
    }

    /// Mutable switch of `kind`.
    pub fn spec_mut(&mut self, kind: FaultKind) -> &mut FaultSpec {
        match kind {
            FaultKind::Unplug => &mut self.unplug,
            FaultKind::ControlTimeout => &mut self.control_timeout,
            FaultKind::Stall => &mut self.stall,
            FaultKind::I2cNak => &mut self.i2c_nak,
            FaultKind::CorruptPayload => &mut self.corrupt_payload,
            FaultKind::ShortPayload => &mut self.short_payload,
            FaultKind::OutOfOrder => &mut self.out_of_order,
            FaultKind::FlashEmpty => &mut self.flash_empty,
            FaultKind::FlashCorrupt => &mut self.flash_corrupt,
            FaultKind::ResetStuck => &mut self.reset_stuck,
        }
    }

    fn validate(&self) -> Result<(), BridgeError> {
        for k in FaultKind::ALL {
            let p = self.spec(k).probability;
            if !(p.is_finite() && (0.0..=1.0).contains(&p)) {
                return Err(BridgeError::config(format!(
                    "faults.{}.probability = {p} not in 0..=1",
                    serde_name(k)
                )));
            }
        }
        Ok(())
    }
}

fn serde_name(k: FaultKind) -> String {
    toml::Value::try_from(k)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_else(|| format!("{k:?}"))
}

/// The emulated device's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmulatedConfig {
    /// Register map file (relative paths: to the config file); default: the
    /// built-in `config/sensor/emulated-irs1645.toml`.
    pub sensor_map: Option<PathBuf>,
    /// Physical model file for frame synthesis (tofprox-model); default: the
    /// model's baseline.
    pub model: Option<PathBuf>,
    /// SPI flash contents persisted here (created erased); default: in
    /// memory (starts erased every run).
    pub flash_file: Option<PathBuf>,
    /// Flash size, bytes (multiple of the sector size).
    pub flash_size_bytes: u32,
    /// The firmware's protocol (must match the driver's).
    pub protocol: ProtocolConfig,
    /// Timing model.
    pub timing: TimingModel,
    /// Frame source.
    pub frame_source: FrameSource,
    /// Scene script in front of the sensor (tofprox-model `SceneScript`:
    /// `kind = "wall" | "hand" | "face"`, distances, period).
    pub scene: SceneScript,
    /// The cover window in front of the sensor (tofprox-model `CoverWindow`):
    /// enables the model's `cover_window_crosstalk` effect with these
    /// parameters (clean or smudged); unset: as the model file says. Only the
    /// `model` frame source renders it.
    pub cover_window: Option<CoverWindow>,
    /// Ambient light, klux (model input).
    pub ambient_klux: f64,
    /// Sensor temperature, °C (model input).
    pub temperature_c: f64,
    /// Fault injection.
    pub faults: FaultConfig,
}

impl Default for EmulatedConfig {
    fn default() -> Self {
        EmulatedConfig {
            sensor_map: None,
            model: None,
            flash_file: None,
            flash_size_bytes: 64 * 1024,
            protocol: ProtocolConfig::default(),
            timing: TimingModel::default(),
            frame_source: FrameSource::Model,
            scene: SceneScript::wall(1.0),
            cover_window: None,
            ambient_klux: 0.0,
            temperature_c: 25.0,
            faults: FaultConfig::default(),
        }
    }
}

impl EmulatedConfig {
    /// Parse TOML text; relative paths are resolved against `base_dir`.
    pub fn from_toml_str(s: &str, base_dir: &Path) -> Result<Self, BridgeError> {
        let mut c: EmulatedConfig = toml::from_str(s).map_err(|e| {
            BridgeError::with_source(ErrorKind::Config, "emulated device config", e)
        })?;
        c.resolve_relative_paths(base_dir);
        c.validate()?;
        Ok(c)
    }

    /// Make `sensor_map`, `model` and `flash_file` absolute against
    /// `base_dir` (for configs embedded in another file, e.g. the daemon's).
    pub fn resolve_relative_paths(&mut self, base_dir: &Path) {
        for p in [&mut self.sensor_map, &mut self.model, &mut self.flash_file]
            .into_iter()
            .flatten()
        {
            if p.is_relative() {
                *p = base_dir.join(&*p);
            }
        }
    }

    /// Load a config file.
    pub fn load(path: &Path) -> Result<Self, BridgeError> {
        let s = crate::error::read_config_text(path)?;
        let base = path.parent().unwrap_or(Path::new("."));
        Self::from_toml_str(&s, base).map_err(|e| e.context_prefix(path.display()))
    }

    /// The register map this config selects.
    pub fn sensor_map(&self) -> Result<SensorMap, BridgeError> {
        match &self.sensor_map {
            Some(p) => SensorMap::load(p),
            None => Ok(SensorMap::emulated()),
        }
    }

    /// The driver configuration matching this device: its register map and
    /// protocol, default waits.
    pub fn driver_config(&self) -> Result<crate::driver::DriverConfig, BridgeError> {
        let c = crate::driver::DriverConfig {
            protocol: self.protocol.clone(),
            map: self.sensor_map()?,
            timing: crate::driver::DriverTiming::default(),
        };
        c.validate()?;
        Ok(c)
    }

    /// Range checks; errors name the key.
    pub fn validate(&self) -> Result<(), BridgeError> {
        self.protocol.validate()?;
        self.timing.validate()?;
        self.scene
            .validate()
            .map_err(|e| BridgeError::with_source(ErrorKind::Config, "scene", e))?;
        self.faults.validate()?;
        if let Some(w) = &self.cover_window {
            w.apply(&mut tofprox_model::ModelConfig::ideal())
                .map_err(|e| BridgeError::with_source(ErrorKind::Config, "cover_window", e))?;
        }
        if !(4096..=(64 << 20)).contains(&self.flash_size_bytes)
            || !self.flash_size_bytes.is_multiple_of(4096)
        {
            return Err(BridgeError::config(format!(
                "flash_size_bytes = {} must be a multiple of 4096 in 4 KiB..=64 MiB",
                self.flash_size_bytes
            )));
        }
        if !(self.ambient_klux.is_finite() && (0.0..=200.0).contains(&self.ambient_klux)) {
            return Err(BridgeError::config("ambient_klux must be in 0..=200"));
        }
        if !(self.temperature_c.is_finite() && (-40.0..=125.0).contains(&self.temperature_c)) {
            return Err(BridgeError::config("temperature_c must be in -40..=125"));
        }
        Ok(())
    }
}
