//! One guidance step: navigation state + target + time to go in, thrust command out.
//!
//! The step validates its inputs, encodes the features the network was trained on, runs the
//! actor's mean head and decodes its action. Any failure is a typed error: the caller (flight
//! software) then commands thrust off; a NaN never reaches the thrusters.

use shared::orbit::{CartesianState, OrbitPlane, OrbitShape, SpatialState};
use shared::spacecraft::CanonicalSpacecraft;

use crate::dynamics::SpacecraftState;
use crate::dynamics::ThrustCommand;
use crate::features::{
    decode_action, decode_action3, rendezvous3_features, rendezvous3_residuals, rendezvous_features,
    rendezvous_residuals, to_network_input, transfer3_features, transfer3_miss, transfer3_residuals, transfer_features,
    transfer_residuals, FeatureError, Residuals, ACTION3_LEN, ACTION_LEN, RENDEZVOUS3_FEATURES, RENDEZVOUS_FEATURES,
    TRANSFER3_FEATURES, TRANSFER_FEATURES,
};
use crate::geometry::{Dimension, Planar, Spatial};
use crate::kepler::{coast, coast3};
use crate::lookahead::{lookahead_step, Lookahead, LookaheadSettings};
use crate::spatial::{RtnCommand, SpatialCraftState};
use crate::terminal::{Terminal, TerminalSettings};

/// A deterministic actor: features in, action in [-1, 1]^OUT out. Implemented by the onboard
/// MLPs (f32 and int8) and by anything else that can fly (tests, baselines). In the plane
/// (`OUT` = 3) the action is the throttle and the two polar direction components, as
/// [`crate::features::decode_action`] reads them; in three dimensions (`OUT` = 4) the throttle
/// and the three RTN components ([`crate::features::decode_action3`]).
pub trait Actor<const IN: usize, const OUT: usize = ACTION_LEN> {
    /// The action for `features` (already narrowed to f32), each component in [-1, 1].
    fn act(&self, features: &[f32; IN]) -> [f32; OUT];
}

/// A borrowed actor flies as the actor (so a [`crate::lookahead::Lookahead`] can hold a reference).
impl<const IN: usize, const OUT: usize, A: Actor<IN, OUT> + ?Sized> Actor<IN, OUT> for &A {
    fn act(&self, features: &[f32; IN]) -> [f32; OUT] {
        (**self).act(features)
    }
}

/// The onboard MLPs fly as actors: their output is already the tanh-squashed action.
impl<const IN: usize, const H1: usize, const H2: usize, const OUT: usize> Actor<IN, OUT>
    for crate::policy::Mlp<'_, IN, H1, H2, OUT>
{
    fn act(&self, features: &[f32; IN]) -> [f32; OUT] {
        self.forward(features)
    }
}

/// Where the spacecraft must go.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GuidanceTarget {
    /// A transfer: reach this orbit, anywhere on it.
    Orbit(OrbitShape),
    /// A rendezvous: meet the body, whose current state is given (propagate it with
    /// [`crate::kepler::coast`] from its epoch).
    Body(CartesianState),
}

/// Why no command was produced (the caller commands thrust off).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GuidanceError {
    /// Navigation state, target or time to go is unusable.
    Input(FeatureError),
    /// The network produced a non-finite action (corrupt weights?).
    NonFiniteAction,
}

impl core::fmt::Display for GuidanceError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Input(e) => write!(f, "guidance input refused: {e}"),
            Self::NonFiniteAction => f.write_str("policy produced a non-finite action"),
        }
    }
}

impl core::error::Error for GuidanceError {}

/// Transfer guidance: features of docs/spec.md section 5, actor, decoded command.
pub fn transfer_step<A: Actor<TRANSFER_FEATURES>>(
    actor: &A,
    navigation: &SpacecraftState,
    target: &OrbitShape,
    time_to_go: f64,
) -> Result<ThrustCommand, GuidanceError> {
    command_at(actor, target, navigation, 0.0, time_to_go)
}

/// Rendezvous guidance: features of docs/spec.md section 6, actor, decoded command.
pub fn rendezvous_step<A: Actor<RENDEZVOUS_FEATURES>>(
    actor: &A,
    navigation: &SpacecraftState,
    target_body: &CartesianState,
    time_to_go: f64,
) -> Result<ThrustCommand, GuidanceError> {
    command_at(actor, target_body, navigation, 0.0, time_to_go)
}

