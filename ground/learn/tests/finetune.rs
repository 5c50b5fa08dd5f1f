//! Fine-tuning through the dynamics as a phase: it lowers its objective on the flights it
//! evaluates, and a run stopped at a checkpoint resumes to the same bytes as one that never
//! stopped, on the nominal environment and on the SIL's dispersed plant; chained phases
//! (`[finetune.then]`) are the hand-run chain of single phases, also when stopped between
//! them. One test in its own binary: torch's generator is global to the process.

// The toy config alone: no dataset is needed.
#[allow(dead_code)]
mod common;

use std::path::Path;

use common::{scratch_dir, toy_config};
use ground_core::env::batch::evaluate_batched;
use ground_core::env::{MdpEnv, Problem, Transfer};
use learn::config::{ExperimentConfig, FinetuneConfig};
use learn::eval::load_agent;
use learn::finetune::Objective;
use learn::finetune::{finetune, FinetuneRow};
use learn::phase::policy_batch;
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
    chained_phases_are_the_hand_run_chain();
    an_arrival_margin_counts_the_early_miss_in_the_evaluations();
    a_phase_ends_at_the_same_bytes_whatever_the_compute_threads();
}

/// A phase runs at its own `[finetune] threads`, so `[compute] threads` does not change its
/// checkpoints: the rendezvous-circular recipe's network from its shipped actor, 3 steps of 64
/// flights (at two torch threads the third step's checkpoint differed in its last bits).
fn a_phase_ends_at_the_same_bytes_whatever_the_compute_threads() {
    let dir = scratch_dir("finetune-threads");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let text = std::fs::read_to_string(root.join("configs/rendezvous-circular.toml")).unwrap();
    let mut config = ExperimentConfig::from_toml(&text).unwrap();
    config.finetune = FinetuneConfig {
        steps: 3,
        flights: 64,
        eval_every: 3,
        eval_episodes: 8,
        learning_rate: 3e-5,
        ..FinetuneConfig::default()
    };
    let start = root.join("models/rendezvous-circular/actor.safetensors");
    let mut run = |threads: i32| {
        config.compute.threads = threads;
        let out = dir.join(format!("compute-threads-{threads}"));
        finetune(&config, &out, &start).unwrap();
        bytes(&out.join("finetune/step-3.safetensors"))
    };
    let (one, two) = (run(1), run(2));
    assert!(one == two, "the phase's checkpoint depends on [compute] threads");
}

/// A toy config fine-tuning `steps` steps (flights on the SIL's dispersed plant when
/// `dispersed`), and an untrained actor file to start from in `dir`.
fn toy_finetuning(dir: &Path, steps: u64, dispersed: bool) -> (ExperimentConfig, std::path::PathBuf) {
    let mut config = toy_config(&dir.join("no-dataset"));
    if dispersed {
        // Dispersed flights are evaluated in the SIL loop: the onboard contract's network.
        config.sac.hidden = vec![256, 256];
    }
    config.finetune = FinetuneConfig {
        steps,
        flights: 4,
        eval_every: 4,
        eval_episodes: 8,
        // A fast learning rate: the toy actor starts untrained.
        learning_rate: 1e-3,
        dispersed,
        ..FinetuneConfig::default()
    };
    config.compute.threads = 1;
    tch::manual_seed(7);
    let start = dir.join("actor.safetensors");
    Sac::new(config.sac.clone(), 10, 3, tch::Device::Cpu)
        .save_flown_actor(&start)
        .unwrap();
    (config, start)
}

/// The shipped transfer-circular actor as the start (fine-tuning only reads it), at the
/// recipes' learning rate and with its network's widths: an untrained actor only learns to coast (under dispersions its
/// objective falls to coasting's, about 4.76 on the toy's flights, and stays), so a lower
/// objective from it would not show that the phase steers.
fn from_a_controller_that_arrives(config: &mut ExperimentConfig) -> std::path::PathBuf {
    config.sac.hidden = vec![256, 256];
    config.finetune.learning_rate = 3e-5;
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/transfer-circular/actor.safetensors")
}

