//! The commands that need no PyTorch: one solve, dataset generation and merge, OEM export,
//! the demonstrations' one-step check.

use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};

use ground_core::crosscheck::{crosscheck_records, write_crosscheck_csv, CrossCheck, CrossCheckSettings};
use ground_core::generate::{
    generate_in, hold_run, holds_spatial_records, merge, read_dataset, read_dataset_of, trajectory_difference,
    DatasetFamily, DatasetRecord, GenerateError, Manifest, Shard, Summary,
};
use ground_core::io::{atomic_write, require_parent_folder, RunLock};
use ground_core::mission::FamilySpec;
use ground_core::oem::{oem_string, write_thrust_csv, CalendarEpoch, OemOptions, OemSource};
use ground_core::plot::{check_svg_path, plot_dataset_sample, plot_trajectories};
use ground_core::solver::direct::DirectError;
use ground_core::solver::shooting::FINAL_EPS;
use ground_core::solver::{solve_scenario, SolveOptions};
use shared::mission::{MissionFamily, SpatialFamily};
use shared::orbit::{OrbitElements, OrbitShape};
use shared::scenario::{ProblemKind, Scenario, ScenarioKind};
use shared::spacecraft::{CanonicalSpacecraft, Spacecraft};
use shared::units::canonical_to_days;

/// `ground data solve`: one fuel-optimal case from explicit orbits or from a scenario draw.
#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
pub struct SolveArgs {
    /// Draw the case from this scenario family (a preset's name or a mission file; with --seed
    /// and --index) instead of giving the orbits explicitly.
    #[arg(long, value_parser = family_argument)]
    scenario: Option<MissionFamily>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long, default_value_t = 0)]
    index: u64,
    /// Initial orbit: semi-major axis (AU), eccentricity, argument of periapsis and true anomaly (deg).
    #[arg(long)]
    a0: Option<f64>,
    #[arg(long, default_value_t = 1e-4)]
    e0: f64,
    #[arg(long, default_value_t = 0.0)]
    omega0: f64,
    #[arg(long, default_value_t = 0.0)]
    nu0: f64,
    /// Target orbit: semi-major axis (AU), eccentricity, argument of periapsis (deg).
    #[arg(long)]
    af: Option<f64>,
    #[arg(long, default_value_t = 1e-4)]
    ef: f64,
    #[arg(long, default_value_t = 0.0)]
    omegaf: f64,
    /// Rendezvous with a body starting at true anomaly --nuf0 (deg) on the target orbit.
    #[arg(long)]
    rendezvous: bool,
    #[arg(long, default_value_t = 0.0)]
    nuf0: f64,
    /// Time of flight in days (default: docs/spec.md section 4, max of the two periods rounded up to
    /// whole 14-day steps). Must be a positive whole number of 14-day steps.
    #[arg(long)]
    tof_days: Option<f64>,
    /// Print one JSON object instead of a summary.
    #[arg(long)]
    json: bool,
    /// Also draw the trajectory with its initial and target orbits into this SVG file (its
    /// folder must exist).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// The spacecraft the case is solved for.
    #[command(flatten)]
    spacecraft: SpacecraftArgs,
}

/// `--scenario`: a preset's name or a mission file, checked.
pub fn family_argument(text: &str) -> Result<MissionFamily, String> {
    FamilySpec::from_argument(text)
        .and_then(|spec| spec.family())
        .map_err(|e| e.to_string())
}

/// `--scenario` of the commands that take inclined families too, checked.
pub fn spatial_family_argument(text: &str) -> Result<SpatialFamily, String> {
    FamilySpec::from_argument(text)
        .and_then(|spec| spec.spatial_family())
        .map_err(|e| e.to_string())
}

