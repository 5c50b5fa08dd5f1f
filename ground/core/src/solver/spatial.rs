//! The indirect method in three dimensions (docs/spec.md section 3.6): the state-costate of
//! section 3.1 with out-of-plane components, its exact sensitivities, and the rendezvous that
//! meets a given arrival state at a fixed time, solved by the multi-start and energy-to-fuel
//! homotopy of the planar solver.
//!
//! State + costate y = (r, v, m, lambda_r, lambda_v, lambda_m), 14 components, r and v in an
//! inertial frame of the central body. The right-hand side is the planar one's written for
//! three components, generic over a dual-number type, so the variational equations come out
//! exact by forward-mode differentiation of the same code. A planar problem embedded with zero
//! out-of-plane components stays in its plane (every out-of-plane derivative is a product with
//! an out-of-plane component), which [`lift_planar`] and the planar-equivalence tests use.

use nalgebra::{Const, DimMin, SMatrix, SVector};
use num_dual::{DualNum, DualVec64};
use onboard::integrator::{IntegrationError, Tolerances};
use shared::scenario::{Scenario, SpatialScenario};
use shared::spacecraft::CanonicalSpacecraft;

use super::pontryagin::{
    run_modal, variational_rhs, BranchRhs, NoClock, OptimalControlParams, Regime, SwitchingLayout,
    SENSITIVITY_STEP_WORK,
};
use super::shooting::{body_at, RendezvousVector, ShootingProblem};
use super::{solve_multistart, SolveOptions};

/// State + costate length in three dimensions.
pub const Y3_LEN: usize = 14;
/// Unknowns of the spatial rendezvous: the seven initial costates.
pub const SPATIAL_UNKNOWNS: usize = 7;
/// State + costate + the 14 x 7 sensitivity to the initial costates (column-major after the
/// first 14).
pub const YS3_LEN: usize = Y3_LEN + Y3_LEN * SPATIAL_UNKNOWNS;
/// The spatial rendezvous's unknowns: lambda_r, lambda_v (three components each) and lambda_m
/// at t = 0, canonical.
pub type SpatialVector = SVector<f64, SPATIAL_UNKNOWNS>;

/// Indices into the spatial y.
pub mod idx3 {
    /// Position (x, y, z): `y[0..3]`.
    pub const R: usize = 0;
    /// Velocity: `y[3..6]`.
    pub const V: usize = 3;
    /// Mass, fraction of m0: `y[6]`.
    pub const M: usize = 6;
    /// Position costate: `y[7..10]`.
    pub const LR: usize = 7;
    /// Velocity costate: `y[10..13]`.
    pub const LV: usize = 10;
    /// Mass costate: `y[13]`.
    pub const LM: usize = 13;
}

pub use shared::orbit::SpatialState;
use shared::orbit::{dot3 as dot, norm3 as norm};

/// Switching function rho = lambda_m + c |lambda_v| / m - 1.
pub fn switching_function3<D: DualNum<Primitive = f64> + Copy>(y: &[D; Y3_LEN], exhaust_speed: f64) -> D {
    let lv = (y[idx3::LV] * y[idx3::LV] + y[idx3::LV + 1] * y[idx3::LV + 1] + y[idx3::LV + 2] * y[idx3::LV + 2]).sqrt();
    y[idx3::LM] + lv * exhaust_speed / y[idx3::M] - 1.0
}

/// d rho / dt = -(c / m) lambda_v . lambda_r / |lambda_v| (independent of the throttle).
pub fn switching_rate3(y: &[f64; Y3_LEN], exhaust_speed: f64) -> f64 {
    let lv: [f64; 3] = core::array::from_fn(|k| y[idx3::LV + k]);
    let lr: [f64; 3] = core::array::from_fn(|k| y[idx3::LR + k]);
    -exhaust_speed * dot(&lv, &lr) / (y[idx3::M] * norm(&lv))
}

