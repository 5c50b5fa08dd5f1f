//! Pontryagin's necessary conditions for the mass-optimal problem with the energy-to-fuel
//! homotopy (SPEC section 3, thesis Chapter 3).
//!
//! State + costate y = (r, v, m, lambda_r, lambda_v, lambda_m), 10 components. The right-hand
//! side is written once, generic over a dual-number type, so the variational equations
//! (sensitivity of y to the initial costates) come out exact by forward-mode differentiation of
//! the very same code instead of a hand-derived Jacobian that could drift from it.

use nalgebra::{Const, SVector};
use num_dual::{Derivative, DualNum, DualVec64};
use std::cell::Cell;

use onboard::integrator::{
    integrate_observed, IntegrationError, IntegrationStats, Observer, OdeSystem, Tolerances, MAX_EVENTS,
};
use shared::spacecraft::CanonicalSpacecraft;

/// State + costate length.
pub const Y_LEN: usize = 10;
/// Shooting variables that the sensitivity is taken against: the five initial costates.
pub const SENS_COLS: usize = 5;
/// State + costate + 10x5 sensitivity matrix (column-major after the first 10).
pub const YS_LEN: usize = Y_LEN + Y_LEN * SENS_COLS;

/// Indices into y.
pub mod idx {
    pub const R: usize = 0;
    pub const V: usize = 2;
    pub const M: usize = 4;
    pub const LR: usize = 5;
    pub const LV: usize = 7;
    pub const LM: usize = 9;
}

/// The spacecraft and the homotopy parameter eps of the running cost L = u - eps u (1 - u).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OptimalControlParams {
    pub spacecraft: CanonicalSpacecraft,
    pub eps: f64,
}

/// Switching function rho = lambda_m + c |lambda_v| / m - 1.
pub fn switching_function<D: DualNum<Primitive = f64> + Copy>(y: &[D; Y_LEN], exhaust_speed: f64) -> D {
    let lv = (y[idx::LV] * y[idx::LV] + y[idx::LV + 1] * y[idx::LV + 1]).sqrt();
    y[idx::LM] + lv * exhaust_speed / y[idx::M] - 1.0
}

/// Smoothed optimal throttle (SPEC section 3): 1 above +eps, 0 below -eps, linear between.
/// With eps = 0 it is the bang-bang law. Derivatives flow through the linear part only.
pub fn optimal_throttle<D: DualNum<Primitive = f64> + Copy>(rho: D, eps: f64) -> D {
    let r = rho.re();
    if eps <= 0.0 {
        return D::from(if r > 0.0 { 1.0 } else { 0.0 });
    }
    if r > eps {
        D::from(1.0)
    } else if r < -eps {
        D::from(0.0)
    } else {
        (rho / eps + 1.0) * 0.5
    }
}

/// Which branch of the smoothed throttle law applies: u = 0, the linear ramp, or u = 1.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Regime {
    Coast,
    Ramp,
    Full,
}

impl Regime {
    /// The branch that the throttle law selects at switching function `rho`.
    pub fn of(rho: f64, eps: f64) -> Self {
        if eps <= 0.0 {
            if rho > 0.0 {
                Self::Full
            } else {
                Self::Coast
            }
        } else if rho > eps {
            Self::Full
        } else if rho < -eps {
            Self::Coast
        } else {
            Self::Ramp
        }
    }

    /// The branch entered when event `index` (0: rho - eps, 1: rho + eps) is crossed upwards
    /// (`rising`) or downwards.
    pub fn after_event(index: usize, rising: bool, eps: f64) -> Self {
        match (index, rising) {
            (0, true) => Self::Full,
            (1, false) => Self::Coast,
            _ if eps <= 0.0 => {
                if rising {
                    Self::Full
                } else {
                    Self::Coast
                }
            }
            _ => Self::Ramp,
        }
    }

    /// The throttle of this branch (the ramp extended beyond [-eps, eps] as a straight line).
    pub fn throttle<D: DualNum<Primitive = f64> + Copy>(self, rho: D, eps: f64) -> D {
        match self {
            Self::Coast => D::from(0.0),
            Self::Full => D::from(1.0),
            Self::Ramp => (rho / eps + 1.0) * 0.5,
        }
    }
}

