//! The one public error type of this crate: every error names the file and,
//! where there is one, the key (`sensor.rows`, `capture[3].phases_deg`,
//! `arrays.offset.sha256`, …) it is about.

use std::fmt;
use std::path::{Path, PathBuf};

/// What went wrong, for callers that want to react differently.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum ErrorKind {
    /// Reading or writing a file failed (missing file, permissions, disk full).
    Io,
    /// A TOML file does not parse, or a key has the wrong type.
    Syntax,
    /// A required key is absent.
    MissingKey,
    /// A key that this format version does not define.
    UnknownKey,
    /// Another format name or an unsupported version.
    Unsupported,
    /// A value is out of range or inconsistent with another one.
    Invalid,
    /// A `.npy` file is malformed, truncated, or of an unsupported dtype/layout.
    Npy,
    /// An array's SHA-256 does not match the checksum recorded for it.
    Checksum,
    /// A calibration does not fit the data it is applied to.
    Incompatible,
    /// A file or directory that must not exist yet already exists.
    AlreadyExists,
    /// A file, a count or a length exceeds a documented limit
    /// ([`crate::limits`]), or a path is not a regular file inside the
    /// recording or calibration set.
    Limit,
    /// A recording whose writer did not finish (`recording.incomplete` present): killed or
    /// failed part-way ([`crate::completion`]).
    Incomplete,
}

/// An error reading, validating or writing a recording or a calibration set.
#[derive(Debug, thiserror::Error)]
pub struct FormatError {
    kind: ErrorKind,
    path: Option<PathBuf>,
    key: Option<String>,
    message: String,
    #[source]
    source: Option<std::io::Error>,
}

impl fmt::Display for FormatError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(p) = &self.path {
            write!(f, "{}: ", p.display())?;
        }
        if let Some(k) = &self.key {
            write!(f, "{k}: ")?;
        }
        f.write_str(&self.message)
    }
}

impl FormatError {
    pub(crate) fn new(kind: ErrorKind, message: impl Into<String>) -> Self {
        FormatError {
            kind,
            path: None,
            key: None,
            message: message.into(),
            source: None,
        }
    }

    pub(crate) fn io(path: &Path, what: &str, err: std::io::Error) -> Self {
        FormatError {
            kind: ErrorKind::Io,
            path: Some(path.to_path_buf()),
            key: None,
            message: what.to_string(),
            source: Some(err),
        }
    }

    pub(crate) fn at(mut self, path: &Path) -> Self {
        self.path = Some(path.to_path_buf());
        self
    }

    pub(crate) fn key(mut self, key: impl Into<String>) -> Self {
        self.key = Some(key.into());
        self
    }

    /// Set the key only when none is set yet.
    pub(crate) fn key_if_none(mut self, key: impl Into<String>) -> Self {
        if self.key.is_none() {
            self.key = Some(key.into());
        }
        self
    }

    /// What kind of failure this is.
    pub fn kind(&self) -> ErrorKind {
        self.kind
    }

    /// The file the error is about, if any.
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }

    /// The key (dotted path inside the TOML file) the error is about, if any.
    pub fn key_name(&self) -> Option<&str> {
        self.key.as_deref()
    }

    /// The message without file and key.
    pub fn message(&self) -> &str {
        &self.message
    }
}

/// Shorthand constructors used throughout the crate.
pub(crate) fn invalid(message: impl Into<String>) -> FormatError {
    FormatError::new(ErrorKind::Invalid, message)
}

/// A sensor geometry that fails [`tofprox_core::SensorGeometry::validate`], as an `Invalid`
/// error naming `table.key` (`sensor.adc_bits`, `valid_for.full_rows`).
pub(crate) fn geometry_invalid(e: tofprox_core::CoreError, table: &str) -> FormatError {
    match e {
        tofprox_core::CoreError::InvalidParameter { name, reason } => {
            invalid(reason).key(format!("{table}.{name}"))
        }
        other => invalid(other.to_string()).key(table),
    }
}

/// Parse a whole TOML file into `T`: errors as [`from_toml`] says, with the key path of the
/// value that failed (`sensor.roi_origin[2]`, `capture[1].exposure_us`) taken from
/// `serde_path_to_error` where serde's message names none (wrong types, wrong lengths).
pub(crate) fn parse_toml<T: serde::de::DeserializeOwned>(
    path: &Path,
    text: &str,
) -> Result<T, FormatError> {
    let de = toml::Deserializer::parse(text).map_err(|e| from_toml(path, text, &e))?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let key = e.path().to_string();
        let out = from_toml(path, text, e.inner());
        let named = matches!(out.kind, ErrorKind::MissingKey | ErrorKind::UnknownKey);
        if named || key.is_empty() || key == "." {
            out
        } else {
            out.key(key)
        }
    })
}

