//! The lab module of every model effect that carries a law on the converter's codes
//! (`tofprox_model::effects::CodeLaw`, such as `adc_sar_mismatch`): its signature is that law,
//! Δcode = Σ_j p_j · b_j(k) at the sample's modelled code k, its fitted coefficients are the
//! law's parameters under their own names, written into and read back from the model file
//! as they are. An effect of this kind needs no code in the lab.

use tofprox_model::ModelConfig;
use tofprox_model::effects::{CodeLaw, Effect as ModelEffect};

use super::{Fitted, LabEffect, Signature, WriteCtx, Writer};
use crate::prepared::{CapInfo, Prepared};
use crate::sample::Rec;
use crate::spec::LabSpec;
use crate::waveform::Waveform;

/// The lab module of the model effect `effect`, whose code law is `law`.
pub(super) struct CodeLawEffect {
    pub(super) effect: &'static dyn ModelEffect,
    pub(super) law: &'static dyn CodeLaw,
}

impl LabEffect for CodeLawEffect {
    fn signature(&self, prep: &Prepared, _: &LabSpec, _: &Waveform) -> Box<dyn Signature> {
        // 2^N = 2 · mid: the converter's bits
        let full = (2.0 * prep.mid).round().max(2.0);
        Box::new(CodeLawSignature {
            id: self.effect.id().as_str(),
            law: self.law,
            mid: prep.mid,
            bits: full.log2().round() as u8,
        })
    }

    fn write(&self, fitted: &Fitted, m: &mut ModelConfig, _: &WriteCtx<'_>) -> Vec<String> {
        let mut w = Writer::new(m);
        for &p in self.law.params() {
            if let Some(v) = fitted.get(p.name()) {
                w.set_in_range(p, *v);
            }
        }
        w.notes
    }

    fn held(&self, m: &ModelConfig, _: &Prepared) -> Option<(Vec<f64>, Vec<f64>)> {
        Some((
            self.law.params().iter().map(|&p| m.get(p)).collect(),
            Vec::new(),
        ))
    }
}

/// The code law at the sample's modelled code, round(mid + x) clamped to the rails (the
/// converter's own rounding, `tofprox_model::effects::adc::Adc::transfer`), averaged over the
/// sample's noise at the converter's input: the law is a function of the noisy code, so the
/// mean code a step leaves is the step smoothed by the noise (σ² = 1/w, the lab's noise
/// model), taken at nine equal-probability points of the normal distribution. lin = its
/// parameters.
struct CodeLawSignature {
    id: &'static str,
    law: &'static dyn CodeLaw,
    mid: f64,
    bits: u8,
}

impl Signature for CodeLawSignature {
    fn id(&self) -> &str {
        self.id
    }
    fn n_lin(&self) -> usize {
        self.law.params().len()
    }
    fn lin_names(&self) -> Vec<String> {
        self.law
            .params()
            .iter()
            .map(|p| p.name().to_string())
            .collect()
    }
    fn basis(&self, _: &[f64], r: &Rec, _: &CapInfo, out: &mut [f64]) {
        let max_code = 2.0 * self.mid - 1.0;
        let code = |x: f64| (self.mid + x + 0.5).floor().clamp(0.0, max_code) as u32;
        let sigma = r.w.recip().sqrt();
        if !(sigma > MIN_SIGMA_LSB && sigma.is_finite()) || out.len() > MAX_PARAMS {
            self.law.basis(code(r.x), self.bits, out);
            return;
        }
        out.fill(0.0);
        let mut at = [0.0; MAX_PARAMS];
        let at = &mut at[..out.len()];
        for z in NORMAL_NINTHS {
            self.law.basis(code(r.x + sigma * z), self.bits, at);
            for (o, a) in out.iter_mut().zip(at.iter()) {
                *o += a / NORMAL_NINTHS.len() as f64;
            }
        }
    }
}

/// Below this noise (LSB) the rounding decides alone.
const MIN_SIGMA_LSB: f64 = 0.05;

/// The most parameters a code law has here (a law with more is taken without the noise).
const MAX_PARAMS: usize = 16;

/// The midpoints Φ⁻¹((i + ½)/9), i = 0 … 8, of nine equal-probability slices of N(0, 1).
const NORMAL_NINTHS: [f64; 9] = [
    -1.593219, -0.967422, -0.589456, -0.282216, 0.0, 0.282216, 0.589456, 0.967422, 1.593219,
];
