//! Temperature drift (thesis 3.1): signature, its phasor law in the lab
//! model, and its mapping onto `[effects.temperature_drift]` of a model file.

use tofprox_model::ModelConfig;
use tofprox_model::effects::temperature_drift as p;
use tofprox_model::effects::temperature_drift::{temperature_drift, temperature_drift_terms};

use super::{Fitted, LabEffect, Signature, TermScope, WriteCtx, Writer, phase_shift_code};
use crate::prepared::{CapInfo, Prepared};
use crate::sample::{Rec, Sample};
use crate::spec::{EffectFit, LabSpec};
use crate::waveform::Waveform;

/// k_g: relative signal gain per K.
const GAIN: &str = "gain_per_k";
/// k_g2: relative signal gain per K².
const GAIN2: &str = "gain_per_k2";
/// k_φ: phase per K.
const PHASE: &str = "phase_rad_per_k";
/// k_φ2: phase per K².
const PHASE2: &str = "phase_rad_per_k2";

/// The lab module of `temperature_drift`.
pub(super) struct Effect;

impl LabEffect for Effect {
    fn signature(
        &self,
        prep: &Prepared,
        spec: &LabSpec,
        waveform: &Waveform,
    ) -> Box<dyn Signature> {
        Box::new(TempDrift {
            // a held model keeps its own law; a fit takes the ΔT² terms only
            // where ≥ 3 temperatures tell them from the linear ones
            second_order: spec.held.iter().any(|h| h.id == p::ID.as_str())
                || distinct_temperatures(prep) >= 3,
            waveform: waveform.clone(),
        })
    }

    fn not_identifiable(&self, prep: &Prepared, _: &LabSpec) -> Option<String> {
        (!prep.temperature_varies).then(|| "temperature_c does not vary in the recording".into())
    }

    /// The second order is fitted when the recording has ≥ 3 temperatures,
    /// else the linear law (0); the reference is the lab's.
    fn write(&self, fitted: &Fitted, m: &mut ModelConfig, ctx: &WriteCtx<'_>) -> Vec<String> {
        let g = |k: &str| fitted.get(k).copied();
        let mut w = Writer::new(m);
        if let Some(v) = g(PHASE) {
            w.set(p::PHASE_MRAD_PER_K, v * 1000.0);
        }
        if let Some(v) = g(GAIN) {
            w.set(p::GAIN_REL_PER_K, v);
        }
        w.set(p::PHASE_MRAD_PER_K2, g(PHASE2).unwrap_or(0.0) * 1000.0);
        w.set(p::GAIN_REL_PER_K2, g(GAIN2).unwrap_or(0.0));
        w.set(p::REFERENCE_C, ctx.prep.temp_ref);
        w.notes
    }

    /// The drift about the lab's reference T_l instead of the file's T_r
    /// (δ = T_l − T_r): k(u + δ) + k2(u + δ)² = const + (k + 2k2δ)u + k2u²;
    /// the constant phase shifts the per-pixel phase (refitted), the constant
    /// gain c0 the per-pixel gain: 1 + G(u + δ) = (1 + c0)·(1 + G′(u)) with
    /// G′'s coefficients divided by 1 + c0. The lab's law is the full one:
    /// nl = phase, lin = gain.
    fn held(&self, m: &ModelConfig, prep: &Prepared) -> Option<(Vec<f64>, Vec<f64>)> {
        let d = prep.temp_ref - m.get(p::REFERENCE_C);
        let (k, k2) = (
            m.get(p::PHASE_MRAD_PER_K) * 1e-3,
            m.get(p::PHASE_MRAD_PER_K2) * 1e-3,
        );
        let (kg, kg2) = (m.get(p::GAIN_REL_PER_K), m.get(p::GAIN_REL_PER_K2));
        let c0 = (1.0 + kg * d + kg2 * d * d).max(1e-9);
        Some((
            vec![(kg + 2.0 * kg2 * d) / c0, kg2 / c0],
            vec![k + 2.0 * k2 * d, k2],
        ))
    }
}

/// The signal gain factor 1 + G (floored at 0 as the simulator does) and the
/// phase shift Δφ (rad) the fitted drift `e` gives capture `cap`, by the
/// model's law (`tofprox_model::effects::temperature_drift::temperature_drift`; lin =
/// gain, nl = phase coefficients).
pub(super) fn gain_phase(e: &EffectFit, cap: &CapInfo) -> (f64, f64) {
    let at = |v: &[f64], i: usize| v.get(i).copied().unwrap_or(0.0);
    let (dphi, g) = temperature_drift(
        cap.temp_rel,
        [at(&e.nl, 0), at(&e.nl, 1)],
        [at(&e.lin, 0), at(&e.lin, 1)],
    );
    ((1.0 + g).max(0.0), dphi)
}

