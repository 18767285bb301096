//! tofproxd: the low-power ToF proximity daemon on D-Bus (thesis 3.5.3, listing 4.11).
//!
//! `tofproxd --config FILE [--bus session|system|ADDRESS]`
//! `tofproxd --demo` — the emulated device with a scripted hand on a private bus,
//! printing near/far events for ~25 s.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, bail};
use clap::Parser;
use tofproxd::client::distance_words;
use tofproxd::config::{Config, PublisherKind};
use tofproxd::run::{BusChoice, Daemon, notify};
use tofproxd::signals::StopSignals;

/// `tofproxd --version`: whether this binary links the test machinery (the emulated device and
/// the physical model, cargo feature `emulated`) — what `packaging/build-deb.sh` refuses to ship.
#[cfg(feature = "emulated")]
const LONG_VERSION: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    " (test build: emulated device and physical model linked, feature `emulated`)"
);
#[cfg(not(feature = "emulated"))]
const LONG_VERSION: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    " (production build: usb, v4l2 and replay backends)"
);

/// The low-power ToF proximity daemon.
#[derive(Parser, Debug)]
#[command(name = "tofproxd", version, long_version = LONG_VERSION, about)]
struct Args {
    /// Configuration file.
    #[arg(long, default_value = "/etc/tofprox/tofproxd.toml")]
    config: PathBuf,
    /// session, system or a D-Bus address (unix:path=…).
    #[arg(long, default_value = "system")]
    bus: String,
    /// Demo: run on the emulated device with the scripted hand
    /// (config/tofproxd-emulated.toml of the installed data, /usr/share/tofprox, or of the
    /// source tree, unless --config is given), on the session bus or a
    /// private dbus-daemon when none runs, and print near/far events.
    #[arg(long)]
    demo: bool,
    /// Demo duration (s).
    #[arg(long, default_value_t = 25)]
    demo_seconds: u64,
    /// Run every check the start runs (config values, frame source, calibration against the
    /// sensor, ROI) without touching the bus, and exit.
    #[arg(long)]
    check_config: bool,
    /// More log output (repeat for more).
    #[arg(short, long, action = clap::ArgAction::Count)]
    verbose: u8,
    /// Write the manual page tofproxd.8 into DIR and exit (packaging/build-deb.sh).
    #[arg(long, value_name = "DIR", hide = true)]
    man: Option<PathBuf>,
}

fn main() -> ExitCode {
    // First of all, before any other thread exists: the stop signals are blocked (every
    // later thread inherits the mask) and taken by one waiting thread, so a signal at any
    // moment from here on stops the daemon cleanly, never by its default action (W6).
    let mut stop = match StopSignals::block() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: blocking the stop signals: {e}");
            return ExitCode::from(2);
        }
    };
    let args = Args::parse();
    if let Some(dir) = &args.man {
        return write_man_page(dir);
    }
    let filter = match args.verbose {
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    tofproxd::logging::init_logging(filter);
    let rt = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: tokio runtime: {e}");
            return ExitCode::from(2);
        }
    };
    match rt.block_on(run(args, &mut stop)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let line = tofproxd::logging::error_line(e.as_ref());
            eprintln!("error: {line}");
            notify::status(&format!("failed: {line}"));
            ExitCode::from(2)
        }
    }
}

/// The manual page (section 8: a system daemon): the clap definitions and `tofproxd::man`'s
/// sections (configuration keys, D-Bus interface, files, signals, exit status, see also).
fn write_man_page(dir: &Path) -> ExitCode {
    use clap::CommandFactory as _;
    let path = dir.join("tofproxd.8");
    let written = std::fs::create_dir_all(dir)
        .and_then(|()| tofproxd::man::render(Args::command()))
        .and_then(|page| std::fs::write(&path, page));
    match written {
        Ok(()) => {
            println!("{}", path.display());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: writing the manual page into {}: {e}", dir.display());
            ExitCode::from(2)
        }
    }
}

