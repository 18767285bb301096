//! Daemon clients and tools: `power`, `monitor`, `status`, `record`, `soak` (issue: tofproxd).
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use tofproxd::client::ProximityProxy;
use tofproxd::config::{Config, Mode};
use tofproxd::energy::{Nominal, TABLE_2_1, modelled_average_mw};
use tofproxd::run::BusChoice;
use tofproxd::service::next_item;

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
    /// Also claim depth frames and render a small live preview.
    #[arg(long)]
    depth: bool,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    seconds: Option<u64>,
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
    /// Record the daemon's DepthFrame signals into this recording directory.
    #[arg(long = "from-daemon", value_name = "REC")]
    from_daemon: PathBuf,
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
    let nominal = Nominal::default();
    let k = mode.raw_images() as u32;
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
        "  assumptions: start-up {:.1} ms at {} mW, flash load {:.1} ms at {} mW, read-out {:.1} ms/image, reset {} mW",
        nominal.startup_ms,
        cfg.energy.startup_mw,
        nominal.flash_load_ms,
        cfg.energy.flash_load_mw,
        nominal.readout_ms_per_image,
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

fn rt() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("tokio runtime")
}

async fn proxy(bus: &BusChoice) -> anyhow::Result<(zbus::Connection, ProximityProxy<'static>)> {
    let conn = tofproxd::run::connect(bus).await?;
    let p = ProximityProxy::new(&conn)
        .await
        .context("org.tofprox.Proximity1 proxy")?;
    Ok((conn, p))
}

pub fn monitor(a: MonitorArgs) -> anyhow::Result<ExitCode> {
    rt()?.block_on(async {
        let (_conn, p) = proxy(&a.bus).await?;
        let mut near_changes = p.receive_near_changed().await;
        let mut depth = if a.depth {
            p.claim_depth().await.context("ClaimDepth (are you in the tofprox-depth group?)")?;
            Some(p.receive_depth_frame().await?)
        } else {
            None
        };
        let t0 = Instant::now();
        p.claim_proximity().await.context("ClaimProximity (is tofproxd running?)")?;
        eprintln!(
            "claimed proximity: near ≤ {} mm, far ≥ {} mm (Ctrl-C to stop)",
            p.near_threshold_mm().await.unwrap_or(0),
            p.far_threshold_mm().await.unwrap_or(0)
        );
        let deadline = a.seconds.map(|s| tokio::time::Instant::now() + Duration::from_secs(s));
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
            tokio::select! {
                _ = until => break,
                _ = tokio::signal::ctrl_c() => break,
                ch = next_item(&mut near_changes) => {
                    let Some(ch) = ch else { bail!("the daemon left the bus") };
                    let near = ch.get().await.unwrap_or(false);
                    let d = p.distance_mm().await.unwrap_or(0);
                    let state = p.state().await.unwrap_or_default();
                    println!("{:8.2}s  {}  distance={} mm  state={state}", t0.elapsed().as_secs_f64(),
                        if near { "NEAR" } else { "far " }, d);
                }
                f = next_depth => {
                    if let Some(f) = f && let Ok(args) = f.args() {
                        render_depth(*args.width(), *args.height(), args.depth_mm_u16_le());
                    }
                }
            }
        }
        let _ = p.release_proximity().await;
        if a.depth {
            let _ = p.release_depth().await;
        }
        Ok(ExitCode::SUCCESS)
    })
}

