//! Is a transfer or rendezvous feasible in its time of flight? The minimum time of flight
//! (`solver::min_time`): with the anomaly on the target orbit free, a trajectory that reaches the
//! target orbit early can coast on it (and one that meets a rendezvous body early coasts beside
//! it), so a draw is infeasible exactly when its time of flight is below the minimum time tf_min.
//! `classify_draw` continues the energy-optimal problem from longer times of
//! flight down to the real one and runs a multi-start of the minimum-time problem (full thrust
//! along the primer vector); the verdict is "recovered" (an energy-optimal solution exists at
//! the time of flight: feasible) or the smallest minimum-time extremal found (a local minimum
//! time), compared with the time of flight.
//!
//! Run (the default is a 1.0 -> 1.52 AU circle raise in 8 steps, 112 days: infeasible, since
//! even the impulsive Hohmann delta-v takes longer at full thrust; about a minute):
//!
//! ```text
//! cargo run --release -p lowthrust-ground-core --example 03_minimum_time
//! cargo run --release -p lowthrust-ground-core --example 03_minimum_time -- --steps 30 --extremals
//! cargo run --release -p lowthrust-ground-core --example 03_minimum_time -- --scenario transfer-hard --seed 7 --index 47 --solve
//! cargo run --release -p lowthrust-ground-core --example 03_minimum_time -- --scenario rendezvous-hard --seed 7 --index 3
//! ```

use std::time::Instant;

use clap::Parser;
use ground_core::solver::bangbang::Hohmann;
use ground_core::solver::min_time::{
    classify_draw, multistart_extremals, reflown_extremal, rendezvous_multistart_extremals, Feasibility, MinTimeVector,
};
use ground_core::solver::{solve_from_energy_start, SolveOptions};
use shared::orbit::{OrbitElements, OrbitShape};
use shared::scenario::{ProblemKind, Scenario, ScenarioKind};
use shared::spacecraft::Spacecraft;
use shared::units::canonical_to_days;

/// Classify a transfer or rendezvous as feasible or infeasible by its minimum time of flight.
#[derive(Parser, Debug)]
struct Args {
    /// Draw the scenario from this distribution (transfer-circular, transfer-hard,
    /// rendezvous-circular or rendezvous-hard) instead of the explicit transfer below.
    #[arg(long)]
    scenario: Option<ScenarioKind>,
    /// Seed of the draw.
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Index of the draw.
    #[arg(long, default_value_t = 0)]
    index: u64,
    /// Explicit transfer: semi-major axis of the departure orbit (AU).
    #[arg(long, default_value_t = 1.0)]
    a0: f64,
    /// Explicit transfer: eccentricity of the departure orbit.
    #[arg(long, default_value_t = 0.0)]
    e0: f64,
    /// Explicit transfer: true anomaly at departure (deg).
    #[arg(long, default_value_t = 0.0)]
    nu0: f64,
    /// Explicit transfer: semi-major axis of the target orbit (AU).
    #[arg(long, default_value_t = 1.52)]
    af: f64,
    /// Explicit transfer: eccentricity of the target orbit.
    #[arg(long, default_value_t = 0.0)]
    ef: f64,
    /// Explicit transfer: time of flight in 14-day steps.
    #[arg(long, default_value_t = 8)]
    steps: u32,
    /// Also list every extremal of the minimum-time multi-start (local minimum times).
    #[arg(long)]
    extremals: bool,
    /// When the transfer is feasible, also run the fuel-optimal homotopy from the recovered
    /// energy-optimal start (the general path: for near-circular transfers see 01_solve_transfer).
    #[arg(long)]
    solve: bool,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    let (kind, scenario) = match args.scenario {
        Some(kind) => (kind, kind.draw(args.seed, args.index)),
        None => (ScenarioKind::TransferHard, explicit_transfer(&args)?),
    };
    let spacecraft = Spacecraft::MSR_ERO.canonical()?;
    let options = SolveOptions::default();
    let tof = scenario.time_of_flight();
    let days = canonical_to_days;
    println!(
        "{}: a {:.4} -> {:.4} AU, e {:.4} -> {:.4}, {} steps",
        kind.name(),
        scenario.initial.shape.a,
        scenario.target.a,
        scenario.initial.shape.e,
        scenario.target.e,
        scenario.steps
    );
    let row = |name: &str, value: String| println!("  {name:<32} {value}");
    row("time of flight", format!("{:.1} days", days(tof)));
    if scenario.initial.shape.e < 1e-3 && scenario.target.e < 1e-3 {
        // The impulsive Hohmann delta-v, spent at full thrust: no transfer between the two
        // circles is shorter.
        let hohmann = Hohmann::new(scenario.initial.shape.a, scenario.target.a, &spacecraft);
        row(
            "Hohmann delta-v at full thrust",
            format!("{:.1} days (a lower bound)", days(hohmann.burn[0] + hohmann.burn[1])),
        );
    }

