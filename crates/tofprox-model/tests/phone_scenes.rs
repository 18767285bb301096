//! The phone scenes' physics against closed-form expectations (not against the model
//! itself): cover-window crosstalk phasor, amplitude ∝ ρ/d², ambient shot noise,
//! grazing table geometry, swipe timing, and the scenes' ground truth.

use std::f64::consts::PI;

use rand::SeedableRng;
use rand::rngs::SmallRng;
use tofprox_model::{
    CaptureRequest, CoverWindow, Expect, ModelConfig, Motion, Scene, SceneScript, ScriptKind,
    SensorGeometry, Simulator, phone_scenes,
};

const C: f64 = 299_792_458.0;
const F_HZ: f64 = 80e6;
const MID: f64 = 2048.0;
/// `[sensor]` constants of every model: e-/µs of a ρ = 1 target at 1 m, LSB per e-.
const SIGNAL_E_PER_US: f64 = 40.0;
const LSB_PER_E: f64 = 3.0e-3;

fn window(n: usize) -> SensorGeometry {
    SensorGeometry::irs1645().window(80, 100, n, n).unwrap()
}

/// The ideal sinusoidal sensor (eq. 2.2/2.3) plus the named effects.
fn ideal_with(effects: &[&str]) -> ModelConfig {
    let mut m = ModelConfig::ideal();
    for id in effects {
        m.set_enabled(id, true).unwrap();
    }
    m
}

/// Closed-form 4-phase code of one return: mid + A cos(φ − θ_k) (eq. 2.3 convention).
fn four_phase_codes(a_lsb: f64, phi: f64) -> [f64; 4] {
    [0.0f64, 90.0, 180.0, 270.0].map(|t| MID + a_lsb * (phi - t.to_radians()).cos())
}

fn assert_codes(got: &ndarray::Array3<f64>, want: [f64; 4], tol: f64, what: &str) {
    for (k, w) in want.iter().enumerate() {
        for v in got.index_axis(ndarray::Axis(0), k) {
            assert!(
                (v - w).abs() <= tol,
                "{what}: image {k}: {v} vs closed form {w}"
            );
        }
    }
}

fn flat_window() -> CoverWindow {
    CoverWindow {
        e_per_us: 20.0,
        smudge_rel: 0.0,
        window_distance_mm: 4.0,
        gradient_rel: 0.0,
    }
}

#[test]
fn crosstalk_is_a_constant_phasor_at_the_window_scaled_by_exposure_and_smudge() {
    // nothing in range (reflectivity 0): only the window's return is left
    let empty = Scene::wall(5.0, 0.0);
    for (w, t_us) in [
        (flat_window(), 100.0),
        (flat_window(), 400.0),
        (
            CoverWindow {
                smudge_rel: 1.0,
                ..flat_window()
            },
            100.0,
        ),
    ] {
        let mut m = ideal_with(&[]);
        w.apply(&mut m).unwrap();
        let sim = Simulator::new(&m, window(4), 1).unwrap();
        let got = sim
            .expected(&empty, &CaptureRequest::four_phase(t_us))
            .unwrap();
        // N_xt = e_per_us (1 + smudge) t; differential amplitude N_xt · lsb (K = 1, C = cos)
        let a = 20.0 * (1.0 + w.smudge_rel) * t_us * LSB_PER_E;
        let phi = 4.0 * PI * F_HZ * 0.004 / C;
        assert_codes(&got, four_phase_codes(a, phi), 1e-6, "window return");
    }
    // dark captures see no crosstalk (it is illumination)
    let mut m = ideal_with(&[]);
    flat_window().apply(&mut m).unwrap();
    let sim = Simulator::new(&m, window(4), 1).unwrap();
    let dark = sim
        .expected(&empty, &CaptureRequest::dark(2, 400.0))
        .unwrap();
    assert!(dark.iter().all(|&v| (v - MID).abs() < 1e-9));
}

