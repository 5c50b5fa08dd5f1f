//! The three-dimensional propagation (`onboard::spatial`, `onboard::kepler::coast3`) against
//! independent references: the planar propagation on planar states, rotation invariance on
//! inclined ones, the two-body invariants on coasts, fixed-step RK4 with Richardson
//! extrapolation on the equations written out again here, the mass law and the refusals.

use onboard::dynamics::{propagate, PropagationError, SpacecraftState, StateError, ThrustCommand};
use onboard::integrator::Tolerances;
use onboard::kepler::{coast, coast3};
use onboard::spatial::{propagate_rtn, RtnCommand, SpatialCraftState};
use shared::orbit::{cross3, dot3, norm3, CartesianState, SpatialState};
use shared::spacecraft::{CanonicalSpacecraft, Spacecraft};
use shared::units::STEP;

fn msr() -> CanonicalSpacecraft {
    Spacecraft::MSR_ERO.canonical().unwrap()
}

/// A rotation of R^3 from a unit quaternion (w, x, y, z).
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

fn turn(m: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    core::array::from_fn(|i| dot3(&m[i], v))
}

fn turned(m: &[[f64; 3]; 3], s: &SpatialState) -> SpatialState {
    SpatialState {
        r: turn(m, &s.r),
        v: turn(m, &s.v),
    }
}

fn close(a: &[f64], b: &[f64], tol: f64) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol * (1.0 + y.abs()))
}

/// An eccentric orbit's state, out of every coordinate plane.
fn inclined() -> SpatialState {
    turned(
        &rotation([0.9, 0.2, -0.35, 0.15]),
        &SpatialState {
            r: [1.1, 0.2, 0.0],
            v: [-0.15, 0.95, 0.0],
        },
    )
}

#[test]
fn a_planar_coast_in_three_dimensions_is_the_planar_coast() {
    for (r, v, dt) in [
        ([1.0, 0.0], [0.0, 1.0], 3.7),
        ([0.7, -0.4], [0.6, 0.9], 11.0),
        ([1.2, 0.3], [-0.2, 1.4], 2.0), // hyperbolic
    ] {
        let planar = coast(&CartesianState { r, v }, dt).unwrap();
        let spatial = coast3(&SpatialState::from_planar(&CartesianState { r, v }), dt).unwrap();
        assert_eq!(spatial.r[2], 0.0);
        assert_eq!(spatial.v[2], 0.0);
        assert!(close(&spatial.r[..2], &planar.r, 1e-14) && close(&spatial.v[..2], &planar.v, 1e-14));
    }
}

#[test]
fn a_coast_keeps_energy_and_angular_momentum_and_turns_with_its_frame() {
    let start = inclined();
    let m = rotation([0.3, -0.8, 0.1, 0.5]);
    for dt in [0.3, 4.0, -2.5, 25.0] {
        let end = coast3(&start, dt).unwrap();
        assert!((end.energy() - start.energy()).abs() < 1e-13);
        assert!(close(&end.angular_momentum(), &start.angular_momentum(), 1e-13));
        // Rotating the start rotates the end.
        let end_turned = coast3(&turned(&m, &start), dt).unwrap();
        let expected = turned(&m, &end);
        assert!(close(&end_turned.r, &expected.r, 1e-12) && close(&end_turned.v, &expected.v, 1e-12));
    }
}

#[test]
fn a_planar_thrust_arc_in_three_dimensions_is_the_planar_arc() {
    let sc = msr();
    let tol = Tolerances::default();
    let planar = SpacecraftState {
        r: [0.8, 0.6],
        v: [-0.55, 0.85],
        m: 0.9,
    };
    let command = ThrustCommand {
        throttle: 0.7,
        alpha_r: 0.6,
        alpha_theta: 0.8,
    };
    let a = propagate(&planar, &command, &sc, STEP, &tol).unwrap();
    let spatial = SpatialCraftState {
        orbit: SpatialState::from_planar(&planar.cartesian()),
        m: planar.m,
    };
    let rtn = RtnCommand {
        throttle: 0.7,
        radial: 0.6,
        transverse: 0.8,
        normal: 0.0,
    };
    let b = propagate_rtn(&spatial, &rtn, &sc, STEP, &tol).unwrap();
    assert_eq!((b.orbit.r[2], b.orbit.v[2]), (0.0, 0.0));
    assert!(close(&b.orbit.r[..2], &a.r, 1e-11) && close(&b.orbit.v[..2], &a.v, 1e-11));
    assert_eq!(b.m, a.m);
}

