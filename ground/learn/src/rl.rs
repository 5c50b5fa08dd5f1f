//! RL (docs/spec.md section 8): SAC from scratch (vanilla) or from the pretrained model and
//! its demonstration buffer, periodic evaluations, the best model kept, resumable.
//!
//! ```text
//! RUN/train-{scratch,pretrained}/{best,last}.safetensors, replay.ltrb, state.json, *.csv, *.svg
//! ```

use std::path::Path;

use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use crate::phase::family_of;
use crate::phase::{load_state, new_agent, Phase, PhaseState, PhaseSummary};
use crate::run_folder::{check_run, load_replay, prepare_run};
use crate::sac::agent::{Sac, UpdateStats};
use crate::sac::replay::{sampler, ReplayBuffer};
use crate::sac::trainer::{self, Episodic, LoopOptions, LoopState, StepOutcome, TrainObserver, WarmupPolicy};
use crate::with_flown_problem;
use ground_core::env::{EnvConfig, EnvError, Environment, FamilyOf, Geometry, MdpEnv, Problem};

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

/// `ground train rl`: RL from scratch or from the pretrained model and its buffer, evaluations
/// every `train.eval_every` environment steps, best model kept, resumable.
pub fn train(config: &ExperimentConfig, run: &Path, start: Start) -> Result<PhaseSummary, ExperimentError> {
    with_flown_problem!(config, P => train_for::<P>(config, run, start))
}

fn train_for<P: Problem>(config: &ExperimentConfig, run: &Path, start: Start) -> Result<PhaseSummary, ExperimentError> {
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
            let buffer = load_replay(&dir.join("replay.ltrb"), P::OBS, P::Geometry::ACT)?;
            let demos = buffer.demonstration_count();
            (buffer, state, demos)
        }
        (None, Start::Scratch) => (
            ReplayBuffer::new(P::OBS, P::Geometry::ACT, config.sac.replay_capacity),
            PhaseState::default(),
            0,
        ),
        (None, Start::Pretrained) => {
            let pre = run.join("pretrain");
            agent.load(&pre.join("best.safetensors"))?;
            let demo_buffer = load_replay(&pre.join("replay.ltrb"), P::OBS, P::Geometry::ACT)?;
            // Demonstrations stay in the buffer (docs/spec.md section 8), followed by the agent's own
            // experience in FIFO order.
            let mut buffer = ReplayBuffer::new(P::OBS, P::Geometry::ACT, config.sac.replay_capacity);
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
        let mut task =
            ScenarioTask::<MdpEnv<P>>::new(&config.env, family_of::<P::Geometry>(config)?, config.seeds.train)?;
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

impl<P: Problem> TrainObserver for RlObserver<'_, '_, P> {
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

/// The MDP of the config's scenario as an [`Episodic`] task: episode `e` is scenario `e` of
/// the training seed's stream. A step the environment refuses (e.g. a state leaving the
/// feature domain) ends the episode as terminal with the printed reward's worst value.
pub struct ScenarioTask<E: Environment> {
    env: E,
    family: FamilyOf<E::Geometry>,
    seed: u64,
    /// Steps the environment refused, each of which ended its episode.
    pub failed_steps: u64,
}

impl<E: Environment> ScenarioTask<E> {
    /// The task on a fresh environment of `config`; episode `e` flies scenario `e` of `family`
    /// drawn with `seed`.
    pub fn new(
        config: &EnvConfig,
        family: impl Into<FamilyOf<E::Geometry>>,
        seed: u64,
    ) -> Result<Self, ExperimentError> {
        let env = E::new(config).map_err(|e| ExperimentError::Mismatch(format!("environment: {e}")))?;
        Ok(Self {
            env,
            family: family.into(),
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
        E::Geometry::ACT
    }

    type Error = EnvError;

    fn reset(&mut self, episode: u64) -> Result<Vec<f32>, EnvError> {
        self.env
            .reset_drawn(self.family, self.seed, episode)
            .map(|o| o.as_ref().to_vec())
    }

    fn step(&mut self, action: &[f32]) -> StepOutcome {
        match self.env.step_slice(action) {
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
