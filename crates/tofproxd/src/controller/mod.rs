//! The loop's brain, free of I/O timing: one [`Controller::step`] = one reading
//! (thesis fig. 3.23 / listing 4.11: restart → flash → exposure → capture →
//! process → stop), then the decisions for the next one, each taken by its own
//! unit in [`crate::policy`] — mode ([`AmbientSwitch`]: 2-phase ↔ 4-phase on
//! background light), exposure ([`AutoExposure`], eye-safe bounded), rate
//! ([`AdaptiveRate`]), rows read ([`ReadoutWindow`]) and the sleep until the next
//! cycle with its energy ([`EnergyAccount`]). The controller composes them, runs
//! the pipeline and the detector and reports in the [`crate::hub`] vocabulary. The
//! daemon thread and `tofprox soak` both drive it.
//!
//! One cycle, in the order its stages run (each a file of this module):
//! [`Controller::step`] here (the request, the capture, its time) → `probe` (the presence
//! probe instead of a full reading, when due) → `capture` (the capture's shape; every code on
//! a rail?) → `rails` (saturation as evidence) or `measure` (the frame through the one
//! pipeline of its mode, once, and everything read from it: implausible near, the second
//! frequency, near/far; `slots` keeps the per-window pipelines and detector) → `window` (the
//! cover window: an object pressed on it is near, else its online estimate) → `probe` (the
//! reference for the next probe) → `decide` (the policy units: the next cycle) → `report`
//! (the published status). `hold`: Near held over cycles without a reading, bounded.

use std::time::Duration;

use ndarray::s;
use tofprox_core::Algorithm;
use tofprox_core::SensorGeometry;
use tofprox_core::crosstalk::CrosstalkStatus;
use tofprox_core::phasor::distance_to_phase_rad;
use tofprox_core::pipeline::Calibration;
use tofprox_core::proximity::{NearFarDetector, Roi};
use tofprox_core::radiometry::AmplitudeScale;

use crate::boottime::boottime_ns;
use crate::config::{Config, Mode};
use crate::cputime::thread_cpu;
use crate::energy::EnergyMeter;
use crate::hub::{DepthMessage, Reason, State, StatusUpdate};
use crate::policy::probe::PresenceProbe;
use crate::policy::{
    AdaptiveRate, AmbientSwitch, AutoExposure, CycleObservation, EnergyAccount, Pacing,
    RailsDecision, ReadoutObservation, ReadoutWindow, SaturationCheck, SecondFrequency,
    WindowTracker, decision_exposure_us, stepped_roi,
};
use crate::source::{CycleRequest, FrameSource, RawCycle, SourceError, SourceErrorKind};

mod capture;
mod decide;
mod hold;
mod measure;
mod probe;
mod rails;
mod report;
mod slots;
mod stepped;
#[cfg(test)]
mod tests;
mod window;

use capture::{check_cycle, rails_only};
use hold::{RecentCycles, SinceValid};
use probe::LastFull;
use slots::{PipelineSlot, detector_config};
use stepped::{Calibrations, on_stepped_array};

/// Full-frame calibrations per mode (cropped to the read-out window on use).
#[derive(Debug, Clone, Default)]
pub struct ModeCalibrations {
    /// For 2-phase processing.
    pub two_phase: Calibration,
    /// For 4-phase processing.
    pub four_phase: Calibration,
    /// Amplitude scale of the `1/d²` law (thesis 2.2.1); `None`: the nominal scale of the config.
    pub amplitude: Option<AmplitudeScale>,
}

impl ModeCalibrations {
    /// The calibration of `mode`.
    pub fn for_mode(&self, mode: Mode) -> &Calibration {
        match mode {
            Mode::TwoPhase => &self.two_phase,
            Mode::FourPhase => &self.four_phase,
        }
    }
}

/// `DistanceMm` of a valid reading with nothing in range (no target, or only returns no real
/// target near the sensor could give): the largest value, so `DistanceMm < threshold` is false.
pub const DISTANCE_BEYOND_RANGE_MM: u32 = u32::MAX;

