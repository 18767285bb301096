//! Layer 4: the emulated device, at the USB transfer level. It speaks the
//! CX3 protocol of [`ProtocolConfig`] on EP0, streams UVC-style payloads on
//! the bulk endpoint, and emulates the sensor behind it: a register file
//! following the [`SensorMap`], the reset pin, an SPI NOR flash (persisted to
//! a file) behind the SPI-forwarding registers, the flash load command, a
//! timing model on the injected [`Clock`], and frames synthesised from a
//! scene. Faults are injected per cycle (a cycle starts at reset release).

pub mod bringup;
pub mod config;
pub mod synth;

use std::collections::{BTreeMap, VecDeque};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use bringup::BringUpMonitor;
pub use bringup::{BusEvent, TraceEvent};
pub use config::{EmulatedConfig, FaultConfig, FaultKind, FaultSpec, FrameSource, TimingModel};
use synth::{FrameSynth, IdealSynth, ModelSynth, RawParams};

use crate::clock::Clock;
use crate::driver::SensorDriver;
use crate::error::{BridgeError, ErrorKind};
use crate::flash;
use crate::frame::{StatusLine, encode_frame};
use crate::protocol::{ProtocolConfig, status};
use crate::regmap::SensorMap;
use crate::transport::{ControlSetup, UsbTransport};
use crate::uvc::{BFH_ERR, split_frame};

/// Counters of the emulated device.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct EmulatedStats {
    /// Cycles (reset releases).
    pub cycles: u64,
    /// Faults that actually fired, by kind.
    pub faults: BTreeMap<FaultKind, u64>,
    /// Total faults fired.
    pub faults_injected: u64,
    /// Frames streamed.
    pub frames_sent: u64,
    /// Control transfers served.
    pub control_transfers: u64,
    /// Flash sector erases.
    pub flash_erases: u64,
    /// Flash page programs.
    pub flash_programs: u64,
    /// Bring-up steps out of the map's `[bring_up]` order or waits (each refused a measurement).
    pub bring_up_violations: u64,
}

#[derive(Debug, Default, Clone)]
struct CycleFaults {
    unplug_at_ctrl: Option<u32>,
    timeout_at_ctrl: Option<u32>,
    nak_at_i2c: Option<u32>,
    stall: bool,
    payload: Option<(FaultKind, u32)>,
    reset_stuck: bool,
}

#[derive(Debug)]
struct Measurement {
    raws: Vec<RawParams>,
    regs: Vec<(u16, u16, bool)>, // exposure reg, phase reg, illumination
    row0: usize,
    rows: usize,
    /// The column window: first column and count (every column: 0 and the array's width).
    col0: usize,
    cols: usize,
    /// Every `row_step`-th row of the window is read (1: every row; ours, as the map's
    /// `row_step_register`).
    row_step: usize,
    /// Modulation frequency of this measurement (Hz).
    modulation_hz: f64,
    next_raw: usize,
    frame_counter: u16,
    superframe: Vec<Vec<u16>>,
    first: bool,
    frames_in_cycle: u32,
}

/// The emulated CX3 + sensor + flash.
pub struct EmulatedDevice {
    cfg: EmulatedConfig,
    map: SensorMap,
    proto: ProtocolConfig,
    clock: Arc<dyn Clock>,
    rng: ChaCha8Rng,
    synth: Box<dyn FrameSynth>,
    regs: Vec<u16>,
    /// None: in reset. Some(t): released at t.
    released_at: Option<Duration>,
    last_status: [u8; 4],
    streaming: bool,
    meas: Option<Measurement>,
    queue: VecDeque<Vec<u8>>,
    fid: bool,
    flash: Vec<u8>,
    flash_path: Option<PathBuf>,
    wip_until: Duration,
    wel: bool,
    spi_busy_until: Duration,
    load_busy_until: Duration,
    load_status: u16,
    unplugged: bool,
    replug_at: Duration,
    halted: bool,
    faults: CycleFaults,
    ctrl_in_cycle: u32,
    i2c_in_cycle: u32,
    injected_this_cycle: Vec<FaultKind>,
    stats: EmulatedStats,
    last_meas_frames: Option<Vec<Vec<u16>>>,
    bring_up: BringUpMonitor,
}

impl std::fmt::Debug for EmulatedDevice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EmulatedDevice")
            .field("stats", &self.stats)
            .finish()
    }
}

