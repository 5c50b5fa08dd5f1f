//! The DOP853 integrator against problems with known solutions: order of the method, accuracy
//! versus tolerance, exact landing on t1 and on event zeros, and refusal of bad input.

use std::cell::Cell;
use std::f64::consts::PI;
use std::rc::Rc;

use onboard::integrator::{
    integrate, integrate_observed, IntegrationError, IntegrationStats, Observer, OdeSystem, Tolerances,
};

/// Event functions of the test systems that have events (unused ones are held at 1).
const EVENTS: usize = 2;

fn tol(rtol: f64, atol: f64) -> Tolerances {
    Tolerances {
        relative: rtol,
        absolute: atol,
        ..Tolerances::default()
    }
}

/// y' = y: y = y0 e^t.
struct Growth;
impl OdeSystem<1> for Growth {
    fn derivatives(&self, _t: f64, y: &[f64; 1], d: &mut [f64; 1]) {
        d[0] = y[0];
    }
}

/// y' = -2 t y^2: y = 1 / (1 + t^2) from y(0) = 1 (nonlinear, non-autonomous).
struct Rational;
impl OdeSystem<1> for Rational {
    fn derivatives(&self, t: f64, y: &[f64; 1], d: &mut [f64; 1]) {
        d[0] = -2.0 * t * y[0] * y[0];
    }
}

/// x'' = -x with events x (index 0) and optionally v (index 1).
struct Oscillator {
    events: bool,
    velocity_event: bool,
}
impl OdeSystem<2, EVENTS> for Oscillator {
    fn derivatives(&self, _t: f64, y: &[f64; 2], d: &mut [f64; 2]) {
        *d = [y[1], -y[0]];
    }
    fn events(&self, _t: f64, y: &[f64; 2]) -> [f64; EVENTS] {
        match (self.events, self.velocity_event) {
            (false, _) => [1.0, 1.0],
            (true, false) => [y[0], 1.0],
            (true, true) => [y[0], y[1]],
        }
    }
}

#[derive(Default)]
struct Recorder {
    steps: Vec<f64>,
    events: Vec<(usize, f64, bool)>,
}
impl<const N: usize> Observer<N> for Recorder {
    fn on_step(&mut self, t: f64, _y: &[f64; N]) {
        self.steps.push(t);
    }
    fn on_event(&mut self, index: usize, t: f64, _y: &[f64; N], rising: bool) {
        self.events.push((index, t, rising));
    }
}

/// x'' = -x / |x|^3 in the plane (nonlinear); the circular orbit is (cos t, sin t).
struct Circular;
impl OdeSystem<4> for Circular {
    fn derivatives(&self, _t: f64, y: &[f64; 4], d: &mut [f64; 4]) {
        let r2 = y[0] * y[0] + y[1] * y[1];
        let k = 1.0 / (r2 * r2.sqrt());
        *d = [y[2], y[3], -y[0] * k, -y[1] * k];
    }
}

/// The error of one step of length h: t1 = t0 + h, initial_step = h, tolerances so loose that
/// the step is accepted as it is.
fn one_step<S: OdeSystem<N, E>, const N: usize, const E: usize>(system: &S, y0: [f64; N], h: f64) -> [f64; N] {
    let single = Tolerances {
        relative: 1.0,
        absolute: 1.0,
        max_steps: 1,
        initial_step: h,
        fixed_steps: 0,
    };
    let (y, stats) = integrate(system, 0.0, &y0, h, &single).unwrap();
    assert_eq!((stats.accepted_steps, stats.rejected_steps), (1, 0));
    y
}

#[test]
fn one_step_error_falls_as_h_to_the_ninth_so_the_weights_are_eighth_order() {
    // Local error of an order-8 method: C h^9, so halving h divides it by 2^9 = 512 (an
    // order-7 method would give 256, order 9 1024). y' = y checks the stability polynomial.
    let growth: Vec<f64> = [1.0f64, 0.5, 0.25]
        .iter()
        .map(|&h| (one_step(&Growth, [1.0], h)[0] - h.exp()).abs())
        .collect();
    for pair in growth.windows(2) {
        let ratio = pair[0] / pair[1];
        assert!(
            (450.0..800.0).contains(&ratio),
            "y' = y: errors {growth:?}, ratio {ratio}"
        );
    }
    // The nonlinear circular orbit exercises all order conditions; its position error even
    // falls one order faster here (ratio ~1000), at least order 8 in any case.
    let orbit: Vec<f64> = [1.0f64, 0.5, 0.25]
        .iter()
        .map(|&h| {
            let y = one_step(&Circular, [1.0, 0.0, 0.0, 1.0], h);
            (y[0] - h.cos()).hypot(y[1] - h.sin())
        })
        .collect();
    for pair in orbit.windows(2) {
        let ratio = pair[0] / pair[1];
        assert!(ratio > 450.0, "orbit: errors {orbit:?}, ratio {ratio}");
    }
    assert!(orbit[2] < 1e-12 && growth[2] < 1e-12);
}

