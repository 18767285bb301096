//! Recording format (version 3; versions 1 and 2 still read): `REC/recording.toml` +
//! `REC/frames/NNNNNN.npy`. A recording is of one [`RecordingKind`]: raw phase
//! images (this module) or depth images ([`crate::depth`]). See
//! `docs/recording-format.md` for the specification and validation rules.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Component, Path, PathBuf};

use ndarray::{Array3, ArrayBase, Data, Ix3};
use serde::{Deserialize, Serialize};

use tofprox_core::phasor::{PhaseConvention, Quadrature, ShiftedSignal, same_shift_deg};
use tofprox_core::{Algorithm, SensorGeometry};

use crate::error::{
    ErrorKind, FormatError, check_format_header, geometry_invalid, invalid, parse_toml,
};
use crate::fsutil;
use crate::limits;
use crate::npy::{self, Dtype, NpyArray, shape_str};

/// `format` value of a recording.
pub const RECORDING_FORMAT: &str = "tofprox-recording";
/// The recording format version this crate writes.
pub const RECORDING_VERSION: i64 = 3;
/// The recording format versions this crate reads, oldest first. Version 2 added `kind`
/// ([`RecordingKind`]); a version 1 file is a raw recording. Version 3 added a capture's
/// `second_frequency` images ([`SecondFrequencyMeta`]).
pub const RECORDING_VERSIONS_READ: [i64; 3] = [1, 2, RECORDING_VERSION];

/// The first version with `[capture.second_frequency]`.
const SECOND_FREQUENCY_VERSION: i64 = 3;

/// What a recording holds (`kind`, format version 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RecordingKind {
    /// Raw phase images (ADC codes) with the sensor setup: [`Recording`].
    Raw,
    /// Depth images in mm (and amplitudes) as `tofproxd` publishes them:
    /// [`crate::DepthRecording`].
    Depth,
}

impl RecordingKind {
    /// The `kind` value in `recording.toml`.
    pub fn name(self) -> &'static str {
        match self {
            RecordingKind::Raw => "raw",
            RecordingKind::Depth => "depth",
        }
    }
}

/// The `kind` key, read before the rest of the file (other keys ignored here).
#[derive(Deserialize)]
struct KindProbe {
    kind: Option<toml::Value>,
}

/// Check `format` and `version` ([`RECORDING_VERSIONS_READ`]) and read `kind`: the one place
/// that knows which version brought which key.
pub(crate) fn read_header(path: &Path, text: &str) -> Result<RecordingKind, FormatError> {
    let version = check_format_header(
        path,
        text,
        RECORDING_FORMAT,
        &RECORDING_VERSIONS_READ,
        "recording",
        "recording",
    )?;
    let probe: KindProbe = parse_toml(path, text)?;
    match (version, probe.kind) {
        (1, None) => Ok(RecordingKind::Raw),
        (1, Some(_)) => Err(FormatError::new(
            ErrorKind::UnknownKey,
            "not defined in recording format version 1 (it came with version 2: write version = 2)",
        )
        .at(path)
        .key("kind")),
        (_, None) => Err(FormatError::new(
            ErrorKind::MissingKey,
            "missing; a version 2 recording says kind = \"raw\" (phase images) or kind = \"depth\" (depth images)",
        )
        .at(path)
        .key("kind")),
        (_, Some(toml::Value::String(k))) if k == "raw" => Ok(RecordingKind::Raw),
        (_, Some(toml::Value::String(k))) if k == "depth" => Ok(RecordingKind::Depth),
        (_, Some(v)) => Err(invalid(format!(
            "{v} is not a recording kind (\"raw\" or \"depth\")"
        ))
        .at(path)
        .key("kind")),
    }
}

/// Which kind of recording `dir` holds (reads only `recording.toml`, bounded).
pub fn recording_kind(dir: &Path) -> Result<RecordingKind, FormatError> {
    let path = dir.join(RECORDING_TOML);
    let text = limits::read_text_bounded(&path, limits::MAX_TOML_BYTES)?;
    read_header(&path, &text)
}

