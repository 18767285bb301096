//! tofprox file formats: recordings (version 2, version 1 read) and calibration sets.
//!
//! - [`Recording`] / [`RecordingWriter`]: `REC/recording.toml` +
//!   `REC/frames/NNNNNN.npy`, validated on read, crash-safe on write
//!   (`docs/recording-format.md`).
//! - [`DepthRecording`] / [`DepthRecordingWriter`]: the same layout holding
//!   depth images (`kind = "depth"`), as `tofprox record` writes them.
//! - [`CalibrationSet`]: `CALIB/calibration.toml` + checksummed `.npy`
//!   arrays (`docs/calibration.md`).
//! - [`encode_points`]: a frame's point cloud as `.npy` or `.ply`.
//! - [`extract()`]: a calibration part extracted from a recording into a set
//!   (the workflow `tofprox calibrate` runs).
//! - [`Processing`]: a recording's captures through the pipeline to depth,
//!   amplitude and the summary row `tofprox process --json` prints (the
//!   workflow `tofprox process` and the Python package run).
//!
//! Every error is a [`FormatError`] naming the file and the key.

mod calibration;
pub mod completion;
mod depth;
mod error;
mod extract;
mod fsutil;
pub mod limits;
pub mod npy;
mod points;
mod process;
mod recording;
mod text;

pub use calibration::{
    CALIBRATION_FORMAT, CALIBRATION_TOML, CALIBRATION_VERSION, CalibPart, CalibrationSet,
    ChainEntry, Dropped, PartSource, PartState, now_rfc3339, rfc3339_from_unix,
};
pub use completion::{INCOMPLETE_MARKER, is_complete};
pub use depth::{
    DepthCaptureMeta, DepthImageSize, DepthRecording, DepthRecordingWriter, validate_recording_toml,
};
pub use error::{ErrorKind, FormatError};
pub use extract::{
    Extract, ExtractError, ExtractOptions, Extraction, NO_TARGET_CONDITION, extract,
    load_lens_datasheet,
};
pub use fsutil::{create_new, write_atomic};
pub use points::{PointCloudFormat, encode_points};
pub use process::{DepthKind, ProcessError, ProcessOptions, ProcessRow, Processed, Processing};
pub use recording::{
    BOOKKEEPING_CONDITIONS, CaptureMeta, CaptureSpec, FRAMES_DIR, RECORDING_FORMAT, RECORDING_TOML,
    RECORDING_VERSION, RECORDING_VERSIONS_READ, RawFrames, Recording, RecordingKind,
    RecordingWriter, SecondFrequencyFrames, SecondFrequencyMeta, check_capture,
    is_bookkeeping_condition, recording_kind, validate_spec,
};
pub use text::fmt_num;
