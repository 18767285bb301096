//! 2-phase ↔ 4-phase on background light (thesis 5.1.2.3): the 2-phase algorithm (eq. 2.2)
//! does not cancel the background the 4-phase one (eq. 2.3) removes, so under strong light
//! the loop captures 4 raw images. While in 2-phase a 4-phase probe runs every
//! `ambient.probe_every` cycles to measure the light; it switches up at once on a high
//! indicator (or a 2-vs-4-phase discrepancy) and back down after `ambient.low_readings`
//! low readings in a row (hysteresis).

use crate::config::{AmbientConfig, Mode};

/// What a 4-phase capture showed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AmbientObservation {
    /// Common-mode level of the raw images above the dark level over the ROI (LSB).
    pub indicator_lsb: f32,
    /// |2-phase − 4-phase| median depth over the ROI (mm), when both had one.
    pub discrepancy_mm: Option<f64>,
}

/// The mode switch with its hysteresis and probe schedule.
#[derive(Debug, Clone)]
pub struct AmbientSwitch {
    cfg: AmbientConfig,
    /// The configured mode (the switch only returns to 2-phase when 2-phase was configured).
    configured: Mode,
    /// Switching is on and the source can choose its mode.
    active: bool,
    mode: Mode,
    low_count: u32,
    cycles_since_probe: u32,
}

impl AmbientSwitch {
    /// New switch starting in `configured`; `source_can_switch`: the source captures
    /// 4-phase on request (a replay cannot).
    pub fn new(cfg: AmbientConfig, configured: Mode, source_can_switch: bool) -> Self {
        Self {
            active: cfg.enabled && source_can_switch,
            cfg,
            configured,
            mode: configured,
            low_count: 0,
            cycles_since_probe: 0,
        }
    }

    /// The mode of the next regular capture.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Whether the next capture is a 4-phase probe (2-phase now, probe due).
    pub fn probe_due(&self) -> bool {
        self.active
            && self.mode == Mode::TwoPhase
            && self.cycles_since_probe + 1 >= self.cfg.probe_every
    }

    /// Count a processed capture for the probe schedule (a 4-phase capture is a probe).
    pub fn note_capture(&mut self, probe: bool, captured: Mode) {
        if probe || captured == Mode::FourPhase {
            self.cycles_since_probe = 0;
        } else {
            self.cycles_since_probe += 1;
        }
    }

    /// The mode after a 4-phase capture showed `obs`.
    pub fn next(&mut self, obs: AmbientObservation) -> Mode {
        if !self.active {
            return self.mode;
        }
        let disc_high = obs
            .discrepancy_mm
            .is_some_and(|d| d > f64::from(self.cfg.discrepancy_mm));
        let ind = obs.indicator_lsb;
        let high = ind > self.cfg.high_lsb || disc_high;
        let low = ind < self.cfg.low_lsb && !disc_high;
        match self.mode {
            Mode::TwoPhase if high => {
                tracing::info!(
                    "switching to 4-phase: background indicator {ind:.0} LSB (high above {:.0}), \
                     2-vs-4-phase discrepancy {} mm (high above {})",
                    self.cfg.high_lsb,
                    obs.discrepancy_mm
                        .map_or("n/a".to_string(), |d| format!("{d:.0}")),
                    self.cfg.discrepancy_mm
                );
                self.mode = Mode::FourPhase;
                self.low_count = 0;
            }
            Mode::FourPhase if self.configured == Mode::TwoPhase => {
                if low {
                    self.low_count += 1;
                    if self.low_count >= self.cfg.low_readings {
                        tracing::info!("background light low again: back to 2-phase");
                        self.mode = Mode::TwoPhase;
                        self.low_count = 0;
                    }
                } else {
                    self.low_count = 0;
                }
            }
            _ => {}
        }
        self.mode
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> AmbientConfig {
        AmbientConfig {
            enabled: true,
            probe_every: 3,
            high_lsb: 100.0,
            low_lsb: 50.0,
            low_readings: 2,
            discrepancy_mm: 30,
        }
    }

    fn obs(indicator_lsb: f32) -> AmbientObservation {
        AmbientObservation {
            indicator_lsb,
            discrepancy_mm: None,
        }
    }

    #[test]
    fn probes_every_n_captures_in_two_phase() {
        let mut a = AmbientSwitch::new(cfg(), Mode::TwoPhase, true);
        assert!(!a.probe_due());
        a.note_capture(false, Mode::TwoPhase);
        assert!(!a.probe_due());
        a.note_capture(false, Mode::TwoPhase);
        assert!(a.probe_due(), "third capture is the probe");
        a.note_capture(true, Mode::FourPhase);
        assert!(!a.probe_due(), "schedule restarts after the probe");
        let fixed = AmbientSwitch::new(cfg(), Mode::TwoPhase, false);
        assert!(
            !fixed.probe_due(),
            "a source that cannot switch is never probed"
        );
    }

    #[test]
    fn up_at_once_down_after_the_hysteresis() {
        let mut a = AmbientSwitch::new(cfg(), Mode::TwoPhase, true);
        assert_eq!(
            a.next(obs(80.0)),
            Mode::TwoPhase,
            "between the thresholds: stay"
        );
        assert_eq!(a.next(obs(150.0)), Mode::FourPhase, "high: up at once");
        assert_eq!(a.next(obs(20.0)), Mode::FourPhase, "one low reading");
        assert_eq!(
            a.next(obs(80.0)),
            Mode::FourPhase,
            "not low: count restarts"
        );
        assert_eq!(a.next(obs(20.0)), Mode::FourPhase);
        assert_eq!(a.next(obs(20.0)), Mode::TwoPhase, "two low in a row: back");
    }

    #[test]
    fn discrepancy_alone_switches_up_and_blocks_the_way_down() {
        let mut a = AmbientSwitch::new(cfg(), Mode::TwoPhase, true);
        let disc = AmbientObservation {
            indicator_lsb: 10.0,
            discrepancy_mm: Some(45.0),
        };
        assert_eq!(a.next(disc), Mode::FourPhase);
        assert_eq!(a.next(disc), Mode::FourPhase);
        assert_eq!(
            a.next(disc),
            Mode::FourPhase,
            "low light but 2-phase disagrees"
        );
    }

    #[test]
    fn configured_four_phase_stays_and_disabled_never_switches() {
        let mut a = AmbientSwitch::new(cfg(), Mode::FourPhase, true);
        for _ in 0..5 {
            assert_eq!(a.next(obs(0.0)), Mode::FourPhase);
        }
        let mut off = AmbientSwitch::new(
            AmbientConfig {
                enabled: false,
                ..cfg()
            },
            Mode::TwoPhase,
            true,
        );
        assert_eq!(off.next(obs(1e6)), Mode::TwoPhase);
        assert!(!off.probe_due());
    }
}
