//! Minimum time of flight in three dimensions: which draws of an inclined family are infeasible
//! in their time of flight (docs/spec.md section 3.6), the counterpart of the planar
//! [`crate::solver::min_time`], whose notes this module follows.
//!
//! The extremal is the planar one's with three components: full thrust along the primer
//! -lambda_v throughout, lambda_m(tf) = 0, so lambda_m enters nothing but H. Transfer to an
//! inclined orbit at a free anomaly ([`SpatialMinTimeTransfer`]): unknowns (lambda_r(0),
//! lambda_v(0), tf, nu_f) (8); residuals r, v on the orbit at nu_f (6), transversality (1) and
//! H(tf) = 0 (1). Rendezvous ([`SpatialMinTimeRendezvous`]): unknowns (lambda_r(0), lambda_v(0),
//! tf) (7); residuals r, v equal the body's (6) and H(tf) = lambda . d(body)/dt (1). Feasibility
//! is monotone in the time of flight as in the plane (coast on the orbit, or beside the body),
//! and a converged extremal is a local minimum time, not a proven global one.
//!
//! How the extremal is found ([`classify_spatial_draw`]): the draw flattened into its departure
//! plane (the target orbit turned about its node line into that plane, the body's anomaly at
//! departure kept) is classified by the planar method; its minimum-time extremal, lifted with
//! zero out-of-plane costates, is carried to the real target by Newton continuation in the
//! target's inclination to the departure plane, from 0 to its value. Where the flattened draw is
//! feasible, its energy-optimal start is carried out of the plane the same way (a recovered
//! draw), and failing that the planar multi-start's extremals are. When no lifted extremal lies
//! below the TOF, a direct multi-start of the minimum-time Newton from the spatial primer
//! guesses runs too, and the smaller minimum time wins. An extremal shorter than the TOF proves
//! the draw feasible by itself: it is returned as such, without an energy-optimal start.

use nalgebra::SVector;
use num_dual::Dual2_64;
use onboard::integrator::{integrate, IntegrationError, OdeSystem, Tolerances};
use shared::orbit::{dot3 as dot, norm3 as norm, SpatialState};
use shared::scenario::{ProblemKind, Scenario, SpatialScenario};
use shared::spacecraft::CanonicalSpacecraft;

use super::transfer::orbit_in_frame;
use super::{
    continue_at_energy_optimum, costate_guesses, from_frame, idx3, initial_state_costate3, spatial_transfer_guesses,
    state_costate_rhs3_in, SpatialOrbitShape, SpatialRendezvous, SpatialTransfer, SpatialTransferVector, SpatialVector,
    Y3_LEN,
};
use crate::solver::min_time::{
    classify_draw, full_params, mass_limit, min_time_newton, multistart_extremals, rendezvous_multistart_extremals,
    scaled_by, Feasibility, MinTimeVector, MULTISTART_TOF_FACTORS,
};
use crate::solver::pontryagin::{charge_stats, variational_rhs, OptimalControlParams, Regime, SENSITIVITY_STEP_WORK};
use crate::solver::shooting::{newton, ShootingProblem};
use crate::solver::SolveOptions;

/// Unknowns of the spatial minimum-time transfer: lambda_r(0), lambda_v(0), tf, nu_f.
pub const SPATIAL_MIN_TIME_UNKNOWNS: usize = 8;
/// Spatial minimum-time unknowns (lambda_r(0), lambda_v(0), tf, nu_f), canonical; a
/// rendezvous's have no nu_f (zero, unused).
pub type SpatialMinTimeVector = SVector<f64, SPATIAL_MIN_TIME_UNKNOWNS>;
/// Unknowns of the spatial minimum-time rendezvous: lambda_r(0), lambda_v(0), tf.
pub const SPATIAL_MIN_TIME_RENDEZVOUS_UNKNOWNS: usize = 7;
/// Spatial minimum-time rendezvous unknowns (lambda_r(0), lambda_v(0), tf), canonical.
pub type SpatialMinTimeRendezvousVector = SVector<f64, SPATIAL_MIN_TIME_RENDEZVOUS_UNKNOWNS>;
/// The classification of a spatial draw: a recovered start holds the spatial transfer's
/// energy-optimal unknowns (a rendezvous's seven costates padded with a zero nu_f).
pub type SpatialFeasibility = Feasibility<SpatialMinTimeVector, SpatialTransferVector>;

/// Index of tf in the minimum-time unknowns.
pub const TF: usize = 6;
/// Index of nu_f in the minimum-time transfer's unknowns.
pub const NU_F: usize = 7;
/// lambda_r and lambda_v: the costates the full-thrust trajectory depends on.
const COSTATES: usize = 6;
/// State-costate and its sensitivity to the six costates (column k after the first 14 at
/// `14 + 14 k`).
const FULL_SENSITIVITY_LEN: usize = Y3_LEN + Y3_LEN * COSTATES;
/// Planar extremals lifted out of the departure plane, smallest tf first.
const LIFTED_EXTREMALS: usize = 3;
/// What the lifted extremals are continued in.
const TILT: &str = "the target's inclination to the departure plane";

/// The spatial state-costate system at full thrust.
struct FullThrust3(OptimalControlParams);

impl OdeSystem<Y3_LEN> for FullThrust3 {
    fn derivatives(&self, _t: f64, y: &[f64; Y3_LEN], dydt: &mut [f64; Y3_LEN]) {
        *dydt = state_costate_rhs3_in(y, &self.0, Regime::Full);
    }
}

/// The same with its sensitivity to lambda_r(0), lambda_v(0) by dual numbers.
struct FullThrustSensitivity3(OptimalControlParams);

impl OdeSystem<FULL_SENSITIVITY_LEN> for FullThrustSensitivity3 {
    fn derivatives(&self, _t: f64, ys: &[f64; FULL_SENSITIVITY_LEN], dydt: &mut [f64; FULL_SENSITIVITY_LEN]) {
        variational_rhs::<Y3_LEN, COSTATES>(ys, |y| state_costate_rhs3_in(y, &self.0, Regime::Full), dydt);
    }
}

/// The initial state-costate of the minimum-time problem from unknowns z (their first six
/// components), mass 1 and lambda_m(0) = 0 (it enters nothing that is propagated).
fn min_time_initial<const N: usize>(departure: &SpatialState, z: &SVector<f64, N>) -> [f64; Y3_LEN] {
    let costates = SpatialVector::from_column_slice(&[z[0], z[1], z[2], z[3], z[4], z[5], 0.0]);
    initial_state_costate3(departure, 1.0, &costates)
}

