//! User effects: a law the catalogue lacks, driven by one condition of the
//! recording (issue 33, item 3). Where the lab finds structure against a
//! condition no catalogue effect follows (`vcsel_bias_ma`, `supply_v`, …), a
//! sensor engineer adds a *condition response*: a function f of that condition
//! acting on one quantity of the signal chain,
//!
//! * `phase`: the time-of-flight phase of every pixel, φ + f(x) (rad) — a delay
//!   of the illumination or the demodulation (thesis 2.2.2, eq. 2.6: a phase
//!   shift Δφ reads as a depth Δd = c·Δφ/(4π f));
//! * `gain`: the signal charge, N·(1 + f(x)) (relative) — the optical power or
//!   the responsivity (thesis 2.2.1);
//! * `offset`: the differential code at the ADC input, u + f(x) (LSB) — a
//!   shift of the read-out (thesis 3.3.7.1).
//!
//! The law has one of two forms:
//! * a **shape**: the model's monotone piecewise-linear curve through
//!   `knots_x` (the condition's unit) and `knots_y` (the quantity's unit),
//!   flat outside the knots ([`crate::effects::shape`]: one evaluation shared
//!   with the catalogue's shape forms) — what `tofprox lab add condition:<KEY>`
//!   fits and writes;
//! * an **expression** of the condition (by its key), the capture's
//!   [`QUANTITIES`] and the effect's own named parameters (start value and
//!   range), parsed once when the model file is read (the `evalexpr` crate:
//!   a maintained evaluator with the usual operators, `^` for powers and
//!   `math::exp`, `math::ln`, `math::tanh`, … — an unknown variable is refused
//!   at load time, not at the first capture). The lab fits the parameters.
//!
//! A capture that does not state the condition gets no response (the
//! condition's reference). In a model file:
//!
//! ```toml
//! [[user_effects]]
//! name = "vcsel_bias_ma_phase"
//! condition = "vcsel_bias_ma"
//! acts_on = "phase"
//! knots_x = [10.0, 20.0, 30.0]
//! knots_y = [0.0, 0.012, 0.018]
//! provenance = { recording = "rec/", date = "2026-12-02", chi2_per_dof_before = 9.1, chi2_per_dof_after = 1.01 }
//! ```
use std::collections::BTreeMap;
use std::fmt::Write as _;

use evalexpr::{ContextWithMutableVariables, DefaultNumericTypes, HashMapContext, Node, Value};
use serde::Serialize;

use crate::effects::shape;
use crate::error::{ErrorKind, ModelError};

/// The model file's key of the user effects (an array of tables).
pub const SECTION: &str = "user_effects";

/// The capture's quantities an expression may read besides its condition and
/// parameters (the names a `CaptureRequest` gives them).
pub const QUANTITIES: &[&str] = &["exposure_us", "temperature_c", "ambient_klux"];

/// Where a user effect acts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum UserActsOn {
    /// The time-of-flight phase of every pixel (rad).
    Phase,
    /// The signal charge, relative (N·(1 + f)).
    Gain,
    /// The differential code at the ADC input (LSB).
    Offset,
}

impl UserActsOn {
    /// Every value, in the order the lab reports them.
    pub const ALL: [Self; 3] = [Self::Offset, Self::Gain, Self::Phase];

    /// The model file's spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Phase => "phase",
            Self::Gain => "gain",
            Self::Offset => "offset",
        }
    }
    /// The unit of the response (`knots_y`).
    pub fn unit(self) -> &'static str {
        match self {
            Self::Phase => "rad",
            Self::Gain => "relative",
            Self::Offset => "LSB",
        }
    }
    /// The value spelt `s`, if any.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|a| a.as_str() == s)
    }
}

/// A named free parameter of an expression law: its value (the start of a
/// fit, the fitted value after one) and its range.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct UserParam {
    /// The variable's name in the expression.
    pub name: String,
    /// Its value.
    pub value: f64,
    /// Lowest value a fit may give it.
    pub min: f64,
    /// Highest value a fit may give it.
    pub max: f64,
}

