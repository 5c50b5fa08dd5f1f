//! Single shooting for the free-anomaly transfer (docs/spec.md section 3): the residual of the terminal
//! conditions and its exact Jacobian, and a damped Newton iteration on them.

use nalgebra::{Const, DMatrix, DVector, DimMin, SMatrix, SVector};
use num_dual::{Dual2_64, DualNum};
use onboard::integrator::{IntegrationError, Tolerances};
use onboard::kepler::coast;
use shared::orbit::{CartesianState, OrbitShape};
use shared::scenario::Scenario;
use shared::spacecraft::CanonicalSpacecraft;

use super::pontryagin::{idx, propagate, propagate_sensitivity, OptimalControlParams, StateCostateSensitivity, Y_LEN};

/// Transfer unknowns: the five initial costates and the final true anomaly nu_f.
pub const TRANSFER_UNKNOWNS: usize = 6;
pub type TransferVector = SVector<f64, TRANSFER_UNKNOWNS>;
pub type TransferJacobian = SMatrix<f64, TRANSFER_UNKNOWNS, TRANSFER_UNKNOWNS>;

/// Cartesian (x, y, vx, vy) on an orbit at true anomaly nu, generic so that first and second
/// derivatives in nu come from dual numbers.
pub fn orbit_state<D: DualNum<Primitive = f64> + Copy>(shape: &OrbitShape, nu: D) -> [D; 4] {
    let p = shape.semi_latus_rectum();
    let k = (1.0 / p).sqrt();
    let theta = nu + shape.omega;
    let r = (nu.cos() * shape.e + 1.0).recip() * p;
    let (so, co) = shape.omega.sin_cos();
    [
        r * theta.cos(),
        r * theta.sin(),
        -(theta.sin() + shape.e * so) * k,
        (theta.cos() + shape.e * co) * k,
    ]
}

/// Initial state-costate vector for a scenario and initial costates.
pub fn initial_state_costate(scenario: &Scenario, lambda0: &[f64; 5]) -> [f64; Y_LEN] {
    let c = scenario.initial.cartesian();
    [
        c.r[0], c.r[1], c.v[0], c.v[1], 1.0, lambda0[0], lambda0[1], lambda0[2], lambda0[3], lambda0[4],
    ]
}

/// The transfer's terminal conditions F at the final state-costate `y` (docs/spec.md section 3): r and v
/// on the target orbit at nu_f, transversality, lambda_m(tf) = 0. Also returns the orbit point
/// with its first and second derivatives in nu_f, which the Jacobian needs.
fn transfer_terminal(scenario: &Scenario, y: &[f64], nu_f: f64) -> (TransferVector, [Dual2_64; 4]) {
    let orbit = orbit_state(&scenario.target, Dual2_64::from_re(nu_f).derivative());
    let mut f = TransferVector::zeros();
    for i in 0..4 {
        f[i] = y[idx::R + i] - orbit[i].re;
    }
    f[4] = (0..4).map(|i| y[idx::LR + i] * orbit[i].v1).sum();
    f[5] = y[idx::LM];
    (f, orbit)
}

/// Terminal residual F(z) of a transfer and its Jacobian dF/dz.
pub fn transfer_residual(
    scenario: &Scenario,
    params: &OptimalControlParams,
    z: &TransferVector,
    tolerances: &Tolerances,
) -> Result<(TransferVector, TransferJacobian), IntegrationError> {
    transfer_residual_at(scenario, scenario.time_of_flight(), params, z, tolerances)
}

/// [`transfer_residual`] at a time of flight other than the scenario's own (the minimum-time
/// search's continuation in the time of flight).
pub fn transfer_residual_at(
    scenario: &Scenario,
    time_of_flight: f64,
    params: &OptimalControlParams,
    z: &TransferVector,
    tolerances: &Tolerances,
) -> Result<(TransferVector, TransferJacobian), IntegrationError> {
    let y0 = initial_state_costate(scenario, &[z[0], z[1], z[2], z[3], z[4]]);
    let ys = propagate_sensitivity(params, &y0, time_of_flight, tolerances)?;
    let (f, orbit) = transfer_terminal(scenario, &ys, z[5]);
    let mut jac = TransferJacobian::zeros();
    for k in 0..5 {
        let s = |row: usize| StateCostateSensitivity::sensitivity(&ys, row, k);
        for i in 0..4 {
            jac[(i, k)] = s(idx::R + i);
        }
        jac[(4, k)] = (0..4).map(|i| s(idx::LR + i) * orbit[i].v1).sum();
        jac[(5, k)] = s(idx::LM);
    }
    for i in 0..4 {
        jac[(i, 5)] = -orbit[i].v1;
    }
    jac[(4, 5)] = (0..4).map(|i| ys[idx::LR + i] * orbit[i].v2).sum();
    Ok((f, jac))
}

/// Terminal residual F(z) of a transfer without the Jacobian: a 10-state propagation instead of
/// the 60-state one, for line-search trials and finite differences in eps.
pub fn transfer_residual_only(
    scenario: &Scenario,
    params: &OptimalControlParams,
    z: &TransferVector,
    tolerances: &Tolerances,
) -> Result<TransferVector, IntegrationError> {
    transfer_residual_only_at(scenario, scenario.time_of_flight(), params, z, tolerances)
}

/// [`transfer_residual_only`] at a time of flight other than the scenario's own.
pub fn transfer_residual_only_at(
    scenario: &Scenario,
    time_of_flight: f64,
    params: &OptimalControlParams,
    z: &TransferVector,
    tolerances: &Tolerances,
) -> Result<TransferVector, IntegrationError> {
    let y0 = initial_state_costate(scenario, &[z[0], z[1], z[2], z[3], z[4]]);
    let y = propagate(params, 0.0, &y0, time_of_flight, tolerances)?;
    Ok(transfer_terminal(scenario, &y, z[5]).0)
}