fn disconnected() -> BridgeError {
    BridgeError::new(ErrorKind::Disconnected, "emulated device unplugged")
}

/// The emulated driver stack, assembled in this one place (the daemon's emulated backend,
/// its scene bench and soak, `tofprox device --emulated`): the device of `cfg` on `clock`
/// behind a [`SensorDriver`] configured with the device's own register map and protocol
/// ([`EmulatedConfig::driver_config`]). `seed` drives the device's noise and fault draws.
impl SensorDriver<EmulatedDevice> {
    /// Build the stack; errors keep the bridge's reason (the config key, the file).
    pub fn emulated(
        cfg: EmulatedConfig,
        clock: Arc<dyn Clock>,
        seed: u64,
    ) -> Result<Self, BridgeError> {
        let dev = EmulatedDevice::new(cfg, clock.clone(), seed)?;
        let dcfg = dev.config().driver_config()?;
        SensorDriver::new(dev, dcfg, clock)
    }
}

impl EmulatedDevice {
    /// A device from `cfg`; `seed` drives noise and fault draws
    /// (deterministic for a given seed and call sequence).
    pub fn new(cfg: EmulatedConfig, clock: Arc<dyn Clock>, seed: u64) -> Result<Self, BridgeError> {
        cfg.validate()?;
        let map = cfg.sensor_map()?;
        let geom = map.sensor.geometry();
        let synth: Box<dyn FrameSynth> = match cfg.frame_source {
            FrameSource::Ideal => Box::new(IdealSynth::new(geom, cfg.scene.clone(), seed)),
            FrameSource::Model => {
                let mut model = match &cfg.model {
                    Some(p) => tofprox_model::ModelConfig::load(p).map_err(|e| {
                        BridgeError::with_source(
                            ErrorKind::Config,
                            format!("model file {}", p.display()),
                            e,
                        )
                    })?,
                    None => tofprox_model::ModelConfig::baseline(),
                };
                if let Some(w) = &cfg.cover_window {
                    w.apply(&mut model).map_err(|e| {
                        BridgeError::with_source(ErrorKind::Config, "cover_window", e)
                    })?;
                }
                Box::new(ModelSynth::new(
                    model,
                    geom,
                    cfg.scene.clone(),
                    seed,
                    cfg.ambient_klux,
                    cfg.temperature_c,
                )?)
            }
        };
        Self::with_synth(cfg, map, clock, seed, synth)
    }

    /// A device with a custom frame source (e.g. the physical model).
    pub fn with_synth(
        cfg: EmulatedConfig,
        map: SensorMap,
        clock: Arc<dyn Clock>,
        seed: u64,
        synth: Box<dyn FrameSynth>,
    ) -> Result<Self, BridgeError> {
        cfg.validate()?;
        map.validate()?;
        let size = cfg.flash_size_bytes as usize;
        let flash = match &cfg.flash_file {
            Some(p) if p.exists() => {
                // bounded: one byte more than the flash is already the wrong size
                let data =
                    tofprox_format::limits::read_bounded(p, size as u64, None).map_err(|e| {
                        BridgeError::with_source(ErrorKind::Io, format!("read flash file {e}"), e)
                    })?;
                if data.len() != size {
                    return Err(BridgeError::config(format!(
                        "flash file {} has {} bytes, flash_size_bytes is {size}",
                        p.display(),
                        data.len()
                    )));
                }
                data
            }
            _ => vec![0xFF; size],
        };
        let d = EmulatedDevice {
            bring_up: BringUpMonitor::new(map.bring_up.clone(), &map.sequences.minimum),
            proto: cfg.protocol.clone(),
            flash_path: cfg.flash_file.clone(),
            cfg,
            map,
            clock,
            rng: ChaCha8Rng::seed_from_u64(seed),
            synth,
            regs: vec![0; 65536],
            released_at: None,
            last_status: [0; 4],
            streaming: false,
            meas: None,
            queue: VecDeque::new(),
            fid: false,
            flash,
            wip_until: Duration::ZERO,
            wel: false,
            spi_busy_until: Duration::ZERO,
            load_busy_until: Duration::ZERO,
            load_status: 0,
            unplugged: false,
            replug_at: Duration::ZERO,
            halted: false,
            faults: CycleFaults::default(),
            ctrl_in_cycle: 0,
            i2c_in_cycle: 0,
            injected_this_cycle: Vec::new(),
            stats: EmulatedStats::default(),
            last_meas_frames: None,
        };
        d.persist_flash()?;
        Ok(d)
    }

