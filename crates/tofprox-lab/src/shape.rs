//! The shape form of the effects whose law physics does not fix (issue 20,
//! item 3): the amplitude-phase error Δφ(A), the temperature drift
//! Δφ(T), G(T), the SBI's removed charge R(N_max) and the VCSEL droop's
//! thermal step response Z(τ) (superposed over the duty cycle) as the model's monotone piecewise-linear shape
//! (`tofprox_model::effects::shape`: f(x) = Σ_j v_j·h_j(x), flat outside the
//! knots) — the same evaluation the simulator runs, so what `add` writes is
//! what was fitted.
//!
//! Knots sit at quantiles of the driver in the recording (K ∈
//! [`KNOT_COUNTS`]): the amplitude of the illuminated samples (LSB), the
//! captures' temperatures (°C), the fuller tap's charge (the SBI's lab units,
//! `signatures::sbi`; only where the ambient light does not vary, else its
//! unit is a fitted parameter), the times since the VCSEL's emission
//! switched on or off before each raw image (µs). The value at the first knot is held at 0 (a constant phase or gain
//! is the per-pixel phase and gain's; the SBI starts there; the first raw
//! image is the droop's reference), so the fitted coefficients are the
//! K − 1 others. The droop's loss enters linearly (−A·C·L); the SBI's
//! removed charge is capped by the emptier tap, so its values are
//! non-linear parameters beside the mismatch (their common scale is pinned
//! only where the cap binds; it starts at the clamp R = N_max − N_first). Fitting: the first-order law (A·C′·Δφ
//! for the phase, linear in the hat basis) by least squares as the start,
//! then the full law — the phasor rotated by Δφ, scaled by 1 + G — refined
//! by the candidates' Levenberg–Marquardt path, like the parametric forms.
//!
//! The choice between the parametric form and the shapes (and of K) is
//! `crate::form`'s ([`choose_form`]).

use std::collections::BTreeMap;
use tofprox_model::effects;

use tofprox_model::effects::shape as law;
use tofprox_model::ids::EffectId;

use crate::prepared::{CapInfo, Prepared};
use crate::sample::{Rec, Sample};
use crate::signatures::sbi::{self, Sbi};
use crate::signatures::{Signature, TermScope, phase_shift_code, quantiles};
use crate::spec::EffectFit;
use crate::waveform::Waveform;

pub use crate::form::{
    FORM_Z, FormChoice, FormScore, MIN_REL_GAIN_OVER_PHYSICAL, choose_form, form_margin, form_name,
};

/// The knot counts the shape form is tried with.
pub const KNOT_COUNTS: &[usize] = &[3, 4, 6];

/// The name of the parametric form in reports.
pub const PHYSICAL_FORM: &str = "physical";

/// The name of the shape form with `k` knots in reports.
pub fn shape_form_name(k: usize) -> String {
    format!("shape_{k}_knots")
}

/// Whether effect `id` has a shape form.
pub fn has_shape_form(id: &str) -> bool {
    law::shape_law(id).is_some()
}

/// The most knots a shape the lab fits or holds may have (a model file's
/// shape with more is fitted freely instead).
const MAX_KNOTS: usize = 32;

/// Σ_{j≥1} c_j·(h_j(x) − h_j(x_ref)): the shape with its first value held at
/// 0, relative to the reference driver value (`x_ref = x` gives 0).
fn rel_shape(knots: &[f64], coef: &[f64], x: f64, x_ref: f64) -> f64 {
    let mut w = [0.0; MAX_KNOTS];
    let w = &mut w[..coef.len()];
    rel_weights(knots, x, x_ref, w);
    w.iter().zip(coef).map(|(a, b)| a * b).sum()
}

/// The capture's temperature and the lab's reference temperature (the drift
/// is relative to it; none when the capture states no temperature).
fn temperatures(cap: &CapInfo) -> Option<(f64, f64)> {
    cap.temperature_c.map(|t| (t, t - cap.temp_rel))
}

