//! One rendezvous or transfer in three dimensions posed as data (docs/missions.md, "One
//! rendezvous or transfer in three dimensions"): the problem file, its conversion to canonical
//! units, the solve's report, the sampled trajectory as CSV and figure, the missed-thrust cases,
//! and the comparison of the three-dimensional solver with the planar one on planar draws.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use shared::mission::{CentralBody, Units, DAY_S};
use shared::scenario::{ProblemKind, SpatialScenario};
use shared::spacecraft::{CanonicalSpacecraft, Spacecraft, SpacecraftError};

use crate::mission::{BodySpec, MissionError};
use crate::solver::spatial::{
    sample_solution, solve_spatial_rendezvous, solve_spatial_transfer, SpatialOrbitShape, SpatialRendezvous,
    SpatialSample, SpatialSolution, SpatialSolveError, SpatialState, SpatialTransfer,
};
use crate::solver::SolveOptions;

/// A position and velocity as a problem file writes them: each in the body's canonical units
/// (`r`, `v`) or in km and km/s (`r_km`, `v_km_s`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct StateSpec {
    /// Position, canonical length units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub r: Option<[f64; 3]>,
    /// Position, km.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub r_km: Option<[f64; 3]>,
    /// Velocity, canonical (length unit per time unit).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub v: Option<[f64; 3]>,
    /// Velocity, km/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub v_km_s: Option<[f64; 3]>,
}

fn sun() -> BodySpec {
    BodySpec::Preset("sun".into())
}

/// A target orbit as a problem file writes it: the semi-major axis in canonical units (`a`) or
/// in km (`a_km`), the eccentricity and the angles in degrees (each 0 by default).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TargetOrbitSpec {
    /// Semi-major axis, canonical length units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub a: Option<f64>,
    /// Semi-major axis, km.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub a_km: Option<f64>,
    /// Eccentricity.
    #[serde(default)]
    pub e: f64,
    /// Inclination to the xy-plane, degrees.
    #[serde(default)]
    pub inclination_deg: f64,
    /// Right ascension of the ascending node, degrees.
    #[serde(default)]
    pub raan_deg: f64,
    /// Argument of periapsis, degrees.
    #[serde(default)]
    pub argp_deg: f64,
}

impl TargetOrbitSpec {
    fn orbit(&self, units: &Units) -> Result<SpatialOrbitShape, SpatialProblemError> {
        let error = |why: &str| SpatialProblemError::State {
            which: "target_orbit",
            why: why.to_string(),
        };
        let a = match (self.a, self.a_km) {
            (Some(a), None) => a,
            (None, Some(km)) => km * 1e3 / units.length_m,
            (Some(_), Some(_)) => return Err(error("give the semi-major axis once: a (canonical) or a_km")),
            (None, None) => return Err(error("the semi-major axis is missing: give a (canonical) or a_km")),
        };
        let orbit = SpatialOrbitShape {
            a,
            e: self.e,
            inclination: self.inclination_deg.to_radians(),
            raan: self.raan_deg.to_radians(),
            omega: self.argp_deg.to_radians(),
        };
        match orbit.invalid() {
            Some(why) => Err(error(why)),
            None => Ok(orbit),
        }
    }
}

/// A problem file: the body, the spacecraft, the time of flight, the departure state, and
/// either the state to meet at arrival (a rendezvous) or the orbit to reach (a transfer).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SpatialProblemSpec {
    /// The central body (as in mission files; default the Sun in AU).
    #[serde(default = "sun")]
    pub body: BodySpec,
    /// Thrust, specific impulse and initial mass.
    pub spacecraft: Spacecraft,
    /// Time of flight, days.
    pub time_of_flight_days: f64,
    /// State at departure.
    pub departure: StateSpec,
    /// State to meet at arrival (a rendezvous).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arrival: Option<StateSpec>,
    /// Orbit to reach anywhere on it (a transfer).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_orbit: Option<TargetOrbitSpec>,
}

/// Why a problem file cannot be posed.
#[derive(Debug, thiserror::Error)]
pub enum SpatialProblemError {
    /// The file cannot be read or is not a problem file.
    #[error("{path}: {why}")]
    File {
        /// The file.
        path: String,
        /// Why.
        why: String,
    },
    /// The body cannot be posed.
    #[error(transparent)]
    Body(#[from] MissionError),
    /// A body given by figures that are not finite and positive.
    #[error("body: mu ({mu_m3_s2} m^3/s^2) and the length unit ({length_unit_m} m) must be finite and positive")]
    BodyFigures {
        /// Gravitational parameter given.
        mu_m3_s2: f64,
        /// Length unit given.
        length_unit_m: f64,
    },
    /// The spacecraft cannot be posed.
    #[error("spacecraft: {0}")]
    Spacecraft(#[from] SpacecraftError),
    /// A state is given twice, not at all, or not finite.
    #[error("{which}: {why}")]
    State {
        /// `departure`, `arrival` or `target_orbit`.
        which: &'static str,
        /// What is wrong.
        why: String,
    },
    /// The time of flight is not a positive number of days.
    #[error("time_of_flight_days must be a positive number of days, not {0}")]
    TimeOfFlight(f64),
    /// Neither or both of `[arrival]` and `[target_orbit]`.
    #[error("give either [arrival] (a rendezvous) or [target_orbit] (a transfer), one of them")]
    Goal,
}

impl StateSpec {
    pub(crate) fn state(&self, which: &'static str, units: &Units) -> Result<SpatialState, SpatialProblemError> {
        let error = |why: &str| SpatialProblemError::State {
            which,
            why: why.to_string(),
        };
        let r = match (self.r, self.r_km) {
            (Some(r), None) => r,
            (None, Some(km)) => km.map(|x| x * 1e3 / units.length_m),
            (Some(_), Some(_)) => return Err(error("give the position once: r (canonical) or r_km")),
            (None, None) => return Err(error("the position is missing: give r (canonical) or r_km")),
        };
        let v = match (self.v, self.v_km_s) {
            (Some(v), None) => v,
            (None, Some(km_s)) => km_s.map(|x| x * 1e3 / units.velocity_m_s()),
            (Some(_), Some(_)) => return Err(error("give the velocity once: v (canonical) or v_km_s")),
            (None, None) => return Err(error("the velocity is missing: give v (canonical) or v_km_s")),
        };
        let state = SpatialState { r, v };
        if !state.is_valid() {
            return Err(error("every component must be finite and the position off the centre"));
        }
        Ok(state)
    }
}

/// What a problem file asks for: meet a state, or reach an orbit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SpatialGoal {
    /// Meet the arrival state at the time of flight.
    Rendezvous(SpatialRendezvous),
    /// Reach the target orbit at the time of flight.
    Transfer(SpatialTransfer),
}

/// A solved goal: its flight as the rendezvous with the state it arrives at, and the solution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolvedGoal {
    /// The departure, mass, time and spacecraft of the goal, the arrival where it arrived.
    pub flight: SpatialRendezvous,
    /// The solution's costates, level, residual and mass.
    pub solution: SpatialSolution,
    /// A transfer's arrival anomaly on the target orbit (rad).
    pub final_anomaly: Option<f64>,
}