/// The error for a recording of another kind than the reader's.
pub(crate) fn wrong_kind(path: &Path, found: RecordingKind) -> FormatError {
    let message = match found {
        RecordingKind::Depth => {
            "\"depth\": a depth recording (depth in mm as tofproxd publishes it), not raw phase images: it cannot be calibrated, processed or fitted; `tofprox info` summarises it"
        }
        RecordingKind::Raw => "\"raw\": a recording of raw phase images, not of depth images",
    };
    FormatError::new(ErrorKind::Unsupported, message)
        .at(path)
        .key("kind")
}
/// File name of the recording header.
pub const RECORDING_TOML: &str = "recording.toml";
/// Sub-directory the writer puts frame files in.
pub const FRAMES_DIR: &str = "frames";

/// `[capture.conditions]` keys that are bookkeeping, not physics: which repeat,
/// which capture of a series, when. They are kept in the file but are never a
/// condition of the measurement (captures differing only in them are repeats).
pub const BOOKKEEPING_CONDITIONS: &[&str] = &[
    "repeat",
    "repeat_index",
    "capture_index",
    "sequence",
    "run_index",
];

/// True for a bookkeeping key of `[capture.conditions]`: one of
/// [`BOOKKEEPING_CONDITIONS`] or any key starting with `timestamp`.
pub fn is_bookkeeping_condition(key: &str) -> bool {
    BOOKKEEPING_CONDITIONS.contains(&key) || key.starts_with("timestamp")
}

/// What one capture is (everything of a `[[capture]]` table except `frames`).
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureSpec {
    /// Phase shift of each raw image in degrees, in acquisition order.
    pub phases_deg: Vec<f64>,
    /// Exposure (integration) time.
    pub exposure_us: f64,
    /// false: illumination off (dark capture).
    pub illumination: bool,
    /// Acquisitions averaged into this capture (1 for a single one).
    pub averaged: u32,
    /// Optional acquisition time.
    pub timestamp_ns: Option<u64>,
    /// Numeric ground truth and environment (`distance_m`, `reflectivity`,
    /// `ambient_klux`, `temperature_c`, any other).
    pub conditions: BTreeMap<String, f64>,
}

/// One `[[capture]]` table (numbers may be written as TOML integers or floats).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaptureMeta {
    /// Path of the `.npy` file relative to the recording directory.
    pub frames: String,
    /// Phase shift of each raw image in degrees, in acquisition order.
    pub phases_deg: Vec<f64>,
    /// Exposure (integration) time.
    pub exposure_us: f64,
    /// false: illumination off (dark capture).
    pub illumination: bool,
    /// Acquisitions averaged into this capture (1 for a single one).
    pub averaged: u32,
    /// Optional acquisition time.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timestamp_ns: Option<u64>,
    /// Numeric ground truth and environment.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub conditions: BTreeMap<String, f64>,
    /// Raw images the device took in the same cycle at a second modulation frequency
    /// (version 3), with this capture's exposure, illumination and averaging.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub second_frequency: Option<SecondFrequencyMeta>,
}

/// A capture's `[capture.second_frequency]` table (format version 3): the same scene, exposure
/// and window at another modulation frequency (range disambiguation, thesis eq. 2.8).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SecondFrequencyMeta {
    /// Path of the `.npy` file relative to the recording directory.
    pub frames: String,
    /// The modulation frequency of these images (Hz), not the sensor's own.
    pub modulation_hz: f64,
    /// Phase shift of each raw image in degrees, in acquisition order.
    pub phases_deg: Vec<f64>,
}

/// Raw images at a second modulation frequency, as [`RecordingWriter::append_with_second`]
/// takes them.
#[derive(Debug, Clone, PartialEq)]
pub struct SecondFrequencyFrames {
    /// Modulation frequency (Hz).
    pub modulation_hz: f64,
    /// Phase shift of each raw image (degrees).
    pub phases_deg: Vec<f64>,
    /// The raw images `(K, rows, cols)`.
    pub frames: RawFrames,
}

