//! Per-frame processing: raw phase images → calibrated depth (thesis 4.3.3, fig. 3.20).
//!
//! In this order per pixel:
//! 1. validity of the RAW codes: saturation (any used image at a rail: `≤ 0` or `≥ 2^bits − 1`),
//!    non-finite input;
//! 2. offset correction (4.3.3.1): `u_k = code_k − dark[p]` (per-pixel dark frame, or the mid code
//!    `2^(bits−1)` when no dark frame is given); with a crosstalk calibration also
//!    `− X_k[p] · t_exp` (the cover window's return, [`crate::crosstalk`]), applied while the raw
//!    images are staged as `f32` (codes at a rail stay there), so the kernels are unchanged;
//! 3. phase: eq. 2.2 (2-phase, images 0°, 90°) or eq. 2.3 (4-phase, 0°, 90°, 180°, 270°),
//! 4. and wiggling correction (3.3.7.2 / 4.3.3.3): `phase − LUT(phase)` with the calibration
//!    table's linear periodic interpolation ([`WigglingLut::correct`]) — both read together from
//!    one table (see *Phase table* below);
//! 5. FPPN (2.3.1.4): `− fppn[p]`, then wrap into `[0, 2π)`;
//! 6. amplitude (eq. 2.4 or its 2-phase form `|z|`), low-amplitude check;
//! 7. depth (eq. 2.6) in metres and `u16` millimetres (0 = invalid; a valid depth that would round
//!    to 0 mm is reported as 1 mm; beyond 65535 mm → invalid). This depth is **radial**: the length
//!    of the pixel's ray to the surface, what the phase measures. Z depth (along the optical axis)
//!    and points need the lens: [`crate::camera::RayGrid::radial_to_z`] and
//!    [`crate::camera::RayGrid::points`].
//!
//! Invalid pixels have `depth_m = 0`, `depth_mm = 0` — never NaN. Buffers are allocated in
//! [`Pipeline::new`]; [`Pipeline::process`] does not allocate.
//!
//! # Phase table
//! `atan2(y, x)` is the octant of `(x, y)` (signs of `x`, `y` and whether `|y| > |x|`) and
//! `atan(t)` of `t = min(|x|, |y|) / max(|x|, |y|) ∈ [0, 1]`. Per octant, a table over `t`
//! (512 bins of value + slope, built in `f64` when the calibration is set) holds the *corrected*
//! phase `wrap(φ − LUT(φ))` at `φ = φ(octant, t)`, so one division, one table read and a linear
//! interpolation replace the `atan2` polynomial and the wiggling lookup. Errors against the `f64`
//! reference `WigglingLut::correct(atan2(y, x))`: linear interpolation of `atan` over bins of
//! `1/512` is within `(1/512)²/8 · max|atan''| = 3.1e-7 rad`; where the calibration table has a
//! kink (its own linear interpolation changes slope between two of its bins) the error is at most
//! `Δslope · h / 4` with `h ≤ 1.95e-3 rad` the table's bin width in phase — `4.9e-5 rad`
//! (0.015 mm) for a slope change of 0.1 rad/rad; plus `f32` rounding (≈ 5e-7 rad). The
//! `lut_resampling_matches_linear_periodic_interpolation` test bounds the whole.
//!
//! # Speed
//! The kernel is written once against eight-lane operations (`simd::Simd`, implemented by each
//! instruction set's token, the proof that the CPU has it) and compiled per instruction set:
//! generic (plain arrays the compiler vectorises), AVX2 (`__m256`), AVX-512 (the AVX2 lanes with
//! AVX-512 enabled), NEON (two `float32x4_t`). [`SimdLevel::detect`] picks the best at run time;
//! [`Pipeline::set_simd_level`] forces another supported one. Every lane operation is
//! the exact IEEE-754 operation (no FMA, no estimates), so the levels agree to the bit (tested).
//! The frame is processed in blocks of 256 pixels, two short passes per block (validity,
//! amplitude and table position; table read, FPPN and outputs) so the core overlaps iterations;
//! the phase table is read by scalar loads (cheaper than `vpgatherdq` on Zen 3). Float→integer
//! conversions use the 1.5·2^23 mantissa trick. No threads: one core per frame. Profile and
//! figures: `docs/performance.md`; `cargo bench -p tofprox-core --bench pipeline`.

mod kernel;
mod process;
mod sample;
mod table;

