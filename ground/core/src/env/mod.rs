//! The Markov decision processes of docs/spec.md sections 4 to 6: the transfer (TBT) and rendezvous (TBR)
//! environments, built only on the onboard crate's dynamics and feature encoding so that
//! training and flight share one implementation.
//!
//! - Physics: [`onboard::dynamics::propagate`] (zero-order hold in the local polar frame, exact
//!   Kepler on coast steps) or in three dimensions [`onboard::spatial::propagate_rtn`]; the
//!   rendezvous body moves by Kepler from its anomaly at t = 0 (the solver's convention).
//! - Features, residuals, reward, action decoding: [`onboard::features`]; the observation is
//!   the f32 narrowing the onboard network sees ([`onboard::features::to_network_input`]).
//! - Time: step k (0..=N) is at t = k STEP with time to go (N - k) STEP; the episode is done
//!   after step N ([`Scenario::steps`], the docs/spec.md section 4 rule).
//!
//! Geometry ([`geometry`]): the planar problems ([`Transfer`], [`Rendezvous`]) fly the polar
//! hold with actions `[a0, a1, a2]` ([`onboard::features::decode_action`]: components clamped to
//! [-1, 1], u = (a0 + 1) / 2, direction (a1, a2) normalised, thrust off when |(a1, a2)| < 1e-6);
//! the three-dimensional ones ([`Transfer3`], [`Rendezvous3`], docs/spec.md sections 3.6, 5.1,
//! 6.1) fly the RTN hold with `[a0, a1, a2, a3]`, the direction (radial, transverse, normal)
//! ([`onboard::features::decode_action3`]). An action of the other size is refused
//! ([`EnvError::ActionLength`]).
//! A **non-finite action** is handled as [`EnvConfig::non_finite_action`] says: by default it is
//! flown as thrust off, exactly what the flight software does when its guidance step refuses a
//! NaN, and flagged in [`StepInfo::non_finite_action`]; [`NonFiniteAction::Refuse`] makes it a
//! typed error instead ([`EnvError::NonFiniteAction`]) and leaves the environment unchanged.
//! Nothing here panics on any action or scenario.
//!
//! Reward: the printed docs/spec.md section 5 form by default; [`TerminalAccuracy`] adds an optional term
//! that weighs the residuals more as time runs out. It is reported apart in [`StepInfo`].

pub mod batch;
pub mod geometry;
#[cfg(test)]
mod spatial_tests;
#[cfg(test)]
mod tests;

pub use geometry::{ActionOf, CommandOf, Dimension, FamilyOf, Geometry, Planar, ScenarioOf, Spatial, StateOf};
use onboard::dynamics::{PropagationError, SpacecraftState};
use onboard::features::{
    rendezvous3_features, rendezvous3_residuals, rendezvous_features, rendezvous_residuals, reward, to_network_input,
    transfer3_features, transfer3_residuals, transfer_features, transfer_residuals, FeatureError, Residuals,
    RewardWeights, RENDEZVOUS3_FEATURES, RENDEZVOUS_FEATURES, TRANSFER3_FEATURES, TRANSFER_FEATURES,
};
use onboard::integrator::Tolerances;
use onboard::kepler::{coast, coast3, KeplerError};
use onboard::spatial::SpatialCraftState;
use serde::{Deserialize, Serialize};
use shared::blob::FeatureLayout;
use shared::mission::CentralBody;
use shared::orbit::{CartesianState, SpatialState};
pub use shared::scenario::ProblemKind;
use shared::scenario::{Scenario, ScenarioError, SpatialScenario};
use shared::spacecraft::{CanonicalSpacecraft, Spacecraft, SpacecraftError};

/// Reward weights of thesis Eq. 4.7-4.8 (docs/spec.md section 5), serialisable.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RewardConfig {
    /// w_p, on the position residual squared.
    pub position: f64,
    /// w_v, on the velocity residual squared.
    pub velocity: f64,
    /// w_u, on the throttle.
    pub throttle: f64,
}

impl Default for RewardConfig {
    fn default() -> Self {
        let w = RewardWeights::default();
        Self {
            position: w.position,
            velocity: w.velocity,
            throttle: w.throttle,
        }
    }
}

