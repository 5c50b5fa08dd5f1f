//! Demonstrations -> experience tuples (docs/spec.md section 7, thesis Section 4.4).
//!
//! For every 14-day step k of a solved trajectory record:
//! - s_k is the environment's observation of the record's optimal state at t_k (step k), s_k+1
//!   that of the optimal state at t_k+1 (the record's step samples);
//! - a_k is the zero-order-hold equivalent of the optimal control over the step in the polar
//!   frame the environment holds its command in: w = (1/STEP) ∫ u (alpha_r, alpha_theta) dt, then
//!   u = |w|, direction w/|w|, a = (2u - 1, w/|w|), clipped to [-1 + 1e-3, 1 - 1e-3];
//! - r_k is the environment's reward for a step ending in the optimal s_k+1 under the throttle
//!   the environment decodes from a_k ([`MdpEnv::reward_at`], the very function its `step` uses);
//! - done_k is true on the last step (k + 1 = N), as in the environment.
//!
//! The integral is computed by re-integrating the state-costate system of the solver
//! ([`crate::solver::pontryagin::StateCostate`], same right-hand side, same switch events, same
//! throttle law at the record's final eps) from the record's initial costates, augmented with
//! the two components of w; each step restarts at its boundary exactly as the record's sampling
//! did, and the re-integrated states are checked against the record's step samples (a record
//! solved with another spacecraft, say, is refused). A quadrature from the record alone is not
//! accurate enough: the record holds two samples per step at most (14-day grid and the 100-point
//! ephemeris), while the optimal throttle switches anywhere inside a step; the report quantifies
//! the endpoint (trapezoid) rule against the exact integral.
//!
//! Clipping: a throttle of 0 or 1 cannot be expressed exactly (u is clipped to
//! [5e-4, 0.9995]); a step whose ZOH throttle is below 2.5e-4 (half the floor) is encoded as
//! thrust off instead, with a zero direction (a1 = a2 = 0), which the decoder turns into u = 0.

pub mod spatial;

use std::path::Path;

use onboard::dynamics::{propagate, SpacecraftState, ThrustCommand};
use onboard::features::ACTION_LEN;
use onboard::integrator::{integrate, IntegrationError, OdeSystem, Tolerances};
use onboard::spatial::SpatialCraftState;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use shared::mission::{MissionFamily, OrbitRanges};
use shared::orbit::CartesianState;
use shared::scenario::{ProblemKind, Range, Scenario};
use shared::spacecraft::CanonicalSpacecraft;
use shared::spacecraft::Spacecraft;

use crate::env::batch::Stats;
use crate::env::{
    body_at, ActionOf, EnvConfig, EnvError, Environment, MdpEnv, Planar, Problem, ScenarioOf, StateOf, Step,
};
use crate::generate::{read_dataset, GenerateError};
use crate::solver::pontryagin::{OptimalControlParams, StateCostate, SWITCH_EVENTS, Y_LEN};
use crate::solver::record::{sample, TrajectoryRecord, TrajectorySample};
use crate::solver::shooting::initial_state_costate;
use crate::solver::{solve_arriving_early, CycledScenario, SolveOptions};

/// Actions are clipped to [-ACTION_BOUND, ACTION_BOUND] so a squashed-Gaussian log-probability
/// stays finite (docs/spec.md section 7).
pub const ACTION_BOUND: f64 = 1.0 - 1e-3;
/// Below this ZOH throttle a step is encoded as thrust off (half the clipped throttle floor).
pub const COAST_THROTTLE: f64 = 0.25e-3;
/// Largest deviation (canonical units, any of r, v, m) allowed between the re-integrated
/// optimal states and the record's step samples.
pub const CONSISTENCY_TOLERANCE: f64 = 1e-6;

/// Which records are turned into tuples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RecordFilter {
    /// Only records whose homotopy reached the final eps (`converged`).
    #[default]
    Converged,
    /// Every record with a solution, including those whose homotopy stopped at a larger eps
    /// (their tuples follow the smoothed control of that eps).
    All,
}

impl RecordFilter {
    /// Whether `record` passes the filter.
    pub fn accepts(&self, record: &TrajectoryRecord) -> bool {
        match self {
            Self::Converged => record.converged,
            Self::All => !record.steps.is_empty(),
        }
    }
}

/// One experience tuple (s_k, a_k, r_k, s_k+1, done_k).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transition<O, A = [f32; ACTION_LEN]> {
    /// s_k: the observation at step k.
    pub observation: O,
    /// a_k: the clipped action encoding the step's ZOH control.
    pub action: A,
    /// r_k: the environment's reward for the step (printed reward plus terminal-accuracy term).
    pub reward: f64,
    /// s_k+1: the observation at step k + 1.
    pub next_observation: O,
    /// True on the episode's last step (k + 1 = N).
    pub done: bool,
    /// Scenario index of the record and step k, for tracing.
    pub record: u64,
    /// Step index k in the episode.
    pub step: u32,
}

/// The zero-order-hold equivalent of the optimal control over one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ZohControl {
    /// w = (1/STEP) ∫ u (alpha_r, alpha_theta) dt.
    pub w: [f64; 2],
    /// Mean throttle (1/STEP) ∫ u dt (>= |w|; equal when the direction does not turn).
    pub mean_throttle: f64,
}

impl ZohControl {
    /// The exact (unclipped, f64) command of w: throttle |w| capped at 1, direction w/|w|;
    /// thrust off below [`COAST_THROTTLE`].
    pub fn command(&self) -> ThrustCommand {
        let u = self.w[0].hypot(self.w[1]);
        if u < COAST_THROTTLE {
            return ThrustCommand::OFF;
        }
        ThrustCommand {
            throttle: u.min(1.0),
            alpha_r: self.w[0] / u,
            alpha_theta: self.w[1] / u,
        }
    }

    /// The action encoding w: (2|w| - 1, w/|w|), clipped; thrust off below [`COAST_THROTTLE`].
    pub fn action(&self) -> [f32; ACTION_LEN] {
        let u = self.w[0].hypot(self.w[1]);
        let a = if u < COAST_THROTTLE {
            [-1.0, 0.0, 0.0]
        } else {
            [2.0 * u.min(1.0) - 1.0, self.w[0] / u, self.w[1] / u]
        };
        a.map(|x| x.clamp(-ACTION_BOUND, ACTION_BOUND) as f32)
    }
}

/// The action of a step flown with thrust off, as [`ZohControl::action`] encodes it.
pub fn coast_action() -> [f32; ACTION_LEN] {
    ZohControl {
        w: [0.0, 0.0],
        mean_throttle: 0.0,
    }
    .action()
}

/// The solver's state-costate system augmented with w' = u (alpha_r, alpha_theta) and the mean
/// throttle; switch events as the solver's.
#[derive(Debug, Clone, Copy)]
struct ControlIntegral(OptimalControlParams);

const AUG_LEN: usize = Y_LEN + 3;

impl OdeSystem<AUG_LEN, SWITCH_EVENTS> for ControlIntegral {
    fn derivatives(&self, t: f64, y: &[f64; AUG_LEN], dydt: &mut [f64; AUG_LEN]) {
        let core: [f64; Y_LEN] = core::array::from_fn(|i| y[i]);
        let mut f = [0.0; Y_LEN];
        StateCostate(self.0).derivatives(t, &core, &mut f);
        dydt[..Y_LEN].copy_from_slice(&f);
        let s = sample(t, &core, &self.0);
        dydt[Y_LEN] = s.throttle * s.direction_polar[0];
        dydt[Y_LEN + 1] = s.throttle * s.direction_polar[1];
        dydt[Y_LEN + 2] = s.throttle;
    }

    fn events(&self, t: f64, y: &[f64; AUG_LEN]) -> [f64; SWITCH_EVENTS] {
        let core: [f64; Y_LEN] = core::array::from_fn(|i| y[i]);
        StateCostate(self.0).events(t, &core)
    }
}