#[test]
fn growth_and_oscillator_reach_1e_13() {
    let (y, stats) = integrate(&Growth, 0.0, &[1.0], 2.0, &tol(1e-14, 1e-14)).unwrap();
    let rel = (y[0] - 2f64.exp()).abs() / 2f64.exp();
    assert!(rel < 1e-13, "y' = y: relative error {rel:e}");
    assert!(stats.accepted_steps > 3 && stats.rejected_steps < stats.accepted_steps);

    let osc = Oscillator {
        events: false,
        velocity_event: false,
    };
    let t1 = 10.0 * PI + 0.7;
    let (y, _) = integrate(&osc, 0.0, &[1.0, 0.0], t1, &tol(1e-14, 1e-14)).unwrap();
    let err = (y[0] - t1.cos()).abs().max((y[1] + t1.sin()).abs());
    assert!(err < 1e-13, "oscillator after five periods: error {err:e}");
}

#[test]
fn error_is_proportional_to_the_tolerance() {
    // Global error of the oscillator over 3 periods, tolerance swept over six decades: the
    // error stays below the tolerance and falls by roughly a decade per decade.
    let osc = Oscillator {
        events: false,
        velocity_event: false,
    };
    let t1 = 6.0 * PI;
    let mut prev: Option<(f64, u32)> = None;
    for k in 6..=12 {
        let rt = 10f64.powi(-k);
        let (y, stats) = integrate(&osc, 0.0, &[1.0, 0.0], t1, &tol(rt, rt)).unwrap();
        let err = (y[0] - t1.cos()).abs().max((y[1] + t1.sin()).abs());
        assert!(err < 10.0 * rt, "tol {rt:e}: error {err:e}");
        if let Some((pe, pevals)) = prev {
            let ratio = pe / err;
            assert!(
                (2.0..50.0).contains(&ratio),
                "tol {rt:e}: error ratio per decade {ratio}"
            );
            // An 8th-order method needs ~10^(1/8) = 1.33x more steps per decade of accuracy.
            let work = f64::from(stats.derivative_evaluations) / f64::from(pevals);
            assert!((1.0..2.0).contains(&work), "work ratio {work}");
        }
        prev = Some((err, stats.derivative_evaluations));
    }
}

/// 60 uncoupled oscillators x'' = -w_k^2 x (120 states, the size of the ground's state +
/// costate + sensitivity systems) with frequencies 0.5 .. 2.
struct Bank;
const BANK: usize = 120;
fn bank_omega(k: usize) -> f64 {
    0.5 + 1.5 * k as f64 / 59.0
}
impl OdeSystem<BANK> for Bank {
    fn derivatives(&self, _t: f64, y: &[f64; BANK], d: &mut [f64; BANK]) {
        for k in 0..BANK / 2 {
            let w = bank_omega(k);
            d[2 * k] = y[2 * k + 1];
            d[2 * k + 1] = -w * w * y[2 * k];
        }
    }
}

#[test]
fn a_120_state_system_integrates_on_the_stack_to_1e_12() {
    let mut y0 = [0.0; BANK];
    for k in 0..BANK / 2 {
        y0[2 * k] = 1.0;
    }
    let t1 = 7.5;
    let (y, stats) = integrate(&Bank, 0.0, &y0, t1, &tol(1e-13, 1e-13)).unwrap();
    for k in 0..BANK / 2 {
        let w = bank_omega(k);
        // Position and velocity / w, both of amplitude 1.
        let err = (y[2 * k] - (w * t1).cos())
            .abs()
            .max((y[2 * k + 1] / w + (w * t1).sin()).abs());
        assert!(err < 1e-12, "oscillator {k} (w = {w}): {err:e}");
    }
    assert!(stats.accepted_steps > 10);
}

