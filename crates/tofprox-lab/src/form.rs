//! The choice between an effect's parametric form and its shape forms
//! (`crate::shape`, and of their knot count K), by cross-validation on
//! held-out blocks of captures ([`choose_form`]) as a test at a fixed
//! significance whose margin does not grow with the effect ([`form_margin`]):
//!
//! * The held-out χ² already charges a form for its free parameters (it is
//!   the predictive counterpart of AIC: a fitted parameter that only follows
//!   noise raises the held-out χ² by about one), so no penalty per parameter
//!   is added on top of it.
//! * What remains is chance: the held-out χ² difference of two forms,
//!   Σ w·(r₁² − r₂²) with r = e + d (e the noise, d each form's leftover),
//!   scatters by 2·√D, D = Σ w·(d₁ − d₂)² the squared distance between the
//!   two forms' predictions. For nested least-squares fits D is the
//!   in-sample χ² difference (Pythagoras), which the fits give; a shape
//!   replaces the incumbent when it predicts the held-out blocks better by
//!   [`FORM_Z`] of those standard deviations (one-sided p ≈ 0.1 %). The
//!   margin grows with √D — the square root of how much the forms differ —
//!   while a law that departs from the family gains ≈ D: the stronger the
//!   departure, the surer the shape. (Before issue 33 the margin was 1 % of
//!   what the physical form explains: it grew with the effect itself, and a
//!   5× temperature drift outside the family kept the family with the shape
//!   predicting 6.7 % better.)
//! * Against the physical form only, the shape must also predict the held-out
//!   samples [`MIN_REL_GAIN_OVER_PHYSICAL`] better per sample: the forms are
//!   compared on the residual of the model fitted without the effect, whose
//!   per-pixel parameters absorbed part of it, and a shape follows that
//!   remnant a little better than the law that made it (2 % for the thesis'
//!   own droop law on docs/lab.md's recording). This share is of the
//!   physical form's held-out χ² per sample — what it leaves, noise included
//!   — not of what it explains, so it too does not grow with the effect.

use rayon::prelude::*;

use crate::candidates::{HeldOut, SignatureFit, add_standard_errors, cv_refit, fit_values};
use crate::error::LabError;
use crate::prepared::Prepared;
use crate::sample::Sample;
use crate::shape::{
    KNOT_COUNTS, PHYSICAL_FORM, has_shape_form, knots_at_quantiles, make_shape_signature,
    shape_form_name,
};
use crate::signatures::{Signature, make_signature};
use crate::spec::LabSpec;
use crate::waveform::Waveform;

/// One form's cross-validation score.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FormScore {
    /// `physical` or `shape_<K>_knots`.
    pub form: String,
    /// Σ over held-out blocks of χ² with every parameter of the form fitted
    /// on the other blocks ([`cv_refit`]).
    pub cv_chi2: f64,
}

/// The form chosen for one effect and what it was chosen from.
pub struct FormChoice {
    /// Knots of the chosen shape (`None`: the parametric form).
    pub knots: Option<Vec<f64>>,
    /// The chosen form's fit.
    pub fit: SignatureFit,
    /// Its signature.
    pub signature: Box<dyn Signature>,
    /// Every form tried, in order.
    pub scores: Vec<FormScore>,
}

