//! Line and point charts.
use std::fmt::Write as _;

use crate::axis::{Scale, nice_ticks, padded_range};
use crate::colour::{PALETTE, Rgb, hex};
use crate::svg::{self, escape, flow, fmt_num, text, text_width, vtext};

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SeriesStyle {
    /// Joined in x order (a curve, or a mean per x).
    Line,
    /// Separate markers (noisy data, several values per x).
    Points,
    /// A filled band between a lower and an upper curve (an uncertainty band); its points are
    /// the outline: the upper curve in x order, then the lower curve back ([`Series::band`]).
    Band,
}

/// One series of a line chart.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// (x, y) points in any order; non-finite values are gaps.
    pub points: Vec<(f64, f64)>,
    /// Line or points.
    pub style: SeriesStyle,
    /// Colour; `None` takes the next palette colour.
    pub colour: Option<Rgb>,
}

impl Series {
    /// A curve.
    pub fn line(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            name: name.into(),
            points,
            style: SeriesStyle::Line,
            colour: None,
        }
    }

    /// Markers.
    pub fn points(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            name: name.into(),
            points,
            style: SeriesStyle::Points,
            colour: None,
        }
    }

    /// A band from (x, lower, upper) triples, drawn filled under the other series and named
    /// once in the legend; a triple with a non-finite value is left out.
    pub fn band(name: impl Into<String>, x_lo_hi: &[(f64, f64, f64)]) -> Self {
        let mut t: Vec<(f64, f64, f64)> = x_lo_hi
            .iter()
            .copied()
            .filter(|(x, lo, hi)| x.is_finite() && lo.is_finite() && hi.is_finite())
            .collect();
        t.sort_by(|a, b| a.0.total_cmp(&b.0));
        let upper = t.iter().map(|(x, _, hi)| (*x, *hi));
        let lower = t.iter().rev().map(|(x, lo, _)| (*x, *lo));
        Series {
            name: name.into(),
            points: upper.chain(lower).collect(),
            style: SeriesStyle::Band,
            colour: None,
        }
    }

    /// With a fixed colour.
    pub fn colour(mut self, c: Rgb) -> Self {
        self.colour = Some(c);
        self
    }
}

/// A chart of x/y series.
#[derive(Debug, Clone, PartialEq)]
pub struct LineChart {
    /// Title above the plot.
    pub title: String,
    /// x axis title with unit.
    pub x_label: String,
    /// y axis title with unit.
    pub y_label: String,
    /// The series, drawn lines first then points (markers stay visible).
    pub series: Vec<Series>,
    /// Extra lines of text under the legend.
    pub notes: Vec<String>,
}

/// The mean y per distinct x (x equal within 1e-9 relative), sorted by x: the
/// one curve through data with several values per x (repeats, exposures).
pub fn mean_per_x(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut p: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    p.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out: Vec<(f64, f64, usize)> = Vec::new();
    for (x, y) in p {
        match out.last_mut() {
            Some((lx, sy, n)) if (x - *lx).abs() <= 1e-9 * x.abs().max(1.0) => {
                *sy += y;
                *n += 1;
            }
            _ => out.push((x, y, 1)),
        }
    }
    out.into_iter().map(|(x, s, n)| (x, s / n as f64)).collect()
}

fn sorted_finite(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut p: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    p.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    p
}

/// Fraction of the y range within which two series count as coincident: about
/// one pixel of a 300 px plot, i.e. indistinguishable on the page.
const COINCIDENT_FRACTION: f64 = 0.004;

/// For each series, the index of an earlier series it coincides with on the
/// page (same x values, every y within 0.4 % of `y_span`).
pub fn coincident_with(series: &[Series], y_span: f64) -> Vec<Option<usize>> {
    let tol = COINCIDENT_FRACTION * y_span.abs();
    let pts: Vec<Vec<(f64, f64)>> = series.iter().map(|s| sorted_finite(&s.points)).collect();
    (0..series.len())
        .map(|j| {
            (0..j).find(|&i| {
                let (a, b) = (&pts[i], &pts[j]);
                !a.is_empty()
                    && a.len() == b.len()
                    && series[i].style == series[j].style
                    && a.iter().zip(b).all(|(p, q)| {
                        (p.0 - q.0).abs() <= 1e-9 * p.0.abs().max(1.0) && (p.1 - q.1).abs() <= tol
                    })
            })
        })
        .collect()
}

