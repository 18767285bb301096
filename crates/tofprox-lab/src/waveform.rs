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
    ///
    /// The powers zʰ of z = e^{ix} run in two independent chains, odd and
    /// even h, each stepping by z²: half the dependency chain of stepping by
    /// z (the lab evaluates this for every sample of every pass).
    #[inline]
    pub fn eval_at(&self, c: f64, s: f64) -> (f64, f64) {
        let (wr, wi) = (c * c - s * s, 2.0 * c * s);
        // (re, im) of z^h and z^(h+1), and the partial sums of C and C′ over each chain
        let (mut ar, mut ai, mut br, mut bi) = (c, s, wr, wi);
        let (mut ca, mut cb, mut da, mut db) = (0.0, 0.0, 0.0, 0.0);
        let mut h = 1.0;
        let mut pairs = self.gamma.chunks_exact(2);
        for pair in &mut pairs {
            let (g, q) = (pair[0], pair[1]);
            ca += g[0] * ar - g[1] * ai;
            da += h * (-g[0] * ai - g[1] * ar);
            cb += q[0] * br - q[1] * bi;
            db += (h + 1.0) * (-q[0] * bi - q[1] * br);
            (ar, ai) = (ar * wr - ai * wi, ar * wi + ai * wr);
            (br, bi) = (br * wr - bi * wi, br * wi + bi * wr);
            h += 2.0;
        }
        if let [g] = pairs.remainder() {
            ca += g[0] * ar - g[1] * ai;
            da += h * (-g[0] * ai - g[1] * ar);
        }
        (ca + cb, da + db)
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
        // against the series summed term by term with cos(hx), sin(hx), every order 1..=9
        let gamma: Vec<[f64; 2]> = (0..9)
            .map(|h| [1.0 / (h as f64 + 1.0), 0.1 * h as f64 - 0.3])
            .collect();
        for order in 1..=gamma.len() {
            let w = Waveform {
                gamma: gamma[..order].to_vec(),
            };
            for i in 0..50 {
                let x = -3.0 + i as f64 * 0.13;
                let (mut cv, mut dv) = (0.0, 0.0);
                for (h, g) in w.gamma.iter().enumerate() {
                    let hx = (h as f64 + 1.0) * x;
                    cv += g[0] * hx.cos() - g[1] * hx.sin();
                    dv -= (h as f64 + 1.0) * (g[0] * hx.sin() + g[1] * hx.cos());
                }
                let (c, d) = w.eval(x);
                assert!(
                    (c - cv).abs() < 1e-13 && (d - dv).abs() < 1e-12,
                    "{order} {x}"
                );
            }
        }
        let s = Waveform::sinusoid();
        assert!((s.eval(0.3).0 - 0.3f64.cos()).abs() < 1e-15);
    }
}