impl SpatialGoal {
    /// The goal a scenario of a family poses, each orbit in its plane.
    pub fn of_scenario(scenario: &SpatialScenario, spacecraft: CanonicalSpacecraft) -> Result<Self, SpatialSolveError> {
        match scenario.scenario.problem {
            ProblemKind::Rendezvous => SpatialRendezvous::from_scenario(scenario, spacecraft)
                .map(Self::Rendezvous)
                .map_err(|e| SpatialSolveError::NotSolved(format!("the body's arrival state: {e:?}"))),
            ProblemKind::Transfer => Ok(Self::Transfer(SpatialTransfer::from_scenario(scenario, spacecraft))),
        }
    }

    /// The goal from another start: `departure` with `initial_mass`, `time_of_flight` left.
    pub fn from(&self, departure: SpatialState, initial_mass: f64, time_of_flight: f64) -> Self {
        match *self {
            Self::Rendezvous(p) => Self::Rendezvous(SpatialRendezvous {
                departure,
                initial_mass,
                time_of_flight,
                ..p
            }),
            Self::Transfer(p) => Self::Transfer(SpatialTransfer {
                departure,
                initial_mass,
                time_of_flight,
                ..p
            }),
        }
    }

    /// The same goal met `by` (t*, in (0, time of flight)) earlier: a rendezvous meets its body
    /// where it is then (its arrival state coasted back), a transfer reaches its orbit sooner.
    /// The flight then coasts with its target to the original time: a margin kept for thrust
    /// lost on the way.
    pub fn arriving_early(&self, by: f64) -> Result<Self, SpatialSolveError> {
        let time_of_flight = self.time_of_flight() - by;
        if !(by > 0.0 && time_of_flight > 0.0) {
            return Err(SpatialSolveError::Invalid(
                "an arrival margin must lie inside the time of flight",
            ));
        }
        Ok(match *self {
            Self::Rendezvous(p) => Self::Rendezvous(SpatialRendezvous {
                arrival: onboard::kepler::coast3(&p.arrival, -by)
                    .map_err(|e| SpatialSolveError::NotSolved(format!("the body's earlier state: {e:?}")))?,
                time_of_flight,
                ..p
            }),
            Self::Transfer(p) => Self::Transfer(SpatialTransfer { time_of_flight, ..p }),
        })
    }

    /// The same goal for a spacecraft with its thrust scaled by `scale` (the exhaust speed
    /// kept): a plan at (1 - margin) of the thrust, flown at full thrust with its throttle
    /// scaled, keeps the margin in hand on every thrust arc.
    pub fn with_thrust_scaled(&self, scale: f64) -> Self {
        let scaled = |sc: CanonicalSpacecraft| CanonicalSpacecraft {
            thrust: sc.thrust * scale,
            ..sc
        };
        match *self {
            Self::Rendezvous(p) => Self::Rendezvous(SpatialRendezvous {
                spacecraft: scaled(p.spacecraft),
                ..p
            }),
            Self::Transfer(p) => Self::Transfer(SpatialTransfer {
                spacecraft: scaled(p.spacecraft),
                ..p
            }),
        }
    }

    /// The time of flight (t*).
    pub fn time_of_flight(&self) -> f64 {
        match self {
            Self::Rendezvous(p) => p.time_of_flight,
            Self::Transfer(p) => p.time_of_flight,
        }
    }

    /// Solves the goal (docs/spec.md section 3.6) from the problem's own guesses.
    pub fn solve(&self, options: &SolveOptions) -> Result<SolvedGoal, SpatialSolveError> {
        match self {
            Self::Rendezvous(p) => Ok(SolvedGoal {
                flight: *p,
                solution: solve_spatial_rendezvous(p, Vec::new(), options)?,
                final_anomaly: None,
            }),
            Self::Transfer(p) => {
                let s = solve_spatial_transfer(p, Vec::new(), options)?;
                Ok(SolvedGoal {
                    flight: SpatialRendezvous {
                        departure: p.departure,
                        initial_mass: p.initial_mass,
                        arrival: p.target.cartesian_at(s.final_anomaly),
                        time_of_flight: p.time_of_flight,
                        spacecraft: p.spacecraft,
                    },
                    solution: SpatialSolution {
                        costates: s.costates,
                        final_eps: s.final_eps,
                        residual: s.residual,
                        final_mass: s.final_mass,
                        distinct_energy_optima: s.distinct_energy_optima,
                    },
                    final_anomaly: Some(s.final_anomaly),
                })
            }
        }
    }
}

