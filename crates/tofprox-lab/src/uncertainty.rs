//! How far a fitted effect's parameters may be off: standard errors with the
//! per-pixel parameters free, and profile-likelihood intervals of the
//! non-linear ones (what lmfit's `Minimizer` and `conf_interval` report).
//!
//! * **Standard errors** ([`profiled_standard_errors`]): the covariance of the
//!   effect's parameters is the inverse of the normal matrix JᵀWJ of *all*
//!   the model's parameters, restricted to them. The per-pixel offset, gain
//!   and phase enter only the samples of their pixel, so that matrix is
//!   block-diagonal in them, and the effect's block of the inverse is the
//!   inverse of the Schur complement
//!   S = A − Σ_p B_p D_p⁻¹ B_pᵀ (A: the effect's block, D_p: pixel p's
//!   3 × 3 block, B_p: their cross terms; Golub & Van Loan, *Matrix
//!   Computations*, 4th ed., §3.2.11 — the elimination of one block of a
//!   linear system). One pass over the samples and a 3 × 3 solve per pixel.
//!   The covariance is then scaled by χ²/dof of the model (lmfit's
//!   `scale_covar`, on by default): where the model leaves more than the
//!   noise the errors widen with it.
//! * **Profile intervals** ([`profile_intervals`]): for each non-linear
//!   parameter θ, the others (linear, non-linear and the global
//!   offset/gain/phase shifts) refitted with θ held at trial values, to find
//!   where χ² rises by 1 and by 4 times χ²/dof (1σ and 2σ, asymmetric; the
//!   scaled χ² as in lmfit's `conf_interval`, which uses the F-test on the
//!   same scaled χ²). The refits hold the per-pixel parameters; that their
//!   freedom widens the profile is put back by the ratio of the two
//!   curvatures (held and free), the exact factor where the profile is
//!   quadratic (our assumption elsewhere).
use std::collections::BTreeMap;

use rayon::prelude::*;
use serde::Serialize;
use tofprox_core::lsq::{Normal, Stop, levenberg_marquardt, solve_sym};

use crate::candidates::{JacobianRows, NUISANCE, accumulate, free_params, total};
use crate::error::LabError;
use crate::fit::LabModel;
use crate::prepared::Prepared;
use crate::sample::Sample;
use crate::signatures::Signature;
use crate::spec::{EffectFit, LabSpec};

/// The inverse of a symmetric positive (semi-)definite `n × n` matrix, by one
/// Cholesky solve per column (`None` when singular).
fn inverse(m: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut inv = vec![0.0; n * n];
    for j in 0..n {
        let mut e = vec![0.0; n];
        e[j] = 1.0;
        let col = solve_sym(m, &e)?;
        for i in 0..n {
            inv[i * n + j] = col[i];
        }
    }
    Some(inv)
}

/// One pixel's part of the normal matrix: D = Σ w j_p j_pᵀ of its own
/// parameters (k of them) and B = Σ w j_g j_pᵀ against the `n` global ones.
#[derive(Debug, Clone)]
pub struct PixelBlock {
    k: usize,
    d: Vec<f64>,
    b: Vec<f64>,
}

impl PixelBlock {
    /// An empty block of `k` pixel parameters against `n` global ones.
    pub fn zeros(n: usize, k: usize) -> Self {
        Self {
            k,
            d: vec![0.0; k * k],
            b: vec![0.0; n * k],
        }
    }
    /// One sample with global Jacobian row `jg`, pixel row `jp`, weight `w`.
    pub fn add(&mut self, jg: &[f64], jp: &[f64], w: f64) {
        let k = self.k;
        for (a, &x) in jp.iter().enumerate() {
            let wx = w * x;
            for (c, &y) in jp.iter().enumerate() {
                self.d[a * k + c] += wx * y;
            }
        }
        for (g, &x) in jg.iter().enumerate() {
            let wx = w * x;
            for (c, &y) in jp.iter().enumerate() {
                self.b[g * k + c] += wx * y;
            }
        }
    }
    /// Subtract B D⁻¹ Bᵀ from the `n × n` matrix `s`: this pixel's
    /// parameters eliminated. Parameters the pixel's samples do not inform
    /// (a zero diagonal: no illuminated sample for its gain and phase) are
    /// left out of D; a pixel whose D is still singular is skipped.
    pub fn eliminate_from(&self, s: &mut [f64], n: usize) {
        let k = self.k;
        let scale = (0..k).map(|a| self.d[a * k + a]).fold(0.0, f64::max);
        let keep: Vec<usize> = (0..k)
            .filter(|&a| self.d[a * k + a] > 1e-12 * scale && scale > 0.0)
            .collect();
        let m = keep.len();
        if m == 0 {
            return;
        }
        let dk: Vec<f64> = keep
            .iter()
            .flat_map(|&a| keep.iter().map(move |&c| self.d[a * k + c]))
            .collect();
        let Some(dinv) = inverse(&dk, m) else {
            return;
        };
        // C = B_keep D⁻¹ (n × m), then s −= C B_keepᵀ
        let bk = |g: usize, a: usize| self.b[g * k + keep[a]];
        let c: Vec<f64> = (0..n)
            .flat_map(|g| (0..m).map(move |a| (g, a)))
            .map(|(g, a)| (0..m).map(|e| bk(g, e) * dinv[e * m + a]).sum())
            .collect();
        for g in 0..n {
            for h in 0..n {
                s[g * n + h] -= (0..m).map(|a| c[g * m + a] * bk(h, a)).sum::<f64>();
            }
        }
    }
}

