//! Pontryagin's necessary conditions for the mass-optimal problem with the energy-to-fuel
//! homotopy (docs/spec.md section 3, thesis Chapter 3).
//!
//! State + costate y = (r, v, m, lambda_r, lambda_v, lambda_m), 10 components. The right-hand
//! side is written once, generic over a dual-number type, so the variational equations
//! (sensitivity of y to the initial costates) come out exact by forward-mode differentiation of
//! the very same code instead of a hand-derived Jacobian that could drift from it.

use nalgebra::{Const, SVector};
use num_dual::{Derivative, DualNum, DualVec64};
use std::cell::Cell;

use onboard::integrator::{integrate_observed, IntegrationError, IntegrationStats, Observer, OdeSystem, Tolerances};
use shared::spacecraft::CanonicalSpacecraft;

/// Event functions of the state-costate systems: the throttle switches rho = -eps and
/// rho = +eps (or, in the modal propagation, a switch and the rate of rho).
pub const SWITCH_EVENTS: usize = 2;
/// State + costate length.
pub const Y_LEN: usize = 10;
/// Shooting variables that the sensitivity is taken against: the five initial costates.
pub const SENS_COLS: usize = 5;
/// State + costate + 10x5 sensitivity matrix (column-major after the first 10).
pub const YS_LEN: usize = Y_LEN + Y_LEN * SENS_COLS;

/// Indices into y.
pub mod idx {
    /// Position (x, y), AU: `y[0..2]`.
    pub const R: usize = 0;
    /// Velocity (vx, vy), AU/t*: `y[2..4]`.
    pub const V: usize = 2;
    /// Mass, fraction of m0: `y[4]`.
    pub const M: usize = 4;
    /// Position costate lambda_r: `y[5..7]`.
    pub const LR: usize = 5;
    /// Velocity costate lambda_v: `y[7..9]`.
    pub const LV: usize = 7;
    /// Mass costate lambda_m: `y[9]`.
    pub const LM: usize = 9;
}

/// The spacecraft and the homotopy parameter eps of the running cost L = u - eps u (1 - u).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OptimalControlParams {
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
    /// Homotopy parameter in [0, 1]: 1 energy-optimal, 0 fuel-optimal (bang-bang).
    pub eps: f64,
}

/// Switching function rho = lambda_m + c |lambda_v| / m - 1.
pub fn switching_function<D: DualNum<Primitive = f64> + Copy>(y: &[D; Y_LEN], exhaust_speed: f64) -> D {
    let lv = (y[idx::LV] * y[idx::LV] + y[idx::LV + 1] * y[idx::LV + 1]).sqrt();
    y[idx::LM] + lv * exhaust_speed / y[idx::M] - 1.0
}

/// Smoothed optimal throttle (docs/spec.md section 3): 1 above +eps, 0 below -eps, linear between.
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
    /// rho < -eps: u = 0.
    Coast,
    /// |rho| <= eps: u = (1 + rho / eps) / 2.
    Ramp,
    /// rho > eps: u = 1.
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

impl OdeSystem<Y_LEN, SWITCH_EVENTS> for StateCostate {
    fn derivatives(&self, _t: f64, y: &[f64; Y_LEN], dydt: &mut [f64; Y_LEN]) {
        *dydt = state_costate_rhs(y, &self.0);
    }

    fn events(&self, _t: f64, y: &[f64; Y_LEN]) -> [f64; SWITCH_EVENTS] {
        switch_events(y, &self.0)
    }
}

fn switch_events(y: &[f64; Y_LEN], p: &OptimalControlParams) -> [f64; SWITCH_EVENTS] {
    let rho = switching_function(y, p.spacecraft.exhaust_speed);
    [rho - p.eps, rho + p.eps]
}

/// Time derivative of the switching function: d rho / dt = -(c / m) lambda_v . lambda_r / |lambda_v|
/// (the mass terms of lambda_m' and of (c |lambda_v| / m)' cancel, so it does not depend on u).
pub fn switching_rate(y: &[f64; Y_LEN], exhaust_speed: f64) -> f64 {
    let lv = y[idx::LV].hypot(y[idx::LV + 1]);
    let dot = y[idx::LV] * y[idx::LR] + y[idx::LV + 1] * y[idx::LR + 1];
    -exhaust_speed * dot / (y[idx::M] * lv)
}

