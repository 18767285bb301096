//! Monotone shapes of one driver: the second form of a law that physics does
//! not fix (issue 20, item 3). Where the thesis gives a mechanism but not the
//! curve — the amplitude-dependent phase error (2.3.1.2, fig. 2.9: a
//! non-linearity of pixel and read-out) and the temperature drift of delays
//! and responsivity (3.1) — a model file may give the law as knots of its
//! driver and values of the effect at them instead of the parametric form
//! (`[effects.<id>] shape_<driver>_<unit> = [..]`, `shape_<quantity>_<unit> =
//! [..]`). One law per effect with two forms: the parametric one, or this.
//!
//! The curve is the monotone piecewise-linear interpolant of the knots:
//! f(x) = Σ_j v_j·h_j(x) with the hat functions h_j (1 at knot j, 0 at the
//! others, linear between). Outside the knots it is clamped flat (f = v_0
//! below the first knot, v_{K−1} above the last): the file says nothing there
//! and a flat continuation never invents a trend. Monotone values give a
//! monotone curve.
//!
//! Why our own (about 40 lines) and not a crate: the lab fits the values by
//! least squares, so the law must be *linear in the values* with a basis the
//! lab can evaluate ([`hat_weights`]) — the simulator and the lab then share
//! one evaluation exactly. A monotone cubic (Fritsch–Carlson) is not linear
//! in its values (its slopes are limited by them), and the crates.io spline
//! crates (`splines`: linear / Catmull-Rom / Bézier keys; `enterpolation`:
//! B-splines / NURBS) neither offer a monotone form nor expose the basis.

use crate::ids::EffectId;

/// The keys of one effect's shape form: the driver's knots and the value
/// curves (each in the effect's units, a curve missing from the file is 0).
#[derive(Debug, Clone, Copy)]
pub struct ShapeLaw {
    /// The effect the shape belongs to.
    pub effect: EffectId,
    /// Key of the driver's knots (strictly increasing).
    pub driver: &'static str,
    /// What the driver is, with its unit (for documentation and messages).
    pub driver_doc: &'static str,
    /// Keys of the value curves, one value per knot, each monotone.
    pub curves: &'static [&'static str],
    /// The physical bounds of a curve beyond monotone (its key and values; the effect's
    /// module states them: a gain above −1, a loss below 1, …).
    pub bounds: fn(&str, &[f64]) -> Result<(), String>,
}

/// No bounds beyond monotone.
pub fn monotone_only(_key: &str, _values: &[f64]) -> Result<(), String> {
    Ok(())
}

/// Every effect with a shape form, in registry order (each effect module carries its own,
/// [`super::Effect::shape_law`]).
pub fn shape_laws() -> impl Iterator<Item = &'static ShapeLaw> {
    super::REGISTRY.iter().filter_map(|e| e.shape_law())
}

/// The charge the SBI removes from each tap by the shape `knots` →
/// `removed_e` (`sbi_asymmetry::SHAPE_LAW`) for tap charges `n_a`, `n_b` (e⁻): the
/// curve at the fuller tap's charge, never more than the emptier tap holds
/// (the invariant of `sbi_asymmetry::sbi_injected_e`). The simulator and the lab's
/// fit both use it.
#[inline]
pub fn sbi_removed_e(knots: &[f64], removed_e: &[f64], n_a: f64, n_b: f64) -> f64 {
    let lo = n_a.min(n_b).max(0.0);
    eval(knots, removed_e, n_a.max(n_b)).clamp(0.0, lo)
}

/// The shape form of effect `id`, if it has one.
pub fn shape_law(id: &str) -> Option<&'static ShapeLaw> {
    shape_laws().find(|l| l.effect.as_str() == id)
}

/// Whether `key` is one of the keys of a shape law.
pub fn is_shape_key(law: &ShapeLaw, key: &str) -> bool {
    key == law.driver || law.curves.contains(&key)
}

