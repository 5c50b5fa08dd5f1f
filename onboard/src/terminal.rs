//! Terminal targeting: over the last cycles of a flight the commands still to fly are solved
//! for the arrival with the onboard propagator, instead of left to the network.
//!
//! With `k <= settings.cycles` cycles to go, the plan is the `k` thrust vectors
//! `tau_j = u_j alpha_j` (each held for its cycle in the local frame, as every command is: polar
//! (alpha_r, alpha_theta) in the plane, RTN in three dimensions; `|tau_j| <= 1`), started from
//! the commands the network would fly along its own nominal continuation. The arrival's miss
//! vector `e` (position then velocity components, each over its goal: a planar transfer's radius
//! and polar velocity differences to the target orbit at the spacecraft's polar angle, in three
//! dimensions the differences to the target orbit's point the features measure against, a
//! rendezvous's Cartesian differences to the body) is driven to zero by damped Gauss-Newton
//! (Levenberg-Marquardt) steps, the Jacobian by forward differences:
//!
//! `d tau = -J^T (J J^T + lambda I)^-1 e`
//!
//! the minimum-norm change of the plan where it has more unknowns than conditions (two or three
//! per cycle against three to six), least squares on the last cycle. A step that does not lower
//! `|e|` is refused and lambda raised. Once the arrival is met (`|e| < 1e-3`), the iterations
//! left lower the plan's propellant (the throttles times the cycles' durations): a step down its
//! gradient projected on the null space of `J` (`p = g - J^T (J J^T)^-1 J g`, which leaves the
//! arrival unmoved to first order), then one Gauss-Newton correction, kept only if the plan
//! still meets the arrival and commands less. The plan's first command is flown; the next cycle solves
//! again from the navigation state, so errors of the plant are corrected while cycles remain.
//! The network's command is flown instead whenever the solved plan does not predict a smaller
//! miss than the network's own continuation, or any rollout fails.
//!
//! A rollout keeps the state at the start of each of its cycles, so a Jacobian column for cycle
//! `j`'s command flies only the cycles from `j` on. The work per cycle is at most
//! `k + iterations x (a k (k + 1) / 2 + 4 k)` propagated cycles, `a` the thrust vector's
//! components (2 in the plane, 3 in three dimensions; [`TerminalDecision::rollout_cycles`]
//! counts them), each one fixed DOP853 step by default ([`TerminalSettings::rollout_steps`]);
//! no allocation, no panic. One implementation
//! serves both dimensions through [`Aim`] and [`Dimension`].

use shared::spacecraft::CanonicalSpacecraft;
use shared::units::STEP;

use crate::dynamics::{SpacecraftState, ThrustCommand};
use crate::features::ACTION3_LEN;
use crate::geometry::{Dimension, Spatial};
pub use crate::guidance::MISS_LEN;
use crate::guidance::{
    command_at, cycle_duration, cycles_left, Actor, Aim, GuidanceError, Guide, SpatialTargetFeatures, TargetFeatures,
};
use crate::integrator::Tolerances;
use crate::lookahead::{lookahead_step, rollout_tolerances, LookaheadSettings, MAX_ROLLOUT_STEPS};
use crate::spatial::{RtnCommand, SpatialCraftState};

/// Most cycles a plan solves for.
pub const MAX_CYCLES: usize = 8;
/// Most Gauss-Newton iterations a cycle may be allowed: the work stays bounded whatever a
/// caller asks for.
pub const MAX_ITERATIONS: u32 = 64;
/// Most unknowns of a plan: three thrust components per cycle.
const MAX_UNKNOWNS: usize = 3 * MAX_CYCLES;
/// The miss vector's position components (the velocity ones follow).
const POSITION_COMPONENTS: usize = 3;

/// What terminal targeting does; `Default` targets the last 8 cycles with up to 3 iterations:
/// at most 320 propagated cycles in the plane, 428 in three dimensions. A miss corrected
/// earlier costs less: over 8 cycles the plan spends less propellant than the network alone.
/// The ground's configs read it (feature `serde`: `cycles`, `iterations` and `rollout_steps` by
/// name, each defaulted; the goals are the evaluation's, adaptive rollouts' tolerances the
/// environment's).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct TerminalSettings {
    /// Cycles to go from which the plan is solved (1 to [`MAX_CYCLES`]).
    pub cycles: u32,
    /// Iterations per guidance cycle, at most: Gauss-Newton steps, then, with the arrival met,
    /// propellant-lowering steps.
    pub iterations: u32,
    /// Position residual that counts as one unit of miss (AU; default 0.01, the goal).
    #[cfg_attr(feature = "serde", serde(skip))]
    pub goal_position: f64,
    /// Velocity residual that counts as one unit of miss (AU/t*; default 0.01).
    #[cfg_attr(feature = "serde", serde(skip))]
    pub goal_velocity: f64,
    /// DOP853 steps per cycle of each rollout, without error control, at least (1 to
    /// [`MAX_ROLLOUT_STEPS`]; default 1: 12 evaluations a cycle, more near a periapsis, and
    /// finite differences as clean as the arithmetic), or 0: the adaptive integrator at
    /// `tolerances`.
    pub rollout_steps: u32,
    /// Tolerances of the rollouts' adaptive propagation, with `rollout_steps` 0 (default: the
    /// onboard ones).
    #[cfg_attr(feature = "serde", serde(skip))]
    pub tolerances: Tolerances,
    /// Length of a guidance cycle (t*; default 14 days, [`STEP`]): the scenario family's.
    #[cfg_attr(feature = "serde", serde(skip))]
    pub cycle: f64,
}

impl Default for TerminalSettings {
    fn default() -> Self {
        Self {
            cycles: 8,
            iterations: 3,
            goal_position: 0.01,
            goal_velocity: 0.01,
            rollout_steps: 1,
            tolerances: Tolerances::default(),
            cycle: STEP,
        }
    }
}

/// Settings out of range: cycles not in 1..=[`MAX_CYCLES`], iterations not in
/// 1..=[`MAX_ITERATIONS`], rollout steps above [`MAX_ROLLOUT_STEPS`], a goal or the cycle not
/// finite and positive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InvalidTerminalSettings;

impl TerminalSettings {
    /// The most cycles one guidance cycle with `k` cycles to go propagates in dimension `G`:
    /// `k + iterations x (a k (k + 1) / 2 + 4 k)`, `a` its thrust components (the network's
    /// continuation, then per iteration a Jacobian and at most four trial plans).
    pub fn most_rollout_cycles<G: Dimension>(&self, k: u32) -> u32 {
        let per_iteration = u32::try_from(G::THRUST_AXES)
            .unwrap_or(u32::MAX)
            .saturating_mul(k.saturating_mul(k.saturating_add(1)) >> 1)
            .saturating_add(k.saturating_mul(4));
        self.iterations.saturating_mul(per_iteration).saturating_add(k)
    }

