//! A comparison as dense arrays: the residual table per raw code and the fitted per-pixel
//! maps — what `tofprox lab … --export DIR` writes as `.npy` files and Python's
//! `tofprox.lab.compare/diagnose(…, arrays=True)` returns (docs/lab-json.md, "Exported files")
//! — and, per capture and unpadded, the model's predicted codes, the measured and predicted
//! depth and a table of how well the model fits each capture ([`per_capture`]).

use std::collections::BTreeMap;
use std::f64::consts::TAU;

use ndarray::{Array2, Array3, Array4};
use rayon::prelude::*;
use serde::Serialize;
use tofprox_core::{Algorithm, phasor};

use crate::fit::{CapInfo, DeltaEval, LabModel};
use crate::signatures::Signature;
use crate::{Comparison, LabError, Prepared};

/// The arrays of one comparison.
#[derive(Debug, Clone)]
pub struct ComparisonArrays {
    /// Measured − model per raw code (LSB), `(captures, K, rows, cols)`; NaN where a code is not
    /// in the fit (saturated, a capture left out, a raw image the capture does not have).
    /// None when the comparison keeps no residual table (`explain`'s steps).
    pub residual_lsb: Option<Array4<f32>>,
    /// The same over its noise σ (unit variance under noise).
    pub residual_z: Option<Array4<f32>>,
    /// χ² per sample, `(rows, cols)`.
    pub pixel_chi2: Array2<f64>,
    /// Fitted per-pixel offset (LSB).
    pub offset_lsb: Array2<f64>,
    /// Fitted amplitude per unit of the signal law (LSB).
    pub gain_lsb: Array2<f64>,
    /// Fitted per-pixel phase (rad).
    pub phase_rad: Array2<f64>,
}

impl ComparisonArrays {
    /// The arrays of `cmp`, fitted on `prep`.
    pub fn of(prep: &Prepared, cmp: &Comparison) -> Self {
        let map = |v: &[f64]| {
            Array2::from_shape_fn((prep.rows, prep.cols), |(r, c)| {
                v.get(r * prep.cols + c).copied().unwrap_or(f64::NAN)
            })
        };
        let (residual_lsb, residual_z) = if cmp.recs.is_empty() {
            (None, None)
        } else {
            let (r, z) = residual_arrays(prep, cmp);
            (Some(r), Some(z))
        };
        ComparisonArrays {
            residual_lsb,
            residual_z,
            pixel_chi2: map(&cmp.pixel_chi2),
            offset_lsb: map(&cmp.model.offset),
            gain_lsb: map(&cmp.model.gain),
            phase_rad: map(&cmp.model.phase),
        }
    }
}

/// The residual table as dense arrays `(captures, K, rows, cols)`: r (LSB) and r·√w.
fn residual_arrays(prep: &Prepared, cmp: &Comparison) -> (Array4<f32>, Array4<f32>) {
    let k_max = prep
        .caps
        .iter()
        .map(|c| c.theta_rad.len())
        .max()
        .unwrap_or(0);
    let shape = (prep.caps.len(), k_max, prep.rows, prep.cols);
    let mut res = Array4::from_elem(shape, f32::NAN);
    let mut z = Array4::from_elem(shape, f32::NAN);
    for s in &cmp.recs {
        let (row, col) = (s.pix as usize / prep.cols, s.pix as usize % prep.cols);
        let at = [s.cap as usize, usize::from(s.k), row, col];
        if let (Some(r), Some(zz)) = (res.get_mut(at), z.get_mut(at)) {
            *r = s.r;
            *zz = s.r * s.w.sqrt();
        }
    }
    (res, z)
}

/// One capture's own arrays, unpadded (a capture has its own number of raw images): what
/// the model predicts and the depth it and the measurement give.
#[derive(Debug, Clone)]
pub struct CaptureArrays {
    /// The model's codes (LSB, mid code and every fitted effect included:
    /// [`crate::LabModel::predict`]), `(K, rows, cols)`, K the capture's raw images; the
    /// model's, not clipped at the ADC's rails.
    pub predicted_codes: Array3<f32>,
    /// Radial depth (mm) of the measured codes less the mid code and the fitted per-pixel
    /// offset, by eq. 2.3 (4-phase) or eq. 2.2 (2-phase) and eq. 2.6, wrapped into the
    /// unambiguous range, `(rows, cols)`; NaN where the capture has no depth
    /// ([`CaptureRow::algorithm`] `None`) or the pixel is saturated.
    pub measured_depth_mm: Array2<f32>,
    /// The same of [`CaptureArrays::predicted_codes`].
    pub predicted_depth_mm: Array2<f32>,
}

