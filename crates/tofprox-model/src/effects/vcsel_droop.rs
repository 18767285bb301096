//! `vcsel_droop`: VCSEL power droop over successive raw images (thesis 3.3.7.2,
//! 5.1.2.1 ('varying emission power during exposure of several raw images')).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law: the relative optical power of a
//! raw image ([`droop_factor`], [`droop_loss`], the shape form's duty cycle
//! [`DutyCycle`]: the thermal step response superposed over the raw images'
//! on- and off-times), which the simulator and the lab's fit call.

use std::collections::BTreeMap;

use crate::config::ModelConfig;
use crate::effects::shape::ShapeLaw;
use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(vcsel_droop {
    DROOP_REL = "droop_rel",
    TAU_US = "tau_us",
    EXPOSURE_POWER = "exposure_power",
    FIRST_IMAGE_INDEX = "first_image_index",
});

/// The capture condition (`[capture.conditions]`) that gives the VCSEL's
/// off-time between two raw images of one acquisition in µs — read-out and
/// set-up, where the VCSEL cools. A recording that does not state it has
/// no gap (0 µs; our assumption: gaps short against the thermal response).
pub const IMAGE_GAP_CONDITION: &str = "image_gap_us";

/// When the VCSEL emits during one acquisition (3.3.7.2: it heats while it
/// emits and cools while it does not): raw image j is lit during
/// [j·(t_exp + g), j·(t_exp + g) + t_exp] µs. Our assumptions: equal gaps
/// g between the raw images, and each acquisition starts cold (the pause
/// between acquisitions is long against the thermal response).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DutyCycle {
    /// On-time (exposure) of each raw image, µs.
    pub exposure_us: f64,
    /// Off-time between two raw images, µs (≥ 0).
    pub gap_us: f64,
}

impl DutyCycle {
    /// The duty cycle of raw images of `exposure_us` with gaps of `gap_us`
    /// (a negative or non-finite gap counts as none).
    pub fn new(exposure_us: f64, gap_us: f64) -> Self {
        let gap_us = if gap_us.is_finite() {
            gap_us.max(0.0)
        } else {
            0.0
        };
        Self {
            exposure_us,
            gap_us,
        }
    }

    /// The duty cycle of a capture of `exposure_us` whose conditions give
    /// the gap as [`IMAGE_GAP_CONDITION`] (none when they do not).
    pub fn of_capture(exposure_us: f64, conditions: &BTreeMap<String, f64>) -> Self {
        Self::new(
            exposure_us,
            conditions.get(IMAGE_GAP_CONDITION).copied().unwrap_or(0.0),
        )
    }

    /// The heating and cooling steps of the power history at the start of
    /// raw image `k`, for linear superposition of the thermal step response
    /// Z(τ) (the loss after τ µs of continuous emission from cold): `f(τ,
    /// +1)` for the loss already present at the first image (τ = 0) and
    /// for each earlier image j switching on τ = t_k − t_j ago, `f(τ, −1)`
    /// for it switching off τ = t_k − t_j − t_exp ago. L_k = Σ sign·Z(τ) —
    /// without gaps it telescopes to Z(k·t_exp), the on-time law.
    pub fn for_each_step(&self, k: usize, mut f: impl FnMut(f64, f64)) {
        f(0.0, 1.0);
        let period_us = self.exposure_us + self.gap_us;
        for j in 0..k {
            let on_us = (k - j) as f64 * period_us;
            f(on_us, 1.0);
            f(on_us - self.exposure_us, -1.0);
        }
    }

    /// The loss at the start of raw image `k` under the thermal step
    /// response `z`: Σ sign·Z(τ) over [`Self::for_each_step`].
    pub fn superpose(&self, k: usize, mut z: impl FnMut(f64) -> f64) -> f64 {
        let mut loss = 0.0;
        self.for_each_step(k, |tau_us, sign| loss += sign * z(tau_us));
        loss
    }
}

/// Relative optical power of raw image `k` (acquisition order) under
/// `vcsel_droop` for the acquisition's `duty` cycle: 1 − L_k with the
/// file's shape as the thermal step response Z(τ) of the on-time
/// ([`SHAPE_LAW`]) superposed over the raw images'
/// heating and cooling ([`DutyCycle::superpose`]) when it gives one, else
/// 1 − D·[`droop_loss`] (the parametric law counts on-time only: it ignores
/// the gaps).
pub fn droop_factor(model: &ModelConfig, k: usize, duty: DutyCycle) -> f64 {
    if !model.is_enabled(ID) {
        return 1.0;
    }
    if let Some(s) = model.shape(ID) {
        return 1.0
            - duty.superpose(k, |tau_us| {
                s.eval(DROOP_LOSS_REL, tau_us)
            });
    }
    let d = model.get(DROOP_REL);
    1.0 - d * droop_loss(
        k as f64,
        duty.exposure_us,
        model.get(TAU_US),
        model.get(EXPOSURE_POWER),
        model.get(FIRST_IMAGE_INDEX),
    )
}

