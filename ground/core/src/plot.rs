//! Figures of solved transfers (thesis Fig. 4.3 to 4.5): transfer paths in the orbit plane
//! coloured by thrust, and the throttle profile along the energy-to-fuel homotopy.
//!
//! Output is SVG only, drawn with `plotters`' SVG backend and no font feature: text stays SVG
//! `<text>` that the viewer renders with its own sans-serif font, so nothing here needs a font
//! file, fontconfig or any system library, and the figures are vector graphics fit for a
//! thesis. (A PNG would need glyphs rasterised from a font shipped with or found by the
//! program.) Files are written atomically through [`atomic_write`].

use std::io;
use std::path::Path;

use onboard::integrator::{IntegrationError, Tolerances};
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use shared::orbit::OrbitShape;
use shared::scenario::Scenario;
use shared::spacecraft::CanonicalSpacecraft;
use shared::units::canonical_to_days;

use crate::generate::{dataset_path, read_dataset, Shard};
use crate::io::atomic_write;
use crate::solver::pontryagin::OptimalControlParams;
use crate::solver::record::{sample_at, TrajectoryRecord, TrajectorySample};
use crate::solver::shooting::{initial_state_costate, HomotopyLevel};

/// One homotopy level's throttle curve: (eps, [(t in days, u)]).
pub type ThrottleCurve = (f64, Vec<(f64, f64)>);

/// Throttle above which a path segment counts as thrusting.
pub const THRUST_THRESHOLD: f64 = 0.5;
/// Points per drawn orbit ellipse (closed: the first point is repeated at the end).
pub const ORBIT_POINTS: usize = 360;

/// Thrusting segments of a transfer path.
pub const THRUST_COLOR: RGBColor = RGBColor(0xD6, 0x27, 0x28);
/// Coasting segments of a transfer path.
pub const COAST_COLOR: RGBColor = RGBColor(0x1F, 0x77, 0xB4);
/// The Sun marker.
pub const SUN_COLOR: RGBColor = RGBColor(0xFF, 0xB0, 0x00);
/// Orbit colours, one per record (cycled), chosen apart from the thrust and coast colours.
pub const RECORD_COLORS: [RGBColor; 6] = [
    RGBColor(0x2C, 0xA0, 0x2C),
    RGBColor(0x94, 0x67, 0xBD),
    RGBColor(0x8C, 0x56, 0x4B),
    RGBColor(0xE3, 0x77, 0xC2),
    RGBColor(0x17, 0xBE, 0xCF),
    RGBColor(0x7F, 0x7F, 0x7F),
];

const TRAJECTORY_SIZE: (u32, u32) = (1300, 960);
const TRAJECTORY_LEGEND_WIDTH: u32 = 360;
const THROTTLE_SIZE: (u32, u32) = (1200, 650);
const THROTTLE_LEGEND_WIDTH: u32 = 200;
pub(crate) const TITLE_SIZE: f64 = 30.0;
pub(crate) const LABEL_SIZE: f64 = 22.0;
pub(crate) const TICK_SIZE: f64 = 18.0;
pub(crate) const LEGEND_SIZE: f64 = 19.0;

