//! The pipeline against its references: every level bit-exact, the phase table, validity.

use super::*;
use ndarray::{Array2, Array3, ShapeBuilder};

fn synth(phi: f64, amp: f64, rows: usize, cols: usize, phases: &[f64]) -> Array3<f64> {
    tofprox_testkit::frames::ideal_codes(phi, amp, 2048.0, (rows, cols), phases)
}

/// Every phase convention: a capture recorded as `[0°, 90°(, 180°, 270°)]` by a sensor with
/// that convention has other canonical shifts; relabelled and evaluated with their
/// quadrature it gives the canonical depth — on every SIMD level.
#[test]
fn every_phase_convention_gives_the_same_depth() {
    use crate::phasor::{PhaseConvention, ShiftedSignal};
    for algo in Algorithm::ALL {
        for shifted in [ShiftedSignal::Demodulation, ShiftedSignal::Illumination] {
            for sign in [1, -1] {
                let conv = PhaseConvention { shifted, sign };
                let canonical: Vec<f64> = algo
                    .phases_deg()
                    .iter()
                    .map(|&l| conv.canonical_deg(l))
                    .collect();
                let q = Quadrature::of_canonical(&canonical, algo).unwrap();
                assert_eq!(
                    q == Quadrature::STANDARD,
                    conv.is_canonical(),
                    "{conv:?} -> {q:?}"
                );
                let cfg = PipelineConfig {
                    algorithm: algo,
                    ..Default::default()
                };
                let mut p = Pipeline::new(2, 9, cfg, Calibration::default()).unwrap();
                p.set_quadrature(q);
                for d in [0.07, 0.5, 0.93, 1.5, 1.8] {
                    let phi = phasor::distance_to_phase_rad(d, 80e6);
                    // the sensor's images: u_k = A·cos(φ − θ_c(label_k))
                    let raw = synth(phi, 800.0, 2, 9, &canonical);
                    for level in SimdLevel::ALL.iter().filter(|l| l.is_supported()) {
                        p.set_simd_level(*level).unwrap();
                        let f = p.process(raw.view()).unwrap();
                        for &dm in f.depth_m.iter() {
                            assert!((dm as f64 - d).abs() < 2e-4, "{algo} {conv:?}: {dm} vs {d}");
                        }
                    }
                    // without the quadrature the depth is wrong (the test can fail)
                    if !conv.is_canonical() && (d == 0.5 || d == 1.5) {
                        let mut plain = Pipeline::new(2, 9, cfg, Calibration::default()).unwrap();
                        let f = plain.process(raw.view()).unwrap();
                        assert!((f.depth_m[(0, 0)] as f64 - d).abs() > 0.05, "{conv:?}");
                    }
                }
            }
        }
    }
}

#[test]
fn phase_convention_labels_round_trip() {
    use crate::phasor::{PhaseConvention, ShiftedSignal};
    for shifted in [ShiftedSignal::Demodulation, ShiftedSignal::Illumination] {
        for sign in [1, -1] {
            let c = PhaseConvention { shifted, sign };
            for l in [0.0, 15.0, 90.0, 180.0, 270.0, 345.0] {
                let back = c.label_deg(c.canonical_deg(l));
                assert!((back - l).abs() < 1e-9, "{c:?} {l} {back}");
            }
        }
    }
    let ill = PhaseConvention {
        shifted: ShiftedSignal::Illumination,
        sign: 1,
    };
    assert_eq!(ill.canonical_deg(90.0), 270.0);
    assert!(
        PhaseConvention {
            shifted: ShiftedSignal::Demodulation,
            sign: 0
        }
        .validate()
        .is_err()
    );
    assert_eq!(
        Quadrature::of_canonical(&[0.0, 45.0], Algorithm::TwoPhase),
        None
    );
    assert_eq!(
        Quadrature::of_canonical(&[0.0, 90.0, 270.0, 180.0], Algorithm::FourPhase),
        None
    );
    // real-world float shifts: π/2 stored as f32 radians is 90.0000025°, a −0° is 359.99…°
    let f32_quarter_deg = f64::from(std::f32::consts::FRAC_PI_2).to_degrees();
    assert!((f32_quarter_deg - 90.0).abs() > 1e-6);
    assert_eq!(
        Quadrature::of_canonical(&[360.0 - 1e-9, f32_quarter_deg], Algorithm::TwoPhase),
        Some(Quadrature::STANDARD)
    );
    // one register step (360°/4096) off is another shift, not the nominal one
    assert_eq!(
        Quadrature::of_canonical(&[0.0, 90.0 + 360.0 / 4096.0], Algorithm::TwoPhase),
        None
    );
}

