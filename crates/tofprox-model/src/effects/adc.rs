//! The ADC transfer of 3.2.1/4.2.1 the effects `adc_gain`, `adc_offset`,
//! `adc_inl`, `adc_dnl` and `quantization` make up together, and saturation at the
//! rails (always): one converter built from the model, its DNL table drawn once.
//! Each effect's entry and its own law are in its module.

use crate::effects::adc_gain::gain_factor;
use crate::effects::adc_inl::inl_shape;
use super::correlation::fast_floor;
use super::fixed_pattern::{TAG_DNL, hashed_normal};
use crate::config::ModelConfig;

/// Front padding of the windowed DNL searches.
const PAD: usize = 3;

/// INL table spacing in LSB.
const INL_STEP: usize = 4;

/// A differential N-bit converter with mid code 2^(N−1) for zero input.
#[derive(Debug, Clone)]
pub struct Adc {
    mid: f64,
    max_code: f64,
    /// slope factor 1/(1 + e_gain) (eq. 3.2)
    k_gain: f64,
    offset_lsb: f64,
    inl_lsb: f64,
    /// INL(x) sampled at every LSB of x ∈ [−2^N, 2^N] (linear interpolation between).
    inl_table: Option<Vec<f32>>,
    /// Δcode(k) of the enabled code laws ([`super::CodeLaw`]) at every code k, summed.
    law_table: Option<Vec<f32>>,
    /// Step centres (T_k + T_{k+1})/2 of the DNL table.
    centres: Option<Vec<f64>>,
    /// 1 / (c_{k+1} − c_k) (0 for coincident centres of missing codes).
    inv_width: Option<Vec<f64>>,
    quantize: bool,
    /// Transition levels padded with +∞ (branch-free windows of four).
    tpad: Vec<f64>,
    /// (centre, 1/width) padded with (+∞, 0).
    cpad: Vec<(f64, f64)>,
    /// Transition levels T_k into code k (k = 0..=2^N, T_0 = −∞ side, T_{2^N} = top), when DNL is on.
    thresholds: Option<Vec<f64>>,
}

