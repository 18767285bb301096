//! The lab model: a fast parametric model of the mean raw code of every pixel
//! in every raw image, fitted to a recording.
//!
//! code = mid + o_p + A·C(φ − θ_k) + Σ_effects Δ, with
//! * o_p per-pixel offset (fpn_offset/adc_offset, thesis 3.3.7.1), started from
//!   the dark captures and refined with all data;
//! * A = g_p · exposure·reflectivity/d² (signal_falloff, prnu; thesis 2.2.1);
//! * φ = 4π f d / c + δ_p (eq. 2.6 inverted; fppn and the global delay);
//! * C the correlation waveform up to the model's harmonic order
//!   (waveform_harmonics; started from the 24-phase correlation capture);
//! * noise var = (a + b·A + c·ambient·t + e·t)/averaged (crate::noise).
//!
//! Saturated capture-pixels (codes near the ADC rails, measured or modelled)
//! are excluded from every fit and statistic.

use rayon::prelude::*;
use serde::Serialize;
use tofprox_core::phasor::distance_to_phase_rad;

use crate::data::Dataset;
use crate::error::LabError;
use crate::noise::{NoiseModel, fit_noise};
use crate::signatures::{ImageMemo, Signature, make_signature};
use crate::waveform::Waveform;
use tofprox_core::lsq::{Normal, solve_sym};

/// Number of cross-validation folds (blocks of distance/condition).
pub const FOLDS: usize = 5;

/// Which parts of the lab model are free, from the model file's enabled effects.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LabSpec {
    /// Highest harmonic of the correlation waveform that is fitted (1 = sinusoid).
    pub harmonic_order: usize,
    /// Fit an offset per pixel (fpn_offset/adc_offset); otherwise one global offset.
    pub per_pixel_offset: bool,
    /// Fit a gain per pixel (prnu); otherwise one global gain.
    pub per_pixel_gain: bool,
    /// Fit a phase offset per pixel (fppn); otherwise one global delay.
    pub per_pixel_phase: bool,
    /// Catalogue effects with a lab signature that the model enables.
    pub effects: Vec<String>,
    /// Effects whose parameters are held at these values (`compare
    /// --hold-effects`: the model file's physics); only the per-pixel and
    /// per-unit parameters are fitted around them.
    pub held: Vec<EffectFit>,
    /// Effects fitted with some of their parameters held (`lab add --hold`,
    /// [`crate::hold`]): per parameter, in `lin` then `nl` order, the value it is held at.
    pub holds: std::collections::BTreeMap<String, crate::hold::HoldMask>,
    /// The dark current's doubling ΔT₂ in K (`dark_current.doubling_c` of the
    /// model file; the registry's typical value by default).
    pub dark_doubling_k: f64,
    /// Effects whose law is the shape form (`crate::shape`): their knots in
    /// the lab's driver units (amplitude: LSB; temperature: °C).
    pub shapes: std::collections::BTreeMap<String, Vec<f64>>,
    /// The model's user effects (`crate::user`), fitted like the enabled
    /// effects: their names are in `effects`.
    pub user_effects: Vec<tofprox_model::effects::user::UserEffect>,
}

impl Default for LabSpec {
    fn default() -> Self {
        Self {
            harmonic_order: 1,
            per_pixel_offset: true,
            per_pixel_gain: true,
            per_pixel_phase: true,
            effects: Vec::new(),
            held: Vec::new(),
            holds: std::collections::BTreeMap::new(),
            dark_doubling_k: tofprox_model::catalogue::typical(
                tofprox_model::ids::dark_current::DOUBLING_C,
            ),
            shapes: std::collections::BTreeMap::new(),
            user_effects: Vec::new(),
        }
    }
}

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

/// Fitted parameters of one effect signature: linear and non-linear parts.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EffectFit {
    /// Catalogue id of the effect.
    pub id: String,
    /// Linear coefficients (see [`Signature::lin_names`]).
    pub lin: Vec<f64>,
    /// Non-linear parameters (see [`Signature::nl_names`]).
    pub nl: Vec<f64>,
}

/// One valid (non-saturated, used) sample with everything a signature needs.
#[derive(Debug, Clone, Copy)]
pub struct Rec {
    /// measured − model (the model of the stage that built the table).
    pub r: f64,
    /// 1/σ².
    pub w: f64,
    /// Modelled amplitude A (LSB), phase φ, image phase θ, C and C' at φ−θ.
    pub a: f64,
    /// Modelled phase φ (rad).
    pub phi: f64,
    /// The raw image's phase shift θ (rad).
    pub theta: f64,
    /// C(φ − θ).
    pub c: f64,
    /// C'(φ − θ).
    pub cd: f64,
    /// Modelled differential code (code − mid) without effects.
    pub x: f64,
    /// The pixel's response relative to the median pixel (PRNU, vignetting).
    pub gain_rel: f64,
    /// Capture index.
    pub cap: u32,
    /// Pixel index in the window.
    pub pix: u32,
    /// Raw image index in the capture.
    pub k: u16,
    /// The capture's cross-validation fold.
    pub fold: u8,
}

/// One valid sample as stored in residual tables: the compact form of a
/// [`Rec`] (44 bytes instead of 88; a full-array sweep has 10⁷ samples).
///
/// f32 where the precision allows: a code, residual or amplitude below 2¹²
/// LSB keeps 2.4·10⁻⁴ LSB (f32's 2⁻²⁴ relative), far below the noise of one
/// acquisition (≥ 0.3 LSB); a phase below 16 rad keeps 10⁻⁶ rad, 0.3 µm of
/// depth at 80 MHz (eq. 2.6). Every sum over samples (χ², normal equations)
/// is accumulated in f64. θ is not stored: it is the capture's phase of raw
/// image `k`.
#[derive(Debug, Clone, Copy)]
pub struct Sample {
    /// measured − model (the model of the stage that built the table).
    pub r: f32,
    /// 1/σ².
    pub w: f32,
    /// Modelled amplitude A (LSB).
    pub a: f32,
    /// Modelled phase φ (rad).
    pub phi: f32,
    /// C(φ − θ).
    pub c: f32,
    /// C'(φ − θ).
    pub cd: f32,
    /// Modelled differential code (code − mid) without effects.
    pub x: f32,
    /// The pixel's response relative to the median pixel.
    pub gain_rel: f32,
    /// Capture index.
    pub cap: u32,
    /// Pixel index in the window.
    pub pix: u32,
    /// Raw image index in the capture.
    pub k: u16,
    /// The capture's cross-validation fold.
    pub fold: u8,
}

