//! Test machinery (feature `testing`, and the crate's own tests): [`ScriptedSource`], a
//! scripted fake frame source, and [`synth_frames`], ideal raw frames of a flat target.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

use ndarray::Array3;
use tofprox_bridge::clock::{Clock, VirtualClock};
use tofprox_core::SensorGeometry;

use super::{CycleRequest, FrameSource, RawCycle, RawImages, SourceError, SourceErrorKind};
use crate::config::Mode;
use crate::energy::CycleTimings;

/// One scripted step of [`ScriptedSource`].
#[derive(Debug, Clone)]
pub enum Step {
    /// A flat target at `distance_mm` with `amplitude_lsb`, `background_lsb` common-mode
    /// (rejected by 4-phase, a bias on 2-phase), `saturated` = clip every code at full scale.
    Target {
        /// Distance (mm).
        distance_mm: f64,
        /// Signal amplitude (LSB).
        amplitude_lsb: f64,
        /// Background-light common-mode (LSB).
        background_lsb: f64,
    },
    /// A failed cycle.
    Fail(SourceErrorKind),
    /// A frame whose codes are garbage (all zeros: reads as invalid/saturated-low).
    Garbage,
}

impl Step {
    /// A flat target at `distance_mm` with a strong signal (400 LSB at 100 µs) and no
    /// background light.
    pub fn target(distance_mm: f64) -> Self {
        Step::Target {
            distance_mm,
            amplitude_lsb: 400.0,
            background_lsb: 0.0,
        }
    }
}

/// Scripted fake source: a queue of steps, then repeats the last step. A request at another
/// modulation frequency (`CycleRequest::modulation_hz`) renders the step just served again at
/// that frequency (the second-frequency images of the same cycle).
/// Synthesises ideal frames by the convention of `tofprox-core` (crate documentation)
/// `code_k = mid + A cos(phi - theta_k) + background` of a 12-bit ADC.
#[derive(Debug)]
pub struct ScriptedSource {
    steps: VecDeque<Step>,
    last: Step,
    served: Option<Step>,
    rows: usize,
    cols: usize,
    modulation_hz: f64,
    /// Every request seen (for assertions).
    pub requests: Vec<CycleRequest>,
    /// Number of `power_off` calls.
    pub power_offs: u32,
    window_support: bool,
    /// The source's own clock ([`ScriptedSource::with_clock`]) and how long a failed cycle takes.
    clock: Option<(Arc<VirtualClock>, Duration)>,
}

impl ScriptedSource {
    /// New scripted source of `rows × cols` pixels.
    pub fn new(rows: usize, cols: usize, steps: impl IntoIterator<Item = Step>) -> Self {
        let steps: VecDeque<Step> = steps.into_iter().collect();
        let last = steps
            .back()
            .cloned()
            .unwrap_or(Step::Fail(SourceErrorKind::EndOfData));
        Self {
            steps,
            last,
            served: None,
            rows,
            cols,
            modulation_hz: 60e6,
            requests: Vec::new(),
            power_offs: 0,
            window_support: true,
            clock: None,
        }
    }

    /// With a clock of its own (`FrameSource::now`, virtual): each cycle moves it on by its
    /// active states' time, a failed one by `fail_takes` (a transfer timeout, a reset that
    /// hangs); the caller moves it on by the loop's sleeps.
    pub fn with_clock(mut self, clock: Arc<VirtualClock>, fail_takes: Duration) -> Self {
        self.clock = Some((clock, fail_takes));
        self
    }

    /// Disable row-window support.
    pub fn without_row_window(mut self) -> Self {
        self.window_support = false;
        self
    }

    /// Append steps.
    pub fn push(&mut self, steps: impl IntoIterator<Item = Step>) {
        self.steps.extend(steps);
        if let Some(s) = self.steps.back() {
            self.last = s.clone();
        }
    }

    /// Modulation frequency used to synthesise phases.
    pub fn modulation_hz(&self) -> f64 {
        self.modulation_hz
    }
}

/// ADC resolution of the frames [`synth_frames`] makes.
const SYNTH_ADC_BITS: u8 = 12;

