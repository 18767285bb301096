//! A second modulation frequency for dim near candidates (thesis 2.2.1: eq. 2.7, the
//! unambiguous range; eqs. 2.8/2.9, range extension with two frequencies).
//!
//! One frequency cannot tell a target at `d` from one at `d + n·d_u` (eq. 2.7); the amplitude
//! test ([`tofprox_core::radiometry::flag_implausible_near`], `A = K·ρ·t/d²`) only rejects
//! returns dimmer than the darkest real target. A retroreflector (safety vest 20–40× a white
//! wall, retroreflective tape ~1000× at a phone's observation angle) just beyond the range is
//! bright enough to pass it: a gain-`G` target at `d + d_u` returns what a diffuse target of
//! reflectivity `G·(d/(d + d_u))²` returns at `d` (1000× at 1.95 m reads 76 mm like a 152 %
//! target). So a near candidate pixel is **dim** — and must be confirmed before Near is
//! published — when its amplitude is below what the brighter of
//!
//! - a diffuse target of `confirm_reflectivity` (20 %) at its measured depth `d`, and
//! - the brightest far target, gain `brightest_far_gain` (1000), one range further
//!   (`d + d_u − δ`, δ the depth uncertainty the amplitude test also allows)
//!
//! would return ([`DimNearRule`]). A dim candidate is confirmed by one capture at the second
//! frequency `f2`: both phases unwrapped together ([`dual_frequency_distance`], eq. 2.8 with
//! the fusion of eq. 2.9) must put it below `far_mm`; a pixel they put farther (an aliased far
//! target) is rejected like a wrapped phase; one the second capture cannot measure (too weak,
//! saturated) carries no evidence and keeps the amplitude test's verdict
//! ([`reject_aliased`]). Only candidates are checked: before Near is published, and while a
//! Near the second frequency has not confirmed lasts (one published by saturation, or by the
//! amplitude test alone) — [`SecondFrequency::next`]. A confirmed near episode takes no
//! further capture until Near is released: one extra capture per near onset.

use ndarray::ArrayView2;
use tofprox_core::phasor::{
    distance_to_phase_rad, dual_frequency_distance, extended_unambiguous_range_m,
    unambiguous_range_m, wrap_to_pi,
};
use tofprox_core::pipeline::{
    DepthFrame, FLAG_IMPLAUSIBLE, FLAG_INVALID, FLAG_LOW_AMPLITUDE, FLAG_SATURATED,
};
use tofprox_core::proximity::Roi;
use tofprox_core::radiometry::expected_amplitude_lsb;

/// When a near candidate pixel is dim (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DimNearRule {
    /// Reflectivity of the diffuse target the candidate is compared with at its depth.
    pub confirm_reflectivity: f64,
    /// Gain (relative to a white wall) of the brightest far target, one range further.
    pub brightest_far_gain: f64,
    /// Depth uncertainty δ (m): the far target is taken at `d + d_u − δ`.
    pub depth_uncertainty_m: f64,
    /// Depths (m) below this are near candidates (`far_mm`: readings that make or hold near).
    pub check_below_m: f64,
    /// The capture's modulation frequency (Hz), for its unambiguous range (eq. 2.7).
    pub modulation_hz: f64,
}

impl DimNearRule {
    /// The amplitude (LSB) below which a candidate at `depth_m` is dim, for scale `K`
    /// (LSB·m²/µs) and `exposure_us` (thesis 2.2.1, `A = K·ρ·t/d²`).
    pub fn threshold_lsb(&self, scale: f64, exposure_us: f64, depth_m: f64) -> f64 {
        let du = unambiguous_range_m(self.modulation_hz);
        let diffuse =
            expected_amplitude_lsb(scale, self.confirm_reflectivity, exposure_us, depth_m);
        let aliased = expected_amplitude_lsb(
            scale,
            self.brightest_far_gain,
            exposure_us,
            (depth_m - self.depth_uncertainty_m).max(0.0) + du,
        );
        diffuse.max(aliased)
    }
}

