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

use crate::calib::{FppnMap, OffsetCalibration, WigglingLut, check_offset};
use crate::crosstalk::CrosstalkCalibration;
use crate::phasor::{self, Quadrature, wrap_to_pi};
pub use crate::simd::SimdLevel;
use crate::simd::{Isa, LANES, LUT_BINS, LUT_T_BINS, Lut, Simd};
use crate::{Algorithm, CoreError};
use ndarray::{ArrayView3, Axis};
use std::f32::consts::TAU;

pub use crate::frame::{
    DepthFrame, FLAG_IMPLAUSIBLE, FLAG_INVALID, FLAG_LOW_AMPLITUDE, FLAG_NON_FINITE,
    FLAG_SATURATED, depth_m_to_mm, median_valid_m,
};

/// Largest frame a pipeline accepts (64 Mpixel; the IRS1645 has 38 528 pixels).
pub const MAX_PIXELS: usize = 1 << 26;

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

    /// Processes one capture `(K, rows, cols)`: the first 2 (2-phase, phases 0°, 90°) or 4
    /// (4-phase, 0°, 90°, 180°, 270°) images are used, extra images are ignored (so a 4-phase
    /// capture can be processed as 2-phase). Errors on a shape mismatch; never panics, never
    /// allocates.
    pub fn process<T: RawSample>(
        &mut self,
        raw: ArrayView3<'_, T>,
    ) -> Result<&DepthFrame, CoreError> {
        let need = self.config.algorithm.raw_images();
        let (k, r, c) = raw.dim();
        if k < need || r != self.rows || c != self.cols {
            return Err(CoreError::shape(
                "raw frames",
                format!(
                    "({}{need}, {}, {})",
                    if k > need { "≥" } else { "" },
                    self.rows,
                    self.cols
                ),
                format!("({k}, {r}, {c})"),
            ));
        }
        let n = self.rows * self.cols;
        if self.calibration.crosstalk.is_some() {
            if self.exposure_us.is_none() {
                return Err(CoreError::Calibration(
                    "the crosstalk calibration is scaled to the exposure: call set_exposure_us first".into(),
                ));
            }
            // Stage `code − X_k · t` (crosstalk, 2.2.1: its phasor adds to every raw image);
            // rail codes stay at the rail so saturation is still flagged on the raw value.
            let rail = self.params.rail_hi;
            let mut st = std::mem::take(&mut self.staging);
            for i in 0..need {
                let dst = &mut st[i * n..(i + 1) * n];
                let xt = &self.crosstalk_codes[i * n..(i + 1) * n];
                for ((d, s), x) in dst
                    .iter_mut()
                    .zip(raw.index_axis(Axis(0), i).iter())
                    .zip(xt)
                {
                    let v = s.to_f32();
                    let at_rail = (v <= 0.0) | (v >= rail) | !v.is_finite();
                    let c = (v - x).clamp(0.5, rail - 0.5);
                    *d = if at_rail { v } else { c };
                }
            }
            {
                let mut sv: [&[f32]; 4] = [&[]; 4];
                for (i, v) in sv.iter_mut().enumerate().take(need) {
                    *v = &st[i * n..(i + 1) * n];
                }
                self.run(sv, need, n);
            }
            self.staging = st;
            return Ok(&self.frame);
        }
        let contiguous = (0..need).all(|i| raw.index_axis(Axis(0), i).as_slice().is_some());
        let mut views: [&[T]; 4] = [&[]; 4];
        if contiguous {
            for (i, v) in views.iter_mut().enumerate().take(need) {
                *v = raw.index_axis_move(Axis(0), i).to_slice().unwrap_or(&[]);
            }
            self.run(views, need, n);
        } else {
            // Non-standard layout: stage as f32 (buffer preallocated in `new`).
            let staging = &mut self.staging;
            for i in 0..need {
                let dst = &mut staging[i * n..(i + 1) * n];
                for (d, s) in dst.iter_mut().zip(raw.index_axis(Axis(0), i).iter()) {
                    *d = s.to_f32();
                }
            }
            let st = std::mem::take(&mut self.staging);
            {
                let mut sv: [&[f32]; 4] = [&[]; 4];
                for (i, v) in sv.iter_mut().enumerate().take(need) {
                    *v = &st[i * n..(i + 1) * n];
                }
                self.run(sv, need, n);
            }
            self.staging = st;
        }
        Ok(&self.frame)
    }

    fn run<T: RawSample>(&mut self, raw: [&[T]; 4], need: usize, n: usize) {
        let out = Outputs {
            phase: self.frame.phase_rad.as_slice_mut().unwrap_or(&mut []),
            amp: self.frame.amplitude_lsb.as_slice_mut().unwrap_or(&mut []),
            depth_m: self.frame.depth_m.as_slice_mut().unwrap_or(&mut []),
            depth_mm: self.frame.depth_mm.as_slice_mut().unwrap_or(&mut []),
            flags: self.frame.flags.as_slice_mut().unwrap_or(&mut []),
        };
        let tabs = Tables {
            dark: &self.dark,
            fppn: self
                .calibration
                .fppn
                .is_some()
                .then_some(self.fppn.as_slice()),
            lut: &self.lut,
        };
        let p = self.params;
        let four = need == 4;
        match self.isa {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512(proof) => {
                // SAFETY: the kernel needs AVX-512 F/BW/VL/DQ, AVX2 and FMA: `proof` is an
                // `Avx512`, which only `Avx512::detect` makes after the CPU reported all of them.
                #[allow(unsafe_code)]
                unsafe {
                    kernel_avx512(proof, raw, four, n, &p, &tabs, out)
                }
            }
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2(proof) => {
                // SAFETY: the kernel needs AVX2 and FMA: `proof` is an `Avx2`, which only
                // `Avx2::detect` makes after the CPU reported both.
                #[allow(unsafe_code)]
                unsafe {
                    kernel_avx2(proof, raw, four, n, &p, &tabs, out)
                }
            }
            #[cfg(target_arch = "aarch64")]
            Isa::Neon(proof) => kernel_dispatch(proof, raw, four, n, &p, &tabs, out),
            Isa::Portable(proof) => kernel_dispatch(proof, raw, four, n, &p, &tabs, out),
        }
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

struct Outputs<'a> {
    phase: &'a mut [f32],
    amp: &'a mut [f32],
    depth_m: &'a mut [f32],
    depth_mm: &'a mut [u16],
    flags: &'a mut [u8],
}

