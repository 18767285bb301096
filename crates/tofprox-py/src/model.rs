//! `tofprox.Model` and `tofprox.effects()`: a model file and the effect catalogue, as
//! `tofprox model show --json` and `tofprox model effects --json` print them (`docs/model.md`).
use std::path::PathBuf;

use pyo3::prelude::*;
use tofprox_model::{ModelConfig, ModelSummary, catalogue};

use crate::errors::to_py_err;
use crate::to_py;

/// A model file (`config/model/*.toml`), validated when loaded: which catalogue effects it
/// enables and the parameters it sets.
///
/// `effects` is a dict effect id → `{"enabled": bool, "params": {name: value}}` for every
/// catalogue effect, `sensor` the `[sensor]` parameters the file sets, `enabled` the ids of
/// the enabled effects; `summary()` is the whole dict `tofprox model show --json` prints.
#[pyclass(module = "tofprox", frozen)]
pub struct Model {
    path: PathBuf,
    model: ModelConfig,
}

#[pymethods]
impl Model {
    /// Load and validate the model file `path`; raises `tofprox.Error` (with `kind`, `file`).
    #[new]
    fn new(path: PathBuf) -> PyResult<Self> {
        let model = ModelConfig::load(&path).map_err(to_py_err)?;
        Ok(Model { path, model })
    }

    /// The model file.
    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    /// The file's description, if any.
    #[getter]
    fn description(&self) -> Option<String> {
        self.model.description.clone()
    }

    /// The ids of the enabled effects, in catalogue order.
    #[getter]
    fn enabled(&self) -> Vec<&'static str> {
        self.model.enabled_effects()
    }

    /// Every catalogue effect: id → `{"enabled": bool, "params": {name: value}}`.
    #[getter]
    fn effects<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &ModelSummary::of(&self.model).effects)
    }

    /// The file's user effects (`[[user_effects]]`): a list of dicts with `name`, `condition`,
    /// `acts_on`, `law` (`{"form": "shape", "knots_x", "knots_y"}` or `{"form": "expression",
    /// "expression", "params"}`) and `provenance`.
    #[getter]
    fn user_effects<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &ModelSummary::of(&self.model).user_effects)
    }

    /// The `[sensor]` parameters the file sets: name → value.
    #[getter]
    fn sensor<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &ModelSummary::of(&self.model).sensor)
    }

    /// The dict `tofprox model show --json` prints (`description`, `sensor`, `effects`,
    /// `measured_waveforms`, `user_effects`).
    fn summary<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &ModelSummary::of(&self.model))
    }

    fn __repr__(&self) -> String {
        format!(
            "Model('{}', enabled: {})",
            self.path.display(),
            self.model.enabled_effects().join(", ")
        )
    }
}

/// The effect catalogue, as `tofprox model effects --json` prints it: one dict per effect
/// (`id`, `title`, `thesis_ref`, `explanation`, `signature`, `acts_on`, `drivers`,
/// `cancels_in_four_phase`, `in_baseline`, and `params`, each with `name`, `unit`, `typical`,
/// `min`, `max`, `doc`, …).
#[pyfunction]
pub fn effects(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    to_py(py, catalogue())
}