/// Fit effect `id`'s parametric form and (when it has one) its shape form
/// with each of [`KNOT_COUNTS`] knots to the residuals `recs`, and keep the
/// one that predicts held-out blocks best (only where the physical form
/// explains at least `MIN_SHARE_FOR_FORMS` of the excess χ² — else it is
/// not the effect missing — and the recording has at least
/// `MIN_CAPTURES_FOR_FORMS` illuminated captures; else `scores` stays empty). The parametric form is kept
/// unless a shape's held-out χ² is lower by the significance margin of
/// [`form_margin`] and by `MIN_REL_GAIN_OVER_PHYSICAL` of the parametric
/// form's own held-out χ²: a law the physics fixes is not traded for a
/// look-alike within the noise, nor for one that absorbs a little of a
/// residual that is not this effect's (the candidates are fitted before the
/// per-pixel parameters are refitted, so their residual holds more than the
/// effect). `noise_floor`: the χ² per sample of the noise alone (dof/n of
/// the model fitted without the effect) where the noise was measured —
/// then the shapes are not fitted where none could win
/// ([`shapes_can_win`]); `None`: always fitted.
pub fn choose_form(
    id: &str,
    prep: &Prepared,
    spec: &LabSpec,
    waveform: &Waveform,
    recs: &[Sample],
    noise_floor: Option<f64>,
) -> Result<FormChoice, LabError> {
    let mut plain = spec.clone();
    plain.shapes.remove(id);
    let sig = make_signature(id, prep, &plain, waveform)?;
    let mut fit = fit_values(sig.as_ref(), recs, prep, None)?;
    // an effect whose physical form explains little of the excess is not the
    // one missing: its forms are not compared (the screening's cost)
    let excess = fit.chi2_before - recs.len() as f64;
    // few captures: a held-out block is one capture or none, which scores
    // how a shape of K free values follows that capture, not the law
    let illuminated = prep.caps.iter().filter(|c| c.illum && c.used).count();
    if !has_shape_form(id)
        || spec.held.iter().any(|h| h.id == id)
        || spec.holds.contains_key(id)
        || illuminated < MIN_CAPTURES_FOR_FORMS
        || fit.chi2_before - fit.chi2 < MIN_SHARE_FOR_FORMS * excess
    {
        add_standard_errors(sig.as_ref(), recs, prep, &mut fit);
        return Ok(FormChoice {
            knots: None,
            fit,
            signature: sig,
            scores: Vec::new(),
        });
    }
    let knot_sets = shape_knot_sets(id, prep, waveform, recs);
    let mut best = if knot_sets.is_empty() {
        // no shape form here (the SBI's where the ambient light varies, a
        // driver of one value): nothing to compare the physical form with
        FormChoice {
            knots: None,
            fit,
            signature: sig,
            scores: Vec::new(),
        }
    } else {
        let held_out = cv_refit(sig.as_ref(), recs, prep, &fit)?;
        let physical = FormChoice {
            knots: None,
            fit,
            signature: sig,
            scores: vec![FormScore {
                form: PHYSICAL_FORM.into(),
                cv_chi2: held_out.chi2,
            }],
        };
        if shapes_can_win(&held_out, noise_floor) {
            best_shape(id, prep, waveform, recs, (physical, knot_sets))
        } else {
            physical
        }
    };
    // the standard errors of the chosen form only
    add_standard_errors(best.signature.as_ref(), recs, prep, &mut best.fit);
    Ok(best)
}

/// The knots of effect `id`'s shape form with each of [`KNOT_COUNTS`] (each
/// length once: fewer where the driver has fewer values) where it has one
/// here.
fn shape_knot_sets(
    id: &str,
    prep: &Prepared,
    waveform: &Waveform,
    recs: &[Sample],
) -> Vec<Vec<f64>> {
    let mut sets: Vec<Vec<f64>> = Vec::new();
    for &k in KNOT_COUNTS {
        if let Some(q) = knots_at_quantiles(id, k, recs, prep, waveform)
            && !sets.iter().any(|p| p.len() == q.len())
            && make_shape_signature(id, &q, prep, waveform).is_some()
        {
            sets.push(q);
        }
    }
    sets
}

/// `physical` (scored) against the shapes of `knot_sets`: the best by
/// held-out χ² under the margins of [`choose_form`], every scored form in
/// its `scores` (a shape whose in-sample χ² already rules it out
/// — [`could_win`] — is fitted but not scored).
fn best_shape(
    id: &str,
    prep: &Prepared,
    waveform: &Waveform,
    recs: &[Sample],
    (physical, knot_sets): (FormChoice, Vec<Vec<f64>>),
) -> FormChoice {
    let mut scores = physical.scores.clone();
    let mut best_cv = scores[0].cv_chi2;
    let mut best = physical;
    // the shapes fitted in parallel, then scored and chosen in order
    let fitted: Vec<Option<(SignatureFit, Box<dyn Signature>)>> = knot_sets
        .par_iter()
        .map(|q| try_shape(id, q, prep, waveform, recs))
        .collect();
    let share = cv_sample_share(recs.len());
    for (knots, fit) in knot_sets.into_iter().zip(fitted) {
        let Some((f, s)) = fit else {
            continue;
        };
        let extra = f.n_params.saturating_sub(best.fit.n_params);
        let d_sub = (best.fit.chi2 - f.chi2) * share;
        let mut margin = form_margin(d_sub, extra);
        if best.knots.is_none() {
            margin = margin.max(MIN_REL_GAIN_OVER_PHYSICAL * best_cv);
        }
        if !could_win(f.chi2 * share, best_cv - margin) {
            continue;
        }
        let Ok(c) = cv_refit(s.as_ref(), recs, prep, &f).map(|h| h.chi2) else {
            continue;
        };
        scores.push(FormScore {
            form: shape_form_name(knots.len()),
            cv_chi2: c,
        });
        if c < best_cv - margin {
            best_cv = c;
            best = FormChoice {
                knots: Some(knots),
                fit: f,
                signature: s,
                scores: Vec::new(),
            };
        }
    }
    best.scores = scores;
    best
}

