//! Residual signatures of the catalogue effects the lab can add on top of its
//! model, one module per effect. Each is Δcode = Σ_j lin_j · b_j(nl; sample)
//! with few global parameters: `lin` enter linearly, `nl` (thresholds, time
//! constants, path lengths) are started from a grid and refined by
//! Levenberg–Marquardt.
//!
//! Each effect's module owns everything the lab knows about it: its basis
//! (calling the model's law in `tofprox_model::effects`, never a law of its
//! own), its fitted parameters' names, how their values are written into a
//! model file ([`LabEffect::write`]), how a model file's values are read back
//! to hold it ([`LabEffect::held`]) and why a recording may not identify it
//! ([`LabEffect::not_identifiable`]). [`REGISTRY`] lists them once, keyed by
//! the model's [`EffectId`]: adding an effect to the lab is one module here
//! and one line in the registry.

use std::collections::BTreeMap;
use std::sync::LazyLock;
use tofprox_model::effects;

use tofprox_model::ModelConfig;
use tofprox_model::catalogue::{self, ActsOn, Driver};
use tofprox_model::ids::{self, EffectId, ParamId};

use crate::error::{ErrorKind, LabError};
use crate::fit::LabModel;
use crate::prepared::{CapInfo, Prepared};
use crate::sample::{Rec, Sample};
use crate::spec::{EffectFit, LabSpec};
use crate::waveform::Waveform;

mod amp_phase;
mod code_law;
mod dark;
mod droop;
mod harmonics;
mod inl;
mod multipath;
pub(crate) mod sbi;
mod tap_gain;
mod temp_drift;

pub use harmonics::{MAX_HARMONIC, harmonic_order};

