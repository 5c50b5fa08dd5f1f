//! The scenarios, the indirect method and the datasets from Python: `draw_scenario`, `solve`
//! (one scenario, `ground data solve`), `generate` (a family in parallel, `ground data
//! generate`, the same files) and `read_dataset` (a dataset as numpy arrays).

use std::path::{Path, PathBuf};

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use ground_core::generate::{
    dataset_solve_request, generate as generate_records, holds_spatial_records, read_dataset as read_records,
    read_dataset_of, DatasetFamily, DatasetFile, GenerateError, Manifest, Shard, Summary,
};
use ground_core::solver::record::{TrajectoryRecord, TrajectorySample};
use ground_core::solver::spatial::record::{solve_spatial_arriving_early, SpatialRecord};
use ground_core::solver::spatial::SpatialSample;
use ground_core::solver::{solve_arriving_early, SolveOptions};
use shared::mission::SpatialFamily;
use shared::scenario::{Scenario, SpatialScenario};
use shared::spacecraft::{CanonicalSpacecraft, Spacecraft};

use crate::{refused, spatial_scenario_family};

fn scenario_dict<'py>(py: Python<'py>, scenario: &Scenario) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item(
        "problem",
        match scenario.problem {
            shared::scenario::ProblemKind::Transfer => "transfer",
            shared::scenario::ProblemKind::Rendezvous => "rendezvous",
        },
    )?;
    let initial = PyDict::new(py);
    initial.set_item("a", scenario.initial.shape.a)?;
    initial.set_item("e", scenario.initial.shape.e)?;
    initial.set_item("omega", scenario.initial.shape.omega)?;
    initial.set_item("nu", scenario.initial.nu)?;
    d.set_item("initial", initial)?;
    let target = PyDict::new(py);
    target.set_item("a", scenario.target.a)?;
    target.set_item("e", scenario.target.e)?;
    target.set_item("omega", scenario.target.omega)?;
    d.set_item("target", target)?;
    d.set_item("target_nu0", scenario.target_nu0)?;
    d.set_item("steps", scenario.steps)?;
    Ok(d)
}

/// An inclined family's scenario: the planar one in each orbit's own plane, and the planes.
fn spatial_scenario_dict<'py>(py: Python<'py>, scenario: &SpatialScenario) -> PyResult<Bound<'py, PyDict>> {
    let d = scenario_dict(py, &scenario.scenario)?;
    for (key, plane) in [
        ("initial_plane", scenario.initial_plane),
        ("target_plane", scenario.target_plane),
    ] {
        let p = PyDict::new(py);
        p.set_item("inclination", plane.inclination)?;
        p.set_item("raan", plane.raan)?;
        d.set_item(key, p)?;
    }
    Ok(d)
}

/// Scenario `index` of the stream `seed` of the distribution `kind` (docs/spec.md section 4):
/// `problem`, `initial` (`a`, `e`, `omega`, `nu`), `target` (`a`, `e`, `omega`), `target_nu0`
/// (rendezvous: the body's anomaly at departure) and `steps` N (guidance cycles); an inclined
/// family's also `initial_plane` and `target_plane` (`inclination`, `raan`), the orbits' shapes
/// then in their own planes.
#[pyfunction]
fn draw_scenario<'py>(py: Python<'py>, kind: &str, seed: u64, index: u64) -> PyResult<Bound<'py, PyDict>> {
    let family = spatial_scenario_family(kind)?;
    match family.as_planar() {
        Some(planar) => scenario_dict(py, &planar.draw(seed, index)),
        None => spatial_scenario_dict(py, &family.draw(seed, index)),
    }
}

