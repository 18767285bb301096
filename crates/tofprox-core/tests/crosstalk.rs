//! Cover-window crosstalk compensation in the pipeline, against the closed-form phasor sum
//! (eq. 2.2/2.3: every return adds `A cos(φ − θ_k)` to raw image k).

use std::f64::consts::PI;

use ndarray::{Array2, Array3};
use tofprox_core::calib::OffsetCalibration;
use tofprox_core::crosstalk::{
    CROSSTALK_PHASES_DEG, CrosstalkCalibration, CrosstalkCapture, CrosstalkMonitor,
    CrosstalkStatus, extract_crosstalk, residual_ratio,
};
use tofprox_core::pipeline::{Calibration, FLAG_SATURATED, Pipeline, PipelineConfig};
use tofprox_core::proximity::Roi;
use tofprox_core::{Algorithm, SPEED_OF_LIGHT_M_PER_S};

const F_HZ: f64 = 80e6;
const DARK: f64 = 2030.0;
const ROWS: usize = 4;
const COLS: usize = 6;
/// Crosstalk of the window (LSB per µs, per pixel varying) at 3 mm.
const XT_LSB_PER_US: f64 = 0.05;

fn phi_of(d_m: f64) -> f64 {
    4.0 * PI * F_HZ * d_m / SPEED_OF_LIGHT_M_PER_S
}

fn xt_amp(c: usize, smudge: f64) -> f64 {
    XT_LSB_PER_US * (1.0 + 0.1 * c as f64) * (1.0 + smudge)
}

/// Raw codes: dark + target return + window return, at `phases`.
fn frames(phases: &[f64], t_us: f64, target: Option<(f64, f64)>, smudge: f64) -> Array3<f64> {
    Array3::from_shape_fn((phases.len(), ROWS, COLS), |(k, _, c)| {
        let th = phases[k].to_radians();
        let mut v = DARK + xt_amp(c, smudge) * t_us * (phi_of(0.003) - th).cos();
        if let Some((d, a)) = target {
            v += a * (phi_of(d) - th).cos();
        }
        v
    })
}

fn calibrated() -> CrosstalkCalibration {
    let dark = OffsetCalibration {
        dark_lsb: Array2::from_elem((ROWS, COLS), DARK as f32),
    };
    // nothing in range at two exposures, 4-phase
    let (a, b) = (
        frames(&CROSSTALK_PHASES_DEG, 200.0, None, 0.0),
        frames(&CROSSTALK_PHASES_DEG, 500.0, None, 0.0),
    );
    let caps = [
        CrosstalkCapture {
            codes: a.view(),
            phases_deg: &CROSSTALK_PHASES_DEG,
            exposure_us: 200.0,
        },
        CrosstalkCapture {
            codes: b.view(),
            phases_deg: &CROSSTALK_PHASES_DEG,
            exposure_us: 500.0,
        },
    ];
    extract_crosstalk(&caps, Some(&dark), 12).unwrap()
}

fn pipeline(algorithm: Algorithm, crosstalk: Option<CrosstalkCalibration>) -> Pipeline {
    let cfg = PipelineConfig {
        algorithm,
        min_amplitude_lsb: 0.0,
        ..PipelineConfig::default()
    };
    let cal = Calibration {
        offset: Some(OffsetCalibration {
            dark_lsb: Array2::from_elem((ROWS, COLS), DARK as f32),
        }),
        crosstalk,
        ..Calibration::default()
    };
    Pipeline::new(ROWS, COLS, cfg, cal).unwrap()
}

#[test]
fn extracted_crosstalk_is_the_window_phasor_per_microsecond() {
    let x = calibrated();
    for c in 0..COLS {
        for (k, th) in CROSSTALK_PHASES_DEG.iter().enumerate() {
            let want = xt_amp(c, 0.0) * (phi_of(0.003) - th.to_radians()).cos();
            let got = f64::from(x.lsb_per_us[[k, 1, c]]);
            assert!((got - want).abs() < 1e-6, "col {c} θ {th}: {got} vs {want}");
        }
    }
}

