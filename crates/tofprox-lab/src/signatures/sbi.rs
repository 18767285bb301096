//! SBI asymmetry (2.2.2.1, 5.1.2.3, fig. 5.6): signature, and its mapping
//! onto `[effects.sbi_asymmetry]` of a model file.

use tofprox_model::ModelConfig;
use tofprox_model::catalogue;
use tofprox_model::effects;
use tofprox_model::effects::sbi_asymmetry as p;

use super::{Fitted, LabEffect, Signature, WriteCtx, Writer, code_per_e, quantiles, write_ambient};
use crate::prepared::{CapInfo, Prepared};
use crate::sample::{Rec, Sample};
use crate::spec::LabSpec;
use crate::waveform::Waveform;

/// The linear coefficient m: LSB of differential code per lab unit of
/// injected charge.
pub(crate) const MISMATCH: &str = "mismatch_lsb_per_unit";
/// ln q0: the threshold in lab units of tap charge.
const LN_THRESHOLD: &str = "ln_threshold";
/// ln κ: signal charge per unit of fundamental amplitude (ambient light varying).
const LN_SIGNAL_WEIGHT: &str = "ln_signal_weight";
/// The model's clamp share s (0 subtracts, 1 clamps).
const CLAMP_SHARE: &str = "clamp_share";

/// The lab module of `sbi_asymmetry`.
pub(super) struct Effect;

impl LabEffect for Effect {
    fn signature(&self, prep: &Prepared, _: &LabSpec, waveform: &Waveform) -> Box<dyn Signature> {
        Box::new(Sbi::new(prep, waveform))
    }

    /// The lab's tap charges are in its own unit (see [`SbiUnits`]); in
    /// electrons: threshold_e = q0·u, and the differential error
    /// m_lab·N_inj[unit] = −m·N_inj[e]·lsb_per_e gives m = −m_lab/(u·lsb_per_e).
    /// With varying ambient light the fit also measured the model's ambient
    /// responsivity, written too.
    fn write(&self, fitted: &Fitted, m: &mut ModelConfig, ctx: &WriteCtx<'_>) -> Vec<String> {
        let g = |k: &str| fitted.get(k).copied();
        let mut w = Writer::new(m);
        let kappa = g(LN_SIGNAL_WEIGHT).map(f64::exp);
        let Some(units) = SbiUnits::from_fit(w.m, ctx.prep, kappa) else {
            w.notes.push(format!(
                "{}: the model file has no conversion gain (sensor.lsb_per_ke) or no fitted signal weight; the model file keeps its typical values",
                p::ID
            ));
            return w.notes;
        };
        if let Some(lq0) = g(LN_THRESHOLD) {
            w.set(p::THRESHOLD_E, lq0.exp() * units.e_per_unit);
        }
        if let Some(ml) = g(MISMATCH) {
            w.set(p::MISMATCH_REL, -ml / (units.e_per_unit * units.lsb_per_e));
        }
        if let Some(v) = g(CLAMP_SHARE) {
            w.set(p::CLAMP_SHARE, v.clamp(0.0, 1.0));
        }
        if let Some(v) = units.ambient_e_per_us_per_klux() {
            write_ambient(
                &mut w,
                v,
                "the SBI fit's background charge per signal charge, which the written threshold and mismatch are scaled with; it is determined only where background light is a sizeable part of the tap charges at the threshold (with little background the fit trades it against the threshold): check it against an independent measurement before simulating noise with it",
            );
        }
        w.notes
    }

    /// The inverse of [`Effect::write`]: nl = [ln q0, (ln κ when the ambient
    /// light varies), clamp share].
    fn held(&self, m: &ModelConfig, prep: &Prepared) -> Option<(Vec<f64>, Vec<f64>)> {
        let u = SbiUnits::from_model(m, prep)?;
        let mut nl = vec![(m.get(p::THRESHOLD_E) / u.e_per_unit).max(1e-300).ln()];
        if prep.ambient_varies {
            nl.push(u.kappa().ln());
        }
        nl.push(m.get(p::CLAMP_SHARE));
        Some((
            vec![-m.get(p::MISMATCH_REL) * u.e_per_unit * u.lsb_per_e],
            nl,
        ))
    }
}

