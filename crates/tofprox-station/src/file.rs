//! The station file (`config/station/*.toml`): the fixture (targets, distances, field of
//! view), the captures with their exposures inside the eye-safe limit, and the pass/fail
//! limits. Unknown keys are refused; every error names the file and the key.

use std::fmt;
use std::path::Path;

use serde::{Deserialize, Serialize};
use tofprox_core::RowWindow;

use crate::StationError;

/// Largest station file read (a station file is a few kB).
const MAX_FILE_BYTES: u64 = 1 << 20;

/// The eye-safe exposure ceiling per raw image the daemon runs with by default
/// (`tofproxd` `[exposure] max_us`, `docs/daemon.md`), µs.
pub const DAEMON_EXPOSURE_MAX_US: f64 = 500.0;

/// Which production line: a bare module, or a module built into a phone behind its cover
/// window (which adds the crosstalk part, `docs/calibration.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Line {
    /// A bare module: fpn → wiggling (+ amplitude) → fppn.
    Module,
    /// A module behind a phone's cover window: fpn → crosstalk → wiggling (+ amplitude) → fppn.
    Phone,
}

impl Line {
    /// `module` or `phone`.
    pub fn name(self) -> &'static str {
        match self {
            Line::Module => "module",
            Line::Phone => "phone",
        }
    }
}

impl fmt::Display for Line {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Line {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "module" => Ok(Line::Module),
            "phone" => Ok(Line::Phone),
            _ => Err(format!("line {s:?}: expected module or phone")),
        }
    }
}

/// A station file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Station {
    /// What the station is (printed in the report).
    pub description: String,
    /// The line the station serves.
    pub line: Line,
    /// The module as the fixture holds it.
    pub module: ModuleSpec,
    /// The eye-safe limit every capture's exposure must stay within.
    pub exposure: ExposureLimit,
    /// The targets of the fixture.
    pub targets: Targets,
    /// What is captured in each step.
    pub captures: Captures,
    /// Pass/fail limits per part and for the check target.
    pub limits: Limits,
}

/// The module in the fixture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModuleSpec {
    /// Field of view of the lens, horizontal and vertical, degrees (the targets must cover it).
    pub fov_deg: [f64; 2],
    /// Read out only these rows, `[first, count]` (the set is then valid for that window);
    /// absent: the full array.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rows: Option<[u16; 2]>,
}

impl ModuleSpec {
    /// The read-out window, if any.
    pub fn row_window(&self) -> Option<RowWindow> {
        self.rows
            .map(|[row0, rows]| RowWindow::rows_only(row0, rows))
    }
}

/// `[exposure]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExposureLimit {
    /// The longest exposure per raw image, µs: the daemon's `exposure.max_us` (eye safety of
    /// the illumination, [`DAEMON_EXPOSURE_MAX_US`] unless the product's laser class allows more).
    pub max_us: f64,
}

/// `[targets]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Targets {
    /// The flat calibration wall (wiggling, amplitude, FPPN).
    pub wall: Target,
    /// The check target at another distance (verification of the calibrated module).
    pub check: Target,
    /// Nothing in range for the cover-window crosstalk (phone line): a black absorber or a
    /// room far beyond the illumination.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub absorber: Option<Target>,
}

/// One flat target of the fixture, perpendicular to the optical axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Target {
    /// Distance from the module's sensor plane to the target, m (the fixture's, measured).
    pub distance_m: f64,
    /// Width and height of the target, m.
    pub size_m: [f64; 2],
    /// Peak-to-valley flatness over the target, mm.
    pub flatness_mm: f64,
    /// Diffuse reflectivity at the illumination's wavelength (0–1).
    pub reflectivity: f64,
}

impl Target {
    /// How many times the target covers the field of view at its distance, the smaller of
    /// width and height: target size / (2 d tan(fov/2)) (pinhole projection, thesis 5.1.3).
    pub fn field_coverage(&self, fov_deg: [f64; 2]) -> f64 {
        let field = |fov: f64| 2.0 * self.distance_m * (fov.to_radians() / 2.0).tan();
        (self.size_m[0] / field(fov_deg[0])).min(self.size_m[1] / field(fov_deg[1]))
    }
}

/// `[captures]`: one table per step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Captures {
    /// Dark frames (the grey image of `4phase-grey` measurements: illumination off) → offset.
    pub dark: CaptureSpec,
    /// Nothing in range, illuminated → crosstalk (phone line only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crosstalk: Option<CaptureSpec>,
    /// 24 × 15° correlation of the wall → wiggling tables and amplitude scale.
    pub wiggling: CaptureSpec,
    /// 4-phase of the wall → FPPN maps.
    pub fppn: CaptureSpec,
    /// 4-phase of the check target → depth error of the calibrated module.
    pub check: CaptureSpec,
}

