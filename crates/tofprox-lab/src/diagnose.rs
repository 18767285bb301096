//! compare → diagnose → add: the lab's workflow on a prepared recording.
use std::collections::BTreeMap;

use rayon::prelude::*;
use serde::Serialize;
use tofprox_model::catalogue::Driver;

use crate::candidates::{fit_signature, fit_values};
use crate::error::{ErrorKind, LabError};
use crate::fit::{LabModel, Progress, fit_model};
use crate::noise::NoiseSource;
use crate::prepared::Prepared;
use crate::sample::Sample;
use crate::signatures::{
    SIGNATURE_IDS, cancels_in_4phase, effect_conditions, make_signature, not_identifiable,
};
use crate::spec::{EffectFit, LabSpec};
use crate::stats::{bic, chi2_z};
use crate::structure::{ConditionScore, score_all};

/// Global misfit below which the residual counts as noise.
pub const Z_NULL: f64 = 4.0;
/// Structure score below which no condition shows structure.
pub const STRUCTURE_NULL: f64 = 6.0;
/// A named effect must explain at least this share of the excess χ².
pub const MIN_EXPLAINED: f64 = 0.6;
/// Several effects at once: a candidate that explains at least this share,
/// also on held-out blocks, and clearly beats the runner-up is named even when
/// the residual after it is far from noise (the next effect is then sought).
pub const MIN_PARTIAL: f64 = 0.5;
/// … and keep at least this cross-validated share.
pub const MIN_CV: f64 = 0.4;
/// Two candidates closer than this in explained share are ambiguous.
pub const AMBIGUITY_MARGIN: f64 = 0.1;

/// Two candidates are told apart when the runner-up leaves at least this many times the excess
/// the best one leaves (e.g. 3.5 % against 0.1 %): both "explain most of it", but only one
/// explains it down to the noise, which is what a measurement can distinguish.
pub const REMAINDER_RATIO: f64 = 3.0;

/// RMS errors of the model against the recording.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct Rms {
    /// RMS raw-code residual (measured − model) over the valid samples, LSB.
    pub raw_lsb: f64,
    /// RMS 2-phase depth error after the model's calibration ([`depth_residuals`]), mm.
    pub depth_2phase_mm: f64,
    /// The same for 4-phase (NaN without 4-phase captures), mm.
    pub depth_4phase_mm: f64,
}

/// Goodness of fit of the noise-weighted residual.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct FitStats {
    /// χ²/dof (1 when the residual is noise).
    pub chi2_per_dof: f64,
    /// Global misfit z = (χ² − dof)/√(2 dof).
    pub z: f64,
    /// Akaike's information criterion χ² + 2k (k the model's fitted
    /// parameters, per-pixel ones included; [`crate::stats::aic`]): only
    /// differences between models of one recording mean anything.
    pub aic: f64,
    /// The Bayesian information criterion χ² + k ln n ([`crate::stats::bic`]).
    pub bic: f64,
}

impl FitStats {
    /// The statistics of χ² `chi2` over `n` samples with `k` fitted parameters.
    pub fn of(chi2: f64, n: usize, k: usize) -> Self {
        let dof = n.saturating_sub(k).max(1) as f64;
        Self {
            chi2_per_dof: chi2 / dof,
            z: chi2_z(chi2, dof),
            aic: crate::stats::aic(chi2, k),
            bic: bic(chi2, k, n),
        }
    }
}

/// Per-capture depth residual means (for plots).
#[derive(Debug, Clone, Serialize)]
pub struct CaptureDepth {
    /// Capture index in the recording.
    pub capture: usize,
    /// Ground-truth distance.
    pub distance_m: f64,
    /// Exposure time.
    pub exposure_us: f64,
    /// Background illuminance.
    pub ambient_klux: f64,
    /// Sensor temperature, if recorded.
    pub temperature_c: Option<f64>,
    /// Mean 2-phase depth error over the capture's pixels, mm.
    pub depth_2phase_mm: f64,
    /// Mean 4-phase depth error (NaN without 4-phase images), mm.
    pub depth_4phase_mm: f64,
    /// Mean measured 4-phase amplitude (eq. 2.4) after the model's offset and effects, LSB.
    pub measured_amplitude_lsb: f64,
    /// Mean amplitude of the model's ideal codes, LSB.
    pub model_amplitude_lsb: f64,
}

/// How large a residual is in practical units.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct Size {
    /// RMS code error in LSB (inverse-variance weighted).
    pub lsb: f64,
    /// Depth-equivalent RMS error in mm (code error / amplitude · c/(4πf)).
    pub mm: f64,
}

/// Default tolerance as a share of the single-acquisition depth-equivalent
/// noise (`Comparison::noise_single`): remaining structure smaller than 15 % of
/// what one raw acquisition scatters by is reported but not a missing effect.
pub const TOLERANCE_NOISE_SHARE: f64 = 0.15;

/// The model compared with the recording.
#[derive(Debug, Clone)]
pub struct Comparison {
    /// The fitted model.
    pub model: LabModel,
    /// The residual table over the valid samples.
    pub recs: Vec<Sample>,
    /// Σ w r² over `recs`.
    pub chi2: f64,
    /// Valid samples.
    pub n: usize,
    /// Degrees of freedom: samples − fitted parameters.
    pub dof: f64,
    /// χ²/dof and the global misfit z.
    pub fit: FitStats,
    /// RMS raw and depth errors.
    pub rms: Rms,
    /// Structure score of every condition that varies, strongest first.
    pub structure: Vec<ConditionScore>,
    /// Per-capture depth residual means.
    pub depth: Vec<CaptureDepth>,
    /// Per-pixel χ²/sample (residual map).
    pub pixel_chi2: Vec<f64>,
    /// Size of the whole systematic residual (χ² beyond its expectation under
    /// noise), over the illuminated samples for the depth equivalent.
    pub size: Size,
    /// The noise of one raw acquisition (averaged = 1) in the same units,
    /// weighted like `size` (σ/A over the samples that inform depth most).
    pub noise_single: Size,
    /// Σw over the samples and Σw·A² over the illuminated ones: the scales
    /// that turn a χ² difference into a size (`structure::structure_size`).
    pub weight_sums: (f64, f64),
}

impl Comparison {
    /// Size (LSB, depth-equivalent mm) of a systematic residual carrying χ²
    /// `chi2` on these samples.
    pub fn size_of(&self, chi2: f64, prep: &Prepared) -> Size {
        let mmr = prep.mm_per_rad();
        Size {
            lsb: crate::structure::structure_size(chi2, self.weight_sums.0, 1.0, mmr).0,
            mm: crate::structure::structure_size(chi2, 1.0, self.weight_sums.1, mmr).1,
        }
    }

    /// The default tolerance of the verdict in depth-equivalent mm.
    pub fn default_tolerance_mm(&self) -> f64 {
        TOLERANCE_NOISE_SHARE * self.noise_single.mm
    }
}

/// Fit the lab model of `spec` to the recording and compare it with the data.
pub fn compare(
    prep: &Prepared,
    spec: &LabSpec,
    progress: Progress<'_>,
) -> Result<Comparison, LabError> {
    let model = fit_model(prep, spec, progress)?;
    comparison_of(prep, model)
}

/// Compare an already fitted model with the recording.
pub fn comparison_of(prep: &Prepared, model: LabModel) -> Result<Comparison, LabError> {
    let recs = model.records(prep)?;
    if recs.len() <= model.n_params + 10 {
        return Err(LabError::data(format!(
            "only {} valid samples for {} parameters (saturation everywhere?)",
            recs.len(),
            model.n_params
        )));
    }
    // sequential sums: the same result on every run (a rayon sum's order is not)
    let chi2: f64 = recs.iter().map(Sample::chi2).sum();
    let n = recs.len();
    let dof = (n - model.n_params) as f64;
    let raw = (recs.iter().map(|r| f64::from(r.r).powi(2)).sum::<f64>() / n as f64).sqrt();
    let (d2, d4, depth) = depth_residuals(prep, &model)?;
    let structure = score_all(&recs, prep);
    let mut pix = vec![(0.0, 0usize); prep.npix];
    // illuminated samples: Σw r², count, Σw·A², Σ A²/var₁ (single acquisition)
    let (mut ci, mut ni, mut swa2, mut s1) = (0.0, 0usize, 0.0, 0.0);
    let mut sw = 0.0;
    let mut sw1 = 0.0;
    for s in &recs {
        let r = s.rec(prep);
        let e = &mut pix[r.pix as usize];
        e.0 += r.w * r.r * r.r;
        e.1 += 1;
        let avg = f64::from(prep.caps[r.cap as usize].averaged.max(1));
        sw += r.w;
        sw1 += r.w / avg;
        if r.a > 0.0 {
            ci += r.w * r.r * r.r;
            ni += 1;
            swa2 += r.w * r.a * r.a;
            s1 += r.w * r.a * r.a / avg;
        }
    }
    let mmr = prep.mm_per_rad();
    let share = dof / n as f64;
    let size = Size {
        lsb: crate::structure::structure_size(chi2 - dof, sw, 1.0, mmr).0,
        mm: crate::structure::structure_size(ci - ni as f64 * share, 1.0, swa2, mmr).1,
    };
    let noise_single = Size {
        lsb: if sw1 > 0.0 {
            (n as f64 / sw1).sqrt()
        } else {
            f64::NAN
        },
        mm: if s1 > 0.0 {
            (ni as f64 / s1).sqrt() * mmr
        } else {
            f64::NAN
        },
    };
    Ok(Comparison {
        size,
        noise_single,
        weight_sums: (sw, swa2),
        fit: FitStats::of(chi2, n, model.n_params),
        rms: Rms {
            raw_lsb: raw,
            depth_2phase_mm: d2,
            depth_4phase_mm: d4,
        },
        model,
        recs,
        chi2,
        n,
        dof,
        structure,
        depth,
        pixel_chi2: pix
            .iter()
            .map(|(s, c)| if *c > 0 { s / *c as f64 } else { f64::NAN })
            .collect(),
    })
}

