//! One fuel-optimal low-thrust trajectory by the indirect method (`solver::solve_scenario`):
//! Pontryagin's conditions, single shooting from a multi-start at the energy-optimal cost, then
//! the energy-to-fuel homotopy down to the final eps. The orbits are given explicitly (AU, deg);
//! the time of flight is the rule of docs/spec.md section 4 (the longer period, rounded up to whole 14-day steps)
//! unless `--steps` sets it. Prints the outcome, the thrust arcs and the throttle profile.
//!
//! Run (the default is a transfer from a 1.0 AU circle to a 1.5 AU circle, a few seconds):
//!
//! ```text
//! cargo run --release -p lowthrust-ground-core --example 01_solve_transfer
//! cargo run --release -p lowthrust-ground-core --example 01_solve_transfer -- --af 0.8 --ef 0.1
//! cargo run --release -p lowthrust-ground-core --example 01_solve_transfer -- --rendezvous --nuf0 60
//! ```

use clap::Parser;
use ground_core::solver::bangbang::Hohmann;
use ground_core::solver::record::TrajectorySample;
use ground_core::solver::{circular, solve_scenario, SolveOptions};
use shared::orbit::{OrbitElements, OrbitShape};
use shared::scenario::{ProblemKind, Scenario, ScenarioKind};
use shared::spacecraft::Spacecraft;
use shared::units::canonical_to_days;

/// Solve one transfer (or rendezvous) between two explicit orbits.
#[derive(Parser, Debug)]
struct Args {
    /// Semi-major axis of the departure orbit (AU).
    #[arg(long, default_value_t = 1.0)]
    a0: f64,
    /// Eccentricity of the departure orbit.
    #[arg(long, default_value_t = 0.0)]
    e0: f64,
    /// Argument of periapsis of the departure orbit (deg).
    #[arg(long, default_value_t = 0.0)]
    omega0: f64,
    /// True anomaly at departure (deg).
    #[arg(long, default_value_t = 0.0)]
    nu0: f64,
    /// Semi-major axis of the target orbit (AU).
    #[arg(long, default_value_t = 1.5)]
    af: f64,
    /// Eccentricity of the target orbit.
    #[arg(long, default_value_t = 0.0)]
    ef: f64,
    /// Argument of periapsis of the target orbit (deg).
    #[arg(long, default_value_t = 0.0)]
    omegaf: f64,
    /// Rendezvous with a body on the target orbit instead of reaching any point of it.
    #[arg(long)]
    rendezvous: bool,
    /// Rendezvous: the target body's true anomaly at departure (deg).
    #[arg(long, default_value_t = 45.0)]
    nuf0: f64,
    /// Time of flight in 14-day steps (default: the rule of docs/spec.md section 4).
    #[arg(long)]
    steps: Option<u32>,
    /// Stop the homotopy at the first eps below this (docs/spec.md: 1e-4).
    #[arg(long)]
    final_eps: Option<f64>,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    let scenario = scenario_of(&args)?;
    let spacecraft = Spacecraft::MSR_ERO;
    let canonical = spacecraft.canonical()?;
    let mut options = SolveOptions::default();
    if let Some(eps) = args.final_eps {
        if !(eps > 0.0 && eps <= 1.0) {
            return Err(format!("--final-eps must lie in (0, 1], got {eps}").into());
        }
        options.final_eps = eps;
    }
    // The kind is only a label of the record here; the "hard" kinds take the general path (with
    // the near-circular path tried first where both orbits are nearly circular).
    let kind = match scenario.problem {
        ProblemKind::Transfer => ScenarioKind::TransferHard,
        ProblemKind::Rendezvous => ScenarioKind::RendezvousHard,
    };
    let tof = scenario.time_of_flight();
    println!(
        "{:?}: a {:.4} -> {:.4} AU, e {:.4} -> {:.4}, {} steps ({:.0} days); spacecraft {} N, Isp {} s, {} kg",
        scenario.problem,
        scenario.initial.shape.a,
        scenario.target.a,
        scenario.initial.shape.e,
        scenario.target.e,
        scenario.steps,
        canonical_to_days(tof),
        spacecraft.max_thrust_n,
        spacecraft.isp_s,
        spacecraft.initial_mass_kg
    );

    let record = solve_scenario(kind, 0, 0, &scenario, &canonical, &options);

