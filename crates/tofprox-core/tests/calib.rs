//! Calibration extraction: offset, wiggling LUT (anchoring, interpolation, errors), FPPN.

use ndarray::{Array1, Array2, Array3};
use std::f64::consts::{PI, TAU};
use tofprox_core::calib::*;
use tofprox_core::phasor::{distance_to_phase_rad, wrap_phase, wrap_to_pi};
use tofprox_core::pipeline::{Calibration, Pipeline, PipelineConfig};
use tofprox_core::{Algorithm, CoreError};

const F: f64 = 80e6;

fn phases24() -> Vec<f64> {
    (0..24).map(|k| 15.0 * k as f64).collect()
}

/// Flat wall capture with per-pixel phase offsets `delta(r, c)` and an optional 3rd harmonic.
fn capture(
    rows: usize,
    cols: usize,
    phases_deg: &[f64],
    total_phase: f64,
    delta: impl Fn(usize, usize) -> f64,
    h3: f64,
) -> Array3<f64> {
    Array3::from_shape_fn((phases_deg.len(), rows, cols), |(k, r, c)| {
        let x = total_phase + delta(r, c) - phases_deg[k].to_radians();
        2048.0 + 600.0 * (x.cos() + h3 * (3.0 * x).cos())
    })
}

/// Phase of one pixel's offset-free samples as `algo` measures it (eq. 2.2 / eq. 2.3).
fn measured_phase(algo: Algorithm, u: &[f64]) -> f64 {
    match algo {
        Algorithm::TwoPhase => tofprox_core::phasor::phase_2phase(u[0], u[1]),
        Algorithm::FourPhase => tofprox_core::phasor::phase_4phase(u[0], u[1], u[2], u[3]),
    }
}

#[test]
fn offset_is_per_pixel_mean_and_rejects_bad_input() {
    let dark = Array3::from_shape_fn((3, 2, 2), |(k, r, c)| {
        2000.0 + (r * 10 + c) as f64 + k as f64
    });
    let off = extract_offset(dark.view()).unwrap();
    assert_eq!(off.dark_lsb[(1, 1)], 2012.0);
    assert_eq!(off.dark_lsb[(0, 1)], 2002.0);
    let mut bad = dark.clone();
    bad[(0, 0, 0)] = f64::NAN;
    assert!(matches!(
        extract_offset(bad.view()),
        Err(CoreError::InvalidData(_))
    ));
    assert!(extract_offset(Array3::<f64>::zeros((0, 2, 2)).view()).is_err());
}

#[test]
fn sinusoidal_correlation_gives_constant_lut_equal_to_global_delay() {
    let d0 = 0.6;
    let delay = 1.1; // rad
    let phi0 = distance_to_phase_rad(d0, F);
    let corr = capture(8, 8, &phases24(), phi0 + delay, |_, _| 0.0, 0.0);
    for algo in Algorithm::ALL {
        let lut = extract_wiggling(
            corr.view(),
            &ExtractionOptions::new(algo, &phases24(), d0, F, 12).lut_size(64),
        )
        .unwrap();
        assert_eq!(lut.len(), 64);
        assert_eq!(lut.algorithm, algo);
        for &c in lut.correction_rad.iter() {
            assert!(
                (wrap_to_pi(c as f64 - delay)).abs() < 1e-5,
                "{algo}: {c} vs {delay}"
            );
        }
        // Applying the table removes the delay at any measured phase.
        for i in 0..50 {
            let m = TAU * i as f64 / 50.0;
            assert!(wrap_to_pi(lut.correct(m) - (m - delay)).abs() < 1e-5);
        }
    }
}

#[test]
fn lut_inverts_a_distorted_correlation_for_any_capture_distance() {
    // 3rd harmonic wiggling, correlation captured at two different distances: both tables must
    // map the measured phase of any target back to its true time-of-flight phase.
    let delay = 0.4;
    for d0 in [0.3, 1.45] {
        let phi0 = distance_to_phase_rad(d0, F);
        let corr = capture(4, 4, &phases24(), phi0 + delay, |_, _| 0.0, 0.08);
        for algo in Algorithm::ALL {
            let lut = extract_wiggling(
                corr.view(),
                &ExtractionOptions::new(algo, &phases24(), d0, F, 12).lut_size(256),
            )
            .unwrap();
            for i in 0..97 {
                let true_tof = TAU * i as f64 / 97.0;
                let target = capture(1, 1, algo.phases_deg(), true_tof + delay, |_, _| 0.0, 0.08);
                let u: Vec<f64> = target.iter().map(|v| v - 2048.0).collect();
                let m = measured_phase(algo, &u);
                let err = wrap_to_pi(lut.correct(m) - true_tof);
                assert!(
                    err.abs() < 2e-4,
                    "{algo} d0 {d0}: err {err} rad at {true_tof}"
                );
            }
        }
    }
}

