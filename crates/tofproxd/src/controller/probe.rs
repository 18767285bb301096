//! The presence probe (`policy::probe`): while far and still (or near and still), one raw image
//! against the last such reading's instead of the full reading; and, after a full reading, the probe's reference.

use std::time::Duration;

use ndarray::{ArrayView2, ArrayView3, Axis, Slice};
use tofprox_core::pipeline::RawSample;
use tofprox_core::proximity::Roi;
use tofprox_core::readout::crop_map;
use tofprox_core::{RowWindow, SensorGeometry};

use crate::boottime::boottime_ns;
use crate::config::Mode;
use crate::cputime::thread_cpu;
use crate::hub::{Reason, State, StatusUpdate};
use crate::policy::probe::{
    ProbeReference, ProbeVerdict, change_threshold_lsb, probe_image, tile_means,
};
use crate::policy::{RateObservation, stepped_roi};
use crate::source::{FrameSource, RawCycle, RawImages, SourceErrorKind};

use super::measure::Measurement;
use super::report::shown_distance_mm;
use super::{Controller, StepOutcome};

/// What a probe that saw no change publishes again: the last full reading.
#[derive(Debug, Clone, Copy)]
pub(super) struct LastFull {
    /// `DistanceMm` shown.
    shown_mm: u32,
    /// The detector's distance.
    distance_mm: Option<u32>,
    /// Nothing in range.
    no_target: bool,
    /// Near was published.
    near: bool,
}

impl<S: FrameSource> Controller<S> {
    /// The presence probe (`policy::probe`), when due: one raw image at `exposure.min_us`.
    /// `Some`: the cycle's outcome (no change: the last reading again; or the failure);
    /// `None`: no probe, or it saw a change — the full reading runs now, with the probe's
    /// energy in it.
    pub(super) fn presence_probe(&mut self) -> Option<StepOutcome> {
        if self.ambient.mode() != Mode::TwoPhase
            || self.ambient.probe_due()
            || self.saturation.confirm_due()
            || !self.source.supports_single_image()
        {
            return None;
        }
        let last = self.last_full?;
        let due = self.probe.due(self.near, self.rate.still_readings())?;
        let image = due.image;
        let step = self.probe_step;
        let mut req = self.request(false, self.read_step);
        req.exposure_us = self.cfg.exposure.min_us;
        req.single_image = Some(image);
        if step > 1 {
            let full_rows = u16::try_from(self.source.full_size().0).unwrap_or(u16::MAX);
            let w = req
                .row_window
                .get_or_insert(RowWindow::rows_only(0, full_rows));
            w.row_step = u16::try_from(step).unwrap_or(1);
        }
        self.since_valid.count(self.last_sleep);
        let result = self.source.cycle(&req);
        let cycle = match result {
            Ok(c) => self.on_array(c, &req),
            Err(e) if e.kind() == SourceErrorKind::Unsupported => {
                tracing::warn!("presence probe refused by the source ({e}): full readings");
                self.probe.refused();
                self.last_sleep = Duration::ZERO;
                return None;
            }
            Err(e) => return Some(self.fail(e)),
        };
        self.since_valid.count(cycle.timings().active());
        let captured_ns = boottime_ns();
        self.cpu_at_capture = thread_cpu();
        self.source_cpu = Duration::ZERO;
        let verdict = self.judge_probe(&cycle);
        tracing::debug!("presence probe: {verdict:?}");
        let rate_hz = self.rate.rate_hz();
        let obs = self.observe(&cycle, rate_hz).with_cpu(self.reading_cpu());
        if let ProbeVerdict::Changed { .. } = verdict {
            self.energy.carry(obs);
            self.last_sleep = Duration::ZERO;
            return None;
        }
        // nothing changed: the last reading stands, as a reading of its own (still)
        self.rate.next(RateObservation {
            near: last.near,
            distance_mm: last.distance_mm,
            no_target: last.no_target,
        });
        let energy = self.energy.next(obs);
        self.last_sleep = energy.sleep;
        self.consecutive_failures = 0;
        self.since_valid.reading(self.source.now());
        self.state = State::Running;
        Some(StepOutcome {
            update: StatusUpdate {
                state: Some(self.state),
                near: Some(last.near),
                timestamp_ns: Some(captured_ns),
                distance_mm: Some(last.shown_mm),
                rate_hz: Some(self.rate.rate_hz()),
                power_mw: Some(energy.average_mw),
                reason: Some(Reason::Probe),
                valid_reading: true,
                cycle: true,
                ..StatusUpdate::default()
            },
            sleep: energy.sleep,
            near: last.near,
            distance_mm: last.distance_mm,
            valid: true,
            captured_mode: Some(Mode::TwoPhase),
            ..StepOutcome::default()
        })
    }