#[test]
fn compensation_restores_a_weak_far_target_in_both_algorithms() {
    // a weak target at 1.2 m (amplitude 20 LSB) behind a window return of ~25-37 LSB
    let (t_us, d, a) = (500.0, 1.2, 20.0);
    for algorithm in Algorithm::ALL {
        let raw = frames(algorithm.phases_deg(), t_us, Some((d, a)), 0.0);
        let mut plain = pipeline(algorithm, None);
        let wrong = plain.process(raw.view()).unwrap().depth_m[[1, 2]];
        assert!(
            (f64::from(wrong) - d).abs() > 0.3,
            "{algorithm}: uncompensated reads {wrong}"
        );
        let mut p = pipeline(algorithm, Some(calibrated()));
        assert!(p.process(raw.view()).is_err(), "exposure required");
        p.set_exposure_us(t_us).unwrap();
        let f = p.process(raw.view()).unwrap();
        for c in 0..COLS {
            let got = f64::from(f.depth_m[[1, c]]);
            assert!((got - d).abs() < 1e-3, "{algorithm} col {c}: {got} vs {d}");
            assert!((f64::from(f.amplitude_lsb[[1, c]]) - a).abs() < 0.01);
        }
        // scaled to another exposure without recalibrating
        let raw = frames(algorithm.phases_deg(), 150.0, Some((d, a)), 0.0);
        p.set_exposure_us(150.0).unwrap();
        let got = f64::from(p.process(raw.view()).unwrap().depth_m[[2, 3]]);
        assert!((got - d).abs() < 1e-3, "{algorithm} at 150 µs: {got}");
    }
}

#[test]
fn saturated_codes_stay_flagged_after_compensation() {
    let mut raw = frames(&[0.0, 90.0], 500.0, Some((0.5, 10.0)), 0.0);
    raw[[0, 0, 0]] = 4095.0;
    raw[[1, 1, 1]] = 0.0;
    let mut p = pipeline(Algorithm::TwoPhase, Some(calibrated()));
    p.set_exposure_us(500.0).unwrap();
    let f = p.process(raw.view()).unwrap();
    assert_ne!(f.flags[[0, 0]] & FLAG_SATURATED, 0);
    assert_ne!(f.flags[[1, 1]] & FLAG_SATURATED, 0);
    assert_eq!(f.flags[[2, 2]] & FLAG_SATURATED, 0);
}

#[test]
fn a_smudge_that_doubles_the_crosstalk_is_reported_and_can_be_followed() {
    let x = calibrated();
    for algorithm in Algorithm::ALL {
        let mut p = pipeline(algorithm, Some(calibrated()));
        p.set_exposure_us(400.0).unwrap();
        // nothing in range, with the window as calibrated (smudge 0) or smudged (1)
        let residual = |p: &mut Pipeline, smudge: f64| {
            let raw = frames(algorithm.phases_deg(), 400.0, None, smudge);
            let f = p.process(raw.view()).unwrap();
            residual_ratio(f, &x, algorithm, Roi::default(), 400.0).unwrap()
        };
        let r0 = residual(&mut p, 0.0);
        assert!(r0.abs() < 1e-3, "{algorithm}: {r0}");
        // smudged: crosstalk doubled → residual ≈ +1
        let r1 = residual(&mut p, 1.0);
        assert!((r1 - 1.0).abs() < 0.01, "{algorithm}: {r1}");
        let mut m = CrosstalkMonitor::default();
        let mut s = m.status();
        for _ in 0..10 {
            s = m.update(r1);
        }
        assert!(
            matches!(s, CrosstalkStatus::Changed { residual_ratio } if residual_ratio > 0.9),
            "{s:?}"
        );
        assert!(s.message().contains("smudged"));
        // following it: the scale makes the smudged window read as calibrated
        p.set_crosstalk_scale(m.suggested_scale()).unwrap();
        let r2 = residual(&mut p, 1.0);
        assert!(r2.abs() < 0.01, "{algorithm}: {r2}");
    }
}