/// Gain factor and phase shift of the shape form of `e` (knots `knots`) at
/// capture `cap` for a pixel of amplitude `a_lsb` (already drifted for the
/// amplitude-phase error): the `phasor_shift` of `signatures.rs` for shapes.
pub fn shape_phasor(e: &EffectFit, knots: &[f64], cap: &CapInfo, a_lsb: f64) -> (f64, f64) {
    match EffectId::parse(&e.id) {
        Some(effects::temperature_drift::ID) => match temperatures(cap) {
            Some((t, t_ref)) => (
                (1.0 + rel_shape(knots, &e.lin, t, t_ref)).max(0.0),
                rel_shape(knots, &e.nl, t, t_ref),
            ),
            None => (1.0, 0.0),
        },
        Some(effects::amplitude_phase_error::ID) if cap.illum => {
            (1.0, rel_shape(knots, &e.nl, a_lsb.max(0.0), knots[0]))
        }
        _ => (1.0, 0.0),
    }
}

/// The amplitude-phase error as a shape of the amplitude A (LSB):
/// Δ = A·(C(x + Δφ(A)) − C(x)), nl = Δφ at knots 1.. (rad).
struct AmpPhaseShape {
    knots: Vec<f64>,
    waveform: Waveform,
}

/// The temperature drift as shapes of T (°C): Δ = A·(1 + G)·C(x + Δφ) − A·C(x),
/// nl = Δφ at knots 1.. (rad), lin = G at knots 1.. (both relative to the
/// lab's reference temperature).
struct DriftShape {
    knots: Vec<f64>,
    waveform: Waveform,
}

/// One name per knot after the first (the fitted values' names).
fn per_knot(knots: &[f64], name: impl Fn(f64) -> String) -> Vec<String> {
    knots.iter().skip(1).map(|k| name(*k)).collect()
}

/// The hat weights of knots 1.. at `x` minus those at `x_ref`
/// (`out`: one per knot after the first; at most [`MAX_KNOTS`] knots).
fn rel_weights(knots: &[f64], x: f64, x_ref: f64, out: &mut [f64]) {
    let n = knots.len().min(MAX_KNOTS);
    let (mut a, mut b) = ([0.0; MAX_KNOTS], [0.0; MAX_KNOTS]);
    law::hat_weights(&knots[..n], x, &mut a[..n]);
    law::hat_weights(&knots[..n], x_ref, &mut b[..n]);
    for (o, j) in out.iter_mut().zip(1..n) {
        *o = a[j] - b[j];
    }
}

/// The first-order screening of a phase shape: least squares of
/// r = Σ_j v_j·A·C′·w_j + nuisance (offset, gain, phase) on a subsample,
/// w the relative hat weights of the sample's driver.
fn screen_phase(
    n: usize,
    recs: &[Sample],
    prep: &Prepared,
    weights: &dyn Fn(&Rec, &mut [f64]),
) -> Option<Vec<f64>> {
    let cols = |r: &Rec, o: &mut [f64]| {
        weights(r, o);
        o.iter_mut().for_each(|x| *x *= r.a * r.cd);
    };
    screen(n, recs, prep, &cols)
}

/// Least squares of r = Σ_j v_j·b_j + nuisance (offset, gain, phase) on a
/// subsample, `cols` the n columns b_j of a sample: a shape's first-order
/// start.
fn screen(
    n: usize,
    recs: &[Sample],
    prep: &Prepared,
    cols: &dyn Fn(&Rec, &mut [f64]),
) -> Option<Vec<f64>> {
    let mut acc = tofprox_core::lsq::Normal::zeros(n + 3);
    let mut j = vec![0.0; n + 3];
    for s in recs.iter().step_by((recs.len() / 60_000).max(1)) {
        let r = s.rec(prep);
        cols(&r, &mut j[..n]);
        j[n..].copy_from_slice(&[1.0, r.a * r.c, r.a * r.cd]);
        acc.add(&j, r.r, r.w);
    }
    acc.symmetrize();
    let sol = tofprox_core::lsq::solve_sym(&acc.jtj, &acc.jtr)?;
    Some(sol[..n].to_vec())
}

/// The screening's start and a stronger one (sin Δφ < Δφ: the first-order
/// fit underestimates a strong phase).
fn grid_from(start: Option<Vec<f64>>, n: usize) -> Vec<Vec<f64>> {
    let mut g = vec![vec![0.0; n]];
    if let Some(v) = start {
        for f in [1.0, 1.25] {
            g.push(v.iter().map(|x| f * x).collect());
        }
    }
    g
}

