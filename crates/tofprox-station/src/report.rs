//! The station's report: JSON (the [`Report`] as it is) and a self-contained HTML page with
//! the figures against their limits (charts by `tofprox-chart`).

use std::fmt::Write as _;
use std::path::Path;

use tofprox_chart::{Bar, BarChart, bar_chart, escape};

use crate::run::{REPORT_HTML, REPORT_JSON};
use crate::{PartCheck, Report, StationError};

/// Write `report.json` and `report.html` into `out`.
pub(crate) fn write_reports(r: &Report, out: &Path) -> Result<(), StationError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| StationError::Io { path, source }
    };
    let json = serde_json::to_string_pretty(r).map_err(|e| StationError::Io {
        path: out.join(REPORT_JSON),
        source: std::io::Error::other(e),
    })?;
    let p = out.join(REPORT_JSON);
    std::fs::write(&p, json + "\n").map_err(io(&p))?;
    let p = out.join(REPORT_HTML);
    std::fs::write(&p, html(r)).map_err(io(&p))?;
    Ok(())
}

/// A figure as a share of its limit (1 = at the limit): the chart's common scale.
fn share_of_limit(c: &PartCheck) -> f64 {
    match (c.min, c.max) {
        (Some(lo), Some(hi)) if c.value < lo => 1.0 + (lo - c.value) / (hi - lo).max(f64::EPSILON),
        (_, Some(hi)) if hi > 0.0 => c.value / hi,
        (_, Some(_)) => {
            if c.value > 0.0 {
                f64::INFINITY
            } else {
                0.0
            }
        }
        _ => f64::NAN,
    }
}

fn fmt_limit(c: &PartCheck) -> String {
    match (c.min, c.max) {
        (Some(lo), Some(hi)) => format!("{lo} … {hi} {}", c.unit),
        (None, Some(hi)) => format!("≤ {hi} {}", c.unit),
        (Some(lo), None) => format!("≥ {lo} {}", c.unit),
        (None, None) => "—".into(),
    }
}

/// The self-contained HTML page.
pub fn html(r: &Report) -> String {
    let verdict = if r.passed {
        "PASS".to_string()
    } else {
        format!("FAIL: {}", r.failed_parts().join(", "))
    };
    let mut o = String::new();
    let _ = write!(
        o,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>tofprox station: {v}</title>\
         <style>body{{font-family:sans-serif;max-width:960px;margin:2em auto}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #ccc;padding:2px 8px;text-align:left}}.fail{{color:#b00020;font-weight:bold}}\
         .pass{{color:#1b7f3b}}</style></head><body>\n<h1>Calibration station: <span class=\"{cls}\">{v}</span></h1>\n\
         <p>{line} line — {station}<br>module: {module}<br>set: {set} (complete: {complete})<br>\
         time: {dev:.3} s on the device's clock, {wall:.2} s wall</p>\n",
        v = escape(&verdict),
        cls = if r.passed { "pass" } else { "fail" },
        line = r.line,
        station = escape(&r.station),
        module = escape(&r.module),
        set = escape(&r.set.display().to_string()),
        complete = if r.complete { "yes" } else { "no" },
        dev = r.device_s,
        wall = r.wall_s,
    );
    let chart = BarChart {
        title: "Each figure as a share of its limit".into(),
        value_label: "value / limit".into(),
        bars: r
            .checks
            .iter()
            .map(|c| Bar {
                label: format!("{}: {}", c.part, c.figure),
                value: share_of_limit(c),
            })
            .collect(),
        threshold: Some((1.0, "limit".into())),
    };
    o.push_str(&bar_chart(&chart));
    o.push_str("\n<h2>Parts</h2>\n<table><tr><th>part</th><th>figure</th><th>value</th><th>limit</th><th>result</th><th>a failure means</th></tr>\n");
    for c in &r.checks {
        let _ = writeln!(
            o,
            "<tr><td>{}</td><td>{}</td><td>{:.4} {}</td><td>{}</td><td class=\"{}\">{}</td><td>{}</td></tr>",
            escape(&c.part),
            escape(&c.figure),
            c.value,
            escape(&c.unit),
            escape(&fmt_limit(c)),
            if c.passed { "pass" } else { "fail" },
            if c.passed { "pass" } else { "FAIL" },
            if c.passed {
                String::new()
            } else {
                escape(&c.meaning)
            },
        );
    }
    o.push_str("</table>\n<h2>Steps</h2>\n<table><tr><th>step</th><th>frames</th><th>exposure</th><th>device time</th><th>wall time</th></tr>\n");
    for s in &r.steps {
        let _ = writeln!(
            o,
            "<tr><td>{}</td><td>{}</td><td>{} µs</td><td>{:.3} s</td><td>{:.2} s</td></tr>",
            escape(&s.step),
            s.frames,
            s.exposure_us,
            s.device_s,
            s.wall_s
        );
    }
    o.push_str("</table>\n<h2>Extraction</h2>\n<ul>\n");
    for n in &r.notes {
        let _ = writeln!(o, "<li>{}</li>", escape(n));
    }
    o.push_str("</ul>\n</body></html>\n");
    o
}