/// Errors building a controller.
#[derive(Debug, thiserror::Error)]
pub enum ControllerError {
    /// A calibration does not fit its mode.
    #[error(
        "calibration for {mode} has a wiggling LUT for {lut}: refused (calibration is keyed to the mode)"
    )]
    CalibrationMode {
        /// The mode it was given for.
        mode: &'static str,
        /// The LUT's algorithm.
        lut: &'static str,
    },
    /// The configured ROI does not lie inside the sensor (no silent fallback to another ROI).
    #[error(
        "proximity.roi = {roi:?} ([row0, col0, rows, cols]) does not lie inside the {full_rows}x{full_cols} sensor"
    )]
    RoiOutsideSensor {
        /// The configured ROI.
        roi: [usize; 4],
        /// Rows of the sensor.
        full_rows: usize,
        /// Columns of the sensor.
        full_cols: usize,
    },
    /// The core refused a parameter.
    #[error("processing setup: {0}")]
    Core(#[from] tofprox_core::CoreError),
}

/// Result of one step.
#[derive(Debug, Clone, Default)]
pub struct StepOutcome {
    /// Status fragment for the publisher.
    pub update: StatusUpdate,
    /// Depth frame (only when asked for).
    pub depth: Option<DepthMessage>,
    /// Sleep before the next cycle.
    pub sleep: Duration,
    /// The cycle failed with this error.
    pub error: Option<SourceError>,
    /// Near as published after this step.
    pub near: bool,
    /// Distance of this reading, if valid.
    pub distance_mm: Option<u32>,
    /// This step produced a valid reading.
    pub valid: bool,
    /// The source has no more data (replay end).
    pub end_of_data: bool,
    /// Mode used for this cycle's capture.
    pub captured_mode: Option<Mode>,
}

/// The loop controller.
pub struct Controller<S: FrameSource> {
    cfg: Config,
    source: S,
    /// The calibration sets: the array's and, where readings skip rows, the stepped array's.
    calib: Calibrations,
    /// A reading reads every `read_step`-th row (`readout.row_step` where the source can;
    /// 1: every row; a depth frame always reads every row).
    read_step: usize,
    /// The presence probe reads every `probe_step`-th row of the array (`Config::row_steps`).
    probe_step: usize,
    /// The pipelines (2-phase, 4-phase), each for the window it was built for.
    pipes: [PipelineSlot; 2],
    /// The second frequency's pipelines (2-phase, 4-phase).
    pipes_f2: [PipelineSlot; 2],
    detector: Option<(SensorGeometry, NearFarDetector)>,
    /// Amplitude scale cropped to the current read-out window.
    amp_scale: Option<(SensorGeometry, ndarray::Array2<f32>)>,
    /// Processing mode (2 ↔ 4-phase on background light).
    ambient: AmbientSwitch,
    exposure: AutoExposure,
    rate: AdaptiveRate,
    readout: ReadoutWindow,
    energy: EnergyAccount,
    /// Saturation is evidence: all-rails frames that are the sensor's own return read near.
    saturation: SaturationCheck,
    /// Confirmation of dim near candidates at a second modulation frequency.
    second: SecondFrequency,
    consecutive_failures: u32,
    /// Time since the last valid reading, for the bound on holding Near across cycles
    /// without one.
    since_valid: SinceValid,
    /// Time from the last reading with a near candidate to the last valid reading (arms the
    /// object-on-the-glass rule within `loop.near_hold_ms`).
    candidate_age: Option<Duration>,
    /// The sleep scheduled after the previous step.
    last_sleep: Duration,
    /// How long the last cycles took (the hold bound allows for the next one).
    recent: RecentCycles,
    /// The presence probe while far and still (`policy::probe`).
    probe: PresenceProbe,
    /// `K` at the weak end of the ROI (LSB·m²/µs): the probe's threshold.
    k_floor: f64,
    /// The measured phase of targets from zero distance to `near_mm` (rad): the probe image.
    near_phase_rad: (f64, f64),
    /// The last full reading, as a probe that saw no change publishes it again.
    last_full: Option<LastFull>,
    /// The loop thread's CPU time when this cycle's frames were in, and the part of it spent
    /// since inside the source (a second capture: the bridge's, not the reading's work).
    cpu_at_capture: Duration,
    source_cpu: Duration,
    near: bool,
    running: bool,
    last_error: String,
    /// The cover window's crosstalk, estimated online and compensated (`policy::window`).
    window: WindowTracker,
    state: State,
    prev_state: State,
    /// Last ambient indicator (LSB).
    pub ambient_lsb: Option<f32>,
}

