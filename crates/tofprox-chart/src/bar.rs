//! Horizontal bar charts: one row per bar, its label on the same row.
use std::fmt::Write as _;

use crate::axis::{Scale, nice_ticks};
use crate::svg::{self, escape, fmt_num, text, text_width};

/// One bar.
#[derive(Debug, Clone, PartialEq)]
pub struct Bar {
    /// What the bar measures (drawn left of it, on its row).
    pub label: String,
    /// Its value (non-finite: an empty bar with the value shown as "n/a").
    pub value: f64,
}

/// Horizontal bars, drawn in the given order from the top.
#[derive(Debug, Clone, PartialEq)]
pub struct BarChart {
    /// Title above the bars.
    pub title: String,
    /// Value axis title with unit.
    pub value_label: String,
    /// The bars.
    pub bars: Vec<Bar>,
    /// A reference level drawn as a dashed line, with its meaning; bars above
    /// it are red, at or below it green.
    pub threshold: Option<(f64, String)>,
}

const W: f64 = 860.0;
const TOP: f64 = 44.0;
const ROW: f64 = 24.0;
const BAR_H: f64 = 16.0;

/// Value → axis coordinate: linear, or log10(1 + v) when the values span more
/// than two decades (a z of 20 000 next to a z of 3 must keep both visible).
fn transform(log: bool, v: f64) -> f64 {
    if log {
        (1.0 + v.max(0.0)).log10()
    } else {
        v.max(0.0)
    }
}

/// Render the chart as a standalone SVG element.
pub fn bar_chart(c: &BarChart) -> String {
    let finite: Vec<f64> = c
        .bars
        .iter()
        .map(|b| b.value)
        .filter(|v| v.is_finite())
        .collect();
    let vmax = finite
        .iter()
        .copied()
        .chain(c.threshold.as_ref().map(|t| t.0))
        .fold(0.0f64, f64::max);
    let log = vmax > 100.0;
    let label_w = c
        .bars
        .iter()
        .map(|b| text_width(&b.label, 12.0))
        .fold(40.0f64, f64::max);
    let (x0, x1) = (16.0 + label_w + 8.0, W - 90.0);
    let n = c.bars.len();
    let y1 = TOP + ROW * n.max(1) as f64;
    let h = y1 + 60.0;
    let top = transform(log, vmax).max(1e-9) * 1.04;
    let xs = Scale {
        d0: 0.0,
        d1: top,
        p0: x0,
        p1: x1,
    };
    let mut o = String::new();
    svg::open(&mut o, "bar-chart", W, h);
    text(&mut o, "title", W / 2.0, 24.0, 15.0, "middle", &c.title);
    let _ = write!(
        o,
        "<rect class=\"plot-area\" x=\"{x0:.1}\" y=\"{TOP:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"none\" stroke=\"#444\"/>",
        x1 - x0,
        y1 - TOP
    );
    o.push_str("<g class=\"axis x-axis\">");
    let ticks: Vec<(f64, String)> = if log {
        (0..)
            .map(|k| 10f64.powi(k))
            .take_while(|v| transform(true, *v) <= top)
            .map(|v| (transform(true, v), fmt_num(v, 0)))
            .chain(std::iter::once((0.0, "0".to_string())))
            .collect()
    } else {
        let (t, d) = nice_ticks(0.0, top, 6);
        t.into_iter().map(|v| (v, fmt_num(v, d))).collect()
    };
    for (t, s) in ticks {
        let px = xs.at(t);
        svg::seg(&mut o, px, TOP, px, y1, "#eee");
        svg::seg(&mut o, px, y1, px, y1 + 5.0, "#444");
        text(&mut o, "tick", px, y1 + 18.0, 11.0, "middle", &s);
    }
    let axis_title = if log {
        format!("{} (logarithmic: log₁₀(1 + value))", c.value_label)
    } else {
        c.value_label.clone()
    };
    text(
        &mut o,
        "axis-title",
        (x0 + x1) / 2.0,
        y1 + 38.0,
        12.0,
        "middle",
        &axis_title,
    );
    o.push_str("</g>");
    for (i, b) in c.bars.iter().enumerate() {
        let cy = TOP + ROW * (i as f64 + 0.5);
        let above = c.threshold.as_ref().is_some_and(|(t, _)| b.value > *t);
        let col = if above { "#c0392b" } else { "#78a078" };
        let wpx = if b.value.is_finite() {
            xs.at(transform(log, b.value)) - x0
        } else {
            0.0
        };
        let _ = write!(
            o,
            "<rect class=\"bar\" data-label=\"{}\" data-value=\"{}\" x=\"{x0:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{BAR_H:.1}\" fill=\"{col}\"/>",
            escape(&b.label),
            fmt_num(b.value, 3),
            cy - BAR_H / 2.0,
            wpx.max(0.0)
        );
        text(
            &mut o,
            "bar-label",
            x0 - 8.0,
            cy + 4.0,
            12.0,
            "end",
            &b.label,
        );
        let digits = if b.value.abs() >= 100.0 { 0 } else { 1 };
        text(
            &mut o,
            "bar-value",
            x0 + wpx.max(0.0) + 6.0,
            cy + 4.0,
            11.0,
            "start",
            &fmt_num(b.value, digits),
        );
    }
    if let Some((t, what)) = &c.threshold {
        let px = xs.at(transform(log, *t));
        let _ = write!(
            o,
            "<line class=\"threshold\" x1=\"{px:.1}\" y1=\"{TOP:.1}\" x2=\"{px:.1}\" y2=\"{y1:.1}\" stroke=\"#333\" stroke-dasharray=\"4 3\"/>"
        );
        text(
            &mut o,
            "threshold-label",
            px + 4.0,
            TOP - 4.0,
            11.0,
            "start",
            what,
        );
    }
    o.push_str("</svg>");
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_huge_bar_keeps_small_ones_visible() {
        let c = BarChart {
            title: "z".into(),
            value_label: "z".into(),
            bars: vec![
                Bar {
                    label: "exposure_us".into(),
                    value: 20800.0,
                },
                Bar {
                    label: "distance_m".into(),
                    value: 3.0,
                },
            ],
            threshold: Some((6.0, "noise level".into())),
        };
        let s = bar_chart(&c);
        let widths: Vec<f64> = s
            .split("class=\"bar\"")
            .skip(1)
            .map(|p| {
                p.split("width=\"")
                    .nth(1)
                    .unwrap()
                    .split('"')
                    .next()
                    .unwrap()
                    .parse()
                    .unwrap()
            })
            .collect();
        assert!(widths[1] > 0.05 * widths[0], "{widths:?}");
        assert!(s.contains("logarithmic"));
    }
}
