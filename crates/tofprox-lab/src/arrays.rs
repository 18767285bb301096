//! A comparison as dense arrays: the residual table per raw code and the fitted per-pixel
//! maps — what `tofprox lab … --export DIR` writes as `.npy` files and Python's
//! `tofprox.lab.compare/diagnose(…, arrays=True)` returns (docs/lab-json.md, "Exported files").

use ndarray::{Array2, Array4};

use crate::{Comparison, Prepared};

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
