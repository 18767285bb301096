//! The lab's self-contained HTML report with inline SVG plots (drawn by `tofprox-chart`).
use std::collections::BTreeMap;
use std::fmt::Write as _;

use tofprox_chart::{
    Bar, BarChart, Heatmap, LineChart, Series, bar_chart, heatmap, line_chart, mean_per_x,
};

use crate::diagnose::{
    AddOutcome, CaptureDepth, Comparison, Diagnosis, ErrorSummary, Explanation, Z_NULL,
};
use crate::signatures::cancels_in_4phase;

use super::{FitNotes, interval_end, percent};

/// The fitted parameters of an added effect as an HTML table: value,
/// standard error and profile interval ends, then the notes ([`FitNotes`]).
fn fitted_html(
    h: &mut String,
    effect: &str,
    (params, standard_errors): (&BTreeMap<String, f64>, &BTreeMap<String, f64>),
    (note, at_bound, intervals): FitNotes<'_>,
) {
    let _ = write!(
        h,
        "<h3>{} fitted</h3><p>± 1 standard error with the per-pixel parameters free, scaled by χ²/dof; \
         profile intervals where χ² rises by 1 and 4 times χ²/dof with the others refitted \
         (≤/≥: the parameter's range bound).</p><table><tr><th>parameter</th><th>value</th><th>± SE</th>\
         <th>1σ lower</th><th>1σ upper</th><th>2σ lower</th><th>2σ upper</th></tr>",
        esc(effect)
    );
    for (k, v) in params {
        let se = standard_errors.get(k).copied().unwrap_or(f64::NAN);
        let ends = intervals.get(k).map_or(
            ["—".to_string(), "—".into(), "—".into(), "—".into()],
            |iv| {
                [
                    interval_end(iv, "lower", 0),
                    interval_end(iv, "upper", 0),
                    interval_end(iv, "lower", 1),
                    interval_end(iv, "upper", 1),
                ]
            },
        );
        let _ = write!(
            h,
            "<tr><th>{}</th><td>{v:.5e}</td><td>{}</td>",
            esc(k),
            if se.is_finite() {
                format!("{se:.2e}")
            } else {
                "—".into()
            }
        );
        for e in ends {
            let _ = write!(h, "<td>{}</td>", esc(&e));
        }
        h.push_str("</tr>");
    }
    h.push_str("</table>");
    for n in note.into_iter().chain(at_bound.iter().map(String::as_str)) {
        let _ = write!(h, "<p>{}</p>", esc(n));
    }
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

/// One value of a capture's depth comparison (mm).
type DepthOf = fn(&CaptureDepth) -> f64;

/// One algorithm's before/after chart: its name, its value, the "after" points, and the
/// colours of before and after.
type BeforeAfter = (&'static str, DepthOf, Curve, [u8; 3], [u8; 3]);

/// Per exposure (ascending), the captures' (distance, `value`) points.
fn by_exposure(d: &[CaptureDepth], value: DepthOf) -> Vec<(f64, Curve)> {
    let mut out: Vec<(f64, Curve)> = Vec::new();
    for c in d {
        match out.iter_mut().find(|(t, _)| *t == c.exposure_us) {
            Some((_, points)) => points.push((c.distance_m, value(c))),
            None => out.push((c.exposure_us, vec![(c.distance_m, value(c))])),
        }
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    out
}

/// The systematic part of a depth residual (mm): the RMS over distances of its mean per
/// distance, which the capture-to-capture noise averages out of; `None` without data.
fn systematic_mm(points: &[(f64, f64)]) -> Option<f64> {
    let means = mean_per_x(points);
    (!means.is_empty())
        .then(|| (means.iter().map(|(_, y)| y * y).sum::<f64>() / means.len() as f64).sqrt())
}

const ORANGE: [u8; 3] = [230, 120, 0];
const BROWN: [u8; 3] = [120, 60, 0];
const LIGHT_BLUE: [u8; 3] = [100, 140, 255];
const BLUE: [u8; 3] = [31, 119, 180];
const RED: [u8; 3] = [214, 39, 40];
const BLACK: [u8; 3] = [0, 0, 0];

fn chart(title: &str, x_label: &str, y_label: &str, series: Vec<Series>) -> String {
    line_chart(&LineChart {
        title: title.into(),
        x_label: x_label.into(),
        y_label: y_label.into(),
        series,
        notes: Vec::new(),
    })
}

/// Horizontal bars of the structure score per condition (red above the noise level).
fn structure_bars(c: &[crate::structure::ConditionScore]) -> String {
    bar_chart(&BarChart {
        title: "structure score z per condition (≤ 6: noise-like)".into(),
        value_label: "structure score z".into(),
        bars: c
            .iter()
            .map(|s| Bar {
                label: s.condition.clone(),
                value: s.z,
            })
            .collect(),
        threshold: Some((6.0, "noise level z = 6".into())),
    })
}

/// Residual map: χ² per sample of every pixel, in sensor coordinates.
fn pixel_map(c: &Comparison, rows: usize, cols: usize, origin: [usize; 2]) -> String {
    let vmax = c
        .pixel_chi2
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(2.0f64, f64::max);
    heatmap(&Heatmap {
        title: "χ² per sample of each pixel (1 = noise-like)".into(),
        rows,
        cols,
        values: c.pixel_chi2.clone(),
        origin: (origin[0], origin[1]),
        range: Some((1.0, vmax)),
        value_label: "χ²/sample".into(),
    })
}

fn esc(s: &str) -> String {
    tofprox_chart::escape(s)
}

/// Why an error summary has no value: no capture of that kind in the recording.
const NO_DATA: &str = "no capture in the recording gives this value";

/// A share as a table cell in percent, or "—" with the reason as tooltip.
fn percent_cell(v: f64, why_not: &str) -> String {
    if v.is_finite() {
        format!("<td>{:.1}%</td>", 100.0 * v)
    } else {
        format!("<td class=\"na\" title=\"{}\">—</td>", esc(why_not))
    }
}

/// A table cell: the value with `decimals`, or "n/a" with the reason as tooltip.
fn cell(v: Option<f64>, decimals: usize, why_not: &str) -> String {
    match v {
        Some(v) if v.is_finite() => format!("<td>{v:.decimals$}</td>"),
        _ => format!("<td class=\"na\" title=\"{}\">n/a</td>", esc(why_not)),
    }
}

fn html_open(title: &str) -> String {
    format!(
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>{t}</title><style>\
         body{{font-family:sans-serif;max-width:820px;margin:auto}} table{{border-collapse:collapse}}\
         td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}} .bad{{color:#b00}} .ok{{color:#070}}\
         </style></head><body><h1>{t}</h1>",
        t = esc(title)
    )
}

/// One self-contained HTML page: comparison, optional diagnosis, optional add.
pub fn html_report(
    title: &str,
    rows: usize,
    cols: usize,
    origin: [usize; 2],
    cmp: &Comparison,
    diag: Option<&Diagnosis>,
    add: Option<(&str, &AddOutcome)>,
) -> String {
    let mut h = html_open(title);
    h.push_str(&html_sections(
        rows,
        cols,
        origin,
        cmp,
        diag,
        add.map(|(e, o)| (e, &o.before, &o.after)),
    ));
    if let Some((e, o)) = add {
        fitted_html(
            &mut h,
            e,
            (&o.params, &o.standard_errors),
            (o.standard_errors_note.as_deref(), &o.at_bound, &o.intervals),
        );
    }
    h.push_str("</body></html>\n");
    h
}

/// One page for `lab explain`: a table of the steps, then every step's
/// comparison, diagnosis and before/after.
pub fn explain_html(
    title: &str,
    rows: usize,
    cols: usize,
    origin: [usize; 2],
    ex: &Explanation,
) -> String {
    let mut h = html_open(title);
    let _ = write!(
        h,
        "<h2>Final verdict: {}</h2><p class=\"evidence\"><b>Evidence:</b> {}</p><p>{}</p><table><tr><th>step</th><th>verdict</th><th>added</th>\
         <th>explained</th><th>cv gain</th><th>χ²/dof</th><th>z</th><th>remaining [mm]</th>\
         <th>raw RMS [LSB]</th><th>2-phase [mm]</th><th>4-phase [mm]</th></tr>",
        ex.verdict().as_str(),
        esc(&ex
            .steps
            .last()
            .map_or(String::new(), |s| s.diagnosis.evidence())),
        esc(ex.steps.last().map_or("", |s| s.diagnosis.reason.as_str()))
    );
    for (i, st) in ex.steps.iter().enumerate() {
        let d = &st.diagnosis;
        let best = st
            .added
            .as_ref()
            .and_then(|e| d.candidates.iter().find(|c| &c.effect == e));
        let _ = write!(
            h,
            "<tr><th>{}</th><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.3}</td><td>{:.1}</td>\
             <td>{:.2}</td><td>{:.3}</td><td>{:.2}</td><td>{:.2}</td></tr>",
            i + 1,
            d.verdict.as_str(),
            esc(st.added.as_deref().unwrap_or("—")),
            best.map_or("".into(), |c| percent(c.explained_excess)),
            best.map_or("".into(), |c| percent(c.cv_gain)),
            d.fit.chi2_per_dof,
            d.fit.z,
            d.size.mm,
            d.rms.raw_lsb,
            d.rms.depth_2phase_mm,
            d.rms.depth_4phase_mm,
        );
    }
    h.push_str("</table>");
    for f in &ex.fitted {
        fitted_html(
            &mut h,
            &f.effect,
            (&f.params, &f.standard_errors),
            (f.standard_errors_note.as_deref(), &f.at_bound, &f.intervals),
        );
    }
    for (i, st) in ex.steps.iter().enumerate() {
        let _ = write!(
            h,
            "<hr><h1>Step {}{}</h1>",
            i + 1,
            st.added
                .as_ref()
                .map_or(String::new(), |e| format!(": add {}", esc(e)))
        );
        let next = ex.steps.get(i + 1).map(|n| &n.comparison);
        h.push_str(&html_sections(
            rows,
            cols,
            origin,
            &st.comparison,
            Some(&st.diagnosis),
            st.added
                .as_deref()
                .zip(next)
                .map(|(e, n)| (e, &st.comparison, n)),
        ));
    }
    h.push_str("</body></html>\n");
    h
}

fn html_sections(
    rows: usize,
    cols: usize,
    origin: [usize; 2],
    cmp: &Comparison,
    diag: Option<&Diagnosis>,
    add: Option<(&str, &Comparison, &Comparison)>,
) -> String {
    let mut h = String::new();
    if let Some(d) = diag {
        verdict_html(&mut h, d);
    }
    fit_html(&mut h, cmp);
    model_charts_html(&mut h, cmp);
    h.push_str("<h3>Residual map</h3>");
    h.push_str(&pixel_map(cmp, rows, cols, origin));
    if let Some(d) = diag {
        candidates_html(&mut h, d);
    }
    if let Some((effect, before, after)) = add {
        after_adding_html(&mut h, effect, before, after);
    }
    h
}

/// The verdict, its reason, what separates look-alikes, the remaining structure in mm and LSB.
fn verdict_html(h: &mut String, d: &Diagnosis) {
    let _ = write!(
        h,
        "<h2>Verdict: {} {}</h2><p class=\"evidence\"><b>Evidence:</b> {}</p><p>{}</p>",
        d.verdict.as_str(),
        esc(d.effect.as_deref().unwrap_or("")),
        esc(&d.evidence()),
        esc(&d.reason)
    );
    if let Some(sep) = &d.separate_by {
        let _ = write!(h, "<p>To separate the two, vary <b>{}</b>.</p>", esc(sep));
    }
    if let Some(p) = crate::user::proposal(d) {
        let _ = write!(
            h,
            "<p class=\"proposal\"><b>Proposal:</b> {}</p>",
            esc(&p.sentence)
        );
    }
    let _ = write!(
        h,
        "<p>Remaining structure: {:.2} mm depth-equivalent ({:.3} LSB, z = {:.1}); tolerance {:.2} mm \
         (single-acquisition noise {:.2} mm).</p>",
        d.size.mm, d.size.lsb, d.fit.z, d.tolerance_mm, d.noise_single.mm
    );
    for sm in &d.small {
        let _ = write!(
            h,
            "<p>Detectable but small: {} <b>{}</b> (z = {:.1}, {:.3} mm, {:.3} LSB)</p>",
            sm.kind,
            esc(&sm.name),
            sm.z,
            sm.size_mm,
            sm.size_lsb
        );
    }
}

/// How well the model explains the measurement: χ²/dof, z, RMS, and the noise model used.
fn fit_html(h: &mut String, cmp: &Comparison) {
    let _ = write!(
        h,
        "<h2>How well the model explains the measurement</h2><table><tr><th>χ²/dof</th><th>z</th><th>raw RMS [LSB]</th>\
         <th>2-phase depth RMS [mm]</th><th>4-phase depth RMS [mm]</th><th>samples</th><th>AIC</th><th>BIC</th></tr>\
         <tr><td class=\"{}\">{:.3}</td><td>{:.1}</td>{}{}{}<td>{}</td><td>{:.1}</td><td>{:.1}</td></tr></table>\
         <p>Noise model (pooled photon transfer, {}): var = ({:.3} + {:.4}·A + {:.2e}·ambient·t + {:.2e}·t)/averaged LSB².</p>",
        if cmp.fit.z > Z_NULL { "bad" } else { "ok" },
        cmp.fit.chi2_per_dof,
        cmp.fit.z,
        cell(Some(cmp.rms.raw_lsb), 3, NO_DATA),
        cell(Some(cmp.rms.depth_2phase_mm), 2, NO_DATA),
        cell(Some(cmp.rms.depth_4phase_mm), 2, NO_DATA),
        cmp.n,
        cmp.fit.aic,
        cmp.fit.bic,
        esc(&cmp.model.noise.source.describe()),
        cmp.model.noise.a,
        cmp.model.noise.b,
        cmp.model.noise.c,
        cmp.model.noise.e,
    );
}

/// The legend of the ±2 SE band: what it is and where its noise came from.
fn band_label(cmp: &Comparison) -> String {
    format!(
        "±2 SE of the binned residual (noise {})",
        cmp.model.noise.source.describe()
    )
}

/// `exposure_us` as a legend label: "250 µs".
fn exposure_label(t: f64) -> String {
    format!("{} µs", tofprox_format::fmt_num(t))
}

/// Measured vs model amplitude, the depth residual per capture, the residual vs each condition.
fn model_charts_html(h: &mut String, cmp: &Comparison) {
    h.push_str("<h3>Measured vs model</h3>");
    // per exposure (the amplitude scales with it), the model as filled markers under the
    // measurement's open ones: both stay visible, each exposure its own marker pair
    let mut series = Vec::new();
    let measured = by_exposure(&cmp.depth, |c| c.measured_amplitude_lsb);
    let model = by_exposure(&cmp.depth, |c| c.model_amplitude_lsb);
    for ((t, meas), (_, modl)) in measured.into_iter().zip(model) {
        let e = exposure_label(t);
        series.push(Series::points(format!("model, {e}"), modl).colour(RED));
        series.push(Series::points(format!("measured, {e}"), meas).colour(BLUE));
    }
    h.push_str(&chart(
        "4-phase amplitude per capture (mean over pixels)",
        "distance [m]",
        "amplitude [LSB]",
        series,
    ));
    h.push_str("<h3>Where the model fails</h3>");
    // one chart per algorithm (small multiples): their residuals overlap near zero; one series
    // per exposure, labelled, told apart by marker shape (the chart's markers cycle)
    let by_alg: [(&str, DepthOf, [u8; 3]); 2] = [
        ("2-phase", |c| c.depth_2phase_mm, ORANGE),
        ("4-phase", |c| c.depth_4phase_mm, BLUE),
    ];
    for (alg, value, colour) in by_alg {
        let series = by_exposure(&cmp.depth, value)
            .into_iter()
            .map(|(t, points)| {
                let name = format!("{alg}, {}", exposure_label(t));
                Series::points(name, points).colour(colour)
            })
            .collect();
        h.push_str(&chart(
            &format!("{alg} depth residual depth(measured) − depth(model), mean per capture"),
            "distance [m]",
            "depth residual [mm]",
            series,
        ));
    }
    h.push_str(&structure_bars(&cmp.structure));
    for st in cmp.structure.iter().take(3) {
        let di = match st.direction {
            "amplitude" => 1,
            "phase" => 2,
            _ => 0,
        };
        let unit = ["offset [LSB]", "relative amplitude", "phase [rad]"][di];
        let est: Vec<(f64, f64)> = st.bins.iter().map(|b| (b.x, b.est[di])).collect();
        let band: Vec<(f64, f64, f64)> = st
            .bins
            .iter()
            .map(|b| (b.x, -2.0 * b.se[di], 2.0 * b.se[di]))
            .collect();
        h.push_str(&chart(
            &format!(
                "residual vs {} (z = {:.1}, {} direction)",
                st.condition, st.z, st.direction
            ),
            &st.condition,
            unit,
            vec![
                Series::band(band_label(cmp), &band).colour(BLACK),
                Series::points("binned residual", est).colour(RED),
            ],
        ));
    }
}

/// The candidate effects table, with what was skipped and each candidate's flags.
fn candidates_html(h: &mut String, d: &Diagnosis) {
    h.push_str(
        "<h2>Candidate effects</h2><table><tr><th>effect</th><th>explained excess</th><th>cv gain</th>\
         <th>explained [mm]</th><th>z after</th><th>ΔAIC</th><th>ΔBIC</th><th>2-phase after [mm]</th><th>4-phase after [mm]</th><th>4-phase cancels</th></tr>",
    );
    const NO_EXCESS: &str =
        "no share: the residual has no significant excess over the noise (see explained [mm])";
    const NOT_REFITTED: &str =
        "not refitted: only the leading candidates are refitted with the whole model";
    for c in &d.candidates {
        let after = c.rms_after;
        let _ = write!(
            h,
            "<tr><th>{}</th>{}{}{}{}{}{}{}{}<td>{}</td></tr>",
            esc(&c.effect),
            percent_cell(c.explained_excess, NO_EXCESS),
            percent_cell(c.cv_gain, NO_EXCESS),
            cell(Some(c.explained.mm), 3, "no screening fit"),
            cell(Some(c.z_after), 1, NOT_REFITTED),
            cell(Some(c.delta_aic), 0, NOT_REFITTED),
            cell(Some(c.delta_bic), 0, NOT_REFITTED),
            cell(after.map(|r| r.depth_2phase_mm), 2, NOT_REFITTED),
            cell(after.map(|r| r.depth_4phase_mm), 2, NOT_REFITTED),
            if cancels_in_4phase(&c.effect) {
                "yes"
            } else {
                "no"
            }
        );
    }
    h.push_str("</table>");
    if d.candidates.iter().any(|c| c.rms_after.is_none()) {
        let _ = write!(
            h,
            "<p class=\"note\">n/a: {NOT_REFITTED}; they are ranked by their screening fit.</p>"
        );
    }
    for (id, why) in &d.skipped {
        let _ = write!(h, "<p>{}: not testable — {}</p>", esc(id), esc(why));
    }
    for c in &d.candidates {
        for f in &c.flags {
            let _ = write!(h, "<p class=\"note\">{}: {}</p>", esc(&c.effect), esc(f));
        }
    }
}

/// The errors before and after adding `effect`, as a table and a chart.
fn after_adding_html(h: &mut String, effect: &str, before: &Comparison, after: &Comparison) {
    let b = ErrorSummary::of(before);
    let a = ErrorSummary::of(after);
    let _ = write!(
        h,
        "<h2>After adding {e}</h2><table><tr><th></th><th>raw RMS [LSB]</th><th>2-phase [mm]</th><th>4-phase [mm]</th><th>χ²/dof</th><th>AIC</th><th>BIC</th></tr>\
         <tr><th>before</th>{}{}{}{}{}{}</tr><tr><th>after</th>{}{}{}{}{}{}</tr></table>",
        cell(Some(b.raw_lsb), 3, NO_DATA),
        cell(Some(b.depth_2phase_mm), 2, NO_DATA),
        cell(Some(b.depth_4phase_mm), 2, NO_DATA),
        cell(Some(b.chi2_per_dof), 3, NO_DATA),
        cell(Some(b.aic), 1, NO_DATA),
        cell(Some(b.bic), 1, NO_DATA),
        cell(Some(a.raw_lsb), 3, NO_DATA),
        cell(Some(a.depth_2phase_mm), 2, NO_DATA),
        cell(Some(a.depth_4phase_mm), 2, NO_DATA),
        cell(Some(a.chi2_per_dof), 3, NO_DATA),
        cell(Some(a.aic), 1, NO_DATA),
        cell(Some(a.bic), 1, NO_DATA),
        e = esc(effect)
    );
    let (b2, b4) = depth_series(&before.depth);
    let (a2, a4) = depth_series(&after.depth);
    let _ = write!(
        h,
        "<p>Systematic depth error (RMS over distances of the mean residual per distance, the part \
         averaging does not remove): 2-phase {} → {} mm, 4-phase {} → {} mm.</p>",
        systematic_mm(&b2).map_or(NO_DATA.into(), |v| format!("{v:.2}")),
        systematic_mm(&a2).map_or(NO_DATA.into(), |v| format!("{v:.2}")),
        systematic_mm(&b4).map_or(NO_DATA.into(), |v| format!("{v:.2}")),
        systematic_mm(&a4).map_or(NO_DATA.into(), |v| format!("{v:.2}")),
    );
    // one chart per algorithm (small multiples): "before" per exposure (labelled, one marker
    // shape each), "after" as the mean per distance, joined in distance order
    let by_alg: [BeforeAfter; 2] = [
        ("2-phase", |c| c.depth_2phase_mm, a2, ORANGE, BROWN),
        ("4-phase", |c| c.depth_4phase_mm, a4, LIGHT_BLUE, BLUE),
    ];
    for (alg, value, a, before_colour, after_colour) in by_alg {
        let mut series: Vec<Series> = by_exposure(&before.depth, value)
            .into_iter()
            .map(|(t, points)| {
                Series::points(format!("{alg} before, {}", exposure_label(t)), points)
                    .colour(before_colour)
            })
            .collect();
        series.push(
            Series::line(format!("{alg} after (mean per distance)"), mean_per_x(&a))
                .colour(after_colour),
        );
        h.push_str(&chart(
            &format!("{alg} depth residual before/after (mean per capture)"),
            "distance [m]",
            "depth residual [mm]",
            series,
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::systematic_mm;

    #[test]
    fn systematic_error_is_the_rms_of_the_mean_per_distance_not_of_the_noise() {
        // per distance a systematic offset (3, −4 mm) and two repeats with ±10 mm of noise
        let points = [
            (0.5, 3.0 + 10.0),
            (0.5, 3.0 - 10.0),
            (1.0, -4.0 - 10.0),
            (1.0, -4.0 + 10.0),
        ];
        let want = ((9.0 + 16.0) / 2.0f64).sqrt();
        assert!((systematic_mm(&points).unwrap() - want).abs() < 1e-12);
        assert_eq!(systematic_mm(&[(0.5, f64::NAN)]), None);
    }
}