/// A problem file's goal in canonical units, with what converts back.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PosedProblem {
    /// The goal, canonical.
    pub goal: SpatialGoal,
    /// The body.
    pub body: CentralBody,
    /// Its canonical units.
    pub units: Units,
    /// The spacecraft as given.
    pub spacecraft: Spacecraft,
}

impl SpatialProblemSpec {
    /// Reads a problem file (TOML).
    pub fn from_file(path: &Path) -> Result<Self, SpatialProblemError> {
        let file_error = |why: String| SpatialProblemError::File {
            path: path.display().to_string(),
            why,
        };
        let text = std::fs::read_to_string(path).map_err(|e| file_error(e.to_string()))?;
        toml::from_str(&text).map_err(|e| file_error(e.to_string()))
    }

    /// The problem in the body's canonical units, checked.
    pub fn pose(&self) -> Result<PosedProblem, SpatialProblemError> {
        let body = self.body.body()?;
        if !(body.mu_m3_s2.is_finite()
            && body.mu_m3_s2 > 0.0
            && body.length_unit_m.is_finite()
            && body.length_unit_m > 0.0)
        {
            return Err(SpatialProblemError::BodyFigures {
                mu_m3_s2: body.mu_m3_s2,
                length_unit_m: body.length_unit_m,
            });
        }
        let units = body.units();
        let days = self.time_of_flight_days;
        if !(days.is_finite() && days > 0.0) {
            return Err(SpatialProblemError::TimeOfFlight(days));
        }
        let departure = self.departure.state("departure", &units)?;
        let time_of_flight = days * DAY_S / units.time_s;
        let spacecraft = self.spacecraft.canonical_in(&units)?;
        let goal = match (&self.arrival, &self.target_orbit) {
            (Some(arrival), None) => SpatialGoal::Rendezvous(SpatialRendezvous {
                departure,
                initial_mass: 1.0,
                arrival: arrival.state("arrival", &units)?,
                time_of_flight,
                spacecraft,
            }),
            (None, Some(orbit)) => SpatialGoal::Transfer(SpatialTransfer {
                departure,
                initial_mass: 1.0,
                target: orbit.orbit(&units)?,
                time_of_flight,
                spacecraft,
            }),
            _ => return Err(SpatialProblemError::Goal),
        };
        Ok(PosedProblem {
            goal,
            body,
            units,
            spacecraft: self.spacecraft,
        })
    }
}

/// What a solve of a problem file found, in physical units.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SpatialReport {
    /// Time of flight, days.
    pub time_of_flight_days: f64,
    /// Final mass, kg.
    pub final_mass_kg: f64,
    /// Propellant used, kg.
    pub propellant_kg: f64,
    /// The homotopy level of the solution (docs/spec.md section 3.3).
    pub final_eps: f64,
    /// Largest terminal residual of a fresh propagation, canonical (max norm).
    pub residual: f64,
    /// Arrival position miss, m, and velocity miss, m/s (from that propagation).
    pub position_miss_m: f64,
    /// See `position_miss_m`.
    pub velocity_miss_m_s: f64,
    /// Maximal intervals with throttle above 1/2 on the sampled grid.
    pub thrust_arcs: u32,
    /// Share of the flight with throttle above 1/2 on the sampled grid.
    pub thrusting_share: f64,
    /// Distinct energy-optimal solutions the multi-start found.
    pub distinct_energy_optima: u32,
    /// A transfer's arrival true anomaly on the target orbit, degrees.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub final_anomaly_deg: Option<f64>,
    /// Initial costates (lambda_r, lambda_v, lambda_m), canonical.
    pub costates: [f64; 7],
    /// Wall time of the solve and the sampling, s.
    pub seconds: f64,
}

/// Samples on the report's grid (evenly spread over the flight, both ends included).
pub const REPORT_SAMPLES: usize = 401;

/// Solves a posed problem and samples it on [`REPORT_SAMPLES`] epochs.
pub fn solve_posed(
    posed: &PosedProblem,
    options: &SolveOptions,
) -> Result<(SpatialReport, SolvedGoal, Vec<SpatialSample>), SpatialSolveError> {
    let clock = Instant::now();
    let solved = posed.goal.solve(options)?;
    let (problem, solution) = (&solved.flight, &solved.solution);
    let tof = problem.time_of_flight;
    let times: Vec<f64> = (0..REPORT_SAMPLES)
        .map(|k| tof * k as f64 / (REPORT_SAMPLES - 1) as f64)
        .collect();
    let samples = sample_solution(problem, solution, &times, &options.tolerances)
        .map_err(|e| SpatialSolveError::NotSolved(format!("sampling the solution failed: {e:?}")))?;
    let last = samples
        .last()
        .copied()
        .ok_or_else(|| SpatialSolveError::NotSolved("no samples".into()))?;
    let miss = |a: [f64; 3], b: [f64; 3]| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
    let thrust_arcs = crate::solver::record::count_arcs(samples.iter().map(|s| s.throttle));
    let thrusting = samples.iter().filter(|s| s.throttle > 0.5).count();
    let m0 = posed.spacecraft.initial_mass_kg;
    let report = SpatialReport {
        time_of_flight_days: tof * posed.units.time_s / DAY_S,
        final_mass_kg: solution.final_mass * m0,
        propellant_kg: (1.0 - solution.final_mass) * m0,
        final_eps: solution.final_eps,
        residual: solution.residual,
        position_miss_m: miss(last.state.r, problem.arrival.r) * posed.units.length_m,
        velocity_miss_m_s: miss(last.state.v, problem.arrival.v) * posed.units.velocity_m_s(),
        thrust_arcs,
        thrusting_share: thrusting as f64 / samples.len() as f64,
        distinct_energy_optima: solution.distinct_energy_optima,
        final_anomaly_deg: solved.final_anomaly.map(f64::to_degrees),
        costates: core::array::from_fn(|k| solution.costates[k]),
        seconds: clock.elapsed().as_secs_f64(),
    };
    Ok((report, solved, samples))
}

