//! Fuzz target `usbcap`: the body is `tofprox_fuzz::usbcap` (fuzz/src/lib.rs, its invariants).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| tofprox_fuzz::usbcap(data));
