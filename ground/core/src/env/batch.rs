//! Many episodes at once (Monte Carlo evaluation, docs/spec.md section 9): a policy flown from a list of
//! scenarios, per-episode figures out.
//!
//! Two drivers, same results:
//! - [`evaluate`]: one rayon task per episode, the policy is a `Fn(&Obs) -> action` shared by
//!   the threads (an onboard MLP, a feedback law, a CPU network);
//! - [`evaluate_batched`]: all episodes in lockstep, the policy called once per step with the
//!   observations of every running episode (a GPU network), the environments stepped in
//!   parallel.
//!
//! An episode that fails (propagation error, state leaving the feature domain) stops there and
//! reports its error and its figures so far; the others go on.

use onboard::features::Residuals;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use shared::mission::MissionFamily;
use shared::scenario::Scenario;

use super::{ActionOf, CommandOf, EnvConfig, EnvError, Environment, Geometry, Planar, ScenarioOf, StateOf};

/// One point of a flown trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajectoryPoint<G: Geometry = Planar> {
    /// Step index (0 = departure).
    pub step: u32,
    /// Spacecraft state at that step (canonical).
    pub state: StateOf<G>,
    /// The command flown over the step that ended here (`None` at departure).
    pub command: Option<CommandOf<G>>,
    /// Reward of the step that ended here (0 at departure).
    pub reward: f64,
}

/// What one episode gave.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeOutcome<G: Geometry = Planar> {
    /// Position of the scenario in the list given.
    pub episode: usize,
    /// Sum of the step rewards.
    pub total_reward: f64,
    /// Mass at the last state reached (fraction of m0).
    pub final_mass: f64,
    /// Residuals at the last state reached (terminal dr, dv when completed).
    pub terminal: Residuals,
    /// Steps flown.
    pub steps: u32,
    /// True when the episode reached its terminal step.
    pub completed: bool,
    /// Why the episode stopped early.
    pub error: Option<EnvError>,
    /// Steps whose action was non-finite (flown as thrust off).
    pub non_finite_actions: u32,
    /// Departure plus one point per step, when asked for.
    pub trajectory: Option<Vec<TrajectoryPoint<G>>>,
}

/// Why a batch evaluation could not run at all.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum EvalError {
    /// The config is unusable (checked once, before any episode).
    #[error("{0}")]
    Env(EnvError),
    /// The batched policy returned `got` actions for `expected` observations.
    #[error("the policy returned {got} actions for {expected} observations")]
    PolicyBatch {
        /// Observations passed (running episodes).
        expected: usize,
        /// Actions returned.
        got: usize,
    },
}

/// Scenarios 0..count of the stream `seed` of `family`.
pub fn draw_scenarios(family: impl Into<MissionFamily>, seed: u64, count: u64) -> Vec<Scenario> {
    let family = family.into();
    (0..count).map(|i| family.draw(seed, i)).collect()
}

/// The running figures of one episode.
struct Tally<G: Geometry> {
    outcome: EpisodeOutcome<G>,
}

impl<G: Geometry> Tally<G> {
    fn start<E: Environment<Geometry = G>>(
        env: &mut E,
        episode: usize,
        scenario: &ScenarioOf<G>,
        record: bool,
    ) -> (Self, Option<E::Obs>) {
        let mut outcome = EpisodeOutcome {
            episode,
            total_reward: 0.0,
            final_mass: 1.0,
            terminal: Residuals {
                position: f64::NAN,
                velocity: f64::NAN,
            },
            steps: 0,
            completed: false,
            error: None,
            non_finite_actions: 0,
            trajectory: None,
        };
        let obs = match env.reset(scenario) {
            Ok(obs) => obs,
            Err(e) => {
                outcome.error = Some(e);
                return (Self { outcome }, None);
            }
        };
        if let Some(state) = env.state() {
            outcome.final_mass = G::mass(&state);
            if record {
                let mut points = Vec::with_capacity(G::plan(scenario).steps as usize + 1);
                points.push(TrajectoryPoint {
                    step: 0,
                    state,
                    command: None,
                    reward: 0.0,
                });
                outcome.trajectory = Some(points);
            }
        }
        (Self { outcome }, Some(obs))
    }

    /// Steps `env` under `action`; returns the next observation while the episode runs.
    fn advance<E: Environment<Geometry = G>>(&mut self, env: &mut E, action: &ActionOf<G>) -> Option<E::Obs> {
        match env.step(action) {
            Ok(step) => {
                let o = &mut self.outcome;
                o.total_reward += step.reward;
                o.final_mass = step.info.mass;
                o.terminal = step.info.residuals;
                o.steps = step.info.step;
                o.non_finite_actions += u32::from(step.info.non_finite_action);
                if let Some(points) = o.trajectory.as_mut() {
                    points.push(TrajectoryPoint {
                        step: step.info.step,
                        state: step.info.state,
                        command: Some(step.info.command),
                        reward: step.reward,
                    });
                }
                if step.done {
                    o.completed = true;
                    None
                } else {
                    Some(step.observation)
                }
            }
            Err(e) => {
                self.outcome.error = Some(e);
                None
            }
        }
    }
}

/// Flies one episode of `scenario` with `policy` in `env`.
pub fn run_episode<E: Environment>(
    env: &mut E,
    episode: usize,
    scenario: &ScenarioOf<E::Geometry>,
    mut policy: impl FnMut(&E::Obs) -> ActionOf<E::Geometry>,
    record: bool,
) -> EpisodeOutcome<E::Geometry> {
    let (mut tally, mut obs) = Tally::start(env, episode, scenario, record);
    while let Some(o) = obs {
        obs = tally.advance(env, &policy(&o));
    }
    tally.outcome
}

