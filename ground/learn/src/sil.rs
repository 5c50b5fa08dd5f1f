//! `ground model sil`: Monte Carlo of a weight blob flown by the software-in-the-loop guidance loop
//! ([`firmware_sim`]) against the dispersed truth plant, reported with the same metrics and
//! figures as the ground evaluation ([`crate::eval`]), plus what only SIL sees (guidance faults,
//! missed thrust).
//!
//! Flight `i` flies scenario `i` of the Monte Carlo stream with dispersion seed
//! `monte_carlo seed + i`, so a blob and its quantized twin meet the same dispersions.

use std::path::{Path, PathBuf};
use std::time::Instant;

use firmware_sim::{
    fly_observed, with_flight_problem, with_spatial_flight_problem, Controller, Dispersions, FlightGeometry,
    FlightSetup, FlightStep, PlanarProblem, SilError,
};
use onboard::features::ACTION3_LEN;
use onboard::guidance::Aided;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use shared::blob::AlignedBlob;
use shared::scenario::{Scenario, SpatialScenario};

use crate::config::{ConfigError, ExperimentConfig};
use crate::error::ExperimentError;
use crate::eval::{gap_line, report_and_write, solved_line, within_accuracy_goal, Flown, MonteCarloReport, Optima};
use crate::export::actor_network;
use crate::sac::agent::Sac;
use ground_core::demo::DemoGeometry;
use ground_core::env::batch::{EpisodeOutcome, TrajectoryPoint};
use ground_core::env::{step_reward, Dimension, EnvError, Geometry, Planar, Spatial};
use ground_core::io::atomic_write;
use ground_core::model_files::lookahead_terms;
use onboard::lookahead::LookaheadSettings;
use onboard::terminal::TerminalSettings;

/// Flights whose paths are drawn.
const PLOTTED_FLIGHTS: usize = 6;

/// The missed thrust one flight met.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MissedThrust {
    /// Canonical time spent in missed-thrust events.
    pub time: f64,
    /// Where the last step with missed thrust ends, as a fraction of the flight's steps (None:
    /// no missed thrust).
    pub last_end: Option<f64>,
}

/// Where in the flight the last missed thrust ended: the bands' upper ends (fractions of the
/// flight's steps). A rendezvous must meet its body at a fixed time, so thrust lost late has
/// little time left to be made up.
pub const MISSED_THRUST_BANDS: [f64; 4] = [0.5, 0.8, 0.9, 1.0];

/// The share within the goal of the flights whose last missed thrust ended in one band.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MissedThrustBand {
    /// "none", or the band of the flight ("0.8-0.9": the last missed thrust ended after 80 %
    /// and by 90 % of the flight's steps).
    pub band: String,
    /// Flights in the band.
    pub flights: usize,
    /// Share of the band's completed flights within 0.01 AU and 0.01.
    pub within_goal: f64,
}

impl std::fmt::Display for MissedThrustBand {
    /// "0.9-1 80.6 % (314)": the band, its share within the goal and its flights.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} {:.1} % ({})", self.band, 100.0 * self.within_goal, self.flights)
    }
}

/// Whether any flight of `bands` ([`by_last_missed_thrust`]) met missed thrust.
fn met_missed_thrust(bands: &[MissedThrustBand]) -> bool {
    bands.iter().skip(1).any(|b| b.flights > 0)
}

/// The flights grouped by where their last missed thrust ended ([`MISSED_THRUST_BANDS`]), the
/// flights without missed thrust first.
pub fn by_last_missed_thrust<G: Geometry>(
    outcomes: &[EpisodeOutcome<G>],
    missed: &[MissedThrust],
) -> Vec<MissedThrustBand> {
    let mut groups: Vec<(String, Vec<EpisodeOutcome<G>>)> = vec![("none".into(), Vec::new())];
    let mut lower = 0.0;
    for upper in MISSED_THRUST_BANDS {
        groups.push((format!("{lower}-{upper}"), Vec::new()));
        lower = upper;
    }
    for (o, m) in outcomes.iter().zip(missed) {
        let group = match m.last_end {
            None => 0,
            Some(end) => {
                1 + MISSED_THRUST_BANDS
                    .iter()
                    .position(|&u| end <= u)
                    .unwrap_or(MISSED_THRUST_BANDS.len() - 1)
            }
        };
        groups[group].1.push(o.clone());
    }
    groups
        .into_iter()
        .map(|(band, flights)| MissedThrustBand {
            band,
            flights: flights.len(),
            within_goal: within_accuracy_goal(&flights),
        })
        .collect()
}

