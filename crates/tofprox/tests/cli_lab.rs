//! End-to-end tests of `tofprox lab` (docs/lab.md): a recording simulated by
//! `tofprox sim sweep` whose truth has VCSEL droop that the model lacks;
//! diagnose names it (JSON per the output contract), add makes the error fall
//! and writes a loadable model, the report is one self-contained HTML file, and
//! bad input exits 2 with a message (never a panic).
use std::path::Path;
use tofprox_model::ModelConfig;

mod common;
use common::{repo_file, run, text};

fn simulate(dir: &Path) -> (String, String, String) {
    let mut truth = ModelConfig::baseline();
    truth.set_enabled("vcsel_droop", true).unwrap();
    truth.set_param("vcsel_droop", "droop_rel", 0.06).unwrap();
    let sweep = common::lab_sweep(dir, &truth, 21);
    (sweep.rec, sweep.base, sweep.truth)
}

/// `params` and `standard_errors` of a JSON object, asserting they name the same parameters.
type Named = serde_json::Map<String, serde_json::Value>;
fn params_with_errors(v: &serde_json::Value) -> (&Named, &Named) {
    let (params, ses) = (
        v["params"].as_object().unwrap(),
        v["standard_errors"].as_object().unwrap(),
    );
    assert!(params.keys().eq(ses.keys()), "{params:?} ± {ses:?}");
    (params, ses)
}

