//! Figures (thesis Fig. 4.3 to 4.5): the SVG files are well formed, hold what they claim (one
//! path per thrust/coast run, one line per homotopy level, circular orbits drawn as circles,
//! i.e. equal axis scaling), are written atomically, and bad inputs are refused.
//!
//! The images are kept under `target/tmp/plot-*/` for a look.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use ground_core::plot::{
    homotopy_throttle_curves, plot_throttle_homotopy, plot_trajectories, PlotError, COAST_COLOR, RECORD_COLORS,
    SUN_COLOR, THRUST_COLOR,
};
use ground_core::solver::pontryagin::OptimalControlParams;
use ground_core::solver::record::{TrajectoryRecord, TrajectorySample, EPHEMERIS_POINTS};
use ground_core::solver::shooting::{
    solve_transfer, solve_transfer_homotopy, HomotopyLevel, NewtonOutcome, TransferVector,
};
use ground_core::solver::{solve_scenario, transfer_guesses, SolveOptions};
use plotters::style::RGBColor;
use shared::orbit::{OrbitElements, OrbitShape};
use shared::scenario::{Scenario, ScenarioKind};
use shared::spacecraft::{CanonicalSpacecraft, Spacecraft};
use shared::units::canonical_to_days;

/// Width of the chart column of the orbit-plane figure (the legend is to its right).
const TRAJECTORY_CHART_WIDTH: f64 = 1300.0 - 360.0;
/// Width of the chart column of the throttle figure.
const THROTTLE_CHART_WIDTH: f64 = 1200.0 - 200.0;