/// The per-flight missed-thrust file of a SIL run, beside `mc.csv` (same `episode` numbers).
pub const MISSED_THRUST_CSV: &str = "missed-thrust.csv";

/// One row per flight: the episode, the canonical time it spent in missed-thrust events, and
/// where its last one ended as a fraction of its steps (empty: none), so each flight's outcome
/// (`mc.csv`) and its optimum (`optimality-gap.csv`) can be read against its missed thrust.
pub fn missed_thrust_csv<G: Geometry>(outcomes: &[EpisodeOutcome<G>], missed: &[MissedThrust]) -> String {
    let mut csv = String::from("episode,missed_thrust_time,last_missed_thrust_end\n");
    for (o, m) in outcomes.iter().zip(missed) {
        let end = m.last_end.map(|e| e.to_string()).unwrap_or_default();
        csv += &format!("{},{},{end}\n", o.episode, m.time);
    }
    csv
}

/// What SIL adds to the Monte Carlo report.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SilReport {
    /// The blob flown.
    pub blob: PathBuf,
    /// "f32", "int8", or "safe mode: " and why the blob was refused.
    pub controller: String,
    /// The rollout lookahead the blob flew with (None: the network alone).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lookahead: Option<LookaheadSettings>,
    /// The terminal targeting its last cycles flew with (None: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub terminal: Option<TerminalSettings>,
    /// The truth plant's dispersions.
    pub dispersions: Dispersions,
    /// Flights flown.
    pub flights: usize,
    /// Flights that could not be completed (plant or feature errors), with their reasons.
    pub failed: Vec<(usize, String)>,
    /// Guidance cycles in which guidance refused its input and commanded thrust off.
    pub guidance_faults: u64,
    /// Fraction of the flown time spent in missed-thrust events.
    pub missed_thrust_fraction: f64,
    /// The share within the goal by where the last missed thrust of a flight ended.
    #[serde(default)]
    pub by_last_missed_thrust: Vec<MissedThrustBand>,
    /// The flights' figures, as the evaluation's Monte Carlo reports them.
    pub monte_carlo: MonteCarloReport,
}

/// One SIL flight as the evaluation's episode outcome, the reward re-summed with the
/// environment's own step reward (terminal-accuracy term included) so the two compare.
fn outcome<const N: usize, G>(
    config: &ExperimentConfig,
    episode: usize,
    scenario: &G::Scenario,
    steps: &[FlightStep<N, G>],
    error: Option<SilError>,
    record: bool,
) -> EpisodeOutcome<G>
where
    G: Geometry + FlightGeometry,
{
    let plan = G::plan(scenario);
    let initial = G::departure(scenario);
    let reward =
        |k: &FlightStep<N, G>| step_reward(&config.env, plan, &k.residuals, G::throttle(&k.command), k.index + 1).0;
    let last = steps.last();
    EpisodeOutcome {
        episode,
        total_reward: steps.iter().map(reward).sum(),
        final_mass: last.map_or(G::mass(&initial), |k| G::mass(&k.state)),
        terminal: last.map_or(
            onboard::features::Residuals {
                position: f64::NAN,
                velocity: f64::NAN,
            },
            |k| k.residuals,
        ),
        steps: steps.len() as u32,
        completed: error.is_none() && steps.len() == plan.steps as usize,
        error: error.map(|e| match e {
            SilError::Plant { index, error } => EnvError::Propagation { step: index, error },
            SilError::Features { index, error } => EnvError::Features { step: index, error },
            SilError::Scenario(e) => EnvError::Scenario(e),
            SilError::Target { index, error } => EnvError::Body { step: index, error },
            SilError::WrongProblem { expected, found } => EnvError::WrongProblem { expected, found },
            SilError::Dispersion(_) | SilError::TimeUnit(_) => EnvError::Config("not flyable in SIL"),
        }),
        non_finite_actions: steps
            .iter()
            .filter(|k| k.guidance_error == Some(onboard::guidance::GuidanceError::NonFiniteAction))
            .count() as u32,
        trajectory: record.then(|| {
            std::iter::once(TrajectoryPoint {
                step: 0,
                state: initial,
                command: None,
                reward: 0.0,
            })
            .chain(steps.iter().map(|k| TrajectoryPoint {
                step: k.index + 1,
                state: k.state,
                command: Some(k.command),
                reward: reward(k),
            }))
            .collect()
        }),
    }
}

