//! Capture requests; the simulated array is the shared [`SensorGeometry`] of `tofprox-core`.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
pub use tofprox_core::SensorGeometry;

use crate::error::ModelError;

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
    /// The capture's other conditions by key (a recording's `[capture.conditions]`
    /// beyond the model inputs, e.g. `vcsel_bias_ma`): what the model's user
    /// effects read ([`crate::effects::user`]); empty by default.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub conditions: BTreeMap<String, f64>,
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
            conditions: BTreeMap::new(),
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
        if let Some((k, v)) = self.conditions.iter().find(|(_, v)| !v.is_finite()) {
            return Err(ModelError::invalid(format!(
                "capture: condition {k} = {v} is not finite"
            )));
        }
        Ok(())
    }

    /// The quantities a user effect's expression reads ([`crate::effects::user::QUANTITIES`]).
    pub fn quantities(&self) -> crate::effects::user::CaptureQuantities {
        crate::effects::user::CaptureQuantities {
            exposure_us: self.exposure_us,
            temperature_c: self.temperature_c,
            ambient_klux: self.ambient_klux,
        }
    }
}
