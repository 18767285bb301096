//! Frame synthesis for the emulated device.
//!
//! [`ModelSynth`] (the default) renders raw frames with the physical model
//! (`tofprox_model::Simulator`) from a `tofprox_model::SceneScript`.
//! [`IdealSynth`] is a fast, simple source for long soak runs: the
//! sinusoidal correlation of the team conventions
//! (`code = mid + offset + A cos(phi - theta)`, `phi = 4π f d / c`, eq. 2.6
//! inverted) with a column offset pattern and a little read noise.

use std::collections::HashMap;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tofprox_core::SensorGeometry;
use tofprox_model::{CaptureRequest, ModelConfig, Scene, SceneScript, Simulator};

use crate::error::{BridgeError, ErrorKind};

/// Parameters of one raw image as the registers say.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawParams {
    /// Exposure, µs.
    pub exposure_us: f64,
    /// Phase shift, degrees.
    pub phase_deg: f64,
    /// Illumination on.
    pub illuminated: bool,
}

/// A source of raw frames.
pub trait FrameSynth: Send {
    /// Synthesise the raw images of one measurement at scene time `t_s`,
    /// rows `row0 .. row0 + rows`, modulated at `modulation_hz`; `out[k]` gets `rows × cols`
    /// codes.
    fn superframe(
        &mut self,
        t_s: f64,
        raws: &[RawParams],
        window: (usize, usize),
        modulation_hz: f64,
        out: &mut Vec<Vec<u16>>,
    ) -> Result<(), BridgeError>;
}

fn model_err(e: tofprox_model::ModelError) -> BridgeError {
    BridgeError::with_source(ErrorKind::Config, "frame synthesis (tofprox-model)", e)
}

/// `script` sized to the full sensor array of `geom`.
fn fit_script(mut script: SceneScript, geom: &SensorGeometry) -> SceneScript {
    script.full_rows = geom.full_rows;
    script.full_cols = geom.full_cols;
    script
}

/// Frames from the physical model.
pub struct ModelSynth {
    model: ModelConfig,
    geom: SensorGeometry,
    script: SceneScript,
    seed: u64,
    ambient_klux: f64,
    temperature_c: f64,
    /// Simulators per read-out window and modulation frequency (Hz bits).
    sims: HashMap<(usize, usize, u64), Simulator>,
    rng: ChaCha8Rng,
}

impl ModelSynth {
    /// A model-backed source; the fixed patterns are drawn from `seed`.
    pub fn new(
        model: ModelConfig,
        geom: SensorGeometry,
        script: SceneScript,
        seed: u64,
        ambient_klux: f64,
        temperature_c: f64,
    ) -> Result<Self, BridgeError> {
        let script = fit_script(script, &geom);
        script.validate().map_err(model_err)?;
        let mut s = ModelSynth {
            model,
            geom,
            script,
            seed,
            ambient_klux,
            temperature_c,
            sims: HashMap::new(),
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0xF4A3_0001),
        };
        s.sim(0, geom.full_rows, geom.modulation_hz)?;
        Ok(s)
    }

    fn sim(
        &mut self,
        row0: usize,
        rows: usize,
        modulation_hz: f64,
    ) -> Result<&Simulator, BridgeError> {
        let key = (row0, rows, modulation_hz.to_bits());
        if !self.sims.contains_key(&key) {
            let g = SensorGeometry {
                modulation_hz,
                ..self
                    .geom
                    .window(row0, 0, rows, self.geom.full_cols)
                    .map_err(|e| model_err(e.into()))?
            };
            let sim = Simulator::new(&self.model, g, self.seed).map_err(model_err)?;
            // bounded: each simulator holds per-pixel patterns
            if self.sims.len() >= 4 {
                self.sims.clear();
            }
            self.sims.insert(key, sim);
        }
        self.sims
            .get(&key)
            .ok_or_else(|| BridgeError::new(ErrorKind::Io, "simulator cache"))
    }
}

impl FrameSynth for ModelSynth {
    fn superframe(
        &mut self,
        t_s: f64,
        raws: &[RawParams],
        (row0, rows): (usize, usize),
        modulation_hz: f64,
        out: &mut Vec<Vec<u16>>,
    ) -> Result<(), BridgeError> {
        let scene = self.script.at(t_s);
        let (amb, temp) = (self.ambient_klux, self.temperature_c);
        let mut rng = ChaCha8Rng::seed_from_u64(self.rng.random());
        let sim = self.sim(row0, rows, modulation_hz)?;
        out.resize_with(raws.len(), Vec::new);
        // consecutive raw images with the same exposure and illumination are
        // one model capture
        let mut start = 0;
        while start < raws.len() {
            let r0 = raws[start];
            let mut end = start + 1;
            while end < raws.len()
                && raws[end].exposure_us == r0.exposure_us
                && raws[end].illuminated == r0.illuminated
            {
                end += 1;
            }
            let req = CaptureRequest {
                phases_deg: raws[start..end].iter().map(|r| r.phase_deg).collect(),
                exposure_us: r0.exposure_us,
                illumination: r0.illuminated,
                averaged: 1,
                ambient_klux: amb,
                temperature_c: temp,
                conditions: Default::default(),
            };
            let codes = sim.capture_u16(&scene, &req, &mut rng).map_err(model_err)?;
            for (k, img) in codes.outer_iter().enumerate() {
                let dst = &mut out[start + k];
                dst.clear();
                dst.extend(img.iter().copied());
            }
            start = end;
        }
        Ok(())
    }
}