/// One row of the per-capture table: the capture's conditions and how well the model fits
/// it. Σ `chi2_share` over the rows is 1 and Σ `samples`·`rms_residual_lsb`² is the
/// comparison's `samples`·`rms.raw_lsb`² (the same residual table, split by capture).
#[derive(Debug, Clone, Serialize)]
pub struct CaptureRow {
    /// Index of the capture in the recording (the lab's order: the recording's).
    pub capture: usize,
    /// Its conditions: `distance_m`, `ambient_klux`, `temperature_c` where recorded,
    /// `averaged`, `illuminated` (1/0) and the recording's own condition keys.
    pub conditions: BTreeMap<String, f64>,
    /// Exposure per raw image (µs).
    pub exposure_us: f64,
    /// Raw images K.
    pub raw_images: usize,
    /// The depth algorithm its phases allow: 4-phase when it has 0°, 90°, 180° and 270°,
    /// 2-phase with 0° and 90°, none otherwise.
    pub algorithm: Option<Algorithm>,
    /// Whether the fit uses it (the lab leaves out a capture it cannot model).
    pub used: bool,
    /// Its codes in the fit (saturated ones left out).
    pub samples: usize,
    /// Its χ² (Σ w·r² of its codes).
    pub chi2: f64,
    /// Its share of the comparison's χ².
    pub chi2_share: f64,
    /// RMS of its residuals measured − model (LSB); NaN without samples.
    pub rms_residual_lsb: f64,
    /// RMS over its pixels of measured − predicted depth (mm), the phase difference wrapped
    /// into (−π, π] (eq. 2.6); NaN without depth.
    pub depth_rms_mm: f64,
}

/// Every capture's arrays and its row of the table, in capture order.
pub fn per_capture(
    prep: &Prepared,
    cmp: &Comparison,
) -> Result<(Vec<CaptureArrays>, Vec<CaptureRow>), LabError> {
    let sigs = cmp.model.signatures(prep)?;
    let arrays: Vec<CaptureArrays> = (0..prep.caps.len())
        .into_par_iter()
        .map(|c| capture_arrays(prep, &cmp.model, &sigs, c))
        .collect();
    // the residual table split by capture: (Σ w r², Σ r², count)
    let mut sums = vec![(0.0, 0.0, 0usize); prep.caps.len()];
    for s in &cmp.recs {
        if let Some(e) = sums.get_mut(s.cap as usize) {
            e.0 += s.chi2();
            e.1 += f64::from(s.r).powi(2);
            e.2 += 1;
        }
    }
    let total: f64 = sums.iter().map(|e| e.0).sum();
    let rows = sums
        .iter()
        .zip(&arrays)
        .enumerate()
        .map(|(c, (&(chi2, r2, n), a))| {
            let cap = &prep.caps[c];
            CaptureRow {
                capture: c,
                conditions: conditions(prep, c),
                exposure_us: cap.exposure_us,
                raw_images: cap.theta_rad.len(),
                algorithm: depth_images(cap).map(|(alg, _)| alg),
                used: cap.used,
                samples: n,
                chi2,
                chi2_share: if total > 0.0 { chi2 / total } else { f64::NAN },
                rms_residual_lsb: if n > 0 {
                    (r2 / n as f64).sqrt()
                } else {
                    f64::NAN
                },
                depth_rms_mm: depth_rms_mm(a, prep),
            }
        })
        .collect();
    Ok((arrays, rows))
}

/// The conditions of capture `c` by name (the recording's own keys in `prep.extra_keys`).
fn conditions(prep: &Prepared, c: usize) -> BTreeMap<String, f64> {
    let cap = &prep.caps[c];
    let mut m = BTreeMap::new();
    if let Some(d) = cap.distance_m {
        m.insert("distance_m".to_string(), d);
    }
    m.insert("ambient_klux".to_string(), cap.ambient_klux);
    if let Some(t) = cap.temperature_c {
        m.insert("temperature_c".to_string(), t);
    }
    m.insert("averaged".to_string(), f64::from(cap.averaged));
    m.insert("illuminated".to_string(), f64::from(u8::from(cap.illum)));
    for (k, v) in prep.extra_keys.iter().zip(&cap.extra) {
        m.insert(k.clone(), *v);
    }
    m
}