#[test]
fn lut_interpolation_is_linear_periodic_and_wrap_safe() {
    let lut = WigglingLut {
        algorithm: Algorithm::TwoPhase,
        correction_rad: Array1::from(vec![0.0f32, 1.0, 2.0, 3.0]),
    };
    assert!((lut.correction_at(PI / 4.0) - 0.5).abs() < 1e-9);
    // Between the last bin (3.0 at 3π/2) and the first (0.0 at 2π), wrapped difference
    // 0 − 3 → +3.28 (mod 2π) is the continuous path.
    let at = lut.correction_at(1.75 * PI);
    assert!((at - (3.0 + 0.5 * wrap_to_pi(-3.0))).abs() < 1e-9, "{at}");
    // A table stored wrapped to (−π, π] interpolates like its continuous version.
    let cont: Vec<f32> = (0..16).map(|i| 2.8 + 0.05 * i as f32).collect();
    let wrapped: Vec<f32> = cont.iter().map(|&v| wrap_to_pi(v as f64) as f32).collect();
    let a = WigglingLut {
        algorithm: Algorithm::TwoPhase,
        correction_rad: Array1::from(cont),
    };
    let b = WigglingLut {
        algorithm: Algorithm::TwoPhase,
        correction_rad: Array1::from(wrapped),
    };
    for i in 0..100 {
        let m = TAU * i as f64 / 100.0;
        assert!(wrap_to_pi(a.correct(m) - b.correct(m)).abs() < 1e-6);
    }
    assert!(lut.correction_at(f64::NAN).is_nan());
}

#[test]
fn wiggling_rejects_bad_input() {
    let p = phases24();
    let corr = capture(4, 4, &p, 1.0, |_, _| 0.0, 0.0);
    let ok = |c: &Array3<f64>, ph: &[f64], d: f64, n: usize| {
        extract_wiggling(
            c.view(),
            &ExtractionOptions::new(Algorithm::TwoPhase, ph, d, F, 12).lut_size(n),
        )
    };
    assert!(ok(&corr, &p, 0.5, 64).is_ok());
    assert!(matches!(
        ok(&corr, &p[..23], 0.5, 64),
        Err(CoreError::ShapeMismatch { .. })
    ));
    let mut uneven = p.clone();
    uneven[3] = 46.0;
    assert!(matches!(
        ok(&corr, &uneven, 0.5, 64),
        Err(CoreError::InvalidPhases { .. })
    ));
    assert!(ok(&corr, &p, f64::NAN, 64).is_err());
    assert!(ok(&corr, &p, -1.0, 64).is_err());
    assert!(ok(&corr, &p, 0.5, 0).is_err());
    let saturated = Array3::from_elem((24, 4, 4), 4095.0);
    assert!(matches!(
        ok(&saturated, &p, 0.5, 64),
        Err(CoreError::InvalidData(_))
    ));
    let flat = Array3::from_elem((24, 4, 4), 2048.0);
    assert!(ok(&flat, &p, 0.5, 64).is_err(), "no signal");
    // A correlation so distorted the phase is not monotone.
    let bad = Array3::from_shape_fn((24, 2, 2), |(k, _, _)| {
        let x = 1.0 - p[k].to_radians();
        2048.0 + 500.0 * (x.cos() + 0.9 * (3.0 * x).cos())
    });
    assert!(matches!(
        ok(&bad, &p, 0.5, 64),
        Err(CoreError::Calibration(_))
    ));
    let off = OffsetCalibration {
        dark_lsb: Array2::zeros((3, 3)),
    };
    assert!(
        extract_wiggling(
            corr.view(),
            &ExtractionOptions::new(Algorithm::TwoPhase, &p, 0.5, F, 12)
                .offset(&off)
                .lut_size(64)
        )
        .is_err()
    );
    assert!(
        extract_wiggling(
            corr.view(),
            &ExtractionOptions::new(Algorithm::TwoPhase, &p, 0.5, F, 0).lut_size(64)
        )
        .is_err()
    );
}

