//! Auto-exposure within the eye-safe limits (thesis 3.1.2: amplitude ∝ exposure; the
//! longest exposure `exposure.max_us` is the eye-safety bound, the shortest `min_us` the
//! sensor's): shorten by `exposure.step` while too much of the ROI saturates, lengthen while
//! too much of it is below the amplitude floor; a frame with every code on a rail is taken
//! as too bright.

use crate::config::ExposureConfig;

/// What the cycle showed about the exposure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ExposureObservation {
    /// Every code of every raw image on a rail (too close/bright to measure, or dead).
    Rails,
    /// The ROI's flag statistics.
    Roi {
        /// Fraction of ROI pixels flagged saturated.
        saturated_fraction: f32,
        /// Fraction of ROI pixels below the amplitude floor (and not saturated).
        low_amplitude_fraction: f32,
    },
}

/// The exposure controller.
#[derive(Debug, Clone)]
pub struct AutoExposure {
    cfg: ExposureConfig,
    exposure_us: f64,
}

impl AutoExposure {
    /// Starts at `exposure.initial_us`.
    pub fn new(cfg: ExposureConfig) -> Self {
        Self {
            exposure_us: cfg.initial_us,
            cfg,
        }
    }

    /// Exposure per raw image of the next capture (µs).
    pub fn exposure_us(&self) -> f64 {
        self.exposure_us
    }

    /// The exposure for the next capture after `obs` (unchanged when auto-exposure is off).
    pub fn next(&mut self, obs: ExposureObservation) -> f64 {
        if !self.cfg.auto {
            return self.exposure_us;
        }
        let e = &self.cfg;
        let t = match obs {
            ExposureObservation::Rails => self.exposure_us / e.step,
            ExposureObservation::Roi {
                saturated_fraction,
                low_amplitude_fraction,
            } => {
                if saturated_fraction > e.saturated_fraction {
                    self.exposure_us / e.step
                } else if low_amplitude_fraction > e.low_amplitude_fraction {
                    self.exposure_us * e.step
                } else {
                    self.exposure_us
                }
            }
        };
        self.exposure_us = t.clamp(e.min_us, e.max_us);
        self.exposure_us
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> ExposureConfig {
        ExposureConfig {
            initial_us: 100.0,
            min_us: 20.0,
            max_us: 500.0,
            auto: true,
            saturated_fraction: 0.05,
            low_amplitude_fraction: 0.5,
            step: 2.0,
        }
    }

    fn roi(sat: f32, low: f32) -> ExposureObservation {
        ExposureObservation::Roi {
            saturated_fraction: sat,
            low_amplitude_fraction: low,
        }
    }

    #[test]
    fn shortens_on_saturation_lengthens_on_weak_returns_within_bounds() {
        let mut a = AutoExposure::new(cfg());
        assert_eq!(a.next(roi(0.2, 0.0)), 50.0);
        assert_eq!(
            a.next(roi(0.2, 0.9)),
            25.0,
            "saturation wins over weak pixels"
        );
        assert_eq!(a.next(roi(0.2, 0.0)), 20.0, "never below min");
        assert_eq!(a.next(roi(0.0, 0.1)), 20.0, "fine: unchanged");
        for _ in 0..10 {
            a.next(roi(0.0, 0.9));
        }
        assert_eq!(a.exposure_us(), 500.0, "never above the eye-safe max");
    }

    #[test]
    fn rails_shorten_and_manual_exposure_is_kept() {
        let mut a = AutoExposure::new(cfg());
        assert_eq!(a.next(ExposureObservation::Rails), 50.0);
        let mut m = AutoExposure::new(ExposureConfig {
            auto: false,
            ..cfg()
        });
        assert_eq!(m.next(ExposureObservation::Rails), 100.0);
        assert_eq!(m.next(roi(1.0, 0.0)), 100.0);
    }
}
