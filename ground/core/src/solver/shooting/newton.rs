//! Damped Newton on a shooting problem: minimum-norm Gauss-Newton steps with backtracking, a
//! look-ahead step across a newborn throttle sub-arc, a valley step for ill-conditioned
//! Jacobians, and a Levenberg-Marquardt fallback.

use nalgebra::{Const, DMatrix, DVector, DimMin, SMatrix, SVector};
use onboard::integrator::{IntegrationError, Tolerances};
use shared::scenario::Scenario;

use super::problem::{ShootingProblem, TransferShooting, TransferVector, TRANSFER_UNKNOWNS};
use crate::solver::pontryagin::OptimalControlParams;

/// Settings of the Newton iteration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonSettings {
    /// Iterations before giving up.
    pub max_iterations: u32,
    /// Converged when every terminal condition holds to this (canonical units).
    pub tolerance: f64,
    /// Give up on an iteration that is going nowhere (see [`Progress`]); `None` never does.
    pub progress: Option<Progress>,
}

/// Required progress: the residual's 2-norm must fall below `factor` times its value `window`
/// iterations earlier. For a multi-start, where most guesses never converge and plateau on a
/// local minimum of |F| while the ones that converge rarely stay flat that long.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress {
    /// Number of iterations looked back.
    pub window: u32,
    /// Required reduction over the window, in (0, 1).
    pub factor: f64,
}

impl Default for NewtonSettings {
    fn default() -> Self {
        Self {
            max_iterations: 60,
            tolerance: 1e-8,
            progress: None,
        }
    }
}

/// Where an iteration ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonOutcome<const K: usize = TRANSFER_UNKNOWNS> {
    /// The last iterate.
    pub z: SVector<f64, K>,
    /// Largest terminal-condition residual at `z` (canonical, max norm).
    pub residual: f64,
    /// Iterations done.
    pub iterations: u32,
    /// Whether `residual` is within the tolerance.
    pub converged: bool,
    /// The Jacobian at `z`, as the iteration computed it (the homotopy's tangent reuses it).
    pub jacobian: Option<SMatrix<f64, K, K>>,
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
    let mut norms: Vec<f64> = Vec::new();
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
                jacobian: Some(jac),
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
        if let Some(Progress { window, factor }) = settings.progress {
            let window = window as usize;
            if norms.len() >= window && norm > factor * norms[norms.len() - window] {
                break;
            }
            norms.push(norm);
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
        jacobian: Some(jac),
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

#[cfg(test)]
mod tests {
    use super::*;
    use onboard::integrator::integrate;
    use shared::spacecraft::Spacecraft;

    use super::super::fixtures::{circular_scenario, hohmann_mass_bound, tight};
    use super::super::problem::{initial_state_costate, transfer_residual};
    use crate::solver::pontryagin::idx;

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
            progress: None,
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

    /// With a required progress, Newton on the problem without a root stops once |F| has
    /// stopped falling by the factor over the window (|F| creeps towards 1e-2), far below the
    /// iteration cap it runs to without one.
    #[test]
    fn newton_gives_up_when_the_residual_stops_falling_over_the_window() {
        let settings = NewtonSettings {
            max_iterations: 40,
            tolerance: 1e-12,
            progress: Some(Progress { window: 4, factor: 0.8 }),
        };
        let z0 = SVector::<f64, 2>::new(1.0, 1.0);
        let out = newton(&NoRoot { stall: u32::MAX }, 0.0, &z0, &tight(), &settings).unwrap();
        assert!(!out.converged);
        // z0 halves per step: |F| falls by more than 0.8 per 4 steps while z0^2 is above ~1e-3,
        // then creeps; 9 iterations by hand.
        assert!((6..12).contains(&out.iterations), "{}", out.iterations);
        assert!((out.residual - 1e-2).abs() < 1e-3, "{}", out.residual);
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
        let (f, jacobian) = transfer_residual(&scenario, &params, &out.z, &tol).unwrap();
        assert!(f.amax() < 1e-8);
        // The Jacobian handed on (to the homotopy's tangent) is the one at the solution.
        assert_eq!(out.jacobian, Some(jacobian));
        let y0 = initial_state_costate(&scenario, &[out.z[0], out.z[1], out.z[2], out.z[3], out.z[4]]);
        let (yf, _) = integrate(
            &crate::solver::pontryagin::StateCostate(params),
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
