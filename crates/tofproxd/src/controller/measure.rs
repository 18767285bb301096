//! Measure: the frame through the one pipeline of its mode — processed once here and passed
//! along —, near depths without a plausible return flagged, dim near candidates confirmed at
//! a second frequency, the detector's reading, and everything the later stages read from the
//! frame ([`Measurement`]): after this stage nothing looks at the frame again.

use tofprox_core::SensorGeometry;
use tofprox_core::crosstalk::flag_window_explained;
use tofprox_core::frame::RoiStats;
use tofprox_core::pipeline::{Calibration, DepthFrame, Pipeline};
use tofprox_core::proximity::{ProximityReading, Roi};
use tofprox_core::radiometry::{NearPlausibility, common_mode_lsb, flag_implausible_near};
use tofprox_core::readout::{at_frequency_ratio, mean_dark_lsb};

use crate::config::Mode;
use crate::cputime::thread_cpu;
use crate::hub::DepthMessage;
use crate::policy::second_frequency::{DimNearRule, dim_near_candidates, reject_aliased};
use crate::policy::window::WINDOW_CHANGE_BOUND;
use crate::policy::{AmbientObservation, CandidateObservation, saturating_fraction_at};
use crate::source::{CycleRequest, FrameSource, RawCycle, RawImages, SourceError, SourceErrorKind};

use super::Controller;
use super::capture::check_cycle;
use super::report::depth_message;
use super::slots::{detector_slot, mode_index, pipeline_slot, process_images};
use super::window::{WindowView, window_view};

/// What the measure stage read from one frame: all that the later stages (window, probe,
/// decide, report) need of it.
pub(super) struct Measurement {
    /// The ROI in the frame's coordinates.
    pub(super) roi: Roi,
    /// The detector's reading.
    pub(super) reading: ProximityReading,
    /// A reading: a distance, near, or nothing in range.
    pub(super) valid: bool,
    /// Saturated and low-amplitude fractions over the ROI.
    pub(super) stats: RoiStats,
    /// For the ambient switch (4-phase frames).
    pub(super) ambient: Option<AmbientObservation>,
    /// The second frequency found a far target.
    pub(super) aliased_far: bool,
    /// The second-frequency capture of this cycle, if one was taken.
    pub(super) second: Option<RawCycle>,
    /// Fraction of the ROI saturated in the second-frequency capture (0 without one).
    pub(super) saturated_f2: f32,
    /// Fraction of the ROI a longer exposure would saturate, in either capture.
    pub(super) saturated_when_longer: f32,
    /// Near pixels the cover window alone can explain (`flag_window_explained`).
    pub(super) window_explained: usize,
    /// What the cover-window monitor reads from the frame.
    pub(super) window: WindowView,
    /// An object pressed on the cover window made this reading near (`policy::window`; set by
    /// the window stage).
    pub(super) on_the_window: bool,
    /// The depth message, when asked for.
    pub(super) depth: Option<DepthMessage>,
}

impl<S: FrameSource> Controller<S> {
    /// Measure: the ambient indicator from the raw images, the frame through the one pipeline
    /// of its mode (pipelines and the detector are rebuilt when the window changes), near
    /// depths without a plausible return flagged, dim near candidates confirmed at a second
    /// frequency, the detector's reading. Everything that can fail a cycle fails here, before
    /// the monitor or a policy sees the frame.
    pub(super) fn measure(
        &mut self,
        cycle: &RawCycle,
        req: &CycleRequest,
        captured: Mode,
        depth_at_ns: Option<u64>,
    ) -> Result<Measurement, SourceError> {
        let g = cycle.geometry;
        let roi = self.roi_of(g);
        if roi.rows == 0 || roi.cols == 0 {
            return Err(SourceError::new(
                SourceErrorKind::Unsupported,
                "the ROI lies outside the read-out window",
            ));
        }
        let indicator_lsb =
            (captured == Mode::FourPhase).then(|| self.ambient_indicator_lsb(cycle, roi));
        let i = mode_index(captured);
        pipeline_slot(
            &mut self.pipes[i],
            self.calib.of(g).for_mode(captured),
            self.cfg.processing.min_amplitude_lsb,
            captured,
            g,
            (cycle.exposure_us, self.window.scale()),
        )?;
        // the cycle's pipeline leaves its slot while its frame is read and goes back after
        let Some((geo, mut pipe)) = self.pipes[i].take() else {
            return Err(SourceError::new(SourceErrorKind::Other, "pipeline missing"));
        };
        let frame_in = (cycle, req, captured, roi);
        let m = self.measure_frame(&mut pipe, frame_in, indicator_lsb, depth_at_ns);
        self.pipes[i] = Some((geo, pipe));
        m
    }

