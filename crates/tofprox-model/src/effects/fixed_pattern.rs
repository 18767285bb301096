//! Fixed per-pixel patterns, one module for three effects because they are drawn
//! together, once per sensor, from one seed ([`FixedPatterns`]):
//!
//! - `prnu`: Photo-response non-uniformity incl. vignetting (thesis 2.3.1.3 (PRNU))
//! - `fppn`: Fixed-pattern phase noise and global delay (thesis 2.3.1.4)
//! - `fpn_offset`: Fixed-pattern offset (FPN) of the read-out (thesis 2.3.1.3,
//!   3.3.3, 3.3.7.1 (fig. 3.12-3.16))
//!
//! Every random draw is a pure function of (seed, effect tag, full-array position),
//! so a read-out window sees exactly the same pixels as the full array.

use crate::config::ModelConfig;
use crate::entry::{ActsOn, EffectInfo, param as p};
use crate::geometry::SensorGeometry;

/// The typed ids of `fpn_offset`.
pub mod fpn_offset {
    crate::ids::effect_ids!(fpn_offset {
        ADC_CHANNEL_SIGMA_LSB = "adc_channel_sigma_lsb",
        COLUMN_SIGMA_LSB = "column_sigma_lsb",
        PIXEL_SIGMA_LSB = "pixel_sigma_lsb",
        COLUMN_LINE_LSB = "column_line_lsb",
        MEAN_LSB = "mean_lsb",
    });
}

/// The typed ids of `fppn`.
pub mod fppn {
    crate::ids::effect_ids!(fppn {
        GLOBAL_DELAY_NS = "global_delay_ns",
        COLUMN_DELAY_PS = "column_delay_ps",
        PIXEL_SIGMA_PS = "pixel_sigma_ps",
    });
}

/// The typed ids of `prnu`.
pub mod prnu {
    crate::ids::effect_ids!(prnu {
        SIGMA_REL = "sigma_rel",
        VIGNETTING_REL = "vignetting_rel",
    });
}

