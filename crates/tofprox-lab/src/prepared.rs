//! A recording flattened for fitting: the per-capture facts every stage uses
//! ([`CapInfo`]), the measured codes in one array ([`Prepared`]), the rails
//! (saturated or clipped samples) and the cross-validation folds. A leaf of
//! the lab: it uses only the recording's types.

use tofprox_core::phasor::distance_to_phase_rad;

use crate::data::Dataset;
use crate::error::LabError;

/// Number of cross-validation folds (blocks of distance/condition).
pub const FOLDS: usize = 5;

/// Per-capture facts used by every stage.
#[derive(Debug, Clone)]
pub struct CapInfo {
    /// Phase shift θ_k of each raw image.
    pub theta_rad: Vec<f64>,
    /// The same in degrees, as recorded.
    pub phases_deg: Vec<f64>,
    /// Exposure (integration) time.
    pub exposure_us: f64,
    /// Background illuminance.
    pub ambient_klux: f64,
    /// Sensor temperature, if recorded.
    pub temperature_c: Option<f64>,
    /// temperature − reference (0 when unknown).
    pub temp_rel: f64,
    /// Ground-truth distance, if recorded.
    pub distance_m: Option<f64>,
    /// false: a dark capture.
    pub illum: bool,
    /// Acquisitions averaged into each code.
    pub averaged: u32,
    /// Signal law exposure_ms·reflectivity/d² (0 when dark).
    pub law: f64,
    /// Time-of-flight phase 4πfd/c of the ground-truth distance (eq. 2.6; 0 when unknown).
    pub phi_tof: f64,
    /// Cross-validation fold (0..FOLDS), by block of distance.
    pub fold: u8,
    /// Whether the capture enters the fit (illuminated captures need a distance).
    pub used: bool,
    /// The recording's other numeric conditions, aligned with
    /// [`Prepared::extra_keys`] (NaN where this capture does not state one).
    pub extra: Vec<f64>,
}

/// A recording flattened for fitting: capture c, raw image k, pixel p lives at
/// `base[c] + k·npix + p`.
#[derive(Debug, Clone)]
pub struct Prepared {
    /// Rows of the window.
    pub rows: usize,
    /// Columns of the window.
    pub cols: usize,
    /// Pixels of the window (rows × cols).
    pub npix: usize,
    /// (row, col) of the window's first pixel on the full array.
    pub roi_origin: [usize; 2],
    /// Mid code `2^(adc_bits-1)`.
    pub mid: f64,
    /// Largest code `2^adc_bits - 1`.
    pub max_code: f64,
    /// Modulation frequency.
    pub modulation_hz: f64,
    /// Per-capture facts, in recording order.
    pub caps: Vec<CapInfo>,
    /// Index of each capture's first code in `meas`.
    pub base: Vec<usize>,
    /// Every measured code, capture by capture, image by image, pixel by pixel.
    pub meas: Vec<f64>,
    /// Saturated (c, p) from the measured codes.
    pub sat_meas: Vec<bool>,
    /// Reference temperature: the correlation capture's, else the median.
    pub temp_ref: f64,
    /// Whether temperature varies over the illuminated captures.
    pub temperature_varies: bool,
    /// Whether ambient light varies over the illuminated captures.
    pub ambient_varies: bool,
    /// Whether the exposure varies over the illuminated captures.
    pub exposure_varies: bool,
    /// Illuminated captures without a ground-truth distance (left out of every fit).
    pub skipped_captures: usize,
    /// Names of the recording's other numeric conditions that vary over the
    /// illuminated captures (the user's own keys, e.g. `supply_voltage_v`).
    pub extra_keys: Vec<String>,
}

/// A condition's value as an exact key (µ-units) for grouping equal conditions.
pub(crate) fn key_f(v: f64) -> i64 {
    (v * 1e6).round() as i64
}