/// One flight's outcome, guidance faults and missed thrust, from its recorded cycles.
fn flown<const N: usize, G>(
    config: &ExperimentConfig,
    episode: usize,
    scenario: &G::Scenario,
    steps: &[FlightStep<N, G>],
    error: Option<SilError>,
    record: bool,
) -> (EpisodeOutcome<G>, u64, MissedThrust)
where
    G: Geometry + FlightGeometry,
{
    let faults = steps.iter().filter(|k| k.guidance_error.is_some()).count() as u64;
    let missed = MissedThrust {
        time: steps.iter().map(|k| k.missed_thrust).sum(),
        last_end: steps
            .iter()
            .rposition(|k| k.missed_thrust > 0.0)
            .map(|k| (k + 1) as f64 / f64::from(G::plan(scenario).steps)),
    };
    (outcome(config, episode, scenario, steps, error, record), faults, missed)
}

/// The flights' outcomes, guidance faults summed, and each flight's missed thrust.
type SilFlown<G> = (Vec<EpisodeOutcome<G>>, u64, Vec<MissedThrust>);

fn gather<G: Geometry>(flights: Vec<(EpisodeOutcome<G>, u64, MissedThrust)>) -> SilFlown<G> {
    let faults = flights.iter().map(|f| f.1).sum();
    let missed = flights.iter().map(|f| f.2).collect();
    (flights.into_iter().map(|f| f.0).collect(), faults, missed)
}

/// How a Monte Carlo of a blob flies, beyond the config: the plant's dispersions, the seed
/// flight i's draws start from (flight i draws from `seed + i`), how many flights keep their
/// trajectories, and the onboard aid flown with the network.
#[derive(Debug, Clone, Copy)]
pub struct SilFlights<'a> {
    /// The truth plant's dispersions.
    pub dispersions: &'a Dispersions,
    /// Flight i's dispersions are drawn from `seed + i`.
    pub seed: u64,
    /// The first `record` flights keep their trajectories.
    pub record: usize,
    /// Rollout lookahead around the network (None: the network alone), as flown: its rollouts'
    /// tolerances included ([`ExperimentConfig::lookahead_settings`]).
    pub lookahead: Option<LookaheadSettings>,
    /// Terminal targeting of the last cycles (None: none), as flown
    /// ([`ExperimentConfig::terminal_settings`]).
    pub terminal: Option<TerminalSettings>,
}

impl<'a> SilFlights<'a> {
    /// The config's SIL Monte Carlo: its seed and lookahead, with `dispersions`.
    pub fn of(config: &'a ExperimentConfig, dispersions: &'a Dispersions, record: usize) -> Self {
        Self {
            dispersions,
            seed: config.seeds.monte_carlo,
            record,
            lookahead: config.lookahead_settings(),
            terminal: config.terminal_settings(),
        }
    }

    /// The network alone, with `dispersions` drawn from `seed` on; no trajectory kept.
    pub fn network_alone(dispersions: &'a Dispersions, seed: u64) -> Self {
        Self {
            dispersions,
            seed,
            record: 0,
            lookahead: None,
            terminal: None,
        }
    }
}

