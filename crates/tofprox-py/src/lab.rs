//! `tofprox.lab`: the model lab's compare, diagnose, add and explain, returning what the
//! `tofprox lab … --json` commands print, as Python objects (`docs/lab.md`).
use std::path::{Path, PathBuf};

use pyo3::prelude::*;
use tofprox_lab::adapter::{spec_from_model, spec_holding_model};
use tofprox_lab::diagnose::{compare as fit, diagnose_with, explain as explain_lab};
use tofprox_lab::workflow::{
    add_to_model, apply_explained, check_addable, check_out, diagnose_options, load, write_model,
};
use tofprox_lab::{LabError, report};

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

/// Fit the model file `model` (its enabled effects) to the recording in `recording_dir` and
/// show where it fails: the dict `tofprox lab compare --json` prints (fit, rms, noise, the
/// residual's structure per condition). `hold_effects`: hold the effects' parameters at the
/// file's values; only per-pixel and per-unit parameters are refitted.
#[pyfunction]
#[pyo3(signature = (recording_dir, model, hold_effects=false))]
fn compare<'py>(
    py: Python<'py>,
    recording_dir: PathBuf,
    model: PathBuf,
    hold_effects: bool,
) -> PyResult<Bound<'py, PyAny>> {
    run(py, || {
        let (prep, m) = load(&recording_dir, &model)?;
        let spec = if hold_effects {
            spec_holding_model(&m, &prep).0
        } else {
            spec_from_model(&m)
        };
        Ok(report::comparison_json(&fit(&prep, &spec, &quiet)?))
    })
}

/// Rank the catalogue effects the model file `model` lacks on the recording in
/// `recording_dir` and give a verdict: the dict `tofprox lab diagnose --json` prints
/// (`verdict`, `candidates`, `fit`, `rms`, …). `tolerance_mm`: remaining structure below this
/// depth-equivalent RMS is not a missing effect (None: a share of the recording's noise).
#[pyfunction]
#[pyo3(signature = (recording_dir, model, tolerance_mm=None))]
fn diagnose<'py>(
    py: Python<'py>,
    recording_dir: PathBuf,
    model: PathBuf,
    tolerance_mm: Option<f64>,
) -> PyResult<Bound<'py, PyAny>> {
    run(py, || {
        let opts = diagnose_options(tolerance_mm)?;
        let (prep, m) = load(&recording_dir, &model)?;
        let cmp = fit(&prep, &spec_from_model(&m), &quiet)?;
        Ok(report::diagnosis_json(&diagnose_with(
            &prep, &cmp, &opts, &quiet,
        )?))
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

/// Enable the catalogue effect `effect` in the model file `model`, fit it on the recording in
/// `data` and return the dict `tofprox lab add --json` prints (errors before and after, the
/// fitted parameters). With `out`, the model with the effect is written there (the file's
/// comments kept); an existing `out` is replaced only with `force=True`.
#[pyfunction]
#[pyo3(signature = (effect, model, data, out=None, force=false))]
fn add<'py>(
    py: Python<'py>,
    effect: String,
    model: PathBuf,
    data: PathBuf,
    out: Option<PathBuf>,
    force: bool,
) -> PyResult<Bound<'py, PyAny>> {
    run(py, || {
        check_addable(&effect)?;
        check_out(out.as_deref(), force)?;
        let (prep, mut m) = load(&data, &model)?;
        let (res, _notes) = add_to_model(&prep, &mut m, &effect, &quiet)?;
        write_out(&model, &m, std::slice::from_ref(&effect), out.as_deref())?;
        Ok(report::add_json(&effect, &res))
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