#[test]
fn lands_exactly_on_t1_forwards_and_backwards_and_t1_equal_t0_is_identity() {
    let mut rec = Recorder::default();
    let t1 = 1.234_567_890_123;
    let (y, _) = integrate_observed(&Growth, 0.1, &[1.0], t1, &Tolerances::default(), &mut rec).unwrap();
    assert_eq!(*rec.steps.last().unwrap(), t1);
    assert!(rec.steps.windows(2).all(|w| w[1] > w[0]));
    assert!((y[0] / (t1 - 0.1).exp() - 1.0).abs() < 1e-12);

    // Backwards: y(-2) from y(0) = 1.
    let mut rec = Recorder::default();
    let (y, stats) = integrate_observed(&Growth, 0.0, &[1.0], -2.0, &Tolerances::default(), &mut rec).unwrap();
    assert_eq!(*rec.steps.last().unwrap(), -2.0);
    assert!(rec.steps.windows(2).all(|w| w[1] < w[0]));
    assert!((y[0] / (-2f64).exp() - 1.0).abs() < 1e-11, "{}", y[0]);
    assert!(stats.accepted_steps > 1);

    let (y, stats) = integrate(&Growth, 3.0, &[7.0], 3.0, &Tolerances::default()).unwrap();
    assert_eq!(y, [7.0]);
    assert_eq!(stats, IntegrationStats::default());
}

#[test]
fn stats_count_steps_and_evaluations_consistently() {
    let (_, s) = integrate(&Rational, 0.0, &[1.0], 5.0, &Tolerances::default()).unwrap();
    // 1 initial evaluation + 1 for the starting step size; 11 new stages per trial, 1 more
    // (first-same-as-last) per accepted step; no events here.
    let expected = 2 + 11 * (s.accepted_steps + s.rejected_steps) + s.accepted_steps;
    assert_eq!(s.derivative_evaluations, expected, "{s:?}");
    assert_eq!(s.events_located, 0);
}

/// Fixed steps are the adaptive integrator's steps without its control: one fixed step is the
/// adaptive step of the same length bit for bit, n of them converge at order 8 (global error
/// C h^8: doubling n divides it by 256), the observer sees each step, the last ending on t1.
#[test]
fn fixed_steps_are_dop853_steps_without_error_control() {
    let y0 = [1.0, 0.0, 0.0, 1.0];
    for h in [0.3, 1.1] {
        let (y, s) = integrate(&Circular, 0.0, &y0, h, &Tolerances::fixed(1)).unwrap();
        assert_eq!(y.map(f64::to_bits), one_step(&Circular, y0, h).map(f64::to_bits));
        assert_eq!(
            (s.accepted_steps, s.rejected_steps, s.derivative_evaluations),
            (1, 0, 12)
        );
    }
    // A quarter of the circular orbit: the arc of a guidance cycle is a tenth of that.
    let t1 = 0.5 * PI;
    let errors: Vec<f64> = [2u32, 4, 8]
        .iter()
        .map(|&n| {
            let (y, _) = integrate(&Circular, 0.0, &y0, t1, &Tolerances::fixed(n)).unwrap();
            (y[0] - t1.cos()).hypot(y[1] - t1.sin())
        })
        .collect();
    for pair in errors.windows(2) {
        let ratio = pair[0] / pair[1];
        assert!((180.0..1100.0).contains(&ratio), "errors {errors:?}, ratio {ratio}");
    }
    assert!(errors[2] < 1e-10, "{errors:?}");
    // Forwards and backwards, each step reported, the last on t1 exactly.
    for t1 in [2.5, -2.5] {
        let mut recorder = Recorder::default();
        let (_, s) = integrate_observed(&Circular, 0.5, &y0, t1, &Tolerances::fixed(7), &mut recorder).unwrap();
        assert_eq!((s.accepted_steps, s.derivative_evaluations), (7, 84));
        assert_eq!(recorder.steps.len(), 7);
        assert_eq!(recorder.steps.last().copied(), Some(t1));
        let h = (t1 - 0.5) / 7.0;
        for (i, t) in recorder.steps.iter().enumerate() {
            assert!((t - (0.5 + (i + 1) as f64 * h)).abs() < 1e-15, "{:?}", recorder.steps);
        }
    }
}

