//! tofprox processing core: raw phase images to calibrated depth (thesis ch. 2.2, 3.3, 4.3).
//!
//! Pure math, no I/O, no async. The modules follow the processing chain of the thesis:
//!
//! - [`phasor`]: scalar phasor math (eqs. 2.2–2.9), N-phase DFT, dual-frequency range extension.
//! - [`calib`]: extraction of offset (FPN, 2.3.1.3 / 3.3.7.1), wiggling LUT (3.3.6 / 3.3.7.2 /
//!   4.3.2.2) and fixed-pattern phase noise (2.3.1.4) from captures.
//! - [`crosstalk`]: cover-window crosstalk (extraction, compensation constants, change monitor).
//! - [`frame`]: the pipeline's output, [`frame::DepthFrame`] with its per-pixel flags, and
//!   [`frame::Roi`], the region of it that the detector and the crosstalk monitor read (below
//!   all of them: re-exported from [`pipeline`] and [`proximity`]).
//! - [`pipeline`]: the per-frame processing (offset correction, phase, wiggling correction, FPPN,
//!   amplitude, validity, depth), vectorised and allocation-free in the steady state.
//! - [`camera`]: the lens (pinhole + Brown–Conrady distortion): pixel rays, ray length to a plane,
//!   radial → Z depth, point clouds (thesis 5.1.3).
//! - [`lens_fit`]: the lens calibration: intrinsics fitted to a flat-wall sweep (alone, or jointly
//!   with a correlation capture's wiggling table), with standard errors.
//! - [`lsq`]: least squares for small parameter vectors: normal equations, Cholesky and the one
//!   Levenberg–Marquardt solver (the lens fit, the model lab's fits).
//! - `simd` (private): the instruction sets of the pipeline's kernel ([`SimdLevel`]), the
//!   zero-sized tokens that prove this CPU has one, and the eight-lane operations the kernel is
//!   written against once (generic, AVX2, NEON).
//! - [`proximity`]: a near/far detector with hysteresis and debounce on top of a [`pipeline::DepthFrame`].
//! - [`radiometry`]: the `1/d²` law of the returned amplitude (2.2.1), its per-pixel calibration,
//!   the plausibility test that keeps a wrapped phase from reading as near, and the background
//!   light's common mode in the raw images.
//! - [`readout`]: a full-array calibration made to fit one capture: cropped to its read-out
//!   window, its dark level over a region, moved to another modulation frequency.
//! - [`sensor`]: the vocabulary every crate shares: [`SensorGeometry`] (window, full array, ADC,
//!   modulation; mid/max code, phase per metre, unambiguous range), [`RowWindow`],
//!   [`CycleRequest`], the physical constants. The measurement mode is [`Algorithm`].
//!
//! # Conventions (shared by every tofprox crate)
//! A raw image taken with phase shift `theta_k` of a pixel whose total phase is `phi` is, ideally,
//! `code_k = mid + offset_pixel + A * cos(phi - theta_k)` with `mid = 2^(adc_bits-1)` (offset binary).
//! Hence `phi = atan2(u90, u0)` (eq. 2.2) with `u = code - offset`, wrapped to `[0, 2π)`.
//! `phi = phi_tof + phi_delay`, `phi_tof = 4π f d / c` ([`phasor::distance_to_phase_rad`]).

pub mod calib;
pub mod camera;
pub mod crosstalk;
mod error;
pub mod frame;
pub mod lens_fit;
pub mod lsq;
pub mod phasor;
pub mod pipeline;
pub mod proximity;
pub mod radiometry;
pub mod readout;
pub mod sensor;
pub mod serde_exact;
mod simd;

pub use error::{CoreError, error_line};
pub use sensor::{CycleRequest, RowWindow, SPEED_OF_LIGHT_M_PER_S, SensorGeometry};
pub use simd::SimdLevel;

use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Depth evaluation algorithm (thesis 2.2.1): the measurement mode every crate uses (the daemon's
/// `processing.mode`, the driver's depth use cases, calibration parts).
///
/// Serialised (serde, [`Display`](fmt::Display), [`FromStr`]) as `"2phase"` / `"4phase"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Algorithm {
    /// Two raw images at 0° and 90° (eq. 2.2). Sensitive to offset and even harmonics.
    #[serde(rename = "2phase")]
    TwoPhase,
    /// Four raw images at 0°, 90°, 180°, 270° (eq. 2.3). Cancels offsets and even harmonics.
    #[serde(rename = "4phase")]
    FourPhase,
}

impl Algorithm {
    /// Both algorithms, in a fixed order.
    pub const ALL: [Algorithm; 2] = [Algorithm::TwoPhase, Algorithm::FourPhase];

    /// The canonical string (`"2phase"` / `"4phase"`).
    pub fn as_str(self) -> &'static str {
        match self {
            Algorithm::TwoPhase => "2phase",
            Algorithm::FourPhase => "4phase",
        }
    }

    /// Number of raw images the algorithm consumes (2 or 4).
    pub fn raw_images(self) -> usize {
        match self {
            Algorithm::TwoPhase => 2,
            Algorithm::FourPhase => 4,
        }
    }

    /// Phase shifts (degrees) of the raw images the algorithm consumes, in order.
    pub fn phases_deg(self) -> &'static [f64] {
        match self {
            Algorithm::TwoPhase => &[0.0, 90.0],
            Algorithm::FourPhase => &[0.0, 90.0, 180.0, 270.0],
        }
    }
}

impl fmt::Display for Algorithm {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Algorithm {
    type Err = CoreError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "2phase" | "2-phase" | "two-phase" => Ok(Algorithm::TwoPhase),
            "4phase" | "4-phase" | "four-phase" => Ok(Algorithm::FourPhase),
            _ => Err(CoreError::InvalidParameter {
                name: "algorithm",
                reason: format!("unknown algorithm {s:?}, expected \"2phase\" or \"4phase\""),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn algorithm_strings_roundtrip() {
        for a in Algorithm::ALL {
            assert_eq!(a.to_string().parse::<Algorithm>().ok(), Some(a));
            assert_eq!(a.phases_deg().len(), a.raw_images());
        }
        assert!("3phase".parse::<Algorithm>().is_err());
    }
}
