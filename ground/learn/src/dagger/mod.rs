//! The relabelling rounds, one submodule per part: [`relabel`] (a round's flights re-solved
//! into tuples, and their files), [`selection`] (which flights a round relabels, and the score
//! that picks the best round) and [`slurm`] (the relabels solved as a Slurm array). This
//! module is the round loop.
//!
//! `ground train dagger`: DAgger-style rounds of relabelled demonstrations (transfers and rendezvous).
//!
//! Each round flies the deterministic policy on fresh training scenarios, re-solves the
//! fuel-optimal rest of each flight by the indirect method from the states it visited
//! ([`ground_core::demo::relabel`]), adds those tuples to the demonstration buffer, and runs
//! behaviour-cloning-regularised updates on the grown buffer. The policy then learns what to do
//! in the states its own errors lead to, which demonstrations of optimal flights never show.
//! With `dagger.dispersed` the flights are the onboard controller's against the SIL's dispersed
//! plant, so the relabels also cover what navigation, thrust and missed-thrust errors lead to.
//!
//! ```text
//! RUN/dagger/round-0.safetensors   the starting learner (copied from --from)
//! RUN/dagger/relabels-R.ltrl       round R's relabelled tuples
//! RUN/dagger/round-R.safetensors   the learner after round R
//! RUN/dagger/best.safetensors      the round with the largest share within the goal
//! RUN/dagger/rounds.{csv,svg}      per-round scores, state.json the same for machines
//! ```
//!
//! A run may also start where another stopped, with another network (`--relabels-from`): the
//! other run's completed rounds' relabels are copied in as rounds 1..K, the start is saved as
//! round K as well, and the rounds go on from K + 1 on the same scenarios the other run's would.
//!
//! Every file is written atomically and is complete when it exists, so a run resumes from
//! them alone: the buffer is the demonstrations plus every round's relabels in order, each
//! round's sampler is seeded from the round number and the agent's noise from its update count. A run stopped anywhere
//! and resumed ends with the same weights as one that never stopped.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use crate::phase::{new_agent, write_rows, LogRow};
use crate::pretrain::demonstration_buffer;
use crate::run_folder::{check_run, prepare_run};
use crate::sac::agent::Sac;
use crate::sac::replay::sampler;
use crate::sil::SilGeometry;
use ground_core::charts::{line_chart, Series};
use ground_core::env::batch::OutcomeSummary;
use ground_core::env::{Geometry, Problem};

pub mod relabel;
pub mod selection;
pub mod slurm;

pub use relabel::{load_relabels, Relabels};
pub use slurm::relabel_shard;

use relabel::{relabels_file, save_relabels, solve_relabels};
use selection::score;

/// Round r flies training scenarios `r * ROUND_STRIDE ..`: past any the RL phase draws.
pub(crate) const ROUND_STRIDE: u64 = 1_000_000;
/// Mixed into the training seed for the rounds' replay samplers (apart from RL's streams).
const SAMPLER_STREAM: u64 = 0xDA66E5;
/// Mixed into the training seed for the dispersions of the flights a round relabels.
pub(crate) const DISPERSION_STREAM: u64 = 0xD15BE25E;

/// The score of the learner after a round (round 0: the starting checkpoint).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RoundRow {
    /// The round (0: the starting learner).
    pub round: u64,
    /// States sent to the solver in the round.
    pub relabels_attempted: u64,
    /// Of those, solved to the final eps.
    pub relabels_converged: u64,
    /// Tuples the round added to the buffer.
    pub tuples_added: u64,
    /// Transitions in the buffer after the round: demonstrations and every relabel so far.
    pub buffer: u64,
    /// Gradient updates of this command so far.
    pub updates: u64,
    /// Share of the completed scoring episodes within 0.01 AU and 0.01 (the accuracy goal's figure).
    pub within_goal: f64,
    /// The same share with the SIL's dispersions (`dagger.dispersed`): the round's score then.
    #[serde(default)]
    pub within_goal_dispersed: Option<f64>,
    /// Reward, final mass and terminal residuals of the nominal scoring episodes.
    pub summary: OutcomeSummary,
    /// Wall time of the round (relabels, updates, scoring).
    pub seconds: f64,
}

