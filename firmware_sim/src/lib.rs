//! Software-in-the-loop flight: the onboard guidance loop flying against a truth plant.
//!
//! The loop is what flight software runs each 14-day guidance cycle: take the navigation
//! state, encode the features, run the network, command the thruster (thrust off when the
//! guidance step refuses its input or the blob was refused at load). The truth plant is
//! propagated by the onboard dynamics, segment by segment inside each cycle, so the
//! [`dispersion`]s of the real world (navigation noise, thrust magnitude and pointing errors,
//! missed-thrust events that start and end anywhere in a cycle) act on it. With
//! [`Dispersions::NONE`] a flight is bit-identical to the ground environment's episode.
//!
//! One loop flies both problems ([`fly_observed`]); a [`Problem`] says what it steers to: the
//! target orbit of a [`Transfer`], or the body of a [`Rendezvous`], whose state flight software
//! propagates onboard each cycle by the Kepler coast from the scenario's epoch.
//!
//! The core is `no_std` and allocation-free ([`fly_observed`] reports each step to a closure),
//! so the Cortex-M4 image runs the very same code; the `std` feature adds [`Flight`], a
//! recorded flight.
//!
//! # Map
//!
//! - this module: the loop ([`fly_observed`], and [`fly`] recording it; one loop for both
//!   geometries), what it flies
//!   with beside the scenario ([`FlightSetup`]), the flight computer's network or safe mode
//!   ([`Controller`]), the problems ([`Transfer`], [`Rendezvous`], and [`Transfer3`],
//!   [`Rendezvous3`] on inclined orbits) and a hand-tuned baseline law ([`ProxyTracking`]);
//! - [`dispersion`]: the real world's dispersions and the truth plant that draws them;
//! - [`trace`]: the flights both the host and the Cortex-M4F image fly, written line by line
//!   so the two can be compared bit for bit.
//!
//! # Example
//!
//! The baseline law flown from a 1 AU circle to a 1.3 AU circle, nominally and with the
//! typical dispersions:
//!
//! ```
//! use firmware_sim::{fly, Dispersions, FlightSetup, ProxyTracking, Transfer};
//! use shared::orbit::{OrbitElements, OrbitShape};
//! use shared::scenario::Scenario;
//! use shared::spacecraft::Spacecraft;
//!
//! let circle = |a| OrbitShape { a, e: 0.0, omega: 0.0 };
//! let scenario = Scenario::transfer(OrbitElements { shape: circle(1.0), nu: 0.0 }, circle(1.3));
//! let nominal = FlightSetup::nominal(Spacecraft::MSR_ERO.canonical()?);
//! let law = ProxyTracking { target_a: 1.3 };
//!
//! let flight = fly(Transfer, &law, &scenario, &nominal, 0)?;
//! assert_eq!(flight.steps.len(), scenario.steps as usize);
//! let miss = flight.final_residuals().ok_or("no cycle flown")?;
//! assert!(miss.position < 0.02, "{miss:?}"); // AU
//! assert!(flight.final_state().m < 1.0); // propellant was spent
//!
//! // Each seed draws its own dispersed flight; the nominal plant ignores the seed.
//! let dispersed = nominal.dispersed(Dispersions::TYPICAL);
//! let a = fly(Transfer, &law, &scenario, &dispersed, 1)?;
//! assert_eq!(a, fly(Transfer, &law, &scenario, &dispersed, 1)?);
//! assert_ne!(a, flight);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod dispersion;
pub mod trace;

use onboard::dynamics::{PropagationError, SpacecraftState, ThrustCommand};
use onboard::features::{
    reward, FeatureError, Residuals, RewardWeights, ACTION3_LEN, ACTION_LEN, RENDEZVOUS3_FEATURES, RENDEZVOUS_FEATURES,
    TRANSFER3_FEATURES, TRANSFER_FEATURES,
};
pub use onboard::geometry::{Dimension, Planar, Spatial};
use onboard::guidance::{Actor, GuidanceError, Guide, SpatialTargetFeatures, TargetFeatures, TargetOrbit3};
use onboard::integrator::Tolerances;
use onboard::kepler::{coast, coast3, KeplerError};
use onboard::policy::{Mlp, PolicyError, Rendezvous3Policy, RendezvousPolicy, Transfer3Policy, TransferPolicy};
use onboard::spatial::{RtnCommand, SpatialCraftState};
use shared::blob::ProblemKind;
use shared::decimal::Decimal6;
use shared::orbit::{CartesianState, OrbitShape, SpatialState};
use shared::scenario::{Scenario, ScenarioError, SpatialScenario};
use shared::spacecraft::CanonicalSpacecraft;

pub use dispersion::{DispersedPlant, DispersionError, Dispersions};

#[doc(hidden)]
pub use onboard::features::{
    RENDEZVOUS3_FEATURES as __RENDEZVOUS3_FEATURES, RENDEZVOUS_FEATURES as __RENDEZVOUS_FEATURES,
    TRANSFER3_FEATURES as __TRANSFER3_FEATURES, TRANSFER_FEATURES as __TRANSFER_FEATURES,
};
#[doc(hidden)]
pub use shared::blob::ProblemKind as __ProblemKind;

/// Evaluates `$body` with the type `$P` naming the loop's [`Problem`] of `$kind` (a
/// `ProblemKind`) and the constant `$N` its feature count: the one place the flight loop's
/// problems are listed, so code generic over [`Problem`] is called for a scenario's problem
/// without a match arm per problem.
///
/// ```
/// use firmware_sim::{with_flight_problem, Problem};
/// use shared::blob::ProblemKind;
///
/// let features = |kind| with_flight_problem!(kind, N, P => (N, P::KIND));
/// assert_eq!(features(ProblemKind::Transfer), (10, ProblemKind::Transfer));
/// assert_eq!(features(ProblemKind::Rendezvous), (22, ProblemKind::Rendezvous));
/// ```
#[macro_export]
macro_rules! with_flight_problem {
    ($kind:expr, $N:ident, $P:ident => $body:expr) => {
        match $kind {
            $crate::__ProblemKind::Transfer => {
                const $N: usize = $crate::__TRANSFER_FEATURES;
                type $P = $crate::Transfer;
                $body
            }
            $crate::__ProblemKind::Rendezvous => {
                const $N: usize = $crate::__RENDEZVOUS_FEATURES;
                type $P = $crate::Rendezvous;
                $body
            }
        }
    };
}