#[test]
fn crosstalk_adds_to_the_target_phasor_and_to_the_shot_noise() {
    let mut m = ideal_with(&["signal_falloff"]);
    flat_window().apply(&mut m).unwrap();
    let sim = Simulator::new(&m, window(4), 1).unwrap();
    let (d, rho, t_us) = (0.8, 0.5, 200.0);
    let got = sim
        .expected(&Scene::wall(d, rho), &CaptureRequest::four_phase(t_us))
        .unwrap();
    let (a_t, phi_t) = (
        SIGNAL_E_PER_US * t_us * rho / (d * d) * LSB_PER_E,
        4.0 * PI * F_HZ * d / C,
    );
    let (a_x, phi_x) = (20.0 * t_us * LSB_PER_E, 4.0 * PI * F_HZ * 0.004 / C);
    let want = [0.0f64, 90.0, 180.0, 270.0].map(|th| {
        let th = th.to_radians();
        MID + a_t * (phi_t - th).cos() + a_x * (phi_x - th).cos()
    });
    for (k, w) in want.iter().enumerate() {
        let v = got[[k, 0, 0]];
        assert!((v - w).abs() < 1e-6, "image {k}: {v} vs {w}");
    }
    // shot noise: var(u) = (N_A + N_B) g² = N_xt g² with nothing else in view (eq. 2.16)
    let mut m = ideal_with(&["shot_noise"]);
    CoverWindow {
        e_per_us: 200.0,
        ..flat_window()
    }
    .apply(&mut m)
    .unwrap();
    let sim = Simulator::new(&m, window(32), 1).unwrap();
    let t_us = 500.0;
    let mut rng = SmallRng::seed_from_u64(5);
    let cap = sim
        .capture(
            &Scene::wall(5.0, 0.0),
            &CaptureRequest::four_phase(t_us),
            &mut rng,
        )
        .unwrap();
    let mean = sim
        .expected(&Scene::wall(5.0, 0.0), &CaptureRequest::four_phase(t_us))
        .unwrap();
    let resid: Vec<f64> = cap.iter().zip(mean.iter()).map(|(a, b)| a - b).collect();
    let var = resid.iter().map(|r| r * r).sum::<f64>() / resid.len() as f64;
    let want = 200.0 * t_us * LSB_PER_E * LSB_PER_E;
    assert!((var / want - 1.0).abs() < 0.08, "var {var} vs {want}");
}

#[test]
fn crosstalk_follows_its_column_profile() {
    let mut m = ideal_with(&[]);
    CoverWindow {
        gradient_rel: 0.5,
        window_distance_mm: 0.0,
        ..flat_window()
    }
    .apply(&mut m)
    .unwrap();
    let g = SensorGeometry::irs1645();
    let sim = Simulator::new(&m, g, 1).unwrap();
    let got = sim
        .expected(&Scene::wall(5.0, 0.0), &CaptureRequest::two_phase(100.0))
        .unwrap();
    // φ_w = 0: image 0 holds the full amplitude, w(c) = 1 + 0.5 (c/223 − ½)
    for c in [0usize, 111, 223] {
        let w = 1.0 + 0.5 * (c as f64 / 223.0 - 0.5);
        let want = MID + 20.0 * 100.0 * LSB_PER_E * w;
        assert!((got[[0, 50, c]] - want).abs() < 1e-6, "col {c}");
        assert!((got[[1, 50, c]] - MID).abs() < 1e-6);
    }
}

#[test]
fn dark_targets_and_far_ceilings_return_rho_over_d_squared_at_the_wrapped_phase() {
    let m = ideal_with(&["signal_falloff"]);
    let sim = Simulator::new(&m, window(2), 1).unwrap();
    // black card 5 % at 3 cm, grey 18 % at 10 cm, dark hair 6 % at 2 cm, white ceiling
    // at 1.95 m (beyond c/2f = 1.874 m: the phase wraps), dark wall at 4 m
    for (d, rho, t_us) in [
        (0.03, 0.05, 20.0),
        (0.10, 0.18, 100.0),
        (0.02, 0.06, 10.0),
        (1.95, 0.9, 500.0),
        (4.0, 0.08, 500.0),
    ] {
        let got = sim
            .expected(&Scene::wall(d, rho), &CaptureRequest::four_phase(t_us))
            .unwrap();
        let a = SIGNAL_E_PER_US * t_us * rho / (d * d) * LSB_PER_E;
        let phi = (4.0 * PI * F_HZ * d / C).rem_euclid(2.0 * PI);
        assert_codes(
            &got,
            four_phase_codes(a, phi),
            1e-6,
            &format!("{d} m, ρ {rho}"),
        );
    }
    // the wrapped ceiling reads as a target at 1.95 − c/2f ≈ 7.6 cm
    let wrapped = 1.95 - C / (2.0 * F_HZ);
    assert!((wrapped - 0.076).abs() < 0.001);
}

