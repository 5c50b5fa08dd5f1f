//! Thrusting arcs of `onboard::dynamics::propagate` against an independent reference: the
//! classical fixed-step RK4 with 2^k steps, Richardson-extrapolated, on the equations of
//! docs/spec.md section 2 written out again here. Also the mass law and the refusal of bad states.

use onboard::dynamics::{propagate, PropagationError, SpacecraftState, StateError, ThrustCommand};
use onboard::integrator::{IntegrationError, Tolerances};
use onboard::kepler::coast;
use shared::spacecraft::{CanonicalSpacecraft, Spacecraft};
use shared::units::{STEP, YEAR};

fn msr() -> CanonicalSpacecraft {
    Spacecraft::MSR_ERO.canonical().unwrap()
}

fn circular_1au(theta: f64) -> SpacecraftState {
    let (s, c) = theta.sin_cos();
    SpacecraftState {
        r: [c, s],
        v: [-s, c],
        m: 1.0,
    }
}

const ALONG_TRACK: ThrustCommand = ThrustCommand {
    throttle: 1.0,
    alpha_r: 0.0,
    alpha_theta: 1.0,
};

/// dr/dt = v, dv/dt = -r/r^3 + (T u / m) alpha, dm/dt = -T u / c with alpha held in the local
/// polar frame (docs/spec.md section 2).
fn rhs(y: &[f64; 5], sc: &CanonicalSpacecraft, cmd: &ThrustCommand) -> [f64; 5] {
    let [x, yy, vx, vy, m] = *y;
    let r = (x * x + yy * yy).sqrt();
    let (ct, st) = (x / r, yy / r);
    let ax = cmd.alpha_r * ct - cmd.alpha_theta * st;
    let ay = cmd.alpha_r * st + cmd.alpha_theta * ct;
    let k = sc.thrust * cmd.throttle / m;
    let r3 = r * r * r;
    [
        vx,
        vy,
        -x / r3 + k * ax,
        -yy / r3 + k * ay,
        -sc.thrust * cmd.throttle / sc.exhaust_speed,
    ]
}

/// Classical RK4 with n equal steps and compensated (Kahan) accumulation of the state.
fn rk4(y0: &[f64; 5], duration: f64, n: u32, sc: &CanonicalSpacecraft, cmd: &ThrustCommand) -> [f64; 5] {
    let h = duration / f64::from(n);
    let mut y = *y0;
    let mut comp = [0.0; 5];
    let add = |y: &[f64; 5], k: &[f64; 5], s: f64| -> [f64; 5] { std::array::from_fn(|i| y[i] + s * k[i]) };
    for _ in 0..n {
        let k1 = rhs(&y, sc, cmd);
        let k2 = rhs(&add(&y, &k1, 0.5 * h), sc, cmd);
        let k3 = rhs(&add(&y, &k2, 0.5 * h), sc, cmd);
        let k4 = rhs(&add(&y, &k3, h), sc, cmd);
        for i in 0..5 {
            let dy = h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) + comp[i];
            let s = y[i] + dy;
            comp[i] = dy - (s - y[i]);
            y[i] = s;
        }
    }
    y
}

/// Richardson extrapolation of RK4 with n and 2n steps (error h^4 -> h^5), and how much it
/// moved from the extrapolation with n/2 and n steps (a bound on its own error).
fn reference(y0: &[f64; 5], duration: f64, n: u32, sc: &CanonicalSpacecraft, cmd: &ThrustCommand) -> ([f64; 5], f64) {
    let a = rk4(y0, duration, n / 2, sc, cmd);
    let b = rk4(y0, duration, n, sc, cmd);
    let c = rk4(y0, duration, 2 * n, sc, cmd);
    let coarse: [f64; 5] = std::array::from_fn(|i| (16.0 * b[i] - a[i]) / 15.0);
    let fine: [f64; 5] = std::array::from_fn(|i| (16.0 * c[i] - b[i]) / 15.0);
    let spread = (0..5).map(|i| (fine[i] - coarse[i]).abs()).fold(0.0, f64::max);
    (fine, spread)
}

fn compare(state: &SpacecraftState, reference: &[f64; 5]) -> (f64, f64, f64) {
    let y = state.to_array();
    (
        (y[0] - reference[0]).hypot(y[1] - reference[1]),
        (y[2] - reference[2]).hypot(y[3] - reference[3]),
        (y[4] - reference[4]).abs(),
    )
}