/// Check a second-frequency table against its sensor; errors carry the key below it.
fn validate_second_frequency(
    s: &SecondFrequencyMeta,
    sensor: &SensorGeometry,
) -> Result<(), FormatError> {
    tofprox_core::sensor::validate_modulation_hz(s.modulation_hz)
        .map_err(|e| invalid(e.to_string()).key("modulation_hz"))?;
    if (s.modulation_hz - sensor.modulation_hz).abs() < 1.0 {
        return Err(invalid(format!(
            "{} Hz is the sensor's own modulation_hz: a second frequency must differ",
            s.modulation_hz
        ))
        .key("modulation_hz"));
    }
    let spec = CaptureSpec {
        phases_deg: s.phases_deg.clone(),
        exposure_us: 0.0,
        illumination: true,
        averaged: 1,
        timestamp_ns: None,
        conditions: BTreeMap::new(),
    };
    validate_spec(&spec)?;
    validate_frames_path(&s.frames).map_err(|e| e.key("frames"))?;
    Ok(())
}

impl CaptureMeta {
    /// The capture without its file name.
    pub fn spec(&self) -> CaptureSpec {
        CaptureSpec {
            phases_deg: self.phases_deg.clone(),
            exposure_us: self.exposure_us,
            illumination: self.illumination,
            averaged: self.averaged,
            timestamp_ns: self.timestamp_ns,
            conditions: self.conditions.clone(),
        }
    }
    /// The physical conditions: `conditions` without its bookkeeping keys
    /// ([`is_bookkeeping_condition`]).
    pub fn physical_conditions(&self) -> impl Iterator<Item = (&str, f64)> {
        self.conditions
            .iter()
            .filter(|(k, _)| !is_bookkeeping_condition(k))
            .map(|(k, v)| (k.as_str(), *v))
    }
    /// Ground-truth distance, if recorded.
    pub fn distance_m(&self) -> Option<f64> {
        self.conditions.get("distance_m").copied()
    }
    /// True for a 4-phase capture: four images whose (canonical) shifts are
    /// `[a, b, a + 180, b + 180]`, `a ∈ {0, 180}`, `b ∈ {90, 270}` — `[0, 90,
    /// 180, 270]`, or what a sensor with another phase convention records as such.
    pub fn is_four_phase(&self) -> bool {
        self.phases_deg.len() == 4 && self.quadrature(Algorithm::FourPhase).is_some()
    }
    /// True when the first two images are a 2-phase pair (`[0, 90]`, or what a
    /// sensor with another phase convention records as such).
    pub fn starts_two_phase(&self) -> bool {
        self.quadrature(Algorithm::TwoPhase).is_some()
    }
    /// How `algorithm` evaluates the first 2 or 4 images
    /// ([`tofprox_core::pipeline::Pipeline::set_quadrature`]), or `None` when they are
    /// not such a set.
    pub fn quadrature(&self, algorithm: Algorithm) -> Option<Quadrature> {
        Quadrature::of_canonical(&self.phases_deg, algorithm)
    }
    /// A short name for the acquisition mode: `4phase`, `2phase`, `correlation-N` or
    /// `N-phase[p0,p1,…]`.
    pub fn mode_label(&self) -> String {
        let n = self.phases_deg.len();
        if self.is_four_phase() {
            "4phase".into()
        } else if n == 2 && self.starts_two_phase() {
            "2phase".into()
        } else if self.is_correlation() {
            format!("correlation-{n}")
        } else {
            let p: Vec<String> = self.phases_deg.iter().map(|p| format!("{p}")).collect();
            format!("{n}-phase[{}]", p.join(","))
        }
    }
    /// True when the phases are `n >= 8` equally spaced steps covering the
    /// circle, in any order (a correlation capture; the standard one is 24 × 15°
    /// from 0°; a sensor shifting its illumination records them descending).
    pub fn is_correlation(&self) -> bool {
        let n = self.phases_deg.len();
        let mut sorted = self.phases_deg.clone();
        sorted.sort_by(f64::total_cmp);
        n >= 8
            && sorted
                .iter()
                .enumerate()
                .all(|(i, p)| same_shift_deg(*p, 360.0 * i as f64 / n as f64))
    }
}

/// The raw images of one capture, shape `(K, rows, cols)`.
#[derive(Debug, Clone, PartialEq)]
pub enum RawFrames {
    /// Raw ADC codes of a single acquisition.
    U16(Array3<u16>),
    /// Averaged codes.
    F32(Array3<f32>),
    /// Averaged codes.
    F64(Array3<f64>),
}

