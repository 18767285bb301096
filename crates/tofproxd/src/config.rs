//! Daemon configuration (`/etc/tofprox/tofproxd.toml`, commented defaults in
//! `config/tofproxd.toml`). Every table denies unknown keys; [`Config::validate`]
//! range-checks every value and names the offending key.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// Errors while loading or validating the configuration. The message always
/// names the file and/or the key.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read (missing, not a regular file, above the size limit).
    #[error("cannot read config {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The bounded reader's error (names the file).
        source: tofprox_format::FormatError,
    },
    /// The TOML is malformed or has unknown keys / wrong types.
    #[error("invalid config {path}: {message}")]
    Parse {
        /// The file (or `<string>`).
        path: PathBuf,
        /// toml's message (names the key and line).
        message: String,
    },
    /// A value is out of range.
    #[error("invalid config value `{key}`: {message}")]
    Range {
        /// Dotted key, e.g. `loop.fast_rate_hz`.
        key: String,
        /// What is wrong.
        message: String,
    },
}

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

/// `[loop]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoopConfig {
    /// Keep the loop running without any claim (otherwise the sensor is held in reset).
    pub always_on: bool,
    /// Reading rate while far and not still (Hz).
    pub rate_hz: f64,
    /// Reading rate while a target approaches or is near (Hz), the upper bound.
    pub fast_rate_hz: f64,
    /// Reading rate while far and still (Hz), the lower bound.
    pub slow_rate_hz: f64,
    /// Far readings with little change before dropping to `slow_rate_hz`.
    pub still_readings: u32,
    /// A distance change below this (mm) between readings counts as still.
    pub still_tolerance_mm: u32,
    /// Approach speed (mm/s) that switches to `fast_rate_hz`.
    pub approach_mm_per_s: f64,
    /// Wait between retries after a failed cycle (ms).
    pub retry_ms: u64,
    /// Consecutive failed cycles after which `State` becomes `unavailable`.
    pub unavailable_after: u32,
    /// How long (ms) a published Near is held across failed cycles without a valid reading;
    /// then Near is released (far). Holding near during a call is the safe side, for ever is not.
    pub near_hold_ms: u64,
    /// Bounded wait of `ClaimProximity` for the first valid reading (ms).
    pub first_reading_timeout_ms: u64,
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self {
            always_on: false,
            rate_hz: 2.0,
            fast_rate_hz: 10.0,
            slow_rate_hz: 1.0,
            still_readings: 10,
            still_tolerance_mm: 20,
            approach_mm_per_s: 150.0,
            retry_ms: 200,
            unavailable_after: 5,
            near_hold_ms: 1000,
            first_reading_timeout_ms: 3000,
        }
    }
}

/// `[processing]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProcessingConfig {
    /// Low-power processing mode (thesis 3.5.3: 2-phase).
    pub mode: Mode,
    /// Minimum amplitude (LSB) for a valid pixel.
    pub min_amplitude_lsb: f32,
    /// Calibration set directory (offset + wiggling, keyed to the mode). Empty: uncalibrated.
    pub calibration: Option<PathBuf>,
    /// Refuse to start without a calibration for the configured mode.
    pub require_calibration: bool,
}

impl Default for ProcessingConfig {
    fn default() -> Self {
        Self {
            mode: Mode::TwoPhase,
            min_amplitude_lsb: 8.0,
            calibration: None,
            require_calibration: false,
        }
    }
}

