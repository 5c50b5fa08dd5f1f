//! Whether the flights that miss under dispersions could still have arrived: each SIL flight
//! (the config's dispersions and aids) that misses the goal after missed thrust is re-solved by
//! the indirect method, on time and with the nominal thrust, from its true state where its last
//! missed-thrust event ended. A rest that re-solves was recoverable by some control; one that
//! does not is classified by its minimum time (`ground data feasibility`'s method): below the
//! time left it is feasible, above it no control arrives on time (a local minimum time, as that
//! classification's are). What no controller can recover bounds the share any can reach.
//!
//! ```text
//! cargo run --release -p lowthrust-learn --example recovery_after_missed_thrust -- CONFIG BLOB COUNT misses|arrivals OUT_CSV [GAP_CSV]
//! ```
//! `arrivals` checks the flights within the goal after missed thrust instead: the control,
//! since each of them did arrive, a verdict of a long shortfall there would discredit the check.
//! One row per flight checked (a miss, or an arrival) with missed thrust: its episode (the SIL's `mc.csv` numbering on
//! the config's Monte Carlo seed), residuals, where its last event ended, and the verdict.
//! GAP_CSV, a SIL run's `optimality-gap.csv` on the same seed, keeps only the draws the indirect
//! method solves from departure (`optimal_converged`; the others may have no transfer at all),
//! and bounds them without foresight of the check: a flight that lost more thrust than its
//! draw's fuel optimum coasts could not have arrived exactly on time by any control.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

use ground_core::demo::{rest_of_flight, solve_rest};
use ground_core::env::batch::EpisodeOutcome;
use ground_core::solver::min_time::{classify_draw, Feasibility};
use ground_core::solver::SolveOptions;
use learn::config::ExperimentConfig;
use learn::eval::{meets, ACCURACY_GOAL};
use learn::sil::{fly_blob, SilFlights};
use rayon::prelude::*;
use shared::mission::{MissionFamily, Units};
use shared::scenario::Scenario;
use shared::spacecraft::CanonicalSpacecraft;

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

