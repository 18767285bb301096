//! The presence probe (issue 34): while far and still, or near and still, one short capture of a **single raw
//! image** decides whether anything changed; the full 2-phase reading runs only when it did.
//! The detect-only mode of dedicated ToF proximity sensors is the anchor.
//!
//! **Why one raw image, not the 2-phase pair.** Raw image `k` of a pixel is, above its dark
//! level, `A·cos(φ − θ_k)` (thesis eq. 2.2/2.3: the correlation sampled at phase `θ_k`), and
//! light without modulation cancels in the pixel's differential read-out (2.2.2, SBI). A
//! target that could make Near lies within `near_mm`: its measured phase `φ` is the global
//! delay `φ₀` (the wiggling table's mean correction) plus at most `4π·f·near/c` (eq. 2.6), an
//! interval a few tenths of a radian wide. The image whose `θ_k` lies closest to that
//! interval sees at least `cos_min` of every such target's amplitude (0.7 or more on the
//! sensors here), so one image measures the change a near target makes; the pair would
//! measure the whole phasor, which only the distance needs, at twice the read-out and
//! capture energy (table 3.1: both ∝ raw images). A target is missed only if its return
//! were orthogonal to the image in every tile at once, which the choice of `θ_k` excludes
//! for the near range.
//!
//! **How small a change counts.** The weakest return that can make Near is a target of
//! `proximity.reflectivity_floor` at `near_mm`: `A = K·ρ·t/d²` (2.2.1). A tile of the ROI
//! (`probe.tile_px`² pixels) changed when its mean code above the dark level differs from the
//! reference, the last full reading's same image scaled to the probe's exposure (`∝ t`, 3.1.2),
//! by more than half of `cos_min·A`. Noise: per pixel the read-out, kTC and shot noise (2.3.2,
//! in low light the read-out noise dominates, 2.3.2.6) average down by the tile's √N — 16 on a
//! 16 × 16 tile, so ~2 LSB of pixel noise is 0.13 LSB against a threshold of ~1.3 LSB at 20 µs.
//! A false "changed" costs one full reading, never a wrong one.

use ndarray::ArrayView2;
use tofprox_core::SensorGeometry;
use tofprox_core::pipeline::RawSample;
use tofprox_core::proximity::Roi;

use crate::config::ProbeConfig;

/// The reference a probe is compared with: the last full far reading's probe image.
#[derive(Debug, Clone, PartialEq)]
pub struct ProbeReference {
    /// The window the reference was read in (a probe must read the same, every
    /// `row_step`-th row of it).
    pub geometry: SensorGeometry,
    /// The probe reads every `row_step`-th row of the window; the reference's tiles are
    /// taken over the same rows.
    pub row_step: usize,
    /// Index of the probe image in the 2-phase sequence.
    pub image: u16,
    /// Tile means of `code − dark` per µs of exposure.
    pub per_us: Vec<f32>,
    /// The smallest share of a near target's amplitude the image sees (`cos_min`).
    pub cos_min: f64,
    /// Taken from a near reading: it serves probes while near only, a far one while far only.
    pub near: bool,
    /// Taken from a reading with nothing in range: nothing there can move, so it serves the
    /// next cycle already (no still readings needed).
    pub nothing_in_range: bool,
}

/// The probe's verdict.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ProbeVerdict {
    /// No tile changed by more than the threshold: the last reading stands.
    Unchanged {
        /// The largest tile change seen (LSB).
        worst_lsb: f32,
    },
    /// A tile changed (or the probe could not be compared): the full reading runs now.
    Changed {
        /// The largest tile change seen (LSB).
        worst_lsb: f32,
    },
}

/// The probe policy.
#[derive(Debug, Clone)]
pub struct PresenceProbe {
    cfg: ProbeConfig,
    reference: Option<ProbeReference>,
    probes_since_full: u32,
    /// Probes in a row that saw a change (each one a probe's energy spent for nothing).
    changed_in_row: u32,
    refused: bool,
}

/// The most extra still readings a probe waits after probes that saw a change.
const MAX_BACKOFF_READINGS: u32 = 7;

impl PresenceProbe {
    /// New policy.
    pub fn new(cfg: ProbeConfig) -> Self {
        Self {
            cfg,
            reference: None,
            probes_since_full: 0,
            changed_in_row: 0,
            refused: false,
        }
    }

    /// The source cannot capture a single image: full readings from now on.
    pub fn refused(&mut self) {
        self.refused = true;
        self.reference = None;
    }

