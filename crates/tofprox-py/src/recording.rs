//! `tofprox.Recording`: a raw recording's metadata as dicts, each capture's frames as a numpy
//! array (the strict reader of `tofprox_format`, `docs/recording-format.md`).
use std::collections::BTreeMap;
use std::path::PathBuf;

use numpy::{PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use serde::Deserialize;
use tofprox_core::SensorGeometry;
use tofprox_format::{CaptureSpec, RawFrames, RecordingWriter};

use crate::errors::to_py_err;
use crate::{frames_to_py, to_py};

/// A raw recording (`REC/recording.toml` + `REC/frames/*.npy`), validated when opened.
///
/// `captures` is a list of dicts with the keys of `recording.toml`'s `[[capture]]` tables
/// (`frames`, `phases_deg`, `exposure_us`, `illumination`, `averaged`, `conditions`, …),
/// `sensor` the `[sensor]` table as a dict, and `frames(i)` capture `i`'s raw images as a
/// numpy array of shape (images, rows, cols) in the file's dtype (uint16 ADC codes, or
/// float32/float64 averaged codes).
#[pyclass(module = "tofprox", frozen)]
pub struct Recording {
    rec: tofprox_format::Recording,
}

#[pymethods]
impl Recording {
    /// Open and validate the recording in directory `path`; raises `tofprox.Error` (with
    /// `kind`, `file`, `key`) when it does not read.
    #[new]
    pub(crate) fn open(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let rec = py
            .detach(|| tofprox_format::Recording::open(&path))
            .map_err(to_py_err)?;
        Ok(Recording { rec })
    }

    /// Write a new recording to directory `path` from arrays and return it, opened:
    /// `sensor` a dict as `Recording.sensor`, `captures` one dict per capture as
    /// `Recording.captures` (`phases_deg`, `exposure_us`, optional `illumination` (True),
    /// `averaged` (1), `timestamp_ns`, `conditions`; a `frames` key is ignored), `frames` one
    /// numpy array (images, rows, cols) per capture, uint16, float32 or float64.
    ///
    /// Everything is checked as a reader checks it (the sensor, every capture's keys and
    /// ranges, each array's shape against the window and the phases, uint16 codes within the
    /// ADC's range) before anything is written; raises `tofprox.Error` with `kind` and `key`
    /// (`capture[2].frames`). An existing recording at `path` is replaced only with
    /// `force=True`.
    #[staticmethod]
    #[pyo3(signature = (path, sensor, captures, frames, description=None, force=false))]
    fn write(
        py: Python<'_>,
        path: PathBuf,
        sensor: &Bound<'_, PyAny>,
        captures: Vec<Bound<'_, PyAny>>,
        frames: Vec<Bound<'_, PyAny>>,
        description: Option<String>,
        force: bool,
    ) -> PyResult<Self> {
        if captures.len() != frames.len() {
            return Err(PyValueError::new_err(format!(
                "{} captures but {} frame arrays",
                captures.len(),
                frames.len()
            )));
        }
        let sensor: SensorGeometry = from_py(py, "sensor", sensor)?;
        let mut todo = Vec::with_capacity(captures.len());
        for (i, (c, f)) in captures.iter().zip(&frames).enumerate() {
            let spec = from_py::<CaptureIn>(py, &format!("captures[{i}]"), c)?.spec();
            let raw = raw_frames(i, f)?;
            tofprox_format::check_capture(&sensor, i, &spec, &raw).map_err(to_py_err)?;
            todo.push((spec, raw));
        }
        py.detach(|| {
            let mut w = new_writer(&path, sensor, description, force)?;
            todo.into_iter()
                .try_for_each(|(spec, raw)| w.append(spec, &raw).map(drop))?;
            w.finish()
        })
        .map_err(to_py_err)?;
        Self::open(py, path)
    }

    /// The recording's directory.
    #[getter]
    fn path(&self) -> PathBuf {
        self.rec.dir().to_path_buf()
    }

    /// The `[sensor]` table: window, full array, ADC bits, modulation frequency.
    #[getter]
    fn sensor<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, self.rec.sensor())
    }

    /// One dict per `[[capture]]` table, in order.
    #[getter]
    fn captures<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, self.rec.captures())
    }

    /// Capture `index`'s raw images, shape (images, rows, cols), in the file's dtype.
    fn frames<'py>(&self, py: Python<'py>, index: usize) -> PyResult<Bound<'py, PyAny>> {
        let raw = py.detach(|| self.rec.load(index)).map_err(to_py_err)?;
        Ok(frames_to_py(py, raw))
    }

    fn __len__(&self) -> usize {
        self.rec.captures().len()
    }

    fn __repr__(&self) -> String {
        let s = self.rec.sensor();
        format!(
            "Recording('{}', {} captures, {}×{} pixels, {} MHz)",
            self.rec.dir().display(),
            self.rec.captures().len(),
            s.rows,
            s.cols,
            s.modulation_hz / 1e6
        )
    }
}