fn wrap_pm(x: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let mut y = x.rem_euclid(t);
    if y > std::f64::consts::PI {
        y -= t;
    }
    y
}

/// Depth residuals after the model's calibration for 2- and 4-phase (eq. 2.2,
/// 2.3) over non-saturated captures with ground truth: RMS in mm and per-capture means.
///
/// The model is used as a calibration: its offsets and the codes its effects
/// add (SBI, dark current, droop, …) are subtracted from the measured codes,
/// and the depth of the corrected codes is compared with the depth of the
/// model's ideal codes A·C(φ − θ) (waveform and per-pixel phase included) at
/// the ground truth. Comparing the raw measured depth with the depth of the
/// model's full prediction instead would judge a common-mode effect by its
/// noise, not by its fit: a common-mode code δ (SBI, 5.1.2.3) moves the 2-phase
/// phasor's origin, and near |A·e^{iφ} + δ(1 + i)| ≈ 0 the phase noise σ/|z|
/// grows without bound although the model predicts δ exactly.
pub fn depth_residuals(
    prep: &Prepared,
    model: &LabModel,
) -> Result<(f64, f64, Vec<CaptureDepth>), LabError> {
    let sigs = model.signatures(prep)?;
    let mm_per_rad = prep.mm_per_rad();
    let find = |cap: &crate::prepared::CapInfo, deg: f64| {
        cap.phases_deg
            .iter()
            .position(|p| ((p - deg).rem_euclid(360.0)).min((deg - p).rem_euclid(360.0)) < 1e-6)
    };
    let npix = prep.npix;
    type PerCapture = Option<(f64, usize, f64, usize, CaptureDepth)>;
    let per: Vec<PerCapture> = (0..prep.caps.len())
        .into_par_iter()
        .map(|c| {
            let cap = &prep.caps[c];
            let d = cap.distance_m?;
            if !cap.illum || !cap.used {
                return None;
            }
            let i0 = find(cap, 0.0)?;
            let i90 = find(cap, 90.0)?;
            let four = find(cap, 180.0).zip(find(cap, 270.0));
            let (mut s2, mut n2, mut s4, mut n4) = (0.0, 0usize, 0.0, 0usize);
            let (mut m2, mut m4, mut am, mut amod) = (0.0, 0.0, 0.0, 0.0);
            // per raw image: the model's ideal code A·C and the codes its effects add
            let mut ideal = vec![0.0; cap.theta_rad.len()];
            let mut eff = vec![0.0; cap.theta_rad.len()];
            let mut eval = crate::fit::DeltaEval::new(&sigs, &model.effects);
            for p in 0..npix {
                if model.sat[c * npix + p] {
                    continue;
                }
                let o = prep.mid + model.offset[p];
                for (k, (v, e)) in ideal.iter_mut().zip(eff.iter_mut()).enumerate() {
                    if k == i0 || k == i90 || four.is_some_and(|(a, b)| k == a || k == b) {
                        let r = model.rec(prep, c, k, p);
                        *v = r.x - model.offset[p];
                        *e = eval.sum(&r, prep);
                    }
                }
                // measured codes calibrated by the model (offset and effects removed)
                let um = |k: usize| prep.meas[prep.idx(c, k, p)] - o - eff[k];
                let up = |k: usize| ideal[k];
                let e2 = wrap_pm(um(i90).atan2(um(i0)) - up(i90).atan2(up(i0))) * mm_per_rad; // eq. 2.2
                s2 += e2 * e2;
                m2 += e2;
                n2 += 1;
                if let Some((i180, i270)) = four {
                    let pm = (um(i90) - um(i270)).atan2(um(i0) - um(i180)); // eq. 2.3
                    let pp = (up(i90) - up(i270)).atan2(up(i0) - up(i180));
                    let e4 = wrap_pm(pm - pp) * mm_per_rad;
                    s4 += e4 * e4;
                    m4 += e4;
                    n4 += 1;
                    am += 0.5 * (um(i90) - um(i270)).hypot(um(i0) - um(i180)); // eq. 2.4
                    amod += 0.5 * (up(i90) - up(i270)).hypot(up(i0) - up(i180));
                }
            }
            if n2 == 0 {
                return None;
            }
            Some((
                s2,
                n2,
                s4,
                n4,
                CaptureDepth {
                    capture: c,
                    distance_m: d,
                    exposure_us: cap.exposure_us,
                    ambient_klux: cap.ambient_klux,
                    temperature_c: cap.temperature_c,
                    depth_2phase_mm: m2 / n2 as f64,
                    depth_4phase_mm: if n4 > 0 { m4 / n4 as f64 } else { f64::NAN },
                    measured_amplitude_lsb: if n4 > 0 { am / n4 as f64 } else { f64::NAN },
                    model_amplitude_lsb: if n4 > 0 { amod / n4 as f64 } else { f64::NAN },
                },
            ))
        })
        .collect();
    let (mut s2, mut n2, mut s4, mut n4) = (0.0, 0usize, 0.0, 0usize);
    let mut caps = Vec::new();
    for (a, b, c, d, e) in per.into_iter().flatten() {
        s2 += a;
        n2 += b;
        s4 += c;
        n4 += d;
        caps.push(e);
    }
    let rms = |s: f64, n: usize| {
        if n > 0 {
            (s / n as f64).sqrt()
        } else {
            f64::NAN
        }
    };
    Ok((rms(s2, n2), rms(s4, n4), caps))
}

/// One candidate effect scored against the residual.
#[derive(Debug, Clone, Serialize)]
pub struct CandidateScore {
    /// Catalogue id of the effect.
    pub effect: String,
    /// BIC(with) − BIC(without); negative supports the effect.
    pub delta_bic: f64,
    /// AIC(with) − AIC(without) ([`crate::stats::aic`]); negative supports
    /// the effect.
    pub delta_aic: f64,
    /// Share of the excess χ² (χ² − dof) the effect removes; NaN (no score,
    /// shown as "—") when the residual has no significant excess over the
    /// noise (z ≤ [`Z_NULL`] with the noise known from repeats): a share of a
    /// vanishing excess is a ratio of noise over noise. `explained` gives the
    /// size then.
    pub explained_excess: f64,
    /// The same share on held-out blocks of distance (5 block folds); NaN
    /// when `explained_excess` is.
    pub cv_gain: f64,
    /// Size of what the effect removes (χ² before − after, as
    /// `structure::structure_size`): depth-equivalent mm and LSB.
    pub explained: Size,
    /// z = (χ² − dof)/√(2 dof) after adding the effect.
    pub z_after: f64,
    /// Fitted parameters by name.
    pub params: BTreeMap<String, f64>,
    /// Their standard errors by name (from the curvature of χ² under the noise model; NaN
    /// for a parameter held on a grid).
    pub standard_errors: BTreeMap<String, f64>,
    /// Why a reported value was clamped (a share above 100 %, a negative
    /// z after): the raw figure and what it means.
    pub flags: Vec<String>,
    /// The parameters fitted at the bound of their range
    /// ([`crate::signatures::at_bounds`]), one sentence each.
    pub at_bound: Vec<String>,
    /// The fitted signature (None when the fit failed).
    #[serde(skip)]
    pub fit: Option<EffectFit>,
    /// Fitted global shifts of offset (LSB), relative gain and phase (rad).
    #[serde(skip)]
    pub nuisance: [f64; 3],
    /// Strongest structure score after refitting with the effect (top candidates only).
    #[serde(skip)]
    pub structure_after: Option<f64>,
    /// RMS errors after refitting with the effect (top candidates only).
    #[serde(skip)]
    pub rms_after: Option<Rms>,
    /// Whether the effect cancels in 4-phase ([`crate::signatures::cancels_in_4phase`]).
    #[serde(skip)]
    pub cancels_in_4phase: bool,
    /// The whole model refitted with this effect (the leading candidates only),
    /// never worse than the candidate's own fit on top of the model.
    #[serde(skip)]
    pub refit: Option<Box<LabModel>>,
    /// The law's form that was fitted: `physical`, or `shape_<K>_knots`
    /// (`crate::shape::choose_form`, by cross-validation on held-out blocks).
    pub form: String,
    /// Held-out χ² of every form tried (empty for an effect with one form).
    pub form_scores: Vec<crate::shape::FormScore>,
    /// The chosen shape's knots in the lab's driver units (None: physical).
    #[serde(skip)]
    pub knots: Option<Vec<f64>>,
}

/// Something the data still show that is smaller than the tolerance.
#[derive(Debug, Clone, Serialize)]
pub struct SmallStructure {
    /// A condition the residual is structured against, or a catalogue effect.
    pub name: String,
    /// `condition` or `effect`.
    pub kind: &'static str,
    /// Structure score (conditions) or the global z (effects: z before it).
    pub z: f64,
    /// Depth-equivalent RMS size in mm.
    pub size_mm: f64,
    /// RMS size in LSB.
    pub size_lsb: f64,
}

/// Settings of the verdict.
#[derive(Debug, Clone, Copy, Default)]
pub struct DiagnoseOptions {
    /// Remaining structure below this depth-equivalent RMS (mm) is not a
    /// missing effect; `None`: [`TOLERANCE_NOISE_SHARE`] × the
    /// single-acquisition noise of the recording.
    pub tolerance_mm: Option<f64>,
}

