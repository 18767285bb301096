//! `tofprox calibrate station`: the production line's calibration station, a thin adapter
//! over `tofprox_station` (`docs/calibration.md`, "Production line"). `tofprox calibrate
//! KIND REC --out CALIB` (one part from a recording) is parsed beside it.

use std::io::BufRead as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::Context as _;
use tofprox_bridge::{
    Clock, DeviceConfigFile, DriverConfig, EmulatedConfig, RusbTransport, SensorDriver,
    SystemClock, UsbSelector, VirtualClock,
};
use tofprox_station::{
    EmulatedFixture, Fixture, Line, OperatorFixture, Report, Station, StationError, run_station,
};

use super::calibrate::CalibrateArgs;

/// `tofprox calibrate`: one part from a recording, or the line's station.
#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct CalibrateCli {
    /// The production line's station.
    #[command(subcommand)]
    pub station: Option<CalibrateCommand>,
    /// One part from a recording.
    #[command(flatten)]
    pub extract: Option<CalibrateArgs>,
}

/// `tofprox calibrate station`.
#[derive(clap::Subcommand, Debug)]
pub enum CalibrateCommand {
    /// Calibrate a module on the production line: dark (FPN), crosstalk (phone line), 24-phase
    /// correlation of a flat wall (wiggling, amplitude), 4-phase wall (FPPN), pass/fail limits,
    /// a check target; writes DIR/calib, DIR/recordings, DIR/report.json and DIR/report.html.
    /// Exit 0: pass; 1: a part failed its limits (named); 2: the station could not run.
    Station(StationArgs),
}

/// `tofprox calibrate station --line module|phone --station STATION.toml --out DIR`
#[derive(clap::Args, Debug)]
pub struct StationArgs {
    /// The production line (the phone line adds the cover-window crosstalk).
    #[arg(long, value_parser = parse_line, value_name = "module|phone")]
    pub line: Line,
    /// The station file: targets, distances, exposures, limits (config/station/*.toml).
    #[arg(long)]
    pub station: PathBuf,
    /// Output directory (must not hold a station's set yet).
    #[arg(long)]
    pub out: PathBuf,
    /// Use the emulated module (its scene is each target in turn; virtual clock).
    #[arg(long)]
    pub emulated: bool,
    /// Device file: with --emulated an emulated-device file (config/emulated/*.toml, the
    /// model, cover window, faults); otherwise the USB device file (config/sensor/device.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Seed of the emulated module (its fixed patterns and noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Read out only rows `FIRST,COUNT` (overrides the station file's module.rows).
    #[arg(long = "rows", value_name = "FIRST,COUNT")]
    pub rows: Option<String>,
}

fn parse_line(s: &str) -> Result<Line, String> {
    s.parse()
}

/// `tofprox calibrate …`
pub fn calibrate(c: CalibrateCli) -> anyhow::Result<ExitCode> {
    match (c.station, c.extract) {
        (Some(CalibrateCommand::Station(a)), _) => station(a),
        (None, Some(a)) => super::calibrate::calibrate(a),
        (None, None) => {
            anyhow::bail!("tofprox calibrate: give a part and a recording, or `station`")
        }
    }
}

fn station(a: StationArgs) -> anyhow::Result<ExitCode> {
    let mut st = Station::load(&a.station)?;
    if let Some(rows) = &a.rows {
        let (first, count) = rows
            .split_once(',')
            .and_then(|(f, c)| Some((f.trim().parse().ok()?, c.trim().parse().ok()?)))
            .with_context(|| format!("--rows {rows:?}: expected FIRST,COUNT"))?;
        st.module.rows = Some([first, count]);
        st.validate(&a.station)?;
    }
    let report = if a.emulated {
        let cfg = match &a.config {
            Some(p) => EmulatedConfig::load(p)?,
            None => EmulatedConfig::default(),
        };
        let mut f = EmulatedFixture::new(cfg, a.seed, Arc::new(VirtualClock::new()));
        run(&st, &a, &mut f)?
    } else {
        let (sel, drv) = match &a.config {
            Some(p) => {
                let (f, d) = DeviceConfigFile::load(p)?;
                (f.usb, d)
            }
            None => (UsbSelector::default(), DriverConfig::emulated_default()),
        };
        let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
        let driver = SensorDriver::new(RusbTransport::open(sel)?, drv, clock.clone())?;
        let mut f = OperatorFixture::new(driver, clock, Default::default(), operator_prompt);
        run(&st, &a, &mut f)?
    };
    print_report(&report, &a);
    if report.passed {
        Ok(ExitCode::SUCCESS)
    } else {
        let failed = report.failed_parts();
        if report.complete {
            eprintln!("error: the module failed: {}", failed.join(", "));
        } else {
            eprintln!(
                "error: the set is not complete; failed: {}",
                failed.join(", ")
            );
        }
        Ok(ExitCode::from(1))
    }
}

fn run<F: Fixture>(st: &Station, a: &StationArgs, f: &mut F) -> anyhow::Result<Report> {
    Ok(run_station(st, a.line, &a.station, f, &a.out)?)
}

/// The operator is told each placement on stderr and confirms with Enter.
fn operator_prompt(what: &str) -> Result<(), StationError> {
    eprintln!("station: {what}, then press Enter");
    let mut line = String::new();
    std::io::stdin()
        .lock()
        .read_line(&mut line)
        .map(|_| ())
        .map_err(|source| StationError::Io {
            path: PathBuf::from("<stdin>"),
            source,
        })
}

fn print_report(r: &Report, a: &StationArgs) {
    println!("station {} line: {}", r.line, r.station);
    println!("module  {}", r.module);
    for c in &r.checks {
        let limit = match (c.min, c.max) {
            (Some(lo), Some(hi)) => format!("{lo} .. {hi}"),
            (None, Some(hi)) => format!("≤ {hi}"),
            (Some(lo), None) => format!("≥ {lo}"),
            (None, None) => "-".into(),
        };
        println!(
            "  {:<5} {:<16} {:<30} {:>10.4} {:<10} limit {limit}",
            if c.passed { "pass" } else { "FAIL" },
            c.part,
            c.figure,
            c.value,
            c.unit,
        );
    }
    for s in &r.steps {
        println!(
            "  step {:<10} {:>3} × {} µs  device {:.3} s  wall {:.2} s",
            s.step, s.frames, s.exposure_us, s.device_s, s.wall_s
        );
    }
    println!(
        "set {} (complete: {}); time {:.3} s device, {:.2} s wall",
        r.set.display(),
        if r.complete { "yes" } else { "no" },
        r.device_s,
        r.wall_s
    );
    println!(
        "report {}/{} and {}/{}",
        a.out.display(),
        tofprox_station::REPORT_JSON,
        a.out.display(),
        tofprox_station::REPORT_HTML
    );
    println!("{}", if r.passed { "PASS" } else { "FAIL" });
}
