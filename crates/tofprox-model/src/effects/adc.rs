//! The ADC model of 3.2.1/4.2.1: `adc_gain`, `adc_offset`, `adc_inl`, `adc_dnl`,
//! `quantization`, and saturation at the rails (always).

use std::f64::consts::TAU;

use super::fixed_pattern::{TAG_DNL, hashed_normal};
use crate::config::ModelConfig;

/// A differential N-bit converter with mid code 2^(N−1) for zero input.
#[derive(Debug, Clone)]
pub struct Adc {
    mid: f64,
    max_code: f64,
    /// slope factor 1/(1 + e_gain) (eq. 3.2)
    k_gain: f64,
    offset_lsb: f64,
    inl_lsb: f64,
    inl_w: f64,
    quantize: bool,
    /// Transition levels T_k into code k (k = 0..=2^N, T_0 = −∞ side, T_{2^N} = top), when DNL is on.
    thresholds: Option<Vec<f64>>,
}

impl Adc {
    /// Build the converter of a model; the DNL table is drawn from `seed`.
    pub fn new(model: &ModelConfig, bits: u8, seed: u64) -> Self {
        let full = f64::from(1u32 << bits);
        let mid = full / 2.0;
        let k_gain = if model.is_enabled("adc_gain") {
            1.0 / (1.0 + model.p("adc_gain", "gain_error_pct_fsr") / 100.0)
        } else {
            1.0
        };
        let offset_lsb = if model.is_enabled("adc_offset") {
            model.p("adc_offset", "offset_lsb")
        } else {
            0.0
        };
        let inl_lsb = if model.is_enabled("adc_inl") {
            model.p("adc_inl", "inl_lsb")
        } else {
            0.0
        };
        let thresholds = if model.is_enabled("adc_dnl") && model.p("adc_dnl", "dnl_lsb") > 0.0 {
            let dnl = model.p("adc_dnl", "dnl_lsb");
            let sigma = dnl / (3.0 * std::f64::consts::SQRT_2);
            let n = 1usize << bits;
            let mut t = Vec::with_capacity(n + 1);
            t.push(-0.5);
            for k in 1..n {
                let e = (sigma * hashed_normal(seed, TAG_DNL, k as u64, 0))
                    .clamp(-dnl / 2.0, dnl / 2.0);
                let ideal = k as f64 - 0.5;
                // a transition below its predecessor is a missing code
                let prev = t.last().copied().unwrap_or(-0.5);
                t.push((ideal + e).max(prev));
            }
            t.push(full - 0.5);
            Some(t)
        } else {
            None
        };
        Self {
            mid,
            max_code: full - 1.0,
            k_gain,
            offset_lsb,
            inl_lsb,
            inl_w: TAU / full,
            quantize: model.is_enabled("quantization"),
            thresholds,
        }
    }

    /// Mid code (zero differential input).
    pub fn mid(&self) -> f64 {
        self.mid
    }

    /// Largest code.
    pub fn max_code(&self) -> f64 {
        self.max_code
    }

    /// Whether the output is integer codes.
    pub fn quantizes(&self) -> bool {
        self.quantize
    }

    /// Continuous transfer (before quantisation) of an input `u` in LSB around mid:
    /// y = mid + k u + o + INL(k u + o), INL(x) = I sin(2π x / 2^N) (fig. 3.4).
    #[inline]
    pub fn transfer(&self, u: f64) -> f64 {
        let x = self.k_gain * u + self.offset_lsb;
        let inl = if self.inl_lsb != 0.0 {
            self.inl_lsb * (self.inl_w * x).sin()
        } else {
            0.0
        };
        self.mid + x + inl
    }

    /// Integer output code for a continuous level `y` (DNL table, rails).
    #[inline]
    pub fn quantize(&self, y: f64) -> f64 {
        match &self.thresholds {
            None => y.round().clamp(0.0, self.max_code),
            Some(t) => {
                let top = self.max_code as usize;
                let mut j = (y.round().clamp(0.0, self.max_code)) as usize;
                // code j ⇔ T_j ≤ y < T_{j+1}
                while j < top && t.get(j + 1).is_some_and(|&v| v <= y) {
                    j += 1;
                }
                while j > 0 && t.get(j).is_some_and(|&v| v > y) {
                    j -= 1;
                }
                j as f64
            }
        }
    }

    /// Mean output code for a level `y` with input noise well above 1 LSB: the
    /// piecewise-linear curve through the step centres (ideal: y itself), at the rails clamped.
    #[inline]
    pub fn mean_code(&self, y: f64) -> f64 {
        match &self.thresholds {
            None => y.clamp(0.0, self.max_code),
            Some(t) => {
                if y <= 0.0 {
                    return 0.0;
                }
                if y >= self.max_code {
                    return self.max_code;
                }
                let top = self.max_code as usize;
                let centre = |k: usize| -> f64 {
                    match (t.get(k), t.get(k + 1)) {
                        (Some(a), Some(b)) => 0.5 * (a + b),
                        _ => k as f64,
                    }
                };
                let mut j = (y.round().clamp(0.0, self.max_code)) as usize;
                while j < top && centre(j + 1) <= y {
                    j += 1;
                }
                while j > 0 && centre(j) > y {
                    j -= 1;
                }
                if j >= top {
                    return self.max_code;
                }
                let (c0, c1) = (centre(j), centre(j + 1));
                let v = if c1 > c0 {
                    j as f64 + (y - c0) / (c1 - c0)
                } else {
                    j as f64 + 1.0
                };
                v.clamp(0.0, self.max_code)
            }
        }
    }
}