async fn run(mut args: Args, stop: &mut StopSignals) -> anyhow::Result<()> {
    if args.demo && args.config == Path::new("/etc/tofprox/tofproxd.toml") {
        args.config = demo_config_path()?;
    }
    if !args.demo && args.config == Path::new("/etc/tofprox/tofproxd.toml") && !args.config.exists()
    {
        bail!(
            "no configuration at /etc/tofprox/tofproxd.toml: pass --config FILE \
             (tofproxd-emulated.toml in /usr/share/tofprox/config or the source tree's config/ \
             runs the emulated sensor), or try `tofproxd --demo`"
        );
    }
    let cfg = Config::load(&args.config)?;
    let base = args.config.parent().unwrap_or(Path::new(".")).to_path_buf();
    if args.check_config {
        // every check the start runs (source, calibration vs the sensor, controller)
        tofproxd::run::prepare(&cfg, &base)
            .with_context(|| format!("{}", args.config.display()))?;
        println!("{}: ok", args.config.display());
        return Ok(());
    }
    if args.demo {
        return demo(cfg, &base, args.demo_seconds, stop).await;
    }
    let bus: BusChoice = args.bus.parse().map_err(anyhow::Error::msg)?;
    serve(cfg, &base, bus, stop).await
}

/// The demo configuration from the installed data or the source tree (`tofproxd::data`).
fn demo_config_path() -> anyhow::Result<PathBuf> {
    tofproxd::data::find("config/tofproxd-emulated.toml")
        .context("the demo configuration: pass --config FILE")
}

async fn build_daemon(cfg: &Config, base: &Path, conn: zbus::Connection) -> anyhow::Result<Daemon> {
    let ctl = tofproxd::run::prepare(cfg, base)?;
    Ok(Daemon::start(conn, cfg, ctl).await?)
}

async fn serve(
    cfg: Config,
    base: &Path,
    bus: BusChoice,
    stop: &mut StopSignals,
) -> anyhow::Result<()> {
    let start = async {
        if cfg.publisher == PublisherKind::Socket {
            // no D-Bus at all: no bus connection is attempted
            let ctl = tofproxd::run::prepare(&cfg, base)?;
            let daemon = Daemon::start_without_bus(&cfg, ctl).await?;
            tracing::info!("serving on {} (no D-Bus)", cfg.socket.path.display());
            anyhow::Ok(daemon)
        } else {
            let conn = tofproxd::run::connect(&bus).await?;
            let daemon = build_daemon(&cfg, base, conn).await?;
            tracing::info!(
                "serving {} on the {:?} bus (compat: {})",
                tofproxd::service::BUS_NAME,
                bus,
                cfg.dbus.iio_sensor_proxy_compat
            );
            Ok(daemon)
        }
    };
    // a stop signal while starting (a bus that does not answer) ends the start, cleanly
    let daemon = tokio::select! {
        d = start => d?,
        name = stop.recv() => {
            tracing::info!("{name} received while starting: not started");
            return Ok(());
        }
    };
    notify::ready("idle: sensor in reset, waiting for a claim");
    let watchdog = notify::watchdog_interval().map(|d| d / 2);
    let mut last_state = String::new();
    loop {
        let tick = async {
            match watchdog {
                Some(d) => tokio::time::sleep(d).await,
                None => std::future::pending::<()>().await,
            }
        };
        tokio::select! {
            name = stop.recv() => {
                tracing::info!("{name} received");
                break;
            }
            _ = tick => {
                // Feed the watchdog only while the loop thread is not stuck in one cycle.
                if daemon.loop_healthy(watchdog.unwrap_or(Duration::from_secs(15))) {
                    notify::watchdog();
                } else {
                    tracing::error!("loop thread stuck in a cycle: not feeding the watchdog");
                }
                let s = daemon.hub().status();
                let line = format!("{}; near={}; {:.2} mW", s.state.as_str(), s.near, s.power_mw);
                if line != last_state {
                    notify::status(&line);
                    last_state = line;
                }
            }
        }
    }
    tracing::info!("stopping: sensor to reset, releasing the bus names");
    notify::stopping();
    daemon.shutdown().await;
    Ok(())
}

/// A private dbus-daemon for the demo, listening in a directory of its own;
/// on drop the daemon is killed and the directory with its socket removed
/// (no stale socket files left behind).
struct PrivateBus {
    child: std::process::Child,
    address: String,
    dir: PathBuf,
}

