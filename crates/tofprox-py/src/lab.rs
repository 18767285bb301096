//! `tofprox.lab`: the model lab's compare, diagnose, add and explain, returning what the
//! `tofprox lab … --json` commands print, as Python objects (`docs/lab.md`).
use std::path::{Path, PathBuf};

use numpy::PyArray;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use tofprox_lab::adapter::{spec_from_model, spec_holding_model};
use tofprox_lab::arrays::{CaptureArrays, CaptureRow, ComparisonArrays, per_capture};
use tofprox_lab::depth_error::depth_split;
use tofprox_lab::diagnose::{compare as fit, diagnose_with, explain as explain_lab};
use tofprox_lab::hold::HoldRequest;
use tofprox_lab::workflow::{
    add_holding, apply_explained, check_addable, check_out, diagnose_options, load, write_model,
};
use tofprox_lab::{Comparison, ErrorKind, LabError, Prepared, report};

use crate::errors::to_py_err;
use crate::to_py;

/// The lab reports no progress to Python.
fn quiet(_stage: &str, _fraction: f64) {}

/// Run `f` without the GIL (the fits take seconds) and turn its JSON into Python objects.
fn run<'py>(
    py: Python<'py>,
    f: impl FnOnce() -> Result<serde_json::Value, LabError> + Send,
) -> PyResult<Bound<'py, PyAny>> {
    let value = py.detach(f).map_err(to_py_err)?;
    to_py(py, &value)
}

/// A comparison's arrays: the dense ones, and per capture its own arrays and table row.
struct Arrays {
    dense: ComparisonArrays,
    captures: Vec<CaptureArrays>,
    table: Vec<CaptureRow>,
}

/// The arrays of `cmp` on `prep` ([`ComparisonArrays::of`], [`per_capture`]).
fn arrays_of(prep: &Prepared, cmp: &Comparison) -> Result<Arrays, LabError> {
    let (captures, table) = per_capture(prep, cmp)?;
    Ok(Arrays {
        dense: ComparisonArrays::of(prep, cmp),
        captures,
        table,
    })
}

/// The comparison's arrays as a dict of numpy arrays (moved, not copied): `residual_lsb`,
/// `residual_z` (float32, captures × K × rows × cols, NaN where a code is not in the fit),
/// `pixel_chi2`, `offset_lsb`, `gain_lsb`, `phase_rad` (float64, rows × cols); per capture,
/// unpadded, the lists `predicted_codes` (float32 K × rows × cols), `measured_depth_mm` and
/// `predicted_depth_mm` (float32 rows × cols); and `captures`, the per-capture table (a list
/// of dicts).
fn arrays_to_py<'py>(py: Python<'py>, a: Arrays) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let dense = a.dense;
    if let (Some(r), Some(z)) = (dense.residual_lsb, dense.residual_z) {
        d.set_item("residual_lsb", PyArray::from_owned_array(py, r))?;
        d.set_item("residual_z", PyArray::from_owned_array(py, z))?;
    }
    d.set_item(
        "pixel_chi2",
        PyArray::from_owned_array(py, dense.pixel_chi2),
    )?;
    d.set_item(
        "offset_lsb",
        PyArray::from_owned_array(py, dense.offset_lsb),
    )?;
    d.set_item("gain_lsb", PyArray::from_owned_array(py, dense.gain_lsb))?;
    d.set_item("phase_rad", PyArray::from_owned_array(py, dense.phase_rad))?;
    let (codes, measured, predicted) = (PyList::empty(py), PyList::empty(py), PyList::empty(py));
    for c in a.captures {
        codes.append(PyArray::from_owned_array(py, c.predicted_codes))?;
        measured.append(PyArray::from_owned_array(py, c.measured_depth_mm))?;
        predicted.append(PyArray::from_owned_array(py, c.predicted_depth_mm))?;
    }
    d.set_item("predicted_codes", codes)?;
    d.set_item("measured_depth_mm", measured)?;
    d.set_item("predicted_depth_mm", predicted)?;
    let table = serde_json::to_value(&a.table)
        .map_err(|e| to_py_err(LabError::new(ErrorKind::Numerical, e.to_string())))?;
    d.set_item("captures", to_py(py, &table)?)?;
    Ok(d)
}