impl Sample {
    /// The stored form of a sample's context.
    #[inline]
    pub fn of(r: &Rec) -> Self {
        Self {
            r: r.r as f32,
            w: r.w as f32,
            a: r.a as f32,
            phi: r.phi as f32,
            c: r.c as f32,
            cd: r.cd as f32,
            x: r.x as f32,
            gain_rel: r.gain_rel as f32,
            cap: r.cap,
            pix: r.pix,
            k: r.k,
            fold: r.fold,
        }
    }

    /// The full context of this sample (θ from the capture).
    #[inline]
    pub fn rec(&self, prep: &Prepared) -> Rec {
        Rec {
            r: f64::from(self.r),
            w: f64::from(self.w),
            a: f64::from(self.a),
            phi: f64::from(self.phi),
            theta: prep.caps[self.cap as usize].theta_rad[usize::from(self.k)],
            c: f64::from(self.c),
            cd: f64::from(self.cd),
            x: f64::from(self.x),
            gain_rel: f64::from(self.gain_rel),
            cap: self.cap,
            pix: self.pix,
            k: self.k,
            fold: self.fold,
        }
    }

    /// w·r², in f64.
    #[inline]
    pub fn chi2(&self) -> f64 {
        let r = f64::from(self.r);
        f64::from(self.w) * r * r
    }
}

/// The fitted lab model.
#[derive(Debug, Clone, Serialize)]
pub struct LabModel {
    /// Which parts were free.
    pub spec: LabSpec,
    /// Offset o_p of each pixel from the mid code, LSB.
    pub offset: Vec<f64>,
    /// Gain g_p of each pixel: amplitude in LSB per unit of the signal law.
    pub gain: Vec<f64>,
    /// Phase offset δ_p of each pixel (fppn and the global delay), rad.
    pub phase: Vec<f64>,
    /// The fitted correlation waveform.
    pub waveform: Waveform,
    /// The fitted effect signatures.
    pub effects: Vec<EffectFit>,
    /// The noise model the fit is weighted by.
    pub noise: NoiseModel,
    /// Saturated (c, p), measured or modelled.
    #[serde(skip)]
    pub sat: Vec<bool>,
    /// Number of fitted parameters (for dof and BIC).
    pub n_params: usize,
    /// Median of the per-pixel gains.
    pub gain_median: f64,
}

/// Amplitude A (LSB), phase φ (rad) and noise variance (LSB²) of a pixel in a
/// capture under a lab model ([`LabModel::rec`]: the same for all raw images).
type PixelState = (f64, f64, f64);

/// Progress callback: (stage name, fraction done).
pub type Progress<'a> = &'a (dyn Fn(&str, f64) + Sync);

impl LabModel {
    /// Amplitude a = g_p·law, phase φ_tof + φ_p and noise variance of pixel p in
    /// capture `cap` under this model (effects excluded).
    #[inline]
    fn amp_phase_var(&self, cap: &CapInfo, p: usize) -> PixelState {
        let (f, dphi) = self.phasor_shift(cap, p);
        let a = self.gain[p] * cap.law * f;
        let phi = cap.phi_tof + self.phase[p] + dphi;
        let var = self
            .noise
            .var(a, cap.ambient_klux, cap.exposure_us, cap.averaged);
        (a, phi, var)
    }

    /// The signal gain factor and phase shift (rad) of pixel `p` in capture
    /// `cap` from the fitted effects that act on the phasor
    /// ([`crate::signatures::phasor_shift`]).
    #[inline]
    pub fn phasor_shift(&self, cap: &CapInfo, p: usize) -> (f64, f64) {
        crate::signatures::phasor_shift(
            &self.effects,
            &self.spec.shapes,
            cap,
            self.gain[p] * cap.law,
        )
    }

    /// Build the context of sample (c, k, p) under this model (code effects
    /// excluded; effects on the phasor included in A and φ).
    #[inline]
    pub fn rec(&self, prep: &Prepared, c: usize, k: usize, p: usize) -> Rec {
        let cap = &prep.caps[c];
        let x = cap.phi_tof + self.phasor_shift(cap, p).1 + self.phase[p] - cap.theta_rad[k];
        let (s, co) = x.sin_cos();
        self.rec_at(prep, c, k, p, (co, s), self.amp_phase_var(cap, p))
    }

    /// (A, φ, σ²) of every pixel in capture `cap` (what all its raw images share).
    fn pixel_states(&self, cap: &CapInfo) -> Vec<PixelState> {
        (0..self.phase.len())
            .map(|p| self.amp_phase_var(cap, p))
            .collect()
    }

    /// [`LabModel::rec`] with e^{i(φ−θ_k)} = (cos, sin) given (from
    /// [`rotation`]: one sin_cos per pixel and capture instead of per raw
    /// image) and the pixel's state in the capture (from
    /// [`LabModel::pixel_states`]: once per pixel and capture).
    #[inline]
    fn rec_at(
        &self,
        prep: &Prepared,
        c: usize,
        k: usize,
        p: usize,
        e: (f64, f64),
        (a, phi, var): PixelState,
    ) -> Rec {
        let cap = &prep.caps[c];
        let theta = cap.theta_rad[k];
        let (cv, cd) = if cap.illum {
            self.waveform.eval_at(e.0, e.1)
        } else {
            (0.0, 0.0)
        };
        let x = self.offset[p] + a * cv;
        Rec {
            r: prep.meas[prep.idx(c, k, p)] - prep.mid - x,
            w: 1.0 / var,
            a,
            phi,
            theta,
            c: cv,
            cd,
            x,
            gain_rel: self.gain[p] / self.gain_median.max(1e-12),
            cap: c as u32,
            pix: p as u32,
            k: k as u16,
            fold: cap.fold,
        }
    }

