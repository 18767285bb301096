//! Per-frame processing: raw phase images → calibrated depth (thesis 4.3.3, fig. 3.20).
//!
//! In this order per pixel:
//! 1. validity of the RAW codes: saturation (any used image at a rail: `≤ 0` or `≥ 2^bits − 1`),
//!    non-finite input;
//! 2. offset correction (4.3.3.1): `u_k = code_k − dark[p]` (per-pixel dark frame, or the mid code
//!    `2^(bits−1)` when no dark frame is given); with a crosstalk calibration also
//!    `− X_k[p] · t_exp` (the cover window's return, [`crate::crosstalk`]), applied while the raw
//!    images are staged as `f32` (codes at a rail stay there), so the kernels are unchanged;
//! 3. phase: eq. 2.2 (2-phase, images 0°, 90°) or eq. 2.3 (4-phase, 0°, 90°, 180°, 270°), with a
//!    branch-free polynomial `atan2` ([`crate::fast_atan2_f32`], error ≤ 1e-4 rad ≈ 0.03 mm);
//! 4. wiggling correction (3.3.7.2 / 4.3.3.3): `phase − LUT(phase)`, linear periodic interpolation
//!    (the table is resampled once to 4096 bins of value + slope; exact for power-of-two tables up to
//!    4096 bins);
//! 5. FPPN (2.3.1.4): `− fppn[p]`, then wrap into `[0, 2π)`;
//! 6. amplitude (eq. 2.4 or its 2-phase form `|z|`), low-amplitude check;
//! 7. depth (eq. 2.6) in metres and `u16` millimetres (0 = invalid; a valid depth that would round
//!    to 0 mm is reported as 1 mm; beyond 65535 mm → invalid).
//!
//! Invalid pixels have `depth_m = 0`, `depth_mm = 0` — never NaN. Buffers are allocated in
//! [`Pipeline::new`]; [`Pipeline::process`] does not allocate.
//!
//! # Speed
//! The frame is processed in chunks of 256 pixels, three passes per chunk (all data of a chunk
//! stays in L1): A — validity, offset, amplitude, phase, LUT index (branch-free, auto-vectorised);
//! B — LUT gather (value and slope packed in one `u64` per bin: one 64-bit gather per pixel);
//! C — corrections, wrap, depth, flags (auto-vectorised). The kernel is compiled three times and
//! chosen at run time: AVX-512 (LLVM vectorises the gather), AVX2+FMA (explicit `vpgatherdq`),
//! and portable scalar-gather code; [`Pipeline::set_simd_level`] forces a lower level and a test
//! checks all levels agree. Float→integer conversions use the 1.5·2^23 mantissa trick instead of
//! `as` (saturating casts do not vectorise). No threads: one core per frame
//! (`cargo bench -p tofprox-core --bench pipeline`).

use crate::calib::{FppnMap, OffsetCalibration, WigglingLut, check_offset};
use crate::crosstalk::CrosstalkCalibration;
use crate::fastmath::atan2_poly;
use crate::phasor::{self, wrap_to_pi};
use crate::{Algorithm, CoreError};
use ndarray::{Array2, ArrayView3, Axis};
use std::f32::consts::TAU;

/// Flag bit: at least one used raw image of the pixel is at a rail (0 or `2^bits − 1`).
pub const FLAG_SATURATED: u8 = 1 << 0;
/// Flag bit: amplitude below [`PipelineConfig::min_amplitude_lsb`].
pub const FLAG_LOW_AMPLITUDE: u8 = 1 << 1;
/// Flag bit: depth invalid (set whenever any other flag is set, or the depth is out of range).
pub const FLAG_INVALID: u8 = 1 << 2;
/// Flag bit: a used raw value is NaN or infinite.
pub const FLAG_NON_FINITE: u8 = 1 << 3;

/// Largest frame a pipeline accepts (64 Mpixel; the IRS1645 has 38 528 pixels).
pub const MAX_PIXELS: usize = 1 << 26;

/// Size of the internal wiggling table (power of two so the index is a mask, no bounds checks).
const LUT_BINS: usize = 4096;