    /// Counters.
    pub fn stats(&self) -> &EmulatedStats {
        &self.stats
    }

    /// Faults that fired since the last reset release.
    pub fn injected_this_cycle(&self) -> &[FaultKind] {
        &self.injected_this_cycle
    }

    /// Change the fault switches (takes effect at the next cycle).
    pub fn set_faults(&mut self, faults: FaultConfig) {
        self.cfg.faults = faults;
    }

    /// Change the scene of the built-in synthesiser.
    pub fn config(&self) -> &EmulatedConfig {
        &self.cfg
    }

    /// The clean pixel data (before any injected damage) of the most recent
    /// measurement: `[k]` = rows × cols codes of raw image k (tests compare
    /// delivered frames against it).
    pub fn last_superframe(&self) -> Option<&[Vec<u16>]> {
        self.last_meas_frames.as_deref()
    }

    /// Register value (tests, diagnostics).
    pub fn register(&self, reg: u16) -> u16 {
        self.regs[usize::from(reg)]
    }

    /// What reached the sensor in the current cycle: from the last reset-low command before
    /// the reset release, every reset command and register write with its clock time.
    pub fn bus_trace(&self) -> &[TraceEvent] {
        self.bring_up.trace()
    }

    /// Why the sensor refused to measure in the current cycle: bring-up steps out of the
    /// order or waits of the map's `[bring_up]` (empty: none).
    pub fn bring_up_violations(&self) -> &[String] {
        self.bring_up.violations()
    }

    /// Whether the sensor is held in reset.
    pub fn in_reset(&self) -> bool {
        self.released_at.is_none()
    }

    fn persist_flash(&self) -> Result<(), BridgeError> {
        if let Some(p) = &self.flash_path {
            tofprox_format::write_atomic(p, &self.flash).map_err(|e| {
                BridgeError::with_source(ErrorKind::Io, format!("write flash file {e}"), e)
            })?;
        }
        Ok(())
    }

    fn fire(&mut self, k: FaultKind) {
        self.injected_this_cycle.push(k);
        self.stats.faults_injected += 1;
        *self.stats.faults.entry(k).or_default() += 1;
    }

    fn roll(&mut self, k: FaultKind) -> bool {
        let spec = self.cfg.faults.spec(k);
        let at = spec.at_cycles.contains(&self.stats.cycles);
        let p = spec.probability;
        at || (p > 0.0 && self.rng.random_bool(p))
    }

    /// Reset released: a new cycle; draw this cycle's faults.
    fn new_cycle(&mut self) -> Result<(), BridgeError> {
        self.stats.cycles += 1;
        self.injected_this_cycle.clear();
        self.ctrl_in_cycle = 0;
        self.i2c_in_cycle = 0;
        let mut f = CycleFaults::default();
        if self.roll(FaultKind::Unplug) {
            f.unplug_at_ctrl = Some(self.rng.random_range(1..16));
        }
        if self.roll(FaultKind::ControlTimeout) {
            f.timeout_at_ctrl = Some(self.rng.random_range(1..16));
        }
        if self.roll(FaultKind::I2cNak) {
            // (index 1 is the start-up chip-id poll, which tolerates NAKs)
            f.nak_at_i2c = Some(self.rng.random_range(2..12));
        }
        f.stall = self.roll(FaultKind::Stall);
        for k in [
            FaultKind::CorruptPayload,
            FaultKind::ShortPayload,
            FaultKind::OutOfOrder,
        ] {
            if f.payload.is_none() && self.roll(k) {
                f.payload = Some((k, self.rng.random()));
            }
        }
        if self.roll(FaultKind::ResetStuck) {
            f.reset_stuck = true;
            self.fire(FaultKind::ResetStuck);
        }
        let base = self.map.flash.image_address as usize;
        if self.roll(FaultKind::FlashEmpty) {
            let end = (base + self.map.spi.sector_bytes as usize).min(self.flash.len());
            if let Some(s) = self.flash.get_mut(base..end) {
                s.fill(0xFF);
            }
            self.fire(FaultKind::FlashEmpty);
            self.persist_flash()?;
        }
        if self.roll(FaultKind::FlashCorrupt) {
            let len = flash::image_len(self.flash.get(base..).unwrap_or(&[])).unwrap_or(64);
            let i = base
                + self
                    .rng
                    .random_range(flash::HEADER_BYTES..len.max(flash::HEADER_BYTES + 1));
            if let Some(b) = self.flash.get_mut(i) {
                *b ^= 1 << self.rng.random_range(0..8);
            }
            self.fire(FaultKind::FlashCorrupt);
            self.persist_flash()?;
        }
        self.faults = f;
        Ok(())
    }

