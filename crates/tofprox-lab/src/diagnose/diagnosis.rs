//! `diagnose`: the candidate effects screened against the residual, the leaders refitted
//! with the whole model, the diagnosis assembled.
use super::*;

/// One candidate effect scored against the residual.
#[derive(Debug, Clone, Serialize)]
pub struct CandidateScore {
    /// Catalogue id of the effect.
    pub effect: String,
    /// BIC(with) − BIC(without); negative supports the effect.
    pub delta_bic: f64,
    /// AIC(with) − AIC(without) ([`crate::stats::aic`]); negative supports
    /// the effect.
    pub delta_aic: f64,
    /// Share of the excess χ² (χ² − dof) the effect removes; NaN (no score,
    /// shown as "—") when the residual has no significant excess over the
    /// noise (z ≤ [`Z_NULL`] with the noise known from repeats): a share of a
    /// vanishing excess is a ratio of noise over noise. `explained` gives the
    /// size then.
    pub explained_excess: f64,
    /// The same share on held-out blocks of distance (5 block folds); NaN
    /// when `explained_excess` is.
    pub cv_gain: f64,
    /// Size of what the effect removes (χ² before − after, as
    /// `structure::structure_size`): depth-equivalent mm and LSB.
    pub explained: Size,
    /// z = (χ² − dof)/√(2 dof) after adding the effect.
    pub z_after: f64,
    /// Fitted parameters by name.
    pub params: BTreeMap<String, f64>,
    /// Their standard errors by name (from the curvature of χ² under the noise model; NaN
    /// for a parameter held on a grid).
    pub standard_errors: BTreeMap<String, f64>,
    /// Why a reported value was clamped (a share above 100 %, a negative
    /// z after): the raw figure and what it means.
    pub flags: Vec<String>,
    /// The parameters fitted at the bound of their range
    /// ([`crate::signatures::at_bounds`]), one sentence each.
    pub at_bound: Vec<String>,
    /// The fitted signature (None when the fit failed).
    #[serde(skip)]
    pub fit: Option<EffectFit>,
    /// Fitted global shifts of offset (LSB), relative gain and phase (rad).
    #[serde(skip)]
    pub nuisance: [f64; 3],
    /// Strongest structure score after refitting with the effect (top candidates only).
    #[serde(skip)]
    pub structure_after: Option<f64>,
    /// RMS errors after refitting with the effect (top candidates only).
    #[serde(skip)]
    pub rms_after: Option<Rms>,
    /// Whether the effect cancels in 4-phase ([`crate::signatures::cancels_in_4phase`]).
    #[serde(skip)]
    pub cancels_in_4phase: bool,
    /// The whole model refitted with this effect (the leading candidates only),
    /// never worse than the candidate's own fit on top of the model.
    #[serde(skip)]
    pub refit: Option<Box<LabModel>>,
    /// The law's form that was fitted: `physical`, or `shape_<K>_knots`
    /// (`crate::shape::choose_form`, by cross-validation on held-out blocks).
    pub form: String,
    /// Held-out χ² of every form tried (empty for an effect with one form).
    pub form_scores: Vec<crate::shape::FormScore>,
    /// The chosen shape's knots in the lab's driver units (None: physical).
    #[serde(skip)]
    pub knots: Option<Vec<f64>>,
}

/// Something the data still show that is smaller than the tolerance.
#[derive(Debug, Clone, Serialize)]
pub struct SmallStructure {
    /// A condition the residual is structured against, or a catalogue effect.
    pub name: String,
    /// `condition` or `effect`.
    pub kind: &'static str,
    /// Structure score (conditions) or the global z (effects: z before it).
    pub z: f64,
    /// Depth-equivalent RMS size in mm.
    pub size_mm: f64,
    /// RMS size in LSB.
    pub size_lsb: f64,
}