/// Fill opacity of a band: the series drawn over it stay readable.
const BAND_OPACITY: f64 = 0.2;

const W: f64 = 860.0;
const LEFT: f64 = 84.0;
const RIGHT: f64 = 24.0;
const TOP: f64 = 44.0;
const PLOT_H: f64 = 300.0;
const LEGEND_ROW: f64 = 20.0;

fn marker(out: &mut String, k: usize, x: f64, y: f64, col: &str, class: &str) {
    match k % 4 {
        0 => {
            let _ = write!(
                out,
                "<circle class=\"{class}\" cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"2.5\" fill=\"{col}\"/>"
            );
        }
        1 => {
            let _ = write!(
                out,
                "<circle class=\"{class}\" cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"4\" fill=\"none\" stroke=\"{col}\" stroke-width=\"1.5\"/>"
            );
        }
        2 => {
            let _ = write!(
                out,
                "<rect class=\"{class}\" x=\"{:.1}\" y=\"{:.1}\" width=\"5\" height=\"5\" fill=\"{col}\"/>",
                x - 2.5,
                y - 2.5
            );
        }
        _ => {
            let _ = write!(
                out,
                "<rect class=\"{class}\" x=\"{:.1}\" y=\"{:.1}\" width=\"7\" height=\"7\" fill=\"none\" stroke=\"{col}\" stroke-width=\"1.5\"/>",
                x - 3.5,
                y - 3.5
            );
        }
    }
}

/// How each series is drawn: its colour, marker shape (points), the earlier series it coincides
/// with on the page, its legend text; and the notes under the legend.
struct Styling {
    colours: Vec<Rgb>,
    marker_kind: Vec<usize>,
    coincident: Vec<Option<usize>>,
    legend_names: Vec<String>,
    notes: Vec<String>,
}

impl Styling {
    fn new(c: &LineChart, y_span: f64) -> Self {
        let coincident = coincident_with(&c.series, y_span);
        let colours = c
            .series
            .iter()
            .enumerate()
            .map(|(i, s)| s.colour.unwrap_or(PALETTE[i % PALETTE.len()]))
            .collect();
        let marker_kind = c
            .series
            .iter()
            .scan(0usize, |k, s| {
                let v = *k;
                if s.style == SeriesStyle::Points {
                    *k += 1;
                }
                Some(v)
            })
            .collect();
        let legend_names = c
            .series
            .iter()
            .zip(&coincident)
            .map(|(s, co)| match co {
                Some(i) => format!("{} (= {}, coincident)", s.name, c.series[*i].name),
                None => s.name.clone(),
            })
            .collect();
        let mut notes = Vec::new();
        for (j, co) in coincident.iter().enumerate() {
            if let Some(i) = co {
                let how = match c.series[j].style {
                    SeriesStyle::Line => "drawn dashed over it",
                    SeriesStyle::Band => "filled over it",
                    SeriesStyle::Points => "its markers drawn over the other's",
                };
                notes.push(format!(
                    "“{}” coincides with “{}” on this scale ({how}).",
                    c.series[j].name, c.series[*i].name
                ));
            }
        }
        notes.extend(c.notes.iter().cloned());
        Styling {
            colours,
            marker_kind,
            coincident,
            legend_names,
            notes,
        }
    }

    /// The dash pattern of series `i`'s line: dashed when it coincides with an earlier one.
    fn dash(&self, i: usize) -> &'static str {
        if self.coincident[i].is_some() {
            " stroke-dasharray=\"7 5\""
        } else {
            ""
        }
    }
}

/// The plot area on the page and the data ranges it shows.
struct Frame {
    x_range: (f64, f64),
    y_range: (f64, f64),
    xs: Scale,
    ys: Scale,
}

