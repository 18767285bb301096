//! A full-array calibration made to fit one capture: cropped to its read-out window
//! ([`SensorGeometry::roi_origin`], `rows × cols`), its mean dark level over a region, and the
//! set moved to another modulation frequency (the second frequency of the dim-near
//! confirmation, thesis 2.2.1 / eqs. 2.8–2.9). Pure; the daemon applies it per window.

use ndarray::{Array2, ArrayBase, Data, Ix2, Slice, s};

use crate::calib::{FppnMap, OffsetCalibration};
use crate::crosstalk::CrosstalkCalibration;
use crate::frame::Roi;
use crate::pipeline::Calibration;
use crate::sensor::SensorGeometry;

/// A full-array map does not cover the capture's read-out window.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CropError {
    /// The window lies (partly) outside the map.
    #[error(
        "{what} calibration is {map_rows}x{map_cols}, frame window {rows}x{cols} at {origin:?} does not fit"
    )]
    Outside {
        /// Which part (`"offset"`, `"fppn"`, `"crosstalk"`, `"amplitude"`).
        what: &'static str,
        /// Rows of the map.
        map_rows: usize,
        /// Columns of the map.
        map_cols: usize,
        /// Rows of the window.
        rows: usize,
        /// Columns of the window.
        cols: usize,
        /// The window's first row and column on the array.
        origin: [usize; 2],
    },
}

/// A full-array per-pixel map cropped to the window of `g` (the map itself when it is the
/// window already).
pub fn crop_map<S: Data<Elem = f32>>(
    a: &ArrayBase<S, Ix2>,
    g: SensorGeometry,
    what: &'static str,
) -> Result<Array2<f32>, CropError> {
    let [r0, c0] = g.roi_origin;
    if a.nrows() == g.rows && a.ncols() == g.cols && r0 == 0 && c0 == 0 {
        return Ok(a.to_owned());
    }
    let (rows, cols) = window_of(a.dim(), g, what)?;
    Ok(a.slice(s![rows, cols]).to_owned())
}

/// The rows and columns of a `map` (rows, cols) that the window of `g` covers, or the error
/// naming `what` when it does not fit.
fn window_of(
    map: (usize, usize),
    g: SensorGeometry,
    what: &'static str,
) -> Result<(Slice, Slice), CropError> {
    let [r0, c0] = g.roi_origin;
    let fits = |o: usize, n: usize, full: usize| o.checked_add(n).is_some_and(|e| e <= full);
    if !(fits(r0, g.rows, map.0) && fits(c0, g.cols, map.1)) {
        return Err(CropError::Outside {
            what,
            map_rows: map.0,
            map_cols: map.1,
            rows: g.rows,
            cols: g.cols,
            origin: g.roi_origin,
        });
    }
    let span = |o: usize, n: usize| Slice::from(o..o + n);
    Ok((span(r0, g.rows), span(c0, g.cols)))
}

/// Every per-pixel part of a calibration set (offset, FPPN, crosstalk planes) cropped to the
/// window of `g`; the wiggling table is per sensor and kept.
pub fn crop_calibration(full: &Calibration, g: SensorGeometry) -> Result<Calibration, CropError> {
    let dims = [
        full.offset.as_ref().map(|o| (o.dark_lsb.dim(), "offset")),
        full.fppn
            .as_ref()
            .map(|f| (f.phase_offset_rad.dim(), "fppn")),
        full.crosstalk.as_ref().map(|x| {
            let (_, r, c) = x.lsb_per_us.dim();
            ((r, c), "crosstalk")
        }),
    ];
    let mut cut = (Slice::from(..), Slice::from(..));
    for (dim, what) in dims.into_iter().flatten() {
        cut = window_of(dim, g, what)?;
    }
    Ok(cut_per_pixel(full, cut))
}

/// A full-array per-pixel map as a sensor that reads every `step`-th row sees it: rows
/// `0, step, 2·step, …` (a read-out that skips rows, thesis 3.1.2: the rows converted fall by
/// the step; the pixels read keep their own calibration).
pub fn every_nth_row<S: Data<Elem = f32>>(a: &ArrayBase<S, Ix2>, step: usize) -> Array2<f32> {
    a.slice(s![nth_rows(step), ..]).to_owned()
}

/// Every `step`-th row (0 or 1: every row).
fn nth_rows(step: usize) -> Slice {
    Slice::new(0, None, isize::try_from(step.max(1)).unwrap_or(isize::MAX))
}

