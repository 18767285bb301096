//! tofprox calibration station for the production line (`docs/calibration.md`, "Production
//! line"): drives a module through the captures its line needs — dark frames (FPN), the
//! cover-window crosstalk with nothing in range (phone line), a 24 × 15° correlation of a flat
//! wall (wiggling tables, amplitude scale), a 4-phase of the wall (FPPN) — at exposures within
//! the eye-safe limit, averaging frames instead of exposing longer (thesis 2.3.2.2: shot noise
//! `σ = √N`, eq. 2.16), extracts each part through `tofprox_format::extract` (what
//! `tofprox calibrate` runs), checks the parts' figures against the station file's limits,
//! verifies the calibrated module on a check target at another distance and writes the set
//! with a report (JSON and HTML) saying pass/fail per part and the time taken.
//!
//! - [`Station`]: the station file (`config/station/*.toml`).
//! - [`Fixture`]: what puts a target in front of the module — [`OperatorFixture`] on the line,
//!   `EmulatedFixture` (feature `emulated`) for tests and demos.
//! - [`run_station`]: the run, giving a [`Report`].
//!
//! `tofprox calibrate station` is a thin adapter over this crate.

mod capture;
mod error;
mod figures;
mod file;
mod fixture;
mod report;
mod run;

pub use error::StationError;
pub use figures::PartCheck;
pub use file::{
    CaptureSpec, Captures, DAEMON_EXPOSURE_MAX_US, ExposureLimit, Limits, Line, ModuleSpec,
    Station, Target, Targets,
};
#[cfg(feature = "emulated")]
pub use fixture::EmulatedFixture;
pub use fixture::{Fixture, OperatorFixture, Placement};
pub use report::html;
pub use run::{
    CheckReading, RECORDINGS_DIR, REPORT_HTML, REPORT_JSON, Report, SET_DIR, StepTime, run_station,
};
