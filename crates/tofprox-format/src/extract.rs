//! Calibration extraction as a workflow over the files: which captures of a
//! [`Recording`] feed which extraction of `tofprox_core`, with the set's
//! earlier parts (offset, crosstalk, lens, wiggling) applied first, and the
//! result stored in a [`CalibrationSet`] with its provenance
//! (`docs/calibration.md`). `tofprox calibrate` is a thin adapter over
//! [`extract`]; the end-to-end tests call it too.
//!
//! Order of a full calibration (thesis 5.1): intrinsics (5.1.3) → offset/FPN
//! (3.3.4) → crosstalk → wiggling + amplitude scale (5.1.2.2, 2.2.1) → FPPN
//! (5.1.2.3). Each step uses what the set already holds and says (through the
//! `notes` sink) what it had to do without.

use std::path::{Path, PathBuf};

use ndarray::{Array3, Axis};
use tofprox_core::calib::{ExtractionOptions, extract_fppn, extract_offset, extract_wiggling};
use tofprox_core::camera::Intrinsics;
use tofprox_core::crosstalk::{CrosstalkCapture, extract_crosstalk};
use tofprox_core::lens_fit::{
    IntrinsicsFit, MIN_HARMONIC_FREE_PHASES, SweepCapture, calibrate_intrinsics,
    calibrate_intrinsics_with_wiggling,
};
use tofprox_core::phasor::unambiguous_range_m;
use tofprox_core::pipeline::PipelineConfig;
use tofprox_core::proximity::Roi;
use tofprox_core::radiometry::{
    AmplitudeScale, DEFAULT_CALIBRATION_REFLECTIVITY, expected_amplitude_lsb,
};
use tofprox_core::{Algorithm, CoreError};

use crate::calibration::{CalibPart, CalibrationSet, PartSource, now_rfc3339};
use crate::error::{FormatError, parse_toml};
use crate::limits;
use crate::recording::{CaptureMeta, Recording};
use crate::text::fmt_num;

/// Condition key marking a capture with nothing in range (crosstalk calibration).
pub const NO_TARGET_CONDITION: &str = "no_target";

/// Which part of a calibration set to extract.
#[derive(Debug, Clone, PartialEq)]
pub enum Extract {
    /// Lens intrinsics and distortion fitted to a sweep of a flat target at ≥ 3 known distances:
    /// correlation captures with `distance_m`, or (with correlation captures at fewer distances)
    /// 4-phase walls corrected by a correlation capture's wiggling table, fitted jointly.
    Intrinsics,
    /// Lens intrinsics taken from a module's datasheet ([`load_lens_datasheet`]) instead.
    LensDatasheet {
        /// The datasheet's lens.
        lens: Intrinsics,
        /// Where it was read from (recorded as the part's source).
        path: PathBuf,
    },
    /// Per-pixel dark frame (FPN) from the dark captures, averaged.
    Offset,
    /// 2- and 4-phase wiggling tables and the amplitude scale from a correlation capture with
    /// `distance_m`.
    Wiggling,
    /// Per-pixel phase offsets (2- and 4-phase) from a flat-target 4-phase capture with
    /// `distance_m`.
    Fppn,
    /// Cover-window crosstalk from illuminated captures with nothing in range
    /// (`conditions.no_target = 1`).
    Crosstalk,
}

/// How to extract.
#[derive(Debug, Clone, PartialEq)]
pub struct ExtractOptions {
    /// Use only this capture (index in the recording) instead of choosing automatically.
    pub capture: Option<usize>,
    /// Number of bins of the wiggling tables.
    pub lut_size: usize,
    /// Program and version recorded as the parts' `tool`.
    pub tool: String,
}

/// What an extraction did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Extraction {
    /// One line per part written, with its headline figures.
    pub report: Vec<String>,
    /// Parts dropped from the set because they were derived from a replaced one.
    pub dropped: Vec<CalibPart>,
}

