use super::*;
use crate::solver::pontryagin::{self, idx, Y_LEN};
use crate::solver::shooting::{initial_state_costate, ShootingProblem};
use crate::solver::{rendezvous_starts, solve_scenario, transfer_guesses, Fallbacks};
use shared::orbit::cross3 as cross;
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn params(eps: f64) -> OptimalControlParams {
    OptimalControlParams {
        spacecraft: Spacecraft::MSR_ERO.canonical().unwrap(),
        eps,
    }
}

/// A state away from the centre, out of every coordinate plane, with costates that put rho
/// inside (-eps, eps) for eps = 0.5.
fn sample_y() -> [f64; Y3_LEN] {
    [
        0.9, 0.5, 0.12, -0.4, 0.8, 0.07, 0.85, 0.3, -0.2, 0.05, -0.25, 0.4, 0.08, 0.1,
    ]
}

fn tight() -> Tolerances {
    Tolerances {
        relative: 1e-12,
        absolute: 1e-13,
        ..Tolerances::default()
    }
}

#[test]
fn costate_equations_are_minus_the_gradient_of_the_hamiltonian() {
    for eps in [0.5, 1.0, 0.0] {
        let p = params(eps);
        let y = sample_y();
        let (u, alpha) = optimal_control3(&y, &p);
        let f = state_costate_rhs3(&y, &p);
        let h = 1e-6;
        for i in 0..Y3_LEN {
            let (mut yp, mut ym) = (y, y);
            yp[i] += h;
            ym[i] -= h;
            // Control frozen at its optimum (envelope theorem).
            let dh = (hamiltonian3(&yp, u, alpha, &p) - hamiltonian3(&ym, u, alpha, &p)) / (2.0 * h);
            // dx/dt = dH/dlambda, dlambda/dt = -dH/dx; x has 7 components.
            let (j, expect) = if i < 7 { (i + 7, -dh) } else { (i - 7, dh) };
            assert!(
                (f[j] - expect).abs() < 1e-8,
                "eps {eps} component {j}: {} vs {expect}",
                f[j]
            );
        }
    }
}

#[test]
fn the_optimal_control_minimises_the_hamiltonian() {
    let p = params(0.5);
    let y = sample_y();
    let (u, alpha) = optimal_control3(&y, &p);
    let best = hamiltonian3(&y, u, alpha, &p);
    for k in 0..200 {
        // Directions spread over the sphere, throttles over [0, 1].
        let (a, b) = (k as f64 * 2.399963, (1.0 - 2.0 * (k as f64 + 0.5) / 200.0).acos());
        let dir = [b.sin() * a.cos(), b.sin() * a.sin(), b.cos()];
        let throttle = (k % 11) as f64 / 10.0;
        assert!(
            hamiltonian3(&y, throttle, dir, &p) >= best - 1e-15,
            "control {throttle} {dir:?} beats the optimum"
        );
    }
}

#[test]
fn sensitivities_match_central_differences() {
    let p = params(0.5);
    let y0 = sample_y();
    let t1 = 0.7;
    let ys = propagate_sensitivity3(&p, &y0, t1, &tight()).unwrap();
    let h = 1e-6;
    for k in 0..SPATIAL_UNKNOWNS {
        let (mut yp, mut ym) = (y0, y0);
        yp[idx3::LR + k] += h;
        ym[idx3::LR + k] -= h;
        let fp = propagate3(&p, 0.0, &yp, t1, &tight()).unwrap();
        let fm = propagate3(&p, 0.0, &ym, t1, &tight()).unwrap();
        for i in 0..Y3_LEN {
            let fd = (fp[i] - fm[i]) / (2.0 * h);
            let exact = ys[Y3_LEN + k * Y3_LEN + i];
            assert!(
                (fd - exact).abs() < 1e-6 * (1.0 + exact.abs()),
                "d y{i} / d lambda{k}: {exact} vs {fd}"
            );
        }
    }
}

