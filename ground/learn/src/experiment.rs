//! The learning phases of an experiment (docs/spec.md sections 7 and 8) in a run folder:
//!
//! ```text
//! RUN/config.toml                      the config that produced everything below
//! RUN/pretrain/{best,last}.safetensors the best (by evaluation) and latest learner state
//! RUN/pretrain/replay.ltrb             the demonstration buffer handed to RL
//! RUN/pretrain/{eval,updates}.csv      evaluation rows and loss averages, plus SVG plots
//! RUN/train-{scratch,pretrained}/...   the same for RL, plus state.json for resumption
//! ```
//!
//! Every file is written atomically; an interrupted phase resumes from its last checkpoint with
//! its replay buffer.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use shared::scenario::ScenarioKind;

use crate::config::{ConfigError, ExperimentConfig};
use crate::sac::agent::{CheckpointError, Sac, UpdateStats};
use crate::sac::replay::{sampler, ReplayBuffer, Transition};
use crate::sac::trainer::{self, Episodic, LoopOptions, LoopState, StepOutcome, TrainObserver, WarmupPolicy};
use ground_core::charts::{line_chart, Series};
use ground_core::demo::{default_tolerances, demonstrations, Demonstrations, Placement};
use ground_core::env::batch::{draw_scenarios, evaluate_batched, summarize, EpisodeOutcome, EvalError, OutcomeSummary};
use ground_core::env::{EnvConfig, EnvError, Environment, MdpEnv, Problem};
use ground_core::generate::{dataset_solve_request, read_dataset};
use ground_core::io::{atomic_write, decode_container, encode_container};
use ground_core::with_problem;

const REPLAY_MAGIC: [u8; 4] = *b"LTRB";
const REPLAY_VERSION: u16 = 1;
/// Loss statistics are averaged over at most this many updates per CSV row (fewer for short
/// phases, so every phase logs about 100 rows).
const UPDATE_LOG_EVERY: u64 = 1_000;

/// Why a phase could not run or stopped.
#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    /// The config was refused, or its dataset or device is not there.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The trajectory dataset could not be read or gave no demonstration tuples.
    #[error("dataset: {0}")]
    Dataset(String),
    /// A checkpoint or actor file could not be read or written.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// A file of the run folder could not be read or written: its path and the I/O error.
    #[error("{}: {}", .0.display(), .1)]
    Io(PathBuf, std::io::Error),
    /// The evaluation episodes could not be flown.
    #[error("evaluation: {0}")]
    Evaluation(EvalError),
    /// A file in the run folder belongs to another experiment (problem, shapes).
    #[error("{0}")]
    Mismatch(String),
    /// The environment refused to start an episode.
    #[error("environment: {0}")]
    Environment(EnvError),
}

// Not `#[from]`: the message already carries the evaluation error, so it is no separate source.
impl From<EvalError> for ExperimentError {
    fn from(e: EvalError) -> Self {
        Self::Evaluation(e)
    }
}

pub(crate) fn write_file(path: &Path, bytes: &[u8]) -> Result<(), ExperimentError> {
    atomic_write(path, bytes).map_err(|e| ExperimentError::Io(path.to_path_buf(), e))
}

/// How RL starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Start {
    /// Vanilla SAC: random warm-up actions, empty buffer.
    Scratch,
    /// From the pretraining phase's best model and its demonstration buffer.
    Pretrained,
}

impl Start {
    /// The phase's folder in the run: `train-scratch` or `train-pretrained`.
    pub fn folder(self) -> &'static str {
        match self {
            Self::Scratch => "train-scratch",
            Self::Pretrained => "train-pretrained",
        }
    }
}

/// One evaluation (100 deterministic episodes by default) during a phase.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EvalRow {
    /// Gradient updates done when evaluated.
    pub updates: u64,
    /// Environment steps taken when evaluated (0 in pretraining).
    pub env_steps: u64,
    /// Wall-clock seconds of the phase so far, across resumptions.
    pub seconds: f64,
    /// Reward, final mass and terminal residuals of the evaluation episodes.
    pub summary: OutcomeSummary,
}

impl EvalRow {
    const HEADER: &'static str = "updates,env_steps,seconds,episodes,completed,reward_mean,reward_std,\
final_mass_mean,dr_p50,dr_p95,dv_p50,dv_p95\n";