/// Evaluates `$body` with the type `$P` naming the three-dimensional loop's [`Problem`] of
/// `$kind` (a `ProblemKind`) and the constant `$N` its feature count (15 or 30), as
/// [`with_flight_problem!`] does in the plane.
#[macro_export]
macro_rules! with_spatial_flight_problem {
    ($kind:expr, $N:ident, $P:ident => $body:expr) => {
        match $kind {
            $crate::__ProblemKind::Transfer => {
                const $N: usize = $crate::__TRANSFER3_FEATURES;
                type $P = $crate::Transfer3;
                $body
            }
            $crate::__ProblemKind::Rendezvous => {
                const $N: usize = $crate::__RENDEZVOUS3_FEATURES;
                type $P = $crate::Rendezvous3;
                $body
            }
        }
    };
}

/// Hidden width of the flown actors (onboard's `TransferPolicy` and `RendezvousPolicy`).
const HIDDEN: usize = 256;

/// The network flown on `N` features with `OUT` action outputs: the transfer (10) or rendezvous
/// (22) actor with 3, in three dimensions (15 or 30 features) with 4.
pub type Policy<'a, const N: usize, const OUT: usize = ACTION_LEN> = Mlp<'a, N, HIDDEN, HIDDEN, OUT>;

// The flown policies are onboard's: a change of their shape there fails to compile here.
const _: fn(TransferPolicy<'_>) -> Policy<'_, TRANSFER_FEATURES> = |p| p;
const _: fn(RendezvousPolicy<'_>) -> Policy<'_, RENDEZVOUS_FEATURES> = |p| p;
const _: fn(Transfer3Policy<'_>) -> Policy<'_, TRANSFER3_FEATURES, ACTION3_LEN> = |p| p;
const _: fn(Rendezvous3Policy<'_>) -> Policy<'_, RENDEZVOUS3_FEATURES, ACTION3_LEN> = |p| p;

/// A dimension of flight as the loop flies it: the dimension ([`Dimension`]: scenario, state,
/// command, propagation) and how the truth plant navigates and points in it. Implemented by
/// [`Planar`] (polar commands) and [`Spatial`] (RTN commands); the loop ([`fly_observed`]) is
/// one implementation for both.
pub trait FlightGeometry: Dimension {
    /// What the navigation system reports for the true state.
    fn navigate(plant: &mut DispersedPlant, truth: &Self::State) -> Self::State;
    /// The command the thruster follows (pointing error applied).
    fn point(plant: &mut DispersedPlant, command: &Self::Command) -> Self::Command;
}

impl FlightGeometry for Planar {
    fn navigate(plant: &mut DispersedPlant, truth: &SpacecraftState) -> SpacecraftState {
        plant.navigate(truth)
    }

    fn point(plant: &mut DispersedPlant, command: &ThrustCommand) -> ThrustCommand {
        plant.point(command)
    }
}

/// The pointing error in three dimensions is a cone about the commanded direction, the
/// navigation error in every axis.
impl FlightGeometry for Spatial {
    fn navigate(plant: &mut DispersedPlant, truth: &SpatialCraftState) -> SpatialCraftState {
        plant.navigate3(truth)
    }

    fn point(plant: &mut DispersedPlant, command: &RtnCommand) -> RtnCommand {
        plant.point3(command)
    }
}

/// The state type of a problem's geometry.
pub type StateOf<P, const N: usize> = <<P as Problem<N>>::Geometry as Dimension>::State;
/// The command type of a problem's geometry.
pub type CommandOf<P, const N: usize> = <<P as Problem<N>>::Geometry as Dimension>::Command;
/// The scenario type of a problem's geometry.
pub type ScenarioOf<P, const N: usize> = <<P as Problem<N>>::Geometry as Dimension>::Scenario;

/// What the guidance loop steers to, and how flight software knows it at each cycle. The loop
/// is generic over it so that every problem flies one implementation. Implemented by the
/// zero-sized markers [`Transfer`] and [`Rendezvous`] (in the plane) and [`Transfer3`] and
/// [`Rendezvous3`] (in three dimensions), passed by value to pick the problem.
pub trait Problem<const N: usize>: Copy {
    /// The problem of the scenarios and blobs this flies.
    const KIND: ProblemKind;
    /// The dimension it is flown in.
    type Geometry: FlightGeometry;
    /// The target as guidance is given it: an orbit, or a body's state. Its features and
    /// residuals are onboard's, the guidance step's own.
    type Target: Copy;

    /// The target at t = `index` cycles, computed as flight software does.
    fn target(scenario: &ScenarioOf<Self, N>, index: u32) -> Result<Self::Target, SilError>;
    /// The `N` features of `state` against `target`, `time_to_go` before the arrival.
    fn features(target: &Self::Target, state: &StateOf<Self, N>, time_to_go: f64) -> Result<[f64; N], FeatureError>;
    /// The residuals read off the features.
    fn residuals(features: &[f64; N]) -> Residuals;
}

/// A problem flown in the plane, its target one the onboard aids (lookahead, terminal targeting)
/// see through [`TargetFeatures`]: [`Transfer`] and [`Rendezvous`].
pub trait PlanarProblem<const N: usize>: Problem<N, Geometry = Planar, Target: TargetFeatures<N>> {}

impl<const N: usize, P: Problem<N, Geometry = Planar, Target: TargetFeatures<N>>> PlanarProblem<N> for P {}

/// A free-anomaly transfer (docs/spec.md section 5): the target is the orbit itself.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Transfer;

/// A rendezvous (docs/spec.md section 6): the target is a body on the target orbit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Rendezvous;

/// A free-anomaly transfer in three dimensions (docs/spec.md section 6.1): the target is the
/// orbit in its plane.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Transfer3;

/// A rendezvous in three dimensions: the target is a body on the inclined target orbit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Rendezvous3;

impl Problem<TRANSFER_FEATURES> for Transfer {
    const KIND: ProblemKind = ProblemKind::Transfer;
    type Geometry = Planar;
    type Target = OrbitShape;

    fn target(scenario: &Scenario, _index: u32) -> Result<OrbitShape, SilError> {
        Ok(scenario.target)
    }

    fn features(
        target: &OrbitShape,
        state: &SpacecraftState,
        time_to_go: f64,
    ) -> Result<[f64; TRANSFER_FEATURES], FeatureError> {
        target.features_after(state, 0.0, time_to_go)
    }

    fn residuals(features: &[f64; TRANSFER_FEATURES]) -> Residuals {
        <OrbitShape as TargetFeatures<TRANSFER_FEATURES>>::residuals(features)
    }
}

impl Problem<RENDEZVOUS_FEATURES> for Rendezvous {
    const KIND: ProblemKind = ProblemKind::Rendezvous;
    type Geometry = Planar;
    type Target = CartesianState;

    fn features(
        target: &CartesianState,
        state: &SpacecraftState,
        time_to_go: f64,
    ) -> Result<[f64; RENDEZVOUS_FEATURES], FeatureError> {
        target.features_after(state, 0.0, time_to_go)
    }

    fn residuals(features: &[f64; RENDEZVOUS_FEATURES]) -> Residuals {
        <CartesianState as TargetFeatures<RENDEZVOUS_FEATURES>>::residuals(features)
    }

    /// The body coasted from its state at the epoch (t = 0, anomaly `target_nu0`) every time,
    /// not from the previous cycle's, so no error accumulates over the flight: the ephemeris
    /// the ground environment uses (`ground_core::env::body_at`), bit for bit.
    fn target(scenario: &Scenario, index: u32) -> Result<CartesianState, SilError> {
        let epoch = scenario.target.cartesian_at(scenario.target_nu0);
        coast(&epoch, scenario.cycle_start(index)).map_err(|error| SilError::Target { index, error })
    }
}

impl Problem<TRANSFER3_FEATURES> for Transfer3 {
    const KIND: ProblemKind = ProblemKind::Transfer;
    type Geometry = Spatial;
    type Target = TargetOrbit3;

    fn target(scenario: &SpatialScenario, _index: u32) -> Result<TargetOrbit3, SilError> {
        Ok(TargetOrbit3 {
            shape: scenario.scenario.target,
            plane: scenario.target_plane,
        })
    }

    fn features(
        target: &TargetOrbit3,
        state: &SpatialCraftState,
        time_to_go: f64,
    ) -> Result<[f64; TRANSFER3_FEATURES], FeatureError> {
        target.features(state, time_to_go)
    }

    fn residuals(features: &[f64; TRANSFER3_FEATURES]) -> Residuals {
        TargetOrbit3::residuals(features)
    }
}

impl Problem<RENDEZVOUS3_FEATURES> for Rendezvous3 {
    const KIND: ProblemKind = ProblemKind::Rendezvous;
    type Geometry = Spatial;
    type Target = SpatialState;

    /// The body coasted from its state at the epoch in its plane, every time (the ground
    /// environment's ephemeris, `ground_core::env::body_at3`, bit for bit).
    fn target(scenario: &SpatialScenario, index: u32) -> Result<SpatialState, SilError> {
        let plan = &scenario.scenario;
        let epoch = scenario.target_plane.embed(&plan.target.cartesian_at(plan.target_nu0));
        coast3(&epoch, plan.cycle_start(index)).map_err(|error| SilError::Target { index, error })
    }

    fn features(
        target: &SpatialState,
        state: &SpatialCraftState,
        time_to_go: f64,
    ) -> Result<[f64; RENDEZVOUS3_FEATURES], FeatureError> {
        target.features(state, time_to_go)
    }

    fn residuals(features: &[f64; RENDEZVOUS3_FEATURES]) -> Residuals {
        SpatialState::residuals(features)
    }
}

/// The flight computer's network on `N` features with `OUT` action outputs: the blob's policy,
/// or safe mode when the blob was refused. `Controller<'a>` is the planar transfer controller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Controller<'a, const N: usize = TRANSFER_FEATURES, const OUT: usize = ACTION_LEN> {
    /// The blob loaded: the network flies.
    Network(Policy<'a, N, OUT>),
    /// The blob was refused at load (why is kept): every command is thrust off.
    SafeMode(PolicyError),
}

impl<'a, const N: usize, const OUT: usize> Controller<'a, N, OUT> {
    /// Loads a blob for problem `P`; a blob of another version, problem or shape, truncated or
    /// altered, puts the controller in safe mode instead of flying garbage.
    pub fn load<P: Problem<N>>(blob: &'a [u8]) -> Self {
        match Policy::from_bytes(blob, P::KIND) {
            Ok(policy) => Self::Network(policy),
            Err(error) => Self::SafeMode(error),
        }
    }
}

impl<'a> Controller<'a, TRANSFER_FEATURES> {
    /// Loads a transfer blob, or goes to safe mode (see [`Controller::load`]).
    pub fn load_transfer(blob: &'a [u8]) -> Self {
        Self::load::<Transfer>(blob)
    }
}

impl<'a> Controller<'a, RENDEZVOUS_FEATURES> {
    /// Loads a rendezvous blob, or goes to safe mode (see [`Controller::load`]).
    pub fn load_rendezvous(blob: &'a [u8]) -> Self {
        Self::load::<Rendezvous>(blob)
    }
}

/// Why the flight computer's loader refuses `blob` as a network of `features` (None: it flies),
/// as [`Controller::load`] of that layout's problem decides it.
pub fn load_refusal(blob: &[u8], features: shared::blob::FeatureLayout) -> Option<PolicyError> {
    fn refusal<const N: usize, const OUT: usize>(controller: Controller<'_, N, OUT>) -> Option<PolicyError> {
        match controller {
            Controller::Network(_) => None,
            Controller::SafeMode(e) => Some(e),
        }
    }
    if features.is_spatial() {
        with_spatial_flight_problem!(features.problem(), N, P => refusal(Controller::<N, ACTION3_LEN>::load::<P>(blob)))
    } else {
        with_flight_problem!(features.problem(), N, P => refusal(Controller::<N>::load::<P>(blob)))
    }
}

/// The action that decodes to thrust off (throttle (a0 + 1) / 2 = 0).
pub const THRUST_OFF_ACTION: [f32; 3] = [-1.0, 0.0, 1.0];

/// The action of `OUT` components that decodes to thrust off: throttle -1, the direction along
/// the second (planar: transverse) component.
fn thrust_off_action<const OUT: usize>() -> [f32; OUT] {
    core::array::from_fn(|i| match i {
        0 => -1.0,
        2 => 1.0,
        _ => 0.0,
    })
}

impl<const N: usize, const OUT: usize> Actor<N, OUT> for Controller<'_, N, OUT> {
    fn act(&self, features: &[f32; N]) -> [f32; OUT] {
        match self {
            Self::Network(policy) => policy.forward(features),
            Self::SafeMode(_) => thrust_off_action(),
        }
    }
}

/// One guidance cycle as flown, with the `N` features of its problem, in geometry `G`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightStep<const N: usize = TRANSFER_FEATURES, G: FlightGeometry = Planar> {
    /// Step index k (0-based): the command was computed at t = k * STEP.
    pub index: u32,
    /// What navigation reported at the start of the step (the truth plus navigation error).
    pub navigation: G::State,
    /// Features of the true state at the start of the step (the MDP's observation).
    pub features: [f64; N],
    /// Command of the guidance step (thrust off when guidance refused its input).
    pub command: G::Command,
    /// What the thruster did with it (pointing error, thrust magnitude factor applied to the
    /// throttle); missed-thrust time inside the step is not in here, see `missed_thrust`.
    pub applied: G::Command,
    /// Canonical time of the step spent in missed-thrust events.
    pub missed_thrust: f64,
    /// Why guidance produced no command, if it did not.
    pub guidance_error: Option<GuidanceError>,
    /// True state at the end of the step.
    pub state: G::State,
    /// Reward at the end of the step (docs/spec.md section 5, printed reward).
    pub reward: f64,
    /// Residuals of the true state against the target at the end of the step.
    pub residuals: Residuals,
}

/// What a flight ended with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightSummary<G: FlightGeometry = Planar> {
    /// Guidance cycles flown.
    pub steps: u32,
    /// Sum of the cycles' rewards (docs/spec.md section 5).
    pub total_reward: f64,
    /// True state after the last cycle.
    pub final_state: G::State,
    /// Residuals at the end (none for a flight of zero steps).
    pub final_residuals: Option<Residuals>,
    /// Cycles in which guidance refused its input and commanded thrust off.
    pub guidance_faults: u32,
}

/// Why a flight could not be flown.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SilError {
    /// The scenario cannot be flown (see [`Scenario::validate`]).
    Scenario(ScenarioError),
    /// The dispersions are not finite or out of range.
    Dispersion(DispersionError),
    /// The setup's time unit (s) is not finite and positive.
    TimeUnit(f64),
    /// The scenario poses another problem than the loop flies.
    WrongProblem {
        /// The problem of the loop.
        expected: ProblemKind,
        /// The scenario's.
        found: ProblemKind,
    },
    /// The rendezvous body could not be propagated to step `index`.
    Target {
        /// The guidance cycle.
        index: u32,
        /// Why the Kepler coast failed.
        error: KeplerError,
    },
    /// The plant could not be propagated (for example the tank ran dry) at step `index`.
    Plant {
        /// The guidance cycle.
        index: u32,
        /// Why the propagation failed.
        error: PropagationError,
    },
    /// The true state left the feature domain (for example r = 0) at step `index`.
    Features {
        /// The guidance cycle.
        index: u32,
        /// Why the features could not be computed.
        error: FeatureError,
    },
}

