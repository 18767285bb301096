//! ADC integral non-linearity (3.2.1, fig. 3.4): signature, and its mapping
//! onto `[effects.adc_inl]` of a model file.

use tofprox_model::ModelConfig;
use tofprox_model::effects::adc_inl as p;

use super::{Fitted, LabEffect, Signature, WriteCtx, Writer};
use crate::prepared::{CapInfo, Prepared};
use crate::sample::Rec;
use crate::spec::LabSpec;
use crate::waveform::Waveform;

/// I: the bow of the INL in LSB (the model's `inl_lsb`).
const BOW: &str = "inl_bow_lsb";

/// The lab module of `adc_inl`.
pub(super) struct Effect;

impl LabEffect for Effect {
    fn signature(&self, prep: &Prepared, _: &LabSpec, _: &Waveform) -> Box<dyn Signature> {
        Box::new(Inl { mid: prep.mid })
    }

    /// The lab fits the model's shape: its bow is the file's.
    fn write(&self, fitted: &Fitted, m: &mut ModelConfig, _: &WriteCtx<'_>) -> Vec<String> {
        let mut w = Writer::new(m);
        if let Some(v) = fitted.get(BOW) {
            w.set(p::INL_LSB, *v);
        }
        w.notes
    }

    fn held(&self, m: &ModelConfig, _: &Prepared) -> Option<(Vec<f64>, Vec<f64>)> {
        Some((vec![m.get(p::INL_LSB)], Vec::new()))
    }
}

/// ADC integral non-linearity of a differential converter with the model's
/// law (`tofprox_model::effects::adc_inl::inl_shape`, 3.2.1, fig. 3.4): zero at
/// mid and both ends, opposite sign on the two half ranges. lin = [I].
struct Inl {
    mid: f64,
}
impl Signature for Inl {
    fn id(&self) -> &'static str {
        p::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        1
    }
    fn lin_names(&self) -> Vec<String> {
        vec![BOW.into()]
    }
    fn basis(&self, _: &[f64], r: &Rec, _: &CapInfo, out: &mut [f64]) {
        let x = r.x.clamp(-self.mid, self.mid);
        out[0] = tofprox_model::effects::adc_inl::inl_shape(x, 2.0 * self.mid);
    }
}
