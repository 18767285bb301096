//! The verdict rule: size in mm/LSB beside z, a noise-tied tolerance, several effects at
//! once, the honest verdicts where the noise is not measured or there is no signal.
use super::*;

/// The verdict from the fit and the ranked candidates, with the structure
/// that remains to explain.
pub(super) fn verdict_of(
    prep: &Prepared,
    cmp: &Comparison,
    cands: &[CandidateScore],
    remaining: Vec<Vec<ConditionScore>>,
    noise_known: bool,
) -> (Decision, Vec<ConditionScore>) {
    let struct_base = cmp.structure.first().map(|s| s.z).unwrap_or(0.0);
    let mut d = decide(cmp.fit.z, cmp.fit.chi2_per_dof, struct_base, cands);
    if !noise_known && d.verdict == Verdict::NothingMissing && struct_base > STRUCTURE_NULL {
        // the global z is not trustworthy without repeats; structure decides
        d = decide(f64::INFINITY, f64::INFINITY, struct_base, cands);
    }
    let remaining_structure = if d.verdict == Verdict::Unexplained
        && cands.first().is_some_and(|c| c.explained_excess > 0.3)
    {
        remaining
            .into_iter()
            .next()
            .unwrap_or_else(|| cmp.structure.clone())
    } else {
        cmp.structure.clone()
    };
    if d.verdict == Verdict::Ambiguous
        && let (Some(a), Some(b)) = (&d.effect, &d.runner_up)
    {
        d.separate_by = Some(separating_condition(a, b, prep));
    }
    (d, remaining_structure)
}

/// Detectable is not the same as relevant: with 10⁶ samples any small
/// departure of the true law from the model's is significant. What remains
/// is compared, in depth-equivalent mm, with a tolerance tied to the noise.
/// Returns the decision, the detectable-but-small structures and the size
/// of what remains (mm).
pub(super) fn apply_tolerance(
    cmp: &Comparison,
    opts: &DiagnoseOptions,
    tolerance_mm: f64,
    cands: &[CandidateScore],
    mut d: Decision,
) -> (Decision, Vec<SmallStructure>, f64) {
    // without repeats the global excess is not known: the structure's size counts
    let top_structure = cmp
        .structure
        .iter()
        .map(|s| s.size_mm)
        .fold(0.0f64, f64::max);
    let remaining_mm = cmp.size.mm.max(top_structure);
    let mut small = Vec::new();
    // a catalogue effect that leaves noise-like residuals is named however small
    let fully_explained = d.verdict == Verdict::MissingEffect
        && cands
            .first()
            .is_some_and(|c| c.z_after <= Z_NULL && c.explained_excess >= MIN_EXPLAINED);
    if remaining_mm <= tolerance_mm && !fully_explained {
        small = small_structures(cmp, &d);
        if d.verdict != Verdict::NothingMissing {
            d = below_tolerance(cmp, opts, tolerance_mm, remaining_mm);
        }
    }
    (d, small, remaining_mm)
}

/// The structures detectable (z > STRUCTURE_NULL) but below the tolerance:
/// the conditions, and the effect `d` names unless nothing is missing.
pub(super) fn small_structures(cmp: &Comparison, d: &Decision) -> Vec<SmallStructure> {
    let mut small = Vec::new();
    for st in cmp.structure.iter().filter(|s| s.z > STRUCTURE_NULL) {
        small.push(SmallStructure {
            name: st.condition.clone(),
            kind: "condition",
            z: st.z,
            size_mm: st.size_mm,
            size_lsb: st.size_lsb,
        });
    }
    if d.verdict != Verdict::NothingMissing
        && let Some(e) = &d.effect
    {
        small.push(SmallStructure {
            name: e.clone(),
            kind: "effect",
            z: cmp.fit.z,
            size_mm: cmp.size.mm,
            size_lsb: cmp.size.lsb,
        });
    }
    small
}

/// The `nothing_missing` decision for what remains below the tolerance.
pub(super) fn below_tolerance(
    cmp: &Comparison,
    opts: &DiagnoseOptions,
    tolerance_mm: f64,
    remaining_mm: f64,
) -> Decision {
    Decision {
        verdict: Verdict::NothingMissing,
        effect: None,
        runner_up: None,
        separate_by: None,
        reason: format!(
            "what remains ({remaining_mm:.2} mm depth-equivalent, {:.2} LSB, z = {:.1}) is below the tolerance {tolerance_mm:.2} mm{}",
            cmp.size.lsb,
            cmp.fit.z,
            if opts.tolerance_mm.is_none() {
                format!(
                    " ({TOLERANCE_NOISE_SHARE} × the single-acquisition noise {:.2} mm)",
                    cmp.noise_single.mm
                )
            } else {
                String::new()
            }
        ),
    }
}

