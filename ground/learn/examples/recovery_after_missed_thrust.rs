//! Whether the flights that miss under dispersions could still have arrived: each SIL flight
//! (the config's dispersions and aids) that misses the goal after missed thrust is re-solved by
//! the indirect method, on time and with the nominal thrust, from its true state where its last
//! missed-thrust event ended. A rest that re-solves was recoverable by some control; one that
//! does not is classified by its minimum time (`ground data feasibility`'s method): below the
//! time left it is feasible, above it no control arrives on time (a local minimum time, as that
//! classification's are). What no controller can recover bounds the share any can reach.
//!
//! ```text
//! cargo run --release -p lowthrust-learn --example recovery_after_missed_thrust -- CONFIG BLOB COUNT OUT_CSV [GAP_CSV]
//! ```
//! One row per missing flight with missed thrust: its episode (the SIL's `mc.csv` numbering on
//! the config's Monte Carlo seed), residuals, where its last event ended, and the verdict.
//! GAP_CSV, a SIL run's `optimality-gap.csv` on the same seed, keeps only the draws the indirect
//! method solves from departure (`optimal_converged`): the others may have no transfer at all.

use std::fmt::Write as _;
use std::path::Path;

use ground_core::demo::{relabel, rest_of_flight};
use ground_core::solver::min_time::{classify_draw, Feasibility};
use ground_core::solver::SolveOptions;
use learn::config::ExperimentConfig;
use learn::sil::{fly_blob, SilFlights};
use rayon::prelude::*;

/// The accuracy goal, AU and v* (canonical).
const GOAL: f64 = 0.01;

/// What re-solving one flight's rest found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Verdict {
    /// The fuel-optimal rest converged: some control arrives.
    Resolves,
    /// No fuel-optimal solve, but the rest is longer than its minimum time.
    Feasible,
    /// The rest is shorter than its minimum time: no control arrives on time.
    Infeasible,
    /// The event ended in the last step: no cycle left to correct.
    NoCycleLeft,
    /// Neither a solve nor a minimum time.
    Unknown,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let (config, blob, count, out, gap) = match &args[..] {
        [_, config, blob, count, out] => (config, blob, count, out, None),
        [_, config, blob, count, out, gap] => (config, blob, count, out, Some(gap)),
        _ => return Err("usage: recovery_after_missed_thrust CONFIG BLOB COUNT OUT_CSV [GAP_CSV]".into()),
    };
    // The draws solved from departure, where a GAP_CSV says (its `optimal_converged` column).
    let solved: Option<Vec<usize>> = match gap {
        None => None,
        Some(gap) => {
            let text = std::fs::read_to_string(gap)?;
            let mut lines = text.lines();
            let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
            let column = header
                .iter()
                .position(|&c| c == "optimal_converged")
                .ok_or("GAP_CSV has no optimal_converged column")?;
            Some(
                lines
                    .filter_map(|line| {
                        let cells: Vec<&str> = line.split(',').collect();
                        (cells.get(column) == Some(&"true")).then(|| cells[0].parse().ok())?
                    })
                    .collect(),
            )
        }
    };
    let config = ExperimentConfig::load(Path::new(config))?;
    let family = config.planar_family("the recovery check")?;
    let blob = std::fs::read(blob)?;
    let count: u64 = count.parse()?;
    let scenarios: Vec<_> = (0..count).map(|i| family.draw(config.seeds.monte_carlo, i)).collect();
    let flights = SilFlights::of(&config, &config.sil.dispersions, scenarios.len());
    let (outcomes, _, missed) = fly_blob(&config, &blob, &scenarios, &flights)?;
    let spacecraft = config.env.canonical_spacecraft()?;
    let units = family.body.units();
    // On time: the question is whether the draw's own arrival is still reachable.
    let options = SolveOptions {
        final_eps: config.generate.final_eps,
        ..SolveOptions::default()
    };
    let missing: Vec<usize> = (0..outcomes.len())
        .filter(|&k| {
            let t = &outcomes[k].terminal;
            !(outcomes[k].completed && t.position <= GOAL && t.velocity <= GOAL)
                && missed[k].last_end.is_some()
                && solved.as_ref().is_none_or(|s| s.contains(&k))
        })
        .collect();
    eprintln!(
        "{} of {} flights miss after missed thrust; re-solving them",
        missing.len(),
        outcomes.len()
    );
    let done = std::sync::atomic::AtomicUsize::new(0);
    // Each flight's verdict, and for a rest shorter than its minimum time the shortfall: in
    // days, and as the velocity full thrust gives over it, in velocity goals (0.01 v*). A miss
    // within the goal may need less than the exact arrival that the minimum time measures, so a
    // shortfall of a small fraction of a goal is no proof that the goal is out of reach.
    let verdicts: Vec<(Verdict, Option<(f64, f64)>)> = missing
        .par_iter()
        .map(|&k| {
            let scenario = &scenarios[k];
            let end = missed[k].last_end.unwrap_or(1.0);
            let step = (end * f64::from(scenario.steps)).round() as u32;
            let verdict = if step >= scenario.steps {
                (Verdict::NoCycleLeft, None)
            } else {
                let state = outcomes[k]
                    .trajectory
                    .as_ref()
                    .and_then(|t| t.get(step as usize))
                    .map(|p| p.state);
                match state {
                    None => (Verdict::Unknown, None),
                    Some(state) => {
                        let solved = relabel(&family, (0, k as u64), scenario, &state, step, &spacecraft, &options)
                            .is_some_and(|(record, _)| record.converged);
                        if solved {
                            (Verdict::Resolves, None)
                        } else {
                            match rest_of_flight(scenario, &state, step, &spacecraft) {
                                None => (Verdict::Unknown, None),
                                Some((rest, scaled)) => {
                                    let tof = rest.time_of_flight();
                                    match classify_draw(&rest, &scaled, &options) {
                                        Feasibility::MinTime { tf_min, .. } if tf_min > tof => (
                                            Verdict::Infeasible,
                                            Some((units.to_days(tf_min - tof), scaled.thrust * (tf_min - tof) / GOAL)),
                                        ),
                                        Feasibility::Recovered { .. } | Feasibility::MinTime { .. } => {
                                            (Verdict::Feasible, None)
                                        }
                                        Feasibility::Unknown(_) => (Verdict::Unknown, None),
                                    }
                                }
                            }
                        }
                    }
                }
            };
            let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            if n.is_multiple_of(10) {
                eprintln!("{n}/{}", missing.len());
            }
            verdict
        })
        .collect();
    let mut csv =
        String::from("episode,dr,dv,last_missed_thrust_end,verdict,shortfall_days,shortfall_velocity_goals\n");
    for (&k, (verdict, shortfall)) in missing.iter().zip(&verdicts) {
        let t = &outcomes[k].terminal;
        let end = missed[k].last_end.unwrap_or(f64::NAN);
        let shortfall = shortfall
            .map(|(d, g)| format!("{d:.3},{g:.3}"))
            .unwrap_or_else(|| ",".into());
        let _ = writeln!(
            csv,
            "{k},{:.4e},{:.4e},{end},{verdict:?},{shortfall}",
            t.position, t.velocity
        );
    }
    std::fs::write(out, csv)?;
    let mut kinds: Vec<Verdict> = verdicts.iter().map(|v| v.0).collect();
    kinds.sort();
    kinds.dedup();
    for kind in kinds {
        println!("{kind:?}: {}", verdicts.iter().filter(|v| v.0 == kind).count());
    }
    Ok(())
}