/// SplitMix64 step: a well-mixed 64-bit hash.
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Deterministic standard normal for (seed, tag, a, b) (Box-Muller on two hashed uniforms).
pub(crate) fn hashed_normal(seed: u64, tag: u64, a: u64, b: u64) -> f64 {
    let h1 = mix64(seed ^ mix64(tag.wrapping_mul(0x1000_0000_01B3) ^ mix64(a ^ (b << 32))));
    let h2 = mix64(h1 ^ 0xD1B5_4A32_D192_ED03);
    // uniforms in (0, 1]
    let u1 = ((h1 >> 11) as f64 + 1.0) / (1u64 << 53) as f64;
    let u2 = (h2 >> 11) as f64 / (1u64 << 53) as f64;
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

const TAG_PRNU: u64 = 1;
const TAG_FPN_CH: u64 = 2;
const TAG_FPN_COL: u64 = 3;
const TAG_FPN_PIX: u64 = 4;
const TAG_FPPN: u64 = 5;
pub(crate) const TAG_DNL: u64 = 6;

/// ADC channel (0..32: `2·adc + parity`) converting full-array column `col`.
///
/// Our reading of fig. 3.12 / 3.3.7.1: within a 32-column block the pattern is
/// mirrored (column 31 has the read-out path of column 0); column j < 8 of the
/// mirrored half goes to ADC j's odd channel, column 15 − j to ADC j's even
/// channel (col 0 → ADC 0 odd, col 15 → ADC 0 even); alternate 32-column blocks
/// use ADCs 8..15, so all 16 ADCs are used.
pub fn adc_channel(col: usize) -> usize {
    let p = col % 32;
    let q = p.min(31 - p);
    let (adc, odd) = if q < 8 { (q, 1) } else { (15 - q, 0) };
    let adc = adc + 8 * ((col / 32) % 2);
    2 * adc + odd
}

/// Per-pixel constants of one sensor, row-major over the window.
#[derive(Debug, Clone)]
pub struct FixedPatterns {
    /// Differential offset at the ADC input in LSB (`fpn_offset`).
    pub offset_lsb: Vec<f64>,
    /// Response gain incl. vignetting (`prnu`), 1 when disabled.
    pub gain: Vec<f64>,
    /// Phase delay in rad (`fppn`, incl. global delay), 0 when disabled.
    pub delay_rad: Vec<f64>,
}

impl FixedPatterns {
    pub(crate) fn draw(model: &ModelConfig, g: &SensorGeometry, seed: u64) -> Self {
        let n = g.rows * g.cols;
        let mut offset_lsb = vec![0.0; n];
        let mut gain = vec![1.0; n];
        let mut delay_rad = vec![0.0; n];
        let fr = g.full_rows.max(2) as f64 - 1.0;
        let fc = g.full_cols.max(2) as f64 - 1.0;
        let (cr, cc) = (fr / 2.0, fc / 2.0);
        let corner2 = cr * cr + cc * cc;

        let fpn = model.is_enabled(fpn_offset::ID);
        let (s_ch, s_col, s_pix, line, mean) = (
            model.get(fpn_offset::ADC_CHANNEL_SIGMA_LSB),
            model.get(fpn_offset::COLUMN_SIGMA_LSB),
            model.get(fpn_offset::PIXEL_SIGMA_LSB),
            model.get(fpn_offset::COLUMN_LINE_LSB),
            model.get(fpn_offset::MEAN_LSB),
        );
        let prnu = model.is_enabled(prnu::ID);
        let (s_gain, vig) = (
            model.get(prnu::SIGMA_REL),
            model.get(prnu::VIGNETTING_REL),
        );
        let fppn = model.is_enabled(fppn::ID);
        let w = std::f64::consts::TAU * g.modulation_hz;
        let (tg, tc, tp) = (
            model.get(fppn::GLOBAL_DELAY_NS) * 1e-9,
            model.get(fppn::COLUMN_DELAY_PS) * 1e-12,
            model.get(fppn::PIXEL_SIGMA_PS) * 1e-12,
        );

        for r in 0..g.rows {
            let fr_idx = r + g.roi_origin[0];
            let x = fr_idx as f64 / fr; // position along the column line, 0 = top
            for c in 0..g.cols {
                let fc_idx = c + g.roi_origin[1];
                let i = r * g.cols + c;
                let (ru, cu) = (fr_idx as u64, fc_idx as u64);
                if fpn {
                    // 3.3.7.1: ADC channel + column amplifier + column line + pixel
                    let ch = adc_channel(fc_idx) as u64;
                    offset_lsb[i] = mean
                        + s_ch * hashed_normal(seed, TAG_FPN_CH, ch, 0)
                        + s_col * hashed_normal(seed, TAG_FPN_COL, cu, 0)
                        + line * x
                        + s_pix * hashed_normal(seed, TAG_FPN_PIX, ru, cu);
                }
                if prnu {
                    let (dr, dc) = (fr_idx as f64 - cr, fc_idx as f64 - cc);
                    let r2 = if corner2 > 0.0 {
                        (dr * dr + dc * dc) / corner2
                    } else {
                        0.0
                    };
                    let gp = 1.0 + s_gain * hashed_normal(seed, TAG_PRNU, ru, cu);
                    gain[i] = (gp * (1.0 - vig * r2)).max(0.0);
                }
                if fppn {
                    // 2.3.1.4: distributed RC line (Elmore delay x(2 − x)) + global + pixel
                    let tau = tg + tc * x * (2.0 - x) + tp * hashed_normal(seed, TAG_FPPN, ru, cu);
                    delay_rad[i] = w * tau;
                }
            }
        }
        Self {
            offset_lsb,
            gain,
            delay_rad,
        }
    }
}

/// The catalogue entry of `prnu`.
pub static PRNU: EffectInfo = EffectInfo {
    id: prnu::ID.as_str(),
    title: "Photo-response non-uniformity incl. vignetting",
    explanation: "Each pixel converts light with its own gain g_p ~ N(1, σ) (fill factor, micro-lens, QE variation) and the lens and illumination profile fall off towards the corners: g_p · (1 − v · r²) with r the distance from the optical centre normalised to the corner. Multiplies signal and background electrons of both taps; never changes the phase.",
    thesis_ref: "2.3.1.3 (PRNU)",
    signature: "per-pixel amplitude ratio fixed over all captures, radial falloff; no depth effect",
    params: &[
        p(
            prnu::SIGMA_REL,
            "",
            0.01,
            0.0,
            0.3,
            "per-pixel gain standard deviation",
        ),
        p(
            prnu::VIGNETTING_REL,
            "",
            0.25,
            0.0,
            0.9,
            "relative response loss at the array corner (quadratic in radius)",
        ),
    ],
    in_baseline: true,
    acts_on: ActsOn::Signal,
    drivers: &[],
    cancels_in_four_phase: false,
};

effect!(Prnu, PRNU, prnu::ID, chain = 70);

/// The catalogue entry of `fppn`.
pub static FPPN: EffectInfo = EffectInfo {
    id: fppn::ID.as_str(),
    title: "Fixed-pattern phase noise and global delay",
    explanation: "The modulation signal reaches each pixel with its own delay: a global delay τ_g of driver and cabling, a delay growing along the distributed RC line of the column, τ(x) = τ_c · x (2 − x) (Elmore delay of a distributed line driven at x = 0, x = row/(rows − 1)), and a per-pixel random part. The phase offset is φ_delay = 2π f τ, added to φ_tof.",
    thesis_ref: "2.3.1.4",
    signature: "constant depth offset per pixel, growing down the columns; independent of distance",
    params: &[
        p(
            fppn::GLOBAL_DELAY_NS,
            "ns",
            1.5,
            -20.0,
            20.0,
            "global delay of driver and cabling",
        ),
        p(
            fppn::COLUMN_DELAY_PS,
            "ps",
            120.0,
            0.0,
            5000.0,
            "extra delay at the far end of the column RC line",
        ),
        p(
            fppn::PIXEL_SIGMA_PS,
            "ps",
            15.0,
            0.0,
            1000.0,
            "per-pixel random delay standard deviation",
        ),
    ],
    in_baseline: true,
    acts_on: ActsOn::Phasor,
    drivers: &[],
    cancels_in_four_phase: false,
};

effect!(Fppn, FPPN, fppn::ID, chain = 80);

/// The catalogue entry of `fpn_offset`.
pub static FPN_OFFSET: EffectInfo = EffectInfo {
    id: fpn_offset::ID.as_str(),
    title: "Fixed-pattern offset (FPN) of the read-out",
    explanation: "Every pixel's differential code carries a fixed offset from its read-out path (fig. 3.12): 16 ADCs with even/odd ping-pong channels (column c maps to ADC channel by the 32-column mirrored pattern of 3.3.7.1: col 0 → ADC0 odd, col 15 → ADC0 even, col 31 ≡ col 0), the column source follower/amplifier, a term growing along the column line, and the pixel's reset transistor. offset = ch(c) + col(c) + line · row/(rows−1) + pix(r, c); overall σ ≈ 34 LSB (fig. 3.13). It is what a dark frame measures and what the offset calibration subtracts.",
    thesis_ref: "2.3.1.3, 3.3.3, 3.3.7.1 (fig. 3.12-3.16)",
    signature: "constant per-pixel code offset, present in dark frames; column stripes; 2-phase depth error growing with distance",
    params: &[
        p(
            fpn_offset::ADC_CHANNEL_SIGMA_LSB,
            "LSB",
            8.0,
            0.0,
            500.0,
            "offset standard deviation between ADC channels",
        ),
        p(
            fpn_offset::COLUMN_SIGMA_LSB,
            "LSB",
            15.0,
            0.0,
            500.0,
            "offset standard deviation between column amplifiers",
        ),
        p(
            fpn_offset::PIXEL_SIGMA_LSB,
            "LSB",
            29.0,
            0.0,
            500.0,
            "per-pixel offset standard deviation",
        ),
        p(
            fpn_offset::COLUMN_LINE_LSB,
            "LSB",
            4.0,
            -500.0,
            500.0,
            "offset change from the top to the bottom of a column line",
        ),
        p(
            fpn_offset::MEAN_LSB,
            "LSB",
            0.0,
            -1000.0,
            1000.0,
            "mean offset over the array",
        ),
    ],
    in_baseline: true,
    acts_on: ActsOn::Offset,
    drivers: &[],
    cancels_in_four_phase: true,
};

effect!(FpnOffset, FPN_OFFSET, fpn_offset::ID, chain = 150);
