//! Depth recordings (`kind = "depth"`, recording format version 2 and later): depth
//! images in mm (and amplitudes), as `tofproxd` publishes them in its
//! `DepthFrame` signal and `tofprox record` stores them. Same directory layout,
//! limits, path rules and crash-safe writing as raw recordings
//! ([`crate::Recording`]); the `[sensor]` table and the raw-capture keys are
//! replaced by a `[depth]` table and per-capture image files
//! (`docs/recording-format.md`).

use std::path::{Path, PathBuf};

use ndarray::{Array2, Ix2};
use serde::{Deserialize, Serialize};

use crate::error::{ErrorKind, FormatError, invalid, parse_toml};
use crate::fsutil;
use crate::limits;
use crate::npy::{self, Dtype, NpyArray, shape_str};
use crate::recording::{
    FRAMES_DIR, FramesFiles, FramesNames, RECORDING_FORMAT, RECORDING_TOML, RECORDING_VERSION,
    RecordingKind, check_header_limits, check_window_limits, parse_recording_toml,
    prepare_new_recording, read_header, sync_new_recording, wrong_kind,
};

/// Parse and validate the text of a `recording.toml` of either kind, without touching any
/// other file (the frames files are checked by [`crate::Recording::open`] /
/// [`DepthRecording::open`]); errors name `path` and the key. For tools that check a
/// header on its own, and the fuzz target. (Here rather than in `recording`, which depth
/// recordings build on: `recording` imports nothing from this module.)
pub fn validate_recording_toml(path: &Path, text: &str) -> Result<RecordingKind, FormatError> {
    let kind = read_header(path, text)?;
    match kind {
        RecordingKind::Raw => parse_recording_toml(path, text).map(|_| kind),
        RecordingKind::Depth => parse_depth_toml(path, text).map(|_| kind),
    }
}

/// The `[depth]` table: the size of every image of a depth recording.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthImageSize {
    /// Image rows.
    pub rows: usize,
    /// Image columns.
    pub cols: usize,
}

/// One `[[capture]]` table of a depth recording.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthCaptureMeta {
    /// `.npy` file (uint16, `(rows, cols)`) of the depth in mm, 0 = invalid pixel.
    pub depth_mm: String,
    /// `.npy` file (uint16, `(rows, cols)`) of the amplitude in LSB (saturated at 65535), if
    /// recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub amplitude_lsb: Option<String>,
    /// Acquisition time, ns (the publisher's clock).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timestamp_ns: Option<u64>,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct DepthToml {
    format: String,
    version: i64,
    kind: RecordingKind,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    description: Option<String>,
    depth: DepthImageSize,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    capture: Vec<DepthCaptureMeta>,
}

type Parsed = (DepthImageSize, Option<String>, Vec<DepthCaptureMeta>);

pub(crate) fn parse_depth_toml(path: &Path, text: &str) -> Result<Parsed, FormatError> {
    let kind = read_header(path, text)?;
    if kind != RecordingKind::Depth {
        return Err(wrong_kind(path, kind));
    }
    let t: DepthToml = parse_toml(path, text)?;
    check_size(&t.depth).map_err(|e| e.at(path))?;
    check_header_limits(path, t.description.as_deref(), t.capture.len())?;
    let mut names = FramesNames::default();
    for (i, c) in t.capture.iter().enumerate() {
        names.add(path, &format!("capture[{i}].depth_mm"), &c.depth_mm)?;
        if let Some(a) = &c.amplitude_lsb {
            names.add(path, &format!("capture[{i}].amplitude_lsb"), a)?;
        }
    }
    Ok((t.depth, t.description, t.capture))
}

fn check_size(size: &DepthImageSize) -> Result<(), FormatError> {
    for (key, v) in [("rows", size.rows), ("cols", size.cols)] {
        if v == 0 {
            return Err(invalid("must be at least 1").key(format!("depth.{key}")));
        }
    }
    check_window_limits("depth", "rows", "cols", size.rows, size.cols)
}

/// An opened, validated depth recording. Images are read on demand.
#[derive(Debug, Clone)]
pub struct DepthRecording {
    dir: PathBuf,
    size: DepthImageSize,
    description: Option<String>,
    captures: Vec<DepthCaptureMeta>,
    complete: bool,
}

