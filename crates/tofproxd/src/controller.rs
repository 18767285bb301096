//! The loop's brain, free of I/O timing: one [`Controller::step`] = one reading
//! (thesis fig. 3.23 / listing 4.11: restart → flash → exposure → capture →
//! process → stop), then the decisions for the next one, each taken by its own
//! unit in [`crate::policy`] — mode ([`AmbientSwitch`]: 2-phase ↔ 4-phase on
//! background light), exposure ([`AutoExposure`], eye-safe bounded), rate
//! ([`AdaptiveRate`]), rows read ([`ReadoutWindow`]) and the sleep until the next
//! cycle with its energy ([`EnergyAccount`]). The controller composes them, runs
//! the pipeline and the detector and reports in the [`crate::hub`] vocabulary. The
//! daemon thread and `tofprox soak` both drive it.

use std::time::Duration;

use ndarray::{ArrayView3, Axis, s};
use tofprox_core::Algorithm;
use tofprox_core::SensorGeometry;
use tofprox_core::crosstalk::{
    CrosstalkStatus, flag_window_explained, phasor_points_at_window, residual_ratio,
};
use tofprox_core::phasor::{Quadrature, distance_to_phase_rad};
use tofprox_core::pipeline::{
    Calibration, DepthFrame, FLAG_LOW_AMPLITUDE, FLAG_SATURATED, Pipeline, PipelineConfig,
    RawSample,
};
use tofprox_core::proximity::{NearFarConfig, NearFarDetector, ProximityReading, Roi};
use tofprox_core::radiometry::{AmplitudeScale, NearPlausibility, flag_implausible_near};

use crate::boottime::boottime_ns;
use crate::config::{Config, Mode};
use crate::cputime::thread_cpu;
use crate::energy::EnergyMeter;
use crate::hub::{DepthMessage, Reason, State, StatusUpdate};
use crate::policy::probe::{
    PresenceProbe, ProbeReference, ProbeVerdict, change_threshold_lsb, probe_image, tile_means,
};
use crate::policy::second_frequency::{DimNearRule, dim_near_candidates, reject_aliased};
use crate::policy::window::{
    GlassObservation, WINDOW_CHANGE_BOUND, object_on_the_window,
};
use crate::policy::{
    AdaptiveRate, AmbientObservation, AmbientSwitch, AutoExposure, CandidateObservation,
    CycleObservation, EnergyAccount, EnergyDecision, ExposureObservation, Pacing, RailsDecision,
    RailsObservation, RateObservation, ReadoutObservation, ReadoutWindow, SaturationCheck,
    SecondFrequency, WindowObservation, WindowTracker, decision_exposure_us,
    rails_point_at_zero_distance, saturating_fraction_at,
};
use crate::source::{CycleRequest, FrameSource, RawCycle, RawImages, SourceError, SourceErrorKind};

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

/// `DistanceMm` of a valid reading with nothing in range (no target, or only returns no real
/// target near the sensor could give): the largest value, so `DistanceMm < threshold` is false.
pub const DISTANCE_BEYOND_RANGE_MM: u32 = u32::MAX;

/// How far from the cover window (m) the ROI's summed phasor may point for a far reading to
/// count as "only the window returns" for the smudge monitor (a few cm: the depth noise of a
/// weak residual; a real target this close to a multiple of the unambiguous range is the
/// documented limit of one frequency).
const WINDOW_TOLERANCE_M: f64 = 0.05;

/// The time since the last valid reading (the bound on holding Near, `loop.near_hold_ms`): on
/// the source's clock when it has one, so every cycle counts with its whole duration — a
/// failing one too (a transfer timeout, a reset that hangs) —, else the sleeps plus the
/// cycles' measured state durations since that reading.
#[derive(Debug, Default)]
struct SinceValid {
    /// The source's clock at the last valid reading.
    reading_at: Option<Duration>,
    /// Sleeps and cycle durations counted since (sources without a clock).
    counted: Duration,
}

impl SinceValid {
    /// A valid reading now.
    fn reading(&mut self, now: Option<Duration>) {
        self.reading_at = now;
        self.counted = Duration::ZERO;
    }
    /// Time passed (a sleep, a cycle's state durations), for sources without a clock.
    fn count(&mut self, d: Duration) {
        self.counted += d;
    }
    /// Time since the last valid reading.
    fn elapsed(&self, now: Option<Duration>) -> Duration {
        match (now, self.reading_at) {
            (Some(now), Some(at)) => now.saturating_sub(at),
            _ => self.counted,
        }
    }
}

/// The longest of the last few cycles (each from its start to its end, failing ones too): what
/// the next attempt may take before it can release a held Near, so the release never comes
/// after `loop.near_hold_ms` (issue 34: 1,018 ms were seen on the daemon's own clock).
#[derive(Debug, Default)]
struct RecentCycles {
    took: [Duration; 8],
    next: usize,
}

impl RecentCycles {
    fn note(&mut self, d: Duration) {
        self.took[self.next] = d;
        self.next = (self.next + 1) % self.took.len();
    }
    fn longest(&self) -> Duration {
        self.took.iter().copied().max().unwrap_or_default()
    }
}

/// Time from the hold decision to the release being published (the status event, the
/// publisher, the bus): our margin, so the release is on the bus within `loop.near_hold_ms`.
const HOLD_PUBLISH_MARGIN: Duration = Duration::from_millis(20);

/// What a probe that saw no change publishes again: the last full reading.
#[derive(Debug, Clone, Copy)]
struct LastFull {
    /// `DistanceMm` shown.
    shown_mm: u32,
    /// The detector's distance.
    distance_mm: Option<u32>,
    /// Nothing in range.
    no_target: bool,
}

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

/// What the measure stage read from one frame (the depth frame itself stays in the pipeline
/// of its mode).
struct Measurement {
    /// The ROI in the frame's coordinates.
    roi: Roi,
    /// The detector's reading.
    reading: ProximityReading,
    /// A reading: a distance, near, or nothing in range.
    valid: bool,
    /// Saturated and low-amplitude fractions over the ROI.
    stats: RoiStats,
    /// For the ambient switch (4-phase frames).
    ambient: Option<AmbientObservation>,
    /// The second frequency found a far target.
    aliased_far: bool,
    /// The second-frequency capture of this cycle, if one was taken.
    second: Option<RawCycle>,
    /// Fraction of the ROI saturated in the second-frequency capture (0 without one).
    saturated_f2: f32,
    /// Fraction of the ROI a longer exposure would saturate, in either capture.
    saturated_when_longer: f32,
    /// Near pixels the cover window alone can explain (`flag_window_explained`).
    window_explained: usize,
    /// An object pressed on the cover window made this reading near (`policy::window`).
    on_the_window: bool,
    /// The depth message, when asked for.
    depth: Option<DepthMessage>,
}

