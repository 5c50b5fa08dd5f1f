//! Monte Carlo evaluation (docs/spec.md section 9): N episodes of the deterministic policy from a seed
//! disjoint from training, against two baselines (zero thrust, uniform random actions) on the
//! same scenarios, and the optimality gap against the indirect solution of the first scenarios.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rand_chacha::ChaCha8Rng;
use rand_core::SeedableRng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::config::{ConfigError, ExperimentConfig};
use crate::error::ExperimentError;
use crate::phase::{family_of, policy_batch};
use crate::sac::agent::{read_checked_safetensors, Sac};
use crate::sac::trainer::uniform_action;
use crate::with_flown_problem;
use ground_core::charts::{flown_trajectories, histogram_grid, FlownPath, Panel};
use ground_core::env::batch::{evaluate_batched, summarize, EpisodeOutcome, OutcomeSummary, Stats};
use ground_core::env::{ActionOf, Geometry, MdpEnv, Planar, Problem, ScenarioOf};
use ground_core::generate::{DatasetFamily, DatasetRecord};
use ground_core::io::atomic_write;
use ground_core::solver::SolveOptions;

/// Episodes whose flown path is drawn.
const PLOTTED_TRAJECTORIES: usize = 6;
/// Terminal accuracy goal: |dr| <= 0.01 AU and |dv| <= 0.01 (canonical units) in 95% of
/// episodes.
pub const ACCURACY_GOAL: f64 = 0.01;
/// Tolerances every Monte Carlo reports its share within (position in AU, velocity in
/// canonical units, the same number for both): the goal and three tighter ones, past the 1e-3
/// that published RL rendezvous results quote to what terminal targeting reaches.
pub const REPORTED_TOLERANCES: [f64; 4] = [0.01, 0.005, 0.001, 0.0001];

/// Where a Monte Carlo's optimality gap takes the indirect optima of its first scenarios from.
#[derive(Debug, Clone, PartialEq)]
pub enum Optima {
    /// Solve the first N scenarios (None: the config's `evaluate.optimality_gap_cases`; 0: no
    /// gap).
    Solve(Option<u64>),
    /// The optima an earlier Monte Carlo of the same draws solved ([`reused_optima`]): the
    /// optimum of a draw does not depend on what flies it, so screening controllers on the
    /// same draws solves them once.
    Reused(Vec<Optimum>),
}

/// One draw's indirect optimum, as a Monte Carlo's gap row records it.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct Optimum {
    /// Index of the draw in the Monte Carlo stream.
    pub episode: usize,
    /// Final mass of the indirect solution (NaN where none was found; written as null).
    #[serde(rename = "optimal_mass", deserialize_with = "nan_if_null")]
    pub mass: f64,
    /// Whether the energy-to-fuel homotopy reached its final eps.
    #[serde(rename = "optimal_converged")]
    pub converged: bool,
    /// The eps the homotopy ended at.
    #[serde(rename = "optimal_eps", deserialize_with = "nan_if_null")]
    pub eps: f64,
}

impl From<&GapRow> for Optimum {
    fn from(row: &GapRow) -> Self {
        Self {
            episode: row.episode,
            mass: row.optimal_mass,
            converged: row.optimal_converged,
            eps: row.optimal_eps,
        }
    }
}

/// JSON writes a NaN as null: read back as NaN.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(deserializer: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(deserializer)?.unwrap_or(f64::NAN))
}

/// What [`reused_optima`] reads of a Monte Carlo's `summary.json`.
#[derive(Deserialize)]
struct SavedOptima {
    #[serde(default)]
    optima_key: Option<String>,
    gap: Vec<Optimum>,
}

impl Optima {
    /// No optimality gap.
    pub const NONE: Optima = Optima::Solve(Some(0));
}

/// What the indirect optima of a Monte Carlo's draws depend on, as 8 hex digits (CRC-32C):
/// the scenario family, the Monte Carlo seed and the spacecraft. Two Monte Carlos with the same
/// key solve the same optima for the same episodes.
pub fn optima_key(config: &ExperimentConfig) -> Result<String, ExperimentError> {
    const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);
    let spacecraft = config
        .env
        .canonical_spacecraft()
        .map_err(|e| ExperimentError::Mismatch(format!("spacecraft: {e}")))?;
    let posed = serde_json::to_vec(&(&config.family, config.seeds.monte_carlo, spacecraft))
        .map_err(|e| ExperimentError::Mismatch(format!("the optima's key: {e}")))?;
    Ok(format!("{:08x}", CRC.checksum(&posed)))
}

/// The optima of the Monte Carlo written to `run` (its `summary.json`, from `ground model
/// evaluate` or `ground model sil` with gap cases), refused unless they were solved for the
/// draws `config` flies (the same [`optima_key`]) or when there are none.
pub fn reused_optima(config: &ExperimentConfig, run: &Path) -> Result<Optima, ExperimentError> {
    let path = run.join("summary.json");
    let bytes = std::fs::read(&path).map_err(|e| ExperimentError::Io(path.clone(), e))?;
    let report: SavedOptima = serde_json::from_slice(&bytes)
        .map_err(|e| ExperimentError::Mismatch(format!("{} is not a Monte Carlo summary: {e}", path.display())))?;
    let wanted = optima_key(config)?;
    match report.optima_key.as_deref() {
        _ if report.gap.is_empty() => Err(ExperimentError::Mismatch(format!(
            "{} holds no optima (its Monte Carlo solved no scenario): solve them with --gap-cases N",
            path.display()
        ))),
        None => Err(ExperimentError::Mismatch(format!(
            "{} names no optima key, so its optima cannot be checked against these draws: solve them with --gap-cases N",
            path.display()
        ))),
        Some(key) if key != wanted => Err(ExperimentError::Mismatch(format!(
            "{}'s optima were solved for other draws (optima key {key}, these draws {wanted}: another family, Monte Carlo seed or spacecraft): solve them with --gap-cases N",
            path.display()
        ))),
        Some(_) => Ok(Optima::Reused(report.gap)),
    }
}

