//! Issue 20: several strong effects at once, on a sensor that is not ours.
//!
//! Recordings come from this file's own simulation, written like the
//! independent campaign of docs/lab.md ("What the lab has been tested on"):
//! 100 MHz, a trapezoid correlation (a clipped triangle, odd harmonics of its
//! own), charge per tap with contrast 0.75, shot noise with an excess factor,
//! read noise, a flicker offset common to each raw image, every acquisition
//! quantised to 12 bits and four averaged. A characterisation campaign varies
//! distance, reflectivity, exposure, temperature and ambient light, with
//! repeats. Hidden effects follow laws of this file, 5–10× their typical size
//! and two or three at once: a temperature drift with a quadratic term, a phase
//! error growing linearly with the signal charge, tap B converting with 1 − ε, an SBI whose
//! removal sets in with a quadratic soft knee, dark current with an Arrhenius
//! law. Neither tofprox-model nor the lab's signatures.
mod common;

use std::collections::BTreeMap;
use std::f64::consts::PI;

use ndarray::Array3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use tofprox_core::SensorGeometry;
use tofprox_lab::adapter::spec_from_model;
use tofprox_lab::diagnose::{
    DiagnoseOptions, Explanation, Verdict, compare, diagnose, effect_params, explain,
};
use tofprox_lab::fit::Prepared;
use tofprox_lab::signatures::write_effect;
use tofprox_lab::{Capture, Dataset};
use tofprox_model::ModelConfig;

const F_MOD_HZ: f64 = 100e6;
const N: usize = 5;
const LSB_PER_E: f64 = 0.08;
const CONTRAST: f64 = 0.75;
/// Signal electrons (both taps) per µs at 1 m, reflectivity 1.
const SIGNAL_E_PER_US: f64 = 2.5;
/// Background electrons per tap per µs per klux.
const AMBIENT_E_PER_US_KLUX: f64 = 0.3;
const AVERAGED: u32 = 4;
const T_REF_C: f64 = 25.0;

/// Hidden effects in this file's formulation.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Hidden {
    /// Phase a1·ΔT + a2·ΔT², gain 1 + g·ΔT.
    TempQuadratic { a1: f64, a2: f64, g: f64 },
    /// Phase k·S of the signal charge S (never saturating).
    LinearPhase { rad_per_e: f64 },
    /// Tap B converts with 1 − ε.
    TapGain { eps: f64 },
    /// Removal r(N_max) = 0 below q − w, (N_max − q + w)²/4w within, N_max − q
    /// above; from tap B with 1 + m; never more than a tap holds.
    SbiQuadraticKnee { q_e: f64, w_e: f64, m: f64 },
    /// Dark electrons per µs D0·exp(−E_a/k_B·(1/T − 1/T_ref)), 3 % more in tap A.
    DarkArrhenius { e_per_us: f64, ea_ev: f64 },
}

struct Pixels {
    offset_lsb: Vec<f64>,
    gain: Vec<f64>,
    delay_rad: Vec<f64>,
    dark_rel: Vec<f64>,
}

fn pixels(seed: u64) -> Pixels {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut g = || -> f64 { rng.sample(StandardNormal) };
    let centre = (N as f64 - 1.0) / 2.0;
    let mut px = Pixels {
        offset_lsb: Vec::new(),
        gain: Vec::new(),
        delay_rad: Vec::new(),
        dark_rel: Vec::new(),
    };
    for p in 0..N * N {
        let (r, c) = ((p / N) as f64 - centre, (p % N) as f64 - centre);
        px.offset_lsb.push(40.0 * g() + 6.0 * ((p % N) % 4) as f64);
        px.gain
            .push((1.0 - 0.004 * (r * r + c * c)) * (1.0 + 0.03 * g()));
        px.delay_rad.push(0.9 + 0.002 * r * r + 0.015 * g());
        px.dark_rel.push(1.0 + 0.3 * g());
    }
    px
}

