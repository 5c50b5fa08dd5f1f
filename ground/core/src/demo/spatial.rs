//! Demonstrations in three dimensions (docs/spec.md section 7.1): for every guidance cycle of a
//! three-dimensional record, the zero-order-hold equivalent of its optimal control in the RTN
//! frame the onboard propagation holds a command in, the action that encodes it, the features
//! of the record's state, and the one-step mismatch of the onboard RTN propagation of (s_k, a_k)
//! against the record's s_k+1.
//!
//! As in the plane, the integral w = (1/cycle) ∫ u (alpha . r_hat, alpha . t_hat, alpha . n_hat) dt
//! is taken by re-integrating the solver's state-costate system (its modal propagation, switches
//! located) from the record's costates, each cycle from its boundary, and the re-integrated
//! states are checked against the record's samples.

use onboard::features::{encode_action3, ACTION3_LEN};
use onboard::integrator::Tolerances;
use onboard::spatial::{propagate_rtn, RtnCommand, SpatialCraftState};
use rayon::prelude::*;
use shared::orbit::{dot3, norm3, SpatialState};
use shared::spacecraft::CanonicalSpacecraft;

use shared::mission::SpatialFamily;
use shared::scenario::{ProblemKind, Scenario, SpatialScenario};

use super::{
    coast_to_the_end, tuple_at, DemoError, Demonstrations, Placement, RecordDemonstration, StepMismatch, ACTION_BOUND,
    COAST_THROTTLE, CONSISTENCY_TOLERANCE,
};
use crate::env::{self, EnvConfig, EnvError, Environment, MdpEnv, Problem};
use crate::solver::pontryagin::{run_modal, BranchRhs, NoClock, OptimalControlParams, Regime};
use crate::solver::spatial::record::solve_spatial_arriving_early;
use crate::solver::spatial::record::SpatialRecord;
use crate::solver::spatial::{
    idx3, initial_state_costate3, state_costate_rhs3_in, switching_function3, Spatial, SpatialSample, Y3_LEN,
};
use crate::solver::SolveOptions;

const AUG3_LEN: usize = Y3_LEN + 4;

/// The spatial state-costate system augmented with w' = u (alpha in RTN) and the mean throttle,
/// on the held throttle branch of the modal propagation.
struct RtnControlIntegral(OptimalControlParams);

impl BranchRhs<AUG3_LEN> for RtnControlIntegral {
    type Layout = Spatial;

    fn rhs(&self, y: &[f64; AUG3_LEN], regime: Regime, dydt: &mut [f64; AUG3_LEN]) {
        let core: [f64; Y3_LEN] = core::array::from_fn(|i| y[i]);
        let f = state_costate_rhs3_in(&core, &self.0, regime);
        dydt[..Y3_LEN].copy_from_slice(&f);
        let rho = switching_function3(&core, self.0.spacecraft.exhaust_speed);
        let u = regime.throttle(rho, self.0.eps);
        let alpha = primer(&core);
        let [r, t, n] = rtn_of(&core).map_or([f64::NAN; 3], |frame| frame.map(|e| dot3(&alpha, &e)));
        dydt[Y3_LEN..].copy_from_slice(&[u * r, u * t, u * n, u]);
    }
}

fn primer(y: &[f64; Y3_LEN]) -> [f64; 3] {
    let lv: [f64; 3] = core::array::from_fn(|k| y[idx3::LV + k]);
    let n = norm3(&lv);
    lv.map(|x| -x / n)
}

fn orbit_of(y: &[f64]) -> SpatialState {
    SpatialState {
        r: core::array::from_fn(|k| y[idx3::R + k]),
        v: core::array::from_fn(|k| y[idx3::V + k]),
    }
}

fn rtn_of(y: &[f64; Y3_LEN]) -> Option<[[f64; 3]; 3]> {
    orbit_of(y).rtn_frame()
}

/// The zero-order-hold equivalent of the optimal control over one cycle, in the RTN frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RtnZoh {
    /// w = (1/cycle) ∫ u (alpha_r, alpha_t, alpha_n) dt.
    pub w: [f64; 3],
    /// Mean throttle (1/cycle) ∫ u dt.
    pub mean_throttle: f64,
}