/// The optima a Monte Carlo of `config`'s draws needs (its `evaluate.optimality_gap_cases`),
/// taken from `earlier` when it solved them for the same draws, else solved.
pub fn optima_from(config: &ExperimentConfig, earlier: &MonteCarloReport) -> Result<Optima, ExperimentError> {
    let wanted = config.evaluate.optimality_gap_cases.min(config.evaluate.episodes) as usize;
    let same_draws = earlier.optima_key.as_deref() == Some(optima_key(config)?.as_str());
    Ok(if same_draws && earlier.gap.len() >= wanted {
        Optima::Reused(earlier.gap.iter().take(wanted).map(Optimum::from).collect())
    } else {
        Optima::Solve(None)
    })
}

/// One scenario's indirect optimum next to what the policy flew.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GapRow {
    /// Index of the scenario in the Monte Carlo stream (the episode that flew it).
    pub episode: usize,
    /// Final mass the policy arrived with (fraction of m0).
    pub policy_mass: f64,
    /// Final mass of the indirect solution (fraction of m0; NaN where no solution was found).
    pub optimal_mass: f64,
    /// Whether the energy-to-fuel homotopy reached its final eps.
    pub optimal_converged: bool,
    /// The eps the homotopy ended at (the final eps when converged).
    pub optimal_eps: f64,
    /// m_policy / m_optimal (docs/spec.md section 9).
    pub mass_ratio: f64,
    /// Propellant used / optimal propellant - 1.
    pub overspend: f64,
    /// The policy's terminal position residual |dr| (AU).
    pub policy_dr: f64,
    /// The policy's terminal velocity residual |dv| (AU/t*).
    pub policy_dv: f64,
}

/// What a Monte Carlo found (`summary.json`): the policy and both baselines on the same
/// scenarios, the accuracy goal's shares and the optimality gap.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MonteCarloReport {
    /// Name of the scenario distribution.
    pub scenario: String,
    /// What flew: the checkpoint or actor file, or the blob for a SIL Monte Carlo.
    pub checkpoint: PathBuf,
    /// Episodes flown by the policy.
    pub episodes: usize,
    /// Seed of the scenario draws (`seeds.monte_carlo`).
    pub seed: u64,
    /// Wall-clock seconds the Monte Carlo took.
    pub seconds: f64,
    /// The policy's reward, final mass and terminal residuals.
    pub policy: OutcomeSummary,
    /// The zero-thrust baseline (coasting) on the same scenarios.
    pub zero_thrust: OutcomeSummary,
    /// The baseline of uniform random actions on the same scenarios.
    pub random: OutcomeSummary,
    /// Fraction of completed episodes with |dr| <= 0.01 AU and |dv| <= 0.01.
    pub within_accuracy_goal: f64,
    /// (tolerance, fraction of completed episodes with |dr| and |dv| within it) for each of
    /// [`REPORTED_TOLERANCES`].
    #[serde(default)]
    pub within_tolerances: Vec<(f64, f64)>,
    /// The optimality gap: one row for each of the first `evaluate.optimality_gap_cases`
    /// scenarios, which the indirect method was run on.
    pub gap: Vec<GapRow>,
    /// Statistics of [`GapRow::mass_ratio`] over the rows with an optimum (None without).
    pub mass_ratio: Option<Stats>,
    /// Statistics of [`GapRow::overspend`] over the same rows.
    pub overspend: Option<Stats>,
    /// The accuracy goal's share by transfer size: quintiles of the zero-thrust miss.
    #[serde(default)]
    pub accuracy_by_coast_miss: Vec<AccuracyBand>,
    /// The goal's share on the optimality-gap scenarios the indirect method solved: draws
    /// shown feasible, where a share of all draws would also count draws no control reaches.
    #[serde(default)]
    pub where_solved: Option<SolvedShare>,
    /// The goal's share by eccentricity (eccentric distributions only).
    #[serde(default)]
    pub accuracy_by_eccentricity: Vec<EccentricityBand>,
    /// [`optima_key`] of the draws, when the gap has rows: what lets a later Monte Carlo of
    /// the same draws reuse its optima ([`reused_optima`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub optima_key: Option<String>,
}

/// The goal's share on the scenarios with an indirect optimum.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SolvedShare {
    /// Scenarios the indirect method was run on (the optimality gap's).
    pub scenarios: usize,
    /// Of those, the ones it solved (converged).
    pub solved: usize,
    /// Share of the solved ones the policy flew within 0.01 AU and 0.01.
    pub within_goal: f64,
    /// Unsolved scenarios the policy flew within the goal (feasible by the flight itself).
    pub unsolved_within_goal: usize,
}

/// Episodes grouped by the larger of the departure and target orbits' eccentricities.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EccentricityBand {
    /// The band's edges: e_min <= max(e_departure, e_target) < e_max.
    pub e_min: f64,
    /// Upper edge of the band (exclusive).
    pub e_max: f64,
    /// Episodes flown in the band.
    pub episodes: usize,
    /// Share of the band's completed episodes within 0.01 AU and 0.01.
    pub within_goal: f64,
    /// The band's optimality-gap scenarios solved by the indirect method, and the goal's share
    /// on them (None when the band has none).
    pub where_solved: Option<(usize, f64)>,
}