impl RewardConfig {
    /// The weights in the onboard reward's form.
    pub fn weights(&self) -> RewardWeights {
        RewardWeights {
            position: self.position,
            velocity: self.velocity,
            throttle: self.throttle,
        }
    }
}

/// The optional terminal-accuracy term of docs/spec.md section 5 (thesis Chapter 7, item i), added to
/// the printed reward. With dr, dv the residuals after the step (same definitions as the
/// reward) and j = N - (k + 1) the number of steps still to go after it:
///
/// - `None`: no term; the printed reward (the default).
/// - `TerminalPenalty`: `-(position dr + velocity dv)` on the last step only (j = 0).
/// - `TimeWeighted`: `-(position dr + velocity dv) exp(-j / horizon_steps)` on every step, so
///   the weight is 1 on the last step and decays with e-folding `horizon_steps` steps towards
///   the start (horizon -> 0 gives `TerminalPenalty`).
///
/// Linear (not Gaussian) in the residuals, so the term keeps a gradient far from the target
/// where the printed reward saturates at -2. In a TOML config:
/// `terminal = { kind = "time-weighted", position = 10.0, velocity = 10.0, horizon_steps = 3.0 }`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum TerminalAccuracy {
    /// No term: the printed reward.
    #[default]
    None,
    /// `-(position dr + velocity dv)` on the last step only.
    TerminalPenalty {
        /// Weight on dr (1/AU), >= 0.
        position: f64,
        /// Weight on dv (t*/AU), >= 0.
        velocity: f64,
    },
    /// `-(position dr + velocity dv) exp(-j / horizon_steps)` on every step.
    TimeWeighted {
        /// Weight on dr (1/AU), >= 0.
        position: f64,
        /// Weight on dv (t*/AU), >= 0.
        velocity: f64,
        /// e-folding length of the weight in steps, > 0.
        horizon_steps: f64,
    },
}

impl TerminalAccuracy {
    /// The term for residuals `res` after a step that leaves `steps_to_go` steps.
    pub fn term(&self, res: &Residuals, steps_to_go: u32) -> f64 {
        match *self {
            Self::None => 0.0,
            Self::TerminalPenalty { position, velocity } => {
                if steps_to_go == 0 {
                    -(position * res.position + velocity * res.velocity)
                } else {
                    0.0
                }
            }
            Self::TimeWeighted {
                position,
                velocity,
                horizon_steps,
            } => {
                let weight = if steps_to_go == 0 {
                    1.0
                } else {
                    (-f64::from(steps_to_go) / horizon_steps).exp()
                };
                -(position * res.position + velocity * res.velocity) * weight
            }
        }
    }

    fn validate(&self) -> Result<(), EnvError> {
        let ok = |x: f64| x.is_finite() && x >= 0.0;
        let valid = match *self {
            Self::None => true,
            Self::TerminalPenalty { position, velocity } => ok(position) && ok(velocity),
            Self::TimeWeighted {
                position,
                velocity,
                horizon_steps,
            } => ok(position) && ok(velocity) && horizon_steps.is_finite() && horizon_steps > 0.0,
        };
        if valid {
            Ok(())
        } else {
            Err(EnvError::Config(
                "terminal-accuracy weights must be finite and >= 0, the horizon > 0",
            ))
        }
    }
}

/// What a non-finite action does (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum NonFiniteAction {
    /// Flown as thrust off (as in flight) and flagged in [`StepInfo::non_finite_action`].
    #[default]
    Coast,
    /// Refused with [`EnvError::NonFiniteAction`]; the environment does not move.
    Refuse,
}

/// Integrator accuracy of the thrusting steps (coast steps are exact Kepler).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IntegratorConfig {
    /// Relative tolerance.
    pub relative: f64,
    /// Absolute tolerance (canonical units).
    pub absolute: f64,
    /// Step cap per 14-day step; a propagation that needs more fails.
    pub max_steps: u32,
}

impl Default for IntegratorConfig {
    /// The onboard defaults (rtol 1e-12, atol 1e-13): what the flight propagator and the SIL
    /// plant use.
    fn default() -> Self {
        let t = Tolerances::default();
        Self {
            relative: t.relative,
            absolute: t.absolute,
            max_steps: t.max_steps,
        }
    }
}