impl core::fmt::Display for SilError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Scenario(e) => write!(f, "invalid scenario: {e}"),
            Self::Dispersion(e) => write!(f, "invalid dispersions: {e}"),
            Self::TimeUnit(s) => write!(f, "the time unit must be finite and > 0 s, got {}", Decimal6(*s)),
            Self::WrongProblem { expected, found } => {
                write!(f, "a {found:?} scenario given to the {expected:?} loop")
            }
            Self::Target { index, error } => write!(f, "target body unusable at step {index}: {error}"),
            Self::Plant { index, error } => write!(f, "plant propagation failed at step {index}: {error}"),
            Self::Features { index, error } => write!(f, "plant state unusable at step {index}: {error}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for SilError {}

/// What a flight is flown with beside its scenario and guidance, the same for every flight of a
/// Monte Carlo: the spacecraft as designed, the plant's integration tolerances, the reward
/// weights the MDP scores a cycle with, and the real world's dispersions (each flight draws its
/// own from its seed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightSetup {
    /// The spacecraft as designed (the plant's thrust is dispersed from it).
    pub spacecraft: CanonicalSpacecraft,
    /// Tolerances of the plant's propagation.
    pub tolerances: Tolerances,
    /// Weights of the reward reported for each cycle (docs/spec.md section 5).
    pub weights: RewardWeights,
    /// The dispersions of the truth plant ([`Dispersions::NONE`]: the nominal plant).
    pub dispersions: Dispersions,
    /// The family's time unit, s (the Sun's by default): the missed-thrust events, given in
    /// days, are timed in it.
    pub time_unit_s: f64,
}

