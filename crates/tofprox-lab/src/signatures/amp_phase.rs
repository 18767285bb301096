//! Amplitude-dependent phase error (2.3.1.2): signature, its phasor law in
//! the lab model, and its mapping onto `[effects.amplitude_phase_error]` of a
//! model file.

use tofprox_model::ModelConfig;
use tofprox_model::catalogue;
use tofprox_model::effects::amplitude_phase_error as p;

use super::{
    Fitted, LabEffect, Signature, TermScope, WriteCtx, Writer, code_per_e, phase_shift_code,
    quantiles,
};
use crate::prepared::{CapInfo, Prepared};
use crate::sample::{Rec, Sample};
use crate::spec::{EffectFit, LabSpec};
use crate::waveform::Waveform;

/// φ0 in rad (the model's `max_rad`).
const PHASE0: &str = "phase0_rad";
/// ln A_ref, A_ref in LSB of fundamental amplitude.
const LN_REFERENCE: &str = "ln_reference_lsb";
/// ln n, the shape exponent.
const LN_SHAPE: &str = "ln_shape";

/// The lab module of `amplitude_phase_error`.
pub(super) struct Effect;

impl LabEffect for Effect {
    fn signature(&self, _: &Prepared, _: &LabSpec, waveform: &Waveform) -> Box<dyn Signature> {
        Box::new(AmpPhase {
            waveform: waveform.clone(),
        })
    }

    /// The lab's law holds φ0 and n in the file's ranges (clamped there, so
    /// written clamped: exp(ln 10) is 10 + 2 ulp); the lab's amplitude is in
    /// codes, the model's in electrons of the differential amplitude:
    /// A[codes] = A[e]·code_per_e.
    fn write(&self, fitted: &Fitted, m: &mut ModelConfig, _: &WriteCtx<'_>) -> Vec<String> {
        let g = |k: &str| fitted.get(k).copied();
        let mut w = Writer::new(m);
        if let Some(v) = g(PHASE0) {
            w.set_in_range(p::MAX_RAD, v);
        }
        if let Some(v) = g(LN_SHAPE) {
            w.set_in_range(p::SHAPE, v.exp());
        }
        let lsb_per_e = code_per_e(w.m);
        if let Some(v) = g(LN_REFERENCE)
            && lsb_per_e > 0.0
        {
            w.set(p::REFERENCE_E, v.exp() / lsb_per_e);
        }
        w.notes
    }

    /// The inverse of [`Effect::write`], where the file has a conversion gain.
    fn held(&self, m: &ModelConfig, _: &Prepared) -> Option<(Vec<f64>, Vec<f64>)> {
        // 0 when the file has no conversion gain (NaN.max(0) is 0)
        let lsb_per_e = code_per_e(m).max(0.0);
        (lsb_per_e > 0.0).then(|| {
            let nl = vec![
                m.get(p::MAX_RAD),
                (m.get(p::REFERENCE_E) * lsb_per_e).max(1e-12).ln(),
                m.get(p::SHAPE).max(1e-6).ln(),
            ];
            (Vec::new(), nl)
        })
    }
}

/// The phase shift (rad) the fitted effect `e` gives a pixel of amplitude
/// `a_lsb` in capture `cap` (none in dark captures).
pub(super) fn phase_at(e: &EffectFit, cap: &CapInfo, a_lsb: f64) -> f64 {
    if cap.illum && e.nl.len() == 3 {
        AmpPhase::phase_rad(&AmpPhase::law(&e.nl), a_lsb)
    } else {
        0.0
    }
}

