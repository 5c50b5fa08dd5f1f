//! The ship stage, for the recipe's best learner or any checkpoint (`ground model ship`): its
//! Monte Carlo, its onboard blobs (f32, int8) flown in the SIL loop against the config's
//! dispersed plant, and the model folder `RUN/model` (actor, blobs, card).

use std::path::Path;

use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use crate::eval::{monte_carlo, optima_from, MonteCarloReport, Optima};
use crate::export::{export, ExportReport};
use crate::model::{current_commit, write_model, ModelCard, ModelSources};
use crate::sil::{aided_monte_carlo, sil_of_blobs, SilReport};
use ground_core::generate::Summary;

/// Where a shipped learner came from, as its card records it.
pub(crate) struct Lineage<'a> {
    /// The commit the run was built from.
    pub(crate) commit: &'a str,
    /// The demonstrations' dataset.
    pub(crate) dataset: &'a Summary,
    /// Relabelling rounds (run, kept), when there were any.
    pub(crate) rounds: Option<(u64, u64)>,
    /// Lines on the lineage beyond the config.
    pub(crate) notes: &'a [String],
}

/// Exports `checkpoint`'s blobs into `run/export`, flies them in the SIL loop against the
/// config's dispersed plant (`run/sil-f32`, `run/sil-int8`) and writes the model
/// folder `run/model` from them, the Monte Carlo `mc` and the learner's `lineage`.
pub(crate) fn export_and_ship(
    config: &ExperimentConfig,
    config_dir: &Path,
    run: &Path,
    checkpoint: &Path,
    mc: &MonteCarloReport,
    lineage: &Lineage,
) -> Result<(ExportReport, [SilReport; 2], ModelCard), ExperimentError> {
    let Lineage {
        commit,
        dataset,
        rounds,
        notes,
    } = *lineage;
    let export = export(config, config_dir, checkpoint, &run.join("export"))?;
    let sil = sil_of_blobs(config, &export.f32.file, &export.int8.file, run)?;
    // The nominal draws of the checkpoint's Monte Carlo: its optima serve the aided one.
    let aided = aided_monte_carlo(config, &export.f32.file, run, optima_from(config, mc)?)?;
    let model = write_model(
        &run.join("model"),
        &ModelSources {
            config,
            commit,
            checkpoint,
            dataset,
            rounds,
            monte_carlo: mc,
            export: &export,
            sil: &sil,
            aided: aided.as_ref(),
            notes,
        },
    )
    .map_err(|e| ExperimentError::Mismatch(format!("model folder: {e}")))?;
    Ok((export, sil, model))
}

/// What [`ship`] produced.
pub struct Shipped {
    /// The Monte Carlo of the checkpoint (`run/mc`).
    pub monte_carlo: MonteCarloReport,
    /// Its onboard blobs (`run/export`).
    pub export: ExportReport,
    /// The blobs flown in the SIL loop against the dispersed plant: f32 and int8.
    pub sil: [SilReport; 2],
    /// The model folder, `run/model`.
    pub model: ModelCard,
}

/// `ground model ship`: the last stages of the recipe for any learner checkpoint (e.g. the best of
/// relabelling rounds started from a shipped actor): the Monte Carlo (`run/mc`), the blobs and
/// their SIL flights, and the model folder `run/model`, whose card records `rounds` (run, kept)
/// and `notes` (the lineage). The demonstrations are the config's `pretrain.dataset`.
pub fn ship(
    config: &ExperimentConfig,
    config_dir: &Path,
    checkpoint: &Path,
    run: &Path,
    rounds: Option<(u64, u64)>,
    notes: &[String],
) -> Result<Shipped, ExperimentError> {
    let commit = current_commit();
    let dataset_file = config.dataset_file(config_dir)?;
    // Absolute here, as the config's folder is not kept; the card writes it relative to the
    // working folder (the repository), where `ground model export --model` finds it again.
    let mut config = config.clone();
    config.pretrain.dataset = Some(std::path::absolute(&dataset_file).unwrap_or(dataset_file.clone()));
    let config = &config;
    let summary_path = dataset_file.with_file_name("summary.json");
    let bytes = std::fs::read(&summary_path).map_err(|e| ExperimentError::Io(summary_path.clone(), e))?;
    let dataset: Summary = serde_json::from_slice(&bytes)
        .map_err(|e| ExperimentError::Mismatch(format!("{} does not parse: {e}", summary_path.display())))?;
    let monte_carlo = monte_carlo(config, checkpoint, &run.join("mc"), None, Optima::Solve(None))?;
    let lineage = Lineage {
        commit: &commit,
        dataset: &dataset,
        rounds,
        notes,
    };
    let (export, sil, model) = export_and_ship(config, config_dir, run, checkpoint, &monte_carlo, &lineage)?;
    Ok(Shipped {
        monte_carlo,
        export,
        sil,
        model,
    })
}