/// The spacecraft given as `thrust_n`, `isp_s` and `mass_kg` (each absent: the thesis's, Table
/// 4.1), in the canonical units of `family`'s central body, checked.
fn canonical(
    family: &shared::mission::MissionFamily,
    thrust_n: Option<f64>,
    isp_s: Option<f64>,
    mass_kg: Option<f64>,
) -> PyResult<CanonicalSpacecraft> {
    let thesis = Spacecraft::MSR_ERO;
    let spacecraft = Spacecraft {
        max_thrust_n: thrust_n.unwrap_or(thesis.max_thrust_n),
        isp_s: isp_s.unwrap_or(thesis.isp_s),
        initial_mass_kg: mass_kg.unwrap_or(thesis.initial_mass_kg),
    };
    spacecraft.canonical_in(&family.body.units()).map_err(|e| {
        refused(format!(
            "spacecraft ({} N, {} s, {} kg): {e}",
            spacecraft.max_thrust_n, spacecraft.isp_s, spacecraft.initial_mass_kg
        ))
    })
}

/// A spacecraft (`thrust_n`, `isp_s`, `mass_kg`; each absent: the thesis's, Table 4.1) in the
/// canonical units of `kind`'s central body (default: the Sun's): `thrust` (T / m0, AU/t*^2)
/// and `exhaust_speed` (g0 Isp, AU/t*).
#[pyfunction]
#[pyo3(signature = (kind="transfer-circular", thrust_n=None, isp_s=None, mass_kg=None))]
fn spacecraft<'py>(
    py: Python<'py>,
    kind: &str,
    thrust_n: Option<f64>,
    isp_s: Option<f64>,
    mass_kg: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    spacecraft_dict(
        py,
        &canonical(&spatial_scenario_family(kind)?.family, thrust_n, isp_s, mass_kg)?,
    )
}

fn spacecraft_dict<'py>(py: Python<'py>, sc: &CanonicalSpacecraft) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("thrust", sc.thrust)?;
    d.set_item("exhaust_speed", sc.exhaust_speed)?;
    Ok(d)
}

fn options(final_eps: Option<f64>, arrival_margin: u32) -> PyResult<SolveOptions> {
    let mut options = SolveOptions {
        arrival_margin_steps: arrival_margin,
        ..SolveOptions::default()
    };
    if let Some(eps) = final_eps {
        if !(eps > 0.0 && eps <= 1.0) {
            return Err(refused(format!("final_eps must be in (0, 1], not {eps}")));
        }
        options.final_eps = eps;
    }
    Ok(options)
}

/// `values`, row after row, as a (rows, width) array.
fn matrix(py: Python<'_>, rows: usize, width: usize, values: Vec<f64>) -> PyResult<Bound<'_, PyArray2<f64>>> {
    Ok(Array2::from_shape_vec((rows, width), values)
        .map_err(refused)?
        .into_pyarray(py))
}

/// Samples as arrays: `t` (k,), `state` (k, 5: x, y, vx, vy, m), `throttle` (k,), `direction`
/// (k, 2, inertial), `direction_polar` (k, 2: radial, transverse).
fn samples_dict<'py>(py: Python<'py>, samples: &[TrajectorySample]) -> PyResult<Bound<'py, PyDict>> {
    let k = samples.len();
    let d = PyDict::new(py);
    d.set_item("t", PyArray1::from_iter(py, samples.iter().map(|s| s.t)))?;
    let state: Vec<f64> = samples
        .iter()
        .flat_map(|s| [s.r[0], s.r[1], s.v[0], s.v[1], s.m])
        .collect();
    d.set_item("state", matrix(py, k, 5, state)?)?;
    d.set_item("throttle", PyArray1::from_iter(py, samples.iter().map(|s| s.throttle)))?;
    let pairs = |f: fn(&TrajectorySample) -> [f64; 2]| matrix(py, k, 2, samples.iter().flat_map(f).collect());
    d.set_item("direction", pairs(|s| s.direction)?)?;
    d.set_item("direction_polar", pairs(|s| s.direction_polar)?)?;
    Ok(d)
}

/// Sets on `d` the fields a planar and a three-dimensional record share by name (the two
/// record types have no common trait).
macro_rules! record_fields {
    ($py:expr, $d:expr, $record:expr) => {
        $d.set_item("kind", $record.family.label().as_str())?;
        $d.set_item("seed", $record.seed)?;
        $d.set_item("index", $record.index)?;
        $d.set_item("converged", $record.converged)?;
        $d.set_item("failure", $record.failure.clone())?;
        $d.set_item("costates", PyArray1::from_slice($py, &$record.costates))?;
        $d.set_item("final_anomaly", $record.final_anomaly)?;
        $d.set_item("final_eps", $record.final_eps)?;
        $d.set_item("final_mass", $record.final_mass)?;
        $d.set_item("thrust_arcs", $record.thrust_arcs)?;
        $d.set_item("residual", $record.residual)?;
        $d.set_item("seconds", $record.seconds)?;
    };
}

