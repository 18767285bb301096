//! docs/calibration.md's command blocks run as written (from the repository root, writing only
//! under /tmp, `git status` unchanged), the shipped `calib/example` complete and rebuilt by its
//! script without touching tracked files, and `tofprox calibrate station` end to end.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_tofprox")
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn tofprox(args: &[&str]) -> Output {
    Command::new(bin())
        .args(args)
        .current_dir(repo())
        .output()
        .unwrap()
}

/// `git status` of the repository (None: no git, skipped loudly; a failure in CI).
fn git_status() -> Option<String> {
    let git = tofprox_testkit::ci::require_program("git", "git")?;
    let o = Command::new(git)
        .args(["status", "--porcelain", "--untracked-files=all"])
        .current_dir(repo())
        .output()
        .unwrap();
    if !o.status.success() {
        // not a git checkout (a source tarball): nothing to compare
        eprintln!("git status failed: {}", text(&o));
        return None;
    }
    Some(String::from_utf8(o.stdout).unwrap())
}

/// Each part's sha256 in a set's calibration.toml.
fn part_checksums(dir: &Path) -> BTreeMap<String, String> {
    let t: toml::Table = std::fs::read_to_string(dir.join("calibration.toml"))
        .unwrap()
        .parse()
        .unwrap();
    t.iter()
        .filter_map(|(k, v)| Some((k.clone(), v.get("sha256")?.as_str()?.to_string())))
        .collect()
}

/// The code blocks of a Markdown file, each as its lines.
fn blocks(md: &str) -> Vec<(usize, Vec<String>)> {
    let mut out = Vec::new();
    let mut cur: Option<(usize, Vec<String>)> = None;
    for (i, l) in md.lines().enumerate() {
        if l.starts_with("```") {
            match cur.take() {
                Some(b) => out.push(b),
                None => cur = Some((i + 1, Vec::new())),
            }
        } else if let Some((_, b)) = cur.as_mut() {
            b.push(l.to_string());
        }
    }
    out
}

/// A command line's words after `tofprox`, comments and continuations resolved.
fn words(line: &str) -> Vec<String> {
    let line = line.split(" #").next().unwrap_or("");
    let mut w: Vec<String> = line.split_whitespace().map(str::to_string).collect();
    assert_eq!(w.first().map(String::as_str), Some("tofprox"), "{line}");
    w.remove(0);
    w
}

/// Run a transcript block (`$ tofprox …` lines, their output below): every command must
/// succeed, and every output line shown (but `…`) must be in what the commands printed.
fn run_transcript(at: usize, lines: &[String]) {
    let mut cmds: Vec<String> = Vec::new();
    let mut expected = Vec::new();
    let mut cont = false;
    for l in lines {
        if let Some(c) = l.strip_prefix("$ ") {
            cmds.push(c.trim_end_matches('\\').to_string());
            cont = l.ends_with('\\');
        } else if cont {
            let last = cmds.last_mut().unwrap();
            last.push(' ');
            last.push_str(l.trim().trim_end_matches('\\'));
            cont = l.ends_with('\\');
        } else if !l.contains('…') && !l.trim().is_empty() {
            expected.push(l.trim().to_string());
        }
    }
    let mut printed = String::new();
    for c in &cmds {
        let w = words(c);
        let args: Vec<&str> = w.iter().map(String::as_str).collect();
        let o = tofprox(&args);
        assert!(
            o.status.success(),
            "docs/calibration.md:{at}: `{c}` failed: {}",
            text(&o)
        );
        printed.push_str(&text(&o));
    }
    for e in expected {
        assert!(
            printed.lines().any(|l| l.trim() == e),
            "docs/calibration.md:{at}: the docs show\n  {e}\nbut the commands printed\n{printed}"
        );
    }
}