/// Settings of the verdict.
#[derive(Debug, Clone, Copy, Default)]
pub struct DiagnoseOptions {
    /// Remaining structure below this depth-equivalent RMS (mm) is not a
    /// missing effect; `None`: [`TOLERANCE_NOISE_SHARE`] × the
    /// single-acquisition noise of the recording.
    pub tolerance_mm: Option<f64>,
}

/// The lab's answer to "what is missing from the model?".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// One catalogue effect explains the residual.
    MissingEffect,
    /// The residual is noise.
    NothingMissing,
    /// Two effects explain it about equally; vary the named condition.
    Ambiguous,
    /// Something is missing that no catalogue effect explains — or the
    /// recording shows no signal the model can follow (the reason says which).
    Unexplained,
    /// The residual looks like noise, but the noise was not measured (no
    /// repeated captures or raw images), so it cannot be called noise.
    NoiseNotMeasured,
}

impl Verdict {
    /// The snake_case name used in reports and JSON.
    pub fn as_str(&self) -> &'static str {
        match self {
            Verdict::MissingEffect => "missing_effect",
            Verdict::NothingMissing => "nothing_missing",
            Verdict::Ambiguous => "ambiguous",
            Verdict::Unexplained => "unexplained",
            Verdict::NoiseNotMeasured => "noise_not_measured",
        }
    }
}

/// What is missing from the model, with the evidence.
#[derive(Debug, Clone)]
pub struct Diagnosis {
    /// The verdict.
    pub verdict: Verdict,
    /// The missing effect (`missing_effect`) or the best of two (`ambiguous`).
    pub effect: Option<String>,
    /// For `ambiguous`: the runner-up and the condition to vary.
    pub runner_up: Option<String>,
    /// For `ambiguous`: the condition whose variation separates the two.
    pub separate_by: Option<String>,
    /// Every scored candidate, best first.
    pub candidates: Vec<CandidateScore>,
    /// Candidates not scored, with why (effect id, reason).
    pub skipped: Vec<(String, String)>,
    /// Goodness of fit of the model without any candidate.
    pub fit: FitStats,
    /// The condition the remaining residual is most structured against.
    pub strongest_condition: Option<String>,
    /// RMS errors of the model without any candidate.
    pub rms: Rms,
    /// Structure scores of what remains to explain.
    pub structure_remaining: Vec<ConditionScore>,
    /// The verdict in one sentence.
    pub reason: String,
    /// Size of what remains unexplained by the model (before any candidate).
    pub size: Size,
    /// Single-acquisition noise in the same units.
    pub noise_single: Size,
    /// The tolerance the verdict used (mm, depth-equivalent RMS).
    pub tolerance_mm: f64,
    /// Detectable (structure z > 6) but below the tolerance.
    pub small: Vec<SmallStructure>,
    /// Where the noise the verdict is measured against came from.
    pub noise: NoiseSource,
}

/// Rank the catalogue effects the model lacks and give a verdict (default tolerance).
pub fn diagnose(
    prep: &Prepared,
    cmp: &Comparison,
    progress: Progress<'_>,
) -> Result<Diagnosis, LabError> {
    diagnose_with(prep, cmp, &DiagnoseOptions::default(), progress)
}