#[derive(clap::Args)]
pub struct GenerateArgs {
    /// The scenario family: a preset's name (transfer-circular, transfer-hard,
    /// rendezvous-circular, rendezvous-hard) or a mission file (docs/missions.md).
    #[arg(long, value_parser = spatial_family_argument)]
    scenario: SpatialFamily,
    #[arg(long)]
    count: u64,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Run folder (created if missing; its parent folder must exist).
    #[arg(long)]
    out: PathBuf,
    /// Solve only shard I of N (indices i with i mod N == I).
    #[arg(long, default_value = "0/1")]
    shard: Shard,
    /// Worker threads, at least 1 (default: all cores).
    #[arg(long, value_parser = thread_count)]
    threads: Option<NonZeroUsize>,
    /// Stop the homotopy at the first level below this eps (docs/spec.md: 1e-4).
    #[arg(long, default_value_t = FINAL_EPS)]
    final_eps: f64,
    /// Solve each draw to arrive this many guidance cycles early (then coasting with its target),
    /// where that converges, on time otherwise: a reserve for thrust lost late in the flight.
    #[arg(long, default_value_t = 0)]
    arrival_margin: u32,
    /// The spacecraft the draws are solved for (recorded in the folder's request.json; a
    /// learner refuses a dataset solved for another than its config's).
    #[command(flatten)]
    spacecraft: SpacecraftArgs,
}

/// `ground data check-mission`: a family checked on a sample of its draws.
#[derive(clap::Args)]
pub struct CheckMissionArgs {
    /// The scenario family: a preset's name or a mission file (docs/missions.md), planar or
    /// inclined.
    #[arg(long, value_parser = spatial_family_argument)]
    scenario: SpatialFamily,
    /// Draws to solve and classify.
    #[arg(long, default_value_t = 20)]
    sample: u64,
    /// Seed of the draws.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[command(flatten)]
    spacecraft: SpacecraftArgs,
    /// Records of the dataset whose generation time is projected.
    #[arg(long, default_value_t = 1000)]
    dataset_count: u64,
    /// Worker threads, at least 1 (default: all cores).
    #[arg(long, value_parser = thread_count)]
    threads: Option<NonZeroUsize>,
    /// Print one JSON object instead of the summary.
    #[arg(long)]
    json: bool,
}

/// `ground data check-mission`: exit status 1 when no draw of the sample was solved.
pub fn check_mission_command(args: &CheckMissionArgs) -> Result<(), Box<dyn std::error::Error>> {
    let sc = args.spacecraft.canonical_in(&args.scenario.family)?;
    if args.sample == 0 {
        return Err("--sample must be at least 1".into());
    }
    if let Some(n) = args.threads {
        rayon::ThreadPoolBuilder::new().num_threads(n.get()).build_global()?;
    }
    let check =
        ground_core::mission::check_family(&args.scenario, &sc, args.sample, args.seed, &SolveOptions::default());
    let threads = rayon::current_num_threads();
    let projected_min = check.solve_seconds[0] * args.dataset_count as f64 / threads as f64 / 60.0;
    if args.json {
        let mut value = serde_json::to_value(&check)?;
        value["projected_dataset_minutes"] = serde_json::json!(projected_min);
        value["threads"] = serde_json::json!(threads);
        println!("{value}");
    } else {
        for line in ground_core::mission::check_lines(&check) {
            println!("{line}");
        }
        println!(
            "a dataset of {} draws: about {projected_min:.1} min on {threads} threads (a whole recipe, stage by stage: ground run --config RECIPE --plan)",
            args.dataset_count
        );
    }
    if check.converged == 0 {
        return Err(format!("no draw of the sample of {} was solved", check.family).into());
    }
    Ok(())
}

