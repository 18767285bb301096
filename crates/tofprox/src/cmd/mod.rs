//! One module per command group; each owns its clap arguments.

pub mod calibrate;
pub mod common;
pub mod daemon;
pub mod device;
pub mod device_decode;
pub mod info;
pub mod lab;
pub mod lab_export;
pub mod live;
pub mod process;
pub mod sim;
pub mod station;

use std::path::Path;

use tofprox_core::SensorGeometry;
use tofprox_format::{ErrorKind, FormatError, RecordingWriter};

/// The writer of a command's output recording: refuses to overwrite an
/// existing recording unless `force` (the commands' `--force`), and says so.
pub fn new_recording(
    out: &Path,
    sensor: SensorGeometry,
    description: Option<String>,
    force: bool,
) -> anyhow::Result<RecordingWriter> {
    let r = if force {
        RecordingWriter::replace(out, sensor, description)
    } else {
        RecordingWriter::create(out, sensor, description)
    };
    r.map_err(|e| output_error(out, e))
}

/// A writer's error for `--out`, saying how to get past an existing recording.
pub fn output_error(out: &Path, e: FormatError) -> anyhow::Error {
    if e.kind() == ErrorKind::AlreadyExists {
        anyhow::anyhow!(
            "{} already holds a recording: pass --force to replace it, or choose another --out",
            out.display()
        )
    } else {
        e.into()
    }
}