    fn csv(&self) -> String {
        let s = &self.summary;
        format!(
            "{},{},{:.1},{},{},{},{},{},{},{},{},{}\n",
            self.updates,
            self.env_steps,
            self.seconds,
            s.episodes,
            s.completed,
            s.total_reward.mean,
            s.total_reward.std,
            s.final_mass.mean,
            s.terminal_position.p50,
            s.terminal_position.p95,
            s.terminal_velocity.p50,
            s.terminal_velocity.p95
        )
    }
}

/// Where a phase stands, saved next to its last checkpoint.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PhaseState {
    /// The RL loop's position (unused in pretraining).
    pub loop_state: LoopState,
    /// Gradient updates done.
    pub updates: u64,
    /// Wall-clock seconds spent, across resumptions.
    pub seconds: f64,
    /// Every evaluation so far, in order (`eval.csv`).
    pub evaluations: Vec<EvalRow>,
    /// Loss averages logged so far, in order (`updates.csv`).
    pub update_log: Vec<UpdateRow>,
    /// The evaluation with the highest mean reward: the one `best.safetensors` holds.
    pub best: Option<EvalRow>,
    /// Word position of the replay sampler stream (restored on resume).
    pub sampler_word_pos: u128,
    /// Loss sums of the updates since the last log row, so a resumed phase logs the same rows.
    #[serde(default)]
    pub unlogged: UpdateAccumulator,
}

/// Loss averages over up to 1,000 updates (fewer in short phases, which log about 100 rows).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct UpdateRow {
    /// Gradient updates done at the end of the averaged span.
    pub updates: u64,
    /// Environment steps taken then (0 in pretraining).
    pub env_steps: u64,
    /// Mean of [`UpdateStats::critic_loss`].
    pub critic_loss: f64,
    /// Mean of [`UpdateStats::actor_loss`].
    pub actor_loss: f64,
    /// Mean of [`UpdateStats::temperature_loss`].
    pub temperature_loss: f64,
    /// Mean temperature alpha.
    pub temperature: f64,
    /// Mean entropy estimate -E[log pi].
    pub entropy: f64,
    /// Mean of [`UpdateStats::q_mean`].
    pub q_mean: f64,
    /// Mean of [`UpdateStats::behaviour_cloning_loss`].
    pub behaviour_cloning_loss: f64,
}

/// Loss sums of updates not yet averaged into an [`UpdateRow`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct UpdateAccumulator {
    sum: UpdateRow,
    count: u64,
}

impl UpdateAccumulator {
    fn add(&mut self, s: &UpdateStats) {
        self.sum.critic_loss += s.critic_loss;
        self.sum.actor_loss += s.actor_loss;
        self.sum.temperature_loss += s.temperature_loss;
        self.sum.temperature += s.temperature;
        self.sum.entropy += s.entropy;
        self.sum.q_mean += s.q_mean;
        self.sum.behaviour_cloning_loss += s.behaviour_cloning_loss;
        self.count += 1;
    }

    fn take(&mut self, updates: u64, env_steps: u64) -> UpdateRow {
        let n = self.count.max(1) as f64;
        let s = std::mem::take(&mut self.sum);
        self.count = 0;
        UpdateRow {
            updates,
            env_steps,
            critic_loss: s.critic_loss / n,
            actor_loss: s.actor_loss / n,
            temperature_loss: s.temperature_loss / n,
            temperature: s.temperature / n,
            entropy: s.entropy / n,
            q_mean: s.q_mean / n,
            behaviour_cloning_loss: s.behaviour_cloning_loss / n,
        }
    }
}

/// Deterministic episodes of the agent (tanh of the mean: what is flown) on scenarios
/// `0..count` of `seed`, all in lockstep with one network call per step.
pub fn evaluate_agent<E: Environment>(
    agent: &Sac,
    env: &EnvConfig,
    kind: ScenarioKind,
    seed: u64,
    count: u64,
    record: bool,
) -> Result<Vec<EpisodeOutcome>, EvalError> {
    let scenarios = draw_scenarios(kind, seed, count);
    evaluate_batched::<E, _>(env, &scenarios, |obs: &[E::Obs]| policy_batch(agent, obs), record)
}

/// The agent's deterministic actions for a batch of observations.
pub fn policy_batch<O: AsRef<[f32]>>(agent: &Sac, obs: &[O]) -> Vec<[f32; 3]> {
    let flat: Vec<f32> = obs.iter().flat_map(|o| o.as_ref().iter().copied()).collect();
    agent
        .act(&flat, obs.len())
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect()
}

