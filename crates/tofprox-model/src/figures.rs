//! The thesis's simulation results (fig. 3.7, 3.8, 3.9, 5.1, 5.7/5.8) recomputed
//! with the model, as plain data: `tofprox sim figures` renders them to SVG and the
//! crate's tests assert their published shape and size. Pure: no I/O.
//!
//! All figures evaluate the centre pixel (as the thesis did) with a 1×1 window.

use std::f64::consts::TAU;

use rand::SeedableRng;
use rand::rngs::SmallRng;

use crate::ModelConfig;
use crate::effects;
use crate::effects::correlation::measured_like_waveforms;
use crate::error::ModelError;
use crate::geometry::{CaptureRequest, SensorGeometry};
use crate::ids;
use crate::scene::Scene;
use crate::sim::Simulator;

/// One curve.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// (x, y) points.
    pub points: Vec<(f64, f64)>,
    /// Draw as points (noisy data) rather than a line.
    pub markers: bool,
}

/// One figure.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// File stem, e.g. `fig3_7_offset`.
    pub id: &'static str,
    /// Title including the thesis figure number.
    pub title: String,
    /// x axis label with unit.
    pub x_label: String,
    /// y axis label with unit.
    pub y_label: String,
    /// Curves.
    pub series: Vec<Series>,
    /// Readability of noisy series that lie on top of each other: drawn apart, each legend entry
    /// naming its shift; `None`: as they are. The data stays unshifted.
    pub offsets: Option<Offsets>,
}

/// How a figure's series are drawn apart: series `k` shifted by `⌊k / every⌋ × step`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Offsets {
    /// Shift between groups, y axis units.
    pub step: f64,
    /// Consecutive series drawn together (e.g. 2: a noisy simulation and its mean).
    pub every: usize,
}

impl Figure {
    /// A series by name prefix.
    pub fn series(&self, prefix: &str) -> Option<&Series> {
        self.series.iter().find(|s| s.name.starts_with(prefix))
    }
}

const MODULATION_HZ: f64 = 80e6;

fn centre_geometry() -> Result<SensorGeometry, ModelError> {
    let g = SensorGeometry::irs1645();
    Ok(g.window(g.full_rows / 2, g.full_cols / 2, 1, 1)?)
}

/// The "2-phase, {label}" and "4-phase, {label}" line series of one sweep.
fn phase_pair(label: &str, p2: Vec<(f64, f64)>, p4: Vec<(f64, f64)>) -> [Series; 2] {
    [
        Series {
            name: format!("2-phase, {label}"),
            points: p2,
            markers: false,
        },
        Series {
            name: format!("4-phase, {label}"),
            points: p4,
            markers: false,
        },
    ]
}

/// Metres per radian of phase (eq. 2.6).
fn m_per_rad() -> f64 {
    1.0 / tofprox_core::phasor::distance_to_phase_rad(1.0, MODULATION_HZ)
}

/// Unambiguous range c / 2f (eq. 2.7).
fn range_m() -> f64 {
    tofprox_core::phasor::unambiguous_range_m(MODULATION_HZ)
}

/// Depth error wrapped into [−R/2, R/2).
fn wrapped_error(depth_m: f64, truth_m: f64) -> f64 {
    let r = range_m();
    (depth_m - truth_m + 1.5 * r).rem_euclid(r) - 0.5 * r
}

/// eq. 2.2 on the first two raw images (0°, 90°), u = code − mid.
pub fn depth_2phase(codes: &[f64], mid: f64) -> f64 {
    let (u0, u90) = (
        codes.first().copied().unwrap_or(mid) - mid,
        codes.get(1).copied().unwrap_or(mid) - mid,
    );
    u90.atan2(u0).rem_euclid(TAU) * m_per_rad()
}

/// eq. 2.3 on four raw images (0°, 90°, 180°, 270°).
pub fn depth_4phase(codes: &[f64]) -> f64 {
    let g = |i: usize| codes.get(i).copied().unwrap_or(0.0);
    (g(1) - g(3)).atan2(g(0) - g(2)).rem_euclid(TAU) * m_per_rad()
}

