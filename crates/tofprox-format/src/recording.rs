//! Recording format version 1: `REC/recording.toml` + `REC/frames/NNNNNN.npy`.
//! See `docs/recording-format.md` for the specification and validation rules.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::fs;
use std::path::{Component, Path, PathBuf};

use ndarray::{Array3, ArrayBase, Data, Ix3};
use serde::de::{self, Deserializer, Visitor};
use serde::{Deserialize, Serialize};

use tofprox_core::SensorGeometry;

use crate::error::{
    ErrorKind, FormatError, check_format_header, from_toml, geometry_invalid, invalid,
};
use crate::fsutil;
use crate::npy::{self, Dtype, NpyArray, shape_str};

/// `format` value of a recording.
pub const RECORDING_FORMAT: &str = "tofprox-recording";
/// The recording format version this crate reads and writes.
pub const RECORDING_VERSION: i64 = 1;
/// File name of the recording header.
pub const RECORDING_TOML: &str = "recording.toml";
/// Sub-directory the writer puts frame files in.
pub const FRAMES_DIR: &str = "frames";

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

/// One `[[capture]]` table.
#[derive(Debug, Clone, PartialEq)]
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
    pub timestamp_ns: Option<u64>,
    /// Numeric ground truth and environment.
    pub conditions: BTreeMap<String, f64>,
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
    /// Ground-truth distance, if recorded.
    pub fn distance_m(&self) -> Option<f64> {
        self.conditions.get("distance_m").copied()
    }
    /// True when the phases are `[0, 90, 180, 270]` (a 4-phase capture).
    pub fn is_four_phase(&self) -> bool {
        phases_match(&self.phases_deg, &[0.0, 90.0, 180.0, 270.0])
    }
    /// True when the phases start with `[0, 90]` (processable as 2-phase).
    pub fn starts_two_phase(&self) -> bool {
        self.phases_deg.len() >= 2 && phases_match(&self.phases_deg[..2], &[0.0, 90.0])
    }
    /// True when the phases are `n >= 8` equally spaced steps starting at 0
    /// (a correlation capture; the standard one is 24 × 15°).
    pub fn is_correlation(&self) -> bool {
        let n = self.phases_deg.len();
        n >= 8
            && self
                .phases_deg
                .iter()
                .enumerate()
                .all(|(i, p)| (p - 360.0 * i as f64 / n as f64).abs() < 1e-6)
    }
}

fn phases_match(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6)
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

/// A number that may be written as a TOML integer or float.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(transparent)]
struct Num(f64);