/// The samples as CSV: time (days), position (km), velocity (km/s), mass (kg), throttle and the
/// unit thrust direction, one row per sample.
pub fn trajectory_csv(posed: &PosedProblem, samples: &[SpatialSample]) -> String {
    let (l_km, v_km_s) = (posed.units.length_m / 1e3, posed.units.velocity_m_s() / 1e3);
    let mut csv = String::from("t_days,x_km,y_km,z_km,vx_km_s,vy_km_s,vz_km_s,mass_kg,throttle,ux,uy,uz\n");
    for s in samples {
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{},{},{},{},{},{}",
            s.t * posed.units.time_s / DAY_S,
            s.state.r[0] * l_km,
            s.state.r[1] * l_km,
            s.state.r[2] * l_km,
            s.state.v[0] * v_km_s,
            s.state.v[1] * v_km_s,
            s.state.v[2] * v_km_s,
            s.m * posed.spacecraft.initial_mass_kg,
            s.throttle,
            s.direction[0],
            s.direction[1],
            s.direction[2],
        );
    }
    csv
}

/// One missed-thrust case of a solved rendezvous ([`missed_thrust_cases`]): the thrust is lost
/// for one guidance cycle, and the rest of the flight is re-planned to the same arrival.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MissedThrustCase {
    /// The cycle lost (0-based).
    pub cycle: u32,
    /// Its start, days after departure.
    pub start_days: f64,
    /// Share of the cycle the optimum thrusts (above half throttle, on 32 samples): what was lost.
    pub optimum_thrusting_share: f64,
    /// Final mass of the re-planned flight, kg, when one was found.
    pub final_mass_kg: Option<f64>,
    /// Propellant the event costs against the optimum, kg.
    pub extra_propellant_kg: Option<f64>,
    /// Why no re-planned flight reaches the arrival (infeasible in the time left, or unsolved).
    pub failure: Option<String>,
}

/// Flies the plan `solved` (the optimum of `posed`, or of its goal arriving whole cycles early:
/// [`SpatialGoal::arriving_early`]) with the thrust lost over each of its guidance cycles in
/// turn (`cycles` equal cycles over `posed`'s time of flight; a Keplerian coast where the plan
/// would thrust), and re-plans the rest of the flight from the end of the lost cycle, with the
/// mass it had there, to `posed`'s goal (arrival state, or target orbit) at its time, by the
/// indirect method (docs/spec.md section 3.6); the extra propellant is counted against the plan.
/// A plan that arrives early has its margin's cycles left to re-plan in; without one, a loss in
/// the last cycle leaves no time: it is a recovery only if the optimum coasts there.
pub fn missed_thrust_cases(
    posed: &PosedProblem,
    solved: &SolvedGoal,
    cycles: u32,
    options: &SolveOptions,
) -> Vec<MissedThrustCase> {
    use crate::solver::pontryagin::OptimalControlParams;
    use crate::solver::spatial::{idx3, optimal_control3, propagate3};
    use rayon::prelude::*;
    let (problem, solution) = (&solved.flight, &solved.solution);
    let params = OptimalControlParams {
        spacecraft: problem.spacecraft,
        eps: solution.final_eps,
    };
    let y0 = problem.initial_state_costate(&solution.costates);
    let goal_time = posed.goal.time_of_flight();
    let cycle = goal_time / f64::from(cycles.max(1));
    // The plan's own cycles: all of them, or those before its early arrival.
    let planned = ((problem.time_of_flight / cycle).round() as u32).min(cycles);
    let m0 = posed.spacecraft.initial_mass_kg;
    let at = |t: f64| {
        if t > 0.0 {
            propagate3(&params, 0.0, &y0, t, &options.tolerances)
        } else {
            Ok(y0)
        }
    };
    (0..planned)
        .into_par_iter()
        .map(|k| {
            let start = f64::from(k) * cycle;
            let mut case = MissedThrustCase {
                cycle: k,
                start_days: start * posed.units.time_s / DAY_S,
                optimum_thrusting_share: f64::NAN,
                final_mass_kg: None,
                extra_propellant_kg: None,
                failure: None,
            };
            let samples: Result<Vec<_>, _> = (0..32)
                .map(|j| at(start + cycle * (f64::from(j) + 0.5) / 32.0))
                .collect();
            let y = match (at(start), samples) {
                (Ok(y), Ok(samples)) => {
                    let on = samples.iter().filter(|y| optimal_control3(y, &params).0 > 0.5).count();
                    case.optimum_thrusting_share = on as f64 / 32.0;
                    y
                }
                (Err(e), _) | (_, Err(e)) => {
                    case.failure = Some(format!("the optimum's propagation failed: {e:?}"));
                    return case;
                }
            };
            let here = SpatialState {
                r: core::array::from_fn(|i| y[idx3::R + i]),
                v: core::array::from_fn(|i| y[idx3::V + i]),
            };
            let mass = y[idx3::M];
            let coasted = match onboard::kepler::coast3(&here, cycle) {
                Ok(s) => s,
                Err(e) => {
                    case.failure = Some(format!("the coast failed: {e:?}"));
                    return case;
                }
            };
            let left = goal_time - f64::from(k + 1) * cycle;
            if k + 1 == cycles {
                // No time left: the loss is recovered only where the coast ends where the
                // optimum does (it coasts through the whole cycle), to the acceptance accuracy.
                let end = match at(problem.time_of_flight) {
                    Ok(y) => y,
                    Err(e) => {
                        case.failure = Some(format!("the optimum's propagation failed: {e:?}"));
                        return case;
                    }
                };
                let gap = (0..3)
                    .map(|i| {
                        (coasted.r[i] - end[idx3::R + i])
                            .abs()
                            .max((coasted.v[i] - end[idx3::V + i]).abs())
                    })
                    .fold(0.0, f64::max);
                if gap <= options.newton.tolerance {
                    case.final_mass_kg = Some(mass * m0);
                    case.extra_propellant_kg = Some((solution.final_mass - mass) * m0);
                } else {
                    case.failure = Some(format!(
                        "no time left to re-plan: the flight ends {gap:.1e} from the goal"
                    ));
                }
                return case;
            }
            match posed.goal.from(coasted, mass, left).solve(options) {
                Ok(replanned) => {
                    let s = replanned.solution;
                    case.final_mass_kg = Some(s.final_mass * m0);
                    case.extra_propellant_kg = Some((solution.final_mass - s.final_mass) * m0);
                }
                Err(e) => case.failure = Some(e.to_string()),
            }
            case
        })
        .collect()
}