impl Signature for AmpPhaseShape {
    fn id(&self) -> &'static str {
        effects::amplitude_phase_error::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        0
    }
    fn lin_names(&self) -> Vec<String> {
        Vec::new()
    }
    fn nl_names(&self) -> Vec<String> {
        per_knot(&self.knots, |k| format!("phase_rad_at_{k:.1}_lsb"))
    }
    fn nl_start(&self) -> Vec<f64> {
        vec![0.0; self.knots.len() - 1]
    }
    fn nl_grid(&self, recs: &[Sample], prep: &Prepared) -> Vec<Vec<f64>> {
        let k0 = self.knots[0];
        let w = |r: &Rec, o: &mut [f64]| rel_weights(&self.knots, r.a, k0, o);
        grid_from(
            screen_phase(self.knots.len() - 1, recs, prep, &w),
            self.knots.len() - 1,
        )
    }
    fn basis(&self, _: &[f64], _: &Rec, _: &CapInfo, _: &mut [f64]) {}
    /// Δφ(A): the same for every raw image of a pixel in a capture.
    fn fixed_scope(&self) -> Option<TermScope> {
        Some(TermScope::Pixel)
    }
    fn fixed_term(&self, nl: &[f64], r: &Rec, _: &CapInfo) -> f64 {
        rel_shape(&self.knots, nl, r.a.max(0.0), self.knots[0])
    }
    fn fixed_with(&self, _: &[f64], r: &Rec, _: &CapInfo, dphi: f64) -> f64 {
        phase_shift_code(&self.waveform, r, dphi)
    }
}

impl DriftShape {
    fn phase(&self, nl: &[f64], cap: &CapInfo) -> f64 {
        temperatures(cap).map_or(0.0, |(t, t_ref)| rel_shape(&self.knots, nl, t, t_ref))
    }
}

