//! The dimension a flight is flown in: [`Planar`] (polar commands held in the orbit plane) or
//! [`Spatial`] (RTN commands in three dimensions). What the ground environments and the
//! software-in-the-loop flight both need of a dimension is here, once: its scenario, state and
//! command, the departure, and the propagation of a held command.

use shared::scenario::{Scenario, ScenarioError, SpatialScenario};
use shared::spacecraft::CanonicalSpacecraft;

use crate::dynamics::{propagate, PropagationError, SpacecraftState, ThrustCommand};
use crate::integrator::Tolerances;
use crate::spatial::{propagate_rtn, RtnCommand, SpatialCraftState};

/// A dimension of flight: its scenario, state and command, and how a command is flown.
pub trait Dimension: Copy + core::fmt::Debug + PartialEq + Send + Sync + 'static {
    /// What one flight flies.
    type Scenario: Copy + core::fmt::Debug + PartialEq + Send + Sync + 'static;
    /// The spacecraft's state.
    type State: Copy + core::fmt::Debug + PartialEq + Send + Sync + 'static;
    /// A thrust command held over one guidance cycle.
    type Command: Copy + core::fmt::Debug + PartialEq + Send + Sync + 'static;
    /// Thrust off.
    const OFF: Self::Command;

    /// The scenario's planar part: problem, cycles, cycle length, target shape and anomaly
    /// (every figure measured in its own orbit's plane).
    fn plan(scenario: &Self::Scenario) -> &Scenario;
    /// Checks every figure of the scenario.
    fn validate(scenario: &Self::Scenario) -> Result<(), ScenarioError>;
    /// The spacecraft at departure (mass 1).
    fn departure(scenario: &Self::Scenario) -> Self::State;
    /// The state's mass (m0 units).
    fn mass(state: &Self::State) -> f64;
    /// The periapsis radius of the state's osculating orbit (canonical units, mu = 1; 0 for a
    /// radial orbit, NaN for a non-finite state): the shortest dynamical time ahead, which
    /// sizes the onboard aids' fixed rollout steps.
    fn periapsis(state: &Self::State) -> f64;
    /// The command's throttle in [0, 1].
    fn throttle(command: &Self::Command) -> f64;
    /// The command with another throttle.
    fn with_throttle(command: &Self::Command, throttle: f64) -> Self::Command;
    /// Components of a thrust vector (throttle times unit direction, in the local frame): 2
    /// (radial, transverse) in the plane, 3 (radial, transverse, normal) in three dimensions.
    const THRUST_AXES: usize;
    /// The command as a thrust vector; components past [`Self::THRUST_AXES`] are 0.
    fn thrust_vector(command: &Self::Command) -> [f64; 3];
    /// The length of a thrust vector (its throttle).
    fn thrust_norm(tau: &[f64; 3]) -> f64;
    /// The command of a thrust vector: throttle its length (at most 1), along it; thrust off
    /// for a vector shorter than 1e-12 or not a number.
    fn command_of(tau: &[f64; 3]) -> Self::Command;
    /// The command's unit direction in the local frame (radial, transverse, normal; the normal
    /// 0 in the plane), as it holds it: for thrust off, the direction it would thrust along.
    fn direction(command: &Self::Command) -> [f64; 3];
    /// The command of `throttle` along the unit `direction` (local frame; components past
    /// [`Self::THRUST_AXES`] ignored), taken as given.
    fn command_along(throttle: f64, direction: &[f64; 3]) -> Self::Command;
    /// `state` propagated for `duration` under `command` (the onboard propagator).
    fn propagate(
        state: &Self::State,
        command: &Self::Command,
        spacecraft: &CanonicalSpacecraft,
        duration: f64,
        tolerances: &Tolerances,
    ) -> Result<Self::State, PropagationError>;
}

/// In the reference plane: polar commands ([`ThrustCommand`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Planar;

/// In three dimensions: RTN commands ([`RtnCommand`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Spatial;

impl Dimension for Planar {
    type Scenario = Scenario;
    type State = SpacecraftState;
    type Command = ThrustCommand;
    const OFF: ThrustCommand = ThrustCommand::OFF;

    fn plan(scenario: &Scenario) -> &Scenario {
        scenario
    }

    fn validate(scenario: &Scenario) -> Result<(), ScenarioError> {
        scenario.validate()
    }

    fn departure(scenario: &Scenario) -> SpacecraftState {
        SpacecraftState::from_cartesian(&scenario.initial.cartesian(), 1.0)
    }

    fn mass(state: &SpacecraftState) -> f64 {
        state.m
    }

    fn periapsis(state: &SpacecraftState) -> f64 {
        let ([x, y], [vx, vy]) = (state.r, state.v);
        periapsis_of(libm::hypot(x, y), vx * vx + vy * vy, x * vy - y * vx)
    }

    fn throttle(command: &ThrustCommand) -> f64 {
        command.throttle
    }