/// `[proximity]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProximityConfig {
    /// Enter near at or below this distance (mm) — at once.
    pub near_mm: u32,
    /// Leave near above this distance (mm) — after the debounce.
    pub far_mm: u32,
    /// Consecutive far readings before far is published.
    pub far_debounce: u32,
    /// Minimum share of valid ROI pixels for a reading to count.
    pub min_valid_fraction: f32,
    /// Region of interest `[row0, col0, rows, cols]`; empty: the central quarter.
    #[serde(deserialize_with = "tofprox_core::serde_exact::option_array")]
    pub roi: Option<[usize; 4]>,
    /// Darkest target reflectivity a reading below `far_mm` must be plausible for (thesis
    /// 2.2.1, `A = K·ρ·t/d²`; `tofprox_core::radiometry`): a dimmer return is a wrapped far
    /// target or stray light, not a target.
    pub reflectivity_floor: f64,
    /// Depth uncertainty (mm) the plausibility test allows: the near hypothesis is tested at
    /// the measured depth plus this.
    pub depth_uncertainty_mm: u32,
    /// Amplitude scale `K` (LSB·m²/µs) used when the calibration set has no `amplitude` part
    /// (status `AmplitudeCheck = "nominal"`). The default is the emulated IRS1645-class module
    /// (2 W VCSEL) as `tofprox calibrate wiggling` measures it.
    pub nominal_amplitude_scale: f64,
    /// Second modulation frequency (Hz) a dim near candidate is confirmed at before Near is
    /// published (thesis eqs. 2.8/2.9; `policy::second_frequency`); 0 = off (the amplitude
    /// test decides alone).
    pub second_modulation_hz: f64,
    /// A near candidate is dim (confirmed at the second frequency) when its return is below
    /// what a diffuse target of this reflectivity returns at its measured depth …
    pub confirm_reflectivity: f64,
    /// … or below what the brightest far target (gain relative to a white wall: retroreflective
    /// tape ~1000× at a phone's observation angle; the default 2000 leaves a factor 2 for the
    /// amplitude scale's error) returns one unambiguous range further.
    pub brightest_far_gain: f64,
}

impl Default for ProximityConfig {
    fn default() -> Self {
        Self {
            near_mm: 100,
            far_mm: 150,
            far_debounce: 3,
            min_valid_fraction: 0.3,
            roi: None,
            reflectivity_floor: tofprox_core::radiometry::DEFAULT_REFLECTIVITY_FLOOR,
            depth_uncertainty_mm: 30,
            nominal_amplitude_scale: NOMINAL_AMPLITUDE_SCALE,
            second_modulation_hz: 70e6,
            confirm_reflectivity: 0.2,
            brightest_far_gain: 2000.0,
        }
    }
}

/// Default of `proximity.nominal_amplitude_scale` (LSB·m²/µs): the emulated sensor's median
/// scale from its factory calibration (`tofprox info calib/emulated`).
pub const NOMINAL_AMPLITUDE_SCALE: f64 = 0.09;

/// `[ambient]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AmbientConfig {
    /// Switch to 4-phase while background light is high.
    pub enabled: bool,
    /// In 2-phase mode, take a 4-phase probe every N cycles to measure background light.
    pub probe_every: u32,
    /// Background indicator (LSB, common-mode level of the 4 raw images above the dark level) to switch to 4-phase.
    pub high_lsb: f32,
    /// Indicator below which 4-phase falls back to 2-phase (hysteresis).
    pub low_lsb: f32,
    /// Consecutive low readings before falling back to 2-phase.
    pub low_readings: u32,
    /// 2-vs-4-phase distance discrepancy (mm) that also counts as high background.
    pub discrepancy_mm: u32,
}

impl Default for AmbientConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            probe_every: 10,
            high_lsb: 60.0,
            low_lsb: 30.0,
            low_readings: 5,
            discrepancy_mm: 60,
        }
    }
}

/// `[exposure]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExposureConfig {
    /// Exposure per raw image at start (µs).
    pub initial_us: f64,
    /// Lower limit (µs).
    pub min_us: f64,
    /// Eye-safe upper limit per raw image (µs) — never exceeded.
    pub max_us: f64,
    /// Adjust exposure automatically.
    pub auto: bool,
    /// Share of saturated ROI pixels that shortens the exposure.
    pub saturated_fraction: f32,
    /// Share of low-amplitude ROI pixels that lengthens it.
    pub low_amplitude_fraction: f32,
    /// Multiplicative step (> 1).
    pub step: f64,
}

impl Default for ExposureConfig {
    fn default() -> Self {
        Self {
            initial_us: 100.0,
            min_us: 20.0,
            max_us: 500.0,
            auto: true,
            saturated_fraction: 0.02,
            low_amplitude_fraction: 0.5,
            step: 1.5,
        }
    }
}

/// `[readout]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReadoutConfig {
    /// Read only a row window around the ROI where the source supports it.
    pub partial: bool,
    /// Extra rows above and below the ROI.
    pub margin_rows: u16,
    /// Extra columns left and right of the ROI, where the sensor reads a column window too.
    pub margin_cols: u16,
}