fn record_dict<'py>(py: Python<'py>, record: &TrajectoryRecord) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    record_fields!(py, d, record);
    d.set_item("scenario", scenario_dict(py, &record.scenario)?)?;
    d.set_item("steps", samples_dict(py, &record.steps)?)?;
    d.set_item("ephemeris", samples_dict(py, &record.ephemeris)?)?;
    Ok(d)
}

/// Solves scenario `index` of the stream `seed` of `kind` by the indirect method (multi-start,
/// energy-to-fuel homotopy to `final_eps`, default the project's; arriving `arrival_margin`
/// steps early where that converges), for the spacecraft `thrust_n` (N), `isp_s` (s) and
/// `mass_kg` (each absent: the thesis's), as `ground data solve`. Returns the record:
/// `converged`, `failure`, `final_mass`, `costates` (5: lambda_r, lambda_v, lambda_m), the
/// solution at each step boundary (`steps`) and on a fine grid (`ephemeris`); an inclined
/// family's in three dimensions (`costates` 7, `state` (k, 7), `direction` (k, 3), see
/// `read_dataset`). Never raises for a scenario that does not converge: `converged` says so.
#[pyfunction]
#[pyo3(signature = (kind, seed, index, final_eps=None, arrival_margin=0, thrust_n=None, isp_s=None, mass_kg=None))]
#[allow(clippy::too_many_arguments)]
fn solve<'py>(
    py: Python<'py>,
    kind: &str,
    seed: u64,
    index: u64,
    final_eps: Option<f64>,
    arrival_margin: u32,
    thrust_n: Option<f64>,
    isp_s: Option<f64>,
    mass_kg: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let family = spatial_scenario_family(kind)?;
    let options = options(final_eps, arrival_margin)?;
    let sc = canonical(&family.family, thrust_n, isp_s, mass_kg)?;
    match family.as_planar() {
        Some(kind) => {
            let scenario = kind.draw(seed, index);
            let record = py.detach(|| solve_arriving_early(kind, seed, index, &scenario, &sc, &options));
            record_dict(py, &record)
        }
        None => {
            let scenario = family.draw(seed, index);
            let record = py.detach(|| solve_spatial_arriving_early(&family, (seed, index), &scenario, &sc, &options));
            spatial_record_dict(py, &record)
        }
    }
}

/// An inclined family's record, as [`record_dict`] in three dimensions.
fn spatial_record_dict<'py>(py: Python<'py>, record: &SpatialRecord) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    record_fields!(py, d, record);
    d.set_item("scenario", spatial_scenario_dict(py, &record.scenario)?)?;
    d.set_item("steps", spatial_samples_dict(py, record.steps.iter())?)?;
    d.set_item("ephemeris", spatial_samples_dict(py, record.ephemeris.iter())?)?;
    Ok(d)
}

/// Three-dimensional samples as arrays: `t` (k,), `state` (k, 7: x, y, z, vx, vy, vz, m),
/// `throttle` (k,), `direction` (k, 3, inertial).
fn spatial_samples_dict<'py, 'a>(
    py: Python<'py>,
    samples: impl ExactSizeIterator<Item = &'a SpatialSample> + Clone,
) -> PyResult<Bound<'py, PyDict>> {
    let k = samples.len();
    let d = PyDict::new(py);
    d.set_item("t", PyArray1::from_iter(py, samples.clone().map(|s| s.t)))?;
    let state: Vec<f64> = samples
        .clone()
        .flat_map(|s| {
            [
                s.state.r[0],
                s.state.r[1],
                s.state.r[2],
                s.state.v[0],
                s.state.v[1],
                s.state.v[2],
                s.m,
            ]
        })
        .collect();
    d.set_item("state", matrix(py, k, 7, state)?)?;
    d.set_item("throttle", PyArray1::from_iter(py, samples.clone().map(|s| s.throttle)))?;
    d.set_item(
        "direction",
        matrix(py, k, 3, samples.flat_map(|s| s.direction).collect())?,
    )?;
    Ok(d)
}

