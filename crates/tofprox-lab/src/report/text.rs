//! The lab's terminal text: the compact tables and verdict lines.
use std::collections::BTreeMap;
use std::fmt::Write as _;

use crate::depth_error::{DepthErrorSplit, DepthSplit};
use crate::diagnose::{Comparison, Diagnosis, ErrorSummary};
use crate::signatures::cancels_in_4phase;

use super::{FitNotes, interval_end, percent};

/// The errors before and after adding effects, as a terminal table: raw and depth RMS and
/// χ²/dof, then how much of each depth RMS is systematic — √max(rms² − noise², 0) with its
/// share of rms² — and the noise floor ([`crate::depth_error`]; docs/lab.md).
pub fn before_after_text(
    (before, after): (&Comparison, &Comparison),
    (split_before, split_after): (&DepthSplit, &DepthSplit),
) -> String {
    let mut t = format!(
        "{:<12} {:>12} {:>14} {:>14} {:>10}\n",
        "", "raw [LSB]", "2-phase [mm]", "4-phase [mm]", "χ²/dof"
    );
    for (n, e) in [
        ("before", ErrorSummary::of(before)),
        ("after", ErrorSummary::of(after)),
    ] {
        let _ = writeln!(
            t,
            "{:<12} {:>12.3} {:>14.2} {:>14.2} {:>10.3}",
            n, e.raw_lsb, e.depth_2phase_mm, e.depth_4phase_mm, e.chi2_per_dof
        );
    }
    let _ = writeln!(
        t,
        "systematic part of the depth rms, √(rms² − noise²) (share of rms²; docs/lab.md):"
    );
    let part = |s: &DepthErrorSplit| {
        if s.rms_mm.is_finite() && s.noise_mm.is_finite() {
            format!(
                "{:.2} ({:.0} %)",
                s.systematic_mm,
                100.0 * s.systematic_share
            )
        } else {
            "—".to_string()
        }
    };
    for (n, s) in [("before", split_before), ("after", split_after)] {
        let _ = writeln!(
            t,
            "{:<12} {:>12} {:>14} {:>14}",
            n,
            "",
            part(&s.two_phase),
            part(&s.four_phase)
        );
    }
    for (n, s) in [("noise before", split_before), ("noise after", split_after)] {
        let _ = writeln!(
            t,
            "{:<12} {:>12} {:>14.2} {:>14.2}",
            n, "", s.two_phase.noise_mm, s.four_phase.noise_mm
        );
    }
    t
}

/// The information criteria before and after `add`, one terminal line: the
/// two changes (negative supports the effect).
pub fn criteria_change_text(before: &ErrorSummary, after: &ErrorSummary) -> String {
    format!(
        "criteria: AIC {:.1} → {:.1} (Δ {:+.1}), BIC {:.1} → {:.1} (Δ {:+.1})\n",
        before.aic,
        after.aic,
        after.aic - before.aic,
        before.bic,
        after.bic,
        after.bic - before.bic
    )
}

/// The fitted parameters with their standard errors, one `  name = value ± SE` line each
/// ("± —" where there is none), under a heading saying what they are, the
/// note of why the errors understate, if any ([`crate::diagnose::errors_note`]),
/// and a line per parameter fitted at its range's bound
/// ([`crate::signatures::at_bounds`]).
pub fn fitted_text(
    effect: &str,
    params: &BTreeMap<String, f64>,
    standard_errors: &BTreeMap<String, f64>,
    (note, at_bound, intervals): FitNotes<'_>,
) -> String {
    let mut s = format!(
        "{effect} fitted (the lab's signature parameters, ± 1 standard error with the per-pixel parameters free, scaled by χ²/dof):\n"
    );
    for (k, v) in params {
        let se = standard_errors.get(k).copied().unwrap_or(f64::NAN);
        let se = if se.is_finite() {
            format!("{se:.2e}")
        } else {
            "—".into()
        };
        let _ = writeln!(s, "  {k:<20} = {v:>12.5e} ± {se}");
    }
    if let Some(n) = note {
        let _ = writeln!(s, "  note: {n}");
    }
    for b in at_bound {
        let _ = writeln!(s, "  at bound: {b}");
    }
    if !intervals.is_empty() {
        let _ = writeln!(
            s,
            "  profile intervals (others refitted; Δχ² = 1 and 4 in units of χ²/dof; ≤/≥: the range's bound):"
        );
    }
    for (k, iv) in intervals {
        let _ = writeln!(
            s,
            "  {k:<20}   1σ [{}, {}]   2σ [{}, {}]",
            interval_end(iv, "lower", 0),
            interval_end(iv, "upper", 0),
            interval_end(iv, "lower", 1),
            interval_end(iv, "upper", 1),
        );
    }
    s
}

/// The information criteria of a fit, one terminal line.
pub fn criteria_text(f: &crate::diagnose::FitStats) -> String {
    format!(
        "criteria: AIC = {:.1}, BIC = {:.1} (χ² + 2k, χ² + k·ln n; only differences between models of one recording count)",
        f.aic, f.bic
    )
}

