//! The learning commands (the `learn` feature, on libtorch), in groups: `ground train`
//! (pretraining, RL, relabelling rounds), `ground model` (Monte Carlo, export, SIL, ship),
//! `ground run` (the main job or a recipe) and `ground dev` (the learner's sanity check and
//! benchmark).

use std::num::NonZeroU64;
use std::path::{Path, PathBuf};

use clap::Subcommand;
use learn::config::{ExperimentConfig, EMBEDDED_DEFAULT};

/// The learning groups, flattened into `ground`'s commands.
#[derive(Subcommand)]
pub enum LearnCommand {
    /// Train a controller: pretrain on demonstrations, RL, relabelling rounds (dagger).
    #[command(subcommand)]
    Train(TrainCommand),
    /// A trained controller: Monte Carlo (evaluate), onboard blobs (export), software in the
    /// loop (sil), and the shipped model folder with its card (ship).
    #[command(subcommand)]
    Model(ModelCommand),
    /// The main job: solve a small transfer dataset, pretrain, train, evaluate by Monte Carlo
    /// and write RUN/report.md (embedded small default config unless --config is given); with
    /// a recipe's config, that recipe end to end.
    Run {
        /// Experiment config (TOML); the embedded default is configs/quick.toml.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Run folder (an existing one is resumed).
        #[arg(long, default_value = "runs/quick")]
        out: PathBuf,
        /// Run nothing: check the family on a sample of draws (as `ground data check-mission`),
        /// time a solve, a SAC update and an episode here, and print each stage's projected time.
        #[arg(long)]
        plan: bool,
        /// With --plan: draws solved for the check and the solve time.
        #[arg(long, default_value_t = 20, requires = "plan")]
        sample: u64,
        /// With --plan: print one JSON object instead of the table.
        #[arg(long, requires = "plan")]
        json: bool,
    },
    /// Development checks: the learner on Pendulum-v1, and its update throughput.
    #[command(subcommand)]
    Dev(DevCommand),
    /// One Slurm array task of a relabelling round (`[compute.slurm]`): solves its share of the
    /// relabels in a request file and writes the answers beside it. Run by the array the rounds
    /// submit, not by hand.
    #[command(hide = true)]
    RelabelShard {
        /// The round's request file (`relabel-*.ltrq`).
        #[arg(long)]
        request: PathBuf,
        /// This task and the task count, `i/N` (relabels i, i + N, ...).
        #[arg(long)]
        shard: ground_core::generate::Shard,
    },
}

