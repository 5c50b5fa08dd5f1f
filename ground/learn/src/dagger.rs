//! `ground train dagger`: DAgger-style rounds of relabelled demonstrations (transfers and rendezvous).
//!
//! Each round flies the deterministic policy on fresh training scenarios, re-solves the
//! fuel-optimal rest of each flight by the indirect method from the states it visited
//! ([`ground_core::demo::relabel`]), adds those tuples to the demonstration buffer, and runs
//! behaviour-cloning-regularised updates on the grown buffer. The policy then learns what to do
//! in the states its own errors lead to, which demonstrations of optimal flights never show.
//! With `dagger.dispersed` the flights are the onboard controller's against the SIL's dispersed
//! plant, so the relabels also cover what navigation, thrust and missed-thrust errors lead to.
//!
//! ```text
//! RUN/dagger/round-0.safetensors   the starting learner (copied from --from)
//! RUN/dagger/relabels-R.ltrl       round R's relabelled tuples
//! RUN/dagger/round-R.safetensors   the learner after round R
//! RUN/dagger/best.safetensors      the round with the largest share within the goal
//! RUN/dagger/rounds.{csv,svg}      per-round scores, state.json the same for machines
//! ```
//!
//! A run may also start where another stopped, with another network (`--relabels-from`): the
//! other run's completed rounds' relabels are copied in as rounds 1..K, the start is saved as
//! round K as well, and the rounds go on from K + 1 on the same scenarios the other run's would.
//!
//! Every file is written atomically and is complete when it exists, so a run resumes from
//! them alone: the buffer is the demonstrations plus every round's relabels in order, each
//! round's sampler is seeded from the round number and the agent's noise from its update count. A run stopped anywhere
//! and resumed ends with the same weights as one that never stopped.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use shared::scenario::{ProblemKind, Scenario};

use crate::config::{ExperimentConfig, SlurmConfig};
use crate::eval::{within_accuracy_goal, ACCURACY_GOAL};
use crate::experiment::{
    check_run, demonstration_buffer, evaluate_agent, new_agent, policy_batch, prepare_run, residual_chart, write_file,
    ExperimentError,
};
use crate::export::actor_network;
use crate::sac::agent::Sac;
use crate::sac::replay::{sampler, ReplayBuffer, Transition};
use crate::sil::fly_blob_seeded;
use ground_core::charts::{line_chart, Series};
use ground_core::demo::{default_tolerances, placed_demonstration, relabel};
use ground_core::env::batch::{evaluate_batched, summarize, EpisodeOutcome, OutcomeSummary};
use ground_core::env::{MdpEnv, Problem};
use ground_core::io::{checksum, decode_container, encode_container};
use ground_core::solver::SolveOptions;
use ground_core::with_problem;
use onboard::dynamics::SpacecraftState;

const RELABELS_MAGIC: [u8; 4] = *b"LTRL";
const RELABELS_VERSION: u16 = 1;
/// Round r flies training scenarios `r * ROUND_STRIDE ..`: past any the RL phase draws.
const ROUND_STRIDE: u64 = 1_000_000;
/// Mixed into the training seed for the rounds' replay samplers (apart from RL's streams).
const SAMPLER_STREAM: u64 = 0xDA66E5;
/// Mixed into the training seed for the dispersions of the flights a round relabels.
const DISPERSION_STREAM: u64 = 0xD15BE25E;

/// One round's relabelled tuples, as saved in `relabels-R.ltrl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Relabels {
    /// The round these tuples were solved in (from 1).
    pub round: u64,
    /// States sent to the solver.
    pub attempted: u64,
    /// Of those, solved to the final eps and turned into tuples.
    pub converged: u64,
    /// The tuples, flagged as demonstrations.
    pub tuples: ReplayBuffer,
}

/// One relabelled tuple as it enters the buffer (what a Slurm task sends back).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RelabelTuple {
    obs: Vec<f32>,
    action: [f32; 3],
    reward: f32,
    next_obs: Vec<f32>,
    done: bool,
}

/// The tuples of one relabel's re-solved flight, `None` where it did not converge.
type Solved = Option<Vec<RelabelTuple>>;

/// One relabel: the rest of training scenario `first + episode`'s flight from `state`
/// (x, y, vx, vy, m) at step `step`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RelabelJob {
    /// The flight, counted from the round's first training scenario.
    pub episode: u64,
    /// The step of the flight whose state the rest is solved from.
    pub step: u32,
    /// The true state there: x, y (AU), vx, vy (AU/t*), mass (fraction of m0).
    pub state: [f64; 5],
}

/// A batch of relabels for a Slurm array (`ground relabel-shard`): the run's config (its
/// scenarios, spacecraft, environment, final eps and arrival margin), the round's first training
/// scenario and
/// the relabels in order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RelabelRequest {
    /// The run's config as TOML.
    pub config: String,
    /// Index of the round's first training scenario (the round times 1,000,000).
    pub first: u64,
    /// The relabels, in order.
    pub jobs: Vec<RelabelJob>,
}

/// A task's answers: (relabel's position in the request, its tuples).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct RelabelShard {
    /// Checksum of the request file answered: a round run again reuses a task's answers only
    /// for the same request.
    request: u32,
    answers: Vec<(u64, Solved)>,
}

const REQUEST_MAGIC: [u8; 4] = *b"LTRQ";
const REQUEST_VERSION: u16 = 1;
const SHARD_MAGIC: [u8; 4] = *b"LTRS";
const SHARD_VERSION: u16 = 2;

