//! The calibration chain (`docs/calibration.md`, thesis 5.1): which part is extracted after which,
//! what a set still lacks, and the parts dropped because a part they were extracted with changed —
//! kept in the set (`[dropped.<part>]`: why, and the recording and captures to extract it from
//! again) until they are extracted again, so neither `tofprox calibrate` nor `tofprox info` can
//! lose them silently.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::{CalibPart, CalibrationSet, NONE, PartSource, invalid};
use crate::error::FormatError;

/// A part dropped from the set because `because` changed after it was extracted.
#[derive(Debug, Clone, PartialEq)]
pub struct Dropped {
    /// The part whose replacement made it stale.
    pub because: CalibPart,
    /// The recording it had been extracted from.
    pub recording: String,
    /// The captures it had been extracted from.
    pub captures: Vec<usize>,
}

impl Dropped {
    /// Why a part extracted with another `because` would mis-correct (thesis 5.1).
    pub fn reason(&self) -> &'static str {
        match self.because {
            CalibPart::Intrinsics => {
                "it was extracted through the rays of another lens (or of none): every pixel's expected phase on the flat target changed"
            }
            CalibPart::Offset => {
                "it was extracted with another dark frame (or the mid code) subtracted"
            }
            CalibPart::Crosstalk => "it was extracted with another crosstalk subtracted",
            CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase => {
                "an FPPN map is absolute w.r.t. the wiggling table it was extracted after (or its absence)"
            }
            CalibPart::Fppn | CalibPart::Fppn2Phase | CalibPart::Amplitude => {
                "a part it depends on changed"
            }
        }
    }
}

/// `[dropped.<part>]` of `calibration.toml`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct DroppedToml {
    because: String,
    source_recording: String,
    source_captures: Vec<usize>,
}

/// Where a part of the documented chain stands in a set.
#[derive(Debug, Clone, PartialEq)]
pub enum PartState {
    /// Present and extracted after every part it needs.
    Current,
    /// Present but extracted while these parts it needs were absent: extracting them drops it.
    Provisional {
        /// The parts it was extracted without.
        without: Vec<CalibPart>,
    },
    /// Dropped because a part it depends on changed; to be extracted again.
    Stale(Dropped),
    /// Not in the set and needed for a complete set.
    Missing,
    /// Not in the set and not needed (the lens for a small central window, the crosstalk without
    /// a cover window).
    Optional,
}

/// One link of the chain: a part, the parts it is extracted after, and its state.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainEntry {
    /// The part.
    pub part: CalibPart,
    /// The parts it is extracted after (its dependencies, optional ones included).
    pub after: Vec<CalibPart>,
    /// Where it stands.
    pub state: PartState,
}

impl CalibPart {
    /// The parts this one is extracted after (thesis 5.1: lens → offset → crosstalk → wiggling
    /// → FPPN); the amplitude scale needs none (the N-phase amplitude is offset-free).
    pub fn after(self) -> Vec<CalibPart> {
        use CalibPart::*;
        match self {
            Intrinsics | Offset | Amplitude => vec![],
            Crosstalk => vec![Offset],
            Wiggling2Phase | Wiggling4Phase => vec![Intrinsics, Offset, Crosstalk],
            Fppn | Fppn2Phase => {
                let alg = self
                    .algorithm()
                    .unwrap_or(tofprox_core::Algorithm::FourPhase);
                vec![Intrinsics, Offset, Crosstalk, CalibPart::wiggling(alg)]
            }
        }
    }

    /// Whether a complete set needs this part: every part but the lens (a small central window
    /// is nearly on-axis) and the crosstalk (only behind a cover window).
    pub fn required(self) -> bool {
        !matches!(self, CalibPart::Intrinsics | CalibPart::Crosstalk)
    }

    /// The `tofprox calibrate` command that extracts it.
    pub fn command(self) -> &'static str {
        match self {
            CalibPart::Intrinsics => "intrinsics",
            CalibPart::Offset => "fpn",
            CalibPart::Crosstalk => "crosstalk",
            CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase | CalibPart::Amplitude => {
                "wiggling"
            }
            CalibPart::Fppn | CalibPart::Fppn2Phase => "fppn",
        }
    }

    /// What a recording must hold for [`CalibPart::command`].
    fn needs(self) -> &'static str {
        match self {
            CalibPart::Intrinsics => "correlation captures of a flat wall at ≥ 3 distances",
            CalibPart::Offset => "dark captures",
            CalibPart::Crosstalk => "captures with conditions.no_target = 1",
            CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase | CalibPart::Amplitude => {
                "a correlation capture with distance_m"
            }
            CalibPart::Fppn | CalibPart::Fppn2Phase => {
                "a 4-phase flat-wall capture with distance_m"
            }
        }
    }
}

impl CalibrationSet {
    /// The chain: every part in order of extraction with the parts it is extracted after and
    /// where it stands in this set.
    pub fn chain(&self) -> Vec<ChainEntry> {
        CalibPart::ALL
            .into_iter()
            .map(|part| ChainEntry {
                part,
                after: part.after(),
                state: self.part_state(part),
            })
            .collect()
    }

