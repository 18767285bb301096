//! Issue 33, item 3: a condition the catalogue lacks becomes an effect the user adds.
//!
//! Recordings come from a small sensor simulation of this file's own (charge per
//! tap A/B, a 60 MHz correlation with 3rd and 5th harmonics, per-pixel offset,
//! gain and delay, shot and read noise) — neither tofprox-model's simulator nor
//! the lab's signatures. Its hidden effects follow conditions no catalogue effect
//! knows: the VCSEL bias current `vcsel_bias_ma` delays the light non-linearly
//! (a tanh), the supply voltage `supply_v` changes the optical power (a power
//! law). The loop: diagnose says `unexplained`, names the key and proposes
//! `condition:<KEY>`; `add` fits the response and writes it into the model as a
//! user effect; the next diagnose says `nothing_missing`, with depth errors within
//! 1.3× those of the twin recording without the effect. The same with the law
//! declared by the engineer as an expression, whose parameters the lab fits.
use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::Path;

use ndarray::Array3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use tofprox_core::SensorGeometry;
use tofprox_lab::adapter::{spec_from_model, spec_holding_model};
use tofprox_lab::diagnose::{Comparison, Verdict, compare, diagnose};
use tofprox_lab::fit::Prepared;
use tofprox_lab::user::proposal;
use tofprox_lab::workflow::add_to_model;
use tofprox_lab::{Capture, Dataset, Diagnosis};
use tofprox_model::ModelConfig;
use tofprox_model::effects::user::{UserActsOn, UserLaw};

const F_MOD_HZ: f64 = 60e6;
const ROWS: usize = 10;
const COLS: usize = 12;
const LSB_PER_E: f64 = 0.05;
const CONTRAST: f64 = 0.7;
const SIGNAL_E_PER_US: f64 = 3.4;

/// Hidden effects in this file's own formulation.
#[derive(Debug, Clone, Copy)]
enum Hidden {
    /// The light is delayed by a·tanh((I − i0)/w) rad at bias current I (mA).
    BiasDelay { a_rad: f64, i0_ma: f64, w_ma: f64 },
    /// Optical power ∝ (V / 3.3 V)^p at supply voltage V.
    SupplyPower { p: f64 },
}

impl Hidden {
    /// (phase rad, gain factor) at bias `i_ma` and supply `v`.
    fn at(&self, i_ma: f64, v: f64) -> (f64, f64) {
        match *self {
            Hidden::BiasDelay { a_rad, i0_ma, w_ma } => {
                (a_rad * ((i_ma - i0_ma) / w_ma).tanh(), 1.0)
            }
            Hidden::SupplyPower { p } => (0.0, (v / 3.3).powf(p)),
        }
    }
}

struct Pixels {
    offset_lsb: Vec<f64>,
    gain: Vec<f64>,
    delay_rad: Vec<f64>,
}

fn pixels(seed: u64) -> Pixels {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = ROWS * COLS;
    let mut g = || -> f64 { rng.sample(StandardNormal) };
    Pixels {
        offset_lsb: (0..n).map(|_| 30.0 * g()).collect(),
        gain: (0..n).map(|_| 1.0 + 0.04 * g()).collect(),
        delay_rad: (0..n).map(|_| 0.4 + 0.02 * g()).collect(),
    }
}

/// Correlation of the square-ish illumination with the gate (harmonics 3, 5).
fn correlation(x: f64) -> f64 {
    x.cos() + 0.045 * (3.0 * x + 0.3).cos() + 0.012 * (5.0 * x - 0.8).cos()
}

#[derive(Debug, Clone, Copy)]
struct Cond {
    distance_m: Option<f64>,
    exposure_us: f64,
    bias_ma: f64,
    supply_v: f64,
}