/// Full-thrust propagation from `departure` with the costates `z[..6]` to `z[6]` (tf).
pub fn propagate_full_thrust3<const N: usize>(
    departure: &SpatialState,
    spacecraft: &CanonicalSpacecraft,
    z: &SVector<f64, N>,
    tolerances: &Tolerances,
) -> Result<[f64; Y3_LEN], IntegrationError> {
    let tf = z[TF];
    if !(tf > 0.0 && tf < mass_limit(spacecraft)) {
        return Err(IntegrationError::NonFinite { t: tf });
    }
    let system = FullThrust3(full_params(spacecraft));
    let (y, stats) = integrate(&system, 0.0, &min_time_initial(departure, z), tf, tolerances)?;
    charge_stats(&stats, 1);
    Ok(y)
}

/// [`propagate_full_thrust3`] with the sensitivity of y(tf) to lambda_r(0), lambda_v(0).
fn full_thrust_sensitivity3<const N: usize>(
    departure: &SpatialState,
    spacecraft: &CanonicalSpacecraft,
    z: &SVector<f64, N>,
    tolerances: &Tolerances,
) -> Result<[f64; FULL_SENSITIVITY_LEN], IntegrationError> {
    let tf = z[TF];
    if !(tf > 0.0 && tf < mass_limit(spacecraft)) {
        return Err(IntegrationError::NonFinite { t: tf });
    }
    let mut ys0 = [0.0; FULL_SENSITIVITY_LEN];
    ys0[..Y3_LEN].copy_from_slice(&min_time_initial(departure, z));
    for k in 0..COSTATES {
        ys0[Y3_LEN + k * Y3_LEN + idx3::LR + k] = 1.0;
    }
    let system = FullThrustSensitivity3(full_params(spacecraft));
    let (ys, stats) = integrate(&system, 0.0, &ys0, tf, tolerances)?;
    charge_stats(&stats, SENSITIVITY_STEP_WORK);
    Ok(ys)
}

/// The end of a full-thrust arc with what the minimum-time Jacobians need: y(tf), the gradient
/// of [`reduced_hamiltonian3`] there, and d y(tf) / d z for the costates and tf.
struct ArcEnd {
    sensitivity: [f64; FULL_SENSITIVITY_LEN],
    y: [f64; Y3_LEN],
    hamiltonian_gradient: [f64; Y3_LEN],
    rate: [f64; Y3_LEN],
}

impl ArcEnd {
    fn of<const N: usize>(
        departure: &SpatialState,
        spacecraft: &CanonicalSpacecraft,
        z: &SVector<f64, N>,
        tolerances: &Tolerances,
    ) -> Result<Self, IntegrationError> {
        let sensitivity = full_thrust_sensitivity3(departure, spacecraft, z, tolerances)?;
        let y: [f64; Y3_LEN] = core::array::from_fn(|i| sensitivity[i]);
        Ok(Self {
            sensitivity,
            y,
            hamiltonian_gradient: hamiltonian_gradient3(&y, spacecraft),
            rate: state_costate_rhs3_in(&y, &full_params(spacecraft), Regime::Full),
        })
    }

    /// d y_i(tf) / d z_k: the costate columns of the sensitivity, then dy/dt for tf.
    fn dy(&self, i: usize, k: usize) -> f64 {
        if k < COSTATES {
            self.sensitivity[Y3_LEN + k * Y3_LEN + i]
        } else {
            self.rate[i]
        }
    }

    /// d H(tf) / d z_k.
    fn dh(&self, k: usize) -> f64 {
        (0..Y3_LEN).map(|i| self.hamiltonian_gradient[i] * self.dy(i, k)).sum()
    }
}

/// The minimum-time Hamiltonian without its lambda_m term (lambda_m(tf) = 0): 1 + lambda_r . v
/// + lambda_v . g(r) - T |lambda_v| / m, at full thrust along the primer.
pub fn reduced_hamiltonian3(y: &[f64; Y3_LEN], spacecraft: &CanonicalSpacecraft) -> f64 {
    let part = |at: usize| -> [f64; 3] { core::array::from_fn(|k| y[at + k]) };
    let (r, v, lr, lv) = (part(idx3::R), part(idx3::V), part(idx3::LR), part(idx3::LV));
    let rn = norm(&r);
    1.0 + dot(&lr, &v) - dot(&lv, &r) / (rn * rn * rn) - spacecraft.thrust * norm(&lv) / y[idx3::M]
}

/// The gradient of [`reduced_hamiltonian3`] in y, from Hamilton's equations (as the planar one):
/// dH/dx = -dlambda/dt, dH/dlambda = dx/dt (lambda_m excluded), dH/dm = T |lambda_v| / m^2.
fn hamiltonian_gradient3(y: &[f64; Y3_LEN], spacecraft: &CanonicalSpacecraft) -> [f64; Y3_LEN] {
    let f = state_costate_rhs3_in(y, &full_params(spacecraft), Regime::Full);
    let lv: [f64; 3] = core::array::from_fn(|k| y[idx3::LV + k]);
    let mut grad = [0.0; Y3_LEN];
    for k in 0..3 {
        grad[idx3::R + k] = -f[idx3::LR + k];
        grad[idx3::V + k] = y[idx3::LR + k];
        grad[idx3::LR + k] = f[idx3::R + k];
        grad[idx3::LV + k] = f[idx3::V + k];
    }
    grad[idx3::M] = spacecraft.thrust * norm(&lv) / (y[idx3::M] * y[idx3::M]);
    grad
}

/// The minimum-time transfer to an inclined orbit at a free anomaly, as a shooting problem (eps
/// is ignored).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpatialMinTimeTransfer {
    /// State at t = 0 (mass 1).
    pub departure: SpatialState,
    /// The orbit to reach.
    pub target: SpatialOrbitShape,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
}