/// Edges of the eccentricity bands (the hard distributions draw e up to 0.75).
pub const ECCENTRICITY_EDGES: [f64; 5] = [0.0, 0.2, 0.4, 0.6, 1.0];

/// The goal's share on the gap's scenarios that the indirect method solved (`policy[i]` flew
/// scenario i; each gap row names its episode). None without gap rows.
pub fn share_where_solved<G: Geometry>(policy: &[EpisodeOutcome<G>], gap: &[GapRow]) -> Option<SolvedShare> {
    if gap.is_empty() {
        return None;
    }
    let flown = |converged: bool| -> Vec<EpisodeOutcome<G>> {
        gap.iter()
            .filter(|g| g.optimal_converged == converged)
            .filter_map(|g| policy.get(g.episode).cloned())
            .collect()
    };
    let solved = flown(true);
    Some(SolvedShare {
        scenarios: gap.len(),
        solved: solved.len(),
        within_goal: within_accuracy_goal(&solved),
        unsolved_within_goal: flown(false).iter().filter(|o| meets(o, ACCURACY_GOAL)).count(),
    })
}

/// The goal's share by the larger eccentricity of each scenario's two orbits, in the bands of
/// [`ECCENTRICITY_EDGES`] that hold episodes; empty when every scenario is near-circular (below
/// the first inner edge). `policy[i]` flew `scenarios[i]`.
pub fn accuracy_by_eccentricity<G: Geometry>(
    scenarios: &[ScenarioOf<G>],
    policy: &[EpisodeOutcome<G>],
    gap: &[GapRow],
) -> Vec<EccentricityBand> {
    let eccentricity = |s: &ScenarioOf<G>| {
        let plan = G::plan(s);
        plan.initial.shape.e.max(plan.target.e)
    };
    if scenarios.iter().all(|s| eccentricity(s) < ECCENTRICITY_EDGES[1]) {
        return Vec::new();
    }
    ECCENTRICITY_EDGES
        .windows(2)
        .filter_map(|edge| {
            let inside = |i: usize| {
                scenarios
                    .get(i)
                    .is_some_and(|s| (edge[0]..edge[1]).contains(&eccentricity(s)))
            };
            let outcomes: Vec<EpisodeOutcome<G>> = policy.iter().filter(|o| inside(o.episode)).cloned().collect();
            if outcomes.is_empty() {
                return None;
            }
            let rows: Vec<GapRow> = gap.iter().filter(|g| inside(g.episode)).copied().collect();
            let where_solved = share_where_solved(policy, &rows)
                .filter(|s| s.solved > 0)
                .map(|s| (s.solved, s.within_goal));
            Some(EccentricityBand {
                e_min: edge[0],
                e_max: edge[1],
                episodes: outcomes.len(),
                within_goal: within_accuracy_goal(&outcomes),
                where_solved,
            })
        })
        .collect()
}

/// Episodes grouped by how far coasting (zero thrust) would miss the target: the transfer's
/// size, since the target proxy is the same orbit at the spacecraft's own anomaly.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AccuracyBand {
    /// Zero-thrust terminal |dr| (AU) of the band's first and last episode.
    pub coast_miss_min: f64,
    /// Zero-thrust terminal |dr| (AU) of the band's last episode, the largest in it.
    pub coast_miss_max: f64,
    /// Episodes in the band (completed by both the policy and the coast).
    pub episodes: usize,
    /// Share of the band's episodes within 0.01 AU and 0.01.
    pub within_goal: f64,
    /// The policy's mean final mass in the band (fraction of m0).
    pub final_mass_mean: f64,
}

/// The goal's share in `bands` equal groups of the policy's completed episodes, ordered by the
/// zero-thrust miss of the same scenario (`zero[i]` flew `policy[i]`'s scenario).
pub fn accuracy_by_coast_miss<G: Geometry>(
    policy: &[EpisodeOutcome<G>],
    zero: &[EpisodeOutcome<G>],
    bands: usize,
) -> Vec<AccuracyBand> {
    let mut paired: Vec<(f64, &EpisodeOutcome<G>)> = policy
        .iter()
        .zip(zero)
        .filter(|(p, z)| p.completed && z.completed)
        .map(|(p, z)| (z.terminal.position, p))
        .collect();
    paired.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n = paired.len();
    // No more bands than episodes, so none is empty.
    let bands = bands.min(n);
    (0..bands)
        .map(|b| {
            let band = &paired[b * n / bands..(b + 1) * n / bands];
            let outcomes: Vec<EpisodeOutcome<G>> = band.iter().map(|(_, p)| (*p).clone()).collect();
            AccuracyBand {
                coast_miss_min: band[0].0,
                coast_miss_max: band[band.len() - 1].0,
                episodes: band.len(),
                within_goal: within_accuracy_goal(&outcomes),
                final_mass_mean: band.iter().map(|(_, p)| p.final_mass).sum::<f64>() / band.len() as f64,
            }
        })
        .collect()
}

/// Fraction of the completed episodes that end with |dr| <= 0.01 AU and |dv| <= 0.01
/// ([`ACCURACY_GOAL`], the accuracy goal).
pub fn within_accuracy_goal<G: Geometry>(outcomes: &[EpisodeOutcome<G>]) -> f64 {
    within_tolerance(outcomes, ACCURACY_GOAL)
}