/// Where `x` falls on `knots` (≥ 1, strictly increasing): the two knots
/// j − 1, j around it and the fraction t of the way from j − 1 to j, or the
/// one knot it is clamped to (NaN: the first).
fn locate(knots: &[f64], x: f64) -> (usize, usize, f64) {
    let n = knots.len();
    if x.is_nan() || x <= knots[0] {
        return (0, 0, 0.0);
    }
    if x >= knots[n - 1] {
        return (n - 1, n - 1, 0.0);
    }
    // first knot above x: 1..n−1
    let j = knots.partition_point(|k| *k <= x);
    (j - 1, j, (x - knots[j - 1]) / (knots[j] - knots[j - 1]))
}

/// The hat-function weights h_j(x) of the piecewise-linear interpolant
/// through `knots` (strictly increasing, ≥ 2): at most two are non-zero and
/// they sum to 1; clamped flat outside the knots. f(x) = Σ_j v_j·h_j(x).
pub fn hat_weights(knots: &[f64], x: f64, out: &mut [f64]) {
    out.iter_mut().for_each(|w| *w = 0.0);
    if knots.is_empty() {
        return;
    }
    let (i, j, t) = locate(knots, x);
    out[i] += 1.0 - t;
    out[j] += t;
}

/// The shape's value at `x`: linear between the knots, flat outside
/// (`values` one per knot).
pub fn eval(knots: &[f64], values: &[f64], x: f64) -> f64 {
    let n = knots.len().min(values.len());
    if n == 0 {
        return 0.0;
    }
    let (i, j, t) = locate(&knots[..n], x);
    values[i] + t * (values[j] - values[i])
}

/// Why `knots` cannot be a shape's knots (finite, strictly increasing, at
/// least 2), if they cannot.
pub fn check_knots(knots: &[f64]) -> Result<(), String> {
    if knots.len() < 2 {
        return Err(format!("needs at least 2 knots, found {}", knots.len()));
    }
    if let Some(i) = knots.iter().position(|k| !k.is_finite()) {
        return Err(format!("knot {i} is not finite"));
    }
    if let Some(i) = knots.windows(2).position(|w| w[1] <= w[0]) {
        return Err(format!(
            "knots must increase strictly: knot {} = {} follows {}",
            i + 1,
            knots[i + 1],
            knots[i]
        ));
    }
    Ok(())
}

/// Why `values` cannot be a monotone curve over `n_knots` knots (one finite
/// value per knot, non-decreasing or non-increasing), if they cannot.
pub fn check_values(values: &[f64], n_knots: usize) -> Result<(), String> {
    if values.len() != n_knots {
        return Err(format!(
            "has {} values for {n_knots} knots (one value per knot)",
            values.len()
        ));
    }
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(format!("value {i} is not finite"));
    }
    let up = values.windows(2).all(|w| w[1] >= w[0]);
    let down = values.windows(2).all(|w| w[1] <= w[0]);
    if !(up || down) {
        return Err("values must be monotone (non-decreasing or non-increasing)".into());
    }
    Ok(())
}

/// The monotone curve closest to `values` in least squares (pool adjacent
/// violators), in the direction of its overall trend (last − first): what a
/// fit that is not constrained writes into a file that must be monotone.
pub fn monotone_projection(values: &[f64]) -> Vec<f64> {
    let up = values.last() >= values.first();
    let s = if up { 1.0 } else { -1.0 };
    // blocks of (mean, count) kept non-decreasing in s·v
    let mut blocks: Vec<(f64, usize)> = Vec::new();
    for v in values {
        blocks.push((s * v, 1));
        while blocks.len() > 1 && blocks[blocks.len() - 2].0 > blocks[blocks.len() - 1].0 {
            let (m2, n2) = blocks.pop().unwrap_or((0.0, 0));
            if let Some((m1, n1)) = blocks.last_mut() {
                *m1 = (*m1 * *n1 as f64 + m2 * n2 as f64) / (*n1 + n2) as f64;
                *n1 += n2;
            }
        }
    }
    blocks
        .iter()
        .flat_map(|&(m, n)| std::iter::repeat_n(s * m, n))
        .collect()
}

