//! The sensing tables: `[proximity]` (the near/far decision), `[ambient]`, `[exposure]`,
//! `[readout]` and `[probe]`.

use serde::{Deserialize, Serialize};

use super::error::{ConfigError, finite_pos, fraction, range};

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
    /// A reading reads every `row_step`-th row of its window where the sensor's sequencer
    /// skips rows (1: every row; a depth frame always reads every row): the near/far
    /// decision is a share of the ROI's pixels, which every 2nd row measures alike.
    pub row_step: u16,
}

impl Default for ReadoutConfig {
    fn default() -> Self {
        Self {
            partial: true,
            margin_rows: 2,
            margin_cols: 0,
            row_step: 2,
        }
    }
}

impl ReadoutConfig {
    /// The row step a reading is read with: `row_step` where the source's sequencer skips rows
    /// that far (`max_row_step`) and the array's rows are a multiple of it, else every row.
    pub fn row_step_for(&self, max_row_step: u16, full_rows: usize) -> u16 {
        let step = self.row_step.max(1);
        if step <= max_row_step && full_rows.is_multiple_of(usize::from(step)) {
            step
        } else {
            1
        }
    }

    pub(super) fn validate(&self) -> Result<(), ConfigError> {
        range(
            "readout.row_step",
            (1..=4).contains(&self.row_step),
            format!("must be within 1..=4, got {}", self.row_step),
        )
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
    /// The row step a probe reads with: `row_step`, at most what the source's sequencer skips
    /// (`max_row_step`; 1: every row).
    pub fn row_step_for(&self, max_row_step: u16) -> u16 {
        self.row_step.min(max_row_step).max(1)
    }

    pub(super) fn validate(&self) -> Result<(), ConfigError> {
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

impl ProximityConfig {
    /// Range-check the `[proximity]` table; the error names the key.
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
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
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
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
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
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
