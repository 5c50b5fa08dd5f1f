//! The transfer in three dimensions: reach a target orbit, given by its shape and orientation,
//! anywhere on it (docs/spec.md section 3.6). Unknowns: the seven initial costates and the final
//! true anomaly; conditions: r(tf), v(tf) on the orbit at that anomaly (6), transversality
//! lambda_r . dr/dnu + lambda_v . dv/dnu = 0 (1) and lambda_m(tf) = 0 (1).

use nalgebra::{SMatrix, SVector};
use num_dual::{Dual2_64, DualNum};
use onboard::integrator::{IntegrationError, Tolerances};
use shared::orbit::{cross3, dot3, OrbitPlane, OrbitShape, SpatialState};
use shared::scenario::{ProblemKind, Scenario, SpatialScenario};
use shared::spacecraft::CanonicalSpacecraft;

use super::{
    costate_guesses, departure_frame, from_frame, idx3, initial_state_costate3, propagate3, propagate_sensitivity3,
    to_frame, SpatialShooting, SpatialSolveError, SpatialVector, FLAT_CYCLES, Y3_LEN,
};
use crate::solver::shooting::{ShootingProblem, TransferVector};
use crate::solver::SolveOptions;

/// Unknowns of the spatial transfer: the seven initial costates and the final true anomaly.
pub const SPATIAL_TRANSFER_UNKNOWNS: usize = 8;
/// The spatial transfer's unknowns (lambda_r, lambda_v, lambda_m at t = 0, nu_f).
pub type SpatialTransferVector = SVector<f64, SPATIAL_TRANSFER_UNKNOWNS>;

/// A closed orbit in three dimensions: semi-major axis (canonical), eccentricity, inclination,
/// right ascension of the ascending node and argument of periapsis (rad), in the inertial frame
/// of the central body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpatialOrbitShape {
    /// Semi-major axis.
    pub a: f64,
    /// Eccentricity, in [0, 1).
    pub e: f64,
    /// Inclination to the xy-plane (rad).
    pub inclination: f64,
    /// Right ascension of the ascending node (rad).
    pub raan: f64,
    /// Argument of periapsis (rad).
    pub omega: f64,
}

impl SpatialOrbitShape {
    /// The planar orbit in the xy-plane.
    pub fn from_planar(shape: &OrbitShape) -> Self {
        Self {
            a: shape.a,
            e: shape.e,
            inclination: 0.0,
            raan: 0.0,
            omega: shape.omega,
        }
    }

    /// Why the orbit is not a closed one, if it is not.
    pub fn invalid(&self) -> Option<&'static str> {
        if !(self.a.is_finite() && self.a > 0.0) {
            return Some("the target's semi-major axis is not positive");
        }
        if !(self.e.is_finite() && (0.0..1.0).contains(&self.e)) {
            return Some("the target's eccentricity is outside [0, 1)");
        }
        if ![self.inclination, self.raan, self.omega].iter().all(|x| x.is_finite()) {
            return Some("a target angle is not finite");
        }
        None
    }

    /// The perifocal unit vectors: P towards periapsis, Q 90 degrees ahead in the orbit plane.
    pub fn perifocal(&self) -> ([f64; 3], [f64; 3]) {
        let plane = OrbitPlane {
            inclination: self.inclination,
            raan: self.raan,
        };
        plane.perifocal(self.omega)
    }

    /// The orbit from its shape and its perifocal vectors (the inverse of [`Self::perifocal`]);
    /// in the plane (inclination below 1e-12) the node is put on the x-axis.
    pub fn from_perifocal(a: f64, e: f64, p: &[f64; 3], q: &[f64; 3]) -> Self {
        let w = cross3(p, q);
        let plane = OrbitPlane::of_normal(&w).unwrap_or(OrbitPlane::REFERENCE);
        let inclination = plane.inclination;
        let (raan, omega) = if inclination.sin() < 1e-12 {
            // In the plane, prograde (w_z = 1) or retrograde (w_z = -1): the node on the x-axis,
            // and P = (cos omega, w_z sin omega, 0).
            (0.0, (p[1] * w[2].signum()).atan2(p[0]))
        } else {
            let (sn, cn) = plane.raan.sin_cos();
            (plane.raan, (p[2] / inclination.sin()).atan2(p[0] * cn + p[1] * sn))
        };
        Self {
            a,
            e,
            inclination,
            raan,
            omega,
        }
    }

    /// Position and velocity at true anomaly `nu`, generic so that derivatives in nu come
    /// from dual numbers.
    pub fn state_at<D: DualNum<Primitive = f64> + Copy>(&self, nu: D) -> [D; 6] {
        let (p_hat, q_hat) = self.perifocal();
        let p = self.a * (1.0 - self.e * self.e);
        let k = (1.0 / p).sqrt();
        let r = (nu.cos() * self.e + 1.0).recip() * p;
        let (x, y) = (r * nu.cos(), r * nu.sin());
        let (vx, vy) = (-nu.sin() * k, (nu.cos() + self.e) * k);
        [
            x * p_hat[0] + y * q_hat[0],
            x * p_hat[1] + y * q_hat[1],
            x * p_hat[2] + y * q_hat[2],
            vx * p_hat[0] + vy * q_hat[0],
            vx * p_hat[1] + vy * q_hat[1],
            vx * p_hat[2] + vy * q_hat[2],
        ]
    }

    /// [`Self::state_at`] in f64.
    pub fn cartesian_at(&self, nu: f64) -> SpatialState {
        let s = self.state_at(nu);
        SpatialState {
            r: [s[0], s[1], s[2]],
            v: [s[3], s[4], s[5]],
        }
    }
}

