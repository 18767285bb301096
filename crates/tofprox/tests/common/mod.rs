//! Helpers shared by the command-line end-to-end tests.
#![allow(dead_code)] // each test binary uses a subset of the helpers
use std::process::{Command, Output};

/// Run the `tofprox` binary built for this test run with `args`.
pub fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tofprox"))
        .args(args)
        .output()
        .expect("run tofprox")
}

/// Lossy UTF-8 text of captured output.
pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}
