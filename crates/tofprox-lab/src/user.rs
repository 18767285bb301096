//! User effects in the lab (issue 33, item 3): a condition the catalogue
//! lacks becomes an effect the user adds. The law is the model's
//! ([`tofprox_model::effects::user`]: a response to one capture condition
//! acting on the phase, the gain or the offset); this module is its lab side:
//!
//! * [`proposal`]: an `unexplained` verdict whose strongest condition is a
//!   capture condition proposes a *condition response* to it, acting where
//!   the structure's projection says (offset, amplitude → gain, phase), with
//!   the exact `lab add` argument `condition:<KEY>`;
//! * [`UserSignature`]: the residual it leaves, evaluated through the model's
//!   law — a shape's values at the knots (the first held at 0: a constant is
//!   the per-pixel offset, gain or phase's) or an expression's parameters
//!   (clamped into their ranges), fitted like the catalogue's signatures
//!   (variable projection, then core's `lsq` Levenberg–Marquardt);
//! * [`add_condition`] / [`add_declared`]: `lab add condition:<KEY>` (a shape
//!   with knots at the condition's recorded values) and `lab add user:<NAME>`
//!   (a user effect the model file declares, e.g. an expression);
//! * [`write_user_effect`] and [`with_user_effects`]: the fitted effect into
//!   the model and its file, with its provenance.
use std::path::Path;

use serde::Serialize;
use tofprox_model::ModelConfig;
use tofprox_model::effects::shape as law;
use tofprox_model::effects::user::{
    CaptureQuantities, Provenance, QUANTITIES, UserActsOn, UserEffect, UserLaw,
};

use crate::candidates::fit_signature;
use crate::diagnose::{
    AddOutcome, Comparison, Diagnosis, Verdict, compare, comparison_of, effect_params,
    fitted_effect,
};
use crate::error::{ErrorKind, LabError};
use crate::fit::Progress;
use crate::prepared::{CapInfo, Prepared};
use crate::sample::{Rec, Sample};
use crate::signatures::{Signature, TermScope, phase_shift_code};
use crate::spec::{EffectFit, LabSpec};
use crate::structure::CONDITIONS;
use crate::waveform::Waveform;

/// The `lab add` argument's prefix for a condition response: `condition:<KEY>`.
pub const CONDITION_PREFIX: &str = "condition:";
/// The `lab add` argument's prefix for a user effect the model file declares: `user:<NAME>`.
pub const USER_PREFIX: &str = "user:";
/// The most knots of a condition response (at the condition's recorded values).
pub const MAX_KNOTS: usize = 6;

/// The value of condition `key` in capture `cap` (None where it states none).
pub fn condition_of(prep: &Prepared, key: &str, cap: &CapInfo) -> Option<f64> {
    match key {
        "exposure_us" => Some(cap.exposure_us),
        "temperature_c" => cap.temperature_c,
        "ambient_klux" => Some(cap.ambient_klux),
        _ => {
            let i = prep.extra_keys.iter().position(|k| k == key)?;
            cap.extra.get(i).copied().filter(|v| v.is_finite())
        }
    }
}

/// Whether `key` is a condition a user effect can follow: one of the model's
/// capture [`QUANTITIES`] or a key of the user's own (not a per-sample
/// quantity like the amplitude or the column).
pub fn is_capture_condition(key: &str) -> bool {
    QUANTITIES.contains(&key) || !CONDITIONS.contains(&key)
}

fn quantities(cap: &CapInfo) -> CaptureQuantities {
    CaptureQuantities {
        exposure_us: cap.exposure_us,
        // as `tofprox_model::sweep::plan_like`: 25 °C where not stated
        temperature_c: cap.temperature_c.unwrap_or(25.0),
        ambient_klux: cap.ambient_klux,
    }
}

/// The quantity the structure's strongest direction (`offset`, `amplitude`,
/// `phase`) says a response acts on.
pub fn acts_on_direction(direction: &str) -> UserActsOn {
    match direction {
        "offset" => UserActsOn::Offset,
        "amplitude" => UserActsOn::Gain,
        _ => UserActsOn::Phase,
    }
}

/// The name `lab add condition:<KEY>` gives the response to `key` on `acts_on`.
pub fn response_name(key: &str, acts_on: UserActsOn) -> String {
    format!("{key}_{}", acts_on.as_str())
}

/// What an `unexplained` diagnosis proposes to add.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Proposal {
    /// The exact `lab add` argument: `condition:<KEY>`.
    pub add: String,
    /// The condition the response follows.
    pub condition: String,
    /// Where it acts (`phase`, `gain`, `offset`), from the structure's direction.
    pub acts_on: &'static str,
    /// The name it gets in the model file.
    pub name: String,
    /// The structure's size against the condition (depth-equivalent mm RMS).
    pub size_mm: f64,
    /// Its structure z.
    pub z: f64,
    /// The proposal in one sentence.
    pub sentence: String,
}