/// 1.5 · 2^23: `(x + ROUND_MAGIC).to_bits() & 0x3F_FFFF` is `round(x)` for `0 ≤ x < 2^22`.
const ROUND_MAGIC: f32 = 12_582_912.0;

/// A raw sample type the pipeline accepts: `u16` codes, or `f32`/`f64` averaged codes.
pub trait RawSample: Copy + Send + Sync + 'static {
    /// The value as `f32` (exact for `u16`; NaN/∞ propagate and are flagged).
    fn to_f32(self) -> f32;
}

impl RawSample for u16 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
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

/// Output of one [`Pipeline::process`] call, all arrays `(rows, cols)`.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthFrame {
    /// Depth in metres (eq. 2.6); 0 where invalid, never NaN.
    pub depth_m: Array2<f32>,
    /// Depth in millimetres; 0 = invalid.
    pub depth_mm: Array2<u16>,
    /// Amplitude in LSB (eq. 2.4 / `|z|`); 0 where the input was non-finite.
    pub amplitude_lsb: Array2<f32>,
    /// Corrected phase in `[0, 2π)`; 0 where the input was non-finite.
    pub phase_rad: Array2<f32>,
    /// Per-pixel flags: [`FLAG_SATURATED`], [`FLAG_LOW_AMPLITUDE`], [`FLAG_INVALID`], [`FLAG_NON_FINITE`].
    pub flags: Array2<u8>,
}

impl DepthFrame {
    /// A zeroed frame (every pixel `depth_mm = 0`, flags 0).
    pub fn zeros(rows: usize, cols: usize) -> Self {
        DepthFrame {
            depth_m: Array2::zeros((rows, cols)),
            depth_mm: Array2::zeros((rows, cols)),
            amplitude_lsb: Array2::zeros((rows, cols)),
            phase_rad: Array2::zeros((rows, cols)),
            flags: Array2::zeros((rows, cols)),
        }
    }

    /// `(rows, cols)`.
    pub fn dim(&self) -> (usize, usize) {
        self.depth_mm.dim()
    }

    /// Whether pixel `(row, col)` has a valid depth (`false` outside the frame).
    pub fn is_valid(&self, row: usize, col: usize) -> bool {
        self.flags
            .get((row, col))
            .is_some_and(|f| f & FLAG_INVALID == 0)
    }

    /// Fraction of pixels with valid depth (0 for an empty frame).
    pub fn valid_fraction(&self) -> f32 {
        let n = self.flags.len();
        if n == 0 {
            return 0.0;
        }
        self.flags
            .iter()
            .filter(|&&f| f & FLAG_INVALID == 0)
            .count() as f32
            / n as f32
    }

    /// Median of valid `depth_m` (metres) over the whole frame, `None` if nothing is valid.
    /// Allocates (not for the hot path).
    pub fn median_valid_depth_m(&self) -> Option<f64> {
        let mut v: Vec<f32> = self
            .depth_m
            .iter()
            .zip(self.flags.iter())
            .filter(|(_, f)| **f & FLAG_INVALID == 0)
            .map(|(d, _)| *d)
            .collect();
        if v.is_empty() {
            return None;
        }
        v.sort_unstable_by(f32::total_cmp);
        let n = v.len();
        let m = if n % 2 == 1 {
            v[n / 2] as f64
        } else {
            0.5 * (v[n / 2 - 1] as f64 + v[n / 2] as f64)
        };
        Some(m)
    }
}

