//! `waveform_harmonics`: Non-sinusoidal correlation (wiggling) (thesis 2.3.1.1,
//! 3.2.2, 3.3.6, 5.1.2.1 (fig. 3.10, 3.11, 5.1)).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law is the correlation waveform's shape
//! (`effects::correlation::Correlation`); its parameters
//! ([`HARMONIC_PARAMS`]) and optional waveform files are here.

use crate::entry::{ActsOn, Driver, EffectInfo, ParamInfo, param as p};
use crate::ids::ParamId;

crate::ids::effect_ids!(waveform_harmonics {});

const fn harmonic_param(name: &'static str) -> ParamId {
    ParamId::new(ID.as_str(), name)
}

/// `waveform_harmonics` amplitudes relative to the fundamental, `h2_rel … h9_rel`.
pub const HARMONIC_REL: [ParamId; 8] = [
    harmonic_param("h2_rel"),
    harmonic_param("h3_rel"),
    harmonic_param("h4_rel"),
    harmonic_param("h5_rel"),
    harmonic_param("h6_rel"),
    harmonic_param("h7_rel"),
    harmonic_param("h8_rel"),
    harmonic_param("h9_rel"),
];

/// `waveform_harmonics` phases, `h2_phase_deg … h9_phase_deg`.
pub const HARMONIC_PHASE_DEG: [ParamId; 8] = [
    harmonic_param("h2_phase_deg"),
    harmonic_param("h3_phase_deg"),
    harmonic_param("h4_phase_deg"),
    harmonic_param("h5_phase_deg"),
    harmonic_param("h6_phase_deg"),
    harmonic_param("h7_phase_deg"),
    harmonic_param("h8_phase_deg"),
    harmonic_param("h9_phase_deg"),
];

/// Harmonic `n` (2..=9) of `waveform_harmonics`: amplitude relative to the fundamental
/// (`h<n>_rel`) and phase (`h<n>_phase_deg`); `None` outside 2..=9.
pub fn harmonic(n: usize) -> Option<(ParamId, ParamId)> {
    let i = n.checked_sub(2)?;
    Some((*HARMONIC_REL.get(i)?, *HARMONIC_PHASE_DEG.get(i)?))
}

/// Harmonic parameters `h2_rel … h9_rel`, `h2_phase_deg … h9_phase_deg`.
/// Typical values: the odd harmonics of the measured-like VCSEL/pulse correlation
/// (`effects::correlation::measured_like_waveforms`, about ±6 mm wiggling at
/// 80 MHz), plus small even harmonics of a slightly asymmetric duty cycle.
pub static HARMONIC_PARAMS: &[ParamInfo] = &[
    p(
        HARMONIC_REL[0],
        "",
        0.008,
        0.0,
        0.5,
        "2nd harmonic amplitude relative to the fundamental (duty-cycle asymmetry)",
    ),
    p(
        HARMONIC_PHASE_DEG[0],
        "deg",
        0.0,
        -180.0,
        180.0,
        "2nd harmonic phase",
    ),
    p(
        HARMONIC_REL[1],
        "",
        0.023,
        0.0,
        0.5,
        "3rd harmonic amplitude relative to the fundamental",
    ),
    p(
        HARMONIC_PHASE_DEG[1],
        "deg",
        28.0,
        -180.0,
        180.0,
        "3rd harmonic phase",
    ),
    p(
        HARMONIC_REL[2],
        "",
        0.002,
        0.0,
        0.5,
        "4th harmonic amplitude relative to the fundamental",
    ),
    p(
        HARMONIC_PHASE_DEG[2],
        "deg",
        0.0,
        -180.0,
        180.0,
        "4th harmonic phase",
    ),
    p(
        HARMONIC_REL[3],
        "",
        0.0032,
        0.0,
        0.5,
        "5th harmonic amplitude relative to the fundamental",
    ),
    p(
        HARMONIC_PHASE_DEG[3],
        "deg",
        54.0,
        -180.0,
        180.0,
        "5th harmonic phase",
    ),
    p(
        HARMONIC_REL[4],
        "",
        0.0005,
        0.0,
        0.5,
        "6th harmonic amplitude relative to the fundamental",
    ),
    p(
        HARMONIC_PHASE_DEG[4],
        "deg",
        0.0,
        -180.0,
        180.0,
        "6th harmonic phase",
    ),
    p(
        HARMONIC_REL[5],
        "",
        0.0009,
        0.0,
        0.5,
        "7th harmonic amplitude relative to the fundamental",
    ),
    p(
        HARMONIC_PHASE_DEG[5],
        "deg",
        79.0,
        -180.0,
        180.0,
        "7th harmonic phase",
    ),
    p(
        HARMONIC_REL[6],
        "",
        0.0002,
        0.0,
        0.5,
        "8th harmonic amplitude relative to the fundamental",
    ),
    p(
        HARMONIC_PHASE_DEG[6],
        "deg",
        0.0,
        -180.0,
        180.0,
        "8th harmonic phase",
    ),
    p(
        HARMONIC_REL[7],
        "",
        0.0003,
        0.0,
        0.5,
        "9th harmonic amplitude relative to the fundamental",
    ),
    p(
        HARMONIC_PHASE_DEG[7],
        "deg",
        103.0,
        -180.0,
        180.0,
        "9th harmonic phase",
    ),
];

/// Optional string keys of `waveform_harmonics` (file paths, relative to the model file).
pub static WAVEFORM_FILE_KEYS: &[&str] = &["illumination_file", "modulation_file"];

/// The catalogue entry of `waveform_harmonics`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "Non-sinusoidal correlation (wiggling)",
    explanation: "Illumination and modulation are rectangular-like, so the correlation is C(x) = cos x + Σ_{n=2..9} r_n cos(n x + ψ_n) (normalised to |C| ≤ 1) instead of cos x. 4-phase sampling aliases odd harmonics 3, 5 onto the fundamental and produces the circular 'wiggling' depth error with 4 periods per 2π; even harmonics (duty-cycle asymmetry) cancel in 4-phase but not in 2-phase. Alternatively C is computed from measured illumination and modulation waveforms (one period each, CSV or NPY) by circular cross-correlation C(τ) = ⟨s(t) · (2 r(t+τ) − 1)⟩.",
    thesis_ref: "2.3.1.1, 3.2.2, 3.3.6, 5.1.2.1 (fig. 3.10, 3.11, 5.1)",
    signature: "depth error periodic in phase (period π/2 for 4-phase, plus π for 2-phase), independent of exposure and amplitude",
    params: HARMONIC_PARAMS,
    in_baseline: true,
    acts_on: ActsOn::Correlation,
    drivers: &[Driver::Phase, Driver::DistanceM],
    cancels_in_four_phase: false,
};

effect!(WaveformHarmonics, INFO, ID, chain = 30);