/// ROI in full-frame coordinates.
pub fn full_roi(cfg: &Config, full_rows: usize, full_cols: usize) -> Roi {
    match cfg.proximity.roi {
        Some([row0, col0, rows, cols]) => Roi {
            row0,
            col0,
            rows,
            cols,
        }
        .resolve(full_rows, full_cols),
        None => Roi::centered(full_rows, full_cols, 0.5),
    }
}

/// The sensor's `K` at the weak end of the ROI (its 10th percentile; the config's nominal
/// scale without an amplitude part), LSB·m²/µs: the decision's exposure and the probe's
/// threshold rest on it.
fn roi_k_floor(
    cfg: &Config,
    calib: &ModeCalibrations,
    (full_rows, full_cols): (usize, usize),
) -> f64 {
    let nominal = cfg.proximity.nominal_amplitude_scale;
    let Some(a) = calib
        .amplitude
        .as_ref()
        .filter(|_| full_rows > 0 && full_cols > 0)
    else {
        return nominal;
    };
    let roi = full_roi(cfg, full_rows, full_cols);
    let k = &a.lsb_m2_per_us;
    let (r1, c1) = (
        (roi.row0 + roi.rows).min(k.nrows()),
        (roi.col0 + roi.cols).min(k.ncols()),
    );
    let mut v: Vec<f32> = k
        .slice(s![roi.row0.min(r1)..r1, roi.col0.min(c1)..c1])
        .iter()
        .copied()
        .filter(|x| x.is_finite() && *x > 0.0)
        .collect();
    if v.is_empty() {
        return nominal;
    }
    let i = v.len() / 10;
    let (_, k10, _) = v.select_nth_unstable_by(i, f32::total_cmp);
    f64::from(*k10)
}

/// The measured 2-phase phase of a target from zero distance to `near_mm` (rad): the global
/// delay — the mean of the 2-phase wiggling table's correction, which holds it — plus
/// `4π·f·d/c` (eq. 2.6).
fn near_phase_rad(cfg: &Config, calib: &ModeCalibrations, modulation_hz: f64) -> (f64, f64) {
    let delay = calib.two_phase.wiggling.as_ref().map_or(0.0, |w| {
        let c = &w.correction_rad;
        if c.is_empty() {
            0.0
        } else {
            c.iter().map(|&x| f64::from(x)).sum::<f64>() / c.len() as f64
        }
    });
    let near_m = f64::from(cfg.proximity.near_mm) / 1e3;
    (delay, delay + distance_to_phase_rad(near_m, modulation_hz))
}

/// The configured ROI in the coordinates of a frame of window `g` (clipped to it), on an
/// array of `array_rows` rows: a window of the stepped array (`g.full_rows` a step below
/// it, `stepped`) sees the ROI's rows that the step reads.
fn frame_roi(cfg: &Config, g: SensorGeometry, array_rows: usize) -> Roi {
    let step = row_step_of(g, array_rows);
    let roi_full = stepped_roi(full_roi(cfg, g.full_rows * step, g.full_cols), step);
    Roi {
        row0: roi_full.row0.saturating_sub(g.roi_origin[0]),
        col0: roi_full.col0.saturating_sub(g.roi_origin[1]),
        rows: roi_full.rows,
        cols: roi_full.cols,
    }
    .resolve(g.rows, g.cols)
}

/// The row step of a frame of window `g` on an array of `array_rows` rows: 1 for a window of
/// the array itself, `array_rows / g.full_rows` for one of the stepped array.
fn row_step_of(g: SensorGeometry, array_rows: usize) -> usize {
    if g.full_rows > 0 && g.full_rows < array_rows && array_rows.is_multiple_of(g.full_rows) {
        array_rows / g.full_rows
    } else {
        1
    }
}