    /// The signatures of this model's effects on `prep`.
    pub fn signatures(&self, prep: &Prepared) -> Result<Vec<Box<dyn Signature>>, LabError> {
        self.effects
            .iter()
            .map(|e| make_signature(&e.id, prep, &self.spec, &self.waveform))
            .collect()
    }

    /// Residual table over valid samples (effects included in the model).
    pub fn records(&self, prep: &Prepared) -> Result<Vec<Sample>, LabError> {
        self.records_of(prep, 1)
    }

    /// Residual table over every `step`-th capture (all when 1), in capture,
    /// raw image, pixel order. Filled in place (one allocation of the exact
    /// size, no per-capture tables).
    pub fn records_of(&self, prep: &Prepared, step: usize) -> Result<Vec<Sample>, LabError> {
        let sigs = self.signatures(prep)?;
        let npix = prep.npix;
        let step = step.max(1);
        // valid samples of each capture: its unsaturated pixels × raw images
        let counts: Vec<usize> = (0..prep.caps.len())
            .map(|c| {
                let cap = &prep.caps[c];
                if !cap.used || c % step != 0 {
                    return 0;
                }
                let valid = self.sat[c * npix..(c + 1) * npix]
                    .iter()
                    .filter(|s| !**s)
                    .count();
                valid * cap.theta_rad.len()
            })
            .collect();
        let blank = Sample {
            r: 0.0,
            w: 0.0,
            a: 0.0,
            phi: 0.0,
            c: 0.0,
            cd: 0.0,
            x: 0.0,
            gain_rel: 0.0,
            cap: 0,
            pix: 0,
            k: 0,
            fold: 0,
        };
        // (written in parallel: 40 MB for 900 captures of 16×16, the main
        // thread's longest serial step when filled alone)
        let mut out = Vec::new();
        (0..counts.iter().sum())
            .into_par_iter()
            .map(|_| blank)
            .collect_into_vec(&mut out);
        let mut parts: Vec<(usize, &mut [Sample])> = Vec::with_capacity(counts.len());
        let mut rest = out.as_mut_slice();
        for (c, &n) in counts.iter().enumerate() {
            let (head, tail) = rest.split_at_mut(n);
            if n > 0 {
                parts.push((c, head));
            }
            rest = tail;
        }
        parts.into_par_iter().for_each(|(c, dst)| {
            let mut i = 0;
            self.residuals_of(prep, &sigs, c, |r| {
                dst[i] = Sample::of(&r);
                i += 1;
            });
        });
        Ok(out)
    }

    /// Every valid sample of capture `c` with its residual (effects
    /// included), in raw image, pixel order.
    #[inline]
    fn residuals_of(
        &self,
        prep: &Prepared,
        sigs: &[Box<dyn Signature>],
        c: usize,
        mut f: impl FnMut(Rec),
    ) {
        let npix = prep.npix;
        let mut eval = DeltaEval::new(sigs, &self.effects);
        let (th, ph) = rotation(self, &prep.caps[c]);
        let states = self.pixel_states(&prep.caps[c]);
        let sat = &self.sat[c * npix..(c + 1) * npix];
        for (k, &et) in th.iter().enumerate() {
            for (p, &e_phi) in ph.iter().enumerate() {
                if sat[p] {
                    continue;
                }
                let mut r = self.rec_at(prep, c, k, p, rotate(e_phi, et), states[p]);
                for i in 0..sigs.len().min(self.effects.len()) {
                    r.r -= eval.one(i, &r, prep);
                }
                f(r);
            }
        }
    }

    /// χ² = Σ w r² over the valid samples (effects included), without building
    /// the residual table.
    pub fn chi2(&self, prep: &Prepared) -> Result<f64, LabError> {
        let sigs = self.signatures(prep)?;
        let parts: Vec<f64> = (0..prep.caps.len())
            .into_par_iter()
            .map(|c| {
                let cap = &prep.caps[c];
                let mut s = 0.0;
                if !cap.used {
                    return s;
                }
                self.residuals_of(prep, &sigs, c, |r| s += r.w * r.r * r.r);
                s
            })
            .collect();
        // summed in capture order: the same result on every run
        Ok(parts.iter().sum())
    }

    /// Modelled code (incl. mid and effects) of sample (c, k, p).
    pub fn predict(
        &self,
        prep: &Prepared,
        sigs: &[Box<dyn Signature>],
        c: usize,
        k: usize,
        p: usize,
    ) -> f64 {
        let r = self.rec(prep, c, k, p);
        let mut eval = DeltaEval::new(sigs, &self.effects);
        let mut v = prep.mid + r.x;
        for i in 0..sigs.len().min(self.effects.len()) {
            v += eval.one(i, &r, prep);
        }
        v
    }
}

/// e^{i(φ − θ)} = (cos, sin) from e^{iφ} = (cφ, sφ) and e^{−iθ} = (cθ, sθ).
#[inline]
pub fn rotate(e_phi: (f64, f64), e_mtheta: (f64, f64)) -> (f64, f64) {
    (
        e_phi.0 * e_mtheta.0 - e_phi.1 * e_mtheta.1,
        e_phi.0 * e_mtheta.1 + e_phi.1 * e_mtheta.0,
    )
}

/// A unit phasor e^{ix} as (cos x, sin x).
pub type Phasor = (f64, f64);

/// e^{−iθ_k} = (cos θ_k, −sin θ_k) of every raw image of a capture.
pub fn theta_rotation(cap: &CapInfo) -> Vec<Phasor> {
    cap.theta_rad
        .iter()
        .map(|t| {
            let (s, c) = t.sin_cos();
            (c, -s)
        })
        .collect()
}