/// The lab's answer to "what is missing from the model?".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// One catalogue effect explains the residual.
    MissingEffect,
    /// The residual is noise.
    NothingMissing,
    /// Two effects explain it about equally; vary the named condition.
    Ambiguous,
    /// Something is missing that no catalogue effect explains — or the
    /// recording shows no signal the model can follow (the reason says which).
    Unexplained,
    /// The residual looks like noise, but the noise was not measured (no
    /// repeated captures or raw images), so it cannot be called noise.
    NoiseNotMeasured,
}

impl Verdict {
    /// The snake_case name used in reports and JSON.
    pub fn as_str(&self) -> &'static str {
        match self {
            Verdict::MissingEffect => "missing_effect",
            Verdict::NothingMissing => "nothing_missing",
            Verdict::Ambiguous => "ambiguous",
            Verdict::Unexplained => "unexplained",
            Verdict::NoiseNotMeasured => "noise_not_measured",
        }
    }
}

/// What is missing from the model, with the evidence.
#[derive(Debug, Clone)]
pub struct Diagnosis {
    /// The verdict.
    pub verdict: Verdict,
    /// The missing effect (`missing_effect`) or the best of two (`ambiguous`).
    pub effect: Option<String>,
    /// For `ambiguous`: the runner-up and the condition to vary.
    pub runner_up: Option<String>,
    /// For `ambiguous`: the condition whose variation separates the two.
    pub separate_by: Option<String>,
    /// Every scored candidate, best first.
    pub candidates: Vec<CandidateScore>,
    /// Candidates not scored, with why (effect id, reason).
    pub skipped: Vec<(String, String)>,
    /// Goodness of fit of the model without any candidate.
    pub fit: FitStats,
    /// The condition the remaining residual is most structured against.
    pub strongest_condition: Option<String>,
    /// RMS errors of the model without any candidate.
    pub rms: Rms,
    /// Structure scores of what remains to explain.
    pub structure_remaining: Vec<ConditionScore>,
    /// The verdict in one sentence.
    pub reason: String,
    /// Size of what remains unexplained by the model (before any candidate).
    pub size: Size,
    /// Single-acquisition noise in the same units.
    pub noise_single: Size,
    /// The tolerance the verdict used (mm, depth-equivalent RMS).
    pub tolerance_mm: f64,
    /// Detectable (structure z > 6) but below the tolerance.
    pub small: Vec<SmallStructure>,
    /// Where the noise the verdict is measured against came from.
    pub noise: NoiseSource,
}

/// Rank the catalogue effects the model lacks and give a verdict (default tolerance).
pub fn diagnose(
    prep: &Prepared,
    cmp: &Comparison,
    progress: Progress<'_>,
) -> Result<Diagnosis, LabError> {
    diagnose_with(prep, cmp, &DiagnoseOptions::default(), progress)
}

/// Rank the catalogue effects the model lacks and give a verdict.
pub fn diagnose_with(
    prep: &Prepared,
    cmp: &Comparison,
    opts: &DiagnoseOptions,
    progress: Progress<'_>,
) -> Result<Diagnosis, LabError> {
    let tolerance_mm = opts
        .tolerance_mm
        .unwrap_or_else(|| cmp.default_tolerance_mm());
    if let Some(why) = no_signal(prep, cmp) {
        return Ok(refused(cmp, why, tolerance_mm));
    }
    let noise_known = cmp.model.noise.source.measured();
    // Shares of the excess are scores only while there is an excess: at
    // z ≤ Z_NULL it is noise, and a share of it is noise over noise (values of
    // 10⁹ % when it vanishes). Then each candidate is given by its size only.
    let significant = !noise_known || cmp.fit.z > Z_NULL;
    let mut excess = (cmp.chi2 - cmp.dof).max(1e-9);
    let mut skipped = Vec::new();
    let ids = candidate_ids(prep, &cmp.model.spec, &mut skipped);
    let mut cands = screen_candidates(prep, cmp, &ids, excess, significant, progress, &mut skipped);
    if !noise_known {
        excess = rescale_to_best(&mut cands, excess);
    }
    cands.sort_by(rank);
    let remaining = refit_leaders(prep, cmp, &mut cands, excess, significant)?;
    // re-rank with the refitted evidence (as reported: clamped, see `clamp_reported`)
    cands.iter_mut().for_each(clamp_reported);
    cands.sort_by(rank);
    progress("candidates", 1.0);
    let (d, remaining_structure) = verdict_of(prep, cmp, &cands, remaining, noise_known);
    let strongest = strongest_condition(&remaining_structure);
    let (mut d, small, remaining_mm) = apply_tolerance(cmp, opts, tolerance_mm, &cands, d);
    (d.verdict, d.reason) = honest_verdict(cmp, d.verdict, d.reason);
    if d.verdict != Verdict::MissingEffect && d.verdict != Verdict::Ambiguous {
        d.effect = None;
        d.runner_up = None;
        d.separate_by = None;
    }
    Ok(Diagnosis {
        noise: cmp.model.noise.source,
        size: Size {
            lsb: cmp.size.lsb,
            mm: remaining_mm,
        },
        noise_single: cmp.noise_single,
        tolerance_mm,
        small,
        verdict: d.verdict,
        effect: d.effect,
        runner_up: d.runner_up,
        separate_by: d.separate_by,
        candidates: cands,
        skipped,
        fit: cmp.fit,
        strongest_condition: strongest,
        rms: cmp.rms,
        structure_remaining: remaining_structure,
        reason: d.reason,
    })
}

/// The catalogue effects the model lacks and the recording can identify;
/// the others go to `skipped` with why.
fn candidate_ids(
    prep: &Prepared,
    spec: &LabSpec,
    skipped: &mut Vec<(String, String)>,
) -> Vec<&'static str> {
    SIGNATURE_IDS
        .iter()
        .copied()
        .filter(|id| !spec.effects.iter().any(|e| e == id))
        .filter(|id| match not_identifiable(id, prep, spec) {
            Some(why) => {
                skipped.push((id.to_string(), why));
                false
            }
            None => true,
        })
        .collect()
}

/// Screening: each candidate's signature fitted to the residuals in parallel;
/// the ones whose fit failed go to `skipped`.
fn screen_candidates(
    prep: &Prepared,
    cmp: &Comparison,
    ids: &[&str],
    excess: f64,
    significant: bool,
    progress: Progress<'_>,
    skipped: &mut Vec<(String, String)>,
) -> Vec<CandidateScore> {
    progress("candidates", 0.0);
    let done = std::sync::atomic::AtomicUsize::new(0);
    let fits: Vec<Result<CandidateScore, (String, LabError)>> = ids
        .par_iter()
        .map(|id| {
            let c = screen_candidate(id, prep, cmp, excess, significant)
                .map_err(|e| (id.to_string(), e))?;
            let k = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            progress("candidates", k as f64 / ids.len().max(1) as f64);
            Ok(c)
        })
        .collect();
    let mut cands = Vec::new();
    for f in fits {
        match f {
            Ok(c) => cands.push(c),
            Err((id, e)) => {
                tracing::warn!("candidate {id} failed: {e}");
                skipped.push((id, format!("fit failed: {e}")));
            }
        }
    }
    cands
}

/// One candidate's screening score: its signature fitted to the residuals of
/// the model as it is (shares of the excess only when `significant`).
fn screen_candidate(
    id: &str,
    prep: &Prepared,
    cmp: &Comparison,
    excess: f64,
    significant: bool,
) -> Result<CandidateScore, LabError> {
    let share = |x: f64| if significant { x } else { f64::NAN };
    let (sig, f, knots, form_scores) = if crate::shape::has_shape_form(id) {
        let c =
            crate::shape::choose_form(id, prep, &cmp.model.spec, &cmp.model.waveform, &cmp.recs)?;
        (c.signature, c.fit, c.knots, c.scores)
    } else {
        let sig = make_signature(id, prep, &cmp.model.spec, &cmp.model.waveform)?;
        let f = fit_signature(sig.as_ref(), &cmp.recs, prep, None)?;
        (sig, f, None, Vec::new())
    };
    let dchi = (f.chi2_before - f.chi2).max(0.0);
    let chi_after = cmp.chi2 - dchi;
    let dof_after = cmp.dof - f.n_params as f64;
    let mut params = BTreeMap::new();
    let mut standard_errors = BTreeMap::new();
    let names = sig.lin_names().into_iter().chain(sig.nl_names());
    let values = f
        .lin
        .iter()
        .chain(&f.nl)
        .zip(f.lin_se.iter().chain(&f.nl_se));
    for (n, (v, se)) in names.zip(values) {
        params.insert(n.clone(), *v);
        standard_errors.insert(n, *se);
    }
    Ok(CandidateScore {
        effect: id.to_string(),
        delta_bic: bic(chi_after, f.n_params, cmp.n) - bic(cmp.chi2, 0, cmp.n),
        delta_aic: crate::stats::aic(chi_after, f.n_params) - crate::stats::aic(cmp.chi2, 0),
        explained_excess: share(dchi / excess),
        cv_gain: share((f.cv_chi2_before - f.cv_chi2) / excess),
        explained: cmp.size_of(dchi, prep),
        z_after: chi2_z(chi_after, dof_after),
        params,
        standard_errors,
        flags: Vec::new(),
        at_bound: crate::signatures::at_bounds(sig.as_ref(), &f.nl),
        fit: Some(EffectFit {
            id: id.to_string(),
            lin: f.lin,
            nl: f.nl,
        }),
        nuisance: f.nuisance,
        structure_after: None,
        rms_after: None,
        cancels_in_4phase: cancels_in_4phase(id),
        refit: None,
        form: crate::shape::form_name(knots.as_ref()),
        form_scores,
        knots,
    })
}