/// A transfer in three dimensions: from `departure` (with `initial_mass`) to the orbit `target`
/// anywhere on it at `time_of_flight`, mass-optimal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpatialTransfer {
    /// State at t = 0.
    pub departure: SpatialState,
    /// Mass at t = 0 (fraction of the mass the thrust is scaled by).
    pub initial_mass: f64,
    /// The orbit to reach.
    pub target: SpatialOrbitShape,
    /// Time of flight (t*).
    pub time_of_flight: f64,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
}

impl SpatialTransfer {
    /// The transfer `scenario` poses, each orbit in its plane.
    pub fn from_scenario(scenario: &SpatialScenario, spacecraft: CanonicalSpacecraft) -> Self {
        let (target, plane) = (&scenario.scenario.target, &scenario.target_plane);
        Self {
            departure: scenario.departure(),
            initial_mass: 1.0,
            target: SpatialOrbitShape {
                inclination: plane.inclination,
                raan: plane.raan,
                ..SpatialOrbitShape::from_planar(target)
            },
            time_of_flight: scenario.scenario.time_of_flight(),
            spacecraft,
        }
    }

    fn costates(z: &SpatialTransferVector) -> SpatialVector {
        SpatialVector::from_column_slice(&z.as_slice()[..7])
    }

    /// The final state-costate of the trajectory of unknowns `z` at `eps`.
    pub fn final_state_costate(
        &self,
        eps: f64,
        z: &SpatialTransferVector,
        tolerances: &Tolerances,
    ) -> Result<[f64; Y3_LEN], IntegrationError> {
        let y0 = initial_state_costate3(&self.departure, self.initial_mass, &Self::costates(z));
        propagate3(&self.params(eps), 0.0, &y0, self.time_of_flight, tolerances)
    }

    fn params(&self, eps: f64) -> crate::solver::pontryagin::OptimalControlParams {
        crate::solver::pontryagin::OptimalControlParams {
            spacecraft: self.spacecraft,
            eps,
        }
    }

    /// The terminal conditions at the final state-costate `y` and the orbit point at `nu_f` with
    /// its first and second derivatives in nu_f.
    fn terminal(&self, y: &[f64], nu_f: f64) -> (SpatialTransferVector, [Dual2_64; 6]) {
        let orbit = self.target.state_at(Dual2_64::from_re(nu_f).derivative());
        let mut f = SpatialTransferVector::zeros();
        for i in 0..6 {
            f[i] = y[idx3::R + i] - orbit[i].re;
        }
        f[6] = (0..6).map(|i| y[idx3::LR + i] * orbit[i].v1).sum();
        f[7] = y[idx3::LM];
        (f, orbit)
    }
}

impl ShootingProblem<SPATIAL_TRANSFER_UNKNOWNS> for SpatialTransfer {
    fn residual_only(
        &self,
        eps: f64,
        z: &SpatialTransferVector,
        tolerances: &Tolerances,
    ) -> Result<SpatialTransferVector, IntegrationError> {
        let y = self.final_state_costate(eps, z, tolerances)?;
        Ok(self.terminal(&y, z[7]).0)
    }