impl<'de> Deserialize<'de> for Num {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl Visitor<'_> for V {
            type Value = Num;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Num, E> {
                Ok(Num(v))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Num, E> {
                Ok(Num(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Num, E> {
                Ok(Num(v as f64))
            }
        }
        d.deserialize_any(V)
    }
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct RecordingToml {
    format: String,
    version: i64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    description: Option<String>,
    sensor: SensorGeometry,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    capture: Vec<CaptureToml>,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct CaptureToml {
    frames: String,
    phases_deg: Vec<Num>,
    exposure_us: Num,
    illumination: bool,
    averaged: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    timestamp_ns: Option<u64>,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    conditions: BTreeMap<String, Num>,
}

impl CaptureToml {
    fn to_meta(&self) -> CaptureMeta {
        CaptureMeta {
            frames: self.frames.clone(),
            phases_deg: self.phases_deg.iter().map(|n| n.0).collect(),
            exposure_us: self.exposure_us.0,
            illumination: self.illumination,
            averaged: self.averaged,
            timestamp_ns: self.timestamp_ns,
            conditions: self
                .conditions
                .iter()
                .map(|(k, v)| (k.clone(), v.0))
                .collect(),
        }
    }
    fn from_meta(m: &CaptureMeta) -> Self {
        CaptureToml {
            frames: m.frames.clone(),
            phases_deg: m.phases_deg.iter().map(|&p| Num(p)).collect(),
            exposure_us: Num(m.exposure_us),
            illumination: m.illumination,
            averaged: m.averaged,
            timestamp_ns: m.timestamp_ns,
            conditions: m
                .conditions
                .iter()
                .map(|(k, &v)| (k.clone(), Num(v)))
                .collect(),
        }
    }
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
    Ok(p.to_path_buf())
}

// ---------------------------------------------------------------- reader

/// An opened, validated recording. Frame data is read on demand by [`Recording::load`].
#[derive(Debug, Clone)]
pub struct Recording {
    dir: PathBuf,
    sensor: SensorGeometry,
    description: Option<String>,
    captures: Vec<CaptureMeta>,
    dtypes: Vec<Dtype>,
}

impl Recording {
    /// Open and validate a recording directory: the TOML (format, version,
    /// every key), and the header and size of every frames file. Values
    /// inside the frames (NaN, codes out of range) are checked by `load`.
    pub fn open(dir: &Path) -> Result<Recording, FormatError> {
        let toml_path = dir.join(RECORDING_TOML);
        if !dir.is_dir() {
            return Err(FormatError::new(
                ErrorKind::Io,
                "is not a directory (a recording is a directory with recording.toml)",
            )
            .at(dir));
        }
        let text = fs::read_to_string(&toml_path)
            .map_err(|e| FormatError::io(&toml_path, "cannot read", e))?;
        let (sensor, description, captures) = parse_recording_toml(&toml_path, &text)?;
        let mut dtypes = Vec::with_capacity(captures.len());
        for (i, c) in captures.iter().enumerate() {
            let file = dir.join(&c.frames);
            let key = format!("capture[{i}].frames");
            let h = npy::read_header(&file).map_err(|e| e.key_if_none(key.clone()))?;
            check_shape(&h.shape, &sensor, c.phases_deg.len())
                .map_err(|e| e.at(&file).key(key.clone()))?;
            dtypes.push(h.dtype);
        }
        Ok(Recording {
            dir: dir.to_path_buf(),
            sensor,
            description,
            captures,
            dtypes,
        })
    }

    /// The recording directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
    /// The `[sensor]` table.
    pub fn sensor(&self) -> &SensorGeometry {
        &self.sensor
    }
    /// The free-text description.
    pub fn description(&self) -> Option<&str> {
        self.description.as_deref()
    }
    /// All captures, in file order.
    pub fn captures(&self) -> &[CaptureMeta] {
        &self.captures
    }
    /// The element type of capture `index`'s frames file.
    pub fn dtype(&self, index: usize) -> Option<Dtype> {
        self.dtypes.get(index).copied()
    }
    /// Full path of capture `index`'s frames file.
    pub fn frames_path(&self, index: usize) -> Option<PathBuf> {
        self.captures.get(index).map(|c| self.dir.join(&c.frames))
    }

    /// Read and validate capture `index`'s raw images.
    pub fn load(&self, index: usize) -> Result<RawFrames, FormatError> {
        let Some(meta) = self.captures.get(index) else {
            return Err(invalid(format!(
                "capture {index} does not exist ({} captures)",
                self.captures.len()
            ))
            .at(&self.dir.join(RECORDING_TOML)));
        };
        let file = self.dir.join(&meta.frames);
        let key = format!("capture[{index}].frames");
        let arr = npy::read(&file).map_err(|e| e.key_if_none(key.clone()))?;
        let frames = to_raw_frames(arr).map_err(|e| e.at(&file).key(key.clone()))?;
        frames
            .validate(&self.sensor, meta.phases_deg.len())
            .map_err(|e| e.at(&file).key(key))?;
        Ok(frames)
    }
}

fn check_shape(shape: &[usize], sensor: &SensorGeometry, phases: usize) -> Result<(), FormatError> {
    let want = [phases, sensor.rows, sensor.cols];
    if shape.len() != 3 {
        return Err(invalid(format!(
            "array has shape {}, expected 3 dimensions (K, rows, cols) = {}",
            shape_str(shape),
            shape_str(&want)
        )));
    }
    if shape[1..] != want[1..] {
        return Err(invalid(format!(
            "array has shape {} but the sensor window is {}×{} (expected {})",
            shape_str(shape),
            sensor.rows,
            sensor.cols,
            shape_str(&want)
        )));
    }
    if shape[0] != phases {
        return Err(invalid(format!(
            "array holds {} raw images (shape {}) but phases_deg lists {phases} phases",
            shape[0],
            shape_str(shape)
        )));
    }
    Ok(())
}

fn to_raw_frames(a: NpyArray) -> Result<RawFrames, FormatError> {
    let dims = |e: ndarray::ShapeError| invalid(format!("expected a 3-dimensional array: {e}"));
    Ok(match a {
        NpyArray::U16(a) => RawFrames::U16(a.into_dimensionality::<Ix3>().map_err(dims)?),
        NpyArray::F32(a) => RawFrames::F32(a.into_dimensionality::<Ix3>().map_err(dims)?),
        NpyArray::F64(a) => RawFrames::F64(a.into_dimensionality::<Ix3>().map_err(dims)?),
    })
}

type Parsed = (SensorGeometry, Option<String>, Vec<CaptureMeta>);

/// Parse and validate the text of a `recording.toml`.
fn parse_recording_toml(path: &Path, text: &str) -> Result<Parsed, FormatError> {
    // format and version first, so that another file or a newer version is
    // reported as such rather than as a list of unknown keys.
    check_format_header(
        path,
        text,
        RECORDING_FORMAT,
        RECORDING_VERSION,
        "recording",
        "recording",
    )?;
    let raw: RecordingToml = toml::from_str(text).map_err(|e| from_toml(path, text, &e))?;
    let sensor = raw.sensor;
    sensor
        .validate()
        .map_err(|e| geometry_invalid(e, "sensor").at(path))?;
    let mut seen = BTreeSet::new();
    let mut captures = Vec::with_capacity(raw.capture.len());
    for (i, c) in raw.capture.iter().enumerate() {
        let meta = c.to_meta();
        let prefix = format!("capture[{i}]");
        validate_frames_path(&meta.frames)
            .map_err(|e| e.at(path).key(format!("{prefix}.frames")))?;
        if !seen.insert(meta.frames.clone()) {
            return Err(invalid(format!(
                "\"{}\" is already used by an earlier capture",
                meta.frames
            ))
            .at(path)
            .key(format!("{prefix}.frames")));
        }
        validate_spec(&meta.spec()).map_err(|e| {
            let k = e.key_name().unwrap_or("").to_string();
            e.at(path).key(format!("{prefix}.{k}"))
        })?;
        captures.push(meta);
    }
    Ok((sensor, raw.description, captures))
}

fn render_recording_toml(
    sensor: &SensorGeometry,
    description: Option<&str>,
    captures: &[CaptureMeta],
) -> Result<String, FormatError> {
    let t = RecordingToml {
        format: RECORDING_FORMAT.to_string(),
        version: RECORDING_VERSION,
        description: description.map(str::to_string),
        sensor: *sensor,
        capture: captures.iter().map(CaptureToml::from_meta).collect(),
    };
    toml::to_string(&t).map_err(|e| invalid(format!("cannot serialise recording.toml: {e}")))
}

// ---------------------------------------------------------------- writer

/// Appends captures to a recording, crash-safely: each frames file is written
/// to a temporary file, fsynced and renamed into place before
/// `recording.toml` is rewritten the same way. A reader of a recording whose
/// writer was killed at any moment sees every capture appended before the
/// last complete rewrite of `recording.toml`.
#[derive(Debug)]
pub struct RecordingWriter {
    dir: PathBuf,
    sensor: SensorGeometry,
    description: Option<String>,
    captures: Vec<CaptureMeta>,
    next_file: usize,
}

impl RecordingWriter {
    /// Start a new recording in `dir` (created if needed). Refuses a
    /// directory that already holds a `recording.toml` (see [`RecordingWriter::open_append`]).
    pub fn create(
        dir: &Path,
        sensor: SensorGeometry,
        description: Option<String>,
    ) -> Result<Self, FormatError> {
        sensor
            .validate()
            .map_err(|e| geometry_invalid(e, "sensor"))?;
        let toml_path = dir.join(RECORDING_TOML);
        if toml_path.exists() {
            return Err(FormatError::new(
                ErrorKind::AlreadyExists,
                "a recording already exists here (append to it instead)",
            )
            .at(&toml_path));
        }
        let frames = dir.join(FRAMES_DIR);
        fs::create_dir_all(&frames)
            .map_err(|e| FormatError::io(&frames, "cannot create directory", e))?;
        let w = RecordingWriter {
            dir: dir.to_path_buf(),
            sensor,
            description,
            captures: Vec::new(),
            next_file: 0,
        };
        w.write_toml()?;
        if let Some(parent) = dir.parent() {
            // make the new directory entry itself durable
            let _ = fsutil::sync_dir(parent);
        }
        Ok(w)
    }

    /// Continue an existing recording (for example after its writer was
    /// killed): validates it, removes leftover temporary files and appends
    /// after the last complete capture.
    pub fn open_append(dir: &Path) -> Result<Self, FormatError> {
        let rec = Recording::open(dir)?;
        let removed =
            fsutil::remove_tmp_files(dir)? + fsutil::remove_tmp_files(&dir.join(FRAMES_DIR))?;
        if removed > 0 {
            tracing::info!(
                "{}: removed {removed} temporary file(s) left by an interrupted writer",
                dir.display()
            );
        }
        let frames = dir.join(FRAMES_DIR);
        fs::create_dir_all(&frames)
            .map_err(|e| FormatError::io(&frames, "cannot create directory", e))?;
        let next_file = rec
            .captures
            .iter()
            .filter_map(|c| {
                c.frames
                    .strip_prefix("frames/")?
                    .strip_suffix(".npy")?
                    .parse::<usize>()
                    .ok()
            })
            .map(|n| n + 1)
            .max()
            .unwrap_or(0)
            .max(rec.captures.len());
        Ok(RecordingWriter {
            dir: dir.to_path_buf(),
            sensor: rec.sensor,
            description: rec.description,
            captures: rec.captures,
            next_file,
        })
    }

    /// The sensor this recording is for.
    pub fn sensor(&self) -> &SensorGeometry {
        &self.sensor
    }

    /// Number of complete captures.
    pub fn len(&self) -> usize {
        self.captures.len()
    }

    /// Whether no capture has been appended yet.
    pub fn is_empty(&self) -> bool {
        self.captures.is_empty()
    }

    /// Validate and append one capture; returns its index. On error nothing
    /// is added (the recording on disk is unchanged).
    pub fn append(
        &mut self,
        capture: CaptureSpec,
        frames: &RawFrames,
    ) -> Result<usize, FormatError> {
        let index = self.captures.len();
        let key = format!("capture[{index}]");
        validate_spec(&capture).map_err(|e| {
            let k = e.key_name().unwrap_or("").to_string();
            e.key(format!("{key}.{k}"))
        })?;
        frames
            .validate(&self.sensor, capture.phases_deg.len())
            .map_err(|e| e.key(format!("{key}.frames")))?;
        let name = format!("{FRAMES_DIR}/{:06}.npy", self.next_file);
        let file = self.dir.join(&name);
        let bytes = match frames {
            RawFrames::U16(a) => npy::encode_u16(a),
            RawFrames::F32(a) => npy::encode_f32(a),
            RawFrames::F64(a) => npy::encode_f64(a),
        };
        fsutil::write_atomic(&file, &bytes)?;
        self.next_file += 1;
        self.captures.push(CaptureMeta {
            frames: name,
            phases_deg: capture.phases_deg,
            exposure_us: capture.exposure_us,
            illumination: capture.illumination,
            averaged: capture.averaged,
            timestamp_ns: capture.timestamp_ns,
            conditions: capture.conditions,
        });
        if let Err(e) = self.write_toml() {
            self.captures.pop();
            let _ = fs::remove_file(&file);
            return Err(e);
        }
        Ok(index)
    }

    fn write_toml(&self) -> Result<(), FormatError> {
        let path = self.dir.join(RECORDING_TOML);
        let text = render_recording_toml(&self.sensor, self.description.as_deref(), &self.captures)
            .map_err(|e| e.at(&path))?;
        fsutil::write_atomic(&path, text.as_bytes())
    }
}

#[cfg(test)]
mod tests;
