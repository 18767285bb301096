//! `demodulation_contrast`: Demodulation contrast (thesis 2.2.2.2, eq. 2.10-2.11).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law, the
//! correlation scaled by K, is evaluated inline by the simulator ([`crate::sim`]).

use crate::entry::{ActsOn, EffectInfo, param as p};

crate::ids::effect_ids!(demodulation_contrast {
    CONTRAST = "contrast",
});

/// The catalogue entry of `demodulation_contrast`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "Demodulation contrast",
    explanation: "Only a share K of the photo-generated charge is separated by the modulation gates; the rest adds equally to both taps: N_A,B = N/2 · (1 ± K·C(φ−θ)). K is eq. 2.10/2.11's demodulation contrast. Disabled, K = 1.",
    thesis_ref: "2.2.2.2, eq. 2.10-2.11",
    signature: "amplitude scales by K at constant intensity; no phase change",
    params: &[p(
        CONTRAST,
        "",
        0.8,
        0.05,
        1.0,
        "demodulation contrast K",
    )],
    in_baseline: true,
    acts_on: ActsOn::Signal,
    drivers: &[],
    cancels_in_four_phase: false,
};

effect!(DemodulationContrast, INFO, ID, chain = 20);