/// Solves one relabel, as [`relabel`] and [`placed_demonstration`] make it.
fn solve_job<P: Problem>(config: &ExperimentConfig, first: u64, job: &RelabelJob) -> Solved {
    let index = first + job.episode;
    let scenario = config.scenario.draw(config.seeds.train, index);
    let sc = config.env.spacecraft.canonical().ok()?;
    // Smoothed relabels among smoothed demonstrations: bang-bang ones mixed in drop the policy
    // to 10.9 % within the goal (docs/results.md).
    let options = SolveOptions {
        final_eps: config.generate.final_eps,
        arrival_margin_steps: config.generate.arrival_margin,
        ..SolveOptions::default()
    };
    let [x, y, vx, vy, m] = job.state;
    let state = SpacecraftState {
        r: [x, y],
        v: [vx, vy],
        m,
    };
    let (record, placement) = relabel((config.seeds.train, index), &scenario, &state, job.step, &sc, &options)?;
    if !record.converged {
        return None;
    }
    let demo = placed_demonstration::<P>(&record, &placement, &config.env, &default_tolerances()).ok()?;
    Some(
        demo.transitions
            .iter()
            .map(|t| RelabelTuple {
                obs: t.observation.as_ref().to_vec(),
                action: t.action,
                reward: t.reward as f32,
                next_obs: t.next_observation.as_ref().to_vec(),
                done: t.done,
            })
            .collect(),
    )
}

fn shard_file(request: &Path, task: u64, tasks: u64) -> PathBuf {
    request.with_extension(format!("{task}-of-{tasks}.ltrs"))
}

/// `ground relabel-shard`: solves the relabels `task`, `task + tasks`, ... of the request file
/// on this machine's cores and writes their answers beside it.
pub fn relabel_shard(request_path: &Path, task: u64, tasks: u64) -> Result<PathBuf, ExperimentError> {
    if tasks == 0 || task >= tasks {
        return Err(ExperimentError::Mismatch(format!(
            "shard {task}/{tasks}: the task must be below the task count"
        )));
    }
    let bytes = std::fs::read(request_path).map_err(|e| ExperimentError::Io(request_path.to_path_buf(), e))?;
    let request: RelabelRequest = decode_container(REQUEST_MAGIC, REQUEST_VERSION, &bytes)
        .map_err(|e| ExperimentError::Mismatch(format!("relabel request {}: {e}", request_path.display())))?;
    let config = ExperimentConfig::from_toml(&request.config)?;
    let mine: Vec<(u64, &RelabelJob)> = (task..request.jobs.len() as u64)
        .step_by(tasks as usize)
        .map(|i| (i, &request.jobs[i as usize]))
        .collect();
    let solve =
        |job: &RelabelJob| with_problem!(config.scenario.problem(), P => solve_job::<P>(&config, request.first, job));
    let answers = mine.par_iter().map(|&(i, job)| (i, solve(job))).collect();
    let out = shard_file(request_path, task, tasks);
    let shard = RelabelShard {
        request: checksum(&bytes),
        answers,
    };
    let bytes = encode_container(SHARD_MAGIC, SHARD_VERSION, &shard)
        .map_err(|e| ExperimentError::Io(out.clone(), std::io::Error::other(e.to_string())))?;
    write_file(&out, &bytes)?;
    Ok(out)
}

/// Solves `jobs` as a Slurm array: writes the request `DIR/relabel-TAG.ltrq`, runs `sbatch
/// --wait --array` on it, reads every task's answers back in the request's order and removes
/// the request and answer files. A task that failed or answered nothing fails the round and the
/// answers of the others are kept: the round run again (the same request) submits only the
/// tasks without answers.
fn solve_on_slurm(
    config: &ExperimentConfig,
    slurm: &SlurmConfig,
    dir: &Path,
    tag: &str,
    first: u64,
    jobs: Vec<RelabelJob>,
) -> Result<Vec<Solved>, ExperimentError> {
    if jobs.is_empty() {
        return Ok(Vec::new());
    }
    let count = jobs.len();
    let request_path = std::path::absolute(dir.join(format!("relabel-{tag}.ltrq")))
        .map_err(|e| ExperimentError::Io(dir.to_path_buf(), e))?;
    let request = RelabelRequest {
        config: config.to_toml(),
        first,
        jobs,
    };
    let bytes = encode_container(REQUEST_MAGIC, REQUEST_VERSION, &request)
        .map_err(|e| ExperimentError::Io(request_path.clone(), std::io::Error::other(e.to_string())))?;
    write_file(&request_path, &bytes)?;
    let request_sum = checksum(&bytes);
    let tasks = slurm.tasks.min(count as u64);
    let answered = |task: u64| -> Result<RelabelShard, String> {
        let path = shard_file(&request_path, task, tasks);
        let bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        let shard: RelabelShard = decode_container(SHARD_MAGIC, SHARD_VERSION, &bytes)
            .map_err(|e| format!("relabel answers {}: {e}", path.display()))?;
        if shard.request != request_sum {
            return Err(format!("relabel answers {} are for another request", path.display()));
        }
        Ok(shard)
    };
    // Answers a stopped round left for this request are read once and kept; the array solves
    // the others, whose answers are read after it.
    let mut shards: Vec<Option<RelabelShard>> = (0..tasks).map(|task| answered(task).ok()).collect();
    let missing: Vec<u64> = (0..tasks).filter(|&task| shards[task as usize].is_none()).collect();
    if !missing.is_empty() {
        submit_relabel_array(slurm, &request_path, tasks, &missing)?;
        for &task in &missing {
            shards[task as usize] = Some(answered(task).map_err(ExperimentError::Mismatch)?);
        }
    }
    let mut solved: Vec<Option<Solved>> = vec![None; count];
    for shard in shards.into_iter().flatten() {
        for (i, answer) in shard.answers {
            if let Some(slot) = solved.get_mut(i as usize) {
                *slot = Some(answer);
            }
        }
    }
    let solved: Vec<Solved> = solved.into_iter().collect::<Option<_>>().ok_or_else(|| {
        ExperimentError::Mismatch(format!(
            "the relabel array left relabels of {} unanswered",
            request_path.display()
        ))
    })?;
    for task in 0..tasks {
        let _ = std::fs::remove_file(shard_file(&request_path, task, tasks));
        let _ = std::fs::remove_file(request_path.with_extension(format!("slurm-{task}.out")));
    }
    let _ = std::fs::remove_file(&request_path);
    Ok(solved)
}

