//! A calibration set as files: `calibration.toml` (its schema, `CalibToml`/`PartToml`) and one
//! `.npy` array per part — writing it crash-safe ([`CalibrationSet::save`]) and reading it back
//! with every check ([`CalibrationSet::load`]: header, keys, each array's SHA-256, dtype, shape,
//! finite values and physical range, the checksums of the parts each part was extracted with).
//! The set itself — its parts, what depends on what, the setters — is the parent module's.

use super::*;

// ---------------------------------------------------------------- TOML schema

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CalibToml {
    format: String,
    version: i64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    description: Option<String>,
    /// Last time the set was written (RFC 3339).
    updated: String,
    valid_for: SensorGeometry,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    intrinsics: Option<PartToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    offset: Option<PartToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    crosstalk: Option<PartToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    wiggling_2phase: Option<PartToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    wiggling_4phase: Option<PartToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fppn: Option<PartToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fppn_2phase: Option<PartToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    amplitude: Option<PartToml>,
    /// Parts dropped as stale and not extracted again yet ([`chain`]).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    dropped: BTreeMap<String, chain::DroppedToml>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PartToml {
    file: String,
    sha256: String,
    /// Array shape, for humans and checked on load.
    shape: Vec<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    algorithm: Option<Algorithm>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    lut_size: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    distance_m: Option<f64>,
    /// Target reflectivity of the capture (amplitude; absent = assumed 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    reflectivity: Option<f64>,
    /// Exposure per raw image of the capture (amplitude), µs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    exposure_us: Option<f64>,
    /// sha256 of the offset array this part was extracted with, or "none".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    offset_sha256: Option<String>,
    /// sha256 of the wiggling array this part was extracted with, or "none".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    wiggling_sha256: Option<String>,
    /// sha256 of the intrinsics this part was extracted through, or "none".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    intrinsics_sha256: Option<String>,
    /// sha256 of the crosstalk array subtracted before extracting this part, or "none".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    crosstalk_sha256: Option<String>,
    source_recording: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    source_description: Option<String>,
    source_captures: Vec<usize>,
    created: String,
    tool: String,
}

impl CalibrationSet {
    // ------------------------------------------------------------ save

    /// Write the set to `dir` (created if needed): every array via a
    /// temporary file + fsync + rename, then `calibration.toml` the same way,
    /// then arrays of parts no longer present are removed.
    pub fn save(&self, dir: &Path) -> Result<(), FormatError> {
        fs::create_dir_all(dir).map_err(|e| FormatError::io(dir, "cannot create directory", e))?;
        let stale = self.stale_parts();
        if let Some(p) = stale.first() {
            return Err(invalid(format!(
                "{p} was extracted with other versions of the parts it depends on"
            ))
            .key(p.name()));
        }
        let mut t = CalibToml {
            format: CALIBRATION_FORMAT.into(),
            version: CALIBRATION_VERSION,
            description: self.description.clone(),
            updated: now_rfc3339(),
            valid_for: self.validity,
            intrinsics: None,
            offset: None,
            crosstalk: None,
            wiggling_2phase: None,
            wiggling_4phase: None,
            fppn: None,
            fppn_2phase: None,
            amplitude: None,
            dropped: self.dropped_toml(),
        };
        for (&part, value) in &self.parts {
            let bytes = value.npy_bytes();
            let file = part.file_name();
            fsutil::write_atomic(&dir.join(&file), &bytes)?;
            let src = self.sources.get(&part).cloned().unwrap_or_default();
            let deps = self.deps.get(&part).cloned().unwrap_or_default();
            let lut_size = match value {
                PartValue::Wiggling(w) => Some(w.len()),
                _ => None,
            };
            let pt = PartToml {
                file,
                sha256: sha256_hex(&bytes),
                shape: value.shape(),
                algorithm: part.algorithm(),
                lut_size,
                distance_m: src.distance_m,
                reflectivity: src.reflectivity,
                exposure_us: src.exposure_us,
                offset_sha256: deps.offset,
                wiggling_sha256: deps.wiggling,
                intrinsics_sha256: deps.intrinsics,
                crosstalk_sha256: deps.crosstalk,
                source_recording: src.recording,
                source_description: src.recording_description,
                source_captures: src.captures,
                created: src.created,
                tool: src.tool,
            };
            match part {
                CalibPart::Intrinsics => t.intrinsics = Some(pt),
                CalibPart::Offset => t.offset = Some(pt),
                CalibPart::Crosstalk => t.crosstalk = Some(pt),
                CalibPart::Wiggling2Phase => t.wiggling_2phase = Some(pt),
                CalibPart::Wiggling4Phase => t.wiggling_4phase = Some(pt),
                CalibPart::Fppn => t.fppn = Some(pt),
                CalibPart::Fppn2Phase => t.fppn_2phase = Some(pt),
                CalibPart::Amplitude => t.amplitude = Some(pt),
            }
        }
        let path = dir.join(CALIBRATION_TOML);
        let text =
            toml::to_string(&t).map_err(|e| invalid(format!("cannot serialise: {e}")).at(&path))?;
        fsutil::write_atomic(&path, text.as_bytes())?;
        for part in CalibPart::ALL {
            if !self.has(part) {
                let _ = fs::remove_file(dir.join(part.file_name()));
            }
        }
        Ok(())
    }

