//! The socket publisher's wire format, schema version [`SCHEMA_VERSION`]: JSON Lines, one
//! object per line (UTF-8, `\n`-terminated), every object a whole snapshot of what a
//! proximity client needs, its `type` saying why it was sent (docs/daemon.md, "The socket
//! publisher"). Pure: the caller gives the time of a status line.
//!
//! | field | type | meaning |
//! |---|---|---|
//! | `version` | integer | [`SCHEMA_VERSION`]; a client refuses a major version it does not know |
//! | `type` | string | `"status"` (on connect; state, `has_sensor` or `last_error` changed), `"near"` (Near changed), `"reading"` (a valid reading) |
//! | `timestamp_ns` | integer | `CLOCK_BOOTTIME` (ns): of the capture for `near` and `reading` (the capture of the reading that changed Near), of the publication for `status` |
//! | `near` | bool | Near (hysteresis and debounce applied) |
//! | `distance_mm` | integer or null | the reading's distance; null when it is not a distance (`range` says why) |
//! | `range` | string | `"measured"` (`distance_mm` is the distance), `"nothing_in_range"` (a valid reading with no target), `"unknown"` (no reading yet, a failed cycle, or too close to measure while near) |
//! | `state` | string | `off`, `starting`, `running`, `error`, `unavailable` |
//! | `mode` | string | `2phase` or `4phase` |
//! | `has_sensor` | bool | a sensor is attached |
//! | `last_error` | string | the last cycle's error, `""` when none |
//! | `reason` | string | the rule that decided the last reading (`Reason` on D-Bus: `distance`, `nothing_in_range`, `saturated`, `second_frequency`, `probe_unchanged`, `hold_expired`, `stopped`; `""` before the first) |
//!
//! A reading that changes Near gives two lines with the same `timestamp_ns`: `near`, then
//! `reading`.

use serde::Serialize;

use super::StatusChange;
use crate::hub::Status;

/// The schema's version (the `version` of every line). Raised when a field changes meaning
/// or goes away; new fields may be added without raising it (clients ignore unknown fields).
pub const SCHEMA_VERSION: u32 = 1;

/// Why a line was sent (its `type`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LineKind {
    /// On connect, and when the state, `has_sensor` or `last_error` changed.
    Status,
    /// Near changed.
    Near,
    /// A valid reading.
    Reading,
}

/// What a reading's distance is (the `range` field).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Range {
    /// A distance.
    Measured,
    /// A valid reading with nothing in range
    /// ([`crate::controller::DISTANCE_BEYOND_RANGE_MM`] on D-Bus).
    NothingInRange,
    /// No distance: no reading yet, a failed cycle, or too close to measure (0 on D-Bus).
    Unknown,
}

impl Range {
    /// Of the hub's `distance_mm` (D-Bus `DistanceMm`: 0 unknown, `u32::MAX` nothing in
    /// range), with the distance when it is one.
    pub fn of(distance_mm: u32) -> (Self, Option<u32>) {
        match distance_mm {
            0 => (Range::Unknown, None),
            crate::controller::DISTANCE_BEYOND_RANGE_MM => (Range::NothingInRange, None),
            d => (Range::Measured, Some(d)),
        }
    }
}

/// One line's object.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Line<'a> {
    /// [`SCHEMA_VERSION`].
    pub version: u32,
    /// Why it was sent.
    #[serde(rename = "type")]
    pub kind: LineKind,
    /// `CLOCK_BOOTTIME` (ns).
    pub timestamp_ns: u64,
    /// Near.
    pub near: bool,
    /// Distance (mm), `None` when the reading is not a distance.
    pub distance_mm: Option<u32>,
    /// What `distance_mm` is.
    pub range: Range,
    /// Service state.
    pub state: &'a str,
    /// Processing mode.
    pub mode: &'a str,
    /// A sensor is attached.
    pub has_sensor: bool,
    /// The last error (`""`: none).
    pub last_error: &'a str,
    /// The rule that decided the last reading (`""`: none yet).
    pub reason: &'a str,
}

