//! The lab's view of a recording: captures of raw codes with their conditions.
//! Independent of the file format so the statistics can be tested on small
//! synthetic data; `adapter` converts a `tofprox_format::Recording`.
use ndarray::Array3;
use tofprox_core::SensorGeometry;

use crate::error::LabError;

/// One capture: K raw images of (rows, cols) mean codes with its conditions.
#[derive(Debug, Clone)]
pub struct Capture {
    /// Phase shift of each raw image, in acquisition order.
    pub phases_deg: Vec<f64>,
    /// Exposure (integration) time.
    pub exposure_us: f64,
    /// false: a dark capture (illumination off).
    pub illumination: bool,
    /// Acquisitions averaged into each code (1 = a single one).
    pub averaged: u32,
    /// Ground-truth radial distance of the flat target, if known.
    pub distance_m: Option<f64>,
    /// Target reflectivity (1 when the recording does not say).
    pub reflectivity: f64,
    /// Background illuminance on the target.
    pub ambient_klux: f64,
    /// Sensor temperature, if recorded.
    pub temperature_c: Option<f64>,
    /// (K, rows, cols) codes (offset binary, mean of `averaged` acquisitions).
    pub frames: Array3<f64>,
}

/// A recording as the lab sees it, captures in acquisition order.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// The recording's window, full array, ADC and modulation.
    pub sensor: SensorGeometry,
    /// The captures, in acquisition order.
    pub captures: Vec<Capture>,
}

impl Dataset {
    /// Check shapes and values; every later stage relies on this.
    pub fn validate(&self) -> Result<(), LabError> {
        let s = &self.sensor;
        if let Err(e) = s.validate() {
            return Err(LabError::data(format!("sensor: {e}")));
        }
        if self.captures.is_empty() {
            return Err(LabError::data("recording has no captures"));
        }
        let full = f64::from(s.max_code()) + 1.0;
        for (i, c) in self.captures.iter().enumerate() {
            let (k, r, cc) = c.frames.dim();
            if r != s.rows || cc != s.cols {
                return Err(LabError::data(format!(
                    "capture {i}: frames are {r}x{cc}, sensor window is {}x{}",
                    s.rows, s.cols
                )));
            }
            if k == 0 || k != c.phases_deg.len() {
                return Err(LabError::data(format!(
                    "capture {i}: {k} raw images but {} phases",
                    c.phases_deg.len()
                )));
            }
            if !(c.exposure_us.is_finite() && c.exposure_us > 0.0) {
                return Err(LabError::data(format!(
                    "capture {i}: exposure_us must be positive"
                )));
            }
            if c.averaged == 0 {
                return Err(LabError::data(format!(
                    "capture {i}: averaged must be >= 1"
                )));
            }
            if let Some(d) = c.distance_m
                && !(d.is_finite() && d > 0.0)
            {
                return Err(LabError::data(format!(
                    "capture {i}: distance_m = {d} is not a positive distance"
                )));
            }
            if !(c.reflectivity.is_finite() && c.reflectivity > 0.0) {
                return Err(LabError::data(format!(
                    "capture {i}: reflectivity must be positive"
                )));
            }
            if !(c.ambient_klux.is_finite() && c.ambient_klux >= 0.0) {
                return Err(LabError::data(format!(
                    "capture {i}: ambient_klux must be >= 0"
                )));
            }
            if c.phases_deg.iter().any(|p| !p.is_finite()) {
                return Err(LabError::data(format!("capture {i}: non-finite phase")));
            }
            if c.frames
                .iter()
                .any(|v| !v.is_finite() || *v < -1.0 || *v > full + 1.0)
            {
                return Err(LabError::data(format!(
                    "capture {i}: codes outside the {}-bit range or not finite",
                    s.adc_bits
                )));
            }
        }
        Ok(())
    }
}
