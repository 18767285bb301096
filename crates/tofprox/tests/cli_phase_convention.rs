//! Phase conventions as data (docs/recording-format.md): a sensor that shifts its illumination
//! instead of its demodulation, or reports `N_B − N_A`, records the same scene as other numbers
//! under the same phase labels. A recording that says so in `[sensor]` processes to the same
//! depth as the canonical recording of the scene, through `tofprox process` — and without the
//! convention the same numbers give another depth (the test can fail).

use std::path::Path;
use std::process::Command;

use rand::SeedableRng;
use rand::rngs::SmallRng;
use tofprox_core::SensorGeometry;
use tofprox_core::phasor::{PhaseConvention, ShiftedSignal};
use tofprox_format::{RawFrames, RecordingWriter};
use tofprox_model::{CaptureRequest, ModelConfig, Scene, Simulator};

const DISTANCES_M: [f64; 3] = [0.25, 0.7, 1.3];

fn geometry() -> SensorGeometry {
    SensorGeometry {
        rows: 8,
        cols: 8,
        roi_origin: [82, 108],
        full_rows: 172,
        full_cols: 224,
        adc_bits: 12,
        modulation_hz: 80e6,
    }
}

/// 2- and 4-phase captures of flat walls by a sensor with `conv`: the raw images its labels
/// `[0, 90(, 180, 270)]` name are, in canonical terms, `conv.canonical_deg(label)`.
fn record(dir: &Path, conv: PhaseConvention) {
    let sim = Simulator::new(&ModelConfig::ideal(), geometry(), 7).unwrap();
    let mut rng = SmallRng::seed_from_u64(11);
    let mut w = RecordingWriter::create(dir, geometry(), Some("phase convention".into())).unwrap();
    w.set_phase_convention(conv).unwrap();
    for labels in [vec![0.0, 90.0], vec![0.0, 90.0, 180.0, 270.0]] {
        let canonical: Vec<f64> = labels.iter().map(|&l| conv.canonical_deg(l)).collect();
        let mut req = CaptureRequest::with_phases(canonical, 1000.0);
        req.averaged = 16;
        for d in DISTANCES_M {
            let x = sim.capture(&Scene::wall(d, 0.9), &req, &mut rng).unwrap();
            w.append(
                tofprox_testkit::capture_spec(&req, Some(d)),
                &RawFrames::F64(x),
            )
            .unwrap();
        }
    }
    w.finish().unwrap();
}

/// `tofprox process --json`: median depth per capture, in file order (dropping the ones the
/// algorithm cannot use).
fn depths(rec: &Path, algo: &str, out: &Path) -> Vec<f64> {
    let o = Command::new(env!("CARGO_BIN_EXE_tofprox"))
        .args([
            "process",
            &rec.display().to_string(),
            "--algo",
            algo,
            "--json",
            "--out",
        ])
        .arg(out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    stdout
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| v["median_depth_m"].as_f64())
        .collect()
}

#[test]
fn a_recording_in_another_phase_convention_gives_the_same_depth() {
    let t = tempfile::tempdir().unwrap();
    let canonical = t.path().join("canonical");
    record(&canonical, PhaseConvention::CANONICAL);
    for (name, conv) in [
        (
            "illumination",
            PhaseConvention {
                shifted: ShiftedSignal::Illumination,
                sign: 1,
            },
        ),
        (
            "negative",
            PhaseConvention {
                shifted: ShiftedSignal::Demodulation,
                sign: -1,
            },
        ),
        (
            "both",
            PhaseConvention {
                shifted: ShiftedSignal::Illumination,
                sign: -1,
            },
        ),
    ] {
        let rec = t.path().join(name);
        record(&rec, conv);
        // the file carries the sensor's own labels and says how to read them
        let text = std::fs::read_to_string(rec.join("recording.toml")).unwrap();
        assert!(
            text.contains("phase_shift_applies_to") || text.contains("phase_sign"),
            "{text}"
        );
        assert!(text.contains("phases_deg = [0.0, 90.0]"), "{text}");
        for algo in ["2phase", "4phase"] {
            let want = depths(&canonical, algo, &t.path().join(format!("out-c-{algo}")));
            let got = depths(&rec, algo, &t.path().join(format!("out-{name}-{algo}")));
            assert_eq!(
                want.len(),
                DISTANCES_M.len() * if algo == "2phase" { 2 } else { 1 }
            );
            assert_eq!(got.len(), want.len(), "{name} {algo}");
            for ((w, g), d) in want.iter().zip(&got).zip(DISTANCES_M.iter().cycle()) {
                assert!((w - d).abs() < 0.005, "{algo} canonical: {w} vs {d}");
                assert!(
                    (w - g).abs() < 0.002,
                    "{name} {algo}: {g} vs canonical {w} at {d} m"
                );
            }
        }
        // the same numbers read in the canonical convention give another depth
        let stripped = t.path().join(format!("{name}-stripped"));
        std::fs::create_dir_all(&stripped).unwrap();
        std::fs::rename(rec.join("frames"), stripped.join("frames")).unwrap();
        let plain: String = text
            .lines()
            .filter(|l| !l.starts_with("phase_shift_applies_to") && !l.starts_with("phase_sign"))
            .map(|l| format!("{l}\n"))
            .collect();
        std::fs::write(stripped.join("recording.toml"), plain).unwrap();
        let wrong = depths(&stripped, "4phase", &t.path().join(format!("out-{name}-x")));
        assert!(
            wrong
                .iter()
                .zip(&DISTANCES_M)
                .any(|(g, d)| (g - d).abs() > 0.05),
            "{name}: {wrong:?} read canonically is still right"
        );
    }
}