/// A clipped triangle of peak 1 at x = 0 (period 2π): the correlation of a
/// trapezoid light pulse with the gate.
fn trapezoid(x: f64) -> f64 {
    let x = x.rem_euclid(2.0 * PI);
    let tri = 2.0 * (x - PI).abs() / PI - 1.0;
    (1.4 * tri).clamp(-1.0, 1.0)
}

fn quadratic_knee(n_max: f64, q: f64, w: f64) -> f64 {
    if n_max <= q - w {
        0.0
    } else if n_max >= q + w {
        n_max - q
    } else {
        (n_max - q + w).powi(2) / (4.0 * w)
    }
}

#[derive(Clone, Copy)]
struct Cond {
    distance_m: Option<f64>,
    reflectivity: f64,
    exposure_us: f64,
    ambient_klux: f64,
    temperature_c: f64,
}

/// Signal charge and phase of pixel `p`.
fn signal(px: &Pixels, hidden: &[Hidden], c: Cond, p: usize) -> (f64, f64) {
    let Some(d) = c.distance_m else {
        return (0.0, 0.0);
    };
    let dt = c.temperature_c - T_REF_C;
    let mut s = SIGNAL_E_PER_US * c.exposure_us * c.reflectivity * px.gain[p] / (d * d);
    let mut phi = 4.0 * PI * F_MOD_HZ * d / 299_792_458.0 + px.delay_rad[p];
    for h in hidden {
        match *h {
            Hidden::TempQuadratic { a1, a2, g } => {
                phi += a1 * dt + a2 * dt * dt;
                s *= 1.0 + g * dt;
            }
            Hidden::LinearPhase { rad_per_e } => phi += rad_per_e * s,
            _ => {}
        }
    }
    (s, phi)
}

/// Tap charges (A, B) of pixel `p` in a raw image shifted by `th_rad`.
fn taps(px: &Pixels, hidden: &[Hidden], c: Cond, p: usize, th_rad: f64) -> (f64, f64) {
    let (s, phi) = signal(px, hidden, c, p);
    let background = AMBIENT_E_PER_US_KLUX * c.ambient_klux * c.exposure_us * px.gain[p];
    let (mut na, mut nb) = (background, background);
    for h in hidden {
        if let Hidden::DarkArrhenius { e_per_us, ea_ev } = *h {
            let inv = 1.0 / (c.temperature_c + 273.15) - 1.0 / (T_REF_C + 273.15);
            let dark = e_per_us * (-ea_ev / 8.617e-5 * inv).exp() * c.exposure_us;
            na += 1.03 * dark * px.dark_rel[p];
            nb += dark * px.dark_rel[p];
        }
    }
    let corr = CONTRAST * trapezoid(phi - th_rad);
    na += 0.5 * s * (1.0 + corr);
    nb += 0.5 * s * (1.0 - corr);
    for h in hidden {
        if let Hidden::SbiQuadraticKnee { q_e, w_e, m } = *h {
            let removed = quadratic_knee(na.max(nb), q_e, w_e)
                .min(na)
                .min(nb / (1.0 + m));
            na -= removed;
            nb -= (1.0 + m) * removed;
        }
    }
    (na, nb)
}