/// The event functions of the modal propagation in branch `regime`. On the ramp they are the two
/// switches rho -+ eps. On a coast only rho + eps can be crossed, so the other slot watches
/// d rho / dt instead: a rise of rho above -eps and back that fits inside one integration step
/// (a short burn where rho peaks near eps, common on these nearly singular transfers at small
/// eps) changes the sign of no switch function at the step's ends and would be stepped over,
/// but it puts a maximum of rho inside the step, which the derivative's sign change reveals;
/// the step then lands on the maximum and the crossing shows. Full thrust likewise watches the
/// minima. (Two event slots, [`SWITCH_EVENTS`].) The rate is watched as -d rho / dt: the
/// integrator keeps the last sign of each slot, and a slot that becomes a switch on entering the
/// ramp must have that switch's sign there (rho - eps < 0 on a rise from a coast, rho + eps > 0
/// on a fall from full thrust), or a crossing right after the entry would go unseen. Leaving the
/// ramp, the slot's sign may flip; the next step then reports a rate event at its start, which
/// keeps the branch.
fn modal_events<L: SwitchingLayout>(ys: &[f64], p: &OptimalControlParams, regime: Regime) -> [f64; SWITCH_EVENTS] {
    let c = p.spacecraft.exhaust_speed;
    let rho = L::rho(ys, c);
    match regime {
        Regime::Ramp => [rho - p.eps, rho + p.eps],
        Regime::Coast => [-L::rate(ys, c), rho + p.eps],
        Regime::Full => [rho - p.eps, -L::rate(ys, c)],
    }
}

/// Where a state-costate vector (alone or at the front of one with variational columns) keeps
/// what the throttle law reads: the modal propagation below serves the planar system of this
/// module and the spatial one of [`super::spatial`] through it.
pub(crate) trait SwitchingLayout {
    /// The switching function rho of the state-costate at the front of `ys`.
    fn rho(ys: &[f64], exhaust_speed: f64) -> f64;
    /// Its time derivative d rho / dt.
    fn rate(ys: &[f64], exhaust_speed: f64) -> f64;
}

/// The planar state-costate of this module.
pub(crate) struct Planar;

impl SwitchingLayout for Planar {
    fn rho(ys: &[f64], exhaust_speed: f64) -> f64 {
        let y: [f64; Y_LEN] = core::array::from_fn(|i| ys[i]);
        switching_function(&y, exhaust_speed)
    }

    fn rate(ys: &[f64], exhaust_speed: f64) -> f64 {
        let y: [f64; Y_LEN] = core::array::from_fn(|i| ys[i]);
        switching_rate(&y, exhaust_speed)
    }
}

/// Whether event slot `index` watches d rho / dt (not a switch) in branch `regime`.
fn is_rate_event(index: usize, regime: Regime) -> bool {
    matches!((index, regime), (0, Regime::Coast) | (1, Regime::Full))
}

/// State-costate plus the sensitivity matrix d y / d lambda_0 (10 x 5), by forward-mode duals.
#[derive(Debug, Clone, Copy)]
pub struct StateCostateSensitivity(pub OptimalControlParams);

type Dual5 = DualVec64<Const<SENS_COLS>>;

/// The state-costate derivatives and the variational equations on one throttle branch.
fn sensitivity_rhs(ys: &[f64; YS_LEN], params: &OptimalControlParams, regime: Regime, dydt: &mut [f64; YS_LEN]) {
    variational_rhs::<Y_LEN, SENS_COLS>(ys, |y: &[Dual5; Y_LEN]| state_costate_rhs_in(y, params, regime), dydt);
}