impl FlightSetup {
    /// The nominal plant for `spacecraft`: default tolerances and reward weights, no dispersions.
    pub fn nominal(spacecraft: CanonicalSpacecraft) -> Self {
        Self {
            spacecraft,
            tolerances: Tolerances::default(),
            weights: RewardWeights::default(),
            dispersions: Dispersions::NONE,
            time_unit_s: shared::units::TIME_UNIT_S,
        }
    }

    /// The same setup with other dispersions.
    pub fn dispersed(self, dispersions: Dispersions) -> Self {
        Self { dispersions, ..self }
    }
}

/// Flies `scenario` closed loop as problem `P` and reports every cycle to `observer`: at each
/// cycle the guidance step computes a command from the navigation state and the target at that
/// time, the truth plant of `setup` flies it (its dispersions drawn from `seed`) to the next
/// cycle. In the plane the command is polar; in three dimensions (docs/spec.md section 6.1) the
/// network commands throttle and an RTN direction, held by the RTN propagator. No allocation.
pub fn fly_observed<const N: usize, P, A, O>(
    _problem: P,
    guide: &A,
    scenario: &ScenarioOf<P, N>,
    setup: &FlightSetup,
    seed: u64,
    observer: O,
) -> Result<FlightSummary<P::Geometry>, SilError>
where
    P: Problem<N>,
    A: Guide<N, P::Target, P::Geometry>,
    O: FnMut(&FlightStep<N, P::Geometry>),
{
    fly_loop::<N, P, _, _>(
        scenario,
        setup,
        seed,
        |navigation, target, time_to_go| guide.command(navigation, target, time_to_go),
        observer,
    )
}