impl Default for ReadoutConfig {
    fn default() -> Self {
        Self {
            partial: true,
            margin_rows: 2,
            margin_cols: 0,
        }
    }
}

/// `[probe]` — the presence probe (`policy::probe`): while far and still one raw image at
/// `exposure.min_us` decides whether anything changed; the full reading runs only if it did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProbeConfig {
    /// Probe while far and still (where the source captures single raw images).
    pub enabled: bool,
    /// Still readings (`loop.still_tolerance_mm`) before probing.
    pub after_still_readings: u32,
    /// Probes before a full reading is taken anyway (refreshes the reference and the cover
    /// window's estimate).
    pub full_every: u32,
    /// Side of the square tiles whose mean code is compared (pixels).
    pub tile_px: u16,
    /// The probe reads every `row_step`-th row of the read-out window, where the sequencer
    /// skips rows (1: every row; at most `tile_px`).
    pub row_step: u16,
}

impl Default for ProbeConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            after_still_readings: 1,
            full_every: 8,
            tile_px: 16,
            row_step: 4,
        }
    }
}

impl ProbeConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        range(
            "probe.full_every",
            self.full_every >= 1,
            format!("must be >= 1, got {}", self.full_every),
        )?;
        range(
            "probe.tile_px",
            (1..=64).contains(&self.tile_px),
            format!("must be within 1..=64, got {}", self.tile_px),
        )?;
        range(
            "probe.row_step",
            (1..=self.tile_px).contains(&self.row_step),
            format!("must be within 1..=probe.tile_px, got {}", self.row_step),
        )
    }
}

/// `[energy]` — thesis table 3.1 (2 W VCSEL): capture 0.058 mJ for 2 images at 0.1 ms →
/// 290 mW while exposing; read-out 0.689 mJ / 2 images = 0.3445 mJ per raw image (the same
/// per image for modes 5 and 9); idle 9.911 mJ over ~1 s → 9.9 mW powered but not capturing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnergyConfig {
    /// Power while exposing, mode 2 of table 3.1 (2 raw images: 2-phase), mW.
    pub capture_mw_mode2: f64,
    /// Power while exposing, mode 5 of table 3.1 (4 phase images + grey: 4-phase), mW.
    pub capture_mw_mode5: f64,
    /// Power while exposing, mode 9 of table 3.1 (2 × 4 phase images + grey: two
    /// frequencies), mW.
    pub capture_mw_mode9: f64,
    /// Energy to read out and transfer one raw image (mJ).
    pub readout_mj_per_image: f64,
    /// Power while powered but idle (mW).
    pub idle_mw: f64,
    /// Power while held in reset (mW) — assumption, the thesis gives none.
    pub off_mw: f64,
    /// Power during start-up after reset release (mW) — assumption: idle level.
    pub startup_mw: f64,
    /// Power while loading the configuration from SPI flash (mW) — assumption.
    pub flash_load_mw: f64,
    /// Power while writing the SPI flash (mW) — assumption (rare: first run only).
    pub flash_write_mw: f64,
    /// Power during the imager bring-up's waits (PLL settling, imager enable), mW — ours: the
    /// sensor powered but not measuring, table 3.1's idle level.
    pub bring_up_mw: f64,
    /// Power of one CPU core running the loop's processing (mW) — ours, of the order of a
    /// phone CPU core at a moderate clock; the loop's measured CPU time per reading is
    /// accounted at it.
    pub cpu_mw_per_core: f64,
    /// Running-average window (cycles).
    pub average_cycles: u32,
}

impl EnergyConfig {
    /// Power while exposing a measurement of `raw_images` images (thesis table 3.1: the row of
    /// the use case the measurement belongs to — up to 2 images mode 2, up to 5 mode 5, more
    /// mode 9), mW.
    pub fn capture_mw(&self, raw_images: u32) -> f64 {
        match raw_images {
            0..=2 => self.capture_mw_mode2,
            3..=5 => self.capture_mw_mode5,
            _ => self.capture_mw_mode9,
        }
    }
}

