//! The station's run: the captures a line needs in the documented order, each part through
//! `tofprox_format`'s extraction workflow (what `tofprox calibrate` runs), the limits, the
//! check target through the processing workflow with the new set.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde::Serialize;
use tofprox_bridge::{Clock, SensorMode};
use tofprox_core::Algorithm;
use tofprox_format::{
    CalibPart, CalibrationSet, Extract, ExtractOptions, NO_TARGET_CONDITION, ProcessOptions,
    Processing, Recording,
};

use crate::capture::{StepRequest, capture_step};
use crate::figures::{self, PartCheck};
use crate::{Fixture, Line, Placement, Station, StationError};

/// Where the station writes under `--out`: the set itself, the recordings of its steps, the
/// report.
pub const SET_DIR: &str = "calib";
/// The steps' recordings (kept: the set's provenance points at them).
pub const RECORDINGS_DIR: &str = "recordings";
/// The JSON report.
pub const REPORT_JSON: &str = "report.json";
/// The HTML report.
pub const REPORT_HTML: &str = "report.html";

/// How long one step took.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StepTime {
    /// The step (`dark`, `crosstalk`, `wiggling`, `fppn`, `check`).
    pub step: String,
    /// Measurements averaged.
    pub frames: u32,
    /// Exposure per raw image the device programmed, µs.
    pub exposure_us: f64,
    /// Time on the device's clock (virtual for the emulated module), s.
    pub device_s: f64,
    /// Wall time of the step (captures, writing, extraction), s.
    pub wall_s: f64,
}

/// The check target's reading with the new set, per algorithm.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CheckReading {
    /// 2- or 4-phase.
    pub algorithm: Algorithm,
    /// The fixture's distance of the check target, m.
    pub distance_m: f64,
    /// Median radial depth over the valid pixels, m.
    pub median_depth_m: Option<f64>,
    /// Median − fixture distance, mm.
    pub error_mm: Option<f64>,
    /// Share of valid pixels.
    pub valid_fraction: f32,
}

/// What the station did and decided.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report {
    /// The line.
    pub line: Line,
    /// The station file's description.
    pub station: String,
    /// The module (the fixture's description).
    pub module: String,
    /// The set's directory.
    pub set: PathBuf,
    /// Whether the set is complete (`tofprox info`).
    pub complete: bool,
    /// Every figure against its limit, in the order of the parts' extraction.
    pub checks: Vec<PartCheck>,
    /// The check target's readings.
    pub check_readings: Vec<CheckReading>,
    /// The steps' times.
    pub steps: Vec<StepTime>,
    /// Total time on the device's clock, s.
    pub device_s: f64,
    /// Total wall time, s.
    pub wall_s: f64,
    /// The extraction's report lines.
    pub notes: Vec<String>,
    /// Whether every check passed.
    pub passed: bool,
}

impl Report {
    /// The parts that failed a limit, in order, each once.
    pub fn failed_parts(&self) -> Vec<&str> {
        let mut out: Vec<&str> = Vec::new();
        for c in self.checks.iter().filter(|c| !c.passed) {
            if !out.contains(&c.part.as_str()) {
                out.push(&c.part);
            }
        }
        out
    }
}

/// The options every extraction of the station runs with (one place, so a change of the
/// extraction's options is one change here).
fn extract_options() -> ExtractOptions {
    ExtractOptions {
        capture: None,
        lut_size: 256,
        tool: format!("tofprox-station {}", env!("CARGO_PKG_VERSION")),
    }
}

struct Ctx<'a, F: Fixture> {
    station: &'a Station,
    fixture: &'a mut F,
    clock: std::sync::Arc<dyn Clock>,
    recordings: PathBuf,
    set_dir: PathBuf,
    set: Option<CalibrationSet>,
    steps: Vec<StepTime>,
    notes: Vec<String>,
}