/// dy/dt of the spatial state-costate system on one branch of the throttle law (see
/// [`super::pontryagin::state_costate_rhs_in`] for why the branch is held).
pub fn state_costate_rhs3_in<D: DualNum<Primitive = f64> + Copy>(
    y: &[D; Y3_LEN],
    p: &OptimalControlParams,
    regime: Regime,
) -> [D; Y3_LEN] {
    let (t_max, c) = (p.spacecraft.thrust, p.spacecraft.exhaust_speed);
    let r: [D; 3] = core::array::from_fn(|k| y[idx3::R + k]);
    let lv: [D; 3] = core::array::from_fn(|k| y[idx3::LV + k]);
    let m = y[idx3::M];
    let r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    let rn = r2.sqrt();
    let r3 = r2 * rn;
    let r5 = r3 * r2;
    let lvn = (lv[0] * lv[0] + lv[1] * lv[1] + lv[2] * lv[2]).sqrt();
    let u = regime.throttle(switching_function3(y, c), p.eps);
    // Primer vector: thrust opposite lambda_v.
    let acc = u * t_max / m;
    let r_dot_lv = r[0] * lv[0] + r[1] * lv[1] + r[2] * lv[2];
    let mut f = [D::from(0.0); Y3_LEN];
    for k in 0..3 {
        f[idx3::R + k] = y[idx3::V + k];
        f[idx3::V + k] = -r[k] / r3 - acc * lv[k] / lvn;
        f[idx3::LR + k] = lv[k] / r3 - r[k] * r_dot_lv * 3.0 / r5;
        f[idx3::LV + k] = -y[idx3::LR + k];
    }
    f[idx3::M] = -u * t_max / c;
    f[idx3::LM] = -u * t_max * lvn / (m * m);
    f
}

/// [`state_costate_rhs3_in`] on the branch the switching function selects.
pub fn state_costate_rhs3<D: DualNum<Primitive = f64> + Copy>(
    y: &[D; Y3_LEN],
    p: &OptimalControlParams,
) -> [D; Y3_LEN] {
    let regime = Regime::of(switching_function3(y, p.spacecraft.exhaust_speed).re(), p.eps);
    state_costate_rhs3_in(y, p, regime)
}

/// The Hamiltonian for an arbitrary control (u, alpha): the tests check the costate equations
/// and the optimal control against it, independently of the code above.
pub fn hamiltonian3(y: &[f64; Y3_LEN], u: f64, alpha: [f64; 3], p: &OptimalControlParams) -> f64 {
    let (t_max, c) = (p.spacecraft.thrust, p.spacecraft.exhaust_speed);
    let r: [f64; 3] = core::array::from_fn(|k| y[idx3::R + k]);
    let rn = norm(&r);
    let m = y[idx3::M];
    let mut h = t_max / c * (u - p.eps * u * (1.0 - u)) - y[idx3::LM] * t_max * u / c;
    for k in 0..3 {
        let g = -r[k] / rn.powi(3);
        h += y[idx3::LR + k] * y[idx3::V + k] + y[idx3::LV + k] * (g + t_max * u * alpha[k] / m);
    }
    h
}

/// The spatial state-costate's layout for the modal propagation.
pub(crate) struct Spatial;

impl SwitchingLayout for Spatial {
    fn rho(ys: &[f64], exhaust_speed: f64) -> f64 {
        let y: [f64; Y3_LEN] = core::array::from_fn(|i| ys[i]);
        switching_function3(&y, exhaust_speed)
    }

    fn rate(ys: &[f64], exhaust_speed: f64) -> f64 {
        let y: [f64; Y3_LEN] = core::array::from_fn(|i| ys[i]);
        switching_rate3(&y, exhaust_speed)
    }
}

struct PlainRhs3(OptimalControlParams);

impl BranchRhs<Y3_LEN> for PlainRhs3 {
    type Layout = Spatial;

    fn rhs(&self, y: &[f64; Y3_LEN], regime: Regime, dydt: &mut [f64; Y3_LEN]) {
        *dydt = state_costate_rhs3_in(y, &self.0, regime);
    }
}

type Dual7 = DualVec64<Const<SPATIAL_UNKNOWNS>>;

