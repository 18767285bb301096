//! What a person sees, checked in a real browser (issue 13): the `lab diagnose`
//! and `lab add` reports and the thesis figures of `sim figures` are rendered
//! by headless Chromium (Debian's `chromium`, installed by `.ci/run`) and the
//! rendered page is checked with the browser's own layout
//! (`getBoundingClientRect`): every bar has exactly one label on its row and it
//! names the condition whose score the bar shows; no `NaN` anywhere in the
//! text; legends do not cover data points or the plot area; lines are joined
//! in x order. Screenshots go to `target/tmp/browser/` for a person to look at.
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

mod common;
use common::{run, text};

/// The checker run inside the page; it appends its findings as JSON in
/// `<pre id="ux-checks">`, which `--dump-dom` prints.
const CHECKER: &str = r#"<script>
(function () {
  const out = { charts: 0, bars: 0, legends: 0, points: 0, lines: 0, problems: [] };
  const P = out.problems;
  const mid = (r) => [(r.left + r.right) / 2, (r.top + r.bottom) / 2];
  document.querySelectorAll('svg.chart').forEach((svg, si) => {
    out.charts++;
    const t = svg.querySelector('text.title');
    const name = t ? t.textContent : 'chart ' + si;
    const bars = [...svg.querySelectorAll('rect.bar')];
    const labels = [...svg.querySelectorAll('text.bar-label')];
    if (bars.length !== labels.length) P.push(`${name}: ${bars.length} bars but ${labels.length} bar labels`);
    out.barValues = out.barValues || {};
    bars.forEach((b) => {
      out.bars++;
      const r = b.getBoundingClientRect();
      const on = labels.filter((l) => { const c = mid(l.getBoundingClientRect())[1]; return c >= r.top && c <= r.bottom; });
      if (on.length !== 1) P.push(`${name}: the bar of ${b.dataset.label} has ${on.length} labels on its row`);
      else if (on[0].textContent !== b.dataset.label) P.push(`${name}: the bar of ${b.dataset.label} is labelled ${on[0].textContent}`);
      else out.barValues[on[0].textContent] = { value: parseFloat(b.dataset.value), width: r.width };
    });
    const plot = svg.querySelector('rect.plot-area');
    const pa = plot ? plot.getBoundingClientRect() : null;
    svg.querySelectorAll('g.series polyline').forEach((pl) => {
      out.lines++;
      const m = pl.getScreenCTM();
      let last = -Infinity;
      for (const p of pl.points) {
        const s = new DOMPoint(p.x, p.y).matrixTransform(m);
        if (s.x < last - 0.01) { P.push(`${name}: a line goes back in x at ${s.x.toFixed(1)} px`); break; }
        last = s.x;
      }
    });
    svg.querySelectorAll('g.legend').forEach((lg) => {
      out.legends++;
      const L = lg.getBoundingClientRect();
      const inside = (x, y) => x >= L.left && x <= L.right && y >= L.top && y <= L.bottom;
      if (pa && !(L.top >= pa.bottom || L.bottom <= pa.top || L.left >= pa.right || L.right <= pa.left))
        P.push(`${name}: the legend overlaps the plot area`);
      svg.querySelectorAll('g.series .point').forEach((p) => {
        out.points++;
        const [x, y] = mid(p.getBoundingClientRect());
        if (inside(x, y)) P.push(`${name}: the legend covers a data point at (${x.toFixed(0)}, ${y.toFixed(0)})`);
      });
      svg.querySelectorAll('g.series polyline').forEach((pl) => {
        const m = pl.getScreenCTM();
        for (const p of pl.points) {
          const s = new DOMPoint(p.x, p.y).matrixTransform(m);
          if (inside(s.x, s.y)) { P.push(`${name}: the legend covers a line point`); break; }
        }
      });
    });
    // every legend entry's text and rendered size; every band's outline on the screen
    svg.querySelectorAll('g.legend-entry').forEach((e) => {
      const r = e.getBoundingClientRect();
      (out.legendEntries = out.legendEntries || []).push({ chart: name, text: e.textContent, w: r.width, h: r.height });
    });
    svg.querySelectorAll('polygon.band').forEach((b) => {
      const m = b.getScreenCTM();
      const pts = [...b.points].map((p) => { const s = new DOMPoint(p.x, p.y).matrixTransform(m); return [s.x, s.y]; });
      (out.bands = out.bands || []).push({ chart: name, fill: b.getAttribute('fill'), opacity: parseFloat(b.getAttribute('fill-opacity')), pts });
    });
    // where each series is on the screen, for the test that looks at the screenshot's pixels
    svg.querySelectorAll('g.series').forEach((g) => {
      const el = g.querySelector('polyline, .point');
      if (!el) return;
      const stroke = el.getAttribute('stroke');
      const colour = stroke && stroke !== 'none' ? stroke : el.getAttribute('fill');
      const entry = [...svg.querySelectorAll('g.legend-entry')].find((e) => e.dataset.name === g.dataset.name);
      const legend = entry ? entry.textContent : '';
      const at = [];
      g.querySelectorAll('polyline').forEach((pl) => {
        const m = pl.getScreenCTM();
        for (const p of pl.points) { const s = new DOMPoint(p.x, p.y).matrixTransform(m); at.push([s.x, s.y]); }
      });
      g.querySelectorAll('.point').forEach((p) => at.push(mid(p.getBoundingClientRect())));
      const style = el.tagName === 'polyline' ? 'line' : 'points';
      (out.seen = out.seen || []).push({ chart: name, name: g.dataset.name, style, colour, legend, at });
    });
  });
  if (document.body.innerText.includes('NaN')) P.push('"NaN" in the page text');
  const pre = document.createElement('pre');
  pre.id = 'ux-checks';
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
})();
</script>"#;

