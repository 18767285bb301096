//! Soak: the daemon's loop against the emulated device with injected faults on
//! a virtual clock (no real sleeps), checking what must hold: no false near, no
//! panic, recovery within a few cycles, flat memory.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;
use tofprox_bridge::emulated::FrameSource as SynthSource;
use tofprox_bridge::{Clock, EmulatedConfig, VirtualClock, emulated::FaultConfig};
use tofprox_model::SceneScript;

use crate::backends::chain;
use crate::config::Config;
use crate::controller::{Controller, ModeCalibrations};

/// Soak parameters.
#[derive(Debug, Clone)]
pub struct SoakConfig {
    /// Cycles to run.
    pub cycles: u64,
    /// Share of cycles with an injected fault (spread over every fault kind).
    pub fault_rate: f64,
    /// Seed of noise and fault draws.
    pub seed: u64,
    /// Hand loop period (s, virtual time).
    pub period_s: f64,
}

impl Default for SoakConfig {
    fn default() -> Self {
        Self {
            cycles: 10_000,
            fault_rate: 0.05,
            seed: 1,
            period_s: 8.0,
        }
    }
}

/// The soak's result (`tofprox soak --json`).
#[derive(Debug, Clone, Default, Serialize, PartialEq, Eq)]
pub struct SoakReport {
    /// Cycles run.
    pub cycles: u64,
    /// Faults the emulated device injected.
    pub faults_injected: u64,
    /// Failure episodes that ended in a good reading.
    pub recovered: u64,
    /// Valid readings that published Near while the scripted truth was beyond the far threshold
    /// for the whole debounce window (the last `far_debounce + 2` valid readings): switched to
    /// (or kept) near on a wrong reading. Must be 0.
    pub false_near: u64,
    /// Failed cycles across which a Near of a hand that has since left was held (bounded by
    /// `loop.near_hold_ms`; the safe side, counted apart from `false_near`).
    pub held_over_failure: u64,
    /// Longest time (ms, virtual) Near was held across failures without a valid reading.
    pub max_hold_ms: u64,
    /// Panics caught in the loop.
    pub panics: u64,
    /// Longest recovery: cycles from the last injected fault of an episode to the next good reading.
    pub max_recovery_cycles: u64,
    /// RSS after warm-up (kB).
    pub rss_kb_start: u64,
    /// RSS at the end (kB).
    pub rss_kb_end: u64,
    /// Cycles that failed.
    pub failed_cycles: u64,
    /// Near transitions seen.
    pub near_transitions: u64,
    /// Failure episodes still open at the end.
    pub unrecovered: u64,
    /// Failed cycles by the loop's error kind (`disconnected`, `timeout`, …): the summary of
    /// what the daemon would have logged one warning each for.
    pub failures_by_kind: std::collections::BTreeMap<String, u64>,
}

/// Resident set size of this process (kB), 0 if unknown.
pub fn rss_kb() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse().ok())
        })
        .unwrap_or(0)
}

/// Errors setting up the soak.
#[derive(Debug, thiserror::Error)]
#[error("soak setup: {0}")]
pub struct SoakError(String);

