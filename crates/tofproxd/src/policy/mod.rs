//! The controller's policies, one unit each: every unit holds only its own state and
//! decides the next value from one observation (`fn next(&mut self, observation) ->
//! decision`). The loop's controller composes them after each cycle (it imports them, never
//! the other way round); none of them touches the source, the pipeline or the bus.
//!
//! | unit | decides | from | thesis |
//! |---|---|---|---|
//! | [`AmbientSwitch`] | 2- or 4-phase | background indicator, 2-vs-4 discrepancy | 5.1.2.3, eq. 2.2/2.3 |
//! | [`AutoExposure`] | exposure per raw image | saturated / weak fraction of the ROI | 3.1.2, eye-safe max |
//! | [`AdaptiveRate`] | reading rate | near, approach speed, stillness | 3.5.3 |
//! | [`ReadoutWindow`] | rows read out | ROI, margin, source alignment | 3.1.2 (read-out ∝ rows) |
//! | [`SecondFrequency`] | confirm dim near candidates at a second frequency | dim candidates, Near | 2.2.1, eqs. 2.7–2.9 |
//! | [`EnergyAccount`] | sleep after the cycle, average power | state timings, K, exposure, rows | table 3.1 |
//! | [`WindowTracker`] | the cover window's crosstalk estimate (compensated, bounded) and its verdict | readings that see only the window, near candidates | 3.1 (stray light), eq. 2.2/2.3 |
//! | [`probe::PresenceProbe`] | a single raw image instead of the full reading while far and still | tile means vs the last far reading's | 2.2.1, eq. 2.2 |
//! | [`SaturationCheck`] | an all-rails frame: near return, confirm (4-phase, `min_us`), or no data | the rails' phasor vs zero distance | 2.2.1, eq. 2.2/2.3 |

mod ambient;
mod energy_account;
mod exposure;
pub mod probe;
mod rate;
mod readout;
mod saturation;
pub mod second_frequency;
pub mod window;

pub use ambient::{AmbientObservation, AmbientSwitch};
pub use energy_account::{CycleObservation, EnergyAccount, EnergyDecision, Pacing};
pub use exposure::{
    AutoExposure, ExposureObservation, decision_exposure_us, saturating_fraction_at,
};
pub use rate::{AdaptiveRate, RateObservation};
pub use readout::{ReadoutObservation, ReadoutWindow, stepped_roi};
pub use saturation::{
    RailsDecision, RailsObservation, SaturationCheck, rails_point_at_zero_distance,
};
pub use second_frequency::{CandidateObservation, SecondFrequency};
pub use window::{WindowObservation, WindowTracker};