/// A right-hand side with its variational equations by forward-mode duals: `ys` holds y (`Y`
/// components) and then `K` columns of a sensitivity matrix Phi (column k from `Y + k Y`).
/// Each component is seeded with its row of Phi, so the dual parts of `rhs` are J(y) Phi, the
/// columns' derivatives. Serves the planar sensitivity and transition matrix and the spatial
/// sensitivity.
pub(crate) fn variational_rhs<const Y: usize, const K: usize>(
    ys: &[f64],
    rhs: impl Fn(&[DualVec64<Const<K>>; Y]) -> [DualVec64<Const<K>>; Y],
    dydt: &mut [f64],
) {
    let y: [DualVec64<Const<K>>; Y] = core::array::from_fn(|i| {
        let row = SVector::<f64, K>::from_fn(|k, _| ys[Y + k * Y + i]);
        DualVec64::new(ys[i], Derivative::some(row))
    });
    let f = rhs(&y);
    for (i, fi) in f.iter().enumerate() {
        dydt[i] = fi.re;
        let d = fi.eps.unwrap_generic(Const::<K>, Const::<1>);
        for k in 0..K {
            dydt[Y + k * Y + i] = d[k];
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

impl OdeSystem<YS_LEN, SWITCH_EVENTS> for StateCostateSensitivity {
    fn derivatives(&self, _t: f64, ys: &[f64; YS_LEN], dydt: &mut [f64; YS_LEN]) {
        let y: [f64; Y_LEN] = core::array::from_fn(|i| ys[i]);
        let regime = Regime::of(switching_function(&y, self.0.spacecraft.exhaust_speed), self.0.eps);
        sensitivity_rhs(ys, &self.0, regime, dydt);
    }

    fn events(&self, _t: f64, ys: &[f64; YS_LEN]) -> [f64; SWITCH_EVENTS] {
        let y: [f64; Y_LEN] = core::array::from_fn(|i| ys[i]);
        switch_events(&y, &self.0)
    }
}

/// A right-hand side on one throttle branch: the state-costate, with or without variational
/// columns, of N components whose front is laid out as `Layout` says.
pub(crate) trait BranchRhs<const N: usize> {
    /// Where the switching function's inputs sit.
    type Layout: SwitchingLayout;
    /// dy/dt on branch `regime`.
    fn rhs(&self, ys: &[f64; N], regime: Regime, dydt: &mut [f64; N]);
}

/// The state-costate alone.
struct PlainRhs(OptimalControlParams);

impl BranchRhs<Y_LEN> for PlainRhs {
    type Layout = Planar;

    fn rhs(&self, y: &[f64; Y_LEN], regime: Regime, dydt: &mut [f64; Y_LEN]) {
        *dydt = state_costate_rhs_in(y, &self.0, regime);
    }
}

/// With the 10 x 5 sensitivity to the initial costates.
struct SensitivityRhs(OptimalControlParams);

impl BranchRhs<YS_LEN> for SensitivityRhs {
    type Layout = Planar;

    fn rhs(&self, ys: &[f64; YS_LEN], regime: Regime, dydt: &mut [f64; YS_LEN]) {
        sensitivity_rhs(ys, &self.0, regime, dydt);
    }
}

/// With the full 10 x 10 transition matrix.
struct StmRhs(OptimalControlParams);

impl BranchRhs<STM_LEN> for StmRhs {
    type Layout = Planar;

    fn rhs(&self, ys: &[f64; STM_LEN], regime: Regime, dydt: &mut [f64; STM_LEN]) {
        stm_rhs(ys, &self.0, regime, dydt);
    }
}

/// The ODE with the throttle branch held in a discrete mode that only the located switches
/// change (see [`state_costate_rhs_in`]). When `abort` is set (a stuck integration, see
/// [`RegimeSwitch`]) the derivatives turn non-finite so that the integrator gives up at once.
struct ModalSystem<'a, R> {
    rhs: R,
    params: OptimalControlParams,
    regime: &'a Cell<Regime>,
    abort: &'a Cell<bool>,
}

impl<const N: usize, R: BranchRhs<N>> OdeSystem<N, SWITCH_EVENTS> for ModalSystem<'_, R> {
    fn derivatives(&self, _t: f64, ys: &[f64; N], dydt: &mut [f64; N]) {
        if self.abort.get() {
            dydt.fill(f64::NAN);
            return;
        }
        self.rhs.rhs(ys, self.regime.get(), dydt);
    }

    fn events(&self, _t: f64, ys: &[f64; N]) -> [f64; SWITCH_EVENTS] {
        modal_events::<R::Layout>(ys, &self.params, self.regime.get())
    }
}

/// Switches the mode at every located switch.
///
/// It also watches for a stuck integration: where a step lands on a switch, the switch function
/// on the step's end state and on the dense output can disagree in sign within the round-off of
/// rho (~2e-16: rho = lambda_m + c |lambda_v| / m - 1 subtracts O(1) terms). The integrator then
/// locates the zero "at the start" of every next step and moves on by a few ulps of t only, which
/// changes rho by less than its round-off when |d rho / dt| is small: it would spend its whole
/// step budget there (seen as `StepBudgetExhausted` on transfer-circular, every corrector at eps
/// 6.6e-3 to 7.6e-3 of seed 7 #0). After [`STUCK_STEPS`] accepted steps shorter than
/// [`STUCK_STEP`] in a row the observer aborts the integration; the propagation restarts from
/// the first of them on the branch beyond the switch (see [`run_modal`]).
struct RegimeSwitch<'a> {
    regime: &'a Cell<Regime>,
    /// The layout's switching function ([`SwitchingLayout::rho`]).
    rho: fn(&[f64], f64) -> f64,
    eps: f64,
    exhaust_speed: f64,
    /// Set by [`Observer::on_step`] at the first step that ended off the held branch.
    broken: Cell<Option<f64>>,
    abort: &'a Cell<bool>,
    last_t: f64,
    /// Accepted steps seen (to charge the work of a failed integration).
    steps: u64,
    tiny_steps: u32,
    /// Where the tiny steps began (time, state), and whether the integration was aborted there.
    stuck_at: Option<(f64, Vec<f64>)>,
    stuck: bool,
}

