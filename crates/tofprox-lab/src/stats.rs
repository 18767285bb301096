//! Small dense linear algebra, test statistics and a Levenberg–Marquardt
//! solver for small parameter vectors (the fits of the lab have at most a few
//! dozen global parameters; the data are reduced to normal equations first).
use crate::error::LabError;

/// Normal equations of a weighted least-squares problem around a parameter
/// vector: `jtj = Jᵀ W J`, `jtr = Jᵀ W r` (r = data − model), `chi2 = rᵀ W r`.
#[derive(Debug, Clone, PartialEq)]
pub struct Normal {
    /// Number of parameters.
    pub n: usize,
    /// `Jᵀ W J`, n × n row-major (only the upper triangle until [`Normal::symmetrize`]).
    pub jtj: Vec<f64>,
    /// `Jᵀ W r`, length n.
    pub jtr: Vec<f64>,
    /// `rᵀ W r`.
    pub chi2: f64,
    /// Samples added.
    pub count: usize,
}

impl Normal {
    /// Empty normal equations for `n` parameters.
    pub fn zeros(n: usize) -> Self {
        Self {
            n,
            jtj: vec![0.0; n * n],
            jtr: vec![0.0; n],
            chi2: 0.0,
            count: 0,
        }
    }
    /// Add one weighted sample with Jacobian row `j` and residual `r`.
    #[inline]
    pub fn add(&mut self, j: &[f64], r: f64, w: f64) {
        let n = self.n;
        for a in 0..n {
            let wa = w * j[a];
            if wa == 0.0 {
                continue;
            }
            self.jtr[a] += wa * r;
            let row = &mut self.jtj[a * n..a * n + n];
            for b in a..n {
                row[b] += wa * j[b];
            }
        }
        self.chi2 += w * r * r;
        self.count += 1;
    }
    /// Mirror the upper triangle filled by `add` into the lower one.
    pub fn symmetrize(&mut self) {
        let n = self.n;
        for a in 0..n {
            for b in 0..a {
                self.jtj[a * n + b] = self.jtj[b * n + a];
            }
        }
    }
    /// Add the samples of `o` (same parameters).
    pub fn merge(&mut self, o: &Normal) {
        for (a, b) in self.jtj.iter_mut().zip(&o.jtj) {
            *a += b;
        }
        for (a, b) in self.jtr.iter_mut().zip(&o.jtr) {
            *a += b;
        }
        self.chi2 += o.chi2;
        self.count += o.count;
    }
    /// The normal equations of the parameters `idx` only (the others held).
    pub fn select(&self, idx: &[usize]) -> Normal {
        let n = idx.len();
        let mut m = Normal::zeros(n);
        for (a, &i) in idx.iter().enumerate() {
            m.jtr[a] = self.jtr[i];
            for (b, &j) in idx.iter().enumerate() {
                m.jtj[a * n + b] = self.jtj[i * self.n + j];
            }
        }
        m.chi2 = self.chi2;
        m.count = self.count;
        m
    }
    /// These normal equations without the samples of `o` (a subset of them):
    /// the training part of a cross-validation fold.
    pub fn minus(&self, o: &Normal) -> Normal {
        let mut m = self.clone();
        for (a, b) in m.jtj.iter_mut().zip(&o.jtj) {
            *a -= b;
        }
        for (a, b) in m.jtr.iter_mut().zip(&o.jtr) {
            *a -= b;
        }
        m.chi2 -= o.chi2;
        m.count = m.count.saturating_sub(o.count);
        m
    }
    /// χ² after moving the parameters by `d` under the linearisation.
    pub fn chi2_after(&self, d: &[f64]) -> f64 {
        let n = self.n;
        let mut q = 0.0;
        for a in 0..n {
            for b in 0..n {
                q += d[a] * self.jtj[a * n + b] * d[b];
            }
        }
        let lin: f64 = d.iter().zip(&self.jtr).map(|(x, y)| x * y).sum();
        self.chi2 - 2.0 * lin + q
    }
}

