//! `adc_gain`: ADC gain error (thesis 3.2.1 eq. 3.2, 3.3.2 eq. 3.3, table 3.2).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law:
//! the converter's slope factor ([`gain_factor`]), which the converter
//! (`effects::adc::Adc`) and the lab call.

use crate::config::ModelConfig;
use crate::entry::{ActsOn, EffectInfo, param as p};

crate::ids::effect_ids!(adc_gain {
    GAIN_ERROR_PCT_FSR = "gain_error_pct_fsr",
});

/// The converter's slope factor k = 1/(1 + e_gain) (eq. 3.2, `adc_gain`; 1
/// when the effect is off): output codes per LSB of input, so a charge of N
/// electrons reads as N·lsb_per_e·k codes.
pub fn gain_factor(model: &ModelConfig) -> f64 {
    if model.is_enabled(ID) {
        1.0 / (1.0 + model.get(GAIN_ERROR_PCT_FSR) / 100.0)
    } else {
        1.0
    }
}

/// The catalogue entry of `adc_gain`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "ADC gain error",
    explanation: "The converter slope deviates from ideal by a gain error in % of full-scale range: k_gain = 2^N / (FSR · (1 + e_gain)) (eq. 3.2). A common factor on all raw images never changes the phase (eq. 3.3) but scales amplitude and moves saturation.",
    thesis_ref: "3.2.1 eq. 3.2, 3.3.2 eq. 3.3, table 3.2",
    signature: "amplitude ratio, earlier saturation; no depth effect",
    params: &[p(
        GAIN_ERROR_PCT_FSR,
        "%FSR",
        -4.713,
        -30.0,
        30.0,
        "gain error e_gain (table 3.2: min -6.096, typ -4.713, max -2.176)",
    )],
    in_baseline: true,
    acts_on: ActsOn::Adc,
    drivers: &[],
    cancels_in_four_phase: false,
};

effect!(AdcGain, INFO, ID, chain = 160);