/// dy/dt of the state-costate system with the optimal control substituted.
pub fn state_costate_rhs<D: DualNum<Primitive = f64> + Copy>(y: &[D; Y_LEN], p: &OptimalControlParams) -> [D; Y_LEN] {
    let regime = Regime::of(switching_function(y, p.spacecraft.exhaust_speed).re(), p.eps);
    state_costate_rhs_in(y, p, regime)
}

/// dy/dt of the state-costate system on one branch of the throttle law. Integrating with the
/// branch held fixed between located switches (see [`propagate`]) keeps every Runge-Kutta step
/// on one smooth arc: the variational equations jump at a switch (du/drho goes from 0 to
/// 1/(2 eps)), and a step whose last stages see the other branch is rejected again and again
/// at small eps until the step size underflows.
pub fn state_costate_rhs_in<D: DualNum<Primitive = f64> + Copy>(
    y: &[D; Y_LEN],
    p: &OptimalControlParams,
    regime: Regime,
) -> [D; Y_LEN] {
    let (t_max, c) = (p.spacecraft.thrust, p.spacecraft.exhaust_speed);
    let (x, yy) = (y[idx::R], y[idx::R + 1]);
    let (vx, vy, m) = (y[idx::V], y[idx::V + 1], y[idx::M]);
    let (lrx, lry) = (y[idx::LR], y[idx::LR + 1]);
    let (lvx, lvy) = (y[idx::LV], y[idx::LV + 1]);
    let r2 = x * x + yy * yy;
    let r = r2.sqrt();
    let r3 = r2 * r;
    let r5 = r3 * r2;
    let lv = (lvx * lvx + lvy * lvy).sqrt();
    let u = regime.throttle(switching_function(y, c), p.eps);
    // Primer vector: thrust opposite lambda_v.
    let acc = u * t_max / m;
    let (ax, ay) = (-acc * lvx / lv, -acc * lvy / lv);
    let r_dot_lv = x * lvx + yy * lvy;
    [
        vx,
        vy,
        -x / r3 + ax,
        -y[idx::R + 1] / r3 + ay,
        -u * t_max / c,
        lvx / r3 - x * r_dot_lv * 3.0 / r5,
        lvy / r3 - yy * r_dot_lv * 3.0 / r5,
        -lrx,
        -lry,
        -u * t_max * lv / (m * m),
    ]
}

/// The Hamiltonian for an arbitrary control (u, alpha): used by the tests to check the costate
/// equations and the optimal control independently of the code above.
pub fn hamiltonian(y: &[f64; Y_LEN], u: f64, alpha: [f64; 2], p: &OptimalControlParams) -> f64 {
    let (t_max, c) = (p.spacecraft.thrust, p.spacecraft.exhaust_speed);
    let r = y[0].hypot(y[1]);
    let g = [-y[0] / r.powi(3), -y[1] / r.powi(3)];
    let m = y[idx::M];
    t_max / c * (u - p.eps * u * (1.0 - u))
        + y[idx::LR] * y[idx::V]
        + y[idx::LR + 1] * y[idx::V + 1]
        + y[idx::LV] * (g[0] + t_max * u * alpha[0] / m)
        + y[idx::LV + 1] * (g[1] + t_max * u * alpha[1] / m)
        - y[idx::LM] * t_max * u / c
}

/// The state-costate ODE, stepping exactly onto the throttle switches rho = +-eps.
#[derive(Debug, Clone, Copy)]
pub struct StateCostate(pub OptimalControlParams);

impl OdeSystem<Y_LEN> for StateCostate {
    fn derivatives(&self, _t: f64, y: &[f64; Y_LEN], dydt: &mut [f64; Y_LEN]) {
        *dydt = state_costate_rhs(y, &self.0);
    }

    fn events(&self, _t: f64, y: &[f64; Y_LEN]) -> [f64; MAX_EVENTS] {
        switch_events(y, &self.0)
    }
}

fn switch_events(y: &[f64; Y_LEN], p: &OptimalControlParams) -> [f64; MAX_EVENTS] {
    let rho = switching_function(y, p.spacecraft.exhaust_speed);
    [rho - p.eps, rho + p.eps]
}

/// State-costate plus the sensitivity matrix d y / d lambda_0 (10 x 5), by forward-mode duals.
#[derive(Debug, Clone, Copy)]
pub struct StateCostateSensitivity(pub OptimalControlParams);

type Dual5 = DualVec64<Const<SENS_COLS>>;

