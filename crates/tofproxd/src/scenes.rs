//! The scene bench: a catalogue of scenes a phone meets, each run through the
//! emulated device (frames from the physical model) and the daemon's real loop
//! ([`Controller`]) on a virtual clock, scored against the scene's scripted truth
//! (`tofprox scenes`).
//!
//! Per scene: readings, false-near readings (Near published by a valid reading
//! while the truth was beyond `far_mm` for the whole debounce window), missed-near
//! readings (Near not published although the truth has been at or below
//! `near_mm` longer than Android's latency allowance: 100 ms + 2 sample
//! periods), the worst latency to near (truth enters `near_mm` → Near) and to far
//! (truth leaves beyond `far_mm` → far), and the modelled energy per reading.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;
use tofprox_bridge::{
    Clock, DriverConfig, EmulatedConfig, EmulatedDevice, SensorDriver, VirtualClock,
    emulated::FrameSource as SynthSource,
};
use tofprox_model::{SceneScript, ScriptKind};

use crate::backends::{BridgeSource, chain};
use crate::config::Config;
use crate::controller::{Controller, ModeCalibrations};

/// One scene of the catalogue.
#[derive(Debug, Clone)]
pub struct SceneSpec {
    /// Short name.
    pub name: String,
    /// The scripted scene.
    pub script: SceneScript,
    /// Background light (klux).
    pub ambient_klux: f64,
    /// Virtual seconds to run.
    pub seconds: f64,
}

/// Margin (m) beyond `far_mm` for a truth to count as far (scripted edges, depth noise).
const FAR_MARGIN_M: f64 = 0.05;
/// Margin (m) below `near_mm` for a truth to count as near.
const NEAR_MARGIN_M: f64 = 0.01;

fn wall(name: &str, distance_m: f64, reflectivity: f64) -> SceneSpec {
    SceneSpec {
        name: name.to_string(),
        script: SceneScript {
            kind: ScriptKind::Wall,
            wall_distance_m: distance_m,
            wall_reflectivity: reflectivity,
            near_m: 0.01,
            far_m: 0.02,
            ..SceneScript::default()
        },
        ambient_klux: 0.0,
        seconds: 6.0,
    }
}

fn hand(name: &str, near_m: f64, reflectivity: f64, period_s: f64, wall_m: f64) -> SceneSpec {
    SceneSpec {
        name: name.to_string(),
        script: SceneScript {
            kind: ScriptKind::Hand,
            wall_distance_m: wall_m,
            wall_reflectivity: 0.8,
            object_reflectivity: reflectivity,
            near_m,
            far_m: 0.6,
            period_s,
            ..SceneScript::default()
        },
        ambient_klux: 0.0,
        seconds: 2.0 * period_s,
    }
}

fn face(name: &str, distance_m: f64, reflectivity: f64) -> SceneSpec {
    SceneSpec {
        name: name.to_string(),
        script: SceneScript {
            kind: ScriptKind::Face,
            wall_distance_m: 1.2,
            object_reflectivity: reflectivity,
            face_distance_m: distance_m,
            near_m: 0.01,
            far_m: 0.02,
            period_s: 4.0,
            ..SceneScript::default()
        },
        ambient_klux: 0.0,
        seconds: 4.0,
    }
}

/// The catalogue (≥ 20 scenes): walls and ceilings from 0.3 to 4 m, white (0.9) and dark
/// (0.1), including just beyond the unambiguous range (1.874 m at 80 MHz) and twice it
/// (3.75–3.9 m); nothing in range; a hand (skin 0.5) and dark hair (0.1) approaching to
/// 2–5 cm; faces at 5–30 cm; a fast swipe; background light 30 and 100 klux.
pub fn catalogue() -> Vec<SceneSpec> {
    let mut v = vec![
        wall("white wall 0.3 m", 0.3, 0.9),
        wall("white wall 1 m", 1.0, 0.9),
        wall("white ceiling 1.8 m", 1.8, 0.9),
        wall("white wall 1.95 m (just beyond range)", 1.95, 0.9),
        wall("white wall 2.2 m", 2.2, 0.9),
        wall("white wall 3.0 m", 3.0, 0.9),
        wall("white wall 3.8 m (beyond twice the range)", 3.8, 0.9),
        wall("white wall 4.0 m", 4.0, 0.9),
        wall("dark wall 0.3 m", 0.3, 0.1),
        wall("dark wall 1.95 m", 1.95, 0.1),
        wall("nothing in range (8 m)", 8.0, 0.5),
        hand("hand to 5 cm", 0.05, 0.5, 8.0, 1.0),
        hand("hand to 2 cm", 0.02, 0.5, 8.0, 1.0),
        hand("dark hair to 3 cm", 0.03, 0.1, 8.0, 1.0),
        hand("hand to 5 cm, ceiling at 1.95 m", 0.05, 0.5, 8.0, 1.95),
        hand("fast swipe to 5 cm", 0.05, 0.5, 1.5, 1.0),
        face("face at 5 cm", 0.05, 0.5),
        face("face at 20 cm", 0.2, 0.5),
        face("face at 30 cm", 0.3, 0.5),
    ];
    let mut sun_far = wall("white wall 1.95 m, 30 klux", 1.95, 0.9);
    sun_far.ambient_klux = 30.0;
    v.push(sun_far);
    let mut sun_far = wall("white wall 1 m, 100 klux", 1.0, 0.9);
    sun_far.ambient_klux = 100.0;
    v.push(sun_far);
    let mut sun_hand = hand("hand to 5 cm, 100 klux", 0.05, 0.5, 8.0, 1.0);
    sun_hand.ambient_klux = 100.0;
    v.push(sun_hand);
    v
}

