//! The per-window state kept across cycles — the pipeline of each mode (and of each mode at
//! the second frequency), the detector and the amplitude scale, each rebuilt when the
//! read-out window changes — and a capture run through a pipeline.

use ndarray::{Array2, s};
use tofprox_core::phasor::Quadrature;
use tofprox_core::pipeline::{Calibration, DepthFrame, Pipeline, PipelineConfig};
use tofprox_core::proximity::{NearFarConfig, NearFarDetector, Roi};
use tofprox_core::radiometry::AmplitudeScale;
use tofprox_core::readout::{crop_calibration, crop_map};
use tofprox_core::{Algorithm, SensorGeometry};

use crate::config::{Config, Mode};
use crate::source::{RawImages, SourceError, SourceErrorKind};

/// A pipeline kept with the read-out window it was built for.
pub(super) type PipelineSlot = Option<(SensorGeometry, Pipeline)>;

/// The slot of `mode` in `[2-phase, 4-phase]`.
pub(super) fn mode_index(mode: Mode) -> usize {
    match mode {
        Mode::TwoPhase => 0,
        Mode::FourPhase => 1,
    }
}

/// The detector's parameters for an ROI.
pub(super) fn detector_config(cfg: &Config, roi: Roi) -> NearFarConfig {
    NearFarConfig {
        near_mm: cfg.proximity.near_mm,
        far_mm: cfg.proximity.far_mm,
        roi,
        far_debounce: cfg.proximity.far_debounce,
        min_valid_fraction: cfg.proximity.min_valid_fraction,
    }
}

/// The pipeline of `mode` for the window of `g` in its slot (built with `full` cropped to the
/// window when the window changed), set to this cycle's exposure and crosstalk scale:
/// `(exposure_us, crosstalk_scale)`.
pub(super) fn pipeline_slot<'a>(
    slot: &'a mut PipelineSlot,
    full: &Calibration,
    min_amplitude_lsb: f32,
    mode: Mode,
    g: SensorGeometry,
    (exposure_us, crosstalk_scale): (f64, f32),
) -> Result<&'a mut Pipeline, SourceError> {
    if slot.as_ref().is_none_or(|(geo, _)| *geo != g) {
        let calib = crop_calibration(full, g)
            .map_err(|e| SourceError::new(SourceErrorKind::Unsupported, e.to_string()))?;
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
pub(super) fn detector_slot<'a>(
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

/// Run a pipeline on the first `k` raw images, whatever their sample type.
pub(super) fn process_images<'p>(
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
pub(super) fn amplitude_scale_slot<'a>(
    slot: &'a mut Option<(SensorGeometry, Array2<f32>)>,
    full: Option<&AmplitudeScale>,
    nominal: f64,
    g: SensorGeometry,
) -> Result<&'a Array2<f32>, SourceError> {
    if slot.as_ref().is_none_or(|(geo, _)| *geo != g) {
        let map = match full {
            Some(a) => crop_map(&a.lsb_m2_per_us, g, "amplitude")
                .map_err(|e| SourceError::new(SourceErrorKind::Unsupported, e.to_string()))?,
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
