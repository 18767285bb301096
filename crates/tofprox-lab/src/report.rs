//! Output of the lab: the `--json` documents (`diagnose`, `add`; their fields are the stable output other programs read),
//! the compact terminal table, and the self-contained HTML report with inline
//! SVG plots (plotters, rendered to strings; no network, no fonts needed).
use std::fmt::Write as _;

use plotters::prelude::*;
use serde_json::{Value, json};

use crate::diagnose::{AddOutcome, CaptureDepth, Comparison, Diagnosis, ErrorSummary, Z_NULL};
use crate::signatures::cancels_in_4phase;

fn num(v: f64) -> Value {
    if v.is_finite() { json!(v) } else { Value::Null }
}

/// `diagnose --json` (stable fields; `separate_by` added for `ambiguous`).
pub fn diagnosis_json(d: &Diagnosis) -> Value {
    json!({
        "verdict": d.verdict.as_str(),
        "effect": d.effect,
        "candidates": d.candidates.iter().map(|c| json!({
            "effect": c.effect,
            "delta_bic": num(c.delta_bic),
            "explained_excess": num(c.explained_excess),
            "cv_gain": num(c.cv_gain),
            "z_after": num(c.z_after),
            "params": c.params.iter().map(|(k, v)| (k.clone(), num(*v))).collect::<serde_json::Map<_, _>>(),
        })).collect::<Vec<_>>(),
        "fit": {"chi2_per_dof": num(d.fit.chi2_per_dof), "z": num(d.fit.z)},
        "strongest_condition": d.strongest_condition,
        "rms": {
            "raw_lsb": num(d.rms.raw_lsb),
            "depth_2phase_mm": num(d.rms.depth_2phase_mm),
            "depth_4phase_mm": num(d.rms.depth_4phase_mm),
        },
        "separate_by": d.separate_by,
    })
}

fn summary_json(s: &ErrorSummary) -> Value {
    json!({
        "raw_lsb": num(s.raw_lsb),
        "depth_2phase_mm": num(s.depth_2phase_mm),
        "depth_4phase_mm": num(s.depth_4phase_mm),
        "chi2_per_dof": num(s.chi2_per_dof),
    })
}

/// `add --json` (stable fields).
pub fn add_json(effect: &str, out: &AddOutcome) -> Value {
    json!({
        "effect": effect,
        "before": summary_json(&ErrorSummary::of(&out.before)),
        "after": summary_json(&ErrorSummary::of(&out.after)),
        "params": out.params.iter().map(|(k, v)| (k.clone(), num(*v))).collect::<serde_json::Map<_, _>>(),
    })
}

/// `compare --json`: fit statistics, RMS and the structure per condition.
pub fn comparison_json(c: &Comparison) -> Value {
    json!({
        "fit": {"chi2_per_dof": num(c.fit.chi2_per_dof), "z": num(c.fit.z)},
        "rms": {
            "raw_lsb": num(c.rms.raw_lsb),
            "depth_2phase_mm": num(c.rms.depth_2phase_mm),
            "depth_4phase_mm": num(c.rms.depth_4phase_mm),
        },
        "samples": c.n,
        "parameters": c.model.n_params,
        "noise": c.model.noise,
        "structure": c.structure.iter().map(|s| json!({
            "condition": s.condition, "z": num(s.z), "dof": s.dof, "direction": s.direction,
        })).collect::<Vec<_>>(),
    })
}