/// The condition response an `unexplained` diagnosis proposes: for the
/// strongest condition of what remains, when it is a capture condition
/// ([`is_capture_condition`]); acting where that structure's direction says.
pub fn proposal(d: &Diagnosis) -> Option<Proposal> {
    if d.verdict != Verdict::Unexplained {
        return None;
    }
    let key = d.strongest_condition.as_deref()?;
    if !is_capture_condition(key) {
        return None;
    }
    let st = d.structure_remaining.iter().find(|s| s.condition == key)?;
    let acts = acts_on_direction(st.direction);
    let add = format!("{CONDITION_PREFIX}{key}");
    Some(Proposal {
        sentence: format!(
            "No catalogue effect explains the structure against `{key}` ({:.2} mm, z {:.1}, in {}): add a response to it acting on the {} — `tofprox lab add {add} --model M --data REC --out M2`.",
            st.size_mm,
            st.z,
            st.direction,
            acts.as_str()
        ),
        name: response_name(key, acts),
        acts_on: acts.as_str(),
        condition: key.to_string(),
        add,
        size_mm: st.size_mm,
        z: st.z,
    })
}

/// The signature of a user effect: Δcode of its response at each sample.
pub struct UserSignature {
    def: UserEffect,
    /// The condition's value per capture (None: not stated, no response).
    x: Vec<Option<f64>>,
    /// The capture quantities per capture (an expression's variables).
    q: Vec<CaptureQuantities>,
    waveform: Waveform,
}

/// The signature of user effect `u` on `prep` (the lab's correlation `waveform`).
pub fn user_signature(u: &UserEffect, prep: &Prepared, waveform: &Waveform) -> Box<dyn Signature> {
    Box::new(UserSignature {
        def: u.clone(),
        x: prep
            .caps
            .iter()
            .map(|c| condition_of(prep, &u.condition, c))
            .collect(),
        q: prep.caps.iter().map(quantities).collect(),
        waveform: waveform.clone(),
    })
}

/// The hat weights of knots 1.. at `x` minus those at the first knot (the
/// shape with its first value held at 0).
fn rel_weights(knots: &[f64], x: f64, out: &mut [f64]) {
    let mut w = vec![0.0; knots.len()];
    law::hat_weights(knots, x, &mut w);
    for (o, v) in out.iter_mut().zip(w.iter().skip(1)) {
        *o = *v;
    }
}

impl UserSignature {
    fn knots(&self) -> Option<&[f64]> {
        match &self.def.law {
            UserLaw::Shape { knots_x, .. } => Some(knots_x),
            UserLaw::Expression { .. } => None,
        }
    }
    /// Fitted values of a shape (knots 1..) or an expression's parameters.
    fn n_values(&self) -> usize {
        match &self.def.law {
            UserLaw::Shape { knots_x, .. } => knots_x.len() - 1,
            UserLaw::Expression { params, .. } => params.len(),
        }
    }
    /// The values live in `nl` (a phase shape, an expression), not `lin`.
    fn in_nl(&self) -> bool {
        self.knots().is_none() || self.def.acts_on == UserActsOn::Phase
    }
    /// The response of capture `c` at `nl` (0 where the capture states no value).
    fn response(&self, nl: &[f64], c: usize) -> f64 {
        let Some(x) = self.x.get(c).copied().flatten() else {
            return 0.0;
        };
        match self.knots() {
            Some(k) => {
                let mut w = vec![0.0; k.len() - 1];
                rel_weights(k, x, &mut w);
                w.iter().zip(nl).map(|(a, b)| a * b).sum()
            }
            None => self
                .def
                .response_with(nl, x, &self.q[c])
                .unwrap_or(f64::NAN),
        }
    }
    /// Δcode of a response `v` at a sample: the phasor rotated (phase), the
    /// signal scaled (gain), a code added (offset).
    fn code(&self, r: &Rec, v: f64) -> f64 {
        match self.def.acts_on {
            UserActsOn::Phase => phase_shift_code(&self.waveform, r, v),
            UserActsOn::Gain => r.a * r.c * v,
            UserActsOn::Offset => v,
        }
    }
    /// First-order start of a phase shape: least squares of
    /// r = Σ_j v_j·A·C′·w_j + nuisance (offset, gain, phase).
    fn screen(&self, recs: &[Sample], prep: &Prepared) -> Option<Vec<f64>> {
        let k = self.knots()?;
        let n = k.len() - 1;
        let mut acc = tofprox_core::lsq::Normal::zeros(n + 3);
        let mut j = vec![0.0; n + 3];
        for s in recs.iter().step_by((recs.len() / 60_000).max(1)) {
            let r = s.rec(prep);
            match self.x.get(r.cap as usize).copied().flatten() {
                Some(x) => rel_weights(k, x, &mut j[..n]),
                None => j[..n].iter_mut().for_each(|v| *v = 0.0),
            }
            j[..n].iter_mut().for_each(|v| *v *= r.a * r.cd);
            j[n..].copy_from_slice(&[1.0, r.a * r.c, r.a * r.cd]);
            acc.add(&j, r.r, r.w);
        }
        acc.symmetrize();
        let sol = tofprox_core::lsq::solve_sym(&acc.jtj, &acc.jtr)?;
        Some(sol[..n].to_vec())
    }
    fn value_names(&self) -> Vec<String> {
        let key = &self.def.condition;
        let q = match self.def.acts_on {
            UserActsOn::Phase => "phase_rad",
            UserActsOn::Gain => "gain_rel",
            UserActsOn::Offset => "offset_lsb",
        };
        match &self.def.law {
            UserLaw::Shape { knots_x, .. } => knots_x
                .iter()
                .skip(1)
                .map(|x| format!("{q}_at_{key}_{x}"))
                .collect(),
            UserLaw::Expression { params, .. } => params.iter().map(|p| p.name.clone()).collect(),
        }
    }
}