    /// Whether the next cycle is a probe: a reference held that was taken in the state
    /// published now (near or far), still for `probe.after_still_readings` readings (none
    /// after nothing in range: nothing there moves), plus the back-off, and no more than
    /// `probe.full_every` probes since the last full reading. Near and still is probed like
    /// far and still: the target leaving changes its tiles by its whole return, more than the
    /// weakest near target returns, so the full reading runs at once.
    ///
    /// **Back-off.** A probe that sees a change costs its energy on top of the full reading
    /// it leads to. After `n` such probes in a row the next one waits `2ⁿ − 1` more still
    /// readings (at most 7); a probe that sees none ends it. A moving
    /// hand thus gets full readings, a still scene probes.
    pub fn due(&self, near: bool, still_readings: u32) -> Option<&ProbeReference> {
        if !self.cfg.enabled || self.refused || self.probes_since_full >= self.cfg.full_every {
            return None;
        }
        let r = self.reference.as_ref().filter(|r| r.near == near)?;
        let base = if r.nothing_in_range {
            0
        } else {
            self.cfg.after_still_readings
        };
        let backoff = (1u32 << self.changed_in_row.min(3)) - 1;
        (still_readings >= base + backoff.min(MAX_BACKOFF_READINGS)).then_some(r)
    }

    /// The reference held, if any.
    pub fn reference(&self) -> Option<&ProbeReference> {
        self.reference.as_ref()
    }

    /// A full reading: far readings leave their reference, any other reading clears it.
    pub fn full_reading(&mut self, reference: Option<ProbeReference>) {
        self.probes_since_full = 0;
        self.reference = reference;
    }

    /// Judge a probe's tile means (`code − dark`, at `exposure_us`) against the reference:
    /// changed when any tile moved by more than `threshold_lsb`.
    pub fn judge(&mut self, tiles: &[f32], exposure_us: f64, threshold_lsb: f64) -> ProbeVerdict {
        self.probes_since_full += 1;
        let Some(r) = &self.reference else {
            return ProbeVerdict::Changed {
                worst_lsb: f32::NAN,
            };
        };
        if tiles.len() != r.per_us.len() || tiles.is_empty() {
            return ProbeVerdict::Changed {
                worst_lsb: f32::NAN,
            };
        }
        let t = exposure_us as f32;
        let worst_lsb = tiles
            .iter()
            .zip(&r.per_us)
            .map(|(p, q)| (p - q * t).abs())
            .fold(0.0f32, f32::max);
        if f64::from(worst_lsb) > threshold_lsb || !worst_lsb.is_finite() {
            self.reference = None;
            self.changed_in_row = self.changed_in_row.saturating_add(1);
            ProbeVerdict::Changed { worst_lsb }
        } else {
            self.changed_in_row = 0;
            ProbeVerdict::Unchanged { worst_lsb }
        }
    }

    /// The tile `(rows, cols)` in the rows a probe of `row_step` reads: `tile_px` × `tile_px`
    /// pixels of the window.
    pub fn tile(&self, row_step: usize) -> (usize, usize) {
        let px = usize::from(self.cfg.tile_px.max(1));
        ((px / row_step.max(1)).max(1), px)
    }
}

/// Tile means of `image − dark` over `roi` (tiles of `tile` = `(rows, cols)` pixels; the last
/// row and column of tiles take what is left). `dark` is the dark level per pixel of the same
/// window.
pub fn tile_means<T: RawSample>(
    image: ArrayView2<'_, T>,
    dark: Option<ArrayView2<'_, f32>>,
    mid_code: f32,
    roi: Roi,
    tile: (usize, usize),
) -> Vec<f32> {
    let (rows, cols) = image.dim();
    let r = roi.resolve(rows, cols);
    let (th, tw) = (tile.0.max(1), tile.1.max(1));
    let mut out = Vec::with_capacity(r.rows.div_ceil(th) * r.cols.div_ceil(tw));
    for tr in (r.row0..r.row0 + r.rows).step_by(th) {
        for tc in (r.col0..r.col0 + r.cols).step_by(tw) {
            let (re, ce) = (
                (tr + th).min(r.row0 + r.rows),
                (tc + tw).min(r.col0 + r.cols),
            );
            let mut sum = 0.0f64;
            for y in tr..re {
                for x in tc..ce {
                    let d = dark.as_ref().map_or(mid_code, |d| d[[y, x]]);
                    sum += f64::from(image[[y, x]].to_f32() - d);
                }
            }
            out.push((sum / ((re - tr) * (ce - tc)) as f64) as f32);
        }
    }
    out
}

