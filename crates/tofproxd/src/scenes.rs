//! The scene bench: the catalogue of scenes a phone meets
//! ([`tofprox_model::phone_scenes`], the one catalogue with its ground truth), each run
//! through the emulated device (frames from the physical model, the scene's cover window
//! in front of the sensor) and the daemon's real loop ([`Controller`], with its crosstalk
//! compensation and calibration) on a virtual clock, scored against the scene's truth
//! (`tofprox scenes`).
//!
//! The truth of a cycle is [`tofprox_model::PhoneScene::expect_in`] over the daemon's ROI at
//! the cycle's start and end (true radial distances: a wall beyond the unambiguous range is
//! far). Per scene: readings, false-near readings (Near published by a valid reading while the
//! truth has been far for longer than the far debounce may take), missed-near readings (Near
//! not published although the truth has been near longer than Android's latency allowance:
//! 100 ms + 2 sample periods), the worst latency to near (truth near → Near) and to far
//! (truth far → far published), the modelled energy per reading, and the controller's
//! verdict on the cover window ([`tofprox_core::crosstalk::CrosstalkStatus`]).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;
use tofprox_bridge::{
    Clock, EmulatedConfig, SensorDriver, VirtualClock, emulated::FrameSource as SynthSource,
};
use tofprox_core::crosstalk::CrosstalkStatus;
use tofprox_model::{CoverWindow, Expect, PhoneScene, SceneScript};

use crate::backends::chain;
use crate::config::Config;
use crate::controller::{Controller, ModeCalibrations, full_roi};
use crate::energy::{EnergyMeter, ReadingKind};

/// The bench's set-up: the daemon's configuration (with `processing.calibration` the
/// sensor's calibration set) and the physical model of the emulated sensor.
#[derive(Debug, Clone)]
pub struct Bench {
    /// Daemon configuration the loop runs with.
    pub config: Config,
    /// Model file of the emulated sensor (the phone sensor: `config/model/phone.toml`).
    pub model: PathBuf,
}

/// What the bench measured for one scene (`tofprox scenes --json`).
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct SceneResult {
    /// Scene name (`tofprox_model::phone_scenes`).
    pub name: String,
    /// Cycles run.
    pub cycles: u64,
    /// Valid readings.
    pub readings: u64,
    /// Valid readings that published Near while the truth was far.
    pub false_near: u64,
    /// Readings without Near while the truth had been near longer than the allowance.
    pub missed_near: u64,
    /// Worst latency truth-near → Near (ms), if the truth became near and Near followed.
    pub latency_to_near_ms: Option<f64>,
    /// Worst latency truth-far → far (ms), if the truth left and far followed.
    pub latency_to_far_ms: Option<f64>,
    /// Modelled energy per reading (mJ, thesis table 3.1 model).
    pub energy_per_reading_mj: f64,
    /// The same by part: where the scene's energy goes (mJ per reading).
    pub energy_parts_mj: EnergyParts,
    /// Cycles and mean energy by kind of reading (full, probe, confirmation, …).
    pub energy_by_kind: Vec<KindEnergy>,
    /// Near transitions published.
    pub near_transitions: u64,
    /// The controller's cover-window verdict at the end (`CrosstalkStatus::message`).
    pub cover_window: String,
    /// The cover window was reported changed (a smudge) at the end.
    pub cover_window_changed: bool,
}

/// Mean energy per reading by part (mJ; `energy::cycle_energy`'s parts and the sleep in
/// reset), summing to [`SceneResult::energy_per_reading_mj`].
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct EnergyParts {
    /// Start-up and the imager bring-up's waits.
    pub startup: f64,
    /// Flash load (and write).
    pub flash: f64,
    /// Illuminated exposure.
    pub capture: f64,
    /// Read-out of the pixels read.
    pub readout: f64,
    /// The daemon's CPU time.
    pub cpu: f64,
    /// Held in reset between readings.
    pub off: f64,
}

/// One kind of reading in a scene: how many and what each cost on average.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct KindEnergy {
    /// The kind.
    pub kind: ReadingKind,
    /// Cycles of that kind.
    pub cycles: u64,
    /// Their mean energy (mJ, the sleep after each included).
    pub mean_mj: f64,
}

/// Per-reading parts and kinds of a meter's totals.
fn breakdown(meter: &EnergyMeter) -> (EnergyParts, Vec<KindEnergy>) {
    let n = meter.cycles().max(1) as f64;
    let (p, off_mj) = meter.parts_total();
    let parts = EnergyParts {
        startup: p.startup_mj / n,
        flash: p.flash_mj / n,
        capture: p.capture_mj / n,
        readout: p.readout_mj / n,
        cpu: p.cpu_mj / n,
        off: off_mj / n,
    };
    let kinds = meter
        .kinds()
        .map(|(kind, t)| KindEnergy {
            kind,
            cycles: t.cycles,
            mean_mj: t.total_mj / t.cycles.max(1) as f64,
        })
        .collect();
    (parts, kinds)
}