/// The missed-thrust cases as CSV, one row per lost cycle.
pub fn missed_thrust_csv(cases: &[MissedThrustCase]) -> String {
    let mut csv = String::from("cycle,start_days,optimum_thrusting_share,final_mass_kg,extra_propellant_kg,failure\n");
    let show = |x: Option<f64>| x.map_or_else(String::new, |x| x.to_string());
    for c in cases {
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{}",
            c.cycle,
            c.start_days,
            c.optimum_thrusting_share,
            show(c.final_mass_kg),
            show(c.extra_propellant_kg),
            c.failure.as_deref().unwrap_or("").replace(',', ";")
        );
    }
    csv
}

/// Orbit points drawn for the departure and arrival orbits.
const ORBIT_SAMPLES: usize = 360;

/// The optimum of a problem file as one figure (SVG): the path projected on the reference
/// plane (x, y) with the departure and arrival orbits, thrust arcs in red; the out-of-plane
/// distance z and the throttle against time; and with `missed` the extra propellant each lost
/// cycle costs, unreachable arrivals marked at the top.
pub fn plot_spatial_optimum(
    posed: &PosedProblem,
    flight: &SpatialRendezvous,
    samples: &[SpatialSample],
    missed: Option<&[MissedThrustCase]>,
    path: &Path,
) -> Result<(), crate::plot::PlotError> {
    use crate::plot::{
        check_svg_path, draw_orbit_plane, render_svg, OrbitPlaneLayer, PlotError, COAST_COLOR, LABEL_SIZE,
        THRUST_COLOR, TICK_SIZE, TITLE_SIZE,
    };
    use plotters::prelude::*;
    check_svg_path(path)?;
    if samples.len() < 2
        || samples
            .iter()
            .any(|s| !(s.state.r.iter().all(|x| x.is_finite()) && s.throttle.is_finite()))
    {
        return Err(PlotError::NonFinite { record: 0 });
    }
    let problem = flight;
    let orbit_of = |state: &SpatialState| -> Vec<(f64, f64)> {
        let period = 2.0 * std::f64::consts::PI * (-0.5 / state.energy()).powf(1.5);
        (0..=ORBIT_SAMPLES)
            .filter_map(|k| onboard::kepler::coast3(state, period * k as f64 / ORBIT_SAMPLES as f64).ok())
            .map(|s| (s.r[0], s.r[1]))
            .collect()
    };
    let points: Vec<(f64, (f64, f64))> = samples
        .iter()
        .map(|s| (s.throttle, (s.state.r[0], s.state.r[1])))
        .collect();
    let runs = crate::plot::thrust_runs_of(&points);
    let days = |t: f64| t * posed.units.time_s / DAY_S;
    let first = samples[0].state.r;
    let last = samples[samples.len() - 1].state.r;
    let final_mass = samples[samples.len() - 1].m * posed.spacecraft.initial_mass_kg;
    let layer = OrbitPlaneLayer {
        initial: orbit_of(&problem.departure),
        target: orbit_of(&problem.arrival),
        runs,
        start: Some((first[0], first[1])),
        end: Some((last[0], last[1])),
        label: format!("{:.2} days", days(problem.time_of_flight)),
        notes: vec![(format!("final mass {final_mass:.3} kg"), BLACK)],
    };
    let z_km: Vec<(f64, f64)> = samples
        .iter()
        .map(|s| (days(s.t), s.state.r[2] * posed.units.length_m / 1e9))
        .collect();
    let throttle: Vec<(f64, f64)> = samples.iter().map(|s| (days(s.t), s.throttle)).collect();
    let tof_days = days(problem.time_of_flight);
    let svg = render_svg((1900, 960), |root| {
        let (left, right) = root.split_horizontally(1100);
        let title = match posed.goal {
            SpatialGoal::Rendezvous(_) => "Fuel-optimal rendezvous, projected on the xy-plane",
            SpatialGoal::Transfer(_) => "Fuel-optimal transfer, projected on the xy-plane",
        };
        draw_orbit_plane(&left, title, 300, &[layer])?;
        let panels = right.split_evenly((if missed.is_some() { 3 } else { 2 }, 1));
        let line_chart = |area: &crate::plot::Area<'_>,
                          points: &[(f64, f64)],
                          y_desc: &str,
                          color: RGBColor|
         -> Result<(), PlotError> {
            let (lo, hi) = points.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.1), hi.max(p.1))
            });
            let pad = 0.05 * (hi - lo).max(1e-12);
            let mut chart = ChartBuilder::on(area)
                .margin(15)
                .x_label_area_size(50)
                .y_label_area_size(80)
                .build_cartesian_2d(0.0..tof_days, (lo - pad)..(hi + pad))?;
            chart
                .configure_mesh()
                .x_desc("days since departure")
                .y_desc(y_desc)
                .axis_desc_style(("sans-serif", LABEL_SIZE))
                .label_style(("sans-serif", TICK_SIZE))
                .draw()?;
            chart.draw_series(LineSeries::new(points.iter().copied(), color.stroke_width(3)))?;
            Ok(())
        };
        line_chart(&panels[0], &z_km, "z [million km]", COAST_COLOR)?;
        line_chart(&panels[1], &throttle, "throttle", THRUST_COLOR)?;
        if let (Some(cases), Some(area)) = (missed, panels.get(2)) {
            let width = tof_days / cases.len().max(1) as f64;
            let top = cases.iter().filter_map(|c| c.extra_propellant_kg).fold(1e-3, f64::max) * 1.15;
            let mut chart = ChartBuilder::on(area)
                .margin(15)
                .caption(
                    "one cycle's thrust lost, rest re-planned",
                    ("sans-serif", TITLE_SIZE * 0.6),
                )
                .x_label_area_size(50)
                .y_label_area_size(80)
                .build_cartesian_2d(0.0..tof_days, 0.0..top)?;
            chart
                .configure_mesh()
                .x_desc("lost cycle's start [days]")
                .y_desc("extra propellant [kg]")
                .axis_desc_style(("sans-serif", LABEL_SIZE))
                .label_style(("sans-serif", TICK_SIZE))
                .draw()?;
            chart.draw_series(cases.iter().filter_map(|c| {
                let extra = c.extra_propellant_kg?.max(0.0);
                Some(Rectangle::new(
                    [(c.start_days, 0.0), (c.start_days + 0.9 * width, extra)],
                    COAST_COLOR.filled(),
                ))
            }))?;
            chart.draw_series(cases.iter().filter(|c| c.extra_propellant_kg.is_none()).map(|c| {
                Cross::new(
                    (c.start_days + 0.45 * width, 0.93 * top),
                    8,
                    THRUST_COLOR.stroke_width(3),
                )
            }))?;
        }
        Ok(())
    })?;
    crate::io::atomic_write(path, svg.as_bytes()).map_err(PlotError::Io)
}