/// The residual an effect leaves in the raw codes, as a basis in which it is
/// linear (`lin`) given a few non-linear parameters (`nl`).
pub trait Signature: Send + Sync {
    /// The catalogue id of the effect (a user effect's name, `crate::user`).
    fn id(&self) -> &str;
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
    /// The range the law holds each non-linear parameter in (its clamp), in
    /// `nl`'s own units, `None` for an unbounded one; empty (the default):
    /// none bounded. A fitted value at or beyond its bound is flagged
    /// ([`at_bounds`]): the data push it there, and its standard error does
    /// not describe how far it may be off.
    fn nl_bounds(&self) -> Vec<Option<(f64, f64)>> {
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
    /// the non-linear parameters set (Δ = fixed + Σ lin_j·b_j), given
    /// `law = prepare(nl)`: [`Signature::fixed_with`] its
    /// [`Signature::fixed_term`] where the signature has a
    /// [`Signature::fixed_scope`], 0 otherwise.
    fn fixed(&self, law: &[f64], r: &Rec, cap: &CapInfo) -> f64 {
        match self.fixed_scope() {
            Some(_) => self.fixed_with(law, r, cap, self.fixed_term(law, r, cap)),
            None => 0.0,
        }
    }
    /// The terms of [`Signature::fixed`] that depend on `nl` alone (clamps
    /// and exponentials of the parameters), computed once per parameter
    /// vector rather than per sample: what `fixed` is called with. `nl`
    /// itself by default.
    fn prepare(&self, nl: &[f64]) -> Vec<f64> {
        nl.to_vec()
    }
    /// [`Signature::fixed`] at each of `laws` (a parameter vector's and its
    /// finite-difference steps'), into `out`: a signature whose laws share
    /// terms computes them once.
    fn fixed_all(&self, laws: &[&[f64]], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        for (o, law) in out.iter_mut().zip(laws) {
            *o = self.fixed(law, r, cap);
        }
    }
    /// Where [`Signature::fixed`] has a term that is the same for many samples:
    /// [`FixedMemo`] then computes it ([`Signature::fixed_term`]) once per raw
    /// image or per pixel of a capture; `None` (the default): no such term.
    fn fixed_scope(&self) -> Option<TermScope> {
        None
    }
    /// The term of [`Signature::fixed`] at `law` shared within
    /// [`Signature::fixed_scope`] (e.g. the phase shift a capture's temperature
    /// or a pixel's amplitude sets). Only called when that scope is `Some`.
    fn fixed_term(&self, _law: &[f64], _r: &Rec, _cap: &CapInfo) -> f64 {
        0.0
    }
    /// [`Signature::fixed_term`] at each of `laws` into `out`: a signature whose
    /// laws share parts of their terms computes those once.
    fn fixed_terms(&self, laws: &[&[f64]], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        for (t, law) in out.iter_mut().zip(laws) {
            *t = self.fixed_term(law, r, cap);
        }
    }
    /// [`Signature::fixed`] given `fixed_term(law, r, cap)` (0: no full law):
    /// a function of the sample and the term, the law entering through the
    /// term only ([`FixedMemo`] reuses the value of equal terms).
    fn fixed_with(&self, _law: &[f64], _r: &Rec, _cap: &CapInfo, _term: f64) -> f64 {
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
    /// when that is `Some`): a signature that has an image term overrides it
    /// with a function of the sample, capture and term, `nl` entering through
    /// the term only ([`ImageMemo::basis_sharing`] reuses the basis of equal
    /// terms).
    fn basis_image(&self, nl: &[f64], r: &Rec, cap: &CapInfo, _image: f64, out: &mut [f64]) {
        self.basis(nl, r, cap, out);
    }
    /// The parameters held at a value, in `lin` then `nl` order (`Some(value)`; empty, the
    /// default: none), which the fit leaves at those values ([`crate::hold`]).
    fn held(&self) -> crate::hold::HoldMask {
        Vec::new()
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
        match self.term(sig, nl, r, cap) {
            Some(t) => sig.basis_image(nl, r, cap, t, out),
            None => sig.basis(nl, r, cap, out),
        }
    }

    /// [`ImageMemo::basis`], or `base_out` (the basis `base` gave for this
    /// sample) where the image terms are equal: a finite-difference step of
    /// one parameter that leaves this image's term unchanged (a shape's knot
    /// away from the image's driver) has the same basis.
    #[inline]
    pub fn basis_sharing(
        &mut self,
        sig: &dyn Signature,
        nl: &[f64],
        r: &Rec,
        cap: &CapInfo,
        (base, base_out): (&ImageMemo, &[f64]),
        out: &mut [f64],
    ) {
        match (self.term(sig, nl, r, cap), base.term) {
            (Some(t), Some(u)) if t.to_bits() == u.to_bits() => out.copy_from_slice(base_out),
            (Some(t), _) => sig.basis_image(nl, r, cap, t, out),
            (None, _) => sig.basis(nl, r, cap, out),
        }
    }

    /// The image term of `sig` at `nl` for sample `r`'s raw image (computed
    /// when the raw image or `nl` changed).
    #[inline]
    fn term(&mut self, sig: &dyn Signature, nl: &[f64], r: &Rec, cap: &CapInfo) -> Option<f64> {
        if self.key != Some((r.cap, r.k)) || self.nl != nl {
            self.term = sig.image_term(nl, r.k, cap);
            self.key = Some((r.cap, r.k));
            self.nl.clear();
            self.nl.extend_from_slice(nl);
        }
        self.term
    }
}

/// Δcode of the phasor rotated by Δφ (rad), the full law of the effects on
/// the phase: A·[C(φ − θ + Δφ) − C(φ − θ)] (C the correlation waveform,
/// thesis 3.2.2; A and C(φ − θ) the sample's).
#[inline]
pub(crate) fn phase_shift_code(waveform: &Waveform, r: &Rec, dphi_rad: f64) -> f64 {
    r.a * (waveform.eval(r.phi - r.theta + dphi_rad).0 - r.c)
}

/// What a [`Signature::fixed_term`] is shared by.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TermScope {
    /// Every pixel of one raw image of a capture.
    Image,
    /// Every raw image of one pixel in a capture (at its modelled amplitude).
    Pixel,
}

/// Evaluates a signature's [`Signature::fixed_all`] sample by sample with its
/// shared term ([`Signature::fixed_term`]) computed once per raw image or per
/// pixel of a capture and law: the residual tables run in capture, raw image,
/// pixel order, so a per-image term is reused by the next sample and a
/// per-pixel one by the pixel's next raw image. The same values as
/// [`Signature::fixed_all`]. One memo serves one list of laws.
#[derive(Debug, Default, Clone)]
pub struct FixedMemo {
    /// Per slot (0 for [`TermScope::Image`], the pixel for [`TermScope::Pixel`]):
    /// the capture, raw image or pixel, and amplitude bits its terms are for.
    keys: Vec<Option<(u32, u32, u64)>>,
    /// The terms of each law, slot by slot.
    terms: Vec<f64>,
}

impl FixedMemo {
    /// [`Signature::fixed`] of `sig` at each of `laws` at sample `r`, into `out`.
    #[inline]
    pub fn fixed_all(
        &mut self,
        sig: &dyn Signature,
        laws: &[&[f64]],
        r: &Rec,
        cap: &CapInfo,
        out: &mut [f64],
    ) {
        let (slot, key) = match sig.fixed_scope() {
            None => return sig.fixed_all(laws, r, cap, out),
            Some(TermScope::Image) => (0, (r.cap, u32::from(r.k), 0)),
            Some(TermScope::Pixel) => (r.pix as usize, (r.cap, r.pix, r.a.to_bits())),
        };
        let n = laws.len();
        if self.keys.len() <= slot {
            self.keys.resize(slot + 1, None);
            self.terms.resize((slot + 1) * n, 0.0);
        }
        let terms = &mut self.terms[slot * n..(slot + 1) * n];
        if self.keys[slot] != Some(key) {
            sig.fixed_terms(laws, r, cap, terms);
            self.keys[slot] = Some(key);
        }
        for (i, (law, t)) in laws.iter().zip(terms.iter()).enumerate() {
            // a law whose term equals an earlier one's (a finite-difference
            // step of a shape's knot away from this image's driver) has its
            // value: `fixed_with` depends on the law through its term only
            out[i] = match terms[..i].iter().position(|u| u.to_bits() == t.to_bits()) {
                Some(j) => out[j],
                None => sig.fixed_with(law, r, cap, *t),
            };
        }
    }
}

/// The fitted non-linear parameters of `sig` (`nl`) at or beyond the bound
/// of their range ([`Signature::nl_bounds`]; within 10⁻⁶ of its width), one
/// line each: name, value and range. Discrete parameters (a choice between
/// forms, [`Signature::nl_discrete`]) are not flagged.
pub fn at_bounds(sig: &dyn Signature, nl: &[f64]) -> Vec<String> {
    let names = sig.nl_names();
    sig.nl_bounds()
        .iter()
        .enumerate()
        .filter(|(i, _)| !sig.nl_discrete(*i))
        .filter_map(|(i, b)| {
            let ((lo, hi), v) = ((*b)?, *nl.get(i)?);
            let tol = 1e-6 * (hi - lo).abs().max(1e-12);
            let side = if v <= lo + tol {
                "lower"
            } else if v >= hi - tol {
                "upper"
            } else {
                return None;
            };
            Some(format!(
                "{} = {v:.6} is at the {side} bound of its range [{lo}, {hi}]: the data push it there, and its standard error does not say how far it may be off",
                names.get(i).map_or("?", String::as_str)
            ))
        })
        .collect()
}

/// A fitted effect's parameters by name ([`Signature::lin_names`],
/// [`Signature::nl_names`]), as `add` and `--json` report them.
pub type Fitted = BTreeMap<String, f64>;

/// What writing a fitted effect into a model file may need besides its
/// parameters: the final lab model (its correlation waveform) and the
/// recording.
#[derive(Clone, Copy)]
pub struct WriteCtx<'a> {
    /// The lab model the effect was fitted in.
    pub model: &'a LabModel,
    /// The recording it was fitted on.
    pub prep: &'a Prepared,
}

