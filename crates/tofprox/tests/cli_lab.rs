//! End-to-end tests of `tofprox lab` (docs/lab.md): a recording simulated by
//! `tofprox sim sweep` whose truth has VCSEL droop that the model lacks;
//! diagnose names it (JSON per the output contract), add makes the error fall
//! and writes a loadable model, the report is one self-contained HTML file, and
//! bad input exits 2 with a message (never a panic).
use std::path::Path;
use tofprox_model::ModelConfig;

mod common;
use common::{run, text};

fn simulate(dir: &Path) -> (String, String, String) {
    let mut truth = ModelConfig::baseline();
    truth.set_enabled("vcsel_droop", true).unwrap();
    truth.set_param("vcsel_droop", "droop_rel", 0.06).unwrap();
    let truth_p = dir.join("truth.toml");
    std::fs::write(&truth_p, truth.to_toml_string()).unwrap();
    let base_p = dir.join("base.toml");
    std::fs::write(&base_p, ModelConfig::baseline().to_toml_string()).unwrap();
    let rec = dir.join("rec");
    let o = run(&[
        "sim",
        "sweep",
        "--model",
        truth_p.to_str().unwrap(),
        "--distances",
        "0.15:1.80:0.15",
        "--exposures",
        "250,1000",
        "--repeats",
        "2",
        "--averaged",
        "16",
        "--window",
        "78,104,16,16",
        "--seed",
        "21",
        "--out",
        rec.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    (
        rec.to_string_lossy().into(),
        base_p.to_string_lossy().into(),
        truth_p.to_string_lossy().into(),
    )
}

#[test]
fn diagnose_add_report_end_to_end() {
    let tmp = tempfile::tempdir().unwrap();
    let (rec, base, _) = simulate(tmp.path());
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
    for k in ["chi2_per_dof", "z"] {
        assert!(v["fit"][k].is_number());
    }
    for k in ["raw_lsb", "depth_2phase_mm", "depth_4phase_mm"] {
        assert!(v["rms"][k].is_number());
    }
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(page.starts_with("<!DOCTYPE html>") && page.matches("<svg").count() >= 4);
    assert!(
        !page.contains("http://") || page.contains("xmlns"),
        "no network references beyond SVG namespaces"
    );

    let m2 = tmp.path().join("m2.toml");
    let o = run(&[
        "lab",
        "add",
        "vcsel_droop",
        "--model",
        &base,
        "--data",
        &rec,
        "--out",
        m2.to_str().unwrap(),
        "--json",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let a: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(a["effect"], "vcsel_droop");
    let before = a["before"]["raw_lsb"].as_f64().unwrap();
    let after = a["after"]["raw_lsb"].as_f64().unwrap();
    assert!(after < 0.8 * before, "raw rms {before} -> {after}");
    assert!(
        a["after"]["chi2_per_dof"].as_f64().unwrap()
            < a["before"]["chi2_per_dof"].as_f64().unwrap()
    );
    let m = ModelConfig::load(&m2).unwrap();
    assert!(m.is_enabled(tofprox_model::ids::vcsel_droop::ID));

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