/// The loop controller.
pub struct Controller<S: FrameSource> {
    cfg: Config,
    source: S,
    calib: ModeCalibrations,
    pipe2: Option<(SensorGeometry, Pipeline)>,
    pipe4: Option<(SensorGeometry, Pipeline)>,
    /// The second frequency's pipelines (2-phase, 4-phase).
    pipes_f2: [Option<(SensorGeometry, Pipeline)>; 2],
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

/// The configured ROI in the coordinates of a frame of window `g` (clipped to it).
fn frame_roi(cfg: &Config, g: SensorGeometry) -> Roi {
    let roi_full = full_roi(cfg, g.full_rows, g.full_cols);
    Roi {
        row0: roi_full.row0.saturating_sub(g.roi_origin[0]),
        col0: roi_full.col0.saturating_sub(g.roi_origin[1]),
        rows: roi_full.rows,
        cols: roi_full.cols,
    }
    .resolve(g.rows, g.cols)
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
            pipe2: None,
            pipe4: None,
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
        let calibrated = [&self.calib.two_phase, &self.calib.four_phase]
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

    fn request(&mut self, probe: bool) -> CycleRequest {
        let (full_rows, full_cols) = self.source.full_size();
        let row_window = self.readout.next(ReadoutObservation {
            full_rows,
            roi: full_roi(&self.cfg, full_rows, full_cols),
            source_supports: self.source.supports_row_window(),
            align_rows: self.source.row_window_align(),
            full_cols,
            align_cols: self.source.column_window_align(),
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

    fn state_before_fail(&self) -> State {
        self.prev_state
    }

    fn fail(&mut self, err: SourceError) -> StepOutcome {
        self.consecutive_failures += 1;
        let state = if err.kind() == SourceErrorKind::Disconnected
            || self.consecutive_failures >= self.cfg.loop_.unavailable_after
        {
            State::Unavailable
        } else {
            State::Error
        };
        self.prev_state = self.state;
        self.state = state;
        self.last_error = err.to_string();
        if state == State::Unavailable && self.state_before_fail() != State::Unavailable {
            tracing::warn!(
                "sensor unavailable ({} failed cycles in a row): {err}",
                self.consecutive_failures
            );
        } else {
            tracing::info!(
                "cycle failed ({} in a row): {err}",
                self.consecutive_failures
            );
        }
        let sleep = Duration::from_millis(self.cfg.loop_.retry_ms);
        let near_update = self.no_reading(sleep);
        self.last_sleep = sleep;
        StepOutcome {
            update: StatusUpdate {
                state: Some(state),
                near: near_update,
                timestamp_ns: Some(boottime_ns()),
                last_error: Some(self.last_error.clone()),
                has_sensor: Some(err.kind() != SourceErrorKind::Disconnected),
                reason: near_update.map(|_| Reason::HoldExpired),
                cycle: true,
                error: true,
                ..StatusUpdate::default()
            },
            sleep,
            end_of_data: err.kind() == SourceErrorKind::EndOfData,
            near: self.near,
            error: Some(err),
            ..StepOutcome::default()
        }
    }

    /// A cycle without a reading (failed, or no data in it) carries no information: Near is
    /// held, but only while the whole time since the last valid reading — failing cycles,
    /// their retries and the sleep before the next attempt included — stays below
    /// `loop.near_hold_ms`; a Near the next reading could only confirm after that bound is
    /// released now (never held for ever). Returns the new Near when it changed.
    fn no_reading(&mut self, next_sleep: Duration) -> Option<bool> {
        let since = self.since_valid.elapsed(self.source.now());
        let bound = Duration::from_millis(self.cfg.loop_.near_hold_ms);
        // the next attempt ends after the sleep and a cycle as long as the recent ones
        let next_attempt = next_sleep + self.recent.longest() + HOLD_PUBLISH_MARGIN;
        if self.near && since + next_attempt >= bound {
            tracing::info!(
                "no valid reading for {} ms (next attempt after {} ms more): Near released",
                since.as_millis(),
                next_sleep.as_millis()
            );
            self.near = false;
            if let Some((_, d)) = &mut self.detector {
                d.reset();
            }
            return Some(false);
        }
        None
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
        let mut req = self.request(probe || confirm);
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
                c
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

    /// The presence probe (`policy::probe`), when due: one raw image at `exposure.min_us`.
    /// `Some`: the cycle's outcome (no change: the last reading again; or the failure);
    /// `None`: no probe, or it saw a change — the full reading runs now, with the probe's
    /// energy in it.
    fn presence_probe(&mut self) -> Option<StepOutcome> {
        if self.ambient.mode() != Mode::TwoPhase
            || self.ambient.probe_due()
            || self.saturation.confirm_due()
            || !self.source.supports_single_image()
        {
            return None;
        }
        let last = self.last_full?;
        let image = self.probe.due(self.near, self.rate.still_readings())?.image;
        let mut req = self.request(false);
        req.exposure_us = self.cfg.exposure.min_us;
        req.single_image = Some(image);
        self.since_valid.count(self.last_sleep);
        let result = self.source.cycle(&req);
        let cycle = match result {
            Ok(c) => c,
            Err(e) if e.kind() == SourceErrorKind::Unsupported => {
                tracing::warn!("presence probe refused by the source ({e}): full readings");
                self.probe.refused();
                self.last_sleep = Duration::ZERO;
                return None;
            }
            Err(e) => return Some(self.fail(e)),
        };
        self.since_valid.count(cycle.timings().active());
        let captured_ns = boottime_ns();
        self.cpu_at_capture = thread_cpu();
        self.source_cpu = Duration::ZERO;
        let verdict = self.judge_probe(&cycle);
        tracing::debug!("presence probe: {verdict:?}");
        let rate_hz = self.rate.rate_hz();
        let obs = CycleObservation::of(&cycle, rate_hz).with_cpu(self.reading_cpu());
        if let ProbeVerdict::Changed { .. } = verdict {
            self.energy.carry(obs);
            self.last_sleep = Duration::ZERO;
            return None;
        }
        // nothing changed: the last reading stands, as a reading of its own (still)
        self.rate.next(RateObservation {
            near: false,
            distance_mm: last.distance_mm,
            no_target: last.no_target,
        });
        let energy = self.energy.next(obs);
        self.last_sleep = energy.sleep;
        self.consecutive_failures = 0;
        self.since_valid.reading(self.source.now());
        self.state = State::Running;
        Some(StepOutcome {
            update: StatusUpdate {
                state: Some(self.state),
                near: Some(false),
                timestamp_ns: Some(captured_ns),
                distance_mm: Some(last.shown_mm),
                rate_hz: Some(self.rate.rate_hz()),
                power_mw: Some(energy.average_mw),
                reason: Some(Reason::Probe),
                valid_reading: true,
                cycle: true,
                ..StatusUpdate::default()
            },
            sleep: energy.sleep,
            near: false,
            distance_mm: last.distance_mm,
            valid: true,
            captured_mode: Some(Mode::TwoPhase),
            ..StepOutcome::default()
        })
    }

    /// The probe image against the reference: a change when the window differs or any tile
    /// moved by more than half the weakest near return ([`change_threshold_lsb`]).
    fn judge_probe(&mut self, cycle: &RawCycle) -> ProbeVerdict {
        let same_window = self.probe_reference_geometry() == Some(cycle.geometry);
        let cos_min = self.probe_cos_min();
        let tiles = self.tiles_of(cycle, 0);
        let (Some(tiles), true) = (tiles, same_window) else {
            return self.probe.judge(&[], cycle.exposure_us, 0.0);
        };
        let threshold = change_threshold_lsb(
            self.k_floor,
            self.cfg.proximity.reflectivity_floor,
            f64::from(self.cfg.proximity.near_mm) / 1e3,
            cycle.exposure_us,
            cos_min,
        );
        self.probe.judge(&tiles, cycle.exposure_us, threshold)
    }

    fn probe_reference_geometry(&self) -> Option<SensorGeometry> {
        self.probe.reference().map(|r| r.geometry)
    }

    fn probe_cos_min(&self) -> f64 {
        self.probe.reference().map_or(0.0, |r| r.cos_min)
    }

    /// Tile means of raw image `image` of `cycle` above the dark level, over the ROI.
    fn tiles_of(&self, cycle: &RawCycle, image: usize) -> Option<Vec<f32>> {
        let g = cycle.geometry;
        let roi = frame_roi(&self.cfg, g);
        let dark = self
            .calib
            .two_phase
            .offset
            .as_ref()
            .and_then(|o| crop_map(&o.dark_lsb, g, "offset").ok());
        let dark = dark.as_ref().map(|d| d.view());
        let (mid, tile) = (g.mid_code() as f32, self.probe.tile_px());
        Some(match &cycle.frames {
            RawImages::U16(a) if image < a.dim().0 => {
                tile_means(a.index_axis(Axis(0), image), dark, mid, roi, tile)
            }
            RawImages::F32(a) if image < a.dim().0 => {
                tile_means(a.index_axis(Axis(0), image), dark, mid, roi, tile)
            }
            _ => return None,
        })
    }

    /// After a full reading: a far, valid 2-phase reading leaves the probe its reference (the
    /// probe image's tile means per µs) and what a probe that sees no change publishes again;
    /// any other reading leaves none.
    fn remember_for_probe(&mut self, cycle: &RawCycle, captured: Mode, m: &Measurement) {
        let far = m.valid && !m.reading.near && !self.near && !m.aliased_far;
        let reference = (far && captured == Mode::TwoPhase && self.cfg.probe.enabled)
            .then(|| probe_image(&cycle.phases_deg, self.near_phase_rad))
            .flatten()
            .and_then(|(image, cos_min)| {
                let tiles = self.tiles_of(cycle, usize::from(image))?;
                let t = cycle.exposure_us as f32;
                Some(ProbeReference {
                    geometry: cycle.geometry,
                    image,
                    per_us: tiles.iter().map(|v| v / t).collect(),
                    cos_min,
                })
            });
        self.last_full = far.then(|| LastFull {
            shown_mm: shown_distance_mm(&m.reading, self.cfg.proximity.far_mm),
            distance_mm: m.reading.distance_mm,
            no_target: m.reading.no_target,
        });
        self.probe.full_reading(reference);
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
    /// one pipeline of its mode, to a near/far reading) → monitor (the cover window) →
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
        self.judge_on_the_window(cycle, captured, &mut m);
        self.monitor_window(cycle, captured, &m);
        self.remember_for_probe(cycle, captured, &m);
        let energy = self.decide_next(cycle, &m);
        Ok(self.report(m, energy, captured))
    }

    /// Measure: the ambient indicator from the raw images, the frame through the one pipeline
    /// of its mode (pipelines and the detector are rebuilt when the window changes), near
    /// depths without a plausible return flagged, dim near candidates confirmed at a second
    /// frequency, the detector's reading. Everything that can fail a cycle fails here, before
    /// the monitor or a policy sees the frame.
    fn measure(
        &mut self,
        cycle: &RawCycle,
        req: &CycleRequest,
        captured: Mode,
        depth_at_ns: Option<u64>,
    ) -> Result<Measurement, SourceError> {
        let g = cycle.geometry;
        let roi = frame_roi(&self.cfg, g);
        if roi.rows == 0 || roi.cols == 0 {
            return Err(SourceError::new(
                SourceErrorKind::Unsupported,
                "the ROI lies outside the read-out window",
            ));
        }
        let indicator_lsb =
            (captured == Mode::FourPhase).then(|| self.ambient_indicator_lsb(cycle, roi));
        let pipe = mode_pipeline(
            [&mut self.pipe2, &mut self.pipe4],
            &self.calib,
            self.cfg.processing.min_amplitude_lsb,
            captured,
            g,
            (cycle.exposure_us, self.window.scale()),
        )?;
        process_images(pipe, &cycle.frames, &cycle.phases_deg, cycle.frames.dim().0)?;
        let ambient = match indicator_lsb {
            Some(indicator_lsb) => Some(AmbientObservation {
                indicator_lsb,
                discrepancy_mm: self.two_phase_discrepancy_mm(cycle, roi)?,
            }),
            None => None,
        };
        let (dim, window_explained) = self.flag_wrapped_near(cycle, captured, roi)?;
        // dim candidates matter only when they can make or hold a near reading
        let decisive = !dim.is_empty() && {
            let frame = processed(&mut self.pipe2, &mut self.pipe4, captured)?.frame();
            detector_slot(&mut self.detector, &self.cfg, g, roi)?.statistic_below_far(frame)
        };
        let second = self.second_frequency_frame(req, cycle, captured, dim.len(), decisive)?;
        let aliased_far = self.apply_second_frequency(cycle, captured, &dim, second.as_ref());
        // saturation at the second frequency counts too: the confirmation needs both measurable
        let saturated_f2 = second
            .as_ref()
            .map_or(0.0, |(_, f2)| roi_stats(f2, roi).saturated_fraction);
        let saturated_when_longer = std::iter::once(cycle)
            .chain(second.as_ref().map(|(c2, _)| c2))
            .map(|c| self.saturated_when_longer(c, roi))
            .fold(0.0f32, f32::max);
        let frame = processed(&mut self.pipe2, &mut self.pipe4, captured)?.frame();
        let stats = roi_stats(frame, roi);
        let depth = depth_at_ns.map(|t| depth_message(frame, t));
        let reading = self.detect(g, roi, captured)?;
        Ok(Measurement {
            roi,
            reading,
            // nothing in range is a reading too: far, DistanceMm "beyond range"
            valid: reading.distance_mm.is_some() || reading.near || reading.no_target,
            stats,
            ambient,
            aliased_far,
            second: second.map(|(c2, _)| c2),
            saturated_f2,
            saturated_when_longer,
            window_explained,
            on_the_window: false,
            depth,
        })
    }

    /// Fraction of the ROI a longer exposure (× `exposure.step`) would saturate: auto-exposure
    /// never lengthens into it (`policy::saturating_fraction_at`).
    fn saturated_when_longer(&self, c: &RawCycle, roi: Roi) -> f32 {
        let (dark, max_code) = (
            self.dark_level(c.geometry, roi),
            c.geometry.max_code() as f32,
        );
        let step = self.cfg.exposure.step;
        match &c.frames {
            RawImages::U16(a) => saturating_fraction_at(a.view(), roi, dark, max_code, step),
            RawImages::F32(a) => saturating_fraction_at(a.view(), roi, dark, max_code, step),
        }
    }

    /// Background-light indicator from the data: the common-mode level of the four raw images
    /// above the dark level over the ROI (eq. 2.3 cancels it, eq. 2.2 does not — 5.1.2.3).
    fn ambient_indicator_lsb(&mut self, cycle: &RawCycle, roi: Roi) -> f32 {
        let dark = self.dark_level(cycle.geometry, roi);
        let ind = match &cycle.frames {
            RawImages::U16(a) => common_mode_lsb(a.view(), roi, dark),
            RawImages::F32(a) => common_mode_lsb(a.view(), roi, dark),
        };
        self.ambient_lsb = Some(ind);
        ind
    }

    /// The ambient switch's cross-check of a 4-phase frame (when the switch is on): its first
    /// two images as a 2-phase frame, |2-phase − 4-phase| median depth over the ROI.
    fn two_phase_discrepancy_mm(
        &mut self,
        cycle: &RawCycle,
        roi: Roi,
    ) -> Result<Option<f64>, SourceError> {
        if !self.cfg.ambient.enabled {
            return Ok(None);
        }
        let four = roi_median_mm(
            processed(&mut self.pipe2, &mut self.pipe4, Mode::FourPhase)?.frame(),
            roi,
        );
        let p2 = pipeline_slot(
            &mut self.pipe2,
            &self.calib.two_phase,
            self.cfg.processing.min_amplitude_lsb,
            Mode::TwoPhase,
            cycle.geometry,
            (cycle.exposure_us, self.window.scale()),
        )?;
        let two = roi_median_mm(
            process_images(p2, &cycle.frames, &cycle.phases_deg, 2)?,
            roi,
        );
        Ok(two.zip(four).map(|(a, b)| (a - b).abs()))
    }

    /// The plausibility of near depths: a near depth needs the amplitude of a real target
    /// (thesis 2.2.1, 1/d²), checked below the far threshold.
    fn plausibility(&self) -> NearPlausibility {
        NearPlausibility {
            reflectivity_floor: self.cfg.proximity.reflectivity_floor,
            depth_uncertainty_m: f64::from(self.cfg.proximity.depth_uncertainty_mm) / 1e3,
            check_below_m: f64::from(self.cfg.proximity.far_mm) / 1e3,
        }
    }

    /// No near from a wrapped phase: near depths of the processed frame without a plausible
    /// return are flagged invalid, and so are near pixels the cover window alone can explain
    /// (`policy::window`, the rule in docs/daemon.md). Returns the dim near candidates left
    /// (pixels to confirm at a second frequency before Near is published) and the number of
    /// window-explained pixels.
    fn flag_wrapped_near(
        &mut self,
        cycle: &RawCycle,
        captured: Mode,
        roi: Roi,
    ) -> Result<(Vec<(usize, usize)>, usize), SourceError> {
        let g = cycle.geometry;
        let plaus = self.plausibility();
        let rule = DimNearRule {
            confirm_reflectivity: self.cfg.proximity.confirm_reflectivity,
            brightest_far_gain: self.cfg.proximity.brightest_far_gain,
            depth_uncertainty_m: plaus.depth_uncertainty_m,
            check_below_m: plaus.check_below_m,
            modulation_hz: g.modulation_hz,
        };
        let scale = amplitude_scale_slot(
            &mut self.amp_scale,
            self.calib.amplitude.as_ref(),
            self.cfg.proximity.nominal_amplitude_scale,
            g,
        )?;
        let pipe = processed(&mut self.pipe2, &mut self.pipe4, captured)?;
        let (frame, used) = pipe.frame_mut_and_calibration();
        let implausible = flag_implausible_near(frame, scale.view(), cycle.exposure_us, &plaus);
        if let Some(n) = implausible.filter(|&n| n > 0) {
            tracing::debug!("{n} pixels with a near depth but no plausible return (wrapped phase)");
        }
        let t = cycle.exposure_us;
        let below_m = plaus.check_below_m as f32;
        let window_explained = used.crosstalk.as_ref().map_or(0, |x| {
            flag_window_explained(frame, x, captured, roi, t, WINDOW_CHANGE_BOUND, below_m)
        });
        let dim = dim_near_candidates(frame, roi, scale.view(), t, &rule);
        Ok((dim, window_explained))
    }

    /// The second frequency's verdict on the dim near candidates, applied to the processed
    /// frame (aliases of a far target lose their near depth). Returns whether it found a far
    /// target — then the frame is not "only the window returns".
    fn apply_second_frequency(
        &mut self,
        cycle: &RawCycle,
        captured: Mode,
        dim: &[(usize, usize)],
        second: Option<&(RawCycle, DepthFrame)>,
    ) -> bool {
        let Some((c2, f2)) = second else {
            return false;
        };
        let check_below_m = self.plausibility().check_below_m;
        let Ok(pipe) = processed(&mut self.pipe2, &mut self.pipe4, captured) else {
            return false;
        };
        let f2_hz = c2.geometry.modulation_hz;
        let g = cycle.geometry;
        let v = reject_aliased(
            pipe.frame_mut(),
            g.modulation_hz,
            f2,
            f2_hz,
            dim,
            check_below_m,
        );
        tracing::debug!("second frequency {f2_hz} Hz: {v:?}");
        self.second.note(v);
        v.aliased > 0
    }

    /// The detector's reading of the processed frame (rebuilt when the window changed; starts
    /// far).
    fn detect(
        &mut self,
        g: SensorGeometry,
        roi: Roi,
        captured: Mode,
    ) -> Result<ProximityReading, SourceError> {
        let frame = processed(&mut self.pipe2, &mut self.pipe4, captured)?.frame();
        Ok(detector_slot(&mut self.detector, &self.cfg, g, roi)?.update(frame))
    }

    /// An object on the glass (`policy::window`, issue 34: the pocket): while armed — Near
    /// published, or a near candidate within `loop.near_hold_ms` — a reading that is not near
    /// but whose ROI light points at the window with a residual above the tracked estimate by
    /// more than `ON_THE_WINDOW_BOUND` is near (`DistanceMm` 0: on the glass), so the window
    /// tracker does not learn from it.
    fn judge_on_the_window(&mut self, cycle: &RawCycle, captured: Mode, m: &mut Measurement) {
        let now = self.source.now();
        let hold = Duration::from_millis(self.cfg.loop_.near_hold_ms);
        let since_reading = self.since_valid.elapsed(now);
        let armed = self.near
            || self
                .candidate_age
                .is_some_and(|a| a + since_reading <= hold);
        if m.valid {
            let far_mm = self.cfg.proximity.far_mm;
            let candidate = m.reading.near || m.reading.distance_mm.is_some_and(|d| d < far_mm);
            self.candidate_age = match candidate {
                true => Some(Duration::ZERO),
                false => self.candidate_age.map(|a| a + since_reading),
            };
        }
        eprintln!("DBG0 scale={} valid={} near={} d={:?} nt={} armed={armed} exp={}", self.window.scale(), m.valid, m.reading.near, m.reading.distance_mm, m.reading.no_target, cycle.exposure_us);
        if m.reading.near || !armed {
            return;
        }
        let Ok(pipe) = processed(&mut self.pipe2, &mut self.pipe4, captured) else {
            return;
        };
        let frame = pipe.frame();
        let tolerance_rad = distance_to_phase_rad(WINDOW_TOLERANCE_M, cycle.geometry.modulation_hz);
        let on = object_on_the_window(GlassObservation {
            armed,
            points_at_window: phasor_points_at_window(frame, m.roi, tolerance_rad),
            aliased_far: m.aliased_far,
            residual_ratio: (pipe.calibration().crosstalk.as_ref())
                .and_then(|x| residual_ratio(frame, x, captured, m.roi, cycle.exposure_us)),
        });
        eprintln!("DBG al={} scale={} armed={armed} near={} cand={:?} pts={} rr={:?} on={on}", m.aliased_far, self.window.scale(), self.near, self.candidate_age, phasor_points_at_window(frame, m.roi, tolerance_rad), (pipe.calibration().crosstalk.as_ref()).and_then(|x| residual_ratio(frame, x, captured, m.roi, cycle.exposure_us)));
        if on {
            m.reading.near = true;
            m.reading.no_target = false;
            m.reading.distance_mm = None;
            m.valid = true;
            m.on_the_window = true;
        }
    }

    /// Monitor: with nothing in range only the cover window returns light; what is left of it
    /// after the compensation says whether the window changed since the estimate (a smudge).
    /// The online estimate (`policy::window`) learns from those readings — valid, no near
    /// candidate, no far target found at the second frequency, and nothing in range or the
    /// ROI's light pointing at the window (a residual big enough to be a depth: ≈ 0 mm or
    /// wrapped just under the range) — never with a near candidate.
    fn monitor_window(&mut self, cycle: &RawCycle, captured: Mode, m: &Measurement) {
        let Ok(pipe) = processed(&mut self.pipe2, &mut self.pipe4, captured) else {
            return;
        };
        let frame = pipe.frame();
        let tolerance_rad = distance_to_phase_rad(WINDOW_TOLERANCE_M, cycle.geometry.modulation_hz);
        let far_mm = self.cfg.proximity.far_mm;
        let became = self.window.next(WindowObservation {
            valid: m.valid,
            near: m.reading.near,
            near_candidates: m.reading.distance_mm.is_some_and(|d| d < far_mm),
            aliased_far: m.aliased_far,
            points_at_window: phasor_points_at_window(frame, m.roi, tolerance_rad),
            no_target: m.reading.no_target,
            window_explained: m.window_explained,
            residual_ratio: (pipe.calibration().crosstalk.as_ref())
                .and_then(|x| residual_ratio(frame, x, captured, m.roi, cycle.exposure_us)),
        });
        if let Some(now) = became {
            tracing::warn!("{}", now.message());
        }
    }

    /// Policies: the decisions for the next cycle in their fixed order — ambient switch
    /// (4-phase frames), exposure, rate, energy account (whose sleep follows the new rate; a
    /// second-frequency capture is counted with its cycle).
    fn decide_next(&mut self, cycle: &RawCycle, m: &Measurement) -> EnergyDecision {
        if let Some(obs) = m.ambient {
            self.ambient.next(obs);
        }
        // the window's return is no target: its pixels count as pixels without a return
        let roi_px = (m.roi.rows * m.roi.cols).max(1) as f32;
        self.exposure.next(ExposureObservation::Roi {
            saturated_fraction: m.stats.saturated_fraction.max(m.saturated_f2),
            low_amplitude_fraction: m.stats.low_amplitude_fraction
                + m.window_explained as f32 / roi_px,
            saturated_when_longer: m.saturated_when_longer,
        });
        self.rate.next(RateObservation {
            near: m.reading.near,
            distance_mm: m.reading.distance_mm,
            no_target: m.valid && m.reading.no_target,
        });
        let rate_hz = self.rate.rate_hz();
        self.energy.next_with(
            CycleObservation::of(cycle, rate_hz).with_cpu(self.reading_cpu()),
            m.second
                .as_ref()
                .map(|c2| CycleObservation::of(c2, rate_hz)),
        )
    }

    /// Report: a valid reading becomes the published Near and state, the failure count and
    /// the time since the last valid reading restart, `LastError` clears — or names the
    /// changed cover window while it lasts.
    fn report(&mut self, m: Measurement, energy: EnergyDecision, captured: Mode) -> StepOutcome {
        self.consecutive_failures = 0;
        self.last_sleep = energy.sleep;
        if m.valid {
            self.since_valid.reading(self.source.now());
            self.near = m.reading.near;
            self.state = State::Running;
        }
        let note = match self.window.status() {
            s @ CrosstalkStatus::Changed { .. } => s.message(),
            _ => String::new(),
        };
        let last_error_changed = self.last_error != note;
        self.last_error = note;
        StepOutcome {
            update: StatusUpdate {
                state: Some(self.state),
                near: m.valid.then_some(self.near),
                // the capture's time, set by `step` (the frames were in)
                timestamp_ns: None,
                distance_mm: Some(shown_distance_mm(&m.reading, self.cfg.proximity.far_mm)),
                mode: Some(self.ambient.mode()),
                rate_hz: Some(self.rate.rate_hz()),
                power_mw: Some(energy.average_mw),
                last_error: last_error_changed.then(|| self.last_error.clone()),
                exposure_us: Some(self.exposure.exposure_us()),
                has_sensor: Some(true),
                amplitude_check: Some(if self.calib.amplitude.is_some() {
                    "calibrated"
                } else {
                    "nominal"
                }),
                reason: m.valid.then(|| reading_reason(&m)),
                valid_reading: m.valid,
                cycle: true,
                error: false,
            },
            depth: m.depth,
            sleep: energy.sleep,
            error: None,
            near: self.near,
            distance_mm: m.reading.distance_mm,
            valid: m.valid,
            end_of_data: false,
            captured_mode: Some(captured),
        }
    }

    /// Saturation is evidence ([`SaturationCheck`]): whether an all-rails frame is the sensor's
    /// own return from something too close to measure (near), to be confirmed first, or no data.
    fn rails_decision(&mut self, cycle: &RawCycle, captured: Mode) -> RailsDecision {
        let g = cycle.geometry;
        let roi = frame_roi(&self.cfg, g);
        let lut = match captured {
            Mode::TwoPhase => self.calib.two_phase.wiggling.as_ref(),
            Mode::FourPhase => self.calib.four_phase.wiggling.as_ref(),
        };
        let max = g.max_code() as f32;
        let ph = &cycle.phases_deg;
        let return_pattern = match &cycle.frames {
            RawImages::U16(a) => rails_point_at_zero_distance(a.view(), ph, roi, max, lut),
            RawImages::F32(a) => rails_point_at_zero_distance(a.view(), ph, roi, max, lut),
        };
        let decision = self.saturation.next(RailsObservation {
            captured,
            return_pattern,
            source_can_confirm: self.source.supports_mode_switch(),
            bright_background: self
                .ambient_lsb
                .is_some_and(|a| a > self.cfg.ambient.high_lsb),
        });
        tracing::debug!("every code on a rail: {decision:?}");
        decision
    }

    /// The second-frequency capture of this cycle's request when the policy asks for one (dim
    /// near candidates, Near not published), processed: `None` when not asked or the source
    /// cannot (then the amplitude test decides alone, `policy::second_frequency`).
    fn second_frequency_frame(
        &mut self,
        req: &CycleRequest,
        cycle: &RawCycle,
        captured: Mode,
        dim_candidates: usize,
        decisive: bool,
    ) -> Result<Option<(RawCycle, DepthFrame)>, SourceError> {
        let g = cycle.geometry;
        let Some(f2_hz) = self.second.next(CandidateObservation {
            dim_candidates,
            decisive,
            near_published: self.near,
            captured_hz: g.modulation_hz,
        }) else {
            return Ok(None);
        };
        let req2 = CycleRequest {
            mode: captured,
            exposure_us: cycle.exposure_us,
            modulation_hz: Some(f2_hz),
            ..*req
        };
        let cpu_before = thread_cpu();
        let captured2 = self.source.cycle(&req2);
        self.source_cpu += thread_cpu().saturating_sub(cpu_before);
        let c2 = match captured2 {
            Ok(c) => c,
            Err(e) if e.kind() == SourceErrorKind::Unsupported => {
                self.second.refused(&e.to_string());
                return Ok(None);
            }
            Err(e) => return Err(e),
        };
        let mode2 = check_cycle(&c2)?;
        let g2 = c2.geometry;
        let same_window = SensorGeometry {
            modulation_hz: g.modulation_hz,
            ..g2
        } == g;
        if !same_window || (g2.modulation_hz - f2_hz).abs() >= 1.0 {
            return Err(SourceError::new(
                SourceErrorKind::CorruptFrame,
                format!(
                    "second-frequency capture at {} Hz of window {:?} {}x{}: {f2_hz} Hz of this cycle's window asked",
                    g2.modulation_hz, g2.roi_origin, g2.rows, g2.cols
                ),
            ));
        }
        let full = match mode2 {
            Mode::TwoPhase => &self.calib.two_phase,
            Mode::FourPhase => &self.calib.four_phase,
        };
        // one pipeline per mode at the second frequency, kept while the window is the same
        // (building one is the costly part: its CPU time is the reading's energy too)
        let slot = match mode2 {
            Mode::TwoPhase => &mut self.pipes_f2[0],
            Mode::FourPhase => &mut self.pipes_f2[1],
        };
        if slot.as_ref().is_none_or(|(geo, _)| *geo != g2) {
            *slot = None;
        }
        let calib = if slot.is_none() {
            at_second_frequency(full, f2_hz / g.modulation_hz)
        } else {
            Calibration::default()
        };
        let min_amp = self.cfg.processing.min_amplitude_lsb;
        let exposure = (c2.exposure_us, self.window.scale());
        let p = pipeline_slot(slot, &calib, min_amp, mode2, g2, exposure)?;
        let k = c2.frames.dim().0;
        let f2 = process_images(p, &c2.frames, &c2.phases_deg, k)?.clone();
        Ok(Some((c2, f2)))
    }

    /// Every code of every raw image on a rail and not a near return: a dead/garbage frame,
    /// light without modulation, or a saturated 2-phase frame awaiting its confirmation.
    /// Such a frame carries no data: it never reaches the detector (it would read as saturated
    /// = near), Near is only held (bounded by `loop.near_hold_ms`), and the exposure is
    /// shortened so a real target becomes measurable in the next cycle.
    fn rails_cycle(&mut self, cycle: &RawCycle) -> StepOutcome {
        self.exposure.next(ExposureObservation::Rails);
        let energy = self
            .energy
            .next(CycleObservation::of(cycle, self.rate.rate_hz()).with_cpu(self.reading_cpu()));
        let sleep = energy.sleep;
        let near_update = self.no_reading(sleep);
        self.last_sleep = sleep;
        tracing::debug!("frame without usable codes (all on the rails): no reading");
        StepOutcome {
            update: StatusUpdate {
                near: near_update,
                exposure_us: Some(self.exposure.exposure_us()),
                power_mw: Some(energy.average_mw),
                reason: near_update.map(|_| Reason::HoldExpired),
                cycle: true,
                ..StatusUpdate::default()
            },
            sleep,
            near: self.near,
            ..StepOutcome::default()
        }
    }

    /// The loop thread's CPU time for this cycle's reading so far: from its frames being in
    /// to now, without the time spent inside the source.
    fn reading_cpu(&self) -> Duration {
        thread_cpu()
            .saturating_sub(self.cpu_at_capture)
            .saturating_sub(self.source_cpu)
    }

    fn dark_level(&self, g: SensorGeometry, roi: Roi) -> f32 {
        let mid = g.mid_code() as f32;
        match &self.calib.four_phase.offset {
            Some(o) => {
                let r0 = g.roi_origin[0] + roi.row0;
                let c0 = g.roi_origin[1] + roi.col0;
                let v = o.dark_lsb.slice(s![
                    r0.min(o.dark_lsb.nrows())..(r0 + roi.rows).min(o.dark_lsb.nrows()),
                    c0.min(o.dark_lsb.ncols())..(c0 + roi.cols).min(o.dark_lsb.ncols())
                ]);
                if v.is_empty() {
                    mid
                } else {
                    v.iter().sum::<f32>() / v.len() as f32
                }
            }
            None => mid,
        }
    }
}

/// The rule that decided a valid reading.
fn reading_reason(m: &Measurement) -> Reason {
    if m.on_the_window {
        Reason::OnTheWindow
    } else if m.reading.near && m.stats.saturated_fraction >= 0.5 {
        Reason::Saturated
    } else if m.reading.no_target {
        Reason::NothingInRange
    } else if m.aliased_far && !m.reading.near {
        Reason::SecondFrequency
    } else {
        Reason::Distance
    }
}

/// Validate a cycle's shape and reject dead frames (every code of every raw image on a
/// rail): such a frame never reaches the detector (it would read as saturated = near).
fn check_cycle(c: &RawCycle) -> Result<Mode, SourceError> {
    let (k, rows, cols) = c.frames.dim();
    let g = &c.geometry;
    let bad = |m: String| Err(SourceError::new(SourceErrorKind::CorruptFrame, m));
    if rows == 0 || cols == 0 {
        return bad("empty frame".into());
    }
    if c.phases_deg.len() != k {
        return bad(format!("{k} raw images but {} phases", c.phases_deg.len()));
    }
    if let Err(e) = g.validate() {
        return bad(format!("bad sensor geometry: {e}"));
    }
    if (rows, cols) != (g.rows, g.cols) {
        return bad(format!(
            "{rows}x{cols} images but a {}x{} window",
            g.rows, g.cols
        ));
    }
    // [0, 90(, 180, 270)], or the same images of a sensor with another phase convention
    // (canonical shifts such as [0, 270]: evaluated with their quadrature)
    let mode = if k == 4 && Quadrature::of_canonical(&c.phases_deg, Algorithm::FourPhase).is_some()
    {
        Mode::FourPhase
    } else if k == 2 && Quadrature::of_canonical(&c.phases_deg, Algorithm::TwoPhase).is_some() {
        Mode::TwoPhase
    } else {
        return bad(format!("unsupported phases {:?}", c.phases_deg));
    };
    let max = g.max_code() as f32;
    if c.frames.any(|v| v > max) {
        return bad(format!("code above the {}-bit range", g.adc_bits));
    }
    Ok(mode)
}

/// The pipeline of `mode` (slots `[2-phase, 4-phase]`) for the window of `g`, at `exposure`
/// (µs, and the window's crosstalk scale).
fn mode_pipeline<'a>(
    [two, four]: [&'a mut Option<(SensorGeometry, Pipeline)>; 2],
    calib: &ModeCalibrations,
    min_amplitude_lsb: f32,
    mode: Mode,
    g: SensorGeometry,
    exposure: (f64, f32),
) -> Result<&'a mut Pipeline, SourceError> {
    let (slot, full) = match mode {
        Mode::TwoPhase => (two, &calib.two_phase),
        Mode::FourPhase => (four, &calib.four_phase),
    };
    pipeline_slot(slot, full, min_amplitude_lsb, mode, g, exposure)
}

/// The pipeline of `mode` holding this cycle's processed frame (slots `[2-phase, 4-phase]`).
fn processed<'a>(
    two: &'a mut Option<(SensorGeometry, Pipeline)>,
    four: &'a mut Option<(SensorGeometry, Pipeline)>,
    mode: Mode,
) -> Result<&'a mut Pipeline, SourceError> {
    let slot = match mode {
        Mode::TwoPhase => two,
        Mode::FourPhase => four,
    };
    slot.as_mut()
        .map(|(_, p)| p)
        .ok_or_else(|| SourceError::new(SourceErrorKind::Other, "pipeline missing"))
}

/// The detector's parameters for an ROI.
fn detector_config(cfg: &Config, roi: Roi) -> NearFarConfig {
    NearFarConfig {
        near_mm: cfg.proximity.near_mm,
        far_mm: cfg.proximity.far_mm,
        roi,
        far_debounce: cfg.proximity.far_debounce,
        min_valid_fraction: cfg.proximity.min_valid_fraction,
    }
}

/// The published `DistanceMm` of a reading: near from saturation (target too close/bright to
/// measure) publishes "unknown" (0) — the statistic of the remaining valid pixels is the
/// background, not the target —; nothing in range [`DISTANCE_BEYOND_RANGE_MM`].
fn shown_distance_mm(reading: &ProximityReading, far_mm: u32) -> u32 {
    match reading.distance_mm {
        Some(d) if reading.near && d >= far_mm => 0,
        Some(d) => d,
        None if reading.no_target && !reading.near => DISTANCE_BEYOND_RANGE_MM,
        None => 0,
    }
}

fn pipeline_slot<'a>(
    slot: &'a mut Option<(SensorGeometry, Pipeline)>,
    full: &Calibration,
    min_amplitude_lsb: f32,
    mode: Mode,
    g: SensorGeometry,
    (exposure_us, crosstalk_scale): (f64, f32),
) -> Result<&'a mut Pipeline, SourceError> {
    if slot.as_ref().is_none_or(|(geo, _)| *geo != g) {
        let calib = crop_calibration(full, g)
            .map_err(|m| SourceError::new(SourceErrorKind::Unsupported, m))?;
        let pcfg = PipelineConfig {
            algorithm: mode,
            modulation_hz: g.modulation_hz,
            adc_bits: g.adc_bits,
            min_amplitude_lsb,
        };
        let p = Pipeline::new(g.rows, g.cols, pcfg, calib).map_err(|e| {
            SourceError::new(SourceErrorKind::Unsupported, format!("pipeline: {e}"))
        })?;
        *slot = Some((g, p));
    }
    match slot {
        Some((_, p)) => {
            // scales the crosstalk calibration (if any) to this cycle's exposure
            // and compensates the window at its current estimate (policy::window)
            p.set_exposure_us(exposure_us)
                .and_then(|()| p.set_crosstalk_scale(crosstalk_scale))
                .map_err(|e| {
                    SourceError::new(SourceErrorKind::CorruptFrame, format!("pipeline: {e}"))
                })?;
            Ok(p)
        }
        None => Err(SourceError::new(SourceErrorKind::Other, "pipeline missing")),
    }
}

