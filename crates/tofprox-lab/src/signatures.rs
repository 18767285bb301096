//! Residual signatures of the catalogue effects the lab can add on top of its
//! model. Each is Δcode = Σ_j lin_j · b_j(nl; sample) with few global
//! parameters: `lin` enter linearly, `nl` (thresholds, time constants, path
//! lengths) are started from a grid and refined by Levenberg–Marquardt.

use tofprox_model::catalogue::{self, ActsOn, Driver};
use tofprox_model::ids::{self, EffectId};

use crate::error::{ErrorKind, LabError};
use crate::fit::{CapInfo, EffectFit, LabSpec, Prepared, Rec, Sample};
use crate::waveform::Waveform;

/// Highest harmonic the extra-harmonics signature reaches (the measured VCSEL/pulse correlation has harmonics up to the 9th, docs/model.md).
pub const MAX_HARMONIC: usize = 9;

/// The residual an effect leaves in the raw codes, as a basis in which it is
/// linear (`lin`) given a few non-linear parameters (`nl`).
pub trait Signature: Send + Sync {
    /// The catalogue id of the effect.
    fn id(&self) -> &'static str;
    /// Number of linear coefficients (basis functions).
    fn n_lin(&self) -> usize;
    /// Names of the linear coefficients, in basis order.
    fn lin_names(&self) -> Vec<String>;
    /// Names of the non-linear parameters (none by default).
    fn nl_names(&self) -> Vec<String> {
        Vec::new()
    }
    /// Default starting values of the non-linear parameters.
    fn nl_start(&self) -> Vec<f64> {
        Vec::new()
    }
    /// Non-linear parameters chosen from the grid only, not refined (a
    /// choice between discrete forms of the law).
    fn nl_discrete(&self, _i: usize) -> bool {
        false
    }
    /// Starting points for the non-linear parameters (variable projection).
    fn nl_grid(&self, _recs: &[Sample], _prep: &Prepared) -> Vec<Vec<f64>> {
        vec![self.nl_start()]
    }
    /// Basis values b_j at one sample.
    fn basis(&self, nl: &[f64], r: &Rec, cap: &CapInfo, out: &mut [f64]);
    /// The part of Δcode no linear coefficient scales: a full law whose size
    /// the non-linear parameters set (Δ = fixed + Σ lin_j·b_j; 0 by default).
    fn fixed(&self, _nl: &[f64], _r: &Rec, _cap: &CapInfo) -> f64 {
        0.0
    }
    /// The part of the basis that is the same for every pixel of raw image
    /// `k` of a capture (given `nl`), e.g. the droop of image k; `None` when
    /// the basis has none. [`ImageMemo`] computes it once per raw image where
    /// samples come in capture, raw-image order.
    fn image_term(&self, _nl: &[f64], _k: u16, _cap: &CapInfo) -> Option<f64> {
        None
    }
    /// [`Signature::basis`] given `image_term(nl, r.k, cap)` (only called
    /// when that is `Some`).
    fn basis_image(&self, nl: &[f64], r: &Rec, cap: &CapInfo, _image: f64, out: &mut [f64]) {
        self.basis(nl, r, cap, out);
    }
}

/// Evaluates a signature's basis sample by sample, computing its per-raw-image
/// term ([`Signature::image_term`]) once per (capture, raw image, `nl`): the
/// residual tables run in capture, raw image, pixel order, so the
/// transcendentals of a per-image law cost one evaluation per image instead
/// of one per pixel. The same values as [`Signature::basis`].
#[derive(Debug, Default, Clone)]
pub struct ImageMemo {
    key: Option<(u32, u16)>,
    nl: Vec<f64>,
    term: Option<f64>,
}

impl ImageMemo {
    /// Basis values b_j of `sig` at sample `r`.
    #[inline]
    pub fn basis(
        &mut self,
        sig: &dyn Signature,
        nl: &[f64],
        r: &Rec,
        cap: &CapInfo,
        out: &mut [f64],
    ) {
        if self.key != Some((r.cap, r.k)) || self.nl != nl {
            self.term = sig.image_term(nl, r.k, cap);
            self.key = Some((r.cap, r.k));
            self.nl.clear();
            self.nl.extend_from_slice(nl);
        }
        match self.term {
            Some(t) => sig.basis_image(nl, r, cap, t, out),
            None => sig.basis(nl, r, cap, out),
        }
    }
}