/// An expression parsed once (its text kept for the file and comparisons).
#[derive(Debug, Clone)]
pub struct Expression {
    text: String,
    node: Node<DefaultNumericTypes>,
}

impl PartialEq for Expression {
    fn eq(&self, other: &Self) -> bool {
        self.text == other.text
    }
}

impl Serialize for Expression {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.text)
    }
}

impl Expression {
    /// Parse `text`; every variable must be one of `allowed`.
    pub fn parse(text: &str, allowed: &[&str]) -> Result<Self, String> {
        let node = evalexpr::build_operator_tree::<DefaultNumericTypes>(text)
            .map_err(|e| format!("cannot parse `{text}`: {e}"))?;
        for v in node.iter_variable_identifiers() {
            if !allowed.contains(&v) {
                return Err(format!(
                    "unknown variable `{v}` in `{text}` (allowed: {})",
                    allowed.join(", ")
                ));
            }
        }
        Ok(Self {
            text: text.to_string(),
            node,
        })
    }
    /// The expression as written.
    pub fn text(&self) -> &str {
        &self.text
    }
    /// Its value with the variables `vars` (name, value).
    pub fn eval(&self, vars: &[(&str, f64)]) -> Result<f64, String> {
        let mut ctx = HashMapContext::<DefaultNumericTypes>::new();
        for (k, v) in vars {
            ctx.set_value((*k).to_string(), Value::Float(*v))
                .map_err(|e| format!("`{}`: {e}", self.text))?;
        }
        match self.node.eval_with_context(&ctx) {
            Ok(Value::Float(f)) => Ok(f),
            Ok(Value::Int(i)) => Ok(i as f64),
            Ok(v) => Err(format!("`{}` gives {v}, not a number", self.text)),
            Err(e) => Err(format!("`{}`: {e}", self.text)),
        }
    }
}

/// The law of a user effect.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "form", rename_all = "lowercase")]
pub enum UserLaw {
    /// The monotone piecewise-linear curve through the knots, flat outside.
    Shape {
        /// The condition's values (its unit), strictly increasing.
        knots_x: Vec<f64>,
        /// The response at each knot (the quantity's unit), monotone.
        knots_y: Vec<f64>,
    },
    /// An expression of the condition, the [`QUANTITIES`] and `params`.
    Expression {
        /// The parsed expression.
        expression: Expression,
        /// Its free parameters.
        params: Vec<UserParam>,
    },
}

/// Where a fitted user effect came from.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Provenance {
    /// The recording it was fitted on.
    pub recording: String,
    /// The day of the fit (UTC, YYYY-MM-DD).
    pub date: String,
    /// χ²/dof of the model without it on that recording.
    pub chi2_per_dof_before: f64,
    /// χ²/dof with it.
    pub chi2_per_dof_after: f64,
}

/// One user effect of a model file.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct UserEffect {
    /// Its name (unique in the file, not a catalogue id).
    pub name: String,
    /// The recording condition driving it (a `[capture.conditions]` key or one
    /// of [`QUANTITIES`]).
    pub condition: String,
    /// Where it acts.
    pub acts_on: UserActsOn,
    /// Its law.
    pub law: UserLaw,
    /// Where it was fitted, if it was.
    pub provenance: Option<Provenance>,
}

/// A capture's quantities an expression reads ([`QUANTITIES`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureQuantities {
    /// Exposure time.
    pub exposure_us: f64,
    /// Sensor temperature.
    pub temperature_c: f64,
    /// Background illuminance.
    pub ambient_klux: f64,
}

impl CaptureQuantities {
    /// The quantity named `key` ([`QUANTITIES`]), if it is one.
    pub fn get(&self, key: &str) -> Option<f64> {
        match key {
            "exposure_us" => Some(self.exposure_us),
            "temperature_c" => Some(self.temperature_c),
            "ambient_klux" => Some(self.ambient_klux),
            _ => None,
        }
    }
}

/// Whether `s` is a lower-case identifier (`[a-z_][a-z0-9_]*`).
pub fn is_identifier(s: &str) -> bool {
    let mut c = s.chars();
    c.next().is_some_and(|f| f.is_ascii_lowercase() || f == '_')
        && c.all(|x| x.is_ascii_lowercase() || x.is_ascii_digit() || x == '_')
}

