//! Calibration sets: `CALIB/calibration.toml` + one `.npy` array per part,
//! each with its SHA-256 recorded in the TOML. See `docs/calibration.md`.
//!
//! Parts and their dependencies (thesis order of application, 4.3.3; order of
//! extraction, 5.1.3): lens intrinsics → offset (FPN dark frame) → cover-window crosstalk →
//! wiggling LUTs (2- and 4-phase) → FPPN map. Wiggling and FPPN record the intrinsics they were
//! extracted through ("none": without a lens model) and the crosstalk subtracted before them;
//! wiggling and FPPN extracted without a crosstalk part (a module calibrated before it was built
//! in behind a cover window) stay valid when a crosstalk part is added later. Beside them the
//! amplitude scale of the `1/d²` law (`tofprox_core::radiometry`), which depends on nothing.
//! Each dependent part records the checksum of the parts it was extracted
//! with; loading refuses a set whose parts do not fit together, and
//! [`CalibrationSet::set_offset`] / [`CalibrationSet::set_crosstalk`] /
//! [`CalibrationSet::set_wiggling`] drop the parts that were derived from what they replace.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use ndarray::{Array1, Array2, Array3, Ix1, Ix2, Ix3};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use tofprox_core::calib::{FppnMap, OffsetCalibration, WigglingLut};
use tofprox_core::camera::{Intrinsics, RayGrid};
use tofprox_core::crosstalk::CrosstalkCalibration;
use tofprox_core::pipeline::Calibration;
use tofprox_core::radiometry::AmplitudeScale;
use tofprox_core::{Algorithm, SensorGeometry};

use crate::error::{
    ErrorKind, FormatError, check_format_header, geometry_invalid, invalid, parse_toml,
};
use crate::fsutil;

mod chain;
mod files;
mod part;
use crate::limits;
use crate::npy::{self, NpyArray, shape_str};
pub use chain::{ChainEntry, Dropped, PartState};
pub use part::{CalibPart, PartValue};
use part::{INTRINSICS_LEN, intrinsics_array, intrinsics_from_array};

/// `format` value of a calibration set.
pub const CALIBRATION_FORMAT: &str = "tofprox-calibration";
/// The calibration format version this crate reads and writes.
pub const CALIBRATION_VERSION: i64 = 1;
/// File name of the calibration header.
pub const CALIBRATION_TOML: &str = "calibration.toml";

/// Where a part came from.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PartSource {
    /// The recording directory it was extracted from (as given on the command line).
    pub recording: String,
    /// That recording's description.
    pub recording_description: Option<String>,
    /// Indices of the captures used.
    pub captures: Vec<usize>,
    /// Ground-truth distance of the capture used (wiggling, FPPN, amplitude).
    pub distance_m: Option<f64>,
    /// Reflectivity of the target of the capture used (amplitude); `None` when the capture did
    /// not say and [`tofprox_core::radiometry::DEFAULT_CALIBRATION_REFLECTIVITY`] was assumed.
    pub reflectivity: Option<f64>,
    /// Exposure per raw image of the capture used (amplitude), µs.
    pub exposure_us: Option<f64>,
    /// When it was extracted (RFC 3339, UTC).
    pub created: String,
    /// Program and version that extracted it.
    pub tool: String,
}

/// A loaded (or being built) calibration set.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationSet {
    /// The parts present, keyed by which part they are (the lens intrinsics in full-array
    /// pixel coordinates and stored as float32; the offset; the crosstalk, extracted after the
    /// offset; the 2- and 4-phase wiggling tables; the FPPN maps, each extracted after its
    /// algorithm's table, the 4-phase one also applied to 2-phase when the 2-phase one is
    /// absent; the amplitude scale of the `1/d²` law). Set through the `set_*` methods, which
    /// check a part and drop what was derived from the part it replaces; read through
    /// [`CalibrationSet::get`] or the typed accessors.
    parts: BTreeMap<CalibPart, PartValue>,
    /// What the set is valid for: the sensor setup and window it was extracted on (the
    /// `[valid_for]` table). Applying it to anything else is refused.
    pub validity: SensorGeometry,
    /// Provenance of each present part.
    pub sources: BTreeMap<CalibPart, PartSource>,
    /// Free text.
    pub description: Option<String>,
    /// The directory it was loaded from, if any.
    pub dir: Option<PathBuf>,
    deps: BTreeMap<CalibPart, Deps>,
    /// Parts dropped because a part they depend on changed, not extracted again yet
    /// (`[dropped.<part>]`, [`chain`]).
    dropped: BTreeMap<CalibPart, Dropped>,
}