/// Flies `blob` on `scenarios` as `flights` says, transfers or rendezvous as the config's
/// scenario, in the plane; returns the per-flight outcomes (trajectories recorded for the first
/// `flights.record`), guidance faults and each flight's missed thrust.
pub fn fly_blob(
    config: &ExperimentConfig,
    blob: &[u8],
    scenarios: &[Scenario],
    flights: &SilFlights,
) -> Result<SilFlown<Planar>, ExperimentError> {
    Planar::fly_blob(config, blob, scenarios, flights)
}

/// A blob of another family of the same problem (its cycle, units or orbits) is the ground's
/// error, not the flight software's, which cannot know the family; a blob of the other problem
/// the flight software refuses itself (safe mode).
fn check_mission(config: &ExperimentConfig, blob: &[u8]) -> Result<(), ExperimentError> {
    if let Ok(decoded) = shared::blob::decode(blob) {
        if decoded.kind == config.problem() {
            if let Some(why) = config.mission_refusal(&decoded.mission) {
                return Err(ExperimentError::Mismatch(why));
            }
        }
    }
    Ok(())
}

/// How a geometry's blobs fly in the SIL loop against the dispersed plant: planar blobs with
/// the onboard aids, three-dimensional ones (the same [`firmware_sim::fly_observed`]) with the
/// network alone.
pub trait SilGeometry: DemoGeometry {
    /// Flies `blob` on `scenarios` as `flights` says (the config's problem in this geometry):
    /// per-flight outcomes (trajectories recorded for the first `flights.record`), guidance
    /// faults and each flight's missed thrust.
    fn fly_blob(
        config: &ExperimentConfig,
        blob: &[u8],
        scenarios: &[Self::Scenario],
        flights: &SilFlights,
    ) -> Result<SilFlown<Self>, ExperimentError>;

    /// The flights of `agent`'s f32 blob on `scenarios` as `flights` says (the relabelling
    /// rounds and the fine-tuning that fly dispersed flights). An actor the flight software
    /// would refuse (not the onboard contract's shape) is an error here, not flights in safe
    /// mode.
    fn fly_learner(
        config: &ExperimentConfig,
        agent: &Sac,
        scenarios: &[Self::Scenario],
        flights: &SilFlights,
    ) -> Result<Vec<EpisodeOutcome<Self>>, ExperimentError> {
        let blob = learner_blob(config, agent)?;
        Ok(Self::fly_blob(config, &blob, scenarios, flights)?.0)
    }
}

impl SilGeometry for Planar {
    fn fly_blob(
        config: &ExperimentConfig,
        blob: &[u8],
        scenarios: &[Scenario],
        flights: &SilFlights,
    ) -> Result<SilFlown<Planar>, ExperimentError> {
        config.planar_family("the software-in-the-loop flight")?;
        check_mission(config, blob)?;
        with_flight_problem!(config.problem(), N, P => {
            fly_blob_as::<N, P>(P::default(), config, blob, scenarios, flights)
        })
    }
}

impl SilGeometry for Spatial {
    fn fly_blob(
        config: &ExperimentConfig,
        blob: &[u8],
        scenarios: &[SpatialScenario],
        flights: &SilFlights,
    ) -> Result<SilFlown<Spatial>, ExperimentError> {
        check_mission(config, blob)?;
        with_spatial_flight_problem!(config.problem(), N, P => {
            fly_spatial_blob_as::<N, P>(config, blob, scenarios, flights)
        })
    }
}