/// The state-costate derivatives and the variational equations on one throttle branch.
fn sensitivity_rhs(ys: &[f64; YS_LEN], params: &OptimalControlParams, regime: Regime, dydt: &mut [f64; YS_LEN]) {
    // Seed each component with its row of the sensitivity matrix: the dual parts of f then
    // are J(y) * Phi, the right-hand side of the variational equations.
    let y: [Dual5; Y_LEN] = core::array::from_fn(|i| {
        let row = SVector::<f64, SENS_COLS>::from_fn(|k, _| ys[Y_LEN + k * Y_LEN + i]);
        Dual5::new(ys[i], Derivative::some(row))
    });
    let f = state_costate_rhs_in(&y, params, regime);
    for (i, fi) in f.iter().enumerate() {
        dydt[i] = fi.re;
        let d = fi.eps.unwrap_generic(Const::<SENS_COLS>, Const::<1>);
        for k in 0..SENS_COLS {
            dydt[Y_LEN + k * Y_LEN + i] = d[k];
        }
    }
}

impl StateCostateSensitivity {
    /// Initial condition: y0 with the identity on the costate rows of the sensitivity.
    pub fn initial(y0: &[f64; Y_LEN]) -> [f64; YS_LEN] {
        let mut ys = [0.0; YS_LEN];
        ys[..Y_LEN].copy_from_slice(y0);
        for k in 0..SENS_COLS {
            ys[Y_LEN + k * Y_LEN + idx::LR + k] = 1.0;
        }
        ys
    }

    /// Sensitivity entry d y_i / d lambda0_k.
    pub fn sensitivity(ys: &[f64; YS_LEN], i: usize, k: usize) -> f64 {
        ys[Y_LEN + k * Y_LEN + i]
    }
}

impl OdeSystem<YS_LEN> for StateCostateSensitivity {
    fn derivatives(&self, _t: f64, ys: &[f64; YS_LEN], dydt: &mut [f64; YS_LEN]) {
        let y: [f64; Y_LEN] = core::array::from_fn(|i| ys[i]);
        let regime = Regime::of(switching_function(&y, self.0.spacecraft.exhaust_speed), self.0.eps);
        sensitivity_rhs(ys, &self.0, regime, dydt);
    }

    fn events(&self, _t: f64, ys: &[f64; YS_LEN]) -> [f64; MAX_EVENTS] {
        let y: [f64; Y_LEN] = core::array::from_fn(|i| ys[i]);
        switch_events(&y, &self.0)
    }
}

/// The state-costate ODE with the throttle branch held in a discrete mode that only the located
/// switches change (see [`state_costate_rhs_in`]).
struct Modal<'a> {
    params: OptimalControlParams,
    regime: &'a Cell<Regime>,
}

impl OdeSystem<Y_LEN> for Modal<'_> {
    fn derivatives(&self, _t: f64, y: &[f64; Y_LEN], dydt: &mut [f64; Y_LEN]) {
        *dydt = state_costate_rhs_in(y, &self.params, self.regime.get());
    }

    fn events(&self, _t: f64, y: &[f64; Y_LEN]) -> [f64; MAX_EVENTS] {
        switch_events(y, &self.params)
    }
}

/// [`StateCostateSensitivity`] with the branch held in a discrete mode.
struct ModalSensitivity<'a> {
    params: OptimalControlParams,
    regime: &'a Cell<Regime>,
}

impl OdeSystem<YS_LEN> for ModalSensitivity<'_> {
    fn derivatives(&self, _t: f64, ys: &[f64; YS_LEN], dydt: &mut [f64; YS_LEN]) {
        sensitivity_rhs(ys, &self.params, self.regime.get(), dydt);
    }

    fn events(&self, _t: f64, ys: &[f64; YS_LEN]) -> [f64; MAX_EVENTS] {
        let y: [f64; Y_LEN] = core::array::from_fn(|i| ys[i]);
        switch_events(&y, &self.params)
    }
}

/// Switches the mode at every located switch.
struct RegimeSwitch<'a> {
    regime: &'a Cell<Regime>,
    eps: f64,
}

impl<const N: usize> Observer<N> for RegimeSwitch<'_> {
    fn on_event(&mut self, index: usize, _t: f64, _y: &[f64; N], rising: bool) {
        self.regime.set(Regime::after_event(index, rising, self.eps));
    }
}