use crate::calib::{FppnMap, OffsetCalibration, WigglingLut, check_offset};
use crate::crosstalk::CrosstalkCalibration;
use crate::phasor::{self, Quadrature, wrap_to_pi};
pub use crate::simd::SimdLevel;
use crate::simd::{Isa, LUT_BINS, Lut};
use crate::{Algorithm, CoreError};
pub use sample::RawSample;
use table::phase_table;

pub use crate::frame::{
    DepthFrame, FLAG_IMPLAUSIBLE, FLAG_INVALID, FLAG_LOW_AMPLITUDE, FLAG_NON_FINITE,
    FLAG_SATURATED, depth_m_to_mm, median_valid_m,
};

/// Largest frame a pipeline accepts (64 Mpixel; the IRS1645 has 38 528 pixels).
pub const MAX_PIXELS: usize = 1 << 26;

/// Processing parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PipelineConfig {
    /// 2- or 4-phase evaluation.
    pub algorithm: Algorithm,
    /// Modulation frequency, Hz (80 MHz on the IRS1645).
    pub modulation_hz: f64,
    /// ADC resolution, bits (1..=16; 12 on the IRS1645).
    pub adc_bits: u8,
    /// Pixels with amplitude (eq. 2.4, in LSB) below this are flagged low-amplitude and invalid.
    pub min_amplitude_lsb: f32,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig {
            algorithm: Algorithm::TwoPhase,
            modulation_hz: 80e6,
            adc_bits: 12,
            min_amplitude_lsb: 10.0,
        }
    }
}

impl PipelineConfig {
    /// Checks ranges: `modulation_hz` and `adc_bits` as every sensor geometry
    /// ([`crate::sensor::validate_modulation_hz`], [`crate::sensor::validate_adc_bits`]),
    /// `min_amplitude_lsb` finite ≥ 0.
    pub fn validate(&self) -> Result<(), CoreError> {
        crate::sensor::validate_modulation_hz(self.modulation_hz)?;
        crate::sensor::validate_adc_bits(self.adc_bits)?;
        if !(self.min_amplitude_lsb.is_finite() && self.min_amplitude_lsb >= 0.0) {
            return Err(CoreError::param(
                "min_amplitude_lsb",
                format!("must be finite and ≥ 0, got {}", self.min_amplitude_lsb),
            ));
        }
        Ok(())
    }
}

/// The calibrations a pipeline applies; each is optional.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Calibration {
    /// Per-pixel dark frame; without it the mid code is subtracted.
    pub offset: Option<OffsetCalibration>,
    /// Wiggling LUT; must be for the pipeline's algorithm.
    pub wiggling: Option<WigglingLut>,
    /// Per-pixel phase offsets.
    pub fppn: Option<FppnMap>,
    /// Cover-window crosstalk per raw image (subtracted scaled to the exposure set with
    /// [`Pipeline::set_exposure_us`]).
    pub crosstalk: Option<CrosstalkCalibration>,
}

/// Constants of the per-pixel kernel.
#[derive(Debug, Clone, Copy)]
struct KernelParams {
    rail_hi: f32,
    min_amp: f32,
    rad_to_m: f32,
    /// Signs of the in-phase and quadrature parts ([`Quadrature`]), ±1.
    x_sign: f32,
    y_sign: f32,
}

/// The processing pipeline: owns its calibration tables and output buffers; `process` is
/// allocation-free.
#[derive(Debug, Clone)]
pub struct Pipeline {
    rows: usize,
    cols: usize,
    config: PipelineConfig,
    calibration: Calibration,
    params: KernelParams,
    /// Per-pixel value subtracted from each raw image (dark frame, or mid code).
    dark: Vec<f32>,
    /// Per-pixel FPPN phase (zeros when none), wrapped to (−π, π].
    fppn: Vec<f32>,
    /// Phase table (eqs. 2.2 / 2.3 and the wiggling correction, see the module docs): per bin
    /// `value | slope << 32` (f32 bits), so one 64-bit load fetches both.
    lut: Box<Lut>,
    /// Staging for non-contiguous input (4 × rows × cols).
    staging: Vec<f32>,
    /// Crosstalk per raw image in codes at the current exposure and scale (4 × rows × cols;
    /// empty without a crosstalk calibration).
    crosstalk_codes: Vec<f32>,
    /// Exposure the crosstalk is scaled to (`None` until [`Pipeline::set_exposure_us`]).
    exposure_us: Option<f64>,
    /// Factor on the calibrated crosstalk ([`Pipeline::set_crosstalk_scale`]).
    crosstalk_scale: f32,
    frame: DepthFrame,
    /// The kernel's instruction set, as the proof that this CPU has it.
    isa: Isa,
}

