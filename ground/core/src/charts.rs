//! Charts of the learning stack (thesis chapter 5): learning curves and losses, histograms of
//! Monte Carlo results (alone or as a grid of panels), and flown trajectories in the orbit
//! plane.
//!
//! Same conventions as [`crate::plot`]: SVG only (text stays SVG `<text>`, so no font file or
//! system library is needed), files written atomically, typed [`PlotError`]s. Non-finite input
//! values are skipped, not refused; a chart left with nothing to draw is an error, and then no
//! file is written.

use std::path::Path;

use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use shared::orbit::OrbitShape;

use crate::io::atomic_write;
pub use crate::plot::PlotError;
use crate::plot::{
    check_svg_path, draw_orbit_plane, orbit_points, render_svg, Area, Legend, Mark, OrbitPlaneLayer, LABEL_SIZE,
    LEGEND_SIZE, THRUST_COLOR, THRUST_THRESHOLD, TICK_SIZE, TITLE_SIZE,
};

/// Line colours, one per series (cycled): the matplotlib "tab10" palette.
pub const SERIES_COLORS: [RGBColor; 10] = [
    RGBColor(0x1F, 0x77, 0xB4),
    RGBColor(0xFF, 0x7F, 0x0E),
    RGBColor(0x2C, 0xA0, 0x2C),
    RGBColor(0xD6, 0x27, 0x28),
    RGBColor(0x94, 0x67, 0xBD),
    RGBColor(0x8C, 0x56, 0x4B),
    RGBColor(0xE3, 0x77, 0xC2),
    RGBColor(0x7F, 0x7F, 0x7F),
    RGBColor(0xBC, 0xBD, 0x22),
    RGBColor(0x17, 0xBE, 0xCF),
];
/// Opacity of a series' shaded band.
pub const BAND_OPACITY: f64 = 0.2;
/// Histogram bars.
pub const BAR_COLOR: RGBColor = RGBColor(0x4C, 0x72, 0xB0);
/// Histogram marker lines, one per marker (cycled).
pub const MARKER_COLORS: [RGBColor; 4] = [
    RGBColor(0xD6, 0x27, 0x28),
    RGBColor(0x40, 0x40, 0x40),
    RGBColor(0x2C, 0xA0, 0x2C),
    RGBColor(0x94, 0x67, 0xBD),
];

const LINE_SIZE: (u32, u32) = (1300, 750);
const LINE_LEGEND_WIDTH: u32 = 300;
const HISTOGRAM_SIZE: (u32, u32) = (1100, 700);
/// One panel of a histogram grid; the grid adds a title band on top.
const PANEL_SIZE: (u32, u32) = (800, 560);
const GRID_TITLE_HEIGHT: u32 = 60;
const PANEL_TITLE_SIZE: f64 = 24.0;
const FLOWN_SIZE: (u32, u32) = (1300, 960);
const FLOWN_LEGEND_WIDTH: u32 = 360;

/// One line of a line chart; `band` = optional (x, low, high) shaded around it (e.g. mean +- std).
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend entry.
    pub name: String,
    /// (x, y) points, drawn in order.
    pub points: Vec<(f64, f64)>,
    /// Shaded band: (x, low, high) per point.
    pub band: Option<Vec<(f64, f64, f64)>>,
}

/// A flown trajectory in the orbit plane (AU) with its initial and target orbits.
#[derive(Debug, Clone, PartialEq)]
pub struct FlownPath {
    /// Legend entry.
    pub label: String,
    /// Departure orbit (AU, rad), drawn as an ellipse.
    pub initial: OrbitShape,
    /// Target orbit (AU, rad), drawn as an ellipse.
    pub target: OrbitShape,
    /// (x, y, throttle of the step ending there).
    pub points: Vec<(f64, f64, f64)>,
}

/// One panel of a histogram grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    /// Panel title.
    pub title: String,
    /// x-axis label.
    pub x_label: String,
    /// Values to bin (non-finite ones skipped).
    pub values: Vec<f64>,
    /// Vertical marker lines: (label, x).
    pub markers: Vec<(String, f64)>,
}

/// Line chart (learning curves against environment steps or updates, losses): one line per
/// series in [`SERIES_COLORS`], its band (if any) shaded in the same colour, a legend of the
/// series names to the right. With `log_y` the y axis is logarithmic and points and band
/// entries with a value <= 0 are skipped (as are non-finite ones in any case).
///
/// Errors: a path not ending in `.svg`, no point left to draw in any series, or a failed write
/// (the file at `path` is then unchanged).
pub fn line_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    log_y: bool,
) -> Result<(), PlotError> {
    check_svg_path(path)?;
    let lines: Vec<Line> = series.iter().map(|s| Line::new(s, log_y)).collect();
    let (mut xs, mut ys) = (Extent::default(), Extent::default());
    for line in &lines {
        for &(x, y) in &line.points {
            xs.add(x);
            ys.add(y);
        }
        for &(x, low, high) in &line.band {
            xs.add(x);
            ys.add(low);
            ys.add(high);
        }
    }
    let (Some(x_range), Some(y_range)) = (xs.padded(false), ys.padded(log_y)) else {
        return Err(PlotError::NothingToDraw("line chart"));
    };
    let svg = render_svg(LINE_SIZE, |root| {
        let body = root.titled(title, ("sans-serif", TITLE_SIZE))?;
        let (width, _) = body.dim_in_pixel();
        let (plot_area, legend_area) = body.split_horizontally(width.saturating_sub(LINE_LEGEND_WIDTH));
        let mut builder = ChartBuilder::on(&plot_area);
        builder.margin(15).x_label_area_size(60).y_label_area_size(100);
        let (x0, x1) = x_range;
        let (y0, y1) = y_range;
        if log_y {
            let mut chart = builder.build_cartesian_2d(x0..x1, (y0..y1).log_scale())?;
            draw_lines(&mut chart, x_label, y_label, &lines)?;
        } else {
            let mut chart = builder.build_cartesian_2d(x0..x1, y0..y1)?;
            draw_lines(&mut chart, x_label, y_label, &lines)?;
        }
        let mut legend = Legend::new(&legend_area);
        for (i, (s, line)) in series.iter().zip(&lines).enumerate() {
            let text = if line.points.is_empty() {
                format!("{} (no data)", s.name)
            } else {
                s.name.clone()
            };
            legend.entry(Mark::Line(series_color(i), 3, false), &text)?;
        }
        Ok(())
    })?;
    atomic_write(path, svg.as_bytes()).map_err(PlotError::Io)
}

