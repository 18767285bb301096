//! `tofprox process`: a recording's captures to depth and amplitude.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
use ndarray::Array2;
use tofprox_core::Algorithm;
use tofprox_core::camera::RayGrid;
use tofprox_core::phasor::unambiguous_range_m;
use tofprox_core::pipeline::{DepthFrame, FLAG_INVALID, PipelineConfig};
use tofprox_format::npy;
use tofprox_format::{
    DepthKind, PointCloudFormat, ProcessOptions, ProcessRow, Processing, encode_points,
};

use super::common::{fmt_num, progress};

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
    #[arg(long, default_value = "radial", value_name = "radial|z")]
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

/// The row as the table prints it.
fn table_line(r: &ProcessRow) -> String {
    format!(
        "{:>5}  {:>10}  {:>14}  {:>9}  {:>8.1}  {:>10.1}",
        r.index,
        r.distance_m.map_or("-".into(), fmt_num),
        r.median_depth_m.map_or("-".into(), |m| format!("{m:.4}")),
        r.error_mm.map_or("-".into(), |e| format!("{e:+.1}")),
        100.0 * r.valid_fraction,
        r.process_us
    )
}

/// Open the recording for processing as `a` asks, its notes on stderr.
fn open(a: &ProcessArgs) -> anyhow::Result<Processing> {
    let opts = ProcessOptions {
        algo: a.algo,
        depth_kind: a.depth_kind,
        min_amplitude_lsb: a.min_amplitude_lsb,
    };
    let proc = Processing::open(&a.recording, a.calib.as_deref(), opts)?;
    for n in proc.notes() {
        eprintln!("note: {n}");
    }
    // points need each pixel's ray (thesis 5.1.3; docs/calibration.md)
    if a.points.is_some() && proc.rays().is_none() {
        bail!(
            "--points needs the lens: a --calib set with intrinsics (tofprox calibrate intrinsics; docs/calibration.md){}",
            a.calib
                .as_ref()
                .map_or(String::new(), |d| format!(", and {} has none", d.display()))
        );
    }
    Ok(proc)
}

pub fn process(a: ProcessArgs) -> anyhow::Result<ExitCode> {
    let points = a.points.as_deref().map(PointsOutput::new).transpose()?;
    let mut proc = open(&a)?;
    let sensor = *proc.recording().sensor();
    let max_m = match a.png_max_m {
        Some(m) if m.is_finite() && m > 0.0 => m,
        Some(m) => bail!("--png-max-m {m} is not a positive distance"),
        None => unambiguous_range_m(sensor.modulation_hz),
    };
    fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let todo = proc.todo().to_vec();
    let pb = progress(todo.len(), "processing");
    let stdout = std::io::stdout();
    if !a.json {
        println!(
            "{:>5}  {:>10}  {:>14}  {:>9}  {:>8}  {:>10}",
            "index", "distance_m", "median_depth_m", "error_mm", "valid_%", "process_us"
        );
    }
    for &i in &todo {
        let done = proc.capture(i)?;
        let stem = format!("{i:06}");
        if let (Some(out), Some(rays)) = (&points, done.rays) {
            out.write(i, done.frame, rays)?;
        }
        let p = a.out.join(format!("{stem}_depth_mm.npy"));
        tofprox_format::write_atomic(&p, &npy::encode_u16(&done.depth_mm))?;
        let p = a.out.join(format!("{stem}_amplitude_lsb.npy"));
        tofprox_format::write_atomic(&p, &npy::encode_f32(&done.frame.amplitude_lsb))?;
        write_depth_png(
            &a.out.join(format!("{stem}_depth.png")),
            &done.depth_mm,
            sensor.roi_origin,
            max_m,
        )?;
        let line = if a.json {
            serde_json::to_string(&done.row)?
        } else {
            table_line(&done.row)
        };
        writeln!(stdout.lock(), "{line}").context("writing to stdout")?;
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