impl DepthRecording {
    /// Open and validate a depth recording: the TOML (format, version, `kind = "depth"`, every
    /// key) and the header of every image file (uint16, `(rows, cols)`).
    pub fn open(dir: &Path) -> Result<DepthRecording, FormatError> {
        let toml_path = dir.join(RECORDING_TOML);
        let text = limits::read_text_bounded(&toml_path, limits::MAX_TOML_BYTES)?;
        let (size, description, captures) = parse_depth_toml(&toml_path, &text)?;
        let mut files = FramesFiles::new(dir);
        for (i, c) in captures.iter().enumerate() {
            let images = [
                ("depth_mm", Some(&c.depth_mm)),
                ("amplitude_lsb", c.amplitude_lsb.as_ref()),
            ];
            for (what, name) in images {
                let Some(name) = name else { continue };
                let key = format!("capture[{i}].{what}");
                let file = files.add(&key, name)?;
                let h =
                    npy::read_header(&file, Some(dir)).map_err(|e| e.key_if_none(key.clone()))?;
                check_image(h.dtype, &h.shape, &size).map_err(|e| e.at(&file).key(key))?;
            }
        }
        Ok(DepthRecording {
            dir: dir.to_path_buf(),
            size,
            description,
            captures,
            complete: crate::completion::is_complete(dir),
        })
    }

    /// Whether the recording's writer finished ([`crate::completion`]); a depth recording is
    /// only summarised (`tofprox info`), which flags one that is not.
    pub fn is_complete(&self) -> bool {
        self.complete
    }

    /// The recording directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
    /// The `[depth]` table.
    pub fn size(&self) -> DepthImageSize {
        self.size
    }
    /// The free-text description.
    pub fn description(&self) -> Option<&str> {
        self.description.as_deref()
    }
    /// All captures, in file order.
    pub fn captures(&self) -> &[DepthCaptureMeta] {
        &self.captures
    }

    /// Capture `index`'s depth image, mm (0 = invalid).
    pub fn load_depth_mm(&self, index: usize) -> Result<Array2<u16>, FormatError> {
        let c = self.capture(index)?;
        self.load_image(&c.depth_mm, &format!("capture[{index}].depth_mm"))
    }

    /// Capture `index`'s amplitude image, LSB, if it was recorded.
    pub fn load_amplitude_lsb(&self, index: usize) -> Result<Option<Array2<u16>>, FormatError> {
        let c = self.capture(index)?;
        c.amplitude_lsb
            .as_ref()
            .map(|name| self.load_image(name, &format!("capture[{index}].amplitude_lsb")))
            .transpose()
    }

    fn capture(&self, index: usize) -> Result<&DepthCaptureMeta, FormatError> {
        self.captures.get(index).ok_or_else(|| {
            invalid(format!(
                "capture {index} does not exist ({} captures)",
                self.captures.len()
            ))
            .at(&self.dir.join(RECORDING_TOML))
        })
    }

    fn load_image(&self, name: &str, key: &str) -> Result<Array2<u16>, FormatError> {
        let file = self.dir.join(name);
        let arr = npy::read(&file, Some(&self.dir)).map_err(|e| e.key_if_none(key))?;
        let bad = |e: FormatError| e.at(&file).key(key);
        let NpyArray::U16(a) = arr else {
            return Err(bad(FormatError::new(
                ErrorKind::Npy,
                "depth recording images must be uint16 ('<u2')",
            )));
        };
        check_image(Dtype::U16, a.shape(), &self.size).map_err(bad)?;
        a.into_dimensionality::<Ix2>()
            .map_err(|e| bad(invalid(format!("expected a (rows, cols) image: {e}"))))
    }
}

fn check_image(dtype: Dtype, shape: &[usize], size: &DepthImageSize) -> Result<(), FormatError> {
    if dtype != Dtype::U16 {
        return Err(FormatError::new(
            ErrorKind::Npy,
            format!(
                "depth recording images must be uint16 ('<u2'), not {}",
                dtype.name()
            ),
        ));
    }
    if shape != [size.rows, size.cols] {
        return Err(invalid(format!(
            "image has shape {} but [depth] says {}",
            shape_str(shape),
            shape_str(&[size.rows, size.cols])
        )));
    }
    Ok(())
}

/// Appends depth images to a depth recording, crash-safely in the same way as
/// [`crate::RecordingWriter`]: image files first (temporary file, fsync, rename), then
/// `recording.toml`; marked incomplete until [`DepthRecordingWriter::finish`].
#[derive(Debug)]
pub struct DepthRecordingWriter {
    dir: PathBuf,
    size: DepthImageSize,
    description: Option<String>,
    captures: Vec<DepthCaptureMeta>,
}