/// Errors setting up the bench.
#[derive(Debug, thiserror::Error)]
#[error("scene bench: {0}")]
pub struct ScenesError(String);

/// Truth over one cycle: near when it is near at its start or end, far when far at both.
fn cycle_truth(a: Expect, b: Expect) -> Expect {
    if a == Expect::Near || b == Expect::Near {
        Expect::Near
    } else if a == Expect::Far && b == Expect::Far {
        Expect::Far
    } else {
        Expect::Either
    }
}

/// Run one scene through the emulated device and the daemon loop on virtual time.
/// The calibration is `bench.config.processing.calibration` (loaded as the daemon does).
pub fn run_scene(bench: &Bench, scene: &PhoneScene, seed: u64) -> Result<SceneResult, ScenesError> {
    let cfg = &bench.config;
    let err = |e: String| ScenesError(format!("{}: {e}", scene.name));
    scene.script.validate().map_err(|e| err(e.to_string()))?;
    let dev_cfg = EmulatedConfig {
        frame_source: SynthSource::Model,
        model: Some(bench.model.clone()),
        scene: scene.script.clone(),
        cover_window: Some(scene.cover_window),
        ambient_klux: scene.ambient_klux,
        ..EmulatedConfig::default()
    };
    let vclock = Arc::new(VirtualClock::new());
    let clock: Arc<dyn Clock> = vclock.clone();
    let source = crate::backends::emulated::bridge_source(
        dev_cfg,
        clock.clone(),
        seed,
        "emulated (scene bench)",
    )
    .map_err(|e| err(chain(&e)))?;
    let geometry = source.driver().config().map.sensor.geometry();
    let (full_rows, full_cols) = (geometry.full_rows, geometry.full_cols);
    let mut calib: ModeCalibrations =
        crate::calibration::load_for(cfg, &source).map_err(|e| err(e.to_string()))?;
    if scene.calibrated_window != CoverWindow::default() {
        calibrate_crosstalk_behind(bench, scene, seed, &mut calib).map_err(err)?;
    }
    let mut ctl = Controller::new(cfg.clone(), source, calib).map_err(|e| err(e.to_string()))?;

    let near_m = f64::from(cfg.proximity.near_mm) / 1e3;
    let far_m = f64::from(cfg.proximity.far_mm) / 1e3;
    let roi = full_roi(cfg, full_rows, full_cols);
    let truth = |t: f64| {
        scene.expect_in(
            t,
            near_m,
            far_m,
            roi.row0..roi.row0 + roi.rows,
            roi.col0..roi.col0 + roi.cols,
        )
    };
    let mut r = SceneResult {
        name: scene.name.to_string(),
        ..SceneResult::default()
    };
    let mut published_near = false;
    let mut near_since: Option<f64> = None; // truth near since
    let mut far_since: Option<f64> = None; // truth far since
    let mut waiting_near: Option<f64> = None; // truth became near, Near not yet published
    let mut waiting_far: Option<f64> = None; // truth left, far not yet published
    let mut worst_near: Option<f64> = None;
    let mut worst_far: Option<f64> = None;
    let mut last_period_s = 1.0 / cfg.loop_.rate_hz;
    // the far debounce may take this long after the truth left (at the slowest rate)
    let debounce_s = f64::from(cfg.proximity.far_debounce + 1) / cfg.loop_.slow_rate_hz;
    while clock.now().as_secs_f64() < scene.duration_s {
        let t0 = clock.now().as_secs_f64();
        let out = ctl.step(false);
        let t1 = clock.now().as_secs_f64();
        r.cycles += 1;
        let now = cycle_truth(truth(t0), truth(t1));
        if now == Expect::Near {
            near_since.get_or_insert(t0);
        } else {
            near_since = None;
        }
        if now == Expect::Far {
            far_since.get_or_insert(t0);
        } else {
            far_since = None;
        }
        if out.valid {
            r.readings += 1;
        }
        if out.near && out.valid && far_since.is_some_and(|s| t1 - s > debounce_s) {
            r.false_near += 1;
        }
        let allowance_s = 0.1 + 2.0 * last_period_s;
        if !out.near && near_since.is_some_and(|s| t1 - s > allowance_s) {
            r.missed_near += 1;
        }
        // latencies
        if near_since.is_some() && !published_near && waiting_near.is_none() {
            waiting_near = near_since;
        }
        if far_since.is_some() && published_near && waiting_far.is_none() {
            waiting_far = far_since;
        }
        if out.near != published_near {
            r.near_transitions += 1;
            published_near = out.near;
            let (done, other) = if out.near {
                (waiting_near.take(), &mut worst_near)
            } else {
                (waiting_far.take(), &mut worst_far)
            };
            if let Some(s) = done {
                let l = (t1 - s) * 1e3;
                *other = Some(other.map_or(l, |w: f64| w.max(l)));
            }
            if out.near {
                waiting_far = None;
            } else {
                waiting_near = None;
            }
        }
        if near_since.is_none() {
            waiting_near = None;
        }
        if far_since.is_none() {
            waiting_far = None;
        }
        last_period_s = (t1 - t0 + out.sleep.as_secs_f64()).max(1e-3);
        clock.sleep(out.sleep.max(Duration::from_millis(1)));
    }
    r.latency_to_near_ms = worst_near;
    r.latency_to_far_ms = worst_far;
    r.energy_per_reading_mj = ctl.energy().total_mj() / (ctl.energy().cycles().max(1) as f64);
    (r.energy_parts_mj, r.energy_by_kind) = breakdown(ctl.energy());
    let window = ctl.crosstalk_status();
    r.cover_window = window.message();
    r.cover_window_changed = matches!(window, CrosstalkStatus::Changed { .. });
    Ok(r)
}