/// Histogram of the finite `values` in `bins` equal bins over [min, max] of those values (or
/// over `range` if given, values outside it left out; see [`bin_counts`]), with a vertical line
/// per marker (label, x) in [`MARKER_COLORS`], e.g. a target of 0.01 AU or the median. The x
/// axis also spans the finite markers; the number of values counted is noted top right.
///
/// Errors: a path not ending in `.svg`, zero bins, a `range` that is not finite and increasing,
/// no value in the bins, or a failed write (the file at `path` is then unchanged).
pub fn histogram(
    path: &Path,
    title: &str,
    x_label: &str,
    values: &[f64],
    bins: usize,
    range: Option<(f64, f64)>,
    markers: &[(String, f64)],
) -> Result<(), PlotError> {
    check_svg_path(path)?;
    if bins == 0 {
        return Err(PlotError::InvalidBins(bins));
    }
    if let Some((low, high)) = range {
        if !(low.is_finite() && high.is_finite() && low < high) {
            return Err(PlotError::InvalidRange { low, high });
        }
    }
    let hist = Hist::new(values, bins, range).ok_or(PlotError::NothingToDraw("histogram"))?;
    let svg = render_svg(HISTOGRAM_SIZE, |root| {
        let body = root.titled(title, ("sans-serif", TITLE_SIZE))?;
        draw_histogram(&body, x_label, &hist, markers)
    })?;
    atomic_write(path, svg.as_bytes()).map_err(PlotError::Io)
}

/// Flown trajectories in the orbit plane (AU), all on one figure with equal axis scaling: the
/// Sun at the origin, each path's initial orbit (dashed) and target orbit (solid) in the path's
/// colour (as in [`crate::plot::plot_trajectories`]), the path itself in [`THRUST_COLOR`] where
/// the step ending at a point has throttle > [`THRUST_THRESHOLD`] and
/// [`COAST_COLOR`](crate::plot::COAST_COLOR) elsewhere, a circle at its first point and a
/// triangle at its last. Points with a non-finite coordinate or throttle are skipped.
///
/// Errors: a path not ending in `.svg`, an orbit that is not an ellipse, no finite point in any
/// path, or a failed write (the file at `path` is then unchanged).
pub fn flown_trajectories(path: &Path, title: &str, paths: &[FlownPath]) -> Result<(), PlotError> {
    check_svg_path(path)?;
    let mut layers = Vec::with_capacity(paths.len());
    for (record, p) in paths.iter().enumerate() {
        for (shape, which) in [(&p.initial, "initial"), (&p.target, "target")] {
            shape
                .validate()
                .map_err(|_| PlotError::InvalidOrbit { record, which })?;
        }
        layers.push(flown_layer(p));
    }
    if layers.iter().all(|l| l.start.is_none()) {
        return Err(PlotError::NothingToDraw("flown trajectories"));
    }
    let svg = render_svg(FLOWN_SIZE, |root| {
        draw_orbit_plane(root, title, FLOWN_LEGEND_WIDTH, &layers)
    })?;
    atomic_write(path, svg.as_bytes()).map_err(PlotError::Io)
}

/// A grid of histogram panels in one SVG (thesis Fig. 5.6: reward, final mass, terminal dr,
/// terminal dv), each drawn like [`histogram`] over [min, max] of its finite values with
/// `bins` bins; up to 3 panels side by side, more on a near-square grid. A panel without a
/// finite value says so.
///
/// Errors: a path not ending in `.svg`, zero bins, no finite value in any panel, or a failed
/// write (the file at `path` is then unchanged).
pub fn histogram_grid(path: &Path, title: &str, panels: &[Panel], bins: usize) -> Result<(), PlotError> {
    check_svg_path(path)?;
    if bins == 0 {
        return Err(PlotError::InvalidBins(bins));
    }
    let hists: Vec<Option<Hist>> = panels.iter().map(|p| Hist::new(&p.values, bins, None)).collect();
    if hists.iter().all(Option::is_none) {
        return Err(PlotError::NothingToDraw("histogram grid"));
    }
    let (rows, cols) = grid_shape(panels.len());
    let size = (
        PANEL_SIZE.0 * cols as u32,
        PANEL_SIZE.1 * rows as u32 + GRID_TITLE_HEIGHT,
    );
    let svg = render_svg(size, |root| {
        let body = root.titled(title, ("sans-serif", TITLE_SIZE))?;
        for ((cell, panel), hist) in body.split_evenly((rows, cols)).iter().zip(panels).zip(&hists) {
            let cell = cell.titled(&panel.title, ("sans-serif", PANEL_TITLE_SIZE))?;
            match hist {
                Some(hist) => draw_histogram(&cell, &panel.x_label, hist, &panel.markers)?,
                None => {
                    let (w, h) = cell.dim_in_pixel();
                    let style = TextStyle::from(("sans-serif", LABEL_SIZE).into_font())
                        .color(&BLACK)
                        .pos(Pos::new(HPos::Center, VPos::Center));
                    cell.draw(&Text::new("no finite values", (w as i32 / 2, h as i32 / 2), style))?;
                }
            }
        }
        Ok(())
    })?;
    atomic_write(path, svg.as_bytes()).map_err(PlotError::Io)
}