/// The share of the codes' modulation the model must follow, below which a
/// recording shows no signal the model can follow (random codes, constant
/// frames, the wrong distances).
pub const MIN_SIGNAL_SHARE: f64 = 0.25;

/// Why the recording cannot be diagnosed at all: its illuminated codes do not
/// follow the illumination. What random and constant frames lack is the
/// modulation the phase–distance relation (eq. 2.6) and the falling amplitude
/// put into the raw images of one capture: the share of the measured codes'
/// variation over a capture's raw images (each pixel's mean removed, so
/// offsets and the background do not count) that the model follows,
/// `1 − Σ(r − r̄)² / Σ(y − ȳ)²`. A model error the lab is there to find
/// (a drift of 0.5 rad leaves 1 − (2 sin 0.25)² ≈ 76 %) or noise at an
/// amplitude-to-σ ratio above ~1 keep it above [`MIN_SIGNAL_SHARE`]; random
/// codes give ~0, constant frames have no variation at all. It rests on no
/// noise estimate, so a residual-based one inflated by a missing effect
/// cannot trip it.
pub(super) fn no_signal(prep: &Prepared, cmp: &Comparison) -> Option<String> {
    // per (capture, pixel), indexed c·npix + p: n, Σy, Σy², Σr, Σr²
    let mut groups = vec![[0.0f64; 5]; prep.caps.len() * prep.npix];
    for r in cmp.recs.iter().filter(|r| prep.caps[r.cap as usize].illum) {
        let y = prep.meas[prep.idx(r.cap as usize, usize::from(r.k), r.pix as usize)];
        let res = f64::from(r.r);
        let g = &mut groups[r.cap as usize * prep.npix + r.pix as usize];
        for (s, v) in g.iter_mut().zip([1.0, y, y * y, res, res * res]) {
            *s += v;
        }
    }
    let centred = |n: f64, s: f64, s2: f64| (s2 - s * s / n).max(0.0);
    let (mut var_y, mut var_r, mut any) = (0.0, 0.0, false);
    for [n, sy, sy2, sr, sr2] in groups.into_iter().filter(|g| g[0] > 0.0) {
        var_y += centred(n, sy, sy2);
        var_r += centred(n, sr, sr2);
        any = true;
    }
    if !any {
        return Some("no valid illuminated sample (all saturated or dark)".into());
    }
    let share = if var_y > 0.0 {
        1.0 - var_r / var_y
    } else {
        f64::NEG_INFINITY
    };
    (share < MIN_SIGNAL_SHARE).then(|| {
        format!(
            "no signal: the model follows {:.0} % of the codes' variation over each capture's \
             raw images (needs ≥ {:.0} %); the codes do not follow the illumination at the \
             recorded distances (random or constant frames?)",
            100.0 * share.max(0.0),
            100.0 * MIN_SIGNAL_SHARE
        )
    })
}

/// The diagnosis of a recording that cannot be diagnosed (`unexplained`, no candidates).
pub(super) fn refused(cmp: &Comparison, reason: String, tolerance_mm: f64) -> Diagnosis {
    Diagnosis {
        verdict: Verdict::Unexplained,
        effect: None,
        runner_up: None,
        separate_by: None,
        candidates: Vec::new(),
        skipped: Vec::new(),
        fit: cmp.fit,
        strongest_condition: None,
        rms: cmp.rms,
        structure_remaining: cmp.structure.clone(),
        reason,
        size: cmp.size,
        noise_single: cmp.noise_single,
        tolerance_mm,
        small: Vec::new(),
        noise: cmp.model.noise.source,
    }
}

/// Below this χ²/dof the residual is smaller than the measured noise by more
/// than any fit could make it: the noise estimate does not describe the data.
pub const MIN_CHI2_PER_DOF: f64 = 0.8;

