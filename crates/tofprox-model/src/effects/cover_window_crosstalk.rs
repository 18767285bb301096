//! `cover_window_crosstalk`: Cover-window crosstalk (thesis not treated in the
//! thesis (extension: phone proximity sensors sit behind a cover glass, 2.4.2); an
//! extra return adds its phasor (2.2.1, eq. 2.2/2.3); the stray-light correction
//! step of fig. 3.1 (3.1)).
//!
//! Its catalogue entry (physics, parameters with units and ranges, what it acts on,
//! its drivers) and its registry entry; its law is evaluated inline by the
//! simulator (`Simulator` in `sim.rs`), where the signal chain combines it.

use crate::entry::{ActsOn, Driver, EffectInfo, param as p};

crate::ids::effect_ids!(cover_window_crosstalk {
    E_PER_US = "e_per_us",
    SMUDGE_REL = "smudge_rel",
    WINDOW_DISTANCE_MM = "window_distance_mm",
    GRADIENT_REL = "gradient_rel",
});

/// The catalogue entry of `cover_window_crosstalk`.
pub static INFO: EffectInfo = EffectInfo {
    id: ID.as_str(),
    title: "Cover-window crosstalk",
    explanation: "The cover window (phone glass) in front of emitter and lens reflects part of the illumination straight back into the pixels, before it reaches the scene. It is a return at the window's distance d_w (a few mm) that does not depend on the scene: N_xt = e_per_us · (1 + smudge_rel) · t_exp · w(c) · g_p · droop_k · drift_gain electrons (both taps, ∝ exposure and illumination power), w(c) = max(0, 1 + gradient_rel · (c/(cols_full − 1) − ½)) the profile across the columns (the emitter sits beside the array), at phase φ_xt = 4π f d_w / c + φ_delay,p (the electrical delay of every return). Its taps follow N_A,B = N_xt/2 · (1 ± K C(φ_xt − θ_k)); its electrons add shot noise and tap charge (SBI) like any light. The measured phasor is the sum of scene and window returns, so a weak far target is pulled towards zero distance; a smudge (grease scatters more light back) multiplies it by 1 + smudge_rel. A diffuse surface of reflectivity ρ pressed on the window (pocket fabric, the scene `OnWindow`) returns by the same path: N_contact = e_per_us · (1 − R)² ρ / R · t_exp · w(c) · g_p · droop_k · drift_gain, added to N_xt at its phase, with R = 4 % the glass's reflectance, at the window's phase (a dark 4 % lining about doubles the window's return, white fabric adds ≈ 20×).",
    thesis_ref: "not treated in the thesis (extension: phone proximity sensors sit behind a cover glass, 2.4.2); an extra return adds its phasor (2.2.1, eq. 2.2/2.3); the stray-light correction step of fig. 3.1 (3.1)",
    signature: "a constant complex offset per pixel ∝ exposure, at ≈ zero distance, present with nothing in range; depth of weak (far, dark) targets pulled short, bright near targets unaffected; same in 2- and 4-phase",
    params: &[
        p(
            E_PER_US,
            "e-/us",
            20.0,
            0.0,
            1e5,
            "crosstalk electrons per µs of exposure (both taps) of the clean window at nominal optical power (20 ≈ the return of a white target at 1.4 m)",
        ),
        p(
            SMUDGE_REL,
            "",
            0.0,
            0.0,
            50.0,
            "extra crosstalk of a smudged window relative to the clean one (1 = doubled)",
        ),
        p(
            WINDOW_DISTANCE_MM,
            "mm",
            3.0,
            0.0,
            50.0,
            "distance d_w of the cover window's reflecting surface from the sensor",
        ),
        p(
            GRADIENT_REL,
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

effect!(CoverWindowCrosstalk, INFO, ID, chain = 50);

/// The reflectance of the cover glass the window's crosstalk comes from: Fresnel's at normal
/// incidence for n = 1.5, `((n − 1)/(n + 1))² = 0.04` (Hecht, *Optics*, 4.6.2).
pub const GLASS_REFLECTANCE: f64 = 0.04;

/// The return of a diffuse surface of `reflectivity` pressed on the window's outer face,
/// relative to the clean window's crosstalk (`e_per_us`, smudge or not), added to it at the window's phase.
///
/// Our assumption, beyond the thesis: the window's crosstalk is the light its outer surface
/// reflects (reflectance [`GLASS_REFLECTANCE`]) that reaches the pixels on the near-field
/// path from emitter to lens. A Lambertian surface (thesis 2.2.1) lying on that surface is
/// lit through the glass (transmission `1 − R`), reflects `ρ`, and its light crosses the
/// glass again (`1 − R`) on the same path, so `N_contact / N_xt = (1 − R)² ρ / R`. Nothing
/// beyond the surface is seen and it is out of the lens's focus: it adds no image of its
/// own. The measurement — a dark pocket lining pressed on the window about doubled
/// the window's return — is a lining of ≈ 4 %; light fabric (50 %) adds ≈ 11.5×.
pub fn on_glass_return_rel(reflectivity: f64) -> f64 {
    let t = 1.0 - GLASS_REFLECTANCE;
    t * t * reflectivity.max(0.0) / GLASS_REFLECTANCE
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The law against the measurement and the transmission written out: a 4 %
    /// lining doubles the window's return (but for the glass's two passes), a white card
    /// behind glass adds what 0.96² × 0.9 / 0.04 says, nothing on the glass adds nothing.
    #[test]
    fn a_dark_lining_about_doubles_the_window_and_light_fabric_is_far_above_it() {
        assert_eq!(on_glass_return_rel(0.0), 0.0);
        let dark = 1.0 + on_glass_return_rel(0.04);
        assert!((dark - 1.9216).abs() < 1e-9, "{dark}");
        let white = on_glass_return_rel(0.9);
        assert!((white - 0.96 * 0.96 * 0.9 / 0.04).abs() < 1e-9, "{white}");
        assert!(on_glass_return_rel(0.5) > 10.0);
        assert_eq!(on_glass_return_rel(-1.0), 0.0, "no negative light");
    }
}
