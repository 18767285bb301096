//! `add`: an effect enabled and refitted, before/after, its parameters read back with
//! standard errors — [`refit_and_report`], the end of every add (catalogue and user).
use super::*;

/// The spec with one more effect enabled.
pub fn spec_with(spec: &LabSpec, effect: &str) -> LabSpec {
    let mut s = spec.clone();
    crate::signatures::enable_in_spec(&mut s, effect);
    s
}

/// Before/after of adding one effect.
#[derive(Debug, Clone, Serialize)]
pub struct ErrorSummary {
    /// As [`Rms::raw_lsb`].
    pub raw_lsb: f64,
    /// As [`Rms::depth_2phase_mm`].
    pub depth_2phase_mm: f64,
    /// As [`Rms::depth_4phase_mm`].
    pub depth_4phase_mm: f64,
    /// As [`FitStats::chi2_per_dof`].
    pub chi2_per_dof: f64,
    /// As [`FitStats::aic`].
    pub aic: f64,
    /// As [`FitStats::bic`].
    pub bic: f64,
}

impl ErrorSummary {
    /// The errors of one comparison.
    pub fn of(c: &Comparison) -> Self {
        Self {
            raw_lsb: c.rms.raw_lsb,
            depth_2phase_mm: c.rms.depth_2phase_mm,
            depth_4phase_mm: c.rms.depth_4phase_mm,
            chi2_per_dof: c.fit.chi2_per_dof,
            aic: c.fit.aic,
            bic: c.fit.bic,
        }
    }
}

/// The result of [`add_effect`].
pub struct AddOutcome {
    /// The model without the effect.
    pub before: Comparison,
    /// The model refitted with it.
    pub after: Comparison,
    /// The effect's fitted signature.
    pub effect: EffectFit,
    /// Its parameters by name.
    pub params: BTreeMap<String, f64>,
    /// Their standard errors by name ([`fitted_effect`]).
    pub standard_errors: BTreeMap<String, f64>,
    /// Why those errors understate how far the values may be off (None when
    /// the model with the effect fits to the noise: [`errors_note`]).
    pub standard_errors_note: Option<String>,
    /// The parameters fitted at the bound of their range ([`FittedEffect::at_bound`]).
    pub at_bound: Vec<String>,
    /// Profile intervals of the non-linear parameters ([`FittedEffect::intervals`]).
    pub intervals: BTreeMap<String, crate::uncertainty::ProfileInterval>,
}

/// Enable `effect` in the spec, refit everything, and compare before/after.
pub fn add_effect(
    prep: &Prepared,
    spec: &LabSpec,
    effect: &str,
    progress: Progress<'_>,
) -> Result<AddOutcome, LabError> {
    check_addable(prep, spec, effect)?;
    let before = compare(prep, spec, progress)?;
    add_effect_to(prep, before, effect, None, progress)
}

pub(super) fn check_addable(prep: &Prepared, spec: &LabSpec, effect: &str) -> Result<(), LabError> {
    if !SIGNATURE_IDS.contains(&effect) {
        return Err(LabError::new(
            ErrorKind::UnknownEffect,
            format!(
                "the lab cannot add `{effect}` (it can add: {})",
                SIGNATURE_IDS.join(", ")
            ),
        ));
    }
    if spec.effects.iter().any(|e| e == effect) {
        return Err(LabError::new(
            ErrorKind::InvalidModel,
            format!("`{effect}` is already enabled in the model"),
        ));
    }
    if let Some(why) = not_identifiable(effect, prep, spec) {
        return Err(LabError::new(
            ErrorKind::NotIdentifiable,
            format!("cannot fit `{effect}`: {why}"),
        ));
    }
    Ok(())
}