/// Synthesise ideal raw frames of a flat target (the `tofprox-core` convention, eq. 2.6 inverted).
pub fn synth_frames(
    mode: Mode,
    rows: usize,
    cols: usize,
    distance_mm: f64,
    amplitude_lsb: f64,
    background_lsb: f64,
    modulation_hz: f64,
) -> (Array3<u16>, Vec<f64>) {
    let phases = mode.phases_deg().to_vec();
    let phi = tofprox_core::phasor::distance_to_phase_rad(distance_mm / 1e3, modulation_hz);
    let mid = f64::from(tofprox_core::sensor::adc_mid_code(SYNTH_ADC_BITS));
    let max = f64::from(tofprox_core::sensor::adc_max_code(SYNTH_ADC_BITS));
    let mut frames = Array3::<u16>::zeros((phases.len(), rows, cols));
    for (k, th) in phases.iter().enumerate() {
        let code = mid + background_lsb + amplitude_lsb * (phi - th.to_radians()).cos();
        let code = code.round().clamp(0.0, max) as u16;
        frames.index_axis_mut(ndarray::Axis(0), k).fill(code);
    }
    (frames, phases)
}

impl FrameSource for ScriptedSource {
    fn cycle(&mut self, req: &CycleRequest) -> Result<RawCycle, SourceError> {
        self.requests.push(*req);
        let step = match (req.modulation_hz, &self.served) {
            (Some(_), Some(served)) => served.clone(),
            _ => self.steps.pop_front().unwrap_or_else(|| self.last.clone()),
        };
        self.served = Some(step.clone());
        let modulation_hz = req.modulation_hz.unwrap_or(self.modulation_hz);
        let (row0, rows) = match (self.window_support, req.row_window) {
            (true, Some(w)) => {
                let row0 = usize::from(w.row0).min(self.rows.saturating_sub(1));
                (row0, usize::from(w.rows).min(self.rows - row0).max(1))
            }
            _ => (0, self.rows),
        };
        let k = req.mode.raw_images() as u32;
        let timings = CycleTimings {
            startup: Duration::from_millis(1),
            config_load: Duration::from_millis(10),
            exposure: Duration::from_secs_f64(f64::from(k) * req.exposure_us / 1e6),
            readout: Duration::from_micros(2500 * u64::from(k)),
            ..CycleTimings::default()
        };
        if let Some((clock, fail_takes)) = &self.clock {
            clock.advance(match step {
                Step::Fail(_) => *fail_takes,
                _ => timings.active(),
            });
        }
        let (frames, phases_deg) = match step {
            Step::Fail(kind) => return Err(SourceError::new(kind, "scripted failure")),
            Step::Target {
                distance_mm,
                amplitude_lsb,
                background_lsb,
            } => synth_frames(
                req.mode,
                rows,
                self.cols,
                distance_mm,
                amplitude_lsb * req.exposure_us / 100.0,
                background_lsb,
                modulation_hz,
            ),
            Step::Garbage => {
                let (_, ph) = synth_frames(req.mode, 1, 1, 0.0, 0.0, 0.0, self.modulation_hz);
                (Array3::zeros((ph.len(), rows, self.cols)), ph)
            }
        };
        let geometry = SensorGeometry {
            rows,
            cols: self.cols,
            roi_origin: [row0, 0],
            full_rows: self.rows,
            full_cols: self.cols,
            adc_bits: SYNTH_ADC_BITS,
            modulation_hz,
        };
        Ok(RawCycle {
            frames: RawImages::U16(frames),
            phases_deg,
            exposure_us: req.exposure_us,
            geometry,
            timings: Some(timings),
        })
    }

    fn power_off(&mut self) -> Result<(), SourceError> {
        self.power_offs += 1;
        Ok(())
    }

    fn supports_row_window(&self) -> bool {
        self.window_support
    }

    fn sensor(&self) -> SensorGeometry {
        SensorGeometry::full(self.rows, self.cols, SYNTH_ADC_BITS, self.modulation_hz)
    }

    fn now(&self) -> Option<Duration> {
        self.clock.as_ref().map(|(c, _)| c.now())
    }

    fn describe(&self) -> String {
        format!("scripted {}x{}", self.rows, self.cols)
    }
}
