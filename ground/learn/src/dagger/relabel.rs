//! A round's relabels: the flights of the learner re-solved by the indirect method from the
//! states they visited, turned into tuples, and saved as `RUN/dagger/relabels-R.ltrl`.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::selection::{largest_misses, ranked_by_miss, relabel_candidates, walk_probes};
use super::slurm::solve_on_slurm;
use super::{progress_bar, DISPERSION_STREAM, ROUND_STRIDE};
use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use crate::phase::family_of;
use crate::phase::policy_batch;
use crate::run_folder::write_file;
use crate::sac::agent::Sac;
use crate::sac::replay::{ReplayBuffer, Transition};
use crate::sil::{SilFlights, SilGeometry};
use ground_core::demo::DemoGeometry;
use ground_core::env::batch::evaluate_batched;
use ground_core::env::{Dimension, Geometry, MdpEnv, Problem, ScenarioOf};
use ground_core::io::{decode_container, encode_container};

const RELABELS_MAGIC: [u8; 4] = *b"LTRL";
// The buffer says its action size (3 planar, 4 in three dimensions): the format is unchanged.
const RELABELS_VERSION: u16 = 1;

/// One round's relabelled tuples, as saved in `relabels-R.ltrl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Relabels {
    /// The round these tuples were solved in (from 1).
    pub round: u64,
    /// States sent to the solver.
    pub attempted: u64,
    /// Of those, solved to the final eps and turned into tuples.
    pub converged: u64,
    /// The tuples, flagged as demonstrations.
    pub tuples: ReplayBuffer,
}

/// One relabelled tuple as it enters the buffer (what a Slurm task sends back).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RelabelTuple {
    obs: Vec<f32>,
    action: Vec<f32>,
    reward: f32,
    next_obs: Vec<f32>,
    done: bool,
}

/// The tuples of one relabel's re-solved flight, `None` where it did not converge.
pub(crate) type Solved = Option<Vec<RelabelTuple>>;

/// One relabel: the rest of training scenario `first + episode`'s flight from `state` at step
/// `step`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RelabelJob {
    /// The flight, counted from the round's first training scenario.
    pub episode: u64,
    /// The step of the flight whose state the rest is solved from.
    pub step: u32,
    /// The true state there ([`DemoGeometry::state_numbers`]): x, y, vx, vy, m in the plane;
    /// x, y, z, vx, vy, vz, m in three dimensions (AU, AU/t*, fraction of m0).
    pub state: Vec<f64>,
}

/// Solves one relabel, as [`DemoGeometry::relabel_tuples`] makes it (a state of another
/// dimension: not solved).
pub(crate) fn solve_job<P: Problem>(config: &ExperimentConfig, first: u64, job: &RelabelJob) -> Solved
where
    P::Geometry: DemoGeometry,
{
    let family = family_of::<P::Geometry>(config).ok()?;
    let state = P::Geometry::state_from_numbers(&job.state)?;
    let sc = config.env.canonical_spacecraft().ok()?;
    // Smoothed relabels among smoothed demonstrations: bang-bang ones mixed in drop the policy
    // to 10.9 % within the goal (docs/history/learning.md).
    let options = ground_core::solver::SolveOptions {
        fallbacks: config.dagger.fallbacks,
        ..config.generate.solve_options()
    };
    let transitions = P::Geometry::relabel_tuples::<P>(
        &family,
        (config.seeds.train, first + job.episode),
        &state,
        job.step,
        &sc,
        &options,
        &config.env,
    )?;
    Some(
        transitions
            .iter()
            .map(|t| RelabelTuple {
                obs: t.observation.as_ref().to_vec(),
                action: t.action.as_ref().to_vec(),
                reward: t.reward as f32,
                next_obs: t.next_observation.as_ref().to_vec(),
                done: t.done,
            })
            .collect(),
    )
}

pub(crate) fn relabels_file(dir: &Path, round: u64) -> PathBuf {
    dir.join(format!("relabels-{round}.ltrl"))
}

/// Reads a round's relabels, refusing a corrupt file or one of another round or problem (its
/// observation and action sizes).
pub fn load_relabels(path: &Path, round: u64, obs_dim: usize, act_dim: usize) -> Result<Relabels, ExperimentError> {
    let bytes = std::fs::read(path).map_err(|e| ExperimentError::Io(path.to_path_buf(), e))?;
    let relabels: Relabels = decode_container(RELABELS_MAGIC, RELABELS_VERSION, &bytes)
        .map_err(|e| ExperimentError::Mismatch(format!("relabels {}: {e}", path.display())))?;
    if relabels.round != round || relabels.tuples.obs_dim() != obs_dim || relabels.tuples.act_dim() != act_dim {
        return Err(ExperimentError::Mismatch(format!(
            "relabels {} hold round {} with {}-feature observations and {}-component actions, expected round \
             {round} with {obs_dim} and {act_dim}",
            path.display(),
            relabels.round,
            relabels.tuples.obs_dim(),
            relabels.tuples.act_dim()
        )));
    }
    Ok(relabels)
}

pub(crate) fn save_relabels(path: &Path, relabels: &Relabels) -> Result<(), ExperimentError> {
    let bytes = encode_container(RELABELS_MAGIC, RELABELS_VERSION, relabels)
        .map_err(|e| ExperimentError::Io(path.to_path_buf(), std::io::Error::other(e.to_string())))?;
    write_file(path, &bytes)
}

