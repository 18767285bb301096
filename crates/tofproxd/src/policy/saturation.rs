//! Saturation is evidence: a frame whose every code sits on a rail is either the sensor's own
//! illumination returned by something too close to measure (a cheek on the window, a finger
//! on the lens) — near for as long as it lasts — or no data at all (an all-zero transfer, a
//! dead frame, background light driving the pixel without modulation).
//!
//! The two differ in the raw images themselves. A return is modulated: each raw image is
//! `mid + A·c(φ − θ_k)` (eq. 2.2/2.3 with the correlation `c`), so a return far above full
//! scale puts image `k` on the rail of the sign of `c(φ − θ_k)`, and those signs are the
//! phasor of the return quantised to its quadrant: `Σ s_k e^{iθ_k}` with `s_k = ±1` for the
//! high/low rail points at `φ` within ±45°. A target within reach of the sensor has the phase
//! of zero distance (the global delay the wiggling table removes, 3.3.7.2), so its rail
//! pattern, corrected like any measured phase, lies within ±90° of zero distance. Background
//! light and a stuck bus are not modulated: an image and its 180° partner sit on the same rail
//! (4-phase: the phasor vanishes), and an all-zero frame points half a period away from zero
//! distance (2-phase: −135° before correction). Neither is a return.
//!
//! Two-phase images cannot tell a common-mode high (strong light on a mismatched pixel) from
//! a return in the first quadrant, so where the source can capture 4-phase the first
//! saturated 2-phase frame of an episode is confirmed once by a 4-phase capture at the
//! shortest exposure (`exposure.min_us`); in a replay (the source cannot choose) the 2-phase
//! pattern is near unless the loop has measured strong background light.

use ndarray::{ArrayView3, Axis, s};
use tofprox_core::calib::WigglingLut;
use tofprox_core::phasor::wrap_to_pi;
use tofprox_core::pipeline::RawSample;
use tofprox_core::proximity::Roi;

use crate::config::Mode;

/// Share of the ROI whose rail pattern must point at zero distance for the frame to be a
/// near return (the detector's "at least half of the ROI" for near truth).
const RETURN_SHARE: f64 = 0.5;

/// What one all-rails frame is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RailsDecision {
    /// The sensor's own return from something too close to measure: a near reading.
    NearReturn,
    /// Confirm first: the next capture is 4-phase at the shortest exposure; no reading now.
    Confirm,
    /// No data (garbage, dead frame, light without modulation): Near only held, bounded.
    NoData,
}

/// One all-rails frame as the policy sees it.
#[derive(Debug, Clone, Copy)]
pub struct RailsObservation {
    /// Mode of the capture.
    pub captured: Mode,
    /// The ROI's rail pattern points at zero distance ([`rails_point_at_zero_distance`]).
    pub return_pattern: bool,
    /// The source can capture 4-phase at a chosen exposure on request.
    pub source_can_confirm: bool,
    /// The loop measured background light above `ambient.high_lsb` (last 4-phase capture).
    pub bright_background: bool,
}

/// The saturation check with its per-episode confirmation.
#[derive(Debug, Clone, Default)]
pub struct SaturationCheck {
    /// The current saturated episode was confirmed as the return.
    confirmed: bool,
    /// A confirmation capture is due next.
    confirm_due: bool,
}

impl SaturationCheck {
    /// Whether the next capture is the confirmation (4-phase, `exposure.min_us`).
    pub fn confirm_due(&self) -> bool {
        self.confirm_due
    }

    /// A frame with usable codes: the saturated episode (if any) is over.
    pub fn measurable(&mut self) {
        self.confirmed = false;
        self.confirm_due = false;
    }

    /// The decision for an all-rails frame.
    pub fn next(&mut self, obs: RailsObservation) -> RailsDecision {
        self.confirm_due = false;
        if !obs.return_pattern {
            self.confirmed = false;
            return RailsDecision::NoData;
        }
        let decision = match obs.captured {
            // 4-phase images tell a return from common-mode light by themselves
            Mode::FourPhase => RailsDecision::NearReturn,
            Mode::TwoPhase if self.confirmed => RailsDecision::NearReturn,
            Mode::TwoPhase if obs.source_can_confirm => {
                self.confirm_due = true;
                return RailsDecision::Confirm;
            }
            Mode::TwoPhase if obs.bright_background => RailsDecision::NoData,
            Mode::TwoPhase => RailsDecision::NearReturn,
        };
        self.confirmed = decision == RailsDecision::NearReturn;
        decision
    }
}

