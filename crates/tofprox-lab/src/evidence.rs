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

/// Why the residual counts as noise: below the tolerance though detectable, or as large as
/// the noise predicts.
fn quiet(d: &Diagnosis) -> String {
    let strongest = strongest_clause(d.structure_remaining.first());
    if d.fit.z > Z_NULL && d.size.mm <= d.tolerance_mm {
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
