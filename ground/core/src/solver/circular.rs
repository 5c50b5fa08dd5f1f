//! Fuel-optimal transfers between nearly circular orbits (transfer-circular, docs/spec.md section 4),
//! solved at eps = 0 by structure-fixed shooting (see docs/design/solver.md for
//! the measurements behind every choice here).
//!
//! Why not the specification's homotopy: between circular orbits with a free final anomaly and a flight
//! longer than the transfer needs, the burn pattern can be shifted along the circles at no cost
//! (exactly for e = 0; e = 1e-4 changes the final mass by ~1e-6 relative over the whole shift
//! range). And the switching function of the fuel-optimal extremal stays tiny: its peaks on the
//! burns are 1e-7 to 3e-4 (the smaller the change of radius, the smaller), so at the specification's final
//! eps = 2^-14 = 6.1e-5 the smoothed extremal of most draws is not near bang-bang at all: it
//! spreads a low throttle over much of the flight with rho hugging -eps, where single shooting has
//! Jacobians of ~1e6 and a Newton basin of ~1e-8. The eps = 0 problem itself is well posed once
//! the throttle structure is fixed (coast, burn, coast, burn, coast) and the switching times are
//! unknowns, with the shift pinned: it converges in 2 to 4 Newton iterations from a Hohmann guess.
//!
//! The solve:
//! 1. Shift scan: the Hohmann transfer made of finite burns, its first burn centred at a few
//!    times across the flight, each solved with its first switching time pinned (the
//!    transversality condition left out).
//! 2. The transversality residual of each scanned solution is proportional to d m_f / d nu_f.
//!    Where it changes sign between neighbours (a maximum of the final mass along the shift), a
//!    regula falsi on the pinned time zeroes it. Where the mass keeps rising to an end of the
//!    scan, the optimum has no coast at that end: the structure without it (burn first, or burn
//!    last) is solved free.
//! 3. Each candidate is replayed: a fresh modal propagation of its initial costates with the
//!    bang-bang law (eps = 0, stepping onto rho = 0) must meet all six terminal conditions to
//!    the solver's tolerance. Of those that do, the one with the largest final mass is returned.
//!
//! So the result is an extremal of the docs/spec.md section 3 problem at eps = 0 (the fuel-optimal
//! problem the homotopy aims at), with its final eps recorded as 0.

use nalgebra::{SMatrix, SVector};
use onboard::integrator::{IntegrationError, Tolerances};
use shared::scenario::{ProblemKind, Scenario};
use shared::spacecraft::CanonicalSpacecraft;

use num_dual::Dual2_64;

use super::bangbang::{BangBangTransfer, Hohmann, Structure};
use super::multiple::{MsVector, MultipleShootingFree, MultipleShootingTransfer, MS_UNKNOWNS};
use super::pontryagin::{idx, propagate, work_done, OptimalControlParams, Regime};
use super::shooting::{
    continue_eps, homotopy, initial_state_costate, newton, orbit_state, transfer_residual_only, NewtonSettings,
    PinnedAnomalyTransfer, RendezvousVector, ShootingProblem, TransferVector,
};
use super::{transfer_guesses, Budgeted, SolveOptions};

/// Largest eccentricity of both orbits for which this path is used.
pub const NEAR_CIRCULAR_ECCENTRICITY: f64 = 0.02;

/// Number of shifts the scan solves.
const SHIFT_SAMPLES: usize = 6;

/// Convergence of the structured solves, and of the transversality residual in the shift search.
const STRUCTURED_TOLERANCE: f64 = 1e-11;
const TRANSVERSALITY_TOLERANCE: f64 = 1e-10;
/// The nu_f search stops at this transversality residual: well inside the 1e-8 of the acceptance
/// test, since the smoothed problem at the final eps can be almost flat along nu_f (a spread
/// throttle on small transfers is nearly shift invariant again) and an exact zero far.
const SEARCH_TOLERANCE: f64 = 2e-9;
/// Convergence of the homotopy correctors of the downward path, at the ~1e-9 noise of the
/// multiple-shooting residual near the final eps: every level this accurate keeps nu_f (a weak
/// direction) on the path; at 5e-9, 7 more draws in 1000 stalled.
const CORRECTOR_TOLERANCE: f64 = 1e-9;
/// Convergence of the multiple-shooting solves in the nu_f search.
const INNER_TOLERANCE: f64 = 1e-10;

/// Relative integration tolerance of the eps continuations (absolute: a tenth of it), the
/// the specification's loosest. Why: the levels before the final one are only starts for the next corrector;
/// at rtol 1e-11 instead of 3e-14 the DOP853 propagations take ~2x fewer steps (the downward
/// homotopy was 60 % of the transfer-circular run time), and the measured final masses and
/// convergence are unchanged because the final level's solves (the nu_f search, the replay) run
/// at the full tolerances.
const CONTINUATION_RTOL: f64 = 1e-11;

fn continuation_tolerances(tol: &Tolerances) -> Tolerances {
    Tolerances {
        relative: CONTINUATION_RTOL.max(tol.relative),
        absolute: (0.1 * CONTINUATION_RTOL).max(tol.absolute),
        ..*tol
    }
}

/// Consecutive stagnating Newton iterations after which a continuation corrector gives up (see
/// [`ShootingProblem::stall_limit`]). Why: a stagnating corrector of these continuations rarely
/// recovers (measured: residuals stuck at 2.5e-8 or 1.4e-5 for 6 to 9 iterations, then failed),
/// and each of those iterations costs a line search, a look-ahead and a valley step, 10 to 15
/// Jacobians; the continuation's shorter step is cheaper. 3, not 2: correctors that crawl for two
/// iterations and then converge are common (2 lost 5 of 100 draws). Only correctors: a start
/// from a guess (the upward start, the nu_f search) may crawl long and converge (seed 7 #527).
const STALL_ITERATIONS: u32 = 3;