/// Why a figure was not written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The output path does not end in `.svg` (the only format written).
    #[error("plots are written as SVG; the path must end in .svg: {0}")]
    UnsupportedFormat(String),
    /// No record was given.
    #[error("no trajectory record to plot")]
    NoRecords,
    /// Record number `record` (position in the slice) has an empty ephemeris.
    #[error("record {record} has no ephemeris samples")]
    NoSamples {
        /// Position of the record in the slice.
        record: usize,
    },
    /// Record number `record` has a non-finite position or throttle.
    #[error("record {record} has a non-finite position or throttle")]
    NonFinite {
        /// Position of the record in the slice.
        record: usize,
    },
    /// Record number `record` has an initial or target orbit that is not a valid ellipse.
    #[error("record {record} has an invalid {which} orbit")]
    InvalidOrbit {
        /// Position of the record (or flown path) in the slice.
        record: usize,
        /// `"initial"` or `"target"`.
        which: &'static str,
    },
    /// No throttle curve was given.
    #[error("no throttle curve to plot")]
    NoCurves,
    /// Curve number `curve` has no points.
    #[error("throttle curve {curve} has no points")]
    EmptyCurve {
        /// Position of the curve in the slice.
        curve: usize,
    },
    /// Curve number `curve` has a non-finite eps, time or throttle.
    #[error("throttle curve {curve} has a non-finite value")]
    NonFiniteCurve {
        /// Position of the curve in the slice.
        curve: usize,
    },
    /// Fewer than two samples were asked for a throttle curve.
    #[error("a throttle curve needs at least 2 samples, {0} asked")]
    TooFewSamples(usize),
    /// None of the homotopy levels converged.
    #[error("no homotopy level converged")]
    NoConvergedLevel,
    /// Re-propagating the costates of the level at `eps` failed.
    #[error("propagating the level eps = {eps:e} failed: {error:?}")]
    Propagation {
        /// Homotopy parameter of the level.
        eps: f64,
        /// The integrator's error.
        error: IntegrationError,
    },
    /// A chart ([`crate::charts`]) has no finite value to draw; names the chart.
    #[error("{0}: no finite value to draw")]
    NothingToDraw(&'static str),
    /// A histogram was asked for zero bins.
    #[error("a histogram needs at least one bin, {0} asked")]
    InvalidBins(usize),
    /// A histogram range that is not finite and increasing.
    #[error("histogram range [{low}, {high}] is not finite and increasing")]
    InvalidRange {
        /// Lower bound asked for.
        low: f64,
        /// Upper bound asked for.
        high: f64,
    },
    /// The drawing library failed.
    #[error("drawing the plot failed: {0}")]
    Render(String),
    /// Writing the file failed.
    #[error("writing the plot failed: {0}")]
    Io(#[source] io::Error),
}

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for PlotError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        Self::Render(e.to_string())
    }
}

/// Transfer paths in the orbit plane (thesis Fig. 4.4/4.5), all records on one figure: the Sun
/// at the origin, each record's initial orbit (dashed) and target orbit (solid) in the record's
/// colour, its ephemeris path in [`THRUST_COLOR`] where u > 1/2 and [`COAST_COLOR`] elsewhere,
/// a circle at departure and a triangle at arrival; equal scaling of x and y (AU).
///
/// Errors: a path not ending in `.svg`, no records, a record without samples or with
/// non-finite ones, an orbit that is not an ellipse, or a failed write (the file at `path` is
/// then unchanged).
pub fn plot_trajectories(records: &[&TrajectoryRecord], path: &Path) -> Result<(), PlotError> {
    check_svg_path(path)?;
    if records.is_empty() {
        return Err(PlotError::NoRecords);
    }
    let mut layers = Vec::with_capacity(records.len());
    for (i, rec) in records.iter().enumerate() {
        layers.push(OrbitPlaneLayer::from_record(i, rec)?);
    }
    let svg = render_svg(TRAJECTORY_SIZE, |root| draw_trajectories(root, records, &layers))?;
    atomic_write(path, svg.as_bytes()).map_err(PlotError::Io)
}

/// Throttle against time (days) for each homotopy level on one chart (thesis Fig. 4.3), one
/// line per `(eps, points)` labelled with its eps, coloured from dark (first) to light (last).
///
/// Errors: a path not ending in `.svg`, no curves, an empty curve, a non-finite value, or a
/// failed write (the file at `path` is then unchanged).
pub fn plot_throttle_homotopy(curves: &[ThrottleCurve], path: &Path) -> Result<(), PlotError> {
    check_svg_path(path)?;
    if curves.is_empty() {
        return Err(PlotError::NoCurves);
    }
    for (i, (eps, points)) in curves.iter().enumerate() {
        if points.is_empty() {
            return Err(PlotError::EmptyCurve { curve: i });
        }
        if !eps.is_finite() || points.iter().any(|(t, u)| !t.is_finite() || !u.is_finite()) {
            return Err(PlotError::NonFiniteCurve { curve: i });
        }
    }
    let svg = render_svg(THROTTLE_SIZE, |root| draw_throttle(root, curves))?;
    atomic_write(path, svg.as_bytes()).map_err(PlotError::Io)
}