    fn with_throttle(command: &ThrustCommand, throttle: f64) -> ThrustCommand {
        ThrustCommand { throttle, ..*command }
    }

    const THRUST_AXES: usize = 2;

    fn thrust_vector(command: &ThrustCommand) -> [f64; 3] {
        [
            command.throttle * command.alpha_r,
            command.throttle * command.alpha_theta,
            0.0,
        ]
    }

    fn thrust_norm(tau: &[f64; 3]) -> f64 {
        libm::hypot(tau[0], tau[1])
    }

    fn command_of(tau: &[f64; 3]) -> ThrustCommand {
        let norm = Self::thrust_norm(tau);
        if norm.is_nan() || norm <= 1e-12 {
            return ThrustCommand::OFF;
        }
        ThrustCommand {
            throttle: norm.min(1.0),
            alpha_r: tau[0] / norm,
            alpha_theta: tau[1] / norm,
        }
    }

    fn direction(command: &ThrustCommand) -> [f64; 3] {
        [command.alpha_r, command.alpha_theta, 0.0]
    }

    fn command_along(throttle: f64, direction: &[f64; 3]) -> ThrustCommand {
        ThrustCommand {
            throttle,
            alpha_r: direction[0],
            alpha_theta: direction[1],
        }
    }

    fn propagate(
        state: &SpacecraftState,
        command: &ThrustCommand,
        spacecraft: &CanonicalSpacecraft,
        duration: f64,
        tolerances: &Tolerances,
    ) -> Result<SpacecraftState, PropagationError> {
        propagate(state, command, spacecraft, duration, tolerances)
    }
}

impl Dimension for Spatial {
    type Scenario = SpatialScenario;
    type State = SpatialCraftState;
    type Command = RtnCommand;
    const OFF: RtnCommand = RtnCommand::OFF;

    fn plan(scenario: &SpatialScenario) -> &Scenario {
        &scenario.scenario
    }

    fn validate(scenario: &SpatialScenario) -> Result<(), ScenarioError> {
        scenario.validate()
    }

    fn departure(scenario: &SpatialScenario) -> SpatialCraftState {
        SpatialCraftState {
            orbit: scenario.departure(),
            m: 1.0,
        }
    }

    fn mass(state: &SpatialCraftState) -> f64 {
        state.m
    }

    fn periapsis(state: &SpatialCraftState) -> f64 {
        let (r, v) = (state.orbit.r, state.orbit.v);
        let h = [
            r[1] * v[2] - r[2] * v[1],
            r[2] * v[0] - r[0] * v[2],
            r[0] * v[1] - r[1] * v[0],
        ];
        let norm = |a: [f64; 3]| libm::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        periapsis_of(norm(r), v[0] * v[0] + v[1] * v[1] + v[2] * v[2], norm(h))
    }

    fn throttle(command: &RtnCommand) -> f64 {
        command.throttle
    }

    fn with_throttle(command: &RtnCommand, throttle: f64) -> RtnCommand {
        RtnCommand { throttle, ..*command }
    }

    const THRUST_AXES: usize = 3;

    fn thrust_vector(command: &RtnCommand) -> [f64; 3] {
        let u = command.throttle;
        [u * command.radial, u * command.transverse, u * command.normal]
    }

    fn thrust_norm(tau: &[f64; 3]) -> f64 {
        libm::hypot(libm::hypot(tau[0], tau[1]), tau[2])
    }

    fn command_of(tau: &[f64; 3]) -> RtnCommand {
        let norm = Self::thrust_norm(tau);
        if norm.is_nan() || norm <= 1e-12 {
            return RtnCommand::OFF;
        }
        RtnCommand {
            throttle: norm.min(1.0),
            radial: tau[0] / norm,
            transverse: tau[1] / norm,
            normal: tau[2] / norm,
        }
    }

    fn direction(command: &RtnCommand) -> [f64; 3] {
        [command.radial, command.transverse, command.normal]
    }

    fn command_along(throttle: f64, direction: &[f64; 3]) -> RtnCommand {
        RtnCommand {
            throttle,
            radial: direction[0],
            transverse: direction[1],
            normal: direction[2],
        }
    }

    fn propagate(
        state: &SpatialCraftState,
        command: &RtnCommand,
        spacecraft: &CanonicalSpacecraft,
        duration: f64,
        tolerances: &Tolerances,
    ) -> Result<SpatialCraftState, PropagationError> {
        propagate_rtn(state, command, spacecraft, duration, tolerances)
    }
}

/// The periapsis radius `h^2 / (1 + e)` of the orbit through radius `r` at speed squared `v2`
/// with angular momentum `h` (mu = 1), `e = sqrt(1 + 2 E h^2)` from the energy
/// `E = v2 / 2 - 1 / r`: valid for every conic.
fn periapsis_of(r: f64, v2: f64, h: f64) -> f64 {
    let energy = 0.5 * v2 - 1.0 / r;
    let e = libm::sqrt((1.0 + 2.0 * energy * h * h).max(0.0));
    h * h / (1.0 + e)
}
