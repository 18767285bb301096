//! `adc_sar_mismatch`: the weight errors of a SAR converter's binary-weighted capacitors
//! (thesis 2.3.2.5: the pixels are read by 12-bit SAR ADCs; 3.3.5: a real converter's DNL
//! does not follow the Gaussian of `adc_dnl`).
//!
//! Its catalogue entry, its registry entry and its law ([`SarLaw`], a [`CodeLaw`]): the
//! converter ([`crate::effects::adc::Adc`]) and the lab apply it from here.

use crate::effects::CodeLaw;
use crate::entry::{ActsOn, Driver, EffectInfo, param as p};
use crate::ids::ParamId;

crate::ids::effect_ids!(adc_sar_mismatch {
    MSB_LSB = "msb_lsb",
    MSB1_LSB = "msb1_lsb",
    MSB2_LSB = "msb2_lsb",
    MSB3_LSB = "msb3_lsb",
});

/// The parameters, the weight errors δ of bits N−1 … N−4 in LSB.
const PARAMS: &[ParamId] = &[MSB_LSB, MSB1_LSB, MSB2_LSB, MSB3_LSB];

/// The law of a successive-approximation converter whose bit b weighs 2^b + δ_b LSB
/// instead of 2^b (standard SAR analysis; the converter of 2.3.2.5): code k is decided where
/// the input reaches the DAC level Σ_b bit_b(k)·(2^b + δ_b), so the output is shifted by
/// −Σ_b bit_b(k)·δ_b, a staircase of steps at the codes where a top bit flips (the largest
/// at mid scale, DNL = δ_{N−1} − Σ_{b<N−1} δ_b there). Of that shift, the code-independent
/// −½ Σ_b δ_b is an offset (`adc_offset`'s, and the lab's per-pixel offsets'): the law is
/// the rest, Δcode(k) = −Σ_b (bit_b(k) − ½)·δ_b, so that its parameters and an offset are
/// not two names for one thing.
pub struct SarLaw;

impl CodeLaw for SarLaw {
    fn params(&self) -> &'static [ParamId] {
        PARAMS
    }

    fn basis(&self, code: u32, bits: u8, out: &mut [f64]) {
        for (j, o) in out.iter_mut().enumerate() {
            let b = u32::from(bits).saturating_sub(1 + j as u32);
            *o = 0.5 - f64::from((code >> b) & 1);
        }
    }
}

/// The catalogue entry of `adc_sar_mismatch`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "SAR capacitor mismatch",
    explanation: "A successive-approximation converter weighs bit b with a capacitor of 2^b unit capacitors; a mismatch δ_b (in LSB) of the top bits shifts every code with that bit set by −δ_b: Δcode(k) = −Σ_b (bit_b(k) − ½)·δ_b (bits N−1 … N−4; the constant −½ Σ δ_b is an offset, `adc_offset`). A staircase over the code range with its largest step at mid scale: the DNL of a real converter, structured by its capacitors rather than the Gaussian of `adc_dnl` (3.3.5).",
    thesis_ref: "2.3.2.5, 3.2.1, 3.3.5",
    signature: "raw residual a staircase in the code, jumping where a top bit flips (mid, quarter and eighth scale); depth error jumping with the phase images' signs",
    params: &[
        p(
            MSB_LSB,
            "LSB",
            1.0,
            -64.0,
            64.0,
            "weight error of bit N−1 (the MSB)",
        ),
        p(
            MSB1_LSB,
            "LSB",
            0.5,
            -32.0,
            32.0,
            "weight error of bit N−2",
        ),
        p(
            MSB2_LSB,
            "LSB",
            -0.3,
            -16.0,
            16.0,
            "weight error of bit N−3",
        ),
        p(
            MSB3_LSB,
            "LSB",
            0.2,
            -8.0,
            8.0,
            "weight error of bit N−4",
        ),
    ],
    in_baseline: false,
    acts_on: ActsOn::Adc,
    drivers: &[Driver::AdcCode],
    cancels_in_four_phase: false,
};

effect!(AdcSarMismatch, INFO, ID, chain = 200, code_law = SarLaw);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ModelConfig;
    use crate::effects::adc::Adc;

    /// The converter applies this law through the registry, as every code law: it adds its
    /// Δcode at the input's ideal code — the same converter without it, plus
    /// −Σ_b (bit_b(k) − ½)·δ_b written out for k = round(mid + x).
    #[test]
    fn the_converter_adds_the_enabled_code_laws_at_the_ideal_code() {
        let mut m = ModelConfig::baseline();
        let plain = Adc::new(&m, 12, 1);
        m.enable(ID, true).unwrap();
        let delta = [6.0, -3.0, 2.0, 1.5];
        for (p, d) in PARAMS.iter().zip(delta) {
            m.set(*p, d).unwrap();
        }
        let sar = Adc::new(&m, 12, 1);
        for i in 0..4000 {
            let u = -2000.0 + f64::from(i) + 0.37;
            let ideal = plain.transfer(u);
            let k = (ideal.round() as u32).min(4095);
            let want: f64 = (0..4)
                .map(|j| (0.5 - f64::from((k >> (11 - j)) & 1)) * delta[j as usize])
                .sum();
            // the ideal code is the converter's before its INL (off in the baseline)
            assert!((sar.transfer(u) - ideal - want).abs() < 1e-9, "u = {u}");
        }
    }

    /// The law against a SAR conversion written out: a binary search of the input, one
    /// bit after the other, against the DAC levels of the mismatched weights. Away from the
    /// codes where a top bit flips (where the law's ideal code and the converter's decision
    /// differ by up to Σ|δ|) the two agree code for code.
    #[test]
    fn the_law_is_a_sar_search_against_mismatched_weights() {
        let bits = 12u8;
        let delta = [3.0, -2.0, 1.0, 2.0];
        let weight = |b: u8| -> f64 {
            let j = usize::from(bits - 1 - b);
            f64::from(1u32 << b) + delta.get(j).copied().unwrap_or(0.0)
        };
        let dac = |k: u32| -> f64 { (0..bits).map(|b| f64::from((k >> b) & 1) * weight(b)).sum() };
        let sar = |v: f64| -> u32 {
            (0..bits).rev().fold(0u32, |k, b| {
                let trial = k | (1 << b);
                if v >= dac(trial) - 0.5 { trial } else { k }
            })
        };
        let mut out = [0.0; 4];
        let (mut compared, mut near_flip) = (0, 0);
        for k in 16..4080u32 {
            let v = f64::from(k) + 0.2;
            SarLaw.basis(k, bits, &mut out);
            let shift: f64 = out.iter().zip(delta).map(|(b, d)| b * d).sum();
            // the law without its offset part, −½ Σ δ_b
            let law = f64::from(k) + shift - 0.5 * delta.iter().sum::<f64>();
            let to_flip = (k % 256).min(256 - k % 256);
            if to_flip <= 8 {
                near_flip += 1;
                continue;
            }
            assert_eq!(f64::from(sar(v)), law, "code {k}");
            compared += 1;
        }
        assert!(compared > 3800 && near_flip < 300, "{compared} {near_flip}");
        // the mid-scale step: DNL = δ_11 − (δ_10 + δ_9 + δ_8 + … ) at code 2048
        SarLaw.basis(2047, bits, &mut out);
        let below: f64 = out.iter().zip(delta).map(|(b, d)| b * d).sum();
        SarLaw.basis(2048, bits, &mut out);
        let above: f64 = out.iter().zip(delta).map(|(b, d)| b * d).sum();
        assert_eq!(above - below, -(3.0 - (-2.0 + 1.0 + 2.0)));
    }
}
