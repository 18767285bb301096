//! Layer 3: the sensor driver. One [`SensorDriver::cycle`] is one proximity
//! reading of the thesis's low-power loop (3.5.3, fig. 3.23, listing 4.11):
//! restart (reset low → high) → minimum configuration over I2C (PLL; with the
//! map's `[bring_up]`: wait, imager `CTRL` then `EN`, wait) → load the
//! configuration from flash (write it if missing or corrupt) → set exposure
//! times (the flash image overwrites them every time) → start → read K raw
//! frames → stop measurement → stop sensor (reset low).
//!
//! Every wait is a bounded poll that sleeps on the injected [`Clock`]. The
//! SPI-flash commands are in `spi`, the configuration and its files in
//! `config`.

use std::sync::Arc;
use std::time::Duration;

use ndarray::Array3;
use serde::{Deserialize, Serialize};
use tofprox_core::{Algorithm, SensorGeometry};

use crate::clock::Clock;
use crate::error::{BridgeError, ErrorKind, ResultExt};
use crate::frame::{ContentError, decode_frame};
use crate::protocol::Cx3;
use crate::regmap::{RegWrite, bursts};
use crate::transport::UsbTransport;
use crate::uvc::{FrameSpec, Push, Reassembler, ReassemblyStats};

mod config;
mod spi;

pub use config::{DeviceConfigFile, DriverConfig, DriverConfigFile, DriverTiming};

/// What one cycle measures: a use case of the register map. The depth modes are the shared
/// measurement mode [`Algorithm`]; the register map also has a grey and a correlation use case.
///
/// Named (serde, [`Display`](std::fmt::Display), [`FromStr`](std::str::FromStr)) by the
/// register map's use-case names: `2phase`, `4phase`, `4phase-grey`, `correlation24`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(into = "String", try_from = "String")]
pub enum SensorMode {
    /// Depth: two raw images 0°/90° (the thesis's low-power mode) or four 0/90/180/270°.
    Depth(Algorithm),
    /// Four phase images plus a grey (unilluminated) image.
    FourPhaseGrey,
    /// 24 raw images at 15° steps (correlation capture).
    Correlation24,
}

impl SensorMode {
    /// The use-case name in the register map (also the serde/CLI name).
    pub fn use_case_name(self) -> &'static str {
        match self {
            SensorMode::Depth(a) => a.as_str(),
            SensorMode::FourPhaseGrey => "4phase-grey",
            SensorMode::Correlation24 => "correlation24",
        }
    }

    /// The depth algorithm of a depth mode.
    pub fn algorithm(self) -> Option<Algorithm> {
        match self {
            SensorMode::Depth(a) => Some(a),
            _ => None,
        }
    }
}

impl From<Algorithm> for SensorMode {
    fn from(a: Algorithm) -> Self {
        SensorMode::Depth(a)
    }
}

impl From<SensorMode> for String {
    fn from(m: SensorMode) -> Self {
        m.use_case_name().to_string()
    }
}

impl TryFrom<String> for SensorMode {
    type Error = BridgeError;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        s.parse()
    }
}

impl std::fmt::Display for SensorMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.use_case_name())
    }
}

impl std::str::FromStr for SensorMode {
    type Err = BridgeError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "2phase" => Ok(SensorMode::Depth(Algorithm::TwoPhase)),
            "4phase" => Ok(SensorMode::Depth(Algorithm::FourPhase)),
            "4phase-grey" => Ok(SensorMode::FourPhaseGrey),
            "correlation24" | "correlation" => Ok(SensorMode::Correlation24),
            _ => Err(BridgeError::config(format!(
                "unknown mode {s:?} (2phase, 4phase, 4phase-grey, correlation24)"
            ))),
        }
    }
}

/// What one cycle should measure: the shared request with the driver's [`SensorMode`].
pub type CycleRequest = tofprox_core::CycleRequest<SensorMode>;

