//! The V4L2 backend (`backend = "v4l2"`): a single-board computer's ToF kernel driver
//! (the IRS1125 driver of the Raspberry Pi kernel; MLX7502x where its controls exist) through
//! the bridge's [`V4l2Camera`], as a [`FrameSource`].
//!
//! One capture per cycle, the stream off between cycles (the V4L2 analogue of the CX3 path's
//! restart → load flash → capture → reset low, `tofprox_bridge::v4l2::camera`); with
//! `v4l2.release_between_cycles` the node is also closed after each cycle, so a driver that
//! powers its sensor with the open file (the IRS1125 driver's `s_power`) holds it in reset
//! between readings — at the price of the driver's whole bring-up every cycle.
//! The node is opened lazily, at the first cycle (the daemon starts before the device is
//! there, like USB), and again after it vanished.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use tofprox_bridge::v4l2::camera::{V4l2Camera, V4l2Capture, V4l2Settings};
use tofprox_bridge::v4l2::{Errno, V4l2Device};
use tofprox_bridge::{Clock, ErrorKind};
use tofprox_core::SensorGeometry;

use super::map_bridge_error;
use crate::energy::CycleTimings;
use crate::source::{CycleRequest, FrameSource, RawCycle, RawImages, SourceError};

/// Opens the device node (the real one: `open(2)`; tests: a fake's).
pub type Opener<D> = Box<dyn FnMut(&Path) -> Result<D, Errno> + Send>;

/// A V4L2 ToF camera as the loop's frame source.
pub struct V4l2Source<D: V4l2Device> {
    settings: V4l2Settings,
    open: Opener<D>,
    clock: Arc<dyn Clock>,
    camera: Option<V4l2Camera<D>>,
}

/// The real device node (Linux).
#[cfg(target_os = "linux")]
pub fn system(settings: V4l2Settings) -> V4l2Source<tofprox_bridge::v4l2::sys::V4l2Fd> {
    let clock: Arc<dyn Clock> = Arc::new(tofprox_bridge::SystemClock::new());
    let open: Opener<_> = Box::new(|p: &Path| tofprox_bridge::v4l2::sys::V4l2Fd::open(p));
    V4l2Source::new(settings, open, clock)
}

impl<D: V4l2Device> V4l2Source<D> {
    /// A source over the devices `open` gives, timed on `clock`.
    pub fn new(settings: V4l2Settings, open: Opener<D>, clock: Arc<dyn Clock>) -> Self {
        Self {
            settings,
            open,
            clock,
            camera: None,
        }
    }

    /// The camera, opened and configured if it is not (the time it took: start-up).
    fn camera(&mut self) -> Result<(&mut V4l2Camera<D>, Duration), SourceError> {
        let t0 = self.clock.now();
        if self.camera.is_none() {
            let path = self.settings.device.clone();
            let dev = (self.open)(&path)
                .map_err(|e| map_bridge_error(e.on(&path.display().to_string(), "open")))?;
            let cam = V4l2Camera::open(dev, self.settings.clone(), self.clock.clone())
                .map_err(map_bridge_error)?;
            self.camera = Some(cam);
        }
        let opened = self.clock.now() - t0;
        let cam = self.camera.as_mut().ok_or_else(|| {
            SourceError::new(crate::source::SourceErrorKind::Disconnected, "no device")
        })?;
        Ok((cam, opened))
    }

    /// Close the node (buffers freed); a vanished device is simply dropped.
    fn release(&mut self) -> Result<(), SourceError> {
        match self.camera.take() {
            Some(cam) => cam.close().or_else(|e| match e.kind() {
                ErrorKind::Disconnected => Ok(()),
                _ => Err(map_bridge_error(e)),
            }),
            None => Ok(()),
        }
    }
}