struct SensitivityRhs3(OptimalControlParams);

impl BranchRhs<YS3_LEN> for SensitivityRhs3 {
    type Layout = Spatial;

    fn rhs(&self, ys: &[f64; YS3_LEN], regime: Regime, dydt: &mut [f64; YS3_LEN]) {
        variational_rhs::<Y3_LEN, SPATIAL_UNKNOWNS>(
            ys,
            |y: &[Dual7; Y3_LEN]| state_costate_rhs3_in(y, &self.0, regime),
            dydt,
        );
    }
}

/// Propagates the spatial state-costate system from (t0, y0) to t1, stepping onto every switch
/// and holding the throttle branch in between, as the planar [`super::pontryagin::propagate`].
pub fn propagate3(
    params: &OptimalControlParams,
    t0: f64,
    y0: &[f64; Y3_LEN],
    t1: f64,
    tolerances: &Tolerances,
) -> Result<[f64; Y3_LEN], IntegrationError> {
    run_modal(PlainRhs3(*params), params, t0, y0, t1, tolerances, 1, &mut NoClock)
}

/// [`propagate3`] from t = 0 with the sensitivity d y / d lambda_0 (14 x 7, column k after the
/// first 14 components at `14 + 14 k`).
pub fn propagate_sensitivity3(
    params: &OptimalControlParams,
    y0: &[f64; Y3_LEN],
    t1: f64,
    tolerances: &Tolerances,
) -> Result<[f64; YS3_LEN], IntegrationError> {
    let mut ys0 = [0.0; YS3_LEN];
    ys0[..Y3_LEN].copy_from_slice(y0);
    for k in 0..SPATIAL_UNKNOWNS {
        ys0[Y3_LEN + k * Y3_LEN + idx3::LR + k] = 1.0;
    }
    run_modal(
        SensitivityRhs3(*params),
        params,
        0.0,
        &ys0,
        t1,
        tolerances,
        SENSITIVITY_STEP_WORK,
        &mut NoClock,
    )
}

/// A rendezvous in three dimensions: from `departure` (with `initial_mass`) to `arrival` at
/// exactly `time_of_flight`, mass-optimal. Terminal conditions (7): r(tf), v(tf) equal the arrival
/// state, lambda_m(tf) = 0; unknowns: the seven initial costates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpatialRendezvous {
    /// State at t = 0.
    pub departure: SpatialState,
    /// Mass at t = 0, fraction of the mass the spacecraft's thrust is scaled by (1 at the
    /// mission's departure; less for a re-plan from mid-flight).
    pub initial_mass: f64,
    /// State to meet at t = `time_of_flight`.
    pub arrival: SpatialState,
    /// Time of flight (t*).
    pub time_of_flight: f64,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
}

impl SpatialRendezvous {
    /// The rendezvous `scenario` poses: the arrival is the body's state at the end of the
    /// flight, on the target orbit in its plane.
    pub fn from_scenario(
        scenario: &SpatialScenario,
        spacecraft: CanonicalSpacecraft,
    ) -> Result<Self, IntegrationError> {
        let flat = &scenario.scenario;
        let end = body_at(flat, flat.time_of_flight())?;
        Ok(Self {
            departure: scenario.departure(),
            initial_mass: 1.0,
            arrival: scenario.target_plane.embed(&end),
            time_of_flight: flat.time_of_flight(),
            spacecraft,
        })
    }

    /// The initial state-costate for initial costates `z`.
    pub fn initial_state_costate(&self, z: &SpatialVector) -> [f64; Y3_LEN] {
        initial_state_costate3(&self.departure, self.initial_mass, z)
    }

    fn params(&self, eps: f64) -> OptimalControlParams {
        OptimalControlParams {
            spacecraft: self.spacecraft,
            eps,
        }
    }

    fn terminal(&self, y: &[f64]) -> SpatialVector {
        let a = &self.arrival;
        SpatialVector::from_column_slice(&[
            y[idx3::R] - a.r[0],
            y[idx3::R + 1] - a.r[1],
            y[idx3::R + 2] - a.r[2],
            y[idx3::V] - a.v[0],
            y[idx3::V + 1] - a.v[1],
            y[idx3::V + 2] - a.v[2],
            y[idx3::LM],
        ])
    }

