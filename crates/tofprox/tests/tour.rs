//! The tour as a test (issue 13): every command of README.md's "Tour" and of
//! the worked examples in docs/*.md runs as written, extracted from the
//! Markdown (never copied here), twice (re-running a step works): the second
//! round re-runs every block that wrote files (one that changed nothing would
//! start again from the state it started from); the lab examples' second run
//! (README step 3, docs/lab.md's worked example) is their run with `--json`,
//! whose numbers are asserted against the transcript and the truth.
//!
//! What is extracted: in README.md every ```sh block between "## Tour" and the
//! next "## " heading; in docs/*.md every fenced block with `$ ` prompts (the
//! prompt lines and their `\` continuations are commands, the rest is output).
//! How they run: one bash script per block, each document's blocks in order in
//! a sandbox of its own (documents in parallel) holding copies of
//! `examples/`, `config/` and `calib/`, with the built `tofprox` and
//! `tofproxd` first on `PATH` (as the README's set-up puts them); `/tmp/` in a
//! command becomes the sandbox's `tmp/` (parallel test runs must not share
//! files). Each command must exit 0, or N where its comment says "exits N".
//! `cargo …` lines (building the binaries) are what the test harness did
//! before running this test; they are not run again in the sandbox.
//! A block that starts `tofproxd` runs on a private session bus
//! (`dbus-run-session`, as the README tells a reader without a bus).
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;
use common::{copy_dir, repo, text};

/// One fenced block's commands, with where they come from.
struct Block {
    origin: String,
    commands: Vec<String>,
}

/// Commands of a fenced block's lines: continuation lines joined.
fn join_continuations(lines: &[&str]) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur = String::new();
    for l in lines {
        if let Some(head) = l.trim_end().strip_suffix('\\') {
            cur.push_str(head);
            cur.push(' ');
        } else {
            cur.push_str(l);
            out.push(std::mem::take(&mut cur));
        }
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out.into_iter().filter(|c| !c.trim().is_empty()).collect()
}

/// Fenced blocks of `md`: (starting line, info string, lines).
fn fences(md: &str) -> Vec<(usize, String, Vec<&str>)> {
    let mut out = Vec::new();
    let mut open: Option<(usize, String, Vec<&str>)> = None;
    for (i, l) in md.lines().enumerate() {
        if let Some(info) = l.trim_start().strip_prefix("```") {
            match open.take() {
                Some(b) => out.push(b),
                None => open = Some((i + 1, info.trim().to_string(), Vec::new())),
            }
        } else if let Some((_, _, lines)) = open.as_mut() {
            lines.push(l);
        }
    }
    out
}

fn readme_tour() -> Vec<Block> {
    let md = std::fs::read_to_string(repo().join("README.md")).unwrap();
    let start = md.find("\n## Tour").expect("README has a Tour section");
    let end = md[start + 1..]
        .find("\n## ")
        .map_or(md.len(), |e| start + 1 + e);
    let first_line = md[..start].lines().count();
    fences(&md[start..end])
        .into_iter()
        .filter(|(_, info, _)| info == "sh")
        .map(|(line, _, lines)| Block {
            origin: format!("README.md:{}", first_line + line),
            commands: join_continuations(&lines),
        })
        .collect()
}