/// Solves scenarios `0..count` of the stream `seed` of `kind` into the folder `out` on every
/// core for the spacecraft `thrust_n`, `isp_s` and `mass_kg` (each absent: the thesis's),
/// resuming what a stopped run left, exactly as `ground data generate` (the same files; a run
/// folder solved for another spacecraft is refused). Returns the run's summary
/// (`summary.json`) as a dict.
#[pyfunction]
#[pyo3(signature = (kind, seed, count, out, final_eps=None, arrival_margin=0, thrust_n=None, isp_s=None, mass_kg=None))]
#[allow(clippy::too_many_arguments)]
fn generate<'py>(
    py: Python<'py>,
    kind: &str,
    seed: u64,
    count: u64,
    out: PathBuf,
    final_eps: Option<f64>,
    arrival_margin: u32,
    thrust_n: Option<f64>,
    isp_s: Option<f64>,
    mass_kg: Option<f64>,
) -> PyResult<Bound<'py, PyAny>> {
    let family = spatial_scenario_family(kind)?;
    if count == 0 {
        return Err(refused("count must be at least 1"));
    }
    let options = options(final_eps, arrival_margin)?;
    let sc = canonical(&family.family, thrust_n, isp_s, mass_kg)?;
    let summary = py
        .detach(|| match family.as_planar() {
            Some(planar) => generate_family(planar, seed, count, &out, &sc, &options),
            None => generate_family(family, seed, count, &out, &sc, &options),
        })
        .map_err(refused)?;
    let json = serde_json_string(&summary)?;
    py.import("json")?.call_method1("loads", (json,))
}

/// The whole family `0..count` of `seed` into `out`, planar or inclined records.
fn generate_family<F: DatasetFamily>(
    family: F,
    seed: u64,
    count: u64,
    out: &Path,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> Result<Summary, GenerateError> {
    let manifest = Manifest { family, seed, count };
    generate_records(manifest, Shard::WHOLE, out, spacecraft, options, false)
}

fn serde_json_string(value: &impl serde::Serialize) -> PyResult<String> {
    serde_json::to_string(value).map_err(refused)
}

/// A dataset (`dataset.ltds`, or the folder of a `generate` run) as numpy arrays, records in
/// index order: per record `index`, `converged`, `final_mass`, `final_eps`, `costates` (n, 5),
/// `steps` (n: N per record); the step-boundary samples of every record one after another
/// (`t`, `state` (m, 5), `throttle`, `direction`, `direction_polar`, see `solve`), record i's
/// rows `offsets[i]:offsets[i + 1]`; `spacecraft` the one its records were solved for (as
/// `spacecraft()` gives it; `None` for a folder that does not record it). An inclined family's
/// records are in three dimensions: `costates` (n, 7: lambda_r, lambda_v, lambda_m), `state`
/// (m, 7: x, y, z, vx, vy, vz, m), `direction` (m, 3, inertial), no `direction_polar`.
#[pyfunction]
fn read_dataset<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let file = if path.is_dir() { path.join("dataset.ltds") } else { path };
    let solved_for = dataset_solve_request(&file)
        .map_err(refused)?
        .and_then(|r| r.spacecraft);
    let d = if holds_spatial_records(&file).map_err(refused)? {
        spatial_dataset_dict(py, &read_dataset_of::<SpatialFamily>(&file).map_err(refused)?)?
    } else {
        planar_dataset_dict(py, &read_records(&file).map_err(refused)?)?
    };
    d.set_item("spacecraft", solved_for.map(|sc| spacecraft_dict(py, &sc)).transpose()?)?;
    Ok(d)
}

