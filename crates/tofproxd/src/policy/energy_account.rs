//! Energy accounting and the sleep after each cycle (thesis 3.5.3: the sensor is held in
//! reset between readings; table 3.1: energy per reading from the state durations, the
//! number of raw images and the exposure — [`crate::energy::cycle_energy`]). Every captured
//! cycle, processed or not, goes through [`EnergyAccount::next`] once: the sleep is the rest
//! of the period (none when replaying a recording as fast as possible) and the cycle plus
//! that sleep enter the running average.

use std::time::Duration;

use crate::config::{Backend, Config, EnergyConfig};
use crate::energy::{CycleTimings, CycleWork, EnergyMeter, ReadingKind, cycle_energy};
use crate::source::RawCycle;

/// Whether cycles are paced at the reading rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pacing {
    /// Sleep the rest of each period (a sensor, an emulation, a real-time replay).
    RealTime,
    /// No sleep at all: a recording replayed as fast as possible (`replay.realtime = false`).
    AsFastAsPossible,
}

impl Pacing {
    /// The pacing a config asks for.
    pub fn of(cfg: &Config) -> Self {
        if cfg.backend == Backend::Replay && !cfg.replay.realtime {
            Pacing::AsFastAsPossible
        } else {
            Pacing::RealTime
        }
    }
}

/// One captured cycle, as the energy model sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleObservation {
    /// Measured state durations (zero where the source has none).
    pub timings: CycleTimings,
    /// Raw images captured (K).
    pub raw_images: u32,
    /// Exposure per raw image (µs).
    pub exposure_us: f64,
    /// Pixels read out (rows × columns of the window).
    pub pixels_read: usize,
    /// Pixels of the full array (0: unknown, taken as a full read-out).
    pub full_pixels: usize,
    /// The reading rate the period follows (Hz).
    pub rate_hz: f64,
    /// The loop's CPU time for this capture's reading (processing and decisions).
    pub cpu: Duration,
}

impl CycleObservation {
    /// The observation of a captured cycle at the reading rate `rate_hz`.
    pub fn of(cycle: &RawCycle, rate_hz: f64) -> Self {
        Self {
            timings: cycle.timings(),
            raw_images: u32::try_from(cycle.frames.dim().0).unwrap_or(u32::MAX),
            exposure_us: cycle.exposure_us,
            pixels_read: cycle.geometry.rows * cycle.geometry.cols,
            full_pixels: cycle.geometry.full_rows * cycle.geometry.full_cols,
            rate_hz,
            cpu: Duration::ZERO,
        }
    }

    /// The same with the loop's measured CPU time for the reading.
    pub fn with_cpu(self, cpu: Duration) -> Self {
        Self { cpu, ..self }
    }

    /// Fraction of the array's pixels read out (scales the read-out energy).
    fn readout_fraction(&self) -> f64 {
        if self.full_pixels > 0 {
            self.pixels_read as f64 / self.full_pixels as f64
        } else {
            1.0
        }
    }
}

/// The accounting's decision for one cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnergyDecision {
    /// Sleep (sensor in reset) before the next cycle.
    pub sleep: Duration,
    /// Average power over the meter's window, this cycle included (mW).
    pub average_mw: f64,
}

/// The energy account of the loop.
#[derive(Debug, Clone)]
pub struct EnergyAccount {
    cfg: EnergyConfig,
    meter: EnergyMeter,
    pacing: Pacing,
    /// Captures whose reading is the next one's (a probe that saw a change).
    carried: Option<CycleObservation>,
}

impl EnergyAccount {
    /// New account.
    pub fn new(cfg: EnergyConfig, pacing: Pacing) -> Self {
        Self {
            meter: EnergyMeter::new(cfg.clone()),
            cfg,
            pacing,
            carried: None,
        }
    }

    /// A capture that belongs to the next reading (a presence probe that saw a change: the
    /// full reading follows at once): its energy and time are that reading's.
    pub fn carry(&mut self, obs: CycleObservation) {
        self.carried = Some(obs);
    }

    /// The meter (totals since start).
    pub fn meter(&self) -> &EnergyMeter {
        &self.meter
    }

    /// Decide the sleep after `obs` and account the cycle with it.
    pub fn next(&mut self, obs: CycleObservation) -> EnergyDecision {
        self.next_with(obs, None)
    }