    let row = |name: &str, value: String| println!("  {name:<24} {value}");
    row("converged", record.converged.to_string());
    if let Some(why) = &record.failure {
        row("failure", why.clone());
    }
    row("final eps", format!("{:.3e}", record.final_eps));
    row("terminal residual", format!("{:.2e}", record.residual));
    row(
        "final mass",
        format!(
            "{:.6} m0 ({:.1} kg of propellant)",
            record.final_mass,
            (1.0 - record.final_mass) * spacecraft.initial_mass_kg
        ),
    );
    if scenario.problem == ProblemKind::Transfer && scenario.initial.shape.e < 1e-3 && scenario.target.e < 1e-3 {
        let bound = Hohmann::new(scenario.initial.shape.a, scenario.target.a, &canonical).final_mass;
        row("impulsive Hohmann bound", format!("{bound:.6} m0 (an upper bound)"));
    }
    if let Some(nu_f) = record.final_anomaly {
        row("final anomaly", format!("{:.2} deg", nu_f.to_degrees()));
    }
    row("thrust arcs", record.thrust_arcs.to_string());
    // A solve by the near-circular path (a structured bang-bang solve) reports no multi-start.
    let path = if record.converged && record.distinct_energy_optima == 0 && circular::applies(&scenario) {
        String::from("near-circular bang-bang structure")
    } else {
        format!(
            "multi-start ({} distinct energy optima) + homotopy",
            record.distinct_energy_optima
        )
    };
    row("solver path", path);
    row("solve time", format!("{:.2} s", record.seconds));
    if record.ephemeris.is_empty() {
        return Ok(());
    }

    println!(
        "\nthrust arcs (u > 1/2 on the {}-point ephemeris):",
        record.ephemeris.len()
    );
    println!(
        "  {:>3} {:>10} {:>10} {:>10} {:>12}",
        "arc", "start (d)", "end (d)", "days", "dm (m0)"
    );
    for (i, (start, end)) in thrust_arcs(&record.ephemeris).into_iter().enumerate() {
        println!(
            "  {:>3} {:>10.1} {:>10.1} {:>10.1} {:>12.6}",
            i + 1,
            canonical_to_days(start.t),
            canonical_to_days(end.t),
            canonical_to_days(end.t - start.t),
            start.m - end.m
        );
    }

    // The throttle at the 14-day step boundaries, runs of equal throttle on one row with the
    // radius (AU) and mass (m0) at the end of the run.
    println!("\nthrottle profile at the 14-day step boundaries:");
    println!(
        "  {:>7} {:>11} {:>7} {:>8} {:>9}  throttle",
        "steps", "days", "u", "r_end", "m_end"
    );
    let mut first = 0;
    for (k, s) in record.steps.iter().enumerate() {
        let same = |o: &TrajectorySample| (o.throttle - s.throttle).abs() < 1e-3;
        if record.steps.get(k + 1).is_some_and(same) {
            continue;
        }
        let start = &record.steps[first];
        println!(
            "  {:>7} {:>11} {:>7.4} {:>8.4} {:>9.6}  {}",
            format!("{first}-{k}"),
            format!("{:.0}-{:.0}", canonical_to_days(start.t), canonical_to_days(s.t)),
            s.throttle,
            s.r[0].hypot(s.r[1]),
            s.m,
            "#".repeat((s.throttle * 20.0).round() as usize)
        );
        first = k + 1;
    }
    Ok(())
}

/// The scenario of the arguments, checked.
fn scenario_of(args: &Args) -> Result<Scenario, Box<dyn std::error::Error>> {
    let initial = OrbitElements {
        shape: OrbitShape {
            a: args.a0,
            e: args.e0,
            omega: args.omega0.to_radians(),
        },
        nu: args.nu0.to_radians(),
    };
    let target = OrbitShape {
        a: args.af,
        e: args.ef,
        omega: args.omegaf.to_radians(),
    };
    let mut scenario = Scenario::transfer(initial, target);
    if args.rendezvous {
        scenario.problem = ProblemKind::Rendezvous;
        scenario.target_nu0 = args.nuf0.to_radians();
    }
    if let Some(steps) = args.steps {
        scenario.steps = steps;
    }
    scenario.validate()?;
    Ok(scenario)
}

/// The first and last sample of every maximal run with u > 1/2.
fn thrust_arcs(samples: &[TrajectorySample]) -> Vec<(TrajectorySample, TrajectorySample)> {
    let mut arcs = Vec::new();
    let mut open: Option<(TrajectorySample, TrajectorySample)> = None;
    for s in samples {
        match (&mut open, s.throttle > 0.5) {
            (None, true) => open = Some((*s, *s)),
            (Some(arc), true) => arc.1 = *s,
            (Some(_), false) => arcs.extend(open.take()),
            (None, false) => {}
        }
    }
    arcs.extend(open);
    arcs
}
