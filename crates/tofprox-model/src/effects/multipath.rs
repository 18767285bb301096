//! `multipath`: Multipath return (thesis not treated in the thesis (extension;
//! standard iToF error)).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law: the second return's phase offset
//! ([`multipath_phase_offset_rad`]), which the simulator and the lab's fit call.

use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(multipath {
    RELATIVE_AMPLITUDE = "relative_amplitude",
    EXTRA_PATH_M = "extra_path_m",
});

/// The phase offset of the multipath's second return (`multipath`): an extra
/// round-trip path L arrives like an extra distance L/2 (eq. 2.6 inverted),
/// Δφ₂ = (4π f / c) · L/2 with `phase_rad_per_m` = 4π f / c. The second return
/// adds a·N electrons at φ + Δφ₂, its taps N/2·(1 ± K·C(φ + Δφ₂ − θ)) like the
/// direct one's. The simulator and the lab's fit both use it.
#[inline]
pub fn multipath_phase_offset_rad(phase_rad_per_m: f64, extra_path_m: f64) -> f64 {
    phase_rad_per_m * extra_path_m / 2.0
}

/// The catalogue entry of `multipath`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "Multipath return",
    explanation: "A second, weaker return travels a longer path (e.g. via the floor or a side wall) and mixes into the pixel: N_2 = a · N_sig at phase φ₂ = 4π f (d + Δ/2) / c. The measured phasor is the sum of both, so the depth is pulled towards the longer path by an amount oscillating with distance.",
    thesis_ref: "not treated in the thesis (extension; standard iToF error)",
    signature: "depth error oscillating with distance with period c/(2f) scaled by path difference; same in 2- and 4-phase",
    params: &[
        p(
            RELATIVE_AMPLITUDE,
            "",
            0.08,
            0.0,
            1.0,
            "amplitude of the second return relative to the direct one",
        ),
        p(
            EXTRA_PATH_M,
            "m",
            0.4,
            0.0,
            20.0,
            "additional round-trip path length of the second return",
        ),
    ],
    in_baseline: false,
    acts_on: ActsOn::Signal,
    drivers: &[Driver::DistanceM],
    cancels_in_four_phase: false,
};

effect!(Multipath, INFO, ID, chain = 40);
