//! The thesis's simulation results, asserted on the published shape and size.

use tofprox_model::figures::{self, Series};

fn ys(s: &Series, pred: impl Fn(f64) -> bool) -> Vec<f64> {
    s.points.iter().filter(|p| pred(p.0)).map(|p| p.1).collect()
}
fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}
fn mean_abs(v: &[f64]) -> f64 {
    v.iter().map(|x| x.abs()).sum::<f64>() / v.len().max(1) as f64
}
fn at(s: &Series, x: f64) -> f64 {
    s.points
        .iter()
        .min_by(|a, b| (a.0 - x).abs().total_cmp(&(b.0 - x).abs()))
        .map(|p| p.1)
        .unwrap_or(f64::NAN)
}

#[test]
fn fig_3_7_offset_makes_2phase_unusable_far_but_not_near() {
    let f = figures::fig_3_7().unwrap();
    let s2 = f.series("2-phase").unwrap();
    let near = ys(s2, |d| d <= 0.40);
    let far = ys(s2, |d| d >= 1.2);
    // unusable at larger distances: tens of centimetres
    assert!(
        max_abs(&far) > 20.0,
        "far 2-phase error {} cm",
        max_abs(&far)
    );
    // smaller deviation up close (a few cm at most)
    assert!(
        max_abs(&near) < 3.0,
        "near 2-phase error {} cm",
        max_abs(&near)
    );
    assert!(mean_abs(&far) > 10.0 * mean_abs(&near));
    // the error grows while the signal falls (45° phasor takes over)
    assert!(at(s2, 0.5).abs() < at(s2, 0.9).abs());
    // 4-phase cancels a common offset (0/180 symmetry)
    assert!(max_abs(&ys(f.series("4-phase").unwrap(), |_| true)) < 1e-6);
}

#[test]
fn fig_3_8_inl_minus_200_is_wiggling_like_and_spec_value_negligible() {
    let f = figures::fig_3_8().unwrap();
    let big = f.series("INL -200").unwrap();
    let q1: Vec<(f64, f64)> = big
        .points
        .iter()
        .copied()
        .filter(|p| p.0 > 2.0 && p.0 < 88.0)
        .collect();
    let (x_min, y_min) = q1
        .iter()
        .copied()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();
    let (x_max, y_max) = q1
        .iter()
        .copied()
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();
    assert!((x_min - 22.5).abs() <= 4.0, "minimum at {x_min}°");
    assert!((x_max - 67.5).abs() <= 4.0, "maximum at {x_max}°");
    assert!(y_min < -0.3 && y_max > 0.3, "extremes {y_min} / {y_max} cm");
    let peak = max_abs(&ys(big, |_| true));
    for k in 1..=8 {
        let x = 45.0 * k as f64;
        assert!(
            at(big, x).abs() < 0.05 * peak,
            "error at {x}° = {} cm",
            at(big, x)
        );
    }
    // mirrored in the next quadrant: same pattern every 90°
    assert!((at(big, 22.5 + 90.0) - at(big, 22.5)).abs() < 0.1 * peak);
    let spec = f.series("INL -1.744").unwrap();
    assert!(
        max_abs(&ys(spec, |_| true)) < 0.05,
        "spec INL error {} cm",
        max_abs(&ys(spec, |_| true))
    );
}

#[test]
fn fig_3_9_dnl_within_table_3_2_stays_well_below_1cm() {
    let f = figures::fig_3_9().unwrap();
    for name in ["2-phase, DNL", "4-phase, DNL"] {
        let e = ys(f.series(name).unwrap(), |_| true);
        assert!(max_abs(&e) < 4.0, "{name}: {} mm", max_abs(&e));
    }
    // the DNL does change the codes: the curves differ from quantisation alone
    let a = ys(f.series("2-phase, DNL").unwrap(), |_| true);
    let b = ys(f.series("2-phase, quantisation only").unwrap(), |_| true);
    assert!(a.iter().zip(&b).any(|(x, y)| (x - y).abs() > 0.05));
}