/// A shooting problem whose Newton solves are continuation correctors ([`STALL_ITERATIONS`]).
struct Correctors<'a, P>(&'a P);

impl<P: ShootingProblem<K>, const K: usize> ShootingProblem<K> for Correctors<'_, P> {
    fn residual_only(
        &self,
        eps: f64,
        z: &SVector<f64, K>,
        tolerances: &Tolerances,
    ) -> Result<SVector<f64, K>, IntegrationError> {
        self.0.residual_only(eps, z, tolerances)
    }

    fn residual(
        &self,
        eps: f64,
        z: &SVector<f64, K>,
        tolerances: &Tolerances,
    ) -> Result<(SVector<f64, K>, SMatrix<f64, K, K>), IntegrationError> {
        self.0.residual(eps, z, tolerances)
    }

    fn stall_limit(&self) -> u32 {
        STALL_ITERATIONS
    }
}

/// Replays whose residual is above this get a single-shooting polish.
const POLISH_ABOVE: f64 = 2e-9;

/// A solved near-circular transfer.
#[derive(Debug, Clone, PartialEq)]
pub struct CircularSolution {
    /// Initial costates and nu_f.
    pub z: TransferVector,
    /// The eps they solve (the specification schedule's final level).
    pub eps: f64,
    /// The switching times of the bang-bang structure.
    pub switches: Vec<f64>,
    /// Whether the flight starts with a coast.
    pub initial_coast: bool,
    /// Largest terminal residual of the replay (fresh propagation of the costates at `eps`).
    pub residual: f64,
    /// Final mass of the replay, fraction of m0.
    pub final_mass: f64,
}

/// Whether the scenario is a transfer this path handles.
pub fn applies(scenario: &Scenario) -> bool {
    scenario.problem == ProblemKind::Transfer
        && scenario.initial.shape.e <= NEAR_CIRCULAR_ECCENTRICITY
        && scenario.target.e <= NEAR_CIRCULAR_ECCENTRICITY
}

const FULL_STRUCTURE: Structure = Structure {
    first: Regime::Coast,
    switches: 4,
};

fn settings() -> NewtonSettings {
    NewtonSettings {
        max_iterations: 12,
        tolerance: STRUCTURED_TOLERANCE,
        progress: None,
    }
}

/// One solved shift: the structured solution with its first switching time pinned.
#[derive(Debug, Clone, Copy)]
struct Shift {
    z: SVector<f64, 10>,
    /// Transversality residual of the free problem.
    transversality: f64,
    mass: f64,
}

impl Shift {
    fn pin(&self) -> f64 {
        self.z[6]
    }
}

/// Solves the 4-switch structure with t_1 pinned at `pin`, from `z0`.
fn solve_pinned(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    z0: &SVector<f64, 10>,
    pin: f64,
    tol: &Tolerances,
    budget: u64,
) -> Option<Shift> {
    let pinned = BangBangTransfer {
        scenario,
        spacecraft: *sc,
        structure: FULL_STRUCTURE,
        pin: Some(pin),
    };
    let budgeted = Budgeted::new(&pinned, budget);
    let out = newton(&budgeted, 0.0, z0, tol, &settings()).ok()?;
    if !out.converged {
        return None;
    }
    let free = BangBangTransfer { pin: None, ..pinned };
    let (f, _) = free.evaluate(out.z.as_slice(), tol, false).ok()?;
    let flight = free.fly(out.z.as_slice(), tol, false).ok()?;
    Some(Shift {
        z: out.z,
        transversality: f[4],
        mass: flight.y_final[idx::M],
    })
}

/// The guess for pin `pin` from a solved shift: every switching time moved by the same amount,
/// nu_f by the slope `dnu` (rad per unit of pin), costates kept.
fn shifted(from: &Shift, pin: f64, dnu: f64) -> SVector<f64, 10> {
    let d = pin - from.pin();
    let mut z = from.z;
    z[5] += dnu * d;
    for k in 6..10 {
        z[k] += d;
    }
    z
}

/// Regula falsi (Illinois) on the pinned time between two shifts whose (oriented) transversality
/// residuals have opposite signs.
fn refine_shift(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    a: Shift,
    b: Shift,
    dnu: f64,
    tol: &Tolerances,
    budget: u64,
) -> Option<Shift> {
    let (mut a, mut b) = (a, b);
    let (mut fa, mut fb) = (a.transversality, b.transversality);
    let mut side = 0i8;
    for _ in 0..40 {
        let pin = (a.pin() * fb - b.pin() * fa) / (fb - fa);
        let from = if (pin - a.pin()).abs() < (pin - b.pin()).abs() {
            a
        } else {
            b
        };
        let m = solve_pinned(scenario, sc, &shifted(&from, pin, dnu), pin, tol, budget / 8)?;
        if m.transversality.abs() < TRANSVERSALITY_TOLERANCE {
            return Some(m);
        }
        if m.transversality.signum() == a.transversality.signum() {
            a = m;
            fa = m.transversality;
            if side == -1 {
                fb *= 0.5;
            }
            side = -1;
        } else {
            b = m;
            fb = m.transversality;
            if side == 1 {
                fa *= 0.5;
            }
            side = 1;
        }
    }
    None
}

