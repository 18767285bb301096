//! `tofprox.simulate` and `tofprox.sweep`: the physical model's captures as numpy arrays or as
//! a recording — the planning and simulation of `tofprox sim sweep` (`tofprox_model::sweep`).
use std::path::{Path, PathBuf};

use numpy::PyArray;
use numpy::ndarray::{ArrayView3, Axis, stack};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyList;
use tofprox_format::{RawFrames, Recording as RecordingFile};
use tofprox_model::sweep as plans;
use tofprox_model::sweep::{PlannedCapture, SweepError, SweepPlan};
use tofprox_model::{CaptureRequest, ModelConfig, ModelError, SensorGeometry, Simulator};

use crate::errors::to_py_err;
use crate::frames_to_py;
use crate::recording::{Recording, new_writer, spec_to_py};

/// The sensor's read-out window `(row, col, height, width)` on the full array (None: all).
fn geometry(window: Option<(usize, usize, usize, usize)>) -> PyResult<SensorGeometry> {
    let full = SensorGeometry::irs1645();
    match window {
        None => Ok(full),
        Some((r, c, h, w)) => full.window(r, c, h, w).map_err(to_py_err),
    }
}

fn load(model: &Path) -> PyResult<ModelConfig> {
    ModelConfig::load(model).map_err(to_py_err)
}

/// The stacked result (captures × images × pixels, 8 bytes a value at most) is refused before
/// anything is simulated when it is larger than one recording array may be
/// (`tofprox_format::limits::MAX_NPY_BYTES`): a huge `distances_m` is a `tofprox.Error`, not an
/// allocation failure that ends the interpreter.
fn check_result_size(captures: usize, images: usize, pixels: usize) -> PyResult<()> {
    let bytes = [captures, images, pixels]
        .iter()
        .try_fold(8usize, |acc, &n| acc.checked_mul(n));
    match bytes {
        Some(b) if b as u64 <= tofprox_format::limits::MAX_NPY_BYTES => Ok(()),
        _ => Err(crate::errors::invalid_argument(
            "distances_m",
            format!(
                "distances_m: {captures} captures of {images} images of {pixels} pixels are \
                 more than one call returns ({} bytes at most): simulate fewer, or use \
                 `sweep(out=…)`",
                tofprox_format::limits::MAX_NPY_BYTES
            ),
        )),
    }
}

/// Every capture of `plan`, simulated, in order.
fn simulate_all(
    sim: &Simulator,
    plan: &[PlannedCapture],
    seed: u64,
) -> Result<Vec<RawFrames>, ModelError> {
    let mut out = Vec::with_capacity(plan.len());
    plans::simulate_each(sim, plan, seed, |_, f| {
        out.push(f);
        Ok::<(), ModelError>(())
    })?;
    Ok(out)
}

/// Captures of one dtype and shape stacked along a new first axis, as one numpy array.
fn stacked<'py, T: numpy::Element + Clone>(
    py: Python<'py>,
    views: &[ArrayView3<'_, T>],
) -> PyResult<Bound<'py, PyAny>> {
    let a = stack(Axis(0), views).map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(PyArray::from_owned_array(py, a).into_any())
}

/// Simulate one capture of a flat wall at each of `distances_m` with the model file `model`:
/// a numpy array of shape (distances, images, rows, cols) — uint16 ADC codes for single
/// acquisitions (`averaged=1`) of a model that quantises, float32 codes otherwise.
///
/// `phases` raw images per capture (2, 4 or 24), `exposure_us` per raw image, the target's
/// `reflectivity`, `ambient_klux`, `temperature_c`, `averaged` acquisitions per capture,
/// `illumination=False` for dark frames, `window` `(row, col, height, width)` on the 172×224
/// array (None: the full array), `seed` the sensor's fixed patterns and the noise (capture `i`
/// draws its noise as capture `i` of a `tofprox sim sweep` with that seed), `conditions` the
/// capture's other conditions by key (what the model's user effects read, e.g.
/// `{"vcsel_bias_ma": 25.0}`).
#[pyfunction]
#[pyo3(signature = (model, distances_m, exposure_us=1000.0, phases=4, reflectivity=0.9,
    ambient_klux=0.0, temperature_c=25.0, averaged=1, illumination=true, window=None, seed=1,
    conditions=None))]