/// The planar state-costate embedded with zero out-of-plane components stays in its plane and
/// follows the planar propagation.
#[test]
fn a_planar_state_stays_planar_and_follows_the_planar_propagation() {
    let p = params(0.25);
    let planar = [0.9, 0.5, -0.4, 0.8, 0.85, 0.3, -0.2, -0.25, 0.4, 0.1];
    let spatial = [
        planar[0], planar[1], 0.0, planar[2], planar[3], 0.0, planar[4], planar[5], planar[6], 0.0, planar[7],
        planar[8], 0.0, planar[9],
    ];
    let t1 = 2.0;
    let a = pontryagin::propagate(&p, 0.0, &planar, t1, &tight()).unwrap();
    let b = propagate3(&p, 0.0, &spatial, t1, &tight()).unwrap();
    for k in [idx3::R + 2, idx3::V + 2, idx3::LR + 2, idx3::LV + 2] {
        assert_eq!(b[k], 0.0, "out-of-plane component {k}");
    }
    let pairs = [
        (idx::R, idx3::R),
        (idx::R + 1, idx3::R + 1),
        (idx::V, idx3::V),
        (idx::V + 1, idx3::V + 1),
        (idx::M, idx3::M),
        (idx::LR, idx3::LR),
        (idx::LR + 1, idx3::LR + 1),
        (idx::LV, idx3::LV),
        (idx::LV + 1, idx3::LV + 1),
        (idx::LM, idx3::LM),
    ];
    for (i, j) in pairs {
        assert!(
            (a[i] - b[j]).abs() < 1e-10,
            "component {i}: planar {} spatial {}",
            a[i],
            b[j]
        );
    }
    assert_eq!(Y_LEN + 4, Y3_LEN);
}

