//! What a person reads from the commands (issue 13, items 6–8): documented
//! flags, re-runnable recording steps, `process --json` with what the table
//! shows, errors without repeated causes, no colour codes when redirected,
//! `lab add` printing what it wrote, `tofproxd` without arguments pointing at
//! `--demo`/`--config`.
use std::path::Path;
use std::process::Command;

mod common;
use common::{repo_file, run, text};

#[test]
fn a_recording_step_can_be_run_again_with_force() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cap");
    let args = |force: bool| {
        let mut v = vec![
            "device",
            "capture",
            "--emulated",
            "--mode",
            "2phase",
            "--exposure-us",
            "300",
            "--rows",
            "80,8",
            "--out",
            out.to_str().unwrap(),
        ];
        if force {
            v.push("--force");
        }
        v
    };
    let o = run(&args(false));
    assert!(o.status.success(), "{}", text(&o.stderr));
    let o = run(&args(false));
    assert_eq!(o.status.code(), Some(2));
    let e = text(&o.stderr);
    assert!(e.contains("--force") && !e.contains("append"), "{e}");
    let o = run(&args(true));
    assert!(o.status.success(), "{}", text(&o.stderr));
}

#[test]
fn help_lists_modes_and_names_no_issue_numbers() {
    let o = run(&["device", "capture", "--help"]);
    let h = text(&o.stdout);
    assert!(h.contains("2phase|4phase|4phase-grey|correlation24"), "{h}");
    assert!(h.contains("--rows <FIRST,COUNT>"), "{h}");
    for cmd in [
        vec!["lab", "diagnose", "--help"],
        vec!["lab", "add", "--help"],
        vec!["record", "--help"],
    ] {
        let h = text(&run(&cmd).stdout);
        assert!(!h.contains("issue "), "{cmd:?}: {h}");
    }
    assert!(text(&run(&["record", "--help"]).stdout).contains("--out <REC>"));
}

