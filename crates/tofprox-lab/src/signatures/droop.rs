//! VCSEL droop (3.3.7.2): signature, and its mapping onto
//! `[effects.vcsel_droop]` of a model file.

use tofprox_model::ModelConfig;
use tofprox_model::effects::vcsel_droop as p;

use super::{Fitted, LabEffect, Signature, WriteCtx, Writer};
use crate::prepared::{CapInfo, Prepared};
use crate::sample::{Rec, Sample};
use crate::spec::LabSpec;
use crate::waveform::Waveform;

/// D/τ: the droop per unit of τ (τ in ms^β).
const RATE: &str = "droop_rate";
/// ln τ (τ in ms^β).
const LN_TAU: &str = "ln_tau";
/// β: 1 heats by on-time, 0 per image.
const EXPOSURE_POWER: &str = "exposure_power";
/// k₀: 1 when the first image is already drooped.
const FIRST_IMAGE: &str = "first_image_index";

/// The lab module of `vcsel_droop`.
pub(super) struct Effect;

impl LabEffect for Effect {
    fn signature(&self, _: &Prepared, _: &LabSpec, _: &Waveform) -> Box<dyn Signature> {
        Box::new(Droop)
    }

    /// The lab fits the model's law with τ in ms^β: τ_us = 1000·τ.
    fn write(&self, fitted: &Fitted, m: &mut ModelConfig, _: &WriteCtx<'_>) -> Vec<String> {
        let g = |k: &str| fitted.get(k).copied();
        let mut w = Writer::new(m);
        if let (Some(rate), Some(lt)) = (g(RATE), g(LN_TAU)) {
            let tau = lt.exp();
            w.set(p::TAU_US, tau * 1000.0);
            w.set(p::DROOP_REL, rate * tau);
        }
        if let Some(beta) = g(EXPOSURE_POWER) {
            w.set(p::EXPOSURE_POWER, beta.clamp(0.0, 2.0));
        }
        if let Some(k0) = g(FIRST_IMAGE) {
            w.set(p::FIRST_IMAGE_INDEX, k0.clamp(0.0, 8.0));
        }
        w.notes
    }

    fn held(&self, m: &ModelConfig, _: &Prepared) -> Option<(Vec<f64>, Vec<f64>)> {
        let tau = (m.get(p::TAU_US) / 1000.0).max(1e-12);
        let nl = vec![
            tau.ln(),
            m.get(p::EXPOSURE_POWER),
            m.get(p::FIRST_IMAGE_INDEX),
        ];
        Some((vec![m.get(p::DROOP_REL) / tau], nl))
    }
}

/// VCSEL droop (3.3.7.2) with the model's law
/// (`tofprox_model::effects::vcsel_droop::droop_loss`): A_k = A·(1 − D·L_k),
/// L_k = 1 − e^{−(k + k₀)·s/τ}, s = t[ms]^β (τ here in ms^β; β = 1: heating by
/// on-time, β = 0: per image; k₀ = 1: the first image is already drooped).
/// lin = [D/τ], nl = [ln τ, β, k₀].
struct Droop;
impl Signature for Droop {
    fn id(&self) -> &'static str {
        p::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        1
    }
    fn lin_names(&self) -> Vec<String> {
        vec![RATE.into()]
    }
    fn nl_names(&self) -> Vec<String> {
        vec![LN_TAU.into(), EXPOSURE_POWER.into(), FIRST_IMAGE.into()]
    }
    fn nl_start(&self) -> Vec<f64> {
        vec![5.0, 1.0, 0.0]
    }
    /// The clamps of `image_term`.
    fn nl_bounds(&self) -> Vec<Option<(f64, f64)>> {
        vec![Some((-5.0, 9.0)), Some((0.0, 2.0)), Some((0.0, 8.0))]
    }
    fn nl_grid(&self, _: &[Sample], _: &Prepared) -> Vec<Vec<f64>> {
        let mut g = Vec::new();
        for k0 in [0.0, 1.0] {
            for beta in [0.0, 1.0] {
                for lt in [-1.0, 0.0, 1.0, 2.0, 3.0, 6.0] {
                    g.push(vec![lt, beta, k0]);
                }
            }
        }
        g
    }
    fn basis(&self, nl: &[f64], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        let t = self.image_term(nl, r.k, cap).unwrap_or(0.0);
        self.basis_image(nl, r, cap, t, out);
    }
    /// τ·L_k: the same for every pixel of raw image k.
    fn image_term(&self, nl: &[f64], k: u16, cap: &CapInfo) -> Option<f64> {
        let tau = nl[0].clamp(-5.0, 9.0).exp();
        let beta = nl[1].clamp(0.0, 2.0);
        let k0 = nl.get(2).copied().unwrap_or(0.0).clamp(0.0, 8.0);
        let loss = tofprox_model::effects::vcsel_droop::droop_loss(
            f64::from(k),
            cap.exposure_us,
            1000.0 * tau,
            beta,
            k0,
        );
        Some(tau * loss)
    }
    fn basis_image(&self, _: &[f64], r: &Rec, _: &CapInfo, image: f64, out: &mut [f64]) {
        out[0] = -r.a * r.c * image;
    }
}