/// Counts of the finite `values` in `bins` equal bins over `range`, or over [min, max] of the
/// finite values when `range` is `None` (widened to [v - 1/2, v + 1/2] when they are all one
/// value v). Bins are half-open [lo, hi) except the last, which also takes values exactly at
/// the upper edge; values outside the range are left out. Zero bins, no finite value (with
/// `range` `None`) or a range that is not finite and increasing give all-zero counts.
pub fn bin_counts(values: &[f64], bins: usize, range: Option<(f64, f64)>) -> Vec<usize> {
    let mut counts = vec![0; bins];
    if bins == 0 {
        return counts;
    }
    let Some((low, high)) = bin_range(values, range) else {
        return counts;
    };
    for &v in values {
        if v.is_finite() && (low..=high).contains(&v) {
            let k = ((v - low) / (high - low) * bins as f64).floor() as usize;
            counts[k.min(bins - 1)] += 1;
        }
    }
    counts
}

/// The interval binned by [`bin_counts`], if any.
fn bin_range(values: &[f64], range: Option<(f64, f64)>) -> Option<(f64, f64)> {
    match range {
        Some((low, high)) => (low.is_finite() && high.is_finite() && low < high).then_some((low, high)),
        None => {
            let mut ext = Extent::default();
            values.iter().for_each(|&v| ext.add(v));
            let (low, high) = ext.bounds()?;
            Some(if low < high {
                (low, high)
            } else {
                (low - 0.5, high + 0.5)
            })
        }
    }
}

/// Rows and columns of a grid of `n` panels: one row up to 3, then a near-square grid.
fn grid_shape(n: usize) -> (usize, usize) {
    let cols = if n <= 3 {
        n.max(1)
    } else {
        (n as f64).sqrt().ceil() as usize
    };
    (n.div_ceil(cols).max(1), cols)
}

fn series_color(i: usize) -> RGBColor {
    SERIES_COLORS[i % SERIES_COLORS.len()]
}

/// Tick label: plain with up to 4 decimals, scientific when very large or small.
fn tick_label(v: f64) -> String {
    let trim = |s: String| {
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    };
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        let s = format!("{v:.2e}");
        let (mantissa, exponent) = s.split_once('e').unwrap_or((&s, "0"));
        format!("{}e{exponent}", trim(mantissa.to_string()))
    } else {
        let s = trim(format!("{v:.4}"));
        if s == "-0" {
            "0".to_string()
        } else {
            s
        }
    }
}

/// The smallest and largest finite value added.
#[derive(Default)]
struct Extent(Option<(f64, f64)>);

impl Extent {
    fn add(&mut self, v: f64) {
        if v.is_finite() {
            self.0 = Some(self.0.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v))));
        }
    }

    fn bounds(&self) -> Option<(f64, f64)> {
        self.0
    }

    /// An axis range holding the extent with a 5 % margin (in log space if `log`, for positive
    /// values); a single value gets a range around it.
    fn padded(&self, log: bool) -> Option<(f64, f64)> {
        let (lo, hi) = self.0?;
        if log {
            let (a, b) = (lo.log10(), hi.log10());
            let pad = if b > a { 0.05 * (b - a) } else { 0.5 };
            return Some((10f64.powf(a - pad), 10f64.powf(b + pad)));
        }
        if hi > lo {
            let pad = 0.05 * (hi - lo);
            Some((lo - pad, hi + pad))
        } else {
            let pad = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
            Some((lo - pad, hi + pad))
        }
    }
}

/// A series with the points and band entries it can draw.
struct Line {
    points: Vec<(f64, f64)>,
    band: Vec<(f64, f64, f64)>,
}

impl Line {
    fn new(series: &Series, log_y: bool) -> Self {
        let ok = |y: f64| y.is_finite() && (!log_y || y > 0.0);
        Self {
            points: series
                .points
                .iter()
                .copied()
                .filter(|&(x, y)| x.is_finite() && ok(y))
                .collect(),
            band: series
                .band
                .iter()
                .flatten()
                .copied()
                .filter(|&(x, low, high)| x.is_finite() && ok(low) && ok(high))
                .collect(),
        }
    }
}

type LineChart<'a, 'b, Y> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, Y>>;

/// Mesh, bands, then lines (so no band hides a line).
fn draw_lines<Y>(
    chart: &mut LineChart<'_, '_, Y>,
    x_label: &str,
    y_label: &str,
    lines: &[Line],
) -> Result<(), PlotError>
where
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .axis_desc_style(("sans-serif", LABEL_SIZE))
        .label_style(("sans-serif", TICK_SIZE))
        .x_label_formatter(&|v| tick_label(*v))
        .y_label_formatter(&|v| tick_label(*v))
        .light_line_style(RGBColor(0xEE, 0xEE, 0xEE))
        .bold_line_style(RGBColor(0xD0, 0xD0, 0xD0))
        .draw()?;
    for (i, line) in lines.iter().enumerate() {
        if line.band.len() >= 2 {
            let outline: Vec<(f64, f64)> = (line.band.iter().map(|&(x, _, high)| (x, high)))
                .chain(line.band.iter().rev().map(|&(x, low, _)| (x, low)))
                .collect();
            chart.draw_series([Polygon::new(outline, series_color(i).mix(BAND_OPACITY).filled())])?;
        }
    }
    for (i, line) in lines.iter().enumerate() {
        if !line.points.is_empty() {
            chart.draw_series(LineSeries::new(
                line.points.iter().copied(),
                series_color(i).stroke_width(2),
            ))?;
        }
    }
    Ok(())
}