/// A rotation of R^3 (unit quaternion (w, x, y, z)).
fn rotation(q: [f64; 4]) -> [[f64; 3]; 3] {
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    let [w, x, y, z] = q.map(|c| c / n);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

fn rotate(m: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    core::array::from_fn(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

fn rotated(problem: &SpatialRendezvous, m: &[[f64; 3]; 3]) -> SpatialRendezvous {
    let turn = |s: &SpatialState| SpatialState {
        r: rotate(m, &s.r),
        v: rotate(m, &s.v),
    };
    SpatialRendezvous {
        departure: turn(&problem.departure),
        arrival: turn(&problem.arrival),
        ..*problem
    }
}

fn short_options() -> SolveOptions {
    SolveOptions {
        final_eps: 0.01,
        ..SolveOptions::default()
    }
}

/// The dynamics have no preferred direction: a rendezvous turned by any rotation (here into a
/// plane inclined by some 50 degrees) has the same optimum, and its costates are the turned
/// costates. Independent of the planar solver: the inclined problem is solved from its own
/// guesses.
#[test]
fn a_rotated_rendezvous_has_the_same_optimum_and_rotated_costates() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let scenario = ScenarioKind::RendezvousCircular.draw(7, 3);
    let flat = SpatialRendezvous::from_scenario(&SpatialScenario::planar(scenario), sc).unwrap();
    let options = short_options();
    let a = solve_spatial_rendezvous(&flat, Vec::new(), &options).unwrap();
    let m = rotation([0.8, 0.35, -0.3, 0.2]);
    let tilted = rotated(&flat, &m);
    let b = solve_spatial_rendezvous(&tilted, Vec::new(), &options).unwrap();
    assert!(inclination_of_departure(&tilted) > 0.5);
    assert!(
        (a.final_mass - b.final_mass).abs() < 1e-9 * a.final_mass,
        "{} vs {}",
        a.final_mass,
        b.final_mass
    );
    let lr = rotate(&m, &[a.costates[0], a.costates[1], a.costates[2]]);
    let lv = rotate(&m, &[a.costates[3], a.costates[4], a.costates[5]]);
    for k in 0..3 {
        assert!(
            (lr[k] - b.costates[k]).abs() < 1e-6,
            "lambda_r {k}: {} vs {}",
            lr[k],
            b.costates[k]
        );
        assert!(
            (lv[k] - b.costates[3 + k]).abs() < 1e-6,
            "lambda_v {k}: {} vs {}",
            lv[k],
            b.costates[3 + k]
        );
    }
    assert!(b.residual <= 1e-8);
}

/// The inclination (rad) of the problem's departure orbit to the xy-plane: the test above
/// asserts its rotation left that plane.
fn inclination_of_departure(problem: &SpatialRendezvous) -> f64 {
    let h = cross(&problem.departure.r, &problem.departure.v);
    (h[2] / norm(&h)).acos()
}

/// The planar-equivalence check of docs/spec.md section 3.6 on a few draws (the 100-draw run is
/// `ground data check-3d`): the spatial solver, from the planar solver's guesses embedded,
/// ends at the planar optimum.
#[test]
fn planar_rendezvous_draws_have_the_planar_optima() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let options = short_options();
    for index in [0, 1] {
        let scenario = ScenarioKind::RendezvousCircular.draw(7, index);
        let planar = solve_scenario(ScenarioKind::RendezvousCircular, 7, index, &scenario, &sc, &options);
        assert!(planar.converged, "{:?}", planar.failure);
        let problem = SpatialRendezvous::from_scenario(&SpatialScenario::planar(scenario), sc).unwrap();
        let guesses = rendezvous_starts(transfer_guesses(&scenario))
            .iter()
            .map(lift_planar)
            .collect();
        let spatial = solve_spatial_rendezvous(&problem, guesses, &options).unwrap();
        let relative = (spatial.final_mass - planar.final_mass).abs() / planar.final_mass;
        assert!(
            relative < 1e-8,
            "#{index}: {} vs {} ({relative:e})",
            spatial.final_mass,
            planar.final_mass
        );
        // The planar costates, embedded, solve the spatial problem too.
        let y0 = initial_state_costate(&scenario, &planar.costates);
        let lifted = lift_planar(&RendezvousVector::from_column_slice(&[
            y0[5], y0[6], y0[7], y0[8], y0[9],
        ]));
        let f = problem
            .residual_only(planar.final_eps, &lifted, &options.tolerances)
            .unwrap();
        assert!(f.amax() < 1e-8, "#{index}: the planar solution misses by {}", f.amax());
    }
}

#[test]
fn a_planar_orbit_in_three_dimensions_is_the_planar_orbit_and_its_elements_round_trip() {
    use crate::solver::shooting::orbit_state;
    use shared::orbit::OrbitShape;
    let flat = OrbitShape {
        a: 1.3,
        e: 0.4,
        omega: 0.7,
    };
    let spatial = SpatialOrbitShape::from_planar(&flat);
    for nu in [-2.0f64, 0.0, 1.1, 3.0] {
        let a: [f64; 4] = orbit_state(&flat, nu);
        let b: [f64; 6] = spatial.state_at(nu);
        for (i, j) in [(0, 0), (1, 1), (2, 3), (3, 4)] {
            assert!((a[i] - b[j]).abs() < 1e-15, "{a:?} {b:?}");
        }
        assert_eq!((b[2], b[5]), (0.0, 0.0));
    }
    let inclined = SpatialOrbitShape {
        a: 1.1,
        e: 0.2,
        inclination: 0.4,
        raan: -1.2,
        omega: 2.5,
    };
    let (p, q) = inclined.perifocal();
    let back = SpatialOrbitShape::from_perifocal(1.1, 0.2, &p, &q);
    for (x, y) in [
        (back.inclination, inclined.inclination),
        (back.raan, inclined.raan),
        (back.omega, inclined.omega),
    ] {
        assert!((x - y).abs() < 1e-14, "{back:?}");
    }
    // In the plane, prograde and retrograde: the inverse puts the node on the x-axis and
    // gives back the same orbit (its states agree).
    for inclination in [0.0, std::f64::consts::PI] {
        let flat = SpatialOrbitShape {
            inclination,
            raan: 0.0,
            ..inclined
        };
        let (p, q) = flat.perifocal();
        let back = SpatialOrbitShape::from_perifocal(1.1, 0.2, &p, &q);
        for nu in [0.0, 1.0, 4.0] {
            let (x, y) = (flat.cartesian_at(nu), back.cartesian_at(nu));
            for k in 0..3 {
                assert!(
                    (x.r[k] - y.r[k]).abs() < 1e-14 && (x.v[k] - y.v[k]).abs() < 1e-14,
                    "i = {inclination}: {back:?}"
                );
            }
        }
    }
    // Energy and angular momentum of the orbit's states: a and p.
    for nu in [0.3, 2.0] {
        let s = inclined.cartesian_at(nu);
        assert!((-0.5 / s.energy() - 1.1).abs() < 1e-13);
        let h = s.angular_momentum();
        assert!(((h[0] * h[0] + h[1] * h[1] + h[2] * h[2]) - 1.1 * (1.0 - 0.04)).abs() < 1e-13);
    }
}

fn inclined_transfer(inclination_deg: f64) -> SpatialTransfer {
    SpatialTransfer {
        departure: SpatialState {
            r: [1.0, 0.0, 0.0],
            v: [0.0, 1.08, 0.0],
        },
        initial_mass: 1.0,
        target: SpatialOrbitShape {
            a: 1.5,
            e: 0.2,
            inclination: inclination_deg.to_radians(),
            raan: 0.6,
            omega: 1.0,
        },
        time_of_flight: 49.0 * shared::units::STEP,
        spacecraft: Spacecraft::MSR_ERO.canonical().unwrap(),
    }
}

#[test]
fn the_transfer_jacobian_matches_central_differences() {
    let problem = inclined_transfer(4.0);
    let z = SpatialTransferVector::from_column_slice(&[-0.3, 0.05, 0.02, 0.01, -0.3, 0.04, 0.1, 4.0]);
    let eps = 0.5;
    let (f, jac) = problem.residual(eps, &z, &tight()).unwrap();
    let h = 1e-6;
    for k in 0..SPATIAL_TRANSFER_UNKNOWNS {
        let (mut zp, mut zm) = (z, z);
        zp[k] += h;
        zm[k] -= h;
        let fd = (problem.residual(eps, &zp, &tight()).unwrap().0 - problem.residual(eps, &zm, &tight()).unwrap().0)
            / (2.0 * h);
        for i in 0..SPATIAL_TRANSFER_UNKNOWNS {
            assert!(
                (fd[i] - jac[(i, k)]).abs() < 1e-5 * (1.0 + fd[i].abs()),
                "dF{i}/dz{k}: {} vs {}",
                jac[(i, k)],
                fd[i]
            );
        }
    }
    assert!(f.iter().all(|x| x.is_finite()));
}

/// The plane change has a price: the same transfer to an orbit inclined by 5 degrees ends
/// lighter than to the coplanar one, and both meet their terminal conditions (eccentric orbits:
/// between nearly circular ones the general path stalls, see docs/spec.md section 3.3).
#[test]
fn an_inclined_transfer_costs_more_than_the_coplanar_one_and_is_rotation_invariant() {
    let options = short_options();
    let flat = solve_spatial_transfer(&inclined_transfer(0.0), Vec::new(), &options).unwrap();
    let tilted_problem = inclined_transfer(5.0);
    let tilted = solve_spatial_transfer(&tilted_problem, Vec::new(), &options).unwrap();
    assert!(flat.residual <= 1e-8 && tilted.residual <= 1e-8);
    assert!(
        tilted.final_mass < flat.final_mass - 1e-3,
        "{} vs {}",
        tilted.final_mass,
        flat.final_mass
    );
    // The whole problem turned: departure and target orbit.
    let m = rotation([0.7, -0.2, 0.5, 0.3]);
    let (p, q) = tilted_problem.target.perifocal();
    let turned = SpatialTransfer {
        departure: SpatialState {
            r: rotate(&m, &tilted_problem.departure.r),
            v: rotate(&m, &tilted_problem.departure.v),
        },
        target: SpatialOrbitShape::from_perifocal(1.5, 0.2, &rotate(&m, &p), &rotate(&m, &q)),
        ..tilted_problem
    };
    let again = solve_spatial_transfer(&turned, Vec::new(), &options).unwrap();
    assert!(
        (again.final_mass - tilted.final_mass).abs() < 1e-9,
        "{} vs {}",
        again.final_mass,
        tilted.final_mass
    );
}

#[test]
fn planar_hard_transfer_draws_have_the_planar_optima() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let options = short_options();
    for index in [1, 3] {
        let scenario = ScenarioKind::TransferHard.draw(7, index);
        let planar = solve_scenario(ScenarioKind::TransferHard, 7, index, &scenario, &sc, &options);
        assert!(planar.converged, "#{index}: {:?}", planar.failure);
        let problem = SpatialTransfer::from_scenario(&SpatialScenario::planar(scenario), sc);
        let spatial = solve_spatial_transfer(&problem, Vec::new(), &options).unwrap();
        let relative = (spatial.final_mass - planar.final_mass).abs() / planar.final_mass;
        assert!(
            relative < 1e-8,
            "#{index}: {} vs {} ({relative:e})",
            spatial.final_mass,
            planar.final_mass
        );
    }
}