#[test]
fn fourteen_day_along_track_arc_matches_the_rk4_richardson_reference() {
    let sc = msr();
    let s0 = circular_1au(0.3);
    let got = propagate(&s0, &ALONG_TRACK, &sc, STEP, &Tolerances::default()).unwrap();
    let (want, spread) = reference(&s0.to_array(), STEP, 1 << 11, &sc, &ALONG_TRACK);
    assert!(spread < 1e-14, "reference not converged: {spread:e}");
    let (dr, dv, dm) = compare(&got, &want);
    println!("14 days: position {dr:.1e} AU, velocity {dv:.1e}, mass {dm:.1e}");
    assert!(dr < 1e-12 && dv < 1e-12 && dm < 1e-14, "{dr:e} {dv:e} {dm:e}");
    // The thrust did something measurable: the arc left the circular orbit by far more than
    // the error (T t^2 / 2 ~ 2e-3 AU).
    let coasted = coast(&s0.cartesian(), STEP).unwrap();
    assert!((got.r[0] - coasted.r[0]).hypot(got.r[1] - coasted.r[1]) > 1e-3);
}

#[test]
fn one_year_along_track_arc_matches_the_rk4_richardson_reference() {
    let sc = msr();
    let s0 = circular_1au(0.0);
    let got = propagate(&s0, &ALONG_TRACK, &sc, YEAR, &Tolerances::default()).unwrap();
    let (want, spread) = reference(&s0.to_array(), YEAR, 1 << 14, &sc, &ALONG_TRACK);
    assert!(spread < 1e-12, "reference not converged: {spread:e}");
    let (dr, dv, dm) = compare(&got, &want);
    println!("1 year: position {dr:.1e} AU, velocity {dv:.1e}, mass {dm:.1e} (reference spread {spread:.1e})");
    assert!(dr < 1e-10 && dv < 1e-10 && dm < 1e-13, "{dr:e} {dv:e} {dm:e}");
    // The spiral raised the orbit: the radius grew by more than 0.3 AU.
    assert!(got.radius() > 1.3, "{}", got.radius());
}

#[test]
fn oblique_partial_throttle_arcs_on_an_eccentric_orbit_match_the_reference() {
    let sc = msr();
    // Periapsis of an e = 0.3, a = 1.2 orbit, half mass gone already.
    let rp: f64 = 1.2 * 0.7;
    let vp = (1.3 / rp).sqrt();
    let s0 = SpacecraftState {
        r: [rp, 0.0],
        v: [0.0, vp],
        m: 0.6,
    };
    for cmd in [
        ThrustCommand {
            throttle: 0.5,
            alpha_r: 0.6,
            alpha_theta: -0.8,
        },
        ThrustCommand {
            throttle: 0.25,
            alpha_r: -1.0,
            alpha_theta: 0.0,
        },
    ] {
        for duration in [STEP, -STEP, 4.0 * STEP] {
            let got = propagate(&s0, &cmd, &sc, duration, &Tolerances::default()).unwrap();
            let (want, spread) = reference(&s0.to_array(), duration, 1 << 12, &sc, &cmd);
            assert!(spread < 1e-13, "reference not converged: {spread:e}");
            let (dr, dv, dm) = compare(&got, &want);
            assert!(
                dr < 1e-11 && dv < 1e-11 && dm < 1e-14,
                "{cmd:?} {duration}: {dr:e} {dv:e} {dm:e}"
            );
        }
    }
}

#[test]
fn mass_follows_the_linear_law_for_constant_throttle() {
    let sc = msr();
    for u in [0.1, 0.37, 0.5, 1.0] {
        let cmd = ThrustCommand {
            throttle: u,
            ..ALONG_TRACK
        };
        for duration in [STEP, 0.5 * YEAR, YEAR] {
            let got = propagate(&circular_1au(1.0), &cmd, &sc, duration, &Tolerances::default()).unwrap();
            let exact = 1.0 - sc.thrust * u * duration / sc.exhaust_speed;
            assert!(
                (got.m - exact).abs() < 1e-14,
                "u {u} t {duration}: m {} vs {exact}",
                got.m
            );
        }
    }
    // Chained 14-day steps accumulate no drift either.
    let mut s = circular_1au(0.0);
    for _ in 0..26 {
        s = propagate(&s, &ALONG_TRACK, &sc, STEP, &Tolerances::default()).unwrap();
    }
    let exact = 1.0 - sc.thrust * 26.0 * STEP / sc.exhaust_speed;
    assert!((s.m - exact).abs() < 1e-14, "{} vs {exact}", s.m);
}

