//! One plain sentence of evidence per verdict, built only from the numbers the
//! [`Diagnosis`] already carries: which condition the residual follows and how
//! strongly (structure z against the noise level [`STRUCTURE_NULL`]), the share
//! of the excess the best catalogue effect explains, and where the noise came
//! from. The lab's text output, HTML report and `--json` (`evidence`) print it.
use crate::diagnose::{
    CandidateScore, Diagnosis, MIN_CHI2_PER_DOF, STRUCTURE_NULL, Verdict, Z_NULL,
};
use crate::structure::ConditionScore;

impl Diagnosis {
    /// The verdict's evidence in one sentence (docs/lab-json.md, `evidence`).
    pub fn evidence(&self) -> String {
        let noise = format!("the noise is {}", self.noise.describe());
        let follows = self.structure_remaining.first().map(follows);
        let best = self.candidates.first();
        match self.verdict {
            Verdict::MissingEffect => missing(self, follows, best, &noise),
            Verdict::Ambiguous => ambiguous(self, follows, &noise),
            Verdict::NothingMissing => format!("{} ({noise}).", quiet(self)),
            Verdict::NoiseNotMeasured => format!(
                "{}, but {noise}: without repeated captures a small missing effect cannot be \
                 told from noise.",
                quiet(self)
            ),
            Verdict::Unexplained => unexplained(self, follows, best, &noise),
        }
    }
}

/// Why the residual counts as noise: below the tolerance though detectable (by the global z
/// or, where the noise was not measured and χ² is the residuals' own, by a structure), or as
/// large as the noise predicts.
fn quiet(d: &Diagnosis) -> String {
    let strongest = strongest_clause(d.structure_remaining.first());
    let detectable = d.fit.z > Z_NULL
        || (!d.noise.measured()
            && d.structure_remaining
                .first()
                .is_some_and(|s| s.z > crate::diagnose::STRUCTURE_NULL));
    if detectable && d.size.mm <= d.tolerance_mm {
        format!(
            "What remains is detectable (z = {:.1}{strongest}) but small: {:.2} mm \
             depth-equivalent, below the tolerance {:.2} mm",
            d.fit.z, d.size.mm, d.tolerance_mm
        )
    } else {
        format!(
            "The residual is as large as the noise predicts (χ²/dof = {:.3}, z = {:.1} against \
             ≤ {Z_NULL} for noise{strongest}); what remains is {:.2} mm depth-equivalent \
             (tolerance {:.2} mm)",
            d.fit.chi2_per_dof, d.fit.z, d.size.mm, d.tolerance_mm
        )
    }
}

/// "The residual follows distance_m (structure z = 41.2 against ≤ 6 for noise, 0.84 mm)".
fn follows(st: &ConditionScore) -> String {
    format!(
        "The residual follows {} (structure z = {:.1} against ≤ {STRUCTURE_NULL} for noise, {:.2} mm \
         in {})",
        st.condition, st.z, st.size_mm, st.direction
    )
}

/// ", strongest structure z = 2.1 against image_index" (or nothing without structure scores).
fn strongest_clause(st: Option<&ConditionScore>) -> String {
    st.map_or(String::new(), |st| {
        format!(
            ", strongest structure z = {:.1} against {}",
            st.z, st.condition
        )
    })
}

/// What the best candidate removes: its share of the excess, or its size when there is no
/// significant excess to share.
fn explains(c: &CandidateScore) -> String {
    if c.explained_excess.is_finite() {
        format!(
            "explains {:.0} % of the excess χ² ({:.2} mm), leaving z = {:.1}",
            100.0 * c.explained_excess,
            c.explained.mm,
            c.z_after
        )
    } else {
        format!(
            "removes {:.2} mm depth-equivalent, leaving z = {:.1}",
            c.explained.mm, c.z_after
        )
    }
}

fn missing(
    d: &Diagnosis,
    follows: Option<String>,
    best: Option<&CandidateScore>,
    noise: &str,
) -> String {
    let lead = follows.unwrap_or_else(|| "The residual has structure".into());
    let Some(c) = best else {
        return format!("{lead}; {noise}.");
    };
    let next = d.candidates.get(1).map_or(String::new(), |n| {
        format!("; the next, {}, {}", n.effect, explains(n))
    });
    format!(
        "{lead}; of the {} catalogue effects tested, {} {}{next} ({noise}).",
        d.candidates.len(),
        c.effect,
        explains(c)
    )
}