impl Prepared {
    /// Validate and flatten a dataset; fails when no illuminated capture has a distance.
    pub fn new(ds: &Dataset) -> Result<Self, LabError> {
        ds.validate()?;
        let npix = ds.sensor.pixels();
        let mid = f64::from(ds.sensor.mid_code());
        let max_code = f64::from(ds.sensor.max_code());
        let margin = (0.0075 * (max_code + 1.0)).max(2.0);
        // Reference temperature: that of the correlation capture, else the median.
        let temps: Vec<f64> = ds.captures.iter().filter_map(|c| c.temperature_c).collect();
        let corr_temp = ds
            .captures
            .iter()
            .find(|c| c.illumination && c.phases_deg.len() >= 8)
            .and_then(|c| c.temperature_c);
        let temp_ref = corr_temp.unwrap_or_else(|| median(&temps).unwrap_or(25.0));
        let varies = |f: &dyn Fn(&crate::data::Capture) -> Option<f64>| {
            let v: Vec<f64> = ds
                .captures
                .iter()
                .filter(|c| c.illumination)
                .filter_map(f)
                .collect();
            let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            hi - lo > 1e-9
        };
        let temperature_varies = varies(&|c| c.temperature_c);
        let ambient_varies = varies(&|c| Some(c.ambient_klux));
        let exposure_varies = varies(&|c| Some(c.exposure_us));
        let mut extra_keys: Vec<String> = ds
            .captures
            .iter()
            .flat_map(|c| c.extra.keys().cloned())
            .collect();
        extra_keys.sort();
        extra_keys.dedup();
        extra_keys.retain(|k| varies(&|c| c.extra.get(k).copied()));
        // Folds over blocks of distance: sorted distinct distances are cut into
        // 2·FOLDS contiguous blocks, block j goes to fold j mod FOLDS.
        let mut dists: Vec<i64> = ds
            .captures
            .iter()
            .filter_map(|c| c.distance_m.map(key_f))
            .collect();
        dists.sort_unstable();
        dists.dedup();
        let nblocks = (2 * FOLDS).min(dists.len().max(1));
        let fold_of = |d: Option<f64>, i: usize| -> u8 {
            match d {
                Some(d) if !dists.is_empty() => {
                    let pos = dists.partition_point(|&x| x < key_f(d));
                    let block = pos * nblocks / dists.len();
                    (block % FOLDS) as u8
                }
                _ => (i % FOLDS) as u8,
            }
        };
        let mut caps = Vec::with_capacity(ds.captures.len());
        let mut base = Vec::with_capacity(ds.captures.len());
        let mut total = 0usize;
        let mut skipped = 0usize;
        for (i, c) in ds.captures.iter().enumerate() {
            let used = !c.illumination || c.distance_m.is_some();
            if !used {
                skipped += 1;
            }
            let law = match (c.illumination, c.distance_m) {
                (true, Some(d)) => c.exposure_us * 1e-3 * c.reflectivity / (d * d), // signal ∝ t·ρ/d² (2.2.1)
                _ => 0.0,
            };
            let phi_tof = c
                .distance_m
                .map(|d| distance_to_phase_rad(d, ds.sensor.modulation_hz)) // eq. 2.6
                .unwrap_or(0.0);
            caps.push(CapInfo {
                theta_rad: c.phases_deg.iter().map(|p| p.to_radians()).collect(),
                phases_deg: c.phases_deg.clone(),
                exposure_us: c.exposure_us,
                ambient_klux: c.ambient_klux,
                temperature_c: c.temperature_c,
                temp_rel: c.temperature_c.map(|t| t - temp_ref).unwrap_or(0.0),
                distance_m: c.distance_m,
                illum: c.illumination,
                averaged: c.averaged,
                law,
                phi_tof,
                fold: fold_of(c.distance_m, i),
                used,
                extra: extra_keys
                    .iter()
                    .map(|k| c.extra.get(k).copied().unwrap_or(f64::NAN))
                    .collect(),
            });
            base.push(total);
            total += c.phases_deg.len() * npix;
        }
        let mut meas = Vec::with_capacity(total);
        for c in &ds.captures {
            meas.extend(c.frames.iter().copied());
        }
        let mut sat_meas = vec![false; caps.len() * npix];
        for (ci, cap) in caps.iter().enumerate() {
            for k in 0..cap.theta_rad.len() {
                for p in 0..npix {
                    let v = meas[base[ci] + k * npix + p];
                    if v >= max_code - margin || v <= margin {
                        sat_meas[ci * npix + p] = true;
                    }
                }
            }
        }
        if !caps.iter().any(|c| c.illum && c.used) {
            return Err(LabError::data(
                "recording has no illuminated capture with a ground-truth distance_m; the lab needs a distance sweep",
            ));
        }
        if let Some(e) = on_the_rails(&caps, (&meas, &base), &sat_meas, npix, (margin, max_code)) {
            return Err(e);
        }
        Ok(Self {
            rows: ds.sensor.rows,
            cols: ds.sensor.cols,
            npix,
            roi_origin: ds.sensor.roi_origin,
            mid,
            max_code,
            modulation_hz: ds.sensor.modulation_hz,
            caps,
            base,
            meas,
            sat_meas,
            temp_ref,
            temperature_varies,
            ambient_varies,
            exposure_varies,
            skipped_captures: skipped,
            extra_keys,
        })
    }

