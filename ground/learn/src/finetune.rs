//! Fine-tuning through the dynamics: the flown actor's flights differentiated end to end, and
//! the actor stepped down the gradient of what each flight ends with (its miss and its
//! propellant), as Origer and Izzo fine-tune a cloned network.
//!
//! The dynamics and the features are the environment's own (the onboard propagator, one
//! implementation): their Jacobians along each flight are central differences of
//! [`Environment::step`] and [`Problem::features`], and only the network is differentiated by
//! autograd. For a flight of N cycles with states s_k, observations o_k = f(s_k, k) and actions
//! a_k = pi(o_k), the objective J(s_N) is back-propagated by the adjoint recursion
//!
//! `lambda_N = dJ/ds_N`, `g_k = B_k^T lambda_{k+1}`, `lambda_k = A_k^T lambda_{k+1} + C_k^T (dpi/do_k)^T g_k`
//!
//! (A_k = ds_{k+1}/ds_k and B_k = ds_{k+1}/da_k of one cycle, C_k = do_k/ds_k), and the actor's
//! gradient is the sum over the flight of `g_k . dpi(o_k)/dtheta`: one Adam step on a batch of
//! flights ([`Sac::action_gradient_step`]).
//!
//! With `[finetune] dispersed` the flights fly against the SIL's dispersed plant instead
//! (`firmware_sim::plant_cycle`: navigation, thrust and pointing errors, missed thrust): the
//! network sees the navigation state, each cycle's Jacobians are central differences of that
//! cycle flown again from a clone of its plant (the same draws), and the evaluations fly the
//! network alone in the SIL loop, so the objective is lowered where the flight software flies.
//!
//! ```text
//! RUN/finetune/start-actor.safetensors   the actor it starts from
//! RUN/finetune/step-S.safetensors        the learner after step S (every eval_every steps)
//! RUN/finetune/best.safetensors          the evaluation with the smallest mean objective
//! RUN/finetune/best-actor.safetensors    its actor, what the run ships
//! RUN/finetune/steps.{csv,svg}           the evaluations, state.json the same for machines
//! RUN/finetune/then/...                   the phase after it (`[finetune.then]`), the same files
//! ```
//!
//! Each step's flights are drawn from the step's number and the learner's Adam state is in its
//! checkpoint, so a run stopped anywhere resumes from its last checkpoint to the same weights.

use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::config::{ExperimentConfig, FinetuneConfig};
use crate::dagger::progress_bar;
use crate::error::ExperimentError;
use crate::eval::{load_agent, meets, ACCURACY_GOAL};
use crate::phase::{family_of, policy_batch, write_rows, LogRow};
use crate::run_folder::{check_run, prepare_run};
use crate::sac::agent::Sac;
use crate::sil::{flight_setup, learner_blob, SilFlights, SilGeometry};
use firmware_sim::{plant_cycle, DispersedPlant, FlightGeometry};
use ground_core::charts::{line_chart, Series};
use ground_core::demo::DemoGeometry;
use ground_core::env::batch::{evaluate_batched, summarize, EpisodeOutcome, OutcomeSummary};
use ground_core::env::{ActionOf, Dimension, Environment, Geometry, MdpEnv, Problem, ScenarioOf, StateOf};
use onboard::features::Residuals;
use shared::spacecraft::CanonicalSpacecraft;

/// Central-difference step of a state component (AU, AU/t*, fraction of m0): the onboard
/// propagator's relative tolerance is 1e-12, so the differences carry about 1e-6 of noise.
const STATE_STEP: f64 = 1e-6;
/// Central-difference step of an action component (the action is f32, about 1e-7 resolution).
const ACTION_STEP: f32 = 1e-3;

/// What a flight ends with, to be lowered: `ln(1 + (dr/goal)^2 + (dv/goal)^2)` plus the
/// propellant burned, weighed per thousandth of the initial mass. Within the goal the miss term
/// is its square; far outside it the logarithm keeps a few flights that miss by tens of goals
/// (a rendezvous's, an infeasible draw's) from outweighing the rest of the batch.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Objective {
    /// Position residual that counts as one unit (AU).
    pub position_goal: f64,
    /// Velocity residual that counts as one unit (AU/t*).
    pub velocity_goal: f64,
    /// Units per thousandth of the initial mass burned.
    pub propellant_weight: f64,
    /// Cycles before the arrival at which the miss counts too (0: only at the arrival): a
    /// flight that meets its target early and follows it keeps the last cycles in reserve.
    #[serde(default)]
    pub arrival_margin: u32,
}

impl Objective {
    /// The objective of a flight that ends with `residuals` and `mass`.
    pub fn value(&self, residuals: &Residuals, mass: f64) -> f64 {
        let miss =
            (residuals.position / self.position_goal).powi(2) + (residuals.velocity / self.velocity_goal).powi(2);
        miss.ln_1p() + self.propellant_weight * 1e3 * (1.0 - mass)
    }
}

/// One flight's Jacobians and what the backward pass needs of it.
struct Linearised {
    /// The observations o_k, k = 0..N.
    obs: Vec<Vec<f32>>,
    /// A_k (d x d, row-major: row i is d s_{k+1,i}).
    a: Vec<Vec<f64>>,
    /// B_k (d x act).
    b: Vec<Vec<f64>>,
    /// C_k (obs x d).
    c: Vec<Vec<f64>>,
    /// dJ/ds_N.
    terminal: Vec<f64>,
    /// With an arrival margin: the cycle e it is judged at and the miss term's dJ/ds_e.
    early: Option<(usize, Vec<f64>)>,
    /// J of the flight.
    value: f64,
}

/// The state numbers after one cycle from `state` at step `k` under `action`.
fn stepped<P: Problem>(
    env: &mut MdpEnv<P>,
    scenario: &ScenarioOf<P::Geometry>,
    state: &[f64],
    k: u32,
    action: &[f32],
) -> Option<Vec<f64>>
where
    P::Geometry: DemoGeometry,
{
    let s = P::Geometry::state_from_numbers(state)?;
    env.reset_at(scenario, &s, k).ok()?;
    let step = env.step_slice(action).ok()?;
    Some(P::Geometry::state_numbers(&step.info.state))
}