/// Fraction of the completed episodes that end with |dr| <= `tolerance` AU and |dv| <=
/// `tolerance`.
pub fn within_tolerance<G: Geometry>(outcomes: &[EpisodeOutcome<G>], tolerance: f64) -> f64 {
    outcomes.iter().filter(|o| meets(o, tolerance)).count() as f64
        / outcomes.iter().filter(|o| o.completed).count().max(1) as f64
}

/// A completed episode that ends with |dr| <= `tolerance` AU and |dv| <= `tolerance`.
pub fn meets<G: Geometry>(outcome: &EpisodeOutcome<G>, tolerance: f64) -> bool {
    outcome.completed && outcome.terminal.position <= tolerance && outcome.terminal.velocity <= tolerance
}

/// `ground model evaluate`: the Monte Carlo of docs/spec.md section 9 for the agent in `checkpoint`, written
/// to `out` (mc.csv, summary.json, histograms.svg, trajectories.svg).
pub fn monte_carlo(
    config: &ExperimentConfig,
    checkpoint: &Path,
    out: &Path,
    episodes: Option<u64>,
    optima: Optima,
) -> Result<MonteCarloReport, ExperimentError> {
    with_flown_problem!(config, P => monte_carlo_for::<P>(config, checkpoint, out, episodes, optima))
}

/// Loads the flown actor of a checkpoint for the config's problem: a learner checkpoint (a
/// phase's best.safetensors) or an actor file (a shipped model's actor.safetensors).
pub fn load_agent(config: &ExperimentConfig, obs_dim: usize, checkpoint: &Path) -> Result<Sac, ExperimentError> {
    tch::set_num_threads(config.compute.threads);
    let names: Vec<String> = read_checked_safetensors(checkpoint)?
        .into_iter()
        .map(|(name, _)| name)
        .collect();
    let actor_only = names.iter().all(|name| name.starts_with("actor."));
    let mut sac = config.sac.clone();
    if !names.iter().any(|name| name.starts_with("average.")) {
        // No averaged copy in the file (an actor file, or a learner saved without one: a
        // fine-tuning step's): its own actor is the one that flies.
        sac.actor_averaging = 0.0;
    }
    let mut agent = Sac::new(sac, obs_dim, config.action_dim(), config.device()?);
    agent.labels = config.learner_labels();
    if actor_only {
        agent.load_actor(checkpoint)?;
    } else {
        agent.load(checkpoint)?;
    }
    Ok(agent)
}

fn fly<P: Problem>(
    config: &ExperimentConfig,
    scenarios: &[ScenarioOf<P::Geometry>],
    policy: impl FnMut(&[P::Obs]) -> Vec<ActionOf<P::Geometry>>,
    record: bool,
) -> Result<Vec<EpisodeOutcome<P::Geometry>>, ExperimentError> {
    Ok(evaluate_batched::<MdpEnv<P>, _>(
        &config.env,
        scenarios,
        policy,
        record,
    )?)
}

fn monte_carlo_for<P: Problem>(
    config: &ExperimentConfig,
    checkpoint: &Path,
    out: &Path,
    episodes: Option<u64>,
    optima: Optima,
) -> Result<MonteCarloReport, ExperimentError> {
    let start = Instant::now();
    let n = episodes.unwrap_or(config.evaluate.episodes);
    if n == 0 {
        return Err(ConfigError::Invalid("a Monte Carlo needs at least one episode".into()).into());
    }
    let agent = load_agent(config, P::OBS, checkpoint)?;
    let seed = config.seeds.monte_carlo;
    let family = family_of::<P::Geometry>(config)?;
    let scenarios: Vec<_> = (0..n).map(|i| P::Geometry::draw(&family, seed, i)).collect();
    let bar = ground_core::progress::spinner(format!("Monte Carlo: {n} episodes"));
    // Trajectories are kept only for the plotted few (memory stays flat for 10^4 episodes).
    let policy = fly::<P>(config, &scenarios, |obs| policy_batch(&agent, obs), false)?;
    let plotted = fly::<P>(
        config,
        &scenarios[..scenarios.len().min(PLOTTED_TRAJECTORIES)],
        |obs| policy_batch(&agent, obs),
        true,
    )?;
    bar.finish_and_clear();
    let flown = Flown {
        scenarios: &scenarios,
        policy: &policy,
        plotted: &plotted,
    };
    report_and_write::<P>(config, checkpoint, &flown, out, optima, start)
}

/// A policy's Monte Carlo flights, however flown: the scenarios, one outcome per scenario, and
/// the outcomes whose trajectories are drawn.
pub struct Flown<'a, G: Geometry = Planar> {
    /// The scenarios flown, in order.
    pub scenarios: &'a [ScenarioOf<G>],
    /// One outcome per scenario.
    pub policy: &'a [EpisodeOutcome<G>],
    /// The outcomes whose paths are plotted (their trajectories recorded).
    pub plotted: &'a [EpisodeOutcome<G>],
}