fn bad(at: &str, why: impl std::fmt::Display) -> ModelError {
    ModelError::new(ErrorKind::Parse, format!("`{at}`: {why}"))
}

fn num(at: &str, v: Option<&toml::Value>) -> Result<f64, ModelError> {
    match v {
        Some(toml::Value::Float(f)) => Ok(*f),
        Some(toml::Value::Integer(i)) => Ok(*i as f64),
        Some(_) => Err(bad(at, "must be a number")),
        None => Err(bad(at, "missing")),
    }
}

fn text<'a>(at: &str, t: &'a toml::Table, key: &str) -> Result<&'a str, ModelError> {
    t.get(key)
        .ok_or_else(|| bad(&format!("{at}.{key}"), "missing"))?
        .as_str()
        .ok_or_else(|| bad(&format!("{at}.{key}"), "must be a string"))
}

fn numbers(at: &str, v: &toml::Value) -> Result<Vec<f64>, ModelError> {
    let a = v.as_array().ok_or_else(|| bad(at, "must be an array"))?;
    a.iter().map(|x| num(at, Some(x))).collect()
}

fn only_keys(at: &str, t: &toml::Table, allowed: &[&str]) -> Result<(), ModelError> {
    match t.keys().find(|k| !allowed.contains(&k.as_str())) {
        Some(k) => Err(ModelError::new(
            ErrorKind::UnknownParam,
            format!("unknown key `{at}.{k}` (allowed: {})", allowed.join(", ")),
        )),
        None => Ok(()),
    }
}

fn parse_param(at: &str, v: &toml::Value) -> Result<UserParam, ModelError> {
    let t = v.as_table().ok_or_else(|| bad(at, "must be a table"))?;
    only_keys(at, t, &["name", "value", "min", "max"])?;
    let name = text(at, t, "name")?.to_string();
    if !is_identifier(&name) {
        return Err(bad(
            &format!("{at}.name"),
            "must be a lower-case identifier",
        ));
    }
    let p = UserParam {
        value: num(&format!("{at}.value"), t.get("value"))?,
        min: num(&format!("{at}.min"), t.get("min"))?,
        max: num(&format!("{at}.max"), t.get("max"))?,
        name,
    };
    if !(p.min.is_finite() && p.max.is_finite() && p.min <= p.value && p.value <= p.max) {
        return Err(ModelError::new(
            ErrorKind::OutOfRange,
            format!(
                "`{at}`: value {} outside its range [{}, {}] (finite, min ≤ value ≤ max)",
                p.value, p.min, p.max
            ),
        ));
    }
    Ok(p)
}

fn parse_provenance(at: &str, v: &toml::Value) -> Result<Provenance, ModelError> {
    let t = v.as_table().ok_or_else(|| bad(at, "must be a table"))?;
    let keys = [
        "recording",
        "date",
        "chi2_per_dof_before",
        "chi2_per_dof_after",
    ];
    only_keys(at, t, &keys)?;
    Ok(Provenance {
        recording: text(at, t, "recording")?.to_string(),
        date: text(at, t, "date")?.to_string(),
        chi2_per_dof_before: num(&format!("{at}.{}", keys[2]), t.get(keys[2]))?,
        chi2_per_dof_after: num(&format!("{at}.{}", keys[3]), t.get(keys[3]))?,
    })
}

