//! `explain`: the diagnose → add loop, with trials of a partial leader taken back when
//! they do not help.
use super::*;

/// One round of `explain`: the comparison and diagnosis at that point and the
/// effect added after it (none on the last step).
#[derive(Debug, Clone)]
pub struct ExplainStep {
    /// The model at this step compared with the recording (residual table dropped).
    pub comparison: Comparison,
    /// The diagnosis of that comparison (candidate refits dropped).
    pub diagnosis: Diagnosis,
    /// The effect added after this step (none on the last).
    pub added: Option<String>,
}

/// The loop diagnose → add until nothing is missing or the rest is unexplained.
#[derive(Debug, Clone)]
pub struct Explanation {
    /// Every step, the last one with the final verdict.
    pub steps: Vec<ExplainStep>,
    /// Effects added, in order.
    pub added: Vec<String>,
    /// Why `explain` could not explain the recording (None: it ends at
    /// `nothing_missing`).
    pub stopped: Option<String>,
    /// The effects added, as fitted in the final model, with standard errors.
    pub fitted: Vec<FittedEffect>,
}

impl Explanation {
    /// The final verdict (of the last diagnosis).
    pub fn verdict(&self) -> Verdict {
        self.steps
            .last()
            .map_or(Verdict::Unexplained, |s| s.diagnosis.verdict)
    }
    /// The final model.
    pub fn final_model(&self) -> Option<&LabModel> {
        self.steps.last().map(|s| &s.comparison.model)
    }
}

/// At most this many effects are added by one `explain`.
pub const MAX_EXPLAIN_STEPS: usize = 6;

/// diagnose → add → diagnose … until the verdict is not `missing_effect` (or
/// adding the named effect does not lower χ²). Where no effect is named but
/// one clearly leads, it is added on trial ([`MIN_TRIAL`]) and kept only if it
/// leads to a named effect and the final model needs it.
pub fn explain(
    prep: &Prepared,
    spec: &LabSpec,
    opts: &DiagnoseOptions,
    progress: Progress<'_>,
) -> Result<Explanation, LabError> {
    let mut cmp = compare(prep, spec, progress)?;
    let mut ex = Explanation {
        steps: Vec::new(),
        added: Vec::new(),
        stopped: None,
        fitted: Vec::new(),
    };
    let mut trials = Vec::new();
    for _ in 0..=MAX_EXPLAIN_STEPS {
        let mut d = diagnose_with(prep, &cmp, opts, progress)?;
        let named = next_effect(&mut d, &mut trials).filter(|_| ex.added.len() < MAX_EXPLAIN_STEPS);
        let start = named.as_ref().and_then(|e| {
            let c = d.candidates.iter_mut().find(|c| c.effect == *e)?;
            c.refit.take()
        });
        for c in &mut d.candidates {
            c.refit = None;
        }
        let Some(effect) = named else {
            ex.fitted = fitted_effects(prep, &cmp, &ex.added)?;
            cmp.recs = Vec::new();
            ex.steps.push(ExplainStep {
                comparison: cmp,
                diagnosis: d,
                added: None,
            });
            break;
        };
        let chi_before = cmp.chi2 / cmp.dof;
        let out = add_effect_to(prep, cmp, &effect, start.as_deref(), progress)?;
        let mut before = out.before;
        let chi_after = out.after.fit.chi2_per_dof;
        let improved = chi_after < chi_before;
        if !improved {
            // the final model is this one
            ex.fitted = fitted_effects(prep, &before, &ex.added)?;
        }
        let why =
            format!("adding {effect} did not lower χ²/dof ({chi_before:.3} → {chi_after:.3})");
        let failed_trial = !improved && trials.contains(&effect);
        if failed_trial {
            trial_failed(&mut d.reason, &format!("on trial: {why}"));
        }
        before.recs = Vec::new();
        ex.steps.push(ExplainStep {
            comparison: before,
            diagnosis: d,
            added: improved.then(|| effect.clone()),
        });
        if !improved {
            if failed_trial {
                break;
            }
            ex.stopped = Some(why);
            return Ok(ex);
        }
        ex.added.push(effect);
        cmp = out.after;
    }
    take_back_dead_trials(prep, &trials, &mut ex)?;
    drop_unneeded_trials(prep, opts, &trials, &mut ex, progress)?;
    ex.stopped = stopped_reason(&ex.steps);
    Ok(ex)
}

/// Why the loop ended where it did (None at `nothing_missing`).
pub(super) fn stopped_reason(steps: &[ExplainStep]) -> Option<String> {
    steps.last().and_then(|s| {
        let d = &s.diagnosis;
        (d.verdict != Verdict::NothingMissing).then(|| match d.verdict {
            Verdict::MissingEffect => format!(
                "still {} after {MAX_EXPLAIN_STEPS} effects: {}",
                d.verdict.as_str(),
                d.reason
            ),
            v => format!("{}: {}", v.as_str(), d.reason),
        })
    })
}

