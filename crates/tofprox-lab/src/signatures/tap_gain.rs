//! Tap gain mismatch (2.2.2, eq. 2.1): signature, and its mapping onto
//! `[effects.tap_gain_mismatch]` of a model file.

use tofprox_model::ModelConfig;
use tofprox_model::effects;
use tofprox_model::effects::correlation::Correlation;
use tofprox_model::effects::tap_gain_mismatch as p;

use super::{Fitted, LabEffect, Signature, WriteCtx, Writer, code_per_e, contrast, write_ambient};
use crate::prepared::{CapInfo, Prepared};
use crate::sample::Rec;
use crate::spec::LabSpec;
use crate::waveform::Waveform;

/// s: LSB per LSB of fundamental amplitude.
const SIGNAL_SHARE: &str = "signal_share";
/// b: LSB per klux·ms of background (ambient light varying).
const AMBIENT: &str = "ambient_lsb_per_klux_ms";

/// The lab module of `tap_gain_mismatch`.
pub(super) struct Effect;

impl LabEffect for Effect {
    fn signature(&self, prep: &Prepared, _: &LabSpec, _: &Waveform) -> Box<dyn Signature> {
        Box::new(TapGain {
            ambient_varies: prep.ambient_varies,
        })
    }

    /// Δ = ε/2 · total charge; the lab's A is the fundamental amplitude,
    /// total = A · peak(C)/contrast (C with fundamental 1): ε = 2·s·K/peak.
    /// Under varying ambient light the fit measured b = ε·N_amb[e per
    /// klux·ms]·lsb_per_e (see [`Effect::held`]): the model's ambient
    /// responsivity b/(ε·1000·lsb_per_e) is written too, or the file held
    /// would leak the file's own (typical) background instead of the measured.
    fn write(&self, fitted: &Fitted, m: &mut ModelConfig, ctx: &WriteCtx<'_>) -> Vec<String> {
        let mut w = Writer::new(m);
        let Some(sh) = fitted.get(SIGNAL_SHARE) else {
            return w.notes;
        };
        let (k, peak) = (contrast(w.m), ctx.model.waveform.peak());
        let eps = 2.0 * sh * k / peak;
        w.set(p::MISMATCH_REL, eps);
        let lsb_per_e = code_per_e(w.m);
        if let Some(b) = fitted.get(AMBIENT)
            && eps.abs() > 1e-9
            && lsb_per_e > 0.0
        {
            let v = b / (eps * 1000.0 * lsb_per_e);
            if v > 0.0 {
                write_ambient(
                    &mut w,
                    v,
                    "the tap-gain fit's background leak ambient_lsb_per_klux_ms over the written mismatch and the file's conversion gain",
                );
            }
        }
        w.notes
    }

    /// The inverse of [`Effect::write`]: s = ε·peak/(2·contrast); the lab's C
    /// has fundamental 1, the model's peak 1: peak_lab = 1/|a₁|. With varying
    /// ambient light also ε/2 · 2·N_ambient per tap, in LSB per klux·ms.
    fn held(&self, m: &ModelConfig, prep: &Prepared) -> Option<(Vec<f64>, Vec<f64>)> {
        // 0 when the file has no conversion gain (NaN.max(0) is 0)
        let lsb_per_e = code_per_e(m).max(0.0);
        let a1 = Correlation::from_model(m)
            .coefficients()
            .get(1)
            .map_or(1.0, |(a, b)| a.hypot(*b))
            .max(1e-9);
        let eps = m.get(p::MISMATCH_REL);
        let mut lin = vec![eps / (a1 * 2.0 * contrast(m).max(1e-9))];
        if prep.ambient_varies {
            let amb = if m.is_enabled(effects::ambient_light::ID) {
                m.get(effects::ambient_light::E_PER_US_PER_KLUX)
            } else {
                0.0
            };
            lin.push(eps * amb * 1000.0 * lsb_per_e);
        }
        Some((lin, Vec::new()))
    }
}

/// Tap gain mismatch (2.2.2, eq. 2.1): D = (1 + ε/2)N_A − (1 − ε/2)N_B leaks
/// ε/2 of the total charge N_A + N_B into the differential code, the same in
/// every raw image (4-phase cancels it). The total signal charge is
/// proportional to the fundamental amplitude A, the background charge to
/// ambient·t[ms] (times the pixel's response): Δ = s·A + b·ambient·t·g_p/ḡ.
/// lin = [s] (+ [b] when the ambient light varies).
struct TapGain {
    ambient_varies: bool,
}
impl Signature for TapGain {
    fn id(&self) -> &'static str {
        p::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        if self.ambient_varies { 2 } else { 1 }
    }
    fn lin_names(&self) -> Vec<String> {
        let mut v = vec![SIGNAL_SHARE.to_string()];
        if self.ambient_varies {
            v.push(AMBIENT.into());
        }
        v
    }
    fn basis(&self, _: &[f64], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        out[0] = r.a;
        if self.ambient_varies {
            out[1] = cap.ambient_klux * cap.exposure_us * 1e-3 * r.gain_rel;
        }
    }
}