/// Distinct temperatures of the illuminated captures the fit uses.
fn distinct_temperatures(prep: &Prepared) -> usize {
    let mut t: Vec<i64> = prep
        .caps
        .iter()
        .filter(|c| c.illum && c.used)
        .filter_map(|c| c.temperature_c)
        .map(|t| (t * 1e3).round() as i64)
        .collect();
    t.sort_unstable();
    t.dedup();
    t.len()
}

/// Temperature drift (thesis 3.1) with the model's full law
/// (`tofprox_model::effects::temperature_drift::temperature_drift`): the phase shifted by
/// Δφ(ΔT) = k_φ·ΔT (+ k_φ2·ΔT²) and the signal scaled by 1 + G(ΔT),
/// G = k_g·ΔT (+ k_g2·ΔT²), applied exactly — the phasor rotated, not its
/// first-order term A·C′·Δφ (a drift of 0.5 rad leaves A·(1 − cos 0.5) ≈ 0.12·A
/// in that term's residual): Δ = A·(1 + G)·C(x + Δφ) − A·C(x), x = φ − θ.
/// nl = the phase coefficients (refined by Levenberg–Marquardt from the
/// first-order screening, [`TempDrift::screen`]), lin = the gain coefficients.
struct TempDrift {
    /// With the ΔT² terms (identifiable from ≥ 3 distinct temperatures).
    second_order: bool,
    /// The fitted correlation waveform C.
    waveform: Waveform,
}
impl TempDrift {
    fn n_terms(&self) -> usize {
        if self.second_order { 2 } else { 1 }
    }
    /// Δφ(ΔT), by the model's law.
    fn phase(&self, nl: &[f64], cap: &CapInfo) -> f64 {
        let k = [nl[0], nl.get(1).copied().unwrap_or(0.0)];
        temperature_drift(cap.temp_rel, k, [0.0; 2]).0
    }
    /// The fast screening: the first-order law A·C′·Δφ + A·C·G (linear in
    /// every coefficient, with the global nuisance shifts) solved by least
    /// squares on a subsample; its phase coefficients start the full law.
    fn screen(&self, recs: &[Sample], prep: &Prepared) -> Option<Vec<f64>> {
        let n = self.n_terms();
        let mut acc = tofprox_core::lsq::Normal::zeros(2 * n + 3);
        let mut j = vec![0.0; 2 * n + 3];
        for s in recs.iter().step_by((recs.len() / 60_000).max(1)) {
            let r = s.rec(prep);
            let t = temperature_drift_terms(prep.caps[r.cap as usize].temp_rel);
            for i in 0..n {
                j[i] = r.a * r.cd * t[i];
                j[n + i] = r.a * r.c * t[i];
            }
            j[2 * n..].copy_from_slice(&[1.0, r.a * r.c, r.a * r.cd]);
            acc.add(&j, r.r, r.w);
        }
        acc.symmetrize();
        let sol = tofprox_core::lsq::solve_sym(&acc.jtj, &acc.jtr)?;
        Some(sol[..n].to_vec())
    }
}
impl Signature for TempDrift {
    fn id(&self) -> &'static str {
        p::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        self.n_terms()
    }
    fn lin_names(&self) -> Vec<String> {
        let mut v = vec![GAIN.to_string()];
        if self.second_order {
            v.push(GAIN2.into());
        }
        v
    }
    fn nl_names(&self) -> Vec<String> {
        let mut v = vec![PHASE.to_string()];
        if self.second_order {
            v.push(PHASE2.into());
        }
        v
    }
    fn nl_start(&self) -> Vec<f64> {
        vec![0.0; self.n_terms()]
    }
    fn nl_grid(&self, recs: &[Sample], prep: &Prepared) -> Vec<Vec<f64>> {
        let mut g = vec![self.nl_start()];
        if let Some(k) = self.screen(recs, prep) {
            // the first-order fit underestimates a strong drift (sin Δφ < Δφ)
            for f in [1.0, 1.25] {
                g.push(k.iter().map(|v| f * v).collect());
            }
        }
        g
    }
    fn basis(&self, nl: &[f64], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        self.basis_image(nl, r, cap, self.phase(nl, cap), out);
    }
    /// Δφ(ΔT): the same for every sample of a capture.
    fn image_term(&self, nl: &[f64], _: u16, cap: &CapInfo) -> Option<f64> {
        Some(self.phase(nl, cap))
    }
    fn basis_image(&self, _: &[f64], r: &Rec, cap: &CapInfo, dphi: f64, out: &mut [f64]) {
        let c = r.a * self.waveform.eval(r.phi - r.theta + dphi).0;
        for (o, ti) in out.iter_mut().zip(temperature_drift_terms(cap.temp_rel)) {
            *o = c * ti;
        }
    }
    fn fixed_scope(&self) -> Option<TermScope> {
        Some(TermScope::Image)
    }
    fn fixed_term(&self, nl: &[f64], _: &Rec, cap: &CapInfo) -> f64 {
        self.phase(nl, cap)
    }
    fn fixed_with(&self, _: &[f64], r: &Rec, _: &CapInfo, dphi: f64) -> f64 {
        phase_shift_code(&self.waveform, r, dphi)
    }
}