/// Solves the structure without the coast at one end (`first` Full: no initial coast; Coast with
/// 3 switches: no final coast) free, from a 4-switch solution.
fn solve_end(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    from: &Shift,
    no_initial_coast: bool,
    dnu: f64,
    tol: &Tolerances,
    budget: u64,
) -> Option<(SVector<f64, 9>, Structure)> {
    let structure = Structure {
        first: if no_initial_coast { Regime::Full } else { Regime::Coast },
        switches: 3,
    };
    // Move the pattern to the end: the first burn starting at 0, or the last one ending at tf.
    let d = if no_initial_coast {
        -from.z[6]
    } else {
        scenario.time_of_flight() - from.z[9]
    };
    let mut z0 = SVector::<f64, 9>::zeros();
    z0.as_mut_slice()[..6].copy_from_slice(&from.z.as_slice()[..6]);
    z0[5] += dnu * d;
    let times: [f64; 3] = if no_initial_coast {
        [from.z[7] + d, from.z[8] + d, from.z[9] + d]
    } else {
        [from.z[6] + d, from.z[7] + d, from.z[8] + d]
    };
    z0.as_mut_slice()[6..].copy_from_slice(&times);
    let problem = BangBangTransfer {
        scenario,
        spacecraft: *sc,
        structure,
        pin: None,
    };
    let budgeted = Budgeted::new(&problem, budget);
    let settings = NewtonSettings {
        max_iterations: 20,
        ..settings()
    };
    let out = newton(&budgeted, 0.0, &z0, tol, &settings).ok()?;
    out.converged.then_some((out.z, structure))
}

/// A bang-bang (eps = 0) stationary shift: initial costates, nu_f and switching times.
#[derive(Debug, Clone)]
struct Candidate {
    z: Vec<f64>,
    structure: Structure,
    mass: f64,
}

impl Candidate {
    fn problem<'a>(&self, scenario: &'a Scenario, sc: &CanonicalSpacecraft) -> BangBangTransfer<'a> {
        BangBangTransfer {
            scenario,
            spacecraft: *sc,
            structure: self.structure,
            pin: None,
        }
    }
}

/// The final eps of the specification schedule (the first halving of 1 below `final_eps`).
pub fn final_level(final_eps: f64) -> f64 {
    super::shooting::homotopy_schedule(final_eps)
        .last()
        .unwrap_or(final_eps)
}

/// The start of the upward continuation: small enough that the smoothed extremal is the
/// bang-bang one (ramps of ~1e-8 / |d rho / dt|), and at most 1/64 of the smallest burn peak of
/// rho (at eps near that peak a ramp spans the burn's flat top, where the variational equations,
/// whose coefficients grow like 1/eps, make the integration stiff).
const UPWARD_START_EPS: f64 = 1.0 / (1u64 << 26) as f64;

/// The smallest, over the burns of a bang-bang candidate, of the largest rho on the burn.
fn smallest_burn_peak(scenario: &Scenario, sc: &CanonicalSpacecraft, c: &Candidate, tol: &Tolerances) -> f64 {
    let bb = c.problem(scenario, sc);
    let mut bounds = vec![0.0];
    bounds.extend_from_slice(&c.z[6..]);
    bounds.push(scenario.time_of_flight());
    let mut smallest = f64::INFINITY;
    for j in 0..bounds.len() - 1 {
        if c.structure.regime(j) != Regime::Full {
            continue;
        }
        let mut peak = f64::NEG_INFINITY;
        for k in 1..8 {
            let t = bounds[j] + (bounds[j + 1] - bounds[j]) * f64::from(k) / 8.0;
            if let Ok(y) = bb.state_at(&c.z, t, tol) {
                peak = peak.max(super::pontryagin::switching_function(&y, sc.exhaust_speed));
            }
        }
        smallest = smallest.min(peak);
    }
    smallest
}

/// The start eps of the upward continuation for a candidate (a power of 2).
fn upward_start(peak: f64) -> f64 {
    let mut eps = UPWARD_START_EPS;
    while eps > peak / 64.0 && eps > 1e-15 {
        eps *= 0.5;
    }
    eps
}

