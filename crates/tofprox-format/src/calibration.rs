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
use std::fmt;
use std::fs;
use std::path::{Path, PathBuf};

use ndarray::{Array1, Array2, Array3, Ix1, Ix2, Ix3};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use tofprox_core::calib::{FppnMap, OffsetCalibration, WigglingLut};
use tofprox_core::camera::{Distortion, Intrinsics, RayGrid};
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
use crate::limits;
use crate::npy::{self, NpyArray, shape_str};
pub use chain::{ChainEntry, Dropped, PartState};

/// `format` value of a calibration set.
pub const CALIBRATION_FORMAT: &str = "tofprox-calibration";
/// The calibration format version this crate reads and writes.
pub const CALIBRATION_VERSION: i64 = 1;
/// File name of the calibration header.
pub const CALIBRATION_TOML: &str = "calibration.toml";

/// One part of a calibration set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum CalibPart {
    /// Lens intrinsics and distortion, `[fx, fy, cx, cy, k1, k2, p1, p2, k3]` (OpenCV order).
    Intrinsics,
    /// Per-pixel dark frame (FPN).
    Offset,
    /// Cover-window crosstalk per raw image (0°, 90°, 180°, 270°), LSB per µs.
    Crosstalk,
    /// Wiggling LUT for 2-phase evaluation.
    Wiggling2Phase,
    /// Wiggling LUT for 4-phase evaluation.
    Wiggling4Phase,
    /// Per-pixel phase offsets (FPPN) for 4-phase evaluation (absolute w.r.t. the 4-phase LUT).
    Fppn,
    /// Per-pixel phase offsets (FPPN) for 2-phase evaluation (absolute w.r.t. the 2-phase LUT).
    Fppn2Phase,
    /// Per-pixel amplitude scale `K` of `A = K·ρ·t/d²` (thesis 2.2.1), LSB·m²/µs.
    Amplitude,
}

impl CalibPart {
    /// All parts, in order of application.
    pub const ALL: [CalibPart; 8] = [
        CalibPart::Intrinsics,
        CalibPart::Offset,
        CalibPart::Crosstalk,
        CalibPart::Wiggling2Phase,
        CalibPart::Wiggling4Phase,
        CalibPart::Fppn,
        CalibPart::Fppn2Phase,
        CalibPart::Amplitude,
    ];
    /// The table name in `calibration.toml` (also the array's file stem).
    pub fn name(self) -> &'static str {
        match self {
            CalibPart::Intrinsics => "intrinsics",
            CalibPart::Offset => "offset",
            CalibPart::Crosstalk => "crosstalk",
            CalibPart::Wiggling2Phase => "wiggling_2phase",
            CalibPart::Wiggling4Phase => "wiggling_4phase",
            CalibPart::Fppn => "fppn",
            CalibPart::Fppn2Phase => "fppn_2phase",
            CalibPart::Amplitude => "amplitude",
        }
    }
    /// The array file name.
    pub fn file_name(self) -> String {
        format!("{}.npy", self.name())
    }
    /// The wiggling part for an algorithm.
    pub fn wiggling(algorithm: Algorithm) -> CalibPart {
        match algorithm {
            Algorithm::TwoPhase => CalibPart::Wiggling2Phase,
            Algorithm::FourPhase => CalibPart::Wiggling4Phase,
        }
    }
    /// The FPPN part for an algorithm.
    pub fn fppn(algorithm: Algorithm) -> CalibPart {
        match algorithm {
            Algorithm::TwoPhase => CalibPart::Fppn2Phase,
            Algorithm::FourPhase => CalibPart::Fppn,
        }
    }
    /// The algorithm a wiggling or FPPN part belongs to.
    pub fn algorithm(self) -> Option<Algorithm> {
        match self {
            CalibPart::Intrinsics
            | CalibPart::Offset
            | CalibPart::Amplitude
            | CalibPart::Crosstalk => None,
            CalibPart::Wiggling2Phase | CalibPart::Fppn2Phase => Some(Algorithm::TwoPhase),
            CalibPart::Wiggling4Phase | CalibPart::Fppn => Some(Algorithm::FourPhase),
        }
    }

    /// A phase correction (a wiggling table, an FPPN map): within one period, and extracted
    /// through the lens, so it records the lens's checksum where the set holds one.
    fn phase_correction(self) -> bool {
        self.algorithm().is_some()
    }
}