/// Why a record gave no tuples.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DemoError {
    /// Reading the dataset failed (the error's text).
    #[error("dataset: {0}")]
    Dataset(String),
    /// The record is of the other problem than the environment asked for.
    #[error("a {found:?} record where {expected:?} was asked")]
    WrongProblem {
        /// The environment's problem.
        expected: ProblemKind,
        /// The record's.
        found: ProblemKind,
    },
    /// The record holds no step samples (failed solve) or not N + 1 of them.
    #[error("record has no (complete) step samples")]
    NoSolution,
    /// A placement whose steps do not add up to the episode's, or a mass outside (0, 1].
    #[error("record does not fit its place in the episode (steps or mass)")]
    Placement,
    /// The environment refused the spacecraft, scenario or a step.
    #[error("{0}")]
    Env(EnvError),
    /// Re-integrating the state-costate system over a step failed.
    #[error("re-integration over step {step} failed: {error:?}")]
    Integration {
        /// Index k of the record's step (from its t = k STEP).
        step: u32,
        /// The integrator's error.
        error: IntegrationError,
    },
    /// The re-integrated optimal state differs from the record's sample at `step` by
    /// `deviation`: other spacecraft, other eps, or corrupt costates.
    #[error(
        "re-integrated optimal state departs from the record at step {step} by {deviation:.3e}: \
         another spacecraft, eps or corrupt costates?"
    )]
    Inconsistent {
        /// Step boundary of the record where the states were compared.
        step: u32,
        /// Largest absolute difference over x, y, vx, vy, m (canonical units).
        deviation: f64,
    },
}

impl From<GenerateError> for DemoError {
    fn from(e: GenerateError) -> Self {
        Self::Dataset(e.to_string())
    }
}

/// Tolerances of the re-integration: those the generator's solves use (rtol 1e-12).
pub fn default_tolerances() -> Tolerances {
    crate::solver::SolveOptions::default().tolerances
}

/// The ZOH controls of every step of a record and the re-integrated state-costate at every
/// step boundary, checked against the record's step samples.
pub fn zoh_controls(
    record: &TrajectoryRecord,
    config: &EnvConfig,
    tolerances: &Tolerances,
) -> Result<Vec<ZohControl>, DemoError> {
    zoh_controls_from_mass(record, 1.0, config, tolerances)
}

/// [`zoh_controls`] of a record solved from mass `start_mass` (see [`Placement`]): the
/// spacecraft's thrust per unit mass is T / start_mass.
fn zoh_controls_from_mass(
    record: &TrajectoryRecord,
    start_mass: f64,
    config: &EnvConfig,
    tolerances: &Tolerances,
) -> Result<Vec<ZohControl>, DemoError> {
    let n = record.scenario.steps;
    if record.steps.len() != n as usize + 1 {
        return Err(DemoError::NoSolution);
    }
    let mut spacecraft = config
        .canonical_spacecraft()
        .map_err(|e| DemoError::Env(EnvError::Spacecraft(e)))?;
    spacecraft.thrust /= start_mass;
    let params = OptimalControlParams {
        spacecraft,
        eps: record.final_eps,
    };
    let system = ControlIntegral(params);
    let y0 = initial_state_costate(&record.scenario, &record.costates);
    let mut y: [f64; AUG_LEN] = core::array::from_fn(|i| if i < Y_LEN { y0[i] } else { 0.0 });
    let mut controls = Vec::with_capacity(n as usize);
    for k in 0..n {
        let cycle = record.scenario.cycle;
        let (t0, t1) = (record.scenario.cycle_start(k), record.scenario.cycle_start(k + 1));
        y[Y_LEN..].fill(0.0);
        y = integrate(&system, t0, &y, t1, tolerances)
            .map_err(|error| DemoError::Integration { step: k, error })?
            .0;
        controls.push(ZohControl {
            w: [y[Y_LEN] / cycle, y[Y_LEN + 1] / cycle],
            mean_throttle: y[Y_LEN + 2] / cycle,
        });
        let deviation = record
            .steps
            .get(k as usize + 1)
            .map_or(f64::INFINITY, |s| state_deviation(s, &y));
        // NaN (a diverged re-integration) counts as inconsistent.
        if deviation.is_nan() || deviation > CONSISTENCY_TOLERANCE {
            return Err(DemoError::Inconsistent { step: k + 1, deviation });
        }
    }
    Ok(controls)
}

fn state_deviation(s: &TrajectorySample, y: &[f64; AUG_LEN]) -> f64 {
    let mine = [y[0], y[1], y[2], y[3], y[4]];
    let theirs = [s.r[0], s.r[1], s.v[0], s.v[1], s.m];
    mine.iter().zip(theirs).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)
}

fn state_of(s: &TrajectorySample) -> SpacecraftState {
    SpacecraftState { r: s.r, v: s.v, m: s.m }
}

/// How far the environment's propagation of (s_k, a_k) lands from the optimal s_k+1.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StepMismatch {
    /// Scenario index of the record.
    pub record: u64,
    /// Step index k in the episode.
    pub step: u32,
    /// |r_env - r_opt| (AU), |v_env - v_opt| (AU/t*), |m_env - m_opt| (m0).
    pub position: f64,
    /// |v_env - v_opt|, AU/t*.
    pub velocity: f64,
    /// |m_env - m_opt|, fraction of m0.
    pub mass: f64,
    /// ZOH throttle |w| and mean throttle of the optimal control over the step.
    pub zoh_throttle: f64,
    /// Mean throttle (1/STEP) ∫ u dt.
    pub mean_throttle: f64,
    /// |w_trapezoid - w| of the endpoint rule on the record's two step samples.
    pub trapezoid_error: f64,
    /// Position error of the unclipped f64 ZOH command ([`ZohControl::command`]) propagated by
    /// the same onboard propagator: the hold error alone, without clipping and f32 narrowing.
    pub unclipped_position: f64,
}

/// The tuples of one record, with the one-step mismatch of every step.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordDemonstration<O, A = [f32; ACTION_LEN]> {
    /// The record's tuples, in step order.
    pub transitions: Vec<Transition<O, A>>,
    /// One-step mismatch of each step the record flies (none for the coast after an early arrival).
    pub mismatch: Vec<StepMismatch>,
}

/// Where a record's flight sits in an episode. A record from departure fills the episode of its
/// draw ([`Placement::whole`]). A relabelled record (DAgger-style: the transfer re-solved from a
/// state a policy visited) starts at step `start_step` of `episode` with mass `start_mass`; it
/// was solved for a scenario of N - start_step steps departing from that state and a spacecraft
/// of thrust T / start_mass (the same dynamics with the mass counted in units of start_mass), so
/// its masses are multiplied by start_mass. A record solved to arrive early
/// ([`crate::solver::solve_arriving_early`]) ends before its episode does: its flight then coasts
/// to the episode's end, with its target. `S`: the episode's scenario type, planar or
/// [`shared::scenario::SpatialScenario`] ([`spatial::relabel_spatial`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement<S = Scenario> {
    /// The episode the tuples belong to (its steps and, for a rendezvous, its body).
    pub episode: S,
    /// Step of the episode at which the record's flight starts.
    pub start_step: u32,
    /// Mass at that step, fraction of the episode's m0.
    pub start_mass: f64,
}

impl Placement {
    /// A record from departure in the episode of its draw: the draw is the record's scenario,
    /// or, for a record that arrives early, the scenario it shortened; a record of no draw fills
    /// the episode of its own scenario.
    pub fn whole(record: &TrajectoryRecord) -> Self {
        Self {
            episode: episode_of_draw(record.scenario, record.family.draw(record.seed, record.index)),
            start_step: 0,
            start_mass: 1.0,
        }
    }
}

/// The episode a record from departure fills, both geometries: `draw` (its draw's scenario)
/// where the record's scenario `own` is the draw shortened by an arrival margin or the draw
/// itself, `own` otherwise (a record of no draw).
pub(crate) fn episode_of_draw<S: CycledScenario>(own: S, draw: S) -> S {
    if own.with_cycles(draw.cycles()) == draw && own.cycles() < draw.cycles() {
        draw
    } else {
        own
    }
}

/// The rest of `episode` from `state` at step `step`, as a scenario of its own, and the
/// spacecraft scaled to the state's mass (the solvers start at unit mass): the problem a relabel
/// or a recoverability check solves. `None` when the state has no orbit (not bound), the step
/// leaves no flight, or (rendezvous) the body's state at that step cannot be computed. The rest
/// departs from the state's osculating orbit; a rendezvous rest chases the same body from where
/// it is at that step.
pub fn rest_of_flight(
    episode: &Scenario,
    state: &SpacecraftState,
    step: u32,
    spacecraft: &CanonicalSpacecraft,
) -> Option<(Scenario, CanonicalSpacecraft)> {
    if step >= episode.steps {
        return None;
    }
    let target_nu0 = match episode.problem {
        ProblemKind::Transfer => episode.target_nu0,
        ProblemKind::Rendezvous => {
            // The body coasts on the target orbit: its polar angle at the step, less the
            // orbit's periapsis angle, is its true anomaly there.
            let body = body_at(episode, step).ok()?;
            let theta = body.r[1].atan2(body.r[0]);
            (theta - episode.target.omega).rem_euclid(2.0 * core::f64::consts::PI)
        }
    };
    let rest = Scenario {
        initial: CartesianState { r: state.r, v: state.v }.elements()?,
        steps: episode.steps - step,
        target_nu0,
        ..*episode
    };
    let scaled = CanonicalSpacecraft {
        thrust: spacecraft.thrust / state.m,
        ..*spacecraft
    };
    Some((rest, scaled))
}

