//! The recording reader: [`Recording`] (`recording.toml` and the header of every frames file
//! checked on open, frames read on demand).

use super::*;

/// An opened, validated recording. Frame data is read on demand by [`Recording::load`].
#[derive(Debug, Clone)]
pub struct Recording {
    pub(super) dir: PathBuf,
    pub(super) sensor: SensorGeometry,
    /// The convention the file's shifts are written in (every `phases_deg` in memory is
    /// canonical); what [`RecordingWriter::open_append`] keeps writing in.
    pub(super) convention: PhaseConvention,
    pub(super) description: Option<String>,
    pub(super) captures: Vec<CaptureMeta>,
    pub(super) dtypes: Vec<Dtype>,
    /// No `recording.incomplete` ([`crate::completion`]).
    pub(super) complete: bool,
}

impl Recording {
    /// Open and validate a complete recording directory: the TOML (format, version,
    /// every key), and the header and size of every frames file. Values
    /// inside the frames (NaN, codes out of range) are checked by `load`. A recording whose
    /// writer did not finish ([`crate::completion`]) is refused ([`ErrorKind::Incomplete`]);
    /// [`Recording::inspect`] opens it too.
    pub fn open(dir: &Path) -> Result<Recording, FormatError> {
        let rec = Self::inspect(dir)?;
        if !rec.complete {
            return Err(crate::completion::incomplete_error(dir, rec.captures.len()));
        }
        Ok(rec)
    }

    /// [`Recording::open`] that also opens an incomplete recording (one whose writer was
    /// killed or failed part-way): every capture it lists is whole and checked the same way;
    /// [`Recording::is_complete`] tells which it is. For `tofprox info` and for appending.
    pub fn inspect(dir: &Path) -> Result<Recording, FormatError> {
        let toml_path = dir.join(RECORDING_TOML);
        if !dir.is_dir() {
            return Err(FormatError::new(
                ErrorKind::Io,
                "is not a directory (a recording is a directory with recording.toml)",
            )
            .at(dir));
        }
        let text = limits::read_text_bounded(&toml_path, limits::MAX_TOML_BYTES)?;
        let (sensor, convention, description, captures) = parse_recording_toml(&toml_path, &text)?;
        let mut dtypes = Vec::with_capacity(captures.len());
        let mut files = FramesFiles::new(dir);
        for (i, c) in captures.iter().enumerate() {
            let key = format!("capture[{i}].frames");
            let file = files.add(&key, &c.frames)?;
            let h = npy::read_header(&file, Some(dir)).map_err(|e| e.key_if_none(key.clone()))?;
            check_shape(&h.shape, &sensor, c.phases_deg.len())
                .map_err(|e| e.at(&file).key(key.clone()))?;
            dtypes.push(h.dtype);
            if let Some(s) = &c.second_frequency {
                let key = format!("capture[{i}].second_frequency.frames");
                let file = files.add(&key, &s.frames)?;
                let h2 =
                    npy::read_header(&file, Some(dir)).map_err(|e| e.key_if_none(key.clone()))?;
                check_shape(&h2.shape, &sensor, s.phases_deg.len())
                    .map_err(|e| e.at(&file).key(key.clone()))?;
            }
        }
        Ok(Recording {
            dir: dir.to_path_buf(),
            sensor,
            convention,
            description,
            captures,
            dtypes,
            complete: crate::completion::is_complete(dir),
        })
    }

    /// Whether the recording's writer finished (no `recording.incomplete`,
    /// [`crate::completion`]); always true of a recording [`Recording::open`] returned.
    pub fn is_complete(&self) -> bool {
        self.complete
    }

    /// The recording directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
    /// The `[sensor]` table.
    pub fn sensor(&self) -> &SensorGeometry {
        &self.sensor
    }
    /// The free-text description.
    pub fn description(&self) -> Option<&str> {
        self.description.as_deref()
    }
    /// All captures, in file order.
    pub fn captures(&self) -> &[CaptureMeta] {
        &self.captures
    }
    /// The element type of capture `index`'s frames file.
    pub fn dtype(&self, index: usize) -> Option<Dtype> {
        self.dtypes.get(index).copied()
    }
    /// Full path of capture `index`'s frames file.
    pub fn frames_path(&self, index: usize) -> Option<PathBuf> {
        self.captures.get(index).map(|c| self.dir.join(&c.frames))
    }

    /// Read and validate capture `index`'s raw images.
    pub fn load(&self, index: usize) -> Result<RawFrames, FormatError> {
        let Some(meta) = self.captures.get(index) else {
            return Err(invalid(format!(
                "capture {index} does not exist ({} captures)",
                self.captures.len()
            ))
            .at(&self.dir.join(RECORDING_TOML)));
        };
        let file = self.dir.join(&meta.frames);
        let key = format!("capture[{index}].frames");
        let arr = npy::read(&file, Some(&self.dir)).map_err(|e| e.key_if_none(key.clone()))?;
        let frames = to_raw_frames(arr).map_err(|e| e.at(&file).key(key.clone()))?;
        frames
            .validate(&self.sensor, meta.phases_deg.len())
            .map_err(|e| e.at(&file).key(key))?;
        Ok(frames)
    }

    /// Read and validate capture `index`'s second-frequency images (format version 3):
    /// `None` when the capture has none.
    pub fn load_second_frequency(&self, index: usize) -> Result<Option<RawFrames>, FormatError> {
        let Some(s) = self
            .captures
            .get(index)
            .and_then(|c| c.second_frequency.as_ref())
        else {
            return Ok(None);
        };
        let file = self.dir.join(&s.frames);
        let key = format!("capture[{index}].second_frequency.frames");
        let arr = npy::read(&file, Some(&self.dir)).map_err(|e| e.key_if_none(key.clone()))?;
        let frames = to_raw_frames(arr).map_err(|e| e.at(&file).key(key.clone()))?;
        frames
            .validate(&self.sensor, s.phases_deg.len())
            .map_err(|e| e.at(&file).key(key))?;
        Ok(Some(frames))
    }
}

fn check_shape(shape: &[usize], sensor: &SensorGeometry, phases: usize) -> Result<(), FormatError> {
    let want = [phases, sensor.rows, sensor.cols];
    if shape.len() != 3 {
        return Err(invalid(format!(
            "array has shape {}, expected 3 dimensions (K, rows, cols) = {}",
            shape_str(shape),
            shape_str(&want)
        )));
    }
    if shape[1..] != want[1..] {
        return Err(invalid(format!(
            "array has shape {} but the sensor window is {}×{} (expected {})",
            shape_str(shape),
            sensor.rows,
            sensor.cols,
            shape_str(&want)
        )));
    }
    if shape[0] != phases {
        return Err(invalid(format!(
            "array holds {} raw images (shape {}) but phases_deg lists {phases} phases",
            shape[0],
            shape_str(shape)
        )));
    }
    Ok(())
}

fn to_raw_frames(a: NpyArray) -> Result<RawFrames, FormatError> {
    let dims = |e: ndarray::ShapeError| invalid(format!("expected a 3-dimensional array: {e}"));
    Ok(match a {
        NpyArray::U16(a) => RawFrames::U16(a.into_dimensionality::<Ix3>().map_err(dims)?),
        NpyArray::F32(a) => RawFrames::F32(a.into_dimensionality::<Ix3>().map_err(dims)?),
        NpyArray::F64(a) => RawFrames::F64(a.into_dimensionality::<Ix3>().map_err(dims)?),
    })
}
