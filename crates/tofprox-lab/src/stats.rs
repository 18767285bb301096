//! Test statistics of the lab's fits (the least squares they use is `tofprox_core::lsq`).

/// Global misfit test: z = (χ² − n)/√(2n) for χ² with n degrees of freedom.
pub fn chi2_z(chi2: f64, dof: f64) -> f64 {
    if dof <= 0.0 {
        return 0.0;
    }
    (chi2 - dof) / (2.0 * dof).sqrt()
}

/// Bayesian information criterion for a Gaussian likelihood with known
/// variances: χ² + k ln n (Schwarz 1978; −2 ln L = χ² up to a constant that
/// is the same for every model of one recording — not in the thesis).
pub fn bic(chi2: f64, k: usize, n: usize) -> f64 {
    chi2 + k as f64 * (n.max(1) as f64).ln()
}

/// Akaike information criterion for a Gaussian likelihood with known
/// variances: χ² + 2k (Akaike 1974; the same constant dropped as in
/// [`bic`]). Only differences between models of one recording mean anything.
pub fn aic(chi2: f64, k: usize) -> f64 {
    chi2 + 2.0 * k as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn z_is_zero_at_expectation_and_grows_with_excess() {
        assert_eq!(chi2_z(100.0, 100.0), 0.0);
        assert!((chi2_z(120.0, 100.0) - 20.0 / 200f64.sqrt()).abs() < 1e-12);
    }

    /// AIC charges 2 per parameter, BIC ln n: a parameter that lowers χ² by 5
    /// is worth it by AIC and, at n = 1000 (ln n ≈ 6.9), not by BIC.
    #[test]
    fn information_criteria_charge_parameters() {
        assert_eq!(aic(100.0, 0), 100.0);
        assert_eq!(aic(95.0, 1) - aic(100.0, 0), -3.0);
        let d = bic(95.0, 1, 1000) - bic(100.0, 0, 1000);
        assert!((d - (1000f64.ln() - 5.0)).abs() < 1e-12 && d > 0.0);
    }
}
