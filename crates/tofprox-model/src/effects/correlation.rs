//! The correlation waveform C(φ − θ) (2.2.2.2, 2.3.1.1, 5.1.2.1): the shared law
//! of `demodulation_contrast` (its scale) and `waveform_harmonics` (its shape,
//! from harmonics or from measured illumination and modulation waveforms), which
//! the simulator and the lab's fit evaluate.

use std::f64::consts::TAU;

use crate::config::ModelConfig;
use crate::waveform::fourier;

/// Number of table entries per period of the correlation function.
const TABLE_SIZE: usize = 8192;
/// Harmonics kept when a measured waveform pair is correlated.
const MEASURED_HARMONICS: usize = 31;

/// The correlation function C(x) of illumination and modulation, normalised so that
/// max |C| = 1 (or exactly `cos` when `waveform_harmonics` is disabled).
#[derive(Debug, Clone)]
pub struct Correlation {
    /// `None`: exact cosine (ideal sinusoidal case of eq. 2.2/2.3).
    table: Option<Box<[f64; TABLE_SIZE + 1]>>,
    /// Fourier coefficients (a_n, b_n), n = 0.., of the normalised C: C = Σ a_n cos nx + b_n sin nx.
    coefficients: Vec<(f64, f64)>,
}

impl Correlation {
    /// The ideal sinusoidal correlation.
    pub fn cosine() -> Self {
        Self {
            table: None,
            coefficients: vec![(0.0, 0.0), (1.0, 0.0)],
        }
    }

    /// From Fourier coefficients (a_n, b_n), normalised to max |C| = 1.
    pub fn from_coefficients(mut coefficients: Vec<(f64, f64)>) -> Self {
        // Σ a_n cos nx + b_n sin nx with cos/sin of nx by the angle-addition
        // recurrence (two trig calls per point instead of two per harmonic)
        let eval = |c: &[(f64, f64)], x: f64| -> f64 {
            let (s1, c1) = x.sin_cos();
            let (mut sn, mut cn) = (0.0f64, 1.0f64);
            let mut acc = 0.0;
            for &(a, b) in c {
                acc += a * cn + b * sn;
                let next_c = cn * c1 - sn * s1;
                sn = sn * c1 + cn * s1;
                cn = next_c;
            }
            acc
        };
        let mut table = Box::new([0.0f64; TABLE_SIZE + 1]);
        for (i, v) in table.iter_mut().enumerate() {
            *v = eval(&coefficients, TAU * i as f64 / TABLE_SIZE as f64);
        }
        let peak = table.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if peak > 0.0 {
            for v in table.iter_mut() {
                *v /= peak;
            }
            for c in &mut coefficients {
                c.0 /= peak;
                c.1 /= peak;
            }
        }
        Self {
            table: Some(table),
            coefficients,
        }
    }

    /// C(x) = cos x + Σ_{n=2..9} r_n cos(n x + ψ_n) (section 3.2.2).
    pub fn from_harmonics(rel: &[(f64, f64)]) -> Self {
        let mut c = vec![(0.0, 0.0), (1.0, 0.0)];
        for &(r, psi_deg) in rel {
            let psi = psi_deg.to_radians();
            // r cos(nx + ψ) = r cos ψ cos nx − r sin ψ sin nx
            c.push((r * psi.cos(), -r * psi.sin()));
        }
        Self::from_coefficients(c)
    }

    /// Circular cross-correlation of measured waveforms: C(τ) = ⟨s(t) · (2 r(t + τ) − 1)⟩.
    pub fn from_waveforms(illumination: &[f64], modulation: &[f64]) -> Self {
        let s = fourier(illumination, MEASURED_HARMONICS);
        let m: Vec<(f64, f64)> = fourier(modulation, MEASURED_HARMONICS)
            .iter()
            .enumerate()
            .map(|(n, &(re, im))| {
                if n == 0 {
                    (2.0 * re - 1.0, 0.0)
                } else {
                    (2.0 * re, 2.0 * im)
                }
            })
            .collect();
        // s(t) = Σ S_n e^{int}; ⟨s(t) m(t+τ)⟩ = Σ_n conj(S_n) M_n e^{inτ}
        let mut coef = Vec::with_capacity(MEASURED_HARMONICS + 1);
        for n in 0..=MEASURED_HARMONICS {
            let (sr, si) = s[n];
            let (mr, mi) = m[n];
            // conj(S) M = (sr − i si)(mr + i mi)
            let re = sr * mr + si * mi;
            let im = sr * mi - si * mr;
            if n == 0 {
                coef.push((re, 0.0));
            } else {
                // 2 Re(z e^{inτ}) = 2 re cos nτ − 2 im sin nτ
                coef.push((2.0 * re, -2.0 * im));
            }
        }
        // Attribute the delay of the fundamental to the global delay (`fppn`):
        // shift so the fundamental is cos x, C'(x) = C(x − ψ).
        if let Some(&(a1, b1)) = coef.get(1) {
            let psi = (-b1).atan2(a1);
            for (n, c) in coef.iter_mut().enumerate() {
                let (s, co) = (n as f64 * psi).sin_cos();
                *c = (c.0 * co - c.1 * s, c.0 * s + c.1 * co);
            }
        }
        Self::from_coefficients(coef)
    }

    /// Build the correlation the model asks for.
    pub fn from_model(model: &ModelConfig) -> Self {
        if !model.is_enabled(crate::effects::waveform_harmonics::ID) {
            return Self::cosine();
        }
        if let Some(w) = model.waveforms() {
            return Self::from_waveforms(&w.illumination, &w.modulation);
        }
        let rel: Vec<(f64, f64)> = (2..=9)
            .filter_map(crate::effects::waveform_harmonics::harmonic)
            .map(|(rel, phase)| (model.get(rel), model.get(phase)))
            .collect();
        Self::from_harmonics(&rel)
    }