#[test]
fn fppn_is_per_pixel_residual_after_lut_and_pipeline_removes_it() {
    let (rows, cols) = (6, 7);
    let d0 = 0.8;
    let delay = 0.7;
    let delta = |r: usize, c: usize| {
        0.02 * (r as f64 - 2.5) - 0.015 * (c as f64 - 3.0)
            + if (r, c) == (1, 1) { 0.1 } else { 0.0 }
    };
    let phi0 = distance_to_phase_rad(d0, F);
    for algo in Algorithm::ALL {
        let corr = capture(rows, cols, &phases24(), phi0 + delay, delta, 0.05);
        let lut = extract_wiggling(
            corr.view(),
            &ExtractionOptions::new(algo, &phases24(), d0, F, 12).lut_size(512),
        )
        .unwrap();
        let flat = capture(
            rows,
            cols,
            &[0.0, 90.0, 180.0, 270.0],
            phi0 + delay,
            delta,
            0.05,
        );
        let fppn = extract_fppn(
            flat.view(),
            &ExtractionOptions::new(algo, &[0.0, 90.0, 180.0, 270.0], d0, F, 12).wiggling(&lut),
        )
        .unwrap();
        for r in 0..rows {
            for c in 0..cols {
                let got = fppn.phase_offset_rad[(r, c)] as f64;
                // Expected: the pixel's deviation relative to the pixels the LUT was anchored on.
                // Differences between pixels must be exact.
                let want_rel = delta(r, c) - delta(0, 0);
                let got_rel = got - fppn.phase_offset_rad[(0, 0)] as f64;
                assert!(
                    (got_rel - want_rel).abs() < 2e-3,
                    "{algo} ({r},{c}): {got_rel} vs {want_rel}"
                );
            }
        }
        // The LUT is anchored on the centre region (rows 1..4, cols 2..5 of 6×7): there the map is
        // ≈ 0 (median), i.e. the map is the per-pixel deviation, not the global delay.
        let mut v: Vec<f32> = fppn
            .phase_offset_rad
            .slice(ndarray::s![1..4, 2..5])
            .iter()
            .copied()
            .collect();
        v.sort_by(f32::total_cmp);
        assert!(
            v[v.len() / 2].abs() < 2e-3,
            "centre median {}",
            v[v.len() / 2]
        );
        // Pipeline with LUT + FPPN: every pixel at the true distance for another target distance.
        let cfg = PipelineConfig {
            algorithm: algo,
            ..PipelineConfig::default()
        };
        let mut p = Pipeline::new(
            rows,
            cols,
            cfg,
            Calibration {
                crosstalk: None,
                offset: None,
                wiggling: Some(lut),
                fppn: Some(fppn),
            },
        )
        .unwrap();
        let d = 1.3;
        let raw = capture(
            rows,
            cols,
            algo.phases_deg(),
            distance_to_phase_rad(d, F) + delay,
            delta,
            0.05,
        );
        let f = p.process(raw.view()).unwrap();
        for &v in f.depth_m.iter() {
            assert!((v as f64 - d).abs() < 2e-3, "{algo}: {v} vs {d}");
        }
    }
    // FPPN extraction needs the algorithm's phases.
    let flat = capture(2, 2, &[0.0, 180.0], 1.0, |_, _| 0.0, 0.0);
    assert!(matches!(
        extract_fppn(
            flat.view(),
            &ExtractionOptions::new(Algorithm::TwoPhase, &[0.0, 180.0], 0.5, F, 12)
        ),
        Err(CoreError::InvalidPhases { .. })
    ));
    let _ = wrap_phase(0.0);
}

