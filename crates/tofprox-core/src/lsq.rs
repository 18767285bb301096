//! Least squares for small parameter vectors: normal equations, a Cholesky solve and the one
//! Levenberg–Marquardt solver of the workspace (the lens fit, the model
//! lab's fits).
//!
//! Every fit here has at most a few dozen parameters, and its data are reduced to the normal
//! equations `Jᵀ W J`, `Jᵀ W r` first; a dense `n × n` Cholesky on `Vec<f64>` is then all the
//! linear algebra needed. A crate (`levenberg-marquardt`, `argmin`, `faer`) would bring
//! `nalgebra`/`faer` matrices and their own problem traits for what is ~150 lines here, and the
//! lab's fits accumulate the normal equations in parallel over captures themselves (the residual
//! vector of a recording, ~10⁷ samples, is never formed), which those APIs do not fit.
//!
//! Convention: `r = data − model`, `J = ∂model/∂p`, so the Gauss–Newton step is
//! `(Jᵀ W J)⁻¹ Jᵀ W r`.
use crate::CoreError;

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
    ///
    /// The sizes the lab's fits use (up to 20 parameters) run a copy of the loop with `n`
    /// known at compile time (unrolled and vectorised; the same operations in the same
    /// order, so the same sums to the last bit); larger ones the general loop.
    #[inline]
    pub fn add(&mut self, j: &[f64], r: f64, w: f64) {
        macro_rules! fixed {
            ($($n:literal)*) => {
                match self.n {
                    $($n => self.add_fixed::<$n>(j, r, w),)*
                    _ => self.add_any(j, r, w),
                }
            };
        }
        fixed!(1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20)
    }
    /// [`Normal::add`] for a caller that knows `n` at compile time (`N == n`).
    #[inline(always)]
    pub fn add_n<const N: usize>(&mut self, j: &[f64; N], r: f64, w: f64) {
        debug_assert_eq!(self.n, N);
        self.add_fixed::<N>(j, r, w);
    }
    /// [`Normal::add`] for `n == N`.
    #[inline(always)]
    fn add_fixed<const N: usize>(&mut self, j: &[f64], r: f64, w: f64) {
        let j: &[f64; N] = j[..N].try_into().expect("Jacobian row of n entries");
        // rows as arrays of N: indexed with no bounds checks and no slice
        // lengths to work out (at n = 16 a third faster than zipped slices)
        let (rows, _) = self.jtj.as_chunks_mut::<N>();
        for (a, (row, jtr)) in rows.iter_mut().zip(&mut self.jtr).enumerate() {
            let wa = w * j[a];
            if wa == 0.0 {
                continue;
            }
            *jtr += wa * r;
            for b in a..N {
                row[b] += wa * j[b];
            }
        }
        self.chi2 += w * r * r;
        self.count += 1;
    }
    /// [`Normal::add`] for any `n`.
    fn add_any(&mut self, j: &[f64], r: f64, w: f64) {
        let n = self.n;
        // rows by zipped slices: no bounds checks in the inner loop, which vectorises
        for (a, (row, jtr)) in self
            .jtj
            .chunks_exact_mut(n.max(1))
            .zip(&mut self.jtr)
            .enumerate()
        {
            let wa = w * j[a];
            if wa == 0.0 {
                continue;
            }
            *jtr += wa * r;
            for (x, jb) in row[a..].iter_mut().zip(&j[a..n]) {
                *x += wa * jb;
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
    /// The normal equations (unit weights) of the residuals `res(p) = model − data` at `p`, with
    /// the Jacobian by central differences of the given steps (one-sided where a trial lies
    /// outside the model's domain, where `res` returns `false`). `None` when `p` itself, or both
    /// sides of a step, are outside the domain.
    pub fn numerical(
        p: &[f64],
        step: &[f64],
        res: &impl Fn(&[f64], &mut Vec<f64>) -> bool,
    ) -> Option<Normal> {
        let n = p.len();
        let mut r = Vec::new();
        if !res(p, &mut r) {
            return None;
        }
        let (mut hi, mut lo, mut trial) = (Vec::new(), Vec::new(), p.to_vec());
        let mut jac = vec![0.0; r.len() * n];
        for j in 0..n {
            trial[j] = p[j] + step[j];
            let up = res(&trial, &mut hi);
            trial[j] = p[j] - step[j];
            let down = res(&trial, &mut lo);
            trial[j] = p[j];
            let (a, b, width) = match (up, down) {
                (true, true) => (&hi[..], &lo[..], 2.0 * step[j]),
                (true, false) => (&hi[..], &r[..], step[j]),
                (false, true) => (&r[..], &lo[..], step[j]),
                (false, false) => return None,
            };
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                jac[i * n + j] = (x - y) / width;
            }
        }
        let mut nrm = Normal::zeros(n);
        for (row, &ri) in jac.chunks_exact(n.max(1)).zip(&r) {
            // residual = model − data, so r (data − model) = −residual
            nrm.add(row, -ri, 1.0);
        }
        nrm.symmetrize();
        Some(nrm)
    }
}

/// Solve the symmetric positive definite system `m x = b` (n × n row-major) by Cholesky; `None`
/// when a pivot falls below 10⁻¹³ of the largest diagonal element (singular to working
/// precision) or the solution is not finite.
pub fn solve_spd(m: &[f64], b: &[f64]) -> Option<Vec<f64>> {
    cholesky_solve(m, b, 0.0)
}

/// Solve the symmetric positive (semi-)definite system `m x = b` by Cholesky,
/// adding a tiny ridge relative to the diagonal when it is singular.
pub fn solve_sym(m: &[f64], b: &[f64]) -> Option<Vec<f64>> {
    [0.0, 1e-12, 1e-9, 1e-6]
        .into_iter()
        .find_map(|ridge| cholesky_solve(m, b, ridge))
}

/// `(m + ridge · max diag · I) x = b` by Cholesky (see [`solve_spd`] for when it gives `None`).
fn cholesky_solve(m: &[f64], b: &[f64], ridge: f64) -> Option<Vec<f64>> {
    let n = b.len();
    if m.len() != n * n {
        return None;
    }
    let scale = (0..n).map(|i| m[i * n + i].abs()).fold(0.0_f64, f64::max);
    if !scale.is_finite() || scale == 0.0 {
        return (n == 0).then(Vec::new);
    }
    let mut l = vec![0.0; n * n];
    for i in 0..n {
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
                    return None;
                }
                l[i * n + i] = s.sqrt();
            } else {
                l[i * n + j] = s / l[j * n + j];
            }
        }
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
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// When [`levenberg_marquardt`] stops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stop {
    /// At most this many iterations (each one accepted step or a failed search for one).
    pub max_iter: usize,
    /// Converged when the Gauss–Newton step would lower χ² by less than
    /// `tol_chi2 + rel_chi2 · χ²` (its predicted decrease `Jᵀ W r · step`), or an accepted step
    /// did. With inverse-variance weights χ² is in units of the noise: an absolute 10⁻² is a
    /// parameter change of 0.1 standard errors, below anything the data can tell apart.
    pub tol_chi2: f64,
    /// The relative part of the tolerance (for costs without a noise scale).
    pub rel_chi2: f64,
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
/// `eval(p)` returns Jᵀ W J, Jᵀ W r and χ² at `p` (r = data − model; a non-finite χ² marks `p`
/// outside the model's domain, and such a trial is rejected). Marquardt's diagonal scaling;
/// steps are accepted only when χ² falls; converged as [`Stop`] says.
///
/// Errors when χ² is not finite at `p0`.
pub fn levenberg_marquardt<F>(mut eval: F, p0: &[f64], stop: Stop) -> Result<LmResult, CoreError>
where
    F: FnMut(&[f64]) -> Normal,
{
    let mut p = p0.to_vec();
    let mut cur = eval(&p);
    if !cur.chi2.is_finite() {
        return Err(CoreError::InvalidData(
            "least squares: χ² is not finite at the start values".into(),
        ));
    }
    let tol = |chi2: f64| stop.tol_chi2 + stop.rel_chi2 * chi2;
    let mut lambda = 1e-3;
    let mut it = 0;
    while it < stop.max_iter {
        if let Some(gn) = solve_sym(&cur.jtj, &cur.jtr) {
            let predicted: f64 = gn.iter().zip(&cur.jtr).map(|(a, b)| a * b).sum();
            if predicted.abs() < tol(cur.chi2) {
                break;
            }
        }
        it += 1;
        match damped_step(&mut eval, &p, &cur, &mut lambda) {
            Some((trial, next)) => {
                let gain = cur.chi2 - next.chi2;
                let converged = gain < tol(cur.chi2);
                p = trial;
                cur = next;
                if converged {
                    break;
                }
            }
            None => break,
        }
    }
    Ok(LmResult {
        params: p,
        chi2: cur.chi2,
        iterations: it,
        normal: cur,
    })
}

