//! Where the model fails: residuals binned against every condition that
//! varies, projected on three directions per sample — offset (1), amplitude
//! (A·C) and phase (A·C') — and each bin's estimate compared with its
//! standard error. Under noise the sum over bins of βᵀ M β is χ² with
//! (channels × bins) degrees of freedom; the structure score is its z.
use rayon::prelude::*;
use serde::Serialize;

use crate::fit::{Prepared, Rec};
use crate::stats::solve_sym;

/// The conditions every recording is scored against, when they vary.
pub const CONDITIONS: &[&str] = &[
    "distance_m",
    "phase",
    "ambient_klux",
    "temperature_c",
    "exposure_us",
    "amplitude",
    "image_index",
    "capture_index",
    "column",
    "adc_channel",
    "row",
    "adc_code",
];

/// One bin of a condition: the residual projected on the three directions.
#[derive(Debug, Clone, Serialize)]
pub struct Bin {
    /// Bin centre in the condition's unit.
    pub x: f64,
    /// Samples (pixel × raw image) in the bin.
    pub samples: usize,
    /// Estimate along offset (LSB), amplitude (relative) and phase (rad).
    pub est: [f64; 3],
    /// Standard errors of `est` (NaN when the direction has no information).
    pub se: [f64; 3],
    /// Weighted mean raw residual (LSB) and the weighted mean |model| signal.
    pub mean_resid_lsb: f64,
}

/// How strongly the residual varies with one condition, beyond the noise.
#[derive(Debug, Clone, Serialize)]
pub struct ConditionScore {
    /// The condition's name (a [`CONDITIONS`] entry).
    pub condition: String,
    /// Structure score: (χ² − dof)/√(2·dof), the larger of the global and
    /// per-pixel binnings; about N(0, 1) when the residual is noise.
    pub z: f64,
    /// χ² of the bin estimates behind `z`.
    pub chi2: f64,
    /// Degrees of freedom of `chi2`.
    pub dof: usize,
    /// Which direction carries most of the structure: offset, amplitude, phase.
    pub direction: &'static str,
    /// The global bins, those with at least 4 samples.
    pub bins: Vec<Bin>,
}

/// Value of condition `cond` at a sample (None = not applicable).
pub fn cond_value(cond: &str, r: &Rec, prep: &Prepared) -> Option<f64> {
    let cap = &prep.caps[r.cap as usize];
    let p = r.pix as usize;
    match cond {
        "distance_m" => cap.distance_m.filter(|_| cap.illum),
        "phase" => cap
            .illum
            .then(|| r.phi.rem_euclid(std::f64::consts::TAU).to_degrees()),
        "ambient_klux" => Some(cap.ambient_klux),
        "temperature_c" => cap.temperature_c,
        "exposure_us" => Some(cap.exposure_us),
        "amplitude" => cap.illum.then_some(r.a),
        "image_index" => Some(f64::from(r.k)),
        "capture_index" => Some(f64::from(r.cap)),
        "column" => Some((p % prep.cols) as f64),
        "adc_channel" => Some(((prep.roi_origin[1] + p % prep.cols) % 16) as f64),
        "row" => Some((p / prep.cols) as f64),
        "adc_code" => Some(r.x + prep.mid),
        _ => None,
    }
}

/// Bin edges: one bin per distinct value when there are few, else quantiles.
fn binning(vals: &[f64]) -> Option<Vec<f64>> {
    let mut u: Vec<f64> = vals.iter().copied().filter(|v| v.is_finite()).collect();
    if u.is_empty() {
        return None;
    }
    u.sort_by(|a, b| a.total_cmp(b));
    let mut distinct = u.clone();
    distinct.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * b.abs().max(1.0));
    if distinct.len() < 2 {
        return None;
    }
    if distinct.len() <= 16 {
        // edges halfway between distinct values
        return Some(distinct.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect());
    }
    let nb = 12;
    let mut edges: Vec<f64> = (1..nb).map(|i| u[u.len() * i / nb]).collect();
    edges.dedup();
    Some(edges)
}