/// Which of the nuisance shifts (offset, gain, phase; the layout of
/// [`crate::candidates::accumulate`]) the model fits per pixel.
fn per_pixel(spec: &LabSpec) -> [bool; NUISANCE] {
    [
        spec.per_pixel_offset,
        spec.per_pixel_gain,
        spec.per_pixel_phase,
    ]
}

/// Runs of `recs` within one raw image in ascending pixel order (a residual
/// table's order: capture, raw image, pixel), as index ranges.
fn image_runs(recs: &[Sample]) -> Vec<(usize, usize)> {
    let mut runs = Vec::new();
    let mut start = 0;
    for i in 1..=recs.len() {
        let new_run = i == recs.len() || {
            let (a, b) = (&recs[i - 1], &recs[i]);
            a.cap != b.cap || a.k != b.k || b.pix <= a.pix
        };
        if new_run {
            runs.push((start, i));
            start = i;
        }
    }
    runs.retain(|(a, b)| b > a);
    runs
}

/// The normal matrix of the `global` parameters (indices into a
/// [`JacobianRows`] row) with the per-pixel copies of the nuisance shifts
/// `pixel` eliminated: the Schur complement A − Σ_p B_p D_p⁻¹ B_pᵀ. Pixels
/// in parallel ranges, each range's samples taken from every raw image's run
/// by binary search (the runs' memos share each raw image's terms); the
/// ranges' parts summed in order (the same result on every run).
fn schur_normal(
    rows: &JacobianRows<'_>,
    recs: &[Sample],
    npix: usize,
    (global, pixel): (&[usize], &[usize]),
) -> Vec<f64> {
    let (n, k) = (global.len(), pixel.len());
    let runs = image_runs(recs);
    let width = npix
        .div_ceil(4 * rayon::current_num_threads().max(1))
        .max(16);
    let ranges: Vec<(u32, u32)> = (0..npix)
        .step_by(width)
        .map(|p| (p as u32, (p + width).min(npix) as u32))
        .collect();
    let parts: Vec<Vec<f64>> = ranges
        .par_iter()
        .map(|&(p0, p1)| {
            let mut a = Normal::zeros(n);
            let mut blocks = vec![PixelBlock::zeros(n, k); (p1 - p0) as usize];
            let samples = runs.iter().flat_map(|&(s, e)| {
                let run = &recs[s..e];
                let lo = run.partition_point(|x| x.pix < p0);
                let hi = run.partition_point(|x| x.pix < p1);
                run[lo..hi].iter()
            });
            let (mut jg, mut jp) = (vec![0.0; n], vec![0.0; k]);
            rows.visit(samples, |r, j, res, w| {
                global.iter().zip(&mut jg).for_each(|(&i, x)| *x = j[i]);
                pixel.iter().zip(&mut jp).for_each(|(&i, x)| *x = j[i]);
                a.add(&jg, res, w);
                blocks[(r.pix - p0) as usize].add(&jg, &jp, w);
            });
            a.symmetrize();
            for b in &blocks {
                b.eliminate_from(&mut a.jtj, n);
            }
            a.jtj
        })
        .collect();
    let mut s = vec![0.0; n * n];
    for part in &parts {
        s.iter_mut().zip(part).for_each(|(x, y)| *x += y);
    }
    s
}

