//! Issue 33, item 2: strong laws outside the catalogue's families close.
//!
//! Recordings come from this file's own sensor simulation — charge per tap
//! A/B at 60 MHz with a correlation of 3rd and 5th harmonics, per-pixel
//! offset, gain and delay, shot and read noise — written without
//! tofprox-model or the lab's signatures. Its hidden laws are formulated
//! here, unlike the lab's families:
//!
//! * a laser turn-on delay that switches like a logistic of the temperature
//!   (the driver's threshold crossing moves once the junction is hot):
//!   τ(T) = τ_max/(1 + e^{−(T − T_m)/w}) — neither linear nor quadratic in T,
//!   about five times a typical module's drift over 0–55 °C;
//! * the same together with a VCSEL whose power falls over the raw images of
//!   one acquisition (a two-effect case on the 60 MHz per-tap simulation);
//! * a tap mismatch that grows with the collected charge, ε = ε₀ + κ·Q;
//! * a VCSEL whose junction follows a power-law thermal response
//!   Z(τ) ∝ τ^0.4, heating while it emits and cooling in the gaps between
//!   raw images (the junction's rise convolved over a discretised on/off
//!   history), recorded at several exposures and several gaps
//!   (`image_gap_us`), alone and with the logistic delay.
//!
//! Each ends at `nothing_missing` after the `explain` loop, names only the
//! hidden effects, and its depth errors come within 1.3× those of a twin
//! recording without them.
use std::f64::consts::PI;

use ndarray::Array3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use tofprox_core::SensorGeometry;
use tofprox_lab::adapter::spec_from_model;
use tofprox_lab::diagnose::{DiagnoseOptions, Explanation, Verdict, compare, diagnose, explain};
use tofprox_lab::fit::{LabSpec, Prepared};
use tofprox_lab::{Capture, Dataset};
use tofprox_model::ModelConfig;

const F_MOD_HZ: f64 = 60e6;
const ROWS: usize = 9;
const COLS: usize = 11;
/// Conversion gain (LSB per electron of tap difference) and contrast.
const LSB_PER_E: f64 = 0.05;
const CONTRAST: f64 = 0.72;
/// Signal electrons (both taps) per µs at 1 m.
const SIGNAL_E_PER_US: f64 = 3.2;

/// A hidden law of this file's own.
#[derive(Debug, Clone, Copy)]
enum Law {
    /// Turn-on delay τ_max/(1 + e^{−(T − T_m)/w}) in ns, as a phase 2π·f·τ,
    /// and a responsivity falling as e^{g·(T − 25)}.
    LogisticDelay {
        tau_max_ns: f64,
        t_mid_c: f64,
        width_k: f64,
        g_per_k: f64,
    },
    /// Optical power of raw image k: 1 − a·(1 − 1/(1 + k·t_exp/t_h)) — a
    /// loss that saturates hyperbolically with the on-time before the image.
    HyperbolicDroop { a: f64, t_h_us: f64 },
    /// Tap B converts with a gain that falls with the collected charge (the
    /// floating diffusions' voltage coefficient): D = (1 + ε/2)·N_A −
    /// (1 − ε/2)·N_B with ε = ε₀ + κ·(N_A + N_B).
    ChargeTapMismatch { eps0: f64, kappa_per_e: f64 },
    /// Optical power 1 − ΔT(t_k) at the start of raw image k, the junction's
    /// rise ΔT the convolution of the emission history with the impulse
    /// response of a power-law thermal step response Z(τ) = a·(τ/1 ms)^n
    /// (a diffusive heat path), discretised in steps of [`DT_US`].
    PowerLawThermal { a: f64, n: f64 },
    /// Suppression of background illumination with a soft knee: each tap's
    /// circuit removes R = w·ln(1 + e^{(N_max − q)/w}) electrons (a
    /// softplus of the fuller tap's charge over the threshold q, never more
    /// than the emptier tap holds), tap A's R·(1 + m/2) and tap B's
    /// R·(1 − m/2).
    SoftKneeSbi { q_e: f64, w_e: f64, m: f64 },
}