/// SBI asymmetry (2.2.2.1, 5.1.2.3, fig. 5.6): the taps collect
/// N_a,b = B + κ·A(g ± C)/100 (B = ambient·t[ms]·pixel response, g = peak of
/// C over the contrast 0.8); once the fuller tap passes the threshold q0 the SBI injects the
/// smaller current into both with mismatch, leaving m·N_min·(1 − q0/N_max) in
/// the differential code — nearly the same in every raw image, so 4-phase
/// cancels it and 2-phase does not. The injected charge is the model's family
/// (`tofprox_model::effects::sbi_asymmetry::sbi_injected_e`): clamp share s = 0
/// injects the smaller tap current (subtracts), s = 1 the larger one (clamps
/// the fuller tap at q0). lin = [m], nl = [ln q0, (ln κ), s] (q0 and κ
/// scale-free: their units depend on the sensor over many decades).
pub(crate) struct Sbi {
    ambient_varies: bool,
    /// Total signal charge per unit of fundamental amplitude (1/contrast for a sinusoid).
    g: f64,
}
impl Sbi {
    /// The signature for `prep` with the correlation `waveform`.
    pub(crate) fn new(prep: &Prepared, waveform: &Waveform) -> Self {
        // total signal charge relative to the fundamental amplitude: the
        // correlation's peak over its fundamental, over the registry's
        // typical demodulation contrast (0.8)
        Self {
            ambient_varies: prep.ambient_varies,
            g: waveform.peak() / catalogue::typical(effects::demodulation_contrast::CONTRAST),
        }
    }
    /// Index of the clamp share in `nl`.
    fn clamp_index(&self) -> usize {
        if self.ambient_varies { 2 } else { 1 }
    }
    /// The tap charges N_a, N_b of sample `r` in lab units (`nl[1]` = ln κ
    /// when the ambient light varies; κ = 1 otherwise).
    pub(crate) fn taps(&self, nl: &[f64], r: &Rec, cap: &CapInfo) -> (f64, f64) {
        let kappa = if self.ambient_varies {
            nl.get(1).copied().unwrap_or(0.0).clamp(-20.0, 20.0).exp()
        } else {
            1.0
        };
        // background light passes the same optics: scaled by the pixel's response
        let b = cap.ambient_klux * cap.exposure_us * 1e-3 * r.gain_rel;
        let s = kappa * r.a / 100.0;
        (b + s * (self.g + r.c) / 2.0, b + s * (self.g - r.c) / 2.0)
    }
}
impl Signature for Sbi {
    fn id(&self) -> &'static str {
        p::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        1
    }
    fn lin_names(&self) -> Vec<String> {
        vec![MISMATCH.into()]
    }
    fn nl_names(&self) -> Vec<String> {
        if self.ambient_varies {
            vec![
                LN_THRESHOLD.into(),
                LN_SIGNAL_WEIGHT.into(),
                CLAMP_SHARE.into(),
            ]
        } else {
            vec![LN_THRESHOLD.into(), CLAMP_SHARE.into()]
        }
    }
    fn nl_start(&self) -> Vec<f64> {
        if self.ambient_varies {
            vec![0.0, 0.0, 0.0]
        } else {
            vec![0.0, 0.0]
        }
    }
    /// The clamp share is chosen between the two ends of the family (the
    /// circuit subtracts or clamps); refined freely it absorbs the
    /// approximations of the lab's tap model.
    fn nl_discrete(&self, i: usize) -> bool {
        i == self.clamp_index()
    }
    fn nl_grid(&self, recs: &[Sample], prep: &Prepared) -> Vec<Vec<f64>> {
        let kappas: Vec<f64> = if self.ambient_varies {
            // signal vs ambient charge per unit: unknown over many decades
            // (ambient responsivity, contrast, conversion gain of the sensor)
            vec![
                -6.0, -3.0, -1.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0,
            ]
        } else {
            vec![0.0]
        };
        let mut out = Vec::new();
        for lk in kappas {
            // threshold below every tap: the taps alone
            let nl0 = if self.ambient_varies {
                vec![-60.0, lk]
            } else {
                vec![-60.0]
            };
            let qs: Vec<f64> = recs
                .iter()
                .step_by((recs.len() / 4000).max(1))
                .map(|s| {
                    let r = &s.rec(prep);
                    let (a, b) = self.taps(&nl0, r, &prep.caps[r.cap as usize]);
                    a.max(b)
                })
                .collect();
            for q0 in quantiles(qs, &[0.0, 0.2, 0.4, 0.6, 0.75, 0.85, 0.93]) {
                // subtracting and clamping ends of the family
                for share in [0.0, 1.0] {
                    let mut v = nl0.clone();
                    v[0] = (q0 * 0.999).max(1e-12).ln();
                    v.push(share);
                    out.push(v);
                }
            }
        }
        out
    }
    fn basis(&self, nl: &[f64], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        let (na, nb) = self.taps(nl, r, cap);
        let q0 = nl.first().copied().unwrap_or(0.0).clamp(-60.0, 60.0).exp();
        let share = nl.get(self.clamp_index()).copied().unwrap_or(0.0);
        out[0] = tofprox_model::effects::sbi_asymmetry::sbi_injected_e(na, nb, q0, share);
    }
}
/// The unit of the lab's SBI tap charges in the model's electrons (the
/// `sbi_asymmetry` signature: N = B + κ·A(g ± C)/100 with B in klux·ms and A
/// the fundamental amplitude in LSB; the model: signal electrons per tap
/// A/lsb_per_e·(g ± C)/2 for the lab's contrast 0.8, background
/// e_per_us_per_klux·klux·µs). With ambient light varying, one unit is a
/// klux·ms of background, u = 1000·e_per_us_per_klux electrons, and κ ties it to
/// the signal: κ/100 = 1/(lsb_per_e·u). Without, κ = 1 and u = 100/lsb_per_e.
#[derive(Debug, Clone, Copy)]
struct SbiUnits {
    /// Electrons per lab unit of tap charge.
    e_per_unit: f64,
    /// Codes per electron of differential charge ([`code_per_e`]).
    lsb_per_e: f64,
    /// One unit is a klux·ms of background (the ambient light varies).
    ambient: bool,
}