/// The guidance loop of every problem and geometry: `guidance` gives each cycle's command from
/// the navigation state, the target and the time to go.
fn fly_loop<const N: usize, P, G, O>(
    scenario: &ScenarioOf<P, N>,
    setup: &FlightSetup,
    seed: u64,
    guidance: G,
    mut observer: O,
) -> Result<FlightSummary<P::Geometry>, SilError>
where
    P: Problem<N>,
    G: Fn(&StateOf<P, N>, &P::Target, f64) -> Result<CommandOf<P, N>, GuidanceError>,
    O: FnMut(&FlightStep<N, P::Geometry>),
{
    let FlightSetup {
        spacecraft,
        tolerances,
        weights,
        dispersions,
        time_unit_s,
    } = setup;
    P::Geometry::validate(scenario).map_err(SilError::Scenario)?;
    let plan = P::Geometry::plan(scenario);
    dispersions.validate().map_err(SilError::Dispersion)?;
    if !(time_unit_s.is_finite() && *time_unit_s > 0.0) {
        return Err(SilError::TimeUnit(*time_unit_s));
    }
    if plan.problem != P::KIND {
        return Err(SilError::WrongProblem {
            expected: P::KIND,
            found: plan.problem,
        });
    }
    let mut plant = DispersedPlant::new(dispersions, *time_unit_s, seed);
    let actual = CanonicalSpacecraft {
        thrust: spacecraft.thrust * plant.thrust_factor(),
        ..*spacecraft
    };
    let mut state = P::Geometry::departure(scenario);
    let mut summary = FlightSummary {
        steps: 0,
        total_reward: 0.0,
        final_state: state,
        final_residuals: None,
        guidance_faults: 0,
    };
    // The target at the start of the cycle; the end of one cycle is the start of the next.
    let mut target = P::target(scenario, 0)?;
    for index in 0..plan.steps {
        let time_to_go = plan.time_to_go(index);
        let features = P::features(&target, &state, time_to_go).map_err(|error| SilError::Features { index, error })?;
        let navigation = P::Geometry::navigate(&mut plant, &state);
        let (command, guidance_error) = match guidance(&navigation, &target, time_to_go) {
            Ok(c) => (c, None),
            Err(e) => (P::Geometry::OFF, Some(e)),
        };
        let cycle = plant_cycle::<P::Geometry>(&mut plant, &state, &command, &actual, plan, index, tolerances)
            .map_err(|error| SilError::Plant { index, error })?;
        let (applied, missed_thrust) = (cycle.applied, cycle.missed_thrust);
        state = cycle.state;
        // The end of the cycle as the MDP sees step index + 1 (its time to go, its target).
        target = P::target(scenario, index + 1)?;
        let after = P::features(&target, &state, plan.time_to_go(index + 1))
            .map_err(|error| SilError::Features { index, error })?;
        let residuals = P::residuals(&after);
        // The reward charges the commanded throttle, as the MDP does.
        let step = FlightStep {
            index,
            navigation,
            features,
            command,
            applied,
            missed_thrust,
            guidance_error,
            state,
            reward: reward(&residuals, P::Geometry::throttle(&command), weights),
            residuals,
        };
        summary.steps += 1;
        summary.total_reward += step.reward;
        summary.final_state = state;
        summary.final_residuals = Some(residuals);
        summary.guidance_faults += u32::from(guidance_error.is_some());
        observer(&step);
    }
    Ok(summary)
}

/// What one guidance cycle of the truth plant did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlantCycle<G: Dimension> {
    /// The true state at the cycle's end.
    pub state: G::State,
    /// The command as the thruster followed it: pointing error and thrust factor applied.
    pub applied: G::Command,
    /// Canonical time of the cycle spent in missed-thrust events.
    pub missed_thrust: f64,
}

/// One guidance cycle (`index` of `plan`) of the truth plant: `command` turned by the plant's
/// pointing error and flown by `actual` (the spacecraft with the flight's thrust factor) from
/// the true `state`, segment by segment, thrust off inside a missed-thrust event. The plant's
/// draws are consumed as the guidance loop consumes them, so a plant cloned at the cycle's
/// start flies the same cycle again from any state and command (the ground differentiates
/// dispersed flights so).
pub fn plant_cycle<G: FlightGeometry>(
    plant: &mut DispersedPlant,
    state: &G::State,
    command: &G::Command,
    actual: &CanonicalSpacecraft,
    plan: &Scenario,
    index: u32,
    tolerances: &Tolerances,
) -> Result<PlantCycle<G>, PropagationError> {
    let pointed = G::point(plant, command);
    let applied = G::with_throttle(&pointed, G::throttle(&pointed) * plant.thrust_factor());
    let (cycle_start, cycle) = (plan.cycle_start(index), plan.cycle);
    let (mut state, mut tau, mut missed_thrust) = (*state, 0.0, 0.0);
    while tau < cycle {
        let (end, thrust_on) = plant.segment(cycle_start, tau, cycle);
        let flown = if thrust_on { pointed } else { G::OFF };
        state = G::propagate(&state, &flown, actual, end - tau, tolerances)?;
        if !thrust_on {
            missed_thrust += end - tau;
        }
        tau = end;
    }
    Ok(PlantCycle {
        state,
        applied,
        missed_thrust,
    })
}

