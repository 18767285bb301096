//! Processing a recording's captures to depth and amplitude as a workflow over the files: the
//! recording, the calibration set checked against it, the pipeline (offset → phase, eq. 2.2 /
//! 2.3 → wiggling → FPPN → depth, eq. 2.6) and, per capture, the summary row that `tofprox
//! process --json` prints. `tofprox process` and the Python package are thin adapters over
//! [`Processing`]; neither has processing logic of its own.

use std::path::{Path, PathBuf};
use std::time::Instant;

use ndarray::{Array2, s};
use serde::Serialize;
use tofprox_core::camera::RayGrid;
use tofprox_core::crosstalk::{CrosstalkCalibration, residual_ratio};
use tofprox_core::pipeline::{DepthFrame, Pipeline, PipelineConfig, depth_m_to_mm, median_valid_m};
use tofprox_core::proximity::Roi;
use tofprox_core::{Algorithm, CoreError};

use crate::calibration::CalibrationSet;
use crate::error::FormatError;
use crate::recording::{CaptureMeta, RawFrames, Recording};
use crate::text::fmt_num;

/// Which depth the depth outputs carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DepthKind {
    /// Radial distance: the length of each pixel's ray to the surface (eq. 2.6, what the phase
    /// measures).
    #[default]
    Radial,
    /// Z depth: the distance along the optical axis (radial · cos θ of the pixel's ray; needs the
    /// calibration set's intrinsics).
    Z,
}

impl DepthKind {
    /// The name on the command line and in the JSON rows: `radial` or `z`.
    pub fn name(self) -> &'static str {
        match self {
            DepthKind::Radial => "radial",
            DepthKind::Z => "z",
        }
    }
}

impl std::str::FromStr for DepthKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "radial" => Ok(DepthKind::Radial),
            "z" => Ok(DepthKind::Z),
            _ => Err(format!("depth kind `{s}`: expected `radial` or `z`")),
        }
    }
}

/// How to process: the measurement mode, the depth the outputs carry, the amplitude threshold.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProcessOptions {
    /// 2-phase (images at 0°, 90°) or 4-phase (0°, 90°, 180°, 270°).
    pub algo: Algorithm,
    /// Radial or Z depth in the depth image and the median.
    pub depth_kind: DepthKind,
    /// Pixels with a lower amplitude (LSB) are invalid.
    pub min_amplitude_lsb: f32,
}

impl ProcessOptions {
    /// Radial depth with the pipeline's default amplitude threshold.
    pub fn new(algo: Algorithm) -> Self {
        ProcessOptions {
            algo,
            depth_kind: DepthKind::Radial,
            min_amplitude_lsb: PipelineConfig::default().min_amplitude_lsb,
        }
    }
}

/// Why a recording cannot be processed.
#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    /// The recording or the calibration set does not read (the error names file and key).
    #[error(transparent)]
    Format(#[from] FormatError),
    /// The calibration set was made for another sensor configuration.
    #[error("refusing to apply {} to {}", calib.display(), recording.display())]
    Incompatible {
        /// The calibration set.
        calib: PathBuf,
        /// The recording.
        recording: PathBuf,
        /// Every mismatch.
        #[source]
        source: Box<FormatError>,
    },
    /// The set's lens does not give a ray per pixel.
    #[error("the lens of {}", calib.display())]
    Lens {
        /// The calibration set.
        calib: PathBuf,
        /// Why.
        #[source]
        source: Box<FormatError>,
    },
    /// Z depth without intrinsics.
    #[error(
        "depth kind z needs the lens: a calibration set with intrinsics (tofprox calibrate intrinsics; docs/calibration.md){}",
        calib.as_ref().map_or(String::new(), |d| format!(", and {} has none", d.display()))
    )]
    NeedsLens {
        /// The calibration set given, if any.
        calib: Option<PathBuf>,
    },
    /// No capture is an illuminated capture of the algorithm's phases.
    #[error("{} has no illuminated capture that can be processed as {algo}", recording.display())]
    NothingToProcess {
        /// The recording.
        recording: PathBuf,
        /// The measurement mode asked for.
        algo: Algorithm,
    },
    /// [`Processing::capture`] was asked for a capture the algorithm cannot process.
    #[error("capture {index} cannot be processed: {why}")]
    Unusable {
        /// The capture's index.
        index: usize,
        /// Why not.
        why: String,
    },
    /// The pipeline refused the configuration or a capture.
    #[error("{what}")]
    Core {
        /// What was being done.
        what: String,
        /// The core crate's error.
        #[source]
        source: CoreError,
    },
}

fn core(what: impl Into<String>) -> impl FnOnce(CoreError) -> ProcessError {
    let what = what.into();
    move |source| ProcessError::Core { what, source }
}

