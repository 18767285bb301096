//! One valid sample of a recording under a lab model: its full context
//! ([`Rec`], what a signature evaluates) and its compact stored form
//! ([`Sample`], residual tables), with the unit phasors they are built from.

use crate::prepared::{CapInfo, Prepared};

/// One valid (non-saturated, used) sample with everything a signature needs.
#[derive(Debug, Clone, Copy)]
pub struct Rec {
    /// measured − model (the model of the stage that built the table).
    pub r: f64,
    /// 1/σ².
    pub w: f64,
    /// Modelled amplitude A (LSB), phase φ, image phase θ, C and C' at φ−θ.
    pub a: f64,
    /// Modelled phase φ (rad).
    pub phi: f64,
    /// The raw image's phase shift θ (rad).
    pub theta: f64,
    /// C(φ − θ).
    pub c: f64,
    /// C'(φ − θ).
    pub cd: f64,
    /// Modelled differential code (code − mid) without effects.
    pub x: f64,
    /// The pixel's response relative to the median pixel (PRNU, vignetting).
    pub gain_rel: f64,
    /// Capture index.
    pub cap: u32,
    /// Pixel index in the window.
    pub pix: u32,
    /// Raw image index in the capture.
    pub k: u16,
    /// The capture's cross-validation fold.
    pub fold: u8,
}

/// One valid sample as stored in residual tables: the compact form of a
/// [`Rec`] (44 bytes instead of 88; a full-array sweep has 10⁷ samples).
///
/// f32 where the precision allows: a code, residual or amplitude below 2¹²
/// LSB keeps 2.4·10⁻⁴ LSB (f32's 2⁻²⁴ relative), far below the noise of one
/// acquisition (≥ 0.3 LSB); a phase below 16 rad keeps 10⁻⁶ rad, 0.3 µm of
/// depth at 80 MHz (eq. 2.6). Every sum over samples (χ², normal equations)
/// is accumulated in f64. θ is not stored: it is the capture's phase of raw
/// image `k`.
#[derive(Debug, Clone, Copy)]
pub struct Sample {
    /// measured − model (the model of the stage that built the table).
    pub r: f32,
    /// 1/σ².
    pub w: f32,
    /// Modelled amplitude A (LSB).
    pub a: f32,
    /// Modelled phase φ (rad).
    pub phi: f32,
    /// C(φ − θ).
    pub c: f32,
    /// C'(φ − θ).
    pub cd: f32,
    /// Modelled differential code (code − mid) without effects.
    pub x: f32,
    /// The pixel's response relative to the median pixel.
    pub gain_rel: f32,
    /// Capture index.
    pub cap: u32,
    /// Pixel index in the window.
    pub pix: u32,
    /// Raw image index in the capture.
    pub k: u16,
    /// The capture's cross-validation fold.
    pub fold: u8,
}

impl Sample {
    /// The stored form of a sample's context.
    #[inline]
    pub fn of(r: &Rec) -> Self {
        Self {
            r: r.r as f32,
            w: r.w as f32,
            a: r.a as f32,
            phi: r.phi as f32,
            c: r.c as f32,
            cd: r.cd as f32,
            x: r.x as f32,
            gain_rel: r.gain_rel as f32,
            cap: r.cap,
            pix: r.pix,
            k: r.k,
            fold: r.fold,
        }
    }

    /// The full context of this sample (θ from the capture).
    #[inline]
    pub fn rec(&self, prep: &Prepared) -> Rec {
        Rec {
            r: f64::from(self.r),
            w: f64::from(self.w),
            a: f64::from(self.a),
            phi: f64::from(self.phi),
            theta: prep.caps[self.cap as usize].theta_rad[usize::from(self.k)],
            c: f64::from(self.c),
            cd: f64::from(self.cd),
            x: f64::from(self.x),
            gain_rel: f64::from(self.gain_rel),
            cap: self.cap,
            pix: self.pix,
            k: self.k,
            fold: self.fold,
        }
    }

    /// w·r², in f64.
    #[inline]
    pub fn chi2(&self) -> f64 {
        let r = f64::from(self.r);
        f64::from(self.w) * r * r
    }
}

/// e^{i(φ − θ)} = (cos, sin) from e^{iφ} = (cφ, sφ) and e^{−iθ} = (cθ, sθ).
#[inline]
pub fn rotate(e_phi: (f64, f64), e_mtheta: (f64, f64)) -> (f64, f64) {
    (
        e_phi.0 * e_mtheta.0 - e_phi.1 * e_mtheta.1,
        e_phi.0 * e_mtheta.1 + e_phi.1 * e_mtheta.0,
    )
}

/// A unit phasor e^{ix} as (cos x, sin x).
pub type Phasor = (f64, f64);

/// e^{−iθ_k} = (cos θ_k, −sin θ_k) of every raw image of a capture.
pub fn theta_rotation(cap: &CapInfo) -> Vec<Phasor> {
    cap.theta_rad
        .iter()
        .map(|t| {
            let (s, c) = t.sin_cos();
            (c, -s)
        })
        .collect()
}