/// What a record of either geometry gives a dataset's arrays.
struct RecordRow<'a> {
    index: u64,
    converged: bool,
    final_mass: f64,
    final_eps: f64,
    /// Guidance cycles N of its scenario.
    steps: u32,
    /// Initial costates: 5 in the plane, 7 in three dimensions.
    costates: &'a [f64],
    /// Its step-boundary samples (N + 1 once solved).
    samples: usize,
}

/// A dataset's arrays that do not depend on its geometry: `kind`, `seed`, per record `index`,
/// `converged`, `final_mass`, `final_eps`, `steps`, `costates` (n, width) and the samples'
/// `offsets` (see [`read_dataset`]).
fn dataset_dict<'py, F: DatasetFamily>(
    py: Python<'py>,
    dataset: &DatasetFile<F>,
    row: impl Fn(&F::Record) -> RecordRow<'_>,
) -> PyResult<Bound<'py, PyDict>> {
    let rows: Vec<RecordRow> = dataset.records.iter().map(row).collect();
    let d = PyDict::new(py);
    d.set_item("kind", dataset.manifest.family.name())?;
    d.set_item("seed", dataset.manifest.seed)?;
    d.set_item("index", PyArray1::from_iter(py, rows.iter().map(|r| r.index)))?;
    d.set_item("converged", PyArray1::from_iter(py, rows.iter().map(|r| r.converged)))?;
    d.set_item("final_mass", PyArray1::from_iter(py, rows.iter().map(|r| r.final_mass)))?;
    d.set_item("final_eps", PyArray1::from_iter(py, rows.iter().map(|r| r.final_eps)))?;
    d.set_item("steps", PyArray1::from_iter(py, rows.iter().map(|r| r.steps)))?;
    let width = rows.first().map_or(0, |r| r.costates.len());
    let costates: Vec<f64> = rows.iter().flat_map(|r| r.costates.iter().copied()).collect();
    d.set_item("costates", matrix(py, rows.len(), width, costates)?)?;
    let offsets: Vec<u64> = std::iter::once(0)
        .chain(rows.iter().scan(0u64, |end, r| {
            *end += r.samples as u64;
            Some(*end)
        }))
        .collect();
    d.set_item("offsets", PyArray1::from_vec(py, offsets))?;
    Ok(d)
}

/// An inclined family's dataset as arrays (see [`read_dataset`]).
fn spatial_dataset_dict<'py>(py: Python<'py>, dataset: &DatasetFile<SpatialFamily>) -> PyResult<Bound<'py, PyDict>> {
    let records = &dataset.records;
    let d = dataset_dict(py, dataset, |r| RecordRow {
        index: r.index,
        converged: r.converged,
        final_mass: r.final_mass,
        final_eps: r.final_eps,
        steps: r.scenario.scenario.steps,
        costates: &r.costates,
        samples: r.steps.len(),
    })?;
    let samples = records.iter().flat_map(|r| r.steps.iter()).collect::<Vec<_>>();
    for (key, value) in spatial_samples_dict(py, samples.into_iter())?.iter() {
        d.set_item(key, value)?;
    }
    Ok(d)
}

/// A planar family's dataset as arrays (see [`read_dataset`]).
fn planar_dataset_dict<'py>(py: Python<'py>, dataset: &DatasetFile) -> PyResult<Bound<'py, PyDict>> {
    let records = &dataset.records;
    let d = dataset_dict(py, dataset, |r| RecordRow {
        index: r.index,
        converged: r.converged,
        final_mass: r.final_mass,
        final_eps: r.final_eps,
        steps: r.scenario.steps,
        costates: &r.costates,
        samples: r.steps.len(),
    })?;
    let samples: Vec<TrajectorySample> = records.iter().flat_map(|r| r.steps.iter().copied()).collect();
    for (key, value) in samples_dict(py, &samples)?.iter() {
        d.set_item(key, value)?;
    }
    Ok(d)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(draw_scenario, m)?)?;
    m.add_function(wrap_pyfunction!(spacecraft, m)?)?;
    m.add_function(wrap_pyfunction!(solve, m)?)?;
    m.add_function(wrap_pyfunction!(generate, m)?)?;
    m.add_function(wrap_pyfunction!(read_dataset, m)?)?;
    Ok(())
}