impl Signature for UserSignature {
    fn id(&self) -> &str {
        &self.def.name
    }
    fn n_lin(&self) -> usize {
        if self.in_nl() { 0 } else { self.n_values() }
    }
    fn lin_names(&self) -> Vec<String> {
        if self.in_nl() {
            Vec::new()
        } else {
            self.value_names()
        }
    }
    fn nl_names(&self) -> Vec<String> {
        if self.in_nl() {
            self.value_names()
        } else {
            Vec::new()
        }
    }
    fn nl_start(&self) -> Vec<f64> {
        match &self.def.law {
            _ if !self.in_nl() => Vec::new(),
            UserLaw::Shape { .. } => vec![0.0; self.n_values()],
            UserLaw::Expression { .. } => self.def.param_values(),
        }
    }
    fn nl_grid(&self, recs: &[Sample], prep: &Prepared) -> Vec<Vec<f64>> {
        let mut g = vec![self.nl_start()];
        if self.in_nl()
            && let Some(v) = self.screen(recs, prep)
        {
            // sin Δφ < Δφ: the first-order fit underestimates a strong phase
            g.push(v.iter().map(|x| 1.25 * x).collect());
            g.push(v);
        }
        g
    }
    /// A shape's lin basis (gain, offset): the relative hat weights, times
    /// A·C for the gain.
    fn basis(&self, _: &[f64], r: &Rec, _: &CapInfo, out: &mut [f64]) {
        let (Some(k), Some(x)) = (self.knots(), self.x.get(r.cap as usize).copied().flatten())
        else {
            out.iter_mut().for_each(|v| *v = 0.0);
            return;
        };
        rel_weights(k, x, out);
        let f = self.code(r, 1.0);
        out.iter_mut().for_each(|v| *v *= f);
    }
    /// An expression's parameters held inside their ranges.
    fn prepare(&self, nl: &[f64]) -> Vec<f64> {
        match &self.def.law {
            UserLaw::Expression { params, .. } => nl
                .iter()
                .zip(params)
                .map(|(v, p)| v.clamp(p.min, p.max))
                .collect(),
            UserLaw::Shape { .. } => nl.to_vec(),
        }
    }
    /// The response: the same for every sample of a capture.
    fn fixed_scope(&self) -> Option<TermScope> {
        self.in_nl().then_some(TermScope::Image)
    }
    fn fixed_term(&self, law: &[f64], r: &Rec, _: &CapInfo) -> f64 {
        self.response(law, r.cap as usize)
    }
    fn fixed_with(&self, _: &[f64], r: &Rec, _: &CapInfo, v: f64) -> f64 {
        self.code(r, v)
    }
}

