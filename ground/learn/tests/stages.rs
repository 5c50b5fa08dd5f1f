//! A recipe's stages at toy scale, in their own test binary (it compares weights byte for byte,
//! and torch's global random stream is shared by every test of a process).

// The toy datasets of the other tests are not used here: the recipe solves its own.
#[allow(dead_code)]
mod common;

use std::path::Path;

use common::{scratch_dir, toy_config};
use learn::config::ExperimentConfig;
use learn::dagger::dagger;
use learn::dataset::demonstrations;
use learn::eval::load_agent;
use learn::pipeline::run_main_job;

fn bytes(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `ground run` of a recipe with two stages (its own demonstrations arriving a step early and
/// cloning-only rounds from the recipe's best actor; then rounds that go on from the last one
/// with its relabels) gives, byte for byte, what the chain of commands it replaces gives: the
/// new dataset by `ground data generate`, rounds by `ground train dagger --from` the shipped
/// actor, then `ground train dagger --from round-N --relabels-from`. The shipped model is the
/// last stage's best, flown with its config, and its card says where it came from.
#[test]
fn a_staged_recipe_equals_the_chain_of_commands_it_replaces() {
    let dir = scratch_dir("stages");
    let mut base = toy_config(&dir.join("unused"));
    base.pretrain.dataset = None;
    base.generate.count = 2;
    base.generate.seed = 9;
    base.generate.final_eps = 0.3;
    // The onboard contract's actor, so the export and SIL stages can fly it.
    base.sac.hidden = vec![256, 256];
    base.sil.episodes = 4;
    base.dagger.rounds = 1;
    base.dagger.episodes = 2;
    base.dagger.fractions = vec![0.5];
    base.dagger.updates = 20;
    base.dagger.score_episodes = 4;
    let stages = r#"
[[stage]]
name = "margin"
start = "best-actor"
generate = { arrival_margin = 1 }
dagger = { rounds = 2, cloning_only = true }

[[stage]]
name = "near"
start = "last"
inherit_relabels = true
dagger = { rounds = 3, max_miss = 1000.0 }
sil = { lookahead = { accuracy_floor = 0.5 } }
"#;
    let recipe = ExperimentConfig::from_toml(&format!("{}{stages}", base.to_toml())).unwrap();
    let staged = recipe.staged().unwrap();
    let run = dir.join("run");
    let job = run_main_job(&recipe, &run).unwrap();

    // The chain by hand, from the recipe's own rounds' best learner.
    let chain = dir.join("chain");
    let mut margin = staged[0].clone();
    let (data, _) = demonstrations(&margin, &chain.join("dataset")).unwrap();
    margin.pretrain.dataset = Some(chain.join("dataset"));
    let actor = chain.join("actor.safetensors");
    let best = run.join("dagger/best.safetensors");
    load_agent(&base, 10, &best).unwrap().save_flown_actor(&actor).unwrap();
    dagger(&margin, &chain, &chain.join("margin"), &actor, None).unwrap();
    let mut near = staged[1].clone();
    near.pretrain.dataset = margin.pretrain.dataset.clone();
    let last_margin = chain.join("margin/dagger/round-2.safetensors");
    let near_rounds = dagger(
        &near,
        &chain,
        &chain.join("near"),
        &last_margin,
        Some(&chain.join("margin")),
    )
    .unwrap();

    // The same trajectories (the files also hold each solve's wall time).
    let read = |dir: &Path| ground_core::generate::read_dataset(&dir.join("dataset.ltds")).unwrap();
    let difference = ground_core::generate::trajectory_difference(
        &read(&run.join("stages/margin/dataset")),
        &read(&chain.join("dataset")),
    );
    assert_eq!(difference, None);
    for (stage, round) in [("margin", 0), ("margin", 1), ("margin", 2), ("near", 2), ("near", 3)] {
        let file = format!("dagger/round-{round}.safetensors");
        assert!(
            bytes(&run.join("stages").join(stage).join(&file)) == bytes(&chain.join(stage).join(&file)),
            "{stage} {file} differ"
        );
    }
    for round in 1..=3 {
        let file = format!("dagger/relabels-{round}.ltrl");
        assert!(
            bytes(&run.join("stages/near").join(&file)) == bytes(&chain.join("near").join(&file)),
            "{file} differ"
        );
    }
    // The stages ran what the recipe says: rounds 1-2 of their own, then round 3 after the
    // inherited ones.
    let rounds: Vec<Vec<u64>> = job
        .stages
        .iter()
        .map(|s| s.rounds.rows.iter().map(|r| r.round).collect())
        .collect();
    assert_eq!(rounds, vec![vec![0, 1, 2], vec![2, 3]]);
    assert_eq!(job.stages[0].new_dataset.as_ref().unwrap().records, data.records);
    assert!(job.stages[1].new_dataset.is_none());
    // The same scores, round by round (each run took its own time).
    let untimed = |rows: &[learn::dagger::RoundRow]| {
        rows.iter()
            .map(|r| learn::dagger::RoundRow { seconds: 0.0, ..*r })
            .collect::<Vec<_>>()
    };
    assert_eq!(untimed(&job.stages[1].rounds.rows), untimed(&near_rounds.rows));

    // The shipped learner is the last stage's best, flown with the last stage's config.
    assert_eq!(
        job.monte_carlo.checkpoint,
        run.join("stages/near/dagger/best.safetensors")
    );
    let model = learn::model::open_model(&run.join("model")).unwrap();
    assert_eq!(model.card.rounds, Some((3, near_rounds.best_round)));
    assert_eq!(model.config.sil.lookahead, staged[1].sil.lookahead);
    assert!(model.card.lookahead.is_some(), "the last stage's [sil] lookahead flew");
    assert_eq!(model.card.notes.len(), 2);
    assert!(
        model.card.notes[0].starts_with("stage margin: rounds 1-2"),
        "{:?}",
        model.card.notes
    );
    assert!(model.card.notes[1].contains("rounds 3-3") && model.card.notes[1].contains("rounds 1-2"));
    // Run again on the finished folder, every stage resumes to what it had.
    let again = run_main_job(&recipe, &run).unwrap();
    for (a, b) in again.stages.iter().zip(&job.stages) {
        assert_eq!(untimed(&a.rounds.rows), untimed(&b.rounds.rows));
    }
    assert_eq!(again.monte_carlo.policy, job.monte_carlo.policy);
    let report = std::fs::read_to_string(&job.report).unwrap();
    assert!(
        report.contains("## Stage margin") && report.contains("## Stage near"),
        "{report}"
    );
    assert_eq!(learn::report::broken_links(&job.report), Vec::<String>::new());
    std::fs::remove_dir_all(&dir).unwrap();
}