/// The raw image of `phases_deg` closest to the phases a near target has (`near_rad`, the
/// measured phase from zero distance to `near_mm`, eq. 2.6 plus the global delay): its index
/// and the smallest `cos(φ − θ)` over that interval.
pub fn probe_image(phases_deg: &[f64], near_rad: (f64, f64)) -> Option<(u16, f64)> {
    let (a, b) = near_rad;
    phases_deg
        .iter()
        .enumerate()
        .map(|(i, &th)| {
            let th = th.to_radians();
            // the cosine over [a, b] is smallest at an end (the interval is < π wide)
            let c = (a - th).cos().min((b - th).cos());
            (i, c)
        })
        .max_by(|x, y| x.1.total_cmp(&y.1))
        .and_then(|(i, c)| Some((u16::try_from(i).ok()?, c)))
}

/// Half the smallest change a near target makes in a tile mean: `½·cos_min·K·ρ·t/d²` (LSB).
pub fn change_threshold_lsb(
    k_lsb_m2_per_us: f64,
    reflectivity: f64,
    near_m: f64,
    exposure_us: f64,
    cos_min: f64,
) -> f64 {
    0.5 * cos_min.max(0.0) * k_lsb_m2_per_us * reflectivity * exposure_us / (near_m * near_m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::stepped_roi;
    use ndarray::Array2;

    fn cfg() -> ProbeConfig {
        ProbeConfig {
            enabled: true,
            after_still_readings: 1,
            full_every: 3,
            tile_px: 4,
            row_step: 1,
        }
    }

    fn reference(per_us: Vec<f32>) -> ProbeReference {
        ProbeReference {
            geometry: SensorGeometry::full(8, 8, 12, 80e6),
            row_step: 1,
            image: 1,
            per_us,
            cos_min: 0.8,
            near: false,
            nothing_in_range: false,
        }
    }

    /// With the 0.8 rad global delay of the emulated module and near_mm 100 at 80 MHz, the
    /// 90° image sees every near target (cos ≥ 0.7), the 0° image would not (cos(1.34) ≈ 0.23).
    #[test]
    fn the_image_nearest_the_near_range_is_chosen() {
        let f = 80e6;
        let near_phase = 4.0 * std::f64::consts::PI * f * 0.1 / 299_792_458.0;
        let (i, c) = probe_image(&[0.0, 90.0], (0.8, 0.8 + near_phase)).expect("an image");
        assert_eq!(i, 1);
        let want = (0.8f64 - std::f64::consts::FRAC_PI_2).cos();
        assert!((c - want).abs() < 1e-12 && c > 0.7, "{c}");
        let (i0, _) = probe_image(&[0.0, 90.0], (0.0, near_phase)).expect("an image");
        assert_eq!(i0, 0, "no delay: the 0° image");
    }

    #[test]
    fn tile_means_subtract_the_dark_level() {
        let mut img = Array2::from_elem((8, 8), 110u16);
        img.slice_mut(ndarray::s![0..4, 0..4]).fill(150);
        let dark = Array2::from_elem((8, 8), 100.0f32);
        let roi = Roi {
            row0: 0,
            col0: 0,
            rows: 8,
            cols: 8,
        };
        let t = tile_means(img.view(), Some(dark.view()), 2048.0, roi, (4, 4));
        assert_eq!(t, vec![50.0, 10.0, 10.0, 10.0]);
        let t = tile_means(img.view(), None, 100.0, roi, (4, 4));
        assert_eq!(
            t,
            vec![50.0, 10.0, 10.0, 10.0],
            "mid code without a dark frame"
        );
    }

    /// A probe reading every 3rd row sees the same tile means as the full image's rows
    /// 0, 3, 6, … (summed here pixel by pixel), over the ROI moved into the rows read.
    #[test]
    fn a_stepped_probe_reads_the_reference_rows() {
        let full = Array2::from_shape_fn((12, 8), |(r, c)| (100 + r * 10 + c) as u16);
        let step = 3;
        let sparse = full.slice(ndarray::s![..;3, ..]).to_owned();
        let roi = Roi {
            row0: 2,
            col0: 0,
            rows: 10,
            cols: 8,
        };
        let sr = stepped_roi(roi, step);
        assert_eq!((sr.row0, sr.rows), (1, 3), "rows 3, 6, 9 of the window");
        let t = tile_means(sparse.view(), None, 100.0, sr, (2, 4));
        // tile 0: rows 3 and 6, columns 0..4; tile 2: row 9 alone
        let mean = |rows: &[usize], c0: usize| {
            let v: Vec<f32> = rows
                .iter()
                .flat_map(|&r| (c0..c0 + 4).map(move |c| (r * 10 + c) as f32))
                .collect();
            v.iter().sum::<f32>() / v.len() as f32
        };
        assert_eq!(
            t,
            vec![
                mean(&[3, 6], 0),
                mean(&[3, 6], 4),
                mean(&[9], 0),
                mean(&[9], 4)
            ]
        );
    }

    /// An unchanged scene at a shorter exposure is unchanged (the reference scales with t); a
    /// tile moved by more than the threshold is a change, and then the reference is gone; a
    /// full reading is forced after `full_every` probes.
    #[test]
    fn judges_against_the_reference_scaled_to_the_exposure() {
        let mut p = PresenceProbe::new(cfg());
        assert!(p.due(false, 5).is_none(), "no reference yet");
        p.full_reading(Some(reference(vec![0.5, 0.1, 0.0, 0.2])));
        assert!(
            p.due(true, 5).is_none(),
            "a far reference never serves while near"
        );
        assert!(p.due(false, 0).is_none(), "not yet still");
        assert!(p.due(false, 1).is_some());
        // at 20 µs the reference predicts 10, 2, 0, 4 LSB
        let v = p.judge(&[10.3, 1.9, 0.2, 4.1], 20.0, 1.0);
        assert!(
            matches!(v, ProbeVerdict::Unchanged { worst_lsb } if (worst_lsb - 0.3).abs() < 1e-5),
            "{v:?}"
        );
        p.judge(&[10.0, 2.0, 0.0, 4.0], 20.0, 1.0);
        p.judge(&[10.0, 2.0, 0.0, 4.0], 20.0, 1.0);
        assert!(
            p.due(false, 9).is_none(),
            "three probes: a full reading is due"
        );
        p.full_reading(Some(reference(vec![0.5, 0.1, 0.0, 0.2])));
        let v = p.judge(&[10.0, 2.0, 3.5, 4.0], 20.0, 1.0);
        assert!(
            matches!(v, ProbeVerdict::Changed { worst_lsb } if (worst_lsb - 3.5).abs() < 1e-5),
            "{v:?}"
        );
        assert!(
            p.due(false, 9).is_none(),
            "a change: no reference until the next full reading"
        );
        p.full_reading(None);
        assert!(p.due(false, 9).is_none(), "an unclear reading leaves none");
        p.full_reading(Some(ProbeReference {
            near: true,
            ..reference(vec![0.5; 4])
        }));
        assert!(
            p.due(false, 9).is_none(),
            "a near reference never serves while far"
        );
        assert!(
            p.due(true, 1).is_none(),
            "near, not yet still (the change's back-off: 1 more)"
        );
        assert!(p.due(true, 2).is_some(), "near and still");
        p.full_reading(Some(reference(vec![0.0; 4])));
        p.refused();
        assert!(
            p.due(false, 9).is_none(),
            "a source without single images: never"
        );
    }

    /// A reference from nothing in range serves the very next cycle; one with a target waits
    /// `after_still_readings`. Probes that keep seeing a change wait 1, 3, 7, 7 more still
    /// readings; a probe that sees none ends the back-off.
    #[test]
    fn nothing_in_range_probes_at_once_and_changes_back_off() {
        let mut p = PresenceProbe::new(ProbeConfig {
            full_every: 100,
            ..cfg()
        });
        let empty = || ProbeReference {
            nothing_in_range: true,
            ..reference(vec![0.0; 4])
        };
        p.full_reading(Some(empty()));
        assert!(p.due(false, 0).is_some(), "nothing in range: at once");
        let mut waits = Vec::new();
        for _ in 0..4 {
            // a change: the reference is gone; the next full reading leaves one again
            assert!(matches!(
                p.judge(&[9.0; 4], 20.0, 1.0),
                ProbeVerdict::Changed { .. }
            ));
            p.full_reading(Some(reference(vec![0.0; 4])));
            waits.push((0..20).find(|&n| p.due(false, n).is_some()));
        }
        // after_still_readings = 1 plus the back-off 1, 3, 7 (capped at 7)
        assert_eq!(waits, vec![Some(2), Some(4), Some(8), Some(8)]);
        assert!(matches!(
            p.judge(&[0.0; 4], 20.0, 1.0),
            ProbeVerdict::Unchanged { .. }
        ));
        assert!(
            p.due(false, 1).is_some(),
            "an unchanged probe ends the back-off"
        );
        p.full_reading(Some(empty()));
        assert!(p.due(false, 0).is_some());
    }

    /// The threshold is half of what a 2 % target at near_mm returns in the image, computed
    /// here from A = K·ρ·t/d².
    #[test]
    fn threshold_is_half_the_weakest_near_return() {
        let th = change_threshold_lsb(0.09, 0.02, 0.1, 20.0, 0.7);
        let weakest = 0.09 * 0.02 * 20.0 / (0.1 * 0.1) * 0.7;
        assert!((th - weakest / 2.0).abs() < 1e-12, "{th}");
    }
}