impl RawFrames {
    /// `(K, rows, cols)`.
    pub fn dim(&self) -> (usize, usize, usize) {
        match self {
            RawFrames::U16(a) => a.dim(),
            RawFrames::F32(a) => a.dim(),
            RawFrames::F64(a) => a.dim(),
        }
    }
    /// The element type.
    pub fn dtype(&self) -> Dtype {
        match self {
            RawFrames::U16(_) => Dtype::U16,
            RawFrames::F32(_) => Dtype::F32,
            RawFrames::F64(_) => Dtype::F64,
        }
    }
    /// A copy as `f64` codes.
    pub fn to_f64(&self) -> Array3<f64> {
        match self {
            RawFrames::U16(a) => a.mapv(f64::from),
            RawFrames::F32(a) => a.mapv(f64::from),
            RawFrames::F64(a) => a.clone(),
        }
    }
    /// Fraction of pixels with at least one raw image at a rail (code ≤ 0.5
    /// or ≥ max − 0.5): the saturation share `tofprox info` reports.
    pub fn saturated_fraction(&self, adc_bits: u8) -> f64 {
        let max = f64::from(tofprox_core::sensor::adc_max_code(adc_bits));
        let (_, rows, cols) = self.dim();
        if rows * cols == 0 {
            return 0.0;
        }
        let mut sat = vec![false; rows * cols];
        let n = rows * cols;
        let mut mark = |i: usize, v: f64| {
            if (v <= 0.5 || v >= max - 0.5)
                && let Some(s) = sat.get_mut(i % n)
            {
                *s = true;
            }
        };
        match self {
            RawFrames::U16(a) => a
                .iter()
                .enumerate()
                .for_each(|(i, &v)| mark(i, f64::from(v))),
            RawFrames::F32(a) => a
                .iter()
                .enumerate()
                .for_each(|(i, &v)| mark(i, f64::from(v))),
            RawFrames::F64(a) => a.iter().enumerate().for_each(|(i, &v)| mark(i, v)),
        }
        sat.iter().filter(|&&s| s).count() as f64 / (rows * cols) as f64
    }
    /// Check shape and values against the sensor and the capture's phases.
    pub fn validate(&self, sensor: &SensorGeometry, phases: usize) -> Result<(), FormatError> {
        let (k, rows, cols) = self.dim();
        if (rows, cols) != (sensor.rows, sensor.cols) {
            return Err(invalid(format!(
                "images are {rows}×{cols} but the sensor window is {}×{} (sensor.rows × sensor.cols)",
                sensor.rows, sensor.cols
            )));
        }
        if k != phases {
            return Err(invalid(format!(
                "{k} raw images but phases_deg lists {phases} phases"
            )));
        }
        let max = sensor.max_code();
        match self {
            RawFrames::U16(a) => check_values(
                a,
                |v| u32::from(v) <= max,
                |v| format!("code {v} exceeds 2^adc_bits − 1 = {max}"),
            ),
            RawFrames::F32(a) => check_values(
                a,
                |v| v.is_finite() && v >= 0.0 && f64::from(v) <= f64::from(max),
                |v| float_msg(f64::from(v), max),
            ),
            RawFrames::F64(a) => check_values(
                a,
                |v| v.is_finite() && v >= 0.0 && v <= f64::from(max),
                |v| float_msg(v, max),
            ),
        }
    }
}

fn float_msg(v: f64, max: u32) -> String {
    if v.is_nan() {
        "holds NaN".to_string()
    } else if v.is_infinite() {
        format!("holds {v}")
    } else {
        format!("code {v} is outside 0..={max} (2^adc_bits − 1)")
    }
}

fn check_values<S, T>(
    a: &ArrayBase<S, Ix3>,
    ok: impl Fn(T) -> bool,
    msg: impl Fn(T) -> String,
) -> Result<(), FormatError>
where
    S: Data<Elem = T>,
    T: Copy,
{
    // fast path: one pass without index bookkeeping
    if a.iter().all(|&v| ok(v)) {
        return Ok(());
    }
    for ((k, r, c), &v) in a.indexed_iter() {
        if !ok(v) {
            return Err(invalid(format!(
                "image {k}, pixel (row {r}, col {c}): {}",
                msg(v)
            )));
        }
    }
    Ok(())
}

