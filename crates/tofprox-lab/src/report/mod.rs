//! Output of the lab: the `--json` documents described in docs/lab.md,
//! the compact terminal table, and the self-contained HTML report with inline
//! SVG plots (drawn by `tofprox-chart`, the one chart component; no network,
//! no fonts needed). One file per output kind; the formatting helpers they share are here.
use std::collections::BTreeMap;

use crate::uncertainty::ProfileInterval;

mod html;
mod json;
mod text;

pub use html::{explain_html, html_report};
pub use json::{add_json, comparison_json, diagnosis_json, explanation_json};
pub use text::{
    before_after_text, comparison_text, criteria_change_text, criteria_text, diagnosis_text,
    fitted_text,
};

/// An interval end for text and HTML ("—" where none was found), with "≥"
/// or "≤" where it stops at the range's bound.
fn interval_end(iv: &ProfileInterval, side: &str, level: usize) -> String {
    let v = if side == "lower" {
        iv.lower[level]
    } else {
        iv.upper[level]
    };
    if !v.is_finite() {
        return "—".into();
    }
    let label = format!("{side}_{}sigma", level + 1);
    let at = iv.at_range_bound.contains(&label);
    let mark = match (at, side) {
        (true, "lower") => "≤ ",
        (true, _) => "≥ ",
        _ => "",
    };
    format!("{mark}{v:.5e}")
}

/// A share in percent, or "—" when there is none (no excess to share).
fn percent(v: f64) -> String {
    if v.is_finite() {
        format!("{:.1}%", 100.0 * v)
    } else {
        "—".into()
    }
}

/// What is said beside fitted values and their standard errors: the note of
/// why the errors understate ([`crate::diagnose::errors_note`]), the
/// parameters at their range's bound ([`crate::signatures::at_bounds`]) and
/// the profile intervals ([`crate::uncertainty::profile_intervals`]).
pub type FitNotes<'a> = (
    Option<&'a str>,
    &'a [String],
    &'a BTreeMap<String, ProfileInterval>,
);