#[test]
fn lut_from_any_equally_spaced_phase_count() {
    // N = 8, 9, 20 phases, starting away from 0°: same LUT quality as the 24-phase capture.
    let d0 = 0.9;
    let delay = 0.25;
    let phi0 = distance_to_phase_rad(d0, F);
    for (n, start) in [(8usize, 0.0f64), (9, 7.5), (20, 3.0)] {
        let phases: Vec<f64> = (0..n)
            .map(|k| start + 360.0 * k as f64 / n as f64)
            .collect();
        let corr = capture(4, 4, &phases, phi0 + delay, |_, _| 0.0, 0.06);
        for algo in Algorithm::ALL {
            let lut = extract_wiggling(
                corr.view(),
                &ExtractionOptions::new(algo, &phases, d0, F, 12).lut_size(128),
            )
            .unwrap();
            for i in 0..41 {
                let true_tof = TAU * i as f64 / 41.0;
                let t = capture(1, 1, algo.phases_deg(), true_tof + delay, |_, _| 0.0, 0.06);
                let u: Vec<f64> = t.iter().map(|v| v - 2048.0).collect();
                let m = measured_phase(algo, &u);
                let err = wrap_to_pi(lut.correct(m) - true_tof);
                assert!(err.abs() < 5e-4, "N {n} {algo}: err {err} at {true_tof}");
            }
        }
    }
}

#[test]
fn nphase_frame_matches_scalar() {
    let phases: Vec<f64> = (0..24).map(|k| 15.0 * k as f64).collect();
    let cap = capture(
        3,
        4,
        &phases,
        2.5,
        |r, c| 0.1 * r as f64 - 0.05 * c as f64,
        0.0,
    );
    let (ph, amp) = tofprox_core::phasor::nphase_frame(cap.view(), &phases).unwrap();
    let rad: Vec<f64> = phases.iter().map(|p| p.to_radians()).collect();
    for r in 0..3 {
        for c in 0..4 {
            let s: Vec<f64> = (0..24).map(|k| cap[(k, r, c)]).collect();
            let (p, a) = tofprox_core::phasor::nphase(&s, &rad).unwrap();
            assert!((p - ph[(r, c)]).abs() < 1e-9 && (a - amp[(r, c)]).abs() < 1e-9);
            assert!(
                wrap_to_pi(p - wrap_phase(2.5 + 0.1 * r as f64 - 0.05 * c as f64)).abs() < 1e-9
            );
            assert!((a - 600.0).abs() < 1e-6);
        }
    }
    assert!(tofprox_core::phasor::nphase_frame(cap.view(), &phases[..23]).is_err());
}

/// A flat wall at `d0` seen through a 62° lens: each pixel's phase is that of its ray length plus
/// a per-pixel electrical delay. Through the lens the FPPN map is that delay; without the lens the
/// map stores the geometry as "phase noise" (the issue's −109 mm near the corner at 0.5 m).
#[test]
fn fppn_after_lens_correction_is_the_electrical_delay_only() {
    use tofprox_core::camera::{Distortion, Intrinsics, Plane};
    let (rows, cols) = (172, 224);
    let k = Intrinsics {
        distortion: Distortion {
            k1: -0.2,
            k2: 0.05,
            ..Distortion::default()
        },
        ..Intrinsics::pinhole_from_fov(rows, cols, 62.0).unwrap()
    };
    let rays = k.rays(0, 0, rows, cols).unwrap();
    let d0 = 0.5;
    let len = rays.ray_lengths_m(&Plane::fronto_parallel(d0));
    let delay = |r: usize, c: usize| 0.02 * ((r * 7 + c * 3) % 11) as f64 - 0.1;
    let phases = [0.0f64, 90.0, 180.0, 270.0];
    let cap = Array3::from_shape_fn((4, rows, cols), |(kk, r, c)| {
        let x = distance_to_phase_rad(len[(r, c)], F) + delay(r, c) - phases[kk].to_radians();
        2048.0 + 600.0 * x.cos()
    });
    let lens = extract_fppn(
        cap.view(),
        &ExtractionOptions::new(Algorithm::FourPhase, &phases, d0, F, 12).rays(&rays),
    )
    .unwrap();
    let plain = extract_fppn(
        cap.view(),
        &ExtractionOptions::new(Algorithm::FourPhase, &phases, d0, F, 12),
    )
    .unwrap();
    let mm_per_rad = 1000.0 * tofprox_core::phasor::unambiguous_range_m(F) / TAU;
    let mut worst = 0.0f64;
    for ((r, c), v) in lens.phase_offset_rad.indexed_iter() {
        worst = worst.max((*v as f64 - delay(r, c)).abs());
    }
    let corner = wrap_to_pi(plain.phase_offset_rad[(2, 2)] as f64 - delay(2, 2)) * mm_per_rad;
    println!(
        "FPPN through the lens: worst error {:.4} mm; without the lens the corner stores {corner:.1} mm of geometry",
        worst * mm_per_rad
    );
    assert!(worst * mm_per_rad < 0.01, "{worst}");
    assert!(corner > 80.0 && corner < 300.0, "{corner}");
    // Rays of another window are refused.
    let small = k.rays(0, 0, 10, 10).unwrap();
    assert!(
        extract_fppn(
            cap.view(),
            &ExtractionOptions::new(Algorithm::FourPhase, &phases, d0, F, 12).rays(&small)
        )
        .is_err()
    );
    // Wiggling through the lens: a pure sinusoid gives the constant global delay (here 0) even
    // though the centre pixels see the wall further away than d0.
    let lut = extract_wiggling(
        Array3::from_shape_fn((24, rows, cols), |(kk, r, c)| {
            let x = distance_to_phase_rad(len[(r, c)], F) - (15.0 * kk as f64).to_radians();
            2048.0 + 600.0 * x.cos()
        })
        .view(),
        &ExtractionOptions::new(Algorithm::FourPhase, &phases24(), d0, F, 12)
            .rays(&rays)
            .lut_size(64),
    )
    .unwrap();
    let max = lut
        .correction_rad
        .iter()
        .fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(
        (max as f64) * mm_per_rad < 0.05,
        "wiggling through the lens {max} rad"
    );
}