impl RtnZoh {
    /// The exact (unclipped, f64) command of w: throttle |w| capped at 1, direction w/|w|;
    /// thrust off below [`COAST_THROTTLE`].
    pub fn command(&self) -> RtnCommand {
        let u = norm3(&self.w);
        if u < COAST_THROTTLE {
            return RtnCommand::OFF;
        }
        RtnCommand {
            throttle: u.min(1.0),
            radial: self.w[0] / u,
            transverse: self.w[1] / u,
            normal: self.w[2] / u,
        }
    }

    /// The action encoding w, clipped to the action bound; thrust off below [`COAST_THROTTLE`]
    /// (a zero direction, which decodes to thrust off).
    pub fn action(&self) -> [f32; ACTION3_LEN] {
        let u = norm3(&self.w);
        let a = if u < COAST_THROTTLE {
            [-1.0, 0.0, 0.0, 0.0]
        } else {
            encode_action3(&self.command())
        };
        a.map(|x| x.clamp(-ACTION_BOUND, ACTION_BOUND) as f32)
    }
}

/// The action of a cycle with the thrust off (the 3D [`super::coast_action`]).
pub fn coast_action3() -> [f32; ACTION3_LEN] {
    RtnZoh {
        w: [0.0; 3],
        mean_throttle: 0.0,
    }
    .action()
}

/// The ZOH controls of every cycle of a three-dimensional record, the re-integrated states
/// checked against its step samples.
pub fn rtn_zoh_controls(
    record: &SpatialRecord,
    spacecraft: &CanonicalSpacecraft,
    tolerances: &Tolerances,
) -> Result<Vec<RtnZoh>, DemoError> {
    let scenario = &record.scenario.scenario;
    let n = scenario.steps;
    if record.steps.len() != n as usize + 1 {
        return Err(DemoError::NoSolution);
    }
    let params = OptimalControlParams {
        spacecraft: *spacecraft,
        eps: record.final_eps,
    };
    let costates = nalgebra::SVector::<f64, 7>::from_column_slice(&record.costates);
    let y0 = initial_state_costate3(&record.scenario.departure(), 1.0, &costates);
    let mut y: [f64; AUG3_LEN] = core::array::from_fn(|i| if i < Y3_LEN { y0[i] } else { 0.0 });
    let mut controls = Vec::with_capacity(n as usize);
    for k in 0..n {
        let (t0, t1) = (scenario.cycle_start(k), scenario.cycle_start(k + 1));
        y[Y3_LEN..].fill(0.0);
        y = run_modal(
            RtnControlIntegral(params),
            &params,
            t0,
            &y,
            t1,
            tolerances,
            1,
            &mut NoClock,
        )
        .map_err(|error| DemoError::Integration { step: k, error })?;
        let cycle = scenario.cycle;
        controls.push(RtnZoh {
            w: [y[Y3_LEN] / cycle, y[Y3_LEN + 1] / cycle, y[Y3_LEN + 2] / cycle],
            mean_throttle: y[Y3_LEN + 3] / cycle,
        });
        let deviation = record
            .steps
            .get(k as usize + 1)
            .map_or(f64::INFINITY, |s| deviation(s, &y));
        if deviation.is_nan() || deviation > CONSISTENCY_TOLERANCE {
            return Err(DemoError::Inconsistent { step: k + 1, deviation });
        }
    }
    Ok(controls)
}

fn deviation(s: &SpatialSample, y: &[f64; AUG3_LEN]) -> f64 {
    let o = orbit_of(y);
    let mine = o.r.iter().chain(&o.v).chain([&y[idx3::M]]);
    let theirs = s.state.r.iter().chain(&s.state.v).chain([&s.m]);
    mine.zip(theirs).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)
}

fn craft(s: &SpatialSample) -> SpatialCraftState {
    SpatialCraftState { orbit: s.state, m: s.m }
}

