//! Daemon clients and tools: `power`, `monitor`, `status`, `record`, `soak` (issue: tofproxd).
use std::process::ExitCode;

#[derive(clap::Args, Debug)]
pub struct PowerArgs {}
#[derive(clap::Args, Debug)]
pub struct MonitorArgs {}
#[derive(clap::Args, Debug)]
pub struct StatusArgs {}
#[derive(clap::Args, Debug)]
pub struct RecordArgs {}
#[derive(clap::Args, Debug)]
pub struct SoakArgs {}

pub fn power(_a: PowerArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("not yet implemented")
}
pub fn monitor(_a: MonitorArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("not yet implemented")
}
pub fn status(_a: StatusArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("not yet implemented")
}
pub fn record(_a: RecordArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("not yet implemented")
}
pub fn soak(_a: SoakArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("not yet implemented")
}
