//! The rollout lookahead (`onboard::lookahead`) flown with the shipped networks in the SIL loop
//! without dispersions, checked against the rollout algorithm's own guarantees: its predictions
//! are the flight, its predicted cost never rises along a flight, and it arrives at a cost no
//! higher than the network flown alone. The guarantees are exact where the plant is the
//! rollouts' model; the plant here is the flight propagator (adaptive DOP853), which the
//! rollouts' fixed steps predict to about 1e-9 a cycle (`onboard::lookahead`'s unit test), so
//! each holds to 1e-4 goal units (a 50-cycle hard transfer closed through the network drifts
//! 1e-5): far below any difference the cost makes between candidates.

use firmware_sim::{fly, Controller, Flight, FlightSetup, PlanarProblem, Rendezvous, Transfer};
use onboard::guidance::{Actor, TargetFeatures};
use onboard::lookahead::{lookahead_step, Lookahead, LookaheadSettings, Prediction};
use shared::blob::AlignedBlob;
use shared::scenario::{Scenario, ScenarioKind};
use shared::spacecraft::{CanonicalSpacecraft, Spacecraft};
use shared::units::STEP;

/// How far a prediction may stand from the flight (goal units and m0): the rollouts' fixed
/// steps against the flight propagator.
const SLACK: f64 = 1e-4;

fn spacecraft() -> CanonicalSpacecraft {
    Spacecraft::MSR_ERO.canonical().unwrap()
}

/// The network's arrival as the lookahead's cost sees it.
fn arrival<const N: usize>(flight: &Flight<N>) -> Prediction {
    let residuals = flight.final_residuals().unwrap();
    let mut p = Prediction {
        residuals,
        mass: flight.final_state().m,
        cost: 0.0,
    };
    p.cost = LookaheadSettings::default().cost(&p);
    p
}

/// Flies `scenario` with the network alone and with lookahead, and checks the flight with
/// lookahead cycle by cycle, its predictions to within `slack`. Returns the
/// two arrivals.
fn check<const N: usize, P: PlanarProblem<N>>(
    problem: P,
    actor: &impl Actor<N>,
    scenario: &Scenario,
    slack: f64,
) -> (Prediction, Prediction)
where
    P::Target: TargetFeatures<N>,
{
    let sc = spacecraft();
    let settings = LookaheadSettings::default();
    let setup = FlightSetup::nominal(sc);
    let alone = fly(problem, actor, scenario, &setup, 0).unwrap();
    let guide = Lookahead {
        actor,
        spacecraft: sc,
        settings,
    };
    let looked = fly(problem, &guide, scenario, &setup, 0).unwrap();
    assert_eq!(looked.steps.len(), scenario.steps as usize);
    let mut previous = f64::INFINITY;
    for step in &looked.steps {
        let target = P::target(scenario, step.index).unwrap();
        let time_to_go = f64::from(scenario.steps - step.index) * STEP;
        let d = lookahead_step(actor, &step.navigation, &target, time_to_go, &sc, &settings).unwrap();
        assert_eq!(d.command, step.command, "cycle {}", step.index);
        let near = |a: &Prediction, b: &Prediction| {
            let d = [
                a.residuals.position - b.residuals.position,
                a.residuals.velocity - b.residuals.velocity,
                a.mass - b.mass,
                a.cost - b.cost,
            ];
            d.iter().all(|x| x.abs() <= slack)
        };
        if step.index == 0 {
            // The network's rollout from the start is the network's own flight.
            let network = d.network_predicted.unwrap();
            assert!(
                near(&network, &arrival(&alone)),
                "{network:?} against {:?}",
                arrival(&alone)
            );
        }
        let predicted = d.predicted.unwrap();
        // The chosen rollout's continuation is the next cycle's network candidate.
        assert!(
            predicted.cost <= previous + slack,
            "cycle {}: {} after {previous}",
            step.index,
            predicted.cost
        );
        previous = predicted.cost;
        if step.index + 1 == scenario.steps {
            assert!(
                near(&predicted, &arrival(&looked)),
                "the last prediction is the arrival"
            );
        }
    }
    (arrival(&alone), arrival(&looked))
}