/// Transfer guidance in three dimensions (docs/spec.md section 6.1): the 15 features of the
/// navigation state against the target orbit (its shape in its plane), actor, decoded RTN
/// command.
pub fn transfer3_step<A: Actor<TRANSFER3_FEATURES, ACTION3_LEN>>(
    actor: &A,
    navigation: &SpatialCraftState,
    target: &TargetOrbit3,
    time_to_go: f64,
) -> Result<RtnCommand, GuidanceError> {
    command3_at(actor, target, navigation, time_to_go)
}

/// Rendezvous guidance in three dimensions (docs/spec.md section 6.1): the 30 features of the
/// navigation state against the body's current state, actor, decoded RTN command.
pub fn rendezvous3_step<A: Actor<RENDEZVOUS3_FEATURES, ACTION3_LEN>>(
    actor: &A,
    navigation: &SpatialCraftState,
    target_body: &SpatialState,
    time_to_go: f64,
) -> Result<RtnCommand, GuidanceError> {
    command3_at(actor, target_body, navigation, time_to_go)
}

/// A transfer's target in three dimensions: the orbit's shape in its own plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetOrbit3 {
    /// Semi-major axis, eccentricity and periapsis argument, measured in `plane`.
    pub shape: OrbitShape,
    /// The orbit's plane.
    pub plane: OrbitPlane,
}

/// A target as three-dimensional guidance sees it: the `N` features of a state against it, now
/// or (for terminal targeting's rollouts) a while after now. Implemented by the transfer's
/// [`TargetOrbit3`] and the rendezvous body's current state.
pub trait SpatialTargetFeatures<const N: usize> {
    /// The `N` features of `state`, `elapsed` after the guidance cycle's start, `time_to_go`
    /// before the arrival.
    fn features_after(
        &self,
        state: &SpatialCraftState,
        elapsed: f64,
        time_to_go: f64,
    ) -> Result<[f64; N], FeatureError>;
    /// The `N` features of `state` at the cycle's start.
    fn features(&self, state: &SpatialCraftState, time_to_go: f64) -> Result<[f64; N], FeatureError> {
        self.features_after(state, 0.0, time_to_go)
    }
    /// The residuals read off the features.
    fn residuals(features: &[f64; N]) -> Residuals;
    /// The residuals' components at `state`, `elapsed` after the cycle's start (the target's
    /// point or the body less the state, position then velocity; their lengths are the
    /// residuals): what [`crate::terminal`] drives to zero.
    fn miss_after(&self, state: &SpatialCraftState, elapsed: f64) -> Result<[f64; MISS_LEN], FeatureError>;
}

impl SpatialTargetFeatures<TRANSFER3_FEATURES> for TargetOrbit3 {
    fn features_after(
        &self,
        state: &SpatialCraftState,
        _elapsed: f64,
        time_to_go: f64,
    ) -> Result<[f64; TRANSFER3_FEATURES], FeatureError> {
        transfer3_features(state, &self.shape, &self.plane, time_to_go)
    }

    fn residuals(features: &[f64; TRANSFER3_FEATURES]) -> Residuals {
        transfer3_residuals(features)
    }

    fn miss_after(&self, state: &SpatialCraftState, _elapsed: f64) -> Result<[f64; MISS_LEN], FeatureError> {
        transfer3_miss(state, &self.shape, &self.plane)
    }
}

/// The body is coasted from its state at the cycle's start; at the start itself it is taken as
/// given, bit for bit.
impl SpatialTargetFeatures<RENDEZVOUS3_FEATURES> for SpatialState {
    fn features_after(
        &self,
        state: &SpatialCraftState,
        elapsed: f64,
        time_to_go: f64,
    ) -> Result<[f64; RENDEZVOUS3_FEATURES], FeatureError> {
        if elapsed == 0.0 {
            return rendezvous3_features(state, self, time_to_go);
        }
        let body = coast3(self, elapsed).map_err(|_| FeatureError::Target)?;
        rendezvous3_features(state, &body, time_to_go)
    }