/// A `[[capture]]` table as `Recording.captures` gives it (its `frames` file name ignored).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CaptureIn {
    phases_deg: Vec<f64>,
    exposure_us: f64,
    #[serde(default = "yes")]
    illumination: bool,
    #[serde(default = "one")]
    averaged: u32,
    #[serde(default)]
    timestamp_ns: Option<u64>,
    #[serde(default)]
    conditions: BTreeMap<String, f64>,
    #[serde(default, rename = "frames")]
    _frames: Option<String>,
}

fn yes() -> bool {
    true
}

fn one() -> u32 {
    1
}

impl CaptureIn {
    fn spec(self) -> CaptureSpec {
        CaptureSpec {
            phases_deg: self.phases_deg,
            exposure_us: self.exposure_us,
            illumination: self.illumination,
            averaged: self.averaged,
            timestamp_ns: self.timestamp_ns,
            conditions: self.conditions,
        }
    }
}

/// A Python dict (or any JSON-like value) as `T`, a `ValueError` naming `what` otherwise.
fn from_py<T: serde::de::DeserializeOwned>(
    py: Python<'_>,
    what: &str,
    value: &Bound<'_, PyAny>,
) -> PyResult<T> {
    let text: String = py
        .import("json")?
        .getattr("dumps")?
        .call1((value,))?
        .extract()?;
    serde_json::from_str(&text).map_err(|e| PyValueError::new_err(format!("{what}: {e}")))
}

/// Capture `i`'s array is refused before it is copied when its `.npy` file could not be read
/// back (over `tofprox_format::limits::MAX_NPY_BYTES`): a huge array — or a broadcast view of
/// one value with a huge shape, which takes no memory in numpy — never reaches the copy, so it
/// is a `tofprox.Error`, not an allocation failure that ends the interpreter.
fn check_size(i: usize, shape: &[usize], value_bytes: usize) -> PyResult<()> {
    let bytes = shape
        .iter()
        .try_fold(value_bytes, |acc, &n| acc.checked_mul(n));
    match bytes {
        Some(b) if b as u64 <= tofprox_format::limits::MAX_NPY_BYTES => Ok(()),
        _ => Err(crate::errors::invalid_argument(
            &format!("frames[{i}]"),
            format!(
                "frames[{i}]: an array of shape {shape:?} is larger than a recording's frames \
                 may be ({} bytes at most)",
                tofprox_format::limits::MAX_NPY_BYTES
            ),
        )),
    }
}

/// Capture `i`'s numpy array as raw frames (copied out of Python's buffer).
fn raw_frames(i: usize, a: &Bound<'_, PyAny>) -> PyResult<RawFrames> {
    if let Ok(v) = a.extract::<PyReadonlyArray3<'_, u16>>() {
        check_size(i, v.shape(), 2)?;
        return Ok(RawFrames::U16(v.as_array().to_owned()));
    }
    if let Ok(v) = a.extract::<PyReadonlyArray3<'_, f32>>() {
        check_size(i, v.shape(), 4)?;
        return Ok(RawFrames::F32(v.as_array().to_owned()));
    }
    if let Ok(v) = a.extract::<PyReadonlyArray3<'_, f64>>() {
        check_size(i, v.shape(), 8)?;
        return Ok(RawFrames::F64(v.as_array().to_owned()));
    }
    let what = match a.cast::<numpy::PyUntypedArray>() {
        Ok(u) => format!("a {}-D {} array", u.ndim(), u.dtype()),
        Err(_) => "not a numpy array".to_string(),
    };
    Err(PyTypeError::new_err(format!(
        "frames[{i}]: expected a 3-D uint16, float32 or float64 numpy array (images, rows, cols), got {what}"
    )))
}

/// A new recording in `dir`; the one already there is replaced only with `force`.
pub(crate) fn new_writer(
    dir: &std::path::Path,
    sensor: SensorGeometry,
    description: Option<String>,
    force: bool,
) -> Result<RecordingWriter, tofprox_format::FormatError> {
    if force {
        RecordingWriter::replace(dir, sensor, description)
    } else {
        RecordingWriter::create(dir, sensor, description)
    }
}

/// A capture's `[[capture]]` keys as a dict (without `frames`: no file yet).
pub(crate) fn spec_to_py<'py>(py: Python<'py>, spec: &CaptureSpec) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("phases_deg", &spec.phases_deg)?;
    d.set_item("exposure_us", spec.exposure_us)?;
    d.set_item("illumination", spec.illumination)?;
    d.set_item("averaged", spec.averaged)?;
    d.set_item("conditions", to_py(py, &spec.conditions)?)?;
    Ok(d)
}