/// A step shorter than this (time units) counts towards a stuck integration.
const STUCK_STEP: f64 = 1e-10;
/// This many such steps in a row abort the integration.
const STUCK_STEPS: u32 = 24;

impl RegimeSwitch<'_> {
    /// A propagation whose mode lost track of rho (see [`Observer::on_step`]) fails; the error
    /// reads as a non-finite trajectory, which every caller already treats as a failed trial.
    fn check(&self) -> Result<(), IntegrationError> {
        match self.broken.get() {
            Some(t) => Err(IntegrationError::NonFinite { t }),
            None => Ok(()),
        }
    }
}

/// How far (in rho) a landing point may lie on the wrong side of the branch an event selects
/// before the branch is taken from rho instead (see [`RegimeSwitch`]).
const EVENT_SIDE_TOLERANCE: f64 = 1e-10;

impl<const N: usize> Observer<N> for RegimeSwitch<'_> {
    /// The branch the crossed switch leads to; a maximum or minimum of rho (a rate event, see
    /// [`modal_events`]) keeps the branch. Safety net: where rho at the landing point contradicts
    /// that branch, the branch is taken from rho. (An event slot changes meaning with the branch,
    /// so the first step after a switch may report that slot's sign change as a crossing at its
    /// start; the rule above maps it to the branch already held.)
    fn on_event(&mut self, index: usize, _t: f64, y: &[f64; N], rising: bool) {
        let current = self.regime.get();
        // A maximum or minimum of rho (see [`modal_events`]) keeps the branch.
        let next = if is_rate_event(index, current) {
            current
        } else {
            Regime::after_event(index, rising, self.eps)
        };
        let rho = (self.rho)(y, self.exhaust_speed);
        let tol = EVENT_SIDE_TOLERANCE;
        let consistent = match next {
            Regime::Coast => rho <= -self.eps + tol,
            Regime::Full => rho >= self.eps - tol,
            Regime::Ramp => rho.abs() <= self.eps + tol,
        };
        self.regime
            .set(if consistent { next } else { Regime::of(rho, self.eps) });
    }

    /// Safety net: a step that ends with rho outside the held branch (a crossing the integrator
    /// did not see) marks the propagation as broken; [`propagate`] and
    /// [`propagate_sensitivity`] then fail instead of returning a trajectory flown on the
    /// wrong branch (on the extended ramp u leaves [0, 1]).
    fn on_step(&mut self, t: f64, y: &[f64; N]) {
        self.steps += 1;
        if (t - self.last_t).abs() < STUCK_STEP {
            if self.tiny_steps == 0 {
                self.stuck_at = Some((t, y.to_vec()));
            }
            self.tiny_steps += 1;
            if self.tiny_steps >= STUCK_STEPS && !self.stuck {
                self.stuck = true;
                self.abort.set(true);
            }
        } else {
            self.tiny_steps = 0;
            self.stuck_at = None;
        }
        self.last_t = t;
        if self.broken.get().is_some() {
            return;
        }
        let rho = (self.rho)(y, self.exhaust_speed);

        let tol = EVENT_SIDE_TOLERANCE;
        let consistent = match self.regime.get() {
            Regime::Coast => rho <= -self.eps + tol,
            Regime::Full => rho >= self.eps - tol,
            Regime::Ramp => rho.abs() <= self.eps + tol,
        };
        if !consistent {
            self.broken.set(Some(t));
        }
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

/// The integration work done on this thread so far (see `WORK`).
pub fn work_done() -> u64 {
    WORK.with(Cell::get)
}

fn add_work(stats: &IntegrationStats, weight: u64) {
    let steps = u64::from(stats.accepted_steps) + u64::from(stats.rejected_steps);
    charge_work(steps * weight);
}

/// Adds `work` to this thread's count (see [`work_done`]): for propagations done elsewhere.
pub(crate) fn charge_work(work: u64) {
    WORK.with(|w| w.set(w.get().saturating_add(work)));
}

/// Charges the steps of an integration at `weight` per step (see [`work_done`]).
pub(crate) fn charge_stats(stats: &IntegrationStats, weight: u64) {
    add_work(stats, weight);
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
    run_modal(PlainRhs(*params), params, t0, y0, t1, tolerances, 1, &mut NoClock)
}

/// Something that watches a modal propagation besides its [`RegimeSwitch`].
pub(crate) trait ModalWatch {
    fn on_event(&mut self, _t: f64, _regime_before: Regime) {}
}

pub(crate) struct NoClock;

impl ModalWatch for NoClock {}

/// [`RegimeSwitch`] plus a [`ModalWatch`], as one observer.
struct Watched<'a, 'w, W> {
    switch: RegimeSwitch<'a>,
    watch: &'w mut W,
}

impl<const N: usize, W: ModalWatch> Observer<N> for Watched<'_, '_, W> {
    fn on_event(&mut self, index: usize, t: f64, y: &[f64; N], rising: bool) {
        self.watch.on_event(t, self.switch.regime.get());
        Observer::<N>::on_event(&mut self.switch, index, t, y, rising);
    }

    fn on_step(&mut self, t: f64, y: &[f64; N]) {
        Observer::<N>::on_step(&mut self.switch, t, y);
    }
}

/// Restarts allowed past stuck switches in one propagation.
const MAX_RESTARTS: u32 = 32;

/// The modal propagation of `rhs` from (t0, ys0) to t1 on the offset clock (see [`TIME_OFFSET`]),
/// restarting past a switch where the integration got stuck (see [`RegimeSwitch`]): from the
/// stuck point, on the branch beyond the switch that rho sits on (by the sign of d rho / dt).
/// Work is charged at `weight` per step.
#[allow(clippy::too_many_arguments)]
pub(crate) fn run_modal<const N: usize, R: BranchRhs<N>, W: ModalWatch>(
    rhs: R,
    params: &OptimalControlParams,
    t0: f64,
    ys0: &[f64; N],
    t1: f64,
    tolerances: &Tolerances,
    weight: u64,
    watch: &mut W,
) -> Result<[f64; N], IntegrationError> {
    let c = params.spacecraft.exhaust_speed;
    let regime = Cell::new(Regime::of(R::Layout::rho(ys0, c), params.eps));
    let abort = Cell::new(false);
    let system = ModalSystem {
        rhs,
        params: *params,
        regime: &regime,
        abort: &abort,
    };
    let (mut t, mut ys) = (t0 + time_offset(), *ys0);
    let end = t1 + time_offset();
    let mut restarts = 0;
    loop {
        let mut observer = Watched {
            switch: RegimeSwitch {
                regime: &regime,
                rho: R::Layout::rho,
                eps: params.eps,
                exhaust_speed: c,
                broken: Cell::new(None),
                abort: &abort,
                last_t: t,
                steps: 0,
                tiny_steps: 0,
                stuck_at: None,
                stuck: false,
            },
            watch: &mut *watch,
        };
        match integrate_observed(&system, t, &ys, end, tolerances, &mut observer) {
            Ok((y, stats)) => {
                add_work(&stats, weight);
                observer.switch.check()?;
                return Ok(y);
            }
            Err(e) => {
                let switch = observer.switch;
                let restart = match (switch.stuck, switch.stuck_at) {
                    (true, Some((ts, state))) if state.len() == N && restarts < MAX_RESTARTS => Some((ts, state)),
                    _ => None,
                };
                // A stuck integration is charged the steps it took (twice, for the rejected
                // ones); any other failure at most its step budget.
                if switch.stuck {
                    charge_work(2 * switch.steps * weight);
                } else {
                    charge_work(u64::from(tolerances.max_steps) * weight);
                }
                let Some((ts, state)) = restart else {
                    return Err(e);
                };
                restarts += 1;
                abort.set(false);
                ys = core::array::from_fn(|i| state[i]);
                t = ts;
                let (rho, rate) = (R::Layout::rho(&ys, c), R::Layout::rate(&ys, c));
                let eps = params.eps;
                let near = |v: f64| (rho - v).abs() < 1e-12;
                // Beyond the switch rho sits on; elsewhere (a rate event) the branch stays.
                if near(-eps) || near(eps) {
                    let beyond = if rate > 0.0 { rho + 1e-12 } else { rho - 1e-12 };
                    let level = if near(eps) { eps } else { -eps };
                    regime.set(Regime::of(beyond + (level - rho), eps));
                }
            }
        }
    }
}

/// Every modal propagation runs on the clock t + [`TIME_OFFSET`] (the dynamics are autonomous).
///
/// Why: where a step lands on a switch rho = -+eps, the event function is evaluated on the
/// step's end state and on the dense output, and the two disagree in sign within the
/// round-off of rho (~2e-16: rho = lambda_m + c |lambda_v| / m - 1 subtracts O(1) terms). The
/// integrator then locates the zero "at the start" of each next step and moves past it by a few
/// ulps of t only; near t = 0.01 that is ~1e-17, which changes rho by ~1e-20, so it never
/// escapes and spends its whole step budget there (seen as `StepBudgetExhausted` at t < 0.2 on
/// the transfer-circular homotopy: every corrector at eps 6.6e-3 to 7.6e-3 of seed 7 #0). On a
/// clock near 1024 the few ulps are ~1e-12, enough to leave the round-off band whenever
/// |d rho / dt| > ~1e-4. The cost: times carry an absolute resolution of ~2e-13 (the end state
/// moves by < 1e-11 over a flight), far inside the 1e-8 terminal accuracy.
pub const TIME_OFFSET: f64 = 1024.0;

fn time_offset() -> f64 {
    TIME_OFFSET
}

/// Records the time spent on the ramp (0 < u < 1) of the throttle law.
struct RampClock {
    since: f64,
    on_ramp: f64,
}

impl ModalWatch for RampClock {
    fn on_event(&mut self, t: f64, regime_before: Regime) {
        if regime_before == Regime::Ramp {
            self.on_ramp += t - self.since;
        }
        self.since = t;
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
    let mut clock = RampClock {
        since: time_offset(),
        on_ramp: 0.0,
    };
    let y = run_modal(PlainRhs(*params), params, 0.0, y0, t1, tolerances, 1, &mut clock)?;
    if Regime::of(switching_function(&y, params.spacecraft.exhaust_speed), params.eps) == Regime::Ramp {
        clock.on_ramp += t1 + time_offset() - clock.since;
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
    let ys0 = StateCostateSensitivity::initial(y0);
    run_modal(
        SensitivityRhs(*params),
        params,
        0.0,
        &ys0,
        t1,
        tolerances,
        SENSITIVITY_STEP_WORK,
        &mut NoClock,
    )
}

/// State-costate + its full 10 x 10 transition matrix (column-major after the first 10).
pub const STM_LEN: usize = Y_LEN + Y_LEN * Y_LEN;

/// Work of one transition-matrix step relative to a plain one (see [`work_done`]).
pub const STM_STEP_WORK: u64 = 10;

type Dual10 = DualVec64<Const<Y_LEN>>;

/// The state-costate derivatives and the variational equations of the full transition matrix on
/// one throttle branch.
pub(crate) fn stm_rhs(ys: &[f64; STM_LEN], params: &OptimalControlParams, regime: Regime, dydt: &mut [f64; STM_LEN]) {
    variational_rhs::<Y_LEN, Y_LEN>(ys, |y: &[Dual10; Y_LEN]| state_costate_rhs_in(y, params, regime), dydt);
}

/// [`propagate`] from (t0, y0) to t1 with the transition matrix d y(t1) / d y(t0): returns y(t1)
/// and the matrix, `stm[i][k]` = d y_i(t1) / d y_k(t0). For eps > 0 (at eps = 0 the jumps of the
/// throttle at the switches would need saltation terms, which this does not add).
pub fn propagate_stm(
    params: &OptimalControlParams,
    t0: f64,
    y0: &[f64; Y_LEN],
    t1: f64,
    tolerances: &Tolerances,
) -> Result<([f64; Y_LEN], [[f64; Y_LEN]; Y_LEN]), IntegrationError> {
    let mut ys0 = [0.0; STM_LEN];
    ys0[..Y_LEN].copy_from_slice(y0);
    for k in 0..Y_LEN {
        ys0[Y_LEN + k * Y_LEN + k] = 1.0;
    }
    let ys = run_modal(
        StmRhs(*params),
        params,
        t0,
        &ys0,
        t1,
        tolerances,
        STM_STEP_WORK,
        &mut NoClock,
    )?;
    let y: [f64; Y_LEN] = core::array::from_fn(|i| ys[i]);
    let stm = core::array::from_fn(|i| core::array::from_fn(|k| ys[Y_LEN + k * Y_LEN + i]));
    Ok((y, stm))
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

    /// Short burns at a tiny eps (transfer-circular seed 7 #5, its bang-bang costates at
    /// eps = 2^-25; the switching function peaks at ~1e-7 on the burns): one plain propagation,
    /// one with sensitivities and one cut into 400 pieces (no step can span a burn) agree on the
    /// final state. Before the rate events, the plain propagation stepped over both burns.
    #[test]
    fn short_burns_are_not_stepped_over() {
        use crate::solver::shooting::initial_state_costate;
        use shared::scenario::ScenarioKind;
        let p = params(1.0 / f64::from(1u32 << 25));
        let scenario = ScenarioKind::TransferCircular.draw(7, 5);
        let lambda = [
            -4.671_354_117_517_756e-1,
            1.345_264_221_995_338_7e-1,
            -2.128_588_145_260_878e-1,
            -7.397_896_359_832_3e-1,
            1.856_149_790_933_322e-2,
        ];
        let y0 = initial_state_costate(&scenario, &lambda);
        let tf = scenario.time_of_flight();
        let tol = Tolerances {
            relative: 3e-14,
            absolute: 3e-15,
            ..Tolerances::default()
        };
        let plain = propagate(&p, 0.0, &y0, tf, &tol).unwrap();
        let sens = propagate_sensitivity(&p, &y0, tf, &tol).unwrap();
        let (mut y, n) = (y0, 400);
        for k in 0..n {
            y = propagate(
                &p,
                tf * f64::from(k) / f64::from(n),
                &y,
                tf * f64::from(k + 1) / f64::from(n),
                &tol,
            )
            .unwrap();
        }
        // Both burns flown: about 1.9 % of the mass spent.
        assert!((plain[idx::M] - 0.98144).abs() < 1e-4, "m_f {}", plain[idx::M]);
        for i in 0..5 {
            assert!(
                (plain[i] - y[i]).abs() < 1e-7 && (sens[i] - y[i]).abs() < 1e-7,
                "y{i}: {} {} {}",
                plain[i],
                sens[i],
                y[i]
            );
        }
    }
}