struct Tables<'a> {
    dark: &'a [f32],
    /// `None` when there is no FPPN map (the kernel then skips the per-pixel load).
    fppn: Option<&'a [f32]>,
    lut: &'a Lut,
}

/// Octant bits of a phase-table index (above the `t` bin): `|y| > |x|`, `x < 0`, `y < 0`.
const OCTANT_SWAP: u32 = LUT_T_BINS as u32;
const OCTANT_NEG_X: u32 = 2 * LUT_T_BINS as u32;
const OCTANT_NEG_Y: u32 = 4 * LUT_T_BINS as u32;

/// The phase (eqs. 2.2 / 2.3, `[0, 2π)`) of the octant bits `octant` (a multiple of
/// [`LUT_T_BINS`]) and `t = min(|x|, |y|) / max(|x|, |y|)`.
fn octant_phase_rad(octant: u32, t: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI, TAU};
    let a = t.atan();
    let a = if octant & OCTANT_SWAP != 0 {
        FRAC_PI_2 - a
    } else {
        a
    };
    let a = if octant & OCTANT_NEG_X != 0 {
        PI - a
    } else {
        a
    };
    let a = if octant & OCTANT_NEG_Y != 0 {
        TAU - a
    } else {
        a
    };
    phasor::wrap_phase(a)
}

/// The kernel's phase table (module docs, *Phase table*): per octant and `t` bin the corrected
/// phase `wrap(φ − LUT(φ))` in `[0, 2π)` (just `φ` without a wiggling table) at the bin's start,
/// and its change to the next bin wrapped to `(−π, π]`, computed in `f64`.
fn phase_table(wiggling: Option<&WigglingLut>) -> Box<Lut> {
    let corrected = |octant: u32, k: usize| {
        let phi = octant_phase_rad(octant, k as f64 / LUT_T_BINS as f64);
        wiggling.map_or(phi, |w| w.correct(phi))
    };
    let mut lut = Box::new([0u64; LUT_BINS]);
    for (j, entry) in lut.iter_mut().enumerate() {
        let (octant, k) = ((j & !(LUT_T_BINS - 1)) as u32, j & (LUT_T_BINS - 1));
        let (v, next) = (corrected(octant, k), corrected(octant, k + 1));
        // An f64 just below 2π rounds to 2π in f32; keep the value in [0, 2π).
        let value = match v as f32 {
            v32 if v32 >= TAU => 0.0,
            v32 => v32,
        };
        let slope = wrap_to_pi(next - f64::from(value)) as f32;
        *entry = u64::from(value.to_bits()) | (u64::from(slope.to_bits()) << 32);
    }
    lut
}

/// The kernel with AVX-512 available to the code generator (masks, 32 registers) on the AVX2
/// lanes; `_proof` shows the CPU has the features this function is compiled for.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq,avx2,fma")]
fn kernel_avx512<T: RawSample>(
    proof: crate::simd::avx2::Avx512,
    raw: [&[T]; 4],
    four: bool,
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
) {
    kernel_dispatch(proof.avx2(), raw, four, n, p, t, out)
}

/// The kernel compiled for AVX2 and FMA (no fused operation is used: see the module docs);
/// `proof` shows the CPU has them.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn kernel_avx2<T: RawSample>(
    proof: crate::simd::avx2::Avx2,
    raw: [&[T]; 4],
    four: bool,
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
) {
    kernel_dispatch(proof, raw, four, n, p, t, out)
}

#[inline(always)]
fn kernel_dispatch<S: Simd, T: RawSample>(
    s: S,
    raw: [&[T]; 4],
    four: bool,
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
) {
    match (four, t.fppn.is_some()) {
        (true, true) => kernel::<S, T, true, true>(s, raw, n, p, t, out),
        (true, false) => kernel::<S, T, true, false>(s, raw, n, p, t, out),
        (false, true) => kernel::<S, T, false, true>(s, raw, n, p, t, out),
        (false, false) => kernel::<S, T, false, false>(s, raw, n, p, t, out),
    }
}

