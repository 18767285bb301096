//! Concrete frame sources: the bridge's [`SensorDriver`] over USB (or over the emulated
//! device: [`emulated`], feature `emulated`), and replay of a version 1 recording.

#[cfg(feature = "emulated")]
pub mod emulated;
pub mod v4l2;

use std::path::Path;
use std::sync::Arc;
use tofprox_bridge::{
    BridgeError, Clock, DriverConfig, DriverConfigFile, ErrorKind, SensorDriver, SensorMode,
    SystemClock, UsbTransport,
};
use tofprox_core::SensorGeometry;
use tofprox_format::{RawFrames, Recording};

use crate::config::{Backend, Config};
use crate::energy::CycleTimings;
use crate::source::{CycleRequest, FrameSource, RawCycle, RawImages, SourceError, SourceErrorKind};

impl FrameSource for Box<dyn FrameSource> {
    fn cycle(&mut self, req: &CycleRequest) -> Result<RawCycle, SourceError> {
        (**self).cycle(req)
    }
    fn power_off(&mut self) -> Result<(), SourceError> {
        (**self).power_off()
    }
    fn supports_row_window(&self) -> bool {
        (**self).supports_row_window()
    }
    fn row_window_align(&self) -> u16 {
        (**self).row_window_align()
    }
    fn column_window_align(&self) -> Option<u16> {
        (**self).column_window_align()
    }
    fn supports_single_image(&self) -> bool {
        (**self).supports_single_image()
    }
    fn max_row_step(&self) -> u16 {
        (**self).max_row_step()
    }
    fn supports_mode_switch(&self) -> bool {
        (**self).supports_mode_switch()
    }
    fn sensor(&self) -> SensorGeometry {
        (**self).sensor()
    }
    fn now(&self) -> Option<std::time::Duration> {
        (**self).now()
    }
    fn describe(&self) -> String {
        (**self).describe()
    }
}

/// An error with its source chain, one line.
pub fn chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        let m = c.to_string();
        if !s.contains(&m) {
            s.push_str(": ");
            s.push_str(&m);
        }
        cur = c.source();
    }
    s
}

/// Map a bridge error to the loop's kinds; the bridge error stays the `source()`.
pub fn map_bridge_error(e: BridgeError) -> SourceError {
    let kind = match e.kind() {
        ErrorKind::Disconnected | ErrorKind::NotFound | ErrorKind::Access => {
            SourceErrorKind::Disconnected
        }
        ErrorKind::Timeout => SourceErrorKind::Timeout,
        ErrorKind::Stall | ErrorKind::Nak | ErrorKind::Protocol => SourceErrorKind::Protocol,
        ErrorKind::CorruptFrame => SourceErrorKind::CorruptFrame,
        ErrorKind::FlashEmpty | ErrorKind::FlashCorrupt => SourceErrorKind::Flash,
        ErrorKind::ResetStuck => SourceErrorKind::Reset,
        ErrorKind::Config => SourceErrorKind::Unsupported,
        _ => SourceErrorKind::Other,
    };
    SourceError::new(kind, format!("{} ({})", chain(&e), e.kind().as_str())).with_source(e)
}

/// The sensor through the bridge's driver stack.
pub struct BridgeSource<T: UsbTransport> {
    driver: SensorDriver<T>,
    clock: Arc<dyn Clock>,
    name: String,
}

impl<T: UsbTransport> BridgeSource<T> {
    /// Wrap a driver.
    pub fn new(driver: SensorDriver<T>, clock: Arc<dyn Clock>, name: impl Into<String>) -> Self {
        Self {
            driver,
            clock,
            name: name.into(),
        }
    }
    /// The driver.
    pub fn driver(&self) -> &SensorDriver<T> {
        &self.driver
    }
}