/// How long each state of a cycle took (clock time), for energy accounting.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct StateTimings {
    /// Reset release until the sensor answered (start-up).
    pub startup: Duration,
    /// Minimum configuration + flash load(s) + exposure/use-case registers (the bring-up
    /// included).
    pub config_load: Duration,
    /// The part of `config_load` that is the minimum configuration and the imager bring-up's
    /// waits (PLL settling, imager enable): the sensor powered, not yet loading or measuring.
    pub bring_up: Duration,
    /// Writing the flash (0 unless the image was missing or corrupt).
    pub flash_write: Duration,
    /// Illuminated integration: K × programmed exposure (bounded by the
    /// measured capture time).
    pub exposure: Duration,
    /// Capture time beyond the exposure: read-out and transfer.
    pub readout: Duration,
    /// Stopping the measurement and putting the sensor in reset.
    pub shutdown: Duration,
    /// Whole cycle (startup through shutdown).
    pub total: Duration,
    /// Time the sensor spent off (in reset) between the end of the previous
    /// cycle and the start of this one (zero for the first cycle).
    pub idle: Duration,
}

/// Result of one cycle.
#[derive(Debug, Clone)]
pub struct CycleOutput {
    /// Raw codes, (K, rows, cols).
    pub frames: Array3<u16>,
    /// Phase of each raw image, degrees.
    pub phases_deg: Vec<f64>,
    /// Illumination of each raw image (false = grey image).
    pub illuminated: Vec<bool>,
    /// Exposure actually programmed (after LSB rounding), µs.
    pub exposure_us: f64,
    /// The captured window (rows and cols as `frames`), the full array, ADC and modulation.
    pub geometry: SensorGeometry,
    /// State durations.
    pub timings: StateTimings,
    /// True if this cycle (re)wrote the flash image.
    pub flash_written: bool,
    /// Clock time at the end of the capture (for time stamps).
    pub captured_at: Duration,
}

/// Counters over the driver's life.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct DriverStats {
    /// Cycles started.
    pub cycles: u64,
    /// Cycles that failed.
    pub failed_cycles: u64,
    /// Flash image writes.
    pub flash_writes: u64,
    /// Reopens after a disconnect.
    pub reopens: u64,
    /// Frames rejected after reassembly (status line, checksum, range,
    /// order).
    pub frames_rejected: u64,
    /// Reassembly counters.
    pub reassembly: ReassemblyStats,
}

/// The sensor driver over a transport.
pub struct SensorDriver<T: UsbTransport> {
    transport: T,
    cx3: Cx3,
    cfg: DriverConfig,
    clock: Arc<dyn Clock>,
    reasm: Reassembler,
    payload: Vec<u8>,
    needs_reopen: bool,
    stats: DriverStats,
    last_end: Option<Duration>,
}

impl<T: UsbTransport> std::fmt::Debug for SensorDriver<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SensorDriver")
            .field("device", &self.transport.describe())
            .field("stats", &self.stats)
            .finish()
    }
}

fn us(v: u64) -> Duration {
    Duration::from_micros(v)
}
fn ms(v: u64) -> Duration {
    Duration::from_millis(v)
}

impl<T: UsbTransport> SensorDriver<T> {
    /// A driver; does not touch the device until the first cycle.
    pub fn new(
        transport: T,
        config: DriverConfig,
        clock: Arc<dyn Clock>,
    ) -> Result<Self, BridgeError> {
        config.validate()?;
        let cx3 = Cx3::new(config.protocol.clone())?;
        let spec = FrameSpec {
            frame_bytes: config.map.frame_bytes(usize::from(config.map.sensor.rows)),
            pad_align: config.map.sensor.pad_align,
        };
        Ok(SensorDriver {
            payload: vec![0u8; config.protocol.max_payload_bytes],
            transport,
            cx3,
            reasm: Reassembler::new(spec),
            cfg: config,
            clock,
            needs_reopen: false,
            stats: DriverStats::default(),
            last_end: None,
        })
    }

    /// The transport (e.g. the emulated device's fault log).
    pub fn transport(&self) -> &T {
        &self.transport
    }

    /// Mutable transport access.
    pub fn transport_mut(&mut self) -> &mut T {
        &mut self.transport
    }

    /// The configuration.
    pub fn config(&self) -> &DriverConfig {
        &self.cfg
    }

    /// Counters.
    pub fn stats(&self) -> DriverStats {
        let mut s = self.stats;
        s.reassembly = self.reasm.stats();
        s
    }