/// dr/dt = v, dv/dt = -r/r^3 + (T u / m) alpha with alpha held in the RTN frame, dm/dt = -T u / c.
fn rhs(y: &[f64; 7], sc: &CanonicalSpacecraft, c: &RtnCommand) -> [f64; 7] {
    let r = [y[0], y[1], y[2]];
    let v = [y[3], y[4], y[5]];
    let rn = norm3(&r);
    let h = cross3(&r, &v);
    let n_hat = h.map(|x| x / norm3(&h));
    let r_hat = r.map(|x| x / rn);
    let t_hat = cross3(&n_hat, &r_hat);
    let k = sc.thrust * c.throttle / y[6];
    let a: [f64; 3] = core::array::from_fn(|i| {
        -r[i] / rn.powi(3) + k * (c.radial * r_hat[i] + c.transverse * t_hat[i] + c.normal * n_hat[i])
    });
    [
        v[0],
        v[1],
        v[2],
        a[0],
        a[1],
        a[2],
        -sc.thrust * c.throttle / sc.exhaust_speed,
    ]
}

fn rk4(y0: &[f64; 7], sc: &CanonicalSpacecraft, c: &RtnCommand, duration: f64, steps: usize) -> [f64; 7] {
    let h = duration / steps as f64;
    let mut y = *y0;
    let add = |y: &[f64; 7], k: &[f64; 7], s: f64| -> [f64; 7] { core::array::from_fn(|i| y[i] + s * k[i]) };
    for _ in 0..steps {
        let k1 = rhs(&y, sc, c);
        let k2 = rhs(&add(&y, &k1, h / 2.0), sc, c);
        let k3 = rhs(&add(&y, &k2, h / 2.0), sc, c);
        let k4 = rhs(&add(&y, &k3, h), sc, c);
        y = core::array::from_fn(|i| y[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]));
    }
    y
}

#[test]
fn a_thrust_arc_with_a_normal_component_matches_extrapolated_rk4() {
    let sc = msr();
    let start = SpatialCraftState {
        orbit: inclined(),
        m: 0.95,
    };
    let command = RtnCommand {
        throttle: 0.8,
        radial: 0.3,
        transverse: 0.6,
        normal: -(1.0f64 - 0.09 - 0.36).sqrt(),
    };
    let got = propagate_rtn(&start, &command, &sc, 2.0 * STEP, &Tolerances::default()).unwrap();
    let y0 = start.to_array();
    let (coarse, fine) = (
        rk4(&y0, &sc, &command, 2.0 * STEP, 256),
        rk4(&y0, &sc, &command, 2.0 * STEP, 512),
    );
    // Richardson: RK4's error falls by 16 per halving.
    let reference: [f64; 7] = core::array::from_fn(|i| fine[i] + (fine[i] - coarse[i]) / 15.0);
    assert!(
        close(&got.to_array(), &reference, 1e-12),
        "{:?}\n{reference:?}",
        got.to_array()
    );
    // The normal thrust turned the orbit plane: the angular momentum moved off its start.
    let h0 = start.orbit.angular_momentum();
    let h1 = got.orbit.angular_momentum();
    let angle = (dot3(&h0, &h1) / (norm3(&h0) * norm3(&h1))).acos();
    assert!(angle > 1e-4, "{angle}");
    // Mass is linear in time.
    assert!((got.m - (0.95 - sc.thrust * 0.8 * 2.0 * STEP / sc.exhaust_speed)).abs() < 1e-14);
}

#[test]
fn bad_states_and_commands_are_refused_with_their_errors() {
    let sc = msr();
    let tol = Tolerances::default();
    let good = SpatialCraftState {
        orbit: inclined(),
        m: 1.0,
    };
    let thrust = RtnCommand {
        throttle: 1.0,
        ..RtnCommand::OFF
    };
    let mut nan = good;
    nan.orbit.v[2] = f64::NAN;
    assert_eq!(
        propagate_rtn(&nan, &thrust, &sc, STEP, &tol),
        Err(PropagationError::State(StateError::NonFinite))
    );
    let mut centre = good;
    centre.orbit.r = [0.0; 3];
    assert_eq!(
        propagate_rtn(&centre, &thrust, &sc, STEP, &tol),
        Err(PropagationError::State(StateError::ZeroRadius))
    );
    let long = RtnCommand { normal: 0.5, ..thrust };
    assert_eq!(
        propagate_rtn(&good, &long, &sc, STEP, &tol),
        Err(PropagationError::Command)
    );
    let radial_fall = SpatialCraftState {
        orbit: SpatialState {
            r: [1.0, 0.0, 0.0],
            v: [-0.3, 0.0, 0.0],
        },
        m: 1.0,
    };
    assert_eq!(
        propagate_rtn(&radial_fall, &thrust, &sc, STEP, &tol),
        Err(PropagationError::NoOrbitPlane)
    );
    assert_eq!(
        propagate_rtn(&good, &thrust, &sc, f64::INFINITY, &tol),
        Err(PropagationError::Duration)
    );
    // A burn longer than the tank.
    assert_eq!(
        propagate_rtn(&good, &thrust, &sc, 1e3, &tol),
        Err(PropagationError::MassDepleted)
    );
}