impl SbiUnits {
    /// [`code_per_e`], if finite and positive.
    fn lsb_per_e(m: &ModelConfig) -> Option<f64> {
        Some(code_per_e(m)).filter(|v| v.is_finite() && *v > 0.0)
    }
    /// From a fit: κ (`ln_signal_weight`) when the ambient light varies.
    fn from_fit(m: &ModelConfig, prep: &Prepared, kappa: Option<f64>) -> Option<Self> {
        let lsb_per_e = Self::lsb_per_e(m)?;
        if prep.ambient_varies {
            let k = kappa.filter(|k| k.is_finite() && *k > 0.0)?;
            let u = 100.0 / (k * lsb_per_e);
            Some(Self {
                e_per_unit: u,
                lsb_per_e,
                ambient: true,
            })
        } else {
            Some(Self {
                e_per_unit: signal_e_per_unit(lsb_per_e),
                lsb_per_e,
                ambient: false,
            })
        }
    }
    /// From the model file: its ambient responsivity when the ambient light
    /// varies (ambient_light must be enabled for the background to reach the
    /// taps).
    fn from_model(m: &ModelConfig, prep: &Prepared) -> Option<Self> {
        let lsb_per_e = Self::lsb_per_e(m)?;
        let u = if prep.ambient_varies {
            if !m.is_enabled(effects::ambient_light::ID) {
                return None;
            }
            1000.0 * m.get(effects::ambient_light::E_PER_US_PER_KLUX)
        } else {
            signal_e_per_unit(lsb_per_e)
        };
        (u.is_finite() && u > 0.0).then_some(Self {
            e_per_unit: u,
            lsb_per_e,
            ambient: prep.ambient_varies,
        })
    }
    /// The model's ambient responsivity these units imply (ambient light
    /// varying): one unit is a klux·ms, u = 1000·e_per_us_per_klux.
    fn ambient_e_per_us_per_klux(&self) -> Option<f64> {
        self.ambient.then_some(self.e_per_unit / 1000.0)
    }
    /// κ of the lab's law for these units (1 without varying ambient light).
    fn kappa(&self) -> f64 {
        100.0 / (self.lsb_per_e * self.e_per_unit)
    }
}

/// Electrons per lab unit of tap charge where the ambient light does not
/// vary (κ = 1: a unit is 100 LSB of fundamental amplitude, [`SbiUnits`]),
/// for `lsb_per_e` codes per electron.
pub(crate) fn signal_e_per_unit(lsb_per_e: f64) -> f64 {
    LSB_PER_UNIT / lsb_per_e
}

/// LSB of fundamental amplitude per lab unit of signal tap charge (κ = 1):
/// the 100 of N = κ·A(g ± C)/100.
pub(crate) const LSB_PER_UNIT: f64 = 100.0;