/// The ROI's dim near candidates `(row, col)` in frame coordinates: valid, unsaturated pixels
/// below `check_below_m` whose amplitude is below [`DimNearRule::threshold_lsb`]. A scale of
/// another shape than the frame gives none.
pub fn dim_near_candidates(
    frame: &DepthFrame,
    roi: Roi,
    scale: ArrayView2<f32>,
    exposure_us: f64,
    rule: &DimNearRule,
) -> Vec<(usize, usize)> {
    if scale.dim() != frame.dim() {
        return Vec::new();
    }
    let (rows, cols) = frame.dim();
    let mut out = Vec::new();
    for r in roi.row0..(roi.row0 + roi.rows).min(rows) {
        for c in roi.col0..(roi.col0 + roi.cols).min(cols) {
            let d = f64::from(frame.depth_m[[r, c]]);
            if frame.flags[[r, c]] & (FLAG_INVALID | FLAG_SATURATED) != 0 || d >= rule.check_below_m
            {
                continue;
            }
            let a = f64::from(frame.amplitude_lsb[[r, c]]);
            if a < rule.threshold_lsb(f64::from(scale[[r, c]]), exposure_us, d) {
                out.push((r, c));
            }
        }
    }
    out
}

/// What the second frequency said about the candidates.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AliasVerdict {
    /// Candidates both frequencies put below `far_m`.
    pub confirmed: usize,
    /// Candidates rejected: farther by eqs. 2.8/2.9.
    pub aliased: usize,
    /// Candidates the second capture could not measure (weak, saturated): kept.
    pub unmeasured: usize,
}

/// Check each candidate of `frame1` (modulation `f1_hz`) against `frame2`, the same pixels
/// captured at `f2_hz`: both phases unwrapped together ([`dual_frequency_distance`], eq. 2.8,
/// fused by eq. 2.9) must lie below `far_m`; one unwrapped farther is rejected like a wrapped
/// phase: [`FLAG_IMPLAUSIBLE`] | [`FLAG_INVALID`], depth 0. A pixel `f2` cannot measure
/// (saturated, invalid, too weak) is kept: no evidence either way. Frames of different shapes
/// confirm nothing and reject nothing.
pub fn reject_aliased(
    frame1: &mut DepthFrame,
    f1_hz: f64,
    frame2: &DepthFrame,
    f2_hz: f64,
    candidates: &[(usize, usize)],
    far_m: f64,
) -> AliasVerdict {
    let mut v = AliasVerdict::default();
    if frame1.dim() != frame2.dim() {
        v.unmeasured = candidates.len();
        return v;
    }
    for &(r, c) in candidates {
        let i = [r, c];
        if frame2.flags[i] & (FLAG_SATURATED | FLAG_INVALID | FLAG_LOW_AMPLITUDE) != 0 {
            v.unmeasured += 1;
            continue;
        }
        let near = dual_frequency_distance(
            f64::from(frame1.phase_rad[i]),
            f64::from(frame1.amplitude_lsb[i]),
            f1_hz,
            f64::from(frame2.phase_rad[i]),
            f64::from(frame2.amplitude_lsb[i]),
            f2_hz,
            None,
        )
        .is_ok_and(|d| d.distance_m < far_m);
        let (d1_m, d2_m) = (f64::from(frame1.depth_m[i]), f64::from(frame2.depth_m[i]));
        if near {
            v.confirmed += 1;
        } else if !alias_is_clear(d1_m, d2_m, f1_hz, f2_hz) {
            // calibration error at f2 could explain the miss as well as an alias: keep
            v.unmeasured += 1;
        } else {
            frame1.flags[i] |= FLAG_IMPLAUSIBLE | FLAG_INVALID;
            frame1.depth_mm[i] = 0;
            frame1.depth_m[i] = 0.0;
            v.aliased += 1;
        }
    }
    v
}

