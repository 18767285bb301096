//! The parts' figures in engineering units, read back from the set as written, and their
//! pass/fail against the station's limits (`docs/calibration.md`, "Production line").

use std::path::Path;

use ndarray::ArrayD;
use serde::Serialize;
use tofprox_core::phasor::{amplitude_4phase, phase_to_distance_m};
use tofprox_format::CalibPart;
use tofprox_format::npy::{self, NpyArray};

use crate::{Limits, StationError};

/// One figure of one part against its limit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PartCheck {
    /// The part (`offset`, `crosstalk`, `wiggling_2phase`, …, `check`).
    pub part: String,
    /// What is measured (`FPN σ`, `hot pixels`, …).
    pub figure: String,
    /// Its value.
    pub value: f64,
    /// Its unit.
    pub unit: String,
    /// Smallest value that passes, if bounded below.
    pub min: Option<f64>,
    /// Largest value that passes, if bounded above.
    pub max: Option<f64>,
    /// Whether it is within its limits.
    pub passed: bool,
    /// What a failure means for the module.
    pub meaning: String,
}

impl PartCheck {
    pub(crate) fn new(
        part: &str,
        figure: &str,
        (value, unit): (f64, &str),
        (min, max): (Option<f64>, Option<f64>),
        meaning: &str,
    ) -> Self {
        let passed =
            value.is_finite() && min.is_none_or(|m| value >= m) && max.is_none_or(|m| value <= m);
        PartCheck {
            part: part.into(),
            figure: figure.into(),
            value,
            unit: unit.into(),
            min,
            max,
            passed,
            meaning: meaning.into(),
        }
    }
}

fn read_part(dir: &Path, part: CalibPart) -> Result<Vec<f64>, StationError> {
    let path = dir.join(part.file_name());
    let a = npy::read(&path, Some(dir)).map_err(|source| StationError::Format {
        step: format!("reading {part}"),
        source,
    })?;
    Ok(match a {
        NpyArray::F32(a) => a.iter().map(|&v| f64::from(v)).collect(),
        NpyArray::F64(a) => a.into_iter().collect(),
        NpyArray::U16(a) => a.iter().map(|&v| f64::from(v)).collect(),
    })
}

fn read_crosstalk(dir: &Path) -> Result<ArrayD<f64>, StationError> {
    let path = dir.join(CalibPart::Crosstalk.file_name());
    let a = npy::read(&path, Some(dir)).map_err(|source| StationError::Format {
        step: "reading crosstalk".into(),
        source,
    })?;
    Ok(match a {
        NpyArray::F32(a) => a.mapv(f64::from),
        NpyArray::F64(a) => a,
        NpyArray::U16(a) => a.mapv(f64::from),
    })
}

fn median(v: &[f64]) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if s.is_empty() {
        return f64::NAN;
    }
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        (s[n / 2 - 1] + s[n / 2]) / 2.0
    }
}

fn sigma(v: &[f64]) -> f64 {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt()
}

/// The offset (FPN) part: σ of the dark level and hot pixels.
pub(crate) fn offset_checks(dir: &Path, l: &Limits) -> Result<Vec<PartCheck>, StationError> {
    let v = read_part(dir, CalibPart::Offset)?;
    let m = median(&v);
    let hot = v
        .iter()
        .filter(|x| (*x - m).abs() > l.hot_pixel_lsb)
        .count();
    Ok(vec![
        PartCheck::new(
            "offset",
            "FPN σ",
            (sigma(&v), "LSB"),
            (None, Some(l.fpn_sigma_lsb)),
            "the dark level varies more than the ADC's range allows for: the module's readout is out of specification",
        ),
        PartCheck::new(
            "offset",
            "hot pixels",
            (hot as f64, "pixels"),
            (None, Some(l.hot_pixels as f64)),
            "pixels whose dark level departs from the median by more than limits.hot_pixel_lsb: a damaged or contaminated array",
        ),
    ])
}

/// A wiggling table's peak-to-peak in mm of radial distance (eq. 2.6).
pub(crate) fn wiggling_check(
    dir: &Path,
    part: CalibPart,
    modulation_hz: f64,
    l: &Limits,
) -> Result<PartCheck, StationError> {
    let v = read_part(dir, part)?;
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let mm = phase_to_distance_m(hi - lo, modulation_hz) * 1e3;
    Ok(PartCheck::new(
        part.name(),
        "wiggling peak-to-peak",
        (mm, "mm"),
        (None, Some(l.wiggling_p2p_mm)),
        "the correlation is far from the module's design (illumination or modulation driver): the table corrects it, but a module this far off is not the product",
    ))
}

/// An FPPN map's σ in mm (eq. 2.6).
pub(crate) fn fppn_check(
    dir: &Path,
    part: CalibPart,
    modulation_hz: f64,
    l: &Limits,
) -> Result<PartCheck, StationError> {
    let v = read_part(dir, part)?;
    let mm = phase_to_distance_m(sigma(&v), modulation_hz) * 1e3;
    Ok(PartCheck::new(
        part.name(),
        "FPPN σ",
        (mm, "mm"),
        (None, Some(l.fppn_sigma_mm)),
        "the per-pixel delays spread more than the array's specification (or the wall was not flat / not perpendicular)",
    ))
}

/// The amplitude scale: median K and dead pixels.
pub(crate) fn amplitude_checks(dir: &Path, l: &Limits) -> Result<Vec<PartCheck>, StationError> {
    let v = read_part(dir, CalibPart::Amplitude)?;
    let m = median(&v);
    let dead = v
        .iter()
        .filter(|x| x.is_nan() || **x < l.dead_pixel_fraction * m)
        .count();
    Ok(vec![
        PartCheck::new(
            "amplitude",
            "median K",
            (m, "LSB·m²/µs"),
            (Some(l.amplitude_k[0]), Some(l.amplitude_k[1])),
            "the module returns too little (weak VCSEL, dirty or misplaced lens, wrong target) or too much light (target reflectivity or distance not as the station file says)",
        ),
        PartCheck::new(
            "amplitude",
            "dead pixels",
            (dead as f64, "pixels"),
            (None, Some(l.dead_pixels as f64)),
            "pixels whose K is below limits.dead_pixel_fraction of the median: dead or shadowed pixels",
        ),
    ])
}

/// The cover window's crosstalk level: median over the pixels of its 4-phase amplitude
/// (eq. 2.4) in LSB per µs of exposure.
pub(crate) fn crosstalk_check(dir: &Path, limit: f64) -> Result<PartCheck, StationError> {
    let x = read_crosstalk(dir)?;
    let shape = x.shape().to_vec();
    let per_image: usize = shape.iter().skip(1).product();
    let flat: Vec<f64> = x.iter().copied().collect();
    let amp: Vec<f64> = if shape.first() == Some(&4) {
        (0..per_image)
            .map(|p| {
                amplitude_4phase(
                    flat[p],
                    flat[per_image + p],
                    flat[2 * per_image + p],
                    flat[3 * per_image + p],
                )
            })
            .collect()
    } else {
        vec![f64::NAN]
    };
    Ok(PartCheck::new(
        "crosstalk",
        "cover-window crosstalk",
        (median(&amp), "LSB/µs"),
        (None, Some(limit)),
        "the cover window reflects more light back than the product allows: a wrong, scratched or smudged window, a missing gasket or ink, or a misplaced module; compensation would leave weak far targets short",
    ))
}
