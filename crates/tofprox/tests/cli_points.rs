//! Radial distance, Z depth and point clouds (issue 14 item 4, thesis 5.1.3) through the command
//! line: the model's flat wall seen through the 66° lens with barrel and decentring distortion of
//! `config/model/lens.toml`, calibrated in the documented order (`calibrate intrinsics` from a
//! 24-phase sweep, then `fpn`, `wiggling`, `fppn` at 0.5 m), processed with
//! `--depth-kind z --points`.
//!
//! Must hold at 1 m: Z depth within 1 cm of 1 m across the whole array (2- and 4-phase), the
//! point cloud (.npy and .ply) flat with a plane-fit RMS below 5 mm, while the radial depth of
//! the same pixels reaches decimetres beyond 1 m at the corners (the test can fail if the
//! depth kind were ignored).

mod common;

use std::path::Path;

use common::{repo_file, run, text};
use tofprox_core::camera::Plane;
use tofprox_format::npy::{self, NpyArray};

fn ok(args: &[&str]) -> String {
    let o = run(args);
    assert!(
        o.status.success(),
        "tofprox {args:?}\n{}\n{}",
        text(&o.stdout),
        text(&o.stderr)
    );
    text(&o.stdout)
}

fn load_u16(p: &Path) -> ndarray::ArrayD<u16> {
    match npy::decode(&std::fs::read(p).unwrap()).unwrap() {
        NpyArray::U16(a) => a,
        _ => panic!("{}: uint16 expected", p.display()),
    }
}

/// The finite points of an `(N, 3)` float32 `.npy` cloud, and N.
fn npy_points(p: &Path) -> (Vec<[f64; 3]>, usize) {
    let NpyArray::F32(a) = npy::decode(&std::fs::read(p).unwrap()).unwrap() else {
        panic!("{}: float32 expected", p.display())
    };
    assert_eq!(a.ndim(), 2);
    assert_eq!(a.shape()[1], 3);
    let n = a.shape()[0];
    let a = a.into_dimensionality::<ndarray::Ix2>().unwrap();
    let pts = a
        .outer_iter()
        .filter(|r| r.iter().all(|v| v.is_finite()))
        .map(|r| [r[0] as f64, r[1] as f64, r[2] as f64])
        .collect();
    (pts, n)
}

/// The vertices of a binary little-endian PLY with `float x, y, z` (as `--points *.ply` writes).
fn ply_points(p: &Path) -> Vec<[f64; 3]> {
    let bytes = std::fs::read(p).unwrap();
    let end = b"end_header\n";
    let at = bytes
        .windows(end.len())
        .position(|w| w == end)
        .expect("PLY header")
        + end.len();
    let header = std::str::from_utf8(&bytes[..at]).unwrap();
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
    assert!(header.contains("property float x\nproperty float y\nproperty float z\n"));
    let n: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .expect("vertex count")
        .parse()
        .unwrap();
    let body = &bytes[at..];
    assert_eq!(body.len(), 12 * n, "{}", p.display());
    body.chunks_exact(12)
        .map(|c| {
            let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]) as f64;
            [f(0), f(4), f(8)]
        })
        .collect()
}