/// Time step of the discretised emission history, µs (the exposures and
/// gaps here are multiples of it).
const DT_US: f64 = 10.0;

/// The junction's rise at the start of raw image `k` of an acquisition of
/// raw images of `exposure_us` every `exposure_us + gap_us` (the VCSEL cold
/// at the first): Σ over the history's cells m before t_k of
/// p_m·[Z(t_k − t_m) − Z(t_k − t_m − Δt)], p_m = 1 while a raw image emits.
fn thermal_rise(a: f64, n: f64, k: usize, exposure_us: f64, gap_us: f64) -> f64 {
    let z = |tau_us: f64| a * (tau_us.max(0.0) * 1e-3).powf(n);
    let t_k = k as f64 * (exposure_us + gap_us);
    let cells = (t_k / DT_US).round() as usize;
    (0..cells)
        .map(|m| m as f64 * DT_US)
        .filter(|t| t % (exposure_us + gap_us) < exposure_us - 1e-9)
        .map(|t| z(t_k - t) - z(t_k - t - DT_US))
        .sum()
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
        offset_lsb: (0..n).map(|_| 25.0 * g()).collect(),
        gain: (0..n).map(|_| 1.0 + 0.05 * g()).collect(),
        delay_rad: (0..n).map(|_| 0.5 + 0.02 * g()).collect(),
    }
}

/// The square-ish illumination correlated with the gate.
fn correlation(x: f64) -> f64 {
    x.cos() + 0.04 * (3.0 * x + 0.2).cos() + 0.01 * (5.0 * x - 0.6).cos()
}

#[derive(Debug, Clone, Copy)]
struct Cond {
    distance_m: Option<f64>,
    exposure_us: f64,
    temperature_c: f64,
    /// Off-time between raw images, recorded as `image_gap_us` (`None`: not
    /// recorded, no gap).
    gap_us: Option<f64>,
}

fn capture(px: &Pixels, laws: &[Law], phases: &[f64], c: Cond, rng: &mut ChaCha8Rng) -> Capture {
    let averaged = 8u32;
    let mut frames = Array3::zeros((phases.len(), ROWS, COLS));
    for p in 0..ROWS * COLS {
        let (mut s_e, mut phi) = (0.0, 0.0);
        if let Some(d) = c.distance_m {
            s_e = SIGNAL_E_PER_US * c.exposure_us * px.gain[p] / (d * d);
            phi = 4.0 * PI * F_MOD_HZ * d / 299_792_458.0 + px.delay_rad[p];
        }
        for law in laws {
            if let Law::LogisticDelay {
                tau_max_ns,
                t_mid_c,
                width_k,
                g_per_k,
            } = *law
            {
                let tau_ns = tau_max_ns / (1.0 + (-(c.temperature_c - t_mid_c) / width_k).exp());
                phi += 2.0 * PI * F_MOD_HZ * tau_ns * 1e-9;
                s_e *= (g_per_k * (c.temperature_c - 25.0)).exp();
            }
        }
        for (k, th) in phases.iter().enumerate() {
            let power = laws.iter().fold(1.0, |pw, law| match *law {
                Law::HyperbolicDroop { a, t_h_us } => {
                    let x = k as f64 * c.exposure_us / t_h_us;
                    pw * (1.0 - a * x / (1.0 + x))
                }
                Law::PowerLawThermal { a, n } => {
                    pw * (1.0 - thermal_rise(a, n, k, c.exposure_us, c.gap_us.unwrap_or(0.0)))
                }
                Law::LogisticDelay { .. }
                | Law::ChargeTapMismatch { .. }
                | Law::SoftKneeSbi { .. } => pw,
            });
            let s = s_e * power;
            let corr = CONTRAST * correlation(phi - th.to_radians());
            let (na, nb) = (0.5 * s * (1.0 + corr), 0.5 * s * (1.0 - corr));
            let var_lsb2 = (LSB_PER_E * LSB_PER_E * (na + nb) + 2.5) / f64::from(averaged);
            let noise: f64 = rng.sample(StandardNormal);
            let diff_e = laws.iter().fold(na - nb, |d, law| match *law {
                Law::ChargeTapMismatch { eps0, kappa_per_e } => {
                    d + 0.5 * (eps0 + kappa_per_e * (na + nb)) * (na + nb)
                }
                Law::SoftKneeSbi { q_e, w_e, m } => {
                    let r = (w_e * (1.0 + ((na.max(nb) - q_e) / w_e).exp()).ln()).min(na.min(nb));
                    d - m * r
                }
                _ => d,
            });
            let code = 2048.0 + px.offset_lsb[p] + LSB_PER_E * diff_e + var_lsb2.sqrt() * noise;
            frames[[k, p / COLS, p % COLS]] = code.clamp(0.0, 4095.0);
        }
    }
    Capture {
        phases_deg: phases.to_vec(),
        exposure_us: c.exposure_us,
        illumination: c.distance_m.is_some(),
        averaged,
        distance_m: c.distance_m,
        reflectivity: 1.0,
        ambient_klux: 0.0,
        temperature_c: Some(c.temperature_c),
        extra: c
            .gap_us
            .map(|g| [("image_gap_us".to_string(), g)].into())
            .unwrap_or_default(),
        frames,
    }
}