/// How one step captures: `frames` measurements at `exposure_us`, averaged into one capture.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaptureSpec {
    /// Exposure per raw image, µs (≤ `exposure.max_us`).
    pub exposure_us: f64,
    /// Measurements averaged (shot noise falls as 1/√frames, like a `frames`× longer exposure).
    pub frames: u32,
}

/// `[limits]`: what a module must meet. Each limit is documented in `docs/calibration.md`
/// ("Production line").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Limits {
    /// Largest standard deviation of the dark level over the pixels (FPN σ), LSB.
    pub fpn_sigma_lsb: f64,
    /// A pixel whose dark level departs from the median by more than this is hot (or cold), LSB.
    pub hot_pixel_lsb: f64,
    /// Most hot pixels allowed.
    pub hot_pixels: usize,
    /// Largest peak-to-peak of either wiggling table, mm of radial distance.
    pub wiggling_p2p_mm: f64,
    /// Largest standard deviation of either FPPN map, mm.
    pub fppn_sigma_mm: f64,
    /// Range `[min, max]` of the median amplitude scale K, LSB·m²/µs.
    pub amplitude_k: [f64; 2],
    /// A pixel whose K is below this share of the median is dead.
    pub dead_pixel_fraction: f64,
    /// Most dead pixels allowed.
    pub dead_pixels: usize,
    /// Largest cover-window crosstalk: median over the pixels of its 4-phase amplitude, LSB/µs
    /// (phone line).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crosstalk_lsb_per_us: Option<f64>,
    /// Largest |median depth − fixture distance| on the check target, either algorithm, mm.
    pub check_error_mm: f64,
}

impl Station {
    /// Read and validate a station file.
    pub fn load(path: &Path) -> Result<Self, StationError> {
        let meta =
            std::fs::metadata(path).map_err(|e| StationError::file(path, "", e.to_string()))?;
        if meta.len() > MAX_FILE_BYTES {
            return Err(StationError::file(
                path,
                "",
                format!(
                    "{} bytes: a station file is at most {MAX_FILE_BYTES}",
                    meta.len()
                ),
            ));
        }
        let text = std::fs::read_to_string(path)
            .map_err(|e| StationError::file(path, "", e.to_string()))?;
        Self::parse(&text, path)
    }

    /// Parse and validate station file text (`path` names it in errors).
    pub fn parse(text: &str, path: &Path) -> Result<Self, StationError> {
        let de = toml::Deserializer::parse(text)
            .map_err(|e| StationError::file(path, "", e.message().trim().to_string()))?;
        let station: Station = serde_path_to_error::deserialize(de).map_err(|e| {
            let key = e.path().to_string();
            let key = if key == "." { String::new() } else { key };
            StationError::file(path, &key, e.inner().message().trim().to_string())
        })?;
        station.validate(path)?;
        Ok(station)
    }

    /// Range checks and the fixture's rules (`docs/calibration.md`, "Production line").
    pub fn validate(&self, path: &Path) -> Result<(), StationError> {
        let bad = |key: &str, msg: String| Err(StationError::file(path, key, msg));
        let [h, v] = self.module.fov_deg;
        if !(h > 0.0 && h < 180.0 && v > 0.0 && v < 180.0) {
            return bad(
                "module.fov_deg",
                format!("[{h}, {v}]: each must be in (0, 180) degrees"),
            );
        }
        if let Some([_, 0]) = self.module.rows {
            return bad("module.rows", "the row count must be at least 1".into());
        }
        let max = self.exposure.max_us;
        if !(max.is_finite() && max > 0.0 && max <= 10_000.0) {
            return bad(
                "exposure.max_us",
                format!("{max}: must be in (0, 10000] µs (eye safety)"),
            );
        }
        self.validate_targets(path)?;
        self.validate_captures(path)?;
        self.validate_limits(path)
    }