/// The features of `state` at step `k`.
fn features_of<P: Problem>(scenario: &ScenarioOf<P::Geometry>, state: &[f64], k: u32) -> Option<Vec<f64>>
where
    P::Geometry: DemoGeometry,
{
    let s = P::Geometry::state_from_numbers(state)?;
    P::features(scenario, &s, k).ok().map(|f| f.as_ref().to_vec())
}

/// J at the end of a flight in `state` (its last step `n`).
fn terminal_value<P: Problem>(
    scenario: &ScenarioOf<P::Geometry>,
    state: &[f64],
    n: u32,
    objective: &Objective,
) -> Option<f64>
where
    P::Geometry: DemoGeometry,
{
    let s = P::Geometry::state_from_numbers(state)?;
    let features = P::features(scenario, &s, n).ok()?;
    Some(objective.value(&P::residuals(&features), P::Geometry::mass(&s)))
}

/// The cycle an arrival margin judges a flight of `steps` cycles at: `margin` before its end,
/// for a flight longer than the margin (None: judged at the arrival alone).
fn margin_cycle(steps: usize, margin: u32) -> Option<usize> {
    let margin = margin as usize;
    (margin > 0 && steps > margin).then(|| steps - margin)
}

/// The arrival margin's term of the objective: the miss of `state`, `e` cycles into the flight,
/// against the target there (the propellant not counted again).
fn early_miss<P: Problem>(
    scenario: &ScenarioOf<P::Geometry>,
    state: &StateOf<P::Geometry>,
    e: u32,
    objective: &Objective,
) -> Option<f64> {
    let features = P::features(scenario, state, e).ok()?;
    let miss_only = Objective {
        propellant_weight: 0.0,
        ..*objective
    };
    Some(miss_only.value(&P::residuals(&features), 1.0))
}

/// Central differences of `f` at `x` with step `h`: column j of the result is df/dx_j, laid out
/// row-major as `rows x x.len()`.
fn jacobian<T: Copy + Into<f64> + std::ops::Add<Output = T> + std::ops::Sub<Output = T>>(
    x: &[T],
    h: T,
    rows: usize,
    mut f: impl FnMut(&[T]) -> Option<Vec<f64>>,
) -> Option<Vec<f64>> {
    let cols = x.len();
    let mut out = vec![0.0; rows * cols];
    let mut probe = x.to_vec();
    for j in 0..cols {
        probe[j] = x[j] + h;
        let up = f(&probe)?;
        probe[j] = x[j] - h;
        let down = f(&probe)?;
        probe[j] = x[j];
        // The step actually taken (f32 actions round it).
        let width = (x[j] + h).into() - (x[j] - h).into();
        for i in 0..rows {
            out[i * cols + j] = (up[i] - down[i]) / width;
        }
    }
    Some(out)
}

/// One flight as flown: the true states s_0..s_N, the states the network saw (the navigation's
/// under dispersions, else the true ones) and its actions.
struct Flown {
    states: Vec<Vec<f64>>,
    seen: Vec<Vec<f64>>,
    actions: Vec<Vec<f32>>,
}

/// Linearises one flight of `scenario` about its flown states and actions, `cycle(k, s, a)`
/// being its cycle k's map from state and action to the next state: None when a propagation or
/// a feature fails along it.
fn linearise<P: Problem>(
    scenario: &ScenarioOf<P::Geometry>,
    flown: &Flown,
    objective: &Objective,
    mut cycle: impl FnMut(u32, &[f64], &[f32]) -> Option<Vec<f64>>,
) -> Option<Linearised>
where
    P::Geometry: DemoGeometry,
{
    let Flown { states, seen, actions } = flown;
    let n = actions.len();
    let d = states[0].len();
    let mut lin = Linearised {
        obs: Vec::with_capacity(n),
        a: Vec::with_capacity(n),
        b: Vec::with_capacity(n),
        c: Vec::with_capacity(n),
        terminal: Vec::new(),
        early: None,
        value: terminal_value::<P>(scenario, &states[n], n as u32, objective)?,
    };
    if let Some(e) = margin_cycle(n, objective.arrival_margin) {
        let term = |x: &[f64]| {
            let s = P::Geometry::state_from_numbers(x)?;
            Some(vec![early_miss::<P>(scenario, &s, e as u32, objective)?])
        };
        lin.value += term(&states[e])?[0];
        lin.early = Some((e, jacobian(&states[e], STATE_STEP, 1, term)?));
    }
    for (k, action) in actions.iter().enumerate() {
        let step = k as u32;
        // What the network saw at this step, as the environment forms it from the state seen.
        let features = P::features(scenario, &P::Geometry::state_from_numbers(&seen[k])?, step).ok()?;
        lin.obs.push(P::observation(&features).as_ref().to_vec());
        let s = &states[k];
        lin.a.push(jacobian(s, STATE_STEP, d, |x| cycle(step, x, action))?);
        lin.b.push(jacobian(action, ACTION_STEP, d, |u| cycle(step, s, u))?);
        // A navigation error adds to the true state, so d o/d s is taken where the network saw.
        lin.c.push(jacobian(&seen[k], STATE_STEP, P::OBS, |x| {
            features_of::<P>(scenario, x, step)
        })?);
    }
    lin.terminal = jacobian(&states[n], STATE_STEP, 1, |x| {
        terminal_value::<P>(scenario, x, n as u32, objective).map(|v| vec![v])
    })?;
    Some(lin)
}