impl Pipeline {
    /// Builds a pipeline for `rows × cols` frames. Validates the configuration and that every
    /// calibration matches (`(rows, cols)` shapes, finite values, LUT for this algorithm).
    pub fn new(
        rows: usize,
        cols: usize,
        config: PipelineConfig,
        calibration: Calibration,
    ) -> Result<Self, CoreError> {
        config.validate()?;
        if rows == 0 || cols == 0 {
            return Err(CoreError::shape(
                "pipeline frame",
                "rows ≥ 1 and cols ≥ 1",
                format!("({rows}, {cols})"),
            ));
        }
        let n = rows
            .checked_mul(cols)
            .filter(|&n| n <= MAX_PIXELS)
            .ok_or_else(|| {
                CoreError::shape(
                    "pipeline frame",
                    format!("rows × cols ≤ {MAX_PIXELS}"),
                    format!("({rows}, {cols})"),
                )
            })?;
        let params = KernelParams {
            rail_hi: crate::sensor::adc_max_code(config.adc_bits) as f32,
            min_amp: config.min_amplitude_lsb,
            rad_to_m: (phasor::unambiguous_range_m(config.modulation_hz) / std::f64::consts::TAU)
                as f32,
            x_sign: 1.0,
            y_sign: 1.0,
        };
        let mut p = Pipeline {
            rows,
            cols,
            config,
            calibration: Calibration::default(),
            params,
            dark: vec![0.0; n],
            fppn: vec![0.0; n],
            lut: Box::new([0; LUT_BINS]),
            staging: vec![0.0; 4 * n],
            crosstalk_codes: Vec::new(),
            exposure_us: None,
            crosstalk_scale: 1.0,
            frame: DepthFrame::zeros(rows, cols),
            isa: Isa::detect(),
        };
        p.set_calibration(calibration)?;
        Ok(p)
    }

    /// Replaces the calibration (validated as in [`Pipeline::new`]; on error nothing changes).
    pub fn set_calibration(&mut self, calibration: Calibration) -> Result<(), CoreError> {
        let shape = (self.rows, self.cols);
        let mut dark =
            vec![crate::sensor::adc_mid_code(self.config.adc_bits) as f32; self.rows * self.cols];
        check_offset(calibration.offset.as_ref(), self.rows, self.cols)?;
        if let Some(off) = &calibration.offset {
            for (d, v) in dark.iter_mut().zip(off.dark_lsb.iter()) {
                *d = *v;
            }
        }
        let mut fppn = vec![0.0f32; self.rows * self.cols];
        if let Some(f) = &calibration.fppn {
            if f.phase_offset_rad.dim() != shape {
                return Err(CoreError::shape(
                    "FPPN map (phase_offset_rad)",
                    format!("{shape:?}"),
                    format!("{:?}", f.phase_offset_rad.dim()),
                ));
            }
            if f.phase_offset_rad.iter().any(|v| !v.is_finite()) {
                return Err(CoreError::Calibration(
                    "FPPN map contains non-finite values".into(),
                ));
            }
            for (d, v) in fppn.iter_mut().zip(f.phase_offset_rad.iter()) {
                *d = wrap_to_pi(*v as f64) as f32;
            }
        }
        if let Some(w) = &calibration.wiggling {
            if w.algorithm != self.config.algorithm {
                return Err(CoreError::Calibration(format!(
                    "wiggling LUT is for {} but the pipeline runs {}",
                    w.algorithm, self.config.algorithm
                )));
            }
            w.validate()?;
        }
        let lut = phase_table(calibration.wiggling.as_ref());
        if let Some(x) = &calibration.crosstalk {
            x.validate(self.rows, self.cols)?;
        }
        self.dark = dark;
        self.fppn = fppn;
        self.lut = lut;
        self.calibration = calibration;
        self.crosstalk_codes = if self.calibration.crosstalk.is_some() {
            vec![0.0; 4 * self.rows * self.cols]
        } else {
            Vec::new()
        };
        self.rescale_crosstalk();
        Ok(())
    }

    /// The exposure per raw image of the frames that follow, µs: the crosstalk calibration is
    /// scaled to it (recomputed only when it changes). Required before [`Pipeline::process`]
    /// when the calibration holds crosstalk; without one it is only recorded.
    pub fn set_exposure_us(&mut self, exposure_us: f64) -> Result<(), CoreError> {
        if !(exposure_us.is_finite() && exposure_us > 0.0) {
            return Err(CoreError::param(
                "exposure_us",
                format!("must be finite and > 0, got {exposure_us}"),
            ));
        }
        if self.exposure_us != Some(exposure_us) {
            self.exposure_us = Some(exposure_us);
            self.rescale_crosstalk();
        }
        Ok(())
    }