impl<S: FrameSource> Controller<S> {
    /// New controller. Calibrations are checked against their mode.
    pub fn new(cfg: Config, source: S, calib: ModeCalibrations) -> Result<Self, ControllerError> {
        for (mode, c) in [
            (Algorithm::TwoPhase, &calib.two_phase),
            (Algorithm::FourPhase, &calib.four_phase),
        ] {
            if let Some(w) = &c.wiggling
                && w.algorithm != mode
            {
                return Err(ControllerError::CalibrationMode {
                    mode: mode.as_str(),
                    lut: w.algorithm.as_str(),
                });
            }
        }
        // The ROI must lie inside the sensor: `Roi::resolve` would otherwise clip it or fall
        // back to the central ROI and publish readings of a region nobody configured.
        if let Some(roi @ [row0, col0, rows, cols]) = cfg.proximity.roi {
            let (full_rows, full_cols) = source.full_size();
            let inside = |o: usize, n: usize, full: usize| {
                n > 0 && o.checked_add(n).is_some_and(|e| e <= full)
            };
            if full_rows > 0 && !(inside(row0, rows, full_rows) && inside(col0, cols, full_cols)) {
                return Err(ControllerError::RoiOutsideSensor {
                    roi,
                    full_rows,
                    full_cols,
                });
            }
        }
        // Validate detector parameters once up front.
        NearFarDetector::new(detector_config(&cfg, Roi::default()))?;
        let mut exposure = AutoExposure::new(cfg.exposure.clone());
        let k_floor = roi_k_floor(&cfg, &calib, source.full_size());
        exposure.set_decision_us(decision_exposure_us(
            k_floor,
            cfg.proximity.reflectivity_floor,
            f64::from(cfg.proximity.far_mm) / 1e3,
            f64::from(cfg.processing.min_amplitude_lsb),
        ));
        let near_phase_rad = near_phase_rad(&cfg, &calib, source.sensor().modulation_hz);
        let probe = PresenceProbe::new(cfg.probe.clone());
        let full_rows = source.full_size().0;
        let (read_step, probe_step) = cfg.row_steps(
            source.supports_row_window(),
            source.max_row_step(),
            full_rows,
        );
        let (read_step, probe_step) = (usize::from(read_step), usize::from(probe_step));
        let calib = Calibrations::new(calib, read_step, full_rows);
        Ok(Self {
            ambient: AmbientSwitch::new(
                cfg.ambient.clone(),
                cfg.processing.mode,
                source.supports_mode_switch(),
            ),
            exposure,
            rate: AdaptiveRate::new(cfg.loop_.clone()),
            readout: ReadoutWindow::new(cfg.readout.clone()),
            energy: EnergyAccount::new(cfg.energy.clone(), Pacing::of(&cfg)),
            saturation: SaturationCheck::default(),
            second: SecondFrequency::new(
                (cfg.proximity.second_modulation_hz > 0.0)
                    .then_some(cfg.proximity.second_modulation_hz),
            ),
            cfg,
            source,
            calib,
            read_step,
            probe_step,
            pipes: [None, None],
            pipes_f2: [None, None],
            detector: None,
            amp_scale: None,
            consecutive_failures: 0,
            since_valid: SinceValid::default(),
            candidate_age: None,
            last_sleep: Duration::ZERO,
            recent: RecentCycles::default(),
            probe,
            k_floor,
            near_phase_rad,
            last_full: None,
            cpu_at_capture: Duration::ZERO,
            source_cpu: Duration::ZERO,
            near: false,
            running: false,
            last_error: String::new(),
            window: WindowTracker::default(),
            state: State::Off,
            prev_state: State::Off,
            ambient_lsb: None,
        })
    }

