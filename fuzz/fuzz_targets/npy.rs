//! Fuzz target `npy`: the body is `tofprox_fuzz::npy` (fuzz/src/lib.rs, its invariants).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| tofprox_fuzz::npy(data));
