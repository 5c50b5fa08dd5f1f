//! Rollout lookahead: the network's command improved by flying a few alternatives to the arrival
//! (a transfer's or a rendezvous's) with the onboard propagator, the network steering after the
//! first cycle.
//!
//! At each guidance cycle the network proposes a command. [`CANDIDATES`] commands around it
//! (other throttles, the direction turned by a few degrees) are each held for one cycle and then
//! the network flies every later cycle, all in the nominal model: the same propagator, spacecraft
//! and time grid as the flight. The candidate whose predicted arrival costs least is commanded:
//!
//! `cost = max(dr / goal_position, dv / goal_velocity, accuracy_floor) + fuel_weight (1 - m_end)`
//!
//! (m in m0 units) so the accuracy counts until the residuals are `accuracy_floor` times the goal,
//! and the propellant decides among arrivals inside that. The cost is the arrival's alone, so
//! predictions made at different cycles compare. The network's own command is candidate 0 and
//! wins ties. Because the predicted continuation of the chosen rollout is the network's
//! candidate at the next cycle, the predicted cost never rises along a nominal flight: flown
//! without dispersions, the lookahead arrives at a cost no higher than the network alone
//! (the rollout algorithm's cost improvement; `tests/tests/lookahead.rs` checks it flight by
//! flight). Under dispersions each cycle replans from the navigation state.
//!
//! The work is at most `CANDIDATES` x the cycles left rollout cycles (an inference and a
//! propagation of one or more fixed steps each; 1,050 for a 50-cycle transfer at its start), or
//! the settings' `rollout_budget` of steps, which flies the most useful candidates first; no
//! allocation, no panic; a candidate whose rollout fails (tank dry, integrator refusal) is simply
//! not chosen, and if every rollout fails the network's command is flown.

use shared::spacecraft::CanonicalSpacecraft;
use shared::units::STEP;

use crate::dynamics::ThrustCommand;
use crate::features::Residuals;
use crate::geometry::Dimension;
use crate::guidance::{command_at, cycle_duration, cycles_left, Actor, Aim, GuidanceError};
use crate::integrator::Tolerances;

/// The candidates after the network's own command, most useful first, so that a rollout
/// budget flies the best prefix: a throttle (an offset from the network's, clamped to [0, 1], or
/// fixed) with a turn of the network's direction in degrees (towards the radial). Thrust off is
/// listed once: in any direction it flies the same.
const ALTERNATIVES: [(Throttle, f64); 20] = [
    (Throttle::Fixed(0.0), 0.0),
    (Throttle::Fixed(1.0), 0.0),
    (Throttle::Offset(0.0), 10.0),
    (Throttle::Offset(0.0), -10.0),
    (Throttle::Fixed(1.0), 10.0),
    (Throttle::Fixed(1.0), -10.0),
    (Throttle::Offset(0.0), 30.0),
    (Throttle::Offset(0.0), -30.0),
    (Throttle::Offset(-0.25), 0.0),
    (Throttle::Offset(0.25), 0.0),
    (Throttle::Offset(-0.25), 10.0),
    (Throttle::Offset(-0.25), -10.0),
    (Throttle::Offset(0.25), 10.0),
    (Throttle::Offset(0.25), -10.0),
    (Throttle::Fixed(1.0), 30.0),
    (Throttle::Fixed(1.0), -30.0),
    (Throttle::Offset(-0.25), 30.0),
    (Throttle::Offset(-0.25), -30.0),
    (Throttle::Offset(0.25), 30.0),
    (Throttle::Offset(0.25), -30.0),
];

/// Candidates per cycle: the network's command, then the alternatives in order.
pub const CANDIDATES: usize = 1 + ALTERNATIVES.len();

#[derive(Debug, Clone, Copy, PartialEq)]
enum Throttle {
    Offset(f64),
    Fixed(f64),
}

/// What the lookahead weighs; `Default` is the goal of docs/spec.md's accuracy figures. The one
/// definition: the ground's configs read it (feature `serde`: the floor, the fuel weight, the
/// thrust margin, the cycle cap and the rollout steps by name, each defaulted; the goals are the
/// evaluation's, adaptive rollouts' tolerances the environment's) and the C interface mirrors it.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct LookaheadSettings {
    /// Position residual that counts as one unit of miss (AU).
    #[cfg_attr(feature = "serde", serde(skip))]
    pub goal_position: f64,
    /// Velocity residual that counts as one unit of miss (canonical).
    #[cfg_attr(feature = "serde", serde(skip))]
    pub goal_velocity: f64,
    /// Below this many goal units, a smaller miss is worth nothing more (> 0).
    pub accuracy_floor: f64,
    /// Cost of spending the whole initial mass as propellant, in goal units (>= 0).
    pub fuel_weight: f64,
    /// DOP853 steps per cycle of each rollout, without error control, at least (1 to
    /// [`MAX_ROLLOUT_STEPS`]; default 1: 12 evaluations a cycle, more near a periapsis, see
    /// [`rollout_tolerances`]), or 0: the adaptive integrator at `tolerances`.
    pub rollout_steps: u32,
    /// Tolerances of the rollouts' adaptive propagation, with `rollout_steps` 0 (default: the
    /// flight propagator's).
    #[cfg_attr(feature = "serde", serde(skip))]
    pub tolerances: Tolerances,
    /// Most cycles a rollout may fly; with more left the network's command is flown unexamined.
    /// A bound on a cycle's work: at most [`CANDIDATES`] x `max_cycles` rollout cycles.
    pub max_cycles: u32,
    /// Fraction of the thrust the rollouts plan without, in [0, 1): a duty-cycle margin against
    /// thrust the flight will lose (missed-thrust events, a weak thruster). 0 plans with the
    /// nominal thrust, the only setting under which the lookahead never arrives worse than the
    /// network in the nominal model.
    #[cfg_attr(feature = "serde", serde(skip_serializing_if = "is_zero"))]
    pub thrust_margin: f64,
    /// Whole cycles before the arrival at which the rollouts are judged (default 0): the
    /// arrival's residuals and mass are taken that much earlier, the target met early and
    /// followed (an orbit coasted along, a body coasted with), so the rollouts keep the last
    /// cycles in reserve against thrust the flight will lose. With no more cycles left than the
    /// margin, the arrival itself.
    #[cfg_attr(feature = "serde", serde(skip_serializing_if = "is_zero_cycles"))]
    pub arrival_margin: u32,
    /// Most rollout steps a guidance cycle may fly in all, or 0 for no limit (default). Each
    /// cycle of a rollout counts its fixed DOP853 steps ([`rollout_tolerances`]: one from a
    /// periapsis beyond 0.68 AU, more nearer the Sun; an adaptive cycle counts one), so a step
    /// costs at most one inference and one step's propagation. The candidates are flown in
    /// their order of usefulness; one whose rollout runs out of budget, and every later one, is
    /// not a candidate (none: the network's command unexamined). With one step a cycle and `n`
    /// cycles to go, `rollout_budget / n` of them. The bound on a cycle's work that holds at any
    /// time to go and any distance from the Sun, where `max_cycles` stops looking.
    #[cfg_attr(feature = "serde", serde(skip_serializing_if = "is_zero_cycles"))]
    pub rollout_budget: u32,
    /// Length of a guidance cycle (t*; default 14 days, [`STEP`]): the scenario family's.
    #[cfg_attr(feature = "serde", serde(skip))]
    pub cycle: f64,
}