    fn residuals(features: &[f64; RENDEZVOUS3_FEATURES]) -> Residuals {
        rendezvous3_residuals(features)
    }

    /// The features' dx, dy, dz, dvx, dvy, dvz (finite, as every feature is).
    fn miss_after(&self, state: &SpatialCraftState, elapsed: f64) -> Result<[f64; MISS_LEN], FeatureError> {
        let f = SpatialTargetFeatures::features_after(self, state, elapsed, 0.0)?;
        Ok([f[20], f[21], f[22], f[23], f[24], f[25]])
    }
}

/// Components of a miss vector: position then velocity, three each (in the plane the third of
/// each is 0).
pub const MISS_LEN: usize = 6;

/// A target as every guidance step and the onboard aids see it, for a network of `N` features
/// and `OUT` action components: the features of a state against it, how the action decodes,
/// the arrival's miss. Implemented for every planar target ([`TargetFeatures`], 3 actions) and
/// every three-dimensional one ([`SpatialTargetFeatures`], 4 actions), so one guidance path and
/// one terminal targeting serve both dimensions.
pub trait Aim<const N: usize, const OUT: usize> {
    /// The dimension the target is flown in.
    type Geometry: Dimension;
    /// The `N` features of `state`, `elapsed` after the guidance cycle's start, `time_to_go`
    /// before the arrival.
    fn features_after(
        &self,
        state: &<Self::Geometry as Dimension>::State,
        elapsed: f64,
        time_to_go: f64,
    ) -> Result<[f64; N], FeatureError>;
    /// The command of a finite action.
    fn decode(action: &[f32; OUT]) -> <Self::Geometry as Dimension>::Command;
    /// The arrival's miss components at `state`, `elapsed` after the cycle's start: position
    /// (AU) then velocity (AU/t*), [`MISS_LEN`] of them.
    fn miss_after(
        &self,
        state: &<Self::Geometry as Dimension>::State,
        elapsed: f64,
    ) -> Result<[f64; MISS_LEN], FeatureError>;
    /// The arrival's residuals at `state`, `elapsed` after the cycle's start (docs/spec.md
    /// sections 5, 6), as the evaluation reads them off the features.
    fn residuals_after(
        &self,
        state: &<Self::Geometry as Dimension>::State,
        elapsed: f64,
    ) -> Result<Residuals, FeatureError>;
}

impl<const N: usize, T: TargetFeatures<N>> Aim<N, ACTION_LEN> for T {
    type Geometry = Planar;

    fn features_after(&self, state: &SpacecraftState, elapsed: f64, time_to_go: f64) -> Result<[f64; N], FeatureError> {
        TargetFeatures::features_after(self, state, elapsed, time_to_go)
    }

    fn decode(action: &[f32; ACTION_LEN]) -> ThrustCommand {
        decode_action(action)
    }

    fn miss_after(&self, state: &SpacecraftState, elapsed: f64) -> Result<[f64; MISS_LEN], FeatureError> {
        let features = TargetFeatures::features_after(self, state, elapsed, 0.0)?;
        Ok(T::miss(&features))
    }

    fn residuals_after(&self, state: &SpacecraftState, elapsed: f64) -> Result<Residuals, FeatureError> {
        let features = TargetFeatures::features_after(self, state, elapsed, 0.0)?;
        Ok(T::residuals(&features))
    }
}

impl<const N: usize, T: SpatialTargetFeatures<N>> Aim<N, ACTION3_LEN> for T {
    type Geometry = Spatial;

    fn features_after(
        &self,
        state: &SpatialCraftState,
        elapsed: f64,
        time_to_go: f64,
    ) -> Result<[f64; N], FeatureError> {
        SpatialTargetFeatures::features_after(self, state, elapsed, time_to_go)
    }

    fn decode(action: &[f32; ACTION3_LEN]) -> RtnCommand {
        decode_action3(action)
    }

    fn miss_after(&self, state: &SpatialCraftState, elapsed: f64) -> Result<[f64; MISS_LEN], FeatureError> {
        SpatialTargetFeatures::miss_after(self, state, elapsed)
    }

    fn residuals_after(&self, state: &SpatialCraftState, elapsed: f64) -> Result<Residuals, FeatureError> {
        let features = SpatialTargetFeatures::features_after(self, state, elapsed, 0.0)?;
        Ok(T::residuals(&features))
    }
}