    /// The final state-costate of the trajectory of costates `z` at homotopy parameter `eps`.
    pub fn final_state_costate(
        &self,
        eps: f64,
        z: &SpatialVector,
        tolerances: &Tolerances,
    ) -> Result<[f64; Y3_LEN], IntegrationError> {
        propagate3(
            &self.params(eps),
            0.0,
            &self.initial_state_costate(z),
            self.time_of_flight,
            tolerances,
        )
    }
}

impl ShootingProblem<SPATIAL_UNKNOWNS> for SpatialRendezvous {
    fn residual_only(
        &self,
        eps: f64,
        z: &SpatialVector,
        tolerances: &Tolerances,
    ) -> Result<SpatialVector, IntegrationError> {
        Ok(self.terminal(&self.final_state_costate(eps, z, tolerances)?))
    }

    fn residual(
        &self,
        eps: f64,
        z: &SpatialVector,
        tolerances: &Tolerances,
    ) -> Result<(SpatialVector, SMatrix<f64, SPATIAL_UNKNOWNS, SPATIAL_UNKNOWNS>), IntegrationError> {
        let ys = propagate_sensitivity3(
            &self.params(eps),
            &self.initial_state_costate(z),
            self.time_of_flight,
            tolerances,
        )?;
        const ROWS: [usize; SPATIAL_UNKNOWNS] = [
            idx3::R,
            idx3::R + 1,
            idx3::R + 2,
            idx3::V,
            idx3::V + 1,
            idx3::V + 2,
            idx3::LM,
        ];
        let jac = SMatrix::from_fn(|i, k| ys[Y3_LEN + k * Y3_LEN + ROWS[i]]);
        Ok((self.terminal(&ys), jac))
    }
}

/// The state-costate at departure: the state, `mass`, and the initial costates `z`.
pub fn initial_state_costate3(departure: &SpatialState, mass: f64, z: &SpatialVector) -> [f64; Y3_LEN] {
    let (r, v) = (departure.r, departure.v);
    [
        r[0], r[1], r[2], v[0], v[1], v[2], mass, z[0], z[1], z[2], z[3], z[4], z[5], z[6],
    ]
}

/// Planar rendezvous unknowns (lambda_x, lambda_y, lambda_vx, lambda_vy, lambda_m) embedded in
/// three dimensions with zero out-of-plane costates.
pub fn lift_planar(z: &RendezvousVector) -> SpatialVector {
    SpatialVector::from_column_slice(&[z[0], z[1], 0.0, z[2], z[3], 0.0, z[4]])
}

/// Physics-shaped energy-optimal guesses, the planar solver's rendezvous starts (docs/spec.md
/// section 3.3) in the departure orbit's plane: lambda_r along -r_hat, lambda_v along -+theta_hat
/// (the primer along the velocity for a raise, against it for a lowering, then the other sign),
/// several magnitudes, out-of-plane costates zero.
pub fn spatial_guesses(problem: &SpatialRendezvous) -> Vec<SpatialVector> {
    let semi_major = |s: &SpatialState| -0.5 / s.energy();
    costate_guesses(
        &problem.departure,
        semi_major(&problem.arrival) >= semi_major(&problem.departure),
    )
}

/// The costate shapes of [`spatial_guesses`] from `departure`, the primer first along the
/// velocity when `raise`, against it otherwise.
pub(crate) fn costate_guesses(departure: &SpatialState, raise: bool) -> Vec<SpatialVector> {
    // A departure without an orbit plane has no guesses: the fallbacks then say why.
    let Some([r_hat, theta_hat, _]) = departure.rtn_frame() else {
        return Vec::new();
    };
    let raise = if raise { 1.0 } else { -1.0 };
    let mut guesses = Vec::new();
    for (k_r, k_v) in [(0.3, 0.3), (0.1, 0.1), (1.0, 1.0), (0.3, 0.1)] {
        for sign in [raise, -raise] {
            guesses.push(SpatialVector::from_column_slice(&[
                -k_r * r_hat[0],
                -k_r * r_hat[1],
                -k_r * r_hat[2],
                -sign * k_v * theta_hat[0],
                -sign * k_v * theta_hat[1],
                -sign * k_v * theta_hat[2],
                0.05,
            ]));
        }
    }
    guesses
}

