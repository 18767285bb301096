//! The recording writer: [`RecordingWriter`] (crash-safe appends, the incomplete mark until
//! [`RecordingWriter::finish`]).

use super::*;

/// What [`RecordingWriter::append`] checks of capture `index` of a recording of `sensor` (the
/// capture's keys and ranges, the frames' shape and codes; errors keyed
/// `capture[<index>].<key>`), for a caller that checks every capture before writing any.
pub fn check_capture(
    sensor: &SensorGeometry,
    index: usize,
    capture: &CaptureSpec,
    frames: &RawFrames,
) -> Result<(), FormatError> {
    let key = format!("capture[{index}]");
    validate_spec(capture).map_err(|e| {
        let k = e.key_name().unwrap_or("").to_string();
        e.key(format!("{key}.{k}"))
    })?;
    frames
        .validate(sensor, capture.phases_deg.len())
        .map_err(|e| e.key(format!("{key}.frames")))
}

/// Appends captures to a recording, crash-safely: each frames file is written
/// to a temporary file, fsynced and renamed into place before
/// `recording.toml` is rewritten the same way. A reader of a recording whose
/// writer was killed at any moment sees every capture appended before the
/// last complete rewrite of `recording.toml`.
///
/// The recording is marked incomplete (`recording.incomplete`, [`crate::completion`]) before
/// anything is written, and the mark goes only in [`RecordingWriter::finish`]: a writer
/// killed, failed or dropped part-way leaves a recording that [`Recording::open`] refuses and
/// `tofprox info` flags.
#[derive(Debug)]
pub struct RecordingWriter {
    dir: PathBuf,
    sensor: SensorGeometry,
    convention: PhaseConvention,
    description: Option<String>,
    captures: Vec<CaptureMeta>,
    next_file: usize,
}

impl RecordingWriter {
    /// Start a new recording in `dir` (created if needed). Refuses a
    /// directory that already holds a `recording.toml` (see [`RecordingWriter::open_append`]).
    pub fn create(
        dir: &Path,
        sensor: SensorGeometry,
        description: Option<String>,
    ) -> Result<Self, FormatError> {
        Self::start(dir, sensor, description, false)
    }

    /// Start a new recording in `dir`, first removing the recording already
    /// there (its `recording.toml` and frames directory; nothing else in
    /// `dir` is touched).
    pub fn replace(
        dir: &Path,
        sensor: SensorGeometry,
        description: Option<String>,
    ) -> Result<Self, FormatError> {
        Self::start(dir, sensor, description, true)
    }

    fn start(
        dir: &Path,
        sensor: SensorGeometry,
        description: Option<String>,
        replace: bool,
    ) -> Result<Self, FormatError> {
        sensor
            .validate()
            .map_err(|e| geometry_invalid(e, "sensor"))?;
        prepare_new_recording(dir, replace)?;
        crate::completion::mark_incomplete(dir)?;
        let w = RecordingWriter {
            dir: dir.to_path_buf(),
            sensor,
            convention: PhaseConvention::CANONICAL,
            description,
            captures: Vec::new(),
            next_file: 0,
        };
        w.write_toml()?;
        sync_new_recording(dir);
        Ok(w)
    }

    /// Continue an existing recording, complete or not (for example after its writer was
    /// killed): validates it, marks it incomplete until [`RecordingWriter::finish`], removes
    /// leftover temporary files and appends after the last complete capture.
    pub fn open_append(dir: &Path) -> Result<Self, FormatError> {
        let rec = Recording::inspect(dir)?;
        // incomplete again until this writer finishes
        crate::completion::mark_incomplete(dir)?;
        let removed =
            fsutil::remove_tmp_files(dir)? + fsutil::remove_tmp_files(&dir.join(FRAMES_DIR))?;
        if removed > 0 {
            tracing::info!(
                "{}: removed {removed} temporary file(s) left by an interrupted writer",
                dir.display()
            );
        }
        let frames = dir.join(FRAMES_DIR);
        fs::create_dir_all(&frames)
            .map_err(|e| FormatError::io(&frames, "cannot create directory", e))?;
        let next_file = rec
            .captures
            .iter()
            .filter_map(|c| {
                c.frames
                    .strip_prefix("frames/")?
                    .strip_suffix(".npy")?
                    .parse::<usize>()
                    .ok()
            })
            .map(|n| n + 1)
            .max()
            .unwrap_or(0)
            .max(rec.captures.len());
        Ok(RecordingWriter {
            dir: dir.to_path_buf(),
            sensor: rec.sensor,
            convention: rec.convention,
            description: rec.description,
            captures: rec.captures,
            next_file,
        })
    }