/// The figure of [`plot_spatial_optimum`] for the first converged record of the inclined
/// family's dataset in `out` (shard `shard`), flown by `spacecraft` (the one it was solved
/// for), written to `out/trajectories.svg`. Returns how many trajectories it shows (0 or 1).
pub fn plot_spatial_dataset_sample(
    out: &Path,
    shard: crate::generate::Shard,
    spacecraft: &Spacecraft,
) -> Result<usize, Box<dyn std::error::Error>> {
    let file =
        crate::generate::read_dataset_of::<shared::mission::SpatialFamily>(&crate::generate::dataset_path(out, shard))?;
    let Some(record) = file.records.iter().find(|r| r.converged && r.ephemeris.len() > 1) else {
        return Ok(0);
    };
    let body = file.manifest.family.family.body;
    let units = body.units();
    let canonical = spacecraft.canonical_in(&units)?;
    let goal = SpatialGoal::of_scenario(&record.scenario, canonical)?;
    let end = record.ephemeris[record.ephemeris.len() - 1].state;
    let flight = SpatialRendezvous {
        departure: record.scenario.departure(),
        initial_mass: 1.0,
        arrival: end,
        time_of_flight: goal.time_of_flight(),
        spacecraft: canonical,
    };
    let posed = PosedProblem {
        goal,
        body,
        units,
        spacecraft: *spacecraft,
    };
    plot_spatial_optimum(&posed, &flight, &record.ephemeris, None, &out.join("trajectories.svg"))?;
    Ok(1)
}

/// One draw of a planar family solved by the planar solver and, embedded in three dimensions,
/// by the spatial one from its own guesses ([`compare_with_planar`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlanarComparison {
    /// Scenario index.
    pub index: u64,
    /// Final mass (fraction of m0) of the planar record, when it converged.
    pub planar_mass: Option<f64>,
    /// Final mass of the spatial solution, when one was found.
    pub spatial_mass: Option<f64>,
    /// Why the spatial solve failed.
    pub spatial_failure: Option<String>,
    /// Distinct energy-optimal starts each solver found (planar, spatial): different local
    /// optima start there.
    pub distinct_energy_optima: (u32, u32),
}

impl PlanarComparison {
    /// |spatial - planar| / planar when both solved.
    pub fn relative_difference(&self) -> Option<f64> {
        Some((self.spatial_mass? - self.planar_mass?).abs() / self.planar_mass?)
    }
}