impl<T: UsbTransport> FrameSource for BridgeSource<T> {
    fn cycle(&mut self, req: &CycleRequest) -> Result<RawCycle, SourceError> {
        let breq = req.map_mode(SensorMode::from);
        let out = self.driver.cycle(&breq).map_err(map_bridge_error)?;
        Ok(RawCycle {
            geometry: out.geometry,
            timings: Some(CycleTimings::from(&out.timings)),
            frames: RawImages::U16(out.frames),
            phases_deg: out.phases_deg,
            exposure_us: out.exposure_us,
        })
    }

    fn power_off(&mut self) -> Result<(), SourceError> {
        self.driver.power_off().map_err(map_bridge_error)
    }

    fn supports_row_window(&self) -> bool {
        self.driver.config().map.row_window.is_some()
    }

    fn row_window_align(&self) -> u16 {
        self.driver
            .config()
            .map
            .row_window
            .as_ref()
            .map_or(1, |w| w.align.max(1))
    }

    fn column_window_align(&self) -> Option<u16> {
        column_align(&self.driver.config().map)
    }

    fn supports_single_image(&self) -> bool {
        true
    }

    fn max_row_step(&self) -> u16 {
        row_step_max(&self.driver.config().map)
    }

    fn sensor(&self) -> SensorGeometry {
        self.driver.config().map.sensor.geometry()
    }

    fn now(&self) -> Option<std::time::Duration> {
        Some(self.clock.now())
    }

    fn describe(&self) -> String {
        self.name.clone()
    }
}

/// Replay of a recording's 2-/4-phase illuminated captures, in order. A request at a second
/// modulation frequency is served the second-frequency images of the capture just replayed
/// (format version 3, `[capture.second_frequency]`), when it has them at that frequency.
pub struct ReplaySource {
    rec: Recording,
    indices: Vec<usize>,
    pos: usize,
    /// The capture served last (its second-frequency images answer the next such request).
    served: Option<usize>,
    repeat: bool,
    name: String,
}

impl ReplaySource {
    /// Open a recording.
    pub fn open(dir: &Path, repeat: bool) -> Result<Self, SourceError> {
        let rec = Recording::open(dir)
            .map_err(|e| SourceError::new(SourceErrorKind::Other, format!("replay: {e}")))?;
        let indices: Vec<usize> = rec
            .captures()
            .iter()
            .enumerate()
            .filter(|(_, c)| {
                c.illumination
                    && (c.is_four_phase() || (c.phases_deg.len() == 2 && c.starts_two_phase()))
            })
            .map(|(i, _)| i)
            .collect();
        if indices.is_empty() {
            return Err(SourceError::new(
                SourceErrorKind::Unsupported,
                format!(
                    "replay: {} has no illuminated 2-phase or 4-phase capture",
                    dir.display()
                ),
            ));
        }
        Ok(Self {
            name: format!("replay {} ({} captures)", dir.display(), indices.len()),
            rec,
            indices,
            pos: 0,
            served: None,
            repeat,
        })
    }

    /// Number of replayable captures.
    pub fn len(&self) -> usize {
        self.indices.len()
    }

    /// Whether there is nothing to replay.
    pub fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }
}

/// A recording's frames as the loop takes them: codes stay codes, averaged codes stay floats
/// (f64 narrowed to f32, the pipeline's working precision — as `tofprox process` does).
fn raw_images(frames: RawFrames) -> RawImages {
    match frames {
        RawFrames::U16(a) => RawImages::U16(a),
        RawFrames::F32(a) => RawImages::F32(a),
        RawFrames::F64(a) => RawImages::F32(a.mapv(|v| v as f32)),
    }
}

