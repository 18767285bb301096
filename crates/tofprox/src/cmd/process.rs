//! `tofprox process`: a recording's captures to depth and amplitude.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, bail};
use ndarray::{Array2, s};
use serde_json::json;
use tofprox_core::camera::RayGrid;
use tofprox_core::crosstalk::{CrosstalkCalibration, residual_ratio};
use tofprox_core::phasor::unambiguous_range_m;
use tofprox_core::pipeline::{
    Calibration, DepthFrame, FLAG_INVALID, Pipeline, PipelineConfig, depth_m_to_mm, median_valid_m,
};
use tofprox_core::proximity::Roi;
use tofprox_core::{Algorithm, SensorGeometry};
use tofprox_format::npy;
use tofprox_format::{
    CalibrationSet, CaptureMeta, PointCloudFormat, RawFrames, Recording, encode_points,
};

use super::common::{fmt_num, mode_label, progress};

/// Which depth the depth outputs carry.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum DepthKind {
    /// Radial distance: the length of each pixel's ray to the surface (eq. 2.6, what the phase
    /// measures).
    Radial,
    /// Z depth: the distance along the optical axis (radial · cos θ of the pixel's ray; needs the
    /// calibration set's intrinsics).
    Z,
}

impl DepthKind {
    fn name(self) -> &'static str {
        match self {
            DepthKind::Radial => "radial",
            DepthKind::Z => "z",
        }
    }
}

#[derive(clap::Args, Debug)]
pub struct ProcessArgs {
    /// Recording directory.
    pub recording: PathBuf,
    /// Calibration set to apply (without it: mid-code offset, no wiggling/FPPN correction).
    #[arg(long)]
    pub calib: Option<PathBuf>,
    /// Evaluation algorithm: 2phase (images at 0°, 90°) or 4phase (0°, 90°, 180°, 270°).
    #[arg(long)]
    pub algo: Algorithm,
    /// Output directory for NNNNNN_depth_mm.npy, NNNNNN_amplitude_lsb.npy and NNNNNN_depth.png.
    #[arg(long)]
    pub out: PathBuf,
    /// Depth in NNNNNN_depth_mm.npy, the preview and the printed median: radial (along each
    /// pixel's ray) or z (along the optical axis; needs --calib with intrinsics).
    #[arg(long, value_enum, default_value_t = DepthKind::Radial)]
    pub depth_kind: DepthKind,
    /// Also write each capture's point cloud (metres, camera frame X right, Y down, Z forward;
    /// needs --calib with intrinsics) to DIR/NAME_NNNNNN.EXT for --points DIR/NAME.EXT: .npy
    /// (float32 (rows·cols, 3) in pixel order, NaN where invalid) or .ply (binary little-endian,
    /// valid pixels only).
    #[arg(long, value_name = "PATH")]
    pub points: Option<PathBuf>,
    /// JSON Lines on stdout: one object per processed capture, one per line (not one JSON
    /// document: read it line by line): index, depth_kind, distance_m, median_depth_m,
    /// error_mm, valid_fraction, process_us [, crosstalk_residual].
    #[arg(long)]
    pub json: bool,
    /// Pixels with a lower amplitude (LSB) are invalid.
    #[arg(long, default_value_t = PipelineConfig::default().min_amplitude_lsb)]
    pub min_amplitude_lsb: f32,
    /// Depth at the top of the PNG colour scale (default: the unambiguous range).
    #[arg(long)]
    pub png_max_m: Option<f64>,
}

