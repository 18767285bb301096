//! The documented limits of every file this crate reads (`docs/recording-format.md`,
//! `docs/calibration.md`), and the one bounded reader that enforces them.
//!
//! Every file is opened through [`open_regular`]: only regular files (no FIFO,
//! device, socket or directory — opened non-blocking so that none can hang the
//! caller), of at most a given size, and — for frames and calibration arrays —
//! inside the recording or set (symlinks followed; checked on the opened file,
//! so a path swapped between a check and the open cannot lead outside).

use std::fs::{File, Metadata, OpenOptions};
use std::io::Read;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

use crate::error::{ErrorKind, FormatError};

/// Largest `recording.toml` or `calibration.toml`, bytes.
pub const MAX_TOML_BYTES: u64 = 4 << 20;
/// Largest `description`, bytes.
pub const MAX_DESCRIPTION_BYTES: usize = 64 << 10;
/// Most `[[capture]]` tables in one recording.
pub const MAX_CAPTURES: usize = 32_768;
/// Largest sensor window or full array side, pixels (the IRS1645 is 224 × 172).
pub const MAX_SIDE_PIXELS: usize = 4096;
/// Largest pixel count of a window or full array (1 Mpx).
pub const MAX_PIXELS: usize = 1 << 20;
/// Largest `.npy` file (frames or calibration array), bytes.
pub const MAX_NPY_BYTES: u64 = 1 << 30;
/// Largest magnitude of a stored phase correction (wiggling table, FPPN map),
/// rad: a phase is defined modulo one period 2π, so a larger stored value is
/// not a measurement (thesis 2.3.1.4, 3.3.6).
pub const MAX_PHASE_CORRECTION_RAD: f32 = std::f32::consts::TAU;

fn limit(path: &Path, message: String) -> FormatError {
    FormatError::new(ErrorKind::Limit, message).at(path)
}

/// Open `path` for reading if it is a regular file of at most `max_bytes`,
/// lying inside `inside` (canonicalised) when given. The open does not block on
/// a FIFO; type, size and containment are checked on the opened file.
pub fn open_regular(
    path: &Path,
    max_bytes: u64,
    inside: Option<&Path>,
) -> Result<(File, Metadata), FormatError> {
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY | libc::O_CLOEXEC)
        .open(path)
        .map_err(|e| FormatError::io(path, "cannot open", e))?;
    if let Some(root) = inside {
        check_open_inside(&file, path, root)?;
    }
    let meta = file
        .metadata()
        .map_err(|e| FormatError::io(path, "cannot stat", e))?;
    if !meta.is_file() {
        return Err(limit(
            path,
            format!(
                "is not a regular file ({}); only regular files are read",
                file_type_name(&meta)
            ),
        ));
    }
    if meta.len() > max_bytes {
        return Err(limit(
            path,
            format!(
                "is {} bytes, more than the limit of {max_bytes} bytes",
                meta.len()
            ),
        ));
    }
    Ok((file, meta))
}

/// Read a whole file through [`open_regular`]; never more than `max_bytes`
/// (a file that grows while it is read is refused).
pub fn read_bounded(
    path: &Path,
    max_bytes: u64,
    inside: Option<&Path>,
) -> Result<Vec<u8>, FormatError> {
    let (file, meta) = open_regular(path, max_bytes, inside)?;
    let mut buf = Vec::with_capacity(meta.len() as usize);
    file.take(max_bytes + 1)
        .read_to_end(&mut buf)
        .map_err(|e| FormatError::io(path, "cannot read", e))?;
    if buf.len() as u64 > max_bytes {
        return Err(limit(
            path,
            format!("grew beyond the limit of {max_bytes} bytes while being read"),
        ));
    }
    Ok(buf)
}

