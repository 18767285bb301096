//! [`Pipeline::process`]: a capture's images checked, staged where they must be (crosstalk
//! subtracted, non-contiguous layouts), and run through the kernel of the pipeline's
//! instruction set.

use super::kernel::{Outputs, Tables, kernel_dispatch};
#[cfg(target_arch = "x86_64")]
use super::kernel::{kernel_avx2, kernel_avx512};
use super::{DepthFrame, Pipeline, RawSample};
use crate::CoreError;
use crate::simd::Isa;
use ndarray::{ArrayView3, Axis};

impl Pipeline {
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
                let image = raw.index_axis(Axis(0), i);
                // contiguous images (the daemon's) as slices: a loop the compiler vectorises
                match image.as_slice() {
                    Some(src) => {
                        for ((d, s), x) in dst.iter_mut().zip(src).zip(xt) {
                            *d = without_crosstalk(s.to_f32(), *x, rail);
                        }
                    }
                    None => {
                        for ((d, s), x) in dst.iter_mut().zip(image.iter()).zip(xt) {
                            *d = without_crosstalk(s.to_f32(), *x, rail);
                        }
                    }
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
}

/// A raw code with the window's crosstalk `x` (codes) subtracted (2.2.1: its phasor adds to every
/// raw image), kept within the codes `[0.5, rail − 0.5]`; a code at a rail (or non-finite) stays
/// as it is, so saturation is still flagged on the raw value.
#[inline(always)]
fn without_crosstalk(v: f32, x: f32, rail: f32) -> f32 {
    let at_rail = (v <= 0.0) | (v >= rail) | !v.is_finite();
    let c = (v - x).clamp(0.5, rail - 0.5);
    if at_rail { v } else { c }
}
