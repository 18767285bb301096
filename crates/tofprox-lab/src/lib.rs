//! tofprox model lab: compare the model with measurements, find the missing
//! effect, add it and watch the error fall (issue: model lab; `docs/lab.md`).
//!
//! Pipeline: [`data::Dataset`] → [`prepared::Prepared`] → [`diagnose::compare`]
//! (fits the [`fit::LabModel`], noise, residual structure) →
//! [`diagnose::diagnose`] (candidate signatures, verdict) →
//! [`diagnose::add_effect`]; [`workflow`]: the same over the user's files.
pub mod adapter;
pub mod arrays;
pub mod candidates;
pub mod data;
pub mod depth_error;
pub mod diagnose;
pub mod error;
mod evidence;

pub mod fit;
pub mod form;
pub mod hold;
pub mod model_file;
pub mod noise;
pub mod prepared;
pub mod report;
pub mod sample;
pub mod shape;
pub mod signatures;
pub mod spec;
pub mod stats;
pub mod structure;
/// Test machinery (feature `testing`): synthetic recordings for the tests.
#[cfg(any(test, feature = "testing"))]
#[doc(hidden)]
pub mod synth;
pub mod uncertainty;
pub mod user;
pub mod waveform;
pub mod workflow;

pub use data::{Capture, Dataset};
pub use diagnose::{
    AddOutcome, Comparison, DiagnoseOptions, Diagnosis, Explanation, Verdict, add_effect, compare,
    diagnose, diagnose_with, explain,
};
pub use error::{ErrorKind, LabError};
pub use fit::{LabModel, LabSpec, Prepared};
