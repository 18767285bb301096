//! Fitting one signature on top of the current model: variable projection
//! over a grid of the non-linear parameters, then Levenberg–Marquardt on all
//! of them, and block cross-validation from per-fold normal equations.
use rayon::prelude::*;

use crate::error::LabError;
use crate::prepared::{FOLDS, Prepared};
use crate::sample::{Rec, Sample};
use crate::signatures::{FixedMemo, ImageMemo, Signature};
use crate::spec::EffectFit;
use tofprox_core::lsq::{Normal, Stop, levenberg_marquardt, solve_sym};

/// Result of fitting one signature.
#[derive(Debug, Clone)]
pub struct SignatureFit {
    /// Fitted linear coefficients, one per [`Signature::lin_names`] entry.
    pub lin: Vec<f64>,
    /// Fitted non-linear parameters, one per [`Signature::nl_names`] entry.
    pub nl: Vec<f64>,
    /// χ² of the residual after the fit (over the given records).
    pub chi2: f64,
    /// χ² before (the records' own residual).
    pub chi2_before: f64,
    /// Σ over folds of the held-out χ² with parameters trained on the other folds.
    pub cv_chi2: f64,
    /// Σ over folds of the held-out χ² without the effect.
    pub cv_chi2_before: f64,
    /// Free parameters of the effect (`lin` + `nl`, nuisance shifts not counted).
    pub n_params: usize,
    /// Fitted global shifts of offset (LSB), relative gain and phase (rad).
    pub nuisance: [f64; NUISANCE],
    /// Standard errors of `lin` and of `nl` (`standard_errors`; NaN for a discrete one,
    /// and all NaN from [`fit_values`] until [`add_standard_errors`]).
    pub lin_se: Vec<f64>,
    /// (see `lin_se`)
    pub nl_se: Vec<f64>,
}

/// Standard errors of the parameters `p` (layout of [`accumulate`]) from the curvature of χ²
/// at the optimum: √diag((JᵀWJ)⁻¹) over the `free` ones (the nuisance shifts among them, so
/// their correlation with the effect widens its errors), NaN for the others. W = 1/σ² of the
/// noise model: errors of the noise, not scaled by χ²/dof.
fn standard_errors(
    sig: &dyn Signature,
    recs: &[Sample],
    prep: &Prepared,
    p: &[f64],
    free: &[usize],
) -> Vec<f64> {
    let m = total(&accumulate(sig, recs, prep, p, true, 1)).select(free);
    let mut se = vec![f64::NAN; p.len()];
    for (j, &i) in free.iter().enumerate() {
        let mut e = vec![0.0; free.len()];
        e[j] = 1.0;
        if let Some(col) = solve_sym(&m.jtj, &e) {
            se[i] = col[j].max(0.0).sqrt();
        }
    }
    se
}

/// Standard errors of the fitted effect `fit` inside a fitted model (`recs`: that model's
/// residual table): as `standard_errors` at the effect's values, with the global
/// offset/gain/phase shifts free at zero (the model's per-pixel parameters hold them); those of
/// `fit.lin`, then of `fit.nl` (NaN for one held on a grid).
pub fn effect_standard_errors(
    sig: &dyn Signature,
    recs: &[Sample],
    prep: &Prepared,
    fit: &EffectFit,
) -> Vec<f64> {
    let nlin = sig.n_lin() + NUISANCE;
    let mut p = fit.lin.clone();
    p.extend([0.0; NUISANCE]);
    p.extend_from_slice(&fit.nl);
    let mut se = standard_errors(sig, recs, prep, &p, &free_params(sig));
    se.drain(sig.n_lin()..nlin);
    se
}

/// The parameters Levenberg–Marquardt refines and [`standard_errors`] covers, in the
/// layout of [`accumulate`]: every linear one and nuisance shift, and the non-linear
/// ones but the discrete ones (held at their grid value: a zero Jacobian column would
/// make JᵀJ singular).
pub(crate) fn free_params(sig: &dyn Signature) -> Vec<usize> {
    let nlin = sig.n_lin() + NUISANCE;
    let held = held_layout(sig);
    (0..nlin + sig.nl_start().len())
        .filter(|&i| i < nlin || !sig.nl_discrete(i - nlin))
        .filter(|&i| held[i].is_none())
        .collect()
}