/// Run headless Chromium on `page` with `extra` arguments; its stdout.
fn headless(chromium: &Path, page: &Path, extra: &[&str]) -> String {
    let profile = tempfile::tempdir().unwrap();
    let o = Command::new(chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
            "--hide-scrollbars",
            "--window-size=900,4800",
            "--virtual-time-budget=5000",
        ])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .args(extra)
        .arg(format!("file://{}", page.display()))
        .output()
        .expect("run chromium");
    assert!(
        o.status.success(),
        "chromium failed on {}: {}",
        page.display(),
        text(&o.stderr)
    );
    text(&o.stdout)
}

fn shots_dir() -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("browser");
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A screenshot's pixels (RGB or RGBA, 8 bit).
struct Screenshot {
    width: usize,
    height: usize,
    channels: usize,
    data: Vec<u8>,
}

/// Fewest of a series' points that must show its own colour, alone, in the screenshot.
const SERIES_ALONE_SHARE: f64 = 0.5;

impl Screenshot {
    fn load(path: &Path) -> Self {
        let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
        let mut reader = png::Decoder::new(file).read_info().unwrap();
        let mut data = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut data).unwrap();
        assert_eq!(info.bit_depth, png::BitDepth::Eight, "{}", path.display());
        Screenshot {
            width: info.width as usize,
            height: info.height as usize,
            channels: info.line_size / info.width as usize,
            data,
        }
    }

    /// The colours (as `#rrggbb`-near RGB) found within `radius` px of `(x, y)`.
    fn near(&self, (x, y): (f64, f64), radius: i64) -> Vec<[u8; 3]> {
        let mut out = Vec::new();
        for dy in -radius..=radius {
            for dx in -radius..=radius {
                let (px, py) = (x.round() as i64 + dx, y.round() as i64 + dy);
                if px < 0 || py < 0 || px as usize >= self.width || py as usize >= self.height {
                    continue;
                }
                let i = (py as usize * self.width + px as usize) * self.channels;
                out.push([self.data[i], self.data[i + 1], self.data[i + 2]]);
            }
        }
        out
    }

    /// Whether a series (as the checker saw it: colour, legend, screen points) can be told apart
    /// in the picture from the chart's `others` series of its style (colour, legend text: a mean
    /// line runs through its own scatter of points): at ≥
    /// [`SERIES_ALONE_SHARE`] of its points its own colour shows within 2 px (5 px for a marker)
    /// and no other series' colour within 3 px. A series the legend announces as coincident with another is
    /// exempt (drawn dashed over it); one that others coincide with need only show its colour.
    fn series_problem(&self, s: &Value, others: &[([u8; 3], &str)]) -> Option<String> {
        let name = s["name"].as_str().unwrap_or_default();
        if s["legend"]
            .as_str()
            .unwrap_or_default()
            .contains("coincident")
        {
            return None;
        }
        let covered = others
            .iter()
            .any(|(_, legend)| legend.contains(&format!("(= {name}, coincident)")));
        let own = hex_rgb(s["colour"].as_str()?)?;
        let at: Vec<(f64, f64)> = s["at"]
            .as_array()?
            .iter()
            .filter_map(|p| Some((p[0].as_f64()?, p[1].as_f64()?)))
            .collect();
        // a marker's colour may lie only on its outline (a ring of radius 4)
        let own_radius = if s["style"] == "points" { 5 } else { 2 };
        let alone = at
            .iter()
            .filter(|&&p| {
                self.near(p, own_radius).iter().any(|c| close(*c, own))
                    && (covered
                        || !self.near(p, 3).iter().any(|c| {
                            // a series in the same colour is drawn as one element with it (the
                            // two edges of a ±2 SE band)
                            others.iter().any(|(o, _)| !close(*o, own) && close(*c, *o))
                        }))
            })
            .count();
        let share = alone as f64 / at.len().max(1) as f64;
        (share < SERIES_ALONE_SHARE).then(|| {
            format!(
                "{}: series “{name}” shows alone in the picture at only {:.0} % of its {} points",
                s["chart"].as_str().unwrap_or_default(),
                100.0 * share,
                at.len()
            )
        })
    }
}