#[test]
fn calibration_docs_blocks_run_as_written_and_leave_the_tree_clean() {
    let before = git_status();
    for d in ["/tmp/tofprox-docs", "/tmp/tofprox-calib"] {
        let _ = std::fs::remove_dir_all(d);
    }
    let md = std::fs::read_to_string(repo().join("docs/calibration.md")).unwrap();
    let all = blocks(&md);
    let mut transcripts = 0;
    for (at, lines) in &all {
        if lines.first().is_some_and(|l| l.starts_with("$ tofprox")) {
            run_transcript(*at, lines);
            transcripts += 1;
        }
    }
    assert!(transcripts >= 6, "{transcripts} transcripts");
    // "Building a set": plain commands, the last one's info says complete
    let i = md.find("## Building a set").unwrap();
    let line = md[..i].lines().count();
    let (_, building) = all.iter().find(|(at, _)| *at > line).unwrap();
    let mut last = String::new();
    for c in building {
        let w = words(c);
        let args: Vec<&str> = w.iter().map(String::as_str).collect();
        let o = tofprox(&args);
        assert!(o.status.success(), "`{c}`: {}", text(&o));
        last = text(&o);
    }
    assert!(last.contains("complete         yes"), "{last}");
    assert!(last.contains("σ 33.7060 LSB"), "{last}");
    assert!(
        last.contains("wiggling peak-to-peak") || last.contains("0.6204 rad (185.0 mm)"),
        "{last}"
    );
    // it builds the shipped set: the same arrays
    let built = part_checksums(Path::new("/tmp/tofprox-calib/example"));
    assert_eq!(built, part_checksums(&repo().join("calib/example")));
    assert_eq!(built.len(), 6, "{built:?}");
    if let (Some(b), Some(a)) = (before, git_status()) {
        assert_eq!(a, b, "the docs' blocks changed the working tree");
    }
}

#[test]
fn calib_example_is_complete() {
    let o = tofprox(&["info", "calib/example"]);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    assert!(t.contains("complete         yes"), "{t}");
    assert!(t.contains("amplitude        scale K"), "{t}");
    let o = tofprox(&["info", "calib/example", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["complete"], true, "{v}");
}

#[test]
fn calib_example_script_writes_outside_the_tree_and_rebuilds_the_set() {
    let before = git_status();
    let t = tempfile::tempdir().unwrap();
    let out = t.path().join("example");
    let o = Command::new("sh")
        .arg(repo().join("calib/example/make.sh"))
        .env("TOFPROX", bin())
        .env("OUT", &out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("complete         yes"), "{}", text(&o));
    assert_eq!(
        part_checksums(&out),
        part_checksums(&repo().join("calib/example"))
    );
    if let (Some(b), Some(a)) = (before, git_status()) {
        assert_eq!(a, b, "make.sh changed the working tree");
    }
}

#[test]
fn station_on_the_emulated_module_passes_and_a_bad_window_fails_crosstalk() {
    let t = tempfile::tempdir().unwrap();
    let p = |x: &Path| x.to_str().unwrap().to_string();
    let module = t.path().join("module");
    let o = tofprox(&[
        "calibrate",
        "station",
        "--line",
        "module",
        "--station",
        "config/station/module.toml",
        "--out",
        &p(&module),
        "--emulated",
        "--rows",
        "78,16",
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(text(&o).contains("\nPASS\n"), "{}", text(&o));
    let out = tofprox(&["info", &p(&module.join("calib"))]);
    assert!(
        text(&out).contains("complete         yes"),
        "{}",
        text(&out)
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(module.join("report.json")).unwrap())
            .unwrap();
    for r in report["check_readings"].as_array().unwrap() {
        let e = r["error_mm"].as_f64().unwrap();
        assert!(e.abs() < 10.0, "{r}");
    }
    // the phone's window 10× the model's typical one (≈ 3× the 0.15 LSB/µs limit)
    let dev = std::fs::read_to_string(repo().join("calib/phone/wall-1m.toml"))
        .unwrap()
        .replace(
            "model = \"../../config/model/phone.toml\"",
            &format!("model = {:?}", p(&repo().join("config/model/phone.toml"))),
        )
        .replace("e_per_us = 20.0", "e_per_us = 200.0");
    let dev_path = t.path().join("bad-window.toml");
    std::fs::write(&dev_path, dev).unwrap();
    let phone = t.path().join("phone");
    let o = tofprox(&[
        "calibrate",
        "station",
        "--line",
        "phone",
        "--station",
        "config/station/phone.toml",
        "--out",
        &p(&phone),
        "--emulated",
        "--config",
        &p(&dev_path),
        "--rows",
        "78,16",
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let s = String::from_utf8_lossy(&o.stderr);
    assert!(s.contains("the module failed: crosstalk"), "{s}");
    let line = String::from_utf8_lossy(&o.stdout)
        .lines()
        .find(|l| l.contains("cover-window crosstalk"))
        .unwrap()
        .to_string();
    assert!(line.trim_start().starts_with("FAIL"), "{line}");
    // the wrong line for the station file is an error (exit 2), not a failed module
    let o = tofprox(&[
        "calibrate",
        "station",
        "--line",
        "phone",
        "--station",
        "config/station/module.toml",
        "--out",
        &p(&t.path().join("x")),
        "--emulated",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains("the station is for the module line"),
        "{}",
        text(&o)
    );
}
