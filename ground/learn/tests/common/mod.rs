//! Toy-scale fixtures shared by the learning-pipeline tests.

use std::path::{Path, PathBuf};

use ground_core::generate::{generate, Manifest, Shard};
use ground_core::solver::SolveOptions;
use learn::config::ExperimentConfig;
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

pub fn scratch_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lowthrust-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Two transfer-circular trajectories, homotopy stopped early (eps 0.3) so the solve is quick:
/// demonstrations are built the same way at any eps.
pub fn toy_dataset(dir: &Path) -> PathBuf {
    toy_dataset_of(dir, ScenarioKind::TransferCircular)
}

/// [`toy_dataset`] of another distribution (seed 9, draws 0 and 1).
pub fn toy_dataset_of(dir: &Path, scenario: ScenarioKind) -> PathBuf {
    let out = dir.join("dataset");
    let manifest = Manifest {
        family: scenario.family(),
        seed: 9,
        count: 2,
    };
    let options = SolveOptions {
        final_eps: 0.3,
        ..SolveOptions::default()
    };
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let summary = generate(manifest, Shard::WHOLE, &out, &sc, &options, false).unwrap();
    assert_eq!(summary.converged, 2, "toy dataset did not solve");
    out
}

pub fn toy_config(dataset: &Path) -> ExperimentConfig {
    ExperimentConfig::from_toml(&format!(
        r#"
scenario = "transfer-circular"
[sac]
hidden = [32, 32]
batch_size = 32
warmup_steps = 60
replay_capacity = 5000
[pretrain]
dataset = "{}"
updates = 120
eval_every = 40
mode = "behaviour-cloning"
records = "all"
[train]
env_steps = 150
eval_every = 50
eval_episodes = 4
checkpoint_every = 50
[evaluate]
episodes = 16
optimality_gap_cases = 0
"#,
        dataset.display()
    ))
    .unwrap()
}
