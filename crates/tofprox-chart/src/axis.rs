//! Axis ticks.

/// Ticks at 1, 2 or 5 × 10^k covering `[lo, hi]` (about `target` of them),
/// with the number of decimals their labels need. Empty for a non-finite or
/// empty range.
pub fn nice_ticks(lo: f64, hi: f64, target: usize) -> (Vec<f64>, usize) {
    if !(lo.is_finite() && hi.is_finite()) || hi < lo {
        return (Vec::new(), 0);
    }
    let span = (hi - lo).max(f64::EPSILON * hi.abs().max(1.0));
    let raw = span / target.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let decimals = if step >= 1.0 {
        0
    } else {
        (-step.log10().floor()) as usize
    };
    let first = (lo / step).ceil();
    let last = (hi / step).floor();
    let n = ((last - first) as i64).clamp(-1, 1000);
    let ticks = (0..=n).map(|i| (first + i as f64) * step).collect();
    (ticks, decimals)
}

/// A linear map from data to pixels.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Scale {
    pub d0: f64,
    pub d1: f64,
    pub p0: f64,
    pub p1: f64,
}

impl Scale {
    pub fn at(&self, v: f64) -> f64 {
        let span = self.d1 - self.d0;
        if span.abs() < f64::MIN_POSITIVE {
            (self.p0 + self.p1) / 2.0
        } else {
            self.p0 + (v - self.d0) / span * (self.p1 - self.p0)
        }
    }
}

/// The finite range of values, padded by `pad` of its span (a point range
/// becomes ±0.5, or ±5 % of its magnitude).
pub(crate) fn padded_range(values: impl Iterator<Item = f64>, pad: f64) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return None;
    }
    if hi - lo <= f64::EPSILON * hi.abs().max(1.0) {
        let d = (0.05 * hi.abs()).max(0.5);
        return Some((lo - d, hi + d));
    }
    let d = (hi - lo) * pad;
    Some((lo - d, hi + d))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_cover_the_range_with_round_steps() {
        let (t, d) = nice_ticks(0.15, 1.8, 6);
        assert_eq!(d, 1);
        assert_eq!(t.len(), 3);
        assert!((t[0] - 0.5).abs() < 1e-12 && (t[2] - 1.5).abs() < 1e-12);
        let (t, d) = nice_ticks(-3.0, 20800.0, 5);
        assert_eq!((t[0], d), (0.0, 0));
        assert!(t.windows(2).all(|w| (w[1] - w[0] - 5000.0).abs() < 1e-9));
        assert!(nice_ticks(f64::NAN, 1.0, 5).0.is_empty());
    }
}
