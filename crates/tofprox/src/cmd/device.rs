//! `tofprox device ...` (issue: bridge and driver): probe for the CX3 bridge,
//! capture raw frames (real hardware or the emulated device) into a version 1
//! recording.
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::{Context, bail};
use ndarray::Axis;
use tofprox_bridge::usb::{UsbSelector, probe};
use tofprox_bridge::{
    Clock, CycleOutput, CycleRequest, DeviceConfigFile, DriverConfig, EmulatedConfig,
    EmulatedDevice, RowWindow, RusbTransport, SensorDriver, SensorMode, SystemClock, UsbTransport,
};
use tofprox_format::{CaptureSpec, RawFrames, RecordingWriter};

#[derive(clap::Subcommand, Debug)]
pub enum DeviceCommand {
    /// List CX3 bridges matching the configured USB ids (exit 1 when none).
    Probe(ProbeArgs),
    /// Capture raw frames into a version 1 recording (uint16 single
    /// acquisitions).
    Capture(CaptureArgs),
    /// Bring-up: read or write sensor registers over the bridge's I2C.
    Reg(RegArgs),
    /// Bring-up: the configuration image in the sensor's SPI flash.
    Flash(FlashArgs),
    /// Bring-up: drive the sensor's reset pin (`hold` = in reset / off,
    /// `release` = running).
    Reset(ResetArgs),
    /// Turn a capture of a camera's USB stream (usbmon pcap/pcapng or text) into a version 1
    /// recording, given the mode it was taken in.
    Decode(super::device_decode::DecodeArgs),
}

#[derive(clap::Args, Debug)]
pub struct RegArgs {
    #[command(flatten)]
    select: SelectArgs,
    /// Use the emulated device (`--config` is then an emulated-device file).
    #[arg(long)]
    emulated: bool,
    /// Release the reset pin and wait for start-up first (always done with
    /// `--emulated`, whose sensor starts in reset).
    #[arg(long)]
    release_reset: bool,
    /// 7-bit I2C address (hex); default: the register map's.
    #[arg(long, value_parser = parse_hex16)]
    addr: Option<u16>,
    #[command(subcommand)]
    op: RegOp,
}

#[derive(clap::Subcommand, Debug)]
pub enum RegOp {
    /// Read COUNT consecutive 16-bit registers from REG (hex).
    Read {
        #[arg(value_parser = parse_hex16)]
        reg: u16,
        #[arg(long, default_value_t = 1)]
        count: usize,
        /// JSON output.
        #[arg(long)]
        json: bool,
    },
    /// Write VALUES (hex) to consecutive registers from REG (hex), as one
    /// burst.
    Write {
        #[arg(value_parser = parse_hex16)]
        reg: u16,
        #[arg(value_parser = parse_hex16, required = true)]
        values: Vec<u16>,
    },
}

#[derive(clap::Args, Debug)]
pub struct FlashArgs {
    #[command(flatten)]
    select: SelectArgs,
    /// Use the emulated device (`--config` is then an emulated-device file;
    /// give it a `flash_file` for the flash to persist between runs).
    #[arg(long)]
    emulated: bool,
    /// status: load the image and report; write: write the full image
    /// (erase, program, verify) and load it.
    #[arg(value_parser = ["status", "write"])]
    action: String,
}

#[derive(clap::Args, Debug)]
pub struct ResetArgs {
    #[command(flatten)]
    select: SelectArgs,
    /// hold (reset low: sensor off) or release (reset high).
    #[arg(value_parser = ["hold", "release"])]
    state: String,
}

#[derive(clap::Args, Debug)]
pub struct SelectArgs {
    /// Device file (`[usb]` selection and `[driver]` settings; see
    /// config/sensor/device.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// USB vendor id (hex), overrides the config.
    #[arg(long, value_parser = parse_hex16)]
    vid: Option<u16>,
    /// USB product id (hex), overrides the config.
    #[arg(long, value_parser = parse_hex16)]
    pid: Option<u16>,
    /// Only the device with this serial number.
    #[arg(long)]
    serial: Option<String>,
    /// Only the device at this bus path (e.g. 1-2.3).
    #[arg(long)]
    bus_path: Option<String>,
}

