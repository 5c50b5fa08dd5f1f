//! Multiple shooting of the transfer with a pinned final anomaly (see [`PinnedAnomalyTransfer`]):
//! the flight is cut into [`SEGMENTS`] equal segments, the state-costate at every inner node is an
//! unknown, and continuity at the nodes joins the terminal conditions.
//!
//! Why: near the final eps the smoothed throttle u = (1 + rho / eps) / 2 makes the flight's end
//! depend on the initial costates through 1/eps over every ramp arc, and single shooting then has
//! Jacobians of ~1e6 and Newton basins of ~1e-8 (transfer-circular). Cut into segments, each map
//! carries a fraction of that gain, and Newton converges from much farther away. The unknowns keep
//! the initial costates, so the solution is still a set of initial costates of docs/spec.md section 3; whether they
//! meet the terminal conditions when propagated alone is checked separately (the replay).
//!
//! [`PinnedAnomalyTransfer`]: super::shooting::PinnedAnomalyTransfer

use nalgebra::{SMatrix, SVector};
use num_dual::Dual2_64;
use onboard::integrator::{IntegrationError, Tolerances};
use shared::scenario::Scenario;
use shared::spacecraft::CanonicalSpacecraft;

use super::pontryagin::{idx, propagate, propagate_stm, OptimalControlParams, Y_LEN};
use super::shooting::{initial_state_costate, orbit_state, ShootingProblem};

/// Number of segments.
pub const SEGMENTS: usize = 6;
/// Unknowns: the initial costates and the state-costate at the inner nodes.
pub const MS_UNKNOWNS: usize = 5 + Y_LEN * (SEGMENTS - 1);
/// Multiple-shooting unknowns: lambda_0 (5), then the state-costate at each inner node (10 each).
pub type MsVector = SVector<f64, MS_UNKNOWNS>;
/// Jacobian of the multiple-shooting residual with respect to [`MsVector`].
pub type MsJacobian = SMatrix<f64, MS_UNKNOWNS, MS_UNKNOWNS>;

/// The pinned-anomaly transfer by multiple shooting. Residual rows: r, v - orbit(nu_f) (0..4),
/// lambda_m(tf) (4), then the continuity defects of the inner nodes, 10 per node.
#[derive(Debug, Clone, Copy)]
pub struct MultipleShootingTransfer<'a> {
    /// The transfer to solve.
    pub scenario: &'a Scenario,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
    /// Pinned final true anomaly on the target orbit (rad).
    pub nu_f: f64,
}

impl MultipleShootingTransfer<'_> {
    /// Node time k (0 ..= SEGMENTS).
    pub fn node(&self, k: usize) -> f64 {
        self.scenario.time_of_flight() * k as f64 / SEGMENTS as f64
    }

    fn params(&self, eps: f64) -> OptimalControlParams {
        OptimalControlParams {
            spacecraft: self.spacecraft,
            eps,
        }
    }

    /// The state-costate at the start of segment k.
    pub fn start(&self, k: usize, x: &MsVector) -> [f64; Y_LEN] {
        if k == 0 {
            initial_state_costate(self.scenario, &[x[0], x[1], x[2], x[3], x[4]])
        } else {
            let o = 5 + Y_LEN * (k - 1);
            core::array::from_fn(|i| x[o + i])
        }
    }

    /// The unknowns of a trajectory given by its state-costate at the nodes.
    pub fn unknowns_from(&self, state_at: impl Fn(f64) -> Option<[f64; Y_LEN]>) -> Option<MsVector> {
        let mut x = MsVector::zeros();
        let y0 = state_at(0.0)?;
        x.as_mut_slice()[..5].copy_from_slice(&y0[idx::LR..]);
        for k in 1..SEGMENTS {
            let y = state_at(self.node(k))?;
            let o = 5 + Y_LEN * (k - 1);
            x.as_mut_slice()[o..o + Y_LEN].copy_from_slice(&y);
        }
        Some(x)
    }

    /// The unknowns of the single-shooting trajectory from initial costates `lambda0` at `eps`.
    pub fn unknowns_from_costates(&self, lambda0: &[f64; 5], eps: f64, tol: &Tolerances) -> Option<MsVector> {
        let params = self.params(eps);
        let mut y = initial_state_costate(self.scenario, lambda0);
        let mut x = MsVector::zeros();
        x.as_mut_slice()[..5].copy_from_slice(lambda0);
        for k in 1..SEGMENTS {
            y = propagate(&params, self.node(k - 1), &y, self.node(k), tol).ok()?;
            let o = 5 + Y_LEN * (k - 1);
            x.as_mut_slice()[o..o + Y_LEN].copy_from_slice(&y);
        }
        Some(x)
    }

    fn terminal(&self, y: &[f64; Y_LEN], f: &mut MsVector) -> [Dual2_64; 4] {
        let orbit = orbit_state(&self.scenario.target, Dual2_64::from_re(self.nu_f).derivative());
        for i in 0..4 {
            f[i] = y[idx::R + i] - orbit[i].re;
        }
        f[4] = y[idx::LM];
        orbit
    }

    /// The final state-costate of the last segment.
    pub fn final_state(&self, eps: f64, x: &MsVector, tol: &Tolerances) -> Result<[f64; Y_LEN], IntegrationError> {
        let k = SEGMENTS - 1;
        propagate(
            &self.params(eps),
            self.node(k),
            &self.start(k, x),
            self.node(k + 1),
            tol,
        )
    }

    /// The transversality residual (the free problem's condition this one leaves out).
    pub fn transversality(&self, eps: f64, x: &MsVector, tol: &Tolerances) -> Result<f64, IntegrationError> {
        let y = self.final_state(eps, x, tol)?;
        let orbit = orbit_state(&self.scenario.target, Dual2_64::from_re(self.nu_f).derivative());
        Ok((0..4).map(|i| y[idx::LR + i] * orbit[i].v1).sum())
    }
}