/// Every per-pixel part of a calibration set at every `step`-th row of the array
/// ([`every_nth_row`]); the wiggling table is per sensor and kept.
pub fn calibration_every_nth_row(full: &Calibration, step: usize) -> Calibration {
    cut_per_pixel(full, (nth_rows(step), Slice::from(..)))
}

/// The rows and columns `(rows, cols)` of every per-pixel map of `full` (offset, FPPN, the
/// crosstalk planes), read in place: only the results are allocated.
fn cut_per_pixel(full: &Calibration, (rows, cols): (Slice, Slice)) -> Calibration {
    Calibration {
        offset: full.offset.as_ref().map(|o| OffsetCalibration {
            dark_lsb: o.dark_lsb.slice(s![rows, cols]).to_owned(),
        }),
        fppn: full.fppn.as_ref().map(|f| FppnMap {
            phase_offset_rad: f.phase_offset_rad.slice(s![rows, cols]).to_owned(),
        }),
        crosstalk: full.crosstalk.as_ref().map(|x| CrosstalkCalibration {
            lsb_per_us: x.lsb_per_us.slice(s![.., rows, cols]).to_owned(),
        }),
        wiggling: full.wiggling.clone(),
    }
}

/// The mean dark level (codes, mid code included) over `roi` of a frame of window `g`
/// (`roi` in the frame's coordinates, clipped to the map); the mid code without an offset
/// calibration or where the region misses the map (eq. 3.4: the level the raw codes sit on).
pub fn mean_dark_lsb(offset: Option<&OffsetCalibration>, g: SensorGeometry, roi: Roi) -> f32 {
    let mid = g.mid_code() as f32;
    let Some(o) = offset else {
        return mid;
    };
    let (r0, c0) = (g.roi_origin[0] + roi.row0, g.roi_origin[1] + roi.col0);
    let (rows, cols) = o.dark_lsb.dim();
    let v = o.dark_lsb.slice(s![
        r0.min(rows)..(r0 + roi.rows).min(rows),
        c0.min(cols)..(c0 + roi.cols).min(cols)
    ]);
    if v.is_empty() {
        mid
    } else {
        v.iter().sum::<f32>() / v.len() as f32
    }
}