impl Screenshot {
    /// Whether a band (as the checker saw it: fill colour and opacity, outline = upper curve
    /// then lower curve back) shows its tint in the picture: a quarter of the way from its upper
    /// to its lower edge, at ≥ [`SERIES_ALONE_SHARE`] of its x positions that lie in the
    /// screenshot and are ≥ 8 px wide, the fill blended over white shows within 1 px.
    /// `Ok(false)`: the band is narrower than that everywhere (its outline shows it).
    fn band_problem(&self, b: &Value) -> Result<bool, String> {
        let chart = b["chart"].as_str().unwrap_or_default();
        let bad = || format!("{chart}: the band has no fill colour or opacity");
        let fill = b["fill"].as_str().and_then(hex_rgb).ok_or_else(bad)?;
        let op = b["opacity"].as_f64().ok_or_else(bad)?;
        let tint = fill.map(|c| (255.0 - op * (255.0 - f64::from(c))).round() as u8);
        let pts: Vec<(f64, f64)> = b["pts"]
            .as_array()
            .map_or(&[][..], |a| a.as_slice())
            .iter()
            .filter_map(|p| Some((p[0].as_f64()?, p[1].as_f64()?)))
            .collect();
        let n = pts.len() / 2;
        let probes: Vec<(f64, f64)> = (0..n)
            .map(|i| (pts[i], pts[pts.len() - 1 - i]))
            .filter(|(up, lo)| lo.1 - up.1 >= 8.0 && lo.1 < self.height as f64)
            .map(|(up, lo)| (up.0, up.1 + 0.25 * (lo.1 - up.1)))
            .collect();
        let shown = probes
            .iter()
            .filter(|&&p| self.near(p, 1).iter().any(|c| close(*c, tint)))
            .count();
        if probes.is_empty() {
            return Ok(false);
        }
        let share = shown as f64 / probes.len() as f64;
        if share < SERIES_ALONE_SHARE {
            return Err(format!(
                "{chart}: the band shows its tint at only {:.0} % of its {} positions",
                100.0 * share,
                probes.len()
            ));
        }
        Ok(true)
    }
}

/// The rendered legend texts of the charts whose title starts with `chart`.
fn legend_texts<'a>(v: &'a Value, chart: &str) -> Vec<&'a str> {
    v["legendEntries"]
        .as_array()
        .map_or(&[][..], |a| a.as_slice())
        .iter()
        .filter(|e| e["chart"].as_str().is_some_and(|c| c.starts_with(chart)))
        .filter(|e| e["w"].as_f64().unwrap_or(0.0) > 10.0 && e["h"].as_f64().unwrap_or(0.0) > 5.0)
        .filter_map(|e| e["text"].as_str())
        .collect()
}