/// A scenario of a family in three dimensions poses its goal with each orbit in its plane: both
/// orbits in one inclined plane is the planar scenario turned, so the optimum is the planar one
/// (the rotation that invariance rests on is the plane's, written apart from the solver's frames).
#[test]
fn a_scenario_whose_orbits_share_an_inclined_plane_has_the_planar_optimum() {
    use crate::spatial::SpatialGoal;
    use shared::orbit::OrbitPlane;
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let options = short_options();
    let plane = OrbitPlane {
        inclination: 0.5,
        raan: 2.0,
    };
    for kind in [ScenarioKind::RendezvousCircular, ScenarioKind::TransferHard] {
        let scenario = kind.draw(7, 0);
        let flat = SpatialGoal::of_scenario(&SpatialScenario::planar(scenario), sc).unwrap();
        let turned = SpatialScenario {
            scenario,
            initial_plane: plane,
            target_plane: plane,
        };
        let goal = SpatialGoal::of_scenario(&turned, sc).unwrap();
        if let SpatialGoal::Transfer(t) = goal {
            // The target orbit's elements put its points where the plane puts the planar ones.
            for nu in [0.0, 1.0, 2.5, 4.0] {
                let a = t.target.cartesian_at(nu);
                let b = plane.embed(&scenario.target.cartesian_at(nu));
                assert!(a
                    .r
                    .iter()
                    .chain(&a.v)
                    .zip(b.r.iter().chain(&b.v))
                    .all(|(x, y)| (x - y).abs() < 1e-14));
            }
        }
        let (m_flat, m_turned) = (
            flat.solve(&options).unwrap().solution.final_mass,
            goal.solve(&options).unwrap().solution.final_mass,
        );
        assert!(
            (m_flat - m_turned).abs() < 1e-9 * m_flat,
            "{kind:?}: {m_flat} vs {m_turned}"
        );
    }
}

