//! An inclined family is learned in three dimensions: pretraining on a three-dimensional
//! dataset, RL from the pretrained model in the 3D transfer environment with 4-component
//! actions, relabelling rounds in 3D, and the Monte Carlo with its optimality gap solved in 3D,
//! the blobs with the three-dimensional layout flown in the 3D SIL loop, and `ground run` from
//! the draws to the model folder; a planar dataset is refused for it.

use std::path::{Path, PathBuf};

#[allow(dead_code)]
mod common;

use common::{scratch_dir, toy_config, toy_dataset_of};

use firmware_sim::Dispersions;
use ground_core::env::{Environment, Spatial, Transfer3Env};
use ground_core::generate::{generate, Manifest, Shard};
use ground_core::solver::spatial::record::solve_spatial_draw;
use ground_core::solver::SolveOptions;
use learn::cloning::CloningTarget;
use learn::config::ExperimentConfig;
use learn::error::ExperimentError;
use learn::eval::Optima;
use learn::export::OnboardPolicy;
use learn::rl::{train, Start};
use learn::sac::agent::Sac;
use shared::blob::FeatureLayout;
use shared::mission::SpatialFamily;
use shared::scenario::{Range, ScenarioKind};
use shared::spacecraft::Spacecraft;
use tch::Device;

/// Transfer-circular's orbits, the target inclined by up to 5 degrees with any node.
fn inclined() -> SpatialFamily {
    let inclination = Range {
        lo: 1f64.to_radians(),
        hi: 5f64.to_radians(),
    };
    SpatialFamily::inclined_target(ScenarioKind::TransferCircular.family(), inclination)
}

/// Two draws of the inclined family solved quickly (eps 0.3) into `dir/spatial`, as
/// [`common::toy_dataset_of`] solves a planar family's.
fn spatial_dataset(dir: &Path) -> PathBuf {
    let out = dir.join("spatial");
    let options = SolveOptions {
        final_eps: 0.3,
        ..SolveOptions::default()
    };
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let manifest = Manifest {
        family: inclined(),
        seed: 9,
        count: 2,
    };
    let summary = generate(manifest, Shard::WHOLE, &out, &sc, &options, false).unwrap();
    assert_eq!(summary.converged, 2, "toy dataset did not solve");
    out
}

/// The toy config on the inclined family, cloning the thrust vector (4 components), one
/// optimality-gap case.
fn inclined_config(dataset: &Path) -> ExperimentConfig {
    let mut config = toy_config(dataset);
    config.family = inclined();
    config.pretrain.cloning_target = CloningTarget::Thrust;
    config.evaluate.episodes = 6;
    config.evaluate.optimality_gap_cases = 1;
    config
}

/// The flown network is 256 wide: `agent`'s actor widened function-preservingly (`config`'s
/// learner otherwise), saved in `dir`.
fn wide_actor(dir: &Path, agent: &Sac, config: &ExperimentConfig) -> PathBuf {
    let narrow = dir.join("actor-32.safetensors");
    agent.save_flown_actor(&narrow).unwrap();
    let mut config = config.clone();
    config.sac.hidden = vec![256, 256];
    let mut widened = Sac::new(config.sac_for(true), Transfer3Env::OBS, 4, Device::Cpu);
    widened.start_from_actor(&narrow).unwrap();
    let wide = dir.join("actor-256.safetensors");
    widened.save_flown_actor(&wide).unwrap();
    wide
}