/// The fuel-optimal solve of a rest of flight ([`rest_of_flight`], with its scaled spacecraft),
/// labelled with the episode's `family` less its departure eccentricities (an osculating orbit
/// may have any: a near-circular rest that the near-circular path cannot solve falls back to the
/// general one), with the options' arrival margin ([`solve_arriving_early`]); seed and index are
/// the caller's, for tracing.
pub fn solve_rest(
    family: &MissionFamily,
    (seed, index): (u64, u64),
    rest: &Scenario,
    scaled: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> TrajectoryRecord {
    let label = MissionFamily {
        departure: OrbitRanges {
            e: Range { lo: 0.0, hi: 0.99 },
            ..family.departure
        },
        ..*family
    };
    solve_arriving_early(label, seed, index, rest, scaled, options)
}

/// Relabels a state a policy visited (DAgger-style): the fuel-optimal rest of `episode`
/// re-solved by the indirect method from `state` at step `step` ([`rest_of_flight`],
/// [`solve_rest`]), as a record and its [`Placement`]; `None` where there is no rest to solve.
pub fn relabel(
    family: &MissionFamily,
    seed_index: (u64, u64),
    episode: &Scenario,
    state: &SpacecraftState,
    step: u32,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> Option<(TrajectoryRecord, Placement)> {
    let (rest, scaled) = rest_of_flight(episode, state, step, spacecraft)?;
    let record = solve_rest(family, seed_index, &rest, &scaled, options);
    let placement = Placement {
        episode: *episode,
        start_step: step,
        start_mass: state.m,
    };
    Some((record, placement))
}

/// The tuples of one record for problem `P` (transfer or rendezvous).
pub fn record_demonstration<P: Problem<Geometry = Planar>>(
    record: &TrajectoryRecord,
    config: &EnvConfig,
    tolerances: &Tolerances,
) -> Result<RecordDemonstration<P::Obs>, DemoError> {
    placed_demonstration::<P>(record, &Placement::whole(record), config, tolerances)
}

/// The tuple of cycle `k` of a record placed in `scenario` (docs/spec.md section 7), both
/// geometries: s_k and s_k+1 the environment's observations of the record's states `s_k`,
/// `s_next`, r_k its reward for a cycle ending in `s_next` under the throttle it decodes from
/// `action`, done its flag; with the environment's own cycle from `s_k` under `action` (for the
/// one-step mismatch). `record` traces the tuple.
pub(crate) fn tuple_at<P: Problem>(
    env: &mut MdpEnv<P>,
    config: &EnvConfig,
    scenario: &ScenarioOf<P::Geometry>,
    (s_k, s_next): (&StateOf<P::Geometry>, &StateOf<P::Geometry>),
    action: ActionOf<P::Geometry>,
    (record, k): (u64, u32),
) -> Result<PlacedTuple<P>, DemoError> {
    let observation = env.reset_at(scenario, s_k, k).map_err(DemoError::Env)?;
    let flown = env.step(&action).map_err(DemoError::Env)?;
    let (reward, ..) =
        MdpEnv::<P>::reward_at(config, scenario, s_next, k + 1, flown.info.throttle).map_err(DemoError::Env)?;
    let next_observation = env.reset_at(scenario, s_next, k + 1).map_err(DemoError::Env)?;
    let tuple = Transition {
        observation,
        action,
        reward,
        next_observation,
        done: flown.done,
        record,
        step: k,
    };
    Ok((tuple, flown))
}

/// A tuple of problem `P` and the environment's own cycle it was taken beside.
pub(crate) type PlacedTuple<P> = (
    Transition<<P as Problem>::Obs, ActionOf<<P as Problem>::Geometry>>,
    Step<<P as Problem>::Obs, <P as Problem>::Geometry>,
);

/// The tuples of a record placed in an episode (see [`Placement`]): observations, rewards and
/// done flags are the episode's at steps start_step.., the actions the record's ZOH controls;
/// after a record that ends before its episode, coast steps from its final state to the
/// episode's end (thrust off, flown by the environment).
pub fn placed_demonstration<P: Problem<Geometry = Planar>>(
    record: &TrajectoryRecord,
    placement: &Placement,
    config: &EnvConfig,
    tolerances: &Tolerances,
) -> Result<RecordDemonstration<P::Obs>, DemoError> {
    if record.scenario.problem != P::KIND || placement.episode.problem != P::KIND {
        return Err(DemoError::WrongProblem {
            expected: P::KIND,
            found: record.scenario.problem,
        });
    }
    // A record shorter than its episode arrived early (an arrival margin) and is coasted to
    // the end: only a converged one has arrived.
    let first_coast = placement.start_step + record.scenario.steps;
    if first_coast > placement.episode.steps
        || (first_coast < placement.episode.steps && !record.converged)
        || !(placement.start_mass > 0.0 && placement.start_mass <= 1.0)
    {
        return Err(DemoError::Placement);
    }
    let controls = zoh_controls_from_mass(record, placement.start_mass, config, tolerances)?;
    let scenario = &placement.episode;
    let mut env = MdpEnv::<P>::new(config).map_err(DemoError::Env)?;
    let mut transitions = Vec::with_capacity(controls.len());
    let mut mismatch = Vec::with_capacity(controls.len());
    let placed = |s: &TrajectorySample| SpacecraftState {
        m: s.m * placement.start_mass,
        ..state_of(s)
    };
    for ((j, control), pair) in (0u32..).zip(&controls).zip(record.steps.windows(2)) {
        let [now, next] = pair else {
            return Err(DemoError::NoSolution);
        };
        let k = placement.start_step + j;
        let (s_k, s_next) = (placed(now), placed(next));
        let action = control.action();
        let (tuple, flown) = tuple_at(&mut env, config, scenario, (&s_k, &s_next), action, (record.index, k))?;
        transitions.push(tuple);
        let e = flown.info.state;
        let exact = propagate(
            &s_k,
            &control.command(),
            env.spacecraft(),
            scenario.cycle,
            &config.integrator.tolerances(),
        )
        .map_err(|error| DemoError::Env(EnvError::Propagation { step: k, error }))?;
        let trapezoid =
            [0, 1].map(|i| 0.5 * (now.throttle * now.direction_polar[i] + next.throttle * next.direction_polar[i]));
        mismatch.push(StepMismatch {
            record: record.index,
            step: k,
            position: (e.r[0] - s_next.r[0]).hypot(e.r[1] - s_next.r[1]),
            velocity: (e.v[0] - s_next.v[0]).hypot(e.v[1] - s_next.v[1]),
            mass: (e.m - s_next.m).abs(),
            zoh_throttle: control.w[0].hypot(control.w[1]),
            mean_throttle: control.mean_throttle,
            trapezoid_error: (trapezoid[0] - control.w[0]).hypot(trapezoid[1] - control.w[1]),
            unclipped_position: (exact.r[0] - s_next.r[0]).hypot(exact.r[1] - s_next.r[1]),
        });
    }
    let arrived = record.steps.last().ok_or(DemoError::NoSolution)?;
    coast_to_the_end(
        &mut env,
        scenario,
        &placed(arrived),
        first_coast..scenario.steps,
        coast_action(),
        record.index,
        &mut transitions,
    )?;
    Ok(RecordDemonstration { transitions, mismatch })
}

/// After a record that arrived early (an arrival margin), its flight coasts with the target
/// over `cycles` from `arrived`: the environment's own cycles, both geometries. A coast is what
/// the environment flies exactly, so its rewards and observations are the tuples'. Nothing
/// for an empty range (a record that arrives on time).
pub(crate) fn coast_to_the_end<P: Problem>(
    env: &mut MdpEnv<P>,
    scenario: &ScenarioOf<P::Geometry>,
    arrived: &StateOf<P::Geometry>,
    cycles: core::ops::Range<u32>,
    coast: ActionOf<P::Geometry>,
    record: u64,
    transitions: &mut Vec<Transition<P::Obs, ActionOf<P::Geometry>>>,
) -> Result<(), DemoError> {
    if cycles.is_empty() {
        return Ok(());
    }
    let mut observation = env.reset_at(scenario, arrived, cycles.start).map_err(DemoError::Env)?;
    for k in cycles {
        let flown = env.step(&coast).map_err(DemoError::Env)?;
        transitions.push(Transition {
            observation,
            action: coast,
            reward: flown.reward,
            next_observation: flown.observation,
            done: flown.done,
            record,
            step: k,
        });
        observation = flown.observation;
    }
    Ok(())
}

/// Tuples of a record set, in record order, with the records that gave none.
#[derive(Debug, Clone, PartialEq)]
pub struct Demonstrations<O, A = [f32; ACTION_LEN]> {
    /// Tuples of every record used, in record order.
    pub transitions: Vec<Transition<O, A>>,
    /// One-step mismatches of those records, in record order.
    pub mismatch: Vec<StepMismatch>,
    /// Records the filter let through: used, and failed with their reasons (scenario index).
    pub used: usize,
    /// The records that gave no tuple: (scenario index, why).
    pub failed: Vec<(u64, DemoError)>,
    /// Records the filter left out.
    pub filtered_out: usize,
}

/// The tuples of every record `filter` accepts (in parallel, output in record order).
pub fn demonstrations<P: Problem<Geometry = Planar>>(
    records: &[TrajectoryRecord],
    config: &EnvConfig,
    filter: RecordFilter,
    tolerances: &Tolerances,
) -> Demonstrations<P::Obs> {
    let chosen: Vec<&TrajectoryRecord> = records.iter().filter(|r| filter.accepts(r)).collect();
    let results: Vec<_> = chosen
        .par_iter()
        .map(|r| (r.index, record_demonstration::<P>(r, config, tolerances)))
        .collect();
    Demonstrations::gather(results, records.len() - chosen.len())
}

/// One record's tuples or why it gave none, with its scenario index.
pub type RecordResult<O, A> = (u64, Result<RecordDemonstration<O, A>, DemoError>);

impl<O, A> Demonstrations<O, A> {
    /// The tuples of each record's result (scenario index, tuples or why none), in the order
    /// given, with `filtered_out` records left out before.
    pub fn gather(results: Vec<RecordResult<O, A>>, filtered_out: usize) -> Self {
        let mut out = Self {
            transitions: Vec::new(),
            mismatch: Vec::new(),
            used: 0,
            failed: Vec::new(),
            filtered_out,
        };
        for (index, result) in results {
            match result {
                Ok(d) => {
                    out.used += 1;
                    out.transitions.extend(d.transitions);
                    out.mismatch.extend(d.mismatch);
                }
                Err(e) => out.failed.push((index, e)),
            }
        }
        out
    }
}

/// A dataset file's records and what they were solved for.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadedDataset<R> {
    /// Its records.
    pub records: Vec<R>,
    /// The family they were drawn from (a planar one in the reference plane).
    pub family: shared::mission::SpatialFamily,
    /// Cycles before the end of its episode a record was solved to arrive
    /// ([`SolveOptions::arrival_margin_steps`]).
    pub arrival_margin: u32,
    /// The spacecraft they were solved for, in the family's canonical units (`None`: not
    /// recorded, a dataset written before it was).
    pub spacecraft: Option<CanonicalSpacecraft>,
}

/// How a geometry's datasets become tuples (docs/spec.md sections 7 and 7.1): the planar
/// records' and the three-dimensional records'. Reading is apart from the tuples, so that a
/// dataset of another family is refused before its records are re-integrated.
pub trait DemoGeometry: crate::env::Geometry {
    /// The records of this geometry's datasets.
    type Record: Send + Sync;
    /// Reads the dataset file at `path` (a file of the other geometry's records is refused).
    fn load_dataset(path: &Path) -> Result<LoadedDataset<Self::Record>, DemoError>;
    /// The tuples of `records` for problem `P` under `config`, `filter` choosing the records
    /// (three-dimensional records keep samples only when converged: the converged ones are used
    /// whatever the filter), `tolerances` re-integrating each record.
    fn tuples<P: Problem<Geometry = Self>>(
        records: &[Self::Record],
        config: &EnvConfig,
        filter: RecordFilter,
        tolerances: &Tolerances,
    ) -> Demonstrations<P::Obs, Self::Action>;
    /// `state` as the numbers a relabel saves: x, y, vx, vy, m in the plane; x, y, z, vx, vy,
    /// vz, m in three dimensions (AU, AU/t*, m0 units).
    fn state_numbers(state: &Self::State) -> Vec<f64>;
    /// The state [`DemoGeometry::state_numbers`] saved; `None` for another count of numbers.
    fn state_from_numbers(numbers: &[f64]) -> Option<Self::State>;
    /// The rest of draw `(seed, index)` of `family` re-solved by the indirect method from
    /// `state`, visited at `step` of the draw's episode, as the tuples it places in that episode
    /// (docs/spec.md sections 7 and 7.1: [`relabel`] and [`placed_demonstration`], or
    /// [`spatial::relabel_spatial`] and [`spatial::placed_spatial_demonstration`]); `None` when
    /// the solve does not converge or its flight does not form tuples.
    fn relabel_tuples<P: Problem<Geometry = Self>>(
        family: &Self::Family,
        draw: (u64, u64),
        state: &Self::State,
        step: u32,
        spacecraft: &CanonicalSpacecraft,
        options: &SolveOptions,
        config: &EnvConfig,
    ) -> Option<Vec<Transition<P::Obs, Self::Action>>>;
}

/// The arrival margin and the spacecraft of the dataset at `path`: its run's request says them;
/// a folder without one (written before it existed, or a file moved out of its folder) shows the
/// margin by its records' `shortfalls` (cycles each ends before its episode) and no spacecraft.
fn dataset_margin_and_spacecraft(
    path: &Path,
    shortfalls: impl Iterator<Item = u32>,
) -> Result<(u32, Option<CanonicalSpacecraft>), DemoError> {
    Ok(match crate::generate::dataset_solve_request(path)? {
        Some(request) => (request.arrival_margin_steps, request.spacecraft),
        None => (shortfalls.max().unwrap_or(0), None),
    })
}

/// Refuses the dataset at `path` when it records a spacecraft other than the one `config` flies
/// (`config.body` the dataset's central body).
fn check_flown_spacecraft(path: &Path, config: &EnvConfig) -> Result<(), DemoError> {
    let flown = config
        .canonical_spacecraft()
        .map_err(|e| DemoError::Env(EnvError::Spacecraft(e)))?;
    Ok(crate::generate::check_dataset_spacecraft(path, &flown)?)
}

impl DemoGeometry for Planar {
    type Record = TrajectoryRecord;

    fn load_dataset(path: &Path) -> Result<LoadedDataset<TrajectoryRecord>, DemoError> {
        let dataset = read_dataset(path)?;
        let (arrival_margin, spacecraft) = dataset_margin_and_spacecraft(
            path,
            dataset
                .records
                .iter()
                .map(|r| Placement::whole(r).episode.steps - r.scenario.steps),
        )?;
        Ok(LoadedDataset {
            family: shared::mission::SpatialFamily::planar(dataset.manifest.family),
            records: dataset.records,
            arrival_margin,
            spacecraft,
        })
    }

    fn tuples<P: Problem<Geometry = Self>>(
        records: &[TrajectoryRecord],
        config: &EnvConfig,
        filter: RecordFilter,
        tolerances: &Tolerances,
    ) -> Demonstrations<P::Obs, [f32; ACTION_LEN]> {
        demonstrations::<P>(records, config, filter, tolerances)
    }

    fn state_numbers(state: &SpacecraftState) -> Vec<f64> {
        vec![state.r[0], state.r[1], state.v[0], state.v[1], state.m]
    }

    fn state_from_numbers(numbers: &[f64]) -> Option<SpacecraftState> {
        let &[x, y, vx, vy, m] = numbers else { return None };
        Some(SpacecraftState {
            r: [x, y],
            v: [vx, vy],
            m,
        })
    }

    fn relabel_tuples<P: Problem<Geometry = Self>>(
        family: &MissionFamily,
        (seed, index): (u64, u64),
        state: &SpacecraftState,
        step: u32,
        spacecraft: &CanonicalSpacecraft,
        options: &SolveOptions,
        config: &EnvConfig,
    ) -> Option<Vec<Transition<P::Obs, [f32; ACTION_LEN]>>> {
        let episode = family.draw(seed, index);
        let (record, placement) = relabel(family, (seed, index), &episode, state, step, spacecraft, options)?;
        if !record.converged {
            return None;
        }
        let demo = placed_demonstration::<P>(&record, &placement, config, &default_tolerances()).ok()?;
        Some(demo.transitions)
    }
}

impl DemoGeometry for crate::env::Spatial {
    type Record = crate::solver::spatial::record::SpatialRecord;

    fn load_dataset(path: &Path) -> Result<LoadedDataset<Self::Record>, DemoError> {
        let dataset = crate::generate::read_dataset_of::<shared::mission::SpatialFamily>(path)?;
        let (arrival_margin, spacecraft) = dataset_margin_and_spacecraft(
            path,
            dataset
                .records
                .iter()
                .map(|r| spatial::episode_of(r).scenario.steps - r.scenario.scenario.steps),
        )?;
        Ok(LoadedDataset {
            family: dataset.manifest.family,
            records: dataset.records,
            arrival_margin,
            spacecraft,
        })
    }

    fn tuples<P: Problem<Geometry = Self>>(
        records: &[Self::Record],
        config: &EnvConfig,
        _filter: RecordFilter,
        tolerances: &Tolerances,
    ) -> Demonstrations<P::Obs, [f32; onboard::features::ACTION3_LEN]> {
        spatial::spatial_demonstrations::<P>(records, config, tolerances)
    }

    fn state_numbers(state: &SpatialCraftState) -> Vec<f64> {
        let (r, v) = (state.orbit.r, state.orbit.v);
        vec![r[0], r[1], r[2], v[0], v[1], v[2], state.m]
    }

    fn state_from_numbers(numbers: &[f64]) -> Option<SpatialCraftState> {
        let &[x, y, z, vx, vy, vz, m] = numbers else {
            return None;
        };
        Some(SpatialCraftState {
            orbit: shared::orbit::SpatialState {
                r: [x, y, z],
                v: [vx, vy, vz],
            },
            m,
        })
    }

    fn relabel_tuples<P: Problem<Geometry = Self>>(
        family: &shared::mission::SpatialFamily,
        (seed, index): (u64, u64),
        state: &SpatialCraftState,
        step: u32,
        spacecraft: &CanonicalSpacecraft,
        options: &SolveOptions,
        config: &EnvConfig,
    ) -> Option<Vec<Transition<P::Obs, [f32; onboard::features::ACTION3_LEN]>>> {
        let episode = family.draw(seed, index);
        let (record, placement) =
            spatial::relabel_spatial(family, (seed, index), &episode, state, step, spacecraft, options)?;
        if !record.converged {
            return None;
        }
        let demo =
            spatial::placed_spatial_demonstration::<P>(&record, &placement, config, &default_tolerances()).ok()?;
        Some(demo.transitions)
    }
}

/// Statistics of the one-step mismatch over a dataset, split into coast steps (ZOH throttle 0),
/// full-thrust steps (mean throttle 1) and the rest (switches or partial throttle inside).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MismatchReport {
    /// Transfer or rendezvous.
    pub problem: ProblemKind,
    /// Records that gave tuples.
    pub records_used: usize,
    /// (scenario index, reason) of the records that gave none.
    pub records_failed: Vec<(u64, String)>,
    /// Records the filter left out.
    pub records_filtered_out: usize,
    /// Number of tuples.
    pub tuples: usize,
    /// |r_env - r_opt| over all steps, AU.
    pub position: Stats,
    /// |v_env - v_opt| over all steps, AU/t*.
    pub velocity: Stats,
    /// |m_env - m_opt| over all steps, fraction of m0.
    pub mass: Stats,
    /// Position mismatch on coast steps (mean throttle 0), AU.
    pub coast_position: Stats,
    /// Position mismatch on full-thrust steps (mean throttle 1), AU.
    pub full_thrust_position: Stats,
    /// Position mismatch on the other steps (switches or partial throttle), AU.
    pub switching_position: Stats,
    /// Velocity mismatch on those steps, AU/t*.
    pub switching_velocity: Stats,
    /// |w_trapezoid - w|: how far the endpoint rule on the record's step samples is off.
    pub trapezoid_error: Stats,
    /// Position mismatch of the unclipped f64 ZOH command: the hold error alone.
    pub unclipped_position: Stats,
}

