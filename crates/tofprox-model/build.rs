//! Rebuild the crate when a file is added to or removed from `src/effects/`: `automod`
//! makes every file there a module (an effect is its file alone, `effects/mod.rs`), but
//! reads the directory itself, which cargo does not track without this.

fn main() {
    println!("cargo:rerun-if-changed=src/effects");
}