/// The Monte Carlo report of a policy's `outcomes` on `scenarios` (flown by whatever flew it:
/// the tch actor here, the SIL loop in [`crate::sil`]): the zero-thrust and random baselines on
/// the same scenarios, the optimality gap on the first ones, the files in `out`.
pub fn report_and_write<P: Problem>(
    config: &ExperimentConfig,
    source: &Path,
    flown: &Flown<P::Geometry>,
    out: &Path,
    optima: Optima,
    start: Instant,
) -> Result<MonteCarloReport, ExperimentError> {
    let Flown {
        scenarios,
        policy,
        plotted,
    } = *flown;
    let seed = config.seeds.monte_carlo;
    let n = scenarios.len() as u64;
    let zero = fly::<P>(
        config,
        scenarios,
        |obs| vec![P::Geometry::zero_thrust_action(); obs.len()],
        false,
    )?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7a6e_646f);
    let random = fly::<P>(
        config,
        scenarios,
        |obs| {
            obs.iter()
                .filter_map(|_| ActionOf::<P::Geometry>::try_from(&uniform_action(&mut rng, P::Geometry::ACT)[..]).ok())
                .collect()
        },
        false,
    )?;

    let gap = match optima {
        Optima::Solve(cases) => {
            let k = cases.unwrap_or(config.evaluate.optimality_gap_cases).min(n) as usize;
            optimality_gap(config, k, policy)?
        }
        Optima::Reused(optima) => optima
            .iter()
            .filter_map(|optimum| {
                Some(gap_row(
                    optimum.episode,
                    policy.get(optimum.episode)?,
                    optimum.mass,
                    optimum.converged,
                    optimum.eps,
                ))
            })
            .collect(),
    };
    let optima_key = if gap.is_empty() {
        None
    } else {
        Some(optima_key(config)?)
    };
    let within = within_accuracy_goal(policy);
    let usable: Vec<&GapRow> = gap
        .iter()
        .filter(|g| g.optimal_converged || g.optimal_mass.is_finite())
        .collect();
    let report = MonteCarloReport {
        scenario: config.family.label().to_string(),
        checkpoint: source.to_path_buf(),
        episodes: policy.len(),
        seed,
        seconds: start.elapsed().as_secs_f64(),
        policy: summarize(policy),
        zero_thrust: summarize(&zero),
        random: summarize(&random),
        within_accuracy_goal: within,
        within_tolerances: REPORTED_TOLERANCES
            .iter()
            .map(|&t| (t, within_tolerance(policy, t)))
            .collect(),
        mass_ratio: (!usable.is_empty()).then(|| Stats::of(usable.iter().map(|g| g.mass_ratio))),
        overspend: (!usable.is_empty()).then(|| Stats::of(usable.iter().map(|g| g.overspend))),
        where_solved: share_where_solved(policy, &gap),
        accuracy_by_eccentricity: accuracy_by_eccentricity(scenarios, policy, &gap),
        accuracy_by_coast_miss: accuracy_by_coast_miss(policy, &zero, 5),
        gap,
        optima_key,
    };
    write_outputs(out, &report, policy, &zero, &random, scenarios, plotted)?;
    Ok(report)
}

/// Indirect solutions of the first `cases` Monte Carlo draws (in parallel; the draws the
/// policy flew) against the policy's final masses: planar draws by the planar method, inclined
/// ones by the three-dimensional one.
fn optimality_gap<G: Geometry>(
    config: &ExperimentConfig,
    cases: usize,
    policy: &[EpisodeOutcome<G>],
) -> Result<Vec<GapRow>, ExperimentError> {
    let family = family_of::<G>(config)?;
    let Ok(spacecraft) = config.env.canonical_spacecraft() else {
        return Ok(Vec::new());
    };
    let options = SolveOptions::default();
    let cases = cases.min(policy.len());
    let bar = ground_core::progress::bar(
        cases as u64,
        "optimality gap {bar:30} {pos}/{len} indirect solves [{elapsed}<{eta}]",
    );
    let rows = policy[..cases]
        .par_iter()
        .enumerate()
        .map(|(i, flown)| {
            let record = family.solve(config.seeds.monte_carlo, i as u64, &spacecraft, &options);
            let figures = record.figures();
            bar.inc(1);
            gap_row(i, flown, figures.final_mass, figures.converged, figures.final_eps)
        })
        .collect();
    bar.finish_and_clear();
    Ok(rows)
}

/// Episode `episode`'s row of the gap: what `flown` arrived with against the optimum's final
/// mass `optimal`.
fn gap_row<G: Geometry>(episode: usize, flown: &EpisodeOutcome<G>, optimal: f64, converged: bool, eps: f64) -> GapRow {
    GapRow {
        episode,
        policy_mass: flown.final_mass,
        optimal_mass: optimal,
        optimal_converged: converged,
        optimal_eps: eps,
        mass_ratio: flown.final_mass / optimal,
        overspend: (1.0 - flown.final_mass) / (1.0 - optimal) - 1.0,
        policy_dr: flown.terminal.position,
        policy_dv: flown.terminal.velocity,
    }
}

