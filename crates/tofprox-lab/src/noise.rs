//! Pooled photon-transfer noise model (thesis 2.3.2, 2.3.2.6):
//! var(code) = (a + b·A + c·ambient·exposure + e·exposure) / averaged, with
//! A the modelled signal amplitude in LSB (shot noise of the signal charge, which
//! is proportional to it), ambient·exposure the background charge (its shot
//! noise), exposure the dark-current charge and `a` the read/kTC/quantisation
//! floor. Fitted once over all conditions, from the differences of repeated
//! captures where the recording has them (never each condition's own variance).
use serde::Serialize;

use crate::error::LabError;
use crate::stats::solve_sym;

/// Number of features in the photon-transfer regression.
pub const NOISE_TERMS: usize = 4;

/// The fitted photon-transfer variance law of one averaged raw code (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NoiseModel {
    /// Read-noise floor, LSB² per acquisition.
    pub a: f64,
    /// Signal shot-noise slope, LSB² per LSB of amplitude.
    pub b: f64,
    /// Background shot-noise slope, LSB² per (klux·µs).
    pub c: f64,
    /// Dark-current shot-noise slope, LSB² per µs.
    pub e: f64,
    /// Where the estimate came from.
    pub from_repeats: bool,
    /// Number of squared differences (or residuals) it rests on.
    pub samples: usize,
}

impl Default for NoiseModel {
    fn default() -> Self {
        Self {
            a: 1.0,
            b: 0.0,
            c: 0.0,
            e: 0.0,
            from_repeats: false,
            samples: 0,
        }
    }
}

impl NoiseModel {
    /// Variance of one averaged code.
    #[inline]
    pub fn var(
        &self,
        amplitude_lsb: f64,
        ambient_klux: f64,
        exposure_us: f64,
        averaged: u32,
    ) -> f64 {
        let v = self.a
            + self.b * amplitude_lsb.max(0.0)
            + self.c * ambient_klux * exposure_us
            + self.e * exposure_us;
        v.max(1e-9) / f64::from(averaged.max(1))
    }

    /// The regression features `[1, A, ambient·exposure, exposure] / averaged`
    /// whose dot product with `[a, b, c, e]` is [`NoiseModel::var`].
    pub fn features(
        amplitude_lsb: f64,
        ambient_klux: f64,
        exposure_us: f64,
        averaged: u32,
    ) -> [f64; NOISE_TERMS] {
        let s = 1.0 / f64::from(averaged.max(1));
        [
            s,
            amplitude_lsb.max(0.0) * s,
            ambient_klux * exposure_us * s,
            exposure_us * s,
        ]
    }

    /// Fit from observations `y` whose expectation is the variance with the
    /// given features (y = d²/2 for a repeat difference d). Iteratively
    /// reweighted least squares with weights 1/v̂² (var(y) = 2v² for a χ²₁
    /// variable), non-negative slopes, then the scale calibrated so that the
    /// mean of y/v̂ is one.
    pub fn fit(obs: &[([f64; NOISE_TERMS], f64)], from_repeats: bool) -> Result<Self, LabError> {
        if obs.len() < 8 {
            return Err(LabError::data(format!(
                "only {} noise observations; need at least 8",
                obs.len()
            )));
        }
        // Terms whose feature never varies from zero cannot be fitted.
        let mut active = [true; NOISE_TERMS];
        for (t, act) in active.iter_mut().enumerate().skip(1) {
            let mut lo = f64::INFINITY;
            let mut hi = f64::NEG_INFINITY;
            for (f, _) in obs {
                let r = f[t] / f[0];
                lo = lo.min(r);
                hi = hi.max(r);
            }
            *act = hi > lo && hi > 0.0;
        }
        let mean_y = obs.iter().map(|o| o.1).sum::<f64>() / obs.len() as f64;
        let mut beta = [0.0; NOISE_TERMS];
        beta[0] = (mean_y / obs[0].0[0].max(1e-12)).max(1e-6);
        for _ in 0..8 {
            let idx: Vec<usize> = (0..NOISE_TERMS).filter(|&t| active[t]).collect();
            let n = idx.len();
            let mut m = vec![0.0; n * n];
            let mut v = vec![0.0; n];
            for (f, y) in obs {
                let pred: f64 = (0..NOISE_TERMS)
                    .map(|t| beta[t] * f[t])
                    .sum::<f64>()
                    .max(1e-9);
                let w = 1.0 / (pred * pred);
                for (a, &ta) in idx.iter().enumerate() {
                    v[a] += w * f[ta] * y;
                    for (b, &tb) in idx.iter().enumerate() {
                        m[a * n + b] += w * f[ta] * f[tb];
                    }
                }
            }
            let Some(sol) = solve_sym(&m, &v) else {
                return Err(LabError::numerical("noise model regression is singular"));
            };
            let mut nb = [0.0; NOISE_TERMS];
            for (a, &ta) in idx.iter().enumerate() {
                nb[ta] = sol[a];
            }
            // Non-negativity: drop a negative slope and refit without it.
            let mut dropped = false;
            for t in 1..NOISE_TERMS {
                if active[t] && nb[t] < 0.0 {
                    active[t] = false;
                    dropped = true;
                }
            }
            if dropped {
                continue;
            }
            nb[0] = nb[0].max(1e-6);
            beta = nb;
        }
        let mut model = NoiseModel {
            a: beta[0],
            b: beta[1],
            c: beta[2],
            e: beta[3],
            from_repeats,
            samples: obs.len(),
        };
        // Calibrate the overall scale: mean(y / v̂) = 1.
        let ratio = obs
            .iter()
            .map(|(f, y)| {
                y / (0..NOISE_TERMS)
                    .map(|t| beta[t] * f[t])
                    .sum::<f64>()
                    .max(1e-9)
            })
            .sum::<f64>()
            / obs.len() as f64;
        if ratio.is_finite() && ratio > 0.0 {
            model.a *= ratio;
            model.b *= ratio;
            model.c *= ratio;
            model.e *= ratio;
        }
        Ok(model)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal as Gauss};

    #[test]
    fn recovers_photon_transfer_from_repeat_differences() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let truth = NoiseModel {
            a: 4.0,
            b: 0.35,
            c: 0.002,
            e: 0.0,
            from_repeats: true,
            samples: 0,
        };
        let mut obs = Vec::new();
        for i in 0..40_000 {
            let amp = 20.0 + (i % 97) as f64 * 10.0;
            let amb = [0.0, 20.0, 50.0][i % 3];
            let t = [250.0, 1000.0][i % 2];
            let v = truth.var(amp, amb, t, 16);
            let g = Gauss::new(0.0, (2.0 * v).sqrt()).unwrap();
            let d: f64 = g.sample(&mut rng);
            obs.push((NoiseModel::features(amp, amb, t, 16), d * d / 2.0));
        }
        let m = NoiseModel::fit(&obs, true).unwrap();
        assert!((m.a - 4.0).abs() < 0.6, "{m:?}");
        assert!((m.b - 0.35).abs() < 0.03, "{m:?}");
        assert!((m.c - 0.002).abs() < 0.0006, "{m:?}");
    }

    #[test]
    fn too_few_observations_is_an_error() {
        assert!(NoiseModel::fit(&[([1.0, 0.0, 0.0, 0.0], 1.0)], true).is_err());
    }
}