fn lowers_and_resumes(dispersed: bool) {
    let dir = scratch_dir(if dispersed { "finetune-dispersed" } else { "finetune" });
    let (mut config, _) = toy_finetuning(&dir, 12, dispersed);
    let start = from_a_controller_that_arrives(&mut config);
    if !dispersed {
        // The shipped actor is nominal fine-tuning's own result at the default weight: weighed
        // ten times, the propellant moves the optimum away from it.
        config.finetune.propellant_weight = 0.3;
    }

    let straight = dir.join("straight");
    let summary = finetune(&config, &straight, &start).unwrap().remove(0);
    let rows = &summary.rows;
    assert_eq!(rows.iter().map(|r| r.step).collect::<Vec<_>>(), [0, 4, 8, 12]);
    let best = rows.iter().find(|r| r.step == summary.best_step).unwrap();
    assert!(
        best.objective < rows[0].objective,
        "dispersed {dispersed}: no evaluation below the start's objective: {rows:?}"
    );
    // Lowered by a controller that arrives, not by one that learned to coast: under
    // dispersions arriving as often, nominally (the propellant weighed more) burning less.
    assert!(rows[0].within_goal >= 0.9, "dispersed {dispersed}: {rows:?}");
    if dispersed {
        assert!(best.within_goal >= rows[0].within_goal, "{rows:?}");
    } else {
        assert!(
            best.summary.final_mass.mean > rows[0].summary.final_mass.mean,
            "{rows:?}"
        );
    }
    assert!(best.summary.final_mass.mean < 0.99, "dispersed {dispersed}: {rows:?}");

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

    // Asked to go on from another actor: refused with both named, the folder as it was. A
    // learner checkpoint whose flown actor is the start (step 0) goes on.
    tch::manual_seed(8);
    let other = dir.join("other-actor.safetensors");
    Sac::new(config.sac.clone(), 10, 3, tch::Device::Cpu)
        .save_flown_actor(&other)
        .unwrap();
    let folder = |run: &Path| -> Vec<(std::path::PathBuf, Vec<u8>)> {
        let mut files: Vec<_> = std::fs::read_dir(run.join("finetune"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_file())
            .map(|p| (p.clone(), bytes(&p)))
            .collect();
        files.sort();
        files
    };
    let before = folder(&stopped);
    let err = finetune(&config, &stopped, &other).unwrap_err().to_string();
    assert!(
        err.contains("began from another actor") && err.contains("other-actor.safetensors"),
        "{err}"
    );
    assert!(folder(&stopped) == before, "a refused resume changed the folder");
    finetune(&config, &stopped, &straight.join("finetune/step-0.safetensors")).unwrap();
    assert!(
        folder(&stopped) == before,
        "a finished phase gone on from its own start changed"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `[finetune]` then `[finetune.then]` in one run folder: each phase's files are those of the
/// single phase run by hand from the best actor of the one before (a nominal phase, then a
/// dispersed one), and a run stopped inside the second phase resumes to the same bytes.
fn chained_phases_are_the_hand_run_chain() {
    let dir = scratch_dir("finetune-chained");
    // The SIL's network for both phases (the dispersed phase flies it in the SIL loop); the
    // start file is the second call's, written over the first's.
    let (first, _) = toy_finetuning(&dir, 8, false);
    let (second, start) = toy_finetuning(&dir, 8, true);
    let mut first = ExperimentConfig {
        sac: second.sac.clone(),
        ..first
    };

    // By hand: two commands, the second from the first's best actor.
    let by_hand = [dir.join("hand-1"), dir.join("hand-2")];
    let one = finetune(&first, &by_hand[0], &start).unwrap();
    let two = finetune(&second, &by_hand[1], &one[0].best_actor).unwrap();

    first.finetune.then = Some(Box::new(second.finetune.clone()));
    let chained = dir.join("chained");
    let phases = finetune(&first, &chained, &start).unwrap();
    assert_eq!(phases.len(), 2);
    assert_eq!(
        phases[1].best_actor,
        chained.join("finetune/then/best-actor.safetensors")
    );
    assert!(phases[1].dispersed && !phases[0].dispersed);

    // Stopped at the second phase's step 4, then the full chain.
    let stopped = dir.join("stopped");
    let mut short = first.clone();
    short.finetune.then.as_mut().unwrap().steps = 4;
    finetune(&short, &stopped, &start).unwrap();
    finetune(&first, &stopped, &start).unwrap();

    for (phase, hand) in [("finetune", &one[0].folder), ("finetune/then", &two[0].folder)] {
        for file in ["step-8.safetensors", "best.safetensors", "best-actor.safetensors"] {
            let reference = bytes(&hand.join(file));
            assert!(
                bytes(&chained.join(phase).join(file)) == reference,
                "chained {phase}/{file} differs from the hand-run phase's"
            );
            assert!(
                bytes(&stopped.join(phase).join(file)) == reference,
                "{phase}/{file} differs after a resume inside the second phase"
            );
        }
    }
    // The second phase moved the actor: not two copies of one phase.
    assert!(bytes(&one[0].best_actor) != bytes(&two[0].best_actor));

    // The first phase's best changed under a begun second phase (here its step 4 put in
    // place): refused, with the second phase's folder named, rather than gone on from a start
    // the chain no longer has.
    std::fs::copy(
        chained.join("finetune/step-4.safetensors"),
        chained.join("finetune/best.safetensors"),
    )
    .unwrap();
    let err = finetune(&first, &chained, &start).unwrap_err().to_string();
    assert!(
        err.contains("finetune/then") && err.contains("use a new folder"),
        "{err}"
    );

    // A step checkpoint is a learner without an averaged copy: loaded under a config that
    // averages (the recipe's own, as `ground model export --checkpoint` loads it), it flies the
    // step's actor instead of being refused for a missing average.
    let step = chained.join("finetune/then/step-8.safetensors");
    let mut averaging = first.clone();
    averaging.sac.actor_averaging = 0.001;
    let mut plain = first.clone();
    plain.sac.actor_averaging = 0.0;
    let obs = [0.1f32; 10];
    assert_eq!(
        load_agent(&averaging, 10, &step).unwrap().act(&obs, 1),
        load_agent(&plain, 10, &step).unwrap().act(&obs, 1)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// With `arrival_margin = 2` the evaluations that pick the best judge what the steps minimise:
/// their objective exceeds the margin-free one, on the same flights of the same actor, by the
/// mean miss two cycles before the arrival, recomputed here from the flights' own states.
fn an_arrival_margin_counts_the_early_miss_in_the_evaluations() {
    let dir = scratch_dir("finetune-margin");
    let (mut config, _) = toy_finetuning(&dir, 4, false);
    let start = from_a_controller_that_arrives(&mut config);
    let start_objective = |margin: u32| {
        let mut phase = config.clone();
        phase.finetune.arrival_margin = margin;
        let summary = finetune(&phase, &dir.join(format!("margin-{margin}")), &start)
            .unwrap()
            .remove(0);
        assert_eq!(summary.rows[0].step, 0);
        summary.rows[0].objective
    };
    let (on_time, early) = (start_objective(0), start_objective(2));

    let family = config.planar_family("the test").unwrap();
    let scenarios: Vec<_> = (0..config.finetune.eval_episodes)
        .map(|i| family.draw(config.seeds.evaluation, i))
        .collect();
    let agent = load_agent(&config, 10, &start).unwrap();
    let flown =
        evaluate_batched::<MdpEnv<Transfer>, _>(&config.env, &scenarios, |o| policy_batch(&agent, o), true).unwrap();
    let miss_only = Objective {
        propellant_weight: 0.0,
        ..Objective::of(&config)
    };
    let early_misses: Vec<f64> = flown
        .iter()
        .map(|o| {
            let scenario = &scenarios[o.episode];
            let e = scenario.steps - 2;
            let state = o.trajectory.as_ref().unwrap()[e as usize].state;
            let features = Transfer::features(scenario, &state, e).unwrap();
            miss_only.value(&Transfer::residuals(&features), 1.0)
        })
        .collect();
    let mean = early_misses.iter().sum::<f64>() / early_misses.len() as f64;
    assert!(mean > 0.0, "{early_misses:?}");
    assert!(
        ((early - on_time) - mean).abs() < 1e-9,
        "margin 2: {early}, on time: {on_time}, mean early miss {mean}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