/// The compact terminal table of `compare`.
pub fn comparison_text(c: &Comparison) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "fit: χ²/dof = {:.3}, z = {:.1} over {} samples ({} parameters); noise {}",
        c.fit.chi2_per_dof,
        c.fit.z,
        c.n,
        c.model.n_params,
        if c.model.noise.from_repeats {
            "from repeated captures"
        } else {
            "from residuals (no repeats)"
        }
    );
    let _ = writeln!(
        s,
        "rms: raw {:.3} LSB, depth 2-phase {:.2} mm, 4-phase {:.2} mm",
        c.rms.raw_lsb, c.rms.depth_2phase_mm, c.rms.depth_4phase_mm
    );
    let _ = writeln!(
        s,
        "{:<16} {:>10} {:>6}  direction   (structure z; ≤ 6 is noise)",
        "condition", "z", "dof"
    );
    for st in &c.structure {
        let flag = if st.z > 6.0 { "  ◀ model fails" } else { "" };
        let _ = writeln!(
            s,
            "{:<16} {:>10.1} {:>6}  {:<10}{flag}",
            st.condition, st.z, st.dof, st.direction
        );
    }
    s
}

/// The compact terminal table of `diagnose`.
pub fn diagnosis_text(d: &Diagnosis) -> String {
    let mut s = String::new();
    let verdict = match (&d.effect, d.verdict.as_str()) {
        (Some(e), "missing_effect") => format!("MISSING EFFECT: {e}"),
        (Some(e), "ambiguous") => format!(
            "AMBIGUOUS: {e} or {} — vary {} to separate them",
            d.runner_up.as_deref().unwrap_or("?"),
            d.separate_by.as_deref().unwrap_or("?")
        ),
        (_, "nothing_missing") => "NOTHING MISSING".to_string(),
        _ => format!(
            "UNEXPLAINED structure, strongest against {}",
            d.strongest_condition.as_deref().unwrap_or("?")
        ),
    };
    let _ = writeln!(s, "verdict: {verdict}");
    let _ = writeln!(s, "         {}", d.reason);
    let _ = writeln!(
        s,
        "fit: χ²/dof = {:.3}, z = {:.1}; rms raw {:.3} LSB, depth 2-phase {:.2} mm, 4-phase {:.2} mm",
        d.fit.chi2_per_dof, d.fit.z, d.rms.raw_lsb, d.rms.depth_2phase_mm, d.rms.depth_4phase_mm
    );
    let _ = writeln!(
        s,
        "{:<24} {:>9} {:>8} {:>10} {:>12}  4-phase cancels",
        "candidate", "explained", "cv_gain", "z_after", "ΔBIC"
    );
    for c in &d.candidates {
        let _ = writeln!(
            s,
            "{:<24} {:>8.1}% {:>7.1}% {:>10.1} {:>12.1}  {}",
            c.effect,
            100.0 * c.explained_excess,
            100.0 * c.cv_gain,
            c.z_after,
            c.delta_bic,
            if cancels_in_4phase(&c.effect) {
                "yes"
            } else {
                "no"
            }
        );
    }
    for (id, why) in &d.skipped {
        let _ = writeln!(s, "{id:<24} not testable: {why}");
    }
    s
}

const W: u32 = 760;
const H: u32 = 360;

type Series<'a> = (&'a str, RGBColor, Vec<(f64, f64)>, bool);