/// Rank the catalogue effects the model lacks and give a verdict.
pub fn diagnose_with(
    prep: &Prepared,
    cmp: &Comparison,
    opts: &DiagnoseOptions,
    progress: Progress<'_>,
) -> Result<Diagnosis, LabError> {
    let tolerance_mm = opts
        .tolerance_mm
        .unwrap_or_else(|| cmp.default_tolerance_mm());
    if let Some(why) = no_signal(prep, cmp) {
        return Ok(refused(cmp, why, tolerance_mm));
    }
    let noise_known = cmp.model.noise.source.measured();
    // Shares of the excess are scores only while there is an excess: at
    // z ≤ Z_NULL it is noise, and a share of it is noise over noise (values of
    // 10⁹ % when it vanishes). Then each candidate is given by its size only.
    let significant = !noise_known || cmp.fit.z > Z_NULL;
    let mut excess = (cmp.chi2 - cmp.dof).max(1e-9);
    let mut skipped = Vec::new();
    let ids = candidate_ids(prep, &cmp.model.spec, &mut skipped);
    let mut cands = screen_candidates(prep, cmp, &ids, excess, significant, progress, &mut skipped);
    if !noise_known {
        excess = rescale_to_best(&mut cands, excess);
    }
    cands.sort_by(rank);
    let remaining = refit_leaders(prep, cmp, &mut cands, excess, significant)?;
    // re-rank with the refitted evidence (as reported: clamped, see `clamp_reported`)
    cands.iter_mut().for_each(clamp_reported);
    cands.sort_by(rank);
    progress("candidates", 1.0);
    let (d, remaining_structure) = verdict_of(prep, cmp, &cands, remaining, noise_known);
    let strongest = strongest_condition(&remaining_structure);
    let (mut d, small, remaining_mm) = apply_tolerance(cmp, opts, tolerance_mm, &cands, d);
    (d.verdict, d.reason) = honest_verdict(cmp, d.verdict, d.reason);
    if d.verdict != Verdict::MissingEffect && d.verdict != Verdict::Ambiguous {
        d.effect = None;
        d.runner_up = None;
        d.separate_by = None;
    }
    Ok(Diagnosis {
        noise: cmp.model.noise.source,
        size: Size {
            lsb: cmp.size.lsb,
            mm: remaining_mm,
        },
        noise_single: cmp.noise_single,
        tolerance_mm,
        small,
        verdict: d.verdict,
        effect: d.effect,
        runner_up: d.runner_up,
        separate_by: d.separate_by,
        candidates: cands,
        skipped,
        fit: cmp.fit,
        strongest_condition: strongest,
        rms: cmp.rms,
        structure_remaining: remaining_structure,
        reason: d.reason,
    })
}

/// The catalogue effects the model lacks and the recording can identify;
/// the others go to `skipped` with why.
pub(super) fn candidate_ids(
    prep: &Prepared,
    spec: &LabSpec,
    skipped: &mut Vec<(String, String)>,
) -> Vec<&'static str> {
    SIGNATURE_IDS
        .iter()
        .copied()
        .filter(|id| !spec.effects.iter().any(|e| e == id))
        .filter(|id| match not_identifiable(id, prep, spec) {
            Some(why) => {
                skipped.push((id.to_string(), why));
                false
            }
            None => true,
        })
        .collect()
}

/// Screening: each candidate's signature fitted to the residuals in parallel;
/// the ones whose fit failed go to `skipped`.
pub(super) fn screen_candidates(
    prep: &Prepared,
    cmp: &Comparison,
    ids: &[&str],
    excess: f64,
    significant: bool,
    progress: Progress<'_>,
    skipped: &mut Vec<(String, String)>,
) -> Vec<CandidateScore> {
    progress("candidates", 0.0);
    let done = std::sync::atomic::AtomicUsize::new(0);
    let fits: Vec<Result<CandidateScore, (String, LabError)>> = ids
        .par_iter()
        .map(|id| {
            let c = screen_candidate(id, prep, cmp, excess, significant)
                .map_err(|e| (id.to_string(), e))?;
            let k = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            progress("candidates", k as f64 / ids.len().max(1) as f64);
            Ok(c)
        })
        .collect();
    let mut cands = Vec::new();
    for f in fits {
        match f {
            Ok(c) => cands.push(c),
            Err((id, e)) => {
                tracing::warn!("candidate {id} failed: {e}");
                skipped.push((id, format!("fit failed: {e}")));
            }
        }
    }
    cands
}