/// Several strong effects at once: each explains only part of the excess, so
/// none may pass [`decide`]. When the best candidate explains at least this
/// share of the excess, as much on held-out blocks, and clearly beats the
/// runner-up, `explain` adds it **on trial** and diagnoses the rest; the
/// diagnosis itself stays `unexplained`.
pub const MIN_TRIAL: f64 = 0.15;

/// The effect `explain` adds after diagnosis `d`: the named one, or one on
/// trial ([`MIN_TRIAL`], recorded in `trials` and in `d.reason`).
pub(super) fn next_effect(d: &mut Diagnosis, trials: &mut Vec<String>) -> Option<String> {
    if d.verdict == Verdict::MissingEffect {
        return d.effect.clone();
    }
    let best = d.candidates.first()?;
    let on_trial = d.verdict == Verdict::Unexplained
        && d.noise.measured()
        && best.explained_excess >= MIN_TRIAL
        && best.cv_gain >= MIN_TRIAL.max(0.7 * best.explained_excess)
        && clearly_best(best, d.candidates.get(1));
    if !on_trial {
        return None;
    }
    let e = best.effect.clone();
    d.reason = format!(
        "{}; `explain` adds {e} on trial ({:.0}% of the excess, {:.0}% on held-out blocks) and diagnoses the rest",
        d.reason,
        100.0 * best.explained_excess,
        100.0 * best.cv_gain
    );
    trials.push(e.clone());
    Some(e)
}

/// The reason of a diagnosis whose trial failed: its announcement replaced by `why`.
pub(super) fn trial_failed(reason: &mut String, why: &str) {
    reason.truncate(reason.find("; `explain` adds").unwrap_or(reason.len()));
    reason.push_str("; ");
    reason.push_str(why);
}

/// A trial is a look-ahead: it stays when the diagnosis after it names an
/// effect or finds nothing missing. When the loop ends `unexplained` right
/// after a trial, the trial is taken back: the step before it is the last,
/// with the model it had.
pub(super) fn take_back_dead_trials(
    prep: &Prepared,
    trials: &[String],
    ex: &mut Explanation,
) -> Result<(), LabError> {
    let closed = |st: &ExplainStep| {
        matches!(
            st.diagnosis.verdict,
            Verdict::NothingMissing | Verdict::MissingEffect
        )
    };
    let steps = &mut ex.steps;
    while steps.len() >= 2 && !closed(&steps[steps.len() - 1]) {
        let prev = &steps[steps.len() - 2];
        let Some(e) = prev
            .added
            .clone()
            .filter(|e| trials.contains(e) && !closed(prev))
        else {
            break;
        };
        steps.pop();
        ex.added.retain(|x| *x != e);
        let last = steps.last_mut().expect("two steps");
        last.added = None;
        let why = format!("{e} added on trial led to no named effect and was taken back");
        trial_failed(&mut last.diagnosis.reason, &why);
        let cmp = comparison_of(prep, last.comparison.model.clone())?;
        ex.fitted = fitted_effects(prep, &cmp, &ex.added)?;
    }
    Ok(())
}

/// An effect added on trial stays only if the final model needs it: when the
/// loop ends at `nothing_missing`, the model without it (fitted from scratch)
/// is diagnosed, and if that, too, is `nothing_missing` the effect goes and
/// that diagnosis becomes the last step (its reason says so).
pub(super) fn drop_unneeded_trials(
    prep: &Prepared,
    opts: &DiagnoseOptions,
    trials: &[String],
    ex: &mut Explanation,
    progress: Progress<'_>,
) -> Result<(), LabError> {
    for e in trials {
        let Some(last) = ex.steps.last_mut() else {
            return Ok(());
        };
        if last.diagnosis.verdict != Verdict::NothingMissing || !ex.added.contains(e) {
            continue;
        }
        let mut spec = last.comparison.model.spec.clone();
        spec.effects.retain(|x| x != e);
        spec.shapes.remove(e);
        let mut without = compare(prep, &spec, progress)?;
        let mut d = diagnose_with(prep, &without, opts, progress)?;
        if d.verdict != Verdict::NothingMissing {
            continue;
        }
        ex.added.retain(|x| x != e);
        ex.fitted = fitted_effects(prep, &without, &ex.added)?;
        d.reason = format!("{e} (added on trial) is not needed: {}", d.reason);
        d.candidates.iter_mut().for_each(|c| c.refit = None);
        without.recs = Vec::new();
        *last = ExplainStep {
            comparison: without,
            diagnosis: d,
            added: None,
        };
    }
    Ok(())
}

/// Each of `added` as fitted in the model of `cmp`, with standard errors.
pub(super) fn fitted_effects(
    prep: &Prepared,
    cmp: &Comparison,
    added: &[String],
) -> Result<Vec<FittedEffect>, LabError> {
    added.iter().map(|e| fitted_effect(prep, cmp, e)).collect()
}
