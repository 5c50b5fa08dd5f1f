//! Three-dimensional environment tests: against the planar environment (one plane, the planar
//! problem turned), the rocket equation, the energy invariant of thrust normal to the orbit,
//! and the refusals.

use super::*;
use shared::orbit::{cross3, norm3, OrbitPlane};
use shared::spacecraft::Spacecraft;
use shared::units::{G0_M_S2, STEP_SECONDS};

/// The planar environment tests' scenarios: an eccentric transfer, and the rendezvous with it.
fn planar_scenario(problem: ProblemKind) -> Scenario {
    match problem {
        ProblemKind::Transfer => super::tests::transfer_scenario(),
        ProblemKind::Rendezvous => super::tests::rendezvous_scenario(),
    }
}

/// Both orbits in one plane inclined 0.7 rad with its node at 2.1 rad.
fn turned(scenario: Scenario) -> SpatialScenario {
    let plane = OrbitPlane {
        inclination: 0.7,
        raan: 2.1,
    };
    SpatialScenario {
        scenario,
        initial_plane: plane,
        target_plane: plane,
    }
}

/// Throttle and in-plane direction of each cycle: thrust along track, then away from the Sun,
/// a coast, and back along track at half throttle.
fn planar_actions(steps: u32) -> Vec<[f32; 3]> {
    (0..steps)
        .map(|k| match k % 4 {
            0 => [1.0, 0.0, 1.0],
            1 => [0.6, 0.8, 0.3],
            2 => [-1.0, 0.0, 1.0],
            _ => [0.0, -0.2, 1.0],
        })
        .collect()
}

/// In one plane the three-dimensional MDP is the planar MDP turned: the same rewards,
/// residuals and masses under the same in-plane commands (normal component 0), for the
/// transfer and the rendezvous, in the reference plane and in an inclined one. The 3D state
/// turned back into the plane is the planar state (two integrators of other state vectors:
/// 1e-9).
#[test]
fn in_one_plane_the_spatial_mdp_is_the_planar_mdp_turned() {
    let config = EnvConfig::default();
    for problem in [ProblemKind::Transfer, ProblemKind::Rendezvous] {
        let planar = planar_scenario(problem);
        for spatial in [SpatialScenario::planar(planar), turned(planar)] {
            let plane = spatial.initial_plane;
            let actions = planar_actions(planar.steps);
            let spatial_actions = spatial_actions(&actions);
            let (flat, space) = match problem {
                ProblemKind::Transfer => (
                    infos(fly::<TransferEnv>(&config, &planar, &actions)),
                    infos(fly::<Transfer3Env>(&config, &spatial, &spatial_actions)),
                ),
                ProblemKind::Rendezvous => (
                    infos(fly::<RendezvousEnv>(&config, &planar, &actions)),
                    infos(fly::<Rendezvous3Env>(&config, &spatial, &spatial_actions)),
                ),
            };
            assert_eq!(flat.len(), planar.steps as usize);
            assert_eq!(space.len(), flat.len());
            for (k, ((reward_a, done_a, a), (reward_b, done_b, b))) in flat.iter().zip(&space).enumerate() {
                let tol = 1e-9;
                assert!((reward_a - reward_b).abs() < tol, "{problem:?} step {k}: rewards");
                assert!((a.residuals.position - b.residuals.position).abs() < tol);
                assert!((a.residuals.velocity - b.residuals.velocity).abs() < tol);
                assert!((a.mass - b.mass).abs() < 1e-12);
                assert_eq!(a.throttle, b.throttle);
                assert_eq!(done_a, done_b);
                let orbit = b.state.orbit;
                let (r, v) = (plane.to_plane(orbit.r), plane.to_plane(orbit.v));
                for i in 0..2 {
                    assert!((r[i] - a.state.r[i]).abs() < tol, "{problem:?} step {k}: r");
                    assert!((v[i] - a.state.v[i]).abs() < tol, "{problem:?} step {k}: v");
                }
                // Still in the plane: the angular momentum along the plane's normal.
                let h = cross3(&orbit.r, &orbit.v);
                let (i, o) = (plane.inclination, plane.raan);
                let n = [i.sin() * o.sin(), -i.sin() * o.cos(), i.cos()];
                assert!(
                    norm3(&cross3(&h, &n)) < 1e-12 * norm3(&h),
                    "{problem:?} step {k}: left the plane"
                );
            }
        }
    }
}

/// The reward, done flag and details of each step.
fn infos<O, G: Geometry>(steps: Vec<Step<O, G>>) -> Vec<(f64, bool, StepInfo<G>)> {
    steps.into_iter().map(|s| (s.reward, s.done, s.info)).collect()
}

fn spatial_actions(planar: &[[f32; 3]]) -> Vec<[f32; 4]> {
    planar.iter().map(|a| [a[0], a[1], a[2], 0.0]).collect()
}

fn fly<E: Environment>(
    config: &EnvConfig,
    scenario: &ScenarioOf<E::Geometry>,
    actions: &[ActionOf<E::Geometry>],
) -> Vec<Step<E::Obs, E::Geometry>> {
    let mut env = E::new(config).unwrap();
    env.reset(scenario).unwrap();
    actions.iter().map(|a| env.step(a).unwrap()).collect()
}

