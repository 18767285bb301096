//! Deterministic generator of the small example recording shipped in
//! `examples/recording/` (until the physical model crate writes it).
//!
//! ```text
//! cargo run -p tofprox-format --example make_example_recording -- examples/recording
//! ```
//!
//! Sensor: a 16×16 window at (78, 104) of the 172×224 IRS1645 array, 12-bit
//! ADC, 80 MHz. Each raw image follows the team convention
//! `code_k = mid + offset_pixel + A · C(φ − θ_k)` with
//! - `φ = 4π f d / c + delay + fppn_pixel` (eq. 2.6 inverted; delay = driver + cabling),
//! - a non-sinusoidal correlation `C` (DC residue, 2nd, 3rd and 5th harmonics:
//!   the wiggling error of 2.3.1.1),
//! - FPN `offset_pixel` with σ ≈ 34 LSB (3.3.7.1), FPPN with σ ≈ 10 mrad (2.3.1.4),
//! - amplitude falling with 1/d², temporal noise averaged over `averaged` acquisitions.
//!
//! The ground truth lives in each capture's `[capture.conditions]`.

use std::collections::BTreeMap;
use std::f64::consts::TAU;
use std::path::PathBuf;

use ndarray::{Array2, Array3};
use tofprox_core::SensorGeometry;
use tofprox_core::phasor::distance_to_phase_rad;
use tofprox_core::sensor::{adc_max_code, adc_mid_code};
use tofprox_format::{CaptureSpec, RawFrames, RecordingWriter};

const MODULATION_HZ: f64 = 80e6;
const ROWS: usize = 16;
const COLS: usize = 16;
const ADC_BITS: u8 = 12;
/// Global delay of driver and cabling, as a phase (≈ 0.18 m of apparent distance).
const DELAY_RAD: f64 = 0.62;
const FPN_SIGMA_LSB: f64 = 34.0;
const FPPN_SIGMA_RAD: f64 = 0.010;
/// Read noise of one acquisition, LSB.
const READ_NOISE_LSB: f64 = 2.5;

/// splitmix64: small, deterministic, good enough for test data.
struct Rng(u64);
impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    /// Standard normal (Box–Muller).
    fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (TAU * u2).cos()
    }
}

/// Normalised correlation of illumination and modulation (fundamental amplitude 1):
/// a VCSEL-rounded, slightly asymmetric square wave.
fn correlation(x: f64) -> f64 {
    0.02 + x.cos()
        + 0.05 * (2.0 * x + 0.4).cos()
        + 0.09 * (3.0 * x).cos()
        + 0.025 * (5.0 * x + 0.3).cos()
}

struct Sensor {
    offset: Array2<f64>,
    fppn: Array2<f64>,
}

impl Sensor {
    fn new(rng: &mut Rng) -> Self {
        // column amplifiers share part of the offset (3.3.7.1): a column component plus a pixel one
        let col: Vec<f64> = (0..COLS).map(|_| rng.normal() * 20.0).collect();
        let pix_sigma = (FPN_SIGMA_LSB.powi(2) - 20.0f64.powi(2)).sqrt();
        let offset =
            Array2::from_shape_fn((ROWS, COLS), |(_, c)| col[c] + rng.normal() * pix_sigma);
        let fppn = Array2::from_shape_fn((ROWS, COLS), |_| rng.normal() * FPPN_SIGMA_RAD);
        Sensor { offset, fppn }
    }

