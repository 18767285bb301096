//! `tofprox device ...` (issue: bridge and driver).
use std::process::ExitCode;

#[derive(clap::Subcommand, Debug)]
pub enum DeviceCommand {}

pub fn run(c: DeviceCommand) -> anyhow::Result<ExitCode> {
    match c {}
}