/// Fixed steps cannot land on a switch, so a system with events is refused, as is a step count
/// above the bound; a non-finite state is the typed error, as in the adaptive path.
#[test]
fn fixed_steps_refuse_events_and_unbounded_work() {
    let osc = Oscillator {
        events: false,
        velocity_event: false,
    };
    assert_eq!(
        integrate(&osc, 0.0, &[1.0, 0.0], 1.0, &Tolerances::fixed(4)).unwrap_err(),
        IntegrationError::InvalidInput
    );
    let too_many = Tolerances::fixed(Tolerances::MAX_FIXED_STEPS + 1);
    assert_eq!(
        integrate(&Growth, 0.0, &[1.0], 1.0, &too_many).unwrap_err(),
        IntegrationError::InvalidInput
    );
    assert!(integrate(
        &Growth,
        0.0,
        &[1.0],
        1.0,
        &Tolerances::fixed(Tolerances::MAX_FIXED_STEPS)
    )
    .is_ok());
    // y' = y from 1e300 overflows within the first step.
    assert!(matches!(
        integrate(&Growth, 0.0, &[1e300], 1000.0, &Tolerances::fixed(1)),
        Err(IntegrationError::NonFinite { .. })
    ));
}

// ------------------------------------------------------------------------------------------
// Events
// ------------------------------------------------------------------------------------------

/// y' = 1 with the event y - 0.3 (and y - 0.7 as the second event).
struct Ramp;
impl OdeSystem<1, EVENTS> for Ramp {
    fn derivatives(&self, _t: f64, _y: &[f64; 1], d: &mut [f64; 1]) {
        d[0] = 1.0;
    }
    fn events(&self, _t: f64, y: &[f64; 1]) -> [f64; EVENTS] {
        [y[0] - 0.3, y[0] - 0.7]
    }
}

#[test]
fn ramp_steps_onto_both_switches_even_inside_one_long_step() {
    for first_step in [0.0, 10.0] {
        let mut rec = Recorder::default();
        let tl = Tolerances {
            initial_step: first_step,
            ..Tolerances::default()
        };
        let (y, stats) = integrate_observed(&Ramp, 0.0, &[0.0], 1.0, &tl, &mut rec).unwrap();
        assert_eq!(stats.events_located, 2, "{stats:?}");
        assert_eq!(rec.events.len(), 2);
        let (i0, t0, up0) = rec.events[0];
        let (i1, t1, up1) = rec.events[1];
        assert_eq!((i0, i1), (0, 1));
        assert!(up0 && up1, "both events rise");
        assert!((t0 - 0.3).abs() < 1e-15, "first switch at {t0}");
        assert!((t1 - 0.7).abs() < 1e-15, "second switch at {t1}");
        // The step list contains the switch times themselves.
        assert!(rec.steps.contains(&t0) && rec.steps.contains(&t1));
        assert!((y[0] - 1.0).abs() < 1e-15);
    }
    // A zero exactly at t1: the integration stops there, with the event counted once.
    let (y, stats) = integrate(&Ramp, 0.0, &[0.0], 0.3, &Tolerances::default()).unwrap();
    assert!(
        (y[0] - 0.3).abs() < 1e-15 && stats.events_located <= 1,
        "{y:?} {stats:?}"
    );
}

#[derive(Default)]
struct EventStates {
    /// (index, t, event function value at the landing point)
    events: Vec<(usize, f64, f64, bool)>,
}
impl Observer<2> for EventStates {
    fn on_event(&mut self, index: usize, t: f64, y: &[f64; 2], rising: bool) {
        self.events.push((index, t, y[index], rising));
    }
}

