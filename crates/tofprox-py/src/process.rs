//! `tofprox.process`: a recording's captures to depth and amplitude, as `tofprox process`.
use std::path::PathBuf;

use numpy::PyArray;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use tofprox_core::Algorithm;
use tofprox_format::{DepthKind, ProcessOptions, Processing};

use crate::errors::to_py_err;
use crate::to_py;

/// `value` parsed by its `FromStr`, a `ValueError` naming `what` otherwise.
fn parse<T: std::str::FromStr<Err: std::fmt::Display>>(what: &str, value: &str) -> PyResult<T> {
    value
        .parse()
        .map_err(|e| pyo3::exceptions::PyValueError::new_err(format!("{what}: {e}")))
}

/// Process every illuminated capture of the recording in `recording_dir` that `algo` can
/// evaluate, as `tofprox process --json` does.
///
/// Returns one dict per processed capture with the keys of a `tofprox process --json` row
/// (`index`, `depth_kind`, `distance_m`, `median_depth_m`, `error_mm`, `valid_fraction`,
/// `process_us`, and `crosstalk_residual` with a crosstalk calibration) plus `depth_mm`
/// (uint16 numpy array, rows × cols, 0 = invalid) and `amplitude_lsb` (float32 array).
///
/// `calib` is a calibration set directory (None: no offset, wiggling or FPPN correction);
/// `algo` is `"2phase"` or `"4phase"`; `depth_kind` `"radial"` (along each pixel's ray) or
/// `"z"` (along the optical axis; needs a calibration set with intrinsics);
/// `min_amplitude_lsb` the amplitude below which a pixel is invalid (None: the pipeline's
/// default). What was done without (no wiggling table, skipped captures) is issued as a
/// `UserWarning`. Raises `tofprox.Error` (with `kind`, `file`, `key`).
#[pyfunction]
#[pyo3(signature = (recording_dir, calib=None, algo="2phase", depth_kind="radial", min_amplitude_lsb=None))]
pub fn process<'py>(
    py: Python<'py>,
    recording_dir: PathBuf,
    calib: Option<PathBuf>,
    algo: &str,
    depth_kind: &str,
    min_amplitude_lsb: Option<f32>,
) -> PyResult<Bound<'py, PyList>> {
    let mut opts = ProcessOptions::new(parse::<Algorithm>("algo", algo)?);
    opts.depth_kind = parse::<DepthKind>("depth_kind", depth_kind)?;
    if let Some(a) = min_amplitude_lsb {
        opts.min_amplitude_lsb = a;
    }
    let mut proc = py
        .detach(|| Processing::open(&recording_dir, calib.as_deref(), opts))
        .map_err(to_py_err)?;
    let warn = py.import("warnings")?.getattr("warn")?;
    for n in proc.notes() {
        warn.call1((n.as_str(),))?;
    }
    let rows = PyList::empty(py);
    for i in proc.todo().to_vec() {
        let done = proc.capture(i).map_err(to_py_err)?;
        let row = to_py(py, &done.row)?.cast_into::<PyDict>()?;
        row.set_item("depth_mm", PyArray::from_owned_array(py, done.depth_mm))?;
        let amplitude = done.frame.amplitude_lsb.clone();
        row.set_item("amplitude_lsb", PyArray::from_owned_array(py, amplitude))?;
        rows.append(row)?;
    }
    Ok(rows)
}