impl Signature for DriftShape {
    fn id(&self) -> &'static str {
        effects::temperature_drift::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        self.knots.len() - 1
    }
    fn lin_names(&self) -> Vec<String> {
        per_knot(&self.knots, |k| format!("gain_rel_at_{k:.2}_c"))
    }
    fn nl_names(&self) -> Vec<String> {
        per_knot(&self.knots, |k| format!("phase_rad_at_{k:.2}_c"))
    }
    fn nl_start(&self) -> Vec<f64> {
        vec![0.0; self.knots.len() - 1]
    }
    fn nl_grid(&self, recs: &[Sample], prep: &Prepared) -> Vec<Vec<f64>> {
        let w = |r: &Rec, o: &mut [f64]| match temperatures(&prep.caps[r.cap as usize]) {
            Some((t, t_ref)) => rel_weights(&self.knots, t, t_ref, o),
            None => o.iter_mut().for_each(|x| *x = 0.0),
        };
        grid_from(
            screen_phase(self.knots.len() - 1, recs, prep, &w),
            self.knots.len() - 1,
        )
    }
    fn basis(&self, nl: &[f64], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        self.basis_image(nl, r, cap, self.phase(nl, cap), out);
    }
    /// Δφ(T): the same for every sample of a capture.
    fn image_term(&self, nl: &[f64], _: u16, cap: &CapInfo) -> Option<f64> {
        Some(self.phase(nl, cap))
    }
    fn basis_image(&self, _: &[f64], r: &Rec, cap: &CapInfo, dphi: f64, out: &mut [f64]) {
        let c = r.a * self.waveform.eval(r.phi - r.theta + dphi).0;
        match temperatures(cap) {
            Some((t, t_ref)) => rel_weights(&self.knots, t, t_ref, out),
            None => out.iter_mut().for_each(|x| *x = 0.0),
        }
        out.iter_mut().for_each(|o| *o *= c);
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

/// The SBI as a shape of the fuller tap's charge N_max (lab units, κ = 1,
/// `signatures::sbi`): Δ = −m·[`sbi::LSB_PER_UNIT`]·R(N_a, N_b) with R the
/// model's [`law::sbi_removed_e`] (the curve at N_max, at most N_min) and m
/// the model's `mismatch_rel`, held inside its range; nl = [R at knots 1..
/// (units), m]. Only m·R is pinned where no tap empties: the fit starts at
/// the largest |m| (the least charge removed) and moves from there only
/// where the cap of the emptier tap tells.
struct SbiShape {
    knots: Vec<f64>,
    taps: Sbi,
}

/// The bound of the SBI's mismatch |m| (the model's range; looked up once:
/// the fit asks for every parameter vector).
fn sbi_mismatch_bound() -> f64 {
    static BOUND: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    *BOUND.get_or_init(|| {
        tofprox_model::catalogue::param_info(effects::sbi_asymmetry::MISMATCH_REL)
            .map_or(1.0, |p| p.max.abs().min(p.min.abs()))
    })
}

impl SbiShape {
    /// Δcode at tap charges `taps` for `law` = [`Signature::prepare`] of the
    /// parameters: the removed charge at knots 0.. (the first 0), then m held
    /// in its range.
    #[inline]
    fn delta(&self, law: &[f64], (na, nb): (f64, f64)) -> f64 {
        let n = self.knots.len().min(MAX_KNOTS);
        -law[n] * sbi::LSB_PER_UNIT * law::sbi_removed_e(&self.knots[..n], &law[..n], na, nb)
    }
}

impl Signature for SbiShape {
    fn id(&self) -> &'static str {
        effects::sbi_asymmetry::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        0
    }
    fn lin_names(&self) -> Vec<String> {
        Vec::new()
    }
    fn nl_names(&self) -> Vec<String> {
        let mut v: Vec<String> = per_knot(&self.knots, |k| format!("removed_at_{k:.1}_units"));
        v.push(effects::sbi_asymmetry::MISMATCH_REL.name().into());
        v
    }
    /// The clamp R = N_max − N_first (the parametric family's clamp end with
    /// its threshold at the first knot) and the typical mismatch.
    fn nl_start(&self) -> Vec<f64> {
        let mut v: Vec<f64> = self.knots[1..].iter().map(|k| k - self.knots[0]).collect();
        v.push(tofprox_model::catalogue::typical(
            effects::sbi_asymmetry::MISMATCH_REL,
        ));
        v
    }
    /// The clamp, and the first-order screening of the product m·R (R at
    /// the fuller tap, uncapped) split at |m| = the bound, a third and a
    /// tenth of it.
    fn nl_grid(&self, recs: &[Sample], prep: &Prepared) -> Vec<Vec<f64>> {
        let n = self.knots.len() - 1;
        let cols = |r: &Rec, o: &mut [f64]| {
            let (na, nb) = self.taps.taps(&[], r, &prep.caps[r.cap as usize]);
            rel_weights(&self.knots, na.max(nb), self.knots[0], o);
        };
        let mut g = vec![self.nl_start()];
        let Some(c) = screen(n, recs, prep, &cols) else {
            return g;
        };
        // c = −m·LSB_PER_UNIT·R: R ≥ 0 rising takes the sign of the largest
        let ext = c
            .iter()
            .fold(0.0f64, |m, x| if x.abs() > m.abs() { *x } else { m });
        if ext != 0.0 {
            let r_at_bound =
                law::monotone_projection(&c.iter().map(|x| x / ext).collect::<Vec<_>>());
            let b = sbi_mismatch_bound();
            let m = -ext.signum() * b;
            for f in [1.05, 3.0, 10.0] {
                // R at |m| = b/f: |c|/(b/f·LSB_PER_UNIT)
                let scale = f * ext.abs() / (b * sbi::LSB_PER_UNIT);
                let mut v: Vec<f64> = r_at_bound.iter().map(|u| scale * u.max(0.0)).collect();
                v.push(m / f);
                g.push(v);
            }
        }
        g
    }
    fn basis(&self, _: &[f64], _: &Rec, _: &CapInfo, _: &mut [f64]) {}
    /// nl (values at knots 1.., then m) as [0, values…, m clamped into its
    /// range]: once per parameter vector, not per sample.
    fn prepare(&self, nl: &[f64]) -> Vec<f64> {
        let n = self.knots.len().min(MAX_KNOTS);
        let b = sbi_mismatch_bound();
        let mut law = vec![0.0; n + 1];
        law[1..n].copy_from_slice(&nl[..n - 1]);
        law[n] = nl.get(n - 1).copied().unwrap_or(0.0).clamp(-b, b);
        law
    }
    fn fixed(&self, law: &[f64], r: &Rec, cap: &CapInfo) -> f64 {
        self.delta(law, self.taps.taps(&[], r, cap))
    }
    /// The tap charges once per sample for every law (they do not depend on it).
    fn fixed_all(&self, laws: &[&[f64]], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        let taps = self.taps.taps(&[], r, cap);
        for (o, law) in out.iter_mut().zip(laws) {
            *o = self.delta(law, taps);
        }
    }
}