/// Constants of the per-pixel kernel.
#[derive(Debug, Clone, Copy)]
struct KernelParams {
    rail_hi: f32,
    min_amp: f32,
    lut_scale: f32,
    rad_to_m: f32,
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
    /// Wiggling table: per bin `value | slope << 32` (f32 bits), so one 64-bit gather fetches both.
    lut: Box<[u64; LUT_BINS]>,
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
    simd: SimdLevel,
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
            lut_scale: LUT_BINS as f32 / TAU,
            rad_to_m: (phasor::unambiguous_range_m(config.modulation_hz) / std::f64::consts::TAU)
                as f32,
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
            simd: detect_simd(),
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
        let mut lut = Box::new([0u64; LUT_BINS]);
        if let Some(w) = &calibration.wiggling {
            if w.algorithm != self.config.algorithm {
                return Err(CoreError::Calibration(format!(
                    "wiggling LUT is for {} but the pipeline runs {}",
                    w.algorithm, self.config.algorithm
                )));
            }
            w.validate()?;
            let step = std::f64::consts::TAU / LUT_BINS as f64;
            let vals: Vec<f64> = (0..LUT_BINS)
                .map(|j| w.correction_at(j as f64 * step))
                .collect();
            for j in 0..LUT_BINS {
                let v = vals[j];
                let next = vals[(j + 1) % LUT_BINS];
                lut[j] = pack_lut(wrap_to_pi(v) as f32, wrap_to_pi(next - v) as f32);
            }
        }
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
        self.crosstalk_scale = scale;
        self.rescale_crosstalk();
        Ok(())
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
        match self.simd {
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => {
                // SAFETY: `Avx512` is only selected when the CPU reports these features at runtime.
                #[allow(unsafe_code)]
                unsafe {
                    kernel_avx512(raw, four, n, &p, &tabs, out)
                }
            }
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx2 => {
                // SAFETY: `Avx2` is only selected when the CPU reports AVX2 and FMA at runtime.
                #[allow(unsafe_code)]
                unsafe {
                    kernel_avx2(raw, four, n, &p, &tabs, out)
                }
            }
            _ => kernel_dispatch::<T, false>(raw, four, n, &p, &tabs, out, gather_scalar),
        }
    }

    /// Selects the kernel's instruction set ("generic", "avx2", "avx512"), e.g. to benchmark or
    /// test the portable paths on a machine with AVX-512. Only levels this CPU supports are
    /// accepted; results agree across levels within the fast-atan2 tolerance.
    pub fn set_simd_level(&mut self, level: &str) -> Result<(), CoreError> {
        let best = detect_simd();
        let wanted = match level {
            "generic" => SimdLevel::Generic,
            "avx2" => SimdLevel::Avx2,
            "avx512" => SimdLevel::Avx512,
            other => {
                return Err(CoreError::param(
                    "simd_level",
                    format!("unknown level {other:?}"),
                ));
            }
        };
        let rank = |l: SimdLevel| match l {
            SimdLevel::Generic => 0,
            SimdLevel::Avx2 => 1,
            SimdLevel::Avx512 => 2,
        };
        if rank(wanted) > rank(best) {
            return Err(CoreError::param(
                "simd_level",
                format!("{level} is not supported by this CPU"),
            ));
        }
        self.simd = wanted;
        Ok(())
    }

    /// The instruction set the per-pixel kernel runs with on this CPU ("avx512", "avx2" or
    /// "generic"), detected once at construction.
    pub fn simd_level(&self) -> &'static str {
        match self.simd {
            SimdLevel::Avx512 => "avx512",
            SimdLevel::Avx2 => "avx2",
            SimdLevel::Generic => "generic",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SimdLevel {
    Generic,
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    Avx2,
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    Avx512,
}

fn detect_simd() -> SimdLevel {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::is_x86_feature_detected as has;
        if has!("avx512f")
            && has!("avx512bw")
            && has!("avx512vl")
            && has!("avx512dq")
            && has!("avx2")
            && has!("fma")
        {
            return SimdLevel::Avx512;
        }
        if has!("avx2") && has!("fma") {
            return SimdLevel::Avx2;
        }
    }
    SimdLevel::Generic
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
    lut: &'a [u64; LUT_BINS],
}

/// Pixels per chunk: the per-chunk scratch (LUT index, fraction, correction) stays in L1.
const CHUNK: usize = 256;

type GatherFn = fn(&[u32], &[f32], &[u64; LUT_BINS], &mut [f32]);

