//! `ground`: the ground-side command line.
//!
//! Today it has the main job's entry point, `ground run`, which flies a demonstration through
//! the onboard crate. The pipeline it will run (indirect data generation, SAC pretraining and
//! training, Monte Carlo evaluation, export, SIL) lands with issues 3 to 6.

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use std::path::{Path, PathBuf};

use lowthrust_ground::config::{ExperimentConfig, EMBEDDED_DEFAULT};

use lowthrust_ground::export::oem::{oem_string, write_thrust_csv, CalendarEpoch, OemOptions};
use lowthrust_ground::generate::{generate, merge, read_dataset, Manifest, Shard, Summary};
use lowthrust_ground::io::atomic_write;
use lowthrust_ground::plot::plot_trajectories;
use lowthrust_ground::solver::shooting::FINAL_EPS;
use lowthrust_ground::solver::{solve_scenario, SolveOptions};
use shared::orbit::{OrbitElements, OrbitShape};
use shared::scenario::{ProblemKind, Scenario, ScenarioKind};
use shared::spacecraft::Spacecraft;
use shared::units::canonical_to_days;

#[derive(Parser)]
#[command(name = "ground", version, about = "Low-thrust guidance: ground trainer and tools")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Solve one mass-optimal transfer or rendezvous (--rendezvous) by the indirect method
    /// (Pontryagin, energy-to-fuel homotopy, shooting).
    Solve(SolveArgs),
    /// Solve every scenario of a distribution into a dataset folder: parallel, resumable,
    /// shardable (see the README for a Slurm job array).
    Generate(GenerateArgs),
    /// Export one trajectory of a dataset as a CCSDS OEM (KVN, EME2000, TDB) plus a thrust CSV.
    Oem {
        /// Dataset file (dataset.ltds).
        #[arg(long)]
        dataset: PathBuf,
        /// Scenario index of the trajectory.
        #[arg(long)]
        index: u64,
        /// Output folder: trajectory-INDEX.oem and trajectory-INDEX-thrust.csv.
        #[arg(long)]
        out: PathBuf,
        /// Departure epoch (TDB, ISO 8601).
        #[arg(long, default_value = "2030-01-01T00:00:00")]
        departure: String,
    },
    /// Combine the dataset files of shards into one dataset.
    Merge {
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Shard dataset files (dataset-I-of-N.ltds).
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
    },
    /// Pretraining (SPEC section 8): demonstration tuples from the config's dataset fill the
    /// replay buffer, then N_pt SAC updates with evaluations; the best model is kept.
    Pretrain(ExperimentArgs),
    /// RL training (vanilla, or from the pretrained model and its buffer with
    /// --from-pretrained), periodic evaluation, best model kept, resumable.
    Train {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Start from RUN/pretrain (best model and demonstration buffer).
        #[arg(long)]
        from_pretrained: bool,
    },
    /// DAgger-style rounds (transfers): fly the policy, re-solve the optimal rest of each flight
    /// from the states it visited, add those tuples to the demonstrations, update; the config's
    /// [dagger] section. Resumable; writes OUT/dagger.
    Dagger {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Learner checkpoint the first round starts from (default: OUT/pretrain/best.safetensors;
        /// ignored when OUT/dagger already holds a start).
        #[arg(long)]
        from: Option<PathBuf>,
    },
    /// Monte Carlo evaluation (SPEC section 9) of a checkpoint against zero-thrust and random
    /// policies, with the optimality gap against the indirect solution on a subset.
    Evaluate {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Agent checkpoint (a best.safetensors of a phase).
        #[arg(long)]
        checkpoint: PathBuf,
        /// Episodes (default: the config's evaluate.episodes).
        #[arg(long)]
        episodes: Option<u64>,
        /// Scenarios also solved by the indirect method (default: the config's).
        #[arg(long)]
        gap_cases: Option<u64>,
    },
    /// Onboard weight blobs (f32 and int8) from a checkpoint's actor, with the action error of
    /// each against the trained actor and their closed-loop Monte Carlo (OUT/export.json).
    Export {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Agent checkpoint (a best.safetensors of a phase).
        #[arg(long)]
        checkpoint: PathBuf,
    },
    /// Software-in-the-loop Monte Carlo: a blob flown by the onboard guidance loop against the
    /// dispersed truth plant (the config's [sil] dispersions), with the evaluation's metrics.
    Sil {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Weight blob (a `ground export` output).
        #[arg(long)]
        blob: PathBuf,
        /// Flights (default: the config's sil.episodes).
        #[arg(long)]
        episodes: Option<u64>,
        /// Fly without dispersions (reproduces the ground evaluation of the blob exactly).
        #[arg(long)]
        no_dispersions: bool,
    },
    /// One-step mismatch between the environment and the optimal trajectories of a dataset
    /// (SPEC section 7).
    Demos {
        /// Dataset file or folder.
        #[arg(long)]
        dataset: PathBuf,
        /// Use every solved record, not only converged ones.
        #[arg(long)]
        all: bool,
    },
    /// Sanity check of the learner on Gymnasium's Pendulum-v1 (SAC should reach about -200 or
    /// better mean episode reward within 20,000 steps); prints the learning curve.
    Pendulum {
        #[arg(long, default_value_t = 20_000)]
        steps: u64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Random-action steps before the first update.
        #[arg(long, default_value_t = 1_000)]
        warmup: u64,
        #[arg(long, default_value_t = 1_000)]
        eval_every: u64,
        /// Torch intra-op threads.
        #[arg(long, default_value_t = 1)]
        threads: i32,
        /// Write the curve as CSV here.
        #[arg(long)]
        csv: Option<PathBuf>,
    },
    /// Learner throughput: SAC updates per second at the thesis settings (10 features, 3
    /// actions, 2x256, batch 256) and the fraction of the measured GEMM rate reached.
    BenchSac {
        #[arg(long, default_value_t = 300)]
        updates: usize,
        /// Torch intra-op thread counts to measure.
        #[arg(long, value_delimiter = ',', default_value = "1,2")]
        threads: Vec<i32>,
    },
    /// The main job: solve a small transfer dataset, pretrain, train, evaluate by Monte Carlo
    /// and write RUN/report.md (embedded small default config unless --config is given).
    Run {
        /// Experiment config (TOML); the embedded default is configs/quick.toml.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Run folder (an existing one is resumed).
        #[arg(long, default_value = "runs/quick")]
        out: PathBuf,
    },
}