/// Steps of [`LANES`] pixels per block: the block's intermediates (4 kB) stay in L1 between the
/// two passes.
const BLOCK_STEPS: usize = 32;

/// Pass-1 → pass-2 intermediates of one block.
struct Scratch {
    /// Phase-table bin and fraction.
    idx: [[u32; LANES]; BLOCK_STEPS],
    fr: [[f32; LANES]; BLOCK_STEPS],
    /// Flags known after pass 1: saturated, low amplitude, non-finite.
    status: [[u32; LANES]; BLOCK_STEPS],
}

/// The whole frame in blocks of [`BLOCK_STEPS`] steps of [`LANES`] pixels, two passes per block:
/// pass 1 (validity, offset, amplitude, phase, table position) and pass 2 (table lookup,
/// corrections, wrap, depth, flags). Each pass is a short loop whose iterations are independent,
/// so the core overlaps several of them (one fused pass is a single long dependency chain —
/// division, polynomial, gather — and runs at its latency). The last `n % LANES` pixels go
/// through the same steps on padded copies, so every pixel is computed by the same instructions.
#[inline(always)]
fn kernel<S: Simd, T: RawSample, const FOUR: bool, const FPPN: bool>(
    s: S,
    raw: [&[T]; 4],
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
) {
    let n = n
        .min(raw[0].len())
        .min(raw[1].len())
        .min(t.dark.len())
        .min(out.phase.len())
        .min(out.amp.len())
        .min(out.depth_m.len())
        .min(out.depth_mm.len())
        .min(out.flags.len());
    let n = if FOUR {
        n.min(raw[2].len()).min(raw[3].len())
    } else {
        n
    };
    let fppn = t.fppn.unwrap_or(t.dark);
    let n = n.min(fppn.len());
    // Unused inputs (images 2, 3 in 2-phase; FPPN without a map) alias used ones: never read.
    let (r2, r3) = if FOUR {
        (raw[2], raw[3])
    } else {
        (raw[0], raw[1])
    };
    let (r0, r0t) = raw[0][..n].as_chunks::<LANES>();
    let (r1, r1t) = raw[1][..n].as_chunks::<LANES>();
    let (r2, r2t) = r2[..n].as_chunks::<LANES>();
    let (r3, r3t) = r3[..n].as_chunks::<LANES>();
    let (dk, dkt) = t.dark[..n].as_chunks::<LANES>();
    let (fp, fpt) = fppn[..n].as_chunks::<LANES>();
    let (ph, pht) = out.phase[..n].as_chunks_mut::<LANES>();
    let (am, amt) = out.amp[..n].as_chunks_mut::<LANES>();
    let (dm, dmt) = out.depth_m[..n].as_chunks_mut::<LANES>();
    let (mm, mmt) = out.depth_mm[..n].as_chunks_mut::<LANES>();
    let (fl, flt) = out.flags[..n].as_chunks_mut::<LANES>();
    let mut sc = Scratch {
        idx: [[0; LANES]; BLOCK_STEPS],
        fr: [[0.0; LANES]; BLOCK_STEPS],
        status: [[0; LANES]; BLOCK_STEPS],
    };
    let b = BLOCK_STEPS;
    let ins = r0
        .chunks(b)
        .zip(r1.chunks(b))
        .zip(r2.chunks(b))
        .zip(r3.chunks(b));
    let ins = ins
        .zip(dk.chunks(b))
        .zip(fp.chunks(b))
        .zip(am.chunks_mut(b));
    let outs = ph.chunks_mut(b).zip(dm.chunks_mut(b)).zip(mm.chunks_mut(b));
    for (((((((r0, r1), r2), r3), dk), fp), am), ((ph, dm), mm), fl) in ins
        .zip(outs)
        .zip(fl.chunks_mut(b))
        .map(|((i, o), f)| (i, o, f))
    {
        // Pass 1.
        let pass1 = r0.iter().zip(r1).zip(r2).zip(r3).zip(dk).zip(am);
        let scr = sc.idx.iter_mut().zip(&mut sc.fr).zip(&mut sc.status);
        for ((((((a0, a1), a2), a3), dk), am), ((idx, fr), st)) in pass1.zip(scr) {
            front::<S, T, FOUR>(s, [a0, a1, a2, a3], dk, p, am, idx, fr, st);
        }
        // Pass 2.
        let scr = sc.idx.iter().zip(&sc.fr).zip(&sc.status);
        let pass2 = fp
            .iter()
            .zip(ph.iter_mut())
            .zip(dm.iter_mut())
            .zip(mm.iter_mut());
        for (((((fp, ph), dm), mm), fl), ((idx, fr), st)) in pass2.zip(fl.iter_mut()).zip(scr) {
            back::<S, FPPN>(
                s,
                idx,
                fr,
                st,
                fp,
                p,
                t.lut,
                T::ALWAYS_FINITE,
                [ph, dm],
                mm,
                fl,
            );
        }
    }
    // The tail: padded with the first tail sample (any value: the padding lanes are dropped).
    let Some(&fill) = r0t.first() else {
        return;
    };
    let raw_pad = [r0t, r1t, r2t, r3t].map(|s| pad(s, fill));
    let (dk_pad, fp_pad) = (pad(dkt, 0.0), pad(fpt, 0.0));
    let (mut ph, mut am, mut dm) = ([0f32; LANES], [0f32; LANES], [0f32; LANES]);
    let (mut mm, mut fl) = ([0u16; LANES], [0u8; LANES]);
    let r = [&raw_pad[0], &raw_pad[1], &raw_pad[2], &raw_pad[3]];
    let (idx, fr, st) = (&mut sc.idx[0], &mut sc.fr[0], &mut sc.status[0]);
    front::<S, T, FOUR>(s, r, &dk_pad, p, &mut am, idx, fr, st);
    let fin = T::ALWAYS_FINITE;
    back::<S, FPPN>(
        s,
        idx,
        fr,
        st,
        &fp_pad,
        p,
        t.lut,
        fin,
        [&mut ph, &mut dm],
        &mut mm,
        &mut fl,
    );
    unpad(pht, &ph);
    unpad(amt, &am);
    unpad(dmt, &dm);
    unpad(mmt, &mm);
    unpad(flt, &fl);
}