fn docs_examples() -> Vec<Block> {
    let mut out = Vec::new();
    let mut files: Vec<PathBuf> = std::fs::read_dir(repo().join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    files.sort();
    for f in files {
        let md = std::fs::read_to_string(&f).unwrap();
        for (line, _, lines) in fences(&md) {
            // prompt lines and their continuations
            let mut cmd_lines = Vec::new();
            let mut in_cmd = false;
            for l in &lines {
                if let Some(c) = l.strip_prefix("$ ") {
                    cmd_lines.push(c);
                    in_cmd = c.trim_end().ends_with('\\');
                } else if in_cmd {
                    cmd_lines.push(l);
                    in_cmd = l.trim_end().ends_with('\\');
                }
            }
            if !cmd_lines.is_empty() {
                out.push(Block {
                    origin: format!("docs/{}:{line}", f.file_name().unwrap().to_string_lossy()),
                    commands: join_continuations(&cmd_lines),
                });
            }
        }
    }
    out
}

/// The exit status a command's comment documents ("exits N"), else 0.
fn expected_status(cmd: &str) -> i32 {
    cmd.split_once('#')
        .and_then(|(_, c)| c.split("exits ").nth(1))
        .and_then(|r| r.split(|ch: char| !ch.is_ascii_digit()).next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0)
}

fn shell_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// The bash script of a block: each command echoed, run, its status checked.
fn script(b: &Block, sandbox: &Path) -> String {
    let tmp = format!("{}/tmp/", sandbox.display());
    // a failing block must not leave its background daemon behind
    let mut s = String::from("set -u\ntrap 'kill $(jobs -p) 2>/dev/null' EXIT\n");
    for c in b
        .commands
        .iter()
        .filter(|c| !c.trim_start().starts_with("cargo "))
    {
        let run = c.replace("/tmp/", &tmp);
        let want = expected_status(c);
        s.push_str(&format!(
            "echo {q} >&2\n{run}\nrc=$?\nif [ \"$rc\" -ne {want} ]; then echo \"tour: {o}: exit $rc (documented: {want}): \"{q} >&2; exit 1; fi\n",
            q = shell_quote(&format!("+ {c}")),
            o = b.origin,
        ));
    }
    s
}

/// Every file below `dir` with its size and modification time: what a block changed.
fn snapshot(dir: &Path) -> Vec<(PathBuf, u64, std::time::SystemTime)> {
    let mut out = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let e = e.unwrap();
            let m = e.metadata().unwrap();
            if m.is_dir() {
                todo.push(e.path());
            } else {
                out.push((e.path(), m.len(), m.modified().unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// Run one block's script in `root` (on a private session bus if it starts `tofproxd`).
fn run_block(b: &Block, root: &Path, scripts: &Path, round: u32) {
    let sh = scripts.join("block.sh");
    std::fs::write(&sh, script(b, root)).unwrap();
    let on_bus = b.commands.iter().any(|c| c.starts_with("tofproxd "));
    let mut cmd = if on_bus {
        let mut c = Command::new("dbus-run-session");
        c.args(["--", "bash"]);
        c
    } else {
        Command::new("bash")
    };
    let o = cmd
        .arg(&sh)
        .current_dir(root)
        .env("PATH", common::path_with_bins())
        .env_remove("DBUS_SESSION_BUS_ADDRESS")
        .env("NO_COLOR", "1")
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "round {round}, {}:\n--- stderr\n{}\n--- stdout\n{}",
        b.origin,
        text(&o.stderr),
        text(&o.stdout)
    );
}

/// One document's blocks, in order, in a sandbox of their own, twice: the first
/// round runs every block; the second runs again each block that wrote files
/// (a block that leaves the sandbox as it found it starts its second run from
/// the same state as its first, so that run would repeat the first). A lab
/// example's second run is its run with `--json` whose numbers are asserted.
fn run_document(blocks: &[&Block], lab: &[(String, Vec<Shown>)]) {
    let sandbox = tempfile::tempdir().unwrap();
    let scripts = tempfile::tempdir().unwrap();
    let root = sandbox.path();
    for d in ["examples", "config", "calib"] {
        copy_dir(&repo().join(d), &root.join(d));
    }
    std::fs::create_dir_all(root.join("tmp")).unwrap();
    let mut again = Vec::new();
    for b in blocks {
        let before = snapshot(root);
        run_block(b, root, scripts.path(), 1);
        let numbers = lab.iter().find(|(o, _)| *o == b.origin);
        if numbers.is_some() || snapshot(root) != before {
            again.push((*b, numbers));
        }
    }
    for (b, numbers) in again {
        match numbers {
            Some((origin, cmds)) => assert_lab_numbers(origin, cmds, root),
            None => run_block(b, root, scripts.path(), 2),
        }
    }
}

#[test]
fn readme_tour_and_docs_worked_examples_run_as_written_twice() {
    let Some(_) = tofprox_testkit::require_program("dbus-run-session", "dbus-daemon") else {
        return;
    };
    let blocks: Vec<Block> = readme_tour().into_iter().chain(docs_examples()).collect();
    assert!(
        blocks.len() >= 6,
        "the tour lost its blocks: {}",
        blocks.len()
    );
    assert!(
        blocks
            .iter()
            .any(|b| b.commands.iter().any(|c| c.starts_with("tofproxd "))),
        "step 5 (the daemon) not found"
    );
    let lab = lab_examples();
    for (origin, _) in &lab {
        assert!(
            blocks.iter().any(|b| b.origin == *origin),
            "the lab example at {origin} is not a block of the tour"
        );
    }
    // each document (README.md, docs/x.md) on a thread of its own: a reader follows
    // one document's blocks in order, never one document's output in another
    let mut documents: Vec<(&str, Vec<&Block>)> = Vec::new();
    for b in &blocks {
        let file = b.origin.split(':').next().unwrap();
        match documents.iter_mut().find(|(f, _)| *f == file) {
            Some((_, bs)) => bs.push(b),
            None => documents.push((file, vec![b])),
        }
    }
    std::thread::scope(|s| {
        for (_, bs) in &documents {
            s.spawn(|| run_document(bs, &lab));
        }
    });
}

#[test]
fn extraction_finds_commands_and_documented_status() {
    assert_eq!(
        expected_status("tofprox device probe   # exits 1: \"no matching device\""),
        1
    );
    assert_eq!(expected_status("tofprox info x   # captures"), 0);
    assert_eq!(
        join_continuations(&["a \\", "  b", "c"]),
        vec!["a    b".to_string(), "c".to_string()]
    );
    let tour = readme_tour();
    assert!(
        tour.iter()
            .flat_map(|b| &b.commands)
            .any(|c| c.starts_with("tofprox lab diagnose"))
    );
    let docs = docs_examples();
    assert!(docs.iter().any(|b| b.origin.starts_with("docs/lab.md")));
    assert_eq!(
        number_after("fit: χ²/dof = 7.786, z = 1811.8", "χ²/dof = "),
        Some(7.786)
    );
    // the lab examples' numbers are checked against a transcript that has them
    let lab = lab_examples();
    let shown = lab[1].1.iter().flat_map(|(_, out)| out);
    assert!(shown.filter(|l| l.contains("χ²/dof = ")).count() >= 3);
    assert!(
        lab[0]
            .1
            .iter()
            .any(|(c, _)| c.starts_with("tofprox lab add"))
    );
}

/// A command and the output lines documented after it.
type Shown = (String, Vec<String>);

/// The README's lab block ("**3. The model lab**") and docs/lab.md's worked
/// example: (origin, commands, each command's documented output lines).
fn lab_examples() -> Vec<(String, Vec<Shown>)> {
    let readme = std::fs::read_to_string(repo().join("README.md")).unwrap();
    let at = readme
        .find("**3. The model lab**")
        .expect("README's lab step");
    let (line, _, lines) = fences(&readme[at..]).into_iter().next().unwrap();
    let first = readme[..at].lines().count();
    let readme_cmds = join_continuations(&lines)
        .into_iter()
        .filter(|c| !c.trim_start().starts_with('#'))
        .map(|c| (c, Vec::new()))
        .collect();
    let md = std::fs::read_to_string(repo().join("docs/lab.md")).unwrap();
    let at = md
        .find("## Worked example")
        .expect("docs/lab.md's worked example");
    let (dline, _, dlines) = fences(&md[at..]).into_iter().next().unwrap();
    let mut doc: Vec<Shown> = Vec::new();
    let mut open = false;
    for l in dlines {
        if let Some(c) = l.strip_prefix("$ ") {
            doc.push((c.to_string(), Vec::new()));
            open = c.trim_end().ends_with('\\');
        } else if let Some((cmd, out)) = doc.last_mut() {
            if open {
                *cmd = format!("{} {}", cmd.trim_end().trim_end_matches('\\'), l.trim());
                open = l.trim_end().ends_with('\\');
            } else {
                out.push(l.to_string());
            }
        }
    }
    let dfirst = md[..at].lines().count();
    vec![
        (format!("README.md:{}", first + line), readme_cmds),
        (format!("docs/lab.md:{}", dfirst + dline), doc),
    ]
}

/// Run `cmd` with bash in `root` (`/tmp/` → the sandbox's); `tofprox lab …`
/// with `--json`, its output parsed.
fn run_json(cmd: &str, root: &Path, path: &str) -> Option<serde_json::Value> {
    let cmd = cmd.split(" #").next().unwrap().trim();
    let lab = cmd.starts_with("tofprox lab ");
    let run = cmd.replace("/tmp/", &format!("{}/tmp/", root.display()));
    let run = if lab { format!("{run} --json") } else { run };
    let o = Command::new("bash")
        .args(["-c", &run])
        .current_dir(root)
        .env("PATH", path)
        .env("NO_COLOR", "1")
        .output()
        .unwrap();
    assert!(o.status.success(), "{run}: {}", text(&o.stderr));
    lab.then(|| serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{run}: {e}")))
}

/// The value after `--flag` in a command, as a path in the sandbox.
fn arg_path(cmd: &str, flag: &str, root: &Path) -> PathBuf {
    let mut it = cmd.split_whitespace();
    it.find(|w| *w == flag).unwrap();
    let v = it.next().unwrap();
    match v.strip_prefix("/tmp/") {
        Some(rel) => root.join("tmp").join(rel),
        None => root.join(v),
    }
}

/// The number after `key` in a documented output line.
fn number_after(line: &str, key: &str) -> Option<f64> {
    let rest = line.split(key).nth(1)?;
    rest.split(|c: char| c == ',' || c.is_whitespace() || c == ')')
        .find(|s| !s.is_empty())?
        .parse()
        .ok()
}

/// What a documented output shows of a command's `--json` result must hold
/// (χ²/dof to its printed digits, the verdict).
fn assert_transcript(origin: &str, cmd: &str, shown: &[String], v: &serde_json::Value) {
    let close = |doc: f64, got: f64, what: &str| {
        assert!(
            (doc - got).abs() <= 0.0015 * doc.max(1.0),
            "{origin}: `{cmd}` shows {what} {doc}, it gives {got}: refresh the transcript"
        );
    };
    for l in shown {
        if let Some(x) = number_after(l, "χ²/dof = ") {
            close(x, v["fit"]["chi2_per_dof"].as_f64().unwrap(), "χ²/dof");
        }
        for row in ["before", "after"] {
            if let Some(x) = l
                .strip_prefix(row)
                .and_then(|r| r.split_whitespace().last())
            {
                let got = v[row]["chi2_per_dof"].as_f64().unwrap();
                close(x.parse().unwrap(), got, &format!("χ²/dof {row}"));
            }
        }
        if let Some(verdict) = l.strip_prefix("verdict: ") {
            let want = verdict
                .split(':')
                .next()
                .unwrap()
                .to_lowercase()
                .replace(' ', "_");
            assert_eq!(want, v["verdict"].as_str().unwrap(), "{origin}: `{cmd}`");
        }
    }
}

/// diagnose names the effect the truth has and the model lacks, `add` writes
/// it near the truth and brings χ²/dof to the noise, diagnose then finds nothing.
fn assert_lab_story(origin: &str, runs: &[(String, Option<serde_json::Value>)], root: &Path) {
    let find = |sub: &'static str| runs.iter().filter(move |(c, _)| c.starts_with(sub));
    let sweep = &find("tofprox sim sweep").next().unwrap().0;
    let truth = tofprox_model::ModelConfig::load(&arg_path(sweep, "--model", root)).unwrap();
    let (add_cmd, add) = find("tofprox lab add").next().unwrap();
    let add = add.as_ref().unwrap();
    let effect = add["effect"].as_str().unwrap();
    let diags: Vec<&serde_json::Value> = find("tofprox lab diagnose")
        .map(|(_, v)| v.as_ref().unwrap())
        .collect();
    let (first, last) = (diags[0], diags[diags.len() - 1]);
    assert_eq!(
        first["verdict"], "missing_effect",
        "{origin}: {}",
        first["reason"]
    );
    assert_eq!(first["effect"], effect, "{origin}");
    assert_eq!(first["noise"]["source"]["kind"], "repeats", "{origin}");
    let top = &first["candidates"][0];
    let share = top["explained_excess"].as_f64().unwrap();
    assert!((0.9..=1.0).contains(&share), "{origin}: explains {share}");
    assert!(top["z_after"].as_f64().unwrap() >= 0.0, "{origin}");
    let chi_before = first["fit"]["chi2_per_dof"].as_f64().unwrap();
    assert!(chi_before > 2.0, "{origin}: χ²/dof before {chi_before}");
    let chi_added = add["after"]["chi2_per_dof"].as_f64().unwrap();
    assert!(
        (0.97..=1.03).contains(&chi_added),
        "{origin}: after add {chi_added}"
    );
    assert_eq!(
        last["verdict"], "nothing_missing",
        "{origin}: {}",
        last["reason"]
    );
    let chi_last = last["fit"]["chi2_per_dof"].as_f64().unwrap();
    assert!((0.97..=1.03).contains(&chi_last), "{origin}: {chi_last}");
    let written = tofprox_model::ModelConfig::load(&arg_path(add_cmd, "--out", root)).unwrap();
    let info = tofprox_model::catalogue()
        .iter()
        .find(|e| e.id == effect)
        .unwrap();
    for p in info.params {
        let (w, t) = (
            written.param(effect, p.name).unwrap(),
            truth.param(effect, p.name).unwrap(),
        );
        assert!(
            (w - t).abs() <= 0.15 * t.abs() + 0.1,
            "{origin}: {effect}.{} written {w}, truth {t}",
            p.name
        );
    }
    assert_errors_carry_their_validity(origin, add, &truth);
    eprintln!(
        "{origin}: {effect} explains {:.1}%, χ²/dof {chi_before:.3} → add {chi_added:.3} → {chi_last:.3}",
        100.0 * share
    );
}

/// `add`'s standard errors are of the noise alone: where a fitted droop
/// parameter lies more than 4 of them from the truth, the output must say the
/// errors understate (`standard_errors_note`, with the figures it rests on).
/// The lab's droop signature: rate D/τ (τ in ms), ln τ, β (docs/lab.md).
fn assert_errors_carry_their_validity(
    origin: &str,
    add: &serde_json::Value,
    truth: &tofprox_model::ModelConfig,
) {
    assert_eq!(
        add["effect"], "vcsel_droop",
        "{origin}: the examples add droop"
    );
    let t = |k: &str| truth.param("vcsel_droop", k).unwrap();
    let tau_ms = t("tau_us") / 1000.0;
    let expected = [
        ("droop_rate", t("droop_rel") / tau_ms),
        ("ln_tau", tau_ms.ln()),
        ("exposure_power", t("exposure_power")),
    ];
    let worst = expected
        .iter()
        .map(|(k, want)| {
            let got = add["params"][k].as_f64().unwrap();
            let se = add["standard_errors"][k].as_f64().unwrap();
            ((got - want) / se).abs()
        })
        .fold(0.0, f64::max);
    let note = add["standard_errors_note"].as_str();
    if worst > 4.0 {
        let n = note.unwrap_or_else(|| {
            panic!("{origin}: a value {worst:.1} errors from the truth, and no note says the errors understate")
        });
        assert!(
            n.contains("may be off by more") && n.contains("leaves χ²/dof "),
            "{origin}: {n}"
        );
    }
    eprintln!(
        "{origin}: worst fitted droop parameter {worst:.1} errors from the truth; note: {note:?}"
    );
}

/// The lab example `cmds` run again in `root` (where they ran as written), each
/// `tofprox lab` command with `--json`: the transcript's and the story's numbers.
fn assert_lab_numbers(origin: &str, cmds: &[Shown], root: &Path) {
    let path = common::path_with_bins();
    let runs: Vec<(String, Option<serde_json::Value>)> = cmds
        .iter()
        .map(|(c, shown)| {
            let v = run_json(c, root, &path);
            if let Some(v) = &v {
                assert_transcript(origin, c, shown, v);
            }
            (c.clone(), v)
        })
        .collect();
    assert_lab_story(origin, &runs, root);
}