/// The VCSEL droop as a shape of its thermal step response Z(τ) (µs)
/// superposed over the capture's duty cycle (`vcsel_droop::DutyCycle`):
/// Δ = −A·C·L_k, L_k = Σ sign·Z(τ) over the heating and cooling steps
/// before raw image k — linear in Z's values, so lin = Z at knots 1.. (the
/// first raw image is the reference).
struct DroopShape {
    knots: Vec<f64>,
}

impl Signature for DroopShape {
    fn id(&self) -> &'static str {
        effects::vcsel_droop::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        self.knots.len() - 1
    }
    fn lin_names(&self) -> Vec<String> {
        per_knot(&self.knots, |k| format!("loss_rel_at_{k:.0}_us"))
    }
    fn basis(&self, _: &[f64], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let mut w = [0.0; MAX_KNOTS];
        let w = &mut w[..out.len()];
        cap.duty.for_each_step(usize::from(r.k), |tau_us, sign| {
            rel_weights(&self.knots, tau_us, self.knots[0], w);
            out.iter_mut()
                .zip(w.iter())
                .for_each(|(o, x)| *o += sign * x);
        });
        out.iter_mut().for_each(|o| *o *= -r.a * r.c);
    }
}

/// The shape-form signature of effect `id` with `knots` in the lab's driver
/// units (amplitude: LSB; temperature: °C; tap charge: the SBI's units;
/// on-time: µs); `None` when it has no shape form here (the SBI's where the
/// ambient light varies: its tap charges' unit is then a fitted parameter).
pub fn make_shape_signature(
    id: &str,
    knots: &[f64],
    prep: &Prepared,
    waveform: &Waveform,
) -> Option<Box<dyn Signature>> {
    let knots = knots.to_vec();
    let waveform_ = || waveform.clone();
    match EffectId::parse(id)? {
        effects::amplitude_phase_error::ID => Some(Box::new(AmpPhaseShape {
            knots,
            waveform: waveform_(),
        })),
        effects::temperature_drift::ID => Some(Box::new(DriftShape {
            knots,
            waveform: waveform_(),
        })),
        effects::sbi_asymmetry::ID if !prep.ambient_varies => Some(Box::new(SbiShape {
            knots,
            taps: Sbi::new(prep, waveform),
        })),
        effects::vcsel_droop::ID => Some(Box::new(DroopShape { knots })),
        _ => None,
    }
}

/// `k` knots of effect `id`'s driver in the recording, or `None` when it has
/// fewer than `k` distinct values: the amplitude at evenly spaced quantiles
/// (2 % … 98 %) of its phase information w·A²; the temperature and the
/// on-time at evenly spaced ranks of the illuminated captures' values (the
/// temperature: distinct values, the extremes included, at most as many
/// knots as values; the on-time: `on_time_knots`); the fuller tap's
/// charge like the amplitude, weighted by w·N_max² (none where the ambient
/// light varies).
pub fn knots_at_quantiles(
    id: &str,
    k: usize,
    recs: &[Sample],
    prep: &Prepared,
    waveform: &Waveform,
) -> Option<Vec<f64>> {
    let qs: Vec<f64> = (0..k)
        .map(|i| 0.02 + 0.96 * i as f64 / (k - 1).max(1) as f64)
        .collect();
    match EffectId::parse(id)? {
        effects::amplitude_phase_error::ID => {
            // where the data pin a phase law: its information per sample is
            // w·(A·C′)² ∝ w·A², so the knots sit at quantiles of the
            // amplitude weighted by w·A² (dense where the bright samples are)
            let a: Vec<(f64, f64)> = recs
                .iter()
                .step_by((recs.len() / 20_000).max(1))
                .filter(|r| r.a > 0.0)
                .map(|r| (f64::from(r.a), f64::from(r.w) * f64::from(r.a).powi(2)))
                .collect();
            strictly_increasing(weighted_quantiles(a, &qs), k)
        }
        effects::temperature_drift::ID => ranked(
            prep.caps
                .iter()
                .filter(|c| c.illum && c.used)
                .filter_map(|c| c.temperature_c)
                .collect(),
            k,
        ),
        effects::vcsel_droop::ID => on_time_knots(prep, k),
        effects::sbi_asymmetry::ID if !prep.ambient_varies => {
            // the circuit acts on the fuller taps: the knots sit at quantiles
            // of N_max weighted by w·N_max² (dense where the full taps are,
            // as the amplitude's)
            let taps = Sbi::new(prep, waveform);
            let n_max: Vec<(f64, f64)> = recs
                .iter()
                .step_by((recs.len() / 20_000).max(1))
                .map(|s| s.rec(prep))
                .filter(|r| r.a > 0.0)
                .map(|r| {
                    let (a, b) = taps.taps(&[], &r, &prep.caps[r.cap as usize]);
                    let n = a.max(b);
                    (n, r.w * n * n)
                })
                .collect();
            strictly_increasing(weighted_quantiles(n_max, &qs), k)
        }
        _ => None,
    }
}