/// One wiggling-table entry: value in the low 32 bits, slope (per bin) in the high 32 bits.
fn pack_lut(value: f32, slope: f32) -> u64 {
    (value.to_bits() as u64) | ((slope.to_bits() as u64) << 32)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq,avx2,fma")]
fn kernel_avx512<T: RawSample>(
    raw: [&[T]; 4],
    four: bool,
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
) {
    // With AVX-512 LLVM vectorises the gather loop itself.
    kernel_dispatch::<T, true>(raw, four, n, p, t, out, gather_avx512)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq,avx2,fma")]
fn gather_avx512(idx: &[u32], fr: &[f32], lut: &[u64; LUT_BINS], out: &mut [f32]) {
    gather_scalar(idx, fr, lut, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn kernel_avx2<T: RawSample>(
    raw: [&[T]; 4],
    four: bool,
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
) {
    kernel_dispatch::<T, true>(raw, four, n, p, t, out, gather_avx2)
}

/// LUT gather with explicit AVX2 `vpgatherdq` (LLVM's cost model does not vectorise it at AVX2):
/// one 64-bit gather fetches value and slope of 4 pixels; they are de-interleaved by shuffles.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn gather_avx2(idx: &[u32], fr: &[f32], lut: &[u64; LUT_BINS], out: &mut [f32]) {
    use std::arch::x86_64::{
        __m256i, _mm256_and_si256, _mm256_castpd_ps, _mm256_castps_pd, _mm256_castsi256_ps,
        _mm256_castsi256_si128, _mm256_extracti128_si256, _mm256_fmadd_ps, _mm256_i32gather_epi64,
        _mm256_loadu_ps, _mm256_loadu_si256, _mm256_permute4x64_pd, _mm256_set1_epi32,
        _mm256_shuffle_ps, _mm256_storeu_ps,
    };
    let len = idx.len().min(fr.len()).min(out.len());
    let mask = _mm256_set1_epi32((LUT_BINS - 1) as i32);
    let base = lut.as_ptr().cast::<i64>();
    let mut j = 0;
    while j + 8 <= len {
        // SAFETY: j + 8 ≤ len ≤ every slice's length, so the unaligned 8-lane loads/store are in
        // bounds; the gather indices are masked to < LUT_BINS, the length of the table.
        #[allow(unsafe_code)]
        unsafe {
            let vi = _mm256_and_si256(
                _mm256_loadu_si256(idx.as_ptr().add(j).cast::<__m256i>()),
                mask,
            );
            let lo = _mm256_castsi256_si128(vi);
            let hi = _mm256_extracti128_si256::<1>(vi);
            let g0 = _mm256_castsi256_ps(_mm256_i32gather_epi64::<8>(base, lo));
            let g1 = _mm256_castsi256_ps(_mm256_i32gather_epi64::<8>(base, hi));
            // [v0 s0 v1 s1 v2 s2 v3 s3], [v4 s4 …] → [v0 v1 v4 v5 v2 v3 v6 v7] → in order.
            let v = _mm256_shuffle_ps::<0b10_00_10_00>(g0, g1);
            let s = _mm256_shuffle_ps::<0b11_01_11_01>(g0, g1);
            let v = _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(v)));
            let s = _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(s)));
            let f = _mm256_loadu_ps(fr.as_ptr().add(j));
            _mm256_storeu_ps(out.as_mut_ptr().add(j), _mm256_fmadd_ps(s, f, v));
        }
        j += 8;
    }
    gather_scalar(&idx[j..len], &fr[j..len], lut, &mut out[j..len]);
}

#[inline(always)]
fn gather_scalar(idx: &[u32], fr: &[f32], lut: &[u64; LUT_BINS], out: &mut [f32]) {
    for ((o, &i), &f) in out.iter_mut().zip(idx).zip(fr) {
        let w = lut[(i as usize) & (LUT_BINS - 1)];
        *o = f32::from_bits(w as u32) + f32::from_bits((w >> 32) as u32) * f;
    }
}

#[inline(always)]
fn kernel_dispatch<T: RawSample, const FMA: bool>(
    raw: [&[T]; 4],
    four: bool,
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
    gather: GatherFn,
) {
    match (four, t.fppn.is_some()) {
        (true, true) => kernel::<T, true, FMA, true>(raw, n, p, t, out, gather),
        (true, false) => kernel::<T, true, FMA, false>(raw, n, p, t, out, gather),
        (false, true) => kernel::<T, false, FMA, true>(raw, n, p, t, out, gather),
        (false, false) => kernel::<T, false, FMA, false>(raw, n, p, t, out, gather),
    }
}