/// `ground train`: the learning phases, each resumable in its run folder.
#[derive(Subcommand)]
pub enum TrainCommand {
    /// Pretraining (docs/spec.md section 8): demonstration tuples from the config's dataset fill the
    /// replay buffer, then N_pt SAC updates with evaluations; the best model is kept.
    Pretrain(ExperimentArgs),
    /// RL training (vanilla, or from the pretrained model and its buffer with
    /// --from-pretrained), periodic evaluation, best model kept, resumable.
    Rl {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Start from RUN/pretrain (best model and demonstration buffer).
        #[arg(long)]
        from_pretrained: bool,
    },
    /// DAgger-style rounds: fly the policy, re-solve the optimal rest of each flight
    /// from the states it visited, add those tuples to the demonstrations, update; the config's
    /// [dagger] section. Resumable; writes OUT/dagger.
    Dagger {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Learner checkpoint the first round starts from (default: OUT/pretrain/best.safetensors;
        /// ignored when OUT/dagger already holds a start), or an actor file (a shipped model's),
        /// widened function-preservingly when its hidden layers are narrower than the config's.
        #[arg(long)]
        from: Option<PathBuf>,
        /// Another run folder (same scenario, seeds, final eps and arrival margin) whose
        /// completed rounds' relabels become this run's first rounds; the rounds go on after
        /// them from --from (ignored when OUT/dagger already holds a start).
        #[arg(long)]
        relabels_from: Option<PathBuf>,
    },
    /// Fine-tuning through the dynamics: each step flies a batch of training flights,
    /// differentiates what they end with (miss over the goal, propellant) end to end through
    /// the environment's propagator and steps the actor; the config's [finetune] section.
    /// Resumable; writes OUT/finetune (best-actor.safetensors: what `model ship --checkpoint` takes),
    /// and a chained phase ([finetune.then]) OUT/finetune/then from that best actor.
    Finetune {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Learner checkpoint or actor file (a shipped model's actor.safetensors) to start from
        /// (ignored when OUT/finetune already holds a start).
        #[arg(long)]
        from: PathBuf,
    },
}

/// `ground model`: what is done with a trained controller.
#[derive(Subcommand)]
pub enum ModelCommand {
    /// Monte Carlo evaluation (docs/spec.md section 9) of a checkpoint against zero-thrust and random
    /// policies, with the optimality gap against the indirect solution on a subset.
    Evaluate {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Agent checkpoint (a best.safetensors of a phase, or an actor file).
        #[arg(long, required_unless_present = "model", conflicts_with = "model")]
        checkpoint: Option<PathBuf>,
        /// A shipped model folder (models/NAME): its actor, checked against its card, flown
        /// with the card's config unless --config is given.
        #[arg(long)]
        model: Option<PathBuf>,
        /// Episodes (default: the config's evaluate.episodes).
        #[arg(long)]
        episodes: Option<NonZeroU64>,
        /// Scenarios also solved by the indirect method (default: the config's).
        #[arg(long)]
        gap_cases: Option<u64>,
        /// Take the optimality gap's optima from an earlier Monte Carlo of the same draws (the
        /// folder of a `ground model evaluate` or `sil` run with gap cases) instead of solving
        /// them again: refused unless it solved them for this family, Monte Carlo seed and
        /// spacecraft.
        #[arg(long, value_name = "RUN", conflicts_with = "gap_cases")]
        gap_from: Option<PathBuf>,
    },
    /// Onboard weight blobs (f32 and int8) and the actor as ONNX (OUT/actor.onnx) from a
    /// checkpoint's actor, with the action error of each blob against the trained actor and
    /// their closed-loop Monte Carlo (OUT/export.json).
    Export {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Agent checkpoint (a best.safetensors of a phase).
        #[arg(long, required_unless_present = "model", conflicts_with = "model")]
        checkpoint: Option<PathBuf>,
        /// A shipped model folder (models/NAME) whose blobs are exported again from its actor
        /// with its card's config, flown in the SIL loop, and replaced in the folder with the
        /// card's SIL figures (after a blob format change); --out holds the export and SIL runs.
        #[arg(long)]
        model: Option<PathBuf>,
        /// With --model: only add the actor's ONNX model (actor.onnx) to the folder and bind
        /// it in the card; the blobs, actor and figures stay as they are (--out is not written).
        #[arg(long, requires = "model")]
        onnx_only: bool,
        /// With --model: fly the folder's blobs, unchanged, in the SIL loop with terminal
        /// targeting over their last K cycles (0: without) and record it in the card (its
        /// config's [sil] terminal, its SIL rows, its nominal Monte Carlo as flown, a note);
        /// the actor, blobs and Monte Carlo stay as they are; --out holds the SIL runs.
        #[arg(long, value_name = "K", requires = "model", conflicts_with = "onnx_only")]
        terminal_cycles: Option<u32>,
        /// With --model: fly the folder's blobs, unchanged, with the onboard aids of the config
        /// CONFIG (its [sil] lookahead and terminal tables; an absent table, that aid not flown)
        /// and record them in the card, as --terminal-cycles does.
        #[arg(long, value_name = "CONFIG", requires = "model", conflicts_with_all = ["onnx_only", "terminal_cycles"])]
        aids: Option<PathBuf>,
        /// With --model: convert the folder's blobs of the previous blob format to the present
        /// one in place (the same network bit for bit, its weights laid out anew; no dataset
        /// needed, the int8 calibration kept), fly them in the SIL loop and record them in the
        /// card; --out holds the converted blobs and the SIL runs.
        #[arg(long, requires = "model", conflicts_with_all = ["onnx_only", "terminal_cycles", "aids"])]
        upgrade: bool,
    },
    /// A learner checkpoint made a shipped model: its Monte Carlo (OUT/mc), its blobs exported
    /// and flown in the SIL loop (OUT/export, OUT/sil-*), and the model folder OUT/model
    /// (actor, blobs, card), as the recipe's last stages do. Copy OUT/model to models/NAME.
    Ship {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Learner checkpoint (e.g. RUN/dagger/best.safetensors).
        #[arg(long)]
        checkpoint: PathBuf,
        /// The relabelling rounds' folder the checkpoint came from (RUN/dagger): the card
        /// records the rounds run and the one kept.
        #[arg(long)]
        rounds: Option<PathBuf>,
        /// The demonstrations' dataset folder the card names, in place of the config's
        /// [pretrain] dataset (a recipe's config names none: its run generates it).
        #[arg(long)]
        dataset: Option<PathBuf>,
        /// A line for the card on the controller's lineage (repeatable).
        #[arg(long)]
        note: Vec<String>,
    },
    /// Software-in-the-loop Monte Carlo: a blob flown by the onboard guidance loop against the
    /// dispersed truth plant (the config's [sil] dispersions), with the evaluation's metrics.
    Sil {
        #[command(flatten)]
        experiment: ExperimentArgs,
        /// Weight blob (a `ground model export` output).
        #[arg(long, required_unless_present = "model", conflicts_with = "model")]
        blob: Option<PathBuf>,
        /// A shipped model folder (models/NAME): its f32 blob (--int8: its int8 blob), checked
        /// against its card, flown with the card's config unless --config is given.
        #[arg(long)]
        model: Option<PathBuf>,
        /// With --model: fly the int8 blob.
        #[arg(long, requires = "model")]
        int8: bool,
        /// Flights (default: the config's sil.episodes).
        #[arg(long)]
        episodes: Option<NonZeroU64>,
        /// Fly without dispersions (reproduces the ground evaluation of the blob exactly).
        #[arg(long)]
        no_dispersions: bool,
        /// Fly the blob with rollout lookahead (onboard::lookahead) at its default settings
        /// when the config has no [sil] lookahead (a config's lookahead flies with or without
        /// this flag).
        #[arg(long)]
        lookahead: bool,
        /// With lookahead: the fraction of the thrust its rollouts plan without, in [0, 1)
        /// (replaces the config's).
        #[arg(long)]
        thrust_margin: Option<f64>,
        /// Fly the last N cycles (1 to 8) with terminal targeting (onboard::terminal): the
        /// remaining commands solved for the arrival each cycle (replaces the config's
        /// [sil] terminal cycles).
        #[arg(long)]
        terminal: Option<u32>,
        /// Solve the first N flights' scenarios by the indirect method: the optimality gap and
        /// the share within the goal where solved, by eccentricity band (default 0: none).
        #[arg(long, default_value_t = 0)]
        gap_cases: u64,
        /// Take the optimality gap's optima from an earlier Monte Carlo of the same draws (the
        /// folder of a `ground model evaluate` or `sil` run with gap cases) instead of solving
        /// them again: refused unless it solved them for this family, Monte Carlo seed and
        /// spacecraft.
        #[arg(long, value_name = "RUN", conflicts_with = "gap_cases")]
        gap_from: Option<PathBuf>,
        /// Exit 0 when the blob is refused and the flights run in safe mode (thrust off), as
        /// the flight software does; without it a refused blob is a failed command.
        #[arg(long)]
        allow_safe_mode: bool,
    },
}

/// `ground dev`: checks of the learner itself.
#[derive(Subcommand)]
pub enum DevCommand {
    /// Sanity check of the learner on Gymnasium's Pendulum-v1 (SAC should reach about -200 or
    /// better mean episode reward within 20,000 steps); prints the learning curve.
    Pendulum {
        #[arg(long, default_value_t = 20_000, value_parser = clap::value_parser!(u64).range(1..))]
        steps: u64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Random-action steps before the first update.
        #[arg(long, default_value_t = 1_000)]
        warmup: u64,
        #[arg(long, default_value_t = 1_000)]
        eval_every: u64,
        /// Torch intra-op threads.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(i32).range(1..))]
        threads: i32,
        /// Write the curve as CSV here.
        #[arg(long)]
        csv: Option<PathBuf>,
    },
    /// Learner throughput: SAC updates per second at the thesis settings (10 features, 3
    /// actions, 2x256, batch 256) and the fraction of the measured GEMM rate reached.
    BenchSac {
        #[arg(long, default_value_t = 300, value_parser = clap::value_parser!(u64).range(1..))]
        updates: u64,
        /// Torch intra-op thread counts to measure.
        #[arg(long, value_delimiter = ',', default_value = "1,2", value_parser = clap::value_parser!(i32).range(1..))]
        threads: Vec<i32>,
        /// Where the updates and the GEMM run: "cpu" or "cuda" (refused where libtorch finds no
        /// CUDA device).
        #[arg(long, default_value = "cpu", value_parser = ["cpu", "cuda"])]
        device: String,
        /// Mini-batch size (the thesis's 256 by default).
        #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u64).range(1..))]
        batch: u64,
    },
}

/// Runs one learning command.
pub fn run(command: LearnCommand) -> Result<(), Box<dyn std::error::Error>> {
    learn::sac::tune_allocator();
    match command {
        LearnCommand::Run {
            config,
            plan: true,
            sample,
            json,
            ..
        } => plan_command(config.as_deref(), sample, json),
        LearnCommand::Run { config, out, .. } => main_job(config.as_deref(), &out),
        LearnCommand::Train(command) => run_train(command),
        LearnCommand::Model(command) => run_model(command),
        LearnCommand::Dev(command) => run_dev(command),
        LearnCommand::RelabelShard { request, shard } => {
            if let Some(threads) = std::env::var("SLURM_CPUS_PER_TASK")
                .ok()
                .and_then(|n| n.parse::<usize>().ok())
            {
                let _ = rayon::ThreadPoolBuilder::new().num_threads(threads).build_global();
            }
            let out = learn::dagger::relabel_shard(&request, u64::from(shard.index), u64::from(shard.count))?;
            println!("{}", out.display());
            Ok(())
        }
    }
}

fn run_train(command: TrainCommand) -> CommandResult {
    match command {
        TrainCommand::Pretrain(args) => pretrain_command(&args),
        TrainCommand::Rl {
            experiment,
            from_pretrained,
        } => train_command(&experiment, from_pretrained),
        TrainCommand::Dagger {
            experiment,
            from,
            relabels_from,
        } => dagger_command(&experiment, from.as_deref(), relabels_from.as_deref()),
        TrainCommand::Finetune { experiment, from } => finetune_command(&experiment, &from),
    }
}

fn finetune_command(args: &ExperimentArgs, from: &Path) -> Result<(), Box<dyn std::error::Error>> {
    // A staged recipe's last stage: the settings its shipped learner flies with, as ground run.
    let (config, _) = args.load_flown()?;
    let phases = in_run_folder(&args.out, || Ok(learn::finetune::finetune(&config, &args.out, from)?))?;
    for (i, summary) in phases.iter().enumerate() {
        if phases.len() > 1 {
            println!("phase {} of {}: {}", i + 1, phases.len(), summary.folder.display());
        }
        for row in &summary.rows {
            println!(
                "step {:>5}: objective {:.4}, {:>5.1} % within 0.01 AU and 0.01 (dr p50 {:.4} AU, p95 {:.4}; final mass {:.5})",
                row.step,
                row.objective,
                100.0 * row.within_goal,
                row.summary.terminal_position.p50,
                row.summary.terminal_position.p95,
                row.summary.final_mass.mean
            );
        }
        println!(
            "best: step {} ({}); written to {}",
            summary.best_step,
            summary.best_actor.display(),
            summary.folder.display()
        );
    }
    Ok(())
}

fn run_model(command: ModelCommand) -> CommandResult {
    match command {
        ModelCommand::Evaluate {
            experiment,
            checkpoint,
            model,
            episodes,
            gap_cases,
            gap_from,
        } => evaluate_command(
            &experiment,
            Flown::from(checkpoint, model, false),
            episodes,
            (gap_cases, gap_from.as_deref()),
        ),
        ModelCommand::Export {
            experiment,
            checkpoint,
            model,
            onnx_only,
            terminal_cycles,
            aids,
            upgrade,
        } => match (checkpoint, model) {
            (_, Some(model)) if upgrade => {
                if experiment.config.is_some() {
                    return Err("--upgrade flies the card's config; --config is not used with it".into());
                }
                let (card, sil) = in_run_folder(&experiment.out, || {
                    Ok(learn::model::upgrade_model(&model, &experiment.out)?)
                })?;
                for report in &sil {
                    println!("{}", learn::sil::describe(report));
                }
                println!(
                    "{} upgraded to blob format {} ({} SIL rows); runs in {}",
                    model.display(),
                    shared::blob::FORMAT_VERSION,
                    card.sil.len(),
                    experiment.out.display()
                );
                Ok(())
            }
            (_, Some(model)) if terminal_cycles.is_some() || aids.is_some() => {
                // Read before the run folder is made: a refused file leaves nothing behind.
                let aids = aids.map(|path| learn::model::read_aids(&path)).transpose()?;
                let (card, sil) = in_run_folder(&experiment.out, || {
                    Ok(match (&aids, terminal_cycles) {
                        (Some(aids), _) => learn::model::fly_aids(&model, &experiment.out, aids)?,
                        (None, cycles) => {
                            learn::model::fly_terminal(&model, &experiment.out, cycles.unwrap_or_default())?
                        }
                    })
                })?;
                for report in &sil {
                    println!("{}", learn::sil::describe(report));
                }
                println!(
                    "{} updated ({} SIL rows); runs in {}",
                    model.display(),
                    card.sil.len(),
                    experiment.out.display()
                );
                Ok(())
            }
            (_, Some(model)) if onnx_only => {
                let card = learn::model::add_onnx(&model)?;
                println!(
                    "{} now holds {} (CRC-32C {})",
                    model.display(),
                    learn::model::ONNX_FILE,
                    card.files.get(learn::model::ONNX_FILE).map_or("?", String::as_str)
                );
                Ok(())
            }
            (_, Some(model)) => reexport_command(&experiment, &model),
            (Some(checkpoint), None) => export_command(&experiment, &checkpoint),
            (None, None) => Err("give --checkpoint or --model".into()),
        },
        ModelCommand::Ship {
            experiment,
            checkpoint,
            rounds,
            dataset,
            note,
        } => ship_command(&experiment, &checkpoint, rounds.as_deref(), dataset.as_deref(), &note),
        ModelCommand::Sil {
            experiment,
            blob,
            model,
            int8,
            episodes,
            no_dispersions,
            lookahead,
            thrust_margin,
            terminal,
            gap_cases,
            gap_from,
            allow_safe_mode,
        } => sil_command(
            &experiment,
            Flown::from(blob, model, int8),
            episodes,
            SilFlags {
                no_dispersions,
                lookahead,
                thrust_margin,
                terminal,
                optima: (Some(gap_cases), gap_from),
                allow_safe_mode,
            },
        ),
    }
}

fn run_dev(command: DevCommand) -> CommandResult {
    match command {
        DevCommand::Pendulum {
            steps,
            seed,
            warmup,
            eval_every,
            threads,
            csv,
        } => pendulum_command(steps, seed, warmup, eval_every, threads, csv.as_deref()),
        DevCommand::BenchSac {
            updates,
            threads,
            device,
            batch,
        } => bench_sac(updates, &threads, &device, batch as usize),
    }
}

type CommandResult<T = ()> = Result<T, Box<dyn std::error::Error>>;

/// Runs `work` holding the run folder `out` (created if missing) against other processes. When
/// the command fails and the folders it created hold nothing but the lock, they are removed
/// again: a refused command leaves nothing behind, and a failed one never loses work.
fn in_run_folder<T>(out: &Path, work: impl FnOnce() -> CommandResult<T>) -> CommandResult<T> {
    let first_created = out
        .ancestors()
        .take_while(|a| !a.as_os_str().is_empty() && !a.exists())
        .last()
        .map(Path::to_path_buf);
    let lock = ground_core::io::RunLock::acquire(out)?;
    let result = work();
    drop(lock);
    if let (Err(_), Some(created)) = (&result, first_created) {
        if holds_only_the_lock(&created) {
            let _ = std::fs::remove_dir_all(&created);
        }
    }
    result
}

/// Does `dir` hold nothing but folders and lock files?
fn holds_only_the_lock(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|entries| {
        entries.flatten().all(|e| {
            let path = e.path();
            if path.is_dir() {
                holds_only_the_lock(&path)
            } else {
                e.file_name() == ground_core::io::LOCK_FILE
            }
        })
    })
}

/// `ground run`'s config: the file given, or the embedded main job.
fn run_config(config: Option<&Path>) -> Result<ExperimentConfig, Box<dyn std::error::Error>> {
    Ok(match config {
        Some(path) => ExperimentConfig::load(path)?,
        None => ExperimentConfig::from_toml(EMBEDDED_DEFAULT)?,
    })
}

fn main_job(config: Option<&Path>, out: &Path) -> CommandResult {
    let config = run_config(config)?;
    tch::set_num_threads(config.compute.threads);
    let job = in_run_folder(out, || Ok(learn::pipeline::run_main_job(&config, out)?))?;
    print!("{}", learn::eval::describe(&job.monte_carlo));
    println!(
        "total {:.1} min; report: {}",
        job.stage_seconds.iter().map(|(_, t)| t).sum::<f64>() / 60.0,
        job.report.display()
    );
    Ok(())
}

fn plan_command(config: Option<&Path>, sample: u64, json: bool) -> CommandResult {
    let config = run_config(config)?;
    tch::set_num_threads(config.compute.threads);
    let plan = learn::plan::plan_recipe(&config, sample)?;
    if json {
        println!("{}", serde_json::to_string(&plan)?);
    } else {
        println!("recipe {}", config.display_name());
        for line in ground_core::mission::check_lines(&plan.check) {
            println!("{line}");
        }
        for line in learn::plan::plan_lines(&plan) {
            println!("{line}");
        }
    }
    if plan.check.converged == 0 {
        return Err(format!("no draw of the sample of {} was solved", plan.check.family).into());
    }
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
    use learn::sac::{pendulum, SacConfig};
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
        ground_core::io::atomic_write(path, text.as_bytes())?;
    }
    Ok(())
}