/// Linearises one nominal flight (the environment's cycles) flown by `actions`.
fn linearise_nominal<P: Problem>(
    config: &ExperimentConfig,
    scenario: &ScenarioOf<P::Geometry>,
    actions: Vec<Vec<f32>>,
    objective: &Objective,
) -> Option<Linearised>
where
    P::Geometry: DemoGeometry,
{
    let mut env = MdpEnv::<P>::new(&config.env).ok()?;
    let mut states = vec![P::Geometry::state_numbers(&P::Geometry::departure(scenario))];
    for (k, action) in actions.iter().enumerate() {
        let next = stepped::<P>(&mut env, scenario, &states[k], k as u32, action)?;
        states.push(next);
    }
    let flown = Flown {
        seen: states.clone(),
        states,
        actions,
    };
    linearise::<P>(scenario, &flown, objective, |k, x, a| {
        stepped::<P>(&mut env, scenario, x, k, a)
    })
}

/// A flight against the SIL's dispersed plant: as flown, each cycle's plant as it was when the
/// cycle's command was taken (after the navigation's draw), and the spacecraft as it flies
/// (the flight's thrust factor applied).
struct DispersedFlight {
    flown: Flown,
    plants: Vec<DispersedPlant>,
    actual: CanonicalSpacecraft,
}

/// Flies `scenarios` with the actor against the SIL's dispersed plant, flight i's dispersions
/// drawn from `seed + i` as the SIL draws them: each cycle the network sees the navigation
/// state and the plant flies its command (`firmware_sim::plant_cycle`). `nudge(i, k, action)`
/// may change flight i's action at cycle k before it is flown (the identity in training).
/// None for a flight whose features or propagation failed.
fn fly_dispersed<P: Problem>(
    config: &ExperimentConfig,
    agent: &Sac,
    scenarios: &[ScenarioOf<P::Geometry>],
    seed: u64,
    nudge: impl Fn(usize, usize, &mut [f32]),
) -> Result<Vec<Option<DispersedFlight>>, ExperimentError>
where
    P::Geometry: DemoGeometry + FlightGeometry,
{
    let setup = flight_setup(config, &config.sil.dispersions)?;
    struct Live<G: Dimension> {
        truth: G::State,
        plant: DispersedPlant,
        flight: Option<DispersedFlight>,
    }
    let mut live: Vec<Live<P::Geometry>> = scenarios
        .iter()
        .enumerate()
        .map(|(i, scenario)| {
            let plant = DispersedPlant::new(&setup.dispersions, setup.time_unit_s, seed.wrapping_add(i as u64));
            let actual = CanonicalSpacecraft {
                thrust: setup.spacecraft.thrust * plant.thrust_factor(),
                ..setup.spacecraft
            };
            let truth = P::Geometry::departure(scenario);
            Live {
                flight: Some(DispersedFlight {
                    flown: Flown {
                        states: vec![P::Geometry::state_numbers(&truth)],
                        seen: Vec::new(),
                        actions: Vec::new(),
                    },
                    plants: Vec::new(),
                    actual,
                }),
                truth,
                plant,
            }
        })
        .collect();
    let longest = scenarios.iter().map(|s| P::Geometry::plan(s).steps).max().unwrap_or(0);
    for k in 0..longest {
        // The navigation's draw, then what the network sees; all flights' actions in one batch.
        let mut rows = Vec::new();
        let mut obs = Vec::new();
        for (i, (l, scenario)) in live.iter_mut().zip(scenarios).enumerate() {
            let Some(flight) = l.flight.as_mut() else { continue };
            if k >= P::Geometry::plan(scenario).steps {
                continue;
            }
            let navigation = P::Geometry::navigate(&mut l.plant, &l.truth);
            match P::features(scenario, &navigation, k) {
                Ok(features) => {
                    obs.extend_from_slice(P::observation(&features).as_ref());
                    flight.flown.seen.push(P::Geometry::state_numbers(&navigation));
                    flight.plants.push(l.plant.clone());
                    rows.push(i);
                }
                Err(_) => l.flight = None,
            }
        }
        let actions = agent.act(&obs, rows.len());
        for (row, &i) in rows.iter().enumerate() {
            let mut action = actions[row * P::Geometry::ACT..(row + 1) * P::Geometry::ACT].to_vec();
            nudge(i, k as usize, &mut action);
            let l = &mut live[i];
            let scenario = &scenarios[i];
            let Some(flight) = l.flight.as_mut() else { continue };
            let cycle = ActionOf::<P::Geometry>::try_from(&action[..]).ok().and_then(|a| {
                let command = P::Geometry::decode(&a);
                let plan = P::Geometry::plan(scenario);
                plant_cycle::<P::Geometry>(
                    &mut l.plant,
                    &l.truth,
                    &command,
                    &flight.actual,
                    plan,
                    k,
                    &setup.tolerances,
                )
                .ok()
            });
            match cycle {
                Some(cycle) => {
                    l.truth = cycle.state;
                    flight.flown.states.push(P::Geometry::state_numbers(&cycle.state));
                    flight.flown.actions.push(action);
                }
                None => l.flight = None,
            }
        }
    }
    Ok(live.into_iter().map(|l| l.flight).collect())
}

/// Linearises one dispersed flight: its cycles are the plant's, each replayed from the plant
/// it started with.
fn linearise_dispersed<P: Problem>(
    config: &ExperimentConfig,
    scenario: &ScenarioOf<P::Geometry>,
    flight: &DispersedFlight,
    objective: &Objective,
) -> Option<Linearised>
where
    P::Geometry: DemoGeometry + FlightGeometry,
{
    let tolerances = config.env.integrator.tolerances();
    linearise::<P>(scenario, &flight.flown, objective, |k, x, a| {
        let state = P::Geometry::state_from_numbers(x)?;
        let command = P::Geometry::decode(&ActionOf::<P::Geometry>::try_from(a).ok()?);
        let mut plant = flight.plants[k as usize].clone();
        let plan = P::Geometry::plan(scenario);
        let cycle =
            plant_cycle::<P::Geometry>(&mut plant, &state, &command, &flight.actual, plan, k, &tolerances).ok()?;
        Some(P::Geometry::state_numbers(&cycle.state))
    })
}

