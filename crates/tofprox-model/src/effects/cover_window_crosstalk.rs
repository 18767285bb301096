//! `cover_window_crosstalk`: Cover-window crosstalk (thesis not treated in the
//! thesis (extension: phone proximity sensors sit behind a cover glass, 2.4.2); an
//! extra return adds its phasor (2.2.1, eq. 2.2/2.3); the stray-light correction
//! step of fig. 3.1 (3.1)).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law is evaluated inline by the
//! simulator ([`crate::sim`]), where the signal chain combines it.

use crate::catalogue::{ActsOn, Driver, EffectInfo, param as p};
use crate::ids;

/// The catalogue entry of `cover_window_crosstalk`.
pub static INFO: EffectInfo = EffectInfo {
    id: ids::cover_window_crosstalk::ID.as_str(),
    title: "Cover-window crosstalk",
    explanation: "The cover window (phone glass) in front of emitter and lens reflects part of the illumination straight back into the pixels, before it reaches the scene. It is a return at the window's distance d_w (a few mm) that does not depend on the scene: N_xt = e_per_us · (1 + smudge_rel) · t_exp · w(c) · g_p · droop_k · drift_gain electrons (both taps, ∝ exposure and illumination power), w(c) = max(0, 1 + gradient_rel · (c/(cols_full − 1) − ½)) the profile across the columns (the emitter sits beside the array), at phase φ_xt = 4π f d_w / c + φ_delay,p (the electrical delay of every return). Its taps follow N_A,B = N_xt/2 · (1 ± K C(φ_xt − θ_k)); its electrons add shot noise and tap charge (SBI) like any light. The measured phasor is the sum of scene and window returns, so a weak far target is pulled towards zero distance; a smudge (grease scatters more light back) multiplies it by 1 + smudge_rel.",
    thesis_ref: "not treated in the thesis (extension: phone proximity sensors sit behind a cover glass, 2.4.2); an extra return adds its phasor (2.2.1, eq. 2.2/2.3); the stray-light correction step of fig. 3.1 (3.1)",
    signature: "a constant complex offset per pixel ∝ exposure, at ≈ zero distance, present with nothing in range; depth of weak (far, dark) targets pulled short, bright near targets unaffected; same in 2- and 4-phase",
    params: &[
        p(
            ids::cover_window_crosstalk::E_PER_US,
            "e-/us",
            20.0,
            0.0,
            1e5,
            "crosstalk electrons per µs of exposure (both taps) of the clean window at nominal optical power (20 ≈ the return of a white target at 1.4 m)",
        ),
        p(
            ids::cover_window_crosstalk::SMUDGE_REL,
            "",
            0.0,
            0.0,
            50.0,
            "extra crosstalk of a smudged window relative to the clean one (1 = doubled)",
        ),
        p(
            ids::cover_window_crosstalk::WINDOW_DISTANCE_MM,
            "mm",
            3.0,
            0.0,
            50.0,
            "distance d_w of the cover window's reflecting surface from the sensor",
        ),
        p(
            ids::cover_window_crosstalk::GRADIENT_REL,
            "",
            0.5,
            -2.0,
            2.0,
            "relative change of the crosstalk from the first to the last column of the full array",
        ),
    ],
    in_baseline: false,
    acts_on: ActsOn::Signal,
    drivers: &[Driver::ExposureUs],
    cancels_in_four_phase: false,
};

effect!(CoverWindowCrosstalk, INFO, cover_window_crosstalk);