impl IntegratorConfig {
    /// As the onboard integrator's [`Tolerances`] (initial step chosen by the integrator).
    pub fn tolerances(&self) -> Tolerances {
        Tolerances {
            relative: self.relative,
            absolute: self.absolute,
            max_steps: self.max_steps,
            initial_step: 0.0,
            fixed_steps: 0,
        }
    }
}

/// Everything an environment is parameterised by; `[env]` of a TOML config.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EnvConfig {
    /// Thrust, Isp and initial mass (SI); converted to canonical units by [`Environment::new`].
    pub spacecraft: Spacecraft,
    /// Weights of the printed reward.
    pub reward: RewardConfig,
    /// Optional terminal-accuracy term.
    pub terminal: TerminalAccuracy,
    /// What a non-finite action does.
    pub non_finite_action: NonFiniteAction,
    /// Integrator accuracy of thrusting steps.
    pub integrator: IntegratorConfig,
    /// The central body whose canonical units the spacecraft is converted to: set from the
    /// scenario family, never written in `[env]`.
    #[serde(skip)]
    pub body: CentralBody,
}

impl EnvConfig {
    /// The spacecraft in the canonical units of [`Self::body`].
    pub fn canonical_spacecraft(&self) -> Result<CanonicalSpacecraft, SpacecraftError> {
        self.spacecraft.canonical_in(&self.body.units())
    }
}

/// Why an environment call failed. Every failure is one of these, never a panic.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum EnvError {
    /// The configured spacecraft does not convert to canonical units.
    #[error("invalid spacecraft: {0}")]
    Spacecraft(SpacecraftError),
    /// A reward, terminal-accuracy or integrator setting is out of range; says which.
    #[error("invalid environment config: {0}")]
    Config(&'static str),
    /// The scenario fails [`Scenario::validate`].
    #[error("invalid scenario: {0}")]
    Scenario(ScenarioError),
    /// A transfer scenario given to the rendezvous environment or the other way round.
    #[error("a {found:?} scenario given to the {expected:?} environment")]
    WrongProblem {
        /// The environment's problem.
        expected: ProblemKind,
        /// The scenario's.
        found: ProblemKind,
    },
    /// `step` before any `reset`.
    #[error("step called before reset")]
    NotReset,
    /// `step` after the terminal step.
    #[error("step called after the terminal step; reset first")]
    EpisodeOver,
    /// `reset_at` with a step index beyond N.
    #[error("step {step} is beyond the episode's {steps} steps")]
    StepOutOfRange {
        /// The step index asked for.
        step: u32,
        /// N.
        steps: u32,
    },
    /// An action with another number of components than the geometry's.
    #[error("an action of {found} components given to an environment of {expected}")]
    ActionLength {
        /// The geometry's action components (3 planar, 4 in three dimensions).
        expected: usize,
        /// The components given.
        found: usize,
    },
    /// The action had a NaN or infinite component and the config refuses such actions.
    #[error("the action has a NaN or infinite component")]
    NonFiniteAction,
    /// The spacecraft state cannot be propagated over step `step` (tank empty, integrator
    /// failure, state at the Sun, ...).
    #[error("propagation over step {step} failed: {error}")]
    Propagation {
        /// Index k of the step flown (from t = k STEP to (k + 1) STEP).
        step: u32,
        /// The onboard propagator's error.
        error: PropagationError,
    },
    /// The state or target at step `step` is outside the feature domain.
    #[error("features at step {step}: {error}")]
    Features {
        /// Step index of the state.
        step: u32,
        /// The onboard feature encoding's error.
        error: FeatureError,
    },
    /// The rendezvous body could not be propagated to step `step`.
    #[error("target body at step {step}: {error:?}")]
    Body {
        /// Step index the body was wanted at.
        step: u32,
        /// The Kepler solver's error.
        error: KeplerError,
    },
}

