//! The vocabulary of the hub's state: the service [`State`], the [`Demand`] that follows the
//! claims, the [`Status`] the properties show, the [`Reason`] of a reading and the [`Claim`]s.

use crate::config::Mode;

/// Service state (the `State` property).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// Sensor held in reset (no claim).
    Off,
    /// Claimed, no valid reading yet.
    Starting,
    /// Readings flowing.
    Running,
    /// The last cycle failed; retrying.
    Error,
    /// Several cycles in a row failed (device gone?); retrying.
    Unavailable,
}

impl State {
    /// The property string.
    pub fn as_str(self) -> &'static str {
        match self {
            State::Off => "off",
            State::Starting => "starting",
            State::Running => "running",
            State::Error => "error",
            State::Unavailable => "unavailable",
        }
    }
}

/// What the clients currently want from the loop.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Demand {
    /// Someone claims proximity (native or compat).
    pub proximity: bool,
    /// Someone claims depth frames.
    pub depth: bool,
}

impl Demand {
    /// Whether the loop must run.
    pub fn any(self) -> bool {
        self.proximity || self.depth
    }
}

/// Everything the properties show.
#[derive(Debug, Clone, PartialEq)]
pub struct Status {
    /// `HasSensor`.
    pub has_sensor: bool,
    /// `State`.
    pub state: State,
    /// `Near`.
    pub near: bool,
    /// `NearChangedNs`: `CLOCK_BOOTTIME` (ns) of the capture whose reading last changed `Near`
    /// (0 = unchanged since the daemon started).
    pub near_changed_ns: u64,
    /// `ReadingTimestampNs`: `CLOCK_BOOTTIME` (ns) of the capture of the last valid reading
    /// (0 = none yet).
    pub reading_ns: u64,
    /// `DistanceMm` (0 = unknown).
    pub distance_mm: u32,
    /// `NearThresholdMm`.
    pub near_threshold_mm: u32,
    /// `FarThresholdMm`.
    pub far_threshold_mm: u32,
    /// `Mode`.
    pub mode: Mode,
    /// `RateHz`.
    pub rate_hz: f64,
    /// `PowerEstimateMw`.
    pub power_mw: f64,
    /// `GetStatus()["EnergyMj"]`: the modelled energy of the cycles counted in `cycles`
    /// since the daemon started (mJ; the energy meter's total, each cycle with the sleep
    /// after it).
    pub energy_mj: f64,
    /// `LastError`.
    pub last_error: String,
    /// Exposure per raw image (µs).
    pub exposure_us: f64,
    /// Cycles run.
    pub cycles: u64,
    /// Valid readings.
    pub valid_readings: u64,
    /// Failed cycles.
    pub errors: u64,
    /// Backend description.
    pub backend: String,
    /// How near readings are checked for plausibility (thesis 2.2.1): `"calibrated"` (the
    /// calibration's amplitude scale), `"nominal"` (no amplitude calibration: the config's
    /// nominal scale), `""` before the first cycle.
    pub amplitude_check: &'static str,
    /// The rule that decided the last reading (or released a held Near).
    pub reason: Reason,
}

/// Which rule decided a reading (`GetStatus()["Reason"]`; issue 34, for issue 37's
/// `tofprox monitor --json` rows).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Reason {
    /// No reading yet.
    #[default]
    None,
    /// The ROI statistic against the thresholds (near at once, far after the debounce).
    Distance,
    /// Nothing in range: no pixel returned enough light for a target (far).
    NothingInRange,
    /// Every code on a rail from the sensor's own return: something too close to measure.
    Saturated,
    /// A dim near candidate unwrapped beyond `far_mm` at the second frequency (far).
    SecondFrequency,
    /// A presence probe saw no change: the last reading stands.
    Probe,
    /// Something pressed on the cover window (its return jumped while near): near.
    OnTheWindow,
    /// Near released: no valid reading for `loop.near_hold_ms`.
    HoldExpired,
    /// The loop stopped (no claim).
    Stopped,
}

impl Reason {
    /// The name published.
    pub fn as_str(self) -> &'static str {
        match self {
            Reason::None => "",
            Reason::Distance => "distance",
            Reason::NothingInRange => "nothing_in_range",
            Reason::Saturated => "saturated",
            Reason::SecondFrequency => "second_frequency",
            Reason::Probe => "probe_unchanged",
            Reason::OnTheWindow => "on_the_window",
            Reason::HoldExpired => "hold_expired",
            Reason::Stopped => "stopped",
        }
    }
}

/// What a client can claim (each held per unique bus name).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Claim {
    /// Native proximity (`ClaimProximity` on `org.tofprox.Proximity1`).
    Proximity,
    /// Depth frames (`ClaimDepth`).
    Depth,
    /// Proximity through the iio-sensor-proxy compatible interface.
    CompatProximity,
}