    /// The integrator settings of a rollout cycle of `duration` from a state of periapsis
    /// `periapsis`: at least `rollout_steps` fixed steps, or the adaptive `tolerances`
    /// ([`rollout_tolerances`]).
    pub fn rollout_tolerances(&self, duration: f64, periapsis: f64) -> Tolerances {
        rollout_tolerances(self.rollout_steps, &self.tolerances, duration, periapsis)
    }

    /// Checks the ranges of [`InvalidTerminalSettings`].
    pub fn validate(&self) -> Result<(), InvalidTerminalSettings> {
        let positive = |x: f64| x.is_finite() && x > 0.0;
        let cycles = usize::try_from(self.cycles).unwrap_or(usize::MAX);
        if (1..=MAX_CYCLES).contains(&cycles)
            && (1..=MAX_ITERATIONS).contains(&self.iterations)
            && self.rollout_steps <= MAX_ROLLOUT_STEPS
            && positive(self.goal_position)
            && positive(self.goal_velocity)
            && positive(self.cycle)
        {
            Ok(())
        } else {
            Err(InvalidTerminalSettings)
        }
    }
}

/// One terminal-targeting cycle: what was flown and why (telemetry). `C` is the dimension's
/// command: polar in the plane, [`RtnCommand`] in three dimensions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TerminalDecision<C = ThrustCommand> {
    /// The command to hold for the cycle.
    pub command: C,
    /// The network's own command.
    pub network: C,
    /// Whether the solved plan's command is flown (false: the network's).
    pub solved: bool,
    /// Predicted miss |e| (in goal units) of the network's continuation, when it was flown out.
    pub network_miss: Option<f64>,
    /// Predicted miss of the plan flown, when a plan was solved.
    pub planned_miss: Option<f64>,
    /// Cycles the rollouts propagated this cycle (the network's continuation included): the
    /// cycle's work, at most [`TerminalSettings::most_rollout_cycles`].
    pub rollout_cycles: u32,
}

/// A plan: the thrust vector of each remaining cycle (radial, transverse and, in three
/// dimensions, normal; the unused component 0), `|tau| <= 1`.
type Plan = [[f64; 3]; MAX_CYCLES];

/// A vector of the plan's unknowns, cycle by cycle (the used ones first).
type Unknowns = [f64; MAX_UNKNOWNS];

/// The miss's Jacobian: one row per miss component, one column per unknown.
type Jacobian = [[f64; MAX_UNKNOWNS]; MISS_LEN];

/// Everything a rollout needs besides its plan.
struct Problem<'a, G: Dimension, T> {
    target: &'a T,
    spacecraft: &'a CanonicalSpacecraft,
    settings: &'a TerminalSettings,
    navigation: &'a G::State,
    time_to_go: f64,
    cycles: usize,
    /// Cycles propagated so far.
    propagated: core::cell::Cell<u32>,
}

/// A plan flown out: its miss vector (goal units) and the state at the start of each of its
/// cycles, from which a change of a later cycle's command flies without repeating the cycles
/// before it.
#[derive(Debug, Clone, Copy)]
struct Rollout<S> {
    e: [f64; MISS_LEN],
    starts: [S; MAX_CYCLES],
}

impl<G: Dimension, T> Problem<'_, G, T> {
    /// The duration of the plan's cycle `k` (the last one possibly shorter).
    fn duration(&self, k: usize) -> f64 {
        cycle_duration(self.time_to_go, k as f64 * self.settings.cycle, self.settings.cycle)
    }

    /// The plan's unknowns: the thrust components of each cycle to go.
    fn unknowns(&self) -> usize {
        G::THRUST_AXES * self.cycles
    }

    /// `plan` flown to the arrival from the start of its cycle `from`, where the state is
    /// `start` (None if a propagation fails or the arrival's state is refused). The states at
    /// the starts of the cycles before `from` are left at `start`.
    fn rollout_from<const N: usize, const OUT: usize>(
        &self,
        plan: &Plan,
        from: usize,
        start: &G::State,
    ) -> Option<Rollout<G::State>>
    where
        T: Aim<N, OUT, Geometry = G>,
    {
        let mut starts = [*start; MAX_CYCLES];
        let mut state = *start;
        for (cycle, tau) in plan.iter().enumerate().take(self.cycles).skip(from) {
            if let Some(slot) = starts.get_mut(cycle) {
                *slot = state;
            }
            state = self.propagate(&state, &G::command_of(tau), cycle)?;
        }
        Some(Rollout {
            e: self.miss_at(&state)?,
            starts,
        })
    }

    /// `state` flown for the plan's cycle `cycle` under `command` (counted).
    fn propagate(&self, state: &G::State, command: &G::Command, cycle: usize) -> Option<G::State> {
        self.propagated.set(self.propagated.get().saturating_add(1));
        let duration = self.duration(cycle);
        let tolerances = self.settings.rollout_tolerances(duration, G::periapsis(state));
        G::propagate(state, command, self.spacecraft, duration, &tolerances).ok()
    }

    /// `plan` flown from the navigation state to the arrival.
    fn rollout<const N: usize, const OUT: usize>(&self, plan: &Plan) -> Option<Rollout<G::State>>
    where
        T: Aim<N, OUT, Geometry = G>,
    {
        self.rollout_from(plan, 0, self.navigation)
    }

    /// The miss vector, in goal units, of the arrival `state` (None if it is refused).
    fn miss_at<const N: usize, const OUT: usize>(&self, state: &G::State) -> Option<[f64; MISS_LEN]>
    where
        T: Aim<N, OUT, Geometry = G>,
    {
        let mut e = self.target.miss_after(state, self.time_to_go).ok()?;
        let (gp, gv) = (self.settings.goal_position, self.settings.goal_velocity);
        // Position components first, then velocity.
        for (i, v) in e.iter_mut().enumerate() {
            *v /= if i < POSITION_COMPONENTS { gp } else { gv };
        }
        e.iter().all(|v| v.is_finite()).then_some(e)
    }
}

fn norm(e: &[f64; MISS_LEN]) -> f64 {
    libm::sqrt(e.iter().map(|v| v * v).sum::<f64>())
}

