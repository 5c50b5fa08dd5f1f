//! The commands that write files (`generate`, `merge`, `oem`, `solve --plot`) from the outside:
//! outputs in folders that do not exist are refused with the reason, and leave nothing
//! behind.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

fn ground(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ground")).args(args).output().unwrap()
}

/// A fresh folder for one test, empty and existing.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lowthrust-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn text(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// One finished whole run (one transfer-circular draw, short homotopy), shared by the tests
/// that need a dataset.
fn finished_run() -> &'static Path {
    static RUN: OnceLock<PathBuf> = OnceLock::new();
    RUN.get_or_init(|| {
        let run = scratch("finished").join("run");
        let out = ground(&[
            "generate",
            "--scenario",
            "transfer-circular",
            "--count",
            "1",
            "--seed",
            "9",
            "--final-eps",
            "0.3",
            "--out",
            text(&run),
        ]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        run
    })
}

fn assert_refused(args: &[&str], needle: &str) {
    let out = ground(args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} was accepted: {err}");
    assert!(err.contains(needle), "{args:?}: {err}");
}

#[test]
fn outputs_in_a_missing_folder_are_refused_and_nothing_is_created() {
    let dataset = finished_run().join("dataset.ltds");
    let parent = scratch("missing-folder");
    let missing = parent.join("missing");
    let inside = |name: &str| missing.join(name).to_str().unwrap().to_string();
    let (plot, run, merged, oem) = (inside("fig.svg"), inside("run"), inside("merged"), inside("oem"));
    let commands: [Vec<&str>; 4] = [
        vec!["solve", "--a0", "1", "--af", "1.3", "--plot", &plot],
        vec![
            "generate",
            "--scenario",
            "transfer-circular",
            "--count",
            "1",
            "--final-eps",
            "0.3",
            "--out",
            &run,
        ],
        vec!["merge", "--out", &merged, text(&dataset)],
        vec!["oem", "--dataset", text(&dataset), "--index", "0", "--out", &oem],
    ];
    for args in commands {
        assert_refused(&args, "is not an existing folder");
        assert!(!missing.exists(), "{args:?} created {}", missing.display());
    }
    let _ = std::fs::remove_dir_all(&parent);
}