/// Add `effect` to the fitted model of `before`. Two fits compete and the
/// better (lower χ²/dof) is kept: the whole model refined from the
/// candidate's fit on top of `before` (`start`: a refit `diagnose` already
/// made) with step control, so it never ends worse than that start; and a fit
/// of the extended model from scratch.
pub fn add_effect_to(
    prep: &Prepared,
    before: Comparison,
    effect: &str,
    start: Option<&LabModel>,
    progress: Progress<'_>,
) -> Result<AddOutcome, LabError> {
    let spec = before.model.spec.clone();
    check_addable(prep, &spec, effect)?;
    let mut spec2 = spec_with(&spec, effect);
    let warm = match start {
        Some(m) => m.clone(),
        None => {
            // the law's form by cross-validation (crate::shape), then its fit
            let c = crate::shape::choose_form(
                effect,
                prep,
                &spec,
                &before.model.waveform,
                &before.recs,
                before.noise_floor(),
            )?;
            let fit = EffectFit {
                id: effect.to_string(),
                lin: c.fit.lin,
                nl: c.fit.nl,
            };
            let base = with_form(&before.model, effect, c.knots.as_ref());
            crate::fit::refit_with(prep, &base, &fit, c.fit.nuisance, 3)?
        }
    };
    if let Some(k) = warm.spec.shapes.get(effect) {
        spec2.shapes.insert(effect.to_string(), k.clone());
    }
    refit_and_report(prep, before, warm, &spec2, effect, progress)
}

/// The end of every `add` (a catalogue effect's here, a user effect's in
/// `crate::user`): the model with `effect`, `warm` (its fit on top of
/// `before`), refined with step control — so it never ends worse than that
/// start — against a fit of `spec` (the model with the effect) from
/// scratch, the lower χ²/dof kept, and the effect read back from it with
/// its standard errors and bounds.
pub fn refit_and_report(
    prep: &Prepared,
    before: Comparison,
    mut warm: LabModel,
    spec: &LabSpec,
    effect: &str,
    progress: Progress<'_>,
) -> Result<AddOutcome, LabError> {
    crate::fit::refine(prep, &mut warm, 4, false, true, &|_, _| {})?;
    let warm = comparison_of(prep, warm)?;
    let scratch = compare(prep, spec, progress)?;
    let after = if scratch.fit.chi2_per_dof < warm.fit.chi2_per_dof {
        scratch
    } else {
        warm
    };
    let f = fitted_effect(prep, &after, effect)?;
    let (fitted, _) = effect_params(prep, &after.model, effect)?;
    Ok(AddOutcome {
        before,
        after,
        effect: fitted,
        params: f.params,
        standard_errors: f.standard_errors,
        standard_errors_note: f.standard_errors_note,
        at_bound: f.at_bound,
        intervals: f.intervals,
    })
}

/// A fitted effect's parameters with their standard errors (`lab add`, `lab explain`).
#[derive(Debug, Clone, Serialize)]
pub struct FittedEffect {
    /// Catalogue id.
    pub effect: String,
    /// Its parameters by the signature's names ([`effect_params`]).
    pub params: BTreeMap<String, f64>,
    /// The standard error of each, same names: √diag((JᵀWJ)⁻¹) over all the model's
    /// parameters at the fitted values, the per-pixel ones free (a Schur complement over
    /// them), W = 1/σ² of the noise model, scaled by χ²/dof
    /// ([`crate::uncertainty::profiled_standard_errors`]); NaN for a parameter held on a
    /// grid and for the waveform's harmonics (fitted inside the waveform, not as a
    /// signature).
    pub standard_errors: BTreeMap<String, f64>,
    /// Why those errors understate how far the values may be off ([`errors_note`]).
    pub standard_errors_note: Option<String>,
    /// The parameters fitted at the bound of their range, one sentence each
    /// ([`crate::signatures::at_bounds`]).
    pub at_bound: Vec<String>,
    /// Profile-likelihood intervals of the non-linear parameters by name
    /// ([`crate::uncertainty::profile_intervals`]).
    pub intervals: BTreeMap<String, crate::uncertainty::ProfileInterval>,
}