    // ------------------------------------------------------------ load

    /// Load a calibration set and verify it: format and version, every key,
    /// each array's SHA-256, dtype and shape, finite values, and that the
    /// parts were extracted with each other.
    pub fn load(dir: &Path) -> Result<Self, FormatError> {
        let path = dir.join(CALIBRATION_TOML);
        if !dir.is_dir() {
            return Err(FormatError::new(
                ErrorKind::Io,
                "is not a directory (a calibration set is a directory with calibration.toml)",
            )
            .at(dir));
        }
        let text = limits::read_text_bounded(&path, limits::MAX_TOML_BYTES)?;
        check_header(&path, &text)?;
        let t: CalibToml = parse_toml(&path, &text)?;
        let sensor = t.valid_for;
        // the documented limits first, then the geometry's own rules
        crate::recording::check_sensor_limits(&sensor, "valid_for").map_err(|e| e.at(&path))?;
        sensor
            .validate()
            .map_err(|e| geometry_invalid(e, "valid_for").at(&path))?;
        let mut set = CalibrationSet::new(&sensor);
        set.description = t.description.clone();
        set.dir = Some(dir.to_path_buf());
        set.dropped = chain::dropped_from_toml(&t.dropped).map_err(|e| e.at(&path))?;
        for (part, pt) in t.parts() {
            check_dependency_checksums(part, pt, t.intrinsics.is_some())
                .map_err(|e| e.at(&path))?;
            let arr = load_part(dir, &path, part, pt, &sensor)?;
            set.install_loaded(dir, &path, part, pt, arr)?;
            set.record_loaded(part, pt);
        }
        if let Some(&p) = set.stale_parts().first() {
            return Err(invalid(format!(
                "[{p}] was extracted with a different {} than the one in this set; re-run `tofprox calibrate` for it",
                set.stale_reason(p)
            ))
            .at(&path)
            .key(p.name()));
        }
        Ok(set)
    }

    /// Put a loaded array into the set as `part`, checked as that part (the lens's values,
    /// the FPPN map's and the wiggling table's algorithm, the table's size).
    fn install_loaded(
        &mut self,
        dir: &Path,
        toml_path: &Path,
        part: CalibPart,
        pt: &PartToml,
        arr: LoadedArray,
    ) -> Result<(), FormatError> {
        let key = part.name();
        let file = dir.join(&pt.file);
        let at_file = |e: String| invalid(e).at(&file).key(key);
        match (part, arr) {
            (CalibPart::Intrinsics, LoadedArray::Lut(a)) => {
                if a.len() != INTRINSICS_LEN {
                    return Err(at_file(format!(
                        "holds {} values, expected {INTRINSICS_LEN}: [fx, fy, cx, cy, k1, k2, p1, p2, k3]",
                        a.len()
                    )));
                }
                let k = intrinsics_from_array(&a);
                k.validate().map_err(|e| at_file(e.to_string()))?;
                self.rays_of(&k).map_err(|e| at_file(e.to_string()))?;
                self.insert(part, PartValue::Intrinsics(k));
            }
            (CalibPart::Offset, LoadedArray::Map(a)) => {
                self.insert(part, PartValue::Offset(OffsetCalibration { dark_lsb: a }))
            }
            (CalibPart::Amplitude, LoadedArray::Map(a)) => self.insert(
                part,
                PartValue::Amplitude(AmplitudeScale { lsb_m2_per_us: a }),
            ),
            (CalibPart::Crosstalk, LoadedArray::Cube(a)) => self.insert(
                part,
                PartValue::Crosstalk(CrosstalkCalibration { lsb_per_us: a }),
            ),
            (CalibPart::Fppn | CalibPart::Fppn2Phase, LoadedArray::Map(a)) => {
                let want = part.algorithm().unwrap_or(Algorithm::FourPhase);
                if pt.algorithm != Some(want) {
                    return Err(invalid(format!(
                        "must be \"{want}\" for [{key}] (the map is absolute w.r.t. the {want} wiggling table)"
                    ))
                    .at(toml_path)
                    .key(format!("{key}.algorithm")));
                }
                self.insert(
                    part,
                    PartValue::Fppn(FppnMap {
                        phase_offset_rad: a,
                    }),
                );
            }
            (CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase, LoadedArray::Lut(a)) => {
                let lut = wiggling_from_loaded(toml_path, part, pt, a)?;
                lut.validate().map_err(|e| at_file(e.to_string()))?;
                self.insert(CalibPart::wiggling(lut.algorithm), PartValue::Wiggling(lut));
            }
            _ => {
                return Err(invalid("internal: array kind mismatch")
                    .at(toml_path)
                    .key(key));
            }
        }
        Ok(())
    }