/// The standard errors of the fitted effect `fit` (signature `sig`) in
/// `model`, with the model's per-pixel parameters free (the Schur complement
/// over them, see the module's text) and scaled by `chi2_per_dof` as lmfit
/// does: those of `fit.lin`, then of `fit.nl` (NaN for one held on a grid).
/// `recs`: the residual table of `model` without the effect (that of the
/// candidate fit; only its samples' contexts enter the curvature).
pub fn profiled_standard_errors(
    sig: &dyn Signature,
    recs: &[Sample],
    prep: &Prepared,
    (model, chi2_per_dof): (&LabModel, f64),
    fit: &EffectFit,
) -> Vec<f64> {
    let nsig = sig.n_lin();
    let p = layout(fit);
    let own = per_pixel(&model.spec);
    let is_pixel = |i: usize| i >= nsig && i < nsig + NUISANCE && own[i - nsig];
    let free = free_params(sig);
    let global: Vec<usize> = free.iter().copied().filter(|&i| !is_pixel(i)).collect();
    let pixel: Vec<usize> = (nsig..nsig + NUISANCE).filter(|&i| is_pixel(i)).collect();
    let rows = JacobianRows::new(sig, prep, &p, true);
    let s = schur_normal(&rows, recs, prep.npix, (&global, &pixel));
    let scale = if chi2_per_dof.is_finite() && chi2_per_dof > 0.0 {
        chi2_per_dof
    } else {
        1.0
    };
    let mut se = vec![f64::NAN; p.len()];
    if let Some(cov) = inverse(&s, global.len()) {
        for (j, &i) in global.iter().enumerate() {
            se[i] = (cov[j * global.len() + j].max(0.0) * scale).sqrt();
        }
    }
    se.drain(nsig..nsig + NUISANCE);
    se
}

/// A parameter vector in the layout of [`crate::candidates::accumulate`]:
/// the effect's linear values, the nuisance shifts at zero, its non-linear ones.
fn layout(fit: &EffectFit) -> Vec<f64> {
    let mut p = fit.lin.clone();
    p.extend([0.0; NUISANCE]);
    p.extend_from_slice(&fit.nl);
    p
}

/// The profile-likelihood interval of one non-linear parameter.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProfileInterval {
    /// The fitted value (held into the parameter's range, where its law
    /// holds it: [`Signature::nl_bounds`]).
    pub value: f64,
    /// Lower ends at Δχ² = 1 and 4 (1σ, 2σ); NaN where none was found.
    pub lower: [f64; 2],
    /// Upper ends at Δχ² = 1 and 4 (1σ, 2σ); NaN where none was found.
    pub upper: [f64; 2],
    /// The ends (`lower_1sigma`, `upper_2sigma`, …) that stop at the bound
    /// of the parameter's range ([`Signature::nl_bounds`]): χ² does not rise
    /// that far inside it, so the interval reaches at least the bound.
    pub at_range_bound: Vec<String>,
    /// Refits made (each a Levenberg–Marquardt fit of the other parameters).
    pub refits: usize,
}

/// Levels of Δχ² (in units of χ²/dof) the intervals end at: 1σ and 2σ.
const LEVELS: [f64; 2] = [1.0, 4.0];

/// Secant steps per interval end (each a warm-started refit).
const END_STEPS: usize = 4;

/// Samples the profile refits use at most (a stride through larger tables;
/// the χ² rise is scaled back by the stride).
const PROFILE_SAMPLES: usize = 100_000;

/// The profile χ² of one non-linear parameter: χ²(θ) minimised over the
/// other free parameters, on every `stride`-th sample of `recs`.
struct Profile<'a> {
    sig: &'a dyn Signature,
    recs: &'a [Sample],
    prep: &'a Prepared,
    /// The fit's parameters (layout of `accumulate`).
    start: Vec<f64>,
    /// Where the next refit starts: the last refit's parameters on this
    /// side of the value (warm start), else `start`.
    warm: Vec<f64>,
    /// Index of the profiled parameter in `start`.
    held: usize,
    /// The other free parameters.
    others: Vec<usize>,
    stride: usize,
    refits: usize,
}

impl Profile<'_> {
    /// χ² (subsample) with the parameter at `theta`, the others refitted
    /// from the last refit (warm start); `None` when the refit fails.
    fn chi2_at(&mut self, theta: f64) -> Option<f64> {
        self.refits += 1;
        let mut base = self.warm.clone();
        base[self.held] = theta;
        let full = |q: &[f64]| {
            let mut v = base.clone();
            for (&i, x) in self.others.iter().zip(q) {
                v[i] = *x;
            }
            v
        };
        let q0: Vec<f64> = self.others.iter().map(|&i| base[i]).collect();
        let (sig, recs, prep, stride) = (self.sig, self.recs, self.prep, self.stride);
        let stop = Stop {
            max_iter: 20,
            tol_chi2: 1e-3 / stride as f64,
            rel_chi2: 0.0,
        };
        let r = levenberg_marquardt(
            |q| total(&accumulate(sig, recs, prep, &full(q), true, stride)).select(&self.others),
            &q0,
            stop,
        )
        .ok()?;
        if !r.chi2.is_finite() {
            return None;
        }
        self.warm = full(&r.params);
        Some(r.chi2)
    }
}

