//! The correlation function as a Fourier series (thesis 3.2.2, 4.2.2):
//! C(x) = Σ_h Re[γ_h e^{i h x}], γ_1 = 1, x = φ − θ_k. The raw code of image k
//! is mid + offset + A·C(φ − θ_k) (the conventions of `tofprox_core`, crate documentation).
use serde::Serialize;

/// Fourier coefficients of the normalised correlation function C(x).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Waveform {
    /// γ_h = [re, im] for h = 1..=H (γ_1 = [1, 0]).
    pub gamma: Vec<[f64; 2]>,
}

impl Waveform {
    /// The ideal correlation C(x) = cos x (fundamental only).
    pub fn sinusoid() -> Self {
        Self {
            gamma: vec![[1.0, 0.0]],
        }
    }
    /// Highest harmonic H in the series.
    pub fn order(&self) -> usize {
        self.gamma.len()
    }
    /// The peak of C over a period relative to its fundamental (≥ 1; on a
    /// 1° grid): the total signal charge per unit of fundamental amplitude.
    pub fn peak(&self) -> f64 {
        (0..360)
            .map(|i| self.eval(f64::from(i).to_radians()).0)
            .fold(1.0f64, f64::max)
    }
    /// (C(x), C'(x)).
    #[inline]
    pub fn eval(&self, x: f64) -> (f64, f64) {
        let (s, c) = x.sin_cos();
        self.eval_at(c, s)
    }
    /// (C(x), C'(x)) from cos x and sin x (the harmonics by complex
    /// multiplication: callers that know e^{ix} from a rotation skip the
    /// sin_cos).
    #[inline]
    pub fn eval_at(&self, c: f64, s: f64) -> (f64, f64) {
        let (mut zr, mut zi) = (c, s);
        let mut cv = 0.0;
        let mut dv = 0.0;
        for (h, g) in self.gamma.iter().enumerate() {
            let hh = (h + 1) as f64;
            cv += g[0] * zr - g[1] * zi;
            dv += hh * (-g[0] * zi - g[1] * zr);
            let nr = zr * c - zi * s;
            let ni = zr * s + zi * c;
            zr = nr;
            zi = ni;
        }
        (cv, dv)
    }
    /// Relative amplitude of every harmonic above the first, for reports.
    pub fn harmonic_magnitudes(&self) -> Vec<f64> {
        self.gamma.iter().map(|g| g[0].hypot(g[1])).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivative_matches_finite_difference() {
        let w = Waveform {
            gamma: vec![[1.0, 0.0], [0.1, -0.05], [0.2, 0.03]],
        };
        for i in 0..20 {
            let x = i as f64 * 0.37;
            let (_, d) = w.eval(x);
            let fd = (w.eval(x + 1e-6).0 - w.eval(x - 1e-6).0) / 2e-6;
            assert!((d - fd).abs() < 1e-6);
        }
        let s = Waveform::sinusoid();
        assert!((s.eval(0.3).0 - 0.3f64.cos()).abs() < 1e-15);
    }
}