fn sweep(from: f64, to: f64, step: f64) -> Vec<f64> {
    let n = ((to - from) / step).round() as usize;
    (0..=n).map(|i| from + step * i as f64).collect()
}

fn codes_of(a: &ndarray::Array3<f64>) -> Vec<f64> {
    a.iter().copied().collect()
}

/// Fig. 3.7: a 30 LSB offset makes 2-phase depth unusable at larger distances
/// (the 45° phasor dominates as the signal falls); smaller deviation up close.
/// Ideal sensor + `signal_falloff` + `adc_offset` = 30 LSB, t_exp = 0.5 ms.
pub fn fig_3_7() -> Result<Figure, ModelError> {
    let mut m = ModelConfig::ideal();
    m.enable(effects::signal_falloff::ID, true)?;
    m.enable(effects::adc_offset::ID, true)?;
    m.set(effects::adc_offset::OFFSET_LSB, 30.0)?;
    let sim = Simulator::new(&m, centre_geometry()?, 1)?;
    let req = CaptureRequest::four_phase(500.0);
    let (mut s2, mut s4) = (Vec::new(), Vec::new());
    for d in sweep(0.25, 1.80, 0.01) {
        let c = codes_of(&sim.expected(&Scene::wall(d, 1.0), &req)?);
        s2.push((
            d,
            100.0 * wrapped_error(depth_2phase(&c, sim.adc().mid()), d),
        ));
        s4.push((d, 100.0 * wrapped_error(depth_4phase(&c), d)));
    }
    Ok(Figure {
        id: "fig3_7_offset",
        title: "Fig. 3.7: 30 LSB offset, t_exp = 0.5 ms".into(),
        x_label: "distance [m]".into(),
        y_label: "depth error [cm]".into(),
        offsets: None,
        series: vec![
            Series {
                name: "2-phase".into(),
                points: s2,
                markers: false,
            },
            Series {
                name: "4-phase (offset cancels)".into(),
                points: s4,
                markers: false,
            },
        ],
    })
}

/// Fig. 3.8: INL of −200 LSB with the phase images reaching half of each half-range:
/// wiggling-like error, extremes at 22.5°/67.5°, zeros at multiples of 45°;
/// the specified −1.744 LSB is negligible. Constant signal, sinusoidal correlation.
pub fn fig_3_8() -> Result<Figure, ModelError> {
    let mut series = Vec::new();
    for inl in [-200.0, -1.744] {
        let mut m = ModelConfig::ideal();
        m.enable(effects::adc_inl::ID, true)?;
        m.set(effects::adc_inl::INL_LSB, inl)?;
        // amplitude 1024 LSB = half of the positive/negative range (3.3.4)
        let t = 1000.0;
        let lsb_per_e = m.get(ids::sensor::LSB_PER_KE) * 1e-3;
        m.set(ids::sensor::SIGNAL_E_PER_US, 1024.0 / (t * lsb_per_e))?;
        let sim = Simulator::new(&m, centre_geometry()?, 1)?;
        let req = CaptureRequest::two_phase(t);
        let mut pts = Vec::new();
        for phi_deg in sweep(1.0, 360.0, 0.5) {
            let d = phi_deg.to_radians() * m_per_rad();
            let c = codes_of(&sim.expected(&Scene::wall(d, 1.0), &req)?);
            pts.push((
                phi_deg,
                100.0 * wrapped_error(depth_2phase(&c, sim.adc().mid()), d),
            ));
        }
        series.push(Series {
            name: format!("INL {inl} LSB"),
            points: pts,
            markers: false,
        });
    }
    Ok(Figure {
        id: "fig3_8_inl",
        title: "Fig. 3.8: ADC INL, 2-phase, amplitude FSR/4".into(),
        x_label: "true phase [deg]".into(),
        y_label: "depth error [cm]".into(),
        offsets: None,
        series,
    })
}

