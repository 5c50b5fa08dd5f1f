//! Single shooting for the free-anomaly transfer (SPEC section 3): the residual of the terminal
//! conditions and its exact Jacobian, and a damped Newton iteration on them.

use nalgebra::{SMatrix, SVector};
use num_dual::{Dual2_64, DualNum};
use onboard::integrator::{integrate, IntegrationError, Tolerances};
use shared::orbit::OrbitShape;
use shared::scenario::Scenario;

use super::pontryagin::{idx, OptimalControlParams, StateCostateSensitivity, Y_LEN};

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

/// Terminal residual F(z) of a transfer and its Jacobian dF/dz.
pub fn transfer_residual(
    scenario: &Scenario,
    params: &OptimalControlParams,
    z: &TransferVector,
    tolerances: &Tolerances,
) -> Result<(TransferVector, TransferJacobian), IntegrationError> {
    let lambda0 = [z[0], z[1], z[2], z[3], z[4]];
    let y0 = initial_state_costate(scenario, &lambda0);
    let system = StateCostateSensitivity(*params);
    let (ys, _) = integrate(
        &system,
        0.0,
        &StateCostateSensitivity::initial(&y0),
        scenario.time_of_flight(),
        tolerances,
    )?;
    let nu_f = z[5];
    let orbit = orbit_state(&scenario.target, Dual2_64::from_re(nu_f).derivative());
    let lambda_rv = [ys[idx::LR], ys[idx::LR + 1], ys[idx::LV], ys[idx::LV + 1]];
    let mut f = TransferVector::zeros();
    let mut jac = TransferJacobian::zeros();
    for i in 0..4 {
        f[i] = ys[idx::R + i] - orbit[i].re;
    }
    f[4] = (0..4).map(|i| lambda_rv[i] * orbit[i].v1).sum();
    f[5] = ys[idx::LM];
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
    jac[(4, 5)] = (0..4).map(|i| lambda_rv[i] * orbit[i].v2).sum();
    Ok((f, jac))
}

/// Settings of the Levenberg-Marquardt iteration.
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
pub struct NewtonOutcome {
    pub z: TransferVector,
    pub residual: f64,
    pub iterations: u32,
    pub converged: bool,
}