/// The flights' actions: each scenario flown by the actor from its departure.
fn flown_actions<P: Problem>(
    config: &ExperimentConfig,
    agent: &Sac,
    scenarios: &[ScenarioOf<P::Geometry>],
) -> Result<Vec<Vec<Vec<f32>>>, ExperimentError> {
    let outcomes = evaluate_batched::<MdpEnv<P>, _>(&config.env, scenarios, |o| policy_batch(agent, o), true)?;
    Ok(outcomes
        .iter()
        .zip(scenarios)
        .map(|(outcome, scenario)| {
            let points = outcome.trajectory.as_deref().unwrap_or_default();
            // The actions again from the recorded states (the actor is deterministic).
            let obs: Vec<P::Obs> = points
                .iter()
                .take(points.len().saturating_sub(1))
                .filter_map(|p| P::features(scenario, &p.state, p.step).ok().map(|f| P::observation(&f)))
                .collect();
            let flat: Vec<f32> = obs.iter().flat_map(|o| o.as_ref().iter().copied()).collect();
            agent
                .act(&flat, obs.len())
                .chunks_exact(agent.act_dim())
                .map(<[f32]>::to_vec)
                .collect()
        })
        .collect())
}

/// What one fine-tuning step measured on its batch of flights.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StepReport {
    /// Flights linearised (the others failed along the way and were left out).
    pub flights: usize,
    /// Their mean objective before the step.
    pub objective: f64,
}

/// What fine-tuning flights fly against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plant {
    /// The environment's nominal cycles.
    Nominal,
    /// The SIL's dispersed plant (`[sil.dispersions]`), flight i's dispersions drawn from
    /// `seed + i`.
    Dispersed {
        /// Flight 0's seed.
        seed: u64,
    },
}

impl Plant {
    /// The plant the config's `[finetune]` flies training scenarios `first..` against: the
    /// dispersed one from its own stream of the training seed when `dispersed` is set.
    pub fn of(config: &ExperimentConfig, first: u64) -> Self {
        if config.finetune.dispersed {
            Plant::Dispersed {
                seed: (config.seeds.train ^ DISPERSION_STREAM).wrapping_add(first),
            }
        } else {
            Plant::Nominal
        }
    }
}

/// The gradient of the batch's mean objective with respect to each flight's actions, and the
/// observations they were taken at: `(obs rows, action-gradient rows, report)`.
pub fn action_gradients<P: Problem>(
    config: &ExperimentConfig,
    agent: &Sac,
    scenarios: &[ScenarioOf<P::Geometry>],
    plant: Plant,
    objective: &Objective,
) -> Result<(Vec<f32>, Vec<f32>, StepReport), ExperimentError>
where
    P::Geometry: DemoGeometry + FlightGeometry,
{
    let flights: Vec<Linearised> = match plant {
        Plant::Nominal => {
            let actions = flown_actions::<P>(config, agent, scenarios)?;
            scenarios
                .par_iter()
                .zip(actions.into_par_iter())
                .filter_map(|(scenario, actions)| linearise_nominal::<P>(config, scenario, actions, objective))
                .collect()
        }
        Plant::Dispersed { seed } => {
            let flown = fly_dispersed::<P>(config, agent, scenarios, seed, |_, _, _| {})?;
            scenarios
                .par_iter()
                .zip(flown.par_iter())
                .filter_map(|(scenario, flight)| {
                    linearise_dispersed::<P>(config, scenario, flight.as_ref()?, objective)
                })
                .collect()
        }
    };
    let count = flights.len().max(1) as f64;
    let act = agent.act_dim();
    let d = flights.first().map_or(0, |f| f.terminal.len());
    // Backward in time, the flights aligned at their ends: one policy product per step back.
    let mut lambda: Vec<Vec<f64>> = flights
        .iter()
        .map(|f| f.terminal.iter().map(|g| g / count).collect())
        .collect();
    let mut grads: Vec<Vec<Vec<f32>>> = flights.iter().map(|f| vec![Vec::new(); f.obs.len()]).collect();
    let longest = flights.iter().map(|f| f.obs.len()).max().unwrap_or(0);
    for back in 0..longest {
        let active: Vec<usize> = (0..flights.len()).filter(|&i| flights[i].obs.len() > back).collect();
        let mut obs_rows = Vec::with_capacity(active.len() * P::OBS);
        let mut g_rows = Vec::with_capacity(active.len() * act);
        for &i in &active {
            let f = &flights[i];
            let k = f.obs.len() - 1 - back;
            obs_rows.extend_from_slice(&f.obs[k]);
            let g: Vec<f32> = (0..act)
                .map(|j| (0..d).map(|r| f.b[k][r * act + j] * lambda[i][r]).sum::<f64>() as f32)
                .collect();
            g_rows.extend_from_slice(&g);
            grads[i][k] = g;
        }
        let g_obs = agent.action_input_gradient(&obs_rows, &g_rows, active.len());
        for (row, &i) in active.iter().enumerate() {
            let f = &flights[i];
            let k = f.obs.len() - 1 - back;
            let go = &g_obs[row * P::OBS..(row + 1) * P::OBS];
            let next: Vec<f64> = (0..d)
                .map(|c| {
                    let through_state: f64 = (0..d).map(|r| f.a[k][r * d + c] * lambda[i][r]).sum();
                    let through_policy: f64 = (0..P::OBS).map(|o| f.c[k][o * d + c] * f64::from(go[o])).sum();
                    through_state + through_policy
                })
                .collect();
            lambda[i] = next;
            // The margin's miss adds to the adjoint of the state it is judged at.
            if let Some((e, g)) = &f.early {
                if *e == k {
                    lambda[i].iter_mut().zip(g).for_each(|(l, g)| *l += g / count);
                }
            }
        }
    }
    let obs: Vec<f32> = flights.iter().flat_map(|f| f.obs.iter().flatten().copied()).collect();
    let g: Vec<f32> = grads.iter().flat_map(|f| f.iter().flatten().copied()).collect();
    let report = StepReport {
        flights: flights.len(),
        objective: flights.iter().map(|f| f.value).sum::<f64>() / count,
    };
    Ok((obs, g, report))
}

