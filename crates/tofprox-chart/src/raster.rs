//! Pixel images of maps (the depth PNGs of `tofprox process`): the map scaled
//! up, row/column axes in sensor coordinates and a colour bar with ticks in the
//! value's unit, lettered with a built-in 5×7 font (no font files needed).

use crate::axis::nice_ticks;
use crate::colour::{Rgb, viridis};
use crate::svg::fmt_num;

/// A map to draw as pixels.
#[derive(Debug, Clone, Copy)]
pub struct RasterMap<'a> {
    /// Rows of `values`.
    pub rows: usize,
    /// Columns of `values`.
    pub cols: usize,
    /// Row-major values; non-finite = invalid (black).
    pub values: &'a [f64],
    /// Sensor row/column of the first value.
    pub origin: (usize, usize),
    /// Colour range (low → dark blue, high → yellow).
    pub range: (f64, f64),
    /// Unit printed over the colour bar, e.g. `m`.
    pub unit: &'a str,
}

/// An RGB image, row-major, 3 bytes per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Pixels.
    pub rgb: Vec<u8>,
}

impl Image {
    fn new(width: usize, height: usize) -> Self {
        Image {
            width,
            height,
            rgb: vec![255; width * height * 3],
        }
    }

    /// The colour at (x, y).
    pub fn at(&self, x: usize, y: usize) -> Rgb {
        let o = (y * self.width + x) * 3;
        [self.rgb[o], self.rgb[o + 1], self.rgb[o + 2]]
    }

    fn fill(&mut self, x: usize, y: usize, w: usize, h: usize, c: Rgb) {
        for yy in y..(y + h).min(self.height) {
            for xx in x..(x + w).min(self.width) {
                let o = (yy * self.width + xx) * 3;
                self.rgb[o..o + 3].copy_from_slice(&c);
            }
        }
    }

    fn text(&mut self, x: usize, y: usize, s: &str) {
        const S: usize = 2; // font scale
        for (k, ch) in s.chars().enumerate() {
            let g = glyph(ch);
            for (r, row) in g.iter().enumerate() {
                for (c, b) in row.bytes().enumerate() {
                    if b == b'#' {
                        self.fill(x + k * 6 * S + c * S, y + r * S, S, S, [0, 0, 0]);
                    }
                }
            }
        }
    }
}

/// Width in pixels of `s` in the built-in font.
fn text_w(s: &str) -> usize {
    s.chars().count() * 12
}

const TEXT_H: usize = 14;

/// Draw the map with axes and colour bar.
pub fn annotated(m: &RasterMap<'_>) -> Image {
    let (rows, cols) = (m.rows.max(1), m.cols.max(1));
    let scale = (448 / cols).clamp(1, 16);
    let (mw, mh) = (cols * scale, rows * scale);
    let (x0, y0) = (56usize, 24usize);
    let bar_x = x0 + mw + 24;
    let width = bar_x + 20 + 8 + text_w("00.00") + 12;
    let height = y0 + mh + 8 + TEXT_H + 8 + TEXT_H + 8;
    let mut img = Image::new(width, height);
    let (lo, hi) = m.range;
    let t_of = |v: f64| (v - lo) / (hi - lo).max(f64::MIN_POSITIVE);
    for r in 0..rows {
        for c in 0..cols {
            let v = m.values.get(r * cols + c).copied().unwrap_or(f64::NAN);
            let col = if v.is_finite() {
                viridis(t_of(v))
            } else {
                [0, 0, 0]
            };
            img.fill(x0 + c * scale, y0 + r * scale, scale, scale, col);
        }
    }
    // frame
    let grey = [68, 68, 68];
    img.fill(x0 - 1, y0 - 1, mw + 2, 1, grey);
    img.fill(x0 - 1, y0 + mh, mw + 2, 1, grey);
    img.fill(x0 - 1, y0 - 1, 1, mh + 2, grey);
    img.fill(x0 + mw, y0 - 1, 1, mh + 2, grey);
    // column axis (bottom), row axis (left): ticks at cell centres
    let (ct, _) = nice_ticks(m.origin.1 as f64, (m.origin.1 + cols - 1) as f64, 5);
    for t in ct {
        let px = x0 + ((t as usize - m.origin.1) * scale) + scale / 2;
        img.fill(px, y0 + mh + 1, 1, 5, grey);
        let s = fmt_num(t, 0);
        img.text(px.saturating_sub(text_w(&s) / 2), y0 + mh + 8, &s);
    }
    let (rt, _) = nice_ticks(m.origin.0 as f64, (m.origin.0 + rows - 1) as f64, 5);
    for t in rt {
        let py = y0 + ((t as usize - m.origin.0) * scale) + scale / 2;
        img.fill(x0 - 6, py, 5, 1, grey);
        let s = fmt_num(t, 0);
        img.text(
            (x0 - 8).saturating_sub(text_w(&s)),
            py.saturating_sub(6),
            &s,
        );
    }
    img.text(x0, y0 + mh + 8 + TEXT_H + 8, "col");
    img.text(4, 4, "row");
    // colour bar: high at the top
    for y in 0..mh {
        let t = 1.0 - (y as f64 + 0.5) / mh as f64;
        img.fill(bar_x, y0 + y, 20, 1, viridis(t));
    }
    let (vt, vd) = nice_ticks(lo, hi, 5);
    for v in vt {
        let py = y0 + ((1.0 - t_of(v)) * (mh - 1) as f64).round() as usize;
        img.fill(bar_x + 20, py, 5, 1, grey);
        img.text(bar_x + 28, py.saturating_sub(6), &fmt_num(v, vd));
    }
    img.text(bar_x, 4, m.unit);
    let note = "black: invalid";
    img.text(
        (x0 + mw).saturating_sub(text_w(note)),
        y0 + mh + 8 + TEXT_H + 8,
        note,
    );
    img
}