    fn enter_reset(&mut self) {
        if self.released_at.is_some() {
            self.bring_up.entered_reset(self.clock.now());
        }
        self.released_at = None;
        self.regs.fill(0);
        self.meas = None;
        self.queue.clear();
        self.load_status = 0;
        self.wel = false;
    }

    fn alive(&self) -> bool {
        match self.released_at {
            Some(t) => {
                !self.faults.reset_stuck
                    && self.clock.now()
                        >= t + Duration::from_secs_f64(self.cfg.timing.startup_us * 1e-6)
            }
            None => false,
        }
    }

    /// Common entry of every control transfer: unplug / timeout faults.
    fn control_gate(&mut self, timeout: Duration) -> Result<(), BridgeError> {
        if self.unplugged {
            return Err(disconnected());
        }
        self.stats.control_transfers += 1;
        if self.released_at.is_some() {
            self.ctrl_in_cycle += 1;
            if self.faults.unplug_at_ctrl == Some(self.ctrl_in_cycle) {
                self.faults.unplug_at_ctrl = None;
                self.fire(FaultKind::Unplug);
                self.unplugged = true;
                self.replug_at = self.clock.now()
                    + Duration::from_secs_f64(self.cfg.timing.replug_after_ms * 1e-3);
                self.enter_reset();
                self.streaming = false;
                return Err(disconnected());
            }
            if self.faults.timeout_at_ctrl == Some(self.ctrl_in_cycle) {
                self.faults.timeout_at_ctrl = None;
                self.fire(FaultKind::ControlTimeout);
                self.clock.sleep(timeout);
                return Err(BridgeError::new(
                    ErrorKind::Timeout,
                    "control transfer timed out",
                ));
            }
        }
        Ok(())
    }

    fn stall_ep0(&mut self, code: u8, addr: u8, reg: u16) -> BridgeError {
        let r = reg.to_be_bytes();
        self.last_status = [code, addr, r[0], r[1]];
        BridgeError::new(ErrorKind::Stall, "control request stalled")
    }

    /// I2C gate: the sensor must be alive, at our address, and not NAK by
    /// fault.
    fn i2c_gate(&mut self, addr: u8, reg: u16) -> Result<(), BridgeError> {
        self.i2c_in_cycle += 1;
        if addr != self.map.sensor.i2c_address || !self.alive() {
            return Err(self.stall_ep0(status::I2C_NAK, addr, reg));
        }
        if self.faults.nak_at_i2c == Some(self.i2c_in_cycle) {
            self.faults.nak_at_i2c = None;
            self.fire(FaultKind::I2cNak);
            return Err(self.stall_ep0(status::I2C_NAK, addr, reg));
        }
        self.last_status = [status::OK, addr, 0, 0];
        Ok(())
    }

    fn read_reg(&self, reg: u16) -> u16 {
        let now = self.clock.now();
        if reg == self.map.sensor.chip_id_register {
            return self.map.sensor.chip_id_value;
        }
        if reg == self.map.flash.status_register {
            return if now < self.load_busy_until {
                self.map.flash.status_busy
            } else {
                self.load_status
            };
        }
        if reg == self.map.spi.busy_register {
            return u16::from(now < self.spi_busy_until);
        }
        self.regs[usize::from(reg)]
    }

    fn write_reg(&mut self, reg: u16, value: u16) -> Result<(), BridgeError> {
        self.regs[usize::from(reg)] = value;
        self.bring_up.write(self.clock.now(), reg, value);
        let m = &self.map;
        let is_load = reg == m.flash.load_register && value == m.flash.load_value;
        let is_spi = reg == m.spi.trigger_register && value & 1 == 1;
        let start = m.sequences.start_measurement.last().copied();
        let stop = m.sequences.stop_measurement.last().copied();
        if is_load {
            self.flash_load();
        } else if is_spi {
            self.spi_transfer()?;
        }
        if start == Some([reg, value]) {
            self.start_measurement();
        } else if stop == Some([reg, value]) {
            self.meas = None;
            self.queue.clear();
        }
        Ok(())
    }