/// Run the station for `line` on the module in `fixture`, writing the set, the steps'
/// recordings and the report (JSON and HTML) under `out` (which must not hold a set yet).
pub fn run_station<F: Fixture>(
    station: &Station,
    line: Line,
    station_path: &Path,
    fixture: &mut F,
    out: &Path,
) -> Result<Report, StationError> {
    if station.line != line {
        return Err(StationError::LineMismatch {
            path: station_path.to_path_buf(),
            file: station.line,
            asked: line,
        });
    }
    let wall0 = Instant::now();
    let clock = fixture.clock();
    let dev0 = clock.now();
    let mut cx = Ctx {
        station,
        fixture,
        clock,
        recordings: out.join(RECORDINGS_DIR),
        set_dir: out.join(SET_DIR),
        set: None,
        steps: Vec::new(),
        notes: Vec::new(),
    };
    if cx.set_dir.join(tofprox_format::CALIBRATION_TOML).exists() {
        return Err(StationError::file(
            &cx.set_dir,
            "",
            "already holds a calibration set: the station writes a new one (choose another --out)",
        ));
    }
    let t = &station.targets;
    let c = &station.captures;
    // docs/calibration.md: fpn → crosstalk (phone) → wiggling (+ amplitude) → fppn
    cx.step(
        "dark",
        Placement::Wall(&t.wall),
        SensorMode::FourPhaseGrey,
        c.dark,
        false,
        Extract::Offset,
    )?;
    if line == Line::Phone
        && let (Some(a), Some(x)) = (&t.absorber, c.crosstalk)
    {
        cx.step(
            "crosstalk",
            Placement::Absorber(a),
            SensorMode::Depth(Algorithm::FourPhase),
            x,
            true,
            Extract::Crosstalk,
        )?;
    }
    cx.step(
        "wiggling",
        Placement::Wall(&t.wall),
        SensorMode::Correlation24,
        c.wiggling,
        true,
        Extract::Wiggling,
    )?;
    cx.step(
        "fppn",
        Placement::Wall(&t.wall),
        SensorMode::Depth(Algorithm::FourPhase),
        c.fppn,
        true,
        Extract::Fppn,
    )?;
    let readings = cx.check()?;
    let set = cx.set.take();
    let complete = set.as_ref().is_some_and(CalibrationSet::is_complete);
    let modulation_hz = set.as_ref().map_or(f64::NAN, |s| s.validity.modulation_hz);
    let checks = part_checks(station, line, &cx.set_dir, modulation_hz, &readings)?;
    let passed = complete && checks.iter().all(|c| c.passed);
    let report = Report {
        line,
        station: station.description.clone(),
        module: cx.fixture.describe(),
        set: cx.set_dir.clone(),
        complete,
        checks,
        check_readings: readings,
        steps: cx.steps,
        device_s: secs(cx.clock.now().saturating_sub(dev0)),
        wall_s: wall0.elapsed().as_secs_f64(),
        notes: cx.notes,
        passed,
    };
    crate::report::write_reports(&report, out)?;
    Ok(report)
}

fn secs(d: Duration) -> f64 {
    d.as_secs_f64()
}