#[derive(Clone)]
struct Acc {
    m: [f64; 9],
    v: [f64; 3],
    sx: f64,
    n: usize,
    swr: f64,
    sw: f64,
}

const ZERO: Acc = Acc {
    m: [0.0; 9],
    v: [0.0; 3],
    sx: 0.0,
    n: 0,
    swr: 0.0,
    sw: 0.0,
};

impl Acc {
    fn merge(&mut self, y: &Acc) {
        for i in 0..9 {
            self.m[i] += y.m[i];
        }
        for i in 0..3 {
            self.v[i] += y.v[i];
        }
        self.sx += y.sx;
        self.n += y.n;
        self.swr += y.swr;
        self.sw += y.sw;
    }
    /// (βᵀMβ, rank, β on the active directions) of this accumulator.
    fn stat(&self) -> Option<(f64, usize, [f64; 3])> {
        let maxd = (0..3).map(|i| self.m[i * 4]).fold(0.0f64, f64::max);
        if maxd <= 0.0 {
            return None;
        }
        let act: Vec<usize> = (0..3).filter(|&i| self.m[i * 4] > 1e-9 * maxd).collect();
        let n = act.len();
        let mut m = vec![0.0; n * n];
        let mut v = vec![0.0; n];
        for (ii, &i) in act.iter().enumerate() {
            v[ii] = self.v[i];
            for (jj, &j) in act.iter().enumerate() {
                m[ii * n + jj] = self.m[i * 3 + j];
            }
        }
        let beta = solve_sym(&m, &v)?;
        let s: f64 = beta.iter().zip(&v).map(|(b, v)| b * v).sum();
        let mut full = [f64::NAN; 3];
        for (ii, &i) in act.iter().enumerate() {
            full[i] = beta[ii];
        }
        Some((s, n, full))
    }
}

/// Between-bins statistic of one unit (all pixels, or one pixel): the
/// structure across bins beyond a constant shift (which the per-pixel
/// parameters absorb): Σ_b v_bᵀM_b⁻¹v_b − VᵀM⁻¹V with Σ rank_b − rank dof.
fn between(bins: &[Acc], per_dir: &mut [f64; 3]) -> (f64, usize) {
    let mut tot = ZERO;
    let mut s = 0.0;
    let mut dof = 0usize;
    for a in bins {
        if a.n < 4 {
            continue;
        }
        if let Some((st, r, beta)) = a.stat() {
            s += st;
            dof += r;
            tot.merge(a);
            for i in 0..3 {
                if beta[i].is_finite() {
                    per_dir[i] += beta[i] * beta[i] * a.m[i * 4];
                }
            }
        }
    }
    if let Some((st, r, _)) = tot.stat() {
        s -= st;
        dof = dof.saturating_sub(r);
    }
    (s.max(0.0), dof)
}