/// A flight's verdict from its true state at step `step` (where its last missed thrust ended),
/// and for a rest shorter than its minimum time the shortfall: in days, and as the velocity full
/// thrust gives over it, in velocity goals (0.01 v*). A miss within the goal may need less than
/// the exact arrival that the minimum time measures, so a shortfall of a small fraction of a
/// goal is no proof that the goal is out of reach.
fn verdict(
    (family, units): (&MissionFamily, &Units),
    (k, scenario, outcome): (usize, &Scenario, &EpisodeOutcome),
    step: u32,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> (Verdict, Option<(f64, f64)>) {
    if step >= scenario.steps {
        return (Verdict::NoCycleLeft, None);
    }
    let Some(state) = outcome
        .trajectory
        .as_ref()
        .and_then(|t| t.get(step as usize))
        .map(|p| p.state)
    else {
        return (Verdict::Unknown, None);
    };
    let Some((rest, scaled)) = rest_of_flight(scenario, &state, step, spacecraft) else {
        return (Verdict::Unknown, None);
    };
    if solve_rest(family, (0, k as u64), &rest, &scaled, options).converged {
        return (Verdict::Resolves, None);
    }
    let tof = rest.time_of_flight();
    match classify_draw(&rest, &scaled, options) {
        Feasibility::MinTime { tf_min, .. } if tf_min > tof => (
            Verdict::Infeasible,
            Some((
                units.to_days(tf_min - tof),
                scaled.thrust * (tf_min - tof) / ACCURACY_GOAL,
            )),
        ),
        Feasibility::Recovered { .. } | Feasibility::MinTime { .. } => (Verdict::Feasible, None),
        Feasibility::Unknown(_) => (Verdict::Unknown, None),
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let usage = "usage: recovery_after_missed_thrust CONFIG BLOB COUNT misses|arrivals OUT_CSV [GAP_CSV]";
    let (config, blob, count, select, out, gap) = match &args[..] {
        [_, config, blob, count, select, out] => (config, blob, count, select, out, None),
        [_, config, blob, count, select, out, gap] => (config, blob, count, select, out, Some(gap)),
        _ => return Err(usage.into()),
    };
    let arrivals = match select.as_str() {
        "misses" => false,
        "arrivals" => true,
        _ => return Err(usage.into()),
    };
    // The final mass of each draw's fuel optimum from departure, where a GAP_CSV says (its
    // `optimal_mass` where `optimal_converged`).
    let optima: Option<HashMap<usize, f64>> = match gap {
        None => None,
        Some(gap) => {
            let text = std::fs::read_to_string(gap)?;
            let mut lines = text.lines();
            let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
            let column = |name: &str| {
                header
                    .iter()
                    .position(|&c| c == name)
                    .ok_or(format!("GAP_CSV has no {name} column"))
            };
            let (converged, mass) = (column("optimal_converged")?, column("optimal_mass")?);
            Some(
                lines
                    .filter_map(|line| {
                        let cells: Vec<&str> = line.split(',').collect();
                        if cells.get(converged) != Some(&"true") {
                            return None;
                        }
                        Some((cells[0].parse().ok()?, cells.get(mass)?.parse().ok()?))
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
    let checked: Vec<usize> = (0..outcomes.len())
        .filter(|&k| {
            meets(&outcomes[k], ACCURACY_GOAL) == arrivals
                && missed[k].last_end.is_some()
                && optima.as_ref().is_none_or(|o| o.contains_key(&k))
        })
        .collect();
    let bar = ground_core::progress::bar(
        checked.len() as u64,
        &format!("{select} after missed thrust {{bar:30}} {{pos}}/{{len}} re-solved [{{elapsed}}<{{eta}}]"),
    );
    let verdicts: Vec<(Verdict, Option<(f64, f64)>)> = checked
        .par_iter()
        .map(|&k| {
            let scenario = &scenarios[k];
            let step = (missed[k].last_end.unwrap_or(1.0) * f64::from(scenario.steps)).round() as u32;
            let found = verdict(
                (&family, &units),
                (k, scenario, &outcomes[k]),
                step,
                &spacecraft,
                &options,
            );
            bar.inc(1);
            found
        })
        .collect();
    bar.finish_and_clear();
    // The fuel optimum burns as little as any arrival on time (its propellant is the burn time
    // at full thrust), so its coast time is the most thrust-off time an exact arrival on time
    // allows: a flight that lost more thrust than that could not have arrived by any control,
    // even one that knew its outages in advance (at the nominal thrust).
    let mass_flow = spacecraft.thrust / spacecraft.exhaust_speed;
    let optimum_coast_days = |k: usize| {
        let mass = optima.as_ref()?.get(&k)?;
        Some(units.to_days(scenarios[k].time_of_flight() - (1.0 - mass) / mass_flow))
    };
    if let Some(optima) = &optima {
        let beyond = |k: usize| optimum_coast_days(k).is_some_and(|coast| units.to_days(missed[k].time) > coast);
        let solved: Vec<usize> = (0..outcomes.len()).filter(|k| optima.contains_key(k)).collect();
        println!(
            "of {} draws solved from departure, {} lost more thrust than their optimum coasts; of the {} checked, {}",
            solved.len(),
            solved.iter().filter(|&&k| beyond(k)).count(),
            checked.len(),
            checked.iter().filter(|&&k| beyond(k)).count()
        );
    }
    let mut csv = String::from(
        "episode,dr,dv,last_missed_thrust_end,verdict,shortfall_days,shortfall_velocity_goals,missed_thrust_days,optimum_coast_days\n",
    );
    for (&k, (verdict, shortfall)) in checked.iter().zip(&verdicts) {
        let t = &outcomes[k].terminal;
        let end = missed[k].last_end.unwrap_or(f64::NAN);
        let shortfall = shortfall
            .map(|(d, g)| format!("{d:.3},{g:.3}"))
            .unwrap_or_else(|| ",".into());
        let missed_days = units.to_days(missed[k].time);
        let coast = optimum_coast_days(k).map(|d| format!("{d:.3}")).unwrap_or_default();
        let _ = writeln!(
            csv,
            "{k},{:.4e},{:.4e},{end},{verdict:?},{shortfall},{missed_days:.3},{coast}",
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