/// Write a colour-mapped depth preview with row/column axes in sensor
/// coordinates and a colour bar in metres (0 … `max_m`; invalid = black), drawn
/// by the one chart component.
fn write_depth_png(
    path: &Path,
    depth_mm: &Array2<u16>,
    origin: [usize; 2],
    max_m: f64,
) -> anyhow::Result<()> {
    let (rows, cols) = depth_mm.dim();
    let values: Vec<f64> = depth_mm
        .iter()
        .map(|&d| {
            if d == 0 {
                f64::NAN
            } else {
                f64::from(d) / 1000.0
            }
        })
        .collect();
    let img = tofprox_chart::raster::annotated(&tofprox_chart::raster::RasterMap {
        rows,
        cols,
        values: &values,
        origin: (origin[0], origin[1]),
        range: (0.0, max_m),
        unit: "m",
    });
    let mut bytes = Vec::new();
    let mut enc = png::Encoder::new(&mut bytes, img.width as u32, img.height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc
        .write_header()
        .with_context(|| format!("cannot write {}", path.display()))?;
    wr.write_image_data(&img.rgb)
        .with_context(|| format!("cannot write {}", path.display()))?;
    wr.finish()
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(tofprox_format::write_atomic(path, &bytes)?)
}

/// Why a capture cannot be processed with `alg`, if it cannot.
fn unusable_reason(c: &CaptureMeta, alg: Algorithm) -> Option<String> {
    if !c.illumination {
        return Some("dark capture".into());
    }
    let need = alg.phases_deg();
    // [0, 90(, 180, 270)], or what a sensor with another phase convention records as such
    // (shifts are canonical once read: docs/recording-format.md)
    if c.quadrature(alg).is_some() {
        None
    } else {
        let need: Vec<String> = need.iter().map(|p| fmt_num(*p)).collect();
        Some(format!(
            "a {} capture; {alg} needs phases starting [{}]",
            mode_label(c),
            need.join(", ")
        ))
    }
}

/// The depth image (`u16` mm, 0 = invalid) and its median over the valid pixels (metres) of
/// `kind`: the frame's radial distance, or Z = radial · cos θ through `rays`.
fn depth_output(
    frame: &DepthFrame,
    kind: DepthKind,
    rays: Option<&RayGrid>,
) -> anyhow::Result<(Array2<u16>, Option<f64>)> {
    Ok(match (kind, rays) {
        (DepthKind::Z, Some(rays)) => {
            let z_m = rays
                .radial_to_z(frame.depth_m.view())
                .context("Z depth through the lens")?;
            let median = median_valid_m(z_m.view(), frame.flags.view());
            (z_m.mapv(depth_m_to_mm), median)
        }
        (DepthKind::Z, None) => bail!("--depth-kind z needs the lens (intrinsics)"),
        (DepthKind::Radial, _) => (frame.depth_mm.clone(), frame.median_valid_depth_m()),
    })
}

/// Where and how `--points DIR/NAME.EXT` writes each capture's cloud: `DIR/NAME_NNNNNN.EXT`.
struct PointsOutput {
    dir: PathBuf,
    name: String,
    format: PointCloudFormat,
}

impl PointsOutput {
    fn new(path: &Path) -> anyhow::Result<Self> {
        let format = PointCloudFormat::from_path(path).context("--points")?;
        let name = path
            .file_stem()
            .and_then(|s| s.to_str())
            .filter(|s| !s.is_empty())
            .with_context(|| format!("--points {}: no file name", path.display()))?
            .to_string();
        let dir = path
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."))
            .to_path_buf();
        fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        Ok(PointsOutput { dir, name, format })
    }

    fn path(&self, index: usize) -> PathBuf {
        self.dir.join(format!(
            "{}_{index:06}.{}",
            self.name,
            self.format.extension()
        ))
    }

    /// Points `radial · ray` of the frame's valid pixels (invalid: NaN in .npy, left out of .ply).
    fn write(&self, index: usize, frame: &DepthFrame, rays: &RayGrid) -> anyhow::Result<()> {
        let pts = rays
            .points(frame.depth_m.view())
            .context("points through the lens")?;
        let valid = frame.flags.mapv(|f| f & FLAG_INVALID == 0);
        let bytes = encode_points(pts.view(), valid.view(), self.format)?;
        let p = self.path(index);
        Ok(tofprox_format::write_atomic(&p, &bytes)?)
    }
}

pub fn process(a: ProcessArgs) -> anyhow::Result<ExitCode> {
    let rec = Recording::open(&a.recording)?;
    let sensor = *rec.sensor();
    let (calibration, rays) = calibration_for(&a, &sensor)?;
    let points = a.points.as_deref().map(PointsOutput::new).transpose()?;
    check_lens(&a, rays.is_some())?;
    let max_m = match a.png_max_m {
        Some(m) if m.is_finite() && m > 0.0 => m,
        Some(m) => bail!("--png-max-m {m} is not a positive distance"),
        None => unambiguous_range_m(sensor.modulation_hz),
    };
    let config = PipelineConfig {
        algorithm: a.algo,
        modulation_hz: sensor.modulation_hz,
        adc_bits: sensor.adc_bits,
        min_amplitude_lsb: a.min_amplitude_lsb,
    };
    let mut pipeline = Pipeline::new(sensor.rows, sensor.cols, config, calibration)
        .context("setting up the processing pipeline")?;
    fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let todo = processable_captures(&rec, &a)?;
    let outputs = Outputs {
        rays: rays.as_ref(),
        points: points.as_ref(),
        origin: sensor.roi_origin,
        max_m,
    };
    let pb = progress(todo.len(), "processing");
    if !a.json {
        println!(
            "{:>5}  {:>10}  {:>14}  {:>9}  {:>8}  {:>10}",
            "index", "distance_m", "median_depth_m", "error_mm", "valid_%", "process_us"
        );
    }
    // (cloned once: the frame borrows the pipeline while the residual is computed)
    let crosstalk = pipeline.calibration().crosstalk.clone();
    for &i in &todo {
        let row = process_capture(&rec, i, &a, &mut pipeline, crosstalk.as_ref(), &outputs)?;
        print_row(&a, i, &row)?;
        pb.inc(1);
    }
    pb.finish_and_clear();
    if !a.json {
        println!(
            "wrote {} depth_mm (.npy, u16, 0 = invalid), amplitude_lsb (.npy, f32) and a depth preview (.png, 0..{max_m:.2} m) per capture to {}",
            a.depth_kind.name(),
            a.out.display()
        );
        if let Some(p) = &points {
            println!(
                "wrote a point cloud per capture to {}",
                p.path(todo[0]).display()
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// The pipeline calibration of `--calib` (checked against the recording's sensor; what it
/// lacks is noted) and its lens's rays; without `--calib` none.
fn calibration_for(
    a: &ProcessArgs,
    sensor: &SensorGeometry,
) -> anyhow::Result<(Calibration, Option<RayGrid>)> {
    let Some(dir) = &a.calib else {
        eprintln!("note: no --calib: processing without offset, wiggling or FPPN correction");
        return Ok((Default::default(), None));
    };
    let set = CalibrationSet::load(dir)?;
    set.check_compatible(sensor).with_context(|| {
        format!(
            "refusing to apply {} to {}",
            dir.display(),
            a.recording.display()
        )
    })?;
    if set.wiggling(a.algo).is_none() {
        eprintln!(
            "note: {} has no {} wiggling table: depth is not wiggling corrected",
            dir.display(),
            a.algo
        );
    }
    if set.offset.is_none() {
        eprintln!(
            "note: {} has no offset (FPN): the mid code is subtracted instead",
            dir.display()
        );
    }
    let rays = set
        .rays()
        .transpose()
        .with_context(|| format!("the lens of {}", dir.display()))?;
    Ok((set.to_pipeline_calibration(a.algo), rays))
}

/// Z depth and points need each pixel's ray (thesis 5.1.3; docs/calibration.md).
fn check_lens(a: &ProcessArgs, has_lens: bool) -> anyhow::Result<()> {
    let needs_lens = a.depth_kind == DepthKind::Z || a.points.is_some();
    if needs_lens && !has_lens {
        bail!(
            "{} needs the lens: a --calib set with intrinsics (tofprox calibrate intrinsics; docs/calibration.md){}",
            if a.points.is_some() {
                "--points"
            } else {
                "--depth-kind z"
            },
            a.calib
                .as_ref()
                .map_or(String::new(), |d| format!(", and {} has none", d.display()))
        );
    }
    Ok(())
}

/// The captures `--algo` can process (illuminated ones it cannot are noted); an error when
/// there is none.
fn processable_captures(rec: &Recording, a: &ProcessArgs) -> anyhow::Result<Vec<usize>> {
    let caps = rec.captures();
    let todo: Vec<usize> = (0..caps.len())
        .filter(|&i| match unusable_reason(&caps[i], a.algo) {
            None => true,
            Some(why) => {
                if caps[i].illumination {
                    eprintln!("note: skipping capture {i}: {why}");
                }
                false
            }
        })
        .collect();
    if todo.is_empty() {
        bail!(
            "{} has no illuminated capture that can be processed as {}",
            a.recording.display(),
            a.algo
        );
    }
    Ok(todo)
}

/// Where a processed capture goes besides the depth and amplitude arrays.
struct Outputs<'a> {
    /// The lens's rays (Z depth, points).
    rays: Option<&'a RayGrid>,
    /// `--points`.
    points: Option<&'a PointsOutput>,
    /// The window's origin in the sensor (the preview's axes).
    origin: [usize; 2],
    /// Depth at the top of the preview's colour scale.
    max_m: f64,
}

/// What one processed capture printed.
struct CaptureRow {
    truth_m: Option<f64>,
    median_m: Option<f64>,
    valid_fraction: f32,
    process_us: f64,
    crosstalk_residual: Option<f32>,
}

/// Process capture `i` and write its depth, amplitude, preview (and points).
fn process_capture(
    rec: &Recording,
    i: usize,
    a: &ProcessArgs,
    pipeline: &mut Pipeline,
    crosstalk: Option<&CrosstalkCalibration>,
    out: &Outputs<'_>,
) -> anyhow::Result<CaptureRow> {
    let meta = &rec.captures()[i];
    let raw = rec.load(i)?;
    pipeline.set_quadrature(meta.quadrature(a.algo).unwrap_or_default());
    if crosstalk.is_some() {
        pipeline
            .set_exposure_us(meta.exposure_us)
            .with_context(|| format!("capture {i}: scaling the crosstalk calibration"))?;
    }
    let k = a.algo.raw_images();
    let t0 = Instant::now();
    let frame = match &raw {
        RawFrames::U16(x) => pipeline.process(x.slice(s![..k, .., ..])),
        RawFrames::F32(x) => pipeline.process(x.slice(s![..k, .., ..])),
        RawFrames::F64(x) => pipeline.process(x.slice(s![..k, .., ..])),
    }
    .with_context(|| format!("processing capture {i}"))?;
    let process_us = t0.elapsed().as_secs_f64() * 1e6;
    // what is left of the cover-window crosstalk relative to the calibrated one
    // (meaningful with nothing in range: +1 = doubled, e.g. a smudge)
    let crosstalk_residual =
        crosstalk.and_then(|x| residual_ratio(frame, x, a.algo, Roi::default(), meta.exposure_us));
    let (depth_mm, median_m) = depth_output(frame, a.depth_kind, out.rays)?;
    let stem = format!("{i:06}");
    if let (Some(points), Some(rays)) = (out.points, out.rays) {
        points.write(i, frame, rays)?;
    }
    let p = a.out.join(format!("{stem}_depth_mm.npy"));
    tofprox_format::write_atomic(&p, &npy::encode_u16(&depth_mm))?;
    let p = a.out.join(format!("{stem}_amplitude_lsb.npy"));
    tofprox_format::write_atomic(&p, &npy::encode_f32(&frame.amplitude_lsb))?;
    let png = a.out.join(format!("{stem}_depth.png"));
    write_depth_png(&png, &depth_mm, out.origin, out.max_m)?;
    Ok(CaptureRow {
        truth_m: meta.distance_m(),
        median_m,
        valid_fraction: frame.valid_fraction(),
        process_us,
        crosstalk_residual,
    })
}

/// One line on stdout for a processed capture: a JSON Lines object or a table row.
fn print_row(a: &ProcessArgs, i: usize, row: &CaptureRow) -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    let error_mm = row.truth_m.zip(row.median_m).map(|(t, m)| (m - t) * 1000.0);
    if a.json {
        let mut line = json!({
            "index": i,
            "depth_kind": a.depth_kind.name(),
            // micrometre resolution: the f32 depth carries no more
            "distance_m": row.truth_m,
            "median_depth_m": row.median_m.map(|m| (m * 1e6).round() / 1e6),
            "error_mm": error_mm.map(|e| (e * 1e3).round() / 1e3),
            "valid_fraction": row.valid_fraction,
            "process_us": (row.process_us * 10.0).round() / 10.0,
        });
        // only with a crosstalk calibration
        if let (Some(r), Some(o)) = (row.crosstalk_residual, line.as_object_mut()) {
            o.insert("crosstalk_residual".into(), json!(r));
        }
        writeln!(out, "{line}").context("writing to stdout")
    } else {
        let err = error_mm.map_or("-".into(), |e| format!("{e:+.1}"));
        writeln!(
            out,
            "{:>5}  {:>10}  {:>14}  {:>9}  {:>8.1}  {:>10.1}",
            i,
            row.truth_m.map_or("-".into(), fmt_num),
            row.median_m.map_or("-".into(), |m| format!("{m:.4}")),
            err,
            100.0 * row.valid_fraction,
            row.process_us
        )
        .context("writing to stdout")
    }
}
