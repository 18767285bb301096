//! The cycle's tables: `[loop]` (rates, hold-offs) and `[processing]` (mode, calibration).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::Mode;
use super::error::{ConfigError, finite_pos, non_neg, range};

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

impl LoopConfig {
    /// Range-check the `[loop]` table; the error names the key.
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
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
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
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
