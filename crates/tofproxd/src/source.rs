//! Frame sources: one cycle → raw frames + state timings, or a typed error.
//!
//! Backends: USB and emulated through `tofprox_bridge::SensorDriver`
//! (`crate::backends`), replay of a version 1 recording, and [`ScriptedSource`]
//! (a scripted fake for tests, in the style of probe-rs's fake probe).

use std::collections::VecDeque;
use std::time::Duration;

use ndarray::{Array3, ArrayView3};
use tofprox_core::SensorGeometry;
use tofprox_core::pipeline::RawSample;

use crate::config::Mode;
use crate::energy::CycleTimings;

/// What one cycle should capture (mode, exposure, row window) and the read-out window: the
/// shared vocabulary of `tofprox-core`.
pub use tofprox_core::{CycleRequest, RowWindow};

/// The raw images of one cycle `(K, rows, cols)` in the sample type the source delivers:
/// ADC codes from a sensor, or a recording's averaged codes as floats — never rounded, so a
/// replay processes the same numbers as `tofprox process` on the same file.
#[derive(Debug, Clone, PartialEq)]
pub enum RawImages {
    /// ADC codes.
    U16(Array3<u16>),
    /// Averaged codes (f32 and f64 recordings).
    F32(Array3<f32>),
}

impl RawImages {
    /// `(K, rows, cols)`.
    pub fn dim(&self) -> (usize, usize, usize) {
        match self {
            RawImages::U16(a) => a.dim(),
            RawImages::F32(a) => a.dim(),
        }
    }

    /// Whether any sample satisfies `f` (samples as `f32`, NaN/∞ kept).
    pub fn any(&self, f: impl Fn(f32) -> bool) -> bool {
        fn go<T: RawSample>(a: ArrayView3<'_, T>, f: impl Fn(f32) -> bool) -> bool {
            a.iter().any(|&v| f(v.to_f32()))
        }
        match self {
            RawImages::U16(a) => go(a.view(), f),
            RawImages::F32(a) => go(a.view(), f),
        }
    }
}

/// One cycle's raw data, source-neutral: the raw images with their phases and exposure,
/// the sensor geometry and read-out window, the state timings where the source measures them
/// (a recording has none). The time published with the reading is the controller's
/// (`CLOCK_BOOTTIME` when the frames are in, [`crate::boottime`]), one clock for every source.
#[derive(Debug, Clone)]
pub struct RawCycle {
    /// The raw images `(K, rows, cols)`.
    pub frames: RawImages,
    /// Phase shift of each raw image (degrees).
    pub phases_deg: Vec<f64>,
    /// Exposure per raw image (µs).
    pub exposure_us: f64,
    /// Sensor geometry and the window the images cover.
    pub geometry: SensorGeometry,
    /// Measured state durations (energy model), `None` when the source has none (replay).
    pub timings: Option<CycleTimings>,
}

impl RawCycle {
    /// State durations for the energy model (zero where the source measured none).
    pub fn timings(&self) -> CycleTimings {
        self.timings.unwrap_or_default()
    }
}

/// Kinds of source failure (mirrors the bridge's kinds the loop cares about).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceErrorKind {
    /// Device gone (unplugged): State → unavailable until it answers again.
    Disconnected,
    /// A transfer timed out.
    Timeout,
    /// Endpoint stall / I2C NAK / protocol trouble.
    Protocol,
    /// A frame was torn, short or corrupt (dropped).
    CorruptFrame,
    /// Flash empty/corrupt and could not be restored.
    Flash,
    /// Sensor did not come out of reset.
    Reset,
    /// The request cannot be served (mode/window not supported, bad data in a recording).
    Unsupported,
    /// End of a replayed recording.
    EndOfData,
    /// Anything else (I/O, config).
    Other,
}

impl SourceErrorKind {
    /// Short stable name (used in `LastError`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Disconnected => "disconnected",
            Self::Timeout => "timeout",
            Self::Protocol => "protocol",
            Self::CorruptFrame => "corrupt-frame",
            Self::Flash => "flash",
            Self::Reset => "reset",
            Self::Unsupported => "unsupported",
            Self::EndOfData => "end-of-data",
            Self::Other => "other",
        }
    }
}

/// A failed cycle: the loop's kind, a message, and the error it came from (e.g. the
/// bridge's, with its own kind and chain) as its `source()`.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{}: {message}", kind.as_str())]
pub struct SourceError {
    kind: SourceErrorKind,
    message: String,
    #[source]
    source: Option<std::sync::Arc<dyn std::error::Error + Send + Sync + 'static>>,
}

impl SourceError {
    /// New error.
    pub fn new(kind: SourceErrorKind, message: impl Into<String>) -> Self {
        Self {
            kind,
            message: message.into(),
            source: None,
        }
    }
    /// Keep `source` as the cause.
    pub fn with_source(mut self, source: impl std::error::Error + Send + Sync + 'static) -> Self {
        self.source = Some(std::sync::Arc::new(source));
        self
    }
    /// The kind.
    pub fn kind(&self) -> SourceErrorKind {
        self.kind
    }
}

/// Something that produces one reading's raw frames per call.
/// Calls block (USB transfers, emulated timing): run them off the async runtime.
pub trait FrameSource: Send {
    /// Restart → config → exposure → capture K raw images → stop → reset low.
    fn cycle(&mut self, req: &CycleRequest) -> Result<RawCycle, SourceError>;
    /// Hold the sensor in reset (fully off).
    fn power_off(&mut self) -> Result<(), SourceError>;
    /// Whether a row window is honoured.
    fn supports_row_window(&self) -> bool;
    /// Row alignment a window must respect (row0 and rows multiples of it).
    fn row_window_align(&self) -> u16 {
        1
    }
    /// The column alignment of a column window, where the source reads one (`None`: the
    /// window is whole rows).
    fn column_window_align(&self) -> Option<u16> {
        None
    }
    /// Whether the source captures a single raw image of a mode on request
    /// (`CycleRequest::single_image`: the presence probe).
    fn supports_single_image(&self) -> bool {
        false
    }
    /// Whether the source can capture 4-phase on request (replay cannot choose).
    fn supports_mode_switch(&self) -> bool {
        true
    }
    /// The sensor the source delivers, as its full array (`SensorGeometry::full_array`: ADC
    /// bits, modulation frequency, full array): what a calibration set's validity is checked
    /// against at start, before any cycle.
    fn sensor(&self) -> SensorGeometry;
    /// Full array size `(rows, cols)`.
    fn full_size(&self) -> (usize, usize) {
        let g = self.sensor();
        (g.full_rows, g.full_cols)
    }
    /// The source's clock (monotonic, the same one the cycles' time stamps and sleeps run on),
    /// `None` when it has none: the loop then counts its sleeps and the cycles' state durations.
    fn now(&self) -> Option<Duration> {
        None
    }
    /// Short description for logs/status.
    fn describe(&self) -> String;
}

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
        }
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

    fn describe(&self) -> String {
        format!("scripted {}x{}", self.rows, self.cols)
    }
}
