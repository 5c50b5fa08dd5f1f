//! The commands of the indirect method in three dimensions: one rendezvous from a problem file,
//! and the check that planar draws keep their planar optima.

use std::path::{Path, PathBuf};

use ground_core::io::{atomic_write, require_parent_folder};
use ground_core::plot::check_svg_path;
use ground_core::solver::SolveOptions;
use ground_core::spatial::{
    compare_with_planar, missed_thrust_cases, missed_thrust_csv, plot_spatial_optimum, solve_posed, trajectory_csv,
    MissedThrustCase, PosedProblem, SpatialProblemSpec,
};
use shared::mission::MissionFamily;
use shared::spacecraft::Spacecraft;

use crate::trajectories::family_argument;

/// `ground data solve-3d`.
#[derive(clap::Args)]
pub struct Solve3dArgs {
    /// Problem file (docs/missions.md, "One rendezvous or transfer in three dimensions").
    #[arg(long)]
    problem: PathBuf,
    /// Print one JSON object instead of a summary.
    #[arg(long)]
    json: bool,
    /// Write optimum.json and trajectory.csv (401 epochs) into this folder (created if
    /// missing; its parent folder must exist), and missed-thrust.csv with --missed-thrust.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also lose the thrust for each of this many equal guidance cycles in turn and re-plan
    /// the rest of the flight to the same goal (arrival state or target orbit): the propellant
    /// each loss costs, or why the goal is out of reach.
    #[arg(long)]
    missed_thrust: Option<u32>,
    /// Plan to arrive this many of the --missed-thrust cycles early (a rendezvous meets its
    /// body where it is then) and coast with the target to the end: the plan reported, flown
    /// with each of its cycles lost, re-planned to the goal at its own time.
    #[arg(long, default_value_t = 0, requires = "missed_thrust")]
    arrival_margin: u32,
    /// Plan with this fraction of the thrust held back (in [0, 0.5]; flown at full thrust with
    /// the plan's throttle scaled): the plan reported, and with --missed-thrust its cycles lost
    /// re-planned at full thrust.
    #[arg(long, default_value_t = 0.0)]
    thrust_margin: f64,
    /// Also draw the optimum (the path on the xy-plane, z and the throttle against time, and
    /// the missed-thrust costs with --missed-thrust) into this SVG file (its folder must exist).
    #[arg(long)]
    plot: Option<PathBuf>,
}

/// `ground data check-3d`.
#[derive(clap::Args)]
pub struct Check3dArgs {
    /// A planar family: a preset's name or a mission file.
    #[arg(long, value_parser = family_argument)]
    scenario: MissionFamily,
    /// The stream the draws come from.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Draws 0..COUNT of the seed's stream.
    #[arg(long, default_value_t = 100)]
    count: u64,
    /// Largest relative difference of the final masses accepted.
    #[arg(long, default_value_t = 1e-8)]
    tolerance: f64,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
}

/// Solves a problem file's rendezvous or transfer and reports it.
pub fn solve_3d_command(args: &Solve3dArgs) -> Result<(), Box<dyn std::error::Error>> {
    let posed = SpatialProblemSpec::from_file(&args.problem)?.pose()?;
    // An output folder that cannot be made is refused before the solve, not after it.
    if let Some(out) = &args.out {
        require_parent_folder(out)?;
    }
    if args.missed_thrust == Some(0) {
        return Err("--missed-thrust must be a positive number of cycles".into());
    }
    if let Some(path) = &args.plot {
        check_svg_path(path)?;
        // The figure may go into the --out folder, made once the solve succeeds.
        let into_out = args.out.as_deref().is_some_and(|out| path.parent() == Some(out));
        if !into_out {
            require_parent_folder(path)?;
        }
    }
    let options = SolveOptions::default();
    if !(0.0..=0.5).contains(&args.thrust_margin) {
        return Err(format!("--thrust-margin must lie in [0, 0.5], not {}", args.thrust_margin).into());
    }
    let mut plan = match args.missed_thrust {
        Some(cycles) if args.arrival_margin > 0 => {
            if args.arrival_margin >= cycles {
                return Err(format!(
                    "--arrival-margin {} leaves no cycle of the {cycles} to fly",
                    args.arrival_margin
                )
                .into());
            }
            let by = posed.goal.time_of_flight() * f64::from(args.arrival_margin) / f64::from(cycles);
            PosedProblem {
                goal: posed.goal.arriving_early(by)?,
                ..posed
            }
        }
        _ => posed,
    };
    plan.goal = plan.goal.with_thrust_scaled(1.0 - args.thrust_margin);
    let (report, solved, samples) = solve_posed(&plan, &options)?;
    let missed = args
        .missed_thrust
        .map(|cycles| missed_thrust_cases(&posed, &solved, cycles, &options));
    if let Some(out) = &args.out {
        write_outputs(
            out,
            &serde_json::to_string_pretty(&report)?,
            &trajectory_csv(&posed, &samples),
        )?;
        if let Some(cases) = &missed {
            atomic_write(&out.join("missed-thrust.csv"), missed_thrust_csv(cases).as_bytes())?;
        }
    }
    if let Some(path) = &args.plot {
        plot_spatial_optimum(&posed, &solved.flight, &samples, missed.as_deref(), path)?;
    }
    if args.json {
        let mut value = serde_json::to_value(&report)?;
        if let Some(cases) = &missed {
            value["missed_thrust"] = serde_json::to_value(cases)?;
        }
        println!("{value}");
    } else {
        println!(
            "final mass: {:.4} kg (propellant {:.4} kg)\nthrust arcs: {} ({:.1} % of the flight)\n\
             final eps: {:.3e}\nresidual: {:.2e} ({:.3} m, {:.3e} m/s at arrival)\n\
             distinct energy optima: {}\nseconds: {:.2}",
            report.final_mass_kg,
            report.propellant_kg,
            report.thrust_arcs,
            100.0 * report.thrusting_share,
            report.final_eps,
            report.residual,
            report.position_miss_m,
            report.velocity_miss_m_s,
            report.distinct_energy_optima,
            report.seconds,
        );
        let profile: String = samples
            .iter()
            .step_by(4)
            .map(|s| match s.throttle {
                u if u > 0.99 => '#',
                u if u > 0.01 => '+',
                _ => '.',
            })
            .collect();
        println!("throttle: {profile}");
        if let Some(cases) = &missed {
            print_missed_thrust(cases);
        }
    }
    Ok(())
}

