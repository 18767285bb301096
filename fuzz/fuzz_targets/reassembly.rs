//! Fuzz target `reassembly`: the body is `tofprox_fuzz::reassembly` (fuzz/src/lib.rs, its invariants).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| tofprox_fuzz::reassembly(data));