/// The bang-bang candidates of a scenario (see the module notes), best final mass first.
fn candidates(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    tol: &Tolerances,
    budget: u64,
) -> Result<Vec<Candidate>, CircularError> {
    let tof = scenario.time_of_flight();
    let h = Hohmann::of(scenario, sc);
    let (lo, hi) = h.centre_range(tof);
    if hi <= lo || hi.is_nan() {
        return Err(CircularError::ShorterThanHohmann);
    }
    let mut shifts: Vec<Shift> = Vec::new();
    for k in 0..SHIFT_SAMPLES {
        let centre = lo + (hi - lo) * (k as f64 + 0.5) / SHIFT_SAMPLES as f64;
        let g = SVector::<f64, 10>::from_column_slice(&h.guess(scenario, centre));
        if let Some(s) = solve_pinned(scenario, sc, &g, g[6], tol, budget / (2 * SHIFT_SAMPLES as u64)) {
            shifts.push(s);
        }
    }
    if shifts.len() < 2 {
        return Err(CircularError::ShiftScan { solved: shifts.len() });
    }
    // nu_f moves with the pin at the rate of the relative motion of the two circles.
    let dnu = {
        let (f, l) = (shifts[0], shifts[shifts.len() - 1]);
        (l.z[5] - f.z[5]) / (l.pin() - f.pin())
    };
    // Transversality is proportional to d m / d nu_f; oriented along the pin it is d m / d pin.
    let orient = dnu.signum();
    let mut found: Vec<Candidate> = Vec::new();
    for w in shifts.windows(2) {
        let (a, b) = (w[0], w[1]);
        if orient * a.transversality > 0.0 && orient * b.transversality <= 0.0 {
            if let Some(s) = refine_shift(scenario, sc, a, b, dnu, tol, budget / 4) {
                found.push(Candidate {
                    z: s.z.as_slice().to_vec(),
                    structure: FULL_STRUCTURE,
                    mass: s.mass,
                });
            }
        }
    }
    let (first, last) = (shifts[0], shifts[shifts.len() - 1]);
    for (end, no_initial_coast) in [(first, true), (last, false)] {
        let outward = if no_initial_coast { -1.0 } else { 1.0 };
        if outward * orient * end.transversality <= 0.0 {
            continue;
        }
        if let Some((z, structure)) = solve_end(scenario, sc, &end, no_initial_coast, dnu, tol, budget / 8) {
            let c = Candidate {
                z: z.as_slice().to_vec(),
                structure,
                mass: 0.0,
            };
            if let Ok(flight) = c.problem(scenario, sc).fly(&c.z, tol, false) {
                found.push(Candidate {
                    mass: flight.y_final[idx::M],
                    ..c
                });
            }
        }
    }
    if found.is_empty() {
        return Err(CircularError::NoStationaryShift);
    }
    found.sort_by(|a, b| b.mass.total_cmp(&a.mass));
    Ok(found)
}

/// Replays costates and nu_f at `eps`: the terminal residual of a fresh single propagation from
/// the initial costates, and the final mass.
fn replay(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    z: &TransferVector,
    eps: f64,
    tol: &Tolerances,
) -> Option<(f64, f64)> {
    let params = OptimalControlParams { spacecraft: *sc, eps };
    let f = transfer_residual_only(scenario, &params, z, tol).ok()?;
    let y0 = initial_state_costate(scenario, &[z[0], z[1], z[2], z[3], z[4]]);
    let yf = propagate(&params, 0.0, &y0, scenario.time_of_flight(), tol).ok()?;
    Some((f.amax(), yf[idx::M]))
}

/// Newton settings of the multiple-shooting solves.
fn ms_settings(tolerance: f64) -> NewtonSettings {
    NewtonSettings {
        max_iterations: 12,
        tolerance,
        progress: None,
    }
}

/// d x / d nu_f along the multiple-shooting solution `x` at `nu` (only the terminal position and
/// velocity rows depend on nu_f), and the slope of the transversality residual along it.
fn nu_tangent(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    x: &MsVector,
    nu: f64,
    eps: f64,
    tol: &Tolerances,
) -> Option<(MsVector, f64)> {
    let problem = MultipleShootingTransfer {
        scenario,
        spacecraft: *sc,
        nu_f: nu,
    };
    let (_, jac) = problem.residual(eps, x, tol).ok()?;
    let orbit = orbit_state(&scenario.target, Dual2_64::from_re(nu).derivative());
    let mut df = MsVector::zeros();
    for i in 0..4 {
        df[i] = -orbit[i].v1;
    }
    let t = jac.lu().solve(&(-df))?;
    let h = 1e-6;
    let moved = MultipleShootingTransfer {
        nu_f: nu + h,
        ..problem
    };
    let f_plus = moved.transversality(eps, &(x + t * h), tol).ok()?;
    let f_minus = MultipleShootingTransfer {
        nu_f: nu - h,
        ..problem
    }
    .transversality(eps, &(x - t * h), tol)
    .ok()?;
    Some((t, (f_plus - f_minus) / (2.0 * h)))
}

/// Zeroes the transversality residual over nu_f at `eps` by multiple shooting: Newton in nu_f
/// with the implicit slope (each trial solved from the tangent prediction, the step halved when
/// that fails), regula falsi (Illinois) once the zero is bracketed. With `stall`, the inner solves
/// give up when they stagnate ([`STALL_ITERATIONS`]).
#[allow(clippy::too_many_arguments)]
fn transversality_search(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    x0: &MsVector,
    nu0: f64,
    eps: f64,
    tol: &Tolerances,
    budget: u64,
    stall: bool,
) -> Result<(MsVector, f64), SearchFailure> {
    let start = work_done();
    let spent = || work_done().saturating_sub(start) >= budget;
    let per = budget / 6;
    let solve_at = |x: &MsVector, t: Option<&MsVector>, from: f64, nu: f64| -> Option<(f64, MsVector)> {
        let guess = t.map_or(*x, |t| x + t * (nu - from));
        let problem = MultipleShootingTransfer {
            scenario,
            spacecraft: *sc,
            nu_f: nu,
        };
        let budgeted = Budgeted::new(&problem, per);
        let settings = ms_settings(INNER_TOLERANCE);
        let o = if stall {
            newton(&Correctors(&budgeted), eps, &guess, tol, &settings)
        } else {
            newton(&budgeted, eps, &guess, tol, &settings)
        }
        .ok()?;
        if o.residual > 10.0 * INNER_TOLERANCE {
            return None;
        }
        Some((problem.transversality(eps, &o.z, tol).ok()?, o.z))
    };
    let (mut f, mut x) = solve_at(x0, None, nu0, nu0).ok_or(SearchFailure::StartSolve)?;
    let mut nu = nu0;
    // Points on either side of the zero seen so far: (nu, F5, x).
    let mut neg: Option<(f64, f64, MsVector)> = None;
    let mut pos: Option<(f64, f64, MsVector)> = None;
    let mut side = 0i8;
    for _ in 0..40 {
        if f.abs() < SEARCH_TOLERANCE {
            return Ok((x, nu));
        }
        if spent() {
            return Err(SearchFailure::Budget);
        }
        if f < 0.0 {
            neg = Some((nu, f, x));
        } else {
            pos = Some((nu, f, x));
        }
        let (t, slope) = nu_tangent(scenario, sc, &x, nu, eps, tol).ok_or(SearchFailure::Tangent)?;
        let mut target = nu - f / slope;
        // Inside a bracket, stay inside it (regula falsi with Illinois weights if Newton leaves).
        if let (Some(a), Some(b)) = (&neg, &pos) {
            let (lo, hi) = (a.0.min(b.0), a.0.max(b.0));
            if target <= lo || target >= hi || !target.is_finite() {
                let (fa, fb) = match side {
                    -1 => (a.1, 0.5 * b.1),
                    1 => (0.5 * a.1, b.1),
                    _ => (a.1, b.1),
                };
                target = (a.0 * fb - b.0 * fa) / (fb - fa);
            }
        }
        if !target.is_finite() {
            return Err(SearchFailure::FlatResidual);
        }
        let mut step = target - nu;
        let mut accepted = None;
        for _ in 0..8 {
            if let Some(r) = solve_at(&x, Some(&t), nu, nu + step) {
                accepted = Some(r);
                break;
            }
            step *= 0.5;
        }
        let Some((fn_, xn)) = accepted else {
            return Err(SearchFailure::InnerSolve);
        };
        side = if fn_ < 0.0 { -1 } else { 1 };
        (nu, f, x) = (nu + step, fn_, xn);
    }
    Err(SearchFailure::NoConvergence)
}

