//! tofprox file formats: recordings (version 1) and calibration sets.
//!
//! - [`Recording`] / [`RecordingWriter`]: `REC/recording.toml` +
//!   `REC/frames/NNNNNN.npy`, validated on read, crash-safe on write
//!   (`docs/recording-format.md`).
//! - [`CalibrationSet`]: `CALIB/calibration.toml` + checksummed `.npy`
//!   arrays (`docs/calibration.md`).
//!
//! Every error is a [`FormatError`] naming the file and the key.

mod calibration;
mod error;
mod fsutil;
pub mod npy;
mod recording;

pub use calibration::{
    CALIBRATION_FORMAT, CALIBRATION_TOML, CALIBRATION_VERSION, CalibPart, CalibrationSet,
    PartSource, now_rfc3339, rfc3339_from_unix,
};
pub use error::{ErrorKind, FormatError};
pub use recording::{
    CaptureMeta, CaptureSpec, FRAMES_DIR, RECORDING_FORMAT, RECORDING_TOML, RECORDING_VERSION,
    RawFrames, Recording, RecordingWriter, validate_spec,
};
