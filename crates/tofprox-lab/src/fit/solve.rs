//! The alternating fit of the lab model: starting values from the dark and
//! correlation captures, then rounds of per-pixel Gauss–Newton, the global
//! harmonics, saturation, the enabled effects and the noise model.

use rayon::prelude::*;
use tofprox_core::lsq::{Normal, solve_sym};

use super::{
    EffectFit, LabModel, LabSpec, Phasor, Prepared, Progress, effects_delta, median, rotate,
    theta_rotation,
};
use crate::error::LabError;
use crate::noise::{NoiseModel, fit_noise};
use crate::signatures::make_signature;
use crate::waveform::Waveform;

/// Fit the lab model with the given spec to a prepared recording.
pub fn fit_model(
    prep: &Prepared,
    spec: &LabSpec,
    progress: Progress<'_>,
) -> Result<LabModel, LabError> {
    let npix = prep.npix;
    let ncap = prep.caps.len();
    progress("offsets", 0.0);
    // Offsets from the dark captures (thesis 4.3.2.1); else from the mean of
    // the raw images of captures with ≥ 4 phases (the first harmonic cancels).
    let mut offset = vec![0.0; npix];
    let mut cnt = vec![0.0; npix];
    let darks: Vec<usize> = (0..ncap).filter(|&c| !prep.caps[c].illum).collect();
    let src: Vec<usize> = if darks.is_empty() {
        (0..ncap)
            .filter(|&c| prep.caps[c].used && prep.caps[c].theta_rad.len() >= 4)
            .collect()
    } else {
        darks.clone()
    };
    for &c in &src {
        for k in 0..prep.caps[c].theta_rad.len() {
            for p in 0..npix {
                if prep.sat_meas[c * npix + p] {
                    continue;
                }
                offset[p] += prep.meas[prep.idx(c, k, p)] - prep.mid;
                cnt[p] += 1.0;
            }
        }
    }
    for p in 0..npix {
        offset[p] = if cnt[p] > 0.0 {
            offset[p] / cnt[p]
        } else {
            0.0
        };
    }
    // Waveform and per-pixel phase from the correlation capture (the capture
    // with the most phases, ≥ 8), by DFT per pixel.
    let corr = (0..ncap)
        .filter(|&c| prep.caps[c].illum && prep.caps[c].used && prep.caps[c].theta_rad.len() >= 8)
        .max_by_key(|&c| prep.caps[c].theta_rad.len());
    let mut phase = vec![0.0; npix];
    let mut waveform = Waveform::sinusoid();
    let order = spec.harmonic_order.max(1);
    let dft = |c: usize, p: usize, h: usize| -> (f64, f64) {
        let cap = &prep.caps[c];
        let n = cap.theta_rad.len() as f64;
        let mut re = 0.0;
        let mut im = 0.0;
        for (k, th) in cap.theta_rad.iter().enumerate() {
            let u = prep.meas[prep.idx(c, k, p)] - prep.mid - offset[p];
            let (s, co) = (h as f64 * th).sin_cos();
            re += u * co;
            im += u * s;
        }
        (2.0 * re / n, 2.0 * im / n)
    };
    let phase_from = |cs: &[usize], p: usize| -> f64 {
        let (mut sr, mut si) = (0.0, 0.0);
        for &c in cs {
            if prep.sat_meas[c * npix + p] {
                continue;
            }
            let (re, im) = dft(c, p, 1);
            let (s, co) = (-prep.caps[c].phi_tof).sin_cos();
            // rotate by −φ_tof
            sr += re * co - im * s;
            si += re * s + im * co;
        }
        si.atan2(sr)
    };
    if let Some(c) = corr {
        for (p, ph) in phase.iter_mut().enumerate() {
            *ph = phase_from(&[c], p);
        }
        let nh = order.min(prep.caps[c].theta_rad.len() / 2 - 1).max(1);
        let mut gsum = vec![[0.0f64; 2]; nh];
        let mut wsum = 0.0;
        for p in 0..npix {
            if prep.sat_meas[c * npix + p] {
                continue;
            }
            let (r1, i1) = dft(c, p, 1);
            let amp = r1.hypot(i1);
            if amp <= 0.0 {
                continue;
            }
            let phi = i1.atan2(r1);
            for (h0, g) in gsum.iter_mut().enumerate().skip(1) {
                let h = h0 + 1;
                let (rh, ih) = dft(c, p, h);
                // γ_h = X_h / (A e^{i h φ})
                let (s, co) = (-(h as f64) * phi).sin_cos();
                g[0] += (rh * co - ih * s) * amp; // weight by amplitude
                g[1] += (rh * s + ih * co) * amp;
            }
            wsum += amp * amp;
        }
        if wsum > 0.0 {
            waveform.gamma = gsum.iter().map(|g| [g[0] / wsum, g[1] / wsum]).collect();
            waveform.gamma[0] = [1.0, 0.0];
        }
    } else {
        let cs: Vec<usize> = (0..ncap)
            .filter(|&c| prep.caps[c].illum && prep.caps[c].used)
            .collect();
        for (p, ph) in phase.iter_mut().enumerate() {
            *ph = phase_from(&cs, p);
        }
    }
    while waveform.gamma.len() < order {
        waveform.gamma.push([0.0, 0.0]);
    }
    let mut model = LabModel {
        spec: spec.clone(),
        offset,
        gain: vec![1.0; npix],
        phase,
        waveform,
        effects: spec
            .effects
            .iter()
            .map(|id| {
                if let Some(h) = spec.held.iter().find(|h| &h.id == id) {
                    return Ok(h.clone());
                }
                let s = make_signature(id, prep, spec, &Waveform::sinusoid())?;
                Ok(EffectFit {
                    id: id.clone(),
                    lin: vec![0.0; s.n_lin()],
                    nl: s.nl_start(),
                })
            })
            .collect::<Result<_, LabError>>()?,
        noise: NoiseModel::default(),
        sat: prep.sat_meas.clone(),
        n_params: 0,
        gain_median: 1.0,
    };
    // Initial gains: least squares with the shape fixed.
    fit_gain_only(prep, &mut model);
    let rounds = if spec.effects.is_empty() { 4 } else { 8 };
    refine(prep, &mut model, rounds, true, false, progress)?;
    Ok(model)
}