impl SpatialMinTimeTransfer {
    /// The terminal conditions at the final state-costate y, and the orbit point at nu_f with
    /// its nu derivatives.
    fn terminal(&self, y: &[f64; Y3_LEN], nu_f: f64) -> (SpatialMinTimeVector, [Dual2_64; 6]) {
        let orbit = self.target.state_at(Dual2_64::from_re(nu_f).derivative());
        let mut f = SpatialMinTimeVector::zeros();
        for i in 0..6 {
            f[i] = y[idx3::R + i] - orbit[i].re;
        }
        f[6] = (0..6).map(|i| y[idx3::LR + i] * orbit[i].v1).sum();
        f[7] = reduced_hamiltonian3(y, &self.spacecraft);
        (f, orbit)
    }
}

impl ShootingProblem<SPATIAL_MIN_TIME_UNKNOWNS> for SpatialMinTimeTransfer {
    fn residual_only(
        &self,
        _eps: f64,
        z: &SpatialMinTimeVector,
        tolerances: &Tolerances,
    ) -> Result<SpatialMinTimeVector, IntegrationError> {
        let y = propagate_full_thrust3(&self.departure, &self.spacecraft, z, tolerances)?;
        Ok(self.terminal(&y, z[NU_F]).0)
    }

    fn residual(
        &self,
        _eps: f64,
        z: &SpatialMinTimeVector,
        tolerances: &Tolerances,
    ) -> Result<(SpatialMinTimeVector, nalgebra::SMatrix<f64, 8, 8>), IntegrationError> {
        let end = ArcEnd::of(&self.departure, &self.spacecraft, z, tolerances)?;
        let y = end.y;
        let (f, orbit) = self.terminal(&y, z[NU_F]);
        let mut jac = nalgebra::SMatrix::<f64, 8, 8>::zeros();
        for k in 0..=TF {
            for i in 0..6 {
                jac[(i, k)] = end.dy(idx3::R + i, k);
            }
            jac[(6, k)] = (0..6).map(|i| end.dy(idx3::LR + i, k) * orbit[i].v1).sum();
            jac[(7, k)] = end.dh(k);
        }
        for i in 0..6 {
            jac[(i, NU_F)] = -orbit[i].v1;
        }
        jac[(6, NU_F)] = (0..6).map(|i| y[idx3::LR + i] * orbit[i].v2).sum();
        Ok((f, jac))
    }
}

/// The body's motion at t: its state (r, v), the state's rate (v, g(r)) and the rate's rate
/// (g(r), G(r) v, with G the gravity gradient 3 r r^T / r^5 - I / r^3).
struct BodyMotion3 {
    state: [f64; 6],
    rate: [f64; 6],
    acceleration: [f64; 6],
}

/// The body on `orbit`, at true anomaly `nu0` at t = 0, at time t (a Keplerian coast).
fn body_motion3(orbit: &SpatialOrbitShape, nu0: f64, t: f64) -> Result<BodyMotion3, IntegrationError> {
    let body = onboard::kepler::coast3(&orbit.cartesian_at(nu0), t).map_err(|_| IntegrationError::InvalidInput)?;
    let (r, v) = (body.r, body.v);
    let r2 = dot(&r, &r);
    let r3 = r2 * r2.sqrt();
    let r5 = r3 * r2;
    let rv = dot(&r, &v);
    let g: [f64; 3] = core::array::from_fn(|k| -r[k] / r3);
    let dg: [f64; 3] = core::array::from_fn(|k| 3.0 * r[k] * rv / r5 - v[k] / r3);
    Ok(BodyMotion3 {
        state: [r[0], r[1], r[2], v[0], v[1], v[2]],
        rate: [v[0], v[1], v[2], g[0], g[1], g[2]],
        acceleration: [g[0], g[1], g[2], dg[0], dg[1], dg[2]],
    })
}

/// The minimum-time rendezvous with a body on an inclined orbit, as a shooting problem (eps is
/// ignored): cost tf, x(tf) = x_body(tf), so lambda(tf) = nu and H(tf) = nu . dx_body/dt.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpatialMinTimeRendezvous {
    /// State at t = 0 (mass 1).
    pub departure: SpatialState,
    /// The body's orbit.
    pub target: SpatialOrbitShape,
    /// The body's true anomaly at t = 0 (rad).
    pub target_nu0: f64,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
}

impl SpatialMinTimeRendezvous {
    fn body(&self, t: f64) -> Result<BodyMotion3, IntegrationError> {
        body_motion3(&self.target, self.target_nu0, t)
    }

    /// H(tf) - lambda(tf) . d(body)/dt: zero at an extremal.
    fn end_condition(&self, y: &[f64; Y3_LEN], body: &BodyMotion3) -> f64 {
        reduced_hamiltonian3(y, &self.spacecraft) - (0..6).map(|i| y[idx3::LR + i] * body.rate[i]).sum::<f64>()
    }

    fn terminal(&self, y: &[f64; Y3_LEN], body: &BodyMotion3) -> SpatialMinTimeRendezvousVector {
        let mut f = SpatialMinTimeRendezvousVector::zeros();
        for i in 0..6 {
            f[i] = y[idx3::R + i] - body.state[i];
        }
        f[6] = self.end_condition(y, body);
        f
    }
}

impl ShootingProblem<SPATIAL_MIN_TIME_RENDEZVOUS_UNKNOWNS> for SpatialMinTimeRendezvous {
    fn residual_only(
        &self,
        _eps: f64,
        z: &SpatialMinTimeRendezvousVector,
        tolerances: &Tolerances,
    ) -> Result<SpatialMinTimeRendezvousVector, IntegrationError> {
        let y = propagate_full_thrust3(&self.departure, &self.spacecraft, z, tolerances)?;
        Ok(self.terminal(&y, &self.body(z[TF])?))
    }

    fn residual(
        &self,
        _eps: f64,
        z: &SpatialMinTimeRendezvousVector,
        tolerances: &Tolerances,
    ) -> Result<(SpatialMinTimeRendezvousVector, nalgebra::SMatrix<f64, 7, 7>), IntegrationError> {
        let end = ArcEnd::of(&self.departure, &self.spacecraft, z, tolerances)?;
        let y = end.y;
        let body = self.body(z[TF])?;
        let f = self.terminal(&y, &body);
        let mut jac = nalgebra::SMatrix::<f64, 7, 7>::zeros();
        for k in 0..=TF {
            for i in 0..6 {
                jac[(i, k)] = end.dy(idx3::R + i, k);
            }
            jac[(6, k)] = end.dh(k) - (0..6).map(|i| end.dy(idx3::LR + i, k) * body.rate[i]).sum::<f64>();
        }
        // The body moves on as tf does.
        for i in 0..6 {
            jac[(i, TF)] -= body.rate[i];
        }
        jac[(6, TF)] -= (0..6).map(|i| y[idx3::LR + i] * body.acceleration[i]).sum::<f64>();
        Ok((f, jac))
    }
}

