//! One station step's captures: `frames` measurements of one mode and exposure, averaged
//! into one capture per illumination (thesis 3.4.2.1: raw frames averaged in floating
//! point), written as a recording the extraction reads.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;

use ndarray::{Array3, Axis};
use tofprox_bridge::{Clock, CycleOutput, CycleRequest, SensorDriver, SensorMode, UsbTransport};
use tofprox_format::{CaptureSpec, RawFrames, RecordingWriter};

use crate::{CaptureSpec as StepSpec, StationError};

/// Retries of a measurement after a transient device error (the driver recovers at the next
/// cycle), as `tofprox device capture` does by default.
const RETRIES: u32 = 2;

/// What a step asks of the device.
pub(crate) struct StepRequest<'a> {
    pub step: &'a str,
    pub mode: SensorMode,
    pub spec: StepSpec,
    pub rows: Option<tofprox_core::RowWindow>,
    /// Keep only the captures of this illumination (dark: the grey image only).
    pub illumination: bool,
    pub conditions: BTreeMap<String, f64>,
}

/// Capture the step into a new recording at `dir`; returns the exposure the device programmed.
pub(crate) fn capture_step<T: UsbTransport>(
    driver: &mut SensorDriver<T>,
    clock: &dyn Clock,
    req: &StepRequest<'_>,
    dir: &Path,
) -> Result<f64, StationError> {
    let dev = |source| StationError::Device {
        step: req.step.to_string(),
        source,
    };
    let cycle = CycleRequest {
        mode: req.mode,
        exposure_us: req.spec.exposure_us,
        row_window: req.rows,
        modulation_hz: None,
        single_image: None,
    };
    driver.check_request(&cycle).map_err(dev)?;
    let mut sum: Option<(Array3<f64>, CycleOutput)> = None;
    for _ in 0..req.spec.frames {
        let out = cycle_with_retries(driver, clock, &cycle).map_err(dev)?;
        match &mut sum {
            Some((acc, _)) => *acc += &out.frames.mapv(f64::from),
            None => sum = Some((out.frames.mapv(f64::from), out)),
        }
    }
    let Some((acc, first)) = sum else {
        return Err(no_frames(req.step));
    };
    let n = f64::from(req.spec.frames);
    let mean = acc.mapv(|v| (v / n) as f32);
    let fmt = |source| StationError::Format {
        step: req.step.to_string(),
        source,
    };
    let desc = format!(
        "calibration station, step {}: {} × {} at {} µs, averaged",
        req.step, req.spec.frames, req.mode, first.exposure_us
    );
    let mut w = RecordingWriter::create(dir, first.geometry, Some(desc)).map_err(fmt)?;
    append_averaged(&mut w, &first, &mean, req).map_err(fmt)?;
    // complete only now (docs/recording-format.md, "Completeness")
    w.finish().map_err(fmt)?;
    Ok(first.exposure_us)
}

fn no_frames(step: &str) -> StationError {
    StationError::Device {
        step: step.into(),
        source: tofprox_bridge::BridgeError::config("a step captures at least one frame"),
    }
}

fn cycle_with_retries<T: UsbTransport>(
    driver: &mut SensorDriver<T>,
    clock: &dyn Clock,
    cycle: &CycleRequest,
) -> Result<CycleOutput, tofprox_bridge::BridgeError> {
    let mut attempt = 0;
    loop {
        match driver.cycle(cycle) {
            Ok(o) => return Ok(o),
            Err(e) if e.kind().is_transient() && attempt < RETRIES => {
                attempt += 1;
                clock.sleep(Duration::from_millis(100));
            }
            Err(e) => return Err(e),
        }
    }
}

/// Consecutive raw images of one illumination are one capture; only those of
/// `req.illumination` are kept.
fn append_averaged(
    w: &mut RecordingWriter,
    out: &CycleOutput,
    mean: &Array3<f32>,
    req: &StepRequest<'_>,
) -> Result<(), tofprox_format::FormatError> {
    let k = mean.dim().0;
    let lit = |i: usize| out.illuminated.get(i).copied().unwrap_or(true);
    let mut start = 0;
    while start < k {
        let il = lit(start);
        let mut end = start + 1;
        while end < k && lit(end) == il {
            end += 1;
        }
        if il == req.illumination {
            let idx: Vec<usize> = (start..end).collect();
            let spec = CaptureSpec {
                phases_deg: out.phases_deg[start..end].to_vec(),
                exposure_us: out.exposure_us,
                illumination: il,
                averaged: req.spec.frames,
                timestamp_ns: None,
                conditions: req.conditions.clone(),
            };
            w.append(spec, &RawFrames::F32(mean.select(Axis(0), &idx)))?;
        }
        start = end;
    }
    Ok(())
}