/// A recorded closed-loop flight.
#[cfg(feature = "std")]
#[derive(Debug, Clone, PartialEq)]
pub struct Flight<const N: usize = TRANSFER_FEATURES, G: FlightGeometry = Planar> {
    /// The state at departure (m = 1).
    pub initial: G::State,
    /// Every guidance cycle, in order.
    pub steps: Vec<FlightStep<N, G>>,
    /// What the flight ended with.
    pub summary: FlightSummary<G>,
}

#[cfg(feature = "std")]
impl<const N: usize, G: FlightGeometry> Flight<N, G> {
    /// Sum of the cycles' rewards.
    pub fn total_reward(&self) -> f64 {
        self.summary.total_reward
    }

    /// True state after the last cycle.
    pub fn final_state(&self) -> G::State {
        self.summary.final_state
    }

    /// Residuals at the end (none for a flight of zero steps).
    pub fn final_residuals(&self) -> Option<Residuals> {
        self.summary.final_residuals
    }
}

/// Flies `scenario` as problem `P` and records every cycle (see [`fly_observed`]).
#[cfg(feature = "std")]
pub fn fly<const N: usize, P: Problem<N>, A: Guide<N, P::Target, P::Geometry>>(
    problem: P,
    guide: &A,
    scenario: &ScenarioOf<P, N>,
    setup: &FlightSetup,
    seed: u64,
) -> Result<Flight<N, P::Geometry>, SilError> {
    let mut steps = Vec::with_capacity(P::Geometry::plan(scenario).steps as usize);
    let summary = fly_observed(problem, guide, scenario, setup, seed, |s| steps.push(*s))?;
    Ok(Flight {
        initial: P::Geometry::departure(scenario),
        steps,
        summary,
    })
}

/// A hand-tuned feedback law for demonstrations and as a baseline for learned policies: thrust
/// along the velocity error to the target-orbit proxy, plus corrections for the radius and
/// semi-major-axis gaps, throttled up with the total error above a dead band. It reads only the
/// features, so it flies through exactly the same guidance path as a network. Far from optimal
/// in propellant: it is what a learned policy must beat.
#[derive(Debug, Clone, Copy)]
pub struct ProxyTracking {
    /// Semi-major axis of the target orbit (AU).
    pub target_a: f64,
}

