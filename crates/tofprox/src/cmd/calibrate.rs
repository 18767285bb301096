//! `tofprox calibrate`: extracts a calibration part from a recording into a set
//! (`docs/calibration.md`).

use std::fs;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
use ndarray::{Array3, Axis};
use tofprox_core::Algorithm;
use tofprox_core::calib::{
    extract_fppn_through_lens, extract_offset, extract_wiggling_through_lens,
};
use tofprox_core::camera::{Intrinsics, SweepCapture, calibrate_intrinsics};
use tofprox_core::crosstalk::{CrosstalkCapture, extract_crosstalk};
use tofprox_core::phasor::unambiguous_range_m;
use tofprox_core::pipeline::PipelineConfig;
use tofprox_core::proximity::Roi;
use tofprox_core::radiometry::{
    AmplitudeScale, DEFAULT_CALIBRATION_REFLECTIVITY, expected_amplitude_lsb,
};
use tofprox_format::{CalibPart, CalibrationSet, CaptureMeta, PartSource, Recording, now_rfc3339};

use super::common::{TOOL, fmt_num};

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