/// Every effect the lab has a signature for, in catalogue order (the ids are
/// the model's registry's, `tofprox_model::ids`).
pub const SIGNATURE_IDS: &[&str] = &[
    ids::sbi_asymmetry::ID.as_str(),
    ids::tap_gain_mismatch::ID.as_str(),
    ids::vcsel_droop::ID.as_str(),
    ids::amplitude_phase_error::ID.as_str(),
    ids::temperature_drift::ID.as_str(),
    ids::waveform_harmonics::ID.as_str(),
    ids::adc_inl::ID.as_str(),
    ids::dark_current::ID.as_str(),
    ids::multipath::ID.as_str(),
];

/// Conditions each effect varies with (used to advise how to separate two):
/// the registry's drivers (`tofprox_model::catalogue::EffectInfo::drivers`).
pub fn effect_conditions(id: &str) -> &'static [Driver] {
    catalogue::effect(id).map_or(&[], |e| e.drivers)
}

/// Whether the effect's residual cancels in the 4-phase algorithm (common to
/// the raw images) — the 2- vs 4-phase contrast of 5.1.2.3; the registry's
/// `cancels_in_four_phase`.
pub fn cancels_in_4phase(id: &str) -> bool {
    catalogue::effect(id).is_some_and(|e| e.cancels_in_four_phase)
}

/// Why an effect cannot be fitted on this recording, if it cannot.
pub fn not_identifiable(id: &str, prep: &Prepared, spec: &LabSpec) -> Option<String> {
    match EffectId::parse(id)? {
        ids::temperature_drift::ID if !prep.temperature_varies => {
            Some("temperature_c does not vary in the recording".into())
        }
        ids::waveform_harmonics::ID if spec.harmonic_order >= MAX_HARMONIC => Some(format!(
            "the model already fits harmonics up to {MAX_HARMONIC}"
        )),
        ids::dark_current::ID if !prep.exposure_varies => {
            Some("exposure_us does not vary in the recording".into())
        }
        _ => None,
    }
}

/// The signature of effect `id` for this recording, model and correlation
/// waveform; [`ErrorKind::UnknownEffect`] when the lab has none.
pub fn make_signature(
    id: &str,
    prep: &Prepared,
    spec: &LabSpec,
    waveform: &Waveform,
) -> Result<Box<dyn Signature>, LabError> {
    let unknown = || {
        LabError::new(
            ErrorKind::UnknownEffect,
            format!(
                "the lab has no signature for effect `{id}` (known: {})",
                SIGNATURE_IDS.join(", ")
            ),
        )
    };
    Ok(match EffectId::parse(id).ok_or_else(unknown)? {
        ids::sbi_asymmetry::ID => {
            // total signal charge relative to the fundamental amplitude: the
            // correlation's peak over its fundamental, over the registry's
            // typical demodulation contrast (0.8)
            Box::new(Sbi {
                ambient_varies: prep.ambient_varies,
                g: waveform.peak() / catalogue::typical(ids::demodulation_contrast::CONTRAST),
            })
        }
        ids::tap_gain_mismatch::ID => Box::new(TapGain {
            ambient_varies: prep.ambient_varies,
        }),
        ids::vcsel_droop::ID => Box::new(Droop),
        ids::amplitude_phase_error::ID => Box::new(AmpPhase {
            waveform: waveform.clone(),
        }),
        ids::temperature_drift::ID => Box::new(TempDrift {
            // a held model keeps its own law; a fit takes the ΔT² terms only
            // where ≥ 3 temperatures tell them from the linear ones
            second_order: spec.held.iter().any(|h| h.id == id) || distinct_temperatures(prep) >= 3,
            waveform: waveform.clone(),
        }),
        ids::waveform_harmonics::ID => Box::new(Harmonics {
            from: spec.harmonic_order.max(1) + 1,
        }),
        ids::adc_inl::ID => Box::new(Inl { mid: prep.mid }),
        ids::dark_current::ID => Box::new(Dark {
            doubling_k: spec.dark_doubling_k,
        }),
        ids::multipath::ID => Box::new(Multipath {
            phase_rad_per_m: tofprox_core::phasor::distance_to_phase_rad(1.0, prep.modulation_hz),
            waveform: waveform.clone(),
        }),
        _ => return Err(unknown()),
    })
}