impl From<Array3<u16>> for RawFrames {
    fn from(a: Array3<u16>) -> Self {
        RawFrames::U16(a)
    }
}
impl From<Array3<f32>> for RawFrames {
    fn from(a: Array3<f32>) -> Self {
        RawFrames::F32(a)
    }
}
impl From<Array3<f64>> for RawFrames {
    fn from(a: Array3<f64>) -> Self {
        RawFrames::F64(a)
    }
}

// ---------------------------------------------------------------- TOML schema

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct RecordingToml {
    format: String,
    version: i64,
    /// Absent in version 1 (checked by [`read_header`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    kind: Option<RecordingKind>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    description: Option<String>,
    sensor: SensorGeometry,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    capture: Vec<CaptureMeta>,
}

/// Keys of the phase convention in `[sensor]` (version 2; docs/recording-format.md).
const PHASE_SHIFT_KEY: &str = "phase_shift_applies_to";
const PHASE_SIGN_KEY: &str = "phase_sign";

/// Read the phase convention keys of `[sensor]` and blank their lines (line numbers kept), so
/// the geometry's own strict reading (unknown keys refused, key paths of errors) sees the rest.
/// Only `key = value` lines are recognised; anywhere else the keys are unknown keys.
fn take_phase_convention<'t>(
    path: &Path,
    text: &'t str,
) -> Result<(PhaseConvention, std::borrow::Cow<'t, str>), FormatError> {
    let mut table = String::new();
    let mut convention = PhaseConvention::CANONICAL;
    let mut out = String::with_capacity(text.len());
    let mut changed = false;
    for (n, line) in text.split_inclusive('\n').enumerate() {
        let l = line.trim();
        if l.starts_with('[') {
            table = l
                .trim_start_matches('[')
                .split(']')
                .next()
                .unwrap_or("")
                .trim()
                .to_string();
        }
        let key = l.split('=').next().unwrap_or("").trim();
        if table == "sensor" && (key == PHASE_SHIFT_KEY || key == PHASE_SIGN_KEY) {
            let at = |msg: String| {
                invalid(format!("line {}: {msg}", n + 1))
                    .at(path)
                    .key(format!("sensor.{key}"))
            };
            let value: toml::Table =
                toml::from_str(l).map_err(|e| at(e.message().trim().to_string()))?;
            match (key, value.get(key)) {
                (PHASE_SHIFT_KEY, Some(toml::Value::String(v))) if v == "demodulation" => {
                    convention.shifted = ShiftedSignal::Demodulation
                }
                (PHASE_SHIFT_KEY, Some(toml::Value::String(v))) if v == "illumination" => {
                    convention.shifted = ShiftedSignal::Illumination
                }
                (PHASE_SIGN_KEY, Some(toml::Value::Integer(v))) if *v == 1 || *v == -1 => {
                    convention.sign = if *v < 0 { -1 } else { 1 }
                }
                (PHASE_SHIFT_KEY, _) => {
                    return Err(at("must be \"demodulation\" or \"illumination\"".into()));
                }
                _ => return Err(at("must be 1 or -1".into())),
            }
            out.push_str(if line.ends_with('\n') { "\n" } else { "" });
            changed = true;
        } else {
            out.push_str(line);
        }
    }
    Ok((
        convention,
        if changed {
            std::borrow::Cow::Owned(out)
        } else {
            std::borrow::Cow::Borrowed(text)
        },
    ))
}

/// `text` (a rendered `recording.toml`) with the phase convention's keys at the end of
/// `[sensor]` when it is not the canonical one.
fn with_phase_convention(text: String, convention: PhaseConvention) -> String {
    if convention.is_canonical() {
        return text;
    }
    let mut keys = String::new();
    if convention.shifted == ShiftedSignal::Illumination {
        keys.push_str(&format!("{PHASE_SHIFT_KEY} = \"illumination\"\n"));
    }
    if convention.sign < 0 {
        keys.push_str(&format!("{PHASE_SIGN_KEY} = -1\n"));
    }
    let Some(start) = text.find("[sensor]\n") else {
        return text;
    };
    // the table ends at the next blank line or header
    let body = start + "[sensor]\n".len();
    let end = text[body..]
        .find("\n\n")
        .map(|e| body + e + 1)
        .or_else(|| text[body..].find("\n[").map(|e| body + e + 1))
        .unwrap_or(text.len());
    let mut out = text;
    out.insert_str(end, &keys);
    out
}

