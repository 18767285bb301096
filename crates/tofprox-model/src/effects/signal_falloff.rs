//! `signal_falloff`: Reflected signal vs distance (thesis 2.2.1, 3.3.3 (fig. 3.7:
//! signal loss with distance)).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law is evaluated inline by the
//! simulator ([`crate::sim`]), where the signal chain combines it.

use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(signal_falloff {
    EXPONENT = "exponent",
});

/// The catalogue entry of `signal_falloff`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "Reflected signal vs distance",
    explanation: "The optical power reaching a pixel from a diffuse target falls with the square of the distance: N_sig = signal_e_per_us · t_exp · ρ · (1 m / d)^n with n = 2 for a Lambertian wall. Disabled, the collected signal is that of 1 m at every distance (the constant-electron sweeps of fig. 3.9).",
    thesis_ref: "2.2.1, 3.3.3 (fig. 3.7: signal loss with distance)",
    signature: "amplitude ∝ d^-n; depth residuals of offset-like effects grow with distance",
    params: &[p(
        EXPONENT,
        "",
        2.0,
        1.0,
        3.0,
        "distance exponent n of the falloff (2 = inverse square)",
    )],
    in_baseline: true,
    acts_on: ActsOn::Signal,
    drivers: &[Driver::DistanceM],
    cancels_in_four_phase: false,
};

effect!(SignalFalloff, INFO, ID, chain = 10);