/// The built-in ideal synthesiser (fast; for soak runs).
pub struct IdealSynth {
    geom: SensorGeometry,
    script: SceneScript,
    col_offset: Vec<f64>,
    rng: ChaCha8Rng,
    phi: Vec<f64>,
    gain: Vec<f64>,
}

impl IdealSynth {
    /// Draw the fixed column pattern from `seed`.
    pub fn new(geom: SensorGeometry, script: SceneScript, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_F1ED);
        let col_offset = (0..geom.full_cols)
            .map(|_| rng.random_range(-20.0..20.0))
            .collect();
        let script = fit_script(script, &geom);
        IdealSynth {
            geom,
            script,
            col_offset,
            rng,
            phi: Vec::new(),
            gain: Vec::new(),
        }
    }
}

impl FrameSynth for IdealSynth {
    fn superframe(
        &mut self,
        t_s: f64,
        raws: &[RawParams],
        (row0, rows): (usize, usize),
        modulation_hz: f64,
        out: &mut Vec<Vec<u16>>,
    ) -> Result<(), BridgeError> {
        let g = SensorGeometry {
            modulation_hz,
            ..self.geom
        };
        let cols = g.full_cols;
        let max = f64::from(g.max_code());
        let mid = f64::from(g.mid_code());
        // per-pixel phase (eq. 2.6 inverted) and inverse-square gain (2.1)
        let k_phi = g.phase_rad_per_m();
        self.phi.clear();
        self.gain.clear();
        match self.script.at(t_s) {
            Scene::FlatWall {
                distance_m,
                reflectivity,
            } => {
                self.phi.resize(rows * cols, k_phi * distance_m);
                self.gain
                    .resize(rows * cols, reflectivity / (distance_m * distance_m));
            }
            Scene::DepthMap {
                distance_m,
                reflectivity,
            } => {
                for r in row0..row0 + rows {
                    for c in 0..cols {
                        let d = distance_m.get((r, c)).copied().unwrap_or(1.0).max(0.005);
                        let rf = reflectivity.get((r, c)).copied().unwrap_or(0.5);
                        self.phi.push(k_phi * d);
                        self.gain.push(rf / (d * d));
                    }
                }
            }
            // pressed on the cover window: no image of its own (this synthesiser has no
            // window path; the model's `cover_window_crosstalk` carries its light)
            Scene::OnWindow { .. } => {
                self.phi.resize(rows * cols, 0.0);
                self.gain.resize(rows * cols, 0.0);
            }
        }
        out.resize_with(raws.len(), Vec::new);
        for (raw, frame) in raws.iter().zip(out.iter_mut()) {
            frame.clear();
            frame.reserve(rows * cols);
            let theta = raw.phase_deg.to_radians();
            let a = if raw.illuminated {
                2.0 * raw.exposure_us
            } else {
                0.0
            };
            for (i, (phi, gain)) in self.phi.iter().zip(&self.gain).enumerate() {
                let c = i % cols;
                let s = a * gain * (phi - theta).cos();
                let n = f64::from(self.rng.random::<u8>() & 7) - 3.5;
                frame.push((mid + self.col_offset[c] + s + n).round().clamp(0.0, max) as u16);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn four(exposure_us: f64) -> Vec<RawParams> {
        [0.0, 90.0, 180.0, 270.0]
            .map(|p| RawParams {
                exposure_us,
                phase_deg: p,
                illuminated: true,
            })
            .to_vec()
    }

    fn geometry_80mhz(full_rows: usize, cols: usize) -> SensorGeometry {
        SensorGeometry::full(full_rows, cols, 12, 80e6)
    }

    fn wall_at_half_metre() -> SceneScript {
        SceneScript {
            far_m: 0.3,
            ..SceneScript::wall(0.5)
        }
    }

    fn centre_distance(out: &[Vec<u16>], rows: usize, cols: usize) -> f64 {
        let i = rows / 2 * cols + cols / 2;
        let m = |k: usize| f64::from(out[k][i]);
        let phi = (m(1) - m(3))
            .atan2(m(0) - m(2))
            .rem_euclid(std::f64::consts::TAU); // eq. 2.3
        tofprox_core::phasor::phase_to_distance_m(phi, 80e6)
    }

    #[test]
    fn ideal_phase_follows_distance() {
        let g = geometry_80mhz(8, 8);
        let mut s = IdealSynth::new(g, wall_at_half_metre(), 1);
        let mut out = Vec::new();
        s.superframe(0.0, &four(500.0), (0, 8), 80e6, &mut out)
            .unwrap();
        let d = centre_distance(&out, 8, 8);
        assert!((d - 0.5).abs() < 0.03, "{d}");
    }

    #[test]
    fn model_frames_have_window_shape() {
        let g = geometry_80mhz(172, 224);
        let mut s =
            ModelSynth::new(ModelConfig::ideal(), g, wall_at_half_metre(), 3, 0.0, 25.0).unwrap();
        let mut out = Vec::new();
        s.superframe(0.0, &four(500.0), (40, 20), 80e6, &mut out)
            .unwrap();
        assert_eq!(out.len(), 4);
        assert!(out.iter().all(|f| f.len() == 20 * 224));
    }
}