#[test]
fn fig_5_1_measured_like_waveform_error_about_2_percent_shrinking_same_shape() {
    let f = figures::fig_5_1().unwrap();
    for name in ["2-phase (simulated)", "4-phase (simulated)"] {
        let s = f.series(name).unwrap();
        let all = ys(s, |_| true);
        assert!(max_abs(&all) <= 2.6, "{name}: max {}%", max_abs(&all));
        assert!(
            max_abs(&all) >= 1.0,
            "{name}: wiggling visible, max {}%",
            max_abs(&all)
        );
        let near = ys(s, |d| d < 0.8);
        let far = ys(s, |d| d > 1.3);
        assert!(
            max_abs(&far) < 0.6 * max_abs(&near),
            "{name}: shrinking with distance"
        );
    }
    // same shape for 2- and 4-phase (noise-free means)
    let e2 = ys(f.series("2-phase mean").unwrap(), |_| true);
    let e4 = ys(f.series("4-phase mean").unwrap(), |_| true);
    let n = e2.len() as f64;
    let (m2, m4) = (e2.iter().sum::<f64>() / n, e4.iter().sum::<f64>() / n);
    let cov: f64 = e2.iter().zip(&e4).map(|(a, b)| (a - m2) * (b - m4)).sum();
    let v2: f64 = e2.iter().map(|a| (a - m2).powi(2)).sum();
    let v4: f64 = e4.iter().map(|b| (b - m4).powi(2)).sum();
    let r = cov / (v2 * v4).sqrt();
    assert!(r > 0.95, "2- vs 4-phase error correlation {r}");
}

#[test]
fn fig_5_8_background_light_sbi_hits_2phase_only() {
    let (f57, f58) = figures::fig_5_7_5_8().unwrap();
    let e2 = ys(f58.series("2-phase, 1 ms").unwrap(), |_| true);
    assert!(
        max_abs(&e2) >= 2.0 && max_abs(&e2) <= 8.0,
        "2-phase 1 ms: {} cm",
        max_abs(&e2)
    );
    let e2_short = ys(f58.series("2-phase, 0.5 ms").unwrap(), |_| true);
    assert!(max_abs(&e2_short) > 0.3 && max_abs(&e2_short) < max_abs(&e2));
    for name in ["4-phase, 0.5 ms", "4-phase, 1 ms"] {
        assert!(
            max_abs(&ys(f58.series(name).unwrap(), |_| true)) < 0.01,
            "{name} affected"
        );
    }
    // fig. 5.7, calculated − ground truth in mm: 4-phase on the identity, 2-phase off it by the
    // fig. 5.8 error
    let d4 = f57.series("4-phase, 1 ms").unwrap();
    assert!(d4.points.iter().all(|(_, e_mm)| e_mm.abs() < 0.1));
    let d2 = ys(f57.series("2-phase, 1 ms").unwrap(), |_| true);
    assert!((max_abs(&d2) - 10.0 * max_abs(&e2)).abs() < 1e-9 * max_abs(&d2));
    assert!(
        ys(f57.series("identity").unwrap(), |_| true)
            .iter()
            .all(|e| *e == 0.0)
    );
}

#[test]
fn sbi_error_vanishes_without_background_light_below_threshold() {
    // Same model as fig. 5.8 but no ambient: taps stay below the SBI threshold at 1 m.
    use tofprox_model::{CaptureRequest, Scene, SensorGeometry, Simulator};
    let m = figures::fig_5_8_model().unwrap();
    let g = SensorGeometry::irs1645().window(86, 112, 1, 1).unwrap();
    let sim = Simulator::new(&m, g, 1).unwrap();
    let c = sim
        .expected(&Scene::wall(1.0, 1.0), &CaptureRequest::four_phase(1000.0))
        .unwrap();
    let v: Vec<f64> = c.iter().copied().collect();
    let z2 = figures::depth_2phase(&v, 2048.0);
    let z4 = figures::depth_4phase(&v);
    assert!((z2 - 1.0).abs() < 1e-6 && (z4 - 1.0).abs() < 1e-6);
}
