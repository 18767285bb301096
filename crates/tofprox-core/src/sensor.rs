//! The shared sensor vocabulary of every tofprox crate: the sensor geometry (read-out window,
//! full array, ADC, modulation), its one validation and derived values, the row window of a
//! partial read-out, the request of one measurement cycle and the physical constants.
//!
//! Every other crate uses these types as they are (recording `[sensor]`, calibration
//! `[valid_for]`, the model's simulated array, the driver's cycle output, the daemon's requests);
//! there are no copies and no field-by-field converters.

use serde::{Deserialize, Serialize};

use crate::{Algorithm, CoreError, phasor};

/// Speed of light in vacuum, m/s (eqs. 2.6–2.8).
pub const SPEED_OF_LIGHT_M_PER_S: f64 = 299_792_458.0;

/// The ADC resolutions a sensor may have, in bits: codes are stored as `u16` (at most 16 bits) and
/// fewer than 8 bits cannot resolve the phase of eq. 2.2 usefully (the IRS1645 has 12, thesis 4.1).
pub const ADC_BITS: std::ops::RangeInclusive<u8> = 8..=16;

/// The modulation frequencies a sensor may use, Hz (continuous-wave ToF modulates at tens of MHz;
/// the thesis uses 80 MHz, 5.1.1; 1 GHz would be an unambiguous range of 15 cm, eq. 2.7).
pub const MODULATION_HZ: std::ops::RangeInclusive<f64> = 1e5..=1e9;

/// Largest pixel array a geometry may describe (2^24 pixels, a 4096 × 4096 array; the IRS1645
/// has 172 × 224). Buffers are sized from geometries: this refuses absurd sizes up front.
pub const MAX_PIXELS: usize = 1 << 24;

/// Zero differential voltage of an offset-binary ADC of `adc_bits` bits: `2^(adc_bits − 1)` (the
/// `mid` of the conventions in the crate documentation). Bits outside `1..=16` are clamped so the
/// shift cannot overflow; [`validate_adc_bits`] is what refuses them.
pub fn adc_mid_code(adc_bits: u8) -> u32 {
    1u32 << (adc_bits.clamp(1, 16) - 1)
}

/// Upper rail of an ADC of `adc_bits` bits: `2^adc_bits − 1` (bits clamped to `1..=16` as in
/// [`adc_mid_code`]).
pub fn adc_max_code(adc_bits: u8) -> u32 {
    (1u32 << adc_bits.clamp(1, 16)) - 1
}

/// The one ADC-resolution check: `adc_bits` in [`ADC_BITS`]; the error names the key `adc_bits`.
pub fn validate_adc_bits(adc_bits: u8) -> Result<(), CoreError> {
    if ADC_BITS.contains(&adc_bits) {
        Ok(())
    } else {
        Err(CoreError::param(
            "adc_bits",
            format!(
                "{adc_bits} is out of range: {}..={} bits (codes are stored as uint16)",
                ADC_BITS.start(),
                ADC_BITS.end()
            ),
        ))
    }
}

/// The one modulation-frequency check: finite and in [`MODULATION_HZ`]; the error names the key
/// `modulation_hz`.
pub fn validate_modulation_hz(modulation_hz: f64) -> Result<(), CoreError> {
    if modulation_hz.is_finite() && MODULATION_HZ.contains(&modulation_hz) {
        Ok(())
    } else {
        Err(CoreError::param(
            "modulation_hz",
            format!(
                "{modulation_hz} is outside the allowed range [{:e}, {:e}] Hz",
                MODULATION_HZ.start(),
                MODULATION_HZ.end()
            ),
        ))
    }
}

/// A sensor as every crate describes it: the read-out window (`rows` × `cols` at `roi_origin`) of
/// the full pixel array, the ADC resolution and the modulation frequency.
///
/// Serialised with exactly these keys (a recording's `[sensor]`, a calibration set's
/// `[valid_for]`); unknown keys are refused, `roi_origin` defaults to `[0, 0]` and
/// `full_rows` / `full_cols` to the window's `rows` / `cols`. Deserialising does not validate:
/// call [`SensorGeometry::validate`], whose errors name the offending key (`adc_bits`,
/// `full_rows`, …) for the caller to prefix with its table (`sensor.adc_bits`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(from = "GeometryKeys")]
pub struct SensorGeometry {
    /// Rows of the window.
    pub rows: usize,
    /// Columns of the window.
    pub cols: usize,
    /// Full-array position `[row, col]` of the window's first pixel.
    pub roi_origin: [usize; 2],
    /// Rows of the full array.
    pub full_rows: usize,
    /// Columns of the full array.
    pub full_cols: usize,
    /// ADC resolution; codes are offset binary around [`SensorGeometry::mid_code`].
    pub adc_bits: u8,
    /// Modulation frequency.
    pub modulation_hz: f64,
}