/// Without repeated captures the noise was estimated from residuals that
/// contain the structure, so χ² − dof understates the excess: shares are
/// measured against the best explanation instead. Returns the excess used.
fn rescale_to_best(cands: &mut [CandidateScore], excess: f64) -> f64 {
    let best = cands
        .iter()
        .map(|c| c.explained_excess * excess)
        .fold(0.0f64, f64::max);
    if best <= excess {
        return excess;
    }
    let f = excess / best;
    for c in cands.iter_mut() {
        c.explained_excess *= f;
        c.cv_gain *= f;
    }
    best
}

/// The leading candidates are refitted with the whole model (the per-pixel
/// parameters re-adjust with the effect present): z after, structure left
/// and depth errors after come from that refit. Returns the structure each
/// refit leaves, in refit order.
fn refit_leaders(
    prep: &Prepared,
    cmp: &Comparison,
    cands: &mut [CandidateScore],
    excess: f64,
    significant: bool,
) -> Result<Vec<Vec<ConditionScore>>, LabError> {
    // The runner-up is refitted only when it could compete (screening share
    // at least half the leader's).
    // (none without an excess: the verdict is `nothing_missing` whatever they do)
    let mut top: Vec<usize> = (0..cands.len().min(usize::from(significant))).collect();
    if cands.len() > 1
        && cands[1].explained_excess >= 0.5 * cands[0].explained_excess.max(0.0)
        && cands[1].explained_excess > 0.05
    {
        top.push(1);
    }
    // One after the other (each refit is parallel inside): only one refitted
    // residual table is alive beside the comparison's.
    let mut remaining: Vec<Vec<ConditionScore>> = Vec::new();
    for i in top {
        remaining.push(refit_leader(prep, cmp, &mut cands[i], excess)?);
    }
    Ok(remaining)
}

/// Refit one leading candidate with the whole model and record its evidence
/// after the refit; returns the structure the refit leaves.
fn refit_leader(
    prep: &Prepared,
    cmp: &Comparison,
    c: &mut CandidateScore,
    excess: f64,
) -> Result<Vec<ConditionScore>, LabError> {
    let fit = c
        .fit
        .clone()
        .ok_or_else(|| LabError::numerical("candidate without fit"))?;
    let base = with_form(&cmp.model, &c.effect, c.knots.as_ref());
    let m = crate::fit::refit_with(prep, &base, &fit, c.nuisance, 3)?;
    let mut c2 = comparison_of(prep, m)?;
    c.explained_excess = c.explained_excess.max((cmp.chi2 - c2.chi2) / excess);
    c.z_after = c2.fit.z;
    c.delta_bic = bic(c2.chi2, c2.model.n_params, cmp.n) - bic(cmp.chi2, cmp.model.n_params, cmp.n);
    c.delta_aic = crate::stats::aic(c2.chi2, c2.model.n_params)
        - crate::stats::aic(cmp.chi2, cmp.model.n_params);
    c.structure_after = Some(c2.structure.first().map(|s| s.z).unwrap_or(0.0));
    if let Some(gain) = refit_cv_gain(prep, &mut c2, c)? {
        c.cv_gain = c.cv_gain.max(gain);
    }
    c.rms_after = Some(c2.rms);
    c.refit = Some(Box::new(c2.model));
    Ok(c2.structure)
}

/// `model` with effect `id`'s law in the form of `knots` (a shape; `None`:
/// the parametric form) for what is fitted next.
fn with_form(model: &LabModel, id: &str, knots: Option<&Vec<f64>>) -> LabModel {
    let mut m = model.clone();
    match knots {
        Some(k) => m.spec.shapes.insert(id.to_string(), k.clone()),
        None => m.spec.shapes.remove(id),
    };
    m
}

/// Cross-validate again on the refitted model (the per-pixel parameters no
/// longer absorb the effect): the effect's contribution is put back into the
/// residual and refitted on training blocks only. (the residual of the
/// refitted model without the effect: for an effect on the phasor its A and φ
/// change too, not only the codes). `None` when there is nothing to credit.
fn refit_cv_gain(
    prep: &Prepared,
    c2: &mut Comparison,
    c: &CandidateScore,
) -> Result<Option<f64>, LabError> {
    let Some(i) = c2.model.effects.iter().position(|e| e.id == c.effect) else {
        return Ok(None);
    };
    let sig = make_signature(&c.effect, prep, &c2.model.spec, &c2.model.waveform)?;
    c2.recs = Vec::new();
    let mut without = c2.model.clone();
    let e = without.effects.remove(i);
    let recs = without.records(prep)?;
    let f = fit_values(sig.as_ref(), &recs, prep, Some(&e))?;
    let ex = f.chi2_before - c2.dof;
    // never credited beyond what the refit explains of the baseline excess
    Ok((ex > 0.0).then(|| ((f.cv_chi2_before - f.cv_chi2) / ex).min(c.explained_excess)))
}

/// The verdict from the fit and the ranked candidates, with the structure
/// that remains to explain.
fn verdict_of(
    prep: &Prepared,
    cmp: &Comparison,
    cands: &[CandidateScore],
    remaining: Vec<Vec<ConditionScore>>,
    noise_known: bool,
) -> (Decision, Vec<ConditionScore>) {
    let struct_base = cmp.structure.first().map(|s| s.z).unwrap_or(0.0);
    let mut d = decide(cmp.fit.z, cmp.fit.chi2_per_dof, struct_base, cands);
    if !noise_known && d.verdict == Verdict::NothingMissing && struct_base > STRUCTURE_NULL {
        // the global z is not trustworthy without repeats; structure decides
        d = decide(f64::INFINITY, f64::INFINITY, struct_base, cands);
    }
    let remaining_structure = if d.verdict == Verdict::Unexplained
        && cands.first().is_some_and(|c| c.explained_excess > 0.3)
    {
        remaining
            .into_iter()
            .next()
            .unwrap_or_else(|| cmp.structure.clone())
    } else {
        cmp.structure.clone()
    };
    if d.verdict == Verdict::Ambiguous
        && let (Some(a), Some(b)) = (&d.effect, &d.runner_up)
    {
        d.separate_by = Some(separating_condition(a, b, prep));
    }
    (d, remaining_structure)
}

/// Detectable is not the same as relevant: with 10⁶ samples any small
/// departure of the true law from the model's is significant. What remains
/// is compared, in depth-equivalent mm, with a tolerance tied to the noise.
/// Returns the decision, the detectable-but-small structures and the size
/// of what remains (mm).
fn apply_tolerance(
    cmp: &Comparison,
    opts: &DiagnoseOptions,
    tolerance_mm: f64,
    cands: &[CandidateScore],
    mut d: Decision,
) -> (Decision, Vec<SmallStructure>, f64) {
    // without repeats the global excess is not known: the structure's size counts
    let top_structure = cmp
        .structure
        .iter()
        .map(|s| s.size_mm)
        .fold(0.0f64, f64::max);
    let remaining_mm = cmp.size.mm.max(top_structure);
    let mut small = Vec::new();
    // a catalogue effect that leaves noise-like residuals is named however small
    let fully_explained = d.verdict == Verdict::MissingEffect
        && cands
            .first()
            .is_some_and(|c| c.z_after <= Z_NULL && c.explained_excess >= MIN_EXPLAINED);
    if remaining_mm <= tolerance_mm && !fully_explained {
        small = small_structures(cmp, &d);
        if d.verdict != Verdict::NothingMissing {
            d = below_tolerance(cmp, opts, tolerance_mm, remaining_mm);
        }
    }
    (d, small, remaining_mm)
}

/// The structures detectable (z > STRUCTURE_NULL) but below the tolerance:
/// the conditions, and the effect `d` names unless nothing is missing.
fn small_structures(cmp: &Comparison, d: &Decision) -> Vec<SmallStructure> {
    let mut small = Vec::new();
    for st in cmp.structure.iter().filter(|s| s.z > STRUCTURE_NULL) {
        small.push(SmallStructure {
            name: st.condition.clone(),
            kind: "condition",
            z: st.z,
            size_mm: st.size_mm,
            size_lsb: st.size_lsb,
        });
    }
    if d.verdict != Verdict::NothingMissing
        && let Some(e) = &d.effect
    {
        small.push(SmallStructure {
            name: e.clone(),
            kind: "effect",
            z: cmp.fit.z,
            size_mm: cmp.size.mm,
            size_lsb: cmp.size.lsb,
        });
    }
    small
}

/// The `nothing_missing` decision for what remains below the tolerance.
fn below_tolerance(
    cmp: &Comparison,
    opts: &DiagnoseOptions,
    tolerance_mm: f64,
    remaining_mm: f64,
) -> Decision {
    Decision {
        verdict: Verdict::NothingMissing,
        effect: None,
        runner_up: None,
        separate_by: None,
        reason: format!(
            "what remains ({remaining_mm:.2} mm depth-equivalent, {:.2} LSB, z = {:.1}) is below the tolerance {tolerance_mm:.2} mm{}",
            cmp.size.lsb,
            cmp.fit.z,
            if opts.tolerance_mm.is_none() {
                format!(
                    " ({TOLERANCE_NOISE_SHARE} × the single-acquisition noise {:.2} mm)",
                    cmp.noise_single.mm
                )
            } else {
                String::new()
            }
        ),
    }
}

/// The share of the codes' modulation the model must follow, below which a
/// recording shows no signal the model can follow (random codes, constant
/// frames, the wrong distances).
pub const MIN_SIGNAL_SHARE: f64 = 0.25;