    /// Record a loaded part's provenance and the checksums it was extracted with.
    fn record_loaded(&mut self, part: CalibPart, pt: &PartToml) {
        self.sources.insert(
            part,
            PartSource {
                recording: pt.source_recording.clone(),
                recording_description: pt.source_description.clone(),
                captures: pt.source_captures.clone(),
                distance_m: pt.distance_m,
                reflectivity: pt.reflectivity,
                exposure_us: pt.exposure_us,
                created: pt.created.clone(),
                tool: pt.tool.clone(),
            },
        );
        // hex digests compare case-insensitively
        let lower = |s: &Option<String>| s.as_deref().map(str::to_ascii_lowercase);
        self.deps.insert(
            part,
            Deps {
                offset: lower(&pt.offset_sha256),
                wiggling: lower(&pt.wiggling_sha256),
                intrinsics: lower(&pt.intrinsics_sha256),
                crosstalk: lower(&pt.crosstalk_sha256),
            },
        );
    }

    /// Which of the parts a stale part `p` was extracted with is no longer the set's.
    fn stale_reason(&self, p: CalibPart) -> String {
        let deps = self.deps.get(&p);
        if deps
            .and_then(|d| d.intrinsics.as_deref())
            .is_some_and(|k| k != self.checksum_or_none(CalibPart::Intrinsics))
        {
            "lens intrinsics".to_string()
        } else if deps.and_then(|d| d.offset.as_deref())
            != Some(self.checksum_or_none(CalibPart::Offset).as_str())
        {
            "offset".to_string()
        } else if deps
            .and_then(|d| d.crosstalk.as_deref())
            .is_some_and(|x| x != NONE && x != self.checksum_or_none(CalibPart::Crosstalk))
        {
            "crosstalk".to_string()
        } else {
            format!(
                "{} wiggling table",
                p.algorithm().map_or("", |a| a.as_str())
            )
        }
    }
}

impl CalibToml {
    /// The parts the file holds, in load order.
    fn parts(&self) -> impl Iterator<Item = (CalibPart, &PartToml)> {
        [
            (CalibPart::Intrinsics, &self.intrinsics),
            (CalibPart::Offset, &self.offset),
            (CalibPart::Crosstalk, &self.crosstalk),
            (CalibPart::Wiggling2Phase, &self.wiggling_2phase),
            (CalibPart::Wiggling4Phase, &self.wiggling_4phase),
            (CalibPart::Fppn, &self.fppn),
            (CalibPart::Fppn2Phase, &self.fppn_2phase),
            (CalibPart::Amplitude, &self.amplitude),
        ]
        .into_iter()
        .filter_map(|(part, pt)| pt.as_ref().map(|pt| (part, pt)))
    }
}