    /// The stages over this cycle's frame, processed here once by `pipe` and passed along
    /// (`depth_at_ns`: the capture time when a depth message is wanted).
    fn measure_frame(
        &mut self,
        pipe: &mut Pipeline,
        (cycle, req, captured, roi): (&RawCycle, &CycleRequest, Mode, Roi),
        indicator_lsb: Option<f32>,
        depth_at_ns: Option<u64>,
    ) -> Result<Measurement, SourceError> {
        let g = cycle.geometry;
        process_images(pipe, &cycle.frames, &cycle.phases_deg, cycle.frames.dim().0)?;
        let (frame, used) = pipe.frame_mut_and_calibration();
        let ambient = match indicator_lsb {
            Some(indicator_lsb) => Some(AmbientObservation {
                indicator_lsb,
                discrepancy_mm: self.two_phase_discrepancy_mm(frame, cycle, roi)?,
            }),
            None => None,
        };
        let (dim, window_explained) = self.flag_wrapped_near(frame, used, cycle, captured, roi)?;
        // dim candidates matter only when they can make or hold a near reading
        let decisive = !dim.is_empty()
            && detector_slot(&mut self.detector, &self.cfg, g, roi)?.statistic_below_far(frame);
        let second = self.second_frequency_frame(req, cycle, captured, dim.len(), decisive)?;
        let aliased_far = self.apply_second_frequency(frame, cycle, &dim, second.as_ref());
        // saturation at the second frequency counts too: the confirmation needs both measurable
        let saturated_f2 = second
            .as_ref()
            .map_or(0.0, |(_, f2)| f2.roi_stats(roi).saturated_fraction);
        let saturated_when_longer = std::iter::once(cycle)
            .chain(second.as_ref().map(|(c2, _)| c2))
            .map(|c| self.saturated_when_longer(c, roi))
            .fold(0.0f32, f32::max);
        let stats = frame.roi_stats(roi);
        let depth = depth_at_ns.map(|t| depth_message(frame, t));
        let reading = detector_slot(&mut self.detector, &self.cfg, g, roi)?.update(frame);
        // nothing in range is a reading too: far, DistanceMm "beyond range"
        let valid = reading.distance_mm.is_some() || reading.near || reading.no_target;
        // the frame's window view (a pass over the ROI's phasors) is taken only where a stage
        // reads it (`policy::window`): the monitor learns only from valid far readings without a
        // near candidate, and the object-on-the-glass rule judges readings that are not near;
        // neither reads a near reading or a far target found at the second frequency
        let may_need_view = !reading.near && !aliased_far;
        Ok(Measurement {
            roi,
            reading,
            valid,
            stats,
            ambient,
            aliased_far,
            second: second.map(|(c2, _)| c2),
            saturated_f2,
            saturated_when_longer,
            window_explained,
            window: if may_need_view {
                window_view(frame, used, captured, roi, cycle)
            } else {
                WindowView::default()
            },
            on_the_window: false,
            depth,
        })
    }

    /// Fraction of the ROI a longer exposure (× `exposure.step`) would saturate: auto-exposure
    /// never lengthens into it (`policy::saturating_fraction_at`).
    fn saturated_when_longer(&self, c: &RawCycle, roi: Roi) -> f32 {
        let (dark, max_code) = (
            self.dark_level(c.geometry, roi),
            c.geometry.max_code() as f32,
        );
        let step = self.cfg.exposure.step;
        match &c.frames {
            RawImages::U16(a) => saturating_fraction_at(a.view(), roi, dark, max_code, step),
            RawImages::F32(a) => saturating_fraction_at(a.view(), roi, dark, max_code, step),
        }
    }

