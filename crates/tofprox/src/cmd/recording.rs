//! `tofprox info`, `calibrate`, `process` (issue: foundation).
use std::process::ExitCode;

#[derive(clap::Args, Debug)]
pub struct InfoArgs {}
#[derive(clap::Args, Debug)]
pub struct CalibrateArgs {}
#[derive(clap::Args, Debug)]
pub struct ProcessArgs {}

pub fn info(_a: InfoArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("not yet implemented")
}
pub fn calibrate(_a: CalibrateArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("not yet implemented")
}
pub fn process(_a: ProcessArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("not yet implemented")
}
