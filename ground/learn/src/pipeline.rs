//! The main job and the recipes (`ground run`), top to bottom: demonstrations by the indirect
//! method, pretraining, RL from the pretrained model, relabelling rounds (when the config's
//! `[dagger]` has rounds), the recipe's stages (`[[stage]]`: more rounds under changed
//! settings), fine-tuning through the dynamics (when the config's `[finetune]` has steps),
//! Monte Carlo evaluation, then the ship stage (onboard blobs flown in
//! the software-in-the-loop against a dispersed plant, the model folder) and the report. All in
//! one run folder; each stage resumes exactly from what an interrupted run left.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::config::ExperimentConfig;
use crate::dagger::{dagger, DaggerSummary};
use crate::dataset::demonstrations;
use crate::error::ExperimentError;
use crate::eval::{monte_carlo, MonteCarloReport, Optima};
use crate::export::ExportReport;
use crate::finetune::{finetune, FinetuneSummary};
use crate::model::{current_commit, ModelCard};
use crate::phase::PhaseSummary;
use crate::pretrain::pretrain;
use crate::report::report_markdown;
use crate::rl::{train, Start};
use crate::ship::{export_and_ship, Lineage};
use crate::sil::SilReport;
use crate::stages::{run_stage, StageInput, StageSummary};
use ground_core::generate::{CrossCheckSummary, Summary};
use ground_core::io::atomic_write;

/// What the main job produced.
#[derive(Debug, Clone)]
pub struct MainJob {
    /// The run's Markdown report, `RUN/report.md`.
    pub report: PathBuf,
    /// The demonstration dataset's summary (`RUN/dataset`).
    pub dataset: Summary,
    /// The dataset's check against the direct transcription and its repairs
    /// (`generate.crosscheck`).
    pub crosscheck: Option<CrossCheckSummary>,
    /// The pretraining phase (`RUN/pretrain`).
    pub pretrain: PhaseSummary,
    /// RL from the pretrained model (`RUN/train-pretrained`).
    pub train: PhaseSummary,
    /// The relabelling rounds, when the config has any.
    pub dagger: Option<DaggerSummary>,
    /// The recipe's stages after them, in order (`RUN/stages/NAME`).
    pub stages: Vec<StageSummary>,
    /// Fine-tuning through the dynamics of the last stage's best, one summary per phase
    /// (`RUN/finetune`, then `RUN/finetune/then`, ...); empty when the config has no steps.
    pub finetune: Vec<FinetuneSummary>,
    /// The Monte Carlo of the best model (`RUN/mc`).
    pub monte_carlo: MonteCarloReport,
    /// The onboard blobs of the best model (run/export).
    pub export: ExportReport,
    /// The shipped form of the result (RUN/model: actor, blobs, card).
    pub model: ModelCard,
    /// The blobs flown in the SIL loop against the dispersed plant: f32 and int8.
    pub sil: [SilReport; 2],
    /// Wall time of each stage run, s, by name (this invocation's: a resumed stage counts only
    /// what it still had to do).
    pub stage_seconds: Vec<(String, f64)>,
}

