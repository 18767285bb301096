//! Numbers as the tools print them.

/// A number with up to six decimals and no trailing zeros (`0.25`, `80`, `-1.5`).
pub fn fmt_num(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s.is_empty() || s == "-" || s == "-0" {
        "0".into()
    } else {
        s.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::fmt_num;

    #[test]
    fn trims_trailing_zeros_only() {
        assert_eq!(fmt_num(0.25), "0.25");
        assert_eq!(fmt_num(80.0), "80");
        assert_eq!(fmt_num(100.0), "100");
        assert_eq!(fmt_num(-1.5), "-1.5");
        assert_eq!(fmt_num(0.0), "0");
        assert_eq!(fmt_num(-0.0000001), "0");
        assert_eq!(fmt_num(1e-6), "0.000001");
    }
}