/// A solved spatial rendezvous.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpatialSolution {
    /// Initial costates (lambda_r, lambda_v, lambda_m).
    pub costates: SpatialVector,
    /// The homotopy level reached.
    pub final_eps: f64,
    /// Largest terminal residual of a fresh propagation at `final_eps` (canonical, max norm).
    pub residual: f64,
    /// Final mass, fraction of m0 (the mass the thrust is scaled by).
    pub final_mass: f64,
    /// Distinct energy-optimal solutions found by the multi-start.
    pub distinct_energy_optima: u32,
}

/// Why a spatial rendezvous was not solved.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpatialSolveError {
    /// A state is not finite or sits at the centre, or the time of flight is not positive.
    #[error("invalid problem: {0}")]
    Invalid(&'static str),
    /// No start converged at eps = 1, or every homotopy failed.
    #[error("{0}")]
    NotSolved(String),
    /// The homotopy stopped above the final level.
    #[error("homotopy stalled below eps = {eps:.3e}{}", if *.budget_spent { " (work budget spent)" } else { "" })]
    Stalled {
        /// The last level reached.
        eps: f64,
        /// Whether the work budget ran out.
        budget_spent: bool,
    },
}

/// What the spatial driver ([`solve_spatial`]) needs of a problem beyond its residual.
pub(crate) trait SpatialShooting<const K: usize>: ShootingProblem<K> {
    /// Why the problem cannot be posed, if it cannot.
    fn invalid(&self) -> Option<&'static str>;
    /// The multi-start's own guesses at eps = 1.
    fn guesses(&self) -> Vec<SVector<f64, K>>;
    /// The final state-costate of unknowns `z` at `eps`.
    fn final_state_costate(
        &self,
        eps: f64,
        z: &SVector<f64, K>,
        tolerances: &Tolerances,
    ) -> Result<[f64; Y3_LEN], IntegrationError>;
    /// The terminal conditions at the final state-costate `y` of unknowns `z`: what
    /// [`ShootingProblem::residual_only`] returns after propagating.
    fn terminal_of(&self, y: &[f64; Y3_LEN], z: &SVector<f64, K>) -> SVector<f64, K>;
    /// An energy-optimal start from the planar fallbacks on the problem flattened into the
    /// departure plane, carried out of the plane by continuation.
    fn start_from_flattened(&self, options: &SolveOptions) -> Result<SVector<f64, K>, String>;
    /// Each start's homotopy budget.
    fn homotopy_work(&self, options: &SolveOptions) -> u64;
}

/// The solution of [`solve_spatial`]: unknowns, level, fresh residual, final mass, distinct
/// energy optima.
pub(crate) struct SpatialSolved<const K: usize> {
    pub(crate) z: SVector<f64, K>,
    pub(crate) eps: f64,
    pub(crate) residual: f64,
    pub(crate) final_mass: f64,
    pub(crate) distinct: u32,
}