/// Profile-likelihood intervals of the fitted effect's non-linear parameters
/// (not the discrete ones), by name: see the module's text. `recs`: the
/// residual table of `model` without the effect; `se_free` and `se_held`:
/// each parameter's standard error (layout of [`profiled_standard_errors`])
/// with the per-pixel parameters free (scaled by χ²/dof) and held (not
/// scaled): their ratio turns the held profile's χ² rise into the scaled one
/// with the per-pixel parameters free.
/// Bounded work: per end and level at most four refits (`END_STEPS`).
pub fn profile_intervals(
    sig: &dyn Signature,
    recs: &[Sample],
    prep: &Prepared,
    fit: &EffectFit,
    (se_free, se_held): (&[f64], &[f64]),
) -> BTreeMap<String, ProfileInterval> {
    let nsig = sig.n_lin();
    let start = layout(fit);
    let free = free_params(sig);
    let stride = (recs.len() / PROFILE_SAMPLES).max(1);
    let bounds = sig.nl_bounds();
    let names = sig.nl_names();
    let mut out = BTreeMap::new();
    for (i, name) in names.iter().enumerate() {
        let held = nsig + NUISANCE + i;
        let (free_se, held_se) = (se_free[nsig + i], se_held[nsig + i]);
        if sig.nl_discrete(i) || !free_se.is_finite() || !held_se.is_finite() || free_se <= 0.0 {
            continue;
        }
        let mut prof = Profile {
            sig,
            recs,
            prep,
            start: start.clone(),
            warm: start.clone(),
            held,
            others: free.iter().copied().filter(|&j| j != held).collect(),
            stride,
            refits: 0,
        };
        // a value the fit left beyond its range is the law's at the bound
        // (the signatures clamp their parameters into `nl_bounds`: χ² is
        // flat beyond it), so the profile starts there — else an end on the
        // flat side would lie beyond the value (`[≤ 0, −0.096]` for a
        // `first_image_index` fitted at −0.096 in [0, 8])
        let bound = bounds.get(i).copied().flatten();
        let value = bound.map_or(fit.nl[i], |(lo, hi)| fit.nl[i].clamp(lo, hi));
        prof.start[held] = value;
        prof.warm = prof.start.clone();
        let Some(chi0) = prof.chi2_at(value) else {
            continue;
        };
        // Δχ² of the subsample back to all samples, in units of χ²/dof and
        // with the per-pixel parameters' freedom put back: `free_se` is the
        // scaled error with them free, `held_se` the unscaled one held
        let factor = stride as f64 * (held_se / free_se).powi(2);
        let mut iv = ProfileInterval {
            value,
            lower: [f64::NAN; 2],
            upper: [f64::NAN; 2],
            at_range_bound: Vec::new(),
            refits: 0,
        };
        for (side, sign) in [("lower", -1.0), ("upper", 1.0)] {
            prof.warm = prof.start.clone();
            let limit = bound.map(|(lo, hi)| if sign < 0.0 { lo } else { hi });
            let mut inside: ProfilePoint = (0.0, 0.0);
            for (l, level) in LEVELS.iter().enumerate() {
                let label = format!("{side}_{}sigma", l + 1);
                let found = find_end(
                    &mut prof,
                    (value, free_se),
                    (sign, *level, limit),
                    (chi0, factor),
                    inside,
                );
                let Some((v, at_bound, point)) = found else {
                    break;
                };
                if sign < 0.0 {
                    iv.lower[l] = v;
                } else {
                    iv.upper[l] = v;
                }
                if at_bound {
                    iv.at_range_bound.push(label);
                    // the wider levels stop at the bound too
                    for (m, _) in LEVELS.iter().enumerate().skip(l + 1) {
                        if sign < 0.0 {
                            iv.lower[m] = v;
                        } else {
                            iv.upper[m] = v;
                        }
                        iv.at_range_bound.push(format!("{side}_{}sigma", m + 1));
                    }
                    break;
                }
                inside = point;
            }
        }
        iv.refits = prof.refits;
        out.insert(name.clone(), iv);
    }
    out
}

