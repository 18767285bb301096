//! Auto-exposure within the eye-safe limits (thesis 3.1.2: amplitude ∝ exposure; the
//! longest exposure `exposure.max_us` is the eye-safety bound, the shortest `min_us` the
//! sensor's): shorten by `exposure.step` while too much of the ROI saturates, lengthen while
//! too much of it is below the amplitude floor; a frame with every code on a rail is taken
//! as too bright. It never lengthens beyond what the near/far decision needs
//! ([`decision_exposure_us`], issue 34): an image-quality exposure costs capture energy
//! the decision does not use.

use ndarray::{ArrayView3, Axis, s};
use tofprox_core::pipeline::RawSample;
use tofprox_core::proximity::Roi;

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
        /// Fraction of ROI pixels that would saturate at the longer exposure
        /// ([`saturating_fraction_at`] with `exposure.step`).
        saturated_when_longer: f32,
    },
}

/// The exposure controller.
#[derive(Debug, Clone)]
pub struct AutoExposure {
    cfg: ExposureConfig,
    exposure_us: f64,
    /// The longest exposure lengthening may reach ([`decision_exposure_us`]); `None`: `max_us`.
    decision_us: Option<f64>,
}

/// The exposure the near/far decision needs: the shortest at which a target of
/// `reflectivity` (the documented minimum, `proximity.reflectivity_floor`) at `far_m` returns
/// `required_lsb` of amplitude, the amplitude a pixel needs to count
/// (`processing.min_amplitude_lsb`). Thesis 2.2.1: `A = K·ρ·t/d²`, so `t = A·d²/(K·ρ)`;
/// 2.3.2.6: in low light the read-out noise dominates the photon transfer curve, a constant,
/// so the SNR a pixel's phase needs is an amplitude floor above that noise — which is what
/// `min_amplitude_lsb` is. A nearer or brighter target returns more (`∝ ρ/d²`), so every
/// target that must count does at this exposure. `k_lsb_m2_per_us` is the sensor's `K` (the
/// weak end of the ROI's: its 10th percentile).
pub fn decision_exposure_us(
    k_lsb_m2_per_us: f64,
    reflectivity: f64,
    far_m: f64,
    required_lsb: f64,
) -> Option<f64> {
    let t = required_lsb * far_m * far_m / (k_lsb_m2_per_us * reflectivity);
    (t.is_finite() && t > 0.0).then_some(t)
}

impl AutoExposure {
    /// Starts at `exposure.initial_us`.
    pub fn new(cfg: ExposureConfig) -> Self {
        Self {
            exposure_us: cfg.initial_us,
            cfg,
            decision_us: None,
        }
    }

    /// Cap lengthening at the exposure the decision needs ([`decision_exposure_us`]; never
    /// below `min_us`, never above `max_us`).
    pub fn set_decision_us(&mut self, decision_us: Option<f64>) {
        self.decision_us = decision_us.map(|t| t.clamp(self.cfg.min_us, self.cfg.max_us));
    }

    /// The cap on lengthening (µs), when one is set.
    pub fn decision_us(&self) -> Option<f64> {
        self.decision_us
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
                saturated_when_longer,
            } => {
                if saturated_fraction > e.saturated_fraction {
                    self.exposure_us / e.step
                } else if low_amplitude_fraction > e.low_amplitude_fraction
                    && saturated_when_longer <= e.saturated_fraction
                {
                    // never longer than the decision needs (nor shortened by this rule)
                    let cap = self.decision_us.unwrap_or(e.max_us).max(self.exposure_us);
                    (self.exposure_us * e.step).min(cap)
                } else {
                    self.exposure_us
                }
            }
        };
        self.exposure_us = t.clamp(e.min_us, e.max_us);
        self.exposure_us
    }
}

