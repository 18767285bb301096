//! Fitting one effect with chosen parameters held (`lab add … --hold NAME[=VALUE]`,
//! Python's `lab.add(…, hold=…)`): the held parameters stay at their value, the others are
//! fitted.
//!
//! The user names the model file's parameters (`[effects.vcsel_droop] tau_us`); the lab fits
//! its signature's own ([`crate::signatures::Signature::lin_names`], `nl_names`: `ln_tau`,
//! `droop_rate`, …), which its module maps onto the file's ([`LabEffect::write`], inverse
//! [`LabEffect::held`]). [`resolve`] finds the lab parameters that the held file parameters
//! depend on — by moving each lab parameter and watching which file parameters it writes —
//! and holds exactly those, at the values [`LabEffect::held`] gives for the held file
//! values: a [`HoldMask`] the signature carries ([`Held`]) and the fit honours
//! (`crate::candidates::fit_values`). Holding a file parameter that shares a lab parameter
//! with one not held (`droop_rel` = `droop_rate`·τ without `tau_us`) would hold both, so it
//! is refused with the names to hold together.
use std::collections::BTreeMap;

use tofprox_model::ModelConfig;

use crate::error::{ErrorKind, LabError};
use crate::fit::{CapInfo, LabModel, Prepared, Rec, Sample};
use crate::signatures::{Fitted, LabEffect, Signature, TermScope, WriteCtx, lab_effect};

/// Per parameter of a signature, in `lin` then `nl` order: `Some(value)` where held.
pub type HoldMask = Vec<Option<f64>>;

/// One parameter to hold: the model file's name, at `value` or (None) at the file's value.
#[derive(Debug, Clone, PartialEq)]
pub struct HoldRequest {
    /// The model file's parameter name (`tau_us`).
    pub name: String,
    /// The value to hold it at; `None`: the model file's.
    pub value: Option<f64>,
}

impl HoldRequest {
    /// `NAME` or `NAME=VALUE` (the CLI's `--hold`).
    pub fn parse(s: &str) -> Result<Self, LabError> {
        let (name, value) = match s.split_once('=') {
            Some((n, v)) => {
                let v: f64 = v.trim().parse().map_err(|_| {
                    LabError::new(
                        ErrorKind::InvalidModel,
                        format!("--hold {s}: `{v}` is not a number (NAME or NAME=VALUE)"),
                    )
                })?;
                (n.trim(), Some(v))
            }
            None => (s.trim(), None),
        };
        Ok(Self {
            name: name.to_string(),
            value,
        })
    }
}

/// What [`resolve`] found: the mask for the lab's signature and the file's held values.
#[derive(Debug, Clone, Default)]
pub struct Resolved {
    /// The lab parameters held.
    pub mask: HoldMask,
    /// The model file's parameters held, at their values.
    pub held: BTreeMap<String, f64>,
}

fn invalid(effect: &str, why: String) -> LabError {
    LabError::new(
        ErrorKind::InvalidModel,
        format!("--hold for `{effect}`: {why}"),
    )
}

/// The lab parameters (`names` order) that the file parameters `params` are written from:
/// each lab parameter moved both ways from `at`, the file parameters it changed.
fn dependencies(
    e: &dyn LabEffect,
    effect: &str,
    (names, at): (&[String], &[f64]),
    m: &ModelConfig,
    ctx: &WriteCtx<'_>,
    params: &[&str],
) -> Result<Vec<Vec<usize>>, LabError> {
    let written = |v: &[f64]| -> Result<Vec<f64>, LabError> {
        let mut w = m.clone();
        w.set_enabled(effect, true)
            .map_err(|err| LabError::model(format!("enabling `{effect}`"), err))?;
        let fitted: Fitted = names.iter().cloned().zip(v.iter().copied()).collect();
        e.write(&fitted, &mut w, ctx);
        Ok(params
            .iter()
            .map(|p| w.param(effect, p).unwrap_or(f64::NAN))
            .collect())
    };
    let base = written(at)?;
    let mut deps = vec![Vec::new(); params.len()];
    for i in 0..at.len() {
        for sign in [1.0, -1.0] {
            let mut v = at.to_vec();
            v[i] += sign * 1e-3 * at[i].abs().max(1.0);
            for (j, (a, b)) in written(&v)?.iter().zip(&base).enumerate() {
                if (a - b).abs() > 1e-12 * b.abs().max(1.0) && !deps[j].contains(&i) {
                    deps[j].push(i);
                }
            }
        }
    }
    Ok(deps)
}