/// Runs `sbatch --wait` on the array tasks `which` (of `tasks`) of a relabel request.
fn submit_relabel_array(
    slurm: &SlurmConfig,
    request_path: &Path,
    tasks: u64,
    which: &[u64],
) -> Result<(), ExperimentError> {
    let ground = match &slurm.ground {
        Some(path) => path.clone(),
        None => std::env::current_exe().map_err(|e| ExperimentError::Io(PathBuf::from("ground"), e))?,
    };
    let quoted = |p: &Path| -> Result<String, ExperimentError> {
        let text = p.to_str().filter(|t| !t.contains('\'')).ok_or_else(|| {
            ExperimentError::Mismatch(format!("{}: a Slurm task cannot be given this path", p.display()))
        })?;
        Ok(format!("'{text}'"))
    };
    let command = format!(
        "{} relabel-shard --request {} --shard \"$SLURM_ARRAY_TASK_ID/{tasks}\"",
        quoted(&ground)?,
        quoted(request_path)?
    );
    // Slurm's array syntax: a range for every task, else the list.
    let array = if which.len() as u64 == tasks {
        format!("0-{}", tasks - 1)
    } else {
        which.iter().map(u64::to_string).collect::<Vec<_>>().join(",")
    };
    let log = request_path.with_extension("slurm-%a.out");
    let status = std::process::Command::new(&slurm.sbatch)
        .arg("--wait")
        .arg("--job-name=lowthrust-relabel")
        .arg(format!("--array={array}"))
        .arg(format!("--output={}", log.display()))
        .args(&slurm.options)
        .arg("--wrap")
        .arg(&command)
        .stdout(std::process::Stdio::null())
        .status()
        .map_err(|e| ExperimentError::Io(PathBuf::from(&slurm.sbatch), e))?;
    if !status.success() {
        return Err(ExperimentError::Mismatch(format!(
            "the relabel array ({}) ended with {status}: see {}; the tasks that answered are kept, and \
             the same command submits only the others",
            slurm.sbatch,
            log.display()
        )));
    }
    Ok(())
}

/// The score of the learner after a round (round 0: the starting checkpoint).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RoundRow {
    /// The round (0: the starting learner).
    pub round: u64,
    /// States sent to the solver in the round.
    pub relabels_attempted: u64,
    /// Of those, solved to the final eps.
    pub relabels_converged: u64,
    /// Tuples the round added to the buffer.
    pub tuples_added: u64,
    /// Transitions in the buffer after the round: demonstrations and every relabel so far.
    pub buffer: u64,
    /// Gradient updates of this command so far.
    pub updates: u64,
    /// Share of the completed scoring episodes within 0.01 AU and 0.01 (the accuracy goal's figure).
    pub within_goal: f64,
    /// The same share with the SIL's dispersions (`dagger.dispersed`): the round's score then.
    #[serde(default)]
    pub within_goal_dispersed: Option<f64>,
    /// Reward, final mass and terminal residuals of the nominal scoring episodes.
    pub summary: OutcomeSummary,
    /// Wall time of the round (relabels, updates, scoring).
    pub seconds: f64,
}

impl RoundRow {
    /// What picks the best round and meets `dagger.stop_at`: the share within the goal under
    /// dispersions when the round was scored under them, else the nominal one.
    pub fn score(&self) -> f64 {
        self.within_goal_dispersed.unwrap_or(self.within_goal)
    }

    const HEADER: &'static str = "round,relabels_attempted,relabels_converged,tuples_added,buffer,updates,\
within_goal,within_goal_dispersed,completed,reward_mean,final_mass_mean,dr_p50,dr_p95,dv_p50,dv_p95,seconds\n";

    fn csv(&self) -> String {
        let s = &self.summary;
        format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.1}\n",
            self.round,
            self.relabels_attempted,
            self.relabels_converged,
            self.tuples_added,
            self.buffer,
            self.updates,
            self.within_goal,
            self.within_goal_dispersed.map_or(String::new(), |d| d.to_string()),
            s.completed,
            s.total_reward.mean,
            s.final_mass.mean,
            s.terminal_position.p50,
            s.terminal_position.p95,
            s.terminal_velocity.p50,
            s.terminal_velocity.p95,
            self.seconds
        )
    }
}

/// What `ground train dagger` ended with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DaggerSummary {
    /// The rounds' folder, `RUN/dagger`.
    pub folder: PathBuf,
    /// Round 0 (the start) and every round done.
    pub rows: Vec<RoundRow>,
    /// The round kept as best.safetensors.
    pub best_round: u64,
}

fn round_file(dir: &Path, round: u64) -> PathBuf {
    dir.join(format!("round-{round}.safetensors"))
}

fn relabels_file(dir: &Path, round: u64) -> PathBuf {
    dir.join(format!("relabels-{round}.ltrl"))
}