#[test]
fn there_and_back_under_thrust_returns_the_state() {
    let sc = msr();
    let s0 = circular_1au(2.0);
    let there = propagate(&s0, &ALONG_TRACK, &sc, STEP, &Tolerances::default()).unwrap();
    let back = propagate(&there, &ALONG_TRACK, &sc, -STEP, &Tolerances::default()).unwrap();
    let (dr, dv, dm) = compare(&back, &s0.to_array());
    assert!(dr < 1e-12 && dv < 1e-12 && dm < 1e-15, "{dr:e} {dv:e} {dm:e}");
}

#[test]
fn zero_throttle_coasts_on_kepler_and_keeps_the_mass() {
    let sc = msr();
    let s0 = SpacecraftState {
        r: [0.9, 0.2],
        v: [-0.1, 1.1],
        m: 0.8,
    };
    let got = propagate(&s0, &ThrustCommand::OFF, &sc, STEP, &Tolerances::default()).unwrap();
    let (want, _) = reference(&s0.to_array(), STEP, 1 << 11, &sc, &ThrustCommand::OFF);
    let (dr, dv, dm) = compare(&got, &want);
    assert!(dr < 1e-13 && dv < 1e-13 && dm == 0.0, "{dr:e} {dv:e} {dm:e}");
}

#[test]
fn bad_states_commands_and_settings_are_typed_errors() {
    let sc = msr();
    let tl = Tolerances::default();
    let ok = circular_1au(0.0);
    let err = |s: &SpacecraftState, c: &ThrustCommand, d: f64, t: &Tolerances| propagate(s, c, &sc, d, t).unwrap_err();
    for cmd in [ALONG_TRACK, ThrustCommand::OFF] {
        let at_sun = SpacecraftState { r: [0.0, 0.0], ..ok };
        assert_eq!(
            err(&at_sun, &cmd, STEP, &tl),
            PropagationError::State(StateError::ZeroRadius)
        );
        for m in [0.0, -1.0] {
            assert_eq!(
                err(&SpacecraftState { m, ..ok }, &cmd, STEP, &tl),
                PropagationError::State(StateError::NonPositiveMass)
            );
        }
        for bad in [f64::NAN, f64::INFINITY] {
            let s = SpacecraftState { r: [bad, 0.0], ..ok };
            assert_eq!(err(&s, &cmd, STEP, &tl), PropagationError::State(StateError::NonFinite));
            let s = SpacecraftState { v: [0.0, bad], ..ok };
            assert_eq!(err(&s, &cmd, STEP, &tl), PropagationError::State(StateError::NonFinite));
            let s = SpacecraftState { m: bad, ..ok };
            assert_eq!(err(&s, &cmd, STEP, &tl), PropagationError::State(StateError::NonFinite));
            assert_eq!(err(&ok, &cmd, bad, &tl), PropagationError::Duration);
        }
    }
    for throttle in [f64::NAN, -0.1, 1.5] {
        let c = ThrustCommand {
            throttle,
            ..ALONG_TRACK
        };
        assert_eq!(err(&ok, &c, STEP, &tl), PropagationError::Command);
    }
    // Invalid tolerances reach the integrator's own check.
    let zero_tol = Tolerances { relative: 0.0, ..tl };
    assert_eq!(
        err(&ok, &ALONG_TRACK, STEP, &zero_tol),
        PropagationError::Integration(IntegrationError::InvalidInput)
    );
    // A step budget too small for a year.
    let tiny = Tolerances { max_steps: 3, ..tl };
    assert!(matches!(
        err(&ok, &ALONG_TRACK, YEAR, &tiny),
        PropagationError::Integration(IntegrationError::StepBudgetExhausted { .. })
    ));
    // Running out of propellant.
    let nearly_empty = SpacecraftState { m: 0.01, ..ok };
    assert_eq!(
        err(&nearly_empty, &ALONG_TRACK, STEP, &tl),
        PropagationError::MassDepleted
    );
}