fn out_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("plot-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A short homotopy keeps the test quick; the figures are the same at any final eps.
fn options() -> SolveOptions {
    SolveOptions {
        final_eps: 0.3,
        ..SolveOptions::default()
    }
}

/// The homotopy levels of a transfer from its first converged energy-optimal start.
fn homotopy_levels(scenario: &Scenario, spacecraft: &CanonicalSpacecraft, opts: &SolveOptions) -> Vec<HomotopyLevel> {
    let energy = OptimalControlParams {
        spacecraft: *spacecraft,
        eps: 1.0,
    };
    let z0: TransferVector = transfer_guesses(scenario)
        .iter()
        .find_map(|g| {
            solve_transfer(scenario, &energy, g, &opts.tolerances, &opts.newton)
                .ok()
                .filter(|o| o.converged)
        })
        .expect("an energy-optimal start")
        .z;
    solve_transfer_homotopy(
        scenario,
        spacecraft,
        &z0,
        &opts.tolerances,
        &opts.newton,
        opts.final_eps,
        opts.max_homotopy_solves,
    )
    .unwrap()
}

fn circle(a: f64) -> OrbitShape {
    OrbitShape { a, e: 0.0, omega: 0.0 }
}

/// A made-up transfer from a circular 1 AU orbit to a circular 1.5 AU one: a spiral over 1.2
/// revolutions that thrusts for the first 40 % of the samples, coasts, and thrusts again for
/// the last 20 %.
fn synthetic_record() -> TrajectoryRecord {
    let (initial, target) = (circle(1.0), circle(1.5));
    let scenario = Scenario::transfer(
        OrbitElements {
            shape: initial,
            nu: 0.0,
        },
        target,
    );
    let tof = scenario.time_of_flight();
    let n = 100;
    let ephemeris = (0..n)
        .map(|k| {
            let s = k as f64 / (n - 1) as f64;
            let (r, theta) = (1.0 + 0.5 * s, 1.2 * 2.0 * std::f64::consts::PI * s);
            let throttle = if !(0.4..0.8).contains(&s) { 1.0 } else { 0.0 };
            TrajectorySample {
                t: tof * s,
                r: [r * theta.cos(), r * theta.sin()],
                v: [-theta.sin() / r.sqrt(), theta.cos() / r.sqrt()],
                m: 1.0 - 0.1 * s,
                throttle,
                direction: [-theta.sin(), theta.cos()],
                direction_polar: [0.0, 1.0],
            }
        })
        .collect();
    TrajectoryRecord {
        family: ScenarioKind::TransferCircular.family(),
        seed: 0,
        index: 0,
        scenario,
        converged: true,
        failure: None,
        costates: [0.0; 5],
        final_anomaly: None,
        final_eps: 1e-4,
        final_mass: 0.9,
        thrust_arcs: 2,
        residual: 0.0,
        seconds: 0.0,
        ephemeris,
        steps: Vec::new(),
        distinct_energy_optima: 1,
    }
}

// ------------------------------------------------------------------------------------------
// A minimal SVG reader: enough to check nesting and to pull out shapes and text.
// ------------------------------------------------------------------------------------------

#[derive(Debug)]
struct Element {
    name: String,
    attrs: HashMap<String, String>,
    text: String,
}

impl Element {
    fn attr(&self, key: &str) -> &str {
        self.attrs.get(key).map_or("", String::as_str)
    }

    fn points(&self) -> Vec<(f64, f64)> {
        self.attr("points")
            .split_whitespace()
            .map(|p| {
                let (x, y) = p.split_once(',').expect("x,y");
                (x.parse().unwrap(), y.parse().unwrap())
            })
            .collect()
    }

    fn num(&self, key: &str) -> f64 {
        self.attr(key).parse().unwrap()
    }
}

fn hex(c: RGBColor) -> String {
    format!("#{:02X}{:02X}{:02X}", c.0, c.1, c.2)
}

/// Parses the document, checking that it is one `<svg>` element with properly nested tags and
/// quoted attributes, and returns every element in document order.
fn parse_svg(doc: &str) -> Vec<Element> {
    assert!(
        doc.starts_with("<svg "),
        "does not start with <svg: {}",
        &doc[..40.min(doc.len())]
    );
    assert!(doc.trim_end().ends_with("</svg>"));
    let mut elements: Vec<Element> = Vec::new();
    let mut open: Vec<(String, usize)> = Vec::new();
    let mut rest = doc;
    while let Some(start) = rest.find('<') {
        let text = &rest[..start];
        if let Some((_, idx)) = open.last() {
            elements[*idx].text.push_str(text.trim());
        } else {
            assert!(text.trim().is_empty(), "text outside the root: {text:?}");
        }
        let end = rest[start..].find('>').expect("unterminated tag") + start;
        let tag = &rest[start + 1..end];
        rest = &rest[end + 1..];
        if let Some(name) = tag.strip_prefix('/') {
            let (top, _) = open.pop().expect("close without open");
            assert_eq!(top, name.trim(), "misnested tags");
            continue;
        }
        let self_closing = tag.ends_with('/');
        let tag = tag.trim_end_matches('/');
        let (name, mut attr_text) = tag.split_once(' ').unwrap_or((tag, ""));
        let mut attrs = HashMap::new();
        loop {
            attr_text = attr_text.trim_start();
            if attr_text.is_empty() {
                break;
            }
            let (key, after) = attr_text.split_once("=\"").expect("attribute without a quoted value");
            let (value, after) = after.split_once('"').expect("unterminated attribute");
            assert!(!key.contains(['<', '>', '"']) && !value.contains('<'));
            attrs.insert(key.to_string(), value.to_string());
            attr_text = after;
        }
        assert!(open.is_empty() == elements.is_empty(), "more than one root element");
        elements.push(Element {
            name: name.to_string(),
            attrs,
            text: String::new(),
        });
        if !self_closing {
            open.push((name.to_string(), elements.len() - 1));
        }
    }
    assert!(open.is_empty(), "unclosed tags: {open:?}");
    assert_eq!(elements[0].name, "svg");
    elements
}

fn read_svg(path: &Path) -> (String, Vec<Element>) {
    let doc = std::fs::read_to_string(path).unwrap();
    assert!(doc.len() > 5_000, "{} is only {} bytes", path.display(), doc.len());
    let elements = parse_svg(&doc);
    (doc, elements)
}

/// Polylines of a colour that lie entirely left of `x_max` (the chart, not the legend).
fn polylines(elements: &[Element], color: RGBColor, x_max: f64) -> Vec<&Element> {
    elements
        .iter()
        .filter(|e| e.name == "polyline" && e.attr("stroke") == hex(color))
        .filter(|e| e.points().iter().all(|p| p.0 < x_max))
        .collect()
}

fn texts(elements: &[Element]) -> Vec<&str> {
    elements
        .iter()
        .filter(|e| e.name == "text")
        .map(|e| e.text.as_str())
        .collect()
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Maximal runs of ephemeris segments thrusting (mean throttle > 1/2) and coasting.
fn run_counts(rec: &TrajectoryRecord) -> (usize, usize) {
    let states: Vec<bool> = rec
        .ephemeris
        .windows(2)
        .map(|w| w[0].throttle + w[1].throttle > 1.0)
        .collect();
    let starts = |on: bool| {
        (0..states.len())
            .filter(|&i| states[i] == on && (i == 0 || states[i - 1] != on))
            .count()
    };
    (starts(true), starts(false))
}

fn sun_center(elements: &[Element]) -> (f64, f64) {
    let sun: Vec<_> = elements
        .iter()
        .filter(|e| e.name == "circle" && e.attr("fill") == hex(SUN_COLOR) && e.num("cx") < TRAJECTORY_CHART_WIDTH)
        .collect();
    assert_eq!(sun.len(), 1, "one Sun in the chart");
    (sun[0].num("cx"), sun[0].num("cy"))
}

#[test]
fn synthetic_transfer_plot_has_thrust_arcs_and_equal_axes() {
    let dir = out_dir("synthetic");
    let rec = synthetic_record();
    let path = dir.join("trajectory.svg");
    plot_trajectories(&[&rec], &path).unwrap();
    assert_eq!(files_in(&dir), ["trajectory.svg"], "no temporary file is left");
    let (_, elements) = read_svg(&path);

    // Two thrust arcs and one coast arc between them, each one polyline.
    let x_max = TRAJECTORY_CHART_WIDTH;
    let thrust = polylines(&elements, THRUST_COLOR, x_max);
    let coast = polylines(&elements, COAST_COLOR, x_max);
    assert_eq!((thrust.len(), coast.len()), (2, 1));
    assert_eq!(run_counts(&rec), (2, 1));
    // The path is continuous: each run starts where the previous one ended.
    let (t0, c0, t1) = (thrust[0].points(), coast[0].points(), thrust[1].points());
    assert_eq!(t0.last(), c0.first());
    assert_eq!(c0.last(), t1.first());
    assert_eq!(t0.len() + c0.len() + t1.len(), rec.ephemeris.len() + 2);

    // Equal scaling: the circular target orbit is a circle in pixels, centred on the Sun, and
    // the dashed 1 AU orbit has 1/1.5 of its radius.
    let sun = sun_center(&elements);
    let orbit_color = RECORD_COLORS[0];
    let lines = polylines(&elements, orbit_color, x_max);
    let target: Vec<_> = lines.iter().filter(|e| e.points().len() > 300).collect();
    assert_eq!(target.len(), 1, "one solid target orbit");
    let radius = |p: &(f64, f64)| (p.0 - sun.0).hypot(p.1 - sun.1);
    let target_radii: Vec<f64> = target[0].points().iter().map(radius).collect();
    let r_target = target_radii.iter().sum::<f64>() / target_radii.len() as f64;
    assert!(r_target > 150.0, "the orbit fills the chart: radius {r_target} px");
    for r in &target_radii {
        assert!(
            (r - r_target).abs() <= 1.5,
            "target orbit is not a circle: {r} vs {r_target}"
        );
    }
    let dashes: Vec<(f64, f64)> = lines
        .iter()
        .filter(|e| e.points().len() <= 300)
        .flat_map(|e| e.points())
        .collect();
    assert!(
        dashes.len() > 50,
        "the initial orbit is dashed: {} dash points",
        dashes.len()
    );
    for p in &dashes {
        assert!(
            (radius(p) - r_target / 1.5).abs() <= 2.0,
            "initial orbit radius {}",
            radius(p)
        );
    }

    // Departure and arrival markers at the ends of the path.
    let start = elements
        .iter()
        .find(|e| e.name == "circle" && e.attr("fill") == hex(orbit_color))
        .expect("departure marker");
    assert_eq!((start.num("cx"), start.num("cy")), t0[0]);
    assert!(elements
        .iter()
        .any(|e| e.name == "polygon" && e.attr("fill") == hex(orbit_color)));

    let labels = texts(&elements);
    for wanted in [
        "x [AU]",
        "y [AU]",
        "thrust arc (u &gt; 0.5)",
        "coast arc",
        "Sun",
        "initial orbit",
        "target orbit",
    ] {
        assert!(
            labels.iter().any(|t| t.contains(wanted)),
            "missing text {wanted:?} in {labels:?}"
        );
    }
    assert!(labels.iter().any(|t| t.starts_with("Fuel-optimal transfer")));
}

#[test]
fn solved_transfer_and_its_homotopy_are_plotted() {
    let dir = out_dir("solved");
    let spacecraft = Spacecraft::MSR_ERO.canonical().unwrap();
    let scenario = ScenarioKind::TransferCircular.draw(1, 0);
    let opts = options();
    let solved = solve_scenario(ScenarioKind::TransferCircular, 1, 0, &scenario, &spacecraft, &opts);
    assert!(solved.converged, "{:?}", solved.failure);
    let synthetic = synthetic_record();

    // Several records on one figure: every run of every record is one polyline.
    let path = dir.join("transfers.svg");
    plot_trajectories(&[&solved, &synthetic], &path).unwrap();
    let (_, elements) = read_svg(&path);
    let x_max = TRAJECTORY_CHART_WIDTH;
    let (ts, cs) = run_counts(&solved);
    let (tx, cx) = run_counts(&synthetic);
    // (At eps = 0.25 this short transfer never reaches u > 1/2: it is drawn as one coast arc.)
    assert!(ts + cs >= 1);
    assert_eq!(polylines(&elements, THRUST_COLOR, x_max).len(), ts + tx);
    assert_eq!(polylines(&elements, COAST_COLOR, x_max).len(), cs + cx);
    for color in &RECORD_COLORS[..2] {
        let long = polylines(&elements, *color, x_max)
            .into_iter()
            .filter(|e| e.points().len() > 300)
            .count();
        assert_eq!(long, 1, "one target orbit per record");
    }
    sun_center(&elements);
    let labels = texts(&elements);
    assert!(labels.iter().any(|t| t.contains("transfer-circular seed 1 #0")));
    assert!(labels.iter().any(|t| t.contains("(2 cases)")));

    // Fig. 4.3: re-propagate each converged homotopy level of the same scenario.
    let levels = homotopy_levels(&scenario, &spacecraft, &opts);
    let converged: Vec<f64> = levels.iter().filter(|l| l.outcome.converged).map(|l| l.eps).collect();
    assert_eq!(converged, [1.0, 0.5, 0.25]);
    let samples = 200;
    let curves = homotopy_throttle_curves(&scenario, &spacecraft, &levels, samples, &opts.tolerances).unwrap();
    assert_eq!(curves.iter().map(|c| c.0).collect::<Vec<_>>(), converged);
    let tof_days = canonical_to_days(scenario.time_of_flight());
    for (_, points) in &curves {
        assert_eq!(points.len(), samples);
        assert_eq!(points[0].0, 0.0);
        assert!((points[samples - 1].0 - tof_days).abs() < 1e-9 * tof_days);
        let dt = tof_days / (samples - 1) as f64;
        assert!(points
            .windows(2)
            .all(|w| (w[1].0 - w[0].0 - dt).abs() < 1e-9 * tof_days));
        assert!(points.iter().all(|p| (0.0..=1.0).contains(&p.1)));
    }
    // The last level re-propagated on the ephemeris grid is the record solve_scenario made
    // (same energy-optimal start, same eps, same costates).
    let last = levels.iter().rev().find(|l| l.outcome.converged).unwrap();
    assert_eq!(solved.final_eps, last.eps);
    let z = last.outcome.z;
    assert!(
        solved.costates.iter().zip(z.iter()).all(|(a, b)| (a - b).abs() < 1e-9),
        "same branch: {:?} vs {z:?}",
        solved.costates
    );
    let on_grid =
        homotopy_throttle_curves(&scenario, &spacecraft, &[*last], EPHEMERIS_POINTS, &opts.tolerances).unwrap();
    for ((t, u), s) in on_grid[0].1.iter().zip(&solved.ephemeris) {
        assert!(
            (t - canonical_to_days(s.t)).abs() < 1e-9 && (u - s.throttle).abs() < 1e-9,
            "{t} {u} vs {s:?}"
        );
    }

    let path = dir.join("throttle_homotopy.svg");
    plot_throttle_homotopy(&curves, &path).unwrap();
    let (_, elements) = read_svg(&path);
    let lines: Vec<_> = elements
        .iter()
        .filter(|e| e.name == "polyline" && e.points().len() >= samples / 2)
        .filter(|e| e.points().iter().all(|p| p.0 < THROTTLE_CHART_WIDTH))
        .collect();
    assert_eq!(lines.len(), curves.len(), "one line per homotopy level");
    let mut colors: Vec<&str> = lines.iter().map(|e| e.attr("stroke")).collect();
    colors.dedup();
    assert_eq!(colors.len(), curves.len(), "distinct colours");
    let labels = texts(&elements);
    for wanted in [
        "\u{3b5} = 1",
        "\u{3b5} = 0.5",
        "\u{3b5} = 0.25",
        "time since departure [days]",
        "throttle u [-]",
    ] {
        assert!(labels.contains(&wanted), "missing text {wanted:?} in {labels:?}");
    }
    assert_eq!(
        files_in(&dir),
        ["throttle_homotopy.svg", "transfers.svg"],
        "no temporary file is left"
    );
}

#[test]
fn a_plot_replaces_an_existing_file_whole() {
    let dir = out_dir("replace");
    let path = dir.join("fig.svg");
    std::fs::write(&path, "old").unwrap();
    let rec = synthetic_record();
    plot_trajectories(&[&rec], &path).unwrap();
    let first = std::fs::read_to_string(&path).unwrap();
    assert!(first.starts_with("<svg"));
    plot_throttle_homotopy(&[(1.0, vec![(0.0, 0.2), (10.0, 0.8)])], &path).unwrap();
    let second = std::fs::read_to_string(&path).unwrap();
    assert!(second.starts_with("<svg") && second != first);
    parse_svg(&second);
    assert_eq!(files_in(&dir), ["fig.svg"]);
}

#[test]
fn bad_inputs_are_refused_and_nothing_is_written() {
    let dir = out_dir("refusals");
    let path = dir.join("fig.svg");
    let good = synthetic_record();
    let mut empty = synthetic_record();
    empty.ephemeris.clear();
    let mut nan = synthetic_record();
    nan.ephemeris[7].r[1] = f64::NAN;
    let mut hyperbolic = synthetic_record();
    hyperbolic.scenario.target.e = 1.5;

    let refusals = [
        plot_trajectories(&[], &path),
        plot_trajectories(&[&good, &empty], &path),
        plot_trajectories(&[&nan], &path),
        plot_trajectories(&[&hyperbolic], &path),
        plot_trajectories(&[&good], &dir.join("fig.png")),
        plot_throttle_homotopy(&[], &path),
        plot_throttle_homotopy(&[(1.0, vec![(0.0, 0.5)]), (0.5, vec![])], &path),
        plot_throttle_homotopy(&[(f64::NAN, vec![(0.0, 0.5)])], &path),
        plot_throttle_homotopy(&[(1.0, vec![(0.0, f64::INFINITY)])], &path),
    ];
    let errors: Vec<PlotError> = refusals.into_iter().map(|r| r.unwrap_err()).collect();
    assert!(matches!(errors[0], PlotError::NoRecords));
    assert!(matches!(errors[1], PlotError::NoSamples { record: 1 }));
    assert!(matches!(errors[2], PlotError::NonFinite { record: 0 }));
    assert!(matches!(
        errors[3],
        PlotError::InvalidOrbit {
            record: 0,
            which: "target"
        }
    ));
    assert!(matches!(errors[4], PlotError::UnsupportedFormat(_)));
    assert!(matches!(errors[5], PlotError::NoCurves));
    assert!(matches!(errors[6], PlotError::EmptyCurve { curve: 1 }));
    assert!(matches!(errors[7], PlotError::NonFiniteCurve { curve: 0 }));
    assert!(matches!(errors[8], PlotError::NonFiniteCurve { curve: 0 }));
    for e in &errors {
        assert!(!e.to_string().is_empty());
    }
    assert!(
        files_in(&dir).is_empty(),
        "refusals write nothing: {:?}",
        files_in(&dir)
    );

    // A folder that cannot be created: the I/O error comes back typed.
    let blocker = dir.join("not-a-folder");
    std::fs::write(&blocker, "x").unwrap();
    let err = plot_trajectories(&[&good], &blocker.join("fig.svg")).unwrap_err();
    assert!(matches!(err, PlotError::Io(_)), "{err}");

    // Throttle curves need 2 samples and a converged level.
    let scenario = good.scenario;
    let spacecraft = Spacecraft::MSR_ERO.canonical().unwrap();
    let tolerances = options().tolerances;
    let failed = HomotopyLevel {
        eps: 1.0,
        outcome: NewtonOutcome {
            z: TransferVector::zeros(),
            residual: f64::INFINITY,
            iterations: 0,
            converged: false,
            jacobian: None,
        },
    };
    assert!(matches!(
        homotopy_throttle_curves(&scenario, &spacecraft, &[failed], 1, &tolerances),
        Err(PlotError::TooFewSamples(1))
    ));
    assert!(matches!(
        homotopy_throttle_curves(&scenario, &spacecraft, &[failed], 50, &tolerances),
        Err(PlotError::NoConvergedLevel)
    ));
    assert!(matches!(
        homotopy_throttle_curves(&scenario, &spacecraft, &[], 50, &tolerances),
        Err(PlotError::NoConvergedLevel)
    ));
}

/// Thesis Fig. 4.3 and 4.4 at the full homotopy (down to eps < 1e-4): slow, so run on demand
/// (`cargo test -p lowthrust-ground --test plot_figures -- --ignored`); the figures are kept
/// in `target/tmp/plot-fig-4-3/`.
#[test]
#[ignore = "full homotopy: slow; run on demand to produce the thesis figures"]
fn full_homotopy_figures() {
    let dir = out_dir("fig-4-3");
    let spacecraft = Spacecraft::MSR_ERO.canonical().unwrap();
    let opts = SolveOptions::default();
    let index: u64 = std::env::var("PLOT_INDEX")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3);
    let scenario = ScenarioKind::TransferCircular.draw(1, index);
    let solved = solve_scenario(ScenarioKind::TransferCircular, 1, index, &scenario, &spacecraft, &opts);
    eprintln!(
        "index {index}: {scenario:?} converged {} m_f {}",
        solved.converged, solved.final_mass
    );
    let levels = homotopy_levels(&scenario, &spacecraft, &opts);
    let curves = homotopy_throttle_curves(&scenario, &spacecraft, &levels, 400, &opts.tolerances).unwrap();
    plot_throttle_homotopy(&curves, &dir.join("throttle_homotopy.svg")).unwrap();
    plot_trajectories(&[&solved], &dir.join("transfer.svg")).unwrap();
}