/// Phase error (rad) at the second frequency that the near hypothesis must show before an
/// alias may be preferred to it. Below it, the approximate calibration at `f2` (the `f1`
/// wiggling table, FPPN scaled by `f2/f1`, the `f1` window crosstalk) explains the miss as
/// well as an alias does, and a lost near at the ear is as bad as a false one.
pub const MIN_NEAR_PHASE_ERROR_RAD: f64 = 0.35;

/// Aliases `d + k·d_u(f1)` considered, `k = 1..=MAX_ALIAS_ORDER`: targets bright enough to
/// pass as near lie just beyond one, two or three unambiguous ranges (the return falls as
/// 1/d², thesis 2.2.1). Farther orders would leave no phase unexplained: at 80/70 MHz the
/// eight aliases of the 15 m extended range lie 45° apart at `f2`.
pub const MAX_ALIAS_ORDER: u32 = 3;

/// Whether the second frequency clearly says "alias" (the hypotheses of eq. 2.8): `d2_m`, the
/// wrapped distance measured at `f2`, misses the near hypothesis `d1_m` by more than
/// [`MIN_NEAR_PHASE_ERROR_RAD`] of `f2` phase, and some alias `d1_m + k·d_u(f1)` (up to
/// [`MAX_ALIAS_ORDER`], within the extended range) fits it at least twice as well.
pub fn alias_is_clear(d1_m: f64, d2_m: f64, f1_hz: f64, f2_hz: f64) -> bool {
    let miss_rad = |d_m: f64| wrap_to_pi(distance_to_phase_rad(d2_m - d_m, f2_hz)).abs();
    let near_miss = miss_rad(d1_m);
    if near_miss.is_nan() || near_miss <= MIN_NEAR_PHASE_ERROR_RAD {
        return false;
    }
    let (du1_m, extended_m) = (
        unambiguous_range_m(f1_hz),
        extended_unambiguous_range_m(f1_hz, f2_hz),
    );
    (1..=MAX_ALIAS_ORDER)
        .map(|k| d1_m + f64::from(k) * du1_m)
        .take_while(|&d| d <= extended_m)
        .any(|d| miss_rad(d) * 2.0 <= near_miss)
}

/// What the loop knows when it decides whether to confirm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CandidateObservation {
    /// Dim near candidates in this cycle's ROI ([`dim_near_candidates`]).
    pub dim_candidates: usize,
    /// The candidates can make or hold a near reading: the detector's statistic counting
    /// them lies below `far_mm` ([`tofprox_core::proximity::NearFarDetector::statistic_below_far`]).
    /// A few dim pixels among far ones (noise on a dark ceiling) decide nothing and take no
    /// capture.
    pub decisive: bool,
    /// Near is published now.
    pub near_published: bool,
    /// The modulation frequency of this cycle's capture (Hz).
    pub captured_hz: f64,
}

/// The policy: which frequency to confirm dim candidates at, and when.
#[derive(Debug, Clone)]
pub struct SecondFrequency {
    modulation_hz: Option<f64>,
    refusal_logged: bool,
    /// The published near episode was confirmed at the second frequency.
    confirmed: bool,
}

impl SecondFrequency {
    /// `modulation_hz`: the second frequency (`proximity.second_modulation_hz`; `None` = off).
    pub fn new(modulation_hz: Option<f64>) -> Self {
        Self {
            modulation_hz,
            refusal_logged: false,
            confirmed: false,
        }
    }

    /// The frequency (Hz) to capture the candidates at, or `None`: no dim candidate, a
    /// published Near already confirmed, the feature off, or `f2` equal to the captured
    /// frequency (no range extension, eq. 2.8).
    pub fn next(&mut self, obs: CandidateObservation) -> Option<f64> {
        if !obs.near_published {
            self.confirmed = false;
        }
        let f2 = self.modulation_hz?;
        let due = !(obs.near_published && self.confirmed);
        let needed = obs.dim_candidates > 0 && obs.decisive && due;
        (needed && (f2 - obs.captured_hz).abs() >= 1.0).then_some(f2)
    }

