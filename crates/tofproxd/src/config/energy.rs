//! `[energy]`: the energy model's powers (thesis table 3.1).

use serde::{Deserialize, Serialize};

use super::error::{ConfigError, non_neg, range};

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

impl EnergyConfig {
    /// Range-check the `[energy]` table; the error names the key.
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
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