#[allow(clippy::too_many_arguments)]
pub fn simulate<'py>(
    py: Python<'py>,
    model: PathBuf,
    distances_m: Vec<f64>,
    exposure_us: f64,
    phases: usize,
    reflectivity: f64,
    ambient_klux: f64,
    temperature_c: f64,
    averaged: u32,
    illumination: bool,
    window: Option<(usize, usize, usize, usize)>,
    seed: u64,
    conditions: Option<std::collections::BTreeMap<String, f64>>,
) -> PyResult<Bound<'py, PyAny>> {
    if distances_m.is_empty() {
        return Err(PyValueError::new_err("distances_m: at least one distance"));
    }
    let m = load(&model)?;
    let request = CaptureRequest {
        phases_deg: plans::phases_for(phases).map_err(to_py_err)?,
        exposure_us,
        illumination,
        averaged,
        ambient_klux,
        temperature_c,
        conditions: conditions.unwrap_or_default(),
    };
    let plan: Vec<PlannedCapture> = distances_m
        .iter()
        .map(|&d| PlannedCapture::wall(request.clone(), d, reflectivity))
        .collect();
    plans::validate(&plan).map_err(to_py_err)?;
    let g = geometry(window)?;
    check_result_size(plan.len(), request.phases_deg.len(), g.rows * g.cols)?;
    let sim = Simulator::new(&m, g, seed).map_err(to_py_err)?;
    let frames = py
        .detach(|| simulate_all(&sim, &plan, seed))
        .map_err(to_py_err)?;
    // one model and one request: every capture has the same dtype
    let u16s: Vec<_> = frames
        .iter()
        .filter_map(|f| match f {
            RawFrames::U16(a) => Some(a.view()),
            _ => None,
        })
        .collect();
    if u16s.len() == frames.len() {
        return stacked(py, &u16s);
    }
    let f32s: Vec<_> = frames
        .iter()
        .filter_map(|f| match f {
            RawFrames::F32(a) => Some(a.view()),
            _ => None,
        })
        .collect();
    stacked(py, &f32s)
}

/// A recording's own conditions as a plan; what is copied but not simulated, or skipped, is
/// issued as a `UserWarning` (the command line's notes).
fn like_plan(py: Python<'_>, like: &Path) -> PyResult<(SensorGeometry, Vec<PlannedCapture>)> {
    let rec = RecordingFile::open(like).map_err(to_py_err)?;
    let plan = plans::plan_like(&rec).map_err(to_py_err)?;
    let warn = py.import("warnings")?.getattr("warn")?;
    if !plan.ignored.is_empty() {
        let note = format!(
            "conditions copied but not simulated (no model input): {}",
            plan.ignored.join(", ")
        );
        warn.call1((note,))?;
    }
    if plan.skipped > 0 {
        let note = format!(
            "skipped {} illuminated captures without distance_m",
            plan.skipped
        );
        warn.call1((note,))?;
    }
    Ok((*rec.sensor(), plan.captures))
}

/// Simulate a calibration-session-like sweep with the model file `model`, as
/// `tofprox sim sweep`: dark frames per temperature and exposure, a 24-phase correlation
/// capture at `correlation_distance_m`, then a wall at each of `distances_m` for every
/// temperature, ambient level, exposure and repeat; the ground truth in each capture's
/// `conditions`. Arguments left None take the command line's defaults (0.15–1.80 m in 5 cm
/// steps, 500 and 1000 µs, 4 phases, 0 klux, 25 °C, reflectivity 0.9, 1 repeat, 1 acquisition,
/// 1 m). `like`: simulate instead the captures of that recording under their own conditions
/// (then no sweep argument may be given).
///
/// With `out`, the recording is written there (an existing one replaced only with
/// `force=True`) — byte for byte what `tofprox sim sweep` writes with the same arguments,
/// except its description — and returned as a `tofprox.Recording`. Without, returns
/// `(captures, frames)`: the capture dicts and the frame arrays `Recording.write` takes.
#[pyfunction]
#[pyo3(signature = (model, out=None, distances_m=None, exposures_us=None, phases=None,
    ambient_klux=None, temperatures_c=None, reflectivity=None, repeats=None, averaged=None,
    correlation_distance_m=None, window=None, seed=1, like=None, force=false))]
