//! A small, self-contained generator of lab-format datasets for the lab's own
//! unit tests and benchmark (independent of tofprox-model on purpose: the
//! statistics are checked against a second implementation of the physics).
use ndarray::Array3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tofprox_core::SensorGeometry;
use tofprox_core::phasor::distance_to_phase_rad;

use crate::data::{Capture, Dataset};
use crate::waveform::Waveform;

/// An effect injected into the synthetic truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Hidden {
    /// Common-mode error m·max(0, ambient·t_ms + A/100 − q0) on every raw image.
    Sbi { m: f64, q0: f64 },
    /// A_k = A(1 − eps·k).
    Droop { eps: f64 },
    /// Δφ = k·A/1000.
    AmpPhase { k: f64 },
    /// Δφ = k·(T − 25).
    TempDrift { k: f64 },
    /// Extra harmonic h with complex coefficient.
    Harmonic { h: usize, re: f64, im: f64 },
    /// INL bow of amplitude s (LSB) on the differential code.
    Inl { s: f64 },
    /// Not in the catalogue: an offset ∝ exposure alternating in sign by row.
    RowExposureOffset { lsb_per_ms: f64 },
}

#[derive(Debug, Clone)]
pub struct SynthSpec {
    pub rows: usize,
    pub cols: usize,
    pub distances_m: Vec<f64>,
    pub exposures_us: Vec<f64>,
    pub ambients_klux: Vec<f64>,
    pub temperatures_c: Vec<f64>,
    pub repeats: usize,
    /// Waveform harmonics of the truth (γ_1 = 1 implied), h = 2.. .
    pub harmonics: Vec<[f64; 2]>,
    pub hidden: Vec<Hidden>,
    pub seed: u64,
    /// Signal in LSB at 1 m, 1 ms, reflectivity 1.
    pub scale_lsb: f64,
}

impl Default for SynthSpec {
    fn default() -> Self {
        Self {
            rows: 8,
            cols: 8,
            distances_m: (0..24).map(|i| 0.15 + i as f64 * 0.07).collect(),
            exposures_us: vec![300.0, 1000.0],
            ambients_klux: vec![0.0],
            temperatures_c: vec![25.0],
            repeats: 2,
            harmonics: vec![[0.0, 0.0], [-0.06, 0.01]],
            hidden: Vec::new(),
            seed: 1,
            scale_lsb: 350.0,
        }
    }
}

impl SynthSpec {
    /// The recording of the `diagnose` benchmark and the `profile_diagnose`
    /// example: 16×16 pixels, 2 darks per exposure, 1 correlation capture,
    /// 3 exposures × 149 distances × 2 repeats = 894 sweep captures → 901
    /// captures, with a 1 % VCSEL droop hidden.
    pub fn diagnose_benchmark() -> Self {
        Self {
            rows: 16,
            cols: 16,
            distances_m: (0..149).map(|i| 0.15 + i as f64 * (1.65 / 148.0)).collect(),
            exposures_us: vec![250.0, 500.0, 1000.0],
            hidden: vec![Hidden::Droop { eps: 0.01 }],
            ..Self::default()
        }
    }

