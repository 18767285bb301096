//! `temperature_drift`: Temperature drift of phase and gain (thesis 3.1
//! (temperature compensation step of fig. 3.1)).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law: the phase and gain drift with
//! temperature ([`temperature_drift`], [`temperature_drift_of`] with the file's
//! shape), which the simulator and the lab's fit call.

use crate::config::ModelConfig;
use crate::effects::shape::ShapeLaw;
use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(temperature_drift {
    PHASE_MRAD_PER_K = "phase_mrad_per_k",
    GAIN_REL_PER_K = "gain_rel_per_k",
    PHASE_MRAD_PER_K2 = "phase_mrad_per_k2",
    GAIN_REL_PER_K2 = "gain_rel_per_k2",
    REFERENCE_C = "reference_c",
});

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

/// Temperature drift (catalogue `temperature_drift`, thesis 3.1) of `model`
/// at `temperature_c`: (Δφ in rad, relative gain change G), by the file's
/// shape of T when it gives one ([`SHAPE_LAW`]),
/// else by the polynomial in ΔT = T − T_ref ([`temperature_drift`]).
pub fn temperature_drift_of(model: &ModelConfig, temperature_c: f64) -> (f64, f64) {
    if let Some(s) = model.shape(ID) {
        return (
            s.eval(DRIFT_PHASE_RAD, temperature_c),
            s.eval(DRIFT_GAIN_REL, temperature_c),
        );
    }
    temperature_drift(
        temperature_c - model.get(REFERENCE_C),
        [
            model.get(PHASE_MRAD_PER_K) * 1e-3,
            model.get(PHASE_MRAD_PER_K2) * 1e-3,
        ],
        [
            model.get(GAIN_REL_PER_K),
            model.get(GAIN_REL_PER_K2),
        ],
    )
}

/// The catalogue entry of `temperature_drift`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "Temperature drift of phase and gain",
    explanation: "Driver and VCSEL delays and the responsivity change with temperature: Δφ = k_φ·ΔT + k_φ2·ΔT², gain ×(1 + k_g·ΔT + k_g2·ΔT²), ΔT = T − T_ref. The second-order terms describe a drift that bends (delays and responsivity that change faster when hot); 0 gives the linear law. T is the capture's temperature_c. Second form: monotone shapes of T itself given by `shape_temperature_c` (knots, °C) with `shape_phase_rad` (Δφ) and `shape_gain_rel` (G), linear between the knots and flat outside them; they replace the polynomial (and its reference_c).",
    thesis_ref: "3.1 (temperature compensation step of fig. 3.1)",
    signature: "depth offset and amplitude change with temperature_c (linear, or bending with the second-order terms)",
    params: &[
        p(
            PHASE_MRAD_PER_K,
            "mrad/K",
            1.5,
            -100.0,
            100.0,
            "phase drift k_φ",
        ),
        p(
            GAIN_REL_PER_K,
            "1/K",
            -0.002,
            -0.05,
            0.05,
            "relative signal drift k_g",
        ),
        p(
            PHASE_MRAD_PER_K2,
            "mrad/K^2",
            0.0,
            -5.0,
            5.0,
            "second-order phase drift k_φ2",
        ),
        p(
            GAIN_REL_PER_K2,
            "1/K^2",
            0.0,
            -0.002,
            0.002,
            "second-order relative signal drift k_g2",
        ),
        p(
            REFERENCE_C,
            "degC",
            25.0,
            -40.0,
            125.0,
            "temperature T_ref without drift",
        ),
    ],
    in_baseline: false,
    acts_on: ActsOn::Phasor,
    drivers: &[Driver::TemperatureC],
    cancels_in_four_phase: false,
};

/// `temperature_drift`: Δφ(T) and the relative gain change G(T) (gain
/// ×(1 + G)) at the capture's temperature T in °C — absolute temperatures,
/// so the shape needs no reference (`reference_c` belongs to the polynomial).
pub const SHAPE_LAW: ShapeLaw = ShapeLaw {
    effect: ID,
    driver: "shape_temperature_c",
    driver_doc: "the capture's temperature T in °C",
    curves: &[DRIFT_PHASE_RAD, DRIFT_GAIN_REL],
    bounds: drift_bounds,
};
/// `temperature_drift`'s phase curve Δφ in rad.
pub const DRIFT_PHASE_RAD: &str = "shape_phase_rad";
/// `temperature_drift`'s gain curve G (gain ×(1 + G), G > −1).
pub const DRIFT_GAIN_REL: &str = "shape_gain_rel";

/// The gain curve's bound: a gain change above −1 (gain ×(1 + G) stays positive).
fn drift_bounds(key: &str, v: &[f64]) -> Result<(), String> {
    match v.iter().find(|g| **g <= -1.0) {
        Some(g) if key == DRIFT_GAIN_REL => {
            Err(format!("gain change {g} would make the gain 1 + G ≤ 0"))
        }
        _ => Ok(()),
    }
}

effect!(TemperatureDrift, INFO, ID, chain = 100, shape = SHAPE_LAW);