/// The fallbacks in three dimensions run on the problem flattened into the departure plane and
/// take the routes `SolveOptions::fallbacks` allows, as in the plane: rendezvous-circular seed 7
/// #4 (its planar multi-start fails, the continuation in the target solves it), turned out of the
/// xy-plane and started from the planar guesses turned with it, fails without fallbacks and
/// reaches the planar optimum through the flattened problem's continuation; on #31, where both
/// planar routes fail, the failure names only the routes taken.
#[test]
fn a_spatial_solve_takes_the_flattened_fallbacks_its_options_allow() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let kind = ScenarioKind::RendezvousCircular;
    let m = rotation([0.8, 0.35, -0.3, 0.2]);
    let turn = |z: &SpatialVector| {
        let (lr, lv) = (rotate(&m, &[z[0], z[1], z[2]]), rotate(&m, &[z[3], z[4], z[5]]));
        SpatialVector::from_column_slice(&[lr[0], lr[1], lr[2], lv[0], lv[1], lv[2], z[6]])
    };
    let solve = |index: u64, fallbacks: Fallbacks| {
        let options = SolveOptions {
            fallbacks,
            ..short_options()
        };
        let scenario = kind.draw(7, index);
        let flat = SpatialRendezvous::from_scenario(&SpatialScenario::planar(scenario), sc).unwrap();
        let guesses = rendezvous_starts(transfer_guesses(&scenario))
            .iter()
            .map(|z| turn(&lift_planar(z)))
            .collect();
        solve_spatial_rendezvous(&rotated(&flat, &m), guesses, &options)
    };
    let why = |result: Result<SpatialSolution, SpatialSolveError>| match result {
        Err(SpatialSolveError::NotSolved(why)) => why,
        other => panic!("expected a failure to solve, got {other:?}"),
    };

    let none = why(solve(4, Fallbacks::None));
    assert!(!none.contains("flattened"), "{none}");
    let continued = solve(4, Fallbacks::Continuation).unwrap();
    let planar = solve_scenario(
        kind,
        7,
        4,
        &kind.draw(7, 4),
        &sc,
        &SolveOptions {
            fallbacks: Fallbacks::Continuation,
            ..short_options()
        },
    );
    assert!(planar.converged, "{:?}", planar.failure);
    assert!(
        (continued.final_mass - planar.final_mass).abs() < 1e-8 * planar.final_mass,
        "{} vs {}",
        continued.final_mass,
        planar.final_mass
    );
    assert!(continued.residual <= 1e-8);

    let continuation_only = why(solve(31, Fallbacks::Continuation));
    assert!(
        continuation_only.contains("the flattened problem's continuation in the target stopped"),
        "{continuation_only}"
    );
    let all = why(solve(31, Fallbacks::All));
    assert!(
        all.contains("flattened") && !all.contains("continuation in the target stopped"),
        "{all}"
    );
}