fn write_outputs<G: Geometry>(
    out: &Path,
    report: &MonteCarloReport,
    policy: &[EpisodeOutcome<G>],
    zero: &[EpisodeOutcome<G>],
    random: &[EpisodeOutcome<G>],
    scenarios: &[ScenarioOf<G>],
    plotted: &[EpisodeOutcome<G>],
) -> Result<(), ExperimentError> {
    let write = |name: &str, bytes: &[u8]| {
        let path = out.join(name);
        atomic_write(&path, bytes).map_err(|e| ExperimentError::Io(path, e))
    };
    let mut csv = String::from(
        "episode,completed,reward,final_mass,dr,dv,zero_thrust_reward,zero_thrust_dr,random_reward,random_dr\n",
    );
    for ((p, z), r) in policy.iter().zip(zero).zip(random) {
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{},{},{},{}",
            p.episode,
            p.completed,
            p.total_reward,
            p.final_mass,
            p.terminal.position,
            p.terminal.velocity,
            z.total_reward,
            z.terminal.position,
            r.total_reward,
            r.terminal.position
        );
    }
    write("mc.csv", csv.as_bytes())?;
    let mut gap = String::from(
        "episode,policy_mass,optimal_mass,optimal_converged,optimal_eps,mass_ratio,overspend,policy_dr,policy_dv\n",
    );
    for g in &report.gap {
        let _ = writeln!(
            gap,
            "{},{},{},{},{},{},{},{},{}",
            g.episode,
            g.policy_mass,
            g.optimal_mass,
            g.optimal_converged,
            g.optimal_eps,
            g.mass_ratio,
            g.overspend,
            g.policy_dr,
            g.policy_dv
        );
    }
    write("optimality-gap.csv", gap.as_bytes())?;
    write("summary.json", &serde_json::to_vec_pretty(report).unwrap_or_default())?;

    let done = || policy.iter().filter(|o| o.completed);
    let dr_median = report.policy.terminal_position.p50;
    let panels = vec![
        Panel {
            title: "Episode reward".into(),
            x_label: "total reward".into(),
            values: done().map(|o| o.total_reward).collect(),
            markers: vec![("zero thrust mean".into(), report.zero_thrust.total_reward.mean)],
        },
        Panel {
            title: "Final mass".into(),
            x_label: "m_f / m_0".into(),
            values: done().map(|o| o.final_mass).collect(),
            markers: vec![],
        },
        Panel {
            title: "Terminal position residual".into(),
            x_label: "|dr| (AU)".into(),
            values: done().map(|o| o.terminal.position).collect(),
            markers: vec![("goal 0.01 AU".into(), ACCURACY_GOAL), ("median".into(), dr_median)],
        },
        Panel {
            title: "Terminal velocity residual".into(),
            x_label: "|dv| (canonical)".into(),
            values: done().map(|o| o.terminal.velocity).collect(),
            markers: vec![("goal 0.01".into(), ACCURACY_GOAL)],
        },
    ];
    let _ = histogram_grid(
        &out.join("histograms.svg"),
        &format!("Monte Carlo, {} episodes", report.episodes),
        &panels,
        40,
    );
    // Flights between orbits of the reference plane are drawn in it; inclined ones are not.
    let paths: Vec<FlownPath> = plotted
        .iter()
        .filter_map(|o| {
            let t = o.trajectory.as_ref()?;
            let (initial, target) = G::reference_orbits(scenarios.get(o.episode)?)?;
            Some(FlownPath {
                label: format!(
                    "#{}: m_f {:.4}, dr {:.4} AU",
                    o.episode, o.final_mass, o.terminal.position
                ),
                initial,
                target,
                points: t
                    .iter()
                    .map(|p| {
                        let [x, y, _] = G::position(&p.state);
                        (x, y, p.command.map_or(0.0, |c| G::throttle(&c)))
                    })
                    .collect(),
            })
        })
        .collect();
    if !paths.is_empty() {
        let _ = flown_trajectories(&out.join("trajectories.svg"), "Flown by the policy", &paths);
    }
    Ok(())
}

/// A short human-readable summary of a Monte Carlo report.
pub fn describe(report: &MonteCarloReport) -> String {
    let mut s = String::new();
    let row = |s: &mut String, name: &str, o: &OutcomeSummary| {
        let _ = writeln!(
            s,
            "{name:<12} reward {:>8.4} +- {:<7.4} final mass {:.4}  dr p50 {:.4} p95 {:.4} AU  dv p50 {:.4} p95 {:.4}  ({} of {} completed)",
            o.total_reward.mean,
            o.total_reward.std,
            o.final_mass.mean,
            o.terminal_position.p50,
            o.terminal_position.p95,
            o.terminal_velocity.p50,
            o.terminal_velocity.p95,
            o.completed,
            o.episodes
        );
    };
    row(&mut s, "policy", &report.policy);
    row(&mut s, "zero thrust", &report.zero_thrust);
    row(&mut s, "random", &report.random);
    let _ = writeln!(s, "{}", accuracy_line(report));
    for band in &report.accuracy_by_coast_miss {
        let _ = writeln!(
            s,
            "  coasting would miss by {:.3}-{:.3} AU: {:>5.1}% within the goal, final mass {:.4} ({} episodes)",
            band.coast_miss_min,
            band.coast_miss_max,
            100.0 * band.within_goal,
            band.final_mass_mean,
            band.episodes
        );
    }
    for band in &report.accuracy_by_eccentricity {
        let _ = writeln!(s, "  {}", eccentricity_line(band));
    }
    if let Some(line) = solved_line(report) {
        let _ = writeln!(s, "{line}");
    }
    if let Some(gap) = gap_line(report) {
        let _ = writeln!(s, "{gap}");
    }
    s
}

/// One eccentricity band in words.
pub fn eccentricity_line(band: &EccentricityBand) -> String {
    let mut line = format!(
        "e {:.1}-{:.1}: {:>5.1}% within the goal ({} episodes)",
        band.e_min,
        band.e_max,
        100.0 * band.within_goal,
        band.episodes
    );
    if let Some((solved, share)) = band.where_solved {
        let _ = write!(
            line,
            "; {:.1}% of the {solved} solved by the indirect method",
            100.0 * share
        );
    }
    line
}

/// The goal's share on the draws the indirect method solved, in words.
pub fn solved_line(report: &MonteCarloReport) -> Option<String> {
    let s = report.where_solved?;
    Some(format!(
        "On the {} of the first {} scenarios the indirect method solved: {:.1}% within the goal ({} unsolved flown within it).",
        s.solved,
        s.scenarios,
        100.0 * s.within_goal,
        s.unsolved_within_goal
    ))
}