/// Either spatial minimum-time problem, with its unknowns held in a [`SpatialMinTimeVector`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SpatialMinTime {
    /// Reach the orbit anywhere on it.
    Transfer(SpatialMinTimeTransfer),
    /// Meet the body.
    Rendezvous(SpatialMinTimeRendezvous),
}

impl SpatialMinTime {
    /// The minimum-time problem `scenario` poses, each orbit in its plane.
    pub fn from_scenario(scenario: &SpatialScenario, spacecraft: CanonicalSpacecraft) -> Self {
        let transfer = SpatialTransfer::from_scenario(scenario, spacecraft);
        match scenario.scenario.problem {
            ProblemKind::Transfer => Self::Transfer(SpatialMinTimeTransfer {
                departure: transfer.departure,
                target: transfer.target,
                spacecraft,
            }),
            ProblemKind::Rendezvous => Self::Rendezvous(SpatialMinTimeRendezvous {
                departure: transfer.departure,
                target: transfer.target,
                target_nu0: scenario.scenario.target_nu0,
                spacecraft,
            }),
        }
    }

    fn departure(&self) -> &SpatialState {
        match self {
            Self::Transfer(p) => &p.departure,
            Self::Rendezvous(p) => &p.departure,
        }
    }

    fn spacecraft(&self) -> &CanonicalSpacecraft {
        match self {
            Self::Transfer(p) => &p.spacecraft,
            Self::Rendezvous(p) => &p.spacecraft,
        }
    }

    /// The terminal residuals of unknowns `z` (a rendezvous's seven, then a zero), from the
    /// plain full-thrust propagation.
    pub fn residual(
        &self,
        z: &SpatialMinTimeVector,
        tolerances: &Tolerances,
    ) -> Result<SpatialMinTimeVector, IntegrationError> {
        match self {
            Self::Transfer(p) => p.residual_only(1.0, z, tolerances),
            Self::Rendezvous(p) => Ok(padded(&p.residual_only(1.0, &truncated(z), tolerances)?)),
        }
    }

    /// The guess with lambda_r, lambda_v scaled so that the end condition holds (it is 1 plus a
    /// term linear in the costates, and the full-thrust trajectory does not depend on their
    /// scale); None where no positive scale does.
    pub fn scaled(&self, guess: &SpatialMinTimeVector, tolerances: &Tolerances) -> Option<SpatialMinTimeVector> {
        let y = propagate_full_thrust3(self.departure(), self.spacecraft(), guess, tolerances).ok()?;
        let end = match self {
            Self::Transfer(p) => reduced_hamiltonian3(&y, &p.spacecraft),
            Self::Rendezvous(p) => p.end_condition(&y, &p.body(guess[TF]).ok()?),
        };
        scaled_by(guess, COSTATES, end - 1.0)
    }

    /// The minimum-time Newton from `guess`.
    pub fn solve(&self, guess: &SpatialMinTimeVector, tolerances: &Tolerances) -> Option<SpatialMinTimeVector> {
        let settings = min_time_newton();
        let solved = match self {
            Self::Transfer(p) => {
                newton(p, 1.0, guess, tolerances, &settings)
                    .ok()
                    .filter(|o| o.converged)?
                    .z
            }
            Self::Rendezvous(p) => padded(
                &newton(p, 1.0, &truncated(guess), tolerances, &settings)
                    .ok()
                    .filter(|o| o.converged)?
                    .z,
            ),
        };
        (solved[TF] > 0.0).then_some(solved)
    }

    /// The direct multi-start's guesses at final time `tf` (not yet scaled): the spatial
    /// transfer's primer guesses (every other one) with their final anomaly swept over tf, or
    /// the rendezvous's costate shapes.
    fn multistart_guesses(&self, tf: f64) -> Vec<SpatialMinTimeVector> {
        let with_tf = |costates: &[f64], nu_f: f64| {
            let mut z = SpatialMinTimeVector::zeros();
            z.as_mut_slice()[..COSTATES].copy_from_slice(&costates[..COSTATES]);
            z[TF] = tf;
            z[NU_F] = nu_f;
            z
        };
        match self {
            Self::Transfer(p) => {
                let stretched = SpatialTransfer {
                    departure: p.departure,
                    initial_mass: 1.0,
                    target: p.target,
                    time_of_flight: tf,
                    spacecraft: p.spacecraft,
                };
                spatial_transfer_guesses(&stretched)
                    .iter()
                    .step_by(2)
                    .map(|g| with_tf(g.as_slice(), g[7]))
                    .collect()
            }
            Self::Rendezvous(p) => costate_guesses(&p.departure, p.target.a >= -0.5 / p.departure.energy())
                .iter()
                .map(|g| with_tf(g.as_slice(), 0.0))
                .collect(),
        }
    }

    /// Every extremal of the direct multi-start at the planar multi-start's final times (1 to 8
    /// `tof`), smallest tf first, each within the Newton tolerance of the minimum-time problems.
    pub fn multistart(&self, tof: f64, tolerances: &Tolerances) -> Vec<SpatialMinTimeVector> {
        let mut found: Vec<SpatialMinTimeVector> = MULTISTART_TOF_FACTORS
            .iter()
            .flat_map(|k| self.multistart_guesses(k * tof))
            .filter_map(|guess| self.solve(&self.scaled(&guess, tolerances)?, tolerances))
            .collect();
        found.sort_by(|a, b| a[TF].total_cmp(&b[TF]));
        found
    }
}

/// A rendezvous's seven unknowns of a [`SpatialMinTimeVector`].
fn truncated(z: &SpatialMinTimeVector) -> SpatialMinTimeRendezvousVector {
    SpatialMinTimeRendezvousVector::from_column_slice(&z.as_slice()[..SPATIAL_MIN_TIME_RENDEZVOUS_UNKNOWNS])
}

/// A rendezvous's seven unknowns padded with a zero nu_f.
fn padded(z: &SpatialMinTimeRendezvousVector) -> SpatialMinTimeVector {
    let mut full = SpatialMinTimeVector::zeros();
    full.as_mut_slice()[..SPATIAL_MIN_TIME_RENDEZVOUS_UNKNOWNS].copy_from_slice(z.as_slice());
    full
}

