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

//!
//! This module holds the model and its evaluation (samples, residuals, χ²,
//! the effects' Δcode); its child `solve` the alternating fit ([`fit_model`], [`refine`]). The lab's shared data
//! types live in leaf modules ([`crate::prepared`], [`crate::spec`],
//! [`crate::sample`]) and are re-exported here.

use rayon::prelude::*;
use serde::Serialize;

use crate::error::LabError;
use crate::noise::NoiseModel;
use crate::signatures::{ImageMemo, Signature, make_signature};
use crate::waveform::Waveform;

mod solve;

pub(crate) use crate::prepared::median;
pub use crate::prepared::{CapInfo, FOLDS, Prepared};
pub use crate::sample::{Phasor, Rec, Sample, rotate, theta_rotation};
pub use crate::spec::{EffectFit, LabSpec};
pub(crate) use solve::param_count;
pub use solve::{fit_model, refine, refit_with};

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