/// Solve the symmetric positive (semi-)definite system `m x = b` by Cholesky,
/// adding a tiny ridge relative to the diagonal when it is singular.
pub fn solve_sym(m: &[f64], b: &[f64]) -> Option<Vec<f64>> {
    let n = b.len();
    if m.len() != n * n {
        return None;
    }
    let scale = (0..n).map(|i| m[i * n + i].abs()).fold(0.0_f64, f64::max);
    if !(scale.is_finite()) || scale == 0.0 {
        return if n == 0 { Some(Vec::new()) } else { None };
    }
    for ridge in [0.0, 1e-12, 1e-9, 1e-6] {
        let mut l = vec![0.0; n * n];
        let mut ok = true;
        'outer: for i in 0..n {
            for j in 0..=i {
                let mut s = m[i * n + j];
                if i == j {
                    s += ridge * scale;
                }
                for k in 0..j {
                    s -= l[i * n + k] * l[j * n + k];
                }
                if i == j {
                    if s <= 1e-13 * scale {
                        ok = false;
                        break 'outer;
                    }
                    l[i * n + i] = s.sqrt();
                } else {
                    l[i * n + j] = s / l[j * n + j];
                }
            }
        }
        if !ok {
            continue;
        }
        let mut y = vec![0.0; n];
        for i in 0..n {
            let mut s = b[i];
            for k in 0..i {
                s -= l[i * n + k] * y[k];
            }
            y[i] = s / l[i * n + i];
        }
        let mut x = vec![0.0; n];
        for i in (0..n).rev() {
            let mut s = y[i];
            for k in i + 1..n {
                s -= l[k * n + i] * x[k];
            }
            x[i] = s / l[i * n + i];
        }
        if x.iter().all(|v| v.is_finite()) {
            return Some(x);
        }
    }
    None
}

/// Global misfit test: z = (χ² − n)/√(2n) for χ² with n degrees of freedom.
pub fn chi2_z(chi2: f64, dof: f64) -> f64 {
    if dof <= 0.0 {
        return 0.0;
    }
    (chi2 - dof) / (2.0 * dof).sqrt()
}

/// Bayesian information criterion for a Gaussian likelihood with known
/// variances: χ² + k ln n.
pub fn bic(chi2: f64, k: usize, n: usize) -> f64 {
    chi2 + k as f64 * (n.max(1) as f64).ln()
}

/// Result of a Levenberg–Marquardt fit.
#[derive(Debug, Clone)]
pub struct LmResult {
    /// The parameters at the minimum found.
    pub params: Vec<f64>,
    /// χ² at `params`.
    pub chi2: f64,
    /// Iterations taken.
    pub iterations: usize,
    /// The normal equations at `params`.
    pub normal: Normal,
}