/// [`SilGeometry::fly_blob`] in three dimensions for one problem: the network, with the
/// onboard aids the flights ask for.
fn fly_spatial_blob_as<const N: usize, P>(
    config: &ExperimentConfig,
    blob: &[u8],
    scenarios: &[SpatialScenario],
    flights: &SilFlights,
) -> Result<SilFlown<Spatial>, ExperimentError>
where
    P: firmware_sim::Problem<N, Geometry = firmware_sim::Spatial> + Default + Sync,
    P::Target: onboard::guidance::SpatialTargetFeatures<N>,
{
    let setup = flight_setup(config, flights.dispersions)?;
    let blob = AlignedBlob::new(blob);
    let controller = Controller::<N, ACTION3_LEN>::load::<P>(blob.bytes());
    let flown_flights = scenarios
        .par_iter()
        .enumerate()
        .map(|(i, scenario)| {
            let mut steps = Vec::with_capacity(scenario.scenario.steps as usize);
            let seed = flights.seed.wrapping_add(i as u64);
            let keep = |k: &FlightStep<N, Spatial>| steps.push(*k);
            // A refused blob flies safe mode, thrust off every cycle: nothing to look ahead with
            // or to target.
            let network = matches!(controller, Controller::Network(_));
            let guide = Aided {
                actor: &controller,
                spacecraft: setup.spacecraft,
                lookahead: flights.lookahead.filter(|_| network),
                terminal: flights.terminal.filter(|_| network),
            };
            let result = fly_observed(P::default(), &guide, scenario, &setup, seed, keep);
            flown(config, i, scenario, &steps, result.err(), i < flights.record)
        })
        .collect();
    Ok(gather(flown_flights))
}

/// The config's spacecraft, plant tolerances and reward weights, flown with `dispersions`.
pub fn flight_setup(config: &ExperimentConfig, dispersions: &Dispersions) -> Result<FlightSetup, ExperimentError> {
    let spacecraft = config
        .env
        .canonical_spacecraft()
        .map_err(|e| ExperimentError::Mismatch(format!("spacecraft: {e}")))?;
    Ok(FlightSetup {
        spacecraft,
        tolerances: config.env.integrator.tolerances(),
        weights: config.env.reward.weights(),
        dispersions: *dispersions,
        time_unit_s: config.family.family.body.units().time_s,
    })
}

/// The f32 blob of `agent`'s flown actor, as the SIL flies a learner; an actor the flight
/// software would refuse (not the onboard contract's shape) is an error, not flights in safe
/// mode.
pub fn learner_blob(config: &ExperimentConfig, agent: &Sac) -> Result<Vec<u8>, ExperimentError> {
    let blob = actor_network(agent, config.feature_layout())?
        .f32_blob_for("learner", config.blob_mission())
        .map_err(|e| ExperimentError::Mismatch(format!("the actor does not export: {e}")))?;
    match firmware_sim::load_refusal(&blob, config.feature_layout()) {
        Some(why) => Err(ExperimentError::Mismatch(format!(
            "the flight software refuses the learner's blob ({why}): dispersed flights fly it in the SIL loop, so its network must have the onboard contract's shape"
        ))),
        None => Ok(blob),
    }
}

/// [`SilGeometry::fly_blob`] in the plane for one problem, with the onboard aids.
fn fly_blob_as<const N: usize, P: PlanarProblem<N> + Sync>(
    problem: P,
    config: &ExperimentConfig,
    blob: &[u8],
    scenarios: &[Scenario],
    flights: &SilFlights,
) -> Result<SilFlown<Planar>, ExperimentError> {
    let SilFlights {
        dispersions,
        seed,
        record,
        lookahead,
        terminal,
    } = *flights;
    let setup = flight_setup(config, dispersions)?;
    // On a cache line: the host kernels' vector loads then never straddle two.
    let blob = AlignedBlob::new(blob);
    let controller = Controller::<N>::load::<P>(blob.bytes());
    let flown_flights = scenarios
        .par_iter()
        .enumerate()
        .map(|(i, scenario)| {
            let mut steps = Vec::with_capacity(scenario.steps as usize);
            let flight_seed = seed.wrapping_add(i as u64);
            let keep = |k: &FlightStep<N>| steps.push(*k);
            // A refused blob flies safe mode, thrust off every cycle: nothing to look ahead with
            // or to target.
            let network = matches!(controller, Controller::Network(_));
            let guide = Aided {
                actor: &controller,
                spacecraft: setup.spacecraft,
                lookahead: lookahead.filter(|_| network),
                terminal: terminal.filter(|_| network),
            };
            let result = fly_observed(problem, &guide, scenario, &setup, flight_seed, keep);
            flown(config, i, scenario, &steps, result.err(), i < record)
        })
        .collect();
    Ok(gather(flown_flights))
}