/// Check a capture's metadata (not its file); errors carry the key below `capture[i]`.
pub fn validate_spec(spec: &CaptureSpec) -> Result<(), FormatError> {
    if spec.phases_deg.is_empty() {
        return Err(invalid("must list at least one phase").key("phases_deg"));
    }
    if spec.phases_deg.len() > 4096 {
        return Err(invalid("more than 4096 phases").key("phases_deg"));
    }
    if let Some((i, p)) = spec
        .phases_deg
        .iter()
        .enumerate()
        .find(|(_, p)| !p.is_finite())
    {
        return Err(invalid(format!("phase {i} is {p}, not a finite number")).key("phases_deg"));
    }
    if !(spec.exposure_us.is_finite() && spec.exposure_us >= 0.0) {
        return Err(invalid(format!(
            "{} is not a non-negative finite time",
            spec.exposure_us
        ))
        .key("exposure_us"));
    }
    if spec.averaged == 0 {
        return Err(invalid("must be at least 1 (1 = a single acquisition)").key("averaged"));
    }
    for (k, v) in &spec.conditions {
        if !v.is_finite() {
            return Err(
                invalid(format!("{v} is not a finite number")).key(format!("conditions.{k}"))
            );
        }
        let nonneg = matches!(k.as_str(), "distance_m" | "reflectivity" | "ambient_klux");
        if nonneg && *v < 0.0 {
            return Err(invalid(format!("{v} is negative")).key(format!("conditions.{k}")));
        }
    }
    Ok(())
}

/// A frames path must be relative, stay inside the recording and end in `.npy`.
fn validate_frames_path(frames: &str) -> Result<PathBuf, FormatError> {
    let p = Path::new(frames);
    if frames.is_empty() || !frames.ends_with(".npy") {
        return Err(invalid(format!("\"{frames}\" is not a .npy file name")));
    }
    if !p.components().all(|c| matches!(c, Component::Normal(_))) {
        return Err(invalid(format!(
            "\"{frames}\" must be a relative path inside the recording (no '..', no leading '/')"
        )));
    }
    // normalised: `frames/./a.npy` and `frames//a.npy` are `frames/a.npy`
    Ok(p.components().collect())
}

/// `description` and the number of captures within [`limits::MAX_DESCRIPTION_BYTES`] and
/// [`limits::MAX_CAPTURES`] (both kinds of recording).
pub(crate) fn check_header_limits(
    path: &Path,
    description: Option<&str>,
    captures: usize,
) -> Result<(), FormatError> {
    if let Some(d) = description
        && d.len() > limits::MAX_DESCRIPTION_BYTES
    {
        return Err(FormatError::new(
            ErrorKind::Limit,
            format!(
                "is {} bytes, more than the limit of {} bytes",
                d.len(),
                limits::MAX_DESCRIPTION_BYTES
            ),
        )
        .at(path)
        .key("description"));
    }
    if captures > limits::MAX_CAPTURES {
        return Err(FormatError::new(
            ErrorKind::Limit,
            format!(
                "{captures} captures, more than the limit of {}",
                limits::MAX_CAPTURES
            ),
        )
        .at(path)
        .key("capture"));
    }
    Ok(())
}

/// The frames file names of one `recording.toml`: each a valid relative `.npy` path
/// ([`validate_frames_path`]), none used twice (compared normalised).
#[derive(Default)]
pub(crate) struct FramesNames {
    seen: BTreeSet<PathBuf>,
}

impl FramesNames {
    /// Check `name` (the value of `key` in the TOML file at `path`).
    pub(crate) fn add(&mut self, path: &Path, key: &str, name: &str) -> Result<(), FormatError> {
        let normalised = validate_frames_path(name).map_err(|e| e.at(path).key(key))?;
        if !self.seen.insert(normalised) {
            return Err(
                invalid(format!("\"{name}\" is already used by an earlier capture"))
                    .at(path)
                    .key(key),
            );
        }
        Ok(())
    }
}