/// Run the soak; `on_cycle(done)` is called after every cycle (progress display).
pub fn run(sc: &SoakConfig, mut on_cycle: impl FnMut(u64)) -> Result<SoakReport, SoakError> {
    if !(sc.fault_rate.is_finite() && (0.0..=1.0).contains(&sc.fault_rate)) {
        return Err(SoakError(format!(
            "fault rate {} must be within 0..=1",
            sc.fault_rate
        )));
    }
    let scene = SceneScript {
        period_s: sc.period_s,
        ..SceneScript::hand()
    };
    let dev_cfg = EmulatedConfig {
        frame_source: SynthSource::Ideal,
        scene: scene.clone(),
        faults: FaultConfig::uniform(sc.fault_rate),
        ..EmulatedConfig::default()
    };
    let vclock = Arc::new(VirtualClock::new());
    let clock: Arc<dyn Clock> = vclock.clone();
    let source = crate::backends::emulated::bridge_source(
        dev_cfg,
        clock.clone(),
        sc.seed,
        "emulated (soak)",
    )
    .map_err(|e| SoakError(chain(&e)))?;
    let mut cfg = Config::default();
    // A small ROI (and row window around it) keeps each cycle cheap.
    cfg.proximity.roi = Some([78, 92, 16, 40]);
    cfg.proximity.near_mm = 150;
    cfg.proximity.far_mm = 250;
    cfg.loop_.retry_ms = 100;
    let far_m = f64::from(cfg.proximity.far_mm) / 1e3;
    let window = cfg.proximity.far_debounce as usize + 2;
    let mut ctl = Controller::new(cfg, source, ModeCalibrations::default())
        .map_err(|e| SoakError(e.to_string()))?;

    let mut rep = SoakReport::default();
    let mut truth: std::collections::VecDeque<f64> =
        std::collections::VecDeque::with_capacity(window + 1);
    let mut in_episode = false;
    let mut since_last_fault: u64 = 0;
    let mut last_near = false;
    let mut faults_before = 0u64;
    // Virtual time of the first cycle without a valid reading while Near was published.
    let mut hold_started: Option<f64> = None;
    for i in 0..sc.cycles {
        if i == 20 {
            rep.rss_kb_start = rss_kb();
        }
        let t_before = clock.now().as_secs_f64();
        let out = catch_unwind(AssertUnwindSafe(|| ctl.step(false)));
        let t_after = clock.now().as_secs_f64();
        rep.cycles += 1;
        on_cycle(rep.cycles);
        let faults_now = ctl.source().driver().transport().stats().faults_injected;
        let injected = faults_now.saturating_sub(faults_before);
        faults_before = faults_now;
        rep.faults_injected += injected;
        let Ok(out) = out else {
            rep.panics += 1;
            clock.sleep(Duration::from_millis(100));
            continue;
        };
        // Truth: the scripted centre distance during the cycle (closest of its start and end).
        let d = scene
            .centre_distance_m(t_before)
            .min(scene.centre_distance_m(t_after));
        // The window is over valid readings: the far debounce counts readings, and a failed
        // cycle between them neither advances nor breaks it.
        if out.valid {
            truth.push_back(d);
            while truth.len() > window {
                truth.pop_front();
            }
        }
        let truth_far = truth.len() == window && truth.iter().all(|&d| d > far_m + 0.05);
        if out.near && truth_far && d > far_m + 0.05 {
            if out.valid {
                rep.false_near += 1;
            } else {
                rep.held_over_failure += 1;
            }
        }
        if out.valid || !out.near {
            hold_started = None;
        } else {
            let t0 = *hold_started.get_or_insert(t_before);
            let held_ms = ((t_after - t0) * 1e3).round() as u64;
            rep.max_hold_ms = rep.max_hold_ms.max(held_ms);
        }
        if out.near != last_near {
            rep.near_transitions += 1;
            last_near = out.near;
        }
        if injected > 0 {
            since_last_fault = 0;
        }
        if let Some(e) = &out.error {
            rep.failed_cycles += 1;
            *rep.failures_by_kind
                .entry(e.kind().as_str().to_string())
                .or_default() += 1;
            if !in_episode {
                in_episode = true;
            }
            if injected == 0 {
                since_last_fault += 1;
            }
        } else if in_episode {
            in_episode = false;
            rep.recovered += 1;
            rep.max_recovery_cycles = rep.max_recovery_cycles.max(since_last_fault + 1);
            since_last_fault = 0;
        }
        clock.sleep(out.sleep);
    }
    rep.unrecovered = u64::from(in_episode);
    rep.rss_kb_end = rss_kb();
    Ok(rep)
}
