//! A recipe's time on this machine, projected before it runs (`ground run --plan`): its family
//! checked on a sample of draws (`ground_core::mission::check_family`), the unit costs measured
//! here (a draw's solve, a SAC update, a cloning-only update, a flown episode, an RL step), and
//! each stage's count of them from the config, its `[[stage]]` sections included. Nothing is
//! written.

use std::time::Instant;

use serde::Serialize;

use crate::config::{DaggerConfig, ExperimentConfig};
use crate::error::ExperimentError;
use crate::finetune::{action_gradients, Objective, Plant};
use crate::phase::{evaluate_agent, new_agent};
use crate::sac::bench::seconds_per_update_of;
use ground_core::demo::DemoGeometry;
use ground_core::env::{Geometry, MdpEnv, Problem};
use ground_core::mission::{check_family, FamilyCheck};

/// Episodes flown to time one (lockstep, as the evaluations fly them).
const TIMED_EPISODES: u64 = 32;
/// SAC updates timed (after the bench's warm-up).
const TIMED_UPDATES: usize = 50;
/// Flights of the timed fine-tuning step.
const TIMED_FINETUNE_FLIGHTS: u64 = 4;
/// What the RL phase spends per environment step besides its updates (the action, the
/// propagation, replay pushes, statistics, checkpoints and its evaluations), in updates: 0.57 and
/// 0.51 on the recorded RL phases of the venus-inward and mars-fixed-time recipes (5.1 and 4.6 ms
/// a step at 8.9 and 9.1 ms a pretraining update, 60,000 steps each, run side by side on a 2-vCPU
/// Intel Xeon guest).
pub const RL_STEP_UPDATES: f64 = 0.55;

/// What one unit of each kind of work costs on this machine.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct UnitCosts {
    /// A draw's indirect solve, mean over the sample, s (one thread).
    pub solve_s: f64,
    /// One pretraining update at the config's sizes, s (the config's torch threads).
    pub pretrain_update_s: f64,
    /// One RL (and relabelling round) update, s.
    pub update_s: f64,
    /// One update of the actor alone on its cloning error (`cloning_only` rounds), s.
    pub cloning_update_s: f64,
    /// One deterministic episode, flown in lockstep with others as evaluations fly them, s.
    pub episode_s: f64,
    /// One flight of a fine-tuning step (flown, linearised, back-propagated), s.
    pub finetune_flight_s: f64,
    /// The same against the SIL's dispersed plant, when a fine-tuning phase flies it, s.
    pub finetune_dispersed_flight_s: Option<f64>,
    /// One RL environment step apart from its updates, its share of the phase's evaluations
    /// included, s (0.55 updates, as measured on two recorded recipes).
    pub env_step_s: f64,
    /// Threads the solves run on.
    pub solver_threads: usize,
}

/// One stage's projected time.
#[derive(Debug, Clone, Serialize)]
pub struct StageTime {
    /// The stage, as `ground run` names it.
    pub stage: String,
    /// Projected wall time, s.
    pub seconds: f64,
    /// What it counts.
    pub counts: String,
}

/// A recipe's projection.
#[derive(Debug, Clone, Serialize)]
pub struct RecipePlan {
    /// The family's check on the sample.
    pub check: FamilyCheck,
    /// The measured unit costs.
    pub costs: UnitCosts,
    /// Every stage, in order (the relabelling rounds at their whole budget).
    pub stages: Vec<StageTime>,
    /// One relabelling round, s (0 without rounds).
    pub round_seconds: f64,
    /// The rounds' budget (`[dagger] rounds`; `stop_at` may end them sooner).
    pub rounds: u64,
    /// The whole recipe with one round in each stage that runs rounds, s: the shortest it can be.
    pub total_one_round_seconds: f64,
    /// The whole recipe with every round of the budget, s.
    pub total_seconds: f64,
}

