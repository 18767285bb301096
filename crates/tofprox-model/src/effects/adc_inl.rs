//! `adc_inl`: ADC integral non-linearity (thesis 3.2.1, 3.3.1, 3.3.4 (fig. 3.4, 3.8), table 3.2).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law:
//! the INL's shape ([`inl_shape`]), which the converter
//! (`effects::adc::Adc`) and the lab's fit call.

use std::f64::consts::TAU;

use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(adc_inl {
    INL_LSB = "inl_lsb",
});

/// The shape of the differential converter's INL (`adc_inl`, 3.2.1, fig. 3.4):
/// INL(x) = I · inl_shape(x), inl_shape(x) = sin(2π x / 2^N) for x the input in LSB
/// around mid and `full_codes` = 2^N: zero at mid and at the rails, extremes at half
/// of each half-range, opposite sign on the two halves. The simulator and the
/// lab's fit both use this one function.
#[inline]
pub fn inl_shape(x_lsb: f64, full_codes: f64) -> f64 {
    (TAU * x_lsb / full_codes).sin()
}

/// The catalogue entry of `adc_inl`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "ADC integral non-linearity",
    explanation: "The differential converter's INL has opposite sign on the two half-ranges (fig. 3.4): INL(u) = I · sin(2π u / 2^N) for u the input in LSB around mid, zero at mid and at the rails, extremes ±I at half of each half-range. It distorts large phase-image voltages and gives a wiggling-like error with extremes at 22.5°/67.5° and zeros at multiples of 45° (fig. 3.8).",
    thesis_ref: "3.2.1, 3.3.1, 3.3.4 (fig. 3.4, 3.8), table 3.2",
    signature: "raw residual odd in (code − mid) with period 2^N; depth error with period π/2 growing with amplitude",
    params: &[p(
        INL_LSB,
        "LSB",
        -1.744,
        -500.0,
        500.0,
        "INL extreme I (table 3.2: min -2.392, typ -1.744, max 1.875)",
    )],
    in_baseline: false,
    acts_on: ActsOn::Adc,
    drivers: &[Driver::AdcCode, Driver::ExposureUs],
    cancels_in_four_phase: false,
};

effect!(AdcInl, INFO, ID, chain = 180);
