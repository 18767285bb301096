//! Pixel effects: `sbi_asymmetry`, `amplitude_phase_error`, `temperature_drift`,
//! `dark_current`, and the noise sources `shot_noise`, `ktc_noise`, `read_noise`.

use crate::config::ModelConfig;
use crate::ids;

/// Boltzmann constant in J/K.
pub const BOLTZMANN_J_PER_K: f64 = 1.380_649e-23;
/// Elementary charge in C.
pub const ELEMENTARY_CHARGE_C: f64 = 1.602_176_634e-19;

/// The saturating law of `amplitude_phase_error` (2.3.1.2, fig. 2.9) as the
/// share of φ_max left at x = A/A_ref: 1 − x/(1 + xⁿ)^(1/n). n = 1 is the
/// hyperbolic A_ref/(A_ref + A); larger n saturate more sharply. The
/// simulator and the lab's fit both use this one function.
#[inline]
pub fn amplitude_phase_shape(x: f64, n: f64) -> f64 {
    if n == 1.0 {
        return 1.0 / (1.0 + x);
    }
    1.0 - x / (1.0 + x.powf(n)).powf(1.0 / n)
}

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

/// The powers of ΔT = T − T_ref the temperature drift is a polynomial in:
/// [ΔT, ΔT²] (catalogue `temperature_drift`).
pub fn temperature_drift_terms(dt: f64) -> [f64; 2] {
    [dt, dt * dt]
}

/// Temperature drift (catalogue `temperature_drift`, thesis 3.1):
/// Δφ = k_φ·ΔT + k_φ2·ΔT² (rad) and the relative gain change
/// k_g·ΔT + k_g2·ΔT², from the coefficients per K and per K²
/// (`phase_rad_per_k` = [k_φ, k_φ2], `gain_per_k` = [k_g, k_g2]).
pub fn temperature_drift(dt: f64, phase_rad_per_k: [f64; 2], gain_per_k: [f64; 2]) -> (f64, f64) {
    let t = temperature_drift_terms(dt);
    (
        phase_rad_per_k[0] * t[0] + phase_rad_per_k[1] * t[1],
        gain_per_k[0] * t[0] + gain_per_k[1] * t[1],
    )
}

/// The temperature factor of the dark current (`dark_current`, eq. 2.17 with
/// i_d(T) = i_d,ref · 2^(ΔT/ΔT₂)): 2^(ΔT/ΔT₂) for ΔT = T − T_ref kelvin and the
/// doubling ΔT₂ (`doubling_c`). The simulator and the lab's fit both use it.
#[inline]
pub fn dark_current_temperature_factor(dt_k: f64, doubling_k: f64) -> f64 {
    2f64.powf(dt_k / doubling_k.max(1e-6))
}

/// The differential charge a tap gain mismatch ε leaks from the total charge
/// (`tap_gain_mismatch`, eq. 2.1): D = (1 + ε/2)·N_A − (1 − ε/2)·N_B adds
/// ε/2 · (N_A + N_B). The simulator and the lab's fit both use it.
#[inline]
pub fn tap_gain_leak_e(mismatch_rel: f64, total_e: f64) -> f64 {
    0.5 * mismatch_rel * total_e
}

/// The amplitude-phase error's law (2.3.1.2) in one of its two forms.
#[derive(Debug, Clone, PartialEq)]
pub enum AmpPhaseLaw {
    /// φ_max · s(A/A_ref; n) ([`amplitude_phase_shape`]): (max_rad, reference_e, n).
    Saturating(f64, f64, f64),
    /// Δφ(A) as a monotone shape of the amplitude in electrons
    /// ([`crate::effects::shape::AMPLITUDE_PHASE`]): knots (e) and values (rad).
    Shape(Vec<f64>, Vec<f64>),
}

impl AmpPhaseLaw {
    /// The law of `model`'s `amplitude_phase_error` (its shape when the file gives one).
    pub fn of(model: &ModelConfig) -> Self {
        use crate::effects::shape::AMPLITUDE_PHASE_RAD;
        if let Some(s) = model.shape(ids::amplitude_phase_error::ID) {
            return Self::Shape(s.knots.clone(), s.values(AMPLITUDE_PHASE_RAD));
        }
        Self::Saturating(
            model.get(ids::amplitude_phase_error::MAX_RAD),
            model.get(ids::amplitude_phase_error::REFERENCE_E),
            model.get(ids::amplitude_phase_error::SHAPE),
        )
    }

    /// Δφ in rad at the differential amplitude `amplitude_e` (electrons, ≥ 0).
    #[inline]
    pub fn phase_rad(&self, amplitude_e: f64) -> f64 {
        let a = amplitude_e.max(0.0);
        match self {
            Self::Saturating(max_rad, reference_e, n) => {
                max_rad * amplitude_phase_shape(a / reference_e, *n)
            }
            Self::Shape(knots, values) => crate::effects::shape::eval(knots, values, a),
        }
    }
}

/// Temperature drift (catalogue `temperature_drift`, thesis 3.1) of `model`
/// at `temperature_c`: (Δφ in rad, relative gain change G), by the file's
/// shape of T when it gives one ([`crate::effects::shape::TEMPERATURE_DRIFT`]),
/// else by the polynomial in ΔT = T − T_ref ([`temperature_drift`]).
pub fn temperature_drift_of(model: &ModelConfig, temperature_c: f64) -> (f64, f64) {
    use crate::effects::shape::{DRIFT_GAIN_REL, DRIFT_PHASE_RAD};
    use ids::temperature_drift as td;
    if let Some(s) = model.shape(td::ID) {
        return (
            s.eval(DRIFT_PHASE_RAD, temperature_c),
            s.eval(DRIFT_GAIN_REL, temperature_c),
        );
    }
    temperature_drift(
        temperature_c - model.get(td::REFERENCE_C),
        [
            model.get(td::PHASE_MRAD_PER_K) * 1e-3,
            model.get(td::PHASE_MRAD_PER_K2) * 1e-3,
        ],
        [
            model.get(td::GAIN_REL_PER_K),
            model.get(td::GAIN_REL_PER_K2),
        ],
    )
}