#[test]
fn sunlight_adds_shot_noise_of_both_taps_but_no_signal() {
    let m = ideal_with(&["ambient_light", "shot_noise"]);
    let sim = Simulator::new(&m, window(32), 1).unwrap();
    let t_us = 100.0;
    for klux in [30.0, 100.0] {
        let req = CaptureRequest {
            ambient_klux: klux,
            ..CaptureRequest::four_phase(t_us)
        };
        let empty = Scene::wall(5.0, 0.0);
        let mean = sim.expected(&empty, &req).unwrap();
        assert!(
            mean.iter().all(|&v| (v - MID).abs() < 1e-9),
            "no phasor from unmodulated light"
        );
        let cap = sim
            .capture(&empty, &req, &mut SmallRng::seed_from_u64(9))
            .unwrap();
        let var = cap.iter().map(|v| (v - MID) * (v - MID)).sum::<f64>() / cap.len() as f64;
        // N_amb = 3 e-/µs/klux per tap; var(u) = (N_A + N_B) g² (eq. 2.16)
        let want = 2.0 * 3.0 * klux * t_us * LSB_PER_E * LSB_PER_E;
        assert!(
            (var / want - 1.0).abs() < 0.08,
            "{klux} klux: var {var} vs {want}"
        );
    }
}

#[test]
fn sunlight_through_the_sbi_gives_a_two_phase_only_error() {
    // 2.2.2.1 / 5.1.2.3: the SBI error depends on |C(φ − θ)|, so it is identical in the
    // 0° and 180° (90° and 270°) images: the 4-phase differences are untouched, the
    // 2-phase images are not
    let req = CaptureRequest {
        ambient_klux: 100.0,
        ..CaptureRequest::four_phase(500.0)
    };
    let codes = |effects: &[&str]| {
        let sim = Simulator::new(&ideal_with(effects), window(2), 1).unwrap();
        sim.expected(&Scene::wall(1.0, 0.5), &req).unwrap()
    };
    let with = codes(&["ambient_light", "sbi_asymmetry", "signal_falloff"]);
    let without = codes(&["ambient_light", "signal_falloff"]);
    for (k, j) in [(0, 2), (1, 3)] {
        let dw = with[[k, 0, 0]] - with[[j, 0, 0]];
        let dn = without[[k, 0, 0]] - without[[j, 0, 0]];
        assert!(
            (dw - dn).abs() < 1e-6,
            "4-phase difference {k}-{j}: {dw} vs {dn}"
        );
    }
    // 100 klux · 3 e-/µs/klux · 500 µs = 150 000 e- per tap ≫ Q_th = 60 000: the SBI injects
    let e0 = with[[0, 0, 0]] - without[[0, 0, 0]];
    assert!(e0.abs() > 0.1, "2-phase image 0 moved by the SBI: {e0} LSB");
}

