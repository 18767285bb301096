//! Pooled photon-transfer noise model (thesis 2.3.2, 2.3.2.6):
//! var(code) = (a + b·A + c·ambient·exposure + e·exposure) / averaged, with
//! A the modelled signal amplitude in LSB (shot noise of the signal charge, which
//! is proportional to it), ambient·exposure the background charge (its shot
//! noise), exposure the dark-current charge and `a` the read/kTC/quantisation
//! floor. Fitted once over all conditions, from the differences of repeated
//! captures where the recording has them (never each condition's own variance),
//! else from raw images of one capture taken at the same phase shift; without
//! either the noise is not measured ([`NoiseSource::NotMeasured`]).
use std::collections::BTreeMap;

use serde::Serialize;

use crate::error::LabError;
use crate::fit::LabModel;
use crate::prepared::{Prepared, key_f};
use tofprox_core::lsq::solve_sym;

/// The floor of `a`, LSB² per acquisition: the quantisation noise of one
/// code (1/12 LSB², thesis 2.3.2.6) is in every acquisition. Without it a
/// residual-based fit whose residual grows faster than the photon-transfer law
/// (a missing effect ∝ A) drives `a` to zero, and the scale calibration then
/// divides the darkest samples' residuals by a near-zero variance.
const QUANTISATION_FLOOR_LSB2: f64 = 1.0 / 12.0;

/// At least this many squared differences make a measured noise model.
const MIN_NOISE_DIFFERENCES: usize = 200;

/// Where a noise model's variances come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum NoiseSource {
    /// Differences of repeated captures: `groups` sets of captures whose
    /// physical conditions are equal (bookkeeping keys such as `repeat` ignored).
    Repeats {
        /// Sets of two or more captures with equal conditions.
        groups: usize,
    },
    /// Differences of raw images of one capture taken at the same phase shift.
    RawImages {
        /// Captures with repeated phase shifts.
        captures: usize,
    },
    /// Not measured: the variances are the model's residuals, which contain
    /// whatever the model lacks; a noise-like residual then proves nothing.
    NotMeasured,
}

impl NoiseSource {
    /// True when the noise was measured (repeats or repeated raw images).
    pub fn measured(&self) -> bool {
        !matches!(self, NoiseSource::NotMeasured)
    }