/// A spatial draw seen from its departure plane: the frame of that plane (rows: its axes,
/// inertial; the departure's planar coordinates are the frame's x, y), the target orbit in the
/// frame, and the planar draw flattened into the plane.
struct DepartureView {
    problem: SpatialMinTime,
    frame: [[f64; 3]; 3],
    seen: SpatialOrbitShape,
    flat: Scenario,
    time_of_flight: f64,
}

impl DepartureView {
    fn of(scenario: &SpatialScenario, spacecraft: &CanonicalSpacecraft) -> Self {
        let problem = SpatialMinTime::from_scenario(scenario, *spacecraft);
        let plane = scenario.initial_plane;
        let (e1, e2) = (plane.to_inertial([1.0, 0.0]), plane.to_inertial([0.0, 1.0]));
        let frame = [e1, e2, shared::orbit::cross3(&e1, &e2)];
        let target = match &problem {
            SpatialMinTime::Transfer(p) => p.target,
            SpatialMinTime::Rendezvous(p) => p.target,
        };
        let seen = orbit_in_frame(&frame, &target);
        // A planar draw is its own flattened draw, to the bit.
        let flat = if scenario.is_planar() {
            scenario.scenario
        } else {
            let mut flat = scenario.scenario;
            flat.target.omega = seen.raan + seen.omega;
            flat
        };
        Self {
            problem,
            frame,
            seen,
            flat,
            time_of_flight: scenario.scenario.time_of_flight(),
        }
    }

    /// The target at s times its inclination to the departure plane (node and periapsis kept),
    /// inertial: the flattened draw's orbit at s = 0, the real one at s = 1.
    fn target_at(&self, s: f64) -> SpatialOrbitShape {
        if s >= 1.0 {
            return match &self.problem {
                SpatialMinTime::Transfer(p) => p.target,
                SpatialMinTime::Rendezvous(p) => p.target,
            };
        }
        let tilted = SpatialOrbitShape {
            inclination: s * self.seen.inclination,
            ..self.seen
        };
        let (p, q) = tilted.perifocal();
        SpatialOrbitShape::from_perifocal(
            self.seen.a,
            self.seen.e,
            &from_frame(&self.frame, &p),
            &from_frame(&self.frame, &q),
        )
    }

    /// Planar lambda_r, lambda_v (x, y each) in the departure plane, inertial.
    fn lift(&self, planar: [f64; 4]) -> [f64; 6] {
        let lr = from_frame(&self.frame, &[planar[0], planar[1], 0.0]);
        let lv = from_frame(&self.frame, &[planar[2], planar[3], 0.0]);
        [lr[0], lr[1], lr[2], lv[0], lv[1], lv[2]]
    }

    /// A planar minimum-time extremal of the flattened draw, lifted and continued in the
    /// target's inclination to the real target, then solved there at full tolerance.
    fn lift_extremal(&self, z: &MinTimeVector, options: &SolveOptions) -> Option<SpatialMinTimeVector> {
        let c = self.lift([z[0], z[1], z[2], z[3]]);
        let z0 = SpatialMinTimeVector::from_column_slice(&[c[0], c[1], c[2], c[3], c[4], c[5], z[4], z[5]]);
        let continued = match self.problem {
            SpatialMinTime::Transfer(p) => {
                let at = |s: f64| SpatialMinTimeTransfer {
                    target: self.target_at(s),
                    ..p
                };
                continue_at_energy_optimum(at, &z0, options, TILT).ok()?
            }
            SpatialMinTime::Rendezvous(p) => {
                let at = |s: f64| SpatialMinTimeRendezvous {
                    target: self.target_at(s),
                    ..p
                };
                padded(&continue_at_energy_optimum(at, &truncated(&z0), options, TILT).ok()?)
            }
        };
        self.problem.solve(&continued, &options.tolerances)
    }

    /// The flattened draw's energy-optimal start at the TOF (planar, a rendezvous's padded),
    /// lifted and continued in the target's inclination: the real draw's (a rendezvous's seven
    /// costates padded with a zero nu_f).
    fn lift_energy_start(
        &self,
        z: &crate::solver::shooting::TransferVector,
        options: &SolveOptions,
    ) -> Result<SpatialTransferVector, String> {
        let c = self.lift([z[0], z[1], z[2], z[3]]);
        let tof = self.time_of_flight;
        match self.problem {
            SpatialMinTime::Transfer(p) => {
                let at = |s: f64| SpatialTransfer {
                    departure: p.departure,
                    initial_mass: 1.0,
                    target: self.target_at(s),
                    time_of_flight: tof,
                    spacecraft: p.spacecraft,
                };
                let z0 = SpatialTransferVector::from_column_slice(&[c[0], c[1], c[2], c[3], c[4], c[5], z[4], z[5]]);
                continue_at_energy_optimum(at, &z0, options, TILT)
            }
            SpatialMinTime::Rendezvous(p) => {
                let arrival = |s: f64| {
                    body_motion3(&self.target_at(s), p.target_nu0, tof).map(|b| SpatialState {
                        r: [b.state[0], b.state[1], b.state[2]],
                        v: [b.state[3], b.state[4], b.state[5]],
                    })
                };
                // The body's coast is checked once: the tilt changes no orbit's period.
                arrival(1.0).map_err(|e| format!("the body's arrival state: {e:?}"))?;
                let at = |s: f64| SpatialRendezvous {
                    departure: p.departure,
                    initial_mass: 1.0,
                    arrival: arrival(s).unwrap_or(SpatialState {
                        r: [f64::NAN; 3],
                        v: [f64::NAN; 3],
                    }),
                    time_of_flight: tof,
                    spacecraft: p.spacecraft,
                };
                let z0 = SpatialVector::from_column_slice(&[c[0], c[1], c[2], c[3], c[4], c[5], z[4]]);
                let z = continue_at_energy_optimum(at, &z0, options, TILT)?;
                let mut full = SpatialTransferVector::zeros();
                full.as_mut_slice()[..7].copy_from_slice(z.as_slice());
                Ok(full)
            }
        }
    }

