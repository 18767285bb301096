//! `tofprox info`, `calibrate`, `process`: recordings in, calibration sets and
//! depth out (recording format: `docs/recording-format.md`, calibration sets:
//! `docs/calibration.md`).

use std::collections::BTreeMap;
use std::fs;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use ndarray::{Array2, Array3, Axis, s};
use serde_json::json;
use tofprox_core::Algorithm;
use tofprox_core::calib::{
    extract_fppn_through_lens, extract_offset, extract_wiggling_through_lens,
};
use tofprox_core::camera::{Intrinsics, SweepCapture, calibrate_intrinsics};
use tofprox_core::crosstalk::{CrosstalkCapture, extract_crosstalk, residual_ratio};
use tofprox_core::phasor::unambiguous_range_m;
use tofprox_core::pipeline::{Pipeline, PipelineConfig};
use tofprox_core::proximity::Roi;
use tofprox_core::radiometry::{
    AmplitudeScale, DEFAULT_CALIBRATION_REFLECTIVITY, expected_amplitude_lsb,
};
use tofprox_format::npy;
use tofprox_format::{
    CalibPart, CalibrationSet, CaptureMeta, PartSource, RawFrames, Recording, now_rfc3339,
};

const TOOL: &str = concat!("tofprox ", env!("CARGO_PKG_VERSION"));

/// `tofprox info REC [--json]`
#[derive(clap::Args, Debug)]
pub struct InfoArgs {
    /// Recording directory (holds recording.toml), or a calibration set
    /// (holds calibration.toml): its validity, parts, provenance and statistics.
    pub recording: PathBuf,
    /// Print one JSON object on stdout instead of the text summary.
    #[arg(long)]
    pub json: bool,
}

/// What `tofprox calibrate` extracts.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum CalibKind {
    /// Lens intrinsics and distortion: a plane fit over a sweep of a flat target at ≥ 3 known
    /// distances (every illuminated capture with distance_m), or --datasheet values.
    Intrinsics,
    /// Per-pixel dark frame (FPN) from the dark captures (illumination = false), averaged.
    Fpn,
    /// 2- and 4-phase wiggling tables from a correlation capture (24 × 15°) with distance_m.
    Wiggling,
    /// Per-pixel phase offsets from a flat-target 4-phase capture with distance_m.
    Fppn,
    /// Cover-window crosstalk from illuminated captures with nothing in range
    /// (conditions.no_target = 1), per raw image and µs of exposure.
    Crosstalk,
}

/// Condition key marking a capture with nothing in range (crosstalk calibration).
pub const NO_TARGET_CONDITION: &str = "no_target";

/// `tofprox calibrate intrinsics|fpn|crosstalk|wiggling|fppn REC --out CALIB`
#[derive(clap::Args, Debug)]
pub struct CalibrateArgs {
    /// Which calibration to extract.
    #[arg(value_enum)]
    pub what: CalibKind,
    /// Recording directory to extract it from.
    pub recording: PathBuf,
    /// Calibration directory to write. If it already holds a set, the part is
    /// added or replaced (parts derived from a replaced one are dropped).
    #[arg(long)]
    pub out: PathBuf,
    /// Number of bins of the wiggling tables.
    #[arg(long, default_value_t = 256)]
    pub lut_size: usize,
    /// Start from this calibration set instead of the one in --out.
    #[arg(long)]
    pub calib: Option<PathBuf>,
    /// Use only this capture (index in the recording) instead of choosing automatically.
    #[arg(long)]
    pub capture: Option<usize>,
    /// intrinsics: take the lens from this TOML (a module's datasheet: fx_px, fy_px, cx_px, cy_px
    /// in full-array pixels and an optional [distortion] table with OpenCV's k1, k2, k3, p1, p2)
    /// instead of fitting it to the recording.
    #[arg(long)]
    pub datasheet: Option<PathBuf>,
}

/// `tofprox process REC --calib CALIB --algo 2phase|4phase --out OUT [--json]`
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
    /// Print one JSON object per processed capture on stdout.
    #[arg(long)]
    pub json: bool,
    /// Pixels with a lower amplitude (LSB) are invalid.
    #[arg(long, default_value_t = PipelineConfig::default().min_amplitude_lsb)]
    pub min_amplitude_lsb: f32,
    /// Depth at the top of the PNG colour scale (default: the unambiguous range).
    #[arg(long)]
    pub png_max_m: Option<f64>,
}

fn progress(len: usize, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len as u64);
    if std::io::stderr().is_terminal() && len > 1 {
        pb.set_draw_target(ProgressDrawTarget::stderr());
        if let Ok(style) = ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed}") {
            pb.set_style(style.progress_chars("=> "));
        }
        pb.set_message(what.to_string());
    } else {
        pb.set_draw_target(ProgressDrawTarget::hidden());
    }
    pb
}

/// A short name for the acquisition mode of a capture.
fn mode_label(c: &CaptureMeta) -> String {
    let n = c.phases_deg.len();
    if c.is_four_phase() {
        "4phase".into()
    } else if n == 2 && c.starts_two_phase() {
        "2phase".into()
    } else if c.is_correlation() {
        format!("correlation-{n}")
    } else {
        let p: Vec<String> = c.phases_deg.iter().map(|p| format!("{p}")).collect();
        format!("{n}-phase[{}]", p.join(","))
    }
}

fn fmt_num(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s.is_empty() || s == "-" {
        "0".into()
    } else {
        s.to_string()
    }
}

