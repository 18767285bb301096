//! Phasor math: known answers from synthetic phasors (eqs. 2.2–2.9) and property tests of the
//! thesis' phasor arguments (3.3.2 gain, 3.3.3 offset / eq. 3.4, 4-phase vs 2-phase cancellation).

use proptest::prelude::*;
use std::f64::consts::{FRAC_PI_4, PI, TAU};
use tofprox_core::phasor::*;
use tofprox_core::pipeline::{Calibration, Pipeline, PipelineConfig};
use tofprox_core::{Algorithm, SPEED_OF_LIGHT_M_PER_S};

/// Circular distance between two phases.
fn circ(a: f64, b: f64) -> f64 {
    wrap_to_pi(a - b).abs()
}

/// `u_k = A cos(phi - theta_k)` (the shared convention, offset already removed).
fn u(a: f64, phi: f64, theta_deg: f64) -> f64 {
    a * (phi - theta_deg.to_radians()).cos()
}

#[test]
fn exact_angles_all_quadrants() {
    // Multiples of 45° hit every quadrant and both axes.
    for k in 0..8 {
        let phi = k as f64 * FRAC_PI_4;
        for a in [1e-3, 1.0, 700.0] {
            let p2 = phase_2phase(u(a, phi, 0.0), u(a, phi, 90.0));
            let p4 = phase_4phase(
                u(a, phi, 0.0),
                u(a, phi, 90.0),
                u(a, phi, 180.0),
                u(a, phi, 270.0),
            );
            assert!((p2 - phi).abs() < 1e-12, "2phase {k}: {p2} vs {phi}");
            assert!((p4 - phi).abs() < 1e-12, "4phase {k}: {p4} vs {phi}");
            assert!(
                (amplitude_2phase(u(a, phi, 0.0), u(a, phi, 90.0)) - a).abs() < 1e-9 * a.max(1.0)
            );
            let a4 = amplitude_4phase(
                u(a, phi, 0.0),
                u(a, phi, 90.0),
                u(a, phi, 180.0),
                u(a, phi, 270.0),
            );
            assert!((a4 - a).abs() < 1e-9 * a.max(1.0));
        }
    }
    // Explicit quadrant representatives (u0, u90) → expected phase.
    let cases = [
        ((3.0, 3.0), PI / 4.0),
        ((-3.0, 3.0), 3.0 * PI / 4.0),
        ((-3.0, -3.0), 5.0 * PI / 4.0),
        ((3.0, -3.0), 7.0 * PI / 4.0),
        ((0.0, 5.0), PI / 2.0),
        ((-5.0, 0.0), PI),
        ((0.0, -5.0), 3.0 * PI / 2.0),
        ((5.0, 0.0), 0.0),
    ];
    for ((u0, u90), want) in cases {
        assert!((phase_2phase(u0, u90) - want).abs() < 1e-15, "({u0},{u90})");
        // 4-phase with a common offset of 100 (must cancel).
        let p4 = phase_4phase(u0 + 100.0, u90 + 100.0, -u0 + 100.0, -u90 + 100.0);
        assert!((p4 - want).abs() < 1e-12);
    }
}

#[test]
fn wrap_around_at_zero_and_two_pi() {
    // Just below the positive x axis: close to 2π but strictly below it.
    let p = phase_2phase(1.0, -1e-12);
    assert!(p < TAU && TAU - p < 1e-11, "{p}");
    let p = phase_2phase(1.0, 1e-12);
    assert!((0.0..1e-11).contains(&p));
    // -0.0 must not produce 2π.
    let p = phase_2phase(1.0, -0.0);
    assert!((0.0..TAU).contains(&p));
    // Phases beyond one turn wrap.
    for turns in [-3.0, -1.0, 1.0, 5.0] {
        let phi = 0.3 + turns * TAU;
        assert!((phase_2phase(u(1.0, phi, 0.0), u(1.0, phi, 90.0)) - 0.3).abs() < 1e-12);
        assert!((wrap_phase(phi) - 0.3).abs() < 1e-9);
    }
}

#[test]
fn intensity_distance_and_ranges() {
    assert_eq!(intensity_4phase(1.0, 2.0, 3.0, 4.0), -1.0); // eq. 2.5 as printed
    let du = unambiguous_range_m(80e6);
    assert!((du - SPEED_OF_LIGHT_M_PER_S / 160e6).abs() < 1e-12);
    assert!((du - 1.873_702_862_5).abs() < 1e-9);
    assert!((phase_to_distance_m(PI, 80e6) - du / 2.0).abs() < 1e-12);
    assert!((phase_to_distance_m(distance_to_phase_rad(0.42, 80e6), 80e6) - 0.42).abs() < 1e-12);
    assert!(
        (extended_unambiguous_range_m(80e6, 60e6) - SPEED_OF_LIGHT_M_PER_S / 40e6).abs() < 1e-9
    );
    assert!(extended_unambiguous_range_m(80e6, 80e6).is_infinite());
}

