//! `tofprox monitor --depth`: the live view. A status region on top (what is
//! claimed, the latest events with near/far and distance, the colour legend)
//! and the depth preview in its own region below it, on the terminal's
//! alternate screen so the shell's screen comes back unchanged on exit; the
//! events are printed again on the normal screen then. Square pixels: each
//! character cell shows two depth pixels stacked (`▀`, foreground = upper,
//! background = lower), cells being about twice as high as wide. Colours from
//! the one colour map of `tofprox-chart`. Rendering is pure (a string of
//! terminal codes); the caller writes it.

use std::fmt::Write as _;

use tofprox_chart::viridis;
use tofproxd::client::distance_words;
use tofproxd::controller::DISTANCE_BEYOND_RANGE_MM;

/// Enter: alternate screen, cursor hidden, screen cleared.
pub const ENTER: &str = "\x1b[?1049h\x1b[?25l\x1b[2J";
/// Leave: cursor shown, normal screen back.
pub const LEAVE: &str = "\x1b[?25h\x1b[?1049l";

/// The distance line until the first reading arrives.
pub const WAITING: &str = "waiting for the first reading";

/// Events kept in the status region.
const EVENTS: usize = 4;

/// One reading or near/far transition as a line of text: time, NEAR/far, distance in
/// words ([`distance_words`]), state.
pub fn event_line(t_s: f64, near: bool, distance_mm: u32, state: &str) -> String {
    format!(
        "{t_s:8.2} s  {}  {}  state {state}",
        if near { "NEAR" } else { "far " },
        distance_words(distance_mm, near)
    )
}

/// One line of `tofprox monitor --json` (JSON Lines: one object per line). `event` is
/// `"first_reading"` or `"near_changed"`; `distance_mm` is a number only when it is a
/// distance (null for nothing in range, saturated or unknown), `distance` says it in words.
pub fn event_json(
    t_s: f64,
    event: &str,
    near: bool,
    distance_mm: u32,
    state: &str,
    reason: &str,
) -> String {
    let is_distance = distance_mm != 0 && distance_mm != DISTANCE_BEYOND_RANGE_MM;
    serde_json::json!({
        "t_s": (t_s * 1e3).round() / 1e3,
        "event": event,
        "near": near,
        "distance_mm": is_distance.then_some(distance_mm),
        "distance": distance_words(distance_mm, near),
        "state": state,
        "reason": reason,
    })
    .to_string()
}

/// The state of the view.
#[derive(Debug, Clone)]
pub struct LiveView {
    header: String,
    distance: String,
    events: Vec<String>,
    range_mm: u32,
}

impl LiveView {
    /// A view whose header names the thresholds; depth colours span
    /// 0 … `range_mm`.
    pub fn new(near_mm: u32, far_mm: u32, range_mm: u32) -> Self {
        LiveView {
            header: format!(
                "tofprox monitor: near ≤ {near_mm} mm, far ≥ {far_mm} mm (Ctrl-C to stop)"
            ),
            distance: WAITING.to_string(),
            events: Vec::new(),
            range_mm: range_mm.max(1),
        }
    }

    /// The current reading, shown on its own line under the header: `distance_words`, or
    /// [`WAITING`].
    pub fn set_distance(&mut self, words: String) {
        self.distance = words;
    }

    /// Add an event line.
    pub fn push_event(&mut self, line: String) {
        self.events.push(line);
        if self.events.len() > EVENTS {
            self.events.remove(0);
        }
    }

    /// The whole screen for a `term_cols` × `term_rows` terminal with the
    /// latest depth frame (`width` × `height`, mm, 0 = invalid), if any.
    pub fn screen(
        &self,
        frame: Option<(usize, usize, &[u16])>,
        term_cols: usize,
        term_rows: usize,
    ) -> String {
        let mut o = String::from("\x1b[H");
        let line = |o: &mut String, s: &str| {
            let s: String = s.chars().take(term_cols.saturating_sub(1)).collect();
            let _ = write!(o, "{s}\x1b[K\r\n");
        };
        line(&mut o, &self.header);
        line(&mut o, &format!("now: {}", self.distance));
        line(&mut o, "latest events:");
        for k in 0..EVENTS {
            match self.events.get(k) {
                Some(e) => line(&mut o, &format!("  {e}")),
                None if k == 0 && self.events.is_empty() => {
                    line(&mut o, "  (no near/far change yet)")
                }
                None => line(&mut o, ""),
            }
        }
        // legend: the colour ramp with its distances
        let _ = write!(o, "depth  0 m ");
        for k in 0..16 {
            let c = viridis((f64::from(k) + 0.5) / 16.0);
            let _ = write!(o, "\x1b[48;2;{};{};{}m \x1b[0m", c[0], c[1], c[2]);
        }
        let _ = write!(
            o,
            " {:.1} m   black: invalid\x1b[K\r\n",
            f64::from(self.range_mm) / 1000.0
        );
        let used = 4 + EVENTS;
        let Some((w, h, depth)) = frame.filter(|(w, h, d)| *w > 0 && *h > 0 && d.len() >= w * h)
        else {
            line(&mut o, "(waiting for depth frames)");
            o.push_str("\x1b[J");
            return o;
        };
        // square pixels: cols × (2 × rows) samples keep the aspect w:h
        let avail_rows = term_rows.saturating_sub(used + 1).max(1);
        let mut cols = term_cols.saturating_sub(1).clamp(1, 96).min(w);
        let mut rows = (cols * h).div_ceil(2 * w).max(1);
        if rows > avail_rows {
            rows = avail_rows;
            cols = ((2 * rows * w) / h).clamp(1, w);
        }
        let sample = |r: usize, c: usize| -> [u8; 3] {
            let (y, x) = ((r * h) / (2 * rows), (c * w) / cols);
            let d = depth[y.min(h - 1) * w + x.min(w - 1)];
            if d == 0 {
                [0, 0, 0]
            } else {
                viridis(f64::from(d) / f64::from(self.range_mm))
            }
        };
        for r in 0..rows {
            for c in 0..cols {
                let (u, l) = (sample(2 * r, c), sample(2 * r + 1, c));
                let _ = write!(
                    o,
                    "\x1b[38;2;{};{};{}m\x1b[48;2;{};{};{}m▀",
                    u[0], u[1], u[2], l[0], l[1], l[2]
                );
            }
            o.push_str("\x1b[0m\x1b[K\r\n");
        }
        o.push_str("\x1b[J");
        o
    }