impl Frame {
    const X0: f64 = LEFT;
    const X1: f64 = W - RIGHT;
    const Y0: f64 = TOP;
    const Y1: f64 = TOP + PLOT_H;

    fn new(c: &LineChart) -> Self {
        let x_range = padded_range(
            c.series.iter().flat_map(|s| s.points.iter().map(|p| p.0)),
            0.02,
        )
        .unwrap_or((0.0, 1.0));
        let y_range = padded_range(
            c.series.iter().flat_map(|s| s.points.iter().map(|p| p.1)),
            0.06,
        )
        .unwrap_or((0.0, 1.0));
        Frame {
            x_range,
            y_range,
            xs: Scale {
                d0: x_range.0,
                d1: x_range.1,
                p0: Self::X0,
                p1: Self::X1,
            },
            ys: Scale {
                d0: y_range.0,
                d1: y_range.1,
                p0: Self::Y1,
                p1: Self::Y0,
            },
        }
    }
}

/// Render the chart as a standalone SVG element.
pub fn line_chart(c: &LineChart) -> String {
    let f = Frame::new(c);
    let st = Styling::new(c, f.y_range.1 - f.y_range.0);
    let (x0, x1) = (Frame::X0, Frame::X1);
    let widths: Vec<f64> = st
        .legend_names
        .iter()
        .map(|n| 34.0 + text_width(n, 12.0) + 16.0)
        .collect();
    let (at, legend_h) = flow(&widths, x1 - x0, LEGEND_ROW);
    let legend_top = Frame::Y1 + 48.0;
    let notes_top = legend_top + legend_h + 8.0;
    let h = notes_top + 18.0 * st.notes.len() as f64 + 8.0;

    let mut o = String::new();
    svg::open(&mut o, "line-chart", W, h);
    text(&mut o, "title", W / 2.0, 24.0, 15.0, "middle", &c.title);
    let _ = write!(
        o,
        "<rect class=\"plot-area\" x=\"{x0:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{PLOT_H:.1}\" fill=\"none\" stroke=\"#444\"/>",
        Frame::Y0,
        x1 - x0
    );
    draw_axes(&mut o, c, &f);
    draw_series(&mut o, c, &f, &st);
    draw_legend(&mut o, c, &st, &at, legend_top);
    for (k, n) in st.notes.iter().enumerate() {
        text(
            &mut o,
            "note",
            x0,
            notes_top + 12.0 + 18.0 * k as f64,
            12.0,
            "start",
            n,
        );
    }
    o.push_str("</svg>");
    o
}

/// Both axes: ticks, grid lines, titles.
fn draw_axes(o: &mut String, c: &LineChart, f: &Frame) {
    let (x0, x1, y0, y1) = (Frame::X0, Frame::X1, Frame::Y0, Frame::Y1);
    let (xt, xd) = nice_ticks(f.x_range.0, f.x_range.1, 8);
    o.push_str("<g class=\"axis x-axis\">");
    for t in xt {
        let px = f.xs.at(t);
        svg::seg(o, px, y0, px, y1, "#eee");
        svg::seg(o, px, y1, px, y1 + 5.0, "#444");
        text(o, "tick", px, y1 + 18.0, 11.0, "middle", &fmt_num(t, xd));
    }
    let x_mid = (x0 + x1) / 2.0;
    text(
        o,
        "axis-title",
        x_mid,
        y1 + 36.0,
        12.0,
        "middle",
        &c.x_label,
    );
    o.push_str("</g><g class=\"axis y-axis\">");
    let (yt, yd) = nice_ticks(f.y_range.0, f.y_range.1, 6);
    for t in yt {
        let py = f.ys.at(t);
        svg::seg(o, x0, py, x1, py, "#eee");
        svg::seg(o, x0 - 5.0, py, x0, py, "#444");
        text(o, "tick", x0 - 8.0, py + 4.0, 11.0, "end", &fmt_num(t, yd));
    }
    vtext(o, "axis-title", 18.0, (y0 + y1) / 2.0, 12.0, &c.y_label);
    o.push_str("</g>");
}