/// A point of a profile: the distance from the value and √Δχ² there.
type ProfilePoint = (f64, f64);

/// Where the profile's Δχ² reaches `level` on the side `sign` of `value`,
/// from `inside` (a point below the level: the value itself, or the end of
/// the lower level): steps on √Δχ² (linear in θ where the profile is
/// quadratic) — extrapolated from the last point until one lies beyond the
/// level, then interpolated within that bracket (regula falsi). The end and
/// whether it is the range's bound `limit` (reached before the level), with
/// the point found; `None` when a refit fails or no point beyond the level
/// was found.
fn find_end(
    prof: &mut Profile<'_>,
    (value, se): (f64, f64),
    (sign, level, limit): (f64, f64, Option<f64>),
    (chi0, factor): (f64, f64),
    inside: ProfilePoint,
) -> Option<(f64, bool, ProfilePoint)> {
    let target = level.sqrt();
    let room = limit.map_or(f64::INFINITY, |b| (sign * (b - value)).max(0.0));
    let (mut lo, mut hi) = (inside, None::<ProfilePoint>);
    let mut dist = if lo.1 > 0.0 {
        lo.0 * target / lo.1
    } else {
        se * target
    };
    for _ in 0..END_STEPS {
        let clipped = dist >= room;
        if clipped {
            dist = room;
        }
        let delta = ((prof.chi2_at(value + sign * dist)? - chi0) * factor).max(0.0);
        let root = delta.sqrt();
        if clipped && root < target {
            return Some((value + sign * dist, true, (dist, root)));
        }
        if (root - target).abs() < 0.01 * target {
            return Some((value + sign * dist, false, (dist, root)));
        }
        if root < target {
            lo = (dist, root);
        } else {
            hi = Some((dist, root));
        }
        dist = match hi {
            Some(h) => bracket_step(lo, h, target),
            // not yet beyond the level: extrapolate through the origin's line
            None if root > 0.0 => (dist * target / root).max(1.2 * dist),
            None => 2.0 * dist,
        };
    }
    let h = hi?;
    // not converged: the bracket's outer end where it is still wide (the
    // interval overstated, never understated), else its interpolation
    let d = if h.0 - lo.0 > 0.1 * h.0 {
        h.0
    } else {
        bracket_step(lo, h, target)
    };
    Some((value + sign * d, false, (d, target)))
}

/// The next distance inside the bracket `lo` (below the level `target`) –
/// `hi` (beyond it): regula falsi on √Δχ², or the bracket's middle where
/// that stays within a tenth of either end (a profile flat at first and
/// steep later — a parameter at its range's bound — made regula falsi creep
/// from the flat end: `first_image_index`'s upper end 10⁻¹⁰ from its value).
fn bracket_step(lo: ProfilePoint, hi: ProfilePoint, target: f64) -> f64 {
    let d = lo.0 + (target - lo.1) * (hi.0 - lo.0) / (hi.1 - lo.1);
    let tenth = 0.1 * (hi.0 - lo.0);
    if d < lo.0 + tenth || d > hi.0 - tenth {
        0.5 * (lo.0 + hi.0)
    } else {
        d
    }
}

/// A fitted effect's uncertainty: [`profiled_standard_errors`] and
/// [`profile_intervals`].
#[derive(Debug, Clone, PartialEq)]
pub struct Uncertainty {
    /// Standard errors with the per-pixel parameters free, scaled by χ²/dof:
    /// those of the linear parameters, then of the non-linear ones.
    pub standard_errors: Vec<f64>,
    /// Profile intervals of the non-linear parameters by name.
    pub intervals: BTreeMap<String, ProfileInterval>,
}

/// The uncertainty of `fit` (signature `sig`) as fitted in `model`, whose
/// χ²/dof is `chi2_per_dof`: its residual table without the effect, then
/// the standard errors (per-pixel parameters free and held) and the profile
/// intervals on it.
pub fn effect_uncertainty(
    sig: &dyn Signature,
    prep: &Prepared,
    (model, chi2_per_dof): (&LabModel, f64),
    fit: &EffectFit,
) -> Result<Uncertainty, LabError> {
    let mut without = model.clone();
    without.effects.retain(|e| e.id != fit.id);
    let recs = without.records(prep)?;
    let free = profiled_standard_errors(sig, &recs, prep, (model, chi2_per_dof), fit);
    let held = crate::candidates::effect_standard_errors(sig, &recs, prep, fit);
    let intervals = profile_intervals(sig, &recs, prep, fit, (&free, &held));
    Ok(Uncertainty {
        standard_errors: free,
        intervals,
    })
}