    /// Mean codes of `averaged` acquisitions (f64) or a single acquisition rounded.
    fn capture(
        &self,
        rng: &mut Rng,
        phases_deg: &[f64],
        distance_m: Option<f64>,
        reflectivity: f64,
        averaged: u32,
    ) -> Array3<f64> {
        let mid = f64::from(adc_mid_code(ADC_BITS));
        let max = f64::from(adc_max_code(ADC_BITS));
        let (amp, phi_tof) = match distance_m {
            // amplitude ∝ reflectivity / d² (≈ 1400 LSB at 0.25 m for a white wall)
            Some(d) => (
                1400.0 * (reflectivity / 0.9) * (0.25 / d).powi(2),
                distance_to_phase_rad(d, MODULATION_HZ),
            ),
            None => (0.0, 0.0),
        };
        Array3::from_shape_fn((phases_deg.len(), ROWS, COLS), |(k, r, c)| {
            let theta = phases_deg[k].to_radians();
            let phi = phi_tof + DELAY_RAD + self.fppn[[r, c]];
            let ideal = mid + self.offset[[r, c]] + amp * correlation(phi - theta);
            // read noise + shot noise (≈ 0.03·sqrt(A) LSB per acquisition), averaged
            let sigma = (READ_NOISE_LSB.powi(2) + 0.5 * amp).sqrt() / f64::from(averaged).sqrt();
            let v = ideal + rng.normal() * sigma;
            let v = if averaged == 1 { v.round() } else { v };
            v.clamp(0.0, max)
        })
    }
}

fn spec(
    phases_deg: Vec<f64>,
    illumination: bool,
    averaged: u32,
    distance_m: Option<f64>,
    t_ns: u64,
) -> CaptureSpec {
    let mut conditions = BTreeMap::new();
    if let Some(d) = distance_m {
        conditions.insert("distance_m".to_string(), d);
        conditions.insert("reflectivity".to_string(), 0.9);
    }
    conditions.insert("ambient_klux".to_string(), 0.0);
    conditions.insert("temperature_c".to_string(), 30.0);
    CaptureSpec {
        phases_deg,
        exposure_us: 500.0,
        illumination,
        averaged,
        timestamp_ns: Some(t_ns),
        conditions,
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir: PathBuf = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .ok_or("usage: make_example_recording OUT_DIR")?;
    let sensor_info = SensorGeometry {
        rows: ROWS,
        cols: COLS,
        roi_origin: [78, 104],
        full_rows: 172,
        full_cols: 224,
        adc_bits: ADC_BITS,
        modulation_hz: MODULATION_HZ,
    };
    let mut rng = Rng(0x7f0f_2026);
    let sensor = Sensor::new(&mut rng);
    let mut w = RecordingWriter::create(
        &dir,
        sensor_info,
        Some(
            "synthetic example: 16x16 window, non-sinusoidal correlation, FPN sigma 34 LSB, \
             FPPN sigma 10 mrad, global delay 0.62 rad; made by make_example_recording"
                .into(),
        ),
    )?;
    let four = vec![0.0, 90.0, 180.0, 270.0];
    let corr: Vec<f64> = (0..24).map(|i| 15.0 * f64::from(i)).collect();
    let mut t_ns = 1_000_000_000u64;
    let mut step = || {
        t_ns += 250_000_000;
        t_ns
    };
    // 0: dark capture (illumination off) for the FPN offset
    let dark = sensor.capture(&mut rng, &four, None, 0.0, 16);
    w.append(
        spec(four.clone(), false, 16, None, step()),
        &RawFrames::F32(dark.mapv(|v| v as f32)),
    )?;
    // 1: correlation capture, 24 × 15°, white wall at 0.50 m, 64 acquisitions averaged
    let c = sensor.capture(&mut rng, &corr, Some(0.5), 0.9, 64);
    w.append(
        spec(corr.clone(), true, 64, Some(0.5), step()),
        &RawFrames::F32(c.mapv(|v| v as f32)),
    )?;
    // 2..: 4-phase captures of the wall at known distances
    for d in [0.25, 0.40, 0.55, 0.70, 0.90] {
        let x = sensor.capture(&mut rng, &four, Some(d), 0.9, 16);
        w.append(
            spec(four.clone(), true, 16, Some(d), step()),
            &RawFrames::F32(x.mapv(|v| v as f32)),
        )?;
    }
    // a single (not averaged) 2-phase acquisition as raw uint16 codes
    let two = vec![0.0, 90.0];
    let x = sensor.capture(&mut rng, &two, Some(0.33), 0.9, 1);
    w.append(
        spec(two, true, 1, Some(0.33), step()),
        &RawFrames::U16(x.mapv(|v| v as u16)),
    )?;
    println!("wrote {} captures to {}", w.len(), dir.display());
    w.finish()?;
    Ok(())
}