/// The MDP of the config's scenario as an [`Episodic`] task: episode `e` is scenario `e` of
/// the training seed's stream. A step the environment refuses (e.g. a state leaving the
/// feature domain) ends the episode as terminal with the printed reward's worst value.
pub struct ScenarioTask<E: Environment> {
    env: E,
    kind: ScenarioKind,
    seed: u64,
    /// Steps the environment refused, each of which ended its episode.
    pub failed_steps: u64,
}

impl<E: Environment> ScenarioTask<E> {
    /// The task on a fresh environment of `config`; episode `e` flies scenario `e` of `kind` drawn
    /// with `seed`.
    pub fn new(config: &EnvConfig, kind: ScenarioKind, seed: u64) -> Result<Self, ExperimentError> {
        let env = E::new(config).map_err(|e| ExperimentError::Mismatch(format!("environment: {e}")))?;
        Ok(Self {
            env,
            kind,
            seed,
            failed_steps: 0,
        })
    }
}

impl<E: Environment> Episodic for ScenarioTask<E> {
    fn obs_dim(&self) -> usize {
        E::OBS
    }

    fn act_dim(&self) -> usize {
        3
    }

    type Error = EnvError;

    fn reset(&mut self, episode: u64) -> Result<Vec<f32>, EnvError> {
        self.env
            .reset_drawn(self.kind, self.seed, episode)
            .map(|o| o.as_ref().to_vec())
    }

    fn step(&mut self, action: &[f32]) -> StepOutcome {
        let a = [0, 1, 2].map(|i| action.get(i).copied().unwrap_or(0.0));
        match self.env.step(&a) {
            Ok(step) => StepOutcome {
                obs: step.observation.as_ref().to_vec(),
                reward: step.reward,
                terminal: step.done,
                truncated: false,
            },
            Err(_) => {
                self.failed_steps += 1;
                StepOutcome {
                    obs: self
                        .env
                        .observation()
                        .map(|o| o.as_ref().to_vec())
                        .unwrap_or(vec![0.0; E::OBS]),
                    reward: -2.0,
                    terminal: true,
                    truncated: false,
                }
            }
        }
    }
}

pub(crate) fn save_replay(path: &Path, buffer: &ReplayBuffer) -> Result<(), ExperimentError> {
    let bytes = encode_container(REPLAY_MAGIC, REPLAY_VERSION, buffer)
        .map_err(|e| ExperimentError::Io(path.to_path_buf(), std::io::Error::other(e.to_string())))?;
    write_file(path, &bytes)
}

pub(crate) fn load_replay(path: &Path, obs_dim: usize) -> Result<ReplayBuffer, ExperimentError> {
    let bytes = std::fs::read(path).map_err(|e| ExperimentError::Io(path.to_path_buf(), e))?;
    let buffer: ReplayBuffer = decode_container(REPLAY_MAGIC, REPLAY_VERSION, &bytes)
        .map_err(|e| ExperimentError::Mismatch(format!("replay buffer {}: {e}", path.display())))?;
    if buffer.obs_dim() != obs_dim || buffer.act_dim() != 3 {
        return Err(ExperimentError::Mismatch(format!(
            "replay buffer {} holds {}-feature observations, this problem has {obs_dim}",
            path.display(),
            buffer.obs_dim()
        )));
    }
    Ok(buffer)
}

fn load_state(path: &Path) -> Result<Option<PhaseState>, ExperimentError> {
    match std::fs::read(path) {
        Ok(bytes) => serde_json::from_slice(&bytes)
            .map(Some)
            .map_err(|e| ExperimentError::Mismatch(format!("{} does not parse: {e}", path.display()))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(ExperimentError::Io(path.to_path_buf(), e)),
    }
}

/// Refuses a run folder that holds a run of another experiment (reads only).
pub fn check_run(config: &ExperimentConfig, run: &Path) -> Result<(), ExperimentError> {
    let path = run.join("config.toml");
    let Ok(existing) = std::fs::read_to_string(&path) else {
        return Ok(());
    };
    let previous = ExperimentConfig::from_toml(&existing)?;
    // What the folder's checkpoints and saved relabels depend on (an averaged actor is part of
    // the checkpoints).
    let same = |c: &ExperimentConfig| (c.relabel_problem(), c.sac.hidden.clone(), c.sac.actor_averaging > 0.0);
    if same(&previous) != same(config) {
        return Err(ExperimentError::Mismatch(format!(
            "{} holds a run of another experiment (scenario, network, seeds, actor averaging, final eps or arrival margin differ); use a new folder",
            run.display()
        )));
    }
    Ok(())
}

/// Writes the config next to the phase outputs, or refuses if the run folder holds another one.
/// Phases call it once their inputs have loaded, so a refused phase writes nothing.
pub fn prepare_run(config: &ExperimentConfig, run: &Path) -> Result<(), ExperimentError> {
    check_run(config, run)?;
    write_file(&run.join("config.toml"), config.to_toml().as_bytes())
}

/// Phase bookkeeping shared by pretraining and RL: logs, evaluations, checkpoints, plots.
struct Phase<'a> {
    dir: PathBuf,
    config: &'a ExperimentConfig,
    state: PhaseState,
    started: Instant,
    seconds_before: f64,
    bar: indicatif::ProgressBar,
    x_is_env_steps: bool,
    log_every: u64,
}