    /// What the second frequency said: a near it confirmed (no candidate aliased) needs no
    /// further capture while it lasts.
    pub fn note(&mut self, verdict: AliasVerdict) {
        self.confirmed = verdict.confirmed > 0 && verdict.aliased == 0;
    }

    /// The source cannot capture at the second frequency (a replayed recording without
    /// second-frequency images, a sensor map without a modulation register): the amplitude
    /// test decides alone for this cycle. Logged once.
    pub fn refused(&mut self, why: &str) {
        if !self.refusal_logged {
            self.refusal_logged = true;
            tracing::warn!(
                "second-frequency confirmation unavailable ({why}): the amplitude test decides alone"
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;
    use std::f64::consts::PI;

    const C: f64 = 299_792_458.0;

    /// A frame of one target: the wrapped phase `4π f D / c mod 2π` written independently of
    /// the pipeline (amplitude from a point-source inverse-square law with gain `g`).
    fn frame_of(distance_m: f64, g: f64, f_hz: f64) -> DepthFrame {
        let mut f = DepthFrame::zeros(4, 4);
        let phase = (4.0 * PI * f_hz * distance_m / C).rem_euclid(2.0 * PI);
        let wrapped = phase * C / (4.0 * PI * f_hz);
        f.phase_rad.fill(phase as f32);
        f.depth_m.fill(wrapped as f32);
        f.depth_mm.fill((wrapped * 1e3) as u16);
        // K·t = 9 LSB·m² (K = 0.09 LSB·m²/µs, 100 µs)
        f.amplitude_lsb
            .fill((9.0 * g / (distance_m * distance_m)) as f32);
        f
    }

    fn rule() -> DimNearRule {
        DimNearRule {
            confirm_reflectivity: 0.2,
            brightest_far_gain: 1000.0,
            depth_uncertainty_m: 0.03,
            check_below_m: 0.15,
            modulation_hz: 80e6,
        }
    }

    fn roi() -> Roi {
        Roi {
            row0: 0,
            col0: 0,
            rows: 4,
            cols: 4,
        }
    }

    #[test]
    fn a_1000x_retroreflector_beyond_the_range_is_a_dim_candidate_and_rejected() {
        let k = Array2::from_elem((4, 4), 0.09f32);
        for d in [1.90, 1.95, 3.80] {
            let mut f1 = frame_of(d, 1000.0, 80e6);
            assert!(f1.depth_m[[0, 0]] < 0.15, "{d} m wraps near");
            let cand = dim_near_candidates(&f1, roi(), k.view(), 100.0, &rule());
            assert_eq!(cand.len(), 16, "{d} m: every pixel is a dim candidate");
            let f2 = frame_of(d, 1000.0, 70e6);
            let v = reject_aliased(&mut f1, 80e6, &f2, 70e6, &cand, 0.15);
            assert_eq!((v.confirmed, v.aliased), (0, 16), "{d} m");
            assert!(f1.depth_mm.iter().all(|&x| x == 0));
            assert!(f1.flags.iter().all(|&x| x & FLAG_IMPLAUSIBLE != 0));
        }
    }

    #[test]
    fn a_near_hand_is_confirmed_a_bright_one_needs_no_confirmation() {
        let k = Array2::from_elem((4, 4), 0.09f32);
        let mut f1 = frame_of(0.06, 0.4, 80e6);
        let cand = dim_near_candidates(&f1, roi(), k.view(), 100.0, &rule());
        assert_eq!(
            cand.len(),
            16,
            "a 40 % hand at 6 cm is dimmer than 1000× at 1.93 m"
        );
        let f2 = frame_of(0.06, 0.4, 70e6);
        let v = reject_aliased(&mut f1, 80e6, &f2, 70e6, &cand, 0.15);
        assert_eq!((v.confirmed, v.aliased), (16, 0));
        assert!(f1.depth_mm.iter().all(|&x| x == 60));
        // a white card at 2 cm returns more than 1000× at 1.89 m and than 20 % at 2 cm
        let f1 = frame_of(0.02, 1.0, 80e6);
        assert!(dim_near_candidates(&f1, roi(), k.view(), 100.0, &rule()).is_empty());
        // saturated and far pixels are no candidates
        let mut f1 = frame_of(0.06, 0.4, 80e6);
        f1.flags.fill(FLAG_SATURATED);
        assert!(dim_near_candidates(&f1, roi(), k.view(), 100.0, &rule()).is_empty());
        let f1 = frame_of(0.5, 0.01, 80e6);
        assert!(dim_near_candidates(&f1, roi(), k.view(), 100.0, &rule()).is_empty());
    }

    #[test]
    fn unmeasurable_at_the_second_frequency_is_no_evidence() {
        let mut f1 = frame_of(0.06, 0.4, 80e6);
        let mut f2 = frame_of(0.06, 0.4, 70e6);
        f2.flags[[0, 0]] = FLAG_LOW_AMPLITUDE;
        f2.flags[[0, 1]] = FLAG_SATURATED;
        let v = reject_aliased(&mut f1, 80e6, &f2, 70e6, &[(0, 0), (0, 1)], 0.15);
        assert_eq!((v.confirmed, v.aliased, v.unmeasured), (0, 0, 2));
        assert_eq!(f1.depth_mm[[0, 0]], 60, "no evidence: kept");
        let other = DepthFrame::zeros(2, 2);
        let v = reject_aliased(&mut f1, 80e6, &other, 70e6, &[(1, 1)], 0.15);
        assert_eq!(v.unmeasured, 1, "frames of another shape say nothing");
    }

    #[test]
    fn confirms_only_onsets_at_another_frequency() {
        let mut p = SecondFrequency::new(Some(70e6));
        let obs = |n, near, f| CandidateObservation {
            dim_candidates: n,
            decisive: n > 0,
            near_published: near,
            captured_hz: f,
        };
        assert_eq!(p.next(obs(5, false, 80e6)), Some(70e6));
        assert_eq!(p.next(obs(0, false, 80e6)), None);
        let stray = CandidateObservation {
            decisive: false,
            ..obs(5, false, 80e6)
        };
        assert_eq!(p.next(stray), None, "dim pixels that cannot make near");
        assert_eq!(
            p.next(obs(5, true, 80e6)),
            Some(70e6),
            "a near not confirmed (saturation) is checked"
        );
        p.note(AliasVerdict {
            confirmed: 5,
            ..AliasVerdict::default()
        });
        assert_eq!(p.next(obs(5, true, 80e6)), None, "confirmed near lasts");
        assert_eq!(p.next(obs(5, false, 80e6)), Some(70e6), "next onset");
        assert_eq!(p.next(obs(5, false, 70e6)), None, "same frequency");
        assert_eq!(SecondFrequency::new(None).next(obs(5, false, 80e6)), None);
    }

    /// A retroreflector one and two ranges beyond a near reading is a clear alias at 70 MHz;
    /// a near hand measured at 70 MHz with a calibration error of up to ~20° is not, nor is
    /// a miss that no alias explains.
    #[test]
    fn an_alias_must_be_clear_before_it_overrides_near() {
        let (f1, f2) = (80e6, 70e6);
        let (du1, du2) = (unambiguous_range_m(f1), unambiguous_range_m(f2));
        let seen_at_f2 = |true_m: f64| true_m.rem_euclid(du2);
        for k in [1.0, 2.0] {
            assert!(
                alias_is_clear(0.05, seen_at_f2(0.05 + k * du1), f1, f2),
                "k = {k}"
            );
        }
        let per_rad = du2 / std::f64::consts::TAU;
        for err_deg in [-20.0f64, -5.0, 0.0, 5.0, 20.0] {
            let d2 = seen_at_f2(0.05 + err_deg.to_radians() * per_rad);
            assert!(!alias_is_clear(0.05, d2, f1, f2), "{err_deg}°");
        }
        // 90° off the other way from the aliases of orders 1–3: no alias explains it
        assert!(!alias_is_clear(0.05, seen_at_f2(0.05 + 0.25 * du2), f1, f2));
    }
}
