//! Where along its flight a controller loses a draw: the Monte Carlo draws that the indirect
//! method solves from departure are flown by an actor, and the rest of each flight is re-solved
//! (as a relabelling round does) from the states at several fractions of it. The first fraction
//! whose state no longer re-solves is where the flight has spent the draw's slack.
//!
//! ```text
//! cargo run --release -p lowthrust-learn --example reach_along_flight -- CONFIG ACTOR REACH_CSV COUNT OUT_CSV
//! ```
//! REACH_CSV: the per-draw rows of ground-core's `05_zoh_reach` example on the config's Monte
//! Carlo seed (its `indirect_converged` column picks the solved draws).

use std::fmt::Write as _;
use std::path::Path;

use ground_core::demo::relabel;
use ground_core::env::batch::evaluate_batched;
use ground_core::env::{MdpEnv, Transfer};
use ground_core::solver::SolveOptions;
use learn::config::ExperimentConfig;
use learn::eval::{load_agent, meets, ACCURACY_GOAL};
use learn::phase::policy_batch;
use onboard::dynamics::SpacecraftState;
use rayon::prelude::*;
use shared::scenario::ProblemKind;

const FRACTIONS: [f64; 8] = [0.02, 0.05, 0.1, 0.2, 0.4, 0.6, 0.8, 0.9];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, config, actor, reach, count, out] = &args[..] else {
        return Err("usage: reach_along_flight CONFIG ACTOR REACH_CSV COUNT OUT_CSV".into());
    };
    let config = ExperimentConfig::load(Path::new(config))?;
    if config.problem() != ProblemKind::Transfer {
        return Err("a transfer config is needed (the diagnostic flies the 10-feature transfer MDP)".into());
    }
    let family = config.planar_family("the reach diagnostic")?;
    let count: usize = count.parse()?;
    let solved: Vec<usize> = std::fs::read_to_string(reach)?
        .lines()
        .skip(1)
        .filter_map(|line| {
            let mut cols = line.split(',');
            let index: usize = cols.next()?.parse().ok()?;
            (cols.next()? == "true" && index < count).then_some(index)
        })
        .collect();
    let agent = load_agent(&config, 10, Path::new(actor))?;
    let scenarios: Vec<_> = solved
        .iter()
        .map(|&i| family.draw(config.seeds.monte_carlo, i as u64))
        .collect();
    let flown = evaluate_batched::<MdpEnv<Transfer>, _>(&config.env, &scenarios, |o| policy_batch(&agent, o), true)?;
    let spacecraft = config.env.canonical_spacecraft()?;
    // As a relabelling round solves them.
    let options = SolveOptions {
        final_eps: config.generate.final_eps,
        arrival_margin_steps: config.generate.arrival_margin,
        ..SolveOptions::default()
    };
    let jobs: Vec<(usize, usize)> = (0..flown.len())
        .flat_map(|k| (0..FRACTIONS.len()).map(move |f| (k, f)))
        .collect();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let solved_at: Vec<Option<bool>> = jobs
        .par_iter()
        .map(|&(k, f)| {
            let scenario = &scenarios[k];
            let step = ((FRACTIONS[f] * f64::from(scenario.steps)).round() as u32).clamp(1, scenario.steps - 1);
            let point = flown[k].trajectory.as_ref()?.get(step as usize)?;
            let state: SpacecraftState = point.state;
            let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            if n.is_multiple_of(100) {
                eprintln!("{n}/{}", jobs.len());
            }
            relabel(&family, (0, 0), scenario, &state, step, &spacecraft, &options).map(|(record, _)| record.converged)
        })
        .collect();
    let mut csv = String::from("index,dr,dv,within_goal");
    for f in FRACTIONS {
        let _ = write!(csv, ",solves_at_{f}");
    }
    csv.push('\n');
    for (k, outcome) in flown.iter().enumerate() {
        let within = meets(outcome, ACCURACY_GOAL);
        let _ = write!(
            csv,
            "{},{:.4e},{:.4e},{}",
            solved[k], outcome.terminal.position, outcome.terminal.velocity, within
        );
        for f in 0..FRACTIONS.len() {
            let cell = solved_at[k * FRACTIONS.len() + f].map_or("", |c| if c { "1" } else { "0" });
            let _ = write!(csv, ",{cell}");
        }
        csv.push('\n');
    }
    std::fs::write(out, csv)?;
    Ok(())
}