    /// The events, for the normal screen after leaving.
    pub fn events(&self) -> &[String] {
        &self.events
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn visible(s: &str) -> String {
        // drop escape sequences
        let mut out = String::new();
        let mut esc = false;
        for ch in s.chars() {
            match (esc, ch) {
                (false, '\x1b') => esc = true,
                (true, c) if c.is_ascii_alphabetic() => esc = false,
                (true, _) => {}
                (false, c) => out.push(c),
            }
        }
        out
    }

    #[test]
    fn status_region_keeps_events_and_legend_above_the_preview() {
        let mut v = LiveView::new(100, 150, 1500);
        v.push_event(event_line(1.0, true, 0, "running"));
        let (w, h) = (224usize, 172usize);
        let depth = vec![800u16; w * h];
        let s = v.screen(Some((w, h, &depth)), 80, 40);
        let lines: Vec<String> = visible(&s).split("\r\n").map(str::to_string).collect();
        assert!(lines[0].starts_with("tofprox monitor: near ≤ 100 mm"));
        assert_eq!(lines[1], "now: waiting for the first reading");
        assert!(lines[3].contains("NEAR  distance saturated"), "{lines:?}");
        assert!(lines[7].contains("0 m") && lines[7].contains("1.5 m"));
        // preview rows follow; the aspect ratio holds: cols / (2 rows) ≈ w / h
        let preview: Vec<&String> = lines.iter().filter(|l| l.contains('▀')).collect();
        let cols = preview[0].chars().filter(|c| *c == '▀').count();
        let ratio = cols as f64 / (2.0 * preview.len() as f64);
        assert!((ratio - w as f64 / h as f64).abs() < 0.1, "{ratio}");
        assert!(preview.len() + 8 < 40);
        // a short terminal shrinks the preview, never the status region
        let s = v.screen(Some((w, h, &depth)), 200, 20);
        let vis = visible(&s);
        assert!(vis.split("\r\n").count() <= 20);
        assert!(vis.contains("NEAR") && vis.contains("black: invalid"));
        // the distance line follows the reading, in words
        v.set_distance(distance_words(DISTANCE_BEYOND_RANGE_MM, false));
        let vis = visible(&v.screen(None, 80, 24));
        assert_eq!(vis.split("\r\n").nth(1), Some("now: nothing in range"));
    }

    #[test]
    fn nothing_in_range_is_said_in_words() {
        let l = event_line(3.5, false, u32::MAX, "running");
        assert!(l.contains("far   nothing in range  state running"), "{l}");
        assert!(!l.contains("4294967295"), "{l}");
    }

    #[test]
    fn json_lines_carry_distances_only_when_they_are_distances() {
        let parse = |s: String| serde_json::from_str::<serde_json::Value>(&s).unwrap();
        let v = parse(event_json(
            1.23456,
            "near_changed",
            true,
            96,
            "running",
            "distance",
        ));
        assert_eq!(v["t_s"], 1.235);
        assert_eq!(v["event"], "near_changed");
        assert_eq!(v["near"], true);
        assert_eq!(v["distance_mm"], 96);
        assert_eq!(v["distance"], "distance 96 mm");
        let v = parse(event_json(
            0.0,
            "first_reading",
            false,
            u32::MAX,
            "running",
            "nothing_in_range",
        ));
        assert!(v["distance_mm"].is_null());
        assert_eq!(v["distance"], "nothing in range");
        let v = parse(event_json(
            0.0,
            "first_reading",
            true,
            0,
            "running",
            "saturated",
        ));
        assert!(v["distance_mm"].is_null());
        assert!(v["distance"].as_str().unwrap().contains("saturated"));
    }

    #[test]
    fn event_lines_say_what_zero_means() {
        assert!(event_line(0.0, true, 0, "x").contains("saturated"));
        assert!(event_line(0.0, false, 0, "x").contains("unknown"));
        assert!(event_line(0.0, false, 812, "x").contains("distance 812 mm"));
    }
}