/// A shooting problem: K unknowns, K terminal conditions, their residual and exact Jacobian at
/// a homotopy parameter eps.
pub trait ShootingProblem<const K: usize> {
    /// The residual alone (cheaper: no sensitivities). Defaults to [`Self::residual`].
    fn residual_only(
        &self,
        eps: f64,
        z: &SVector<f64, K>,
        tolerances: &Tolerances,
    ) -> Result<SVector<f64, K>, IntegrationError> {
        self.residual(eps, z, tolerances).map(|(f, _)| f)
    }

    fn residual(
        &self,
        eps: f64,
        z: &SVector<f64, K>,
        tolerances: &Tolerances,
    ) -> Result<(SVector<f64, K>, SMatrix<f64, K, K>), IntegrationError>;

    /// [`newton`] gives up after this many consecutive iterations that each reduced the residual
    /// (2-norm) by less than half; by default it never does.
    fn stall_limit(&self) -> u32 {
        u32::MAX
    }
}

/// The free-anomaly transfer (6 unknowns: lambda_0 and nu_f).
#[derive(Debug, Clone, Copy)]
pub struct TransferShooting<'a> {
    pub scenario: &'a Scenario,
    pub spacecraft: CanonicalSpacecraft,
}

impl ShootingProblem<TRANSFER_UNKNOWNS> for TransferShooting<'_> {
    fn residual(
        &self,
        eps: f64,
        z: &TransferVector,
        tolerances: &Tolerances,
    ) -> Result<(TransferVector, TransferJacobian), IntegrationError> {
        transfer_residual(
            self.scenario,
            &OptimalControlParams {
                spacecraft: self.spacecraft,
                eps,
            },
            z,
            tolerances,
        )
    }
}

/// The transfer with its final anomaly pinned: unknowns lambda_0, equations r, v on the target
/// orbit at the given nu_f and lambda_m(tf) = 0 (the transversality condition left out). Between
/// nearly circular orbits the free problem's weakest direction is almost exactly nu_f (the shift
/// of the burn pattern along the circles); with it pinned the system is well conditioned, and
/// the transversality residual [`TransferShooting`] leaves out is a smooth function of nu_f
/// whose zero a 1-D search finds.
#[derive(Debug, Clone, Copy)]
pub struct PinnedAnomalyTransfer<'a> {
    pub scenario: &'a Scenario,
    pub spacecraft: CanonicalSpacecraft,
    pub nu_f: f64,
}

impl PinnedAnomalyTransfer<'_> {
    fn full(&self, z: &RendezvousVector) -> TransferVector {
        TransferVector::from_column_slice(&[z[0], z[1], z[2], z[3], z[4], self.nu_f])
    }

    fn params(&self, eps: f64) -> OptimalControlParams {
        OptimalControlParams {
            spacecraft: self.spacecraft,
            eps,
        }
    }

    /// The free problem's residual (all six conditions, transversality in row 4) at costates `z`.
    pub fn free_residual(
        &self,
        eps: f64,
        z: &RendezvousVector,
        tolerances: &Tolerances,
    ) -> Result<TransferVector, IntegrationError> {
        transfer_residual_only(self.scenario, &self.params(eps), &self.full(z), tolerances)
    }
}

const PINNED_ROWS: [usize; 5] = [0, 1, 2, 3, 5];

impl ShootingProblem<RENDEZVOUS_UNKNOWNS> for PinnedAnomalyTransfer<'_> {
    fn residual_only(
        &self,
        eps: f64,
        z: &RendezvousVector,
        tolerances: &Tolerances,
    ) -> Result<RendezvousVector, IntegrationError> {
        let f = self.free_residual(eps, z, tolerances)?;
        Ok(RendezvousVector::from_fn(|i, _| f[PINNED_ROWS[i]]))
    }

    fn residual(
        &self,
        eps: f64,
        z: &RendezvousVector,
        tolerances: &Tolerances,
    ) -> Result<(RendezvousVector, SMatrix<f64, RENDEZVOUS_UNKNOWNS, RENDEZVOUS_UNKNOWNS>), IntegrationError> {
        let (f, jac) = transfer_residual(self.scenario, &self.params(eps), &self.full(z), tolerances)?;
        Ok((
            RendezvousVector::from_fn(|i, _| f[PINNED_ROWS[i]]),
            SMatrix::from_fn(|i, k| jac[(PINNED_ROWS[i], k)]),
        ))
    }
}

/// Settings of the Newton iteration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonSettings {
    pub max_iterations: u32,
    /// Converged when every terminal condition holds to this (canonical units).
    pub tolerance: f64,
}

impl Default for NewtonSettings {
    fn default() -> Self {
        Self {
            max_iterations: 60,
            tolerance: 1e-8,
        }
    }
}

/// Where an iteration ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonOutcome<const K: usize = TRANSFER_UNKNOWNS> {
    pub z: SVector<f64, K>,
    pub residual: f64,
    pub iterations: u32,
    pub converged: bool,
}

/// Minimum-norm solution of J dz = -F by the singular value decomposition, singular values
/// below `rcond * s_max` treated as zero, and optionally the `drop` smallest ones dropped as
/// well. Returns the step and the ratio s_min / s_max of the full spectrum.
fn svd_step<const K: usize>(
    jac: &SMatrix<f64, K, K>,
    f: &SVector<f64, K>,
    rcond: f64,
    drop: usize,
) -> Option<(SVector<f64, K>, f64)> {
    // A dynamic copy: nalgebra's fixed-size SVD needs type-level bounds a const-generic K lacks,
    // and a 6x6 copy costs nothing next to one propagation.
    let svd = DMatrix::from_column_slice(K, K, jac.as_slice()).svd(true, true);
    let (u, v_t) = (svd.u.as_ref()?, svd.v_t.as_ref()?);
    let sv = &svd.singular_values;
    let s_max = sv.max();
    if !(s_max.is_finite() && s_max > 0.0) {
        return None;
    }
    let mut order: Vec<usize> = (0..K).collect();
    order.sort_by(|&a, &b| sv[a].total_cmp(&sv[b]));
    let s_min = sv[order[0]];
    let mut step = SVector::<f64, K>::zeros();
    for (rank, &i) in order.iter().enumerate() {
        if rank < drop || sv[i] <= rcond * s_max {
            continue;
        }
        let coef = -u.column(i).dot(&DVector::from_column_slice(f.as_slice())) / sv[i];
        for k in 0..K {
            step[k] += coef * v_t[(i, k)];
        }
    }
    step.iter().all(|x| x.is_finite()).then_some((step, s_min / s_max))
}

