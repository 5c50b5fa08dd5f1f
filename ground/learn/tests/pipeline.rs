//! The learning pipeline at toy scale through the same code as the CLI: a tiny dataset,
//! pretraining, RL from the pretrained model (interrupted and resumed), Monte Carlo evaluation.
//! Checks that every artifact exists, loads and is consistent.

mod common;

use std::path::{Path, PathBuf};

use common::{scratch_dir, toy_config, toy_dataset};
use learn::config::{ExperimentConfig, FinetuneConfig};
use learn::error::ExperimentError;
use learn::eval::{monte_carlo, Optima};
use learn::phase::PhaseState;
use learn::pretrain::pretrain;
use learn::rl::{train, Start};
use learn::sac::agent::{read_checked_safetensors, write_checked_safetensors, CheckpointError, Sac};
use shared::scenario::ScenarioKind;

fn bytes(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The model card's file checksum (CRC-32C).
fn card_checksum(bytes: &[u8]) -> String {
    format!("{:08x}", crc::Crc::<u32>::new(&crc::CRC_32_ISCSI).checksum(bytes))
}

/// `path` (absolute) written relative to the current directory: "../" up to the root, then down.
fn relative_to_cwd(path: &Path) -> PathBuf {
    let cwd = std::env::current_dir().unwrap();
    let mut rel = PathBuf::new();
    for _ in cwd.components().skip(1) {
        rel.push("..");
    }
    rel.join(path.strip_prefix("/").unwrap())
}

fn state(path: &Path) -> PhaseState {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

#[test]
fn pretrain_train_resume_and_evaluate_at_toy_scale() {
    let dir = scratch_dir("pipeline");
    let dataset = toy_dataset(&dir);
    let mut config = toy_config(&dataset);
    let run = dir.join("run");

    // Pretraining: demonstrations of both records, evaluations at 0, 40, 80, 120 updates.
    let pre = pretrain(&config, &dir, &run).unwrap();
    assert_eq!(pre.updates, 120);
    assert_eq!(pre.demonstration_records, 2);
    let steps: usize = (0..2)
        .map(|i| ScenarioKind::TransferCircular.draw(9, i).steps as usize)
        .sum();
    assert_eq!(
        pre.demonstration_tuples, steps,
        "one tuple per 14-day step of each record"
    );
    let pre_state = state(&run.join("pretrain/state.json"));
    let eval_updates: Vec<u64> = pre_state.evaluations.iter().map(|r| r.updates).collect();
    assert_eq!(eval_updates, vec![0, 40, 80, 120]);
    let best = pre.best.unwrap();
    let best_reward = pre_state
        .evaluations
        .iter()
        .map(|r| r.summary.total_reward.mean)
        .fold(f64::NEG_INFINITY, f64::max);
    assert_eq!(
        best.summary.total_reward.mean, best_reward,
        "the best evaluation is the one kept"
    );
    for file in [
        "best.safetensors",
        "last.safetensors",
        "replay.ltrb",
        "eval.csv",
        "updates.csv",
        "state.json",
    ] {
        assert!(run.join("pretrain").join(file).is_file(), "pretrain/{file} missing");
    }
    let csv = std::fs::read_to_string(run.join("pretrain/eval.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 4);

    // RL from the pretrained model, interrupted after 100 steps and resumed to 150.
    config.train.env_steps = 100;
    let first = train(&config, &run, Start::Pretrained).unwrap();
    assert_eq!(first.env_steps, 100);
    assert_eq!(
        first.demonstration_tuples, steps,
        "demonstrations stay in the RL buffer"
    );
    config.train.env_steps = 150;
    let resumed = train(&config, &run, Start::Pretrained).unwrap();
    assert_eq!(resumed.env_steps, 150);
    let rl_state = state(&run.join("train-pretrained/state.json"));
    let eval_steps: Vec<u64> = rl_state.evaluations.iter().map(|r| r.env_steps).collect();
    assert_eq!(eval_steps, vec![0, 50, 100, 150]);
    // Updates: one per step once the buffer is past warm-up (60 steps), in both invocations.
    assert_eq!(rl_state.updates, 150 - 60 + 1);

    // The best RL checkpoint loads into a fresh agent with the config's shapes.
    let best = run.join("train-pretrained/best.safetensors");
    let mut agent = Sac::new(config.sac.clone(), 10, 3, tch::Device::Cpu);
    agent.load(&best).unwrap();

    // Monte Carlo: every episode completes, baselines on the same scenarios, files written.
    let mc_dir = run.join("mc");
    let report = monte_carlo(&config, &best, &mc_dir, None, Optima::Solve(None)).unwrap();
    assert_eq!(report.episodes, 16);
    assert_eq!(report.policy.completed, 16);
    assert_eq!(report.zero_thrust.completed, 16);
    // Zero thrust keeps all the mass: the final mass statistics say so exactly.
    assert_eq!(report.zero_thrust.final_mass.min, 1.0);
    for file in ["mc.csv", "summary.json", "optimality-gap.csv"] {
        assert!(mc_dir.join(file).is_file(), "mc/{file} missing");
    }
    assert_eq!(
        std::fs::read_to_string(mc_dir.join("mc.csv")).unwrap().lines().count(),
        17
    );

    // The checkpoint names its family: a config of another family of the same problem refuses
    // it where it is used, both named.
    let mut transfer_hard = config.clone();
    transfer_hard.family = shared::mission::SpatialFamily::planar(ScenarioKind::TransferHard.family());
    match monte_carlo(
        &transfer_hard,
        &best,
        &dir.join("mc-other"),
        Some(2),
        Optima::Solve(Some(0)),
    ) {
        Err(e) => {
            let why = e.to_string();
            assert!(
                why.contains("transfer-circular") && why.contains("transfer-hard"),
                "{why}"
            );
        }
        Ok(_) => panic!("a checkpoint of another family was flown"),
    }
    assert!(!dir.join("mc-other").exists());

    // A config of another problem is refused on the same run folder.
    let other = ExperimentConfig::from_toml("scenario = \"rendezvous-circular\"").unwrap();
    assert!(matches!(
        train(&other, &run, Start::Scratch),
        Err(ExperimentError::Mismatch(_))
    ));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_missing_dataset_is_refused_before_any_work() {
    let dir = scratch_dir("missing");
    let config = toy_config(&dir.join("no-such-dataset"));
    let err = pretrain(&config, &dir, &dir.join("run")).unwrap_err();
    assert!(matches!(err, ExperimentError::Config(_)), "{err}");
    assert!(!dir.join("run/pretrain").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The main job (`ground run`) end to end at toy scale: the same stages as the default run,
/// and a report whose every link resolves.
#[test]
fn main_job_writes_a_report_whose_links_resolve() {
    use learn::pipeline::run_main_job;
    use learn::report::broken_links;
    let dir = scratch_dir("main-job");
    let mut config = toy_config(&dir.join("unused"));
    config.pretrain.dataset = None;
    config.generate.count = 2;
    config.generate.seed = 9;
    config.generate.final_eps = 0.3;
    config.generate.crosscheck = true;
    // The onboard contract's actor (10-256-256-3), so the export and SIL stages can fly it.
    config.sac.hidden = vec![256, 256];
    config.sil.episodes = 8;
    // One relabelling round, toy-sized.
    config.dagger.rounds = 1;
    config.dagger.episodes = 2;
    config.dagger.fractions = vec![0.5];
    config.dagger.updates = 20;
    config.dagger.score_episodes = 4;
    // Fine-tuning after it in two phases, toy-sized: nominal flights, then dispersed ones.
    config.finetune = FinetuneConfig {
        steps: 2,
        flights: 2,
        eval_every: 1,
        eval_episodes: 2,
        ..FinetuneConfig::default()
    };
    config.finetune.then = Some(Box::new(FinetuneConfig {
        dispersed: true,
        ..config.finetune.clone()
    }));
    // A relative run folder, as `ground run --out runs/quick` gives (the dataset path must not be
    // resolved against it twice).
    let run = relative_to_cwd(&dir.join("run"));
    assert!(run.is_relative());
    let job = run_main_job(&config, &run).unwrap();
    assert_eq!(job.dataset.records, 2);
    // The records were checked against the direct transcription before pretraining.
    let check = job.crosscheck.as_ref().unwrap();
    assert_eq!(
        (check.count, check.checked),
        (2, job.dataset.converged as u64),
        "{check:?}"
    );
    assert!(run.join("dataset/crosscheck.json").is_file());
    assert_eq!(job.pretrain.updates, 120);
    assert_eq!(job.train.env_steps, 150);
    assert_eq!(job.monte_carlo.episodes, 16);
    let text = std::fs::read_to_string(&job.report).unwrap();
    assert!(text.contains("| zero thrust |"), "{text}");
    assert!(text.contains("Checked against the direct transcription"), "{text}");
    assert_eq!(broken_links(&job.report), Vec::<String>::new());
    for figure in [
        "pretrain/critic-loss.svg",
        "train-pretrained/eval-reward.svg",
        "mc/histograms.svg",
        "mc/trajectories.svg",
        "export/transfer-f32.blob",
        "export/transfer-int8.blob",
        "export/export.json",
        "sil-f32/sil.json",
        "sil-int8/histograms.svg",
        "sil-int8/trajectories.svg",
    ] {
        assert!(run.join(figure).is_file(), "{figure} not drawn");
    }
    // The blobs load onboard and SIL flew them: f32 and int8, every flight completed.
    for (sil, name) in job.sil.iter().zip(["f32", "int8"]) {
        assert_eq!(sil.controller, name);
        assert_eq!(sil.monte_carlo.policy.completed, 8);
    }
    assert!(job.export.f32.action_error.max <= 1e-5);
    assert!(text.contains("SIL with dispersions"), "{text}");
    // The relabelling round ran from RL's best model, and its best is what the Monte Carlo
    // evaluated.
    let rounds = job.dagger.as_ref().unwrap();
    assert_eq!(rounds.rows.iter().map(|r| r.round).collect::<Vec<_>>(), vec![0, 1]);
    assert!(text.contains("## Relabelling rounds"), "{text}");
    assert!(run.join("dagger/rounds.csv").is_file());
    // The fine-tuning's phases ran from the round's best, the second from the first's best
    // actor, and the second's best actor is what the Monte Carlo evaluated and the run ships.
    let phases: Vec<(PathBuf, bool)> = job.finetune.iter().map(|f| (f.folder.clone(), f.dispersed)).collect();
    assert_eq!(
        phases,
        [(run.join("finetune"), false), (run.join("finetune/then"), true)]
    );
    assert_eq!(
        bytes(&run.join("finetune/then/start-actor.safetensors")),
        bytes(&run.join("finetune/best-actor.safetensors"))
    );
    assert_eq!(
        job.monte_carlo.checkpoint,
        run.join("finetune/then/best-actor.safetensors")
    );
    assert!(text.contains("## Fine-tuning through the dynamics"), "{text}");
    assert!(text.contains("](finetune/then/steps.csv)"), "{text}");
    // The model folder opens, and its actor file flies exactly as the checkpoint it came from.
    let model_dir = run.join("model");
    let model = learn::model::open_model(&model_dir).unwrap();
    assert_eq!(model.card.rounds, Some((1, rounds.best_round)));
    let fine_tuned: Vec<&String> = model
        .card
        .notes
        .iter()
        .filter(|n| n.starts_with("fine-tuned through the dynamics"))
        .collect();
    assert_eq!(fine_tuned.len(), 2, "{:?}", model.card.notes);
    assert!(fine_tuned[1].contains("on dispersed flights"), "{fine_tuned:?}");
    // The actor as ONNX beside the blobs, bound by the card like them.
    assert!(model.card.files.contains_key(learn::model::ONNX_FILE));
    assert!(run.join("export/actor.onnx").is_file());
    assert_eq!(model.card.sil.len(), 2);
    let created = model.card.created.as_bytes();
    assert!(
        created.len() == 10 && created[4] == b'-' && created[7] == b'-',
        "card date {}",
        model.card.created
    );
    let from_actor = monte_carlo(
        &config,
        &model.actor(),
        &dir.join("mc-actor"),
        None,
        Optima::Solve(Some(0)),
    )
    .unwrap();
    assert_eq!(from_actor.policy, job.monte_carlo.policy);
    assert_eq!(
        model.card.monte_carlo.share_within(0.01),
        Some(job.monte_carlo.within_accuracy_goal)
    );
    // Files that disagree with the card, or with each other, are refused.
    let copy = |name: &str| {
        let to = dir.join(name);
        let _ = std::fs::remove_dir_all(&to);
        std::fs::create_dir_all(&to).unwrap();
        for e in std::fs::read_dir(&model_dir).unwrap().flatten() {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
        to
    };
    let flipped = copy("model-flipped");
    let int8 = flipped.join("transfer-int8.blob");
    let mut bytes = std::fs::read(&int8).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    std::fs::write(&int8, bytes).unwrap();
    assert!(matches!(
        learn::model::open_model(&flipped),
        Err(learn::model::ModelError::Checksum { .. })
    ));
    // A card.md that no longer says what card.json says.
    let edited = copy("model-edited-card");
    let mut text = std::fs::read_to_string(edited.join("card.md")).unwrap();
    text = text.replacen("within 0.01", "within 0.001", 1);
    std::fs::write(edited.join("card.md"), text).unwrap();
    assert!(matches!(
        learn::model::open_model(&edited),
        Err(learn::model::ModelError::MarkdownDisagrees { .. })
    ));
    // A valid int8 blob of the same layout but other weights (its own trailer CRC-32 made right
    // again): the whole file's CRC-32 would not change, the card's checksum must.
    let other_int8 = copy("model-other-int8");
    let int8 = other_int8.join("transfer-int8.blob");
    let mut bytes = std::fs::read(&int8).unwrap();
    let (header, trailer) = (shared::blob::HEADER_LEN, bytes.len() - shared::blob::TRAILER_LEN);
    bytes[(header + trailer) / 2] ^= 1;
    let payload_crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&bytes[header..trailer]);
    bytes[trailer..].copy_from_slice(&payload_crc.to_le_bytes());
    assert!(
        shared::blob::decode(&bytes).is_ok(),
        "the altered blob is still a valid blob"
    );
    std::fs::write(&int8, bytes).unwrap();
    assert!(matches!(
        learn::model::open_model(&other_int8),
        Err(learn::model::ModelError::Checksum { .. })
    ));
    // Another actor under a card rewritten to match it: the f32 blob no longer holds its weights.
    let swapped = copy("model-swapped");
    tch::manual_seed(77);
    let other = Sac::new(config.sac.clone(), 10, 3, tch::Device::Cpu);
    other.save_flown_actor(&swapped.join("actor.safetensors")).unwrap();
    let mut card = model.card.clone();
    let crc = card_checksum(&std::fs::read(swapped.join("actor.safetensors")).unwrap());
    card.files.insert("actor.safetensors".into(), crc);
    let sealed = |card: &learn::model::ModelCard| {
        ground_core::model_files::sealed_card_text(&serde_json::to_value(card).unwrap()).unwrap()
    };
    std::fs::write(swapped.join("card.json"), sealed(&card)).unwrap();
    assert!(matches!(
        learn::model::open_model(&swapped),
        Err(learn::model::ModelError::BlobDisagrees { .. })
    ));
    // A card.json edited by hand: its config (the thrust it flies with) or a figure.
    let hand_edited = copy("model-hand-edited");
    let card_text = std::fs::read_to_string(hand_edited.join("card.json")).unwrap();
    let thrust = format!("max_thrust_n = {}", config.env.spacecraft.max_thrust_n);
    let completed = format!("\"completed\": {}", model.card.monte_carlo.completed);
    for (from, to) in [
        (thrust.clone(), "max_thrust_n = 2.5".to_string()),
        (completed.clone(), "\"completed\": 1".to_string()),
    ] {
        assert!(card_text.contains(&from), "{from}");
        std::fs::write(hand_edited.join("card.json"), card_text.replacen(&from, &to, 1)).unwrap();
        match learn::model::open_model(&hand_edited) {
            Err(e @ learn::model::ModelError::CardEdited(_)) => {
                assert!(e.to_string().contains("changed after it was written"), "{e}")
            }
            other => panic!("{from} -> {to}: {other:?}"),
        }
    }
    // A card of the unsealed layout is refused by readers, and sealed by the rewriting command.
    let old = learn::model::ModelCard {
        format: 2,
        ..model.card.clone()
    };
    std::fs::write(hand_edited.join("card.json"), serde_json::to_vec_pretty(&old).unwrap()).unwrap();
    match learn::model::open_model(&hand_edited) {
        Err(e @ learn::model::ModelError::Format { found: 2, .. }) => {
            assert!(e.to_string().contains("--onnx-only"), "{e}")
        }
        other => panic!("an unsealed card: {other:?}"),
    }
    learn::model::add_onnx(&hand_edited).unwrap();
    assert_eq!(learn::model::open_model(&hand_edited).unwrap().card, model.card);
    // The same blobs flown with terminal targeting: the card records it, its files and Monte
    // Carlo unchanged, and its config flies its SIL rows again.
    let aided = copy("model-terminal");
    let (card, sil) = learn::model::fly_terminal(&aided, &dir.join("terminal-runs"), 3).unwrap();
    assert_eq!(card.terminal.map(|t| t.cycles), Some(3));
    assert_eq!(
        (&card.files, &card.monte_carlo),
        (&model.card.files, &model.card.monte_carlo)
    );
    assert!(sil.iter().all(|r| r.terminal.is_some_and(|t| t.cycles == 3)));
    let reopened = learn::model::open_model(&aided).unwrap();
    assert_eq!(reopened.card, card);
    let again = learn::sil::sil_monte_carlo(
        &reopened.config,
        &reopened.blob(shared::blob::Quantization::F32),
        &dir.join("terminal-again"),
        None,
        &reopened.config.sil.dispersions,
        Optima::NONE,
    )
    .unwrap();
    assert_eq!(reopened.card.sil[0].1.within, again.monte_carlo.within_tolerances);
    // The card adds the controller as it flies: the f32 blob with terminal targeting on the Monte
    // Carlo's scenarios without dispersions (a nominal SIL of the same count, flown on its own).
    let flown = card
        .with_terminal
        .as_ref()
        .expect("the card records the flown Monte Carlo");
    assert_eq!(flown.monte_carlo.episodes as u64, reopened.config.evaluate.episodes);
    let nominal = learn::sil::sil_monte_carlo(
        &reopened.config,
        &reopened.blob(shared::blob::Quantization::F32),
        &dir.join("terminal-nominal"),
        Some(reopened.config.evaluate.episodes),
        &firmware_sim::Dispersions::NONE,
        Optima::NONE,
    )
    .unwrap();
    assert_eq!(flown.monte_carlo.within, nominal.monte_carlo.within_tolerances);
    assert_eq!(
        flown.monte_carlo.dr_p50,
        nominal.monte_carlo.policy.terminal_position.p50
    );
    assert!(learn::model::card_markdown(&card).contains("As flown: with terminal targeting"));
    let (without, _) = learn::model::fly_terminal(&aided, &dir.join("terminal-off"), 0).unwrap();
    assert_eq!((without.terminal, without.sil), (None, model.card.sil.clone()));
    assert!(
        without.with_terminal.is_none(),
        "no figures of an aid it no longer flies"
    );
    // One note says how the rows were flown: the latest.
    assert_eq!(without.notes.len(), model.card.notes.len() + 1, "{:?}", without.notes);
    // The aids of a config's [sil] tables: the card's config flies them and its note names
    // them; a key an aid does not take, or no [sil] table, is refused with the reason.
    let aids_file = dir.join("aids.toml");
    std::fs::write(
        &aids_file,
        "scenario = \"ignored\"\n[sil]\nepisodes = 3\nlookahead = { thrust_margin = 0.1, max_cycles = 3, arrival_margin = 1 }\nterminal = { cycles = 2 }\n",
    )
    .unwrap();
    let aids = learn::model::read_aids(&aids_file).unwrap();
    let (card, sil) = learn::model::fly_aids(&aided, &dir.join("aids-runs"), &aids).unwrap();
    assert!(sil
        .iter()
        .all(|r| r.lookahead.is_some_and(|l| l.thrust_margin == 0.1) && r.terminal.is_some_and(|t| t.cycles == 2)));
    let reopened = learn::model::open_model(&aided).unwrap();
    assert_eq!(reopened.card, card);
    assert_eq!(
        reopened
            .config
            .sil
            .lookahead
            .map(|l| (l.thrust_margin, l.max_cycles, l.arrival_margin)),
        Some((0.1, 3, 1))
    );
    assert!(card.lookahead.is_some(), "the nominal Monte Carlo with the lookahead");
    let note = card.notes.last().unwrap();
    assert!(
        note.contains(
            "with rollout lookahead planning without 0.1 of the thrust and judging its rollouts 1 cycle before \
             the arrival and terminal targeting of the last 2 cycles"
        ),
        "{note}"
    );
    assert_eq!(card.notes.len(), without.notes.len(), "{:?}", card.notes);
    std::fs::write(&aids_file, "[sil.terminal]\ncycles = 2\ngoal_position = 0.1\n").unwrap();
    let refused = learn::model::read_aids(&aids_file).unwrap_err();
    assert!(refused.to_string().contains("goal_position"), "{refused}");
    std::fs::write(&aids_file, "[terminal]\ncycles = 2\n").unwrap();
    let refused = learn::model::read_aids(&aids_file).unwrap_err();
    assert!(refused.to_string().contains("no [sil] table"), "{refused}");
    std::fs::write(swapped.join("card.json"), b"{ not a card").unwrap();
    assert!(matches!(
        learn::model::open_model(&swapped),
        Err(learn::model::ModelError::Card { .. })
    ));
    // Monte Carlo figures at every reported tolerance.
    assert_eq!(
        job.monte_carlo
            .within_tolerances
            .iter()
            .map(|t| t.0)
            .collect::<Vec<_>>(),
        learn::eval::REPORTED_TOLERANCES.to_vec()
    );

    // Relabelling rounds of dispersed flights started from an actor file alone (the rounds'
    // best actor, which the fine-tuning started from), with cloning-only updates, then
    // `ship`ped: round 0 flies exactly the main job's best round,
    // every round is also scored under the dispersions, and the new card records the rounds
    // and the lineage note.
    let mut dispersed = config.clone();
    // Relative to the config's folder (`dir`), as a config file names it.
    dispersed.pretrain.dataset = Some(PathBuf::from("run/dataset"));
    dispersed.dagger.dispersed = true;
    dispersed.dagger.cloning_only = true;
    // Shipped flying with lookahead: the rounds still fly and score the network alone (round 0
    // below equals the main job's), the card adds the lookahead's Monte Carlo.
    dispersed.sil.lookahead = Some(Default::default());
    let again = dir.join("dispersed");
    let actor = run.join("finetune/start-actor.safetensors");
    let summary = learn::dagger::dagger(&dispersed, &dir, &again, &actor, None).unwrap();
    let kept = rounds.rows.iter().find(|r| r.round == rounds.best_round).unwrap();
    assert_eq!(summary.rows[0].within_goal, kept.within_goal);
    assert_eq!(summary.rows[0].summary, kept.summary);
    assert!(summary.rows.iter().all(|r| r.within_goal_dispersed.is_some()));
    assert_eq!(summary.rows.last().unwrap().updates, 20, "cloning-only updates counted");
    let read = learn::dagger::read_rounds(&again.join("dagger")).unwrap();
    assert_eq!((read.rows.len(), read.best_round), (2, summary.best_round));
    let note = "started from the main job's model".to_string();
    let shipped = learn::ship::ship(
        &dispersed,
        &dir,
        &again.join("dagger/best.safetensors"),
        &dir.join("ship"),
        Some((1, read.best_round)),
        std::slice::from_ref(&note),
    )
    .unwrap();
    let shipped_model = learn::model::open_model(&dir.join("ship/model")).unwrap();
    assert!(shipped_model.config.pretrain.dataset.as_ref().unwrap().is_absolute());
    let card = shipped_model.card;
    assert_eq!(card.notes, vec![note.clone()]);
    assert_eq!(card.rounds, Some((1, read.best_round)));
    assert_eq!(card.sil.len(), 2);
    assert_eq!(
        card.monte_carlo.share_within(0.01),
        Some(shipped.monte_carlo.within_accuracy_goal)
    );
    assert!(learn::model::card_markdown(&card).contains(&note));
    let lookahead = card.lookahead.as_ref().expect("the card records the lookahead");
    assert_eq!(Some(lookahead.settings), dispersed.sil.lookahead);
    assert_eq!(lookahead.flown.monte_carlo.episodes as u64, dispersed.evaluate.episodes);
    assert!(shipped.sil.iter().all(|r| r.lookahead == dispersed.sil.lookahead));
    assert!(learn::model::card_markdown(&card).contains("With rollout lookahead"));
    // Exported again from its own actor (after a blob format change, say): the dataset the card
    // names is found again, the same weights fly the same SIL figures, and the folder opens.
    let again = learn::model::reexport_model(&dir.join("ship/model"), &dir.join("reexport")).unwrap();
    assert_eq!(again.card.sil, card.sil);
    assert_eq!(again.card.monte_carlo, card.monte_carlo);
    assert!(again.card.reexported.is_some());
    learn::model::open_model(&dir.join("ship/model")).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn altered_checkpoints_are_refused() {
    let dir = scratch_dir("checkpoint-integrity");
    let config = toy_config(&dir.join("unused"));
    tch::manual_seed(3);
    let agent = Sac::new(config.sac.clone(), 10, 3, tch::Device::Cpu);
    let good = dir.join("good.safetensors");
    agent.save(&good).unwrap();
    let mut fresh = Sac::new(config.sac.clone(), 10, 3, tch::Device::Cpu);
    fresh.load(&good).unwrap();

    // One flipped bit anywhere in the tensor data (the last bytes: the end of some tensor).
    let mut flipped = bytes(&good);
    let n = flipped.len();
    flipped[n - 5] ^= 0x10;
    let path = dir.join("flipped.safetensors");
    std::fs::write(&path, &flipped).unwrap();
    assert!(matches!(fresh.load(&path), Err(CheckpointError::Corrupt(_))));

    // A file without a checksum (as plain tch or PyTorch writes it).
    let tensors = read_checked_safetensors(&good).unwrap();
    let plain = dir.join("plain.safetensors");
    tch::Tensor::write_safetensors(&tensors, &plain).unwrap();
    assert!(matches!(fresh.load(&plain), Err(CheckpointError::Corrupt(_))));

    // A NaN actor weight under a valid checksum.
    let poisoned: Vec<(String, tch::Tensor)> = tensors
        .iter()
        .map(|(name, t)| {
            let t = t.copy();
            if name == "online.actor.l0.weight" {
                let _ = t.get(0).get(0).fill_(f64::NAN);
            }
            (name.clone(), t)
        })
        .collect();
    let nan = dir.join("nan.safetensors");
    write_checked_safetensors(&poisoned, &Default::default(), &nan).unwrap();
    match fresh.load(&nan) {
        Err(CheckpointError::NonFinite(name)) => assert_eq!(name, "online.actor.l0.weight"),
        other => panic!("NaN weight not refused: {other:?}"),
    }
    // The refused loads left the agent as the good checkpoint made it.
    let obs = [0.1f32; 10];
    assert_eq!(fresh.act(&obs, 1), agent.act(&obs, 1));
    std::fs::remove_dir_all(&dir).unwrap();
}
