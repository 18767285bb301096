//! Daemon configuration (`/etc/tofprox/tofproxd.toml`, commented defaults in
//! `config/tofproxd.toml`). Every table denies unknown keys; [`Config::validate`]
//! range-checks every value and names the offending key.

mod backends;
mod cycle;
mod energy;
mod error;
mod publish;
mod sensing;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use backends::{DeviceSpec, EmulatedConfig, ReplayConfig, UsbConfig};
pub use cycle::{LoopConfig, ProcessingConfig};
pub use energy::EnergyConfig;
pub use error::ConfigError;
use error::range;
pub use publish::{DbusConfig, SOCKET_MAX_CLIENTS, SOCKET_MAX_QUEUE_LINES, SocketConfig};
pub use sensing::{
    AmbientConfig, ExposureConfig, NOMINAL_AMPLITUDE_SCALE, ProbeConfig, ProximityConfig,
    ReadoutConfig,
};

/// Which frame source drives the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// Real hardware over USB (CX3 bridge).
    Usb,
    /// The bridge's emulated device through the same driver stack.
    Emulated,
    /// Replay of a version 1 recording.
    Replay,
    /// A V4L2 capture device whose kernel driver delivers the raw phase images (a
    /// single-board computer's ToF module: `[v4l2]`).
    V4l2,
}

/// Where the readings are published (`publisher =`; the publishers themselves: the crate's
/// `publisher` module).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PublisherKind {
    /// D-Bus: `org.tofprox.Proximity1` (status, claims), and `net.hadess.SensorProxy` with
    /// `[dbus] iio_sensor_proxy_compat`.
    Dbus,
    /// D-Bus, and a uinput device reporting `SW_FRONT_PROXIMITY` (iio-sensor-proxy reads it).
    /// No claim reaches us through an input device, so the loop runs as with `loop.always_on`.
    Input,
    /// JSON Lines on the Unix socket of `[socket]`, and no D-Bus at all: no bus connection is
    /// made. A connected client is a proximity claim.
    Socket,
}

/// Processing mode of a reading: the shared measurement mode [`tofprox_core::Algorithm`]
/// (serde and the D-Bus `Mode` property: `"2phase"` / `"4phase"`, thesis eqs. 2.2 / 2.3).
pub use tofprox_core::Algorithm as Mode;

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// `usb`, `emulated`, `replay` or `v4l2`.
    pub backend: Backend,
    /// Where the readings go: `dbus` (the native interface only), `input` (also the switch
    /// of a uinput device, for iio-sensor-proxy) or `socket` (JSON Lines on `[socket] path`,
    /// no D-Bus).
    pub publisher: PublisherKind,
    /// Main loop settings.
    #[serde(rename = "loop")]
    pub loop_: LoopConfig,
    /// Processing (mode, calibration).
    pub processing: ProcessingConfig,
    /// Near/far decision.
    pub proximity: ProximityConfig,
    /// Background light detection (2-phase ↔ 4-phase switching).
    pub ambient: AmbientConfig,
    /// Auto-exposure and its eye-safe limits.
    pub exposure: ExposureConfig,
    /// Partial read-out.
    pub readout: ReadoutConfig,
    /// The presence probe while far and still.
    pub probe: ProbeConfig,
    /// Energy model (thesis table 3.1).
    pub energy: EnergyConfig,
    /// D-Bus.
    pub dbus: DbusConfig,
    /// The socket publisher (`publisher = "socket"`).
    pub socket: SocketConfig,
    /// USB backend.
    pub usb: UsbConfig,
    /// Emulated backend.
    pub emulated: EmulatedConfig,
    /// Replay backend.
    pub replay: ReplayConfig,
    /// V4L2 backend: the device node, its format and the names of its controls (the bridge's
    /// settings, unknown keys refused).
    pub v4l2: tofprox_bridge::v4l2::camera::V4l2Settings,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            backend: Backend::Emulated,
            publisher: PublisherKind::Dbus,
            loop_: LoopConfig::default(),
            processing: ProcessingConfig::default(),
            proximity: ProximityConfig::default(),
            ambient: AmbientConfig::default(),
            exposure: ExposureConfig::default(),
            readout: ReadoutConfig::default(),
            probe: ProbeConfig::default(),
            energy: EnergyConfig::default(),
            dbus: DbusConfig::default(),
            socket: SocketConfig::default(),
            usb: UsbConfig::default(),
            emulated: EmulatedConfig::default(),
            replay: ReplayConfig::default(),
            v4l2: Default::default(),
        }
    }
}

impl Config {
    /// The rows read, as row steps on the array `(reading, probe)`, on a source that reads row
    /// windows (`reads_windows`) and skips rows up to `max_row_step`, of `full_rows` rows: a
    /// reading's `readout.row_step` with partial read-out where the sequencer skips that far
    /// and the rows divide by it (else every row); the probe's `probe.row_step` at most the
    /// sequencer's, when a multiple of the reading's (else the reading's). The daemon's loop
    /// and `tofprox power` read with these.
    pub fn row_steps(
        &self,
        reads_windows: bool,
        max_row_step: u16,
        full_rows: usize,
    ) -> (u16, u16) {
        let reading = if self.readout.partial && reads_windows {
            self.readout.row_step_for(max_row_step, full_rows)
        } else {
            1
        };
        let probe = self.probe.row_step_for(max_row_step);
        (
            reading,
            if probe.is_multiple_of(reading) {
                probe
            } else {
                reading
            },
        )
    }