/// `--thrust-n`, `--isp-s` and `--mass-kg`: a spacecraft (default: the thesis's, as configs
/// default). A dataset records the spacecraft it was solved for (its request.json): a command
/// that reads one refuses another ([`SpacecraftArgs::for_dataset`]).
#[derive(clap::Args)]
pub struct SpacecraftArgs {
    /// Maximum thrust, N.
    #[arg(long, default_value_t = Spacecraft::MSR_ERO.max_thrust_n)]
    thrust_n: f64,
    /// Specific impulse, s.
    #[arg(long, default_value_t = Spacecraft::MSR_ERO.isp_s)]
    isp_s: f64,
    /// Initial mass, kg.
    #[arg(long, default_value_t = Spacecraft::MSR_ERO.initial_mass_kg)]
    mass_kg: f64,
}

impl SpacecraftArgs {
    /// The spacecraft as given.
    fn physical(&self) -> Spacecraft {
        Spacecraft {
            max_thrust_n: self.thrust_n,
            isp_s: self.isp_s,
            initial_mass_kg: self.mass_kg,
        }
    }

    /// The spacecraft in the canonical units of `family`'s central body, checked.
    fn canonical_in(&self, family: &MissionFamily) -> Result<CanonicalSpacecraft, String> {
        self.physical()
            .canonical_in(&family.body.units())
            .map_err(|e| format!("spacecraft: {e}"))
    }

    /// [`Self::canonical_in`] for the records of the dataset file `file`, refused when the
    /// dataset records that they were solved for another spacecraft.
    fn for_dataset(
        &self,
        file: &Path,
        family: &MissionFamily,
    ) -> Result<CanonicalSpacecraft, Box<dyn std::error::Error>> {
        let spacecraft = self.canonical_in(family)?;
        ground_core::generate::check_dataset_spacecraft(file, &spacecraft)?;
        Ok(spacecraft)
    }
}

/// `--threads`: a whole number, at least 1 (rayon would read 0 as "all cores").
fn thread_count(text: &str) -> Result<NonZeroUsize, String> {
    text.parse::<usize>()
        .ok()
        .and_then(NonZeroUsize::new)
        .ok_or_else(|| format!("need a whole number of threads, at least 1, got '{text}'"))
}

pub fn generate_command(args: &GenerateArgs) -> Result<(), Box<dyn std::error::Error>> {
    let sc = args.spacecraft.canonical_in(&args.scenario.family)?;
    let options = SolveOptions {
        final_eps: args.final_eps,
        arrival_margin_steps: args.arrival_margin,
        ..SolveOptions::default()
    };
    if let Some(n) = args.threads {
        rayon::ThreadPoolBuilder::new().num_threads(n.get()).build_global()?;
    }
    let Some(planar) = args.scenario.as_planar() else {
        // An inclined family: records of the three-dimensional solver, one drawn.
        let (_held, summary) = generate_family(args.scenario, args, &sc, &options)?;
        print_summary(&summary);
        if ground_core::spatial::plot_spatial_dataset_sample(&args.out, args.shard, &args.spacecraft.physical())? > 0 {
            println!(
                "plotted the first solved trajectory in {}",
                args.out.join("trajectories.svg").display()
            );
        }
        return Ok(());
    };
    let (_held, summary) = generate_family(planar, args, &sc, &options)?;
    print_summary(&summary);
    // A few solved trajectories on one figure (thesis Fig. 4.4/4.5).
    let shown = plot_dataset_sample(&args.out, args.shard)?;
    if shown > 0 {
        println!(
            "plotted {shown} trajectories in {}",
            args.out.join("trajectories.svg").display()
        );
    }
    Ok(())
}

