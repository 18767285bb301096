//! The capture's shape checked before anything reads it, and whether any of its codes is off
//! the rails.

use tofprox_core::Algorithm;
use tofprox_core::phasor::Quadrature;

use crate::config::Mode;
use crate::source::{RawCycle, SourceError, SourceErrorKind};

/// Validate a cycle's shape and reject dead frames (every code of every raw image on a
/// rail): such a frame never reaches the detector (it would read as saturated = near).
pub(super) fn check_cycle(c: &RawCycle) -> Result<Mode, SourceError> {
    let (k, rows, cols) = c.frames.dim();
    let g = &c.geometry;
    let bad = |m: String| Err(SourceError::new(SourceErrorKind::CorruptFrame, m));
    if rows == 0 || cols == 0 {
        return bad("empty frame".into());
    }
    if c.phases_deg.len() != k {
        return bad(format!("{k} raw images but {} phases", c.phases_deg.len()));
    }
    if let Err(e) = g.validate() {
        return bad(format!("bad sensor geometry: {e}"));
    }
    if (rows, cols) != (g.rows, g.cols) {
        return bad(format!(
            "{rows}x{cols} images but a {}x{} window",
            g.rows, g.cols
        ));
    }
    // [0, 90(, 180, 270)], or the same images of a sensor with another phase convention
    // (canonical shifts such as [0, 270]: evaluated with their quadrature)
    let mode = if k == 4 && Quadrature::of_canonical(&c.phases_deg, Algorithm::FourPhase).is_some()
    {
        Mode::FourPhase
    } else if k == 2 && Quadrature::of_canonical(&c.phases_deg, Algorithm::TwoPhase).is_some() {
        Mode::TwoPhase
    } else {
        return bad(format!("unsupported phases {:?}", c.phases_deg));
    };
    let max = g.max_code() as f32;
    if c.frames.any(|v| v > max) {
        return bad(format!("code above the {}-bit range", g.adc_bits));
    }
    Ok(mode)
}

/// Whether every code of every raw image is 0 or full scale.
pub(super) fn rails_only(c: &RawCycle) -> bool {
    let max = c.geometry.max_code() as f32;
    !c.frames.any(|v| v > 0.0 && v < max)
}