/// The `qs` quantiles (increasing) of the values of (value, weight) pairs
/// `a`, each counted by its weight.
fn weighted_quantiles(mut a: Vec<(f64, f64)>, qs: &[f64]) -> Vec<f64> {
    a.sort_by(|x, y| x.0.total_cmp(&y.0));
    let total: f64 = a.iter().map(|x| x.1).sum();
    let mut q = Vec::with_capacity(qs.len());
    let mut acc = 0.0;
    let mut next = qs.iter().peekable();
    for (v, w) in a {
        acc += w;
        while next.peek().is_some_and(|&&l| acc >= l * total) {
            q.push(v);
            next.next();
        }
    }
    q
}

/// Up to `k` knots of the droop's step response from the illuminated raw
/// images of `prep`: the times since each earlier raw image switched on and
/// off at the start of each raw image (`DutyCycle::for_each_step`; without
/// gaps the on-times k·t_exp) — the shortest (0: the first raw image, the
/// reference), then evenly spaced in ln τ from the shortest longer one to
/// the longest (a step response is concave: dense where it rises fastest;
/// on a power law τ^0.4 over 25 recorded times, 6 such knots leave 13×
/// less than 6 at evenly spaced ranks); only times
/// recorded in at least two captures (one that a single capture holds,
/// like a long correlation capture's, has no held-out block to score it:
/// the shape is flat there); at most half as many knots as such times,
/// fewer where they repeat.
fn on_time_knots(prep: &Prepared, k: usize) -> Option<Vec<f64>> {
    let per_cap: Vec<Vec<f64>> = prep
        .caps
        .iter()
        .filter(|c| c.illum && c.used)
        .map(|c| {
            // each time once per capture, to the ns (t_k − t_j − t_exp and
            // t_k − t_j' are the same time up to rounding)
            let mut taus = Vec::new();
            for i in 0..c.phases_deg.len() {
                c.duty
                    .for_each_step(i, |tau_us, _| taus.push((tau_us * 1e3).round() / 1e3));
            }
            taus.sort_by(f64::total_cmp);
            taus.dedup();
            taus
        })
        .collect();
    // captures recording each time (each capture counted once)
    let mut captures_with: BTreeMap<u64, usize> = BTreeMap::new();
    for c in &per_cap {
        let mut bits: Vec<u64> = c.iter().map(|t| t.to_bits()).collect();
        bits.sort_unstable();
        bits.dedup();
        bits.into_iter()
            .for_each(|b| *captures_with.entry(b).or_default() += 1);
    }
    let mut v: Vec<f64> = per_cap
        .iter()
        .flatten()
        .copied()
        .filter(|t| captures_with.get(&t.to_bits()).is_some_and(|n| *n >= 2))
        .collect();
    v.sort_by(f64::total_cmp);
    let first = *v.first()?;
    // at most one knot per two recorded on-times: with few exposures and raw
    // images a knot per on-time would follow each image of each exposure on
    // its own — any residual that differs between raw images, not a droop
    let k = k.min(
        captures_with
            .values()
            .filter(|n| **n >= 2)
            .count()
            .div_ceil(2),
    );
    if k < 2 {
        return None;
    }
    // a heat path's step response rises fastest at first (a diffusive one
    // as √τ, or slower: concave in τ): the knots after the first are
    // evenly spaced in ln τ from the shortest longer time to the longest
    let (lo, hi) = (*v.iter().find(|t| **t > first)?, *v.last()?);
    let mut q = vec![first];
    q.extend((1..k).map(|i| {
        let f = if k > 2 {
            (i - 1) as f64 / (k - 2) as f64
        } else {
            1.0
        };
        (lo * (hi / lo).powf(f) * 1e3).round() / 1e3
    }));
    q.dedup();
    (q.len() >= 2 && law::check_knots(&q).is_ok()).then_some(q)
}