/// One Levenberg–Marquardt step from `p`: raise the damping `lambda` (Marquardt's diagonal
/// scaling) until a step lowers χ², then lower it; `None` when none does within 12 tries.
fn damped_step<F>(
    eval: &mut F,
    p: &[f64],
    cur: &Normal,
    lambda: &mut f64,
) -> Option<(Vec<f64>, Normal)>
where
    F: FnMut(&[f64]) -> Normal,
{
    let n = p.len();
    for _ in 0..12 {
        let mut m = cur.jtj.clone();
        for i in 0..n {
            let d = cur.jtj[i * n + i];
            m[i * n + i] = d + *lambda * if d > 0.0 { d } else { 1e-12 };
        }
        let Some(step) = solve_sym(&m, &cur.jtr) else {
            *lambda *= 10.0;
            continue;
        };
        let trial: Vec<f64> = p.iter().zip(&step).map(|(a, b)| a + b).collect();
        let next = eval(&trial);
        if next.chi2.is_finite() && next.chi2 < cur.chi2 {
            *lambda = (*lambda / 10.0).max(1e-12);
            return Some((trial, next));
        }
        *lambda *= 10.0;
        if *lambda > 1e12 {
            break;
        }
    }
    None
}

/// Levenberg–Marquardt minimising `Σ res(p)²` for residuals `res(p) = model − data` with a
/// numerical Jacobian ([`Normal::numerical`]); trials outside the model's domain (`res` returns
/// `false`) are rejected. Errors when the start is outside the domain.
pub fn fit_residuals(
    res: impl Fn(&[f64], &mut Vec<f64>) -> bool,
    p0: &[f64],
    step: &[f64],
    stop: Stop,
) -> Result<LmResult, CoreError> {
    let eval = |p: &[f64]| {
        Normal::numerical(p, step, &res).unwrap_or_else(|| Normal {
            chi2: f64::INFINITY,
            ..Normal::zeros(p.len())
        })
    };
    levenberg_marquardt(eval, p0, stop)
}