impl RoundRow {
    /// What picks the best round and meets `dagger.stop_at`: the share within the goal under
    /// dispersions when the round was scored under them, else the nominal one.
    pub fn score(&self) -> f64 {
        self.within_goal_dispersed.unwrap_or(self.within_goal)
    }
}

impl LogRow for RoundRow {
    const HEADER: &'static str = "round,relabels_attempted,relabels_converged,tuples_added,buffer,updates,\
within_goal,within_goal_dispersed,completed,reward_mean,final_mass_mean,dr_p50,dr_p95,dv_p50,dv_p95,seconds\n";

    fn csv(&self) -> String {
        let s = &self.summary;
        format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.1}\n",
            self.round,
            self.relabels_attempted,
            self.relabels_converged,
            self.tuples_added,
            self.buffer,
            self.updates,
            self.within_goal,
            self.within_goal_dispersed.map_or(String::new(), |d| d.to_string()),
            s.completed,
            s.total_reward.mean,
            s.final_mass.mean,
            s.terminal_position.p50,
            s.terminal_position.p95,
            s.terminal_velocity.p50,
            s.terminal_velocity.p95,
            self.seconds
        )
    }

    fn point(&self) -> (f64, OutcomeSummary) {
        (self.round as f64, self.summary)
    }
}

/// What `ground train dagger` ended with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DaggerSummary {
    /// The rounds' folder, `RUN/dagger`.
    pub folder: PathBuf,
    /// Round 0 (the start) and every round done.
    pub rows: Vec<RoundRow>,
    /// The round kept as best.safetensors.
    pub best_round: u64,
    /// Why the rounds ended where they did ([`stop_reason`], or the budget spent; empty when
    /// read back from the folder by [`read_rounds`]).
    #[serde(default)]
    pub stopped: String,
}

/// Why the rounds stop after `rows` rather than run another: the last round met `stop_at`, or
/// `patience` rounds in a row brought no new best score. A function of the recorded rounds, so a
/// resumed run stops where the uninterrupted one did.
pub fn stop_reason(rows: &[RoundRow], stop_at: Option<f64>, patience: Option<u64>) -> Option<String> {
    let last = rows.last()?;
    if let Some(goal) = stop_at.filter(|goal| last.score() >= *goal) {
        return Some(format!(
            "round {} scored {:.1} %, the goal {:.1} %",
            last.round,
            100.0 * last.score(),
            100.0 * goal
        ));
    }
    let best = best_row(rows)?;
    patience.filter(|p| last.round >= best.round + p).map(|p| {
        format!(
            "{p} rounds without a new best after round {} ({:.1} %): a plateau",
            best.round,
            100.0 * best.score()
        )
    })
}

fn round_file(dir: &Path, round: u64) -> PathBuf {
    dir.join(format!("round-{round}.safetensors"))
}

pub(crate) fn progress_bar(total: u64, what: &str) -> indicatif::ProgressBar {
    ground_core::progress::bar(
        total,
        &format!("{what:>16} {{bar:36}} {{pos}}/{{len}} {{msg}} [{{elapsed}}<{{eta}}]"),
    )
}

/// `ground train dagger`: `config.dagger.rounds` rounds from `start` (a learner checkpoint, e.g.
/// RUN/pretrain/best.safetensors, or an actor file, narrower ones widened) in RUN/dagger,
/// resuming whatever rounds are already there. With `relabels_from` (another run folder of the
/// same scenario, seeds, final eps and arrival margin) that run's completed rounds' relabels
/// become this run's first rounds, and its own rounds follow them from `start`.
pub fn dagger(
    config: &ExperimentConfig,
    config_dir: &Path,
    run: &Path,
    start: &Path,
    relabels_from: Option<&Path>,
) -> Result<DaggerSummary, ExperimentError> {
    if config.dagger.rounds == 0 {
        return Err(crate::config::ConfigError::Invalid("dagger.rounds is 0: no round to run".into()).into());
    }
    crate::with_flown_problem!(config, P => dagger_for::<P>(config, config_dir, run, start, relabels_from))
}