/// Exposure (µs) and count of the nothing-in-range captures the crosstalk is measured from,
/// as `calib/phone/make.sh` takes them (the daemon's longest exposure).
const CROSSTALK_CAPTURE: (f64, usize) = (500.0, 8);

/// The crosstalk part for a sensor built behind `scene.calibrated_window`, measured as the
/// phone line does (`docs/calibration.md`: illuminated 4-phase captures with nothing in range,
/// `extract_crosstalk` against the set's offset) and put in place of the set's.
fn calibrate_crosstalk_behind(
    bench: &Bench,
    scene: &PhoneScene,
    seed: u64,
    calib: &mut ModeCalibrations,
) -> Result<(), String> {
    use tofprox_core::crosstalk::{CrosstalkCapture, extract_crosstalk};
    let dev_cfg = EmulatedConfig {
        frame_source: SynthSource::Model,
        model: Some(bench.model.clone()),
        scene: SceneScript::wall(30.0),
        cover_window: Some(scene.calibrated_window),
        ..EmulatedConfig::default()
    };
    let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
    let mut driver = SensorDriver::emulated(dev_cfg, clock, seed).map_err(|e| chain(&e))?;
    let (exposure_us, count) = CROSSTALK_CAPTURE;
    let req = tofprox_bridge::CycleRequest {
        mode: tofprox_bridge::SensorMode::Depth(tofprox_core::Algorithm::FourPhase),
        exposure_us,
        row_window: None,
        modulation_hz: None,
        single_image: None,
    };
    let mut outs = Vec::with_capacity(count);
    for _ in 0..count {
        let o = driver.cycle(&req).map_err(|e| chain(&e))?;
        outs.push((o.frames.mapv(f64::from), o.phases_deg, o.exposure_us));
    }
    let captures: Vec<CrosstalkCapture<'_>> = outs
        .iter()
        .map(|(codes, phases_deg, exposure_us)| CrosstalkCapture {
            codes: codes.view(),
            phases_deg,
            exposure_us: *exposure_us,
        })
        .collect();
    let adc_bits = driver.config().map.sensor.adc_bits;
    let offset = calib.four_phase.offset.as_ref();
    let x = extract_crosstalk(&captures, offset, adc_bits).map_err(|e| e.to_string())?;
    calib.two_phase.crosstalk = Some(x.clone());
    calib.four_phase.crosstalk = Some(x);
    Ok(())
}

/// The catalogue for `cfg`'s thresholds (`tofprox_model::phone_scenes`).
pub fn catalogue(cfg: &Config) -> Vec<PhoneScene> {
    tofprox_model::phone_scenes(
        f64::from(cfg.proximity.near_mm) / 1e3,
        f64::from(cfg.proximity.far_mm) / 1e3,
    )
}

/// The bench with the shipped defaults (`Config::default()` = `config/tofproxd.toml`) on the
/// emulated backend, the phone sensor's model (`model`) and, when given, its calibration set.
pub fn bench(model: &Path, calibration: Option<&Path>) -> Bench {
    let mut config = Config {
        backend: crate::config::Backend::Emulated,
        ..Config::default()
    };
    config.processing.calibration = calibration.map(Path::to_path_buf);
    Bench {
        config,
        model: model.to_path_buf(),
    }
}
