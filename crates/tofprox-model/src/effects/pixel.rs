//! A pixel's per-capture constants ([`PixelParams`]) resolved from the model by
//! the laws of the pixel effects (`sbi_asymmetry`, `amplitude_phase_error`,
//! `temperature_drift`, `dark_current`, each in its own module) and the noise
//! variances of [`crate::effects::noise`] (2.3.2).

use crate::config::ModelConfig;
use crate::effects::amplitude_phase_error::AmpPhaseLaw;
use crate::effects::dark_current::dark_current_temperature_factor;
use crate::effects::sbi_asymmetry::SbiLaw;
use crate::effects::temperature_drift::temperature_drift_of;
use crate::ids;

/// Boltzmann constant in J/K.
pub const BOLTZMANN_J_PER_K: f64 = 1.380_649e-23;
/// Elementary charge in C.
pub const ELEMENTARY_CHARGE_C: f64 = 1.602_176_634e-19;

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
        let sbi = on(crate::effects::sbi_asymmetry::ID).then(|| {
            (
                model.get(crate::effects::sbi_asymmetry::MISMATCH_REL),
                SbiLaw::of(model),
            )
        });
        let amp_phase = on(crate::effects::amplitude_phase_error::ID).then(|| AmpPhaseLaw::of(model));
        let (drift_rad, drift_gain) = if on(crate::effects::temperature_drift::ID) {
            let (phase, gain) = temperature_drift_of(model, temperature_c);
            (phase, (1.0 + gain).max(0.0))
        } else {
            (0.0, 1.0)
        };
        // eq. 2.17 with i_d(T) = i_d,25 · 2^((T − 25)/ΔT₂)
        let dark_e = if on(crate::effects::dark_current::ID) {
            model.get(crate::effects::dark_current::E_PER_US)
                * exposure_us
                * dark_current_temperature_factor(
                    temperature_c - 25.0,
                    model.get(crate::effects::dark_current::DOUBLING_C),
                )
        } else {
            0.0
        };
        let shot_f = if on(crate::effects::shot_noise::ID) {
            model.get(crate::effects::shot_noise::EXCESS_NOISE_FACTOR)
        } else {
            0.0
        };
        // eq. 2.15: σ_kTC = √(k T C) / e
        let ktc_var_e2 = if on(crate::effects::ktc_noise::ID) {
            let t_k = temperature_c + 273.15;
            BOLTZMANN_J_PER_K * t_k * model.get(crate::effects::ktc_noise::C_INT_FF) * 1e-15
                / (ELEMENTARY_CHARGE_C * ELEMENTARY_CHARGE_C)
        } else {
            0.0
        };
        let read_var_lsb2 = if on(crate::effects::read_noise::ID) {
            model.get(crate::effects::read_noise::SIGMA_LSB).powi(2)
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
            dark_shot: on(crate::effects::dark_current::ID),
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