/// Reads a round's relabels, refusing a corrupt file or one of another round or problem.
pub fn load_relabels(path: &Path, round: u64, obs_dim: usize) -> Result<Relabels, ExperimentError> {
    let bytes = std::fs::read(path).map_err(|e| ExperimentError::Io(path.to_path_buf(), e))?;
    let relabels: Relabels = decode_container(RELABELS_MAGIC, RELABELS_VERSION, &bytes)
        .map_err(|e| ExperimentError::Mismatch(format!("relabels {}: {e}", path.display())))?;
    if relabels.round != round || relabels.tuples.obs_dim() != obs_dim || relabels.tuples.act_dim() != 3 {
        return Err(ExperimentError::Mismatch(format!(
            "relabels {} hold round {} with {}-feature observations, expected round {round} with {obs_dim}",
            path.display(),
            relabels.round,
            relabels.tuples.obs_dim()
        )));
    }
    Ok(relabels)
}

fn save_relabels(path: &Path, relabels: &Relabels) -> Result<(), ExperimentError> {
    let bytes = encode_container(RELABELS_MAGIC, RELABELS_VERSION, relabels)
        .map_err(|e| ExperimentError::Io(path.to_path_buf(), std::io::Error::other(e.to_string())))?;
    write_file(path, &bytes)
}

fn progress_bar(total: u64, what: &str) -> indicatif::ProgressBar {
    ground_core::progress::bar(
        total,
        &format!("{what:>16} {{bar:36}} {{pos}}/{{len}} {{msg}} [{{elapsed}}<{{eta}}]"),
    )
}

/// Flies the policy on round `round`'s training scenarios and relabels the visited states at
/// the config's fractions of each flight, solved to the demonstrations' eps.
fn solve_relabels<P: Problem>(
    config: &ExperimentConfig,
    agent: &Sac,
    round: u64,
    dagger_dir: &Path,
) -> Result<Relabels, ExperimentError> {
    let dagger = &config.dagger;
    let first = ROUND_STRIDE * round;
    let candidates = dagger.candidates.unwrap_or(dagger.episodes);
    let scenarios: Vec<Scenario> = (first..first + candidates)
        .map(|i| config.scenario.draw(config.seeds.train, i))
        .collect();
    let flown = if dagger.dispersed {
        // The onboard controller's flights (the f32 blob of this actor) in the dispersed plant:
        // the trajectory holds the true states, which the relabels start from.
        let blob = flown_blob(agent, P::KIND)?;
        let seed = (config.seeds.train ^ DISPERSION_STREAM).wrapping_add(first);
        fly_blob_seeded(
            config,
            &blob,
            &scenarios,
            &config.sil.dispersions,
            seed,
            scenarios.len(),
            // The learner's own flights: the network alone.
            None,
        )?
        .0
    } else {
        evaluate_batched::<MdpEnv<P>, _>(&config.env, &scenarios, |o| policy_batch(agent, o), true)?
    };
    let eligible = relabel_candidates(&flown, &scenarios, dagger.max_miss);
    let step_at = |episode: usize, fraction: f64| {
        let steps = scenarios[episode].steps;
        ((fraction * f64::from(steps)).round() as u32).clamp(1, steps - 1)
    };
    let wanted = dagger.episodes as usize;
    let bar = progress_bar(
        (wanted * dagger.fractions.len()) as u64,
        &format!("round {round} relabel"),
    );
    let mut batches = 0u64;
    // The rest of each (episode, step)'s flight re-solved from its state there, in order: here
    // on every core, or as a Slurm array (the same results).
    let mut solve_batch = |pairs: &[(usize, u32)]| -> Result<Vec<Solved>, ExperimentError> {
        let jobs: Vec<Option<RelabelJob>> = pairs
            .iter()
            .map(|&(episode, step)| {
                let point = flown[episode].trajectory.as_ref()?.get(step as usize)?;
                let (r, v, m) = (point.state.r, point.state.v, point.state.m);
                Some(RelabelJob {
                    episode: episode as u64,
                    step,
                    state: [r[0], r[1], v[0], v[1], m],
                })
            })
            .collect();
        let solved = match &config.compute.slurm {
            None => jobs
                .par_iter()
                .map(|job| {
                    bar.inc(1);
                    job.as_ref().and_then(|job| solve_job::<P>(config, first, job))
                })
                .collect(),
            Some(slurm) => {
                batches += 1;
                let present: Vec<RelabelJob> = jobs.iter().flatten().copied().collect();
                let tag = format!("{round}-{batches}");
                let mut results = solve_on_slurm(config, slurm, dagger_dir, &tag, first, present)?.into_iter();
                bar.inc(jobs.len() as u64);
                jobs.iter()
                    .map(|job| job.as_ref().and_then(|_| results.next().flatten()))
                    .collect()
            }
        };
        Ok(solved)
    };
    let (solved, attempted): (Vec<Vec<RelabelTuple>>, usize) = if dagger.solvable_only && !dagger.fractions.is_empty() {
        // The earliest fraction probes each flight, largest miss first, until enough re-solve;
        // the other fractions are solved for those alone.
        let mut fractions = dagger.fractions.clone();
        fractions.sort_by(f64::total_cmp);
        let ranked: Vec<usize> = ranked_by_miss(eligible).iter().map(|o| o.episode).collect();
        let (kept, probed) = walk_probes(&ranked, wanted, |episodes| {
            let pairs: Vec<(usize, u32)> = episodes.iter().map(|&e| (e, step_at(e, fractions[0]))).collect();
            let found = solve_batch(&pairs)?;
            bar.inc_length(found.iter().filter(|f| f.is_none()).count() as u64);
            Ok::<_, ExperimentError>(found)
        })?;
        let rest: Vec<(usize, u32)> = kept
            .iter()
            .flat_map(|(episode, _)| fractions[1..].iter().map(move |&f| (*episode, step_at(*episode, f))))
            .collect();
        let more = solve_batch(&rest)?.into_iter().flatten();
        let solved = kept.into_iter().map(|(_, demo)| demo).chain(more).collect();
        (solved, probed + rest.len())
    } else {
        let jobs: Vec<(usize, u32)> = largest_misses(eligible, wanted)
            .into_iter()
            .flat_map(|o| {
                dagger
                    .fractions
                    .iter()
                    .map(move |&f| (o.episode, step_at(o.episode, f)))
            })
            .collect();
        (solve_batch(&jobs)?.into_iter().flatten().collect(), jobs.len())
    };
    bar.finish_and_clear();
    let count: usize = solved.iter().map(Vec::len).sum();
    let mut tuples = ReplayBuffer::new(P::OBS, 3, count.max(1));
    for t in solved.iter().flatten() {
        tuples.push(&Transition {
            obs: &t.obs,
            action: &t.action,
            reward: t.reward,
            next_obs: &t.next_obs,
            done: t.done,
            demonstration: true,
        });
    }
    Ok(Relabels {
        round,
        attempted: attempted as u64,
        converged: solved.len() as u64,
        tuples,
    })
}