/// Checks the config's family on `sample` draws, measures the unit costs here, and projects
/// each stage of the recipe.
pub fn plan_recipe(config: &ExperimentConfig, sample: u64) -> Result<RecipePlan, ExperimentError> {
    if sample == 0 {
        return Err(ExperimentError::Mismatch(
            "the plan needs a sample of at least 1 draw".into(),
        ));
    }
    let spacecraft = config
        .env
        .canonical_spacecraft()
        .map_err(|e| ExperimentError::Mismatch(format!("spacecraft: {e}")))?;
    let options = config.generate.solve_options();
    let check = check_family(&config.family, &spacecraft, sample, config.generate.seed, &options);
    let costs = crate::with_flown_problem!(config, P => measure::<P>(config, &check))?;
    let staged = config.staged()?;
    Ok(project(config, &staged, check, costs))
}

fn measure<P: Problem>(config: &ExperimentConfig, check: &FamilyCheck) -> Result<UnitCosts, ExperimentError>
where
    P::Geometry: DemoGeometry + firmware_sim::FlightGeometry,
{
    let obs = P::OBS;
    let device = config.device()?;
    // RL's learner flies the timed episodes (untrained: an episode costs what a trained one
    // does), then is timed updating.
    let mut learner = new_agent(config, false, obs, device);
    let start = Instant::now();
    evaluate_agent::<MdpEnv<P>>(
        &learner,
        &config.env,
        crate::phase::family_of::<P::Geometry>(config)?,
        config.seeds.train,
        TIMED_EPISODES,
        false,
    )
    .map_err(|e| ExperimentError::Mismatch(format!("timing episodes: {e}")))?;
    let episode_s = start.elapsed().as_secs_f64() / TIMED_EPISODES as f64;
    // Each phase's learner: pretraining's on demonstrations alone, RL's with half its rows
    // demonstrations when it keeps its cloning term.
    let mut pretraining = new_agent(config, true, obs, device);
    let pretrain_update_s = seconds_per_update_of(&mut pretraining, obs, P::Geometry::ACT, 1, TIMED_UPDATES, false);
    let demonstration_every = if config.train.keep_behaviour_cloning { 2 } else { 0 };
    let update_s = seconds_per_update_of(
        &mut learner,
        obs,
        P::Geometry::ACT,
        demonstration_every,
        TIMED_UPDATES,
        false,
    );
    let cloning_update_s = seconds_per_update_of(&mut learner, obs, P::Geometry::ACT, 2, TIMED_UPDATES, true);
    let family = crate::phase::family_of::<P::Geometry>(config)?;
    let flights: Vec<_> = (0..TIMED_FINETUNE_FLIGHTS)
        .map(|i| P::Geometry::draw(&family, config.seeds.train, i))
        .collect();
    let objective = Objective::of(config);
    let flight_s = |plant: Plant| {
        let start = Instant::now();
        action_gradients::<P>(config, &learner, &flights, plant, &objective)?;
        Ok::<_, ExperimentError>(start.elapsed().as_secs_f64() / TIMED_FINETUNE_FLIGHTS as f64)
    };
    let finetune_flight_s = flight_s(Plant::Nominal)?;
    let finetune_dispersed_flight_s = if config.finetune.phases().any(|phase| phase.dispersed) {
        Some(flight_s(Plant::Dispersed {
            seed: config.seeds.train,
        })?)
    } else {
        None
    };
    Ok(UnitCosts {
        solve_s: check.solve_seconds[0],
        pretrain_update_s,
        update_s,
        cloning_update_s,
        episode_s,
        finetune_flight_s,
        finetune_dispersed_flight_s,
        env_step_s: RL_STEP_UPDATES * update_s,
        solver_threads: rayon::current_num_threads(),
    })
}

impl UnitCosts {
    /// `n` solves spread over the solver threads, s.
    fn solves_s(&self, n: f64) -> f64 {
        n * self.solve_s / self.solver_threads.max(1) as f64
    }
}

/// What one relabelling round of `dagger` does: its updates, the episodes it flies and the
/// relabels it solves.
struct RoundWork {
    updates: u64,
    /// Candidates, then the scoring episodes, flown again against the SIL's dispersed plant when
    /// the round scores under dispersions.
    flown: u64,
    relabels: u64,
}

