//! One capture per cycle from a V4L2 ToF driver: exposure (and modulation frequency) through
//! the driver's controls, queue the buffers, STREAMON, one stacked buffer, STREAMOFF.
//!
//! Stream-off between cycles is the power strategy: the V4L2 analogue of the CX3 path's
//! restart → load flash → capture → reset low (thesis 3.5.3, listing 4.11). Stopping the
//! stream lets the driver stop the sensor's sequencer (the IRS1125 driver clears its trigger
//! and stops the firmware); what the sensor draws between cycles is then up to the driver and
//! the board — the CX3 path holds the sensor in reset and reloads its configuration each
//! cycle, which a V4L2 client cannot ask for (runtime PM of the sensor is the driver's).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use ndarray::Array3;
use serde::{Deserialize, Serialize};

use super::{
    BUF_FLAG_ERROR, CAP_STREAMING, CAP_VIDEO_CAPTURE, ControlInfo, PixFormat, PixelFormat,
    V4l2Device, find_control, fourcc_str,
};
use crate::clock::Clock;
use crate::error::{BridgeError, ErrorKind};
use crate::pixels::{BufferLayout, decode_buffer};

/// The `[v4l2]` settings: the device node, the format the driver delivers and the names of
/// its controls. Unknown keys are refused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct V4l2Settings {
    /// Device node (`/dev/video0`).
    pub device: PathBuf,
    /// Pixel format asked with S_FMT: `Y12`, `Y12P` or `Y16`.
    pub pixel_format: PixelFormat,
    /// Pixels per line.
    pub width: u32,
    /// Lines of one raw image (the buffer holds `images` of them stacked).
    pub rows: u32,
    /// Raw images stacked in one buffer (the driver's sequence length).
    pub images: u32,
    /// Index of the first phase image in the stack (1 when the sequence starts with an
    /// image the pipeline does not take, e.g. a grey one).
    pub first_phase_image: u32,
    /// Phases (degrees) of the images from `first_phase_image` on, as the sequence orders
    /// them: 2 or 4 quadrature phases.
    pub phases_deg: Vec<f64>,
    /// ADC resolution of the codes.
    pub adc_bits: u8,
    /// Modulation frequency of the sequence (Hz).
    pub modulation_hz: f64,
    /// Exposure per raw image (µs) when no `exposure_controls` are named (the sequence's own).
    pub fixed_exposure_us: f64,
    /// Names of the integer controls setting the exposure, all set to the same value (one per
    /// sequence entry where the driver has one each); empty: none.
    pub exposure_controls: Vec<String>,
    /// Microseconds per unit of that control (`"Exposure Time, Absolute"`: 100).
    pub exposure_us_per_unit: f64,
    /// Name of the integer control setting the modulation frequency, empty: none (a second
    /// frequency is then unsupported).
    pub modulation_control: String,
    /// Hz per unit of that control (1e6 for a control in MHz).
    pub modulation_hz_per_unit: f64,
    /// Buffers requested (REQBUFS).
    pub buffers: u32,
    /// Longest wait for a buffer after STREAMON (ms).
    pub frame_timeout_ms: u64,
    /// Close the node after every cycle (not only when no client claims): a driver that
    /// powers its sensor with the open file then holds it in reset between readings, and
    /// runs its whole bring-up each cycle. For the daemon's source; the camera ignores it.
    pub release_between_cycles: bool,
}

impl Default for V4l2Settings {
    fn default() -> Self {
        Self {
            device: PathBuf::from("/dev/video0"),
            pixel_format: PixelFormat::Y12,
            width: 352,
            rows: 288,
            images: 4,
            first_phase_image: 0,
            phases_deg: vec![0.0, 90.0, 180.0, 270.0],
            adc_bits: 12,
            modulation_hz: 80e6,
            fixed_exposure_us: 1000.0,
            exposure_controls: Vec::new(),
            exposure_us_per_unit: 1.0,
            modulation_control: String::new(),
            modulation_hz_per_unit: 1e6,
            buffers: 2,
            frame_timeout_ms: 2000,
            release_between_cycles: false,
        }
    }
}