/// The tuples of a converged three-dimensional record for problem `P` ([`env::Transfer3`] or
/// [`env::Rendezvous3`]), from departure in the episode of its scenario, with the one-step mismatch
/// of every cycle: observations, rewards and done flags are the environment's at the record's
/// states, the actions encode the record's RTN ZOH controls (docs/spec.md section 7.1).
/// `tolerances` re-integrate the state-costate system; the environment flies with `config`'s.
pub fn spatial_demonstration<P: Problem<Geometry = env::Spatial>>(
    record: &SpatialRecord,
    config: &EnvConfig,
    tolerances: &Tolerances,
) -> Result<RecordDemonstration<P::Obs, [f32; ACTION3_LEN]>, DemoError> {
    let whole = Placement {
        episode: episode_of(record),
        start_step: 0,
        start_mass: 1.0,
    };
    placed_spatial_demonstration::<P>(record, &whole, config, tolerances)
}

/// The episode a record from departure fills: its draw's scenario, of which the record's is the
/// scenario itself or, for a record that arrives early (an arrival margin), the same shortened;
/// a record of no draw fills its own scenario's (the 3D [`Placement::whole`]).
pub fn episode_of(record: &SpatialRecord) -> SpatialScenario {
    super::episode_of_draw(record.scenario, record.family.draw(record.seed, record.index))
}