impl RoundWork {
    fn of(dagger: &DaggerConfig) -> Self {
        let scoring = dagger.score_episodes * if dagger.dispersed { 2 } else { 1 };
        Self {
            updates: dagger.updates,
            flown: dagger.candidates.unwrap_or(dagger.episodes) + scoring,
            relabels: dagger.episodes * dagger.fractions.len() as u64,
        }
    }
}

/// One relabelling round of `dagger` at these costs, s.
fn round_seconds(dagger: &DaggerConfig, c: &UnitCosts) -> f64 {
    let work = RoundWork::of(dagger);
    // A relabel solves from a flown state with the rest of the flight to go: counted as that
    // share of a draw's solve (its warm start makes it cheaper still: an upper bound).
    let left = if dagger.fractions.is_empty() {
        0.0
    } else {
        1.0 - dagger.fractions.iter().sum::<f64>() / dagger.fractions.len() as f64
    };
    let update_s = if dagger.cloning_only {
        c.cloning_update_s
    } else {
        c.update_s
    };
    work.updates as f64 * update_s + work.flown as f64 * c.episode_s + c.solves_s(work.relabels as f64 * left)
}

/// What a round of `dagger` counts, as the plan prints it.
fn round_counts(dagger: &DaggerConfig) -> String {
    let work = RoundWork::of(dagger);
    format!(
        "{} rounds at most, each {} {}updates, {} relabels, {} episodes flown{}",
        dagger.rounds,
        work.updates,
        if dagger.cloning_only { "cloning-only " } else { "" },
        work.relabels,
        work.flown,
        if dagger.dispersed {
            " (the scoring twice: nominal and dispersed)"
        } else {
            ""
        }
    )
}