/// A capture's summary: one row of `tofprox process --json` (serialised as that row: depth in
/// metres to the micrometre the f32 depth carries, errors in mm to the micrometre, time to 0.1 µs).
#[derive(Debug, Clone, PartialEq)]
pub struct ProcessRow {
    /// The capture's index in the recording.
    pub index: usize,
    /// Which depth the median is of.
    pub depth_kind: DepthKind,
    /// The capture's true distance (`[capture.conditions] distance_m`), if recorded.
    pub distance_m: Option<f64>,
    /// Median depth over the valid pixels, if any is valid.
    pub median_depth_m: Option<f64>,
    /// Median − truth (mm), when both are known.
    pub error_mm: Option<f64>,
    /// Share of valid pixels, 0…1.
    pub valid_fraction: f32,
    /// Time the pipeline took for this capture (µs).
    pub process_us: f64,
    /// What is left of the cover-window crosstalk relative to the calibrated one (only with a
    /// crosstalk calibration; meaningful with nothing in range: +1 = doubled, e.g. a smudge).
    pub crosstalk_residual: Option<f32>,
}

/// The `--json` form of a [`ProcessRow`].
#[derive(Serialize)]
struct RowJson {
    index: usize,
    depth_kind: DepthKind,
    distance_m: Option<f64>,
    median_depth_m: Option<f64>,
    error_mm: Option<f64>,
    valid_fraction: f32,
    process_us: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    crosstalk_residual: Option<f32>,
}

impl Serialize for ProcessRow {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        RowJson {
            index: self.index,
            depth_kind: self.depth_kind,
            distance_m: self.distance_m,
            // micrometre resolution: the f32 depth carries no more
            median_depth_m: self.median_depth_m.map(|m| (m * 1e6).round() / 1e6),
            error_mm: self.error_mm.map(|e| (e * 1e3).round() / 1e3),
            valid_fraction: self.valid_fraction,
            process_us: (self.process_us * 10.0).round() / 10.0,
            crosstalk_residual: self.crosstalk_residual,
        }
        .serialize(s)
    }
}

/// One processed capture: its row, its depth image (`u16` mm of the chosen kind, 0 = invalid)
/// and the pipeline's frame (radial depth, amplitude, flags), valid until the next capture.
#[derive(Debug)]
pub struct Processed<'a> {
    /// The summary row.
    pub row: ProcessRow,
    /// Depth of [`ProcessOptions::depth_kind`] in mm, 0 = invalid.
    pub depth_mm: Array2<u16>,
    /// The pipeline's output for the capture.
    pub frame: &'a DepthFrame,
    /// Each pixel's ray, when the calibration set has the lens.
    pub rays: Option<&'a RayGrid>,
}

/// Why a capture cannot be processed with `alg`, if it cannot.
fn unusable_reason(c: &CaptureMeta, alg: Algorithm) -> Option<String> {
    if !c.illumination {
        return Some("dark capture".into());
    }
    // [0, 90(, 180, 270)], or what a sensor with another phase convention records as such
    // (shifts are canonical once read: docs/recording-format.md)
    if c.quadrature(alg).is_some() {
        return None;
    }
    let need: Vec<String> = alg.phases_deg().iter().map(|p| fmt_num(*p)).collect();
    Some(format!(
        "a {} capture; {alg} needs phases starting [{}]",
        c.mode_label(),
        need.join(", ")
    ))
}

/// A recording opened for processing with a calibration set (or none).
pub struct Processing {
    rec: Recording,
    opts: ProcessOptions,
    pipeline: Pipeline,
    rays: Option<RayGrid>,
    crosstalk: Option<CrosstalkCalibration>,
    todo: Vec<usize>,
    notes: Vec<String>,
}

impl Processing {
    /// Open `recording`, load and check `calib` against it, set up the pipeline and choose the
    /// captures `opts.algo` can process. What is done without (no calibration, no wiggling
    /// table, skipped captures) is said in [`Processing::notes`].
    pub fn open(
        recording: &Path,
        calib: Option<&Path>,
        opts: ProcessOptions,
    ) -> Result<Self, ProcessError> {
        let rec = Recording::open(recording)?;
        let sensor = *rec.sensor();
        let mut notes = Vec::new();
        let (calibration, rays) = match calib {
            Some(dir) => {
                let set = CalibrationSet::load(dir)?;
                set.check_compatible(&sensor)
                    .map_err(|source| ProcessError::Incompatible {
                        calib: dir.to_path_buf(),
                        recording: recording.to_path_buf(),
                        source: Box::new(source),
                    })?;
                if set.wiggling(opts.algo).is_none() {
                    notes.push(format!(
                        "{} has no {} wiggling table: depth is not wiggling corrected",
                        dir.display(),
                        opts.algo
                    ));
                }
                if set.offset().is_none() {
                    notes.push(format!(
                        "{} has no offset (FPN): the mid code is subtracted instead",
                        dir.display()
                    ));
                }
                let rays = set
                    .rays()
                    .transpose()
                    .map_err(|source| ProcessError::Lens {
                        calib: dir.to_path_buf(),
                        source: Box::new(source),
                    })?;
                (set.to_pipeline_calibration(opts.algo), rays)
            }
            None => {
                notes.push(
                    "no calibration: processing without offset, wiggling or FPPN correction".into(),
                );
                (Default::default(), None)
            }
        };
        // Z depth needs each pixel's ray (thesis 5.1.3; docs/calibration.md)
        if opts.depth_kind == DepthKind::Z && rays.is_none() {
            return Err(ProcessError::NeedsLens {
                calib: calib.map(Path::to_path_buf),
            });
        }
        let config = PipelineConfig {
            algorithm: opts.algo,
            modulation_hz: sensor.modulation_hz,
            adc_bits: sensor.adc_bits,
            min_amplitude_lsb: opts.min_amplitude_lsb,
        };
        let pipeline = Pipeline::new(sensor.rows, sensor.cols, config, calibration)
            .map_err(core("setting up the processing pipeline"))?;
        let crosstalk = pipeline.calibration().crosstalk.clone();
        let todo = Self::usable(&rec, opts.algo, &mut notes);
        if todo.is_empty() {
            return Err(ProcessError::NothingToProcess {
                recording: recording.to_path_buf(),
                algo: opts.algo,
            });
        }
        Ok(Processing {
            rec,
            opts,
            pipeline,
            rays,
            crosstalk,
            todo,
            notes,
        })
    }