#[cfg(test)]
mod tests {
    use super::*;

    const STOP: Stop = Stop {
        max_iter: 100,
        tol_chi2: 1e-14,
        rel_chi2: 0.0,
    };

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

    /// The unrolled sizes give the general loop's sums to the last bit (zero
    /// Jacobian entries included), and both the sums written out by hand.
    #[test]
    fn fixed_size_add_equals_the_general_loop() {
        for n in 1..=22 {
            let (mut fast, mut general) = (Normal::zeros(n), Normal::zeros(n));
            let mut by_hand = vec![0.0; n * n];
            for s in 0..7 {
                let j: Vec<f64> = (0..n)
                    .map(|i| {
                        if (i + s) % 4 == 0 {
                            0.0
                        } else {
                            ((i * 7 + s * 3) as f64).sin()
                        }
                    })
                    .collect();
                let (r, w) = (0.3 * s as f64 - 1.0, 1.0 + 0.1 * s as f64);
                fast.add(&j, r, w);
                general.add_any(&j, r, w);
                for a in 0..n {
                    for b in a..n {
                        by_hand[a * n + b] += w * j[a] * j[b];
                    }
                }
            }
            assert_eq!(fast, general, "n = {n}");
            for (a, b) in fast.jtj.iter().zip(&by_hand) {
                assert!((a - b).abs() <= 1e-12 * b.abs().max(1.0), "n = {n}");
            }
        }
    }

