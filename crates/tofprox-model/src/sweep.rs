//! Planned simulations: a calibration-session-like sweep, the conditions of a recording, and
//! running a plan through the [`Simulator`] into frames or a recording — the one
//! implementation behind `tofprox sim sweep|scene` and Python's `tofprox.simulate/sweep`.
//!
//! A sweep is what a calibration session records (thesis 5.1): dark frames per exposure and
//! temperature (offset and fixed-pattern extraction, 2.3.1.3), one 24-phase correlation
//! capture at a known distance (3.3.6), then distance sweeps over exposures, ambient light and
//! temperature, with the ground truth in each capture's conditions. Every capture draws its
//! noise from its own seed ([`capture_rng`]), so the output is the same for any thread count.

use std::collections::{BTreeMap, BTreeSet};

use rand::SeedableRng;
use rand::rngs::SmallRng;
use rayon::prelude::*;
use tofprox_format::{CaptureSpec, FormatError, RawFrames, Recording, RecordingWriter};

use crate::{CaptureRequest, ModelError, Scene, Simulator};

/// The most distances a sweep takes from one `FROM:TO:STEP` range.
pub const MAX_DISTANCES: usize = 100_001;
/// The most repeated captures per condition.
pub const MAX_REPEATS: u32 = 10_000;

/// One capture to simulate: what the sensor does, what it sees, and the conditions written to
/// the recording (`[capture.conditions]`: the ground truth and any copied ones).
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedCapture {
    /// What the sensor does.
    pub request: CaptureRequest,
    /// What it sees.
    pub scene: Scene,
    /// The capture's `[capture.conditions]`.
    pub conditions: BTreeMap<String, f64>,
}

impl PlannedCapture {
    /// A capture of a flat wall at `distance_m` with `reflectivity`, its conditions the
    /// model's inputs (distance, reflectivity, ambient light, temperature).
    pub fn wall(request: CaptureRequest, distance_m: f64, reflectivity: f64) -> Self {
        let conditions = [
            ("distance_m", distance_m),
            ("reflectivity", reflectivity),
            ("ambient_klux", request.ambient_klux),
            ("temperature_c", request.temperature_c),
        ];
        PlannedCapture {
            scene: Scene::wall(distance_m, reflectivity),
            conditions: conditions
                .iter()
                .map(|(k, v)| (k.to_string(), *v))
                .chain(request.conditions.iter().map(|(k, v)| (k.clone(), *v)))
                .collect(),
            request,
        }
    }

    /// The capture as a recording's `[[capture]]` (no timestamp).
    pub fn spec(&self) -> CaptureSpec {
        CaptureSpec {
            phases_deg: self.request.phases_deg.clone(),
            exposure_us: self.request.exposure_us,
            illumination: self.request.illumination,
            averaged: self.request.averaged,
            timestamp_ns: None,
            conditions: self.conditions.clone(),
        }
    }
}

/// The phase shifts of `n` raw images: 2 (0°, 90°), 4 (0°, 90°, 180°, 270°) or 24 (every 15°,
/// the correlation capture of 3.3.6).
pub fn phases_for(n: usize) -> Result<Vec<f64>, ModelError> {
    Ok(match n {
        2 => vec![0.0, 90.0],
        4 => vec![0.0, 90.0, 180.0, 270.0],
        24 => (0..24).map(|k| 15.0 * k as f64).collect(),
        other => {
            return Err(ModelError::invalid(format!(
                "phases {other}: allowed 2, 4 or 24"
            )));
        }
    })
}

/// The distances `from, from + step, …` up to `to` (inclusive, within 1e-9 steps).
pub fn distance_range(from_m: f64, to_m: f64, step_m: f64) -> Result<Vec<f64>, ModelError> {
    let ok = step_m.is_finite() && step_m > 0.0 && from_m.is_finite() && to_m.is_finite();
    if !(ok && to_m >= from_m) {
        return Err(ModelError::invalid(format!(
            "distances {from_m}:{to_m}:{step_m}: need STEP > 0 and TO ≥ FROM"
        )));
    }
    let n = ((to_m - from_m) / step_m + 1e-9).floor() as usize;
    if n >= MAX_DISTANCES {
        return Err(ModelError::invalid(format!(
            "distances {from_m}:{to_m}:{step_m} give {} points, at most {MAX_DISTANCES}",
            n + 1
        )));
    }
    Ok((0..=n).map(|i| from_m + step_m * i as f64).collect())
}