/// Per capture: e^{−iθ_k} of every raw image; per pixel: e^{iφ_p} of the
/// model's phase in that capture. `rotate` of the two gives e^{i(φ−θ_k)}.
pub fn rotation(model: &LabModel, cap: &CapInfo) -> (Vec<Phasor>, Vec<Phasor>) {
    let th = theta_rotation(cap);
    let ph = model
        .phase
        .iter()
        .enumerate()
        .map(|(p, d)| {
            let (s, c) = (cap.phi_tof + model.phasor_shift(cap, p).1 + d).sin_cos();
            (c, s)
        })
        .collect();
    (th, ph)
}

/// Δcode of fitted effects, sample by sample: each effect's per-raw-image
/// terms are computed once per raw image ([`ImageMemo`]) when the samples come
/// in capture, raw-image order.
pub struct DeltaEval<'a> {
    sigs: &'a [Box<dyn Signature>],
    /// Effects on the phasor: already in A and φ, no Δcode added.
    on_phasor: Vec<bool>,
    effects: &'a [EffectFit],
    /// Each effect's prepared law ([`Signature::prepare`]).
    laws: Vec<Vec<f64>>,
    memos: Vec<ImageMemo>,
    buf: Vec<f64>,
}

impl<'a> DeltaEval<'a> {
    /// For the effects `effects` with their signatures `sigs` (same order).
    pub fn new(sigs: &'a [Box<dyn Signature>], effects: &'a [EffectFit]) -> Self {
        Self {
            sigs,
            on_phasor: sigs
                .iter()
                .map(|s| crate::signatures::acts_on_phasor(s.id()))
                .collect(),
            effects,
            laws: sigs
                .iter()
                .zip(effects)
                .map(|(s, e)| s.prepare(&e.nl))
                .collect(),
            memos: vec![ImageMemo::default(); sigs.len()],
            buf: vec![0.0; 64],
        }
    }

    /// Δcode of effect `i` at a sample.
    #[inline]
    pub fn one(&mut self, i: usize, r: &Rec, prep: &Prepared) -> f64 {
        let (sig, e) = (self.sigs[i].as_ref(), &self.effects[i]);
        if self.on_phasor[i] {
            return 0.0;
        }
        let n = sig.n_lin();
        if self.buf.len() < n {
            self.buf.resize(n, 0.0);
        }
        self.memos[i].basis(
            sig,
            &e.nl,
            r,
            &prep.caps[r.cap as usize],
            &mut self.buf[..n],
        );
        let fixed = sig.fixed(&self.laws[i], r, &prep.caps[r.cap as usize]);
        fixed
            + self.buf[..n]
                .iter()
                .zip(&e.lin)
                .map(|(b, l)| b * l)
                .sum::<f64>()
    }

    /// Σ of every effect's Δcode at a sample.
    #[inline]
    pub fn sum(&mut self, r: &Rec, prep: &Prepared) -> f64 {
        (0..self.sigs.len().min(self.effects.len()))
            .map(|i| self.one(i, r, prep))
            .sum()
    }
}

/// Fit the lab model with the given spec to a prepared recording.
pub fn fit_model(
    prep: &Prepared,
    spec: &LabSpec,
    progress: Progress<'_>,
) -> Result<LabModel, LabError> {
    let npix = prep.npix;
    let ncap = prep.caps.len();
    progress("offsets", 0.0);
    // Offsets from the dark captures (thesis 4.3.2.1); else from the mean of
    // the raw images of captures with ≥ 4 phases (the first harmonic cancels).
    let mut offset = vec![0.0; npix];
    let mut cnt = vec![0.0; npix];
    let darks: Vec<usize> = (0..ncap).filter(|&c| !prep.caps[c].illum).collect();
    let src: Vec<usize> = if darks.is_empty() {
        (0..ncap)
            .filter(|&c| prep.caps[c].used && prep.caps[c].theta_rad.len() >= 4)
            .collect()
    } else {
        darks.clone()
    };
    for &c in &src {
        for k in 0..prep.caps[c].theta_rad.len() {
            for p in 0..npix {
                if prep.sat_meas[c * npix + p] {
                    continue;
                }
                offset[p] += prep.meas[prep.idx(c, k, p)] - prep.mid;
                cnt[p] += 1.0;
            }
        }
    }
    for p in 0..npix {
        offset[p] = if cnt[p] > 0.0 {
            offset[p] / cnt[p]
        } else {
            0.0
        };
    }
    // Waveform and per-pixel phase from the correlation capture (the capture
    // with the most phases, ≥ 8), by DFT per pixel.
    let corr = (0..ncap)
        .filter(|&c| prep.caps[c].illum && prep.caps[c].used && prep.caps[c].theta_rad.len() >= 8)
        .max_by_key(|&c| prep.caps[c].theta_rad.len());
    let mut phase = vec![0.0; npix];
    let mut waveform = Waveform::sinusoid();
    let order = spec.harmonic_order.max(1);
    let dft = |c: usize, p: usize, h: usize| -> (f64, f64) {
        let cap = &prep.caps[c];
        let n = cap.theta_rad.len() as f64;
        let mut re = 0.0;
        let mut im = 0.0;
        for (k, th) in cap.theta_rad.iter().enumerate() {
            let u = prep.meas[prep.idx(c, k, p)] - prep.mid - offset[p];
            let (s, co) = (h as f64 * th).sin_cos();
            re += u * co;
            im += u * s;
        }
        (2.0 * re / n, 2.0 * im / n)
    };
    let phase_from = |cs: &[usize], p: usize| -> f64 {
        let (mut sr, mut si) = (0.0, 0.0);
        for &c in cs {
            if prep.sat_meas[c * npix + p] {
                continue;
            }
            let (re, im) = dft(c, p, 1);
            let (s, co) = (-prep.caps[c].phi_tof).sin_cos();
            // rotate by −φ_tof
            sr += re * co - im * s;
            si += re * s + im * co;
        }
        si.atan2(sr)
    };
    if let Some(c) = corr {
        for (p, ph) in phase.iter_mut().enumerate() {
            *ph = phase_from(&[c], p);
        }
        let nh = order.min(prep.caps[c].theta_rad.len() / 2 - 1).max(1);
        let mut gsum = vec![[0.0f64; 2]; nh];
        let mut wsum = 0.0;
        for p in 0..npix {
            if prep.sat_meas[c * npix + p] {
                continue;
            }
            let (r1, i1) = dft(c, p, 1);
            let amp = r1.hypot(i1);
            if amp <= 0.0 {
                continue;
            }
            let phi = i1.atan2(r1);
            for (h0, g) in gsum.iter_mut().enumerate().skip(1) {
                let h = h0 + 1;
                let (rh, ih) = dft(c, p, h);
                // γ_h = X_h / (A e^{i h φ})
                let (s, co) = (-(h as f64) * phi).sin_cos();
                g[0] += (rh * co - ih * s) * amp; // weight by amplitude
                g[1] += (rh * s + ih * co) * amp;
            }
            wsum += amp * amp;
        }
        if wsum > 0.0 {
            waveform.gamma = gsum.iter().map(|g| [g[0] / wsum, g[1] / wsum]).collect();
            waveform.gamma[0] = [1.0, 0.0];
        }
    } else {
        let cs: Vec<usize> = (0..ncap)
            .filter(|&c| prep.caps[c].illum && prep.caps[c].used)
            .collect();
        for (p, ph) in phase.iter_mut().enumerate() {
            *ph = phase_from(&cs, p);
        }
    }
    while waveform.gamma.len() < order {
        waveform.gamma.push([0.0, 0.0]);
    }
    let mut model = LabModel {
        spec: spec.clone(),
        offset,
        gain: vec![1.0; npix],
        phase,
        waveform,
        effects: spec
            .effects
            .iter()
            .map(|id| {
                if let Some(h) = spec.held.iter().find(|h| &h.id == id) {
                    return Ok(h.clone());
                }
                let s = make_signature(id, prep, spec, &Waveform::sinusoid())?;
                Ok(EffectFit {
                    id: id.clone(),
                    lin: vec![0.0; s.n_lin()],
                    nl: s.nl_start(),
                })
            })
            .collect::<Result<_, LabError>>()?,
        noise: NoiseModel::default(),
        sat: prep.sat_meas.clone(),
        n_params: 0,
        gain_median: 1.0,
    };
    // Initial gains: least squares with the shape fixed.
    fit_gain_only(prep, &mut model);
    let rounds = if spec.effects.is_empty() { 4 } else { 8 };
    refine(prep, &mut model, rounds, true, false, progress)?;
    Ok(model)
}

