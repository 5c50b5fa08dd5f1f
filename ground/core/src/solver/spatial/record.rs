//! Trajectory records in three dimensions (docs/spec.md section 3.5): what one solved draw of an
//! inclined family keeps, sampled like the planar records at the ephemeris epochs and at every
//! guidance cycle's boundary.

use std::time::Instant;

use serde::{Deserialize, Serialize};
use shared::mission::SpatialFamily;
use shared::scenario::SpatialScenario;
use shared::spacecraft::CanonicalSpacecraft;

use super::{sample_solution, SpatialSample};
use crate::solver::record::{count_arcs, sample_grids};
use crate::solver::{arriving_early, SolveOptions, SolveOutcome};
use crate::spatial::SpatialGoal;

/// One solved (or failed) draw of an inclined family.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpatialRecord {
    /// Family the scenario was drawn from.
    pub family: SpatialFamily,
    /// Seed of the draw: `family.draw(seed, index)` gave `scenario`.
    pub seed: u64,
    /// Index of the draw in its seed's stream.
    pub index: u64,
    /// The scenario solved.
    pub scenario: SpatialScenario,
    /// Whether the homotopy reached the final eps with the terminal conditions met and the
    /// solution was sampled.
    pub converged: bool,
    /// Why the solve failed, when it did.
    pub failure: Option<String>,
    /// Initial costates (lambda_r, lambda_v, lambda_m), inertial.
    pub costates: [f64; 7],
    /// Transfers: the final true anomaly on the target orbit (rad).
    pub final_anomaly: Option<f64>,
    /// Homotopy parameter of the stored costates: the last level solved.
    pub final_eps: f64,
    /// Final mass, fraction of m0.
    pub final_mass: f64,
    /// Number of maximal intervals with u > 1/2 sampled on the ephemeris grid.
    pub thrust_arcs: u32,
    /// Largest terminal-condition residual (canonical).
    pub residual: f64,
    /// Wall time of the solve, s.
    pub seconds: f64,
    /// Samples evenly spread over [0, TOF] (the planar records' ephemeris grid).
    pub ephemeris: Vec<SpatialSample>,
    /// One sample per guidance cycle boundary: k = 0..=N at t = k * cycle.
    pub steps: Vec<SpatialSample>,
    /// How many distinct energy-optimal solutions the multi-start found.
    pub distinct_energy_optima: u32,
}

/// Draws scenario `index` of `family` (seed `seed`), solves it by the indirect method in three
/// dimensions and samples the solution. Never fails: a draw that does not converge is returned
/// with `converged = false` and the reason.
pub fn solve_spatial_draw(
    family: &SpatialFamily,
    seed: u64,
    index: u64,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> SpatialRecord {
    solve_spatial_scenario(family, (seed, index), &family.draw(seed, index), spacecraft, options)
}

/// [`solve_spatial_scenario`] on the scenario shortened by [`SolveOptions::arrival_margin_steps`]
/// where that converges, on the scenario itself otherwise: the three-dimensional
/// [`crate::solver::solve_arriving_early`] (a flight that arrives early coasts with its target,
/// on its orbit or with the body, for the margin's cycles).
pub fn solve_spatial_arriving_early(
    family: &SpatialFamily,
    draw: (u64, u64),
    scenario: &SpatialScenario,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> SpatialRecord {
    arriving_early(scenario, options.arrival_margin_steps, |scenario| {
        solve_spatial_scenario(family, draw, scenario, spacecraft, options)
    })
}

impl SolveOutcome for SpatialRecord {
    fn converged(&self) -> bool {
        self.converged
    }

    fn seconds_and_failure(&mut self) -> (&mut f64, &mut Option<String>) {
        (&mut self.seconds, &mut self.failure)
    }
}

/// Solves `scenario` by the indirect method in three dimensions and samples the solution, as
/// [`solve_spatial_draw`] does a draw: for a scenario posed otherwise (the rest of a flight from a
/// state it visited), labelled with `family` and (`seed`, `index`) for tracing.
pub fn solve_spatial_scenario(
    family: &SpatialFamily,
    (seed, index): (u64, u64),
    scenario: &SpatialScenario,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> SpatialRecord {
    let start = Instant::now();
    let scenario = *scenario;
    let mut record = SpatialRecord {
        family: *family,
        seed,
        index,
        scenario,
        converged: false,
        failure: None,
        costates: [0.0; 7],
        final_anomaly: None,
        final_eps: 1.0,
        final_mass: f64::NAN,
        thrust_arcs: 0,
        residual: f64::INFINITY,
        seconds: 0.0,
        ephemeris: Vec::new(),
        steps: Vec::new(),
        distinct_energy_optima: 0,
    };
    let solved = match scenario.validate() {
        Err(e) => Err(format!("invalid scenario: {e}")),
        Ok(()) => SpatialGoal::of_scenario(&scenario, *spacecraft)
            .and_then(|goal| goal.solve(options))
            .map_err(|e| e.to_string()),
    };
    match solved {
        Err(why) => record.failure = Some(why),
        Ok(solved) => {
            let s = solved.solution;
            record.costates = core::array::from_fn(|k| s.costates[k]);
            record.final_anomaly = solved.final_anomaly;
            record.final_eps = s.final_eps;
            record.residual = s.residual;
            record.distinct_energy_optima = s.distinct_energy_optima;
            let (ephemeris, steps) = sample_grids(&scenario.scenario);
            let sampled = sample_solution(&solved.flight, &s, &ephemeris, &options.tolerances)
                .and_then(|e| Ok((e, sample_solution(&solved.flight, &s, &steps, &options.tolerances)?)));
            match sampled {
                Ok((ephemeris, steps)) => {
                    record.final_mass = s.final_mass;
                    record.thrust_arcs = count_arcs(ephemeris.iter().map(|x| x.throttle));
                    record.ephemeris = ephemeris;
                    record.steps = steps;
                    record.converged = true;
                }
                Err(e) => record.failure = Some(format!("sampling the solution failed: {e:?}")),
            }
        }
    }
    record.seconds = start.elapsed().as_secs_f64();
    record
}