/// The throttle curves of the converged homotopy levels: each level's initial costates are
/// propagated with that level's eps and sampled at `samples` times evenly spread over
/// [0, TOF]. Returns `(eps, [(t in days, u)])` in the order of `levels`; unconverged levels
/// are skipped.
///
/// Errors: fewer than 2 samples, no converged level, or a failed propagation.
pub fn homotopy_throttle_curves(
    scenario: &Scenario,
    spacecraft: &CanonicalSpacecraft,
    levels: &[HomotopyLevel],
    samples: usize,
    tolerances: &Tolerances,
) -> Result<Vec<ThrottleCurve>, PlotError> {
    if samples < 2 {
        return Err(PlotError::TooFewSamples(samples));
    }
    let tof = scenario.time_of_flight();
    let times: Vec<f64> = (0..samples).map(|k| tof * k as f64 / (samples - 1) as f64).collect();
    let mut curves = Vec::new();
    for level in levels.iter().filter(|l| l.outcome.converged) {
        let z = level.outcome.z;
        let y0 = initial_state_costate(scenario, &[z[0], z[1], z[2], z[3], z[4]]);
        let params = OptimalControlParams {
            spacecraft: *spacecraft,
            eps: level.eps,
        };
        let sampled = sample_at(&y0, &params, &times, tolerances)
            .map_err(|error| PlotError::Propagation { eps: level.eps, error })?;
        curves.push((
            level.eps,
            sampled.iter().map(|s| (canonical_to_days(s.t), s.throttle)).collect(),
        ));
    }
    if curves.is_empty() {
        return Err(PlotError::NoConvergedLevel);
    }
    Ok(curves)
}

/// `eps` for a legend, 4 significant digits: plain when 0.01 or more, else scientific.
pub fn format_eps(eps: f64) -> String {
    if eps >= 0.01 {
        let decimals = (3 - eps.log10().floor() as i32).max(0) as usize;
        let s = format!("{eps:.decimals$}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{eps:.2e}")
    }
}

/// Refuses a figure path that does not end in `.svg`, the only format written: cheap, so a
/// caller can check before the work that makes the figure.
pub fn check_svg_path(path: &Path) -> Result<(), PlotError> {
    let svg = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("svg"));
    if svg {
        Ok(())
    } else {
        Err(PlotError::UnsupportedFormat(path.display().to_string()))
    }
}

pub(crate) type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// Draws on an SVG canvas of `size` pixels and returns the document.
pub(crate) fn render_svg(
    size: (u32, u32),
    draw: impl FnOnce(&Area<'_>) -> Result<(), PlotError>,
) -> Result<String, PlotError> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
    }
    Ok(svg)
}

/// What one record contributes to the orbit-plane figure, in AU.
/// One transfer in the orbit plane: its orbits, its path split into thrust and coast runs,
/// departure and arrival, and its legend lines (the first drawn in the layer's colour).
pub(crate) struct OrbitPlaneLayer {
    pub(crate) initial: Vec<(f64, f64)>,
    pub(crate) target: Vec<(f64, f64)>,
    /// Maximal runs of path segments with one thrust state: (thrusting, points).
    pub(crate) runs: Vec<(bool, Vec<(f64, f64)>)>,
    pub(crate) start: Option<(f64, f64)>,
    pub(crate) end: Option<(f64, f64)>,
    pub(crate) label: String,
    pub(crate) notes: Vec<(String, RGBColor)>,
}