/// Solves a spatial problem as the planar solver solves one (docs/spec.md sections 3.3, 3.6):
/// the multi-start of `guesses` at eps = 1 (the problem's own when empty), every distinct energy
/// optimum continued to the final level, the largest final mass kept, the flattened problem's
/// start where no guess converges; then a fresh propagation checks the terminal conditions.
pub(crate) fn solve_spatial<P: SpatialShooting<K>, const K: usize>(
    problem: &P,
    guesses: Vec<SVector<f64, K>>,
    options: &SolveOptions,
) -> Result<SpatialSolved<K>, SpatialSolveError>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    if let Some(why) = problem.invalid() {
        return Err(SpatialSolveError::Invalid(why));
    }
    let guesses = if guesses.is_empty() { problem.guesses() } else { guesses };
    let mass = |z: &SVector<f64, K>, eps: f64| {
        problem
            .final_state_costate(eps, z, &options.tolerances)
            .ok()
            .map(|y| y[idx3::M])
    };
    let work = problem.homotopy_work(options);
    let mut solved = solve_multistart(problem, guesses, options, work, &mass);
    // No guess converged at eps = 1: the planar solver's own fallbacks on the problem flattened
    // into the departure plane, then continuation out of that plane.
    if matches!(solved, Err((_, 0))) && options.fallbacks.continuation() {
        let flat = match problem.start_from_flattened(options) {
            Ok(z) => match solve_multistart(problem, vec![z], options, work, &mass) {
                Err((from_flat, 0)) => Err(format!("; from the flattened problem's start: {from_flat}")),
                other => Ok(other),
            },
            Err(flat_why) => Err(format!("; {flat_why}")),
        };
        match flat {
            Ok(other) => solved = other,
            Err(more) => {
                if let Err((why, _)) = &mut solved {
                    why.push_str(&more);
                }
            }
        }
    }
    let solved = solved.map_err(|(why, _)| SpatialSolveError::NotSolved(why))?;
    if !solved.reached_final {
        return Err(SpatialSolveError::Stalled {
            eps: solved.level.eps,
            budget_spent: solved.budget_spent,
        });
    }
    let z = solved.level.outcome.z;
    let eps = solved.level.eps;
    // One fresh propagation gives both the acceptance residual and the final mass.
    let end = problem
        .final_state_costate(eps, &z, &options.tolerances)
        .map_err(|e| SpatialSolveError::NotSolved(format!("the solution's propagation failed: {e:?}")))?;
    let residual = problem.terminal_of(&end, &z).amax();
    if residual > options.newton.tolerance {
        return Err(SpatialSolveError::NotSolved(format!(
            "a fresh propagation misses the target by {residual:.3e}"
        )));
    }
    Ok(SpatialSolved {
        z,
        eps,
        residual,
        final_mass: end[idx3::M],
        distinct: solved.distinct,
    })
}

impl SpatialShooting<SPATIAL_UNKNOWNS> for SpatialRendezvous {
    fn invalid(&self) -> Option<&'static str> {
        if !(self.departure.is_valid() && self.arrival.is_valid()) {
            return Some("a state is not finite or sits at the centre");
        }
        if !(self.time_of_flight.is_finite() && self.time_of_flight > 0.0) {
            return Some("the time of flight is not positive");
        }
        if !(self.initial_mass.is_finite() && self.initial_mass > 0.0) {
            return Some("the initial mass is not positive");
        }
        None
    }

    fn guesses(&self) -> Vec<SpatialVector> {
        spatial_guesses(self)
    }

    fn final_state_costate(
        &self,
        eps: f64,
        z: &SpatialVector,
        tolerances: &Tolerances,
    ) -> Result<[f64; Y3_LEN], IntegrationError> {
        SpatialRendezvous::final_state_costate(self, eps, z, tolerances)
    }

    fn terminal_of(&self, y: &[f64; Y3_LEN], _z: &SpatialVector) -> SpatialVector {
        self.terminal(y)
    }

    fn start_from_flattened(&self, options: &SolveOptions) -> Result<SpatialVector, String> {
        start_from_flattened(self, options)
    }

    fn homotopy_work(&self, options: &SolveOptions) -> u64 {
        options.max_homotopy_work
    }
}

/// Solves a spatial rendezvous as the planar solver solves one (docs/spec.md sections 3.3, 3.6),
/// from `guesses` ([`spatial_guesses`] when empty).
pub fn solve_spatial_rendezvous(
    problem: &SpatialRendezvous,
    guesses: Vec<SpatialVector>,
    options: &SolveOptions,
) -> Result<SpatialSolution, SpatialSolveError> {
    let solved = solve_spatial(problem, guesses, options)?;
    Ok(SpatialSolution {
        costates: solved.z,
        final_eps: solved.eps,
        residual: solved.residual,
        final_mass: solved.final_mass,
        distinct_energy_optima: solved.distinct,
    })
}

