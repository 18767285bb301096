//! Model files: one `[effects.<id>]` table per catalogue effect with `enabled` and
//! its parameters, plus the always-on `[sensor]` constants. Everything is validated
//! against the catalogue: unknown ids/parameters and values outside the physical
//! range are errors naming the key and the allowed range.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::catalogue::{self, ParamInfo, SENSOR_PARAMS, SENSOR_SECTION};
use crate::effects::shape::{self, EffectShape, ShapeLaw};
use crate::effects::user::{self, UserEffect};
use crate::effects::waveform_harmonics;
use crate::error::{ErrorKind, ModelError};
use crate::ids::{EffectId, ParamId};
use tofprox_core::camera::Intrinsics;

/// The model file's lens section: intrinsics in full-array pixels and OpenCV distortion.
pub const CAMERA_SECTION: &str = "camera";

/// Settings of one effect.
#[derive(Debug, Clone, PartialEq)]
pub struct EffectSettings {
    /// Whether the effect is part of the model.
    pub enabled: bool,
    /// Parameter values by name (every catalogue parameter is present).
    pub params: BTreeMap<&'static str, f64>,
    /// The law as a monotone shape instead of its parametric form (effects
    /// with a [`crate::effects::shape::ShapeLaw`] only; validated).
    pub shape: Option<EffectShape>,
}

/// Measured illumination and modulation waveforms (one period each, equally spaced).
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredWaveforms {
    /// Optical power of the illumination over one period (arbitrary units, ≥ 0).
    pub illumination: Vec<f64>,
    /// Modulation gate signal over one period, 0 = tap B … 1 = tap A.
    pub modulation: Vec<f64>,
    /// Where the illumination was loaded from (kept for `to_toml_string`).
    pub illumination_file: Option<PathBuf>,
    /// Where the modulation was loaded from.
    pub modulation_file: Option<PathBuf>,
}

/// A complete, validated model: which effects are on and their parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelConfig {
    /// Free text description.
    pub description: Option<String>,
    sensor: BTreeMap<&'static str, f64>,
    effects: BTreeMap<&'static str, EffectSettings>,
    waveforms: Option<MeasuredWaveforms>,
    camera: Option<Intrinsics>,
    user_effects: Vec<UserEffect>,
}