/// A histogram ready to draw: the binned interval and the counts.
struct Hist {
    range: (f64, f64),
    counts: Vec<usize>,
}

impl Hist {
    /// `None` when no value falls in a bin.
    fn new(values: &[f64], bins: usize, range: Option<(f64, f64)>) -> Option<Self> {
        let counts = bin_counts(values, bins, range);
        if counts.iter().sum::<usize>() == 0 {
            return None;
        }
        Some(Self {
            range: bin_range(values, range)?,
            counts,
        })
    }

    /// Left and right edge of bin `k`.
    fn edges(&self, k: usize) -> (f64, f64) {
        let (lo, hi) = self.range;
        let w = (hi - lo) / self.counts.len() as f64;
        (
            lo + w * k as f64,
            if k + 1 == self.counts.len() {
                hi
            } else {
                lo + w * (k + 1) as f64
            },
        )
    }
}

/// One histogram on `area`: a bar per bin (empty bins too, at zero height) in [`BAR_COLOR`],
/// then the marker lines with their labels, stacked from the top.
fn draw_histogram(area: &Area<'_>, x_label: &str, hist: &Hist, markers: &[(String, f64)]) -> Result<(), PlotError> {
    let markers: Vec<&(String, f64)> = markers.iter().filter(|m| m.1.is_finite()).collect();
    let mut xs = Extent::default();
    xs.add(hist.range.0);
    xs.add(hist.range.1);
    markers.iter().for_each(|m| xs.add(m.1));
    let (x0, x1) = xs.padded(false).unwrap_or(hist.range);
    let max_count = hist.counts.iter().copied().max().unwrap_or(0) as u32;
    let top = (f64::from(max_count) * 1.15).ceil().max(1.0) as u32;
    let mut chart = ChartBuilder::on(area)
        .margin(15)
        .x_label_area_size(60)
        .y_label_area_size(80)
        .build_cartesian_2d(x0..x1, 0u32..top)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_desc(x_label)
        .y_desc("count")
        .axis_desc_style(("sans-serif", LABEL_SIZE))
        .label_style(("sans-serif", TICK_SIZE))
        .x_label_formatter(&|v| tick_label(*v))
        .light_line_style(RGBColor(0xEE, 0xEE, 0xEE))
        .bold_line_style(RGBColor(0xD0, 0xD0, 0xD0))
        .draw()?;
    chart.draw_series(hist.counts.iter().enumerate().map(|(k, &c)| {
        let (a, b) = hist.edges(k);
        let mut bar = Rectangle::new([(a, 0), (b, c as u32)], BAR_COLOR.filled());
        bar.set_margin(0, 0, 1, 1);
        bar
    }))?;
    for (i, (label, x)) in markers.iter().enumerate() {
        let color = MARKER_COLORS[i % MARKER_COLORS.len()];
        chart.draw_series(LineSeries::new([(*x, 0), (*x, top)], color.stroke_width(2)))?;
        let style = TextStyle::from(("sans-serif", LEGEND_SIZE).into_font())
            .color(&color)
            .pos(Pos::new(HPos::Left, VPos::Top));
        let y = top.saturating_sub((top as f64 * (0.02 + 0.07 * i as f64)).round() as u32);
        chart.draw_series([Text::new(format!(" {label} = {}", tick_label(*x)), (*x, y), style)])?;
    }
    let n: usize = hist.counts.iter().sum();
    let style = TextStyle::from(("sans-serif", LEGEND_SIZE).into_font())
        .color(&BLACK)
        .pos(Pos::new(HPos::Right, VPos::Top));
    chart.draw_series([Text::new(format!("n = {n} "), (x1, top), style)])?;
    Ok(())
}

/// A flown path as an orbit-plane layer (non-finite points dropped; orbits must be valid).
fn flown_layer(path: &FlownPath) -> OrbitPlaneLayer {
    let points: Vec<(f64, f64, f64)> = path
        .points
        .iter()
        .copied()
        .filter(|&(x, y, u)| x.is_finite() && y.is_finite() && u.is_finite())
        .collect();
    let notes = if points.is_empty() {
        vec![("no finite point".to_string(), THRUST_COLOR)]
    } else {
        Vec::new()
    };
    OrbitPlaneLayer {
        initial: orbit_points(&path.initial),
        target: orbit_points(&path.target),
        runs: throttle_runs(&points),
        start: points.first().map(|p| (p.0, p.1)),
        end: points.last().map(|p| (p.0, p.1)),
        label: path.label.clone(),
        notes,
    }
}