/// Checksums of the parts a part was extracted with ("none" when absent).
#[derive(Debug, Clone, PartialEq, Default)]
struct Deps {
    offset: Option<String>,
    wiggling: Option<String>,
    intrinsics: Option<String>,
    crosstalk: Option<String>,
}

const NONE: &str = "none";

fn sha256_hex(bytes: &[u8]) -> String {
    let d = Sha256::digest(bytes);
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// Current UTC time as RFC 3339 (`2026-11-21T05:30:00Z`).
pub fn now_rfc3339() -> String {
    humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string()
}

/// Format seconds since the Unix epoch as RFC 3339 UTC.
pub fn rfc3339_from_unix(secs: u64) -> String {
    let t = std::time::UNIX_EPOCH + std::time::Duration::from_secs(secs);
    humantime::format_rfc3339_seconds(t).to_string()
}

impl CalibrationSet {
    /// An empty set for data of `sensor`.
    pub fn new(sensor: &SensorGeometry) -> Self {
        CalibrationSet {
            parts: BTreeMap::new(),
            validity: *sensor,
            sources: BTreeMap::new(),
            description: None,
            dir: None,
            deps: BTreeMap::new(),
            dropped: BTreeMap::new(),
        }
    }

    /// A part's value, if the set holds it.
    pub fn get(&self, part: CalibPart) -> Option<&PartValue> {
        self.parts.get(&part)
    }

    /// The lens intrinsics.
    pub fn intrinsics(&self) -> Option<&Intrinsics> {
        match self.get(CalibPart::Intrinsics) {
            Some(PartValue::Intrinsics(k)) => Some(k),
            _ => None,
        }
    }

    /// The per-pixel dark frame.
    pub fn offset(&self) -> Option<&OffsetCalibration> {
        match self.get(CalibPart::Offset) {
            Some(PartValue::Offset(o)) => Some(o),
            _ => None,
        }
    }

    /// The cover-window crosstalk.
    pub fn crosstalk(&self) -> Option<&CrosstalkCalibration> {
        match self.get(CalibPart::Crosstalk) {
            Some(PartValue::Crosstalk(x)) => Some(x),
            _ => None,
        }
    }

    /// The amplitude scale of the `1/d²` law.
    pub fn amplitude(&self) -> Option<&AmplitudeScale> {
        match self.get(CalibPart::Amplitude) {
            Some(PartValue::Amplitude(a)) => Some(a),
            _ => None,
        }
    }

    /// The wiggling LUT for an algorithm.
    pub fn wiggling(&self, algorithm: Algorithm) -> Option<&WigglingLut> {
        match self.get(CalibPart::wiggling(algorithm)) {
            Some(PartValue::Wiggling(w)) => Some(w),
            _ => None,
        }
    }

    /// The FPPN map extracted for an algorithm (no fallback: [`CalibrationSet::fppn_for`]).
    pub fn fppn(&self, algorithm: Algorithm) -> Option<&FppnMap> {
        match self.get(CalibPart::fppn(algorithm)) {
            Some(PartValue::Fppn(f)) => Some(f),
            _ => None,
        }
    }

    /// The FPPN map applied for an algorithm (2-phase falls back to the 4-phase map).
    pub fn fppn_for(&self, algorithm: Algorithm) -> Option<&FppnMap> {
        match algorithm {
            Algorithm::TwoPhase => self
                .fppn(Algorithm::TwoPhase)
                .or(self.fppn(Algorithm::FourPhase)),
            Algorithm::FourPhase => self.fppn(Algorithm::FourPhase),
        }
    }

    /// Which parts are present, in order of application.
    pub fn parts(&self) -> Vec<CalibPart> {
        self.parts.keys().copied().collect()
    }

    /// Whether a part is present.
    pub fn has(&self, part: CalibPart) -> bool {
        self.parts.contains_key(&part)
    }

    fn part_bytes(&self, part: CalibPart) -> Option<Vec<u8>> {
        self.get(part).map(PartValue::npy_bytes)
    }

    /// Hold `value` as `part` (the caller has checked it).
    fn insert(&mut self, part: CalibPart, value: PartValue) {
        self.parts.insert(part, value);
    }

    /// SHA-256 (hex) of a part's array file as it would be saved.
    pub fn checksum(&self, part: CalibPart) -> Option<String> {
        self.part_bytes(part).map(|b| sha256_hex(&b))
    }

    fn checksum_or_none(&self, part: CalibPart) -> String {
        self.checksum(part).unwrap_or_else(|| NONE.to_string())
    }

    fn remove(&mut self, part: CalibPart) {
        self.parts.remove(&part);
        self.sources.remove(&part);
        self.deps.remove(&part);
    }

    /// Parts whose recorded dependencies no longer match the set.
    pub fn stale_parts(&self) -> Vec<CalibPart> {
        let mut out = Vec::new();
        let off = self.checksum_or_none(CalibPart::Offset);
        let lens = self.checksum_or_none(CalibPart::Intrinsics);
        let xt = self.checksum_or_none(CalibPart::Crosstalk);
        for part in [
            CalibPart::Crosstalk,
            CalibPart::Wiggling2Phase,
            CalibPart::Wiggling4Phase,
            CalibPart::Fppn,
            CalibPart::Fppn2Phase,
        ] {
            if !self.has(part) {
                continue;
            }
            let Some(d) = self.deps.get(&part) else {
                continue;
            };
            if d.offset.as_deref().is_some_and(|o| o != off)
                || d.intrinsics.as_deref().is_some_and(|k| k != lens)
            {
                out.push(part);
                continue;
            }
            // extracted with a crosstalk subtracted that is no longer the set's ("none":
            // extracted without one, e.g. before the module went behind a window: still valid)
            if d.crosstalk.as_deref().is_some_and(|x| x != NONE && x != xt) {
                out.push(part);
                continue;
            }
            if let (CalibPart::Fppn | CalibPart::Fppn2Phase, Some(alg)) = (part, part.algorithm()) {
                let w = self.checksum_or_none(CalibPart::wiggling(alg));
                if d.wiggling.as_deref().is_some_and(|x| x != w) {
                    out.push(part);
                }
            }
        }
        out
    }

    /// Remove parts that were extracted with a different version of the
    /// parts they depend on; returns what was dropped.
    fn drop_stale(&mut self) -> Vec<CalibPart> {
        let mut dropped = Vec::new();
        loop {
            let stale = self.stale_parts();
            if stale.is_empty() {
                return dropped;
            }
            for p in stale {
                self.remove(p);
                dropped.push(p);
            }
        }
    }

    /// Set (or replace) the lens intrinsics (stored as float32, so the values are rounded to
    /// float32 here: what is extracted through them is what is saved). Returns the parts dropped
    /// because they were extracted through the previous intrinsics.
    pub fn set_intrinsics(
        &mut self,
        intrinsics: Intrinsics,
        source: PartSource,
    ) -> Result<Vec<CalibPart>, FormatError> {
        let k = intrinsics_from_array(&intrinsics_array(&intrinsics));
        k.validate()
            .map_err(|e| invalid(e.to_string()).key(CalibPart::Intrinsics.name()))?;
        self.rays_of(&k)
            .map_err(|e| invalid(e.to_string()).key(CalibPart::Intrinsics.name()))?;
        self.insert(CalibPart::Intrinsics, PartValue::Intrinsics(k));
        Ok(self.record_part(CalibPart::Intrinsics, source, Deps::default()))
    }

    /// The unit rays of the set's window through its intrinsics (`None` without intrinsics).
    pub fn rays(&self) -> Option<Result<RayGrid, FormatError>> {
        self.intrinsics().map(|k| {
            self.rays_of(k)
                .map_err(|e| invalid(e.to_string()).key(CalibPart::Intrinsics.name()))
        })
    }

    fn rays_of(&self, k: &Intrinsics) -> Result<RayGrid, tofprox_core::CoreError> {
        let v = &self.validity;
        k.rays(v.roi_origin[0], v.roi_origin[1], v.rows, v.cols)
    }

    /// Set (or replace) the offset. Returns the parts dropped because they
    /// were extracted with the previous offset.
    pub fn set_offset(
        &mut self,
        offset: OffsetCalibration,
        source: PartSource,
    ) -> Result<Vec<CalibPart>, FormatError> {
        self.check_map(&offset.dark_lsb, "dark level", CalibPart::Offset.name())?;
        self.insert(CalibPart::Offset, PartValue::Offset(offset));
        Ok(self.record_part(CalibPart::Offset, source, Deps::default()))
    }

    /// Set (or replace) the wiggling LUT of `lut.algorithm`, recording the
    /// current offset as its dependency. Returns the parts dropped.
    pub fn set_wiggling(
        &mut self,
        lut: WigglingLut,
        source: PartSource,
    ) -> Result<Vec<CalibPart>, FormatError> {
        let part = CalibPart::wiggling(lut.algorithm);
        lut.validate()
            .map_err(|e| invalid(e.to_string()).key(part.name()))?;
        let deps = Deps {
            offset: Some(self.checksum_or_none(CalibPart::Offset)),
            wiggling: None,
            intrinsics: Some(self.checksum_or_none(CalibPart::Intrinsics)),
            crosstalk: Some(self.checksum_or_none(CalibPart::Crosstalk)),
        };
        self.insert(part, PartValue::Wiggling(lut));
        Ok(self.record_part(part, source, deps))
    }

    /// Set (or replace) the 4-phase FPPN map, recording the current offset
    /// and 4-phase wiggling LUT as its dependencies.
    pub fn set_fppn(
        &mut self,
        fppn: FppnMap,
        source: PartSource,
    ) -> Result<Vec<CalibPart>, FormatError> {
        self.set_fppn_for(Algorithm::FourPhase, fppn, source)
    }

    /// Set (or replace) the FPPN map of `algorithm`, recording the current
    /// offset and that algorithm's wiggling LUT as its dependencies.
    pub fn set_fppn_for(
        &mut self,
        algorithm: Algorithm,
        fppn: FppnMap,
        source: PartSource,
    ) -> Result<Vec<CalibPart>, FormatError> {
        let part = CalibPart::fppn(algorithm);
        self.check_map(&fppn.phase_offset_rad, "phase offset", part.name())?;
        let deps = Deps {
            offset: Some(self.checksum_or_none(CalibPart::Offset)),
            wiggling: Some(self.checksum_or_none(CalibPart::wiggling(algorithm))),
            intrinsics: Some(self.checksum_or_none(CalibPart::Intrinsics)),
            crosstalk: Some(self.checksum_or_none(CalibPart::Crosstalk)),
        };
        self.insert(part, PartValue::Fppn(fppn));
        Ok(self.record_part(part, source, deps))
    }

    /// Set (or replace) the amplitude scale. It depends on no other part (the N-phase
    /// amplitude is offset-free). Returns the parts dropped (none).
    pub fn set_amplitude(
        &mut self,
        scale: AmplitudeScale,
        source: PartSource,
    ) -> Result<Vec<CalibPart>, FormatError> {
        let key = CalibPart::Amplitude.name();
        self.check_map(&scale.lsb_m2_per_us, "amplitude scale", key)?;
        if let Some(problem) = amplitude_scale_problem(&scale.lsb_m2_per_us, &self.validity) {
            return Err(invalid(problem).key(key));
        }
        self.insert(CalibPart::Amplitude, PartValue::Amplitude(scale));
        Ok(self.record_part(CalibPart::Amplitude, source, Deps::default()))
    }

    /// Set (or replace) the cover-window crosstalk (extracted with the current
    /// offset, recorded as its dependency). Returns the parts dropped because
    /// they were extracted with a previous crosstalk subtracted.
    pub fn set_crosstalk(
        &mut self,
        crosstalk: CrosstalkCalibration,
        source: PartSource,
    ) -> Result<Vec<CalibPart>, FormatError> {
        let key = CalibPart::Crosstalk.name();
        crosstalk
            .validate(self.validity.rows, self.validity.cols)
            .map_err(|e| {
                invalid(format!(
                    "the set is for a {}×{} window: {e}",
                    self.validity.rows, self.validity.cols
                ))
                .key(key)
            })?;
        let deps = Deps {
            offset: Some(self.checksum_or_none(CalibPart::Offset)),
            ..Deps::default()
        };
        self.insert(CalibPart::Crosstalk, PartValue::Crosstalk(crosstalk));
        Ok(self.record_part(CalibPart::Crosstalk, source, deps))
    }

    /// Record where `part` came from and what it was computed with, then
    /// drop the parts that no longer match their dependencies.
    fn record_part(&mut self, part: CalibPart, source: PartSource, deps: Deps) -> Vec<CalibPart> {
        self.sources.insert(part, source);
        self.deps.insert(part, deps);
        let before = self.sources.clone();
        let dropped = self.drop_stale();
        self.remember_dropped(part, &dropped, &before);
        dropped
    }

    /// A per-pixel map must fit the window and be finite everywhere; `what`
    /// names its values in the error, `key` the part.
    fn check_map(&self, a: &Array2<f32>, what: &str, key: &str) -> Result<(), FormatError> {
        self.check_map_shape(a, key)?;
        if let Some((r, c)) = first_non_finite(a) {
            return Err(invalid(format!("{what} at (row {r}, col {c}) is not finite")).key(key));
        }
        Ok(())
    }

    fn check_map_shape(&self, a: &Array2<f32>, key: &str) -> Result<(), FormatError> {
        let want = (self.validity.rows, self.validity.cols);
        if a.dim() != want {
            return Err(invalid(format!(
                "map is {}×{} but the set is for a {}×{} window",
                a.nrows(),
                a.ncols(),
                want.0,
                want.1
            ))
            .key(key.to_string()));
        }
        Ok(())
    }

    /// Refuse to apply this set to data of another sensor setup.
    pub fn check_compatible(&self, sensor: &SensorGeometry) -> Result<(), FormatError> {
        let v = &self.validity;
        let mut problems = Vec::new();
        let rel =
            (v.modulation_hz - sensor.modulation_hz).abs() / sensor.modulation_hz.abs().max(1.0);
        if rel.is_nan() || rel > 1e-9 {
            problems.push(format!(
                "modulation_hz: calibration is for {} Hz, the data is {} Hz",
                v.modulation_hz, sensor.modulation_hz
            ));
        }
        if v.adc_bits != sensor.adc_bits {
            problems.push(format!(
                "adc_bits: calibration is for {} bit, the data is {} bit",
                v.adc_bits, sensor.adc_bits
            ));
        }
        if (v.rows, v.cols) != (sensor.rows, sensor.cols) {
            problems.push(format!(
                "window size: calibration is for {}×{} pixels, the data is {}×{}",
                v.rows, v.cols, sensor.rows, sensor.cols
            ));
        }
        if v.roi_origin != sensor.roi_origin {
            problems.push(format!(
                "roi_origin: calibration is for a window at {:?}, the data's window is at {:?}",
                v.roi_origin, sensor.roi_origin
            ));
        }
        if (v.full_rows, v.full_cols) != (sensor.full_rows, sensor.full_cols) {
            problems.push(format!(
                "full array: calibration is for {}×{}, the data is from a {}×{} array",
                v.full_rows, v.full_cols, sensor.full_rows, sensor.full_cols
            ));
        }
        if problems.is_empty() {
            return Ok(());
        }
        let mut e = FormatError::new(
            ErrorKind::Incompatible,
            format!("calibration does not fit the data: {}", problems.join("; ")),
        )
        .key("valid_for");
        if let Some(d) = &self.dir {
            e = e.at(&d.join(CALIBRATION_TOML));
        }
        Err(e)
    }

    /// The calibration the pipeline applies for `algorithm`.
    pub fn to_pipeline_calibration(&self, algorithm: Algorithm) -> Calibration {
        Calibration {
            offset: self.offset().cloned(),
            wiggling: self.wiggling(algorithm).cloned(),
            fppn: self.fppn_for(algorithm).cloned(),
            crosstalk: self.crosstalk().cloned(),
        }
    }
}

/// Why an amplitude scale `K` (LSB·m²/µs, `A = K·ρ·t/d²`, thesis 2.2.1) is outside its
/// physical range, if it is (issue 12 item 7): `K ≥ 0`, and a white target (ρ = 1) at 1 m
/// with a 1 µs exposure reaches at most one full-scale code, `K ≤ max_code·1 m²/1 µs`. A
/// larger `K` would saturate every pixel at every working distance with any practical
/// exposure (the shipped modules measure K ≈ 0.1, five orders of magnitude below).
fn amplitude_scale_problem(a: &Array2<f32>, sensor: &SensorGeometry) -> Option<String> {
    let max = sensor.max_code() as f32;
    let (i, v) = a
        .iter()
        .enumerate()
        .find(|(_, v)| !(0.0..=max).contains(*v))?;
    Some(if *v < 0.0 {
        format!("amplitude scale {v} (element {i}) is negative")
    } else {
        format!(
            "amplitude scale {v} LSB·m²/µs (element {i}) is beyond its physical range: a white target at 1 m would exceed full scale ({max} LSB) within 1 µs"
        )
    })
}

fn first_non_finite(a: &Array2<f32>) -> Option<(usize, usize)> {
    a.indexed_iter()
        .find(|(_, v)| !v.is_finite())
        .map(|(i, _)| i)
}

#[cfg(test)]
mod tests;