/// Draws `indices` of the planar family from stream `seed`, solves each with the planar solver
/// and the spatial one (docs/spec.md section 3.6: the optima must agree), in
/// parallel.
pub fn compare_with_planar(
    family: &shared::mission::MissionFamily,
    seed: u64,
    indices: std::ops::Range<u64>,
    spacecraft: &shared::spacecraft::CanonicalSpacecraft,
    options: &SolveOptions,
) -> Vec<PlanarComparison> {
    use rayon::prelude::*;
    indices
        .into_par_iter()
        .map(|index| {
            let scenario = family.draw(seed, index);
            let planar = crate::solver::solve_scenario(*family, seed, index, &scenario, spacecraft, options);
            let spatial = SpatialGoal::of_scenario(&SpatialScenario::planar(scenario), *spacecraft)
                .and_then(|goal| goal.solve(options))
                .map(|solved| solved.solution);
            PlanarComparison {
                index,
                planar_mass: planar.converged.then_some(planar.final_mass),
                spatial_mass: spatial.as_ref().ok().map(|s| s.final_mass),
                distinct_energy_optima: (
                    planar.distinct_energy_optima,
                    spatial.as_ref().map_or(0, |s| s.distinct_energy_optima),
                ),
                spatial_failure: spatial.err().map(|e| e.to_string()),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(text: &str) -> SpatialProblemSpec {
        toml::from_str(text).unwrap()
    }

    const BASE: &str = r#"
        time_of_flight_days = 300.0
        [spacecraft]
        max_thrust_n = 0.5
        isp_s = 2000.0
        initial_mass_kg = 1000.0
    "#;

    #[test]
    fn states_in_km_convert_to_the_bodys_units() {
        let posed = spec(&format!(
            "{BASE}\n[departure]\nr_km = [149597870.7, 0.0, 0.0]\nv_km_s = [0.0, 29.78469183, 0.0]\n\
             [arrival]\nr = [0.0, 1.5, 0.01]\nv = [-0.8, 0.0, 0.0]\n"
        ))
        .pose()
        .unwrap();
        let SpatialGoal::Rendezvous(problem) = posed.goal else {
            panic!("not a rendezvous: {:?}", posed.goal)
        };
        let d = problem.departure;
        assert!((d.r[0] - 1.0).abs() < 1e-15 && d.r[1] == 0.0);
        // The Sun's velocity unit is 29,784.69 m/s (docs/spec.md section 1).
        assert!((d.v[1] - 1.0).abs() < 1e-8, "{}", d.v[1]);
        assert_eq!(problem.arrival.r, [0.0, 1.5, 0.01]);
        // 300 days in the Sun's time unit of 5,022,642.89 s.
        assert!((problem.time_of_flight - 300.0 * 86400.0 / 5_022_642.89).abs() < 1e-8);
    }

    #[test]
    fn bad_problems_are_refused_with_the_field_named() {
        let twice = spec(&format!(
            "{BASE}\n[departure]\nr = [1.0, 0.0, 0.0]\nr_km = [1.0, 0.0, 0.0]\nv = [0.0, 1.0, 0.0]\n\
             [arrival]\nr = [0.0, 1.5, 0.0]\nv = [-0.8, 0.0, 0.0]\n"
        ));
        let e = twice.pose().unwrap_err().to_string();
        assert!(e.contains("departure") && e.contains("once"), "{e}");
        let missing = spec(&format!(
            "{BASE}\n[departure]\nr = [1.0, 0.0, 0.0]\nv = [0.0, 1.0, 0.0]\n[arrival]\nr = [0.0, 1.5, 0.0]\n"
        ));
        let e = missing.pose().unwrap_err().to_string();
        assert!(e.contains("arrival") && e.contains("velocity"), "{e}");
        let centre = spec(&format!(
            "{BASE}\n[departure]\nr = [0.0, 0.0, 0.0]\nv = [0.0, 1.0, 0.0]\n[arrival]\nr = [0.0, 1.5, 0.0]\nv = [-0.8, 0.0, 0.0]\n"
        ));
        assert!(centre.pose().unwrap_err().to_string().contains("departure"));
        let mut bad_time = centre.clone();
        bad_time.departure.r = Some([1.0, 0.0, 0.0]);
        bad_time.time_of_flight_days = -3.0;
        assert!(matches!(bad_time.pose(), Err(SpatialProblemError::TimeOfFlight(_))));
        let mut bad_craft = bad_time.clone();
        bad_craft.time_of_flight_days = 300.0;
        bad_craft.spacecraft.max_thrust_n = f64::NAN;
        assert!(bad_craft.pose().unwrap_err().to_string().starts_with("spacecraft"));
        assert!(toml::from_str::<SpatialProblemSpec>(&format!("{BASE}\nextra = 1\n")).is_err());
    }

    /// The shipped Earth-Mars problem file (Zavoli and Federici's rendezvous) solves to the
    /// final level, and the solution passes checks independent of the shooting: the Hamiltonian
    /// of this autonomous system is constant along it, the propellant is the thrust's flow
    /// integrated over the sampled throttle, and the terminal conditions hold on a fresh
    /// propagation.
    #[test]
    fn the_earth_mars_optimum_conserves_the_hamiltonian_and_its_propellant() {
        use crate::solver::pontryagin::OptimalControlParams;
        use crate::solver::spatial::{hamiltonian3, optimal_control3, propagate3};
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/missions/earth-mars-optimum.toml");
        let posed = SpatialProblemSpec::from_file(&path).unwrap().pose().unwrap();
        let options = SolveOptions::default();
        let (report, solved, samples) = solve_posed(&posed, &options).unwrap();
        let solution = &solved.solution;
        assert!(report.residual <= 1e-8 && report.final_eps < 1e-4, "{report:?}");
        // Above the 600.23 kg of the published PPO policy, below the initial mass.
        assert!(
            report.final_mass_kg > 600.23 && report.final_mass_kg < 1000.0,
            "{report:?}"
        );
        let problem = &solved.flight;
        let params = OptimalControlParams {
            spacecraft: problem.spacecraft,
            eps: solution.final_eps,
        };
        let y0 = problem.initial_state_costate(&solution.costates);
        let h = |y: &[f64; 14]| {
            let (u, alpha) = optimal_control3(y, &params);
            hamiltonian3(y, u, alpha, &params)
        };
        let h0 = h(&y0);
        for t in [0.5, 1.7, 3.1, 4.4, problem.time_of_flight] {
            let y = propagate3(&params, 0.0, &y0, t, &options.tolerances).unwrap();
            assert!(
                (h(&y) - h0).abs() < 1e-9 * (1.0 + h0.abs()),
                "H({t}) = {} against {h0}",
                h(&y)
            );
        }
        // dm/dt = -T u / c: the trapezoid over 401 samples is exact on every interval where
        // the throttle holds, and off by at most half an interval's flow on each interval
        // that holds a switch.
        let dt = problem.time_of_flight / (samples.len() - 1) as f64;
        let flow = problem.spacecraft.thrust / problem.spacecraft.exhaust_speed;
        let burnt: f64 = samples
            .windows(2)
            .map(|w| 0.5 * (w[0].throttle + w[1].throttle) * dt)
            .sum();
        let switches = samples
            .windows(2)
            .filter(|w| (w[0].throttle - w[1].throttle).abs() > 1e-6)
            .count();
        assert!(switches >= 2 * report.thrust_arcs as usize - 2, "{switches} switches");
        let error = (flow * burnt - (1.0 - solution.final_mass)).abs();
        assert!(
            error <= 0.5 * flow * dt * switches as f64 + 1e-9,
            "{error:e} over {switches} switches"
        );
        for s in &samples {
            let n = s.direction.iter().map(|x| x * x).sum::<f64>().sqrt();
            assert!((n - 1.0).abs() < 1e-12);
        }
    }

    /// The cycles the plan coasts through, each with the final mass (kg) of its re-plan; at
    /// least 10 of them, every one re-planned.
    fn coasting_recoveries(cases: &[MissedThrustCase]) -> Vec<(u32, f64)> {
        let coasting: Vec<(u32, f64)> = cases
            .iter()
            .filter(|c| c.optimum_thrusting_share == 0.0)
            .map(|c| {
                let mass = c
                    .final_mass_kg
                    .unwrap_or_else(|| panic!("cycle {}: {:?}", c.cycle, c.failure));
                (c.cycle, mass)
            })
            .collect();
        assert!(coasting.len() >= 10, "{} coasting cycles", coasting.len());
        coasting
    }

    /// Bellman's principle as a check of the re-plans from mid-flight: losing the thrust in a
    /// cycle where the optimum coasts loses nothing, so the re-plan from the end of that cycle
    /// (its own multi-start and homotopy, from a mass below 1) must find the optimum's final mass
    /// again; a loss where the optimum thrusts costs propellant, and one in the last cycle, in
    /// the middle of the arrival burn, cannot be made up.
    #[test]
    fn a_missed_cycle_where_the_optimum_coasts_costs_nothing_and_one_that_thrusts_costs_propellant() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/missions/earth-mars-optimum.toml");
        let posed = SpatialProblemSpec::from_file(&path).unwrap().pose().unwrap();
        let options = SolveOptions::default();
        let (report, solved, _) = solve_posed(&posed, &options).unwrap();
        let cases = missed_thrust_cases(&posed, &solved, 40, &options);
        assert_eq!(cases.len(), 40);
        for (cycle, mass) in coasting_recoveries(&cases) {
            // Both solutions meet their terminal conditions to 1e-8: their masses agree to
            // about that (measured: 5e-9 relative at worst).
            let relative = (mass - report.final_mass_kg).abs() / report.final_mass_kg;
            assert!(
                relative < 2e-8,
                "cycle {cycle}: {mass} against {}",
                report.final_mass_kg
            );
        }
        for c in cases.iter().filter(|c| c.optimum_thrusting_share == 1.0) {
            if let Some(extra) = c.extra_propellant_kg {
                assert!(extra > 0.1, "cycle {}: {extra} kg", c.cycle);
            }
        }
        assert!(cases[0].extra_propellant_kg.unwrap() > 1.0);
        assert!(cases[39].failure.as_deref().unwrap().contains("no time left"));
    }

    /// A plan that meets the body one cycle early (585.4 kg) has one cycle fewer to lose, and
    /// its margin to re-plan in: every loss where the plan coasts is recovered at least as heavy
    /// as the plan (the plan itself, coasting with the body to the end, is still a flight to the
    /// goal), and the loss of its last cycle is re-planned, not refused for want of time. A plan
    /// at a share of the thrust is that weaker spacecraft's optimum.
    #[test]
    fn a_plan_with_a_margin_recovers_its_coasting_cycles_at_no_cost() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/missions/earth-mars-optimum.toml");
        let posed = SpatialProblemSpec::from_file(&path).unwrap().pose().unwrap();
        let options = SolveOptions::default();
        let cycle = posed.goal.time_of_flight() / 40.0;
        let plan = PosedProblem {
            goal: posed.goal.arriving_early(cycle).unwrap(),
            ..posed
        };
        let (report, solved, _) = solve_posed(&plan, &options).unwrap();
        assert!((report.final_mass_kg - 585.4).abs() < 0.05, "{}", report.final_mass_kg);
        let cases = missed_thrust_cases(&posed, &solved, 40, &options);
        assert_eq!(cases.len(), 39);
        for (cycle, mass) in coasting_recoveries(&cases) {
            assert!(mass >= report.final_mass_kg * (1.0 - 2e-8), "cycle {cycle}: {mass}");
        }
        assert!(!cases[38].failure.as_deref().unwrap_or("").contains("no time left"));
        // A plan at 95 % of the thrust is the optimum of the spacecraft whose thrust is 95 % of
        // it, posed from its own file: 599.1 kg.
        let mut weaker = SpatialProblemSpec::from_file(&path).unwrap();
        weaker.spacecraft.max_thrust_n *= 0.95;
        let direct = weaker.pose().unwrap().goal.solve(&options).unwrap().solution.final_mass;
        let scaled = posed
            .goal
            .with_thrust_scaled(0.95)
            .solve(&options)
            .unwrap()
            .solution
            .final_mass;
        assert!((direct - scaled).abs() < 1e-9 * direct, "{direct} vs {scaled}");
        assert!((scaled * 1000.0 - 599.1).abs() < 0.05, "{scaled}");
        assert!(matches!(
            posed.goal.arriving_early(posed.goal.time_of_flight()),
            Err(SpatialSolveError::Invalid(_))
        ));
    }
}