impl V4l2Settings {
    /// Check the values; the error names the key (`v4l2.images`).
    pub fn validate(&self) -> Result<(), BridgeError> {
        let bad = |key: &str, m: String| Err(BridgeError::config(format!("v4l2.{key}: {m}")));
        if self.width == 0 || self.rows == 0 || self.images == 0 {
            return bad("width/rows/images", "must be at least 1".into());
        }
        self.validate_bounds()?;
        let n = self.phases_deg.len();
        if !(n == 2 || n == 4) || self.first_phase_image as usize + n > self.images as usize {
            return bad(
                "phases_deg",
                format!(
                    "{n} phases from image {} of {}: 2 or 4 phases within the stack",
                    self.first_phase_image, self.images
                ),
            );
        }
        tofprox_core::sensor::validate_adc_bits(self.adc_bits)
            .map_err(|e| BridgeError::config(format!("v4l2.adc_bits: {e}")))?;
        tofprox_core::sensor::validate_modulation_hz(self.modulation_hz)
            .map_err(|e| BridgeError::config(format!("v4l2.modulation_hz: {e}")))?;
        for (key, v) in [
            ("fixed_exposure_us", self.fixed_exposure_us),
            ("exposure_us_per_unit", self.exposure_us_per_unit),
            ("modulation_hz_per_unit", self.modulation_hz_per_unit),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(key, format!("must be a positive number, got {v}"));
            }
        }
        if !(1..=32).contains(&self.buffers) {
            return bad("buffers", "must be within 1..=32".into());
        }
        if self.frame_timeout_ms == 0 {
            return bad("frame_timeout_ms", "must be at least 1".into());
        }
        Ok(())
    }

    /// Every key's upper bound (issue 35 W4): the sides and stack of the buffer layout's
    /// limits ([`crate::pixels::BufferLayout::validate`]: 4096 pixels a side, 2^20 a image, 64
    /// images, 256 MiB a buffer), exposure within the daemon's eye-safe 10 ms, the control
    /// names as V4L2 holds them (31 bytes, at most 16 exposure controls), a path of at most
    /// 4096 bytes, phases finite, a frame timeout of at most 60 s.
    fn validate_bounds(&self) -> Result<(), BridgeError> {
        let bad = |key: &str, m: String| Err(BridgeError::config(format!("v4l2.{key}: {m}")));
        if let Err(e) = self.layout(None).validate() {
            return bad("width/rows/images", e.to_string());
        }
        if self.first_phase_image >= self.images {
            return bad("first_phase_image", "must be within the stack".into());
        }
        if self.device.as_os_str().len() > 4096 {
            return bad("device", "a path of at most 4096 bytes".into());
        }
        if let Some(p) = self.phases_deg.iter().find(|p| !p.is_finite()) {
            return bad("phases_deg", format!("{p} is not a finite angle"));
        }
        if self.fixed_exposure_us > 10_000.0 {
            return bad(
                "fixed_exposure_us",
                "must be at most 10000 µs (eye safety)".into(),
            );
        }
        for (key, v, max) in [
            ("exposure_us_per_unit", self.exposure_us_per_unit, 1e6),
            ("modulation_hz_per_unit", self.modulation_hz_per_unit, 1e9),
        ] {
            if v > max {
                return bad(key, format!("must be at most {max:e}, got {v}"));
            }
        }
        if self.exposure_controls.len() > 16 {
            return bad("exposure_controls", "at most 16 controls".into());
        }
        let names = self
            .exposure_controls
            .iter()
            .map(|n| ("exposure_controls", n));
        for (key, name) in names.chain([("modulation_control", &self.modulation_control)]) {
            // struct v4l2_queryctrl's name: 32 bytes with the terminating NUL
            if name.len() > 31 || name.contains('\0') {
                return bad(
                    key,
                    format!("{name:?}: a V4L2 control name of at most 31 bytes"),
                );
            }
        }
        if self.frame_timeout_ms > 60_000 {
            return bad("frame_timeout_ms", "must be at most 60000".into());
        }
        Ok(())
    }

    /// The buffer layout before the driver's stride is known.
    fn layout(&self, stride_bytes: Option<usize>) -> BufferLayout {
        BufferLayout {
            packing: self.pixel_format.packing(),
            cols: self.width as usize,
            rows: self.rows as usize,
            images: self.images as usize,
            stride_bytes,
            adc_bits: self.adc_bits,
        }
    }
}

/// Where one capture's time went (the source's clock).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct V4l2Timings {
    /// Setting the controls (the driver's register writes).
    pub controls: Duration,
    /// VIDIOC_STREAMON (the driver starts the sensor).
    pub stream_on: Duration,
    /// STREAMON's return until the buffer was dequeued (exposure and read-out of the sequence).
    pub to_frame: Duration,
    /// VIDIOC_STREAMOFF.
    pub stream_off: Duration,
}

