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
            b.effect(id).map(|e| (e.enabled, &e.shape))
                != m.effect(id).map(|e| (e.enabled, &e.shape))
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
        write_shape_keys(t, id, m.effect(id).and_then(|e| e.shape.as_ref()), &set);
    }
    Ok(doc.to_string())
}

/// The shape form's keys of `[effects.<id>]`: its knots and curves when
/// `shape` is given, none of them when not (the parametric form).
fn write_shape_keys(
    t: &mut toml_edit::Table,
    id: &str,
    shape: Option<&tofprox_model::effects::shape::EffectShape>,
    set: &dyn Fn(&mut toml_edit::Table, &str, toml_edit::Value),
) {
    let Some(law) = tofprox_model::effects::shape::shape_law(id) else {
        return;
    };
    let array = |v: &[f64]| toml_edit::Value::Array(v.iter().copied().collect());
    match shape {
        Some(sh) => {
            set(t, law.driver, array(&sh.knots));
            for c in law.curves {
                match sh.curves.iter().find(|(k, _)| k == c) {
                    Some((_, v)) => set(t, c, array(v)),
                    None => {
                        t.remove(c);
                    }
                }
            }
        }
        None => {
            for k in std::iter::once(law.driver).chain(law.curves.iter().copied()) {
                t.remove(k);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tofprox_model::effects;

    #[test]
    fn update_keeps_comments_and_sets_fitted_values() {
        let text = "# my sensor\ndescription = \"bench unit 3\"\n\n[effects.vcsel_droop]\n\
                    enabled = false  # off until measured\ndroop_rel = 0.03\n";
        let mut m = ModelConfig::from_toml_str(text).unwrap();
        m.enable(effects::vcsel_droop::ID, true).unwrap();
        m.set(effects::vcsel_droop::DROOP_REL, 0.071).unwrap();
        m.enable(effects::adc_inl::ID, true).unwrap();
        m.set(effects::adc_inl::INL_LSB, -3.5).unwrap();
        let out = update_model_text(
            text,
            &m,
            &[
                effects::vcsel_droop::ID.as_str().into(),
                effects::adc_inl::ID.as_str().into(),
            ],
        )
        .unwrap();
        assert!(out.starts_with("# my sensor\n"), "{out}");
        assert!(
            out.contains("enabled = true  # off until measured"),
            "{out}"
        );
        let back = ModelConfig::from_toml_str(&out).unwrap();
        assert_eq!(back.get(effects::vcsel_droop::DROOP_REL), 0.071);
        assert!(back.is_enabled(effects::vcsel_droop::ID) && back.is_enabled(effects::adc_inl::ID));
        assert_eq!(back.get(effects::adc_inl::INL_LSB), -3.5);
        assert!(update_model_text("[effects", &m, &[]).is_err());
    }

    #[test]
    fn update_writes_the_chosen_form_only() {
        use tofprox_model::effects::shape::EffectShape;
        use tofprox_model::effects::temperature_drift::DRIFT_PHASE_RAD;
        let id = effects::temperature_drift::ID;
        let text = "[effects.temperature_drift]\nenabled = true  # measured\n\
                    phase_mrad_per_k = 2.0\n";
        let mut m = ModelConfig::from_toml_str(text).unwrap();
        let shape = EffectShape {
            knots: vec![10.0, 25.0, 45.0],
            curves: vec![(DRIFT_PHASE_RAD, vec![-0.1, 0.0, 0.3])],
        };
        m.set_shape(id, Some(shape.clone())).unwrap();
        let out = update_model_text(text, &m, &[id.as_str().into()]).unwrap();
        assert!(out.contains("enabled = true  # measured"), "{out}");
        let back = ModelConfig::from_toml_str(&out).unwrap();
        assert_eq!(back.shape(id), Some(&shape));
        // back to the parametric form: the shape's keys go
        let mut p = back.clone();
        p.set_shape(id, None).unwrap();
        let out2 = update_model_text(&out, &p, &[id.as_str().into()]).unwrap();
        assert!(!out2.contains("shape_"), "{out2}");
        assert_eq!(ModelConfig::from_toml_str(&out2).unwrap().shape(id), None);
        // a shape the model refuses is never set
        let bad = EffectShape {
            knots: vec![10.0, 25.0],
            curves: vec![(DRIFT_PHASE_RAD, vec![0.0])],
        };
        assert!(m.set_shape(id, Some(bad)).is_err());
    }
}
