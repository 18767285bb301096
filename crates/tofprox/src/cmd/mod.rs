//! One module per command group; each owns its clap arguments.

pub mod daemon;
pub mod device;
pub mod lab;
pub mod recording;
pub mod sim;
