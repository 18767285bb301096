//! `adc_dnl`: ADC differential non-linearity (thesis 3.2.1, 3.3.1, 3.3.5 (fig. 3.9), table 3.2).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law is applied
//! by the converter the ADC effects make up together (`effects::adc::Adc`).

use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(adc_dnl {
    DNL_LSB = "dnl_lsb",
});

/// The catalogue entry of `adc_dnl`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "ADC differential non-linearity",
    explanation: "Code transition levels deviate randomly from their ideal positions, T_k = k − ½ + ε_k with ε_k Gaussian (σ = DNL/(3√2), clipped to ±DNL/2) from a fixed per-sensor table, so step widths 1 + ε_{k+1} − ε_k lie within 1 ± DNL LSB (a transition below its predecessor is a missing code).",
    thesis_ref: "3.2.1, 3.3.1, 3.3.5 (fig. 3.9), table 3.2",
    signature: "raw residual jumping from code to code, fixed per code; depth error well below 1 cm",
    params: &[p(
        DNL_LSB,
        "LSB",
        1.906,
        0.0,
        4.0,
        "maximum DNL (table 3.2: min 1.594, typ 1.906, max 2.438)",
    )],
    in_baseline: false,
    acts_on: ActsOn::Adc,
    drivers: &[Driver::AdcCode],
    cancels_in_four_phase: false,
};

effect!(AdcDnl, INFO, ID, chain = 190);