/// The final state-costate and its transition matrix over the last segment.
type LastSegment = ([f64; Y_LEN], [[f64; Y_LEN]; Y_LEN]);

impl MultipleShootingTransfer<'_> {
    /// The residual and the final state-costate.
    fn residual_and_final(
        &self,
        eps: f64,
        x: &MsVector,
        tol: &Tolerances,
    ) -> Result<(MsVector, [f64; Y_LEN]), IntegrationError> {
        let params = self.params(eps);
        let mut f = MsVector::zeros();
        let mut last = [0.0; Y_LEN];
        for k in 0..SEGMENTS {
            let y = propagate(&params, self.node(k), &self.start(k, x), self.node(k + 1), tol)?;
            if k + 1 < SEGMENTS {
                let next = self.start(k + 1, x);
                let o = 5 + Y_LEN * k;
                for i in 0..Y_LEN {
                    f[o + i] = y[i] - next[i];
                }
            } else {
                self.terminal(&y, &mut f);
                last = y;
            }
        }
        Ok((f, last))
    }

    /// The residual, its Jacobian, and the last segment's final state-costate and transition
    /// matrix (the free-anomaly problem's transversality row needs them).
    fn residual_and_last(
        &self,
        eps: f64,
        x: &MsVector,
        tol: &Tolerances,
    ) -> Result<(MsVector, MsJacobian, LastSegment), IntegrationError> {
        let params = self.params(eps);
        let mut f = MsVector::zeros();
        let mut jac = MsJacobian::zeros();
        let mut last = ([0.0; Y_LEN], [[0.0; Y_LEN]; Y_LEN]);
        for k in 0..SEGMENTS {
            let (y, stm) = propagate_stm(&params, self.node(k), &self.start(k, x), self.node(k + 1), tol)?;
            // Columns of this segment's start: the costates (k = 0) or the whole node.
            let columns: Vec<(usize, usize)> = if k == 0 {
                (0..5).map(|j| (j, idx::LR + j)).collect()
            } else {
                let o = 5 + Y_LEN * (k - 1);
                (0..Y_LEN).map(|j| (o + j, j)).collect()
            };
            if k + 1 < SEGMENTS {
                let next = self.start(k + 1, x);
                let o = 5 + Y_LEN * k;
                for i in 0..Y_LEN {
                    f[o + i] = y[i] - next[i];
                    for &(col, j) in &columns {
                        jac[(o + i, col)] = stm[i][j];
                    }
                    jac[(o + i, o + i)] = -1.0;
                }
            } else {
                self.terminal(&y, &mut f);
                let rows = [idx::R, idx::R + 1, idx::V, idx::V + 1, idx::LM];
                for (r, &i) in rows.iter().enumerate() {
                    for &(col, j) in &columns {
                        jac[(r, col)] = stm[i][j];
                    }
                }
                last = (y, stm);
            }
        }
        Ok((f, jac, last))
    }
}

