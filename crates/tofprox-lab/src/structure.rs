//! Where the model fails: residuals binned against every condition that
//! varies, projected on three directions per sample — offset (1), amplitude
//! (A·C) and phase (A·C') — and each bin's estimate compared with its
//! standard error. Under noise the sum over bins of βᵀ M β is χ² with
//! (channels × bins) degrees of freedom; the structure score is its z.
use rayon::prelude::*;
use serde::Serialize;

use crate::prepared::Prepared;
use crate::sample::{Rec, Sample};
use tofprox_core::lsq::solve_sym;

/// The conditions every recording is scored against (when they vary); the
/// recording's own numeric conditions are added by name ([`conditions`]).
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

/// Every condition of this recording: [`CONDITIONS`] and the user's keys.
pub fn conditions(prep: &Prepared) -> Vec<String> {
    CONDITIONS
        .iter()
        .map(|c| c.to_string())
        .chain(prep.extra_keys.iter().cloned())
        .collect()
}

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
    /// The condition's name (a [`CONDITIONS`] entry or one of the user's keys).
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
    /// Size of the structure (its χ² beyond the noise's expectation) as an
    /// RMS code error in LSB: √(max(0, χ² − dof)/Σw).
    pub size_lsb: f64,
    /// The same as a depth-equivalent error in mm: the code error over the
    /// amplitude (phase-equivalent, rad) times c/(4πf),
    /// √(max(0, χ² − dof)/Σw·A²)·c/(4πf).
    pub size_mm: f64,
    /// The global bins, those with at least 4 samples.
    pub bins: Vec<Bin>,
}

/// A condition resolved once per scan (not matched by name per sample).
#[derive(Debug, Clone, Copy)]
enum Cond {
    Distance,
    Phase,
    Ambient,
    Temperature,
    Exposure,
    Amplitude,
    ImageIndex,
    CaptureIndex,
    Column,
    AdcChannel,
    Row,
    AdcCode,
    /// One of the recording's own keys, by its index in `Prepared::extra_keys`.
    Extra(usize),
}

impl Cond {
    fn parse(cond: &str, prep: &Prepared) -> Option<Self> {
        Some(match cond {
            "distance_m" => Self::Distance,
            "phase" => Self::Phase,
            "ambient_klux" => Self::Ambient,
            "temperature_c" => Self::Temperature,
            "exposure_us" => Self::Exposure,
            "amplitude" => Self::Amplitude,
            "image_index" => Self::ImageIndex,
            "capture_index" => Self::CaptureIndex,
            "column" => Self::Column,
            "adc_channel" => Self::AdcChannel,
            "row" => Self::Row,
            "adc_code" => Self::AdcCode,
            other => Self::Extra(prep.extra_keys.iter().position(|k| k == other)?),
        })
    }

    #[inline]
    fn value(self, r: &Rec, prep: &Prepared) -> Option<f64> {
        let cap = &prep.caps[r.cap as usize];
        let p = r.pix as usize;
        match self {
            Self::Distance => cap.distance_m.filter(|_| cap.illum),
            Self::Phase => cap
                .illum
                .then(|| r.phi.rem_euclid(std::f64::consts::TAU).to_degrees()),
            Self::Ambient => Some(cap.ambient_klux),
            Self::Temperature => cap.temperature_c,
            Self::Exposure => Some(cap.exposure_us),
            Self::Amplitude => cap.illum.then_some(r.a),
            Self::ImageIndex => Some(f64::from(r.k)),
            Self::CaptureIndex => Some(f64::from(r.cap)),
            Self::Column => Some((p % prep.cols) as f64),
            // the model's mirrored 32-column read-out map (thesis 3.3.7.1)
            Self::AdcChannel => Some(tofprox_model::effects::fixed_pattern::adc_channel(
                prep.roi_origin[1] + p % prep.cols,
            ) as f64),
            Self::Row => Some((p / prep.cols) as f64),
            Self::AdcCode => Some(r.x + prep.mid),
            Self::Extra(i) => cap.extra.get(i).copied().filter(|v| v.is_finite()),
        }
    }
}

/// Value of condition `cond` at a sample (None = not applicable).
pub fn cond_value(cond: &str, r: &Rec, prep: &Prepared) -> Option<f64> {
    Cond::parse(cond, prep)?.value(r, prep)
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
    /// Σ w·A² (phase information).
    swa2: f64,
}

const ZERO: Acc = Acc {
    m: [0.0; 9],
    v: [0.0; 3],
    sx: 0.0,
    n: 0,
    swr: 0.0,
    sw: 0.0,
    swa2: 0.0,
};

