//! The energy-to-fuel homotopy in eps (docs/spec.md section 3): the schedule down to
//! [`FINAL_EPS`], the tangent predictor with its curvature correction, and the continuation
//! with a Newton corrector.

use nalgebra::{Const, DimMin, SMatrix, SVector};
use onboard::integrator::{IntegrationError, Tolerances};
use shared::scenario::Scenario;
use shared::spacecraft::CanonicalSpacecraft;

use super::newton::{newton, NewtonOutcome, NewtonSettings};
use super::problem::{ShootingProblem, TransferShooting, TransferVector, TRANSFER_UNKNOWNS};

/// One level of the energy-to-fuel homotopy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HomotopyLevel<const K: usize = TRANSFER_UNKNOWNS> {
    /// Homotopy parameter of this level.
    pub eps: f64,
    /// Where the Newton corrector ended at `eps`.
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
/// difference in eps (the propagations are smooth in eps for eps > 0). `jacobian`: J at (eps,
/// z) when the corrector that found z already has it, computed otherwise.
pub fn homotopy_tangent<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    z: &SVector<f64, K>,
    eps: f64,
    jacobian: Option<&SMatrix<f64, K, K>>,
    tolerances: &Tolerances,
) -> Result<Option<SVector<f64, K>>, IntegrationError>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    // Not smaller: the propagations carry ~1e-11 of round-off (see pontryagin::TIME_OFFSET).
    let h = eps * 1e-3;
    let jac = match jacobian {
        Some(j) => *j,
        None => problem.residual(eps, z, tolerances)?.1,
    };
    let fp = problem.residual_only(eps + h, z, tolerances)?;
    let fm = problem.residual_only(eps - h, z, tolerances)?;
    let df_de = (fp - fm) / (2.0 * h);
    Ok(jac.lu().solve(&(-df_de)))
}

/// The predicted solution at `next` from the solution `z` at `eps` (with its Jacobian when known,
/// see [`homotopy_tangent`]): the tangent step, plus the
/// quadratic term that makes the prediction pass through the previous solution `previous`
/// (at another eps) when there is one. Near eps -> 0 the path bends on the scale of eps itself
/// (the throttle ramps narrow like eps), and Newton's basin shrinks with it, so the curvature term
/// is what lets the corrector converge at the schedule's step.
pub fn predict<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    z: &SVector<f64, K>,
    jacobian: Option<&SMatrix<f64, K, K>>,
    eps: f64,
    next: f64,
    previous: Option<(f64, SVector<f64, K>)>,
    tolerances: &Tolerances,
) -> SVector<f64, K>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    let Ok(Some(t)) = homotopy_tangent(problem, z, eps, jacobian, tolerances) else {
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
    let mut jacobian = None;
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
        let predicted = predict(problem, &z, jacobian.as_ref(), eps, next, previous, tolerances);
        let step = newton(problem, next, &predicted, tolerances, settings);
        match step {
            Ok(o) if o.converged => {
                previous = Some((eps, z));
                (eps, z, jacobian) = (next, o.z, o.jacobian);
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
    let (mut eps, mut z, mut jacobian) = (first, outcome.z, outcome.jacobian);
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
            let predicted = predict(problem, &z, jacobian.as_ref(), eps, next, previous, tolerances);
            // A propagation that fails from a predicted point is a failed corrector, not an error.
            let step = newton(problem, next, &predicted, tolerances, settings).unwrap_or(NewtonOutcome {
                z: predicted,
                residual: f64::INFINITY,
                iterations: 0,
                converged: false,
                jacobian: None,
            });
            if step.converged {
                previous = Some((eps, z));
                (eps, z, jacobian, last) = (next, step.z, step.jacobian, step);
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

#[cfg(test)]
mod tests {
    use super::*;
    use onboard::integrator::integrate;
    use shared::spacecraft::Spacecraft;

    use super::super::fixtures::{circular_scenario, hohmann_mass_bound, tight};
    use super::super::problem::initial_state_costate;
    use crate::solver::pontryagin::{idx, OptimalControlParams};

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
            let system = crate::solver::pontryagin::StateCostate(params);
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
}