fn capture(
    px: &Pixels,
    hidden: &[Hidden],
    phases: &[f64],
    c: Cond,
    rng: &mut ChaCha8Rng,
) -> Capture {
    let averaged = 8u32;
    let mut frames = Array3::zeros((phases.len(), ROWS, COLS));
    let (mut dphi, mut gain) = (0.0, 1.0);
    for h in hidden {
        let (p, g) = h.at(c.bias_ma, c.supply_v);
        dphi += p;
        gain *= g;
    }
    for p in 0..ROWS * COLS {
        let (mut s_e, mut phi) = (0.0, 0.0);
        if let Some(d) = c.distance_m {
            s_e = SIGNAL_E_PER_US * c.exposure_us * px.gain[p] * gain / (d * d);
            phi = 4.0 * PI * F_MOD_HZ * d / 299_792_458.0 + px.delay_rad[p] + dphi;
        }
        for (k, th) in phases.iter().enumerate() {
            let corr = CONTRAST * correlation(phi - th.to_radians());
            let (na, nb) = (0.5 * s_e * (1.0 + corr), 0.5 * s_e * (1.0 - corr));
            let var_lsb2 = (LSB_PER_E * LSB_PER_E * (na + nb) + 2.5) / f64::from(averaged);
            let noise: f64 = rng.sample(StandardNormal);
            let code = 2048.0 + px.offset_lsb[p] + LSB_PER_E * (na - nb) + var_lsb2.sqrt() * noise;
            frames[[k, p / COLS, p % COLS]] = code.clamp(0.0, 4095.0);
        }
    }
    let extra = BTreeMap::from([
        ("vcsel_bias_ma".to_string(), c.bias_ma),
        ("supply_v".to_string(), c.supply_v),
    ]);
    Capture {
        phases_deg: phases.to_vec(),
        exposure_us: c.exposure_us,
        illumination: c.distance_m.is_some(),
        averaged,
        distance_m: c.distance_m,
        reflectivity: 1.0,
        ambient_klux: 0.0,
        temperature_c: Some(25.0),
        extra,
        frames,
    }
}

const BIAS_MA: [f64; 5] = [10.0, 15.0, 20.0, 25.0, 30.0];
const SUPPLY_V: [f64; 5] = [3.0, 3.15, 3.3, 3.45, 3.6];

/// Which condition a recording steps through (the other held at its nominal value).
#[derive(Clone, Copy)]
enum Vary {
    Bias,
    Supply,
}

/// Darks, a 24-phase correlation capture, then a 4-phase sweep of 7 distances at
/// two exposures, repeated, at five bias currents (or five supply voltages).
fn record(hidden: &[Hidden], vary: Vary, seed: u64) -> Dataset {
    let px = pixels(seed);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xbead);
    let base = Cond {
        distance_m: None,
        exposure_us: 300.0,
        bias_ma: 20.0,
        supply_v: 3.3,
    };
    let four = [0.0, 90.0, 180.0, 270.0];
    let exposures = [300.0, 1000.0];
    let mut caps = Vec::new();
    for &t in &exposures {
        for _ in 0..2 {
            let c = Cond {
                exposure_us: t,
                ..base
            };
            caps.push(capture(&px, hidden, &four, c, &mut rng));
        }
    }
    let corr: Vec<f64> = (0..24).map(|i| 15.0 * f64::from(i)).collect();
    let c = Cond {
        distance_m: Some(0.7),
        exposure_us: 500.0,
        ..base
    };
    caps.push(capture(&px, hidden, &corr, c, &mut rng));
    for i in 0..5 {
        let (bias_ma, supply_v) = match vary {
            Vary::Bias => (BIAS_MA[i], 3.3),
            Vary::Supply => (20.0, SUPPLY_V[i]),
        };
        for &t in &exposures {
            for j in 0..7 {
                let d = 0.2 + 1.4 * f64::from(j) / 6.0;
                for _ in 0..2 {
                    let c = Cond {
                        distance_m: Some(d),
                        exposure_us: t,
                        bias_ma,
                        supply_v,
                    };
                    caps.push(capture(&px, hidden, &four, c, &mut rng));
                }
            }
        }
    }
    Dataset {
        sensor: SensorGeometry {
            rows: ROWS,
            cols: COLS,
            roi_origin: [40, 64],
            full_rows: 172,
            full_cols: 224,
            adc_bits: 12,
            modulation_hz: F_MOD_HZ,
        },
        captures: caps,
    }
}

/// Baseline with this sensor's constants and harmonics to the 5th.
fn model_under_test() -> ModelConfig {
    let mut m = ModelConfig::baseline();
    m.set_enabled("dark_current", false).unwrap();
    m.set_param("waveform_harmonics", "h5_rel", 0.01).unwrap();
    for h in 6..=9 {
        m.set_param("waveform_harmonics", &format!("h{h}_rel"), 0.0)
            .unwrap();
    }
    m
}