/// Singular values below this fraction of the largest are treated as zero (minimum-norm step).
const RCOND: f64 = 1e-13;
/// A Jacobian this ill-conditioned (s_min / s_max) has a flat valley along its weakest
/// direction (the transfer-circular shift family, see the module notes): the valley step is tried.
const VALLEY_CONDITION: f64 = 1e-3;
/// Below this the Jacobian is rank deficient rather than ill-conditioned (typically a trial that
/// never thrusts, where F does not depend on the costates at all): no valley to follow there.
const PLATEAU_CONDITION: f64 = 1e-13;

/// Newton on a shooting problem, built for Jacobians that are nearly rank deficient.
///
/// Each iteration takes the minimum-norm Gauss-Newton step dz = -J^+ F (SVD) with backtracking
/// (Armijo on |F|^2, trials on the residual alone). When that fails and J is ill-conditioned,
/// the solution lies in a curved, nearly flat valley (between circular orbits the thrust
/// program can slide along a one-parameter family of near-extremals): a straight step along the
/// weak direction leaves the valley by its curvature, so the valley step moves along it and
/// then projects back onto the valley floor with Gauss-Newton steps that leave the weakest
/// direction out. Last comes a Levenberg-Marquardt step with Nielsen's damping. A failed
/// propagation counts as a rejected trial.
pub fn newton<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    eps: f64,
    z0: &SVector<f64, K>,
    tolerances: &Tolerances,
    settings: &NewtonSettings,
) -> Result<NewtonOutcome<K>, IntegrationError>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    // See ShootingProblem::stall_limit.
    let stall = problem.stall_limit();
    let mut stalled = 0u32;
    let mut last_norm = f64::INFINITY;
    let eval = |z: &SVector<f64, K>| problem.residual(eps, z, tolerances);
    let mut z = *z0;
    let (mut f, mut jac) = eval(&z)?;
    let mut mu = 1e-3;
    let mut nu = 2.0;
    let mut iterations = 0;
    while iterations < settings.max_iterations {
        let residual = f.amax();
        if residual < settings.tolerance {
            return Ok(NewtonOutcome {
                z,
                residual,
                iterations,
                converged: true,
            });
        }
        // The 2-norm, which the line search decreases (the max norm can stay put while it falls).
        let norm = f.norm();
        if norm > 0.5 * last_norm {
            stalled += 1;
            if stalled >= stall {
                break;
            }
        } else {
            stalled = 0;
        }
        last_norm = norm;
        iterations += 1;
        let f2 = f.norm_squared();
        let full = svd_step(&jac, &f, RCOND, 0);
        if let Some((step, _)) = full {
            let mut alpha = 1.0;
            let mut accepted = None;
            for k in 0..8 {
                let trial = z + step * alpha;
                // Trials need F only; the Jacobian is computed once a trial is accepted.
                if let Ok(ft) = problem.residual_only(eps, &trial, tolerances) {
                    if ft.norm_squared() <= (1.0 - 1e-4 * alpha) * f2 {
                        if let Ok((ft, jt)) = eval(&trial) {
                            accepted = Some((trial, ft, jt));
                        }
                        break;
                    }
                }
                if k == 0 {
                    if let Some(two) = look_ahead(problem, eps, &trial, f2, tolerances) {
                        accepted = Some(two);
                        break;
                    }
                }
                alpha *= 0.5;
            }
            if let Some((trial, ft, jt)) = accepted {
                (z, f, jac) = (trial, ft, jt);
                continue;
            }
        }
        if let Some((step, condition)) = full.filter(|(_, c)| (PLATEAU_CONDITION..VALLEY_CONDITION).contains(c)) {
            if let Some((trial, ft, jt)) = valley_step(problem, eps, &z, &step, condition, f2, tolerances) {
                (z, f, jac) = (trial, ft, jt);
                continue;
            }
        }
        // Levenberg-Marquardt fallback.
        let jtj = jac.transpose() * jac;
        let g = jac.transpose() * f;
        let mut a = jtj;
        for i in 0..K {
            a[(i, i)] += mu * jtj[(i, i)].max(1e-12);
        }
        let Some(step) = a.lu().solve(&(-g)) else {
            mu *= nu;
            nu *= 2.0;
            continue;
        };
        let trial = z + step;
        let predicted = f2 - (f + jac * step).norm_squared();
        match eval(&trial) {
            Ok((ft, jt)) if ft.norm_squared() < f2 => {
                let gain = (f2 - ft.norm_squared()) / predicted.max(1e-300);
                mu *= (1.0f64 / 3.0).max(1.0 - (2.0 * gain - 1.0).powi(3));
                nu = 2.0;
                (z, f, jac) = (trial, ft, jt);
            }
            _ => {
                mu *= nu;
                nu *= 2.0;
            }
        }
    }
    let residual = f.amax();
    Ok(NewtonOutcome {
        z,
        residual,
        iterations,
        converged: residual < settings.tolerance,
    })
}

type Evaluated<const K: usize> = (SVector<f64, K>, SVector<f64, K>, SMatrix<f64, K, K>);

