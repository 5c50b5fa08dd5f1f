//! The demonstrations stage: the config's scenarios solved by the indirect method into
//! `RUN/dataset` (resumable), checked against the direct transcription where the config asks,
//! and a sample plotted.

use std::path::Path;

use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use ground_core::crosscheck::CrossCheckSettings;
use ground_core::generate::{crosscheck_once, generate, CrossCheckSummary, Manifest, Shard, Summary};
use ground_core::plot::plot_dataset_sample;
use ground_core::solver::SolveOptions;

/// Solves the config's `[generate]` draws into `dataset_dir` (finished records are skipped),
/// repairs worse local optima found by the direct transcription when `generate.crosscheck` is
/// set, and plots a sample. Returns the dataset's summary and the cross-check's.
pub fn demonstrations(
    config: &ExperimentConfig,
    dataset_dir: &Path,
) -> Result<(Summary, Option<CrossCheckSummary>), ExperimentError> {
    let spacecraft = config
        .env
        .spacecraft
        .canonical()
        .map_err(|e| ExperimentError::Mismatch(format!("spacecraft: {e:?}")))?;
    let manifest = Manifest {
        family: config.family,
        seed: config.generate.seed,
        count: config.generate.count,
    };
    let options = SolveOptions {
        final_eps: config.generate.final_eps,
        arrival_margin_steps: config.generate.arrival_margin,
        ..SolveOptions::default()
    };
    let mut dataset = generate(manifest, Shard::WHOLE, dataset_dir, &spacecraft, &options, true)
        .map_err(|e| ExperimentError::Dataset(e.to_string()))?;
    // Worse local optima re-solved onto the better one the direct transcription finds, before
    // anything imitates them (once per dataset: a resumed run reads what was found).
    let crosscheck = if config.generate.crosscheck {
        println!("      checking the records against the direct transcription (repairing worse optima)");
        let (found, rewritten) =
            crosscheck_once(dataset_dir, &spacecraft, &CrossCheckSettings::default(), &options, true)
                .map_err(|e| ExperimentError::Dataset(e.to_string()))?;
        // A resumed run's dataset, read above, already holds the repairs.
        if let Some(repaired) = rewritten {
            dataset = repaired;
        }
        Some(found)
    } else {
        None
    };
    // The figure is a convenience: a dataset that cannot be plotted is still a dataset.
    let _ = plot_dataset_sample(dataset_dir, Shard::WHOLE);
    Ok((dataset, crosscheck))
}