/// One fine-tuning step on training scenarios `first..first + count` of the config's family:
/// flies them, back-propagates the objective through their flights and steps the actor.
pub fn finetune_step<P: Problem>(
    config: &ExperimentConfig,
    agent: &mut Sac,
    first: u64,
    count: u64,
    objective: &Objective,
) -> Result<StepReport, ExperimentError>
where
    P::Geometry: DemoGeometry + FlightGeometry,
{
    let family = family_of::<P::Geometry>(config)?;
    let scenarios: Vec<ScenarioOf<P::Geometry>> = (first..first + count)
        .map(|i| P::Geometry::draw(&family, config.seeds.train, i))
        .collect();
    let (obs, g, report) = action_gradients::<P>(config, agent, &scenarios, Plant::of(config, first), objective)?;
    let rows = obs.len() / P::OBS;
    if rows > 0 {
        agent.action_gradient_step(&obs, &g, rows);
    }
    Ok(report)
}

/// Fine-tuning flights come from the training stream past every round's scenarios (rounds
/// stride by 1e6 from 1e6).
const FIRST_SCENARIO: u64 = 1 << 40;
/// Mixed into the training seed for the dispersions of the fine-tuning flights.
const DISPERSION_STREAM: u64 = 0xF17E_D15B;

impl Objective {
    /// The objective of `config`'s `[finetune]`: the accuracy goal in both residuals.
    pub fn of(config: &ExperimentConfig) -> Self {
        Self {
            position_goal: ACCURACY_GOAL,
            velocity_goal: ACCURACY_GOAL,
            propellant_weight: config.finetune.propellant_weight,
            arrival_margin: config.finetune.arrival_margin,
        }
    }
}

/// One evaluation of the fine-tuning phase.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FinetuneRow {
    /// Steps taken.
    pub step: u64,
    /// Mean objective of the training batches since the last evaluation (0 at step 0).
    pub batch_objective: f64,
    /// Mean objective of the evaluation flights.
    pub objective: f64,
    /// Share of the evaluation flights within the accuracy goal.
    pub within_goal: f64,
    /// Their residuals and final masses.
    pub summary: OutcomeSummary,
    /// Wall time since the last evaluation, s.
    pub seconds: f64,
}

impl LogRow for FinetuneRow {
    const HEADER: &'static str =
        "step,batch_objective,objective,within_goal,final_mass_mean,dr_p50,dr_p95,dv_p50,dv_p95,seconds\n";

    fn csv(&self) -> String {
        let s = &self.summary;
        format!(
            "{},{},{},{},{},{},{},{},{},{:.1}\n",
            self.step,
            self.batch_objective,
            self.objective,
            self.within_goal,
            s.final_mass.mean,
            s.terminal_position.p50,
            s.terminal_position.p95,
            s.terminal_velocity.p50,
            s.terminal_velocity.p95,
            self.seconds
        )
    }

    fn point(&self) -> (f64, OutcomeSummary) {
        (self.step as f64, self.summary)
    }
}

/// What the fine-tuning phase did.
#[derive(Debug, Clone, PartialEq)]
pub struct FinetuneSummary {
    /// `RUN/finetune`.
    pub folder: PathBuf,
    /// Every evaluation, from step 0 (the start).
    pub rows: Vec<FinetuneRow>,
    /// The step of the best evaluation.
    pub best_step: u64,
    /// The flights flew against the SIL's dispersed plant.
    pub dispersed: bool,
    /// Its actor file, what the run ships.
    pub best_actor: PathBuf,
}

impl FinetuneSummary {
    /// One line for the model card and the report: the steps, the best and what it changed.
    pub fn lineage_line(&self) -> String {
        let best = self.rows.iter().find(|r| r.step == self.best_step);
        match (self.rows.first(), best) {
            (Some(start), Some(best)) => format!(
                "fine-tuned through the dynamics{} for {} steps, step {} kept: on {} evaluation flights objective {:.4} -> {:.4}, within the goal {:.1} -> {:.1} %, mean final mass {:.5} -> {:.5}",
                if self.dispersed { " on dispersed flights" } else { "" },
                self.rows.last().map_or(0, |r| r.step),
                best.step,
                start.summary.episodes,
                start.objective,
                best.objective,
                100.0 * start.within_goal,
                100.0 * best.within_goal,
                start.summary.final_mass.mean,
                best.summary.final_mass.mean
            ),
            _ => "fine-tuned through the dynamics".into(),
        }
    }
}

fn step_file(dir: &Path, step: u64) -> PathBuf {
    dir.join(format!("step-{step}.safetensors"))
}

/// The learner of the fine-tuning phase: the config's network, no averaged copy (the actor
/// stepped is the one flown) and `[finetune]`'s learning rate.
fn learner(config: &ExperimentConfig, obs_dim: usize) -> Result<Sac, ExperimentError> {
    let mut sac = config.sac.clone();
    sac.actor_averaging = 0.0;
    sac.learning_rate = config.finetune.learning_rate;
    tch::set_num_threads(config.compute.threads);
    // The critics it carries are never trained, but they are in its checkpoints: drawn from
    // the seed, so every start writes the same bytes.
    tch::manual_seed(config.seeds.train as i64);
    let mut agent = Sac::new(sac, obs_dim, config.action_dim(), config.device()?);
    agent.labels = config.learner_labels();
    Ok(agent)
}

