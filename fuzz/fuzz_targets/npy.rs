//! Fuzz the bounded `.npy` decoder every frames file and calibration array
//! goes through: any bytes give an array or an error, never a panic, and the
//! decoder never allocates more than the input's size. A decoded array
//! re-encodes to a file that decodes to the same array.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tofprox_format::npy::{self, NpyArray};

fuzz_target!(|data: &[u8]| {
    let Ok(a) = npy::decode(data) else { return };
    let bytes = match &a {
        NpyArray::U16(x) => npy::encode_u16(x),
        NpyArray::F32(x) => npy::encode_f32(x),
        NpyArray::F64(x) => npy::encode_f64(x),
    };
    let b = npy::decode(&bytes).expect("a re-encoded array decodes");
    match (&a, &b) {
        (NpyArray::U16(x), NpyArray::U16(y)) => assert_eq!(x, y),
        // bit patterns: NaN payloads must survive too
        (NpyArray::F32(x), NpyArray::F32(y)) => {
            assert_eq!(x.shape(), y.shape());
            assert!(x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits()));
        }
        (NpyArray::F64(x), NpyArray::F64(y)) => {
            assert_eq!(x.shape(), y.shape());
            assert!(x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits()));
        }
        _ => panic!("dtype changed on re-encoding"),
    }
});