    fn flash_load(&mut self) {
        let base = self.map.flash.image_address as usize;
        let t = &self.cfg.timing;
        let (status, n) = match flash::parse_image(self.flash.get(base..).unwrap_or(&[])) {
            Ok(pairs) => {
                for [r, v] in &pairs {
                    self.regs[usize::from(*r)] = *v;
                }
                (self.map.flash.status_ok, pairs.len())
            }
            Err(flash::ImageError::Empty) => (self.map.flash.status_empty, 0),
            Err(flash::ImageError::Corrupt) => (self.map.flash.status_corrupt, 0),
        };
        self.load_status = status;
        self.load_busy_until = self.clock.now()
            + Duration::from_secs_f64(
                (t.config_load_base_us + t.config_load_per_register_us * n as f64) * 1e-6,
            );
    }

    fn spi_transfer(&mut self) -> Result<(), BridgeError> {
        let s = self.map.spi.clone();
        let len =
            usize::from(self.regs[usize::from(s.length_register)]).min(usize::from(s.window_bytes));
        let mut tx = Vec::with_capacity(len + 1);
        for i in 0..len.div_ceil(2) {
            let w = self.regs[usize::from(s.tx_base) + i];
            tx.extend_from_slice(&w.to_be_bytes());
        }
        tx.truncate(len);
        let mut rx = vec![0xFFu8; len];
        let now = self.clock.now();
        let busy = now < self.wip_until;
        let addr = |tx: &[u8]| -> usize {
            (usize::from(tx.get(1).copied().unwrap_or(0)) << 16)
                | (usize::from(tx.get(2).copied().unwrap_or(0)) << 8)
                | usize::from(tx.get(3).copied().unwrap_or(0))
        };
        let mut persist = false;
        match tx.first().copied() {
            Some(flash::CMD_RDSR) => {
                let sr =
                    if busy { flash::SR_WIP } else { 0 } | if self.wel { flash::SR_WEL } else { 0 };
                for b in rx.iter_mut().skip(1) {
                    *b = sr;
                }
            }
            Some(flash::CMD_WREN) if !busy => self.wel = true,
            Some(flash::CMD_READ) if !busy && len >= 4 => {
                let a = addr(&tx);
                for (i, b) in rx.iter_mut().enumerate().skip(4) {
                    *b = self.flash.get(a + i - 4).copied().unwrap_or(0xFF);
                }
            }
            Some(flash::CMD_SE) if !busy && self.wel && len >= 4 => {
                let sec = s.sector_bytes as usize;
                let a = addr(&tx) / sec * sec;
                if let Some(x) = self.flash.get_mut(a..a + sec) {
                    x.fill(0xFF);
                }
                self.wel = false;
                self.wip_until =
                    now + Duration::from_secs_f64(self.cfg.timing.flash_sector_erase_us * 1e-6);
                self.stats.flash_erases += 1;
                persist = true;
            }
            Some(flash::CMD_PP) if !busy && self.wel && len >= 4 => {
                let page = s.page_bytes as usize;
                let a = addr(&tx);
                let page_start = a / page * page;
                for (i, &b) in tx[4..].iter().enumerate() {
                    // wraps within the page like real SPI NOR
                    let at = page_start + (a - page_start + i) % page;
                    if let Some(x) = self.flash.get_mut(at) {
                        *x &= b;
                    }
                }
                self.wel = false;
                self.wip_until =
                    now + Duration::from_secs_f64(self.cfg.timing.flash_page_program_us * 1e-6);
                self.stats.flash_programs += 1;
                persist = true;
            }
            _ => {}
        }
        for (i, c) in rx.chunks(2).enumerate() {
            let w = u16::from_be_bytes([c[0], c.get(1).copied().unwrap_or(0xFF)]);
            self.regs[usize::from(s.rx_base) + i] = w;
        }
        self.spi_busy_until =
            now + Duration::from_secs_f64(len as f64 * 8.0 / self.cfg.timing.spi_bit_rate_hz);
        if persist {
            self.persist_flash()?;
        }
        Ok(())
    }