impl Default for EnergyConfig {
    fn default() -> Self {
        Self {
            capture_mw_mode2: 290.0,
            capture_mw_mode5: 384.0,
            capture_mw_mode9: 411.0,
            readout_mj_per_image: 0.3445,
            idle_mw: 9.9,
            off_mw: 0.01,
            startup_mw: 9.9,
            flash_load_mw: 15.0,
            flash_write_mw: 30.0,
            bring_up_mw: 9.9,
            cpu_mw_per_core: 250.0,
            average_cycles: 16,
        }
    }
}

/// `[dbus]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DbusConfig {
    /// Also own `net.hadess.SensorProxy` (iio-sensor-proxy compatibility).
    pub iio_sensor_proxy_compat: bool,
    /// Files whose presence means iio-sensor-proxy is installed (its binary, its unit): the
    /// compatibility mode refuses to start beside it. A unit masked in `/etc/systemd/system`
    /// (a link to `/dev/null`) does not count. Empty: no check.
    pub iio_sensor_proxy_paths: Vec<PathBuf>,
    /// Maximum DepthFrame signal rate (Hz).
    pub depth_max_hz: f64,
}

impl Default for DbusConfig {
    fn default() -> Self {
        Self {
            iio_sensor_proxy_compat: false,
            iio_sensor_proxy_paths: [
                "/usr/libexec/iio-sensor-proxy",
                "/usr/sbin/iio-sensor-proxy",
                "/usr/lib/iio-sensor-proxy/iio-sensor-proxy",
                "/usr/lib/systemd/system/iio-sensor-proxy.service",
                "/lib/systemd/system/iio-sensor-proxy.service",
            ]
            .into_iter()
            .map(PathBuf::from)
            .collect(),
            depth_max_hz: 5.0,
        }
    }
}

/// `[socket]`: the socket publisher (`publisher = "socket"`, docs/daemon.md "The socket
/// publisher").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SocketConfig {
    /// The Unix stream socket's path (its directory must exist: systemd's
    /// `RuntimeDirectory=tofprox` makes `/run/tofprox`).
    pub path: PathBuf,
    /// The socket file's permission bits (TOML octal, `0o660`: the daemon's user and group
    /// may connect; `0o666`: anyone). At most `0o777`.
    pub mode: u32,
    /// Most clients connected at once (1–256).
    pub max_clients: usize,
    /// Lines queued per client before a client that does not read is disconnected
    /// (1–65536).
    pub queue_lines: usize,
}

impl Default for SocketConfig {
    fn default() -> Self {
        Self {
            path: PathBuf::from("/run/tofprox/proximity.sock"),
            mode: 0o660,
            max_clients: 16,
            queue_lines: 256,
        }
    }
}

/// Most clients `[socket] max_clients` allows.
pub const SOCKET_MAX_CLIENTS: usize = 256;
/// Most lines `[socket] queue_lines` allows per client.
pub const SOCKET_MAX_QUEUE_LINES: usize = 65_536;

impl SocketConfig {
    /// Range-check the `[socket]` table; the error names the key.
    fn validate(&self) -> Result<(), ConfigError> {
        range(
            "socket.path",
            !self.path.as_os_str().is_empty(),
            "must not be empty",
        )?;
        range(
            "socket.mode",
            self.mode <= 0o777,
            format!("must be permission bits within 0o777, got {:#o}", self.mode),
        )?;
        range(
            "socket.max_clients",
            (1..=SOCKET_MAX_CLIENTS).contains(&self.max_clients),
            format!(
                "must be within 1..={SOCKET_MAX_CLIENTS}, got {}",
                self.max_clients
            ),
        )?;
        range(
            "socket.queue_lines",
            (1..=SOCKET_MAX_QUEUE_LINES).contains(&self.queue_lines),
            format!(
                "must be within 1..={SOCKET_MAX_QUEUE_LINES}, got {}",
                self.queue_lines
            ),
        )
    }
}

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

fn range(key: &str, ok: bool, message: impl Into<String>) -> Result<(), ConfigError> {
    if ok {
        Ok(())
    } else {
        Err(ConfigError::Range {
            key: key.to_string(),
            message: message.into(),
        })
    }
}

fn finite_pos(key: &str, v: f64) -> Result<(), ConfigError> {
    range(
        key,
        v.is_finite() && v > 0.0,
        format!("must be a positive number, got {v}"),
    )
}