impl Drop for PrivateBus {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn start_private_bus() -> anyhow::Result<PrivateBus> {
    use std::io::BufRead;
    use std::os::unix::fs::DirBuilderExt;
    let dir = std::env::temp_dir().join(format!("tofproxd-demo-bus-{}", std::process::id()));
    // a leftover of an earlier process of the same id goes (a link as a name, never followed)
    let _ = std::fs::remove_dir_all(&dir).or_else(|_| std::fs::remove_file(&dir));
    std::fs::DirBuilder::new()
        .mode(0o700)
        .create(&dir)
        .with_context(|| format!("creating {} for the private bus socket", dir.display()))?;
    let mut child = std::process::Command::new("dbus-daemon")
        .args(["--session", "--print-address", "--nofork"])
        .arg(format!("--address=unix:path={}", dir.join("bus").display()))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .context("starting dbus-daemon (install the dbus-daemon package)")?;
    let stdout = child.stdout.take().context("dbus-daemon stdout")?;
    let mut line = String::new();
    std::io::BufReader::new(stdout)
        .read_line(&mut line)
        .context("reading the bus address")?;
    let address = line.trim().to_string();
    if address.is_empty() {
        let _ = child.kill();
        let _ = child.wait();
        let _ = std::fs::remove_dir_all(&dir);
        bail!("dbus-daemon printed no address");
    }
    Ok(PrivateBus {
        child,
        address,
        dir,
    })
}

/// The demo's bus: the session bus, or a private dbus-daemon when none runs (kept in
/// `private`, so that it ends with the demo however the demo ends).
async fn demo_bus(
    private: &mut Option<PrivateBus>,
) -> anyhow::Result<(zbus::Connection, BusChoice)> {
    if let Ok(c) = tofproxd::run::connect(&BusChoice::Session).await {
        eprintln!("demo: using the session bus");
        return Ok((c, BusChoice::Session));
    }
    let pb = private.insert(start_private_bus()?);
    eprintln!(
        "demo: no session bus; started a private dbus-daemon at {}",
        pb.address
    );
    let bus = BusChoice::Address(pb.address.clone());
    Ok((tofproxd::run::connect(&bus).await?, bus))
}

async fn demo(
    cfg: Config,
    base: &Path,
    seconds: u64,
    stop: &mut StopSignals,
) -> anyhow::Result<()> {
    use tofproxd::client::ProximityProxy;
    // dropped last, on every way out of this function: the private bus and its directory go
    let mut private: Option<PrivateBus> = None;
    let start = async {
        let (conn, bus) = demo_bus(&mut private).await?;
        let daemon = build_daemon(&cfg, base, conn).await?;
        // An independent client connection, like `tofprox monitor`.
        let client = tofproxd::run::connect(&bus).await?;
        let proxy = ProximityProxy::new(&client).await?;
        let near_changes = proxy.receive_near_changed().await;
        anyhow::Ok((daemon, client, proxy, near_changes))
    };
    let (daemon, _client, proxy, mut near_changes) = tokio::select! {
        r = start => r?,
        name = stop.recv() => {
            eprintln!("demo: {name} received while starting: stopped");
            return Ok(());
        }
    };
    let t0 = std::time::Instant::now();
    eprintln!(
        "demo: emulated sensor, hand approaching and leaving in front of a wall; near ≤ {} mm, far ≥ {} mm",
        cfg.proximity.near_mm, cfg.proximity.far_mm
    );
    eprintln!(
        "demo: {} processing, calibration {}",
        cfg.processing.mode.as_str(),
        cfg.processing.calibration.as_deref().map_or_else(
            || "none".to_string(),
            |p| std::fs::canonicalize(p)
                .unwrap_or_else(|_| p.to_path_buf())
                .display()
                .to_string()
        )
    );
    let average_mw = match demo_events(&proxy, &mut near_changes, t0, seconds, stop).await {
        Ok(run) => run.average_mw(),
        Err(e) => {
            daemon.shutdown().await;
            return Err(e);
        }
    };
    let _ = proxy.release_proximity().await;
    let s = daemon.hub().status();
    println!(
        "demo: {} cycles, {} valid readings, {} errors, modelled power {} over the run \
         (GetStatus EnergyMj over the run's time)",
        s.cycles,
        s.valid_readings,
        s.errors,
        average_mw.map_or_else(|| "not measured".to_string(), |p| format!("{p:.2} mW"))
    );
    daemon.shutdown().await;
    drop(private);
    Ok(())
}

/// The demo's run as the daemon's energy meter saw it: `GetStatus()["EnergyMj"]` (the
/// modelled energy since start) at the claim and at the end, and the wall time between.
struct EnergyRun {
    start_mj: f64,
    end_mj: f64,
    seconds: f64,
}

impl EnergyRun {
    /// The run's exact average modelled power (mJ / s = mW); `None` for a run of no time or
    /// without the key.
    fn average_mw(&self) -> Option<f64> {
        let mw = (self.end_mj - self.start_mj) / self.seconds;
        (self.seconds > 0.0 && mw.is_finite()).then_some(mw)
    }
}

/// `GetStatus()["EnergyMj"]` (NaN when the daemon does not say).
async fn energy_mj(proxy: &tofproxd::client::ProximityProxy<'_>) -> f64 {
    proxy
        .get_status()
        .await
        .ok()
        .and_then(|m| m.get(tofproxd::service::ENERGY_MJ_KEY).cloned())
        .and_then(|v| f64::try_from(v).ok())
        .unwrap_or(f64::NAN)
}

/// Claim, then print near/far changes until the deadline or a stop signal: the run's energy.
async fn demo_events(
    proxy: &tofproxd::client::ProximityProxy<'_>,
    near_changes: &mut zbus::proxy::PropertyStream<'_, bool>,
    t0: std::time::Instant,
    seconds: u64,
    stop: &mut StopSignals,
) -> anyhow::Result<EnergyRun> {
    proxy.claim_proximity().await?;
    let (claimed, start_mj) = (std::time::Instant::now(), energy_mj(proxy).await);
    let near = proxy.near().await?;
    println!(
        "{:7.2}s  claimed: near={near} {} state={}",
        t0.elapsed().as_secs_f64(),
        distance_words(proxy.distance_mm().await?, near),
        proxy.state().await?
    );
    let deadline = tokio::time::Instant::now() + Duration::from_secs(seconds);
    let end = |end_mj| EnergyRun {
        start_mj,
        end_mj,
        seconds: claimed.elapsed().as_secs_f64(),
    };
    loop {
        tokio::select! {
            _ = tokio::time::sleep_until(deadline) => return Ok(end(energy_mj(proxy).await)),
            name = stop.recv() => {
                eprintln!("demo: {name} received: stopping");
                return Ok(end(energy_mj(proxy).await));
            }
            ch = tofproxd::service::next_item(near_changes) => {
                let Some(ch) = ch else { return Ok(end(energy_mj(proxy).await)) };
                let near = ch.get().await.unwrap_or(false);
                let d = distance_words(proxy.distance_mm().await.unwrap_or(0), near);
                let p = proxy.power_estimate_mw().await.unwrap_or(0.0);
                let rate = proxy.rate_hz().await.unwrap_or(0.0);
                let why = proxy.reason().await.unwrap_or_default();
                println!(
                    "{:7.2}s  {}  {d}  rate={rate:.1} Hz  power≈{p:.2} mW  ({why})",
                    t0.elapsed().as_secs_f64(),
                    if near { "NEAR" } else { "far " }
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_demo_averages_its_own_run_from_the_energy_total() {
        // 300 mJ over a minute is 5 mW, whatever the cycles did within it
        let run = EnergyRun {
            start_mj: 100.0,
            end_mj: 400.0,
            seconds: 60.0,
        };
        assert_eq!(run.average_mw(), Some(5.0));
        // no time, or a daemon that did not say: no average
        assert_eq!(
            EnergyRun {
                seconds: 0.0,
                ..run
            }
            .average_mw(),
            None
        );
        assert_eq!(
            EnergyRun {
                end_mj: f64::NAN,
                ..run
            }
            .average_mw(),
            None
        );
    }
}