    fn min_config_ok(&self) -> bool {
        self.map
            .sequences
            .minimum
            .iter()
            .all(|[r, v]| self.regs[usize::from(*r)] == *v)
    }

    fn start_measurement(&mut self) {
        self.queue.clear();
        self.meas = None;
        if !self.min_config_ok() || self.load_status != self.map.flash.status_ok {
            tracing::debug!(
                "emulated sensor: start ignored (minimum config or flash load missing)"
            );
            return;
        }
        if !self.bring_up.may_measure(self.clock.now()) {
            self.stats.bring_up_violations += 1;
            return;
        }
        let raw = &self.map.raw;
        let k = usize::from(self.regs[usize::from(raw.count_register)]);
        if k == 0 || k > usize::from(raw.max_count) {
            return;
        }
        let full = usize::from(self.map.sensor.rows);
        let (row0, rows) = match &self.map.row_window {
            Some(w) => {
                let n = usize::from(self.regs[usize::from(w.rows_register)]);
                let r0 = usize::from(self.regs[usize::from(w.row0_register)]);
                if n == 0 {
                    (0, full)
                } else if r0 + n > full {
                    return;
                } else {
                    (r0, n)
                }
            }
            None => (0, full),
        };
        let full_cols = usize::from(self.map.sensor.cols);
        let columns = self
            .map
            .row_window
            .as_ref()
            .and_then(|w| w.column_registers());
        let (col0, cols) = match columns {
            Some((c0_reg, n_reg)) => {
                let n = usize::from(self.regs[usize::from(n_reg)]);
                let c0 = usize::from(self.regs[usize::from(c0_reg)]);
                if n == 0 {
                    (0, full_cols)
                } else if c0 + n > full_cols {
                    return;
                } else {
                    (c0, n)
                }
            }
            None => (0, full_cols),
        };
        let row_step = match self.map.row_window.as_ref() {
            Some(w) => match w.row_step_register {
                Some(reg) => usize::from(self.regs[usize::from(reg)].max(1)),
                None => 1,
            },
            None => 1,
        };
        if row_step > usize::from(self.map.row_window.as_ref().map_or(1, |w| w.row_step_max())) {
            return;
        }
        let mut raws = Vec::with_capacity(k);
        let mut regs = Vec::with_capacity(k);
        for i in 0..k as u16 {
            let e = self.regs[usize::from(raw.exposure_base + i)];
            let p = self.regs[usize::from(raw.phase_base + i)];
            let il = self.regs[usize::from(raw.illumination_base + i)] & 1 == 1;
            raws.push(RawParams {
                exposure_us: f64::from(e) * raw.exposure_lsb_us,
                phase_deg: (f64::from(p) * raw.phase_lsb_deg).rem_euclid(360.0),
                illuminated: il,
            });
            regs.push((e, p, il));
        }
        let modulation_hz = self
            .map
            .modulation
            .as_ref()
            .map(|m| f64::from(self.regs[usize::from(m.register)]) * m.lsb_hz)
            .filter(|&f| f > 0.0)
            .unwrap_or(self.map.sensor.modulation_hz);
        self.meas = Some(Measurement {
            raws,
            regs,
            row0,
            rows,
            col0,
            cols,
            row_step,
            modulation_hz,
            next_raw: 0,
            frame_counter: 0,
            superframe: Vec::new(),
            first: true,
            frames_in_cycle: 0,
        });
    }

