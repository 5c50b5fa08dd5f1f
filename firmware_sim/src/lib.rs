//! Software-in-the-loop flight: the onboard guidance step flying against a plant.
//!
//! Today the plant is the onboard propagator itself, stepped once per 14-day guidance cycle
//! with the command held in the polar frame (the MDP's zero-order hold). Dispersions
//! (navigation noise, thrust and pointing errors, missed-thrust windows), a plant propagated
//! independently of the guidance cycle and the Cortex-M4 image under QEMU come with the export
//! work (issue 5).

use onboard::dynamics::{propagate, PropagationError, SpacecraftState, ThrustCommand};
use onboard::features::{
    reward, transfer_features, transfer_residuals, FeatureError, Residuals, RewardWeights, TRANSFER_FEATURES,
};
use onboard::guidance::{transfer_step, Actor, GuidanceError};
use onboard::integrator::Tolerances;
use shared::scenario::{ProblemKind, Scenario, ScenarioError};
use shared::spacecraft::CanonicalSpacecraft;
use shared::units::STEP;

/// One guidance cycle as flown.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightStep {
    /// Step index k (0-based): the command was computed at t = k * STEP.
    pub index: u32,
    /// Features the actor saw at the start of the step.
    pub features: [f64; TRANSFER_FEATURES],
    /// Command applied over the step (thrust off when guidance refused its input).
    pub command: ThrustCommand,
    /// Why guidance produced no command, if it did not.
    pub guidance_error: Option<GuidanceError>,
    /// State at the end of the step.
    pub state: SpacecraftState,
    /// Reward at the end of the step (SPEC section 5).
    pub reward: f64,
    /// Residuals against the target at the end of the step.
    pub residuals: Residuals,
}

/// A closed-loop flight.
#[derive(Debug, Clone, PartialEq)]
pub struct Flight {
    pub initial: SpacecraftState,
    pub steps: Vec<FlightStep>,
}

impl Flight {
    pub fn total_reward(&self) -> f64 {
        self.steps.iter().map(|s| s.reward).sum()
    }

    pub fn final_state(&self) -> SpacecraftState {
        self.steps.last().map_or(self.initial, |s| s.state)
    }

    pub fn final_residuals(&self) -> Option<Residuals> {
        self.steps.last().map(|s| s.residuals)
    }
}

/// Why a flight could not be flown.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SilError {
    Scenario(ScenarioError),
    /// This loop flies transfers; rendezvous comes with its environment.
    NotATransfer,
    /// The plant could not be propagated (for example the tank ran dry) at step `index`.
    Plant {
        index: u32,
        error: PropagationError,
    },
    /// The plant state left the feature domain (for example r = 0) at step `index`.
    Features {
        index: u32,
        error: FeatureError,
    },
}

impl core::fmt::Display for SilError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Scenario(e) => write!(f, "invalid scenario: {e}"),
            Self::NotATransfer => f.write_str("only transfer scenarios can be flown so far"),
            Self::Plant { index, error } => write!(f, "plant propagation failed at step {index}: {error}"),
            Self::Features { index, error } => write!(f, "plant state unusable at step {index}: {error}"),
        }
    }
}

impl std::error::Error for SilError {}

/// Flies a transfer scenario closed-loop: at each 14-day cycle the guidance step computes a
/// command from the current state, the plant propagates one step under it.
pub fn fly_transfer<A: Actor<TRANSFER_FEATURES>>(
    actor: &A,
    scenario: &Scenario,
    spacecraft: &CanonicalSpacecraft,
    tolerances: &Tolerances,
    weights: &RewardWeights,
) -> Result<Flight, SilError> {
    scenario.validate().map_err(SilError::Scenario)?;
    if scenario.problem != ProblemKind::Transfer {
        return Err(SilError::NotATransfer);
    }
    let initial = SpacecraftState::from_cartesian(&scenario.initial.cartesian(), 1.0);
    let mut state = initial;
    let mut steps = Vec::with_capacity(scenario.steps as usize);
    for index in 0..scenario.steps {
        let time_to_go = f64::from(scenario.steps - index) * STEP;
        let features = transfer_features(&state, &scenario.target, time_to_go)
            .map_err(|error| SilError::Features { index, error })?;
        let (command, guidance_error) = match transfer_step(actor, &state, &scenario.target, time_to_go) {
            Ok(c) => (c, None),
            Err(e) => (ThrustCommand::OFF, Some(e)),
        };
        state = propagate(&state, &command, spacecraft, STEP, tolerances)
            .map_err(|error| SilError::Plant { index, error })?;
        let after = transfer_features(&state, &scenario.target, time_to_go - STEP)
            .map_err(|error| SilError::Features { index, error })?;
        let residuals = transfer_residuals(&after);
        steps.push(FlightStep {
            index,
            features,
            command,
            guidance_error,
            state,
            reward: reward(&residuals, command.throttle, weights),
            residuals,
        });
    }
    Ok(Flight { initial, steps })
}

/// A hand-tuned feedback law for demonstrations and as a baseline for learned policies: thrust
/// along the velocity error to the target-orbit proxy, plus corrections for the radius and
/// semi-major-axis gaps, throttled up with the total error above a dead band. It reads only the
/// features, so it flies through exactly the same guidance path as a network. Far from optimal
/// in propellant: it is what a learned policy must beat.
#[derive(Debug, Clone, Copy)]
pub struct ProxyTracking {
    pub target_a: f64,
}

impl Actor<TRANSFER_FEATURES> for ProxyTracking {
    fn act(&self, f: &[f32; TRANSFER_FEATURES]) -> [f32; 3] {
        let [r, _, _, v_r, v_theta, _, r_t, v_r_t, v_theta_t, _] = f.map(f64::from);
        let a = 1.0 / (2.0 / r - (v_r * v_r + v_theta * v_theta));
        let gap = if a > 0.0 { self.target_a - a } else { self.target_a };
        let error = gap.abs() + (r_t - r).abs() + (v_r_t - v_r).hypot(v_theta_t - v_theta);
        let throttle = ((error - 0.02) / 0.2).clamp(0.0, 1.0);
        let (radial, along) = (v_r_t - v_r + 0.5 * (r_t - r), v_theta_t - v_theta + 0.5 * gap);
        let norm = radial.hypot(along).max(1e-9);
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
    use onboard::kepler::coast;
    use shared::orbit::{OrbitElements, OrbitShape};
    use shared::spacecraft::Spacecraft;

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
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let s = scenario(1.52);
        let flight = fly_transfer(&Off, &s, &sc, &Tolerances::default(), &RewardWeights::default()).unwrap();
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
        let flight = fly_transfer(&law, &s, &sc, &Tolerances::default(), &RewardWeights::default()).unwrap();
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
        let off = fly_transfer(&Off, &s, &sc, &Tolerances::default(), &RewardWeights::default()).unwrap();
        assert!(flight.total_reward() > off.total_reward());
    }
}