impl Acc {
    /// Add one sample: weight `w`, directions `dir`, residual `e`, condition value `x`.
    #[inline]
    fn add(&mut self, w: f64, dir: &[f64; 3], e: f64, x: f64, a: f64) {
        for i in 0..3 {
            let wd = w * dir[i];
            self.v[i] += wd * e;
            for (j, dj) in dir.iter().enumerate().skip(i) {
                self.m[i * 3 + j] += wd * dj;
            }
        }
        self.sx += x;
        self.n += 1;
        self.swr += w * e;
        self.sw += w;
        self.swa2 += w * a * a;
    }
    /// Mirror the upper triangle filled by `add` into the lower one.
    fn symmetrize(&mut self) {
        for i in 0..3 {
            for j in 0..i {
                self.m[i * 3 + j] = self.m[j * 3 + i];
            }
        }
    }
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
        self.swa2 += y.swa2;
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

/// Structure score of the residuals in `recs` against one condition:
/// the larger of the all-pixel score and the pixel-resolved score (structure
/// that differs between pixels, e.g. a row pattern growing with exposure).
pub fn score(cond: &str, recs: &[Sample], prep: &Prepared) -> Option<ConditionScore> {
    let which = Cond::parse(cond, prep)?;
    let stride = (recs.len() / 20_000).max(1);
    let sample: Vec<f64> = recs
        .iter()
        .step_by(stride)
        .filter_map(|s| which.value(&s.rec(prep), prep))
        .collect();
    let edges = binning(&sample)?;
    let nb = edges.len() + 1;
    // pixel-resolved scores for the stepped conditions (few bins); the
    // continuous ones are scored over all pixels
    let per_pixel = matches!(
        which,
        Cond::Ambient | Cond::Temperature | Cond::Exposure | Cond::ImageIndex | Cond::Extra(_)
    );
    let units = if per_pixel { prep.npix } else { 1 };
    // accumulators [pixel][bin] (pixel-resolved) and [bin] (all pixels), one
    // sequential pass (the conditions run in parallel, `score_all`): one
    // set of accumulators per condition whatever the size of the recording,
    // and the same sums in the same order on every run
    let (mut accs, mut glob) = (vec![ZERO; units * nb], vec![ZERO; nb]);
    for s in recs {
        let r = s.rec(prep);
        let Some(x) = which.value(&r, prep) else {
            continue;
        };
        let b = edges.partition_point(|&t| t < x);
        let dir = [1.0, r.a * r.c, r.a * r.cd];
        glob[b].add(r.w, &dir, r.r, x, r.a);
        if per_pixel {
            accs[r.pix as usize * nb + b].add(r.w, &dir, r.r, x, r.a);
        }
    }
    accs.iter_mut().for_each(Acc::symmetrize);
    glob.iter_mut().for_each(Acc::symmetrize);
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
    let (sw, swa2) = glob
        .iter()
        .fold((0.0, 0.0), |s, a| (s.0 + a.sw, s.1 + a.swa2));
    let (size_lsb, size_mm) = structure_size(chi2 - dof as f64, sw, swa2, prep.mm_per_rad());
    Some(ConditionScore {
        condition: cond.to_string(),
        z,
        chi2,
        dof,
        size_lsb,
        size_mm,
        direction: ["offset", "amplitude", "phase"][di],
        bins,
    })
}

/// Size of a systematic residual whose χ² exceeds the noise's expectation by
/// `excess`, over samples with Σw = `sw` and Σw·A² = `swa2`: (RMS code error in
/// LSB, depth-equivalent RMS in mm). The depth equivalent divides each code
/// error by its amplitude (a code error δ moves the phase by at most δ/A) and
/// converts phase to depth by c/(4πf) (eq. 2.6), weighted as the data inform it.
pub fn structure_size(excess: f64, sw: f64, swa2: f64, mm_per_rad: f64) -> (f64, f64) {
    let e = excess.max(0.0);
    let lsb = if sw > 0.0 { (e / sw).sqrt() } else { 0.0 };
    let mm = if swa2 > 0.0 {
        (e / swa2).sqrt() * mm_per_rad
    } else {
        0.0
    };
    (lsb, mm)
}

/// Scores against every condition that varies, strongest first.
pub fn score_all(recs: &[Sample], prep: &Prepared) -> Vec<ConditionScore> {
    let mut v: Vec<ConditionScore> = conditions(prep)
        .par_iter()
        .filter_map(|c| score(c, recs, prep))
        .collect();
    v.sort_by(|a, b| b.z.total_cmp(&a.z));
    v
}