/// Relabels a three-dimensional state a policy visited (DAgger-style, the 3D twin of
/// [`super::relabel`]): the fuel-optimal rest of `episode` re-solved by the indirect method in
/// three dimensions from `state` at cycle `step`, as a record and its [`Placement`]. The rest
/// departs from the state's osculating orbit in its own plane; a rendezvous rest chases the same
/// body from where it is at that cycle; the spacecraft's thrust is counted in units of the
/// state's mass. `None` when the state has no orbit (not bound, or no plane), the step leaves no
/// flight, or the body's state cannot be computed. Solved with the options' arrival margin
/// ([`solve_spatial_arriving_early`]); labelled with `family` and (`seed`, `index`).
pub fn relabel_spatial(
    family: &SpatialFamily,
    (seed, index): (u64, u64),
    episode: &SpatialScenario,
    state: &SpatialCraftState,
    step: u32,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> Option<(SpatialRecord, Placement<SpatialScenario>)> {
    let plan = &episode.scenario;
    if step >= plan.steps || !(state.m > 0.0 && state.m <= 1.0) {
        return None;
    }
    let (initial, initial_plane) = state.orbit.elements()?;
    let target_nu0 = match plan.problem {
        ProblemKind::Transfer => plan.target_nu0,
        ProblemKind::Rendezvous => {
            // The body's angle in its own plane from the node, less its periapsis argument: its
            // true anomaly at the step.
            let body = env::body_at3(episode, step).ok()?;
            let [x, y] = episode.target_plane.to_plane(body.r);
            (y.atan2(x) - plan.target.omega).rem_euclid(core::f64::consts::TAU)
        }
    };
    let rest = SpatialScenario {
        scenario: Scenario {
            initial,
            steps: plan.steps - step,
            target_nu0,
            ..*plan
        },
        initial_plane,
        target_plane: episode.target_plane,
    };
    let scaled = CanonicalSpacecraft {
        thrust: spacecraft.thrust / state.m,
        ..*spacecraft
    };
    let record = solve_spatial_arriving_early(family, (seed, index), &rest, &scaled, options);
    let placement = Placement {
        episode: *episode,
        start_step: step,
        start_mass: state.m,
    };
    Some((record, placement))
}

/// The tuples of a converged three-dimensional record placed in an episode ([`Placement`]):
/// observations, rewards and done flags are the episode's at cycles start_step.., masses scaled by
/// the start mass, the actions the record's RTN ZOH controls (re-integrated with the thrust in
/// units of the start mass, as the record was solved). The record must fill the rest of its
/// episode.
pub fn placed_spatial_demonstration<P: Problem<Geometry = env::Spatial>>(
    record: &SpatialRecord,
    placement: &Placement<SpatialScenario>,
    config: &EnvConfig,
    tolerances: &Tolerances,
) -> Result<RecordDemonstration<P::Obs, [f32; ACTION3_LEN]>, DemoError> {
    let scenario = &placement.episode;
    for found in [record.scenario.scenario.problem, scenario.scenario.problem] {
        if found != P::KIND {
            return Err(DemoError::WrongProblem {
                expected: P::KIND,
                found,
            });
        }
    }
    // A record shorter than its episode arrived early (an arrival margin) and is coasted to
    // the end: only a converged one has arrived.
    let first_coast = placement.start_step + record.scenario.scenario.steps;
    if first_coast > scenario.scenario.steps
        || (first_coast < scenario.scenario.steps && !record.converged)
        || !(placement.start_mass > 0.0 && placement.start_mass <= 1.0)
    {
        return Err(DemoError::Placement);
    }
    let mut env = MdpEnv::<P>::new(config).map_err(DemoError::Env)?;
    let spacecraft = *env.spacecraft();
    let solved_with = CanonicalSpacecraft {
        thrust: spacecraft.thrust / placement.start_mass,
        ..spacecraft
    };
    let controls = rtn_zoh_controls(record, &solved_with, tolerances)?;
    let cycle = scenario.scenario.cycle;
    let env_tolerances = config.integrator.tolerances();
    let placed = |s: &SpatialSample| SpatialCraftState {
        m: s.m * placement.start_mass,
        ..craft(s)
    };
    let mut demo = RecordDemonstration {
        transitions: Vec::with_capacity(controls.len()),
        mismatch: Vec::with_capacity(controls.len()),
    };
    for ((j, control), pair) in (0u32..).zip(&controls).zip(record.steps.windows(2)) {
        let [now, next] = pair else {
            return Err(DemoError::NoSolution);
        };
        let k = placement.start_step + j;
        let (s_k, s_next) = (placed(now), placed(next));
        let (tuple, flown) = tuple_at(
            &mut env,
            config,
            scenario,
            (&s_k, &s_next),
            control.action(),
            (record.index, k),
        )?;
        demo.transitions.push(tuple);
        let unclipped = propagate_rtn(&s_k, &control.command(), &spacecraft, cycle, &env_tolerances)
            .map_err(|error| DemoError::Env(EnvError::Propagation { step: k, error }))?;
        let gap = |a: &[f64; 3], b: &[f64; 3]| norm3(&[a[0] - b[0], a[1] - b[1], a[2] - b[2]]);
        // The endpoint rule on the record's two samples, in each sample's own RTN frame.
        let endpoint = |s: &SpatialSample| {
            let frame = s.state.rtn_frame().unwrap_or([[f64::NAN; 3]; 3]);
            let (u, alpha) = (s.throttle, s.direction);
            frame.map(|e| u * dot3(&alpha, &e))
        };
        let (wa, wb) = (endpoint(now), endpoint(next));
        let trapezoid: [f64; 3] = core::array::from_fn(|i| 0.5 * (wa[i] + wb[i]));
        let e = flown.info.state;
        demo.mismatch.push(StepMismatch {
            record: record.index,
            step: k,
            position: gap(&e.orbit.r, &s_next.orbit.r),
            velocity: gap(&e.orbit.v, &s_next.orbit.v),
            mass: (e.m - s_next.m).abs(),
            zoh_throttle: norm3(&control.w),
            mean_throttle: control.mean_throttle,
            trapezoid_error: gap(&trapezoid, &control.w),
            unclipped_position: gap(&unclipped.orbit.r, &s_next.orbit.r),
        });
    }
    let arrived = record.steps.last().ok_or(DemoError::NoSolution)?;
    coast_to_the_end(
        &mut env,
        scenario,
        &placed(arrived),
        first_coast..scenario.scenario.steps,
        coast_action3(),
        record.index,
        &mut demo.transitions,
    )?;
    Ok(demo)
}

/// The tuples of every converged record (in parallel, in record order), with the records that
/// gave none and why; unconverged records (which keep no samples) are counted as filtered out.
pub fn spatial_demonstrations<P: Problem<Geometry = env::Spatial>>(
    records: &[SpatialRecord],
    config: &EnvConfig,
    tolerances: &Tolerances,
) -> Demonstrations<P::Obs, [f32; ACTION3_LEN]> {
    let results: Vec<_> = records
        .par_iter()
        .filter(|r| r.converged)
        .map(|r| (r.index, spatial_demonstration::<P>(r, config, tolerances)))
        .collect();
    let converged = results.len();
    Demonstrations::gather(results, records.len() - converged)
}

#[cfg(test)]
mod tests {
    use shared::mission::{PlaneRanges, SpatialFamily};
    use shared::scenario::{Range, ScenarioKind};
    use shared::spacecraft::Spacecraft;

    use super::*;
    use crate::demo::{default_tolerances, record_demonstration, zoh_controls};
    use crate::env::{EnvConfig, Rendezvous, Rendezvous3, Transfer3};
    use crate::solver::spatial::record::solve_spatial_draw;
    use crate::solver::{solve_scenario, SolveOptions};

    fn quick() -> SolveOptions {
        SolveOptions {
            final_eps: 0.3,
            ..SolveOptions::default()
        }
    }

    /// A planar draw in three dimensions: its RTN controls are the planar method's polar ones,
    /// integrated by the planar demonstrations' own state-costate system, with no normal part.
    #[test]
    fn in_the_plane_the_rtn_controls_are_the_polar_ones() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let kind = ScenarioKind::RendezvousCircular;
        let family = SpatialFamily::planar(kind.family());
        let spatial = solve_spatial_draw(&family, 3, 0, &sc, &quick());
        assert!(spatial.converged, "{:?}", spatial.failure);
        let planar = solve_scenario(kind, 3, 0, &spatial.scenario.scenario, &sc, &quick());
        assert!(planar.converged);
        let tol = default_tolerances();
        let rtn = rtn_zoh_controls(&spatial, &sc, &tol).unwrap();
        let polar = zoh_controls(&planar, &EnvConfig::default(), &tol).unwrap();
        assert_eq!(rtn.len(), polar.len());
        for (k, (a, b)) in rtn.iter().zip(&polar).enumerate() {
            let d = (a.w[0] - b.w[0]).abs().max((a.w[1] - b.w[1]).abs());
            assert!(d < 1e-6 && a.w[2].abs() < 1e-12, "cycle {k}: {a:?} vs {b:?}");
            assert!((a.mean_throttle - b.mean_throttle).abs() < 1e-6);
        }
        // And its tuples are the planar tuples: actions with no normal part, the same rewards
        // and done flags.
        let config = EnvConfig::default();
        let flat = record_demonstration::<Rendezvous>(&planar, &config, &tol).unwrap();
        let space = spatial_demonstration::<Rendezvous3>(&spatial, &config, &tol).unwrap();
        assert_eq!(flat.transitions.len(), space.transitions.len());
        for (a, b) in flat.transitions.iter().zip(&space.transitions) {
            assert!(
                (a.reward - b.reward).abs() < 1e-6,
                "cycle {}: {} vs {}",
                a.step,
                a.reward,
                b.reward
            );
            assert_eq!(a.done, b.done);
            for i in 0..3 {
                assert!((a.action[i] - b.action[i]).abs() < 1e-5, "cycle {}", a.step);
            }
            assert!(b.action[3].abs() < 1e-12);
        }
    }

    /// An inclined family's draw re-solved from its own state at mid-flight ([`relabel_spatial`])
    /// is the tail of the whole optimum: the same final mass, and placed in the episode the same
    /// tuples as the whole record's from that cycle on (the body chased from where it is, the
    /// thrust in units of the state's mass); a placement that does not add up is refused.
    fn resolved_from_mid_flight_gives_the_tail<P: Problem<Geometry = env::Spatial>>(family: &SpatialFamily) {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let whole = solve_spatial_draw(family, 2, 0, &sc, &quick());
        assert!(whole.converged, "{:?}", whole.failure);
        let n = whole.scenario.scenario.steps;
        let k = n / 2;
        let mid = craft(&whole.steps[k as usize]);
        assert!(mid.m < 1.0);
        let (tail, placement) = relabel_spatial(family, (7, 0), &whole.scenario, &mid, k, &sc, &quick()).unwrap();
        assert!(tail.converged, "{:?}", tail.failure);
        assert_eq!(tail.final_eps, whole.final_eps);
        assert_eq!((placement.start_step, placement.start_mass), (k, mid.m));
        let tail_final = placement.start_mass * tail.final_mass;
        assert!(
            (tail_final - whole.final_mass).abs() < 1e-6,
            "{tail_final} vs {}",
            whole.final_mass
        );
        let config = EnvConfig::default();
        let tol = default_tolerances();
        let a = spatial_demonstration::<P>(&whole, &config, &tol).unwrap();
        let b = placed_spatial_demonstration::<P>(&tail, &placement, &config, &tol).unwrap();
        assert_eq!(b.transitions.len(), (n - k) as usize);
        crate::demo::tests::assert_same_tail(&b.transitions, &a.transitions[k as usize..]);
        let wrong = Placement {
            start_step: k + 1,
            ..placement
        };
        assert_eq!(
            placed_spatial_demonstration::<P>(&tail, &wrong, &config, &tol).err(),
            Some(DemoError::Placement)
        );
        assert!(relabel_spatial(family, (7, 0), &whole.scenario, &mid, n, &sc, &quick()).is_none());
    }

    /// The target orbit inclined 4 degrees, its node at 1 rad.
    fn inclined_target(kind: ScenarioKind) -> SpatialFamily {
        SpatialFamily {
            family: kind.family(),
            departure_plane: PlaneRanges::REFERENCE,
            target_plane: PlaneRanges {
                inclination: Range { lo: 0.07, hi: 0.07 },
                raan: Range { lo: 1.0, hi: 1.0 },
            },
            departure_dispersion: shared::mission::StateDispersion::NONE,
        }
    }

    #[test]
    fn an_inclined_transfer_resolved_from_mid_flight_gives_the_tail_of_the_whole_tuples() {
        resolved_from_mid_flight_gives_the_tail::<Transfer3>(&inclined_target(ScenarioKind::TransferCircular));
    }

    #[test]
    fn an_inclined_rendezvous_resolved_from_mid_flight_gives_the_tail_of_the_whole_tuples() {
        resolved_from_mid_flight_gives_the_tail::<Rendezvous3>(&inclined_target(ScenarioKind::RendezvousCircular));
    }

    /// Solved with an arrival margin, an inclined rendezvous meets the body `margin` cycles
    /// early: in the plane the same optimum as the planar method's margin (final mass to 1e-8);
    /// inclined, its tuples fill the draw's whole episode, the last `margin` coasting on the body
    /// to the end (the environment's terminal reward there); a relabel keeps the margin.
    #[test]
    fn an_inclined_rendezvous_arriving_early_coasts_with_the_body_to_the_end_of_its_episode() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let kind = ScenarioKind::RendezvousCircular;
        let margin = 2;
        let options = SolveOptions {
            arrival_margin_steps: margin,
            ..quick()
        };
        let flat = SpatialFamily::planar(kind.family());
        let early3 = solve_spatial_arriving_early(&flat, (9, 0), &flat.draw(9, 0), &sc, &options);
        let early2 = crate::solver::solve_arriving_early(kind, 9, 0, &kind.draw(9, 0), &sc, &options);
        assert!(
            early3.converged && early2.converged,
            "{:?} {:?}",
            early3.failure,
            early2.failure
        );
        assert_eq!(early3.scenario.scenario.steps, early2.scenario.steps);
        assert!((early3.final_mass / early2.final_mass - 1.0).abs() < 1e-8);

        let family = inclined_target(kind);
        let draw = family.draw(9, 0);
        let n = draw.scenario.steps;
        let record = solve_spatial_arriving_early(&family, (9, 0), &draw, &sc, &options);
        assert!(record.converged, "{:?}", record.failure);
        assert_eq!(record.scenario.scenario.steps, n - margin);
        assert_eq!(episode_of(&record), draw);
        let config = EnvConfig::default();
        let demo = spatial_demonstration::<Rendezvous3>(&record, &config, &default_tolerances()).unwrap();
        assert_eq!(demo.transitions.len(), n as usize);
        let coast = coast_action3();
        let mut env = MdpEnv::<Rendezvous3>::new(&config).unwrap();
        let mut state = craft(record.steps.last().unwrap());
        for (k, t) in (0u32..).zip(&demo.transitions) {
            assert_eq!((t.step, t.done), (k, k + 1 == n));
            if k < n - margin {
                continue;
            }
            assert_eq!(t.action, coast, "cycle {k}");
            let body = env::body_at3(&draw, k).unwrap();
            let gap = |a: [f64; 3], b: [f64; 3]| norm3(&[a[0] - b[0], a[1] - b[1], a[2] - b[2]]);
            let (miss, speed) = (gap(state.orbit.r, body.r), gap(state.orbit.v, body.v));
            assert!(miss < 1e-6 && speed < 1e-6, "cycle {k}: {miss:e} AU, {speed:e}");
            assert_eq!(t.observation, env.reset_at(&draw, &state, k).unwrap());
            state = env.step(&coast).unwrap().info.state;
            assert_eq!(t.next_observation, env.reset_at(&draw, &state, k + 1).unwrap());
        }
        let last = demo.transitions.last().unwrap();
        let (reward, ..) = MdpEnv::<Rendezvous3>::reward_at(&config, &draw, &state, n, 0.0).unwrap();
        assert_eq!(last.reward.to_bits(), reward.to_bits());

        // From mid-flight the rest is solved to arrive early too, and placed it fills the episode.
        let k = n / 2;
        let mid = craft(&record.steps[k as usize]);
        let (tail, placement) = relabel_spatial(&family, (9, 0), &draw, &mid, k, &sc, &options).unwrap();
        assert!(tail.converged, "{:?}", tail.failure);
        assert_eq!(tail.scenario.scenario.steps, n - k - margin);
        assert!((placement.start_mass * tail.final_mass - record.final_mass).abs() < 1e-6);
        let placed = placed_spatial_demonstration::<Rendezvous3>(&tail, &placement, &config, &default_tolerances());
        assert_eq!(placed.unwrap().transitions.len(), (n - k) as usize);
    }

    /// An inclined transfer: coast cycles flown by the onboard RTN propagation land on the
    /// record's next state exactly, thrust cycles near it; the plane change shows as normal
    /// thrust; the features have the transfer's layout; corrupt costates are refused.
    #[test]
    fn an_inclined_record_gives_actions_that_fly_its_cycles_and_corrupt_costates_are_refused() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let family = SpatialFamily {
            family: ScenarioKind::TransferCircular.family(),
            departure_plane: PlaneRanges::REFERENCE,
            target_plane: PlaneRanges {
                inclination: Range { lo: 0.07, hi: 0.07 },
                raan: Range { lo: 1.0, hi: 1.0 },
            },
            departure_dispersion: shared::mission::StateDispersion::NONE,
        };
        let record = solve_spatial_draw(&family, 2, 0, &sc, &quick());
        assert!(record.converged, "{:?}", record.failure);
        let tol = default_tolerances();
        let config = EnvConfig::default();
        let demo = spatial_demonstration::<Transfer3>(&record, &config, &tol).unwrap();
        let n = record.scenario.scenario.steps as usize;
        assert_eq!((demo.transitions.len(), demo.mismatch.len()), (n, n));
        for m in &demo.mismatch {
            if m.mean_throttle == 0.0 {
                assert!(m.position < 1e-10 && m.velocity < 1e-10, "{m:?}");
            } else {
                assert!(m.position < 2e-3 && m.velocity < 2e-3, "{m:?}");
            }
        }
        // Consecutive tuples chain (s_k+1 of one is s_k of the next), only the last is done.
        for (k, pair) in demo.transitions.windows(2).enumerate() {
            assert_eq!(pair[0].next_observation, pair[1].observation, "cycle {k}");
            assert!(!pair[0].done);
        }
        assert!(demo.transitions.last().is_some_and(|t| t.done));
        let normal = demo
            .transitions
            .iter()
            .map(|t| f64::from(t.action[3].abs()))
            .fold(0.0, f64::max);
        assert!(normal > 0.05, "no out-of-plane thrust: {normal}");
        // At the record's arrival the residuals are the solver's terminal error: none.
        let last = demo.transitions.last().unwrap();
        let residuals = (last.next_observation[12], last.next_observation[13]);
        assert!(residuals.0 < 1e-6 && residuals.1 < 1e-6, "{residuals:?}");
        assert!(matches!(
            spatial_demonstration::<Rendezvous3>(&record, &config, &tol),
            Err(DemoError::WrongProblem { .. })
        ));
        let mut corrupt = record.clone();
        corrupt.costates[3] *= 1.01;
        assert!(matches!(
            rtn_zoh_controls(&corrupt, &sc, &tol),
            Err(DemoError::Inconsistent { .. })
        ));
    }
}
