//! The geometry an MDP flies in: [`Planar`] (docs/spec.md sections 3 to 6: the polar hold, 3
//! action components) or [`Spatial`] (sections 3.6, 5.1, 6.1: the RTN hold, 4 action
//! components). Everything the environments and the Monte Carlo drivers do that depends on
//! the dimension is here, once: what a scenario and a family are, the departure state, how an
//! action decodes and how a step is propagated. The problems ([`super::Problem`]) add their
//! features on top.

use onboard::dynamics::{propagate, PropagationError, SpacecraftState, ThrustCommand};
use onboard::features::{decode_action, decode_action3, ACTION3_LEN, ACTION_LEN};
use onboard::integrator::Tolerances;
use onboard::spatial::{propagate_rtn, RtnCommand, SpatialCraftState};

use crate::generate::DatasetFamily;
use shared::mission::{MissionFamily, SpatialFamily};
use shared::orbit::OrbitShape;
use shared::scenario::{Scenario, ScenarioError, SpatialScenario};
use shared::spacecraft::CanonicalSpacecraft;

/// A dimension of flight: its scenario, family, state, command and action types.
pub trait Geometry: Send + Sync + Copy + core::fmt::Debug + PartialEq + 'static {
    /// Number of action components (3 planar, 4 spatial).
    const ACT: usize;
    /// What one episode flies.
    type Scenario: Copy + core::fmt::Debug + PartialEq + Send + Sync + 'static;
    /// What scenarios are drawn from (docs/spec.md section 4), and solved draw by draw into
    /// datasets.
    type Family: DatasetFamily;
    /// The spacecraft's state.
    type State: Copy + core::fmt::Debug + PartialEq + Send + Sync + 'static;
    /// A thrust command held over one guidance cycle.
    type Command: Copy + core::fmt::Debug + PartialEq + Send + Sync + 'static;
    /// `[f32; ACT]`: what the network outputs.
    type Action: Copy + core::fmt::Debug + PartialEq + Send + Sync + AsRef<[f32]> + for<'a> TryFrom<&'a [f32]> + 'static;

    /// A family of this geometry's: a planar one only when both planes are the reference
    /// plane; every family in three dimensions.
    fn family_of(family: &SpatialFamily) -> Option<Self::Family>;
    /// Scenario `index` of the stream `seed` of `family`.
    fn draw(family: &Self::Family, seed: u64, index: u64) -> Self::Scenario;
    /// The scenario's planar part: problem, cycles, cycle length, target shape and anomaly
    /// (every figure measured in its own orbit's plane).
    fn plan(scenario: &Self::Scenario) -> &Scenario;
    /// Checks every figure of the scenario.
    fn validate(scenario: &Self::Scenario) -> Result<(), ScenarioError>;
    /// The spacecraft at departure (mass 1).
    fn departure(scenario: &Self::Scenario) -> Self::State;
    /// The state's mass (m0 units).
    fn mass(state: &Self::State) -> f64;
    /// The state's inertial position (z = 0 in the plane).
    fn position(state: &Self::State) -> [f64; 3];
    /// The departure and target orbits when both lie in the reference plane (to draw them as
    /// ellipses in it); `None` for inclined orbits.
    fn reference_orbits(scenario: &Self::Scenario) -> Option<(OrbitShape, OrbitShape)>;
    /// The action of the zero-thrust baseline: throttle -1, no direction.
    fn zero_thrust_action() -> Self::Action;
    /// The command an action decodes to (onboard decoding; a non-finite action is thrust off).
    fn decode(action: &Self::Action) -> Self::Command;
    /// The command's throttle in [0, 1].
    fn throttle(command: &Self::Command) -> f64;
    /// `state` propagated for `duration` under `command` (the onboard propagator).
    fn propagate(
        state: &Self::State,
        command: &Self::Command,
        spacecraft: &CanonicalSpacecraft,
        duration: f64,
        tolerances: &Tolerances,
    ) -> Result<Self::State, PropagationError>;
}

/// The scenario type of a geometry.
pub type ScenarioOf<G> = <G as Geometry>::Scenario;
/// The family type of a geometry.
pub type FamilyOf<G> = <G as Geometry>::Family;
/// The state type of a geometry.
pub type StateOf<G> = <G as Geometry>::State;
/// The command type of a geometry.
pub type CommandOf<G> = <G as Geometry>::Command;
/// The action type of a geometry.
pub type ActionOf<G> = <G as Geometry>::Action;

/// In the reference plane: polar hold, actions `[u, alpha_r, alpha_theta]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Planar;

/// In three dimensions: RTN hold, actions `[u, radial, transverse, normal]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Spatial;

impl Geometry for Planar {
    const ACT: usize = ACTION_LEN;
    type Scenario = Scenario;
    type Family = MissionFamily;
    type State = SpacecraftState;
    type Command = ThrustCommand;
    type Action = [f32; ACTION_LEN];

    fn family_of(family: &SpatialFamily) -> Option<MissionFamily> {
        family.as_planar()
    }

    fn draw(family: &MissionFamily, seed: u64, index: u64) -> Scenario {
        family.draw(seed, index)
    }

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

    fn position(state: &SpacecraftState) -> [f64; 3] {
        [state.r[0], state.r[1], 0.0]
    }

    fn reference_orbits(scenario: &Scenario) -> Option<(OrbitShape, OrbitShape)> {
        Some((scenario.initial.shape, scenario.target))
    }

    fn zero_thrust_action() -> [f32; ACTION_LEN] {
        [-1.0, 0.0, 0.0]
    }

    fn decode(action: &[f32; ACTION_LEN]) -> ThrustCommand {
        decode_action(action)
    }

    fn throttle(command: &ThrustCommand) -> f64 {
        command.throttle
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

impl Geometry for Spatial {
    const ACT: usize = ACTION3_LEN;
    type Scenario = SpatialScenario;
    type Family = SpatialFamily;
    type State = SpatialCraftState;
    type Command = RtnCommand;
    type Action = [f32; ACTION3_LEN];

    fn family_of(family: &SpatialFamily) -> Option<SpatialFamily> {
        Some(*family)
    }

    fn draw(family: &SpatialFamily, seed: u64, index: u64) -> SpatialScenario {
        family.draw(seed, index)
    }

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

    fn position(state: &SpatialCraftState) -> [f64; 3] {
        state.orbit.r
    }

    fn reference_orbits(scenario: &SpatialScenario) -> Option<(OrbitShape, OrbitShape)> {
        let plan = &scenario.scenario;
        scenario.is_planar().then_some((plan.initial.shape, plan.target))
    }

    fn zero_thrust_action() -> [f32; ACTION3_LEN] {
        [-1.0, 0.0, 0.0, 0.0]
    }

    fn decode(action: &[f32; ACTION3_LEN]) -> RtnCommand {
        decode_action3(action)
    }

    fn throttle(command: &RtnCommand) -> f64 {
        command.throttle
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
