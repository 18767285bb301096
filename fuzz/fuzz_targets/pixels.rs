//! Fuzz target `pixels`: the body is `tofprox_fuzz::pixels` (fuzz/src/lib.rs, its invariants).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| tofprox_fuzz::pixels(data));