fn parse_law(at: &str, t: &toml::Table, condition: &str) -> Result<UserLaw, ModelError> {
    match (t.get("expression"), t.get("knots_x"), t.get("knots_y")) {
        (None, Some(x), Some(y)) => {
            let knots_x = numbers(&format!("{at}.knots_x"), x)?;
            let knots_y = numbers(&format!("{at}.knots_y"), y)?;
            shape::check_knots(&knots_x).map_err(|e| bad(&format!("{at}.knots_x"), e))?;
            shape::check_values(&knots_y, knots_x.len())
                .map_err(|e| bad(&format!("{at}.knots_y"), e))?;
            Ok(UserLaw::Shape { knots_x, knots_y })
        }
        (Some(e), None, None) => {
            let params = match t.get("params") {
                Some(toml::Value::Array(a)) => a
                    .iter()
                    .enumerate()
                    .map(|(i, p)| parse_param(&format!("{at}.params[{i}]"), p))
                    .collect::<Result<Vec<_>, _>>()?,
                Some(_) => return Err(bad(&format!("{at}.params"), "must be an array of tables")),
                None => Vec::new(),
            };
            let mut allowed: Vec<&str> = vec![condition];
            allowed.extend(QUANTITIES.iter().filter(|q| **q != condition));
            for p in &params {
                if allowed.contains(&p.name.as_str()) {
                    return Err(bad(
                        &format!("{at}.params"),
                        format!("`{}` named twice", p.name),
                    ));
                }
                allowed.push(&p.name);
            }
            let s = e
                .as_str()
                .ok_or_else(|| bad(&format!("{at}.expression"), "must be a string"))?;
            let expression =
                Expression::parse(s, &allowed).map_err(|e| bad(&format!("{at}.expression"), e))?;
            Ok(UserLaw::Expression { expression, params })
        }
        _ => Err(bad(
            at,
            "give either `knots_x` and `knots_y` (a shape) or `expression` (with `params`)",
        )),
    }
}

impl UserEffect {
    /// The `index`-th `[[user_effects]]` table of a model file, validated.
    pub fn parse(index: usize, v: &toml::Value) -> Result<Self, ModelError> {
        let at = format!("{SECTION}[{index}]");
        let t = v.as_table().ok_or_else(|| bad(&at, "must be a table"))?;
        let keys = [
            "name",
            "condition",
            "acts_on",
            "knots_x",
            "knots_y",
            "expression",
            "params",
            "provenance",
        ];
        only_keys(&at, t, &keys)?;
        let name = text(&at, t, "name")?.to_string();
        if !is_identifier(&name) || crate::ids::EffectId::parse(&name).is_some() {
            return Err(bad(
                &format!("{at}.name"),
                format!("`{name}` must be a lower-case identifier and not a catalogue effect id"),
            ));
        }
        let condition = text(&at, t, "condition")?.to_string();
        if !is_identifier(&condition) {
            return Err(bad(
                &format!("{at}.condition"),
                "must be a recording condition key (a lower-case identifier)",
            ));
        }
        let acts = text(&at, t, "acts_on")?;
        let acts_on = UserActsOn::parse(acts).ok_or_else(|| {
            bad(
                &format!("{at}.acts_on"),
                format!("`{acts}` is not one of phase, gain, offset"),
            )
        })?;
        let law = parse_law(&at, t, &condition)?;
        let provenance = t
            .get("provenance")
            .map(|p| parse_provenance(&format!("{at}.provenance"), p))
            .transpose()?;
        Ok(Self {
            name,
            condition,
            acts_on,
            law,
            provenance,
        })
    }

    /// The effect as a `[[user_effects]]` table of a model file (parses back
    /// to the same effect).
    pub fn to_toml(&self) -> String {
        let mut out = format!(
            "[[{SECTION}]]\n# a response to `{}` acting on the {} ({})\nname = {:?}\ncondition = {:?}\nacts_on = {:?}\n",
            self.condition,
            self.acts_on.as_str(),
            self.acts_on.unit(),
            self.name,
            self.condition,
            self.acts_on.as_str()
        );
        match &self.law {
            UserLaw::Shape { knots_x, knots_y } => {
                let _ = writeln!(out, "knots_x = {knots_x:?}\nknots_y = {knots_y:?}");
            }
            UserLaw::Expression { expression, params } => {
                let _ = writeln!(out, "expression = {}", toml::Value::from(expression.text()));
                let _ = writeln!(out, "params = [");
                for p in params {
                    let _ = writeln!(
                        out,
                        "  {{ name = {:?}, value = {:?}, min = {:?}, max = {:?} }},",
                        p.name, p.value, p.min, p.max
                    );
                }
                out.push_str("]\n");
            }
        }
        if let Some(p) = &self.provenance {
            let _ = writeln!(
                out,
                "provenance = {{ recording = {}, date = {:?}, chi2_per_dof_before = {:?}, chi2_per_dof_after = {:?} }}",
                toml::Value::from(p.recording.as_str()),
                p.date,
                p.chi2_per_dof_before,
                p.chi2_per_dof_after
            );
        }
        out
    }

