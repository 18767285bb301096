//! No code: the features that make the production daemon's and the Python wheel's
//! builds reuse the dependencies `cargo test --workspace` compiled (see `Cargo.toml`).