impl MismatchReport {
    /// The report of `demos`' one-step mismatches.
    pub fn from_mismatch<O, A>(problem: ProblemKind, demos: &Demonstrations<O, A>) -> Self {
        Self::of_steps(
            problem,
            &demos.mismatch,
            demos.transitions.len(),
            (demos.used, &demos.failed, demos.filtered_out),
        )
    }

    /// The report of one-step mismatches `m` of `tuples` tuples, from records used, failed and
    /// filtered out as `records` says.
    pub fn of_steps(
        problem: ProblemKind,
        m: &[StepMismatch],
        tuples: usize,
        records: (usize, &[(u64, DemoError)], usize),
    ) -> Self {
        let (used, failed, filtered_out) = records;
        let coast = |s: &&StepMismatch| s.mean_throttle == 0.0;
        let full = |s: &&StepMismatch| s.mean_throttle >= 1.0 - 1e-12;
        let switching = |s: &&StepMismatch| !coast(s) && !full(s);
        Self {
            problem,
            records_used: used,
            records_failed: failed.iter().map(|(i, e)| (*i, e.to_string())).collect(),
            records_filtered_out: filtered_out,
            tuples,
            position: Stats::of(m.iter().map(|s| s.position)),
            velocity: Stats::of(m.iter().map(|s| s.velocity)),
            mass: Stats::of(m.iter().map(|s| s.mass)),
            coast_position: Stats::of(m.iter().filter(coast).map(|s| s.position)),
            full_thrust_position: Stats::of(m.iter().filter(full).map(|s| s.position)),
            switching_position: Stats::of(m.iter().filter(switching).map(|s| s.position)),
            switching_velocity: Stats::of(m.iter().filter(switching).map(|s| s.velocity)),
            trapezoid_error: Stats::of(m.iter().map(|s| s.trapezoid_error)),
            unclipped_position: Stats::of(m.iter().map(|s| s.unclipped_position)),
        }
    }
}