#[test]
fn oscillator_zero_crossings_are_located_to_1e_13_in_both_directions() {
    let osc = Oscillator {
        events: true,
        velocity_event: true,
    };
    let t1 = 2.0 * PI + 1.0;
    let tl = tol(1e-14, 1e-14);
    let mut rec = EventStates::default();
    let (y, stats) = integrate_observed(&osc, 0.0, &[1.0, 0.0], t1, &tl, &mut rec).unwrap();
    // x = cos t: zeros at pi/2 (falling) and 3pi/2 (rising); v = -sin t: zero at pi (rising)
    // and 2 pi (falling). t = 0 is a zero of v: it is on no side there and must not count.
    let expected = [
        (0, PI / 2.0, false),
        (1, PI, true),
        (0, 1.5 * PI, true),
        (1, 2.0 * PI, false),
    ];
    assert_eq!(rec.events.len(), expected.len(), "{:?}", rec.events);
    assert_eq!(stats.events_located, 4);
    for ((i, t, g, up), (ei, et, eup)) in rec.events.iter().zip(expected) {
        assert_eq!((*i, *up), (ei, eup));
        assert!(
            (t - et).abs() < 1e-13,
            "event {i} at {t}, expected {et}: {:e}",
            (t - et).abs()
        );
        // The step ends on the zero of the numerical solution itself (a few ulps past it).
        assert!(
            g.abs() < 1e-14 && g.signum() == if eup { 1.0 } else { -1.0 },
            "event {i}: g = {g:e}"
        );
    }
    let err = (y[0] - t1.cos()).abs().max((y[1] + t1.sin()).abs());
    assert!(err < 1e-13, "{err:e}");

    // Backwards from 2 pi + 1 to 0.5 finds the same four zeros, in reverse order.
    let mut back = EventStates::default();
    integrate_observed(&osc, t1, &y, 0.5, &tl, &mut back).unwrap();
    let want = [(1, 2.0 * PI), (0, 1.5 * PI), (1, PI), (0, PI / 2.0)];
    assert_eq!(back.events.len(), 4, "{:?}", back.events);
    for ((i, t, g, _), (wi, wt)) in back.events.iter().zip(want) {
        assert_eq!(*i, wi);
        assert!((t - wt).abs() < 1e-13, "backwards event at {t}, expected {wt}");
        assert!(g.abs() < 1e-14);
    }
}

#[test]
fn many_crossings_never_stick_on_a_zero() {
    // 50 periods: 100 zeros of x; each is found once, on the numerical solution's zero, and
    // the step count stays that of a smooth integration plus a redo per zero.
    let osc = Oscillator {
        events: true,
        velocity_event: false,
    };
    let t1 = 100.0 * PI + 0.5;
    let tl = tol(1e-12, 1e-12);
    let mut rec = EventStates::default();
    let (_, with) = integrate_observed(&osc, 0.0, &[1.0, 0.0], t1, &tl, &mut rec).unwrap();
    let plain = Oscillator {
        events: false,
        velocity_event: false,
    };
    let (y_plain, without) = integrate(&plain, 0.0, &[1.0, 0.0], t1, &tl).unwrap();
    // Phase error of the solution itself at t1 (amplitude 1), growing linearly in time.
    let drift = (y_plain[0] - t1.cos()).hypot(y_plain[1] + t1.sin());
    assert_eq!(with.events_located, 100);
    for (k, (_, t, g, _)) in rec.events.iter().enumerate() {
        let exact = PI / 2.0 + PI * k as f64;
        let allowed = 1e-13 + 2.0 * drift * t / t1;
        assert!(
            (t - exact).abs() < allowed,
            "zero {k} at {t}, expected {exact} (drift {drift:e})"
        );
        // A few ulps of t past the zero (|x'| = 1 there).
        assert!(g.abs() < 16.0 * f64::EPSILON * t, "zero {k}: x = {g:e}");
    }
    assert!(drift < 1e-10, "{drift:e}");
    assert!(
        with.accepted_steps <= without.accepted_steps + 2 * 100,
        "with events {with:?}, without {without:?}"
    );
}

#[test]
fn an_event_starting_on_its_zero_is_not_reported_there() {
    // x = -sin t from (0, -1): x is zero at the start, then at pi and 2 pi.
    let osc = Oscillator {
        events: true,
        velocity_event: false,
    };
    let mut rec = Recorder::default();
    integrate_observed(&osc, 0.0, &[0.0, -1.0], 7.0, &tol(1e-14, 1e-14), &mut rec).unwrap();
    let times: Vec<f64> = rec.events.iter().map(|e| e.1).collect();
    assert_eq!(times.len(), 2, "{times:?}");
    assert!(
        (times[0] - PI).abs() < 1e-13 && (times[1] - 2.0 * PI).abs() < 1e-13,
        "{times:?}"
    );
    assert!(rec.events[0].2 && !rec.events[1].2);
}