fn main() -> ExitCode {
    // Piped into `head`, the CLI should stop quietly like other Unix tools: Rust ignores SIGPIPE,
    // so println! on the closed pipe would panic with a backtrace instead.
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of one signal before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    lowthrust_ground::sac::tune_allocator();
    let result = match cli.command {
        Command::Run { config, out } => main_job(config.as_deref(), &out),
        Command::Solve(args) => solve_command(&args),
        Command::Generate(args) => generate_command(&args),
        Command::Oem {
            dataset,
            index,
            out,
            departure,
        } => oem_command(&dataset, index, &out, &departure),
        Command::Pretrain(args) => pretrain_command(&args),
        Command::Train {
            experiment,
            from_pretrained,
        } => train_command(&experiment, from_pretrained),
        Command::Dagger { experiment, from } => dagger_command(&experiment, from.as_deref()),
        Command::Evaluate {
            experiment,
            checkpoint,
            episodes,
            gap_cases,
        } => evaluate_command(&experiment, &checkpoint, episodes, gap_cases),
        Command::Export { experiment, checkpoint } => export_command(&experiment, &checkpoint),
        Command::Sil {
            experiment,
            blob,
            episodes,
            no_dispersions,
        } => sil_command(&experiment, &blob, episodes, no_dispersions),
        Command::Demos { dataset, all } => demos_command(&dataset, all),
        Command::Pendulum {
            steps,
            seed,
            warmup,
            eval_every,
            threads,
            csv,
        } => pendulum_command(steps, seed, warmup, eval_every, threads, csv.as_deref()),
        Command::BenchSac { updates, threads } => {
            bench_sac(updates, &threads);
            Ok(())
        }
        Command::Merge { out, inputs } => merge(&inputs, &out)
            .map(|summary| print_summary(&summary))
            .map_err(Into::into),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// `ground solve`: one fuel-optimal case from explicit orbits or from a scenario draw.
#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
struct SolveArgs {
    /// Draw the case from this scenario distribution (with --seed and --index) instead of
    /// giving the orbits explicitly.
    #[arg(long, value_parser = parse_scenario_kind)]
    scenario: Option<ScenarioKind>,
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
    /// Time of flight in days (default: SPEC section 4, max of the two periods rounded up to
    /// whole 14-day steps). Must be a positive whole number of 14-day steps.
    #[arg(long)]
    tof_days: Option<f64>,
    /// Print one JSON object instead of a summary.
    #[arg(long)]
    json: bool,
    /// Also draw the trajectory with its initial and target orbits into this SVG file.
    #[arg(long)]
    plot: Option<PathBuf>,
}

#[derive(clap::Args)]
struct GenerateArgs {
    #[arg(long, value_parser = parse_scenario_kind)]
    scenario: ScenarioKind,
    #[arg(long)]
    count: u64,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long)]
    out: PathBuf,
    /// Solve only shard I of N (indices i with i mod N == I).
    #[arg(long, default_value = "0/1")]
    shard: Shard,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Stop the homotopy at the first level below this eps (SPEC: 1e-4).
    #[arg(long, default_value_t = FINAL_EPS)]
    final_eps: f64,
}

