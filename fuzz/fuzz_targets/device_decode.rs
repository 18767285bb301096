//! Fuzz target `device_decode`: the body is `tofprox_fuzz::device_decode` (fuzz/src/lib.rs, its invariants).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| tofprox_fuzz::device_decode(data));