impl fmt::Display for CalibPart {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

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
    /// Lens intrinsics and distortion (full-array pixel coordinates), stored as float32.
    pub intrinsics: Option<Intrinsics>,
    /// Per-pixel dark frame.
    pub offset: Option<OffsetCalibration>,
    /// Cover-window crosstalk (extracted after the offset).
    pub crosstalk: Option<CrosstalkCalibration>,
    /// 2-phase wiggling LUT.
    pub wiggling_2phase: Option<WigglingLut>,
    /// 4-phase wiggling LUT.
    pub wiggling_4phase: Option<WigglingLut>,
    /// FPPN map for 4-phase evaluation (extracted after the 4-phase wiggling
    /// LUT; also applied to 2-phase when `fppn_2phase` is absent).
    pub fppn: Option<FppnMap>,
    /// FPPN map for 2-phase evaluation (extracted after the 2-phase wiggling LUT).
    pub fppn_2phase: Option<FppnMap>,
    /// Amplitude scale of the `1/d²` law (from the correlation capture).
    pub amplitude: Option<AmplitudeScale>,
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
            intrinsics: None,
            offset: None,
            crosstalk: None,
            wiggling_2phase: None,
            wiggling_4phase: None,
            fppn: None,
            fppn_2phase: None,
            amplitude: None,
            validity: *sensor,
            sources: BTreeMap::new(),
            description: None,
            dir: None,
            deps: BTreeMap::new(),
            dropped: BTreeMap::new(),
        }
    }

    /// The wiggling LUT for an algorithm.
    pub fn wiggling(&self, algorithm: Algorithm) -> Option<&WigglingLut> {
        match algorithm {
            Algorithm::TwoPhase => self.wiggling_2phase.as_ref(),
            Algorithm::FourPhase => self.wiggling_4phase.as_ref(),
        }
    }

    /// The FPPN map for an algorithm (2-phase falls back to the 4-phase map).
    pub fn fppn_for(&self, algorithm: Algorithm) -> Option<&FppnMap> {
        match algorithm {
            Algorithm::TwoPhase => self.fppn_2phase.as_ref().or(self.fppn.as_ref()),
            Algorithm::FourPhase => self.fppn.as_ref(),
        }
    }

    /// Which parts are present.
    pub fn parts(&self) -> Vec<CalibPart> {
        CalibPart::ALL
            .into_iter()
            .filter(|p| self.has(*p))
            .collect()
    }

    /// Whether a part is present.
    pub fn has(&self, part: CalibPart) -> bool {
        match part {
            CalibPart::Intrinsics => self.intrinsics.is_some(),
            CalibPart::Offset => self.offset.is_some(),
            CalibPart::Crosstalk => self.crosstalk.is_some(),
            CalibPart::Wiggling2Phase => self.wiggling_2phase.is_some(),
            CalibPart::Wiggling4Phase => self.wiggling_4phase.is_some(),
            CalibPart::Fppn => self.fppn.is_some(),
            CalibPart::Fppn2Phase => self.fppn_2phase.is_some(),
            CalibPart::Amplitude => self.amplitude.is_some(),
        }
    }

    fn part_bytes(&self, part: CalibPart) -> Option<Vec<u8>> {
        match part {
            CalibPart::Intrinsics => self
                .intrinsics
                .as_ref()
                .map(|k| npy::encode_f32(&intrinsics_array(k))),
            CalibPart::Offset => self.offset.as_ref().map(|o| npy::encode_f32(&o.dark_lsb)),
            CalibPart::Crosstalk => self
                .crosstalk
                .as_ref()
                .map(|x| npy::encode_f32(&x.lsb_per_us)),
            CalibPart::Wiggling2Phase => self
                .wiggling_2phase
                .as_ref()
                .map(|w| npy::encode_f32(&w.correction_rad)),
            CalibPart::Wiggling4Phase => self
                .wiggling_4phase
                .as_ref()
                .map(|w| npy::encode_f32(&w.correction_rad)),
            CalibPart::Fppn => self
                .fppn
                .as_ref()
                .map(|f| npy::encode_f32(&f.phase_offset_rad)),
            CalibPart::Fppn2Phase => self
                .fppn_2phase
                .as_ref()
                .map(|f| npy::encode_f32(&f.phase_offset_rad)),
            CalibPart::Amplitude => self
                .amplitude
                .as_ref()
                .map(|a| npy::encode_f32(&a.lsb_m2_per_us)),
        }
    }

    /// SHA-256 (hex) of a part's array file as it would be saved.
    pub fn checksum(&self, part: CalibPart) -> Option<String> {
        self.part_bytes(part).map(|b| sha256_hex(&b))
    }

    fn checksum_or_none(&self, part: CalibPart) -> String {
        self.checksum(part).unwrap_or_else(|| NONE.to_string())
    }

    fn remove(&mut self, part: CalibPart) {
        match part {
            CalibPart::Intrinsics => self.intrinsics = None,
            CalibPart::Offset => self.offset = None,
            CalibPart::Crosstalk => self.crosstalk = None,
            CalibPart::Wiggling2Phase => self.wiggling_2phase = None,
            CalibPart::Wiggling4Phase => self.wiggling_4phase = None,
            CalibPart::Fppn => self.fppn = None,
            CalibPart::Fppn2Phase => self.fppn_2phase = None,
            CalibPart::Amplitude => self.amplitude = None,
        }
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
        self.intrinsics = Some(k);
        Ok(self.record_part(CalibPart::Intrinsics, source, Deps::default()))
    }

    /// The unit rays of the set's window through its intrinsics (`None` without intrinsics).
    pub fn rays(&self) -> Option<Result<RayGrid, FormatError>> {
        self.intrinsics.as_ref().map(|k| {
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
        self.offset = Some(offset);
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
        match lut.algorithm {
            Algorithm::TwoPhase => self.wiggling_2phase = Some(lut),
            Algorithm::FourPhase => self.wiggling_4phase = Some(lut),
        }
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
        match algorithm {
            Algorithm::TwoPhase => self.fppn_2phase = Some(fppn),
            Algorithm::FourPhase => self.fppn = Some(fppn),
        }
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
        self.amplitude = Some(scale);
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
        self.crosstalk = Some(crosstalk);
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
            offset: self.offset.clone(),
            wiggling: self.wiggling(algorithm).cloned(),
            fppn: self.fppn_for(algorithm).cloned(),
            crosstalk: self.crosstalk.clone(),
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

/// Number of values of the intrinsics array.
const INTRINSICS_LEN: usize = 9;

/// `[fx, fy, cx, cy, k1, k2, p1, p2, k3]`: OpenCV's camera-matrix entries, then its
/// `distCoeffs` order.
fn intrinsics_array(k: &Intrinsics) -> Array1<f32> {
    let d = &k.distortion;
    Array1::from_iter(
        [
            k.fx_px, k.fy_px, k.cx_px, k.cy_px, d.k1, d.k2, d.p1, d.p2, d.k3,
        ]
        .map(|v| v as f32),
    )
}

fn intrinsics_from_array(a: &Array1<f32>) -> Intrinsics {
    let v = |i: usize| a.get(i).copied().map_or(f64::NAN, f64::from);
    Intrinsics {
        fx_px: v(0),
        fy_px: v(1),
        cx_px: v(2),
        cy_px: v(3),
        distortion: Distortion {
            k1: v(4),
            k2: v(5),
            p1: v(6),
            p2: v(7),
            k3: v(8),
        },
    }
}

fn first_non_finite(a: &Array2<f32>) -> Option<(usize, usize)> {
    a.indexed_iter()
        .find(|(_, v)| !v.is_finite())
        .map(|(i, _)| i)
}

#[cfg(test)]
mod tests;