/// Alternating rounds: per-pixel Gauss–Newton, global harmonics, saturation,
/// enabled effects (grid search early unless `warm`), noise (if `noise`).
pub fn refine(
    prep: &Prepared,
    model: &mut LabModel,
    rounds: usize,
    noise: bool,
    warm: bool,
    progress: Progress<'_>,
) -> Result<(), LabError> {
    let npix = prep.npix;
    // Step control (when the noise model is held, χ² values are comparable):
    // a round that ends with a higher χ² than it started from is undone and
    // the refinement stops, so a refit never ends worse than its start.
    let mut last = if noise {
        None
    } else {
        Some((model.chi2(prep)?, model.clone()))
    };
    for round in 0..rounds {
        progress("per-pixel fit", round as f64 / rounds as f64);
        if let Some((chi_prev, prev)) = &mut last
            && round > 0
        {
            let chi = model.chi2(prep)?;
            // NaN counts as worse
            if chi.is_nan() || chi > *chi_prev {
                tracing::debug!("refit round {round}: χ² {chi:.1} > {chi_prev:.1}, step undone");
                *model = prev.clone();
                break;
            }
            *chi_prev = chi;
            *prev = model.clone();
        }
        let delta = effects_delta(prep, model)?;
        for _ in 0..2 {
            per_pixel_step(prep, model, &delta);
        }
        if model.waveform.order() > 1 {
            waveform_step(prep, model, &delta);
        }
        update_saturation(prep, model);
        if !model.effects.is_empty() {
            // full grid search early and once more late; warm refinement between
            let w = warm || (round >= 2 && round + 2 != rounds);
            fit_enabled_effects(prep, model, w)?;
        }
        if noise && (round == 0 || round + 2 == rounds) {
            model.noise = fit_noise(prep, model)?;
        }
    }
    if let Some((chi_prev, prev)) = last {
        let chi = model.chi2(prep)?;
        if chi.is_nan() || chi > chi_prev {
            *model = prev;
        }
    }
    progress("per-pixel fit", 1.0);
    model.n_params = param_count(model, npix);
    Ok(())
}

