//! The indirect optimum checked by an independent method: the same scenario solved by the
//! indirect solver (`solver::solve_scenario`, costates and shooting) and by the direct
//! transcription (`solver::direct`: piecewise-constant controls on K segments, sequential
//! quadratic programming, no costates), on the same cost functional (the indirect record's final
//! eps). The direct solution is refined on meshes K, 2K, 4K, ...; its final mass converges to the
//! indirect one from below as the control gets more freedom.
//!
//! Run (the default is the 1.0 -> 1.5 AU circle-to-circle transfer on 96, 192 and 384 segments,
//! a few seconds):
//!
//! ```text
//! cargo run --release -p lowthrust-ground-core --example 02_direct_crosscheck
//! cargo run --release -p lowthrust-ground-core --example 02_direct_crosscheck -- --scenario transfer-hard --seed 1 --index 1
//! cargo run --release -p lowthrust-ground-core --example 02_direct_crosscheck -- --start indirect --segments-per-step 1
//! ```
//!
//! `ground data crosscheck` runs the same check (tangential start) over every record of a dataset.

use clap::{Parser, ValueEnum};
use ground_core::solver::direct::{solve_direct_refined, DirectGuess, DirectOptions, DirectSolution};
use ground_core::solver::{solve_scenario, SolveOptions};
use shared::orbit::{OrbitElements, OrbitShape};
use shared::scenario::{Scenario, ScenarioKind};
use shared::spacecraft::Spacecraft;
use shared::units::canonical_to_days;

/// Solve one scenario by the indirect and the direct method and compare the final masses.
#[derive(Parser, Debug)]
struct Args {
    /// Draw the scenario from this distribution (transfer-circular, transfer-hard,
    /// rendezvous-circular, rendezvous-hard) instead of the explicit orbits below.
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
    /// Explicit transfer: semi-major axis of the target orbit (AU).
    #[arg(long, default_value_t = 1.5)]
    af: f64,
    /// Explicit transfer: eccentricity of the target orbit.
    #[arg(long, default_value_t = 0.0)]
    ef: f64,
    /// Direct segments per 14-day step on the first mesh.
    #[arg(long, default_value_t = 2)]
    segments_per_step: usize,
    /// Number of meshes (each twice as fine as the one before, warm-started from it).
    #[arg(long, default_value_t = 3)]
    levels: usize,
    /// First guess of the direct method.
    #[arg(long, value_enum, default_value_t = Start::Tangential)]
    start: Start,
}

/// Where the direct method starts.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum Start {
    /// Tangential thrust at half throttle: nothing taken from the indirect solution.
    Tangential,
    /// The indirect solution's control sampled at the segment midpoints.
    Indirect,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    if args.segments_per_step == 0 || args.levels == 0 {
        return Err("--segments-per-step and --levels must be at least 1".into());
    }
    let (kind, scenario) = match args.scenario {
        Some(kind) => (kind, kind.draw(args.seed, args.index)),
        None => (ScenarioKind::TransferHard, explicit_transfer(&args)?),
    };
    let spacecraft = Spacecraft::MSR_ERO.canonical()?;
    println!(
        "{:?}: a {:.4} -> {:.4} AU, e {:.4} -> {:.4}, {} steps ({:.0} days)",
        scenario.problem,
        scenario.initial.shape.a,
        scenario.target.a,
        scenario.initial.shape.e,
        scenario.target.e,
        scenario.steps,
        canonical_to_days(scenario.time_of_flight())
    );

    let record = solve_scenario(
        kind,
        args.seed,
        args.index,
        &scenario,
        &spacecraft,
        &SolveOptions::default(),
    );
    if !record.converged {
        println!(
            "note: the indirect solve did not converge ({}); compared at eps = {:.3e}",
            record.failure.as_deref().unwrap_or("no reason given"),
            record.final_eps
        );
    }
    let eps = record.final_eps;

    println!(
        "\n{:<10} {:>6} {:>10} {:>12} {:>10} {:>9} {:>9} {:>5} {:>8}",
        "method", "K", "eps", "m_f (m0)", "rel. diff", "violation", "onboard", "iter", "time (s)"
    );
    println!(
        "{:<10} {:>6} {:>10.3e} {:>12.9} {:>10} {:>9.1e} {:>9} {:>5} {:>8.2}",
        "indirect", "-", eps, record.final_mass, "-", record.residual, "-", "-", record.seconds
    );
    let options = DirectOptions::default();
    let k0 = args.segments_per_step * scenario.steps as usize;
    let guess = match args.start {
        Start::Tangential => DirectGuess::tangential(&scenario, &spacecraft, k0, 0.5, &options.tolerances)?,
        Start::Indirect => DirectGuess::from_record(&record, &spacecraft, k0, &SolveOptions::default().tolerances)
            .map_err(|e| format!("sampling the indirect control failed: {e:?}"))?,
    };
    let solutions = solve_direct_refined(&scenario, &spacecraft, guess, args.levels - 1, eps, &options)?;
    for solution in &solutions {
        print_direct(solution, record.final_mass);
    }
    let masses: Vec<f64> = solutions.iter().map(|s| s.final_mass).collect();
    // Richardson extrapolation of the last three meshes: the mesh-converged direct mass.
    if let [.., a, b, c] = masses[..] {
        let order = ((b - a) / (c - b)).abs().log2();
        let limit = c + (c - b) / (2f64.powf(order) - 1.0);
        println!(
            "{:<10} {:>6} {:>10} {:>12.9} {:>+10.2e}   (observed order {order:.2})",
            "richardson",
            "inf",
            "",
            limit,
            (limit - record.final_mass) / record.final_mass
        );
    }
    println!("\nrel. diff = (direct - indirect) / indirect; violation: largest terminal-condition error");
    println!("(canonical; indirect: its shooting residual); onboard: the direct controls re-flown by the");
    println!("onboard zero-order-hold propagator.");
    Ok(())
}

fn print_direct(s: &DirectSolution, indirect_mass: f64) {
    let method = if s.converged { "direct" } else { "direct (!)" };
    println!(
        "{:<10} {:>6} {:>10.3e} {:>12.9} {:>+10.2e} {:>9.1e} {:>9.1e} {:>5} {:>8.2}",
        method,
        s.segments,
        s.eps,
        s.final_mass,
        (s.final_mass - indirect_mass) / indirect_mass,
        s.infeasibility,
        s.onboard_infeasibility,
        s.iterations,
        s.seconds
    );
}

/// A circle-to-circle (or eccentric, coaxial) transfer from the arguments, checked.
fn explicit_transfer(args: &Args) -> Result<Scenario, Box<dyn std::error::Error>> {
    let shape = |a, e| OrbitShape { a, e, omega: 0.0 };
    let initial = OrbitElements {
        shape: shape(args.a0, args.e0),
        nu: 0.0,
    };
    let scenario = Scenario::transfer(initial, shape(args.af, args.ef));
    scenario.validate()?;
    Ok(scenario)
}
