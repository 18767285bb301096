//! Camera model against closed forms: pinhole rays to a fronto-parallel plane, distortion
//! round trips, radial → Z, point clouds, plane fits.

use ndarray::Array2;
use proptest::prelude::*;
use tofprox_core::camera::{Distortion, Intrinsics, Plane, UNDISTORT_TOLERANCE};

/// A 62° IRS1645-class lens (172 × 224 array) with the given distortion.
fn lens(distortion: Distortion) -> Intrinsics {
    Intrinsics {
        distortion,
        ..Intrinsics::pinhole_from_fov(172, 224, 62.0).unwrap()
    }
}

fn barrel() -> Distortion {
    Distortion {
        k1: -0.28,
        k2: 0.09,
        k3: -0.012,
        p1: 0.0012,
        p2: -0.0008,
    }
}

proptest! {
    /// No distortion: the ray of pixel (u, v) to a fronto-parallel plane at d is d / cos θ with
    /// tan θ = |((u − cx)/fx, (v − cy)/fy)|.
    #[test]
    fn pinhole_ray_length_is_d_over_cos_theta(
        u in 0.0f64..224.0, v in 0.0f64..172.0, d in 0.05f64..5.0, f in 80.0f64..600.0,
    ) {
        let k = Intrinsics { fx_px: f, fy_px: 1.1 * f, ..lens(Distortion::default()) };
        let dir = k.ray(u, v).unwrap();
        let (x, y) = ((u - k.cx_px) / k.fx_px, (v - k.cy_px) / k.fy_px);
        let cos_theta = 1.0 / (1.0 + x * x + y * y).sqrt();
        let len = Plane::fronto_parallel(d).ray_length_m(dir).unwrap();
        prop_assert!((len - d / cos_theta).abs() < 1e-12 * d);
        prop_assert!((dir.iter().map(|c| c * c).sum::<f64>() - 1.0).abs() < 1e-12);
    }

    /// distort ∘ undistort ≈ identity within the documented tolerance over the whole array,
    /// and project ∘ ray returns the pixel.
    #[test]
    fn undistort_inverts_distort(u in 0.0f64..224.0, v in 0.0f64..172.0, s in 0.0f64..1.0) {
        let d = Distortion { k1: -0.28 * s, k2: 0.09 * s, k3: -0.012 * s, p1: 0.0012 * s, p2: -0.0008 * s };
        let k = lens(d);
        let (xd, yd) = ((u - k.cx_px) / k.fx_px, (v - k.cy_px) / k.fy_px);
        let (x, y) = d.undistort(xd, yd).unwrap();
        let (rx, ry) = d.distort(x, y);
        prop_assert!((rx - xd).hypot(ry - yd) < UNDISTORT_TOLERANCE);
        let dir = k.ray(u, v).unwrap();
        let (pu, pv) = k.project([2.0 * dir[0], 2.0 * dir[1], 2.0 * dir[2]]).unwrap();
        prop_assert!((pu - u).abs() < 1e-8 && (pv - v).abs() < 1e-8, "({pu}, {pv}) vs ({u}, {v})");
    }

    /// Z = radial · cos θ and the point's Z is Z: a flat wall's points lie on the wall.
    #[test]
    fn points_of_a_wall_lie_on_the_wall(d in 0.1f64..3.0, row0 in 0usize..150, col0 in 0usize..200) {
        let rays = lens(barrel()).rays(row0, col0, 20, 20).unwrap();
        let plane = Plane::fronto_parallel(d);
        let radial = rays.ray_lengths_m(&plane).mapv(|v| v as f32);
        let z = rays.radial_to_z(radial.view()).unwrap();
        let pts = rays.points(radial.view()).unwrap();
        for ((r, c), &zv) in z.indexed_iter() {
            prop_assert!((zv as f64 - d).abs() < 1e-6 * d.max(1.0));
            prop_assert!((pts[(r, c, 2)] - zv).abs() < 1e-6);
        }
    }
}

#[test]
fn corner_of_a_62_degree_lens_sees_a_wall_much_further_away() {
    // The figure: at 0.5 m the corner ray is decimetres longer than the axis.
    let rays = lens(Distortion::default()).rays(0, 0, 172, 224).unwrap();
    let len = rays.ray_lengths_m(&Plane::fronto_parallel(0.5));
    let centre = len[(86, 112)];
    let corner = len[(0, 0)];
    assert!((centre - 0.5).abs() < 1e-3, "centre {centre}");
    assert!(corner - 0.5 > 0.1, "corner {corner}");
}

