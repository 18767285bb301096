//! `ambient_light`: Uncorrelated background light (thesis 2.2.2.1, 5.1.2.3).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law is evaluated
//! inline by the simulator ([`crate::sim`]), where the signal chain combines it.

use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(ambient_light {
    E_PER_US_PER_KLUX = "e_per_us_per_klux",
});

/// The catalogue entry of `ambient_light`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "Uncorrelated background light",
    explanation: "Background light (sunlight, lamps) is not modulated: it adds N_amb = k · E · t_exp electrons equally to both taps (E in klux, after the optical filter). It carries no phase but adds shot noise and drives the taps towards the SBI threshold.",
    thesis_ref: "2.2.2.1, 5.1.2.3",
    signature: "noise grows with ambient_klux; with SBI mismatch a 2-phase-only depth error",
    params: &[p(
        E_PER_US_PER_KLUX,
        "e-/us/klux",
        3.0,
        0.0,
        1e4,
        "electrons per µs per tap per klux",
    )],
    in_baseline: true,
    acts_on: ActsOn::TapCharge,
    drivers: &[Driver::AmbientKlux],
    cancels_in_four_phase: false,
};

effect!(AmbientLight, INFO, ID, chain = 110);