/// `ground model sil`: the SIL Monte Carlo of `blob_path`, written to `out` (the evaluation's files
/// plus sil.json), with the optimality gap where `optima` says.
pub fn sil_monte_carlo(
    config: &ExperimentConfig,
    blob_path: &Path,
    out: &Path,
    episodes: Option<u64>,
    dispersions: &Dispersions,
    optima: Optima,
) -> Result<SilReport, ExperimentError> {
    crate::with_flown_problem!(config, P => sil_monte_carlo_for::<P>(config, blob_path, out, episodes, dispersions, optima))
}

fn sil_monte_carlo_for<P: ground_core::env::Problem>(
    config: &ExperimentConfig,
    blob_path: &Path,
    out: &Path,
    episodes: Option<u64>,
    dispersions: &Dispersions,
    optima: Optima,
) -> Result<SilReport, ExperimentError>
where
    P::Geometry: SilGeometry,
{
    // Refused before any folder is made (the flights would refuse them after).
    config.validate()?;
    dispersions
        .validate()
        .map_err(|e| ExperimentError::Mismatch(format!("dispersions: {e}")))?;
    let n = episodes.unwrap_or(config.sil.episodes);
    if n == 0 {
        return Err(ConfigError::Invalid("a SIL Monte Carlo needs at least one flight".into()).into());
    }
    let start = Instant::now();
    let blob = std::fs::read(blob_path).map_err(|e| ExperimentError::Io(blob_path.to_path_buf(), e))?;
    std::fs::create_dir_all(out).map_err(|e| ExperimentError::Io(out.to_path_buf(), e))?;
    let controller = describe_controller(config, &blob);
    let family = crate::phase::family_of::<P::Geometry>(config)?;
    let scenarios: Vec<_> = (0..n)
        .map(|i| P::Geometry::draw(&family, config.seeds.monte_carlo, i))
        .collect();
    let plant = if *dispersions == Dispersions::NONE {
        "nominal"
    } else {
        "dispersed"
    };
    let bar = ground_core::progress::spinner(format!("SIL: {n} {plant} flights"));
    let flights = SilFlights::of(config, dispersions, PLOTTED_FLIGHTS);
    let (outcomes, guidance_faults, missed) = P::Geometry::fly_blob(config, &blob, &scenarios, &flights)?;
    bar.finish_and_clear();
    // In the family's canonical time: each flight's cycles at its own length.
    let flown_time: f64 = outcomes
        .iter()
        .map(|o| f64::from(o.steps) * P::Geometry::plan(&scenarios[o.episode]).cycle)
        .sum();
    let failed = outcomes
        .iter()
        .filter_map(|o| o.error.map(|e| (o.episode, e.to_string())))
        .collect();
    let plotted: Vec<_> = outcomes.iter().filter(|o| o.trajectory.is_some()).cloned().collect();
    let flown = Flown {
        scenarios: &scenarios,
        policy: &outcomes,
        plotted: &plotted,
    };
    let monte_carlo = report_and_write::<P>(config, blob_path, &flown, out, optima, start)?;
    let report = SilReport {
        blob: blob_path.to_path_buf(),
        controller,
        lookahead: config.sil.lookahead,
        terminal: config.sil.terminal,
        dispersions: *dispersions,
        flights: outcomes.len(),
        failed,
        guidance_faults,
        missed_thrust_fraction: missed.iter().map(|m| m.time).sum::<f64>() / flown_time.max(f64::MIN_POSITIVE),
        by_last_missed_thrust: by_last_missed_thrust(&outcomes, &missed),
        monte_carlo,
    };
    let path = out.join(MISSED_THRUST_CSV);
    atomic_write(&path, missed_thrust_csv(&outcomes, &missed).as_bytes()).map_err(|e| ExperimentError::Io(path, e))?;
    let path = out.join("sil.json");
    atomic_write(&path, &serde_json::to_vec_pretty(&report).unwrap_or_default())
        .map_err(|e| ExperimentError::Io(path, e))?;
    Ok(report)
}

/// The folders under a run of the f32 and the int8 blob's SIL Monte Carlos ([`sil_of_blobs`]).
pub const SIL_FOLDERS: [&str; 2] = ["sil-f32", "sil-int8"];