/// The serialised keys with their defaults (see [`SensorGeometry`]).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct GeometryKeys {
    rows: usize,
    cols: usize,
    #[serde(default, deserialize_with = "crate::serde_exact::array")]
    roi_origin: [usize; 2],
    full_rows: Option<usize>,
    full_cols: Option<usize>,
    adc_bits: u8,
    modulation_hz: f64,
}

impl From<GeometryKeys> for SensorGeometry {
    fn from(k: GeometryKeys) -> Self {
        SensorGeometry {
            rows: k.rows,
            cols: k.cols,
            roi_origin: k.roi_origin,
            full_rows: k.full_rows.unwrap_or(k.rows),
            full_cols: k.full_cols.unwrap_or(k.cols),
            adc_bits: k.adc_bits,
            modulation_hz: k.modulation_hz,
        }
    }
}

impl SensorGeometry {
    /// A full-array geometry (window = full array, origin 0).
    pub fn full(rows: usize, cols: usize, adc_bits: u8, modulation_hz: f64) -> Self {
        SensorGeometry {
            rows,
            cols,
            roi_origin: [0, 0],
            full_rows: rows,
            full_cols: cols,
            adc_bits,
            modulation_hz,
        }
    }

    /// The IRS1645-class full array of the thesis: 172 rows × 224 columns, 12-bit ADC, 80 MHz
    /// modulation (4.1, 5.1.1).
    pub fn irs1645() -> Self {
        Self::full(172, 224, 12, 80e6)
    }

    /// Check every field; the error ([`CoreError::InvalidParameter`]) names the key: `rows`,
    /// `cols` (empty window), `full_rows` / `full_cols` (window outside the array, array larger
    /// than [`MAX_PIXELS`]), `adc_bits` ([`ADC_BITS`]), `modulation_hz` ([`MODULATION_HZ`]).
    pub fn validate(&self) -> Result<(), CoreError> {
        if self.rows == 0 {
            return Err(CoreError::param("rows", "must be at least 1"));
        }
        if self.cols == 0 {
            return Err(CoreError::param("cols", "must be at least 1"));
        }
        window_fits("full_rows", self.roi_origin[0], self.rows, self.full_rows)?;
        window_fits("full_cols", self.roi_origin[1], self.cols, self.full_cols)?;
        if self
            .full_rows
            .checked_mul(self.full_cols)
            .is_none_or(|n| n > MAX_PIXELS)
        {
            return Err(CoreError::param(
                "full_rows",
                format!(
                    "the {} × {} array has more than {MAX_PIXELS} pixels (a 4096 × 4096 array)",
                    self.full_rows, self.full_cols
                ),
            ));
        }
        validate_adc_bits(self.adc_bits)?;
        validate_modulation_hz(self.modulation_hz)
    }

    /// Zero differential voltage, `2^(adc_bits − 1)` ([`adc_mid_code`]).
    pub fn mid_code(&self) -> u32 {
        adc_mid_code(self.adc_bits)
    }

    /// Upper rail, `2^adc_bits − 1` ([`adc_max_code`]).
    pub fn max_code(&self) -> u32 {
        adc_max_code(self.adc_bits)
    }

    /// Phase per metre of distance, `4π f / c` (eq. 2.6 inverted: `φ = 4π f d / c`).
    pub fn phase_rad_per_m(&self) -> f64 {
        phasor::distance_to_phase_rad(1.0, self.modulation_hz)
    }

    /// Unambiguous range `c / (2 f)`, eq. 2.7 (1.874 m at 80 MHz).
    pub fn unambiguous_range_m(&self) -> f64 {
        phasor::unambiguous_range_m(self.modulation_hz)
    }

    /// Pixels in the window.
    pub fn pixels(&self) -> usize {
        self.rows * self.cols
    }

    /// The whole array of this geometry (window = full array).
    pub fn full_array(&self) -> Self {
        Self {
            rows: self.full_rows,
            cols: self.full_cols,
            roi_origin: [0, 0],
            ..*self
        }
    }

