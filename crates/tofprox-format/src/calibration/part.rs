//! The parts of a calibration set: which part ([`CalibPart`], the key of the set's map) and its
//! value ([`PartValue`]), with the array each is saved as (`docs/calibration.md`).

use std::fmt;

use ndarray::Array1;
use tofprox_core::Algorithm;
use tofprox_core::calib::{FppnMap, OffsetCalibration, WigglingLut};
use tofprox_core::camera::{Distortion, Intrinsics};
use tofprox_core::crosstalk::CrosstalkCalibration;
use tofprox_core::radiometry::AmplitudeScale;

use crate::npy;

/// One part of a calibration set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum CalibPart {
    /// Lens intrinsics and distortion, `[fx, fy, cx, cy, k1, k2, p1, p2, k3]` (OpenCV order).
    Intrinsics,
    /// Per-pixel dark frame (FPN).
    Offset,
    /// Cover-window crosstalk per raw image (0°, 90°, 180°, 270°), LSB per µs.
    Crosstalk,
    /// Wiggling LUT for 2-phase evaluation.
    Wiggling2Phase,
    /// Wiggling LUT for 4-phase evaluation.
    Wiggling4Phase,
    /// Per-pixel phase offsets (FPPN) for 4-phase evaluation (absolute w.r.t. the 4-phase LUT).
    Fppn,
    /// Per-pixel phase offsets (FPPN) for 2-phase evaluation (absolute w.r.t. the 2-phase LUT).
    Fppn2Phase,
    /// Per-pixel amplitude scale `K` of `A = K·ρ·t/d²` (thesis 2.2.1), LSB·m²/µs.
    Amplitude,
}

impl CalibPart {
    /// All parts, in order of application.
    pub const ALL: [CalibPart; 8] = [
        CalibPart::Intrinsics,
        CalibPart::Offset,
        CalibPart::Crosstalk,
        CalibPart::Wiggling2Phase,
        CalibPart::Wiggling4Phase,
        CalibPart::Fppn,
        CalibPart::Fppn2Phase,
        CalibPart::Amplitude,
    ];
    /// The table name in `calibration.toml` (also the array's file stem).
    pub fn name(self) -> &'static str {
        match self {
            CalibPart::Intrinsics => "intrinsics",
            CalibPart::Offset => "offset",
            CalibPart::Crosstalk => "crosstalk",
            CalibPart::Wiggling2Phase => "wiggling_2phase",
            CalibPart::Wiggling4Phase => "wiggling_4phase",
            CalibPart::Fppn => "fppn",
            CalibPart::Fppn2Phase => "fppn_2phase",
            CalibPart::Amplitude => "amplitude",
        }
    }
    /// The array file name.
    pub fn file_name(self) -> String {
        format!("{}.npy", self.name())
    }
    /// The wiggling part for an algorithm.
    pub fn wiggling(algorithm: Algorithm) -> CalibPart {
        match algorithm {
            Algorithm::TwoPhase => CalibPart::Wiggling2Phase,
            Algorithm::FourPhase => CalibPart::Wiggling4Phase,
        }
    }
    /// The FPPN part for an algorithm.
    pub fn fppn(algorithm: Algorithm) -> CalibPart {
        match algorithm {
            Algorithm::TwoPhase => CalibPart::Fppn2Phase,
            Algorithm::FourPhase => CalibPart::Fppn,
        }
    }
    /// The algorithm a wiggling or FPPN part belongs to.
    pub fn algorithm(self) -> Option<Algorithm> {
        match self {
            CalibPart::Intrinsics
            | CalibPart::Offset
            | CalibPart::Amplitude
            | CalibPart::Crosstalk => None,
            CalibPart::Wiggling2Phase | CalibPart::Fppn2Phase => Some(Algorithm::TwoPhase),
            CalibPart::Wiggling4Phase | CalibPart::Fppn => Some(Algorithm::FourPhase),
        }
    }

    /// A phase correction (a wiggling table, an FPPN map): within one period, and extracted
    /// through the lens, so it records the lens's checksum where the set holds one.
    pub(super) fn phase_correction(self) -> bool {
        self.algorithm().is_some()
    }
}

impl fmt::Display for CalibPart {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A part's value as the set holds it, under its [`CalibPart`]. The two wiggling tables and the
/// two FPPN maps share a variant: which algorithm one belongs to is its key's
/// ([`CalibPart::algorithm`]).
#[derive(Debug, Clone, PartialEq)]
pub enum PartValue {
    /// [`CalibPart::Intrinsics`].
    Intrinsics(Intrinsics),
    /// [`CalibPart::Offset`].
    Offset(OffsetCalibration),
    /// [`CalibPart::Crosstalk`].
    Crosstalk(CrosstalkCalibration),
    /// [`CalibPart::Wiggling2Phase`] or [`CalibPart::Wiggling4Phase`].
    Wiggling(WigglingLut),
    /// [`CalibPart::Fppn`] or [`CalibPart::Fppn2Phase`].
    Fppn(FppnMap),
    /// [`CalibPart::Amplitude`].
    Amplitude(AmplitudeScale),
}

impl PartValue {
    /// The part's array file as it is saved (float32 `.npy`).
    pub(super) fn npy_bytes(&self) -> Vec<u8> {
        match self {
            PartValue::Intrinsics(k) => npy::encode_f32(&intrinsics_array(k)),
            PartValue::Offset(o) => npy::encode_f32(&o.dark_lsb),
            PartValue::Crosstalk(x) => npy::encode_f32(&x.lsb_per_us),
            PartValue::Wiggling(w) => npy::encode_f32(&w.correction_rad),
            PartValue::Fppn(f) => npy::encode_f32(&f.phase_offset_rad),
            PartValue::Amplitude(a) => npy::encode_f32(&a.lsb_m2_per_us),
        }
    }

    /// The shape of its array.
    pub(super) fn shape(&self) -> Vec<usize> {
        match self {
            PartValue::Intrinsics(_) => vec![INTRINSICS_LEN],
            PartValue::Offset(o) => o.dark_lsb.shape().to_vec(),
            PartValue::Crosstalk(x) => x.lsb_per_us.shape().to_vec(),
            PartValue::Wiggling(w) => vec![w.len()],
            PartValue::Fppn(f) => f.phase_offset_rad.shape().to_vec(),
            PartValue::Amplitude(a) => a.lsb_m2_per_us.shape().to_vec(),
        }
    }
}

/// Number of values of the intrinsics array.
pub(super) const INTRINSICS_LEN: usize = 9;

/// `[fx, fy, cx, cy, k1, k2, p1, p2, k3]`: OpenCV's camera-matrix entries, then its
/// `distCoeffs` order.
pub(super) fn intrinsics_array(k: &Intrinsics) -> Array1<f32> {
    let d = &k.distortion;
    Array1::from_iter(
        [
            k.fx_px, k.fy_px, k.cx_px, k.cy_px, d.k1, d.k2, d.p1, d.p2, d.k3,
        ]
        .map(|v| v as f32),
    )
}

pub(super) fn intrinsics_from_array(a: &Array1<f32>) -> Intrinsics {
    let v = |i: usize| a.get(i).copied().map_or(f64::NAN, f64::from);
    Intrinsics {
        fx_px: v(0),
        fy_px: v(1),
        cx_px: v(2),
        cy_px: v(3),
        distortion: Distortion {
            k1: v(4),
            k2: v(5),
            p1: v(6),
            p2: v(7),
            k3: v(8),
        },
    }
}