/// [`read_bounded`] as UTF-8 text.
pub fn read_text_bounded(path: &Path, max_bytes: u64) -> Result<String, FormatError> {
    let bytes = read_bounded(path, max_bytes, None)?;
    String::from_utf8(bytes).map_err(|e| {
        FormatError::new(
            ErrorKind::Syntax,
            format!("is not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        )
        .at(path)
    })
}

/// `path`, symlinks resolved, lies inside `root` (also resolved). A check of a name only:
/// what is read is checked again on the opened file ([`open_regular`]).
pub fn check_inside(path: &Path, root: &Path) -> Result<PathBuf, FormatError> {
    let real = path
        .canonicalize()
        .map_err(|e| FormatError::io(path, "cannot open", e))?;
    real_inside(real, path, root)
}

/// The opened `file` (opened as `path`) lies inside `root`: its real path is the one the
/// kernel holds for the descriptor (`/proc/self/fd/N`), not a name resolved again.
pub fn check_open_inside(file: &File, path: &Path, root: &Path) -> Result<PathBuf, FormatError> {
    use std::os::fd::AsRawFd;
    let fd_link = PathBuf::from(format!("/proc/self/fd/{}", file.as_raw_fd()));
    let real = std::fs::read_link(&fd_link)
        .map_err(|e| FormatError::io(path, "cannot find the opened file's real path", e))?;
    real_inside(real, path, root)
}

fn real_inside(real: PathBuf, path: &Path, root: &Path) -> Result<PathBuf, FormatError> {
    let root_c = root
        .canonicalize()
        .map_err(|e| FormatError::io(root, "cannot resolve", e))?;
    if !real.starts_with(&root_c) {
        return Err(limit(
            path,
            format!(
                "resolves to {}, outside {} (symlinks must stay inside it)",
                real.display(),
                root_c.display()
            ),
        ));
    }
    Ok(real)
}

fn file_type_name(meta: &Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_a_fifo_without_blocking() {
        let t = tempfile::tempdir().unwrap();
        let fifo = t.path().join("f.npy");
        let st = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(st.success());
        let e = read_bounded(&fifo, 100, None).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Limit);
        assert!(e.to_string().contains("a FIFO"), "{e}");
    }

    #[test]
    fn refuses_a_device_and_a_directory() {
        let e = read_bounded(Path::new("/dev/zero"), 100, None).unwrap_err();
        assert!(e.to_string().contains("character device"), "{e}");
        let t = tempfile::tempdir().unwrap();
        let e = read_bounded(t.path(), 100, None).unwrap_err();
        assert!(e.to_string().contains("a directory"), "{e}");
    }

    #[test]
    fn refuses_a_file_above_the_limit() {
        let t = tempfile::tempdir().unwrap();
        let p = t.path().join("x");
        std::fs::write(&p, [0u8; 101]).unwrap();
        let e = read_bounded(&p, 100, None).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Limit);
        assert!(e.to_string().contains("101 bytes"), "{e}");
        assert_eq!(read_bounded(&p, 101, None).unwrap().len(), 101);
    }

    /// The containment check is made on the descriptor that is read: a name swapped from an
    /// outside to an inside target after the open does not make the outside file pass.
    #[test]
    fn containment_is_checked_on_the_opened_file_not_the_name() {
        let t = tempfile::tempdir().unwrap();
        let root = t.path().join("rec");
        std::fs::create_dir(&root).unwrap();
        let outside = t.path().join("secret");
        std::fs::write(&outside, b"x").unwrap();
        std::fs::write(root.join("inside.npy"), b"y").unwrap();
        let name = root.join("000000.npy");
        std::os::unix::fs::symlink(&outside, &name).unwrap();
        let opened = File::open(&name).unwrap();
        // the attacker flips the name to an inside target after the open
        std::fs::remove_file(&name).unwrap();
        std::os::unix::fs::symlink("inside.npy", &name).unwrap();
        assert!(
            check_inside(&name, &root).is_ok(),
            "the name now looks fine"
        );
        let e = check_open_inside(&opened, &name, &root).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Limit);
        assert!(e.to_string().contains("outside"), "{e}");
        let opened = File::open(&name).unwrap();
        assert_eq!(
            check_open_inside(&opened, &name, &root).unwrap(),
            root.canonicalize().unwrap().join("inside.npy")
        );
    }

    #[test]
    fn refuses_a_symlink_out_of_the_root() {
        let t = tempfile::tempdir().unwrap();
        let root = t.path().join("rec");
        std::fs::create_dir(&root).unwrap();
        let outside = t.path().join("secret");
        std::fs::write(&outside, b"x").unwrap();
        std::os::unix::fs::symlink(&outside, root.join("a.npy")).unwrap();
        std::fs::write(root.join("b.npy"), b"y").unwrap();
        std::os::unix::fs::symlink("b.npy", root.join("c.npy")).unwrap();
        let e = read_bounded(&root.join("a.npy"), 100, Some(&root)).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Limit);
        assert!(e.to_string().contains("outside"), "{e}");
        // a symlink that stays inside is followed
        assert_eq!(
            read_bounded(&root.join("c.npy"), 100, Some(&root)).unwrap(),
            b"y"
        );
    }
}