/// The network's RTN command for `state` against `target` at the cycle's start: features,
/// actor, decoded command (the one path of every guidance step, in either dimension).
pub fn command3_at<const N: usize, A: Actor<N, ACTION3_LEN> + ?Sized, T: SpatialTargetFeatures<N>>(
    actor: &A,
    target: &T,
    state: &SpatialCraftState,
    time_to_go: f64,
) -> Result<RtnCommand, GuidanceError> {
    command_at(actor, target, state, 0.0, time_to_go)
}

/// A guidance law as flight software calls it each cycle: navigation state, target and time to go
/// in, the command to hold out, in dimension `G` (the plane by default). Any [`Actor`] is one
/// (through [`transfer_step`] and [`rendezvous_step`] in the plane, [`command3_at`] in three
/// dimensions); so is an actor with rollout lookahead ([`crate::lookahead::Lookahead`]), with
/// terminal targeting ([`crate::terminal::Terminal`]), or with whichever are set ([`Aided`]).
pub trait Guide<const N: usize, T, G: Dimension = Planar> {
    /// The command for this cycle, or why there is none (the caller commands thrust off).
    fn command(&self, navigation: &G::State, target: &T, time_to_go: f64) -> Result<G::Command, GuidanceError>;
}

/// Any four-output actor flies the three-dimensional guidance step of its problem.
impl<const N: usize, T: SpatialTargetFeatures<N>, A: Actor<N, ACTION3_LEN>> Guide<N, T, Spatial> for A {
    fn command(
        &self,
        navigation: &SpatialCraftState,
        target: &T,
        time_to_go: f64,
    ) -> Result<RtnCommand, GuidanceError> {
        command3_at(self, target, navigation, time_to_go)
    }
}

/// Any actor flies the plain guidance step of its problem.
impl<const N: usize, T: TargetFeatures<N>, A: Actor<N>> Guide<N, T> for A {
    fn command(
        &self,
        navigation: &SpacecraftState,
        target: &T,
        time_to_go: f64,
    ) -> Result<ThrustCommand, GuidanceError> {
        command_at(self, target, navigation, 0.0, time_to_go)
    }
}

impl<const N: usize, T: TargetFeatures<N>, A: Actor<N>> Guide<N, T> for Lookahead<A> {
    fn command(
        &self,
        navigation: &SpacecraftState,
        target: &T,
        time_to_go: f64,
    ) -> Result<ThrustCommand, GuidanceError> {
        lookahead_step(
            &self.actor,
            navigation,
            target,
            time_to_go,
            &self.spacecraft,
            &self.settings,
        )
        .map(|d| d.command)
    }
}

impl<const N: usize, T: SpatialTargetFeatures<N>, A: Actor<N, ACTION3_LEN>> Guide<N, T, Spatial> for Lookahead<A> {
    fn command(
        &self,
        navigation: &SpatialCraftState,
        target: &T,
        time_to_go: f64,
    ) -> Result<RtnCommand, GuidanceError> {
        lookahead_step(
            &self.actor,
            navigation,
            target,
            time_to_go,
            &self.spacecraft,
            &self.settings,
        )
        .map(|d| d.command)
    }
}

/// An actor flown with whichever onboard aids are set, as a configuration chooses them at run
/// time: terminal targeting over the last cycles (with the lookahead before them when set),
/// else rollout lookahead, else the plain step. The one choice the SIL, the Python package and
/// flight software holding optional settings make alike.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aided<A> {
    /// The network.
    pub actor: A,
    /// The nominal spacecraft of the aids' rollouts.
    pub spacecraft: CanonicalSpacecraft,
    /// Rollout lookahead (None: not flown).
    pub lookahead: Option<LookaheadSettings>,
    /// Terminal targeting of the last cycles (None: not flown).
    pub terminal: Option<TerminalSettings>,
}