#[test]
fn table_edge_is_a_grazing_plane_below_the_axis() {
    let s = SceneScript {
        kind: ScriptKind::TableEdge,
        object_reflectivity: 0.3,
        near_m: 0.02,
        far_m: 0.3,
        wall_distance_m: 2.0,
        wall_reflectivity: 0.5,
        ..SceneScript::default()
    };
    s.validate().unwrap();
    let Scene::DepthMap {
        distance_m,
        reflectivity,
    } = s.at(0.0)
    else {
        panic!("a table is a depth map");
    };
    let f_px = 112.0 / (30f64.to_radians()).tan();
    let (cr, cc) = (85.5, 111.5);
    // upper half: the wall
    assert_eq!(distance_m[[10, 50]], 2.0);
    // bottom row, centre column: the ray (x, y, 1) meets z = h / y
    let (r, c) = (171usize, 111usize);
    let (x, y) = ((c as f64 - cc) / f_px, (r as f64 - cr) / f_px);
    let norm = (1.0 + x * x + y * y).sqrt();
    let z = 0.02 / y;
    assert!((distance_m[[r, c]] - z * norm).abs() < 1e-9);
    // Lambertian at incidence θ_i: ρ cos θ_i with cos θ_i = y / |ray|
    assert!((reflectivity[[r, c]] - 0.3 * y / norm).abs() < 1e-9);
    // rows whose ray meets the table beyond its edge (z > 0.3 m) see the wall
    let r_edge = (cr + f_px * 0.02 / 0.3).floor() as usize;
    assert_eq!(distance_m[[r_edge - 1, c]], 2.0);
}

#[test]
fn a_swipe_is_in_view_for_its_crossing_time() {
    let s = SceneScript {
        object_reflectivity: 0.5,
        near_m: 0.05,
        swipe_m_per_s: 1.5,
        period_s: 4.0,
        ..SceneScript::hand()
    }
    .with_motion(Motion::Swipe);
    s.validate().unwrap();
    // in view while |x| < z tan(fov/2) + r_hand
    let span = 0.05 * 30f64.to_radians().tan() + 0.045;
    let want = 2.0 * span / 1.5;
    let dt = 1e-3;
    let visible = (0..4000)
        .filter(|i| s.object_pose(f64::from(*i) * dt).is_some())
        .count() as f64
        * dt;
    assert!((visible - want).abs() < 2.0 * dt, "{visible} vs {want}");
    let mid = s.object_pose(0.8 + want / 2.0).unwrap();
    assert!(mid.lateral_m.abs() < 1e-2 && (mid.distance_m - 0.05).abs() < 1e-12);
}

#[test]
fn phone_scenes_have_stable_unique_names_and_valid_scripts() {
    let scenes = phone_scenes(0.10, 0.15);
    assert!(scenes.len() >= 20);
    let mut names: Vec<&str> = scenes.iter().map(|s| s.name).collect();
    for s in &scenes {
        assert!(
            s.name
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_'),
            "{}",
            s.name
        );
        s.script
            .validate()
            .unwrap_or_else(|e| panic!("{}: {e}", s.name));
        let mut m = ModelConfig::baseline();
        s.cover_window.apply(&mut m).unwrap();
        assert!(s.duration_s > 0.0 && s.duration_s <= 20.0);
    }
    names.sort_unstable();
    names.dedup();
    assert_eq!(names.len(), scenes.len(), "unique names");
}

#[test]
fn phone_scene_ground_truth_follows_the_true_distances() {
    let scenes = phone_scenes(0.10, 0.15);
    let get = |n: &str| scenes.iter().find(|s| s.name == n).unwrap();
    let over = |n: &str| -> Vec<Expect> {
        let s = get(n);
        (0..=100)
            .map(|i| s.expect(s.duration_s * f64::from(i) / 100.0, 0.10, 0.15, 0.5))
            .collect()
    };
    // far everywhere: nothing, ceilings beyond the range (true distance, not the wrapped one),
    // the table top below the axis, a face at reading distance, a grey card beyond far
    for n in [
        "nothing_in_range",
        "ceiling_white_195cm",
        "wall_white_380cm",
        "ceiling_dark_195cm",
        "table_edge",
        "face_30cm",
        "grey_card_beyond_far",
        "sunlight_far_100klux",
        "window_smudged_nothing_in_range",
    ] {
        assert!(over(n).iter().all(|e| *e == Expect::Far), "{n}");
    }
    // approaching objects: far at the start and the end, near while held close
    for n in [
        "hand_approach_05cm",
        "black_card_02cm",
        "face_dark_hair_02cm",
        "grey_card_near_threshold",
        "pocket",
        "sunlight_hand_100klux",
    ] {
        let e = over(n);
        assert_eq!(e[0], Expect::Far, "{n}");
        assert_eq!(e[100], Expect::Far, "{n}");
        assert_eq!(e[52], Expect::Near, "{n} held close");
    }
    // the swipe is near only around its crossing
    let e = over("swipe_fast");
    let near = e.iter().filter(|x| **x == Expect::Near).count();
    assert!((1..=6).contains(&near), "{near}");
}