/// The checksums of the parts `part` was extracted with are required: deleting them must not
/// switch the staleness check off (the lens's checksum where the set holds a lens — only the
/// parts extracted through the lens record it, wiggling and FPPN: a part written before lens
/// models existed was extracted without one).
fn check_dependency_checksums(
    part: CalibPart,
    pt: &PartToml,
    set_has_lens: bool,
) -> Result<(), FormatError> {
    let mut required: Vec<(&str, &Option<String>)> = match part {
        CalibPart::Intrinsics | CalibPart::Offset | CalibPart::Amplitude => vec![],
        CalibPart::Crosstalk | CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase => {
            vec![("offset_sha256", &pt.offset_sha256)]
        }
        CalibPart::Fppn | CalibPart::Fppn2Phase => vec![
            ("offset_sha256", &pt.offset_sha256),
            ("wiggling_sha256", &pt.wiggling_sha256),
        ],
    };
    if set_has_lens && part.phase_correction() {
        required.push(("intrinsics_sha256", &pt.intrinsics_sha256));
    }
    match required.iter().find(|(_, v)| v.is_none()) {
        Some((k, _)) => Err(FormatError::new(
            ErrorKind::MissingKey,
            "missing: the checksum of the part this one was extracted with (\"none\" if there was none) is required",
        )
        .key(format!("{}.{k}", part.name()))),
        None => Ok(()),
    }
}

/// A wiggling part's table with the algorithm and size its TOML entry must state.
fn wiggling_from_loaded(
    toml_path: &Path,
    part: CalibPart,
    pt: &PartToml,
    a: Array1<f32>,
) -> Result<WigglingLut, FormatError> {
    let key = part.name();
    let want = part.algorithm().unwrap_or(Algorithm::FourPhase);
    let missing = |what: &str, sub: &str| {
        FormatError::new(ErrorKind::MissingKey, what)
            .at(toml_path)
            .key(format!("{key}.{sub}"))
    };
    let wrong = |m: String, sub: &str| invalid(m).at(toml_path).key(format!("{key}.{sub}"));
    match pt.algorithm {
        Some(alg) if alg == want => {}
        Some(alg) => {
            return Err(wrong(
                format!("is \"{alg}\" but the table is [{key}]"),
                "algorithm",
            ));
        }
        None => return Err(missing("missing (\"2phase\" or \"4phase\")", "algorithm")),
    }
    match pt.lut_size {
        Some(n) if n == a.len() => {}
        Some(n) => {
            return Err(wrong(
                format!("is {n} but {} holds {} bins", pt.file, a.len()),
                "lut_size",
            ));
        }
        None => return Err(missing("missing", "lut_size")),
    }
    Ok(WigglingLut {
        algorithm: want,
        correction_rad: a,
    })
}

enum LoadedArray {
    Map(Array2<f32>),
    Lut(Array1<f32>),
    Cube(Array3<f32>),
}

fn check_header(path: &Path, text: &str) -> Result<(), FormatError> {
    check_format_header(
        path,
        text,
        CALIBRATION_FORMAT,
        &[CALIBRATION_VERSION],
        "calibration set",
        "calibration",
    )
    .map(|_| ())
}

/// Read one part's array and check it as the file: its name, SHA-256, dtype, recorded
/// shape, finite values, physical range, then its dimensions against the window.
fn load_part(
    dir: &Path,
    toml_path: &Path,
    part: CalibPart,
    pt: &PartToml,
    sensor: &SensorGeometry,
) -> Result<LoadedArray, FormatError> {
    let key = part.name();
    if pt.file != part.file_name() {
        return Err(
            invalid(format!("\"{}\" must be \"{}\"", pt.file, part.file_name()))
                .at(toml_path)
                .key(format!("{key}.file")),
        );
    }
    let file = dir.join(&pt.file);
    let a = read_checked_f32(dir, &file, part, pt)?;
    if a.shape() != pt.shape.as_slice() {
        return Err(invalid(format!(
            "{} records shape {} but the file holds {}",
            CALIBRATION_TOML,
            shape_str(&pt.shape),
            shape_str(a.shape())
        ))
        .at(&file)
        .key(format!("{key}.shape")));
    }
    if let Some(i) = a.iter().position(|v| !v.is_finite()) {
        return Err(invalid(format!("element {i} is not finite"))
            .at(&file)
            .key(key));
    }
    check_physical_range(part, &a, sensor).map_err(|m| invalid(m).at(&file).key(key))?;
    let (rows, cols) = (sensor.rows, sensor.cols);
    let shape = shape_str(&pt.shape);
    match part {
        CalibPart::Offset | CalibPart::Fppn | CalibPart::Fppn2Phase | CalibPart::Amplitude => {
            let a = a.into_dimensionality::<Ix2>().map_err(|_| {
                format!("expected a (rows, cols) = ({rows}, {cols}) map, found shape {shape}")
            });
            a.and_then(|a| check_loaded_map(part, a, sensor))
                .map(LoadedArray::Map)
        }
        CalibPart::Crosstalk => {
            let a = a.into_dimensionality::<Ix3>().map_err(|_| {
                format!("expected a (4, rows, cols) = (4, {rows}, {cols}) array, found shape {shape}")
            });
            a.and_then(|a| {
                if a.dim() == (4, rows, cols) {
                    Ok(LoadedArray::Cube(a))
                } else {
                    Err(format!(
                        "crosstalk is {:?} but valid_for says the window is {rows}×{cols} (expected 4 raw images × window)",
                        a.dim()
                    ))
                }
            })
        }
        CalibPart::Intrinsics | CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase => a
            .into_dimensionality::<Ix1>()
            .map(LoadedArray::Lut)
            .map_err(|_| format!("expected a 1-dimensional table, found shape {shape}")),
    }
    .map_err(|m| invalid(m).at(&file).key(key))
}