#[test]
fn ideal_2phase_and_4phase_depth() {
    for algo in Algorithm::ALL {
        let cfg = PipelineConfig {
            algorithm: algo,
            ..Default::default()
        };
        let mut p = Pipeline::new(3, 5, cfg, Calibration::default()).unwrap();
        for d in [0.1, 0.5, 0.93, 1.5, 1.8] {
            let phi = phasor::distance_to_phase_rad(d, 80e6);
            let raw = synth(phi, 800.0, 3, 5, algo.phases_deg());
            let f = p.process(raw.view()).unwrap();
            for (&dm, &fl) in f.depth_m.iter().zip(f.flags.iter()) {
                assert_eq!(fl, 0);
                assert!((dm as f64 - d).abs() < 2e-4, "{algo}: {dm} vs {d}");
            }
            let mm = f.depth_mm[(1, 2)] as f64;
            assert!((mm - d * 1000.0).abs() <= 1.0);
            assert!((f.amplitude_lsb[(0, 0)] as f64 - 800.0).abs() < 0.5);
            // the scalar rounding is the kernel's, pixel for pixel
            assert_eq!(f.depth_m.mapv(depth_m_to_mm), f.depth_mm);
            assert_eq!(
                median_valid_m(f.depth_m.view(), f.flags.view()),
                f.median_valid_depth_m()
            );
        }
    }
    assert_eq!(depth_m_to_mm(0.0), 0);
    assert_eq!(depth_m_to_mm(f32::NAN), 0);
    assert_eq!(depth_m_to_mm(1e-5), 1);
    assert_eq!(depth_m_to_mm(65.6), 0);
    assert_eq!(depth_m_to_mm(0.0125), 12, "ties to even, as the kernel");
}

#[test]
fn u16_f32_f64_and_noncontiguous_agree() {
    let cfg = PipelineConfig::default();
    let mut p = Pipeline::new(4, 6, cfg, Calibration::default()).unwrap();
    let phi = 2.2;
    let raw = synth(phi, 700.0, 4, 6, &[0.0, 90.0]).mapv(|v| v.round());
    let a = p.process(raw.view()).unwrap().clone();
    let b = p.process(raw.mapv(|v| v as u16).view()).unwrap().clone();
    let c = p.process(raw.mapv(|v| v as f32).view()).unwrap().clone();
    assert_eq!(a, b);
    assert_eq!(a, c);
    // Fortran-order (non-contiguous per image) input goes through the staging path.
    let mut f = Array3::<f64>::zeros((2, 4, 6).f());
    f.assign(&raw);
    let d = p.process(f.view()).unwrap().clone();
    assert_eq!(a, d);
}