/// Runs every stage into `run` and writes `run/report.md`.
pub fn run_main_job(config: &ExperimentConfig, run: &Path) -> Result<MainJob, ExperimentError> {
    // Refused before the dataset's hours of solves, not at the pretraining after them.
    config.device()?;
    // The code this run is built from: read now, as the tree may change while it runs.
    let commit = current_commit();
    let recipe = config;
    let recipe_stages = config.staged()?;
    let mut config = config.clone();
    let relabel = config.dagger.rounds > 0;
    let finetuned = recipe_stages.last().unwrap_or(&config).finetune.steps > 0;
    let stages = 5 + usize::from(relabel) + recipe_stages.len() + usize::from(finetuned);
    let mut stage = 0;
    let mut next = |what: String| {
        stage += 1;
        println!("[{stage}/{stages}] {what}");
    };
    let mut stage_seconds = Vec::new();

    // 1. Fuel-optimal demonstrations (resumable: finished records are skipped).
    let t = Instant::now();
    next(format!(
        "solving {} {} trajectories (indirect method)",
        config.generate.count,
        config.family.label()
    ));
    let dataset_dir = run.join("dataset");
    let (dataset, crosscheck) = demonstrations(&config, &dataset_dir)?;
    // Absolute, so the config's relative-path base cannot apply twice.
    config.pretrain.dataset = Some(std::path::absolute(&dataset_dir).unwrap_or(dataset_dir.clone()));
    stage_seconds.push(("dataset".into(), t.elapsed().as_secs_f64()));

    // 2. Pretraining on the demonstrations.
    let t = Instant::now();
    next(format!(
        "pretraining: {} updates on the demonstration buffer",
        config.pretrain.updates
    ));
    let pre = pretrain(&config, run, run)?;
    stage_seconds.push(("pretraining".into(), t.elapsed().as_secs_f64()));

    // 3. RL from the pretrained model.
    let t = Instant::now();
    next(format!(
        "training: {} environment steps from the pretrained model",
        config.train.env_steps
    ));
    let rl = train(&config, run, Start::Pretrained)?;
    stage_seconds.push(("RL".into(), t.elapsed().as_secs_f64()));
    let mut best = rl.folder.join("best.safetensors");

    // 4. Relabelling rounds from RL's best model.
    let rounds = if relabel {
        let t = Instant::now();
        next(format!(
            "relabelling rounds: at most {}, {} of {} flights relabelled each{}",
            config.dagger.rounds,
            config.dagger.episodes,
            config.dagger.candidates.unwrap_or(config.dagger.episodes),
            config
                .dagger
                .stop_at
                .map_or(String::new(), |g| format!(", until {:.1} % within the goal", 100.0 * g))
        ));
        let summary = dagger(&config, run, run, &best, None)?;
        best = summary.folder.join("best.safetensors");
        stage_seconds.push(("relabelling".into(), t.elapsed().as_secs_f64()));
        Some(summary)
    } else {
        None
    };

    // 5. The recipe's stages, each from the learner the one before ended with.
    let mut input = StageInput {
        config: config.clone(),
        folder: run.to_path_buf(),
        best: best.clone(),
        rounds: rounds.clone(),
        dataset: dataset.clone(),
    };
    let mut stage_runs = Vec::new();
    for (stage, stage_config) in recipe.stages.iter().zip(&recipe_stages) {
        let t = Instant::now();
        next(format!(
            "stage {}: relabelling rounds to {}",
            stage.name, stage_config.dagger.rounds
        ));
        let (summary, after) = run_stage(stage, stage_config, run, &input)?;
        stage_seconds.push((format!("stage {}", stage.name), t.elapsed().as_secs_f64()));
        stage_runs.push(summary);
        input = after;
    }
    // The last stage's learner, flown with its config.
    let (flown, flown_dataset) = (input.config, input.dataset);

    // 6. Fine-tuning through the dynamics: its best actor is what ships.
    let (best, fine) = if finetuned {
        let t = Instant::now();
        let phases: Vec<String> = flown
            .finetune
            .phases()
            .map(|p| {
                format!(
                    "{} steps of {} flights{}",
                    p.steps,
                    p.flights,
                    if p.dispersed { " (dispersed)" } else { "" }
                )
            })
            .collect();
        next(format!("fine-tuning through the dynamics: {}", phases.join(", then ")));
        let summaries = finetune(&flown, run, &input.best)?;
        stage_seconds.push(("fine-tuning".into(), t.elapsed().as_secs_f64()));
        let last = summaries.last().map_or(input.best, |s| s.best_actor.clone());
        (last, summaries)
    } else {
        (input.best, Vec::new())
    };

    // 7. Monte Carlo of the best model.
    let t = Instant::now();
    next(format!("Monte Carlo: {} episodes", flown.evaluate.episodes));
    let mc = monte_carlo(&flown, &best, &run.join("mc"), None, Optima::Solve(None))?;
    stage_seconds.push(("Monte Carlo".into(), t.elapsed().as_secs_f64()));

    // 8. Onboard blobs, flown in the SIL loop against the dispersed plant.
    let t = Instant::now();
    next(format!(
        "export f32 + int8 blobs, SIL: {} dispersed flights each",
        flown.sil.episodes
    ));
    let last_rounds = stage_runs.last().map(|s| &s.rounds).or(rounds.as_ref());
    let rounds_run = last_rounds.map(|r| (r.rows.last().map_or(0, |row| row.round), r.best_round));
    let notes: Vec<String> = stage_runs
        .iter()
        .map(StageSummary::lineage_line)
        .chain(fine.iter().map(FinetuneSummary::lineage_line))
        .collect();
    let lineage = Lineage {
        commit: &commit,
        dataset: &flown_dataset,
        rounds: rounds_run,
        notes: &notes,
    };
    let (export, sil, model) = export_and_ship(&flown, run, run, &best, &mc, &lineage)?;
    stage_seconds.push(("export and SIL".into(), t.elapsed().as_secs_f64()));

    let job = MainJob {
        report: run.join("report.md"),
        dataset,
        crosscheck,
        pretrain: pre,
        train: rl,
        dagger: rounds,
        stages: stage_runs,
        finetune: fine,
        monte_carlo: mc,
        export,
        model,
        sil,
        stage_seconds,
    };
    let text = report_markdown(&config, run, &job);
    atomic_write(&job.report, text.as_bytes()).map_err(|e| ExperimentError::Io(job.report.clone(), e))?;
    Ok(job)
}