/// Everything the lab knows about one catalogue effect besides its residual
/// shape: how to build its [`Signature`] for a recording, whether the
/// recording can identify it, and the two-way mapping between its fitted
/// parameters and the model file's.
pub trait LabEffect: Sync {
    /// The signature of the effect for this recording, model and correlation
    /// waveform.
    fn signature(&self, prep: &Prepared, spec: &LabSpec, waveform: &Waveform)
    -> Box<dyn Signature>;
    /// Why the effect cannot be fitted on this recording, if it cannot.
    fn not_identifiable(&self, _prep: &Prepared, _spec: &LabSpec) -> Option<String> {
        None
    }
    /// Write the fitted values into `m` (the effect already enabled) where
    /// they map onto the model's parameters; notes on what was not written.
    fn write(&self, fitted: &Fitted, m: &mut ModelConfig, ctx: &WriteCtx<'_>) -> Vec<String>;
    /// The lab's (lin, nl) at the model file's values (the inverse of
    /// [`LabEffect::write`], for `--hold-effects`); `None` where they do not
    /// map onto the lab's law.
    fn held(&self, _m: &ModelConfig, _prep: &Prepared) -> Option<(Vec<f64>, Vec<f64>)> {
        None
    }
    /// Whether the effect is part of the lab model's correlation waveform
    /// (fitted with it) rather than a Δcode on top of the model; the methods
    /// below are called only for such an effect.
    fn in_waveform(&self) -> bool {
        false
    }
    /// `spec` made to fit the effect with the waveform.
    fn widen_spec(&self, _spec: &mut LabSpec) {}
    /// `w` extended by the effect's fitted linear coefficients `lin` (its
    /// signature's, on top of `w`).
    fn extend_waveform(&self, _w: &mut Waveform, _lin: &[f64]) {}
    /// The effect's parameters, read from the fitted waveform `w`.
    fn waveform_params(&self, _w: &Waveform) -> Fitted {
        Fitted::new()
    }
}

/// One entry of the lab's registry: a catalogue effect and its lab module.
pub struct Entry {
    /// The model's id of the effect.
    pub id: EffectId,
    /// Its lab module.
    pub effect: &'static dyn LabEffect,
}

/// The lab modules of the lab's own signatures, in catalogue order.
const OWN: &[Entry] = &[
    entry(effects::sbi_asymmetry::ID, &sbi::Effect),
    entry(effects::tap_gain_mismatch::ID, &tap_gain::Effect),
    entry(effects::vcsel_droop::ID, &droop::Effect),
    entry(effects::amplitude_phase_error::ID, &amp_phase::Effect),
    entry(effects::temperature_drift::ID, &temp_drift::Effect),
    entry(effects::waveform_harmonics::ID, &harmonics::Effect),
    entry(effects::adc_inl::ID, &inl::Effect),
    entry(effects::dark_current::ID, &dark::Effect),
    entry(effects::multipath::ID, &multipath::Effect),
];

/// The lab modules of the model's effects with a code law (`tofprox_model::effects::CodeLaw`),
/// built from the model's registry: such an effect needs no line in the lab.
static CODE_LAWS: LazyLock<Vec<code_law::CodeLawEffect>> = LazyLock::new(|| {
    tofprox_model::effects::REGISTRY
        .iter()
        .filter_map(|&effect| {
            effect
                .code_law()
                .map(|law| code_law::CodeLawEffect { effect, law })
        })
        .collect()
});

/// Every effect the lab has a signature for: its own modules, then the model's code laws —
/// the one place that pairs a model effect with its lab module.
pub static REGISTRY: LazyLock<Vec<Entry>> = LazyLock::new(|| {
    let code_laws = CODE_LAWS.iter().map(|e| Entry {
        id: e.effect.id(),
        effect: e,
    });
    OWN.iter()
        .map(|e| entry(e.id, e.effect))
        .chain(code_laws)
        .collect()
});

const fn entry(id: EffectId, effect: &'static dyn LabEffect) -> Entry {
    Entry { id, effect }
}

/// The ids of [`REGISTRY`], in its order.
pub static SIGNATURE_IDS: LazyLock<Vec<&'static str>> =
    LazyLock::new(|| REGISTRY.iter().map(|e| e.id.as_str()).collect());

/// The lab module of effect `id`, if the lab has one.
pub fn lab_effect(id: &str) -> Option<&'static dyn LabEffect> {
    REGISTRY
        .iter()
        .find(|e| e.id.as_str() == id)
        .map(|e| e.effect)
}