#[test]
fn nphase_known_answers_and_rejects() {
    let phases4: Vec<f64> = [0.0f64, 90.0, 180.0, 270.0]
        .iter()
        .map(|d| d.to_radians())
        .collect();
    let s = [3.0, 5.0, -1.0, 2.0];
    let (p, a) = nphase(&s, &phases4).unwrap();
    assert!((p - phase_4phase(3.0, 5.0, -1.0, 2.0)).abs() < 1e-12);
    assert!((a - amplitude_4phase(3.0, 5.0, -1.0, 2.0)).abs() < 1e-12);
    assert!(
        nphase(&[1.0, 2.0], &phases4[..2]).is_none(),
        "N = 2 is not a full circle DFT"
    );
    assert!(nphase(&s, &phases4[..3]).is_none(), "length mismatch");
    let uneven = [0.0, 0.5, 2.0, 4.0];
    assert!(nphase(&s, &uneven).is_none());
    assert!(nphase(&[1.0, f64::NAN, 0.0, 0.0], &phases4).is_none());
}

#[test]
fn dual_frequency_thesis_example_and_errors() {
    // Thesis fig. 2.3: a target at 4 m is ambiguous for each frequency alone.
    let (f1, f2) = (80e6, 60e6);
    let d = 4.0;
    let p1 = wrap_phase(distance_to_phase_rad(d, f1));
    let p2 = wrap_phase(distance_to_phase_rad(d, f2));
    assert!(phase_to_distance_m(p1, f1) < 1.9);
    let r = dual_frequency_distance(p1, 100.0, f1, p2, 50.0, f2, None).unwrap();
    assert!((r.distance_m - d).abs() < 1e-9, "{r:?}");
    assert_eq!(r.wraps1, 2);
    assert_eq!(r.wraps2, 1);
    assert!(r.residual_m < 1e-9);
    assert!(dual_frequency_distance(p1, 1.0, f1, p2, 1.0, f1, None).is_err());
    assert!(dual_frequency_distance(f64::NAN, 1.0, f1, p2, 1.0, f2, None).is_err());
    assert!(dual_frequency_distance(p1, -1.0, f1, p2, 1.0, f2, None).is_err());
    assert!(dual_frequency_distance(p1, 1.0, f1, p2, 1.0, f2, Some(0.0)).is_err());
    // Tiny frequency difference: extended range huge → refuse unbounded search.
    assert!(dual_frequency_distance(p1, 1.0, 80e6, p2, 1.0, 80e6 + 1.0, None).is_err());
}

#[test]
fn weighted_fusion_eq_2_9() {
    // Equal A·f → plain mean; one weight zero → the other distance.
    assert!((weighted_distance_m(1.0, 2.0, 60e6, 2.0, 1.5, 80e6).unwrap() - 1.5).abs() < 1e-12);
    assert_eq!(
        weighted_distance_m(1.0, 0.0, 60e6, 2.0, 1.0, 80e6),
        Some(2.0)
    );
    assert_eq!(weighted_distance_m(1.0, 0.0, 60e6, 2.0, 0.0, 80e6), None);
    // Weight ratio A1 f1 : A2 f2 = 3 : 1.
    let d = weighted_distance_m(1.0, 3.0, 80e6, 2.0, 1.0, 80e6).unwrap();
    assert!((d - 1.25).abs() < 1e-12);
}