/// Whether a begun phase's `start_actor` file is the flown actor of `start` (a learner
/// checkpoint or an actor file), compared as the files the phase writes.
fn began_from(phase: &ExperimentConfig, obs: usize, start_actor: &Path, start: &Path) -> Result<bool, ExperimentError> {
    let written = std::fs::read(start_actor).map_err(|e| ExperimentError::Io(start_actor.to_path_buf(), e))?;
    if std::fs::read(start).is_ok_and(|bytes| bytes == written) {
        return Ok(true);
    }
    Ok(load_agent(phase, obs, start)?.flown_actor_bytes()? == written)
}

/// `ground train finetune`: the config's fine-tuning from `start` (a learner checkpoint or an
/// actor file: its flown actor), resuming the steps already there. Each phase runs in its own
/// folder (`RUN/finetune`, then `RUN/finetune/then`, ...) from the best actor of the phase
/// before; the last phase's best actor is the result. One summary per phase, in order.
pub fn finetune(config: &ExperimentConfig, run: &Path, start: &Path) -> Result<Vec<FinetuneSummary>, ExperimentError> {
    if config.finetune.steps == 0 {
        return Err(crate::config::ConfigError::Invalid("finetune.steps is 0: no step to take".into()).into());
    }
    let mut summaries: Vec<FinetuneSummary> = Vec::new();
    let mut dir = run.join("finetune");
    for settings in config.finetune.phases() {
        // The phase's settings as the config's own, so the plant, the objective and the learner
        // read them where a single phase does.
        let mut phase = config.clone();
        phase.finetune = FinetuneConfig {
            then: None,
            ..settings.clone()
        };
        phase.compute.threads = settings.threads;
        let from = summaries.last().map_or(start, |before| before.best_actor.as_path());
        let chained = !summaries.is_empty();
        let summary =
            crate::with_flown_problem!(config, P => finetune_for::<P>(config, &phase, run, &dir, from, chained))?;
        summaries.push(summary);
        dir = dir.join("then");
    }
    Ok(summaries)
}

/// One phase: `phase.finetune`'s steps in `dir`; `run_config` is the run's, what its folder
/// records. A `chained` phase (one after another) refuses to go on from a start that is no
/// longer the phase before's best actor.
fn finetune_for<P: Problem>(
    run_config: &ExperimentConfig,
    phase: &ExperimentConfig,
    run: &Path,
    dir: &Path,
    start: &Path,
    chained: bool,
) -> Result<FinetuneSummary, ExperimentError>
where
    P::Geometry: SilGeometry + FlightGeometry,
{
    let settings = &phase.finetune;
    let objective = Objective::of(phase);
    check_run(run_config, run)?;
    let dir = dir.to_path_buf();
    let state_path = dir.join("state.json");
    let family = family_of::<P::Geometry>(phase)?;
    let evaluation: Vec<ScenarioOf<P::Geometry>> = (0..settings.eval_episodes)
        .map(|i| P::Geometry::draw(&family, phase.seeds.evaluation, i))
        .collect();
    // With an arrival margin the evaluation judges what the steps minimise: the miss at the
    // margin's cycle too, read off the flights' states there.
    let margin = objective.arrival_margin;
    let judged = |o: &EpisodeOutcome<P::Geometry>| {
        let scenario = &evaluation[o.episode];
        let early = margin_cycle(P::Geometry::plan(scenario).steps as usize, margin).and_then(|e| {
            let point = o.trajectory.as_ref()?.get(e)?;
            early_miss::<P>(scenario, &point.state, e as u32, &objective)
        });
        early.unwrap_or(0.0) + objective.value(&o.terminal, o.final_mass)
    };
    let evaluate = |agent: &Sac, step: u64, batch_objective: f64, seconds: f64| {
        // Dispersed fine-tuning is judged as the SIL flies the network alone, dispersed.
        let outcomes = if settings.dispersed {
            let flights = SilFlights {
                record: if margin > 0 { evaluation.len() } else { 0 },
                ..SilFlights::network_alone(&phase.sil.dispersions, phase.seeds.evaluation)
            };
            P::Geometry::fly_learner(phase, agent, &evaluation, &flights)?
        } else {
            evaluate_batched::<MdpEnv<P>, _>(&phase.env, &evaluation, |o| policy_batch(agent, o), margin > 0)?
        };
        let n = outcomes.len().max(1) as f64;
        Ok::<_, ExperimentError>(FinetuneRow {
            step,
            batch_objective,
            objective: outcomes.iter().map(judged).sum::<f64>() / n,
            within_goal: outcomes.iter().filter(|o| meets(o, ACCURACY_GOAL)).count() as f64 / n,
            summary: summarize(&outcomes),
            seconds,
        })
    };
    let mut agent = learner(phase, P::OBS)?;
    let start_actor = dir.join("start-actor.safetensors");
    if step_file(&dir, 0).exists() && !began_from(phase, P::OBS, &start_actor, start)? {
        let why = if chained {
            "the phase before's best now: the phase before changed since; use a new folder"
        } else {
            "the actor it is asked to go on from: resume with the start it began from, or use a new folder"
        };
        return Err(ExperimentError::Mismatch(format!(
            "{} began from another actor than {}, {why}",
            dir.display(),
            start.display()
        )));
    }
    if !step_file(&dir, 0).exists() {
        // The flown actor of a learner checkpoint or of an actor file.
        let flown = load_agent(phase, P::OBS, start)?;
        if settings.dispersed {
            // Refused before the folder is made: the SIL loop must fly this network.
            learner_blob(phase, &flown)?;
        }
        prepare_run(run_config, run)?;
        flown.save_flown_actor(&start_actor)?;
        agent.start_from_actor(&start_actor)?;
        let _ = std::fs::remove_file(&state_path);
        // Written last: the start is complete once step 0 is there.
        agent.save(&step_file(&dir, 0))?;
    }
    let done = (0..=settings.steps)
        .rev()
        .find(|&s| s % settings.eval_every == 0 && step_file(&dir, s).exists())
        .unwrap_or(0);
    agent.load(&step_file(&dir, done))?;
    let mut rows: Vec<FinetuneRow> = match std::fs::read(&state_path) {
        Ok(bytes) => serde_json::from_slice(&bytes)
            .map_err(|e| ExperimentError::Mismatch(format!("{} does not parse: {e}", state_path.display())))?,
        Err(_) => Vec::new(),
    };
    rows.retain(|r| r.step <= done);
    if rows.last().is_none_or(|r| r.step != done) {
        // Stopped between a checkpoint and its evaluation.
        let row = evaluate(&agent, done, 0.0, 0.0)?;
        rows.push(row);
        write_logs(&dir, &rows, &agent)?;
    }
    let bar = progress_bar(settings.steps - done, "finetune step");
    let mut clock = Instant::now();
    let mut batch_objectives = Vec::new();
    for step in done + 1..=settings.steps {
        let first = FIRST_SCENARIO + step * settings.flights;
        let report = finetune_step::<P>(phase, &mut agent, first, settings.flights, &objective)?;
        batch_objectives.push(report.objective);
        bar.inc(1);
        if step % settings.eval_every == 0 || step == settings.steps {
            agent.save(&step_file(&dir, step))?;
            let mean = batch_objectives.iter().sum::<f64>() / batch_objectives.len().max(1) as f64;
            let row = evaluate(&agent, step, mean, clock.elapsed().as_secs_f64())?;
            bar.set_message(format!(
                "objective {:.4}, {:.1} % within the goal",
                row.objective,
                100.0 * row.within_goal
            ));
            rows.push(row);
            write_logs(&dir, &rows, &agent)?;
            batch_objectives.clear();
            clock = Instant::now();
        }
    }
    bar.finish_and_clear();
    let best = best_row(&rows).map_or(0, |r| r.step);
    let best_actor = dir.join("best-actor.safetensors");
    let mut flown = learner(phase, P::OBS)?;
    flown.load(&dir.join("best.safetensors"))?;
    flown.save_flown_actor(&best_actor)?;
    Ok(FinetuneSummary {
        folder: dir,
        rows,
        best_step: best,
        dispersed: settings.dispersed,
        best_actor,
    })
}