/// The SIL Monte Carlos of a controller's f32 and int8 blobs with the config's dispersions,
/// written to `run/sil-f32` and `run/sil-int8` ([`SIL_FOLDERS`]): the rows a model card records.
pub fn sil_of_blobs(
    config: &ExperimentConfig,
    f32_blob: &Path,
    int8_blob: &Path,
    run: &Path,
) -> Result<[SilReport; 2], ExperimentError> {
    let [f32_folder, int8_folder] = SIL_FOLDERS;
    let fly = |blob: &Path, folder: &str| {
        sil_monte_carlo(
            config,
            blob,
            &run.join(folder),
            None,
            &config.sil.dispersions,
            Optima::NONE,
        )
    };
    Ok([fly(f32_blob, f32_folder)?, fly(int8_blob, int8_folder)?])
}

/// The folder under a run of [`aided_monte_carlo`]'s flights.
pub const AIDED_FOLDER: &str = "mc-aided";

/// When the config flies an onboard aid (`[sil] lookahead` or `[sil] terminal`): the nominal
/// Monte Carlo of `blob` flown with it (the config's `[evaluate]` episodes and optimality-gap
/// cases, no dispersions) in `run`'s [`AIDED_FOLDER`], for the model card: the controller as it
/// flies, where the card's Monte Carlo is the network alone. None otherwise. The optima come
/// from `optima` (the network's Monte Carlo of the same draws has them: [`Optima::Reused`]).
pub fn aided_monte_carlo(
    config: &ExperimentConfig,
    blob: &Path,
    run: &Path,
    optima: Optima,
) -> Result<Option<SilReport>, ExperimentError> {
    if config.sil.lookahead.is_none() && config.sil.terminal.is_none() {
        return Ok(None);
    }
    sil_monte_carlo(
        config,
        blob,
        &run.join(AIDED_FOLDER),
        Some(config.evaluate.episodes),
        &Dispersions::NONE,
        optima,
    )
    .map(Some)
}

/// Why the flight software would refuse the blob at `blob_path` for the config's problem
/// (None: it loads and flies). A refused blob flies its flights in safe mode, thrust off.
pub fn blob_refusal(config: &ExperimentConfig, blob_path: &Path) -> Result<Option<String>, ExperimentError> {
    let blob = std::fs::read(blob_path).map_err(|e| ExperimentError::Io(blob_path.to_path_buf(), e))?;
    Ok(firmware_sim::load_refusal(&blob, config.feature_layout()).map(|e| e.to_string()))
}

/// "f32", "int8", or "safe mode: <why the blob was refused>".
fn describe_controller(config: &ExperimentConfig, blob: &[u8]) -> String {
    match (
        firmware_sim::load_refusal(blob, config.feature_layout()),
        shared::blob::decode(blob),
    ) {
        (None, Ok(decoded)) => format!("{:?}", decoded.quantization).to_lowercase(),
        (Some(e), _) => format!("safe mode: {e}"),
        (None, Err(e)) => format!("safe mode: {e}"),
    }
}

/// A short summary of a SIL Monte Carlo.
pub fn describe(report: &SilReport) -> String {
    let p = &report.monte_carlo.policy;
    let mut controller = match &report.lookahead {
        Some(l) => {
            let terms: String = lookahead_terms(l).iter().map(|t| format!(", {t}")).collect();
            format!(
                "{} with lookahead, accuracy floor {}, fuel weight {}{terms}",
                report.controller, l.accuracy_floor, l.fuel_weight
            )
        }
        None => report.controller.clone(),
    };
    if let Some(t) = &report.terminal {
        controller += &format!(", terminal targeting of the last {} cycles", t.cycles);
    }
    let mut text = format!(
        "SIL: {} flights of {} ({}), {} failed, {} guidance faults, {:.2} % of the time in missed thrust\n\
         reward {:.4} +- {:.4} (zero thrust {:.4}); final mass {:.4}; |dr| p50/p95 {:.4}/{:.4} AU; |dv| p50/p95 {:.4}/{:.4}; {:.1} % within 0.01 AU / 0.01",
        report.flights,
        report.blob.display(),
        controller,
        report.failed.len(),
        report.guidance_faults,
        100.0 * report.missed_thrust_fraction,
        p.total_reward.mean,
        p.total_reward.std,
        report.monte_carlo.zero_thrust.total_reward.mean,
        p.final_mass.mean,
        p.terminal_position.p50,
        p.terminal_position.p95,
        p.terminal_velocity.p50,
        p.terminal_velocity.p95,
        100.0 * report.monte_carlo.within_accuracy_goal
    ) + &missed_thrust_line(&report.by_last_missed_thrust);
    // With the indirect solutions (ground model sil --gap-cases): the share where solved, by band.
    for band in &report.monte_carlo.accuracy_by_eccentricity {
        text += &format!("\n  {}", crate::eval::eccentricity_line(band));
    }
    for line in [solved_line(&report.monte_carlo), gap_line(&report.monte_carlo)]
        .into_iter()
        .flatten()
    {
        text += &format!("\n{line}");
    }
    text
}

