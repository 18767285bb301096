//! `vcsel_droop`: VCSEL power droop over successive raw images (thesis 3.3.7.2,
//! 5.1.2.1 ('varying emission power during exposure of several raw images')).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law: the relative optical power of a
//! raw image ([`droop_factor`], [`droop_loss`], the shape form's driver
//! [`droop_on_time_us`]), which the simulator and the lab's fit call.

use crate::catalogue::{ActsOn, Driver, EffectInfo, param as p};
use crate::config::ModelConfig;
use crate::ids;

/// Relative optical power of raw image `k` (acquisition order) under
/// `vcsel_droop`: 1 − L(t_on) by the file's shape of the on-time
/// t_on = k·t_exp when it gives one ([`crate::effects::shape::VCSEL_DROOP`]),
/// else 1 − D·[`droop_loss`].
pub fn droop_factor(model: &ModelConfig, k: usize, exposure_us: f64) -> f64 {
    if !model.is_enabled(ids::vcsel_droop::ID) {
        return 1.0;
    }
    if let Some(s) = model.shape(ids::vcsel_droop::ID) {
        let t_on = droop_on_time_us(k as f64, exposure_us);
        return 1.0 - s.eval(crate::effects::shape::DROOP_LOSS_REL, t_on);
    }
    let d = model.get(ids::vcsel_droop::DROOP_REL);
    1.0 - d * droop_loss(
        k as f64,
        exposure_us,
        model.get(ids::vcsel_droop::TAU_US),
        model.get(ids::vcsel_droop::EXPOSURE_POWER),
        model.get(ids::vcsel_droop::FIRST_IMAGE_INDEX),
    )
}

/// The driver of the droop's shape form (3.3.7.2: the VCSEL heats while it
/// emits): its on-time before raw image `k`, k·t_exp in µs. The simulator
/// and the lab's fit both use it.
#[inline]
pub fn droop_on_time_us(k: f64, exposure_us: f64) -> f64 {
    k * exposure_us
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
    id: ids::vcsel_droop::ID.as_str(),
    title: "VCSEL power droop over successive raw images",
    explanation: "The VCSEL heats while it emits; its optical power falls over successive raw images of one acquisition: P_k = P · (1 − D · (1 − exp(−(k + k₀) · s / τ))) for raw image k in acquisition order, with heating per image s = 1 ms · (t_exp / 1 ms)^β (β = 1: heating by on-time, s = t_exp; β = 0: by image count) and k₀ images of heating before the first one (k₀ = 1: the first image is already drooped). Unequal amplitudes of the images used together distort the phasor; 4-phase loses its 0/180 symmetry. Second form: a monotone shape of the VCSEL's on-time before image k, t_on = k·t_exp, given by `shape_on_time_us` (knots, µs) and `shape_loss_rel` (the loss L < 1, P_k = P·(1 − L(t_on))), linear between the knots and flat outside them; it replaces the parametric law.",
    thesis_ref: "3.3.7.2, 5.1.2.1 ('varying emission power during exposure of several raw images')",
    signature: "raw residual grows with raw-image index and with exposure; depth error with period 2π in phase",
    params: &[
        p(
            ids::vcsel_droop::DROOP_REL,
            "",
            0.03,
            0.0,
            0.5,
            "asymptotic relative power loss D",
        ),
        p(
            ids::vcsel_droop::TAU_US,
            "us",
            3000.0,
            1.0,
            1e7,
            "thermal time constant τ of the droop (in accumulated exposure)",
        ),
        p(
            ids::vcsel_droop::EXPOSURE_POWER,
            "1",
            1.0,
            0.0,
            2.0,
            "β: heating per raw image ∝ exposure^β (1: on-time, 0: image count)",
        ),
        p(
            ids::vcsel_droop::FIRST_IMAGE_INDEX,
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

effect!(VcselDroop, INFO, vcsel_droop);
