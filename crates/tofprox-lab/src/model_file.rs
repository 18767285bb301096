//! A model file's text updated with fitted values: the user's comments,
//! order and other tables kept.
use tofprox_model::ModelConfig;

use crate::error::{ErrorKind, LabError};

/// The model file's text with the `enabled` flag and the parameters of the
/// effects `ids` set to `m`'s values, and of every other effect whose values
/// in `m` differ from the file's (an effect's fit may measure a neighbour's
/// parameter: the SBI fit the ambient responsivity); everything else —
/// comments, order, other tables — is kept as the user wrote it.
pub fn update_model_text(
    original: &str,
    m: &ModelConfig,
    ids: &[String],
) -> Result<String, LabError> {
    use toml_edit::{DocumentMut, Item, Value};
    let bad = |why: String| LabError::new(ErrorKind::InvalidModel, why);
    let before = ModelConfig::from_toml_str(original).ok();
    let differs = |id: &str| {
        before.as_ref().is_some_and(|b| {
            b.effect(id).map(|e| e.enabled) != m.effect(id).map(|e| e.enabled)
                || tofprox_model::catalogue::effect(id).is_some_and(|info| {
                    info.params
                        .iter()
                        .any(|p| b.param(id, p.name) != m.param(id, p.name))
                })
        })
    };
    let mut ids: Vec<&str> = ids.iter().map(String::as_str).collect();
    for info in tofprox_model::catalogue() {
        if !ids.contains(&info.id) && differs(info.id) {
            ids.push(info.id);
        }
    }
    let mut doc: DocumentMut = original
        .parse()
        .map_err(|e| bad(format!("model file is not valid TOML: {e}")))?;
    let effects = doc
        .entry("effects")
        .or_insert(toml_edit::table())
        .as_table_mut()
        .ok_or_else(|| bad("`effects` in the model file is not a table".into()))?;
    effects.set_implicit(true);
    // a new value keeps the old one's surrounding whitespace and comment
    let set = |t: &mut toml_edit::Table, key: &str, v: Value| match t.get_mut(key) {
        Some(Item::Value(old)) => {
            let decor = old.decor().clone();
            *old = v;
            *old.decor_mut() = decor;
        }
        _ => {
            t.insert(key, Item::Value(v));
        }
    };
    for id in ids {
        let info = tofprox_model::catalogue::effect(id).ok_or_else(|| {
            LabError::new(ErrorKind::UnknownEffect, format!("unknown effect `{id}`"))
        })?;
        let t = effects
            .entry(id)
            .or_insert(toml_edit::table())
            .as_table_mut()
            .ok_or_else(|| bad(format!("`effects.{id}` in the model file is not a table")))?;
        set(
            t,
            "enabled",
            Value::from(m.effect(id).is_some_and(|e| e.enabled)),
        );
        for p in info.params {
            if let Some(v) = m.param(id, p.name) {
                set(t, p.name, Value::from(v));
            }
        }
    }
    Ok(doc.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tofprox_model::ids;

    #[test]
    fn update_keeps_comments_and_sets_fitted_values() {
        let text = "# my sensor\ndescription = \"bench unit 3\"\n\n[effects.vcsel_droop]\n\
                    enabled = false  # off until measured\ndroop_rel = 0.03\n";
        let mut m = ModelConfig::from_toml_str(text).unwrap();
        m.enable(ids::vcsel_droop::ID, true).unwrap();
        m.set(ids::vcsel_droop::DROOP_REL, 0.071).unwrap();
        m.enable(ids::adc_inl::ID, true).unwrap();
        m.set(ids::adc_inl::INL_LSB, -3.5).unwrap();
        let out = update_model_text(
            text,
            &m,
            &[
                ids::vcsel_droop::ID.as_str().into(),
                ids::adc_inl::ID.as_str().into(),
            ],
        )
        .unwrap();
        assert!(out.starts_with("# my sensor\n"), "{out}");
        assert!(
            out.contains("enabled = true  # off until measured"),
            "{out}"
        );
        let back = ModelConfig::from_toml_str(&out).unwrap();
        assert_eq!(back.get(ids::vcsel_droop::DROOP_REL), 0.071);
        assert!(back.is_enabled(ids::vcsel_droop::ID) && back.is_enabled(ids::adc_inl::ID));
        assert_eq!(back.get(ids::adc_inl::INL_LSB), -3.5);
        assert!(update_model_text("[effects", &m, &[]).is_err());
    }
}