impl ShootingProblem<MS_UNKNOWNS> for MultipleShootingTransfer<'_> {
    fn residual_only(&self, eps: f64, x: &MsVector, tol: &Tolerances) -> Result<MsVector, IntegrationError> {
        self.residual_and_final(eps, x, tol).map(|(f, _)| f)
    }

    fn residual(&self, eps: f64, x: &MsVector, tol: &Tolerances) -> Result<(MsVector, MsJacobian), IntegrationError> {
        self.residual_and_last(eps, x, tol).map(|(f, j, _)| (f, j))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::scenario::ScenarioKind;
    use shared::spacecraft::Spacecraft;

    /// The multiple-shooting Jacobian against central differences, at an eps where the flight
    /// switches between the throttle branches.
    #[test]
    fn multiple_shooting_jacobian_matches_finite_differences() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let scenario = ScenarioKind::TransferCircular.draw(7, 0);
        let problem = MultipleShootingTransfer {
            scenario: &scenario,
            spacecraft: sc,
            nu_f: 11.8,
        };
        let tol = Tolerances {
            relative: 1e-12,
            absolute: 1e-13,
            ..Tolerances::default()
        };
        let c = scenario.initial.cartesian();
        let lambda0 = [0.096, 0.638, -0.719, 0.103, 0.067];
        let _ = c;
        let eps = 0.05;
        let x = problem.unknowns_from_costates(&lambda0, eps, &tol).unwrap();
        // Perturb the nodes so that the defects are not zero.
        let x = x + MsVector::from_fn(|i, _| 1e-4 * ((i as f64) * 0.7).sin());
        let (_, jac) = problem.residual(eps, &x, &tol).unwrap();
        let h = 1e-6;
        for k in 0..MS_UNKNOWNS {
            let (mut xp, mut xm) = (x, x);
            xp[k] += h;
            xm[k] -= h;
            let fp = problem.residual_only(eps, &xp, &tol).unwrap();
            let fm = problem.residual_only(eps, &xm, &tol).unwrap();
            for i in 0..MS_UNKNOWNS {
                let fd = (fp[i] - fm[i]) / (2.0 * h);
                assert!(
                    (jac[(i, k)] - fd).abs() < 1e-5 * (1.0 + fd.abs()),
                    "dF{i}/dx{k}: {} vs {fd}",
                    jac[(i, k)]
                );
            }
        }
    }

    /// The free-anomaly Jacobian (its transversality row and nu_f column built from the last
    /// segment's transition matrix and the orbit's derivatives) against central differences of
    /// its residual, and that residual's rows against the pinned problem's.
    #[test]
    fn free_anomaly_jacobian_matches_finite_differences() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let scenario = ScenarioKind::TransferCircular.draw(7, 0);
        let tol = Tolerances {
            relative: 1e-12,
            absolute: 1e-13,
            ..Tolerances::default()
        };
        let eps = 0.05;
        let nu = 11.8;
        let pinned = MultipleShootingTransfer {
            scenario: &scenario,
            spacecraft: sc,
            nu_f: nu,
        };
        let lambda0 = [0.096, 0.638, -0.719, 0.103, 0.067];
        let x = pinned.unknowns_from_costates(&lambda0, eps, &tol).unwrap();
        let x = x + MsVector::from_fn(|i, _| 1e-4 * ((i as f64) * 0.3).cos());
        let free = MultipleShootingFree {
            scenario: &scenario,
            spacecraft: sc,
        };
        let z = MultipleShootingFree::join(&x, nu);
        let (f, jac) = free.residual(eps, &z, &tol).unwrap();
        let f_only = free.residual_only(eps, &z, &tol).unwrap();
        let f_pinned = pinned.residual_only(eps, &x, &tol).unwrap();
        let t = pinned.transversality(eps, &x, &tol).unwrap();
        assert!((f - f_only).amax() < 1e-9, "{}", (f - f_only).amax());
        for i in 0..MS_UNKNOWNS {
            assert!((f[i] - f_pinned[i]).abs() < 1e-9, "row {i}");
        }
        assert!((f[MS_UNKNOWNS] - t).abs() < 1e-9);
        let h = 1e-6;
        for k in 0..MS_FREE_UNKNOWNS {
            let (mut zp, mut zm) = (z, z);
            zp[k] += h;
            zm[k] -= h;
            let fd =
                (free.residual_only(eps, &zp, &tol).unwrap() - free.residual_only(eps, &zm, &tol).unwrap()) / (2.0 * h);
            for i in 0..MS_FREE_UNKNOWNS {
                assert!(
                    (jac[(i, k)] - fd[i]).abs() < 1e-5 * (1.0 + fd[i].abs()),
                    "dF{i}/dz{k}: {} vs {}",
                    jac[(i, k)],
                    fd[i]
                );
            }
        }
    }
}