/// The relabels of another run's completed rounds (1, 2, ... while both a round's relabels and
/// its learner are there), refused unless they were solved for this config's problem.
fn completed_relabels(
    config: &ExperimentConfig,
    other: &Path,
    (obs_dim, act_dim): (usize, usize),
) -> Result<Vec<Relabels>, ExperimentError> {
    let path = other.join("config.toml");
    let text = std::fs::read_to_string(&path).map_err(|e| ExperimentError::Io(path.clone(), e))?;
    let theirs = ExperimentConfig::from_toml(&text)?;
    if theirs.relabel_problem() != config.relabel_problem() {
        return Err(ExperimentError::Mismatch(format!(
            "{} relabels another problem (scenario, seeds, final eps or arrival margin differ)",
            other.display()
        )));
    }
    let dir = other.join("dagger");
    let mut rounds = Vec::new();
    for round in 1.. {
        let path = relabels_file(&dir, round);
        if !path.exists() || !round_file(&dir, round).exists() {
            break;
        }
        rounds.push(load_relabels(&path, round, obs_dim, act_dim)?);
    }
    if rounds.is_empty() {
        return Err(ExperimentError::Mismatch(format!(
            "{} holds no completed round",
            dir.display()
        )));
    }
    Ok(rounds)
}

fn dagger_for<P: Problem>(
    config: &ExperimentConfig,
    config_dir: &Path,
    run: &Path,
    start: &Path,
    relabels_from: Option<&Path>,
) -> Result<DaggerSummary, ExperimentError>
where
    P::Geometry: SilGeometry,
{
    let sizes = (P::OBS, P::Geometry::ACT);
    let device = config.device()?;
    let (mut buffer, _) = demonstration_buffer::<P>(config, config_dir)?;
    check_run(config, run)?;
    let dir = run.join("dagger");
    let mut agent = new_agent(config, true, P::OBS, device);
    let state_path = dir.join("state.json");
    if !round_file(&dir, 0).exists() {
        // A learner checkpoint, or a shipped model's actor alone (its critics are fresh: train
        // it with dagger.cloning_only).
        if let Err(checkpoint) = agent.load(start) {
            agent = new_agent(config, true, P::OBS, device);
            let widths = agent.start_from_actor(start).map_err(|_| checkpoint)?;
            if widths != config.sac.hidden {
                println!(
                    "{}: hidden layers {widths:?} widened to {:?} (the same actor until trained)",
                    start.display(),
                    config.sac.hidden
                );
            }
        }
        let inherited = match relabels_from {
            Some(other) => completed_relabels(config, other, sizes)?,
            None => Vec::new(),
        };
        prepare_run(config, run)?;
        // The inherited rounds are this run's own: its folder alone resumes it.
        for relabels in &inherited {
            save_relabels(&relabels_file(&dir, relabels.round), relabels)?;
        }
        if let Some(last) = inherited.last() {
            agent.save(&round_file(&dir, last.round))?;
        }
        // Written last: the start is complete once round 0 is there.
        agent.save(&round_file(&dir, 0))?;
        // A state left by an earlier start belongs to another learner.
        let _ = std::fs::remove_file(&state_path);
    }
    // The learner counts its updates since its first; this command's start at round 0.
    agent.load(&round_file(&dir, 0))?;
    let updates_before = agent.updates;
    // The last round with its learner saved (inherited rounds have relabels alone).
    let mut done = 0;
    for round in 1.. {
        if !relabels_file(&dir, round).exists() {
            break;
        }
        if round_file(&dir, round).exists() {
            done = round;
        }
    }
    agent.load(&round_file(&dir, done))?;
    let mut rows: Vec<RoundRow> = match std::fs::read(&state_path) {
        Ok(bytes) => serde_json::from_slice(&bytes)
            .map_err(|e| ExperimentError::Mismatch(format!("{} does not parse: {e}", state_path.display())))?,
        Err(_) => Vec::new(),
    };
    rows.retain(|r| r.round <= done);
    let mut last_relabels = (0, 0, 0);
    for round in 1..=done {
        let relabels = load_relabels(&relabels_file(&dir, round), round, sizes.0, sizes.1)?;
        buffer.extend_from(&relabels.tuples);
        last_relabels = (relabels.attempted, relabels.converged, relabels.tuples.len() as u64);
    }
    let updates = |agent: &Sac| agent.updates - updates_before;
    if rows.last().is_none_or(|r| r.round != done) {
        // Stopped between a round's checkpoint and its score.
        let clock = Instant::now();
        let score = score::<P>(config, &agent)?;
        rows.push(RoundRow {
            round: done,
            relabels_attempted: last_relabels.0,
            relabels_converged: last_relabels.1,
            tuples_added: last_relabels.2,
            buffer: buffer.len() as u64,
            updates: updates(&agent),
            within_goal: score.within_goal,
            within_goal_dispersed: score.within_goal_dispersed,
            summary: score.summary,
            seconds: clock.elapsed().as_secs_f64(),
        });
        write_logs(&dir, &rows, &agent, is_best(&rows))?;
    }
    let stop = |rows: &[RoundRow]| stop_reason(rows, config.dagger.stop_at, config.dagger.patience);
    for round in done + 1..=config.dagger.rounds {
        if stop(&rows).is_some() {
            break;
        }
        let clock = Instant::now();
        let path = relabels_file(&dir, round);
        let relabels = if path.exists() {
            load_relabels(&path, round, sizes.0, sizes.1)?
        } else {
            let relabels = solve_relabels::<P>(config, &agent, round, &dir)?;
            save_relabels(&path, &relabels)?;
            relabels
        };
        buffer.extend_from(&relabels.tuples);
        // The sampler is seeded by the round and the agent's noise by its update count, so a
        // resumed round repeats exactly.
        let mut rng = sampler(config.seeds.train ^ SAMPLER_STREAM ^ round);
        let bar = progress_bar(config.dagger.updates, &format!("round {round} update"));
        for i in 0..config.dagger.updates {
            let batch = buffer.sample(config.sac.batch_size, &mut rng);
            if config.dagger.cloning_only {
                agent.cloning_update(&batch);
            } else {
                agent.update(&batch);
            }
            if i % 100 == 0 {
                bar.set_position(i);
            }
        }
        bar.finish_and_clear();
        agent.save(&round_file(&dir, round))?;
        let score = score::<P>(config, &agent)?;
        let (within_goal, summary) = (score.within_goal, score.summary);
        rows.push(RoundRow {
            round,
            relabels_attempted: relabels.attempted,
            relabels_converged: relabels.converged,
            tuples_added: relabels.tuples.len() as u64,
            buffer: buffer.len() as u64,
            updates: updates(&agent),
            within_goal,
            within_goal_dispersed: score.within_goal_dispersed,
            summary,
            seconds: clock.elapsed().as_secs_f64(),
        });
        // Time left: this command's mean round so far times the rounds left of the budget (an
        // upper bound when a goal may stop the rounds early).
        let timed: Vec<f64> = rows.iter().skip(1).map(|r| r.seconds).collect();
        let left = (config.dagger.rounds - round) as f64 * timed.iter().sum::<f64>() / timed.len().max(1) as f64;
        println!(
            "round {round} of {}: {} of {} relabels converged, {} tuples; within 0.01 AU and 0.01: {:.1} %{} \
             (dr p50 {:.4} AU, p95 {:.4}; dv p50 {:.4}, p95 {:.4}) [{:.0} s; at most {:.0} min left]",
            config.dagger.rounds,
            relabels.converged,
            relabels.attempted,
            relabels.tuples.len(),
            100.0 * within_goal,
            score.within_goal_dispersed.map_or(String::new(), |d| format!(
                ", {:.1} % with the SIL's dispersions",
                100.0 * d
            )),
            summary.terminal_position.p50,
            summary.terminal_position.p95,
            summary.terminal_velocity.p50,
            summary.terminal_velocity.p95,
            clock.elapsed().as_secs_f64(),
            left / 60.0
        );
        write_logs(&dir, &rows, &agent, is_best(&rows))?;
    }
    let best_round = best_row(&rows).map_or(0, |r| r.round);
    let stopped = stop(&rows).unwrap_or_else(|| format!("the budget of {} rounds spent", config.dagger.rounds));
    if let Some(reason) = stop(&rows) {
        println!("rounds stopped: {reason}");
    }
    Ok(DaggerSummary {
        folder: dir,
        rows,
        best_round,
        stopped,
    })
}