/// Flies every scenario with `policy`, one rayon task per episode; outcomes in scenario order.
pub fn evaluate<E, F>(
    config: &EnvConfig,
    scenarios: &[ScenarioOf<E::Geometry>],
    policy: F,
    record: bool,
) -> Result<Vec<EpisodeOutcome<E::Geometry>>, EvalError>
where
    E: Environment,
    F: Fn(&E::Obs) -> ActionOf<E::Geometry> + Sync,
{
    let template = E::new(config).map_err(EvalError::Env)?;
    drop(template);
    Ok(scenarios
        .par_iter()
        .enumerate()
        .map_init(
            || E::new(config),
            |env, (i, scenario)| match env {
                Ok(env) => run_episode(env, i, scenario, &policy, record),
                // Unreachable in practice: the same config was accepted above.
                Err(e) => failed(i, *e),
            },
        )
        .collect())
}

fn failed<G: Geometry>(episode: usize, error: EnvError) -> EpisodeOutcome<G> {
    EpisodeOutcome {
        episode,
        total_reward: 0.0,
        final_mass: f64::NAN,
        terminal: Residuals {
            position: f64::NAN,
            velocity: f64::NAN,
        },
        steps: 0,
        completed: false,
        error: Some(error),
        non_finite_actions: 0,
        trajectory: None,
    }
}

/// Flies every scenario in lockstep: each round, `policy` gets the observations of all running
/// episodes (in scenario order) and returns one action each; the environments step in
/// parallel. Episodes of different lengths drop out as they finish.
pub fn evaluate_batched<E, F>(
    config: &EnvConfig,
    scenarios: &[ScenarioOf<E::Geometry>],
    mut policy: F,
    record: bool,
) -> Result<Vec<EpisodeOutcome<E::Geometry>>, EvalError>
where
    E: Environment,
    F: FnMut(&[E::Obs]) -> Vec<ActionOf<E::Geometry>>,
{
    struct Slot<E: Environment> {
        env: E,
        tally: Tally<E::Geometry>,
        obs: Option<E::Obs>,
    }
    let mut slots: Vec<Slot<E>> = scenarios
        .par_iter()
        .enumerate()
        .map(|(i, scenario)| {
            let mut env = E::new(config)?;
            let (tally, obs) = Tally::start(&mut env, i, scenario, record);
            Ok(Slot { env, tally, obs })
        })
        .collect::<Result<_, EnvError>>()
        .map_err(EvalError::Env)?;
    loop {
        let observations: Vec<E::Obs> = slots.iter().filter_map(|s| s.obs).collect();
        if observations.is_empty() {
            break;
        }
        let actions = policy(&observations);
        if actions.len() != observations.len() {
            return Err(EvalError::PolicyBatch {
                expected: observations.len(),
                got: actions.len(),
            });
        }
        let mut running: Vec<&mut Slot<E>> = slots.iter_mut().filter(|s| s.obs.is_some()).collect();
        running
            .par_iter_mut()
            .zip(actions.par_iter())
            .for_each(|(slot, action)| {
                slot.obs = slot.tally.advance(&mut slot.env, action);
            });
    }
    Ok(slots.into_iter().map(|s| s.tally.outcome).collect())
}

/// Mean, standard deviation and percentiles of one figure.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    /// Number of finite values.
    pub count: usize,
    /// Mean.
    pub mean: f64,
    /// Standard deviation (population).
    pub std: f64,
    /// Smallest value.
    pub min: f64,
    /// 5th percentile (nearest rank).
    pub p05: f64,
    /// Median (nearest rank).
    pub p50: f64,
    /// 95th percentile (nearest rank).
    pub p95: f64,
    /// Largest value.
    pub max: f64,
}

impl Stats {
    /// Statistics of the finite values of `values` (NaN everywhere when there are none).
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n == 0 {
            return Self {
                count: 0,
                mean: f64::NAN,
                std: f64::NAN,
                min: f64::NAN,
                p05: f64::NAN,
                p50: f64::NAN,
                p95: f64::NAN,
                max: f64::NAN,
            };
        }
        let mean = v.iter().sum::<f64>() / n as f64;
        let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n as f64;
        // Nearest-rank percentile.
        let pct = |p: f64| v[(((p / 100.0) * n as f64).ceil() as usize).clamp(1, n) - 1];
        Self {
            count: n,
            mean,
            std: var.sqrt(),
            min: v[0],
            p05: pct(5.0),
            p50: pct(50.0),
            p95: pct(95.0),
            max: v[n - 1],
        }
    }
}

/// Summary of a set of episodes (completed ones only for the figures).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OutcomeSummary {
    /// Episodes flown.
    pub episodes: usize,
    /// Episodes that reached their terminal step.
    pub completed: usize,
    /// Sum of the step rewards per episode.
    pub total_reward: Stats,
    /// Final mass, fraction of m0.
    pub final_mass: Stats,
    /// Terminal position residual dr, AU.
    pub terminal_position: Stats,
    /// Terminal velocity residual dv, AU/t*.
    pub terminal_velocity: Stats,
}

/// Figures of `outcomes`, the statistics over the completed episodes only.
pub fn summarize<G: Geometry>(outcomes: &[EpisodeOutcome<G>]) -> OutcomeSummary {
    let done = || outcomes.iter().filter(|o| o.completed);
    OutcomeSummary {
        episodes: outcomes.len(),
        completed: done().count(),
        total_reward: Stats::of(done().map(|o| o.total_reward)),
        final_mass: Stats::of(done().map(|o| o.final_mass)),
        terminal_position: Stats::of(done().map(|o| o.terminal.position)),
        terminal_velocity: Stats::of(done().map(|o| o.terminal.velocity)),
    }
}
