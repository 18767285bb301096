//! `compare`: the model fitted to a recording and its errors — RMS of the raw codes and
//! of the 2- and 4-phase depths, the fit's χ², AIC and BIC, the residual's structure.
use super::*;

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

    /// The χ² per sample of the noise alone, dof/n, where the noise was
    /// measured (`None` where it was estimated from these residuals: their
    /// χ² per sample is then near 1 whatever they hold); what
    /// `crate::form::shapes_can_win` measures a form against.
    pub fn noise_floor(&self) -> Option<f64> {
        (self.model.noise.source.measured() && self.n > 0).then(|| self.dof / self.n as f64)
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

pub(super) fn wrap_pm(x: f64) -> f64 {
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