/// The held values ([`Signature::held`], `crate::hold`) in the layout of [`accumulate`]:
/// `Some(value)` for a parameter held, None for one fitted (the nuisance shifts always).
fn held_layout(sig: &dyn Signature) -> Vec<Option<f64>> {
    let nsig = sig.n_lin();
    let mut out = vec![None; nsig + NUISANCE + sig.nl_start().len()];
    for (i, v) in sig.held().into_iter().enumerate() {
        let at = if i < nsig { i } else { i + NUISANCE };
        if let Some(o) = out.get_mut(at) {
            *o = v;
        }
    }
    out
}

/// The linear parameters' least-squares solution of `t` (normal equations at zero) with
/// those `held` (the layout's first `t.n`) at their values: the free ones solve
/// JᵀWJ_FF·x_F = JᵀWr_F − JᵀWJ_FH·v_H.
fn solve_linear(t: &Normal, held: &[Option<f64>]) -> Option<Vec<f64>> {
    let held_at = |i: usize| held.get(i).copied().flatten();
    if (0..t.n).all(|i| held_at(i).is_none()) {
        return solve_sym(&t.jtj, &t.jtr);
    }
    let free: Vec<usize> = (0..t.n).filter(|&i| held_at(i).is_none()).collect();
    let mut sub = t.select(&free);
    for (a, &i) in free.iter().enumerate() {
        for j in 0..t.n {
            if let Some(v) = held_at(j) {
                sub.jtr[a] -= t.jtj[i * t.n + j] * v;
            }
        }
    }
    let xf = solve_sym(&sub.jtj, &sub.jtr)?;
    let mut x: Vec<f64> = (0..t.n).map(|i| held_at(i).unwrap_or(0.0)).collect();
    for (a, &i) in free.iter().enumerate() {
        x[i] = xf[a];
    }
    Some(x)
}

/// The standard errors of `f` (a [`fit_values`] of `sig` to `recs`) into its
/// `lin_se` and `nl_se`: what [`fit_signature`] adds to the fitted values — one pass
/// over every sample with the Jacobian, which only a reported fit needs.
pub fn add_standard_errors(
    sig: &dyn Signature,
    recs: &[Sample],
    prep: &Prepared,
    f: &mut SignatureFit,
) {
    let nsig = f.lin.len();
    let mut p = f.lin.clone();
    p.extend_from_slice(&f.nuisance);
    p.extend_from_slice(&f.nl);
    let se = standard_errors(sig, recs, prep, &p, &free_params(sig));
    f.lin_se = se[..nsig].to_vec();
    f.nl_se = se[nsig + NUISANCE..].to_vec();
}

/// Global nuisance directions refitted with every candidate: the shifts of
/// offset, gain and phase that the per-pixel parameters absorbed from the
/// effect while the model was fitted without it.
pub const NUISANCE: usize = 3;

#[inline]
fn nuisance(r: &Rec) -> [f64; NUISANCE] {
    [1.0, r.a * r.c, r.a * r.cd]
}

/// Convergence of the non-linear parameters: at most 30 iterations; a χ²
/// decrease below 10⁻² (in units of the noise) is a parameter change of 0.1
/// standard errors.
const LM_STOP: Stop = Stop {
    max_iter: 30,
    tol_chi2: 1e-2,
    rel_chi2: 0.0,
};

/// A finite-difference step h, the parameter vector nl + h·e_i and its
/// prepared law ([`Signature::prepare`]); `None` for a discrete parameter
/// (held at its grid value: no derivative, no step).
type Step = Option<(f64, Vec<f64>, Vec<f64>)>;