    fn part_state(&self, part: CalibPart) -> PartState {
        if self.has(part) {
            let without = self.extracted_without(part);
            return if without.is_empty() {
                PartState::Current
            } else {
                PartState::Provisional { without }
            };
        }
        match self.dropped.get(&part) {
            Some(d) => PartState::Stale(d.clone()),
            None if part.required() => PartState::Missing,
            None => PartState::Optional,
        }
    }

    /// Required parts this present part was extracted without (recorded as `"none"`).
    fn extracted_without(&self, part: CalibPart) -> Vec<CalibPart> {
        let Some(d) = self.deps.get(&part) else {
            return Vec::new();
        };
        let none = |v: &Option<String>| v.as_deref() == Some(NONE);
        part.after()
            .into_iter()
            .filter(|dep| dep.required())
            .filter(|dep| match dep {
                CalibPart::Offset => none(&d.offset),
                CalibPart::Wiggling2Phase | CalibPart::Wiggling4Phase => none(&d.wiggling),
                _ => false,
            })
            .collect()
    }

    /// Whether every required part is present and extracted after the parts it needs.
    pub fn is_complete(&self) -> bool {
        self.chain()
            .iter()
            .all(|e| matches!(e.state, PartState::Current | PartState::Optional))
    }

    /// The parts dropped as stale and not extracted again yet.
    pub fn dropped(&self) -> &BTreeMap<CalibPart, Dropped> {
        &self.dropped
    }

    /// The commands that complete the set written to `out`, in the chain's order, one per
    /// `tofprox calibrate` step (a stale part names the recording and captures it came from; a
    /// missing one what its recording must hold). Empty for a complete set.
    pub fn next_steps(&self, out: &str) -> Vec<String> {
        let mut steps: Vec<String> = Vec::new();
        let mut done: Vec<&str> = Vec::new();
        for e in self.chain() {
            let cmd = e.part.command();
            let (rec, why) = match &e.state {
                PartState::Current | PartState::Optional => continue,
                PartState::Stale(d) => (
                    capture_args(&d.recording, &d.captures),
                    format!("{} changed since {} was extracted", d.because, e.part),
                ),
                PartState::Missing => ("REC".to_string(), format!("REC: {}", e.part.needs())),
                PartState::Provisional { without } => (
                    capture_args(
                        self.sources
                            .get(&e.part)
                            .map_or("REC", |s| s.recording.as_str()),
                        self.sources.get(&e.part).map_or(&[][..], |s| &s.captures),
                    ),
                    format!(
                        "{} was extracted without {} and is dropped when that is added",
                        e.part,
                        names(without)
                    ),
                ),
            };
            if done.contains(&cmd) {
                continue;
            }
            done.push(cmd);
            steps.push(format!(
                "tofprox calibrate {cmd} {rec} --out {out}   # {why}"
            ));
        }
        steps
    }

    /// Bookkeeping of [`CalibrationSet::record_part`]: `part` was just extracted (no longer
    /// dropped); `dropped` went stale because of it (`before`: the sources before the drop).
    pub(super) fn remember_dropped(
        &mut self,
        part: CalibPart,
        dropped: &[CalibPart],
        before: &BTreeMap<CalibPart, PartSource>,
    ) {
        self.dropped.remove(&part);
        for p in dropped {
            let src = before.get(p).cloned().unwrap_or_default();
            self.dropped.insert(
                *p,
                Dropped {
                    because: part,
                    recording: src.recording,
                    captures: src.captures,
                },
            );
        }
    }

    pub(super) fn dropped_toml(&self) -> BTreeMap<String, DroppedToml> {
        self.dropped
            .iter()
            .filter(|(p, _)| !self.has(**p))
            .map(|(p, d)| {
                let t = DroppedToml {
                    because: d.because.name().to_string(),
                    source_recording: d.recording.clone(),
                    source_captures: d.captures.clone(),
                };
                (p.name().to_string(), t)
            })
            .collect()
    }
}

/// `[dropped]` of `calibration.toml` read back; part names are checked.
pub(super) fn dropped_from_toml(
    t: &BTreeMap<String, DroppedToml>,
) -> Result<BTreeMap<CalibPart, Dropped>, FormatError> {
    let part = |name: &str, key: String| {
        CalibPart::ALL
            .into_iter()
            .find(|p| p.name() == name)
            .ok_or_else(|| invalid(format!("{name:?} is not a calibration part")).key(key))
    };
    let mut out = BTreeMap::new();
    for (name, d) in t {
        let p = part(name, format!("dropped.{name}"))?;
        let because = part(&d.because, format!("dropped.{name}.because"))?;
        out.insert(
            p,
            Dropped {
                because,
                recording: d.source_recording.clone(),
                captures: d.source_captures.clone(),
            },
        );
    }
    Ok(out)
}

/// `REC --capture I` for a single capture, `REC` otherwise.
fn capture_args(recording: &str, captures: &[usize]) -> String {
    match captures {
        [i] => format!("{recording} --capture {i}"),
        _ => recording.to_string(),
    }
}

fn names(parts: &[CalibPart]) -> String {
    parts
        .iter()
        .map(|p| p.name())
        .collect::<Vec<_>>()
        .join(", ")
}