/// Fig. 3.9: DNL within table 3.2 (1.906 LSB) with quantisation, constant electrons
/// over the sweep, sinusoidal correlation: error well below 1 cm.
pub fn fig_3_9() -> Result<Figure, ModelError> {
    let mut series = Vec::new();
    for (name, dnl) in [("DNL 1.906 LSB", true), ("quantisation only", false)] {
        let mut m = ModelConfig::ideal();
        m.enable(effects::quantization::ID, true)?;
        m.enable(effects::adc_dnl::ID, dnl)?;
        let t = 1000.0;
        let lsb_per_e = m.get(ids::sensor::LSB_PER_KE) * 1e-3;
        m.set(ids::sensor::SIGNAL_E_PER_US, 300.0 / (t * lsb_per_e))?;
        let sim = Simulator::new(&m, centre_geometry()?, 3)?;
        let req = CaptureRequest::four_phase(t);
        let mut rng = SmallRng::seed_from_u64(0);
        let (mut p2, mut p4) = (Vec::new(), Vec::new());
        for d in sweep(0.05, 1.85, 0.005) {
            let c = codes_of(&sim.capture(&Scene::wall(d, 1.0), &req, &mut rng)?);
            p2.push((
                d,
                1000.0 * wrapped_error(depth_2phase(&c, sim.adc().mid()), d),
            ));
            p4.push((d, 1000.0 * wrapped_error(depth_4phase(&c), d)));
        }
        series.extend(phase_pair(name, p2, p4));
    }
    Ok(Figure {
        id: "fig3_9_dnl",
        title: "Fig. 3.9: ADC DNL (table 3.2), amplitude 300 LSB".into(),
        x_label: "distance [m]".into(),
        y_label: "depth error [mm]".into(),
        offsets: Some(Offsets {
            step: 8.0,
            every: 1,
        }),
        series,
    })
}

/// The model of fig. 5.1: measured-like waveform, ADC at table 3.2 (offset 0),
/// noise sources on, falloff and contrast.
pub fn fig_5_1_model() -> Result<ModelConfig, ModelError> {
    let mut m = ModelConfig::ideal();
    for id in [
        effects::signal_falloff::ID,
        effects::demodulation_contrast::ID,
        effects::waveform_harmonics::ID,
        effects::adc_gain::ID,
        effects::adc_inl::ID,
        effects::adc_dnl::ID,
        effects::quantization::ID,
        effects::shot_noise::ID,
        effects::read_noise::ID,
        effects::ktc_noise::ID,
        effects::dark_current::ID,
    ] {
        m.enable(id, true)?;
    }
    let (illum, modul) = measured_like_waveforms(MODULATION_HZ, 1000);
    m.set_waveforms(illum, modul)?;
    Ok(m)
}

/// Fig. 5.1: relative distance deviation with a measured-like waveform, t_exp = 1 ms,
/// 16× averaged raw images: ≈ 2 % at most, shrinking with distance, same shape
/// for 2- and 4-phase. Series: noisy simulation and the noise-free mean.
pub fn fig_5_1() -> Result<Figure, ModelError> {
    let m = fig_5_1_model()?;
    let sim = Simulator::new(&m, centre_geometry()?, 5)?;
    let mut req = CaptureRequest::four_phase(1000.0);
    req.averaged = 16;
    let mut rng = SmallRng::seed_from_u64(51);
    let mid = sim.adc().mid();
    let (mut n2, mut n4, mut e2, mut e4) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for d in sweep(0.30, 1.80, 0.01) {
        let scene = Scene::wall(d, 1.0);
        let c = codes_of(&sim.capture(&scene, &req, &mut rng)?);
        n2.push((d, 100.0 * wrapped_error(depth_2phase(&c, mid), d) / d));
        n4.push((d, 100.0 * wrapped_error(depth_4phase(&c), d) / d));
        let c = codes_of(&sim.expected(&scene, &req)?);
        e2.push((d, 100.0 * wrapped_error(depth_2phase(&c, mid), d) / d));
        e4.push((d, 100.0 * wrapped_error(depth_4phase(&c), d) / d));
    }
    Ok(Figure {
        id: "fig5_1_wiggling",
        title: "Fig. 5.1: measured-like waveform, t_exp = 1 ms, 16x averaged".into(),
        x_label: "distance [m]".into(),
        y_label: "relative depth error [%]".into(),
        offsets: Some(Offsets {
            step: 3.0,
            every: 2,
        }),
        series: vec![
            Series {
                name: "2-phase (simulated)".into(),
                points: n2,
                markers: true,
            },
            Series {
                name: "2-phase mean".into(),
                points: e2,
                markers: false,
            },
            Series {
                name: "4-phase (simulated)".into(),
                points: n4,
                markers: true,
            },
            Series {
                name: "4-phase mean".into(),
                points: e4,
                markers: false,
            },
        ],
    })
}