/// The [`Step`] of each of the first `nnl` non-linear parameters.
fn fd_steps(sig: &dyn Signature, nl: &[f64], nnl: usize) -> Vec<Step> {
    (0..nnl)
        .map(|i| {
            (!sig.nl_discrete(i)).then(|| {
                let h = 1e-4 * nl[i].abs().max(1e-2);
                let mut nlh = nl.to_vec();
                nlh[i] = nl[i] + h;
                let law = sig.prepare(&nlh);
                (h, nlh, law)
            })
        })
        .collect()
}

/// The prepared laws of nl (`law`, first) and of its `steps`, and each
/// step's slot among them ([`Signature::fixed_all`] evaluates them together).
fn step_laws<'a>(law: &'a [f64], steps: &'a [Step]) -> (Vec<&'a [f64]>, Vec<Option<usize>>) {
    let mut laws = vec![law];
    let slots = steps
        .iter()
        .map(|s| {
            s.as_ref().map(|(_, _, l)| {
                laws.push(l.as_slice());
                laws.len() - 1
            })
        })
        .collect();
    (laws, slots)
}

/// The Jacobian rows of a signature at one parameter vector `p` (layout
/// [signature lin…, nuisance…, signature nl…]; the non-linear ones by finite
/// differences when `deriv`): the laws prepared once, visited sample by
/// sample by [`JacobianRows::visit`].
pub(crate) struct JacobianRows<'a> {
    sig: &'a dyn Signature,
    prep: &'a Prepared,
    p: &'a [f64],
    nnl: usize,
    steps: Vec<Step>,
    law: Vec<f64>,
}

impl<'a> JacobianRows<'a> {
    /// The rows of `sig` at `p`, with the non-linear columns when `deriv`.
    pub(crate) fn new(
        sig: &'a dyn Signature,
        prep: &'a Prepared,
        p: &'a [f64],
        deriv: bool,
    ) -> Self {
        let nlin = sig.n_lin() + NUISANCE;
        let nnl = if deriv { p.len() - nlin } else { 0 };
        let steps = fd_steps(sig, &p[nlin..], nnl);
        let law = sig.prepare(&p[nlin..]);
        Self {
            sig,
            prep,
            p,
            nnl,
            steps,
            law,
        }
    }

    /// Columns of a row: the linear ones and nuisance shifts, then the non-linear ones.
    pub(crate) fn width(&self) -> usize {
        self.sig.n_lin() + NUISANCE + self.nnl
    }

    /// `f(sample, row, residual − Δ(p), weight)` for each of `samples` in
    /// order (capture, raw-image order lets the memos share each raw image's terms).
    pub(crate) fn visit<'s>(
        &self,
        samples: impl Iterator<Item = &'s Sample>,
        mut f: impl FnMut(&Rec, &[f64], f64, f64),
    ) {
        let (sig, prep) = (self.sig, self.prep);
        let nsig = sig.n_lin();
        let nlin = nsig + NUISANCE;
        let (lin_all, nl) = self.p.split_at(nlin);
        let (lin, nui) = lin_all.split_at(nsig);
        let (laws, slots) = step_laws(&self.law, &self.steps);
        let mut b = vec![0.0; nsig];
        let mut b2 = vec![0.0; nsig];
        let mut j = vec![0.0; self.width()];
        let mut fx = vec![0.0; laws.len()];
        // one memo per parameter vector: nl and each finite-difference step
        let mut memo = ImageMemo::default();
        let mut memo_h = vec![ImageMemo::default(); self.nnl];
        let mut memo_fixed = FixedMemo::default();
        for s in samples {
            let r = &s.rec(prep);
            let cap = &prep.caps[r.cap as usize];
            // (a signature without linear terms has no basis to evaluate)
            if nsig > 0 {
                memo.basis(sig, nl, r, cap, &mut b);
            }
            let nu = nuisance(r);
            let dn: f64 = nu.iter().zip(nui).map(|(x, y)| x * y).sum();
            memo_fixed.fixed_all(sig, &laws, r, cap, &mut fx);
            let d: f64 = fx[0] + b.iter().zip(lin).map(|(x, y)| x * y).sum::<f64>() + dn;
            j[..nsig].copy_from_slice(&b);
            j[nsig..nlin].copy_from_slice(&nu);
            for (i, (step, slot)) in self.steps.iter().zip(&slots).enumerate() {
                let (Some((h, nlh, _)), Some(k)) = (step, slot) else {
                    j[nlin + i] = 0.0;
                    continue;
                };
                if nsig > 0 {
                    memo_h[i].basis_sharing(sig, nlh, r, cap, (&memo, &b), &mut b2);
                }
                let d2: f64 = fx[*k] + b2.iter().zip(lin).map(|(x, y)| x * y).sum::<f64>() + dn;
                j[nlin + i] = (d2 - d) / h;
            }
            f(r, &j, r.r - d, r.w);
        }
    }
}