impl core::fmt::Display for MismatchReport {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        writeln!(
            f,
            "{:?} demonstrations: {} records used, {} failed, {} filtered out, {} tuples",
            self.problem,
            self.records_used,
            self.records_failed.len(),
            self.records_filtered_out,
            self.tuples
        )?;
        writeln!(
            f,
            "one-step mismatch, environment propagation of (s_k, a_k) vs optimal s_k+1 (canonical units):"
        )?;
        writeln!(
            f,
            "  {:<28} {:>6} {:>10} {:>10} {:>10} {:>10} {:>10}",
            "", "count", "mean", "p50", "p95", "max", "km / m/s"
        )?;
        let rows: [(&str, &Stats, f64); 9] = [
            ("position (AU)", &self.position, shared::units::AU_M / 1e3),
            ("velocity (AU/t*)", &self.velocity, shared::units::VELOCITY_UNIT_M_S),
            ("mass (m0)", &self.mass, f64::NAN),
            ("position, coast steps", &self.coast_position, shared::units::AU_M / 1e3),
            (
                "position, full-thrust steps",
                &self.full_thrust_position,
                shared::units::AU_M / 1e3,
            ),
            (
                "position, switching steps",
                &self.switching_position,
                shared::units::AU_M / 1e3,
            ),
            (
                "velocity, switching steps",
                &self.switching_velocity,
                shared::units::VELOCITY_UNIT_M_S,
            ),
            (
                "position, unclipped f64 ZOH",
                &self.unclipped_position,
                shared::units::AU_M / 1e3,
            ),
            ("trapezoid rule |dw|", &self.trapezoid_error, f64::NAN),
        ];
        for (name, s, unit) in rows {
            let si = if unit.is_nan() {
                String::from("-")
            } else {
                format!("{:.3e}", s.p95 * unit)
            };
            writeln!(
                f,
                "  {name:<28} {:>6} {:>10.3e} {:>10.3e} {:>10.3e} {:>10.3e} {:>10}",
                s.count, s.mean, s.p50, s.p95, s.max, si
            )?;
        }
        write!(f, "  (last column: p95 in km or m/s)")?;
        for (i, e) in &self.records_failed {
            write!(f, "\n  record {i} failed: {e}")?;
        }
        Ok(())
    }
}