    #[test]
    fn cholesky_solves_a_known_system() {
        let m = [4.0, 2.0, 2.0, 3.0];
        let x = solve_sym(&m, &[2.0, 1.0]).unwrap();
        assert!((4.0 * x[0] + 2.0 * x[1] - 2.0).abs() < 1e-12);
        assert!((2.0 * x[0] + 3.0 * x[1] - 1.0).abs() < 1e-12);
        assert!(solve_sym(&[0.0, 0.0, 0.0, 0.0], &[1.0, 1.0]).is_none());
        // singular: the strict solve refuses, the ridged one answers
        let singular = [1.0, 1.0, 1.0, 1.0];
        assert!(solve_spd(&singular, &[1.0, 1.0]).is_none());
        let x = solve_sym(&singular, &[1.0, 1.0]).unwrap();
        assert!((x[0] + x[1] - 1.0).abs() < 1e-5, "{x:?}");
    }

    /// y = 3 exp(−x / 2.5) + 0.5 with deterministic pseudo-noise of ±0.01.
    fn decay() -> (Vec<f64>, Vec<f64>) {
        let xs: Vec<f64> = (0..60).map(|i| i as f64 * 0.2).collect();
        let ys = xs
            .iter()
            .enumerate()
            .map(|(i, x)| 3.0 * (-x / 2.5).exp() + 0.5 + 0.01 * if i % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        (xs, ys)
    }

    #[test]
    fn lm_recovers_an_exponential_decay() {
        let (xs, ys) = decay();
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
        let r = levenberg_marquardt(eval, &[1.0, 1.0, 0.0], STOP).unwrap();
        assert!((r.params[0] - 3.0).abs() < 0.02, "{:?}", r.params);
        assert!((r.params[1] - 2.5).abs() < 0.03, "{:?}", r.params);
        assert!((r.params[2] - 0.5).abs() < 0.02, "{:?}", r.params);
        assert!(r.chi2 < 60.0 * 0.0002);
    }

    #[test]
    fn numerical_jacobian_fit_matches_the_analytic_one_and_respects_the_domain() {
        let (xs, ys) = decay();
        // the decay length must stay positive: the domain ends at p[1] ≤ 0
        let res = |p: &[f64], out: &mut Vec<f64>| {
            out.clear();
            out.extend(
                xs.iter()
                    .zip(&ys)
                    .map(|(x, y)| p[0] * (-x / p[1]).exp() + p[2] - y),
            );
            p[1] > 0.0
        };
        let relative = Stop {
            tol_chi2: 0.0,
            rel_chi2: 1e-12,
            ..STOP
        };
        let r = fit_residuals(res, &[1.0, 1.0, 0.0], &[1e-6; 3], relative).unwrap();
        assert!((r.params[1] - 2.5).abs() < 0.03, "{:?}", r.params);
        assert!(r.chi2 < 60.0 * 0.0002);
        let err = fit_residuals(res, &[1.0, -1.0, 0.0], &[1e-6; 3], relative).unwrap_err();
        assert!(err.to_string().contains("not finite at the start"), "{err}");
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
