//! `tofprox.Recording`: a raw recording's metadata as dicts, each capture's frames as a numpy
//! array (the strict reader of `tofprox_format`, `docs/recording-format.md`).
use std::path::PathBuf;

use numpy::PyArray;
use pyo3::prelude::*;
use tofprox_format::RawFrames;

use crate::errors::to_py_err;
use crate::to_py;

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
    fn new(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let rec = py
            .detach(|| tofprox_format::Recording::open(&path))
            .map_err(to_py_err)?;
        Ok(Recording { rec })
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
        // moved into numpy, not copied
        Ok(match raw {
            RawFrames::U16(a) => PyArray::from_owned_array(py, a).into_any(),
            RawFrames::F32(a) => PyArray::from_owned_array(py, a).into_any(),
            RawFrames::F64(a) => PyArray::from_owned_array(py, a).into_any(),
        })
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