/// Why the recording cannot be diagnosed at all: its illuminated codes do not
/// follow the illumination. What random and constant frames lack is the
/// modulation the phase–distance relation (eq. 2.6) and the falling amplitude
/// put into the raw images of one capture: the share of the measured codes'
/// variation over a capture's raw images (each pixel's mean removed, so
/// offsets and the background do not count) that the model follows,
/// `1 − Σ(r − r̄)² / Σ(y − ȳ)²`. A model error the lab is there to find
/// (a drift of 0.5 rad leaves 1 − (2 sin 0.25)² ≈ 76 %) or noise at an
/// amplitude-to-σ ratio above ~1 keep it above [`MIN_SIGNAL_SHARE`]; random
/// codes give ~0, constant frames have no variation at all. It rests on no
/// noise estimate, so a residual-based one inflated by a missing effect
/// cannot trip it.
fn no_signal(prep: &Prepared, cmp: &Comparison) -> Option<String> {
    // per (capture, pixel), indexed c·npix + p: n, Σy, Σy², Σr, Σr²
    let mut groups = vec![[0.0f64; 5]; prep.caps.len() * prep.npix];
    for r in cmp.recs.iter().filter(|r| prep.caps[r.cap as usize].illum) {
        let y = prep.meas[prep.idx(r.cap as usize, usize::from(r.k), r.pix as usize)];
        let res = f64::from(r.r);
        let g = &mut groups[r.cap as usize * prep.npix + r.pix as usize];
        for (s, v) in g.iter_mut().zip([1.0, y, y * y, res, res * res]) {
            *s += v;
        }
    }
    let centred = |n: f64, s: f64, s2: f64| (s2 - s * s / n).max(0.0);
    let (mut var_y, mut var_r, mut any) = (0.0, 0.0, false);
    for [n, sy, sy2, sr, sr2] in groups.into_iter().filter(|g| g[0] > 0.0) {
        var_y += centred(n, sy, sy2);
        var_r += centred(n, sr, sr2);
        any = true;
    }
    if !any {
        return Some("no valid illuminated sample (all saturated or dark)".into());
    }
    let share = if var_y > 0.0 {
        1.0 - var_r / var_y
    } else {
        f64::NEG_INFINITY
    };
    (share < MIN_SIGNAL_SHARE).then(|| {
        format!(
            "no signal: the model follows {:.0} % of the codes' variation over each capture's \
             raw images (needs ≥ {:.0} %); the codes do not follow the illumination at the \
             recorded distances (random or constant frames?)",
            100.0 * share.max(0.0),
            100.0 * MIN_SIGNAL_SHARE
        )
    })
}

/// The diagnosis of a recording that cannot be diagnosed (`unexplained`, no candidates).
fn refused(cmp: &Comparison, reason: String, tolerance_mm: f64) -> Diagnosis {
    Diagnosis {
        verdict: Verdict::Unexplained,
        effect: None,
        runner_up: None,
        separate_by: None,
        candidates: Vec::new(),
        skipped: Vec::new(),
        fit: cmp.fit,
        strongest_condition: None,
        rms: cmp.rms,
        structure_remaining: cmp.structure.clone(),
        reason,
        size: cmp.size,
        noise_single: cmp.noise_single,
        tolerance_mm,
        small: Vec::new(),
        noise: cmp.model.noise.source,
    }
}

/// Below this χ²/dof the residual is smaller than the measured noise by more
/// than any fit could make it: the noise estimate does not describe the data.
pub const MIN_CHI2_PER_DOF: f64 = 0.8;

/// `nothing_missing` only where the noise was measured and describes the
/// residual: otherwise `noise_not_measured`, or `unexplained` with the reason.
fn honest_verdict(cmp: &Comparison, verdict: Verdict, reason: String) -> (Verdict, String) {
    if verdict != Verdict::NothingMissing {
        return (verdict, reason);
    }
    if !cmp.model.noise.source.measured() {
        return (
            Verdict::NoiseNotMeasured,
            format!(
                "the residual looks like noise ({reason}), but the noise is {}: record repeated captures to tell noise from a missing effect",
                cmp.model.noise.source.describe()
            ),
        );
    }
    if cmp.fit.chi2_per_dof < MIN_CHI2_PER_DOF {
        return (
            Verdict::Unexplained,
            format!(
                "the residual is far below the measured noise (χ²/dof = {:.3} < {MIN_CHI2_PER_DOF}): the repeats' noise does not describe this recording",
                cmp.fit.chi2_per_dof
            ),
        );
    }
    (verdict, reason)
}

/// No share above 100 % and no negative z after reaches a report: the value
/// is clamped and the raw figure kept in `flags` with its meaning.
fn clamp_reported(c: &mut CandidateScore) {
    for (name, v) in [
        ("explains", &mut c.explained_excess),
        ("explains on held-out blocks", &mut c.cv_gain),
    ] {
        if *v > 1.0 {
            c.flags.push(format!(
                "{name} {:.0}% of the excess: more than there is (what remains is below the noise expectation); shown as 100%",
                100.0 * *v
            ));
            *v = 1.0;
        }
    }
    if c.z_after < 0.0 {
        if c.z_after < -Z_NULL {
            c.flags.push(format!(
                "z after {:.1}: χ² after is far below its noise expectation (the noise is overestimated or the effect fits noise); shown as 0",
                c.z_after
            ));
        }
        c.z_after = 0.0;
    }
}

/// Candidate order: by held-out share, then share, then (when there is no
/// excess to share) by the size of what the candidate removes.
fn rank(a: &CandidateScore, b: &CandidateScore) -> std::cmp::Ordering {
    let key = |x: f64| if x.is_nan() { f64::NEG_INFINITY } else { x };
    key(b.cv_gain)
        .total_cmp(&key(a.cv_gain))
        .then(key(b.explained_excess).total_cmp(&key(a.explained_excess)))
        .then(b.explained.lsb.total_cmp(&a.explained.lsb))
}

/// The condition the residual is most structured against. Acquisition order
/// (`capture_index`) stands in for every condition the sweep stepped through,
/// so it is named only when it clearly beats all physical conditions.
pub fn strongest_condition(st: &[ConditionScore]) -> Option<String> {
    let best_phys = st
        .iter()
        .filter(|s| s.condition != "capture_index")
        .max_by(|a, b| a.z.total_cmp(&b.z));
    let order = st.iter().find(|s| s.condition == "capture_index");
    match (best_phys, order) {
        (Some(p), Some(o)) if o.z > 2.0 * p.z.max(0.0) => Some(o.condition.clone()),
        (Some(p), _) => Some(p.condition.clone()),
        (None, Some(o)) => Some(o.condition.clone()),
        (None, None) => None,
    }
}

/// Outcome of the decision rule (separate for testing).
#[derive(Debug, Clone, PartialEq)]
pub struct Decision {
    /// As [`Diagnosis::verdict`].
    pub verdict: Verdict,
    /// As [`Diagnosis::effect`].
    pub effect: Option<String>,
    /// As [`Diagnosis::runner_up`].
    pub runner_up: Option<String>,
    /// As [`Diagnosis::separate_by`].
    pub separate_by: Option<String>,
    /// As [`Diagnosis::reason`].
    pub reason: String,
}

/// Several missing effects: most of the excess explained, on held-out blocks too.
fn passes_partial(c: &CandidateScore) -> bool {
    c.explained_excess >= MIN_PARTIAL && c.cv_gain >= MIN_PARTIAL
}

/// `best` is clearly better than `runner_up` (partial acceptance needs it).
fn clearly_best(best: &CandidateScore, runner_up: Option<&CandidateScore>) -> bool {
    runner_up.is_none_or(|ru| {
        ru.cv_gain <= 0.5 * best.cv_gain || best.cv_gain - ru.cv_gain >= 2.5 * AMBIGUITY_MARGIN
    })
}

fn passes(c: &CandidateScore, z_base: f64, struct_base: f64) -> bool {
    let noise_like = c.z_after <= Z_NULL;
    let z_ok = c.z_after <= Z_NULL.max(0.1 * z_base);
    let s_ok = c
        .structure_after
        .is_none_or(|s| s <= STRUCTURE_NULL.max(0.1 * struct_base));
    // When the residual after the fit is noise-like, the remaining "excess" is
    // noise and the explained share need not be large.
    (c.explained_excess >= MIN_EXPLAINED || noise_like)
        && c.cv_gain >= MIN_CV.min(0.7 * c.explained_excess)
        && z_ok
        && s_ok
}

/// The verdict from the global fit and the ranked candidates (sorted by cv_gain).
/// ΔBIC alone is never enough: an effect must explain most of the excess, hold
/// up on held-out blocks, leave noise-like residuals and beat the runner-up.
pub fn decide(
    z_base: f64,
    chi2_per_dof: f64,
    struct_base: f64,
    cands: &[CandidateScore],
) -> Decision {
    if z_base <= Z_NULL || (chi2_per_dof <= 1.02 && struct_base <= STRUCTURE_NULL) {
        return Decision {
            verdict: Verdict::NothingMissing,
            effect: None,
            runner_up: None,
            separate_by: None,
            reason: format!(
                "residual consistent with noise (z = {z_base:.1}, χ²/dof = {chi2_per_dof:.3}, strongest structure z = {struct_base:.1})"
            ),
        };
    }
    let Some(best) = cands.first() else {
        return Decision {
            verdict: Verdict::Unexplained,
            effect: None,
            runner_up: None,
            separate_by: None,
            reason: "misfit but no candidate effect could be fitted".into(),
        };
    };
    let full = passes(best, z_base, struct_base);
    let partial = passes_partial(best) && clearly_best(best, cands.get(1));
    if !(full || partial) {
        return Decision {
            verdict: Verdict::Unexplained,
            effect: None,
            runner_up: None,
            separate_by: None,
            reason: format!(
                "best candidate {} explains {:.0}% of the excess (cv {:.0}%, z after {:.1}): not enough",
                best.effect,
                100.0 * best.explained_excess,
                100.0 * best.cv_gain,
                best.z_after
            ),
        };
    }
    // Occam: a runner-up with more parameters that explains no more than the
    // best does not make the verdict ambiguous
    let simpler_suffices = |ru: &CandidateScore| {
        best.params.len() < ru.params.len()
            && best.explained_excess >= ru.explained_excess
            && best.cv_gain >= ru.cv_gain
    };
    if let Some(ru) = cands.get(1)
        && (passes(ru, z_base, struct_base) || passes_partial(ru))
        && !simpler_suffices(ru)
        && best.cv_gain - ru.cv_gain < AMBIGUITY_MARGIN
        && (best.explained_excess - ru.explained_excess) < AMBIGUITY_MARGIN
        && (1.0 - ru.explained_excess) < REMAINDER_RATIO * (1.0 - best.explained_excess).max(0.0)
    {
        return Decision {
            verdict: Verdict::Ambiguous,
            effect: Some(best.effect.clone()),
            runner_up: Some(ru.effect.clone()),
            separate_by: None,
            reason: format!(
                "{} and {} explain the residual equally well ({:.0}% vs {:.0}%)",
                best.effect,
                ru.effect,
                100.0 * best.explained_excess,
                100.0 * ru.explained_excess
            ),
        };
    }
    Decision {
        verdict: Verdict::MissingEffect,
        effect: Some(best.effect.clone()),
        runner_up: cands.get(1).map(|c| c.effect.clone()),
        separate_by: None,
        reason: format!(
            "{} explains {:.0}% of the excess χ² ({:.0}% on held-out distance blocks), z after {:.1}{}",
            best.effect,
            100.0 * best.explained_excess,
            100.0 * best.cv_gain,
            best.z_after,
            if full {
                ""
            } else {
                "; structure remains after it: add it and diagnose again (`lab explain` continues)"
            }
        ),
    }
}