/// The SBI's law (2.2.2.1, 5.1.2.3) in one of its two forms: the charge it
/// removes from each tap; the mismatch m leaves −m times it in the
/// differential charge.
#[derive(Debug, Clone, PartialEq)]
pub enum SbiLaw {
    /// The circuit of [`sbi_injected_e`]: (threshold Q_th in e⁻, clamp share s).
    Circuit(f64, f64),
    /// The removed charge as a monotone shape of the fuller tap's charge
    /// ([`crate::effects::shape::SBI_ASYMMETRY`]): knots (e⁻) and values (e⁻).
    Shape(Vec<f64>, Vec<f64>),
}

impl SbiLaw {
    /// The law of `model`'s `sbi_asymmetry` (its shape when the file gives one).
    pub fn of(model: &ModelConfig) -> Self {
        use crate::effects::shape::SBI_REMOVED_E;
        if let Some(s) = model.shape(ids::sbi_asymmetry::ID) {
            return Self::Shape(s.knots.clone(), s.values(SBI_REMOVED_E));
        }
        Self::Circuit(
            model.get(ids::sbi_asymmetry::THRESHOLD_E),
            model.get(ids::sbi_asymmetry::CLAMP_SHARE),
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

/// Per-capture constants of the pixel effects.
#[derive(Debug, Clone)]
pub struct PixelParams {
    /// SBI on: the mismatch m and the law of the removed charge.
    pub sbi: Option<(f64, SbiLaw)>,
    /// Amplitude-phase error, when on.
    pub amp_phase: Option<AmpPhaseLaw>,
    /// Phase drift in rad for this temperature.
    pub drift_rad: f64,
    /// Signal gain for this temperature.
    pub drift_gain: f64,
    /// Dark electrons per tap for this exposure and temperature.
    pub dark_e: f64,
    /// Shot noise excess factor (0 = shot noise off).
    pub shot_f: f64,
    /// Whether dark shot noise is present.
    pub dark_shot: bool,
    /// kTC noise variance per tap in e².
    pub ktc_var_e2: f64,
    /// Read noise variance in LSB².
    pub read_var_lsb2: f64,
}

impl PixelParams {
    /// Constants for one capture at `exposure_us` and `temperature_c`.
    pub fn new(model: &ModelConfig, exposure_us: f64, temperature_c: f64) -> Self {
        let on = |id: ids::EffectId| model.is_enabled(id);
        let sbi = on(ids::sbi_asymmetry::ID).then(|| {
            (
                model.get(ids::sbi_asymmetry::MISMATCH_REL),
                SbiLaw::of(model),
            )
        });
        let amp_phase = on(ids::amplitude_phase_error::ID).then(|| AmpPhaseLaw::of(model));
        let (drift_rad, drift_gain) = if on(ids::temperature_drift::ID) {
            let (phase, gain) = temperature_drift_of(model, temperature_c);
            (phase, (1.0 + gain).max(0.0))
        } else {
            (0.0, 1.0)
        };
        // eq. 2.17 with i_d(T) = i_d,25 · 2^((T − 25)/ΔT₂)
        let dark_e = if on(ids::dark_current::ID) {
            model.get(ids::dark_current::E_PER_US)
                * exposure_us
                * dark_current_temperature_factor(
                    temperature_c - 25.0,
                    model.get(ids::dark_current::DOUBLING_C),
                )
        } else {
            0.0
        };
        let shot_f = if on(ids::shot_noise::ID) {
            model.get(ids::shot_noise::EXCESS_NOISE_FACTOR)
        } else {
            0.0
        };
        // eq. 2.15: σ_kTC = √(k T C) / e
        let ktc_var_e2 = if on(ids::ktc_noise::ID) {
            let t_k = temperature_c + 273.15;
            BOLTZMANN_J_PER_K * t_k * model.get(ids::ktc_noise::C_INT_FF) * 1e-15
                / (ELEMENTARY_CHARGE_C * ELEMENTARY_CHARGE_C)
        } else {
            0.0
        };
        let read_var_lsb2 = if on(ids::read_noise::ID) {
            model.get(ids::read_noise::SIGMA_LSB).powi(2)
        } else {
            0.0
        };
        Self {
            sbi,
            amp_phase,
            drift_rad,
            drift_gain,
            dark_e,
            shot_f,
            dark_shot: on(ids::dark_current::ID),
            ktc_var_e2,
            read_var_lsb2,
        }
    }

    /// Amplitude-dependent phase error (2.3.1.2).
    #[inline]
    pub fn amplitude_phase_rad(&self, amplitude_e: f64) -> f64 {
        self.amp_phase
            .as_ref()
            .map_or(0.0, |law| law.phase_rad(amplitude_e))
    }

    /// SBI differential error in electrons for tap charges `n_a`, `n_b`
    /// (2.2.2.1, 5.1.2.3): −m · [`SbiLaw::removed_e`].
    #[inline]
    pub fn sbi_error_e(&self, n_a: f64, n_b: f64) -> f64 {
        match &self.sbi {
            Some((m, law)) => -m * law.removed_e(n_a, n_b),
            None => 0.0,
        }
    }
}

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