/// What a recording sweeps: every capture of the 4-phase sweep at each
/// temperature, exposure and gap between raw images.
struct Plan<'a> {
    temps: &'a [f64],
    exposures_us: &'a [f64],
    gaps_us: &'a [f64],
}

/// Darks, a 24-phase correlation capture at 25 °C, then a 4-phase sweep of
/// 8 distances at each of the plan's temperatures, exposures and gaps,
/// every capture twice.
fn record(laws: &[Law], plan: &Plan<'_>, seed: u64) -> Dataset {
    let px = pixels(seed);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
    let four = [0.0, 90.0, 180.0, 270.0];
    // the gap is recorded where the plan varies it
    let gap = |g: f64| (plan.gaps_us.len() > 1).then_some(g);
    let mut caps = Vec::new();
    for &t in plan.exposures_us {
        for _ in 0..2 {
            let c = Cond {
                distance_m: None,
                exposure_us: t,
                temperature_c: 25.0,
                gap_us: gap(plan.gaps_us[0]),
            };
            caps.push(capture(&px, laws, &four, c, &mut rng));
        }
    }
    let corr: Vec<f64> = (0..24).map(|i| 15.0 * f64::from(i)).collect();
    let c = Cond {
        distance_m: Some(0.7),
        exposure_us: 500.0,
        temperature_c: 25.0,
        gap_us: gap(plan.gaps_us[0]),
    };
    caps.push(capture(&px, laws, &corr, c, &mut rng));
    for &temperature_c in plan.temps {
        for &exposure_us in plan.exposures_us {
            for &gap_us in plan.gaps_us {
                for i in 0..8 {
                    let d = 0.2 + 1.4 * f64::from(i) / 7.0;
                    for _ in 0..2 {
                        let c = Cond {
                            distance_m: Some(d),
                            exposure_us,
                            temperature_c,
                            gap_us: gap(gap_us),
                        };
                        caps.push(capture(&px, laws, &four, c, &mut rng));
                    }
                }
            }
        }
    }
    Dataset {
        sensor: SensorGeometry {
            rows: ROWS,
            cols: COLS,
            roi_origin: [60, 90],
            full_rows: 172,
            full_cols: 224,
            adc_bits: 12,
            modulation_hz: F_MOD_HZ,
        },
        captures: caps,
    }
}

/// The model under test: baseline, harmonics to the 5th, no lab effect.
fn spec() -> LabSpec {
    let mut m = ModelConfig::baseline();
    m.set_enabled("dark_current", false).unwrap();
    m.set_param("waveform_harmonics", "h5_rel", 0.01).unwrap();
    for h in 6..=9 {
        m.set_param("waveform_harmonics", &format!("h{h}_rel"), 0.0)
            .unwrap();
    }
    spec_from_model(&m)
}

const TEMPS: [f64; 5] = [0.0, 15.0, 25.0, 40.0, 55.0];
/// The exposures of every sweep.
const EXPOSURES_US: [f64; 2] = [300.0, 1000.0];