/// The first `s.len() ≤ LANES` lanes from `s`, the rest `fill`.
#[inline(always)]
fn pad<X: Copy>(s: &[X], fill: X) -> [X; LANES] {
    let mut a = [fill; LANES];
    for (d, v) in a.iter_mut().zip(s) {
        *d = *v;
    }
    a
}

/// Copies the first `d.len() ≤ LANES` lanes back.
#[inline(always)]
fn unpad<X: Copy>(d: &mut [X], s: &[X; LANES]) {
    for (d, v) in d.iter_mut().zip(s) {
        *d = *v;
    }
}

/// Pass 1 on [`LANES`] pixels: raw validity, offset correction, amplitude (final output) and
/// phase-table position. Compares and selects only, no branches; `raw[2..4]` are read only when
/// `FOUR`.
#[allow(clippy::too_many_arguments)] // the step's inputs and outputs, each one array
#[inline(always)]
fn front<S: Simd, T: RawSample, const FOUR: bool>(
    s: S,
    raw: [&[T; LANES]; 4],
    dark: &[f32; LANES],
    p: &KernelParams,
    amp_out: &mut [f32; LANES],
    idx_out: &mut [u32; LANES],
    fr_out: &mut [f32; LANES],
    status_out: &mut [u32; LANES],
) {
    let a0 = T::load_lanes(s, raw[0]);
    let a1 = T::load_lanes(s, raw[1]);
    // Saturation on the RAW codes: any used image at a rail (≤ 0 or ≥ 2^bits − 1).
    let (mut lo, mut hi) = (s.min(a0, a1), s.max(a0, a1));
    let (x, y, amp);
    if FOUR {
        let a2 = T::load_lanes(s, raw[2]);
        let a3 = T::load_lanes(s, raw[3]);
        lo = s.min(lo, s.min(a2, a3));
        hi = s.max(hi, s.max(a2, a3));
        // eq. 2.3: the per-pixel offset cancels in the differences.
        x = s.sub(a0, a2);
        y = s.sub(a1, a3);
        let norm = s.sqrt(s.add(s.mul(x, x), s.mul(y, y)));
        amp = s.mul(s.splat(0.5), norm); // eq. 2.4
    } else {
        // Offset correction (4.3.3.1), then eq. 2.2.
        let d = s.load(dark);
        x = s.sub(a0, d);
        y = s.sub(a1, d);
        amp = s.sqrt(s.add(s.mul(x, x), s.mul(y, y))); // |z|, the 2-phase form of eq. 2.4
    }
    let sat = s.or(s.le(lo, s.splat(0.0)), s.le(s.splat(p.rail_hi), hi));
    let low = s.lt(amp, s.splat(p.min_amp));
    let mut status = s.or_int(
        s.bits(sat, FLAG_SATURATED.into()),
        s.bits(low, FLAG_LOW_AMPLITUDE.into()),
    );
    if T::ALWAYS_FINITE {
        s.store(amp, amp_out);
    } else {
        // Non-finite raw values (or an offset-corrected value beyond f32) make x or y non-finite.
        let finite = s.and(s.is_finite(x), s.is_finite(y));
        status = s.or_int(status, s.bits(s.not(finite), FLAG_NON_FINITE.into()));
        s.store(s.select(finite, amp, s.splat(0.0)), amp_out);
    }
    s.store_int(status, status_out);
    // The signs place the images' canonical shifts (`Quadrature`): multiplying by ±1 is exact,
    // so every level still agrees to the bit.
    let (x, y) = (s.mul(x, s.splat(p.x_sign)), s.mul(y, s.splat(p.y_sign)));
    // Phase-table position (module docs): octant bits and t = min/max of |x|, |y| in [0, 1].
    let (ax, ay) = (s.abs(x), s.abs(y));
    // max == 0 only at the origin; divide by a tiny positive instead (gives t = 0).
    let t = s.div(
        s.min(ax, ay),
        s.max(s.max(ax, ay), s.splat(f32::MIN_POSITIVE)),
    );
    let zero = s.splat(0.0);
    let octant = s.or_int(
        s.or_int(
            s.bits(s.lt(ax, ay), OCTANT_SWAP),
            s.bits(s.lt(x, zero), OCTANT_NEG_X),
        ),
        s.bits(s.lt(y, zero), OCTANT_NEG_Y),
    );
    // Bin and fraction: `tf − 0.5` rounded is floor(tf) (a tie gives k − 1 with fr = 1: the same
    // interpolated value); tf = 512 (t = 1) is bin 511 with fr = 1. A NaN t gives an index the
    // lookup masks into range.
    let tf = s.mul(t, s.splat(LUT_T_BINS as f32)); // exact: a power of two
    let top = s.min(tf, s.splat(LUT_T_BINS as f32 - 0.5));
    let k = s.round_low22(s.sub(top, s.splat(0.5)));
    s.store_int(s.or_int(k, octant), idx_out);
    s.store(s.sub(tf, s.int_to_f32(k)), fr_out);
}