/// A sensor whose 2-phase pair has the canonical shifts `[0°, 270°]` (it shifts its illumination,
/// `PhaseConvention`): with an even harmonic in the correlation, `−g(φ − 270°) ≠ g(φ − 90°)`, so
/// its 2-phase wiggling differs from the `[0°, 90°]` pair's. The table extracted for its own pair
/// corrects it; the standard table does not (the test can fail).
#[test]
fn wiggling_is_extracted_for_the_sensors_own_two_phase_pair() {
    use tofprox_core::phasor::Quadrature;
    let delay = 0.4;
    let d0 = 0.6;
    let phi0 = distance_to_phase_rad(d0, F);
    let g = |x: f64| 600.0 * (x.cos() + 0.06 * (2.0 * x).cos() + 0.05 * (3.0 * x).cos());
    let corr = Array3::from_shape_fn((24, 3, 3), |(k, _, _)| {
        2048.0 + g(phi0 + delay - phases24()[k].to_radians())
    });
    for q in [
        Quadrature {
            x_sign: 1,
            y_sign: -1,
        },
        Quadrature {
            x_sign: -1,
            y_sign: -1,
        },
        Quadrature {
            x_sign: -1,
            y_sign: 1,
        },
    ] {
        let own = extract_wiggling(
            corr.view(),
            &ExtractionOptions::new(Algorithm::TwoPhase, &phases24(), d0, F, 12)
                .quadrature(q)
                .lut_size(256),
        )
        .unwrap();
        let standard = extract_wiggling(
            corr.view(),
            &ExtractionOptions::new(Algorithm::TwoPhase, &phases24(), d0, F, 12).lut_size(256),
        )
        .unwrap();
        let (a, b) = (
            if q.x_sign < 0 { PI } else { 0.0 },
            if q.y_sign < 0 { 1.5 * PI } else { 0.5 * PI },
        );
        let (mut worst_own, mut worst_std) = (0.0f64, 0.0f64);
        for i in 0..97 {
            let tof = TAU * i as f64 / 97.0;
            let (ua, ub) = (g(tof + delay - a), g(tof + delay - b));
            let m = tofprox_core::phasor::phase_2phase(
                f64::from(q.x_sign) * ua,
                f64::from(q.y_sign) * ub,
            );
            worst_own = worst_own.max(wrap_to_pi(own.correct(m) - tof).abs());
            worst_std = worst_std.max(wrap_to_pi(standard.correct(m) - tof).abs());
        }
        assert!(worst_own < 2e-4, "{q:?}: own table leaves {worst_own} rad");
        assert!(
            worst_std > 1e-2,
            "{q:?}: the standard table leaves only {worst_std} rad"
        );
    }
}
