//! Where the shipped data is (the demo configuration, the emulated sensor's factory
//! calibration, model files): a directory laid out like the repository, with `config/` and
//! `calib/`. No path is compiled into the binaries; the data is looked up, in this order,
//!
//! 1. under the executable's install prefix, `<exe>/../share/tofprox` (`/usr/bin/tofproxd` →
//!    `/usr/share/tofprox`, as the Debian package installs it; `/usr/local/bin` →
//!    `/usr/local/share/tofprox`),
//! 2. in the source tree the executable was built in (`<tree>/target/<profile>/tofproxd` →
//!    `<tree>`), only when that tree exists,
//! 3. in [`INSTALLED_DATA_DIR`] (a binary copied elsewhere on a machine with the package),
//! 4. in the current directory when it is a source tree (`cargo run` with another target dir).

use std::path::{Path, PathBuf};

/// The package's data directory (`packaging/build-deb.sh` installs `config/` and `calib/` here).
pub const INSTALLED_DATA_DIR: &str = "/usr/share/tofprox";

/// A data file was found in none of the places it is looked up in.
#[derive(Debug, thiserror::Error)]
#[error(
    "{wanted} not found in the installed data ({INSTALLED_DATA_DIR}), beside the executable or in a source tree (tried {})",
    tried.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
)]
pub struct DataNotFound {
    /// The path asked for, relative to a data directory (`config/tofproxd-emulated.toml`).
    pub wanted: String,
    /// Every full path that was tried, in order.
    pub tried: Vec<PathBuf>,
}

/// The data directories to look in, best first, for an executable at `exe` run in `cwd`
/// (pure: nothing is checked on disk). A source tree (2. and 4.) is offered only when
/// `is_source_tree` says the directory is one.
pub fn data_roots(
    exe: Option<&Path>,
    cwd: Option<&Path>,
    is_source_tree: impl Fn(&Path) -> bool,
) -> Vec<PathBuf> {
    let mut roots = Vec::new();
    let bin_dir = exe.and_then(Path::parent);
    if let Some(prefix) = bin_dir.and_then(Path::parent) {
        roots.push(prefix.join("share/tofprox"));
        // target/<profile>/ → the tree holding target/
        if let Some(tree) = prefix.parent().filter(|t| is_source_tree(t)) {
            roots.push(tree.to_path_buf());
        }
    }
    roots.push(PathBuf::from(INSTALLED_DATA_DIR));
    if let Some(cwd) = cwd.filter(|c| is_source_tree(c)) {
        roots.push(cwd.to_path_buf());
    }
    roots.dedup();
    roots
}

/// A directory is a tofprox source tree when it has the workspace manifest and `config/`.
fn is_source_tree(dir: &Path) -> bool {
    dir.join("Cargo.toml").is_file() && dir.join("config").is_dir()
}

/// The first existing `<root>/<rel>` over [`data_roots`] for this process, made absolute
/// without `..` (so messages name the real place), or which paths were tried.
pub fn find(rel: &str) -> Result<PathBuf, DataNotFound> {
    let exe = std::env::current_exe()
        .ok()
        .map(|e| std::fs::canonicalize(&e).unwrap_or(e));
    let cwd = std::env::current_dir().ok();
    let tried: Vec<PathBuf> = data_roots(exe.as_deref(), cwd.as_deref(), is_source_tree)
        .into_iter()
        .map(|root| root.join(rel))
        .collect();
    match tried.iter().find(|p| p.exists()) {
        Some(p) => Ok(std::fs::canonicalize(p).unwrap_or_else(|_| p.clone())),
        None => Err(DataNotFound {
            wanted: rel.to_string(),
            tried,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn installed_binary_looks_under_its_prefix_first() {
        let roots = data_roots(Some(Path::new("/opt/x/bin/tofproxd")), None, |_| true);
        assert_eq!(roots[0], Path::new("/opt/x/share/tofprox"));
        assert!(roots.contains(&PathBuf::from(INSTALLED_DATA_DIR)));
    }

    #[test]
    fn source_tree_only_when_it_is_one() {
        let exe = Path::new("/src/tofprox/target/debug/tofproxd");
        let tree = PathBuf::from("/src/tofprox");
        let with = data_roots(Some(exe), None, |d| d == tree);
        assert_eq!(
            with,
            vec![
                PathBuf::from("/src/tofprox/target/share/tofprox"),
                tree.clone(),
                PathBuf::from(INSTALLED_DATA_DIR)
            ]
        );
        let without = data_roots(Some(exe), Some(Path::new("/home/u")), |_| false);
        assert!(!without.contains(&tree), "{without:?}");
        assert!(!without.contains(&PathBuf::from("/home/u")), "{without:?}");
    }

    #[test]
    fn missing_data_names_every_place_tried() {
        let e = find("config/no-such-file-anywhere.toml").unwrap_err();
        let msg = e.to_string();
        assert!(msg.starts_with("config/no-such-file-anywhere.toml not found"));
        assert!(msg.contains("/usr/share/tofprox/config/no-such-file-anywhere.toml"));
        assert!(e.tried.len() >= 2, "{:?}", e.tried);
    }
}