/// The evaluation with the smallest mean objective (the earlier of equals).
fn best_row(rows: &[FinetuneRow]) -> Option<&FinetuneRow> {
    rows.iter()
        .reduce(|best, r| if r.objective < best.objective { r } else { best })
}

/// state.json, steps.csv, steps.svg, the residual chart, and best.safetensors when the last
/// row is the best.
fn write_logs(dir: &Path, rows: &[FinetuneRow], agent: &Sac) -> Result<(), ExperimentError> {
    if best_row(rows).map(|r| r.step) == rows.last().map(|r| r.step) {
        agent.save(&dir.join("best.safetensors"))?;
    }
    write_rows(
        dir,
        "steps",
        rows,
        "Fine-tuning through the dynamics: terminal residuals (evaluation flights)",
        "step",
    )?;
    let series = |name: &str, f: &dyn Fn(&FinetuneRow) -> f64| Series {
        name: name.into(),
        points: rows.iter().map(|r| (r.step as f64, f(r))).collect(),
        band: None,
    };
    let _ = line_chart(
        &dir.join("steps.svg"),
        "Fine-tuning through the dynamics: evaluation flights",
        "step",
        "share / objective",
        &[
            series("within the goal", &|r| r.within_goal),
            series("objective (relative to the start)", &|r| {
                r.objective / rows[0].objective.max(f64::MIN_POSITIVE)
            }),
        ],
        false,
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::EMBEDDED_DEFAULT;
    use ground_core::env::{Planar, Transfer};

    /// The closed-loop objective of flight `scenario` with `delta` added to component `j` of
    /// the action at step `k`, every other action the policy's on the state it reaches.
    fn perturbed_objective(
        config: &ExperimentConfig,
        agent: &Sac,
        scenario: &ScenarioOf<Planar>,
        (k, j, delta): (usize, usize, f32),
        objective: &Objective,
    ) -> f64 {
        let mut env = MdpEnv::<Transfer>::new(&config.env).unwrap();
        let mut obs = env.reset(scenario).unwrap();
        let steps = Planar::plan(scenario).steps as usize;
        let early = steps - objective.arrival_margin as usize;
        let only_miss = Objective {
            propellant_weight: 0.0,
            ..*objective
        };
        let mut value = 0.0;
        let mut step = 0;
        loop {
            let mut action = agent.act(obs.as_ref(), 1);
            if step == k {
                action[j] += delta;
            }
            let s = env.step_slice(&action).unwrap();
            step += 1;
            if step == early && objective.arrival_margin > 0 {
                let state = s.info.state;
                let features = Transfer::features(scenario, &state, step as u32).unwrap();
                value += only_miss.value(&Transfer::residuals(&features), 1.0);
            }
            if s.done {
                return value + objective.value(&s.info.residuals, s.info.mass);
            }
            obs = s.observation;
        }
    }

    /// The backward pass's d(mean objective)/d(action) at a step is what moving that action
    /// does to the closed loop (the policy flying the rest from the states it then reaches):
    /// the adjoint through the cycles' Jacobians, the features' and the policy's is checked
    /// against central differences of whole flights.
    #[test]
    fn action_gradients_equal_central_differences_of_the_closed_loop() {
        // At the arrival only, and with the miss also counted two cycles before it.
        for arrival_margin in [0, 2] {
            gradients_match_differences(arrival_margin);
        }
    }

    fn gradients_match_differences(arrival_margin: u32) {
        let mut config = ExperimentConfig::from_toml(EMBEDDED_DEFAULT).unwrap();
        config.sac.hidden = vec![32, 32];
        tch::manual_seed(5);
        let agent = Sac::new(config.sac.clone(), Transfer::OBS, 3, tch::Device::Cpu);
        let family = family_of::<Planar>(&config).unwrap();
        let scenarios: Vec<_> = (0..2).map(|i| Planar::draw(&family, 11, i)).collect();
        let objective = Objective {
            position_goal: 0.01,
            velocity_goal: 0.01,
            propellant_weight: 0.03,
            arrival_margin,
        };
        let (_, g, report) =
            action_gradients::<Transfer>(&config, &agent, &scenarios, Plant::Nominal, &objective).unwrap();
        assert_eq!(report.flights, 2);
        // Flight 0's rows come first; the gradient is of the mean over the two flights.
        let steps = Planar::plan(&scenarios[0]).steps as usize;
        let largest = g[..3 * steps].iter().fold(0.0f32, |m, x| m.max(x.abs()));
        assert!(largest > 0.0);
        let mut checked = 0;
        for k in [0, steps / 3, steps / 2, steps - 2, steps - 1] {
            for j in 0..3 {
                let h = ACTION_STEP;
                let up = perturbed_objective(&config, &agent, &scenarios[0], (k, j, h), &objective);
                let down = perturbed_objective(&config, &agent, &scenarios[0], (k, j, -h), &objective);
                let reference = (up - down) / (2.0 * f64::from(h)) / 2.0;
                let found = f64::from(g[3 * k + j]);
                assert!(
                    (found - reference).abs() <= 2e-3 * f64::from(largest),
                    "step {k} component {j}: backward pass {found}, closed-loop differences {reference}"
                );
                checked += usize::from(reference.abs() > 0.05 * f64::from(largest));
            }
        }
        // Not a check of zeros: most of the compared components move the objective.
        assert!(checked >= 5, "{checked}");
    }

    /// The torch actor as the flight software's actor, its action at one cycle moved.
    struct Nudged<'a> {
        agent: &'a Sac,
        cycle: std::cell::Cell<usize>,
        nudge: (usize, usize, f32),
    }

    impl onboard::guidance::Actor<10> for Nudged<'_> {
        fn act(&self, features: &[f32; 10]) -> [f32; 3] {
            let mut a = self.agent.act(features, 1);
            let (k, j, delta) = self.nudge;
            if self.cycle.get() == k {
                a[j] += delta;
            }
            self.cycle.set(self.cycle.get() + 1);
            [a[0], a[1], a[2]]
        }
    }

    /// A dispersed flight fine-tuned is the SIL's: flown by the SIL loop itself
    /// (`firmware_sim::fly`, the torch actor as the flight software's network) against the
    /// same dispersions, it ends where the fine-tuning's flight ends, and the backward pass's
    /// d(objective)/d(action) equals central differences of whole SIL flights with one action
    /// moved (navigation errors, pointing, the thrust factor and missed thrust all drawn).
    #[test]
    fn dispersed_action_gradients_equal_central_differences_of_sil_flights() {
        let mut config = ExperimentConfig::from_toml(EMBEDDED_DEFAULT).unwrap();
        config.sac.hidden = vec![32, 32];
        // Missed thrust often enough that the flights see an event.
        config.sil.dispersions.missed_thrust_per_year = 6.0;
        tch::manual_seed(5);
        let agent = Sac::new(config.sac.clone(), Transfer::OBS, 3, tch::Device::Cpu);
        let family = family_of::<Planar>(&config).unwrap();
        let scenario = Planar::draw(&family, 11, 0);
        let objective = Objective {
            position_goal: 0.01,
            velocity_goal: 0.01,
            propellant_weight: 0.03,
            arrival_margin: 0,
        };
        let seed = 77;
        let setup = flight_setup(&config, &config.sil.dispersions).unwrap();
        let sil = |nudge: (usize, usize, f32)| {
            let actor = Nudged {
                agent: &agent,
                cycle: std::cell::Cell::new(0),
                nudge,
            };
            let flight = firmware_sim::fly(firmware_sim::Transfer, &actor, &scenario, &setup, seed).unwrap();
            assert_eq!(flight.summary.guidance_faults, 0);
            flight
        };
        let plain = sil((usize::MAX, 0, 0.0));
        assert!(
            plain.steps.iter().any(|s| s.missed_thrust > 0.0),
            "no missed thrust drawn"
        );
        let value =
            |f: &firmware_sim::Flight| objective.value(&f.summary.final_residuals.unwrap(), f.summary.final_state.m);
        let flown = fly_dispersed::<Transfer>(&config, &agent, std::slice::from_ref(&scenario), seed, |_, _, _| {})
            .unwrap()
            .remove(0)
            .unwrap();
        let last = flown.flown.states.last().unwrap();
        let end = Planar::state_numbers(&plain.summary.final_state);
        for (a, b) in last.iter().zip(&end) {
            assert!(
                (a - b).abs() < 1e-9,
                "fine-tuning flight ends at {last:?}, the SIL's at {end:?}"
            );
        }
        let (_, g, report) = action_gradients::<Transfer>(
            &config,
            &agent,
            std::slice::from_ref(&scenario),
            Plant::Dispersed { seed },
            &objective,
        )
        .unwrap();
        assert_eq!(report.flights, 1);
        assert!((report.objective - value(&plain)).abs() < 1e-6);
        let steps = Planar::plan(&scenario).steps as usize;
        let largest = g.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        assert!(largest > 0.0);
        let mut checked = 0;
        for k in [0, steps / 3, steps / 2, steps - 2, steps - 1] {
            for j in 0..3 {
                let h = ACTION_STEP;
                let reference = (value(&sil((k, j, h))) - value(&sil((k, j, -h)))) / (2.0 * f64::from(h));
                let found = f64::from(g[3 * k + j]);
                assert!(
                    (found - reference).abs() <= 2e-3 * f64::from(largest),
                    "step {k} component {j}: backward pass {found}, SIL differences {reference}"
                );
                checked += usize::from(reference.abs() > 0.05 * f64::from(largest));
            }
        }
        assert!(checked >= 5, "{checked}");
    }
}