/// Solves `a x = b` for a symmetric positive definite `a` (Cholesky); None if it is not.
fn solve_spd(a: &[[f64; MISS_LEN]; MISS_LEN], b: &[f64; MISS_LEN]) -> Option<[f64; MISS_LEN]> {
    let mut l = [[0.0f64; MISS_LEN]; MISS_LEN];
    for i in 0..MISS_LEN {
        for j in 0..=i {
            let mut sum = *a.get(i)?.get(j)?;
            for k in 0..j {
                sum -= l.get(i)?.get(k)? * l.get(j)?.get(k)?;
            }
            let value = if i == j {
                if sum.is_nan() || sum <= 0.0 {
                    return None;
                }
                libm::sqrt(sum)
            } else {
                sum / l.get(j)?.get(j)?
            };
            *l.get_mut(i)?.get_mut(j)? = value;
        }
    }
    // L z = b, then L^T x = z.
    let mut z = [0.0f64; MISS_LEN];
    for i in 0..MISS_LEN {
        let mut sum = *b.get(i)?;
        for k in 0..i {
            sum -= l.get(i)?.get(k)? * z.get(k)?;
        }
        *z.get_mut(i)? = sum / l.get(i)?.get(i)?;
    }
    let mut x = [0.0f64; MISS_LEN];
    for i in (0..MISS_LEN).rev() {
        let mut sum = *z.get(i)?;
        for k in i + 1..MISS_LEN {
            sum -= l.get(k)?.get(i)? * x.get(k)?;
        }
        *x.get_mut(i)? = sum / l.get(i)?.get(i)?;
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Each cycle's thrust vector clipped to the unit ball.
fn clip<G: Dimension>(plan: &mut Plan) {
    for tau in plan.iter_mut() {
        let n = G::thrust_norm(tau);
        if n > 1.0 {
            tau.iter_mut().for_each(|c| *c /= n);
        }
    }
}

/// Unknown `u` of a plan: component `u mod a` of cycle `u / a`'s thrust vector, `a` the
/// dimension's thrust components.
fn component<G: Dimension>(plan: &mut Plan, u: usize) -> Option<&mut f64> {
    plan.get_mut(u.checked_div(G::THRUST_AXES)?)?
        .get_mut(u.checked_rem(G::THRUST_AXES)?)
}

/// Forward-difference step of the thrust vectors' components.
const DIFFERENCE: f64 = 1e-7;

/// Within this miss (in goal units) the arrival is met: no Gauss-Newton step is worth a
/// propagation, and a cheaper plan must stay within it.
const MET: f64 = 1e-3;

/// The miss's Jacobian by forward differences at `plan` (flown out as `base`): MISS_LEN rows,
/// one column per unknown (cycle j, component c), each flown from cycle j's start; None if a
/// rollout fails.
fn jacobian<const N: usize, const OUT: usize, G: Dimension, T: Aim<N, OUT, Geometry = G>>(
    problem: &Problem<'_, G, T>,
    plan: &Plan,
    base: &Rollout<G::State>,
) -> Option<Jacobian> {
    let mut jacobian = [[0.0f64; MAX_UNKNOWNS]; MISS_LEN];
    for u in 0..problem.unknowns() {
        let cycle = u.checked_div(G::THRUST_AXES)?;
        let mut moved = *plan;
        if let Some(v) = component::<G>(&mut moved, u) {
            *v += DIFFERENCE;
        }
        let em = problem.rollout_from(&moved, cycle, base.starts.get(cycle)?)?.e;
        for (row, (a, b)) in jacobian.iter_mut().zip(em.iter().zip(base.e.iter())) {
            if let Some(slot) = row.get_mut(u) {
                *slot = (a - b) / DIFFERENCE;
            }
        }
    }
    Some(jacobian)
}

/// `J v` for a vector `v` of the unknowns.
fn apply(jacobian: &Jacobian, v: &Unknowns) -> [f64; MISS_LEN] {
    jacobian.map(|row| row.iter().zip(v.iter()).map(|(a, b)| a * b).sum())
}

/// `J^T y` over the first `unknowns` unknowns.
fn apply_transposed(jacobian: &Jacobian, y: &[f64; MISS_LEN], unknowns: usize) -> Unknowns {
    let mut out = [0.0f64; MAX_UNKNOWNS];
    for (u, slot) in out.iter_mut().enumerate().take(unknowns) {
        *slot = jacobian
            .iter()
            .zip(y.iter())
            .map(|(row, yi)| row.get(u).unwrap_or(&0.0) * yi)
            .sum();
    }
    out
}

/// `J J^T`.
fn gram(jacobian: &Jacobian) -> [[f64; MISS_LEN]; MISS_LEN] {
    let mut gram = [[0.0f64; MISS_LEN]; MISS_LEN];
    for (i, row_i) in jacobian.iter().enumerate() {
        for (k, row_k) in jacobian.iter().enumerate() {
            let dot: f64 = row_i.iter().zip(row_k.iter()).map(|(a, b)| a * b).sum();
            if let Some(slot) = gram.get_mut(i).and_then(|r| r.get_mut(k)) {
                *slot = dot;
            }
        }
    }
    gram
}

/// `gram + lambda (1 + diag) I`: also what keeps the rows of a miss component the dimension
/// does not have (all zero) solvable.
fn damped(gram: &[[f64; MISS_LEN]; MISS_LEN], lambda: f64) -> [[f64; MISS_LEN]; MISS_LEN] {
    let mut normal = *gram;
    for (i, row) in normal.iter_mut().enumerate() {
        if let Some(d) = row.get_mut(i) {
            *d += lambda * (1.0 + *d);
        }
    }
    normal
}

/// `plan` moved by `-step` (the unknowns' order) and clipped to the unit balls.
fn moved_by<G: Dimension>(plan: &Plan, step: &Unknowns, unknowns: usize) -> Plan {
    let mut moved = *plan;
    for (u, d) in step.iter().enumerate().take(unknowns) {
        if let Some(v) = component::<G>(&mut moved, u) {
            *v -= d;
        }
    }
    clip::<G>(&mut moved);
    moved
}

/// The propellant a plan commands, as throttle times duration summed over its cycles.
fn fuel<G: Dimension, T>(problem: &Problem<'_, G, T>, plan: &Plan) -> f64 {
    plan.iter()
        .take(problem.cycles)
        .enumerate()
        .map(|(k, tau)| G::thrust_norm(tau) * problem.duration(k))
        .sum()
}

/// Damped Gauss-Newton on `plan` (flown out as `flown`; see the module documentation), then,
/// with the arrival met and iterations left, steps that lower the plan's propellant along the
/// miss's null space and keep it met; returns the best plan found and its rollout.
fn solve<const N: usize, const OUT: usize, G: Dimension, T: Aim<N, OUT, Geometry = G>>(
    problem: &Problem<'_, G, T>,
    mut plan: Plan,
    mut flown: Rollout<G::State>,
) -> (Plan, Rollout<G::State>) {
    let unknowns = problem.unknowns();
    let mut lambda = 1e-6;
    let mut iterations = 0;
    while iterations < problem.settings.iterations && norm(&flown.e) >= MET {
        iterations += 1;
        let Some(jacobian) = jacobian(problem, &plan, &flown) else {
            return (plan, flown);
        };
        let gram = gram(&jacobian);
        let mut improved = false;
        // A few tries with more damping before the iteration gives up.
        for _ in 0..4 {
            let Some(y) = solve_spd(&damped(&gram, lambda), &flown.e) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = moved_by::<G>(&plan, &apply_transposed(&jacobian, &y, unknowns), unknowns);
            match problem.rollout(&candidate) {
                Some(rolled) if norm(&rolled.e) < norm(&flown.e) => {
                    plan = candidate;
                    flown = rolled;
                    lambda = (lambda / 10.0).max(1e-12);
                    improved = true;
                    break;
                }
                _ => lambda *= 10.0,
            }
        }
        if !improved {
            return (plan, flown);
        }
    }
    lower_fuel(problem, plan, flown, problem.settings.iterations - iterations)
}

/// Up to `iterations` steps of a met plan down the propellant's gradient projected on the
/// miss's null space (`p = g - J^T (J J^T)^-1 J g`, the change that leaves the arrival unmoved
/// to first order), each followed by a Gauss-Newton correction and kept only if the plan
/// still meets the arrival and commands less propellant. Each costs a Jacobian and at most 4
/// rollouts.
fn lower_fuel<const N: usize, const OUT: usize, G: Dimension, T: Aim<N, OUT, Geometry = G>>(
    problem: &Problem<'_, G, T>,
    mut plan: Plan,
    mut flown: Rollout<G::State>,
    iterations: u32,
) -> (Plan, Rollout<G::State>) {
    let unknowns = problem.unknowns();
    let axes = G::THRUST_AXES;
    for _ in 0..iterations {
        if norm(&flown.e) >= MET {
            break;
        }
        let Some(jacobian) = jacobian(problem, &plan, &flown) else {
            break;
        };
        // The propellant's gradient: each cycle's duration along its thrust vector.
        let mut gradient = [0.0f64; MAX_UNKNOWNS];
        for (cycle, tau) in plan.iter().take(problem.cycles).enumerate() {
            let n = G::thrust_norm(tau);
            if n > 1e-9 {
                let dt = problem.duration(cycle);
                if let Some(g) = gradient.get_mut(axes * cycle..axes * cycle + axes) {
                    for (g, t) in g.iter_mut().zip(tau.iter()) {
                        *g = dt * t / n;
                    }
                }
            }
        }
        // One normal matrix for the projection and the corrections back onto the arrival.
        let normal = damped(&gram(&jacobian), 1e-12);
        let Some(y) = solve_spd(&normal, &apply(&jacobian, &gradient)) else {
            break;
        };
        let back = apply_transposed(&jacobian, &y, unknowns);
        let mut projected = [0.0f64; MAX_UNKNOWNS];
        for ((p, g), b) in projected.iter_mut().zip(gradient.iter()).zip(back.iter()) {
            *p = g - b;
        }
        let largest = projected.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if !largest.is_finite() || largest <= 1e-12 {
            break;
        }
        let before = fuel(problem, &plan);
        let mut lowered = false;
        // The first try moves some thrust vector component by a tenth, the second by a fortieth.
        for scale in [0.1, 0.025] {
            let step = projected.map(|p| p * scale / largest);
            let trial = moved_by::<G>(&plan, &step, unknowns);
            let Some(et) = problem.rollout(&trial).map(|rolled| rolled.e) else {
                break;
            };
            // Back onto the arrival: one Gauss-Newton correction from the trial plan.
            let Some(y) = solve_spd(&normal, &et) else {
                break;
            };
            let corrected = moved_by::<G>(&trial, &apply_transposed(&jacobian, &y, unknowns), unknowns);
            match problem.rollout(&corrected) {
                Some(rolled) if norm(&rolled.e) < MET && fuel(problem, &corrected) < before => {
                    plan = corrected;
                    flown = rolled;
                    lowered = true;
                    break;
                }
                _ => {}
            }
        }
        if !lowered {
            break;
        }
    }
    (plan, flown)
}

/// One guidance cycle with terminal targeting, in the plane or in three dimensions (the
/// target's [`Aim`]): the network's command at `navigation` (refused inputs and non-finite
/// actions are errors, as in [`crate::guidance`]); with `1 ..= settings.cycles` cycles to go
/// (`time_to_go` cut into cycles of `settings.cycle`, the last possibly shorter), the first
/// command of the solved plan when it predicts a smaller miss than the network's own
/// continuation.
#[allow(clippy::type_complexity)]
pub fn terminal_step<const N: usize, const OUT: usize, A: Actor<N, OUT>, T: Aim<N, OUT>>(
    actor: &A,
    navigation: &<T::Geometry as Dimension>::State,
    target: &T,
    time_to_go: f64,
    spacecraft: &CanonicalSpacecraft,
    settings: &TerminalSettings,
) -> Result<TerminalDecision<<T::Geometry as Dimension>::Command>, GuidanceError> {
    let network = command_at(actor, target, navigation, 0.0, time_to_go)?;
    let mut decision = TerminalDecision {
        command: network,
        network,
        solved: false,
        network_miss: None,
        planned_miss: None,
        rollout_cycles: 0,
    };
    if settings.validate().is_err() {
        return Ok(decision);
    }
    let cycles = cycles_left(time_to_go, settings.cycle);
    if !(cycles >= 1.0 && cycles <= f64::from(settings.cycles)) {
        return Ok(decision);
    }
    let cycles = cycles as usize;
    let problem = Problem::<T::Geometry, T> {
        target,
        spacecraft,
        settings,
        navigation,
        time_to_go,
        cycles,
        propagated: core::cell::Cell::new(0),
    };
    // The network's continuation, flown nominally: the plan's start.
    let mut plan: Plan = [[0.0; 3]; MAX_CYCLES];
    let mut starts = [*navigation; MAX_CYCLES];
    let mut continuation = || {
        let mut state = *navigation;
        for (cycle, (tau, start)) in plan.iter_mut().zip(starts.iter_mut()).take(cycles).enumerate() {
            let elapsed = cycle as f64 * settings.cycle;
            let command = if cycle == 0 {
                network
            } else {
                command_at(actor, target, &state, elapsed, time_to_go - elapsed).ok()?
            };
            *tau = T::Geometry::thrust_vector(&command);
            *start = state;
            state = problem.propagate(&state, &command, cycle)?;
        }
        problem.miss_at(&state)
    };
    let flown = continuation();
    decision.rollout_cycles = problem.propagated.get();
    let Some(e0) = flown else {
        return Ok(decision);
    };
    decision.network_miss = Some(norm(&e0));
    let (solved, best) = solve(&problem, plan, Rollout { e: e0, starts });
    decision.rollout_cycles = problem.propagated.get();
    if norm(&best.e) < norm(&e0) {
        decision.command = T::Geometry::command_of(&solved[0]);
        decision.solved = true;
        decision.planned_miss = Some(norm(&best.e));
    }
    Ok(decision)
}

/// An actor flown with terminal targeting over its last cycles: what flight software holds to
/// call [`terminal_step`] each cycle (it implements [`crate::guidance::Guide`]). Before them it
/// flies the network, or the network with rollout lookahead when `lookahead` is set.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Terminal<A> {
    /// The network.
    pub actor: A,
    /// The nominal spacecraft of the rollouts.
    pub spacecraft: CanonicalSpacecraft,
    /// How many cycles, how many iterations.
    pub settings: TerminalSettings,
    /// Rollout lookahead before the terminal cycles (None: the network alone).
    pub lookahead: Option<LookaheadSettings>,
}

/// In the plane, with rollout lookahead before the terminal cycles when it is set.
impl<const N: usize, T: TargetFeatures<N>, A: Actor<N>> Guide<N, T> for Terminal<A> {
    fn command(
        &self,
        navigation: &SpacecraftState,
        target: &T,
        time_to_go: f64,
    ) -> Result<ThrustCommand, GuidanceError> {
        let (actor, spacecraft) = (&self.actor, &self.spacecraft);
        let cycles = cycles_left(time_to_go, self.settings.cycle);
        match self.lookahead {
            Some(settings) if cycles > f64::from(self.settings.cycles) => {
                lookahead_step(actor, navigation, target, time_to_go, spacecraft, &settings).map(|d| d.command)
            }
            _ => terminal_step(actor, navigation, target, time_to_go, spacecraft, &self.settings).map(|d| d.command),
        }
    }
}

/// In three dimensions, the same: rollout lookahead before the terminal cycles when it is set.
impl<const N: usize, T: SpatialTargetFeatures<N>, A: Actor<N, ACTION3_LEN>> Guide<N, T, Spatial> for Terminal<A> {
    fn command(
        &self,
        navigation: &SpatialCraftState,
        target: &T,
        time_to_go: f64,
    ) -> Result<RtnCommand, GuidanceError> {
        let (actor, spacecraft) = (&self.actor, &self.spacecraft);
        let cycles = cycles_left(time_to_go, self.settings.cycle);
        match self.lookahead {
            Some(settings) if cycles > f64::from(self.settings.cycles) => {
                lookahead_step(actor, navigation, target, time_to_go, spacecraft, &settings).map(|d| d.command)
            }
            _ => terminal_step(actor, navigation, target, time_to_go, spacecraft, &self.settings).map(|d| d.command),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::propagate;
    use crate::features::encode_action;
    use crate::features::{RENDEZVOUS_FEATURES, TRANSFER_FEATURES};
    use crate::geometry::Planar;
    use crate::guidance::tests::Tangential;
    use crate::kepler::coast;
    use shared::orbit::{CartesianState, OrbitShape, SpatialState};
    use shared::spacecraft::Spacecraft;

    fn spacecraft() -> CanonicalSpacecraft {
        Spacecraft::MSR_ERO.canonical().unwrap()
    }

    /// The known commands of [`reachable`]'s three cycles, as thrust vectors.
    const PLAN: [[f64; 2]; 3] = [[0.3, 0.6], [0.0, 0.8], [-0.2, 0.4]];

    /// A network that is nearly right: each cycle (read off the time to go, the feature
    /// `TTG`) it commands [`PLAN`]'s thrust at 90 % and turned by 4 degrees, so it misses the
    /// arrival [`PLAN`] reaches by a few hundredths of an AU (as a trained network misses by
    /// thousandths).
    #[derive(Clone, Copy)]
    struct NearlyRight<const TTG: usize> {
        /// The guidance cycle the network counts its time to go in.
        cycle: f64,
    }
    impl<const N: usize, const TTG: usize> Actor<N> for NearlyRight<TTG> {
        fn act(&self, features: &[f32; N]) -> [f32; 3] {
            let to_go = (f64::from(features[TTG]) / self.cycle).round() as usize;
            let tau = PLAN[3 - to_go.clamp(1, 3)];
            let (s, c) = (libm::sin(0.07), libm::cos(0.07));
            let turned = [0.9 * (tau[0] * c + tau[1] * s), 0.9 * (tau[1] * c - tau[0] * s)];
            encode_action(&Planar::command_of(&[turned[0], turned[1], 0.0])).map(|a| a as f32)
        }
    }

    /// Three cycles of known commands from a 1 AU circular orbit: the start and where they
    /// arrive. A target set there is met exactly by those commands, so a solution exists.
    fn reachable(cycle: f64) -> (SpacecraftState, SpacecraftState) {
        let start = SpacecraftState::from_cartesian(
            &OrbitShape {
                a: 1.0,
                e: 0.0,
                omega: 0.0,
            }
            .cartesian_at(0.3),
            1.0,
        );
        let mut arrival = start;
        for tau in PLAN {
            arrival = propagate(
                &arrival,
                &Planar::command_of(&[tau[0], tau[1], 0.0]),
                &spacecraft(),
                cycle,
                &Tolerances::default(),
            )
            .unwrap();
        }
        (start, arrival)
    }

    /// The orbit the spacecraft is on at `state` (the transfer target [`reachable`] meets).
    fn orbit_through(state: &SpacecraftState) -> OrbitShape {
        CartesianState { r: state.r, v: state.v }.elements().unwrap().shape
    }

    /// Flies three cycles from `start` with `guide`; `target(k)` is the target as flight
    /// software knows it at cycle k. Returns the arrival.
    fn fly<const N: usize, G: Dimension, T>(
        guide: &impl Guide<N, T, G>,
        start: G::State,
        target: impl Fn(u32) -> T,
        cycle: f64,
    ) -> G::State {
        let mut state = start;
        for k in 0..3u32 {
            let time_to_go = f64::from(3 - k) * cycle;
            let command = guide.command(&state, &target(k), time_to_go).unwrap();
            state = G::propagate(&state, &command, &spacecraft(), cycle, &Tolerances::default()).unwrap();
        }
        state
    }

    /// A transfer whose target orbit the flight can reach in its last three cycles: the nearly
    /// right network misses it; terminal targeting meets it within a thousandth of the goal
    /// (its stopping rule), the orbit's own elements as reference; with 14-day cycles and with
    /// 7-day ones.
    #[test]
    fn a_reachable_target_orbit_is_met() {
        for cycle in [STEP, STEP / 2.0] {
            let (start, arrival) = reachable(cycle);
            let target = orbit_through(&arrival);
            let miss = |state: &SpacecraftState| {
                OrbitShape::residuals(
                    &TargetFeatures::<TRANSFER_FEATURES>::features_after(&target, state, 0.0, 0.0).unwrap(),
                )
            };
            let network = NearlyRight::<9> { cycle };
            let alone = fly::<TRANSFER_FEATURES, Planar, _>(&network, start, |_| target, cycle);
            let off = miss(&alone);
            assert!(off.position.max(off.velocity) > 0.001, "{off:?}");
            let guide = Terminal {
                actor: network,
                spacecraft: spacecraft(),
                settings: TerminalSettings {
                    cycle,
                    ..TerminalSettings::default()
                },
                lookahead: None,
            };
            let end = fly::<TRANSFER_FEATURES, Planar, _>(&guide, start, |_| target, cycle);
            let met = miss(&end);
            assert!(met.position < 1e-5 && met.velocity < 1e-5, "{cycle}: {met:?}");
            // Counting 14-day cycles in a 7-day flight, the aid plans the wrong horizon.
            if cycle != STEP {
                let miscounted = Terminal {
                    settings: TerminalSettings::default(),
                    ..guide
                };
                let end = fly::<TRANSFER_FEATURES, Planar, _>(&miscounted, start, |_| target, cycle);
                let off = miss(&end);
                assert!(off.position.max(off.velocity) > 1e-4, "{off:?}");
            }
        }
    }

    /// [`crate::guidance::Aided`] flies as the aids it holds: terminal targeting (with the
    /// lookahead before it), the lookahead alone, the actor alone, bit for bit; the flights
    /// differ, so the choice is seen.
    #[test]
    fn an_aided_actor_flies_as_the_aids_it_holds() {
        use crate::guidance::Aided;
        use crate::lookahead::{Lookahead, LookaheadSettings};
        let (start, arrival) = reachable(STEP);
        let target = orbit_through(&arrival);
        let network = NearlyRight::<9> { cycle: STEP };
        let settings = TerminalSettings {
            cycles: 2,
            ..TerminalSettings::default()
        };
        // A floor far below the network's miss, so that the lookahead has a reason to differ.
        let lookahead = LookaheadSettings {
            accuracy_floor: 1e-6,
            ..LookaheadSettings::default()
        };
        let end = |guide: &dyn Guide<TRANSFER_FEATURES, OrbitShape>| {
            fly::<TRANSFER_FEATURES, Planar, _>(&GuideRef(guide), start, |_| target, STEP)
        };
        let aided = |lookahead, terminal| Aided {
            actor: network,
            spacecraft: spacecraft(),
            lookahead,
            terminal,
        };
        let terminal = |lookahead| Terminal {
            actor: network,
            spacecraft: spacecraft(),
            settings,
            lookahead,
        };
        let looking = Lookahead {
            actor: network,
            spacecraft: spacecraft(),
            settings: lookahead,
        };
        let ends = [
            (
                end(&aided(Some(lookahead), Some(settings))),
                end(&terminal(Some(lookahead))),
            ),
            (end(&aided(None, Some(settings))), end(&terminal(None))),
            (end(&aided(Some(lookahead), None)), end(&looking)),
            (end(&aided(None, None)), end(&network)),
        ];
        for (k, (aided, reference)) in ends.iter().enumerate() {
            assert_eq!(aided, reference, "case {k}");
        }
        assert_ne!(ends[1].1, ends[3].1, "terminal targeting flew as the network");
        assert_ne!(ends[2].1, ends[3].1, "the lookahead flew as the network");
    }

    /// A `dyn Guide` as a sized one, for [`fly`].
    struct GuideRef<'a, const N: usize, T>(&'a dyn Guide<N, T>);
    impl<const N: usize, T> Guide<N, T> for GuideRef<'_, N, T> {
        fn command(
            &self,
            navigation: &SpacecraftState,
            target: &T,
            time_to_go: f64,
        ) -> Result<ThrustCommand, GuidanceError> {
            self.0.command(navigation, target, time_to_go)
        }
    }

    /// [`PLAN`]'s thrust vectors with normal components: [`reachable3`]'s commands.
    const PLAN3: [[f64; 3]; 3] = [[0.3, 0.6, 0.2], [0.0, 0.8, -0.3], [-0.2, 0.4, 0.3]];

    /// [`NearlyRight`] in three dimensions: `plan`'s thrust at 90 %, turned by 4 degrees about
    /// the local normal.
    #[derive(Clone, Copy)]
    struct NearlyRight3<const TTG: usize> {
        cycle: f64,
        plan: [[f64; 3]; 3],
    }
    impl<const N: usize, const TTG: usize> Actor<N, ACTION3_LEN> for NearlyRight3<TTG> {
        fn act(&self, features: &[f32; N]) -> [f32; ACTION3_LEN] {
            let to_go = (f64::from(features[TTG]) / self.cycle).round() as usize;
            let tau = self.plan[3 - to_go.clamp(1, 3)];
            let (s, c) = (libm::sin(0.07), libm::cos(0.07));
            let turned = [
                0.9 * (tau[0] * c + tau[1] * s),
                0.9 * (tau[1] * c - tau[0] * s),
                0.9 * tau[2],
            ];
            crate::features::encode_action3(&Spatial::command_of(&turned)).map(|a| a as f32)
        }
    }

    /// [`reachable`] in three dimensions: three cycles of [`PLAN3`] from a 1 AU circular orbit
    /// inclined by 2.3 degrees.
    fn reachable3(cycle: f64) -> (SpatialCraftState, SpatialCraftState) {
        let plane = shared::orbit::OrbitPlane {
            inclination: 0.04,
            raan: 0.5,
        };
        let circle = OrbitShape {
            a: 1.0,
            e: 0.0,
            omega: 0.0,
        };
        let start = SpatialCraftState {
            orbit: plane.embed(&circle.cartesian_at(0.3)),
            m: 1.0,
        };
        let mut arrival = start;
        for tau in PLAN3 {
            arrival = Spatial::propagate(
                &arrival,
                &Spatial::command_of(&tau),
                &spacecraft(),
                cycle,
                &Tolerances::default(),
            )
            .unwrap();
        }
        (start, arrival)
    }

    /// An inclined orbit and an inclined body the last three cycles can reach, with normal
    /// thrust: the nearly right network misses them; terminal targeting in three dimensions
    /// meets them within a thousandth of the goal, the reference being the orbit's own elements
    /// and the body coasted by Kepler; with 14-day and 7-day cycles.
    #[test]
    fn a_reachable_inclined_orbit_and_body_are_met_in_three_dimensions() {
        use crate::features::{RENDEZVOUS3_FEATURES, TRANSFER3_FEATURES};
        use crate::guidance::TargetOrbit3;
        use crate::kepler::coast3;
        for cycle in [STEP, STEP / 2.0] {
            let (start, arrival) = reachable3(cycle);
            let settings = TerminalSettings {
                cycle,
                ..TerminalSettings::default()
            };
            let (elements, plane) = arrival.orbit.elements().unwrap();
            let orbit = TargetOrbit3 {
                shape: elements.shape,
                plane,
            };
            let network = NearlyRight3::<14> { cycle, plan: PLAN3 };
            let residuals = |end: &SpatialCraftState| TargetOrbit3::residuals(&orbit.features(end, 0.0).unwrap());
            let off = residuals(&fly::<TRANSFER3_FEATURES, Spatial, _>(
                &network,
                start,
                |_| orbit,
                cycle,
            ));
            assert!(off.position.max(off.velocity) > 0.001, "{off:?}");
            let guide = Terminal {
                actor: network,
                spacecraft: spacecraft(),
                settings,
                lookahead: None,
            };
            let met = residuals(&fly::<TRANSFER3_FEATURES, Spatial, _>(&guide, start, |_| orbit, cycle));
            assert!(met.position < 1e-5 && met.velocity < 1e-5, "transfer {cycle}: {met:?}");

            let epoch = coast3(&arrival.orbit, -3.0 * cycle).unwrap();
            let body = |k: u32| coast3(&epoch, f64::from(k) * cycle).unwrap();
            let network = NearlyRight3::<28> { cycle, plan: PLAN3 };
            let residuals = |end: &SpatialCraftState| SpatialState::residuals(&body(3).features(end, 0.0).unwrap());
            let off = residuals(&fly::<RENDEZVOUS3_FEATURES, Spatial, _>(&network, start, body, cycle));
            assert!(off.position.max(off.velocity) > 0.001, "{off:?}");
            let guide = Terminal {
                actor: network,
                spacecraft: spacecraft(),
                settings,
                lookahead: None,
            };
            let met = residuals(&fly::<RENDEZVOUS3_FEATURES, Spatial, _>(&guide, start, body, cycle));
            assert!(
                met.position < 1e-5 && met.velocity < 1e-5,
                "rendezvous {cycle}: {met:?}"
            );
        }
    }

    /// A rendezvous the last three cycles can meet, in the plane and the same lifted into three
    /// dimensions: the planar start, the body's epoch (the arrival coasted back), the start in
    /// three dimensions and the network that flies [`PLAN`] there.
    struct InPlane {
        start: SpacecraftState,
        epoch: CartesianState,
        lifted: SpatialCraftState,
        network: NearlyRight3<28>,
    }

    fn in_plane() -> InPlane {
        let (start, arrival) = reachable(STEP);
        let epoch = coast(
            &CartesianState {
                r: arrival.r,
                v: arrival.v,
            },
            -3.0 * STEP,
        )
        .unwrap();
        let lifted = SpatialCraftState {
            orbit: SpatialState::from_planar(&CartesianState { r: start.r, v: start.v }),
            m: start.m,
        };
        let network = NearlyRight3::<28> {
            cycle: STEP,
            plan: PLAN.map(|t| [t[0], t[1], 0.0]),
        };
        InPlane {
            start,
            epoch,
            lifted,
            network,
        }
    }

    /// In the reference plane, terminal targeting in three dimensions plans a rendezvous as the
    /// planar one does (the same miss components, the normal ones zero): the same command to
    /// 1e-6, no normal thrust, the same predicted misses.
    #[test]
    fn in_the_plane_the_spatial_rendezvous_plan_is_the_planar_one() {
        use crate::features::RENDEZVOUS3_FEATURES;
        let InPlane {
            start,
            epoch,
            lifted,
            network,
        } = in_plane();
        let settings = TerminalSettings::default();
        let planar = terminal_step::<RENDEZVOUS_FEATURES, 3, _, _>(
            &NearlyRight::<20> { cycle: STEP },
            &start,
            &epoch,
            3.0 * STEP,
            &spacecraft(),
            &settings,
        )
        .unwrap();
        let spatial = terminal_step::<RENDEZVOUS3_FEATURES, 4, _, _>(
            &network,
            &lifted,
            &SpatialState::from_planar(&epoch),
            3.0 * STEP,
            &spacecraft(),
            &settings,
        )
        .unwrap();
        assert!(planar.solved && spatial.solved);
        let (p, s) = (planar.command, spatial.command);
        for (a, b) in [
            (p.throttle, s.throttle),
            (p.alpha_r, s.radial),
            (p.alpha_theta, s.transverse),
            (0.0, s.normal),
        ] {
            assert!((a - b).abs() < 1e-6, "{p:?} against {s:?}");
        }
        let close = |a: Option<f64>, b: Option<f64>| (a.unwrap() - b.unwrap()).abs() < 1e-6;
        assert!(
            close(planar.network_miss, spatial.network_miss),
            "{planar:?} {spatial:?}"
        );
        assert!(
            close(planar.planned_miss, spatial.planned_miss),
            "{planar:?} {spatial:?}"
        );
    }

    /// In the plane the spatial rollout lookahead decides as the planar one: the same candidate
    /// from as many rollouts, the same command and predicted arrivals to 1e-9.
    #[test]
    fn in_the_plane_the_spatial_lookahead_decides_as_the_planar_one() {
        use crate::features::RENDEZVOUS3_FEATURES;
        use crate::lookahead::lookahead_step;
        let InPlane {
            start,
            epoch,
            lifted,
            network,
        } = in_plane();
        let settings = LookaheadSettings::default();
        let planar = lookahead_step::<RENDEZVOUS_FEATURES, 3, _, _>(
            &NearlyRight::<20> { cycle: STEP },
            &start,
            &epoch,
            3.0 * STEP,
            &spacecraft(),
            &settings,
        )
        .unwrap();
        let spatial = lookahead_step::<RENDEZVOUS3_FEATURES, 4, _, _>(
            &network,
            &lifted,
            &SpatialState::from_planar(&epoch),
            3.0 * STEP,
            &spacecraft(),
            &settings,
        )
        .unwrap();
        assert_eq!(
            (planar.chosen, planar.rollouts),
            (spatial.chosen, spatial.rollouts),
            "{planar:?} {spatial:?}"
        );
        assert!(planar.rollouts > 1, "{planar:?}");
        let (p, s) = (planar.command, spatial.command);
        for (a, b) in [
            (p.throttle, s.throttle),
            (p.alpha_r, s.radial),
            (p.alpha_theta, s.transverse),
            (0.0, s.normal),
        ] {
            assert!((a - b).abs() < 1e-9, "{p:?} against {s:?}");
        }
        for (a, b) in [
            (planar.predicted, spatial.predicted),
            (planar.network_predicted, spatial.network_predicted),
        ] {
            let (a, b) = (a.unwrap(), b.unwrap());
            assert!(
                (a.cost - b.cost).abs() < 1e-9 && (a.mass - b.mass).abs() < 1e-12,
                "{a:?} {b:?}"
            );
        }
    }

    /// The 3-cycle transfer problem to the orbit through where [`PLAN`] flies from
    /// [`reachable`]'s start, with the default settings, given to `test` with that start and
    /// arrival.
    fn on_reachable_orbit(test: impl FnOnce(&Problem<'_, Planar, OrbitShape>, &SpacecraftState, &SpacecraftState)) {
        let (start, arrival) = reachable(STEP);
        let target = orbit_through(&arrival);
        let (craft, settings) = (spacecraft(), TerminalSettings::default());
        let problem = Problem::<Planar, _> {
            target: &target,
            spacecraft: &craft,
            settings: &settings,
            navigation: &start,
            time_to_go: 3.0 * STEP,
            cycles: 3,
            propagated: core::cell::Cell::new(0),
        };
        test(&problem, &start, &arrival);
    }

    /// [`PLAN`]'s thrust vectors scaled by `scale` and their radial components moved by `shift`.
    fn plan_near(scale: f64, shift: f64) -> Plan {
        let mut plan: Plan = [[0.0; 3]; MAX_CYCLES];
        for (planned, tau) in plan.iter_mut().zip(PLAN) {
            *planned = [scale * tau[0] + shift, scale * tau[1], 0.0];
        }
        plan
    }

    /// The propellant phase on a plan that meets the arrival (the commands that built the
    /// target): a transfer leaves it three degrees of freedom beyond its three conditions, and
    /// the phase finds a cheaper plan that still meets the orbit when flown.
    #[test]
    fn the_propellant_phase_lowers_a_met_plan_and_keeps_it_met() {
        on_reachable_orbit(|problem, start, arrival| {
            let (target, craft) = (problem.target, problem.spacecraft);
            let plan = plan_near(1.0, 0.0);
            let flown = problem.rollout::<TRANSFER_FEATURES, 3>(&plan).unwrap();
            assert!(norm(&flown.e) < MET, "{:?}", flown.e);
            let (lowered, met) = lower_fuel::<TRANSFER_FEATURES, 3, _, _>(problem, plan, flown, 8);
            assert!(norm(&met.e) < MET, "{:?}", met.e);
            let (before, after) = (fuel(problem, &plan), fuel(problem, &lowered));
            assert!(after < 0.99 * before, "propellant {after} against {before}");
            let mut state = *start;
            for tau in lowered.iter().take(3) {
                state = propagate(&state, &Planar::command_of(tau), craft, STEP, &Tolerances::default()).unwrap();
            }
            let flown = OrbitShape::residuals(
                &TargetFeatures::<TRANSFER_FEATURES>::features_after(target, &state, 0.0, 0.0).unwrap(),
            );
            assert!(flown.position < 1e-5 && flown.velocity < 1e-5, "{flown:?}");
            assert!(state.m > arrival.m, "final mass {} against {}", state.m, arrival.m);
        });
    }

    /// A Jacobian column flown from its cycle's start is the column of the whole rollout bit for
    /// bit (the cycles before it are the same propagation), for a fraction of the work: columns
    /// of cycle j fly 3 - j of the 3 cycles.
    #[test]
    fn jacobian_columns_from_each_cycles_start_equal_whole_rollouts() {
        on_reachable_orbit(|problem, _, _| {
            // The plan that built the target, moved off it.
            let plan = plan_near(0.9, 0.05);
            let base = problem.rollout::<TRANSFER_FEATURES, 3>(&plan).unwrap();
            problem.propagated.set(0);
            let jacobian = jacobian(problem, &plan, &base).unwrap();
            assert_eq!(problem.propagated.get(), 2 * (3 + 2 + 1));
            for u in 0..problem.unknowns() {
                let mut moved = plan;
                *component::<Planar>(&mut moved, u).unwrap() += DIFFERENCE;
                let whole = problem.rollout::<TRANSFER_FEATURES, 3>(&moved).unwrap().e;
                for (row, (a, b)) in jacobian.iter().zip(whole.iter().zip(base.e.iter())) {
                    assert_eq!(row[u].to_bits(), ((a - b) / DIFFERENCE).to_bits(), "unknown {u}");
                }
                assert!(
                    jacobian.iter().any(|row| row[u].abs() > 1.0),
                    "unknown {u}: {jacobian:?}"
                );
            }
        });
    }

    /// A rendezvous with a body that the last three cycles can meet (the arrival coasted back
    /// to the epoch): met in position and velocity within a thousandth of the goal.
    #[test]
    fn a_reachable_body_is_met() {
        for cycle in [STEP, STEP / 2.0] {
            let (start, arrival) = reachable(cycle);
            let at_arrival = CartesianState {
                r: arrival.r,
                v: arrival.v,
            };
            let epoch = coast(&at_arrival, -3.0 * cycle).unwrap();
            let body = |k: u32| coast(&epoch, f64::from(k) * cycle).unwrap();
            let network = NearlyRight::<20> { cycle };
            let guide = Terminal {
                actor: network,
                spacecraft: spacecraft(),
                settings: TerminalSettings {
                    cycle,
                    ..TerminalSettings::default()
                },
                lookahead: None,
            };
            let end = fly::<RENDEZVOUS_FEATURES, Planar, _>(&guide, start, body, cycle);
            let features = TargetFeatures::<RENDEZVOUS_FEATURES>::features_after(&body(3), &end, 0.0, 0.0).unwrap();
            let met = CartesianState::residuals(&features);
            assert!(met.position < 1e-5 && met.velocity < 1e-5, "{cycle}: {met:?}");
            let alone = fly::<RENDEZVOUS_FEATURES, Planar, _>(&network, start, body, cycle);
            let features = TargetFeatures::<RENDEZVOUS_FEATURES>::features_after(&body(3), &alone, 0.0, 0.0).unwrap();
            let off = CartesianState::residuals(&features);
            assert!(off.position.max(off.velocity) > 0.001, "{off:?}");
        }
    }

    /// Outside its last cycles, with settings out of range, or with a network that cannot be
    /// improved on, the network's command is flown unchanged.
    #[test]
    fn the_network_flies_unless_a_solved_plan_predicts_a_smaller_miss() {
        let (start, arrival) = reachable(STEP);
        let target = orbit_through(&arrival);
        // A tangential network misses by more than two goals: enough iterations to meet it.
        let settings = TerminalSettings {
            iterations: 8,
            ..TerminalSettings::default()
        };
        let decide = |time_to_go: f64, settings: &TerminalSettings| {
            terminal_step::<TRANSFER_FEATURES, 3, _, _>(
                &Tangential,
                &start,
                &target,
                time_to_go,
                &spacecraft(),
                settings,
            )
            .unwrap()
        };
        let early = decide(10.0 * STEP, &settings);
        assert!(!early.solved && early.command == early.network && early.network_miss.is_none());
        for bad in [
            TerminalSettings { cycles: 0, ..settings },
            TerminalSettings { cycles: 9, ..settings },
            TerminalSettings {
                iterations: 0,
                ..settings
            },
            TerminalSettings {
                iterations: MAX_ITERATIONS + 1,
                ..settings
            },
            TerminalSettings {
                goal_position: f64::NAN,
                ..settings
            },
        ] {
            assert!(bad.validate().is_err());
            assert!(!decide(3.0 * STEP, &bad).solved);
        }
        let late = decide(3.0 * STEP, &settings);
        assert!(late.solved);
        assert!(
            late.planned_miss.unwrap() < 1e-3 && late.network_miss.unwrap() > 1.0,
            "{late:?}"
        );
        assert!(late.command.validate().is_ok());
        // The cycle's work is counted and within the settings' bound; outside the last cycles
        // there is none.
        assert_eq!(early.rollout_cycles, 0);
        for iterations in [1, 2, 5, 8] {
            let settings = TerminalSettings { iterations, ..settings };
            for k in 1..=3u32 {
                let d = decide(f64::from(k) * STEP, &settings);
                let most = settings.most_rollout_cycles::<Planar>(k);
                assert!(
                    d.rollout_cycles > k && d.rollout_cycles <= most,
                    "{k} cycles, {iterations} iterations: {d:?}"
                );
                assert_eq!(most, k + iterations * (k * (k + 1) + 4 * k));
                let spatial = settings.most_rollout_cycles::<Spatial>(k);
                assert_eq!(spatial, k + iterations * (3 * k * (k + 1) / 2 + 4 * k));
            }
        }
    }
}
