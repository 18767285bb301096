//! SVG text helpers shared by the chart kinds.
use std::fmt::Write as _;

/// Escape text for SVG/HTML content and attribute values.
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            _ => o.push(c),
        }
    }
    o
}

/// Estimated width in px of `s` in a sans-serif font of `size_px` (generous, so
/// layouts computed from it do not collide when the real font is wider).
pub(crate) fn text_width(s: &str, size_px: f64) -> f64 {
    0.62 * size_px * s.chars().count() as f64
}

/// Format a number for a tick or value label with `decimals` digits, never `NaN`.
pub(crate) fn fmt_num(v: f64, decimals: usize) -> String {
    if v.is_finite() {
        let s = format!("{v:.decimals$}");
        // "-0.0" reads as a different value than "0.0"
        if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
            s[1..].to_string()
        } else {
            s
        }
    } else {
        "n/a".to_string()
    }
}

/// Start an SVG document of the given size with a white background.
pub(crate) fn open(out: &mut String, kind: &str, w: f64, h: f64) {
    let _ = write!(
        out,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" class=\"chart {kind}\" width=\"{w:.0}\" height=\"{h:.0}\" \
         viewBox=\"0 0 {w:.0} {h:.0}\" font-family=\"sans-serif\">\
         <rect x=\"0\" y=\"0\" width=\"{w:.0}\" height=\"{h:.0}\" fill=\"white\"/>"
    );
}

/// A text element.
pub(crate) fn text(
    out: &mut String,
    class: &str,
    x: f64,
    y: f64,
    size: f64,
    anchor: &str,
    s: &str,
) {
    let _ = write!(
        out,
        "<text class=\"{class}\" x=\"{x:.1}\" y=\"{y:.1}\" font-size=\"{size:.0}\" text-anchor=\"{anchor}\">{}</text>",
        escape(s)
    );
}

/// A text element rotated −90° about its anchor (vertical axis titles).
pub(crate) fn vtext(out: &mut String, class: &str, x: f64, y: f64, size: f64, s: &str) {
    let _ = write!(
        out,
        "<text class=\"{class}\" x=\"{x:.1}\" y=\"{y:.1}\" font-size=\"{size:.0}\" text-anchor=\"middle\" \
         transform=\"rotate(-90 {x:.1} {y:.1})\">{}</text>",
        escape(s)
    );
}

/// A straight line.
pub(crate) fn seg(out: &mut String, x0: f64, y0: f64, x1: f64, y1: f64, stroke: &str) {
    let _ = write!(
        out,
        "<line x1=\"{x0:.1}\" y1=\"{y0:.1}\" x2=\"{x1:.1}\" y2=\"{y1:.1}\" stroke=\"{stroke}\" stroke-width=\"1\"/>"
    );
}

/// Lay out legend entries left to right, wrapping at `width`; returns the
/// (x, y) of each entry's top-left corner relative to the legend origin and
/// the total height.
pub(crate) fn flow(widths: &[f64], width: f64, row_h: f64) -> (Vec<(f64, f64)>, f64) {
    let (mut x, mut y) = (0.0, 0.0);
    let mut at = Vec::with_capacity(widths.len());
    for &w in widths {
        if x > 0.0 && x + w > width {
            x = 0.0;
            y += row_h;
        }
        at.push((x, y));
        x += w;
    }
    let h = if widths.is_empty() { 0.0 } else { y + row_h };
    (at, h)
}