/// A problem in its geometry: how its features and residuals are computed. Implemented by
/// [`Transfer`] and [`Rendezvous`] (planar) and [`Transfer3`] and [`Rendezvous3`]
/// (three-dimensional); [`MdpEnv`] is generic over it.
pub trait Problem: Send + Sync + 'static {
    /// Which problem the scenarios must be.
    const KIND: ProblemKind;
    /// Number of features (10 or 22 planar, 15 or 30 in three dimensions).
    const OBS: usize;
    /// The features as a weight blob names them (its network's inputs and action outputs).
    const LAYOUT: FeatureLayout;
    /// The dimension the problem is flown in.
    type Geometry: Geometry;
    /// `[f64; OBS]`.
    type Features: Copy + core::fmt::Debug + PartialEq + Send + Sync + AsRef<[f64]>;
    /// `[f32; OBS]`: what the network sees.
    type Obs: Copy + core::fmt::Debug + PartialEq + Send + Sync + AsRef<[f32]> + 'static;

    /// Features of `state` at step `step` (time t = step STEP, time to go (N - step) STEP).
    fn features(
        scenario: &ScenarioOf<Self::Geometry>,
        state: &StateOf<Self::Geometry>,
        step: u32,
    ) -> Result<Self::Features, EnvError>;
    /// Position and velocity residuals in the features (AU, AU/t*).
    fn residuals(features: &Self::Features) -> Residuals;
    /// The features narrowed to f32 for the network.
    fn observation(features: &Self::Features) -> Self::Obs;
}

/// Evaluates `$body` with the type `$P` naming the planar [`Problem`] of `$kind` (a
/// [`ProblemKind`]): the one place the ground side lists its planar problems, so that code
/// generic over [`Problem`] is called for a run's problem without a match arm per problem at
/// each call. [`with_spatial_problem!`](crate::with_spatial_problem) names the
/// three-dimensional ones.
///
/// ```
/// use ground_core::env::Problem;
/// use ground_core::with_problem;
/// use shared::scenario::ProblemKind;
///
/// let features = |kind| with_problem!(kind, P => P::OBS);
/// assert_eq!(features(ProblemKind::Transfer), 10);
/// assert_eq!(features(ProblemKind::Rendezvous), 22);
/// ```
#[macro_export]
macro_rules! with_problem {
    ($kind:expr, $P:ident => $body:expr) => {
        match $kind {
            $crate::env::ProblemKind::Transfer => {
                type $P = $crate::env::Transfer;
                $body
            }
            $crate::env::ProblemKind::Rendezvous => {
                type $P = $crate::env::Rendezvous;
                $body
            }
        }
    };
}

/// [`with_problem!`](crate::with_problem) for the three-dimensional problems.
///
/// ```
/// use ground_core::env::Problem;
/// use ground_core::with_spatial_problem;
/// use shared::scenario::ProblemKind;
///
/// let features = |kind| with_spatial_problem!(kind, P => P::OBS);
/// assert_eq!(features(ProblemKind::Transfer), 15);
/// assert_eq!(features(ProblemKind::Rendezvous), 30);
/// ```
#[macro_export]
macro_rules! with_spatial_problem {
    ($kind:expr, $P:ident => $body:expr) => {
        match $kind {
            $crate::env::ProblemKind::Transfer => {
                type $P = $crate::env::Transfer3;
                $body
            }
            $crate::env::ProblemKind::Rendezvous => {
                type $P = $crate::env::Rendezvous3;
                $body
            }
        }
    };
}

/// The transfer problem (docs/spec.md section 5).
#[derive(Debug, Clone, Copy)]
pub struct Transfer;

/// The rendezvous problem (docs/spec.md section 6).
#[derive(Debug, Clone, Copy)]
pub struct Rendezvous;

/// The transfer problem in three dimensions (docs/spec.md section 5.1).
#[derive(Debug, Clone, Copy)]
pub struct Transfer3;

/// The rendezvous problem in three dimensions (docs/spec.md section 6.1).
#[derive(Debug, Clone, Copy)]
pub struct Rendezvous3;

/// Time to go at step `step` of `scenario`: (N - step) cycles, clamped at 0.
pub fn time_to_go(scenario: &Scenario, step: u32) -> f64 {
    scenario.time_to_go(step)
}