    /// The planar multi-start's extremals of the flattened draw, smallest tf first.
    fn flat_extremals(&self, options: &SolveOptions) -> Vec<MinTimeVector> {
        let spacecraft = self.problem.spacecraft();
        match self.flat.problem {
            ProblemKind::Transfer => multistart_extremals(&self.flat, spacecraft, &options.tolerances),
            ProblemKind::Rendezvous => rendezvous_multistart_extremals(&self.flat, spacecraft, &options.tolerances),
        }
    }
}

/// Classifies a spatial draw the indirect method could not solve by its minimum time of flight
/// (see the module notes), as the planar [`classify_draw`] does a planar one: `Recovered` with an
/// energy-optimal start at the TOF, `MinTime` with the smallest extremal found (infeasible when
/// tf_min > TOF, feasible below; `stopped_at` is NaN), or `Unknown` with the reasons.
pub fn classify_spatial_draw(
    scenario: &SpatialScenario,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> SpatialFeasibility {
    if let Err(e) = scenario.validate() {
        return Feasibility::Unknown(format!("invalid scenario: {e}"));
    }
    let view = DepartureView::of(scenario, spacecraft);
    let tof = view.time_of_flight;
    let mut why = Vec::new();
    let planar = match classify_draw(&view.flat, spacecraft, options) {
        Feasibility::MinTime { z, .. } => vec![z],
        Feasibility::Recovered { z } => {
            match view.lift_energy_start(&z, options) {
                Ok(z) => return Feasibility::Recovered { z },
                Err(e) => why.push(format!("the flattened draw's energy-optimal start: {e}")),
            }
            view.flat_extremals(options)
        }
        Feasibility::Unknown(w) => {
            why.push(format!("flattened draw: {w}"));
            Vec::new()
        }
    };
    let by_tf = |a: &SpatialMinTimeVector, b: &SpatialMinTimeVector| a[TF].total_cmp(&b[TF]);
    let lifted = planar
        .iter()
        .take(LIFTED_EXTREMALS)
        .filter_map(|z| view.lift_extremal(z, options))
        .min_by(by_tf);
    if lifted.is_none() {
        why.push("no planar extremal carried out of the departure plane".into());
    }
    // A lifted extremal below the TOF already decides; otherwise the direct multi-start may find
    // a shorter one on another branch (as in the plane).
    let direct = match lifted {
        Some(z) if z[TF] <= tof => None,
        _ => view.problem.multistart(tof, &options.tolerances).into_iter().next(),
    };
    match [lifted, direct].into_iter().flatten().min_by(by_tf) {
        Some(z) => Feasibility::MinTime {
            tf_min: z[TF],
            z,
            stopped_at: f64::NAN,
        },
        None => {
            why.push("minimum-time multi-start: no extremal".into());
            Feasibility::Unknown(why.join("; "))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::spatial::{hamiltonian3, propagate3};
    use shared::orbit::OrbitPlane;
    use shared::spacecraft::Spacecraft;

    fn sc() -> CanonicalSpacecraft {
        Spacecraft::MSR_ERO.canonical().unwrap()
    }

    /// The planar module's circle raise: 1 AU to 1.52 AU in 8 cycles (112 days), infeasible
    /// (its planar minimum time is 269 days); `lead` rad: a rendezvous with the body that far
    /// ahead at departure, None: the free-anomaly transfer.
    fn circle_raise(lead: Option<f64>) -> Scenario {
        let transfer = crate::solver::min_time::tests::circle_raise();
        match lead {
            None => transfer,
            Some(lead) => Scenario {
                problem: ProblemKind::Rendezvous,
                target_nu0: transfer.initial.nu + lead,
                ..transfer
            },
        }
    }

    /// `scenario` with its target orbit inclined by `degrees` (node at 1 rad).
    fn inclined(scenario: Scenario, degrees: f64) -> SpatialScenario {
        SpatialScenario {
            target_plane: OrbitPlane {
                inclination: degrees.to_radians(),
                raan: 1.0,
            },
            ..SpatialScenario::planar(scenario)
        }
    }

    fn min_time_of(result: &SpatialFeasibility) -> (f64, SpatialMinTimeVector) {
        match result {
            Feasibility::MinTime { tf_min, z, .. } => (*tf_min, *z),
            other => panic!("no minimum-time extremal: {other:?}"),
        }
    }

    /// The minimum-time Hamiltonian from the fuel problem's own [`hamiltonian3`] (an independent
    /// formula): at u = 1 along the primer its running cost is T / c, which the time's cost 1
    /// replaces.
    fn h_min_time(y: &[f64; Y3_LEN], sc: &CanonicalSpacecraft) -> f64 {
        let p = OptimalControlParams {
            spacecraft: *sc,
            eps: 0.5,
        };
        let lv: [f64; 3] = core::array::from_fn(|k| y[idx3::LV + k]);
        let alpha = lv.map(|x| -x / norm(&lv));
        1.0 + hamiltonian3(y, 1.0, alpha, &p) - sc.thrust / sc.exhaust_speed
    }

    /// A fresh flight of a spatial extremal on the fuel problem's modal propagation (u = 1 held
    /// by lambda_m(0) = 1e3, the primer from the propagated lambda_v): it must land on the
    /// target, placed by the scenario's plane and the planar orbit (not by the solver's
    /// elements), to 1e-8, with H = 0 at both ends for a transfer (transversality too) and
    /// H(tf) = lambda . d(body)/dt = H(0) for a rendezvous.
    fn fly_extremal(scenario: &SpatialScenario, sc: &CanonicalSpacecraft, z: &SpatialMinTimeVector) {
        let tolerances = Tolerances::default();
        let big = 1e3;
        let costates = SpatialVector::from_column_slice(&[z[0], z[1], z[2], z[3], z[4], z[5], big]);
        let y0 = initial_state_costate3(&scenario.departure(), 1.0, &costates);
        let p = OptimalControlParams {
            spacecraft: *sc,
            eps: 1e-3,
        };
        let y = propagate3(&p, 0.0, &y0, z[TF], &tolerances).unwrap();
        let plane = scenario.target_plane;
        let flat = &scenario.scenario;
        let (on_target, moving) = match flat.problem {
            ProblemKind::Transfer => {
                let at = |nu: f64| plane.embed(&flat.target.cartesian_at(nu));
                let (ahead, behind) = (at(z[NU_F] + 1e-5), at(z[NU_F] - 1e-5));
                let rate: Vec<f64> = (0..3)
                    .map(|k| (ahead.r[k] - behind.r[k]) / 2e-5)
                    .chain((0..3).map(|k| (ahead.v[k] - behind.v[k]) / 2e-5))
                    .collect();
                (at(z[NU_F]), rate)
            }
            ProblemKind::Rendezvous => {
                let start = flat.target.cartesian_at(flat.target_nu0);
                let body = plane.embed(&onboard::kepler::coast(&start, z[TF]).unwrap());
                let r3 = norm(&body.r).powi(3);
                let rate: Vec<f64> = body.v.iter().copied().chain(body.r.iter().map(|x| -x / r3)).collect();
                (body, rate)
            }
        };
        let target: Vec<f64> = on_target.r.iter().chain(&on_target.v).copied().collect();
        let miss = (0..6).map(|i| (y[idx3::R + i] - target[i]).abs()).fold(0.0, f64::max);
        assert!(miss < 1e-8, "the flown extremal misses the target by {miss:e}");
        let (mut first, mut last) = (y0, y);
        first[idx3::LM] = big - y[idx3::LM];
        last[idx3::LM] = 0.0;
        let (h0, h1) = (h_min_time(&first, sc), h_min_time(&last, sc));
        let pull: f64 = (0..6).map(|i| last[idx3::LR + i] * moving[i]).sum();
        match flat.problem {
            // Transversality from the orbit's rate by differences (1e-10 truncation).
            ProblemKind::Transfer => assert!(
                pull.abs() < 1e-6 && h1.abs() < 1e-8,
                "transversality {pull}, H(tf) {h1}"
            ),
            ProblemKind::Rendezvous => assert!((h1 - pull).abs() < 1e-8, "H(tf) {h1}, lambda . body rate {pull}"),
        }
        assert!((h0 - h1).abs() < 1e-8, "H(0) {h0}, H(tf) {h1}");
        // Full thrust all the way: lambda_m decreases to 0 from a positive value.
        assert!(first[idx3::LM] > 0.0 && y[idx3::M] > 0.0);
    }

    /// The circle raise's planar minimum-time extremals, as the planar classification found them
    /// (measured: tf_min 4.629914170 as a transfer, 7.496876942 as the rendezvous with lead 0.5,
    /// both at the fold of the energy-optimal family), rounded to 6 digits and solved again by the
    /// planar minimum-time Newton: the planar reference without the planar classification's 7-25
    /// s.
    fn planar_extremal(lead: Option<f64>) -> MinTimeVector {
        let sc = sc();
        let scenario = circle_raise(lead);
        let tolerances = Tolerances::default();
        match lead {
            None => {
                let guess = MinTimeVector::from_column_slice(&[-8.80955, -5.49865, 1.30168, -13.174, 4.62991, 3.75974]);
                crate::solver::min_time::solve_min_time(&scenario, &sc, &guess, &tolerances).expect("planar extremal")
            }
            Some(_) => {
                let problem = crate::solver::min_time::MinTimeRendezvous {
                    scenario: &scenario,
                    spacecraft: sc,
                };
                let guess = SVector::<f64, 5>::from_column_slice(&[-33.1004, -20.2194, -1.76795, -41.6657, 7.49688]);
                let z = newton(&problem, 1.0, &guess, &tolerances, &min_time_newton()).unwrap();
                assert!(z.converged);
                MinTimeVector::from_column_slice(&[z.z[0], z.z[1], z.z[2], z.z[3], z.z[4], 0.0])
            }
        }
    }

    /// Planar equivalence for a transfer: the circle raise embedded in three dimensions has the
    /// planar minimum time (4.629914170, 269 days, above the TOF of 112 days) to 1e-6 relative by
    /// the spatial direct multi-start alone (spatial guesses, spatial Newton, no planar code;
    /// measured: 33 extremals, all within 4e-12 of it) and by the planar extremal lifted and
    /// solved in 3D; the extremal stays in the plane and flies onto the target orbit.
    #[test]
    fn a_planar_transfer_embedded_in_three_dimensions_has_the_planar_minimum_time() {
        let sc = sc();
        let options = SolveOptions::default();
        let scenario = circle_raise(None);
        let planar = planar_extremal(None)[4];
        assert!((planar - 4.629_914_170).abs() < 1e-8, "planar tf_min {planar}");
        let embedded = SpatialScenario::planar(scenario);
        let direct =
            SpatialMinTime::from_scenario(&embedded, sc).multistart(scenario.time_of_flight(), &options.tolerances);
        let z = *direct.first().expect("the spatial multi-start finds an extremal");
        let relative = (z[TF] - planar).abs() / planar;
        assert!(
            relative < 1e-6,
            "3D multi-start {}, planar {planar} ({relative:e})",
            z[TF]
        );
        assert!(z[2].abs() < 1e-12 && z[5].abs() < 1e-12, "out-of-plane costates {z}");
        fly_extremal(&embedded, &sc, &z);
        let view = DepartureView::of(&embedded, &sc);
        let lifted = view.lift_extremal(&planar_extremal(None), &options).expect("lifted");
        assert!((lifted[TF] - planar).abs() < 1e-9 * planar, "lifted {}", lifted[TF]);
    }

    /// Planar equivalence for a rendezvous: the circle raise with the body 0.5 rad ahead, embedded
    /// in three dimensions, is classified infeasible with the planar classification's minimum
    /// time (7.496876942, 436 days) to 1e-6 relative; the spatial direct multi-start alone finds
    /// it too (measured: its smallest of 7 extremals; the planar multi-start's smallest is 9.416,
    /// another branch), and the extremal stays in the plane and meets the body.
    #[test]
    fn a_planar_rendezvous_embedded_in_three_dimensions_has_the_planar_minimum_time() {
        let sc = sc();
        let options = SolveOptions::default();
        let scenario = circle_raise(Some(0.5));
        let tof = scenario.time_of_flight();
        let Feasibility::MinTime { tf_min: planar, .. } = classify_draw(&scenario, &sc, &options) else {
            panic!("the planar classification has no extremal");
        };
        assert!(planar > tof);
        let embedded = SpatialScenario::planar(scenario);
        let result = classify_spatial_draw(&embedded, &sc, &options);
        assert!(result.infeasible(tof), "{result:?}");
        let (tf_min, z) = min_time_of(&result);
        let relative = (tf_min - planar).abs() / planar;
        assert!(relative < 1e-6, "3D {tf_min}, planar {planar} ({relative:e})");
        assert!(z[2].abs() < 1e-12 && z[5].abs() < 1e-12, "out-of-plane costates {z}");
        fly_extremal(&embedded, &sc, &z);
        let direct = SpatialMinTime::from_scenario(&embedded, sc).multistart(tof, &options.tolerances);
        let smallest = direct.first().expect("the spatial multi-start finds an extremal")[TF];
        let relative = (smallest - planar).abs() / planar;
        assert!(
            relative < 1e-6,
            "3D multi-start {smallest}, planar {planar} ({relative:e})"
        );
    }

    /// The circle raise's target inclined by 0, 2 and 5 degrees (node at 1 rad, so even 0 degrees
    /// goes through the departure-plane frames): the minimum time grows with the inclination
    /// (measured: 4.629914, 4.648627, 4.746983), 0 degrees is the planar one, and each extremal,
    /// flown with full thrust along its primer by the fuel problem's propagation, lands on the
    /// inclined orbit (placed by the scenario's plane) within the shooting tolerance.
    #[test]
    fn the_minimum_time_grows_with_the_targets_inclination() {
        let sc = sc();
        let options = SolveOptions::default();
        let planar = planar_extremal(None);
        let mut previous = 0.0;
        for degrees in [0.0, 2.0, 5.0] {
            let scenario = inclined(circle_raise(None), degrees);
            let view = DepartureView::of(&scenario, &sc);
            let z = view
                .lift_extremal(&planar, &options)
                .expect("an extremal at the inclination");
            fly_extremal(&scenario, &sc, &z);
            if degrees == 0.0 {
                assert!(
                    (z[TF] - planar[4]).abs() < 1e-9 * planar[4],
                    "{} vs {}",
                    z[TF],
                    planar[4]
                );
            }
            assert!(
                z[TF] > previous * (1.0 + 1e-3),
                "{degrees} deg: tf_min {} after {previous}",
                z[TF]
            );
            previous = z[TF];
        }
    }

    /// The classification agrees with the fuel solver on an inclined rendezvous (the circle raise
    /// with the body 0.5 rad ahead, its orbit inclined by 5 degrees): at 112 days it is infeasible
    /// (the minimum time, 7.508700 measured, above the planar 7.496877, passes the flight check);
    /// with the time of flight 1.3 tf_min the three-dimensional fuel solver solves it and the
    /// classification recovers an energy-optimal start (the flattened draw's, carried out of the
    /// plane) that solves the spatial rendezvous at eps = 1.
    #[test]
    fn the_classification_of_an_inclined_rendezvous_agrees_with_the_fuel_solver() {
        let sc = sc();
        let options = SolveOptions::default();
        let short = SpatialScenario {
            target_plane: OrbitPlane {
                inclination: 5f64.to_radians(),
                raan: 0.0,
            },
            ..SpatialScenario::planar(circle_raise(Some(0.5)))
        };
        let result = classify_spatial_draw(&short, &sc, &options);
        assert!(result.infeasible(short.scenario.time_of_flight()), "{result:?}");
        let (tf_min, z) = min_time_of(&result);
        assert!(tf_min > 7.496_876_9, "tf_min {tf_min} not above the planar one");
        fly_extremal(&short, &sc, &z);
        let mut long = short;
        long.scenario.steps = (1.3 * tf_min / long.scenario.cycle).ceil() as u32;
        let goal = crate::spatial::SpatialGoal::of_scenario(&long, sc).unwrap();
        let solved = goal.solve(&options).expect("the fuel solver solves the longer flight");
        assert!(solved.solution.residual < 1e-8 && solved.solution.final_mass > 0.5);
        let result = classify_spatial_draw(&long, &sc, &options);
        assert!(!result.infeasible(long.scenario.time_of_flight()), "{result:?}");
        let Feasibility::Recovered { z } = result else {
            panic!("no energy-optimal start at 1.3 tf_min: {result:?}");
        };
        let problem = SpatialRendezvous::from_scenario(&long, sc).unwrap();
        let costates = SpatialVector::from_column_slice(&z.as_slice()[..7]);
        let f = problem.residual_only(1.0, &costates, &options.tolerances).unwrap();
        assert!(f.amax() < 1e-8, "eps = 1 residual of the recovered start {f}");
    }

    /// The spatial minimum-time Jacobians against central differences of their residuals.
    #[test]
    fn spatial_min_time_jacobians_match_central_differences() {
        let tol = Tolerances {
            relative: 1e-13,
            absolute: 1e-14,
            ..Tolerances::default()
        };
        let scenario = inclined(circle_raise(Some(0.5)), 5.0);
        let z = SpatialMinTimeVector::from_column_slice(&[-0.8, 0.3, 0.1, 0.4, -1.1, -0.2, 2.7, 2.2]);
        for problem in [
            SpatialMinTime::from_scenario(&scenario, sc()),
            SpatialMinTime::from_scenario(&inclined(circle_raise(None), 5.0), sc()),
        ] {
            let h = 1e-6;
            let jacobian = |z: &SpatialMinTimeVector| match problem {
                SpatialMinTime::Transfer(p) => p.residual(1.0, z, &tol).unwrap().1,
                SpatialMinTime::Rendezvous(p) => {
                    let j = p.residual(1.0, &truncated(z), &tol).unwrap().1;
                    nalgebra::SMatrix::<f64, 8, 8>::from_fn(|i, k| if i < 7 && k < 7 { j[(i, k)] } else { 0.0 })
                }
            };
            let jac = jacobian(&z);
            let n = match problem {
                SpatialMinTime::Transfer(_) => 8,
                SpatialMinTime::Rendezvous(_) => 7,
            };
            for k in 0..n {
                let (mut zp, mut zm) = (z, z);
                zp[k] += h;
                zm[k] -= h;
                let fd = (problem.residual(&zp, &tol).unwrap() - problem.residual(&zm, &tol).unwrap()) / (2.0 * h);
                for i in 0..n {
                    assert!(
                        (jac[(i, k)] - fd[i]).abs() < 1e-6 * (1.0 + fd[i].abs()),
                        "dF{i}/dz{k}: {} vs {}",
                        jac[(i, k)],
                        fd[i]
                    );
                }
            }
        }
    }
}