fn capture(
    px: &Pixels,
    hidden: &[Hidden],
    phases: &[f64],
    c: Cond,
    rng: &mut ChaCha8Rng,
) -> Capture {
    let mut frames = Array3::zeros((phases.len(), N, N));
    let gain_b = hidden.iter().fold(1.0, |g, h| match *h {
        Hidden::TapGain { eps } => g * (1.0 - eps),
        _ => g,
    });
    for (k, th) in phases.iter().enumerate() {
        let flicker_lsb = 0.25 * rng.sample::<f64, _>(StandardNormal);
        for p in 0..N * N {
            let (na, nb) = taps(px, hidden, c, p, th.to_radians());
            let code = 2048.0 + px.offset_lsb[p] + flicker_lsb + LSB_PER_E * (na - gain_b * nb);
            // shot noise with an excess factor 1.2, read noise 2 LSB²
            let sd = (LSB_PER_E * LSB_PER_E * 1.2 * (na + nb) + 2.0).sqrt();
            let sum: f64 = (0..AVERAGED)
                .map(|_| {
                    (code + sd * rng.sample::<f64, _>(StandardNormal))
                        .round()
                        .clamp(0.0, 4095.0)
                })
                .sum();
            frames[[k, p / N, p % N]] = sum / f64::from(AVERAGED);
        }
    }
    Capture {
        phases_deg: phases.to_vec(),
        exposure_us: c.exposure_us,
        illumination: c.distance_m.is_some(),
        averaged: AVERAGED,
        distance_m: c.distance_m,
        reflectivity: c.reflectivity,
        ambient_klux: c.ambient_klux,
        temperature_c: Some(c.temperature_c),
        extra: BTreeMap::new(),
        frames,
    }
}

/// Darks per exposure and temperature, two 24-phase correlation captures, a
/// 4-phase sweep over distance (reflectivity 1 and 0.4 alternating) × exposure
/// × temperature × ambient light, and a 2-phase sweep; every capture twice.
fn record(hidden: &[Hidden], seed: u64) -> Dataset {
    let px = pixels(seed);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5e7e);
    let base = Cond {
        distance_m: None,
        reflectivity: 1.0,
        exposure_us: 200.0,
        ambient_klux: 0.0,
        temperature_c: T_REF_C,
    };
    let (four, temps, exposures) = ([0.0, 90.0, 180.0, 270.0], [5.0, 25.0, 45.0], [200.0, 800.0]);
    let mut conds = Vec::new();
    for &temperature_c in &temps {
        for &exposure_us in &exposures {
            conds.push((
                four.to_vec(),
                Cond {
                    exposure_us,
                    temperature_c,
                    ..base
                },
            ));
        }
    }
    let corr: Vec<f64> = (0..24).map(|i| 15.0 * f64::from(i)).collect();
    conds.push((
        corr,
        Cond {
            distance_m: Some(0.6),
            exposure_us: 400.0,
            ..base
        },
    ));
    for &temperature_c in &temps {
        for ambient_klux in [0.0, 20.0] {
            for &exposure_us in &exposures {
                for i in 0..6 {
                    let c = Cond {
                        distance_m: Some(0.25 + 1.1 * i as f64 / 5.0),
                        reflectivity: if i % 2 == 0 { 1.0 } else { 0.4 },
                        exposure_us,
                        ambient_klux,
                        temperature_c,
                    };
                    conds.push((four.to_vec(), c));
                }
            }
        }
    }
    for i in 0..6 {
        let c = Cond {
            distance_m: Some(0.25 + 1.1 * i as f64 / 5.0),
            exposure_us: 400.0,
            ..base
        };
        conds.push((vec![0.0, 90.0], c));
    }
    let captures = conds
        .iter()
        .flat_map(|(ph, c)| [*c, *c].map(|c| capture(&px, hidden, ph, c, &mut rng)))
        .collect();
    Dataset {
        sensor: SensorGeometry {
            rows: N,
            cols: N,
            roi_origin: [80, 100],
            full_rows: 172,
            full_cols: 224,
            adc_bits: 12,
            modulation_hz: F_MOD_HZ,
        },
        captures,
    }
}

/// The model the campaign starts from: config/model/baseline.toml.
fn baseline() -> ModelConfig {
    ModelConfig::baseline()
}