/// The in-waveform lab module of effect `id` ([`LabEffect::in_waveform`]).
pub fn waveform_effect(id: &str) -> Option<&'static dyn LabEffect> {
    lab_effect(id).filter(|e| e.in_waveform())
}

/// `spec` with effect `id` enabled: an in-waveform effect widens the
/// waveform's fit, any other is added to the fitted effects.
pub fn enable_in_spec(spec: &mut LabSpec, id: &str) {
    match waveform_effect(id) {
        Some(e) => e.widen_spec(spec),
        None if !spec.effects.iter().any(|e| e == id) => spec.effects.push(id.to_string()),
        None => {}
    }
}

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

/// Why an effect cannot be fitted on this recording, if it cannot
/// ([`LabEffect::not_identifiable`]).
pub fn not_identifiable(id: &str, prep: &Prepared, spec: &LabSpec) -> Option<String> {
    lab_effect(id)?.not_identifiable(prep, spec)
}

/// The signature of effect `id` for this recording, model and correlation
/// waveform; [`ErrorKind::UnknownEffect`] when the lab has none.
pub fn make_signature(
    id: &str,
    prep: &Prepared,
    spec: &LabSpec,
    waveform: &Waveform,
) -> Result<Box<dyn Signature>, LabError> {
    if let Some(u) = spec.user_effects.iter().find(|u| u.name == id) {
        return Ok(crate::user::user_signature(u, prep, waveform));
    }
    let effect = lab_effect(id).ok_or_else(|| {
        LabError::new(
            ErrorKind::UnknownEffect,
            format!(
                "the lab has no signature for effect `{id}` (known: {})",
                SIGNATURE_IDS.join(", ")
            ),
        )
    })?;
    // the spec gives the law as a shape (crate::shape)
    if let Some(sig) = spec
        .shapes
        .get(id)
        .and_then(|k| crate::shape::make_shape_signature(id, k, prep, waveform))
    {
        return Ok(sig);
    }
    let sig = effect.signature(prep, spec, waveform);
    // parameters held (`lab add --hold`, crate::hold): the fit leaves them at their values
    Ok(match spec.holds.get(id) {
        Some(mask) => Box::new(crate::hold::Held {
            inner: sig,
            mask: mask.clone(),
        }),
        None => sig,
    })
}