fn fraction(key: &str, v: f32) -> Result<(), ConfigError> {
    range(
        key,
        v.is_finite() && (0.0..=1.0).contains(&v),
        format!("must be within 0..=1, got {v}"),
    )
}

fn non_neg(key: &str, v: f64) -> Result<(), ConfigError> {
    range(
        key,
        v.is_finite() && v >= 0.0,
        format!("must be >= 0, got {v}"),
    )
}

impl Config {
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

impl LoopConfig {
    /// Range-check the `[loop]` table; the error names the key.
    fn validate(&self) -> Result<(), ConfigError> {
        finite_pos("loop.rate_hz", self.rate_hz)?;
        finite_pos("loop.fast_rate_hz", self.fast_rate_hz)?;
        finite_pos("loop.slow_rate_hz", self.slow_rate_hz)?;
        range(
            "loop.rate_hz",
            self.rate_hz <= 100.0,
            "must be at most 100 Hz",
        )?;
        range(
            "loop.fast_rate_hz",
            self.fast_rate_hz <= 100.0,
            "must be at most 100 Hz",
        )?;
        range(
            "loop.fast_rate_hz",
            self.fast_rate_hz >= self.rate_hz,
            "must be >= loop.rate_hz",
        )?;
        range(
            "loop.slow_rate_hz",
            self.slow_rate_hz <= self.rate_hz,
            "must be <= loop.rate_hz",
        )?;
        range(
            "loop.slow_rate_hz",
            self.slow_rate_hz >= 0.01,
            "must be at least 0.01 Hz",
        )?;
        range(
            "loop.still_readings",
            self.still_readings >= 1,
            "must be at least 1",
        )?;
        non_neg("loop.approach_mm_per_s", self.approach_mm_per_s)?;
        range(
            "loop.retry_ms",
            (1..=60_000).contains(&self.retry_ms),
            "must be within 1..=60000",
        )?;
        range(
            "loop.near_hold_ms",
            self.near_hold_ms <= 60_000,
            "must be at most 60000",
        )?;
        range(
            "loop.unavailable_after",
            self.unavailable_after >= 1,
            "must be at least 1",
        )?;
        range(
            "loop.first_reading_timeout_ms",
            (1..=60_000).contains(&self.first_reading_timeout_ms),
            "must be within 1..=60000",
        )?;
        Ok(())
    }
}

impl ProcessingConfig {
    /// Range-check the `[processing]` table; the error names the key.
    fn validate(&self) -> Result<(), ConfigError> {
        range(
            "processing.min_amplitude_lsb",
            self.min_amplitude_lsb.is_finite() && self.min_amplitude_lsb >= 0.0,
            "must be >= 0",
        )?;
        range(
            "processing.require_calibration",
            !self.require_calibration || self.calibration.is_some(),
            "is true but processing.calibration is not set",
        )?;
        Ok(())
    }
}

impl ProximityConfig {
    /// Range-check the `[proximity]` table; the error names the key.
    fn validate(&self) -> Result<(), ConfigError> {
        range(
            "proximity.near_mm",
            (1..=65_000).contains(&self.near_mm),
            "must be within 1..=65000",
        )?;
        range(
            "proximity.far_mm",
            self.far_mm > self.near_mm,
            "must be greater than proximity.near_mm",
        )?;
        range(
            "proximity.far_mm",
            self.far_mm <= 65_000,
            "must be at most 65000",
        )?;
        range(
            "proximity.far_debounce",
            (1..=1000).contains(&self.far_debounce),
            "must be within 1..=1000",
        )?;
        fraction("proximity.min_valid_fraction", self.min_valid_fraction)?;
        range(
            "proximity.reflectivity_floor",
            self.reflectivity_floor.is_finite()
                && self.reflectivity_floor > 0.0
                && self.reflectivity_floor < 1.0,
            "must be within (0, 1)",
        )?;
        range(
            "proximity.depth_uncertainty_mm",
            self.depth_uncertainty_mm <= 1000,
            "must be at most 1000",
        )?;
        range(
            "proximity.nominal_amplitude_scale",
            self.nominal_amplitude_scale.is_finite() && self.nominal_amplitude_scale > 0.0,
            "must be > 0",
        )?;
        range(
            "proximity.second_modulation_hz",
            self.second_modulation_hz == 0.0
                || tofprox_core::sensor::validate_modulation_hz(self.second_modulation_hz).is_ok(),
            "must be 0 (off) or a valid modulation frequency",
        )?;
        range(
            "proximity.confirm_reflectivity",
            self.confirm_reflectivity.is_finite() && self.confirm_reflectivity >= 0.0,
            "must be ≥ 0",
        )?;
        range(
            "proximity.brightest_far_gain",
            self.brightest_far_gain.is_finite() && self.brightest_far_gain >= 0.0,
            "must be ≥ 0",
        )?;
        if let Some([_, _, rows, cols]) = self.roi {
            range(
                "proximity.roi",
                rows > 0 && cols > 0,
                "rows and cols must be > 0",
            )?;
        }
        Ok(())
    }
}

impl AmbientConfig {
    /// Range-check the `[ambient]` table; the error names the key.
    fn validate(&self) -> Result<(), ConfigError> {
        range(
            "ambient.probe_every",
            self.probe_every >= 1,
            "must be at least 1",
        )?;
        range(
            "ambient.high_lsb",
            self.high_lsb.is_finite() && self.high_lsb > 0.0,
            "must be > 0",
        )?;
        range(
            "ambient.low_lsb",
            self.low_lsb.is_finite() && self.low_lsb >= 0.0 && self.low_lsb < self.high_lsb,
            "must be >= 0 and below ambient.high_lsb",
        )?;
        range(
            "ambient.low_readings",
            self.low_readings >= 1,
            "must be at least 1",
        )?;
        Ok(())
    }
}

impl ExposureConfig {
    /// Range-check the `[exposure]` table; the error names the key.
    fn validate(&self) -> Result<(), ConfigError> {
        finite_pos("exposure.min_us", self.min_us)?;
        finite_pos("exposure.max_us", self.max_us)?;
        range(
            "exposure.max_us",
            self.max_us <= 10_000.0,
            "must be at most 10000 µs (eye safety)",
        )?;
        range(
            "exposure.max_us",
            self.max_us >= self.min_us,
            "must be >= exposure.min_us",
        )?;
        range(
            "exposure.initial_us",
            self.initial_us.is_finite()
                && self.initial_us >= self.min_us
                && self.initial_us <= self.max_us,
            "must be within exposure.min_us..=exposure.max_us",
        )?;
        fraction("exposure.saturated_fraction", self.saturated_fraction)?;
        fraction(
            "exposure.low_amplitude_fraction",
            self.low_amplitude_fraction,
        )?;
        range(
            "exposure.step",
            self.step.is_finite() && self.step > 1.0 && self.step <= 10.0,
            "must be within (1, 10]",
        )?;
        Ok(())
    }
}

impl EnergyConfig {
    /// Range-check the `[energy]` table; the error names the key.
    fn validate(&self) -> Result<(), ConfigError> {
        non_neg("energy.capture_mw_mode2", self.capture_mw_mode2)?;
        non_neg("energy.capture_mw_mode5", self.capture_mw_mode5)?;
        non_neg("energy.capture_mw_mode9", self.capture_mw_mode9)?;
        non_neg("energy.readout_mj_per_image", self.readout_mj_per_image)?;
        non_neg("energy.idle_mw", self.idle_mw)?;
        non_neg("energy.off_mw", self.off_mw)?;
        non_neg("energy.startup_mw", self.startup_mw)?;
        non_neg("energy.flash_load_mw", self.flash_load_mw)?;
        non_neg("energy.flash_write_mw", self.flash_write_mw)?;
        non_neg("energy.bring_up_mw", self.bring_up_mw)?;
        non_neg("energy.cpu_mw_per_core", self.cpu_mw_per_core)?;
        range(
            "energy.average_cycles",
            (1..=10_000).contains(&self.average_cycles),
            "must be within 1..=10000",
        )?;
        Ok(())
    }
}

impl DbusConfig {
    /// Range-check the `[dbus]` table; the error names the key.
    fn validate(&self) -> Result<(), ConfigError> {
        finite_pos("dbus.depth_max_hz", self.depth_max_hz)?;
        range(
            "dbus.depth_max_hz",
            self.depth_max_hz <= 60.0,
            "must be at most 60 Hz",
        )?;
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
