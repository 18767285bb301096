//! `tofprox`: the command-line tool. A thin binary: every command group lives
//! in its own module under `cmd/` and calls into the library crates.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cmd;

/// tofprox: low-power time-of-flight proximity sensing and the sensor model lab.
#[derive(Parser, Debug)]
#[command(name = "tofprox", version, about, propagate_version = true)]
struct Cli {
    /// More log output (repeat for more).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Summarise a recording (captures by mode/exposure/conditions, saturation share).
    Info(cmd::info::InfoArgs),
    /// Extract a calibration part (intrinsics, fpn, crosstalk, wiggling, fppn) from a recording,
    /// or calibrate a module on the production line (`calibrate station`).
    Calibrate(cmd::station::CalibrateCli),
    /// Process a recording's captures to depth and amplitude.
    Process(cmd::process::ProcessArgs),
    /// Simulate recordings with the physical model.
    #[command(subcommand)]
    Sim(cmd::sim::SimCommand),
    /// The physical model's effect catalogue and model files.
    #[command(subcommand)]
    Model(cmd::sim::ModelCommand),
    /// The model lab: compare, diagnose, add effects.
    #[command(subcommand)]
    Lab(cmd::lab::LabCommand),
    /// Talk to the sensor through the CX3 bridge (or the emulated device).
    #[command(subcommand)]
    Device(cmd::device::DeviceCommand),
    /// Modelled power of the low-power loop beside commercial proximity sensors.
    Power(cmd::daemon::PowerArgs),
    /// Claim proximity from tofproxd and print near/far transitions.
    Monitor(cmd::daemon::MonitorArgs),
    /// Print every property of a running tofproxd.
    Status(cmd::daemon::StatusArgs),
    /// Record depth frames published by tofproxd.
    Record(cmd::daemon::RecordArgs),
    /// Run the daemon loop against the emulated device with injected faults.
    Soak(cmd::daemon::SoakArgs),
    /// Run the scene catalogue through the emulated device and the daemon loop (virtual time).
    Scenes(cmd::daemon::ScenesArgs),
    /// Write the manual pages (tofprox.1, `tofprox-<command>.1`, …) into --out and exit
    /// (packaging/build-deb.sh).
    #[command(hide = true)]
    Man {
        /// Directory for the pages.
        #[arg(long, value_name = "DIR")]
        out: std::path::PathBuf,
    },
}

fn main() -> ExitCode {
    restore_default_sigpipe();
    let cli = Cli::parse();
    let filter = match cli.verbose {
        // The soak injects faults on purpose: the loop's warning for each is summarised in
        // its report (failed cycles by kind) instead of flooding stderr; `-v` shows them.
        0 if matches!(cli.command, Command::Soak(_)) => "warn,tofproxd::controller=error",
        0 => "warn",
        1 => "info",
        2 => "debug",
        _ => "trace",
    };
    tofproxd::logging::init_logging(filter);
    let result = match cli.command {
        Command::Info(a) => cmd::info::info(a),
        Command::Calibrate(a) => cmd::station::calibrate(a),
        Command::Process(a) => cmd::process::process(a),
        Command::Sim(c) => cmd::sim::run_sim(c),
        Command::Model(c) => cmd::sim::run_model(c),
        Command::Lab(c) => cmd::lab::run(c),
        Command::Device(c) => cmd::device::run(c),
        Command::Power(a) => cmd::daemon::power(a),
        Command::Monitor(a) => cmd::daemon::monitor(a),
        Command::Status(a) => cmd::daemon::status(a),
        Command::Record(a) => cmd::daemon::record(a),
        Command::Soak(a) => cmd::daemon::soak(a),
        Command::Scenes(a) => cmd::daemon::scenes(a),
        Command::Man { out } => write_man_pages(&out),
    };
    match result {
        Ok(code) => code,
        Err(err) => {
            // Every failure is reported as one clear line chain, never a panic
            // trace. Exit code 2: bad input or a failed operation (see README).
            eprintln!("error: {}", tofproxd::logging::error_line(err.as_ref()));
            ExitCode::from(2)
        }
    }
}

/// The manual pages of every (visible) command, from the clap definitions.
fn write_man_pages(out: &std::path::Path) -> anyhow::Result<ExitCode> {
    use anyhow::Context as _;
    use clap::CommandFactory as _;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    clap_mangen::generate_to(Cli::command(), out)
        .with_context(|| format!("writing the manual pages into {}", out.display()))?;
    Ok(ExitCode::SUCCESS)
}

/// `tofprox … | head` must end quietly when the reader goes away, as other
/// Unix tools do, instead of panicking on EPIPE inside `println!`: Rust
/// ignores SIGPIPE by default, so restore the default action.
fn restore_default_sigpipe() {
    // SAFETY: called once at start-up before any thread exists; SIG_DFL is a
    // valid disposition for SIGPIPE.
    #[allow(unsafe_code)]
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