/// The parameters `model` fits on a window of `npix` pixels: per pixel (or
/// pooled) offset, gain and phase, the waveform's harmonics and the free
/// effects' values.
pub(crate) fn param_count(model: &LabModel, npix: usize) -> usize {
    let spec = &model.spec;
    let pp = |b: bool| if b { npix } else { 1 };
    pp(spec.per_pixel_offset)
        + pp(spec.per_pixel_gain)
        + pp(spec.per_pixel_phase)
        + 2 * (model.waveform.order() - 1)
        + model
            .effects
            .iter()
            .filter(|e| !spec.held.iter().any(|h| h.id == e.id))
            .map(|e| {
                let held = spec
                    .holds
                    .get(&e.id)
                    .map_or(0, |m| m.iter().flatten().count());
                (e.lin.len() + e.nl.len()).saturating_sub(held)
            })
            .sum::<usize>()
}

/// The model `base` with one more effect, started from a candidate fit on top
/// of it (and the global shifts fitted alongside), refined for a few rounds.
pub fn refit_with(
    prep: &Prepared,
    base: &LabModel,
    effect: &EffectFit,
    nuisance: [f64; 3],
    rounds: usize,
) -> Result<LabModel, LabError> {
    let mut m = base.clone();
    if let Some(e) = crate::signatures::waveform_effect(&effect.id) {
        e.widen_spec(&mut m.spec);
        e.extend_waveform(&mut m.waveform, &effect.lin);
    } else {
        m.spec.effects.push(effect.id.clone());
        m.effects.push(effect.clone());
    }
    m.offset.iter_mut().for_each(|o| *o += nuisance[0]);
    m.gain.iter_mut().for_each(|g| *g *= 1.0 + nuisance[1]);
    m.phase.iter_mut().for_each(|p| *p += nuisance[2]);
    refine(prep, &mut m, rounds, false, true, &|_, _| {})?;
    Ok(m)
}

fn fit_gain_only(prep: &Prepared, model: &mut LabModel) {
    let npix = prep.npix;
    let gains: Vec<f64> = (0..npix)
        .into_par_iter()
        .map(|p| {
            let (mut num, mut den) = (0.0, 0.0);
            for (c, cap) in prep.caps.iter().enumerate() {
                if !cap.illum || !cap.used || model.sat[c * npix + p] {
                    continue;
                }
                let phi = cap.phi_tof + model.phase[p];
                for (k, th) in cap.theta_rad.iter().enumerate() {
                    let (cv, _) = model.waveform.eval(phi - th);
                    let u = prep.meas[prep.idx(c, k, p)] - prep.mid - model.offset[p];
                    num += u * cap.law * cv;
                    den += (cap.law * cv).powi(2);
                }
            }
            if den > 0.0 { num / den } else { 0.0 }
        })
        .collect();
    let med = median(
        &gains
            .iter()
            .copied()
            .filter(|g| *g > 0.0)
            .collect::<Vec<_>>(),
    )
    .unwrap_or(1.0);
    model.gain = gains
        .into_iter()
        .map(|g| if g > 0.0 { g } else { med })
        .collect();
    update_gain_median(model);
}

/// [`LabModel::gain_median`] from the current gains (positive ones; 1 if
/// none): the reference of every `gain_rel`, so that the effects'
/// background terms (ambient light through the pixel's relative response)
/// are in klux·ms, not scaled by the absolute gain in LSB per unit law.
fn update_gain_median(model: &mut LabModel) {
    let positive: Vec<f64> = model.gain.iter().copied().filter(|g| *g > 0.0).collect();
    model.gain_median = median(&positive).unwrap_or(1.0);
}

/// e^{−iθ_k} of every raw image of every capture.
fn theta_rotations(prep: &Prepared) -> Vec<Vec<(f64, f64)>> {
    prep.caps.iter().map(theta_rotation).collect()
}