    /// One phrase for reports: "measured from 70 repeat groups", ….
    pub fn describe(&self) -> String {
        match self {
            NoiseSource::Repeats { groups } => {
                format!("measured from {groups} groups of repeated captures")
            }
            NoiseSource::RawImages { captures } => {
                format!("measured from repeated raw images of {captures} captures")
            }
            NoiseSource::NotMeasured => {
                "not measured (no repeated captures or raw images): estimated from the model residuals"
                    .to_string()
            }
        }
    }
}

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
    pub source: NoiseSource,
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
            source: NoiseSource::NotMeasured,
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
    pub fn fit(obs: &[([f64; NOISE_TERMS], f64)], source: NoiseSource) -> Result<Self, LabError> {
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
        beta[0] = (mean_y / obs[0].0[0].max(1e-12)).max(QUANTISATION_FLOOR_LSB2);
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
            nb[0] = nb[0].max(QUANTISATION_FLOOR_LSB2);
            beta = nb;
        }
        let mut model = NoiseModel {
            a: beta[0],
            b: beta[1],
            c: beta[2],
            e: beta[3],
            source,
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

/// The pooled noise model of a recording under `model`: from repeated
/// captures (equal physical conditions), else from raw images of one capture
/// taken at the same phase shift, else — not measured — from the residuals.
pub fn fit_noise(prep: &Prepared, model: &LabModel) -> Result<NoiseModel, LabError> {
    let (obs, groups) = repeat_differences(prep, model);
    if obs.len() >= MIN_NOISE_DIFFERENCES {
        return NoiseModel::fit(&obs, NoiseSource::Repeats { groups });
    }
    let recs = model.records(prep)?;
    let features = |c: u32, a: f32| {
        let cap = &prep.caps[c as usize];
        NoiseModel::features(
            f64::from(a),
            cap.ambient_klux,
            cap.exposure_us,
            cap.averaged,
        )
    };
    // raw images of one capture at the same shift: residual differences
    // (the model's prediction, droop included, differs between them)
    let repeats_shift = |c: &crate::prepared::CapInfo| {
        let mut keys: Vec<i64> = c.phases_deg.iter().map(|p| key_f(*p)).collect();
        keys.sort_unstable();
        keys.windows(2).any(|w| w[0] == w[1])
    };
    let with_repeats: Vec<bool> = prep.caps.iter().map(repeats_shift).collect();
    let mut by_image: BTreeMap<(u32, i64, u32), Vec<(f32, f32)>> = BTreeMap::new();
    for r in recs.iter().filter(|r| with_repeats[r.cap as usize]) {
        let theta = prep.caps[r.cap as usize].phases_deg[usize::from(r.k)];
        by_image
            .entry((r.cap, key_f(theta), r.pix))
            .or_default()
            .push((r.r, r.a));
    }
    let mut obs = Vec::new();
    let mut captures = std::collections::BTreeSet::new();
    for ((cap, _, _), same) in &by_image {
        for pair in same.chunks_exact(2) {
            captures.insert(*cap);
            let d = f64::from(pair[0].0 - pair[1].0);
            obs.push((features(*cap, pair[0].1), d * d / 2.0));
        }
    }
    if obs.len() >= MIN_NOISE_DIFFERENCES {
        let captures = captures.len();
        return NoiseModel::fit(&obs, NoiseSource::RawImages { captures });
    }
    // not measured: the result says so (`NoiseSource::NotMeasured`), once, where it is
    // reported — not here, where every refit of a diagnosis passes
    let dof_scale = residual_dof_scale(recs.len(), crate::fit::param_count(model, prep.npix));
    let obs: Vec<_> = recs
        .iter()
        .map(|r| (features(r.cap, r.a), dof_scale * f64::from(r.r).powi(2)))
        .collect();
    NoiseModel::fit(&obs, NoiseSource::NotMeasured)
}

/// n/(n − p): what the squared residuals of a least-squares fit of `p`
/// parameters to `n` samples are scaled by to estimate the noise variance —
/// the fit follows p of the n noise dimensions, so E[Σ r²/σ²] = n − p (the
/// unbiased variance estimate). Without it a noise taken from the residuals
/// gives χ² = n, χ²/dof = n/(n − p): on a sparse recording (11 captures of
/// 16×16 pixels, no repeats, ≈ 5 % of the samples' worth of per-pixel
/// parameters) z = 4.4 from the fit's own parameters — an `unexplained`
/// verdict about nothing (issue 33).
fn residual_dof_scale(n: usize, p: usize) -> f64 {
    if n > p {
        n as f64 / (n - p) as f64
    } else {
        1.0
    }
}

/// Squared differences (halved) of captures repeated under equal physical
/// conditions, paired in acquisition order, and the number of such groups.
fn repeat_differences(
    prep: &Prepared,
    model: &LabModel,
) -> (Vec<([f64; NOISE_TERMS], f64)>, usize) {
    let npix = prep.npix;
    let mut groups: BTreeMap<Vec<i64>, Vec<usize>> = BTreeMap::new();
    for (c, cap) in prep.caps.iter().enumerate() {
        if !cap.used {
            continue;
        }
        let mut key: Vec<i64> = cap.phases_deg.iter().map(|p| key_f(*p)).collect();
        key.extend([
            key_f(cap.exposure_us),
            i64::from(cap.illum),
            key_f(cap.distance_m.unwrap_or(-1.0)),
            key_f(cap.ambient_klux),
            key_f(cap.temperature_c.unwrap_or(-999.0)),
            key_f(cap.law),
            i64::from(cap.averaged),
        ]);
        key.extend(
            cap.extra
                .iter()
                .map(|v| key_f(if v.is_nan() { -1e9 } else { *v })),
        );
        groups.entry(key).or_default().push(c);
    }
    let mut obs = Vec::new();
    for cs in groups.values() {
        for pair in cs.chunks_exact(2) {
            let (c1, c2) = (pair[0], pair[1]);
            let cap = &prep.caps[c1];
            for p in 0..npix {
                if model.sat[c1 * npix + p] || model.sat[c2 * npix + p] {
                    continue;
                }
                let a = model.gain[p] * cap.law * model.phasor_shift(cap, p).0;
                let f = NoiseModel::features(a, cap.ambient_klux, cap.exposure_us, cap.averaged);
                for k in 0..cap.theta_rad.len() {
                    let d = prep.meas[prep.idx(c1, k, p)] - prep.meas[prep.idx(c2, k, p)];
                    obs.push((f, d * d / 2.0));
                }
            }
        }
    }
    let repeated = groups.values().filter(|cs| cs.len() >= 2).count();
    (obs, repeated)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The residuals of p fitted parameters carry n − p of the noise's n
    /// dimensions: the scale restores σ² (1 for no parameters).
    #[test]
    fn residual_variance_is_scaled_by_the_degrees_of_freedom() {
        assert_eq!(residual_dof_scale(100, 0), 1.0);
        assert!((residual_dof_scale(1000, 50) - 1000.0 / 950.0).abs() < 1e-12);
        assert_eq!(residual_dof_scale(10, 20), 1.0);
    }
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
            source: NoiseSource::Repeats { groups: 1 },
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
        let m = NoiseModel::fit(&obs, NoiseSource::Repeats { groups: 1 }).unwrap();
        assert!((m.a - 4.0).abs() < 0.6, "{m:?}");
        assert!((m.b - 0.35).abs() < 0.03, "{m:?}");
        assert!((m.c - 0.002).abs() < 0.0006, "{m:?}");
    }

    #[test]
    fn too_few_observations_is_an_error() {
        assert!(NoiseModel::fit(&[([1.0, 0.0, 0.0, 0.0], 1.0)], NoiseSource::NotMeasured).is_err());
    }
}