    fn residual(
        &self,
        eps: f64,
        z: &SpatialTransferVector,
        tolerances: &Tolerances,
    ) -> Result<
        (
            SpatialTransferVector,
            SMatrix<f64, SPATIAL_TRANSFER_UNKNOWNS, SPATIAL_TRANSFER_UNKNOWNS>,
        ),
        IntegrationError,
    > {
        let y0 = initial_state_costate3(&self.departure, self.initial_mass, &Self::costates(z));
        let ys = propagate_sensitivity3(&self.params(eps), &y0, self.time_of_flight, tolerances)?;
        let (f, orbit) = self.terminal(&ys, z[7]);
        let sens = |row: usize, k: usize| ys[Y3_LEN + k * Y3_LEN + row];
        let mut jac = SMatrix::<f64, SPATIAL_TRANSFER_UNKNOWNS, SPATIAL_TRANSFER_UNKNOWNS>::zeros();
        for k in 0..7 {
            for i in 0..6 {
                jac[(i, k)] = sens(idx3::R + i, k);
            }
            jac[(6, k)] = (0..6).map(|i| sens(idx3::LR + i, k) * orbit[i].v1).sum();
            jac[(7, k)] = sens(idx3::LM, k);
        }
        for i in 0..6 {
            jac[(i, 7)] = -orbit[i].v1;
        }
        jac[(6, 7)] = (0..6).map(|i| ys[idx3::LR + i] * orbit[i].v2).sum();
        Ok((f, jac))
    }
}

/// The departure's angle in the target orbit's plane, from the target's periapsis.
fn anomaly_in_target_plane(departure: &SpatialState, target: &SpatialOrbitShape) -> f64 {
    let (p, q) = target.perifocal();
    dot3(&departure.r, &q).atan2(dot3(&departure.r, &p))
}

/// The planar solver's transfer guesses (docs/spec.md section 3.3) in three dimensions: the
/// rendezvous costate shapes of [`super::spatial_guesses`], each with the final anomalies reached by
/// sweeping at the mean, initial and final mean motions.
pub fn spatial_transfer_guesses(problem: &SpatialTransfer) -> Vec<SpatialTransferVector> {
    let shapes = costate_guesses(
        &problem.departure,
        problem.target.a >= -0.5 / problem.departure.energy(),
    );
    let n0 = (-2.0 * problem.departure.energy()).powf(1.5);
    let nf = problem.target.a.powf(-1.5);
    let start = anomaly_in_target_plane(&problem.departure, &problem.target);
    let mut guesses = Vec::new();
    for rate in [0.5 * (n0 + nf), n0, nf, 0.75 * n0 + 0.25 * nf, 0.25 * n0 + 0.75 * nf] {
        let nu_f = start + rate * problem.time_of_flight;
        for shape in &shapes {
            let mut z = SpatialTransferVector::zeros();
            z.as_mut_slice()[..7].copy_from_slice(shape.as_slice());
            z[7] = nu_f;
            guesses.push(z);
        }
    }
    guesses
}

impl SpatialShooting<SPATIAL_TRANSFER_UNKNOWNS> for SpatialTransfer {
    fn invalid(&self) -> Option<&'static str> {
        if !self.departure.is_valid() {
            return Some("the departure state is not finite or sits at the centre");
        }
        if !(self.time_of_flight.is_finite() && self.time_of_flight > 0.0) {
            return Some("the time of flight is not positive");
        }
        if !(self.initial_mass.is_finite() && self.initial_mass > 0.0) {
            return Some("the initial mass is not positive");
        }
        self.target.invalid()
    }

    fn guesses(&self) -> Vec<SpatialTransferVector> {
        spatial_transfer_guesses(self)
    }

    fn final_state_costate(
        &self,
        eps: f64,
        z: &SpatialTransferVector,
        tolerances: &Tolerances,
    ) -> Result<[f64; Y3_LEN], IntegrationError> {
        SpatialTransfer::final_state_costate(self, eps, z, tolerances)
    }

    fn terminal_of(&self, y: &[f64; Y3_LEN], z: &SpatialTransferVector) -> SpatialTransferVector {
        self.terminal(y, z[7]).0
    }

    fn start_from_flattened(&self, options: &SolveOptions) -> Result<SpatialTransferVector, String> {
        start_from_flattened_transfer(self, options)
    }

    fn homotopy_work(&self, options: &SolveOptions) -> u64 {
        options.max_transfer_homotopy_work
    }
}

/// The target orbit seen in `frame` (rows: the frame's axes in inertial coordinates).
pub(crate) fn orbit_in_frame(frame: &[[f64; 3]; 3], orbit: &SpatialOrbitShape) -> SpatialOrbitShape {
    let (p, q) = orbit.perifocal();
    SpatialOrbitShape::from_perifocal(orbit.a, orbit.e, &to_frame(frame, &p), &to_frame(frame, &q))
}

