//! `ground`: the ground-side command line, in groups.
//!
//! - `ground data` (no PyTorch, also with `--no-default-features`): trajectories by the indirect
//!   method, datasets, shards and their merge, CCSDS OEM export, the demonstrations' check, the
//!   cross-check against the direct transcription and the feasibility classification
//!   ([`trajectories`]).
//! - With the default `learn` feature ([`learning`]): `ground train` (pretraining, RL,
//!   relabelling rounds), `ground model` (Monte Carlo, export, SIL, ship), `ground run` (the main
//!   job or any recipe, end to end) and `ground dev` (the learner's sanity check and benchmark).

use std::process::ExitCode;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

#[cfg(feature = "learn")]
mod learning;
mod spatial;
mod trajectories;

use trajectories::{GenerateArgs, SolveArgs};

#[derive(Parser)]
#[command(name = "ground", version, about = "Low-thrust guidance: ground trainer and tools")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Trajectories and datasets by the indirect method: solve, generate, merge, compare, oem,
    /// demos, crosscheck, feasibility (no PyTorch needed).
    #[command(subcommand)]
    Data(Box<DataCommand>),
    #[cfg(feature = "learn")]
    #[command(flatten)]
    Learn(learning::LearnCommand),
}

/// `ground data`: the commands that need no PyTorch.
#[derive(Subcommand)]
enum DataCommand {
    /// Solve one mass-optimal transfer or rendezvous (--rendezvous) by the indirect method
    /// (Pontryagin, energy-to-fuel homotopy, shooting).
    Solve(SolveArgs),
    /// Solve every scenario of a distribution into a dataset folder: parallel, resumable,
    /// shardable (see the README for a Slurm job array).
    Generate(GenerateArgs),
    /// Export one trajectory of a dataset as a CCSDS OEM (KVN, TDB; EME2000 about the Sun or the
    /// Earth, MCI about Mars) plus a thrust CSV.
    Oem {
        /// Dataset file (dataset.ltds).
        #[arg(long)]
        dataset: PathBuf,
        /// Scenario index of the trajectory.
        #[arg(long)]
        index: u64,
        /// Output folder: trajectory-INDEX.oem and trajectory-INDEX-thrust.csv (created if
        /// missing; its parent folder must exist).
        #[arg(long)]
        out: PathBuf,
        /// Departure epoch (TDB, ISO 8601).
        #[arg(long, default_value = "2030-01-01T00:00:00")]
        departure: String,
    },
    /// Combine the dataset files of shards into one dataset.
    Merge {
        /// Output folder (created if missing; its parent folder must exist).
        #[arg(long)]
        out: PathBuf,
        /// Shard dataset files (dataset-I-of-N.ltds).
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
    },
    /// Check that two dataset files hold the same trajectories, solve times aside (a sharded or
    /// resumed run against a single one): exit status 1 when they differ.
    Compare {
        /// Dataset files (dataset.ltds or dataset-I-of-N.ltds).
        first: PathBuf,
        second: PathBuf,
    },
    /// One-step mismatch between the environment and the optimal trajectories of a dataset
    /// (docs/spec.md section 7; a three-dimensional dataset's cycles flown by the onboard RTN
    /// propagation, section 7.1).
    Demos {
        /// Dataset file or folder.
        #[arg(long)]
        dataset: PathBuf,
        /// Use every solved record, not only converged ones.
        #[arg(long)]
        all: bool,
        /// The spacecraft the dataset was solved for.
        #[command(flatten)]
        spacecraft: trajectories::SpacecraftArgs,
    },
    /// Check the converged records of a dataset against the direct transcription started on its
    /// own (tangential thrust, the record's cost): exit status 1 when a direct solution that
    /// reaches the target ends heavier than a record (a worse local optimum). With --repair such
    /// a record is re-solved from the direct solution, or, where that does not end heavier, cut
    /// from the demonstrations (not converged, its samples dropped, the evidence as its failure).
    Crosscheck(trajectories::CrossCheckArgs),
    /// Check a scenario family before spending hours on it: its units, times of flight and
    /// cycles, the share of a sample of draws the indirect method solves, the unsolved ones
    /// classified by their minimum time of flight (infeasible or not), the solve time and the
    /// projected dataset time on this machine, and whether the tank lasts the flight. An
    /// inclined family is solved in three dimensions. Exit status 1 when no draw was solved.
    CheckMission(trajectories::CheckMissionArgs),
    /// Solve one mass-optimal rendezvous or transfer in three dimensions from a problem file
    /// (departure state, arrival state or target orbit, time of flight, spacecraft): the
    /// indirect method of `solve` with out-of-plane components; optionally the trajectory as
    /// CSV, a figure, and the cost of each guidance cycle's thrust lost.
    #[command(name = "solve-3d")]
    Solve3d(spatial::Solve3dArgs),
    /// Solve draws of a planar family with the planar and the three-dimensional
    /// solver and compare their optima (final mass within --tolerance, relative): exit status
    /// 1 when they differ or the three-dimensional one misses a draw the planar one solves.
    #[command(name = "check-3d")]
    Check3d(spatial::Check3dArgs),
    /// Classify the unconverged records (transfer or rendezvous) of a finished dataset run by
    /// their minimum time of flight (infeasible, feasible, or unknown) and rewrite the records,
    /// the dataset and the summaries, which then count the infeasible draws apart (about 10 s to
    /// 5 min of work per record).
    Feasibility {
        /// Dataset folder of a whole (unsharded) `ground data generate` run.
        #[arg(long)]
        out: PathBuf,
        /// The spacecraft the dataset was solved for.
        #[command(flatten)]
        spacecraft: trajectories::SpacecraftArgs,
    },
}

/// Runs one `ground data` command.
fn run_data(command: DataCommand) -> Result<(), Box<dyn std::error::Error>> {
    match command {
        DataCommand::Solve(args) => trajectories::solve_command(&args),
        DataCommand::Generate(args) => trajectories::generate_command(&args),
        DataCommand::Oem {
            dataset,
            index,
            out,
            departure,
        } => trajectories::oem_command(&dataset, index, &out, &departure),
        DataCommand::Merge { out, inputs } => trajectories::merge_command(&inputs, &out),
        DataCommand::Compare { first, second } => trajectories::compare_command(&first, &second),
        DataCommand::Demos {
            dataset,
            all,
            spacecraft,
        } => trajectories::demos_command(&dataset, all, &spacecraft),
        DataCommand::Feasibility { out, spacecraft } => trajectories::feasibility_command(&out, &spacecraft),
        DataCommand::Crosscheck(args) => trajectories::crosscheck_command(&args),
        DataCommand::CheckMission(args) => trajectories::check_mission_command(&args),
        DataCommand::Solve3d(args) => spatial::solve_3d_command(&args),
        DataCommand::Check3d(args) => spatial::check_3d_command(&args),
    }
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
    let result = match cli.command {
        Command::Data(command) => run_data(*command),
        #[cfg(feature = "learn")]
        Command::Learn(command) => learning::run(command),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