#[test]
fn all_simd_levels_agree_to_the_bit() {
    // Odd sizes exercise the vector tail; phases over the whole circle, saturated and
    // low-amplitude pixels, an FPPN map and a wiggling table.
    let (rows, cols) = (13, 37);
    let lut = WigglingLut {
        algorithm: Algorithm::TwoPhase,
        correction_rad: ndarray::Array1::from_shape_fn(360, |i| {
            0.4 + 0.05 * (i as f32 * 0.05).sin()
        }),
    };
    let fppn = FppnMap {
        phase_offset_rad: Array2::from_shape_fn((rows, cols), |(r, c)| {
            0.3 * ((r * 7 + c) % 5) as f32 - 0.6
        }),
    };
    let raw = Array3::from_shape_fn((4, rows, cols), |(k, r, c)| {
        let i = r * cols + c;
        let phi = i as f64 * 0.013;
        let amp = if i % 17 == 3 { 3.0 } else { 900.0 };
        let v = 2048.0 + amp * (phi - k as f64 * std::f64::consts::FRAC_PI_2).cos();
        if i % 23 == 5 { 4095 } else { v.round() as u16 }
    });
    for (algorithm, with_fppn) in [(Algorithm::TwoPhase, false), (Algorithm::FourPhase, true)] {
        let cal = Calibration {
            wiggling: Some(WigglingLut {
                algorithm,
                ..lut.clone()
            }),
            fppn: with_fppn.then(|| fppn.clone()),
            ..Default::default()
        };
        let cfg = PipelineConfig {
            algorithm,
            ..Default::default()
        };
        let mut p = Pipeline::new(rows, cols, cfg, cal).unwrap();
        p.set_simd_level(SimdLevel::Generic).unwrap();
        let reference = p.process(raw.view()).unwrap().clone();
        let reference_f64 = p.process(raw.mapv(f64::from).view()).unwrap().clone();
        assert_eq!(reference, reference_f64);
        assert!(reference.flags.iter().any(|&f| f == 0));
        assert!(reference.flags.iter().any(|&f| f & FLAG_SATURATED != 0));
        for level in SimdLevel::supported() {
            p.set_simd_level(level).unwrap();
            assert_eq!(p.simd_level(), level);
            let f = p.process(raw.view()).unwrap();
            assert_eq!(*f, reference, "{algorithm} {level}");
            let f = p.process(raw.mapv(f64::from).view()).unwrap();
            assert_eq!(*f, reference, "{algorithm} {level} f64");
        }
    }
    for level in SimdLevel::ALL {
        let mut p = Pipeline::new(1, 1, PipelineConfig::default(), Calibration::default()).unwrap();
        assert_eq!(p.set_simd_level(level).is_ok(), level.is_supported());
    }
    assert!("sse9".parse::<SimdLevel>().is_err());
    assert_eq!("avx2".parse::<SimdLevel>().ok(), Some(SimdLevel::Avx2));
}

#[test]
fn phase_table_matches_f64_atan2() {
    // Without calibration the table is atan2 alone: dense phases over the whole circle, both
    // algorithms, radii from the low-amplitude limit to full scale, against f64 atan2 of the
    // same f32 offset-corrected values (module docs: interpolation 3.1e-7 rad, f32 rounding
    // of the table values and of t ≈ 5e-7 rad).
    let n = 4099;
    for algo in Algorithm::ALL {
        let cfg = PipelineConfig {
            algorithm: algo,
            min_amplitude_lsb: 0.0,
            ..Default::default()
        };
        let mut p = Pipeline::new(1, n, cfg, Calibration::default()).unwrap();
        let mut worst = 0.0f64;
        for amp in [12.0, 300.0, 2000.0] {
            let raw = Array3::from_shape_fn((algo.raw_images(), 1, n), |(k, _, c)| {
                let phi = std::f64::consts::TAU * c as f64 / n as f64 + 1e-3;
                let v = 2048.0 + amp * (phi - k as f64 * std::f64::consts::FRAC_PI_2).cos();
                f64::from(v as f32)
            });
            let f = p.process(raw.view()).unwrap();
            for c in 0..n {
                let u = |k: usize| raw[(k, 0, c)] as f32;
                let (x, y) = if algo == Algorithm::FourPhase {
                    (u(0) - u(2), u(1) - u(3))
                } else {
                    (u(0) - 2048.0, u(1) - 2048.0)
                };
                let want = phasor::wrap_phase(f64::from(y).atan2(f64::from(x)));
                let got = f64::from(f.phase_rad[(0, c)]);
                assert!((0.0..std::f64::consts::TAU).contains(&got), "{got}");
                worst = worst.max(wrap_to_pi(got - want).abs());
            }
        }
        assert!(worst < 2e-6, "{algo}: worst {worst} rad");
    }
}