/// `#rrggbb` → RGB.
fn hex_rgb(h: &str) -> Option<[u8; 3]> {
    let h = h.strip_prefix('#')?;
    let c = |i: usize| u8::from_str_radix(h.get(i..i + 2)?, 16).ok();
    Some([c(0)?, c(2)?, c(4)?])
}

/// Two colours the eye takes for the same (sum of channel differences ≤ 60).
fn close(a: [u8; 3], b: [u8; 3]) -> bool {
    a.iter()
        .zip(b)
        .map(|(x, y)| x.abs_diff(y) as u32)
        .sum::<u32>()
        <= 60
}

/// Render `html` (a page or a bare SVG) in the browser: a screenshot for a
/// person, and the checker's findings — its layout checks, and every series
/// told apart in the screenshot's pixels ([`Screenshot::series_problem`]).
fn render(chromium: &Path, name: &str, html: &str) -> Value {
    let body = if html.trim_start().starts_with("<svg") {
        format!(
            "<!DOCTYPE html><html><head><meta charset=\"utf-8\"></head><body>{html}</body></html>"
        )
    } else {
        html.to_string()
    };
    let page_plain = shots_dir().join(format!("{name}.html"));
    std::fs::write(&page_plain, &body).unwrap();
    let shot = shots_dir().join(format!("{name}.png"));
    headless(
        chromium,
        &page_plain,
        &[&format!("--screenshot={}", shot.display())],
    );
    assert!(shot.is_file(), "no screenshot {}", shot.display());
    eprintln!("screenshot: {}", shot.display());
    let checked = body.replace("</body>", &format!("{CHECKER}</body>"));
    assert_ne!(
        checked, body,
        "{name}: no </body> to put the checker before"
    );
    let page = shots_dir().join(format!("{name}.checked.html"));
    std::fs::write(&page, checked).unwrap();
    let dom = headless(chromium, &page, &["--dump-dom"]);
    let json = dom
        .split("<pre id=\"ux-checks\">")
        .nth(1)
        .and_then(|s| s.split("</pre>").next())
        .unwrap_or_else(|| panic!("{name}: the checker did not run; DOM:\n{dom}"));
    let json = json
        .replace("&quot;", "\"")
        .replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&amp;", "&");
    let v: Value = serde_json::from_str(&json).unwrap();
    let mut problems: Vec<Value> = v["problems"].as_array().unwrap().clone();
    let picture = Screenshot::load(&shot);
    let bands: Vec<Value> = v["bands"].as_array().cloned().unwrap_or_default();
    let mut bands_seen = 0;
    for b in &bands {
        match picture.band_problem(b) {
            Ok(seen) => bands_seen += usize::from(seen),
            Err(p) => problems.push(Value::from(p)),
        }
    }
    let seen: &[Value] = v["seen"].as_array().map_or(&[], |a| a.as_slice());
    for s in seen {
        let others: Vec<([u8; 3], &str)> = seen
            .iter()
            .filter(|o| o["chart"] == s["chart"] && o["name"] != s["name"])
            .filter(|o| o["style"] == s["style"])
            .filter_map(|o| Some((hex_rgb(o["colour"].as_str()?)?, o["legend"].as_str()?)))
            .collect();
        problems.extend(picture.series_problem(s, &others).map(Value::from));
    }
    assert!(
        problems.is_empty(),
        "{name} as rendered by chromium (screenshot {}):\n{}",
        shot.display(),
        problems
            .iter()
            .map(|p| p.as_str().unwrap_or_default().to_string())
            .collect::<Vec<_>>()
            .join("\n")
    );
    let mut v = v;
    v["bands_seen"] = Value::from(bands_seen);
    v
}