#[allow(clippy::too_many_arguments)]
pub fn sweep<'py>(
    py: Python<'py>,
    model: PathBuf,
    out: Option<PathBuf>,
    distances_m: Option<Vec<f64>>,
    exposures_us: Option<Vec<f64>>,
    phases: Option<usize>,
    ambient_klux: Option<Vec<f64>>,
    temperatures_c: Option<Vec<f64>>,
    reflectivity: Option<f64>,
    repeats: Option<u32>,
    averaged: Option<u32>,
    correlation_distance_m: Option<f64>,
    window: Option<(usize, usize, usize, usize)>,
    seed: u64,
    like: Option<PathBuf>,
    force: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let m = load(&model)?;
    let given = [
        distances_m.is_some(),
        exposures_us.is_some(),
        phases.is_some(),
        ambient_klux.is_some(),
        temperatures_c.is_some(),
        reflectivity.is_some(),
        repeats.is_some(),
        averaged.is_some(),
        correlation_distance_m.is_some(),
        window.is_some(),
    ];
    let (geometry, captures) = match &like {
        Some(_) if given.contains(&true) => {
            return Err(PyValueError::new_err(
                "like: the recording sets the captures; give no sweep argument with it",
            ));
        }
        Some(rec) => like_plan(py, rec)?,
        None => {
            let d = SweepPlan::default();
            let plan = SweepPlan {
                distances_m: distances_m.unwrap_or(d.distances_m),
                exposures_us: exposures_us.unwrap_or(d.exposures_us),
                phases: phases.unwrap_or(d.phases),
                ambient_klux: ambient_klux.unwrap_or(d.ambient_klux),
                temperatures_c: temperatures_c.unwrap_or(d.temperatures_c),
                reflectivity: reflectivity.unwrap_or(d.reflectivity),
                repeats: repeats.unwrap_or(d.repeats),
                averaged: averaged.unwrap_or(d.averaged),
                correlation_distance_m: correlation_distance_m.unwrap_or(d.correlation_distance_m),
            };
            (geometry(window)?, plan.captures().map_err(to_py_err)?)
        }
    };
    let sim = Simulator::new(&m, geometry, seed).map_err(to_py_err)?;
    let Some(out) = out else {
        return sweep_arrays(py, &sim, &captures, seed);
    };
    let description = format!(
        "tofprox.sweep{}: model {} (effects: {}), seed {seed}",
        like.map_or(String::new(), |l| format!(" like {}", l.display())),
        model.display(),
        m.enabled_effects().join(", "),
    );
    py.detach(|| {
        let mut writer = new_writer(&out, geometry, Some(description), force)?;
        plans::write_plan(&sim, &captures, seed, &mut writer, || {})?;
        writer.finish().map_err(SweepError::from)
    })
    .map_err(|e: SweepError| to_py_err(e))?;
    let rec = Recording::open(py, out)?;
    Ok(Bound::new(py, rec)?.into_any())
}

/// The simulated captures as `(captures, frames)`: the dicts and arrays `Recording.write` takes.
fn sweep_arrays<'py>(
    py: Python<'py>,
    sim: &Simulator,
    captures: &[PlannedCapture],
    seed: u64,
) -> PyResult<Bound<'py, PyAny>> {
    let frames = py
        .detach(|| simulate_all(sim, captures, seed))
        .map_err(to_py_err)?;
    let specs = PyList::empty(py);
    for p in captures {
        specs.append(spec_to_py(py, &p.spec())?)?;
    }
    let arrays: Vec<_> = frames.into_iter().map(|f| frames_to_py(py, f)).collect();
    Ok((specs, arrays).into_pyobject(py)?.into_any())
}