impl<'a> Phase<'a> {
    fn new(dir: PathBuf, config: &'a ExperimentConfig, state: PhaseState, total: u64, what: &str) -> Self {
        let bar = ground_core::progress::bar(
            total,
            &format!("{what:>9} {{bar:36}} {{pos}}/{{len}} {{msg}} [{{elapsed}}<{{eta}}]"),
        );
        let seconds_before = state.seconds;
        Self {
            dir,
            config,
            state,
            started: Instant::now(),
            seconds_before,
            bar,
            x_is_env_steps: what != "pretrain",
            log_every: (total / 100).clamp(1, UPDATE_LOG_EVERY),
        }
    }

    fn seconds(&self) -> f64 {
        self.seconds_before + self.started.elapsed().as_secs_f64()
    }

    fn record_update(&mut self, env_steps: u64, stats: &UpdateStats) {
        self.state.updates += 1;
        self.state.unlogged.add(stats);
        if self.state.updates.is_multiple_of(self.log_every) {
            let row = self.state.unlogged.take(self.state.updates, env_steps);
            self.state.update_log.push(row);
        }
        if !self.x_is_env_steps {
            self.bar.set_position(self.state.updates);
        }
    }

    fn evaluate<E: Environment>(&mut self, agent: &Sac, env_steps: u64) -> Result<EvalRow, ExperimentError> {
        let outcomes = evaluate_agent::<E>(
            agent,
            &self.config.env,
            self.config.scenario,
            self.config.seeds.evaluation,
            self.config.train.eval_episodes,
            false,
        )?;
        let row = EvalRow {
            updates: self.state.updates,
            env_steps,
            seconds: self.seconds(),
            summary: summarize(&outcomes),
        };
        self.state.evaluations.push(row);
        self.bar.set_message(format!(
            "eval reward {:.3}, dr p50 {:.3} AU",
            row.summary.total_reward.mean, row.summary.terminal_position.p50
        ));
        Ok(row)
    }

    /// Is `row` better than the best so far (higher mean evaluation reward)?
    fn improves(&self, row: &EvalRow) -> bool {
        self.state
            .best
            .is_none_or(|b| row.summary.total_reward.mean > b.summary.total_reward.mean)
    }

    fn checkpoint(
        &mut self,
        agent: &Sac,
        buffer: Option<&ReplayBuffer>,
        rng: &ChaCha8Rng,
    ) -> Result<(), ExperimentError> {
        self.state.seconds = self.seconds();
        self.state.sampler_word_pos = rng.get_word_pos();
        agent.save(&self.dir.join("last.safetensors"))?;
        if let Some(buffer) = buffer {
            save_replay(&self.dir.join("replay.ltrb"), buffer)?;
        }
        let json = serde_json::to_vec_pretty(&self.state).unwrap_or_default();
        write_file(&self.dir.join("state.json"), &json)?;
        self.write_logs()
    }

    fn write_logs(&self) -> Result<(), ExperimentError> {
        let mut eval = String::from(EvalRow::HEADER);
        for row in &self.state.evaluations {
            eval.push_str(&row.csv());
        }
        write_file(&self.dir.join("eval.csv"), eval.as_bytes())?;
        let mut upd = String::from(
            "updates,env_steps,critic_loss,actor_loss,temperature_loss,temperature,entropy,q_mean,bc_loss\n",
        );
        for r in &self.state.update_log {
            let _ = writeln!(
                upd,
                "{},{},{},{},{},{},{},{},{}",
                r.updates,
                r.env_steps,
                r.critic_loss,
                r.actor_loss,
                r.temperature_loss,
                r.temperature,
                r.entropy,
                r.q_mean,
                r.behaviour_cloning_loss
            );
        }
        write_file(&self.dir.join("updates.csv"), upd.as_bytes())?;
        self.plot();
        Ok(())
    }

