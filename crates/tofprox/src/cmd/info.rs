//! `tofprox info`: what a recording or a calibration set holds (recording format:
//! `docs/recording-format.md`, calibration sets: `docs/calibration.md`).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use serde_json::json;
use tofprox_core::Algorithm;
use tofprox_core::phasor::unambiguous_range_m;
use tofprox_format::{
    CalibPart, CalibrationSet, DepthRecording, PartSource, PartState, Recording, RecordingKind,
};

use super::common::{fmt_num, progress};

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

pub fn info(a: InfoArgs) -> anyhow::Result<ExitCode> {
    let is_calib = a.recording.join(tofprox_format::CALIBRATION_TOML).is_file()
        && !a.recording.join(tofprox_format::RECORDING_TOML).exists();
    if is_calib {
        return calib_info(&a);
    }
    if tofprox_format::recording_kind(&a.recording).ok() == Some(RecordingKind::Depth) {
        return depth_info(&a);
    }
    // an incomplete recording (writer killed part-way) is shown, and flagged as such
    let rec = Recording::inspect(&a.recording)?;
    warn_if_incomplete(&a.recording, rec.is_complete(), rec.captures().len());
    let sat = saturation_per_capture(&rec)?;
    let tally = Tally::of(&rec);
    if a.json {
        println!("{}", recording_json(&a, &rec, &tally, &sat));
    } else {
        print!("{}", recording_text(&a, &rec, &tally, &sat));
    }
    Ok(ExitCode::SUCCESS)
}

/// On stderr: the recording's writer did not finish (`tofprox_format::completion`).
fn warn_if_incomplete(dir: &std::path::Path, complete: bool, captures: usize) {
    if !complete {
        eprintln!(
            "warning: {}: INCOMPLETE recording: its writer did not finish (killed or failed \
             part-way); the {captures} capture(s) shown are whole, processing refuses it",
            dir.display()
        );
    }
}

/// The `complete` line of the text summary.
fn completeness_line(complete: bool) -> &'static str {
    if complete {
        "complete    yes\n"
    } else {
        "complete    NO: its writer did not finish (killed or failed part-way; recording.incomplete present)\n"
    }
}

/// Per capture, the fraction of pixels with a raw image at a rail. Every image is read and
/// checked as the daemon's replay reads it (`Recording::load`, `load_second_frequency`: NaN,
/// infinities and codes outside the ADC's range are refused), the second-frequency images
/// included.
fn saturation_per_capture(rec: &Recording) -> anyhow::Result<Vec<f64>> {
    let n = rec.captures().len();
    let pb = progress(n, "reading");
    let mut sat = Vec::with_capacity(n);
    for i in 0..n {
        rec.load_second_frequency(i)?;
        let f = rec.load(i)?;
        sat.push(f.saturated_fraction(rec.sensor().adc_bits));
        pb.inc(1);
    }
    pb.finish_and_clear();
    Ok(sat)
}

/// A recording's captures counted by mode, exposure, illumination and sample type, and the
/// values of each condition.
struct Tally {
    by_mode: BTreeMap<String, usize>,
    by_exposure: BTreeMap<String, usize>,
    by_illum: BTreeMap<String, usize>,
    by_dtype: BTreeMap<String, usize>,
    conds: BTreeMap<String, Vec<f64>>,
}

impl Tally {
    fn of(rec: &Recording) -> Self {
        let mut t = Tally {
            by_mode: BTreeMap::new(),
            by_exposure: BTreeMap::new(),
            by_illum: BTreeMap::new(),
            by_dtype: BTreeMap::new(),
            conds: BTreeMap::new(),
        };
        for (i, c) in rec.captures().iter().enumerate() {
            let mode = if c.illumination {
                c.mode_label()
            } else {
                format!("dark {}", c.mode_label())
            };
            *t.by_mode.entry(mode).or_default() += 1;
            *t.by_exposure.entry(fmt_num(c.exposure_us)).or_default() += 1;
            *t.by_illum.entry(on_off(c.illumination).into()).or_default() += 1;
            *t.by_dtype.entry(dtype_name(rec, i).into()).or_default() += 1;
            for (k, v) in &c.conditions {
                t.conds.entry(k.clone()).or_default().push(*v);
            }
        }
        t
    }
}

