//! The raw sample types the pipeline accepts (`u16` codes, `f32`/`f64` averaged codes), each
//! with the kernel's vector load.

/// A raw sample type the pipeline accepts: `u16` codes, or `f32`/`f64` averaged codes.
///
/// Sealed: the kernel has a vector load for each of the three types.
pub trait RawSample: Copy + Send + Sync + 'static + sealed::LoadLanes {
    /// The value as `f32` (exact for `u16`; NaN/∞ propagate and are flagged).
    fn to_f32(self) -> f32;
}

mod sealed {
    use crate::simd::{LANES, Simd};

    /// Loads eight samples into the kernel's lanes as `f32`.
    pub trait LoadLanes: Sized {
        /// Every value converts to a finite `f32` (`u16`): the kernel skips the finiteness check.
        const ALWAYS_FINITE: bool;
        /// The eight values as `f32` lanes (the conversion of [`super::RawSample::to_f32`]).
        fn load_lanes<S: Simd>(s: S, a: &[Self; LANES]) -> S::F32;
    }

    impl LoadLanes for u16 {
        const ALWAYS_FINITE: bool = true;
        #[inline(always)]
        fn load_lanes<S: Simd>(s: S, a: &[Self; LANES]) -> S::F32 {
            s.load_u16(a)
        }
    }

    impl LoadLanes for f32 {
        const ALWAYS_FINITE: bool = false;
        #[inline(always)]
        fn load_lanes<S: Simd>(s: S, a: &[Self; LANES]) -> S::F32 {
            s.load(a)
        }
    }

    impl LoadLanes for f64 {
        const ALWAYS_FINITE: bool = false;
        #[inline(always)]
        fn load_lanes<S: Simd>(s: S, a: &[Self; LANES]) -> S::F32 {
            s.load_f64(a)
        }
    }
}

impl RawSample for u16 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        f32::from(self)
    }
}

impl RawSample for f32 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
}

impl RawSample for f64 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}