impl Actor<TRANSFER_FEATURES> for ProxyTracking {
    fn act(&self, f: &[f32; TRANSFER_FEATURES]) -> [f32; 3] {
        let [r, _, _, v_r, v_theta, _, r_t, v_r_t, v_theta_t, _] = f.map(f64::from);
        let a = 1.0 / (2.0 / r - (v_r * v_r + v_theta * v_theta));
        let gap = if a > 0.0 { self.target_a - a } else { self.target_a };
        let error = gap.abs() + (r_t - r).abs() + libm::hypot(v_r_t - v_r, v_theta_t - v_theta);
        let throttle = ((error - 0.02) / 0.2).clamp(0.0, 1.0);
        let (radial, along) = (v_r_t - v_r + 0.5 * (r_t - r), v_theta_t - v_theta + 0.5 * gap);
        let norm = libm::hypot(radial, along).max(1e-9);
        [
            (2.0 * throttle - 1.0) as f32,
            (radial / norm) as f32,
            (along / norm) as f32,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use onboard::dynamics::propagate;
    use onboard::kepler::coast;
    use shared::orbit::{OrbitElements, OrbitShape};
    use shared::spacecraft::Spacecraft;
    use shared::units::STEP;

    fn scenario(target_a: f64) -> Scenario {
        let initial = OrbitElements {
            shape: OrbitShape {
                a: 1.0,
                e: 0.0,
                omega: 0.0,
            },
            nu: 0.3,
        };
        let target = OrbitShape {
            a: target_a,
            e: 0.0,
            omega: 0.0,
        };
        Scenario::transfer(initial, target)
    }

    struct Off;
    impl Actor<TRANSFER_FEATURES> for Off {
        fn act(&self, _: &[f32; TRANSFER_FEATURES]) -> [f32; 3] {
            [-1.0, 0.0, 1.0]
        }
    }

    #[test]
    fn a_coasting_flight_is_one_kepler_arc_and_keeps_its_mass() {
        let s = scenario(1.52);
        let flight = fly(&Off, &s, &Dispersions::NONE, 0);
        let end = flight.final_state();
        let direct = coast(&s.initial.cartesian(), s.time_of_flight()).unwrap();
        for (a, b) in end.r.iter().chain(&end.v).zip(direct.r.iter().chain(&direct.v)) {
            assert!((a - b).abs() < 1e-11);
        }
        assert_eq!(end.m, 1.0);
        // Circular 1 AU vs 1.52 AU: dr = 0.52, dv = 1 - 1/sqrt(1.52) each step.
        let dv = 1.0 - 1.0 / 1.52f64.sqrt();
        let per_step = (-0.2 * 0.52f64 * 0.52).exp_m1() + (-0.2 * dv * dv).exp_m1();
        assert!((flight.total_reward() - per_step * f64::from(s.steps)).abs() < 1e-8);
    }

    #[test]
    fn proxy_tracking_reaches_the_target_and_burns_mass_at_the_rocket_equation_rate() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let s = scenario(1.52);
        let law = ProxyTracking { target_a: 1.52 };
        let flight = fly(&law, &s, &Dispersions::NONE, 0);
        let throttle_steps: f64 = flight.steps.iter().map(|k| k.command.throttle).sum();
        assert!(throttle_steps > 0.0);
        let expected_mass = 1.0 - sc.thrust * throttle_steps * STEP / sc.exhaust_speed;
        assert!((flight.final_state().m - expected_mass).abs() < 1e-12);
        // Coasting steps conserve energy; the flight ends near the target orbit.
        let mut energy = flight.initial.cartesian().energy();
        for k in &flight.steps {
            let e = k.state.cartesian().energy();
            if k.command.throttle == 0.0 {
                assert!((e - energy).abs() < 1e-12);
            }
            energy = e;
        }
        let res = flight.final_residuals().unwrap();
        assert!(res.position < 0.02 && res.velocity < 0.02, "{res:?}");
        // It must beat not thrusting at all, by the spec's reward.
        let off = fly(&Off, &s, &Dispersions::NONE, 0);
        assert!(flight.total_reward() > off.total_reward());
    }

    fn fly(law: &impl Actor<TRANSFER_FEATURES>, s: &Scenario, d: &Dispersions, seed: u64) -> Flight {
        super::fly(Transfer, law, s, &setup(*d), seed).unwrap()
    }

    /// The thesis spacecraft with default tolerances and weights, flown with `dispersions`.
    fn setup(dispersions: Dispersions) -> FlightSetup {
        FlightSetup::nominal(Spacecraft::MSR_ERO.canonical().unwrap()).dispersed(dispersions)
    }

    /// The transfer of `scenario(target_a)` as a rendezvous with a body at `nu0` at t = 0.
    fn rendezvous(target_a: f64, nu0: f64) -> Scenario {
        Scenario {
            problem: ProblemKind::Rendezvous,
            target_nu0: nu0,
            ..scenario(target_a)
        }
    }

    fn fly_rdv(
        law: &impl Actor<RENDEZVOUS_FEATURES>,
        s: &Scenario,
        d: &Dispersions,
        seed: u64,
    ) -> Flight<RENDEZVOUS_FEATURES> {
        super::fly(Rendezvous, law, s, &setup(*d), seed).unwrap()
    }

    /// Half throttle along-track whatever the features: the same commands for either problem.
    struct Half;
    impl<const N: usize> Actor<N> for Half {
        fn act(&self, _: &[f32; N]) -> [f32; 3] {
            [0.0, 0.0, 1.0]
        }
    }

    #[test]
    fn a_rendezvous_sees_the_body_coasted_from_its_epoch_each_cycle() {
        let s = rendezvous(1.52, 1.2);
        let flight = fly_rdv(&Half, &s, &Dispersions::NONE, 0);
        assert_eq!(flight.steps.len(), s.steps as usize);
        let epoch = s.target.cartesian_at(s.target_nu0);
        let body = |k: u32| coast(&epoch, f64::from(k) * STEP).unwrap();
        for k in &flight.steps {
            // Features 10..14: the body's x, y, vx, vy, as guidance was given them.
            let b = body(k.index);
            assert_eq!(k.features[10..14], [b.r[0], b.r[1], b.v[0], b.v[1]], "step {}", k.index);
            assert_eq!(k.features[20], f64::from(s.steps - k.index) * STEP);
            // Residuals against the body at the end of the cycle.
            let b = body(k.index + 1);
            let (dr, dv) = (
                libm::hypot(b.r[0] - k.state.r[0], b.r[1] - k.state.r[1]),
                libm::hypot(b.v[0] - k.state.v[0], b.v[1] - k.state.v[1]),
            );
            assert_eq!(
                (k.residuals.position, k.residuals.velocity),
                (dr, dv),
                "step {}",
                k.index
            );
            let w = RewardWeights::default();
            assert_eq!(k.reward, reward(&k.residuals, 0.5, &w));
        }
        // Coasting, the spacecraft flies one Kepler arc and keeps its mass, as in a transfer.
        let coasting = fly_rdv(&THRUST_OFF, &s, &Dispersions::NONE, 0);
        let end = coasting.final_state();
        let direct = coast(&s.initial.cartesian(), s.time_of_flight()).unwrap();
        for (a, b) in end.r.iter().chain(&end.v).zip(direct.r.iter().chain(&direct.v)) {
            assert!((a - b).abs() < 1e-11);
        }
        assert_eq!(end.m, 1.0);
    }

    /// Thrust off whatever the features.
    const THRUST_OFF: Constant = Constant(THRUST_OFF_ACTION);
    struct Constant([f32; 3]);
    impl<const N: usize> Actor<N> for Constant {
        fn act(&self, _: &[f32; N]) -> [f32; 3] {
            self.0
        }
    }

    #[test]
    fn dispersions_act_on_a_rendezvous_exactly_as_on_a_transfer() {
        // The same commands from the same start meet the same plant: every draw (navigation,
        // thrust magnitude, pointing, missed thrust) comes from the seed alone, not the problem.
        let (t, r) = (scenario(1.52), rendezvous(1.52, 2.0));
        for (d, seed) in [(Dispersions::TYPICAL, 7), (Dispersions::NONE, 0)] {
            let a = fly(&Half, &t, &d, seed);
            let b = fly_rdv(&Half, &r, &d, seed);
            assert_eq!(a.steps.len(), b.steps.len());
            for (x, y) in a.steps.iter().zip(&b.steps) {
                assert_eq!(
                    (x.navigation, x.command, x.applied, x.missed_thrust, x.state),
                    (y.navigation, y.command, y.applied, y.missed_thrust, y.state),
                    "step {}",
                    x.index
                );
            }
            // Only the target differs: the body is not where the transfer's proxy is.
            assert_ne!(a.total_reward(), b.total_reward());
        }
        let d = Dispersions::TYPICAL;
        let flight = fly_rdv(&Half, &r, &d, 7);
        assert!(flight.steps.iter().any(|k| k.missed_thrust > 0.0));
        assert!(flight.steps.iter().all(|k| k.navigation != k.state));
    }

    #[test]
    fn a_refused_rendezvous_blob_flies_thrust_off_and_the_wrong_problem_is_refused() {
        let r = rendezvous(1.52, 1.0);
        let controller = Controller::load_rendezvous(&[0u8; 64]);
        assert!(matches!(controller, Controller::SafeMode(_)));
        let flight = fly_rdv(&controller, &r, &Dispersions::TYPICAL, 1);
        assert_eq!(flight.steps.len(), r.steps as usize);
        assert!(flight
            .steps
            .iter()
            .all(|k| k.command.throttle == 0.0 && k.applied.throttle == 0.0));
        assert_eq!(flight.final_state().m, 1.0);
        let t = scenario(1.52);
        let nominal = setup(Dispersions::NONE);
        assert_eq!(
            super::fly(Rendezvous, &controller, &t, &nominal, 1),
            Err(SilError::WrongProblem {
                expected: ProblemKind::Rendezvous,
                found: ProblemKind::Transfer
            })
        );
        assert_eq!(
            super::fly(Transfer, &Half, &r, &nominal, 1),
            Err(SilError::WrongProblem {
                expected: ProblemKind::Transfer,
                found: ProblemKind::Rendezvous
            })
        );
        let bad = Dispersions {
            pointing: f64::NAN,
            ..Dispersions::NONE
        };
        assert_eq!(
            super::fly(Rendezvous, &controller, &r, &setup(bad), 1),
            Err(SilError::Dispersion(DispersionError))
        );
        let nowhere = Scenario {
            target_nu0: f64::NAN,
            ..r
        };
        assert!(matches!(
            super::fly(Rendezvous, &controller, &nowhere, &nominal, 1),
            Err(SilError::Scenario(_))
        ));
    }

    #[test]
    fn without_dispersions_each_step_is_one_onboard_propagation_of_the_command() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let s = scenario(1.3);
        let law = ProxyTracking { target_a: 1.3 };
        let flight = fly(&law, &s, &Dispersions::NONE, 9);
        let mut state = flight.initial;
        for k in &flight.steps {
            assert_eq!(k.navigation, state);
            assert_eq!(k.applied, k.command);
            assert_eq!(k.missed_thrust, 0.0);
            state = propagate(&state, &k.command, &sc, STEP, &Tolerances::default()).unwrap();
            assert_eq!(k.state, state, "step {}", k.index);
        }
    }