/// A part's file, bounded in size, with the SHA-256 its TOML entry records, decoded as the
/// float32 array every calibration part is.
fn read_checked_f32(
    dir: &Path,
    file: &Path,
    part: CalibPart,
    pt: &PartToml,
) -> Result<ndarray::ArrayD<f32>, FormatError> {
    let key = part.name();
    let bytes =
        limits::read_bounded(file, limits::MAX_NPY_BYTES, Some(dir)).map_err(|e| e.key(key))?;
    let sum = sha256_hex(&bytes);
    if !sum.eq_ignore_ascii_case(pt.sha256.trim()) {
        return Err(FormatError::new(
            ErrorKind::Checksum,
            format!(
                "SHA-256 mismatch: the file's is {sum}, {CALIBRATION_TOML} records {} — the array was modified or damaged; re-create the calibration",
                pt.sha256
            ),
        )
        .at(file)
        .key(format!("{key}.sha256")));
    }
    match npy::decode(&bytes).map_err(|e| e.at(file).key(key))? {
        NpyArray::F32(a) => Ok(a),
        _ => Err(
            FormatError::new(ErrorKind::Npy, "calibration arrays must be float32 ('<f4')")
                .at(file)
                .key(key),
        ),
    }
}

/// Each array within its physical range (issue 12 item 7): phase corrections within one
/// period; the crosstalk (LSB per µs of exposure, per raw image) within one full-scale code
/// per µs, as no exposure is shorter than 1 µs; the dark level within the ADC range and the
/// amplitude scale ([`check_loaded_map`]); the lens by `Intrinsics::validate` when the set is
/// assembled.
fn check_physical_range(
    part: CalibPart,
    a: &ndarray::ArrayD<f32>,
    sensor: &SensorGeometry,
) -> Result<(), String> {
    if part == CalibPart::Crosstalk {
        let max = sensor.max_code() as f32;
        if let Some((i, v)) = a.iter().enumerate().find(|(_, v)| v.abs() > max) {
            return Err(format!(
                "element {i} is {v} LSB/µs, beyond one full-scale code per µs (|crosstalk| ≤ {max})"
            ));
        }
    }
    if part.phase_correction() {
        let max = limits::MAX_PHASE_CORRECTION_RAD;
        if let Some((i, v)) = a.iter().enumerate().find(|(_, v)| v.abs() > max) {
            return Err(format!(
                "element {i} is {v} rad, beyond one period (|correction| ≤ 2π = {max} rad)"
            ));
        }
    }
    Ok(())
}

/// A per-pixel map part (offset, FPPN, amplitude) fits the window; the amplitude scale and
/// the dark level lie within their physical ranges.
fn check_loaded_map(
    part: CalibPart,
    a: Array2<f32>,
    sensor: &SensorGeometry,
) -> Result<Array2<f32>, String> {
    if a.dim() != (sensor.rows, sensor.cols) {
        return Err(format!(
            "map is {}×{} but valid_for says the window is {}×{}",
            a.nrows(),
            a.ncols(),
            sensor.rows,
            sensor.cols
        ));
    }
    if part == CalibPart::Amplitude
        && let Some(problem) = amplitude_scale_problem(&a, sensor)
    {
        return Err(problem);
    }
    if part == CalibPart::Offset {
        let max = sensor.max_code() as f32;
        if let Some(v) = a.iter().find(|v| !(0.0..=max).contains(*v)) {
            return Err(format!("dark level {v} is outside the ADC range 0..={max}"));
        }
    }
    Ok(a)
}