/// Whether a setting is at its default of zero (left out when written).
#[cfg(feature = "serde")]
fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

/// Whether a count of cycles is at its default of zero (left out when written).
#[cfg(feature = "serde")]
fn is_zero_cycles(n: &u32) -> bool {
    *n == 0
}

impl Default for LookaheadSettings {
    fn default() -> Self {
        Self {
            goal_position: 0.01,
            goal_velocity: 0.01,
            accuracy_floor: 0.5,
            fuel_weight: 5.0,
            rollout_steps: 1,
            tolerances: Tolerances::default(),
            max_cycles: 200,
            thrust_margin: 0.0,
            arrival_margin: 0,
            rollout_budget: 0,
            cycle: STEP,
        }
    }
}

/// Most DOP853 steps a cycle of an onboard aid's rollout may take.
pub const MAX_ROLLOUT_STEPS: u32 = 32;

/// The longest fixed rollout step as a fraction of the periapsis's dynamical time `rp^1.5`
/// (t*, mu = 1): one such step of a 14-day thrust arc from an orbit of periapsis 0.68 AU
/// predicts it to about 1e-9, and the error falls as the ninth power of the step.
const STEP_SPAN: f64 = 0.43;

/// The integrator settings of one rollout cycle of `duration` from a state whose osculating
/// orbit has periapsis `periapsis`: with `steps` 0 the adaptive `tolerances`; otherwise equal
/// DOP853 steps without error control, at least `steps` and at least
/// `duration / (0.43 rp^1.5)`, at most [`MAX_ROLLOUT_STEPS`] (a non-finite periapsis takes the
/// most). One step then predicts a 14-day thrust arc to about 1e-11 AU at 1 AU and 1e-9 down
/// to 0.68 AU in 12 evaluations, where the flight propagator's tolerances take 38 to 98; closer
/// to the Sun more steps keep it near 1e-7 of the radius (19 from a periapsis at 0.1 AU); and
/// the prediction is smooth in the commands.
pub fn rollout_tolerances(steps: u32, tolerances: &Tolerances, duration: f64, periapsis: f64) -> Tolerances {
    if steps == 0 {
        return Tolerances {
            fixed_steps: 0,
            ..*tolerances
        };
    }
    let needed = libm::ceil(libm::fabs(duration) / (STEP_SPAN * periapsis * libm::sqrt(periapsis)));
    let most = f64::from(MAX_ROLLOUT_STEPS);
    // Saturating: NaN (no periapsis) and anything past the bound take the most.
    let needed = if needed <= most {
        needed as u32
    } else {
        MAX_ROLLOUT_STEPS
    };
    Tolerances {
        fixed_steps: steps.max(needed).min(MAX_ROLLOUT_STEPS),
        ..*tolerances
    }
}

/// Settings the lookahead refuses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InvalidSettings;

impl core::fmt::Display for InvalidSettings {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(
            "lookahead goals, floor and cycle must be finite and > 0, the fuel weight finite and >= 0, the thrust margin in [0, 1), \
             the rollout steps at most 32",
        )
    }
}

impl LookaheadSettings {
    /// The integrator settings of a rollout cycle of `duration` from a state of periapsis
    /// `periapsis` (see [`rollout_tolerances`]).
    pub fn rollout_tolerances(&self, duration: f64, periapsis: f64) -> Tolerances {
        rollout_tolerances(self.rollout_steps, &self.tolerances, duration, periapsis)
    }

    /// Checks the figures (the integrator checks its own tolerances when a rollout runs).
    pub fn validate(&self) -> Result<(), InvalidSettings> {
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if positive(self.goal_position)
            && positive(self.goal_velocity)
            && positive(self.accuracy_floor)
            && self.fuel_weight.is_finite()
            && self.fuel_weight >= 0.0
            && (0.0..1.0).contains(&self.thrust_margin)
            && self.rollout_steps <= MAX_ROLLOUT_STEPS
            && positive(self.cycle)
        {
            Ok(())
        } else {
            Err(InvalidSettings)
        }
    }