/// Why an extraction failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExtractError {
    /// Reading the recording or storing the part in the set failed.
    #[error(transparent)]
    Format(#[from] FormatError),
    /// [`ExtractOptions::capture`] names no capture of the recording.
    #[error("capture {index} does not exist: the recording has {count} captures")]
    NoSuchCapture {
        /// The requested index.
        index: usize,
        /// Captures in the recording.
        count: usize,
    },
    /// [`ExtractOptions::capture`] names a capture the extraction cannot use.
    #[error("capture {index} is not usable as {what}: {why}")]
    CaptureUnusable {
        /// The requested index.
        index: usize,
        /// What the extraction needs.
        what: String,
        /// Why this capture is not it.
        why: String,
    },
    /// The recording holds no capture the extraction can use.
    #[error("{} has no {what}", recording.display())]
    NoCapture {
        /// The recording directory.
        recording: PathBuf,
        /// What the extraction needs.
        what: String,
    },
    /// The extraction itself failed (too few valid pixels, a degenerate sweep, …).
    #[error("{context}")]
    Core {
        /// What was being extracted, from which captures.
        context: String,
        /// The extraction's error.
        #[source]
        source: CoreError,
    },
}

fn core(context: impl Into<String>) -> impl FnOnce(CoreError) -> ExtractError {
    let context = context.into();
    move |source| ExtractError::Core { context, source }
}

/// Read a lens datasheet: a TOML file with `fx_px`, `fy_px`, `cx_px`, `cy_px` in full-array
/// pixels and an optional `[distortion]` table (OpenCV's `k1`, `k2`, `k3`, `p1`, `p2`), bounded
/// like every file this crate reads and validated.
pub fn load_lens_datasheet(path: &Path) -> Result<Intrinsics, FormatError> {
    let text = limits::read_text_bounded(path, limits::MAX_TOML_BYTES)?;
    let lens: Intrinsics = parse_toml(path, &text)?;
    lens.validate().map_err(|e| {
        FormatError::new(crate::ErrorKind::Invalid, format!("not a valid lens: {e}")).at(path)
    })?;
    Ok(lens)
}

/// Extract `what` from `rec` into `set` (which must already be compatible with the recording's
/// sensor, [`CalibrationSet::check_compatible`]). Remarks on what the extraction had to do
/// without go to `notes` as they arise; the set is changed only by a successful extraction.
pub fn extract(
    rec: &Recording,
    set: &mut CalibrationSet,
    what: &Extract,
    opts: &ExtractOptions,
    notes: &mut dyn FnMut(&str),
) -> Result<Extraction, ExtractError> {
    let mut x = Extractor {
        rec,
        opts,
        notes,
        report: Vec::new(),
    };
    let dropped = match what {
        Extract::Intrinsics => {
            let (k, idx, line) = x.fit_lens()?;
            x.report.push(line);
            set.set_intrinsics(k, x.source(idx, None))?
        }
        Extract::LensDatasheet { lens, path } => {
            let mut src = x.source(Vec::new(), None);
            src.recording = path.display().to_string();
            src.recording_description = Some("lens datasheet".into());
            x.report
                .push(format!("intrinsics: from the datasheet {}", path.display()));
            set.set_intrinsics(*lens, src)?
        }
        Extract::Offset => x.offset(set)?,
        Extract::Wiggling => x.wiggling(set)?,
        Extract::Fppn => x.fppn(set)?,
        Extract::Crosstalk => x.crosstalk(set)?,
    };
    Ok(Extraction {
        report: x.report,
        dropped,
    })
}

struct Extractor<'a> {
    rec: &'a Recording,
    opts: &'a ExtractOptions,
    notes: &'a mut dyn FnMut(&str),
    report: Vec<String>,
}