impl OrbitPlaneLayer {
    /// A solved record's layer; its path must be finite and its orbits valid ellipses.
    fn from_record(record: usize, rec: &TrajectoryRecord) -> Result<Self, PlotError> {
        let (Some(first), Some(last)) = (rec.ephemeris.first(), rec.ephemeris.last()) else {
            return Err(PlotError::NoSamples { record });
        };
        if rec
            .ephemeris
            .iter()
            .any(|s| !s.r.iter().all(|x| x.is_finite()) || !s.throttle.is_finite())
        {
            return Err(PlotError::NonFinite { record });
        }
        let orbit = |shape: &OrbitShape, which| -> Result<Vec<(f64, f64)>, PlotError> {
            shape
                .validate()
                .map_err(|_| PlotError::InvalidOrbit { record, which })?;
            Ok(orbit_points(shape))
        };
        let mut notes = vec![(record_detail(rec), BLACK)];
        if !rec.converged {
            notes.push(("NOT converged".to_string(), THRUST_COLOR));
        }
        Ok(Self {
            initial: orbit(&rec.scenario.initial.shape, "initial")?,
            target: orbit(&rec.scenario.target, "target")?,
            runs: thrust_runs(&rec.ephemeris),
            start: Some((first.r[0], first.r[1])),
            end: Some((last.r[0], last.r[1])),
            label: record_label(rec),
            notes,
        })
    }

    fn points(&self) -> impl Iterator<Item = &(f64, f64)> {
        self.initial
            .iter()
            .chain(&self.target)
            .chain(self.runs.iter().flat_map(|(_, p)| p))
            .chain(self.start.iter())
            .chain(self.end.iter())
    }
}

/// The closed ellipse of an orbit shape, [`ORBIT_POINTS`] + 1 points.
pub(crate) fn orbit_points(shape: &OrbitShape) -> Vec<(f64, f64)> {
    (0..=ORBIT_POINTS)
        .map(|k| {
            let c = shape.cartesian_at(2.0 * std::f64::consts::PI * k as f64 / ORBIT_POINTS as f64);
            (c.r[0], c.r[1])
        })
        .collect()
}

/// Splits the sampled path into maximal runs of segments that thrust (mean throttle of the two
/// ends above [`THRUST_THRESHOLD`]) or coast; consecutive runs share their joining sample.
fn thrust_runs(samples: &[TrajectorySample]) -> Vec<(bool, Vec<(f64, f64)>)> {
    let points: Vec<(f64, (f64, f64))> = samples.iter().map(|s| (s.throttle, (s.r[0], s.r[1]))).collect();
    thrust_runs_of(&points)
}

/// [`thrust_runs`] of (throttle, (x, y)) points: planar samples or spatial ones projected.
pub(crate) fn thrust_runs_of(points: &[(f64, (f64, f64))]) -> Vec<(bool, Vec<(f64, f64)>)> {
    let mut runs: Vec<(bool, Vec<(f64, f64)>)> = Vec::new();
    for w in points.windows(2) {
        let thrusting = 0.5 * (w[0].0 + w[1].0) > THRUST_THRESHOLD;
        let (a, b) = (w[0].1, w[1].1);
        match runs.last_mut() {
            Some((t, points)) if *t == thrusting => points.push(b),
            _ => runs.push((thrusting, vec![a, b])),
        }
    }
    runs
}

pub(crate) fn record_color(i: usize) -> RGBColor {
    RECORD_COLORS[i % RECORD_COLORS.len()]
}

fn record_label(rec: &TrajectoryRecord) -> String {
    format!("{} seed {} #{}", rec.family.label(), rec.seed, rec.index)
}

fn record_detail(rec: &TrajectoryRecord) -> String {
    format!(
        "m_f = {:.4}, \u{3b5} = {}, {:.0} d",
        rec.final_mass,
        format_eps(rec.final_eps),
        canonical_to_days(rec.scenario.time_of_flight())
    )
}

/// Axis ranges that hold `bounds` (x0, x1, y0, y1) with a margin and give one AU the same
/// number of pixels on both axes of a `pixels` (width, height) plotting area.
pub(crate) fn equal_aspect_ranges(bounds: (f64, f64, f64, f64), pixels: (u32, u32)) -> ((f64, f64), (f64, f64)) {
    let (x0, x1, y0, y1) = bounds;
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (w, h) = (f64::from(pixels.0.max(1)), f64::from(pixels.1.max(1)));
    let per_pixel = ((x1 - x0) / w).max((y1 - y0) / h).max(1e-9) * 1.08;
    let (hx, hy) = (0.5 * per_pixel * w, 0.5 * per_pixel * h);
    ((cx - hx, cx + hx), (cy - hy, cy + hy))
}