fn typical_params(params: &'static [ParamInfo]) -> BTreeMap<&'static str, f64> {
    params.iter().map(|p| (p.name, p.typical)).collect()
}

fn check_range(section: &str, info: &ParamInfo, v: f64) -> Result<(), ModelError> {
    if !v.is_finite() || v < info.min || v > info.max {
        return Err(ModelError::new(
            ErrorKind::OutOfRange,
            format!(
                "`{section}.{}` = {v} is outside the physical range [{}, {}]{}",
                info.name,
                info.min,
                info.max,
                if info.unit.is_empty() {
                    String::new()
                } else {
                    format!(" {}", info.unit)
                }
            ),
        ));
    }
    Ok(())
}

/// `: did you mean `x`?` for a misspelled parameter name, or nothing.
fn did_you_mean(name: &str, params: &[ParamInfo]) -> String {
    catalogue::closest(name, params.iter().map(|p| p.name))
        .map_or_else(String::new, |p| format!(": did you mean `{p}`?"))
}

fn allowed_names(params: &[ParamInfo]) -> String {
    params.iter().map(|p| p.name).collect::<Vec<_>>().join(", ")
}

fn numbers(key: &str, v: &toml::Value) -> Result<Vec<f64>, ModelError> {
    let arr = v.as_array().ok_or_else(|| {
        ModelError::new(
            ErrorKind::Parse,
            format!("`{key}` must be an array of numbers"),
        )
    })?;
    arr.iter().map(|x| value_as_f64(key, x)).collect()
}

/// The shape form's keys of `[effects.<id>]` (`law`'s driver and curves)
/// from `t`, validated; `None` when the table gives none of them.
fn parse_shape(
    section: &str,
    law: &ShapeLaw,
    t: &toml::Table,
) -> Result<Option<EffectShape>, ModelError> {
    let key = |k: &str| format!("{section}.{k}");
    let knots = t.get(law.driver).map(|v| numbers(&key(law.driver), v));
    let mut curves = Vec::new();
    for c in law.curves {
        if let Some(v) = t.get(*c) {
            curves.push((*c, numbers(&key(c), v)?));
        }
    }
    let knots = match knots {
        Some(k) => k?,
        None if curves.is_empty() => return Ok(None),
        None => {
            return Err(ModelError::new(
                ErrorKind::InvalidInput,
                format!(
                    "`{}`: a shape's values need its knots `{}` ({})",
                    key(curves[0].0),
                    key(law.driver),
                    law.driver_doc
                ),
            ));
        }
    };
    let s = EffectShape { knots, curves };
    s.check(law).map_err(|(k, why)| {
        ModelError::new(ErrorKind::InvalidInput, format!("`{}` {why}", key(&k)))
    })?;
    Ok(Some(s))
}

fn value_as_f64(key: &str, v: &toml::Value) -> Result<f64, ModelError> {
    match v {
        toml::Value::Float(f) => Ok(*f),
        toml::Value::Integer(i) => Ok(*i as f64),
        other => Err(ModelError::new(
            ErrorKind::Parse,
            format!("`{key}` must be a number, found {}", other.type_str()),
        )),
    }
}

impl ModelConfig {
    fn with_all(enabled: impl Fn(&catalogue::EffectInfo) -> bool) -> Self {
        Self {
            description: None,
            sensor: typical_params(SENSOR_PARAMS),
            effects: catalogue::catalogue()
                .iter()
                .map(|e| {
                    (
                        e.id,
                        EffectSettings {
                            enabled: enabled(e),
                            params: typical_params(e.params),
                            shape: None,
                        },
                    )
                })
                .collect(),
            waveforms: None,
            camera: None,
            user_effects: Vec::new(),
        }
    }

    /// Everything a usual calibration covers, typical parameters.
    pub fn baseline() -> Self {
        let mut m = Self::with_all(|e| e.in_baseline);
        m.description = Some("baseline: what a usual calibration covers".into());
        m
    }
    /// Every effect enabled with its typical parameters.
    pub fn full() -> Self {
        let mut m = Self::with_all(|_| true);
        m.description = Some("full: every effect of the catalogue".into());
        m
    }
    /// Every effect disabled: the ideal sinusoidal sensor of eq. 2.2/2.3.
    pub fn ideal() -> Self {
        let mut m = Self::with_all(|_| false);
        m.description = Some("ideal: every effect off".into());
        m
    }

    /// Load and validate a model file; waveform files are resolved relative to it.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let text = tofprox_format::limits::read_text_bounded(
            path,
            tofprox_format::limits::MAX_TOML_BYTES,
        )?;
        let base = path.parent().map(Path::to_path_buf);
        Self::parse(&text, base.as_deref()).map_err(|e| e.with_path(path))
    }

    /// Parse and validate a model from TOML text (waveform files relative to the working directory).
    pub fn from_toml_str(s: &str) -> Result<Self, ModelError> {
        Self::parse(s, None)
    }

    fn parse(s: &str, base: Option<&Path>) -> Result<Self, ModelError> {
        let table: toml::Table = toml::from_str(s)
            .map_err(|e| ModelError::new(ErrorKind::Parse, format!("invalid TOML: {e}")))?;
        // Tables not mentioned keep their defaults: effects disabled, typical parameters.
        let mut m = Self::with_all(|_| false);
        for (key, value) in &table {
            match key.as_str() {
                "description" => match value {
                    toml::Value::String(d) => m.description = Some(d.clone()),
                    _ => {
                        return Err(ModelError::new(
                            ErrorKind::Parse,
                            "`description` must be a string",
                        ));
                    }
                },
                SENSOR_SECTION => {
                    let t = value.as_table().ok_or_else(|| {
                        ModelError::new(ErrorKind::Parse, "`sensor` must be a table")
                    })?;
                    for (name, v) in t {
                        let info =
                            SENSOR_PARAMS
                                .iter()
                                .find(|p| p.name == name)
                                .ok_or_else(|| {
                                    ModelError::new(
                                        ErrorKind::UnknownParam,
                                        format!(
                                            "unknown parameter `sensor.{name}`{} (allowed: {})",
                                            did_you_mean(name, SENSOR_PARAMS),
                                            allowed_names(SENSOR_PARAMS)
                                        ),
                                    )
                                })?;
                        let f = value_as_f64(&format!("sensor.{name}"), v)?;
                        check_range(SENSOR_SECTION, info, f)?;
                        m.sensor.insert(info.name, f);
                    }
                }
                CAMERA_SECTION => {
                    let k: Intrinsics = value
                        .clone()
                        .try_into()
                        .map_err(|e| ModelError::new(ErrorKind::Parse, format!("`camera`: {e}")))?;
                    m.set_camera(Some(k))?;
                }
                "effects" => {
                    let t = value.as_table().ok_or_else(|| {
                        ModelError::new(ErrorKind::Parse, "`effects` must be a table of tables")
                    })?;
                    for (id, v) in t {
                        m.parse_effect(id, v, base)?;
                    }
                }
                user::SECTION => {
                    let a = value.as_array().ok_or_else(|| {
                        ModelError::new(
                            ErrorKind::Parse,
                            "`user_effects` must be an array of tables ([[user_effects]])",
                        )
                    })?;
                    for (i, v) in a.iter().enumerate() {
                        let e = UserEffect::parse(i, v)?;
                        if m.user_effects.iter().any(|o| o.name == e.name) {
                            return Err(ModelError::new(
                                ErrorKind::InvalidInput,
                                format!("`user_effects[{i}]`: the name `{}` is used twice", e.name),
                            ));
                        }
                        m.set_user_effect(e)?;
                    }
                }
                other => {
                    return Err(ModelError::new(
                        ErrorKind::UnknownParam,
                        format!(
                            "unknown top-level key `{other}` (allowed: description, sensor, camera, effects, user_effects)"
                        ),
                    ));
                }
            }
        }
        Ok(m)
    }

    fn parse_effect(
        &mut self,
        id: &str,
        v: &toml::Value,
        base: Option<&Path>,
    ) -> Result<(), ModelError> {
        let info = catalogue::effect(id).ok_or_else(|| unknown_effect(id))?;
        let t = v.as_table().ok_or_else(|| {
            ModelError::new(ErrorKind::Parse, format!("`effects.{id}` must be a table"))
        })?;
        let section = format!("effects.{id}");
        let law = shape::shape_law(info.id);
        if let Some(law) = law {
            let sh = parse_shape(&section, law, t)?;
            if let Some(s) = self.effects.get_mut(info.id) {
                s.shape = sh;
            }
        }
        let mut illum: Option<(Vec<f64>, Option<PathBuf>)> = None;
        let mut modul: Option<(Vec<f64>, Option<PathBuf>)> = None;
        for (name, value) in t {
            if name == "enabled" {
                let b = value.as_bool().ok_or_else(|| {
                    ModelError::new(
                        ErrorKind::Parse,
                        format!("`{section}.enabled` must be true or false"),
                    )
                })?;
                if let Some(s) = self.effects.get_mut(info.id) {
                    s.enabled = b;
                }
                continue;
            }
            if law.is_some_and(|l| shape::is_shape_key(l, name)) {
                continue;
            }
            if info.id == waveform_harmonics::ID.as_str() {
                let key = format!("{section}.{name}");
                match name.as_str() {
                    "illumination_file" | "modulation_file" => {
                        let rel = value.as_str().ok_or_else(|| {
                            ModelError::new(
                                ErrorKind::Parse,
                                format!("`{key}` must be a file path"),
                            )
                        })?;
                        let path = match base {
                            Some(b) if Path::new(rel).is_relative() => b.join(rel),
                            _ => PathBuf::from(rel),
                        };
                        let samples = crate::waveform::load_waveform(&path)
                            .map_err(|e| ModelError::new(e.kind(), format!("`{key}`: {e}")))?;
                        let slot = if name == "illumination_file" {
                            &mut illum
                        } else {
                            &mut modul
                        };
                        *slot = Some((samples, Some(PathBuf::from(rel))));
                        continue;
                    }
                    "illumination" | "modulation" => {
                        let arr = value.as_array().ok_or_else(|| {
                            ModelError::new(
                                ErrorKind::Parse,
                                format!("`{key}` must be an array of numbers"),
                            )
                        })?;
                        let samples = arr
                            .iter()
                            .map(|x| value_as_f64(&key, x))
                            .collect::<Result<Vec<_>, _>>()?;
                        let slot = if name == "illumination" {
                            &mut illum
                        } else {
                            &mut modul
                        };
                        *slot = Some((samples, None));
                        continue;
                    }
                    _ => {}
                }
            }
            let pinfo = info.param(name).ok_or_else(|| {
                let extra = if info.id == waveform_harmonics::ID.as_str() {
                    ", illumination_file, modulation_file, illumination, modulation".to_string()
                } else if let Some(l) = law {
                    format!(", {}, {}", l.driver, l.curves.join(", "))
                } else {
                    String::new()
                };
                ModelError::new(
                    ErrorKind::UnknownParam,
                    format!(
                        "unknown parameter `{section}.{name}`{} (allowed: enabled, {}{extra})",
                        did_you_mean(name, info.params),
                        allowed_names(info.params)
                    ),
                )
            })?;
            let f = value_as_f64(&format!("{section}.{name}"), value)?;
            check_range(&section, pinfo, f)?;
            if let Some(s) = self.effects.get_mut(info.id) {
                s.params.insert(pinfo.name, f);
            }
        }
        match (illum, modul) {
            (None, None) => {}
            (Some((i, ip)), Some((m, mp))) => {
                crate::waveform::validate_waveforms(&i, &m)
                    .map_err(|e| ModelError::new(e.kind(), format!("`{section}`: {e}")))?;
                self.waveforms = Some(MeasuredWaveforms {
                    illumination: i,
                    modulation: m,
                    illumination_file: ip,
                    modulation_file: mp,
                });
            }
            _ => {
                return Err(ModelError::new(
                    ErrorKind::InvalidInput,
                    format!(
                        "`{section}`: measured waveforms need both an illumination and a modulation waveform"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The lens (`[camera]`): with it, a flat wall's `distance_m` is its perpendicular distance
    /// and each pixel sees it along its own ray (`d / cos θ`) with the lens's natural vignetting;
    /// without it every pixel sees the scene's distance as its radial distance (no lens geometry,
    /// as model files without `[camera]` always did).
    pub fn camera(&self) -> Option<&Intrinsics> {
        self.camera.as_ref()
    }

    /// Sets or removes the lens (validated: finite values, positive focal lengths).
    pub fn set_camera(&mut self, camera: Option<Intrinsics>) -> Result<(), ModelError> {
        if let Some(k) = &camera {
            k.validate()
                .map_err(|e| ModelError::new(ErrorKind::OutOfRange, format!("`camera`: {e}")))?;
        }
        self.camera = camera;
        Ok(())
    }

    /// Serialise to a model file that parses back to the same model.
    pub fn to_toml_string(&self) -> String {
        let mut out = String::new();
        if let Some(d) = &self.description {
            let _ = writeln!(out, "description = {}", toml::Value::String(d.clone()));
            out.push('\n');
        }
        if let Some(k) = &self.camera {
            let d = &k.distortion;
            let _ = writeln!(out, "[{CAMERA_SECTION}]");
            for (name, v) in [
                ("fx_px", k.fx_px),
                ("fy_px", k.fy_px),
                ("cx_px", k.cx_px),
                ("cy_px", k.cy_px),
            ] {
                let _ = writeln!(out, "{name} = {v:?}");
            }
            let _ = writeln!(out, "\n[{CAMERA_SECTION}.distortion]");
            for (name, v) in [
                ("k1", d.k1),
                ("k2", d.k2),
                ("k3", d.k3),
                ("p1", d.p1),
                ("p2", d.p2),
            ] {
                let _ = writeln!(out, "{name} = {v:?}");
            }
            out.push('\n');
        }
        let _ = writeln!(out, "[sensor]");
        for p in SENSOR_PARAMS {
            let v = self.sensor.get(p.name).copied().unwrap_or(p.typical);
            let _ = writeln!(out, "{} = {:?}  # {}", p.name, v, p.unit);
        }
        for e in catalogue::catalogue() {
            let Some(s) = self.effects.get(e.id) else {
                continue;
            };
            let _ = writeln!(
                out,
                "\n# {} ({})\n[effects.{}]",
                e.title, e.thesis_ref, e.id
            );
            let _ = writeln!(out, "enabled = {}", s.enabled);
            for p in e.params {
                let v = s.params.get(p.name).copied().unwrap_or(p.typical);
                // dimensionless ("" or "1") parameters carry no unit comment
                let unit = if p.unit.is_empty() || p.unit == "1" {
                    String::new()
                } else {
                    format!("  # {}", p.unit)
                };
                let _ = writeln!(out, "{} = {:?}{unit}", p.name, v);
            }
            if let (Some(sh), Some(law)) = (&s.shape, shape::shape_law(e.id)) {
                let _ = writeln!(out, "# the law as a monotone shape of {}", law.driver_doc);
                let _ = writeln!(out, "{} = {:?}", law.driver, sh.knots);
                for (k, v) in &sh.curves {
                    let _ = writeln!(out, "{k} = {v:?}");
                }
            }
            if let (true, Some(w)) = (e.id == waveform_harmonics::ID.as_str(), &self.waveforms) {
                write_wave(
                    &mut out,
                    "illumination",
                    &w.illumination,
                    w.illumination_file.as_deref(),
                );
                write_wave(
                    &mut out,
                    "modulation",
                    &w.modulation,
                    w.modulation_file.as_deref(),
                );
            }
        }
        for u in &self.user_effects {
            out.push('\n');
            out.push_str(&u.to_toml());
        }
        out
    }

    /// The user effects (`[[user_effects]]`, [`crate::effects::user`]), in file order.
    pub fn user_effects(&self) -> &[UserEffect] {
        &self.user_effects
    }

    /// Add `e`, or replace the user effect of its name; refused when its name
    /// is a catalogue effect id or another user effect has a different name
    /// for the same condition and quantity (one response per pair).
    pub fn set_user_effect(&mut self, e: UserEffect) -> Result<(), ModelError> {
        if catalogue::effect(&e.name).is_some() {
            return Err(ModelError::new(
                ErrorKind::InvalidInput,
                format!(
                    "user effect `{}`: the name is a catalogue effect id",
                    e.name
                ),
            ));
        }
        if let Some(o) = self
            .user_effects
            .iter()
            .find(|o| o.name != e.name && o.condition == e.condition && o.acts_on == e.acts_on)
        {
            return Err(ModelError::new(
                ErrorKind::InvalidInput,
                format!(
                    "user effect `{}`: `{}` already responds to `{}` on the {}",
                    e.name,
                    o.name,
                    e.condition,
                    e.acts_on.as_str()
                ),
            ));
        }
        match self.user_effects.iter_mut().find(|o| o.name == e.name) {
            Some(o) => *o = e,
            None => self.user_effects.push(e),
        }
        Ok(())
    }

    /// Remove the user effect `name` (whether it was there).
    pub fn remove_user_effect(&mut self, name: &str) -> bool {
        let n = self.user_effects.len();
        self.user_effects.retain(|e| e.name != name);
        n != self.user_effects.len()
    }

    /// Whether an effect is enabled.
    pub fn is_enabled(&self, id: EffectId) -> bool {
        self.effects.get(id.as_str()).is_some_and(|s| s.enabled)
    }

    /// Switch an effect on or off.
    pub fn set_enabled(&mut self, id: &str, on: bool) -> Result<(), ModelError> {
        let s = self.effects.get_mut(id).ok_or_else(|| unknown_effect(id))?;
        s.enabled = on;
        Ok(())
    }

    /// A parameter value; `id` is an effect id or `"sensor"`.
    pub fn param(&self, id: &str, name: &str) -> Option<f64> {
        if id == SENSOR_SECTION {
            return self.sensor.get(name).copied();
        }
        self.effects.get(id)?.params.get(name).copied()
    }

    /// Set a parameter (range-checked); `id` is an effect id or `"sensor"`.
    pub fn set_param(&mut self, id: &str, name: &str, v: f64) -> Result<(), ModelError> {
        let (section, params): (String, &'static [ParamInfo]) = if id == SENSOR_SECTION {
            (SENSOR_SECTION.to_string(), SENSOR_PARAMS)
        } else {
            let info = catalogue::effect(id).ok_or_else(|| unknown_effect(id))?;
            (format!("effects.{id}"), info.params)
        };
        let info = params.iter().find(|p| p.name == name).ok_or_else(|| {
            ModelError::new(
                ErrorKind::UnknownParam,
                format!(
                    "unknown parameter `{section}.{name}`{} (allowed: {})",
                    did_you_mean(name, params),
                    allowed_names(params)
                ),
            )
        })?;
        check_range(&section, info, v)?;
        let map = if id == SENSOR_SECTION {
            &mut self.sensor
        } else {
            match self.effects.get_mut(id) {
                Some(s) => &mut s.params,
                None => return Err(unknown_effect(id)),
            }
        };
        map.insert(info.name, v);
        Ok(())
    }

    /// Settings of one effect.
    pub fn effect(&self, id: &str) -> Option<&EffectSettings> {
        self.effects.get(id)
    }

    /// The law of effect `id` as a monotone shape, when the model gives it so.
    pub fn shape(&self, id: EffectId) -> Option<&EffectShape> {
        self.effects.get(id.as_str())?.shape.as_ref()
    }

    /// Give effect `id`'s law as a monotone shape (validated against its
    /// [`ShapeLaw`]), or `None` for its parametric form.
    pub fn set_shape(&mut self, id: EffectId, s: Option<EffectShape>) -> Result<(), ModelError> {
        if let Some(sh) = &s {
            let law = shape::shape_law(id.as_str())
                .ok_or_else(|| ModelError::invalid(format!("`effects.{id}` has no shape form")))?;
            sh.check(law)
                .map_err(|(k, why)| ModelError::invalid(format!("`effects.{id}.{k}` {why}")))?;
        }
        let e = self
            .effects
            .get_mut(id.as_str())
            .ok_or_else(|| unknown_effect(id.as_str()))?;
        e.shape = s;
        Ok(())
    }

    /// Ids of the enabled effects, in catalogue order.
    pub fn enabled_effects(&self) -> Vec<&'static str> {
        catalogue::catalogue()
            .iter()
            .filter(|e| self.effects.get(e.id).is_some_and(|s| s.enabled))
            .map(|e| e.id)
            .collect()
    }

    /// Measured waveforms used by `waveform_harmonics` instead of its harmonic parameters.
    pub fn waveforms(&self) -> Option<&MeasuredWaveforms> {
        self.waveforms.as_ref()
    }

    /// Use measured illumination/modulation waveforms (one period each) for the correlation.
    pub fn set_waveforms(
        &mut self,
        illumination: Vec<f64>,
        modulation: Vec<f64>,
    ) -> Result<(), ModelError> {
        crate::waveform::validate_waveforms(&illumination, &modulation)?;
        self.waveforms = Some(MeasuredWaveforms {
            illumination,
            modulation,
            illumination_file: None,
            modulation_file: None,
        });
        Ok(())
    }

    /// A parameter's value. Every [`ParamId`] names a catalogue parameter (checked by the
    /// tests of [`crate::ids`]) and every catalogue parameter has a value, so this never misses;
    /// were it to, the value is NaN, which no simulation lets pass unnoticed.
    pub fn get(&self, p: ParamId) -> f64 {
        self.param(p.section(), p.name()).unwrap_or(f64::NAN)
    }

    /// Set a parameter by its typed id (range-checked, [`ModelConfig::set_param`]).
    pub fn set(&mut self, p: ParamId, v: f64) -> Result<(), ModelError> {
        self.set_param(p.section(), p.name(), v)
    }

    /// Switch an effect on or off by its typed id.
    pub fn enable(&mut self, id: EffectId, on: bool) -> Result<(), ModelError> {
        self.set_enabled(id.as_str(), on)
    }
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self::baseline()
    }
}

fn write_wave(out: &mut String, name: &str, samples: &[f64], file: Option<&Path>) {
    match file {
        Some(f) => {
            let _ = writeln!(
                out,
                "{name}_file = {}",
                toml::Value::String(f.display().to_string())
            );
        }
        None => {
            let list: Vec<String> = samples.iter().map(|v| format!("{v:?}")).collect();
            let _ = writeln!(out, "{name} = [{}]", list.join(", "));
        }
    }
}

fn unknown_effect(id: &str) -> ModelError {
    let known: Vec<&str> = catalogue::catalogue().iter().map(|e| e.id).collect();
    ModelError::new(
        ErrorKind::UnknownEffect,
        match catalogue::closest(id, known.iter().copied()) {
            Some(near) => format!(
                "unknown effect `effects.{id}`: did you mean `{near}`? (known: {})",
                known.join(", ")
            ),
            None => format!(
                "unknown effect `effects.{id}` (known: {})",
                known.join(", ")
            ),
        },
    )
}