/// The rounds recorded in a relabelling folder (`RUN/dagger/state.json`) and the best of them.
pub fn read_rounds(dir: &Path) -> Result<DaggerSummary, ExperimentError> {
    let path = dir.join("state.json");
    let bytes = std::fs::read(&path).map_err(|e| ExperimentError::Io(path.clone(), e))?;
    let rows: Vec<RoundRow> = serde_json::from_slice(&bytes)
        .map_err(|e| ExperimentError::Mismatch(format!("{} does not parse: {e}", path.display())))?;
    let best_round = best_row(&rows)
        .map(|r| r.round)
        .ok_or_else(|| ExperimentError::Mismatch(format!("{} records no round", path.display())))?;
    Ok(DaggerSummary {
        folder: dir.to_path_buf(),
        rows,
        best_round,
        stopped: String::new(),
    })
}

/// The row with the largest share within the goal (the earliest of equals).
fn best_row(rows: &[RoundRow]) -> Option<&RoundRow> {
    rows.iter().rev().max_by(|a, b| a.score().total_cmp(&b.score()))
}

/// Is the last row the best so far?
fn is_best(rows: &[RoundRow]) -> bool {
    match (rows.last(), best_row(rows)) {
        (Some(last), Some(best)) => last.round == best.round,
        _ => false,
    }
}