    let clock = Instant::now();
    let verdict = classify_draw(&scenario, &spacecraft, &options);
    let seconds = clock.elapsed().as_secs_f64();
    match &verdict {
        Feasibility::Recovered { z } => {
            row("verdict", String::from("FEASIBLE (energy-optimal solution at the TOF)"));
            if scenario.problem == ProblemKind::Transfer {
                row(
                    "final anomaly of that solution",
                    format!("{:.2} deg", z[5].to_degrees()),
                );
            }
        }
        Feasibility::MinTime { tf_min, z, stopped_at } => {
            let class = if *tf_min > tof {
                "INFEASIBLE (tf_min > TOF)"
            } else {
                "feasible (tf_min < TOF), but no solution at the TOF"
            };
            row("verdict", class.into());
            row("minimum time tf_min", format!("{:.1} days", days(*tf_min)));
            row("tf_min / TOF", format!("{:.4}", tf_min / tof));
            let found_by = if stopped_at.is_nan() {
                String::from("minimum-time multi-start")
            } else {
                format!("continuation in TOF (stopped at {:.4} TOF)", stopped_at / tof)
            };
            row("extremal found by", found_by);
            let (y, error, h) = reflown_extremal(&scenario, &spacecraft, z, &options.tolerances)
                .map_err(|e| format!("re-flying the extremal failed: {e:?}"))?;
            row(
                "re-flown: terminal error, end condition",
                format!("{error:.1e}, {h:.1e}"),
            );
            row("mass at tf_min (full thrust)", format!("{:.4} m0", y[4]));
        }
        Feasibility::Unknown(why) => row("verdict", format!("UNDECIDED: {why}")),
    }
    row("classification time", format!("{seconds:.1} s"));

    if args.extremals {
        let clock = Instant::now();
        let found = match scenario.problem {
            ProblemKind::Transfer => multistart_extremals(&scenario, &spacecraft, &options.tolerances),
            ProblemKind::Rendezvous => rendezvous_multistart_extremals(&scenario, &spacecraft, &options.tolerances),
        };
        // The same extremal is reached from several guesses, its nu_f counted a whole number of
        // revolutions apart: one row per distinct (costates, tf), with its count.
        let mut distinct: Vec<(MinTimeVector, usize)> = Vec::new();
        for z in &found {
            let same =
                |d: &&mut (MinTimeVector, usize)| (0..5).all(|i| (z[i] - d.0[i]).abs() < 1e-6 * (1.0 + z[i].abs()));
            match distinct.iter_mut().find(same) {
                Some(d) => d.1 += 1,
                None => distinct.push((*z, 1)),
            }
        }
        println!(
            "\nminimum-time multi-start: {} extremals ({} distinct) in {:.1} s",
            found.len(),
            distinct.len(),
            clock.elapsed().as_secs_f64()
        );
        println!(
            "  {:>3} {:>10} {:>9} {:>12} {:>9} {:>6}",
            "#", "tf (days)", "tf / TOF", "nu_f (deg)", "error", "found"
        );
        for (i, (z, count)) in distinct.iter().enumerate() {
            let error = reflown_extremal(&scenario, &spacecraft, z, &options.tolerances).map_or(f64::NAN, |r| r.1);
            println!(
                "  {:>3} {:>10.1} {:>9.4} {:>12.1} {:>9.1e} {:>6}",
                i + 1,
                days(z[4]),
                z[4] / tof,
                // A rendezvous has no free final anomaly.
                match scenario.problem {
                    ProblemKind::Transfer => z[5].to_degrees().rem_euclid(360.0),
                    ProblemKind::Rendezvous => f64::NAN,
                },
                error,
                count
            );
        }
    }

    if let (true, Feasibility::Recovered { z }) = (args.solve, &verdict) {
        let record = solve_from_energy_start(kind, args.seed, args.index, &scenario, &spacecraft, &options, *z);
        println!(
            "\nfuel-optimal from the recovered start: converged {}, m_f {:.6}, eps {:.2e}, {} arcs, {:.1} s{}",
            record.converged,
            record.final_mass,
            record.final_eps,
            record.thrust_arcs,
            record.seconds,
            record.failure.map(|f| format!(" ({f})")).unwrap_or_default()
        );
    }
    Ok(())
}

/// A coaxial transfer (both arguments of periapsis 0) from the arguments, checked.
fn explicit_transfer(args: &Args) -> Result<Scenario, Box<dyn std::error::Error>> {
    let shape = |a, e| OrbitShape { a, e, omega: 0.0 };
    let initial = OrbitElements {
        shape: shape(args.a0, args.e0),
        nu: args.nu0.to_radians(),
    };
    let scenario = Scenario {
        steps: args.steps,
        ..Scenario::transfer(initial, shape(args.af, args.ef))
    };
    scenario.validate()?;
    Ok(scenario)
}