#[test]
fn on_hard_transfers_the_lookahead_predicts_its_flight_and_never_arrives_worse_than_the_network() {
    let blob = AlignedBlob::new(include_bytes!("../../models/transfer-hard/transfer-f32.blob"));
    let controller = Controller::load_transfer(blob.bytes());
    assert!(matches!(controller, Controller::Network(_)));
    // Draws of the shipped card's Monte Carlo stream: 1 and 23 the network misses (0.019 and
    // 0.042 AU off, 0.031 and 0.049 in velocity), 0 and 3 it flies within the goal.
    let (mut alone_within, mut looked_within) = (0, 0);
    for index in [0, 1, 3, 23] {
        let scenario = ScenarioKind::TransferHard.draw(2_000_003, index);
        let (alone, looked) = check(Transfer, &controller, &scenario, SLACK);
        assert!(
            looked.cost <= alone.cost + SLACK,
            "draw {index}: {looked:?} against {alone:?}"
        );
        let within = |p: &Prediction| p.residuals.position < 0.01 && p.residuals.velocity < 0.01;
        alone_within += usize::from(within(&alone));
        looked_within += usize::from(within(&looked));
    }
    assert_eq!(alone_within, 2);
    assert_eq!(looked_within, 4);
}

#[test]
fn on_rendezvous_the_body_is_coasted_in_the_rollouts_as_the_flight_meets_it() {
    let blob = AlignedBlob::new(include_bytes!("../../models/rendezvous-circular/rendezvous-f32.blob"));
    let controller = Controller::load_rendezvous(blob.bytes());
    assert!(matches!(controller, Controller::Network(_)));
    for index in [0, 1] {
        let scenario = ScenarioKind::RendezvousCircular.draw(2_000_003, index);
        // The rollouts also coast the body from its state at each cycle, the flight from its
        // epoch: the two ephemerides differ in the last bits.
        let (alone, looked) = check(Rendezvous, &controller, &scenario, SLACK);
        assert!(
            looked.cost <= alone.cost + SLACK,
            "draw {index}: {looked:?} against {alone:?}"
        );
    }
}

/// In three dimensions the same rollouts (one implementation through `onboard::geometry`): the
/// shipped inclined transfer network on its family (the target plane inclined up to 5 degrees,
/// any node), flown nominally with lookahead, arrives at a cost no higher than flown alone, draw
/// by draw (measured: lower on all three, 0.5-1.1 % of the initial mass saved within the floor).
#[test]
fn in_three_dimensions_the_lookahead_never_arrives_worse_than_the_network() {
    use firmware_sim::{Dimension, Spatial, Transfer3};
    use onboard::features::{ACTION3_LEN, TRANSFER3_FEATURES};
    use shared::mission::SpatialFamily;
    use shared::scenario::Range;
    let blob = AlignedBlob::new(include_bytes!(
        "../../models/transfer-circular-inclined/transfer-f32.blob"
    ));
    let network = Controller::<TRANSFER3_FEATURES, ACTION3_LEN>::load::<Transfer3>(blob.bytes());
    assert!(matches!(network, Controller::Network(_)));
    let inclination = Range {
        lo: 0.0,
        hi: 5f64.to_radians(),
    };
    let family = SpatialFamily::inclined_target(ScenarioKind::TransferCircular.family(), inclination);
    let sc = spacecraft();
    let setup = FlightSetup::nominal(sc);
    let guide = Lookahead {
        actor: &network,
        spacecraft: sc,
        settings: LookaheadSettings::default(),
    };
    let cost = |flight: &Flight<TRANSFER3_FEATURES, Spatial>| {
        let mut p = Prediction {
            residuals: flight.final_residuals().unwrap(),
            mass: Spatial::mass(&flight.final_state()),
            cost: 0.0,
        };
        p.cost = LookaheadSettings::default().cost(&p);
        p
    };
    let mut lower = 0;
    for index in 0..3 {
        let scenario = family.draw(2_000_003, index);
        let alone = cost(&fly(Transfer3, &network, &scenario, &setup, 0).unwrap());
        let looked = cost(&fly(Transfer3, &guide, &scenario, &setup, 0).unwrap());
        assert!(
            looked.cost <= alone.cost + SLACK,
            "draw {index}: {looked:?} against {alone:?}"
        );
        lower += usize::from(looked.cost < alone.cost - 0.01);
    }
    assert!(lower >= 2, "the lookahead chose the network's commands throughout");
}