/// The rendezvous body's state at step `step`: its orbit point at `target_nu0`, coasted for
/// `step` cycles (from t = 0 every time, so no error accumulates along the episode).
pub fn body_at(scenario: &Scenario, step: u32) -> Result<CartesianState, EnvError> {
    let start = scenario.target.cartesian_at(scenario.target_nu0);
    coast(&start, scenario.cycle_start(step)).map_err(|error| EnvError::Body { step, error })
}

/// [`body_at`] in three dimensions: the body's orbit in the target plane.
pub fn body_at3(scenario: &SpatialScenario, step: u32) -> Result<SpatialState, EnvError> {
    let plan = &scenario.scenario;
    let start = scenario.target_plane.embed(&plan.target.cartesian_at(plan.target_nu0));
    coast3(&start, plan.cycle_start(step)).map_err(|error| EnvError::Body { step, error })
}

impl Problem for Transfer {
    const KIND: ProblemKind = ProblemKind::Transfer;
    const OBS: usize = TRANSFER_FEATURES;
    const LAYOUT: FeatureLayout = FeatureLayout::TransferPolar10;
    type Geometry = Planar;
    type Features = [f64; TRANSFER_FEATURES];
    type Obs = [f32; TRANSFER_FEATURES];

    fn features(scenario: &Scenario, state: &SpacecraftState, step: u32) -> Result<Self::Features, EnvError> {
        transfer_features(state, &scenario.target, time_to_go(scenario, step))
            .map_err(|error| EnvError::Features { step, error })
    }

    fn residuals(features: &Self::Features) -> Residuals {
        transfer_residuals(features)
    }

    fn observation(features: &Self::Features) -> Self::Obs {
        to_network_input(features)
    }
}

impl Problem for Rendezvous {
    const KIND: ProblemKind = ProblemKind::Rendezvous;
    const OBS: usize = RENDEZVOUS_FEATURES;
    const LAYOUT: FeatureLayout = FeatureLayout::RendezvousPolar22;
    type Geometry = Planar;
    type Features = [f64; RENDEZVOUS_FEATURES];
    type Obs = [f32; RENDEZVOUS_FEATURES];

    fn features(scenario: &Scenario, state: &SpacecraftState, step: u32) -> Result<Self::Features, EnvError> {
        let body = body_at(scenario, step)?;
        rendezvous_features(state, &body, time_to_go(scenario, step))
            .map_err(|error| EnvError::Features { step, error })
    }

    fn residuals(features: &Self::Features) -> Residuals {
        rendezvous_residuals(features)
    }

    fn observation(features: &Self::Features) -> Self::Obs {
        to_network_input(features)
    }
}

impl Problem for Transfer3 {
    const KIND: ProblemKind = ProblemKind::Transfer;
    const OBS: usize = TRANSFER3_FEATURES;
    const LAYOUT: FeatureLayout = FeatureLayout::TransferSpatial15;
    type Geometry = Spatial;
    type Features = [f64; TRANSFER3_FEATURES];
    type Obs = [f32; TRANSFER3_FEATURES];

    fn features(scenario: &SpatialScenario, state: &SpatialCraftState, step: u32) -> Result<Self::Features, EnvError> {
        let plan = &scenario.scenario;
        transfer3_features(state, &plan.target, &scenario.target_plane, time_to_go(plan, step))
            .map_err(|error| EnvError::Features { step, error })
    }

    fn residuals(features: &Self::Features) -> Residuals {
        transfer3_residuals(features)
    }

    fn observation(features: &Self::Features) -> Self::Obs {
        to_network_input(features)
    }
}

impl Problem for Rendezvous3 {
    const KIND: ProblemKind = ProblemKind::Rendezvous;
    const OBS: usize = RENDEZVOUS3_FEATURES;
    const LAYOUT: FeatureLayout = FeatureLayout::RendezvousSpatial30;
    type Geometry = Spatial;
    type Features = [f64; RENDEZVOUS3_FEATURES];
    type Obs = [f32; RENDEZVOUS3_FEATURES];

    fn features(scenario: &SpatialScenario, state: &SpatialCraftState, step: u32) -> Result<Self::Features, EnvError> {
        let body = body_at3(scenario, step)?;
        rendezvous3_features(state, &body, time_to_go(&scenario.scenario, step))
            .map_err(|error| EnvError::Features { step, error })
    }