/// A condition that one of two effects varies with and the other does not,
/// preferring one the recording did not vary.
pub fn separating_condition(a: &str, b: &str, prep: &Prepared) -> String {
    let ca = effect_conditions(a);
    let cb = effect_conditions(b);
    let mut diff: Vec<Driver> = ca
        .iter()
        .filter(|c| !cb.contains(c))
        .chain(cb.iter().filter(|c| !ca.contains(c)))
        .copied()
        .collect();
    let varied = |c: Driver| match c {
        Driver::AmbientKlux => prep.ambient_varies,
        Driver::TemperatureC => prep.temperature_varies,
        Driver::ExposureUs => prep.exposure_varies,
        _ => true,
    };
    diff.sort_by_key(|c| varied(*c));
    diff.first()
        .copied()
        .unwrap_or(Driver::ExposureUs)
        .as_str()
        .to_string()
}

/// The spec with one more effect enabled.
pub fn spec_with(spec: &LabSpec, effect: &str) -> LabSpec {
    let mut s = spec.clone();
    crate::signatures::enable_in_spec(&mut s, effect);
    s
}

/// Before/after of adding one effect.
#[derive(Debug, Clone, Serialize)]
pub struct ErrorSummary {
    /// As [`Rms::raw_lsb`].
    pub raw_lsb: f64,
    /// As [`Rms::depth_2phase_mm`].
    pub depth_2phase_mm: f64,
    /// As [`Rms::depth_4phase_mm`].
    pub depth_4phase_mm: f64,
    /// As [`FitStats::chi2_per_dof`].
    pub chi2_per_dof: f64,
    /// As [`FitStats::aic`].
    pub aic: f64,
    /// As [`FitStats::bic`].
    pub bic: f64,
}

impl ErrorSummary {
    /// The errors of one comparison.
    pub fn of(c: &Comparison) -> Self {
        Self {
            raw_lsb: c.rms.raw_lsb,
            depth_2phase_mm: c.rms.depth_2phase_mm,
            depth_4phase_mm: c.rms.depth_4phase_mm,
            chi2_per_dof: c.fit.chi2_per_dof,
            aic: c.fit.aic,
            bic: c.fit.bic,
        }
    }
}

/// The result of [`add_effect`].
pub struct AddOutcome {
    /// The model without the effect.
    pub before: Comparison,
    /// The model refitted with it.
    pub after: Comparison,
    /// The effect's fitted signature.
    pub effect: EffectFit,
    /// Its parameters by name.
    pub params: BTreeMap<String, f64>,
    /// Their standard errors by name ([`fitted_effect`]).
    pub standard_errors: BTreeMap<String, f64>,
    /// Why those errors understate how far the values may be off (None when
    /// the model with the effect fits to the noise: [`errors_note`]).
    pub standard_errors_note: Option<String>,
    /// The parameters fitted at the bound of their range ([`FittedEffect::at_bound`]).
    pub at_bound: Vec<String>,
    /// Profile intervals of the non-linear parameters ([`FittedEffect::intervals`]).
    pub intervals: BTreeMap<String, crate::uncertainty::ProfileInterval>,
}

/// Enable `effect` in the spec, refit everything, and compare before/after.
pub fn add_effect(
    prep: &Prepared,
    spec: &LabSpec,
    effect: &str,
    progress: Progress<'_>,
) -> Result<AddOutcome, LabError> {
    check_addable(prep, spec, effect)?;
    let before = compare(prep, spec, progress)?;
    add_effect_to(prep, before, effect, None, progress)
}

fn check_addable(prep: &Prepared, spec: &LabSpec, effect: &str) -> Result<(), LabError> {
    if !SIGNATURE_IDS.contains(&effect) {
        return Err(LabError::new(
            ErrorKind::UnknownEffect,
            format!(
                "the lab cannot add `{effect}` (it can add: {})",
                SIGNATURE_IDS.join(", ")
            ),
        ));
    }
    if spec.effects.iter().any(|e| e == effect) {
        return Err(LabError::new(
            ErrorKind::InvalidModel,
            format!("`{effect}` is already enabled in the model"),
        ));
    }
    if let Some(why) = not_identifiable(effect, prep, spec) {
        return Err(LabError::new(
            ErrorKind::NotIdentifiable,
            format!("cannot fit `{effect}`: {why}"),
        ));
    }
    Ok(())
}

/// Add `effect` to the fitted model of `before`. Two fits compete and the
/// better (lower χ²/dof) is kept: the whole model refined from the
/// candidate's fit on top of `before` (`start`: a refit `diagnose` already
/// made) with step control, so it never ends worse than that start; and a fit
/// of the extended model from scratch.
pub fn add_effect_to(
    prep: &Prepared,
    before: Comparison,
    effect: &str,
    start: Option<&LabModel>,
    progress: Progress<'_>,
) -> Result<AddOutcome, LabError> {
    let spec = before.model.spec.clone();
    check_addable(prep, &spec, effect)?;
    let mut spec2 = spec_with(&spec, effect);
    let mut warm = match start {
        Some(m) => m.clone(),
        None => {
            // the law's form by cross-validation (crate::shape), then its fit
            let c = crate::shape::choose_form(
                effect,
                prep,
                &spec,
                &before.model.waveform,
                &before.recs,
            )?;
            let fit = EffectFit {
                id: effect.to_string(),
                lin: c.fit.lin,
                nl: c.fit.nl,
            };
            let base = with_form(&before.model, effect, c.knots.as_ref());
            crate::fit::refit_with(prep, &base, &fit, c.fit.nuisance, 3)?
        }
    };
    if let Some(k) = warm.spec.shapes.get(effect) {
        spec2.shapes.insert(effect.to_string(), k.clone());
    }
    crate::fit::refine(prep, &mut warm, 4, false, true, &|_, _| {})?;
    let warm = comparison_of(prep, warm)?;
    let scratch = compare(prep, &spec2, progress)?;
    let after = if scratch.fit.chi2_per_dof < warm.fit.chi2_per_dof {
        scratch
    } else {
        warm
    };
    let f = fitted_effect(prep, &after, effect)?;
    let (fitted, _) = effect_params(prep, &after.model, effect)?;
    Ok(AddOutcome {
        before,
        after,
        effect: fitted,
        params: f.params,
        standard_errors: f.standard_errors,
        standard_errors_note: f.standard_errors_note,
        at_bound: f.at_bound,
        intervals: f.intervals,
    })
}

/// A fitted effect's parameters with their standard errors (`lab add`, `lab explain`).
#[derive(Debug, Clone, Serialize)]
pub struct FittedEffect {
    /// Catalogue id.
    pub effect: String,
    /// Its parameters by the signature's names ([`effect_params`]).
    pub params: BTreeMap<String, f64>,
    /// The standard error of each, same names: √diag((JᵀWJ)⁻¹) over the effect's parameters
    /// and the global offset/gain/phase shifts at the fitted values, W = 1/σ² of the noise
    /// model, the per-pixel parameters held (as [`CandidateScore::standard_errors`]); NaN for
    /// a parameter held on a grid and for the waveform's harmonics (fitted inside the
    /// waveform, not as a signature).
    pub standard_errors: BTreeMap<String, f64>,
    /// Why those errors understate how far the values may be off ([`errors_note`]).
    pub standard_errors_note: Option<String>,
    /// The parameters fitted at the bound of their range, one sentence each
    /// ([`crate::signatures::at_bounds`]).
    pub at_bound: Vec<String>,
    /// Profile-likelihood intervals of the non-linear parameters by name
    /// ([`crate::uncertainty::profile_intervals`]).
    pub intervals: BTreeMap<String, crate::uncertainty::ProfileInterval>,
}