/// The compact terminal table of `compare`.
pub fn comparison_text(c: &Comparison) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "fit: χ²/dof = {:.3}, z = {:.1} over {} samples ({} parameters); noise {}",
        c.fit.chi2_per_dof,
        c.fit.z,
        c.n,
        c.model.n_params,
        c.model.noise.source.describe()
    );
    let _ = writeln!(s, "{}", criteria_text(&c.fit));
    let _ = writeln!(
        s,
        "rms: raw {:.3} LSB, depth 2-phase {:.2} mm, 4-phase {:.2} mm",
        c.rms.raw_lsb, c.rms.depth_2phase_mm, c.rms.depth_4phase_mm
    );
    let _ = writeln!(
        s,
        "remaining: {:.2} mm depth-equivalent, {:.3} LSB (single-acquisition noise {:.2} mm, {:.2} LSB)",
        c.size.mm, c.size.lsb, c.noise_single.mm, c.noise_single.lsb
    );
    structure_table(&mut s, &c.structure);
    s
}

fn structure_table(s: &mut String, st: &[crate::structure::ConditionScore]) {
    let _ = writeln!(
        s,
        "{:<18} {:>10} {:>6} {:>9} {:>9}  direction   (structure z; ≤ 6 is noise)",
        "condition", "z", "dof", "size[mm]", "size[LSB]"
    );
    for st in st {
        let flag = if st.z > 6.0 { "  ◀ model fails" } else { "" };
        let _ = writeln!(
            s,
            "{:<18} {:>10.1} {:>6} {:>9.3} {:>9.3}  {:<10}{flag}",
            st.condition, st.z, st.dof, st.size_mm, st.size_lsb, st.direction
        );
    }
}

/// The compact terminal table of `diagnose`.
pub fn diagnosis_text(d: &Diagnosis) -> String {
    let mut s = String::new();
    let verdict = match (&d.effect, d.verdict.as_str()) {
        (Some(e), "missing_effect") => format!("MISSING EFFECT: {e}"),
        (Some(e), "ambiguous") => format!(
            "AMBIGUOUS: {e} or {} — vary {} to separate them",
            d.runner_up.as_deref().unwrap_or("?"),
            d.separate_by.as_deref().unwrap_or("?")
        ),
        (_, "nothing_missing") => "NOTHING MISSING".to_string(),
        (_, "noise_not_measured") => "NOISE NOT MEASURED: no verdict".to_string(),
        _ => format!(
            "UNEXPLAINED structure, strongest against {}",
            d.strongest_condition.as_deref().unwrap_or("?")
        ),
    };
    let _ = writeln!(s, "verdict: {verdict}");
    let _ = writeln!(s, "         {}", d.reason);
    let _ = writeln!(s, "evidence: {}", d.evidence());
    if let Some(p) = crate::user::proposal(d) {
        let _ = writeln!(s, "proposal: {}", p.sentence);
    }
    let _ = writeln!(
        s,
        "fit: χ²/dof = {:.3}, z = {:.1}; rms raw {:.3} LSB, depth 2-phase {:.2} mm, 4-phase {:.2} mm",
        d.fit.chi2_per_dof, d.fit.z, d.rms.raw_lsb, d.rms.depth_2phase_mm, d.rms.depth_4phase_mm
    );
    let _ = writeln!(s, "{}", criteria_text(&d.fit));
    let _ = writeln!(s, "noise: {}", d.noise.describe());
    let _ = writeln!(
        s,
        "remaining: {:.2} mm depth-equivalent ({:.3} LSB) — tolerance {:.2} mm (single-acquisition noise {:.2} mm)",
        d.size.mm, d.size.lsb, d.tolerance_mm, d.noise_single.mm
    );
    for sm in &d.small {
        let _ = writeln!(
            s,
            "detectable but small: {} {} (z = {:.1}, {:.3} mm, {:.3} LSB)",
            sm.kind, sm.name, sm.z, sm.size_mm, sm.size_lsb
        );
    }
    let _ = writeln!(
        s,
        "{:<24} {:>9} {:>8} {:>12} {:>10} {:>12} {:>12}  4-phase cancels",
        "candidate", "explained", "cv_gain", "removes [mm]", "z_after", "ΔAIC", "ΔBIC"
    );
    for c in &d.candidates {
        let _ = writeln!(
            s,
            "{:<24} {:>9} {:>8} {:>12.3} {:>10.1} {:>12.1} {:>12.1}  {}",
            c.effect,
            percent(c.explained_excess),
            percent(c.cv_gain),
            c.explained.mm,
            c.z_after,
            c.delta_aic,
            c.delta_bic,
            if cancels_in_4phase(&c.effect) {
                "yes"
            } else {
                "no"
            }
        );
    }
    for (id, why) in &d.skipped {
        let _ = writeln!(s, "{id:<24} not testable: {why}");
    }
    for c in &d.candidates {
        for f in &c.flags {
            let _ = writeln!(s, "note: {}: {f}", c.effect);
        }
    }
    s
}