/// What the bench measured for one scene (`tofprox scenes --json`).
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct SceneResult {
    /// Scene name.
    pub name: String,
    /// Cycles run.
    pub cycles: u64,
    /// Valid readings.
    pub readings: u64,
    /// Valid readings that published Near while the truth was far.
    pub false_near: u64,
    /// Readings without Near while the truth had been near longer than the allowance.
    pub missed_near: u64,
    /// Worst latency truth-near → Near (ms), if the truth became near.
    pub latency_to_near_ms: Option<f64>,
    /// Worst latency truth-far → far (ms), if the truth left.
    pub latency_to_far_ms: Option<f64>,
    /// Modelled energy per reading (mJ, thesis table 3.1 model).
    pub energy_per_reading_mj: f64,
    /// Near transitions published.
    pub near_transitions: u64,
}

/// Errors setting up the bench.
#[derive(Debug, thiserror::Error)]
#[error("scene bench: {0}")]
pub struct ScenesError(String);

/// Run one scene through the emulated device and the daemon loop on virtual time.
/// The calibration is `cfg.processing.calibration` (loaded as the daemon does).
pub fn run_scene(cfg: &Config, spec: &SceneSpec, seed: u64) -> Result<SceneResult, ScenesError> {
    spec.script
        .validate()
        .map_err(|e| ScenesError(format!("{}: {e}", spec.name)))?;
    let dev_cfg = EmulatedConfig {
        frame_source: SynthSource::Model,
        scene: spec.script.clone(),
        ambient_klux: spec.ambient_klux,
        ..EmulatedConfig::default()
    };
    let vclock = Arc::new(VirtualClock::new());
    let clock: Arc<dyn Clock> = vclock.clone();
    let map = dev_cfg.sensor_map().map_err(|e| ScenesError(chain(&e)))?;
    let dev = EmulatedDevice::new(dev_cfg.clone(), clock.clone(), seed)
        .map_err(|e| ScenesError(chain(&e)))?;
    let dcfg = DriverConfig {
        protocol: dev_cfg.protocol.clone(),
        map,
        ..DriverConfig::emulated_default()
    };
    let driver = SensorDriver::new(dev, dcfg, clock.clone()).map_err(|e| ScenesError(chain(&e)))?;
    let source = BridgeSource::new(driver, clock.clone(), "emulated (scene bench)");
    let calib: ModeCalibrations =
        crate::calibration::load_for(cfg, &source).map_err(|e| ScenesError(e.to_string()))?;
    let mut ctl =
        Controller::new(cfg.clone(), source, calib).map_err(|e| ScenesError(e.to_string()))?;

    let near_m = f64::from(cfg.proximity.near_mm) / 1e3;
    let far_m = f64::from(cfg.proximity.far_mm) / 1e3;
    let script = &spec.script;
    let truth = |t: f64| script.centre_distance_m(t);
    let mut r = SceneResult {
        name: spec.name.clone(),
        ..SceneResult::default()
    };
    let mut published_near = false;
    let mut near_since: Option<f64> = None; // truth at or below near_mm since
    let mut far_since: Option<f64> = None; // truth beyond far_mm (+margin) since
    let mut waiting_near: Option<f64> = None; // truth became near, Near not yet published
    let mut waiting_far: Option<f64> = None; // truth left, far not yet published
    let mut worst_near: Option<f64> = None;
    let mut worst_far: Option<f64> = None;
    let mut last_period_s = 1.0 / cfg.loop_.rate_hz;
    while clock.now().as_secs_f64() < spec.seconds {
        let t0 = clock.now().as_secs_f64();
        let out = ctl.step(false);
        let t1 = clock.now().as_secs_f64();
        r.cycles += 1;
        // Truth at the cycle's capture (its start and end).
        let d = truth(t0).min(truth(t1));
        let d_far = truth(t0).max(truth(t1));
        if d <= near_m - NEAR_MARGIN_M {
            near_since.get_or_insert(t0);
        } else {
            near_since = None;
        }
        if d_far >= far_m + FAR_MARGIN_M && d >= far_m + FAR_MARGIN_M {
            far_since.get_or_insert(t0);
        } else {
            far_since = None;
        }
        if out.valid {
            r.readings += 1;
        }
        // false near: a valid reading publishes Near while the truth has been far for
        // the whole debounce (the time the far debounce may legitimately take).
        let debounce_s = f64::from(cfg.proximity.far_debounce + 1) / cfg.loop_.slow_rate_hz;
        if out.near && out.valid && far_since.is_some_and(|s| t1 - s > debounce_s) {
            r.false_near += 1;
        }
        // missed near: truth near for longer than Android's allowance, Near not published.
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
            if out.near {
                if let Some(s) = waiting_near.take() {
                    let l = (t1 - s) * 1e3;
                    worst_near = Some(worst_near.map_or(l, |w: f64| w.max(l)));
                }
                waiting_far = None;
            } else {
                if let Some(s) = waiting_far.take() {
                    let l = (t1 - s) * 1e3;
                    worst_far = Some(worst_far.map_or(l, |w: f64| w.max(l)));
                }
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
    Ok(r)
}

/// Run the whole catalogue with `cfg`.
pub fn run_catalogue(cfg: &Config, seed: u64) -> Result<Vec<SceneResult>, ScenesError> {
    catalogue()
        .iter()
        .map(|s| run_scene(cfg, s, seed))
        .collect()
}

/// The daemon configuration the bench runs by default: the shipped defaults
/// (`config/tofproxd.toml`) with the emulated backend and, when given, a calibration set.
pub fn bench_config(calibration: Option<&Path>) -> Config {
    let mut cfg = Config {
        backend: crate::config::Backend::Emulated,
        ..Config::default()
    };
    cfg.processing.calibration = calibration.map(Path::to_path_buf);
    cfg
}
