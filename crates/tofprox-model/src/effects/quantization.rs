//! `quantization`: Quantisation to integer codes (thesis 2.3.2.5, eq. 2.20-2.21, 3.2.1).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law is applied
//! by the converter the ADC effects make up together (`effects::adc::Adc`).

use crate::entry::{ActsOn, EffectInfo};

crate::ids::effect_ids!(quantization {});

/// The catalogue entry of `quantization`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "Quantisation to integer codes",
    explanation: "The ADC outputs integer codes: uniform error in [−½, ½] LSB with σ = 1/√12 LSB (2.3.2.5). Averaged captures (averaged = n) return the mean of n quantised acquisitions, modelled as the continuous transfer plus noise of variance (σ² + 1/12)/n. Codes saturate at 0 and 2^N − 1 (the saturation flag of 3.2.1) whether or not this effect is on.",
    thesis_ref: "2.3.2.5, eq. 2.20-2.21, 3.2.1",
    signature: "integer codes; 1/12 LSB² noise floor",
    params: &[],
    in_baseline: true,
    acts_on: ActsOn::Adc,
    drivers: &[],
    cancels_in_four_phase: false,
};

effect!(Quantization, INFO, ID, chain = 210);