/// One capture: the phase images of the stack as `(phases, rows, cols)` codes.
#[derive(Debug, Clone)]
pub struct V4l2Capture {
    /// Raw images.
    pub frames: Array3<u16>,
    /// Phase of each (degrees).
    pub phases_deg: Vec<f64>,
    /// Exposure per raw image the driver applied (µs).
    pub exposure_us: f64,
    /// Modulation frequency the images were taken at (Hz).
    pub modulation_hz: f64,
    /// Time spent per step.
    pub timings: V4l2Timings,
}

/// A V4L2 ToF camera opened and configured: format set, controls found, buffers requested.
pub struct V4l2Camera<D: V4l2Device> {
    dev: D,
    settings: V4l2Settings,
    name: String,
    layout: BufferLayout,
    exposure: Vec<ControlInfo>,
    modulation: Option<ControlInfo>,
    buffers: u32,
    clock: Arc<dyn Clock>,
}

/// A control named in the settings, looked up on the device (empty name: none).
fn named_control(
    dev: &mut dyn V4l2Device,
    name: &str,
    key: &str,
    device: &str,
) -> Result<Option<ControlInfo>, BridgeError> {
    if name.is_empty() {
        return Ok(None);
    }
    match find_control(dev, name).map_err(|e| e.on(device, "VIDIOC_QUERYCTRL"))? {
        Some(c) if c.flags & super::CTRL_FLAG_DISABLED == 0 => Ok(Some(c)),
        _ => Err(BridgeError::config(format!(
            "{device}: v4l2.{key} = {name:?}: the driver has no such enabled control"
        ))),
    }
}

impl<D: V4l2Device> V4l2Camera<D> {
    /// Check the device can capture and stream, set the format, find the controls, request
    /// the buffers. Errors name the device path.
    pub fn open(
        mut dev: D,
        settings: V4l2Settings,
        clock: Arc<dyn Clock>,
    ) -> Result<Self, BridgeError> {
        settings.validate()?;
        let name = settings.device.display().to_string();
        let cap = dev.querycap().map_err(|e| e.on(&name, "VIDIOC_QUERYCAP"))?;
        let need = CAP_VIDEO_CAPTURE | CAP_STREAMING;
        if cap.device_caps & need != need {
            return Err(BridgeError::config(format!(
                "{name}: driver {:?} ({}) is not a streaming video capture device",
                cap.driver, cap.card
            )));
        }
        let layout = set_format(&mut dev, &settings, &name)?;
        let exposure = (settings.exposure_controls.iter())
            .map(|c| named_control(&mut dev, c, "exposure_controls", &name))
            .filter_map(Result::transpose)
            .collect::<Result<Vec<_>, _>>()?;
        let modulation = named_control(
            &mut dev,
            &settings.modulation_control,
            "modulation_control",
            &name,
        )?;
        let buffers = dev
            .reqbufs(settings.buffers)
            .map_err(|e| e.on(&name, "VIDIOC_REQBUFS"))?;
        if buffers == 0 {
            return Err(BridgeError::new(
                ErrorKind::Io,
                format!("{name}: no buffers granted"),
            ));
        }
        Ok(Self {
            dev,
            settings,
            name,
            layout,
            exposure,
            modulation,
            buffers,
            clock,
        })
    }

    /// The settings.
    pub fn settings(&self) -> &V4l2Settings {
        &self.settings
    }

    /// Whether a second modulation frequency can be asked (a modulation control exists).
    pub fn has_modulation_control(&self) -> bool {
        self.modulation.is_some()
    }

    /// Set a control to `value` in units of `per_unit`, rounded and clamped to its range.
    /// Returns the value applied, in the same physical unit.
    fn set_scaled(
        &mut self,
        c: &ControlInfo,
        value: f64,
        per_unit: f64,
    ) -> Result<f64, BridgeError> {
        let units = (value / per_unit)
            .round()
            .clamp(f64::from(c.minimum), f64::from(c.maximum));
        let applied = self
            .dev
            .s_ctrl(c.id, units as i32)
            .map_err(|e| e.on(&self.name, &format!("VIDIOC_S_CTRL {:?}", c.name)))?;
        Ok(f64::from(applied) * per_unit)
    }