/// How many episodes met the terminal-accuracy goal, in words.
pub fn accuracy_line(report: &MonteCarloReport) -> String {
    let mut line = format!(
        "Within |dr| <= 0.01 AU and |dv| <= 0.01: {:.1}% of completed episodes",
        100.0 * report.within_accuracy_goal
    );
    let tighter: Vec<String> = report
        .within_tolerances
        .iter()
        .filter(|(t, _)| *t < ACCURACY_GOAL)
        .map(|(t, share)| format!("within {t}: {:.1}%", 100.0 * share))
        .collect();
    if !tighter.is_empty() {
        let _ = write!(line, " ({})", tighter.join(", "));
    }
    line.push('.');
    line
}

/// The optimality gap in words, when the indirect solutions were computed.
pub fn gap_line(report: &MonteCarloReport) -> Option<String> {
    let (ratio, over) = (report.mass_ratio.as_ref()?, report.overspend.as_ref()?);
    Some(format!(
        "Optimality gap on {} scenarios solved by the indirect method: m_policy / m_optimal mean {:.4} (min {:.4}); propellant overspend median {:.2}% (p95 {:.1}%).",
        ratio.count,
        ratio.mean,
        ratio.min,
        100.0 * over.p50,
        100.0 * over.p95
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use onboard::features::Residuals;

    fn outcome(episode: usize, dr: f64, mass: f64) -> EpisodeOutcome {
        EpisodeOutcome {
            episode,
            total_reward: 0.0,
            final_mass: mass,
            terminal: Residuals {
                position: dr,
                velocity: 0.0,
            },
            steps: 1,
            completed: true,
            error: None,
            non_finite_actions: 0,
            trajectory: None,
        }
    }

    /// An unsolved draw's NaN optimum is written as null and read back as NaN; the rows come
    /// back as the Monte Carlo wrote them.
    #[test]
    fn optima_written_by_a_monte_carlo_are_read_back_including_unsolved_draws() {
        let config = ExperimentConfig::from_toml("scenario = \"transfer-hard\"\n").unwrap();
        let flown = [outcome(0, 0.001, 0.7), outcome(1, 0.3, 0.9)];
        let rows = [
            super::gap_row(0, &flown[0], 0.72, true, 6.1e-5),
            super::gap_row(1, &flown[1], f64::NAN, false, 0.25),
        ];
        let dir = std::env::temp_dir().join(format!("lowthrust-optima-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let summary = serde_json::json!({ "optima_key": optima_key(&config).unwrap(), "gap": rows });
        std::fs::write(dir.join("summary.json"), serde_json::to_vec(&summary).unwrap()).unwrap();
        let Optima::Reused(optima) = reused_optima(&config, &dir).unwrap() else {
            panic!("not reused");
        };
        assert_eq!(optima.len(), 2);
        assert_eq!(
            (optima[0].episode, optima[0].mass, optima[0].converged),
            (0, 0.72, true)
        );
        assert!(optima[1].mass.is_nan() && !optima[1].converged && optima[1].eps == 0.25);
        // The gap rows rebuilt from them against the same flights are the rows written.
        let again: Vec<GapRow> = optima
            .iter()
            .map(|o| super::gap_row(o.episode, &flown[o.episode], o.mass, o.converged, o.eps))
            .collect();
        assert_eq!(format!("{again:?}"), format!("{rows:?}"));
        // Another spacecraft poses other optima.
        let other = ExperimentConfig::from_toml(
            "scenario = \"transfer-hard\"\n[env.spacecraft]\nmax_thrust_n = 2.5\nisp_s = 3872.0\ninitial_mass_kg = 3366.0",
        )
        .unwrap();
        assert_ne!(optima_key(&other).unwrap(), optima_key(&config).unwrap());
        assert!(reused_optima(&other, &dir)
            .unwrap_err()
            .to_string()
            .contains("other draws"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bands_follow_the_coasting_miss_whatever_the_episode_order() {
        // Episode i coasts to a miss of (i * 7 % 10) / 10 AU; the policy meets the goal on
        // the episodes whose coasting miss is below 0.5 AU, and ends with mass 1 - miss.
        let coast: Vec<f64> = (0..10).map(|i| f64::from(i * 7 % 10) / 10.0).collect();
        let zero: Vec<EpisodeOutcome> = coast.iter().enumerate().map(|(i, &m)| outcome(i, m, 1.0)).collect();
        let policy: Vec<EpisodeOutcome> = coast
            .iter()
            .enumerate()
            .map(|(i, &m)| outcome(i, if m < 0.5 { 0.001 } else { 0.1 }, 1.0 - m))
            .collect();
        let bands = accuracy_by_coast_miss(&policy, &zero, 5);
        let shares: Vec<f64> = bands.iter().map(|b| b.within_goal).collect();
        assert_eq!(shares, vec![1.0, 1.0, 0.5, 0.0, 0.0]);
        assert_eq!(bands[2].coast_miss_min, 0.4);
        assert_eq!(bands[2].coast_miss_max, 0.5);
        assert!((bands[4].final_mass_mean - (1.0 - 0.85)).abs() < 1e-12);
        assert_eq!(bands.iter().map(|b| b.episodes).sum::<usize>(), 10);
        // Fewer episodes than bands: one band per episode.
        let few = accuracy_by_coast_miss(&policy[..2], &zero[..2], 5);
        assert_eq!(few.iter().map(|b| b.episodes).collect::<Vec<_>>(), vec![1, 1]);
        // An incomplete policy episode leaves its band.
        let mut cut = policy.clone();
        cut[0].completed = false;
        assert_eq!(
            accuracy_by_coast_miss(&cut, &zero, 5)
                .iter()
                .map(|b| b.episodes)
                .sum::<usize>(),
            9
        );
    }

    fn gap_row(episode: usize, converged: bool) -> GapRow {
        GapRow {
            episode,
            policy_mass: 0.8,
            optimal_mass: if converged { 0.81 } else { f64::NAN },
            optimal_converged: converged,
            optimal_eps: 1e-4,
            mass_ratio: 0.8 / 0.81,
            overspend: 0.0,
            policy_dr: 0.0,
            policy_dv: 0.0,
        }
    }

    #[test]
    fn the_solved_share_counts_only_the_gap_scenarios_the_indirect_method_solved() {
        // Episodes 0..6 are gap scenarios: 0, 1, 2, 4 solved; the policy meets the goal on 0,
        // 2, 3 (unsolved) and 6 (outside the gap).
        let policy: Vec<EpisodeOutcome> = (0..8)
            .map(|i| outcome(i, if [0, 2, 3, 6].contains(&i) { 0.001 } else { 0.1 }, 0.8))
            .collect();
        let gap: Vec<GapRow> = (0..6).map(|i| gap_row(i, [0, 1, 2, 4].contains(&i))).collect();
        let share = share_where_solved(&policy, &gap).expect("gap rows");
        assert_eq!((share.scenarios, share.solved, share.unsolved_within_goal), (6, 4, 1));
        assert_eq!(share.within_goal, 0.5);
        assert!(share_where_solved(&policy, &[]).is_none());
    }

    #[test]
    fn eccentricity_bands_follow_the_larger_eccentricity_and_skip_circular_draws() {
        let kind = shared::scenario::ScenarioKind::TransferHard;
        // (e departure, e target): bands [0, 0.2), [0.2, 0.4), [0.6, 1.0); none in [0.4, 0.6).
        let es = [
            (0.1, 0.05),
            (0.3, 0.1),
            (0.1, 0.35),
            (0.7, 0.0),
            (0.65, 0.62),
            (0.0, 0.19),
        ];
        let scenarios: Vec<shared::scenario::Scenario> = es
            .iter()
            .enumerate()
            .map(|(i, &(e0, ef))| {
                let mut s = kind.draw(1, i as u64);
                s.initial.shape.e = e0;
                s.target.e = ef;
                s
            })
            .collect();
        // The goal is met on episodes 0, 1 and 3; episodes 0..4 are gap scenarios, 3 unsolved.
        let policy: Vec<EpisodeOutcome> = (0..6)
            .map(|i| outcome(i, if [0, 1, 3].contains(&i) { 0.001 } else { 0.1 }, 0.8))
            .collect();
        let gap: Vec<GapRow> = (0..4).map(|i| gap_row(i, i != 3)).collect();
        let bands = accuracy_by_eccentricity(&scenarios, &policy, &gap);
        let edges: Vec<(f64, f64)> = bands.iter().map(|b| (b.e_min, b.e_max)).collect();
        assert_eq!(edges, vec![(0.0, 0.2), (0.2, 0.4), (0.6, 1.0)]);
        assert_eq!(bands.iter().map(|b| b.episodes).collect::<Vec<_>>(), vec![2, 2, 2]);
        assert_eq!(
            bands.iter().map(|b| b.within_goal).collect::<Vec<_>>(),
            vec![0.5, 0.5, 0.5]
        );
        // Band [0, 0.2): gap episode 0 solved and met; [0.2, 0.4): 1 met, 2 missed; [0.6, 1):
        // its only gap episode (3) unsolved.
        assert_eq!(bands[0].where_solved, Some((1, 1.0)));
        assert_eq!(bands[1].where_solved, Some((2, 0.5)));
        assert_eq!(bands[2].where_solved, None);
        // Near-circular draws give no bands.
        let circular: Vec<shared::scenario::Scenario> = (0..6)
            .map(|i| shared::scenario::ScenarioKind::TransferCircular.draw(1, i))
            .collect();
        assert!(accuracy_by_eccentricity(&circular, &policy, &gap).is_empty());
    }

    #[test]
    fn tolerance_shares_count_both_residuals_and_completed_episodes_only() {
        // (dr, dv): inside 0.001; inside 0.005 by dr but not by dv; inside 0.01; outside 0.01
        // by dv alone; on the 0.005 boundary (inside); and one incomplete episode inside all.
        let cases = [
            (0.0005, 0.0009),
            (0.001, 0.006),
            (0.009, 0.002),
            (0.002, 0.02),
            (0.005, 0.005),
            (0.0, 0.0),
        ];
        let outcomes: Vec<EpisodeOutcome> = cases
            .iter()
            .enumerate()
            .map(|(i, &(dr, dv))| {
                let mut o = outcome(i, dr, 1.0);
                o.terminal.velocity = dv;
                o.completed = i < 5;
                o
            })
            .collect();
        assert_eq!(within_tolerance(&outcomes, 0.001), 1.0 / 5.0);
        assert_eq!(within_tolerance(&outcomes, 0.005), 2.0 / 5.0);
        assert_eq!(within_tolerance(&outcomes, 0.01), 4.0 / 5.0);
        assert_eq!(
            within_accuracy_goal(&outcomes),
            within_tolerance(&outcomes, ACCURACY_GOAL)
        );
    }
}