/// One candidate's screening score: its signature fitted to the residuals of
/// the model as it is (shares of the excess only when `significant`).
pub(super) fn screen_candidate(
    id: &str,
    prep: &Prepared,
    cmp: &Comparison,
    excess: f64,
    significant: bool,
) -> Result<CandidateScore, LabError> {
    let share = |x: f64| if significant { x } else { f64::NAN };
    // (no excess over the noise: no form explains more than noise, and the
    // verdict is `nothing_missing` whatever they score — the forms are not
    // compared, as for an effect that explains little of an excess)
    let (sig, f, knots, form_scores) = if crate::shape::has_shape_form(id) && significant {
        let c = crate::shape::choose_form(
            id,
            prep,
            &cmp.model.spec,
            &cmp.model.waveform,
            &cmp.recs,
            cmp.noise_floor(),
        )?;
        (c.signature, c.fit, c.knots, c.scores)
    } else {
        let sig = make_signature(id, prep, &cmp.model.spec, &cmp.model.waveform)?;
        let f = fit_signature(sig.as_ref(), &cmp.recs, prep, None)?;
        (sig, f, None, Vec::new())
    };
    let dchi = (f.chi2_before - f.chi2).max(0.0);
    let chi_after = cmp.chi2 - dchi;
    let dof_after = cmp.dof - f.n_params as f64;
    let mut params = BTreeMap::new();
    let mut standard_errors = BTreeMap::new();
    let names = sig.lin_names().into_iter().chain(sig.nl_names());
    let values = f
        .lin
        .iter()
        .chain(&f.nl)
        .zip(f.lin_se.iter().chain(&f.nl_se));
    for (n, (v, se)) in names.zip(values) {
        params.insert(n.clone(), *v);
        standard_errors.insert(n, *se);
    }
    Ok(CandidateScore {
        effect: id.to_string(),
        delta_bic: bic(chi_after, f.n_params, cmp.n) - bic(cmp.chi2, 0, cmp.n),
        delta_aic: crate::stats::aic(chi_after, f.n_params) - crate::stats::aic(cmp.chi2, 0),
        explained_excess: share(dchi / excess),
        cv_gain: share((f.cv_chi2_before - f.cv_chi2) / excess),
        explained: cmp.size_of(dchi, prep),
        z_after: chi2_z(chi_after, dof_after),
        params,
        standard_errors,
        flags: Vec::new(),
        at_bound: crate::signatures::at_bounds(sig.as_ref(), &f.nl),
        fit: Some(EffectFit {
            id: id.to_string(),
            lin: f.lin,
            nl: f.nl,
        }),
        nuisance: f.nuisance,
        structure_after: None,
        rms_after: None,
        cancels_in_4phase: cancels_in_4phase(id),
        refit: None,
        form: crate::shape::form_name(knots.as_ref()),
        form_scores,
        knots,
    })
}

/// Without repeated captures the noise was estimated from residuals that
/// contain the structure, so χ² − dof understates the excess: shares are
/// measured against the best explanation instead. Returns the excess used.
pub(super) fn rescale_to_best(cands: &mut [CandidateScore], excess: f64) -> f64 {
    let best = cands
        .iter()
        .map(|c| c.explained_excess * excess)
        .fold(0.0f64, f64::max);
    if best <= excess {
        return excess;
    }
    let f = excess / best;
    for c in cands.iter_mut() {
        c.explained_excess *= f;
        c.cv_gain *= f;
    }
    best
}