/// Pass 2 on [`LANES`] pixels: corrected phase from the phase table (linear interpolation), FPPN,
/// wrap, depth, flags. `fppn` is read only when `FPPN`; `finite` says pass 1 saw only finite
/// values (`u16` input), so the non-finite selects are skipped.
#[allow(clippy::too_many_arguments)] // the step's inputs and outputs, each one array
#[inline(always)]
fn back<S: Simd, const FPPN: bool>(
    s: S,
    idx: &[u32; LANES],
    fr: &[f32; LANES],
    status: &[u32; LANES],
    fppn: &[f32; LANES],
    p: &KernelParams,
    lut: &Lut,
    finite: bool,
    [phase_out, depth_m_out]: [&mut [f32; LANES]; 2],
    depth_mm_out: &mut [u16; LANES],
    flags_out: &mut [u8; LANES],
) {
    // eq. 2.2 / 2.3 with the wiggling correction (3.3.7.2 / 4.3.3.3), by the phase table.
    let (value, slope) = s.lut(lut, idx);
    let mut ph = s.add(value, s.mul(slope, s.load(fr)));
    if FPPN {
        ph = s.sub(ph, s.load(fppn)); // 2.3.1.4
    }
    // Wrap into [0, 2π): value in [0, 2π), |slope · fr| ≤ π, FPPN in (−π, π], so ph is in
    // [−2π, 4π): one step up, then one down (which also folds a sum that rounded up to 2π).
    let zero = s.splat(0.0);
    let tau = s.splat(TAU);
    ph = s.select(s.lt(ph, zero), s.add(ph, tau), ph);
    ph = s.select(s.le(tau, ph), s.sub(ph, tau), ph);

    let d = s.mul(ph, s.splat(p.rad_to_m)); // eq. 2.6
    let d_mm = s.mul(d, s.splat(1000.0));
    let in_range = s.lt(d_mm, s.splat(65_535.5)); // false for NaN
    let status = s.load_int(status);
    let ok = s.and(s.int_is_zero(status), in_range);
    let flags = s.or_int(status, s.bits(s.not(ok), FLAG_INVALID.into()));
    s.store_flags(flags, flags_out);
    // round(d · 1000) by the mantissa trick; ≥ 1 mm when valid.
    s.store_mm(s.round_low22(d_mm), ok, depth_mm_out);
    s.store(s.select(ok, d, zero), depth_m_out);
    if finite {
        s.store(ph, phase_out);
    } else {
        let finite = s.not(s.has_bit(status, FLAG_NON_FINITE.into()));
        s.store(s.select(finite, ph, zero), phase_out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array2, Array3, ShapeBuilder};

    fn synth(phi: f64, amp: f64, rows: usize, cols: usize, phases: &[f64]) -> Array3<f64> {
        tofprox_testkit::frames::ideal_codes(phi, amp, 2048.0, (rows, cols), phases)
    }

    /// Every phase convention: a capture recorded as `[0°, 90°(, 180°, 270°)]` by a sensor with
    /// that convention has other canonical shifts; relabelled and evaluated with their
    /// quadrature it gives the canonical depth — on every SIMD level.
    #[test]
    fn every_phase_convention_gives_the_same_depth() {
        use crate::phasor::{PhaseConvention, ShiftedSignal};
        for algo in Algorithm::ALL {
            for shifted in [ShiftedSignal::Demodulation, ShiftedSignal::Illumination] {
                for sign in [1, -1] {
                    let conv = PhaseConvention { shifted, sign };
                    let canonical: Vec<f64> = algo
                        .phases_deg()
                        .iter()
                        .map(|&l| conv.canonical_deg(l))
                        .collect();
                    let q = Quadrature::of_canonical(&canonical, algo).unwrap();
                    assert_eq!(
                        q == Quadrature::STANDARD,
                        conv.is_canonical(),
                        "{conv:?} -> {q:?}"
                    );
                    let cfg = PipelineConfig {
                        algorithm: algo,
                        ..Default::default()
                    };
                    let mut p = Pipeline::new(2, 9, cfg, Calibration::default()).unwrap();
                    p.set_quadrature(q);
                    for d in [0.07, 0.5, 0.93, 1.5, 1.8] {
                        let phi = phasor::distance_to_phase_rad(d, 80e6);
                        // the sensor's images: u_k = A·cos(φ − θ_c(label_k))
                        let raw = synth(phi, 800.0, 2, 9, &canonical);
                        for level in SimdLevel::ALL.iter().filter(|l| l.is_supported()) {
                            p.set_simd_level(*level).unwrap();
                            let f = p.process(raw.view()).unwrap();
                            for &dm in f.depth_m.iter() {
                                assert!(
                                    (dm as f64 - d).abs() < 2e-4,
                                    "{algo} {conv:?}: {dm} vs {d}"
                                );
                            }
                        }
                        // without the quadrature the depth is wrong (the test can fail)
                        if !conv.is_canonical() && (d == 0.5 || d == 1.5) {
                            let mut plain =
                                Pipeline::new(2, 9, cfg, Calibration::default()).unwrap();
                            let f = plain.process(raw.view()).unwrap();
                            assert!((f.depth_m[(0, 0)] as f64 - d).abs() > 0.05, "{conv:?}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn phase_convention_labels_round_trip() {
        use crate::phasor::{PhaseConvention, ShiftedSignal};
        for shifted in [ShiftedSignal::Demodulation, ShiftedSignal::Illumination] {
            for sign in [1, -1] {
                let c = PhaseConvention { shifted, sign };
                for l in [0.0, 15.0, 90.0, 180.0, 270.0, 345.0] {
                    let back = c.label_deg(c.canonical_deg(l));
                    assert!((back - l).abs() < 1e-9, "{c:?} {l} {back}");
                }
            }
        }
        let ill = PhaseConvention {
            shifted: ShiftedSignal::Illumination,
            sign: 1,
        };
        assert_eq!(ill.canonical_deg(90.0), 270.0);
        assert!(
            PhaseConvention {
                shifted: ShiftedSignal::Demodulation,
                sign: 0
            }
            .validate()
            .is_err()
        );
        assert_eq!(
            Quadrature::of_canonical(&[0.0, 45.0], Algorithm::TwoPhase),
            None
        );
        assert_eq!(
            Quadrature::of_canonical(&[0.0, 90.0, 270.0, 180.0], Algorithm::FourPhase),
            None
        );
        // real-world float shifts: π/2 stored as f32 radians is 90.0000025°, a −0° is 359.99…°
        let f32_quarter_deg = f64::from(std::f32::consts::FRAC_PI_2).to_degrees();
        assert!((f32_quarter_deg - 90.0).abs() > 1e-6);
        assert_eq!(
            Quadrature::of_canonical(&[360.0 - 1e-9, f32_quarter_deg], Algorithm::TwoPhase),
            Some(Quadrature::STANDARD)
        );
        // one register step (360°/4096) off is another shift, not the nominal one
        assert_eq!(
            Quadrature::of_canonical(&[0.0, 90.0 + 360.0 / 4096.0], Algorithm::TwoPhase),
            None
        );
    }

    #[test]
    fn ideal_2phase_and_4phase_depth() {
        for algo in Algorithm::ALL {
            let cfg = PipelineConfig {
                algorithm: algo,
                ..Default::default()
            };
            let mut p = Pipeline::new(3, 5, cfg, Calibration::default()).unwrap();
            for d in [0.1, 0.5, 0.93, 1.5, 1.8] {
                let phi = phasor::distance_to_phase_rad(d, 80e6);
                let raw = synth(phi, 800.0, 3, 5, algo.phases_deg());
                let f = p.process(raw.view()).unwrap();
                for (&dm, &fl) in f.depth_m.iter().zip(f.flags.iter()) {
                    assert_eq!(fl, 0);
                    assert!((dm as f64 - d).abs() < 2e-4, "{algo}: {dm} vs {d}");
                }
                let mm = f.depth_mm[(1, 2)] as f64;
                assert!((mm - d * 1000.0).abs() <= 1.0);
                assert!((f.amplitude_lsb[(0, 0)] as f64 - 800.0).abs() < 0.5);
                // the scalar rounding is the kernel's, pixel for pixel
                assert_eq!(f.depth_m.mapv(depth_m_to_mm), f.depth_mm);
                assert_eq!(
                    median_valid_m(f.depth_m.view(), f.flags.view()),
                    f.median_valid_depth_m()
                );
            }
        }
        assert_eq!(depth_m_to_mm(0.0), 0);
        assert_eq!(depth_m_to_mm(f32::NAN), 0);
        assert_eq!(depth_m_to_mm(1e-5), 1);
        assert_eq!(depth_m_to_mm(65.6), 0);
        assert_eq!(depth_m_to_mm(0.0125), 12, "ties to even, as the kernel");
    }

    #[test]
    fn u16_f32_f64_and_noncontiguous_agree() {
        let cfg = PipelineConfig::default();
        let mut p = Pipeline::new(4, 6, cfg, Calibration::default()).unwrap();
        let phi = 2.2;
        let raw = synth(phi, 700.0, 4, 6, &[0.0, 90.0]).mapv(|v| v.round());
        let a = p.process(raw.view()).unwrap().clone();
        let b = p.process(raw.mapv(|v| v as u16).view()).unwrap().clone();
        let c = p.process(raw.mapv(|v| v as f32).view()).unwrap().clone();
        assert_eq!(a, b);
        assert_eq!(a, c);
        // Fortran-order (non-contiguous per image) input goes through the staging path.
        let mut f = Array3::<f64>::zeros((2, 4, 6).f());
        f.assign(&raw);
        let d = p.process(f.view()).unwrap().clone();
        assert_eq!(a, d);
    }

    #[test]
    fn all_simd_levels_agree_to_the_bit() {
        // Odd sizes exercise the vector tail; phases over the whole circle, saturated and
        // low-amplitude pixels, an FPPN map and a wiggling table.
        let (rows, cols) = (13, 37);
        let lut = WigglingLut {
            algorithm: Algorithm::TwoPhase,
            correction_rad: ndarray::Array1::from_shape_fn(360, |i| {
                0.4 + 0.05 * (i as f32 * 0.05).sin()
            }),
        };
        let fppn = FppnMap {
            phase_offset_rad: Array2::from_shape_fn((rows, cols), |(r, c)| {
                0.3 * ((r * 7 + c) % 5) as f32 - 0.6
            }),
        };
        let raw = Array3::from_shape_fn((4, rows, cols), |(k, r, c)| {
            let i = r * cols + c;
            let phi = i as f64 * 0.013;
            let amp = if i % 17 == 3 { 3.0 } else { 900.0 };
            let v = 2048.0 + amp * (phi - k as f64 * std::f64::consts::FRAC_PI_2).cos();
            if i % 23 == 5 { 4095 } else { v.round() as u16 }
        });
        for (algorithm, with_fppn) in [(Algorithm::TwoPhase, false), (Algorithm::FourPhase, true)] {
            let cal = Calibration {
                wiggling: Some(WigglingLut {
                    algorithm,
                    ..lut.clone()
                }),
                fppn: with_fppn.then(|| fppn.clone()),
                ..Default::default()
            };
            let cfg = PipelineConfig {
                algorithm,
                ..Default::default()
            };
            let mut p = Pipeline::new(rows, cols, cfg, cal).unwrap();
            p.set_simd_level(SimdLevel::Generic).unwrap();
            let reference = p.process(raw.view()).unwrap().clone();
            let reference_f64 = p.process(raw.mapv(f64::from).view()).unwrap().clone();
            assert_eq!(reference, reference_f64);
            assert!(reference.flags.iter().any(|&f| f == 0));
            assert!(reference.flags.iter().any(|&f| f & FLAG_SATURATED != 0));
            for level in SimdLevel::supported() {
                p.set_simd_level(level).unwrap();
                assert_eq!(p.simd_level(), level);
                let f = p.process(raw.view()).unwrap();
                assert_eq!(*f, reference, "{algorithm} {level}");
                let f = p.process(raw.mapv(f64::from).view()).unwrap();
                assert_eq!(*f, reference, "{algorithm} {level} f64");
            }
        }
        for level in SimdLevel::ALL {
            let mut p =
                Pipeline::new(1, 1, PipelineConfig::default(), Calibration::default()).unwrap();
            assert_eq!(p.set_simd_level(level).is_ok(), level.is_supported());
        }
        assert!("sse9".parse::<SimdLevel>().is_err());
        assert_eq!("avx2".parse::<SimdLevel>().ok(), Some(SimdLevel::Avx2));
    }

    #[test]
    fn phase_table_matches_f64_atan2() {
        // Without calibration the table is atan2 alone: dense phases over the whole circle, both
        // algorithms, radii from the low-amplitude limit to full scale, against f64 atan2 of the
        // same f32 offset-corrected values (module docs: interpolation 3.1e-7 rad, f32 rounding
        // of the table values and of t ≈ 5e-7 rad).
        let n = 4099;
        for algo in Algorithm::ALL {
            let cfg = PipelineConfig {
                algorithm: algo,
                min_amplitude_lsb: 0.0,
                ..Default::default()
            };
            let mut p = Pipeline::new(1, n, cfg, Calibration::default()).unwrap();
            let mut worst = 0.0f64;
            for amp in [12.0, 300.0, 2000.0] {
                let raw = Array3::from_shape_fn((algo.raw_images(), 1, n), |(k, _, c)| {
                    let phi = std::f64::consts::TAU * c as f64 / n as f64 + 1e-3;
                    let v = 2048.0 + amp * (phi - k as f64 * std::f64::consts::FRAC_PI_2).cos();
                    f64::from(v as f32)
                });
                let f = p.process(raw.view()).unwrap();
                for c in 0..n {
                    let u = |k: usize| raw[(k, 0, c)] as f32;
                    let (x, y) = if algo == Algorithm::FourPhase {
                        (u(0) - u(2), u(1) - u(3))
                    } else {
                        (u(0) - 2048.0, u(1) - 2048.0)
                    };
                    let want = phasor::wrap_phase(f64::from(y).atan2(f64::from(x)));
                    let got = f64::from(f.phase_rad[(0, c)]);
                    assert!((0.0..std::f64::consts::TAU).contains(&got), "{got}");
                    worst = worst.max(wrap_to_pi(got - want).abs());
                }
            }
            assert!(worst < 2e-6, "{algo}: worst {worst} rad");
        }
    }

    #[test]
    fn lut_resampling_matches_linear_periodic_interpolation() {
        // A 360-bin table (not a power of two) with a steep feature and a 2π-wrapped stretch:
        // the kernel's 4096-bin value+slope table must reproduce WigglingLut::correct.
        let lut = WigglingLut {
            algorithm: Algorithm::TwoPhase,
            correction_rad: ndarray::Array1::from_shape_fn(360, |i| {
                let x = i as f32 * std::f32::consts::TAU / 360.0;
                let v = 3.0
                    + 0.2 * (3.0 * x).sin()
                    + if (100..110).contains(&i) {
                        0.05 * (i - 100) as f32
                    } else {
                        0.0
                    };
                wrap_to_pi(v as f64) as f32
            }),
        };
        let cal = Calibration {
            wiggling: Some(lut.clone()),
            ..Default::default()
        };
        let cfg = PipelineConfig {
            min_amplitude_lsb: 0.0,
            ..Default::default()
        };
        let n = 1000;
        let mut p = Pipeline::new(1, n, cfg, cal).unwrap();
        let raw = Array3::from_shape_fn((2, 1, n), |(k, _, c)| {
            let phi = std::f64::consts::TAU * c as f64 / n as f64;
            2048.0 + 1500.0 * (phi - k as f64 * std::f64::consts::FRAC_PI_2).cos()
        });
        let f = p.process(raw.view()).unwrap();
        let mut worst = 0.0f64;
        for c in 0..n {
            let m = phasor::phase_2phase(raw[(0, 0, c)] - 2048.0, raw[(1, 0, c)] - 2048.0);
            let want = lut.correct(m);
            let d = wrap_to_pi(f.phase_rad[(0, c)] as f64 - want).abs();
            worst = worst.max(d);
        }
        // fast atan2 (1e-4) + f32 + resampling of a piecewise-linear table at 4096 bins.
        assert!(worst < 2e-4, "worst deviation {worst} rad");
    }

    #[test]
    fn validity_flags() {
        let cfg = PipelineConfig {
            min_amplitude_lsb: 50.0,
            ..Default::default()
        };
        let mut p = Pipeline::new(1, 5, cfg, Calibration::default()).unwrap();
        let mut raw = Array3::<f64>::from_elem((2, 1, 5), 2048.0 + 300.0);
        raw[(0, 0, 0)] = 4095.0; // saturated high
        raw[(1, 0, 1)] = 0.0; // saturated low
        raw[(0, 0, 2)] = f64::NAN;
        raw[(0, 0, 3)] = 2048.0; // low amplitude
        raw[(1, 0, 3)] = 2050.0;
        let f = p.process(raw.view()).unwrap();
        assert_eq!(f.flags[(0, 0)], FLAG_SATURATED | FLAG_INVALID);
        assert_eq!(f.flags[(0, 1)], FLAG_SATURATED | FLAG_INVALID);
        assert_ne!(f.flags[(0, 2)] & (FLAG_NON_FINITE | FLAG_INVALID), 0);
        assert_eq!(f.flags[(0, 3)], FLAG_LOW_AMPLITUDE | FLAG_INVALID);
        assert_eq!(f.flags[(0, 4)], 0);
        for i in 0..4 {
            assert_eq!(f.depth_mm[(0, i)], 0);
            assert_eq!(f.depth_m[(0, i)], 0.0);
        }
        assert!(f.depth_m.iter().all(|v| v.is_finite()));
        assert!(f.depth_mm[(0, 4)] > 0);
    }

    #[test]
    fn shape_errors_not_panics() {
        let cfg = PipelineConfig {
            algorithm: Algorithm::FourPhase,
            ..Default::default()
        };
        let mut p = Pipeline::new(2, 2, cfg, Calibration::default()).unwrap();
        assert!(matches!(
            p.process(Array3::<u16>::zeros((2, 2, 2)).view()),
            Err(CoreError::ShapeMismatch { .. })
        ));
        assert!(p.process(Array3::<u16>::zeros((4, 3, 2)).view()).is_err());
        assert!(p.process(Array3::<u16>::zeros((0, 0, 0)).view()).is_err());
        let bad = Calibration {
            offset: Some(OffsetCalibration {
                dark_lsb: Array2::zeros((3, 3)),
            }),
            ..Default::default()
        };
        assert!(Pipeline::new(2, 2, cfg, bad).is_err());
        assert!(Pipeline::new(0, 2, cfg, Calibration::default()).is_err());
        assert!(Pipeline::new(usize::MAX, 2, cfg, Calibration::default()).is_err());
        assert!(Pipeline::new(1 << 14, 1 << 13, cfg, Calibration::default()).is_err());
        let bad_cfg = PipelineConfig {
            modulation_hz: f64::NAN,
            ..cfg
        };
        assert!(Pipeline::new(2, 2, bad_cfg, Calibration::default()).is_err());
        let wrong_algo = Calibration {
            wiggling: Some(WigglingLut {
                algorithm: Algorithm::TwoPhase,
                correction_rad: ndarray::Array1::zeros(16),
            }),
            ..Default::default()
        };
        assert!(Pipeline::new(2, 2, cfg, wrong_algo).is_err());
    }
}