fn generate_command(args: &GenerateArgs) -> Result<(), Box<dyn std::error::Error>> {
    if !(args.final_eps.is_finite() && args.final_eps > 0.0 && args.final_eps <= 1.0) {
        return Err(format!("--final-eps must be in (0, 1], got {}", args.final_eps).into());
    }
    if let Some(n) = args.threads {
        rayon::ThreadPoolBuilder::new().num_threads(n.max(1)).build_global()?;
    }
    let sc = Spacecraft::MSR_ERO
        .canonical()
        .map_err(|e| format!("spacecraft: {e}"))?;
    let manifest = Manifest {
        scenario: args.scenario,
        seed: args.seed,
        count: args.count,
    };
    let options = SolveOptions {
        final_eps: args.final_eps,
        ..SolveOptions::default()
    };
    let summary = generate(manifest, args.shard, &args.out, &sc, &options, true)?;
    print_summary(&summary);
    // A few solved trajectories on one figure (thesis Fig. 4.4/4.5).
    let shown = lowthrust_ground::pipeline::plot_dataset_sample(&args.out, args.shard)?;
    if shown > 0 {
        println!(
            "plotted {shown} trajectories in {}",
            args.out.join("trajectories.svg").display()
        );
    }
    Ok(())
}

fn oem_command(dataset: &Path, index: u64, out: &Path, departure: &str) -> Result<(), Box<dyn std::error::Error>> {
    let file = read_dataset(dataset)?;
    let record = file
        .records
        .iter()
        .find(|r| r.index == index)
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

fn print_summary(s: &Summary) {
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

fn parse_scenario_kind(name: &str) -> Result<ScenarioKind, String> {
    ScenarioKind::ALL.into_iter().find(|k| k.name() == name).ok_or_else(|| {
        let names: Vec<_> = ScenarioKind::ALL.iter().map(|k| k.name()).collect();
        format!("unknown scenario '{name}', expected one of: {}", names.join(", "))
    })
}

fn scenario_from_args(args: &SolveArgs) -> Result<(ScenarioKind, Scenario), String> {
    if let Some(kind) = args.scenario {
        return Ok((kind, kind.draw(args.seed, args.index)));
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
    };
    scenario.validate().map_err(|e| e.to_string())?;
    Ok((kind, scenario))
}

fn solve_command(args: &SolveArgs) -> Result<(), Box<dyn std::error::Error>> {
    let (kind, scenario) = scenario_from_args(args)?;
    let sc = Spacecraft::MSR_ERO
        .canonical()
        .map_err(|e| format!("spacecraft: {e}"))?;
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

fn main_job(config: Option<&Path>, out: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let config = match config {
        Some(path) => ExperimentConfig::load(path)?,
        None => ExperimentConfig::from_toml(EMBEDDED_DEFAULT)?,
    };
    tch::set_num_threads(config.compute.threads);
    let job = lowthrust_ground::pipeline::run_main_job(&config, out)?;
    print!("{}", lowthrust_ground::eval::describe(&job.monte_carlo));
    println!(
        "total {:.1} min; report: {}",
        job.stage_seconds.iter().sum::<f64>() / 60.0,
        job.report.display()
    );
    Ok(())
}

fn pendulum_command(
    steps: u64,
    seed: u64,
    warmup: u64,
    eval_every: u64,
    threads: i32,
    csv: Option<&Path>,
) -> Result<(), Box<dyn std::error::Error>> {
    use lowthrust_ground::sac::{pendulum, SacConfig};
    tch::set_num_threads(threads);
    let config = SacConfig {
        warmup_steps: warmup,
        ..SacConfig::default()
    };
    let curve = pendulum::sanity_run(config, steps, eval_every, seed);
    let mut text = String::from("env_steps,mean_reward,std_reward,seconds\n");
    for p in &curve {
        println!(
            "step {:>6}  mean reward {:>8.1} +- {:>6.1}  ({:.0} s)",
            p.env_steps, p.mean_reward, p.std_reward, p.seconds
        );
        text.push_str(&format!(
            "{},{},{},{}\n",
            p.env_steps, p.mean_reward, p.std_reward, p.seconds
        ));
    }
    if let Some(path) = csv {
        lowthrust_ground::io::atomic_write(path, text.as_bytes())?;
    }
    Ok(())
}

fn bench_sac(updates: usize, threads: &[i32]) {
    use lowthrust_ground::sac::{bench, SacConfig};
    let config = SacConfig::default();
    let flops = bench::update_flops(10, 3, &config.hidden, config.batch_size);
    for &n in threads {
        tch::set_num_threads(n);
        let gemm = bench::gemm_gflops(256, 51);
        let seconds = bench::seconds_per_update(&config, 10, 3, updates);
        println!(
            "threads {n}: {:.0} updates/s ({:.2} ms each, {:.2} GFLOP), {:.1} GFLOP/s = {:.0}% of the 256^3 GEMM rate ({:.1} GFLOP/s)",
            1.0 / seconds,
            seconds * 1e3,
            flops / 1e9,
            flops / seconds / 1e9,
            100.0 * flops / seconds / 1e9 / gemm,
            gemm
        );
    }
}

/// The experiment config and run folder shared by pretrain, train and evaluate.
#[derive(clap::Args)]
struct ExperimentArgs {
    /// Experiment config (TOML); without it the embedded small default (configs/quick.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Run folder (created; an existing one is resumed).
    #[arg(long)]
    out: PathBuf,
}

impl ExperimentArgs {
    /// The config and the folder its relative paths start from.
    fn load(&self) -> Result<(ExperimentConfig, PathBuf), Box<dyn std::error::Error>> {
        match &self.config {
            Some(path) => {
                let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
                Ok((ExperimentConfig::load(path)?, base))
            }
            None => Ok((ExperimentConfig::from_toml(EMBEDDED_DEFAULT)?, self.out.clone())),
        }
    }
}

fn print_phase(summary: &lowthrust_ground::experiment::PhaseSummary) {
    println!(
        "{}: {} updates, {} environment steps, {:.0} s, {} demonstration tuples in the buffer",
        summary.folder.display(),
        summary.updates,
        summary.env_steps,
        summary.seconds,
        summary.demonstration_tuples
    );
    if let Some(best) = &summary.best {
        let s = &best.summary;
        println!(
            "best evaluation (updates {}, steps {}): reward {:.4} +- {:.4}, dr p50 {:.4} AU p95 {:.4} AU, dv p50 {:.4}, final mass {:.4}",
            best.updates,
            best.env_steps,
            s.total_reward.mean,
            s.total_reward.std,
            s.terminal_position.p50,
            s.terminal_position.p95,
            s.terminal_velocity.p50,
            s.final_mass.mean
        );
    }
}

fn pretrain_command(args: &ExperimentArgs) -> Result<(), Box<dyn std::error::Error>> {
    let (config, base) = args.load()?;
    let summary = lowthrust_ground::experiment::pretrain(&config, &base, &args.out)?;
    print_phase(&summary);
    Ok(())
}

fn train_command(args: &ExperimentArgs, from_pretrained: bool) -> Result<(), Box<dyn std::error::Error>> {
    use lowthrust_ground::experiment::{train, Start};
    let (config, _) = args.load()?;
    let start = if from_pretrained {
        Start::Pretrained
    } else {
        Start::Scratch
    };
    let summary = train(&config, &args.out, start)?;
    print_phase(&summary);
    Ok(())
}

fn dagger_command(args: &ExperimentArgs, from: Option<&Path>) -> Result<(), Box<dyn std::error::Error>> {
    let (config, base) = args.load()?;
    let start = from.map_or_else(|| args.out.join("pretrain").join("best.safetensors"), Path::to_path_buf);
    let summary = lowthrust_ground::dagger::dagger(&config, &base, &args.out, &start)?;
    for row in &summary.rows {
        println!(
            "round {:>3}: {:>5.1} % within 0.01 AU and 0.01 (dr p95 {:.4} AU, dv p95 {:.4}, final mass {:.4}), {} tuples in the buffer",
            row.round,
            100.0 * row.within_goal,
            row.summary.terminal_position.p95,
            row.summary.terminal_velocity.p95,
            row.summary.final_mass.mean,
            row.buffer
        );
    }
    println!(
        "best: round {} ({}); written to {}",
        summary.best_round,
        summary.folder.join("best.safetensors").display(),
        summary.folder.display()
    );
    Ok(())
}

fn evaluate_command(
    args: &ExperimentArgs,
    checkpoint: &Path,
    episodes: Option<u64>,
    gap_cases: Option<u64>,
) -> Result<(), Box<dyn std::error::Error>> {
    let (config, _) = args.load()?;
    let report = lowthrust_ground::eval::monte_carlo(&config, checkpoint, &args.out, episodes, gap_cases)?;
    print!("{}", lowthrust_ground::eval::describe(&report));
    println!("written to {}", args.out.display());
    Ok(())
}

fn export_command(args: &ExperimentArgs, checkpoint: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let (config, base) = args.load()?;
    let report = lowthrust_ground::export::policy::export(&config, &base, checkpoint, &args.out)?;
    println!("{}", lowthrust_ground::export::policy::describe(&report));
    println!("written to {}", args.out.display());
    Ok(())
}

fn sil_command(
    args: &ExperimentArgs,
    blob: &Path,
    episodes: Option<u64>,
    no_dispersions: bool,
) -> Result<(), Box<dyn std::error::Error>> {
    let (config, _) = args.load()?;
    let dispersions = if no_dispersions {
        firmware_sim::Dispersions::NONE
    } else {
        config.sil.dispersions
    };
    let report = lowthrust_ground::sil::sil_monte_carlo(&config, blob, &args.out, episodes, &dispersions)?;
    println!("{}", lowthrust_ground::sil::describe(&report));
    println!("written to {}", args.out.display());
    Ok(())
}

fn demos_command(dataset: &Path, all: bool) -> Result<(), Box<dyn std::error::Error>> {
    use lowthrust_ground::demo::{print_mismatch_report, RecordFilter};
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
    print_mismatch_report(&file, &shared::spacecraft::Spacecraft::MSR_ERO, filter)?;
    Ok(())
}