/// `explain` adds exactly `expected`, ends at `nothing_missing`, and the depth
/// errors after it are within 1.3× those of the twin without the laws (which
/// is itself `nothing_missing`). Returns the explanation.
fn closes(laws: &[Law], seed: u64, expected: &[&str]) -> Explanation {
    closes_at(laws, &TEMPS, seed, expected)
}

/// [`closes`] over the temperatures `temps`.
fn closes_at(laws: &[Law], temps: &[f64], seed: u64, expected: &[&str]) -> Explanation {
    let plan = Plan {
        temps,
        exposures_us: &EXPOSURES_US,
        gaps_us: &[0.0],
    };
    closes_in(laws, &plan, seed, expected)
}

/// [`closes`] over the recording `plan`.
fn closes_in(laws: &[Law], plan: &Plan<'_>, seed: u64, expected: &[&str]) -> Explanation {
    let prep = Prepared::new(&record(laws, plan, seed)).unwrap();
    let ex = explain(&prep, &spec(), &DiagnoseOptions::default(), &|_, _| {}).unwrap();
    for (i, st) in ex.steps.iter().enumerate() {
        let d = &st.diagnosis;
        eprintln!(
            "step {i}: {:?} {:?} ({}) remaining {:.3} mm tol {:.3} mm; χ²/dof {:.3} AIC {:.1}",
            d.verdict, d.effect, d.reason, d.size.mm, d.tolerance_mm, d.fit.chi2_per_dof, d.fit.aic
        );
        for c in &st.comparison.structure {
            eprintln!(
                "   structure {:24} z {:8.1} {} {:.3} mm",
                c.condition, c.z, c.direction, c.size_mm
            );
        }
        for c in d.candidates.iter().take(3) {
            eprintln!(
                "   {:24} expl {:6.3} cv {:6.3} z_after {:8.1} form {} {:?}",
                c.effect, c.explained_excess, c.cv_gain, c.z_after, c.form, c.form_scores
            );
        }
    }
    let mut added = ex.added.clone();
    added.sort();
    let mut want: Vec<String> = expected.iter().map(|s| s.to_string()).collect();
    want.sort();
    assert_eq!(added, want, "effects added");
    assert_eq!(ex.verdict(), Verdict::NothingMissing, "{:?}", ex.stopped);
    let twin = Prepared::new(&record(&[], plan, seed)).unwrap();
    let c = compare(&twin, &spec(), &|_, _| {}).unwrap();
    let last = &ex.steps.last().unwrap().comparison;
    eprintln!("after {:?}\ntwin  {:?}", last.rms, c.rms);
    assert!(last.rms.depth_2phase_mm <= 1.3 * c.rms.depth_2phase_mm);
    assert!(last.rms.depth_4phase_mm <= 1.3 * c.rms.depth_4phase_mm);
    let dc = diagnose(&twin, &c, &|_, _| {}).unwrap();
    assert_eq!(dc.verdict, Verdict::NothingMissing, "twin: {}", dc.reason);
    ex
}

/// 1.5 ns of turn-on delay switching in around 30 °C over ±14 K (0.57 rad
/// at 60 MHz; 0.42 rad between 0 and 55 °C, 7.7 mrad/K on average: 5× the
/// catalogue's typical 1.5 mrad/K), the responsivity falling 0.3 %/K. The
/// quadratic law cannot follow the switch; the 5-knot shape predicts the
/// held-out captures about half as badly — yet less than 1 % of what the
/// physical form explains there, the margin that kept the family before
/// issue 33. The lab closes it with the shape.
#[test]
fn logistic_turn_on_delay_closes_as_a_shape() {
    let law = Law::LogisticDelay {
        tau_max_ns: 1.5,
        t_mid_c: 30.0,
        width_k: 14.0,
        g_per_k: -0.003,
    };
    let ex = closes(&[law], 71, &["temperature_drift"]);
    let fin = ex.final_model().unwrap();
    assert!(
        fin.spec.shapes.contains_key("temperature_drift"),
        "the drift is written as a shape: {:?}",
        fin.spec.shapes
    );
}

