//! `tofprox lab add condition:<KEY>` end to end (docs/lab.md, "An effect the
//! catalogue lacks"): a recording whose captures state a VCSEL bias current,
//! simulated by `tofprox sim sweep --like` from a truth whose user effect delays
//! the light with the bias; `lab diagnose --json` proposes `condition:vcsel_bias_ma`,
//! `lab add` writes the response into the model file as a user effect with its
//! provenance, `model show --json` lists it and the next diagnose finds nothing missing.
use std::path::Path;

use tofprox_model::ModelConfig;

mod common;
use common::{run, text};

const BIAS_MA: [f64; 5] = [10.0, 15.0, 20.0, 25.0, 30.0];

/// `rec` with `vcsel_bias_ma` stated by every capture: the darks and the correlation
/// capture at 20 mA, the illuminated sweep repeated at each of [`BIAS_MA`] (its frames
/// copied; `sim sweep --like` simulates them anew), so that the bias is independent of
/// distance and exposure and repeats share it.
fn state_bias(rec: &Path) {
    let p = rec.join("recording.toml");
    let mut doc: toml::Table = toml::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    let caps = doc["capture"].as_array().unwrap().clone();
    let with_bias = |c: &toml::Value, b: f64, frames: Option<String>| {
        let mut c = c.as_table().unwrap().clone();
        if let Some(f) = frames {
            std::fs::copy(rec.join(c["frames"].as_str().unwrap()), rec.join(&f)).unwrap();
            c.insert("frames".into(), toml::Value::String(f));
        }
        let cond = c
            .entry("conditions")
            .or_insert(toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .unwrap();
        cond.insert("vcsel_bias_ma".into(), toml::Value::Float(b));
        toml::Value::Table(c)
    };
    let sweep = |c: &toml::Value| {
        c["illumination"].as_bool() == Some(true) && c["phases_deg"].as_array().unwrap().len() < 8
    };
    let mut out: Vec<toml::Value> = caps
        .iter()
        .filter(|c| !sweep(c))
        .map(|c| with_bias(c, 20.0, None))
        .collect();
    for (j, b) in BIAS_MA.iter().enumerate() {
        for (i, c) in caps.iter().enumerate().filter(|(_, c)| sweep(c)) {
            out.push(with_bias(c, *b, Some(format!("frames/bias{j}_{i:04}.npy"))));
        }
    }
    assert!(out.len() > 200, "{}", out.len());
    doc.insert("capture".into(), toml::Value::Array(out));
    std::fs::write(&p, toml::to_string(&doc).unwrap()).unwrap();
}

fn json(args: &[&str]) -> serde_json::Value {
    let o = run(args);
    assert!(o.status.success(), "{args:?}: {}", text(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn lab_add_condition_writes_a_user_effect_that_closes_the_loop() {
    let tmp = tempfile::tempdir().unwrap();
    let s = |p: &Path| p.to_string_lossy().into_owned();
    let sweep = common::lab_sweep(tmp.path(), &ModelConfig::baseline(), 33);
    state_bias(Path::new(&sweep.rec));
    // the truth: the baseline with a delay rising with the bias (0.05 rad ≈ 15 mm at 80 MHz)
    let truth = tmp.path().join("truth_bias.toml");
    let truth_text = format!(
        "{}\n[[user_effects]]\nname = \"truth_bias\"\ncondition = \"vcsel_bias_ma\"\nacts_on = \"phase\"\nknots_x = [10.0, 20.0, 30.0]\nknots_y = [0.0, 0.035, 0.05]\n",
        ModelConfig::baseline().to_toml_string()
    );
    std::fs::write(&truth, truth_text).unwrap();
    let rec = tmp.path().join("rec_bias");
    let o = run(&[
        "sim",
        "sweep",
        "--like",
        &sweep.rec,
        "--model",
        &s(&truth),
        "--seed",
        "7",
        "--out",
        &s(&rec),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));

    let d = json(&[
        "lab",
        "diagnose",
        &s(&rec),
        "--model",
        &sweep.base,
        "--json",
    ]);
    assert_eq!(d["verdict"], "unexplained", "{}", d["reason"]);
    assert_eq!(d["strongest_condition"], "vcsel_bias_ma");
    let p = &d["proposal"];
    assert_eq!(p["add"], "condition:vcsel_bias_ma", "{d}");
    assert_eq!(p["acts_on"], "phase");
    assert_eq!(p["name"], "vcsel_bias_ma_phase");
    assert!(
        p["sentence"]
            .as_str()
            .unwrap()
            .contains("tofprox lab add condition:vcsel_bias_ma")
    );
    let o = run(&["lab", "diagnose", &s(&rec), "--model", &sweep.base]);
    assert!(
        text(&o.stdout).contains("proposal: No catalogue effect explains"),
        "{}",
        text(&o.stdout)
    );

    let m2 = tmp.path().join("m2.toml");
    let a = json(&[
        "lab",
        "add",
        "condition:vcsel_bias_ma",
        "--model",
        &sweep.base,
        "--data",
        &s(&rec),
        "--out",
        &s(&m2),
        "--json",
    ]);
    let (before, after) = (
        a["before"]["chi2_per_dof"].as_f64().unwrap(),
        a["after"]["chi2_per_dof"].as_f64().unwrap(),
    );
    assert!(
        after < 0.5 * before && after < 1.3,
        "χ²/dof {before} → {after}"
    );

    let show = json(&["model", "show", &s(&m2), "--json"]);
    let u = &show["user_effects"][0];
    assert_eq!(u["name"], "vcsel_bias_ma_phase", "{show}");
    assert_eq!(u["condition"], "vcsel_bias_ma");
    assert_eq!(u["acts_on"], "phase");
    assert_eq!(u["law"]["form"], "shape");
    let xs: Vec<f64> = serde_json::from_value(u["law"]["knots_x"].clone()).unwrap();
    let ys: Vec<f64> = serde_json::from_value(u["law"]["knots_y"].clone()).unwrap();
    assert_eq!(xs, BIAS_MA.to_vec());
    // the truth relative to 10 mA: 0, 0.0175, 0.035, 0.0425, 0.05 rad; within 3 mrad (≈ 1 mm)
    for (y, want) in ys.iter().zip([0.0, 0.0175, 0.035, 0.0425, 0.05]) {
        assert!((y - want).abs() < 0.003, "{ys:?}");
    }
    let prov = &u["provenance"];
    assert_eq!(prov["recording"], s(&rec));
    assert!((prov["chi2_per_dof_before"].as_f64().unwrap() - before).abs() < 1e-9);
    assert!((prov["chi2_per_dof_after"].as_f64().unwrap() - after).abs() < 1e-9);
    // the catalogue effects are untouched and the next diagnose closes
    assert_eq!(
        show["effects"],
        json(&["model", "show", &sweep.base, "--json"])["effects"]
    );
    let d2 = json(&["lab", "diagnose", &s(&rec), "--model", &s(&m2), "--json"]);
    assert_eq!(d2["verdict"], "nothing_missing", "{}", d2["reason"]);
    assert!(d2["proposal"].is_null());
}

#[test]
fn lab_add_condition_refuses_a_key_the_recording_lacks() {
    let tmp = tempfile::tempdir().unwrap();
    let sweep = common::lab_sweep(tmp.path(), &ModelConfig::baseline(), 34);
    let o = run(&[
        "lab",
        "add",
        "condition:vcsel_bias_ma",
        "--model",
        &sweep.base,
        "--data",
        &sweep.rec,
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stdout));
    let e = text(&o.stderr);
    assert!(
        e.contains("cannot add a response to `vcsel_bias_ma`"),
        "{e}"
    );
    let o = run(&[
        "lab",
        "add",
        "condition:Bad Key",
        "--model",
        &sweep.base,
        "--data",
        &sweep.rec,
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr).contains("lower-case identifier"),
        "{}",
        text(&o.stderr)
    );
}