    /// Check a request against the map without touching the device.
    pub fn check_request(&self, req: &CycleRequest) -> Result<(), BridgeError> {
        let m = &self.cfg.map;
        let uc = m.use_case(req.mode.use_case_name())?;
        if let Some(i) = req.single_image
            && uc.only_image(usize::from(i)).is_none()
        {
            return Err(BridgeError::config(format!(
                "use case {} has no raw image {i}",
                req.mode.use_case_name()
            )));
        }
        m.exposure_to_reg(req.exposure_us)?;
        m.modulation_write(req.modulation_hz)?;
        if let Some(w) = req.row_window {
            let Some(wr) = &m.row_window else {
                return Err(BridgeError::config(format!(
                    "sensor map {} has no row window registers",
                    m.sensor.name
                )));
            };
            let end = u32::from(w.row0) + u32::from(w.rows);
            if w.rows == 0 || end > u32::from(m.sensor.rows) {
                return Err(BridgeError::config(format!(
                    "row window {}+{} outside the array's {} rows",
                    w.row0, w.rows, m.sensor.rows
                )));
            }
            if w.row0 % wr.align != 0 || w.rows % wr.align != 0 {
                return Err(BridgeError::config(format!(
                    "row window {}+{} not aligned to {} rows",
                    w.row0, w.rows, wr.align
                )));
            }
            if w.cols > 0 {
                check_columns(wr, w.col0, w.cols, m.sensor.cols, &m.sensor.name)?;
            }
            if w.step() > usize::from(wr.row_step_max()) {
                return Err(BridgeError::config(format!(
                    "row step {} beyond the sequencer's {} (sensor map {})",
                    w.step(),
                    wr.row_step_max(),
                    m.sensor.name
                )));
            }
        }
        Ok(())
    }

    /// One reading: the whole per-cycle sequence. On error the sensor is put
    /// back in reset (best effort) and the next call starts clean (reopening
    /// the device after a disconnect, clearing a stalled endpoint).
    pub fn cycle(&mut self, req: &CycleRequest) -> Result<CycleOutput, BridgeError> {
        self.check_request(req)?;
        self.stats.cycles += 1;
        let n = self.stats.cycles;
        let start = self.clock.now();
        let idle = self
            .last_end
            .map(|t| start.saturating_sub(t))
            .unwrap_or_default();
        let r = self.recover().and_then(|()| self.cycle_inner(req));
        self.last_end = Some(self.clock.now());
        match r {
            Ok(mut o) => {
                o.timings.idle = idle;
                Ok(o)
            }
            Err(e) => {
                self.stats.failed_cycles += 1;
                self.after_error(&e);
                Err(e.context_prefix(format!("cycle {n} ({})", req.mode)))
            }
        }
    }

    /// Bring-up: restart the sensor (reset low → high, wait for the chip id)
    /// and write the minimum configuration. Leaves it running (call
    /// [`power_off`](Self::power_off) afterwards).
    pub fn bring_up(&mut self) -> Result<(), BridgeError> {
        self.recover()?;
        self.restart()
            .and_then(|()| self.configure_imager())
            .inspect_err(|e| self.after_error(e))
    }

    /// Bring-up: issue the flash load command and check its status
    /// (`FlashEmpty` / `FlashCorrupt` when there is no valid image). Call
    /// after [`bring_up`](Self::bring_up).
    pub fn flash_load(&mut self) -> Result<(), BridgeError> {
        self.load_from_flash()
    }

    /// Bring-up: write the map's full configuration image to flash (erase,
    /// program, verify by read-back CRC-32), then load it. Call after
    /// [`bring_up`](Self::bring_up).
    pub fn flash_write(&mut self) -> Result<(), BridgeError> {
        self.write_flash()?;
        self.load_from_flash().ctx(|| "flash load after write")
    }

    /// Put the sensor in reset (fully off) and stop streaming.
    pub fn power_off(&mut self) -> Result<(), BridgeError> {
        self.recover()?;
        let _ = self.cx3.stream(&mut self.transport, false);
        self.cx3
            .set_reset(&mut self.transport, true)
            .ctx(|| "power off")
            .inspect_err(|e| self.after_error(e))
    }

    fn recover(&mut self) -> Result<(), BridgeError> {
        if self.needs_reopen {
            self.transport.reopen().ctx(|| "reopen after disconnect")?;
            self.stats.reopens += 1;
            self.needs_reopen = false;
        }
        Ok(())
    }

