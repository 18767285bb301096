//! Dark current (2.3.2, eq. 2.17): signature; the model file keeps its own
//! parameters.

use tofprox_model::ModelConfig;
use tofprox_model::effects::dark_current as p;

use super::{Fitted, LabEffect, Signature, WriteCtx, not_written};
use crate::prepared::{CapInfo, Prepared};
use crate::sample::Rec;
use crate::spec::LabSpec;
use crate::waveform::Waveform;

/// LSB of differential offset per ms of exposure at the lab's reference
/// temperature.
const RATE: &str = "lsb_per_ms";

/// The lab module of `dark_current`.
pub(super) struct Effect;

impl LabEffect for Effect {
    fn signature(&self, _: &Prepared, spec: &LabSpec, _: &Waveform) -> Box<dyn Signature> {
        Box::new(Dark {
            doubling_k: spec.dark_doubling_k,
        })
    }

    fn not_identifiable(&self, prep: &Prepared, _: &LabSpec) -> Option<String> {
        (!prep.exposure_varies).then(|| "exposure_us does not vary in the recording".into())
    }

    /// The fit measures the tap mismatch of the dark charge in LSB per ms,
    /// which the model file does not describe as one parameter.
    fn write(&self, _: &Fitted, _: &mut ModelConfig, _: &WriteCtx<'_>) -> Vec<String> {
        vec![not_written(p::ID.as_str())]
    }
}

/// Dark current (2.3.2, eq. 2.17) with the model's law: charge ∝ exposure,
/// doubling every ΔT₂ kelvin (`tofprox_model::effects::dark_current::
/// dark_current_temperature_factor`, ΔT₂ the model's `doubling_c`), whose tap
/// mismatch shifts the differential offset. lin = [LSB per ms at the lab's
/// reference temperature].
struct Dark {
    /// ΔT₂ in K.
    doubling_k: f64,
}
impl Signature for Dark {
    fn id(&self) -> &'static str {
        p::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        1
    }
    fn lin_names(&self) -> Vec<String> {
        vec![RATE.into()]
    }
    fn basis(&self, nl: &[f64], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        let t = self.image_term(nl, r.k, cap).unwrap_or(0.0);
        self.basis_image(nl, r, cap, t, out);
    }
    /// The exposure (ms) times the temperature factor: the same for every
    /// sample of a capture (its `powf` once per raw image).
    fn image_term(&self, _: &[f64], _: u16, cap: &CapInfo) -> Option<f64> {
        Some(
            cap.exposure_us
                * 1e-3
                * tofprox_model::effects::dark_current::dark_current_temperature_factor(
                    cap.temp_rel,
                    self.doubling_k,
                ),
        )
    }
    fn basis_image(&self, _: &[f64], _: &Rec, _: &CapInfo, image: f64, out: &mut [f64]) {
        out[0] = image;
    }
}
