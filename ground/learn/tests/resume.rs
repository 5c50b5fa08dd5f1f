//! Exact resumption: a phase stopped at a checkpoint and started again ends with the same bytes
//! as one that never stopped. One test in its own binary: torch's generator is global to the
//! process, and another test's draws would interleave with these.

mod common;

use std::path::Path;

use common::{scratch_dir, toy_config, toy_dataset};
use learn::phase::PhaseState;
use learn::pretrain::pretrain;
use learn::rl::{train, Start};

fn bytes(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The phase's evaluations and loss rows without their wall times.
fn curves(path: &Path) -> String {
    let state: PhaseState = serde_json::from_slice(&bytes(path)).unwrap();
    let evaluations: Vec<_> = state
        .evaluations
        .iter()
        .map(|r| (r.updates, r.env_steps, r.summary))
        .collect();
    format!(
        "{evaluations:?} {:?} {:?}",
        state.update_log,
        state.best.map(|b| b.summary)
    )
}

#[test]
fn pretraining_and_rl_stopped_and_resumed_end_byte_identical() {
    let dir = scratch_dir("resume");
    let dataset = toy_dataset(&dir);
    let config = toy_config(&dataset);
    let straight = dir.join("straight");
    let stopped = dir.join("stopped");

    // Pretraining: 120 updates in one go, against 80 (a checkpoint) and then the same command
    // asking for 120 again.
    pretrain(&config, &dir, &straight).unwrap();
    let mut short = config.clone();
    short.pretrain.updates = 80;
    pretrain(&short, &dir, &stopped).unwrap();
    pretrain(&config, &dir, &stopped).unwrap();
    for file in ["last.safetensors", "best.safetensors", "replay.ltrb"] {
        assert!(
            bytes(&straight.join("pretrain").join(file)) == bytes(&stopped.join("pretrain").join(file)),
            "pretrain/{file} differs after a resume"
        );
    }
    assert_eq!(
        curves(&straight.join("pretrain/state.json")),
        curves(&stopped.join("pretrain/state.json"))
    );

    // RL from the pretrained model: 150 steps, against a stop at 97 (inside an episode: episodes
    // are 20-odd steps here) and a resume.
    train(&config, &straight, Start::Pretrained).unwrap();
    let mut short = config.clone();
    short.train.env_steps = 97;
    train(&short, &stopped, Start::Pretrained).unwrap();
    let state: PhaseState = serde_json::from_slice(&bytes(&stopped.join("train-pretrained/state.json"))).unwrap();
    assert!(
        state.loop_state.episode_steps > 0,
        "the stop must fall inside an episode"
    );
    train(&config, &stopped, Start::Pretrained).unwrap();
    for file in ["last.safetensors", "best.safetensors", "replay.ltrb"] {
        assert!(
            bytes(&straight.join("train-pretrained").join(file)) == bytes(&stopped.join("train-pretrained").join(file)),
            "train-pretrained/{file} differs after a resume"
        );
    }
    assert_eq!(
        curves(&straight.join("train-pretrained/state.json")),
        curves(&stopped.join("train-pretrained/state.json"))
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
