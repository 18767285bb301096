//! Adaptive reading rate (thesis 3.5.3: the energy per reading is fixed, so the average
//! power is set by the rate): fast while near or while a target approaches faster than
//! `loop.approach_mm_per_s`, slow after `loop.still_readings` readings that moved less than
//! `loop.still_tolerance_mm`, the nominal rate otherwise; always within [slow, fast].
//! Nothing in range is a reading of its own: readings with nothing in range one after another
//! are still (a far, still phone — an empty hall, the sky — drops to the slow rate), and a
//! target appearing out of nothing in range is an approach.

use crate::config::LoopConfig;

/// What a processed cycle read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RateObservation {
    /// The detector's near.
    pub near: bool,
    /// The ROI distance (mm), when one was measured.
    pub distance_mm: Option<u32>,
    /// A valid reading with nothing in range (no distance: no target returns).
    pub no_target: bool,
}

/// Where "nothing in range" sits for the motion history: beyond every distance, so two such
/// readings are still and a target appearing from it approaches at once.
const BEYOND_RANGE_MM: u32 = u32::MAX;

/// The rate controller.
#[derive(Debug, Clone)]
pub struct AdaptiveRate {
    cfg: LoopConfig,
    rate_hz: f64,
    still_count: u32,
    last_distance_mm: Option<u32>,
}

impl AdaptiveRate {
    /// Starts at the nominal `loop.rate_hz`.
    pub fn new(cfg: LoopConfig) -> Self {
        Self {
            rate_hz: cfg.rate_hz,
            cfg,
            still_count: 0,
            last_distance_mm: None,
        }
    }

    /// Current rate (Hz).
    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    /// Readings in a row that moved less than `loop.still_tolerance_mm` (nothing in range
    /// after nothing in range included; near readings count too, near after near).
    pub fn still_readings(&self) -> u32 {
        self.still_count
    }

    /// Forget the motion history (the loop stopped); the rate is kept.
    pub fn reset(&mut self) {
        self.still_count = 0;
        self.last_distance_mm = None;
    }

    /// The rate after a reading `obs` taken one period after the previous one.
    pub fn next(&mut self, obs: RateObservation) -> f64 {
        let l = &self.cfg;
        let period_s = 1.0 / self.rate_hz;
        let distance_mm = obs.distance_mm.or(obs.no_target.then_some(BEYOND_RANGE_MM));
        let new_rate = if obs.near {
            // near stays fast; it is still while its distance holds (the near probe's count)
            let held = matches!((distance_mm, self.last_distance_mm),
                (Some(d), Some(prev)) if d.abs_diff(prev) <= l.still_tolerance_mm);
            self.still_count = if held {
                self.still_count.saturating_add(1)
            } else {
                0
            };
            l.fast_rate_hz
        } else if let (Some(d), Some(prev)) = (distance_mm, self.last_distance_mm) {
            let speed = (f64::from(prev) - f64::from(d)) / period_s; // + = approaching
            if speed > l.approach_mm_per_s {
                self.still_count = 0;
                l.fast_rate_hz
            } else if d.abs_diff(prev) <= l.still_tolerance_mm {
                self.still_count = self.still_count.saturating_add(1);
                if self.still_count >= l.still_readings {
                    l.slow_rate_hz
                } else {
                    l.rate_hz
                }
            } else {
                self.still_count = 0;
                l.rate_hz
            }
        } else {
            l.rate_hz
        };
        self.rate_hz = new_rate.clamp(l.slow_rate_hz, l.fast_rate_hz);
        if distance_mm.is_some() {
            self.last_distance_mm = distance_mm;
        }
        self.rate_hz
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(d: u32) -> RateObservation {
        RateObservation {
            near: false,
            distance_mm: Some(d),
            no_target: false,
        }
    }

    fn cfg() -> LoopConfig {
        LoopConfig {
            rate_hz: 2.0,
            fast_rate_hz: 10.0,
            slow_rate_hz: 1.0,
            still_readings: 3,
            still_tolerance_mm: 20,
            approach_mm_per_s: 150.0,
            ..LoopConfig::default()
        }
    }

    #[test]
    fn fast_when_near_or_approaching() {
        let mut r = AdaptiveRate::new(cfg());
        assert_eq!(r.next(at(900)), 2.0, "first reading: nominal");
        assert_eq!(r.next(at(700)), 10.0, "200 mm in 0.5 s = 400 mm/s");
        assert_eq!(r.next(at(690)), 2.0, "10 mm in 0.1 s = 100 mm/s: nominal");
        let near = RateObservation {
            near: true,
            distance_mm: Some(40),
            no_target: false,
        };
        assert_eq!(r.next(near), 10.0);
        assert_eq!(r.still_readings(), 0, "near after 690 mm: moved");
        assert_eq!(r.next(near), 10.0, "near and still: still fast");
        assert_eq!(r.still_readings(), 1, "near after near at 40 mm: still");
        let closer = RateObservation {
            distance_mm: Some(5),
            ..near
        };
        r.next(closer);
        assert_eq!(r.still_readings(), 0, "35 mm closer: moved");
    }

    #[test]
    fn slow_after_still_readings_and_reset_forgets_motion() {
        let mut r = AdaptiveRate::new(cfg());
        r.next(at(900));
        assert_eq!(r.next(at(905)), 2.0);
        assert_eq!(r.next(at(900)), 2.0);
        assert_eq!(r.next(at(910)), 1.0, "three still readings: slow");
        assert_eq!(r.next(at(800)), 2.0, "moved away by 110 mm: nominal again");
        r.reset();
        assert_eq!(
            r.next(at(100)),
            2.0,
            "no history after a reset: no approach seen"
        );
        let unknown = RateObservation {
            near: false,
            distance_mm: None,
            no_target: false,
        };
        assert_eq!(r.next(unknown), 2.0);
    }

    /// Issue 34: a far, still phone (an empty hall, the sky: nothing in range, reading after
    /// reading) drops to the slow rate; a hand appearing out of nothing in range is an
    /// approach (fast at once).
    #[test]
    fn nothing_in_range_reading_after_reading_is_still() {
        let mut r = AdaptiveRate::new(cfg());
        let nothing = RateObservation {
            near: false,
            distance_mm: None,
            no_target: true,
        };
        assert_eq!(r.next(nothing), 2.0, "first reading: nominal");
        assert_eq!(r.next(nothing), 2.0);
        assert_eq!(r.next(nothing), 2.0);
        assert_eq!(r.next(nothing), 1.0, "three still readings: slow");
        assert_eq!(r.next(nothing), 1.0, "and it stays slow");
        assert_eq!(
            r.next(at(400)),
            10.0,
            "a target out of nothing in range: approach"
        );
        assert_eq!(r.next(nothing), 2.0, "it left: moving, nominal");
    }
}