    fn validate_targets(&self, path: &Path) -> Result<(), StationError> {
        let bad = |key: String, msg: String| Err(StationError::file(path, &key, msg));
        let mut targets = vec![("wall", &self.targets.wall), ("check", &self.targets.check)];
        match (&self.targets.absorber, self.line) {
            (Some(a), _) => targets.push(("absorber", a)),
            (None, Line::Phone) => {
                return bad(
                    "targets.absorber".into(),
                    "the phone line needs nothing in range for the crosstalk: add [targets.absorber]"
                        .into(),
                );
            }
            (None, Line::Module) => {}
        }
        for (name, t) in targets {
            let key = |k: &str| format!("targets.{name}.{k}");
            if !(t.distance_m.is_finite() && t.distance_m > 0.0 && t.distance_m <= 100.0) {
                return bad(
                    key("distance_m"),
                    format!("{}: must be in (0, 100] m", t.distance_m),
                );
            }
            if !(0.0..=1.0).contains(&t.reflectivity) {
                return bad(
                    key("reflectivity"),
                    format!("{}: must be in [0, 1]", t.reflectivity),
                );
            }
            if !(t.flatness_mm.is_finite() && t.flatness_mm >= 0.0) {
                return bad(
                    key("flatness_mm"),
                    format!("{}: must be ≥ 0", t.flatness_mm),
                );
            }
            if name != "absorber" {
                // a target less flat than half the check budget would eat it
                if t.flatness_mm > self.limits.check_error_mm / 2.0 {
                    return bad(
                        key("flatness_mm"),
                        format!(
                            "{} mm: at most half of limits.check_error_mm ({} mm)",
                            t.flatness_mm, self.limits.check_error_mm
                        ),
                    );
                }
                let cov = t.field_coverage(self.module.fov_deg);
                if cov.is_nan() || cov < 1.0 {
                    return bad(
                        key("size_m"),
                        format!(
                            "{:?} m covers {:.0} % of the {h}° × {v}° field at {d} m: the target must fill the field of view",
                            t.size_m,
                            cov * 100.0,
                            h = self.module.fov_deg[0],
                            v = self.module.fov_deg[1],
                            d = t.distance_m
                        ),
                    );
                }
            }
        }
        if (self.targets.check.distance_m - self.targets.wall.distance_m).abs() < 0.05 {
            return bad(
                "targets.check.distance_m".into(),
                "must differ from targets.wall.distance_m by at least 0.05 m (the check verifies the set at another distance)"
                    .into(),
            );
        }
        Ok(())
    }

    fn validate_captures(&self, path: &Path) -> Result<(), StationError> {
        let c = &self.captures;
        let mut steps = vec![
            ("dark", c.dark),
            ("wiggling", c.wiggling),
            ("fppn", c.fppn),
            ("check", c.check),
        ];
        match (c.crosstalk, self.line) {
            (Some(x), _) => steps.push(("crosstalk", x)),
            (None, Line::Phone) => {
                return Err(StationError::file(
                    path,
                    "captures.crosstalk",
                    "the phone line captures the cover-window crosstalk: add [captures.crosstalk]",
                ));
            }
            (None, Line::Module) => {}
        }
        for (name, s) in steps {
            let max = self.exposure.max_us;
            if !(s.exposure_us.is_finite() && s.exposure_us > 0.0 && s.exposure_us <= max) {
                return Err(StationError::file(
                    path,
                    &format!("captures.{name}.exposure_us"),
                    format!(
                        "{} µs: must be in (0, exposure.max_us = {max}] µs (eye safety: average more frames instead of exposing longer)",
                        s.exposure_us
                    ),
                ));
            }
            if !(1..=1024).contains(&s.frames) {
                return Err(StationError::file(
                    path,
                    &format!("captures.{name}.frames"),
                    format!("{}: must be 1..=1024", s.frames),
                ));
            }
        }
        Ok(())
    }

    fn validate_limits(&self, path: &Path) -> Result<(), StationError> {
        let l = &self.limits;
        let positive = [
            ("fpn_sigma_lsb", l.fpn_sigma_lsb),
            ("hot_pixel_lsb", l.hot_pixel_lsb),
            ("wiggling_p2p_mm", l.wiggling_p2p_mm),
            ("fppn_sigma_mm", l.fppn_sigma_mm),
            ("check_error_mm", l.check_error_mm),
            (
                "crosstalk_lsb_per_us",
                l.crosstalk_lsb_per_us.unwrap_or(1.0),
            ),
        ];
        for (k, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(StationError::file(
                    path,
                    &format!("limits.{k}"),
                    format!("{v}: must be > 0"),
                ));
            }
        }
        let [lo, hi] = l.amplitude_k;
        if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo < hi) {
            return Err(StationError::file(
                path,
                "limits.amplitude_k",
                format!("[{lo}, {hi}]: must be 0 ≤ min < max"),
            ));
        }
        if !(0.0..1.0).contains(&l.dead_pixel_fraction) {
            return Err(StationError::file(
                path,
                "limits.dead_pixel_fraction",
                format!("{}: must be in [0, 1)", l.dead_pixel_fraction),
            ));
        }
        if self.line == Line::Phone && l.crosstalk_lsb_per_us.is_none() {
            return Err(StationError::file(
                path,
                "limits.crosstalk_lsb_per_us",
                "the phone line checks the cover-window crosstalk: set its limit",
            ));
        }
        Ok(())
    }
}