    fn after_error(&mut self, e: &BridgeError) {
        match e.kind() {
            ErrorKind::Disconnected => self.needs_reopen = true,
            _ => {
                let ep = self.cfg.protocol.bulk_in_endpoint;
                if e.kind() == ErrorKind::Stall {
                    let _ = self.transport.clear_halt(ep);
                }
                // Best effort: leave the sensor off. Errors here are
                // secondary to the one reported.
                let _ = self.cx3.stream(&mut self.transport, false);
                match self.cx3.set_reset(&mut self.transport, true) {
                    Err(e2) if e2.kind() == ErrorKind::Disconnected => self.needs_reopen = true,
                    _ => {}
                }
            }
        }
    }

    fn addr(&self) -> u8 {
        self.cfg.map.sensor.i2c_address
    }

    fn write_seq(&mut self, seq: &[RegWrite]) -> Result<(), BridgeError> {
        let addr = self.addr();
        for (reg, vals) in bursts(seq) {
            self.cx3.i2c_write(&mut self.transport, addr, reg, &vals)?;
        }
        Ok(())
    }

    fn write_reg(&mut self, reg: u16, value: u16) -> Result<(), BridgeError> {
        let addr = self.addr();
        self.cx3.i2c_write(&mut self.transport, addr, reg, &[value])
    }

    fn read_reg(&mut self, reg: u16) -> Result<u16, BridgeError> {
        let addr = self.addr();
        self.cx3.i2c_read1(&mut self.transport, addr, reg)
    }

    /// Poll `reg` until `done(value)` or `timeout`; sleeps between polls.
    fn poll_reg(
        &mut self,
        reg: u16,
        timeout: Duration,
        what: &str,
        mut done: impl FnMut(u16) -> bool,
    ) -> Result<u16, BridgeError> {
        self.poll_until(
            timeout,
            |d| {
                let v = d.read_reg(reg)?;
                Ok(if done(v) { Ok(v) } else { Err(v) })
            },
            |v| {
                BridgeError::new(
                    ErrorKind::Timeout,
                    format!("{what}: register {reg:#06x} still {v:#06x} after {timeout:?}"),
                )
            },
        )
    }

    /// Run `step` until it gives `Ok(done)`, sleeping the poll interval
    /// between attempts; after `timeout` the last `Err(pending)` becomes the
    /// error `timed_out` builds. Errors of `step` itself end the poll at once.
    fn poll_until<V, P>(
        &mut self,
        timeout: Duration,
        mut step: impl FnMut(&mut Self) -> Result<Result<V, P>, BridgeError>,
        timed_out: impl FnOnce(P) -> BridgeError,
    ) -> Result<V, BridgeError> {
        let deadline = self.clock.now() + timeout;
        let poll = us(self.cfg.timing.poll_interval_us);
        loop {
            let pending = match step(self)? {
                Ok(done) => return Ok(done),
                Err(pending) => pending,
            };
            if self.clock.now() >= deadline {
                return Err(timed_out(pending));
            }
            self.clock.sleep(poll);
        }
    }

    fn restart(&mut self) -> Result<(), BridgeError> {
        let t = self.cfg.timing.clone();
        self.cx3
            .stream(&mut self.transport, false)
            .ctx(|| "restart")?;
        self.cx3
            .set_reset(&mut self.transport, true)
            .ctx(|| "restart: reset low")?;
        self.clock.sleep(us(t.reset_low_us));
        self.cx3
            .set_reset(&mut self.transport, false)
            .ctx(|| "restart: reset high")?;
        self.clock.sleep(us(t.startup_delay_us));
        let (reg, want) = (
            self.cfg.map.sensor.chip_id_register,
            self.cfg.map.sensor.chip_id_value,
        );
        self.poll_until(
            ms(t.startup_timeout_ms),
            |d| match d.read_reg(reg) {
                Ok(v) if v == want => Ok(Ok(())),
                Ok(v) => Ok(Err(format!("chip id {v:#06x}, expected {want:#06x}"))),
                Err(e) if e.kind() == ErrorKind::Nak => {
                    Ok(Err("not answering on I2C (NAK)".to_string()))
                }
                Err(e) => Err(e.context_prefix("start-up: chip id")),
            },
            |last| {
                BridgeError::new(
                    ErrorKind::ResetStuck,
                    format!(
                        "sensor did not come out of reset within {} ms: {last}",
                        t.startup_timeout_ms
                    ),
                )
            },
        )
    }

