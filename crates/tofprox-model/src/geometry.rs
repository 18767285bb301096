//! Sensor geometry and capture requests.

use serde::{Deserialize, Serialize};

use crate::error::ModelError;

/// The pixel array (or a read-out window of it) being simulated.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorGeometry {
    /// Rows of the window.
    pub rows: usize,
    /// Columns of the window.
    pub cols: usize,
    /// Full-array position of the window's first pixel `[row, col]`.
    pub roi_origin: [usize; 2],
    /// Rows of the full array.
    pub full_rows: usize,
    /// Columns of the full array.
    pub full_cols: usize,
    /// ADC resolution (12 for the IRS1645).
    pub adc_bits: u8,
    /// Modulation frequency (80 MHz in the thesis, 5.1.1).
    pub modulation_hz: f64,
}

impl SensorGeometry {
    /// The IRS1645-class full array: 172 rows × 224 columns, 12-bit, 80 MHz.
    pub fn irs1645() -> Self {
        Self {
            rows: 172,
            cols: 224,
            roi_origin: [0, 0],
            full_rows: 172,
            full_cols: 224,
            adc_bits: 12,
            modulation_hz: 80e6,
        }
    }

    /// A window of this geometry's full array.
    pub fn window(
        &self,
        row0: usize,
        col0: usize,
        rows: usize,
        cols: usize,
    ) -> Result<Self, ModelError> {
        let g = Self {
            rows,
            cols,
            roi_origin: [row0, col0],
            ..*self
        };
        g.validate()?;
        Ok(g)
    }

    /// Check consistency.
    pub fn validate(&self) -> Result<(), ModelError> {
        if self.rows == 0 || self.cols == 0 {
            return Err(ModelError::invalid(format!(
                "geometry: window {}x{} must have at least one pixel",
                self.rows, self.cols
            )));
        }
        if self.full_rows > 8192 || self.full_cols > 8192 {
            return Err(ModelError::invalid(
                "geometry: full array larger than 8192x8192",
            ));
        }
        if self.roi_origin[0] + self.rows > self.full_rows
            || self.roi_origin[1] + self.cols > self.full_cols
        {
            return Err(ModelError::invalid(format!(
                "geometry: window {}x{} at {:?} does not fit in the {}x{} array",
                self.rows, self.cols, self.roi_origin, self.full_rows, self.full_cols
            )));
        }
        if !(8..=16).contains(&self.adc_bits) {
            return Err(ModelError::invalid(format!(
                "geometry: adc_bits = {} outside the allowed range [8, 16]",
                self.adc_bits
            )));
        }
        if !(self.modulation_hz.is_finite() && (1e5..=1e9).contains(&self.modulation_hz)) {
            return Err(ModelError::invalid(format!(
                "geometry: modulation_hz = {} outside the allowed range [1e5, 1e9] Hz",
                self.modulation_hz
            )));
        }
        Ok(())
    }
}

impl Default for SensorGeometry {
    fn default() -> Self {
        Self::irs1645()
    }
}

/// One capture: K raw images at the given phase shifts, in acquisition order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaptureRequest {
    /// Phase shift θ_k of each raw image in degrees (acquisition order).
    pub phases_deg: Vec<f64>,
    /// Exposure (integration) time per raw image.
    pub exposure_us: f64,
    /// Whether the VCSEL is on (false: dark capture).
    pub illumination: bool,
    /// Number of acquisitions averaged into the returned frames (noise / √n).
    pub averaged: u32,
    /// Uncorrelated background light.
    pub ambient_klux: f64,
    /// Sensor/illumination temperature.
    pub temperature_c: f64,
}

impl CaptureRequest {
    /// A 4-phase capture [0, 90, 180, 270]°, illuminated, 25 °C, no ambient light.
    pub fn four_phase(exposure_us: f64) -> Self {
        Self::with_phases(vec![0.0, 90.0, 180.0, 270.0], exposure_us)
    }
    /// A 2-phase capture [0, 90]°.
    pub fn two_phase(exposure_us: f64) -> Self {
        Self::with_phases(vec![0.0, 90.0], exposure_us)
    }
    /// The 24-phase correlation capture [0, 15, …, 345]°.
    pub fn correlation24(exposure_us: f64) -> Self {
        Self::with_phases((0..24).map(|k| 15.0 * k as f64).collect(), exposure_us)
    }
    /// A dark capture (illumination off) with K raw images at 0°.
    pub fn dark(k: usize, exposure_us: f64) -> Self {
        Self {
            illumination: false,
            ..Self::with_phases(vec![0.0; k], exposure_us)
        }
    }
    /// Illuminated capture with the given phases.
    pub fn with_phases(phases_deg: Vec<f64>, exposure_us: f64) -> Self {
        Self {
            phases_deg,
            exposure_us,
            illumination: true,
            averaged: 1,
            ambient_klux: 0.0,
            temperature_c: 25.0,
        }
    }

    /// Check physical ranges.
    pub fn validate(&self) -> Result<(), ModelError> {
        if self.phases_deg.is_empty() || self.phases_deg.len() > 256 {
            return Err(ModelError::invalid(format!(
                "capture: {} raw images, allowed [1, 256]",
                self.phases_deg.len()
            )));
        }
        if let Some(p) = self.phases_deg.iter().find(|p| !p.is_finite()) {
            return Err(ModelError::invalid(format!(
                "capture: phases_deg contains {p}"
            )));
        }
        if !(self.exposure_us.is_finite() && self.exposure_us > 0.0 && self.exposure_us <= 1e6) {
            return Err(ModelError::invalid(format!(
                "capture: exposure_us = {} outside the allowed range (0, 1e6] us",
                self.exposure_us
            )));
        }
        if self.averaged == 0 || self.averaged > 65_536 {
            return Err(ModelError::invalid(format!(
                "capture: averaged = {} outside the allowed range [1, 65536]",
                self.averaged
            )));
        }
        if !(self.ambient_klux.is_finite() && (0.0..=200.0).contains(&self.ambient_klux)) {
            return Err(ModelError::invalid(format!(
                "capture: ambient_klux = {} outside the allowed range [0, 200] klux",
                self.ambient_klux
            )));
        }
        if !(self.temperature_c.is_finite() && (-40.0..=150.0).contains(&self.temperature_c)) {
            return Err(ModelError::invalid(format!(
                "capture: temperature_c = {} outside the allowed range [-40, 150] degC",
                self.temperature_c
            )));
        }
        Ok(())
    }
}