/// `k` knots at evenly spaced ranks of the distinct values `v`: few
/// recorded values make the extremes knots (the law is flat beyond them),
/// the others at evenly spaced ranks; at most one knot per value (then the
/// shape is any monotone law).
fn ranked(mut v: Vec<f64>, k: usize) -> Option<Vec<f64>> {
    v.sort_by(f64::total_cmp);
    v.dedup();
    let k = k.min(v.len());
    if k < 2 {
        return None;
    }
    let ranks: Vec<f64> = (0..k).map(|i| i as f64 / (k - 1) as f64).collect();
    strictly_increasing(quantiles(v, &ranks), k)
}

fn strictly_increasing(mut q: Vec<f64>, k: usize) -> Option<Vec<f64>> {
    q.dedup();
    (q.len() == k && law::check_knots(&q).is_ok()).then_some(q)
}

/// The model file's shape of effect `id` (`fit` in the lab's form with
/// `knots`): knots in the model's units (amplitude: LSB ÷ `code_per_e` =
/// electrons; temperature: °C; tap charge: SBI units × e⁻ per unit; on-time:
/// µs) and the values relative to the lab's reference `temp_ref_c` (drift)
/// — each curve projected onto the nearest monotone one
/// (`law::monotone_projection`), as the model requires; the SBI's removed
/// charge non-negative, its sign carried by the mismatch (`sbi_split`),
/// the droop's loss below 1. `None` where `fit`
/// is not of the shape form.
pub fn model_shape(
    id: &str,
    knots: &[f64],
    fit: &EffectFit,
    code_per_e: f64,
    temp_ref_c: f64,
) -> Option<law::EffectShape> {
    let with0 = |c: &[f64]| -> Vec<f64> { std::iter::once(0.0).chain(c.iter().copied()).collect() };
    let one = |key, values| law::EffectShape {
        knots: knots.to_vec(),
        curves: vec![(key, values)],
    };
    match EffectId::parse(id)? {
        effects::amplitude_phase_error::ID if code_per_e > 0.0 => Some(law::EffectShape {
            knots: knots.iter().map(|k| k / code_per_e).collect(),
            curves: vec![(
                effects::amplitude_phase_error::AMPLITUDE_PHASE_RAD,
                law::monotone_projection(&with0(&fit.nl)),
            )],
        }),
        effects::temperature_drift::ID => {
            // relative to T_ref: G(T_ref) = 0 makes the file's 1 + G(T) the lab's factor
            let at_ref = |c: &[f64]| {
                let v = with0(c);
                let r = law::eval(knots, &v, temp_ref_c);
                law::monotone_projection(&v.iter().map(|x| x - r).collect::<Vec<_>>())
            };
            Some(law::EffectShape {
                knots: knots.to_vec(),
                curves: vec![
                    (effects::temperature_drift::DRIFT_PHASE_RAD, at_ref(&fit.nl)),
                    (effects::temperature_drift::DRIFT_GAIN_REL, at_ref(&fit.lin)),
                ],
            })
        }
        effects::sbi_asymmetry::ID if code_per_e > 0.0 && fit.nl.len() == knots.len() => {
            let u = sbi::signal_e_per_unit(code_per_e);
            let (v, _) = sbi_split(&fit.nl);
            let r = law::monotone_projection(&with0(&v));
            Some(law::EffectShape {
                knots: knots.iter().map(|k| k * u).collect(),
                curves: vec![(
                    effects::sbi_asymmetry::SBI_REMOVED_E,
                    r.iter().map(|x| (x * u).max(0.0)).collect(),
                )],
            })
        }
        effects::vcsel_droop::ID if fit.lin.len() + 1 == knots.len() => {
            let l = law::monotone_projection(&with0(&fit.lin));
            Some(one(
                effects::vcsel_droop::DROOP_LOSS_REL,
                l.iter().map(|v| v.min(MAX_LOSS_REL)).collect(),
            ))
        }
        _ => None,
    }
}