    /// The minimum configuration (clocks, PLL) and, for a map with `[bring_up]`, the imager
    /// bring-up of the public record (`docs/bridge.md`, "Public facts"): wait for the PLL,
    /// `CTRL` then `EN`, wait for the imager. The waits sleep on the injected clock.
    fn configure_imager(&mut self) -> Result<(), BridgeError> {
        let minimum = self.cfg.map.sequences.minimum.clone();
        self.write_seq(&minimum).ctx(|| "minimum configuration")?;
        let Some(b) = self.cfg.map.bring_up.clone() else {
            return Ok(());
        };
        self.clock.sleep(us(b.pll_settle_us));
        self.write_reg(b.ctrl[0], b.ctrl[1])
            .ctx(|| "bring-up: imager CTRL")?;
        self.write_reg(b.en[0], b.en[1])
            .ctx(|| "bring-up: imager EN")?;
        self.clock.sleep(us(b.enable_settle_us));
        Ok(())
    }

    fn cycle_inner(&mut self, req: &CycleRequest) -> Result<CycleOutput, BridgeError> {
        let clock = Arc::clone(&self.clock);
        let t0 = clock.now();
        let mut timings = StateTimings::default();

        // 1. restart
        self.restart()?;
        let t1 = clock.now();
        timings.startup = t1 - t0;

        // 2. minimum configuration (PLL), the imager enabled
        self.configure_imager()?;
        timings.bring_up = clock.now() - t1;

        // 3. load from flash, write it if missing
        let mut flash_written = false;
        match self.load_from_flash() {
            Ok(()) => {}
            Err(e)
                if matches!(e.kind(), ErrorKind::FlashEmpty | ErrorKind::FlashCorrupt)
                    && self.cfg.timing.write_flash_if_missing =>
            {
                tracing::info!("{e}; writing the configuration image to flash");
                let tw = clock.now();
                self.write_flash()
                    .ctx(|| format!("writing flash after: {e}"))?;
                timings.flash_write = clock.now() - tw;
                flash_written = true;
                self.load_from_flash().ctx(|| "flash load after write")?;
            }
            Err(e) => return Err(e),
        }

        // 4. use case, exposure (overwritten by the flash image: thesis 3.5.3), window
        let map = &self.cfg.map;
        let uc = map.use_case(req.mode.use_case_name())?;
        let uc = match req.single_image {
            None => uc.clone(),
            Some(i) => uc.only_image(usize::from(i)).ok_or_else(|| {
                BridgeError::config(format!(
                    "use case {} has no raw image {i}",
                    req.mode.use_case_name()
                ))
            })?,
        };
        let k = uc.phases_deg.len();
        let exp_reg = map.exposure_to_reg(req.exposure_us)?;
        let exposure_us = f64::from(exp_reg) * map.raw.exposure_lsb_us;
        let mut regs: Vec<RegWrite> = uc.registers.clone();
        // the modulation select, written every cycle (the flash image holds the default)
        let modulation = map.modulation_write(req.modulation_hz)?;
        let modulation_hz = modulation.map_or(map.sensor.modulation_hz, |(_, f)| f);
        regs.extend(modulation.map(|(w, _)| w));
        let raw = map.raw.clone();
        regs.push([raw.count_register, k as u16]);
        for (i, ph) in uc.phases_deg.iter().enumerate() {
            let i16 = i as u16; // k <= max_count <= 64
            regs.push([raw.exposure_base + i16, exp_reg]);
            regs.push([raw.phase_base + i16, map.phase_to_reg(*ph)]);
            regs.push([raw.illumination_base + i16, u16::from(uc.illuminated(i))]);
        }
        let full_rows = usize::from(map.sensor.rows);
        let full_cols = usize::from(map.sensor.cols);
        // the rows read: every `row_step`-th of the window
        let (row0, rows) = match req.row_window {
            Some(w) => (usize::from(w.row0), w.rows_read()),
            None => (0, full_rows),
        };
        let (col0, cols) = req
            .row_window
            .map_or((0, full_cols), |w| w.columns(full_cols));
        if let Some(wr) = &map.row_window {
            let (r0, n, c0, nc) = match req.row_window {
                Some(w) => (w.row0, w.rows, w.col0, w.cols),
                None => (0, 0, 0, 0),
            };
            regs.push([wr.row0_register, r0]);
            regs.push([wr.rows_register, n]);
            if let Some((c0_reg, cols_reg)) = wr.column_registers() {
                regs.push([c0_reg, if nc == 0 { 0 } else { c0 }]);
                regs.push([cols_reg, nc]);
            }
            if let Some(step_reg) = wr.row_step_register {
                regs.push([step_reg, req.row_window.map_or(0, |w| w.row_step)]);
            }
        }
        // registers grouped by address so consecutive ones become bursts
        regs.sort_by_key(|r| r[0]);
        self.write_seq(&regs)
            .ctx(|| "use case and exposure registers")?;
        let t2 = clock.now();
        timings.config_load = t2 - t1 - timings.flash_write;

        // 5. start
        let spec = FrameSpec {
            frame_bytes: self.cfg.map.frame_bytes_of(rows, cols),
            pad_align: self.cfg.map.sensor.pad_align,
        };
        self.reasm.reset(spec);
        self.cx3.stream(&mut self.transport, true)?;
        let start = self.cfg.map.sequences.start_measurement.clone();
        self.write_seq(&start).ctx(|| "start measurement")?;

        // 6. read K frames
        let expect: Vec<(u16, bool)> = (0..k)
            .map(|i| {
                (
                    self.cfg.map.phase_to_reg(uc.phases_deg[i]),
                    uc.illuminated(i),
                )
            })
            .collect();
        let frames = self.read_frames(&expect, rows, cols, row0, exp_reg)?;
        let t3 = clock.now();
        let capture = t3 - t2;
        let exposure = Duration::from_secs_f64(exposure_us * 1e-6 * k as f64).min(capture);
        timings.exposure = exposure;
        timings.readout = capture - exposure;

        // 7. stop measurement, 8. stop sensor (reset low)
        let stop = self.cfg.map.sequences.stop_measurement.clone();
        self.write_seq(&stop).ctx(|| "stop measurement")?;
        self.cx3.stream(&mut self.transport, false)?;
        self.cx3
            .set_reset(&mut self.transport, true)
            .ctx(|| "stop sensor")?;
        let t4 = clock.now();
        timings.shutdown = t4 - t3;
        timings.total = t4 - t0;

        let map = &self.cfg.map;
        Ok(CycleOutput {
            frames,
            illuminated: (0..k).map(|i| uc.illuminated(i)).collect(),
            phases_deg: uc.phases_deg,
            exposure_us,
            geometry: SensorGeometry {
                rows,
                cols,
                roi_origin: [row0, col0],
                modulation_hz,
                ..map.sensor.geometry()
            },
            timings,
            flash_written,
            captured_at: t3,
        })
    }