    /// Apply the exposure and frequency of one capture; returns those applied (µs, Hz).
    fn apply_controls(
        &mut self,
        exposure_us: f64,
        modulation_hz: Option<f64>,
    ) -> Result<(f64, f64), BridgeError> {
        let s = self.settings.clone();
        let mut applied_us = s.fixed_exposure_us;
        for c in self.exposure.clone() {
            applied_us = self.set_scaled(&c, exposure_us, s.exposure_us_per_unit)?;
        }
        let exposure_us = applied_us;
        let want_hz = modulation_hz.unwrap_or(s.modulation_hz);
        let modulation_hz = match self.modulation.clone() {
            Some(c) => self.set_scaled(&c, want_hz, s.modulation_hz_per_unit)?,
            None if (want_hz - s.modulation_hz).abs() < 1.0 => s.modulation_hz,
            None => {
                return Err(BridgeError::config(format!(
                    "{}: no v4l2.modulation_control to capture at {want_hz} Hz",
                    self.name
                )));
            }
        };
        Ok((exposure_us, modulation_hz))
    }

    /// One cycle: controls, queue every buffer, STREAMON, one buffer, STREAMOFF (also when
    /// the capture failed, so the sensor never keeps streaming).
    pub fn capture(
        &mut self,
        exposure_us: f64,
        modulation_hz: Option<f64>,
    ) -> Result<V4l2Capture, BridgeError> {
        let t0 = self.clock.now();
        let (exposure_us, modulation_hz) = self.apply_controls(exposure_us, modulation_hz)?;
        let t1 = self.clock.now();
        let mut timings = V4l2Timings {
            controls: t1 - t0,
            ..V4l2Timings::default()
        };
        let frames = self.stream_one(&mut timings);
        let t3 = self.clock.now();
        let off = self
            .dev
            .streamoff()
            .map_err(|e| e.on(&self.name, "VIDIOC_STREAMOFF"));
        timings.stream_off = self.clock.now() - t3;
        let stack = frames?;
        off?;
        let first = self.settings.first_phase_image as usize;
        let k = self.settings.phases_deg.len();
        let frames = stack
            .slice(ndarray::s![first..first + k, .., ..])
            .to_owned();
        Ok(V4l2Capture {
            frames,
            phases_deg: self.settings.phases_deg.clone(),
            exposure_us,
            modulation_hz,
            timings,
        })
    }

    /// QBUF every buffer, STREAMON, DQBUF one and decode it.
    fn stream_one(&mut self, timings: &mut V4l2Timings) -> Result<Array3<u16>, BridgeError> {
        let name = self.name.clone();
        for i in 0..self.buffers {
            self.dev.qbuf(i).map_err(|e| e.on(&name, "VIDIOC_QBUF"))?;
        }
        let t1 = self.clock.now();
        self.dev
            .streamon()
            .map_err(|e| e.on(&name, "VIDIOC_STREAMON"))?;
        let t2 = self.clock.now();
        let timeout = Duration::from_millis(self.settings.frame_timeout_ms);
        let d = self
            .dev
            .dqbuf(timeout)
            .map_err(|e| e.on(&name, "VIDIOC_DQBUF"))?;
        timings.stream_on = t2 - t1;
        timings.to_frame = self.clock.now() - t2;
        let corrupt = |m: String| BridgeError::new(ErrorKind::CorruptFrame, format!("{name}: {m}"));
        if d.flags & BUF_FLAG_ERROR != 0 {
            return Err(corrupt(format!(
                "buffer {} (frame {}) flagged as corrupt",
                d.index, d.sequence
            )));
        }
        let need = self.layout.buffer_bytes();
        let buf = self
            .dev
            .buffer(d.index)
            .map_err(|e| e.on(&name, "mmap buffer"))?;
        let used = (d.bytesused as usize).min(buf.len());
        if used < need {
            return Err(corrupt(format!(
                "frame {} holds {used} bytes, the format needs {need}",
                d.sequence
            )));
        }
        decode_buffer(&buf[..need], &self.layout).map_err(|e| {
            BridgeError::with_source(
                ErrorKind::CorruptFrame,
                format!("{name}: frame {}", d.sequence),
                e,
            )
        })
    }

    /// Free the buffers (REQBUFS 0); the device closes when dropped.
    pub fn close(mut self) -> Result<(), BridgeError> {
        self.dev
            .reqbufs(0)
            .map_err(|e| e.on(&self.name, "VIDIOC_REQBUFS 0"))
            .map(drop)
    }