impl Adc {
    /// Build the converter of a model; the DNL table is drawn from `seed`.
    pub fn new(model: &ModelConfig, bits: u8, seed: u64) -> Self {
        let full = f64::from(1u32 << bits);
        let mid = full / 2.0;
        let k_gain = gain_factor(model);
        let offset_lsb = if model.is_enabled(crate::effects::adc_offset::ID) {
            model.get(crate::effects::adc_offset::OFFSET_LSB)
        } else {
            0.0
        };
        let inl_lsb = if model.is_enabled(crate::effects::adc_inl::ID) {
            model.get(crate::effects::adc_inl::INL_LSB)
        } else {
            0.0
        };
        let thresholds =
            if model.is_enabled(crate::effects::adc_dnl::ID) && model.get(crate::effects::adc_dnl::DNL_LSB) > 0.0 {
                let dnl = model.get(crate::effects::adc_dnl::DNL_LSB);
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
        // one entry per INL_STEP LSB over x ∈ [−2^N, 2^N] as f32 (fits in L1);
        // linear interpolation error ≤ (2π·4/2^N)²/8 · |I| ≈ 5e-6 |I| LSB at 12 bit
        let inl_table = (inl_lsb != 0.0).then(|| {
            (0..=(2 * (1usize << bits)) / INL_STEP)
                .map(|i| (inl_lsb * inl_shape((i * INL_STEP) as f64 - full, full)) as f32)
                .collect()
        });
        let law_table = code_law_table(model, bits);
        let centres = thresholds
            .as_ref()
            .map(|t: &Vec<f64>| t.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect());
        let inv_width: Option<Vec<f64>> = centres.as_ref().map(|c: &Vec<f64>| {
            c.windows(2)
                .map(|w| {
                    if w[1] > w[0] {
                        1.0 / (w[1] - w[0])
                    } else {
                        0.0
                    }
                })
                .chain(std::iter::once(0.0))
                .collect()
        });
        // Padded copies for the windowed searches: index i + PAD holds level i;
        // pads (and T_0, which no code counts) are +∞ so they never count.
        let tpad = match &thresholds {
            Some(t) => {
                let mut v = vec![f64::INFINITY; t.len() + PAD + 8];
                for (j, &tj) in t.iter().enumerate().skip(1).take(t.len().saturating_sub(2)) {
                    if let Some(slot) = v.get_mut(j + PAD) {
                        *slot = tj;
                    }
                }
                v
            }
            None => Vec::new(),
        };
        let cpad = match (&centres, &inv_width) {
            (Some(c), Some(inv)) => {
                let mut v = vec![(f64::INFINITY, 0.0); c.len() + PAD + 8];
                for (j, (&cj, &ij)) in c.iter().zip(inv.iter()).enumerate() {
                    if let Some(slot) = v.get_mut(j + PAD) {
                        *slot = (cj, ij);
                    }
                }
                v
            }
            _ => Vec::new(),
        };
        Self {
            tpad,
            cpad,
            mid,
            max_code: full - 1.0,
            k_gain,
            offset_lsb,
            inl_lsb,
            inl_table,
            law_table,
            centres,
            inv_width,
            quantize: model.is_enabled(crate::effects::quantization::ID),
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
    /// y = mid + k u + o + INL(k u + o) + Δcode(mid + k u + o), INL(x) = I sin(2π x / 2^N)
    /// (fig. 3.4), Δcode the enabled code laws at the ideal code (rounded, at the rails clamped).
    #[inline]
    pub fn transfer(&self, u: f64) -> f64 {
        let x = self.k_gain * u + self.offset_lsb;
        let law = match &self.law_table {
            Some(t) => {
                let code = fast_floor(self.mid + x + 0.5).clamp(0.0, self.max_code) as usize;
                t.get(code).map_or(0.0, |&d| f64::from(d))
            }
            None => 0.0,
        };
        self.inl_transfer(x) + law
    }

    /// mid + x + INL(x) for x = k u + o.
    #[inline]
    fn inl_transfer(&self, x: f64) -> f64 {
        let inl = match &self.inl_table {
            Some(t) => {
                let full = 2.0 * self.mid;
                let p = (x + full).clamp(0.0, 2.0 * full) * (1.0 / INL_STEP as f64);
                let i = p as usize;
                let w = p - i as f64;
                match (t.get(i), t.get(i + 1)) {
                    (Some(&a), Some(&b)) => f64::from(a) + f64::from(b - a) * w,
                    (Some(&a), None) => f64::from(a),
                    _ => self.inl_lsb * inl_shape(x, 2.0 * self.mid),
                }
            }
            None => 0.0,
        };
        self.mid + x + inl
    }

    /// Integer output code for a continuous level `y` (DNL table, rails).
    #[inline]
    pub fn quantize(&self, y: f64) -> f64 {
        match &self.thresholds {
            Some(t) => {
                if y < 0.0 {
                    return 0.0;
                }
                let k = y.min(self.max_code) as usize; // y ≥ 0: truncation is floor
                // code = #{j ≥ 1 : T_j ≤ y}. |T_j − (j − ½)| ≤ 2, so every j ≤ k − 2 counts,
                // none ≥ k + 4 does: compare the five in between (independent loads)
                let before = k.saturating_sub(2);
                let mut j = before;
                if let Some(w) = self.tpad.get(k + PAD - 1..k + PAD + 4) {
                    for &v in w {
                        j += usize::from(v <= y);
                    }
                } else {
                    j = t
                        .iter()
                        .skip(1)
                        .take(t.len().saturating_sub(2))
                        .filter(|&&v| v <= y)
                        .count();
                }
                (j as f64).min(self.max_code)
            }
            _ => fast_floor(y + 0.5).clamp(0.0, self.max_code),
        }
    }

    /// Mean output code for a level `y` with input noise well above 1 LSB: the
    /// piecewise-linear curve through the step centres (ideal: y itself), at the rails clamped.
    #[inline]
    pub fn mean_code(&self, y: f64) -> f64 {
        match (&self.centres, &self.inv_width) {
            (Some(c), Some(inv)) => {
                if y <= 0.0 {
                    return 0.0;
                }
                if y >= self.max_code {
                    return self.max_code;
                }
                let k = y as usize; // 0 < y < max: truncation is floor
                // j = last centre ≤ y. |c_i − i| ≤ 2: all i ≤ k − 2 count, none ≥ k + 4
                let mut total = k.saturating_sub(1);
                match self.cpad.get(k + PAD - 1..k + PAD + 4) {
                    Some(w) => {
                        for &(v, _) in w {
                            total += usize::from(v <= y);
                        }
                    }
                    None => total = c.iter().filter(|&&v| v <= y).count(),
                }
                if total == 0 {
                    return 0.0;
                }
                let j = total - 1;
                let (cj, inv_j) = match self.cpad.get(j + PAD) {
                    Some(&p) => p,
                    None => (j as f64, inv.get(j).copied().unwrap_or(0.0)),
                };
                let v = j as f64 + (y - cj) * inv_j;
                v.clamp(0.0, self.max_code)
            }
            _ => y.clamp(0.0, self.max_code),
        }
    }
}

/// Δcode(k) of `model`'s enabled code laws ([`active_code_laws`]) at every code k of an
/// N-bit converter; `None` when there is none.
fn code_law_table(model: &ModelConfig, bits: u8) -> Option<Vec<f32>> {
    let laws = active_code_laws(model);
    if laws.is_empty() {
        return None;
    }
    let mut basis = Vec::new();
    let table = (0..1u32 << bits)
        .map(|code| {
            let mut sum = 0.0;
            for (law, values) in &laws {
                basis.resize(values.len(), 0.0);
                law.basis(code, bits, &mut basis);
                sum += basis.iter().zip(values).map(|(b, v)| b * v).sum::<f64>();
            }
            sum as f32
        })
        .collect();
    Some(table)
}

/// The enabled code laws of `model` with their parameter values (an effect whose
/// parameters are all zero left out).
fn active_code_laws(model: &ModelConfig) -> Vec<(&'static dyn super::CodeLaw, Vec<f64>)> {
    super::REGISTRY
        .iter()
        .filter(|e| model.is_enabled(e.id()))
        .filter_map(|e| e.code_law())
        .map(|law| {
            (
                law,
                law.params()
                    .iter()
                    .map(|&p| model.get(p))
                    .collect::<Vec<f64>>(),
            )
        })
        .filter(|(_, v)| v.iter().any(|&x| x != 0.0))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dnl_adc(dnl: f64, seed: u64) -> Adc {
        let mut m = ModelConfig::ideal();
        m.enable(crate::effects::adc_dnl::ID, true).unwrap();
        m.enable(crate::effects::quantization::ID, true).unwrap();
        m.set(crate::effects::adc_dnl::DNL_LSB, dnl).unwrap();
        Adc::new(&m, 12, seed)
    }

    #[test]
    fn fast_quantizer_matches_brute_force_count_of_transitions() {
        for (dnl, seed) in [(1.906, 1), (3.9, 2), (0.5, 3)] {
            let adc = dnl_adc(dnl, seed);
            let t = adc.thresholds.as_ref().unwrap();
            for i in 0..40_000 {
                let y = -3.0 + 4102.0 * i as f64 / 40_000.0;
                let brute = t[1..t.len() - 1].iter().filter(|&&v| v <= y).count() as f64;
                assert_eq!(adc.quantize(y), brute.min(4095.0), "y = {y}, dnl {dnl}");
            }
            // DNL bounded: step widths within 1 ± dnl
            for w in t.windows(2).skip(1).take(4094) {
                assert!(w[1] - w[0] <= 1.0 + dnl + 1e-12 && w[1] >= w[0]);
            }
        }
    }

    #[test]
    fn mean_code_is_monotone_through_the_step_centres() {
        let adc = dnl_adc(1.906, 4);
        let c = adc.centres.as_ref().unwrap();
        for k in [5usize, 100, 2047, 3000, 4090] {
            assert!((adc.mean_code(c[k]) - k as f64).abs() < 1e-9, "centre {k}");
        }
        let mut last = 0.0;
        for i in 0..100_000 {
            let y = 4095.0 * i as f64 / 100_000.0;
            let v = adc.mean_code(y);
            assert!(v >= last - 1e-9, "not monotone at {y}");
            last = v;
        }
        // ideal converter: the mean is the input itself
        let ideal = Adc::new(&ModelConfig::ideal(), 12, 0);
        assert_eq!(ideal.mean_code(1234.5678), 1234.5678);
        assert_eq!(ideal.quantize(1234.5678), 1235.0);
        assert_eq!(ideal.quantize(5000.0), 4095.0);
        assert_eq!(ideal.quantize(-7.0), 0.0);
        assert_eq!(ideal.quantize(2048.0), 2048.0);
    }

    /// Without an enabled code law the converter has no Δcode table (a code law's own
    /// test is in its module, `adc_sar_mismatch`).
    #[test]
    fn without_a_code_law_there_is_no_table() {
        assert!(Adc::new(&ModelConfig::ideal(), 12, 1).law_table.is_none());
        assert!(Adc::new(&ModelConfig::baseline(), 12, 1).law_table.is_none());
    }
}