    /// Read one measurement of `k` frames. A dropped or rejected frame fails
    /// the cycle (or restarts the collection while retries remain). Bounded
    /// by a clock deadline and a payload budget.
    fn read_frames(
        &mut self,
        expect: &[(u16, bool)],
        rows: usize,
        cols: usize,
        row0: usize,
        exp_reg: u16,
    ) -> Result<Array3<u16>, BridgeError> {
        let k = expect.len();
        let mut out = Array3::<u16>::zeros((k, rows, cols));
        let ep = self.cfg.protocol.bulk_in_endpoint;
        let timeout = self.cfg.protocol.bulk_timeout();
        let attempts = u64::from(self.cfg.timing.frame_retries) + 1;
        let per_frame = self.reasm.spec().frame_bytes.div_ceil(
            self.cfg
                .protocol
                .max_payload_bytes
                .saturating_sub(crate::uvc::FULL_HEADER_LEN)
                .max(1),
        ) as u64
            + 2;
        let budget = per_frame * (k as u64 + 1) * attempts * 2 + 8;
        let deadline = self.clock.now()
            + timeout * u32::try_from((k + 1) * attempts as usize).unwrap_or(u32::MAX);
        let (status_line, adc_bits) = (
            self.cfg.map.sensor.status_line,
            self.cfg.map.sensor.adc_bits,
        );
        let mut retries_left = attempts - 1;
        let mut next = 0usize;
        let mut resync = false;
        let mut last_counter: Option<u16> = None;
        for _ in 0..budget {
            if next == k {
                return Ok(out);
            }
            if self.clock.now() > deadline {
                break;
            }
            let n = self
                .transport
                .bulk_in(ep, &mut self.payload, timeout)
                .ctx(|| format!("reading raw frame {next} of {k}"))?;
            let payload = &self.payload[..n.min(self.payload.len())];
            let rejected: Option<String> = match self.reasm.push(payload) {
                Push::Pending => None,
                Push::Dropped(r) => Some(format!("frame dropped by reassembly: {r}")),
                Push::Frame(bytes) => {
                    let Some(slot) = out.index_axis_mut(ndarray::Axis(0), next).into_slice() else {
                        return Err(BridgeError::new(
                            ErrorKind::Io,
                            "frame buffer not contiguous",
                        ));
                    };
                    match decode_frame(bytes, cols, rows, adc_bits, status_line, slot) {
                        Err(e) => Some(format!(
                            "frame content rejected: {}",
                            match e {
                                ContentError::Size => "size",
                                ContentError::StatusLine => "bad status line",
                                ContentError::Checksum => "pixel checksum mismatch",
                                ContentError::PixelRange => "pixel value above ADC range",
                            }
                        )),
                        Ok(None) => {
                            next += 1;
                            None
                        }
                        Ok(Some(s)) => {
                            let idx = usize::from(s.raw_index);
                            let consecutive =
                                last_counter.is_none_or(|c| c.wrapping_add(1) == s.frame_counter);
                            if resync && idx != 0 {
                                // skipping to the start of the next measurement
                                last_counter = Some(s.frame_counter);
                                None
                            } else if idx != next || (next > 0 && !consecutive) {
                                Some(format!(
                                    "raw image {idx} (counter {}) where {next} was expected",
                                    s.frame_counter
                                ))
                            } else if usize::from(s.row0) != row0
                                || usize::from(s.rows) != rows
                                || s.exposure_reg != exp_reg
                                || expect.get(idx) != Some(&(s.phase_reg, s.illumination))
                            {
                                Some(format!(
                                    "frame settings (rows {}+{}, exposure {}) differ from the request (rows {row0}+{rows}, exposure {exp_reg})",
                                    s.row0, s.rows, s.exposure_reg
                                ))
                            } else {
                                resync = false;
                                last_counter = Some(s.frame_counter);
                                next += 1;
                                None
                            }
                        }
                    }
                }
            };
            if let Some(why) = rejected {
                self.stats.frames_rejected += 1;
                if retries_left == 0 {
                    return Err(BridgeError::new(
                        ErrorKind::CorruptFrame,
                        format!("raw frame {next} of {k}: {why}"),
                    ));
                }
                tracing::debug!("raw frame {next}: {why}; restarting collection");
                retries_left -= 1;
                next = 0;
                resync = true;
                last_counter = None;
            }
        }
        if next == k {
            return Ok(out);
        }
        Err(BridgeError::new(
            ErrorKind::Timeout,
            format!("measurement incomplete: {next} of {k} raw frames before the deadline"),
        ))
    }
}

/// A column window must lie inside the array, aligned, and the map must have its registers.
fn check_columns(
    wr: &crate::regmap::RowWindowRegs,
    col0: u16,
    cols: u16,
    full_cols: u16,
    sensor: &str,
) -> Result<(), BridgeError> {
    if wr.column_registers().is_none() {
        return Err(BridgeError::config(format!(
            "sensor map {sensor} has no column window registers"
        )));
    }
    if u32::from(col0) + u32::from(cols) > u32::from(full_cols) {
        return Err(BridgeError::config(format!(
            "column window {col0}+{cols} outside the array's {full_cols} columns"
        )));
    }
    let align = wr.col_align.max(1);
    if !col0.is_multiple_of(align) || !cols.is_multiple_of(align) {
        return Err(BridgeError::config(format!(
            "column window {col0}+{cols} not aligned to {align} columns"
        )));
    }
    Ok(())
}
