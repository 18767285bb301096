//! The one chart component of tofprox: every plot a person looks at — the lab's
//! HTML report, the thesis figures of `tofprox sim figures`, the depth previews
//! of `tofprox process` — is drawn here, so the rules a reader relies on hold
//! everywhere:
//!
//! - a bar chart has exactly one label per bar, on the bar's row ([`bar_chart`]);
//! - line series are joined in x order (never in capture order) and broken at
//!   missing values ([`line_chart`]);
//! - the legend sits below the plot area, never on the data;
//! - series that coincide on the page are drawn dashed and said to coincide in
//!   the legend and a note, so no curve hides another unannounced;
//! - maps carry axes and a colour bar with units ([`heatmap`], [`raster`]).
//!
//! Pure: functions return SVG text or RGB pixels, no I/O. The SVG carries
//! semantic classes (`plot-area`, `series`, `line`, `point`, `legend`,
//! `legend-entry`, `bar`, `bar-label`, `bar-value`, `cell`, `colour-bar`, `note`)
//! and `data-*` attributes so tests — including the headless-browser test of
//! the rendered pages — can check the geometry a person sees.

mod axis;
mod bar;
mod colour;
mod line;
mod map;
pub mod raster;
mod svg;

pub use axis::nice_ticks;
pub use bar::{Bar, BarChart, bar_chart};
pub use colour::{PALETTE, Rgb, viridis};
pub use line::{LineChart, Series, SeriesStyle, coincident_with, line_chart, mean_per_x};
pub use map::{Heatmap, heatmap};
pub use svg::escape;
