//! A reading that reads every `step`-th row (`readout.row_step`, where the sequencer skips
//! rows): its frame is a frame of the **stepped array** — the array's rows `0, step, 2·step, …`
//! as a sensor of their own — so the one pipeline, the detector and every per-pixel stage
//! process it as any window, with the calibration taken at the same rows (thesis 3.1.2: the
//! rows converted, and so the read-out, fall by the step; each pixel read keeps its own
//! calibration).

use tofprox_core::SensorGeometry;
use tofprox_core::radiometry::AmplitudeScale;
use tofprox_core::readout::{calibration_every_nth_row, every_nth_row};

use crate::source::RawCycle;

use super::ModeCalibrations;

/// The calibration sets of the loop: the array's, and the stepped array's when readings skip
/// rows.
pub(super) struct Calibrations {
    /// For frames that read every row (depth frames, sources that cannot skip rows).
    pub(super) full: ModeCalibrations,
    /// For frames of the stepped array: its rows and the sets at every `step`-th row.
    stepped: Option<(usize, ModeCalibrations)>,
}

impl Calibrations {
    /// The sets for an array of `full_rows` rows read every `step`-th row (1: every row).
    pub(super) fn new(full: ModeCalibrations, step: usize, full_rows: usize) -> Self {
        let stepped = (step > 1).then(|| {
            let at = |c| calibration_every_nth_row(c, step);
            let amplitude = full.amplitude.as_ref().map(|a| AmplitudeScale {
                lsb_m2_per_us: every_nth_row(&a.lsb_m2_per_us, step),
            });
            let sets = ModeCalibrations {
                two_phase: at(&full.two_phase),
                four_phase: at(&full.four_phase),
                amplitude,
            };
            (full_rows.div_ceil(step), sets)
        });
        Self { full, stepped }
    }

    /// The sets a frame of window `g` is processed with: the stepped array's when `g` is one
    /// of its windows.
    pub(super) fn of(&self, g: SensorGeometry) -> &ModeCalibrations {
        match &self.stepped {
            Some((rows, sets)) if g.full_rows == *rows => sets,
            _ => &self.full,
        }
    }
}

/// A capture read every `step`-th row of its window (`step` > 1, the window starting on a row
/// the step reads) as a frame of the stepped array: its window's first row and the array's
/// rows divided by the step. The rows read are already the frame's rows.
pub(super) fn on_stepped_array(mut cycle: RawCycle, step: usize) -> RawCycle {
    if step > 1 {
        let g = &mut cycle.geometry;
        g.roi_origin[0] /= step;
        g.full_rows = g.full_rows.div_ceil(step);
    }
    cycle
}