/// The knots of a response to `key`: its distinct recorded values over the
/// illuminated captures (at most [`MAX_KNOTS`], evenly ranked, the extremes
/// included); an error where it takes fewer than 2.
pub fn condition_knots(prep: &Prepared, key: &str) -> Result<Vec<f64>, LabError> {
    let mut v: Vec<f64> = prep
        .caps
        .iter()
        .filter(|c| c.illum && c.used)
        .filter_map(|c| condition_of(prep, key, c))
        .collect();
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * b.abs().max(1.0));
    if v.len() < 2 {
        let known = prep.extra_keys.join(", ");
        return Err(LabError::new(
            ErrorKind::NotIdentifiable,
            format!(
                "cannot add a response to `{key}`: the recording's illuminated captures state {} value(s) of it (it must vary; conditions of the recording's own that vary: {known})",
                v.len()
            ),
        ));
    }
    let k = v.len().min(MAX_KNOTS);
    Ok((0..k).map(|i| v[i * (v.len() - 1) / (k - 1)]).collect())
}

/// `lab add condition:<KEY>`: fit a condition response to `key` (a shape with
/// knots at its recorded values), acting where the structure against it says,
/// on top of `spec`.
pub fn add_condition(
    prep: &Prepared,
    spec: &LabSpec,
    key: &str,
    progress: Progress<'_>,
) -> Result<AddOutcome, LabError> {
    if !is_capture_condition(key) {
        return Err(LabError::new(
            ErrorKind::UnknownEffect,
            format!(
                "`{key}` is not a capture condition a response can follow (one of {} or a key of the recording's own: {})",
                QUANTITIES.join(", "),
                prep.extra_keys.join(", ")
            ),
        ));
    }
    let knots = condition_knots(prep, key)?;
    let before = compare(prep, spec, progress)?;
    let direction = before
        .structure
        .iter()
        .find(|s| s.condition == key)
        .map_or("phase", |s| s.direction);
    let acts_on = acts_on_direction(direction);
    let name = response_name(key, acts_on);
    if spec.user_effects.iter().any(|u| u.name == name) {
        return Err(LabError::new(
            ErrorKind::InvalidModel,
            format!("the model already has the user effect `{name}`"),
        ));
    }
    let def = UserEffect {
        name,
        condition: key.to_string(),
        acts_on,
        law: UserLaw::Shape {
            knots_y: vec![0.0; knots.len()],
            knots_x: knots,
        },
        provenance: None,
    };
    add_user_to(prep, before, def, progress)
}

/// `lab add user:<NAME>`: fit the user effect `name` the model file declares
/// (its expression's parameters, or its shape's values) on top of the model
/// without it.
pub fn add_declared(
    prep: &Prepared,
    spec: &LabSpec,
    name: &str,
    progress: Progress<'_>,
) -> Result<AddOutcome, LabError> {
    let def = spec
        .user_effects
        .iter()
        .find(|u| u.name == name)
        .cloned()
        .ok_or_else(|| {
            let names: Vec<&str> = spec.user_effects.iter().map(|u| u.name.as_str()).collect();
            LabError::new(
                ErrorKind::UnknownEffect,
                format!(
                    "the model file declares no user effect `{name}` (it declares: {})",
                    names.join(", ")
                ),
            )
        })?;
    condition_knots(prep, &def.condition)?;
    let mut without = spec.clone();
    without.user_effects.retain(|u| u.name != name);
    without.effects.retain(|e| e != name);
    let before = compare(prep, &without, progress)?;
    add_user_to(prep, before, def, progress)
}