/// Two Newton steps without a descent test in between: the full step to `trial` (which raised
/// |F|), then the Newton step from there; accepted when that lands below |F|^2 = `f2`.
///
/// Why: the smoothed throttle is piecewise linear in rho, so where a maximum of rho touches +eps
/// (or a minimum -eps) a full-thrust (or coast) sub-arc is born, and F picks up a term
/// ~ (rho_max - eps)^(3/2): continuous with its first derivative, but with unbounded curvature.
/// A Newton step from the side without the sub-arc cannot see it and overshoots, and halving the
/// step only crawls (seen on transfer-circular near eps ~ 1e-4: 15 iterations at |F| ~ 1e-5);
/// the Jacobian taken on the far side includes the sub-arc, and the next step converges.
fn look_ahead<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    eps: f64,
    trial: &SVector<f64, K>,
    f2: f64,
    tolerances: &Tolerances,
) -> Option<Evaluated<K>>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    let (f1, j1) = problem.residual(eps, trial, tolerances).ok()?;
    let (step, _) = svd_step(&j1, &f1, RCOND, 0)?;
    let next = trial + step;
    let f_next = problem.residual_only(eps, &next, tolerances).ok()?;
    if f_next.norm_squared() > (1.0 - 1e-4) * f2 {
        return None;
    }
    let (f, j) = problem.residual(eps, &next, tolerances).ok()?;
    Some((next, f, j))
}

/// Moves a fraction of the Newton step along the valley, then projects back onto its floor by up
/// to four Gauss-Newton steps without the weakest direction; accepted when |F|^2 fell.
fn valley_step<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    eps: f64,
    z: &SVector<f64, K>,
    step: &SVector<f64, K>,
    _condition: f64,
    f2: f64,
    tolerances: &Tolerances,
) -> Option<Evaluated<K>>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    for alpha in [1.0, 0.25, 0.0625] {
        let mut trial = z + step * alpha;
        let (mut ft, mut jt) = problem.residual(eps, &trial, tolerances).ok()?;
        for _ in 0..4 {
            if ft.norm_squared() <= (1.0 - 1e-4) * f2 {
                break;
            }
            let Some((proj, _)) = svd_step(&jt, &ft, RCOND, 1) else {
                break;
            };
            let next = trial + proj;
            let Ok((fn_, jn)) = problem.residual(eps, &next, tolerances) else {
                break;
            };
            if fn_.norm_squared() >= ft.norm_squared() {
                break;
            }
            (trial, ft, jt) = (next, fn_, jn);
        }
        if ft.norm_squared() <= (1.0 - 1e-4) * f2 {
            return Some((trial, ft, jt));
        }
    }
    None
}

/// Newton on the transfer residual (see [`newton`]).
pub fn solve_transfer(
    scenario: &Scenario,
    params: &OptimalControlParams,
    z0: &TransferVector,
    tolerances: &Tolerances,
    settings: &NewtonSettings,
) -> Result<NewtonOutcome, IntegrationError> {
    let problem = TransferShooting {
        scenario,
        spacecraft: params.spacecraft,
    };
    newton(&problem, params.eps, z0, tolerances, settings)
}

/// One level of the energy-to-fuel homotopy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HomotopyLevel<const K: usize = TRANSFER_UNKNOWNS> {
    pub eps: f64,
    pub outcome: NewtonOutcome<K>,
}

/// The last level of the docs/spec.md section 3 schedule is the first eps below this.
pub const FINAL_EPS: f64 = 1e-4;

/// The homotopy schedule: eps = 1, halving, the last level the first one below `final_eps`
/// (docs/spec.md section 3: [`FINAL_EPS`]).
pub fn homotopy_schedule(final_eps: f64) -> impl Iterator<Item = f64> {
    core::iter::successors(Some(1.0f64), move |&e| (e >= final_eps).then_some(e * 0.5))
}

/// Tangent of the solution path: dz/d(eps) = -J^-1 dF/d(eps), with dF/d(eps) by a central
/// difference in eps (the propagations are smooth in eps for eps > 0).
pub fn homotopy_tangent<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    z: &SVector<f64, K>,
    eps: f64,
    tolerances: &Tolerances,
) -> Result<Option<SVector<f64, K>>, IntegrationError>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    // Not smaller: the propagations carry ~1e-11 of round-off (see pontryagin::TIME_OFFSET).
    let h = eps * 1e-3;
    let (_, jac) = problem.residual(eps, z, tolerances)?;
    let fp = problem.residual_only(eps + h, z, tolerances)?;
    let fm = problem.residual_only(eps - h, z, tolerances)?;
    let df_de = (fp - fm) / (2.0 * h);
    Ok(jac.lu().solve(&(-df_de)))
}

/// The predicted solution at `next` from the solution `z` at `eps`: the tangent step, plus the
/// quadratic term that makes the prediction pass through the previous solution `previous`
/// (at another eps) when there is one. Near eps -> 0 the path bends on the scale of eps itself
/// (the throttle ramps narrow like eps), and Newton's basin shrinks with it, so the curvature term
/// is what lets the corrector converge at the schedule's step.
pub fn predict<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    z: &SVector<f64, K>,
    eps: f64,
    next: f64,
    previous: Option<(f64, SVector<f64, K>)>,
    tolerances: &Tolerances,
) -> SVector<f64, K>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    let Ok(Some(t)) = homotopy_tangent(problem, z, eps, tolerances) else {
        return *z;
    };
    let d = next - eps;
    let linear = t * d;
    match previous {
        Some((e_p, z_p)) if (e_p - eps).abs() > 0.0 => {
            let dp = e_p - eps;
            let c = (z_p - z - t * dp) / (dp * dp);
            let quadratic = c * (d * d);
            // Only as a correction: a curvature term larger than the tangent step is not trusted.
            if quadratic.amax() <= linear.amax() {
                z + linear + quadratic
            } else {
                z + linear
            }
        }
        _ => z + linear,
    }
}