/// A transfer guess that cannot converge: no primer vector (lambda_v = 0), so no thrust
/// direction; lambda_m = 1. Its first 7 components are the rendezvous's.
fn no_primer_guess() -> SpatialTransferVector {
    let mut z = SpatialTransferVector::zeros();
    z[6] = 1.0;
    z
}

/// `draw` with its target's plane tilted by 2 degrees, the node on the x axis.
fn tilted_by_two_degrees(draw: shared::scenario::Scenario) -> SpatialScenario {
    SpatialScenario {
        target_plane: shared::orbit::OrbitPlane {
            inclination: 2f64.to_radians(),
            raan: 0.0,
        },
        ..SpatialScenario::planar(draw)
    }
}

/// The transfer's fallback in three dimensions: flattened into the departure plane (the target
/// turned about its node line into it), solved there, lifted and carried back to the target's
/// inclination by continuation. Started from a guess that cannot converge (no primer vector),
/// the transfer to the orbit inclined by 20 degrees fails without fallbacks, and with them
/// reaches the optimum its own multi-start finds. The continuation is what carries it: the lifted
/// planar start put straight at the full inclination does not converge. On transfer-hard seed 7
/// #19 with its target tilted by 2 degrees, where both planar routes fail, the failure names only
/// the routes the options allow.
#[test]
fn a_spatial_transfer_falls_back_to_the_flattened_transfer_carried_to_its_inclination() {
    let hopeless = || vec![no_primer_guess()];
    let solve = |problem: &SpatialTransfer, guesses: Vec<SpatialTransferVector>, fallbacks: Fallbacks| {
        let options = SolveOptions {
            fallbacks,
            ..short_options()
        };
        solve_spatial_transfer(problem, guesses, &options)
    };
    let why = |result: Result<SpatialTransferSolution, SpatialSolveError>| match result {
        Err(SpatialSolveError::NotSolved(why)) => why,
        other => panic!("expected a failure to solve, got {other:?}"),
    };

    let problem = inclined_transfer(20.0);
    let none = why(solve(&problem, hopeless(), Fallbacks::None));
    assert!(!none.contains("flattened"), "{none}");
    let fallen_back = solve(&problem, hopeless(), Fallbacks::Continuation).unwrap();
    let own = solve(&problem, Vec::new(), Fallbacks::None).unwrap();
    assert!(fallen_back.residual <= 1e-8);
    assert!(
        (fallen_back.final_mass - own.final_mass).abs() < 1e-8 * own.final_mass,
        "{} vs {}",
        fallen_back.final_mass,
        own.final_mass
    );

    let tilted = tilted_by_two_degrees(ScenarioKind::TransferHard.draw(7, 19));
    let hard = SpatialTransfer::from_scenario(&tilted, Spacecraft::MSR_ERO.canonical().unwrap());
    let continuation_only = why(solve(&hard, hopeless(), Fallbacks::Continuation));
    assert!(
        continuation_only.contains("the flattened problem's continuation in the target stopped"),
        "{continuation_only}"
    );
    let all = why(solve(&hard, hopeless(), Fallbacks::All));
    assert!(
        all.contains("the flattened problem has no start either")
            && !all.contains("continuation in the target stopped"),
        "{all}"
    );
}