impl ReplaySource {
    /// The second-frequency images at `f_hz` of the capture served last.
    fn second_frequency(&self, f_hz: f64) -> Result<RawCycle, SourceError> {
        let unsupported = |m: String| SourceError::new(SourceErrorKind::Unsupported, m);
        let idx = self
            .served
            .ok_or_else(|| unsupported("no capture replayed yet".into()))?;
        let meta = self.rec.captures().get(idx).cloned().ok_or_else(|| {
            SourceError::new(SourceErrorKind::Other, "capture index out of range")
        })?;
        let Some(s) = meta
            .second_frequency
            .filter(|s| (s.modulation_hz - f_hz).abs() < 1.0)
        else {
            return Err(unsupported(format!(
                "capture {idx} has no second-frequency images at {f_hz} Hz"
            )));
        };
        let frames = self
            .rec
            .load_second_frequency(idx)
            .map_err(|e| {
                SourceError::new(
                    SourceErrorKind::CorruptFrame,
                    format!("replay capture {idx}: {e}"),
                )
            })?
            .ok_or_else(|| unsupported(format!("capture {idx}: no second-frequency images")))?;
        Ok(RawCycle {
            frames: raw_images(frames),
            phases_deg: s.phases_deg,
            exposure_us: meta.exposure_us,
            geometry: SensorGeometry {
                modulation_hz: s.modulation_hz,
                ..*self.rec.sensor()
            },
            timings: None,
        })
    }
}

impl FrameSource for ReplaySource {
    fn cycle(&mut self, req: &CycleRequest) -> Result<RawCycle, SourceError> {
        if let Some(f_hz) = req
            .modulation_hz
            .filter(|f| (f - self.rec.sensor().modulation_hz).abs() >= 1.0)
        {
            return self.second_frequency(f_hz);
        }
        if self.pos >= self.indices.len() {
            if self.repeat {
                self.pos = 0;
            } else {
                return Err(SourceError::new(
                    SourceErrorKind::EndOfData,
                    "end of recording",
                ));
            }
        }
        let idx = self.indices.get(self.pos).copied().unwrap_or(0);
        self.pos += 1;
        self.served = Some(idx);
        let sensor = *self.rec.sensor();
        let meta = self.rec.captures().get(idx).cloned().ok_or_else(|| {
            SourceError::new(SourceErrorKind::Other, "capture index out of range")
        })?;
        let frames = self.rec.load(idx).map_err(|e| {
            SourceError::new(
                SourceErrorKind::CorruptFrame,
                format!("replay capture {idx}: {e}"),
            )
        })?;
        Ok(RawCycle {
            frames: raw_images(frames),
            phases_deg: meta.phases_deg,
            exposure_us: meta.exposure_us,
            geometry: sensor,
            // A recording holds no state timings: none are invented.
            timings: None,
        })
    }

    fn power_off(&mut self) -> Result<(), SourceError> {
        Ok(())
    }

    fn supports_row_window(&self) -> bool {
        false
    }

    fn supports_mode_switch(&self) -> bool {
        false
    }

    fn sensor(&self) -> SensorGeometry {
        self.rec.sensor().full_array()
    }

    fn describe(&self) -> String {
        self.name.clone()
    }
}

/// Build the configured frame source. `base` resolves relative paths (the config's directory).
pub fn build_source(cfg: &Config, base: &Path) -> Result<Box<dyn FrameSource>, SourceError> {
    match cfg.backend {
        Backend::Replay => {
            let dir = cfg.replay.recording.as_ref().ok_or_else(|| {
                SourceError::new(SourceErrorKind::Unsupported, "replay.recording is not set")
            })?;
            Ok(Box::new(ReplaySource::open(dir, cfg.replay.repeat)?))
        }
        Backend::Emulated => emulated_backend(cfg, base),
        Backend::V4l2 => v4l2_backend(cfg),
        Backend::Usb => {
            let dcfg = match &cfg.usb.driver_config {
                Some(p) => DriverConfigFile::load(p).map_err(|e| {
                    SourceError::new(
                        SourceErrorKind::Unsupported,
                        format!("usb.driver_config: {}", chain(&e)),
                    )
                })?,
                None => DriverConfig::emulated_default(),
            };
            dcfg.validate()
                .map_err(|e| berr_unsupported("usb.driver_config", e))?;
            Ok(Box::new(UsbSource {
                sel: cfg.usb.device.clone(),
                dcfg,
                clock: Arc::new(SystemClock::new()),
                inner: None,
            }))
        }
    }
}

