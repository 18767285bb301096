//! Harmonics of the correlation waveform above the fitted order (3.2.2):
//! signature, and its mapping onto `[effects.waveform_harmonics]` of a
//! model file.

use tofprox_model::ModelConfig;
use tofprox_model::effects;
use tofprox_model::effects::waveform_harmonics as p;

use super::{Fitted, LabEffect, Signature, WriteCtx, Writer};
use crate::prepared::{CapInfo, Prepared};
use crate::sample::Rec;
use crate::spec::LabSpec;
use crate::waveform::Waveform;

/// Highest harmonic the extra-harmonics signature reaches (the measured VCSEL/pulse correlation has harmonics up to the 9th, docs/model.md).
pub const MAX_HARMONIC: usize = 9;

/// The lab module of `waveform_harmonics`.
pub(super) struct Effect;

impl LabEffect for Effect {
    fn signature(&self, _: &Prepared, spec: &LabSpec, _: &Waveform) -> Box<dyn Signature> {
        Box::new(Harmonics {
            from: spec.harmonic_order.max(1) + 1,
        })
    }

    fn not_identifiable(&self, _: &Prepared, spec: &LabSpec) -> Option<String> {
        (spec.harmonic_order >= MAX_HARMONIC)
            .then(|| format!("the model already fits harmonics up to {MAX_HARMONIC}"))
    }

    /// The harmonics are the lab model's correlation waveform (the fit
    /// extends it): each written as its relative amplitude and phase.
    fn write(&self, _: &Fitted, m: &mut ModelConfig, ctx: &WriteCtx<'_>) -> Vec<String> {
        let mut w = Writer::new(m);
        for (i, gm) in ctx.model.waveform.gamma.iter().enumerate().skip(1) {
            if let Some((rel, phase)) = effects::waveform_harmonics::harmonic(i + 1) {
                w.set(rel, gm[0].hypot(gm[1]));
                w.set(phase, gm[1].atan2(gm[0]).to_degrees());
            }
        }
        w.notes
    }

    fn in_waveform(&self) -> bool {
        true
    }

    fn widen_spec(&self, spec: &mut LabSpec) {
        spec.harmonic_order = MAX_HARMONIC;
    }

    /// lin = [Re γ_h, Im γ_h] for h from the waveform's order + 1 to
    /// [`MAX_HARMONIC`] (the signature's basis).
    fn extend_waveform(&self, w: &mut Waveform, lin: &[f64]) {
        let from = w.order() + 1;
        for (i, h) in (from..=MAX_HARMONIC).enumerate() {
            while w.gamma.len() < h {
                w.gamma.push([0.0, 0.0]);
            }
            let re = lin.get(2 * i).copied().unwrap_or(0.0);
            let im = lin.get(2 * i + 1).copied().unwrap_or(0.0);
            w.gamma[h - 1] = [re, im];
        }
    }

    fn waveform_params(&self, w: &Waveform) -> Fitted {
        let mut params = Fitted::new();
        for (h, g) in w.gamma.iter().enumerate().skip(1) {
            let [re, im] = coefficient_names(h + 1);
            params.insert(re, g[0]);
            params.insert(im, g[1]);
        }
        params
    }
}

/// The names of harmonic h's fitted coefficients: its real and imaginary part.
fn coefficient_names(h: usize) -> [String; 2] {
    [format!("h{h}_re"), format!("h{h}_im")]
}

/// Highest harmonic the model file describes (1 when waveform_harmonics is off).
pub fn harmonic_order(m: &ModelConfig) -> usize {
    if !m.is_enabled(p::ID) {
        return 1;
    }
    if m.waveforms().is_some() {
        return MAX_HARMONIC;
    }
    (2..=MAX_HARMONIC)
        .rev()
        .find(|h| {
            effects::waveform_harmonics::harmonic(*h).is_some_and(|(rel, _)| m.get(rel).abs() > 0.0)
        })
        .unwrap_or(1)
}

/// Harmonics of the correlation above the fitted order (3.2.2): A·Re[γ_h e^{ih(φ−θ)}].
struct Harmonics {
    from: usize,
}
impl Signature for Harmonics {
    fn id(&self) -> &'static str {
        p::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        2 * (MAX_HARMONIC + 1).saturating_sub(self.from)
    }
    fn lin_names(&self) -> Vec<String> {
        (self.from..=MAX_HARMONIC)
            .flat_map(coefficient_names)
            .collect()
    }
    fn basis(&self, _: &[f64], r: &Rec, _: &CapInfo, out: &mut [f64]) {
        // e^{ihx} by complex multiplication from e^{ix}: one sin_cos per sample
        let (s1, c1) = (r.phi - r.theta).sin_cos();
        let (mut zr, mut zi) = (c1, s1);
        for _ in 1..self.from {
            (zr, zi) = (zr * c1 - zi * s1, zr * s1 + zi * c1);
        }
        for i in 0..=MAX_HARMONIC.saturating_sub(self.from) {
            out[2 * i] = r.a * zr;
            out[2 * i + 1] = -r.a * zi;
            (zr, zi) = (zr * c1 - zi * s1, zr * s1 + zi * c1);
        }
    }
}
