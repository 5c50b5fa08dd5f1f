//! The learning commands from the outside: impossible requests are refused before any work, a
//! refused command leaves no folder behind, and a run folder serves one process at a time.
#![cfg(feature = "learn")]

use std::path::{Path, PathBuf};
use std::process::Command;

fn ground(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_ground")).args(args).output().unwrap()
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lowthrust-cli-learn-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn refused(args: &[&str], needle: &str) {
    let out = ground(args);
    assert!(!out.status.success(), "{args:?} was accepted");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(needle), "{args:?}: {err}");
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn impossible_counts_are_refused_and_leave_nothing_behind() {
    let dir = scratch("counts");
    let out = dir.join("new/run");
    let checkpoint = dir.join("missing.safetensors");
    // The two Monte Carlo commands, each refusal adding its arguments.
    let evaluate = [
        "model",
        "evaluate",
        "--out",
        path(&out),
        "--checkpoint",
        path(&checkpoint),
    ];
    let sil = ["model", "sil", "--out", path(&out), "--blob", path(&checkpoint)];
    for args in [
        [&evaluate[..], &["--episodes", "0"]].concat(),
        [&sil[..], &["--episodes", "0"]].concat(),
        vec!["dev", "pendulum", "--threads", "0"],
        vec!["dev", "bench-sac", "--threads", "1,0"],
    ] {
        refused(&args, "0");
    }
    // Refused after the folder was taken: a missing checkpoint, a missing pretraining phase.
    refused(&evaluate, "missing.safetensors");
    refused(&["train", "rl", "--out", path(&out), "--from-pretrained"], "pretrain");
    // Fine-tuning: a config without [finetune] steps; one that has them, a missing start.
    let finetune = |steps: u32, needle: &str| {
        let config = dir.join(format!("finetune-{steps}.toml"));
        let text = format!("scenario = \"transfer-circular\"\n[finetune]\nsteps = {steps}\n");
        std::fs::write(&config, text).unwrap();
        let args = [
            "train",
            "finetune",
            "--out",
            path(&out),
            "--from",
            path(&checkpoint),
            "--config",
            path(&config),
        ];
        refused(&args, needle);
    };
    finetune(0, "finetune.steps is 0");
    finetune(10, "missing.safetensors");
    // A lookahead thrust margin without the lookahead, or outside [0, 1).
    refused(&[&sil[..], &["--thrust-margin", "0.05"]].concat(), "--lookahead");
    refused(
        &[&sil[..], &["--lookahead", "--thrust-margin", "1.5"]].concat(),
        "thrust margin",
    );
    // Optima reused from a folder that holds no Monte Carlo, or asked for twice: refused
    // before the folder is taken.
    let nothing = dir.join("nothing");
    let reusing = [&evaluate[..], &["--gap-from", path(&nothing)]].concat();
    refused(&reusing, "summary.json");
    refused(&[&reusing[..], &["--gap-cases", "3"]].concat(), "--gap-cases");
    assert!(!dir.join("new").exists(), "a refused command left a folder behind");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// On a machine where libtorch finds no GPU, a config that asks for CUDA is refused by the
/// commands that train, with the reason, before any work: no folder is left behind (on a
/// machine with a GPU there is nothing to refuse).
#[test]
fn a_cuda_config_is_refused_before_any_work_where_there_is_no_gpu() {
    if learn::sac::cuda_device().is_ok() {
        return;
    }
    let dir = scratch("cuda");
    let config = dir.join("cuda.toml");
    std::fs::write(
        &config,
        "scenario = \"transfer-circular\"\n[compute]\ndevice = \"cuda\"\n",
    )
    .unwrap();
    let out = dir.join("new/run");
    for command in [&["run"][..], &["train", "pretrain"], &["train", "rl"]] {
        let mut args = command.to_vec();
        args.extend(["--config", path(&config), "--out", path(&out)]);
        refused(&args, "compute.device = \"cuda\"");
    }
    assert!(!dir.join("new").exists(), "a refused command left a folder behind");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_run_folder_in_use_is_refused() {
    let dir = scratch("lock");
    let run = dir.join("run");
    let held = ground_core::io::RunLock::acquire(&run).unwrap();
    refused(&["train", "pretrain", "--out", path(&run)], "in use");
    // Nothing was written next to the lock.
    let entries: Vec<_> = std::fs::read_dir(&run)
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert_eq!(entries, vec![std::ffi::OsString::from(ground_core::io::LOCK_FILE)]);
    drop(held);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A small config whose actor has the onboard contract's shape, flown on few episodes.
fn small_config(dir: &Path) -> PathBuf {
    let path = dir.join("small.toml");
    std::fs::write(
        &path,
        "scenario = \"transfer-circular\"\n[sac]\nhidden = [256, 256]\n[evaluate]\nepisodes = 4\noptimality_gap_cases = 0\n[sil]\nepisodes = 2\n",
    )
    .unwrap();
    path
}

#[test]
fn a_blob_refused_by_the_sil_is_a_failed_command_unless_safe_mode_is_allowed() {
    let dir = scratch("sil-refused");
    let config = small_config(&dir);
    let blob = dir.join("not-a.blob");
    std::fs::write(&blob, b"LTNB but not a blob at all").unwrap();
    let args = |out: &str| {
        vec![
            "model".to_string(),
            "sil".into(),
            "--config".into(),
            path(&config).into(),
            "--blob".into(),
            path(&blob).into(),
            "--out".into(),
            path(&dir.join(out)).into(),
        ]
    };
    let strict = args("strict");
    refused(&strict.iter().map(String::as_str).collect::<Vec<_>>(), "safe mode");
    assert!(!dir.join("strict").exists(), "a refused SIL left its folder behind");
    let mut allowed = args("allowed");
    allowed.push("--allow-safe-mode".into());
    let out = ground(&allowed.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(dir.join("allowed").join("sil.json").is_file());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_export_that_fails_its_accuracy_check_is_a_failed_command() {
    use learn::config::ExperimentConfig;
    use learn::sac::agent::{read_checked_safetensors, write_checked_safetensors, Sac};
    let dir = scratch("export-check");
    let config_path = small_config(&dir);
    let config = ExperimentConfig::load(&config_path).unwrap();
    tch::manual_seed(1);
    let agent = Sac::new(config.sac.clone(), 10, 3, tch::Device::Cpu);
    let good = dir.join("good.safetensors");
    agent.save(&good).unwrap();
    // A first hidden unit at 1e30 whatever the input, which the next layer ignores (zero
    // weights): the f32 blob flies as the trained actor, but the int8 blob's activation scale
    // for that layer is set by the 1e30 and every other unit quantizes to zero.
    let huge: Vec<(String, tch::Tensor)> = read_checked_safetensors(&good)
        .unwrap()
        .into_iter()
        .map(|(name, t)| {
            match name.as_str() {
                "online.actor.l0.bias" => {
                    let _ = t.get(0).fill_(1e30);
                }
                "online.actor.l1.weight" => {
                    let _ = t.narrow(1, 0, 1).fill_(0.0);
                }
                _ => {}
            }
            (name, t)
        })
        .collect();
    let bad = dir.join("huge.safetensors");
    write_checked_safetensors(&huge, &Default::default(), &bad).unwrap();
    for (checkpoint, ok) in [(&good, true), (&bad, false)] {
        let out = dir.join(if ok { "good" } else { "bad" });
        let result = ground(&[
            "model",
            "export",
            "--config",
            path(&config_path),
            "--checkpoint",
            path(checkpoint),
            "--out",
            path(&out),
        ]);
        let err = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.success(), ok, "{}: {err}", checkpoint.display());
        if !ok {
            assert!(
                err.contains("export check failed") && err.contains("int8 blob"),
                "{err}"
            );
        }
        // The blobs and their figures stay for study either way; export.json says which it was.
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("export.json")).unwrap()).unwrap();
        assert_eq!(report["passed"], ok, "{report}");
        assert_eq!(report["failed"].as_array().unwrap().is_empty(), ok, "{report}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A stand-in for `sbatch --wait --array=LIST --wrap CMD`: runs each listed task's command in
/// turn with `SLURM_ARRAY_TASK_ID` set and appends its arguments to `asked`. While the file
/// `fail` exists, task `fail_task` removes it and fails the array there (the tasks after it do
/// not run), as a node lost midway would. Written beside the test binaries, where executing is
/// allowed wherever the tests run (a temporary folder may be mounted without it).
fn slurm_stand_in(name: &str, asked: &Path, fail: &Path, fail_task: u32) -> PathBuf {
    let sbatch = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("sbatch-{name}-{}", std::process::id()));
    std::fs::write(
        &sbatch,
        format!(
            "#!/bin/sh\necho \"$@\" >> '{}'\narray=\nwrap=\nwhile [ $# -gt 0 ]; do\n  case \"$1\" in\n    --array=*) array=${{1#--array=}} ;;\n    --wrap) shift; wrap=$1 ;;\n  esac\n  shift\ndone\n\
case \"$array\" in\n  *-*) list=$(seq \"${{array%-*}}\" \"${{array#*-}}\") ;;\n  *) list=$(echo \"$array\" | tr ',' ' ') ;;\nesac\n\
for i in $list; do\n  if [ \"$i\" = {fail_task} ] && [ -e '{}' ]; then rm '{}'; exit 1; fi\n  SLURM_ARRAY_TASK_ID=$i sh -c \"$wrap\" > /dev/null || exit 1\ndone\n",
            path(asked),
            path(fail),
            path(fail)
        ),
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&sbatch, std::fs::Permissions::from_mode(0o755)).unwrap();
    sbatch
}

/// The configs of the Slurm relabel tests: one round solved here, and the same as an array of
/// four tasks run by `sbatch`, over a two-draw dataset in `dir/data`.
fn slurm_relabel_configs(dir: &Path, sbatch: &Path) -> (PathBuf, PathBuf) {
    let out = ground(&[
        "data",
        "generate",
        "--scenario",
        "transfer-circular",
        "--count",
        "2",
        "--seed",
        "9",
        "--final-eps",
        "0.3",
        "--out",
        path(&dir.join("data")),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let common = "scenario = \"transfer-circular\"\n[sac]\nhidden = [32, 32]\nbatch_size = 32\nwarmup_steps = 60\n\
[generate]\ncount = 2\nseed = 9\nfinal_eps = 0.3\n[pretrain]\ndataset = \"data\"\nupdates = 40\neval_every = 20\n\
mode = \"behaviour-cloning\"\nrecords = \"all\"\n[dagger]\nrounds = 1\nepisodes = 3\ncandidates = 6\nfractions = [0.3, 0.6]\n\
updates = 10\nscore_episodes = 4\n";
    let here = dir.join("here.toml");
    std::fs::write(&here, common).unwrap();
    let array = dir.join("array.toml");
    std::fs::write(
        &array,
        format!(
            "{common}[compute.slurm]\ntasks = 4\nsbatch = \"{}\"\nground = \"{}\"\noptions = [\"--partition=test\"]\n",
            path(sbatch),
            env!("CARGO_BIN_EXE_ground")
        ),
    )
    .unwrap();
    (here, array)
}

/// Pretraining and one round in `run`; the round's relabel file, checked to hold relabels.
fn pretrain_and_round(config: &Path, run: &Path) -> Vec<u8> {
    for command in ["pretrain", "dagger"] {
        let out = ground(&["train", command, "--config", path(config), "--out", path(run)]);
        assert!(
            out.status.success(),
            "{command}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let file = run.join("dagger/relabels-1.ltrl");
    let solved = learn::dagger::load_relabels(&file, 1, 10, 3).unwrap();
    assert_eq!(solved.attempted, 6);
    assert!(solved.converged > 0 && !solved.tuples.is_empty(), "nothing to compare");
    let left: Vec<_> = std::fs::read_dir(run.join("dagger"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|name| name.starts_with("relabel-"))
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
    std::fs::read(&file).unwrap()
}

/// A round's relabels solved as a Slurm array (`[compute.slurm]`) are the bytes the round solves
/// on this machine, in one array of every task with the config's options. The request and
/// answer files are gone after the round.
#[test]
fn relabels_solved_by_a_slurm_array_equal_those_solved_here() {
    let dir = scratch("slurm-relabel");
    let asked = dir.join("asked.txt");
    let sbatch = slurm_stand_in("whole", &asked, &dir.join("no-failure"), 0);
    let (here, array) = slurm_relabel_configs(&dir, &sbatch);
    let solved_here = pretrain_and_round(&here, &dir.join("run-here"));
    let solved_by_array = pretrain_and_round(&array, &dir.join("run-array"));
    assert_eq!(
        solved_here, solved_by_array,
        "the array's relabels differ from those solved here"
    );
    let asked = std::fs::read_to_string(&asked).unwrap();
    assert_eq!(asked.lines().count(), 1, "one array for the round: {asked}");
    assert!(
        asked.contains("--wait") && asked.contains("--array=0-3") && asked.contains("--partition=test"),
        "{asked}"
    );
    std::fs::remove_file(&sbatch).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An array that fails at its third task fails the round with the reason; the same command
/// then submits only the tasks that did not answer (the third and fourth), and the round ends
/// with the relabels solved here.
#[test]
fn a_failed_relabel_array_resubmits_only_the_tasks_that_did_not_answer() {
    let dir = scratch("slurm-relabel-failed");
    let asked = dir.join("asked.txt");
    let fail = dir.join("fail");
    let sbatch = slurm_stand_in("failed", &asked, &fail, 2);
    let (here, array) = slurm_relabel_configs(&dir, &sbatch);
    let solved_here = pretrain_and_round(&here, &dir.join("run-here"));
    let run = dir.join("run-array");
    let out = ground(&["train", "pretrain", "--config", path(&array), "--out", path(&run)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    std::fs::write(&fail, "").unwrap();
    let out = ground(&["train", "dagger", "--config", path(&array), "--out", path(&run)]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "the round went on past a failed array");
    assert!(stderr.contains("submits only the others"), "{stderr}");
    assert!(!fail.exists(), "the array never reached its third task");
    let solved_by_array = pretrain_and_round(&array, &run);
    assert_eq!(
        solved_here, solved_by_array,
        "the resumed array's relabels differ from those solved here"
    );
    let asked: Vec<String> = std::fs::read_to_string(&asked)
        .unwrap()
        .lines()
        .map(str::to_owned)
        .collect();
    assert_eq!(asked.len(), 2, "{asked:?}");
    assert!(asked[0].contains("--array=0-3"), "{}", asked[0]);
    assert!(asked[1].contains("--array=2,3 "), "{}", asked[1]);
    std::fs::remove_file(&sbatch).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}
