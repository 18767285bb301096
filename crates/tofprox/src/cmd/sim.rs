//! `tofprox sim ...` and `tofprox model ...` (issue: physical model).
use std::process::ExitCode;

#[derive(clap::Subcommand, Debug)]
pub enum SimCommand {}
#[derive(clap::Subcommand, Debug)]
pub enum ModelCommand {}

pub fn run_sim(c: SimCommand) -> anyhow::Result<ExitCode> {
    match c {}
}
pub fn run_model(c: ModelCommand) -> anyhow::Result<ExitCode> {
    match c {}
}