#[test]
fn plane_fit_recovers_a_tilted_plane_and_rejects_degenerate_input() {
    let n = {
        let v = [0.1f64, -0.2, 1.0];
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|c| c / l)
    };
    let plane = Plane {
        normal: n,
        distance_m: 0.8,
    };
    let rays = lens(barrel()).rays(0, 0, 30, 40).unwrap();
    let radial = rays.ray_lengths_m(&plane).mapv(|v| v as f32);
    let pts = rays.points(radial.view()).unwrap();
    let list: Vec<[f64; 3]> = pts
        .outer_iter()
        .flat_map(|row| {
            row.outer_iter()
                .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
                .collect::<Vec<_>>()
        })
        .collect();
    let (fit, rms) = Plane::fit(&list).unwrap();
    assert!(rms < 1e-6, "rms {rms}");
    assert!((fit.distance_m - 0.8).abs() < 1e-6);
    for (got, want) in fit.normal.iter().zip(n) {
        assert!((got - want).abs() < 1e-6);
    }
    assert!(Plane::fit(&list[..2]).is_err());
    let line: Vec<[f64; 3]> = (0..10).map(|i| [i as f64, 2.0 * i as f64, 1.0]).collect();
    assert!(Plane::fit(&line).is_err());
}

#[test]
fn invalid_pixels_stay_zero_and_shapes_are_checked() {
    let rays = lens(barrel()).rays(10, 10, 4, 5).unwrap();
    let mut radial = Array2::<f32>::from_elem((4, 5), 1.0);
    radial[(1, 2)] = 0.0;
    radial[(2, 2)] = f32::NAN;
    let pts = rays.points(radial.view()).unwrap();
    assert_eq!([pts[(1, 2, 0)], pts[(1, 2, 1)], pts[(1, 2, 2)]], [0.0; 3]);
    assert_eq!([pts[(2, 2, 0)], pts[(2, 2, 1)], pts[(2, 2, 2)]], [0.0; 3]);
    assert_eq!(rays.radial_to_z(radial.view()).unwrap()[(1, 2)], 0.0);
    assert!(rays.points(Array2::<f32>::zeros((5, 4)).view()).is_err());
    // A distortion that folds over cannot be inverted far out: an error, not a wrong ray.
    let folding = Distortion {
        k1: -2.0,
        ..Distortion::default()
    };
    assert!(folding.undistort(2.0, 2.0).is_err());
    assert!(
        Intrinsics {
            fx_px: 0.0,
            ..lens(barrel())
        }
        .validate()
        .is_err()
    );
    let nan = Distortion {
        k2: f64::NAN,
        ..barrel()
    };
    assert!(lens(nan).validate().is_err());
}

/// Phase images of a fronto-parallel wall at `d` through `k`, with a global delay.
fn wall_phases(k: &Intrinsics, distances: &[f64], delay_rad: f64) -> Vec<(f64, Array2<f64>)> {
    let rays = k.rays(0, 0, 172, 224).unwrap();
    distances
        .iter()
        .map(|&d| {
            let len = rays.ray_lengths_m(&Plane::fronto_parallel(d));
            let ph = len.mapv(|l| {
                tofprox_core::phasor::wrap_phase(
                    tofprox_core::phasor::distance_to_phase_rad(l, 80e6) + delay_rad,
                )
            });
            (d, ph)
        })
        .collect()
}

#[test]
fn intrinsics_are_recovered_from_a_flat_wall_sweep() {
    // k3 = 0: the fit holds it there (OpenCV's CALIB_FIX_K3 advice).
    let d = Distortion {
        k3: 0.0,
        ..barrel()
    };
    let truth = Intrinsics {
        cx_px: 114.3,
        cy_px: 84.8,
        fy_px: 1.01 * lens(d).fx_px,
        ..lens(d)
    };
    let sweep = wall_phases(&truth, &[0.3, 0.45, 0.6, 0.75, 0.9, 1.05], 2.5);
    let views: Vec<_> = sweep.iter().map(|(d, p)| (*d, p.view())).collect();
    let l = tofprox_core::camera::ray_factors_from_sweep(&views, 80e6).unwrap();
    let fit = tofprox_core::lens_fit::fit_intrinsics(l.view(), 0, 0).unwrap();
    // What matters: every pixel's ray (and so its ray length) is right.
    let got = fit.intrinsics.rays(0, 0, 172, 224).unwrap();
    let want = truth.rays(0, 0, 172, 224).unwrap();
    let plane = Plane::fronto_parallel(1.0);
    let (lg, lw) = (got.ray_lengths_m(&plane), want.ray_lengths_m(&plane));
    let worst = (&lg - &lw).iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        worst < 1e-4,
        "worst ray-length error at 1 m: {worst} m ({fit:?})"
    );
    assert!(fit.rms_ray_factor < 1e-6, "{fit:?}");
    // Too few distances is an error, not a guess.
    assert!(tofprox_core::camera::ray_factors_from_sweep(&views[..2], 80e6).is_err());
}