/// Thrust along the orbit normal does no work (it is perpendicular to the velocity at every
/// instant), so the specific energy stays while the plane turns; the mass falls as the rocket
/// equation says, and the inclination grows.
#[test]
fn normal_thrust_turns_the_plane_at_constant_energy_and_burns_by_the_rocket_equation() {
    let spatial = SpatialScenario::planar(planar_scenario(ProblemKind::Transfer));
    let mut env = Transfer3Env::new(&EnvConfig::default()).unwrap();
    env.reset(&spatial).unwrap();
    let start = env.state().unwrap();
    let energy0 = start.orbit.energy();
    let sc = Spacecraft::MSR_ERO;
    let mdot_kg_s = sc.max_thrust_n / (sc.isp_s * G0_M_S2);
    let mut last_tilt = 0.0;
    for k in 1..=3u32 {
        let step = env.step(&[1.0, 0.0, 0.0, 1.0]).unwrap();
        let s = step.info.state;
        assert!(
            (s.orbit.energy() - energy0).abs() < 1e-9,
            "step {k}: energy {} vs {energy0}",
            s.orbit.energy()
        );
        let expected_kg = sc.initial_mass_kg - mdot_kg_s * f64::from(k) * STEP_SECONDS;
        assert!((s.m * sc.initial_mass_kg - expected_kg).abs() < 1e-9 * expected_kg);
        let h = s.orbit.angular_momentum();
        let tilt = (h[2] / norm3(&h)).acos();
        assert!(tilt > last_tilt + 1e-3, "step {k}: the plane did not turn ({tilt} rad)");
        last_tilt = tilt;
    }
}

/// The coast action of either size and a non-finite one fly a Kepler coast.
#[test]
fn coasting_cycles_are_kepler_arcs() {
    let spatial = turned(planar_scenario(ProblemKind::Rendezvous));
    let mut env = Rendezvous3Env::new(&EnvConfig::default()).unwrap();
    env.reset(&spatial).unwrap();
    let start = env.state().unwrap().orbit;
    let cycle = spatial.scenario.cycle;
    let coasts = [[-1.0, 0.3, 0.2, 0.1], [0.5, 0.0, 0.0, 0.0], [f32::NAN, 0.0, 1.0, 0.0]];
    for (k, action) in coasts.iter().enumerate() {
        let step = env.step(action).unwrap();
        assert_eq!(step.info.throttle, 0.0);
        assert_eq!(step.info.non_finite_action, action[0].is_nan());
        let kepler = onboard::kepler::coast3(&start, (k + 1) as f64 * cycle).unwrap();
        for i in 0..3 {
            assert!((step.info.state.orbit.r[i] - kepler.r[i]).abs() < 1e-11);
            assert!((step.info.state.orbit.v[i] - kepler.v[i]).abs() < 1e-11);
        }
        // The residuals are the distance and speed difference to the body in its plane.
        let body = body_at3(&spatial, (k + 1) as u32).unwrap();
        let dr: [f64; 3] = core::array::from_fn(|i| body.r[i] - kepler.r[i]);
        assert!((step.info.residuals.position - norm3(&dr)).abs() < 1e-10);
    }
}

/// A planar action given to a 3D environment, a scenario of the other problem, a step before
/// any reset: typed refusals that leave the environment as it was.
#[test]
fn refusals_are_typed_and_change_nothing() {
    let config = EnvConfig::default();
    let spatial = turned(planar_scenario(ProblemKind::Transfer));
    let mut env = Transfer3Env::new(&config).unwrap();
    assert_eq!(env.step(&[1.0, 0.0, 1.0, 0.0]).unwrap_err(), EnvError::NotReset);
    let obs = env.reset(&spatial).unwrap();
    assert_eq!(
        env.step_slice(&[1.0, 0.0, 1.0]).unwrap_err(),
        EnvError::ActionLength { expected: 4, found: 3 }
    );
    assert_eq!(env.steps_taken(), 0);
    assert_eq!(env.observation(), Some(obs));
    let step = env.step_slice(&[1.0, 0.0, 1.0, 0.0]).unwrap();
    assert_eq!(step.info.step, 1);
    let mut planar_env = TransferEnv::new(&config).unwrap();
    planar_env.reset(&spatial.scenario).unwrap();
    assert_eq!(
        planar_env.step_slice(&[1.0, 0.0, 1.0, 0.0]).unwrap_err(),
        EnvError::ActionLength { expected: 3, found: 4 }
    );
    let rendezvous = turned(planar_scenario(ProblemKind::Rendezvous));
    assert_eq!(
        env.reset(&rendezvous).unwrap_err(),
        EnvError::WrongProblem {
            expected: ProblemKind::Transfer,
            found: ProblemKind::Rendezvous
        }
    );
    let bad_plane = SpatialScenario {
        initial_plane: OrbitPlane {
            inclination: f64::NAN,
            raan: 0.0,
        },
        ..spatial
    };
    assert!(matches!(env.reset(&bad_plane).unwrap_err(), EnvError::Scenario(_)));
    assert_eq!(env.steps_taken(), 1, "a refused reset keeps the episode");
}

/// Each problem's blob layout has its feature count as inputs and its geometry's action size
/// as outputs (the export's networks and the onboard policies are sized by them).
#[test]
fn each_problems_blob_layout_fits_its_features_and_actions() {
    fn check<P: Problem>(spatial: bool) {
        assert_eq!(P::LAYOUT.len(), P::OBS);
        assert_eq!(P::LAYOUT.actions(), P::Geometry::ACT);
        assert_eq!(P::LAYOUT.problem(), P::KIND);
        assert_eq!(P::LAYOUT, shared::blob::FeatureLayout::of(P::KIND, spatial));
    }
    check::<Transfer>(false);
    check::<Rendezvous>(false);
    check::<Transfer3>(true);
    check::<Rendezvous3>(true);
}
