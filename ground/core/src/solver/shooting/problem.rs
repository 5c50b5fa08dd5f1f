//! The shooting problems: the unknowns and terminal conditions of the transfer (free or pinned
//! final anomaly) and of the rendezvous, their residuals and exact Jacobians.

use nalgebra::{SMatrix, SVector};
use num_dual::{Dual2_64, DualNum};
use onboard::integrator::{IntegrationError, Tolerances};
use onboard::kepler::coast;
use shared::orbit::{CartesianState, OrbitShape};
use shared::scenario::Scenario;
use shared::spacecraft::CanonicalSpacecraft;

use crate::solver::pontryagin::{
    idx, propagate, propagate_sensitivity, OptimalControlParams, StateCostateSensitivity, Y_LEN,
};

/// Transfer unknowns: the five initial costates and the final true anomaly nu_f.
pub const TRANSFER_UNKNOWNS: usize = 6;
/// Transfer unknowns (lambda_r, lambda_v, lambda_m at t = 0, nu_f), canonical and rad.
pub type TransferVector = SVector<f64, TRANSFER_UNKNOWNS>;
/// Jacobian of the transfer residual with respect to [`TransferVector`].
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

    /// The residual F(z) at homotopy parameter `eps` and its Jacobian dF/dz.
    fn residual(
        &self,
        eps: f64,
        z: &SVector<f64, K>,
        tolerances: &Tolerances,
    ) -> Result<(SVector<f64, K>, SMatrix<f64, K, K>), IntegrationError>;

    /// [`newton`](super::newton) gives up after this many consecutive iterations that each reduced the residual
    /// (2-norm) by less than half; by default it never does.
    fn stall_limit(&self) -> u32 {
        u32::MAX
    }
}

/// The free-anomaly transfer (6 unknowns: lambda_0 and nu_f).
#[derive(Debug, Clone, Copy)]
pub struct TransferShooting<'a> {
    /// The transfer to solve.
    pub scenario: &'a Scenario,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
}

impl ShootingProblem<TRANSFER_UNKNOWNS> for TransferShooting<'_> {
    fn residual_only(
        &self,
        eps: f64,
        z: &TransferVector,
        tolerances: &Tolerances,
    ) -> Result<TransferVector, IntegrationError> {
        transfer_residual_only(
            self.scenario,
            &OptimalControlParams {
                spacecraft: self.spacecraft,
                eps,
            },
            z,
            tolerances,
        )
    }

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
    /// The transfer to solve.
    pub scenario: &'a Scenario,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
    /// Pinned final true anomaly on the target orbit (rad).
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

/// Rendezvous unknowns: the five initial costates.
pub const RENDEZVOUS_UNKNOWNS: usize = 5;
/// Rendezvous unknowns: lambda_r, lambda_v, lambda_m at t = 0, canonical.
pub type RendezvousVector = SVector<f64, RENDEZVOUS_UNKNOWNS>;

/// The rendezvous (docs/spec.md section 3, TBR): r(tf), v(tf) equal the body's state, lambda_m(tf) = 0.
/// The body moves on its Keplerian orbit from anomaly nu_f0 at t = 0.
#[derive(Debug, Clone, Copy)]
pub struct RendezvousShooting<'a> {
    /// The rendezvous to solve.
    pub scenario: &'a Scenario,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
}

impl<'a> RendezvousShooting<'a> {
    /// The body's state at the end of the flight.
    pub fn body_at_arrival(&self) -> Result<CartesianState, IntegrationError> {
        self.at_own_time().body_at_arrival()
    }

    fn at_own_time(&self) -> RendezvousAtTime<'a> {
        RendezvousAtTime {
            scenario: self.scenario,
            spacecraft: self.spacecraft,
            time_of_flight: self.scenario.time_of_flight(),
        }
    }
}

impl ShootingProblem<RENDEZVOUS_UNKNOWNS> for RendezvousShooting<'_> {
    fn residual_only(
        &self,
        eps: f64,
        z: &RendezvousVector,
        tolerances: &Tolerances,
    ) -> Result<RendezvousVector, IntegrationError> {
        self.at_own_time().residual_only(eps, z, tolerances)
    }

    fn residual(
        &self,
        eps: f64,
        z: &RendezvousVector,
        tolerances: &Tolerances,
    ) -> Result<(RendezvousVector, SMatrix<f64, RENDEZVOUS_UNKNOWNS, RENDEZVOUS_UNKNOWNS>), IntegrationError> {
        self.at_own_time().residual(eps, z, tolerances)
    }
}

/// [`RendezvousShooting`] at a time of flight other than the scenario's own (the minimum-time
/// search's continuation in the time of flight): the body is met where it is at that time.
#[derive(Debug, Clone, Copy)]
pub struct RendezvousAtTime<'a> {
    /// The rendezvous to solve.
    pub scenario: &'a Scenario,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
    /// Time of flight to solve at (t*).
    pub time_of_flight: f64,
}

impl RendezvousAtTime<'_> {
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
        body_at(self.scenario, self.time_of_flight)
    }

    fn params(&self, eps: f64) -> OptimalControlParams {
        OptimalControlParams {
            spacecraft: self.spacecraft,
            eps,
        }
    }
}

/// The rendezvous body's state at time t (its Keplerian coast from anomaly nu_f0 at t = 0).
pub fn body_at(scenario: &Scenario, t: f64) -> Result<CartesianState, IntegrationError> {
    let start = scenario.target.cartesian_at(scenario.target_nu0);
    coast(&start, t).map_err(|_| IntegrationError::InvalidInput)
}

impl ShootingProblem<RENDEZVOUS_UNKNOWNS> for RendezvousAtTime<'_> {
    fn residual_only(
        &self,
        eps: f64,
        z: &RendezvousVector,
        tolerances: &Tolerances,
    ) -> Result<RendezvousVector, IntegrationError> {
        let y0 = initial_state_costate(self.scenario, &[z[0], z[1], z[2], z[3], z[4]]);
        let y = propagate(&self.params(eps), 0.0, &y0, self.time_of_flight, tolerances)?;
        self.terminal(&y)
    }

    fn residual(
        &self,
        eps: f64,
        z: &RendezvousVector,
        tolerances: &Tolerances,
    ) -> Result<(RendezvousVector, SMatrix<f64, RENDEZVOUS_UNKNOWNS, RENDEZVOUS_UNKNOWNS>), IntegrationError> {
        let y0 = initial_state_costate(self.scenario, &[z[0], z[1], z[2], z[3], z[4]]);
        let ys = propagate_sensitivity(&self.params(eps), &y0, self.time_of_flight, tolerances)?;
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
    use shared::orbit::OrbitElements;
    use shared::scenario::ProblemKind;
    use shared::spacecraft::Spacecraft;

    use super::super::fixtures::tight;
    use crate::solver::pontryagin::work_done;

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
            cycle: shared::units::STEP,
        }
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
        let before = work_done();
        let (f, _) = t.residual(0.3, &z, &tol).unwrap();
        let sensitivity_work = work_done() - before;
        let before = work_done();
        assert!((t.residual_only(0.3, &z, &tol).unwrap() - f).amax() < 1e-9);
        let plain_work = work_done() - before;
        // Line-search trials and eps differences rely on F alone being the cheap 10-state
        // propagation, not the sensitivity one with its Jacobian thrown away.
        assert!(
            plain_work * 3 < sensitivity_work,
            "F alone cost {plain_work}, F and J {sensitivity_work}"
        );
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
}