/// An energy-optimal start of a spatial transfer from the planar fallbacks (continuation in the
/// target, then the direct transcription's multipliers) on the transfer flattened into the
/// departure plane (the target orbit turned about its node line into that plane), lifted, then
/// carried to the real target by continuation in the inclination to the departure plane.
fn start_from_flattened_transfer(
    problem: &SpatialTransfer,
    options: &SolveOptions,
) -> Result<SpatialTransferVector, String> {
    let frame = departure_frame(&problem.departure).ok_or("the departure has no orbital plane")?;
    let seen = orbit_in_frame(&frame, &problem.target);
    let flat_omega = seen.raan + seen.omega;
    let r = to_frame(&frame, &problem.departure.r);
    let v = to_frame(&frame, &problem.departure.v);
    let initial = shared::orbit::CartesianState {
        r: [r[0], r[1]],
        v: [v[0], v[1]],
    }
    .elements()
    .ok_or("the departure is not on a closed orbit")?;
    let scenario = Scenario {
        problem: ProblemKind::Transfer,
        initial,
        target: OrbitShape {
            a: seen.a,
            e: seen.e,
            omega: flat_omega,
        },
        target_nu0: 0.0,
        steps: FLAT_CYCLES,
        cycle: problem.time_of_flight / f64::from(FLAT_CYCLES),
    };
    scenario
        .validate()
        .map_err(|e| format!("the flattened transfer cannot be posed: {e:?}"))?;
    let planar: TransferVector =
        match crate::solver::continuation::transfer_start(&scenario, &problem.spacecraft, options) {
            Ok(z) => z,
            Err(_) if !options.fallbacks.direct() => {
                return Err("the flattened problem's continuation in the target stopped".to_string())
            }
            Err(_) => match crate::solver::direct::indirect_start(&scenario, &problem.spacecraft) {
                Ok((l, nu_f)) => {
                    TransferVector::from_column_slice(&[l[0], l[1], l[2], l[3], l[4], nu_f.unwrap_or(0.0)])
                }
                Err(e) => return Err(format!("the flattened problem has no start either: {e}")),
            },
        };
    let lift = |x: f64, y: f64| from_frame(&frame, &[x, y, 0.0]);
    let (lr, lv) = (lift(planar[0], planar[1]), lift(planar[2], planar[3]));
    let z0 =
        SpatialTransferVector::from_column_slice(&[lr[0], lr[1], lr[2], lv[0], lv[1], lv[2], planar[4], planar[5]]);
    // The target at inclination s times its own to the departure plane, node and periapsis
    // kept, back in inertial coordinates.
    let at = |s: f64| {
        let tilted = SpatialOrbitShape {
            inclination: s * seen.inclination,
            ..seen
        };
        let (p, q) = tilted.perifocal();
        SpatialTransfer {
            target: SpatialOrbitShape::from_perifocal(seen.a, seen.e, &from_frame(&frame, &p), &from_frame(&frame, &q)),
            ..*problem
        }
    };
    super::continue_at_energy_optimum(at, &z0, options, "the inclination to the departure plane")
}

/// A solved spatial transfer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpatialTransferSolution {
    /// Initial costates (lambda_r, lambda_v, lambda_m).
    pub costates: SpatialVector,
    /// True anomaly of the arrival on the target orbit (rad).
    pub final_anomaly: f64,
    /// The homotopy level reached.
    pub final_eps: f64,
    /// Largest terminal residual of a fresh propagation at `final_eps`.
    pub residual: f64,
    /// Final mass, fraction of m0 (the mass the thrust is scaled by).
    pub final_mass: f64,
    /// Distinct energy-optimal solutions found by the multi-start.
    pub distinct_energy_optima: u32,
}

/// Solves a spatial transfer as the planar solver solves one (docs/spec.md sections 3.3, 3.6),
/// from `guesses` ([`spatial_transfer_guesses`] when empty).
pub fn solve_spatial_transfer(
    problem: &SpatialTransfer,
    guesses: Vec<SpatialTransferVector>,
    options: &SolveOptions,
) -> Result<SpatialTransferSolution, SpatialSolveError> {
    let solved = super::solve_spatial(problem, guesses, options)?;
    Ok(SpatialTransferSolution {
        costates: SpatialTransfer::costates(&solved.z),
        final_anomaly: solved.z[7],
        final_eps: solved.eps,
        residual: solved.residual,
        final_mass: solved.final_mass,
        distinct_energy_optima: solved.distinct,
    })
}

/// Planar transfer unknowns (lambda_r, lambda_v, lambda_m, nu_f) embedded in three dimensions.
pub fn lift_planar_transfer(z: &TransferVector) -> SpatialTransferVector {
    SpatialTransferVector::from_column_slice(&[z[0], z[1], 0.0, z[2], z[3], 0.0, z[4], z[5]])
}
