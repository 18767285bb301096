//! The one place that decides what a test does when an external tool it drives
//! (`dbus-daemon`, `busctl`, `monitor-sensor`, `systemd-analyze`, python3 with dbus-python…)
//! is missing: with `CI` set it **fails** the test, otherwise it skips it **loudly** on the
//! real standard error (visible without `--nocapture`) and the test returns early.
//! `.ci/run` installs every tool named here; the README's set-up section lists them.

use std::ffi::OsStr;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// Whether a missing tool fails the test: the environment variable `CI` is set
/// to anything but empty, `0` or `false` (CI services set `CI=true`).
pub fn in_ci() -> bool {
    ci_value_is_set(std::env::var_os("CI").as_deref())
}

fn ci_value_is_set(v: Option<&OsStr>) -> bool {
    v.is_some_and(|v| !v.is_empty() && v != "0" && !v.eq_ignore_ascii_case("false"))
}

/// The executable `program` on `PATH`, or — when it is missing — a failed test
/// in CI and a loud skip elsewhere (`None`: the caller returns).
/// `package` is the Debian package that provides it.
///
/// ```no_run
/// let Some(_busctl) = tofprox_testkit::require_program("busctl", "systemd") else { return };
/// ```
pub fn require_program(program: &str, package: &str) -> Option<PathBuf> {
    let found = find_on_path(program, std::env::var_os("PATH").as_deref());
    match found {
        Some(p) => Some(p),
        None => missing(in_ci(), &format!("`{program}` (not on PATH)"), package),
    }
}

/// A `python3` that can run `import_line` (e.g. `"import dbus"`): the system
/// interpreter `/usr/bin/python3` first (where Debian's python3-* packages
/// install), then `python3` on `PATH`. When none can, the test fails in CI
/// and skips loudly elsewhere (`None`). `packages` names the Debian packages.
pub fn require_python(import_line: &str, packages: &str) -> Option<PathBuf> {
    let candidates = [
        Some(PathBuf::from("/usr/bin/python3")),
        find_on_path("python3", std::env::var_os("PATH").as_deref()),
    ];
    for p in candidates.into_iter().flatten() {
        let ok = Command::new(&p)
            .args(["-c", import_line])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        if ok {
            return Some(p);
        }
    }
    missing(
        in_ci(),
        &format!("python3 able to `{import_line}`"),
        packages,
    )
}

/// An executable regular file named `program` in one of the `path` directories.
fn find_on_path(program: &str, path: Option<&OsStr>) -> Option<PathBuf> {
    use std::os::unix::fs::PermissionsExt;
    let is_exe = |p: &Path| {
        p.metadata()
            .is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
    };
    std::env::split_paths(path?)
        .map(|dir| dir.join(program))
        .find(|p| is_exe(p))
}

/// Fail (in CI) or announce the skip on the process's real standard error —
/// `std::io::stderr()` is not captured by the test harness, unlike `eprintln!`.
fn missing<T>(ci: bool, what: &str, package: &str) -> Option<T> {
    missing_to(ci, what, package, &mut std::io::stderr().lock())
}

fn missing_to<T>(ci: bool, what: &str, package: &str, out: &mut impl Write) -> Option<T> {
    let current = std::thread::current();
    let test = current.name().unwrap_or("test");
    if ci {
        panic!("{test}: {what} is required (CI is set); install it: apt-get install {package}");
    }
    let _ = writeln!(
        out,
        "\n!!!!! SKIPPED {test}: {what} is missing; install it (apt-get install {package}) — with CI=true this test fails !!!!!\n"
    );
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ci_is_set_unless_empty_zero_or_false() {
        assert!(ci_value_is_set(Some(OsStr::new("true"))));
        assert!(ci_value_is_set(Some(OsStr::new("1"))));
        assert!(!ci_value_is_set(None));
        assert!(!ci_value_is_set(Some(OsStr::new(""))));
        assert!(!ci_value_is_set(Some(OsStr::new("0"))));
        assert!(!ci_value_is_set(Some(OsStr::new("FALSE"))));
    }

    #[test]
    fn finds_only_executable_files_on_the_path() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let exe = dir.path().join("tool");
        std::fs::write(&exe, "#!/bin/sh\n").unwrap();
        std::fs::set_permissions(&exe, std::fs::Permissions::from_mode(0o755)).unwrap();
        std::fs::write(dir.path().join("data"), "").unwrap();
        std::fs::create_dir(dir.path().join("subdir")).unwrap();
        let path = dir.path().as_os_str();
        assert_eq!(find_on_path("tool", Some(path)), Some(exe));
        assert_eq!(find_on_path("data", Some(path)), None);
        assert_eq!(find_on_path("subdir", Some(path)), None);
        assert_eq!(find_on_path("absent", Some(path)), None);
        assert_eq!(find_on_path("tool", None), None);
    }

    #[test]
    fn a_missing_tool_skips_loudly_outside_ci() {
        let mut out = Vec::new();
        assert_eq!(missing_to::<PathBuf>(false, "`x`", "x-pkg", &mut out), None);
        let out = String::from_utf8(out).unwrap();
        assert!(
            out.contains(
                "SKIPPED ci::tests::a_missing_tool_skips_loudly_outside_ci: `x` is missing"
            ) && out.contains("apt-get install x-pkg"),
            "{out}"
        );
    }

    #[test]
    #[should_panic(expected = "is required (CI is set); install it: apt-get install x-pkg")]
    fn a_missing_tool_fails_in_ci() {
        let _ = missing_to::<PathBuf>(true, "`x`", "x-pkg", &mut Vec::new());
    }
}
