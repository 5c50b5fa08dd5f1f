//! The geometry an MDP flies in: [`Planar`] (docs/spec.md sections 3 to 6: the polar hold, 3
//! action components) or [`Spatial`] (sections 3.6, 5.1, 6.1: the RTN hold, 4 action
//! components). The dimension itself (scenario, state, command, departure, propagation) is
//! onboard's [`Dimension`], which the SIL loop flies too; the environments add here what a
//! family is, the action and how it decodes. The problems ([`super::Problem`]) add their
//! features on top.

use onboard::dynamics::{SpacecraftState, ThrustCommand};
use onboard::features::{decode_action, decode_action3, ACTION3_LEN, ACTION_LEN};
pub use onboard::geometry::{Dimension, Planar, Spatial};
use onboard::spatial::{RtnCommand, SpatialCraftState};

use crate::generate::DatasetFamily;
use shared::mission::{MissionFamily, SpatialFamily};
use shared::orbit::OrbitShape;
use shared::scenario::{Scenario, SpatialScenario};

/// A dimension of flight ([`Dimension`]: scenario, state, command, departure, propagation,
/// shared with the onboard side) with what the environments add: its family, its action and
/// how an action decodes.
pub trait Geometry: Dimension {
    /// Number of action components (3 planar, 4 spatial).
    const ACT: usize;
    /// What scenarios are drawn from (docs/spec.md section 4), and solved draw by draw into
    /// datasets.
    type Family: DatasetFamily;
    /// `[f32; ACT]`: what the network outputs.
    type Action: Copy + core::fmt::Debug + PartialEq + Send + Sync + AsRef<[f32]> + for<'a> TryFrom<&'a [f32]> + 'static;

    /// A family of this geometry's: a planar one only when both planes are the reference
    /// plane; every family in three dimensions.
    fn family_of(family: &SpatialFamily) -> Option<Self::Family>;
    /// Scenario `index` of the stream `seed` of `family`.
    fn draw(family: &Self::Family, seed: u64, index: u64) -> Self::Scenario;
    /// The state's inertial position (z = 0 in the plane).
    fn position(state: &Self::State) -> [f64; 3];
    /// The departure and target orbits when both lie in the reference plane (to draw them as
    /// ellipses in it); `None` for inclined orbits.
    fn reference_orbits(scenario: &Self::Scenario) -> Option<(OrbitShape, OrbitShape)>;
    /// The action of the zero-thrust baseline: throttle -1, no direction.
    fn zero_thrust_action() -> Self::Action;
    /// The command an action decodes to (onboard decoding; a non-finite action is thrust off).
    fn decode(action: &Self::Action) -> Self::Command;
}

/// The scenario type of a geometry.
pub type ScenarioOf<G> = <G as Dimension>::Scenario;
/// The family type of a geometry.
pub type FamilyOf<G> = <G as Geometry>::Family;
/// The state type of a geometry.
pub type StateOf<G> = <G as Dimension>::State;
/// The command type of a geometry.
pub type CommandOf<G> = <G as Dimension>::Command;
/// The action type of a geometry.
pub type ActionOf<G> = <G as Geometry>::Action;

impl Geometry for Planar {
    const ACT: usize = ACTION_LEN;
    type Family = MissionFamily;
    type Action = [f32; ACTION_LEN];

    fn family_of(family: &SpatialFamily) -> Option<MissionFamily> {
        family.as_planar()
    }

    fn draw(family: &MissionFamily, seed: u64, index: u64) -> Scenario {
        family.draw(seed, index)
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
}

impl Geometry for Spatial {
    const ACT: usize = ACTION3_LEN;
    type Family = SpatialFamily;
    type Action = [f32; ACTION3_LEN];

    fn family_of(family: &SpatialFamily) -> Option<SpatialFamily> {
        Some(*family)
    }

    fn draw(family: &SpatialFamily, seed: u64, index: u64) -> SpatialScenario {
        family.draw(seed, index)
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
}
