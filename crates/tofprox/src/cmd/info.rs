//! `tofprox info`: what a recording or a calibration set holds (recording format:
//! `docs/recording-format.md`, calibration sets: `docs/calibration.md`).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;

use serde_json::json;
use tofprox_core::phasor::unambiguous_range_m;
use tofprox_format::{
    CalibPart, CalibrationSet, DepthRecording, PartState, Recording, RecordingKind,
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
            c.mode_label()
        } else {
            format!("dark {}", c.mode_label())
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
            c.mode_label(),
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
            "chain": set.chain().iter().map(|e| json!({
                "part": e.part.name(),
                "after": e.after.iter().map(|p| p.name()).collect::<Vec<_>>(),
                "state": chain_state(&e.state),
            })).collect::<Vec<_>>(),
            "complete": set.is_complete(),
            "next_steps": set.next_steps(&a.recording.display().to_string()),
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
    print_chain(&set, &a.recording.display().to_string());
    Ok(ExitCode::SUCCESS)
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
