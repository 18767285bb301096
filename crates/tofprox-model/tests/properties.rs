//! Physical sanity as property tests.

use std::f64::consts::{PI, TAU};

use proptest::prelude::*;
use rand::SeedableRng;
use rand::rngs::SmallRng;
use tofprox_core::phasor::distance_to_phase_rad;
use tofprox_model::{CaptureRequest, ModelConfig, Scene, SensorGeometry, Simulator};

const F: f64 = 80e6;

fn centre(rows: usize, cols: usize) -> SensorGeometry {
    SensorGeometry::irs1645()
        .window(80, 100, rows, cols)
        .unwrap()
}

fn wrap_pm_pi(x: f64) -> f64 {
    (x + PI).rem_euclid(TAU) - PI
}

fn phases(c: &ndarray::Array3<f64>, r: usize, col: usize) -> (f64, f64) {
    let u = |k: usize| c[[k, r, col]] - 2048.0;
    let p2 = u(1).atan2(u(0)).rem_euclid(TAU); // eq. 2.2
    let p4 = (u(1) - u(3)).atan2(u(0) - u(2)).rem_euclid(TAU); // eq. 2.3
    (p2, p4)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, .. ProptestConfig::default() })]

    /// Every effect disabled: eq. 2.2 and 2.3 recover φ = 4π f d / c to float precision.
    #[test]
    fn ideal_model_gives_eq_2_2_and_2_3(d in 0.02f64..3.5, refl in 0.05f64..1.0, t in 50.0f64..2000.0, seed in any::<u64>()) {
        let sim = Simulator::new(&ModelConfig::ideal(), centre(2, 2), seed).unwrap();
        let req = CaptureRequest::four_phase(t);
        let scene = Scene::wall(d, refl);
        let e = sim.expected(&scene, &req).unwrap();
        let mut rng = SmallRng::seed_from_u64(seed);
        let c = sim.capture(&scene, &req, &mut rng).unwrap();
        let amp = e.iter().fold(0.0f64, |m, v| m.max((v - 2048.0).abs()));
        prop_assume!(amp < 2000.0 && amp > 1e-3); // inside the ADC range
        prop_assert_eq!(&e, &c); // no noise effect on: capture is the mean exactly
        let truth = distance_to_phase_rad(d, F);
        let (p2, p4) = phases(&e, 1, 1);
        prop_assert!(wrap_pm_pi(p2 - truth).abs() < 1e-9, "2-phase {} vs {}", p2, truth);
        prop_assert!(wrap_pm_pi(p4 - truth).abs() < 1e-9, "4-phase {} vs {}", p4, truth);
    }

    /// Gain (ADC gain error, PRNU, temperature gain drift) never changes the phase (eq. 3.3).
    #[test]
    fn gain_never_changes_phase(gain_pct in -20.0f64..20.0, sigma in 0.0f64..0.3, vig in 0.0f64..0.9,
                                kg in -0.01f64..0.01, temp in -20.0f64..80.0, d in 0.3f64..1.8, seed in any::<u64>()) {
        let mut m = ModelConfig::ideal();
        m.set_enabled("signal_falloff", true).unwrap();
        m.set_enabled("adc_gain", true).unwrap();
        m.set_param("adc_gain", "gain_error_pct_fsr", gain_pct).unwrap();
        m.set_enabled("prnu", true).unwrap();
        m.set_param("prnu", "sigma_rel", sigma).unwrap();
        m.set_param("prnu", "vignetting_rel", vig).unwrap();
        m.set_enabled("temperature_drift", true).unwrap();
        m.set_param("temperature_drift", "phase_mrad_per_k", 0.0).unwrap();
        m.set_param("temperature_drift", "gain_rel_per_k", kg).unwrap();
        let g = SensorGeometry::irs1645().window(0, 0, 3, 3).unwrap(); // corner: strong vignetting
        let sim = Simulator::new(&m, g, seed).unwrap();
        let mut req = CaptureRequest::four_phase(300.0);
        req.temperature_c = temp;
        let e = sim.expected(&Scene::wall(d, 0.7), &req).unwrap();
        let truth = distance_to_phase_rad(d, F);
        for r in 0..3 {
            for c in 0..3 {
                let (p2, p4) = phases(&e, r, c);
                prop_assert!(wrap_pm_pi(p2 - truth).abs() < 1e-9);
                prop_assert!(wrap_pm_pi(p4 - truth).abs() < 1e-9);
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 6, .. ProptestConfig::default() })]

    /// Noise variance follows the photon transfer curve (2.3.2.6):
    /// var = g² (N_A + N_B) + σ_read², divided by the number of averaged acquisitions.
    #[test]
    fn noise_variance_follows_photon_transfer_curve(d in 0.3f64..1.5, t in 100.0f64..1000.0,
                                                    read in 0.5f64..4.0, averaged in 1u32..8, seed in any::<u64>()) {
        let mut m = ModelConfig::ideal();
        m.set_enabled("signal_falloff", true).unwrap();
        m.set_enabled("shot_noise", true).unwrap();
        m.set_enabled("read_noise", true).unwrap();
        m.set_param("read_noise", "sigma_lsb", read).unwrap();
        let (rows, cols) = (48, 64);
        let sim = Simulator::new(&m, centre(rows, cols), seed).unwrap();
        let mut req = CaptureRequest::four_phase(t);
        req.averaged = averaged;
        let scene = Scene::wall(d, 1.0);
        let mean = sim.expected(&scene, &req).unwrap();
        let mut rng = SmallRng::seed_from_u64(seed ^ 0xABCD);
        let c = sim.capture(&scene, &req, &mut rng).unwrap();
        // photo-electrons in both taps together = signal electrons (no ambient, K = 1)
        let n_e = m.param("sensor", "signal_e_per_us").unwrap() * t / (d * d);
        let g = m.param("sensor", "lsb_per_ke").unwrap() * 1e-3;
        let predicted = (g * g * n_e + read * read) / f64::from(averaged);
        for k in 0..4 {
            let plane = c.index_axis(ndarray::Axis(0), k);
            let mplane = mean.index_axis(ndarray::Axis(0), k);
            let n = (rows * cols) as f64;
            let var = plane.iter().zip(mplane.iter()).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / n;
            // relative standard error of a variance from 3072 samples ≈ 2.6 %
            prop_assert!((var / predicted - 1.0).abs() < 0.12, "image {}: var {} predicted {}", k, var, predicted);
        }
    }
}