fn bench_sac(updates: u64, threads: &[i32], device: &str, batch: usize) -> Result<(), Box<dyn std::error::Error>> {
    use learn::sac::{bench, SacConfig};
    let device = match device {
        "cuda" => learn::sac::cuda_device().map_err(|reason| format!("--device cuda: {reason}"))?,
        _ => tch::Device::Cpu,
    };
    let config = SacConfig {
        batch_size: batch,
        ..SacConfig::default()
    };
    let flops = bench::update_flops(10, 3, &config.hidden, config.batch_size);
    for &n in threads {
        tch::set_num_threads(n);
        let gemm = bench::gemm_gflops(256, 51, device);
        let seconds = bench::seconds_per_update(&config, 10, 3, updates as usize, device);
        println!(
            "{device:?}, threads {n}, batch {batch}: {:.0} updates/s ({:.2} ms each, median of {}-update blocks; {:.2} GFLOP), {:.1} GFLOP/s = {:.0}% of the 256^3 GEMM rate ({:.1} GFLOP/s)",
            1.0 / seconds,
            seconds * 1e3,
            bench::BLOCK,
            flops / 1e9,
            flops / seconds / 1e9,
            100.0 * flops / seconds / 1e9 / gemm,
            gemm
        );
    }
    Ok(())
}

