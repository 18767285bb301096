//! `tap_gain_mismatch`: Tap gain mismatch (A/B) (thesis 2.2.2 (two-tap pixel, eq.
//! 2.1), 3.3.3 eq. 3.4).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law: the differential charge the
//! mismatch leaks ([`tap_gain_leak_e`]), which the simulator and the lab's fit
//! call.

use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(tap_gain_mismatch {
    MISMATCH_REL = "mismatch_rel",
});

/// The differential charge a tap gain mismatch ε leaks from the total charge
/// (`tap_gain_mismatch`, eq. 2.1): D = (1 + ε/2)·N_A − (1 − ε/2)·N_B adds
/// ε/2 · (N_A + N_B). The simulator and the lab's fit both use it.
#[inline]
pub fn tap_gain_leak_e(mismatch_rel: f64, total_e: f64) -> f64 {
    0.5 * mismatch_rel * total_e
}

/// The catalogue entry of `tap_gain_mismatch`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "Tap gain mismatch (A/B)",
    explanation: "The two taps of a pixel convert charge with slightly different gains (storage capacitance, source follower): D = (1 + ε/2)·N_A − (1 − ε/2)·N_B = (N_A − N_B) + ε/2·(N_A + N_B). A share of the total charge (signal, background light, dark current) leaks into the differential code, the same in every raw image: 4-phase cancels it (0° − 180°), 2-phase does not (it moves the phasor's origin like an offset that grows with the signal, cf. eq. 3.4).",
    thesis_ref: "2.2.2 (two-tap pixel, eq. 2.1), 3.3.3 eq. 3.4",
    signature: "common-mode code ∝ total charge (signal and ambient), equal in all raw images; 2-phase depth error, 4-phase unaffected",
    params: &[p(
        MISMATCH_REL,
        "1",
        0.002,
        -0.1,
        0.1,
        "relative gain difference ε = g_A/g_B − 1",
    )],
    in_baseline: false,
    acts_on: ActsOn::Differential,
    drivers: &[Driver::Amplitude, Driver::AmbientKlux],
    cancels_in_four_phase: true,
};

effect!(TapGainMismatch, INFO, ID, chain = 140);