/// The calibration applied at another modulation frequency, `frequency_ratio = f₂/f₁` (no
/// calibration set holds one for it): the dark offset (no modulation in it), the per-pixel
/// phase offsets scaled as a propagation delay (`φ = 2π·f·τ`, eq. 2.6), the cover-window
/// crosstalk (a return from millimetres: its phase `4π·f·d/c` is ≈ 0 at either frequency) and
/// this frequency's wiggling LUT with its global phase offset — on the phone sensor the second
/// frequency's residual is then ≈ 5 cm, within what the unwrapping tolerates (the aliases lie
/// ≥ 27 cm apart); without the LUT it is 23 cm, and a near face unwraps to an alias.
pub fn at_frequency_ratio(full: &Calibration, frequency_ratio: f64) -> Calibration {
    let mut fppn = full.fppn.clone();
    if let Some(f) = &mut fppn {
        f.phase_offset_rad
            .mapv_inplace(|p| (f64::from(p) * frequency_ratio) as f32);
    }
    Calibration {
        offset: full.offset.clone(),
        fppn,
        crosstalk: full.crosstalk.clone(),
        wiggling: full.wiggling.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn window(rows: usize, cols: usize, origin: [usize; 2]) -> SensorGeometry {
        SensorGeometry {
            rows,
            cols,
            roi_origin: origin,
            full_rows: 6,
            full_cols: 8,
            adc_bits: 12,
            modulation_hz: 60e6,
        }
    }

    /// A map whose value names its pixel: `row · 100 + col`.
    fn named(rows: usize, cols: usize) -> Array2<f32> {
        Array2::from_shape_fn((rows, cols), |(r, c)| (r * 100 + c) as f32)
    }

    /// A 6 × 8 set whose maps name their pixels, with `planes` crosstalk planes (plane k adds
    /// k · 10 000).
    fn named_set(planes: usize) -> Calibration {
        let planes = ndarray::Array3::from_shape_fn((planes, 6, 8), |(k, r, c)| {
            (k * 10_000 + r * 100 + c) as f32
        });
        Calibration {
            offset: Some(OffsetCalibration {
                dark_lsb: named(6, 8),
            }),
            fppn: Some(FppnMap {
                phase_offset_rad: named(6, 8),
            }),
            crosstalk: Some(CrosstalkCalibration { lsb_per_us: planes }),
            wiggling: None,
        }
    }

    #[test]
    fn a_window_is_cut_at_its_origin_and_a_window_outside_is_refused() {
        let full = named(6, 8);
        let w = crop_map(&full, window(2, 3, [4, 5]), "offset").unwrap();
        assert_eq!(w.dim(), (2, 3));
        // each value names its pixel on the array: row 4 + r, column 5 + c
        for ((r, c), v) in w.indexed_iter() {
            assert_eq!(*v, ((4 + r) * 100 + 5 + c) as f32);
        }
        assert_eq!(
            crop_map(&full, window(6, 8, [0, 0]), "offset").unwrap(),
            full
        );
        let err = crop_map(&full, window(3, 3, [4, 0]), "fppn").unwrap_err();
        assert_eq!(
            err.to_string(),
            "fppn calibration is 6x8, frame window 3x3 at [4, 0] does not fit"
        );
        assert!(crop_map(&full, window(1, 1, [usize::MAX, 0]), "offset").is_err());
    }

    #[test]
    fn every_per_pixel_part_is_cropped_the_wiggling_table_kept() {
        let full = named_set(4);
        let g = window(2, 2, [1, 3]);
        let c = crop_calibration(&full, g).unwrap();
        assert_eq!(c.offset.unwrap().dark_lsb[[1, 1]], 204.0);
        assert_eq!(c.fppn.unwrap().phase_offset_rad[[0, 1]], 104.0);
        let x = c.crosstalk.unwrap().lsb_per_us;
        assert_eq!(x.dim(), (4, 2, 2));
        assert_eq!(x[[3, 1, 0]], 30_203.0);
    }

    /// Every 2nd row of the array, then the window of the stepped sensor: each value still
    /// names its own pixel (array row 2·r, and the window's rows 1, 2 are array rows 2, 4).
    #[test]
    fn every_nth_row_keeps_each_pixels_calibration() {
        let c = calibration_every_nth_row(&named_set(2), 2);
        let dark = c.offset.as_ref().unwrap().dark_lsb.clone();
        assert_eq!(dark.dim(), (3, 8));
        assert_eq!(dark.column(5).to_vec(), vec![5.0, 205.0, 405.0]);
        let x = &c.crosstalk.as_ref().unwrap().lsb_per_us;
        assert_eq!((x.dim(), x[[1, 2, 7]]), ((2, 3, 8), 10_407.0));
        let stepped = SensorGeometry {
            full_rows: 3,
            ..window(2, 8, [1, 0])
        };
        let w = crop_calibration(&c, stepped).unwrap();
        assert_eq!(
            w.offset.unwrap().dark_lsb.column(0).to_vec(),
            vec![200.0, 400.0]
        );
        assert_eq!(
            every_nth_row(&named(5, 2), 3).column(1).to_vec(),
            vec![1.0, 301.0]
        );
    }

    #[test]
    fn the_mean_dark_level_is_the_regions_mean_on_the_array() {
        let o = OffsetCalibration {
            dark_lsb: named(6, 8),
        };
        let g = window(4, 6, [2, 1]);
        let roi = Roi {
            row0: 1,
            col0: 2,
            rows: 2,
            cols: 2,
        };
        // array rows 3..5, columns 3..5: (303 + 304 + 403 + 404) / 4
        assert_eq!(mean_dark_lsb(Some(&o), g, roi), 353.5);
        assert_eq!(mean_dark_lsb(None, g, roi), g.mid_code() as f32);
        let outside = Roi { row0: 9, ..roi };
        assert_eq!(mean_dark_lsb(Some(&o), g, outside), g.mid_code() as f32);
    }

    #[test]
    fn at_another_frequency_the_phase_offsets_scale_as_a_delay() {
        let full = Calibration {
            fppn: Some(FppnMap {
                phase_offset_rad: Array2::from_elem((2, 2), 0.3),
            }),
            offset: Some(OffsetCalibration {
                dark_lsb: Array2::from_elem((2, 2), 2050.0),
            }),
            ..Calibration::default()
        };
        // the same delay τ at 70 MHz instead of 60: φ₂ = φ₁ · 70/60
        let c = at_frequency_ratio(&full, 70.0 / 60.0);
        let p = c.fppn.unwrap().phase_offset_rad[[1, 0]];
        assert!((f64::from(p) - 0.35).abs() < 1e-6, "{p}");
        assert_eq!(c.offset, full.offset);
    }
}