impl<const N: usize, T, G: Dimension, A> Guide<N, T, G> for Aided<A>
where
    A: Guide<N, T, G>,
    for<'a> Lookahead<&'a A>: Guide<N, T, G>,
    for<'a> Terminal<&'a A>: Guide<N, T, G>,
{
    fn command(&self, navigation: &G::State, target: &T, time_to_go: f64) -> Result<G::Command, GuidanceError> {
        let (actor, spacecraft) = (&self.actor, self.spacecraft);
        match (self.terminal, self.lookahead) {
            (Some(settings), lookahead) => Terminal {
                actor,
                spacecraft,
                settings,
                lookahead,
            }
            .command(navigation, target, time_to_go),
            (None, Some(settings)) => Lookahead {
                actor,
                spacecraft,
                settings,
            }
            .command(navigation, target, time_to_go),
            (None, None) => actor.command(navigation, target, time_to_go),
        }
    }
}

/// A target as guidance sees it: the features of a state against it, now or (for the
/// lookahead's rollouts) a while after now. Implemented by the transfer's target orbit and the
/// rendezvous body's current state.
pub trait TargetFeatures<const N: usize> {
    /// The `N` features of `state`, `elapsed` after the guidance cycle's start, `time_to_go` before
    /// the arrival.
    fn features_after(&self, state: &SpacecraftState, elapsed: f64, time_to_go: f64) -> Result<[f64; N], FeatureError>;
    /// The residuals read off the features.
    fn residuals(features: &[f64; N]) -> Residuals;
    /// The residuals' components, position then velocity (AU, then AU/t*; [`MISS_LEN`], the
    /// third of each 0 in the plane): what [`crate::terminal`] drives to zero. A transfer's are
    /// the radius difference and the polar velocity differences to the target orbit at the
    /// spacecraft's polar angle.
    fn miss(features: &[f64; N]) -> [f64; MISS_LEN];
}

/// A transfer's target orbit does not move (docs/spec.md section 5).
impl TargetFeatures<TRANSFER_FEATURES> for OrbitShape {
    fn features_after(
        &self,
        state: &SpacecraftState,
        _elapsed: f64,
        time_to_go: f64,
    ) -> Result<[f64; TRANSFER_FEATURES], FeatureError> {
        transfer_features(state, self, time_to_go)
    }

    fn residuals(features: &[f64; TRANSFER_FEATURES]) -> Residuals {
        transfer_residuals(features)
    }

    fn miss(f: &[f64; TRANSFER_FEATURES]) -> [f64; MISS_LEN] {
        let [r, _, _, v_r, v_theta, _, r_t, v_r_t, v_theta_t, _] = *f;
        [r_t - r, 0.0, 0.0, v_r_t - v_r, v_theta_t - v_theta, 0.0]
    }
}

/// A rendezvous body (docs/spec.md section 6) is coasted from its state at the cycle's start; at
/// the start itself it is taken as given, bit for bit.
impl TargetFeatures<RENDEZVOUS_FEATURES> for CartesianState {
    fn features_after(
        &self,
        state: &SpacecraftState,
        elapsed: f64,
        time_to_go: f64,
    ) -> Result<[f64; RENDEZVOUS_FEATURES], FeatureError> {
        if elapsed == 0.0 {
            return rendezvous_features(state, self, time_to_go);
        }
        let body = coast(self, elapsed).map_err(|_| FeatureError::Target)?;
        rendezvous_features(state, &body, time_to_go)
    }

    fn residuals(features: &[f64; RENDEZVOUS_FEATURES]) -> Residuals {
        rendezvous_residuals(features)
    }

    fn miss(f: &[f64; RENDEZVOUS_FEATURES]) -> [f64; MISS_LEN] {
        let [.., dx, dy, dvx, dvy, _, _, _, _] = *f;
        [dx, dy, 0.0, dvx, dvy, 0.0]
    }
}

/// Guidance cycles of length `cycle` left in `time_to_go`: whole cycles, the last one possibly
/// partial (a sliver below 1e-9 of a cycle is rounding). How the onboard aids count their horizon.
pub fn cycles_left(time_to_go: f64, cycle: f64) -> f64 {
    libm::ceil(time_to_go / cycle - 1e-9)
}

/// The duration of the cycle that starts `start` after now with `time_to_go` left: whole cycles
/// are exactly `cycle`, as the flight holds them; only a last partial one is shorter (a remainder
/// within rounding of `cycle` is a whole cycle). How the onboard aids' rollouts cut the time.
pub(crate) fn cycle_duration(time_to_go: f64, start: f64, cycle: f64) -> f64 {
    let remaining = time_to_go - start;
    if remaining >= cycle * (1.0 - 1e-9) {
        cycle
    } else {
        remaining
    }
}