/// The leading candidates are refitted with the whole model (the per-pixel
/// parameters re-adjust with the effect present): z after, structure left
/// and depth errors after come from that refit. Returns the structure each
/// refit leaves, in refit order.
pub(super) fn refit_leaders(
    prep: &Prepared,
    cmp: &Comparison,
    cands: &mut [CandidateScore],
    excess: f64,
    significant: bool,
) -> Result<Vec<Vec<ConditionScore>>, LabError> {
    // The runner-up is refitted only when it could compete (screening share
    // at least half the leader's).
    // (none without an excess: the verdict is `nothing_missing` whatever they do)
    let mut top: Vec<usize> = (0..cands.len().min(usize::from(significant))).collect();
    if cands.len() > 1
        && cands[1].explained_excess >= 0.5 * cands[0].explained_excess.max(0.0)
        && cands[1].explained_excess > 0.05
    {
        top.push(1);
    }
    // One after the other (each refit is parallel inside): only one refitted
    // residual table is alive beside the comparison's.
    let mut remaining: Vec<Vec<ConditionScore>> = Vec::new();
    for i in top {
        remaining.push(refit_leader(prep, cmp, &mut cands[i], excess)?);
    }
    Ok(remaining)
}

/// Refit one leading candidate with the whole model and record its evidence
/// after the refit; returns the structure the refit leaves.
pub(super) fn refit_leader(
    prep: &Prepared,
    cmp: &Comparison,
    c: &mut CandidateScore,
    excess: f64,
) -> Result<Vec<ConditionScore>, LabError> {
    let fit = c
        .fit
        .clone()
        .ok_or_else(|| LabError::numerical("candidate without fit"))?;
    let base = with_form(&cmp.model, &c.effect, c.knots.as_ref());
    let m = crate::fit::refit_with(prep, &base, &fit, c.nuisance, 3)?;
    let mut c2 = comparison_of(prep, m)?;
    c.explained_excess = c.explained_excess.max((cmp.chi2 - c2.chi2) / excess);
    c.z_after = c2.fit.z;
    c.delta_bic = bic(c2.chi2, c2.model.n_params, cmp.n) - bic(cmp.chi2, cmp.model.n_params, cmp.n);
    c.delta_aic = crate::stats::aic(c2.chi2, c2.model.n_params)
        - crate::stats::aic(cmp.chi2, cmp.model.n_params);
    c.structure_after = Some(c2.structure.first().map(|s| s.z).unwrap_or(0.0));
    if let Some(gain) = refit_cv_gain(prep, &mut c2, c)? {
        c.cv_gain = c.cv_gain.max(gain);
    }
    c.rms_after = Some(c2.rms);
    c.refit = Some(Box::new(c2.model));
    Ok(c2.structure)
}

/// `model` with effect `id`'s law in the form of `knots` (a shape; `None`:
/// the parametric form) for what is fitted next.
pub(super) fn with_form(model: &LabModel, id: &str, knots: Option<&Vec<f64>>) -> LabModel {
    let mut m = model.clone();
    match knots {
        Some(k) => m.spec.shapes.insert(id.to_string(), k.clone()),
        None => m.spec.shapes.remove(id),
    };
    m
}

/// Cross-validate again on the refitted model (the per-pixel parameters no
/// longer absorb the effect): the effect's contribution is put back into the
/// residual and refitted on training blocks only. (the residual of the
/// refitted model without the effect: for an effect on the phasor its A and φ
/// change too, not only the codes). `None` when there is nothing to credit.
pub(super) fn refit_cv_gain(
    prep: &Prepared,
    c2: &mut Comparison,
    c: &CandidateScore,
) -> Result<Option<f64>, LabError> {
    let Some(i) = c2.model.effects.iter().position(|e| e.id == c.effect) else {
        return Ok(None);
    };
    let sig = make_signature(&c.effect, prep, &c2.model.spec, &c2.model.waveform)?;
    c2.recs = Vec::new();
    let mut without = c2.model.clone();
    let e = without.effects.remove(i);
    let recs = without.records(prep)?;
    let f = fit_values(sig.as_ref(), &recs, prep, Some(&e))?;
    let ex = f.chi2_before - c2.dof;
    // never credited beyond what the refit explains of the baseline excess
    Ok((ex > 0.0).then(|| ((f.cv_chi2_before - f.cv_chi2) / ex).min(c.explained_excess)))
}
