//! What the workspace's tests share, in one place (a dev-dependency only; nothing in a
//! product crate depends on it):
//!
//! - [`ci`]: what a test does when an external tool it drives is missing — skip loudly, or
//!   fail when `CI` is set ([`require_program`], [`require_python`]);
//! - [`bus`]: a private `dbus-daemon` ([`PrivateBus`]);
//! - [`frames`]: ideal raw frames of one sinusoidal return, independent of the model and the
//!   pipeline;
//! - [`recording`]: recording and calibration metadata of simulated captures.

pub mod bus;
pub mod ci;
pub mod frames;
pub mod recording;

pub use bus::PrivateBus;
pub use ci::{in_ci, require_program, require_python};
pub use recording::{capture_spec, part_source};