/// Alternating rounds: per-pixel Gauss–Newton, global harmonics, saturation,
/// enabled effects (grid search early unless `warm`), noise (if `noise`).
pub fn refine(
    prep: &Prepared,
    model: &mut LabModel,
    rounds: usize,
    noise: bool,
    warm: bool,
    progress: Progress<'_>,
) -> Result<(), LabError> {
    let npix = prep.npix;
    // Step control (when the noise model is held, χ² values are comparable):
    // a round that ends with a higher χ² than it started from is undone and
    // the refinement stops, so a refit never ends worse than its start.
    let mut last = if noise {
        None
    } else {
        Some((model.chi2(prep)?, model.clone()))
    };
    for round in 0..rounds {
        progress("per-pixel fit", round as f64 / rounds as f64);
        if let Some((chi_prev, prev)) = &mut last
            && round > 0
        {
            let chi = model.chi2(prep)?;
            // NaN counts as worse
            if chi.is_nan() || chi > *chi_prev {
                tracing::debug!("refit round {round}: χ² {chi:.1} > {chi_prev:.1}, step undone");
                *model = prev.clone();
                break;
            }
            *chi_prev = chi;
            *prev = model.clone();
        }
        let delta = effects_delta(prep, model)?;
        for _ in 0..2 {
            per_pixel_step(prep, model, &delta);
        }
        if model.waveform.order() > 1 {
            waveform_step(prep, model, &delta);
        }
        update_saturation(prep, model);
        if !model.effects.is_empty() {
            // full grid search early and once more late; warm refinement between
            let w = warm || (round >= 2 && round + 2 != rounds);
            fit_enabled_effects(prep, model, w)?;
        }
        if noise && (round == 0 || round + 2 == rounds) {
            model.noise = fit_noise(prep, model)?;
        }
    }
    if let Some((chi_prev, prev)) = last {
        let chi = model.chi2(prep)?;
        if chi.is_nan() || chi > chi_prev {
            *model = prev;
        }
    }
    progress("per-pixel fit", 1.0);
    model.n_params = param_count(model, npix);
    Ok(())
}

/// The parameters `model` fits on a window of `npix` pixels: per pixel (or
/// pooled) offset, gain and phase, the waveform's harmonics and the free
/// effects' values.
pub(crate) fn param_count(model: &LabModel, npix: usize) -> usize {
    let spec = &model.spec;
    let pp = |b: bool| if b { npix } else { 1 };
    pp(spec.per_pixel_offset)
        + pp(spec.per_pixel_gain)
        + pp(spec.per_pixel_phase)
        + 2 * (model.waveform.order() - 1)
        + model
            .effects
            .iter()
            .filter(|e| !spec.held.iter().any(|h| h.id == e.id))
            .map(|e| {
                let held = spec
                    .holds
                    .get(&e.id)
                    .map_or(0, |m| m.iter().flatten().count());
                (e.lin.len() + e.nl.len()).saturating_sub(held)
            })
            .sum::<usize>()
}