/// One Gauss–Newton step of (o_p, g_p, δ_p) for every pixel, effects fixed.
fn per_pixel_step(prep: &Prepared, model: &mut LabModel, delta: &[f64]) {
    let npix = prep.npix;
    let m = &*model;
    let rot = theta_rotations(prep);
    let steps: Vec<(Normal, [f64; 3])> = (0..npix)
        .into_par_iter()
        .map(|p| {
            let mut nrm = Normal::zeros(3);
            for (c, cap) in prep.caps.iter().enumerate() {
                if !cap.used || m.sat[c * npix + p] {
                    continue;
                }
                let (a, phi, var) = m.amp_phase_var(cap, p);
                // ∂A/∂g_p: the signal law times the effects' gain on the phasor
                let law = cap.law * m.phasor_shift(cap, p).0;
                let w = 1.0 / var;
                let (s, co) = phi.sin_cos();
                for (k, et) in rot[c].iter().enumerate() {
                    let i = prep.idx(c, k, p);
                    let (cv, cd) = if cap.illum {
                        let (ec, es) = rotate((co, s), *et);
                        m.waveform.eval_at(ec, es)
                    } else {
                        (0.0, 0.0)
                    };
                    let r = prep.meas[i] - delta[i] - prep.mid - m.offset[p] - a * cv;
                    nrm.add_n(&[1.0, law * cv, a * cd], r, w);
                }
            }
            nrm.symmetrize();
            let step = solve_sym(&nrm.jtj, &nrm.jtr)
                .map(|s| [s[0], s[1], s[2]])
                .unwrap_or_else(|| {
                    // no illuminated data: offset only
                    let d = nrm.jtj[0];
                    [if d > 0.0 { nrm.jtr[0] / d } else { 0.0 }, 0.0, 0.0]
                });
            (nrm, step)
        })
        .collect();
    for (p, (_, s)) in steps.iter().enumerate() {
        model.offset[p] += s[0];
        model.gain[p] += s[1];
        model.phase[p] += s[2].clamp(-0.5, 0.5);
    }
    // Parts the model does not make per-pixel are pooled (weighted mean).
    let pool = |vals: &mut Vec<f64>, j: usize| {
        let (mut s, mut w) = (0.0, 0.0);
        for (p, v) in vals.iter().enumerate() {
            let d = steps[p].0.jtj[j * 3 + j];
            s += v * d;
            w += d;
        }
        if w > 0.0 {
            let mean = s / w;
            vals.iter_mut().for_each(|v| *v = mean);
        }
    };
    if !model.spec.per_pixel_offset {
        pool(&mut model.offset, 0);
    }
    if !model.spec.per_pixel_gain {
        pool(&mut model.gain, 1);
    }
    if !model.spec.per_pixel_phase {
        pool(&mut model.phase, 2);
    }
    update_gain_median(model);
}

/// Gauss–Newton step of the global harmonics γ_2..γ_H on all data.
///
/// The Jacobian of harmonic m at a sample is A·(cos mx, −sin mx), x = φ − θ_k
/// (`crate::waveform`), so JᵀWJ holds only products cos mx·cos nx, sin mx·sin nx
/// and cos mx·sin nx: halves of cos and sin of (m ± n)x. It follows from the moments
/// S_j = Σ w·A²·e^{ijx}, j = 0..2H ([`HarmonicMoments`]), and those of a pixel's raw
/// images from e^{ijφ} times the capture's Σ_k e^{−ijθ_k}: once per pixel and capture
/// instead of a 2(H−1)-parameter update per sample. JᵀWr stays a sum over samples.
fn waveform_step(prep: &Prepared, model: &mut LabModel, delta: &[f64]) {
    let npix = prep.npix;
    let order = model.waveform.order();
    let m = &*model;
    // one partial sum per capture, merged in order (deterministic, unlike a
    // rayon fold whose splits depend on thread scheduling)
    let parts: Vec<HarmonicMoments> = (0..prep.caps.len())
        .into_par_iter()
        .map(|c| {
            let mut acc = HarmonicMoments::zeros(order);
            let cap = &prep.caps[c];
            if !cap.used || !cap.illum {
                return acc;
            }
            let rot = theta_rotation(cap);
            let theta_sums = phasor_power_sums(&rot, 2 * order);
            for p in 0..npix {
                if m.sat[c * npix + p] {
                    continue;
                }
                let (a, phi, var) = m.amp_phase_var(cap, p);
                let w = 1.0 / var;
                let (s, co) = phi.sin_cos();
                acc.add_pixel(w * a * a, (co, s), &theta_sums);
                for (k, et) in rot.iter().enumerate() {
                    let i = prep.idx(c, k, p);
                    let (c1, s1) = rotate((co, s), *et);
                    let (cv, _) = m.waveform.eval_at(c1, s1);
                    let r = prep.meas[i] - delta[i] - prep.mid - m.offset[p] - a * cv;
                    acc.add_residual(w, a, r, (c1, s1));
                }
            }
            acc
        })
        .collect();
    let mut total = HarmonicMoments::zeros(order);
    for part in &parts {
        total.merge(part);
    }
    let nrm = total.normal();
    if let Some(s) = solve_sym(&nrm.jtj, &nrm.jtr) {
        for h in 0..order - 1 {
            model.waveform.gamma[h + 1][0] += s[2 * h];
            model.waveform.gamma[h + 1][1] += s[2 * h + 1];
        }
    }
}