/// Levenberg–Marquardt on a problem reduced to normal equations:
/// `eval(p)` returns Jᵀ W J, Jᵀ W r and χ² at `p` (r = data − model).
/// Marquardt's diagonal scaling; steps are accepted only when χ² falls.
///
/// Converged when the Gauss–Newton step would lower χ² by less than
/// `tol_chi2` (its predicted decrease Jᵀ W r · step), or an accepted step
/// did. With inverse-variance weights χ² is in units of the noise: a
/// decrease of 10⁻² is a parameter change of 0.1 standard errors, below
/// anything the data can tell apart (so no evaluations are spent there).
pub fn levenberg_marquardt<F>(
    mut eval: F,
    p0: &[f64],
    max_iter: usize,
    tol_chi2: f64,
) -> Result<LmResult, LabError>
where
    F: FnMut(&[f64]) -> Normal,
{
    let n = p0.len();
    let mut p = p0.to_vec();
    let mut cur = eval(&p);
    if !cur.chi2.is_finite() {
        return Err(LabError::numerical("χ² is not finite at the start values"));
    }
    let mut lambda = 1e-3;
    let mut it = 0;
    while it < max_iter {
        if let Some(gn) = solve_sym(&cur.jtj, &cur.jtr) {
            let predicted: f64 = gn.iter().zip(&cur.jtr).map(|(a, b)| a * b).sum();
            if predicted.abs() < tol_chi2 {
                break;
            }
        }
        it += 1;
        let mut improved = false;
        for _ in 0..12 {
            let mut m = cur.jtj.clone();
            for i in 0..n {
                let d = cur.jtj[i * n + i];
                m[i * n + i] = d + lambda * if d > 0.0 { d } else { 1e-12 };
            }
            let Some(step) = solve_sym(&m, &cur.jtr) else {
                lambda *= 10.0;
                continue;
            };
            let trial: Vec<f64> = p.iter().zip(&step).map(|(a, b)| a + b).collect();
            let next = eval(&trial);
            if next.chi2.is_finite() && next.chi2 < cur.chi2 {
                let gain = cur.chi2 - next.chi2;
                p = trial;
                cur = next;
                lambda = (lambda / 10.0).max(1e-12);
                improved = true;
                if gain < tol_chi2 {
                    return Ok(LmResult {
                        params: p,
                        chi2: cur.chi2,
                        iterations: it,
                        normal: cur,
                    });
                }
                break;
            }
            lambda *= 10.0;
            if lambda > 1e12 {
                break;
            }
        }
        if !improved {
            break;
        }
    }
    Ok(LmResult {
        params: p,
        chi2: cur.chi2,
        iterations: it,
        normal: cur,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn select_keeps_the_chosen_parameters_normal_equations() {
        let mut n = Normal::zeros(3);
        n.add(&[1.0, 2.0, 0.0], 0.5, 2.0);
        n.add(&[0.0, 1.0, 3.0], -1.0, 1.0);
        n.symmetrize();
        let s = n.select(&[0, 2]);
        assert_eq!(s.jtj, vec![n.jtj[0], n.jtj[2], n.jtj[6], n.jtj[8]]);
        assert_eq!(s.jtr, vec![n.jtr[0], n.jtr[2]]);
        assert_eq!((s.chi2, s.count), (n.chi2, n.count));
    }

    #[test]
    fn cholesky_solves_a_known_system() {
        let m = [4.0, 2.0, 2.0, 3.0];
        let x = solve_sym(&m, &[2.0, 1.0]).unwrap();
        assert!((4.0 * x[0] + 2.0 * x[1] - 2.0).abs() < 1e-12);
        assert!((2.0 * x[0] + 3.0 * x[1] - 1.0).abs() < 1e-12);
        assert!(solve_sym(&[0.0, 0.0, 0.0, 0.0], &[1.0, 1.0]).is_none());
    }

    #[test]
    fn z_is_zero_at_expectation_and_grows_with_excess() {
        assert_eq!(chi2_z(100.0, 100.0), 0.0);
        assert!((chi2_z(120.0, 100.0) - 20.0 / 200f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn lm_recovers_an_exponential_decay() {
        // y = 3 exp(-x / 2.5) + 0.5, deterministic pseudo-noise of ±0.01.
        let xs: Vec<f64> = (0..60).map(|i| i as f64 * 0.2).collect();
        let ys: Vec<f64> = xs
            .iter()
            .enumerate()
            .map(|(i, x)| 3.0 * (-x / 2.5).exp() + 0.5 + 0.01 * if i % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        let eval = |p: &[f64]| {
            let mut nrm = Normal::zeros(3);
            for (x, y) in xs.iter().zip(&ys) {
                let e = (-x / p[1]).exp();
                let model = p[0] * e + p[2];
                let j = [e, p[0] * e * x / (p[1] * p[1]), 1.0];
                nrm.add(&j, y - model, 1.0);
            }
            nrm.symmetrize();
            nrm
        };
        let r = levenberg_marquardt(eval, &[1.0, 1.0, 0.0], 100, 1e-14).unwrap();
        assert!((r.params[0] - 3.0).abs() < 0.02, "{:?}", r.params);
        assert!((r.params[1] - 2.5).abs() < 0.03, "{:?}", r.params);
        assert!((r.params[2] - 0.5).abs() < 0.02, "{:?}", r.params);
        assert!(r.chi2 < 60.0 * 0.0002);
    }

    #[test]
    fn linearised_chi2_matches_refit_for_linear_model() {
        let mut nrm = Normal::zeros(1);
        for (x, y) in [(1.0, 2.0), (2.0, 4.1), (3.0, 5.9)] {
            nrm.add(&[x], y, 1.0);
        }
        nrm.symmetrize();
        let d = solve_sym(&nrm.jtj, &nrm.jtr).unwrap();
        let direct: f64 = [(1.0, 2.0), (2.0, 4.1), (3.0, 5.9)]
            .iter()
            .map(|(x, y)| (y - d[0] * x).powi(2))
            .sum();
        assert!((nrm.chi2_after(&d) - direct).abs() < 1e-9);
    }
}