/// The tests of this file train with torch, whose thread count is process-wide: run one at a
/// time, so each trains as it would alone.
static TORCH: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn an_inclined_family_pretrains_trains_and_is_evaluated_in_three_dimensions() {
    let _torch = TORCH.lock().unwrap_or_else(|e| e.into_inner());
    let dir = scratch_dir("inclined");
    let spatial = spatial_dataset(&dir);
    let config = inclined_config(&spatial);
    assert!(config.is_inclined());
    assert_eq!(config.action_dim(), 4);
    // The config writes and reads back as the inclined family.
    assert_eq!(ExperimentConfig::from_toml(&config.to_toml()).unwrap(), config);

    // Pretraining on the 3D tuples: every cycle of both records in the buffer.
    let run = dir.join("run");
    let pre = learn::pretrain::pretrain(&config, &dir, &run).unwrap();
    assert_eq!((pre.updates, pre.demonstration_records), (120, 2));
    let cycles: u32 = (0..2).map(|i| config.family.draw(9, i).scenario.steps).sum();
    assert_eq!(pre.demonstration_tuples, cycles as usize);

    // RL from the pretrained model and its buffer, in the 3D environment.
    let summary = train(&config, &run, Start::Pretrained).unwrap();
    assert_eq!(summary.env_steps, 150);
    let best = run.join("train-pretrained").join("best.safetensors");
    let log = std::fs::read_to_string(run.join("train-pretrained").join("eval.csv")).unwrap();
    assert_eq!(log.lines().count(), 5, "{log}");
    let agent = learn::eval::load_agent(&config, Transfer3Env::OBS, &best).unwrap();
    assert_eq!(agent.act_dim(), 4);
    let mut env = Transfer3Env::new(&config.env).unwrap();
    let obs = env.reset(&config.family.draw(1, 0)).unwrap();
    let action: Vec<[f32; 4]> = learn::phase::policy_batch(&agent, &[obs]);
    assert_eq!(action.len(), 1);
    assert!(env.step(&action[0]).is_ok());

    // The Monte Carlo: every episode flown in 3D, the zero-thrust baseline keeps its mass and
    // misses, the optimality gap's optimum solved in 3D.
    let out = dir.join("mc");
    let report = learn::eval::monte_carlo(&config, &best, &out, None, Optima::Solve(None)).unwrap();
    assert_eq!((report.episodes, report.policy.completed), (6, 6));
    let zero = &report.zero_thrust;
    assert!(zero.final_mass.min == 1.0 && zero.final_mass.max == 1.0, "{zero:?}");
    assert!(zero.terminal_position.min > 1e-3, "{zero:?}");
    assert_eq!(report.gap.len(), 1);
    assert!(report.gap[0].optimal_converged, "{:?}", report.gap[0]);
    // The optimum of the Monte Carlo's first draw, solved by the 3D method.
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let first = solve_spatial_draw(
        &config.family,
        config.seeds.monte_carlo,
        0,
        &sc,
        &SolveOptions::default(),
    );
    assert_eq!(report.gap[0].optimal_mass, first.final_mass);
    let mc = std::fs::read_to_string(out.join("mc.csv")).unwrap();
    assert_eq!(mc.lines().count(), 7);
    assert!(
        !out.join("trajectories.svg").exists(),
        "inclined flights are not drawn in the plane"
    );

    // A relabelling round in 3D: the learner's flights of round 1's training scenarios
    // re-solved from their states at half-flight, 15-feature observations and 4-component
    // actions, each relabel's first tuple at the state the learner visited there.
    let mut rounds = config.clone();
    rounds.generate.final_eps = 0.3;
    rounds.dagger.rounds = 1;
    rounds.dagger.episodes = 2;
    rounds.dagger.fractions = vec![0.5];
    rounds.dagger.updates = 20;
    rounds.dagger.score_episodes = 4;
    let relabelled = dir.join("rounds");
    let summary = learn::dagger::dagger(&rounds, &dir, &relabelled, &best, None).unwrap();
    let row = summary.rows[1];
    assert_eq!((row.round, row.relabels_attempted, row.updates), (1, 2, 20));
    // The relabels start where the briefly trained learner flew, which its training's float
    // arithmetic moves between runs: usually both converge at eps 0.3, now and then one.
    assert!(row.relabels_converged >= 1, "no relabel converged at eps 0.3");
    assert_eq!(row.buffer, cycles as u64 + row.tuples_added);
    let relabels = learn::dagger::load_relabels(&relabelled.join("dagger/relabels-1.ltrl"), 1, 15, 4).unwrap();
    assert!(learn::dagger::load_relabels(&relabelled.join("dagger/relabels-1.ltrl"), 1, 15, 3).is_err());
    let tuples = &relabels.tuples;
    assert_eq!(tuples.demonstration_count(), tuples.len());
    let learner = learn::eval::load_agent(
        &config,
        Transfer3Env::OBS,
        &relabelled.join("dagger/round-0.safetensors"),
    )
    .unwrap();
    let (mut first_tuple, mut matched) = (0, 0);
    for episode in 0..2 {
        let scenario = config.family.draw(config.seeds.train, 1_000_000 + episode);
        let steps = scenario.scenario.steps;
        let step = (0.5 * f64::from(steps)).round() as u32;
        let mut env = Transfer3Env::new(&config.env).unwrap();
        let mut obs = env.reset(&scenario).unwrap();
        for _ in 0..step {
            let action: Vec<[f32; 4]> = learn::phase::policy_batch(&learner, &[obs]);
            obs = env.step(&action[0]).unwrap().observation;
        }
        let relabel = tuples.get(first_tuple).obs;
        let visited = relabel
            .iter()
            .zip(obs.iter())
            .all(|(a, b)| (a - b).abs() <= 1e-5 * (1.0 + b.abs()));
        if !visited && row.relabels_converged < 2 {
            // This episode's relabel did not converge: the next one's tuples come first.
            continue;
        }
        assert!(visited, "episode {episode}: {relabel:?} against {obs:?}");
        matched += 1;
        // The rest of the flight, one tuple per cycle, the last one done.
        first_tuple += (steps - step) as usize;
        assert!(tuples.get(first_tuple - 1).done);
        assert!((first_tuple - (steps - step) as usize..first_tuple - 1).all(|i| !tuples.get(i).done));
    }
    assert_eq!((first_tuple, matched), (tuples.len(), row.relabels_converged));
    // Dispersed rounds relabel the onboard controller's flights in the 3D SIL plant, and score
    // it there too.
    let mut dispersed = rounds.clone();
    dispersed.dagger.dispersed = true;
    dispersed.sac.hidden = vec![256, 256];
    let summary = learn::dagger::dagger(
        &dispersed,
        &dir,
        &dir.join("dispersed"),
        &wide_actor(&dir, &agent, &config),
        None,
    )
    .unwrap();
    assert_eq!(summary.rows[1].relabels_attempted, 2);
    assert!(summary.rows.iter().all(|r| r.within_goal_dispersed.is_some()));

    // A planar dataset is not one of this family's: refused, no pretraining written.
    let planar = toy_dataset_of(&dir, ScenarioKind::TransferCircular);
    let mut other = config.clone();
    other.pretrain.dataset = Some(planar);
    let refused = learn::pretrain::pretrain(&other, &dir, &dir.join("other"));
    assert!(matches!(refused, Err(ExperimentError::Dataset(_))), "{refused:?}");
    assert!(!dir.join("other").exists());
    // The file reads as a planar dataset: it is refused for its dimension.
    assert!(ground_core::generate::read_dataset(&other.dataset_file(&dir).unwrap()).is_ok());

    // The blobs in three dimensions: 15 inputs, 4 action outputs, the family's mission; the f32
    // blob flies the trained actor, and a planar policy refuses it.
    let mut wide = config.clone();
    wide.sac.hidden = vec![256, 256];
    let wide_actor = wide_actor(&dir, &agent, &config);
    let mut widened = Sac::new(wide.sac_for(true), Transfer3Env::OBS, 4, Device::Cpu);
    widened.load_actor(&wide_actor).unwrap();
    let export = learn::export::export(&wide, &dir, &wide_actor, &dir.join("export")).unwrap();
    assert!(export.f32.action_error.max <= 1e-4, "{:?}", export.f32.action_error);
    assert!(export.int8.action_error.p50 <= 0.05, "{:?}", export.int8.action_error);
    assert_eq!(export.closed_loop_episodes, 6);
    for (file, tolerance) in [(&export.f32.file, 1e-4), (&export.int8.file, 0.05)] {
        let bytes = shared::blob::AlignedBlob::new(&std::fs::read(file).unwrap());
        let blob = shared::blob::decode(bytes.bytes()).unwrap();
        assert_eq!(blob.features, FeatureLayout::TransferSpatial15);
        assert_eq!(blob.layers.last().map(|l| l.outputs), Some(4));
        assert_eq!(blob.mission, config.blob_mission());
        let policy = OnboardPolicy::load(bytes.bytes(), FeatureLayout::TransferSpatial15).unwrap();
        let reference: Vec<[f32; 4]> = learn::phase::policy_batch(&widened, &[obs]);
        let onboard = policy.action::<Spatial>(&obs);
        for (a, r) in onboard.iter().zip(&reference[0]) {
            assert!((a - r).abs() <= tolerance, "{onboard:?} against {:?}", reference[0]);
        }
        assert!(OnboardPolicy::load(bytes.bytes(), FeatureLayout::TransferPolar10).is_err());
    }

    // The blobs in the 3D SIL loop: without dispersions each flight is the ground environment's
    // episode of the same blob (the export's closed loop); with the typical dispersions every
    // flight is flown, and differently; a planar blob flies safe mode.
    for (file, closed_loop) in [
        (&export.f32.file, &export.f32.closed_loop),
        (&export.int8.file, &export.int8.closed_loop),
    ] {
        assert_eq!(learn::sil::blob_refusal(&wide, file).unwrap(), None);
        let nominal =
            learn::sil::sil_monte_carlo(&wide, file, &dir.join("sil"), Some(6), &Dispersions::NONE, Optima::NONE)
                .unwrap();
        assert_eq!((nominal.flights, nominal.guidance_faults), (6, 0));
        let flown = &nominal.monte_carlo.policy;
        assert_eq!(flown.completed, 6);
        assert!(
            (flown.total_reward.mean - closed_loop.total_reward.mean).abs()
                <= 1e-12 * closed_loop.total_reward.mean.abs()
        );
        assert_eq!(flown.terminal_position.p50, closed_loop.terminal_position.p50);
        let dispersed = learn::sil::sil_monte_carlo(
            &wide,
            file,
            &dir.join("sil"),
            Some(6),
            &Dispersions::TYPICAL,
            Optima::NONE,
        )
        .unwrap();
        assert_eq!(dispersed.monte_carlo.policy.completed, 6);
        assert_ne!(
            dispersed.monte_carlo.policy.terminal_position.p50,
            flown.terminal_position.p50
        );
    }
    let planar_blob = dir.join("planar.blob");
    std::fs::write(
        &planar_blob,
        std::fs::read("../../models/transfer-circular/transfer-f32.blob").unwrap(),
    )
    .unwrap();
    let refusal = learn::sil::blob_refusal(&wide, &planar_blob).unwrap();
    assert!(
        refusal.is_some_and(|why| why.contains("feature layout")),
        "a planar blob flies the 3D loop"
    );

    // Terminal targeting flies in three dimensions.
    let mut targeted = wide.clone();
    targeted.sil.terminal = Some(learn::config::TerminalSettings::default());
    assert!(targeted.validate().is_ok());
    // Nominally the rollouts are the plant: the targeted flights end nearer the orbit.
    let fly = |config: &ExperimentConfig, name: &str| {
        learn::sil::sil_monte_carlo(
            config,
            &export.f32.file,
            &dir.join(name),
            Some(6),
            &Dispersions::NONE,
            Optima::NONE,
        )
        .unwrap()
    };
    let (alone, aimed) = (fly(&wide, "alone"), fly(&targeted, "targeted"));
    assert!(alone.terminal.is_none() && aimed.terminal.is_some());
    assert_eq!((aimed.flights, aimed.guidance_faults), (6, 0));
    let miss = |r: &learn::sil::SilReport| r.monte_carlo.policy.terminal_position.p50;
    assert!(miss(&aimed) < miss(&alone), "{} against {}", miss(&aimed), miss(&alone));
    // Rollout lookahead flies in three dimensions too, before the terminal cycles.
    let mut aided = targeted.clone();
    aided.sil.lookahead = Some(Default::default());
    aided.validate().unwrap();
    let looked = learn::sil::sil_monte_carlo(
        &aided,
        &export.f32.file,
        &dir.join("aided"),
        Some(2),
        &Dispersions::NONE,
        Optima::NONE,
    )
    .unwrap();
    assert!(looked.lookahead.is_some() && looked.terminal.is_some());
    assert_eq!((looked.flights, looked.guidance_faults), (2, 0));

    // The run plan times the 3D environment and solves a sample in 3D.
    let plan = learn::plan::plan_recipe(&config, 1).unwrap();
    assert!(!plan.stages.is_empty() && plan.stages.iter().all(|s| s.seconds.is_finite() && s.seconds >= 0.0));
    let _ = std::fs::remove_dir_all(&dir);
}