/// state.json, rounds.csv and rounds.svg, and best.safetensors when `agent` is the best.
fn write_logs(dir: &Path, rows: &[RoundRow], agent: &Sac, best: bool) -> Result<(), ExperimentError> {
    if best {
        agent.save(&dir.join("best.safetensors"))?;
    }
    write_rows(
        dir,
        "rounds",
        rows,
        "DAgger-style rounds: terminal residuals (scoring episodes)",
        "round",
    )?;
    let series = |name: &str, f: &dyn Fn(&RoundRow) -> f64| Series {
        name: name.into(),
        points: rows.iter().map(|r| (r.round as f64, f(r))).collect(),
        band: None,
    };
    // A chart that cannot be drawn yet (one point) is skipped: the CSV holds the numbers.
    let _ = line_chart(
        &dir.join("rounds.svg"),
        "DAgger-style rounds: scoring episodes within 0.01 AU and 0.01",
        "round",
        "share",
        &if rows.iter().any(|r| r.within_goal_dispersed.is_some()) {
            vec![
                series("within the goal", &|r| r.within_goal),
                series("with the SIL's dispersions", &|r| {
                    r.within_goal_dispersed.unwrap_or(f64::NAN)
                }),
            ]
        } else {
            vec![series("within the goal", &|r| r.within_goal)]
        },
        false,
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rounds 0.. scoring `scores`.
    fn rounds(scores: &[f64]) -> Vec<RoundRow> {
        let summary = ground_core::env::batch::summarize::<ground_core::env::Planar>(&[]);
        scores
            .iter()
            .enumerate()
            .map(|(round, &within_goal)| RoundRow {
                round: round as u64,
                relabels_attempted: 0,
                relabels_converged: 0,
                tuples_added: 0,
                buffer: 0,
                updates: 0,
                within_goal,
                within_goal_dispersed: None,
                summary,
                seconds: 0.0,
            })
            .collect()
    }

    #[test]
    fn the_rounds_stop_at_the_goal_or_after_patience_rounds_without_a_new_best() {
        let climbing = rounds(&[0.2, 0.5, 0.7, 0.9]);
        assert_eq!(stop_reason(&climbing, None, Some(1)), None);
        assert_eq!(stop_reason(&climbing, Some(0.95), Some(2)), None);
        let met = stop_reason(&climbing, Some(0.9), None).unwrap();
        assert!(met.starts_with("round 3 scored 90.0 %"), "{met}");
        // Best at round 2; rounds 3 and 4 bring nothing better (an equal score is no new best).
        let plateau = rounds(&[0.2, 0.5, 0.8, 0.79, 0.8]);
        assert_eq!(stop_reason(&plateau, None, Some(3)), None);
        let stopped = stop_reason(&plateau, None, Some(2)).unwrap();
        assert!(
            stopped.starts_with("2 rounds without a new best after round 2 (80.0 %)"),
            "{stopped}"
        );
        assert_eq!(stop_reason(&plateau, None, None), None);
        assert_eq!(stop_reason(&[], Some(0.5), Some(1)), None);
    }
}