fn on_off(b: bool) -> &'static str {
    if b { "on" } else { "off" }
}

fn dtype_name(rec: &Recording, i: usize) -> &'static str {
    rec.dtype(i).map_or("?", |d| d.name())
}

/// The distinct values of a condition, sorted.
fn distinct(v: &[f64]) -> Vec<f64> {
    let mut d = v.to_vec();
    d.sort_by(f64::total_cmp);
    d.dedup();
    d
}

fn mean_or_zero(v: &[f64]) -> f64 {
    if v.is_empty() {
        0.0
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

/// `tofprox info REC --json`.
fn recording_json(a: &InfoArgs, rec: &Recording, t: &Tally, sat: &[f64]) -> serde_json::Value {
    let s = *rec.sensor();
    let caps = rec.captures();
    let per: Vec<_> = caps
        .iter()
        .enumerate()
        .map(|(i, c)| {
            json!({
                "index": i,
                "frames": c.frames,
                "mode": c.mode_label(),
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
    let cond_json: BTreeMap<_, _> = t
        .conds
        .iter()
        .map(|(k, v)| {
            (
                k.clone(),
                json!({"captures": v.len(), "values": distinct(v)}),
            )
        })
        .collect();
    json!({
        "recording": a.recording.display().to_string(),
        "complete": rec.is_complete(),
        "description": rec.description(),
        "sensor": {
            "rows": s.rows, "cols": s.cols, "roi_origin": s.roi_origin,
            "full_rows": s.full_rows, "full_cols": s.full_cols,
            "adc_bits": s.adc_bits, "modulation_hz": s.modulation_hz,
            "unambiguous_range_m": unambiguous_range_m(s.modulation_hz),
        },
        "captures": caps.len(),
        "by_mode": t.by_mode,
        "by_exposure_us": t.by_exposure,
        "by_illumination": t.by_illum,
        "by_dtype": t.by_dtype,
        "conditions": cond_json,
        "saturated_fraction": mean_or_zero(sat),
        "per_capture": per,
    })
}

/// `tofprox info REC`: the summary, then one line per capture.
fn recording_text(a: &InfoArgs, rec: &Recording, t: &Tally, sat: &[f64]) -> String {
    let s = *rec.sensor();
    let mut o = String::new();
    let _ = writeln!(o, "recording   {}", a.recording.display());
    o.push_str(completeness_line(rec.is_complete()));
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
        unambiguous_range_m(s.modulation_hz)
    );
    write_tally(&mut o, rec.captures().len(), t);
    write_saturation(&mut o, sat);
    let _ = writeln!(o);
    let _ = writeln!(
        o,
        "{:>5}  {:<20} {:<16} {:>11} {:>5} {:>4} {:>8} {:>7}  conditions",
        "index", "frames", "mode", "exposure_us", "illum", "avg", "dtype", "sat %"
    );
    for (i, c) in rec.captures().iter().enumerate() {
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
            c.mode_label(),
            fmt_num(c.exposure_us),
            on_off(c.illumination),
            c.averaged,
            dtype_name(rec, i),
            100.0 * sat.get(i).copied().unwrap_or(0.0),
            cond.join(" ")
        );
    }
    o
}

/// The captures' counts and each condition's values (the first 12).
fn write_tally(o: &mut String, captures: usize, t: &Tally) {
    let join = |m: &BTreeMap<String, usize>, unit: &str| -> String {
        m.iter()
            .map(|(k, v)| format!("{k}{unit} ×{v}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let _ = writeln!(o, "captures    {captures}");
    let _ = writeln!(o, "  by mode         {}", join(&t.by_mode, ""));
    let _ = writeln!(o, "  by exposure     {}", join(&t.by_exposure, " µs"));
    let _ = writeln!(o, "  illumination    {}", join(&t.by_illum, ""));
    let _ = writeln!(o, "  dtype           {}", join(&t.by_dtype, ""));
    for (k, v) in &t.conds {
        let d = distinct(v);
        let shown: Vec<String> = d.iter().take(12).map(|x| fmt_num(*x)).collect();
        let more = if d.len() > 12 { ", …" } else { "" };
        let _ = writeln!(
            o,
            "  {k:<15} {} capture(s): {}{more}",
            v.len(),
            shown.join(", ")
        );
    }
}

/// The mean share of pixels at a rail and the worst capture.
fn write_saturation(o: &mut String, sat: &[f64]) {
    let (worst_i, worst) =
        sat.iter().copied().enumerate().fold(
            (0, 0.0f64),
            |acc, (i, v)| if v > acc.1 { (i, v) } else { acc },
        );
    let _ = write!(
        o,
        "saturation  {:.2} % of pixels have a raw image at a rail",
        100.0 * mean_or_zero(sat)
    );
    if worst > 0.0 {
        let _ = write!(o, " (worst: capture {worst_i}, {:.2} %)", 100.0 * worst);
    }
    let _ = writeln!(o);
}

/// One part of a calibration set, summarised: the quantity it holds, its statistics over
/// every value, and where it came from.
struct PartSummary {
    part: CalibPart,
    what: &'static str,
    mean: f64,
    sd: f64,
    lo: f64,
    hi: f64,
    unit: &'static str,
    src: PartSource,
}

impl PartSummary {
    fn of(set: &CalibrationSet, part: CalibPart) -> Self {
        let values: Vec<f32> = match part {
            CalibPart::Intrinsics => set
                .intrinsics()
                .iter()
                .flat_map(|k| [k.fx_px as f32, k.fy_px as f32])
                .collect(),
            CalibPart::Offset => set
                .offset()
                .iter()
                .flat_map(|o| o.dark_lsb.iter().copied())
                .collect(),
            CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase => part
                .algorithm()
                .and_then(|alg| set.wiggling(alg))
                .into_iter()
                .flat_map(|w| w.correction_rad.iter().copied())
                .collect(),
            CalibPart::Amplitude => set
                .amplitude()
                .iter()
                .flat_map(|a| a.lsb_m2_per_us.iter().copied())
                .collect(),
            CalibPart::Crosstalk => set
                .crosstalk()
                .iter()
                .flat_map(|x| x.lsb_per_us.iter().copied())
                .collect(),
            CalibPart::Fppn | CalibPart::Fppn2Phase => match part {
                CalibPart::Fppn => set.fppn(Algorithm::FourPhase),
                _ => set.fppn(Algorithm::TwoPhase),
            }
            .into_iter()
            .flat_map(|f| f.phase_offset_rad.iter().copied())
            .collect(),
        };
        let (what, unit) = match part {
            CalibPart::Intrinsics => ("focal length", "px"),
            CalibPart::Offset => ("dark level", "LSB"),
            CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase => ("correction", "rad"),
            CalibPart::Amplitude => ("scale K of A = K·ρ·t/d²", "LSB·m²/µs"),
            CalibPart::Crosstalk => ("crosstalk", "LSB/us"),
            CalibPart::Fppn | CalibPart::Fppn2Phase => ("phase offset", "rad"),
        };
        let v: Vec<f64> = values.into_iter().map(f64::from).collect();
        let n = v.len().max(1) as f64;
        let mean = v.iter().sum::<f64>() / n;
        PartSummary {
            part,
            what,
            mean,
            sd: (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt(),
            lo: v.iter().copied().fold(f64::INFINITY, f64::min),
            hi: v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            unit,
            src: set.sources.get(&part).cloned().unwrap_or_default(),
        }
    }
}

/// `tofprox info CALIB`: what a calibration set holds.
fn calib_info(a: &InfoArgs) -> anyhow::Result<ExitCode> {
    let set = CalibrationSet::load(&a.recording)?;
    let parts: Vec<PartSummary> = set
        .parts()
        .into_iter()
        .map(|p| PartSummary::of(&set, p))
        .collect();
    if a.json {
        println!("{}", calib_json(a, &set, &parts));
        return Ok(ExitCode::SUCCESS);
    }
    let v = &set.validity;
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
    for p in &parts {
        print_part(&set, p);
    }
    if parts.is_empty() {
        println!("(no parts)");
    }
    print_chain(&set, &a.recording.display().to_string());
    Ok(ExitCode::SUCCESS)
}

/// `tofprox info CALIB --json`.
fn calib_json(a: &InfoArgs, set: &CalibrationSet, parts: &[PartSummary]) -> serde_json::Value {
    let v = &set.validity;
    let ps: BTreeMap<_, _> = parts
        .iter()
        .map(|p| {
            let src = &p.src;
            (
                p.part.name(),
                json!({
                    "quantity": p.what, "unit": p.unit, "mean": p.mean, "std": p.sd,
                    "min": p.lo, "max": p.hi,
                    "sha256": set.checksum(p.part),
                    "source_recording": src.recording, "source_captures": src.captures,
                    "distance_m": src.distance_m, "created": src.created, "tool": src.tool,
                }),
            )
        })
        .collect();
    json!({
        "calibration": a.recording.display().to_string(),
        "description": set.description,
        "valid_for": {
            "modulation_hz": v.modulation_hz, "adc_bits": v.adc_bits, "rows": v.rows,
            "cols": v.cols, "roi_origin": v.roi_origin, "full_rows": v.full_rows,
            "full_cols": v.full_cols,
        },
        "parts": ps,
        "chain": set.chain().iter().map(|e| json!({
            "part": e.part.name(),
            "after": e.after.iter().map(|p| p.name()).collect::<Vec<_>>(),
            "state": chain_state(&e.state),
        })).collect::<Vec<_>>(),
        "complete": set.is_complete(),
        "next_steps": set.next_steps(&a.recording.display().to_string()),
    })
}

/// Two lines of a part: its statistics (phase values also in mm of depth), then where it
/// came from.
fn print_part(set: &CalibrationSet, p: &PartSummary) {
    let mm_per_rad =
        1000.0 * unambiguous_range_m(set.validity.modulation_hz) / std::f64::consts::TAU;
    let in_mm = |x: f64| {
        if p.unit == "rad" {
            format!(" ({:.1} mm)", x * mm_per_rad)
        } else {
            String::new()
        }
    };
    let size = match p.part {
        CalibPart::Intrinsics => set.intrinsics().map_or(String::new(), |k| {
            let d = &k.distortion;
            format!(
                "; principal point ({:.2}, {:.2}) px, k1 {:.4}, k2 {:.4}, k3 {:.4}, p1 {:.5}, p2 {:.5}",
                k.cx_px, k.cy_px, d.k1, d.k2, d.k3, d.p1, d.p2
            )
        }),
        CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase => p
            .part
            .algorithm()
            .and_then(|alg| set.wiggling(alg))
            .map_or(String::new(), |w| format!(", {} bins", w.len())),
        _ => String::new(),
    };
    let (what, unit, mean, sd, lo, hi) = (p.what, p.unit, p.mean, p.sd, p.lo, p.hi);
    println!(
        "{:<16} {what}: mean {mean:.4} {unit}{}, σ {sd:.4} {unit}{}, range {lo:.4} .. {hi:.4} {unit}{size}",
        p.part.name(),
        in_mm(mean),
        in_mm(sd),
    );
    let src = &p.src;
    let dist = src
        .distance_m
        .map_or(String::new(), |d| format!(" at {} m", fmt_num(d)));
    println!(
        "{:<16} from {} captures {:?}{dist}, {} by {}",
        "", src.recording, src.captures, src.created, src.tool
    );
}

/// The chain of a set: each part, what it is extracted after, where it stands; then whether the
/// set is complete and, if not, the commands that complete it (`docs/calibration.md`).
fn print_chain(set: &CalibrationSet, dir: &str) {
    println!("chain            part extracted after → state");
    for e in set.chain() {
        let after: Vec<&str> = e.after.iter().map(|p| p.name()).collect();
        let after = if after.is_empty() {
            "—".to_string()
        } else {
            after.join(", ")
        };
        println!(
            "  {:<16} {:<50} {}",
            e.part.name(),
            after,
            chain_state(&e.state)
        );
    }
    let steps = set.next_steps(dir);
    if steps.is_empty() {
        println!("complete         yes");
    } else {
        println!("complete         no; to complete it run, in order:");
        for s in steps {
            println!("  {s}");
        }
    }
}

/// A chain state in words.
fn chain_state(s: &PartState) -> String {
    match s {
        PartState::Current => "current".into(),
        PartState::Optional => "absent (optional)".into(),
        PartState::Missing => "MISSING".into(),
        PartState::Provisional { without } => format!(
            "provisional: extracted without {}",
            without
                .iter()
                .map(|p| p.name())
                .collect::<Vec<_>>()
                .join(", ")
        ),
        PartState::Stale(d) => format!(
            "STALE: dropped when {} changed (was from {} captures {:?})",
            d.because, d.recording, d.captures
        ),
    }
}

/// `tofprox info REC` of a depth recording (`kind = "depth"`, as `tofprox record` writes it):
/// images, time span and rate, valid share and median depth per image.
fn depth_info(a: &InfoArgs) -> anyhow::Result<ExitCode> {
    let rec = DepthRecording::open(&a.recording)?;
    warn_if_incomplete(&a.recording, rec.is_complete(), rec.captures().len());
    let size = rec.size();
    let caps = rec.captures();
    let pb = progress(caps.len(), "reading");
    // (valid fraction, median valid depth in mm) per image; 0 mm = invalid
    let mut per = Vec::with_capacity(caps.len());
    for i in 0..caps.len() {
        let d = rec.load_depth_mm(i)?;
        let mut valid: Vec<u16> = d.iter().copied().filter(|&v| v > 0).collect();
        valid.sort_unstable();
        let median = valid.get(valid.len() / 2).copied();
        per.push((valid.len() as f64 / d.len().max(1) as f64, median));
        pb.inc(1);
    }
    pb.finish_and_clear();
    let stamps: Vec<u64> = caps.iter().filter_map(|c| c.timestamp_ns).collect();
    let span_s = match (stamps.iter().min(), stamps.iter().max()) {
        (Some(lo), Some(hi)) if hi > lo => Some((hi - lo) as f64 / 1e9),
        _ => None,
    };
    let rate_hz = span_s.map(|s| (stamps.len() - 1) as f64 / s);
    let with_amplitude = caps.iter().filter(|c| c.amplitude_lsb.is_some()).count();
    let valid_all = if per.is_empty() {
        0.0
    } else {
        per.iter().map(|p| p.0).sum::<f64>() / per.len() as f64
    };
    if a.json {
        let per_json: Vec<_> = caps
            .iter()
            .zip(&per)
            .enumerate()
            .map(|(i, (c, (valid, median)))| {
                json!({
                    "index": i,
                    "timestamp_ns": c.timestamp_ns,
                    "valid_fraction": valid,
                    "median_depth_mm": median,
                    "amplitude": c.amplitude_lsb.is_some(),
                })
            })
            .collect();
        let out = json!({
            "recording": a.recording.display().to_string(),
            "kind": RecordingKind::Depth.name(),
            "complete": rec.is_complete(),
            "description": rec.description(),
            "depth": {"rows": size.rows, "cols": size.cols},
            "captures": caps.len(),
            "with_amplitude": with_amplitude,
            "span_s": span_s,
            "rate_hz": rate_hz,
            "valid_fraction": valid_all,
            "per_capture": per_json,
        });
        println!("{out}");
        return Ok(ExitCode::SUCCESS);
    }
    println!("recording   {} (depth images, mm)", a.recording.display());
    print!("{}", completeness_line(rec.is_complete()));
    if let Some(d) = rec.description() {
        println!("description {d}");
    }
    println!(
        "images      {} of {}×{} pixels, {with_amplitude} with amplitude",
        caps.len(),
        size.rows,
        size.cols
    );
    if let (Some(s), Some(r)) = (span_s, rate_hz) {
        println!(
            "time        {} s at {} Hz",
            fmt_num(s),
            fmt_num((r * 100.0).round() / 100.0)
        );
    }
    println!(
        "valid       {:.1} % of pixels (depth > 0)",
        100.0 * valid_all
    );
    println!();
    println!(
        "{:>5}  {:>20}  {:>8}  {:>16}",
        "index", "timestamp_ns", "valid_%", "median_depth_mm"
    );
    for (i, (c, (valid, median))) in caps.iter().zip(&per).enumerate() {
        println!(
            "{:>5}  {:>20}  {:>8.1}  {:>16}",
            i,
            c.timestamp_ns.map_or("-".into(), |t| t.to_string()),
            100.0 * valid,
            median.map_or("-".into(), |m| m.to_string())
        );
    }
    Ok(ExitCode::SUCCESS)
}
