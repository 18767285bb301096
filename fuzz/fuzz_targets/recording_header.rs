//! Fuzz the `recording.toml` reader (both kinds: raw and depth, format
//! versions 1 and 2): any text must give a kind or a `FormatError` naming the
//! file, never a panic, and never allocate by a size the text merely claims
//! (window sizes and capture counts are bounded before anything is sized).
//! A valid header stays valid when its own validation is run again.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use tofprox_format::validate_recording_toml;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let path = Path::new("REC/recording.toml");
    match validate_recording_toml(path, text) {
        Ok(kind) => assert_eq!(validate_recording_toml(path, text).ok(), Some(kind)),
        Err(e) => assert_eq!(e.path(), Some(path), "{e}"),
    }
});