/// An orthonormal frame (rows e1, e2, e3) with e3 along the departure's angular momentum and e1
/// along its position (its RTN frame): the departure orbit's plane is the frame's xy-plane.
fn departure_frame(departure: &SpatialState) -> Option<[[f64; 3]; 3]> {
    departure.rtn_frame()
}

fn to_frame(frame: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    core::array::from_fn(|i| dot(&frame[i], v))
}

fn from_frame(frame: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    core::array::from_fn(|k| frame[0][k] * v[0] + frame[1][k] * v[1] + frame[2][k] * v[2])
}

/// Guidance cycles the flattened problem is cut into: only the direct transcription's mesh
/// ([`direct::indirect_start`](super::direct::indirect_start)) depends on them.
const FLAT_CYCLES: u32 = 25;

/// The problem flattened into the departure orbit's plane: the planar rendezvous whose arrival is
/// the arrival state's in-plane part, as a scenario (elements, the body's anomaly at t = 0).
fn flattened_scenario(problem: &SpatialRendezvous, frame: &[[f64; 3]; 3]) -> Option<Scenario> {
    use shared::orbit::CartesianState;
    use shared::scenario::ProblemKind;
    let planar = |s: &SpatialState| {
        let (r, v) = (to_frame(frame, &s.r), to_frame(frame, &s.v));
        CartesianState {
            r: [r[0], r[1]],
            v: [v[0], v[1]],
        }
    };
    let initial = planar(&problem.departure).elements()?;
    let arrival = planar(&problem.arrival);
    let target = arrival.elements()?.shape;
    let at_departure = onboard::kepler::coast(&arrival, -problem.time_of_flight).ok()?;
    let scenario = Scenario {
        problem: ProblemKind::Rendezvous,
        initial,
        target,
        target_nu0: at_departure.elements()?.nu,
        steps: FLAT_CYCLES,
        cycle: problem.time_of_flight / f64::from(FLAT_CYCLES),
    };
    scenario.validate().is_ok().then_some(scenario)
}

/// An energy-optimal (eps = 1) start from the planar solver's fallbacks (docs/spec.md section
/// 3.3: continuation in the target from the departure orbit, then the direct transcription's
/// multipliers) on the flattened problem, lifted into three dimensions, then carried to the real
/// arrival by continuation in its out-of-plane components.
fn start_from_flattened(problem: &SpatialRendezvous, options: &SolveOptions) -> Result<SpatialVector, String> {
    let frame = departure_frame(&problem.departure).ok_or("the departure has no orbital plane")?;
    let scenario = flattened_scenario(problem, &frame).ok_or("the flattened problem is not a bound rendezvous")?;
    let planar = match super::continuation::rendezvous_start_either_way(&scenario, &problem.spacecraft, options) {
        Ok(z) => z,
        Err(_) if !options.fallbacks.direct() => {
            return Err("the flattened problem's continuation in the target stopped".to_string())
        }
        Err(_) => match super::direct::indirect_start(&scenario, &problem.spacecraft) {
            Ok((l, _)) => RendezvousVector::from_column_slice(&l),
            Err(e) => return Err(format!("the flattened problem has no start either: {e}")),
        },
    };
    let lift = |v: [f64; 2]| from_frame(&frame, &[v[0], v[1], 0.0]);
    let (lr, lv) = (lift([planar[0], planar[1]]), lift([planar[2], planar[3]]));
    let z0 = SpatialVector::from_column_slice(&[lr[0], lr[1], lr[2], lv[0], lv[1], lv[2], planar[4]]);
    let (r_in, v_in) = (
        to_frame(&frame, &problem.arrival.r),
        to_frame(&frame, &problem.arrival.v),
    );
    let at = |s: f64| SpatialRendezvous {
        arrival: SpatialState {
            r: from_frame(&frame, &[r_in[0], r_in[1], s * r_in[2]]),
            v: from_frame(&frame, &[v_in[0], v_in[1], s * v_in[2]]),
        },
        ..*problem
    };
    continue_at_energy_optimum(at, &z0, options, "the arrival's out-of-plane components")
}

