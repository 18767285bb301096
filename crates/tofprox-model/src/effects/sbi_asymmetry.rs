//! `sbi_asymmetry`: SBI circuit with mismatch (thesis 2.2.2.1, 5.1.2.3 (fig. 5.6-5.8)).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law:
//! the charge the circuit removes from each tap ([`sbi_injected_e`]) or the
//! file's shape of it ([`SbiLaw`]), which the simulator and the lab's fit call.

use crate::config::ModelConfig;
use crate::effects::shape::ShapeLaw;
use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(sbi_asymmetry {
    THRESHOLD_E = "threshold_e",
    MISMATCH_REL = "mismatch_rel",
    CLAMP_SHARE = "clamp_share",
});

/// Charge the SBI circuit injects into each tap (2.2.2.1, fig. 2.7, 5.1.2.3),
/// for tap charges `n_a`, `n_b` collected at constant rates: the fuller tap
/// reaches the threshold Q_th at t_on = Q_th/r_max; from then on the circuit
/// injects r_inj = (1 − s)·r_min + s·r_max into both taps, so
/// N_inj = [(1 − s)·N_min + s·N_max]·(1 − Q_th/N_max) (0 below the
/// threshold). `clamp_share` s = 0 subtracts the common (smaller) current,
/// the thesis' circuit; s = 1 clamps the fuller tap at Q_th
/// (N_inj = N_max − Q_th); between, a mixture. The injection is common to
/// both taps and cannot remove more charge than the emptier tap holds:
/// N_inj ≤ N_min (a clamp whose fuller tap runs Q_th + N_min above the
/// threshold empties the other tap and stops there). Mismatch m of the
/// injection leaves −m·N_inj in the differential charge.
#[inline]
pub fn sbi_injected_e(n_a: f64, n_b: f64, threshold_e: f64, clamp_share: f64) -> f64 {
    let hi = n_a.max(n_b);
    let lo = n_a.min(n_b).max(0.0);
    if hi > threshold_e && hi > 0.0 {
        let s = clamp_share.clamp(0.0, 1.0);
        (((1.0 - s) * lo + s * hi) * (1.0 - threshold_e / hi)).min(lo)
    } else {
        0.0
    }
}

/// The SBI's law (2.2.2.1, 5.1.2.3) in one of its two forms: the charge it
/// removes from each tap; the mismatch m leaves −m times it in the
/// differential charge.
#[derive(Debug, Clone, PartialEq)]
pub enum SbiLaw {
    /// The circuit of [`sbi_injected_e`]: (threshold Q_th in e⁻, clamp share s).
    Circuit(f64, f64),
    /// The removed charge as a monotone shape of the fuller tap's charge
    /// ([`SHAPE_LAW`]): knots (e⁻) and values (e⁻).
    Shape(Vec<f64>, Vec<f64>),
}

impl SbiLaw {
    /// The law of `model`'s `sbi_asymmetry` (its shape when the file gives one).
    pub fn of(model: &ModelConfig) -> Self {
        if let Some(s) = model.shape(ID) {
            return Self::Shape(s.knots.clone(), s.values(SBI_REMOVED_E));
        }
        Self::Circuit(
            model.get(THRESHOLD_E),
            model.get(CLAMP_SHARE),
        )
    }

    /// The charge removed from each tap (e⁻) for tap charges `n_a`, `n_b`:
    /// never more than the emptier tap holds, in either form.
    #[inline]
    pub fn removed_e(&self, n_a: f64, n_b: f64) -> f64 {
        match self {
            Self::Circuit(q_th, s) => sbi_injected_e(n_a, n_b, *q_th, *s),
            Self::Shape(knots, values) => {
                crate::effects::shape::sbi_removed_e(knots, values, n_a, n_b)
            }
        }
    }
}