/// The data, clipped to the plot area: bands first, then lines, then markers on top.
fn draw_series(o: &mut String, c: &LineChart, f: &Frame, st: &Styling) {
    let _ = write!(
        o,
        "<clipPath id=\"plot-clip\"><rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{PLOT_H:.1}\"/></clipPath>",
        Frame::X0,
        Frame::Y0,
        Frame::X1 - Frame::X0
    );
    for pass in [SeriesStyle::Band, SeriesStyle::Line, SeriesStyle::Points] {
        for (i, s) in c.series.iter().enumerate().filter(|(_, s)| s.style == pass) {
            let col = hex(st.colours[i]);
            let _ = write!(
                o,
                "<g class=\"series\" data-name=\"{}\" clip-path=\"url(#plot-clip)\">",
                escape(&s.name)
            );
            match s.style {
                SeriesStyle::Line => polylines(o, s, f, &col, st.dash(i)),
                SeriesStyle::Band => {
                    o.push_str("<polygon class=\"band\" points=\"");
                    for (x, y) in &s.points {
                        let _ = write!(o, "{:.1},{:.1} ", f.xs.at(*x), f.ys.at(*y));
                    }
                    let _ = write!(
                        o,
                        "\" fill=\"{col}\" fill-opacity=\"{BAND_OPACITY}\" stroke=\"{col}\" stroke-width=\"1\"/>"
                    );
                }
                SeriesStyle::Points => {
                    for (x, y) in s
                        .points
                        .iter()
                        .filter(|(x, y)| x.is_finite() && y.is_finite())
                    {
                        marker(
                            o,
                            st.marker_kind[i],
                            f.xs.at(*x),
                            f.ys.at(*y),
                            &col,
                            "point",
                        );
                    }
                }
            }
            o.push_str("</g>");
        }
    }
}

/// A line series joined in x order, one polyline per run between missing values.
fn polylines(o: &mut String, s: &Series, f: &Frame, col: &str, dash: &str) {
    let mut pts = s.points.clone();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    for run in pts.split(|(x, y)| !(x.is_finite() && y.is_finite())) {
        if run.is_empty() {
            continue;
        }
        o.push_str("<polyline class=\"line\" points=\"");
        for (x, y) in run {
            let _ = write!(o, "{:.1},{:.1} ", f.xs.at(*x), f.ys.at(*y));
        }
        let _ = write!(
            o,
            "\" fill=\"none\" stroke=\"{col}\" stroke-width=\"2\"{dash}/>"
        );
    }
}

/// The legend below the plot area (never on the data), entries at `at` (from [`flow`]).
fn draw_legend(o: &mut String, c: &LineChart, st: &Styling, at: &[(f64, f64)], top: f64) {
    let _ = write!(
        o,
        "<g class=\"legend\" transform=\"translate({:.1} {top:.1})\">",
        Frame::X0
    );
    for (i, ((s, name), (lx, ly))) in c.series.iter().zip(&st.legend_names).zip(at).enumerate() {
        let col = hex(st.colours[i]);
        let _ = write!(
            o,
            "<g class=\"legend-entry\" data-name=\"{}\" transform=\"translate({lx:.1} {ly:.1})\">",
            escape(&s.name)
        );
        match s.style {
            SeriesStyle::Line => {
                let _ = write!(
                    o,
                    "<line x1=\"0\" y1=\"9\" x2=\"26\" y2=\"9\" stroke=\"{col}\" stroke-width=\"2\"{}/>",
                    st.dash(i)
                );
            }
            SeriesStyle::Points => marker(o, st.marker_kind[i], 13.0, 9.0, &col, "legend-marker"),
            SeriesStyle::Band => {
                let _ = write!(
                    o,
                    "<rect x=\"0\" y=\"3\" width=\"26\" height=\"12\" fill=\"{col}\" fill-opacity=\"{BAND_OPACITY}\" stroke=\"{col}\" stroke-width=\"1\"/>"
                );
            }
        }
        text(o, "legend-text", 34.0, 13.0, 12.0, "start", name);
        o.push_str("</g>");
    }
    o.push_str("</g>");
}

#[cfg(test)]
mod tests {
    use super::*;