/// The delay's switch together with a droop that saturates with the on-time
/// (≈ 5 % of the power lost by the 4th raw image at 1 ms): both named, the
/// loop closes.
#[test]
fn turn_on_delay_and_droop_together_close() {
    let laws = [
        Law::LogisticDelay {
            tau_max_ns: 1.0,
            t_mid_c: 30.0,
            width_k: 8.0,
            g_per_k: -0.002,
        },
        Law::HyperbolicDroop {
            a: 0.08,
            t_h_us: 2000.0,
        },
    ];
    closes(&laws, 72, &["temperature_drift", "vcsel_droop"]);
}

/// A tap mismatch of 1 % (5× the catalogue's typical 0.2 %) that doubles
/// at ≈ 40 000 e⁻ of collected charge (κ = 2.5·10⁻⁷ per e⁻; ε = ε₀ + κ·Q,
/// the floating diffusions' voltage coefficient): named `tap_gain_mismatch`,
/// not the SBI whose residual it resembles, and what the linear leak ε/2·Q
/// leaves after `add` is below the tolerance — the loop closes.
#[test]
fn charge_dependent_tap_mismatch_closes() {
    let law = Law::ChargeTapMismatch {
        eps0: 0.01,
        kappa_per_e: 2.5e-7,
    };
    closes_at(&[law], &[25.0], 73, &["tap_gain_mismatch"]);
}

/// A droop 5× a typical module's (≈ 10 % of the power lost 3 ms into the
/// emission, against the catalogue's 3 %·(1 − e⁻¹) ≈ 1.9 %) from a
/// power-law thermal response Z(τ) = 0.06·(τ/1 ms)^0.4 that heats while
/// the VCSEL emits and cools in the gaps, recorded at two exposures and
/// three gaps between raw images (0, 0.4 and 2 ms): the exponential law of
/// the on-time follows neither the power law nor the cooling; the step
/// response's shape over the duty cycle closes it.
#[test]
fn duty_cycle_droop_closes_as_a_shape() {
    let law = Law::PowerLawThermal { a: 0.06, n: 0.4 };
    let plan = Plan {
        temps: &[25.0],
        exposures_us: &EXPOSURES_US,
        gaps_us: &[0.0, 400.0, 2000.0],
    };
    let ex = closes_in(&[law], &plan, 74, &["vcsel_droop"]);
    let fin = ex.final_model().unwrap();
    assert!(
        fin.spec.shapes.contains_key("vcsel_droop"),
        "the droop is written as a shape: {:?}",
        fin.spec.shapes
    );
}

/// The duty-cycle droop together with a strong logistic turn-on delay
/// (5× a typical drift) over five temperatures: both named, nothing else,
/// the loop closes.
#[test]
fn duty_cycle_droop_and_logistic_delay_together_close() {
    let laws = [
        Law::PowerLawThermal { a: 0.06, n: 0.4 },
        Law::LogisticDelay {
            tau_max_ns: 1.5,
            t_mid_c: 30.0,
            width_k: 14.0,
            g_per_k: -0.003,
        },
    ];
    let plan = Plan {
        temps: &TEMPS,
        exposures_us: &EXPOSURES_US,
        gaps_us: &[0.0, 2000.0],
    };
    closes_in(&laws, &plan, 75, &["temperature_drift", "vcsel_droop"]);
}

/// An SBI with a soft knee, 5× a typical module's mismatch (15 %): the
/// removal rises like a softplus of the fuller tap's charge over 15 000 e⁻
/// (width 4000 e⁻), so it has begun well below the threshold — neither the
/// parametric clamp nor its screening follows the knee. Named
/// `sbi_asymmetry`, written as its shape, the loop closes.
#[test]
fn soft_knee_sbi_closes() {
    let law = Law::SoftKneeSbi {
        q_e: 15_000.0,
        w_e: 4_000.0,
        m: 0.15,
    };
    closes_at(&[law], &[25.0], 76, &["sbi_asymmetry"]);
}