/// The near/far detector for the window of `g` (rebuilt when it changes; starts far).
fn detector_slot<'a>(
    slot: &'a mut Option<(SensorGeometry, NearFarDetector)>,
    cfg: &Config,
    g: SensorGeometry,
    roi: Roi,
) -> Result<&'a mut NearFarDetector, SourceError> {
    if slot.as_ref().is_none_or(|(geo, _)| *geo != g) {
        let det = NearFarDetector::new(detector_config(cfg, roi))
            .map_err(|e| SourceError::new(SourceErrorKind::Other, format!("detector: {e}")))?;
        *slot = Some((g, det));
    }
    match slot {
        Some((_, d)) => Ok(d),
        None => Err(SourceError::new(SourceErrorKind::Other, "detector missing")),
    }
}

/// Whether every code of every raw image is 0 or full scale.
fn rails_only(c: &RawCycle) -> bool {
    let max = c.geometry.max_code() as f32;
    !c.frames.any(|v| v > 0.0 && v < max)
}

/// Run a pipeline on the first `k` raw images, whatever their sample type.
fn process_images<'p>(
    p: &'p mut Pipeline,
    frames: &RawImages,
    phases_deg: &[f64],
    k: usize,
) -> Result<&'p DepthFrame, SourceError> {
    // the images' canonical shifts (a replayed recording of a sensor with another phase
    // convention: docs/recording-format.md); check_cycle accepted them
    let algorithm = if k == 4 {
        Algorithm::FourPhase
    } else {
        Algorithm::TwoPhase
    };
    p.set_quadrature(Quadrature::of_canonical(phases_deg, algorithm).unwrap_or_default());
    let r = match frames {
        RawImages::U16(a) => p.process(a.slice(s![0..k, .., ..])),
        RawImages::F32(a) => p.process(a.slice(s![0..k, .., ..])),
    };
    r.map_err(|e| SourceError::new(SourceErrorKind::CorruptFrame, format!("processing: {e}")))
}