/// Whether at least half of the ROI's pixels have a rail pattern that is a return at zero
/// distance: the phasor `Σ s_k (cos θ_k, sin θ_k)` of the images' rails (`s_k = +1` at
/// `max_code`, −1 at 0; the module docs) is not zero and, corrected by `lut` (the measured →
/// true phase of the wiggling table, with the global delay) where there is one, lies within
/// ±90° of zero distance. Pixels with a code off the rails do not count.
pub fn rails_point_at_zero_distance<T: RawSample>(
    frames: ArrayView3<'_, T>,
    phases_deg: &[f64],
    roi: Roi,
    max_code: f32,
    lut: Option<&WigglingLut>,
) -> bool {
    let (_, rows, cols) = frames.dim();
    let r = roi.resolve(rows, cols);
    let view = frames.slice(s![.., r.row0..r.row0 + r.rows, r.col0..r.col0 + r.cols]);
    let trig: Vec<(f64, f64)> = phases_deg
        .iter()
        .map(|d| (d.to_radians().cos(), d.to_radians().sin()))
        .collect();
    let total = r.rows * r.cols;
    let mut returns = 0usize;
    for px in view.lanes(Axis(0)) {
        let (mut x, mut y) = (0.0f64, 0.0f64);
        let mut on_rails = true;
        for (&v, &(c, s)) in px.iter().zip(&trig) {
            let v = v.to_f32();
            let sign = if v >= max_code {
                1.0
            } else if v <= 0.0 {
                -1.0
            } else {
                on_rails = false;
                break;
            };
            x += sign * c;
            y += sign * s;
        }
        if !on_rails || x.hypot(y) < 1e-6 {
            continue;
        }
        let measured = y.atan2(x);
        let true_phase = lut.map_or(measured, |l| l.correct(measured));
        if wrap_to_pi(true_phase).abs() < std::f64::consts::FRAC_PI_2 {
            returns += 1;
        }
    }
    total > 0 && returns as f64 >= RETURN_SHARE * total as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;

    /// Raw images of a return `A·cos(φ − θ)` far above full scale, clipped to a 12-bit range
    /// (the testkit's ideal codes, not the crate's synthesiser).
    fn clipped(phi: f64, phases: &[f64], amplitude: f64) -> Array3<u16> {
        use tofprox_testkit::frames::{clipped_u16, ideal_codes};
        clipped_u16(&ideal_codes(phi, amplitude, 2048.0, (4, 4), phases), 4095.0)
    }

    #[test]
    fn a_saturated_return_at_zero_distance_is_told_from_zeros_and_common_mode_light() {
        let roi = Roi::centered(4, 4, 1.0);
        let is_return = |f: &Array3<u16>, phases: &[f64]| {
            rails_point_at_zero_distance(f.view(), phases, roi, 4095.0, None)
        };
        let two = [0.0, 90.0];
        let four = [0.0, 90.0, 180.0, 270.0];
        // a cheek at 1 cm behind a 0.8 rad global delay (80 MHz), 100× full scale
        for phases in [&two[..], &four[..]] {
            assert!(is_return(&clipped(0.8 + 0.005, phases, 2e5), phases));
        }
        // an all-zero transfer
        assert!(!is_return(&Array3::zeros((2, 4, 4)), &two));
        // common-mode light on every image: 4-phase has no phasor
        assert!(!is_return(&Array3::from_elem((4, 4, 4), 4095), &four));
        // a return at half the unambiguous range (φ = π) is not at zero distance
        let f = clipped(std::f64::consts::PI + 0.1, &four, 2e5);
        assert!(!is_return(&f, &four));
        // a measurable frame is no rail pattern at all
        assert!(!is_return(&clipped(0.8, &four, 500.0), &four));
    }

    #[test]
    fn two_phase_saturation_is_confirmed_once_per_episode_where_the_source_can() {
        let obs = |captured, return_pattern, can| RailsObservation {
            captured,
            return_pattern,
            source_can_confirm: can,
            bright_background: false,
        };
        let mut c = SaturationCheck::default();
        assert_eq!(
            c.next(obs(Mode::TwoPhase, true, true)),
            RailsDecision::Confirm
        );
        assert!(c.confirm_due());
        assert_eq!(
            c.next(obs(Mode::FourPhase, true, true)),
            RailsDecision::NearReturn
        );
        assert!(!c.confirm_due());
        // confirmed: the episode's 2-phase frames are near without another confirmation
        for _ in 0..3 {
            assert_eq!(
                c.next(obs(Mode::TwoPhase, true, true)),
                RailsDecision::NearReturn
            );
        }
        // a measurable frame ends the episode: the next one is confirmed again
        c.measurable();
        assert_eq!(
            c.next(obs(Mode::TwoPhase, true, true)),
            RailsDecision::Confirm
        );
        // the confirmation showed common-mode light: no data, and no confirmed episode
        assert_eq!(
            c.next(obs(Mode::FourPhase, false, true)),
            RailsDecision::NoData
        );
        // a replay: near unless the loop measured strong background light
        let mut c = SaturationCheck::default();
        assert_eq!(
            c.next(obs(Mode::TwoPhase, true, false)),
            RailsDecision::NearReturn
        );
        let mut c = SaturationCheck::default();
        let bright = RailsObservation {
            bright_background: true,
            ..obs(Mode::TwoPhase, true, false)
        };
        assert_eq!(c.next(bright), RailsDecision::NoData);
    }
}