    /// The condition's value in a capture: one of its [`QUANTITIES`] or its
    /// `conditions` (None when the capture does not state it).
    pub fn condition_value(
        &self,
        conditions: &BTreeMap<String, f64>,
        q: &CaptureQuantities,
    ) -> Option<f64> {
        q.get(&self.condition)
            .or_else(|| conditions.get(&self.condition).copied())
    }

    /// The expression's parameter values (none for a shape).
    pub fn param_values(&self) -> Vec<f64> {
        match &self.law {
            UserLaw::Shape { .. } => Vec::new(),
            UserLaw::Expression { params, .. } => params.iter().map(|p| p.value).collect(),
        }
    }

    /// The response at condition value `x` (the [`UserActsOn::unit`]) with the
    /// file's own values.
    pub fn response(&self, x: f64, q: &CaptureQuantities) -> Result<f64, ModelError> {
        self.response_with(&self.param_values(), x, q)
    }

    /// The response at `x` with the expression's parameters at `values` (in
    /// the order of its `params`; ignored by a shape): what the lab fits.
    pub fn response_with(
        &self,
        values: &[f64],
        x: f64,
        q: &CaptureQuantities,
    ) -> Result<f64, ModelError> {
        match &self.law {
            UserLaw::Shape { knots_x, knots_y } => Ok(shape::eval(knots_x, knots_y, x)),
            UserLaw::Expression { expression, params } => {
                let mut vars: Vec<(&str, f64)> = vec![(self.condition.as_str(), x)];
                for k in QUANTITIES.iter().filter(|k| **k != self.condition) {
                    vars.push((k, q.get(k).unwrap_or(0.0)));
                }
                vars.extend(
                    params
                        .iter()
                        .zip(values)
                        .map(|(p, v)| (p.name.as_str(), *v)),
                );
                let v = expression.eval(&vars).map_err(|e| {
                    ModelError::new(
                        ErrorKind::InvalidInput,
                        format!("user effect `{}`: {e}", self.name),
                    )
                })?;
                if v.is_finite() {
                    Ok(v)
                } else {
                    Err(ModelError::new(
                        ErrorKind::OutOfRange,
                        format!(
                            "user effect `{}`: `{}` is {v} at {} = {x}",
                            self.name,
                            expression.text(),
                            self.condition
                        ),
                    ))
                }
            }
        }
    }
}

/// The user effects' response in one capture, by where they act.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UserResponse {
    /// Phase added to every pixel (rad).
    pub phase_rad: f64,
    /// Factor on the signal charge: Π (1 + f) of the gain effects.
    pub gain_factor: f64,
    /// Code added at the ADC input (LSB).
    pub offset_lsb: f64,
}

impl Default for UserResponse {
    fn default() -> Self {
        Self {
            phase_rad: 0.0,
            gain_factor: 1.0,
            offset_lsb: 0.0,
        }
    }
}