/// x'' = -u with u = sign(x): a bang-bang oscillator whose right-hand side jumps at x = 0. From
/// (1, 0) its motion is piecewise parabolic with period 4 sqrt 2 (zeros of x at odd multiples of
/// sqrt 2). `mode`: None evaluates the sign from the state; Some(cell) uses a discrete mode
/// that the observer below switches at the events (the way a hybrid system is integrated).
struct BangBang {
    events: bool,
    mode: Option<Rc<Cell<f64>>>,
}
impl OdeSystem<2, EVENTS> for BangBang {
    fn derivatives(&self, _t: f64, y: &[f64; 2], d: &mut [f64; 2]) {
        let u = match &self.mode {
            Some(m) => m.get(),
            None if y[0] > 0.0 => 1.0,
            None => -1.0,
        };
        *d = [y[1], -u];
    }
    fn events(&self, _t: f64, y: &[f64; 2]) -> [f64; EVENTS] {
        if self.events {
            [y[0], 1.0]
        } else {
            [1.0, 1.0]
        }
    }
}

/// Records the switch times and flips the mode at each.
struct Switcher {
    mode: Option<Rc<Cell<f64>>>,
    times: Vec<f64>,
}
impl Observer<2> for Switcher {
    fn on_event(&mut self, _index: usize, t: f64, _y: &[f64; 2], rising: bool) {
        self.times.push(t);
        if let Some(m) = &self.mode {
            m.set(if rising { 1.0 } else { -1.0 });
        }
    }
}

fn run_bang_bang(events: bool, with_mode: bool, tl: &Tolerances) -> ([f64; 2], IntegrationStats, Vec<f64>) {
    let mode = with_mode.then(|| Rc::new(Cell::new(1.0)));
    let system = BangBang {
        events,
        mode: mode.clone(),
    };
    let mut obs = Switcher {
        mode,
        times: Vec::new(),
    };
    let t1 = 8.0 * 2f64.sqrt(); // two periods: back to (1, 0)
    let (y, stats) = integrate_observed(&system, 0.0, &[1.0, 0.0], t1, tl, &mut obs).unwrap();
    (y, stats, obs.times)
}

#[test]
fn bang_bang_is_exact_with_events_and_a_switched_mode() {
    let tl = tol(1e-9, 1e-9);
    let (y, stats, times) = run_bang_bang(true, true, &tl);
    assert_eq!(stats.events_located, 4);
    for (k, t) in times.iter().enumerate() {
        let exact = (2 * k + 1) as f64 * 2f64.sqrt();
        assert!((t - exact).abs() < 1e-13, "switch {k} at {t}, expected {exact}");
    }
    // Every arc is a parabola, which the 8th-order method integrates exactly once no step
    // straddles a switch: the error is roundoff, at a tolerance of 1e-9.
    let err = (y[0] - 1.0).abs().max(y[1].abs());
    assert!(err < 1e-13, "with events and mode: {err:e} ({stats:?})");
    // Without events the mode never switches: the motion is one parabola, far off.
    let (y, _, _) = run_bang_bang(false, true, &tl);
    assert!((y[0] - 1.0).abs() > 1.0);
}

#[test]
fn bang_bang_from_the_state_sign_is_more_accurate_with_events_than_without() {
    // The right-hand side decides u from the sign of x itself: the last stages of the step
    // that lands on a switch see either sign, so events help less than with a mode (that step
    // is cut down by the error test), but still a lot.
    let tl = tol(1e-9, 1e-9);
    let (y_with, with, times) = run_bang_bang(true, false, &tl);
    let (y_without, without, _) = run_bang_bang(false, false, &tl);
    let err_with = (y_with[0] - 1.0).abs().max(y_with[1].abs());
    let err_without = (y_without[0] - 1.0).abs().max(y_without[1].abs());
    assert_eq!(with.events_located, 4);
    assert!((times[0] - 2f64.sqrt()).abs() < 1e-13, "{times:?}");
    // Measured: 1.2e-10 with events (831 evaluations), 6e-7 without (2343 evaluations).
    assert!(err_with < 1e-9, "with events: {err_with:e} ({with:?})");
    assert!(
        err_without > 100.0 * err_with,
        "without {err_without:e}, with {err_with:e}"
    );
    assert!(with.derivative_evaluations < without.derivative_evaluations);
}

/// The smoothed bang-bang: x'' = -sat(x / eps), linear inside |x| < eps, +-1 outside, the
/// shape of the smoothed throttle with switches at +-eps (events x - eps and x + eps).
struct Smoothed {
    eps: f64,
    events: bool,
}
impl OdeSystem<2, EVENTS> for Smoothed {
    fn derivatives(&self, _t: f64, y: &[f64; 2], d: &mut [f64; 2]) {
        *d = [y[1], -(y[0] / self.eps).clamp(-1.0, 1.0)];
    }
    fn events(&self, _t: f64, y: &[f64; 2]) -> [f64; EVENTS] {
        if self.events {
            [y[0] - self.eps, y[0] + self.eps]
        } else {
            [1.0, 1.0]
        }
    }
}