    /// Background-light indicator from the data: the common-mode level of the four raw images
    /// above the dark level over the ROI (eq. 2.3 cancels it, eq. 2.2 does not — 5.1.2.3).
    fn ambient_indicator_lsb(&mut self, cycle: &RawCycle, roi: Roi) -> f32 {
        let dark = self.dark_level(cycle.geometry, roi);
        let ind = match &cycle.frames {
            RawImages::U16(a) => common_mode_lsb(a.view(), roi, dark),
            RawImages::F32(a) => common_mode_lsb(a.view(), roi, dark),
        };
        self.ambient_lsb = Some(ind);
        ind
    }

    /// The dark level over the ROI (the 4-phase set's offset: the raw codes' level).
    fn dark_level(&self, g: SensorGeometry, roi: Roi) -> f32 {
        mean_dark_lsb(self.calib.of(g).four_phase.offset.as_ref(), g, roi)
    }

    /// The ambient switch's cross-check of a 4-phase frame (when the switch is on): its first
    /// two images as a 2-phase frame, |2-phase − 4-phase| median depth over the ROI.
    fn two_phase_discrepancy_mm(
        &mut self,
        four_phase: &DepthFrame,
        cycle: &RawCycle,
        roi: Roi,
    ) -> Result<Option<f64>, SourceError> {
        if !self.cfg.ambient.enabled {
            return Ok(None);
        }
        let four = four_phase.roi_median_mm(roi);
        let p2 = pipeline_slot(
            &mut self.pipes[mode_index(Mode::TwoPhase)],
            &self.calib.of(cycle.geometry).two_phase,
            self.cfg.processing.min_amplitude_lsb,
            Mode::TwoPhase,
            cycle.geometry,
            (cycle.exposure_us, self.window.scale()),
        )?;
        let two = process_images(p2, &cycle.frames, &cycle.phases_deg, 2)?.roi_median_mm(roi);
        Ok(two.zip(four).map(|(a, b)| (a - b).abs()))
    }

    /// The plausibility of near depths: a near depth needs the amplitude of a real target
    /// (thesis 2.2.1, 1/d²), checked below the far threshold.
    fn plausibility(&self) -> NearPlausibility {
        NearPlausibility {
            reflectivity_floor: self.cfg.proximity.reflectivity_floor,
            depth_uncertainty_m: f64::from(self.cfg.proximity.depth_uncertainty_mm) / 1e3,
            check_below_m: f64::from(self.cfg.proximity.far_mm) / 1e3,
        }
    }

    /// No near from a wrapped phase: near depths of the processed frame without a plausible
    /// return are flagged invalid, and so are near pixels the cover window alone can explain
    /// (`policy::window`, the rule in docs/daemon.md; `used`: the calibration the frame was
    /// processed with). Returns the dim near candidates left (pixels to confirm at a second
    /// frequency before Near is published) and the number of window-explained pixels.
    fn flag_wrapped_near(
        &mut self,
        frame: &mut DepthFrame,
        used: &Calibration,
        cycle: &RawCycle,
        captured: Mode,
        roi: Roi,
    ) -> Result<(Vec<(usize, usize)>, usize), SourceError> {
        let g = cycle.geometry;
        let plaus = self.plausibility();
        let rule = DimNearRule {
            confirm_reflectivity: self.cfg.proximity.confirm_reflectivity,
            brightest_far_gain: self.cfg.proximity.brightest_far_gain,
            depth_uncertainty_m: plaus.depth_uncertainty_m,
            check_below_m: plaus.check_below_m,
            modulation_hz: g.modulation_hz,
        };
        let scale = super::slots::amplitude_scale_slot(
            &mut self.amp_scale,
            self.calib.of(g).amplitude.as_ref(),
            self.cfg.proximity.nominal_amplitude_scale,
            g,
        )?;
        let implausible = flag_implausible_near(frame, scale.view(), cycle.exposure_us, &plaus);
        if let Some(n) = implausible.filter(|&n| n > 0) {
            tracing::debug!("{n} pixels with a near depth but no plausible return (wrapped phase)");
        }
        let t = cycle.exposure_us;
        let below_m = plaus.check_below_m as f32;
        let window_explained = used.crosstalk.as_ref().map_or(0, |x| {
            flag_window_explained(frame, x, captured, roi, t, WINDOW_CHANGE_BOUND, below_m)
        });
        let dim = dim_near_candidates(frame, roi, scale.view(), t, &rule);
        Ok((dim, window_explained))
    }

