//! tofproxd: the low-power ToF proximity daemon on D-Bus (thesis 3.5.3, fig. 3.23,
//! listing 4.11): restart → load config from flash → set exposure → capture →
//! process → stop (reset low) → sleep, publishing near/far over D-Bus.
//!
//! The test machinery — the emulated backend (`backends::emulated`), the scene bench (`scenes`)
//! and the soak (`soak`) — is behind the cargo feature `emulated` (on by default, for
//! `tofproxd --demo` and the `tofprox` CLI). The production daemon is built without it,
//! `cargo build -p tofproxd --no-default-features`, and links neither the emulated device
//! nor the physical model (`tofprox-model`).

pub mod backends;
pub mod boottime;
pub mod calibration;
pub mod client;
pub mod config;
pub mod controller;
pub mod cputime;
pub mod data;
pub mod energy;
pub mod hub;
pub mod input;
pub mod logging;
pub mod man;
pub mod policy;
pub mod publisher;
pub mod run;
#[cfg(feature = "emulated")]
pub mod scenes;
pub mod service;
pub mod signals;
#[cfg(feature = "emulated")]
pub mod soak;
pub mod source;