    fn residuals(features: &Self::Features) -> Residuals {
        rendezvous3_residuals(features)
    }

    fn observation(features: &Self::Features) -> Self::Obs {
        to_network_input(features)
    }
}

/// The reward of a step that ended at step index `step_after` (1..=N) with residuals `res`
/// under throttle `throttle` (the decoded one, 0 when the thrust was off): the printed reward
/// plus the terminal-accuracy term. Returned as (total, printed, terminal term). The one
/// function both the environment and the demonstrations use.
pub fn step_reward(
    config: &EnvConfig,
    scenario: &Scenario,
    res: &Residuals,
    throttle: f64,
    step_after: u32,
) -> (f64, f64, f64) {
    let base = reward(res, throttle, &config.reward.weights());
    let extra = config.terminal.term(res, scenario.steps.saturating_sub(step_after));
    (base + extra, base, extra)
}

/// What a step did besides its reward.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepInfo<G: Geometry = Planar> {
    /// Step index after this step (1..=N).
    pub step: u32,
    /// Residuals after the step (docs/spec.md section 5/6 definitions).
    pub residuals: Residuals,
    /// The command flown (thrust off: throttle 0).
    pub command: CommandOf<G>,
    /// Throttle flown, 0..=1 (0 when the direction was undefined or the action not finite).
    pub throttle: f64,
    /// Mass after the step (m0 units).
    pub mass: f64,
    /// Spacecraft state after the step.
    pub state: StateOf<G>,
    /// The printed reward (docs/spec.md section 5), before the terminal-accuracy term.
    pub base_reward: f64,
    /// The terminal-accuracy term (0 by default).
    pub terminal_term: f64,
    /// The action had a non-finite component and was flown as thrust off.
    pub non_finite_action: bool,
}

/// One transition as the learner sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step<O, G: Geometry = Planar> {
    /// Observation after the step.
    pub observation: O,
    /// Total reward of the step: printed reward plus terminal-accuracy term.
    pub reward: f64,
    /// True after step N (terminal; no bootstrapping past it).
    pub done: bool,
    /// Details of the step.
    pub info: StepInfo<G>,
}

/// An MDP the SAC code can be generic over.
pub trait Environment: Send {
    /// Number of observation features.
    const OBS: usize;
    /// Transfer or rendezvous.
    const PROBLEM: ProblemKind;
    /// Planar or three-dimensional: the scenario, state, command and action types.
    type Geometry: Geometry;
    /// `[f32; OBS]`.
    type Obs: Copy + core::fmt::Debug + PartialEq + Send + Sync + AsRef<[f32]> + 'static;

    /// A new environment (no episode yet: call a reset first).
    fn new(config: &EnvConfig) -> Result<Self, EnvError>
    where
        Self: Sized;
    /// The configuration the environment was built with.
    fn config(&self) -> &EnvConfig;
    /// Starts an episode of `scenario` at its initial state (m = 1, step 0).
    fn reset(&mut self, scenario: &ScenarioOf<Self::Geometry>) -> Result<Self::Obs, EnvError>;
    /// Starts an episode of scenario `index` of the stream `seed` of `family` (docs/spec.md
    /// section 4).
    fn reset_drawn(
        &mut self,
        family: impl Into<FamilyOf<Self::Geometry>>,
        seed: u64,
        index: u64,
    ) -> Result<Self::Obs, EnvError>
    where
        Self: Sized,
    {
        self.reset(&Self::Geometry::draw(&family.into(), seed, index))
    }
    /// Starts an episode of `scenario` in `state` at step `step` (0..=N; N gives a finished
    /// episode). For demonstrations and tests.
    fn reset_at(
        &mut self,
        scenario: &ScenarioOf<Self::Geometry>,
        state: &StateOf<Self::Geometry>,
        step: u32,
    ) -> Result<Self::Obs, EnvError>;
    /// One guidance cycle under `action`.
    fn step(&mut self, action: &ActionOf<Self::Geometry>) -> Result<Step<Self::Obs, Self::Geometry>, EnvError>;
    /// [`Environment::step`] with the action as a slice of the learner's: refused with
    /// [`EnvError::ActionLength`] unless it has the geometry's number of components.
    fn step_slice(&mut self, action: &[f32]) -> Result<Step<Self::Obs, Self::Geometry>, EnvError> {
        let action = ActionOf::<Self::Geometry>::try_from(action).map_err(|_| EnvError::ActionLength {
            expected: Self::Geometry::ACT,
            found: action.len(),
        })?;
        self.step(&action)
    }
    /// The current observation (`None` before the first reset).
    fn observation(&self) -> Option<Self::Obs>;
    /// The current spacecraft state.
    fn state(&self) -> Option<StateOf<Self::Geometry>>;
    /// The scenario of the current episode (`None` before the first reset).
    fn scenario(&self) -> Option<&ScenarioOf<Self::Geometry>>;
    /// Steps taken so far in the episode (k).
    fn steps_taken(&self) -> u32;
    /// Whether the episode has taken its N steps (false before the first reset).
    fn is_done(&self) -> bool;
}