/// The normal equations of `sig` at `p` per cross-validation fold (layout of
/// [`JacobianRows`]), over every `stride`-th sample.
pub(crate) fn accumulate(
    sig: &dyn Signature,
    recs: &[Sample],
    prep: &Prepared,
    p: &[f64],
    deriv: bool,
    stride: usize,
) -> Vec<Normal> {
    let rows = JacobianRows::new(sig, prep, p, deriv);
    let n = rows.width();
    let chunk = 8192;
    let parts: Vec<Vec<Normal>> = recs
        .par_chunks(chunk * stride)
        .map(|ch| {
            let mut acc: Vec<Normal> = (0..FOLDS).map(|_| Normal::zeros(n)).collect();
            rows.visit(ch.iter().step_by(stride), |r, j, res, w| {
                acc[usize::from(r.fold) % FOLDS].add(j, res, w);
            });
            acc
        })
        .collect();
    let mut out: Vec<Normal> = (0..FOLDS).map(|_| Normal::zeros(n)).collect();
    for part in parts {
        for (o, a) in out.iter_mut().zip(&part) {
            o.merge(a);
        }
    }
    for o in &mut out {
        o.symmetrize();
    }
    out
}

pub(crate) fn total(folds: &[Normal]) -> Normal {
    let mut t = Normal::zeros(folds[0].n);
    for f in folds {
        t.merge(f);
    }
    t
}

/// The block of capture `cap` in [`cv_refit`]: pairs of consecutive captures
/// dealt round the [`FOLDS`] blocks.
fn form_block(cap: u32) -> usize {
    (cap / 2) as usize % FOLDS
}

/// The most samples [`cv_refit`] trains and scores on (a stride through larger tables).
pub const CV_SUBSAMPLE: usize = 30_000;

/// Block cross-validation of every parameter of a fitted signature (its
/// non-linear ones too, which [`SignatureFit::cv_chi2`] holds at the fit on
/// all blocks): per held-out block, the signature refitted on the other
/// blocks (started from `f`, the fit on all of them) and its χ² on the
/// held-out block (large tables: both on a subsample). Returns Σ over
/// blocks ([`HeldOut`]): what compares
/// forms with different numbers of non-linear parameters
/// (`crate::shape::choose_form`). The blocks are whole captures, pairs of
/// consecutive ones (a capture and its repeat together) dealt round the
/// blocks in recording order (`form_block`): each block spans the
/// drivers' range, so the score measures how a form predicts conditions it
/// did not see between those it did — not its extrapolation beyond the
/// recorded range, where a shape is flat by definition (the distance blocks
/// of [`SignatureFit::cv_chi2`] hold out the nearest, brightest captures
/// whole).
pub fn cv_refit(
    sig: &dyn Signature,
    recs: &[Sample],
    prep: &Prepared,
    f: &SignatureFit,
) -> Result<HeldOut, LabError> {
    // large tables: a subsample of ≤ 30 000 samples for training and scoring
    // (a choice between forms, not the fit: ~6 000 samples per block)
    let stride = (recs.len() / CV_SUBSAMPLE).max(1);
    let start = EffectFit {
        id: sig.id().to_string(),
        lin: f.lin.clone(),
        nl: f.nl.clone(),
    };
    // the blocks in parallel, summed in block order
    let per_block: Vec<Option<(f64, f64, usize)>> = (0..FOLDS)
        .into_par_iter()
        .map(|fold| {
            let held: Vec<Sample> = recs
                .iter()
                .step_by(stride)
                .filter(|r| form_block(r.cap) == fold)
                .copied()
                .collect();
            let train: Vec<Sample> = recs
                .iter()
                .step_by(stride)
                .filter(|r| form_block(r.cap) != fold)
                .copied()
                .collect();
            if held.is_empty() || train.is_empty() {
                return Ok(None);
            }
            let t = fit_values(sig, &train, prep, Some(&start))?;
            let mut p = t.lin;
            p.extend_from_slice(&t.nuisance);
            p.extend_from_slice(&t.nl);
            let cv = total(&accumulate(sig, &held, prep, &p, false, 1)).chi2;
            let before = held.iter().map(Sample::chi2).sum::<f64>();
            Ok(Some((cv, before, held.len())))
        })
        .collect::<Result<_, LabError>>()?;
    let mut out = HeldOut::default();
    for (c, b, n) in per_block.into_iter().flatten() {
        out.chi2 += c;
        out.chi2_before += b;
        out.samples += n;
    }
    Ok(out)
}

