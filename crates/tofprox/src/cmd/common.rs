//! Helpers shared by the recording commands (`info`, `calibrate`, `process`):
//! progress bars, number formatting.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
pub use tofprox_format::fmt_num;

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