/// Checks the request and the folder, holds it, and generates the family's records into it;
/// the folder stays held while the caller keeps the hold (its figure is written under it).
fn generate_family<F: DatasetFamily>(
    family: F,
    args: &GenerateArgs,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> Result<(RunLock, Summary), GenerateError> {
    let manifest = Manifest {
        family,
        seed: args.seed,
        count: args.count,
    };
    let run = hold_run(manifest, args.shard, &args.out, spacecraft, options)?;
    let summary = generate_in(&run, manifest, args.shard, spacecraft, options, true)?;
    Ok((run, summary))
}

pub fn oem_command(dataset: &Path, index: u64, out: &Path, departure: &str) -> Result<(), Box<dyn std::error::Error>> {
    if holds_spatial_records(dataset)? {
        oem_of::<SpatialFamily>(dataset, index, out, departure)
    } else {
        oem_of::<MissionFamily>(dataset, index, out, departure)
    }
}

/// [`oem_command`] on a dataset of family kind `F`.
fn oem_of<F: DatasetFamily>(
    dataset: &Path,
    index: u64,
    out: &Path,
    departure: &str,
) -> Result<(), Box<dyn std::error::Error>>
where
    F::Record: OemSource,
{
    let file = read_dataset_of::<F>(dataset)?;
    let record = file
        .records
        .iter()
        .find(|r| r.figures().index == index)
        .ok_or_else(|| format!("{} has no record with index {index}", dataset.display()))?;
    let options = OemOptions::new(departure.parse::<CalendarEpoch>()?);
    let oem = oem_string(record, &options)?;
    let mut csv = Vec::new();
    write_thrust_csv(record, &options, &mut csv)?;
    let oem_path = out.join(format!("trajectory-{index}.oem"));
    let csv_path = out.join(format!("trajectory-{index}-thrust.csv"));
    atomic_write(&oem_path, oem.as_bytes()).map_err(|e| format!("{}: {e}", oem_path.display()))?;
    atomic_write(&csv_path, &csv).map_err(|e| format!("{}: {e}", csv_path.display()))?;
    println!("wrote {} and {}", oem_path.display(), csv_path.display());
    Ok(())
}

pub fn print_summary(s: &Summary) {
    println!(
        "{} seed {} shard {}/{}: {} records, {} converged ({:.1} %), solve time mean {:.2} s median {:.2} s max {:.2} s",
        s.scenario,
        s.seed,
        s.shard.index,
        s.shard.count,
        s.records,
        s.converged,
        100.0 * s.convergence_rate,
        s.seconds_mean,
        s.seconds_median,
        s.seconds_max
    );
    if s.converged > 0 {
        println!(
            "final mass: mean {:.4} std {:.4} min {:.4} max {:.4}",
            s.final_mass_mean, s.final_mass_std, s.final_mass_min, s.final_mass_max
        );
    }
    for (index, reason) in s.failures.iter().take(10) {
        println!("  failed #{index}: {reason}");
    }
}

fn scenario_from_args(args: &SolveArgs) -> Result<(MissionFamily, Scenario), String> {
    if let Some(family) = args.scenario {
        return Ok((family, family.draw(args.seed, args.index)));
    }
    let (Some(a0), Some(af)) = (args.a0, args.af) else {
        return Err("give either --scenario NAME (with --seed/--index) or at least --a0 and --af".into());
    };
    let initial = OrbitElements {
        shape: OrbitShape {
            a: a0,
            e: args.e0,
            omega: args.omega0.to_radians(),
        },
        nu: args.nu0.to_radians(),
    };
    let target = OrbitShape {
        a: af,
        e: args.ef,
        omega: args.omegaf.to_radians(),
    };
    initial.validate().map_err(|e| format!("initial orbit: {e}"))?;
    target.validate().map_err(|e| format!("target orbit: {e}"))?;
    let steps = match args.tof_days {
        None => Scenario::steps_for(&initial.shape, &target),
        Some(days) => {
            let n = days / 14.0;
            if !(days.is_finite() && days > 0.0) || (n - n.round()).abs() > 1e-9 || n.round() > f64::from(u32::MAX) {
                return Err(format!(
                    "--tof-days must be a positive whole number of 14-day steps, got {days}"
                ));
            }
            n.round() as u32
        }
    };
    let (problem, kind) = if args.rendezvous {
        (ProblemKind::Rendezvous, ScenarioKind::RendezvousHard)
    } else {
        (ProblemKind::Transfer, ScenarioKind::TransferHard)
    };
    let scenario = Scenario {
        problem,
        initial,
        target,
        target_nu0: args.nuf0.to_radians(),
        steps,
        cycle: shared::units::STEP,
    };
    scenario.validate().map_err(|e| e.to_string())?;
    Ok((kind.family(), scenario))
}

pub fn solve_command(args: &SolveArgs) -> Result<(), Box<dyn std::error::Error>> {
    let (kind, scenario) = scenario_from_args(args)?;
    let sc = args.spacecraft.canonical_in(&kind)?;
    // A figure path that cannot be written is refused before the solve, not after it.
    if let Some(path) = &args.plot {
        check_svg_path(path)?;
        require_parent_folder(path)?;
    }
    let record = solve_scenario(kind, args.seed, args.index, &scenario, &sc, &SolveOptions::default());
    if let Some(path) = &args.plot {
        plot_trajectories(&[&record], path)?;
    }
    if args.json {
        let summary = serde_json::json!({
            "converged": record.converged,
            "failure": record.failure,
            "final_mass": record.final_mass,
            "thrust_arcs": record.thrust_arcs,
            "final_eps": record.final_eps,
            "residual": record.residual,
            "seconds": record.seconds,
            "costates": record.costates,
            "final_anomaly_deg": record.final_anomaly.map(f64::to_degrees),
            "distinct_energy_optima": record.distinct_energy_optima,
            "steps": scenario.steps,
            "tof_days": canonical_to_days(scenario.time_of_flight()),
        });
        println!("{summary}");
    } else {
        println!(
            "converged: {} ({})\nfinal mass: {:.6} m0\nthrust arcs: {}\nfinal eps: {:.3e}\nresidual: {:.2e}\nseconds: {:.3}\ncostates: {:?}",
            record.converged,
            record.failure.as_deref().unwrap_or("ok"),
            record.final_mass,
            record.thrust_arcs,
            record.final_eps,
            record.residual,
            record.seconds,
            record.costates
        );
        let profile: String = record
            .ephemeris
            .iter()
            .map(|s| match s.throttle {
                u if u > 0.99 => '#',
                u if u > 0.01 => '+',
                _ => '.',
            })
            .collect();
        println!("throttle over the flight (100 epochs, # full, + partial, . off):\n{profile}");
    }
    Ok(())
}

pub fn merge_command(inputs: &[PathBuf], out: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let summary = merge(inputs, out)?;
    print_summary(&summary);
    Ok(())
}

pub fn compare_command(first: &Path, second: &Path) -> Result<(), Box<dyn std::error::Error>> {
    if holds_spatial_records(first)? {
        compare_of::<SpatialFamily>(first, second)
    } else {
        compare_of::<MissionFamily>(first, second)
    }
}

/// [`compare_command`] of two datasets of family kind `F` (a file of the other kind is refused).
fn compare_of<F: DatasetFamily>(first: &Path, second: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let (a, b) = (read_dataset_of::<F>(first)?, read_dataset_of::<F>(second)?);
    match trajectory_difference(&a, &b) {
        None => {
            println!(
                "{} and {}: the same {} trajectories",
                first.display(),
                second.display(),
                a.records.len()
            );
            Ok(())
        }
        Some(difference) => Err(format!("{} and {} differ: {difference}", first.display(), second.display()).into()),
    }
}

/// `ground data crosscheck`: the converged records of a dataset against the direct transcription.
#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
pub struct CrossCheckArgs {
    /// Dataset file, or the folder of a `ground data generate` run.
    #[arg(long)]
    dataset: PathBuf,
    /// Check the first N converged records (all when absent).
    #[arg(long)]
    count: Option<NonZeroUsize>,
    /// Direct segments per 14-day step of the first mesh.
    #[arg(long, default_value = "1")]
    segments_per_step: NonZeroUsize,
    /// Meshes after the first, each twice as fine (warm-started from the one before).
    #[arg(long, default_value_t = 0)]
    refinements: usize,
    /// A direct final mass above the record's by more than this (fraction of the initial
    /// mass) marks the record a worse local optimum.
    #[arg(long, default_value_t = 1e-3)]
    margin: f64,
    /// Write one row per record here (CSV; its folder must exist).
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Re-solve each record a direct solution beats from that solution, and replace it when the
    /// result converges heavier by the margin, or else cut it from the demonstrations (the
    /// dataset and summaries are rewritten; --dataset must be a run folder of a planar family).
    #[arg(long)]
    repair: bool,
    /// The spacecraft the dataset was solved with (another makes the direct solution differ
    /// from the records for that reason alone).
    #[command(flatten)]
    spacecraft: SpacecraftArgs,
}

pub fn crosscheck_command(args: &CrossCheckArgs) -> Result<(), Box<dyn std::error::Error>> {
    use ground_core::generate::{crosscheck_run, run_solve_options};
    if !(args.margin.is_finite() && args.margin >= 0.0) {
        return Err(format!("--margin must be a finite number >= 0, not {}", args.margin).into());
    }
    if args.refinements > 4 {
        return Err(format!(
            "--refinements {} would solve on 2^{} times the first mesh: at most 4",
            args.refinements, args.refinements
        )
        .into());
    }
    if args.repair && (args.count.is_some() || !args.dataset.join("manifest.json").is_file()) {
        return Err(format!(
            "--repair rewrites a whole run: --dataset must be the folder of a `ground data generate` run (without --count), not {}",
            args.dataset.display()
        )
        .into());
    }
    if let Some(csv) = &args.csv {
        require_parent_folder(csv)?;
    }
    let file = dataset_file(&args.dataset);
    let spatial = holds_spatial_records(&file)?;
    if args.repair && spatial {
        return Err(format!(
            "--repair re-solves planar records only: {} holds records of an inclined family (check them without --repair)",
            args.dataset.display()
        )
        .into());
    }
    let settings = CrossCheckSettings {
        segments_per_step: args.segments_per_step.get(),
        refinements: args.refinements,
        margin: args.margin,
    };
    let spacecraft_of = |family: &MissionFamily| args.spacecraft.for_dataset(&file, family);
    let limit = args.count.map(NonZeroUsize::get);
    if spatial {
        let dataset = read_dataset_of::<SpatialFamily>(&file)?;
        let spacecraft = spacecraft_of(&dataset.manifest.family.family)?;
        let checks = crosscheck_records(&dataset.records, limit, &spacecraft, &settings, true);
        return report_crosscheck(args, &settings, &checks, &[], &[]);
    }
    let dataset = read_dataset(&file)?;
    let spacecraft = spacecraft_of(&dataset.manifest.family)?;
    if args.repair {
        let run = crosscheck_run(
            &args.dataset,
            &spacecraft,
            &settings,
            &run_solve_options(&args.dataset)?,
            true,
            true,
        )?;
        report_crosscheck(args, &settings, &run.checks, &run.repaired, &run.cut)
    } else {
        let checks = crosscheck_records(&dataset.records, limit, &spacecraft, &settings, true);
        report_crosscheck(args, &settings, &checks, &[], &[])
    }
}

/// The end of [`crosscheck_command`], planar (`C` = 3) or inclined (4): the CSV, the beaten,
/// repaired and cut records, and the summary line; an error when a beaten record is left.
fn report_crosscheck<const C: usize>(
    args: &CrossCheckArgs,
    settings: &CrossCheckSettings,
    checks: &[(u64, Result<CrossCheck<C>, DirectError>)],
    repaired: &[(u64, f64, f64)],
    cut: &[(u64, f64, f64)],
) -> Result<(), Box<dyn std::error::Error>> {
    if checks.is_empty() {
        return Err(format!("{}: no converged record to check", args.dataset.display()).into());
    }
    if let Some(csv) = &args.csv {
        write_crosscheck_csv(csv, checks, settings.margin).map_err(|e| format!("{}: {e}", csv.display()))?;
    }
    let flown: Vec<_> = checks
        .iter()
        .filter_map(|(_, c)| c.as_ref().ok())
        .filter(|c| c.direct_flies())
        .collect();
    let mut differences: Vec<f64> = flown
        .iter()
        .map(|c| c.direct_final_mass - c.indirect_final_mass)
        .collect();
    differences.sort_by(f64::total_cmp);
    let beaten: Vec<_> = flown.iter().filter(|c| c.beats_record(settings.margin)).collect();
    for c in &beaten {
        println!(
            "#{}: the direct solution ends at {:.6} of the initial mass, the record at {:.6} (+{:.4})",
            c.index,
            c.direct_final_mass,
            c.indirect_final_mass,
            c.direct_final_mass - c.indirect_final_mass
        );
    }
    for (index, before, after) in repaired {
        println!("#{index}: repaired, re-solved from the direct solution: {before:.6} -> {after:.6}");
    }
    for (index, _, _) in cut {
        println!("#{index}: its re-solve from the direct solution did not end heavier: cut from the demonstrations");
    }
    for (index, check) in checks {
        if let Err(e) = check {
            println!("#{index}: the direct solve failed: {e}");
        }
    }
    let median = differences.get(differences.len() / 2).copied().unwrap_or(f64::NAN);
    println!(
        "{} records checked on {} segments per step: the direct solution reaches the target on {}, \
         median direct - indirect final mass {median:+.2e}; {} records beaten by more than {} (worse local optima){}",
        checks.len(),
        settings.segments_per_step << settings.refinements,
        flown.len(),
        beaten.len(),
        settings.margin,
        if args.repair {
            format!(", {} repaired, {} cut", repaired.len(), cut.len())
        } else {
            String::new()
        }
    );
    // With --repair every beaten record is repaired or cut: the dataset imitates none of them.
    let left = beaten.len() - repaired.len() - cut.len();
    if left == 0 {
        Ok(())
    } else {
        Err(format!("{left} of {} records are worse local optima", checks.len()).into())
    }
}

pub fn demos_command(dataset: &Path, all: bool, spacecraft: &SpacecraftArgs) -> Result<(), Box<dyn std::error::Error>> {
    use ground_core::demo::{print_mismatch_report, RecordFilter};
    let filter = if all {
        RecordFilter::All
    } else {
        RecordFilter::Converged
    };
    let file = if dataset.is_dir() {
        dataset.join("dataset.ltds")
    } else {
        dataset.to_path_buf()
    };
    // The report refuses a dataset that records another spacecraft.
    print_mismatch_report(&file, &spacecraft.physical(), filter)?;
    Ok(())
}

/// The dataset file of `path`: the file itself, or a run folder's `dataset.ltds`.
fn dataset_file(path: &Path) -> PathBuf {
    if path.is_dir() {
        path.join("dataset.ltds")
    } else {
        path.to_path_buf()
    }
}

pub fn feasibility_command(out: &Path, spacecraft: &SpacecraftArgs) -> Result<(), Box<dyn std::error::Error>> {
    let family = ground_core::generate::require_manifest(out)?.family;
    let sc = spacecraft.for_dataset(&dataset_file(out), &family)?;
    // A recovered draw is solved as the run's other records were (its request.json).
    let options = ground_core::generate::run_solve_options(out)?;
    let summary = ground_core::generate::classify_run(out, &sc, &options)?;
    for (index, why) in &summary.failures {
        println!("#{index}: {why}");
    }
    println!(
        "{}: {} records, {} converged, {} infeasible, converged / feasible = {:.3}",
        summary.scenario, summary.records, summary.converged, summary.infeasible, summary.feasible_convergence_rate
    );
    Ok(())
}