fn run(hidden: &[Hidden], seed: u64) -> (Prepared, Explanation) {
    let prep = Prepared::new(&record(hidden, seed)).unwrap();
    let spec = spec_from_model(&baseline());
    let ex = explain(&prep, &spec, &DiagnoseOptions::default(), &|_, _| {}).unwrap();
    for (i, st) in ex.steps.iter().enumerate() {
        let d = &st.diagnosis;
        eprintln!(
            "step {i}: {:?} χ²/dof {:.3} → {:?}: {}",
            d.verdict, d.fit.chi2_per_dof, st.added, d.reason
        );
        for c in d.candidates.iter().take(3) {
            eprintln!(
                "   {:24} expl {:6.3} cv {:6.3} z_after {:8.1}",
                c.effect, c.explained_excess, c.cv_gain, c.z_after
            );
        }
    }
    eprintln!("added {:?}, stopped {:?}", ex.added, ex.stopped);
    (prep, ex)
}

/// χ²/dof of the same recording without the hidden effects (`compare`).
fn control_chi2(seed: u64) -> f64 {
    let prep = Prepared::new(&record(&[], seed)).unwrap();
    let spec = spec_from_model(&baseline());
    compare(&prep, &spec, &|_, _| {}).unwrap().fit.chi2_per_dof
}

/// The file `explain` would write (`--out`), held at its values
/// (`--hold-effects`, from a cold start): its χ²/dof.
fn held_chi2(ex: &Explanation, prep: &Prepared) -> f64 {
    let (held, _) = common::written_and_held(ex, prep, &baseline());
    compare(prep, &held, &|_, _| {}).unwrap().fit.chi2_per_dof
}

/// The control: nothing missing on the same campaign without hidden effects.
#[test]
fn control_is_nothing_missing() {
    let prep = Prepared::new(&record(&[], 51)).unwrap();
    let spec = spec_from_model(&baseline());
    let c = compare(&prep, &spec, &|_, _| {}).unwrap();
    let d = diagnose(&prep, &c, &|_, _| {}).unwrap();
    eprintln!("control χ²/dof {:.3}: {}", c.fit.chi2_per_dof, d.reason);
    assert_eq!(d.verdict, Verdict::NothingMissing, "{}", d.reason);
}

/// A parameter of the file `explain` writes for `effect` (model units).
fn written(ex: &Explanation, prep: &Prepared, effect: &str, key: &str) -> f64 {
    let fin = ex.final_model().unwrap();
    let mut m = baseline();
    let (_, params) = effect_params(prep, fin, effect).unwrap();
    write_effect(&mut m, effect, &params, fin, prep).unwrap();
    m.param(effect, key).unwrap()
}

/// What every case must show: the effects named are hidden ones, a loop that
/// did not close says why (never `nothing_missing` with structure left), and
/// the written file held fits within 2 % of the free fit.
fn never_confident_wrong(ex: &Explanation, prep: &Prepared, hidden_ids: &[&str]) {
    for e in &ex.added {
        assert!(hidden_ids.contains(&e.as_str()), "{e} is not hidden here");
    }
    if ex.verdict() != Verdict::NothingMissing {
        assert!(ex.stopped.is_some(), "a loop that did not close says why");
    }
    if !ex.added.is_empty() {
        let free = ex.steps.last().unwrap().comparison.fit.chi2_per_dof;
        let held = held_chi2(ex, prep);
        eprintln!("held χ²/dof {held:.4} vs free {free:.4}");
        assert!(held <= 1.02 * free, "held {held} free {free}");
    }
}

const DRIFT: Hidden = Hidden::TempQuadratic {
    a1: 0.012,
    a2: 2e-4,
    g: -0.002,
};
const LINEAR_PHASE: Hidden = Hidden::LinearPhase { rad_per_e: 1.5e-5 };