/// The model `base` with one more effect, started from a candidate fit on top
/// of it (and the global shifts fitted alongside), refined for a few rounds.
pub fn refit_with(
    prep: &Prepared,
    base: &LabModel,
    effect: &EffectFit,
    nuisance: [f64; 3],
    rounds: usize,
) -> Result<LabModel, LabError> {
    let mut m = base.clone();
    if let Some(e) = crate::signatures::waveform_effect(&effect.id) {
        e.widen_spec(&mut m.spec);
        e.extend_waveform(&mut m.waveform, &effect.lin);
    } else {
        m.spec.effects.push(effect.id.clone());
        m.effects.push(effect.clone());
    }
    m.offset.iter_mut().for_each(|o| *o += nuisance[0]);
    m.gain.iter_mut().for_each(|g| *g *= 1.0 + nuisance[1]);
    m.phase.iter_mut().for_each(|p| *p += nuisance[2]);
    refine(prep, &mut m, rounds, false, true, &|_, _| {})?;
    Ok(m)
}

/// Δ of all enabled effects for every sample (zero where not valid).
fn effects_delta(prep: &Prepared, model: &LabModel) -> Result<Vec<f64>, LabError> {
    let mut delta = vec![0.0; prep.meas.len()];
    if model.effects.is_empty() {
        return Ok(delta);
    }
    let sigs = model.signatures(prep)?;
    let npix = prep.npix;
    let parts: Vec<(usize, Vec<f64>)> = (0..prep.caps.len())
        .into_par_iter()
        .filter(|&c| prep.caps[c].used)
        .map(|c| {
            let mut eval = DeltaEval::new(&sigs, &model.effects);
            let kk = prep.caps[c].theta_rad.len();
            let mut v = vec![0.0; kk * npix];
            let (th, ph) = rotation(model, &prep.caps[c]);
            let states = model.pixel_states(&prep.caps[c]);
            for (k, &et) in th.iter().enumerate() {
                for p in 0..npix {
                    let r = model.rec_at(prep, c, k, p, rotate(ph[p], et), states[p]);
                    v[k * npix + p] = eval.sum(&r, prep);
                }
            }
            (c, v)
        })
        .collect();
    for (c, v) in parts {
        let b = prep.base[c];
        delta[b..b + v.len()].copy_from_slice(&v);
    }
    Ok(delta)
}

fn fit_gain_only(prep: &Prepared, model: &mut LabModel) {
    let npix = prep.npix;
    let gains: Vec<f64> = (0..npix)
        .into_par_iter()
        .map(|p| {
            let (mut num, mut den) = (0.0, 0.0);
            for (c, cap) in prep.caps.iter().enumerate() {
                if !cap.illum || !cap.used || model.sat[c * npix + p] {
                    continue;
                }
                let phi = cap.phi_tof + model.phase[p];
                for (k, th) in cap.theta_rad.iter().enumerate() {
                    let (cv, _) = model.waveform.eval(phi - th);
                    let u = prep.meas[prep.idx(c, k, p)] - prep.mid - model.offset[p];
                    num += u * cap.law * cv;
                    den += (cap.law * cv).powi(2);
                }
            }
            if den > 0.0 { num / den } else { 0.0 }
        })
        .collect();
    let med = median(
        &gains
            .iter()
            .copied()
            .filter(|g| *g > 0.0)
            .collect::<Vec<_>>(),
    )
    .unwrap_or(1.0);
    model.gain = gains
        .into_iter()
        .map(|g| if g > 0.0 { g } else { med })
        .collect();
    update_gain_median(model);
}

/// [`LabModel::gain_median`] from the current gains (positive ones; 1 if
/// none): the reference of every `gain_rel`, so that the effects'
/// background terms (ambient light through the pixel's relative response)
/// are in klux·ms, not scaled by the absolute gain in LSB per unit law.
fn update_gain_median(model: &mut LabModel) {
    let positive: Vec<f64> = model.gain.iter().copied().filter(|g| *g > 0.0).collect();
    model.gain_median = median(&positive).unwrap_or(1.0);
}

/// e^{−iθ_k} of every raw image of every capture.
fn theta_rotations(prep: &Prepared) -> Vec<Vec<(f64, f64)>> {
    prep.caps.iter().map(theta_rotation).collect()
}

/// One Gauss–Newton step of (o_p, g_p, δ_p) for every pixel, effects fixed.
fn per_pixel_step(prep: &Prepared, model: &mut LabModel, delta: &[f64]) {
    let npix = prep.npix;
    let m = &*model;
    let rot = theta_rotations(prep);
    let steps: Vec<(Normal, [f64; 3])> = (0..npix)
        .into_par_iter()
        .map(|p| {
            let mut nrm = Normal::zeros(3);
            for (c, cap) in prep.caps.iter().enumerate() {
                if !cap.used || m.sat[c * npix + p] {
                    continue;
                }
                let (a, phi, var) = m.amp_phase_var(cap, p);
                // ∂A/∂g_p: the signal law times the effects' gain on the phasor
                let law = cap.law * m.phasor_shift(cap, p).0;
                let w = 1.0 / var;
                let (s, co) = phi.sin_cos();
                for (k, et) in rot[c].iter().enumerate() {
                    let i = prep.idx(c, k, p);
                    let (cv, cd) = if cap.illum {
                        let (ec, es) = rotate((co, s), *et);
                        m.waveform.eval_at(ec, es)
                    } else {
                        (0.0, 0.0)
                    };
                    let r = prep.meas[i] - delta[i] - prep.mid - m.offset[p] - a * cv;
                    nrm.add_n(&[1.0, law * cv, a * cd], r, w);
                }
            }
            nrm.symmetrize();
            let step = solve_sym(&nrm.jtj, &nrm.jtr)
                .map(|s| [s[0], s[1], s[2]])
                .unwrap_or_else(|| {
                    // no illuminated data: offset only
                    let d = nrm.jtj[0];
                    [if d > 0.0 { nrm.jtr[0] / d } else { 0.0 }, 0.0, 0.0]
                });
            (nrm, step)
        })
        .collect();
    for (p, (_, s)) in steps.iter().enumerate() {
        model.offset[p] += s[0];
        model.gain[p] += s[1];
        model.phase[p] += s[2].clamp(-0.5, 0.5);
    }
    // Parts the model does not make per-pixel are pooled (weighted mean).
    let pool = |vals: &mut Vec<f64>, j: usize| {
        let (mut s, mut w) = (0.0, 0.0);
        for (p, v) in vals.iter().enumerate() {
            let d = steps[p].0.jtj[j * 3 + j];
            s += v * d;
            w += d;
        }
        if w > 0.0 {
            let mean = s / w;
            vals.iter_mut().for_each(|v| *v = mean);
        }
    };
    if !model.spec.per_pixel_offset {
        pool(&mut model.offset, 0);
    }
    if !model.spec.per_pixel_gain {
        pool(&mut model.gain, 1);
    }
    if !model.spec.per_pixel_phase {
        pool(&mut model.phase, 2);
    }
    update_gain_median(model);
}

