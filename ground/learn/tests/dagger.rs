//! `ground train dagger` at toy scale, in its own test binary: it compares weights byte for byte, and
//! torch's global random stream is shared by every test of a process.

mod common;

use std::path::Path;

use common::{scratch_dir, toy_config, toy_dataset};
use learn::dagger::{dagger, load_relabels, RoundRow};
use learn::error::ExperimentError;
use learn::pretrain::pretrain;
use learn::sac::agent::Sac;
use shared::scenario::ScenarioKind;
use tch::Device;

/// `ground train dagger` at toy scale: rounds stopped and resumed (between rounds, and between a
/// round's relabels and its updates) end with the same learner, byte for byte, as rounds run
/// without a stop; saved relabels are reused, not solved again; a corrupt one is refused; another
/// run goes on from them with a wider actor.
#[test]
fn dagger_rounds_resume_to_the_same_learner_and_refuse_corrupt_relabels() {
    let dir = scratch_dir("dagger");
    let dataset = toy_dataset(&dir);
    let mut config = toy_config(&dataset);
    // Relabels solved to the toy dataset's eps, so they are quick.
    config.generate.final_eps = 0.3;
    config.dagger.episodes = 3;
    config.dagger.fractions = vec![0.5];
    config.dagger.updates = 30;
    config.dagger.score_episodes = 4;
    config.dagger.rounds = 2;
    let pre = dir.join("pre");
    pretrain(&config, &dir, &pre).unwrap();
    let start = pre.join("pretrain/best.safetensors");

    // Two rounds in one invocation.
    let straight = dir.join("straight");
    let whole = dagger(&config, &dir, &straight, &start, None).unwrap();
    let rounds: Vec<u64> = whole.rows.iter().map(|r| r.round).collect();
    assert_eq!(rounds, vec![0, 1, 2]);
    let demos: usize = (0..2)
        .map(|i| ScenarioKind::TransferCircular.draw(9, i).steps as usize)
        .sum();
    let mut buffer = demos as u64;
    for row in &whole.rows[1..] {
        assert_eq!(row.relabels_attempted, 3, "one relabel per flown episode");
        assert!(row.relabels_converged <= row.relabels_attempted);
        let relabels = load_relabels(
            &straight.join(format!("dagger/relabels-{}.ltrl", row.round)),
            row.round,
            10,
            3,
        )
        .unwrap();
        assert_eq!(relabels.tuples.len() as u64, row.tuples_added);
        assert_eq!(relabels.tuples.demonstration_count(), relabels.tuples.len());
        buffer += row.tuples_added;
        assert_eq!(
            row.buffer, buffer,
            "the buffer keeps the demonstrations and every round's relabels"
        );
        assert_eq!(row.updates, 30 * row.round);
    }
    assert!(
        whole.rows.iter().map(|r| r.relabels_converged).sum::<u64>() > 0,
        "no relabel converged: the test shows nothing"
    );
    let weights =
        |run: &Path, round: u64| std::fs::read(run.join(format!("dagger/round-{round}.safetensors"))).unwrap();

    // One round, then the second in a later invocation.
    let resumed = dir.join("resumed");
    config.dagger.rounds = 1;
    dagger(&config, &dir, &resumed, &start, None).unwrap();
    config.dagger.rounds = 2;
    let later = dagger(&config, &dir, &resumed, &start, None).unwrap();
    assert_eq!(later.rows.len(), 3);
    assert_eq!(weights(&resumed, 2), weights(&straight, 2));

    // Stopped after round 2's relabels were saved, before its updates ended: the relabels are
    // reused (the file is not written again) and the learner is the same.
    let relabels_2 = straight.join("dagger/relabels-2.ltrl");
    let written = std::fs::metadata(&relabels_2).unwrap().modified().unwrap();
    let expected = weights(&straight, 2);
    std::fs::remove_file(straight.join("dagger/round-2.safetensors")).unwrap();
    let again = dagger(&config, &dir, &straight, &start, None).unwrap();
    assert_eq!(weights(&straight, 2), expected);
    assert_eq!(std::fs::metadata(&relabels_2).unwrap().modified().unwrap(), written);
    let without_seconds = |rows: &[RoundRow]| rows.iter().map(|r| RoundRow { seconds: 0.0, ..*r }).collect::<Vec<_>>();
    assert_eq!(without_seconds(&again.rows), without_seconds(&whole.rows));

    // Another run goes on from the two rounds with a wider actor: their relabels are its first
    // rounds, its start (round 2) flies as round 2's learner did, and its round 3 relabels round
    // 3's scenarios.
    let mut narrow = Sac::new(config.sac_for(true), 10, 3, Device::Cpu);
    narrow.load(&straight.join("dagger/round-2.safetensors")).unwrap();
    let actor = dir.join("actor-2.safetensors");
    narrow.save_flown_actor(&actor).unwrap();
    let mut wide = config.clone();
    wide.sac.hidden = vec![48, 40];
    wide.dagger.rounds = 3;
    let wider = dir.join("wider");
    let rows = dagger(&wide, &dir, &wider, &actor, Some(&straight)).unwrap().rows;
    assert_eq!(rows.iter().map(|r| r.round).collect::<Vec<_>>(), vec![2, 3]);
    let (start_row, round_2) = (&rows[0], &whole.rows[2]);
    assert_eq!(
        start_row.buffer, round_2.buffer,
        "the buffer holds both rounds' relabels"
    );
    assert_eq!(start_row.within_goal, round_2.within_goal);
    let (p50, p50_narrow) = (
        start_row.summary.terminal_position.p50,
        round_2.summary.terminal_position.p50,
    );
    assert!(
        (p50 - p50_narrow).abs() <= 1e-5 * p50_narrow,
        "{p50} against {p50_narrow}"
    );
    for round in 1..=2 {
        let file = |run: &Path| std::fs::read(run.join(format!("dagger/relabels-{round}.ltrl"))).unwrap();
        assert_eq!(file(&wider), file(&straight));
    }
    assert_eq!(rows[1].relabels_attempted, 3);
    assert_eq!(rows[1].buffer, round_2.buffer + rows[1].tuples_added);
    assert_eq!(rows[1].updates, 30);
    // Resumed: nothing left to do, the same rows.
    let again = dagger(&wide, &dir, &wider, &actor, Some(&straight)).unwrap().rows;
    assert_eq!(without_seconds(&again), without_seconds(&rows));
    // Relabels of other scenarios (another training seed): refused before any work.
    let mut reseeded = wide.clone();
    reseeded.seeds.train += 1;
    let err = dagger(&reseeded, &dir, &dir.join("reseeded"), &actor, Some(&straight)).unwrap_err();
    assert!(err.to_string().contains("another problem"), "{err}");
    assert!(!dir.join("reseeded").exists(), "{err}");

    // A truncated relabels file is refused, not half-read.
    let bytes = std::fs::read(&relabels_2).unwrap();
    std::fs::write(&relabels_2, &bytes[..bytes.len() / 2]).unwrap();
    std::fs::remove_file(straight.join("dagger/round-2.safetensors")).unwrap();
    let err = dagger(&config, &dir, &straight, &start, None).unwrap_err();
    assert!(matches!(err, ExperimentError::Mismatch(_)), "{err}");
    assert!(err.to_string().contains("relabels-2.ltrl"), "{err}");

    // Relabelling only flights that re-solve: of the 40 flights, one chunk of 32 is probed at
    // the earliest fraction (the quota of 2 is met there), and the later fraction is solved only
    // for the k probes that converged, so attempted = 32 + k and at least those k converged.
    let mut probed = config.clone();
    probed.dagger.solvable_only = true;
    probed.dagger.rounds = 1;
    probed.dagger.episodes = 2;
    probed.dagger.candidates = Some(40);
    probed.dagger.fractions = vec![0.6, 0.3];
    let rows = dagger(&probed, &dir, &dir.join("probed"), &start, None).unwrap().rows;
    let (attempted, converged) = (rows[1].relabels_attempted, rows[1].relabels_converged);
    let kept = attempted - 32;
    assert!((2..=32).contains(&kept), "attempted {attempted}, converged {converged}");
    assert!(
        (kept..=2 * kept).contains(&converged),
        "attempted {attempted}, converged {converged}"
    );

    // A config of another problem than the demonstrations: refused before any work.
    let mut other = config.clone();
    other.family = shared::mission::SpatialFamily::planar(ScenarioKind::RendezvousCircular.family());
    let err = dagger(&other, &dir, &dir.join("rendezvous"), &start, None).unwrap_err();
    assert!(!dir.join("rendezvous").exists(), "{err}");
    // Relabels arriving early among demonstrations on time: refused before any work.
    let mut early = config.clone();
    early.generate.arrival_margin = 2;
    let err = dagger(&early, &dir, &dir.join("early"), &start, None).unwrap_err();
    assert!(
        matches!(err, ExperimentError::Mismatch(_)) && err.to_string().contains("arrival_margin"),
        "{err}"
    );
    assert!(!dir.join("early").exists(), "{err}");
    // Demonstrations solved for the thesis's spacecraft, a config flying another: refused before
    // any work, with the command that solves them for the config's.
    let mut other_craft = config.clone();
    other_craft.env.spacecraft = shared::spacecraft::Spacecraft {
        max_thrust_n: 0.5,
        isp_s: 2000.0,
        initial_mass_kg: 1000.0,
    };
    let err = dagger(&other_craft, &dir, &dir.join("other-craft"), &start, None).unwrap_err();
    assert!(
        matches!(err, ExperimentError::Mismatch(_))
            && err.to_string().contains("another spacecraft")
            && err.to_string().contains("--thrust-n 0.5 --isp-s 2000 --mass-kg 1000"),
        "{err}"
    );
    assert!(!dir.join("other-craft").exists(), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
