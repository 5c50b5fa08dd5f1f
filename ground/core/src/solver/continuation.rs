//! Energy-optimal (eps = 1) starts by continuation in the target: when no guess of the
//! multi-start converges, the target is moved from the departure orbit (where coasting, zero
//! costates, is the solution) to the real one, solving the eps = 1 problem at each intermediate
//! target from the extrapolation of the previous solutions.
//!
//! The path: semi-major axis and eccentricity vector (e cos omega, e sin omega) linear in s, so
//! that a nearly circular end has no ill-defined omega to interpolate; for a rendezvous the body's
//! polar angle at t = 0 also moves linearly, from the spacecraft's to the real body's, the shorter
//! way round. The time of flight stays the real scenario's.

use std::f64::consts::PI;

use nalgebra::{Const, DimMin, SVector};
use onboard::integrator::Tolerances;
use onboard::kepler::coast;
use shared::orbit::OrbitShape;
use shared::scenario::Scenario;
use shared::spacecraft::CanonicalSpacecraft;

use super::pontryagin;
use super::shooting::{
    newton, NewtonSettings, RendezvousShooting, RendezvousVector, ShootingProblem, TransferShooting, TransferVector,
    RENDEZVOUS_UNKNOWNS, TRANSFER_UNKNOWNS,
};
use super::{Budgeted, SolveOptions};

/// First and largest continuation steps in s, and the smallest before giving up.
const FIRST_STEP: f64 = 1.0 / 16.0;
const MAX_STEP: f64 = 0.25;
const MIN_STEP: f64 = 1.0 / 512.0;
/// The continuation's work budget in multi-start budgets: the path takes 10-20 Newton solves
/// (seed 7 transfer-hard #1 reaches s = 1 with 5 budgets, stops at s = 0.96 with 1).
const CONTINUATION_WORK: u64 = 3;

/// The intermediate scenario at s in [0, 1] (s = 0: the target is the departure orbit and, for a
/// rendezvous, the body sits on the spacecraft; s = 1: the real scenario).
pub fn intermediate(scenario: &Scenario, s: f64) -> Scenario {
    intermediate_turning(scenario, s, 0)
}

/// [`intermediate`] with the body's polar angle at t = 0 moved the shorter way round plus
/// `turns` whole turns (the same s = 1 scenario, another path to it).
pub fn intermediate_turning(scenario: &Scenario, s: f64, turns: i32) -> Scenario {
    let (o, t) = (scenario.initial.shape, scenario.target);
    let ex = (1.0 - s) * o.e * o.omega.cos() + s * t.e * t.omega.cos();
    let ey = (1.0 - s) * o.e * o.omega.sin() + s * t.e * t.omega.sin();
    let target = OrbitShape {
        a: (1.0 - s) * o.a + s * t.a,
        e: ex.hypot(ey),
        omega: ey.atan2(ex),
    };
    let theta0 = o.omega + scenario.initial.nu;
    let sweep = wrap(t.omega + scenario.target_nu0 - theta0) + 2.0 * PI * f64::from(turns);
    let theta_body = theta0 + s * sweep;
    Scenario {
        target,
        target_nu0: theta_body - target.omega,
        ..*scenario
    }
}

/// The angle in (-pi, pi].
fn wrap(x: f64) -> f64 {
    let y = x.rem_euclid(2.0 * PI);
    if y > PI {
        y - 2.0 * PI
    } else {
        y
    }
}