/// The frames files of an opened recording: each resolving (symlinks followed) inside the
/// recording directory, and two names of one file (through a symlink inside it, or a hard
/// link: the same device and inode) refused.
pub(crate) struct FramesFiles<'d> {
    dir: &'d Path,
    real: BTreeMap<(u64, u64), String>,
}

impl<'d> FramesFiles<'d> {
    pub(crate) fn new(dir: &'d Path) -> Self {
        FramesFiles {
            dir,
            real: BTreeMap::new(),
        }
    }

    /// The full path of `name` (the value of `key`), checked.
    pub(crate) fn add(&mut self, key: &str, name: &str) -> Result<PathBuf, FormatError> {
        let file = self.dir.join(name);
        let real = limits::check_inside(&file, self.dir).map_err(|e| e.key(key))?;
        let id = {
            use std::os::unix::fs::MetadataExt;
            let m = fs::metadata(&real).map_err(|e| FormatError::io(&file, "cannot stat", e))?;
            (m.dev(), m.ino())
        };
        if let Some(other) = self.real.insert(id, key.to_string()) {
            return Err(invalid(format!("\"{name}\" is the same file as {other}"))
                .at(&self.dir.join(RECORDING_TOML))
                .key(key));
        }
        Ok(file)
    }
}

/// Make `dir` ready for a new recording: refuse (or, with `replace`, first remove) the
/// recording already there — its `recording.toml` and frames directory; nothing else in `dir`
/// is touched — and create the frames directory.
pub(crate) fn prepare_new_recording(dir: &Path, replace: bool) -> Result<(), FormatError> {
    let toml_path = dir.join(RECORDING_TOML);
    let frames = dir.join(FRAMES_DIR);
    if toml_path.exists() {
        if !replace {
            return Err(FormatError::new(
                ErrorKind::AlreadyExists,
                "a recording already exists here (write to another directory, or replace it)",
            )
            .at(&toml_path));
        }
        fs::remove_file(&toml_path).map_err(|e| FormatError::io(&toml_path, "cannot remove", e))?;
        if frames.exists() {
            fs::remove_dir_all(&frames)
                .map_err(|e| FormatError::io(&frames, "cannot remove", e))?;
        }
    }
    fs::create_dir_all(&frames).map_err(|e| FormatError::io(&frames, "cannot create directory", e))
}

/// After the first `recording.toml` of a new recording is written: make the new directory
/// entry itself durable.
pub(crate) fn sync_new_recording(dir: &Path) {
    if let Some(parent) = dir.parent() {
        let _ = fsutil::sync_dir(parent);
    }
}

/// Window and full array within [`limits::MAX_SIDE_PIXELS`] and
/// [`limits::MAX_PIXELS`], so that nothing sized by them is absurd; errors
/// name `<table>.rows` … `<table>.full_cols`.
pub(crate) fn check_sensor_limits(s: &SensorGeometry, table: &str) -> Result<(), FormatError> {
    check_window_limits(table, "rows", "cols", s.rows, s.cols)?;
    check_window_limits(table, "full_rows", "full_cols", s.full_rows, s.full_cols)
}

/// A `rows × cols` image within [`limits::MAX_SIDE_PIXELS`] and [`limits::MAX_PIXELS`]; errors
/// name `<table>.<rows_key>` or `<table>.<cols_key>`.
pub(crate) fn check_window_limits(
    table: &str,
    rows_key: &str,
    cols_key: &str,
    rows: usize,
    cols: usize,
) -> Result<(), FormatError> {
    for (k, v) in [(rows_key, rows), (cols_key, cols)] {
        if v > limits::MAX_SIDE_PIXELS {
            return Err(FormatError::new(
                ErrorKind::Limit,
                format!("{v} is more than the limit of {}", limits::MAX_SIDE_PIXELS),
            )
            .key(format!("{table}.{k}")));
        }
    }
    if rows * cols > limits::MAX_PIXELS {
        return Err(FormatError::new(
            ErrorKind::Limit,
            format!(
                "{rows} × {cols} = {} pixels, more than the limit of {}",
                rows * cols,
                limits::MAX_PIXELS
            ),
        )
        .key(format!("{table}.{rows_key}")));
    }
    Ok(())
}