    /// C(x) for any real x (period 2π).
    #[inline]
    pub fn eval(&self, x: f64) -> f64 {
        match &self.table {
            None => x.cos(),
            Some(t) => {
                // one floor: the integer part is masked to the period (two's complement
                // makes this right for negative x too), the fraction interpolates
                let pos = x * (TABLE_SIZE as f64 / TAU);
                let fl = fast_floor(pos);
                let i = (fl as i64 as usize) & (TABLE_SIZE - 1);
                let w = pos - fl;
                let (a, b) = (t[i], t[i + 1]);
                a + (b - a) * w
            }
        }
    }

    /// Fourier coefficients (a_n, b_n) of the normalised correlation.
    pub fn coefficients(&self) -> &[(f64, f64)] {
        &self.coefficients
    }

    /// Harmonics n = 2..=nmax relative to the fundamental as (r_n, ψ_n in degrees),
    /// the parameters of `waveform_harmonics`.
    pub fn harmonics_rel(&self, nmax: usize) -> Vec<(f64, f64)> {
        let a1 = self
            .coefficients
            .get(1)
            .map_or(1.0, |c| c.0.hypot(c.1))
            .max(1e-300);
        (2..=nmax)
            .map(|n| {
                let (a, b) = self.coefficients.get(n).copied().unwrap_or((0.0, 0.0));
                (a.hypot(b) / a1, (-b).atan2(a).to_degrees())
            })
            .collect()
    }
}

/// floor() without a libm call (the baseline x86-64 target has no `roundsd`);
/// exact for |x| < 2^52, which every phase and code here is.
#[inline(always)]
pub(crate) fn fast_floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    // branch-free: subtract 1 where truncation rounded up (negative non-integers)
    t - f64::from(u8::from(t > x))
}

/// A measured-like waveform pair (section 5.1.2.1): a VCSEL pulse train with
/// first-order rise (1.4 ns) and slower fall (1.8 ns) at 50 % duty, and a
/// pulse-shaped modulation gate with 2.4 ns edges, `n` samples per period at
/// `modulation_hz`. At 80 MHz its correlation gives a wiggling error of about
/// ±5 mm (fig. 5.1: ≈ 2 % at 25 cm).
pub fn measured_like_waveforms(modulation_hz: f64, n: usize) -> (Vec<f64>, Vec<f64>) {
    let period = 1.0 / modulation_hz;
    let dt = period / n as f64;
    // first-order response to a 50 % square, iterated to periodic steady state
    let shape = |tau_rise: f64, tau_fall: f64, duty: f64| -> Vec<f64> {
        let mut y = 0.0;
        let mut out = vec![0.0; n];
        for _ in 0..3 {
            for (k, o) in out.iter_mut().enumerate() {
                let on = (k as f64) < duty * n as f64;
                let (target, tau) = if on { (1.0, tau_rise) } else { (0.0, tau_fall) };
                y += (target - y) * (1.0 - (-dt / tau).exp());
                *o = y;
            }
        }
        out
    };
    let illumination = shape(RISE_NS * 1e-9, FALL_NS * 1e-9, 0.5);
    let modulation = shape(GATE_EDGE_NS * 1e-9, GATE_EDGE_NS * 1e-9, 0.5);
    (illumination, modulation)
}

/// VCSEL rise time constant of the measured-like waveform.
const RISE_NS: f64 = 1.4;
/// VCSEL fall time constant (slower: thermal tail).
const FALL_NS: f64 = 1.8;
/// Modulation gate edge time constant.
const GATE_EDGE_NS: f64 = 2.4;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::waveform::validate_waveforms;

    #[test]
    fn harmonic_series_round_trips_and_table_matches_the_series() {
        let rel = vec![
            (0.01, 10.0),
            (0.03, -40.0),
            (0.0, 0.0),
            (0.012, 75.0),
            (0.0, 0.0),
            (0.004, 0.0),
            (0.0, 0.0),
            (0.002, 170.0),
        ];
        let c = Correlation::from_harmonics(&rel);
        for ((r, p), (r2, p2)) in rel.iter().zip(c.harmonics_rel(9)) {
            assert!((r - r2).abs() < 1e-12);
            if *r > 0.0 {
                assert!((p - p2).abs() < 1e-9, "{p} vs {p2}");
            }
        }
        let exact = |x: f64| {
            c.coefficients()
                .iter()
                .enumerate()
                .map(|(n, (a, b))| a * (n as f64 * x).cos() + b * (n as f64 * x).sin())
                .sum::<f64>()
        };
        for i in -500..500 {
            let x = i as f64 * 0.0371;
            assert!((c.eval(x) - exact(x)).abs() < 2e-6, "x = {x}");
        }
    }

    #[test]
    fn sinusoidal_waveforms_correlate_to_the_cosine() {
        let n = 256;
        let ill: Vec<f64> = (0..n)
            .map(|k| 1.0 + (TAU * k as f64 / n as f64).cos())
            .collect();
        let m: Vec<f64> = (0..n)
            .map(|k| 0.5 + 0.5 * (TAU * k as f64 / n as f64 + 0.7).cos())
            .collect();
        let c = Correlation::from_waveforms(&ill, &m);
        for i in 0..100 {
            let x = i as f64 * 0.1;
            assert!((c.eval(x) - x.cos()).abs() < 1e-6);
        }
        assert!(validate_waveforms(&ill, &m).is_ok());
        assert!(validate_waveforms(&ill, &vec![0.5; n]).is_err());
        assert!(validate_waveforms(&[1.0; 4], &m).is_err());
    }
}