/// The energy model's states of one V4L2 capture: opening the node and STREAMON are the
/// sensor's start-up, the controls its configuration, `K × exposure` the exposure (modelled:
/// the driver reports no exposure time), the rest until the buffer plus STREAMOFF read-out.
fn cycle_timings(c: &V4l2Capture, opened: Duration) -> CycleTimings {
    let k = c.frames.dim().0 as f64;
    let exposure = Duration::from_secs_f64(k * c.exposure_us / 1e6).min(c.timings.to_frame);
    CycleTimings {
        startup: opened + c.timings.stream_on,
        bring_up: Duration::ZERO,
        config_load: c.timings.controls,
        flash_write: Duration::ZERO,
        exposure,
        readout: c.timings.to_frame - exposure + c.timings.stream_off,
    }
}

impl<D: V4l2Device> FrameSource for V4l2Source<D> {
    fn cycle(&mut self, req: &CycleRequest) -> Result<RawCycle, SourceError> {
        let (cam, opened) = self.camera()?;
        let captured = cam.capture(req.exposure_us, req.modulation_hz);
        let cap = match captured {
            Ok(c) => c,
            Err(e) => {
                if e.kind() == ErrorKind::Disconnected {
                    self.camera = None; // reopened at the next cycle
                }
                return Err(map_bridge_error(e));
            }
        };
        if self.settings.release_between_cycles {
            self.release()?;
        }
        let s = &self.settings;
        let geometry = SensorGeometry::full(
            s.rows as usize,
            s.width as usize,
            s.adc_bits,
            cap.modulation_hz,
        );
        Ok(RawCycle {
            timings: Some(cycle_timings(&cap, opened)),
            frames: RawImages::U16(cap.frames),
            phases_deg: cap.phases_deg,
            exposure_us: cap.exposure_us,
            geometry,
        })
    }

    /// Close the node: the driver may power the sensor down (the stream is already off).
    fn power_off(&mut self) -> Result<(), SourceError> {
        self.release()
    }

    fn supports_row_window(&self) -> bool {
        false
    }

    /// The driver's sequence fixes the images (the phases of `v4l2.phases_deg`).
    fn supports_mode_switch(&self) -> bool {
        false
    }

    fn sensor(&self) -> SensorGeometry {
        let s = &self.settings;
        SensorGeometry::full(
            s.rows as usize,
            s.width as usize,
            s.adc_bits,
            s.modulation_hz,
        )
    }

    fn now(&self) -> Option<Duration> {
        Some(self.clock.now())
    }

    fn describe(&self) -> String {
        let s = &self.settings;
        format!(
            "V4L2 {} ({:?}, {} stacked images of {}x{})",
            s.device.display(),
            s.pixel_format,
            s.images,
            s.width,
            s.rows
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tofprox_bridge::v4l2::camera::V4l2Timings;

    #[test]
    fn capture_steps_become_the_energy_models_states() {
        let ms = Duration::from_millis;
        let c = V4l2Capture {
            frames: ndarray::Array3::zeros((4, 2, 2)),
            phases_deg: vec![0.0, 90.0, 180.0, 270.0],
            exposure_us: 500.0,
            modulation_hz: 80e6,
            timings: V4l2Timings {
                controls: ms(1),
                stream_on: ms(3),
                to_frame: ms(30),
                stream_off: ms(2),
            },
        };
        let t = cycle_timings(&c, ms(5));
        // start-up: open + STREAMON; configuration: controls; exposure: 4 × 0.5 ms (modelled);
        // read-out: the rest of the wait for the buffer (30 − 2 ms) + STREAMOFF
        assert_eq!(t.startup, ms(8));
        assert_eq!(t.config_load, ms(1));
        assert_eq!(t.exposure, ms(2));
        assert_eq!(t.readout, ms(30));
        assert_eq!(t.active(), ms(41));
        // an exposure longer than the wait (a driver answering early) is capped by it
        let long = V4l2Capture {
            exposure_us: 20_000.0,
            ..c
        };
        assert_eq!(cycle_timings(&long, ms(0)).exposure, ms(30));
    }
}