/// The note for an effect whose fitted values the model file does not take.
fn not_written(effect: &str) -> String {
    format!(
        "{effect}: the lab's parameters are in measurement units (see --json params); the model file keeps its typical values"
    )
}

/// Enable `effect` in `m` and write the fitted values where the lab's
/// parameters map onto the model's ([`LabEffect::write`]); returns notes
/// about what was not mapped.
pub fn write_effect(
    m: &mut ModelConfig,
    effect: &str,
    params: &Fitted,
    model: &LabModel,
    prep: &Prepared,
) -> Result<Vec<String>, LabError> {
    m.set_enabled(effect, true).map_err(|e| {
        LabError::new(
            ErrorKind::InvalidModel,
            format!("cannot enable `{effect}`: {e}"),
        )
    })?;
    if let Some(notes) = write_shape(m, effect, model, prep) {
        return Ok(notes);
    }
    Ok(match lab_effect(effect) {
        Some(e) => e.write(params, m, &WriteCtx { model, prep }),
        None => vec![not_written(effect)],
    })
}

/// The chosen form of an effect that has one ([`tofprox_model::effects::shape::shape_law`]):
/// a shape (its knots in the lab's spec) is written and its notes returned; the parametric
/// law removes any shape keys and returns `None` (its parameters are written next) —
/// never both forms in the file.
fn write_shape(
    m: &mut ModelConfig,
    effect: &str,
    model: &LabModel,
    prep: &Prepared,
) -> Option<Vec<String>> {
    let id = EffectId::parse(effect)
        .filter(|id| tofprox_model::effects::shape::shape_law(id.as_str()).is_some())?;
    let fit = model.effects.iter().find(|e| e.id == effect);
    let shape = model.spec.shapes.get(effect).and_then(|knots| {
        crate::shape::model_shape(effect, knots, fit?, code_per_e(m), prep.temp_ref)
    });
    let mut w = Writer::new(m);
    if let Err(e) = w.m.set_shape(id, shape.clone()) {
        w.notes.push(format!("{effect}: shape not written ({e})"));
    }
    // the SBI's shape form keeps the parametric mismatch
    if let (Some(_), Some(f), effects::sbi_asymmetry::ID) = (&shape, fit, id)
        && let Some(v) = crate::shape::shape_mismatch_rel(f)
    {
        w.set(effects::sbi_asymmetry::MISMATCH_REL, v);
    }
    shape.is_some().then_some(w.notes)
}