/// The mismatch report of a dataset file, for the CLI: reads it, builds the tuples for its
/// problem with `config` (its spacecraft must be the one the dataset was solved with) and
/// returns the statistics.
pub fn mismatch_report(dataset: &Path, config: &EnvConfig, filter: RecordFilter) -> Result<MismatchReport, DemoError> {
    if crate::generate::holds_spatial_records(dataset)? {
        return spatial_mismatch_report(dataset, config);
    }
    let file = read_dataset(dataset)?;
    let problem = file.manifest.family.problem;
    // The spacecraft flies in the units of the dataset's central body.
    let config = &EnvConfig {
        body: file.manifest.family.body,
        ..*config
    };
    check_flown_spacecraft(dataset, config)?;
    let tol = default_tolerances();
    Ok(crate::with_problem!(problem, P => MismatchReport::from_mismatch(
        problem,
        &demonstrations::<P>(&file.records, config, filter, &tol),
    )))
}

/// [`mismatch_report`] of a three-dimensional dataset: its converged records' cycles flown by the
/// onboard RTN propagation ([`spatial::spatial_demonstrations`]). A 3D record keeps samples only
/// when converged, so the record filter changes nothing here.
fn spatial_mismatch_report(dataset: &Path, config: &EnvConfig) -> Result<MismatchReport, DemoError> {
    let file = crate::generate::read_dataset_of::<shared::mission::SpatialFamily>(dataset)?;
    let family = &file.manifest.family.family;
    let config = &EnvConfig {
        body: family.body,
        ..*config
    };
    check_flown_spacecraft(dataset, config)?;
    let tol = default_tolerances();
    Ok(
        crate::with_spatial_problem!(family.problem, P => MismatchReport::from_mismatch(
            family.problem,
            &spatial::spatial_demonstrations::<P>(&file.records, config, &tol),
        )),
    )
}

