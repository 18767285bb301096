//! The lab's `--json` documents (docs/lab-json.md).
use std::collections::BTreeMap;

use serde_json::{Value, json};

use crate::depth_error::{DepthErrorSplit, DepthSplit};
use crate::diagnose::{AddOutcome, Comparison, Diagnosis, ErrorSummary, Explanation};
use crate::uncertainty::ProfileInterval;

fn num(v: f64) -> Value {
    if v.is_finite() { json!(v) } else { Value::Null }
}

/// `diagnose --json` (docs/lab.md; `separate_by` set for `ambiguous`).
pub fn diagnosis_json(d: &Diagnosis) -> Value {
    json!({
        "verdict": d.verdict.as_str(),
        "effect": d.effect,
        "candidates": d.candidates.iter().map(|c| json!({
            "effect": c.effect,
            "delta_bic": num(c.delta_bic),
            "delta_aic": num(c.delta_aic),
            "explained_excess": num(c.explained_excess),
            "cv_gain": num(c.cv_gain),
            "explained_mm": num(c.explained.mm),
            "explained_lsb": num(c.explained.lsb),
            "z_after": num(c.z_after),
            "params": named(&c.params),
            "standard_errors": named(&c.standard_errors),
            "flags": c.flags,
            "at_bound": c.at_bound,
            "form": c.form,
            "form_scores": c.form_scores.iter().map(|f| json!({"form": f.form, "cv_chi2": num(f.cv_chi2)})).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "reason": d.reason,
        "evidence": d.evidence(),
        "noise": {"source": d.noise, "description": d.noise.describe()},
        "fit": fit_json(&d.fit),
        "strongest_condition": d.strongest_condition,
        "rms": {
            "raw_lsb": num(d.rms.raw_lsb),
            "depth_2phase_mm": num(d.rms.depth_2phase_mm),
            "depth_4phase_mm": num(d.rms.depth_4phase_mm),
        },
        "separate_by": d.separate_by,
        "remaining": {
            "size_mm": num(d.size.mm),
            "size_lsb": num(d.size.lsb),
            "z": num(d.fit.z),
        },
        "noise_single_acquisition": {"mm": num(d.noise_single.mm), "lsb": num(d.noise_single.lsb)},
        "tolerance_mm": num(d.tolerance_mm),
        "detectable_but_small": d.small.iter().map(|s| json!({
            "name": s.name, "kind": s.kind, "z": num(s.z),
            "size_mm": num(s.size_mm), "size_lsb": num(s.size_lsb),
        })).collect::<Vec<_>>(),
        "skipped": d.skipped.iter().map(|(e, why)| json!({"effect": e, "reason": why})).collect::<Vec<_>>(),
        "structure": d.structure_remaining.iter().map(structure_json).collect::<Vec<_>>(),
        "proposal": crate::user::proposal(d).map(|p| json!({
            "add": p.add, "condition": p.condition, "acts_on": p.acts_on, "name": p.name,
            "size_mm": num(p.size_mm), "z": num(p.z), "sentence": p.sentence,
        })),
    })
}

/// `fit` of every document: χ²/dof, z and the information criteria.
fn fit_json(f: &crate::diagnose::FitStats) -> Value {
    json!({"chi2_per_dof": num(f.chi2_per_dof), "z": num(f.z), "aic": num(f.aic), "bic": num(f.bic)})
}

fn structure_json(s: &crate::structure::ConditionScore) -> Value {
    json!({
        "condition": s.condition, "z": num(s.z), "dof": s.dof, "direction": s.direction,
        "size_mm": num(s.size_mm), "size_lsb": num(s.size_lsb),
    })
}

/// `explain --json`: every step's verdict, the effects added and the final verdict.
pub fn explanation_json(ex: &Explanation) -> Value {
    json!({
        "verdict": ex.verdict().as_str(),
        "added": ex.added,
        "stopped": ex.stopped,
        "fitted": ex.fitted.iter().map(|f| json!({
            "effect": f.effect,
            "params": named(&f.params),
            "standard_errors": named(&f.standard_errors),
            "standard_errors_note": f.standard_errors_note,
            "at_bound": f.at_bound,
            "intervals": intervals_json(&f.intervals),
        })).collect::<Vec<_>>(),
        "steps": ex.steps.iter().map(|s| json!({
            "added": s.added,
            "diagnosis": diagnosis_json(&s.diagnosis),
            "error": summary_json(&ErrorSummary::of(&s.comparison)),
        })).collect::<Vec<_>>(),
    })
}

fn summary_json(s: &ErrorSummary) -> Value {
    json!({
        "raw_lsb": num(s.raw_lsb),
        "depth_2phase_mm": num(s.depth_2phase_mm),
        "depth_4phase_mm": num(s.depth_4phase_mm),
        "chi2_per_dof": num(s.chi2_per_dof),
        "aic": num(s.aic),
        "bic": num(s.bic),
    })
}

/// `add --json` (docs/lab.md): with the depth error's split before and after
/// ([`crate::depth_error`]) and the parameters held at given values (`held`, by the model
/// file's names).
pub fn add_json(
    effect: &str,
    out: &AddOutcome,
    (split_before, split_after): (&DepthSplit, &DepthSplit),
    held: &BTreeMap<String, f64>,
) -> Value {
    json!({
        "effect": effect,
        "name": out.effect.id,
        "before": summary_json(&ErrorSummary::of(&out.before)),
        "after": summary_json(&ErrorSummary::of(&out.after)),
        "depth_error": {"before": split_json(split_before), "after": split_json(split_after)},
        "held": named(held),
        "params": named(&out.params),
        "standard_errors": named(&out.standard_errors),
        "standard_errors_note": out.standard_errors_note,
        "at_bound": out.at_bound,
        "intervals": intervals_json(&out.intervals),
    })
}

fn split_json(s: &DepthSplit) -> Value {
    let one = |e: &DepthErrorSplit| {
        json!({
            "rms_mm": num(e.rms_mm),
            "noise_mm": num(e.noise_mm),
            "systematic_mm": num(e.systematic_mm),
            "systematic_share": num(e.systematic_share),
        })
    };
    json!({"2phase": one(&s.two_phase), "4phase": one(&s.four_phase)})
}

/// Profile intervals as JSON: per parameter its value, the 1σ and 2σ ends
/// (null where none was found) and the ends that stop at its range's bound.
fn intervals_json(m: &BTreeMap<String, ProfileInterval>) -> Value {
    Value::Object(
        m.iter()
            .map(|(k, iv)| {
                let v = json!({
                    "value": num(iv.value),
                    "lower_1sigma": num(iv.lower[0]),
                    "upper_1sigma": num(iv.upper[0]),
                    "lower_2sigma": num(iv.lower[1]),
                    "upper_2sigma": num(iv.upper[1]),
                    "at_range_bound": iv.at_range_bound,
                    "refits": iv.refits,
                });
                (k.clone(), v)
            })
            .collect(),
    )
}

/// A name → number map as a JSON object (non-finite numbers as null).
fn named(m: &BTreeMap<String, f64>) -> Value {
    Value::Object(m.iter().map(|(k, v)| (k.clone(), num(*v))).collect())
}

/// `compare --json`: fit statistics, RMS and the structure per condition.
pub fn comparison_json(c: &Comparison) -> Value {
    json!({
        "fit": fit_json(&c.fit),
        "rms": {
            "raw_lsb": num(c.rms.raw_lsb),
            "depth_2phase_mm": num(c.rms.depth_2phase_mm),
            "depth_4phase_mm": num(c.rms.depth_4phase_mm),
        },
        "samples": c.n,
        "parameters": c.model.n_params,
        "noise": c.model.noise,
        "remaining": {"size_mm": num(c.size.mm), "size_lsb": num(c.size.lsb)},
        "noise_single_acquisition": {"mm": num(c.noise_single.mm), "lsb": num(c.noise_single.lsb)},
        "structure": c.structure.iter().map(structure_json).collect::<Vec<_>>(),
    })
}