    /// The source.
    pub fn source(&self) -> &S {
        &self.source
    }
    /// The source, mutably.
    pub fn source_mut(&mut self) -> &mut S {
        &mut self.source
    }
    /// Current processing mode.
    pub fn mode(&self) -> Mode {
        self.ambient.mode()
    }
    /// Current exposure (µs).
    pub fn exposure_us(&self) -> f64 {
        self.exposure.exposure_us()
    }
    /// Current rate (Hz).
    pub fn rate_hz(&self) -> f64 {
        self.rate.rate_hz()
    }
    /// Published near.
    pub fn near(&self) -> bool {
        self.near
    }

    /// The cover window as the readings with nothing in range see it: `Uncalibrated` without
    /// a crosstalk calibration, `Changed` once the compensated residual stays beyond ±50 % of
    /// the calibrated crosstalk (a smudge doubling it reads ≈ +100 %; also in `LastError`).
    pub fn crosstalk_status(&self) -> CrosstalkStatus {
        let calibrated = [&self.calib.full.two_phase, &self.calib.full.four_phase]
            .iter()
            .any(|c| c.crosstalk.is_some());
        if calibrated {
            self.window.status()
        } else {
            CrosstalkStatus::Uncalibrated
        }
    }

    /// Energy meter.
    pub fn energy(&self) -> &EnergyMeter {
        self.energy.meter()
    }
    /// Consecutive failed cycles.
    pub fn consecutive_failures(&self) -> u32 {
        self.consecutive_failures
    }

    /// Stop: sensor to reset (fully off), detector reset, state off.
    pub fn stop(&mut self) -> StatusUpdate {
        if let Err(e) = self.source.power_off() {
            tracing::warn!("power off: {e}");
        }
        self.running = false;
        self.near = false;
        self.candidate_age = None;
        if let Some((_, d)) = &mut self.detector {
            d.reset();
        }
        self.rate.reset();
        self.state = State::Off;
        StatusUpdate {
            state: Some(State::Off),
            near: Some(false),
            timestamp_ns: Some(boottime_ns()),
            distance_mm: Some(0),
            rate_hz: Some(0.0),
            reason: Some(Reason::Stopped),
            ..StatusUpdate::default()
        }
    }

    /// The next cycle's request: `probe` the ambient switch's 4-phase probe, `row_step` the
    /// rows to read (1: every row).
    fn request(&mut self, probe: bool, row_step: usize) -> CycleRequest {
        let (full_rows, full_cols) = self.source.full_size();
        let row_window = self.readout.next(ReadoutObservation {
            full_rows,
            roi: full_roi(&self.cfg, full_rows, full_cols),
            source_supports: self.source.supports_row_window(),
            align_rows: self.source.row_window_align(),
            full_cols,
            align_cols: self.source.column_window_align(),
            row_step: u16::try_from(row_step).unwrap_or(1),
        });
        CycleRequest {
            mode: if probe {
                Mode::FourPhase
            } else {
                self.ambient.mode()
            },
            exposure_us: self.exposure.exposure_us(),
            row_window,
            modulation_hz: None,
            single_image: None,
        }
    }

    /// One cycle. `want_depth`: build a depth message.
    pub fn step(&mut self, want_depth: bool) -> StepOutcome {
        if !self.running {
            self.running = true;
            self.state = State::Starting;
        }
        if !want_depth && let Some(out) = self.presence_probe() {
            return out;
        }
        let probe = self.ambient.probe_due();
        let confirm = self.saturation.confirm_due();
        let step = if want_depth { 1 } else { self.read_step };
        let mut req = self.request(probe || confirm, step);
        if confirm {
            // the confirmation of a saturated 2-phase frame: 4-phase at the shortest exposure
            req.exposure_us = self.cfg.exposure.min_us;
        }
        self.since_valid.count(self.last_sleep);
        let (started, started_wall) = (self.source.now(), std::time::Instant::now());
        let result = self.source.cycle(&req);
        self.recent.note(match (started, self.source.now()) {
            (Some(a), Some(b)) => b.saturating_sub(a),
            _ => started_wall.elapsed(),
        });
        let cycle = match result {
            Ok(c) => {
                self.since_valid.count(c.timings().active());
                self.on_array(c, &req)
            }
            Err(e) => {
                if e.kind() == SourceErrorKind::Unsupported && req.row_window.is_some() {
                    tracing::warn!(
                        "partial read-out refused by the source ({e}): reading full frames"
                    );
                    self.readout.refused_by_source();
                }
                return self.fail(e);
            }
        };
        // The capture's time: its frames are in (published with Near and the reading).
        let captured_ns = boottime_ns();
        self.cpu_at_capture = thread_cpu();
        self.source_cpu = Duration::ZERO;
        let mut out = self.after_capture(&cycle, &req, probe, want_depth, captured_ns);
        out.update.timestamp_ns = Some(captured_ns);
        out
    }