/// The emulated backend ([`emulated`]).
#[cfg(feature = "emulated")]
fn emulated_backend(cfg: &Config, base: &Path) -> Result<Box<dyn FrameSource>, SourceError> {
    Ok(Box::new(emulated::source(cfg, base)?))
}

/// A production build (without the feature `emulated`) has no emulated device: refused,
/// naming the feature.
#[cfg(not(feature = "emulated"))]
fn emulated_backend(_cfg: &Config, _base: &Path) -> Result<Box<dyn FrameSource>, SourceError> {
    Err(SourceError::new(
        SourceErrorKind::Unsupported,
        "backend = \"emulated\": this tofproxd is a production build without the emulated \
         device (build it with the default feature `emulated`)",
    ))
}

/// The V4L2 backend on the real device node (opened at the first cycle).
#[cfg(target_os = "linux")]
fn v4l2_backend(cfg: &Config) -> Result<Box<dyn FrameSource>, SourceError> {
    cfg.v4l2
        .validate()
        .map_err(|e| berr_unsupported("v4l2", e))?;
    Ok(Box::new(v4l2::system(cfg.v4l2.clone())))
}

/// V4L2 is Linux's.
#[cfg(not(target_os = "linux"))]
fn v4l2_backend(_cfg: &Config) -> Result<Box<dyn FrameSource>, SourceError> {
    Err(SourceError::new(
        SourceErrorKind::Unsupported,
        "backend = \"v4l2\" needs Linux",
    ))
}

/// A bridge error met while building a source: unsupported, naming what was built.
fn berr_unsupported(what: &str, e: BridgeError) -> SourceError {
    SourceError::new(SourceErrorKind::Unsupported, format!("{what}: {e}")).with_source(e)
}

/// USB backend that opens the device lazily (the daemon starts without the
/// device plugged in and reports `unavailable` until it appears).
pub struct UsbSource {
    sel: tofprox_bridge::UsbSelector,
    dcfg: DriverConfig,
    /// One clock for the daemon's life, also while the device is absent.
    clock: Arc<dyn Clock>,
    inner: Option<BridgeSource<tofprox_bridge::RusbTransport>>,
}

impl UsbSource {
    fn inner(&mut self) -> Result<&mut BridgeSource<tofprox_bridge::RusbTransport>, SourceError> {
        if self.inner.is_none() {
            let transport =
                tofprox_bridge::RusbTransport::open(self.sel.clone()).map_err(map_bridge_error)?;
            let clock = self.clock.clone();
            let driver =
                SensorDriver::new(transport, self.dcfg.clone(), clock.clone()).map_err(|e| {
                    SourceError::new(SourceErrorKind::Unsupported, format!("driver: {e}"))
                })?;
            self.inner = Some(BridgeSource::new(driver, clock, "CX3 over USB"));
        }
        self.inner
            .as_mut()
            .ok_or_else(|| SourceError::new(SourceErrorKind::Disconnected, "no device"))
    }
}

impl FrameSource for UsbSource {
    fn cycle(&mut self, req: &CycleRequest) -> Result<RawCycle, SourceError> {
        self.inner()?.cycle(req)
    }
    fn power_off(&mut self) -> Result<(), SourceError> {
        match &mut self.inner {
            Some(s) => s.power_off(),
            None => Ok(()),
        }
    }
    fn supports_row_window(&self) -> bool {
        self.dcfg.map.row_window.is_some()
    }
    fn row_window_align(&self) -> u16 {
        self.dcfg
            .map
            .row_window
            .as_ref()
            .map_or(1, |w| w.align.max(1))
    }
    fn column_window_align(&self) -> Option<u16> {
        column_align(&self.dcfg.map)
    }
    fn supports_single_image(&self) -> bool {
        true
    }
    fn max_row_step(&self) -> u16 {
        row_step_max(&self.dcfg.map)
    }
    fn sensor(&self) -> SensorGeometry {
        self.dcfg.map.sensor.geometry()
    }
    fn now(&self) -> Option<std::time::Duration> {
        Some(self.clock.now())
    }
    fn describe(&self) -> String {
        format!(
            "CX3 over USB {:04x}:{:04x}",
            self.sel.vendor_id, self.sel.product_id
        )
    }
}