#[test]
fn lut_resampling_matches_linear_periodic_interpolation() {
    // A 360-bin table (not a power of two) with a steep feature and a 2π-wrapped stretch:
    // the kernel's 4096-bin value+slope table must reproduce WigglingLut::correct.
    let lut = WigglingLut {
        algorithm: Algorithm::TwoPhase,
        correction_rad: ndarray::Array1::from_shape_fn(360, |i| {
            let x = i as f32 * std::f32::consts::TAU / 360.0;
            let v = 3.0
                + 0.2 * (3.0 * x).sin()
                + if (100..110).contains(&i) {
                    0.05 * (i - 100) as f32
                } else {
                    0.0
                };
            wrap_to_pi(v as f64) as f32
        }),
    };
    let cal = Calibration {
        wiggling: Some(lut.clone()),
        ..Default::default()
    };
    let cfg = PipelineConfig {
        min_amplitude_lsb: 0.0,
        ..Default::default()
    };
    let n = 1000;
    let mut p = Pipeline::new(1, n, cfg, cal).unwrap();
    let raw = Array3::from_shape_fn((2, 1, n), |(k, _, c)| {
        let phi = std::f64::consts::TAU * c as f64 / n as f64;
        2048.0 + 1500.0 * (phi - k as f64 * std::f64::consts::FRAC_PI_2).cos()
    });
    let f = p.process(raw.view()).unwrap();
    let mut worst = 0.0f64;
    for c in 0..n {
        let m = phasor::phase_2phase(raw[(0, 0, c)] - 2048.0, raw[(1, 0, c)] - 2048.0);
        let want = lut.correct(m);
        let d = wrap_to_pi(f.phase_rad[(0, c)] as f64 - want).abs();
        worst = worst.max(d);
    }
    // fast atan2 (1e-4) + f32 + resampling of a piecewise-linear table at 4096 bins.
    assert!(worst < 2e-4, "worst deviation {worst} rad");
}

#[test]
fn validity_flags() {
    let cfg = PipelineConfig {
        min_amplitude_lsb: 50.0,
        ..Default::default()
    };
    let mut p = Pipeline::new(1, 5, cfg, Calibration::default()).unwrap();
    let mut raw = Array3::<f64>::from_elem((2, 1, 5), 2048.0 + 300.0);
    raw[(0, 0, 0)] = 4095.0; // saturated high
    raw[(1, 0, 1)] = 0.0; // saturated low
    raw[(0, 0, 2)] = f64::NAN;
    raw[(0, 0, 3)] = 2048.0; // low amplitude
    raw[(1, 0, 3)] = 2050.0;
    let f = p.process(raw.view()).unwrap();
    assert_eq!(f.flags[(0, 0)], FLAG_SATURATED | FLAG_INVALID);
    assert_eq!(f.flags[(0, 1)], FLAG_SATURATED | FLAG_INVALID);
    assert_ne!(f.flags[(0, 2)] & (FLAG_NON_FINITE | FLAG_INVALID), 0);
    assert_eq!(f.flags[(0, 3)], FLAG_LOW_AMPLITUDE | FLAG_INVALID);
    assert_eq!(f.flags[(0, 4)], 0);
    for i in 0..4 {
        assert_eq!(f.depth_mm[(0, i)], 0);
        assert_eq!(f.depth_m[(0, i)], 0.0);
    }
    assert!(f.depth_m.iter().all(|v| v.is_finite()));
    assert!(f.depth_mm[(0, 4)] > 0);
}

#[test]
fn shape_errors_not_panics() {
    let cfg = PipelineConfig {
        algorithm: Algorithm::FourPhase,
        ..Default::default()
    };
    let mut p = Pipeline::new(2, 2, cfg, Calibration::default()).unwrap();
    assert!(matches!(
        p.process(Array3::<u16>::zeros((2, 2, 2)).view()),
        Err(CoreError::ShapeMismatch { .. })
    ));
    assert!(p.process(Array3::<u16>::zeros((4, 3, 2)).view()).is_err());
    assert!(p.process(Array3::<u16>::zeros((0, 0, 0)).view()).is_err());
    let bad = Calibration {
        offset: Some(OffsetCalibration {
            dark_lsb: Array2::zeros((3, 3)),
        }),
        ..Default::default()
    };
    assert!(Pipeline::new(2, 2, cfg, bad).is_err());
    assert!(Pipeline::new(0, 2, cfg, Calibration::default()).is_err());
    assert!(Pipeline::new(usize::MAX, 2, cfg, Calibration::default()).is_err());
    assert!(Pipeline::new(1 << 14, 1 << 13, cfg, Calibration::default()).is_err());
    let bad_cfg = PipelineConfig {
        modulation_hz: f64::NAN,
        ..cfg
    };
    assert!(Pipeline::new(2, 2, bad_cfg, Calibration::default()).is_err());
    let wrong_algo = Calibration {
        wiggling: Some(WigglingLut {
            algorithm: Algorithm::TwoPhase,
            correction_rad: ndarray::Array1::zeros(16),
        }),
        ..Default::default()
    };
    assert!(Pipeline::new(2, 2, cfg, wrong_algo).is_err());
}