impl<'a> Line<'a> {
    /// The line of `kind` for the status `s` at `timestamp_ns`.
    pub fn new(kind: LineKind, s: &'a Status, timestamp_ns: u64) -> Self {
        let (range, distance_mm) = Range::of(s.distance_mm);
        Self {
            version: SCHEMA_VERSION,
            kind,
            timestamp_ns,
            near: s.near,
            distance_mm,
            range,
            state: s.state.as_str(),
            mode: s.mode.as_str(),
            has_sensor: s.has_sensor,
            last_error: &s.last_error,
            reason: s.reason.as_str(),
        }
    }

    /// As one JSON Lines line, `\n` included.
    pub fn to_line(&self) -> String {
        // a struct of strings, numbers and bools always serialises
        let mut text = serde_json::to_string(self).unwrap_or_default();
        text.push('\n');
        text
    }
}

/// The lines for one change, in order (none when nothing a proximity client sees changed):
/// `status` (publication time `now_ns`), `near`, `reading`.
pub fn lines_for(change: StatusChange<'_>, now_ns: u64) -> Vec<String> {
    let (b, a) = (change.before, change.after);
    let mut out = Vec::new();
    if b.state != a.state || b.has_sensor != a.has_sensor || b.last_error != a.last_error {
        out.push(Line::new(LineKind::Status, a, now_ns).to_line());
    }
    if change.near_changed() {
        out.push(Line::new(LineKind::Near, a, a.near_changed_ns).to_line());
    }
    if change.reading() {
        out.push(Line::new(LineKind::Reading, a, a.reading_ns).to_line());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;
    use crate::hub::{Hub, State, StatusUpdate};

    fn parse(line: &str) -> serde_json::Value {
        assert!(line.ends_with('\n') && !line[..line.len() - 1].contains('\n'));
        serde_json::from_str(line).expect("json")
    }

    #[test]
    fn a_reading_that_changes_near_gives_near_then_reading_with_its_capture_time() {
        let (hub, _d) = Hub::new(&Config::default(), "test".into());
        let (b, a) = hub.apply(&StatusUpdate {
            state: Some(State::Running),
            near: Some(true),
            distance_mm: Some(48),
            timestamp_ns: Some(7_000),
            valid_reading: true,
            cycle: true,
            ..StatusUpdate::default()
        });
        let lines = lines_for(
            StatusChange {
                before: &b,
                after: &a,
            },
            9_000,
        );
        let v: Vec<_> = lines.iter().map(|l| parse(l)).collect();
        assert_eq!(v.len(), 3);
        assert_eq!(v[0]["type"], "status");
        assert_eq!(v[0]["state"], "running");
        assert_eq!(v[0]["timestamp_ns"], 9_000);
        assert_eq!(v[1]["type"], "near");
        assert_eq!(v[2]["type"], "reading");
        for x in &v[1..] {
            assert_eq!(x["version"], SCHEMA_VERSION);
            assert_eq!(x["near"], true);
            assert_eq!(x["distance_mm"], 48);
            assert_eq!(x["range"], "measured");
            assert_eq!(x["timestamp_ns"], 7_000);
        }
    }

    #[test]
    fn nothing_in_range_is_null_and_an_unchanged_status_sends_nothing() {
        let (hub, _d) = Hub::new(&Config::default(), "test".into());
        let (b, a) = hub.apply(&StatusUpdate {
            distance_mm: Some(u32::MAX),
            timestamp_ns: Some(5),
            valid_reading: true,
            ..StatusUpdate::default()
        });
        let change = StatusChange {
            before: &b,
            after: &a,
        };
        let v: Vec<_> = lines_for(change, 6).iter().map(|l| parse(l)).collect();
        assert_eq!(v.len(), 1);
        assert_eq!(v[0]["type"], "reading");
        assert!(v[0]["distance_mm"].is_null());
        assert_eq!(v[0]["range"], "nothing_in_range");
        assert_eq!(v[0]["near"], false);
        let same = StatusChange {
            before: &a,
            after: &a,
        };
        assert!(lines_for(same, 7).is_empty());
    }
}
