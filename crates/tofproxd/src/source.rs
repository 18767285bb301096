//! Frame sources: one cycle → raw frames + state timings, or a typed error.
//!
//! The seam [`FrameSource`] and its source-neutral cycle [`RawCycle`]; the backends that
//! implement it live above (the crate's `backends`). With the feature `testing` (and in the
//! crate's own tests) also `ScriptedSource`, a scripted fake in the style of probe-rs's fake
//! probe, and `synth_frames` (module `scripted`).

use std::time::Duration;

use ndarray::{Array3, ArrayView3};
use tofprox_core::SensorGeometry;
use tofprox_core::pipeline::RawSample;

use crate::energy::CycleTimings;

#[cfg(any(test, feature = "testing"))]
mod scripted;
#[cfg(any(test, feature = "testing"))]
pub use scripted::{ScriptedSource, Step, synth_frames};

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
    /// The largest row step the source reads (`RowWindow::row_step`; 1: every row).
    fn max_row_step(&self) -> u16 {
        1
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