fn draw_trajectories(
    root: &Area<'_>,
    records: &[&TrajectoryRecord],
    layers: &[OrbitPlaneLayer],
) -> Result<(), PlotError> {
    let title = if records.len() == 1 {
        format!("Fuel-optimal transfer: {}", record_label(records[0]))
    } else {
        format!("Fuel-optimal transfers ({} cases)", records.len())
    };
    draw_orbit_plane(root, &title, TRAJECTORY_LEGEND_WIDTH, layers)
}

/// Transfers in the orbit plane with equal axis scales, the Sun at the origin, and a legend.
pub(crate) fn draw_orbit_plane(
    root: &Area<'_>,
    title: &str,
    legend_width: u32,
    layers: &[OrbitPlaneLayer],
) -> Result<(), PlotError> {
    let body = root.titled(title, ("sans-serif", TITLE_SIZE))?;
    let (width, _) = body.dim_in_pixel();
    let (plot_area, legend_area) = body.split_horizontally(width.saturating_sub(legend_width));

    let mut bounds = (0.0f64, 0.0f64, 0.0f64, 0.0f64); // the Sun is always in view
    for &(x, y) in layers.iter().flat_map(OrbitPlaneLayer::points) {
        bounds = (bounds.0.min(x), bounds.1.max(x), bounds.2.min(y), bounds.3.max(y));
    }
    let builder = |x: (f64, f64), y: (f64, f64)| {
        ChartBuilder::on(&plot_area)
            .margin(15)
            .x_label_area_size(60)
            .y_label_area_size(80)
            .build_cartesian_2d(x.0..x.1, y.0..y.1)
    };
    // Building a chart draws nothing: a first build measures the plotting area in pixels.
    let pixels = builder((-1.0, 1.0), (-1.0, 1.0))?.plotting_area().dim_in_pixel();
    let (xr, yr) = equal_aspect_ranges(bounds, pixels);
    let mut chart = builder(xr, yr)?;
    chart
        .configure_mesh()
        .x_desc("x [AU]")
        .y_desc("y [AU]")
        .axis_desc_style(("sans-serif", LABEL_SIZE))
        .label_style(("sans-serif", TICK_SIZE))
        .x_label_formatter(&|v| format!("{v:.1}"))
        .y_label_formatter(&|v| format!("{v:.1}"))
        .light_line_style(RGBColor(0xEE, 0xEE, 0xEE))
        .bold_line_style(RGBColor(0xD0, 0xD0, 0xD0))
        .draw()?;

    for (i, layer) in layers.iter().enumerate() {
        let color = record_color(i);
        chart.draw_series(DashedLineSeries::new(
            layer.initial.iter().copied(),
            9,
            6,
            color.stroke_width(2),
        ))?;
        chart.draw_series(LineSeries::new(layer.target.iter().copied(), color.stroke_width(2)))?;
    }
    for layer in layers {
        for (thrusting, points) in &layer.runs {
            let color = if *thrusting { THRUST_COLOR } else { COAST_COLOR };
            chart.draw_series(LineSeries::new(points.iter().copied(), color.stroke_width(3)))?;
        }
    }
    chart.draw_series([Circle::new((0.0, 0.0), 10, SUN_COLOR.filled())])?;
    for (i, layer) in layers.iter().enumerate() {
        let color = record_color(i);
        if let (Some(start), Some(end)) = (layer.start, layer.end) {
            chart.draw_series([
                Circle::new(start, 7, color.filled()),
                Circle::new(start, 7, BLACK.stroke_width(1)),
            ])?;
            chart.draw_series([TriangleMarker::new(end, 9, color.filled())])?;
        }
    }

    let mut legend = Legend::new(&legend_area);
    legend.entry(Mark::Line(THRUST_COLOR, 3, false), "thrust arc (u > 0.5)")?;
    legend.entry(Mark::Line(COAST_COLOR, 3, false), "coast arc (u \u{2264} 0.5)")?;
    legend.entry(Mark::Circle(SUN_COLOR), "Sun")?;
    legend.entry(Mark::Circle(BLACK), "departure")?;
    legend.entry(Mark::Triangle(BLACK), "arrival")?;
    for (i, layer) in layers.iter().enumerate() {
        let color = record_color(i);
        legend.gap();
        legend.heading(&layer.label, color)?;
        for (note, note_color) in &layer.notes {
            legend.heading(note, *note_color)?;
        }
        legend.entry(Mark::Line(color, 2, true), "initial orbit")?;
        legend.entry(Mark::Line(color, 2, false), "target orbit")?;
    }
    Ok(())
}

