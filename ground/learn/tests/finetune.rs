//! Fine-tuning through the dynamics as a phase: it lowers its objective on the flights it
//! evaluates, and a run stopped at a checkpoint resumes to the same bytes as one that never
//! stopped, on the nominal environment and on the SIL's dispersed plant. One test in its own binary: torch's generator is global to the process.

// The toy config alone: no dataset is needed.
#[allow(dead_code)]
mod common;

use std::path::Path;

use common::{scratch_dir, toy_config};
use learn::finetune::{finetune, FinetuneRow};
use learn::sac::agent::Sac;

fn bytes(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The evaluations without their wall times.
fn evaluations(path: &Path) -> Vec<(u64, f64, f64, f64)> {
    let rows: Vec<FinetuneRow> = serde_json::from_slice(&bytes(path)).unwrap();
    rows.iter()
        .map(|r| (r.step, r.batch_objective, r.objective, r.within_goal))
        .collect()
}

#[test]
fn finetuning_lowers_its_objective_and_resumes_byte_identical() {
    // On the nominal environment, and against the SIL's dispersed plant.
    for dispersed in [false, true] {
        lowers_and_resumes(dispersed);
    }
}

fn lowers_and_resumes(dispersed: bool) {
    let dir = scratch_dir(if dispersed { "finetune-dispersed" } else { "finetune" });
    let mut config = toy_config(&dir.join("no-dataset"));
    config.finetune.dispersed = dispersed;
    if dispersed {
        // Dispersed flights are evaluated in the SIL loop: the onboard contract's network.
        config.sac.hidden = vec![256, 256];
    }
    config.finetune.steps = 12;
    config.finetune.flights = 4;
    config.finetune.eval_every = 4;
    config.finetune.eval_episodes = 8;
    // A fast learning rate: the toy actor starts untrained.
    config.finetune.learning_rate = 1e-3;
    config.compute.threads = 1;
    tch::manual_seed(7);
    let start = dir.join("actor.safetensors");
    Sac::new(config.sac.clone(), 10, 3, tch::Device::Cpu)
        .save_flown_actor(&start)
        .unwrap();

    let straight = dir.join("straight");
    let summary = finetune(&config, &straight, &start).unwrap();
    let rows = &summary.rows;
    assert_eq!(rows.iter().map(|r| r.step).collect::<Vec<_>>(), [0, 4, 8, 12]);
    let best = rows.iter().find(|r| r.step == summary.best_step).unwrap();
    assert!(
        best.objective < rows[0].objective,
        "dispersed {dispersed}: no evaluation below the start's objective: {rows:?}"
    );

    // Stopped at step 8 (a checkpoint), then the same command asking for 12.
    let stopped = dir.join("stopped");
    let mut short = config.clone();
    short.finetune.steps = 8;
    finetune(&short, &stopped, &start).unwrap();
    finetune(&config, &stopped, &start).unwrap();
    for file in [
        "step-4.safetensors",
        "step-8.safetensors",
        "step-12.safetensors",
        "best.safetensors",
        "best-actor.safetensors",
    ] {
        assert!(
            bytes(&straight.join("finetune").join(file)) == bytes(&stopped.join("finetune").join(file)),
            "dispersed {dispersed}: finetune/{file} differs after a resume"
        );
    }
    assert_eq!(
        evaluations(&straight.join("finetune/state.json")),
        evaluations(&stopped.join("finetune/state.json"))
    );
    let _ = std::fs::remove_dir_all(&dir);
}