/// The catalogue entry of `sbi_asymmetry`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "SBI circuit with mismatch",
    explanation: "The suppression-of-background-illumination circuit (fig. 2.7) monitors both taps; once the fuller tap passes the threshold Q_th (at t_on = Q_th / r_max) it injects a common current into both taps: the smaller photo-current (clamp_share s = 0, the thesis' circuit: it subtracts the common part) or, towards s = 1, the larger one (a clamp that holds the fuller tap at Q_th); r_inj = (1 − s)·r_min + s·r_max, never removing more charge than the emptier tap holds (N_inj ≤ N_min). Mismatch m between the two injection transistors leaves a differential error ΔN = −m · r_inj · (t_exp − t_on). The error depends on |C(φ−θ)| and is identical in the 0°/180° (90°/270°) images, so 4-phase cancels it and 2-phase does not (fig. 5.6-5.8). Second form, a clamp with a knee of any shape: the charge removed from each tap as a monotone shape of the fuller tap's charge, `shape_tap_charge_e` (knots, e⁻) and `shape_removed_e` (values, e⁻, 0 at the first knot where the circuit starts, non-decreasing), linear between the knots, never more than the emptier tap holds; it replaces threshold_e and clamp_share (the mismatch m stays).",
    thesis_ref: "2.2.2.1, 5.1.2.3 (fig. 5.6-5.8)",
    signature: "2-phase-only depth error rising with ambient_klux and exposure above a threshold; 4-phase unaffected",
    params: &[
        p(
            THRESHOLD_E,
            "e-",
            60000.0,
            100.0,
            1e8,
            "tap charge Q_th at which the SBI starts to inject",
        ),
        p(
            MISMATCH_REL,
            "",
            0.03,
            -0.3,
            0.3,
            "relative mismatch m of the injected currents between tap A and B",
        ),
        p(
            CLAMP_SHARE,
            "",
            0.0,
            0.0,
            1.0,
            "s: 0 injects the smaller tap current (subtracts), 1 the larger (clamps the fuller tap at Q_th)",
        ),
    ],
    in_baseline: false,
    acts_on: ActsOn::Differential,
    drivers: &[Driver::AmbientKlux, Driver::ExposureUs, Driver::Amplitude],
    cancels_in_four_phase: true,
};

/// `sbi_asymmetry`: the charge R(N_max) in electrons the SBI circuit removes
/// from each tap (2.2.2.1, 5.1.2.3) as a function of the fuller tap's charge
/// N_max in electrons — a clamp with a knee of any shape (the clamp end of
/// the parametric family is R = N_max − Q_th). The first knot is where the
/// circuit starts: its value is 0 and the curve does not decrease, so
/// nothing is removed below it. As in the parametric law the removal is
/// common to both taps and never more than the emptier tap holds
/// ([`crate::effects::shape::sbi_removed_e`]); the mismatch `mismatch_rel` leaves −m·R in the
/// differential charge (`threshold_e` and `clamp_share` are unused).
pub const SHAPE_LAW: ShapeLaw = ShapeLaw {
    effect: ID,
    driver: "shape_tap_charge_e",
    driver_doc: "the fuller tap's charge N_max in electrons",
    curves: &[SBI_REMOVED_E],
    bounds: sbi_bounds,
};
/// `sbi_asymmetry`'s curve: the charge removed from each tap, e⁻.
pub const SBI_REMOVED_E: &str = "shape_removed_e";

/// The removed charge's bounds: 0 on the first knot (where the circuit starts) and not
/// decreasing (the circuit removes more from a fuller tap).
fn sbi_bounds(_key: &str, v: &[f64]) -> Result<(), String> {
    if let Some(r) = v.first().filter(|r| **r != 0.0) {
        return Err(format!(
            "must start at 0 on the first knot (where the circuit starts), found {r}"
        ));
    }
    if v.windows(2).any(|w| w[1] < w[0]) {
        return Err("must not decrease: the circuit removes more from a fuller tap".into());
    }
    Ok(())
}

effect!(SbiAsymmetry, INFO, ID, chain = 130, shape = SHAPE_LAW);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sbi_family_subtracts_clamps_and_never_empties_a_tap_below_zero() {
        // below the threshold nothing is injected, whatever the circuit
        assert_eq!(sbi_injected_e(900.0, 500.0, 1000.0, 0.0), 0.0);
        assert_eq!(sbi_injected_e(900.0, 500.0, 1000.0, 1.0), 0.0);
        // s = 0: the thesis' circuit, N_min·(1 − Q_th/N_max)
        let sub = sbi_injected_e(2000.0, 1500.0, 1000.0, 0.0);
        assert!((sub - 1500.0 * 0.5).abs() < 1e-9, "{sub}");
        // s = 1: the fuller tap is held at Q_th: N_max − Q_th
        let clamp = sbi_injected_e(1500.0, 2000.0, 1000.0, 1.0);
        assert!((clamp - 1000.0).abs() < 1e-9, "{clamp}");
        // between: the mixture, monotone in s
        let mid = sbi_injected_e(2000.0, 1500.0, 1000.0, 0.5);
        assert!(sub < mid && mid < clamp, "{sub} {mid} {clamp}");
        // a clamp far above the threshold cannot remove more than the emptier tap holds
        let deep = sbi_injected_e(9000.0, 300.0, 1000.0, 1.0);
        assert!((deep - 300.0).abs() < 1e-9, "{deep}");
        for s in [0.0, 0.3, 1.0] {
            for (a, b) in [(5000.0, 10.0), (1200.0, 1100.0), (4e4, 2e4)] {
                let inj = sbi_injected_e(a, b, 1000.0, s);
                assert!((0.0..=b).contains(&inj), "s {s}: {inj} from taps {a}, {b}");
            }
        }
    }
}
