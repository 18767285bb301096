//! `tofprox.Calibration`: a calibration set's metadata as dicts and its per-pixel tables as
//! numpy arrays (the strict loader of `tofprox_format`, `docs/calibration.md`).
use std::path::PathBuf;

use numpy::PyArray;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use tofprox_core::Algorithm;
use tofprox_format::{CalibPart, CalibrationSet};

use crate::errors::to_py_err;
use crate::to_py;

/// A calibration set directory (`calibration.toml` + one `.npy` per part), verified when
/// loaded (checksums, shapes, the parts' dependencies), as `tofprox process --calib` uses it.
///
/// `parts` names the parts present (`offset`, `wiggling_2phase`, `fppn`, `amplitude`, …),
/// `valid_for` is the sensor setup it applies to, `sources` each part's provenance, and
/// `arrays` each part's table as a float32 numpy array (the part's `.npy` file).
#[pyclass(module = "tofprox", frozen)]
pub struct Calibration {
    set: CalibrationSet,
}

#[pymethods]
impl Calibration {
    /// Load and verify the calibration set in directory `path`; raises `tofprox.Error` (with
    /// `kind`, `file`, `key`) when it does not load.
    #[new]
    fn new(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let set = py
            .detach(|| CalibrationSet::load(&path))
            .map_err(to_py_err)?;
        Ok(Calibration { set })
    }

    /// The set's directory.
    #[getter]
    fn path(&self) -> Option<PathBuf> {
        self.set.dir.clone()
    }

    /// The set's description, if any.
    #[getter]
    fn description(&self) -> Option<String> {
        self.set.description.clone()
    }

    /// The names of the parts present, in extraction order.
    #[getter]
    fn parts(&self) -> Vec<&'static str> {
        self.set.parts().into_iter().map(CalibPart::name).collect()
    }

    /// The `[valid_for]` table: the sensor setup and window the set was extracted on.
    #[getter]
    fn valid_for<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &self.set.validity)
    }

    /// The lens intrinsics (`fx`, `fy`, `cx`, `cy`, distortion) as a dict, None without them.
    #[getter]
    fn intrinsics<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &self.set.intrinsics())
    }

    /// Part name → its provenance: `recording`, `recording_description`, `captures`,
    /// `distance_m`, `reflectivity`, `exposure_us`, `created`, `tool`.
    #[getter]
    fn sources<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let out = PyDict::new(py);
        for (part, s) in &self.set.sources {
            let d = PyDict::new(py);
            d.set_item("recording", &s.recording)?;
            d.set_item("recording_description", &s.recording_description)?;
            d.set_item("captures", &s.captures)?;
            d.set_item("distance_m", s.distance_m)?;
            d.set_item("reflectivity", s.reflectivity)?;
            d.set_item("exposure_us", s.exposure_us)?;
            d.set_item("created", &s.created)?;
            d.set_item("tool", &s.tool)?;
            out.set_item(part.name(), d)?;
        }
        Ok(out)
    }

    /// Part name → its table as a float32 array: `offset` (rows, cols) dark level in LSB,
    /// `crosstalk` (phases, rows, cols) LSB per µs, `wiggling_2phase`/`wiggling_4phase`
    /// (LUT entries) phase correction in rad, `fppn`/`fppn_2phase` (rows, cols) phase offset
    /// in rad, `amplitude` (rows, cols) LSB·m²/µs. Intrinsics are in `intrinsics`.
    #[getter]
    fn arrays<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = &self.set;
        let d = PyDict::new(py);
        let put = |part: CalibPart, a: Option<Bound<'py, PyAny>>| match a {
            Some(a) => d.set_item(part.name(), a),
            None => Ok(()),
        };
        let arr2 = |a: &numpy::ndarray::Array2<f32>| PyArray::from_array(py, a).into_any();
        let arr1 = |a: &numpy::ndarray::Array1<f32>| PyArray::from_array(py, a).into_any();
        put(CalibPart::Offset, s.offset().map(|o| arr2(&o.dark_lsb)))?;
        let xt = s.crosstalk();
        put(
            CalibPart::Crosstalk,
            xt.map(|x| PyArray::from_array(py, &x.lsb_per_us).into_any()),
        )?;
        let w2 = s.wiggling(Algorithm::TwoPhase);
        put(
            CalibPart::Wiggling2Phase,
            w2.map(|w| arr1(&w.correction_rad)),
        )?;
        let w4 = s.wiggling(Algorithm::FourPhase);
        put(
            CalibPart::Wiggling4Phase,
            w4.map(|w| arr1(&w.correction_rad)),
        )?;
        put(
            CalibPart::Fppn,
            s.fppn(Algorithm::FourPhase)
                .map(|f| arr2(&f.phase_offset_rad)),
        )?;
        let f2 = s.fppn(Algorithm::TwoPhase);
        put(CalibPart::Fppn2Phase, f2.map(|f| arr2(&f.phase_offset_rad)))?;
        let amp = s.amplitude();
        put(CalibPart::Amplitude, amp.map(|a| arr2(&a.lsb_m2_per_us)))?;
        Ok(d)
    }

    fn __repr__(&self) -> String {
        let dir = self.set.dir.as_deref().unwrap_or(std::path::Path::new("?"));
        format!(
            "Calibration('{}', parts: {})",
            dir.display(),
            self.parts().join(", ")
        )
    }
}
