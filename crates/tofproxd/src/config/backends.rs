//! The backends' tables: `[usb]`, `[emulated]` and `[replay]`.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// `[usb]`
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct UsbConfig {
    /// Driver/bridge configuration file (tofprox-bridge format). Empty: bridge defaults.
    pub driver_config: Option<PathBuf>,
    /// Which device (`vendor_id`, `product_id`, `serial`, `bus_path`, `interface`).
    pub device: tofprox_bridge::UsbSelector,
}

/// The emulated device: a path to a bridge config file, or the table inline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum DeviceSpec {
    /// `device = "emulated/hand.toml"`.
    Path(PathBuf),
    /// `[emulated.device]` table (tofprox-bridge `EmulatedConfig` keys).
    Inline(toml::Table),
}

/// `[emulated]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmulatedConfig {
    /// Emulated device: a tofprox-bridge config file path, or the `[emulated.device]` table inline.
    pub device: Option<DeviceSpec>,
    /// Random seed of the emulated frames.
    pub seed: u64,
    /// Run the emulated device on virtual time (no real sleeps; tests).
    pub virtual_time: bool,
}

impl Default for EmulatedConfig {
    fn default() -> Self {
        Self {
            device: None,
            seed: 1,
            virtual_time: false,
        }
    }
}

/// `[replay]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// Recording directory (version 1).
    pub recording: Option<PathBuf>,
    /// `true`: pace at the recording's timestamps / the loop rate; `false`: as fast as possible.
    pub realtime: bool,
    /// Start over at the end (otherwise the source reports end-of-recording and the loop stops).
    pub repeat: bool,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        Self {
            recording: None,
            realtime: true,
            repeat: false,
        }
    }
}