/// Background light level of fig. 5.7/5.8 (a halogen spot, uncontrolled in the thesis).
pub const FIG_5_8_AMBIENT_KLUX: f64 = 40.0;

/// The model of fig. 5.7/5.8: falloff, contrast, ambient light and the SBI with
/// typical mismatch (wiggling calibrated away: sinusoidal correlation).
pub fn fig_5_8_model() -> Result<ModelConfig, ModelError> {
    let mut m = ModelConfig::ideal();
    for id in [
        effects::signal_falloff::ID,
        effects::demodulation_contrast::ID,
        effects::ambient_light::ID,
        effects::sbi_asymmetry::ID,
    ] {
        m.enable(id, true)?;
    }
    Ok(m)
}

/// Fig. 5.7/5.8: background light activating the SBI: 2-phase error of several cm,
/// 4-phase unaffected; t_exp = 0.5 ms and 1 ms. Returns (fig. 5.7, fig. 5.8). The thesis's
/// fig. 5.7 plots the calculated distance against the ground truth, where every line lies on the
/// identity at the page's scale; here it plots the calculated distance minus the ground truth
/// (mm) against the ground truth, the identity as the zero line.
pub fn fig_5_7_5_8() -> Result<(Figure, Figure), ModelError> {
    let m = fig_5_8_model()?;
    let sim = Simulator::new(&m, centre_geometry()?, 8)?;
    let mid = sim.adc().mid();
    let (mut dist, mut err) = (Vec::new(), Vec::new());
    let identity: Vec<(f64, f64)> = sweep(0.30, 1.50, 0.01)
        .into_iter()
        .map(|d| (d, 0.0))
        .collect();
    dist.push(Series {
        name: "identity (calculated = ground truth)".into(),
        points: identity,
        markers: false,
    });
    for t in [500.0, 1000.0] {
        let mut req = CaptureRequest::four_phase(t);
        req.ambient_klux = FIG_5_8_AMBIENT_KLUX;
        let (mut d2, mut d4, mut e2, mut e4) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for d in sweep(0.30, 1.50, 0.01) {
            let c = codes_of(&sim.expected(&Scene::wall(d, 1.0), &req)?);
            let (z2, z4) = (depth_2phase(&c, mid), depth_4phase(&c));
            d2.push((d, 1000.0 * wrapped_error(z2, d)));
            d4.push((d, 1000.0 * wrapped_error(z4, d)));
            e2.push((d, 100.0 * wrapped_error(z2, d)));
            e4.push((d, 100.0 * wrapped_error(z4, d)));
        }
        let label = format!("{} ms", t / 1000.0);
        dist.extend(phase_pair(&label, d2, d4));
        err.extend(phase_pair(&label, e2, e4));
    }
    Ok((
        Figure {
            id: "fig5_7_sbi_distance",
            title: format!(
                "Fig. 5.7: calculated distance with background light ({FIG_5_8_AMBIENT_KLUX} klux), against the identity"
            ),
            x_label: "ground truth [m]".into(),
            y_label: "calculated − ground truth [mm]".into(),
            offsets: None,
            series: dist,
        },
        Figure {
            id: "fig5_8_sbi_error",
            title: format!("Fig. 5.8: SBI asymmetry, background light {FIG_5_8_AMBIENT_KLUX} klux"),
            x_label: "distance [m]".into(),
            y_label: "depth error [cm]".into(),
            offsets: None,
            series: err,
        },
    ))
}

/// Every figure, in thesis order.
pub fn all() -> Result<Vec<Figure>, ModelError> {
    let (f57, f58) = fig_5_7_5_8()?;
    Ok(vec![
        fig_3_7()?,
        fig_3_8()?,
        fig_3_9()?,
        fig_5_1()?,
        f57,
        f58,
    ])
}