/// The `count` outcomes that miss the accuracy goal the most, max(dr, dv) / [`ACCURACY_GOAL`]
/// (the earlier of equal misses first), returned in episode order. Fewer outcomes than `count`:
/// all of them.
fn largest_misses(outcomes: Vec<&EpisodeOutcome>, count: usize) -> Vec<&EpisodeOutcome> {
    if outcomes.len() <= count {
        return outcomes;
    }
    let mut largest = ranked_by_miss(outcomes);
    largest.truncate(count);
    largest.sort_by_key(|o| o.episode);
    largest
}

/// The outcomes from the largest miss of the accuracy goal to the smallest, max(dr, dv) /
/// [`ACCURACY_GOAL`], the earlier of equal misses first.
fn ranked_by_miss(mut outcomes: Vec<&EpisodeOutcome>) -> Vec<&EpisodeOutcome> {
    outcomes.sort_by(|a, b| miss(b).total_cmp(&miss(a)).then(a.episode.cmp(&b.episode)));
    outcomes
}

/// A flight's miss in units of the accuracy goal: max(dr, dv) / [`ACCURACY_GOAL`].
fn miss(outcome: &EpisodeOutcome) -> f64 {
    outcome.terminal.position.max(outcome.terminal.velocity) / ACCURACY_GOAL
}

/// The flights a round may relabel, in episode order: completed, with a step strictly inside
/// the flight, and missing by at most `max_miss` times the goal when that is set.
fn relabel_candidates<'a>(
    flown: &'a [EpisodeOutcome],
    scenarios: &[Scenario],
    max_miss: Option<f64>,
) -> Vec<&'a EpisodeOutcome> {
    flown
        .iter()
        .filter(|o| o.completed && scenarios[o.episode].steps >= 2)
        .filter(|o| max_miss.is_none_or(|cap| miss(o) <= cap))
        .collect()
}

/// Flights probed at once by [`walk_probes`]: enough to keep every core busy, few enough that
/// the probes past the quota waste little.
const PROBE_CHUNK: usize = 32;

/// Probes `ranked` in order, [`PROBE_CHUNK`] at a time (`probe` takes a chunk and answers for
/// each item, in order), until at least `quota` probes have succeeded (every success of the last
/// chunk is kept, so the result does not depend on how a chunk is solved). Returns the successes
/// in rank order and how many were probed.
fn walk_probes<T, E>(
    ranked: &[usize],
    quota: usize,
    mut probe: impl FnMut(&[usize]) -> Result<Vec<Option<T>>, E>,
) -> Result<(Vec<(usize, T)>, usize), E> {
    let mut kept = Vec::new();
    let mut probed = 0;
    for chunk in ranked.chunks(PROBE_CHUNK) {
        if kept.len() >= quota {
            break;
        }
        let results = probe(chunk)?;
        probed += chunk.len();
        kept.extend(chunk.iter().zip(results).filter_map(|(&item, r)| r.map(|t| (item, t))));
    }
    Ok((kept, probed))
}

/// The learner's flown actor as an f32 blob.
fn flown_blob(agent: &Sac, kind: ProblemKind) -> Result<Vec<u8>, ExperimentError> {
    actor_network(agent, kind)?
        .f32_blob("relabelling round")
        .map_err(|e| ExperimentError::Mismatch(format!("the actor does not export: {e}")))
}

/// A round's score on the evaluation seed's first `dagger.score_episodes` scenarios.
struct Score {
    within_goal: f64,
    summary: OutcomeSummary,
    /// The share within the goal of the onboard f32 controller with the SIL's dispersions
    /// (`dagger.dispersed`).
    within_goal_dispersed: Option<f64>,
}

/// Scores the learner on the evaluation seed's first `dagger.score_episodes` scenarios, and
/// under the SIL's dispersions when the rounds relabel dispersed flights.
fn score<P: Problem>(config: &ExperimentConfig, agent: &Sac) -> Result<Score, ExperimentError> {
    let outcomes = evaluate_agent::<MdpEnv<P>>(
        agent,
        &config.env,
        config.scenario,
        config.seeds.evaluation,
        config.dagger.score_episodes,
        false,
    )?;
    let within_goal_dispersed = if config.dagger.dispersed {
        let scenarios: Vec<Scenario> = (0..config.dagger.score_episodes)
            .map(|i| config.scenario.draw(config.seeds.evaluation, i))
            .collect();
        let blob = flown_blob(agent, P::KIND)?;
        let dispersions = &config.sil.dispersions;
        let (flown, _, _) = fly_blob_seeded(config, &blob, &scenarios, dispersions, config.seeds.evaluation, 0, None)?;
        Some(within_accuracy_goal(&flown))
    } else {
        None
    };
    Ok(Score {
        within_goal: within_accuracy_goal(&outcomes),
        summary: summarize(&outcomes),
        within_goal_dispersed,
    })
}