/// Levenberg-Marquardt on the transfer residual: Gauss-Newton steps (JtJ + mu D) dz = -Jt F with
/// Nielsen's damping update, which falls back to gradient-like steps far from a root and is
/// Newton's method near one. A failed propagation counts as a rejected step.
pub fn solve_transfer(
    scenario: &Scenario,
    params: &OptimalControlParams,
    z0: &TransferVector,
    tolerances: &Tolerances,
    settings: &NewtonSettings,
) -> Result<NewtonOutcome, IntegrationError> {
    let mut z = *z0;
    let (mut f, mut jac) = transfer_residual(scenario, params, &z, tolerances)?;
    let mut mu = 1e-6;
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
        iterations += 1;
        let jtj = jac.transpose() * jac;
        let g = jac.transpose() * f;
        let mut a = jtj;
        for i in 0..TRANSFER_UNKNOWNS {
            a[(i, i)] += mu * jtj[(i, i)].max(1e-12);
        }
        let Some(step) = a.lu().solve(&(-g)) else {
            mu *= nu;
            nu *= 2.0;
            continue;
        };
        let trial = z + step;
        let predicted = f.norm_squared() - (f + jac * step).norm_squared();
        match transfer_residual(scenario, params, &trial, tolerances) {
            Ok((ft, jt)) if ft.norm_squared() < f.norm_squared() => {
                let gain = (f.norm_squared() - ft.norm_squared()) / predicted.max(1e-300);
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

/// One level of the energy-to-fuel homotopy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HomotopyLevel {
    pub eps: f64,
    pub outcome: NewtonOutcome,
}

/// The homotopy schedule of SPEC section 3: eps = 1, halving, last level the first below 1e-4.
pub fn homotopy_schedule() -> impl Iterator<Item = f64> {
    core::iter::successors(Some(1.0f64), |&e| (e >= 1e-4).then_some(e * 0.5))
}

/// Solves the transfer along the homotopy, each level warm-started from the previous one.
/// A level that does not converge from there is approached through intermediate eps values
/// (geometric means, up to `MAX_SUBDIVISIONS` halvings of the log-step). Stops at the first
/// level that cannot be reached; the levels solved so far are returned.
pub fn solve_transfer_homotopy(
    scenario: &Scenario,
    spacecraft: &shared::spacecraft::CanonicalSpacecraft,
    z0: &TransferVector,
    tolerances: &Tolerances,
    settings: &NewtonSettings,
) -> Result<Vec<HomotopyLevel>, IntegrationError> {
    const MAX_SUBDIVISIONS: u32 = 6;
    let solve_at = |eps: f64, z: &TransferVector| {
        solve_transfer(
            scenario,
            &OptimalControlParams {
                spacecraft: *spacecraft,
                eps,
            },
            z,
            tolerances,
            settings,
        )
    };
    let mut z = *z0;
    let mut solved_eps: Option<f64> = None;
    let mut levels = Vec::new();
    for eps in homotopy_schedule() {
        let mut outcome = solve_at(eps, &z)?;
        if let (false, Some(from)) = (outcome.converged, solved_eps) {
            // Walk from the last solved eps towards this level in smaller log-steps.
            let (mut at, mut z_at, mut ratio, mut halvings) = (from, z, eps / from, 0);
            while at > eps && halvings <= MAX_SUBDIVISIONS {
                let next = (at * ratio).max(eps);
                let step = solve_at(next, &z_at)?;
                if step.converged {
                    (at, z_at) = (next, step.z);
                    outcome = step;
                } else {
                    ratio = ratio.sqrt();
                    halvings += 1;
                }
            }
            if at > eps {
                outcome.converged = false;
            }
        }
        levels.push(HomotopyLevel { eps, outcome });
        if !outcome.converged {
            break;
        }
        z = outcome.z;
        solved_eps = Some(eps);
    }
    Ok(levels)
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::orbit::OrbitElements;
    use shared::scenario::ProblemKind;
    use shared::spacecraft::Spacecraft;

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
        let steps = Scenario::steps_for(&initial.shape, &target);
        Scenario {
            problem: ProblemKind::Transfer,
            initial,
            target,
            target_nu0: 0.0,
            steps,
        }
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
        let (r1, r2) = (1.0f64, 1.3f64);
        let dv_hohmann = (1.0 / r1).sqrt() * ((2.0 * r2 / (r1 + r2)).sqrt() - 1.0)
            + (1.0 / r2).sqrt() * (1.0 - (2.0 * r1 / (r1 + r2)).sqrt());
        let bound = (-dv_hohmann / sc.exhaust_speed).exp();
        assert!(
            yf[idx::M] < bound && yf[idx::M] > 0.8,
            "m_f {} vs Hohmann bound {bound}",
            yf[idx::M]
        );
    }

    /// What the homotopy reaches today: the first levels, with fuel use falling monotonically.
    /// Deeper levels (eps <= 1/64 on this case) stall at a residual floor near 1e-8 and are the
    /// next piece of work (issue 3); when they converge this test should demand all 15 levels.
    #[test]
    fn homotopy_levels_converge_with_monotone_fuel_use() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let tol = Tolerances {
            relative: 1e-12,
            absolute: 1e-13,
            ..Tolerances::default()
        };
        let scenario = circular_scenario(1.0, 1.3);
        let z0 = TransferVector::from_column_slice(&[-0.3, 0.0, 0.0, -0.3, 0.05, 7.5]);
        let levels = solve_transfer_homotopy(&scenario, &sc, &z0, &tol, &NewtonSettings::default()).unwrap();
        let schedule: Vec<f64> = homotopy_schedule().collect();
        assert_eq!(schedule.len(), 15);
        assert!(schedule[14] < 1e-4 && schedule[13] >= 1e-4);
        let solved: Vec<&HomotopyLevel> = levels.iter().filter(|l| l.outcome.converged).collect();
        assert!(solved.len() >= 6, "only {} levels solved", solved.len());
        let mut previous_mass = 0.0;
        for level in solved {
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
        let (r1, r2) = (1.0f64, 1.3f64);
        let dv_hohmann = (1.0 / r1).sqrt() * ((2.0 * r2 / (r1 + r2)).sqrt() - 1.0)
            + (1.0 / r2).sqrt() * (1.0 - (2.0 * r1 / (r1 + r2)).sqrt());
        assert!(previous_mass < (-dv_hohmann / sc.exhaust_speed).exp());
        println!(
            "solved {} levels, last eps {:?}, m_f {previous_mass}",
            levels.len(),
            levels.last().map(|l| l.eps)
        );
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
        let tol = Tolerances {
            relative: 1e-12,
            absolute: 1e-13,
            ..Tolerances::default()
        };
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
}