/// What [`cv_refit`] scores: Σ over held-out blocks.
#[derive(Debug, Clone, Copy, Default)]
pub struct HeldOut {
    /// χ² of the held-out samples with the form fitted on the other blocks.
    pub chi2: f64,
    /// Their χ² without the effect.
    pub chi2_before: f64,
    /// How many samples were held out (each of the scored ones once).
    pub samples: usize,
}

/// Fit `sig` to the residuals in `recs` (r = measured − current model), with the
/// standard errors of its parameters.
pub fn fit_signature(
    sig: &dyn Signature,
    recs: &[Sample],
    prep: &Prepared,
    start: Option<&EffectFit>,
) -> Result<SignatureFit, LabError> {
    let mut f = fit_values(sig, recs, prep, start)?;
    add_standard_errors(sig, recs, prep, &mut f);
    Ok(f)
}

/// [`fit_signature`] without the standard errors (`lin_se` and `nl_se` NaN; see
/// [`add_standard_errors`]): for fits whose values alone are used (cross-validation,
/// the model's enabled effects, forms compared).
pub fn fit_values(
    sig: &dyn Signature,
    recs: &[Sample],
    prep: &Prepared,
    start: Option<&EffectFit>,
) -> Result<SignatureFit, LabError> {
    let nlin = sig.n_lin() + NUISANCE;
    if recs.is_empty() {
        return Err(LabError::data("no valid samples to fit"));
    }
    // Variable projection over the grid (on a subsample when large).
    let stride = (recs.len() / 60_000).max(1);
    // A previous fit (from an earlier round) is refined without a new grid search.
    // (a fitted effect, not the placeholder fit_model starts an enabled one from)
    let warm = start.filter(|s| {
        s.nl.len() == sig.nl_start().len()
            && (s.lin.iter().any(|v| *v != 0.0) || s.nl != sig.nl_start())
    });
    let mut grid = match warm {
        Some(s) => vec![s.nl.clone()],
        None => sig.nl_grid(recs, prep),
    };
    if grid.is_empty() {
        grid.push(sig.nl_start());
    }
    // held non-linear parameters at their values on every grid point (crate::hold)
    let held = held_layout(sig);
    for nl in &mut grid {
        for (i, v) in nl.iter_mut().enumerate() {
            if let Some(h) = held.get(nlin + i).copied().flatten() {
                *v = h;
            }
        }
    }
    let mut unique: Vec<Vec<f64>> = Vec::with_capacity(grid.len());
    for nl in grid {
        if !unique.contains(&nl) {
            unique.push(nl);
        }
    }
    let grid = unique;
    // The best grid point of each setting of the discrete parameters: those
    // are chosen after the continuous ones are refined, since at a coarse grid
    // point the wrong end of a family can fit better than the right one.
    let n_nl = sig.nl_start().len();
    let discrete: Vec<usize> = (0..n_nl).filter(|&i| sig.nl_discrete(i)).collect();
    let mut best: Vec<(Vec<f64>, f64, Vec<f64>)> = Vec::new();
    for nl in &grid {
        let mut p = vec![0.0; nlin];
        p.extend_from_slice(nl);
        let t = total(&accumulate(sig, recs, prep, &p, false, stride));
        let Some(lin) = solve_linear(&t, &held) else {
            continue;
        };
        let chi = t.chi2_after(&lin);
        let mut full = lin;
        full.extend_from_slice(nl);
        let key: Vec<f64> = discrete
            .iter()
            .filter_map(|&i| nl.get(i).copied())
            .collect();
        match best.iter_mut().find(|b| b.0 == key) {
            Some(b) if chi < b.1 => (b.1, b.2) = (chi, full),
            Some(_) => {}
            None => best.push((key, chi, full)),
        }
    }
    if best.is_empty() {
        return Err(LabError::numerical(format!(
            "{}: no grid point gave a solvable fit",
            sig.id()
        )));
    }
    let mut p = best[0].2.clone();
    let free = free_params(sig);
    if n_nl > 0 {
        // LM on a subsample (the non-linear parameters are few and smooth) …
        let mut refined: Option<(f64, Vec<f64>)> = None;
        for (_, _, start) in &best {
            let full = |q: &[f64]| {
                let mut v = start.clone();
                for (&i, x) in free.iter().zip(q) {
                    v[i] = *x;
                }
                v
            };
            let q0: Vec<f64> = free.iter().map(|&i| start[i]).collect();
            let r = levenberg_marquardt(
                |q| total(&accumulate(sig, recs, prep, &full(q), true, stride)).select(&free),
                &q0,
                LM_STOP,
            )
            .map_err(|e| LabError::numerical(e.to_string()))?;
            // … from the best grid point of each discrete setting, keeping the lowest χ²
            if refined.as_ref().is_none_or(|b| r.chi2 < b.0) {
                refined = Some((r.chi2, full(&r.params)));
            }
        }
        if let Some((_, v)) = refined {
            p = v;
        }
    }
    // … then the linear parameters exactly on all data at those values, and
    // the block cross-validation, from one pass: the normal equations of the
    // linear parameters do not depend on their values (taken at zero here),
    // so the total gives the solution and each training part its own.
    let folds = {
        let mut q = vec![0.0; nlin];
        q.extend_from_slice(&p[nlin..]);
        accumulate(sig, recs, prep, &q, false, 1)
    };
    let tot = total(&folds);
    if let Some(lin) = solve_linear(&tot, &held) {
        p[..nlin].copy_from_slice(&lin);
    }
    let chi2 = tot.chi2_after(&p[..nlin]);
    let mut cv = 0.0;
    for f in &folds {
        if f.count == 0 {
            continue;
        }
        let train = tot.minus(f);
        let step = solve_linear(&train, &held).unwrap_or_else(|| vec![0.0; nlin]);
        // held-out χ² at the training optimum
        cv += f.chi2_after(&step);
    }
    let before: Vec<f64> = {
        let mut v = vec![0.0; FOLDS];
        for r in recs {
            v[usize::from(r.fold) % FOLDS] += r.chi2();
        }
        v
    };
    let chi2_before: f64 = before.iter().sum();
    let nl = p[nlin..].to_vec();
    let nuisance = [p[nlin - 3], p[nlin - 2], p[nlin - 1]];
    p.truncate(nlin - NUISANCE);
    Ok(SignatureFit {
        lin_se: vec![f64::NAN; p.len()],
        nl_se: vec![f64::NAN; nl.len()],
        n_params: (p.len() + nl.len()).saturating_sub(held.iter().flatten().count()),
        lin: p,
        nl,
        chi2,
        chi2_before,
        cv_chi2: cv,
        cv_chi2_before: chi2_before,
        nuisance,
    })
}