#[test]
fn z_depth_and_point_cloud_of_a_flat_wall_through_a_wide_distorting_lens() {
    let t = tempfile::tempdir().unwrap();
    let s = |p: &Path| p.to_string_lossy().into_owned();
    let (sweep, flat, calib) = (
        t.path().join("sweep"),
        t.path().join("flat"),
        t.path().join("calib"),
    );
    let model = repo_file("config/model/lens.toml");
    // lens sweep: 24 equally spaced phases cancel the uncalibrated wiggling (docs/calibration.md)
    ok(&[
        "sim",
        "sweep",
        "--model",
        &model,
        "--distances",
        "0.3,0.45,0.6,0.75,0.9,1.05",
        "--exposures",
        "1000",
        "--phases",
        "24",
        "--averaged",
        "64",
        "--out",
        &s(&sweep),
    ]);
    // the same sensor (same seed): dark, correlation at 0.5 m, 4-phase walls at 0.5 and 1 m
    ok(&[
        "sim",
        "sweep",
        "--model",
        &model,
        "--distances",
        "0.5,1.0",
        "--exposures",
        "1000",
        "--phases",
        "4",
        "--averaged",
        "256",
        "--correlation-distance",
        "0.5",
        "--out",
        &s(&flat),
    ]);
    let out = ok(&["calibrate", "intrinsics", &s(&sweep), "--out", &s(&calib)]);
    eprintln!("{out}");
    for what in ["fpn", "wiggling", "fppn"] {
        let out = ok(&["calibrate", what, &s(&flat), "--out", &s(&calib)]);
        eprintln!("{out}");
    }

    // capture 3 is the wall at 1 m (0: dark, 1: correlation, 2: wall at 0.5 m)
    let wall = "000003";
    for (algo, cloud_ext) in [("4phase", "ply"), ("2phase", "npy")] {
        let out_dir = t.path().join(format!("out-{algo}"));
        let cloud = out_dir.join(format!("cloud.{cloud_ext}"));
        let stdout = ok(&[
            "process",
            &s(&flat),
            "--calib",
            &s(&calib),
            "--algo",
            algo,
            "--out",
            &s(&out_dir),
            "--depth-kind",
            "z",
            "--points",
            &s(&cloud),
            "--json",
        ]);
        let line: serde_json::Value = stdout
            .lines()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .find(|v| v["index"] == 3)
            .expect("capture 3 processed");
        assert_eq!(line["depth_kind"], "z");

        // Z depth: ≈ 1 m across the whole array
        let z = load_u16(&out_dir.join(format!("{wall}_depth_mm.npy")));
        let valid: Vec<f64> = z
            .iter()
            .filter(|&&v| v > 0)
            .map(|&v| f64::from(v))
            .collect();
        let valid_fraction = valid.len() as f64 / z.len() as f64;
        let worst_mm = valid.iter().map(|v| (v - 1000.0).abs()).fold(0.0, f64::max);
        eprintln!(
            "{algo} wall at 1 m: Z depth worst |Z − 1 m| over the whole array {worst_mm:.0} mm (valid {:.1} %)",
            100.0 * valid_fraction
        );
        assert!(valid_fraction > 0.99, "{algo}: valid {valid_fraction}");
        assert!(worst_mm < 10.0, "{algo}: worst Z error {worst_mm} mm");

        // the point cloud is flat, 1 m in front of the camera, facing it
        let points = cloud.with_file_name(format!("cloud_{wall}.{cloud_ext}"));
        let pts = if cloud_ext == "npy" {
            let (pts, n) = npy_points(&points);
            assert_eq!(n, z.len(), "one row per pixel (NaN where invalid)");
            pts
        } else {
            ply_points(&points)
        };
        assert_eq!(pts.len(), valid.len(), "the valid pixels' points");
        let (plane, rms) = Plane::fit(&pts).unwrap();
        eprintln!(
            "{algo} point cloud ({cloud_ext}) at 1 m: {} points, plane at {:.4} m, normal {:?}, RMS {:.2} mm",
            pts.len(),
            plane.distance_m,
            plane.normal,
            rms * 1000.0
        );
        assert!(rms < 0.005, "{algo}: plane-fit RMS {:.2} mm", rms * 1000.0);
        assert!((plane.distance_m - 1.0).abs() < 0.01, "{plane:?}");
        assert!(plane.normal[2] > 0.9999, "{plane:?}");

        // the default (radial) depth of the same capture is the ray length: decimetres beyond
        // 1 m towards the corners of a 66° field
        let radial_dir = t.path().join(format!("radial-{algo}"));
        ok(&[
            "process",
            &s(&flat),
            "--calib",
            &s(&calib),
            "--algo",
            algo,
            "--out",
            &s(&radial_dir),
        ]);
        let r = load_u16(&radial_dir.join(format!("{wall}_depth_mm.npy")));
        // per pixel radial ≥ Z (ray length vs its component along the axis)
        assert!(r.iter().zip(z.iter()).all(|(&r, &z)| r + 1 >= z));
        let longest = r.iter().copied().max().unwrap_or(0);
        eprintln!("{algo} wall at 1 m: longest radial depth {longest} mm");
        assert!(longest > 1150, "longest radial depth {longest} mm");
    }
}

/// Z depth and points need the lens: refused, naming what is missing, before anything is
/// processed; an unknown cloud extension is refused naming the path.
#[test]
fn z_depth_and_points_without_a_lens_are_refused() {
    let t = tempfile::tempdir().unwrap();
    let s = |p: &Path| p.to_string_lossy().into_owned();
    let rec = t.path().join("rec");
    ok(&[
        "sim",
        "sweep",
        "--model",
        &repo_file("config/model/ideal.toml"),
        "--distances",
        "0.5",
        "--window",
        "80,100,8,8",
        "--out",
        &s(&rec),
    ]);
    let out = t.path().join("out");
    for extra in [vec!["--depth-kind", "z"], vec!["--points", "cloud.ply"]] {
        let mut args = vec!["process", rec.to_str().unwrap(), "--algo", "4phase"];
        let o_s = s(&out);
        args.extend(["--out", &o_s]);
        args.extend(extra.iter().copied());
        let o = run(&args);
        assert!(!o.status.success());
        let err = text(&o.stderr);
        assert!(
            err.contains("needs the lens") && err.contains("intrinsics"),
            "{err}"
        );
        assert!(
            !out.join("000002_depth_mm.npy").exists(),
            "nothing processed"
        );
    }
    let cloud = t.path().join("cloud.xyz");
    let o = run(&[
        "process",
        rec.to_str().unwrap(),
        "--algo",
        "4phase",
        "--out",
        &s(&out),
        "--points",
        &s(&cloud),
    ]);
    assert!(!o.status.success());
    let err = text(&o.stderr);
    assert!(err.contains("cloud.xyz") && err.contains(".ply"), "{err}");
}