fn compared(prep: &Prepared, m: &ModelConfig) -> (Comparison, Diagnosis) {
    let cmp = compare(prep, &spec_from_model(m), &|_, _| {}).unwrap();
    let d = diagnose(prep, &cmp, &|_, _| {}).unwrap();
    eprintln!(
        "{:?} {:?} strongest {:?} ({}); rms {:?}",
        d.verdict, d.effect, d.strongest_condition, d.reason, d.rms
    );
    (cmp, d)
}

/// Diagnose says unexplained, names `key` and proposes `condition:<key>` acting
/// on `acts_on`, naming no catalogue effect.
fn proposes(d: &Diagnosis, key: &str, acts_on: &str) {
    assert_eq!(d.verdict, Verdict::Unexplained, "{}", d.reason);
    assert_eq!(d.effect, None, "no catalogue effect is named");
    assert_eq!(d.strongest_condition.as_deref(), Some(key));
    let p = proposal(d).expect("an unexplained verdict against a condition proposes");
    eprintln!("proposal: {}", p.sentence);
    assert_eq!(p.add, format!("condition:{key}"));
    assert_eq!(p.acts_on, acts_on);
    assert!(
        p.sentence
            .contains(&format!("tofprox lab add condition:{key}"))
    );
    assert!(p.size_mm > 0.5, "{}", p.size_mm);
}

/// After the add: nothing missing, no effect named, depth errors within 1.3× of
/// the twin recording without the hidden effect.
fn closes(prep: &Prepared, m: &ModelConfig, vary: Vary, seed: u64) {
    let (after, d) = compared(prep, m);
    assert_eq!(d.verdict, Verdict::NothingMissing, "{}", d.reason);
    assert_eq!(d.effect, None);
    assert!(proposal(&d).is_none());
    let twin = Prepared::new(&record(&[], vary, seed)).unwrap();
    let (control, dc) = compared(&twin, &model_under_test());
    assert_eq!(dc.verdict, Verdict::NothingMissing, "{}", dc.reason);
    eprintln!("after {:?}\ncontrol {:?}", after.rms, control.rms);
    assert!(after.rms.depth_2phase_mm <= 1.3 * control.rms.depth_2phase_mm);
    assert!(after.rms.depth_4phase_mm <= 1.3 * control.rms.depth_4phase_mm);
}

/// The written shape's values against the truth's response relative to the first knot.
fn shape_matches(m: &ModelConfig, name: &str, truth: impl Fn(f64) -> f64, tol: f64) {
    let u = m.user_effects().iter().find(|u| u.name == name).unwrap();
    let UserLaw::Shape { knots_x, knots_y } = &u.law else {
        panic!("a condition response is a shape: {u:?}");
    };
    let p = u.provenance.as_ref().expect("written with its provenance");
    assert_eq!(p.recording, "rec/bias");
    assert!(p.chi2_per_dof_after < p.chi2_per_dof_before, "{p:?}");
    assert_eq!(p.date.len(), 10);
    for (x, y) in knots_x.iter().zip(knots_y) {
        let want = truth(*x) - truth(knots_x[0]);
        eprintln!("{name} at {x}: {y:.5} (truth {want:.5})");
        assert!((y - want).abs() <= tol, "{name} at {x}: {y} vs {want}");
    }
}

#[test]
fn a_bias_current_delay_becomes_a_user_effect_on_the_phase() {
    let h = Hidden::BiasDelay {
        a_rad: 0.06,
        i0_ma: 19.0,
        w_ma: 6.0,
    };
    let seed = 41;
    let prep = Prepared::new(&record(&[h], Vary::Bias, seed)).unwrap();
    let mut m = model_under_test();
    let (_, d) = compared(&prep, &m);
    proposes(&d, "vcsel_bias_ma", "phase");
    let (res, notes) = add_to_model(
        &prep,
        &mut m,
        "condition:vcsel_bias_ma",
        Path::new("rec/bias"),
        &|_, _| {},
    )
    .unwrap();
    eprintln!(
        "notes {notes:?}; params {:?} ± {:?}",
        res.params, res.standard_errors
    );
    assert_eq!(res.effect.id, "vcsel_bias_ma_phase");
    assert!(res.after.fit.chi2_per_dof < 0.5 * res.before.fit.chi2_per_dof);
    let u = &m.user_effects()[0];
    assert_eq!(
        (u.condition.as_str(), u.acts_on),
        ("vcsel_bias_ma", UserActsOn::Phase)
    );
    // 0.06 rad spans ±50 mm of depth at 60 MHz; the fit within 3 mrad (1.2 mm)
    shape_matches(&m, "vcsel_bias_ma_phase", |x| h.at(x, 3.3).0, 0.003);
    // held at the written values (`compare --hold-effects`) it fits as well as free
    let (held, notes) = spec_holding_model(&m, &prep);
    assert!(notes.is_empty(), "{notes:?}");
    assert_eq!(held.held.len(), 1);
    let h = compare(&prep, &held, &|_, _| {}).unwrap();
    eprintln!(
        "held χ²/dof {:.4}, free {:.4}",
        h.fit.chi2_per_dof, res.after.fit.chi2_per_dof
    );
    assert!(h.fit.chi2_per_dof <= 1.02 * res.after.fit.chi2_per_dof);
    // the file round-trips and the next diagnose closes
    let m = ModelConfig::from_toml_str(&m.to_toml_string()).unwrap();
    closes(&prep, &m, Vary::Bias, seed);
}