/// `ground train dagger`: `config.dagger.rounds` rounds from `start` (a learner checkpoint, e.g.
/// RUN/pretrain/best.safetensors, or an actor file, narrower ones widened) in RUN/dagger,
/// resuming whatever rounds are already there. With `relabels_from` (another run folder of the
/// same scenario, seeds, final eps and arrival margin) that run's completed rounds' relabels
/// become this run's first rounds, and its own rounds follow them from `start`.
pub fn dagger(
    config: &ExperimentConfig,
    config_dir: &Path,
    run: &Path,
    start: &Path,
    relabels_from: Option<&Path>,
) -> Result<DaggerSummary, ExperimentError> {
    if config.dagger.rounds == 0 {
        return Err(crate::config::ConfigError::Invalid("dagger.rounds is 0: no round to run".into()).into());
    }
    with_problem!(config.scenario.problem(), P => dagger_for::<P>(config, config_dir, run, start, relabels_from))
}

/// The relabels of another run's completed rounds (1, 2, ... while both a round's relabels and
/// its learner are there), refused unless they were solved for this config's problem.
fn completed_relabels(
    config: &ExperimentConfig,
    other: &Path,
    obs_dim: usize,
) -> Result<Vec<Relabels>, ExperimentError> {
    let path = other.join("config.toml");
    let text = std::fs::read_to_string(&path).map_err(|e| ExperimentError::Io(path.clone(), e))?;
    let theirs = ExperimentConfig::from_toml(&text)?;
    if theirs.relabel_problem() != config.relabel_problem() {
        return Err(ExperimentError::Mismatch(format!(
            "{} relabels another problem (scenario, seeds, final eps or arrival margin differ)",
            other.display()
        )));
    }
    let dir = other.join("dagger");
    let mut rounds = Vec::new();
    for round in 1.. {
        let path = relabels_file(&dir, round);
        if !path.exists() || !round_file(&dir, round).exists() {
            break;
        }
        rounds.push(load_relabels(&path, round, obs_dim)?);
    }
    if rounds.is_empty() {
        return Err(ExperimentError::Mismatch(format!(
            "{} holds no completed round",
            dir.display()
        )));
    }
    Ok(rounds)
}