/// The droop law's shape (3.3.7.2): the share 1 − exp(−(k + k₀)·s/τ) of the
/// asymptotic loss D reached at raw image `k`, s = 1 ms·(t_exp/1 ms)^β the
/// heating per image. P_k = P·(1 − D·droop_loss). The simulator and the lab's
/// fit both use this one function.
#[inline]
pub fn droop_loss(
    k: f64,
    exposure_us: f64,
    tau_us: f64,
    exposure_power: f64,
    first_image_index: f64,
) -> f64 {
    let s_us = 1000.0 * (exposure_us * 1e-3).powf(exposure_power);
    1.0 - (-(k + first_image_index) * s_us / tau_us.max(1e-9)).exp()
}

/// The catalogue entry of `vcsel_droop`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "VCSEL power droop over successive raw images",
    explanation: "The VCSEL heats while it emits; its optical power falls over successive raw images of one acquisition: P_k = P · (1 − D · (1 − exp(−(k + k₀) · s / τ))) for raw image k in acquisition order, with heating per image s = 1 ms · (t_exp / 1 ms)^β (β = 1: heating by on-time, s = t_exp; β = 0: by image count) and k₀ images of heating before the first one (k₀ = 1: the first image is already drooped). Unequal amplitudes of the images used together distort the phasor; 4-phase loses its 0/180 symmetry. Second form: the thermal step response Z(τ) — the loss after τ µs of continuous emission from cold — as a monotone shape, given by `shape_on_time_us` (knots, µs) and `shape_loss_rel` (values, Z < 1), linear between the knots and flat outside them; it replaces the parametric law. The loss of image k superposes the heating and cooling steps of the acquisition's duty cycle (each acquisition starting cold, raw image j lit during [j·(t_exp + g), j·(t_exp + g) + t_exp]): L_k = Z(0) + Σ_{j<k} [Z(t_k − t_j) − Z(t_k − t_j − t_exp)], P_k = P·(1 − L_k); the gap g is the capture condition `image_gap_us` (0 when the recording does not state it: then L_k = Z(k·t_exp), a shape of the on-time). The parametric law ignores the gaps.",
    thesis_ref: "3.3.7.2, 5.1.2.1 ('varying emission power during exposure of several raw images')",
    signature: "raw residual grows with raw-image index and with exposure; depth error with period 2π in phase",
    params: &[
        p(
            DROOP_REL,
            "",
            0.03,
            0.0,
            0.5,
            "asymptotic relative power loss D",
        ),
        p(
            TAU_US,
            "us",
            3000.0,
            1.0,
            1e7,
            "thermal time constant τ of the droop (in accumulated exposure)",
        ),
        p(
            EXPOSURE_POWER,
            "1",
            1.0,
            0.0,
            2.0,
            "β: heating per raw image ∝ exposure^β (1: on-time, 0: image count)",
        ),
        p(
            FIRST_IMAGE_INDEX,
            "1",
            0.0,
            0.0,
            8.0,
            "k₀: raw images of heating before the first (1: the first image already drooped)",
        ),
    ],
    in_baseline: false,
    acts_on: ActsOn::Signal,
    drivers: &[Driver::ImageIndex],
    cancels_in_four_phase: false,
};

/// `vcsel_droop`: the thermal step response Z(τ) of the VCSEL's power — the
/// relative loss after τ µs of continuous emission from cold — superposed
/// over the raw images' on- and off-times
/// ([`DutyCycle`]; 3.3.7.2: the VCSEL heats
/// *while it emits* and cools in the gaps between raw images): P_k =
/// P·(1 − L_k), L_k = Z(0) + Σ_{j<k} [Z(t_k − t_j) − Z(t_k − t_j − t_exp)].
/// Without gaps L_k = Z(k·t_exp), the on-time law (the parametric law with
/// β = 1, k₀ = 0 has the same driver). Not the image index: one curve
/// serves every exposure and gap of a recording, where a curve of k would
/// need one per exposure; a droop per image whatever the exposure (β = 0)
/// stays the parametric form's.
pub const SHAPE_LAW: ShapeLaw = ShapeLaw {
    effect: ID,
    driver: "shape_on_time_us",
    driver_doc: "the time τ in µs since a step of the VCSEL's emission (its thermal step response Z(τ))",
    curves: &[DROOP_LOSS_REL],
    bounds: droop_bounds,
};
/// `vcsel_droop`'s curve: the relative power loss L (< 1).
pub const DROOP_LOSS_REL: &str = "shape_loss_rel";

/// The loss curve's bound: a power loss below 1 (the power 1 − L stays positive).
fn droop_bounds(_key: &str, v: &[f64]) -> Result<(), String> {
    match v.iter().find(|l| **l >= 1.0) {
        Some(l) => Err(format!("power loss {l} would make the power 1 − L ≤ 0")),
        None => Ok(()),
    }
}

effect!(VcselDroop, INFO, ID, chain = 60, shape = SHAPE_LAW);
