//! Frame synthesis for the emulated device.
//!
//! `IdealSynth` is the simple built-in source: the sinusoidal correlation of
//! the team conventions (`code = mid + offset + A cos(phi - theta)`,
//! `phi = 4π f d / c`, eq. 2.6 inverted) with a column fixed-pattern offset
//! and a little read noise. The physical model (tofprox-model) replaces it
//! where available (see `model_synth`).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::config::SceneConfig;
use crate::error::BridgeError;

/// Speed of light, m/s.
const C_M_PER_S: f64 = 299_792_458.0;

/// Parameters of one raw image as the registers say.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawParams {
    /// Exposure, µs.
    pub exposure_us: f64,
    /// Phase shift, degrees.
    pub phase_deg: f64,
    /// Illumination on.
    pub illuminated: bool,
}

/// Sensor geometry for synthesis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geometry {
    /// Full rows.
    pub full_rows: usize,
    /// Columns.
    pub cols: usize,
    /// ADC bits.
    pub adc_bits: u8,
    /// Modulation frequency, Hz.
    pub modulation_hz: f64,
}

/// A source of raw frames.
pub trait FrameSynth: Send {
    /// Synthesise the raw images of one measurement at scene time `t_s`,
    /// rows `row0 .. row0 + rows`; `out[k]` gets `rows × cols` codes.
    fn superframe(
        &mut self,
        t_s: f64,
        raws: &[RawParams],
        row0: usize,
        rows: usize,
        out: &mut Vec<Vec<u16>>,
    ) -> Result<(), BridgeError>;
}

/// Per-pixel distance and reflectivity of a scene at time `t_s`: returns
/// (wall distance, wall refl, optional (hand distance, hand refl)); the hand
/// covers the central half of the array.
pub fn scene_at(scene: &SceneConfig, t_s: f64) -> (f64, f64, Option<(f64, f64)>) {
    match *scene {
        SceneConfig::Wall {
            distance_m,
            reflectivity,
        } => (distance_m, reflectivity, None),
        SceneConfig::Hand {
            wall_distance_m,
            near_distance_m,
            period_s,
            reflectivity,
            wall_reflectivity,
        } => {
            // Triangle over the period: absent in the first and last quarter,
            // approaching to near_distance at the middle.
            let x = (t_s / period_s).rem_euclid(1.0);
            let hand = if (0.25..0.75).contains(&x) {
                let u = 1.0 - ((x - 0.5).abs() / 0.25); // 0 at the edges, 1 at the middle
                let d = wall_distance_m * 0.8 + (near_distance_m - wall_distance_m * 0.8) * u;
                Some((d, reflectivity))
            } else {
                None
            };
            (wall_distance_m, wall_reflectivity, hand)
        }
    }
}

/// The built-in ideal synthesiser.
pub struct IdealSynth {
    geom: Geometry,
    scene: SceneConfig,
    col_offset: Vec<f64>,
    rng: ChaCha8Rng,
}

impl IdealSynth {
    /// Draw the fixed column pattern from `seed`.
    pub fn new(geom: Geometry, scene: SceneConfig, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_F1ED);
        let col_offset = (0..geom.cols)
            .map(|_| rng.random_range(-20.0..20.0))
            .collect();
        IdealSynth {
            geom,
            scene,
            col_offset,
            rng,
        }
    }
}

impl FrameSynth for IdealSynth {
    fn superframe(
        &mut self,
        t_s: f64,
        raws: &[RawParams],
        row0: usize,
        rows: usize,
        out: &mut Vec<Vec<u16>>,
    ) -> Result<(), BridgeError> {
        let g = self.geom;
        let cols = g.cols;
        let max = f64::from((1u32 << g.adc_bits) - 1);
        let mid = f64::from(1u32 << (g.adc_bits - 1));
        let (wall_d, wall_r, hand) = scene_at(&self.scene, t_s);
        // Hand region: central half of rows and columns of the full array.
        let (hr0, hr1) = (g.full_rows / 4, g.full_rows * 3 / 4);
        let (hc0, hc1) = (cols / 4, cols * 3 / 4);
        out.resize_with(raws.len(), Vec::new);
        for (raw, frame) in raws.iter().zip(out.iter_mut()) {
            frame.clear();
            frame.reserve(rows * cols);
            // A ∝ exposure × reflectivity / d² (inverse-square law, thesis 2.1).
            let signal = |d: f64, r: f64| -> f64 {
                if !raw.illuminated {
                    return 0.0;
                }
                let amp = 2.0 * raw.exposure_us * r / (d * d);
                let phi = 4.0 * std::f64::consts::PI * g.modulation_hz * d / C_M_PER_S; // eq. 2.6
                amp * (phi - raw.phase_deg.to_radians()).cos()
            };
            let s_wall = signal(wall_d, wall_r);
            let s_hand = hand.map(|(d, r)| signal(d, r)).unwrap_or(s_wall);
            for r in row0..row0 + rows {
                for c in 0..cols {
                    let in_hand =
                        hand.is_some() && (hr0..hr1).contains(&r) && (hc0..hc1).contains(&c);
                    let s = if in_hand { s_hand } else { s_wall };
                    let n: f64 = f64::from(self.rng.random::<u8>() & 7) - 3.5;
                    let v = (mid + self.col_offset[c] + s + n).round().clamp(0.0, max);
                    frame.push(v as u16);
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phase_follows_distance() {
        let g = Geometry {
            full_rows: 8,
            cols: 8,
            adc_bits: 12,
            modulation_hz: 80e6,
        };
        let mut s = IdealSynth::new(
            g,
            SceneConfig::Wall {
                distance_m: 0.5,
                reflectivity: 0.5,
            },
            1,
        );
        let raws = [0.0, 90.0, 180.0, 270.0].map(|p| RawParams {
            exposure_us: 500.0,
            phase_deg: p,
            illuminated: true,
        });
        let mut out = Vec::new();
        s.superframe(0.0, &raws, 0, 8, &mut out).unwrap();
        let m = |k: usize| out[k].iter().map(|&v| f64::from(v)).sum::<f64>() / 64.0;
        let phi = (m(1) - m(3))
            .atan2(m(0) - m(2))
            .rem_euclid(std::f64::consts::TAU); // eq. 2.3
        let d = phi * C_M_PER_S / (4.0 * std::f64::consts::PI * 80e6);
        assert!((d - 0.5).abs() < 0.02, "{d}");
    }
}