/// `nothing_missing` only where the noise was measured and describes the
/// residual: otherwise `noise_not_measured`, or `unexplained` with the reason.
pub(super) fn honest_verdict(
    cmp: &Comparison,
    verdict: Verdict,
    reason: String,
) -> (Verdict, String) {
    if verdict != Verdict::NothingMissing {
        return (verdict, reason);
    }
    if !cmp.model.noise.source.measured() {
        return (
            Verdict::NoiseNotMeasured,
            format!(
                "the residual looks like noise ({reason}), but the noise is {}: record repeated captures to tell noise from a missing effect",
                cmp.model.noise.source.describe()
            ),
        );
    }
    if cmp.fit.chi2_per_dof < MIN_CHI2_PER_DOF {
        return (
            Verdict::Unexplained,
            format!(
                "the residual is far below the measured noise (χ²/dof = {:.3} < {MIN_CHI2_PER_DOF}): the repeats' noise does not describe this recording",
                cmp.fit.chi2_per_dof
            ),
        );
    }
    (verdict, reason)
}

/// No share above 100 % and no negative z after reaches a report: the value
/// is clamped and the raw figure kept in `flags` with its meaning.
pub(super) fn clamp_reported(c: &mut CandidateScore) {
    for (name, v) in [
        ("explains", &mut c.explained_excess),
        ("explains on held-out blocks", &mut c.cv_gain),
    ] {
        if *v > 1.0 {
            c.flags.push(format!(
                "{name} {:.0}% of the excess: more than there is (what remains is below the noise expectation); shown as 100%",
                100.0 * *v
            ));
            *v = 1.0;
        }
    }
    if c.z_after < 0.0 {
        if c.z_after < -Z_NULL {
            c.flags.push(format!(
                "z after {:.1}: χ² after is far below its noise expectation (the noise is overestimated or the effect fits noise); shown as 0",
                c.z_after
            ));
        }
        c.z_after = 0.0;
    }
}

/// Candidate order: by held-out share, then share, then (when there is no
/// excess to share) by the size of what the candidate removes.
pub(super) fn rank(a: &CandidateScore, b: &CandidateScore) -> std::cmp::Ordering {
    let key = |x: f64| if x.is_nan() { f64::NEG_INFINITY } else { x };
    key(b.cv_gain)
        .total_cmp(&key(a.cv_gain))
        .then(key(b.explained_excess).total_cmp(&key(a.explained_excess)))
        .then(b.explained.lsb.total_cmp(&a.explained.lsb))
}

/// The condition the residual is most structured against. Acquisition order
/// (`capture_index`) stands in for every condition the sweep stepped through,
/// so it is named only when it clearly beats all physical conditions.
pub fn strongest_condition(st: &[ConditionScore]) -> Option<String> {
    let best_phys = st
        .iter()
        .filter(|s| s.condition != "capture_index")
        .max_by(|a, b| a.z.total_cmp(&b.z));
    let order = st.iter().find(|s| s.condition == "capture_index");
    match (best_phys, order) {
        (Some(p), Some(o)) if o.z > 2.0 * p.z.max(0.0) => Some(o.condition.clone()),
        (Some(p), _) => Some(p.condition.clone()),
        (None, Some(o)) => Some(o.condition.clone()),
        (None, None) => None,
    }
}

/// Outcome of the decision rule (separate for testing).
#[derive(Debug, Clone, PartialEq)]
pub struct Decision {
    /// As [`Diagnosis::verdict`].
    pub verdict: Verdict,
    /// As [`Diagnosis::effect`].
    pub effect: Option<String>,
    /// As [`Diagnosis::runner_up`].
    pub runner_up: Option<String>,
    /// As [`Diagnosis::separate_by`].
    pub separate_by: Option<String>,
    /// As [`Diagnosis::reason`].
    pub reason: String,
}

/// Several missing effects: most of the excess explained, on held-out blocks too.
pub(super) fn passes_partial(c: &CandidateScore) -> bool {
    c.explained_excess >= MIN_PARTIAL && c.cv_gain >= MIN_PARTIAL
}

/// `best` is clearly better than `runner_up` (partial acceptance needs it).
pub(super) fn clearly_best(best: &CandidateScore, runner_up: Option<&CandidateScore>) -> bool {
    runner_up.is_none_or(|ru| {
        ru.cv_gain <= 0.5 * best.cv_gain || best.cv_gain - ru.cv_gain >= 2.5 * AMBIGUITY_MARGIN
    })
}

pub(super) fn passes(c: &CandidateScore, z_base: f64, struct_base: f64) -> bool {
    let noise_like = c.z_after <= Z_NULL;
    let z_ok = c.z_after <= Z_NULL.max(0.1 * z_base);
    let s_ok = c
        .structure_after
        .is_none_or(|s| s <= STRUCTURE_NULL.max(0.1 * struct_base));
    // When the residual after the fit is noise-like, the remaining "excess" is
    // noise and the explained share need not be large.
    (c.explained_excess >= MIN_EXPLAINED || noise_like)
        && c.cv_gain >= MIN_CV.min(0.7 * c.explained_excess)
        && z_ok
        && s_ok
}