/// A calibration-session-like sweep (the defaults of `tofprox sim sweep`).
#[derive(Debug, Clone, PartialEq)]
pub struct SweepPlan {
    /// Target distances of the illuminated captures.
    pub distances_m: Vec<f64>,
    /// Exposure times per raw image.
    pub exposures_us: Vec<f64>,
    /// Raw images per capture: 2, 4 or 24.
    pub phases: usize,
    /// Ambient light levels.
    pub ambient_klux: Vec<f64>,
    /// Sensor temperatures.
    pub temperatures_c: Vec<f64>,
    /// The target's reflectivity.
    pub reflectivity: f64,
    /// Repeated captures per condition.
    pub repeats: u32,
    /// Acquisitions averaged per capture (1: single acquisitions).
    pub averaged: u32,
    /// Distance of the 24-phase correlation capture.
    pub correlation_distance_m: f64,
}

impl Default for SweepPlan {
    fn default() -> Self {
        SweepPlan {
            distances_m: (0..=33).map(|i| 0.15 + 0.05 * f64::from(i)).collect(),
            exposures_us: vec![500.0, 1000.0],
            phases: 4,
            ambient_klux: vec![0.0],
            temperatures_c: vec![25.0],
            reflectivity: 0.9,
            repeats: 1,
            averaged: 1,
            correlation_distance_m: 1.0,
        }
    }
}

impl SweepPlan {
    /// Every capture of the sweep, in recording order: dark frames per temperature and
    /// exposure, the 24-phase correlation capture (first exposure and temperature), then the
    /// illuminated sweeps (temperature, ambient, exposure, distance, repeat). All validated.
    pub fn captures(&self) -> Result<Vec<PlannedCapture>, ModelError> {
        self.check()?;
        let phases = phases_for(self.phases)?;
        let request =
            |ph: &[f64], t: f64, illumination: bool, amb: f64, temp: f64| CaptureRequest {
                phases_deg: ph.to_vec(),
                exposure_us: t,
                illumination,
                averaged: self.averaged,
                ambient_klux: amb,
                temperature_c: temp,
                conditions: BTreeMap::new(),
            };
        let (refl, corr_m) = (self.reflectivity, self.correlation_distance_m);
        let mut plan = Vec::new();
        for &temp in &self.temperatures_c {
            for &t in &self.exposures_us {
                let dark = request(&phases, t, false, 0.0, temp);
                let mut p = PlannedCapture::wall(dark, corr_m, refl);
                p.conditions
                    .retain(|k, _| k == "ambient_klux" || k == "temperature_c");
                plan.push(p);
            }
        }
        let (t0, temp0) = (self.exposures_us[0], self.temperatures_c[0]);
        let corr = request(&phases_for(24)?, t0, true, 0.0, temp0);
        plan.push(PlannedCapture::wall(corr, corr_m, refl));
        for &temp in &self.temperatures_c {
            for &amb in &self.ambient_klux {
                for &t in &self.exposures_us {
                    for &d in &self.distances_m {
                        for rep in 0..self.repeats {
                            let req = request(&phases, t, true, amb, temp);
                            let mut p = PlannedCapture::wall(req, d, refl);
                            p.conditions.insert("repeat".into(), f64::from(rep));
                            plan.push(p);
                        }
                    }
                }
            }
        }
        validate(&plan)?;
        Ok(plan)
    }

    fn check(&self) -> Result<(), ModelError> {
        if self.distances_m.is_empty()
            || self.exposures_us.is_empty()
            || self.ambient_klux.is_empty()
            || self.temperatures_c.is_empty()
        {
            return Err(ModelError::invalid(
                "distances, exposures, ambient and temperatures need at least one value",
            ));
        }
        if self.repeats == 0 || self.repeats > MAX_REPEATS {
            return Err(ModelError::invalid(format!(
                "repeats {}: allowed 1..={MAX_REPEATS}",
                self.repeats
            )));
        }
        Ok(())
    }
}