/// The standard errors rest on the noise model alone: they say how far the
/// values may be off only where the model fits to the noise. Where the model
/// with the effect still leaves an excess χ² (z > [`Z_NULL`]) or structure
/// against a condition (z > [`STRUCTURE_NULL`]), the law fitted and the
/// truth's differ by more than the noise, and the values can be off by many
/// of these errors (docs/lab.md, worked example: τ and β, 14 and 20 of them):
/// the note says so, with the figures it rests on.
pub fn errors_note(cmp: &Comparison) -> Option<String> {
    let strongest = cmp
        .structure
        .iter()
        .max_by(|a, b| a.z.total_cmp(&b.z))
        .filter(|s| s.z > STRUCTURE_NULL);
    if cmp.fit.z <= Z_NULL && strongest.is_none() {
        return None;
    }
    let structure = strongest.map_or_else(String::new, |s| {
        format!(
            ", structure z {:.1} against {} (≤ {STRUCTURE_NULL} for noise)",
            s.z, s.condition
        )
    });
    Some(format!(
        "errors of the noise alone: with it the model leaves χ²/dof {:.3} (z {:.1}, ≤ {Z_NULL} for noise){structure}, so the values may be off by more than these errors",
        cmp.fit.chi2_per_dof, cmp.fit.z
    ))
}

/// `effect` as fitted in the model of `cmp` (which must hold its residual table), with the
/// standard errors of its parameters.
pub fn fitted_effect(
    prep: &Prepared,
    cmp: &Comparison,
    effect: &str,
) -> Result<FittedEffect, LabError> {
    let (fit, params) = effect_params(prep, &cmp.model, effect)?;
    let mut standard_errors: BTreeMap<String, f64> =
        params.keys().map(|k| (k.clone(), f64::NAN)).collect();
    let mut at_bound = Vec::new();
    let mut intervals = BTreeMap::new();
    if effect != tofprox_model::effects::waveform_harmonics::ID.as_str() {
        let sig = make_signature(effect, prep, &cmp.model.spec, &cmp.model.waveform)?;
        let u = crate::uncertainty::effect_uncertainty(
            sig.as_ref(),
            prep,
            (&cmp.model, cmp.fit.chi2_per_dof),
            &fit,
        )?;
        let names = sig.lin_names().into_iter().chain(sig.nl_names());
        standard_errors.extend(names.zip(u.standard_errors));
        intervals = u.intervals;
        at_bound = crate::signatures::at_bounds(sig.as_ref(), &fit.nl);
    }
    Ok(FittedEffect {
        effect: effect.to_string(),
        params,
        standard_errors,
        standard_errors_note: errors_note(cmp),
        at_bound,
        intervals,
    })
}

/// The fitted parameters of `effect` in `model`, by the signature's names.
pub fn effect_params(
    prep: &Prepared,
    model: &LabModel,
    effect: &str,
) -> Result<(EffectFit, BTreeMap<String, f64>), LabError> {
    if let Some(e) = crate::signatures::waveform_effect(effect) {
        let params = e.waveform_params(&model.waveform);
        let fit = EffectFit {
            id: effect.into(),
            lin: Vec::new(),
            nl: Vec::new(),
        };
        return Ok((fit, params));
    }
    let mut params = BTreeMap::new();
    let sig = make_signature(effect, prep, &model.spec, &model.waveform)?;
    let f = model
        .effects
        .iter()
        .find(|e| e.id == effect)
        .cloned()
        .ok_or_else(|| LabError::numerical(format!("{effect} is not in the fitted model")))?;
    for (n, v) in sig.lin_names().into_iter().zip(&f.lin) {
        params.insert(n, *v);
    }
    for (n, v) in sig.nl_names().into_iter().zip(&f.nl) {
        params.insert(n, *v);
    }
    Ok((f, params))
}