    /// Index in `meas` of capture `c`, raw image `k`, pixel `p`.
    #[inline]
    pub fn idx(&self, c: usize, k: usize, p: usize) -> usize {
        self.base[c] + k * self.npix + p
    }

    /// Depth per radian of phase at the recording's modulation frequency in
    /// mm: c/(4π f) (eq. 2.6).
    pub fn mm_per_rad(&self) -> f64 {
        1000.0 / distance_to_phase_rad(1.0, self.modulation_hz)
    }

    /// Rail margin used for saturation.
    pub fn margin(&self) -> f64 {
        (0.0075 * (self.max_code + 1.0)).max(2.0)
    }
}

/// Why nothing can be fitted when every illuminated sample of the used
/// captures is on a rail of the ADC (a raw image within `margin` LSB of code
/// 0 or of `max_code`: saturated or clipped, [`Prepared::sat_meas`]): the
/// rails named, with the share of the illuminated codes at each. `None`
/// when any sample is valid.
fn on_the_rails(
    caps: &[CapInfo],
    (meas, base): (&[f64], &[usize]),
    sat: &[bool],
    npix: usize,
    (margin, max_code): (f64, f64),
) -> Option<LabError> {
    let lit: Vec<usize> = (0..caps.len())
        .filter(|&c| caps[c].illum && caps[c].used)
        .collect();
    if lit
        .iter()
        .any(|&c| sat[c * npix..(c + 1) * npix].iter().any(|s| !s))
    {
        return None;
    }
    let (mut low, mut high, mut n) = (0usize, 0usize, 0usize);
    for &c in &lit {
        let codes = &meas[base[c]..base[c] + caps[c].theta_rad.len() * npix];
        n += codes.len();
        low += codes.iter().filter(|v| **v <= margin).count();
        high += codes.iter().filter(|v| **v >= max_code - margin).count();
    }
    let pct = |k: usize| 100.0 * k as f64 / n.max(1) as f64;
    Some(LabError::data(format!(
        "no valid samples to fit: every pixel of the {} illuminated captures is on a rail of the \
         ADC in at least one raw image — {:.1} % of their codes at the low rail (0 to {margin:.0} \
         LSB), {:.1} % at the high rail ({:.0} to {max_code:.0} LSB); too much signal or \
         ambient light, a wrong offset, or frames that are not raw codes?",
        lit.len(),
        pct(low),
        pct(high),
        max_code - margin,
    )))
}

pub(crate) fn median(v: &[f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if s.is_empty() {
        return None;
    }
    s.sort_by(|a, b| a.total_cmp(b));
    Some(s[s.len() / 2])
}
