//! Multipath: signature, and its mapping onto `[effects.multipath]` of a
//! model file (the signature's parameters are the model file's).

use tofprox_model::ModelConfig;
use tofprox_model::effects::multipath as p;

use super::{Fitted, LabEffect, Signature, WriteCtx, Writer};
use crate::prepared::{CapInfo, Prepared};
use crate::sample::{Rec, Sample};
use crate::spec::LabSpec;
use crate::waveform::Waveform;

/// The lab module of `multipath`.
pub(super) struct Effect;

impl LabEffect for Effect {
    fn signature(&self, prep: &Prepared, _: &LabSpec, waveform: &Waveform) -> Box<dyn Signature> {
        Box::new(Multipath {
            phase_rad_per_m: tofprox_core::phasor::distance_to_phase_rad(1.0, prep.modulation_hz),
            waveform: waveform.clone(),
        })
    }

    fn write(&self, fitted: &Fitted, m: &mut ModelConfig, _: &WriteCtx<'_>) -> Vec<String> {
        let mut w = Writer::new(m);
        for q in [p::RELATIVE_AMPLITUDE, p::EXTRA_PATH_M] {
            if let Some(v) = fitted.get(q.name()) {
                w.set(q, v.abs());
            }
        }
        w.notes
    }

    fn held(&self, m: &ModelConfig, _: &Prepared) -> Option<(Vec<f64>, Vec<f64>)> {
        Some((
            vec![m.get(p::RELATIVE_AMPLITUDE)],
            vec![m.get(p::EXTRA_PATH_M)],
        ))
    }
}

/// Multipath with the model's law: a second return of a·A at the phase
/// offset of an extra round-trip path L
/// (`tofprox_model::effects::multipath::multipath_phase_offset_rad`),
/// Δ = a·A·C(φ + Δφ₂(L) − θ) with the fitted correlation C. In the model
/// file's units: lin = [relative_amplitude a], nl = [extra_path_m L].
struct Multipath {
    /// 4π f / c.
    phase_rad_per_m: f64,
    /// The fitted correlation waveform C.
    waveform: Waveform,
}
impl Signature for Multipath {
    fn id(&self) -> &'static str {
        p::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        1
    }
    fn lin_names(&self) -> Vec<String> {
        vec![p::RELATIVE_AMPLITUDE.name().into()]
    }
    fn nl_names(&self) -> Vec<String> {
        vec![p::EXTRA_PATH_M.name().into()]
    }
    fn nl_start(&self) -> Vec<f64> {
        vec![0.6]
    }
    fn nl_grid(&self, _: &[Sample], _: &Prepared) -> Vec<Vec<f64>> {
        [0.1, 0.2, 0.4, 0.8, 1.6, 3.2]
            .iter()
            .map(|v| vec![*v])
            .collect()
    }
    fn basis(&self, nl: &[f64], r: &Rec, _: &CapInfo, out: &mut [f64]) {
        let dphi = tofprox_model::effects::multipath::multipath_phase_offset_rad(
            self.phase_rad_per_m,
            nl[0].abs(),
        );
        out[0] = r.a * self.waveform.eval(r.phi + dphi - r.theta).0;
    }
}