    /// [`EnergyAccount::next`] for a reading that took a `second` capture (a second modulation
    /// frequency): both captures' energy and active time are the reading's, the sleep is the
    /// rest of the period after both.
    pub fn next_with(
        &mut self,
        obs: CycleObservation,
        second: Option<CycleObservation>,
    ) -> EnergyDecision {
        let carried = self.carried.take();
        let kind = match (carried.is_some(), second.is_some(), obs.raw_images) {
            (true, _, _) => ReadingKind::ProbeThenFull,
            (_, true, _) => ReadingKind::SecondFrequency,
            (_, _, 1) => ReadingKind::Probe,
            (_, _, k) if k >= 4 => ReadingKind::FourPhase,
            _ => ReadingKind::Full,
        };
        let extra = [second, carried]
            .into_iter()
            .flatten()
            .map(|s| (self.energy_of(&s), s.timings.active()))
            .fold(
                None,
                |acc: Option<(crate::energy::CycleEnergy, Duration)>, (e, t)| {
                    Some(acc.map_or((e, t), |(ae, at)| (ae.plus(&e), at + t)))
                },
            );
        let (extra_e, extra_active) = extra.unwrap_or_default();
        let active = obs.timings.active() + extra_active;
        let sleep = match self.pacing {
            Pacing::AsFastAsPossible => Duration::ZERO,
            Pacing::RealTime => Duration::from_secs_f64(1.0 / obs.rate_hz).saturating_sub(active),
        };
        let e = self.energy_of(&obs).plus(&extra_e);
        self.meter.record(kind, &e, active, sleep);
        EnergyDecision {
            sleep,
            average_mw: self.meter.average_mw(),
        }
    }

