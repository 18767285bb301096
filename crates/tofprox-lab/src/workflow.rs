//! The lab's commands as a workflow over files: read the recording and the model file, check
//! what `add` is asked before fitting, and write fitted effects back into the user's model file
//! with its comments and layout kept. `tofprox lab` and the Python package are thin adapters
//! over these functions and [`mod@crate::diagnose`]; neither has lab logic of its own.
use std::collections::BTreeMap;
use std::path::Path;

use tofprox_model::ModelConfig;

use crate::adapter::{load_recording, spec_from_model};
use crate::diagnose::{
    AddOutcome, DiagnoseOptions, Explanation, add_effect, add_effect_to, compare, effect_params,
};
use crate::error::{ErrorKind, LabError};
use crate::fit::Progress;
use crate::hold::{HoldRequest, resolve};
use crate::model_file::update_model_text;
use crate::prepared::Prepared;
use crate::signatures::{SIGNATURE_IDS, write_effect};
use crate::user;

/// The recording at `rec`, prepared for fitting, and the model file at `model`.
pub fn load(rec: &Path, model: &Path) -> Result<(Prepared, ModelConfig), LabError> {
    let m = ModelConfig::load(model)
        .map_err(|e| LabError::model(format!("model file {}", model.display()), e))?;
    let ds = load_recording(rec)?;
    let prep = Prepared::new(&ds)
        .map_err(|e| LabError::new(e.kind(), format!("recording {}: {e}", rec.display())))?;
    Ok((prep, m))
}

/// `Ok` when the lab can add `effect`: a catalogue effect it has a signature for, a
/// condition response `condition:<KEY>` or a declared user effect `user:<NAME>`
/// ([`crate::user`]); otherwise an [`ErrorKind::UnknownEffect`] naming the closest id and
/// every addable one.
pub fn check_addable(effect: &str) -> Result<(), LabError> {
    if SIGNATURE_IDS.contains(&effect) {
        return Ok(());
    }
    for prefix in [user::CONDITION_PREFIX, user::USER_PREFIX] {
        if let Some(key) = effect.strip_prefix(prefix) {
            return if tofprox_model::effects::user::is_identifier(key) {
                Ok(())
            } else {
                Err(LabError::new(
                    ErrorKind::UnknownEffect,
                    format!(
                        "`{effect}`: `{key}` must be a lower-case identifier (`{prefix}<KEY>`)"
                    ),
                ))
            };
        }
    }
    let hint = tofprox_model::catalogue::closest(effect, SIGNATURE_IDS.iter().copied())
        .map(|c| format!(" (did you mean `{c}`?)"))
        .unwrap_or_default();
    Err(LabError::new(
        ErrorKind::UnknownEffect,
        format!(
            "the lab cannot add `{effect}`{hint}; it can add: {}, condition:<KEY> (a response to a condition of the recording) and user:<NAME> (a user effect the model file declares)",
            SIGNATURE_IDS.join(", ")
        ),
    ))
}

/// The verdict's settings: `tolerance_mm` must be a finite number ≥ 0 (`None`: the
/// recording's noise decides).
pub fn diagnose_options(tolerance_mm: Option<f64>) -> Result<DiagnoseOptions, LabError> {
    if let Some(t) = tolerance_mm
        && !(t.is_finite() && t >= 0.0)
    {
        return Err(LabError::new(
            ErrorKind::InvalidModel,
            format!("--tolerance-mm must be a finite number >= 0, got {t}"),
        ));
    }
    Ok(DiagnoseOptions { tolerance_mm })
}

/// A model file is never overwritten (the model read included) unless `force`.
pub fn check_out(out: Option<&Path>, force: bool) -> Result<(), LabError> {
    match out {
        Some(p) if p.exists() && !force => Err(LabError::new(
            ErrorKind::Io,
            format!(
                "{} exists: pass --force to replace it, or choose another --out",
                p.display()
            ),
        )),
        _ => Ok(()),
    }
}