/// The mask that holds `hold` (the model file's parameters of `effect`) in a fit on `prep`
/// around `model` (the lab model the effect is added to): the file's value where a request
/// gives none. Refused: an effect the lab fits inside its waveform or as a user effect, a
/// name the effect does not have, one the lab does not write, and a set whose lab
/// parameters also fix a file parameter not held.
pub fn resolve(
    effect: &str,
    hold: &[HoldRequest],
    m: &ModelConfig,
    prep: &Prepared,
    model: &LabModel,
) -> Result<Resolved, LabError> {
    if hold.is_empty() {
        return Ok(Resolved::default());
    }
    let e = lab_effect(effect)
        .filter(|e| !e.in_waveform())
        .ok_or_else(|| {
            invalid(
                effect,
                "the lab holds parameters of the catalogue effects it fits as a signature only"
                    .into(),
            )
        })?;
    let info = tofprox_model::catalogue::effect(effect)
        .ok_or_else(|| invalid(effect, "not a catalogue effect".into()))?;
    let all: Vec<&str> = info.params.iter().map(|p| p.name).collect();
    let mut held_m = m.clone();
    let mut held = BTreeMap::new();
    for h in hold {
        if !all.contains(&h.name.as_str()) {
            let hint = tofprox_model::catalogue::closest(&h.name, all.iter().copied())
                .map(|c| format!(" (did you mean `{c}`?)"))
                .unwrap_or_default();
            return Err(invalid(
                effect,
                format!(
                    "`{}` is not one of its parameters{hint}: {}",
                    h.name,
                    all.join(", ")
                ),
            ));
        }
        let v = match h.value {
            Some(v) => v,
            None => m.param(effect, &h.name).unwrap_or(f64::NAN),
        };
        held_m
            .set_param(effect, &h.name, v)
            .map_err(|err| LabError::model(format!("--hold {}={v}", h.name), err))?;
        held.insert(h.name.clone(), v);
    }
    let (lin, nl) = e.held(&held_m, prep).ok_or_else(|| {
        invalid(
            effect,
            "its lab module cannot read parameters back from a model file".into(),
        )
    })?;
    let sig = e.signature(prep, &model.spec, &model.waveform);
    let names: Vec<String> = sig.lin_names().into_iter().chain(sig.nl_names()).collect();
    let at: Vec<f64> = lin.into_iter().chain(nl).collect();
    let ctx = WriteCtx { model, prep };
    let deps = dependencies(e, effect, (&names, &at), &held_m, &ctx, &all)?;
    let mut lab: Vec<usize> = Vec::new();
    for (name, d) in all.iter().zip(&deps) {
        if held.contains_key(*name) {
            if d.is_empty() {
                return Err(invalid(effect, format!("the lab does not fit `{name}`")));
            }
            for &i in d {
                if !lab.contains(&i) {
                    lab.push(i);
                }
            }
        }
    }
    // a file parameter written from held lab parameters alone is held too: it must be asked
    let also: Vec<&str> = all
        .iter()
        .zip(&deps)
        .filter(|(n, d)| {
            !held.contains_key(**n) && !d.is_empty() && d.iter().all(|i| lab.contains(i))
        })
        .map(|(n, _)| *n)
        .collect();
    if !also.is_empty() {
        let lab_names: Vec<&str> = lab.iter().map(|&i| names[i].as_str()).collect();
        return Err(invalid(
            effect,
            format!(
                "holding {} holds {} too (the lab fits {}): hold them together",
                held.keys().cloned().collect::<Vec<_>>().join(", "),
                also.join(", "),
                lab_names.join(", ")
            ),
        ));
    }
    let mask = (0..at.len())
        .map(|i| lab.contains(&i).then_some(at[i]))
        .collect();
    Ok(Resolved { mask, held })
}

/// A signature with some of its parameters held ([`Signature::held`]): everything else is
/// its inner signature's.
pub struct Held {
    /// The signature.
    pub inner: Box<dyn Signature>,
    /// Its held parameters.
    pub mask: HoldMask,
}

impl Signature for Held {
    fn id(&self) -> &str {
        self.inner.id()
    }
    fn n_lin(&self) -> usize {
        self.inner.n_lin()
    }
    fn lin_names(&self) -> Vec<String> {
        self.inner.lin_names()
    }
    fn nl_names(&self) -> Vec<String> {
        self.inner.nl_names()
    }
    fn nl_start(&self) -> Vec<f64> {
        let n = self.inner.n_lin();
        let mut s = self.inner.nl_start();
        for (i, v) in s.iter_mut().enumerate() {
            if let Some(h) = self.mask.get(n + i).copied().flatten() {
                *v = h;
            }
        }
        s
    }
    fn nl_bounds(&self) -> Vec<Option<(f64, f64)>> {
        self.inner.nl_bounds()
    }
    fn nl_discrete(&self, i: usize) -> bool {
        self.inner.nl_discrete(i)
    }
    fn nl_grid(&self, recs: &[Sample], prep: &Prepared) -> Vec<Vec<f64>> {
        self.inner.nl_grid(recs, prep)
    }
    fn held(&self) -> HoldMask {
        self.mask.clone()
    }
    fn basis(&self, nl: &[f64], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        self.inner.basis(nl, r, cap, out);
    }
    fn fixed(&self, law: &[f64], r: &Rec, cap: &CapInfo) -> f64 {
        self.inner.fixed(law, r, cap)
    }
    fn prepare(&self, nl: &[f64]) -> Vec<f64> {
        self.inner.prepare(nl)
    }
    fn fixed_all(&self, laws: &[&[f64]], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        self.inner.fixed_all(laws, r, cap, out);
    }
    fn fixed_scope(&self) -> Option<TermScope> {
        self.inner.fixed_scope()
    }
    fn fixed_term(&self, law: &[f64], r: &Rec, cap: &CapInfo) -> f64 {
        self.inner.fixed_term(law, r, cap)
    }
    fn fixed_terms(&self, laws: &[&[f64]], r: &Rec, cap: &CapInfo, out: &mut [f64]) {
        self.inner.fixed_terms(laws, r, cap, out);
    }
    fn fixed_with(&self, law: &[f64], r: &Rec, cap: &CapInfo, term: f64) -> f64 {
        self.inner.fixed_with(law, r, cap, term)
    }
    fn image_term(&self, nl: &[f64], k: u16, cap: &CapInfo) -> Option<f64> {
        self.inner.image_term(nl, k, cap)
    }
    fn basis_image(&self, nl: &[f64], r: &Rec, cap: &CapInfo, image: f64, out: &mut [f64]) {
        self.inner.basis_image(nl, r, cap, image, out);
    }
}