    /// Produce the next frame's payloads (sleeping the exposure and read-out
    /// time on the clock).
    fn produce_frame(&mut self) -> Result<(), BridgeError> {
        let t = self.cfg.timing.clone();
        let full_cols = usize::from(self.map.sensor.cols);
        let status_line = self.map.sensor.status_line;
        let Some(m) = self.meas.as_mut() else {
            return Ok(());
        };
        let i = m.next_raw;
        let raw = m.raws[i];
        // a row's conversions are its columns read (ours: time ∝ columns)
        let row_us = t.readout_per_row_us * m.cols as f64 / full_cols.max(1) as f64;
        let rows_read = m.rows.div_ceil(m.row_step);
        let mut wait_us = raw.exposure_us + row_us * rows_read as f64;
        if m.first {
            wait_us += t.measurement_start_us;
            m.first = false;
        }
        self.clock.sleep(Duration::from_secs_f64(wait_us * 1e-6));
        if i == 0 {
            let t_s = self.clock.now().as_secs_f64();
            self.synth.superframe(
                t_s,
                &m.raws,
                (m.row0, m.rows),
                m.modulation_hz,
                &mut m.superframe,
            )?;
            self.last_meas_frames = Some(m.superframe.clone());
        }
        let (e, p, il) = m.regs[i];
        let st = status_line.then_some(StatusLine {
            frame_counter: m.frame_counter,
            raw_index: i as u16,
            row0: m.row0 as u16,
            rows: rows_read as u16,
            exposure_reg: e,
            phase_reg: p,
            illumination: il,
            crc32: 0,
        });
        let mut bytes = if m.cols == full_cols && m.row_step == 1 {
            encode_frame(&m.superframe[i], full_cols, st)
        } else {
            let window: Vec<u16> = m.superframe[i]
                .chunks_exact(full_cols)
                .step_by(m.row_step)
                .flat_map(|row| row[m.col0..m.col0 + m.cols].iter().copied())
                .collect();
            encode_frame(&window, m.cols, st)
        };
        let align = self.map.sensor.pad_align;
        bytes.resize(bytes.len().div_ceil(align) * align, 0);
        m.frame_counter = m.frame_counter.wrapping_add(1);
        m.next_raw = (i + 1) % m.raws.len();
        let frame_no = m.frames_in_cycle;
        m.frames_in_cycle += 1;
        let k = m.raws.len() as u32;
        self.fid = !self.fid;
        let pts = (self.clock.now().as_micros() & 0xFFFF_FFFF) as u32;
        let mut payloads = split_frame(&bytes, self.fid, pts, self.proto.max_payload_bytes);
        if let Some((kind, pick)) = self.faults.payload
            && frame_no == pick % k
        {
            self.faults.payload = None;
            self.damage(kind, &mut payloads);
            self.fire(kind);
        }
        self.stats.frames_sent += 1;
        self.queue.extend(payloads);
        Ok(())
    }

    fn damage(&mut self, kind: FaultKind, p: &mut Vec<Vec<u8>>) {
        let n = p.len();
        let j = self.rng.random_range(0..n);
        match kind {
            FaultKind::CorruptPayload => match self.rng.random_range(0..3) {
                0 => p[j][1] |= BFH_ERR,
                1 => p[j][0] = 0xFF,
                _ => {
                    let len = p[j].len();
                    if len > 12 {
                        let at = self.rng.random_range(12..len);
                        p[j][at] ^= 1 << self.rng.random_range(0..8);
                    } else {
                        p[j][1] |= BFH_ERR;
                    }
                }
            },
            FaultKind::ShortPayload => {
                let len = p[j].len();
                let cut = self
                    .rng
                    .random_range(2..=(len - 12).max(2))
                    .min(len - 12)
                    .max(1);
                p[j].truncate(len - cut);
            }
            FaultKind::OutOfOrder => {
                if n >= 2 {
                    let a = self.rng.random_range(0..n - 1);
                    p.swap(a, a + 1);
                } else {
                    // one payload per frame: deliver it twice (duplicate)
                    let dup = p[0].clone();
                    p.push(dup);
                }
            }
            _ => {}
        }
    }
}

