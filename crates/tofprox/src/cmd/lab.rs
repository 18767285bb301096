//! `tofprox lab ...` (issue: model lab).
use std::process::ExitCode;

#[derive(clap::Subcommand, Debug)]
pub enum LabCommand {}

pub fn run(c: LabCommand) -> anyhow::Result<ExitCode> {
    match c {}
}