/// Phase error caused by a common offset `c` on a phasor `A e^{iφ}` (eq. 3.4 / fig. 3.6): the
/// offset adds the 45° phasor `c√2 e^{iπ/4}`; seen from `z`, the angle it turns `z` by is
/// `atan2(c√2 sin(π/4 − φ), A + c√2 cos(π/4 − φ))`.
fn offset_error_prediction(a: f64, phi: f64, c: f64) -> f64 {
    let r = c * 2f64.sqrt();
    (r * (FRAC_PI_4 - phi).sin()).atan2(a + r * (FRAC_PI_4 - phi).cos())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// 3.3.2: a common gain on every phase image leaves the phase unchanged (fig. 3.5).
    #[test]
    fn gain_leaves_phase_unchanged(phi in 0.0..TAU, a in 1.0..2000.0f64, g in 0.01..100.0f64) {
        let s: Vec<f64> = [0.0, 90.0, 180.0, 270.0].iter().map(|&t| u(a, phi, t)).collect();
        let p2 = phase_2phase(s[0], s[1]);
        let p2g = phase_2phase(g * s[0], g * s[1]);
        prop_assert!(circ(p2, p2g) < 1e-9);
        let p4 = phase_4phase(s[0], s[1], s[2], s[3]);
        let p4g = phase_4phase(g * s[0], g * s[1], g * s[2], g * s[3]);
        prop_assert!(circ(p4, p4g) < 1e-9);
        prop_assert!(circ(p2, phi) < 1e-9);
        // The amplitude scales with the gain (the deviation is visible in the amplitude image).
        prop_assert!((amplitude_2phase(g * s[0], g * s[1]) / (g * a) - 1.0).abs() < 1e-9);
    }

    /// 3.3.3 / eq. 3.4: a common offset c moves the 2-phase phase by exactly the angle the 45°
    /// phasor c(1+i) turns z by, and the magnitude becomes |z + c(1+i)|; 4-phase cancels it.
    #[test]
    fn offset_changes_2phase_as_eq_3_4(phi in 0.0..TAU, a in 5.0..2000.0f64, c in -200.0..200.0f64) {
        let (u0, u90) = (u(a, phi, 0.0), u(a, phi, 90.0));
        let measured = phase_2phase(u0 + c, u90 + c);
        let predicted = wrap_phase(phi + offset_error_prediction(a, phi, c));
        prop_assume!((a * a + 2.0 * c * c + 2.0 * a * c * (phi.cos() + phi.sin())) > 1e-6); // z_offset ≠ 0
        prop_assert!(circ(measured, predicted) < 1e-9, "measured {} predicted {}", measured, predicted);
        let mag = ((u0 + c).powi(2) + (u90 + c).powi(2)).sqrt();
        prop_assert!((amplitude_2phase(u0 + c, u90 + c) - mag).abs() < 1e-9 * mag.max(1.0));
        // Fig. 3.7: the same offset hurts more when the signal is weaker.
        let weaker = phase_2phase(u0 / 4.0 + c, u90 / 4.0 + c);
        prop_assert!(circ(weaker, phi) + 1e-12 >= circ(measured, phi));
        // 4-phase: the offset cancels exactly.
        let s: Vec<f64> = [0.0, 90.0, 180.0, 270.0].iter().map(|&t| u(a, phi, t) + c).collect();
        prop_assert!(circ(phase_4phase(s[0], s[1], s[2], s[3]), phi) < 1e-9);
        // 2-phase is not immune: away from the 45° axis a real offset gives a real error.
        if c.abs() > 1.0 && (FRAC_PI_4 - phi).sin().abs() > 0.1 {
            prop_assert!(circ(measured, phi) > 1e-6);
        }
    }

    /// The pipeline without a dark frame (global mid-code subtraction only) shows the eq. 3.4 error
    /// of a per-pixel offset; with the dark frame it is gone.
    #[test]
    fn pipeline_offset_matches_eq_3_4(phi in 0.05..6.2f64, a in 50.0..1500.0f64, c in -150.0..150.0f64) {
        let raw = ndarray::Array3::from_shape_fn((2, 1, 1), |(k, _, _)| 2048.0 + c + u(a, phi, 90.0 * k as f64));
        let cfg = PipelineConfig { min_amplitude_lsb: 0.0, ..PipelineConfig::default() };
        let mut p = Pipeline::new(1, 1, cfg, Calibration::default()).unwrap();
        let got = p.process(raw.view()).unwrap().phase_rad[(0, 0)] as f64;
        let predicted = wrap_phase(phi + offset_error_prediction(a, phi, c));
        prop_assert!(circ(got, predicted) < 2e-4, "got {} predicted {}", got, predicted);
        let dark = tofprox_core::calib::OffsetCalibration { dark_lsb: ndarray::Array2::from_elem((1, 1), (2048.0 + c) as f32) };
        let mut p = Pipeline::new(1, 1, cfg, Calibration { offset: Some(dark), ..Calibration::default() }).unwrap();
        let got = p.process(raw.view()).unwrap().phase_rad[(0, 0)] as f64;
        prop_assert!(circ(got, phi) < 2e-4);
    }

    /// Even harmonics of the correlation cancel in 4-phase (θ and θ+180° see the same 2nd
    /// harmonic), but distort 2-phase.
    #[test]
    fn even_harmonics_cancel_in_4phase_only(a in 100.0..2000.0f64, rel in 0.02..0.3f64, psi in 0.0..TAU, c in -100.0..100.0f64) {
        let b = rel * a;
        let sample = |phi: f64, t: f64| {
            let x = phi - t.to_radians();
            c + a * x.cos() + b * (2.0 * x + psi).cos() + 0.3 * b * (4.0 * x - psi).cos()
        };
        let mut worst_2phase: f64 = 0.0;
        for i in 0..64 {
            let phi = TAU * i as f64 / 64.0;
            let p4 = phase_4phase(sample(phi, 0.0), sample(phi, 90.0), sample(phi, 180.0), sample(phi, 270.0));
            prop_assert!(circ(p4, phi) < 1e-9);
            // 2-phase after perfect offset removal still sees the even harmonics.
            let p2 = phase_2phase(sample(phi, 0.0) - c, sample(phi, 90.0) - c);
            worst_2phase = worst_2phase.max(circ(p2, phi));
        }
        prop_assert!(worst_2phase > 0.1 * rel, "2-phase worst error {} for rel {}", worst_2phase, rel);
    }

    /// N-phase DFT recovers phase and amplitude for any equally spaced set (any start, any order),
    /// cancelling a common offset and harmonics up to N−2.
    #[test]
    fn nphase_recovers_phase(n in 3usize..=32, start in 0.0..TAU, phi in 0.0..TAU, a in 1.0..2000.0f64,
                             c in -300.0..300.0f64, h in 0.0..0.2f64, rot in 0usize..32) {
        let mut phases: Vec<f64> = (0..n).map(|k| start + TAU * k as f64 / n as f64).collect();
        phases.rotate_left(rot % n);
        let samples: Vec<f64> = phases.iter().map(|&t| {
            let x = phi - t;
            let mut v = c + a * x.cos();
            if n >= 4 { v += h * a * (2.0 * x + 0.3).cos(); }
            if n >= 5 { v += h * a * (3.0 * x - 1.0).cos(); }
            v
        }).collect();
        let (p, amp) = nphase(&samples, &phases).unwrap();
        prop_assert!(circ(p, phi) < 1e-9, "n {} got {} want {}", n, p, phi);
        prop_assert!((amp - a).abs() < 1e-9 * a);
    }

    /// Dual frequency: any distance inside the extended range is recovered (eq. 2.8), and the
    /// fused distance (eq. 2.9) equals it.
    #[test]
    fn dual_frequency_recovers_distance(d in 0.0..7.4f64, a1 in 1.0..1000.0f64, a2 in 1.0..1000.0f64) {
        let (f1, f2) = (80e6, 60e6); // extended range 7.49 m
        let p1 = wrap_phase(distance_to_phase_rad(d, f1));
        let p2 = wrap_phase(distance_to_phase_rad(d, f2));
        let r = dual_frequency_distance(p1, a1, f1, p2, a2, f2, None).unwrap();
        prop_assert!((r.distance_m - d).abs() < 1e-6, "{:?} vs {}", r, d);
        prop_assert!((r.distance1_m - d).abs() < 1e-6 && (r.distance2_m - d).abs() < 1e-6);
    }
}