/// CLI entry: prints the mismatch report of a dataset for `spacecraft` and the default reward.
pub fn print_mismatch_report(dataset: &Path, spacecraft: &Spacecraft, filter: RecordFilter) -> Result<(), DemoError> {
    let config = EnvConfig {
        spacecraft: *spacecraft,
        ..EnvConfig::default()
    };
    let report = mismatch_report(dataset, &config, filter)?;
    println!("{report}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::sync::OnceLock;

    use super::*;
    use crate::env::{Rendezvous, Transfer};
    use crate::solver::record::sample_at;
    use crate::solver::{solve_scenario, SolveOptions};
    use onboard::features::decode_action;
    use shared::scenario::{Scenario, ScenarioKind};
    use shared::units::STEP;

    /// A short homotopy keeps the solve quick; the tuples are built the same at any eps.
    fn quick_options() -> SolveOptions {
        SolveOptions {
            final_eps: 0.3,
            ..SolveOptions::default()
        }
    }

    fn solved(kind: ScenarioKind, seed: u64) -> TrajectoryRecord {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let scenario = kind.draw(seed, 0);
        let record = solve_scenario(kind, seed, 0, &scenario, &sc, &quick_options());
        assert!(record.converged, "{:?}", record.failure);
        record
    }

    fn transfer_record() -> &'static TrajectoryRecord {
        static R: OnceLock<TrajectoryRecord> = OnceLock::new();
        R.get_or_init(|| solved(ScenarioKind::TransferCircular, 9))
    }

    fn rendezvous_record() -> &'static TrajectoryRecord {
        static R: OnceLock<TrajectoryRecord> = OnceLock::new();
        R.get_or_init(|| solved(ScenarioKind::RendezvousCircular, 9))
    }

    fn check_tuples<P: Problem<Geometry = Planar>>(record: &TrajectoryRecord) -> RecordDemonstration<P::Obs> {
        let config = EnvConfig::default();
        let demo = record_demonstration::<P>(record, &config, &default_tolerances()).unwrap();
        let n = record.scenario.steps;
        assert_eq!(demo.transitions.len(), n as usize);
        let mut env = MdpEnv::<P>::new(&config).unwrap();
        for (k, t) in (0u32..).zip(&demo.transitions) {
            let (now, next) = (
                state_of(&record.steps[k as usize]),
                state_of(&record.steps[k as usize + 1]),
            );
            assert_eq!(t.step, k);
            // Observations are the environment's, of the optimal states.
            assert_eq!(t.observation, env.reset_at(&record.scenario, &now, k).unwrap());
            assert_eq!(
                t.next_observation,
                env.reset_at(&record.scenario, &next, k + 1).unwrap()
            );
            // Reward and done bit-identical to the environment's on the same next state.
            let throttle = decode_action(&t.action).throttle;
            let (reward, ..) = MdpEnv::<P>::reward_at(&config, &record.scenario, &next, k + 1, throttle).unwrap();
            assert_eq!(t.reward.to_bits(), reward.to_bits());
            env.reset_at(&record.scenario, &now, k).unwrap();
            assert_eq!(t.done, env.step(&t.action).unwrap().done);
            assert_eq!(t.done, k + 1 == n);
            assert!(t.action.iter().all(|a| a.abs() <= ACTION_BOUND as f32));
        }
        demo
    }

    #[test]
    fn transfer_tuples_use_the_environment_reward_and_done() {
        let demo = check_tuples::<Transfer>(transfer_record());
        // The ZOH control reproduces the optimal step to within the hold error: well under the
        // distance flown in a step (about 0.24 AU).
        for m in &demo.mismatch {
            assert!(m.position < 5e-3 && m.velocity < 2e-2 && m.mass < 1e-3, "{m:?}");
        }
    }

    #[test]
    fn rendezvous_tuples_use_the_environment_reward_and_done() {
        let demo = check_tuples::<Rendezvous>(rendezvous_record());
        for m in &demo.mismatch {
            assert!(m.position < 5e-3 && m.velocity < 2e-2 && m.mass < 1e-3, "{m:?}");
        }
    }

    /// Bellman's principle of optimality as a check of [`relabel`] and [`placed_demonstration`]:
    /// re-solved from the optimal state at mid-flight (mass m, a spacecraft of thrust T / m, the
    /// steps left, for a rendezvous the body where it is then), the optimal tail is the tail of
    /// the whole optimal flight, so the relabelled record placed at that step gives the whole
    /// record's tuples from there on.
    /// A re-solved tail's tuples are the whole record's from the same cycle on: cycles and done
    /// flags equal, observations within 1e-5, actions 1e-4, rewards 1e-6.
    pub(super) fn assert_same_tail<O, A>(tail: &[Transition<O, A>], whole: &[Transition<O, A>])
    where
        O: AsRef<[f32]> + core::fmt::Debug,
        A: AsRef<[f32]> + core::fmt::Debug,
    {
        assert!(!tail.is_empty() && tail.len() == whole.len());
        let worst = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        for (t, w) in tail.iter().zip(whole) {
            assert_eq!((t.step, t.done), (w.step, w.done));
            assert!(
                worst(t.observation.as_ref(), w.observation.as_ref()) < 1e-5,
                "{t:?}\n{w:?}"
            );
            assert!(
                worst(t.next_observation.as_ref(), w.next_observation.as_ref()) < 1e-5,
                "{t:?}\n{w:?}"
            );
            assert!(worst(t.action.as_ref(), w.action.as_ref()) < 1e-4, "{t:?}\n{w:?}");
            assert!((t.reward - w.reward).abs() < 1e-6, "{t:?}\n{w:?}");
        }
    }

    fn resolved_from_mid_flight_gives_the_tail<P: Problem<Geometry = Planar>>(whole_record: &TrajectoryRecord) {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let n = whole_record.scenario.steps;
        let k = n / 2;
        let mid = state_of(&whole_record.steps[k as usize]);
        let (tail_record, placement) = relabel(
            &whole_record.family,
            (7, 0),
            &whole_record.scenario,
            &mid,
            k,
            &sc,
            &quick_options(),
        )
        .unwrap();
        assert!(tail_record.converged, "{:?}", tail_record.failure);
        assert_eq!(tail_record.final_eps, whole_record.final_eps);
        assert_eq!((placement.start_step, placement.start_mass), (k, mid.m));
        // The same optimum: the tail ends at the whole flight's final mass.
        let tail_final = placement.start_mass * tail_record.final_mass;
        assert!(
            (tail_final - whole_record.final_mass).abs() < 1e-6,
            "{tail_final} vs {}",
            whole_record.final_mass
        );
        let config = EnvConfig::default();
        let tol = default_tolerances();
        let whole = record_demonstration::<P>(whole_record, &config, &tol).unwrap();
        let tail = placed_demonstration::<P>(&tail_record, &placement, &config, &tol).unwrap();
        assert_eq!(tail.transitions.len(), (n - k) as usize);
        assert_same_tail(&tail.transitions, &whole.transitions[k as usize..]);
        // A placement whose steps do not add up is refused.
        let wrong = Placement {
            start_step: k + 1,
            ..placement
        };
        assert_eq!(
            placed_demonstration::<P>(&tail_record, &wrong, &config, &tol).err(),
            Some(DemoError::Placement)
        );
    }

    #[test]
    fn a_transfer_resolved_from_mid_flight_gives_the_tail_of_the_whole_tuples() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let kind = ScenarioKind::TransferHard;
        let whole_record = solve_scenario(kind, 7, 0, &kind.draw(7, 0), &sc, &quick_options());
        assert!(whole_record.converged, "{:?}", whole_record.failure);
        resolved_from_mid_flight_gives_the_tail::<Transfer>(&whole_record);
    }

    #[test]
    fn a_rendezvous_resolved_from_mid_flight_gives_the_tail_of_the_whole_tuples() {
        resolved_from_mid_flight_gives_the_tail::<Rendezvous>(rendezvous_record());
    }

    /// Solved with an arrival margin, a rendezvous meets the body `margin` steps early; its
    /// tuples fill the draw's whole episode, the last `margin` of them coasting, and the coasted
    /// spacecraft stays on the body (its Keplerian orbit, computed independently of the
    /// environment's propagator) to the end.
    #[test]
    fn a_rendezvous_arriving_early_coasts_with_the_body_to_the_end_of_its_episode() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let kind = ScenarioKind::RendezvousCircular;
        let draw = kind.draw(9, 0);
        let margin = 2;
        let options = SolveOptions {
            arrival_margin_steps: margin,
            ..quick_options()
        };
        let record = solve_arriving_early(kind, 9, 0, &draw, &sc, &options);
        assert!(record.converged, "{:?}", record.failure);
        assert_eq!(record.scenario.steps, draw.steps - margin);
        assert_eq!(Placement::whole(&record).episode, draw);
        let config = EnvConfig::default();
        let demo = record_demonstration::<Rendezvous>(&record, &config, &default_tolerances()).unwrap();
        let n = draw.steps;
        assert_eq!(demo.transitions.len(), n as usize);
        let coast = coast_action();
        let mut env = MdpEnv::<Rendezvous>::new(&config).unwrap();
        let mut state = state_of(record.steps.last().unwrap());
        for (k, t) in (0u32..).zip(&demo.transitions) {
            assert_eq!((t.step, t.done), (k, k + 1 == n));
            if k < n - margin {
                continue;
            }
            assert_eq!(t.action, coast, "step {k}");
            let body = body_at(&draw, k).unwrap();
            let miss = (state.r[0] - body.r[0]).hypot(state.r[1] - body.r[1]);
            let speed = (state.v[0] - body.v[0]).hypot(state.v[1] - body.v[1]);
            assert!(miss < 1e-6 && speed < 1e-6, "step {k}: {miss:e} AU, {speed:e}");
            assert_eq!(t.observation, env.reset_at(&draw, &state, k).unwrap());
            state = env.step(&coast).unwrap().info.state;
            assert_eq!(t.next_observation, env.reset_at(&draw, &state, k + 1).unwrap());
        }
        let body = body_at(&draw, n).unwrap();
        assert!((state.r[0] - body.r[0]).hypot(state.r[1] - body.r[1]) < 1e-6);
        // The environment's terminal residuals of the last tuple's state are the body's.
        let last = demo.transitions.last().unwrap();
        let (reward, ..) = MdpEnv::<Rendezvous>::reward_at(&config, &draw, &state, n, 0.0).unwrap();
        assert_eq!(last.reward.to_bits(), reward.to_bits());
    }

    /// A transfer arriving early coasts on its target orbit: every coasted state's orbit (from
    /// vis-viva and the eccentricity vector, mu = 1) is the target's, and the tuples are the
    /// environment's own coast steps.
    #[test]
    fn a_transfer_arriving_early_coasts_on_its_target_orbit_to_the_end_of_its_episode() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let kind = ScenarioKind::TransferHard;
        let draw = kind.draw(9, 1);
        let margin = 2;
        let options = SolveOptions {
            arrival_margin_steps: margin,
            ..quick_options()
        };
        let record = solve_arriving_early(kind, 9, 1, &draw, &sc, &options);
        assert!(record.converged, "{:?}", record.failure);
        assert_eq!(record.scenario.steps, draw.steps - margin);
        let config = EnvConfig::default();
        let demo = record_demonstration::<Transfer>(&record, &config, &default_tolerances()).unwrap();
        let n = draw.steps;
        assert_eq!(demo.transitions.len(), n as usize);
        let target = draw.target;
        let on_target = |state: &SpacecraftState, k: u32| {
            let r = state.r[0].hypot(state.r[1]);
            let v2 = state.v[0] * state.v[0] + state.v[1] * state.v[1];
            let a = 1.0 / (2.0 / r - v2);
            let rv = state.r[0] * state.v[0] + state.r[1] * state.v[1];
            let e = [0, 1].map(|i| (v2 - 1.0 / r) * state.r[i] - rv * state.v[i]);
            let wanted = [target.e * target.omega.cos(), target.e * target.omega.sin()];
            let off = (a - target.a).abs().max((e[0] - wanted[0]).hypot(e[1] - wanted[1]));
            assert!(off < 1e-6, "step {k}: {off:e} off the target orbit");
        };
        let coast = coast_action();
        let mut env = MdpEnv::<Transfer>::new(&config).unwrap();
        let mut state = state_of(record.steps.last().unwrap());
        for (k, t) in (0u32..).zip(&demo.transitions).skip((n - margin) as usize) {
            assert_eq!((t.step, t.done, t.action), (k, k + 1 == n, coast));
            on_target(&state, k);
            assert_eq!(t.observation, env.reset_at(&draw, &state, k).unwrap());
            let flown = env.step(&coast).unwrap();
            state = flown.info.state;
            assert_eq!(
                (t.next_observation, t.reward.to_bits()),
                (flown.observation, flown.reward.to_bits())
            );
        }
        on_target(&state, n);
    }

    /// A relabel keeps the margin too: the rest of the flight is solved to arrive early and its
    /// tuples coast to the episode's end.
    #[test]
    fn a_relabel_with_a_margin_arrives_early_and_coasts_to_the_end() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let whole = rendezvous_record();
        let n = whole.scenario.steps;
        let k = n / 2;
        let options = SolveOptions {
            arrival_margin_steps: 2,
            ..quick_options()
        };
        let mid = state_of(&whole.steps[k as usize]);
        let (rest, placement) = relabel(&whole.family, (7, 0), &whole.scenario, &mid, k, &sc, &options).unwrap();
        assert!(rest.converged, "{:?}", rest.failure);
        assert_eq!(rest.scenario.steps, n - k - 2);
        let demo = placed_demonstration::<Rendezvous>(&rest, &placement, &EnvConfig::default(), &default_tolerances())
            .unwrap();
        assert_eq!(demo.transitions.len(), (n - k) as usize);
        let coast = coast_action();
        assert!(demo.transitions[(n - k - 2) as usize..]
            .iter()
            .all(|t| t.action == coast));
        assert!(demo.transitions.last().unwrap().done);
    }

    /// The rest of a rendezvous chases the same body: at the rest's start and at its arrival
    /// the body stands where it stands at those steps of the whole flight (Kepler from two
    /// epochs); the spacecraft is scaled to the state's mass; no rest after the last step.
    #[test]
    fn the_rest_of_a_rendezvous_meets_the_same_body_at_the_same_time() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let whole = rendezvous_record();
        let n = whole.scenario.steps;
        let k = n / 2;
        let mid = state_of(&whole.steps[k as usize]);
        let (rest, scaled) = rest_of_flight(&whole.scenario, &mid, k, &sc).unwrap();
        assert_eq!(rest.steps, n - k);
        assert!((scaled.thrust * mid.m - sc.thrust).abs() < 1e-15);
        for (rest_step, whole_step) in [(0, k), (n - k, n)] {
            let a = body_at(&rest, rest_step).unwrap();
            let b = body_at(&whole.scenario, whole_step).unwrap();
            let gap = (0..2)
                .map(|i| (a.r[i] - b.r[i]).abs() + (a.v[i] - b.v[i]).abs())
                .sum::<f64>();
            assert!(gap < 1e-9, "step {whole_step}: {gap:e}");
        }
        let start = rest.initial.cartesian();
        assert!((0..2).all(|i| (start.r[i] - mid.r[i]).abs() < 1e-12 && (start.v[i] - mid.v[i]).abs() < 1e-12));
        assert!(rest_of_flight(&whole.scenario, &mid, n, &sc).is_none());
    }

    /// A margin the flight cannot hold is not applied: the draw is solved on time.
    #[test]
    fn a_margin_as_long_as_the_flight_solves_it_on_time() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let kind = ScenarioKind::RendezvousCircular;
        let draw = kind.draw(9, 0);
        let options = SolveOptions {
            arrival_margin_steps: draw.steps,
            ..quick_options()
        };
        let record = solve_arriving_early(kind, 9, 0, &draw, &sc, &options);
        assert_eq!(record.scenario, draw);
        assert_eq!(record.final_mass, rendezvous_record().final_mass);
    }

    /// The re-integrated integral against a fine composite Simpson rule on states sampled by
    /// the dataset's own sampler (independent of the augmented system).
    #[test]
    fn zoh_integral_matches_a_fine_quadrature() {
        let record = transfer_record();
        let config = EnvConfig::default();
        let tol = default_tolerances();
        let controls = zoh_controls(record, &config, &tol).unwrap();
        let params = OptimalControlParams {
            spacecraft: Spacecraft::MSR_ERO.canonical().unwrap(),
            eps: record.final_eps,
        };
        let y0 = initial_state_costate(&record.scenario, &record.costates);
        for k in [0u32, 7, 15] {
            let m = 2000;
            let t0 = f64::from(k) * STEP;
            let times: Vec<f64> = (0..=m).map(|i| t0 + STEP * f64::from(i) / f64::from(m)).collect();
            let samples = sample_at(&y0, &params, &times, &tol).unwrap();
            let mut w = [0.0; 2];
            for (i, s) in samples.iter().enumerate() {
                let weight = if i == 0 || i == m as usize {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                for (j, wj) in w.iter_mut().enumerate() {
                    *wj += weight * s.throttle * s.direction_polar[j] / (3.0 * f64::from(m));
                }
            }
            let c = controls[k as usize];
            assert!(
                (c.w[0] - w[0]).abs() < 1e-9 && (c.w[1] - w[1]).abs() < 1e-9,
                "step {k}: {c:?} vs {w:?}"
            );
            assert!(c.mean_throttle + 1e-12 >= c.w[0].hypot(c.w[1]));
        }
    }

    #[test]
    fn actions_are_clipped_and_tiny_throttles_coast() {
        let full = ZohControl {
            w: [0.0, 1.0],
            mean_throttle: 1.0,
        };
        let a = full.action();
        assert_eq!(a, [ACTION_BOUND as f32, 0.0, ACTION_BOUND as f32]);
        let d = decode_action(&a);
        assert!((d.throttle - 0.9995).abs() < 1e-7 && d.alpha_theta == 1.0);
        let off = ZohControl {
            w: [1e-5, 0.0],
            mean_throttle: 1e-5,
        };
        assert_eq!(off.action(), [-ACTION_BOUND as f32, 0.0, 0.0]);
        assert_eq!(decode_action(&off.action()).throttle, 0.0);
        let small = ZohControl {
            w: [0.0, -3e-4],
            mean_throttle: 3e-4,
        };
        let d = decode_action(&small.action());
        assert!((d.throttle - 5e-4).abs() < 1e-7 && d.alpha_theta == -1.0);
        let half = ZohControl {
            w: [0.3, 0.4],
            mean_throttle: 0.5,
        };
        let d = decode_action(&half.action());
        assert!((d.throttle - 0.5).abs() < 1e-7 && (d.alpha_r - 0.6).abs() < 1e-7);
    }

    #[test]
    fn filters_wrong_problems_and_other_spacecraft_are_handled() {
        let good = transfer_record().clone();
        let mut stalled = good.clone();
        stalled.converged = false;
        stalled.index = 1;
        let mut failed = good.clone();
        failed.converged = false;
        failed.steps.clear();
        failed.index = 2;
        let records = [good.clone(), stalled, failed];
        let config = EnvConfig::default();
        let tol = default_tolerances();
        let n = good.scenario.steps as usize;
        let converged = demonstrations::<Transfer>(&records, &config, RecordFilter::Converged, &tol);
        assert_eq!(
            (converged.used, converged.filtered_out, converged.transitions.len()),
            (1, 2, n)
        );
        let all = demonstrations::<Transfer>(&records, &config, RecordFilter::All, &tol);
        assert_eq!((all.used, all.filtered_out, all.transitions.len()), (2, 1, 2 * n));
        assert_eq!(all.transitions[n].record, 1);
        let report = MismatchReport::from_mismatch(ProblemKind::Transfer, &all);
        assert_eq!(report.tuples, 2 * n);
        assert!(report.position.max < 5e-3);
        assert!(report.to_string().contains("one-step mismatch"));
        // Rendezvous tuples from a transfer record: refused.
        assert!(matches!(
            record_demonstration::<Rendezvous>(&good, &config, &tol),
            Err(DemoError::WrongProblem { .. })
        ));
        // A heavier spacecraft than the one the record was solved with: caught.
        let other = EnvConfig {
            spacecraft: Spacecraft {
                initial_mass_kg: 4000.0,
                ..Spacecraft::MSR_ERO
            },
            ..EnvConfig::default()
        };
        assert!(matches!(
            record_demonstration::<Transfer>(&good, &other, &tol),
            Err(DemoError::Inconsistent { .. })
        ));
        let _: &Scenario = &good.scenario;
    }

    /// Through a dataset file as the CLI will: written by the generator's writer, read back,
    /// the problem taken from its manifest, the filter applied.
    #[test]
    fn mismatch_report_reads_a_dataset_file() {
        use crate::generate::{write_outputs, DatasetFile, Manifest, Shard};
        let dir = std::env::temp_dir().join(format!("lowthrust-demo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let record = rendezvous_record().clone();
        let mut stalled = record.clone();
        stalled.index = 1;
        stalled.converged = false;
        let file = DatasetFile {
            manifest: Manifest {
                family: record.family,
                seed: record.seed,
                count: 2,
            },
            shard: Shard::WHOLE,
            records: vec![record, stalled],
        };
        write_outputs(&dir, &file).unwrap();
        let path = dir.join("dataset.ltds");
        let config = EnvConfig::default();
        let converged = mismatch_report(&path, &config, RecordFilter::Converged).unwrap();
        let all = mismatch_report(&path, &config, RecordFilter::All).unwrap();
        assert_eq!(converged.problem, ProblemKind::Rendezvous);
        assert_eq!((converged.records_used, converged.records_filtered_out), (1, 1));
        assert_eq!((all.records_used, all.tuples), (2, 2 * converged.tuples));
        // The hold error dominates: the action's f32 narrowing moves the one-step position by
        // far less than 1e-8 AU (an f32 rounding of a command whose displacement over one step
        // is ~1e-3 AU), in either direction, so the two maxima agree to that.
        assert!(converged.position.max > 0.0);
        assert!((converged.unclipped_position.max - converged.position.max).abs() < 1e-8);
        assert!((converged.unclipped_position.mean - converged.position.mean).abs() < 1e-8);
        assert!(matches!(
            mismatch_report(&dir.join("missing.ltds"), &config, RecordFilter::All),
            Err(DemoError::Dataset(_))
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The report of a real dataset: `LOWTHRUST_DATASET=/path/dataset.ltds cargo test -p
    /// lowthrust-ground --lib demo::tests::dataset_mismatch_report -- --ignored --nocapture`
    /// (`LOWTHRUST_FILTER=all` to include unconverged records).
    #[test]
    #[ignore = "needs a dataset file"]
    fn dataset_mismatch_report() {
        let path = std::env::var("LOWTHRUST_DATASET").expect("LOWTHRUST_DATASET");
        let filter = match std::env::var("LOWTHRUST_FILTER").as_deref() {
            Ok("all") => RecordFilter::All,
            _ => RecordFilter::Converged,
        };
        print_mismatch_report(Path::new(&path), &Spacecraft::MSR_ERO, filter).unwrap();
    }

    #[test]
    fn quick_records_report() {
        let config = EnvConfig::default();
        let tol = default_tolerances();
        let t = demonstrations::<Transfer>(
            std::slice::from_ref(transfer_record()),
            &config,
            RecordFilter::All,
            &tol,
        );
        println!("{}", MismatchReport::from_mismatch(ProblemKind::Transfer, &t));
        let r = demonstrations::<Rendezvous>(
            std::slice::from_ref(rendezvous_record()),
            &config,
            RecordFilter::All,
            &tol,
        );
        println!("{}", MismatchReport::from_mismatch(ProblemKind::Rendezvous, &r));
        assert!(t.failed.is_empty() && r.failed.is_empty());
    }
}