/// A small terminal preview: near = dense characters.
fn render_depth(width: u16, height: u16, depth_le: &[u8]) {
    let (w, h) = (usize::from(width), usize::from(height));
    if w == 0 || h == 0 || depth_le.len() < w * h * 2 {
        return;
    }
    let ramp: &[u8] = b"@%#*+=-:. ";
    let (cw, ch) = (48usize.min(w), 12usize.min(h));
    let mut out = String::from("\x1b[s\x1b[1;1H");
    for r in 0..ch {
        for c in 0..cw {
            let (y, x) = (r * h / ch, c * w / cw);
            let i = (y * w + x) * 2;
            let d = u16::from_le_bytes([depth_le[i], depth_le[i + 1]]);
            let ch = if d == 0 {
                b'?'
            } else {
                ramp[(usize::from(d.min(1499)) * ramp.len() / 1500).min(ramp.len() - 1)]
            };
            out.push(char::from(ch));
        }
        out.push_str("\x1b[K\n");
    }
    out.push_str("\x1b[u");
    eprint!("{out}");
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
                println!("{k:<16} {v}");
            }
        }
        Ok(ExitCode::SUCCESS)
    })
}

pub fn record(a: RecordArgs) -> anyhow::Result<ExitCode> {
    use tofprox_core::SensorGeometry;
    use tofprox_format::{CaptureSpec, RawFrames, RecordingWriter};
    if a.frames == 0 {
        bail!("--frames must be at least 1");
    }
    rt()?.block_on(async {
        let (_conn, p) = proxy(&a.bus).await?;
        let mut frames = p.receive_depth_frame().await?;
        p.claim_depth().await.context("ClaimDepth (is tofproxd running, are you in the tofprox-depth group?)")?;
        let deadline = tokio::time::Instant::now() + Duration::from_secs(a.timeout_s);
        let mut writer: Option<RecordingWriter> = None;
        let mut n = 0usize;
        while n < a.frames {
            let f = tokio::select! {
                _ = tokio::time::sleep_until(deadline) => break,
                f = next_item(&mut frames) => f,
            };
            let Some(f) = f else { break };
            let args = f.args()?;
            let (w, h) = (usize::from(*args.width()), usize::from(*args.height()));
            let bytes = args.depth_mm_u16_le();
            if w == 0 || h == 0 || bytes.len() != w * h * 2 {
                eprintln!("skipping a malformed DepthFrame ({w}x{h}, {} bytes)", bytes.len());
                continue;
            }
            let depth: Vec<u16> = bytes.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
            let arr = ndarray::Array3::from_shape_vec((1, h, w), depth)?;
            if writer.is_none() {
                writer = Some(RecordingWriter::create(
                    &a.from_daemon,
                    SensorGeometry::full(h, w, 16, 80e6),
                    Some("depth frames from tofproxd (DepthFrame): each capture holds ONE image, depth in mm (0 = invalid), not raw phase codes".into()),
                )?);
            }
            let Some(wr) = writer.as_mut() else { continue };
            if (wr.sensor().rows, wr.sensor().cols) != (h, w) {
                eprintln!("skipping a {w}x{h} frame (recording is {}x{})", wr.sensor().cols, wr.sensor().rows);
                continue;
            }
            let mut conditions = std::collections::BTreeMap::new();
            conditions.insert("depth_frame".to_string(), 1.0);
            wr.append(
                CaptureSpec {
                    phases_deg: vec![0.0],
                    exposure_us: 0.0,
                    illumination: true,
                    averaged: 1,
                    timestamp_ns: Some(*args.timestamp_ns()),
                    conditions,
                },
                &RawFrames::U16(arr),
            )?;
            n += 1;
        }
        let _ = p.release_depth().await;
        if n == 0 {
            bail!("no DepthFrame received within {} s", a.timeout_s);
        }
        eprintln!("recorded {n} depth frames to {}", a.from_daemon.display());
        Ok(ExitCode::SUCCESS)
    })
}

pub fn soak(a: SoakArgs) -> anyhow::Result<ExitCode> {
    let rep = tofproxd::soak::run(&tofproxd::soak::SoakConfig {
        cycles: a.cycles,
        fault_rate: a.fault_rate,
        seed: a.seed,
        ..tofproxd::soak::SoakConfig::default()
    })?;
    if a.json {
        println!("{}", serde_json::to_string(&rep)?);
    } else {
        println!("{rep:#?}");
    }
    let ok = rep.false_near == 0 && rep.panics == 0 && rep.max_recovery_cycles <= 3;
    Ok(if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