/// Why a near-circular transfer was not solved: where each path stopped. The messages are the
/// text of a record's failure (after "near-circular transfer: "), so they must not change.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CircularError {
    /// No bang-bang candidate: the time of flight is below the Hohmann transfer's.
    #[error("the flight is shorter than the Hohmann transfer")]
    ShorterThanHohmann,
    /// Fewer than two shifts of the bang-bang scan solved.
    #[error("bang-bang shift scan: {solved} of {samples} shifts solved", samples = SHIFT_SAMPLES)]
    ShiftScan {
        /// Shifts that solved.
        solved: usize,
    },
    /// No shift of the scan led to a stationary bang-bang candidate.
    #[error("bang-bang: no stationary shift solved")]
    NoStationaryShift,
    /// The upward path (from the bang-bang candidates) failed.
    #[error("upward: {0}")]
    Upward(Box<CircularError>),
    /// The downward path (homotopy with nu_f free) failed.
    #[error("downward: {0}")]
    Downward(Box<CircularError>),
    /// Both paths failed, in the order they were tried.
    #[error("{first}; {second}")]
    BothPaths {
        /// Why the path tried first failed.
        first: Box<CircularError>,
        /// Why the other failed.
        second: Box<CircularError>,
    },
    /// No energy-optimal (eps = 1) solution to start the downward homotopy from.
    #[error("no energy-optimal start")]
    NoEnergyOptimalStart,
    /// The energy-optimal solution could not be propagated to the multiple-shooting nodes.
    #[error("energy-optimal propagation failed")]
    EnergyOptimalPropagation,
    /// The downward homotopy's first solve failed to propagate.
    #[error("{0:?}")]
    Homotopy(IntegrationError),
    /// The downward homotopy returned no level.
    #[error("empty homotopy")]
    EmptyHomotopy,
    /// The downward homotopy solved no level.
    #[error("stalled at eps = 1")]
    StalledAtStart,
    /// The free-anomaly path stalled below `eps`, and the pinned path from there failed.
    #[error("stalled below eps = {eps:.3e}; pinned: {pinned}")]
    Pinned {
        /// Lowest eps the free-anomaly path solved.
        eps: f64,
        /// Why the pinned path failed.
        pinned: Box<CircularError>,
    },
    /// The pinned path stalled at this eps.
    #[error("stalled at eps = {0:.3e}")]
    Stalled(f64),
    /// The final nu_f search and replay failed with stall-limited inner solves, then without.
    #[error("{limited}; without the stall limit: {unlimited}")]
    Finish {
        /// Failure with the stall limit.
        limited: Box<CircularError>,
        /// Failure without it.
        unlimited: Box<CircularError>,
    },
    /// The nu_f search failed, and Newton with nu_f free failed to propagate.
    #[error("{search}; free nu_f: {error:?}")]
    FreeAnomaly {
        /// Where the nu_f search stopped.
        search: SearchFailure,
        /// The propagation error of the free-nu_f Newton.
        error: IntegrationError,
    },
    /// The nu_f search failed, and Newton with nu_f free ended at this residual.
    #[error("{search}; free nu_f: residual {residual:.1e}")]
    FreeAnomalyResidual {
        /// Where the nu_f search stopped.
        search: SearchFailure,
        /// Largest terminal residual where Newton ended (canonical).
        residual: f64,
    },
    /// The single propagation from the initial costates failed.
    #[error("replay: propagation failed")]
    ReplayPropagation,
    /// The single propagation from the initial costates misses by this residual.
    #[error("replay: terminal residual {0:.1e} from the initial costates alone")]
    ReplayResidual(f64),
    /// A bang-bang candidate could not be propagated to the multiple-shooting nodes.
    #[error("bang-bang candidate: propagation failed")]
    CandidatePropagation,
    /// The first solve of the upward path failed to propagate.
    #[error("upward start: {0:?}")]
    UpwardStart(IntegrationError),
    /// The first solve of the upward path ended at this residual.
    #[error("upward start: residual {0:.1e}")]
    UpwardStartResidual(f64),
    /// The upward continuation stopped at this eps.
    #[error("upward continuation stalled at eps = {0:.3e}")]
    UpwardStalled(f64),
}

