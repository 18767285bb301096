//! Crash-safe file replacement: write a temporary file beside the target,
//! fsync it, rename it over the target, fsync the directory.

use std::fs::{self, File};
use std::io::Write;
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

/// Atomically replace `path` with `bytes`: after a crash at any point the
/// file holds either its old content (or does not exist) or the new content.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), FormatError> {
    let tmp = tmp_path(path);
    {
        let mut f = File::create(&tmp).map_err(|e| FormatError::io(&tmp, "cannot create", e))?;
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
        if p.is_file() && p.to_string_lossy().ends_with(TMP_SUFFIX) {
            fs::remove_file(&p)
                .map_err(|e| FormatError::io(&p, "cannot remove temporary file", e))?;
            n += 1;
        }
    }
    Ok(n)
}