/// The largest power loss a written droop shape keeps (the model refuses
/// L ≥ 1: no power left).
const MAX_LOSS_REL: f64 = 0.99;

/// The SBI shape's removed charge at knots 1.. (lab units) and mismatch m
/// from its `nl`: m held in its range, and R non-decreasing — a fit whose
/// values fall is the same law with both signs flipped (only m·R counts).
fn sbi_split(nl: &[f64]) -> (Vec<f64>, f64) {
    let (v, m) = nl.split_at(nl.len().saturating_sub(1));
    let b = sbi_mismatch_bound();
    let m = m.first().copied().unwrap_or(0.0).clamp(-b, b);
    if v.iter().sum::<f64>() < 0.0 {
        (v.iter().map(|x| -x).collect(), -m)
    } else {
        (v.to_vec(), m)
    }
}

/// The model's `mismatch_rel` of the SBI's shape form fitted as `fit`
/// (`sbi_split`).
pub fn shape_mismatch_rel(fit: &EffectFit) -> Option<f64> {
    (!fit.nl.is_empty()).then(|| sbi_split(&fit.nl).1)
}

/// The lab's knots and (lin, nl) of model file `m`'s shape of effect `id`
/// (the inverse of [`model_shape`]): values relative to the first knot's;
/// the drift's gain divided by the file's 1 + G(T_ref) (the lab's factor is
/// relative to its reference temperature `temp_ref_c`); the droop's loss
/// relative to the first raw image's power, 1 − L(0); the SBI's values in
/// its units, its mismatch from the file's `mismatch_rel`.
pub fn held_shape(
    id: EffectId,
    m: &tofprox_model::ModelConfig,
    code_per_e: f64,
    temp_ref_c: f64,
) -> Option<(Vec<f64>, Vec<f64>, Vec<f64>)> {
    let s = m.shape(id)?;
    let curve = |key: &str| s.values(key);
    if s.knots.len() > MAX_KNOTS {
        return None;
    }
    let rel =
        |v: &[f64], scale: f64| -> Vec<f64> { v[1..].iter().map(|x| (x - v[0]) / scale).collect() };
    match id {
        effects::amplitude_phase_error::ID if code_per_e > 0.0 => Some((
            s.knots.iter().map(|k| k * code_per_e).collect(),
            Vec::new(),
            rel(
                &curve(effects::amplitude_phase_error::AMPLITUDE_PHASE_RAD),
                1.0,
            ),
        )),
        effects::temperature_drift::ID => {
            let g = curve(effects::temperature_drift::DRIFT_GAIN_REL);
            let g_ref = (1.0 + law::eval(&s.knots, &g, temp_ref_c)).max(1e-9);
            Some((
                s.knots.clone(),
                rel(&g, g_ref),
                rel(&curve(effects::temperature_drift::DRIFT_PHASE_RAD), 1.0),
            ))
        }
        effects::sbi_asymmetry::ID if code_per_e > 0.0 => {
            let u = sbi::signal_e_per_unit(code_per_e);
            let r = curve(effects::sbi_asymmetry::SBI_REMOVED_E);
            let m_rel = m.get(effects::sbi_asymmetry::MISMATCH_REL);
            Some((
                s.knots.iter().map(|k| k / u).collect(),
                Vec::new(),
                r[1..].iter().map(|v| v / u).chain([m_rel]).collect(),
            ))
        }
        effects::vcsel_droop::ID => {
            let l = curve(effects::vcsel_droop::DROOP_LOSS_REL);
            Some((s.knots.clone(), rel(&l, 1.0 - l[0]), Vec::new()))
        }
        _ => None,
    }
}

/// The lab's knots of every enabled effect the model file gives as a shape
/// (`code_per_e`: the file's output codes per electron).
pub fn spec_shapes(m: &tofprox_model::ModelConfig, code_per_e: f64) -> BTreeMap<String, Vec<f64>> {
    law::shape_laws()
        .filter(|l| m.is_enabled(l.effect))
        .filter_map(|l| {
            let (knots, _, _) = held_shape(l.effect, m, code_per_e, 0.0)?;
            Some((l.effect.as_str().to_string(), knots))
        })
        .collect()
}