impl DepthRecordingWriter {
    /// Start a new depth recording in `dir` (created if needed); refuses a directory that
    /// already holds a `recording.toml` unless `replace` (then the recording there — its
    /// `recording.toml` and frames directory — is removed first).
    pub fn create(
        dir: &Path,
        size: DepthImageSize,
        description: Option<String>,
        replace: bool,
    ) -> Result<Self, FormatError> {
        check_size(&size)?;
        if let Some(d) = &description {
            check_header_limits(&dir.join(RECORDING_TOML), Some(d), 0)?;
        }
        prepare_new_recording(dir, replace)?;
        crate::completion::mark_incomplete(dir)?;
        let w = DepthRecordingWriter {
            dir: dir.to_path_buf(),
            size,
            description,
            captures: Vec::new(),
        };
        w.write_toml()?;
        sync_new_recording(dir);
        Ok(w)
    }

    /// The image size.
    pub fn size(&self) -> DepthImageSize {
        self.size
    }

    /// The recording is complete: remove its incomplete mark ([`crate::completion`]; without
    /// this call it stays marked incomplete).
    pub fn finish(self) -> Result<(), FormatError> {
        crate::completion::mark_complete(&self.dir)
    }

    /// Number of complete captures.
    pub fn len(&self) -> usize {
        self.captures.len()
    }

    /// Whether no capture has been appended yet.
    pub fn is_empty(&self) -> bool {
        self.captures.is_empty()
    }

    /// Append one depth image (mm, 0 = invalid) and, if given, its amplitude image (LSB);
    /// returns the capture's index. On error nothing is added.
    pub fn append(
        &mut self,
        timestamp_ns: Option<u64>,
        depth_mm: &Array2<u16>,
        amplitude_lsb: Option<&Array2<u16>>,
    ) -> Result<usize, FormatError> {
        let index = self.captures.len();
        if self.captures.len() >= limits::MAX_CAPTURES {
            return Err(FormatError::new(
                ErrorKind::Limit,
                format!(
                    "a recording holds at most {} captures",
                    limits::MAX_CAPTURES
                ),
            )
            .at(&self.dir.join(RECORDING_TOML))
            .key("capture"));
        }
        let images = [
            ("depth_mm", Some(depth_mm)),
            ("amplitude_lsb", amplitude_lsb),
        ];
        for (what, a) in images {
            if let Some(a) = a {
                check_image(Dtype::U16, a.shape(), &self.size)
                    .map_err(|e| e.key(format!("capture[{index}].{what}")))?;
            }
        }
        let depth_name = format!("{FRAMES_DIR}/{index:06}_depth_mm.npy");
        let amp_name = amplitude_lsb.map(|_| format!("{FRAMES_DIR}/{index:06}_amplitude_lsb.npy"));
        let mut written = Vec::new();
        let mut write = |name: &str, a: &Array2<u16>| -> Result<(), FormatError> {
            let file = self.dir.join(name);
            fsutil::write_atomic(&file, &npy::encode_u16(a))?;
            written.push(file);
            Ok(())
        };
        let mut result = write(&depth_name, depth_mm);
        if let (Ok(()), Some(name), Some(a)) = (&result, &amp_name, amplitude_lsb) {
            result = write(name, a);
        }
        self.captures.push(DepthCaptureMeta {
            depth_mm: depth_name,
            amplitude_lsb: amp_name,
            timestamp_ns,
        });
        if let Err(e) = result.and_then(|()| self.write_toml()) {
            self.captures.pop();
            for f in written {
                let _ = std::fs::remove_file(f);
            }
            return Err(e);
        }
        Ok(index)
    }

    fn write_toml(&self) -> Result<(), FormatError> {
        let path = self.dir.join(RECORDING_TOML);
        let t = DepthToml {
            format: RECORDING_FORMAT.to_string(),
            version: RECORDING_VERSION,
            kind: RecordingKind::Depth,
            description: self.description.clone(),
            depth: self.size,
            capture: self.captures.clone(),
        };
        let text = toml::to_string(&t)
            .map_err(|e| invalid(format!("cannot serialise recording.toml: {e}")).at(&path))?;
        fsutil::write_atomic(&path, text.as_bytes())
    }
}

#[cfg(test)]
mod tests;