    /// The second frequency's verdict on the dim near candidates, applied to the processed
    /// frame (aliases of a far target lose their near depth). Returns whether it found a far
    /// target — then the frame is not "only the window returns".
    fn apply_second_frequency(
        &mut self,
        frame: &mut DepthFrame,
        cycle: &RawCycle,
        dim: &[(usize, usize)],
        second: Option<&(RawCycle, DepthFrame)>,
    ) -> bool {
        let Some((c2, f2)) = second else {
            return false;
        };
        let check_below_m = self.plausibility().check_below_m;
        let f2_hz = c2.geometry.modulation_hz;
        let f1_hz = cycle.geometry.modulation_hz;
        let v = reject_aliased(frame, f1_hz, f2, f2_hz, dim, check_below_m);
        tracing::debug!("second frequency {f2_hz} Hz: {v:?}");
        self.second.note(v);
        v.aliased > 0
    }

    /// The second-frequency capture of this cycle's request when the policy asks for one (dim
    /// near candidates, Near not published), processed: `None` when not asked or the source
    /// cannot (then the amplitude test decides alone, `policy::second_frequency`).
    fn second_frequency_frame(
        &mut self,
        req: &CycleRequest,
        cycle: &RawCycle,
        captured: Mode,
        dim_candidates: usize,
        decisive: bool,
    ) -> Result<Option<(RawCycle, DepthFrame)>, SourceError> {
        let g = cycle.geometry;
        let Some(f2_hz) = self.second.next(CandidateObservation {
            dim_candidates,
            decisive,
            near_published: self.near,
            captured_hz: g.modulation_hz,
        }) else {
            return Ok(None);
        };
        let req2 = CycleRequest {
            mode: captured,
            exposure_us: cycle.exposure_us,
            modulation_hz: Some(f2_hz),
            ..*req
        };
        let cpu_before = thread_cpu();
        let captured2 = self.source.cycle(&req2);
        self.source_cpu += thread_cpu().saturating_sub(cpu_before);
        let c2 = match captured2 {
            Ok(c) => self.on_array(c, &req2),
            Err(e) if e.kind() == SourceErrorKind::Unsupported => {
                self.second.refused(&e.to_string());
                return Ok(None);
            }
            Err(e) => return Err(e),
        };
        let mode2 = check_cycle(&c2)?;
        let g2 = c2.geometry;
        let same_window = SensorGeometry {
            modulation_hz: g.modulation_hz,
            ..g2
        } == g;
        if !same_window || (g2.modulation_hz - f2_hz).abs() >= 1.0 {
            return Err(SourceError::new(
                SourceErrorKind::CorruptFrame,
                format!(
                    "second-frequency capture at {} Hz of window {:?} {}x{}: {f2_hz} Hz of this cycle's window asked",
                    g2.modulation_hz, g2.roi_origin, g2.rows, g2.cols
                ),
            ));
        }
        // one pipeline per mode at the second frequency, kept while the window is the same
        // (building one is the costly part: its CPU time is the reading's energy too)
        let slot = &mut self.pipes_f2[mode_index(mode2)];
        if slot.as_ref().is_none_or(|(geo, _)| *geo != g2) {
            *slot = None;
        }
        let calib = if slot.is_none() {
            at_frequency_ratio(self.calib.of(g).for_mode(mode2), f2_hz / g.modulation_hz)
        } else {
            Calibration::default()
        };
        let min_amp = self.cfg.processing.min_amplitude_lsb;
        let exposure = (c2.exposure_us, self.window.scale());
        let p = pipeline_slot(slot, &calib, min_amp, mode2, g2, exposure)?;
        let k = c2.frames.dim().0;
        let f2 = process_images(p, &c2.frames, &c2.phases_deg, k)?.clone();
        Ok(Some((c2, f2)))
    }
}