/// Each stage's count of unit costs: the recipe's own stages, then each of `staged` (the
/// `[[stage]]` sections' configs, [`ExperimentConfig::staged`]) with its demonstrations where
/// it changes `[generate]` and its rounds (the rounds whose relabels it inherits from the
/// stage before are loaded, not run).
fn project(config: &ExperimentConfig, staged: &[ExperimentConfig], check: FamilyCheck, costs: UnitCosts) -> RecipePlan {
    let c = &costs;
    let mut stages = Vec::new();
    let mut stage = |name: &str, seconds: f64, counts: String| {
        stages.push(StageTime {
            stage: name.into(),
            seconds,
            counts,
        })
    };
    let generate = &config.generate;
    stage(
        "dataset",
        c.solves_s(generate.count as f64),
        format!("{} solves on {} threads", generate.count, c.solver_threads),
    );
    let train = &config.train;
    // One evaluation before the first update, then one every `every`.
    let evals = |steps: u64, every: u64| 1 + steps.checked_div(every).unwrap_or(0);
    let pretrain = &config.pretrain;
    let pretrain_evals = evals(pretrain.updates, pretrain.eval_every);
    stage(
        "pretraining",
        pretrain.updates as f64 * c.pretrain_update_s + (pretrain_evals * train.eval_episodes) as f64 * c.episode_s,
        format!(
            "{} updates, {pretrain_evals} evaluations of {} episodes",
            pretrain.updates, train.eval_episodes
        ),
    );
    let updating = train.env_steps.saturating_sub(config.sac.warmup_steps) * u64::from(config.sac.updates_per_step);
    let train_evals = evals(train.env_steps, train.eval_every);
    stage(
        "RL",
        train.env_steps as f64 * c.env_step_s + updating as f64 * c.update_s,
        format!(
            "{} environment steps, {updating} updates, {train_evals} evaluations of {} episodes",
            train.env_steps, train.eval_episodes
        ),
    );
    let dagger = &config.dagger;
    let round = if dagger.rounds == 0 {
        0.0
    } else {
        round_seconds(dagger, c)
    };
    stage("relabelling", round * dagger.rounds as f64, round_counts(dagger));
    // The shortest the rounds can be: one round a stage (`stop_at` may end each after it).
    let mut rounds_beyond_one = round * dagger.rounds.saturating_sub(1) as f64;
    let mut before = config;
    for (section, staged) in config.stages.iter().zip(staged) {
        if staged.generate != before.generate {
            stage(
                &format!("{}: dataset", section.name),
                c.solves_s(staged.generate.count as f64),
                format!("{} solves on {} threads", staged.generate.count, c.solver_threads),
            );
        }
        let d = &staged.dagger;
        let inherited = if section.inherit_relabels {
            before.dagger.rounds
        } else {
            0
        };
        let own = d.rounds.saturating_sub(inherited);
        let each = round_seconds(d, c);
        let counts = if inherited > 0 {
            format!(
                "{}; rounds 1-{inherited} the stage before's relabels, loaded",
                round_counts(d)
            )
        } else {
            round_counts(d)
        };
        stage(&format!("{}: rounds", section.name), each * own as f64, counts);
        rounds_beyond_one += each * own.saturating_sub(1) as f64;
        before = staged;
    }
    for (i, fine) in before.finetune.phases().enumerate().filter(|(_, f)| f.steps > 0) {
        let evaluations = fine.steps / fine.eval_every + 1;
        let flight_s = match (fine.dispersed, c.finetune_dispersed_flight_s) {
            (true, Some(dispersed)) => dispersed,
            _ => c.finetune_flight_s,
        };
        stage(
            if i == 0 { "fine-tuning" } else { "fine-tuning, then" },
            (fine.steps * fine.flights) as f64 * flight_s + (evaluations * fine.eval_episodes) as f64 * c.episode_s,
            format!(
                "{} steps of {}{} flights, {evaluations} evaluations of {} episodes",
                fine.steps,
                fine.flights,
                if fine.dispersed { " dispersed" } else { "" },
                fine.eval_episodes
            ),
        );
    }
    let evaluate = &config.evaluate;
    stage(
        "Monte Carlo",
        evaluate.episodes as f64 * c.episode_s + c.solves_s(evaluate.optimality_gap_cases as f64),
        format!(
            "{} episodes, {} solves for the optimality gap",
            evaluate.episodes, evaluate.optimality_gap_cases
        ),
    );
    // Each blob's closed-loop Monte Carlo at export, then its SIL flights.
    stage(
        "export and SIL",
        (2 * (evaluate.episodes + config.sil.episodes)) as f64 * c.episode_s,
        format!(
            "2 blobs x ({} episodes + {} SIL flights; onboard aids not counted)",
            evaluate.episodes, config.sil.episodes
        ),
    );
    let total_seconds: f64 = stages.iter().map(|s| s.seconds).sum();
    RecipePlan {
        check,
        costs,
        stages,
        round_seconds: round,
        rounds: dagger.rounds,
        total_one_round_seconds: total_seconds - rounds_beyond_one,
        total_seconds,
    }
}

/// The plan as the lines `ground run --plan` prints.
pub fn plan_lines(plan: &RecipePlan) -> Vec<String> {
    let c = &plan.costs;
    let mut lines = vec![format!(
        "measured here: a solve {:.3} s (one thread, {} solver threads), an update {:.2} ms (pretraining {:.2} ms, cloning only {:.2} ms), an episode {:.1} ms, an RL step {:.2} ms besides its updates, a fine-tuning flight {:.0} ms",
        c.solve_s,
        c.solver_threads,
        c.update_s * 1e3,
        c.pretrain_update_s * 1e3,
        c.cloning_update_s * 1e3,
        c.episode_s * 1e3,
        c.env_step_s * 1e3,
        c.finetune_flight_s * 1e3
    )];
    for s in &plan.stages {
        lines.push(format!("{:<28} {:>7.1} min  ({})", s.stage, s.seconds / 60.0, s.counts));
    }
    if plan.rounds > 0 {
        lines.push(format!(
            "one relabelling round {:.1} min; the recipe {:.0} min with one round a stage, {:.0} min with every round of the budgets",
            plan.round_seconds / 60.0,
            plan.total_one_round_seconds / 60.0,
            plan.total_seconds / 60.0,
        ));
    } else {
        lines.push(format!("the recipe {:.0} min", plan.total_seconds / 60.0));
    }
    lines
}