    /// The probe image against the reference: a change when the window differs or any tile
    /// moved by more than half the weakest near return ([`change_threshold_lsb`]).
    fn judge_probe(&mut self, cycle: &RawCycle) -> ProbeVerdict {
        let Some((window, step, cos_min)) = self
            .probe
            .reference()
            .map(|r| (r.geometry, r.row_step, r.cos_min))
        else {
            return self.probe.judge(&[], cycle.exposure_us, 0.0);
        };
        // the reference's window, every `step`-th row of it
        let read = SensorGeometry {
            rows: window.rows.div_ceil(step),
            ..window
        };
        let tiles = (cycle.geometry == read)
            .then(|| self.tiles_of(cycle, 0, window, step))
            .flatten();
        let Some(tiles) = tiles else {
            return self.probe.judge(&[], cycle.exposure_us, 0.0);
        };
        let threshold = change_threshold_lsb(
            self.k_floor,
            self.cfg.proximity.reflectivity_floor,
            f64::from(self.cfg.proximity.near_mm) / 1e3,
            cycle.exposure_us,
            cos_min,
        );
        self.probe.judge(&tiles, cycle.exposure_us, threshold)
    }

    /// Tile means of raw image `image` of `cycle` above the dark level, over the ROI of
    /// `window`, from every `step`-th row of the window: `cycle` read them all (a full reading,
    /// the reference) or only those (a probe).
    fn tiles_of(
        &self,
        cycle: &RawCycle,
        image: usize,
        window: SensorGeometry,
        step: usize,
    ) -> Option<Vec<f32>> {
        let rows = Slice::new(0, None, isize::try_from(step.max(1)).ok()?);
        let sparse = cycle.geometry.rows != window.rows;
        let roi = stepped_roi(self.roi_of(window), step);
        let dark = self
            .calib
            .of(window)
            .two_phase
            .offset
            .as_ref()
            .and_then(|o| crop_map(&o.dark_lsb, window, "offset").ok());
        let dark = dark.as_ref().map(|d| d.slice_axis(Axis(0), rows));
        // tiles of `probe.tile_px` rows of the array: `step` rows of the frame apart, each
        // row of the frame `step_of(window)` rows of the array
        let array_step = step * self.step_of(window);
        let (mid, tile) = (window.mid_code() as f32, self.probe.tile(array_step));
        let rows = (!sparse).then_some(rows);
        match &cycle.frames {
            RawImages::U16(a) => image_tile_means(a.view(), image, rows, dark, mid, roi, tile),
            RawImages::F32(a) => image_tile_means(a.view(), image, rows, dark, mid, roi, tile),
        }
    }

    /// After a full reading: a far, valid 2-phase reading leaves the probe its reference (the
    /// probe image's tile means per µs) and what a probe that sees no change publishes again;
    /// any other reading leaves none. A far the second frequency decided (a retroreflector
    /// one range further, eq. 2.7–2.9) is a far like any other: the probe asks only whether the
    /// scene changed since it was proved far, and a scene that did not change is still far.
    ///
    /// Near after near leaves one too when no pixel of the ROI saturated (a saturated code
    /// does not scale with the exposure, 3.1.2): a near probe compares with it, and a probe
    /// that sees no change publishes the Near again.
    pub(super) fn remember_for_probe(&mut self, cycle: &RawCycle, captured: Mode, m: &Measurement) {
        let far = m.valid && !m.reading.near && !self.near;
        let near = m.valid
            && m.reading.near
            && self.near
            && m.stats.saturated_fraction == 0.0
            && m.saturated_f2 == 0.0;
        let reference = ((far || near) && captured == Mode::TwoPhase && self.cfg.probe.enabled)
            .then(|| probe_image(&cycle.phases_deg, self.near_phase_rad))
            .flatten()
            .and_then(|(image, cos_min)| {
                // the probe's rows in this frame's rows (a frame of the stepped array has
                // every `step_of`-th row of the array already)
                let step = self.probe_step / self.step_of(cycle.geometry);
                let tiles = self.tiles_of(cycle, usize::from(image), cycle.geometry, step)?;
                let t = cycle.exposure_us as f32;
                Some(ProbeReference {
                    geometry: cycle.geometry,
                    row_step: step,
                    image,
                    per_us: tiles.iter().map(|v| v / t).collect(),
                    cos_min,
                    near,
                    nothing_in_range: far && m.reading.no_target,
                })
            });
        self.last_full = (far || near).then(|| LastFull {
            shown_mm: shown_distance_mm(&m.reading, self.cfg.proximity.far_mm),
            distance_mm: m.reading.distance_mm,
            no_target: m.reading.no_target,
            near,
        });
        self.probe.full_reading(reference);
    }
}

/// [`tile_means`] of raw image `image` of `frames` (None past the last), from the rows `rows`
/// selects (None: the frames hold only the rows read, a probe's sparse read-out).
fn image_tile_means<T: RawSample>(
    frames: ArrayView3<'_, T>,
    image: usize,
    rows: Option<Slice>,
    dark: Option<ArrayView2<'_, f32>>,
    mid_code: f32,
    roi: Roi,
    tile: (usize, usize),
) -> Option<Vec<f32>> {
    let img = frames.index_axis_move(Axis(0), (image < frames.dim().0).then_some(image)?);
    let img = match rows {
        Some(rows) => img.slice_axis_move(Axis(0), rows),
        None => img,
    };
    Some(tile_means(img, dark, mid_code, roi, tile))
}