/// `ground run` for an inclined family, at toy scale: the three-dimensional demonstrations,
/// pretraining, RL, a relabelling round, the Monte Carlo, the 3D blobs flown in the SIL loop and
/// the model folder, in one command; the report's links resolve and the folder opens.
#[test]
fn one_command_runs_an_inclined_family_from_the_draws_to_the_model_folder() {
    let _torch = TORCH.lock().unwrap_or_else(|e| e.into_inner());
    use learn::pipeline::run_main_job;
    use learn::report::broken_links;
    let dir = scratch_dir("inclined-main-job");
    let mut config = inclined_config(&dir.join("unused"));
    config.pretrain.dataset = None;
    config.generate.count = 2;
    config.generate.seed = 9;
    config.generate.final_eps = 0.3;
    config.sac.hidden = vec![256, 256];
    config.sil.episodes = 4;
    config.dagger.rounds = 1;
    config.dagger.episodes = 2;
    config.dagger.fractions = vec![0.5];
    config.dagger.updates = 20;
    config.dagger.score_episodes = 4;
    let run = dir.join("run");
    let job = run_main_job(&config, &run).unwrap();
    assert_eq!((job.dataset.records, job.dataset.converged), (2, 2));
    assert!(job.crosscheck.is_none());
    assert_eq!(job.monte_carlo.episodes, 6);
    assert_eq!(broken_links(&job.report), Vec::<String>::new());
    for (sil, name) in job.sil.iter().zip(["f32", "int8"]) {
        assert_eq!(sil.controller, name);
        assert_eq!(sil.monte_carlo.policy.completed, 4);
    }
    let model = learn::model::open_model(&run.join("model")).unwrap();
    assert_eq!(model.card.sil.len(), 2);
    let blob = std::fs::read(run.join("model/transfer-f32.blob")).unwrap();
    assert_eq!(
        shared::blob::decode(&blob).unwrap().features,
        FeatureLayout::TransferSpatial15
    );
    let _ = std::fs::remove_dir_all(&dir);
}