/// The standard errors rest on the noise model alone: they say how far the
/// values may be off only where the model fits to the noise. Where the model
/// with the effect still leaves an excess χ² (z > [`Z_NULL`]) or structure
/// against a condition (z > [`STRUCTURE_NULL`]), the law fitted and the
/// truth's differ by more than the noise, and the values can be off by many
/// of these errors (docs/lab.md, worked example: τ and β, 14 and 20 of them):
/// the note says so, with the figures it rests on.
pub fn errors_note(cmp: &Comparison) -> Option<String> {
    let strongest = cmp
        .structure
        .iter()
        .max_by(|a, b| a.z.total_cmp(&b.z))
        .filter(|s| s.z > STRUCTURE_NULL);
    if cmp.fit.z <= Z_NULL && strongest.is_none() {
        return None;
    }
    let structure = strongest.map_or_else(String::new, |s| {
        format!(
            ", structure z {:.1} against {} (≤ {STRUCTURE_NULL} for noise)",
            s.z, s.condition
        )
    });
    Some(format!(
        "errors of the noise alone: with it the model leaves χ²/dof {:.3} (z {:.1}, ≤ {Z_NULL} for noise){structure}, so the values may be off by more than these errors",
        cmp.fit.chi2_per_dof, cmp.fit.z
    ))
}

/// `effect` as fitted in the model of `cmp` (which must hold its residual table), with the
/// standard errors of its parameters.
pub fn fitted_effect(
    prep: &Prepared,
    cmp: &Comparison,
    effect: &str,
) -> Result<FittedEffect, LabError> {
    let (fit, params) = effect_params(prep, &cmp.model, effect)?;
    let mut standard_errors: BTreeMap<String, f64> =
        params.keys().map(|k| (k.clone(), f64::NAN)).collect();
    let mut at_bound = Vec::new();
    let mut intervals = BTreeMap::new();
    if effect != tofprox_model::ids::waveform_harmonics::ID.as_str() {
        let sig = make_signature(effect, prep, &cmp.model.spec, &cmp.model.waveform)?;
        let u = crate::uncertainty::effect_uncertainty(
            sig.as_ref(),
            prep,
            (&cmp.model, cmp.fit.chi2_per_dof),
            &fit,
        )?;
        let names = sig.lin_names().into_iter().chain(sig.nl_names());
        standard_errors.extend(names.zip(u.standard_errors));
        intervals = u.intervals;
        at_bound = crate::signatures::at_bounds(sig.as_ref(), &fit.nl);
    }
    Ok(FittedEffect {
        effect: effect.to_string(),
        params,
        standard_errors,
        standard_errors_note: errors_note(cmp),
        at_bound,
        intervals,
    })
}

/// The fitted parameters of `effect` in `model`, by the signature's names.
pub fn effect_params(
    prep: &Prepared,
    model: &LabModel,
    effect: &str,
) -> Result<(EffectFit, BTreeMap<String, f64>), LabError> {
    if let Some(e) = crate::signatures::waveform_effect(effect) {
        let params = e.waveform_params(&model.waveform);
        let fit = EffectFit {
            id: effect.into(),
            lin: Vec::new(),
            nl: Vec::new(),
        };
        return Ok((fit, params));
    }
    let mut params = BTreeMap::new();
    let sig = make_signature(effect, prep, &model.spec, &model.waveform)?;
    let f = model
        .effects
        .iter()
        .find(|e| e.id == effect)
        .cloned()
        .ok_or_else(|| LabError::numerical(format!("{effect} is not in the fitted model")))?;
    for (n, v) in sig.lin_names().into_iter().zip(&f.lin) {
        params.insert(n, *v);
    }
    for (n, v) in sig.nl_names().into_iter().zip(&f.nl) {
        params.insert(n, *v);
    }
    Ok((f, params))
}

/// One round of `explain`: the comparison and diagnosis at that point and the
/// effect added after it (none on the last step).
#[derive(Debug, Clone)]
pub struct ExplainStep {
    /// The model at this step compared with the recording (residual table dropped).
    pub comparison: Comparison,
    /// The diagnosis of that comparison (candidate refits dropped).
    pub diagnosis: Diagnosis,
    /// The effect added after this step (none on the last).
    pub added: Option<String>,
}

/// The loop diagnose → add until nothing is missing or the rest is unexplained.
#[derive(Debug, Clone)]
pub struct Explanation {
    /// Every step, the last one with the final verdict.
    pub steps: Vec<ExplainStep>,
    /// Effects added, in order.
    pub added: Vec<String>,
    /// Why `explain` could not explain the recording (None: it ends at
    /// `nothing_missing`).
    pub stopped: Option<String>,
    /// The effects added, as fitted in the final model, with standard errors.
    pub fitted: Vec<FittedEffect>,
}

impl Explanation {
    /// The final verdict (of the last diagnosis).
    pub fn verdict(&self) -> Verdict {
        self.steps
            .last()
            .map_or(Verdict::Unexplained, |s| s.diagnosis.verdict)
    }
    /// The final model.
    pub fn final_model(&self) -> Option<&LabModel> {
        self.steps.last().map(|s| &s.comparison.model)
    }
}

/// At most this many effects are added by one `explain`.
pub const MAX_EXPLAIN_STEPS: usize = 6;

/// diagnose → add → diagnose … until the verdict is not `missing_effect` (or
/// adding the named effect does not lower χ²). Where no effect is named but
/// one clearly leads, it is added on trial ([`MIN_TRIAL`]) and kept only if it
/// leads to a named effect and the final model needs it.
pub fn explain(
    prep: &Prepared,
    spec: &LabSpec,
    opts: &DiagnoseOptions,
    progress: Progress<'_>,
) -> Result<Explanation, LabError> {
    let mut cmp = compare(prep, spec, progress)?;
    let mut ex = Explanation {
        steps: Vec::new(),
        added: Vec::new(),
        stopped: None,
        fitted: Vec::new(),
    };
    let mut trials = Vec::new();
    for _ in 0..=MAX_EXPLAIN_STEPS {
        let mut d = diagnose_with(prep, &cmp, opts, progress)?;
        let named = next_effect(&mut d, &mut trials).filter(|_| ex.added.len() < MAX_EXPLAIN_STEPS);
        let start = named.as_ref().and_then(|e| {
            let c = d.candidates.iter_mut().find(|c| c.effect == *e)?;
            c.refit.take()
        });
        for c in &mut d.candidates {
            c.refit = None;
        }
        let Some(effect) = named else {
            ex.fitted = fitted_effects(prep, &cmp, &ex.added)?;
            cmp.recs = Vec::new();
            ex.steps.push(ExplainStep {
                comparison: cmp,
                diagnosis: d,
                added: None,
            });
            break;
        };
        let chi_before = cmp.chi2 / cmp.dof;
        let out = add_effect_to(prep, cmp, &effect, start.as_deref(), progress)?;
        let mut before = out.before;
        let chi_after = out.after.fit.chi2_per_dof;
        let improved = chi_after < chi_before;
        if !improved {
            // the final model is this one
            ex.fitted = fitted_effects(prep, &before, &ex.added)?;
        }
        let why =
            format!("adding {effect} did not lower χ²/dof ({chi_before:.3} → {chi_after:.3})");
        let failed_trial = !improved && trials.contains(&effect);
        if failed_trial {
            trial_failed(&mut d.reason, &format!("on trial: {why}"));
        }
        before.recs = Vec::new();
        ex.steps.push(ExplainStep {
            comparison: before,
            diagnosis: d,
            added: improved.then(|| effect.clone()),
        });
        if !improved {
            if failed_trial {
                break;
            }
            ex.stopped = Some(why);
            return Ok(ex);
        }
        ex.added.push(effect);
        cmp = out.after;
    }
    take_back_dead_trials(prep, &trials, &mut ex)?;
    drop_unneeded_trials(prep, opts, &trials, &mut ex, progress)?;
    ex.stopped = stopped_reason(&ex.steps);
    Ok(ex)
}

/// Why the loop ended where it did (None at `nothing_missing`).
fn stopped_reason(steps: &[ExplainStep]) -> Option<String> {
    steps.last().and_then(|s| {
        let d = &s.diagnosis;
        (d.verdict != Verdict::NothingMissing).then(|| match d.verdict {
            Verdict::MissingEffect => format!(
                "still {} after {MAX_EXPLAIN_STEPS} effects: {}",
                d.verdict.as_str(),
                d.reason
            ),
            v => format!("{}: {}", v.as_str(), d.reason),
        })
    })
}

/// Several strong effects at once: each explains only part of the excess, so
/// none may pass [`decide`]. When the best candidate explains at least this
/// share of the excess, as much on held-out blocks, and clearly beats the
/// runner-up, `explain` adds it **on trial** and diagnoses the rest; the
/// diagnosis itself stays `unexplained`.
pub const MIN_TRIAL: f64 = 0.15;

/// The effect `explain` adds after diagnosis `d`: the named one, or one on
/// trial ([`MIN_TRIAL`], recorded in `trials` and in `d.reason`).
fn next_effect(d: &mut Diagnosis, trials: &mut Vec<String>) -> Option<String> {
    if d.verdict == Verdict::MissingEffect {
        return d.effect.clone();
    }
    let best = d.candidates.first()?;
    let on_trial = d.verdict == Verdict::Unexplained
        && d.noise.measured()
        && best.explained_excess >= MIN_TRIAL
        && best.cv_gain >= MIN_TRIAL.max(0.7 * best.explained_excess)
        && clearly_best(best, d.candidates.get(1));
    if !on_trial {
        return None;
    }
    let e = best.effect.clone();
    d.reason = format!(
        "{}; `explain` adds {e} on trial ({:.0}% of the excess, {:.0}% on held-out blocks) and diagnoses the rest",
        d.reason,
        100.0 * best.explained_excess,
        100.0 * best.cv_gain
    );
    trials.push(e.clone());
    Some(e)
}

/// The reason of a diagnosis whose trial failed: its announcement replaced by `why`.
fn trial_failed(reason: &mut String, why: &str) {
    reason.truncate(reason.find("; `explain` adds").unwrap_or(reason.len()));
    reason.push_str("; ");
    reason.push_str(why);
}