    /// The window `rows` × `cols` at `(row0, col0)` of this geometry's full array, validated.
    pub fn window(
        &self,
        row0: usize,
        col0: usize,
        rows: usize,
        cols: usize,
    ) -> Result<Self, CoreError> {
        let g = Self {
            rows,
            cols,
            roi_origin: [row0, col0],
            ..*self
        };
        g.validate()?;
        Ok(g)
    }

    /// The full-width window of a partial read-out ([`RowWindow`]) of this geometry's full
    /// array; `None` is the whole array. Validated.
    pub fn row_window(&self, window: Option<RowWindow>) -> Result<Self, CoreError> {
        match window {
            Some(w) => self.window(usize::from(w.row0), 0, usize::from(w.rows), self.full_cols),
            None => {
                let g = self.full_array();
                g.validate()?;
                Ok(g)
            }
        }
    }
}

/// The window `origin..origin + len` of one axis lies inside the full array of `full` pixels;
/// the error names `key` (`full_rows` / `full_cols`).
fn window_fits(key: &'static str, origin: usize, len: usize, full: usize) -> Result<(), CoreError> {
    if origin.checked_add(len).is_none_or(|e| e > full) {
        return Err(CoreError::param(
            key,
            format!(
                "window {origin}..{} does not fit in {key} = {full}",
                origin.saturating_add(len)
            ),
        ));
    }
    Ok(())
}

/// A window for a partial read-out: whole rows (the sensor reads fewer rows, so less data and
/// read-out time per raw image: thesis 3.5.2) and, where the sensor's sequencer can, fewer
/// columns of them (`cols` = 0: every column; fewer conversions, column current sources and
/// MIPI data, thesis 3.1.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RowWindow {
    /// First row (full-array coordinates).
    pub row0: u16,
    /// Number of rows.
    pub rows: u16,
    /// First column (full-array coordinates; with `cols` = 0 ignored).
    #[serde(default)]
    pub col0: u16,
    /// Number of columns; 0 = the full width.
    #[serde(default)]
    pub cols: u16,
    /// Read every `row_step`-th row of `row0..row0 + rows` (0 or 1: every row), where the
    /// sensor's sequencer skips rows: the rows converted, so the read-out's conversions and
    /// data, fall by the step (thesis 3.1.2, fig. 3.12: conversion is row by row). The
    /// presence probe's sparse image; a depth frame always reads every row.
    #[serde(default, skip_serializing_if = "every_row")]
    pub row_step: u16,
}

fn every_row(step: &u16) -> bool {
    *step <= 1
}

impl RowWindow {
    /// Rows `row0..row0 + rows`, every column.
    pub const fn rows_only(row0: u16, rows: u16) -> Self {
        Self {
            row0,
            rows,
            col0: 0,
            cols: 0,
            row_step: 0,
        }
    }

    /// The row step (1: every row).
    pub fn step(&self) -> usize {
        usize::from(self.row_step.max(1))
    }

    /// Rows read: `row0`, `row0 + step`, … below [`end`](Self::end).
    pub fn rows_read(&self) -> usize {
        usize::from(self.rows).div_ceil(self.step())
    }

    /// One past the last row.
    pub fn end(&self) -> u32 {
        u32::from(self.row0) + u32::from(self.rows)
    }

    /// The columns read of an array `full_cols` wide: `(first, count)`.
    pub fn columns(&self, full_cols: usize) -> (usize, usize) {
        if self.cols == 0 {
            (0, full_cols)
        } else {
            (usize::from(self.col0), usize::from(self.cols))
        }
    }
}

/// What one measurement cycle should capture: the measurement mode (by default the depth
/// [`Algorithm`]; the driver's own use cases are a mode type of the bridge), the exposure of every
/// raw image, the partial read-out window (`None`: full array) and the modulation frequency
/// (`None`: the sensor's own; `Some(f)`: a capture at a second frequency `f` for range
/// disambiguation, thesis 2.2.1 eq. 2.8).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CycleRequest<M = Algorithm> {
    /// What to measure.
    pub mode: M,
    /// Exposure (integration) time of every raw image.
    pub exposure_us: f64,
    /// Partial read-out (`None`: full array).
    pub row_window: Option<RowWindow>,
    /// Modulation frequency (Hz) of this capture; `None`: the sensor's configured one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulation_hz: Option<f64>,
    /// Capture only raw image `i` of the mode's sequence (a presence probe: one raw image);
    /// `None`: every raw image of the mode.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub single_image: Option<u16>,
}