    /// The device path.
    pub fn device(&self) -> &Path {
        &self.settings.device
    }
}

/// S_FMT of the stacked buffer (`width × rows·images`), then the layout with the driver's
/// stride; a driver that answers with another format, size or a too-small buffer is refused.
fn set_format(
    dev: &mut dyn V4l2Device,
    s: &V4l2Settings,
    name: &str,
) -> Result<BufferLayout, BridgeError> {
    let want = PixFormat {
        width: s.width,
        height: s.rows * s.images,
        pixelformat: s.pixel_format.fourcc(),
        bytesperline: 0,
        sizeimage: 0,
    };
    let got = dev.s_fmt(&want).map_err(|e| e.on(name, "VIDIOC_S_FMT"))?;
    if (got.width, got.height, got.pixelformat) != (want.width, want.height, want.pixelformat) {
        return Err(BridgeError::config(format!(
            "{name}: asked {} {}x{} ({} images of {} rows), the driver gives {} {}x{}",
            fourcc_str(want.pixelformat),
            want.width,
            want.height,
            s.images,
            s.rows,
            fourcc_str(got.pixelformat),
            got.width,
            got.height
        )));
    }
    let line = s.pixel_format.packing().line_bytes(s.width as usize);
    let stride = (got.bytesperline as usize).max(line);
    let layout = s.layout(Some(stride));
    if (got.sizeimage as usize) < layout.buffer_bytes() {
        return Err(BridgeError::config(format!(
            "{name}: the driver's buffers hold {} bytes, {} images need {}",
            got.sizeimage,
            s.images,
            layout.buffer_bytes()
        )));
    }
    Ok(layout)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_errors_name_the_key() {
        let mut s = V4l2Settings {
            images: 2,
            ..V4l2Settings::default()
        };
        let e = s.validate().unwrap_err();
        assert!(
            e.to_string()
                .contains("v4l2.phases_deg: 4 phases from image 0 of 2"),
            "{e}"
        );
        s.phases_deg = vec![0.0, 90.0];
        s.first_phase_image = 1;
        assert!(
            s.validate()
                .unwrap_err()
                .to_string()
                .contains("2 phases from image 1 of 2")
        );
        s.first_phase_image = 0;
        s.exposure_us_per_unit = 0.0;
        let e = s.validate().unwrap_err();
        assert!(e.to_string().contains("v4l2.exposure_us_per_unit"), "{e}");
        assert_eq!(e.kind(), ErrorKind::Config);
    }

    /// Issue 35 W4: `width` and `rows` had no upper bound (nor had the other keys); every key
    /// is bounded and the error names it.
    #[test]
    fn every_key_is_bounded() {
        type Edit = fn(&mut V4l2Settings);
        let cases: [(Edit, &str); 12] = [
            (|s| s.width = u32::MAX, "v4l2.width/rows/images"),
            (|s| s.rows = 4097, "v4l2.width/rows/images"),
            (
                |s| (s.width, s.rows) = (4096, 4096),
                "v4l2.width/rows/images",
            ),
            (|s| s.images = 65, "v4l2.width/rows/images"),
            (|s| s.first_phase_image = 9, "v4l2.first_phase_image"),
            (|s| s.phases_deg = vec![0.0, f64::NAN], "v4l2.phases_deg"),
            (|s| s.fixed_exposure_us = 1e9, "v4l2.fixed_exposure_us"),
            (
                |s| s.exposure_us_per_unit = 1e300,
                "v4l2.exposure_us_per_unit",
            ),
            (
                |s| s.exposure_controls = vec![String::new(); 17],
                "v4l2.exposure_controls",
            ),
            (
                |s| s.modulation_control = "x".repeat(32),
                "v4l2.modulation_control",
            ),
            (|s| s.frame_timeout_ms = u64::MAX, "v4l2.frame_timeout_ms"),
            (
                |s| s.device = PathBuf::from("/".repeat(5000)),
                "v4l2.device",
            ),
        ];
        for (edit, key) in cases {
            let mut s = V4l2Settings::default();
            edit(&mut s);
            let e = s.validate().unwrap_err();
            assert!(e.to_string().contains(key), "{key}: {e}");
        }
        // the largest accepted: a 4096 × 256 RAW16 image, four stacked (8 MiB)
        let s = V4l2Settings {
            width: 4096,
            rows: 256,
            ..V4l2Settings::default()
        };
        s.validate().unwrap();
    }
}