/// "none 92.0 % (512), 0.9-1 80.6 % (314)": the bands that hold flights, for `ground model sil` and
/// the recipe's report; `None` when no flight met missed thrust.
pub fn missed_thrust_bands(bands: &[MissedThrustBand]) -> Option<String> {
    met_missed_thrust(bands).then(|| {
        let parts: Vec<String> = bands.iter().filter(|b| b.flights > 0).map(|b| b.to_string()).collect();
        parts.join(", ")
    })
}

/// "within the goal by where the last missed thrust ended ...: none 92.0 % (512), ..." (empty
/// without missed thrust).
fn missed_thrust_line(bands: &[MissedThrustBand]) -> String {
    missed_thrust_bands(bands).map_or_else(String::new, |bands| {
        format!("\nwithin the goal by where the last missed thrust ended (fraction of the flight): {bands}")
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use onboard::features::Residuals;

    fn flight(episode: usize, miss: f64) -> EpisodeOutcome {
        EpisodeOutcome {
            episode,
            total_reward: 0.0,
            final_mass: 0.9,
            terminal: Residuals {
                position: miss,
                velocity: miss,
            },
            steps: 40,
            completed: true,
            error: None,
            non_finite_actions: 0,
            trajectory: None,
        }
    }

    /// Each flight lands in the band of its last missed thrust (upper ends inclusive), and each
    /// band's share counts its own flights only.
    #[test]
    fn flights_are_grouped_by_where_their_last_missed_thrust_ended() {
        let missed = |last_end: Option<f64>| MissedThrust {
            time: if last_end.is_some() { 0.1 } else { 0.0 },
            last_end,
        };
        let cases = [
            (None, 0.001),
            (None, 0.02),
            (Some(0.3), 0.001),
            (Some(0.5), 0.001),
            (Some(0.85), 0.02),
            (Some(0.9), 0.001),
            (Some(0.95), 0.02),
            (Some(1.0), 0.02),
        ];
        let outcomes: Vec<_> = cases.iter().enumerate().map(|(i, c)| flight(i, c.1)).collect();
        let flights: Vec<_> = cases.iter().map(|c| missed(c.0)).collect();
        let bands = by_last_missed_thrust(&outcomes, &flights);
        let csv = missed_thrust_csv(&outcomes, &flights);
        let rows: Vec<&str> = csv.lines().collect();
        assert_eq!(rows.len(), cases.len() + 1);
        assert_eq!(rows[0], "episode,missed_thrust_time,last_missed_thrust_end");
        assert_eq!(rows[1], "0,0,");
        assert_eq!(rows[5], "4,0.1,0.85");
        let got: Vec<(&str, usize, f64)> = bands
            .iter()
            .map(|b| (b.band.as_str(), b.flights, b.within_goal))
            .collect();
        assert_eq!(
            got,
            vec![
                ("none", 2, 0.5),
                ("0-0.5", 2, 1.0),
                ("0.5-0.8", 0, 0.0),
                ("0.8-0.9", 2, 0.5),
                ("0.9-1", 2, 0.0),
            ]
        );
    }
}