/// Follows the solution path of a shooting problem from (`eps0`, `z0`, solved) to `eps1` (up or
/// down) in geometric steps, with the curvature-corrected predictor ([`predict`]) and a Newton
/// corrector; the step ratio shrinks after a failed corrector and grows after a success. Returns
/// the last solved point (eps and unknowns), which is at `eps1` unless the step ratio (at most
/// `max_ratio` per step) shrank to ~1 or `max_solves` correctors were spent.
#[allow(clippy::too_many_arguments)]
pub fn continue_eps<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    z0: &SVector<f64, K>,
    eps0: f64,
    eps1: f64,
    tolerances: &Tolerances,
    settings: &NewtonSettings,
    max_ratio: f64,
    max_solves: u32,
) -> (f64, SVector<f64, K>)
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    let up = eps1 > eps0;
    let mut factor: f64 = max_ratio;
    let (mut eps, mut z) = (eps0, *z0);
    let mut previous: Option<(f64, SVector<f64, K>)> = None;
    for _ in 0..max_solves {
        if (up && eps >= eps1) || (!up && eps <= eps1) {
            break;
        }
        let next = if up {
            (eps * factor).min(eps1)
        } else {
            (eps / factor).max(eps1)
        };
        let predicted = predict(problem, &z, eps, next, previous, tolerances);
        let step = newton(problem, next, &predicted, tolerances, settings);
        match step {
            Ok(o) if o.converged => {
                previous = Some((eps, z));
                (eps, z) = (next, o.z);
                factor = (factor * factor).min(max_ratio);
            }
            _ => {
                factor = factor.sqrt();
                if factor < 1.01 {
                    break;
                }
            }
        }
    }
    (eps, z)
}

/// Solves a shooting problem along the homotopy schedule. Between levels it follows the
/// solution path with a tangent predictor and a Newton corrector, halving the log-step in eps
/// when the corrector fails (down to a ratio of 0.99), within a budget of
/// `max_corrector_solves` Newton solves in all. Stops at the first level that cannot be
/// reached; the levels solved so far are returned, the failed one last.
pub fn homotopy<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    z0: &SVector<f64, K>,
    tolerances: &Tolerances,
    settings: &NewtonSettings,
    final_eps: f64,
    max_corrector_solves: u32,
) -> Result<Vec<HomotopyLevel<K>>, IntegrationError>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    let mut schedule = homotopy_schedule(final_eps);
    let Some(first) = schedule.next() else {
        return Ok(Vec::new());
    };
    let outcome = newton(problem, first, z0, tolerances, settings)?;
    let mut levels = vec![HomotopyLevel { eps: first, outcome }];
    if !outcome.converged {
        return Ok(levels);
    }
    let (mut eps, mut z) = (first, outcome.z);
    let mut previous: Option<(f64, SVector<f64, K>)> = None;
    let mut ratio: f64 = 0.5;
    let mut solves = 0u32;
    for target in schedule {
        let mut last = outcome;
        while eps > target {
            solves += 1;
            if solves > max_corrector_solves {
                levels.push(HomotopyLevel {
                    eps: target,
                    outcome: NewtonOutcome {
                        converged: false,
                        ..last
                    },
                });
                return Ok(levels);
            }
            let next = (eps * ratio).max(target);
            let predicted = predict(problem, &z, eps, next, previous, tolerances);
            // A propagation that fails from a predicted point is a failed corrector, not an error.
            let step = newton(problem, next, &predicted, tolerances, settings).unwrap_or(NewtonOutcome {
                z: predicted,
                residual: f64::INFINITY,
                iterations: 0,
                converged: false,
            });
            if step.converged {
                previous = Some((eps, z));
                (eps, z, last) = (next, step.z, step);
                ratio = (ratio * ratio).max(0.5); // grow the step back after a success
            } else {
                ratio = ratio.sqrt();
                if ratio > 0.99 {
                    levels.push(HomotopyLevel {
                        eps: target,
                        outcome: NewtonOutcome {
                            converged: false,
                            ..step
                        },
                    });
                    return Ok(levels);
                }
            }
        }
        levels.push(HomotopyLevel {
            eps: target,
            outcome: last,
        });
    }
    Ok(levels)
}

/// [`homotopy`] on a transfer.
pub fn solve_transfer_homotopy(
    scenario: &Scenario,
    spacecraft: &CanonicalSpacecraft,
    z0: &TransferVector,
    tolerances: &Tolerances,
    settings: &NewtonSettings,
    final_eps: f64,
    max_corrector_solves: u32,
) -> Result<Vec<HomotopyLevel>, IntegrationError> {
    let problem = TransferShooting {
        scenario,
        spacecraft: *spacecraft,
    };
    homotopy(&problem, z0, tolerances, settings, final_eps, max_corrector_solves)
}

/// Rendezvous unknowns: the five initial costates.
pub const RENDEZVOUS_UNKNOWNS: usize = 5;
pub type RendezvousVector = SVector<f64, RENDEZVOUS_UNKNOWNS>;

/// The rendezvous (docs/spec.md section 3, TBR): r(tf), v(tf) equal the body's state, lambda_m(tf) = 0.
/// The body moves on its Keplerian orbit from anomaly nu_f0 at t = 0.
#[derive(Debug, Clone, Copy)]
pub struct RendezvousShooting<'a> {
    pub scenario: &'a Scenario,
    pub spacecraft: CanonicalSpacecraft,
}

impl RendezvousShooting<'_> {
    /// The terminal conditions at the final state-costate `y`: r and v equal the body's,
    /// lambda_m(tf) = 0.
    fn terminal(&self, y: &[f64]) -> Result<RendezvousVector, IntegrationError> {
        let body = self.body_at_arrival()?;
        let target = [body.r[0], body.r[1], body.v[0], body.v[1]];
        let mut f = RendezvousVector::zeros();
        for i in 0..4 {
            f[i] = y[idx::R + i] - target[i];
        }
        f[4] = y[idx::LM];
        Ok(f)
    }

    /// The body's state at the end of the flight.
    pub fn body_at_arrival(&self) -> Result<CartesianState, IntegrationError> {
        let start = self.scenario.target.cartesian_at(self.scenario.target_nu0);
        coast(&start, self.scenario.time_of_flight()).map_err(|_| IntegrationError::InvalidInput)
    }
}

