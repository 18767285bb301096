//! Daemon clients and tools: `power`, `monitor`, `status`, `record`, `soak` (issue: tofproxd).
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use tofproxd::client::ProximityProxy;
use tofproxd::config::{Config, Mode};
use tofproxd::energy::{CycleEnergy, Nominal, TABLE_2_1, modelled_average_mw, modelled_reading};
use tofproxd::run::BusChoice;
use tofproxd::service::next_item;

use super::live;

fn parse_bus(s: &str) -> Result<BusChoice, String> {
    s.parse()
}

#[derive(clap::Args, Debug)]
pub struct PowerArgs {
    /// Daemon configuration (default: /etc/tofprox/tofproxd.toml if present, else the defaults).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override the mode (2phase, 4phase).
    #[arg(long)]
    mode: Option<String>,
    /// Override the reading rate (Hz).
    #[arg(long)]
    rate_hz: Option<f64>,
    /// Override the exposure per raw image (µs).
    #[arg(long)]
    exposure_us: Option<f64>,
    /// JSON on stdout.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args, Debug)]
pub struct MonitorArgs {
    /// session, system or a D-Bus address.
    #[arg(long, default_value = "system", value_parser = parse_bus)]
    bus: BusChoice,
    /// Also claim depth frames and show a live preview below the status lines
    /// (on a terminal; the terminal is restored on exit).
    #[arg(long)]
    depth: bool,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    seconds: Option<u64>,
    /// JSON Lines on stdout: one object per line (not one JSON document), for the first
    /// reading and each near/far change: {"t_s", "event": "first_reading"|"near_changed", "reason" (the rule that decided it),
    /// "near", "distance_mm" (null when not a distance), "distance" (in words), "state"}.
    #[arg(long, conflicts_with = "depth")]
    json: bool,
}

#[derive(clap::Args, Debug)]
pub struct StatusArgs {
    /// session, system or a D-Bus address.
    #[arg(long, default_value = "system", value_parser = parse_bus)]
    bus: BusChoice,
    /// JSON on stdout.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args, Debug)]
pub struct RecordArgs {
    /// Output recording directory for the daemon's DepthFrame signals.
    #[arg(long, alias = "from-daemon", value_name = "REC")]
    out: PathBuf,
    /// Replace the recording already in `--out`.
    #[arg(long)]
    force: bool,
    /// session, system or a D-Bus address.
    #[arg(long, default_value = "system", value_parser = parse_bus)]
    bus: BusChoice,
    /// Number of frames to record.
    #[arg(long, default_value_t = 50)]
    frames: usize,
    /// Give up after this many seconds.
    #[arg(long, default_value_t = 120)]
    timeout_s: u64,
}

#[derive(clap::Args, Debug)]
pub struct SoakArgs {
    /// Cycles to run.
    #[arg(long, default_value_t = 10_000)]
    cycles: u64,
    /// Share of cycles with an injected fault (0..=1).
    #[arg(long, default_value_t = 0.05)]
    fault_rate: f64,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// JSON on stdout.
    #[arg(long)]
    json: bool,
}

/// `tofprox scenes`
#[derive(Debug, clap::Args)]
pub struct ScenesArgs {
    /// Daemon configuration (default: the shipped defaults with the emulated backend).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Calibration set of the emulated sensor (default: calib/phone of the installed data,
    /// /usr/share/tofprox, or of the source tree, when it exists).
    #[arg(long)]
    calib: Option<PathBuf>,
    /// Model file of the emulated sensor, the phone sensor behind its cover window (default:
    /// config/model/phone.toml of the installed data or of the source tree).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Only scenes whose name contains this.
    #[arg(long)]
    only: Option<String>,
    /// Seed of the emulated sensor (its fixed patterns must match the calibration).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// JSON on stdout.
    #[arg(long)]
    json: bool,
}

fn load_config(path: Option<&PathBuf>) -> anyhow::Result<Config> {
    match path {
        Some(p) => Ok(Config::load(p)?),
        None => {
            let p = PathBuf::from("/etc/tofprox/tofproxd.toml");
            if p.exists() {
                Ok(Config::load(&p)?)
            } else {
                Ok(Config::default())
            }
        }
    }
}

pub fn power(a: PowerArgs) -> anyhow::Result<ExitCode> {
    let cfg = load_config(a.config.as_ref())?;
    let mode = match a.mode.as_deref() {
        None => cfg.processing.mode,
        Some("2phase") => Mode::TwoPhase,
        Some("4phase") => Mode::FourPhase,
        Some(m) => bail!("--mode: expected 2phase or 4phase, got {m:?}"),
    };
    let rate = a.rate_hz.unwrap_or(cfg.loop_.rate_hz);
    let exposure = a.exposure_us.unwrap_or(cfg.exposure.initial_us);
    if !(rate.is_finite() && rate > 0.0 && rate <= 100.0) {
        bail!("--rate-hz must be within (0, 100], got {rate}");
    }
    if !(exposure.is_finite() && exposure > 0.0 && exposure <= 10_000.0) {
        bail!("--exposure-us must be within (0, 10000], got {exposure}");
    }
    // a reading reads every `readout.row_step`-th row where the sequencer skips rows (the
    // daemon's `read_step`), the probe every `probe.row_step`-th
    let (reading_step, probe_step) = row_steps(&cfg);
    let nominal = Nominal {
        readout_fraction: shipped_readout_fraction(&cfg, reading_step),
        ..Nominal::default()
    };
    let k = mode.raw_images() as u32;
    let (full, _) = modelled_reading(&cfg.energy, &nominal, k, exposure);
    let probe_nominal = Nominal {
        readout_fraction: shipped_readout_fraction(&cfg, probe_step),
        ..nominal
    };
    let (probe, _) = modelled_reading(&cfg.energy, &probe_nominal, 1, cfg.exposure.min_us);
    let low = modelled_average_mw(&cfg.energy, &nominal, k, exposure, rate, true);
    let powered = modelled_average_mw(&cfg.energy, &nominal, k, exposure, rate, false);
    let slow = modelled_average_mw(
        &cfg.energy,
        &nominal,
        k,
        exposure,
        cfg.loop_.slow_rate_hz,
        true,
    );
    let fast = modelled_average_mw(
        &cfg.energy,
        &nominal,
        k,
        exposure,
        cfg.loop_.fast_rate_hz,
        true,
    );
    let per_reading_mj = low / rate;
    if a.json {
        let refs: Vec<_> = TABLE_2_1
            .iter()
            .map(|r| {
                serde_json::json!({"model": r.model, "power_mw": r.power_mw, "period_ms": r.period_ms,
                "energy_per_reading_mj": r.energy_per_reading_mj(), "range_m": r.range_m})
            })
            .collect();
        let v = serde_json::json!({
            "mode": mode.as_str(), "rate_hz": rate, "exposure_us": exposure,
            "average_mw": low, "energy_per_reading_mj": per_reading_mj,
            "powered_idle_average_mw": powered,
            "slow_rate_hz": cfg.loop_.slow_rate_hz, "slow_average_mw": slow,
            "fast_rate_hz": cfg.loop_.fast_rate_hz, "fast_average_mw": fast,
            "reading_parts_mj": parts_json(&full), "probe_parts_mj": parts_json(&probe),
            "readout_fraction": nominal.readout_fraction, "reading_row_step": reading_step,
            "probe_row_step": probe_step, "probe_readout_fraction": probe_nominal.readout_fraction,
            "table_2_1": refs,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(ExitCode::SUCCESS);
    }
    println!(
        "tofprox low-power loop (thesis 3.5.3): {} ({} raw images), {:.0} µs exposure, {:.2} Hz",
        mode.as_str(),
        k,
        exposure,
        rate
    );
    println!(
        "  modelled average    {low:8.3} mW   ({per_reading_mj:.3} mJ per reading; sensor in reset between readings)"
    );
    println!(
        "  sensor left powered {powered:8.3} mW   (table 3.1's setting: idle between readings)"
    );
    println!(
        "  adaptive range      {slow:8.3} mW at {:.2} Hz (far, still) … {fast:.3} mW at {:.2} Hz (approach/near)",
        cfg.loop_.slow_rate_hz, cfg.loop_.fast_rate_hz
    );
    println!(
        "  one reading         {:.3} mJ: {} ({} of the window)",
        full.total_mj(),
        parts_line(&full),
        rows_read(reading_step)
    );
    println!(
        "  one presence probe  {:.3} mJ: {} (1 raw image at {:.0} µs, {} of the window, while far and still)",
        probe.total_mj(),
        parts_line(&probe),
        cfg.exposure.min_us,
        rows_read(probe_step)
    );
    println!(
        "  assumptions: start-up {:.1} ms at {} mW + bring-up {:.1} ms at {} mW, flash load {:.1} ms at {} mW, read-out {:.1} ms/image of {:.0} % of the pixels, CPU {:.2} ms at {} mW, reset {} mW",
        nominal.startup_ms,
        cfg.energy.startup_mw,
        nominal.bring_up_ms,
        cfg.energy.bring_up_mw,
        nominal.flash_load_ms,
        cfg.energy.flash_load_mw,
        nominal.readout_ms_per_image,
        nominal.readout_fraction * 100.0,
        nominal.cpu_ms,
        cfg.energy.cpu_mw_per_core,
        cfg.energy.off_mw
    );
    println!();
    println!("commercial proximity sensors (thesis table 2.1):");
    println!(
        "  {:<22} {:>10} {:>11} {:>16} {:>9}",
        "model", "power mW", "period ms", "mJ per reading", "range m"
    );
    for r in TABLE_2_1 {
        println!(
            "  {:<22} {:>10.3} {:>11.2} {:>16.4} {:>9.2}",
            r.model,
            r.power_mw,
            r.period_ms,
            r.energy_per_reading_mj(),
            r.range_m
        );
    }
    println!(
        "  {:<22} {:>10.3} {:>11.2} {:>16.4} {:>9.2}",
        "tofprox (modelled)",
        low,
        1e3 / rate,
        per_reading_mj,
        1.87
    );
    Ok(ExitCode::SUCCESS)
}

/// Share of the array's pixels read on the shipped (emulated IRS1645-class) sensor map when
/// every `step`-th row of the shipped ROI's read-out window is read: the ROI's rows ±
/// `readout.margin_rows` and, where the map reads a column window, its columns ±
/// `readout.margin_cols`, aligned as the map requires (the daemon's `ReadoutWindow`).
fn shipped_readout_fraction(cfg: &Config, step: u16) -> f64 {
    let (reading_step, _) = row_steps(cfg);
    use tofproxd::policy::{ReadoutObservation, ReadoutWindow};
    let map = tofprox_bridge::SensorMap::emulated();
    let (rows, cols) = (usize::from(map.sensor.rows), usize::from(map.sensor.cols));
    let window = map.row_window.as_ref();
    let w = ReadoutWindow::new(cfg.readout.clone()).next(ReadoutObservation {
        full_rows: rows,
        roi: tofproxd::controller::full_roi(cfg, rows, cols),
        source_supports: window.is_some(),
        align_rows: window.map_or(1, |w| w.align),
        full_cols: cols,
        align_cols: window.and_then(|w| w.column_registers().map(|_| w.col_align.max(1))),
        row_step: reading_step,
    });
    let read = |n: usize| n.div_ceil(usize::from(step.max(1)));
    match w {
        Some(w) => {
            let (_, n) = w.columns(cols);
            (read(usize::from(w.rows)) * n) as f64 / (rows * cols) as f64
        }
        None => read(rows) as f64 / rows as f64,
    }
}

/// The row steps `(reading, probe)` on the emulated sensor at `cfg`, as the daemon reads
/// ([`Config::row_steps`] with the map's row window and how far its sequencer skips rows).
fn row_steps(cfg: &Config) -> (u16, u16) {
    let map = tofprox_bridge::SensorMap::emulated();
    let window = map.row_window.as_ref();
    cfg.row_steps(
        window.is_some(),
        window.map_or(1, |w| w.row_step_max()),
        usize::from(map.sensor.rows),
    )
}

/// "every row", "every 2nd row", "every 4th row", …
fn rows_read(step: u16) -> String {
    let suffix = match (step % 10, step % 100) {
        (1, r) if r != 11 => "st",
        (2, r) if r != 12 => "nd",
        (3, r) if r != 13 => "rd",
        _ => "th",
    };
    match step {
        1 => "every row".to_string(),
        _ => format!("every {step}{suffix} row"),
    }
}

fn parts_line(e: &CycleEnergy) -> String {
    format!(
        "start-up {:.3} + flash {:.3} + capture {:.3} + read-out {:.3} + CPU {:.3}",
        e.startup_mj, e.flash_mj, e.capture_mj, e.readout_mj, e.cpu_mj
    )
}

fn parts_json(e: &CycleEnergy) -> serde_json::Value {
    serde_json::json!({"startup": e.startup_mj, "flash": e.flash_mj, "capture": e.capture_mj,
        "readout": e.readout_mj, "cpu": e.cpu_mj, "total": e.total_mj()})
}

fn rt() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("tokio runtime")
}

/// Connect and wait up to 5 s for tofproxd's name on the bus (a daemon
/// started just before, `tofproxd … &`, may not own it yet).
async fn proxy(bus: &BusChoice) -> anyhow::Result<(zbus::Connection, ProximityProxy<'static>)> {
    let conn = tofproxd::run::connect(bus).await?;
    let dbus = zbus::fdo::DBusProxy::new(&conn)
        .await
        .context("org.freedesktop.DBus proxy")?;
    let name = zbus::names::BusName::try_from(tofproxd::service::BUS_NAME)?;
    let until = tokio::time::Instant::now() + Duration::from_secs(5);
    let mut said = false;
    while !dbus.name_has_owner(name.clone()).await.unwrap_or(false) {
        if tokio::time::Instant::now() >= until {
            anyhow::bail!(
                "tofproxd is not running on this bus ({} has no owner); start it with `tofproxd --config FILE --bus session|system`",
                tofproxd::service::BUS_NAME
            );
        }
        if !said {
            eprintln!("waiting for tofproxd to appear on the bus …");
            said = true;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let p = ProximityProxy::new(&conn)
        .await
        .context("org.tofprox.Proximity1 proxy")?;
    Ok((conn, p))
}

/// The terminal size of stdout (columns, rows), if it is a terminal.
#[allow(unsafe_code)] // the TIOCGWINSZ ioctl; nothing else
fn terminal_size() -> Option<(usize, usize)> {
    use std::io::IsTerminal as _;
    if !std::io::stdout().is_terminal() {
        return None;
    }
    // SAFETY: `winsize` is plain old data; all-zero is a valid value.
    let mut ws: libc::winsize = unsafe { std::mem::zeroed() };
    // SAFETY: TIOCGWINSZ writes one `winsize` into the struct we pass; fd 1 is open.
    let ok = unsafe { libc::ioctl(1, libc::TIOCGWINSZ, &mut ws) } == 0;
    (ok && ws.ws_col > 0 && ws.ws_row > 0)
        .then(|| (usize::from(ws.ws_col), usize::from(ws.ws_row)))
        .or(Some((80, 24)))
}

/// The live view on the alternate screen; leaving it (also on an error
/// return) restores the terminal and prints the events on the normal screen.
struct Screen {
    view: live::LiveView,
}

impl Screen {
    fn draw(&self, frame: Option<(usize, usize, &[u16])>) {
        use std::io::Write as _;
        let (c, r) = terminal_size().unwrap_or((80, 24));
        let mut out = std::io::stdout().lock();
        let _ = out.write_all(self.view.screen(frame, c, r).as_bytes());
        let _ = out.flush();
    }
}

impl Drop for Screen {
    fn drop(&mut self) {
        use std::io::Write as _;
        let mut out = std::io::stdout().lock();
        let _ = out.write_all(live::LEAVE.as_bytes());
        for e in self.view.events() {
            let _ = writeln!(out, "{e}");
        }
        let _ = out.flush();
    }
}

/// Where the monitor's readings go: lines of text, JSON Lines, or the live view.
enum MonitorOut {
    Text,
    Json,
    Live(Screen),
}

/// The monitor's view of the daemon: readings since the claim, the latest depth frame.
struct Monitor {
    out: MonitorOut,
    t0: Instant,
    /// `ValidReadings` before the claim: a larger count is a reading made for us.
    readings_before: u64,
    waiting: bool,
    /// Near as last shown (a property stream also yields the unchanged value).
    last_near: Option<bool>,
    last_frame: Option<(usize, usize, Vec<u16>)>,
}

/// A kept frame as the live view draws it.
fn frame_ref(f: &Option<(usize, usize, Vec<u16>)>) -> Option<(usize, usize, &[u16])> {
    f.as_ref().map(|(w, h, d)| (*w, *h, d.as_slice()))
}

impl Monitor {
    /// Show a reading (`event`: first_reading, near_changed) with the daemon's current
    /// distance and state.
    async fn show(&mut self, p: &ProximityProxy<'_>, event: &str, near: bool) {
        self.waiting = false;
        self.last_near = Some(near);
        let d = p.distance_mm().await.unwrap_or(0);
        let state = p.state().await.unwrap_or_default();
        let reason = p.reason().await.unwrap_or_default();
        let t_s = self.t0.elapsed().as_secs_f64();
        match &mut self.out {
            MonitorOut::Json => {
                println!("{}", live::event_json(t_s, event, near, d, &state, &reason))
            }
            MonitorOut::Text => println!("{}", live::event_line(t_s, near, d, &state)),
            MonitorOut::Live(s) => {
                s.view
                    .set_distance(tofproxd::client::distance_words(d, near));
                s.view.push_event(live::event_line(t_s, near, d, &state));
                s.draw(frame_ref(&self.last_frame));
            }
        }
    }

    /// A `Near` value from the property stream: shown when it changed since the last reading
    /// shown (before the first reading: taken as the sign to look for it).
    async fn near_value(&mut self, p: &ProximityProxy<'_>, near: bool) {
        if self.waiting {
            self.poll_first_reading(p).await;
        } else if self.last_near != Some(near) {
            self.show(p, "near_changed", near).await;
        }
    }

    /// While waiting: has the first reading since the claim been made? Then show it.
    async fn poll_first_reading(&mut self, p: &ProximityProxy<'_>) {
        if valid_readings(p).await > self.readings_before {
            let near = p.near().await.unwrap_or(false);
            self.show(p, "first_reading", near).await;
        }
    }

    /// A depth frame: kept for the preview, drawn with the current distance.
    async fn depth_frame(&mut self, p: &ProximityProxy<'_>, w: usize, h: usize, d: Vec<u16>) {
        self.last_frame = Some((w, h, d));
        if let MonitorOut::Live(s) = &mut self.out {
            if !self.waiting {
                let (d, near) = (
                    p.distance_mm().await.unwrap_or(0),
                    p.near().await.unwrap_or(false),
                );
                s.view
                    .set_distance(tofproxd::client::distance_words(d, near));
            }
            s.draw(frame_ref(&self.last_frame));
        }
    }
}

/// `ValidReadings` of the daemon (0 when it cannot be read).
async fn valid_readings(p: &ProximityProxy<'_>) -> u64 {
    let Ok(s) = p.get_status().await else {
        return 0;
    };
    s.get("ValidReadings")
        .and_then(|v| u64::try_from(v).ok())
        .unwrap_or(0)
}

/// The monitor's output for `a`: the live view on a terminal with `--depth`, else text or
/// JSON Lines (notes on stderr).
fn monitor_out(a: &MonitorArgs, near_mm: u32, far_mm: u32) -> MonitorOut {
    if a.depth && terminal_size().is_some() {
        print!("{}", live::ENTER);
        let s = Screen {
            view: live::LiveView::new(near_mm, far_mm, 1500),
        };
        s.draw(None);
        return MonitorOut::Live(s);
    }
    if a.depth {
        eprintln!("note: stdout is not a terminal: no live preview, events only");
    }
    eprintln!("claiming proximity: near ≤ {near_mm} mm, far ≥ {far_mm} mm (Ctrl-C to stop)");
    eprintln!("{} …", live::WAITING);
    if a.json {
        MonitorOut::Json
    } else {
        MonitorOut::Text
    }
}

/// A `DepthFrame` signal as (width, height, depth mm), if well formed.
fn depth_of(f: &tofproxd::client::DepthFrame) -> Option<(usize, usize, Vec<u16>)> {
    let args = f.args().ok()?;
    let (w, h) = (usize::from(*args.width()), usize::from(*args.height()));
    let d = u16_le_image(args.depth_mm_u16_le(), h, w)?;
    (w > 0 && h > 0).then(|| (w, h, d.into_raw_vec_and_offset().0))
}

/// The monitor's claims (depth first, when asked, then proximity) and its state; the
/// depth frames' stream with `--depth`.
async fn start_monitor(
    a: &MonitorArgs,
    p: &ProximityProxy<'static>,
) -> anyhow::Result<(Monitor, Option<tofproxd::client::DepthFrameStream>)> {
    let depth = if a.depth {
        p.claim_depth()
            .await
            .context("ClaimDepth (are you in the tofprox-depth group?)")?;
        Some(p.receive_depth_frame().await?)
    } else {
        None
    };
    let (near_mm, far_mm) = (
        p.near_threshold_mm().await.unwrap_or(0),
        p.far_threshold_mm().await.unwrap_or(0),
    );
    let mut m = Monitor {
        readings_before: valid_readings(p).await,
        out: monitor_out(a, near_mm, far_mm),
        t0: Instant::now(),
        waiting: true,
        last_near: None,
        last_frame: None,
    };
    p.claim_proximity()
        .await
        .context("ClaimProximity (is tofproxd running?)")?;
    m.poll_first_reading(p).await;
    Ok((m, depth))
}

pub fn monitor(a: MonitorArgs) -> anyhow::Result<ExitCode> {
    rt()?.block_on(async {
        let (_conn, p) = proxy(&a.bus).await?;
        let mut near_changes = p.receive_near_changed().await;
        let (mut m, mut depth) = start_monitor(&a, &p).await?;
        let deadline = a
            .seconds
            .map(|s| tokio::time::Instant::now() + Duration::from_secs(s));
        loop {
            let until = async {
                match deadline {
                    Some(d) => tokio::time::sleep_until(d).await,
                    None => std::future::pending().await,
                }
            };
            let next_depth = async {
                match &mut depth {
                    Some(s) => next_item(s).await,
                    None => std::future::pending().await,
                }
            };
            let poll = async {
                match m.waiting {
                    true => tokio::time::sleep(Duration::from_millis(200)).await,
                    false => std::future::pending().await,
                }
            };
            tokio::select! {
                _ = until => break,
                _ = tokio::signal::ctrl_c() => break,
                _ = poll => m.poll_first_reading(&p).await,
                ch = next_item(&mut near_changes) => {
                    let Some(ch) = ch else { bail!("the daemon left the bus") };
                    let near = ch.get().await.unwrap_or(false);
                    m.near_value(&p, near).await;
                }
                f = next_depth => {
                    if let Some((w, h, d)) = f.as_ref().and_then(depth_of) {
                        m.depth_frame(&p, w, h, d).await;
                    }
                }
            }
        }
        drop(m);
        let _ = p.release_proximity().await;
        if a.depth {
            let _ = p.release_depth().await;
        }
        Ok(ExitCode::SUCCESS)
    })
}

pub fn status(a: StatusArgs) -> anyhow::Result<ExitCode> {
    rt()?.block_on(async {
        let (_conn, p) = proxy(&a.bus).await?;
        let s = p
            .get_status()
            .await
            .context("GetStatus (is tofproxd running?)")?;
        let mut keys: Vec<&String> = s.keys().collect();
        keys.sort();
        let mut obj = serde_json::Map::new();
        for k in keys {
            let v = &s[k];
            let j = if let Ok(b) = bool::try_from(v) {
                serde_json::Value::from(b)
            } else if let Ok(x) = u32::try_from(v) {
                serde_json::Value::from(x)
            } else if let Ok(x) = u64::try_from(v) {
                serde_json::Value::from(x)
            } else if let Ok(x) = f64::try_from(v) {
                serde_json::Value::from(x)
            } else if let Ok(x) = String::try_from(v.try_clone()?) {
                serde_json::Value::from(x)
            } else {
                serde_json::Value::from(format!("{v:?}"))
            };
            obj.insert(k.clone(), j);
        }
        if a.json {
            println!("{}", serde_json::Value::Object(obj));
        } else {
            for (k, v) in obj {
                println!("{k:<16} {}", shown_value(&v));
            }
        }
        Ok(ExitCode::SUCCESS)
    })
}

/// `DepthFrame` image bytes (little-endian u16, row-major) as a `rows × cols` image.
fn u16_le_image(bytes: &[u8], rows: usize, cols: usize) -> Option<ndarray::Array2<u16>> {
    if bytes.len() != rows * cols * 2 {
        return None;
    }
    let v: Vec<u16> = bytes
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    ndarray::Array2::from_shape_vec((rows, cols), v).ok()
}

pub fn record(a: RecordArgs) -> anyhow::Result<ExitCode> {
    use tofprox_format::{DepthImageSize, DepthRecordingWriter};
    if a.frames == 0 {
        bail!("--frames must be at least 1");
    }
    rt()?.block_on(async {
        let (_conn, p) = proxy(&a.bus).await?;
        let mut frames = p.receive_depth_frame().await?;
        p.claim_depth()
            .await
            .context("ClaimDepth (is tofproxd running, are you in the tofprox-depth group?)")?;
        let deadline = tokio::time::Instant::now() + Duration::from_secs(a.timeout_s);
        let mut writer: Option<DepthRecordingWriter> = None;
        let mut n = 0usize;
        while n < a.frames {
            let f = tokio::select! {
                _ = tokio::time::sleep_until(deadline) => break,
                f = next_item(&mut frames) => f,
            };
            let Some(f) = f else { break };
            let args = f.args()?;
            let (w, h) = (usize::from(*args.width()), usize::from(*args.height()));
            let Some(depth) = u16_le_image(args.depth_mm_u16_le(), h, w).filter(|_| w > 0 && h > 0)
            else {
                eprintln!(
                    "skipping a malformed DepthFrame ({w}x{h}, {} depth bytes)",
                    args.depth_mm_u16_le().len()
                );
                continue;
            };
            // the amplitude is kept when it is well formed (an empty one is "not sent")
            let amplitude = u16_le_image(args.amplitude_u16_le(), h, w);
            if writer.is_none() {
                let size = DepthImageSize { rows: h, cols: w };
                let description =
                    Some("depth frames from tofproxd (DepthFrame signals)".to_string());
                writer = Some(
                    DepthRecordingWriter::create(&a.out, size, description, a.force)
                        .map_err(|e| super::output_error(&a.out, e))?,
                );
            }
            let Some(wr) = writer.as_mut() else { continue };
            if (wr.size().rows, wr.size().cols) != (h, w) {
                eprintln!(
                    "skipping a {w}x{h} frame (recording is {}x{})",
                    wr.size().cols,
                    wr.size().rows
                );
                continue;
            }
            wr.append(Some(*args.timestamp_ns()), &depth, amplitude.as_ref())?;
            n += 1;
        }
        let _ = p.release_depth().await;
        if n == 0 {
            bail!("no DepthFrame received within {} s", a.timeout_s);
        }
        // the recording ends here, whole; a killed `daemon record` leaves it marked incomplete
        if let Some(w) = writer {
            w.finish().map_err(|e| super::output_error(&a.out, e))?;
        }
        eprintln!(
            "recorded {n} depth frames to {} (a depth recording: `tofprox info` summarises it)",
            a.out.display()
        );
        Ok(ExitCode::SUCCESS)
    })
}

/// A status value as a person reads it: floats to 3 decimals without trailing zeros (a 500 µs
/// exposure is not `499.9999999999999`), text without quotes, everything else as JSON text.
fn shown_value(v: &serde_json::Value) -> String {
    if let serde_json::Value::String(s) = v {
        return s.clone();
    }
    match v.as_f64() {
        Some(x) if v.is_f64() => {
            let s = format!("{x:.3}");
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        }
        _ => v.to_string(),
    }
}

/// RSS is sampled after the warm-up; a shorter run (or no /proc) has no figure.
fn soak_rss_measured(rep: &tofproxd::soak::SoakReport) -> bool {
    rep.rss_kb_start > 0 && rep.rss_kb_end > 0
}

/// The soak report as JSON, the memory figures null when not measured.
fn soak_json(rep: &tofproxd::soak::SoakReport) -> anyhow::Result<serde_json::Value> {
    let mut v = serde_json::to_value(rep)?;
    if !soak_rss_measured(rep) {
        v["rss_kb_start"] = serde_json::Value::Null;
        v["rss_kb_end"] = serde_json::Value::Null;
    }
    Ok(v)
}

/// The soak report for people.
fn print_soak(rep: &tofproxd::soak::SoakReport, ok: bool) {
    let memory = if soak_rss_measured(rep) {
        format!(
            "{} kB after warm-up, {} kB at the end ({:+} kB)",
            rep.rss_kb_start,
            rep.rss_kb_end,
            rep.rss_kb_end as i64 - rep.rss_kb_start as i64
        )
    } else {
        "not measured (the run ended within the warm-up)".to_string()
    };
    let by_kind = if rep.failures_by_kind.is_empty() {
        "none".to_string()
    } else {
        rep.failures_by_kind
            .iter()
            .map(|(k, n)| format!("{k} {n}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    println!(
        "soak: {} cycles on a virtual clock, {} faults injected, {} cycles failed\n\
         failed by:    {by_kind} (each logged with -v)\n\
         false near:   {}\n\
         panics:       {}\n\
         recovery:     {} episodes recovered, longest {} cycles, {} still open at the end\n\
         near events:  {}\n\
         memory (RSS): {memory}\n\
         verdict:      {} (needs 0 false near, 0 panics, recovery within 3 cycles)",
        rep.cycles,
        rep.faults_injected,
        rep.failed_cycles,
        rep.false_near,
        rep.panics,
        rep.recovered,
        rep.max_recovery_cycles,
        rep.unrecovered,
        rep.near_transitions,
        if ok { "PASS" } else { "FAIL" }
    );
}

pub fn soak(a: SoakArgs) -> anyhow::Result<ExitCode> {
    // drawn only when stderr is a terminal
    let pb = indicatif::ProgressBar::with_draw_target(
        Some(a.cycles),
        indicatif::ProgressDrawTarget::stderr(),
    );
    if let Ok(st) =
        indicatif::ProgressStyle::with_template("soak [{bar:30}] {pos}/{len} cycles {elapsed}")
    {
        pb.set_style(st.progress_chars("=> "));
    }
    let rep = tofproxd::soak::run(
        &tofproxd::soak::SoakConfig {
            cycles: a.cycles,
            fault_rate: a.fault_rate,
            seed: a.seed,
            ..tofproxd::soak::SoakConfig::default()
        },
        |done| {
            if done % 64 == 0 {
                pb.set_position(done);
            }
        },
    )?;
    pb.finish_and_clear();
    let ok = rep.false_near == 0 && rep.panics == 0 && rep.max_recovery_cycles <= 3;
    if a.json {
        println!("{}", soak_json(&rep)?);
    } else {
        print_soak(&rep, ok);
    }
    // (held_over_failure is the bounded, safe-side hold across failed cycles: reported, not a failure)
    Ok(if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

pub fn scenes(a: ScenesArgs) -> anyhow::Result<ExitCode> {
    let calib = a.calib.clone().or_else(|| {
        let set = tofproxd::data::find("calib/phone/calibration.toml").ok()?;
        set.parent().map(PathBuf::from)
    });
    let model = match &a.model {
        Some(m) => m.clone(),
        None => tofproxd::data::find("config/model/phone.toml")
            .context("the phone model: pass --model FILE")?,
    };
    let mut bench = tofproxd::scenes::bench(&model, calib.as_deref());
    if let Some(p) = &a.config {
        let mut c = Config::load(p)?;
        if a.calib.is_some() || c.processing.calibration.is_none() {
            c.processing.calibration = calib;
        }
        bench.config = c;
    }
    bench.config.backend = tofproxd::config::Backend::Emulated;
    let mut results = Vec::new();
    for s in tofproxd::scenes::catalogue(&bench.config) {
        if a.only.as_deref().is_some_and(|o| !s.name.contains(o)) {
            continue;
        }
        results.push(tofproxd::scenes::run_scene(&bench, &s, a.seed)?);
    }
    if a.json {
        println!("{}", serde_json::to_string(&results)?);
    } else {
        let ms = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.0}"));
        println!(
            "| scene | readings | false near | missed near | to near (ms) | to far (ms) | energy/reading (mJ) | cover window |"
        );
        println!("|---|---|---|---|---|---|---|---|");
        for r in &results {
            println!(
                "| {} | {}/{} | {} | {} | {} | {} | {:.3} | {} |",
                r.name,
                r.readings,
                r.cycles,
                r.false_near,
                r.missed_near,
                ms(r.latency_to_near_ms),
                ms(r.latency_to_far_ms),
                r.energy_per_reading_mj,
                if r.cover_window_changed {
                    "changed"
                } else {
                    "ok"
                }
            );
        }
    }
    let ok = results
        .iter()
        .all(|r| r.false_near == 0 && r.missed_near == 0);
    Ok(if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

#[cfg(test)]
mod tests {
    use super::shown_value;
    use serde_json::json;

    #[test]
    fn status_floats_are_rounded_for_people() {
        assert_eq!(shown_value(&json!(499.9999999999999)), "500");
        assert_eq!(shown_value(&json!(0.1 + 0.2)), "0.3");
        assert_eq!(shown_value(&json!(-1.25)), "-1.25");
        assert_eq!(shown_value(&json!(12)), "12");
        assert_eq!(shown_value(&json!("running")), "running");
        assert_eq!(shown_value(&json!([1, 2])), "[1,2]");
    }
}