/// Enable `effect` in `m`, fit it on `prep` (the recording at `recording`) and write the
/// fitted values into `m`: the outcome (before/after) and notes on what did not map onto the
/// model file's parameters. `condition:<KEY>` and `user:<NAME>` add a user effect
/// ([`crate::user`]), written with its provenance.
pub fn add_to_model(
    prep: &Prepared,
    m: &mut ModelConfig,
    effect: &str,
    recording: &Path,
    progress: Progress<'_>,
) -> Result<(AddOutcome, Vec<String>), LabError> {
    check_addable(effect)?;
    let spec = spec_from_model(m);
    let res = if let Some(key) = effect.strip_prefix(user::CONDITION_PREFIX) {
        Some(user::add_condition(prep, &spec, key, progress)?)
    } else if let Some(name) = effect.strip_prefix(user::USER_PREFIX) {
        Some(user::add_declared(prep, &spec, name, progress)?)
    } else {
        None
    };
    if let Some(res) = res {
        let name = res.effect.id.clone();
        let notes = user::write_user_effect(m, &res, &name, recording)?;
        return Ok((res, notes));
    }
    let res = add_effect(prep, &spec_from_model(m), effect, progress)?;
    let notes = write_effect(m, effect, &res.params, &res.after.model, prep)?;
    Ok((res, notes))
}

/// The model file's parameters held in an `add`, by name, at their values.
pub type Held = BTreeMap<String, f64>;

/// [`add_to_model`] with the model file's parameters `hold` of `effect` held ([`crate::hold`]):
/// they keep their values (the file's where a request gives none), the others are fitted.
/// Returns the outcome, the notes and the held parameters with their values (by the file's
/// names). Without `hold`, exactly [`add_to_model`].
pub fn add_holding(
    prep: &Prepared,
    m: &mut ModelConfig,
    effect: &str,
    recording: &Path,
    hold: &[HoldRequest],
    progress: Progress<'_>,
) -> Result<(AddOutcome, Vec<String>, Held), LabError> {
    if hold.is_empty() {
        let (res, notes) = add_to_model(prep, m, effect, recording, progress)?;
        return Ok((res, notes, BTreeMap::new()));
    }
    check_addable(effect)?;
    let spec = spec_from_model(m);
    let mut before = compare(prep, &spec, progress)?;
    let held = resolve(effect, hold, m, prep, &before.model)?;
    before
        .model
        .spec
        .holds
        .insert(effect.to_string(), held.mask);
    let res = add_effect_to(prep, before, effect, None, progress)?;
    let notes = write_effect(m, effect, &res.params, &res.after.model, prep)?;
    // a held parameter is written as asked, not as its round trip through the lab's
    // parameterisation (τ = exp(ln τ) would write 3000.0000000000005 for 3000)
    for (name, v) in &held.held {
        m.set_param(effect, name, *v)
            .map_err(|err| LabError::model(format!("writing the held {name}"), err))?;
    }
    Ok((res, notes, held.held))
}

/// Write every effect `ex` added, as fitted in its final model, into `m`; notes as
/// [`add_to_model`]'s.
pub fn apply_explained(
    prep: &Prepared,
    m: &mut ModelConfig,
    ex: &Explanation,
) -> Result<Vec<String>, LabError> {
    let mut notes = Vec::new();
    if let Some(fin) = ex.final_model() {
        for e in &ex.added {
            let (_, params) = effect_params(prep, fin, e)?;
            notes.extend(write_effect(m, e, &params, fin, prep)?);
        }
    }
    Ok(notes)
}

/// Write `m` to `out` as the user's model file `from` with the `changed` effects updated
/// (comments and layout of `from` kept).
pub fn write_model(
    from: &Path,
    m: &ModelConfig,
    changed: &[String],
    out: &Path,
) -> Result<(), LabError> {
    let text =
        tofprox_format::limits::read_text_bounded(from, tofprox_format::limits::MAX_TOML_BYTES)
            .map_err(|e| LabError::format(format!("reading model {}", from.display()), e))?;
    // user effects (`condition:<KEY>`, `user:<NAME>`) are the file's `[[user_effects]]`
    let catalogue: Vec<String> = changed
        .iter()
        .filter(|e| tofprox_model::catalogue::effect(e).is_some())
        .cloned()
        .collect();
    let updated = update_model_text(&text, m, &catalogue)
        .and_then(|t| user::with_user_effects(&t, m))
        .map_err(|e| LabError::new(e.kind(), format!("model file {}: {e}", from.display())))?;
    tofprox_format::write_atomic(out, updated.as_bytes())
        .map_err(|e| LabError::format(format!("writing model {}", out.display()), e))
}