    /// Learning curves and losses (thesis Figures 5.1 to 5.4). A figure that cannot be drawn
    /// (too few points yet) is skipped: the CSV files hold the same numbers.
    fn plot(&self) {
        let x_label = if self.x_is_env_steps {
            "environment steps"
        } else {
            "gradient updates"
        };
        let x_eval = |r: &EvalRow| {
            if self.x_is_env_steps {
                r.env_steps as f64
            } else {
                r.updates as f64
            }
        };
        let x_upd = |r: &UpdateRow| {
            if self.x_is_env_steps {
                r.env_steps as f64
            } else {
                r.updates as f64
            }
        };
        let evals = &self.state.evaluations;
        let reward = Series {
            name: "mean evaluation reward".into(),
            points: evals.iter().map(|r| (x_eval(r), r.summary.total_reward.mean)).collect(),
            band: Some(
                evals
                    .iter()
                    .map(|r| {
                        let s = r.summary.total_reward;
                        (x_eval(r), s.mean - s.std, s.mean + s.std)
                    })
                    .collect(),
            ),
        };
        let _ = line_chart(
            &self.dir.join("eval-reward.svg"),
            "Evaluation reward",
            x_label,
            "episode reward",
            &[reward],
            false,
        );
        let points: Vec<(f64, OutcomeSummary)> = evals.iter().map(|r| (x_eval(r), r.summary)).collect();
        residual_chart(
            &self.dir.join("eval-residuals.svg"),
            "Terminal residuals (evaluation episodes)",
            x_label,
            &points,
        );
        let log = &self.state.update_log;
        let loss = |name: &str, f: &dyn Fn(&UpdateRow) -> f64| Series {
            name: name.into(),
            points: log.iter().map(|r| (x_upd(r), f(r))).collect(),
            band: None,
        };
        let _ = line_chart(
            &self.dir.join("critic-loss.svg"),
            "Critic loss",
            x_label,
            "loss",
            &[loss("critic loss", &|r| r.critic_loss)],
            true,
        );
        let _ = line_chart(
            &self.dir.join("actor-loss.svg"),
            "Actor loss",
            x_label,
            "loss",
            &[loss("actor loss (soft)", &|r| r.actor_loss)],
            false,
        );
        let _ = line_chart(
            &self.dir.join("temperature.svg"),
            "Temperature and entropy",
            x_label,
            "value",
            &[
                loss("temperature alpha", &|r| r.temperature),
                loss("entropy estimate", &|r| r.entropy),
            ],
            false,
        );
    }
}

/// Terminal residual medians and 95th percentiles (log scale) against `x`. Not drawn while
/// there is too little to draw: the CSV files next to it hold the same numbers.
pub(crate) fn residual_chart(path: &Path, title: &str, x_label: &str, points: &[(f64, OutcomeSummary)]) {
    let series = |name: &str, f: &dyn Fn(&OutcomeSummary) -> f64| Series {
        name: name.into(),
        points: points.iter().map(|(x, s)| (*x, f(s))).collect(),
        band: None,
    };
    let _ = line_chart(
        path,
        title,
        x_label,
        "AU or canonical velocity",
        &[
            series("dr median (AU)", &|s| s.terminal_position.p50),
            series("dr 95th percentile (AU)", &|s| s.terminal_position.p95),
            series("dv median", &|s| s.terminal_velocity.p50),
            series("dv 95th percentile", &|s| s.terminal_velocity.p95),
        ],
        true,
    );
}

/// `ground train pretrain`: demonstrations into the buffer, N_pt updates, evaluations every
/// `pretrain.eval_every` updates, the best model kept (docs/spec.md section 8).
pub fn pretrain(config: &ExperimentConfig, config_dir: &Path, run: &Path) -> Result<PhaseSummary, ExperimentError> {
    with_problem!(config.scenario.problem(), P => pretrain_for::<P>(config, config_dir, run))
}

/// What a phase ended with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhaseSummary {
    /// The phase's folder in the run (`RUN/pretrain`, `RUN/train-*`).
    pub folder: PathBuf,
    /// Gradient updates done in the phase.
    pub updates: u64,
    /// Environment steps taken (0 for pretraining).
    pub env_steps: u64,
    /// Wall-clock seconds spent, across resumptions.
    pub seconds: f64,
    /// The best evaluation (highest mean reward), the model in `best.safetensors`.
    pub best: Option<EvalRow>,
    /// Trajectory records turned into demonstrations (pretraining only).
    pub demonstration_records: usize,
    /// Demonstration tuples in the phase's replay buffer.
    pub demonstration_tuples: usize,
}

