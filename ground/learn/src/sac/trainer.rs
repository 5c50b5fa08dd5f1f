//! The SAC interaction loop: act, step, store, update (1 update per environment step after the
//! warm-up), evaluate periodically, keep the best model, checkpoint for resumption. Generic over
//! [`Episodic`] so the sanity task and the spacecraft problems run the same loop.

use rand_chacha::ChaCha8Rng;

use super::agent::{Sac, UpdateStats};
use super::replay::{ReplayBuffer, Transition};

/// An episodic task as the learner sees it: flat f32 observations and actions in [-1, 1].
pub trait Episodic {
    /// Why an episode could not start.
    type Error;
    /// Observation features.
    fn obs_dim(&self) -> usize;
    /// Action components.
    fn act_dim(&self) -> usize;
    /// Starts episode number `episode` (deterministic per task seed and episode number).
    fn reset(&mut self, episode: u64) -> Result<Vec<f32>, Self::Error>;
    /// One step under `action`.
    fn step(&mut self, action: &[f32]) -> StepOutcome;
}

/// The result of one environment step.
#[derive(Debug, Clone, PartialEq)]
pub struct StepOutcome {
    /// The observation after the step.
    pub obs: Vec<f32>,
    /// The step's reward.
    pub reward: f64,
    /// The episode reached a terminal state: no bootstrapping past it.
    pub terminal: bool,
    /// The episode was cut by a time limit that is not part of the state: bootstrap through it.
    pub truncated: bool,
}

/// How the exploration actions of the warm-up steps are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WarmupPolicy {
    /// Uniform random actions (an agent trained from scratch).
    Random,
    /// The agent's own stochastic policy (a pretrained agent).
    Agent,
}

/// Where the loop stands; checkpointed so a run resumes where it stopped.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LoopState {
    /// Environment steps taken so far.
    pub env_steps: u64,
    /// Episodes finished; the one in progress is episode number `episodes`.
    pub episodes: u64,
    /// Sum of rewards of the episode in progress.
    pub episode_reward: f64,
    /// Steps taken in the episode in progress (its newest transitions in the buffer).
    #[serde(default)]
    pub episode_steps: u64,
}

/// What the caller wants to hear about while the loop runs.
pub trait TrainObserver {
    /// After every gradient update.
    fn on_update(&mut self, _env_steps: u64, _stats: &UpdateStats) {}
    /// After every finished training episode.
    fn on_episode(&mut self, _env_steps: u64, _reward: f64) {}
    /// Every `eval_every` environment steps: evaluate the agent (and keep it if it is the best).
    fn evaluate(&mut self, env_steps: u64, agent: &Sac);
    /// Stop the loop early (an observer failed to write its outputs, say).
    fn stop(&self) -> bool {
        false
    }
    /// Every `checkpoint_every` steps and at the end: persist agent, buffer and loop state.
    fn checkpoint(&mut self, _agent: &Sac, _buffer: &ReplayBuffer, _state: &LoopState, _rng: &ChaCha8Rng) {}
}

/// Loop settings that are not SAC hyper-parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopOptions {
    /// The environment step count the loop runs up to.
    pub total_steps: u64,
    /// Environment steps between evaluations (0: none).
    pub eval_every: u64,
    /// Environment steps between checkpoints (0: only the one at the end).
    pub checkpoint_every: u64,
    /// How the actions of the first `warmup_steps` steps are chosen.
    pub warmup: WarmupPolicy,
}

/// An action drawn uniformly from [-1, 1]^dim (exploration before learning; the random baseline).
pub fn uniform_action(rng: &mut ChaCha8Rng, dim: usize) -> Vec<f32> {
    use rand_core::Rng;
    (0..dim)
        .map(|_| ((rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0)
        .collect()
}

/// Runs environment steps from `state.env_steps` to `options.total_steps`.
pub fn run<T: Episodic>(
    task: &mut T,
    agent: &mut Sac,
    buffer: &mut ReplayBuffer,
    state: &mut LoopState,
    rng: &mut ChaCha8Rng,
    options: &LoopOptions,
    observer: &mut dyn TrainObserver,
) -> Result<(), T::Error> {
    let act_dim = task.act_dim();
    let warmup_steps = agent.config.warmup_steps;
    let batch_size = agent.config.batch_size;
    let updates_per_step = agent.config.updates_per_step;
    let mut obs = resume_episode(task, buffer, state)?;
    while state.env_steps < options.total_steps && !observer.stop() {
        let action = if state.env_steps < warmup_steps && options.warmup == WarmupPolicy::Random {
            uniform_action(rng, act_dim)
        } else {
            agent.explore(&obs, 1, state.env_steps)
        };
        let out = task.step(&action);
        buffer.push(&Transition {
            obs: &obs,
            action: &action,
            reward: out.reward as f32,
            next_obs: &out.obs,
            done: out.terminal,
            demonstration: false,
        });
        state.env_steps += 1;
        state.episode_reward += out.reward;
        state.episode_steps += 1;
        if out.terminal || out.truncated {
            observer.on_episode(state.env_steps, state.episode_reward);
            state.episodes += 1;
            state.episode_reward = 0.0;
            state.episode_steps = 0;
            obs = task.reset(state.episodes)?;
        } else {
            obs = out.obs;
        }
        if state.env_steps >= warmup_steps && buffer.len() >= batch_size {
            for _ in 0..updates_per_step {
                let stats = agent.update(&buffer.sample(batch_size, rng));
                observer.on_update(state.env_steps, &stats);
            }
        }
        if options.eval_every > 0 && state.env_steps.is_multiple_of(options.eval_every) {
            observer.evaluate(state.env_steps, agent);
        }
        if options.checkpoint_every > 0 && state.env_steps.is_multiple_of(options.checkpoint_every) {
            observer.checkpoint(agent, buffer, state, rng);
        }
    }
    observer.checkpoint(agent, buffer, state, rng);
    Ok(())
}

/// The observation the loop continues from: episode `state.episodes` from its start, with the
/// steps already taken in it replayed from their stored actions. The environment is
/// deterministic given the actions, so a run resumed from a checkpoint taken mid-episode
/// continues exactly as one that never stopped (its state is never saved itself).
fn resume_episode<T: Episodic>(
    task: &mut T,
    buffer: &ReplayBuffer,
    state: &mut LoopState,
) -> Result<Vec<f32>, T::Error> {
    let mut obs = task.reset(state.episodes)?;
    state.episode_reward = 0.0;
    let taken = state.episode_steps as usize;
    let actions: Option<Vec<Vec<f32>>> = (1..=taken)
        .rev()
        .map(|back| buffer.newest(back).map(|t| t.action.to_vec()))
        .collect();
    match actions {
        Some(actions) => {
            for action in &actions {
                let out = task.step(action);
                state.episode_reward += out.reward;
                obs = out.obs;
            }
        }
        // Not in the buffer any more (a buffer shorter than an episode): restart the episode.
        None => state.episode_steps = 0,
    }
    Ok(obs)
}

/// Mean and standard deviation of `values`.
pub fn mean_std(values: &[f64]) -> (f64, f64) {
    let n = values.len().max(1) as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    (mean, var.sqrt())
}