/// Gauss–Newton step of the global harmonics γ_2..γ_H on all data.
///
/// The Jacobian of harmonic m at a sample is A·(cos mx, −sin mx), x = φ − θ_k
/// (`crate::waveform`), so JᵀWJ holds only products cos mx·cos nx, sin mx·sin nx
/// and cos mx·sin nx: halves of cos and sin of (m ± n)x. It follows from the moments
/// S_j = Σ w·A²·e^{ijx}, j = 0..2H ([`HarmonicMoments`]), and those of a pixel's raw
/// images from e^{ijφ} times the capture's Σ_k e^{−ijθ_k}: once per pixel and capture
/// instead of a 2(H−1)-parameter update per sample. JᵀWr stays a sum over samples.
fn waveform_step(prep: &Prepared, model: &mut LabModel, delta: &[f64]) {
    let npix = prep.npix;
    let order = model.waveform.order();
    let m = &*model;
    // one partial sum per capture, merged in order (deterministic, unlike a
    // rayon fold whose splits depend on thread scheduling)
    let parts: Vec<HarmonicMoments> = (0..prep.caps.len())
        .into_par_iter()
        .map(|c| {
            let mut acc = HarmonicMoments::zeros(order);
            let cap = &prep.caps[c];
            if !cap.used || !cap.illum {
                return acc;
            }
            let rot = theta_rotation(cap);
            let theta_sums = phasor_power_sums(&rot, 2 * order);
            for p in 0..npix {
                if m.sat[c * npix + p] {
                    continue;
                }
                let (a, phi, var) = m.amp_phase_var(cap, p);
                let w = 1.0 / var;
                let (s, co) = phi.sin_cos();
                acc.add_pixel(w * a * a, (co, s), &theta_sums);
                for (k, et) in rot.iter().enumerate() {
                    let i = prep.idx(c, k, p);
                    let (c1, s1) = rotate((co, s), *et);
                    let (cv, _) = m.waveform.eval_at(c1, s1);
                    let r = prep.meas[i] - delta[i] - prep.mid - m.offset[p] - a * cv;
                    acc.add_residual(w, a, r, (c1, s1));
                }
            }
            acc
        })
        .collect();
    let mut total = HarmonicMoments::zeros(order);
    for part in &parts {
        total.merge(part);
    }
    let nrm = total.normal();
    if let Some(s) = solve_sym(&nrm.jtj, &nrm.jtr) {
        for h in 0..order - 1 {
            model.waveform.gamma[h + 1][0] += s[2 * h];
            model.waveform.gamma[h + 1][1] += s[2 * h + 1];
        }
    }
}

/// Σ_k z_kʲ for j = 0..=`top` of the unit phasors `z` (complex powers).
fn phasor_power_sums(z: &[Phasor], top: usize) -> Vec<Phasor> {
    let mut sums = vec![(0.0, 0.0); top + 1];
    for &zk in z {
        let mut p = (1.0, 0.0);
        for s in &mut sums {
            s.0 += p.0;
            s.1 += p.1;
            p = rotate(p, zk);
        }
    }
    sums
}

/// The normal equations of the harmonics γ_2..γ_H ([`waveform_step`]) as the moments
/// S_j = Σ w·A²·e^{ijx} (j = 0..2H) and JᵀWr, χ².
struct HarmonicMoments {
    /// S_j, j = 0..=2H.
    moments: Vec<Phasor>,
    /// JᵀWr: (Σ w·r·A·cos mx, −Σ w·r·A·sin mx) for m = 2..=H.
    jtr: Vec<f64>,
    chi2: f64,
    count: usize,
}

