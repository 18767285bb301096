//! Helpers shared by the command-line end-to-end tests.
#![allow(dead_code)] // each test binary uses a subset of the helpers
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use tofprox_model::ModelConfig;

/// Run the `tofprox` binary built for this test run with `args`.
pub fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tofprox"))
        .args(args)
        .output()
        .expect("run tofprox")
}

/// The repository's root (the workspace above `crates/tofprox`).
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A path below the repository's root, as a command-line argument.
pub fn repo_file(rel: &str) -> String {
    repo().join(rel).to_string_lossy().into_owned()
}

/// Lossy UTF-8 text of captured output.
pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// What [`lab_sweep`] wrote: paths as strings, ready for `run`.
pub struct LabSweep {
    /// The simulated recording.
    pub rec: String,
    /// The baseline model (what the lab starts from).
    pub base: String,
    /// The model the recording was simulated with.
    pub truth: String,
}

/// The sweep the lab tests diagnose: `tofprox sim sweep` of `truth` (16×16 window at the
/// centre, 0.15–1.80 m in 12 steps, 250 and 1000 µs, 2 repeats, 16 averaged) into
/// `dir/rec`, with the truth and the baseline model written beside it.
pub fn lab_sweep(dir: &Path, truth: &ModelConfig, seed: u64) -> LabSweep {
    let s = |p: &Path| p.to_string_lossy().into_owned();
    let truth_p = dir.join("truth.toml");
    std::fs::write(&truth_p, truth.to_toml_string()).unwrap();
    let base_p = dir.join("base.toml");
    std::fs::write(&base_p, ModelConfig::baseline().to_toml_string()).unwrap();
    let rec = dir.join("rec");
    let seed = seed.to_string();
    let o = run(&[
        "sim",
        "sweep",
        "--model",
        &s(&truth_p),
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
        &seed,
        "--out",
        &s(&rec),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    LabSweep {
        rec: s(&rec),
        base: s(&base_p),
        truth: s(&truth_p),
    }
}

/// The directory of the `tofprox` binary under test, asserting that `tofproxd` is built beside
/// it (`cargo test --workspace` builds both; or `cargo build -p tofproxd`): a test that needs
/// the daemon fails without it instead of passing unseen.
pub fn bin_dir() -> PathBuf {
    let bin = Path::new(env!("CARGO_BIN_EXE_tofprox"))
        .parent()
        .expect("the binary has a directory")
        .to_path_buf();
    assert!(
        bin.join("tofproxd").is_file(),
        "{} missing (cargo test --workspace builds it; or cargo build -p tofproxd)",
        bin.join("tofproxd").display()
    );
    bin
}

/// `PATH` with [`bin_dir`] first, so commands run as written (`tofprox …`, `tofproxd …`).
pub fn path_with_bins() -> String {
    format!(
        "{}:{}",
        bin_dir().display(),
        std::env::var("PATH").unwrap_or_default()
    )
}

/// Copy the directory tree `src` to `dst` (files keep their permissions).
pub fn copy_dir(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        let to = dst.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to);
        } else {
            std::fs::copy(e.path(), to).unwrap();
        }
    }
}