/// The amplitude scale for the frame's window: the calibration's map cropped, or the nominal
/// scale everywhere.
fn amplitude_scale_slot<'a>(
    slot: &'a mut Option<(SensorGeometry, ndarray::Array2<f32>)>,
    full: Option<&AmplitudeScale>,
    nominal: f64,
    g: SensorGeometry,
) -> Result<&'a ndarray::Array2<f32>, SourceError> {
    if slot.as_ref().is_none_or(|(geo, _)| *geo != g) {
        let map = match full {
            Some(a) => crop_map(&a.lsb_m2_per_us, g, "amplitude")
                .map_err(|m| SourceError::new(SourceErrorKind::Unsupported, m))?,
            None => AmplitudeScale::uniform(g.rows, g.cols, nominal as f32).lsb_m2_per_us,
        };
        *slot = Some((g, map));
    }
    match slot {
        Some((_, m)) => Ok(m),
        None => Err(SourceError::new(
            SourceErrorKind::Other,
            "amplitude scale missing",
        )),
    }
}

/// A full-array per-pixel map cropped to the frame's window.
fn crop_map(
    a: &ndarray::Array2<f32>,
    g: SensorGeometry,
    what: &str,
) -> Result<ndarray::Array2<f32>, String> {
    let [r0, c0] = g.roi_origin;
    if a.nrows() == g.rows && a.ncols() == g.cols && r0 == 0 && c0 == 0 {
        return Ok(a.clone());
    }
    if r0 + g.rows > a.nrows() || c0 + g.cols > a.ncols() {
        return Err(format!(
            "{what} calibration is {}x{}, frame window {}x{} at {:?} does not fit",
            a.nrows(),
            a.ncols(),
            g.rows,
            g.cols,
            g.roi_origin
        ));
    }
    Ok(a.slice(s![r0..r0 + g.rows, c0..c0 + g.cols]).to_owned())
}