/// The demonstration tuples of the config's dataset (refused when the dataset is of another
/// problem or arrival margin), with the dataset file and its record count.
pub fn load_demonstrations<P: Problem>(
    config: &ExperimentConfig,
    config_dir: &Path,
) -> Result<(Demonstrations<P::Obs>, PathBuf, usize), ExperimentError> {
    let file = config.dataset_file(config_dir)?;
    let dataset = read_dataset(&file).map_err(|e| ExperimentError::Dataset(format!("{}: {e}", file.display())))?;
    if dataset.manifest.scenario.problem() != P::KIND {
        return Err(ExperimentError::Mismatch(format!(
            "dataset {} holds {} trajectories, the config is for {}",
            file.display(),
            dataset.manifest.scenario.name(),
            config.scenario.name()
        )));
    }
    // Relabels are solved with the config's margin: demonstrations of another would teach two
    // arrival times. The run's request says it; a folder without one (written before it
    // existed, or a file moved out of its folder) shows it by its records.
    let request = dataset_solve_request(&file).map_err(|e| ExperimentError::Dataset(e.to_string()))?;
    let margin = match request {
        Some(request) => request.arrival_margin_steps,
        None => dataset
            .records
            .iter()
            .map(|r| Placement::whole(r).episode.steps - r.scenario.steps)
            .max()
            .unwrap_or(0),
    };
    if margin != config.generate.arrival_margin {
        return Err(ExperimentError::Mismatch(format!(
            "dataset {} was solved to arrive {margin} steps early, the config asks for generate.arrival_margin = {}",
            file.display(),
            config.generate.arrival_margin
        )));
    }
    let filter = config.pretrain.records;
    let demos = demonstrations::<P>(&dataset.records, &config.env, filter, &default_tolerances());
    Ok((demos, file, dataset.records.len()))
}

/// The demonstration tuples of the config's dataset as replay transitions.
pub fn demonstration_buffer<P: Problem>(
    config: &ExperimentConfig,
    config_dir: &Path,
) -> Result<(ReplayBuffer, usize), ExperimentError> {
    let (demos, file, records) = load_demonstrations::<P>(config, config_dir)?;
    if demos.transitions.is_empty() {
        return Err(ExperimentError::Dataset(format!(
            "{} gave no demonstration tuples ({} records, {} failed, {} filtered out)",
            file.display(),
            records,
            demos.failed.len(),
            demos.filtered_out
        )));
    }
    let mut buffer = ReplayBuffer::new(P::OBS, 3, config.sac.replay_capacity.max(demos.transitions.len()));
    push_demonstrations(&mut buffer, &demos.transitions);
    Ok((buffer, demos.used))
}

/// Appends demonstration tuples to a replay buffer, flagged as demonstrations.
pub fn push_demonstrations<O: AsRef<[f32]>>(
    buffer: &mut ReplayBuffer,
    transitions: &[ground_core::demo::Transition<O>],
) {
    for t in transitions {
        buffer.push(&Transition {
            obs: t.observation.as_ref(),
            action: &t.action,
            reward: t.reward as f32,
            next_obs: t.next_observation.as_ref(),
            done: t.done,
            demonstration: true,
        });
    }
}

/// A fresh agent of the config on `device` (the config's, asked by the caller before any work).
pub(crate) fn new_agent(config: &ExperimentConfig, pretraining: bool, obs_dim: usize, device: tch::Device) -> Sac {
    tch::set_num_threads(config.compute.threads);
    // The initial weights; every later draw is seeded by the agent itself (`Sac::noise_seed`).
    tch::manual_seed(config.seeds.train as i64);
    let mut agent = Sac::with_cloning_loss(config.sac_for(pretraining), obs_dim, 3, device, config.cloning_loss());
    agent.noise_seed = config.seeds.train;
    agent
}