/// The lab's (lin, nl) of effect `id` at model file `m`'s values
/// ([`LabEffect::held`]), where they map onto the lab's law.
pub fn held_params(id: &str, m: &ModelConfig, prep: &Prepared) -> Option<(Vec<f64>, Vec<f64>)> {
    let effect = lab_effect(id)?;
    // a file's shape form is held as the lab's shape (crate::shape)
    if let Some(e) = EffectId::parse(id).filter(|e| m.shape(*e).is_some()) {
        return crate::shape::held_shape(e, m, code_per_e(m).max(0.0), prep.temp_ref)
            .map(|(_, lin, nl)| (lin, nl));
    }
    effect.held(m, prep)
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
/// effects that act on the phasor: the temperature drift first
/// (`temp_drift::gain_phase`), then the amplitude-phase error at the
/// drifted amplitude (`amp_phase::phase_at`). Called per sample, so the
/// two phasor effects are matched directly rather than looked up.
pub fn phasor_shift(
    effects: &[EffectFit],
    shapes: &std::collections::BTreeMap<String, Vec<f64>>,
    cap: &CapInfo,
    a_lsb: f64,
) -> (f64, f64) {
    let (mut f, mut ph) = (1.0, 0.0);
    for e in effects
        .iter()
        .filter(|e| e.id == effects::temperature_drift::ID.as_str())
    {
        let (gain, dphi) = match shapes.get(&e.id) {
            Some(k) => crate::shape::shape_phasor(e, k, cap, a_lsb),
            None => temp_drift::gain_phase(e, cap),
        };
        f *= gain;
        ph += dphi;
    }
    for e in effects
        .iter()
        .filter(|e| e.id == effects::amplitude_phase_error::ID.as_str())
    {
        ph += match shapes.get(&e.id) {
            Some(k) => crate::shape::shape_phasor(e, k, cap, a_lsb * f).1,
            None => amp_phase::phase_at(e, cap, a_lsb * f),
        };
    }
    (f, ph)
}

/// The `qs` quantiles of the finite values of `v` (empty if none; nearest rank below).
pub(crate) fn quantiles(mut v: Vec<f64>, qs: &[f64]) -> Vec<f64> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return Vec::new();
    }
    v.sort_by(|a, b| a.total_cmp(b));
    qs.iter()
        .map(|q| v[((v.len() - 1) as f64 * q) as usize])
        .collect()
}

/// Writes fitted values into a model file, collecting a note for every value
/// the file's range refuses.
struct Writer<'a> {
    m: &'a mut ModelConfig,
    notes: Vec<String>,
}

impl<'a> Writer<'a> {
    fn new(m: &'a mut ModelConfig) -> Self {
        Self {
            m,
            notes: Vec::new(),
        }
    }
    fn set(&mut self, p: ParamId, v: f64) {
        if let Err(e) = self.m.set(p, v) {
            self.notes.push(format!(
                "{p} = {v:.6} not written ({e}); kept {:?}",
                self.m.param(p.section(), p.name())
            ));
        }
    }
    /// `v` clamped into the parameter's range (the lab's law holds it there).
    fn set_in_range(&mut self, p: ParamId, v: f64) {
        let v = catalogue::param_info(p).map_or(v, |i| v.clamp(i.min, i.max));
        self.set(p, v);
    }
}