/// Turn a `toml` deserialisation error into a `FormatError` that says the line,
/// the offending text and the key (`capture[1].gain`), without the multi-line
/// ASCII art.
pub(crate) fn from_toml(path: &Path, text: &str, err: &toml::de::Error) -> FormatError {
    let msg = err.message().trim().to_string();
    let kind = if msg.starts_with("missing field") {
        ErrorKind::MissingKey
    } else if msg.starts_with("unknown field") {
        ErrorKind::UnknownKey
    } else {
        ErrorKind::Syntax
    };
    // the field named in serde's message, e.g. "unknown field `gain`, expected …"
    let field = msg
        .split('`')
        .nth(1)
        .filter(|_| matches!(kind, ErrorKind::MissingKey | ErrorKind::UnknownKey))
        .map(str::to_string);
    let mut out = FormatError::new(kind, msg);
    if let Some(span) = err.span() {
        let start = span.start.min(text.len());
        let before = text.get(..start).unwrap_or("");
        let line_no = before.matches('\n').count() + 1;
        let line_text = text.lines().nth(line_no - 1).unwrap_or("").trim();
        let shown: String = line_text.chars().take(60).collect();
        out.message = format!("line {line_no} (`{shown}`): {}", out.message);
        // which table the error is in: the last header at or before the error's line
        let mut table = String::new();
        let mut counts: std::collections::BTreeMap<String, usize> = Default::default();
        for line in text.lines().take(line_no) {
            let l = line.trim();
            if let Some(name) = l.strip_prefix("[[").and_then(|r| r.split("]]").next()) {
                let name = name.trim().to_string();
                let n = counts.entry(name.clone()).or_insert(0);
                table = format!("{name}[{n}]");
                *n += 1;
            } else if let Some(name) = l.strip_prefix('[').and_then(|r| r.split(']').next()) {
                let name = name.trim();
                // `[capture.conditions]` belongs to the latest `[[capture]]`
                table = match name.split_once('.') {
                    Some((parent, child)) if counts.contains_key(parent) => {
                        format!("{parent}[{}].{child}", counts[parent].saturating_sub(1))
                    }
                    _ => name.to_string(),
                };
            }
        }
        let key = match (&field, table.is_empty()) {
            (Some(f), true) => Some(f.clone()),
            (Some(f), false) => Some(format!("{table}.{f}")),
            (None, false) => Some(table),
            (None, true) => None,
        };
        if let Some(k) = key {
            out = out.key(k);
        }
    }
    out.at(path)
}

/// The `format` and `version` keys of a TOML file, read before anything else.
#[derive(serde::Deserialize)]
struct FormatHeader {
    format: Option<toml::Value>,
    version: Option<toml::Value>,
}

/// Check `format = "<format>"` and `version` (one of `versions`, the newest last) first, so
/// that another file or a newer version is reported as such rather than as a list of unknown
/// keys; returns the version read. `what` names the file in messages (`recording`, `calibration
/// set`), `version_of` the format (`recording`, `calibration`).
pub(crate) fn check_format_header(
    path: &Path,
    text: &str,
    format: &str,
    versions: &[i64],
    what: &str,
    version_of: &str,
) -> Result<i64, FormatError> {
    let header: FormatHeader = parse_toml(path, text)?;
    match &header.format {
        None => {
            return Err(FormatError::new(
                ErrorKind::MissingKey,
                format!("missing; a {what} starts with format = \"{format}\""),
            )
            .at(path)
            .key("format"));
        }
        Some(toml::Value::String(s)) if s == format => {}
        Some(v) => {
            return Err(FormatError::new(
                ErrorKind::Unsupported,
                format!("{v} is not a tofprox {what} (expected \"{format}\")"),
            )
            .at(path)
            .key("format"));
        }
    }
    let readable = versions
        .iter()
        .map(i64::to_string)
        .collect::<Vec<_>>()
        .join(" or ");
    let newest = versions.last().copied().unwrap_or(0);
    match &header.version {
        None => Err(FormatError::new(
            ErrorKind::MissingKey,
            format!("missing (expected {newest})"),
        )
        .at(path)
        .key("version")),
        Some(toml::Value::Integer(v)) if versions.contains(v) => Ok(*v),
        Some(v) => Err(FormatError::new(
            ErrorKind::Unsupported,
            format!(
                "{version_of} format version {v} is not supported (this tofprox reads version {readable})"
            ),
        )
        .at(path)
        .key("version")),
    }
}