/// The verdict from the global fit and the ranked candidates (sorted by cv_gain).
/// ΔBIC alone is never enough: an effect must explain most of the excess, hold
/// up on held-out blocks, leave noise-like residuals and beat the runner-up.
pub fn decide(
    z_base: f64,
    chi2_per_dof: f64,
    struct_base: f64,
    cands: &[CandidateScore],
) -> Decision {
    if z_base <= Z_NULL || (chi2_per_dof <= 1.02 && struct_base <= STRUCTURE_NULL) {
        return Decision {
            verdict: Verdict::NothingMissing,
            effect: None,
            runner_up: None,
            separate_by: None,
            reason: format!(
                "residual consistent with noise (z = {z_base:.1}, χ²/dof = {chi2_per_dof:.3}, strongest structure z = {struct_base:.1})"
            ),
        };
    }
    let Some(best) = cands.first() else {
        return Decision {
            verdict: Verdict::Unexplained,
            effect: None,
            runner_up: None,
            separate_by: None,
            reason: "misfit but no candidate effect could be fitted".into(),
        };
    };
    let full = passes(best, z_base, struct_base);
    let partial = passes_partial(best) && clearly_best(best, cands.get(1));
    if !(full || partial) {
        return Decision {
            verdict: Verdict::Unexplained,
            effect: None,
            runner_up: None,
            separate_by: None,
            reason: format!(
                "best candidate {} explains {:.0}% of the excess (cv {:.0}%, z after {:.1}): not enough",
                best.effect,
                100.0 * best.explained_excess,
                100.0 * best.cv_gain,
                best.z_after
            ),
        };
    }
    // Occam: a runner-up with more parameters that explains no more than the
    // best does not make the verdict ambiguous
    let simpler_suffices = |ru: &CandidateScore| {
        best.params.len() < ru.params.len()
            && best.explained_excess >= ru.explained_excess
            && best.cv_gain >= ru.cv_gain
    };
    if let Some(ru) = cands.get(1)
        && (passes(ru, z_base, struct_base) || passes_partial(ru))
        && !simpler_suffices(ru)
        && best.cv_gain - ru.cv_gain < AMBIGUITY_MARGIN
        && (best.explained_excess - ru.explained_excess) < AMBIGUITY_MARGIN
        && (1.0 - ru.explained_excess) < REMAINDER_RATIO * (1.0 - best.explained_excess).max(0.0)
    {
        return Decision {
            verdict: Verdict::Ambiguous,
            effect: Some(best.effect.clone()),
            runner_up: Some(ru.effect.clone()),
            separate_by: None,
            reason: format!(
                "{} and {} explain the residual equally well ({:.0}% vs {:.0}%)",
                best.effect,
                ru.effect,
                100.0 * best.explained_excess,
                100.0 * ru.explained_excess
            ),
        };
    }
    Decision {
        verdict: Verdict::MissingEffect,
        effect: Some(best.effect.clone()),
        runner_up: cands.get(1).map(|c| c.effect.clone()),
        separate_by: None,
        reason: format!(
            "{} explains {:.0}% of the excess χ² ({:.0}% on held-out distance blocks), z after {:.1}{}",
            best.effect,
            100.0 * best.explained_excess,
            100.0 * best.cv_gain,
            best.z_after,
            if full {
                ""
            } else {
                "; structure remains after it: add it and diagnose again (`lab explain` continues)"
            }
        ),
    }
}

/// A condition that one of two effects varies with and the other does not,
/// preferring one the recording did not vary.
pub fn separating_condition(a: &str, b: &str, prep: &Prepared) -> String {
    let ca = effect_conditions(a);
    let cb = effect_conditions(b);
    let mut diff: Vec<Driver> = ca
        .iter()
        .filter(|c| !cb.contains(c))
        .chain(cb.iter().filter(|c| !ca.contains(c)))
        .copied()
        .collect();
    let varied = |c: Driver| match c {
        Driver::AmbientKlux => prep.ambient_varies,
        Driver::TemperatureC => prep.temperature_varies,
        Driver::ExposureUs => prep.exposure_varies,
        _ => true,
    };
    diff.sort_by_key(|c| varied(*c));
    diff.first()
        .copied()
        .unwrap_or(Driver::ExposureUs)
        .as_str()
        .to_string()
}