#[test]
fn smoothed_bang_bang_lands_on_both_switches_and_gains_accuracy() {
    // From (1, 0): parabola down to x = eps at ta = sqrt(2 (1 - eps)) with speed w = ta, then
    // harmonic motion (omega = 1/sqrt eps) across the band in sb = (pi - 2 phi)/omega with
    // tan phi = w / (omega eps), leaving at -eps with the same speed; the period is
    // 4 ta + 2 sb. Analytic switch times: ta, ta + sb, 3 ta + sb, 3 ta + 2 sb, ...
    let eps: f64 = 1e-3;
    let ta = (2.0 * (1.0 - eps)).sqrt();
    let omega = 1.0 / eps.sqrt();
    let phi = (ta / (omega * eps)).atan();
    let sb = (PI - 2.0 * phi) / omega;
    let period = 4.0 * ta + 2.0 * sb;
    let switches = [ta, ta + sb, 3.0 * ta + sb, 3.0 * ta + 2.0 * sb];
    let tl = tol(1e-10, 1e-10);
    let t1 = 2.0 * period;

    let mut rec = EventStates::default();
    let (y_with, with) =
        integrate_observed(&Smoothed { eps, events: true }, 0.0, &[1.0, 0.0], t1, &tl, &mut rec).unwrap();
    let (y_without, without) = integrate(&Smoothed { eps, events: false }, 0.0, &[1.0, 0.0], t1, &tl).unwrap();
    assert_eq!(with.events_located, 8, "{:?}", rec.events);
    for (k, (_, t, _, _)) in rec.events.iter().enumerate() {
        let exact = switches[k % 4] + period * (k / 4) as f64;
        assert!((t - exact).abs() < 1e-10, "switch {k} at {t}, expected {exact}");
    }
    let err_with = (y_with[0] - 1.0).abs().max(y_with[1].abs());
    let err_without = (y_without[0] - 1.0).abs().max(y_without[1].abs());
    // Measured: 5e-14 with events (1127 evaluations), 3e-8 without (2414 evaluations).
    assert!(err_with < 1e-12, "with events {err_with:e} ({with:?})");
    assert!(
        err_without > 1000.0 * err_with,
        "without {err_without:e} ({without:?}), with {err_with:e}"
    );
    assert!(
        with.derivative_evaluations < without.derivative_evaluations,
        "with {with:?}, without {without:?}"
    );
}

// ------------------------------------------------------------------------------------------
// Bad input and failures
// ------------------------------------------------------------------------------------------

struct Nan;
impl OdeSystem<1> for Nan {
    fn derivatives(&self, _t: f64, _y: &[f64; 1], d: &mut [f64; 1]) {
        d[0] = f64::NAN;
    }
}

/// y' = 1/(1 - t): y = -ln(1 - t), singular at t = 1.
struct Singular;
impl OdeSystem<1> for Singular {
    fn derivatives(&self, t: f64, _y: &[f64; 1], d: &mut [f64; 1]) {
        d[0] = 1.0 / (1.0 - t);
    }
}

/// y' = y^2 from y = 1: y = 1 / (1 - t), blows up at t = 1.
struct Blowup;
impl OdeSystem<1> for Blowup {
    fn derivatives(&self, _t: f64, y: &[f64; 1], d: &mut [f64; 1]) {
        d[0] = y[0] * y[0];
    }
}

/// y' = sqrt(0.5 - t): NaN beyond t = 0.5.
struct NanLater;
impl OdeSystem<1> for NanLater {
    fn derivatives(&self, t: f64, _y: &[f64; 1], d: &mut [f64; 1]) {
        d[0] = (0.5 - t).sqrt();
    }
}