/// The raw image of `cap` at phase `deg` (to 10⁻⁶°).
fn image_at(cap: &CapInfo, deg: f64) -> Option<usize> {
    cap.phases_deg
        .iter()
        .position(|p| (p - deg).rem_euclid(360.0).min((deg - p).rem_euclid(360.0)) < 1e-6)
}

/// The depth algorithm of `cap` and its raw images at 0°, 90° (and 180°, 270° for 4-phase).
pub(crate) fn depth_images(cap: &CapInfo) -> Option<(Algorithm, [usize; 4])> {
    if !cap.illum {
        return None;
    }
    let (i0, i90) = (image_at(cap, 0.0)?, image_at(cap, 90.0)?);
    Some(match image_at(cap, 180.0).zip(image_at(cap, 270.0)) {
        Some((i180, i270)) => (Algorithm::FourPhase, [i0, i90, i180, i270]),
        None => (Algorithm::TwoPhase, [i0, i90, i0, i90]),
    })
}

/// Phase (rad, [0, 2π)) of the offset-corrected codes `u` at the images `at` by `alg`.
fn phase_of(alg: Algorithm, u: impl Fn(usize) -> f64, at: [usize; 4]) -> f64 {
    match alg {
        Algorithm::TwoPhase => phasor::phase_2phase(u(at[0]), u(at[1])), // eq. 2.2
        Algorithm::FourPhase => phasor::phase_4phase(u(at[0]), u(at[1]), u(at[2]), u(at[3])), // eq. 2.3
    }
}

/// The arrays of capture `c`.
fn capture_arrays(
    prep: &Prepared,
    model: &LabModel,
    sigs: &[Box<dyn Signature>],
    c: usize,
) -> CaptureArrays {
    let cap = &prep.caps[c];
    let (k_n, npix) = (cap.theta_rad.len(), prep.npix);
    let mut codes = Array3::from_elem((k_n, prep.rows, prep.cols), f32::NAN);
    let mut meas_d = Array2::from_elem((prep.rows, prep.cols), f32::NAN);
    let mut pred_d = Array2::from_elem((prep.rows, prep.cols), f32::NAN);
    let mut eval = DeltaEval::new(sigs, &model.effects);
    let depth = depth_images(cap);
    let mut pred = vec![0.0; k_n];
    for p in 0..npix {
        let (row, col) = (p / prep.cols, p % prep.cols);
        for (k, v) in pred.iter_mut().enumerate() {
            let r = model.rec(prep, c, k, p);
            *v = prep.mid + r.x + eval.sum(&r, prep);
            codes[[k, row, col]] = *v as f32;
        }
        let saturated = prep.sat_meas[c * npix + p] || model.sat[c * npix + p];
        if let (Some((alg, at)), false) = (depth, saturated) {
            let o = prep.mid + model.offset[p];
            let to_mm = |phase: f64| {
                (1000.0 * phasor::phase_to_distance_m(phase, prep.modulation_hz)) as f32 // eq. 2.6
            };
            meas_d[[row, col]] = to_mm(phase_of(alg, |k| prep.meas[prep.idx(c, k, p)] - o, at));
            pred_d[[row, col]] = to_mm(phase_of(alg, |k| pred[k] - o, at));
        }
    }
    CaptureArrays {
        predicted_codes: codes,
        measured_depth_mm: meas_d,
        predicted_depth_mm: pred_d,
    }
}

/// RMS of measured − predicted depth over the pixels that have both (mm): the difference
/// taken as a phase wrapped into (−π, π], so a pixel either side of the range's wrap is
/// near, not a range apart.
fn depth_rms_mm(a: &CaptureArrays, prep: &Prepared) -> f64 {
    let range_mm = 1000.0 * phasor::unambiguous_range_m(prep.modulation_hz);
    let (mut s, mut n) = (0.0, 0usize);
    for (m, p) in a.measured_depth_mm.iter().zip(&a.predicted_depth_mm) {
        if m.is_finite() && p.is_finite() {
            let d = phasor::wrap_to_pi(f64::from(m - p) / range_mm * TAU) / TAU * range_mm;
            s += d * d;
            n += 1;
        }
    }
    if n > 0 {
        (s / n as f64).sqrt()
    } else {
        f64::NAN
    }
}