/// `a * b + c`, fused when the kernel is compiled with FMA (never a libm call otherwise).
#[inline(always)]
fn madd<const FMA: bool>(a: f32, b: f32, c: f32) -> f32 {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

/// The per-pixel work in chunks of [`CHUNK`] pixels, three passes per chunk:
/// A (vectorised): raw validity, offset correction, amplitude, phase, LUT index/fraction;
/// B: LUT gather (vectorised where the ISA allows); C (vectorised): wiggling + FPPN correction,
/// wrap, depth, flags. All slices are re-sliced to the chunk length first so there are no bounds
/// checks, and the loops use selects instead of branches.
#[inline(always)]
fn kernel<T: RawSample, const FOUR: bool, const FMA: bool, const FPPN: bool>(
    raw: [&[T]; 4],
    n: usize,
    p: &KernelParams,
    t: &Tables<'_>,
    out: Outputs<'_>,
    gather: GatherFn,
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
    let fppn_all = t.fppn.unwrap_or(&[]);
    let n = if FPPN { n.min(fppn_all.len()) } else { n };
    let rail = p.rail_hi;
    let mut idx_buf = [0u32; CHUNK];
    let mut fr_buf = [0f32; CHUNK];
    let mut corr_buf = [0f32; CHUNK];
    // Pass A → C intermediates stay in L1 (no pack/unpack of u8 flags, outputs written once).
    let mut m_buf = [0f32; CHUNK];
    let mut amp_buf = [0f32; CHUNK];
    let mut bad_buf = [0u32; CHUNK];
    let mut base = 0;
    while base < n {
        let len = CHUNK.min(n - base);
        let end = base + len;
        let r0 = &raw[0][base..end];
        let r1 = &raw[1][base..end];
        let (r2, r3) = if FOUR {
            (&raw[2][base..end], &raw[3][base..end])
        } else {
            (r0, r1)
        };
        let dark = &t.dark[base..end];
        let fppn: &[f32] = if FPPN { &fppn_all[base..end] } else { &[] };
        let phase = &mut out.phase[base..end];
        let amp = &mut out.amp[base..end];
        let depth_m = &mut out.depth_m[base..end];
        let depth_mm = &mut out.depth_mm[base..end];
        let flags = &mut out.flags[base..end];
        let idx = &mut idx_buf[..len];
        let frb = &mut fr_buf[..len];
        let corr = &mut corr_buf[..len];
        let mb = &mut m_buf[..len];
        let ab = &mut amp_buf[..len];
        let bb = &mut bad_buf[..len];

        // Pass A.
        for j in 0..len {
            let a0 = r0[j].to_f32();
            let a1 = r1[j].to_f32();
            // Saturation and finiteness on the RAW codes (non-short-circuit `|`/`&`: no branches).
            let mut sat = (a0 <= 0.0) | (a0 >= rail) | (a1 <= 0.0) | (a1 >= rail);
            let mut finite = a0.is_finite() & a1.is_finite();
            let (x, y, amp_v);
            if FOUR {
                let a2 = r2[j].to_f32();
                let a3 = r3[j].to_f32();
                sat = sat | (a2 <= 0.0) | (a2 >= rail) | (a3 <= 0.0) | (a3 >= rail);
                finite = finite & a2.is_finite() & a3.is_finite();
                // eq. 2.3: the per-pixel offset cancels in the differences.
                x = a0 - a2;
                y = a1 - a3;
                amp_v = 0.5 * madd::<FMA>(x, x, y * y).sqrt(); // eq. 2.4
            } else {
                // Offset correction (4.3.3.1), then eq. 2.2.
                x = a0 - dark[j];
                y = a1 - dark[j];
                amp_v = madd::<FMA>(x, x, y * y).sqrt(); // |z|, 2-phase form of eq. 2.4
            }
            let m = atan2_poly::<FMA>(y, x); // eq. 2.2 / 2.3, [0, 2π)
            // Float→int without `as` (saturating casts do not vectorise): adding 1.5·2^23 puts
            // round(x) in the low mantissa bits. `xf − 0.5` rounds to floor (a tie gives idx − 1
            // with fr = 1: the same interpolated value). NaN gives an index masked into range.
            let xf = m * p.lut_scale;
            let xi = (xf - 0.5 + ROUND_MAGIC).to_bits() & 0x3F_FFFF;
            idx[j] = xi;
            frb[j] = xf - (xi as i32) as f32; // signed convert: native on x86 (xi < 2^22)
            mb[j] = m;
            ab[j] = amp_v;
            bb[j] = (sat as u32) | ((!finite as u32) << 3);
        }

        // Pass B: wiggling LUT (3.3.7.2), linear periodic interpolation.
        gather(idx, frb, t.lut, corr);

        // Pass C.
        for j in 0..len {
            let f0 = bb[j];
            let finite = f0 & FLAG_NON_FINITE as u32 == 0;
            let sat = f0 & FLAG_SATURATED as u32 != 0;
            let amp_v = ab[j];
            // Wiggling and FPPN (2.3.1.4), then wrap into [0, 2π) (ph is within (−3π, 5π)).
            let mut ph = mb[j] - corr[j];
            if FPPN {
                ph -= fppn[j];
            }
            ph = if ph < 0.0 { ph + TAU } else { ph };
            ph = if ph < 0.0 { ph + TAU } else { ph };
            ph = if ph >= TAU { ph - TAU } else { ph };
            ph = if ph >= TAU { ph - TAU } else { ph };
            let d = ph * p.rad_to_m; // eq. 2.6
            let in_range = d * 1000.0 < 65_535.5; // false for NaN
            let low = amp_v < p.min_amp;
            let invalid = sat | low | !finite | !in_range;
            flags[j] = (f0 | ((low as u32) << 1) | ((invalid as u32) << 2)) as u8;
            // round(d · 1000) by the same mantissa trick; ≥ 1 mm when valid.
            let mm = ((((d * 1000.0 + ROUND_MAGIC).to_bits() & 0x3F_FFFF) as i32).max(1)) as u16;
            depth_mm[j] = if invalid { 0 } else { mm };
            depth_m[j] = if invalid { 0.0 } else { d };
            phase[j] = if finite { ph } else { 0.0 };
            amp[j] = if finite { amp_v } else { 0.0 };
        }
        base = end;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array3, ShapeBuilder};

    fn synth(phi: f64, amp: f64, rows: usize, cols: usize, phases: &[f64]) -> Array3<f64> {
        Array3::from_shape_fn((phases.len(), rows, cols), |(k, _, _)| {
            2048.0 + amp * (phi - phases[k].to_radians()).cos()
        })
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
            }
        }
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
    fn all_simd_levels_agree() {
        let (rows, cols) = (13, 37); // odd sizes exercise the chunk and vector tails
        let lut = WigglingLut {
            algorithm: Algorithm::TwoPhase,
            correction_rad: ndarray::Array1::from_shape_fn(360, |i| {
                0.4 + 0.05 * (i as f32 * 0.05).sin()
            }),
        };
        let cal = Calibration {
            wiggling: Some(lut),
            ..Default::default()
        };
        let mut p = Pipeline::new(rows, cols, PipelineConfig::default(), cal).unwrap();
        let raw = Array3::from_shape_fn((2, rows, cols), |(k, r, c)| {
            let phi = (r * cols + c) as f64 * 0.013;
            (2048.0 + 900.0 * (phi - k as f64 * std::f64::consts::FRAC_PI_2).cos()).round() as u16
        });
        p.set_simd_level("generic").unwrap();
        let reference = p.process(raw.view()).unwrap().clone();
        for level in ["avx2", "avx512"] {
            if p.set_simd_level(level).is_err() {
                continue; // not on this CPU
            }
            assert_eq!(p.simd_level(), level);
            let f = p.process(raw.view()).unwrap();
            assert_eq!(f.flags, reference.flags, "{level}");
            for (a, b) in f.phase_rad.iter().zip(reference.phase_rad.iter()) {
                let d = (a - b).abs();
                assert!(d.min(TAU - d) < 2e-5, "{level}: {a} vs {b}");
            }
            for (a, b) in f.depth_mm.iter().zip(reference.depth_mm.iter()) {
                assert!((*a as i32 - *b as i32).abs() <= 1, "{level}: {a} vs {b}");
            }
        }
        assert!(p.set_simd_level("sse9").is_err());
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
