//! The tour as a test (issue 13): every command of README.md's "Tour" and of
//! the worked examples in docs/*.md runs as written, extracted from the
//! Markdown (never copied here), twice (re-running a step works).
//!
//! What is extracted: in README.md every ```sh block between "## Tour" and the
//! next "## " heading; in docs/*.md every fenced block with `$ ` prompts (the
//! prompt lines and their `\` continuations are commands, the rest is output).
//! How they run: one bash script per block in a sandbox holding copies of
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

#[test]
fn readme_tour_and_docs_worked_examples_run_as_written_twice() {
    let Some(_) = tofprox_e2e::require_program("dbus-run-session", "dbus-daemon") else {
        return;
    };
    let sandbox = tempfile::tempdir().unwrap();
    let root = sandbox.path();
    for d in ["examples", "config", "calib"] {
        copy_dir(&repo().join(d), &root.join(d));
    }
    std::fs::create_dir_all(root.join("tmp")).unwrap();
    let path = common::path_with_bins();
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
    for round in 1..=2 {
        for b in &blocks {
            let sh = root.join("block.sh");
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
                .env("PATH", &path)
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
    }
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
}