/// Output codes per electron of differential charge — the unit the lab's
/// "LSB" are in: the conversion gain (`sensor.lsb_per_ke` / 1000) times the
/// converter's slope (eq. 3.2, [`tofprox_model::effects::adc_gain::gain_factor`]).
/// NaN when the file has no conversion gain.
pub(crate) fn code_per_e(m: &ModelConfig) -> f64 {
    m.get(ids::sensor::LSB_PER_KE) * 1e-3 * tofprox_model::effects::adc_gain::gain_factor(m)
}

/// A fit that measured the background charge per klux·ms (SBI, tap-gain
/// mismatch under varying ambient light) writes it as the model's ambient
/// responsivity `v` (e⁻/µs/klux), so that the file held reproduces the fit;
/// `why` says what the fit measured.
fn write_ambient(w: &mut Writer<'_>, v: f64, why: &str) {
    let a = effects::ambient_light::E_PER_US_PER_KLUX;
    if let Err(e) =
        w.m.enable(effects::ambient_light::ID, true)
            .and_then(|()| w.m.set(a, v))
    {
        w.notes.push(format!(
            "{a} = {v:.6} not written ({e}); kept {:?}",
            w.m.param(a.section(), a.name())
        ));
    } else {
        w.notes
            .push(format!("{a} = {v:.6} e-/us/klux written too: {why}"));
    }
}

/// The demodulation contrast K of the model file (1 when the effect is off).
fn contrast(m: &ModelConfig) -> f64 {
    if m.is_enabled(effects::demodulation_contrast::ID) {
        m.get(effects::demodulation_contrast::CONTRAST)
    } else {
        1.0
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
        for id in SIGNATURE_IDS.iter() {
            let e = catalogue::effect(id).unwrap_or_else(|| panic!("{id}: not in the registry"));
            assert!(!e.drivers.is_empty(), "{id}: no drivers");
            assert!(!effect_conditions(id).is_empty());
        }
        let ids_where = |f: fn(&str) -> bool| -> Vec<&str> {
            SIGNATURE_IDS.iter().copied().filter(|id| f(id)).collect()
        };
        assert_eq!(
            ids_where(acts_on_phasor),
            [
                effects::amplitude_phase_error::ID,
                effects::temperature_drift::ID
            ]
            .map(EffectId::as_str)
        );
        assert_eq!(
            ids_where(cancels_in_4phase),
            [
                effects::sbi_asymmetry::ID,
                effects::tap_gain_mismatch::ID,
                effects::dark_current::ID
            ]
            .map(EffectId::as_str)
        );
        assert!(effect_conditions("no_such_effect").is_empty() && !cancels_in_4phase("x"));
    }

    /// Each registry entry is listed once and builds the signature of the
    /// effect it is keyed by, whose parameter names are distinct; an effect
    /// without a lab module is a clear error.
    #[test]
    fn registry_entries_build_their_own_signature() {
        let ds = crate::synth::generate(&crate::synth::SynthSpec {
            rows: 2,
            cols: 2,
            ..Default::default()
        });
        let prep = Prepared::new(&ds).unwrap();
        let spec = LabSpec::default();
        let mut seen = Vec::new();
        for e in REGISTRY.iter() {
            assert!(!seen.contains(&e.id), "{}: listed twice", e.id.as_str());
            seen.push(e.id);
            let sig = make_signature(e.id.as_str(), &prep, &spec, &Waveform::sinusoid()).unwrap();
            assert_eq!(sig.id(), e.id.as_str());
            let mut names = sig.lin_names();
            names.extend(sig.nl_names());
            assert_eq!(
                names.len(),
                sig.n_lin() + sig.nl_start().len(),
                "{}",
                e.id.as_str()
            );
            let mut uniq = names.clone();
            uniq.sort();
            uniq.dedup();
            assert_eq!(uniq.len(), names.len(), "{}: {names:?}", e.id.as_str());
        }
        assert_eq!(SIGNATURE_IDS.len(), REGISTRY.len());
        let err = make_signature(
            effects::prnu::ID.as_str(),
            &prep,
            &spec,
            &Waveform::sinusoid(),
        )
        .err()
        .unwrap();
        assert_eq!(err.kind(), ErrorKind::UnknownEffect);
    }
}
