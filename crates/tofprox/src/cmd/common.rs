//! Helpers shared by the recording commands (`info`, `calibrate`, `process`):
//! progress bars, number formatting, capture mode labels.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tofprox_format::CaptureMeta;

/// The tool name and version recorded in the provenance of what the commands write.
pub const TOOL: &str = concat!("tofprox ", env!("CARGO_PKG_VERSION"));

/// A progress bar on stderr when it is a terminal and there is more than one step (hidden otherwise).
pub fn progress(len: usize, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len as u64);
    if std::io::stderr().is_terminal() && len > 1 {
        pb.set_draw_target(ProgressDrawTarget::stderr());
        if let Ok(style) = ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed}") {
            pb.set_style(style.progress_chars("=> "));
        }
        pb.set_message(what.to_string());
    } else {
        pb.set_draw_target(ProgressDrawTarget::hidden());
    }
    pb
}

/// A short name for the acquisition mode of a capture.
pub fn mode_label(c: &CaptureMeta) -> String {
    let n = c.phases_deg.len();
    if c.is_four_phase() {
        "4phase".into()
    } else if n == 2 && c.starts_two_phase() {
        "2phase".into()
    } else if c.is_correlation() {
        format!("correlation-{n}")
    } else {
        let p: Vec<String> = c.phases_deg.iter().map(|p| format!("{p}")).collect();
        format!("{n}-phase[{}]", p.join(","))
    }
}

/// A number with up to six decimals and no trailing zeros (`0.25`, `80`).
pub fn fmt_num(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s.is_empty() || s == "-" {
        "0".into()
    } else {
        s.to_string()
    }
}