/// 5×7 glyphs of the characters the maps print.
fn glyph(c: char) -> [&'static str; 7] {
    match c {
        '0' => [
            " ### ", "#   #", "#  ##", "# # #", "##  #", "#   #", " ### ",
        ],
        '1' => [
            "  #  ", " ##  ", "  #  ", "  #  ", "  #  ", "  #  ", " ### ",
        ],
        '2' => [
            " ### ", "#   #", "    #", "   # ", "  #  ", " #   ", "#####",
        ],
        '3' => [
            "#####", "   # ", "  #  ", "   # ", "    #", "#   #", " ### ",
        ],
        '4' => [
            "   # ", "  ## ", " # # ", "#  # ", "#####", "   # ", "   # ",
        ],
        '5' => [
            "#####", "#    ", "#### ", "    #", "    #", "#   #", " ### ",
        ],
        '6' => [
            "  ## ", " #   ", "#    ", "#### ", "#   #", "#   #", " ### ",
        ],
        '7' => [
            "#####", "    #", "   # ", "  #  ", " #   ", " #   ", " #   ",
        ],
        '8' => [
            " ### ", "#   #", "#   #", " ### ", "#   #", "#   #", " ### ",
        ],
        '9' => [
            " ### ", "#   #", "#   #", " ####", "    #", "   # ", " ##  ",
        ],
        '.' => [
            "     ", "     ", "     ", "     ", "     ", " ##  ", " ##  ",
        ],
        '-' => [
            "     ", "     ", "     ", "#####", "     ", "     ", "     ",
        ],
        ':' => [
            "     ", " ##  ", " ##  ", "     ", " ##  ", " ##  ", "     ",
        ],
        'a' => [
            "     ", "     ", " ### ", "    #", " ####", "#   #", " ####",
        ],
        'b' => [
            "#    ", "#    ", "# ## ", "##  #", "#   #", "#   #", "#### ",
        ],
        'c' => [
            "     ", "     ", " ### ", "#    ", "#    ", "#   #", " ### ",
        ],
        'd' => [
            "    #", "    #", " ## #", "#  ##", "#   #", "#   #", " ####",
        ],
        'i' => [
            "  #  ", "     ", " ##  ", "  #  ", "  #  ", "  #  ", " ### ",
        ],
        'k' => [
            "#    ", "#    ", "#  # ", "# #  ", "##   ", "# #  ", "#  # ",
        ],
        'l' => [
            " ##  ", "  #  ", "  #  ", "  #  ", "  #  ", "  #  ", " ### ",
        ],
        'm' => [
            "     ", "     ", "## # ", "# # #", "# # #", "#   #", "#   #",
        ],
        'n' => [
            "     ", "     ", "# ## ", "##  #", "#   #", "#   #", "#   #",
        ],
        'o' => [
            "     ", "     ", " ### ", "#   #", "#   #", "#   #", " ### ",
        ],
        'r' => [
            "     ", "     ", "# ## ", "##  #", "#    ", "#    ", "#    ",
        ],
        'v' => [
            "     ", "     ", "#   #", "#   #", "#   #", " # # ", "  #  ",
        ],
        'w' => [
            "     ", "     ", "#   #", "#   #", "# # #", "# # #", " # # ",
        ],
        _ => ["     "; 7],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_has_colour_bar_axes_and_black_invalid() {
        let mut v: Vec<f64> = (0..16 * 16).map(|i| (i % 16) as f64 / 10.0).collect();
        v[0] = f64::NAN;
        let img = annotated(&RasterMap {
            rows: 16,
            cols: 16,
            values: &v,
            origin: (78, 104),
            range: (0.0, 1.5),
            unit: "m",
        });
        let scale = 16; // 448 px / 16 columns, at most 16 px per pixel
        // invalid cell black, a valid cell coloured, colour bar yellow at top and blue at bottom
        assert_eq!(img.at(56 + 1, 24 + 1), [0, 0, 0]);
        assert_eq!(img.at(56 + 15 * scale + 1, 24 + 1), viridis(1.5 / 1.5));
        let bar_x = 56 + 16 * scale + 24;
        assert_eq!(
            img.at(bar_x + 5, 24),
            viridis(1.0 - 0.5 / (16 * scale) as f64)
        );
        assert_eq!(
            img.at(bar_x + 5, 24 + 16 * scale - 1),
            viridis(0.5 / (16 * scale) as f64)
        );
        // tick labels drawn (black pixels) right of the bar and left of the map
        let black = |x0: usize, x1: usize, y0: usize, y1: usize| {
            (y0..y1).any(|y| (x0..x1).any(|x| img.at(x, y) == [0, 0, 0]))
        };
        assert!(black(bar_x + 28, img.width, 24, 24 + 16 * scale));
        assert!(black(0, 50, 24, 24 + 16 * scale));
        assert!(black(56, 56 + 16 * scale, 24 + 16 * scale + 8, img.height));
    }
}