impl<M> CycleRequest<M> {
    /// The same request with the mode mapped (e.g. an [`Algorithm`] into a driver use case).
    pub fn map_mode<N>(self, f: impl FnOnce(M) -> N) -> CycleRequest<N> {
        CycleRequest {
            mode: f(self.mode),
            exposure_us: self.exposure_us,
            row_window: self.row_window,
            modulation_hz: self.modulation_hz,
            single_image: self.single_image,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn param_name(e: CoreError) -> &'static str {
        match e {
            CoreError::InvalidParameter { name, .. } => name,
            other => panic!("not a parameter error: {other}"),
        }
    }

    #[test]
    fn codes_follow_the_adc_resolution() {
        let g = SensorGeometry::irs1645();
        assert_eq!((g.mid_code(), g.max_code()), (2048, 4095));
        assert_eq!((adc_mid_code(16), adc_max_code(16)), (32768, 65535));
        // out-of-range bits never overflow
        assert_eq!((adc_mid_code(0), adc_max_code(40)), (1, 65535));
    }

    #[test]
    fn derived_values_follow_eqs_2_6_and_2_7() {
        let g = SensorGeometry::irs1645();
        let k = 4.0 * std::f64::consts::PI * 80e6 / SPEED_OF_LIGHT_M_PER_S;
        assert!((g.phase_rad_per_m() - k).abs() < 1e-12);
        assert!((g.unambiguous_range_m() - 1.873_702_862_5).abs() < 1e-9);
    }

    #[test]
    fn validation_names_the_key() {
        let g = SensorGeometry::irs1645();
        assert!(g.validate().is_ok());
        let bad = |f: fn(&mut SensorGeometry)| {
            let mut b = g;
            f(&mut b);
            param_name(b.validate().unwrap_err())
        };
        assert_eq!(bad(|b| b.rows = 0), "rows");
        assert_eq!(bad(|b| b.cols = 0), "cols");
        assert_eq!(bad(|b| b.roi_origin = [1, 0]), "full_rows");
        assert_eq!(bad(|b| b.roi_origin = [0, usize::MAX]), "full_cols");
        assert_eq!(bad(|b| b.adc_bits = 7), "adc_bits");
        assert_eq!(bad(|b| b.adc_bits = 17), "adc_bits");
        assert_eq!(bad(|b| b.modulation_hz = f64::NAN), "modulation_hz");
        assert_eq!(bad(|b| b.modulation_hz = 0.0), "modulation_hz");
        let huge = SensorGeometry::full(8192, 8192, 12, 80e6);
        assert_eq!(param_name(huge.validate().unwrap_err()), "full_rows");
    }

    #[test]
    fn windows_of_the_full_array() {
        let g = SensorGeometry::irs1645();
        let w = g.window(78, 104, 16, 16).unwrap();
        assert_eq!(
            (w.roi_origin, w.full_rows, w.pixels()),
            ([78, 104], 172, 256)
        );
        let full = w.full_array();
        assert_eq!(
            (full.roi_origin, full.rows, full.cols),
            ([0, 0], w.full_rows, w.full_cols)
        );
        assert!(g.window(170, 0, 4, 4).is_err());
        let r = g.row_window(Some(RowWindow::rows_only(40, 20))).unwrap();
        assert_eq!((r.roi_origin, r.rows, r.cols), ([40, 0], 20, 224));
        assert_eq!(w.row_window(None).unwrap(), g);
    }

    #[test]
    fn serde_keys_and_defaults() {
        let g: SensorGeometry =
            toml::from_str("rows = 2\ncols = 3\nadc_bits = 12\nmodulation_hz = 80000000\n")
                .unwrap();
        assert_eq!(g, SensorGeometry::full(2, 3, 12, 80e6));
        let back: SensorGeometry = toml::from_str(&toml::to_string(&g).unwrap()).unwrap();
        assert_eq!(back, g);
        let e = toml::from_str::<SensorGeometry>(
            "rows = 2\ncols = 3\nadc_bits = 12\nmodulation_hz = 8e7\nadc_bitz = 1\n",
        )
        .unwrap_err();
        assert!(e.to_string().contains("adc_bitz"), "{e}");
    }
}