#[test]
fn a_supply_voltage_power_law_becomes_a_user_effect_on_the_gain() {
    let h = Hidden::SupplyPower { p: 1.5 };
    let seed = 42;
    let prep = Prepared::new(&record(&[h], Vary::Supply, seed)).unwrap();
    let mut m = model_under_test();
    let (_, d) = compared(&prep, &m);
    proposes(&d, "supply_v", "gain");
    let (res, _) = add_to_model(
        &prep,
        &mut m,
        "condition:supply_v",
        Path::new("rec/bias"),
        &|_, _| {},
    )
    .unwrap();
    assert_eq!(res.effect.id, "supply_v_gain");
    // the lab's gain is relative to the first knot's (the per-pixel gains take the rest)
    let truth = |v: f64| (v / 3.0f64).powf(1.5) - 1.0;
    shape_matches(&m, "supply_v_gain", truth, 0.01);
    closes(&prep, &m, Vary::Supply, seed);
}

#[test]
fn an_expression_the_engineer_declares_is_fitted_and_closes() {
    let h = Hidden::BiasDelay {
        a_rad: 0.06,
        i0_ma: 19.0,
        w_ma: 6.0,
    };
    let seed = 43;
    let prep = Prepared::new(&record(&[h], Vary::Bias, seed)).unwrap();
    let (_, d) = compared(&prep, &model_under_test());
    proposes(&d, "vcsel_bias_ma", "phase");
    let text = format!(
        "{}\n[[user_effects]]\nname = \"bias_delay\"\ncondition = \"vcsel_bias_ma\"\nacts_on = \"phase\"\n\
         expression = \"a * math::tanh((vcsel_bias_ma - i0) / w)\"\n\
         params = [{{ name = \"a\", value = 0.03, min = 0.0, max = 0.5 }}, {{ name = \"i0\", value = 22.0, min = 5.0, max = 35.0 }}, {{ name = \"w\", value = 10.0, min = 1.0, max = 40.0 }}]\n",
        model_under_test().to_toml_string()
    );
    let mut m = ModelConfig::from_toml_str(&text).unwrap();
    let (res, notes) = add_to_model(
        &prep,
        &mut m,
        "user:bias_delay",
        Path::new("rec/bias"),
        &|_, _| {},
    )
    .unwrap();
    eprintln!(
        "notes {notes:?}; params {:?} ± {:?}",
        res.params, res.standard_errors
    );
    let got = |k: &str| res.params[k];
    // truth a = 0.06 rad, i0 = 19 mA, w = 6 mA
    assert!((got("a") - 0.06).abs() <= 0.006, "a = {}", got("a"));
    assert!((got("i0") - 19.0).abs() <= 0.8, "i0 = {}", got("i0"));
    assert!((got("w") - 6.0).abs() <= 1.0, "w = {}", got("w"));
    let u = &m.user_effects()[0];
    let values: Vec<f64> = match &u.law {
        UserLaw::Expression { params, .. } => params.iter().map(|p| p.value).collect(),
        UserLaw::Shape { .. } => panic!("declared as an expression"),
    };
    assert_eq!(values, vec![got("a"), got("i0"), got("w")]);
    assert!(u.provenance.is_some());
    closes(&prep, &m, Vary::Bias, seed);
}