    fn energy_of(&self, obs: &CycleObservation) -> crate::energy::CycleEnergy {
        let work = CycleWork {
            raw_images: obs.raw_images,
            exposure_us: obs.exposure_us,
            readout_fraction: obs.readout_fraction(),
            cpu: obs.cpu,
        };
        cycle_energy(&self.cfg, &obs.timings, &work)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs(rows_read: usize) -> CycleObservation {
        CycleObservation {
            timings: CycleTimings {
                startup: Duration::from_millis(1),
                config_load: Duration::from_millis(10),
                exposure: Duration::from_micros(200),
                readout: Duration::from_millis(5),
                ..CycleTimings::default()
            },
            raw_images: 2,
            exposure_us: 100.0,
            pixels_read: rows_read * 160,
            full_pixels: 120 * 160,
            rate_hz: 2.0,
            cpu: Duration::ZERO,
        }
    }

    fn full_work() -> CycleWork {
        CycleWork {
            raw_images: 2,
            exposure_us: 100.0,
            readout_fraction: 1.0,
            cpu: Duration::ZERO,
        }
    }

    #[test]
    fn sleeps_the_rest_of_the_period_and_accounts_it() {
        let mut a = EnergyAccount::new(EnergyConfig::default(), Pacing::RealTime);
        let d = a.next(obs(120));
        let active = obs(120).timings.active();
        assert_eq!(d.sleep, Duration::from_millis(500) - active);
        let e = cycle_energy(&EnergyConfig::default(), &obs(120).timings, &full_work());
        let off_mj = EnergyConfig::default().off_mw * d.sleep.as_secs_f64();
        let want_mw = (e.total_mj() + off_mj) / 0.5;
        assert!(
            (d.average_mw - want_mw).abs() < 1e-9,
            "{} vs {want_mw}",
            d.average_mw
        );
        assert_eq!(a.meter().cycles(), 1);
    }

    #[test]
    fn unpaced_replay_never_sleeps() {
        let cfg = Config {
            backend: Backend::Replay,
            replay: crate::config::ReplayConfig {
                realtime: false,
                ..crate::config::ReplayConfig::default()
            },
            ..Config::default()
        };
        assert_eq!(Pacing::of(&cfg), Pacing::AsFastAsPossible);
        assert_eq!(Pacing::of(&Config::default()), Pacing::RealTime);
        let mut a = EnergyAccount::new(EnergyConfig::default(), Pacing::AsFastAsPossible);
        assert_eq!(a.next(obs(120)).sleep, Duration::ZERO);
    }

    #[test]
    fn a_second_frequency_capture_is_accounted_in_its_reading() {
        let mut one = EnergyAccount::new(EnergyConfig::default(), Pacing::RealTime);
        let mut two = EnergyAccount::new(EnergyConfig::default(), Pacing::RealTime);
        let d1 = one.next(obs(120));
        let d2 = two.next_with(obs(120), Some(obs(120)));
        let e = cycle_energy(&EnergyConfig::default(), &obs(120).timings, &full_work());
        let off_mj = |d: &EnergyDecision| EnergyConfig::default().off_mw * d.sleep.as_secs_f64();
        assert!(
            (two.meter().total_mj() - (2.0 * e.total_mj() + off_mj(&d2))).abs() < 1e-9,
            "two captures' energy in one reading"
        );
        assert!((one.meter().total_mj() - (e.total_mj() + off_mj(&d1))).abs() < 1e-9);
        assert_eq!(
            d1.sleep - d2.sleep,
            obs(120).timings.active(),
            "sleep after both"
        );
        assert_eq!(two.meter().cycles(), 1, "one reading");
        let kinds: Vec<_> = two.meter().kinds().map(|(k, t)| (k, t.cycles)).collect();
        assert_eq!(kinds, vec![(ReadingKind::SecondFrequency, 1)]);
    }

    /// A probe that saw a change is part of the full reading that follows: one reading with
    /// both captures' energy, the sleep after both.
    #[test]
    fn a_carried_probe_is_accounted_in_the_next_reading() {
        let mut a = EnergyAccount::new(EnergyConfig::default(), Pacing::RealTime);
        let probe = CycleObservation {
            raw_images: 1,
            exposure_us: 20.0,
            ..obs(120)
        };
        a.carry(probe);
        let d = a.next(obs(120));
        let w = |o: &CycleObservation| CycleWork {
            raw_images: o.raw_images,
            exposure_us: o.exposure_us,
            readout_fraction: 1.0,
            cpu: Duration::ZERO,
        };
        let cfg = EnergyConfig::default();
        let want = cycle_energy(&cfg, &probe.timings, &w(&probe)).total_mj()
            + cycle_energy(&cfg, &obs(120).timings, &w(&obs(120))).total_mj()
            + cfg.off_mw * d.sleep.as_secs_f64();
        assert!((a.meter().total_mj() - want).abs() < 1e-12);
        assert_eq!(a.meter().cycles(), 1);
        let kinds: Vec<_> = a.meter().kinds().map(|(k, t)| (k, t.cycles)).collect();
        assert_eq!(kinds, vec![(ReadingKind::ProbeThenFull, 1)]);
        a.next(probe);
        a.next(CycleObservation {
            raw_images: 4,
            ..obs(120)
        });
        let kinds: Vec<_> = a.meter().kinds().map(|(k, t)| (k, t.cycles)).collect();
        assert_eq!(
            kinds,
            vec![
                (ReadingKind::FourPhase, 1),
                (ReadingKind::Probe, 1),
                (ReadingKind::ProbeThenFull, 1)
            ]
        );
        assert_eq!(
            d.sleep,
            Duration::from_millis(500) - 2 * obs(120).timings.active()
        );
    }

    #[test]
    fn partial_readout_costs_less() {
        let mut full = EnergyAccount::new(EnergyConfig::default(), Pacing::RealTime);
        let mut part = EnergyAccount::new(EnergyConfig::default(), Pacing::RealTime);
        let f = full.next(obs(120)).average_mw;
        let p = part.next(obs(30)).average_mw;
        assert!(p < f, "a quarter of the rows: {p} < {f} mW");
    }

    /// The read-out is the pixels read (a window in rows and columns), and the reading's CPU
    /// time is accounted at the per-core power.
    #[test]
    fn readout_follows_the_pixels_read_and_cpu_is_accounted() {
        let cfg = EnergyConfig::default();
        let mut a = EnergyAccount::new(cfg.clone(), Pacing::AsFastAsPossible);
        let quarter = CycleObservation {
            pixels_read: 60 * 80,
            ..obs(120)
        };
        a.next(quarter.with_cpu(Duration::from_millis(1)));
        let e = cycle_energy(&cfg, &obs(120).timings, &full_work());
        let want = e.total_mj() - 0.75 * e.readout_mj + cfg.cpu_mw_per_core * 1e-3;
        assert!(
            (a.meter().total_mj() - want).abs() < 1e-12,
            "{} vs {want}",
            a.meter().total_mj()
        );
    }
}
