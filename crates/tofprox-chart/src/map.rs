//! Maps of per-pixel values with axes and a colour bar.
use std::fmt::Write as _;

use crate::axis::{Scale, nice_ticks};
use crate::colour::{hex, viridis};
use crate::svg::{self, fmt_num, text, vtext};

/// A per-pixel map.
#[derive(Debug, Clone, PartialEq)]
pub struct Heatmap {
    /// Title above the map.
    pub title: String,
    /// Rows and columns of `values`.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Row-major values; non-finite cells are drawn grey ("no data").
    pub values: Vec<f64>,
    /// Sensor row/column of the first cell (the read-out window's origin), for the axes.
    pub origin: (usize, usize),
    /// Colour-bar range (low → dark blue, high → yellow); `None` = finite min/max.
    pub range: Option<(f64, f64)>,
    /// Colour-bar title with unit.
    pub value_label: String,
}

/// Where the map sits on the page: cell size, the cell area's corners, the colour bar's left edge.
struct Frame {
    cell: f64,
    x0: f64,
    y0: f64,
    x1: f64,
    y1: f64,
    bar_x: f64,
}

impl Frame {
    fn new(rows: usize, cols: usize) -> Self {
        let cell = (320.0 / rows.max(cols) as f64).clamp(1.5, 24.0);
        let (x0, y0) = (70.0, 44.0);
        let (x1, y1) = (x0 + cell * cols as f64, y0 + cell * rows as f64);
        Frame {
            cell,
            x0,
            y0,
            x1,
            y1,
            bar_x: x1 + 28.0,
        }
    }
}

/// The colour bar's range: the given one, else the finite values' min/max (`(0, 1)` without any).
fn value_range(m: &Heatmap) -> (f64, f64) {
    m.range.unwrap_or_else(|| {
        let f = m.values.iter().copied().filter(|v| v.is_finite());
        let lo = f.clone().fold(f64::INFINITY, f64::min);
        let hi = f.fold(f64::NEG_INFINITY, f64::max);
        if lo.is_finite() {
            (lo, hi.max(lo + 1e-9))
        } else {
            (0.0, 1.0)
        }
    })
}

/// Render the map as a standalone SVG element: cells, row/column axes in
/// sensor coordinates, colour bar with ticks.
pub fn heatmap(m: &Heatmap) -> String {
    let (rows, cols) = (m.rows.max(1), m.cols.max(1));
    let f = Frame::new(rows, cols);
    let (lo, hi) = value_range(m);
    let any_missing = m.values.iter().any(|v| !v.is_finite());
    let w = f.bar_x + 16.0 + 70.0 + 30.0;
    let h = f.y1 + 64.0 + if any_missing { 18.0 } else { 0.0 };
    let mut o = String::new();
    svg::open(&mut o, "heatmap", w.max(420.0), h);
    text(&mut o, "title", 12.0, 24.0, 15.0, "start", &m.title);
    o.push_str("<g class=\"cells\" shape-rendering=\"crispEdges\">");
    for (p, v) in m.values.iter().enumerate().take(rows * cols) {
        let (r, c) = ((p / cols) as f64, (p % cols) as f64);
        let col = if v.is_finite() {
            hex(viridis((v - lo) / (hi - lo)))
        } else {
            "#bbbbbb".to_string()
        };
        let _ = write!(
            o,
            "<rect class=\"cell\" x=\"{:.2}\" y=\"{:.2}\" width=\"{:.2}\" height=\"{:.2}\" fill=\"{col}\"/>",
            f.x0 + c * f.cell,
            f.y0 + r * f.cell,
            f.cell + 0.05,
            f.cell + 0.05
        );
    }
    o.push_str("</g>");
    let _ = write!(
        o,
        "<rect class=\"plot-area\" x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"none\" stroke=\"#444\"/>",
        f.x0,
        f.y0,
        f.x1 - f.x0,
        f.y1 - f.y0
    );
    draw_axes(&mut o, &f, m.origin, rows, cols);
    draw_colour_bar(&mut o, &f, (lo, hi), &m.value_label);
    if any_missing {
        let y = f.y1 + 54.0;
        text(
            &mut o,
            "note",
            f.x0,
            y,
            12.0,
            "start",
            "grey cells: no data",
        );
    }
    o.push_str("</svg>");
    o
}

/// Row and column axes in sensor coordinates (ticks at cell centres).
fn draw_axes(o: &mut String, f: &Frame, origin: (usize, usize), rows: usize, cols: usize) {
    o.push_str("<g class=\"axis x-axis\">");
    let (ct, _) = nice_ticks(origin.1 as f64, (origin.1 + cols - 1) as f64, 6);
    for t in ct {
        let px = f.x0 + (t - origin.1 as f64 + 0.5) * f.cell;
        svg::seg(o, px, f.y1, px, f.y1 + 5.0, "#444");
        text(o, "tick", px, f.y1 + 17.0, 11.0, "middle", &fmt_num(t, 0));
    }
    let x_mid = (f.x0 + f.x1) / 2.0;
    text(
        o,
        "axis-title",
        x_mid,
        f.y1 + 34.0,
        12.0,
        "middle",
        "sensor column",
    );
    o.push_str("</g><g class=\"axis y-axis\">");
    let (rt, _) = nice_ticks(origin.0 as f64, (origin.0 + rows - 1) as f64, 6);
    for t in rt {
        let py = f.y0 + (t - origin.0 as f64 + 0.5) * f.cell;
        svg::seg(o, f.x0 - 5.0, py, f.x0, py, "#444");
        text(o, "tick", f.x0 - 8.0, py + 4.0, 11.0, "end", &fmt_num(t, 0));
    }
    vtext(
        o,
        "axis-title",
        22.0,
        (f.y0 + f.y1) / 2.0,
        12.0,
        "sensor row",
    );
    o.push_str("</g>");
}

/// The colour bar right of the map: 32 steps, high at the top, ticks and title.
fn draw_colour_bar(o: &mut String, f: &Frame, (lo, hi): (f64, f64), label: &str) {
    let (bar_x, y0, y1) = (f.bar_x, f.y0, f.y1);
    o.push_str("<g class=\"colour-bar\">");
    let steps = 32;
    let bh = y1 - y0;
    for k in 0..steps {
        let t = (k as f64 + 0.5) / steps as f64;
        let _ = write!(
            o,
            "<rect x=\"{bar_x:.1}\" y=\"{:.2}\" width=\"16\" height=\"{:.2}\" fill=\"{}\"/>",
            y1 - (k + 1) as f64 * bh / steps as f64,
            bh / steps as f64 + 0.05,
            hex(viridis(t))
        );
    }
    let _ = write!(
        o,
        "<rect x=\"{bar_x:.1}\" y=\"{y0:.1}\" width=\"16\" height=\"{bh:.1}\" fill=\"none\" stroke=\"#444\"/>"
    );
    let bs = Scale {
        d0: lo,
        d1: hi,
        p0: y1,
        p1: y0,
    };
    let (vt, vd) = nice_ticks(lo, hi, 5);
    for t in vt {
        let py = bs.at(t);
        svg::seg(o, bar_x + 16.0, py, bar_x + 21.0, py, "#444");
        text(
            o,
            "tick",
            bar_x + 24.0,
            py + 4.0,
            11.0,
            "start",
            &fmt_num(t, vd),
        );
    }
    vtext(o, "axis-title", bar_x + 86.0, (y0 + y1) / 2.0, 12.0, label);
    o.push_str("</g>");
}