    /// The exposure set with [`Pipeline::set_exposure_us`].
    pub fn exposure_us(&self) -> Option<f64> {
        self.exposure_us
    }

    /// Multiply the calibrated crosstalk by `scale` (default 1; e.g.
    /// [`crate::crosstalk::CrosstalkMonitor::suggested_scale`] to follow a smudged window).
    pub fn set_crosstalk_scale(&mut self, scale: f32) -> Result<(), CoreError> {
        if !(scale.is_finite() && (0.0..=100.0).contains(&scale)) {
            return Err(CoreError::param(
                "crosstalk_scale",
                format!("must be within 0..=100, got {scale}"),
            ));
        }
        if self.crosstalk_scale != scale {
            self.crosstalk_scale = scale;
            self.rescale_crosstalk();
        }
        Ok(())
    }

    /// The factor on the calibrated crosstalk ([`Pipeline::set_crosstalk_scale`]).
    pub fn crosstalk_scale(&self) -> f32 {
        self.crosstalk_scale
    }

    fn rescale_crosstalk(&mut self) {
        let (Some(x), Some(t)) = (&self.calibration.crosstalk, self.exposure_us) else {
            return;
        };
        let f = (t as f32) * self.crosstalk_scale;
        for (d, s) in self.crosstalk_codes.iter_mut().zip(x.lsb_per_us.iter()) {
            *d = s * f;
        }
    }

    /// The configuration.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    /// The calibration in use.
    pub fn calibration(&self) -> &Calibration {
        &self.calibration
    }

    /// `(rows, cols)` this pipeline processes.
    pub fn dim(&self) -> (usize, usize) {
        (self.rows, self.cols)
    }

    /// The last processed frame (zeros before the first `process`).
    pub fn frame(&self) -> &DepthFrame {
        &self.frame
    }

    /// The last processed frame, for post-processing steps that flag pixels
    /// (e.g. [`crate::radiometry::flag_implausible_near`]).
    pub fn frame_mut(&mut self) -> &mut DepthFrame {
        &mut self.frame
    }

    /// The last processed frame to flag pixels in, beside the calibration it was processed
    /// with (e.g. [`crate::crosstalk::flag_window_explained`] needs the crosstalk).
    pub fn frame_mut_and_calibration(&mut self) -> (&mut DepthFrame, &Calibration) {
        (&mut self.frame, &self.calibration)
    }

    /// Selects the kernel's instruction set, e.g. to benchmark or test the portable path on a
    /// machine with AVX2. Only levels this CPU supports ([`SimdLevel::is_supported`]) are
    /// accepted; every level gives bit-identical results (the kernel uses exact IEEE operations only).
    pub fn set_simd_level(&mut self, level: SimdLevel) -> Result<(), CoreError> {
        self.isa = Isa::of(level).ok_or_else(|| {
            CoreError::param(
                "simd_level",
                format!("{level} is not supported by this CPU"),
            )
        })?;
        Ok(())
    }

    /// The canonical phase shifts of the raw images given to [`Pipeline::process`] (default
    /// [`Quadrature::STANDARD`], images at 0°, 90°(, 180°, 270°)): a recording made with another
    /// [`crate::phasor::PhaseConvention`] has its shifts relabelled to canonical ones, and e.g. a
    /// `[0°, 270°]` pair is evaluated by eq. 2.2 with the quadrature part negated.
    pub fn set_quadrature(&mut self, quadrature: Quadrature) {
        let sign = |s: i8| if s < 0 { -1.0 } else { 1.0 };
        self.params.x_sign = sign(quadrature.x_sign);
        self.params.y_sign = sign(quadrature.y_sign);
    }

    /// The quadrature set with [`Pipeline::set_quadrature`].
    pub fn quadrature(&self) -> Quadrature {
        let sign = |v: f32| if v < 0.0 { -1 } else { 1 };
        Quadrature {
            x_sign: sign(self.params.x_sign),
            y_sign: sign(self.params.y_sign),
        }
    }

    /// The instruction set the per-pixel kernel runs with (the best this CPU supports, detected
    /// at construction, unless [`Pipeline::set_simd_level`] chose another).
    pub fn simd_level(&self) -> SimdLevel {
        self.isa.level()
    }
}

#[cfg(test)]
mod tests;