#[test]
fn process_json_has_distance_and_error() {
    let tmp = tempfile::tempdir().unwrap();
    let o = run(&[
        "process",
        &repo_file("examples/recording"),
        "--calib",
        &repo_file("calib/example"),
        "--algo",
        "2phase",
        "--out",
        tmp.path().to_str().unwrap(),
        "--json",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    // JSON Lines, and the help says so (for `process` and `monitor`)
    let lines: Vec<serde_json::Value> = text(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert!(lines.len() >= 2, "one object per capture");
    assert!(serde_json::from_slice::<serde_json::Value>(&o.stdout).is_err());
    for cmd in ["process", "monitor"] {
        let help = text(&run(&[cmd, "--help"]).stdout);
        assert!(help.contains("JSON Lines"), "{cmd} --help: {help}");
    }
    let with_truth: Vec<&serde_json::Value> = lines
        .iter()
        .filter(|l| l["distance_m"].is_number())
        .collect();
    assert!(!with_truth.is_empty(), "{lines:?}");
    for l in with_truth {
        let err = l["error_mm"].as_f64().unwrap();
        let expect =
            (l["median_depth_m"].as_f64().unwrap() - l["distance_m"].as_f64().unwrap()) * 1000.0;
        assert!((err - expect).abs() < 0.01, "{l}");
    }
}

#[test]
fn errors_name_each_cause_once_and_stderr_has_no_colour_codes() {
    let o = run(&["info", "/nonexistent/recording"]);
    assert_eq!(o.status.code(), Some(2));
    let e = text(&o.stderr);
    assert_eq!(e.lines().count(), 1, "{e}");
    let os = "(os error 2)";
    assert!(e.matches(os).count() <= 1, "{e}");
    // the daemon's error and log output, redirected: no ANSI colour
    let d = common::bin_dir().join("tofproxd");
    let o = Command::new(&d)
        .args(["--config", "/nonexistent/tofproxd.toml"])
        .output()
        .unwrap();
    let e = text(&o.stderr);
    assert!(!e.contains('\x1b'), "{e:?}");
    assert!(e.matches(os).count() <= 1, "{e}");
    // no arguments: point at --demo / --config
    let o = Command::new(&d).output().unwrap();
    let e = text(&o.stderr);
    if !Path::new("/etc/tofprox/tofproxd.toml").exists() {
        assert!(e.contains("--demo") && e.contains("--config"), "{e}");
    }
}

#[test]
fn lab_add_prints_what_it_wrote_with_units() {
    let tmp = tempfile::tempdir().unwrap();
    let mut truth = tofprox_model::ModelConfig::baseline();
    truth.set_enabled("vcsel_droop", true).unwrap();
    let sweep = common::lab_sweep(tmp.path(), &truth, 3);
    let rec = Path::new(&sweep.rec);
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let m2 = tmp.path().join("m2.toml");
    let o = run(&[
        "lab",
        "add",
        "vcsel_droop",
        "--model",
        &repo_file("config/model/baseline.toml"),
        "--data",
        &s(rec),
        "--out",
        &s(&m2),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let shown = text(&o.stdout);
    let written = tofprox_model::ModelConfig::load(&m2).unwrap();
    let info = tofprox_model::catalogue()
        .iter()
        .find(|e| e.id == "vcsel_droop")
        .unwrap();
    assert!(shown.contains("enabled = true"), "{shown}");
    for p in info.params {
        let v = written.param("vcsel_droop", p.name).unwrap();
        let line = shown
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{} = ", p.name)))
            .unwrap_or_else(|| panic!("{} not shown:\n{shown}", p.name));
        let printed: f64 = line
            .split('=')
            .nth(1)
            .unwrap()
            .split_whitespace()
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!(
            (printed - v).abs() <= 1e-6 * v.abs().max(1.0),
            "{line} vs {v}"
        );
        assert!(line.contains(p.unit), "{line}: unit {}", p.unit);
    }
}

/// Issue 13 item 8: `soak` prints a readable summary (not a `Debug` dump) and summarises the
/// injected faults by kind instead of one warning line per failed cycle, with or without
/// `--json`; `-v` shows the warnings.
#[test]
fn soak_summarises_its_faults_instead_of_flooding_stderr() {
    let args = [
        "soak",
        "--cycles",
        "600",
        "--fault-rate",
        "0.2",
        "--seed",
        "3",
    ];
    let o = run(&args);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    let err = text(&o.stderr);
    assert!(!out.contains("SoakReport"), "a Debug dump: {out}");
    let failed_by = out
        .lines()
        .find(|l| l.starts_with("failed by:"))
        .unwrap_or_else(|| panic!("no summary by kind: {out}"));
    assert!(failed_by.contains("disconnected"), "{failed_by}");
    assert!(!err.contains("WARN"), "warnings flood stderr: {err}");
    // memory: measured after the warm-up, a real resident size (the test binary itself is MBs)
    let memory = out
        .lines()
        .find(|l| l.starts_with("memory (RSS):"))
        .unwrap_or_else(|| panic!("{out}"));
    let start_kb: u64 = memory
        .split_whitespace()
        .nth(2)
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("{memory}"));
    assert!(
        start_kb > 1000 && memory.contains("kB after warm-up"),
        "{memory}"
    );
    // a run shorter than the warm-up has no memory figure, and says so instead of "0 kB"
    let short = ["soak", "--cycles", "10", "--fault-rate", "0.5"];
    let o = run(&short);
    let out_short = text(&o.stdout);
    assert!(
        out_short.contains("memory (RSS): not measured") && !out_short.contains(" 0 kB"),
        "{out_short}"
    );
    let mut short_json = short.to_vec();
    short_json.push("--json");
    let v: serde_json::Value = serde_json::from_slice(&run(&short_json).stdout).unwrap();
    assert!(
        v["rss_kb_start"].is_null() && v["rss_kb_end"].is_null(),
        "{v}"
    );
    assert_eq!(v["cycles"], 10, "{v}");
    let mut json_args = args.to_vec();
    json_args.push("--json");
    let o = run(&json_args);
    assert_eq!(o.status.code(), Some(0));
    assert!(!text(&o.stderr).contains("WARN"), "{}", text(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let sum: u64 = v["failures_by_kind"]
        .as_object()
        .unwrap()
        .values()
        .map(|n| n.as_u64().unwrap())
        .sum();
    assert!(sum > 20, "{v}");
    assert_eq!(sum, v["failed_cycles"].as_u64().unwrap(), "{v}");
    // asked for: every warning
    let mut verbose_args = args.to_vec();
    verbose_args.insert(0, "-v");
    let o = run(&verbose_args);
    let warns = text(&o.stderr).matches("WARN").count() as u64;
    assert!(warns >= 1, "{}", text(&o.stderr));
}

/// Issue 24 item 4: a misspelled effect or parameter in a model file gets a "did you mean".
#[test]
fn misspelled_effect_and_parameter_get_a_suggestion() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("typo.toml");
    let show = |toml: &str| {
        std::fs::write(&model, toml).unwrap();
        let o = run(&["model", "show", model.to_str().unwrap()]);
        assert_eq!(o.status.code(), Some(2), "{}", text(&o.stdout));
        text(&o.stderr)
    };
    let err = show("[effects.vcsel_drop]\nenabled = true\n");
    assert!(
        err.contains("unknown effect `effects.vcsel_drop`: did you mean `vcsel_droop`?"),
        "{err}"
    );
    let err = show("[effects.vcsel_droop]\nenabled = true\ndroop_rell = 0.01\n");
    assert!(
        err.contains(
            "unknown parameter `effects.vcsel_droop.droop_rell`: did you mean `droop_rel`?"
        ),
        "{err}"
    );
    let err = show("[effects.banana]\nenabled = true\n");
    assert!(
        err.contains("unknown effect `effects.banana` (known:") && !err.contains("did you mean"),
        "{err}"
    );
    // the lab's `add` names the effect it probably meant, before reading any file
    let o = run(&[
        "lab",
        "add",
        "vcsel_drop",
        "--model",
        "absent.toml",
        "--data",
        "absent",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stdout));
    assert!(
        text(&o.stderr).contains("cannot add `vcsel_drop` (did you mean `vcsel_droop`?)"),
        "{}",
        text(&o.stderr)
    );
}

/// Issue 24 item 4: each warning once. A recording without repeats gets one warning that its
/// noise is not measured (the library fits the noise on every refit pass and no longer logs
/// it there), and the verdict says the same.
#[test]
fn unmeasured_noise_is_warned_once() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    let model = repo_file("config/model/baseline.toml");
    let o = run(&[
        "sim",
        "sweep",
        "--model",
        &model,
        "--distances",
        "0.3:1.0:0.1",
        "--exposures",
        "500",
        "--window",
        "78,104,8,8",
        "--seed",
        "3",
        "--out",
        rec.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let o = run(&["lab", "diagnose", rec.to_str().unwrap(), "--model", &model]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let err = text(&o.stderr);
    assert_eq!(err.matches("noise not measured").count(), 1, "{err}");
    assert_eq!(err.matches("WARN").count(), 1, "{err}");
    assert!(
        text(&o.stdout).contains("NOISE NOT MEASURED"),
        "{}",
        text(&o.stdout)
    );
}

/// `tofprox model preset <name>` prints the shipped model file byte for byte (the files are
/// generated from the effect registry, docs/model.md); a name that is no preset is refused
/// with the three that are.
#[test]
fn model_preset_prints_the_shipped_file_and_refuses_an_unknown_name() {
    for name in ["baseline", "full", "ideal"] {
        let out = run(&["model", "preset", name]);
        assert!(out.status.success(), "{name}: {}", text(&out.stderr));
        let shipped =
            std::fs::read_to_string(repo_file(&format!("config/model/{name}.toml"))).unwrap();
        assert_eq!(text(&out.stdout), shipped, "{name}");
        assert!(shipped.contains(&format!("description = \"{name}:")));
    }
    let full = text(&run(&["model", "preset", "full"]).stdout);
    let n_effects = tofprox_model::catalogue().len();
    assert_eq!(
        full.matches("\n[effects.").count(),
        n_effects,
        "one table per effect"
    );
    let out = run(&["model", "preset", "fulll"]);
    assert_eq!(out.status.code(), Some(2));
    let err = text(&out.stderr);
    assert!(
        err.contains("`fulll` is not a preset (baseline, full, ideal)"),
        "{err}"
    );
}