type Parsed = (
    SensorGeometry,
    PhaseConvention,
    Option<String>,
    Vec<CaptureMeta>,
);

/// Parse and validate the text of a `recording.toml`.
pub(crate) fn parse_recording_toml(path: &Path, text: &str) -> Result<Parsed, FormatError> {
    // format, version and kind first, so that another file, a newer version or
    // a depth recording is reported as such rather than as a list of unknown keys.
    let kind = read_header(path, text)?;
    if kind != RecordingKind::Raw {
        return Err(wrong_kind(path, kind));
    }
    let (convention, text) = take_phase_convention(path, text)?;
    let raw: RecordingToml = parse_toml(path, &text)?;
    let sensor = raw.sensor;
    // the documented limits first, then the geometry's own rules
    check_sensor_limits(&sensor, "sensor").map_err(|e| e.at(path))?;
    sensor
        .validate()
        .map_err(|e| geometry_invalid(e, "sensor").at(path))?;
    check_header_limits(path, raw.description.as_deref(), raw.capture.len())?;
    let mut names = FramesNames::default();
    let mut captures = Vec::with_capacity(raw.capture.len());
    for (i, c) in raw.capture.iter().enumerate() {
        let meta = c.clone();
        let prefix = format!("capture[{i}]");
        names.add(path, &format!("{prefix}.frames"), &meta.frames)?;
        validate_spec(&meta.spec()).map_err(|e| {
            let k = e.key_name().unwrap_or("").to_string();
            e.at(path).key(format!("{prefix}.{k}"))
        })?;
        if let Some(s) = &meta.second_frequency {
            let key = format!("{prefix}.second_frequency");
            if raw.version < SECOND_FREQUENCY_VERSION {
                return Err(FormatError::new(
                    ErrorKind::UnknownKey,
                    format!(
                        "not defined in recording format version {} (it came with version {SECOND_FREQUENCY_VERSION})",
                        raw.version
                    ),
                )
                .at(path)
                .key(key));
            }
            names.add(path, &format!("{key}.frames"), &s.frames)?;
            validate_second_frequency(s, &sensor).map_err(|e| {
                let k = e.key_name().unwrap_or("").to_string();
                e.at(path).key(format!("{key}.{k}"))
            })?;
        }
        // in memory every shift is canonical: u = A·cos(φ − θ) (docs/recording-format.md)
        let mut meta = meta;
        if !convention.is_canonical() {
            let second = meta.second_frequency.iter_mut();
            for p in meta
                .phases_deg
                .iter_mut()
                .chain(second.flat_map(|s| s.phases_deg.iter_mut()))
            {
                *p = convention.canonical_deg(*p);
            }
        }
        captures.push(meta);
    }
    Ok((sensor, convention, raw.description, captures))
}

fn render_recording_toml(
    sensor: &SensorGeometry,
    convention: PhaseConvention,
    description: Option<&str>,
    captures: &[CaptureMeta],
) -> Result<String, FormatError> {
    let mut captures = captures.to_vec();
    if !convention.is_canonical() {
        for c in &mut captures {
            let second = c.second_frequency.iter_mut();
            for p in c
                .phases_deg
                .iter_mut()
                .chain(second.flat_map(|s| s.phases_deg.iter_mut()))
            {
                *p = convention.label_deg(*p);
            }
        }
    }
    let t = RecordingToml {
        format: RECORDING_FORMAT.to_string(),
        version: RECORDING_VERSION,
        kind: Some(RecordingKind::Raw),
        description: description.map(str::to_string),
        sensor: *sensor,
        capture: captures,
    };
    toml::to_string(&t)
        .map(|text| with_phase_convention(text, convention))
        .map_err(|e| invalid(format!("cannot serialise recording.toml: {e}")))
}

mod reader;
mod writer;
pub use reader::Recording;
pub use writer::{RecordingWriter, check_capture};

#[cfg(test)]
mod tests;