/// Fabric pressed on the window (the pocket, issue 34): no image of its own, its light comes
/// by the window's path at the window's phase. Closed form written here: the glass (n = 1.5)
/// reflects R = ((n − 1)/(n + 1))² = 4 %, the fabric is lit through it and seen through it
/// again, so the window's return grows by (1 − R)² ρ / R — a 4 % lining about doubles it,
/// light fabric (50 %) adds 11.5×, a smudge adds on top.
#[test]
fn fabric_pressed_on_the_window_adds_to_its_return_at_its_phase() {
    let r_glass = (0.5f64 / 2.5).powi(2);
    for (rho, smudge, t_us) in [(0.04, 0.0, 100.0), (0.5, 0.0, 50.0), (0.03, 1.0, 200.0)] {
        let w = CoverWindow {
            smudge_rel: smudge,
            ..flat_window()
        };
        let mut m = ideal_with(&["signal_falloff"]);
        w.apply(&mut m).unwrap();
        let sim = Simulator::new(&m, window(4), 1).unwrap();
        let got = sim
            .expected(
                &Scene::OnWindow { reflectivity: rho },
                &CaptureRequest::four_phase(t_us),
            )
            .unwrap();
        let contact = (1.0 - r_glass).powi(2) * rho / r_glass;
        let a = 20.0 * (1.0 + smudge + contact) * t_us * LSB_PER_E;
        let phi = 4.0 * PI * F_HZ * 0.004 / C;
        assert_codes(&got, four_phase_codes(a, phi), 1e-6, "fabric on the window");
    }
    // without the window's path (the effect off) the fabric returns nothing at all
    let sim = Simulator::new(&ideal_with(&["signal_falloff"]), window(4), 1).unwrap();
    let got = sim
        .expected(
            &Scene::OnWindow { reflectivity: 0.5 },
            &CaptureRequest::four_phase(100.0),
        )
        .unwrap();
    assert!(got.iter().all(|&v| (v - MID).abs() < 1e-9));
    assert!(
        Scene::OnWindow { reflectivity: 1.5 }.validate().is_err(),
        "a diffuse surface"
    );
}

/// The pocket scenes: the room, the fabric coming to 2 cm, pressed on the window (the scene
/// is `OnWindow`, the truth near: distance 0), lifted and gone (the room, far).
#[test]
fn pocket_scenes_press_the_fabric_on_the_window_and_leave() {
    let scenes = phone_scenes(0.10, 0.15);
    for (name, rho) in [("pocket_dark_fabric", 0.03), ("pocket_light_fabric", 0.5)] {
        let s = scenes.iter().find(|s| s.name == name).expect(name);
        let d = s.duration_s;
        assert_eq!(d, 20.0, "{name}");
        let expect = |t: f64| s.expect(t, 0.10, 0.15, 0.5);
        assert_eq!(expect(0.5), Expect::Far, "{name}: the room");
        assert_eq!(s.script.at(0.5), Scene::wall(1.5, 0.5), "{name}");
        assert_eq!(expect(5.9), Expect::Near, "{name}: at 2 cm");
        for t in [6.1, 10.0, 14.9] {
            assert_eq!(expect(t), Expect::Near, "{name} pressed at {t} s");
            assert_eq!(s.script.at(t), Scene::OnWindow { reflectivity: rho });
        }
        assert_eq!(s.script.object_distance_m(10.0), Some(0.0));
        for t in [18.5, 19.9] {
            assert_eq!(expect(t), Expect::Far, "{name} out of the pocket at {t} s");
        }
    }
    // only a plane filling the view can be pressed on the window
    let hand = SceneScript::hand().with_motion(Motion::Press);
    assert!(hand.validate().is_err());
    let plane = SceneScript {
        kind: ScriptKind::Plane,
        ..SceneScript::hand()
    }
    .with_motion(Motion::Press);
    assert!(plane.validate().is_ok());
}
