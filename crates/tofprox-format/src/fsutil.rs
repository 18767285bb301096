//! Crash-safe file replacement: write a temporary file beside the target,
//! fsync it, rename it over the target, fsync the directory. Nothing is ever
//! written through a link: the temporary file is created new (`O_EXCL |
//! O_NOFOLLOW`, a planted link in its place is removed, never followed) and the
//! rename replaces a link at the target name instead of writing where it points.

use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

use crate::error::FormatError;

/// Suffix of temporary files; readers ignore such files, writers remove them.
pub const TMP_SUFFIX: &str = ".tmp";

/// The temporary name used while `path` is being written.
pub fn tmp_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(TMP_SUFFIX);
    path.with_file_name(name)
}

/// Create `path` as a new regular file (mode 0644 before the umask), never through a
/// link: `O_CREAT | O_EXCL | O_NOFOLLOW` fail on anything already there, a symlink
/// (even a dangling one) included.
pub fn create_new(path: &Path) -> Result<File, FormatError> {
    OpenOptions::new()
        .write(true)
        .create_new(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
        .mode(0o644)
        .open(path)
        .map_err(|e| FormatError::io(path, "cannot create (a new file, never through a link)", e))
}

/// Atomically replace `path` with `bytes`: after a crash at any point the
/// file holds either its old content (or does not exist) or the new content.
/// A symlink at `path` or at its temporary name is replaced, never followed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), FormatError> {
    let tmp = tmp_path(path);
    {
        // a leftover (or planted) temporary name: the name itself goes, not what it points to
        match fs::remove_file(&tmp) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => {
                return Err(FormatError::io(
                    &tmp,
                    "cannot remove the old temporary file",
                    e,
                ));
            }
        }
        let mut f = create_new(&tmp)?;
        f.write_all(bytes)
            .map_err(|e| FormatError::io(&tmp, "cannot write", e))?;
        f.sync_all()
            .map_err(|e| FormatError::io(&tmp, "cannot fsync", e))?;
    }
    fs::rename(&tmp, path)
        .map_err(|e| FormatError::io(path, "cannot rename the temporary file onto", e))?;
    sync_dir(path.parent().unwrap_or(Path::new(".")))
}

/// fsync a directory so that a rename inside it is durable.
pub fn sync_dir(dir: &Path) -> Result<(), FormatError> {
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let f = File::open(dir).map_err(|e| FormatError::io(dir, "cannot open directory", e))?;
    f.sync_all()
        .map_err(|e| FormatError::io(dir, "cannot fsync directory", e))
}

/// Remove leftover temporary files (`*.tmp`) directly inside `dir`.
pub fn remove_tmp_files(dir: &Path) -> Result<usize, FormatError> {
    let mut n = 0;
    let rd = match fs::read_dir(dir) {
        Ok(rd) => rd,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(FormatError::io(dir, "cannot list directory", e)),
    };
    for entry in rd.flatten() {
        let p = entry.path();
        // a regular file or a link (removed as a name, never followed)
        let removable = entry
            .file_type()
            .is_ok_and(|t| t.is_file() || t.is_symlink());
        if removable && p.to_string_lossy().ends_with(TMP_SUFFIX) {
            fs::remove_file(&p)
                .map_err(|e| FormatError::io(&p, "cannot remove temporary file", e))?;
            n += 1;
        }
    }
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A link planted at the target or at its temporary name is replaced, and the file it
    /// points to keeps its content.
    #[test]
    fn write_atomic_never_writes_through_a_planted_link() {
        let t = tempfile::tempdir().unwrap();
        let victim = t.path().join("victim");
        fs::write(&victim, b"precious").unwrap();
        let out = t.path().join("out");
        fs::create_dir(&out).unwrap();
        let target = out.join("offset.npy");
        std::os::unix::fs::symlink(&victim, tmp_path(&target)).unwrap();
        write_atomic(&target, b"new").unwrap();
        assert_eq!(fs::read(&victim).unwrap(), b"precious");
        assert_eq!(fs::read(&target).unwrap(), b"new");
        assert!(!fs::symlink_metadata(&target).unwrap().is_symlink());
        let other = out.join("000000_depth_mm.npy");
        std::os::unix::fs::symlink("../victim", &other).unwrap();
        write_atomic(&other, b"depth").unwrap();
        assert_eq!(fs::read(&victim).unwrap(), b"precious");
        assert_eq!(fs::read(&other).unwrap(), b"depth");
        assert!(!fs::symlink_metadata(&other).unwrap().is_symlink());
    }

    #[test]
    fn create_new_refuses_an_existing_name_or_link() {
        let t = tempfile::tempdir().unwrap();
        let victim = t.path().join("victim");
        fs::write(&victim, b"precious").unwrap();
        let link = t.path().join("link");
        std::os::unix::fs::symlink(&victim, &link).unwrap();
        let dangling = t.path().join("dangling");
        std::os::unix::fs::symlink(t.path().join("nowhere"), &dangling).unwrap();
        for p in [&victim, &link, &dangling] {
            let e = create_new(p).unwrap_err();
            assert!(e.to_string().contains("never through a link"), "{e}");
        }
        assert!(!t.path().join("nowhere").exists());
        assert_eq!(fs::read(&victim).unwrap(), b"precious");
    }
}