    /// The shipped defaults replaying `recording` as fast as the data comes, at the recording's
    /// own exposure (no auto-exposure): a recording read back reading by reading.
    pub fn replay_as_fast_as_possible(recording: &Path) -> Config {
        let mut cfg = Config {
            backend: Backend::Replay,
            ..Config::default()
        };
        cfg.replay.recording = Some(recording.to_path_buf());
        cfg.replay.realtime = false;
        cfg.exposure.auto = false;
        cfg
    }

    /// Load and validate a config file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text =
            tofprox_format::limits::read_text_bounded(path, tofprox_format::limits::MAX_TOML_BYTES)
                .map_err(|source| ConfigError::Read {
                    path: path.to_path_buf(),
                    source,
                })?;
        let mut cfg = Self::parse(&text, path)?;
        cfg.resolve_paths(path.parent().unwrap_or(Path::new(".")));
        Ok(cfg)
    }

    /// Parse and validate TOML text (`origin` only for messages).
    pub fn parse(text: &str, origin: &Path) -> Result<Self, ConfigError> {
        let cfg: Config = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: origin.to_path_buf(),
            message: e.to_string(),
        })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Relative paths in the file are relative to the file's directory.
    fn resolve_paths(&mut self, base: &Path) {
        let fix = |p: &mut Option<PathBuf>| {
            if let Some(p) = p
                && p.is_relative()
            {
                *p = base.join(&*p);
            }
        };
        fix(&mut self.processing.calibration);
        fix(&mut self.usb.driver_config);
        if let Some(DeviceSpec::Path(p)) = &mut self.emulated.device
            && p.is_relative()
        {
            *p = base.join(&*p);
        }
        fix(&mut self.replay.recording);
        if self.socket.path.is_relative() {
            self.socket.path = base.join(&self.socket.path);
        }
    }

    /// Range-check every value; the error names the key.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.loop_.validate()?;
        self.processing.validate()?;
        self.proximity.validate()?;
        self.ambient.validate()?;
        self.exposure.validate()?;
        self.probe.validate()?;
        self.readout.validate()?;
        error::range(
            "probe.row_step",
            self.probe
                .row_step
                .is_multiple_of(self.readout.row_step.max(1)),
            format!(
                "must be a multiple of readout.row_step ({}), got {}",
                self.readout.row_step, self.probe.row_step
            ),
        )?;
        self.energy.validate()?;
        self.dbus.validate()?;
        self.socket.validate()?;
        if self.backend == Backend::Replay {
            range(
                "replay.recording",
                self.replay.recording.is_some(),
                "must be set for backend = \"replay\"",
            )?;
        }
        if self.backend == Backend::V4l2 {
            self.v4l2.validate().map_err(|e| ConfigError::Range {
                key: "v4l2".into(),
                message: e.to_string(),
            })?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_default_file_equals_defaults() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/tofproxd.toml");
        let text = std::fs::read_to_string(&path).expect("config/tofproxd.toml is shipped");
        let cfg = Config::parse(&text, &path).expect("shipped config parses");
        // the installed file differs from the defaults only in its backend and in requiring
        // the module's factory calibration where the package keeps it
        let mut expected = Config {
            backend: cfg.backend,
            ..Config::default()
        };
        expected.processing.calibration = Some(PathBuf::from("/var/lib/tofprox/calib"));
        expected.processing.require_calibration = true;
        assert_eq!(cfg, expected, "config/tofproxd.toml must list the defaults");
    }

    #[test]
    fn the_socket_table_is_checked_and_names_its_key() {
        let ok = "publisher = \"socket\"\n[socket]\npath = \"/run/x.sock\"\nmode = 0o600\n";
        let cfg = Config::parse(ok, Path::new("x.toml")).expect("valid");
        assert_eq!(cfg.publisher, PublisherKind::Socket);
        assert_eq!(cfg.socket.mode, 0o600);
        assert_eq!(cfg.socket.path, Path::new("/run/x.sock"));
        for (text, key) in [
            ("[socket]\npaht = \"/x\"\n", "paht"),
            ("[socket]\nmode = 0o1777\n", "socket.mode"),
            ("[socket]\nmax_clients = 0\n", "socket.max_clients"),
            ("[socket]\nmax_clients = 257\n", "socket.max_clients"),
            ("[socket]\nqueue_lines = 0\n", "socket.queue_lines"),
            ("[socket]\nqueue_lines = 65537\n", "socket.queue_lines"),
            ("[socket]\npath = \"\"\n", "socket.path"),
        ] {
            let err = Config::parse(text, Path::new("x.toml")).unwrap_err();
            assert!(err.to_string().contains(key), "{text}: {err}");
        }
    }

    #[test]
    fn unknown_key_is_named() {
        let err = Config::parse("[loop]\nrate_hzz = 3.0\n", Path::new("x.toml")).unwrap_err();
        assert!(err.to_string().contains("rate_hzz"), "{err}");
    }

    #[test]
    fn out_of_range_names_key() {
        let err = Config::parse("[exposure]\nmax_us = 20000.0\n", Path::new("x.toml")).unwrap_err();
        assert!(err.to_string().contains("exposure.max_us"), "{err}");
        let err = Config::parse(
            "[proximity]\nnear_mm = 200\nfar_mm = 150\n",
            Path::new("x.toml"),
        )
        .unwrap_err();
        assert!(err.to_string().contains("proximity.far_mm"), "{err}");
        let err = Config::parse("backend = \"replay\"\n", Path::new("x.toml")).unwrap_err();
        assert!(err.to_string().contains("replay.recording"), "{err}");
    }

    #[test]
    fn bad_enum_rejected() {
        assert!(Config::parse("backend = \"serial\"\n", Path::new("x.toml")).is_err());
        assert!(Config::parse("[processing]\nmode = \"3phase\"\n", Path::new("x.toml")).is_err());
    }
}