/// Σ_k z_kʲ for j = 0..=`top` of the unit phasors `z` (complex powers).
fn phasor_power_sums(z: &[Phasor], top: usize) -> Vec<Phasor> {
    let mut sums = vec![(0.0, 0.0); top + 1];
    for &zk in z {
        let mut p = (1.0, 0.0);
        for s in &mut sums {
            s.0 += p.0;
            s.1 += p.1;
            p = rotate(p, zk);
        }
    }
    sums
}

/// The normal equations of the harmonics γ_2..γ_H ([`waveform_step`]) as the moments
/// S_j = Σ w·A²·e^{ijx} (j = 0..2H) and JᵀWr, χ².
struct HarmonicMoments {
    /// S_j, j = 0..=2H.
    moments: Vec<Phasor>,
    /// JᵀWr: (Σ w·r·A·cos mx, −Σ w·r·A·sin mx) for m = 2..=H.
    jtr: Vec<f64>,
    chi2: f64,
    count: usize,
}

impl HarmonicMoments {
    fn zeros(order: usize) -> Self {
        Self {
            moments: vec![(0.0, 0.0); 2 * order + 1],
            jtr: vec![0.0; 2 * order.saturating_sub(1)],
            chi2: 0.0,
            count: 0,
        }
    }
    /// The moments of a pixel's raw images: w·A²·e^{ijφ}·Σ_k e^{−ijθ_k}
    /// (`theta_sums` from [`phasor_power_sums`] of the e^{−iθ_k}).
    fn add_pixel(&mut self, wa2: f64, e_phi: Phasor, theta_sums: &[Phasor]) {
        let mut p = (wa2, 0.0);
        for (s, t) in self.moments.iter_mut().zip(theta_sums) {
            let v = rotate(p, *t);
            s.0 += v.0;
            s.1 += v.1;
            p = rotate(p, e_phi);
        }
    }
    /// One sample's residual `r` (weight `w`, amplitude `a`, e^{ix} = `z`).
    fn add_residual(&mut self, w: f64, a: f64, r: f64, z: Phasor) {
        let war = w * a * r;
        let mut zm = rotate(z, z);
        for j in self.jtr.chunks_exact_mut(2) {
            j[0] += war * zm.0;
            j[1] -= war * zm.1;
            zm = rotate(zm, z);
        }
        self.chi2 += w * r * r;
        self.count += 1;
    }
    fn merge(&mut self, o: &Self) {
        for (a, b) in self.moments.iter_mut().zip(&o.moments) {
            a.0 += b.0;
            a.1 += b.1;
        }
        for (a, b) in self.jtr.iter_mut().zip(&o.jtr) {
            *a += b;
        }
        self.chi2 += o.chi2;
        self.count += o.count;
    }
    /// JᵀWJ from the moments: with S_{−j} = conj S_j,
    /// Σ w A² cos mx cos nx = ½ Re(S_{m+n} + S_{m−n}),
    /// Σ w A² sin mx sin nx = ½ Re(S_{m−n} − S_{m+n}),
    /// Σ w A² cos mx sin nx = ½ Im(S_{m+n} − S_{m−n}).
    fn normal(&self) -> Normal {
        let n = self.jtr.len();
        let s = |j: i64| {
            let v = self.moments[j.unsigned_abs() as usize];
            if j < 0 { (v.0, -v.1) } else { v }
        };
        let cos_sin = |m: i64, q: i64| 0.5 * (s(m + q).1 - s(m - q).1);
        let mut nrm = Normal::zeros(n);
        for h in 0..n / 2 {
            for g in 0..n / 2 {
                let (mh, mg) = (h as i64 + 2, g as i64 + 2);
                let (sum, diff) = (s(mh + mg).0, s(mh - mg).0);
                nrm.jtj[2 * h * n + 2 * g] = 0.5 * (sum + diff);
                nrm.jtj[(2 * h + 1) * n + 2 * g + 1] = 0.5 * (diff - sum);
                // columns (A cos, −A sin): the mixed products change sign
                nrm.jtj[2 * h * n + 2 * g + 1] = -cos_sin(mh, mg);
                nrm.jtj[(2 * h + 1) * n + 2 * g] = -cos_sin(mg, mh);
            }
        }
        nrm.jtr.copy_from_slice(&self.jtr);
        nrm.chi2 = self.chi2;
        nrm.count = self.count;
        nrm
    }
}