/// Validate every capture's request and scene before anything is simulated or written.
pub fn validate(plan: &[PlannedCapture]) -> Result<(), ModelError> {
    for p in plan {
        p.request.validate()?;
        p.scene.validate()?;
    }
    Ok(())
}

/// The conditions of a recorded capture that the model takes as inputs.
pub const MODEL_INPUTS: &[&str] = &[
    "distance_m",
    "reflectivity",
    "ambient_klux",
    "temperature_c",
];

/// The plan that simulates a recording's own conditions ([`plan_like`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LikePlan {
    /// The captures to simulate, in the recording's order.
    pub captures: Vec<PlannedCapture>,
    /// Conditions copied to the output but not simulated (no model input), by name.
    pub ignored: Vec<String>,
    /// Illuminated captures skipped for want of `distance_m`.
    pub skipped: usize,
}

/// Every capture of `rec` under its own conditions: phases, exposure, illumination,
/// averaging and the [`MODEL_INPUTS`] (reflectivity 1 and 25 °C when not stated); its other
/// conditions copied unchanged. Illuminated captures without `distance_m` are skipped.
pub fn plan_like(rec: &Recording) -> Result<LikePlan, ModelError> {
    let mut captures = Vec::new();
    let mut ignored = BTreeSet::new();
    let mut skipped = 0;
    for (i, meta) in rec.captures().iter().enumerate() {
        let cond = |k: &str| meta.conditions.get(k).copied();
        let distance = cond("distance_m");
        if meta.illumination && distance.is_none() {
            skipped += 1;
            continue;
        }
        let request = CaptureRequest {
            phases_deg: meta.phases_deg.clone(),
            exposure_us: meta.exposure_us,
            illumination: meta.illumination,
            averaged: meta.averaged,
            ambient_klux: cond("ambient_klux").unwrap_or(0.0),
            temperature_c: cond("temperature_c").unwrap_or(25.0),
            // the other conditions, for the model's user effects
            conditions: meta
                .physical_conditions()
                .filter(|(k, _)| !MODEL_INPUTS.contains(k))
                .map(|(k, v)| (k.to_string(), v))
                .collect(),
        };
        // a dark capture sees no target; the wall only sets the geometry
        let scene = Scene::wall(distance.unwrap_or(1.0), cond("reflectivity").unwrap_or(1.0));
        let at = |e: ModelError| {
            let capture = format!("{}: capture {i}: {e}", rec.dir().display());
            ModelError::invalid(capture).with_source(e)
        };
        request.validate().map_err(at)?;
        scene.validate().map_err(at)?;
        ignored.extend(
            meta.conditions
                .keys()
                .filter(|k| !MODEL_INPUTS.contains(&k.as_str()))
                .cloned(),
        );
        let conditions = meta.conditions.clone();
        captures.push(PlannedCapture {
            request,
            scene,
            conditions,
        });
    }
    if captures.is_empty() {
        return Err(ModelError::invalid(format!(
            "{}: no capture to simulate (illuminated captures need distance_m)",
            rec.dir().display()
        )));
    }
    let ignored = ignored.into_iter().collect();
    Ok(LikePlan {
        captures,
        ignored,
        skipped,
    })
}

/// Noise seed of capture `index`: independent of scheduling, so the output is the same for
/// any thread count.
pub fn capture_rng(seed: u64, index: usize) -> SmallRng {
    let mut z = seed ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    SmallRng::seed_from_u64(z ^ (z >> 31))
}

/// Simulate capture `index` of a plan: uint16 ADC codes for a single acquisition of a model
/// that quantises, float32 codes otherwise (averaged or unquantised).
fn simulate_one(
    sim: &Simulator,
    p: &PlannedCapture,
    seed: u64,
    index: usize,
) -> Result<RawFrames, ModelError> {
    let mut rng = capture_rng(seed, index);
    if p.request.averaged == 1 && sim.model().is_enabled(crate::effects::quantization::ID) {
        Ok(RawFrames::U16(
            sim.capture_u16(&p.scene, &p.request, &mut rng)?,
        ))
    } else {
        let codes = sim.capture(&p.scene, &p.request, &mut rng)?;
        Ok(RawFrames::F32(codes.mapv(|v| v as f32)))
    }
}