    /// A full-array sweep (224×172 pixels): 2 darks per exposure, 1
    /// correlation capture, 2 exposures × 24 distances × 2 repeats = 96 sweep
    /// captures → 101 captures, 15.4 M samples, with a 1 % VCSEL droop hidden.
    pub fn full_array_sweep() -> Self {
        Self {
            rows: 172,
            cols: 224,
            hidden: vec![Hidden::Droop { eps: 0.01 }],
            ..Self::default()
        }
    }
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    // Box–Muller
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

pub fn generate(spec: &SynthSpec) -> Dataset {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let npix = spec.rows * spec.cols;
    let f_mod = 80.32e6;
    let mid = 2048.0;
    let offs: Vec<f64> = (0..npix).map(|_| 25.0 * gauss(&mut rng)).collect();
    let gains: Vec<f64> = (0..npix).map(|_| 1.0 + 0.04 * gauss(&mut rng)).collect();
    let delays: Vec<f64> = (0..npix)
        .map(|p| 0.9 + 0.002 * (p % spec.cols) as f64 + 0.01 * gauss(&mut rng))
        .collect();
    let mut gamma = vec![[1.0, 0.0]];
    gamma.extend(spec.harmonics.iter().copied());
    for h in &spec.hidden {
        if let Hidden::Harmonic { h, re, im } = *h {
            while gamma.len() < h {
                gamma.push([0.0, 0.0]);
            }
            gamma[h - 1][0] += re;
            gamma[h - 1][1] += im;
        }
    }
    let wf = Waveform { gamma };
    let mut caps = Vec::new();
    #[allow(clippy::too_many_arguments)]
    let make = |rng: &mut ChaCha8Rng,
                phases: Vec<f64>,
                t: f64,
                illum: bool,
                d: f64,
                amb: f64,
                temp: f64| {
        let k = phases.len();
        let mut fr = Array3::<f64>::zeros((k, spec.rows, spec.cols));
        for p in 0..npix {
            let a0 = if illum {
                spec.scale_lsb * gains[p] * t * 1e-3 / (d * d)
            } else {
                0.0
            };
            let mut phi = distance_to_phase_rad(d, f_mod) + delays[p];
            let mut a = a0;
            for h in &spec.hidden {
                match *h {
                    Hidden::AmpPhase { k } => phi += k * a0 / 1000.0,
                    Hidden::TempDrift { k } => phi += k * (temp - 25.0),
                    _ => {}
                }
            }
            let var = (3.0 + 0.4 * a0 + 0.01 * amb * t) / 16.0;
            for (kk, th) in phases.iter().enumerate() {
                let mut ak = a;
                for h in &spec.hidden {
                    if let Hidden::Droop { eps } = *h {
                        ak = a0 * (1.0 - eps * kk as f64);
                    }
                }
                let mut x = offs[p]
                    + if illum {
                        ak * wf.eval(phi - th.to_radians()).0
                    } else {
                        0.0
                    };
                for h in &spec.hidden {
                    match *h {
                        Hidden::Sbi { m, q0 } => {
                            x += m * (amb * t * 1e-3 + a0 / 100.0 - q0).max(0.0)
                        }
                        Hidden::Inl { s } => {
                            let u = (x / mid).clamp(-1.0, 1.0);
                            x += s * 4.0 * u * (1.0 - u.abs());
                        }
                        Hidden::RowExposureOffset { lsb_per_ms } => {
                            let row = p / spec.cols;
                            x += lsb_per_ms
                                * t
                                * 1e-3
                                * if row.is_multiple_of(2) { 1.0 } else { -1.0 };
                        }
                        _ => {}
                    }
                }
                let v = (mid + x + var.sqrt() * gauss(rng)).clamp(0.0, 4095.0);
                fr[[kk, p / spec.cols, p % spec.cols]] = v;
            }
            a = a0;
            let _ = a;
        }
        Capture {
            phases_deg: phases,
            exposure_us: t,
            illumination: illum,
            averaged: 16,
            distance_m: illum.then_some(d),
            reflectivity: 1.0,
            ambient_klux: amb,
            temperature_c: Some(temp),
            extra: Default::default(),
            frames: fr,
        }
    };
    let four = vec![0.0, 90.0, 180.0, 270.0];
    let t0 = spec.temperatures_c.first().copied().unwrap_or(25.0);
    for &t in &spec.exposures_us {
        for _ in 0..spec.repeats.max(1) {
            caps.push(make(&mut rng, four.clone(), t, false, 1.0, 0.0, t0));
        }
    }
    let corr: Vec<f64> = (0..24).map(|i| i as f64 * 15.0).collect();
    let t_corr = spec.exposures_us.first().copied().unwrap_or(500.0);
    caps.push(make(&mut rng, corr, t_corr, true, 0.9, 0.0, t0));
    for &temp in &spec.temperatures_c {
        for &amb in &spec.ambients_klux {
            for &t in &spec.exposures_us {
                for &d in &spec.distances_m {
                    for _ in 0..spec.repeats.max(1) {
                        caps.push(make(&mut rng, four.clone(), t, true, d, amb, temp));
                    }
                }
            }
        }
    }
    Dataset {
        sensor: SensorGeometry::full(spec.rows, spec.cols, 12, f_mod),
        captures: caps,
    }
}