/// Unknowns of the free-anomaly multiple shooting: [`MS_UNKNOWNS`] and nu_f last.
pub const MS_FREE_UNKNOWNS: usize = MS_UNKNOWNS + 1;
/// Free-anomaly multiple-shooting unknowns: [`MsVector`]'s, then nu_f (rad).
pub type MsFreeVector = SVector<f64, MS_FREE_UNKNOWNS>;

/// The free-anomaly transfer by multiple shooting: [`MultipleShootingTransfer`]'s unknowns plus
/// nu_f, its residual plus the transversality condition (last row).
#[derive(Debug, Clone, Copy)]
pub struct MultipleShootingFree<'a> {
    /// The transfer to solve.
    pub scenario: &'a Scenario,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
}

impl MultipleShootingFree<'_> {
    fn pinned(&self, nu: f64) -> MultipleShootingTransfer<'_> {
        MultipleShootingTransfer {
            scenario: self.scenario,
            spacecraft: self.spacecraft,
            nu_f: nu,
        }
    }

    fn split(x: &MsFreeVector) -> (MsVector, f64) {
        (
            MsVector::from_column_slice(&x.as_slice()[..MS_UNKNOWNS]),
            x[MS_UNKNOWNS],
        )
    }

    /// Joins pinned unknowns and nu_f.
    pub fn join(x: &MsVector, nu: f64) -> MsFreeVector {
        let mut v = MsFreeVector::zeros();
        v.as_mut_slice()[..MS_UNKNOWNS].copy_from_slice(x.as_slice());
        v[MS_UNKNOWNS] = nu;
        v
    }
}

impl ShootingProblem<MS_FREE_UNKNOWNS> for MultipleShootingFree<'_> {
    fn residual_only(&self, eps: f64, x: &MsFreeVector, tol: &Tolerances) -> Result<MsFreeVector, IntegrationError> {
        let (xp, nu) = Self::split(x);
        let p = self.pinned(nu);
        let (f, y) = p.residual_and_final(eps, &xp, tol)?;
        let orbit = orbit_state(&self.scenario.target, Dual2_64::from_re(nu).derivative());
        let mut out = MsFreeVector::zeros();
        out.as_mut_slice()[..MS_UNKNOWNS].copy_from_slice(f.as_slice());
        out[MS_UNKNOWNS] = (0..4).map(|i| y[idx::LR + i] * orbit[i].v1).sum();
        Ok(out)
    }

    fn residual(
        &self,
        eps: f64,
        x: &MsFreeVector,
        tol: &Tolerances,
    ) -> Result<(MsFreeVector, SMatrix<f64, MS_FREE_UNKNOWNS, MS_FREE_UNKNOWNS>), IntegrationError> {
        let (xp, nu) = Self::split(x);
        let p = self.pinned(nu);
        let (f, jac, (y, stm)) = p.residual_and_last(eps, &xp, tol)?;
        let k = SEGMENTS - 1;
        let orbit = orbit_state(&self.scenario.target, Dual2_64::from_re(nu).derivative());
        let mut out = MsFreeVector::zeros();
        out.as_mut_slice()[..MS_UNKNOWNS].copy_from_slice(f.as_slice());
        out[MS_UNKNOWNS] = (0..4).map(|i| y[idx::LR + i] * orbit[i].v1).sum();
        let mut j = SMatrix::<f64, MS_FREE_UNKNOWNS, MS_FREE_UNKNOWNS>::zeros();
        j.view_mut((0, 0), (MS_UNKNOWNS, MS_UNKNOWNS)).copy_from(&jac);
        for i in 0..4 {
            j[(i, MS_UNKNOWNS)] = -orbit[i].v1;
        }
        let o = 5 + Y_LEN * (k - 1);
        for jj in 0..Y_LEN {
            j[(MS_UNKNOWNS, o + jj)] = (0..4).map(|i| stm[idx::LR + i][jj] * orbit[i].v1).sum();
        }
        j[(MS_UNKNOWNS, MS_UNKNOWNS)] = (0..4).map(|i| y[idx::LR + i] * orbit[i].v2).sum();
        Ok((out, j))
    }
}