    /// The sensor this recording is for.
    pub fn sensor(&self) -> &SensorGeometry {
        &self.sensor
    }

    /// Write the file's shifts in `convention` (before the first capture; the
    /// default is the canonical one). Shifts given to [`RecordingWriter::append`]
    /// stay canonical (`u = A·cos(φ − θ)`); the file carries them relabelled.
    pub fn set_phase_convention(&mut self, convention: PhaseConvention) -> Result<(), FormatError> {
        convention
            .validate()
            .map_err(|e| invalid(e.to_string()).key(format!("sensor.{PHASE_SIGN_KEY}")))?;
        if !self.captures.is_empty() {
            return Err(invalid(
                "the phase convention is set before the first capture is appended",
            )
            .key(format!("sensor.{PHASE_SHIFT_KEY}")));
        }
        self.convention = convention;
        self.write_toml()
    }

    /// The recording is complete: remove its incomplete mark (durably). Without this call
    /// the recording stays marked incomplete ([`crate::completion`]).
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

    /// Validate and append one capture; returns its index. On error nothing
    /// is added (the recording on disk is unchanged).
    pub fn append(
        &mut self,
        capture: CaptureSpec,
        frames: &RawFrames,
    ) -> Result<usize, FormatError> {
        self.append_with_second(capture, frames, None)
    }

    /// [`RecordingWriter::append`] with the images the device took in the same cycle at a
    /// second modulation frequency (format version 3, `[capture.second_frequency]`).
    pub fn append_with_second(
        &mut self,
        capture: CaptureSpec,
        frames: &RawFrames,
        second: Option<&SecondFrequencyFrames>,
    ) -> Result<usize, FormatError> {
        let index = self.captures.len();
        check_capture(&self.sensor, index, &capture, frames)?;
        let second = match second {
            Some(s) => Some(self.write_second(index, s)?),
            None => None,
        };
        let name = format!("{FRAMES_DIR}/{:06}.npy", self.next_file);
        let file = self.dir.join(&name);
        let bytes = match frames {
            RawFrames::U16(a) => npy::encode_u16(a),
            RawFrames::F32(a) => npy::encode_f32(a),
            RawFrames::F64(a) => npy::encode_f64(a),
        };
        fsutil::write_atomic(&file, &bytes)?;
        self.next_file += 1;
        self.captures.push(CaptureMeta {
            frames: name,
            phases_deg: capture.phases_deg,
            exposure_us: capture.exposure_us,
            illumination: capture.illumination,
            averaged: capture.averaged,
            timestamp_ns: capture.timestamp_ns,
            conditions: capture.conditions,
            second_frequency: second,
        });
        if let Err(e) = self.write_toml() {
            if let Some(s) = self.captures.pop().and_then(|c| c.second_frequency) {
                let _ = fs::remove_file(self.dir.join(s.frames));
            }
            let _ = fs::remove_file(&file);
            return Err(e);
        }
        Ok(index)
    }

    /// Validate and write one capture's second-frequency images; their table.
    fn write_second(
        &mut self,
        index: usize,
        s: &SecondFrequencyFrames,
    ) -> Result<SecondFrequencyMeta, FormatError> {
        let key = format!("capture[{index}].second_frequency");
        let name = format!("{FRAMES_DIR}/{:06}.npy", self.next_file);
        let meta = SecondFrequencyMeta {
            frames: name.clone(),
            modulation_hz: s.modulation_hz,
            phases_deg: s.phases_deg.clone(),
        };
        validate_second_frequency(&meta, &self.sensor).map_err(|e| {
            let k = e.key_name().unwrap_or("").to_string();
            e.key(format!("{key}.{k}"))
        })?;
        s.frames
            .validate(&self.sensor, s.phases_deg.len())
            .map_err(|e| e.key(format!("{key}.frames")))?;
        let bytes = match &s.frames {
            RawFrames::U16(a) => npy::encode_u16(a),
            RawFrames::F32(a) => npy::encode_f32(a),
            RawFrames::F64(a) => npy::encode_f64(a),
        };
        fsutil::write_atomic(&self.dir.join(&name), &bytes)?;
        self.next_file += 1;
        Ok(meta)
    }

    fn write_toml(&self) -> Result<(), FormatError> {
        let path = self.dir.join(RECORDING_TOML);
        let text = render_recording_toml(
            &self.sensor,
            self.convention,
            self.description.as_deref(),
            &self.captures,
        )
        .map_err(|e| e.at(&path))?;
        fsutil::write_atomic(&path, text.as_bytes())
    }
}