impl HarmonicMoments {
    fn zeros(order: usize) -> Self {
        Self {
            moments: vec![(0.0, 0.0); 2 * order + 1],
            jtr: vec![0.0; 2 * order.saturating_sub(1)],
            chi2: 0.0,
            count: 0,
        }
    }
    /// The moments of a pixel's raw images: w·A²·e^{ijφ}·Σ_k e^{−ijθ_k}
    /// (`theta_sums` from [`phasor_power_sums`] of the e^{−iθ_k}).
    fn add_pixel(&mut self, wa2: f64, e_phi: Phasor, theta_sums: &[Phasor]) {
        let mut p = (wa2, 0.0);
        for (s, t) in self.moments.iter_mut().zip(theta_sums) {
            let v = rotate(p, *t);
            s.0 += v.0;
            s.1 += v.1;
            p = rotate(p, e_phi);
        }
    }
    /// One sample's residual `r` (weight `w`, amplitude `a`, e^{ix} = `z`).
    fn add_residual(&mut self, w: f64, a: f64, r: f64, z: Phasor) {
        let war = w * a * r;
        let mut zm = rotate(z, z);
        for j in self.jtr.chunks_exact_mut(2) {
            j[0] += war * zm.0;
            j[1] -= war * zm.1;
            zm = rotate(zm, z);
        }
        self.chi2 += w * r * r;
        self.count += 1;
    }
    fn merge(&mut self, o: &Self) {
        for (a, b) in self.moments.iter_mut().zip(&o.moments) {
            a.0 += b.0;
            a.1 += b.1;
        }
        for (a, b) in self.jtr.iter_mut().zip(&o.jtr) {
            *a += b;
        }
        self.chi2 += o.chi2;
        self.count += o.count;
    }
    /// JᵀWJ from the moments: with S_{−j} = conj S_j,
    /// Σ w A² cos mx cos nx = ½ Re(S_{m+n} + S_{m−n}),
    /// Σ w A² sin mx sin nx = ½ Re(S_{m−n} − S_{m+n}),
    /// Σ w A² cos mx sin nx = ½ Im(S_{m+n} − S_{m−n}).
    fn normal(&self) -> Normal {
        let n = self.jtr.len();
        let s = |j: i64| {
            let v = self.moments[j.unsigned_abs() as usize];
            if j < 0 { (v.0, -v.1) } else { v }
        };
        let cos_sin = |m: i64, q: i64| 0.5 * (s(m + q).1 - s(m - q).1);
        let mut nrm = Normal::zeros(n);
        for h in 0..n / 2 {
            for g in 0..n / 2 {
                let (mh, mg) = (h as i64 + 2, g as i64 + 2);
                let (sum, diff) = (s(mh + mg).0, s(mh - mg).0);
                nrm.jtj[2 * h * n + 2 * g] = 0.5 * (sum + diff);
                nrm.jtj[(2 * h + 1) * n + 2 * g + 1] = 0.5 * (diff - sum);
                // columns (A cos, −A sin): the mixed products change sign
                nrm.jtj[2 * h * n + 2 * g + 1] = -cos_sin(mh, mg);
                nrm.jtj[(2 * h + 1) * n + 2 * g] = -cos_sin(mg, mh);
            }
        }
        nrm.jtr.copy_from_slice(&self.jtr);
        nrm.chi2 = self.chi2;
        nrm.count = self.count;
        nrm
    }
}

/// Mark capture-pixels whose modelled codes come near the ADC rails.
fn update_saturation(prep: &Prepared, model: &mut LabModel) {
    let npix = prep.npix;
    let margin = prep.margin();
    for (c, cap) in prep.caps.iter().enumerate() {
        if !cap.illum || !cap.used {
            continue;
        }
        for p in 0..npix {
            if prep.sat_meas[c * npix + p] {
                model.sat[c * npix + p] = true;
                continue;
            }
            let a = model.gain[p] * cap.law * model.phasor_shift(cap, p).0;
            let o = prep.mid + model.offset[p];
            model.sat[c * npix + p] = o + a >= prep.max_code - margin || o - a <= margin;
        }
    }
}

/// Re-fit the parameters of the model's enabled effects on its residual.
fn fit_enabled_effects(prep: &Prepared, model: &mut LabModel, warm: bool) -> Result<(), LabError> {
    for i in 0..model.effects.len() {
        if model.spec.held.iter().any(|h| h.id == model.effects[i].id) {
            continue;
        }
        // residual with every other effect included
        let mut tmp = model.clone();
        let this = tmp.effects.remove(i);
        // large recordings: every other capture (repeats come in consecutive
        // pairs, so every condition stays represented)
        let step = if prep.meas.len() > 300_000 { 2 } else { 1 };
        let recs = tmp.records_of(prep, step)?;
        let sig = make_signature(&this.id, prep, &model.spec, &model.waveform)?;
        let start = if warm { Some(&this) } else { None };
        let fitted = crate::candidates::fit_values(sig.as_ref(), &recs, prep, start)?;
        model.effects[i] = EffectFit {
            id: this.id.clone(),
            lin: fitted.lin,
            nl: fitted.nl,
        };
        // the global shifts fitted alongside move the per-pixel parameters
        let nu = fitted.nuisance;
        model.offset.iter_mut().for_each(|o| *o += nu[0]);
        model.gain.iter_mut().for_each(|g| *g *= 1.0 + nu[1]);
        model.phase.iter_mut().for_each(|p| *p += nu[2]);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The harmonics' normal equations from the moments are those of the Jacobian
    /// rows A·(cos mx, −sin mx) summed sample by sample (written here with `cos`
    /// and `sin` of m·x), for raw-image phases that are not evenly spaced.
    #[test]
    fn harmonic_moments_give_the_sampled_normal_equations() {
        let order = 5;
        let thetas = [0.0, 1.1, 2.0, 4.4];
        let rot: Vec<Phasor> = thetas.iter().map(|t: &f64| (t.cos(), -t.sin())).collect();
        let sums = phasor_power_sums(&rot, 2 * order);
        let (mut moments, mut direct) = (HarmonicMoments::zeros(order), Normal::zeros(8));
        for p in 0..7 {
            let (a, phi, w) = (
                50.0 + 30.0 * p as f64,
                0.9 * p as f64 - 2.0,
                0.5 + 0.1 * p as f64,
            );
            moments.add_pixel(w * a * a, (phi.cos(), phi.sin()), &sums);
            for (k, t) in thetas.iter().enumerate() {
                let (x, r) = (phi - t, (p * 4 + k) as f64 * 0.37 - 3.0);
                moments.add_residual(w, a, r, (x.cos(), x.sin()));
                let j: Vec<f64> = (2..=order)
                    .flat_map(|m| [a * (m as f64 * x).cos(), -a * (m as f64 * x).sin()])
                    .collect();
                direct.add(&j, r, w);
            }
        }
        direct.symmetrize();
        let got = moments.normal();
        let scale = direct.jtj.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (g, d) in got.jtj.iter().zip(&direct.jtj) {
            assert!((g - d).abs() < 1e-12 * scale, "{g} vs {d}");
        }
        for (g, d) in got.jtr.iter().zip(&direct.jtr) {
            assert!((g - d).abs() < 1e-9 * d.abs().max(1.0), "{g} vs {d}");
        }
        assert!((got.chi2 - direct.chi2).abs() < 1e-12 * direct.chi2);
        assert_eq!(got.count, 28);
    }
}