/// Mark capture-pixels whose modelled codes come near the ADC rails.
fn update_saturation(prep: &Prepared, model: &mut LabModel) {
    let npix = prep.npix;
    let margin = prep.margin();
    for (c, cap) in prep.caps.iter().enumerate() {
        if !cap.illum || !cap.used {
            continue;
        }
        for p in 0..npix {
            if prep.sat_meas[c * npix + p] {
                model.sat[c * npix + p] = true;
                continue;
            }
            let a = model.gain[p] * cap.law * model.phasor_shift(cap, p).0;
            let o = prep.mid + model.offset[p];
            model.sat[c * npix + p] = o + a >= prep.max_code - margin || o - a <= margin;
        }
    }
}

/// Re-fit the parameters of the model's enabled effects on its residual.
fn fit_enabled_effects(prep: &Prepared, model: &mut LabModel, warm: bool) -> Result<(), LabError> {
    for i in 0..model.effects.len() {
        if model.spec.held.iter().any(|h| h.id == model.effects[i].id) {
            continue;
        }
        // residual with every other effect included
        let mut tmp = model.clone();
        let this = tmp.effects.remove(i);
        // large recordings: every other capture (repeats come in consecutive
        // pairs, so every condition stays represented)
        let step = if prep.meas.len() > 300_000 { 2 } else { 1 };
        let recs = tmp.records_of(prep, step)?;
        let sig = make_signature(&this.id, prep, &model.spec, &model.waveform)?;
        let start = if warm { Some(&this) } else { None };
        let fitted = crate::candidates::fit_values(sig.as_ref(), &recs, prep, start)?;
        model.effects[i] = EffectFit {
            id: this.id.clone(),
            lin: fitted.lin,
            nl: fitted.nl,
        };
        // the global shifts fitted alongside move the per-pixel parameters
        let nu = fitted.nuisance;
        model.offset.iter_mut().for_each(|o| *o += nu[0]);
        model.gain.iter_mut().for_each(|g| *g *= 1.0 + nu[1]);
        model.phase.iter_mut().for_each(|p| *p += nu[2]);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The harmonics' normal equations from the moments are those of the Jacobian
    /// rows A·(cos mx, −sin mx) summed sample by sample (written here with `cos`
    /// and `sin` of m·x), for raw-image phases that are not evenly spaced.
    #[test]
    fn harmonic_moments_give_the_sampled_normal_equations() {
        let order = 5;
        let thetas = [0.0, 1.1, 2.0, 4.4];
        let rot: Vec<Phasor> = thetas.iter().map(|t: &f64| (t.cos(), -t.sin())).collect();
        let sums = phasor_power_sums(&rot, 2 * order);
        let (mut moments, mut direct) = (HarmonicMoments::zeros(order), Normal::zeros(8));
        for p in 0..7 {
            let (a, phi, w) = (
                50.0 + 30.0 * p as f64,
                0.9 * p as f64 - 2.0,
                0.5 + 0.1 * p as f64,
            );
            moments.add_pixel(w * a * a, (phi.cos(), phi.sin()), &sums);
            for (k, t) in thetas.iter().enumerate() {
                let (x, r) = (phi - t, (p * 4 + k) as f64 * 0.37 - 3.0);
                moments.add_residual(w, a, r, (x.cos(), x.sin()));
                let j: Vec<f64> = (2..=order)
                    .flat_map(|m| [a * (m as f64 * x).cos(), -a * (m as f64 * x).sin()])
                    .collect();
                direct.add(&j, r, w);
            }
        }
        direct.symmetrize();
        let got = moments.normal();
        let scale = direct.jtj.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (g, d) in got.jtj.iter().zip(&direct.jtj) {
            assert!((g - d).abs() < 1e-12 * scale, "{g} vs {d}");
        }
        for (g, d) in got.jtr.iter().zip(&direct.jtr) {
            assert!((g - d).abs() < 1e-9 * d.abs().max(1.0), "{g} vs {d}");
        }
        assert!((got.chi2 - direct.chi2).abs() < 1e-12 * direct.chi2);
        assert_eq!(got.count, 28);
    }
}