/// Follows s from 0 to 1; `solve(s, z_guess)` solves the eps = 1 problem of the intermediate
/// scenario at s. `first` is the guess at the first step; later guesses extrapolate the last two
/// solutions linearly in s (the first one from the coast, z = `origin`). Steps grow by 1.5 after a
/// success and halve after a failure. Err: the last s reached.
fn follow<const K: usize>(
    origin: SVector<f64, K>,
    first: SVector<f64, K>,
    mut solve: impl FnMut(f64, &SVector<f64, K>) -> Option<SVector<f64, K>>,
) -> Result<SVector<f64, K>, f64> {
    let (mut s_prev, mut z_prev) = (0.0, origin);
    let (mut s, mut z) = (0.0, origin);
    let mut step = FIRST_STEP;
    while s < 1.0 {
        let s_next = (s + step).min(1.0);
        let guess = if s == 0.0 {
            first
        } else {
            z + (z - z_prev) * ((s_next - s) / (s - s_prev))
        };
        match solve(s_next, &guess) {
            Some(z_next) => {
                (s_prev, z_prev) = (s, z);
                (s, z) = (s_next, z_next);
                step = (step * 1.5).min(MAX_STEP);
            }
            None => {
                step *= 0.5;
                if step < MIN_STEP {
                    return Err(s);
                }
            }
        }
    }
    Ok(z)
}

/// One Newton solve at eps = 1 at the multi-start search's accuracy
/// ([`SolveOptions::search_tolerances`]), within what is left of `work` integration steps counted
/// from `start`: the continuation's points are guesses of its next step, and only its last one
/// is [`polish`]ed.
pub(super) fn solve_at<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    guess: &SVector<f64, K>,
    options: &SolveOptions,
    start: u64,
    work: u64,
) -> Option<SVector<f64, K>>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    let settings = NewtonSettings {
        tolerance: options.search_newton_tolerance,
        ..options.start_newton
    };
    newton_within(problem, guess, &options.search_tolerances, &settings, start, work)
}

/// `z`, solved at eps = 1 by [`solve_at`], solved again at the full accuracy
/// ([`SolveOptions::start_tolerances`] and [`SolveOptions::start_newton`]) within the same
/// budget; `z` itself if that does not converge (the multi-start then searches from it).
pub(super) fn polish<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    z: SVector<f64, K>,
    options: &SolveOptions,
    start: u64,
    work: u64,
) -> SVector<f64, K>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    newton_within(
        problem,
        &z,
        &options.start_tolerances(),
        &options.start_newton,
        start,
        work,
    )
    .unwrap_or(z)
}

fn newton_within<P: ShootingProblem<K>, const K: usize>(
    problem: &P,
    guess: &SVector<f64, K>,
    tolerances: &Tolerances,
    settings: &NewtonSettings,
    start: u64,
    work: u64,
) -> Option<SVector<f64, K>>
where
    Const<K>: DimMin<Const<K>, Output = Const<K>>,
{
    let spent = pontryagin::work_done().saturating_sub(start);
    if spent >= work {
        return None;
    }
    let budgeted = Budgeted::new(problem, work - spent);
    newton(&budgeted, 1.0, guess, tolerances, settings)
        .ok()
        .filter(|o| o.converged)
        .map(|o| o.z)
}

/// A small primer along the velocity (raise) or against it (lowering) at departure: the first
/// step's guess, close to the zero costates of the coast.
fn small_primer(scenario: &Scenario) -> [f64; 4] {
    let theta = scenario.initial.polar().theta;
    let sign = if scenario.target.a >= scenario.initial.shape.a {
        1.0
    } else {
        -1.0
    };
    let k = 1e-3;
    // Primer = -lambda_v = sign * theta_hat; lambda_r small along -r_hat.
    [
        -k * theta.cos(),
        -k * theta.sin(),
        sign * k * theta.sin(),
        -sign * k * theta.cos(),
    ]
}

