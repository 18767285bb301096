//! Rust errors as `tofprox.Error`, keeping the kind, the file and the key.
use std::error::Error as StdError;

use pyo3::prelude::*;
use tofprox_format::{FormatError, ProcessError};
use tofprox_lab::LabError;
use tofprox_model::ModelError;

pyo3::create_exception!(
    tofprox,
    Error,
    pyo3::exceptions::PyException,
    "A tofprox error. `kind` names what went wrong (the Rust error kind, e.g. `MissingKey`, \
`Incompatible`, `UnknownEffect`), `file` the file it is about and `key` the key in it \
(`capture[3].phases_deg`), each None when unknown; str(e) is the message the command line prints."
);

/// The first error of type `T` (or a boxed one) in `e`'s chain (`e` itself, then its sources).
fn find<'a, T: StdError + 'static>(e: &'a (dyn StdError + 'static)) -> Option<&'a T> {
    let mut cur = Some(e);
    while let Some(err) = cur {
        if let Some(t) = err
            .downcast_ref::<T>()
            .or_else(|| err.downcast_ref::<Box<T>>().map(|b| &**b))
        {
            return Some(t);
        }
        cur = err.source();
    }
    None
}

/// The kind of the outermost error that has one of its own.
fn kind(e: &(dyn StdError + 'static)) -> String {
    let own = match find::<ProcessError>(e) {
        Some(ProcessError::NeedsLens { .. }) => Some("NeedsLens"),
        Some(ProcessError::NothingToProcess { .. }) => Some("NothingToProcess"),
        Some(ProcessError::Unusable { .. }) => Some("Unusable"),
        Some(ProcessError::Core { .. }) => Some("Invalid"),
        _ => None,
    };
    if let Some(k) = own {
        return k.into();
    }
    if let Some(l) = find::<LabError>(e).filter(|l| l.kind() != tofprox_lab::ErrorKind::Format) {
        return format!("{:?}", l.kind());
    }
    if let Some(f) = find::<FormatError>(e) {
        return format!("{:?}", f.kind());
    }
    find::<ModelError>(e).map_or("Other".into(), |m| format!("{:?}", m.kind()))
}

/// `e` as a `tofprox.Error` whose message is the command line's error line, with `kind`,
/// `file` and `key` attributes.
pub(crate) fn to_py_err(e: impl StdError + 'static) -> PyErr {
    let e: &(dyn StdError + 'static) = &e;
    let err = Error::new_err(tofprox_core::error_line(e));
    let fe = find::<FormatError>(e);
    let file = fe
        .and_then(FormatError::path)
        .or_else(|| find::<ModelError>(e).and_then(ModelError::path))
        .map(|p| p.display().to_string());
    let key = fe.and_then(FormatError::key_name).map(str::to_string);
    Python::attach(|py| {
        let value = err.value(py);
        let set = value
            .setattr("kind", kind(e))
            .and_then(|_| value.setattr("file", file))
            .and_then(|_| value.setattr("key", key));
        match set {
            Ok(()) => err.clone_ref(py),
            Err(other) => other,
        }
    })
}

/// A `tofprox.Error` of kind `Invalid` about an argument (`key`, e.g. `frames[0]`) that the
/// package refuses itself, before any Rust library sees it; `file` is None.
pub(crate) fn invalid_argument(key: &str, message: String) -> PyErr {
    let err = Error::new_err(message);
    Python::attach(|py| {
        let value = err.value(py);
        let set = value
            .setattr("kind", "Invalid")
            .and_then(|_| value.setattr("file", py.None()))
            .and_then(|_| value.setattr("key", key));
        match set {
            Ok(()) => err.clone_ref(py),
            Err(other) => other,
        }
    })
}
