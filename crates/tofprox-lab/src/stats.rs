//! Test statistics of the lab's fits (the least squares they use is `tofprox_core::lsq`).

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn z_is_zero_at_expectation_and_grows_with_excess() {
        assert_eq!(chi2_z(100.0, 100.0), 0.0);
        assert!((chi2_z(120.0, 100.0) - 20.0 / 200f64.sqrt()).abs() < 1e-12);
    }
}