/// Add the user effect `def` to the fitted model of `before`: its signature
/// fitted on the residual, the whole model refined from there, against a fit
/// of the extended model from scratch — the better kept (as
/// [`crate::diagnose::add_effect_to`] for a catalogue effect).
pub fn add_user_to(
    prep: &Prepared,
    before: Comparison,
    def: UserEffect,
    progress: Progress<'_>,
) -> Result<AddOutcome, LabError> {
    let name = def.name.clone();
    let sig = user_signature(&def, prep, &before.model.waveform);
    let start = EffectFit {
        id: name.clone(),
        lin: vec![0.0; sig.n_lin()],
        nl: sig.nl_start(),
    };
    let fit = fit_signature(sig.as_ref(), &before.recs, prep, Some(&start))?;
    let mut base = before.model.clone();
    base.spec.user_effects.push(def.clone());
    let mut spec2 = before.model.spec.clone();
    spec2.user_effects.push(def);
    spec2.effects.push(name.clone());
    let effect = EffectFit {
        id: name.clone(),
        lin: fit.lin,
        nl: fit.nl,
    };
    let mut warm = crate::fit::refit_with(prep, &base, &effect, fit.nuisance, 3)?;
    crate::fit::refine(prep, &mut warm, 4, false, true, &|_, _| {})?;
    let warm = comparison_of(prep, warm)?;
    let scratch = compare(prep, &spec2, progress)?;
    let after = if scratch.fit.chi2_per_dof < warm.fit.chi2_per_dof {
        scratch
    } else {
        warm
    };
    let f = fitted_effect(prep, &after, &name)?;
    let (fitted, _) = effect_params(prep, &after.model, &name)?;
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

/// The user effect `name` as fitted in `out` (its model's values: a shape's
/// values at the knots, made monotone where the fit is not; an expression's
/// parameters inside their ranges), with its provenance from `recording`
/// and the χ²/dof before and after; notes on what was changed.
pub fn fitted_user_effect(
    out: &AddOutcome,
    name: &str,
    recording: &Path,
) -> Result<(UserEffect, Vec<String>), LabError> {
    let model = &out.after.model;
    let mut def = model
        .spec
        .user_effects
        .iter()
        .find(|u| u.name == name)
        .cloned()
        .ok_or_else(|| LabError::numerical(format!("{name} is not in the fitted model")))?;
    let fit = model
        .effects
        .iter()
        .find(|e| e.id == name)
        .ok_or_else(|| LabError::numerical(format!("{name} is not in the fitted model")))?;
    let mut notes = Vec::new();
    let on_nl = matches!(def.law, UserLaw::Expression { .. }) || def.acts_on == UserActsOn::Phase;
    let values = if on_nl { &fit.nl } else { &fit.lin };
    match &mut def.law {
        UserLaw::Shape { knots_y, .. } => {
            let mut y = vec![0.0];
            y.extend_from_slice(values);
            let m = law::monotone_projection(&y);
            if m != y {
                notes.push(format!(
                    "{name}: the fitted values {y:?} are not monotone; written as the closest monotone curve {m:?}"
                ));
            }
            *knots_y = m;
        }
        UserLaw::Expression { params, .. } => {
            for (p, v) in params.iter_mut().zip(values) {
                let c = v.clamp(p.min, p.max);
                if c != *v {
                    notes.push(format!(
                        "{name}.{} = {v} fitted at its range's bound [{}, {}]",
                        p.name, p.min, p.max
                    ));
                }
                p.value = c;
            }
        }
    }
    def.provenance = Some(Provenance {
        recording: recording.display().to_string(),
        date: today_utc(),
        chi2_per_dof_before: out.before.fit.chi2_per_dof,
        chi2_per_dof_after: out.after.fit.chi2_per_dof,
    });
    Ok((def, notes))
}

/// Write the user effect `name` as fitted in `out` into `m` ([`fitted_user_effect`]).
pub fn write_user_effect(
    m: &mut ModelConfig,
    out: &AddOutcome,
    name: &str,
    recording: &Path,
) -> Result<Vec<String>, LabError> {
    let (def, notes) = fitted_user_effect(out, name, recording)?;
    m.set_user_effect(def)
        .map_err(|e| LabError::model(format!("user effect `{name}`"), e))?;
    Ok(notes)
}

/// The lab's fit of user effect `u` at the file's values (`compare --hold-effects`): a
/// shape's values relative to its first knot (the constant is the per-pixel parameters'),
/// an expression's parameters.
pub fn held_user(u: &UserEffect) -> EffectFit {
    let values = match &u.law {
        UserLaw::Shape { knots_y, .. } => knots_y.iter().skip(1).map(|y| y - knots_y[0]).collect(),
        UserLaw::Expression { .. } => u.param_values(),
    };
    let on_nl = matches!(u.law, UserLaw::Expression { .. }) || u.acts_on == UserActsOn::Phase;
    let (lin, nl) = if on_nl {
        (Vec::new(), values)
    } else {
        (values, Vec::new())
    };
    EffectFit {
        id: u.name.clone(),
        lin,
        nl,
    }
}

/// A model file's text with its `[[user_effects]]` replaced by `m`'s
/// (the rest as given; comments inside the old user effects are not kept).
pub fn with_user_effects(text: &str, m: &ModelConfig) -> Result<String, LabError> {
    let mut doc: toml_edit::DocumentMut = text.parse().map_err(|e| {
        LabError::new(
            ErrorKind::InvalidModel,
            format!("model file is not valid TOML: {e}"),
        )
    })?;
    if doc.remove(tofprox_model::effects::user::SECTION).is_none() && m.user_effects().is_empty() {
        return Ok(text.to_string());
    }
    let mut out = doc.to_string();
    for u in m.user_effects() {
        if !out.ends_with("\n\n") {
            out.push('\n');
        }
        out.push_str(&u.to_toml());
    }
    Ok(out)
}

/// Today's date (UTC) as YYYY-MM-DD (the civil date of the Unix day count,
/// H. Hinnant's `civil_from_days`).
fn today_utc() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let z = (secs / 86_400) as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}")
}