fn draw_throttle(root: &Area<'_>, curves: &[ThrottleCurve]) -> Result<(), PlotError> {
    let body = root.titled(
        "Optimal throttle along the energy-to-fuel homotopy",
        ("sans-serif", TITLE_SIZE),
    )?;
    let (width, _) = body.dim_in_pixel();
    let (plot_area, legend_area) = body.split_horizontally(width.saturating_sub(THROTTLE_LEGEND_WIDTH));
    let points = curves.iter().flat_map(|(_, p)| p);
    let t0 = points.clone().map(|p| p.0).fold(f64::INFINITY, f64::min);
    let mut t1 = points.clone().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
    if t1 <= t0 {
        t1 = t0 + 1.0;
    }
    let u_min = points.clone().map(|p| p.1).fold(0.0, f64::min);
    let u_max = points.map(|p| p.1).fold(1.0, f64::max);
    let pad = 0.04 * (u_max - u_min);
    let mut chart = ChartBuilder::on(&plot_area)
        .margin(15)
        .x_label_area_size(60)
        .y_label_area_size(80)
        .build_cartesian_2d(t0..t1, (u_min - pad)..(u_max + pad))?;
    chart
        .configure_mesh()
        .x_desc("time since departure [days]")
        .y_desc("throttle u [-]")
        .axis_desc_style(("sans-serif", LABEL_SIZE))
        .label_style(("sans-serif", TICK_SIZE))
        .x_label_formatter(&|v| format!("{v:.0}"))
        .y_label_formatter(&|v| format!("{v:.1}"))
        .light_line_style(RGBColor(0xEE, 0xEE, 0xEE))
        .bold_line_style(RGBColor(0xD0, 0xD0, 0xD0))
        .draw()?;
    let mut legend = Legend::new(&legend_area);
    legend.heading("homotopy level", BLACK)?;
    for (i, (eps, points)) in curves.iter().enumerate() {
        let color = sequential_color(i, curves.len());
        let width = if i + 1 == curves.len() { 3 } else { 2 };
        chart.draw_series(LineSeries::new(points.iter().copied(), color.stroke_width(width)))?;
        legend.entry(
            Mark::Line(color, width, false),
            &format!("\u{3b5} = {}", format_eps(*eps)),
        )?;
    }
    Ok(())
}