#[test]
fn lab_reports_render_correctly_in_a_browser() {
    let Some(chromium) = tofprox_testkit::require_program("chromium", "chromium") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let mut truth = tofprox_model::ModelConfig::baseline();
    truth.set_enabled("vcsel_droop", true).unwrap();
    let sweep = common::lab_sweep(tmp.path(), &truth, 7);
    let (rec, base_p) = (Path::new(&sweep.rec), Path::new(&sweep.base));
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let diag = tmp.path().join("diag.html");
    let o = run(&[
        "lab",
        "diagnose",
        &s(rec),
        "--model",
        &s(base_p),
        "--report",
        &s(&diag),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let v = render(
        &chromium,
        "lab-diagnose",
        &std::fs::read_to_string(&diag).unwrap(),
    );
    assert!(v["bars"].as_u64().unwrap() >= 5, "{v}");
    assert!(v["legends"].as_u64().unwrap() >= 3, "{v}");
    // the ±2 SE band: one labelled band per residual chart, saying where the noise came from,
    // its tint seen in the picture (`render` checks it); each exposure labelled
    let bands = v["bands"].as_array().map_or(0, |b| b.len());
    let band_legends = legend_texts(&v, "residual vs ");
    let band_legends: Vec<_> = band_legends
        .iter()
        .filter(|t| t.starts_with("±2 SE of the binned residual (noise measured from "))
        .collect();
    assert!(
        bands >= 1 && band_legends.len() == bands,
        "{bands} bands, legends {band_legends:?}"
    );
    assert!(
        v["bands_seen"].as_u64().unwrap() >= 1,
        "no band wide enough to see its tint"
    );
    for (chart, label) in [
        ("4-phase amplitude", "measured, "),
        ("4-phase amplitude", "model, "),
        ("2-phase depth residual", "2-phase, "),
        ("4-phase depth residual", "4-phase, "),
    ] {
        let shown = legend_texts(&v, chart);
        for e in ["250 µs", "1000 µs"] {
            let want = format!("{label}{e}");
            assert!(
                shown.iter().any(|t| t.starts_with(&want)),
                "{chart}: no legend {want:?} in {shown:?}"
            );
        }
    }
    // each bar shows the score of the condition it is labelled with (compare --json
    // computes the same fit)
    let o = run(&["lab", "compare", &s(rec), "--model", &s(base_p), "--json"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let cmp: Value = serde_json::from_slice(&o.stdout).unwrap();
    let shown = &v["barValues"];
    let structure = cmp["structure"].as_array().unwrap();
    assert_eq!(shown.as_object().unwrap().len(), structure.len());
    for st in structure {
        let (cond, z) = (st["condition"].as_str().unwrap(), st["z"].as_f64().unwrap());
        let bar = &shown[cond];
        let shown_z = bar["value"].as_f64().unwrap();
        assert!(
            (shown_z - z).abs() <= 1e-3 * z.abs().max(1.0),
            "bar labelled {cond} shows {shown_z}, its z is {z}"
        );
    }
    // longer bar ⇔ larger score
    let mut by_z: Vec<(f64, f64)> = shown
        .as_object()
        .unwrap()
        .values()
        .map(|b| (b["value"].as_f64().unwrap(), b["width"].as_f64().unwrap()))
        .collect();
    by_z.sort_by(|a, b| a.0.total_cmp(&b.0));
    assert!(by_z.windows(2).all(|w| w[0].1 <= w[1].1 + 0.5), "{by_z:?}");

    let add = tmp.path().join("add.html");
    let o = run(&[
        "lab",
        "add",
        "vcsel_droop",
        "--model",
        &s(base_p),
        "--data",
        &s(rec),
        "--out",
        &s(&tmp.path().join("m2.toml")),
        "--report",
        &s(&add),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let v = render(
        &chromium,
        "lab-add",
        &std::fs::read_to_string(&add).unwrap(),
    );
    assert!(v["lines"].as_u64().unwrap() >= 2, "{v}");
    let shown = legend_texts(&v, "2-phase depth residual before/after");
    for e in ["250 µs", "1000 µs"] {
        let want = format!("2-phase before, {e}");
        assert!(
            shown.iter().any(|t| t.starts_with(&want)),
            "no legend {want:?} in {shown:?}"
        );
    }
}

#[test]
fn thesis_figures_render_correctly_in_a_browser() {
    let Some(chromium) = tofprox_testkit::require_program("chromium", "chromium") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let o = run(&["sim", "figures", "--out", tmp.path().to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let mut n = 0;
    for e in std::fs::read_dir(tmp.path()).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "svg") {
            let stem = p.file_stem().unwrap().to_string_lossy().into_owned();
            let svg = std::fs::read_to_string(&p).unwrap();
            let v = render(&chromium, &stem, &svg);
            assert_eq!(v["legends"], 1, "{stem}: {v}");
            n += 1;
        }
    }
    assert_eq!(n, 6);
}
