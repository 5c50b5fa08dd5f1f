//! Which solved draws a controller on the environment's control can reach at all: the indirect
//! optimum is a continuous control, the environment holds one thrust vector per 14-day step in
//! the local polar frame. For each draw the indirect method solves, the direct transcription on
//! one segment per step (exactly the environment's control space) is started from the indirect
//! control at the step midpoints and solved on the record's cost. A converged, re-flown solution
//! proves the draw reachable by a zero-order-hold controller; one that stops at full throttle
//! with its terminal violation stuck is evidence that the 14-day hold costs more than the draw's
//! slack. The re-flown final state's residuals are those the environment scores.
//!
//! Run (the default: 10 draws in about 10 s; seed 2000003 is the transfer configs' Monte Carlo
//! stream, so the rows line up with `ground model evaluate`'s mc.csv episode by episode):
//!
//! ```text
//! cargo run --release -p lowthrust-ground-core --example 05_zoh_reach
//! cargo run --release -p lowthrust-ground-core --example 05_zoh_reach -- --scenario transfer-hard --seed 2000003 --count 1000 --csv reach.csv
//! ```

use std::fmt::Write as _;
use std::sync::atomic::{AtomicUsize, Ordering};

use clap::Parser;
use ground_core::solver::direct::{fly_onboard, solve_direct, DirectGuess, DirectOptions};
use ground_core::solver::record::TrajectoryRecord;
use ground_core::solver::{solve_scenario, SolveOptions};
use onboard::dynamics::SpacecraftState;
use onboard::features::{transfer_features, transfer_residuals};
use rayon::prelude::*;
use shared::scenario::{ProblemKind, ScenarioKind};
use shared::spacecraft::{CanonicalSpacecraft, Spacecraft};

#[derive(Parser, Debug)]
struct Args {
    /// Distribution of the draws (a transfer class).
    #[arg(long, default_value = "transfer-hard")]
    scenario: ScenarioKind,
    #[arg(long, default_value_t = 2_000_003)]
    seed: u64,
    /// Draws 0..count of the seed's stream.
    #[arg(long, default_value_t = 10)]
    count: u64,
    /// Per-draw rows are written here (stdout gets the summary).
    #[arg(long, default_value = "zoh-reach.csv")]
    csv: std::path::PathBuf,
}

struct Row {
    index: u64,
    converged: bool,
    eps: f64,
    indirect_mass: f64,
    full_throttle_time: f64,
    direct: Option<DirectRow>,
}

struct DirectRow {
    converged: bool,
    mass: f64,
    violation: f64,
    full_throttle_segments: f64,
    dr: f64,
    dv: f64,
    iterations: u32,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    let spacecraft = Spacecraft::MSR_ERO.canonical()?;
    let done = AtomicUsize::new(0);
    let rows: Vec<Row> = (0..args.count)
        .into_par_iter()
        .map(|index| {
            let row = reach(args.scenario, args.seed, index, &spacecraft);
            let n = done.fetch_add(1, Ordering::Relaxed) + 1;
            if n.is_multiple_of(50) {
                eprintln!("{n}/{}", args.count);
            }
            row
        })
        .collect();
    let mut csv = String::from(
        "index,indirect_converged,eps,indirect_mass,full_throttle_time,direct_converged,direct_mass,violation,full_throttle_segments,dr,dv,iterations\n",
    );
    for r in &rows {
        let _ = write!(
            csv,
            "{},{},{},{},{:.4}",
            r.index, r.converged, r.eps, r.indirect_mass, r.full_throttle_time
        );
        match &r.direct {
            Some(d) => {
                let _ = writeln!(
                    csv,
                    ",{},{},{:.3e},{:.4},{:.3e},{:.3e},{}",
                    d.converged, d.mass, d.violation, d.full_throttle_segments, d.dr, d.dv, d.iterations
                );
            }
            None => csv.push_str(",,,,,,,\n"),
        }
    }
    std::fs::write(&args.csv, csv)?;
    let solved: Vec<&Row> = rows.iter().filter(|r| r.converged).collect();
    let reached = solved
        .iter()
        .filter(|r| r.direct.as_ref().is_some_and(|d| d.converged && d.violation < 1e-7))
        .count();
    let within = solved
        .iter()
        .filter(|r| r.direct.as_ref().is_some_and(|d| d.dr < 0.01 && d.dv < 0.01))
        .count();
    println!(
        "{} draws, {} solved by the indirect method; on one segment per step: {} reached exactly, {} within 0.01 AU / 0.01",
        rows.len(),
        solved.len(),
        reached,
        within
    );
    Ok(())
}

fn reach(kind: ScenarioKind, seed: u64, index: u64, spacecraft: &CanonicalSpacecraft) -> Row {
    let scenario = kind.draw(seed, index);
    let record = solve_scenario(kind, seed, index, &scenario, spacecraft, &SolveOptions::default());
    let full =
        record.ephemeris.iter().filter(|s| s.throttle > 0.99).count() as f64 / record.ephemeris.len().max(1) as f64;
    let direct = (record.converged && scenario.problem == ProblemKind::Transfer)
        .then(|| direct_row(&record, spacecraft))
        .flatten();
    Row {
        index,
        converged: record.converged,
        eps: record.final_eps,
        indirect_mass: record.final_mass,
        full_throttle_time: full,
        direct,
    }
}

fn direct_row(record: &TrajectoryRecord, spacecraft: &CanonicalSpacecraft) -> Option<DirectRow> {
    let scenario = &record.scenario;
    let segments = scenario.steps as usize;
    let h = scenario.time_of_flight() / segments as f64;
    let guess = DirectGuess::from_record(record, spacecraft, segments, &SolveOptions::default().tolerances).ok()?;
    let options = DirectOptions {
        full_throttle_window: Some(10),
        stagnation_window: Some(20),
        ..DirectOptions::default()
    };
    let solution = solve_direct(scenario, spacecraft, &guess, record.final_eps, &options).ok()?;
    let xf = fly_onboard(scenario, spacecraft, &solution.controls, h, &options.tolerances).ok()?;
    let state = SpacecraftState::from_array(&xf);
    let residuals = transfer_residuals(&transfer_features(&state, &scenario.target, 0.0).ok()?);
    let full = solution.controls.iter().filter(|c| c[2] > 1.0 - 1e-6).count() as f64 / segments as f64;
    Some(DirectRow {
        converged: solution.converged,
        mass: solution.final_mass,
        violation: solution.onboard_infeasibility,
        full_throttle_segments: full,
        dr: residuals.position,
        dv: residuals.velocity,
        iterations: solution.iterations,
    })
}