/// The fraction of `roi`'s pixels whose codes would reach a rail at `factor` × the exposure:
/// a code's excursion from the dark level grows with the exposure (thesis 3.1.2, the return
/// and the background light both ∝ exposure), so a pixel saturates when some image's
/// `dark + factor·(code − dark)` lies at or beyond 0 or `max_code`. A bright target beside
/// dark ones (a retroreflector over a third of the view) then keeps the exposure where it is
/// measurable instead of lengthening it back into saturation for the dark pixels' sake.
pub fn saturating_fraction_at<T: RawSample>(
    frames: ArrayView3<'_, T>,
    roi: Roi,
    dark: f32,
    max_code: f32,
    factor: f64,
) -> f32 {
    let (_, rows, cols) = frames.dim();
    let r = roi.resolve(rows, cols);
    let view = frames.slice(s![.., r.row0..r.row0 + r.rows, r.col0..r.col0 + r.cols]);
    let f = factor as f32;
    let total = (r.rows * r.cols).max(1);
    let saturating = view
        .lanes(Axis(0))
        .into_iter()
        .filter(|px| {
            px.iter().any(|&v| {
                let c = dark + f * (v.to_f32() - dark);
                c <= 0.0 || c >= max_code
            })
        })
        .count();
    saturating as f32 / total as f32
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
            saturated_when_longer: 0.0,
        }
    }

    /// A third of the view bright enough to saturate at the longer exposure, the rest dark:
    /// the exposure stays where the bright third is measurable.
    #[test]
    fn never_lengthens_into_saturation() {
        // 2 images of 3×3, dark level 100, 12-bit rails; column 0 at +2100 codes, the rest +5
        let mut codes = ndarray::Array3::from_elem((2, 3, 3), 105.0f32);
        codes.slice_mut(s![.., .., 0]).fill(2200.0);
        let all = Roi::centered(3, 3, 1.0);
        let f = saturating_fraction_at(codes.view(), all, 100.0, 4095.0, 2.0);
        assert!((f - 1.0 / 3.0).abs() < 1e-6, "{f}");
        assert_eq!(
            saturating_fraction_at(codes.view(), all, 100.0, 4095.0, 1.5),
            0.0
        );
        let mut a = AutoExposure::new(cfg());
        let weak_but_bright_third = ExposureObservation::Roi {
            saturated_fraction: 0.0,
            low_amplitude_fraction: 2.0 / 3.0,
            saturated_when_longer: f,
        };
        assert_eq!(a.next(weak_but_bright_third), 100.0, "kept");
        assert_eq!(a.next(roi(0.0, 2.0 / 3.0)), 200.0, "lengthened without");
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

    /// Issue 34: nothing returns (an empty hall), yet the exposure stops where a 2 % target
    /// at `far_mm` returns the amplitude a pixel needs — computed independently here from the
    /// law `A = K·ρ·t/d²` — instead of climbing to the eye-safe maximum.
    #[test]
    fn lengthens_only_as_far_as_the_decision_needs() {
        let (k, rho, far_m, need) = (0.09, 0.02, 0.15, 8.0);
        let t = decision_exposure_us(k, rho, far_m, need).expect("finite");
        let amplitude_at_t = k * rho * t / (far_m * far_m);
        assert!((amplitude_at_t - need).abs() < 1e-9, "{amplitude_at_t}");
        assert!((t - 100.0).abs() < 1e-9, "{t}");
        let mut a = AutoExposure::new(ExposureConfig {
            initial_us: 30.0,
            ..cfg()
        });
        a.set_decision_us(Some(t));
        assert_eq!(a.next(roi(0.0, 1.0)), 60.0);
        assert_eq!(
            a.next(roi(0.0, 1.0)),
            100.0,
            "capped at the decision's need"
        );
        assert_eq!(a.next(roi(0.0, 1.0)), 100.0, "and kept there");
        assert_eq!(a.next(roi(0.2, 1.0)), 50.0, "saturation still shortens");
        assert_eq!(decision_exposure_us(0.0, rho, far_m, need), None);
    }
}