    /// The cost of an arrival (see the module documentation); only its residuals and mass count.
    pub fn cost(&self, arrival: &Prediction) -> f64 {
        let miss = (arrival.residuals.position / self.goal_position)
            .max(arrival.residuals.velocity / self.goal_velocity)
            .max(self.accuracy_floor);
        miss + self.fuel_weight * (1.0 - arrival.mass)
    }
}

/// A predicted arrival: residuals and mass at the end of a rollout.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prediction {
    /// Residuals at the arrival (docs/spec.md sections 5, 6).
    pub residuals: Residuals,
    /// Mass at the arrival (m0 units).
    pub mass: f64,
    /// The settings' cost of this arrival.
    pub cost: f64,
}

/// One lookahead guidance cycle: the command and why it was chosen (telemetry). `C` is the
/// dimension's command: polar in the plane, [`crate::spatial::RtnCommand`] in three dimensions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decision<C = ThrustCommand> {
    /// The command to hold for the cycle.
    pub command: C,
    /// The network's own command.
    pub network: C,
    /// Which candidate was chosen (0: the network's).
    pub chosen: usize,
    /// The chosen candidate's predicted arrival (None when no rollout succeeded or none ran).
    pub predicted: Option<Prediction>,
    /// The network's own predicted arrival (None when its rollout failed or none ran).
    pub network_predicted: Option<Prediction>,
    /// Candidates flown out this cycle: those that fly differently from every earlier one (a
    /// repeat of an earlier command, or thrust off in another direction, is not flown again);
    /// under a rollout budget the last may have been cut short by it.
    pub rollouts: u32,
    /// Fixed steps the rollouts propagated (an adaptive cycle counts one): the work a rollout
    /// budget bounds.
    pub steps: u32,
}

/// The `index`-th candidate around the network's command `network` (0: itself), in dimension
/// `G`: the direction turned about the local normal (towards the radial), its normal component
/// kept.
pub fn candidate<G: Dimension>(network: &G::Command, index: usize) -> Option<G::Command> {
    let Some(k) = index.checked_sub(1) else {
        return Some(*network);
    };
    let &(throttle, turn_deg) = ALTERNATIVES.get(k)?;
    let turn = turn_deg.to_radians();
    let network_throttle = G::throttle(network);
    let u = match throttle {
        Throttle::Offset(d) => (network_throttle + d).clamp(0.0, 1.0),
        Throttle::Fixed(u) => u,
    };
    // Thrust off from the network has no direction: turn the along-track one.
    let [ar, at, an] = if network_throttle > 0.0 {
        G::direction(network)
    } else {
        [0.0, 1.0, 0.0]
    };
    let (s, c) = (libm::sin(turn), libm::cos(turn));
    Some(G::command_along(u, &[ar * c + at * s, at * c - ar * s, an]))
}

/// Whether two commands fly the same: equal, or both thrust off (whatever their directions).
fn flies_as<G: Dimension>(a: &G::Command, b: &G::Command) -> bool {
    a == b || (G::throttle(a) == 0.0 && G::throttle(b) == 0.0)
}

/// Flies `first` for one cycle from `navigation`, then the network, `cycles` cycles to the
/// `horizon` (the arrival `time_to_go` away, or earlier by the settings' margin), where the
/// arrival is judged.
#[allow(clippy::too_many_arguments)] // one rollout's inputs
fn rollout<const N: usize, const OUT: usize, A: Actor<N, OUT>, T: Aim<N, OUT>>(
    actor: &A,
    target: &T,
    spacecraft: &CanonicalSpacecraft,
    settings: &LookaheadSettings,
    navigation: &<T::Geometry as Dimension>::State,
    time_to_go: f64,
    horizon: f64,
    cycles: u32,
    first: &<T::Geometry as Dimension>::Command,
    steps_left: &mut u32,
) -> Result<Option<Prediction>, OutOfBudget> {
    let mut state = *navigation;
    let mut command = *first;
    for cycle in 0..cycles {
        let start = f64::from(cycle) * settings.cycle;
        let duration = cycle_duration(horizon, start, settings.cycle);
        if cycle > 0 {
            let Ok(next) = command_at(actor, target, &state, start, time_to_go - start) else {
                return Ok(None);
            };
            command = next;
        }
        let tolerances = settings.rollout_tolerances(duration, T::Geometry::periapsis(&state));
        // The budget's unit: a fixed step (an adaptive cycle counts one).
        let steps = tolerances.fixed_steps.max(1);
        *steps_left = steps_left.checked_sub(steps).ok_or(OutOfBudget)?;
        let Ok(next) = T::Geometry::propagate(&state, &command, spacecraft, duration, &tolerances) else {
            return Ok(None);
        };
        state = next;
    }
    let Ok(residuals) = target.residuals_after(&state, horizon) else {
        return Ok(None);
    };
    let mut arrival = Prediction {
        residuals,
        mass: T::Geometry::mass(&state),
        cost: 0.0,
    };
    arrival.cost = settings.cost(&arrival);
    Ok(arrival.cost.is_finite().then_some(arrival))
}

/// A rollout stopped where the cycle's rollout budget ran out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct OutOfBudget;

