//! `adc_offset`: ADC offset error (thesis 3.2.1, 3.3.3 eq. 3.4, fig. 3.7, table 3.2).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law is applied
//! by the converter the ADC effects make up together (`effects::adc::Adc`).

use crate::entry::{ActsOn, EffectInfo, param as p};

crate::ids::effect_ids!(adc_offset {
    OFFSET_LSB = "offset_lsb",
});

/// The catalogue entry of `adc_offset`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "ADC offset error",
    explanation: "A constant added to the transfer function: code = mid + k·u + o (3.2.1). Equal in all raw images, it adds a 45° phasor in 2-phase (eq. 3.4, fig. 3.7) and cancels in 4-phase; it is part of what dark frames measure.",
    thesis_ref: "3.2.1, 3.3.3 eq. 3.4, fig. 3.7, table 3.2",
    signature: "constant code offset; 2-phase depth error growing with distance (45° phasor)",
    params: &[p(
        OFFSET_LSB,
        "LSB",
        -10.84,
        -500.0,
        500.0,
        "offset error o (table 3.2: min -13.94, typ -10.84, max 12.19)",
    )],
    in_baseline: true,
    acts_on: ActsOn::Offset,
    drivers: &[],
    cancels_in_four_phase: true,
};

effect!(AdcOffset, INFO, ID, chain = 170);