/// One effect's shape: the driver's knots and its value curves (by the law's
/// curve keys; a curve not given is 0).
#[derive(Debug, Clone, PartialEq)]
pub struct EffectShape {
    /// Knots of the driver, strictly increasing.
    pub knots: Vec<f64>,
    /// Value curves by key, one value per knot, each monotone.
    pub curves: Vec<(&'static str, Vec<f64>)>,
}

impl EffectShape {
    /// Curve `key`'s values, one per knot (0s when the shape has no such curve).
    pub fn values(&self, key: &str) -> Vec<f64> {
        self.curves
            .iter()
            .find(|(k, _)| *k == key)
            .map_or_else(|| vec![0.0; self.knots.len()], |(_, v)| v.clone())
    }

    /// Curve `key` at driver value `x` (0 when the shape has no such curve).
    pub fn eval(&self, key: &str, x: f64) -> f64 {
        self.curves
            .iter()
            .find(|(k, _)| *k == key)
            .map_or(0.0, |(_, v)| eval(&self.knots, v, x))
    }

    /// Why this cannot be `law`'s shape, if it cannot: the knots' and every
    /// curve's check, each named by its key; at least one curve; a gain
    /// curve above −1 (the gain 1 + G stays positive).
    pub fn check(&self, law: &ShapeLaw) -> Result<(), (String, String)> {
        check_knots(&self.knots).map_err(|e| (law.driver.to_string(), e))?;
        if self.curves.is_empty() {
            return Err((
                law.driver.to_string(),
                format!("needs a value curve ({})", law.curves.join(" or ")),
            ));
        }
        for (key, v) in &self.curves {
            if !law.curves.contains(key) {
                return Err((key.to_string(), format!("not a curve of {}", law.effect)));
            }
            check_values(v, self.knots.len()).map_err(|e| (key.to_string(), e))?;
            (law.bounds)(key, v).map_err(|e| (key.to_string(), e))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::sbi_asymmetry::{SBI_REMOVED_E, SHAPE_LAW as SBI_ASYMMETRY};
    use crate::effects::vcsel_droop::{DROOP_LOSS_REL, SHAPE_LAW as VCSEL_DROOP};

    #[test]
    fn interpolates_linearly_and_clamps_flat_outside() {
        let (k, v) = ([1.0, 2.0, 4.0], [0.0, 0.3, 0.5]);
        assert_eq!(eval(&k, &v, 1.0), 0.0);
        assert!((eval(&k, &v, 1.5) - 0.15).abs() < 1e-12);
        assert!((eval(&k, &v, 3.0) - 0.4).abs() < 1e-12);
        assert_eq!(eval(&k, &v, -7.0), 0.0);
        assert_eq!(eval(&k, &v, 40.0), 0.5);
        // the hat weights reproduce the curve exactly and sum to 1
        let mut w = [0.0; 3];
        for x in [-1.0, 1.0, 1.25, 2.0, 3.9, 4.0, 9.0] {
            hat_weights(&k, x, &mut w);
            let f: f64 = w.iter().zip(v).map(|(a, b)| a * b).sum();
            assert!((f - eval(&k, &v, x)).abs() < 1e-12, "x {x}");
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn checks_name_what_is_wrong() {
        assert!(check_knots(&[1.0]).is_err());
        assert!(check_knots(&[1.0, 1.0]).unwrap_err().contains("strictly"));
        assert!(
            check_knots(&[0.0, f64::NAN])
                .unwrap_err()
                .contains("finite")
        );
        assert!(
            check_values(&[0.0, 1.0], 3)
                .unwrap_err()
                .contains("one value per knot")
        );
        assert!(
            check_values(&[0.0, 1.0, 0.5], 3)
                .unwrap_err()
                .contains("monotone")
        );
        assert!(check_values(&[1.0, 1.0, 0.5], 3).is_ok());
        use crate::effects::temperature_drift::{DRIFT_GAIN_REL, SHAPE_LAW as TEMPERATURE_DRIFT};
        let s = EffectShape {
            knots: vec![0.0, 10.0],
            curves: vec![(DRIFT_GAIN_REL, vec![0.0, -1.5])],
        };
        assert_eq!(s.check(&TEMPERATURE_DRIFT).unwrap_err().0, DRIFT_GAIN_REL);
    }

    #[test]
    fn sbi_shape_removes_from_the_threshold_on_and_never_empties_a_tap() {
        let (k, r) = ([1000.0, 3000.0, 5000.0], [0.0, 400.0, 2400.0]);
        // below and at the first knot nothing is removed
        assert_eq!(sbi_removed_e(&k, &r, 800.0, 500.0), 0.0);
        assert_eq!(sbi_removed_e(&k, &r, 300.0, 1000.0), 0.0);
        // the curve at the fuller tap, whichever it is
        assert!((sbi_removed_e(&k, &r, 2000.0, 900.0) - 200.0).abs() < 1e-9);
        assert!((sbi_removed_e(&k, &r, 900.0, 2000.0) - 200.0).abs() < 1e-9);
        // never more than the emptier tap holds, never below 0
        assert!((sbi_removed_e(&k, &r, 4000.0, 600.0) - 600.0).abs() < 1e-9);
        assert_eq!(sbi_removed_e(&k, &r, 9000.0, -5.0), 0.0);
        let ok = |v: Vec<f64>| EffectShape {
            knots: k.to_vec(),
            curves: vec![(SBI_REMOVED_E, v)],
        };
        assert!(ok(r.to_vec()).check(&SBI_ASYMMETRY).is_ok());
        let e = ok(vec![10.0, 400.0, 2400.0])
            .check(&SBI_ASYMMETRY)
            .unwrap_err();
        assert!(e.0 == SBI_REMOVED_E && e.1.contains("start at 0"), "{e:?}");
        let e = ok(vec![0.0, -4.0, -9.0]).check(&SBI_ASYMMETRY).unwrap_err();
        assert!(e.1.contains("not decrease"), "{e:?}");
    }

    #[test]
    fn droop_shape_keeps_the_power_positive() {
        let s = |v: Vec<f64>| EffectShape {
            knots: vec![0.0, 1000.0, 3000.0],
            curves: vec![(DROOP_LOSS_REL, v)],
        };
        assert!(s(vec![0.0, 0.02, 0.05]).check(&VCSEL_DROOP).is_ok());
        let e = s(vec![0.0, 0.5, 1.0]).check(&VCSEL_DROOP).unwrap_err();
        assert!(e.0 == DROOP_LOSS_REL && e.1.contains("1 − L ≤ 0"), "{e:?}");
        assert!((s(vec![0.0, 0.02, 0.05]).eval(DROOP_LOSS_REL, 2000.0) - 0.035).abs() < 1e-12);
        assert_eq!(shape_law("vcsel_droop").map(|l| l.driver), Some(VCSEL_DROOP.driver));
        assert_eq!(shape_law("sbi_asymmetry").map(|l| l.driver), Some(SBI_ASYMMETRY.driver));
        let with_shape: Vec<&str> = shape_laws().map(|l| l.effect.as_str()).collect();
        assert_eq!(
            with_shape,
            ["vcsel_droop", "amplitude_phase_error", "temperature_drift", "sbi_asymmetry"]
        );
    }

    #[test]
    fn projection_is_monotone_and_keeps_monotone_curves() {
        assert_eq!(monotone_projection(&[0.0, 1.0, 2.0]), [0.0, 1.0, 2.0]);
        assert_eq!(
            monotone_projection(&[0.0, 2.0, 1.0, 3.0]),
            [0.0, 1.5, 1.5, 3.0]
        );
        assert_eq!(
            monotone_projection(&[3.0, 1.0, 2.0, 0.0]),
            [3.0, 1.5, 1.5, 0.0]
        );
    }
}