/// Simulate `plan` in parallel (in chunks, so memory stays bounded) and hand every capture's
/// frames to `each`, in order.
pub fn simulate_each<E: From<ModelError>>(
    sim: &Simulator,
    plan: &[PlannedCapture],
    seed: u64,
    mut each: impl FnMut(&PlannedCapture, RawFrames) -> Result<(), E>,
) -> Result<(), E> {
    let chunk = (rayon::current_num_threads() * 8).max(8);
    for (ci, block) in plan.chunks(chunk).enumerate() {
        let base = ci * chunk;
        let frames: Vec<Result<RawFrames, ModelError>> = block
            .par_iter()
            .enumerate()
            .map(|(j, p)| simulate_one(sim, p, seed, base + j))
            .collect();
        for (p, f) in block.iter().zip(frames) {
            each(p, f?)?;
        }
    }
    Ok(())
}

/// Why a plan could not be simulated into a recording: the model, or the writer.
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    /// The model refused a capture.
    #[error("{0}")]
    Model(#[from] ModelError),
    /// The recording could not be written.
    #[error("{0}")]
    Write(#[from] FormatError),
}

/// Simulate `plan` and append every capture to `writer`; `on_capture` is called after each.
pub fn write_plan(
    sim: &Simulator,
    plan: &[PlannedCapture],
    seed: u64,
    writer: &mut RecordingWriter,
    mut on_capture: impl FnMut(),
) -> Result<(), SweepError> {
    simulate_each(sim, plan, seed, |p, frames| {
        writer.append(p.spec(), &frames)?;
        on_capture();
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sweep_is_dark_frames_a_correlation_capture_and_the_distances() {
        let plan = SweepPlan {
            distances_m: vec![0.3, 0.6],
            exposures_us: vec![250.0, 1000.0],
            repeats: 2,
            ..SweepPlan::default()
        };
        let caps = plan.captures().unwrap();
        // 2 dark + 1 correlation + 2 exposures × 2 distances × 2 repeats
        assert_eq!(caps.len(), 2 + 1 + 8);
        assert!(!caps[0].request.illumination && !caps[1].request.illumination);
        assert!(!caps[0].conditions.contains_key("distance_m"));
        assert_eq!(caps[2].request.phases_deg.len(), 24);
        assert_eq!(caps[2].conditions["distance_m"], 1.0);
        let last = &caps[10];
        assert_eq!(last.request.exposure_us, 1000.0);
        assert_eq!(last.conditions["distance_m"], 0.6);
        assert_eq!(last.conditions["repeat"], 1.0);
        assert_eq!(last.conditions["reflectivity"], 0.9);
    }

    #[test]
    fn bad_plans_are_refused_before_anything_is_simulated() {
        let bad = |p: SweepPlan| p.captures().unwrap_err().kind();
        let default = SweepPlan::default;
        assert_eq!(
            bad(SweepPlan {
                phases: 3,
                ..default()
            }),
            crate::ErrorKind::InvalidInput
        );
        assert!(
            SweepPlan {
                repeats: 0,
                ..default()
            }
            .captures()
            .is_err()
        );
        assert!(
            SweepPlan {
                exposures_us: vec![],
                ..default()
            }
            .captures()
            .is_err()
        );
        assert!(
            SweepPlan {
                distances_m: vec![-1.0],
                ..default()
            }
            .captures()
            .is_err()
        );
        assert!(distance_range(1.0, 0.5, 0.1).is_err());
        assert!(distance_range(0.0, 1e9, 1e-3).is_err());
        let d = distance_range(0.15, 1.80, 0.05).unwrap();
        assert_eq!(d.len(), 34);
        assert_eq!(d, SweepPlan::default().distances_m);
    }
}