/// Millimetres of distance per radian of phase at `modulation_hz` (thesis eq. 2.5).
fn mm_per_rad(modulation_hz: f64) -> f64 {
    1000.0 * unambiguous_range_m(modulation_hz) / std::f64::consts::TAU
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

impl<'a> Extractor<'a> {
    fn note(&mut self, s: &str) {
        (self.notes)(s);
    }

    fn source(&self, captures: Vec<usize>, distance_m: Option<f64>) -> PartSource {
        PartSource {
            recording: self.rec.dir().display().to_string(),
            recording_description: self.rec.description().map(str::to_string),
            captures,
            distance_m,
            created: now_rfc3339(),
            tool: self.opts.tool.clone(),
            ..PartSource::default()
        }
    }

    /// The capture of [`ExtractOptions::capture`] if it passes `ok`, else the first that does.
    fn pick(
        &self,
        what: &str,
        ok: impl Fn(&CaptureMeta) -> Result<(), String>,
    ) -> Result<usize, ExtractError> {
        let caps = self.rec.captures();
        if let Some(index) = self.opts.capture {
            let c = caps.get(index).ok_or(ExtractError::NoSuchCapture {
                index,
                count: caps.len(),
            })?;
            return match ok(c) {
                Ok(()) => Ok(index),
                Err(why) => Err(ExtractError::CaptureUnusable {
                    index,
                    what: what.into(),
                    why,
                }),
            };
        }
        caps.iter()
            .position(|c| ok(c).is_ok())
            .ok_or_else(|| ExtractError::NoCapture {
                recording: self.rec.dir().to_path_buf(),
                what: what.into(),
            })
    }

    /// [`Self::pick`] for an illuminated capture of a target at a known distance whose phases
    /// pass `phases_ok`; returns its index, metadata and `distance_m`.
    fn pick_target(
        &self,
        what: &str,
        phases_ok: impl Fn(&CaptureMeta) -> Result<(), String>,
    ) -> Result<(usize, &'a CaptureMeta, f64), ExtractError> {
        let usable = |c: &CaptureMeta| {
            if !c.illumination {
                return Err("it is a dark capture".to_string());
            }
            phases_ok(c)?;
            need_distance(c)
        };
        let i = self.pick(what, |c| usable(c).map(|_| ()))?;
        let rec: &'a Recording = self.rec;
        let c = &rec.captures()[i];
        let d = usable(c).map_err(|why| ExtractError::CaptureUnusable {
            index: i,
            what: what.into(),
            why,
        })?;
        Ok((i, c, d))
    }

    /// Every capture passing `ok`, or only [`ExtractOptions::capture`] (which must pass it).
    fn pick_all(
        &self,
        what: &str,
        one_ok: impl Fn(&CaptureMeta) -> Result<(), String>,
        all_ok: impl Fn(&CaptureMeta) -> bool,
    ) -> Result<Vec<usize>, ExtractError> {
        let idx: Vec<usize> = match self.opts.capture {
            Some(_) => vec![self.pick(what, one_ok)?],
            None => (0..self.rec.captures().len())
                .filter(|&i| all_ok(&self.rec.captures()[i]))
                .collect(),
        };
        if idx.is_empty() {
            return Err(ExtractError::NoCapture {
                recording: self.rec.dir().to_path_buf(),
                what: what.into(),
            });
        }
        Ok(idx)
    }

    /// Capture `i`'s codes with the set's cover-window crosstalk subtracted (unchanged without
    /// one), so wiggling and FPPN extracted behind a cover window do not absorb it.
    fn load_without_crosstalk(
        &mut self,
        set: &CalibrationSet,
        i: usize,
    ) -> Result<Array3<f64>, ExtractError> {
        let mut data = self.rec.load(i)?.to_f64();
        if let Some(x) = set.crosstalk() {
            self.note("subtracting the set's cover-window crosstalk before the extraction");
            let rec: &'a Recording = self.rec;
            let c = &rec.captures()[i];
            x.subtract_from(data.view_mut(), &c.phases_deg, c.exposure_us)
                .map_err(core("subtracting the crosstalk"))?;
        }
        Ok(data)
    }

    fn offset(&mut self, set: &mut CalibrationSet) -> Result<Vec<CalibPart>, ExtractError> {
        let idx = self.pick_all(
            "dark capture (illumination = false) to extract the FPN offset from",
            |c| {
                if c.illumination {
                    Err("illumination = true".into())
                } else {
                    Ok(())
                }
            },
            |c| !c.illumination,
        )?;
        let rec: &'a Recording = self.rec;
        let caps = rec.captures();
        let exposures: Vec<f64> = idx.iter().map(|&i| caps[i].exposure_us).collect();
        if exposures.iter().any(|e| (e - exposures[0]).abs() > 1e-9) {
            let list: Vec<String> = exposures.iter().map(|e| fmt_num(*e)).collect();
            self.note(&format!(
                "averaging dark captures of different exposures ({} µs)",
                list.join(", ")
            ));
        }
        let mut images: Vec<Array3<f64>> = Vec::with_capacity(idx.len());
        for &i in &idx {
            images.push(self.rec.load(i)?.to_f64());
        }
        let views: Vec<_> = images.iter().map(|x| x.view()).collect();
        // every capture was validated against the one sensor window: the stack cannot fail
        let all = ndarray::concatenate(Axis(0), &views).map_err(|e| {
            core("stacking the dark captures")(CoreError::ShapeMismatch {
                what: "dark captures",
                expected: "one sensor window".into(),
                got: e.to_string(),
            })
        })?;
        let off = extract_offset(all.view()).map_err(core("extracting the offset (FPN)"))?;
        let mean = off.dark_lsb.mean().unwrap_or(0.0);
        let sd = off.dark_lsb.std(0.0);
        self.report.push(format!(
            "offset: {} dark capture(s) ({} images), mean dark level {:.1} LSB (mid code {}), FPN σ {:.1} LSB",
            idx.len(),
            all.len_of(Axis(0)),
            mean,
            self.rec.sensor().mid_code(),
            sd
        ));
        Ok(set.set_offset(off, self.source(idx, None))?)
    }

    fn wiggling(&mut self, set: &mut CalibrationSet) -> Result<Vec<CalibPart>, ExtractError> {
        let sensor = *self.rec.sensor();
        let (i, c, d) = self.pick_target(
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
        let data = self.load_without_crosstalk(set, i)?;
        if set.offset().is_none() {
            self.note(
                "no offset (FPN) in the calibration set: the wiggling tables are extracted with the mid code subtracted; run `tofprox calibrate fpn` first for the best 2-phase result",
            );
        }
        let rays = set.rays().transpose()?;
        let mm_per_rad = mm_per_rad(sensor.modulation_hz);
        let mut dropped = Vec::new();
        for alg in Algorithm::ALL {
            let lut = extract_wiggling(
                data.view(),
                &ExtractionOptions::new(
                    alg,
                    &c.phases_deg,
                    d,
                    sensor.modulation_hz,
                    sensor.adc_bits,
                )
                .offset(set.offset())
                .rays(rays.as_ref())
                .lut_size(self.opts.lut_size),
            )
            .map_err(core(format!(
                "extracting the {alg} wiggling table from capture {i}"
            )))?;
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
            self.report.push(format!(
                "wiggling_{alg}: {} bins from capture {i} at {} m, mean correction {:.4} rad (global delay, {:.1} mm), wiggling peak-to-peak {:.4} rad ({:.1} mm)",
                lut.len(),
                fmt_num(d),
                mean,
                f64::from(mean) * mm_per_rad,
                hi - lo,
                f64::from(hi - lo) * mm_per_rad
            ));
            dropped.extend(set.set_wiggling(lut, self.source(vec![i], Some(d)))?);
        }
        // The amplitude scale of the 1/d² law (thesis 2.2.1) from the same capture.
        let given_rho = c.conditions.get("reflectivity").copied();
        let rho = match given_rho {
            Some(r) => r,
            None => {
                self.note(&format!(
                    "capture {i} has no conditions.reflectivity: the amplitude scale assumes {} (a perfect diffuse reflector: the scale is a lower bound, so no real target is rejected as implausible)",
                    DEFAULT_CALIBRATION_REFLECTIVITY
                ));
                DEFAULT_CALIBRATION_REFLECTIVITY
            }
        };
        let scale = AmplitudeScale::extract(data.view(), &c.phases_deg, c.exposure_us, d, rho)
            .map_err(core(format!(
                "extracting the amplitude scale from capture {i}"
            )))?;
        let mut sorted: Vec<f32> = scale.lsb_m2_per_us.iter().copied().collect();
        sorted.sort_unstable_by(f32::total_cmp);
        let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
        self.report.push(format!(
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
            ..self.source(vec![i], Some(d))
        };
        dropped.extend(set.set_amplitude(scale, src)?);
        Ok(dropped)
    }

    fn fppn(&mut self, set: &mut CalibrationSet) -> Result<Vec<CalibPart>, ExtractError> {
        let sensor = *self.rec.sensor();
        let (i, c, d) = self.pick_target(
            "an illuminated 4-phase capture of a flat target with distance_m",
            |c| {
                if !c.is_four_phase() {
                    return Err("its phases are not [0, 90, 180, 270]".into());
                }
                Ok(())
            },
        )?;
        let data = self.load_without_crosstalk(set, i)?;
        let mm_per_rad = mm_per_rad(sensor.modulation_hz);
        let rays = set.rays().transpose()?;
        if rays.is_none() {
            self.note(&format!(
                "no lens intrinsics in the calibration set: every pixel is compared with the on-axis distance {} m, so the FPPN maps also hold the lens geometry (d/cos θ) and are only right at that distance; run `tofprox calibrate intrinsics` first (thesis 5.1.3)",
                fmt_num(d)
            ));
        }
        let mut dropped = Vec::new();
        // one map per algorithm: each is absolute w.r.t. that algorithm's wiggling table
        // (2-phase from the capture's first two images)
        for alg in Algorithm::ALL {
            if set.wiggling(alg).is_none() {
                self.note(&format!(
                    "no {alg} wiggling table in the calibration set: the {alg} FPPN map also holds the global delay and the wiggling error at {} m; run `tofprox calibrate wiggling` first",
                    fmt_num(d)
                ));
            }
            let map = extract_fppn(
                data.view(),
                &ExtractionOptions::new(
                    alg,
                    &c.phases_deg,
                    d,
                    sensor.modulation_hz,
                    sensor.adc_bits,
                )
                .offset(set.offset())
                .wiggling(set.wiggling(alg))
                .rays(rays.as_ref()),
            )
            .map_err(core(format!(
                "extracting the {alg} FPPN map from capture {i}"
            )))?;
            let sd = map.phase_offset_rad.std(0.0);
            let mean = map.phase_offset_rad.mean().unwrap_or(0.0);
            self.report.push(format!(
                "{}: from capture {i} at {} m, per-pixel phase offset σ {:.2} mrad ({:.2} mm), mean {:+.2} mrad",
                CalibPart::fppn(alg),
                fmt_num(d),
                1000.0 * sd,
                f64::from(sd) * mm_per_rad,
                1000.0 * mean
            ));
            dropped.extend(set.set_fppn_for(alg, map, self.source(vec![i], Some(d)))?);
        }
        Ok(dropped)
    }

    fn crosstalk(&mut self, set: &mut CalibrationSet) -> Result<Vec<CalibPart>, ExtractError> {
        let sensor = *self.rec.sensor();
        let idx = self.pick_all(
            &format!(
                "illuminated capture with nothing in range (conditions.{NO_TARGET_CONDITION} = 1) to extract the crosstalk from"
            ),
            |c| {
                if c.illumination {
                    Ok(())
                } else {
                    Err("it is a dark capture (illumination = false)".into())
                }
            },
            |c| {
                c.illumination
                    && c.conditions
                        .get(NO_TARGET_CONDITION)
                        .is_some_and(|v| *v >= 0.5)
            },
        )?;
        if set.offset().is_none() {
            self.note(
                "no offset (FPN) in the calibration set: the crosstalk is measured against the mid code; run `tofprox calibrate fpn` first",
            );
        }
        let rec: &'a Recording = self.rec;
        let caps = rec.captures();
        let data: Vec<Array3<f64>> = idx
            .iter()
            .map(|&i| self.rec.load(i).map(|f| f.to_f64()))
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
        let x = extract_crosstalk(&captures, set.offset(), sensor.adc_bits).map_err(core(
            format!("extracting the crosstalk from captures {idx:?}"),
        ))?;
        let amp = x.mean_amplitude_lsb(Algorithm::TwoPhase, Roi::default(), 1.0);
        let (px, py) = (0..x.lsb_per_us.dim().1)
            .flat_map(|r| (0..x.lsb_per_us.dim().2).map(move |c| (r, c)))
            .map(|(r, c)| x.phasor_per_us(Algorithm::TwoPhase, r, c))
            .fold((0.0f64, 0.0f64), |(a, b), (p, q)| {
                (a + f64::from(p), b + f64::from(q))
            });
        let phase = py.atan2(px).rem_euclid(std::f64::consts::TAU);
        self.report.push(format!(
            "crosstalk: {} capture(s) with nothing in range, mean amplitude {:.4} LSB/µs in the central ROI ({:.1} LSB at 500 µs), mean phase {:.3} rad ({:.0} mm before the wiggling/delay correction)",
            idx.len(),
            amp,
            500.0 * amp,
            phase,
            phase * mm_per_rad(sensor.modulation_hz)
        ));
        Ok(set.set_crosstalk(x, self.source(idx, None))?)
    }

    /// Fits the lens to the recording's flat-target captures (thesis 5.1.3). With correlation
    /// captures (N ≥ [`MIN_HARMONIC_FREE_PHASES`] equally spaced phases) at ≥ 3 distinct
    /// distances, to their first harmonic alone ([`calibrate_intrinsics`]): it is shaped by the
    /// lens alone; 4-phase walls are then left out with a note (their wiggling is not corrected
    /// yet when the lens comes first, and the lens would absorb it). With correlation captures at
    /// fewer distances, to the 4-phase walls and correlation captures together, their 4-phase
    /// phase corrected by the wiggling table of the nearest correlation capture, table and lens
    /// fitted jointly ([`calibrate_intrinsics_with_wiggling`]). Data at fewer than 3 distinct
    /// distances, or walls without a correlation capture, is refused with what to capture.
    fn fit_lens(&mut self) -> Result<(Intrinsics, Vec<usize>, String), ExtractError> {
        let sensor = *self.rec.sensor();
        let rec: &'a Recording = self.rec;
        let caps = rec.captures();
        let (correlation, walls) = lens_captures(caps);
        let distances =
            |idx: &[usize]| distinct_distances(idx.iter().map(|&i| caps[i].distance_m()));
        let corr_m = distances(&correlation);
        let all: Vec<usize> = correlation.iter().chain(&walls).copied().collect();
        let joint = corr_m.len() < 3 && !correlation.is_empty() && distances(&all).len() >= 3;
        if corr_m.len() < 3 && !joint {
            return Err(self.cannot_pin_lens(&corr_m, &distances(&walls)));
        }
        if sensor.rows * 2 < sensor.full_rows || sensor.cols * 2 < sensor.full_cols {
            self.note(&format!(
                "the {}×{} window covers less than half of the {}×{} array: the distortion is only determined inside it",
                sensor.rows, sensor.cols, sensor.full_rows, sensor.full_cols
            ));
        }
        let mut idx = if joint { all } else { correlation.clone() };
        idx.sort_unstable();
        let data = idx
            .iter()
            .map(|&i| Ok((i, self.rec.load(i)?.to_f64())))
            .collect::<Result<Vec<_>, ExtractError>>()?;
        let sweep: Vec<SweepCapture<'_>> = data
            .iter()
            .map(|(i, raw)| SweepCapture {
                distance_m: caps[*i].distance_m().unwrap_or(0.0),
                raw: raw.view(),
                phases_deg: &caps[*i].phases_deg,
            })
            .collect();
        let at_m = fmt_list(idx.iter().map(|&i| caps[i].distance_m().unwrap_or(0.0)));
        let context = core(format!(
            "{}: fitting the lens to captures {idx:?} (at {at_m} m)",
            self.rec.dir().display()
        ));
        let (fit, how) = if joint {
            self.fit_lens_jointly(&sweep, &idx, &correlation, corr_m.len())
        } else {
            self.fit_lens_to_first_harmonic(&sweep, &walls)
        }
        .map_err(context)?;
        let line = format!(
            "intrinsics: fitted to {} captures at {at_m} m over {} pixels ({how}): {}; ray-factor residual RMS {:.2e} ({:.2} mm at 1 m)",
            idx.len(),
            fit.pixels,
            lens_with_errors(&fit.intrinsics, &fit.standard_errors),
            fit.rms_ray_factor,
            1000.0 * fit.rms_ray_factor
        );
        Ok((fit.intrinsics, idx, line))
    }

    /// [`calibrate_intrinsics_with_wiggling`] with the wiggling table of the nearest correlation
    /// capture (the strongest return, 1/d², thesis 2.2.1); `idx` are the sweep's capture indices.
    fn fit_lens_jointly(
        &mut self,
        sweep: &[SweepCapture<'_>],
        idx: &[usize],
        correlation: &[usize],
        correlation_distances: usize,
    ) -> Result<(IntrinsicsFit, String), CoreError> {
        let k = (0..idx.len())
            .filter(|&j| correlation.contains(&idx[j]))
            .min_by(|&a, &b| sweep[a].distance_m.total_cmp(&sweep[b].distance_m))
            .unwrap_or(0);
        let min_amplitude_lsb = f64::from(PipelineConfig::default().min_amplitude_lsb);
        let j = calibrate_intrinsics_with_wiggling(
            &sweep[k],
            sweep,
            self.rec.sensor(),
            min_amplitude_lsb,
        )?;
        self.note(&format!(
            "correlation captures at only {correlation_distances} distance(s): the lens is fitted to the 4-phase walls too, their wiggling corrected by the table of capture {} (fitted jointly with the lens)",
            idx[k]
        ));
        let how = format!(
            "4-phase phases corrected by the wiggling table of capture {} at {} m, fitted jointly with the lens ({} passes, last change {:.2} standard errors)",
            idx[k],
            fmt_num(sweep[k].distance_m),
            j.passes,
            j.last_change_se
        );
        Ok((j.fit, how))
    }

    /// [`calibrate_intrinsics`] on correlation captures; the 4-phase `walls` left out with a note.
    fn fit_lens_to_first_harmonic(
        &mut self,
        sweep: &[SweepCapture<'_>],
        walls: &[usize],
    ) -> Result<(IntrinsicsFit, String), CoreError> {
        if !walls.is_empty() {
            self.note(&format!(
                "left out captures {walls:?} of the lens fit: with fewer than {MIN_HARMONIC_FREE_PHASES} phases their phase holds the uncorrected wiggling (3rd/5th harmonics, thesis 3.3.6), which the lens would absorb; the fit uses the correlation captures (≥ {MIN_HARMONIC_FREE_PHASES} equally spaced phases)"
            ));
        }
        let sensor = self.rec.sensor();
        let fit = calibrate_intrinsics(
            sweep,
            sensor.adc_bits,
            sensor.modulation_hz,
            f64::from(PipelineConfig::default().min_amplitude_lsb),
            sensor.roi_origin[0],
            sensor.roi_origin[1],
        )?;
        Ok((
            fit,
            "first harmonic of the correlation captures".to_string(),
        ))
    }

    /// Why the recording's captures cannot pin the lens, and what to capture.
    fn cannot_pin_lens(&self, correlation_m: &[f64], walls_m: &[f64]) -> ExtractError {
        let listed = |d: &[f64]| match d {
            [] => "none".to_string(),
            d => format!("at {} m", fmt_list(d.iter().copied())),
        };
        let todo = if correlation_m.is_empty() && walls_m.len() >= 3 {
            "capture one correlation capture (24 × 15°) of the wall at any distance in range, whose wiggling table corrects the 4-phase walls".to_string()
        } else {
            let have = distinct_distances(correlation_m.iter().chain(walls_m).map(|d| Some(*d)));
            format!(
                "capture the flat wall at {} more distinct distance(s), e.g. correlation captures (24 × 15°){}",
                3 - have.len().min(3),
                if correlation_m.is_empty() {
                    ""
                } else {
                    " or 4-phase walls"
                }
            )
        };
        ExtractError::NoCapture {
            recording: self.rec.dir().to_path_buf(),
            what: format!(
                "captures that can pin the lens: it needs a flat target perpendicular to the optical axis at ≥ 3 distinct distances (at one distance a pixel's ray factor cannot be told from its delay), as correlation captures (N ≥ {MIN_HARMONIC_FREE_PHASES} equally spaced phases) or as 4-phase walls with a correlation capture whose wiggling table corrects them; correlation captures: {}; 4-phase walls: {}; {todo}",
                listed(correlation_m),
                listed(walls_m)
            ),
        }
    }
}

/// The captures a lens fit may use: illuminated, with a positive `distance_m`, as
/// (correlation captures: N ≥ [`MIN_HARMONIC_FREE_PHASES`] equally spaced phases; 4-phase walls).
fn lens_captures(caps: &[CaptureMeta]) -> (Vec<usize>, Vec<usize>) {
    let (mut correlation, mut walls) = (Vec::new(), Vec::new());
    for (i, c) in caps.iter().enumerate() {
        if !c.illumination || !c.distance_m().is_some_and(|d| d > 0.0) {
            continue;
        }
        let phases_rad: Vec<f64> = c.phases_deg.iter().map(|p| p.to_radians()).collect();
        let equally_spaced = tofprox_core::phasor::is_equally_spaced_circle(&phases_rad);
        if equally_spaced && c.phases_deg.len() >= MIN_HARMONIC_FREE_PHASES {
            correlation.push(i);
        } else if c.is_four_phase() {
            walls.push(i);
        }
    }
    (correlation, walls)
}

/// The distinct distances (1 µm apart) among `distances`, ascending.
fn distinct_distances(distances: impl Iterator<Item = Option<f64>>) -> Vec<f64> {
    let mut d: Vec<f64> = distances.flatten().collect();
    d.sort_by(f64::total_cmp);
    d.dedup_by(|b, a| (*b - *a).abs() <= 1e-6);
    d
}

/// `0.3, 0.45, 0.6` (each number as [`fmt_num`] writes it).
fn fmt_list(values: impl Iterator<Item = f64>) -> String {
    values.map(fmt_num).collect::<Vec<_>>().join(", ")
}

/// A fitted lens with the standard error of each value (`fx 172.50 ± 2.1e-2 px, …`; `k3` is held
/// at 0 by the fit and printed without one).
fn lens_with_errors(k: &Intrinsics, se: &Intrinsics) -> String {
    let (d, e) = (&k.distortion, &se.distortion);
    format!(
        "fx {:.2} ± {:.1e} px, fy {:.2} ± {:.1e} px, principal point ({:.2} ± {:.1e}, {:.2} ± {:.1e}) px, k1 {:.4} ± {:.1e}, k2 {:.4} ± {:.1e}, k3 {:.4} (held), p1 {:.5} ± {:.1e}, p2 {:.5} ± {:.1e}",
        k.fx_px,
        se.fx_px,
        k.fy_px,
        se.fy_px,
        k.cx_px,
        se.cx_px,
        k.cy_px,
        se.cy_px,
        d.k1,
        e.k1,
        d.k2,
        e.k2,
        d.k3,
        d.p1,
        e.p1,
        d.p2,
        e.p2
    )
}