fn dagger_for<P: Problem>(
    config: &ExperimentConfig,
    config_dir: &Path,
    run: &Path,
    start: &Path,
    relabels_from: Option<&Path>,
) -> Result<DaggerSummary, ExperimentError> {
    let device = config.device()?;
    let (mut buffer, _) = demonstration_buffer::<P>(config, config_dir)?;
    check_run(config, run)?;
    let dir = run.join("dagger");
    let mut agent = new_agent(config, true, P::OBS, device);
    let state_path = dir.join("state.json");
    if !round_file(&dir, 0).exists() {
        // A learner checkpoint, or a shipped model's actor alone (its critics are fresh: train
        // it with dagger.cloning_only).
        if let Err(checkpoint) = agent.load(start) {
            agent = new_agent(config, true, P::OBS, device);
            let widths = agent.start_from_actor(start).map_err(|_| checkpoint)?;
            if widths != config.sac.hidden {
                println!(
                    "{}: hidden layers {widths:?} widened to {:?} (the same actor until trained)",
                    start.display(),
                    config.sac.hidden
                );
            }
        }
        let inherited = match relabels_from {
            Some(other) => completed_relabels(config, other, P::OBS)?,
            None => Vec::new(),
        };
        prepare_run(config, run)?;
        // The inherited rounds are this run's own: its folder alone resumes it.
        for relabels in &inherited {
            save_relabels(&relabels_file(&dir, relabels.round), relabels)?;
        }
        if let Some(last) = inherited.last() {
            agent.save(&round_file(&dir, last.round))?;
        }
        // Written last: the start is complete once round 0 is there.
        agent.save(&round_file(&dir, 0))?;
        // A state left by an earlier start belongs to another learner.
        let _ = std::fs::remove_file(&state_path);
    }
    // The learner counts its updates since its first; this command's start at round 0.
    agent.load(&round_file(&dir, 0))?;
    let updates_before = agent.updates;
    // The last round with its learner saved (inherited rounds have relabels alone).
    let mut done = 0;
    for round in 1.. {
        if !relabels_file(&dir, round).exists() {
            break;
        }
        if round_file(&dir, round).exists() {
            done = round;
        }
    }
    agent.load(&round_file(&dir, done))?;
    let mut rows: Vec<RoundRow> = match std::fs::read(&state_path) {
        Ok(bytes) => serde_json::from_slice(&bytes)
            .map_err(|e| ExperimentError::Mismatch(format!("{} does not parse: {e}", state_path.display())))?,
        Err(_) => Vec::new(),
    };
    rows.retain(|r| r.round <= done);
    let mut last_relabels = (0, 0, 0);
    for round in 1..=done {
        let relabels = load_relabels(&relabels_file(&dir, round), round, P::OBS)?;
        buffer.extend_from(&relabels.tuples);
        last_relabels = (relabels.attempted, relabels.converged, relabels.tuples.len() as u64);
    }
    let updates = |agent: &Sac| agent.updates - updates_before;
    if rows.last().is_none_or(|r| r.round != done) {
        // Stopped between a round's checkpoint and its score.
        let clock = Instant::now();
        let score = score::<P>(config, &agent)?;
        rows.push(RoundRow {
            round: done,
            relabels_attempted: last_relabels.0,
            relabels_converged: last_relabels.1,
            tuples_added: last_relabels.2,
            buffer: buffer.len() as u64,
            updates: updates(&agent),
            within_goal: score.within_goal,
            within_goal_dispersed: score.within_goal_dispersed,
            summary: score.summary,
            seconds: clock.elapsed().as_secs_f64(),
        });
        write_logs(&dir, &rows, &agent, is_best(&rows))?;
    }
    let reached = |rows: &[RoundRow]| {
        config
            .dagger
            .stop_at
            .is_some_and(|goal| rows.last().is_some_and(|r| r.score() >= goal))
    };
    for round in done + 1..=config.dagger.rounds {
        if reached(&rows) {
            break;
        }
        let clock = Instant::now();
        let path = relabels_file(&dir, round);
        let relabels = if path.exists() {
            load_relabels(&path, round, P::OBS)?
        } else {
            let relabels = solve_relabels::<P>(config, &agent, round, &dir)?;
            save_relabels(&path, &relabels)?;
            relabels
        };
        buffer.extend_from(&relabels.tuples);
        // The sampler is seeded by the round and the agent's noise by its update count, so a
        // resumed round repeats exactly.
        let mut rng = sampler(config.seeds.train ^ SAMPLER_STREAM ^ round);
        let bar = progress_bar(config.dagger.updates, &format!("round {round} update"));
        for i in 0..config.dagger.updates {
            let batch = buffer.sample(config.sac.batch_size, &mut rng);
            if config.dagger.cloning_only {
                agent.cloning_update(&batch);
            } else {
                agent.update(&batch);
            }
            if i % 100 == 0 {
                bar.set_position(i);
            }
        }
        bar.finish_and_clear();
        agent.save(&round_file(&dir, round))?;
        let score = score::<P>(config, &agent)?;
        let (within_goal, summary) = (score.within_goal, score.summary);
        rows.push(RoundRow {
            round,
            relabels_attempted: relabels.attempted,
            relabels_converged: relabels.converged,
            tuples_added: relabels.tuples.len() as u64,
            buffer: buffer.len() as u64,
            updates: updates(&agent),
            within_goal,
            within_goal_dispersed: score.within_goal_dispersed,
            summary,
            seconds: clock.elapsed().as_secs_f64(),
        });
        // Time left: this command's mean round so far times the rounds left of the budget (an
        // upper bound when a goal may stop the rounds early).
        let timed: Vec<f64> = rows.iter().skip(1).map(|r| r.seconds).collect();
        let left = (config.dagger.rounds - round) as f64 * timed.iter().sum::<f64>() / timed.len().max(1) as f64;
        println!(
            "round {round} of {}: {} of {} relabels converged, {} tuples; within 0.01 AU and 0.01: {:.1} %{} \
             (dr p50 {:.4} AU, p95 {:.4}; dv p50 {:.4}, p95 {:.4}) [{:.0} s; at most {:.0} min left]",
            config.dagger.rounds,
            relabels.converged,
            relabels.attempted,
            relabels.tuples.len(),
            100.0 * within_goal,
            score.within_goal_dispersed.map_or(String::new(), |d| format!(
                ", {:.1} % with the SIL's dispersions",
                100.0 * d
            )),
            summary.terminal_position.p50,
            summary.terminal_position.p95,
            summary.terminal_velocity.p50,
            summary.terminal_velocity.p95,
            clock.elapsed().as_secs_f64(),
            left / 60.0
        );
        write_logs(&dir, &rows, &agent, is_best(&rows))?;
    }
    let best_round = best_row(&rows).map_or(0, |r| r.round);
    Ok(DaggerSummary {
        folder: dir,
        rows,
        best_round,
    })
}

/// The rounds recorded in a relabelling folder (`RUN/dagger/state.json`) and the best of them.
pub fn read_rounds(dir: &Path) -> Result<DaggerSummary, ExperimentError> {
    let path = dir.join("state.json");
    let bytes = std::fs::read(&path).map_err(|e| ExperimentError::Io(path.clone(), e))?;
    let rows: Vec<RoundRow> = serde_json::from_slice(&bytes)
        .map_err(|e| ExperimentError::Mismatch(format!("{} does not parse: {e}", path.display())))?;
    let best_round = best_row(&rows)
        .map(|r| r.round)
        .ok_or_else(|| ExperimentError::Mismatch(format!("{} records no round", path.display())))?;
    Ok(DaggerSummary {
        folder: dir.to_path_buf(),
        rows,
        best_round,
    })
}

/// The row with the largest share within the goal (the earliest of equals).
fn best_row(rows: &[RoundRow]) -> Option<&RoundRow> {
    rows.iter().rev().max_by(|a, b| a.score().total_cmp(&b.score()))
}

/// Is the last row the best so far?
fn is_best(rows: &[RoundRow]) -> bool {
    match (rows.last(), best_row(rows)) {
        (Some(last), Some(best)) => last.round == best.round,
        _ => false,
    }
}