/// Whether a form whose in-sample χ² scaled to the held-out samples is
/// `in_sample` could score below `needed` on them: a form fitted on the
/// other blocks predicts a sample no better than one fitted on all of them
/// (the held-out χ² exceeds the in-sample one by the fit's optimism, ≥ 0 in
/// expectation), but for the scatter of a subsample's χ², [`FORM_Z`]·√(2χ²).
/// A shape that cannot win is not refitted on the blocks (five fits each).
fn could_win(in_sample: f64, needed: f64) -> bool {
    in_sample - FORM_Z * (2.0 * in_sample.max(0.0)).sqrt() - FORM_Z * FORM_Z < needed
}

/// The shape form of effect `id` with `knots` fitted to `recs` and its
/// signature; `None` when it cannot be fitted.
fn try_shape(
    id: &str,
    knots: &[f64],
    prep: &Prepared,
    waveform: &Waveform,
    recs: &[Sample],
) -> Option<(SignatureFit, Box<dyn Signature>)> {
    let s = make_shape_signature(id, knots, prep, waveform)?;
    let f = fit_values(s.as_ref(), recs, prep, None).ok()?;
    Some((f, s))
}

/// Whether a shape could replace the physical form that scored `physical`
/// on the held-out blocks, the noise alone giving `noise_floor` χ² per
/// sample (`None`: not measured — always). A shape must predict the
/// held-out samples [`MIN_REL_GAIN_OVER_PHYSICAL`] of the physical form's
/// χ² better, and no form fitted on the other blocks predicts them better
/// than their noise: its held-out χ² Σ w·(e + d)² = Σ w·e² + D + 2·Σ w·e·d
/// (d its leftover, independent of the held-out noise e) is at least
/// Σ w·e² − [`FORM_Z`]² at the significance of the form choice, and Σ w·e²
/// of n held-out samples at least n·floor − [`FORM_Z`]·√(2n). Below that a
/// physical form that explains all but the noise needs no shape, and its
/// shapes — three of the four refits of [`choose_form`] — are not fitted
/// (issue 33: most of a diagnosis' time was spent there).
pub fn shapes_can_win(physical: &HeldOut, noise_floor: Option<f64>) -> bool {
    let Some(floor) = noise_floor else {
        return true;
    };
    let n = physical.samples as f64;
    let least = floor * n - FORM_Z * (2.0 * n).sqrt() - FORM_Z * FORM_Z;
    (1.0 - MIN_REL_GAIN_OVER_PHYSICAL) * physical.chi2 > least
}

/// The fewest illuminated captures on which the forms are compared (two per
/// held-out block; `examples/recording`'s 7 fit a 4-knot SBI shape to a
/// recording without SBI).
const MIN_CAPTURES_FOR_FORMS: usize = 10;

/// The least share of the physical form's held-out χ² (per sample: what it
/// leaves, noise included) a shape must predict better to replace it — the
/// bias of comparing forms on a residual the per-pixel parameters absorbed
/// part of (the thesis' own droop law on docs/lab.md's recording: 2 % by a
/// 3-knot shape; the shapes of laws outside the catalogue's families in
/// `tests/shapes_independent.rs` and `tests/beyond_families.rs`: 6–70 %).
pub const MIN_REL_GAIN_OVER_PHYSICAL: f64 = 0.05;

/// The significance of the form choice in standard deviations of the
/// held-out χ² difference (one-sided p ≈ 0.13 %).
pub const FORM_Z: f64 = 3.0;

/// The margin by which a form must lower the incumbent's held-out χ² to
/// replace it: [`FORM_Z`] standard deviations 2·√D of the held-out χ²
/// difference of two forms whose predictions differ by D (χ² units, on the
/// held-out samples: the in-sample χ² difference `d_sub` of the two fits,
/// at least the `extra` parameters the challenger has — what fitting noise
/// alone gains). The module doc argues it.
pub fn form_margin(d_sub: f64, extra: usize) -> f64 {
    FORM_Z * 2.0 * d_sub.max(extra.max(1) as f64).sqrt()
}

/// The share of the samples [`cv_refit`] scores on (its subsample of large
/// tables): scales an in-sample χ² over all `n` samples to its held-out
/// blocks.
fn cv_sample_share(n: usize) -> f64 {
    let stride = (n / crate::candidates::CV_SUBSAMPLE).max(1);
    n.div_ceil(stride) as f64 / n.max(1) as f64
}

/// The least share of the residual's excess χ² (χ² − samples) the physical
/// form must explain for the forms to be compared.
const MIN_SHARE_FOR_FORMS: f64 = 0.05;

/// The name of the chosen form of `knots` (`physical` for none).
pub fn form_name(knots: Option<&Vec<f64>>) -> String {
    knots.map_or_else(|| PHYSICAL_FORM.to_string(), |k| shape_form_name(k.len()))
}