/// The experiment config and run folder shared by pretrain, train and evaluate.
#[derive(clap::Args)]
pub struct ExperimentArgs {
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

    /// The config a recipe's shipped learner flies with (its last stage's, see
    /// `ExperimentConfig::flown`) and the folder its relative paths start from: what the
    /// commands that fly, export or ship a checkpoint use.
    fn load_flown(&self) -> Result<(ExperimentConfig, PathBuf), Box<dyn std::error::Error>> {
        let (config, base) = self.load()?;
        Ok((config.flown()?, base))
    }
}

fn print_phase(summary: &learn::phase::PhaseSummary) {
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
    let summary = in_run_folder(&args.out, || Ok(learn::pretrain::pretrain(&config, &base, &args.out)?))?;
    print_phase(&summary);
    Ok(())
}

fn train_command(args: &ExperimentArgs, from_pretrained: bool) -> Result<(), Box<dyn std::error::Error>> {
    use learn::rl::{train, Start};
    let (config, _) = args.load()?;
    let start = if from_pretrained {
        Start::Pretrained
    } else {
        Start::Scratch
    };
    let summary = in_run_folder(&args.out, || Ok(train(&config, &args.out, start)?))?;
    print_phase(&summary);
    Ok(())
}

fn dagger_command(
    args: &ExperimentArgs,
    from: Option<&Path>,
    relabels_from: Option<&Path>,
) -> Result<(), Box<dyn std::error::Error>> {
    let (config, base) = args.load()?;
    let start = from.map_or_else(|| args.out.join("pretrain").join("best.safetensors"), Path::to_path_buf);
    let summary = in_run_folder(&args.out, || {
        Ok(learn::dagger::dagger(&config, &base, &args.out, &start, relabels_from)?)
    })?;
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

/// What a command flies: a file given as such, or one of a shipped model's.
enum Flown {
    File(PathBuf),
    Model { dir: PathBuf, int8: bool },
}

impl Flown {
    fn from(file: Option<PathBuf>, model: Option<PathBuf>, int8: bool) -> Self {
        match (file, model) {
            (_, Some(dir)) => Self::Model { dir, int8 },
            // clap requires one of the two.
            (file, None) => Self::File(file.unwrap_or_default()),
        }
    }

    /// The config and the file to fly. A model is opened first (every check of its card) and
    /// flown with its own config unless the command names one; `blob` picks its f32 or int8
    /// blob (`ground model sil`) instead of its actor (`ground model evaluate`).
    fn resolve(&self, args: &ExperimentArgs, blob: bool) -> CommandResult<(ExperimentConfig, PathBuf)> {
        match self {
            Self::File(file) => Ok((args.load_flown()?.0, file.clone())),
            Self::Model { dir, int8 } => {
                let model = learn::model::open_model(dir)?;
                let file = match (blob, int8) {
                    (false, _) => model.actor(),
                    (true, false) => model.blob(shared::blob::Quantization::F32),
                    (true, true) => model.blob(shared::blob::Quantization::Int8),
                };
                let config = match &args.config {
                    Some(_) => args.load_flown()?.0,
                    None => model.config,
                };
                Ok((config, file))
            }
        }
    }
}

fn evaluate_command(
    args: &ExperimentArgs,
    flown: Flown,
    episodes: Option<NonZeroU64>,
    (gap_cases, gap_from): (Option<u64>, Option<&Path>),
) -> Result<(), Box<dyn std::error::Error>> {
    let (config, checkpoint) = flown.resolve(args, false)?;
    let checkpoint = checkpoint.as_path();
    let optima = optima(&config, gap_cases, gap_from)?;
    let report = in_run_folder(&args.out, || {
        Ok(learn::eval::monte_carlo(
            &config,
            checkpoint,
            &args.out,
            episodes.map(NonZeroU64::get),
            optima,
        )?)
    })?;
    print!("{}", learn::eval::describe(&report));
    println!("written to {}", args.out.display());
    Ok(())
}

fn export_command(args: &ExperimentArgs, checkpoint: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let (config, base) = args.load_flown()?;
    let report = in_run_folder(&args.out, || {
        Ok(learn::export::export(&config, &base, checkpoint, &args.out)?)
    })?;
    println!("{}", learn::export::describe(&report));
    println!("written to {}", args.out.display());
    // The blobs stay for study (export.json has every figure); the exit status says they failed.
    match report.failed_criteria().as_slice() {
        [] => Ok(()),
        failed => Err(format!("export check failed: {}", failed.join("; ")).into()),
    }
}

fn reexport_command(args: &ExperimentArgs, model: &Path) -> Result<(), Box<dyn std::error::Error>> {
    if args.config.is_some() {
        return Err("--model exports with the card's config; --config is not used with it".into());
    }
    let done = in_run_folder(&args.out, || Ok(learn::model::reexport_model(model, &args.out)?))?;
    println!("{}", learn::export::describe(&done.export));
    for report in &done.sil {
        println!("{}", learn::sil::describe(report));
    }
    println!("{} updated; runs in {}", model.display(), args.out.display());
    match done.export.failed_criteria().as_slice() {
        [] => Ok(()),
        failed => Err(format!("export check failed: {}", failed.join("; ")).into()),
    }
}

fn ship_command(
    args: &ExperimentArgs,
    checkpoint: &Path,
    rounds: Option<&Path>,
    dataset: Option<&Path>,
    notes: &[String],
) -> Result<(), Box<dyn std::error::Error>> {
    let (mut config, base) = args.load_flown()?;
    if let Some(dir) = dataset {
        config.pretrain.dataset = Some(std::path::absolute(dir)?);
    }
    let rounds = match rounds {
        Some(dir) => {
            let summary = learn::dagger::read_rounds(dir)?;
            Some((summary.rows.last().map_or(0, |r| r.round), summary.best_round))
        }
        None => None,
    };
    let shipped = in_run_folder(&args.out, || {
        Ok(learn::ship::ship(&config, &base, checkpoint, &args.out, rounds, notes)?)
    })?;
    print!("{}", learn::eval::describe(&shipped.monte_carlo));
    println!("{}", learn::export::describe(&shipped.export));
    for report in &shipped.sil {
        println!("{}", learn::sil::describe(report));
    }
    println!("model folder written to {}", args.out.join("model").display());
    match shipped.export.failed_criteria().as_slice() {
        [] => Ok(()),
        failed => Err(format!("export check failed: {}", failed.join("; ")).into()),
    }
}

/// The optimality gap's optima: solved for the first `gap_cases` scenarios, or those of the
/// earlier Monte Carlo `gap_from` of the same draws, checked before anything is written.
fn optima(
    config: &ExperimentConfig,
    gap_cases: Option<u64>,
    gap_from: Option<&Path>,
) -> Result<learn::eval::Optima, learn::error::ExperimentError> {
    match gap_from {
        Some(run) => learn::eval::reused_optima(config, run),
        None => Ok(learn::eval::Optima::Solve(gap_cases)),
    }
}

/// How `ground model sil` flies, beyond the config.
struct SilFlags {
    no_dispersions: bool,
    lookahead: bool,
    thrust_margin: Option<f64>,
    terminal: Option<u32>,
    /// Gap cases, or the earlier run whose optima are reused.
    optima: (Option<u64>, Option<PathBuf>),
    allow_safe_mode: bool,
}

fn sil_command(
    args: &ExperimentArgs,
    flown: Flown,
    episodes: Option<NonZeroU64>,
    flags: SilFlags,
) -> Result<(), Box<dyn std::error::Error>> {
    let SilFlags {
        no_dispersions,
        lookahead,
        thrust_margin,
        terminal,
        optima: (gap_cases, gap_from),
        allow_safe_mode,
    } = flags;
    let (mut config, blob) = flown.resolve(args, true)?;
    if lookahead && config.sil.lookahead.is_none() {
        config.sil.lookahead = Some(Default::default());
    }
    if let Some(cycles) = terminal {
        config.sil.terminal = Some(learn::config::TerminalSettings {
            cycles,
            ..config.sil.terminal.unwrap_or_default()
        });
        config.validate()?;
    }
    if let Some(margin) = thrust_margin {
        let settings = config
            .sil
            .lookahead
            .as_mut()
            .ok_or("--thrust-margin sets the lookahead's margin: add --lookahead")?;
        settings.thrust_margin = margin;
        config.validate()?;
    }
    let blob = blob.as_path();
    let dispersions = if no_dispersions {
        firmware_sim::Dispersions::NONE
    } else {
        config.sil.dispersions
    };
    // A blob the flight software refuses would fly every flight thrust off: refused before
    // anything is written, unless that is what was asked for.
    if let (Some(why), false) = (learn::sil::blob_refusal(&config, blob)?, allow_safe_mode) {
        return Err(format!(
            "{}: the flight software refuses the blob ({why}); every flight would run in safe mode (thrust off): --allow-safe-mode flies them so",
            blob.display()
        )
        .into());
    }
    let optima = optima(&config, gap_cases, gap_from.as_deref())?;
    let report = in_run_folder(&args.out, || {
        Ok(learn::sil::sil_monte_carlo(
            &config,
            blob,
            &args.out,
            episodes.map(NonZeroU64::get),
            &dispersions,
            optima,
        )?)
    })?;
    println!("{}", learn::sil::describe(&report));
    println!("written to {}", args.out.display());
    Ok(())
}
