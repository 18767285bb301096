//! The emulated backend (cargo feature `emulated`, on by default): the bridge's
//! transfer-level emulated device — frames from the physical model — behind the real
//! driver, as a [`FrameSource`](crate::source::FrameSource). A child of [`crate::backends`]
//! (it wraps the parent's [`BridgeSource`]; the parent's `build_source` dispatches here).
//! The daemon's test machinery (the scene bench and the soak run on it); the production
//! build (`--no-default-features`) leaves it out and links neither the emulator nor
//! `tofprox-model`.

use std::path::Path;
use std::sync::Arc;

use tofprox_bridge::{
    BridgeError, Clock, EmulatedConfig as DeviceConfig, EmulatedDevice, SensorDriver, SystemClock,
    VirtualClock,
};

use super::{BridgeSource, chain};
use crate::config::{Config, DeviceSpec};
use crate::source::{SourceError, SourceErrorKind};

/// The emulated device as a frame source: the bridge's one emulated stack
/// ([`SensorDriver::emulated`]) wrapped for the loop, named `name` in logs and status.
pub fn bridge_source(
    device: DeviceConfig,
    clock: Arc<dyn Clock>,
    seed: u64,
    name: &str,
) -> Result<BridgeSource<EmulatedDevice>, BridgeError> {
    let driver = SensorDriver::emulated(device, clock.clone(), seed)?;
    Ok(BridgeSource::new(driver, clock, name))
}

/// The configured emulated backend (`backend = "emulated"`): the device of
/// `[emulated]` on the system clock, or on a virtual one with `virtual_time`.
pub fn source(cfg: &Config, base: &Path) -> Result<BridgeSource<EmulatedDevice>, SourceError> {
    let clock: Arc<dyn Clock> = if cfg.emulated.virtual_time {
        Arc::new(VirtualClock::new())
    } else {
        Arc::new(SystemClock::new())
    };
    bridge_source(
        device_config(cfg, base)?,
        clock,
        cfg.emulated.seed,
        "emulated CX3 + IRS1645",
    )
    .map_err(|e| {
        SourceError::new(
            SourceErrorKind::Unsupported,
            format!("emulated device: {}", chain(&e)),
        )
        .with_source(e)
    })
}

/// Load the emulated device configuration of a daemon config. A `device = "FILE"` path is
/// used as it stands in `cfg` ([`Config::load`] already made it relative to the config
/// file's directory — joining `base` again would resolve it twice); paths inside an inline
/// `[emulated.device]` table are resolved against `base` (the config file's directory).
/// Errors keep the bridge's reason (an unknown key is named).
pub fn device_config(cfg: &Config, base: &Path) -> Result<DeviceConfig, SourceError> {
    let err = |what: &str, e: BridgeError| {
        SourceError::new(
            SourceErrorKind::Unsupported,
            format!("{what}: {}", chain(&e)),
        )
        .with_source(e)
    };
    match &cfg.emulated.device {
        None => Ok(DeviceConfig::default()),
        Some(DeviceSpec::Path(p)) => DeviceConfig::load(p).map_err(|e| err("emulated.device", e)),
        Some(DeviceSpec::Inline(t)) => {
            let text = toml::to_string(t).map_err(|e| {
                SourceError::new(
                    SourceErrorKind::Unsupported,
                    format!("[emulated.device]: {e}"),
                )
            })?;
            DeviceConfig::from_toml_str(&text, base).map_err(|e| err("[emulated.device]", e))
        }
    }
}
