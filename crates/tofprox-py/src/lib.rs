//! tofprox for Python: the recordings, the depth pipeline and the model lab as a numpy package
//! (`docs/python.md`). A thin adapter: every result comes from the same library call the
//! `tofprox` command line makes (`tofprox_format::Processing`, `tofprox_lab::workflow`,
//! `tofprox_lab::report`), as the same JSON content turned into Python objects, plus numpy
//! arrays moved (not copied) out of the Rust buffers.
use pyo3::prelude::*;

mod calibration;
mod errors;
mod lab;
mod model;
mod process;
mod recording;
mod simulate;

pub use errors::Error;

/// A serialisable value as the Python object `json.loads` makes of its JSON: the dicts, lists
/// and numbers the command line's `--json` prints.
pub(crate) fn to_py<'py, T: serde::Serialize + ?Sized>(
    py: Python<'py>,
    value: &T,
) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value)
        .map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string()))?;
    py.import("json")?.getattr("loads")?.call1((text,))
}

/// Raw frames as a numpy array, moved (not copied) out of the Rust buffer.
pub(crate) fn frames_to_py(py: Python<'_>, raw: tofprox_format::RawFrames) -> Bound<'_, PyAny> {
    use numpy::PyArray;
    use tofprox_format::RawFrames;
    match raw {
        RawFrames::U16(a) => PyArray::from_owned_array(py, a).into_any(),
        RawFrames::F32(a) => PyArray::from_owned_array(py, a).into_any(),
        RawFrames::F64(a) => PyArray::from_owned_array(py, a).into_any(),
    }
}

/// The native module `tofprox._tofprox`; the package `tofprox` re-exports it.
#[pymodule]
fn _tofprox(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("Error", py.get_type::<Error>())?;
    m.add_class::<recording::Recording>()?;
    m.add_class::<calibration::Calibration>()?;
    m.add_class::<model::Model>()?;
    m.add_function(wrap_pyfunction!(process::process, m)?)?;
    m.add_function(wrap_pyfunction!(model::effects, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::simulate, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::sweep, m)?)?;
    let lab = PyModule::new(py, "lab")?;
    lab::register(&lab)?;
    m.add_submodule(&lab)?;
    Ok(())
}