/// The network's command for `state`, `elapsed` after the cycle's start and `time_to_go` before
/// the arrival: features, actor, decoded command; the one path of every guidance step, in
/// either dimension.
pub(crate) fn command_at<const N: usize, const OUT: usize, A: Actor<N, OUT> + ?Sized, T: Aim<N, OUT>>(
    actor: &A,
    target: &T,
    state: &<T::Geometry as Dimension>::State,
    elapsed: f64,
    time_to_go: f64,
) -> Result<<T::Geometry as Dimension>::Command, GuidanceError> {
    let features = target
        .features_after(state, elapsed, time_to_go)
        .map_err(GuidanceError::Input)?;
    let action = actor.act(&to_network_input(&features));
    if !action.iter().all(|a| a.is_finite()) {
        return Err(GuidanceError::NonFiniteAction);
    }
    Ok(T::decode(&action))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::dynamics::StateError;

    /// Along-track full thrust whatever the input.
    pub(crate) struct Tangential;
    impl<const N: usize> Actor<N> for Tangential {
        fn act(&self, _: &[f32; N]) -> [f32; ACTION_LEN] {
            [1.0, 0.0, 1.0]
        }
    }

    /// Returns a feature as throttle so the test sees what the actor was given.
    struct Echo(usize);
    impl<const N: usize> Actor<N> for Echo {
        fn act(&self, x: &[f32; N]) -> [f32; ACTION_LEN] {
            [x.get(self.0).copied().unwrap_or(f32::NAN), 0.0, 1.0]
        }
    }

    /// A network gone bad: a NaN action whatever the input.
    pub(crate) struct Broken;
    impl<const N: usize> Actor<N> for Broken {
        fn act(&self, _: &[f32; N]) -> [f32; ACTION_LEN] {
            [f32::NAN, 0.0, 1.0]
        }
    }

    const NAV: SpacecraftState = SpacecraftState {
        r: [1.0, 0.0],
        v: [0.0, 1.0],
        m: 0.9,
    };
    const MARS: OrbitShape = OrbitShape {
        a: 1.52,
        e: 0.0,
        omega: 0.0,
    };

    #[test]
    fn flies_the_actor_through_the_features() {
        let c = transfer_step(&Tangential, &NAV, &MARS, 2.0).unwrap();
        assert_eq!((c.throttle, c.alpha_r, c.alpha_theta), (1.0, 0.0, 1.0));
        // Feature 5 is the mass: the actor saw 0.9 -> throttle (0.9 + 1) / 2.
        let c = transfer_step(&Echo(5), &NAV, &MARS, 2.0).unwrap();
        assert!((c.throttle - 0.95).abs() < 1e-7);
        // Rendezvous feature 20 is the time to go (0.5 -> throttle 0.75).
        let body = MARS.cartesian_at(1.0);
        let c = rendezvous_step(&Echo(20), &NAV, &body, 0.5).unwrap();
        assert!((c.throttle - 0.75).abs() < 1e-7);
    }

    #[test]
    fn bad_inputs_and_bad_networks_give_errors_not_commands() {
        let bad = SpacecraftState {
            r: [f64::NAN, 0.0],
            ..NAV
        };
        assert_eq!(
            transfer_step(&Tangential, &bad, &MARS, 1.0),
            Err(GuidanceError::Input(FeatureError::State(StateError::NonFinite)))
        );
        let at_sun = SpacecraftState { r: [0.0, 0.0], ..NAV };
        assert_eq!(
            transfer_step(&Tangential, &at_sun, &MARS, 1.0),
            Err(GuidanceError::Input(FeatureError::State(StateError::ZeroRadius)))
        );
        let empty = SpacecraftState { m: -0.1, ..NAV };
        assert!(rendezvous_step(&Tangential, &empty, &MARS.cartesian_at(0.0), 1.0).is_err());
        assert_eq!(
            transfer_step(&Broken, &NAV, &MARS, 1.0),
            Err(GuidanceError::NonFiniteAction)
        );
    }
}