fn crop_calibration(full: &Calibration, g: SensorGeometry) -> Result<Calibration, String> {
    let crop = |a: &ndarray::Array2<f32>, what: &str| crop_map(a, g, what);
    let mut out = full.clone();
    if let Some(o) = &mut out.offset {
        o.dark_lsb = crop(&o.dark_lsb, "offset")?;
    }
    if let Some(f) = &mut out.fppn {
        f.phase_offset_rad = crop(&f.phase_offset_rad, "fppn")?;
    }
    if let Some(x) = &mut out.crosstalk {
        let planes = x
            .lsb_per_us
            .outer_iter()
            .map(|p| crop(&p.to_owned(), "crosstalk"))
            .collect::<Result<Vec<_>, _>>()?;
        let views: Vec<_> = planes.iter().map(|p| p.view()).collect();
        x.lsb_per_us = ndarray::stack(Axis(0), &views).map_err(|e| format!("crosstalk: {e}"))?;
    }
    Ok(out)
}

/// The calibration applied at another modulation frequency (no calibration set holds one
/// for it): the dark offset (no modulation in it), the per-pixel phase offsets scaled as a
/// propagation delay (`φ = 2π·f·τ`, eq. 2.6), the cover-window crosstalk (a return from
/// millimetres: its phase `4π·f·d/c` is ≈ 0 at either frequency) and this frequency's wiggling
/// LUT with its global phase offset — on the phone sensor the second frequency's residual is
/// then ≈ 5 cm, within what the unwrapping tolerates (the aliases lie ≥ 27 cm apart); without
/// the LUT it is 23 cm, and a near face unwraps to an alias.
fn at_second_frequency(full: &Calibration, frequency_ratio: f64) -> Calibration {
    let mut fppn = full.fppn.clone();
    if let Some(f) = &mut fppn {
        f.phase_offset_rad
            .mapv_inplace(|p| (f64::from(p) * frequency_ratio) as f32);
    }
    Calibration {
        offset: full.offset.clone(),
        fppn,
        crosstalk: full.crosstalk.clone(),
        wiggling: full.wiggling.clone(),
    }
}