/// state.json, rounds.csv and rounds.svg, and best.safetensors when `agent` is the best.
fn write_logs(dir: &Path, rows: &[RoundRow], agent: &Sac, best: bool) -> Result<(), ExperimentError> {
    if best {
        agent.save(&dir.join("best.safetensors"))?;
    }
    let json = serde_json::to_vec_pretty(rows).unwrap_or_default();
    write_file(&dir.join("state.json"), &json)?;
    let mut csv = String::from(RoundRow::HEADER);
    for row in rows {
        let _ = write!(csv, "{}", row.csv());
    }
    write_file(&dir.join("rounds.csv"), csv.as_bytes())?;
    let series = |name: &str, f: &dyn Fn(&RoundRow) -> f64| Series {
        name: name.into(),
        points: rows.iter().map(|r| (r.round as f64, f(r))).collect(),
        band: None,
    };
    // A chart that cannot be drawn yet (one point) is skipped: the CSV holds the numbers.
    let _ = line_chart(
        &dir.join("rounds.svg"),
        "DAgger-style rounds: scoring episodes within 0.01 AU and 0.01",
        "round",
        "share",
        &if rows.iter().any(|r| r.within_goal_dispersed.is_some()) {
            vec![
                series("within the goal", &|r| r.within_goal),
                series("with the SIL's dispersions", &|r| {
                    r.within_goal_dispersed.unwrap_or(f64::NAN)
                }),
            ]
        } else {
            vec![series("within the goal", &|r| r.within_goal)]
        },
        false,
    );
    let points: Vec<(f64, OutcomeSummary)> = rows.iter().map(|r| (r.round as f64, r.summary)).collect();
    residual_chart(
        &dir.join("rounds-residuals.svg"),
        "DAgger-style rounds: terminal residuals (scoring episodes)",
        "round",
        &points,
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use onboard::features::Residuals;

    fn outcome(episode: usize, dr: f64, dv: f64) -> EpisodeOutcome {
        EpisodeOutcome {
            episode,
            total_reward: 0.0,
            final_mass: 1.0,
            terminal: Residuals {
                position: dr,
                velocity: dv,
            },
            steps: 10,
            completed: true,
            error: None,
            non_finite_actions: 0,
            trajectory: None,
        }
    }

    #[test]
    fn the_relabelled_episodes_are_the_largest_misses_in_episode_order() {
        // Misses in goal units: 0.5, 3 (velocity), 2, 0.1, 2 (tie with 2: the earlier wins), 4.
        let flown = [
            outcome(0, 0.005, 0.001),
            outcome(1, 0.002, 0.03),
            outcome(2, 0.02, 0.0),
            outcome(3, 0.001, 0.001),
            outcome(4, 0.0, 0.02),
            outcome(5, 0.04, 0.04),
        ];
        let chosen = |count| -> Vec<usize> {
            largest_misses(flown.iter().collect(), count)
                .iter()
                .map(|o| o.episode)
                .collect()
        };
        assert_eq!(chosen(3), vec![1, 2, 5]);
        assert_eq!(chosen(4), vec![1, 2, 4, 5]);
        // As many as flown (the default: candidates = episodes): every one, in order.
        assert_eq!(chosen(6), vec![0, 1, 2, 3, 4, 5]);
        assert_eq!(chosen(9), vec![0, 1, 2, 3, 4, 5]);
    }

    #[test]
    fn flights_beyond_the_miss_cap_are_not_relabelled() {
        let scenarios: Vec<Scenario> = (0..5)
            .map(|i| shared::scenario::ScenarioKind::TransferHard.draw(3, i))
            .collect();
        let mut flown = vec![
            outcome(0, 0.005, 0.001),
            outcome(1, 0.2, 0.0),
            outcome(2, 0.0, 0.1),
            outcome(3, 0.1000001, 0.0),
            outcome(4, 0.5, 0.5),
        ];
        let kept = |flown: &[EpisodeOutcome], cap| -> Vec<usize> {
            relabel_candidates(flown, &scenarios, cap)
                .iter()
                .map(|o| o.episode)
                .collect()
        };
        assert_eq!(kept(&flown, None), vec![0, 1, 2, 3, 4]);
        // 10 times the goal: 0.1 AU or 0.1, inclusive.
        assert_eq!(kept(&flown, Some(10.0)), vec![0, 2]);
        assert_eq!(kept(&flown, Some(20.0)), vec![0, 1, 2, 3]);
        flown[0].completed = false;
        assert_eq!(kept(&flown, Some(20.0)), vec![1, 2, 3]);
    }

    #[test]
    fn probes_walk_the_ranking_in_chunks_until_the_quota_and_keep_the_last_chunk_whole() {
        // Items ranked 0..100; the probe succeeds on multiples of 3 and reports its item.
        let ranked: Vec<usize> = (0..100).collect();
        let probe = |chunk: &[usize]| -> Result<Vec<Option<usize>>, ()> {
            Ok(chunk
                .iter()
                .map(|&item| item.is_multiple_of(3).then_some(item * 10))
                .collect())
        };
        // 11 successes in the first chunk (0..32): a quota of 5 stops there, all 11 kept.
        let (kept, probed) = walk_probes(&ranked, 5, probe).unwrap();
        assert_eq!(probed, PROBE_CHUNK);
        assert_eq!(kept.len(), 11);
        assert!(kept.iter().all(|&(item, t)| item.is_multiple_of(3) && t == item * 10));
        assert!(kept.windows(2).all(|w| w[0].0 < w[1].0), "rank order");
        // A quota of 12 needs the second chunk (32..64: 11 more).
        let (kept, probed) = walk_probes(&ranked, 12, probe).unwrap();
        assert_eq!((kept.len(), probed), (22, 2 * PROBE_CHUNK));
        // More than can succeed: every item probed once.
        let (kept, probed) = walk_probes(&ranked, 1000, probe).unwrap();
        assert_eq!((kept.len(), probed), (34, 100));
        // A ranking that is not in item order is walked in its own order.
        let reversed: Vec<usize> = (0..100).rev().collect();
        let (kept, _) = walk_probes(&reversed, 1, probe).unwrap();
        assert_eq!(kept.first().map(|k| k.0), Some(99));
    }
}
