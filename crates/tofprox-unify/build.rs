//! Nothing to build: the build-dependencies in `Cargo.toml` only ask for features of the
//! host's `syn`, which cargo resolves for a crate with a build script.
fn main() {}