/// One guidance cycle with lookahead, in the plane or in three dimensions (the target's
/// [`Aim`]): the network's command at `navigation` (refused inputs and non-finite actions are
/// errors, as in [`crate::guidance`]), improved by the rollouts of the module documentation.
/// `time_to_go` is cut into cycles of `settings.cycle` from now (the last one shorter when it
/// is not a whole number of them); with more than `settings.max_cycles` cycles left, or none,
/// or a `rollout_budget` smaller than the cycles left, the network's command is returned
/// unexamined.
#[allow(clippy::type_complexity)]
pub fn lookahead_step<const N: usize, const OUT: usize, A: Actor<N, OUT>, T: Aim<N, OUT>>(
    actor: &A,
    navigation: &<T::Geometry as Dimension>::State,
    target: &T,
    time_to_go: f64,
    spacecraft: &CanonicalSpacecraft,
    settings: &LookaheadSettings,
) -> Result<Decision<<T::Geometry as Dimension>::Command>, GuidanceError> {
    let network = command_at(actor, target, navigation, 0.0, time_to_go)?;
    let mut decision = Decision {
        command: network,
        network,
        chosen: 0,
        predicted: None,
        network_predicted: None,
        rollouts: 0,
        steps: 0,
    };
    if settings.validate().is_err() {
        return Ok(decision);
    }
    let cycles = cycles_left(time_to_go, settings.cycle);
    if !(cycles >= 1.0 && cycles <= f64::from(settings.max_cycles)) {
        return Ok(decision);
    }
    // The rollouts' horizon: the arrival, or `arrival_margin` whole cycles before it.
    let margin = f64::from(settings.arrival_margin) * settings.cycle;
    let horizon = if cycles > f64::from(settings.arrival_margin) {
        time_to_go - margin
    } else {
        time_to_go
    };
    let cycles = cycles_left(horizon, settings.cycle) as u32;
    let planned = CanonicalSpacecraft {
        thrust: spacecraft.thrust * (1.0 - settings.thrust_margin),
        ..*spacecraft
    };
    let budget = match settings.rollout_budget {
        0 => u32::MAX,
        budget => budget,
    };
    let mut steps_left = budget;
    let mut candidates = [<T::Geometry as Dimension>::OFF; CANDIDATES];
    for index in 0..CANDIDATES {
        let Some(first) = candidate::<T::Geometry>(&network, index) else {
            break;
        };
        // A candidate that flies as an earlier one would repeat its rollout and cannot beat it
        // (ties go to the lower index): offsets that clamp to 0 or 1, the unturned offset 0,
        // every direction of thrust off.
        let repeated = candidates
            .iter()
            .take(index)
            .any(|c| flies_as::<T::Geometry>(c, &first));
        if let Some(slot) = candidates.get_mut(index) {
            *slot = first;
        }
        if repeated {
            continue;
        }
        // Not even one step a cycle left: no whole rollout fits.
        if steps_left < cycles {
            break;
        }
        decision.rollouts += 1;
        let arrival = rollout(
            actor,
            target,
            &planned,
            settings,
            navigation,
            time_to_go,
            horizon,
            cycles,
            &first,
            &mut steps_left,
        );
        let arrival = match arrival {
            Ok(Some(arrival)) => arrival,
            Ok(None) => continue,
            Err(OutOfBudget) => break,
        };
        if index == 0 {
            decision.network_predicted = Some(arrival);
        }
        if decision.predicted.is_none_or(|best| arrival.cost < best.cost) {
            decision.command = first;
            decision.chosen = index;
            decision.predicted = Some(arrival);
        }
    }
    decision.steps = budget - steps_left;
    Ok(decision)
}