/// Colour `i` of `n` on a dark-purple to green ramp (viridis, stopping before its pale yellow).
fn sequential_color(i: usize, n: usize) -> RGBColor {
    const RAMP: [(u8, u8, u8); 5] = [
        (0x44, 0x01, 0x54),
        (0x3B, 0x52, 0x8B),
        (0x21, 0x91, 0x8C),
        (0x3D, 0xBC, 0x74),
        (0x9B, 0xD9, 0x3C),
    ];
    let s = if n > 1 { i as f64 / (n - 1) as f64 } else { 0.0 } * (RAMP.len() - 1) as f64;
    let k = (s.floor() as usize).min(RAMP.len() - 2);
    let f = s - k as f64;
    let mix = |a: u8, b: u8| (f64::from(a) + f * (f64::from(b) - f64::from(a))).round() as u8;
    let (a, b) = (RAMP[k], RAMP[k + 1]);
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// A legend symbol.
pub(crate) enum Mark {
    /// Colour, stroke width, dashed.
    Line(RGBColor, u32, bool),
    Circle(RGBColor),
    Triangle(RGBColor),
}

/// A legend drawn as a column in its own area (pixel coordinates), so it never hides data.
pub(crate) struct Legend<'a, 'b> {
    area: &'a Area<'b>,
    y: i32,
}

impl<'a, 'b> Legend<'a, 'b> {
    const X: i32 = 10;
    const SYMBOL: i32 = 40;
    const ROW: i32 = 28;

    pub(crate) fn new(area: &'a Area<'b>) -> Self {
        Self { area, y: 40 }
    }

    fn text(&self, x: i32, text: &str, color: RGBColor) -> Result<(), PlotError> {
        let style = TextStyle::from(("sans-serif", LEGEND_SIZE).into_font())
            .color(&color)
            .pos(Pos::new(HPos::Left, VPos::Center));
        self.area.draw(&Text::new(text.to_string(), (x, self.y), style))?;
        Ok(())
    }

    pub(crate) fn heading(&mut self, text: &str, color: RGBColor) -> Result<(), PlotError> {
        self.text(Self::X, text, color)?;
        self.y += Self::ROW;
        Ok(())
    }

    pub(crate) fn gap(&mut self) {
        self.y += Self::ROW / 2;
    }

    pub(crate) fn entry(&mut self, mark: Mark, text: &str) -> Result<(), PlotError> {
        let (x0, x1, y) = (Self::X, Self::X + Self::SYMBOL, self.y);
        match mark {
            Mark::Line(color, width, false) => {
                self.area
                    .draw(&PathElement::new(vec![(x0, y), (x1, y)], color.stroke_width(width)))?;
            }
            Mark::Line(color, width, true) => {
                self.area.draw(&DashedPathElement::new(
                    [(x0, y), (x1, y)],
                    9,
                    6,
                    color.stroke_width(width),
                ))?;
            }
            Mark::Circle(color) => self.area.draw(&Circle::new(((x0 + x1) / 2, y), 7, color.filled()))?,
            Mark::Triangle(color) => self
                .area
                .draw(&TriangleMarker::new(((x0 + x1) / 2, y), 9, color.filled()))?,
        }
        self.text(x1 + 12, text, BLACK)?;
        self.y += Self::ROW;
        Ok(())
    }
}

/// Plots the first four solved trajectories of a dataset folder (thesis Fig. 4.4/4.5) into
/// `trajectories.svg` there; returns how many were drawn.
pub fn plot_dataset_sample(out: &Path, shard: Shard) -> Result<usize, Box<dyn std::error::Error>> {
    let file = read_dataset(&dataset_path(out, shard))?;
    let shown: Vec<_> = file
        .records
        .iter()
        .filter(|r| !r.ephemeris.is_empty())
        .take(4)
        .collect();
    if !shown.is_empty() {
        plot_trajectories(&shown, &out.join("trajectories.svg"))?;
    }
    Ok(shown.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_aspect_ranges_give_the_same_scale_on_both_axes() {
        for (bounds, pixels) in [
            ((-1.0, 1.0, -0.5, 0.5), (800, 600)),
            ((-2.0, 1.0, -1.0, 3.0), (500, 900)),
            ((0.0, 0.0, 0.0, 0.0), (300, 300)),
        ] {
            let ((x0, x1), (y0, y1)) = equal_aspect_ranges(bounds, pixels);
            let (sx, sy) = ((x1 - x0) / f64::from(pixels.0), (y1 - y0) / f64::from(pixels.1));
            assert!((sx - sy).abs() <= 1e-12 * sx.max(1.0), "{sx} vs {sy}");
            assert!(x0 <= bounds.0 && x1 >= bounds.1 && y0 <= bounds.2 && y1 >= bounds.3);
        }
    }

    #[test]
    fn eps_labels_are_short() {
        assert_eq!(format_eps(1.0), "1");
        assert_eq!(format_eps(0.5), "0.5");
        assert_eq!(format_eps(0.0625), "0.0625");
        assert_eq!(format_eps(0.03125), "0.03125");
        assert_eq!(format_eps(12.5), "12.5");
        assert_eq!(format_eps(6.103515625e-5), "6.10e-5");
    }

    #[test]
    fn sequential_colors_run_from_first_to_last_anchor() {
        assert_eq!(sequential_color(0, 5), RGBColor(0x44, 0x01, 0x54));
        assert_eq!(sequential_color(4, 5), RGBColor(0x9B, 0xD9, 0x3C));
        assert_eq!(sequential_color(0, 1), RGBColor(0x44, 0x01, 0x54));
    }
}