std::thread_local! {
    /// Integration work done on this thread by [`propagate`] and [`propagate_sensitivity`], in
    /// Runge-Kutta trial steps of the 10-state system (a step of the 60-state sensitivity system
    /// counts [`SENSITIVITY_STEP_WORK`]). Solver budgets are taken from it: a count, unlike a
    /// clock, is the same on every machine and under any load.
    static WORK: Cell<u64> = const { Cell::new(0) };
}

/// Work of one sensitivity step relative to a plain one (measured: ~6x the derivative cost).
pub const SENSITIVITY_STEP_WORK: u64 = 6;

/// The integration work done on this thread so far (see [`WORK`]).
pub fn work_done() -> u64 {
    WORK.with(Cell::get)
}

fn add_work(stats: &IntegrationStats, weight: u64) {
    let steps = u64::from(stats.accepted_steps) + u64::from(stats.rejected_steps);
    WORK.with(|w| w.set(w.get().saturating_add(steps * weight)));
}

/// Propagates the state-costate system from (t0, y0) to t1, stepping onto every switch and
/// holding the throttle branch fixed in between (the way every solver propagation is done).
pub fn propagate(
    params: &OptimalControlParams,
    t0: f64,
    y0: &[f64; Y_LEN],
    t1: f64,
    tolerances: &Tolerances,
) -> Result<[f64; Y_LEN], IntegrationError> {
    let regime = Cell::new(Regime::of(
        switching_function(y0, params.spacecraft.exhaust_speed),
        params.eps,
    ));
    let system = Modal {
        params: *params,
        regime: &regime,
    };
    let mut observer = RegimeSwitch {
        regime: &regime,
        eps: params.eps,
    };
    let (y, stats) = integrate_observed(&system, t0, y0, t1, tolerances, &mut observer).inspect_err(|_| {
        // A failed propagation spent at most its step budget.
        WORK.with(|w| w.set(w.get().saturating_add(u64::from(tolerances.max_steps))));
    })?;
    add_work(&stats, 1);
    Ok(y)
}

/// Records the time spent on the ramp (0 < u < 1) of the throttle law.
struct RampClock<'a> {
    switch: RegimeSwitch<'a>,
    since: f64,
    on_ramp: f64,
}

impl<const N: usize> Observer<N> for RampClock<'_> {
    fn on_event(&mut self, index: usize, t: f64, y: &[f64; N], rising: bool) {
        if self.switch.regime.get() == Regime::Ramp {
            self.on_ramp += t - self.since;
        }
        self.since = t;
        Observer::<N>::on_event(&mut self.switch, index, t, y, rising);
    }
}

/// Fraction of [0, t1] that the optimal trajectory from y0 spends on the throttle ramp
/// (|rho| < eps). A fuel-optimal solution is bang-bang, so at small eps this is small; a large
/// value means the smoothed extremal hugs the switching surface (a singular, degenerate limit).
pub fn ramp_fraction(
    params: &OptimalControlParams,
    y0: &[f64; Y_LEN],
    t1: f64,
    tolerances: &Tolerances,
) -> Result<f64, IntegrationError> {
    let regime = Cell::new(Regime::of(
        switching_function(y0, params.spacecraft.exhaust_speed),
        params.eps,
    ));
    let system = Modal {
        params: *params,
        regime: &regime,
    };
    let mut clock = RampClock {
        switch: RegimeSwitch {
            regime: &regime,
            eps: params.eps,
        },
        since: 0.0,
        on_ramp: 0.0,
    };
    let (_, stats) = integrate_observed(&system, 0.0, y0, t1, tolerances, &mut clock)?;
    add_work(&stats, 1);
    if regime.get() == Regime::Ramp {
        clock.on_ramp += t1 - clock.since;
    }
    Ok(clock.on_ramp / t1)
}