impl<F: Fixture> Ctx<'_, F> {
    fn capture(
        &mut self,
        step: &str,
        placement: Placement<'_>,
        mode: SensorMode,
        spec: crate::CaptureSpec,
        illumination: bool,
    ) -> Result<(PathBuf, f64), StationError> {
        let t = placement.target();
        let mut conditions = self.fixture.conditions();
        match placement {
            Placement::Absorber(_) => {
                conditions.insert(NO_TARGET_CONDITION.into(), 1.0);
            }
            Placement::Wall(_) | Placement::Check(_) => {
                conditions.insert("distance_m".into(), t.distance_m);
                conditions.insert("reflectivity".into(), t.reflectivity);
            }
        }
        let req = StepRequest {
            step,
            mode,
            spec,
            rows: self.station.module.row_window(),
            illumination,
            conditions,
        };
        let dir = self.recordings.join(step);
        let clock = self.clock.clone();
        let driver = self.fixture.present(placement)?;
        let exposure_us = capture_step(driver, clock.as_ref(), &req, &dir)?;
        Ok((dir, exposure_us))
    }

    fn step(
        &mut self,
        step: &str,
        placement: Placement<'_>,
        mode: SensorMode,
        spec: crate::CaptureSpec,
        illumination: bool,
        what: Extract,
    ) -> Result<(), StationError> {
        let (wall0, dev0) = (Instant::now(), self.clock.now());
        let (dir, exposure_us) = self.capture(step, placement, mode, spec, illumination)?;
        let device_s = secs(self.clock.now().saturating_sub(dev0));
        let fmt = |source| StationError::Format {
            step: step.to_string(),
            source,
        };
        let rec = Recording::open(&dir).map_err(fmt)?;
        let set = self
            .set
            .get_or_insert_with(|| CalibrationSet::new(rec.sensor()));
        let mut notes = Vec::new();
        let done = tofprox_format::extract(&rec, set, &what, &extract_options(), &mut |n| {
            notes.push(format!("{step}: note: {n}"));
        })
        .map_err(|source| StationError::Extract {
            step: step.to_string(),
            source,
        })?;
        set.description = Some(format!("calibration station: {}", self.station.description));
        set.save(&self.set_dir).map_err(fmt)?;
        self.notes.extend(notes);
        self.notes
            .extend(done.report.into_iter().map(|r| format!("{step}: {r}")));
        self.steps.push(StepTime {
            step: step.into(),
            frames: spec.frames,
            exposure_us,
            device_s,
            wall_s: wall0.elapsed().as_secs_f64(),
        });
        Ok(())
    }

    /// The check target, 4-phase, processed with the new set by both algorithms (the 2-phase
    /// one from the capture's first two images, eq. 2.2).
    fn check(&mut self) -> Result<Vec<CheckReading>, StationError> {
        let target = &self.station.targets.check;
        let spec = self.station.captures.check;
        let (wall0, dev0) = (Instant::now(), self.clock.now());
        let (dir, exposure_us) = self.capture(
            "check",
            Placement::Check(target),
            SensorMode::Depth(Algorithm::FourPhase),
            spec,
            true,
        )?;
        let device_s = secs(self.clock.now().saturating_sub(dev0));
        let mut out = Vec::new();
        for algo in [Algorithm::TwoPhase, Algorithm::FourPhase] {
            let check = |source| StationError::Check { source };
            let mut p = Processing::open(&dir, Some(&self.set_dir), ProcessOptions::new(algo))
                .map_err(check)?;
            let first = p.todo().first().copied().unwrap_or(0);
            let row = p.capture(first).map_err(check)?.row;
            out.push(CheckReading {
                algorithm: algo,
                distance_m: target.distance_m,
                median_depth_m: row.median_depth_m,
                error_mm: row.error_mm,
                valid_fraction: row.valid_fraction,
            });
        }
        self.steps.push(StepTime {
            step: "check".into(),
            frames: spec.frames,
            exposure_us,
            device_s,
            wall_s: wall0.elapsed().as_secs_f64(),
        });
        Ok(out)
    }
}

/// Every figure of the set as written against the limits, in extraction order, then the check.
fn part_checks(
    station: &Station,
    line: Line,
    dir: &Path,
    modulation_hz: f64,
    readings: &[CheckReading],
) -> Result<Vec<PartCheck>, StationError> {
    let l = &station.limits;
    let mut v = figures::offset_checks(dir, l)?;
    if line == Line::Phone
        && let Some(limit) = l.crosstalk_lsb_per_us
    {
        v.push(figures::crosstalk_check(dir, limit)?);
    }
    for part in [CalibPart::Wiggling2Phase, CalibPart::Wiggling4Phase] {
        v.push(figures::wiggling_check(dir, part, modulation_hz, l)?);
    }
    v.extend(figures::amplitude_checks(dir, l)?);
    for part in [CalibPart::Fppn2Phase, CalibPart::Fppn] {
        v.push(figures::fppn_check(dir, part, modulation_hz, l)?);
    }
    for r in readings {
        v.push(PartCheck::new(
            "check",
            &format!("{} depth error at {} m", r.algorithm, r.distance_m),
            (r.error_mm.map_or(f64::NAN, f64::abs), "mm"),
            (None, Some(l.check_error_mm)),
            "the calibrated module does not read the check target's distance: a part is wrong although within its limits (the fixture moved, a target is misplaced, the module changed after the captures)",
        ));
    }
    Ok(v)
}
