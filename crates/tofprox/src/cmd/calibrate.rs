//! `tofprox calibrate`: extracts a calibration part from a recording into a set
//! (`docs/calibration.md`). A thin adapter over [`tofprox_format::extract()`],
//! which holds the workflow (capture selection, dark stacking, one extraction
//! per algorithm, crosstalk and lens handling).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use tofprox_format::{
    CalibrationSet, Extract, ExtractError, ExtractOptions, Recording, load_lens_datasheet,
};

use super::common::TOOL;

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
    /// in full-array pixels and an optional `[distortion]` table with OpenCV's k1, k2, k3, p1, p2)
    /// instead of fitting it to the recording.
    #[arg(long)]
    pub datasheet: Option<PathBuf>,
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
    let what = match a.what {
        CalibKind::Intrinsics => match &a.datasheet {
            Some(path) => Extract::LensDatasheet {
                lens: load_lens_datasheet(path)?,
                path: path.clone(),
            },
            None => Extract::Intrinsics,
        },
        CalibKind::Fpn => Extract::Offset,
        CalibKind::Wiggling => Extract::Wiggling,
        CalibKind::Fppn => Extract::Fppn,
        CalibKind::Crosstalk => Extract::Crosstalk,
    };
    let opts = ExtractOptions {
        capture: a.capture,
        lut_size: a.lut_size,
        tool: TOOL.to_string(),
    };
    let done = tofprox_format::extract(&rec, &mut set, &what, &opts, &mut |n| {
        eprintln!("note: {n}");
    })
    .map_err(|e| cli_error(e, &a))?;
    for p in &done.dropped {
        let why = set
            .dropped()
            .get(p)
            .map_or("a part it depends on changed".to_string(), |d| {
                format!("the {} changed and {}", d.because, d.reason())
            });
        eprintln!("warning: dropped {p} from the set: {why}; extract it again (the steps below)");
    }
    if set.description.is_none() {
        set.description = Some(format!("calibration of {}", a.recording.display()));
    }
    set.save(&a.out)?;
    println!("wrote {}", a.out.display());
    for r in done.report {
        println!("  {r}");
    }
    let parts: Vec<&str> = set.parts().iter().map(|p| p.name()).collect();
    println!("  set now holds: {}", parts.join(", "));
    let steps = set.next_steps(&a.out.display().to_string());
    if steps.is_empty() {
        println!("  the set is complete");
    } else {
        eprintln!("note: the set is not complete yet; run, in order:");
        for s in steps {
            eprintln!("  {s}");
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// The workflow's errors in the command's words (`--capture`, `tofprox info`).
fn cli_error(e: ExtractError, a: &CalibrateArgs) -> anyhow::Error {
    match e {
        ExtractError::NoSuchCapture { index, count } => {
            anyhow::anyhow!("--capture {index}: the recording has {count} captures")
        }
        ExtractError::CaptureUnusable { index, what, why } => {
            anyhow::anyhow!("--capture {index} is not usable as {what}: {why}")
        }
        e @ ExtractError::NoCapture { .. } => anyhow::anyhow!(
            "{e} (see `tofprox info {}`, or choose one with --capture)",
            a.recording.display()
        ),
        e => e.into(),
    }
}