    /// Everything a cycle's capture (its frames in at `captured_ns`) leads to: a rails
    /// decision or a processed reading.
    fn after_capture(
        &mut self,
        cycle: &RawCycle,
        req: &CycleRequest,
        probe: bool,
        want_depth: bool,
        captured_ns: u64,
    ) -> StepOutcome {
        let captured = match check_cycle(cycle) {
            Ok(m) => m,
            Err(e) => return self.fail(e),
        };
        if !rails_only(cycle) {
            self.saturation.measurable();
        } else if self.rails_decision(cycle, captured) != RailsDecision::NearReturn {
            return self.rails_cycle(cycle);
        }
        // (a near return on the rails is processed: every pixel saturated reads near)
        self.ambient.note_capture(probe, captured);
        let depth_at_ns = want_depth.then_some(captured_ns);
        match self.process(cycle, req, captured, depth_at_ns) {
            Ok(out) => out,
            Err(e) => self.fail(e),
        }
    }

    /// A frame with usable codes, through the daemon's cycle: measure (the frame through the
    /// one pipeline of its mode, to a near/far reading) → window (an object on the glass is
    /// near; the monitor of the cover window) →
    /// policies (the next cycle) → report (the published status). `depth_at_ns`: the capture time
    /// (CLOCK_BOOTTIME) when a depth message is wanted.
    fn process(
        &mut self,
        cycle: &RawCycle,
        req: &CycleRequest,
        captured: Mode,
        depth_at_ns: Option<u64>,
    ) -> Result<StepOutcome, SourceError> {
        let mut m = self.measure(cycle, req, captured, depth_at_ns)?;
        self.judge_on_the_window(&mut m);
        self.monitor_window(&m);
        self.remember_for_probe(cycle, captured, &m);
        let energy = self.decide_next(cycle, &m);
        Ok(self.report(m, energy, captured))
    }

    /// A capture of `req` as the loop processes it: read every `read_step`-th row (or a
    /// multiple: the probe), a frame of the stepped array ([`on_stepped_array`]).
    fn on_array(&self, cycle: RawCycle, req: &CycleRequest) -> RawCycle {
        let stepped = req.row_window.is_some_and(|w| w.step() > 1);
        on_stepped_array(cycle, if stepped { self.read_step } else { 1 })
    }

    /// The ROI in the coordinates of a frame of window `g` ([`frame_roi`]).
    fn roi_of(&self, g: SensorGeometry) -> Roi {
        frame_roi(&self.cfg, g, self.source.full_size().0)
    }

    /// The row step of a frame of window `g` (1: every row of the array).
    fn step_of(&self, g: SensorGeometry) -> usize {
        row_step_of(g, self.source.full_size().0)
    }

    /// The energy model's view of a capture at `rate_hz`: the pixels read against the
    /// array's (a frame of the stepped array reads a share of the array's rows).
    fn observe(&self, cycle: &RawCycle, rate_hz: f64) -> CycleObservation {
        let (rows, cols) = self.source.full_size();
        let obs = CycleObservation::of(cycle, rate_hz);
        if rows * cols > 0 {
            CycleObservation {
                full_pixels: rows * cols,
                ..obs
            }
        } else {
            obs
        }
    }

    /// The loop thread's CPU time for this cycle's reading so far: from its frames being in
    /// to now, without the time spent inside the source.
    fn reading_cpu(&self) -> Duration {
        thread_cpu()
            .saturating_sub(self.cpu_at_capture)
            .saturating_sub(self.source_cpu)
    }
}