fn print_missed_thrust(cases: &[MissedThrustCase]) {
    println!("\nthrust lost for one cycle, the rest re-planned to the same arrival:");
    println!("cycle  from day  optimum thrusting  final mass (kg)  extra propellant (kg)");
    for c in cases {
        let outcome = match (c.final_mass_kg, c.extra_propellant_kg) {
            // A re-plan that finds the optimum again differs from it by round-off: no "-0.000".
            (Some(m), Some(extra)) => format!("{m:>15.3}  {:>21.3}", if extra.abs() < 5e-4 { 0.0 } else { extra }),
            _ => format!("  not reached: {}", c.failure.as_deref().unwrap_or("")),
        };
        println!(
            "{:>5}  {:>8.1}  {:>16.0} %  {outcome}",
            c.cycle,
            c.start_days,
            100.0 * c.optimum_thrusting_share
        );
    }
    let reached: Vec<f64> = cases.iter().filter_map(|c| c.extra_propellant_kg).collect();
    let worst = reached.iter().copied().fold(0.0, f64::max);
    println!(
        "{} of {} losses recovered; the worst recovered one costs {worst:.3} kg more propellant",
        reached.len(),
        cases.len()
    );
}

fn write_outputs(out: &Path, json: &str, csv: &str) -> std::io::Result<()> {
    std::fs::create_dir_all(out)?;
    atomic_write(&out.join("optimum.json"), json.as_bytes())?;
    atomic_write(&out.join("trajectory.csv"), csv.as_bytes())
}

/// Solves planar draws with both solvers; a failed check exits non-zero.
pub fn check_3d_command(args: &Check3dArgs) -> Result<(), Box<dyn std::error::Error>> {
    if !(args.tolerance.is_finite() && args.tolerance > 0.0) {
        return Err(format!("--tolerance must be positive, not {}", args.tolerance).into());
    }
    let spacecraft = Spacecraft::MSR_ERO
        .canonical_in(&args.scenario.body.units())
        .map_err(|e| format!("spacecraft: {e}"))?;
    let rows = compare_with_planar(
        &args.scenario,
        args.seed,
        0..args.count,
        &spacecraft,
        &SolveOptions::default(),
    );
    let both: Vec<f64> = rows.iter().filter_map(|r| r.relative_difference()).collect();
    let worst = both.iter().copied().fold(0.0, f64::max);
    let planar_only = rows
        .iter()
        .filter(|r| r.planar_mass.is_some() && r.spatial_mass.is_none())
        .count();
    let spatial_only = rows
        .iter()
        .filter(|r| r.planar_mass.is_none() && r.spatial_mass.is_some())
        .count();
    let differing = both.iter().filter(|&&d| d > args.tolerance).count();
    let passed = differing == 0 && planar_only == 0;
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "draws": rows.len(),
                "both_solved": both.len(),
                "planar_only": planar_only,
                "spatial_only": spatial_only,
                "differing": differing,
                "worst_relative_difference": worst,
                "tolerance": args.tolerance,
                "passed": passed,
                "rows": rows,
            })
        );
    } else {
        for r in &rows {
            let show = |m: Option<f64>| m.map_or_else(|| "-".to_string(), |m| format!("{m:.12}"));
            let diff = r
                .relative_difference()
                .map_or_else(|| "-".into(), |d| format!("{d:.1e}"));
            let why = r.spatial_failure.as_deref().unwrap_or("");
            println!(
                "#{:<4} planar {:>15}  3d {:>15}  rel. diff {diff:>8}  {why}",
                r.index,
                show(r.planar_mass),
                show(r.spatial_mass)
            );
        }
        println!(
            "{} draws: {} solved by both, worst relative difference {worst:.1e} (tolerance {:.0e}), \
             {differing} beyond it; planar only {planar_only}, 3d only {spatial_only}: {}",
            rows.len(),
            both.len(),
            args.tolerance,
            if passed { "passed" } else { "FAILED" }
        );
    }
    if passed {
        Ok(())
    } else {
        Err(format!(
            "the three-dimensional solver differs from the planar one on {} of {} draws",
            differing + planar_only,
            rows.len()
        )
        .into())
    }
}