#[test]
fn bad_arguments_are_refused() {
    let ok = Tolerances::default();
    let bad = |r: Result<([f64; 1], IntegrationStats), IntegrationError>| {
        assert_eq!(r.unwrap_err(), IntegrationError::InvalidInput)
    };
    bad(integrate(&Growth, 0.0, &[f64::NAN], 1.0, &ok));
    bad(integrate(&Growth, 0.0, &[f64::INFINITY], 1.0, &ok));
    bad(integrate(&Growth, 0.0, &[1.0], f64::NAN, &ok));
    bad(integrate(&Growth, f64::NEG_INFINITY, &[1.0], 1.0, &ok));
    bad(integrate(&Growth, -1e308, &[1.0], 1e308, &ok)); // span overflows
    for (r, a) in [
        (0.0, 1e-12),
        (-1e-12, 1e-12),
        (1e-12, 0.0),
        (1e-12, -1.0),
        (f64::NAN, 1e-12),
        (1e-12, f64::INFINITY),
    ] {
        bad(integrate(&Growth, 0.0, &[1.0], 1.0, &tol(r, a)));
    }
    bad(integrate(&Growth, 0.0, &[1.0], 1.0, &Tolerances { max_steps: 0, ..ok }));
    bad(integrate(
        &Growth,
        0.0,
        &[1.0],
        1.0,
        &Tolerances {
            initial_step: -0.1,
            ..ok
        },
    ));
    bad(integrate(
        &Growth,
        0.0,
        &[1.0],
        1.0,
        &Tolerances {
            initial_step: f64::NAN,
            ..ok
        },
    ));
}

#[test]
fn failures_are_typed_errors_not_panics_or_hangs() {
    let ok = Tolerances::default();
    assert_eq!(
        integrate(&Nan, 0.0, &[1.0], 1.0, &ok).unwrap_err(),
        IntegrationError::NonFinite { t: 0.0 }
    );

    match integrate(&Singular, 0.0, &[0.0], 2.0, &ok).unwrap_err() {
        IntegrationError::StepSizeUnderflow { t } | IntegrationError::NonFinite { t } => {
            assert!((0.999..=1.001).contains(&t), "stopped at {t}")
        }
        e => panic!("singular: {e:?}"),
    }
    match integrate(&Blowup, 0.0, &[1.0], 2.0, &ok).unwrap_err() {
        IntegrationError::StepSizeUnderflow { t } | IntegrationError::NonFinite { t } => {
            assert!((0.99..=1.001).contains(&t), "stopped at {t}")
        }
        e => panic!("blow-up: {e:?}"),
    }
    match integrate(&NanLater, 0.0, &[0.0], 1.0, &ok).unwrap_err() {
        IntegrationError::StepSizeUnderflow { t } | IntegrationError::NonFinite { t } => {
            assert!((0.4..=0.5).contains(&t), "stopped at {t}")
        }
        e => panic!("NaN beyond 0.5: {e:?}"),
    }
    // A budget of 5 steps is not enough for 20 oscillator periods.
    let osc = Oscillator {
        events: false,
        velocity_event: false,
    };
    let small = Tolerances { max_steps: 5, ..ok };
    match integrate(&osc, 0.0, &[1.0, 0.0], 40.0 * PI, &small).unwrap_err() {
        IntegrationError::StepBudgetExhausted { t } => assert!(t > 0.0 && t < 40.0 * PI),
        e => panic!("budget: {e:?}"),
    }
    // An unreachable tolerance ends in an error or a result, never a hang.
    let _ = integrate(&osc, 0.0, &[1.0, 0.0], 10.0, &tol(1e-300, 1e-300));
}

#[test]
fn arbitrary_inputs_never_panic() {
    use proptest::prelude::*;
    let values = prop_oneof![
        Just(f64::NAN),
        Just(f64::INFINITY),
        Just(f64::NEG_INFINITY),
        Just(0.0),
        Just(f64::MAX),
        Just(f64::MIN_POSITIVE),
        -1e3f64..1e3,
        proptest::num::f64::ANY,
    ];
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig::with_cases(512));
    runner
        .run(
            &(values.clone(), values.clone(), values.clone(), values.clone(), values),
            |(y0, y1, t1, rt, h0)| {
                let tl = Tolerances {
                    relative: rt,
                    absolute: 1e-12,
                    max_steps: 2_000,
                    initial_step: h0,
                    fixed_steps: 0,
                };
                let osc = Oscillator {
                    events: true,
                    velocity_event: true,
                };
                let _ = integrate(&osc, 0.0, &[y0, y1], t1, &tl);
                let _ = integrate(&Blowup, 0.0, &[y0], t1, &tl);
                Ok(())
            },
        )
        .unwrap();
}