/// Run a comparison-based `f` without the GIL: its JSON as Python objects, with the
/// comparison's arrays under `"arrays"` when asked for.
fn run_with_arrays<'py>(
    py: Python<'py>,
    arrays: bool,
    f: impl FnOnce() -> Result<(serde_json::Value, Prepared, Comparison), LabError> + Send,
) -> PyResult<Bound<'py, PyAny>> {
    let (value, a) = py
        .detach(|| {
            let (v, prep, cmp) = f()?;
            let a = if arrays {
                Some(arrays_of(&prep, &cmp)?)
            } else {
                None
            };
            Ok::<_, LabError>((v, a))
        })
        .map_err(to_py_err)?;
    let out = to_py(py, &value)?;
    if let Some(a) = a {
        out.set_item("arrays", arrays_to_py(py, a)?)?;
    }
    Ok(out)
}

/// Fit the model file `model` (its enabled effects) to the recording in `recording_dir` and
/// show where it fails: the dict `tofprox lab compare --json` prints (fit, rms, noise, the
/// residual's structure per condition). `hold_effects`: hold the effects' parameters at the
/// file's values; only per-pixel and per-unit parameters are refitted. `arrays=True` adds
/// `"arrays"`: the residuals and per-pixel maps `--export DIR` writes as `.npy` files, as
/// numpy arrays (`residual_lsb`, `residual_z`, `pixel_chi2`, `offset_lsb`, `gain_lsb`,
/// `phase_rad`; docs/lab-json.md).
#[pyfunction]
#[pyo3(signature = (recording_dir, model, hold_effects=false, arrays=false))]
fn compare<'py>(
    py: Python<'py>,
    recording_dir: PathBuf,
    model: PathBuf,
    hold_effects: bool,
    arrays: bool,
) -> PyResult<Bound<'py, PyAny>> {
    run_with_arrays(py, arrays, || {
        let (prep, m) = load(&recording_dir, &model)?;
        let spec = if hold_effects {
            spec_holding_model(&m, &prep).0
        } else {
            spec_from_model(&m)
        };
        let cmp = fit(&prep, &spec, &quiet)?;
        Ok((report::comparison_json(&cmp), prep, cmp))
    })
}

/// Rank the catalogue effects the model file `model` lacks on the recording in
/// `recording_dir` and give a verdict: the dict `tofprox lab diagnose --json` prints
/// (`verdict`, `candidates`, `fit`, `rms`, …). `tolerance_mm`: remaining structure below this
/// depth-equivalent RMS is not a missing effect (None: a share of the recording's noise).
/// `arrays=True` adds `"arrays"`, the comparison's residuals and maps (as `compare`).
#[pyfunction]
#[pyo3(signature = (recording_dir, model, tolerance_mm=None, arrays=false))]
fn diagnose<'py>(
    py: Python<'py>,
    recording_dir: PathBuf,
    model: PathBuf,
    tolerance_mm: Option<f64>,
    arrays: bool,
) -> PyResult<Bound<'py, PyAny>> {
    run_with_arrays(py, arrays, || {
        let opts = diagnose_options(tolerance_mm)?;
        let (prep, m) = load(&recording_dir, &model)?;
        let cmp = fit(&prep, &spec_from_model(&m), &quiet)?;
        let d = diagnose_with(&prep, &cmp, &opts, &quiet)?;
        Ok((report::diagnosis_json(&d), prep, cmp))
    })
}

/// Write the model to `out` (when given) as the file `from` with `changed` updated.
fn write_out(
    from: &Path,
    m: &tofprox_model::ModelConfig,
    changed: &[String],
    out: Option<&Path>,
) -> Result<(), LabError> {
    match out {
        Some(p) if !changed.is_empty() => write_model(from, m, changed, p),
        _ => Ok(()),
    }
}

