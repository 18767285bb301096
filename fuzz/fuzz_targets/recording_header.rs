//! Fuzz target `recording_header`: the body is `tofprox_fuzz::recording_header` (fuzz/src/lib.rs, its invariants).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| tofprox_fuzz::recording_header(data));