/// Amplitude-dependent phase error (2.3.1.2) with the model's own saturating
/// law (`tofprox_model::effects::amplitude_phase_error::amplitude_phase_shape`), applied
/// exactly (the phasor rotated): Δφ = φ0·(s(A/A_ref; n) − 1),
/// s(x; n) = 1 − x/(1 + xⁿ)^(1/n) (n = 1: 1/(1 + x); large A_ref: linear in
/// A, −φ0·A/A_ref). The model's law is φ0·s; the constant −φ0 is a phase
/// common to every sample, which the per-pixel phases take whichever way the
/// law is written, and without it a linear law (φ0 → ∞, φ0/A_ref finite)
/// stays a small rotation. Δ = A·[C(x + Δφ) − C(x)], x = φ − θ.
/// nl = [φ0, ln A_ref, ln n]: the grid over (A_ref, n) takes φ0 from the
/// first-order law A·C′·Δφ (the fast screening, linear in φ0), then
/// Levenberg–Marquardt refines all three with the full law.
struct AmpPhase {
    /// The fitted correlation waveform C.
    waveform: Waveform,
}
impl AmpPhase {
    /// The law's parameters [φ0, A_ref, n] from nl = [φ0, ln A_ref, ln n]:
    /// φ0 held in the model file's range (what `add` can write), A_ref and
    /// n in the lab's ranges — the clamps and exponentials, once per
    /// parameter vector ([`Signature::prepare`]).
    fn law(nl: &[f64]) -> Vec<f64> {
        let (lo, hi) = Self::phase0_range();
        let aref = nl[1].clamp(-5.0, 18.0).exp();
        let n = nl
            .get(2)
            .copied()
            .unwrap_or(0.0)
            .clamp(0.25f64.ln(), 10f64.ln())
            .exp();
        vec![nl[0].clamp(lo, hi), aref, n]
    }
    /// s(A/A_ref; n) − 1 for `law` = [φ0, A_ref, n] ([`AmpPhase::law`]).
    fn shape(law: &[f64], a: f64) -> f64 {
        tofprox_model::effects::amplitude_phase_error::amplitude_phase_shape(
            a.max(0.0) / law[1],
            law[2],
        ) - 1.0
    }
    /// The model file's range of φ0 (`amplitude_phase_error.max_rad`).
    fn phase0_range() -> (f64, f64) {
        // looked up once: the fit asks for every parameter vector
        static RANGE: std::sync::OnceLock<(f64, f64)> = std::sync::OnceLock::new();
        *RANGE.get_or_init(|| {
            catalogue::param_info(p::MAX_RAD).map_or((-0.5, 0.5), |p| (p.min, p.max))
        })
    }
    /// Δφ at amplitude `a` (LSB) for `law` ([`AmpPhase::law`]).
    fn phase_rad(law: &[f64], a: f64) -> f64 {
        law[0] * Self::shape(law, a)
    }
    /// The first-order φ0 at (ln A_ref, ln n): least squares of A·C′·(s − 1)
    /// with the global nuisance shifts on a subsample.
    fn screen(nl: &[f64], recs: &[Sample], prep: &Prepared) -> Option<f64> {
        let law = Self::law(nl);
        let mut acc = tofprox_core::lsq::Normal::zeros(4);
        for s in recs.iter().step_by((recs.len() / 20_000).max(1)) {
            let r = s.rec(prep);
            let j = [
                r.a * r.cd * Self::shape(&law, r.a),
                1.0,
                r.a * r.c,
                r.a * r.cd,
            ];
            acc.add(&j, r.r, r.w);
        }
        acc.symmetrize();
        tofprox_core::lsq::solve_sym(&acc.jtj, &acc.jtr).map(|v| v[0])
    }
}
impl Signature for AmpPhase {
    fn id(&self) -> &'static str {
        p::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        0
    }
    fn lin_names(&self) -> Vec<String> {
        Vec::new()
    }
    fn nl_names(&self) -> Vec<String> {
        vec![PHASE0.into(), LN_REFERENCE.into(), LN_SHAPE.into()]
    }
    fn nl_start(&self) -> Vec<f64> {
        vec![0.0, 5.0, 0.0]
    }
    /// The clamps of [`AmpPhase::law`].
    fn nl_bounds(&self) -> Vec<Option<(f64, f64)>> {
        vec![
            Some(Self::phase0_range()),
            Some((-5.0, 18.0)),
            Some((0.25f64.ln(), 10f64.ln())),
        ]
    }
    fn nl_grid(&self, recs: &[Sample], prep: &Prepared) -> Vec<Vec<f64>> {
        let a: Vec<f64> = recs
            .iter()
            .step_by((recs.len() / 4000).max(1))
            .filter(|r| r.a > 0.0)
            .map(|r| f64::from(r.a))
            .collect();
        let mut refs = quantiles(a, &[0.05, 0.2, 0.5, 0.8, 0.95]);
        // far above every amplitude: the linear regime
        if let Some(&top) = refs.last() {
            refs.extend([10.0 * top, 100.0 * top]);
        }
        let mut g = Vec::new();
        for q in refs {
            for ln_n in [0.0, 2f64.ln(), 4f64.ln()] {
                let mut nl = vec![0.0, q.max(1.0).ln(), ln_n];
                if let Some(phi0) = Self::screen(&nl, recs, prep) {
                    nl[0] = phi0;
                    // beyond the file's range: in the linear regime only
                    // φ0/A_ref counts, so the same law at the range's end
                    let (lo, hi) = Self::phase0_range();
                    let end = phi0.clamp(lo, hi);
                    if end != phi0 && end != 0.0 {
                        g.push(vec![end, nl[1] + (end / phi0).ln(), 10f64.ln()]);
                    }
                    g.push(nl);
                }
            }
        }
        g
    }
    fn basis(&self, _: &[f64], _: &Rec, _: &CapInfo, _: &mut [f64]) {}
    fn prepare(&self, nl: &[f64]) -> Vec<f64> {
        Self::law(nl)
    }
    /// Δφ depends on the pixel's amplitude only: its `powf`s once per pixel
    /// and capture ([`super::FixedMemo`]).
    fn fixed_scope(&self) -> Option<TermScope> {
        Some(TermScope::Pixel)
    }
    fn fixed_term(&self, law: &[f64], r: &Rec, _: &CapInfo) -> f64 {
        Self::phase_rad(law, r.a)
    }
    /// The step of φ0 shares the shape s − 1 (the `powf`s) with the law
    /// before it.
    fn fixed_terms(&self, laws: &[&[f64]], r: &Rec, _: &CapInfo, out: &mut [f64]) {
        let mut prev: Option<(&[f64], f64)> = None;
        for (o, &law) in out.iter_mut().zip(laws) {
            let s = match prev {
                Some((p, s)) if p[1..] == law[1..] => s,
                _ => Self::shape(law, r.a),
            };
            prev = Some((law, s));
            *o = law[0] * s;
        }
    }
    fn fixed_with(&self, _: &[f64], r: &Rec, _: &CapInfo, dphi: f64) -> f64 {
        phase_shift_code(&self.waveform, r, dphi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The prepared laws of a parameter vector and of its finite-difference
    /// steps, evaluated together through the memo (the shape once per pixel),
    /// give the Δcode of Δφ = φ0·(s − 1) with s written as 1 − (1 + x⁻ⁿ)^(−1/n)
    /// and C = cos, each the same to the last bit as the law evaluated alone,
    /// also for the pixel's next raw image (the memo's term reused).
    #[test]
    fn laws_evaluated_together_are_the_phasor_law() {
        let ds = crate::synth::generate(&crate::synth::SynthSpec {
            rows: 2,
            cols: 2,
            ..Default::default()
        });
        let prep = Prepared::new(&ds).unwrap();
        let sig = AmpPhase {
            waveform: Waveform::sinusoid(),
        };
        let (lo, hi) = AmpPhase::phase0_range();
        for phi0 in [0.1, 5.0] {
            let nl = [phi0, 300f64.ln(), 2.5f64.ln()];
            let mut vecs = vec![nl.to_vec()];
            for i in 0..3 {
                let mut v = nl.to_vec();
                v[i] += 1e-4 * nl[i].abs().max(1e-2);
                vecs.push(v);
            }
            let laws: Vec<Vec<f64>> = vecs.iter().map(|v| sig.prepare(v)).collect();
            let refs: Vec<&[f64]> = laws.iter().map(Vec::as_slice).collect();
            let mut memo = super::super::FixedMemo::default();
            for (k, theta) in [1.2, 2.77].into_iter().enumerate() {
                let (a, phi) = (1000.0, 0.7);
                let r = Rec {
                    r: 0.0,
                    w: 1.0,
                    a,
                    phi,
                    theta,
                    c: (phi - theta).cos(),
                    cd: -(phi - theta).sin(),
                    x: 0.0,
                    gain_rel: 1.0,
                    cap: 0,
                    pix: 0,
                    k: k as u16,
                    fold: 0,
                };
                let mut out = [0.0; 4];
                memo.fixed_all(&sig, &refs, &r, &prep.caps[0], &mut out);
                for (v, (law, o)) in vecs.iter().zip(laws.iter().zip(out)) {
                    let (x, n) = (a / v[1].exp(), v[2].exp());
                    let s = 1.0 - (1.0 + x.powf(-n)).powf(-1.0 / n);
                    let dphi = v[0].clamp(lo, hi) * (s - 1.0);
                    let want = a * ((phi - theta + dphi).cos() - (phi - theta).cos());
                    assert!((o - want).abs() < 1e-9, "{v:?}: {o} vs {want}");
                    assert!(want.abs() > 1.0, "{v:?}: {want}");
                    assert_eq!(o.to_bits(), sig.fixed(law, &r, &prep.caps[0]).to_bits());
                }
            }
        }
    }
}
