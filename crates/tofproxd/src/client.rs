//! Client-side proxies of the daemon's interfaces (used by `tofprox monitor`,
//! `status`, `record`, the demo and the tests).

use std::collections::HashMap;

use zbus::{OwnedVariant, proxy};

use crate::controller::DISTANCE_BEYOND_RANGE_MM;

/// `org.tofprox.Proximity1`.
#[proxy(
    interface = "org.tofprox.Proximity1",
    default_service = "org.tofprox.Proximity1",
    default_path = "/org/tofprox/Proximity1"
)]
pub trait Proximity {
    /// Claim proximity.
    fn claim_proximity(&self) -> zbus::Result<()>;
    /// Release proximity.
    fn release_proximity(&self) -> zbus::Result<()>;
    /// Claim depth frames.
    fn claim_depth(&self) -> zbus::Result<()>;
    /// Release depth frames.
    fn release_depth(&self) -> zbus::Result<()>;
    /// All properties and counters.
    fn get_status(&self) -> zbus::Result<HashMap<String, OwnedVariant>>;
    /// HasSensor.
    #[zbus(property)]
    fn has_sensor(&self) -> zbus::Result<bool>;
    /// State.
    #[zbus(property)]
    fn state(&self) -> zbus::Result<String>;
    /// Near.
    #[zbus(property)]
    fn near(&self) -> zbus::Result<bool>;
    /// NearChangedNs (CLOCK_BOOTTIME of the capture that last changed Near; signalled with Near).
    #[zbus(property)]
    fn near_changed_ns(&self) -> zbus::Result<u64>;
    /// ReadingTimestampNs (CLOCK_BOOTTIME of the last valid reading's capture; no change signal).
    #[zbus(property(emits_changed_signal = "false"))]
    fn reading_timestamp_ns(&self) -> zbus::Result<u64>;
    /// DistanceMm (no change signal).
    #[zbus(property(emits_changed_signal = "false"))]
    fn distance_mm(&self) -> zbus::Result<u32>;
    /// NearThresholdMm.
    #[zbus(property(emits_changed_signal = "const"))]
    fn near_threshold_mm(&self) -> zbus::Result<u32>;
    /// FarThresholdMm.
    #[zbus(property(emits_changed_signal = "const"))]
    fn far_threshold_mm(&self) -> zbus::Result<u32>;
    /// Mode.
    #[zbus(property)]
    fn mode(&self) -> zbus::Result<String>;
    /// RateHz.
    #[zbus(property)]
    fn rate_hz(&self) -> zbus::Result<f64>;
    /// PowerEstimateMw.
    #[zbus(property)]
    fn power_estimate_mw(&self) -> zbus::Result<f64>;
    /// LastError.
    #[zbus(property)]
    fn last_error(&self) -> zbus::Result<String>;
    /// Reason: the rule that decided the last reading.
    #[zbus(property)]
    fn reason(&self) -> zbus::Result<String>;
    /// DepthFrame signal (radial depth in mm, amplitude).
    #[zbus(signal)]
    fn depth_frame(
        &self,
        timestamp_ns: u64,
        width: u16,
        height: u16,
        depth_mm_u16_le: Vec<u8>,
        amplitude_u16_le: Vec<u8>,
    ) -> zbus::Result<()>;
}

/// `DistanceMm` in words for a person (the demo, `tofprox monitor`): a distance, or what the
/// special values mean — 0 is "saturated" while near (the ROI was too close or bright to
/// measure) and "unknown" otherwise; [`DISTANCE_BEYOND_RANGE_MM`] is a valid reading with
/// nothing in range.
pub fn distance_words(distance_mm: u32, near: bool) -> String {
    match (distance_mm, near) {
        (DISTANCE_BEYOND_RANGE_MM, _) => "nothing in range".to_string(),
        (0, true) => "distance saturated (too close or too bright to measure)".to_string(),
        (0, false) => "distance unknown".to_string(),
        (d, _) => format!("distance {d} mm"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn special_distances_are_said_in_words() {
        assert_eq!(distance_words(u32::MAX, false), "nothing in range");
        assert_eq!(distance_words(u32::MAX, true), "nothing in range");
        assert_eq!(distance_words(0, false), "distance unknown");
        assert!(distance_words(0, true).starts_with("distance saturated"));
        assert_eq!(distance_words(982, false), "distance 982 mm");
        assert_eq!(distance_words(96, true), "distance 96 mm");
    }
}