/// A trial is a look-ahead: it stays when the diagnosis after it names an
/// effect or finds nothing missing. When the loop ends `unexplained` right
/// after a trial, the trial is taken back: the step before it is the last,
/// with the model it had.
fn take_back_dead_trials(
    prep: &Prepared,
    trials: &[String],
    ex: &mut Explanation,
) -> Result<(), LabError> {
    let closed = |st: &ExplainStep| {
        matches!(
            st.diagnosis.verdict,
            Verdict::NothingMissing | Verdict::MissingEffect
        )
    };
    let steps = &mut ex.steps;
    while steps.len() >= 2 && !closed(&steps[steps.len() - 1]) {
        let prev = &steps[steps.len() - 2];
        let Some(e) = prev
            .added
            .clone()
            .filter(|e| trials.contains(e) && !closed(prev))
        else {
            break;
        };
        steps.pop();
        ex.added.retain(|x| *x != e);
        let last = steps.last_mut().expect("two steps");
        last.added = None;
        let why = format!("{e} added on trial led to no named effect and was taken back");
        trial_failed(&mut last.diagnosis.reason, &why);
        let cmp = comparison_of(prep, last.comparison.model.clone())?;
        ex.fitted = fitted_effects(prep, &cmp, &ex.added)?;
    }
    Ok(())
}

/// An effect added on trial stays only if the final model needs it: when the
/// loop ends at `nothing_missing`, the model without it (fitted from scratch)
/// is diagnosed, and if that, too, is `nothing_missing` the effect goes and
/// that diagnosis becomes the last step (its reason says so).
fn drop_unneeded_trials(
    prep: &Prepared,
    opts: &DiagnoseOptions,
    trials: &[String],
    ex: &mut Explanation,
    progress: Progress<'_>,
) -> Result<(), LabError> {
    for e in trials {
        let Some(last) = ex.steps.last_mut() else {
            return Ok(());
        };
        if last.diagnosis.verdict != Verdict::NothingMissing || !ex.added.contains(e) {
            continue;
        }
        let mut spec = last.comparison.model.spec.clone();
        spec.effects.retain(|x| x != e);
        spec.shapes.remove(e);
        let mut without = compare(prep, &spec, progress)?;
        let mut d = diagnose_with(prep, &without, opts, progress)?;
        if d.verdict != Verdict::NothingMissing {
            continue;
        }
        ex.added.retain(|x| x != e);
        ex.fitted = fitted_effects(prep, &without, &ex.added)?;
        d.reason = format!("{e} (added on trial) is not needed: {}", d.reason);
        d.candidates.iter_mut().for_each(|c| c.refit = None);
        without.recs = Vec::new();
        *last = ExplainStep {
            comparison: without,
            diagnosis: d,
            added: None,
        };
    }
    Ok(())
}

/// Each of `added` as fitted in the model of `cmp`, with standard errors.
fn fitted_effects(
    prep: &Prepared,
    cmp: &Comparison,
    added: &[String],
) -> Result<Vec<FittedEffect>, LabError> {
    added.iter().map(|e| fitted_effect(prep, cmp, e)).collect()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use tofprox_model::ids;

    /// A scored candidate with the given evidence (the other fields empty).
    pub(crate) fn cand(
        effect: &str,
        explained: f64,
        cv: f64,
        z_after: f64,
        dbic: f64,
    ) -> CandidateScore {
        CandidateScore {
            effect: effect.into(),
            delta_bic: dbic,
            delta_aic: dbic,
            explained_excess: explained,
            cv_gain: cv,
            explained: Size::default(),
            z_after,
            params: BTreeMap::new(),
            standard_errors: BTreeMap::new(),
            flags: Vec::new(),
            at_bound: Vec::new(),
            fit: None,
            nuisance: [0.0; 3],
            structure_after: Some(2.0),
            rms_after: None,
            cancels_in_4phase: false,
            refit: None,
            form: crate::shape::PHYSICAL_FORM.into(),
            form_scores: Vec::new(),
            knots: None,
        }
    }

    #[test]
    fn noise_like_residual_is_nothing_missing() {
        let d = decide(
            1.5,
            1.001,
            3.0,
            &[cand(ids::adc_inl::ID.as_str(), 0.9, 0.8, 0.5, -30.0)],
        );
        assert_eq!(d.verdict, Verdict::NothingMissing);
        assert!(d.effect.is_none());
    }

    #[test]
    fn clear_winner_is_named() {
        let c = [
            cand(ids::vcsel_droop::ID.as_str(), 0.97, 0.95, 2.0, -9e5),
            cand(ids::sbi_asymmetry::ID.as_str(), 0.2, 0.1, 800.0, -1e5),
        ];
        let d = decide(1000.0, 5.0, 3000.0, &c);
        assert_eq!(d.verdict, Verdict::MissingEffect);
        assert_eq!(d.effect.as_deref(), Some(ids::vcsel_droop::ID.as_str()));
    }

    #[test]
    fn two_close_candidates_are_ambiguous() {
        let c = [
            cand(
                ids::amplitude_phase_error::ID.as_str(),
                0.95,
                0.93,
                3.0,
                -9e4,
            ),
            cand(ids::multipath::ID.as_str(), 0.93, 0.90, 3.5, -8.9e4),
        ];
        let d = decide(300.0, 2.0, 900.0, &c);
        assert_eq!(d.verdict, Verdict::Ambiguous);
        assert_eq!(d.runner_up.as_deref(), Some(ids::multipath::ID.as_str()));
    }

    #[test]
    fn delta_bic_alone_names_nothing() {
        // every candidate has a hugely negative ΔBIC but none explains most of
        // the excess on held-out blocks: unexplained, no effect named
        let c = [
            cand(ids::multipath::ID.as_str(), 0.3, 0.25, 700.0, -5e5),
            cand(ids::adc_inl::ID.as_str(), 0.1, -0.2, 900.0, -2e5),
        ];
        let d = decide(1000.0, 4.0, 5000.0, &c);
        assert_eq!(d.verdict, Verdict::Unexplained);
        assert!(d.effect.is_none());
    }

    #[test]
    fn overfitting_candidate_fails_cross_validation() {
        let c = [cand(
            ids::waveform_harmonics::ID.as_str(),
            0.8,
            -0.3,
            3.0,
            -1e4,
        )];
        assert_eq!(decide(50.0, 1.3, 80.0, &c).verdict, Verdict::Unexplained);
    }

    #[test]
    fn separating_condition_prefers_what_was_not_varied() {
        let ds = crate::synth::generate(&crate::synth::SynthSpec {
            rows: 2,
            cols: 2,
            ..Default::default()
        });
        let prep = Prepared::new(&ds).unwrap();
        // temperature was not varied: it separates drift from amplitude-phase error
        assert_eq!(
            separating_condition(
                ids::temperature_drift::ID.as_str(),
                ids::amplitude_phase_error::ID.as_str(),
                &prep
            ),
            "temperature_c"
        );
        assert_eq!(
            separating_condition(
                ids::sbi_asymmetry::ID.as_str(),
                ids::dark_current::ID.as_str(),
                &prep
            ),
            "ambient_klux"
        );
    }

    /// An unexplained diagnosis with `cands` (noise from repeats unless `measured` is false).
    fn unexplained(cands: Vec<CandidateScore>, measured: bool) -> Diagnosis {
        Diagnosis {
            verdict: Verdict::Unexplained,
            effect: None,
            runner_up: None,
            separate_by: None,
            candidates: cands,
            skipped: Vec::new(),
            fit: FitStats {
                chi2_per_dof: 138.0,
                z: 9000.0,
                ..FitStats::default()
            },
            strongest_condition: None,
            rms: Rms::default(),
            structure_remaining: Vec::new(),
            reason: "best candidate explains 29% of the excess: not enough".into(),
            size: Size::default(),
            noise_single: Size::default(),
            tolerance_mm: 0.5,
            small: Vec::new(),
            noise: if measured {
                crate::noise::NoiseSource::Repeats { groups: 12 }
            } else {
                crate::noise::NoiseSource::NotMeasured
            },
        }
    }

    /// The trial rule: a clear leader of ≥ 15 % (held out as well) is added on
    /// trial and recorded; a close runner-up, a share that does not hold out,
    /// a small share or unmeasured noise add nothing.
    #[test]
    fn a_clear_partial_leader_is_added_on_trial() {
        let (drift_id, droop_id) = (
            ids::temperature_drift::ID.as_str(),
            ids::vcsel_droop::ID.as_str(),
        );
        let drift = cand(drift_id, 0.29, 0.29, 9000.0, -1e5);
        let mut d = unexplained(
            vec![
                drift.clone(),
                cand(ids::multipath::ID.as_str(), 0.04, 0.03, 9500.0, -10.0),
            ],
            true,
        );
        let mut trials = Vec::new();
        assert_eq!(next_effect(&mut d, &mut trials).as_deref(), Some(drift_id));
        assert_eq!(trials, [drift_id]);
        assert!(d.reason.ends_with("adds temperature_drift on trial (29% of the excess, 29% on held-out blocks) and diagnoses the rest"));
        trial_failed(&mut d.reason, "taken back");
        assert_eq!(
            d.reason,
            "best candidate explains 29% of the excess: not enough; taken back"
        );
        let none = |cands: Vec<CandidateScore>, measured: bool| {
            let mut t = Vec::new();
            next_effect(&mut unexplained(cands, measured), &mut t).is_none() && t.is_empty()
        };
        assert!(none(
            vec![
                drift.clone(),
                cand(ids::adc_inl::ID.as_str(), 0.25, 0.24, 9100.0, -1e5)
            ],
            true
        ));
        assert!(none(vec![cand(droop_id, 0.30, 0.10, 9000.0, -1e5)], true));
        assert!(none(vec![cand(droop_id, 0.12, 0.12, 9000.0, -1e5)], true));
        assert!(none(vec![drift], false));
    }
}