#[test]
fn four_phase_pipeline_ignores_per_pixel_offsets() {
    // FPN of ±100 LSB per pixel, no dark frame: 4-phase depth stays exact (offset cancels), 2-phase not.
    let (rows, cols) = (4, 4);
    let d = 1.2;
    let phi = distance_to_phase_rad(d, 80e6);
    let raw = ndarray::Array3::from_shape_fn((4, rows, cols), |(k, r, c)| {
        2048.0 + (r as f64 - 1.5) * 60.0 + (c as f64 - 1.5) * 25.0 + u(120.0, phi, 90.0 * k as f64)
    });
    let mut errs = [0.0f64; 2];
    for (i, algo) in Algorithm::ALL.into_iter().enumerate() {
        let cfg = PipelineConfig {
            algorithm: algo,
            ..PipelineConfig::default()
        };
        let mut p = Pipeline::new(rows, cols, cfg, Calibration::default()).unwrap();
        let f = p.process(raw.view()).unwrap();
        errs[i] = f
            .depth_m
            .iter()
            .fold(0.0f64, |m, &v| m.max((v as f64 - d).abs()));
    }
    assert!(errs[1] < 1e-3, "4-phase error {}", errs[1]);
    assert!(errs[0] > 0.05, "2-phase error {}", errs[0]);
}