    /// The captures `algo` can process; a note for each illuminated one it cannot.
    fn usable(rec: &Recording, algo: Algorithm, notes: &mut Vec<String>) -> Vec<usize> {
        let caps = rec.captures();
        (0..caps.len())
            .filter(|&i| match unusable_reason(&caps[i], algo) {
                None => true,
                Some(why) => {
                    if caps[i].illumination {
                        notes.push(format!("skipping capture {i}: {why}"));
                    }
                    false
                }
            })
            .collect()
    }

    /// The recording.
    pub fn recording(&self) -> &Recording {
        &self.rec
    }

    /// The indices of the captures that will be processed, in order.
    pub fn todo(&self) -> &[usize] {
        &self.todo
    }

    /// Each pixel's ray, when the calibration set has the lens.
    pub fn rays(&self) -> Option<&RayGrid> {
        self.rays.as_ref()
    }

    /// What was done without or skipped, one sentence each.
    pub fn notes(&self) -> &[String] {
        &self.notes
    }

    /// Process capture `i` (one of [`Processing::todo`]).
    pub fn capture(&mut self, i: usize) -> Result<Processed<'_>, ProcessError> {
        let algo = self.opts.algo;
        // (load checks that capture i exists)
        let raw = self.rec.load(i)?;
        let meta = &self.rec.captures()[i];
        if let Some(why) = unusable_reason(meta, algo) {
            return Err(ProcessError::Unusable { index: i, why });
        }
        self.pipeline
            .set_quadrature(meta.quadrature(algo).unwrap_or_default());
        if self.crosstalk.is_some() {
            self.pipeline
                .set_exposure_us(meta.exposure_us)
                .map_err(core(format!(
                    "capture {i}: scaling the crosstalk calibration"
                )))?;
        }
        let k = algo.raw_images();
        let t0 = Instant::now();
        let frame = match &raw {
            RawFrames::U16(x) => self.pipeline.process(x.slice(s![..k, .., ..])),
            RawFrames::F32(x) => self.pipeline.process(x.slice(s![..k, .., ..])),
            RawFrames::F64(x) => self.pipeline.process(x.slice(s![..k, .., ..])),
        }
        .map_err(core(format!("processing capture {i}")))?;
        let process_us = t0.elapsed().as_secs_f64() * 1e6;
        let crosstalk_residual = self
            .crosstalk
            .as_ref()
            .and_then(|x| residual_ratio(frame, x, algo, Roi::default(), meta.exposure_us));
        let (depth_mm, median) = depth_output(frame, self.opts.depth_kind, self.rays.as_ref())?;
        let truth = meta.distance_m();
        let row = ProcessRow {
            index: i,
            depth_kind: self.opts.depth_kind,
            distance_m: truth,
            median_depth_m: median,
            error_mm: truth.zip(median).map(|(t, m)| (m - t) * 1000.0),
            valid_fraction: frame.valid_fraction(),
            process_us,
            crosstalk_residual,
        };
        Ok(Processed {
            row,
            depth_mm,
            frame,
            rays: self.rays.as_ref(),
        })
    }
}

/// The depth image (`u16` mm, 0 = invalid) and its median over the valid pixels (metres) of
/// `kind`: the frame's radial distance, or Z = radial · cos θ through `rays`.
fn depth_output(
    frame: &DepthFrame,
    kind: DepthKind,
    rays: Option<&RayGrid>,
) -> Result<(Array2<u16>, Option<f64>), ProcessError> {
    match (kind, rays) {
        (DepthKind::Z, Some(rays)) => {
            let z_m = rays
                .radial_to_z(frame.depth_m.view())
                .map_err(core("Z depth through the lens"))?;
            let median = median_valid_m(z_m.view(), frame.flags.view());
            Ok((z_m.mapv(depth_m_to_mm), median))
        }
        (DepthKind::Z, None) => Err(ProcessError::NeedsLens { calib: None }),
        (DepthKind::Radial, _) => Ok((frame.depth_mm.clone(), frame.median_valid_depth_m())),
    }
}