/// [`propagate`] with the sensitivity matrix d y / d lambda_0 (see [`StateCostateSensitivity`]),
/// from y0 with the identity on the costate rows.
pub fn propagate_sensitivity(
    params: &OptimalControlParams,
    y0: &[f64; Y_LEN],
    t1: f64,
    tolerances: &Tolerances,
) -> Result<[f64; YS_LEN], IntegrationError> {
    let regime = Cell::new(Regime::of(
        switching_function(y0, params.spacecraft.exhaust_speed),
        params.eps,
    ));
    let system = ModalSensitivity {
        params: *params,
        regime: &regime,
    };
    let mut observer = RegimeSwitch {
        regime: &regime,
        eps: params.eps,
    };
    let ys0 = StateCostateSensitivity::initial(y0);
    let (y, stats) = integrate_observed(&system, 0.0, &ys0, t1, tolerances, &mut observer).inspect_err(|_| {
        WORK.with(|w| {
            w.set(
                w.get()
                    .saturating_add(u64::from(tolerances.max_steps) * SENSITIVITY_STEP_WORK),
            )
        });
    })?;
    add_work(&stats, SENSITIVITY_STEP_WORK);
    Ok(y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use onboard::integrator::integrate;
    use shared::spacecraft::Spacecraft;

    fn params(eps: f64) -> OptimalControlParams {
        OptimalControlParams {
            spacecraft: Spacecraft::MSR_ERO.canonical().unwrap(),
            eps,
        }
    }

    /// A state away from the Sun with costates that put rho inside (-eps, eps) for eps = 0.5.
    fn sample_y() -> [f64; Y_LEN] {
        [0.9, 0.5, -0.4, 0.8, 0.85, 0.3, -0.2, -0.25, 0.4, 0.1]
    }

    fn optimal_control(y: &[f64; Y_LEN], p: &OptimalControlParams) -> (f64, [f64; 2]) {
        let u = optimal_throttle(switching_function(y, p.spacecraft.exhaust_speed), p.eps);
        let lv = y[idx::LV].hypot(y[idx::LV + 1]);
        (u, [-y[idx::LV] / lv, -y[idx::LV + 1] / lv])
    }

    #[test]
    fn costate_equations_are_minus_the_gradient_of_the_hamiltonian() {
        for eps in [0.5, 1.0, 0.0] {
            let p = params(eps);
            let y = sample_y();
            let (u, alpha) = optimal_control(&y, &p);
            let f = state_costate_rhs(&y, &p);
            let h = 1e-6;
            for i in 0..Y_LEN {
                let (mut yp, mut ym) = (y, y);
                yp[i] += h;
                ym[i] -= h;
                // Control frozen at its optimum (envelope theorem).
                let dh = (hamiltonian(&yp, u, alpha, &p) - hamiltonian(&ym, u, alpha, &p)) / (2.0 * h);
                // dx/dt = dH/dlambda, dlambda/dt = -dH/dx.
                let expect = if i < 5 { -dh } else { dh };
                let j = if i < 5 { i + 5 } else { i - 5 };
                assert!(
                    (f[j] - expect).abs() < 1e-8,
                    "eps {eps} component {j}: {} vs {expect}",
                    f[j]
                );
            }
        }
    }

    #[test]
    fn optimal_control_minimises_the_hamiltonian() {
        for eps in [1.0, 0.3, 0.05, 0.0] {
            let p = params(eps);
            for s in 0..20 {
                let mut y = sample_y();
                y[idx::LM] = -0.6 + 0.06 * f64::from(s); // sweep rho across both switches
                let (u_opt, a_opt) = optimal_control(&y, &p);
                let h_opt = hamiltonian(&y, u_opt, a_opt, &p);
                for iu in 0..=20 {
                    for ia in 0..36 {
                        let u = f64::from(iu) / 20.0;
                        let ang = f64::from(ia) * 10f64.to_radians();
                        let h = hamiltonian(&y, u, [ang.cos(), ang.sin()], &p);
                        assert!(h >= h_opt - 1e-14, "eps {eps}: u {u} beats u* {u_opt}");
                    }
                }
            }
        }
    }

    #[test]
    fn smoothed_throttle_is_continuous_at_the_switches() {
        for eps in [1.0, 0.1, 1e-4] {
            for edge in [-eps, eps] {
                let below: f64 = optimal_throttle(edge - 1e-12 * eps, eps);
                let above: f64 = optimal_throttle(edge + 1e-12 * eps, eps);
                assert!((below - above).abs() < 1e-11, "jump at {edge}");
            }
            assert_eq!(optimal_throttle(0.0, eps), 0.5);
        }
    }

    #[test]
    fn sensitivity_matrix_matches_finite_differences() {
        let p = params(0.5);
        let y0 = [1.0, 0.0, 0.0, 1.0, 1.0, 0.2, 0.1, -0.3, -0.6, 0.05];
        let tol = Tolerances {
            relative: 1e-12,
            absolute: 1e-13,
            ..Tolerances::default()
        };
        let tf = 2.5;
        let (ys, _) = integrate(
            &StateCostateSensitivity(p),
            0.0,
            &StateCostateSensitivity::initial(&y0),
            tf,
            &tol,
        )
        .unwrap();
        // The plain system and the augmented one agree on y.
        let (y_plain, _) = integrate(&StateCostate(p), 0.0, &y0, tf, &tol).unwrap();
        for i in 0..Y_LEN {
            assert!((ys[i] - y_plain[i]).abs() < 1e-9);
        }
        let h = 1e-6;
        for k in 0..SENS_COLS {
            let (mut yp, mut ym) = (y0, y0);
            yp[idx::LR + k] += h;
            ym[idx::LR + k] -= h;
            let (fp, _) = integrate(&StateCostate(p), 0.0, &yp, tf, &tol).unwrap();
            let (fm, _) = integrate(&StateCostate(p), 0.0, &ym, tf, &tol).unwrap();
            for i in 0..Y_LEN {
                let fd = (fp[i] - fm[i]) / (2.0 * h);
                let s = StateCostateSensitivity::sensitivity(&ys, i, k);
                assert!(
                    (s - fd).abs() < 1e-5 * (1.0 + fd.abs()),
                    "d y{i} / d lambda{k}: {s} vs {fd}"
                );
            }
        }
    }

    #[test]
    fn regime_follows_the_throttle_law_and_the_event_directions() {
        for eps in [0.5, 1e-4, 0.0] {
            for rho in [-1.0, -0.3, -1e-5, 0.0, 2e-5, 0.3, 1.0] {
                let regime = Regime::of(rho, eps);
                let u: f64 = regime.throttle(rho, eps.max(1e-300));
                let expect: f64 = optimal_throttle(rho, eps);
                assert!((u - expect).abs() < 1e-15, "eps {eps} rho {rho}: {regime:?}");
            }
        }
        // Event 0 is rho - eps, event 1 is rho + eps; crossing one moves to the adjacent branch.
        assert_eq!(Regime::after_event(0, true, 0.1), Regime::Full);
        assert_eq!(Regime::after_event(0, false, 0.1), Regime::Ramp);
        assert_eq!(Regime::after_event(1, true, 0.1), Regime::Ramp);
        assert_eq!(Regime::after_event(1, false, 0.1), Regime::Coast);
        // Bang-bang: both events are rho itself.
        assert_eq!(Regime::after_event(0, false, 0.0), Regime::Coast);
        assert_eq!(Regime::after_event(1, true, 0.0), Regime::Full);
    }

    /// A propagation that switches between the three branches many times agrees with the
    /// state-dependent right-hand side, and its sensitivities with finite differences, at a small
    /// eps where the branch jump of the variational equations matters.
    #[test]
    fn modal_propagation_matches_the_plain_system_and_finite_differences() {
        let p = params(1e-3);
        let y0 = [1.0, 0.0, 0.0, 1.0, 1.0, 0.2, 0.1, -0.3, -0.6, 0.05];
        let tol = Tolerances {
            relative: 1e-12,
            absolute: 1e-13,
            ..Tolerances::default()
        };
        let tf = 6.0;
        let modal = propagate(&p, 0.0, &y0, tf, &tol).unwrap();
        let (plain, stats) = integrate(&StateCostate(p), 0.0, &y0, tf, &tol).unwrap();
        assert!(stats.events_located >= 2, "the test arc should switch: {stats:?}");
        for i in 0..Y_LEN {
            assert!(
                (modal[i] - plain[i]).abs() < 1e-8 * (1.0 + plain[i].abs()),
                "y{i}: {} vs {}",
                modal[i],
                plain[i]
            );
        }
        let ys = propagate_sensitivity(&p, &y0, tf, &tol).unwrap();
        let h = 1e-7;
        for k in 0..SENS_COLS {
            let (mut yp, mut ym) = (y0, y0);
            yp[idx::LR + k] += h;
            ym[idx::LR + k] -= h;
            let fp = propagate(&p, 0.0, &yp, tf, &tol).unwrap();
            let fm = propagate(&p, 0.0, &ym, tf, &tol).unwrap();
            for i in 0..Y_LEN {
                let fd = (fp[i] - fm[i]) / (2.0 * h);
                let s = StateCostateSensitivity::sensitivity(&ys, i, k);
                assert!(
                    (s - fd).abs() < 1e-4 * (1.0 + fd.abs()),
                    "d y{i} / d lambda{k}: {s} vs {fd}"
                );
            }
        }
    }
}
