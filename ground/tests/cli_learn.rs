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
    for args in [
        vec![
            "evaluate",
            "--out",
            path(&out),
            "--checkpoint",
            path(&checkpoint),
            "--episodes",
            "0",
        ],
        vec![
            "sil",
            "--out",
            path(&out),
            "--blob",
            path(&checkpoint),
            "--episodes",
            "0",
        ],
        vec!["pendulum", "--threads", "0"],
        vec!["bench-sac", "--threads", "1,0"],
    ] {
        refused(&args, "0");
    }
    // Refused after the folder was taken: a missing checkpoint, a missing pretraining phase.
    refused(
        &["evaluate", "--out", path(&out), "--checkpoint", path(&checkpoint)],
        "missing.safetensors",
    );
    refused(&["train", "--out", path(&out), "--from-pretrained"], "pretrain");
    assert!(!dir.join("new").exists(), "a refused command left a folder behind");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_run_folder_in_use_is_refused() {
    let dir = scratch("lock");
    let run = dir.join("run");
    let held = ground_core::io::RunLock::acquire(&run).unwrap();
    refused(&["pretrain", "--out", path(&run)], "in use");
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
