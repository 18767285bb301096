//! Completeness of a recording (issue 35 W1): a writer marks its recording incomplete before
//! it writes anything and removes the mark only when it has finished
//! ([`crate::RecordingWriter::finish`], [`crate::DepthRecordingWriter::finish`]). A writer
//! killed part-way — or one that returned an error — leaves the mark: the recording's
//! `recording.toml` is consistent (every capture it lists is whole, see
//! [`crate::RecordingWriter`]), but it holds fewer captures than were asked for.
//!
//! The mark is a file, [`INCOMPLETE_MARKER`], beside `recording.toml`, so the rule holds for
//! every format version: a recording (versions 1–3) without it is complete; recordings
//! written before the mark existed carry none and are taken as complete
//! (`docs/recording-format.md`, "Completeness").

use std::path::Path;

use crate::error::{ErrorKind, FormatError};
use crate::fsutil;

/// The file that marks a recording incomplete while (or because) its writer has not
/// finished.
pub const INCOMPLETE_MARKER: &str = "recording.incomplete";

const MARKER_TEXT: &str = "\
This recording is incomplete: its writer has not finished (it is still running, or it was
killed or failed part-way). recording.toml lists only the captures written whole.
`tofprox info` shows what it holds; processing refuses it. Remove this file to accept the
captures it has as the whole recording.
";

/// Mark `dir`'s recording incomplete (durably, before anything else is written).
pub(crate) fn mark_incomplete(dir: &Path) -> Result<(), FormatError> {
    fsutil::write_atomic(&dir.join(INCOMPLETE_MARKER), MARKER_TEXT.as_bytes())
}

/// Remove the mark: the recording is complete (durably: the directory is synced).
pub(crate) fn mark_complete(dir: &Path) -> Result<(), FormatError> {
    let path = dir.join(INCOMPLETE_MARKER);
    match std::fs::remove_file(&path) {
        Ok(()) => fsutil::sync_dir(dir),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(FormatError::io(
            &path,
            "cannot remove the incomplete mark",
            e,
        )),
    }
}

/// Whether `dir`'s recording is complete: no [`INCOMPLETE_MARKER`] of any file type (a link
/// or a directory of that name marks it too: nothing is followed).
pub fn is_complete(dir: &Path) -> bool {
    std::fs::symlink_metadata(dir.join(INCOMPLETE_MARKER)).is_err()
}

/// The error of a reader that needs a complete recording, for one that is not.
pub(crate) fn incomplete_error(dir: &Path, captures: usize) -> FormatError {
    FormatError::new(
        ErrorKind::Incomplete,
        format!(
            "is incomplete: its writer did not finish (killed or failed part-way; \
             {INCOMPLETE_MARKER} is present), {captures} capture(s) written whole. \
             `tofprox info` shows them; record again, or remove {INCOMPLETE_MARKER} to accept \
             them as the whole recording"
        ),
    )
    .at(dir)
}