impl UsbTransport for EmulatedDevice {
    fn control_in(
        &mut self,
        s: ControlSetup,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError> {
        self.control_gate(timeout)?;
        if !s.is_in() {
            return Err(self.stall_ep0(status::BAD_REQUEST, 0, 0));
        }
        if s.request == self.proto.req_status {
            let n = buf.len().min(4);
            buf[..n].copy_from_slice(&self.last_status[..n]);
            return Ok(n);
        }
        if s.request == self.proto.req_i2c_read {
            let addr = u8::try_from(s.value).unwrap_or(0xFF);
            let reg = s.index;
            if !buf.len().is_multiple_of(2) || buf.is_empty() {
                return Err(self.stall_ep0(status::BAD_REQUEST, addr, reg));
            }
            self.i2c_gate(addr, reg)?;
            for (i, c) in buf.chunks_exact_mut(2).enumerate() {
                let r = reg.wrapping_add(i as u16);
                c.copy_from_slice(&self.read_reg(r).to_be_bytes());
            }
            return Ok(buf.len());
        }
        Err(self.stall_ep0(status::BAD_REQUEST, 0, 0))
    }

    fn control_out(
        &mut self,
        s: ControlSetup,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError> {
        self.control_gate(timeout)?;
        if s.is_in() {
            return Err(self.stall_ep0(status::BAD_REQUEST, 0, 0));
        }
        let p = &self.proto;
        if s.request == p.req_i2c_write {
            let addr = u8::try_from(s.value).unwrap_or(0xFF);
            let reg = s.index;
            if data.is_empty()
                || !data.len().is_multiple_of(2)
                || usize::from(reg) + data.len() / 2 > 65536
            {
                return Err(self.stall_ep0(status::BAD_REQUEST, addr, reg));
            }
            self.i2c_gate(addr, reg)?;
            for (i, c) in data.chunks_exact(2).enumerate() {
                self.write_reg(reg + i as u16, u16::from_be_bytes([c[0], c[1]]))?;
            }
            return Ok(data.len());
        }
        if s.request == p.req_gpio {
            let high = s.index != 0;
            if s.value == p.gpio_reset {
                if !high {
                    self.bring_up.reset_commanded(self.clock.now());
                }
                match (self.released_at.is_some(), high) {
                    (false, true) => {
                        self.released_at = Some(self.clock.now());
                        self.bring_up.released(self.clock.now());
                        self.new_cycle()?;
                    }
                    (true, false) => self.enter_reset(),
                    _ => {}
                }
            } else if s.value != p.gpio_standby {
                return Err(self.stall_ep0(status::BAD_REQUEST, 0, s.value));
            }
            self.last_status = [status::OK, 0, 0, 0];
            return Ok(0);
        }
        if s.request == p.req_stream_start {
            self.streaming = true;
            return Ok(0);
        }
        if s.request == p.req_stream_stop {
            self.streaming = false;
            self.queue.clear();
            return Ok(0);
        }
        Err(self.stall_ep0(status::BAD_REQUEST, 0, 0))
    }

    fn bulk_in(&mut self, ep: u8, buf: &mut [u8], timeout: Duration) -> Result<usize, BridgeError> {
        if self.unplugged {
            return Err(disconnected());
        }
        if ep != self.proto.bulk_in_endpoint {
            return Err(BridgeError::new(
                ErrorKind::Io,
                format!("no endpoint {ep:#04x}"),
            ));
        }
        if self.faults.stall {
            self.faults.stall = false;
            self.halted = true;
            self.fire(FaultKind::Stall);
        }
        if self.halted {
            return Err(BridgeError::new(
                ErrorKind::Stall,
                format!("endpoint {ep:#04x} halted"),
            ));
        }
        if self.queue.is_empty() && self.streaming && self.meas.is_some() {
            self.produce_frame()?;
        }
        match self.queue.pop_front() {
            Some(p) => {
                if p.len() > buf.len() {
                    return Err(BridgeError::new(
                        ErrorKind::Io,
                        format!(
                            "babble: payload of {} bytes into a {}-byte buffer",
                            p.len(),
                            buf.len()
                        ),
                    ));
                }
                buf[..p.len()].copy_from_slice(&p);
                Ok(p.len())
            }
            None => {
                self.clock.sleep(timeout);
                Err(BridgeError::new(
                    ErrorKind::Timeout,
                    format!("bulk IN {ep:#04x}: no data"),
                ))
            }
        }
    }

    fn bulk_out(&mut self, ep: u8, _data: &[u8], _timeout: Duration) -> Result<usize, BridgeError> {
        if self.unplugged {
            return Err(disconnected());
        }
        Err(BridgeError::new(
            ErrorKind::Stall,
            format!("no bulk OUT endpoint {ep:#04x}"),
        ))
    }

    fn clear_halt(&mut self, _ep: u8) -> Result<(), BridgeError> {
        if self.unplugged {
            return Err(disconnected());
        }
        self.halted = false;
        Ok(())
    }

    fn reopen(&mut self) -> Result<(), BridgeError> {
        if self.unplugged {
            if self.clock.now() < self.replug_at {
                return Err(BridgeError::new(
                    ErrorKind::NotFound,
                    "emulated device not replugged yet",
                ));
            }
            self.unplugged = false;
            self.halted = false;
            self.streaming = false;
            self.enter_reset();
        }
        Ok(())
    }

    fn describe(&self) -> String {
        format!(
            "emulated CX3 bridge with {} ({}x{})",
            self.map.sensor.name, self.map.sensor.cols, self.map.sensor.rows
        )
    }
}