/// An energy-optimal start of the free-anomaly transfer by continuation in the target orbit,
/// within `CONTINUATION_WORK` times `options.max_start_work` integration steps; Err: the last s reached.
pub fn transfer_start(
    scenario: &Scenario,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> Result<TransferVector, f64> {
    // Where the coast from departure ends: the s = 0 solution's final polar angle.
    let end = coast(&scenario.initial.cartesian(), scenario.time_of_flight()).map_err(|_| 0.0)?;
    let theta_f = end.r[1].atan2(end.r[0]);
    let omega0 = scenario.initial.shape.omega;
    let mut origin = TransferVector::zeros();
    origin[5] = theta_f - omega0;
    let p = small_primer(scenario);
    let first = TransferVector::from_column_slice(&[p[0], p[1], p[2], p[3], 0.0, theta_f - omega0]);
    let start = pontryagin::work_done();
    // nu_f is carried as the polar angle theta_f = nu_f + omega, continuous along the path while
    // omega may turn quickly where the eccentricity vector passes near zero.
    let to_theta = |z: &TransferVector, s: f64| {
        let mut y = *z;
        y[5] += intermediate(scenario, s).target.omega;
        y
    };
    let mut origin_theta = origin;
    origin_theta[5] = theta_f;
    let mut first_theta = first;
    first_theta[5] = theta_f;
    let solution = follow::<TRANSFER_UNKNOWNS>(origin_theta, first_theta, |s, guess| {
        let sc = intermediate(scenario, s);
        let mut z = *guess;
        z[5] -= sc.target.omega;
        let problem = TransferShooting {
            scenario: &sc,
            spacecraft: *spacecraft,
        };
        solve_at(&problem, &z, options, start, CONTINUATION_WORK * options.max_start_work).map(|z| to_theta(&z, s))
    })?;
    let mut z = solution;
    z[5] -= scenario.target.omega;
    let problem = TransferShooting {
        scenario,
        spacecraft: *spacecraft,
    };
    Ok(polish(
        &problem,
        z,
        options,
        start,
        CONTINUATION_WORK * options.max_start_work,
    ))
}

/// An energy-optimal start of the rendezvous by continuation in the target orbit and the body's
/// phase, within `CONTINUATION_WORK` times `options.max_start_work` integration steps; Err: the last s reached.
pub fn rendezvous_start(
    scenario: &Scenario,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> Result<RendezvousVector, f64> {
    rendezvous_start_turning(scenario, spacecraft, options, 0)
}

/// [`rendezvous_start`], and where that path stops, the same continuation with the body's phase
/// moved the longer way round ([`intermediate_turning`] with one turn against the shorter
/// sweep), on a budget of its own. Err: the last s reached on each path.
///
/// Where the body is nearly opposite the spacecraft the shorter sweep may pass through
/// intermediate targets that the engine cannot reach in the time of flight (the energy-optimal
/// throttle saturates over most of the flight, the path stops), while the longer one does not:
/// of the 10 rendezvous-circular draws of seeds 7 and 8 whose shorter path stops (all with the
/// body behind, by 110-180 degrees), the longer one reaches s = 1 on 7, each within 50 k steps.
pub fn rendezvous_start_either_way(
    scenario: &Scenario,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> Result<RendezvousVector, (f64, f64)> {
    let shorter = match rendezvous_start(scenario, spacecraft, options) {
        Ok(z) => return Ok(z),
        Err(s) => s,
    };
    let theta0 = scenario.initial.shape.omega + scenario.initial.nu;
    let turns = if wrap(scenario.target.omega + scenario.target_nu0 - theta0) < 0.0 {
        1
    } else {
        -1
    };
    rendezvous_start_turning(scenario, spacecraft, options, turns).map_err(|longer| (shorter, longer))
}

/// [`rendezvous_start`] along the path of [`intermediate_turning`] with `turns`.
pub fn rendezvous_start_turning(
    scenario: &Scenario,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
    turns: i32,
) -> Result<RendezvousVector, f64> {
    let p = small_primer(scenario);
    let first = RendezvousVector::from_column_slice(&[p[0], p[1], p[2], p[3], 0.0]);
    let start = pontryagin::work_done();
    let work = CONTINUATION_WORK * options.max_start_work;
    let z = follow::<RENDEZVOUS_UNKNOWNS>(RendezvousVector::zeros(), first, |s, guess| {
        let sc = intermediate_turning(scenario, s, turns);
        let problem = RendezvousShooting {
            scenario: &sc,
            spacecraft: *spacecraft,
        };
        solve_at(&problem, guess, options, start, work)
    })?;
    // The path ends on the real scenario (the turns are whole at s = 1).
    let problem = RendezvousShooting {
        scenario,
        spacecraft: *spacecraft,
    };
    Ok(polish(&problem, z, options, start, work))
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::scenario::ScenarioKind;

    /// The path's ends: at s = 0 the target orbit is the departure orbit and the rendezvous body
    /// sits on the spacecraft (so coasting solves it), at s = 1 target and body are the real ones
    /// (same positions and velocities, whatever branch of omega and nu0 the path picks).
    #[test]
    fn the_path_runs_from_the_departure_orbit_to_the_real_target() {
        for index in 0..20 {
            let scenario = ScenarioKind::RendezvousHard.draw(7, index);
            let close = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]) < 1e-12;
            let start = intermediate(&scenario, 0.0);
            let here = scenario.initial.cartesian();
            let body = start.target.cartesian_at(start.target_nu0);
            assert!(
                close(here.r, body.r) && close(here.v, body.v),
                "#{index}: s = 0 body {body:?}"
            );
            let end = intermediate(&scenario, 1.0);
            let (a, b) = (
                end.target.cartesian_at(end.target_nu0),
                scenario.target.cartesian_at(scenario.target_nu0),
            );
            assert!(
                close(a.r, b.r) && close(a.v, b.v),
                "#{index}: s = 1 body {a:?} vs {b:?}"
            );
            assert_eq!(end.time_of_flight(), scenario.time_of_flight());
            // Intermediate targets are orbits (e < 1: the eccentricity vector moves on a segment
            // between two points inside the unit disc).
            for k in 1..8 {
                let mid = intermediate(&scenario, k as f64 / 8.0);
                assert!(mid.target.e < 1.0 && mid.target.a > 0.0 && mid.target.validate().is_ok());
            }
        }
    }

    /// The continuation's start solves the real eps = 1 problem: a fresh plain propagation (the
    /// Newton used the sensitivity one) meets every terminal condition to 1e-8.
    #[test]
    fn continuation_starts_meet_the_terminal_conditions() {
        use shared::spacecraft::Spacecraft;
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let options = SolveOptions::default();
        let scenario = ScenarioKind::TransferHard.draw(7, 0);
        let z = transfer_start(&scenario, &sc, &options).expect("continuation reaches s = 1");
        let problem = TransferShooting {
            scenario: &scenario,
            spacecraft: sc,
        };
        let f = problem.residual_only(1.0, &z, &options.tolerances).unwrap();
        assert!(f.amax() < 1e-8, "transfer residual {f}");

        let scenario = ScenarioKind::RendezvousCircular.draw(7, 0);
        let z = rendezvous_start(&scenario, &sc, &options).expect("continuation reaches s = 1");
        let problem = RendezvousShooting {
            scenario: &scenario,
            spacecraft: sc,
        };
        let f = problem.residual_only(1.0, &z, &options.tolerances).unwrap();
        assert!(f.amax() < 1e-8, "rendezvous residual {f}");
    }

    /// Rendezvous-circular seed 7 #5 (the body 123 degrees behind the spacecraft): the path that
    /// moves the body's phase the shorter way stops short of s = 1, the longer way round reaches
    /// it, and its solution meets every terminal condition of the real scenario to 1e-8 (fresh
    /// plain propagation).
    #[test]
    fn the_longer_way_round_reaches_a_rendezvous_the_shorter_one_does_not() {
        use shared::spacecraft::Spacecraft;
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let options = SolveOptions::default();
        let scenario = ScenarioKind::RendezvousCircular.draw(7, 5);
        let stopped = rendezvous_start(&scenario, &sc, &options).expect_err("the shorter way stops");
        assert!(stopped < 1.0);
        let end = intermediate_turning(&scenario, 1.0, 1);
        let (a, b) = (
            end.target.cartesian_at(end.target_nu0),
            scenario.target.cartesian_at(scenario.target_nu0),
        );
        assert!((a.r[0] - b.r[0]).hypot(a.r[1] - b.r[1]) < 1e-12);
        let z = rendezvous_start_either_way(&scenario, &sc, &options).expect("the longer way reaches s = 1");
        let problem = RendezvousShooting {
            scenario: &scenario,
            spacecraft: sc,
        };
        let f = problem.residual_only(1.0, &z, &options.tolerances).unwrap();
        assert!(f.amax() < 1e-8, "rendezvous residual {f}");
    }
}