struct Episode<P: Problem> {
    scenario: ScenarioOf<P::Geometry>,
    state: StateOf<P::Geometry>,
    step: u32,
    features: P::Features,
}

impl<P: Problem> Clone for Episode<P> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<P: Problem> Copy for Episode<P> {}

impl<P: Problem> core::fmt::Debug for Episode<P> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Episode")
            .field("scenario", &self.scenario)
            .field("state", &self.state)
            .field("step", &self.step)
            .field("features", &self.features)
            .finish()
    }
}

/// The environment of problem `P`: [`TransferEnv`], [`RendezvousEnv`] or their
/// three-dimensional [`Transfer3Env`], [`Rendezvous3Env`].
#[derive(Debug, Clone)]
pub struct MdpEnv<P: Problem> {
    config: EnvConfig,
    spacecraft: CanonicalSpacecraft,
    tolerances: Tolerances,
    episode: Option<Episode<P>>,
}

/// The transfer MDP (docs/spec.md section 5): 10 features.
pub type TransferEnv = MdpEnv<Transfer>;
/// The rendezvous MDP (docs/spec.md section 6): 22 features.
pub type RendezvousEnv = MdpEnv<Rendezvous>;
/// The transfer MDP in three dimensions (docs/spec.md section 5.1): 15 features, 4 actions.
pub type Transfer3Env = MdpEnv<Transfer3>;
/// The rendezvous MDP in three dimensions (docs/spec.md section 6.1): 30 features, 4 actions.
pub type Rendezvous3Env = MdpEnv<Rendezvous3>;

impl<P: Problem> MdpEnv<P> {
    /// The configured spacecraft in canonical units.
    pub fn spacecraft(&self) -> &CanonicalSpacecraft {
        &self.spacecraft
    }

    /// Current features in f64 (the observation before narrowing).
    pub fn features(&self) -> Option<P::Features> {
        self.episode.as_ref().map(|e| e.features)
    }

    /// The reward the environment gives for a step that ends in `state_after` at step index
    /// `step_after` under `throttle`: `(total reward, residuals, printed reward, terminal term)`.
    /// [`Environment::step`] computes its reward with exactly this function.
    pub fn reward_at(
        config: &EnvConfig,
        scenario: &ScenarioOf<P::Geometry>,
        state_after: &StateOf<P::Geometry>,
        step_after: u32,
        throttle: f64,
    ) -> Result<(f64, Residuals, f64, f64), EnvError> {
        let features = P::features(scenario, state_after, step_after)?;
        let res = P::residuals(&features);
        let plan = P::Geometry::plan(scenario);
        let (total, base, extra) = step_reward(config, plan, &res, throttle, step_after);
        Ok((total, res, base, extra))
    }

    fn check_scenario(scenario: &ScenarioOf<P::Geometry>) -> Result<(), EnvError> {
        let found = P::Geometry::plan(scenario).problem;
        if found != P::KIND {
            return Err(EnvError::WrongProblem {
                expected: P::KIND,
                found,
            });
        }
        P::Geometry::validate(scenario).map_err(EnvError::Scenario)
    }
}

impl<P: Problem> Environment for MdpEnv<P> {
    const OBS: usize = P::OBS;
    const PROBLEM: ProblemKind = P::KIND;
    type Geometry = P::Geometry;
    type Obs = P::Obs;

