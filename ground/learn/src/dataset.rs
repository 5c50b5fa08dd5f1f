//! The demonstrations stage: the config's scenarios solved by the indirect method into
//! `RUN/dataset` (resumable; an inclined family's by the three-dimensional method), checked
//! against the direct transcription where the config asks, and a sample plotted.

use std::path::Path;

use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use ground_core::crosscheck::CrossCheckSettings;
use ground_core::generate::{crosscheck_once, generate, CrossCheckSummary, Manifest, Shard, Summary};
use ground_core::plot::plot_dataset_sample;
use ground_core::spatial::plot_spatial_dataset_sample;

/// Solves the config's `[generate]` draws into `dataset_dir` (finished records are skipped),
/// repairs worse local optima found by the direct transcription when `generate.crosscheck` is
/// set, and plots a sample. Returns the dataset's summary and the cross-check's.
pub fn demonstrations(
    config: &ExperimentConfig,
    dataset_dir: &Path,
) -> Result<(Summary, Option<CrossCheckSummary>), ExperimentError> {
    // In the family's units: the demonstrations are solved for the spacecraft the MDP flies.
    let spacecraft = config
        .env
        .canonical_spacecraft()
        .map_err(|e| ExperimentError::Mismatch(format!("spacecraft: {e}")))?;
    let options = config.generate.solve_options();
    if config.is_inclined() {
        // Records of the three-dimensional solver; the direct transcription is planar.
        if config.generate.crosscheck {
            return Err(ExperimentError::Inclined {
                stage: "the direct transcription cross-check",
                family: config.family.label().to_string(),
            });
        }
        let manifest = Manifest {
            family: config.family,
            seed: config.generate.seed,
            count: config.generate.count,
        };
        let dataset = generate(manifest, Shard::WHOLE, dataset_dir, &spacecraft, &options, true)
            .map_err(|e| ExperimentError::Dataset(e.to_string()))?;
        let _ = plot_spatial_dataset_sample(dataset_dir, Shard::WHOLE, &config.env.spacecraft);
        return Ok((dataset, None));
    }
    let manifest = Manifest {
        family: config.planar_family("the demonstrations dataset")?,
        seed: config.generate.seed,
        count: config.generate.count,
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

#[cfg(test)]
mod tests {
    use super::*;
    use ground_core::solver::solve_scenario;

    /// The demonstrations of a family around another body are solved for the spacecraft in that
    /// body's units: the records equal the indirect method's solves of the same draws with it.
    #[test]
    fn demonstrations_fly_the_spacecraft_in_the_familys_units() {
        let config = ExperimentConfig::from_toml(
            "scenario = { problem = \"transfer\", body = { mu_m3_s2 = 1.32712440018e19, length_unit_m = 1.495978707e11 }, \
             departure = { a = 1.0, e = 0.0 }, target = { a = 1.2, e = 0.0 }, time_of_flight = { days = 700.0 }, \
             cycle = { days = 14.0 } }\n[generate]\ncount = 2\nseed = 3\ncrosscheck = false",
        )
        .unwrap();
        let dir = std::env::temp_dir().join(format!("lowthrust-weak-sun-{}", std::process::id()));
        let (summary, _) = demonstrations(&config, &dir).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        let spacecraft = config.env.canonical_spacecraft().unwrap();
        let options = config.generate.solve_options();
        let masses: Vec<f64> = (0..2)
            .map(|index| {
                let scenario = config.family.family.draw(3, index);
                let record = solve_scenario(config.family.family, 3, index, &scenario, &spacecraft, &options);
                assert!(record.converged);
                record.final_mass
            })
            .collect();
        assert_eq!(summary.converged, 2);
        let mean = (masses[0] + masses[1]) / 2.0;
        assert!(
            (summary.final_mass_mean - mean).abs() < 1e-12,
            "{} {mean}",
            summary.final_mass_mean
        );
    }
}