/// The largest row step of a map's sequencer (1: every row).
fn row_step_max(map: &tofprox_bridge::SensorMap) -> u16 {
    map.row_window.as_ref().map_or(1, |w| w.row_step_max())
}

/// The column alignment of a map whose sequencer reads column windows (`None`: whole rows).
fn column_align(map: &tofprox_bridge::SensorMap) -> Option<u16> {
    let w = map.row_window.as_ref()?;
    w.column_registers().map(|_| w.col_align.max(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn usb_config(driver_config: &Path) -> Config {
        let mut cfg = Config {
            backend: Backend::Usb,
            ..Config::default()
        };
        cfg.usb.driver_config = Some(driver_config.to_path_buf());
        cfg
    }

    fn build_err(cfg: &Config) -> SourceError {
        match build_source(cfg, Path::new(".")) {
            Ok(s) => panic!("expected an error, built {}", s.describe()),
            Err(e) => e,
        }
    }

    #[test]
    fn usb_driver_config_errors_name_the_key_and_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let missing = dir.path().join("missing.toml");
        let e = build_err(&usb_config(&missing));
        assert_eq!(e.kind(), SourceErrorKind::Unsupported);
        let msg = e.to_string();
        assert!(msg.contains("usb.driver_config"), "{msg}");
        assert!(msg.contains("missing.toml"), "{msg}");

        let bad = dir.path().join("bad.toml");
        std::fs::write(&bad, "no_such_key = 1\n").expect("write");
        let msg = build_err(&usb_config(&bad)).to_string();
        assert!(msg.contains("usb.driver_config"), "{msg}");
        assert!(msg.contains("no_such_key"), "{msg}");

        let zero_poll = dir.path().join("zero_poll.toml");
        std::fs::write(&zero_poll, "[timing]\npoll_interval_us = 0\n").expect("write");
        let msg = build_err(&usb_config(&zero_poll)).to_string();
        assert!(msg.contains("usb.driver_config"), "{msg}");
        assert!(msg.contains("poll_interval_us"), "{msg}");
    }

    #[cfg(not(feature = "emulated"))]
    #[test]
    fn production_build_refuses_the_emulated_backend_naming_the_feature() {
        let cfg = Config {
            backend: Backend::Emulated,
            ..Config::default()
        };
        let e = build_err(&cfg);
        assert_eq!(e.kind(), SourceErrorKind::Unsupported);
        let msg = e.to_string();
        assert!(msg.contains("backend = \"emulated\""), "{msg}");
        assert!(msg.contains("feature `emulated`"), "{msg}");
    }

    #[test]
    fn bridge_errors_keep_their_kind_and_stay_the_source() {
        use std::error::Error as _;
        let e = map_bridge_error(BridgeError::new(ErrorKind::Timeout, "bulk read of frame 3"));
        assert_eq!(e.kind(), SourceErrorKind::Timeout);
        let src = e.source().expect("the bridge error is the source");
        assert!(src.to_string().contains("bulk read of frame 3"), "{src}");
        assert!(e.to_string().contains("bulk read of frame 3"), "{e}");
    }

    #[test]
    fn usb_driver_config_file_is_loaded_without_opening_the_device() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("driver.toml");
        std::fs::write(&p, "[timing]\npoll_interval_us = 250\n").expect("write");
        let src = match build_source(&usb_config(&p), Path::new(".")) {
            Ok(s) => s,
            Err(e) => panic!("usb source: {e}"),
        };
        let map = tofprox_bridge::SensorMap::emulated();
        assert_eq!(
            src.full_size(),
            (usize::from(map.sensor.rows), usize::from(map.sensor.cols))
        );
        assert!(src.describe().contains("USB"), "{}", src.describe());
    }
}