fn pretrain_for<P: Problem>(
    config: &ExperimentConfig,
    config_dir: &Path,
    run: &Path,
) -> Result<PhaseSummary, ExperimentError>
where
    MdpEnv<P>: Environment,
{
    let device = config.device()?;
    let (buffer, used) = demonstration_buffer::<P>(config, config_dir)?;
    prepare_run(config, run)?;
    let dir = run.join("pretrain");
    let mut agent = new_agent(config, true, P::OBS, device);
    let mut rng = sampler(config.seeds.train);
    let state = load_state(&dir.join("state.json"))?.unwrap_or_default();
    if state.updates > 0 {
        agent.load(&dir.join("last.safetensors"))?;
        rng.set_word_pos(state.sampler_word_pos);
    }
    let total = config.pretrain.updates;
    let mut phase = Phase::new(dir.clone(), config, state, total, "pretrain");
    phase.bar.set_position(phase.state.updates);
    // A finished phase asked for more updates continues; asked for the same, it only reports.
    if phase.state.updates < total || phase.state.evaluations.is_empty() {
        // Evaluate the untrained policy once, so the curve starts at update 0.
        if phase.state.evaluations.is_empty() {
            let row = phase.evaluate::<MdpEnv<P>>(&agent, 0)?;
            phase.state.best = Some(row);
            agent.save(&dir.join("best.safetensors"))?;
        }
        while phase.state.updates < total {
            let stats = agent.update(&buffer.sample(config.sac.batch_size, &mut rng));
            phase.record_update(0, &stats);
            if phase.state.updates.is_multiple_of(config.pretrain.eval_every) || phase.state.updates == total {
                let row = phase.evaluate::<MdpEnv<P>>(&agent, 0)?;
                if phase.improves(&row) {
                    phase.state.best = Some(row);
                    agent.save(&dir.join("best.safetensors"))?;
                }
                phase.checkpoint(&agent, None, &rng)?;
            }
        }
        save_replay(&dir.join("replay.ltrb"), &buffer)?;
        phase.checkpoint(&agent, None, &rng)?;
    }
    phase.bar.finish();
    Ok(PhaseSummary {
        folder: dir,
        updates: phase.state.updates,
        env_steps: 0,
        seconds: phase.state.seconds,
        best: phase.state.best,
        demonstration_records: used,
        demonstration_tuples: buffer.demonstration_count(),
    })
}

/// `ground train rl`: RL from scratch or from the pretrained model and its buffer, evaluations
/// every `train.eval_every` environment steps, best model kept, resumable.
pub fn train(config: &ExperimentConfig, run: &Path, start: Start) -> Result<PhaseSummary, ExperimentError> {
    with_problem!(config.scenario.problem(), P => train_for::<P>(config, run, start))
}

fn train_for<P: Problem>(config: &ExperimentConfig, run: &Path, start: Start) -> Result<PhaseSummary, ExperimentError>
where
    MdpEnv<P>: Environment,
{
    let device = config.device()?;
    check_run(config, run)?;
    let dir = run.join(start.folder());
    let mut agent = new_agent(config, false, P::OBS, device);
    if start == Start::Scratch {
        // Vanilla SAC: no demonstrations, so no behaviour-cloning term and no 1/mean|Q| scaling
        // of the actor loss, whatever the config keeps for the pretrained arm.
        agent.config.behaviour_cloning = 0.0;
    }
    let mut rng = sampler(config.seeds.train ^ 0x7261_696e);
    let state = load_state(&dir.join("state.json"))?;
    let (mut buffer, state, demonstrations) = match (state, start) {
        (Some(state), _) => {
            agent.load(&dir.join("last.safetensors"))?;
            rng.set_word_pos(state.sampler_word_pos);
            let buffer = load_replay(&dir.join("replay.ltrb"), P::OBS)?;
            let demos = buffer.demonstration_count();
            (buffer, state, demos)
        }
        (None, Start::Scratch) => (
            ReplayBuffer::new(P::OBS, 3, config.sac.replay_capacity),
            PhaseState::default(),
            0,
        ),
        (None, Start::Pretrained) => {
            let pre = run.join("pretrain");
            agent.load(&pre.join("best.safetensors"))?;
            let demo_buffer = load_replay(&pre.join("replay.ltrb"), P::OBS)?;
            // Demonstrations stay in the buffer (docs/spec.md section 8), followed by the agent's own
            // experience in FIFO order.
            let mut buffer = ReplayBuffer::new(P::OBS, 3, config.sac.replay_capacity);
            buffer.extend_from(&demo_buffer);
            let demos = buffer.demonstration_count();
            (buffer, PhaseState::default(), demos)
        }
    };
    prepare_run(config, run)?;
    // The pretrained agent's optimiser moments and update count carry over; the RL loop counts
    // its own updates from here.
    let warmup = match start {
        Start::Scratch => WarmupPolicy::Random,
        Start::Pretrained => WarmupPolicy::Agent,
    };
    let total = config.train.env_steps;
    let mut phase = Phase::new(dir.clone(), config, state, total, start.folder());
    phase.bar.set_position(phase.state.loop_state.env_steps);
    if phase.state.loop_state.env_steps < total || phase.state.evaluations.is_empty() {
        if phase.state.evaluations.is_empty() {
            let row = phase.evaluate::<MdpEnv<P>>(&agent, 0)?;
            phase.state.best = Some(row);
            agent.save(&dir.join("best.safetensors"))?;
        }
        let mut task = ScenarioTask::<MdpEnv<P>>::new(&config.env, config.scenario, config.seeds.train)?;
        let options = LoopOptions {
            total_steps: total,
            eval_every: config.train.eval_every,
            checkpoint_every: config.train.checkpoint_every,
            warmup,
        };
        let mut loop_state = phase.state.loop_state.clone();
        let mut observer = RlObserver::<P> {
            phase: &mut phase,
            error: None,
            marker: std::marker::PhantomData,
        };
        trainer::run(
            &mut task,
            &mut agent,
            &mut buffer,
            &mut loop_state,
            &mut rng,
            &options,
            &mut observer,
        )
        .map_err(ExperimentError::Environment)?;
        if let Some(e) = observer.error.take() {
            return Err(e);
        }
        // trainer::run checkpointed at its end (through the observer).
        phase.state.loop_state = loop_state;
    }
    phase.bar.finish();
    Ok(PhaseSummary {
        folder: dir,
        updates: phase.state.updates,
        env_steps: phase.state.loop_state.env_steps,
        seconds: phase.state.seconds,
        best: phase.state.best,
        demonstration_records: 0,
        demonstration_tuples: demonstrations,
    })
}