fn quantiles(mut v: Vec<f64>, qs: &[f64]) -> Vec<f64> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return Vec::new();
    }
    v.sort_by(|a, b| a.total_cmp(b));
    qs.iter()
        .map(|q| v[((v.len() - 1) as f64 * q) as usize])
        .collect()
}

/// SBI asymmetry (2.2.2.1, 5.1.2.3, fig. 5.6): the taps collect
/// N_a,b = B + κ·A(g ± C)/100 (B = ambient·t[ms]·pixel response, g = peak of
/// C over the contrast 0.8); once the fuller tap passes the threshold q0 the SBI injects the
/// smaller current into both with mismatch, leaving m·N_min·(1 − q0/N_max) in
/// the differential code — nearly the same in every raw image, so 4-phase
/// cancels it and 2-phase does not. The injected charge is the model's family
/// (`tofprox_model::effects::pixel::sbi_injected_e`): clamp share s = 0
/// injects the smaller tap current (subtracts), s = 1 the larger one (clamps
/// the fuller tap at q0). lin = [m], nl = [ln q0, (ln κ), s] (q0 and κ
/// scale-free: their units depend on the sensor over many decades).
struct Sbi {
    ambient_varies: bool,
    /// Total signal charge per unit of fundamental amplitude (1/contrast for a sinusoid).
    g: f64,
}
impl Sbi {
    /// Index of the clamp share in `nl`.
    fn clamp_index(&self) -> usize {
        if self.ambient_varies { 2 } else { 1 }
    }
    fn taps(&self, nl: &[f64], r: &Rec, cap: &CapInfo) -> (f64, f64) {
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
        ids::sbi_asymmetry::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        1
    }
    fn lin_names(&self) -> Vec<String> {
        vec!["mismatch_lsb_per_unit".into()]
    }
    fn nl_names(&self) -> Vec<String> {
        if self.ambient_varies {
            vec![
                "ln_threshold".into(),
                "ln_signal_weight".into(),
                "clamp_share".into(),
            ]
        } else {
            vec!["ln_threshold".into(), "clamp_share".into()]
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
        out[0] = tofprox_model::effects::pixel::sbi_injected_e(na, nb, q0, share);
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
        ids::tap_gain_mismatch::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        if self.ambient_varies { 2 } else { 1 }
    }
    fn lin_names(&self) -> Vec<String> {
        let mut v = vec!["signal_share".to_string()];
        if self.ambient_varies {
            v.push("ambient_lsb_per_klux_ms".into());
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

/// VCSEL droop (3.3.7.2) with the model's law
/// (`tofprox_model::effects::optical::droop_loss`): A_k = A·(1 − D·L_k),
/// L_k = 1 − e^{−(k + k₀)·s/τ}, s = t[ms]^β (τ here in ms^β; β = 1: heating by
/// on-time, β = 0: per image; k₀ = 1: the first image is already drooped).
/// lin = [D/τ], nl = [ln τ, β, k₀].
struct Droop;
impl Signature for Droop {
    fn id(&self) -> &'static str {
        ids::vcsel_droop::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        1
    }
    fn lin_names(&self) -> Vec<String> {
        vec!["droop_rate".into()]
    }
    fn nl_names(&self) -> Vec<String> {
        vec![
            "ln_tau".into(),
            "exposure_power".into(),
            "first_image_index".into(),
        ]
    }
    fn nl_start(&self) -> Vec<f64> {
        vec![5.0, 1.0, 0.0]
    }
    fn nl_grid(&self, _: &[Sample], _: &Prepared) -> Vec<Vec<f64>> {
        let mut g = Vec::new();
        for k0 in [0.0, 1.0] {
            for beta in [0.0, 1.0] {
                for lt in [-1.0, 0.0, 1.0, 2.0, 3.0, 6.0] {
                    g.push(vec![lt, beta, k0]);
                }
            }
        }
        g
    }
    fn basis(&self, nl: &[f64], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        let t = self.image_term(nl, r.k, cap).unwrap_or(0.0);
        self.basis_image(nl, r, cap, t, out);
    }
    /// τ·L_k: the same for every pixel of raw image k.
    fn image_term(&self, nl: &[f64], k: u16, cap: &CapInfo) -> Option<f64> {
        let tau = nl[0].clamp(-5.0, 9.0).exp();
        let beta = nl[1].clamp(0.0, 2.0);
        let k0 = nl.get(2).copied().unwrap_or(0.0).clamp(0.0, 8.0);
        let loss = tofprox_model::effects::optical::droop_loss(
            f64::from(k),
            cap.exposure_us,
            1000.0 * tau,
            beta,
            k0,
        );
        Some(tau * loss)
    }
    fn basis_image(&self, _: &[f64], r: &Rec, _: &CapInfo, image: f64, out: &mut [f64]) {
        out[0] = -r.a * r.c * image;
    }
}

/// Amplitude-dependent phase error (2.3.1.2) with the model's own saturating
/// law (`tofprox_model::effects::pixel::amplitude_phase_shape`), applied
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
    /// s(A/A_ref; n) − 1 for nl = [φ0, ln A_ref, ln n].
    fn shape(nl: &[f64], a: f64) -> f64 {
        let aref = nl[1].clamp(-5.0, 18.0).exp();
        let n = nl
            .get(2)
            .copied()
            .unwrap_or(0.0)
            .clamp(0.25f64.ln(), 10f64.ln())
            .exp();
        tofprox_model::effects::pixel::amplitude_phase_shape(a.max(0.0) / aref, n) - 1.0
    }
    /// The model file's range of φ0 (`amplitude_phase_error.max_rad`).
    fn phase0_range() -> (f64, f64) {
        // looked up once: the fit asks for every sample
        static RANGE: std::sync::OnceLock<(f64, f64)> = std::sync::OnceLock::new();
        *RANGE.get_or_init(|| {
            catalogue::param_info(ids::amplitude_phase_error::MAX_RAD)
                .map_or((-0.5, 0.5), |p| (p.min, p.max))
        })
    }
    /// Δφ at amplitude `a` (LSB), φ0 held in the model file's range (what
    /// `add` can write).
    fn phase_rad(nl: &[f64], a: f64) -> f64 {
        let (lo, hi) = Self::phase0_range();
        nl[0].clamp(lo, hi) * Self::shape(nl, a)
    }
    /// The first-order φ0 at (ln A_ref, ln n): least squares of A·C′·(s − 1)
    /// with the global nuisance shifts on a subsample.
    fn screen(nl: &[f64], recs: &[Sample], prep: &Prepared) -> Option<f64> {
        let mut acc = tofprox_core::lsq::Normal::zeros(4);
        for s in recs.iter().step_by((recs.len() / 20_000).max(1)) {
            let r = s.rec(prep);
            let j = [
                r.a * r.cd * Self::shape(nl, r.a),
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
        ids::amplitude_phase_error::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        0
    }
    fn lin_names(&self) -> Vec<String> {
        Vec::new()
    }
    fn nl_names(&self) -> Vec<String> {
        vec![
            "phase0_rad".into(),
            "ln_reference_lsb".into(),
            "ln_shape".into(),
        ]
    }
    fn nl_start(&self) -> Vec<f64> {
        vec![0.0, 5.0, 0.0]
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
    fn fixed(&self, nl: &[f64], r: &Rec, _: &CapInfo) -> f64 {
        let dphi = Self::phase_rad(nl, r.a);
        r.a * (self.waveform.eval(r.phi - r.theta + dphi).0 - r.c)
    }
}

/// Temperature drift (thesis 3.1) with the model's full law
/// (`tofprox_model::effects::pixel::temperature_drift`): the phase shifted by
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
    /// Δφ(ΔT) and the powers of ΔT, by the model's law.
    fn phase_and_terms(&self, nl: &[f64], cap: &CapInfo) -> (f64, [f64; 2]) {
        let k = [nl[0], nl.get(1).copied().unwrap_or(0.0)];
        let (dphi, _) = tofprox_model::effects::pixel::temperature_drift(cap.temp_rel, k, [0.0; 2]);
        let t = tofprox_model::effects::pixel::temperature_drift_terms(cap.temp_rel);
        (dphi, t)
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
            let t = tofprox_model::effects::pixel::temperature_drift_terms(
                prep.caps[r.cap as usize].temp_rel,
            );
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
        ids::temperature_drift::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        self.n_terms()
    }
    fn lin_names(&self) -> Vec<String> {
        let mut v = vec!["gain_per_k".to_string()];
        if self.second_order {
            v.push("gain_per_k2".into());
        }
        v
    }
    fn nl_names(&self) -> Vec<String> {
        let mut v = vec!["phase_rad_per_k".to_string()];
        if self.second_order {
            v.push("phase_rad_per_k2".into());
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
        let (dphi, t) = self.phase_and_terms(nl, cap);
        let c = r.a * self.waveform.eval(r.phi - r.theta + dphi).0;
        for (o, ti) in out.iter_mut().zip(t) {
            *o = c * ti;
        }
    }
    fn fixed(&self, nl: &[f64], r: &Rec, cap: &CapInfo) -> f64 {
        let (dphi, _) = self.phase_and_terms(nl, cap);
        r.a * (self.waveform.eval(r.phi - r.theta + dphi).0 - r.c)
    }
}

/// Whether effect `id` acts on the signal phasor (its gain and phase) rather
/// than adding codes: the lab model applies it to A and φ
/// ([`phasor_shift`]), so the per-pixel fit sees its true derivatives, and
/// does not add its Δcode again. Its signature is the Δcode it makes relative
/// to a model without it (what the candidate fit sees).
pub fn acts_on_phasor(id: &str) -> bool {
    catalogue::effect(id).is_some_and(|e| e.acts_on == ActsOn::Phasor)
}

/// The signal gain factor 1 + G and the phase shift Δφ (rad) of a pixel of
/// capture `cap` whose amplitude without them is `a_lsb`, from the fitted
/// effects that act on the phasor: the temperature drift by the model's law
/// (`tofprox_model::effects::pixel::temperature_drift`, gain factor floored
/// at 0 as the simulator does; lin = gain, nl = phase coefficients,
/// `TempDrift`), then the amplitude-phase error at the drifted amplitude
/// (`AmpPhase`).
pub fn phasor_shift(effects: &[EffectFit], cap: &CapInfo, a_lsb: f64) -> (f64, f64) {
    let at = |v: &[f64], i: usize| v.get(i).copied().unwrap_or(0.0);
    let (mut f, mut ph) = (1.0, 0.0);
    for e in effects
        .iter()
        .filter(|e| e.id == ids::temperature_drift::ID.as_str())
    {
        let (dphi, g) = tofprox_model::effects::pixel::temperature_drift(
            cap.temp_rel,
            [at(&e.nl, 0), at(&e.nl, 1)],
            [at(&e.lin, 0), at(&e.lin, 1)],
        );
        f *= (1.0 + g).max(0.0);
        ph += dphi;
    }
    for e in effects
        .iter()
        .filter(|e| e.id == ids::amplitude_phase_error::ID.as_str())
    {
        if cap.illum && e.nl.len() == 3 {
            ph += AmpPhase::phase_rad(&e.nl, a_lsb * f);
        }
    }
    (f, ph)
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

/// Harmonics of the correlation above the fitted order (3.2.2): A·Re[γ_h e^{ih(φ−θ)}].
struct Harmonics {
    from: usize,
}
impl Signature for Harmonics {
    fn id(&self) -> &'static str {
        ids::waveform_harmonics::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        2 * (MAX_HARMONIC + 1).saturating_sub(self.from)
    }
    fn lin_names(&self) -> Vec<String> {
        (self.from..=MAX_HARMONIC)
            .flat_map(|h| [format!("h{h}_re"), format!("h{h}_im")])
            .collect()
    }
    fn basis(&self, _: &[f64], r: &Rec, _: &CapInfo, out: &mut [f64]) {
        // e^{ihx} by complex multiplication from e^{ix}: one sin_cos per sample
        let (s1, c1) = (r.phi - r.theta).sin_cos();
        let (mut zr, mut zi) = (c1, s1);
        for _ in 1..self.from {
            (zr, zi) = (zr * c1 - zi * s1, zr * s1 + zi * c1);
        }
        for i in 0..=MAX_HARMONIC.saturating_sub(self.from) {
            out[2 * i] = r.a * zr;
            out[2 * i + 1] = -r.a * zi;
            (zr, zi) = (zr * c1 - zi * s1, zr * s1 + zi * c1);
        }
    }
}

/// ADC integral non-linearity of a differential converter with the model's
/// law (`tofprox_model::effects::adc::inl_shape`, 3.2.1, fig. 3.4): zero at
/// mid and both ends, opposite sign on the two half ranges. lin = [I].
struct Inl {
    mid: f64,
}
impl Signature for Inl {
    fn id(&self) -> &'static str {
        ids::adc_inl::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        1
    }
    fn lin_names(&self) -> Vec<String> {
        vec!["inl_bow_lsb".into()]
    }
    fn basis(&self, _: &[f64], r: &Rec, _: &CapInfo, out: &mut [f64]) {
        let x = r.x.clamp(-self.mid, self.mid);
        out[0] = tofprox_model::effects::adc::inl_shape(x, 2.0 * self.mid);
    }
}

/// Dark current (2.3.2, eq. 2.17) with the model's law: charge ∝ exposure,
/// doubling every ΔT₂ kelvin (`tofprox_model::effects::pixel::
/// dark_current_temperature_factor`, ΔT₂ the model's `doubling_c`), whose tap
/// mismatch shifts the differential offset. lin = [LSB per ms at the lab's
/// reference temperature].
struct Dark {
    /// ΔT₂ in K.
    doubling_k: f64,
}
impl Signature for Dark {
    fn id(&self) -> &'static str {
        ids::dark_current::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        1
    }
    fn lin_names(&self) -> Vec<String> {
        vec!["lsb_per_ms".into()]
    }
    fn basis(&self, _: &[f64], _: &Rec, cap: &CapInfo, out: &mut [f64]) {
        out[0] = cap.exposure_us
            * 1e-3
            * tofprox_model::effects::pixel::dark_current_temperature_factor(
                cap.temp_rel,
                self.doubling_k,
            );
    }
}

/// Multipath with the model's law: a second return of a·A at the phase
/// offset of an extra round-trip path L
/// (`tofprox_model::effects::optical::multipath_phase_offset_rad`),
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
        ids::multipath::ID.as_str()
    }
    fn n_lin(&self) -> usize {
        1
    }
    fn lin_names(&self) -> Vec<String> {
        vec![ids::multipath::RELATIVE_AMPLITUDE.name().into()]
    }
    fn nl_names(&self) -> Vec<String> {
        vec![ids::multipath::EXTRA_PATH_M.name().into()]
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
        let dphi = tofprox_model::effects::optical::multipath_phase_offset_rad(
            self.phase_rad_per_m,
            nl[0].abs(),
        );
        out[0] = r.a * self.waveform.eval(r.phi + dphi - r.theta).0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every effect the lab fits is a registry entry with at least one driver
    /// (the separating-condition advice needs one), and the lab's phasor
    /// effects are exactly the registry's `phasor` entries among them.
    #[test]
    fn every_signature_is_a_registry_entry_with_drivers() {
        for id in SIGNATURE_IDS {
            let e = catalogue::effect(id).unwrap_or_else(|| panic!("{id}: not in the registry"));
            assert!(!e.drivers.is_empty(), "{id}: no drivers");
            assert!(!effect_conditions(id).is_empty());
        }
        let ids_where = |f: fn(&str) -> bool| -> Vec<&str> {
            SIGNATURE_IDS.iter().copied().filter(|id| f(id)).collect()
        };
        assert_eq!(
            ids_where(acts_on_phasor),
            [ids::amplitude_phase_error::ID, ids::temperature_drift::ID].map(EffectId::as_str)
        );
        assert_eq!(
            ids_where(cancels_in_4phase),
            [
                ids::sbi_asymmetry::ID,
                ids::tap_gain_mismatch::ID,
                ids::dark_current::ID
            ]
            .map(EffectId::as_str)
        );
        assert!(effect_conditions("no_such_effect").is_empty() && !cancels_in_4phase("x"));
    }
}