/// Why the nu_f search at the final eps (`transversality_search`) stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SearchFailure {
    /// The inner multiple-shooting solve at the starting nu_f failed.
    #[error("transversality search: inner solve failed at the start")]
    StartSolve,
    /// The search spent its integration-work budget.
    #[error("transversality search: work budget spent")]
    Budget,
    /// The tangent d x / d nu_f of the inner solution, or the residual's slope along it, failed.
    #[error("transversality search: tangent failed")]
    Tangent,
    /// The next nu_f is not finite (a flat transversality residual).
    #[error("transversality search: flat transversality residual")]
    FlatResidual,
    /// The inner solve at the next nu_f failed, even with the step halved 8 times.
    #[error("transversality search: inner solve failed")]
    InnerSolve,
    /// 40 iterations without the transversality residual meeting the search tolerance.
    #[error("transversality search: no convergence")]
    NoConvergence,
}

/// Solves a near-circular transfer at the specification's final eps (see the module notes). Errors say
/// where it stopped.
pub fn solve(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> Result<CircularSolution, CircularError> {
    let tol = options.tolerances;
    let target = final_level(options.final_eps);
    let list = candidates(scenario, sc, &tol, options.max_start_work / 4)?;
    let best = &list[0];
    let peak = smallest_burn_peak(scenario, sc, best, &tol);
    // The best candidate, then the second best if there is one.
    let up = || {
        let mut result = solve_candidate(scenario, sc, best, target, options);
        if result.is_err() {
            if let Some(second) = list.get(1) {
                result = solve_candidate(scenario, sc, second, target, options);
            }
        }
        result.map_err(|e| CircularError::Upward(Box::new(e)))
    };
    let down =
        || solve_downward_free(scenario, sc, best, target, options).map_err(|e| CircularError::Downward(Box::new(e)));
    // Burns whose switching function peaks this low are spread over most of the flight at the
    // final eps: far from the bang-bang extremal the upward path starts from.
    let (first, second): (&Path, &Path) = if peak > UPWARD_MIN_PEAK {
        (&up, &down)
    } else {
        (&down, &up)
    };
    first().or_else(|e1| {
        second().map_err(|e2| CircularError::BothPaths {
            first: Box::new(e1),
            second: Box::new(e2),
        })
    })
}

/// One way to the final eps.
type Path<'a> = dyn Fn() -> Result<CircularSolution, CircularError> + 'a;

/// Below this smallest burn peak of rho the downward path is tried first.
const UPWARD_MIN_PEAK: f64 = 1e-6;

/// The the specification's downward homotopy by multiple shooting with nu_f free, from the energy-optimal
/// free-anomaly solution nearest the candidate's nu_f.
fn solve_downward_free(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    c: &Candidate,
    target: f64,
    options: &SolveOptions,
) -> Result<CircularSolution, CircularError> {
    let tol = options.tolerances;
    let single = super::shooting::TransferShooting {
        scenario,
        spacecraft: *sc,
    };
    let start = Budgeted::new(&single, options.max_start_work / 4);
    let mut z = None;
    for g in transfer_guesses(scenario) {
        let mut g = g;
        g[5] = c.z[5];
        if let Ok(o) = newton(&start, 1.0, &g, &tol, &options.start_newton) {
            if o.converged {
                z = Some(o.z);
                break;
            }
        }
        if start.exhausted() {
            break;
        }
    }
    let z = z.ok_or(CircularError::NoEnergyOptimalStart)?;
    let nu = z[5];
    let ms = MultipleShootingTransfer {
        scenario,
        spacecraft: *sc,
        nu_f: nu,
    };
    let x0 = ms
        .unknowns_from_costates(&[z[0], z[1], z[2], z[3], z[4]], 1.0, &tol)
        .ok_or(CircularError::EnergyOptimalPropagation)?;
    let free = MultipleShootingFree {
        scenario,
        spacecraft: *sc,
    };
    let budgeted = Budgeted::new(&free, options.max_homotopy_work);
    let levels = homotopy(
        &Correctors(&budgeted),
        &MultipleShootingFree::join(&x0, nu),
        &continuation_tolerances(&tol),
        &ms_settings(CORRECTOR_TOLERANCE),
        options.final_eps,
        3 * options.max_homotopy_solves,
    )
    .map_err(CircularError::Homotopy)?;
    let mut last = *levels.last().ok_or(CircularError::EmptyHomotopy)?;
    if last.outcome.converged {
        // Again at the full tolerances (1-2 iterations); the nu_f search below starts from here.
        if let Ok(o) = newton(
            &budgeted,
            last.eps,
            &last.outcome.z,
            &tol,
            &ms_settings(CORRECTOR_TOLERANCE),
        ) {
            if o.converged {
                last.outcome = o;
            }
        }
    }
    if !(last.outcome.converged && last.eps <= target) {
        let Some(deepest) = levels.iter().rev().find(|l| l.outcome.converged) else {
            return Err(CircularError::StalledAtStart);
        };
        return pinned_downward(scenario, sc, c, &deepest.outcome.z, deepest.eps, target, options).map_err(|e| {
            CircularError::Pinned {
                eps: deepest.eps,
                pinned: Box::new(e),
            }
        });
    }
    let x = MsVector::from_column_slice(&last.outcome.z.as_slice()[..MS_UNKNOWNS]);
    finish(
        scenario,
        sc,
        c,
        &x,
        last.outcome.z[MS_UNKNOWNS],
        target,
        options,
        options.max_homotopy_work / 6,
    )
}

/// The rest of the downward path with nu_f pinned, from a free-anomaly solution `z` at `eps`.
///
/// Why: on the smallest transfers (|da| < ~0.013 AU) the free-anomaly path stalls at eps ~ 1e-4
/// to 5e-4 (no corrector converges even for a 1 % step), while nu_f, nearly a symmetry there
/// (a spread throttle can slide along the circles), is only weakly determined. With nu_f pinned
/// that direction leaves the problem, and the nu_f search at the final level puts it back.
fn pinned_downward(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    c: &Candidate,
    z: &super::multiple::MsFreeVector,
    eps: f64,
    target: f64,
    options: &SolveOptions,
) -> Result<CircularSolution, CircularError> {
    let tol = options.tolerances;
    let nu = z[MS_UNKNOWNS];
    let ms = MultipleShootingTransfer {
        scenario,
        spacecraft: *sc,
        nu_f: nu,
    };
    let budgeted = Budgeted::new(&ms, options.max_homotopy_work / 3);
    let x0 = MsVector::from_column_slice(&z.as_slice()[..MS_UNKNOWNS]);
    let (reached, x) = continue_eps(
        &Correctors(&budgeted),
        &x0,
        eps,
        target,
        &continuation_tolerances(&tol),
        &ms_settings(CORRECTOR_TOLERANCE),
        2.0,
        40,
    );
    if reached > target {
        return Err(CircularError::Stalled(reached));
    }
    // nu_f was pinned where the free path stalled, farther from its zero than on the other
    // paths: the search gets the whole homotopy budget (seed 7 #260 and #308 need ~1/3 of it).
    finish(scenario, sc, c, &x, nu, target, options, options.max_homotopy_work)
}

/// The nu_f search at the final eps from a multiple-shooting solution, then the replay.
#[allow(clippy::too_many_arguments)]
fn finish(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    c: &Candidate,
    x: &MsVector,
    nu: f64,
    target: f64,
    options: &SolveOptions,
    search_budget: u64,
) -> Result<CircularSolution, CircularError> {
    // Stagnating inner solves cut short first (cheaper; seed 7 #260 and #308 need it to finish
    // within the budget), then run to their iteration cap (#149 and #356 need that: their
    // stall-limited search ends on costates whose replay misses by 1.3e-8 and 4e-8).
    finish_with(scenario, sc, c, x, nu, target, options, search_budget, true).or_else(|e| {
        finish_with(scenario, sc, c, x, nu, target, options, search_budget, false).map_err(|f| CircularError::Finish {
            limited: Box::new(e),
            unlimited: Box::new(f),
        })
    })
}

/// [`finish`] with the nu_f search's inner solves stall-limited or not.
#[allow(clippy::too_many_arguments)]
fn finish_with(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    c: &Candidate,
    x: &MsVector,
    nu: f64,
    target: f64,
    options: &SolveOptions,
    search_budget: u64,
    stall: bool,
) -> Result<CircularSolution, CircularError> {
    let tol = options.tolerances;
    let (x, nu) = match transversality_search(scenario, sc, x, nu, target, &tol, search_budget, stall) {
        Ok(r) => r,
        Err(e) => {
            // nu_f free as a Newton unknown instead.
            let free = MultipleShootingFree {
                scenario,
                spacecraft: *sc,
            };
            let budgeted = Budgeted::new(&free, options.max_homotopy_work / 6);
            let settings = NewtonSettings {
                max_iterations: 20,
                tolerance: SEARCH_TOLERANCE,
                progress: None,
            };
            let o = newton(&budgeted, target, &MultipleShootingFree::join(x, nu), &tol, &settings)
                .map_err(|error| CircularError::FreeAnomaly { search: e, error })?;
            // Near the residual's noise floor (~1e-9 at the final eps) the replay below, not this
            // tolerance, decides: it is the acceptance test.
            if o.residual >= options.newton.tolerance {
                return Err(CircularError::FreeAnomalyResidual {
                    search: e,
                    residual: o.residual,
                });
            }
            (
                MsVector::from_column_slice(&o.z.as_slice()[..MS_UNKNOWNS]),
                o.z[MS_UNKNOWNS],
            )
        }
    };
    let z = TransferVector::from_column_slice(&[x[0], x[1], x[2], x[3], x[4], nu]);
    let (mut residual, mut final_mass) =
        replay(scenario, sc, &z, target, &tol).ok_or(CircularError::ReplayPropagation)?;
    let mut z = z;
    if residual >= POLISH_ABOVE {
        // The multiple-shooting costates are exact to round-off, but a single propagation over the
        // whole flight amplifies its own integration error by the single-shooting Jacobian (up to
        // ~1e7 here): a few single-shooting Newton steps at the pinned nu_f absorb it.
        let single = PinnedAnomalyTransfer {
            scenario,
            spacecraft: *sc,
            nu_f: nu,
        };
        let settings = NewtonSettings {
            max_iterations: 4,
            tolerance: 1e-10,
            progress: None,
        };
        let z0 = RendezvousVector::from_column_slice(&z.as_slice()[..5]);
        if let Ok(o) = newton(&single, target, &z0, &tol, &settings) {
            let polished = TransferVector::from_column_slice(&[o.z[0], o.z[1], o.z[2], o.z[3], o.z[4], nu]);
            if let Some((r, m)) = replay(scenario, sc, &polished, target, &tol) {
                if r < residual {
                    (z, residual, final_mass) = (polished, r, m);
                }
            }
        }
    }
    if residual >= options.newton.tolerance {
        return Err(CircularError::ReplayResidual(residual));
    }
    Ok(CircularSolution {
        z,
        eps: target,
        switches: c.z[6..].to_vec(),
        initial_coast: c.structure.first == Regime::Coast,
        residual,
        final_mass,
    })
}

fn solve_candidate(
    scenario: &Scenario,
    sc: &CanonicalSpacecraft,
    c: &Candidate,
    target: f64,
    options: &SolveOptions,
) -> Result<CircularSolution, CircularError> {
    let tol = options.tolerances;
    let bb = c.problem(scenario, sc);
    let nu = c.z[5];
    let ms = MultipleShootingTransfer {
        scenario,
        spacecraft: *sc,
        nu_f: nu,
    };
    let x0 = ms
        .unknowns_from(|t| bb.state_at(&c.z, t, &tol).ok())
        .ok_or(CircularError::CandidatePropagation)?;
    let budgeted = Budgeted::new(&ms, options.max_homotopy_work / 3);
    let start = upward_start(smallest_burn_peak(scenario, sc, c, &tol));
    let first =
        newton(&budgeted, start, &x0, &tol, &ms_settings(INNER_TOLERANCE)).map_err(CircularError::UpwardStart)?;
    if first.residual > 10.0 * INNER_TOLERANCE {
        return Err(CircularError::UpwardStartResidual(first.residual));
    }
    let (eps, x) = continue_eps(
        &Correctors(&budgeted),
        &first.z,
        start,
        target,
        &continuation_tolerances(&tol),
        &ms_settings(1e-9),
        4.0,
        40,
    );
    if eps < target {
        return Err(CircularError::UpwardStalled(eps));
    }
    finish(scenario, sc, c, &x, nu, target, options, options.max_homotopy_work / 6)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The messages end up in records' failure texts: each is what the solver wrote before the
    /// errors were typed, nested the way the paths nest them.
    #[test]
    fn error_messages_are_the_failure_texts() {
        let leaves = [
            (
                CircularError::ShorterThanHohmann,
                "the flight is shorter than the Hohmann transfer",
            ),
            (
                CircularError::ShiftScan { solved: 1 },
                "bang-bang shift scan: 1 of 6 shifts solved",
            ),
            (
                CircularError::NoStationaryShift,
                "bang-bang: no stationary shift solved",
            ),
            (CircularError::NoEnergyOptimalStart, "no energy-optimal start"),
            (
                CircularError::EnergyOptimalPropagation,
                "energy-optimal propagation failed",
            ),
            (
                CircularError::Homotopy(IntegrationError::NonFinite { t: 0.5 }),
                "NonFinite { t: 0.5 }",
            ),
            (CircularError::EmptyHomotopy, "empty homotopy"),
            (CircularError::StalledAtStart, "stalled at eps = 1"),
            (CircularError::Stalled(2.5e-4), "stalled at eps = 2.500e-4"),
            (CircularError::ReplayPropagation, "replay: propagation failed"),
            (
                CircularError::ReplayResidual(3.3e-8),
                "replay: terminal residual 3.3e-8 from the initial costates alone",
            ),
            (
                CircularError::CandidatePropagation,
                "bang-bang candidate: propagation failed",
            ),
            (
                CircularError::UpwardStart(IntegrationError::InvalidInput),
                "upward start: InvalidInput",
            ),
            (
                CircularError::UpwardStartResidual(1.7e-6),
                "upward start: residual 1.7e-6",
            ),
            (
                CircularError::UpwardStalled(6.1e-5),
                "upward continuation stalled at eps = 6.100e-5",
            ),
        ];
        for (e, text) in leaves {
            assert_eq!(e.to_string(), text);
        }
        let searches = [
            (SearchFailure::StartSolve, "inner solve failed at the start"),
            (SearchFailure::Budget, "work budget spent"),
            (SearchFailure::Tangent, "tangent failed"),
            (SearchFailure::FlatResidual, "flat transversality residual"),
            (SearchFailure::InnerSolve, "inner solve failed"),
            (SearchFailure::NoConvergence, "no convergence"),
        ];
        for (e, what) in searches {
            assert_eq!(e.to_string(), format!("transversality search: {what}"));
        }
        let nested = CircularError::BothPaths {
            first: Box::new(CircularError::Upward(Box::new(CircularError::Finish {
                limited: Box::new(CircularError::FreeAnomalyResidual {
                    search: SearchFailure::Budget,
                    residual: 3.3e-7,
                }),
                unlimited: Box::new(CircularError::FreeAnomaly {
                    search: SearchFailure::Tangent,
                    error: IntegrationError::InvalidInput,
                }),
            }))),
            second: Box::new(CircularError::Downward(Box::new(CircularError::Pinned {
                eps: 1.5e-4,
                pinned: Box::new(CircularError::Stalled(2.5e-4)),
            }))),
        };
        assert_eq!(
            nested.to_string(),
            "upward: transversality search: work budget spent; free nu_f: residual 3.3e-7; \
             without the stall limit: transversality search: tangent failed; free nu_f: InvalidInput; \
             downward: stalled below eps = 1.500e-4; pinned: stalled at eps = 2.500e-4"
        );
    }
}