/// An actor flown with lookahead: what flight software holds to call [`lookahead_step`] each
/// cycle (it implements [`crate::guidance::Guide`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lookahead<A> {
    /// The network.
    pub actor: A,
    /// The nominal spacecraft of the rollouts.
    pub spacecraft: CanonicalSpacecraft,
    /// What the rollouts weigh.
    pub settings: LookaheadSettings,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::{propagate, SpacecraftState};
    use crate::features::{transfer_features, transfer_residuals, ACTION_LEN};
    use crate::geometry::Planar;
    use crate::guidance::tests::{Broken, Tangential};
    use shared::orbit::OrbitShape;

    const ORBIT: OrbitShape = OrbitShape {
        a: 1.2,
        e: 0.0,
        omega: 0.0,
    };

    fn on_orbit() -> SpacecraftState {
        SpacecraftState::from_cartesian(&ORBIT.cartesian_at(0.3), 0.9)
    }

    fn spacecraft() -> CanonicalSpacecraft {
        shared::spacecraft::Spacecraft::MSR_ERO
            .canonical()
            .unwrap_or(CanonicalSpacecraft {
                thrust: f64::NAN,
                exhaust_speed: f64::NAN,
            })
    }

    /// In three dimensions a candidate turns the direction about the local normal: a unit
    /// direction with the network's normal component, the transverse one turned towards the
    /// radial; in the plane, with no normal component, the planar candidate bit for bit.
    #[test]
    fn spatial_candidates_turn_about_the_normal_and_match_the_plane() {
        use crate::geometry::Spatial;
        use crate::spatial::RtnCommand;
        let network = RtnCommand {
            throttle: 0.6,
            radial: 0.36,
            transverse: 0.8,
            normal: 0.48,
        };
        let flat = ThrustCommand {
            throttle: 0.6,
            alpha_r: 0.6,
            alpha_theta: 0.8,
        };
        let lifted_flat = RtnCommand {
            throttle: 0.6,
            radial: 0.6,
            transverse: 0.8,
            normal: 0.0,
        };
        for index in 0..CANDIDATES {
            let c = candidate::<Spatial>(&network, index).expect("in range");
            let norm = libm::sqrt(c.radial * c.radial + c.transverse * c.transverse + c.normal * c.normal);
            assert!(
                (norm - 1.0).abs() < 1e-15 && c.normal == network.normal,
                "{index}: {c:?}"
            );
            let planar = candidate::<Planar>(&flat, index).expect("in range");
            let lifted = candidate::<Spatial>(&lifted_flat, index).expect("in range");
            assert_eq!(
                (planar.throttle, planar.alpha_r, planar.alpha_theta),
                (lifted.throttle, lifted.radial, lifted.transverse)
            );
        }
        // Candidate 3: the network's throttle, turned 10 degrees towards the radial.
        assert_eq!(ALTERNATIVES[2], (Throttle::Offset(0.0), 10.0));
        let turned = candidate::<Spatial>(&network, 3).expect("in range");
        assert!(
            turned.radial > network.radial && turned.transverse < network.transverse,
            "{turned:?}"
        );
    }

    /// The fixed rollout steps predict a 14-day thrust arc of the flight propagator (its
    /// adaptive tolerances) to the accuracy [`rollout_tolerances`] states, planar and in three
    /// dimensions: one step on orbits at 1.2, 1 and 0.72 AU (to 1e-9 AU), 19 from the
    /// periapsis of an orbit that passes 0.1 AU from the Sun (to 2e-8 AU, a 1e-7 part of its
    /// radius); one more step always tightens it.
    #[test]
    fn fixed_rollout_steps_predict_the_flight_propagator() {
        use crate::spatial::{propagate_rtn, RtnCommand, SpatialCraftState};
        use shared::orbit::SpatialState;
        let sc = spacecraft();
        let command = ThrustCommand {
            throttle: 1.0,
            alpha_r: 0.6,
            alpha_theta: 0.8,
        };
        let adaptive = Tolerances::default();
        for (a, e, steps, scale) in [
            (1.2, 0.05, 1, 1.0),
            (1.0, 0.05, 1, 1.0),
            (0.72, 0.05, 1, 1.0),
            (0.39, 0.75, 19, 20.0),
        ] {
            let shape = OrbitShape { a, e, omega: 0.0 };
            let start = SpacecraftState::from_cartesian(&shape.cartesian_at(0.3), 0.9);
            let fixed = rollout_tolerances(1, &adaptive, STEP, Planar::periapsis(&start));
            assert_eq!(fixed.fixed_steps, steps, "a = {a}, e = {e}");
            let exact = propagate(&start, &command, &sc, STEP, &adaptive).expect("propagates");
            let gaps = [fixed.fixed_steps, fixed.fixed_steps + 1].map(|steps| {
                let end = propagate(&start, &command, &sc, STEP, &Tolerances::fixed(steps)).expect("propagates");
                let (e, x) = (end.cartesian(), exact.cartesian());
                let position = libm::hypot(e.r[0] - x.r[0], e.r[1] - x.r[1]);
                let velocity = libm::hypot(e.v[0] - x.v[0], e.v[1] - x.v[1]);
                (position, velocity, (end.m - exact.m).abs())
            });
            assert!(
                gaps[0].0 < 1e-9 * scale && gaps[0].1 < 1e-8 * scale && gaps[0].2 < 1e-14,
                "a = {a}: {gaps:?}"
            );
            assert!(gaps[1].0 < gaps[0].0 && gaps[1].1 < gaps[0].1, "a = {a}: {gaps:?}");
            // The same arc in three dimensions, out of the plane by 3 degrees.
            let c = shape.cartesian_at(0.3);
            let (ci, si) = (libm::cos(0.05), libm::sin(0.05));
            let craft = SpatialCraftState {
                orbit: SpatialState {
                    r: [c.r[0], c.r[1] * ci, c.r[1] * si],
                    v: [c.v[0], c.v[1] * ci, c.v[1] * si],
                },
                m: 0.9,
            };
            assert!((crate::geometry::Spatial::periapsis(&craft) / Planar::periapsis(&start) - 1.0).abs() < 1e-12);
            let rtn = RtnCommand {
                throttle: 1.0,
                radial: 0.6,
                transverse: 0.64,
                normal: 0.48,
            };
            let exact = propagate_rtn(&craft, &rtn, &sc, STEP, &adaptive).expect("propagates");
            let end = propagate_rtn(&craft, &rtn, &sc, STEP, &fixed).expect("propagates");
            let gap = |x: [f64; 3], y: [f64; 3]| libm::sqrt((0..3).map(|i| (x[i] - y[i]) * (x[i] - y[i])).sum());
            let (position, velocity) = (gap(end.orbit.r, exact.orbit.r), gap(end.orbit.v, exact.orbit.v));
            assert!(
                position < 1e-9 * scale && velocity < 1e-8 * scale,
                "a = {a}, 3D: {position:e} {velocity:e}"
            );
        }
        // The periapsis of a circular orbit is its radius; a radial or non-finite state takes
        // the most steps; 0 keeps the adaptive integrator; a larger setting is a floor.
        let circular = SpacecraftState::from_cartesian(&ORBIT.cartesian_at(0.0), 1.0);
        // (e = sqrt(1 + 2 E h^2) turns rounding near 0 into about 1e-8.)
        assert!((Planar::periapsis(&circular) - 1.2).abs() < 1e-7);
        let radial = SpacecraftState {
            v: [0.3, 0.0],
            ..SpacecraftState::from_cartesian(&ORBIT.cartesian_at(0.0), 1.0)
        };
        assert_eq!(
            rollout_tolerances(1, &adaptive, STEP, Planar::periapsis(&radial)).fixed_steps,
            MAX_ROLLOUT_STEPS
        );
        assert_eq!(
            rollout_tolerances(1, &adaptive, STEP, f64::NAN).fixed_steps,
            MAX_ROLLOUT_STEPS
        );
        assert_eq!(rollout_tolerances(0, &adaptive, STEP, 1.0), adaptive);
        assert_eq!(rollout_tolerances(5, &adaptive, STEP, 1.0).fixed_steps, 5);
    }

    #[test]
    fn candidates_are_unit_directions_with_throttles_in_range() {
        let network = ThrustCommand {
            throttle: 0.9,
            alpha_r: 0.6,
            alpha_theta: 0.8,
        };
        assert_eq!(candidate::<Planar>(&network, 0), Some(network));
        for index in 1..CANDIDATES {
            let c = candidate::<Planar>(&network, index).expect("in range");
            assert!(c.validate().is_ok(), "candidate {index}: {c:?}");
        }
        // Throttle + 0.25 clamps at full; a 10 degree turn keeps the angle to the network's.
        let index_of =
            |alternative: (Throttle, f64)| 1 + ALTERNATIVES.iter().position(|a| *a == alternative).expect("listed");
        let up = candidate::<Planar>(&network, index_of((Throttle::Offset(0.25), 10.0))).expect("in range");
        assert_eq!(up.throttle, 1.0);
        let dot = up.alpha_r * network.alpha_r + up.alpha_theta * network.alpha_theta;
        assert!((dot - 10f64.to_radians().cos()).abs() < 1e-12);
        assert_eq!(candidate::<Planar>(&network, CANDIDATES), None);
        // Off from the network: the along-track direction is turned.
        let off = candidate::<Planar>(&ThrustCommand::OFF, index_of((Throttle::Fixed(1.0), 0.0))).expect("in range");
        assert_eq!((off.throttle, off.alpha_r, off.alpha_theta), (1.0, 0.0, 1.0));
    }

    #[test]
    fn on_the_target_orbit_it_coasts_where_the_network_would_thrust_away() {
        // Three cycles from the arrival, already on the target orbit: a coast arrives exactly,
        // full along-track thrust raises the orbit. Only the thrust-off candidates can win.
        let settings = LookaheadSettings::default();
        let d = lookahead_step(&Tangential, &on_orbit(), &ORBIT, 3.0 * STEP, &spacecraft(), &settings)
            .expect("valid inputs");
        assert_eq!(d.network.throttle, 1.0);
        assert_eq!(d.command.throttle, 0.0, "{d:?}");
        let network = d.network_predicted.expect("the network's rollout flies");
        let chosen = d.predicted.expect("a rollout flies");
        // The network's rollout only thrusts; the chosen one coasts the first cycle and then the
        // network takes over: less propellant, smaller miss.
        assert!(chosen.cost < network.cost);
        assert!(chosen.mass > network.mass);
        let spent = spacecraft().thrust * 3.0 * STEP / spacecraft().exhaust_speed;
        assert!((on_orbit().m - network.mass - spent).abs() < 1e-9);
        // With a thrust margin the rollouts plan with less thrust: a fifth less propellant.
        let margin = LookaheadSettings {
            thrust_margin: 0.2,
            ..settings
        };
        let d =
            lookahead_step(&Tangential, &on_orbit(), &ORBIT, 3.0 * STEP, &spacecraft(), &margin).expect("valid inputs");
        let planned = d.network_predicted.expect("flies");
        assert!((on_orbit().m - planned.mass - 0.8 * spent).abs() < 1e-9, "{planned:?}");
        // The network's miss is its own flight's: one more check against a plain propagation.
        let mut x = on_orbit();
        for _ in 0..3 {
            x = propagate(
                &x,
                &ThrustCommand {
                    throttle: 1.0,
                    alpha_r: 0.0,
                    alpha_theta: 1.0,
                },
                &spacecraft(),
                STEP,
                &settings.rollout_tolerances(STEP, Planar::periapsis(&x)),
            )
            .expect("propagates");
        }
        let res = transfer_residuals(&transfer_features(&x, &ORBIT, 0.0).expect("features"));
        assert_eq!(network.residuals, res);
    }

    /// Candidates that fly as an earlier one are not flown, and the decision is the one over
    /// all 21 rollouts (the lowest cost, the lowest index of equal costs): 21 distinct
    /// candidates at half throttle, 16 near full (the +0.25 offsets clamp to full throttle), 11
    /// at thrust off (every zero throttle coasts alike).
    #[test]
    fn candidates_that_fly_as_an_earlier_one_are_not_flown_again() {
        struct Constant(f32);
        impl<const N: usize> Actor<N> for Constant {
            fn act(&self, _: &[f32; N]) -> [f32; ACTION_LEN] {
                [self.0, 0.3, 0.9]
            }
        }
        let (sc, settings) = (spacecraft(), LookaheadSettings::default());
        for (action, distinct) in [(0.0f32, 21), (0.8, 16), (-1.0, 11)] {
            let actor = Constant(action);
            let time_to_go = 3.0 * STEP;
            let d = lookahead_step(&actor, &on_orbit(), &ORBIT, time_to_go, &sc, &settings).expect("valid inputs");
            assert_eq!(d.rollouts, distinct, "action {action}");
            let mut best: Option<(usize, Prediction)> = None;
            for index in 0..CANDIDATES {
                let first = candidate::<Planar>(&d.network, index).expect("in range");
                let arrival = rollout(
                    &actor,
                    &ORBIT,
                    &sc,
                    &settings,
                    &on_orbit(),
                    time_to_go,
                    time_to_go,
                    3,
                    &first,
                    &mut { u32::MAX },
                )
                .expect("within budget")
                .expect("flies");
                if best.is_none_or(|(_, b)| arrival.cost < b.cost) {
                    best = Some((index, arrival));
                }
            }
            let (chosen, predicted) = best.expect("a candidate");
            assert_eq!((d.chosen, d.predicted), (chosen, Some(predicted)), "action {action}");
        }
    }

    /// A rollout budget flies the first candidates whose whole rollouts fit, `budget / cycles`
    /// of them, and decides among those alone as a search over that prefix would; a budget
    /// smaller than the cycles left flies the network's command unexamined, 0 flies them all.
    #[test]
    fn a_rollout_budget_flies_the_first_candidates_that_fit() {
        struct Constant;
        impl<const N: usize> Actor<N> for Constant {
            fn act(&self, _: &[f32; N]) -> [f32; ACTION_LEN] {
                [0.0, 0.3, 0.9]
            }
        }
        let sc = spacecraft();
        let time_to_go = 3.0 * STEP;
        let unlimited = LookaheadSettings::default();
        let predictions: [Prediction; CANDIDATES] = core::array::from_fn(|index| {
            let first = candidate::<Planar>(
                &command_at(&Constant, &ORBIT, &on_orbit(), 0.0, time_to_go).expect("acts"),
                index,
            )
            .expect("in range");
            rollout(
                &Constant,
                &ORBIT,
                &sc,
                &unlimited,
                &on_orbit(),
                time_to_go,
                time_to_go,
                3,
                &first,
                &mut { u32::MAX },
            )
            .expect("within budget")
            .expect("flies")
        });
        // The budget's candidates must decide differently from the whole set somewhere.
        let mut decided_otherwise = false;
        for (budget, flown) in [
            (0, 21),
            (2, 0),
            (3, 1),
            (8, 2),
            (9, 3),
            (20, 6),
            (62, 20),
            (63, 21),
            (1000, 21),
        ] {
            let settings = LookaheadSettings {
                rollout_budget: budget,
                ..unlimited
            };
            let d = lookahead_step(&Constant, &on_orbit(), &ORBIT, time_to_go, &sc, &settings).expect("valid inputs");
            assert_eq!(d.rollouts, flown, "budget {budget}");
            let best = predictions.iter().take(flown as usize).enumerate().fold(
                None,
                |best: Option<(usize, Prediction)>, (i, p)| match best {
                    Some((_, b)) if b.cost <= p.cost => best,
                    _ => Some((i, *p)),
                },
            );
            match best {
                Some((chosen, predicted)) => {
                    assert_eq!((d.chosen, d.predicted), (chosen, Some(predicted)), "budget {budget}");
                    let whole = candidate::<Planar>(&d.network, chosen).expect("in range");
                    assert_eq!(d.command, whole);
                }
                None => assert_eq!((d.command, d.chosen, d.predicted), (d.network, 0, None)),
            }
            decided_otherwise |= flown > 0 && d.chosen != predictions_best(&predictions);
        }
        assert!(decided_otherwise, "every budget chose what the whole set chose");
    }

    /// Near the Sun a rollout cycle takes several steps, and the budget counts each: on an
    /// orbit at 0.3 AU (about four steps a 14-day cycle) the candidates flown whole are those
    /// whose steps, summed in order, fit the budget, and the decision is among them alone.
    #[test]
    fn near_the_sun_the_budget_counts_every_step() {
        struct Constant;
        impl<const N: usize> Actor<N> for Constant {
            fn act(&self, _: &[f32; N]) -> [f32; ACTION_LEN] {
                [0.0, 0.3, 0.9]
            }
        }
        const LOW: OrbitShape = OrbitShape {
            a: 0.3,
            e: 0.0,
            omega: 0.0,
        };
        let start = SpacecraftState::from_cartesian(&LOW.cartesian_at(0.0), 1.0);
        let (sc, unlimited) = (spacecraft(), LookaheadSettings::default());
        let time_to_go = 3.0 * STEP;
        let network = command_at(&Constant, &ORBIT, &start, 0.0, time_to_go).expect("acts");
        // Each candidate's steps and prediction, flown alone.
        let flown: [(u32, Prediction); CANDIDATES] = core::array::from_fn(|index| {
            let first = candidate::<Planar>(&network, index).expect("in range");
            let mut steps_left = u32::MAX;
            let p = rollout(
                &Constant,
                &ORBIT,
                &sc,
                &unlimited,
                &start,
                time_to_go,
                time_to_go,
                3,
                &first,
                &mut steps_left,
            )
            .expect("within budget")
            .expect("flies");
            (u32::MAX - steps_left, p)
        });
        assert!(flown.iter().all(|(steps, _)| *steps >= 9), "{:?}", flown.map(|f| f.0));
        let mut decided_otherwise = false;
        for budget in [flown[0].0 - 1, flown[0].0, 40, 100, 150] {
            let settings = LookaheadSettings {
                rollout_budget: budget,
                ..unlimited
            };
            let d = lookahead_step(&Constant, &start, &ORBIT, time_to_go, &sc, &settings).expect("valid inputs");
            // The candidates whose steps fit, in order.
            let mut used = 0;
            let whole = flown
                .iter()
                .take_while(|(steps, _)| {
                    used += steps;
                    used <= budget
                })
                .count();
            // The steps reported: those of the whole rollouts, and of a cut one's cycles that fit.
            let whole_steps: u32 = flown.iter().take(whole).map(|f| f.0).sum();
            assert!(
                whole_steps <= d.steps && d.steps <= budget,
                "budget {budget}: {} steps",
                d.steps
            );
            match whole {
                0 => assert_eq!((d.command, d.predicted), (d.network, None), "budget {budget}"),
                k => {
                    let best = predictions_best(&flown.map(|f| f.1)[..k]);
                    assert_eq!((d.chosen, d.predicted), (best, Some(flown[best].1)), "budget {budget}");
                    decided_otherwise |= best != predictions_best(&flown.map(|f| f.1));
                }
            }
        }
        assert!(decided_otherwise, "every budget chose what the whole set chose");
    }

    /// The index of the lowest cost (the lowest index of equal costs).
    fn predictions_best(predictions: &[Prediction]) -> usize {
        (0..predictions.len()).fold(0, |best, i| {
            if predictions[i].cost < predictions[best].cost {
                i
            } else {
                best
            }
        })
    }

    /// With an arrival margin the rollouts are judged that many cycles early: a network that
    /// ignores its inputs predicts, 3.5 cycles out with a margin of 1, what it predicts 2.5
    /// cycles out without one, bit for bit (the same commands and cycles, the partial one last);
    /// with no more cycles left than the margin, the arrival itself.
    #[test]
    fn an_arrival_margin_judges_the_rollouts_that_many_cycles_early() {
        let sc = spacecraft();
        let plain = LookaheadSettings::default();
        let early = LookaheadSettings {
            arrival_margin: 1,
            ..plain
        };
        let decide = |time_to_go: f64, settings: &LookaheadSettings| {
            lookahead_step(&Tangential, &on_orbit(), &ORBIT, time_to_go, &sc, settings).expect("valid inputs")
        };
        let (judged_early, judged_there) = (decide(3.5 * STEP, &early), decide(2.5 * STEP, &plain));
        assert!(judged_early.network_predicted.is_some());
        assert_eq!(judged_early.network_predicted, judged_there.network_predicted);
        assert_eq!(judged_early.predicted, judged_there.predicted);
        assert_ne!(judged_early.predicted, decide(3.5 * STEP, &plain).predicted);
        for time_to_go in [0.5 * STEP, STEP] {
            assert_eq!(decide(time_to_go, &early), decide(time_to_go, &plain));
        }
    }

    #[test]
    fn the_network_wins_ties_and_a_partial_last_cycle_is_flown_to_the_arrival() {
        // A coasting network on the target orbit arrives exactly: nothing beats it.
        struct Coast;
        impl<const N: usize> Actor<N> for Coast {
            fn act(&self, _: &[f32; N]) -> [f32; ACTION_LEN] {
                [-1.0, 0.0, 1.0]
            }
        }
        let d = lookahead_step(
            &Coast,
            &on_orbit(),
            &ORBIT,
            2.5 * STEP,
            &spacecraft(),
            &LookaheadSettings::default(),
        )
        .expect("valid inputs");
        assert_eq!(d.chosen, 0);
        let p = d.predicted.expect("flies");
        assert!(p.residuals.position < 1e-9 && p.residuals.velocity < 1e-9, "{p:?}");
        assert_eq!(p.mass, on_orbit().m);
        // The floor: an exact arrival costs the floor, no less, plus the propellant spent before
        // (m = 0.9 of m0 at 5 goal units per m0).
        let s = LookaheadSettings::default();
        assert!(
            (p.cost - (s.accuracy_floor + s.fuel_weight * 0.1)).abs() < 1e-12,
            "{p:?}"
        );
    }

    #[test]
    fn bad_inputs_are_errors_and_unusable_settings_fly_the_network() {
        let sc = spacecraft();
        let ok = LookaheadSettings::default();
        let nan = SpacecraftState {
            r: [f64::NAN, 0.0],
            ..on_orbit()
        };
        assert!(matches!(
            lookahead_step(&Tangential, &nan, &ORBIT, STEP, &sc, &ok),
            Err(GuidanceError::Input(_))
        ));
        assert_eq!(
            lookahead_step(&Broken, &on_orbit(), &ORBIT, STEP, &sc, &ok),
            Err(GuidanceError::NonFiniteAction)
        );
        for bad in [
            LookaheadSettings {
                goal_position: 0.0,
                ..ok
            },
            LookaheadSettings {
                accuracy_floor: f64::NAN,
                ..ok
            },
            LookaheadSettings {
                fuel_weight: -1.0,
                ..ok
            },
        ] {
            assert_eq!(bad.validate(), Err(InvalidSettings));
            let d = lookahead_step(&Tangential, &on_orbit(), &ORBIT, STEP, &sc, &bad).expect("flies the network");
            assert_eq!((d.command, d.chosen, d.predicted), (d.network, 0, None));
        }
        for margin in [-0.1, 1.0, f64::NAN] {
            assert_eq!(
                LookaheadSettings {
                    thrust_margin: margin,
                    ..ok
                }
                .validate(),
                Err(InvalidSettings)
            );
        }
        // Too far to look, or nothing left to look at: the network's command.
        let short = LookaheadSettings { max_cycles: 2, ..ok };
        let d = lookahead_step(&Tangential, &on_orbit(), &ORBIT, 3.0 * STEP, &sc, &short).expect("flies");
        assert_eq!(d.predicted, None);
        let d = lookahead_step(&Tangential, &on_orbit(), &ORBIT, 0.0, &sc, &ok).expect("flies");
        assert_eq!(d.predicted, None);
        // A spacecraft the propagator refuses: no rollout flies, the network's command stands.
        let broken = CanonicalSpacecraft { thrust: f64::NAN, ..sc };
        let d = lookahead_step(&Tangential, &on_orbit(), &ORBIT, 3.0 * STEP, &broken, &ok).expect("flies");
        assert_eq!((d.command, d.predicted), (d.network, None));
    }

    #[test]
    fn a_rendezvous_body_is_coasted_along_the_rollout() {
        // The spacecraft flies in formation with the body: coasting keeps the miss at zero.
        let body = ORBIT.cartesian_at(1.0);
        let ship = SpacecraftState::from_cartesian(&body, 0.8);
        let d = lookahead_step(
            &Tangential,
            &ship,
            &body,
            4.0 * STEP,
            &spacecraft(),
            &LookaheadSettings::default(),
        )
        .expect("valid inputs");
        assert_eq!(d.command.throttle, 0.0);
        let network = d.network_predicted.expect("flies");
        assert!(network.residuals.position > 0.01, "{network:?}");
    }
}