/// Carries the energy-optimal (eps = 1) solution `z0` of `at(0)` to one of `at(1)` by Newton
/// continuation in s (the step doubled after a success, halved after a failure, down to 1/256);
/// `what` names the parameter in the error.
pub(crate) fn continue_at_energy_optimum<P: ShootingProblem<K>, const K: usize>(
    at: impl Fn(f64) -> P,
    z0: &SVector<f64, K>,
    options: &SolveOptions,
    what: &str,
) -> Result<SVector<f64, K>, String>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    let tolerances = options.start_tolerances();
    let solve = |s: f64, guess: &SVector<f64, K>| {
        super::shooting::newton(&at(s), 1.0, guess, &tolerances, &options.start_newton)
            .ok()
            .filter(|o| o.converged)
            .map(|o| o.z)
    };
    let mut z = solve(0.0, z0).ok_or("the lifted planar start does not solve the flattened problem")?;
    let (mut s, mut ds) = (0.0f64, 1.0f64);
    while s < 1.0 {
        let next = (s + ds).min(1.0);
        match solve(next, &z) {
            Some(found) => {
                (s, z) = (next, found);
                ds = (2.0 * ds).min(1.0);
            }
            None if ds > 1.0 / 256.0 => ds *= 0.5,
            None => return Err(format!("continuation in {what} stopped at s = {s:.3}")),
        }
    }
    Ok(z)
}

/// The optimal control along a solution: throttle and unit thrust direction at state-costate y.
pub fn optimal_control3(y: &[f64; Y3_LEN], params: &OptimalControlParams) -> (f64, [f64; 3]) {
    let rho = switching_function3(y, params.spacecraft.exhaust_speed);
    let u = Regime::of(rho, params.eps).throttle(rho, params.eps);
    let lv: [f64; 3] = core::array::from_fn(|k| y[idx3::LV + k]);
    let n = norm(&lv);
    (u, lv.map(|x| -x / n))
}

/// One sample of a spatial solution.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SpatialSample {
    /// Time since departure (t*).
    pub t: f64,
    /// State.
    pub state: SpatialState,
    /// Mass, fraction of m0.
    pub m: f64,
    /// Throttle in [0, 1].
    pub throttle: f64,
    /// Unit thrust direction (the primer vector).
    pub direction: [f64; 3],
}

/// Samples the solution at `times` (sorted, from 0), propagating from one sample to the next:
/// the integration restarts at every sample, so no interpolation error enters (as the planar
/// records are sampled).
pub fn sample_solution(
    problem: &SpatialRendezvous,
    solution: &SpatialSolution,
    times: &[f64],
    tolerances: &Tolerances,
) -> Result<Vec<SpatialSample>, IntegrationError> {
    let params = problem.params(solution.final_eps);
    let (mut t, mut y) = (0.0, problem.initial_state_costate(&solution.costates));
    let mut samples = Vec::with_capacity(times.len());
    for &ti in times {
        debug_assert!(ti >= t, "sample times must be sorted");
        if ti > t {
            y = propagate3(&params, t, &y, ti, tolerances)?;
            t = ti;
        }
        let (throttle, direction) = optimal_control3(&y, &params);
        samples.push(SpatialSample {
            t,
            state: SpatialState {
                r: core::array::from_fn(|k| y[idx3::R + k]),
                v: core::array::from_fn(|k| y[idx3::V + k]),
            },
            m: y[idx3::M],
            throttle,
            direction,
        });
    }
    Ok(samples)
}

pub mod direct;
pub mod min_time;
pub mod record;
mod transfer;
pub use transfer::{
    lift_planar_transfer, solve_spatial_transfer, spatial_transfer_guesses, SpatialOrbitShape, SpatialTransfer,
    SpatialTransferSolution, SpatialTransferVector, SPATIAL_TRANSFER_UNKNOWNS,
};

#[cfg(test)]
mod tests;