    fn new(config: &EnvConfig) -> Result<Self, EnvError> {
        let spacecraft = config.canonical_spacecraft().map_err(EnvError::Spacecraft)?;
        config.terminal.validate()?;
        let r = &config.reward;
        if ![r.position, r.velocity, r.throttle]
            .iter()
            .all(|w| w.is_finite() && *w >= 0.0)
        {
            return Err(EnvError::Config("reward weights must be finite and >= 0"));
        }
        let i = &config.integrator;
        if !(i.relative.is_finite() && i.relative > 0.0 && i.absolute.is_finite() && i.absolute > 0.0)
            || i.max_steps == 0
        {
            return Err(EnvError::Config(
                "integrator tolerances must be finite and > 0, max_steps > 0",
            ));
        }
        Ok(Self {
            config: *config,
            spacecraft,
            tolerances: i.tolerances(),
            episode: None,
        })
    }

    fn config(&self) -> &EnvConfig {
        &self.config
    }

    fn reset(&mut self, scenario: &ScenarioOf<P::Geometry>) -> Result<Self::Obs, EnvError> {
        self.reset_at(scenario, &P::Geometry::departure(scenario), 0)
    }

    fn reset_at(
        &mut self,
        scenario: &ScenarioOf<P::Geometry>,
        state: &StateOf<P::Geometry>,
        step: u32,
    ) -> Result<Self::Obs, EnvError> {
        Self::check_scenario(scenario)?;
        let steps = P::Geometry::plan(scenario).steps;
        if step > steps {
            return Err(EnvError::StepOutOfRange { step, steps });
        }
        let features = P::features(scenario, state, step)?;
        self.episode = Some(Episode {
            scenario: *scenario,
            state: *state,
            step,
            features,
        });
        Ok(P::observation(&features))
    }

    fn step(&mut self, action: &ActionOf<P::Geometry>) -> Result<Step<Self::Obs, P::Geometry>, EnvError> {
        let episode = self.episode.as_ref().ok_or(EnvError::NotReset)?;
        let plan = *P::Geometry::plan(&episode.scenario);
        if episode.step >= plan.steps {
            return Err(EnvError::EpisodeOver);
        }
        let non_finite = !action.as_ref().iter().all(|a| a.is_finite());
        if non_finite && self.config.non_finite_action == NonFiniteAction::Refuse {
            return Err(EnvError::NonFiniteAction);
        }
        // The decoding maps a non-finite action to thrust off itself.
        let command = P::Geometry::decode(action);
        let throttle = P::Geometry::throttle(&command);
        let k = episode.step;
        let state = P::Geometry::propagate(&episode.state, &command, &self.spacecraft, plan.cycle, &self.tolerances)
            .map_err(|error| EnvError::Propagation { step: k, error })?;
        let step_after = k + 1;
        let features = P::features(&episode.scenario, &state, step_after)?;
        let residuals = P::residuals(&features);
        let (total, base, extra) = step_reward(&self.config, &plan, &residuals, throttle, step_after);
        let done = step_after == plan.steps;
        self.episode = Some(Episode {
            scenario: episode.scenario,
            state,
            step: step_after,
            features,
        });
        Ok(Step {
            observation: P::observation(&features),
            reward: total,
            done,
            info: StepInfo {
                step: step_after,
                residuals,
                command,
                throttle,
                mass: P::Geometry::mass(&state),
                state,
                base_reward: base,
                terminal_term: extra,
                non_finite_action: non_finite,
            },
        })
    }

    fn observation(&self) -> Option<Self::Obs> {
        self.episode.as_ref().map(|e| P::observation(&e.features))
    }

    fn state(&self) -> Option<StateOf<P::Geometry>> {
        self.episode.as_ref().map(|e| e.state)
    }

    fn scenario(&self) -> Option<&ScenarioOf<P::Geometry>> {
        self.episode.as_ref().map(|e| &e.scenario)
    }

    fn steps_taken(&self) -> u32 {
        self.episode.as_ref().map_or(0, |e| e.step)
    }

    fn is_done(&self) -> bool {
        self.episode
            .as_ref()
            .is_some_and(|e| e.step >= P::Geometry::plan(&e.scenario).steps)
    }
}