struct RlObserver<'p, 'c, P: Problem> {
    phase: &'p mut Phase<'c>,
    error: Option<ExperimentError>,
    marker: std::marker::PhantomData<P>,
}

impl<P: Problem> TrainObserver for RlObserver<'_, '_, P>
where
    MdpEnv<P>: Environment,
{
    fn on_update(&mut self, env_steps: u64, stats: &UpdateStats) {
        self.phase.record_update(env_steps, stats);
    }

    fn on_episode(&mut self, env_steps: u64, _reward: f64) {
        self.phase.bar.set_position(env_steps);
    }

    fn evaluate(&mut self, env_steps: u64, agent: &Sac) {
        match self.phase.evaluate::<MdpEnv<P>>(agent, env_steps) {
            Ok(row) => {
                if self.phase.improves(&row) {
                    self.phase.state.best = Some(row);
                    if let Err(e) = agent.save(&self.phase.dir.join("best.safetensors")) {
                        self.error.get_or_insert(e.into());
                    }
                }
            }
            Err(e) => {
                self.error.get_or_insert(e);
            }
        }
    }

    fn stop(&self) -> bool {
        self.error.is_some()
    }

    fn checkpoint(&mut self, agent: &Sac, buffer: &ReplayBuffer, state: &LoopState, rng: &ChaCha8Rng) {
        self.phase.state.loop_state = state.clone();
        if let Err(e) = self.phase.checkpoint(agent, Some(buffer), rng) {
            self.error.get_or_insert(e);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run folder continues under a config that only asks for more work, and refuses one whose
    /// checkpoints or relabels would mean something else.
    #[test]
    fn a_run_folder_refuses_a_config_of_another_experiment() {
        let run = std::env::temp_dir().join(format!("lowthrust-check-run-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&run);
        std::fs::create_dir_all(&run).unwrap();
        let base = "scenario = \"rendezvous-circular\"\n[generate]\nfinal_eps = 0.016\n";
        let config = |extra: &str| ExperimentConfig::from_toml(&format!("{base}{extra}")).unwrap();
        prepare_run(&config(""), &run).unwrap();
        assert!(check_run(&config("[pretrain]\nupdates = 123456\n"), &run).is_ok());
        for other in [
            "arrival_margin = 2\n",
            "[seeds]\ntrain = 99\n",
            "[sac]\nhidden = [64, 64]\n",
        ] {
            assert!(
                matches!(check_run(&config(other), &run), Err(ExperimentError::Mismatch(_))),
                "{other}"
            );
        }
        let other_eps =
            ExperimentConfig::from_toml("scenario = \"rendezvous-circular\"\n[generate]\nfinal_eps = 0.25\n").unwrap();
        assert!(matches!(check_run(&other_eps, &run), Err(ExperimentError::Mismatch(_))));
        std::fs::remove_dir_all(&run).unwrap();
    }
}
