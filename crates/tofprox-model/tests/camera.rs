//! The model seen through a lens (`[camera]`, thesis 5.1.3): a flat wall's pixels see their own
//! ray length d / cos θ and the light falls off with cos⁵ θ; without `[camera]` nothing changes.

use tofprox_core::camera::{Distortion, Intrinsics, Plane};
use tofprox_core::phasor::{amplitude_4phase, distance_to_phase_rad, phase_4phase, wrap_to_pi};
use tofprox_model::{CaptureRequest, ModelConfig, Scene, SensorGeometry, Simulator};

const LENS_TOML: &str = r#"
[camera]
fx_px = 150.0
fy_px = 151.0
cx_px = 112.0
cy_px = 85.0
[camera.distortion]
k1 = -0.1
p2 = 0.001
"#;

#[test]
fn flat_wall_through_the_lens_is_seen_along_each_ray() {
    let model = ModelConfig::from_toml_str(LENS_TOML).unwrap();
    let k = *model.camera().unwrap();
    assert_eq!(
        k.distortion,
        Distortion {
            k1: -0.1,
            p2: 0.001,
            ..Distortion::default()
        }
    );
    // The file round-trips.
    let again = ModelConfig::from_toml_str(&model.to_toml_string()).unwrap();
    assert_eq!(again.camera(), Some(&k));

    let g = SensorGeometry::irs1645();
    let sim = Simulator::new(&model, g, 1).unwrap();
    let d = 0.8;
    let x = sim
        .expected(&Scene::wall(d, 1.0), &CaptureRequest::four_phase(1000.0))
        .unwrap();
    let rays = k.rays(0, 0, g.rows, g.cols).unwrap();
    let len = rays.ray_lengths_m(&Plane::fronto_parallel(d));
    let u = |kk: usize, r: usize, c: usize| x[(kk, r, c)] - 2048.0;
    let at = |r: usize, c: usize| {
        (
            phase_4phase(u(0, r, c), u(1, r, c), u(2, r, c), u(3, r, c)),
            amplitude_4phase(u(0, r, c), u(1, r, c), u(2, r, c), u(3, r, c)),
        )
    };
    let (centre_phase, centre_amp) = at(85, 112);
    for (r, c) in [(0, 0), (0, 223), (171, 0), (171, 223), (40, 60), (85, 112)] {
        let (phase, amp) = at(r, c);
        // The ideal model: phase = 4πf·len/c exactly (up to the centre pixel's ray).
        let want =
            distance_to_phase_rad(len[(r, c)], 80e6) - distance_to_phase_rad(len[(85, 112)], 80e6);
        assert!(
            (wrap_to_pi(phase - centre_phase) - want).abs() < 1e-9,
            "({r}, {c})"
        );
        // cos⁴ θ vignetting × cos θ incidence, relative to the centre.
        let cos = rays.dir(r, c).unwrap()[2] / rays.dir(85, 112).unwrap()[2];
        assert!(
            (amp / centre_amp - cos.powi(5)).abs() < 1e-9,
            "({r}, {c}): {}",
            amp / centre_amp
        );
    }
    // Without [camera] every pixel sees the same radial distance, as before.
    let flat = Simulator::new(&ModelConfig::ideal(), g, 1)
        .unwrap()
        .expected(&Scene::wall(d, 1.0), &CaptureRequest::four_phase(1000.0))
        .unwrap();
    assert!((flat[(0, 0, 0)] - flat[(0, 85, 112)]).abs() < 1e-12);
    // A bad lens is an error naming the section.
    let bad = ModelConfig::from_toml_str(
        "[camera]\nfx_px = -1.0\nfy_px = 1.0\ncx_px = 0.0\ncy_px = 0.0\n",
    );
    assert!(bad.unwrap_err().to_string().contains("camera"));
    assert!(ModelConfig::from_toml_str("[camera]\nfx_px = 1.0\n").is_err());
}

#[test]
fn a_lens_built_from_a_field_of_view_matches_the_scene_scripts_pinhole() {
    let k = Intrinsics::pinhole_from_fov(172, 224, 60.0).unwrap();
    assert!((k.fx_px - 112.0 / (30f64).to_radians().tan()).abs() < 1e-9);
}