/// The response of `effects` in a capture with `conditions` and quantities `q`
/// (an effect whose condition the capture does not state contributes none).
pub fn capture_response(
    effects: &[UserEffect],
    conditions: &BTreeMap<String, f64>,
    q: &CaptureQuantities,
) -> Result<UserResponse, ModelError> {
    let mut r = UserResponse::default();
    for e in effects {
        let Some(x) = e.condition_value(conditions, q) else {
            continue;
        };
        let v = e.response(x, q)?;
        match e.acts_on {
            UserActsOn::Phase => r.phase_rad += v,
            UserActsOn::Gain => r.gain_factor *= (1.0 + v).max(0.0),
            UserActsOn::Offset => r.offset_lsb += v,
        }
    }
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Result<UserEffect, ModelError> {
        let t: toml::Table = toml::from_str(s).unwrap();
        UserEffect::parse(0, &toml::Value::Table(t))
    }

    const Q: CaptureQuantities = CaptureQuantities {
        exposure_us: 500.0,
        temperature_c: 30.0,
        ambient_klux: 0.0,
    };

    #[test]
    fn a_shape_round_trips_and_interpolates() {
        let e = parse(
            "name = \"bias_phase\"\ncondition = \"vcsel_bias_ma\"\nacts_on = \"phase\"\nknots_x = [10, 20, 30]\nknots_y = [0.0, 0.01, 0.015]\nprovenance = { recording = \"r\", date = \"2026-12-02\", chi2_per_dof_before = 9.5, chi2_per_dof_after = 1.01 }",
        )
        .unwrap();
        assert!((e.response(15.0, &Q).unwrap() - 0.005).abs() < 1e-12);
        assert_eq!(e.response(40.0, &Q).unwrap(), 0.015);
        let t: toml::Table = toml::from_str(&e.to_toml()).unwrap();
        let back = UserEffect::parse(0, &t[SECTION].as_array().unwrap()[0]).unwrap();
        assert_eq!(back, e);
    }

    #[test]
    fn an_expression_reads_its_condition_quantities_and_parameters() {
        let e = parse(
            "name = \"bias_gain\"\ncondition = \"vcsel_bias_ma\"\nacts_on = \"gain\"\nexpression = \"k * (vcsel_bias_ma - 20.0)^2 + 0.0 * exposure_us\"\nparams = [{ name = \"k\", value = 0.001, min = -1, max = 1 }]",
        )
        .unwrap();
        assert!((e.response(25.0, &Q).unwrap() - 0.025).abs() < 1e-12);
        assert!((e.response_with(&[0.002], 25.0, &Q).unwrap() - 0.05).abs() < 1e-12);
        let t: toml::Table = toml::from_str(&e.to_toml()).unwrap();
        let back = UserEffect::parse(0, &t[SECTION].as_array().unwrap()[0]).unwrap();
        assert_eq!(back, e);
        let mut c = BTreeMap::new();
        let none = capture_response(std::slice::from_ref(&e), &c, &Q).unwrap();
        assert_eq!(none, UserResponse::default());
        c.insert("vcsel_bias_ma".into(), 30.0);
        let r = capture_response(&[e], &c, &Q).unwrap();
        assert!((r.gain_factor - 1.1).abs() < 1e-12);
    }

    #[test]
    fn bad_user_effects_are_clear_errors() {
        let base = "name = \"x\"\ncondition = \"supply_v\"\nacts_on = \"phase\"\n";
        for (extra, needle) in [
            ("expression = \"a * supply_v\"", "unknown variable `a`"),
            ("expression = \"2 * (supply_v\"", "cannot parse"),
            ("knots_x = [1, 1]\nknots_y = [0, 1]", "increase strictly"),
            ("knots_x = [1, 2, 3]\nknots_y = [0, 1, 0]", "monotone"),
            (
                "expression = \"k\"\nparams = [{ name = \"k\", value = 5, min = 0, max = 1 }]",
                "outside its range",
            ),
            ("knots_x = [1, 2]", "either"),
            (
                "knots_x = [1, 2]\nknots_y = [0, 1]\ncolour = 1",
                "unknown key",
            ),
        ] {
            let err = parse(&format!("{base}{extra}")).unwrap_err().to_string();
            assert!(err.contains(needle), "{extra}: {err}");
        }
        let err = parse("name = \"x\"\ncondition = \"supply_v\"\nacts_on = \"depth\"\nknots_x = [1, 2]\nknots_y = [0, 1]")
            .unwrap_err()
            .to_string();
        assert!(err.contains("phase, gain, offset"), "{err}");
        let err = parse("name = \"prnu\"\ncondition = \"supply_v\"\nacts_on = \"gain\"\nknots_x = [1, 2]\nknots_y = [0, 1]")
            .unwrap_err()
            .to_string();
        assert!(err.contains("catalogue"), "{err}");
    }
}
