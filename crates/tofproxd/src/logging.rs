//! Log set-up shared by the `tofproxd` and `tofprox` binaries.

/// Log to stderr with `RUST_LOG` if set, else `default_filter` (e.g. `"info"`).
/// A second call (a subscriber is already installed) changes nothing.
pub fn init_logging(default_filter: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}