fn range_of(series: &[Series<'_>]) -> ((f64, f64), (f64, f64)) {
    let mut xr = (f64::INFINITY, f64::NEG_INFINITY);
    let mut yr = (f64::INFINITY, f64::NEG_INFINITY);
    for (_, _, pts, _) in series {
        for (x, y) in pts.iter().filter(|(x, y)| x.is_finite() && y.is_finite()) {
            xr = (xr.0.min(*x), xr.1.max(*x));
            yr = (yr.0.min(*y), yr.1.max(*y));
        }
    }
    if !xr.0.is_finite() {
        xr = (0.0, 1.0);
        yr = (0.0, 1.0);
    }
    let pad = |r: (f64, f64)| {
        let d = (r.1 - r.0).abs().max(1e-9) * 0.05;
        (r.0 - d, r.1 + d)
    };
    (pad(xr), pad(yr))
}

/// A scatter/line chart as an SVG string (`true` in a series = points).
fn chart(title: &str, xl: &str, yl: &str, series: &[Series<'_>]) -> String {
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (W, H)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let ((x0, x1), (y0, y1)) = range_of(series);
        let Ok(mut c) = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(8)
            .x_label_area_size(36)
            .y_label_area_size(60)
            .build_cartesian_2d(x0..x1, y0..y1)
        else {
            return String::new();
        };
        let _ = c
            .configure_mesh()
            .x_desc(xl)
            .y_desc(yl)
            .light_line_style(WHITE.mix(0.0))
            .draw();
        for (name, col, pts, points) in series {
            let pts: Vec<(f64, f64)> = pts
                .iter()
                .copied()
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .collect();
            let col = *col;
            let r = if *points {
                c.draw_series(pts.iter().map(|p| Circle::new(*p, 2, col.filled())))
            } else {
                c.draw_series(LineSeries::new(pts, col.stroke_width(2)))
            };
            if let Ok(r) = r {
                r.label(*name).legend(move |(x, y)| {
                    Rectangle::new([(x, y - 4), (x + 12, y + 4)], col.filled())
                });
            }
        }
        let _ = c
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw();
        let _ = root.present();
    }
    out
}

/// Horizontal bars of the structure score per condition (red above the noise level).
fn structure_bars(c: &[crate::structure::ConditionScore]) -> String {
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (W, 40 + 24 * c.len().max(1) as u32))
            .into_drawing_area();
        let _ = root.fill(&WHITE);
        let zmax = c.iter().map(|s| s.z).fold(10.0f64, f64::max);
        let n = c.len().max(1);
        let Ok(mut ch) = ChartBuilder::on(&root)
            .caption(
                "structure score z per condition (≤ 6: noise-like)",
                ("sans-serif", 16),
            )
            .margin(8)
            .x_label_area_size(28)
            .y_label_area_size(120)
            .build_cartesian_2d(0.0..zmax * 1.05, 0..n)
        else {
            return String::new();
        };
        let names: Vec<String> = c.iter().map(|s| s.condition.clone()).collect();
        let _ = ch
            .configure_mesh()
            .y_labels(n)
            .y_label_formatter(&|i| {
                names
                    .get(n.saturating_sub(1 + *i))
                    .cloned()
                    .unwrap_or_default()
            })
            .draw();
        for (i, s) in c.iter().enumerate() {
            let y = n - 1 - i;
            let col = if s.z > 6.0 {
                RED
            } else {
                RGBColor(120, 160, 120)
            };
            let _ = ch.draw_series(std::iter::once(Rectangle::new(
                [(0.0, y), (s.z.max(0.0), y + 1)],
                col.filled(),
            )));
        }
        let _ = root.present();
    }
    out
}

