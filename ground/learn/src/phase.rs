//! What pretraining and RL share: a phase's bookkeeping (evaluations, loss logs, checkpoints,
//! learning curves, resumption) and the learner's deterministic flights.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use crate::run_folder::{save_replay, write_file};
use crate::sac::agent::{Sac, UpdateStats};
use crate::sac::replay::ReplayBuffer;
use crate::sac::trainer::LoopState;
use ground_core::charts::{line_chart, Series};
use ground_core::env::batch::{evaluate_batched, summarize, EpisodeOutcome, EvalError, OutcomeSummary};
use ground_core::env::{EnvConfig, Environment, FamilyOf, Geometry};

/// Loss statistics are averaged over at most this many updates per CSV row (fewer for short
/// phases, so every phase logs about 100 rows).
const UPDATE_LOG_EVERY: u64 = 1_000;

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

/// Deterministic episodes of the agent (tanh of the mean: what is flown) on scenarios
/// `0..count` of `seed`, all in lockstep with one network call per step.
pub fn evaluate_agent<E: Environment>(
    agent: &Sac,
    env: &EnvConfig,
    family: impl Into<FamilyOf<E::Geometry>>,
    seed: u64,
    count: u64,
    record: bool,
) -> Result<Vec<EpisodeOutcome<E::Geometry>>, EvalError> {
    let family = family.into();
    let scenarios: Vec<_> = (0..count).map(|i| E::Geometry::draw(&family, seed, i)).collect();
    evaluate_batched::<E, _>(env, &scenarios, |obs: &[E::Obs]| policy_batch(agent, obs), record)
}

/// The config's family in geometry `G`: refused when it is inclined and `G` planar.
pub(crate) fn family_of<G: Geometry>(config: &ExperimentConfig) -> Result<FamilyOf<G>, ExperimentError> {
    G::family_of(&config.family).ok_or_else(|| ExperimentError::Inclined {
        stage: "a planar environment",
        family: config.family.label().to_string(),
    })
}

/// The agent's deterministic actions for a batch of observations. An agent whose action size
/// is not `A`'s returns no actions (the drivers refuse the batch with its sizes).
pub fn policy_batch<O: AsRef<[f32]>, A: for<'a> TryFrom<&'a [f32]>>(agent: &Sac, obs: &[O]) -> Vec<A> {
    let flat: Vec<f32> = obs.iter().flat_map(|o| o.as_ref().iter().copied()).collect();
    agent
        .act(&flat, obs.len())
        .chunks_exact(agent.act_dim().max(1))
        .map_while(|c| A::try_from(c).ok())
        .collect()
}

/// A fresh agent of the config on `device` (the config's, asked by the caller before any work).
pub(crate) fn new_agent(config: &ExperimentConfig, pretraining: bool, obs_dim: usize, device: tch::Device) -> Sac {
    tch::set_num_threads(config.compute.threads);
    // The initial weights; every later draw is seeded by the agent itself (`Sac::noise_seed`).
    tch::manual_seed(config.seeds.train as i64);
    let mut agent = Sac::with_cloning_loss(
        config.sac_for(pretraining),
        obs_dim,
        config.action_dim(),
        device,
        config.cloning_loss(),
    );
    agent.noise_seed = config.seeds.train;
    agent.labels = config.learner_labels();
    agent
}

pub(crate) fn load_state(path: &Path) -> Result<Option<PhaseState>, ExperimentError> {
    match std::fs::read(path) {
        Ok(bytes) => serde_json::from_slice(&bytes)
            .map(Some)
            .map_err(|e| ExperimentError::Mismatch(format!("{} does not parse: {e}", path.display()))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(ExperimentError::Io(path.to_path_buf(), e)),
    }
}

/// Phase bookkeeping shared by pretraining and RL: logs, evaluations, checkpoints, plots.
pub(crate) struct Phase<'a> {
    pub(crate) dir: PathBuf,
    config: &'a ExperimentConfig,
    pub(crate) state: PhaseState,
    started: Instant,
    seconds_before: f64,
    pub(crate) bar: indicatif::ProgressBar,
    x_is_env_steps: bool,
    log_every: u64,
}

impl<'a> Phase<'a> {
    pub(crate) fn new(dir: PathBuf, config: &'a ExperimentConfig, state: PhaseState, total: u64, what: &str) -> Self {
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

    pub(crate) fn record_update(&mut self, env_steps: u64, stats: &UpdateStats) {
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

    pub(crate) fn evaluate<E: Environment>(&mut self, agent: &Sac, env_steps: u64) -> Result<EvalRow, ExperimentError> {
        let outcomes = evaluate_agent::<E>(
            agent,
            &self.config.env,
            family_of::<E::Geometry>(self.config)?,
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
    pub(crate) fn improves(&self, row: &EvalRow) -> bool {
        self.state
            .best
            .is_none_or(|b| row.summary.total_reward.mean > b.summary.total_reward.mean)
    }

    pub(crate) fn checkpoint(
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

/// One row of a phase's table (the relabelling rounds', the fine-tuning's evaluations).
pub(crate) trait LogRow: Serialize {
    /// The CSV header, newline-terminated.
    const HEADER: &'static str;
    /// The row as a CSV line, newline-terminated.
    fn csv(&self) -> String;
    /// Its x (round, step) and its flights' summary.
    fn point(&self) -> (f64, OutcomeSummary);
}

/// Writes a phase's rows as `state.json`, `NAME.csv` and `NAME-residuals.svg` (the terminal
/// residuals against x, titled `what`) in `dir`.
pub(crate) fn write_rows<R: LogRow>(
    dir: &Path,
    name: &str,
    rows: &[R],
    what: &str,
    x_label: &str,
) -> Result<(), ExperimentError> {
    write_file(
        &dir.join("state.json"),
        &serde_json::to_vec_pretty(rows).unwrap_or_default(),
    )?;
    let mut csv = String::from(R::HEADER);
    for row in rows {
        csv.push_str(&row.csv());
    }
    write_file(&dir.join(format!("{name}.csv")), csv.as_bytes())?;
    let points: Vec<(f64, OutcomeSummary)> = rows.iter().map(LogRow::point).collect();
    residual_chart(&dir.join(format!("{name}-residuals.svg")), what, x_label, &points);
    Ok(())
}