    fn polyline_xs(svg: &str) -> Vec<Vec<f64>> {
        svg.split("<polyline class=\"line\" points=\"")
            .skip(1)
            .map(|s| {
                s.split('"')
                    .next()
                    .unwrap()
                    .split_whitespace()
                    .map(|p| p.split(',').next().unwrap().parse().unwrap())
                    .collect()
            })
            .collect()
    }

    #[test]
    fn lines_are_joined_in_x_order_and_broken_at_gaps() {
        let c = LineChart {
            title: "t".into(),
            x_label: "distance [m]".into(),
            y_label: "mm".into(),
            series: vec![Series::line(
                "after",
                vec![
                    (1.0, 1.0),
                    (0.15, 2.0),
                    (1.8, 0.0),
                    (f64::NAN, 3.0),
                    (0.25, 1.0),
                ],
            )],
            notes: vec![],
        };
        let s = line_chart(&c);
        let runs = polyline_xs(&s);
        assert!(!runs.is_empty());
        for r in &runs {
            assert!(r.windows(2).all(|w| w[0] <= w[1]), "{r:?}");
        }
        assert!(!s.contains("NaN"));
    }

    #[test]
    fn a_band_is_one_filled_outline_under_the_data_with_one_legend_entry() {
        let b = Series::band(
            "±2 SE",
            &[(2.0, -1.0, 1.0), (1.0, -2.0, 2.0), (f64::NAN, 0.0, 1.0)],
        );
        // upper edge in x order, then the lower edge back; the non-finite triple left out
        assert_eq!(
            b.points,
            vec![(1.0, 2.0), (2.0, 1.0), (2.0, -1.0), (1.0, -2.0)]
        );
        let c = LineChart {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            series: vec![Series::points("data", vec![(1.0, 0.5)]), b],
            notes: vec![],
        };
        let s = line_chart(&c);
        assert_eq!(s.matches("<polygon class=\"band\"").count(), 1);
        assert!(s.find("class=\"band\"").unwrap() < s.find("class=\"point\"").unwrap());
        assert_eq!(s.matches("class=\"legend-entry\"").count(), 2);
        assert!(s.contains(">±2 SE</text>"));
    }

    #[test]
    fn coincident_series_are_announced() {
        let a: Vec<(f64, f64)> = (0..50).map(|i| (i as f64, (i as f64).sin())).collect();
        let b: Vec<(f64, f64)> = a.iter().map(|(x, y)| (*x, y + 1e-4)).collect();
        let c = LineChart {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            series: vec![
                Series::line("4-phase, 0.5 ms", a.clone()),
                Series::line("4-phase, 1 ms", b),
                Series::line("other", a.iter().map(|(x, y)| (*x, y + 0.5)).collect()),
            ],
            notes: vec![],
        };
        assert_eq!(coincident_with(&c.series, 2.0), vec![None, Some(0), None]);
        let s = line_chart(&c);
        assert!(s.contains("4-phase, 1 ms (= 4-phase, 0.5 ms, coincident)"));
        assert_eq!(
            s.matches("stroke-dasharray").count(),
            2,
            "series and legend dashed"
        );
    }

    #[test]
    fn mean_per_x_averages_repeats() {
        let m = mean_per_x(&[(1.0, 2.0), (0.5, 1.0), (1.0, 4.0), (0.5, f64::NAN)]);
        assert_eq!(m, vec![(0.5, 1.0), (1.0, 3.0)]);
    }

    #[test]
    fn legend_is_below_the_plot_area() {
        let c = LineChart {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            series: (0..9)
                .map(|i| {
                    Series::points(
                        format!("a rather long series name {i}"),
                        vec![(0.0, 0.0), (1.0, 1.0)],
                    )
                })
                .collect(),
            notes: vec![],
        };
        let s = line_chart(&c);
        let legend_y: f64 = s
            .split("class=\"legend\" transform=\"translate(")
            .nth(1)
            .unwrap()
            .split([' ', ')'])
            .nth(1)
            .unwrap()
            .parse()
            .unwrap();
        assert!(legend_y > TOP + PLOT_H);
    }
}