#[derive(clap::Args, Debug)]
pub struct ProbeArgs {
    #[command(flatten)]
    select: SelectArgs,
    /// JSON output on stdout.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args, Debug)]
pub struct CaptureArgs {
    #[command(flatten)]
    select: SelectArgs,
    /// Use the emulated device; `--config` is then an emulated-device file
    /// (config/emulated/*.toml).
    #[arg(long)]
    emulated: bool,
    /// Seed of the emulated device (noise, faults).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Measurement mode: 2phase, 4phase, 4phase-grey (4-phase plus an
    /// unilluminated image) or correlation24 (24-phase correlation sweep).
    #[arg(long, value_parser = parse_mode, value_name = "2phase|4phase|4phase-grey|correlation24")]
    mode: SensorMode,
    /// Exposure per raw image, µs.
    #[arg(long)]
    exposure_us: f64,
    /// Rows to read out, `FIRST,COUNT` (partial read-out of whole rows);
    /// default: the full array.
    #[arg(long = "rows", value_name = "FIRST,COUNT", value_parser = parse_window)]
    window: Option<RowWindow>,
    /// Number of measurements (one capture each).
    #[arg(long, default_value_t = 1)]
    count: u32,
    /// Retry a measurement this many times after a transient device error
    /// (the driver recovers at the next cycle: reopen, clear halt, restart).
    #[arg(long, default_value_t = 2)]
    retries: u32,
    /// Capture condition `KEY=VALUE` (e.g. distance_m=0.5), repeatable.
    #[arg(long = "condition", value_parser = parse_condition)]
    conditions: Vec<(String, f64)>,
    /// Recording description.
    #[arg(long)]
    description: Option<String>,
    /// Output recording directory (must not hold a recording yet, unless --force).
    #[arg(long)]
    out: PathBuf,
    /// Replace the recording already in `--out`.
    #[arg(long)]
    force: bool,
}

fn parse_hex16(s: &str) -> Result<u16, String> {
    let t = s.trim_start_matches("0x").trim_start_matches("0X");
    u16::from_str_radix(t, 16).map_err(|e| format!("{s:?} is not a 16-bit hex id: {e}"))
}

fn parse_mode(s: &str) -> Result<SensorMode, String> {
    s.parse::<SensorMode>().map_err(|e| e.to_string())
}

fn parse_window(s: &str) -> Result<RowWindow, String> {
    let (a, b) = s
        .split_once(',')
        .ok_or_else(|| format!("window {s:?}: expected ROW0,ROWS"))?;
    let row0 = a
        .trim()
        .parse::<u16>()
        .map_err(|e| format!("window row0 {a:?}: {e}"))?;
    let rows = b
        .trim()
        .parse::<u16>()
        .map_err(|e| format!("window rows {b:?}: {e}"))?;
    if rows == 0 {
        return Err("window rows must be > 0".into());
    }
    Ok(RowWindow::rows_only(row0, rows))
}

fn parse_condition(s: &str) -> Result<(String, f64), String> {
    let (k, v) = s
        .split_once('=')
        .ok_or_else(|| format!("condition {s:?}: expected KEY=VALUE"))?;
    let v: f64 = v
        .trim()
        .parse()
        .map_err(|e| format!("condition {k}: {e}"))?;
    if !v.is_finite() {
        return Err(format!("condition {k}: value must be finite"));
    }
    Ok((k.trim().to_string(), v))
}

fn selector(a: &SelectArgs) -> anyhow::Result<(UsbSelector, Option<DriverConfig>)> {
    let (mut sel, drv) = match &a.config {
        Some(p) => {
            let (f, d) = DeviceConfigFile::load(p)?;
            (f.usb, Some(d))
        }
        None => (UsbSelector::default(), None),
    };
    if let Some(v) = a.vid {
        sel.vendor_id = v;
    }
    if let Some(p) = a.pid {
        sel.product_id = p;
    }
    if a.serial.is_some() {
        sel.serial = a.serial.clone();
    }
    if a.bus_path.is_some() {
        sel.bus_path = a.bus_path.clone();
    }
    Ok((sel, drv))
}

pub fn run(c: DeviceCommand) -> anyhow::Result<ExitCode> {
    match c {
        DeviceCommand::Probe(a) => probe_cmd(a),
        DeviceCommand::Capture(a) => capture(a),
        DeviceCommand::Reg(a) => reg_cmd(a),
        DeviceCommand::Reset(a) => reset_cmd(a),
        DeviceCommand::Flash(a) => flash_cmd(a),
        DeviceCommand::Decode(a) => super::device_decode::decode(a),
    }
}

fn flash_cmd(a: FlashArgs) -> anyhow::Result<ExitCode> {
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
    if a.emulated {
        let cfg = match &a.select.config {
            Some(p) => EmulatedConfig::load(p)?,
            None => EmulatedConfig::default(),
        };
        flash_with(&a, SensorDriver::emulated(cfg, clock.clone(), 1)?, clock)
    } else {
        let (sel, drv) = selector(&a.select)?;
        let drv = drv.unwrap_or_else(DriverConfig::emulated_default);
        let driver = SensorDriver::new(RusbTransport::open(sel)?, drv, clock.clone())?;
        flash_with(&a, driver, clock)
    }
}

fn flash_with<T: UsbTransport>(
    a: &FlashArgs,
    mut driver: SensorDriver<T>,
    clock: Arc<dyn Clock>,
) -> anyhow::Result<ExitCode> {
    driver.bring_up()?;
    let t0 = clock.now();
    let r = if a.action == "write" {
        driver.flash_write()
    } else {
        driver.flash_load()
    };
    let took = clock.now() - t0;
    let _ = driver.power_off();
    match r {
        Ok(()) if a.action == "write" => {
            println!("flash written, verified and loaded in {took:?}");
            Ok(ExitCode::SUCCESS)
        }
        Ok(()) => {
            println!("flash holds a valid configuration image (loaded in {took:?})");
            Ok(ExitCode::SUCCESS)
        }
        Err(e)
            if a.action == "status"
                && matches!(
                    e.kind(),
                    tofprox_bridge::ErrorKind::FlashEmpty | tofprox_bridge::ErrorKind::FlashCorrupt
                ) =>
        {
            println!("{e} (write it with `tofprox device flash write`)");
            Ok(ExitCode::from(1))
        }
        Err(e) => Err(e.into()),
    }
}

fn reg_cmd(a: RegArgs) -> anyhow::Result<ExitCode> {
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
    let (mut dev, drv, release): (Box<dyn UsbTransport>, DriverConfig, bool) = if a.emulated {
        let cfg = match &a.select.config {
            Some(p) => EmulatedConfig::load(p)?,
            None => EmulatedConfig::default(),
        };
        let drv = cfg.driver_config()?;
        (
            Box::new(EmulatedDevice::new(cfg, clock.clone(), 1)?),
            drv,
            true,
        )
    } else {
        let (sel, drv) = selector(&a.select)?;
        let drv = drv.unwrap_or_else(DriverConfig::emulated_default);
        (Box::new(RusbTransport::open(sel)?), drv, a.release_reset)
    };
    let cx3 = tofprox_bridge::protocol::Cx3::new(drv.protocol.clone())?;
    let addr = match a.addr {
        Some(v) => u8::try_from(v)
            .ok()
            .filter(|v| *v <= 0x7F)
            .with_context(|| format!("--addr {v:#x} is not a 7-bit I2C address"))?,
        None => drv.map.sensor.i2c_address,
    };
    if release {
        cx3.set_reset(&mut dev, false)?;
        clock.sleep(std::time::Duration::from_micros(
            drv.timing.startup_delay_us,
        ));
    }
    match a.op {
        RegOp::Read { reg, count, json } => {
            if count == 0
                || usize::from(reg)
                    .checked_add(count)
                    .is_none_or(|end| end > 0x1_0000)
            {
                bail!(
                    "--count {count} from register {reg:#06x}: must be 1.. and stay below 0x10000"
                );
            }
            let v = cx3.i2c_read(&mut dev, addr, reg, count)?;
            if json {
                let rows: Vec<_> = v
                    .iter()
                    .enumerate()
                    .map(|(i, x)| serde_json::json!({"register": usize::from(reg) + i, "value": x}))
                    .collect();
                println!("{}", serde_json::to_string_pretty(&rows)?);
            } else {
                for (i, x) in v.iter().enumerate() {
                    println!("{:#06x} = {x:#06x}", usize::from(reg) + i);
                }
            }
        }
        RegOp::Write { reg, values } => {
            cx3.i2c_write(&mut dev, addr, reg, &values)?;
            eprintln!("wrote {} register(s) from {reg:#06x}", values.len());
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn reset_cmd(a: ResetArgs) -> anyhow::Result<ExitCode> {
    let (sel, drv) = selector(&a.select)?;
    let drv = drv.unwrap_or_else(DriverConfig::emulated_default);
    let mut dev = RusbTransport::open(sel)?;
    let cx3 = tofprox_bridge::protocol::Cx3::new(drv.protocol)?;
    cx3.set_reset(&mut dev, a.state == "hold")?;
    eprintln!(
        "sensor reset pin: {}",
        if a.state == "hold" {
            "low (held in reset)"
        } else {
            "high (released)"
        }
    );
    Ok(ExitCode::SUCCESS)
}

fn probe_cmd(a: ProbeArgs) -> anyhow::Result<ExitCode> {
    let (sel, _) = selector(&a.select)?;
    let found = probe(&sel)?;
    if a.json {
        let v = serde_json::json!({
            "vendor_id": format!("{:04x}", sel.vendor_id),
            "product_id": format!("{:04x}", sel.product_id),
            "devices": found,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else if found.is_empty() {
        println!(
            "no matching device found (USB {:04x}:{:04x}{}{})",
            sel.vendor_id,
            sel.product_id,
            sel.serial
                .as_deref()
                .map(|s| format!(", serial {s}"))
                .unwrap_or_default(),
            sel.bus_path
                .as_deref()
                .map(|s| format!(", bus path {s}"))
                .unwrap_or_default(),
        );
    } else {
        for d in &found {
            println!(
                "{:04x}:{:04x}  bus {:03} address {:03}  path {}  serial {}  {}",
                d.vendor_id,
                d.product_id,
                d.bus,
                d.address,
                d.bus_path,
                d.serial.as_deref().unwrap_or("-"),
                d.product.as_deref().unwrap_or("")
            );
        }
    }
    Ok(if found.is_empty() {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}

fn capture(a: CaptureArgs) -> anyhow::Result<ExitCode> {
    if a.count == 0 {
        bail!("--count must be at least 1");
    }
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
    let mut conditions: BTreeMap<String, f64> = a.conditions.iter().cloned().collect();
    if a.emulated {
        let cfg = match &a.select.config {
            Some(p) => EmulatedConfig::load(p)?,
            None => EmulatedConfig::default(),
        };
        conditions
            .entry("ambient_klux".into())
            .or_insert(cfg.ambient_klux);
        conditions
            .entry("temperature_c".into())
            .or_insert(cfg.temperature_c);
        if cfg.scene.kind == tofprox_model::ScriptKind::Wall {
            conditions
                .entry("distance_m".into())
                .or_insert(cfg.scene.wall_distance_m);
            conditions
                .entry("reflectivity".into())
                .or_insert(cfg.scene.wall_reflectivity);
        }
        let driver = SensorDriver::emulated(cfg, clock.clone(), a.seed)?;
        run_capture(&a, driver, clock, conditions)
    } else {
        let (sel, drv) = selector(&a.select)?;
        let dev = RusbTransport::open(sel)?;
        let drv = drv.unwrap_or_else(DriverConfig::emulated_default);
        let driver = SensorDriver::new(dev, drv, clock.clone())?;
        run_capture(&a, driver, clock, conditions)
    }
}

fn run_capture<T: UsbTransport>(
    a: &CaptureArgs,
    mut driver: SensorDriver<T>,
    clock: Arc<dyn Clock>,
    conditions: BTreeMap<String, f64>,
) -> anyhow::Result<ExitCode> {
    let desc = driver.transport().describe();
    let req = CycleRequest {
        mode: a.mode,
        exposure_us: a.exposure_us,
        row_window: a.window,
        modulation_hz: None,
        single_image: None,
    };
    driver.check_request(&req)?;
    let mut writer: Option<RecordingWriter> = None;
    for i in 0..a.count {
        let mut attempt = 0;
        let out = loop {
            match driver.cycle(&req) {
                Ok(o) => break o,
                Err(e) if e.kind().is_transient() && attempt < a.retries => {
                    attempt += 1;
                    eprintln!(
                        "warning: capture {}: {e} [{}]; retrying ({attempt}/{})",
                        i + 1,
                        e.kind(),
                        a.retries
                    );
                    // give an unplugged device time to come back
                    clock.sleep(std::time::Duration::from_millis(100));
                }
                Err(e) => {
                    return Err(anyhow::Error::new(e).context(format!(
                        "capture {} of {} from {desc}",
                        i + 1,
                        a.count
                    )));
                }
            }
        };
        let w = match writer.as_mut() {
            Some(w) => w,
            None => writer.insert(create_writer(a, &out, &desc)?),
        };
        append(w, &out, &conditions).with_context(|| format!("writing {}", a.out.display()))?;
        tracing::info!(
            "capture {}: {} raw images {:?}, total {:?}{}",
            i + 1,
            out.frames.dim().0,
            out.frames.dim(),
            out.timings.total,
            if out.flash_written {
                " (flash written)"
            } else {
                ""
            }
        );
    }
    let _ = driver.power_off();
    if let Some(w) = writer {
        w.finish()
            .with_context(|| format!("writing {}", a.out.display()))?;
    }
    eprintln!("wrote {} capture(s) to {}", a.count, a.out.display());
    Ok(ExitCode::SUCCESS)
}

fn create_writer(
    a: &CaptureArgs,
    out: &CycleOutput,
    desc: &str,
) -> anyhow::Result<RecordingWriter> {
    let sensor = out.geometry;
    let description = a
        .description
        .clone()
        .unwrap_or_else(|| format!("tofprox device capture, {} mode, {desc}", a.mode));
    super::new_recording(&a.out, sensor, Some(description), a.force)
}

/// Append one cycle: consecutive raw images with the same illumination
/// become one capture (a 4phase-grey measurement gives a 4-image capture and
/// a 1-image dark capture).
fn append(
    w: &mut RecordingWriter,
    out: &CycleOutput,
    conditions: &BTreeMap<String, f64>,
) -> anyhow::Result<()> {
    let ts = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .ok()
        .and_then(|d| u64::try_from(d.as_nanos()).ok());
    let k = out.frames.dim().0;
    let mut start = 0;
    while start < k {
        let il = out.illuminated.get(start).copied().unwrap_or(true);
        let mut end = start + 1;
        while end < k && out.illuminated.get(end).copied().unwrap_or(true) == il {
            end += 1;
        }
        let idx: Vec<usize> = (start..end).collect();
        let frames = out.frames.select(Axis(0), &idx);
        let spec = CaptureSpec {
            phases_deg: out.phases_deg[start..end].to_vec(),
            exposure_us: out.exposure_us,
            illumination: il,
            averaged: 1,
            timestamp_ns: ts,
            conditions: conditions.clone(),
        };
        w.append(spec, &RawFrames::U16(frames))?;
        start = end;
    }
    Ok(())
}
