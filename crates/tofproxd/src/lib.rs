//! tofproxd: the low-power ToF proximity daemon on D-Bus (thesis 3.5.3, fig. 3.23,
//! listing 4.11): restart → load config from flash → set exposure → capture →
//! process → stop (reset low) → sleep, publishing near/far over D-Bus.

pub mod backends;
pub mod calibration;
pub mod client;
pub mod config;
pub mod controller;
pub mod data;
pub mod energy;
pub mod hub;
pub mod logging;
pub mod policy;
pub mod publisher;
pub mod run;
pub mod scenes;
pub mod service;
pub mod soak;
pub mod source;