/// Splits the path into maximal runs of segments that thrust (throttle of the step ending at
/// the segment's end above [`THRUST_THRESHOLD`]) or coast; consecutive runs share their joining
/// point.
fn throttle_runs(points: &[(f64, f64, f64)]) -> Vec<(bool, Vec<(f64, f64)>)> {
    let mut runs: Vec<(bool, Vec<(f64, f64)>)> = Vec::new();
    for w in points.windows(2) {
        let thrusting = w[1].2 > THRUST_THRESHOLD;
        let (a, b) = ((w[0].0, w[0].1), (w[1].0, w[1].1));
        match runs.last_mut() {
            Some((t, run)) if *t == thrusting => run.push(b),
            _ => runs.push((thrusting, vec![a, b])),
        }
    }
    runs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plot::{record_color, COAST_COLOR, SUN_COLOR};
    use std::path::PathBuf;

    fn out_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("lowthrust-charts-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn hex(c: RGBColor) -> String {
        format!("#{:02X}{:02X}{:02X}", c.0, c.1, c.2)
    }

    /// A parsed SVG element: tag name, attributes, text.
    struct El {
        name: String,
        attrs: Vec<(String, String)>,
        text: String,
    }

    impl El {
        fn attr(&self, key: &str) -> &str {
            self.attrs
                .iter()
                .find(|(k, _)| k == key)
                .map_or("", |(_, v)| v.as_str())
        }

        fn num(&self, key: &str) -> f64 {
            self.attr(key).parse().unwrap()
        }

        fn points(&self) -> Vec<(f64, f64)> {
            self.attr("points")
                .split_whitespace()
                .map(|p| {
                    let (x, y) = p.split_once(',').unwrap();
                    (x.parse().unwrap(), y.parse().unwrap())
                })
                .collect()
        }
    }

    /// Reads the file and parses it as XML with an `<svg>` root; every element in document order.
    fn read_svg(path: &Path) -> Vec<El> {
        let doc = std::fs::read_to_string(path).unwrap();
        let xml = roxmltree::Document::parse(&doc).expect("well-formed XML");
        assert_eq!(xml.root_element().tag_name().name(), "svg");
        xml.descendants()
            .filter(|n| n.is_element())
            .map(|n| El {
                name: n.tag_name().name().to_string(),
                attrs: n
                    .attributes()
                    .map(|a| (a.name().to_string(), a.value().to_string()))
                    .collect(),
                text: n.text().unwrap_or("").trim().to_string(),
            })
            .collect()
    }

    fn with<'a>(els: &'a [El], name: &str, key: &str, color: RGBColor) -> Vec<&'a El> {
        els.iter()
            .filter(|e| e.name == name && e.attr(key) == hex(color))
            .collect()
    }

    fn texts(els: &[El]) -> Vec<&str> {
        els.iter()
            .filter(|e| e.name == "text")
            .map(|e| e.text.as_str())
            .collect()
    }

    /// Polylines of a colour entirely left of `x_max` (the chart, not the legend).
    fn chart_lines(els: &[El], color: RGBColor, x_max: f64) -> Vec<&El> {
        with(els, "polyline", "stroke", color)
            .into_iter()
            .filter(|e| e.points().iter().all(|p| p.0 < x_max))
            .collect()
    }

    const LINE_CHART_WIDTH: f64 = (LINE_SIZE.0 - LINE_LEGEND_WIDTH) as f64;
    const FLOWN_CHART_WIDTH: f64 = (FLOWN_SIZE.0 - FLOWN_LEGEND_WIDTH) as f64;

    #[test]
    fn bin_counts_match_a_hand_count() {
        let v: Vec<f64> = (0..=10).map(f64::from).collect();
        // Edges 0, 2, 4, 6, 8, 10: [0, 2) [2, 4) [4, 6) [6, 8) [8, 10], 10 into the last bin.
        assert_eq!(bin_counts(&v, 5, None), [2, 2, 2, 2, 3]);
        let mut dirty = v.clone();
        dirty.extend([f64::NAN, f64::INFINITY, f64::NEG_INFINITY]);
        assert_eq!(bin_counts(&dirty, 5, None), [2, 2, 2, 2, 3]);
        // Over [0, 5]: 0 | 1 | 2 | 3 | 4 and 5 (the upper edge); 6..10 left out.
        assert_eq!(bin_counts(&dirty, 5, Some((0.0, 5.0))), [1, 1, 1, 1, 2]);
        // Over [0.5, 2.5] in 2 bins: [0.5, 1.5) holds 1, [1.5, 2.5] holds 2.
        assert_eq!(bin_counts(&v, 2, Some((0.5, 2.5))), [1, 1]);
        assert_eq!(bin_counts(&[-1.0, -0.25, 0.0, 0.5], 3, Some((-1.0, 0.5))), [1, 1, 2]);
        // One value: the range is widened to [v - 1/2, v + 1/2] and v lands in the middle bin.
        assert_eq!(bin_counts(&[3.0; 4], 3, None), [0, 4, 0]);
        assert_eq!(bin_counts(&[3.0; 4], 4, None), [0, 0, 4, 0]);
        // Nothing to count.
        assert_eq!(bin_counts(&v, 0, None), Vec::<usize>::new());
        assert_eq!(bin_counts(&[f64::NAN], 3, None), [0, 0, 0]);
        assert_eq!(bin_counts(&v, 2, Some((1.0, 1.0))), [0, 0]);
        assert_eq!(bin_counts(&v, 2, Some((0.0, f64::NAN))), [0, 0]);
    }

    #[test]
    fn bin_counts_add_up_to_the_finite_values() {
        let mut x = 12345u64;
        let mut values: Vec<f64> = (0..1000)
            .map(|_| {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (x >> 11) as f64 / (1u64 << 53) as f64 * 7.0 - 3.0
            })
            .collect();
        values[17] = f64::NAN;
        values[400] = f64::INFINITY;
        for bins in [1, 2, 7, 50, 1000] {
            assert_eq!(bin_counts(&values, bins, None).iter().sum::<usize>(), 998);
        }
        let inside = values.iter().filter(|v| (-1.0..=1.0).contains(*v)).count();
        assert_eq!(bin_counts(&values, 9, Some((-1.0, 1.0))).iter().sum::<usize>(), inside);
    }

    #[test]
    fn histogram_has_one_bar_per_bin_sized_by_its_count() {
        let dir = out_dir("histogram");
        let path = dir.join("hist.svg");
        let mut values: Vec<f64> = (0..200).map(|k| (f64::from(k) * 0.37).sin().powi(2) * 0.05).collect();
        values.extend([f64::NAN, f64::INFINITY]);
        let markers = [
            ("target".to_string(), 0.01),
            ("median".to_string(), 0.02),
            ("bad".to_string(), f64::NAN),
        ];
        histogram(&path, "Terminal dr", "dr [AU]", &values, 12, None, &markers).unwrap();
        let els = read_svg(&path);

        let counts = bin_counts(&values, 12, None);
        assert_eq!(counts.iter().sum::<usize>(), 200);
        let mut bars = with(&els, "rect", "fill", BAR_COLOR);
        assert_eq!(bars.len(), 12, "one bar per bin, empty bins too");
        bars.sort_by(|a, b| a.num("x").total_cmp(&b.num("x")));
        let c_max = *counts.iter().max().unwrap() as f64;
        let h_max = bars.iter().map(|b| b.num("height")).fold(0.0, f64::max);
        for (bar, &c) in bars.iter().zip(&counts) {
            let expected = c as f64 * h_max / c_max;
            assert!(
                (bar.num("height") - expected).abs() <= 1.0,
                "{} vs {expected}",
                bar.num("height")
            );
        }
        // All bars stand on the same baseline.
        let base: Vec<f64> = bars.iter().map(|b| b.num("y") + b.num("height")).collect();
        assert!(base.iter().all(|&y| (y - base[0]).abs() <= 1.0), "{base:?}");

        assert_eq!(with(&els, "polyline", "stroke", MARKER_COLORS[0]).len(), 1);
        assert_eq!(with(&els, "polyline", "stroke", MARKER_COLORS[1]).len(), 1);
        assert_eq!(
            with(&els, "polyline", "stroke", MARKER_COLORS[2]).len(),
            0,
            "NaN marker skipped"
        );
        let t = texts(&els);
        assert!(t.contains(&"Terminal dr") && t.contains(&"dr [AU]"), "{t:?}");
        assert!(t.contains(&"target = 0.01") && t.contains(&"median = 0.02"), "{t:?}");
        assert!(t.contains(&"n = 200"), "{t:?}");
    }

    #[test]
    fn histogram_with_a_range_counts_only_inside_it() {
        let dir = out_dir("histogram-range");
        let path = dir.join("hist.svg");
        let values = [0.0, 0.5, 1.0, 1.5, 2.0, 9.0, -3.0];
        histogram(&path, "r", "x", &values, 4, Some((0.0, 2.0)), &[]).unwrap();
        let els = read_svg(&path);
        assert_eq!(with(&els, "rect", "fill", BAR_COLOR).len(), 4);
        assert!(texts(&els).contains(&"n = 5"));
    }

    fn series(name: &str, points: Vec<(f64, f64)>, band: Option<Vec<(f64, f64, f64)>>) -> Series {
        Series {
            name: name.to_string(),
            points,
            band,
        }
    }

    #[test]
    fn line_chart_draws_each_series_once_with_its_band() {
        let dir = out_dir("line");
        let path = dir.join("curves.svg");
        let curve =
            |s: f64| -> Vec<(f64, f64)> { (0..50).map(|k| (1e4 * f64::from(k), s * f64::from(k).sqrt())).collect() };
        let mut gappy = curve(2.0);
        gappy[3].1 = f64::NAN;
        gappy[10].0 = f64::INFINITY;
        let band: Vec<(f64, f64, f64)> = curve(1.0).iter().map(|&(x, y)| (x, y - 0.5, y + 0.5)).collect();
        let all = [
            series("SAC", curve(1.0), Some(band)),
            series("SAC noisy", gappy, None),
            series("empty", vec![(f64::NAN, 1.0)], None),
            series("baseline", vec![(0.0, 3.0), (4.9e5, 3.0)], None),
        ];
        line_chart(&path, "Learning curve", "environment steps", "return", &all, false).unwrap();
        let els = read_svg(&path);

        let lines: Vec<usize> = (0..4)
            .map(|i| chart_lines(&els, SERIES_COLORS[i], LINE_CHART_WIDTH).len())
            .collect();
        assert_eq!(lines, [1, 1, 0, 1]);
        let noisy = &chart_lines(&els, SERIES_COLORS[1], LINE_CHART_WIDTH)[0];
        assert_eq!(noisy.points().len(), 48, "two non-finite points skipped");
        // Legend: one swatch per series, right of the chart.
        for color in &SERIES_COLORS[..4] {
            assert_eq!(
                with(&els, "polyline", "stroke", *color).len() - chart_lines(&els, *color, LINE_CHART_WIDTH).len(),
                1
            );
        }
        let bands = with(&els, "polygon", "fill", SERIES_COLORS[0]);
        assert_eq!(bands.len(), 1);
        assert_eq!(bands[0].points().len(), 100);
        assert_eq!(els.iter().filter(|e| e.name == "polygon").count(), 1);
        let t = texts(&els);
        for s in [
            "Learning curve",
            "environment steps",
            "return",
            "SAC",
            "SAC noisy",
            "empty (no data)",
            "baseline",
        ] {
            assert!(t.contains(&s), "{s} missing from {t:?}");
        }
        // The band lies around its line: at every x the line is between its edges (pixel y grows down).
        let line = chart_lines(&els, SERIES_COLORS[0], LINE_CHART_WIDTH)[0].points();
        let edge = bands[0].points();
        for (k, p) in line.iter().enumerate() {
            let (high, low) = (edge[k], edge[edge.len() - 1 - k]);
            assert!(high.1 <= p.1 && p.1 <= low.1, "{high:?} {p:?} {low:?}");
        }
    }

    #[test]
    fn log_scale_skips_values_that_are_not_positive() {
        let dir = out_dir("line-log");
        let path = dir.join("loss.svg");
        let loss: Vec<(f64, f64)> = (0..40)
            .map(|k| (f64::from(k), 10f64.powf(-0.1 * f64::from(k))))
            .collect();
        let mut with_zeros = loss.clone();
        with_zeros[5].1 = 0.0;
        with_zeros[6].1 = -1.0;
        line_chart(
            &path,
            "Critic loss",
            "update",
            "loss",
            &[series("q1", with_zeros, None)],
            true,
        )
        .unwrap();
        let els = read_svg(&path);
        let line = chart_lines(&els, SERIES_COLORS[0], LINE_CHART_WIDTH);
        assert_eq!(line.len(), 1);
        let pts = line[0].points();
        assert_eq!(pts.len(), 38);
        // A straight line in log scale: pixel y steps by equal amounts (decades are evenly spaced).
        let steps: Vec<f64> = pts[8..].windows(2).map(|w| w[1].1 - w[0].1).collect();
        assert!(steps.iter().all(|s| (s - steps[0]).abs() <= 1.0), "{steps:?}");

        let bad = dir.join("nothing.svg");
        let err = line_chart(
            &bad,
            "t",
            "x",
            "y",
            &[series("z", vec![(0.0, 0.0), (1.0, -2.0)], None)],
            true,
        );
        assert!(matches!(err, Err(PlotError::NothingToDraw(_))));
        assert!(!bad.exists());
    }

    fn circle(a: f64) -> OrbitShape {
        OrbitShape { a, e: 0.0, omega: 0.0 }
    }

    #[test]
    fn flown_trajectories_colour_each_run_by_throttle() {
        let dir = out_dir("flown");
        let path = dir.join("flown.svg");
        // A spiral from 1 to 1.5 AU; throttle 1 on points 1..=10 and 31..=40, else 0: segments
        // thrust, coast, thrust. Point 20 is NaN (skipped, the coast run goes on past it).
        let spiral = |n: usize, u: &dyn Fn(usize) -> f64| -> Vec<(f64, f64, f64)> {
            (0..n)
                .map(|k| {
                    let s = k as f64 / (n - 1) as f64;
                    let (r, th) = (1.0 + 0.5 * s, 7.0 * s);
                    (r * th.cos(), r * th.sin(), u(k))
                })
                .collect()
        };
        let mut first = spiral(41, &|k| if (1..=10).contains(&k) || k > 30 { 1.0 } else { 0.0 });
        first[20].0 = f64::NAN;
        // Coast only, but an early point with a NaN throttle.
        let mut second = spiral(30, &|_| 0.2);
        second[2].2 = f64::NAN;
        let paths = [
            FlownPath {
                label: "hard #0".to_string(),
                initial: circle(1.0),
                target: circle(1.5),
                points: first,
            },
            FlownPath {
                label: "hard #1".to_string(),
                initial: OrbitShape {
                    a: 1.1,
                    e: 0.1,
                    omega: 0.5,
                },
                target: circle(1.5),
                points: second,
            },
        ];
        flown_trajectories(&path, "Flown policy", &paths).unwrap();
        let els = read_svg(&path);

        let thrust = chart_lines(&els, THRUST_COLOR, FLOWN_CHART_WIDTH);
        let coast = chart_lines(&els, COAST_COLOR, FLOWN_CHART_WIDTH);
        assert_eq!(thrust.len(), 2);
        assert_eq!(coast.len(), 2, "one coast run in each path");
        let mut thrust_points: Vec<usize> = thrust.iter().map(|e| e.points().len()).collect();
        thrust_points.sort();
        assert_eq!(thrust_points, [11, 11], "points 0..=10 and 30..=40");
        let mut coast_points: Vec<usize> = coast.iter().map(|e| e.points().len()).collect();
        coast_points.sort();
        assert_eq!(
            coast_points,
            [20, 29],
            "points 10..=30 less the NaN one; 30 less the NaN one"
        );
        // Orbits: the target (solid) is a polyline in the path colour; the initial one dashed.
        for i in 0..2 {
            let solid = chart_lines(&els, record_color(i), FLOWN_CHART_WIDTH);
            assert!(solid.iter().any(|e| e.points().len() == crate::plot::ORBIT_POINTS + 1));
        }
        let sun: Vec<_> = with(&els, "circle", "fill", SUN_COLOR)
            .into_iter()
            .filter(|e| e.num("cx") < FLOWN_CHART_WIDTH)
            .collect();
        assert_eq!(sun.len(), 1);
        let t = texts(&els);
        assert!(t.contains(&"Flown policy") && t.contains(&"hard #0") && t.contains(&"hard #1"));
    }

    #[test]
    fn histogram_grid_has_a_panel_per_histogram() {
        let dir = out_dir("grid");
        let path = dir.join("grid.svg");
        let panel = |title: &str, values: Vec<f64>, markers: Vec<(String, f64)>| Panel {
            title: title.to_string(),
            x_label: format!("{title} [-]"),
            values,
            markers,
        };
        let ramp = |n: i32, s: f64| (0..n).map(|k| s * f64::from(k)).collect::<Vec<f64>>();
        let panels = [
            panel("reward", ramp(100, -1.0), vec![]),
            panel("final mass", ramp(80, 0.001), vec![("median".to_string(), 0.04)]),
            panel("terminal dr", vec![f64::NAN; 5], vec![]),
            panel("terminal dv", ramp(60, 0.01), vec![("target".to_string(), 0.1)]),
        ];
        histogram_grid(&path, "Monte Carlo, 1000 runs", &panels, 9).unwrap();
        let els = read_svg(&path);
        let svg = &els[0];
        assert_eq!(svg.num("width"), f64::from(2 * PANEL_SIZE.0));
        assert_eq!(with(&els, "rect", "fill", BAR_COLOR).len(), 3 * 9);
        assert_eq!(with(&els, "polyline", "stroke", MARKER_COLORS[0]).len(), 2);
        let t = texts(&els);
        for s in [
            "Monte Carlo, 1000 runs",
            "reward",
            "final mass",
            "terminal dr",
            "terminal dv",
            "no finite values",
        ] {
            assert!(t.contains(&s), "{s} missing from {t:?}");
        }
        for n in ["n = 100", "n = 80", "n = 60"] {
            assert!(t.contains(&n), "{n} missing");
        }
        assert_eq!(grid_shape(1), (1, 1));
        assert_eq!(grid_shape(3), (1, 3));
        assert_eq!(grid_shape(4), (2, 2));
        assert_eq!(grid_shape(5), (2, 3));
    }

    #[test]
    fn bad_inputs_are_refused_and_nothing_is_written() {
        let dir = out_dir("refused");
        let svg = dir.join("out.svg");
        let png = dir.join("out.png");
        let ok_series = [series("a", vec![(0.0, 1.0), (1.0, 2.0)], None)];
        let ok_panel = Panel {
            title: "p".to_string(),
            x_label: "x".to_string(),
            values: vec![1.0, 2.0],
            markers: vec![],
        };
        let nan_panel = Panel {
            values: vec![f64::NAN],
            ..ok_panel.clone()
        };
        let flown = |points: Vec<(f64, f64, f64)>, e: f64| FlownPath {
            label: "f".to_string(),
            initial: OrbitShape { a: 1.0, e, omega: 0.0 },
            target: circle(1.5),
            points,
        };
        let results = [
            line_chart(&png, "t", "x", "y", &ok_series, false),
            line_chart(&svg, "t", "x", "y", &[], false),
            line_chart(
                &svg,
                "t",
                "x",
                "y",
                &[series("n", vec![(f64::NAN, 1.0), (1.0, f64::INFINITY)], None)],
                false,
            ),
            histogram(&png, "t", "x", &[1.0], 3, None, &[]),
            histogram(&svg, "t", "x", &[], 3, None, &[]),
            histogram(&svg, "t", "x", &[f64::NAN, f64::NEG_INFINITY], 3, None, &[]),
            histogram(&svg, "t", "x", &[5.0, 6.0], 3, Some((0.0, 1.0)), &[]),
            histogram(&svg, "t", "x", &[1.0], 0, None, &[]),
            histogram(&svg, "t", "x", &[1.0], 3, Some((1.0, 0.0)), &[]),
            flown_trajectories(&png, "t", &[flown(vec![(1.0, 0.0, 0.0)], 0.0)]),
            flown_trajectories(&svg, "t", &[]),
            flown_trajectories(&svg, "t", &[flown(vec![(f64::NAN, 0.0, 0.0)], 0.0)]),
            flown_trajectories(&svg, "t", &[flown(vec![(1.0, 0.0, 0.0)], 1.5)]),
            histogram_grid(&png, "t", std::slice::from_ref(&ok_panel), 3),
            histogram_grid(&svg, "t", &[], 3),
            histogram_grid(&svg, "t", &[nan_panel], 3),
            histogram_grid(&svg, "t", &[ok_panel], 0),
        ];
        let errors: Vec<PlotError> = results.into_iter().map(|r| r.unwrap_err()).collect();
        let kinds: Vec<String> = errors
            .iter()
            .map(|e| match e {
                PlotError::UnsupportedFormat(_) => "format".to_string(),
                PlotError::NothingToDraw(chart) => format!("nothing {chart}"),
                PlotError::InvalidBins(0) => "bins".to_string(),
                PlotError::InvalidRange { low, high } if (*low, *high) == (1.0, 0.0) => "range".to_string(),
                PlotError::InvalidOrbit {
                    record: 0,
                    which: "initial",
                } => "orbit".to_string(),
                other => format!("unexpected {other}"),
            })
            .collect();
        assert_eq!(
            kinds,
            [
                "format",
                "nothing line chart",
                "nothing line chart",
                "format",
                "nothing histogram",
                "nothing histogram",
                "nothing histogram",
                "bins",
                "range",
                "format",
                "nothing flown trajectories",
                "nothing flown trajectories",
                "orbit",
                "format",
                "nothing histogram grid",
                "nothing histogram grid",
                "bins",
            ]
        );
        for e in &errors {
            assert!(!e.to_string().is_empty());
        }
        assert!(std::fs::read_dir(&dir).unwrap().next().is_none(), "no file written");
    }

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick_label(0.0), "0");
        assert_eq!(tick_label(-0.0), "0");
        assert_eq!(tick_label(0.30000000000000004), "0.3");
        assert_eq!(tick_label(12.5), "12.5");
        assert_eq!(tick_label(20000.0), "20000");
        assert_eq!(tick_label(200000.0), "2e5");
        assert_eq!(tick_label(1.25e6), "1.25e6");
        assert_eq!(tick_label(1e-4), "1e-4");
    }
}
