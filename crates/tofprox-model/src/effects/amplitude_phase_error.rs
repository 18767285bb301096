//! `amplitude_phase_error`: Amplitude-dependent phase error (thesis 2.3.1.2 (fig. 2.9)).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law:
//! Δφ(A) in its saturating form ([`amplitude_phase_shape`]) or the file's shape
//! ([`AmpPhaseLaw`]), which the simulator and the lab's fit call.

use crate::config::ModelConfig;
use crate::effects::shape::ShapeLaw;
use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(amplitude_phase_error {
    MAX_RAD = "max_rad",
    REFERENCE_E = "reference_e",
    SHAPE = "shape",
});

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

/// The amplitude-phase error's law (2.3.1.2) in one of its two forms.
#[derive(Debug, Clone, PartialEq)]
pub enum AmpPhaseLaw {
    /// φ_max · s(A/A_ref; n) ([`amplitude_phase_shape`]): (max_rad, reference_e, n).
    Saturating(f64, f64, f64),
    /// Δφ(A) as a monotone shape of the amplitude in electrons
    /// ([`SHAPE_LAW`]): knots (e) and values (rad).
    Shape(Vec<f64>, Vec<f64>),
}

impl AmpPhaseLaw {
    /// The law of `model`'s `amplitude_phase_error` (its shape when the file gives one).
    pub fn of(model: &ModelConfig) -> Self {
        if let Some(s) = model.shape(ID) {
            return Self::Shape(s.knots.clone(), s.values(AMPLITUDE_PHASE_RAD));
        }
        Self::Saturating(
            model.get(MAX_RAD),
            model.get(REFERENCE_E),
            model.get(SHAPE),
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

/// The catalogue entry of `amplitude_phase_error`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "Amplitude-dependent phase error",
    explanation: "Non-linearity of pixel and read-out makes the phase depend on the signal amplitude (dark vs bright surfaces, fig. 2.9): Δφ = φ_max · (1 − x/(1 + xⁿ)^(1/n)), x = A/A_ref, A the differential amplitude in electrons. n = 1 is the hyperbolic law φ_max·A_ref/(A_ref + A); larger n saturate more sharply (n ≈ 2 is close to a tanh). Second form, where no member of the family fits: a monotone shape Δφ(A) given by `shape_amplitude_e` (knots, e⁻) and `shape_phase_rad` (values), linear between the knots and flat outside them; it replaces the parametric law.",
    thesis_ref: "2.3.1.2 (fig. 2.9)",
    signature: "depth error depending on amplitude (reflectivity, distance, exposure), not on phase",
    params: &[
        p(
            MAX_RAD,
            "rad",
            0.03,
            -0.5,
            0.5,
            "phase error φ_max in the limit of zero amplitude",
        ),
        p(
            REFERENCE_E,
            "e-",
            3000.0,
            1.0,
            1e10,
            "amplitude A_ref at which half of φ_max remains",
        ),
        p(
            SHAPE,
            "1",
            1.0,
            0.25,
            10.0,
            "sharpness n of the saturation (1: hyperbolic)",
        ),
    ],
    in_baseline: false,
    acts_on: ActsOn::Phasor,
    drivers: &[Driver::Amplitude, Driver::ExposureUs],
    cancels_in_four_phase: false,
};

/// `amplitude_phase_error`: Δφ(A) with A the differential signal amplitude
/// in electrons (the driver of the parametric law φ_max·s(A/A_ref; n)).
pub const SHAPE_LAW: ShapeLaw = ShapeLaw {
    effect: ID,
    driver: "shape_amplitude_e",
    driver_doc: "differential signal amplitude A in electrons",
    curves: &[AMPLITUDE_PHASE_RAD],
    bounds: crate::effects::shape::monotone_only,
};
/// `amplitude_phase_error`'s curve: Δφ in rad at each amplitude knot.
pub const AMPLITUDE_PHASE_RAD: &str = "shape_phase_rad";

effect!(AmplitudePhaseError, INFO, ID, chain = 90, shape = SHAPE_LAW);
