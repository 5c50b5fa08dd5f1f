//! `ground train dagger` on rendezvous at toy scale, in its own test binary (torch's global random
//! stream is shared by every test of a process, and the resumption check compares weights).

mod common;

use common::{scratch_dir, toy_config, toy_dataset_of};
use learn::dagger::{dagger, load_relabels};
use learn::pretrain::pretrain;
use shared::scenario::ScenarioKind;

/// Rendezvous rounds relabel with the body where it is at the relabelled step: the relabels
/// are 22-feature tuples, some converge, and a run stopped after its first round and resumed
/// ends with the learner of a run that never stopped.
#[test]
fn rendezvous_rounds_relabel_and_resume_to_the_same_learner() {
    let dir = scratch_dir("dagger-rendezvous");
    let dataset = toy_dataset_of(&dir, ScenarioKind::RendezvousCircular);
    let mut config = toy_config(&dataset);
    config.family = shared::mission::SpatialFamily::planar(ScenarioKind::RendezvousCircular.family());
    config.generate.final_eps = 0.3;
    config.dagger.episodes = 4;
    config.dagger.fractions = vec![0.5, 0.75];
    config.dagger.updates = 30;
    config.dagger.score_episodes = 4;
    config.dagger.rounds = 2;
    let pre = dir.join("pre");
    pretrain(&config, &dir, &pre).unwrap();
    let start = pre.join("pretrain/best.safetensors");

    let straight = dir.join("straight");
    let whole = dagger(&config, &dir, &straight, &start, None).unwrap();
    assert_eq!(whole.rows.len(), 3);
    for row in &whole.rows[1..] {
        assert_eq!(row.relabels_attempted, 8, "two relabels per flown episode");
        let relabels = load_relabels(
            &straight.join(format!("dagger/relabels-{}.ltrl", row.round)),
            row.round,
            22,
            3,
        )
        .unwrap();
        assert_eq!(relabels.tuples.len() as u64, row.tuples_added);
    }
    assert!(
        whole.rows.iter().map(|r| r.relabels_converged).sum::<u64>() > 0,
        "no rendezvous relabel converged: the test shows nothing"
    );
    // The relabels of a rendezvous run are not transfer tuples.
    assert!(load_relabels(&straight.join("dagger/relabels-1.ltrl"), 1, 10, 3).is_err());

    let resumed = dir.join("resumed");
    config.dagger.rounds = 1;
    dagger(&config, &dir, &resumed, &start, None).unwrap();
    config.dagger.rounds = 2;
    dagger(&config, &dir, &resumed, &start, None).unwrap();
    let weights = |run: &std::path::Path| std::fs::read(run.join("dagger/round-2.safetensors")).unwrap();
    assert_eq!(weights(&resumed), weights(&straight));

    // A transfer learner cannot start rendezvous rounds: refused before the run folder exists.
    let transfer_dir = dir.join("transfer");
    std::fs::create_dir_all(&transfer_dir).unwrap();
    let transfer_dataset = common::toy_dataset(&transfer_dir);
    let transfer_config = toy_config(&transfer_dataset);
    pretrain(&transfer_config, &transfer_dir, &transfer_dir.join("pre")).unwrap();
    let err = dagger(
        &config,
        &dir,
        &dir.join("mixed"),
        &transfer_dir.join("pre/pretrain/best.safetensors"),
        None,
    )
    .unwrap_err();
    assert!(!dir.join("mixed").exists(), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