/// `tofprox lab add vcsel_droop --model base --data rec [extra…] --out out --json`: its JSON
/// (asserting it exits 0).
fn add_droop(base: &str, rec: &str, out: &Path, extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["lab", "add", "vcsel_droop", "--model", base, "--data", rec];
    args.extend_from_slice(extra);
    args.extend(["--out", out.to_str().unwrap(), "--json"]);
    let o = run(&args);
    assert!(o.status.success(), "{}", text(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn diagnose_add_report_end_to_end() {
    let tmp = tempfile::tempdir().unwrap();
    let (rec, base, truth) = simulate(tmp.path());
    let html = tmp.path().join("diag.html");
    let o = run(&[
        "lab",
        "diagnose",
        &rec,
        "--model",
        &base,
        "--json",
        "--report",
        html.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["verdict"], "missing_effect");
    assert_eq!(v["effect"], "vcsel_droop");
    for k in ["candidates", "fit", "strongest_condition", "rms"] {
        assert!(v.get(k).is_some(), "missing key {k}");
    }
    let c0 = &v["candidates"][0];
    for k in [
        "effect",
        "delta_bic",
        "explained_excess",
        "cv_gain",
        "z_after",
        "params",
    ] {
        assert!(c0.get(k).is_some(), "candidate lacks {k}");
    }
    // each fitted parameter with its standard error; the droop the truth has is many of
    // them away from zero
    let (params, ses) = params_with_errors(c0);
    let significance = params
        .iter()
        .filter_map(|(k, p)| Some((p.as_f64()? / ses[k].as_f64()?).abs()))
        .fold(0.0, f64::max);
    assert!(
        ses.values().any(|s| s.as_f64().is_some_and(|s| s > 0.0)),
        "{ses:?}"
    );
    assert!(significance > 10.0, "{params:?} ± {ses:?}");
    // the one sentence of evidence quotes the diagnosis' own numbers
    let ev = v["evidence"].as_str().unwrap();
    let st0 = &v["structure"][0];
    for want in [
        format!(
            "The residual follows {} (structure z = {:.1}",
            st0["condition"].as_str().unwrap(),
            st0["z"].as_f64().unwrap()
        ),
        format!(
            "of the {} catalogue effects tested, vcsel_droop explains {:.0} % of the excess",
            v["candidates"].as_array().unwrap().len(),
            100.0 * c0["explained_excess"].as_f64().unwrap()
        ),
        format!("leaving z = {:.1}", c0["z_after"].as_f64().unwrap()),
        format!(
            "the noise is {}",
            v["noise"]["description"].as_str().unwrap()
        ),
    ] {
        assert!(ev.contains(&want), "evidence {ev:?} lacks {want:?}");
    }
    for k in ["chi2_per_dof", "z"] {
        assert!(v["fit"][k].is_number());
    }
    for k in ["raw_lsb", "depth_2phase_mm", "depth_4phase_mm"] {
        assert!(v["rms"][k].is_number());
    }
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(page.starts_with("<!DOCTYPE html>") && page.matches("<svg").count() >= 4);
    let quoted = format!("structure z = {:.1}", st0["z"].as_f64().unwrap());
    assert!(page.contains("<b>Evidence:</b> The residual follows") && page.contains(&quoted));
    assert!(
        !page.contains("http://") || page.contains("xmlns"),
        "no network references beyond SVG namespaces"
    );

    let m2 = tmp.path().join("m2.toml");
    let a = add_droop(&base, &rec, &m2, &[]);
    assert_eq!(a["effect"], "vcsel_droop");
    let before = a["before"]["raw_lsb"].as_f64().unwrap();
    let after = a["after"]["raw_lsb"].as_f64().unwrap();
    assert!(after < 0.8 * before, "raw rms {before} -> {after}");
    assert!(
        a["after"]["chi2_per_dof"].as_f64().unwrap()
            < a["before"]["chi2_per_dof"].as_f64().unwrap()
    );
    let m = ModelConfig::load(&m2).unwrap();
    assert!(m.is_enabled(tofprox_model::effects::vcsel_droop::ID));
    // each fitted parameter with a finite positive standard error, and the truth's droop
    // rate (droop_rel/τ, τ in ms: the lab's signature) within 4 of them of the fit
    let (params, ses) = params_with_errors(&a);
    for k in ["droop_rate", "ln_tau"] {
        let se = ses[k].as_f64().unwrap();
        assert!(se.is_finite() && se > 0.0, "{k}: SE {se}");
    }
    let truth = ModelConfig::load(Path::new(&truth)).unwrap();
    let tau_ms = truth.param("vcsel_droop", "tau_us").unwrap() / 1000.0;
    let want = 0.06 / tau_ms;
    let got = params["droop_rate"].as_f64().unwrap();
    let se = ses["droop_rate"].as_f64().unwrap();
    assert!(
        (got - want).abs() < 4.0 * se,
        "droop_rate {got} ± {se}, truth {want}"
    );

    // the depth error split: systematic² = max(rms² − noise², 0), its share of rms²
    for when in ["before", "after"] {
        for alg in ["2phase", "4phase"] {
            let e = &a["depth_error"][when][alg];
            let f = |k: &str| e[k].as_f64().unwrap();
            let (rms, noise, sys) = (f("rms_mm"), f("noise_mm"), f("systematic_mm"));
            assert!(rms > 0.0 && noise > 0.0, "{when} {alg}: {e}");
            let want = (rms * rms - noise * noise).max(0.0).sqrt();
            assert!(
                (sys - want).abs() < 1e-9 * rms.max(1.0),
                "{when} {alg}: {e}"
            );
            assert!((f("systematic_share") - sys * sys / (rms * rms)).abs() < 1e-9);
        }
    }
    // --hold: τ held at the truth's value, the rate fitted around it (and τ written as held)
    let m3 = tmp.path().join("m3.toml");
    let tau_us = tau_ms * 1000.0;
    let h = add_droop(&base, &rec, &m3, &["--hold", &format!("tau_us={tau_us}")]);
    assert_eq!(h["held"]["tau_us"].as_f64(), Some(tau_us));
    assert!((h["params"]["ln_tau"].as_f64().unwrap() - tau_ms.ln()).abs() < 1e-9);
    assert!(h["standard_errors"]["ln_tau"].is_null(), "held: no error");
    let (rate, se) = (
        h["params"]["droop_rate"].as_f64().unwrap(),
        h["standard_errors"]["droop_rate"].as_f64().unwrap(),
    );
    // (its SE, with τ no longer free, is 20× smaller than the free fit's: the 3 % the
    // rate is off at 0.06 droop is the first-order law's, not noise; within 5 % of the truth)
    assert!(
        (rate - want).abs() < 0.05 * want && se > 0.0,
        "held τ: rate {rate} ± {se}, truth {want}"
    );
    let m = ModelConfig::load(&m3).unwrap();
    assert!((m.param("vcsel_droop", "tau_us").unwrap() - tau_us).abs() < 1e-6 * tau_us);
    assert!(h["after"]["raw_lsb"].as_f64().unwrap() < 0.8 * before);

    let o = run(&[
        "lab",
        "diagnose",
        &rec,
        "--model",
        m2.to_str().unwrap(),
        "--json",
    ]);
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_ne!(
        v["effect"], "vcsel_droop",
        "after add the droop is no longer missing"
    );
}

#[test]
fn bad_input_exits_2_with_a_message() {
    let tmp = tempfile::tempdir().unwrap();
    let base = tmp.path().join("base.toml");
    std::fs::write(&base, ModelConfig::baseline().to_toml_string()).unwrap();
    let o = run(&[
        "lab",
        "diagnose",
        tmp.path().join("nowhere").to_str().unwrap(),
        "--model",
        base.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("error:"));
    let o = run(&[
        "lab",
        "add",
        "no_such_effect",
        "--model",
        base.to_str().unwrap(),
        "--data",
        "x",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("no_such_effect"));
    let bad = tmp.path().join("bad.toml");
    std::fs::write(&bad, "[effects.not_an_effect]\nenabled = true\n").unwrap();
    let o = run(&["lab", "compare", "x", "--model", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(!text(&o.stderr).contains("panicked"));
    let o = run(&["lab", "effects"]);
    assert!(o.status.success());
    assert!(text(&o.stdout).contains("sbi_asymmetry"));
}

/// `sim sweep --like REC`: the recording's window, modulation frequency and
/// per-capture conditions through the model; its own keys are copied and
/// named as ignored, an illuminated capture without distance is skipped.
#[test]
fn sim_sweep_like_simulates_the_recordings_conditions() {
    use std::collections::BTreeMap;
    use tofprox_format::{CaptureSpec, RawFrames, Recording, RecordingWriter};
    let tmp = tempfile::tempdir().unwrap();
    // 60 MHz (not the model's default 80.32 MHz), a 6×10 window off the centre
    let f_hz = 60e6;
    let sensor = tofprox_core::SensorGeometry::irs1645();
    let sensor = tofprox_core::SensorGeometry {
        modulation_hz: f_hz,
        ..sensor
    }
    .window(40, 60, 6, 10)
    .unwrap();
    let src = tmp.path().join("src");
    let mut w = RecordingWriter::create(&src, sensor, None).unwrap();
    let frames = RawFrames::U16(ndarray::Array3::from_elem((4, 6, 10), 2048u16));
    let four = vec![0.0, 90.0, 180.0, 270.0];
    let spec = |illum: bool, cond: &[(&str, f64)]| CaptureSpec {
        phases_deg: four.clone(),
        exposure_us: 700.0,
        illumination: illum,
        averaged: 8,
        timestamp_ns: None,
        conditions: cond
            .iter()
            .map(|(k, v)| (k.to_string(), *v))
            .collect::<BTreeMap<_, _>>(),
    };
    w.append(spec(false, &[("supply_voltage_v", 3.3)]), &frames)
        .unwrap();
    for (d, v) in [(0.5, 3.3), (0.8, 3.1)] {
        let c = [
            ("distance_m", d),
            ("reflectivity", 0.8),
            ("temperature_c", 35.0),
            ("supply_voltage_v", v),
        ];
        w.append(spec(true, &c), &frames).unwrap();
    }
    // illuminated without ground truth: cannot be simulated
    w.append(spec(true, &[("supply_voltage_v", 3.2)]), &frames)
        .unwrap();
    w.finish().unwrap();
    let model = tmp.path().join("m.toml");
    std::fs::write(&model, ModelConfig::baseline().to_toml_string()).unwrap();
    let like = |extra: &[&str], out: &Path| {
        let mut args = vec![
            "sim",
            "sweep",
            "--like",
            src.to_str().unwrap(),
            "--model",
            model.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        run(&args)
    };
    let out = tmp.path().join("out");
    let o = like(&[], &out);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("supply_voltage_v"), "{err}");
    assert!(err.contains("skipped 1"), "{err}");
    let rec = Recording::open(&out).unwrap();
    assert_eq!(*rec.sensor(), sensor);
    let caps = rec.captures();
    assert_eq!(caps.len(), 3);
    for (c, want_illum) in caps.iter().zip([false, true, true]) {
        assert_eq!(c.phases_deg, four);
        assert_eq!(c.exposure_us, 700.0);
        assert_eq!(c.averaged, 8);
        assert_eq!(c.illumination, want_illum);
    }
    assert_eq!(caps[1].conditions.get("distance_m"), Some(&0.5));
    assert_eq!(caps[2].conditions.get("supply_voltage_v"), Some(&3.1));
    assert_eq!(caps[2].conditions.get("temperature_c"), Some(&35.0));
    // the phase moves with distance at the recording's 60 MHz: 4πfΔd/c (eq. 2.6)
    let phase = |i: usize| {
        let f = rec.load(i).unwrap().to_f64();
        let (mut re, mut im) = (0.0, 0.0);
        for r in 0..6 {
            for c in 0..10 {
                // eq. 2.3 per pixel, averaged as phasors
                let (x, y) = (f[[0, r, c]] - f[[2, r, c]], f[[1, r, c]] - f[[3, r, c]]);
                let n = x.hypot(y);
                re += x / n;
                im += y / n;
            }
        }
        im.atan2(re)
    };
    let dphi = (phase(2) - phase(1)).rem_euclid(std::f64::consts::TAU);
    let want = tofprox_core::phasor::distance_to_phase_rad(0.3, f_hz);
    let at_default = tofprox_core::phasor::distance_to_phase_rad(0.3, 80.32e6);
    assert!(
        (dphi - want).abs() < 0.4 * (at_default - want).abs(),
        "phase step {dphi:.3} rad, expected {want:.3} (80 MHz would give {at_default:.3})"
    );
    // sweep options conflict with --like
    let o = like(&["--exposures", "100"], &tmp.path().join("x"));
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
}

#[test]
fn explain_that_cannot_explain_exits_1_with_its_reason() {
    // examples/recording has one capture per condition: the noise is not
    // measured, so explain can never end at nothing_missing
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("m.toml");
    let o = run(&[
        "lab",
        "explain",
        &repo_file("examples/recording"),
        "--model",
        &repo_file("config/model/baseline.toml"),
        "--out",
        out.to_str().unwrap(),
        "--json",
        "--report",
        tmp.path().join("explain.html").to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["verdict"], "noise_not_measured");
    let why = v["stopped"].as_str().unwrap();
    assert!(why.contains("not measured"), "{why}");
    assert!(text(&o.stderr).contains("could not explain the recording"));
    assert!(!out.exists(), "nothing added, nothing written");
    assert_eq!(
        v["fitted"],
        serde_json::json!([]),
        "nothing added, nothing fitted"
    );
    // the final verdict's evidence heads the report (the sentence's numbers: its diagnosis)
    let last = &v["steps"][v["steps"].as_array().unwrap().len() - 1]["diagnosis"];
    let evidence = last["evidence"].as_str().unwrap();
    assert!(
        evidence.contains("but the noise is not measured"),
        "{evidence}"
    );
    let tol = format!(
        "below the tolerance {:.2} mm",
        last["tolerance_mm"].as_f64().unwrap()
    );
    assert!(evidence.contains(&tol), "{evidence} lacks {tol}");
    let page = std::fs::read_to_string(tmp.path().join("explain.html")).unwrap();
    let head = page.split("<table>").next().unwrap();
    assert!(
        head.contains("<b>Evidence:</b> What remains is detectable"),
        "{head}"
    );
}

#[test]
fn add_onto_an_existing_file_needs_force() {
    let tmp = tempfile::tempdir().unwrap();
    let model = tmp.path().join("m.toml");
    let before = std::fs::read_to_string(repo_file("config/model/baseline.toml")).unwrap();
    std::fs::write(&model, &before).unwrap();
    let m = model.to_str().unwrap();
    let rec = repo_file("examples/recording");
    // its own input as --out
    let add = |force: &[&str]| {
        let args = [
            "lab",
            "add",
            "vcsel_droop",
            "--model",
            m,
            "--data",
            &rec,
            "--out",
            m,
        ];
        run(&[&args[..], force].concat())
    };
    let o = add(&[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(
        text(&o.stderr).contains("pass --force"),
        "{}",
        text(&o.stderr)
    );
    assert_eq!(std::fs::read_to_string(&model).unwrap(), before);
    let o = add(&["--force"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let written = tofprox_model::ModelConfig::load(&model).unwrap();
    assert!(written.effect("vcsel_droop").is_some_and(|e| e.enabled));
}

/// What numpy reads back from `--export`: the shapes, the χ²/dof and raw RMS recomputed from
/// the exported residuals, the per-pixel χ² map against the residuals it summarises.
const READ_EXPORT_PY: &str = r#"
import json, sys
import numpy as np
d = sys.argv[1]
r = np.load(d + "/residual_lsb.npy").astype(np.float64)
z = np.load(d + "/residual_z.npy").astype(np.float64)
pc = np.load(d + "/pixel_chi2.npy")
maps = {n: list(np.load(d + "/" + n + ".npy").shape) for n in ("offset_lsb", "gain_lsb", "phase_rad")}
ok = np.isfinite(r)
cnt = np.isfinite(z).sum(axis=(0, 1))
per_pixel = np.nansum(z ** 2, axis=(0, 1)) / cnt
print(json.dumps({
    "shape": list(r.shape), "dtype": str(np.load(d + "/residual_lsb.npy").dtype),
    "samples": int(ok.sum()), "same_mask": bool((ok == np.isfinite(z)).all()),
    "chi2": float(np.nansum(z ** 2)), "raw_rms_lsb": float(np.sqrt(np.mean(r[ok] ** 2))),
    "pixel_chi2_max_rel_diff": float(np.nanmax(np.abs(per_pixel - pc) / pc)),
    "maps": maps,
}))
"#;

#[test]
fn export_writes_residuals_maps_and_tables_numpy_reads_back() {
    let Some(python) = tofprox_testkit::require_python("import numpy", "python3-numpy") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("out");
    let rec = repo_file("examples/recording");
    let model = repo_file("config/model/baseline.toml");
    let compare = |extra: &[&str]| {
        let args = [
            "lab", "compare", &rec, "--model", &model, "--json", "--export",
        ];
        run(&[&args[..], &[dir.to_str().unwrap()], extra].concat())
    };
    let o = compare(&[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let out = std::process::Command::new(python)
        .args(["-c", READ_EXPORT_PY, dir.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out.stderr));
    let np: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // the recording's own shape, read by the format crate
    let r = tofprox_format::Recording::open(std::path::Path::new(&rec)).unwrap();
    let k_max = r
        .captures()
        .iter()
        .map(|c| c.phases_deg.len())
        .max()
        .unwrap();
    let (rows, cols) = (r.sensor().rows, r.sensor().cols);
    assert_eq!(
        np["shape"],
        serde_json::json!([r.captures().len(), k_max, rows, cols])
    );
    assert_eq!(np["dtype"], "float32");
    assert_eq!(np["same_mask"], true);
    for m in ["offset_lsb", "gain_lsb", "phase_rad"] {
        assert_eq!(np["maps"][m], serde_json::json!([rows, cols]), "{m}");
    }
    // the fit's own figures, recomputed from the exported residuals
    let n = v["samples"].as_f64().unwrap();
    assert_eq!(np["samples"].as_f64().unwrap(), n);
    let dof = n - v["parameters"].as_f64().unwrap();
    let chi2_per_dof = np["chi2"].as_f64().unwrap() / dof;
    let want = v["fit"]["chi2_per_dof"].as_f64().unwrap();
    assert!(
        (chi2_per_dof / want - 1.0).abs() < 1e-5,
        "{chi2_per_dof} vs {want}"
    );
    let rms = np["raw_rms_lsb"].as_f64().unwrap();
    let want = v["rms"]["raw_lsb"].as_f64().unwrap();
    assert!((rms / want - 1.0).abs() < 1e-5, "{rms} vs {want}");
    assert!(np["pixel_chi2_max_rel_diff"].as_f64().unwrap() < 1e-5);
    // the tables: the structure rows are the JSON's, in order; one row per ranged capture
    let structure = std::fs::read_to_string(dir.join("structure.csv")).unwrap();
    let names: Vec<&str> = structure
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap())
        .collect();
    let want: Vec<&str> = v["structure"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["condition"].as_str().unwrap())
        .collect();
    assert_eq!(names, want);
    let captures = std::fs::read_to_string(dir.join("captures.csv")).unwrap();
    let ranged = r
        .captures()
        .iter()
        .filter(|c| c.illumination && c.conditions.contains_key("distance_m"))
        .count();
    assert_eq!(captures.lines().count() - 1, ranged, "{captures}");
    // nothing replaced without --force
    let o = compare(&[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr).contains("pass --force"),
        "{}",
        text(&o.stderr)
    );
    assert!(compare(&["--force"]).status.success());
}
