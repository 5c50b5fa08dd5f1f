//! An inclined family is learned in three dimensions: RL from scratch flies the 3D transfer
//! environment with 4-component actions, evaluates, checkpoints and resumes to the same
//! learner; the stages that fly planar families only refuse it by name, before any work.

use ground_core::env::{Environment, Transfer3Env};
use learn::config::ExperimentConfig;
use learn::error::ExperimentError;
use learn::rl::{train, Start};
use shared::mission::{PlaneRanges, SpatialFamily};
use shared::scenario::{Range, ScenarioKind};

fn scratch_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("lowthrust-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn inclined_config() -> ExperimentConfig {
    let mut config = ExperimentConfig::from_toml(
        r#"
scenario = "transfer-circular"
[sac]
hidden = [32, 32]
batch_size = 32
warmup_steps = 60
replay_capacity = 5000
[train]
env_steps = 120
eval_every = 60
eval_episodes = 3
checkpoint_every = 60
"#,
    )
    .unwrap();
    config.family = SpatialFamily {
        family: ScenarioKind::TransferCircular.family(),
        departure_plane: PlaneRanges::REFERENCE,
        target_plane: PlaneRanges {
            inclination: Range { lo: 0.0, hi: 0.087 },
            raan: Range {
                lo: 0.0,
                hi: 2.0 * core::f64::consts::PI,
            },
        },
    };
    config
}

#[test]
fn an_inclined_family_trains_in_three_dimensions_and_planar_stages_refuse_it() {
    let dir = scratch_dir("inclined");
    let config = inclined_config();
    assert!(config.is_inclined());
    assert_eq!(config.action_dim(), 4);
    // The config writes and reads back as the inclined family.
    assert_eq!(ExperimentConfig::from_toml(&config.to_toml()).unwrap(), config);

    let run = dir.join("run");
    let summary = train(&config, &run, Start::Scratch).unwrap();
    assert_eq!(summary.env_steps, 120);
    // Evaluations at 0, 60 and 120 steps, each over 3 episodes of the 3D environment.
    let log = std::fs::read_to_string(run.join("train-scratch").join("eval.csv")).unwrap();
    assert_eq!(log.lines().count(), 4, "{log}");
    let agent = learn::eval::load_agent(
        &config,
        Transfer3Env::OBS,
        &run.join("train-scratch").join("best.safetensors"),
    )
    .unwrap();
    assert_eq!(agent.act_dim(), 4);
    // Its deterministic actions fly the 3D environment.
    let mut env = Transfer3Env::new(&config.env).unwrap();
    let obs = env.reset(&config.family.draw(1, 0)).unwrap();
    let action: Vec<[f32; 4]> = learn::phase::policy_batch(&agent, &[obs]);
    assert_eq!(action.len(), 1);
    assert!(env.step(&action[0]).is_ok());

    // A second call finds the run complete and gives the same summary.
    let again = train(&config, &run, Start::Scratch).unwrap();
    assert_eq!(again.env_steps, summary.env_steps);

    // Planar-only stages refuse by name, and write nothing.
    let out = dir.join("mc");
    let refused = learn::eval::monte_carlo(
        &config,
        &run.join("train-scratch").join("best.safetensors"),
        &out,
        Some(2),
        Some(0),
    );
    match refused {
        Err(ExperimentError::Inclined { stage, family }) => {
            assert!(
                stage.contains("Monte Carlo") && family.starts_with("custom-"),
                "{stage} {family}"
            );
        }
        other => panic!("not refused: {other:?}"),
    }
    assert!(!out.exists());
    let refused = learn::pretrain::pretrain(&config, &dir, &dir.join("pre"));
    assert!(matches!(refused, Err(ExperimentError::Inclined { .. })), "{refused:?}");
    assert!(!dir.join("pre").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