fn ambiguous(d: &Diagnosis, follows: Option<String>, noise: &str) -> String {
    let lead = follows.unwrap_or_else(|| "The residual has structure".into());
    let [a, b] = [d.effect.as_deref(), d.runner_up.as_deref()]
        .map(|e| e.and_then(|e| d.candidates.iter().find(|c| c.effect == e)));
    match (a, b) {
        (Some(a), Some(b)) => format!(
            "{lead}; {} {} and {} {} — about equally, so vary {} to tell them apart ({noise}).",
            a.effect,
            explains(a),
            b.effect,
            explains(b),
            d.separate_by.as_deref().unwrap_or("another condition"),
        ),
        _ => format!("{lead}; two effects explain it about equally ({noise})."),
    }
}

fn unexplained(
    d: &Diagnosis,
    follows: Option<String>,
    best: Option<&CandidateScore>,
    noise: &str,
) -> String {
    let Some(c) = best else {
        // refused before any candidate: the reason is the evidence
        return format!("No effect was tested: {} ({noise}).", d.reason);
    };
    if d.fit.chi2_per_dof < MIN_CHI2_PER_DOF {
        return format!(
            "The residual is smaller than the noise allows (χ²/dof = {:.3} < {MIN_CHI2_PER_DOF}): \
             the noise does not describe this recording ({noise}).",
            d.fit.chi2_per_dof
        );
    }
    let lead = follows.unwrap_or_else(|| {
        format!(
            "The residual is off the noise (χ²/dof = {:.3}, z = {:.1})",
            d.fit.chi2_per_dof, d.fit.z
        )
    });
    format!(
        "{lead}, and no catalogue effect accounts for it: the best of {}, {}, {} ({noise}).",
        d.candidates.len(),
        c.effect,
        explains(c)
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::{FitStats, Rms, Size};
    use crate::noise::NoiseSource;
    use tofprox_model::effects;

    fn candidate(effect: &str, share: f64, mm: f64, z_after: f64) -> CandidateScore {
        let mut c = crate::diagnose::tests::cand(effect, share, share, z_after, -100.0);
        c.explained = Size { lsb: 1.0, mm };
        c
    }

    /// Two candidates explain about equally (the one verdict no synthetic test reaches).
    fn ambiguous() -> Diagnosis {
        Diagnosis {
            verdict: Verdict::Ambiguous,
            effect: Some(effects::adc_inl::ID.as_str().into()),
            runner_up: Some(effects::tap_gain_mismatch::ID.as_str().into()),
            separate_by: Some("exposure_us".into()),
            candidates: vec![
                candidate(effects::adc_inl::ID.as_str(), 0.81, 0.52, 30.5),
                candidate(effects::tap_gain_mismatch::ID.as_str(), 0.77, 0.49, 35.25),
            ],
            skipped: Vec::new(),
            fit: FitStats {
                chi2_per_dof: 1.9,
                z: 160.0,
                ..FitStats::default()
            },
            strongest_condition: Some("adc_code".into()),
            rms: Rms::default(),
            structure_remaining: vec![ConditionScore {
                condition: "adc_code".into(),
                z: 88.04,
                chi2: 900.0,
                dof: 10,
                direction: "offset",
                size_lsb: 0.4,
                size_mm: 0.61,
                bins: Vec::new(),
            }],
            reason: String::new(),
            size: Size { lsb: 0.5, mm: 0.7 },
            noise_single: Size { lsb: 2.0, mm: 3.0 },
            tolerance_mm: 0.45,
            small: Vec::new(),
            noise: NoiseSource::Repeats { groups: 12 },
        }
    }

    #[test]
    fn ambiguous_names_both_shares_and_what_to_vary() {
        let ev = ambiguous().evidence();
        for want in [
            "The residual follows adc_code (structure z = 88.0 against ≤ 6 for noise, 0.61 mm in offset)",
            "adc_inl explains 81 % of the excess χ² (0.52 mm), leaving z = 30.5",
            "tap_gain_mismatch explains 77 % of the excess χ² (0.49 mm), leaving z = 35.2",
            "vary exposure_us to tell them apart",
            "the noise is measured from 12 groups of repeated captures",
        ] {
            assert!(ev.contains(want), "{ev:?} lacks {want:?}");
        }
    }

    #[test]
    fn without_a_share_the_size_removed_is_the_evidence() {
        let mut d = ambiguous();
        d.verdict = Verdict::MissingEffect;
        d.candidates[0].explained_excess = f64::NAN;
        let ev = d.evidence();
        assert!(
            ev.contains("of the 2 catalogue effects tested, adc_inl removes 0.52 mm depth-equivalent, leaving z = 30.5"),
            "{ev}"
        );
        assert!(!ev.contains("NaN"), "{ev}");
    }
}