/// Structure score of residuals `res` (one per record) against one condition:
/// the larger of the all-pixel score and the pixel-resolved score (structure
/// that differs between pixels, e.g. a row pattern growing with exposure).
pub fn score(cond: &str, recs: &[Rec], res: &[f64], prep: &Prepared) -> Option<ConditionScore> {
    let stride = (recs.len() / 20_000).max(1);
    let sample: Vec<f64> = recs
        .iter()
        .step_by(stride)
        .filter_map(|r| cond_value(cond, r, prep))
        .collect();
    let edges = binning(&sample)?;
    let nb = edges.len() + 1;
    // pixel-resolved scores for the stepped conditions (few bins); the
    // continuous ones are scored over all pixels
    let per_pixel = matches!(
        cond,
        "ambient_klux" | "temperature_c" | "exposure_us" | "image_index"
    );
    let units = if per_pixel { prep.npix } else { 1 };
    // accumulators [pixel][bin] (pixel-resolved) and [bin] (all pixels)
    // partial sums over fixed chunks, merged in order: the same result on
    // every run whatever the thread scheduling (rayon's fold splits are not)
    let parts: Vec<(Vec<Acc>, Vec<Acc>)> = recs
        .par_chunks(16_384)
        .zip(res.par_chunks(16_384))
        .map(|(rc, rs)| {
            let (mut acc, mut g) = (vec![ZERO; units * nb], vec![ZERO; nb]);
            for (r, &e) in rc.iter().zip(rs) {
                let Some(x) = cond_value(cond, r, prep) else {
                    continue;
                };
                let b = edges.partition_point(|&t| t < x);
                let dir = [1.0, r.a * r.c, r.a * r.cd];
                let mut one = ZERO;
                for i in 0..3 {
                    one.v[i] = r.w * dir[i] * e;
                    for j in 0..3 {
                        one.m[i * 3 + j] = r.w * dir[i] * dir[j];
                    }
                }
                one.sx = x;
                one.n = 1;
                one.swr = r.w * e;
                one.sw = r.w;
                g[b].merge(&one);
                if per_pixel {
                    acc[r.pix as usize * nb + b].merge(&one);
                }
            }
            (acc, g)
        })
        .collect();
    let (mut accs, mut glob) = (vec![ZERO; units * nb], vec![ZERO; nb]);
    for (b, gb) in &parts {
        for (x, y) in accs.iter_mut().zip(b) {
            x.merge(y);
        }
        for (x, y) in glob.iter_mut().zip(gb) {
            x.merge(y);
        }
    }
    let mut per_dir = [0.0f64; 3];
    let (chi_g, dof_g) = between(&glob, &mut per_dir);
    let zf = |c: f64, d: usize| {
        if d == 0 {
            f64::NEG_INFINITY
        } else {
            (c - d as f64) / (2.0 * d as f64).sqrt()
        }
    };
    let z_g = zf(chi_g, dof_g);
    let (mut chi_p, mut dof_p) = (0.0, 0usize);
    let mut dir_p = [0.0f64; 3];
    if per_pixel {
        for p in 0..prep.npix {
            let (c, d) = between(&accs[p * nb..(p + 1) * nb], &mut dir_p);
            chi_p += c;
            dof_p += d;
        }
    }
    let z_p = zf(chi_p, dof_p);
    let (z, chi2, dof, pd) = if z_p > z_g {
        (z_p, chi_p, dof_p, dir_p)
    } else {
        (z_g, chi_g, dof_g, per_dir)
    };
    if dof == 0 {
        return None;
    }
    let bins = glob
        .iter()
        .filter(|a| a.n >= 4)
        .map(|a| {
            let (est, se) = match a.stat() {
                Some((_, _, beta)) => {
                    let mut se = [f64::NAN; 3];
                    for i in 0..3 {
                        if beta[i].is_finite() && a.m[i * 4] > 0.0 {
                            se[i] = 1.0 / a.m[i * 4].sqrt();
                        }
                    }
                    (beta, se)
                }
                None => ([f64::NAN; 3], [f64::NAN; 3]),
            };
            Bin {
                x: a.sx / a.n as f64,
                samples: a.n,
                est,
                se,
                mean_resid_lsb: if a.sw > 0.0 { a.swr / a.sw } else { 0.0 },
            }
        })
        .collect();
    let di = (0..3).max_by(|&a, &b| pd[a].total_cmp(&pd[b])).unwrap_or(0);
    Some(ConditionScore {
        condition: cond.to_string(),
        z,
        chi2,
        dof,
        direction: ["offset", "amplitude", "phase"][di],
        bins,
    })
}

/// Scores against every condition that varies, strongest first.
pub fn score_all(recs: &[Rec], res: &[f64], prep: &Prepared) -> Vec<ConditionScore> {
    let mut v: Vec<ConditionScore> = CONDITIONS
        .par_iter()
        .filter_map(|c| score(c, recs, res, prep))
        .collect();
    v.sort_by(|a, b| b.z.total_cmp(&a.z));
    v
}