impl ShootingProblem<RENDEZVOUS_UNKNOWNS> for RendezvousShooting<'_> {
    fn residual_only(
        &self,
        eps: f64,
        z: &RendezvousVector,
        tolerances: &Tolerances,
    ) -> Result<RendezvousVector, IntegrationError> {
        let params = OptimalControlParams {
            spacecraft: self.spacecraft,
            eps,
        };
        let y0 = initial_state_costate(self.scenario, &[z[0], z[1], z[2], z[3], z[4]]);
        let y = propagate(&params, 0.0, &y0, self.scenario.time_of_flight(), tolerances)?;
        self.terminal(&y)
    }

    fn residual(
        &self,
        eps: f64,
        z: &RendezvousVector,
        tolerances: &Tolerances,
    ) -> Result<(RendezvousVector, SMatrix<f64, RENDEZVOUS_UNKNOWNS, RENDEZVOUS_UNKNOWNS>), IntegrationError> {
        let params = OptimalControlParams {
            spacecraft: self.spacecraft,
            eps,
        };
        let y0 = initial_state_costate(self.scenario, &[z[0], z[1], z[2], z[3], z[4]]);
        let ys = propagate_sensitivity(&params, &y0, self.scenario.time_of_flight(), tolerances)?;
        let f = self.terminal(&ys)?;
        let mut jac = SMatrix::<f64, RENDEZVOUS_UNKNOWNS, RENDEZVOUS_UNKNOWNS>::zeros();
        for k in 0..RENDEZVOUS_UNKNOWNS {
            for i in 0..4 {
                jac[(i, k)] = StateCostateSensitivity::sensitivity(&ys, idx::R + i, k);
            }
            jac[(4, k)] = StateCostateSensitivity::sensitivity(&ys, idx::LM, k);
        }
        Ok((f, jac))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use onboard::integrator::integrate;
    use shared::orbit::OrbitElements;
    use shared::scenario::ProblemKind;
    use shared::spacecraft::Spacecraft;

    /// F(z) = (z0^2 + 1e-2, z1): no root, its |F| only creeps towards 1e-2 under Newton (z0 halves
    /// per step); `stall` is its stall limit.
    struct NoRoot {
        stall: u32,
    }

    impl ShootingProblem<2> for NoRoot {
        fn residual(
            &self,
            _eps: f64,
            z: &SVector<f64, 2>,
            _tolerances: &Tolerances,
        ) -> Result<(SVector<f64, 2>, SMatrix<f64, 2, 2>), IntegrationError> {
            Ok((
                SVector::<f64, 2>::new(z[0] * z[0] + 1e-2, z[1]),
                SMatrix::<f64, 2, 2>::new(2.0 * z[0], 0.0, 0.0, 1.0),
            ))
        }

        fn stall_limit(&self) -> u32 {
            self.stall
        }
    }

    /// Newton with a stall limit stops after that many consecutive iterations that did not halve
    /// |F|, not converged, where the default runs to its iteration cap; and a stall limit does
    /// not stop an iteration that converges (the same problem with a root).
    #[test]
    fn newton_gives_up_after_the_stall_limit() {
        let settings = NewtonSettings {
            max_iterations: 40,
            tolerance: 1e-12,
        };
        let z0 = SVector::<f64, 2>::new(1.0, 1.0);
        let capped = newton(&NoRoot { stall: u32::MAX }, 0.0, &z0, &tight(), &settings).unwrap();
        assert!(!capped.converged);
        assert_eq!(capped.iterations, 40);
        let stalled = newton(&NoRoot { stall: 3 }, 0.0, &z0, &tight(), &settings).unwrap();
        assert!(!stalled.converged);
        // |F| halves while z0^2 dominates 1e-2 (a few steps), then creeps: 3 stagnating ones later
        // it stops, far below the cap.
        assert!(stalled.iterations < 12, "{}", stalled.iterations);
        assert!((stalled.residual - 1e-2).abs() < 1e-3, "{}", stalled.residual);

        /// z0^2 - 1e-2: a root at z0 = 0.1, converging quadratically.
        struct Root;
        impl ShootingProblem<1> for Root {
            fn residual(
                &self,
                _eps: f64,
                z: &SVector<f64, 1>,
                _tolerances: &Tolerances,
            ) -> Result<(SVector<f64, 1>, SMatrix<f64, 1, 1>), IntegrationError> {
                Ok((
                    SVector::<f64, 1>::new(z[0] * z[0] - 1e-2),
                    SMatrix::<f64, 1, 1>::new(2.0 * z[0]),
                ))
            }

            fn stall_limit(&self) -> u32 {
                1
            }
        }
        let root = newton(&Root, 0.0, &SVector::<f64, 1>::new(0.3), &tight(), &settings).unwrap();
        assert!(root.converged && (root.z[0] - 0.1).abs() < 1e-10, "{root:?}");
    }

    /// The integration accuracy every shooting test uses (docs/spec.md: rtol 1e-11 or tighter).
    fn tight() -> Tolerances {
        Tolerances {
            relative: 1e-12,
            absolute: 1e-13,
            ..Tolerances::default()
        }
    }

    /// Final mass of the impulsive Hohmann transfer between circular orbits r1 -> r2: the
    /// upper bound of any finite-thrust transfer's final mass.
    fn hohmann_mass_bound(r1: f64, r2: f64, exhaust_speed: f64) -> f64 {
        let dv = (1.0 / r1).sqrt() * ((2.0 * r2 / (r1 + r2)).sqrt() - 1.0)
            + (1.0 / r2).sqrt() * (1.0 - (2.0 * r1 / (r1 + r2)).sqrt());
        (-dv / exhaust_speed).exp()
    }

    fn scenario() -> Scenario {
        let initial = OrbitElements {
            shape: OrbitShape {
                a: 1.0,
                e: 0.05,
                omega: 0.3,
            },
            nu: 0.4,
        };
        let target = OrbitShape {
            a: 1.3,
            e: 0.2,
            omega: 1.1,
        };
        Scenario {
            problem: ProblemKind::Transfer,
            initial,
            target,
            target_nu0: 0.0,
            steps: 20,
        }
    }

    fn circular_scenario(a0: f64, af: f64) -> Scenario {
        let initial = OrbitElements {
            shape: OrbitShape {
                a: a0,
                e: 1e-4,
                omega: 0.0,
            },
            nu: 0.0,
        };
        let target = OrbitShape {
            a: af,
            e: 1e-4,
            omega: 0.0,
        };
        Scenario::transfer(initial, target)
    }

    #[test]
    fn energy_optimal_circular_transfer_converges_and_respects_the_hohmann_bound() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let params = OptimalControlParams {
            spacecraft: sc,
            eps: 1.0,
        };
        let tol = Tolerances {
            relative: 1e-11,
            absolute: 1e-12,
            ..Tolerances::default()
        };
        let scenario = circular_scenario(1.0, 1.3);
        // A rough physics-shaped guess: primer along-track, lambda_r radial, one revolution plus
        // a quarter for the final anomaly. (Finding such guesses automatically is the solver's job.)
        let z0 = TransferVector::from_column_slice(&[-0.3, 0.0, 0.0, -0.3, 0.05, 7.5]);
        let out = solve_transfer(&scenario, &params, &z0, &tol, &NewtonSettings::default()).unwrap();
        assert!(out.converged, "{out:?}");
        // Re-propagate the solution: terminal conditions hold, and the mass is feasible.
        let (f, _) = transfer_residual(&scenario, &params, &out.z, &tol).unwrap();
        assert!(f.amax() < 1e-8);
        let y0 = initial_state_costate(&scenario, &[out.z[0], out.z[1], out.z[2], out.z[3], out.z[4]]);
        let (yf, _) = integrate(
            &super::super::pontryagin::StateCostate(params),
            0.0,
            &y0,
            scenario.time_of_flight(),
            &tol,
        )
        .unwrap();
        let bound = hohmann_mass_bound(1.0, 1.3, sc.exhaust_speed);
        assert!(
            yf[idx::M] < bound && yf[idx::M] > 0.8,
            "m_f {} vs Hohmann bound {bound}",
            yf[idx::M]
        );
    }

    /// The homotopy follows the solution path down to eps = 1/32 (a bounded-time test; deeper
    /// levels are reached too but slowly, see the solver notes), with fuel use falling
    /// monotonically and the mass staying below the impulsive bound.
    #[test]
    fn homotopy_levels_converge_with_monotone_fuel_use() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let tol = tight();
        let scenario = circular_scenario(1.0, 1.3);
        let z0 = TransferVector::from_column_slice(&[-0.3, 0.0, 0.0, -0.3, 0.05, 7.5]);
        let schedule: Vec<f64> = homotopy_schedule(FINAL_EPS).collect();
        assert_eq!(schedule.len(), 15);
        assert!(schedule[14] < 1e-4 && schedule[13] >= 1e-4);
        let settings = NewtonSettings {
            max_iterations: 30,
            ..NewtonSettings::default()
        };
        let levels = solve_transfer_homotopy(&scenario, &sc, &z0, &tol, &settings, 0.05, 100).unwrap();
        assert_eq!(levels.iter().map(|l| l.eps).collect::<Vec<_>>(), schedule[..6].to_vec());
        // With the tangent predictor each level takes a handful of Newton iterations.
        assert!(
            levels.iter().all(|l| l.outcome.converged && l.outcome.iterations <= 12),
            "{levels:?}"
        );
        let mut previous_mass = 0.0;
        for level in &levels {
            let params = OptimalControlParams {
                spacecraft: sc,
                eps: level.eps,
            };
            let z = level.outcome.z;
            let y0 = initial_state_costate(&scenario, &[z[0], z[1], z[2], z[3], z[4]]);
            let system = super::super::pontryagin::StateCostate(params);
            let (yf, _) = integrate(&system, 0.0, &y0, scenario.time_of_flight(), &tol).unwrap();
            // Less weight on energy, less propellant: the final mass never drops along the way.
            assert!(
                yf[idx::M] >= previous_mass - 1e-9,
                "eps {}: {} < {previous_mass}",
                level.eps,
                yf[idx::M]
            );
            previous_mass = yf[idx::M];
        }
        let bound = hohmann_mass_bound(1.0, 1.3, sc.exhaust_speed);
        assert!(previous_mass < bound);
        println!(
            "solved {} levels, last eps {:?}, m_f {previous_mass}",
            levels.len(),
            levels.last().map(|l| l.eps)
        );
    }

    #[test]
    fn rendezvous_jacobian_matches_finite_differences_and_targets_the_moving_body() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let mut scenario = scenario();
        scenario.problem = ProblemKind::Rendezvous;
        scenario.target_nu0 = 1.2;
        let problem = RendezvousShooting {
            scenario: &scenario,
            spacecraft: sc,
        };
        // The body's arrival state is the Kepler coast of its departure state (independent check:
        // same orbit shape, energy and angular momentum).
        let body = problem.body_at_arrival().unwrap();
        let el = body.elements().unwrap();
        assert!((el.shape.a - scenario.target.a).abs() < 1e-12 && (el.shape.e - scenario.target.e).abs() < 1e-12);
        let tol = tight();
        let z = RendezvousVector::from_column_slice(&[0.3, -0.2, 0.5, -0.9, 0.1]);
        let (f, jac) = problem.residual(0.5, &z, &tol).unwrap();
        let h = 1e-6;
        for k in 0..RENDEZVOUS_UNKNOWNS {
            let (mut zp, mut zm) = (z, z);
            zp[k] += h;
            zm[k] -= h;
            let (fp, _) = problem.residual(0.5, &zp, &tol).unwrap();
            let (fm, _) = problem.residual(0.5, &zm, &tol).unwrap();
            for i in 0..RENDEZVOUS_UNKNOWNS {
                let fd = (fp[i] - fm[i]) / (2.0 * h);
                assert!(
                    (jac[(i, k)] - fd).abs() < 1e-5 * (1.0 + fd.abs()),
                    "dF{i}/dz{k}: {} vs {fd}",
                    jac[(i, k)]
                );
            }
        }
        // The position residual is measured against the body, not the orbit point of the
        // spacecraft's own anomaly: moving the body's phase changes it.
        let mut later = scenario;
        later.target_nu0 += 0.5;
        let (f_later, _) = RendezvousShooting {
            scenario: &later,
            spacecraft: sc,
        }
        .residual(0.5, &z, &tol)
        .unwrap();
        assert!((f_later[0] - f[0]).abs() + (f_later[1] - f[1]).abs() > 0.1);
    }

    #[test]
    fn residual_only_agrees_with_the_residual_of_the_sensitivity_propagation() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let tol = tight();
        let mut sce = scenario();
        let z = TransferVector::from_column_slice(&[0.3, -0.2, 0.5, -0.9, 0.1, 2.0]);
        let t = TransferShooting {
            scenario: &sce,
            spacecraft: sc,
        };
        let (f, _) = t.residual(0.3, &z, &tol).unwrap();
        assert!((t.residual_only(0.3, &z, &tol).unwrap() - f).amax() < 1e-9);
        sce.problem = ProblemKind::Rendezvous;
        let r = RendezvousShooting {
            scenario: &sce,
            spacecraft: sc,
        };
        let zr = RendezvousVector::from_column_slice(&[0.3, -0.2, 0.5, -0.9, 0.1]);
        let (f, _) = r.residual(0.3, &zr, &tol).unwrap();
        assert!((r.residual_only(0.3, &zr, &tol).unwrap() - f).amax() < 1e-9);
    }

    #[test]
    fn orbit_state_derivatives_match_the_polar_formulas() {
        let shape = OrbitShape {
            a: 1.3,
            e: 0.4,
            omega: 0.7,
        };
        for k in 0..10 {
            let nu = 0.6 * f64::from(k);
            let s = orbit_state(&shape, Dual2_64::from_re(nu).derivative());
            let c = shape.cartesian_at(nu);
            let direct = [c.r[0], c.r[1], c.v[0], c.v[1]];
            let h = 1e-5;
            let (p, m) = (orbit_state(&shape, nu + h), orbit_state(&shape, nu - h));
            for i in 0..4 {
                assert!((s[i].re - direct[i]).abs() < 1e-14);
                assert!((s[i].v1 - (p[i] - m[i]) / (2.0 * h)).abs() < 1e-9);
                // Second differences need a wider step against round-off.
                let h2 = 1e-4;
                let (p2, m2) = (orbit_state(&shape, nu + h2), orbit_state(&shape, nu - h2));
                let fd2 = (p2[i] - 2.0 * direct[i] + m2[i]) / (h2 * h2);
                assert!((s[i].v2 - fd2).abs() < 1e-6, "{} vs {fd2}", s[i].v2);
            }
        }
    }

    #[test]
    fn transfer_jacobian_matches_finite_differences() {
        let params = OptimalControlParams {
            spacecraft: Spacecraft::MSR_ERO.canonical().unwrap(),
            eps: 0.5,
        };
        let tol = tight();
        let z = TransferVector::from_column_slice(&[0.3, -0.2, 0.5, -0.9, 0.1, 2.0]);
        let (_, jac) = transfer_residual(&scenario(), &params, &z, &tol).unwrap();
        let h = 1e-6;
        for k in 0..TRANSFER_UNKNOWNS {
            let (mut zp, mut zm) = (z, z);
            zp[k] += h;
            zm[k] -= h;
            let (fp, _) = transfer_residual(&scenario(), &params, &zp, &tol).unwrap();
            let (fm, _) = transfer_residual(&scenario(), &params, &zm, &tol).unwrap();
            for i in 0..TRANSFER_UNKNOWNS {
                let fd = (fp[i] - fm[i]) / (2.0 * h);
                assert!(
                    (jac[(i, k)] - fd).abs() < 1e-5 * (1.0 + fd.abs()),
                    "dF{i}/dz{k}: {} vs {fd}",
                    jac[(i, k)]
                );
            }
        }
    }

    #[test]
    fn svd_step_is_the_minimum_norm_solution_and_can_drop_the_weakest_direction() {
        // Rank 2 in 3 unknowns: the null direction (1, -1, 0) / sqrt 2 gets no component.
        let jac = SMatrix::<f64, 3, 3>::new(1.0, 1.0, 0.0, 2.0, 2.0, 0.0, 0.0, 0.0, 3.0);
        let f = SVector::<f64, 3>::new(-1.0, -2.0, -3.0);
        let (step, condition) = svd_step(&jac, &f, RCOND, 0).unwrap();
        assert!(condition < 1e-15);
        assert!((jac * step + f).amax() < 1e-12, "consistent system solved: {step}");
        assert!((step[0] - step[1]).abs() < 1e-12, "no null-space component: {step}");
        // Invertible but ill-conditioned: dropping the weakest direction leaves it out.
        let jac = SMatrix::<f64, 2, 2>::new(1.0, 0.0, 0.0, 1e-6);
        let f = SVector::<f64, 2>::new(-1.0, -1.0);
        let (full, condition) = svd_step(&jac, &f, RCOND, 0).unwrap();
        assert!((condition - 1e-6).abs() < 1e-18 && (full[1] - 1e6).abs() < 1e-3);
        let (projected, _) = svd_step(&jac, &f, RCOND, 1).unwrap();
        assert!((projected[0] - 1.0).abs() < 1e-15 && projected[1] == 0.0);
    }
}