/// Residual map: χ² per sample of every pixel.
fn pixel_map(c: &Comparison, rows: usize, cols: usize) -> String {
    let mut out = String::new();
    {
        let cell = (320 / cols.max(rows).max(1)).max(4) as i32;
        let root = SVGBackend::with_string(
            &mut out,
            (
                (cell as usize * cols + 140) as u32,
                (cell as usize * rows + 40) as u32,
            ),
        )
        .into_drawing_area();
        let _ = root.fill(&WHITE);
        let vmax = c
            .pixel_chi2
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(2.0f64, f64::max);
        for (p, v) in c.pixel_chi2.iter().enumerate() {
            let (r, cc) = ((p / cols) as i32, (p % cols) as i32);
            let t = if v.is_finite() {
                ((v - 1.0) / (vmax - 1.0).max(1e-9)).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let col = RGBColor(
                (255.0 * t) as u8,
                (255.0 * (1.0 - t) * 0.8) as u8,
                (255.0 * (1.0 - t)) as u8,
            );
            let _ = root.draw(&Rectangle::new(
                [
                    (10 + cc * cell, 30 + r * cell),
                    (10 + (cc + 1) * cell, 30 + (r + 1) * cell),
                ],
                col.filled(),
            ));
        }
        let _ = root.draw(&Text::new(
            format!("χ²/sample per pixel (blue 1 … red {vmax:.1})"),
            (10, 8),
            ("sans-serif", 14),
        ));
        let _ = root.present();
    }
    out
}

type Curve = Vec<(f64, f64)>;

fn depth_series(d: &[CaptureDepth]) -> (Curve, Curve) {
    (
        d.iter()
            .map(|c| (c.distance_m, c.depth_2phase_mm))
            .collect(),
        d.iter()
            .map(|c| (c.distance_m, c.depth_4phase_mm))
            .collect(),
    )
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// One self-contained HTML page: comparison, optional diagnosis, optional add.
pub fn html_report(
    title: &str,
    rows: usize,
    cols: usize,
    cmp: &Comparison,
    diag: Option<&Diagnosis>,
    add: Option<(&str, &AddOutcome)>,
) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>{t}</title><style>\
         body{{font-family:sans-serif;max-width:820px;margin:auto}} table{{border-collapse:collapse}}\
         td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}} .bad{{color:#b00}} .ok{{color:#070}}\
         </style></head><body><h1>{t}</h1>",
        t = esc(title)
    );
    if let Some(d) = diag {
        let _ = write!(
            h,
            "<h2>Verdict: {} {}</h2><p>{}</p>",
            d.verdict.as_str(),
            esc(d.effect.as_deref().unwrap_or("")),
            esc(&d.reason)
        );
        if let Some(sep) = &d.separate_by {
            let _ = write!(h, "<p>To separate the two, vary <b>{}</b>.</p>", esc(sep));
        }
    }
    let _ = write!(
        h,
        "<h2>How well the model explains the measurement</h2><table><tr><th>χ²/dof</th><th>z</th><th>raw RMS [LSB]</th>\
         <th>2-phase depth RMS [mm]</th><th>4-phase depth RMS [mm]</th><th>samples</th></tr>\
         <tr><td class=\"{}\">{:.3}</td><td>{:.1}</td><td>{:.3}</td><td>{:.2}</td><td>{:.2}</td><td>{}</td></tr></table>\
         <p>Noise model (pooled photon transfer, {}): var = ({:.3} + {:.4}·A + {:.2e}·ambient·t + {:.2e}·t)/averaged LSB².</p>",
        if cmp.fit.z > Z_NULL { "bad" } else { "ok" },
        cmp.fit.chi2_per_dof,
        cmp.fit.z,
        cmp.rms.raw_lsb,
        cmp.rms.depth_2phase_mm,
        cmp.rms.depth_4phase_mm,
        cmp.n,
        if cmp.model.noise.from_repeats {
            "from repeated captures"
        } else {
            "from residuals"
        },
        cmp.model.noise.a,
        cmp.model.noise.b,
        cmp.model.noise.c,
        cmp.model.noise.e,
    );
    let meas: Vec<(f64, f64)> = cmp
        .depth
        .iter()
        .map(|c| (c.distance_m, c.measured_amplitude_lsb))
        .collect();
    let model: Vec<(f64, f64)> = cmp
        .depth
        .iter()
        .map(|c| (c.distance_m, c.model_amplitude_lsb))
        .collect();
    h.push_str("<h3>Measured vs model</h3>");
    h.push_str(&chart(
        "4-phase amplitude per capture (mean over pixels)",
        "distance [m]",
        "amplitude [LSB]",
        &[("measured", BLUE, meas, true), ("model", RED, model, true)],
    ));
    let (d2, d4) = depth_series(&cmp.depth);
    h.push_str("<h3>Where the model fails</h3>");
    h.push_str(&chart(
        "depth residual depth(measured) − depth(model), mean per capture",
        "distance [m]",
        "depth residual [mm]",
        &[
            ("2-phase", RGBColor(230, 120, 0), d2, true),
            ("4-phase", BLUE, d4, true),
        ],
    ));
    h.push_str(&structure_bars(&cmp.structure));
    for st in cmp.structure.iter().take(3) {
        let di = match st.direction {
            "amplitude" => 1,
            "phase" => 2,
            _ => 0,
        };
        let unit = ["offset [LSB]", "relative amplitude", "phase [rad]"][di];
        let est: Vec<(f64, f64)> = st.bins.iter().map(|b| (b.x, b.est[di])).collect();
        let hi: Vec<(f64, f64)> = st.bins.iter().map(|b| (b.x, 2.0 * b.se[di])).collect();
        let lo: Vec<(f64, f64)> = st.bins.iter().map(|b| (b.x, -2.0 * b.se[di])).collect();
        h.push_str(&chart(
            &format!(
                "residual vs {} (z = {:.1}, {} direction)",
                st.condition, st.z, st.direction
            ),
            &st.condition,
            unit,
            &[
                ("binned residual", RED, est, true),
                ("+2 SE", BLACK, hi, false),
                ("−2 SE", BLACK, lo, false),
            ],
        ));
    }
    h.push_str("<h3>Residual map</h3>");
    h.push_str(&pixel_map(cmp, rows, cols));
    if let Some(d) = diag {
        h.push_str(
            "<h2>Candidate effects</h2><table><tr><th>effect</th><th>explained excess</th><th>cv gain</th>\
             <th>z after</th><th>ΔBIC</th><th>2-phase after [mm]</th><th>4-phase after [mm]</th><th>4-phase cancels</th></tr>",
        );
        for c in &d.candidates {
            let (a2, a4) = c
                .rms_after
                .map(|r| (r.depth_2phase_mm, r.depth_4phase_mm))
                .unwrap_or((f64::NAN, f64::NAN));
            let _ = write!(
                h,
                "<tr><th>{}</th><td>{:.1}%</td><td>{:.1}%</td><td>{:.1}</td><td>{:.0}</td><td>{:.2}</td><td>{:.2}</td><td>{}</td></tr>",
                esc(&c.effect),
                100.0 * c.explained_excess,
                100.0 * c.cv_gain,
                c.z_after,
                c.delta_bic,
                a2,
                a4,
                if cancels_in_4phase(&c.effect) {
                    "yes"
                } else {
                    "no"
                }
            );
        }
        h.push_str("</table>");
        for (id, why) in &d.skipped {
            let _ = write!(h, "<p>{}: not testable — {}</p>", esc(id), esc(why));
        }
    }
    if let Some((effect, out)) = add {
        let b = ErrorSummary::of(&out.before);
        let a = ErrorSummary::of(&out.after);
        let _ = write!(
            h,
            "<h2>After adding {e}</h2><table><tr><th></th><th>raw RMS [LSB]</th><th>2-phase [mm]</th><th>4-phase [mm]</th><th>χ²/dof</th></tr>\
             <tr><th>before</th><td>{:.3}</td><td>{:.2}</td><td>{:.2}</td><td>{:.3}</td></tr>\
             <tr><th>after</th><td>{:.3}</td><td>{:.2}</td><td>{:.2}</td><td>{:.3}</td></tr></table>",
            b.raw_lsb,
            b.depth_2phase_mm,
            b.depth_4phase_mm,
            b.chi2_per_dof,
            a.raw_lsb,
            a.depth_2phase_mm,
            a.depth_4phase_mm,
            a.chi2_per_dof,
            e = esc(effect)
        );
        let (b2, b4) = depth_series(&out.before.depth);
        let (a2, a4) = depth_series(&out.after.depth);
        h.push_str(&chart(
            "depth residual before/after (mean per capture)",
            "distance [m]",
            "depth residual [mm]",
            &[
                ("2-phase before", RGBColor(230, 120, 0), b2, true),
                ("2-phase after", RGBColor(120, 60, 0), a2, false),
                ("4-phase before", RGBColor(100, 140, 255), b4, true),
                ("4-phase after", BLUE, a4, false),
            ],
        ));
    }
    h.push_str("</body></html>\n");
    h
}