    #[test]
    fn missed_thrust_inside_cycles_burns_only_the_time_thrust_was_on() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let s = scenario(1.52);
        let law = ProxyTracking { target_a: 1.52 };
        let d = Dispersions {
            missed_thrust_per_year: 6.0,
            missed_thrust_days: 9.0,
            ..Dispersions::NONE
        };
        let flight = fly(&law, &s, &d, 4);
        let missed: f64 = flight.steps.iter().map(|k| k.missed_thrust).sum();
        let nine_days = 9.0 * 86_400.0 / shared::units::TIME_UNIT_S;
        // Events happened, some straddle a cycle boundary (neither 0 nor a whole event).
        assert!(missed > nine_days, "{missed}");
        assert!(flight
            .steps
            .iter()
            .any(|k| k.missed_thrust > 0.0 && (k.missed_thrust - nine_days).abs() > 1e-9));
        // Mass: the rocket equation over the time thrust was really on.
        let mut m = 1.0;
        for k in &flight.steps {
            m -= sc.thrust * k.command.throttle * (STEP - k.missed_thrust) / sc.exhaust_speed;
            assert!((k.state.m - m).abs() < 1e-12, "step {}", k.index);
        }
    }

    #[test]
    fn thrust_magnitude_error_scales_the_mass_flow_for_the_whole_flight() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let s = scenario(1.52);
        let law = ProxyTracking { target_a: 1.52 };
        let d = Dispersions {
            thrust_magnitude: 0.05,
            ..Dispersions::NONE
        };
        let flight = fly(&law, &s, &d, 11);
        let factor = DispersedPlant::new(&d, shared::units::TIME_UNIT_S, 11).thrust_factor();
        assert!(factor != 1.0 && (factor - 1.0).abs() < 0.25, "{factor}");
        let throttle_time: f64 = flight.steps.iter().map(|k| k.command.throttle * STEP).sum();
        let expected = 1.0 - sc.thrust * factor * throttle_time / sc.exhaust_speed;
        assert!((flight.final_state().m - expected).abs() < 1e-12);
        for k in &flight.steps {
            assert!((k.applied.throttle - k.command.throttle * factor).abs() < 1e-15);
        }
    }

    #[test]
    fn navigation_and_pointing_errors_have_the_sizes_asked_for() {
        let s = scenario(1.52);
        let law = ProxyTracking { target_a: 1.52 };
        let d = Dispersions {
            navigation_position: 1e-3,
            navigation_velocity: 2e-3,
            pointing: 0.05,
            ..Dispersions::NONE
        };
        let (mut dr, mut dv, mut angle, mut n, mut burns) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for seed in 0..40 {
            let flight = fly(&law, &s, &d, seed);
            let mut truth = flight.initial;
            for k in &flight.steps {
                for i in 0..2 {
                    dr += (k.navigation.r[i] - truth.r[i]).powi(2);
                    dv += (k.navigation.v[i] - truth.v[i]).powi(2);
                }
                n += 2.0;
                if k.command.throttle > 0.0 {
                    let (c, a) = (k.command, k.applied);
                    assert!((a.alpha_r.hypot(a.alpha_theta) - 1.0).abs() < 1e-12);
                    let turn = (c.alpha_r * a.alpha_theta - c.alpha_theta * a.alpha_r)
                        .atan2(c.alpha_r * a.alpha_r + c.alpha_theta * a.alpha_theta);
                    angle += turn * turn;
                    burns += 1.0;
                }
                truth = k.state;
            }
        }
        // Sample standard deviations within 10 % of the sigmas (thousands of draws each).
        assert!(((dr / n).sqrt() / 1e-3 - 1.0).abs() < 0.1, "{}", (dr / n).sqrt());
        assert!(((dv / n).sqrt() / 2e-3 - 1.0).abs() < 0.1, "{}", (dv / n).sqrt());
        assert!(burns > 300.0);
        assert!(
            ((angle / burns).sqrt() / 0.05 - 1.0).abs() < 0.1,
            "{}",
            (angle / burns).sqrt()
        );
    }

    #[test]
    fn a_refused_blob_flies_thrust_off_and_bad_dispersions_are_refused() {
        let s = scenario(1.52);
        let controller = Controller::load_transfer(&[0u8; 64]);
        assert!(matches!(controller, Controller::SafeMode(_)));
        let flight = fly(&controller, &s, &Dispersions::TYPICAL, 1);
        assert!(flight.steps.iter().all(|k| k.command.throttle == 0.0));
        assert_eq!(flight.final_state().m, 1.0);
        let bad = Dispersions {
            pointing: f64::NAN,
            ..Dispersions::NONE
        };
        assert_eq!(
            super::fly(Transfer, &controller, &s, &setup(bad), 1),
            Err(SilError::Dispersion(DispersionError))
        );
    }
}