/// `goal` solved from a guess that cannot converge (no primer vector) by the flattened fallbacks
/// at [`short_options`]: without the direct start it must fail where the flattened problem's
/// continuation stops, and with it reach a solution. That solution against the direct
/// transcription of `goal` in three dimensions from tangential thrust at `throttle` on
/// `segments` segments and one mesh twice as fine, nothing taken from the indirect solution:
/// the direct final mass less the indirect one.
fn solved_through_the_direct_start(goal: &crate::spatial::SpatialGoal, segments: usize, throttle: f64) -> f64 {
    use crate::solver::direct::DirectOptions;
    use crate::solver::spatial::direct::{solve_spatial_direct_refined, tangential_guess, SpatialDirectProblem};
    use crate::spatial::SpatialGoal;

    let solve = |fallbacks| {
        let options = SolveOptions {
            fallbacks,
            ..short_options()
        };
        let hopeless = no_primer_guess();
        match goal {
            SpatialGoal::Transfer(p) => {
                solve_spatial_transfer(p, vec![hopeless], &options).map(|s| (s.final_mass, s.final_eps, s.residual))
            }
            SpatialGoal::Rendezvous(p) => {
                solve_spatial_rendezvous(p, vec![hopeless.fixed_rows::<7>(0).into()], &options)
                    .map(|s| (s.final_mass, s.final_eps, s.residual))
            }
        }
    };
    match solve(Fallbacks::Continuation) {
        Err(SpatialSolveError::NotSolved(why)) => assert!(
            why.contains("the flattened problem's continuation in the target stopped"),
            "{why}"
        ),
        other => panic!("expected the continuation to stop, got {other:?}"),
    }
    let (final_mass, final_eps, residual) = solve(Fallbacks::All).unwrap();
    assert!(residual <= 1e-8, "residual {residual:e}");

    let direct = SpatialDirectProblem::of_goal(goal);
    let options = DirectOptions::default();
    let guess = tangential_guess(&direct, segments, throttle, &options.tolerances).unwrap();
    let meshes = solve_spatial_direct_refined(&direct, guess, 1, final_eps, &options).unwrap();
    let finest = meshes.last().unwrap();
    assert!(finest.converged, "{:?}", finest.history.last());
    finest.final_mass - final_mass
}

/// The transfer fallback's last route: transfer-hard seed 7 #50 tilted by 2 degrees, where the
/// flattened problem's continuation in the target stops. The direct transcription's multipliers
/// on the flattened problem, lifted and carried to the inclination, reach a solution that the
/// direct transcription in three dimensions meets within the mesh's cost.
#[test]
fn a_spatial_transfer_whose_flattened_continuation_stops_is_solved_through_the_direct_start() {
    let draw = ScenarioKind::TransferHard.draw(7, 50);
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let goal = crate::spatial::SpatialGoal::Transfer(SpatialTransfer::from_scenario(&tilted_by_two_degrees(draw), sc));
    let difference = solved_through_the_direct_start(&goal, draw.steps as usize, 0.5);
    // Measured: the direct solution 3.6e-4 of the initial mass lighter (92 segments).
    assert!((-1e-3..1e-6).contains(&difference), "direct - indirect {difference:e}");
}

/// The rendezvous twin: rendezvous-hard seed 7 #109 tilted by 2 degrees, solved through the
/// direct start on the flattened problem, carried to the arrival out of the plane.
#[test]
fn a_spatial_rendezvous_whose_flattened_continuation_stops_is_solved_through_the_direct_start() {
    let draw = ScenarioKind::RendezvousHard.draw(7, 109);
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let problem = SpatialRendezvous::from_scenario(&tilted_by_two_degrees(draw), sc).unwrap();
    // A quarter of the throttle: from half, the direct guess's own propagation does not finish.
    let difference = solved_through_the_direct_start(
        &crate::spatial::SpatialGoal::Rendezvous(problem),
        draw.steps as usize,
        0.25,
    );
    // Measured: the direct solution 1.7e-4 of the initial mass lighter (92 segments).
    assert!((-1e-3..1e-6).contains(&difference), "direct - indirect {difference:e}");
}