/// A strong quadratic drift (−0.16 … +0.32 rad over 5–45 °C; 8× a typical
/// 1.5 mrad/K) with a phase error growing linearly with the signal (up to
/// ≈ 0.4 rad, outside the catalogue's saturating law). Both are named and the
/// misfit falls by far more than 5×, but the saturating law cannot follow a
/// linear growth: `explain` ends `unexplained` and says so. The drift alone
/// explains 33 % of the excess: before issue 20's trial step `explain` added
/// nothing here.
#[test]
fn quadratic_drift_with_linear_phase_error() {
    let drift = Hidden::TempQuadratic {
        a1: 0.008,
        a2: 1.5e-4,
        g: -0.002,
    };
    let (prep, ex) = run(&[drift, LINEAR_PHASE], 52);
    // the drift alone explains 33 %: added on trial, it lets the phase error
    // be named; a last trial that named nothing was taken back
    let trial = &ex.steps[0];
    assert_eq!(trial.diagnosis.verdict, Verdict::Unexplained);
    assert_eq!(trial.added.as_deref(), Some("temperature_drift"));
    assert_eq!(ex.added, ["temperature_drift", "amplitude_phase_error"]);
    let first = ex.steps[0].diagnosis.fit.chi2_per_dof;
    let last = ex.steps.last().unwrap().comparison.fit.chi2_per_dof;
    let control = control_chi2(52);
    eprintln!("χ²/dof {first:.2} → {last:.3}, control {control:.3}");
    assert!(first > 5.0 * last && last > 1.05 * control);
    assert_eq!(ex.verdict(), Verdict::Unexplained);
    never_confident_wrong(&ex, &prep, &["temperature_drift", "amplitude_phase_error"]);
}

/// Tap B converting 6 % less (30× typical) with the quadratic drift, under 0
/// and 20 klux: both named, the loop closes, and the written file reproduces
/// the free fit. Before issue 20's fix the tap gain's file held gave χ²/dof
/// 2.7 against 1.09 free on the campaign's recording: its background leak
/// was not written (the file's typical ambient responsivity was held instead).
#[test]
fn tap_gain_with_quadratic_drift_under_ambient_light() {
    let (prep, ex) = run(&[Hidden::TapGain { eps: 0.06 }, DRIFT], 53);
    let mut added = ex.added.clone();
    added.sort();
    assert_eq!(added, ["tap_gain_mismatch", "temperature_drift"]);
    let eps = written(&ex, &prep, "tap_gain_mismatch", "mismatch_rel");
    let k1 = written(&ex, &prep, "temperature_drift", "phase_mrad_per_k");
    let k2 = written(&ex, &prep, "temperature_drift", "phase_mrad_per_k2");
    eprintln!("written mismatch_rel {eps} (truth 0.06), k1 {k1} (12), k2 {k2} (0.2)");
    assert!((eps - 0.06).abs() < 0.006, "{eps}");
    assert!((k1 - 12.0).abs() < 1.2, "{k1}");
    assert!((k2 - 0.2).abs() < 0.03, "{k2}");
    let last = ex.steps.last().unwrap().comparison.fit.chi2_per_dof;
    let control = control_chi2(53);
    eprintln!("χ²/dof after {last:.3}, control {control:.3}");
    assert!(last < 1.1 * control);
    never_confident_wrong(&ex, &prep, &["tap_gain_mismatch", "temperature_drift"]);
}

/// Dark current with an Arrhenius law (0.9 eV: ×11 from 25 to 45 °C, 3 % more
/// in tap A) filling the taps of a soft-knee SBI: no catalogue effect explains
/// it, and the lab says so — `unexplained` with its reason, nothing added.
#[test]
fn arrhenius_dark_current_with_sbi_is_unexplained() {
    let dark = Hidden::DarkArrhenius {
        e_per_us: 4.0,
        ea_ev: 0.9,
    };
    let sbi = Hidden::SbiQuadraticKnee {
        q_e: 14_000.0,
        w_e: 3_000.0,
        m: 0.06,
    };
    let (prep, ex) = run(&[dark, sbi], 55);
    assert_eq!(ex.verdict(), Verdict::Unexplained);
    never_confident_wrong(&ex, &prep, &["dark_current", "sbi_asymmetry"]);
}