/// The `hold` argument of `add`: a dict name → value, or a list of names (held at the model
/// file's values).
fn hold_requests(hold: Option<&Bound<'_, PyAny>>) -> PyResult<Vec<HoldRequest>> {
    let Some(h) = hold else {
        return Ok(Vec::new());
    };
    if let Ok(d) = h.cast::<PyDict>() {
        return d
            .iter()
            .map(|(k, v)| {
                Ok(HoldRequest {
                    name: k.extract()?,
                    value: Some(v.extract()?),
                })
            })
            .collect();
    }
    let names: Vec<String> = h.extract().map_err(|_| {
        to_py_err(LabError::new(
            ErrorKind::InvalidModel,
            "hold must be a dict {name: value} or a list of names (held at the model file's values)",
        ))
    })?;
    Ok(names
        .into_iter()
        .map(|name| HoldRequest { name, value: None })
        .collect())
}

/// Enable the catalogue effect `effect` (or add the condition response `"condition:KEY"`, or
/// fit the user effect `"user:NAME"` the file declares: docs/lab.md, "An effect the catalogue
/// lacks") in the model file `model`, fit it on the recording in
/// `data` and return the dict `tofprox lab add --json` prints (errors before and after, how
/// much of the depth error is systematic, the fitted parameters, the held ones). With `out`,
/// the model with the effect is written there (the file's comments kept); an existing `out`
/// is replaced only with `force=True`. `hold`: the effect's model-file parameters to hold
/// while the others are fitted — `{"tau_us": 800.0}`, or `["tau_us"]` at the file's value.
#[pyfunction]
#[pyo3(signature = (effect, model, data, out=None, force=false, hold=None))]
fn add<'py>(
    py: Python<'py>,
    effect: String,
    model: PathBuf,
    data: PathBuf,
    out: Option<PathBuf>,
    force: bool,
    hold: Option<Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let hold = hold_requests(hold.as_ref())?;
    run(py, || {
        check_addable(&effect)?;
        check_out(out.as_deref(), force)?;
        let (prep, mut m) = load(&data, &model)?;
        let (res, _notes, held) = add_holding(&prep, &mut m, &effect, &data, &hold, &quiet)?;
        write_out(&model, &m, std::slice::from_ref(&effect), out.as_deref())?;
        let splits = (
            depth_split(&prep, &res.before),
            depth_split(&prep, &res.after),
        );
        Ok(report::add_json(
            &effect,
            &res,
            (&splits.0, &splits.1),
            &held,
        ))
    })
}

/// Loop diagnose → add from the model file `model` on the recording in `recording_dir` until
/// nothing is missing or the rest is unexplained: the dict `tofprox lab explain --json` prints
/// (every step, the effects added, the final verdict, why it stopped). With `out`, the model
/// with every added effect is written there (nothing is written when nothing was added).
#[pyfunction]
#[pyo3(signature = (recording_dir, model, out=None, force=false, tolerance_mm=None))]
fn explain<'py>(
    py: Python<'py>,
    recording_dir: PathBuf,
    model: PathBuf,
    out: Option<PathBuf>,
    force: bool,
    tolerance_mm: Option<f64>,
) -> PyResult<Bound<'py, PyAny>> {
    run(py, || {
        let opts = diagnose_options(tolerance_mm)?;
        check_out(out.as_deref(), force)?;
        let (prep, mut m) = load(&recording_dir, &model)?;
        let ex = explain_lab(&prep, &spec_from_model(&m), &opts, &quiet)?;
        apply_explained(&prep, &mut m, &ex)?;
        write_out(&model, &m, &ex.added, out.as_deref())?;
        Ok(report::explanation_json(&ex))
    })
}

/// Add the lab's functions to the submodule `tofprox.lab`.
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(compare, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose, m)?)?;
    m.add_function(wrap_pyfunction!(add, m)?)?;
    m.add_function(wrap_pyfunction!(explain, m)?)?;
    Ok(())
}