fn common_mode_lsb<T: RawSample>(frames: ArrayView3<'_, T>, roi: Roi, dark: f32) -> f32 {
    let mut sum = 0.0f64;
    let mut n = 0usize;
    for img in frames.axis_iter(Axis(0)).take(4) {
        let v = img.slice(s![
            roi.row0..roi.row0 + roi.rows,
            roi.col0..roi.col0 + roi.cols
        ]);
        for &x in v.iter() {
            sum += f64::from(x.to_f32());
            n += 1;
        }
    }
    if n == 0 {
        0.0
    } else {
        (sum / n as f64) as f32 - dark
    }
}

#[derive(Debug, Clone, Copy)]
struct RoiStats {
    saturated_fraction: f32,
    low_amplitude_fraction: f32,
}

fn roi_stats(f: &DepthFrame, roi: Roi) -> RoiStats {
    let v = f.flags.slice(s![
        roi.row0..roi.row0 + roi.rows,
        roi.col0..roi.col0 + roi.cols
    ]);
    let n = v.len().max(1) as f32;
    let sat = v.iter().filter(|&&x| x & FLAG_SATURATED != 0).count() as f32;
    let low = v
        .iter()
        .filter(|&&x| x & FLAG_LOW_AMPLITUDE != 0 && x & FLAG_SATURATED == 0)
        .count() as f32;
    RoiStats {
        saturated_fraction: sat / n,
        low_amplitude_fraction: low / n,
    }
}

fn roi_median_mm(f: &DepthFrame, roi: Roi) -> Option<f64> {
    let v = f.depth_mm.slice(s![
        roi.row0..roi.row0 + roi.rows,
        roi.col0..roi.col0 + roi.cols
    ]);
    let mut vals: Vec<u16> = v.iter().copied().filter(|&d| d != 0).collect();
    if vals.is_empty() {
        return None;
    }
    let mid = vals.len() / 2;
    let (_, m, _) = vals.select_nth_unstable(mid);
    Some(f64::from(*m))
}

