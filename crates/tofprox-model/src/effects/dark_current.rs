//! `dark_current`: Dark current and its shot noise (thesis 2.3.2.3, eq. 2.17).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law:
//! the dark current's temperature factor ([`dark_current_temperature_factor`]),
//! which the simulator and the lab's fit call.

use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(dark_current {
    E_PER_US = "e_per_us",
    DOUBLING_C = "doubling_c",
});

/// The temperature factor of the dark current (`dark_current`, eq. 2.17 with
/// i_d(T) = i_d,ref · 2^(ΔT/ΔT₂)): 2^(ΔT/ΔT₂) for ΔT = T − T_ref kelvin and the
/// doubling ΔT₂ (`doubling_c`). The simulator and the lab's fit both use it.
#[inline]
pub fn dark_current_temperature_factor(dt_k: f64, doubling_k: f64) -> f64 {
    2f64.powf(dt_k / doubling_k.max(1e-6))
}

/// The catalogue entry of `dark_current`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "Dark current and its shot noise",
    explanation: "Thermally generated electrons add N_dark = i_d · t_exp to both taps, doubling every ΔT_2 kelvin: i_d(T) = i_d,25 · 2^((T − 25 °C)/ΔT_2). Their Poisson noise σ² = N_dark per tap (eq. 2.17) is part of this effect.",
    thesis_ref: "2.3.2.3, eq. 2.17",
    signature: "noise floor growing with exposure and temperature; common mode only",
    params: &[
        p(
            E_PER_US,
            "e-/us",
            0.05,
            0.0,
            1e4,
            "dark electrons per µs per tap at 25 °C",
        ),
        p(
            DOUBLING_C,
            "K",
            7.0,
            1.0,
            30.0,
            "temperature increase that doubles the dark current",
        ),
    ],
    in_baseline: true,
    acts_on: ActsOn::TapCharge,
    drivers: &[Driver::ExposureUs],
    cancels_in_four_phase: true,
};

effect!(DarkCurrent, INFO, ID, chain = 120);