/// Flies the policy on round `round`'s training scenarios and relabels the visited states at
/// the config's fractions of each flight, solved to the demonstrations' eps.
pub(crate) fn solve_relabels<P: Problem>(
    config: &ExperimentConfig,
    agent: &Sac,
    round: u64,
    dagger_dir: &Path,
) -> Result<Relabels, ExperimentError>
where
    P::Geometry: SilGeometry,
{
    let dagger = &config.dagger;
    let first = ROUND_STRIDE * round;
    let candidates = dagger.candidates.unwrap_or(dagger.episodes);
    let family = family_of::<P::Geometry>(config)?;
    let scenarios: Vec<ScenarioOf<P::Geometry>> = (first..first + candidates)
        .map(|i| P::Geometry::draw(&family, config.seeds.train, i))
        .collect();
    let flown = if dagger.dispersed {
        // The onboard controller's flights (the f32 blob of this actor) in the dispersed plant:
        // the trajectory holds the true states, which the relabels start from.
        let seed = (config.seeds.train ^ DISPERSION_STREAM).wrapping_add(first);
        // The learner's own flights: the network alone, every trajectory kept.
        let flights = SilFlights {
            record: scenarios.len(),
            ..SilFlights::network_alone(&config.sil.dispersions, seed)
        };
        P::Geometry::fly_learner(config, agent, &scenarios, &flights)?
    } else {
        evaluate_batched::<MdpEnv<P>, _>(&config.env, &scenarios, |o| policy_batch(agent, o), true)?
    };
    let eligible = relabel_candidates(&flown, &scenarios, dagger.max_miss);
    let step_at = |episode: usize, fraction: f64| {
        let steps = P::Geometry::plan(&scenarios[episode]).steps;
        ((fraction * f64::from(steps)).round() as u32).clamp(1, steps - 1)
    };
    let wanted = dagger.episodes as usize;
    let bar = progress_bar(
        (wanted * dagger.fractions.len()) as u64,
        &format!("round {round} relabel"),
    );
    let mut batches = 0u64;
    // The rest of each (episode, step)'s flight re-solved from its state there, in order: here
    // on every core, or as a Slurm array (the same results).
    let mut solve_batch = |pairs: &[(usize, u32)]| -> Result<Vec<Solved>, ExperimentError> {
        let jobs: Vec<Option<RelabelJob>> = pairs
            .iter()
            .map(|&(episode, step)| {
                let point = flown[episode].trajectory.as_ref()?.get(step as usize)?;
                Some(RelabelJob {
                    episode: episode as u64,
                    step,
                    state: P::Geometry::state_numbers(&point.state),
                })
            })
            .collect();
        let solved = match &config.compute.slurm {
            None => jobs
                .par_iter()
                .map(|job| {
                    bar.inc(1);
                    job.as_ref().and_then(|job| solve_job::<P>(config, first, job))
                })
                .collect(),
            Some(slurm) => {
                batches += 1;
                let present: Vec<RelabelJob> = jobs.iter().flatten().cloned().collect();
                let tag = format!("{round}-{batches}");
                let mut results = solve_on_slurm(config, slurm, dagger_dir, &tag, first, present)?.into_iter();
                bar.inc(jobs.len() as u64);
                jobs.iter()
                    .map(|job| job.as_ref().and_then(|_| results.next().flatten()))
                    .collect()
            }
        };
        Ok(solved)
    };
    let (solved, attempted): (Vec<Vec<RelabelTuple>>, usize) = if dagger.solvable_only && !dagger.fractions.is_empty() {
        // The earliest fraction probes each flight, largest miss first, until enough re-solve;
        // the other fractions are solved for those alone.
        let mut fractions = dagger.fractions.clone();
        fractions.sort_by(f64::total_cmp);
        let ranked: Vec<usize> = ranked_by_miss(eligible).iter().map(|o| o.episode).collect();
        let (kept, probed) = walk_probes(&ranked, wanted, |episodes| {
            let pairs: Vec<(usize, u32)> = episodes.iter().map(|&e| (e, step_at(e, fractions[0]))).collect();
            let found = solve_batch(&pairs)?;
            bar.inc_length(found.iter().filter(|f| f.is_none()).count() as u64);
            Ok::<_, ExperimentError>(found)
        })?;
        let rest: Vec<(usize, u32)> = kept
            .iter()
            .flat_map(|(episode, _)| fractions[1..].iter().map(move |&f| (*episode, step_at(*episode, f))))
            .collect();
        let more = solve_batch(&rest)?.into_iter().flatten();
        let solved = kept.into_iter().map(|(_, demo)| demo).chain(more).collect();
        (solved, probed + rest.len())
    } else {
        let jobs: Vec<(usize, u32)> = largest_misses(eligible, wanted)
            .into_iter()
            .flat_map(|o| {
                dagger
                    .fractions
                    .iter()
                    .map(move |&f| (o.episode, step_at(o.episode, f)))
            })
            .collect();
        (solve_batch(&jobs)?.into_iter().flatten().collect(), jobs.len())
    };
    bar.finish_and_clear();
    let count: usize = solved.iter().map(Vec::len).sum();
    let mut tuples = ReplayBuffer::new(P::OBS, P::Geometry::ACT, count.max(1));
    for t in solved.iter().flatten() {
        tuples.push(&Transition {
            obs: &t.obs,
            action: &t.action,
            reward: t.reward,
            next_obs: &t.next_obs,
            done: t.done,
            demonstration: true,
        });
    }
    Ok(Relabels {
        round,
        attempted: attempted as u64,
        converged: solved.len() as u64,
        tuples,
    })
}