// ---------------------------------------------------------------- info

pub fn info(a: InfoArgs) -> anyhow::Result<ExitCode> {
    let is_calib = a.recording.join(tofprox_format::CALIBRATION_TOML).is_file()
        && !a.recording.join(tofprox_format::RECORDING_TOML).exists();
    if is_calib {
        return calib_info(&a);
    }
    let rec = Recording::open(&a.recording)?;
    let s = *rec.sensor();
    let caps = rec.captures();
    let pb = progress(caps.len(), "reading");
    let mut sat = Vec::with_capacity(caps.len());
    for i in 0..caps.len() {
        let f = rec.load(i)?;
        sat.push(f.saturated_fraction(s.adc_bits));
        pb.inc(1);
    }
    pb.finish_and_clear();

    let mut by_mode: BTreeMap<String, usize> = BTreeMap::new();
    let mut by_exposure: BTreeMap<String, usize> = BTreeMap::new();
    let mut by_illum: BTreeMap<&str, usize> = BTreeMap::new();
    let mut by_dtype: BTreeMap<&str, usize> = BTreeMap::new();
    let mut conds: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for (i, c) in caps.iter().enumerate() {
        let mode = if c.illumination {
            mode_label(c)
        } else {
            format!("dark {}", mode_label(c))
        };
        *by_mode.entry(mode).or_default() += 1;
        *by_exposure.entry(fmt_num(c.exposure_us)).or_default() += 1;
        *by_illum
            .entry(if c.illumination { "on" } else { "off" })
            .or_default() += 1;
        *by_dtype
            .entry(rec.dtype(i).map_or("?", |d| d.name()))
            .or_default() += 1;
        for (k, v) in &c.conditions {
            conds.entry(k.clone()).or_default().push(*v);
        }
    }
    let total_sat = if sat.is_empty() {
        0.0
    } else {
        sat.iter().sum::<f64>() / sat.len() as f64
    };
    let range_m = unambiguous_range_m(s.modulation_hz);

    if a.json {
        let per: Vec<_> = caps
            .iter()
            .enumerate()
            .map(|(i, c)| {
                json!({
                    "index": i,
                    "frames": c.frames,
                    "mode": mode_label(c),
                    "phases_deg": c.phases_deg,
                    "exposure_us": c.exposure_us,
                    "illumination": c.illumination,
                    "averaged": c.averaged,
                    "dtype": rec.dtype(i).map(|d| d.name()),
                    "timestamp_ns": c.timestamp_ns,
                    "conditions": c.conditions,
                    "saturated_fraction": sat.get(i),
                })
            })
            .collect();
        let cond_json: BTreeMap<_, _> = conds
            .iter()
            .map(|(k, v)| {
                let mut d = v.clone();
                d.sort_by(f64::total_cmp);
                d.dedup();
                (k.clone(), json!({"captures": v.len(), "values": d}))
            })
            .collect();
        let out = json!({
            "recording": a.recording.display().to_string(),
            "description": rec.description(),
            "sensor": {
                "rows": s.rows, "cols": s.cols, "roi_origin": s.roi_origin,
                "full_rows": s.full_rows, "full_cols": s.full_cols,
                "adc_bits": s.adc_bits, "modulation_hz": s.modulation_hz,
                "unambiguous_range_m": range_m,
            },
            "captures": caps.len(),
            "by_mode": by_mode,
            "by_exposure_us": by_exposure,
            "by_illumination": by_illum,
            "by_dtype": by_dtype,
            "conditions": cond_json,
            "saturated_fraction": total_sat,
            "per_capture": per,
        });
        println!("{out}");
        return Ok(ExitCode::SUCCESS);
    }

    let mut o = String::new();
    use std::fmt::Write as _;
    let _ = writeln!(o, "recording   {}", a.recording.display());
    if let Some(d) = rec.description() {
        let _ = writeln!(o, "description {d}");
    }
    let _ = writeln!(
        o,
        "sensor      {}×{} window at (row {}, col {}) of a {}×{} array, {}-bit ADC (mid code {}), {} MHz (unambiguous range {:.3} m)",
        s.rows,
        s.cols,
        s.roi_origin[0],
        s.roi_origin[1],
        s.full_rows,
        s.full_cols,
        s.adc_bits,
        s.mid_code(),
        fmt_num(s.modulation_hz / 1e6),
        range_m
    );
    let join = |m: &BTreeMap<String, usize>, unit: &str| -> String {
        m.iter()
            .map(|(k, v)| format!("{k}{unit} ×{v}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let _ = writeln!(o, "captures    {}", caps.len());
    let _ = writeln!(o, "  by mode         {}", join(&by_mode, ""));
    let _ = writeln!(o, "  by exposure     {}", join(&by_exposure, " µs"));
    let illum: BTreeMap<String, usize> =
        by_illum.iter().map(|(k, v)| (k.to_string(), *v)).collect();
    let _ = writeln!(o, "  illumination    {}", join(&illum, ""));
    let dt: BTreeMap<String, usize> = by_dtype.iter().map(|(k, v)| (k.to_string(), *v)).collect();
    let _ = writeln!(o, "  dtype           {}", join(&dt, ""));
    for (k, v) in &conds {
        let mut d = v.clone();
        d.sort_by(f64::total_cmp);
        d.dedup();
        let shown: Vec<String> = d.iter().take(12).map(|x| fmt_num(*x)).collect();
        let more = if d.len() > 12 { ", …" } else { "" };
        let _ = writeln!(
            o,
            "  {k:<15} {} capture(s): {}{more}",
            v.len(),
            shown.join(", ")
        );
    }
    let (worst_i, worst) =
        sat.iter().copied().enumerate().fold(
            (0, 0.0f64),
            |acc, (i, v)| if v > acc.1 { (i, v) } else { acc },
        );
    let _ = write!(
        o,
        "saturation  {:.2} % of pixels have a raw image at a rail",
        100.0 * total_sat
    );
    if worst > 0.0 {
        let _ = write!(o, " (worst: capture {worst_i}, {:.2} %)", 100.0 * worst);
    }
    let _ = writeln!(o);
    let _ = writeln!(o);
    let _ = writeln!(
        o,
        "{:>5}  {:<20} {:<16} {:>11} {:>5} {:>4} {:>8} {:>7}  conditions",
        "index", "frames", "mode", "exposure_us", "illum", "avg", "dtype", "sat %"
    );
    for (i, c) in caps.iter().enumerate() {
        let cond: Vec<String> = c
            .conditions
            .iter()
            .map(|(k, v)| format!("{k}={}", fmt_num(*v)))
            .collect();
        let _ = writeln!(
            o,
            "{:>5}  {:<20} {:<16} {:>11} {:>5} {:>4} {:>8} {:>7.2}  {}",
            i,
            c.frames,
            mode_label(c),
            fmt_num(c.exposure_us),
            if c.illumination { "on" } else { "off" },
            c.averaged,
            rec.dtype(i).map_or("?", |d| d.name()),
            100.0 * sat.get(i).copied().unwrap_or(0.0),
            cond.join(" ")
        );
    }
    print!("{o}");
    Ok(ExitCode::SUCCESS)
}

/// `tofprox info CALIB`: what a calibration set holds.
fn calib_info(a: &InfoArgs) -> anyhow::Result<ExitCode> {
    let set = CalibrationSet::load(&a.recording)?;
    let v = &set.validity;
    let mm_per_rad = 1000.0 * unambiguous_range_m(v.modulation_hz) / std::f64::consts::TAU;
    let stats = |x: &mut dyn Iterator<Item = f32>| -> (f64, f64, f64, f64) {
        let v: Vec<f64> = x.map(f64::from).collect();
        let n = v.len().max(1) as f64;
        let mean = v.iter().sum::<f64>() / n;
        let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (mean, sd, lo, hi)
    };
    let mut parts = Vec::new();
    for part in set.parts() {
        let (what, (mean, sd, lo, hi), unit) = match part {
            CalibPart::Intrinsics => (
                "focal length",
                stats(
                    &mut set
                        .intrinsics
                        .iter()
                        .flat_map(|k| [k.fx_px as f32, k.fy_px as f32]),
                ),
                "px",
            ),
            CalibPart::Offset => (
                "dark level",
                stats(&mut set.offset.iter().flat_map(|o| o.dark_lsb.iter().copied())),
                "LSB",
            ),
            CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase => (
                "correction",
                stats(
                    &mut part
                        .algorithm()
                        .and_then(|alg| set.wiggling(alg))
                        .into_iter()
                        .flat_map(|w| w.correction_rad.iter().copied()),
                ),
                "rad",
            ),
            CalibPart::Amplitude => (
                "scale K of A = K·ρ·t/d²",
                stats(
                    &mut set
                        .amplitude
                        .iter()
                        .flat_map(|a| a.lsb_m2_per_us.iter().copied()),
                ),
                "LSB·m²/µs",
            ),
            CalibPart::Crosstalk => (
                "crosstalk",
                stats(
                    &mut set
                        .crosstalk
                        .iter()
                        .flat_map(|x| x.lsb_per_us.iter().copied()),
                ),
                "LSB/us",
            ),
            CalibPart::Fppn | CalibPart::Fppn2Phase => (
                "phase offset",
                stats(
                    &mut (match part {
                        CalibPart::Fppn => set.fppn.as_ref(),
                        _ => set.fppn_2phase.as_ref(),
                    })
                    .into_iter()
                    .flat_map(|f| f.phase_offset_rad.iter().copied()),
                ),
                "rad",
            ),
        };
        let src = set.sources.get(&part).cloned().unwrap_or_default();
        parts.push((part, what, mean, sd, lo, hi, unit, src));
    }
    if a.json {
        let ps: BTreeMap<_, _> = parts
            .iter()
            .map(|(part, what, mean, sd, lo, hi, unit, src)| {
                (
                    part.name(),
                    json!({
                        "quantity": what, "unit": unit, "mean": mean, "std": sd, "min": lo, "max": hi,
                        "sha256": set.checksum(*part),
                        "source_recording": src.recording, "source_captures": src.captures,
                        "distance_m": src.distance_m, "created": src.created, "tool": src.tool,
                    }),
                )
            })
            .collect();
        let out = json!({
            "calibration": a.recording.display().to_string(),
            "description": set.description,
            "valid_for": {
                "modulation_hz": v.modulation_hz, "adc_bits": v.adc_bits, "rows": v.rows,
                "cols": v.cols, "roi_origin": v.roi_origin, "full_rows": v.full_rows,
                "full_cols": v.full_cols,
            },
            "parts": ps,
        });
        println!("{out}");
        return Ok(ExitCode::SUCCESS);
    }
    println!("calibration {} (checksums verified)", a.recording.display());
    if let Some(d) = &set.description {
        println!("description {d}");
    }
    println!(
        "valid for   {}×{} window at (row {}, col {}) of a {}×{} array, {}-bit ADC, {} MHz",
        v.rows,
        v.cols,
        v.roi_origin[0],
        v.roi_origin[1],
        v.full_rows,
        v.full_cols,
        v.adc_bits,
        fmt_num(v.modulation_hz / 1e6)
    );
    for (part, what, mean, sd, lo, hi, unit, src) in &parts {
        let in_mm = |x: f64| {
            if *unit == "rad" {
                format!(" ({:.1} mm)", x * mm_per_rad)
            } else {
                String::new()
            }
        };
        let size = match part {
            CalibPart::Intrinsics => set.intrinsics.as_ref().map_or(String::new(), |k| {
                let d = &k.distortion;
                format!(
                    "; principal point ({:.2}, {:.2}) px, k1 {:.4}, k2 {:.4}, k3 {:.4}, p1 {:.5}, p2 {:.5}",
                    k.cx_px, k.cy_px, d.k1, d.k2, d.k3, d.p1, d.p2
                )
            }),
            CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase => part
                .algorithm()
                .and_then(|alg| set.wiggling(alg))
                .map_or(String::new(), |w| format!(", {} bins", w.len())),
            _ => String::new(),
        };
        println!(
            "{:<16} {what}: mean {mean:.4} {unit}{}, σ {sd:.4} {unit}{}, range {lo:.4} .. {hi:.4} {unit}{size}",
            part.name(),
            in_mm(*mean),
            in_mm(*sd),
        );
        let dist = src
            .distance_m
            .map_or(String::new(), |d| format!(" at {} m", fmt_num(d)));
        println!(
            "{:<16} from {} captures {:?}{dist}, {} by {}",
            "", src.recording, src.captures, src.created, src.tool
        );
    }
    if parts.is_empty() {
        println!("(no parts)");
    }
    Ok(ExitCode::SUCCESS)
}

// ---------------------------------------------------------------- calibrate

fn source(
    rec: &Recording,
    path: &Path,
    captures: Vec<usize>,
    distance_m: Option<f64>,
) -> PartSource {
    PartSource {
        recording: path.display().to_string(),
        recording_description: rec.description().map(str::to_string),
        captures,
        distance_m,
        created: now_rfc3339(),
        tool: TOOL.to_string(),
        ..PartSource::default()
    }
}

fn pick_capture(
    rec: &Recording,
    wanted: Option<usize>,
    what: &str,
    ok: impl Fn(&CaptureMeta) -> Result<(), String>,
) -> anyhow::Result<usize> {
    let caps = rec.captures();
    if let Some(i) = wanted {
        let c = caps
            .get(i)
            .with_context(|| format!("--capture {i}: the recording has {} captures", caps.len()))?;
        if let Err(why) = ok(c) {
            bail!("--capture {i} is not usable as {what}: {why}");
        }
        return Ok(i);
    }
    caps.iter().position(|c| ok(c).is_ok()).with_context(|| {
        format!(
            "{} has no {what} (see `tofprox info {}`)",
            rec.dir().display(),
            rec.dir().display()
        )
    })
}

/// [`pick_capture`] for an illuminated capture of a target at a known
/// distance whose phases pass `phases_ok`; returns its index, metadata and
/// `distance_m`.
fn pick_target_capture<'r>(
    rec: &'r Recording,
    wanted: Option<usize>,
    what: &str,
    phases_ok: impl Fn(&CaptureMeta) -> Result<(), String>,
) -> anyhow::Result<(usize, &'r CaptureMeta, f64)> {
    let usable = |c: &CaptureMeta| {
        if !c.illumination {
            return Err("it is a dark capture".to_string());
        }
        phases_ok(c)?;
        need_distance(c)
    };
    let i = pick_capture(rec, wanted, what, |c| usable(c).map(|_| ()))?;
    let c = rec
        .captures()
        .get(i)
        .with_context(|| format!("capture {i} vanished from the recording"))?;
    let d = usable(c).map_err(anyhow::Error::msg)?;
    Ok((i, c, d))
}

fn need_distance(c: &CaptureMeta) -> Result<f64, String> {
    match c.distance_m() {
        Some(d) if d > 0.0 => Ok(d),
        Some(d) => Err(format!(
            "conditions.distance_m = {d} is not a positive distance"
        )),
        None => Err("it has no conditions.distance_m (ground-truth distance)".into()),
    }
}

/// The capture's codes with the set's cover-window crosstalk subtracted (unchanged without one),
/// so wiggling and FPPN extracted behind a cover window do not absorb it.
fn without_crosstalk(
    set: &CalibrationSet,
    mut data: Array3<f64>,
    c: &CaptureMeta,
) -> anyhow::Result<Array3<f64>> {
    if let Some(x) = &set.crosstalk {
        eprintln!("note: subtracting the set's cover-window crosstalk before the extraction");
        x.subtract_from(data.view_mut(), &c.phases_deg, c.exposure_us)
            .context("subtracting the crosstalk")?;
    }
    Ok(data)
}

pub fn calibrate(a: CalibrateArgs) -> anyhow::Result<ExitCode> {
    let rec = Recording::open(&a.recording)?;
    let sensor = *rec.sensor();
    let base_dir = a.calib.clone().or_else(|| {
        a.out
            .join(tofprox_format::CALIBRATION_TOML)
            .exists()
            .then(|| a.out.clone())
    });
    let mut set = match &base_dir {
        Some(d) => {
            let set = CalibrationSet::load(d)?;
            set.check_compatible(&sensor)
                .with_context(|| format!("cannot add to the calibration set in {}", d.display()))?;
            set
        }
        None => CalibrationSet::new(&sensor),
    };
    let mut report = Vec::new();
    let dropped = match a.what {
        CalibKind::Intrinsics => {
            let (k, src, line) = match &a.datasheet {
                Some(path) => {
                    let text = fs::read_to_string(path)
                        .with_context(|| format!("cannot read {}", path.display()))?;
                    let k: Intrinsics = toml::from_str(&text)
                        .with_context(|| format!("{}: not a lens datasheet", path.display()))?;
                    k.validate()
                        .with_context(|| format!("{}: invalid lens", path.display()))?;
                    let mut src = source(&rec, &a.recording, Vec::new(), None);
                    src.recording = path.display().to_string();
                    src.recording_description = Some("lens datasheet".into());
                    (
                        k,
                        src,
                        format!("intrinsics: from the datasheet {}", path.display()),
                    )
                }
                None => {
                    let (k, idx, line) = fit_lens(&rec, &sensor)?;
                    (k, source(&rec, &a.recording, idx, None), line)
                }
            };
            report.push(line);
            set.set_intrinsics(k, src)?
        }
        CalibKind::Fpn => {
            let idx: Vec<usize> = match a.capture {
                Some(i) => vec![pick_capture(&rec, Some(i), "a dark capture", |c| {
                    if c.illumination {
                        Err("illumination = true".into())
                    } else {
                        Ok(())
                    }
                })?],
                None => (0..rec.captures().len())
                    .filter(|&i| !rec.captures()[i].illumination)
                    .collect(),
            };
            if idx.is_empty() {
                bail!(
                    "{} has no dark capture (illumination = false) to extract the FPN offset from",
                    a.recording.display()
                );
            }
            let exposures: Vec<f64> = idx.iter().map(|&i| rec.captures()[i].exposure_us).collect();
            if exposures.iter().any(|e| (e - exposures[0]).abs() > 1e-9) {
                eprintln!(
                    "note: averaging dark captures of different exposures ({} µs)",
                    exposures
                        .iter()
                        .map(|e| fmt_num(*e))
                        .collect::<Vec<_>>()
                        .join(", ")
                );
            }
            let mut images: Vec<Array3<f64>> = Vec::new();
            for &i in &idx {
                images.push(rec.load(i)?.to_f64());
            }
            let views: Vec<_> = images.iter().map(|x| x.view()).collect();
            let all =
                ndarray::concatenate(Axis(0), &views).context("stacking the dark captures")?;
            let off = extract_offset(all.view()).context("extracting the offset (FPN)")?;
            let mean = off.dark_lsb.mean().unwrap_or(0.0);
            let sd = off.dark_lsb.std(0.0);
            report.push(format!(
                "offset: {} dark capture(s) ({} images), mean dark level {:.1} LSB (mid code {}), FPN σ {:.1} LSB",
                idx.len(),
                all.len_of(Axis(0)),
                mean,
                sensor.mid_code(),
                sd
            ));
            set.set_offset(off, source(&rec, &a.recording, idx, None))?
        }
        CalibKind::Wiggling => {
            let (i, c, d) = pick_target_capture(
                &rec,
                a.capture,
                "an illuminated correlation capture with distance_m",
                |c| {
                    if !c.is_correlation() {
                        return Err(format!(
                            "its {} phases are not ≥ 8 equally spaced steps from 0° (a correlation capture is 24 × 15°)",
                            c.phases_deg.len()
                        ));
                    }
                    Ok(())
                },
            )?;
            let data = without_crosstalk(&set, rec.load(i)?.to_f64(), c)?;
            if set.offset.is_none() {
                eprintln!(
                    "note: no offset (FPN) in the calibration set: the wiggling tables are extracted with the mid code subtracted; run `tofprox calibrate fpn` first for the best 2-phase result"
                );
            }
            let rays = set.rays().transpose()?;
            let mut dropped = Vec::new();
            for alg in Algorithm::ALL {
                let lut = extract_wiggling_through_lens(
                    data.view(),
                    &c.phases_deg,
                    set.offset.as_ref(),
                    d,
                    rays.as_ref(),
                    sensor.modulation_hz,
                    sensor.adc_bits,
                    alg,
                    a.lut_size,
                )
                .with_context(|| format!("extracting the {alg} wiggling table from capture {i}"))?;
                let lo = lut
                    .correction_rad
                    .iter()
                    .copied()
                    .fold(f32::INFINITY, f32::min);
                let hi = lut
                    .correction_rad
                    .iter()
                    .copied()
                    .fold(f32::NEG_INFINITY, f32::max);
                let mean = lut.correction_rad.mean().unwrap_or(0.0);
                let mm_per_rad =
                    1000.0 * unambiguous_range_m(sensor.modulation_hz) / std::f64::consts::TAU;
                report.push(format!(
                    "wiggling_{alg}: {} bins from capture {i} at {} m, mean correction {:.4} rad (global delay, {:.1} mm), wiggling peak-to-peak {:.4} rad ({:.1} mm)",
                    lut.len(),
                    fmt_num(d),
                    mean,
                    f64::from(mean) * mm_per_rad,
                    hi - lo,
                    f64::from(hi - lo) * mm_per_rad
                ));
                dropped
                    .extend(set.set_wiggling(lut, source(&rec, &a.recording, vec![i], Some(d)))?);
            }
            // The amplitude scale of the 1/d² law (thesis 2.2.1) from the same capture.
            let given_rho = c.conditions.get("reflectivity").copied();
            let rho = match given_rho {
                Some(r) => r,
                None => {
                    eprintln!(
                        "note: capture {i} has no conditions.reflectivity: the amplitude scale assumes {} (a perfect diffuse reflector: the scale is a lower bound, so no real target is rejected as implausible)",
                        DEFAULT_CALIBRATION_REFLECTIVITY
                    );
                    DEFAULT_CALIBRATION_REFLECTIVITY
                }
            };
            let scale = AmplitudeScale::extract(data.view(), &c.phases_deg, c.exposure_us, d, rho)
                .with_context(|| format!("extracting the amplitude scale from capture {i}"))?;
            let k = &scale.lsb_m2_per_us;
            let mut sorted: Vec<f32> = k.iter().copied().collect();
            sorted.sort_unstable_by(f32::total_cmp);
            let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
            report.push(format!(
                "amplitude: scale K of A = K·ρ·t/d² from capture {i} at {} m, reflectivity {}{}, {} µs: median {:.4} LSB·m²/µs (a 2 % target at 10 cm, 100 µs: {:.0} LSB)",
                fmt_num(d),
                fmt_num(rho),
                if given_rho.is_some() { "" } else { " (assumed)" },
                fmt_num(c.exposure_us),
                median,
                expected_amplitude_lsb(f64::from(median), 0.02, 100.0, 0.1)
            ));
            let src = PartSource {
                reflectivity: given_rho,
                exposure_us: Some(c.exposure_us),
                ..source(&rec, &a.recording, vec![i], Some(d))
            };
            dropped.extend(set.set_amplitude(scale, src)?);
            dropped
        }
        CalibKind::Fppn => {
            let (i, c, d) = pick_target_capture(
                &rec,
                a.capture,
                "an illuminated 4-phase capture of a flat target with distance_m",
                |c| {
                    if !c.is_four_phase() {
                        return Err("its phases are not [0, 90, 180, 270]".into());
                    }
                    Ok(())
                },
            )?;
            let data = without_crosstalk(&set, rec.load(i)?.to_f64(), c)?;
            let mm_per_rad =
                1000.0 * unambiguous_range_m(sensor.modulation_hz) / std::f64::consts::TAU;
            let rays = set.rays().transpose()?;
            if rays.is_none() {
                eprintln!(
                    "note: no lens intrinsics in the calibration set: every pixel is compared with the on-axis distance {} m, so the FPPN maps also hold the lens geometry (d/cos θ) and are only right at that distance; run `tofprox calibrate intrinsics` first (thesis 5.1.3)",
                    fmt_num(d)
                );
            }
            let mut dropped = Vec::new();
            // one map per algorithm: each is absolute w.r.t. that algorithm's wiggling table
            // (2-phase from the capture's first two images)
            for alg in Algorithm::ALL {
                if set.wiggling(alg).is_none() {
                    eprintln!(
                        "note: no {alg} wiggling table in the calibration set: the {alg} FPPN map also holds the global delay and the wiggling error at {} m; run `tofprox calibrate wiggling` first",
                        fmt_num(d)
                    );
                }
                let map = extract_fppn_through_lens(
                    data.view(),
                    &c.phases_deg,
                    set.offset.as_ref(),
                    set.wiggling(alg),
                    d,
                    rays.as_ref(),
                    sensor.modulation_hz,
                    sensor.adc_bits,
                    alg,
                )
                .with_context(|| format!("extracting the {alg} FPPN map from capture {i}"))?;
                let sd = map.phase_offset_rad.std(0.0);
                let mean = map.phase_offset_rad.mean().unwrap_or(0.0);
                report.push(format!(
                    "{}: from capture {i} at {} m, per-pixel phase offset σ {:.2} mrad ({:.2} mm), mean {:+.2} mrad",
                    CalibPart::fppn(alg),
                    fmt_num(d),
                    1000.0 * sd,
                    f64::from(sd) * mm_per_rad,
                    1000.0 * mean
                ));
                dropped.extend(set.set_fppn_for(
                    alg,
                    map,
                    source(&rec, &a.recording, vec![i], Some(d)),
                )?);
            }
            dropped
        }
        CalibKind::Crosstalk => {
            let caps = rec.captures();
            let idx: Vec<usize> = match a.capture {
                Some(i) => vec![pick_capture(
                    &rec,
                    Some(i),
                    "a capture with nothing in range",
                    |c| {
                        if c.illumination {
                            Ok(())
                        } else {
                            Err("it is a dark capture (illumination = false)".into())
                        }
                    },
                )?],
                None => (0..caps.len())
                    .filter(|&i| {
                        caps[i].illumination
                            && caps[i]
                                .conditions
                                .get(NO_TARGET_CONDITION)
                                .is_some_and(|v| *v >= 0.5)
                    })
                    .collect(),
            };
            if idx.is_empty() {
                bail!(
                    "{} has no illuminated capture with nothing in range (conditions.{NO_TARGET_CONDITION} = 1) to extract the crosstalk from; mark one or pass --capture",
                    a.recording.display()
                );
            }
            if set.offset.is_none() {
                eprintln!(
                    "note: no offset (FPN) in the calibration set: the crosstalk is measured against the mid code; run `tofprox calibrate fpn` first"
                );
            }
            let data: Vec<Array3<f64>> = idx
                .iter()
                .map(|&i| rec.load(i).map(|f| f.to_f64()))
                .collect::<Result<_, _>>()?;
            let captures: Vec<CrosstalkCapture<'_>> = idx
                .iter()
                .zip(&data)
                .map(|(&i, d)| CrosstalkCapture {
                    codes: d.view(),
                    phases_deg: &caps[i].phases_deg,
                    exposure_us: caps[i].exposure_us,
                })
                .collect();
            let x = extract_crosstalk(&captures, set.offset.as_ref(), sensor.adc_bits)
                .with_context(|| format!("extracting the crosstalk from captures {idx:?}"))?;
            let roi = Roi::default();
            let amp = x.mean_amplitude_lsb(Algorithm::TwoPhase, roi, 1.0);
            let (px, py) = (0..x.lsb_per_us.dim().1)
                .flat_map(|r| (0..x.lsb_per_us.dim().2).map(move |c| (r, c)))
                .map(|(r, c)| x.phasor_per_us(Algorithm::TwoPhase, r, c))
                .fold((0.0f64, 0.0f64), |(a, b), (p, q)| {
                    (a + f64::from(p), b + f64::from(q))
                });
            let phase = py.atan2(px).rem_euclid(std::f64::consts::TAU);
            let mm_per_rad =
                1000.0 * unambiguous_range_m(sensor.modulation_hz) / std::f64::consts::TAU;
            report.push(format!(
                "crosstalk: {} capture(s) with nothing in range, mean amplitude {:.4} LSB/µs in the central ROI ({:.1} LSB at 500 µs), mean phase {:.3} rad ({:.0} mm before the wiggling/delay correction)",
                idx.len(),
                amp,
                500.0 * amp,
                phase,
                phase * mm_per_rad
            ));
            set.set_crosstalk(x, source(&rec, &a.recording, idx, None))?
        }
    };
    for p in &dropped {
        eprintln!(
            "note: dropped {p} from the set: it was extracted with the part just replaced; re-run `tofprox calibrate {}`",
            match p {
                CalibPart::Intrinsics => "intrinsics",
                CalibPart::Offset => "fpn",
                CalibPart::Crosstalk => "crosstalk",
                CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase => "wiggling",
                CalibPart::Fppn | CalibPart::Fppn2Phase => "fppn",
                CalibPart::Amplitude => "wiggling",
            }
        );
    }
    if set.description.is_none() {
        set.description = Some(format!("calibration of {}", a.recording.display()));
    }
    set.save(&a.out)?;
    println!("wrote {}", a.out.display());
    for r in report {
        println!("  {r}");
    }
    let parts: Vec<&str> = set.parts().iter().map(|p| p.name()).collect();
    println!("  set now holds: {}", parts.join(", "));
    Ok(ExitCode::SUCCESS)
}

/// Fits the lens to every illuminated capture of a flat target with `distance_m` and N ≥ 4
/// equally spaced phases ([`calibrate_intrinsics`]).
fn fit_lens(
    rec: &Recording,
    sensor: &tofprox_core::SensorGeometry,
) -> anyhow::Result<(Intrinsics, Vec<usize>, String)> {
    let mut idx = Vec::new();
    let mut data = Vec::new();
    for (i, c) in rec.captures().iter().enumerate() {
        let Some(d) = c.distance_m().filter(|d| *d > 0.0) else {
            continue;
        };
        let phases_rad: Vec<f64> = c.phases_deg.iter().map(|p| p.to_radians()).collect();
        if !c.illumination
            || c.phases_deg.len() < 4
            || !tofprox_core::phasor::is_equally_spaced_circle(&phases_rad)
        {
            continue;
        }
        idx.push(i);
        data.push((d, rec.load(i)?.to_f64(), c.phases_deg.clone()));
    }
    let sweep: Vec<SweepCapture<'_>> = data
        .iter()
        .map(|(d, raw, phases)| SweepCapture {
            distance_m: *d,
            raw: raw.view(),
            phases_deg: phases,
        })
        .collect();
    if sensor.rows * 2 < sensor.full_rows || sensor.cols * 2 < sensor.full_cols {
        eprintln!(
            "note: the {}×{} window covers less than half of the {}×{} array: the distortion is only determined inside it",
            sensor.rows, sensor.cols, sensor.full_rows, sensor.full_cols
        );
    }
    let fit = calibrate_intrinsics(
        &sweep,
        sensor.adc_bits,
        sensor.modulation_hz,
        f64::from(PipelineConfig::default().min_amplitude_lsb),
        sensor.roi_origin[0],
        sensor.roi_origin[1],
    )
    .with_context(|| {
        format!(
            "{}: lens calibration needs illuminated captures of a flat target (perpendicular to the optical axis) at ≥ 3 distances with conditions.distance_m and N ≥ 4 equally spaced phases; {} such captures",
            rec.dir().display(),
            idx.len()
        )
    })?;
    let k = fit.intrinsics;
    let d = &k.distortion;
    let line = format!(
        "intrinsics: fitted to {} captures at {} m over {} pixels: fx {:.2} px, fy {:.2} px, principal point ({:.2}, {:.2}) px, k1 {:.4}, k2 {:.4}, k3 {:.4}, p1 {:.5}, p2 {:.5}; ray-factor residual RMS {:.2e} ({:.2} mm at 1 m)",
        idx.len(),
        data.iter()
            .map(|(d, _, _)| fmt_num(*d))
            .collect::<Vec<_>>()
            .join(", "),
        fit.pixels,
        k.fx_px,
        k.fy_px,
        k.cx_px,
        k.cy_px,
        d.k1,
        d.k2,
        d.k3,
        d.p1,
        d.p2,
        fit.rms_ray_factor,
        1000.0 * fit.rms_ray_factor
    );
    Ok((k, idx, line))
}

// ---------------------------------------------------------------- process

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
    let f = fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut enc = png::Encoder::new(
        std::io::BufWriter::new(f),
        img.width as u32,
        img.height as u32,
    );
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc
        .write_header()
        .with_context(|| format!("cannot write {}", path.display()))?;
    wr.write_image_data(&img.rgb)
        .with_context(|| format!("cannot write {}", path.display()))?;
    wr.finish()
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

/// Why a capture cannot be processed with `alg`, if it cannot.
fn unusable_reason(c: &CaptureMeta, alg: Algorithm) -> Option<String> {
    if !c.illumination {
        return Some("dark capture".into());
    }
    let need = alg.phases_deg();
    let ok = c.phases_deg.len() >= need.len()
        && c.phases_deg
            .iter()
            .zip(need)
            .all(|(a, b)| (a - b).abs() < 1e-6);
    if ok {
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

pub fn process(a: ProcessArgs) -> anyhow::Result<ExitCode> {
    let rec = Recording::open(&a.recording)?;
    let sensor = *rec.sensor();
    let calibration = match &a.calib {
        Some(dir) => {
            let set = CalibrationSet::load(dir)?;
            set.check_compatible(&sensor).with_context(|| {
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
            set.to_pipeline_calibration(a.algo)
        }
        None => {
            eprintln!("note: no --calib: processing without offset, wiggling or FPPN correction");
            Default::default()
        }
    };
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
    let k = a.algo.raw_images();
    let pb = progress(todo.len(), "processing");
    let stdout = std::io::stdout();
    if !a.json {
        println!(
            "{:>5}  {:>10}  {:>14}  {:>9}  {:>8}  {:>10}",
            "index", "distance_m", "median_depth_m", "error_mm", "valid_%", "process_us"
        );
    }
    for &i in &todo {
        let raw = rec.load(i)?;
        let crosstalk = pipeline.calibration().crosstalk.clone();
        if crosstalk.is_some() {
            pipeline
                .set_exposure_us(caps[i].exposure_us)
                .with_context(|| format!("capture {i}: scaling the crosstalk calibration"))?;
        }
        let t0 = Instant::now();
        let frame = match &raw {
            RawFrames::U16(x) => pipeline.process(x.slice(s![..k, .., ..])),
            RawFrames::F32(x) => pipeline.process(x.slice(s![..k, .., ..])),
            RawFrames::F64(x) => pipeline.process(x.slice(s![..k, .., ..])),
        }
        .with_context(|| format!("processing capture {i}"))?;
        let process_us = t0.elapsed().as_secs_f64() * 1e6;
        let median = frame.median_valid_depth_m();
        let valid = frame.valid_fraction();
        // what is left of the cover-window crosstalk relative to the calibrated one
        // (meaningful with nothing in range: +1 = doubled, e.g. a smudge)
        let crosstalk_residual = crosstalk
            .as_ref()
            .and_then(|x| residual_ratio(frame, x, a.algo, Roi::default(), caps[i].exposure_us));
        let depth_mm = frame.depth_mm.clone();
        let amplitude = frame.amplitude_lsb.clone();
        let stem = format!("{i:06}");
        let p = a.out.join(format!("{stem}_depth_mm.npy"));
        fs::write(&p, npy::encode_u16(&depth_mm))
            .with_context(|| format!("cannot write {}", p.display()))?;
        let p = a.out.join(format!("{stem}_amplitude_lsb.npy"));
        fs::write(&p, npy::encode_f32(&amplitude))
            .with_context(|| format!("cannot write {}", p.display()))?;
        write_depth_png(
            &a.out.join(format!("{stem}_depth.png")),
            &depth_mm,
            sensor.roi_origin,
            max_m,
        )?;
        let mut out = stdout.lock();
        let truth = caps[i].distance_m();
        let error_mm = truth.zip(median).map(|(t, m)| (m - t) * 1000.0);
        if a.json {
            let mut line = json!({
                "index": i,
                // micrometre resolution: the f32 depth carries no more
                "distance_m": truth,
                "median_depth_m": median.map(|m| (m * 1e6).round() / 1e6),
                "error_mm": error_mm.map(|e| (e * 1e3).round() / 1e3),
                "valid_fraction": valid,
                "process_us": (process_us * 10.0).round() / 10.0,
            });
            // only with a crosstalk calibration
            if let (Some(r), Some(o)) = (crosstalk_residual, line.as_object_mut()) {
                o.insert("crosstalk_residual".into(), json!(r));
            }
            writeln!(out, "{line}").context("writing to stdout")?;
        } else {
            let err = error_mm.map_or("-".into(), |e| format!("{e:+.1}"));
            writeln!(
                out,
                "{:>5}  {:>10}  {:>14}  {:>9}  {:>8.1}  {:>10.1}",
                i,
                truth.map_or("-".into(), fmt_num),
                median.map_or("-".into(), |m| format!("{m:.4}")),
                err,
                100.0 * valid,
                process_us
            )
            .context("writing to stdout")?;
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    if !a.json {
        println!(
            "wrote depth_mm (.npy, u16, 0 = invalid), amplitude_lsb (.npy, f32) and a depth preview (.png, 0..{max_m:.2} m) per capture to {}",
            a.out.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}
