//! One module per command group; each owns its clap arguments.

pub mod calibrate;
pub mod common;
pub mod daemon;
pub mod device;
pub mod info;
pub mod lab;
pub mod live;
pub mod process;
pub mod sim;

use std::path::Path;

use tofprox_core::SensorGeometry;
use tofprox_format::{ErrorKind, RecordingWriter};

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
    r.map_err(|e| {
        if e.kind() == ErrorKind::AlreadyExists {
            anyhow::anyhow!(
                "{} already holds a recording: pass --force to replace it, or choose another --out",
                out.display()
            )
        } else {
            e.into()
        }
    })
}