fn depth_message(f: &DepthFrame, timestamp_ns: u64) -> DepthMessage {
    let (rows, cols) = f.dim();
    let mut depth_le = Vec::with_capacity(rows * cols * 2);
    for &d in f.depth_mm.iter() {
        depth_le.extend_from_slice(&d.to_le_bytes());
    }
    let mut amplitude_le = Vec::with_capacity(rows * cols * 2);
    for &a in f.amplitude_lsb.iter() {
        let a = if a.is_finite() {
            a.round().clamp(0.0, 65535.0) as u16
        } else {
            0
        };
        amplitude_le.extend_from_slice(&a.to_le_bytes());
    }
    DepthMessage {
        timestamp_ns,
        width: u16::try_from(cols).unwrap_or(u16::MAX),
        height: u16::try_from(rows).unwrap_or(u16::MAX),
        depth_le,
        amplitude_le,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::{ScriptedSource, Step};

    fn cfg() -> Config {
        let mut c = Config::default();
        c.ambient.probe_every = 1000;
        c
    }

    fn ctl(steps: Vec<Step>) -> Controller<ScriptedSource> {
        Controller::new(
            cfg(),
            ScriptedSource::new(24, 32, steps),
            ModeCalibrations::default(),
        )
        .unwrap()
    }

    #[test]
    fn cycles_with_real_world_float_shifts_are_accepted_other_shifts_refused() {
        let mut src = ScriptedSource::new(24, 32, vec![Step::target(800.0)]);
        let req = CycleRequest {
            mode: Mode::FourPhase,
            exposure_us: 100.0,
            row_window: None,
            modulation_hz: None,
            single_image: None,
        };
        let mut c = src.cycle(&req).unwrap();
        assert_eq!(check_cycle(&c).unwrap(), Mode::FourPhase);
        // shifts as f32 radians (π/2 → 90.0000025°) and a −0° wrapped to 359.99…°
        c.phases_deg = [0.0f32, 90.0, 180.0, 270.0]
            .iter()
            .map(|d| f64::from(d.to_radians()).to_degrees())
            .collect();
        c.phases_deg[0] = 360.0 - 1e-9;
        assert!(c.phases_deg.iter().any(|p| (p - p.round()).abs() > 1e-6));
        assert_eq!(check_cycle(&c).unwrap(), Mode::FourPhase);
        // a sensor shifting its illumination: [0, 270, 180, 90] canonical
        c.phases_deg = vec![0.0, 270.0, 180.0, 90.0];
        assert_eq!(check_cycle(&c).unwrap(), Mode::FourPhase);
        // a 1° offset is another shift (a wrong depth, not a float rounding)
        c.phases_deg = vec![0.0, 91.0, 180.0, 270.0];
        assert!(check_cycle(&c).is_err());
    }

    #[test]
    fn near_at_once_far_after_debounce() {
        let mut c = ctl(vec![
            Step::target(800.0),
            Step::target(50.0),
            Step::target(800.0),
            Step::target(800.0),
            Step::target(800.0),
        ]);
        let o = c.step(false);
        assert!(o.valid && !o.near, "{o:?}");
        assert!(
            o.distance_mm.is_some_and(|d| d.abs_diff(800) < 30),
            "{:?}",
            o.distance_mm
        );
        assert!(c.step(false).near, "near at once");
        assert!(c.step(false).near, "debounce 1");
        assert!(c.step(false).near, "debounce 2");
        assert!(!c.step(false).near, "far after 3");
    }

    /// Every update carries a CLOCK_BOOTTIME stamp taken between the cycle's call and its
    /// return (the capture's frames are in), read against `/proc/uptime` (an independent view
    /// of the same clock), never going backwards — failed cycles and the stop included.
    #[test]
    fn every_update_carries_the_capture_time_on_boottime() {
        let uptime_ns = || -> u64 {
            let s = std::fs::read_to_string("/proc/uptime").expect("/proc/uptime");
            let secs: f64 = s.split_whitespace().next().unwrap().parse().unwrap();
            (secs * 1e9) as u64
        };
        let mut c = ctl(vec![
            Step::target(800.0),
            Step::target(50.0),
            Step::Fail(SourceErrorKind::Timeout),
            Step::target(800.0),
        ]);
        let mut last = 0;
        for _ in 0..4 {
            let before = uptime_ns();
            let t = c.step(false).update.timestamp_ns.expect("stamped");
            let after = uptime_ns();
            // /proc/uptime has 10 ms resolution
            assert!(
                t + 20_000_000 >= before && t <= after + 20_000_000,
                "{before} ≤ {t} ≤ {after}"
            );
            assert!(t >= last, "monotone: {last} then {t}");
            last = t;
        }
        let t = c.stop().timestamp_ns.expect("the stop is stamped");
        assert!(t >= last);
    }

    #[test]
    fn failures_never_publish_near_and_recover() {
        let mut c = ctl(vec![
            Step::target(800.0),
            Step::Fail(SourceErrorKind::Timeout),
            Step::Garbage,
            Step::Fail(SourceErrorKind::Disconnected),
            Step::target(800.0),
        ]);
        assert!(!c.step(false).near);
        let o = c.step(false);
        assert_eq!(o.update.state, Some(State::Error));
        assert!(
            o.update
                .last_error
                .as_deref()
                .is_some_and(|e| e.contains("timeout"))
        );
        assert_eq!(o.update.near, None, "a failed cycle does not touch Near");
        let o = c.step(false);
        assert!(!o.valid && o.update.near.is_none(), "{o:?}");
        assert!(!o.near, "garbage (all-zero) frame must not read as near");
        let o = c.step(false);
        assert_eq!(o.update.state, Some(State::Unavailable));
        let o = c.step(false);
        assert_eq!(o.update.state, Some(State::Running));
        assert_eq!(
            o.update.last_error.as_deref(),
            Some(""),
            "error cleared on recovery"
        );
    }

    #[test]
    fn partial_readout_requests_a_window_around_the_roi() {
        let mut c = ctl(vec![Step::target(800.0)]);
        c.step(false);
        let w = c.source().requests[0].row_window.expect("window requested");
        // central half of 24 rows = rows 6..18, margin 2 → 4..20
        assert_eq!((w.row0, w.rows), (4, 16));
        let mut c = Controller::new(
            cfg(),
            ScriptedSource::new(24, 32, vec![Step::target(800.0)]).without_row_window(),
            ModeCalibrations::default(),
        )
        .unwrap();
        assert!(c.step(false).valid);
        assert_eq!(c.source().requests[0].row_window, None);
    }

    #[test]
    fn adaptive_rate_fast_when_approaching_slow_when_still() {
        let mut steps = vec![
            Step::target(900.0),
            Step::target(700.0),
            Step::target(500.0),
        ];
        steps.extend(std::iter::repeat_n(Step::target(900.0), 14));
        let mut c = ctl(steps);
        c.step(false);
        assert_eq!(c.rate_hz(), 2.0);
        c.step(false);
        assert_eq!(c.rate_hz(), 10.0, "approaching 200 mm in 0.5 s");
        c.step(false);
        for _ in 0..13 {
            c.step(false);
        }
        assert_eq!(c.rate_hz(), 1.0, "far and still → slow");
    }

    #[test]
    fn background_light_switches_to_4phase_and_back() {
        let mut cfg = cfg();
        cfg.ambient.probe_every = 3;
        cfg.ambient.low_readings = 2;
        let bright = Step::Target {
            distance_mm: 800.0,
            amplitude_lsb: 300.0,
            background_lsb: 200.0,
        };
        let mut steps = vec![bright.clone(); 6];
        steps.extend(vec![Step::target(800.0); 4]);
        let mut c = Controller::new(
            cfg,
            ScriptedSource::new(24, 32, steps),
            ModeCalibrations::default(),
        )
        .unwrap();
        c.step(false);
        c.step(false);
        assert_eq!(c.mode(), Mode::TwoPhase);
        let o = c.step(false);
        assert_eq!(o.captured_mode, Some(Mode::FourPhase), "probe");
        assert_eq!(c.mode(), Mode::FourPhase, "ambient {:?}", c.ambient_lsb);
        for _ in 0..3 {
            c.step(false);
            assert_eq!(c.mode(), Mode::FourPhase);
        }
        c.step(false);
        assert_eq!(c.mode(), Mode::FourPhase, "hysteresis: 1 low reading");
        c.step(false);
        assert_eq!(c.mode(), Mode::TwoPhase, "2 low readings → back");
        c.step(false);
        assert_eq!(
            c.source().requests.last().map(|r| r.mode),
            Some(Mode::TwoPhase)
        );
    }

    #[test]
    fn auto_exposure_bounded() {
        let weak = Step::Target {
            distance_mm: 800.0,
            amplitude_lsb: 2.0,
            background_lsb: 0.0,
        };
        let mut c = ctl(vec![weak; 20]);
        for _ in 0..20 {
            c.step(false);
        }
        // the decision's need: a 2 % target at far_mm (150 mm) returns min_amplitude_lsb (8)
        // with the nominal K 0.09 LSB·m²/µs after 8 · 0.15² / (0.09 · 0.02) = 100 µs
        let need_us = 8.0 * 0.15 * 0.15 / (0.09 * 0.02);
        assert!(
            (c.exposure_us() - need_us).abs() < 1e-6,
            "lengthened up to the decision's need, not the eye-safe max: {}",
            c.exposure_us()
        );
        c.exposure.set_decision_us(None);
        for _ in 0..20 {
            c.step(false);
        }
        assert_eq!(c.exposure_us(), 500.0, "without it: up to the eye-safe max");
        let hot = Step::Target {
            distance_mm: 800.0,
            amplitude_lsb: 4000.0,
            background_lsb: 0.0,
        };
        c.source_mut().push(vec![hot; 20]);
        for _ in 0..20 {
            c.step(false);
        }
        // amplitude scales with exposure: 4000 LSB × t/100 µs fits the 12-bit range below ~51 µs
        let t = c.exposure_us();
        assert!(
            (20.0..51.0).contains(&t),
            "shortened until unsaturated, never below min: {t}"
        );
    }

    #[test]
    fn calibration_keyed_to_mode() {
        let lut = tofprox_core::calib::WigglingLut {
            algorithm: Algorithm::FourPhase,
            correction_rad: ndarray::Array1::zeros(16),
        };
        let calib = ModeCalibrations {
            two_phase: Calibration {
                wiggling: Some(lut),
                ..Calibration::default()
            },
            ..ModeCalibrations::default()
        };
        let err = Controller::new(cfg(), ScriptedSource::new(4, 4, vec![]), calib)
            .err()
            .unwrap();
        assert!(err.to_string().contains("refused"), "{err}");
    }

    #[test]
    fn roi_outside_the_sensor_is_refused_naming_the_key() {
        for roi in [
            [20, 0, 10, 10],
            [0, 30, 4, 4],
            [0, 0, 0, 4],
            [usize::MAX, 0, 2, 2],
        ] {
            let mut c = cfg();
            c.proximity.roi = Some(roi);
            let err = Controller::new(
                c,
                ScriptedSource::new(24, 32, vec![]),
                ModeCalibrations::default(),
            )
            .err()
            .unwrap_or_else(|| panic!("{roi:?} accepted"));
            let msg = err.to_string();
            assert!(
                msg.contains("proximity.roi") && msg.contains("24x32"),
                "{msg}"
            );
        }
        let mut c = cfg();
        c.proximity.roi = Some([14, 22, 10, 10]);
        assert!(
            Controller::new(
                c,
                ScriptedSource::new(24, 32, vec![]),
                ModeCalibrations::default()
            )
            .is_ok(),
            "touching the last row and column is inside"
        );
    }

    #[test]
    fn stop_powers_off() {
        let mut c = ctl(vec![Step::target(50.0)]);
        assert!(c.step(false).near);
        let u = c.stop();
        assert_eq!(u.state, Some(State::Off));
        assert_eq!(u.near, Some(false));
        assert_eq!(c.source().power_offs, 1);
    }

    /// The rails path (every code on a rail) is paced and accounted by the same rule as a
    /// processed cycle: no sleep when a recording is replayed as fast as possible, the rest
    /// of the period otherwise, and the cycle enters the energy meter either way.
    #[test]
    fn rails_cycles_follow_the_replay_pacing_and_are_accounted() {
        let mut replay = cfg();
        replay.backend = crate::config::Backend::Replay;
        replay.replay.realtime = false;
        let mut c = Controller::new(
            replay,
            ScriptedSource::new(24, 32, vec![Step::Garbage, Step::target(800.0)]),
            ModeCalibrations::default(),
        )
        .unwrap();
        let rails = c.step(false);
        assert!(!rails.valid && rails.error.is_none(), "{rails:?}");
        assert_eq!(
            rails.sleep,
            Duration::ZERO,
            "unpaced replay: no sleep after a rails frame"
        );
        let ok = c.step(false);
        assert!(ok.valid);
        assert_eq!(ok.sleep, Duration::ZERO);
        assert_eq!(c.energy().cycles(), 2, "both cycles accounted");

        let mut c = ctl(vec![Step::Garbage]);
        let rails = c.step(false);
        let period = Duration::from_secs_f64(1.0 / c.rate_hz());
        assert!(
            rails.sleep > Duration::ZERO && rails.sleep < period,
            "paced: the rest of the period, {:?}",
            rails.sleep
        );
        assert!(rails.update.power_mw.is_some_and(|p| p > 0.0));
    }

    /// Saturation is evidence (issue 21): a cheek on the window saturating every code at the
    /// shortest exposure is near for as long as it lasts — far beyond `loop.near_hold_ms` —
    /// after one 4-phase confirmation at `exposure.min_us`; an all-zero frame is no data and a
    /// held Near is released within the bound.
    #[test]
    fn a_saturating_cheek_is_near_while_it_lasts_zeros_are_no_data() {
        let cheek = Step::Target {
            distance_mm: 10.0,
            amplitude_lsb: 1e6,
            background_lsb: 0.0,
        };
        let mut steps = vec![Step::target(800.0)];
        steps.extend(std::iter::repeat_n(cheek, 40));
        steps.extend(std::iter::repeat_n(Step::Garbage, 30));
        let mut c = ctl(steps);
        assert!(!c.step(false).near);
        let first = c.step(false);
        assert!(!first.valid && !first.near, "confirm first: {first:?}");
        let confirmed = c.step(false);
        let req = c.source().requests[2];
        assert_eq!(req.mode, Mode::FourPhase, "the confirmation is 4-phase");
        assert_eq!(
            req.exposure_us, c.cfg.exposure.min_us,
            "at the shortest exposure"
        );
        assert!(confirmed.valid && confirmed.near, "{confirmed:?}");
        let hold = Duration::from_millis(c.cfg.loop_.near_hold_ms);
        let mut held = Duration::ZERO;
        for _ in 0..38 {
            let o = c.step(false);
            assert!(o.valid && o.near, "{o:?}");
            assert_eq!(
                o.update.distance_mm,
                Some(0),
                "near from saturation: unknown"
            );
            held += o.sleep;
        }
        assert!(held > 2 * hold, "near for {held:?}, beyond the hold bound");
        assert_eq!(c.exposure_us(), c.cfg.exposure.min_us);
        // all-zero frames: no data; Near held at most near_hold_ms since the last reading
        let mut since = Duration::ZERO;
        let mut released = false;
        for _ in 0..30 {
            let o = c.step(false);
            assert!(!o.valid, "{o:?}");
            since += o.sleep;
            if !o.near {
                released = true;
                break;
            }
            assert!(since < hold + o.sleep, "held {since:?}");
        }
        assert!(released, "Near released after the hold bound");
    }

    /// A bright target just beyond the unambiguous range (2.498 m at the scripted 60 MHz)
    /// wraps to 50 mm with the amplitude of a 1000× retroreflector (`K·G·t/d²`, K = 0.09
    /// LSB·m²/µs nominal, 100 µs): the second frequency puts it at 2.55 m, Far is published;
    /// a hand at 50 mm is confirmed and Near published. The extra capture is accounted.
    #[test]
    fn a_dim_near_candidate_is_confirmed_at_the_second_frequency() {
        let du = tofprox_core::phasor::unambiguous_range_m(60e6);
        let retro = Step::Target {
            distance_mm: (du + 0.05) * 1e3,
            amplitude_lsb: 0.09 * 1000.0 * 100.0 / (du + 0.05).powi(2),
            background_lsb: 0.0,
        };
        let mut c = ctl(vec![retro.clone(), retro, Step::target(50.0)]);
        for _ in 0..2 {
            let o = c.step(false);
            assert!(o.valid && !o.near, "aliased retroreflector is far: {o:?}");
        }
        let asked: Vec<_> = c
            .source()
            .requests
            .iter()
            .map(|r| r.modulation_hz)
            .collect();
        assert_eq!(asked, [None, Some(70e6), None, Some(70e6)]);
        let o = c.step(false);
        assert!(o.near, "a hand at 50 mm is confirmed: {o:?}");
        assert_eq!(c.source().requests.len(), 6);
        assert!(c.step(false).near);
        assert_eq!(
            c.source().requests.len(),
            7,
            "no confirmation while a confirmed near lasts"
        );
        assert_eq!(
            c.energy().cycles(),
            4,
            "one reading per step, both captures in it"
        );

        // off: the amplitude test decides alone, the retroreflector reads near
        let mut off = cfg();
        off.proximity.second_modulation_hz = 0.0;
        let retro = Step::Target {
            distance_mm: (du + 0.05) * 1e3,
            amplitude_lsb: 0.09 * 1000.0 * 100.0 / (du + 0.05).powi(2),
            background_lsb: 0.0,
        };
        let mut c = Controller::new(
            off,
            ScriptedSource::new(24, 32, vec![retro]),
            ModeCalibrations::default(),
        )
        .unwrap();
        assert!(c.step(false).near, "one frequency cannot tell");
    }

    #[test]
    fn depth_message_only_when_wanted() {
        let mut c = ctl(vec![Step::target(800.0)]);
        assert!(c.step(false).depth.is_none());
        let d = c.step(true).depth.expect("depth");
        assert_eq!(
            d.depth_le.len(),
            usize::from(d.width) * usize::from(d.height) * 2
        );
    }
}
