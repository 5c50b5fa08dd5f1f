//! The commands that write files (`generate`, `merge`, `oem`, `feasibility`, `crosscheck`,
//! `solve --plot`) from the outside: impossible requests, outputs in folders that do not exist
//! and run folders held by another process are refused with the reason, and leave nothing
//! behind.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use ground_core::io::RunLock;

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
            "data",
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

/// Every file under `dir` with its bytes, sorted by path: equal snapshots mean nothing changed.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut files = Vec::new();
    let mut pending = vec![dir.to_path_buf()];
    while let Some(d) = pending.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            let relative = path.strip_prefix(dir).unwrap().to_path_buf();
            if path.is_dir() {
                files.push((relative, Vec::new()));
                pending.push(path);
            } else {
                files.push((relative, std::fs::read(&path).unwrap()));
            }
        }
    }
    files.sort();
    files
}

fn assert_refused(args: &[&str], needle: &str) {
    let out = ground(args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} was accepted: {err}");
    assert!(err.contains(needle), "{args:?}: {err}");
}

#[test]
fn impossible_generate_requests_are_refused_before_the_folder_is_created() {
    let parent = scratch("impossible");
    let out = parent.join("run");
    for (extra, needle) in [
        (&["--count", "0"][..], "count must be at least 1"),
        (&["--count", "1", "--threads", "0"][..], "--threads"),
        (&["--count", "3", "--shard", "5/8"][..], "shard 5/8 is empty"),
        (&["--count", "1", "--final-eps", "0"][..], "final eps"),
    ] {
        let mut args = vec![
            "data",
            "generate",
            "--scenario",
            "transfer-circular",
            "--out",
            text(&out),
        ];
        args.extend_from_slice(extra);
        assert_refused(&args, needle);
        assert!(!out.exists(), "{extra:?}: the refused run created {}", out.display());
    }
    let _ = std::fs::remove_dir_all(&parent);
}

/// A figure is a file: its folder must exist (run folders, `--out`, are created with their
/// parents, as `mkdir -p` does).
#[test]
fn a_figure_in_a_missing_folder_is_refused_and_nothing_is_created() {
    let parent = scratch("missing-folder");
    let missing = parent.join("missing");
    let plot = missing.join("fig.svg");
    assert_refused(
        &[
            "data",
            "solve",
            "--a0",
            "1",
            "--af",
            "1.3",
            "--plot",
            plot.to_str().unwrap(),
        ],
        "is not an existing folder",
    );
    assert!(!missing.exists(), "solve --plot created {}", missing.display());
    let _ = std::fs::remove_dir_all(&parent);
}

#[test]
fn run_folders_held_by_another_process_are_refused_and_left_unchanged() {
    let run = finished_run();
    let parent = scratch("held");
    let dataset = run.join("dataset.ltds");
    let target = parent.join("target");
    let generate = [
        "data",
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
        text(&target),
    ];
    let merge = ["data", "merge", "--out", text(&target), text(&dataset)];
    for args in [&generate[..], &merge[..]] {
        let held = RunLock::acquire(&target).unwrap();
        let before = snapshot(&target);
        assert_refused(args, "is in use by another process");
        assert_eq!(snapshot(&target), before, "{args:?} changed the held folder");
        drop(held);
    }
    let held = RunLock::acquire(run).unwrap();
    let before = snapshot(run);
    assert_refused(
        &["data", "feasibility", "--out", text(run)],
        "is in use by another process",
    );
    assert_eq!(snapshot(run), before, "feasibility changed the held folder");
    drop(held);
    let _ = std::fs::remove_dir_all(&parent);
}

/// `crosscheck` reads a finished run and writes only its CSV: bad settings and a CSV in a
/// missing folder are refused before any solve, with nothing created; a good request checks the
/// converged record and writes one row for it.
#[test]
fn crosscheck_refuses_bad_settings_and_writes_one_row_per_record() {
    let run = finished_run();
    let parent = scratch("crosscheck");
    let csv = parent.join("crosscheck.csv");
    // The dataset alone: another test holds the shared run (its lock file) meanwhile.
    let dataset = run.join("dataset.ltds");
    let before = std::fs::read(&dataset).unwrap();
    for (extra, needle) in [
        (&["--count", "0"][..], "--count"),
        (&["--segments-per-step", "0"][..], "--segments-per-step"),
        (&["--margin", "-1"][..], "--margin must be"),
        (&["--margin", "NaN"][..], "--margin must be"),
        (&["--refinements", "9"][..], "at most 4"),
    ] {
        let mut args = vec!["data", "crosscheck", "--dataset", text(run), "--csv", text(&csv)];
        args.extend_from_slice(extra);
        assert_refused(&args, needle);
        assert!(!csv.exists(), "{extra:?}: the refused check wrote {}", csv.display());
    }
    // --repair rewrites a run: a dataset file, or a part of the run, is not one.
    for args in [
        &[
            "data",
            "crosscheck",
            "--dataset",
            &format!("{}/dataset.ltds", text(run)),
            "--repair",
        ][..],
        &["data", "crosscheck", "--dataset", text(run), "--repair", "--count", "1"][..],
    ] {
        assert_refused(args, "--repair rewrites a whole run");
    }
    assert!(
        std::fs::read(&dataset).unwrap() == before,
        "a refused repair changed the dataset"
    );
    let missing = parent.join("missing").join("crosscheck.csv");
    assert_refused(
        &["data", "crosscheck", "--dataset", text(run), "--csv", text(&missing)],
        "is not an existing folder",
    );
    assert!(!missing.parent().unwrap().exists());
    let out = ground(&["data", "crosscheck", "--dataset", text(run), "--csv", text(&csv)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows: Vec<String> = std::fs::read_to_string(&csv)
        .unwrap()
        .lines()
        .map(String::from)
        .collect();
    assert_eq!(rows.len(), 2, "{rows:?}");
    assert!(rows[1].starts_with("0,"), "{rows:?}");
    assert!(
        std::fs::read(&dataset).unwrap() == before,
        "crosscheck changed the dataset"
    );
    let _ = std::fs::remove_dir_all(&parent);
}

/// `crosscheck` on a run of an inclined family (configs/missions/transfer-circular-inclined.toml,
/// seed 7, draws 0 to 2; draw 1's homotopy stalls): each converged record is checked by the
/// spatial direct transcription, which flies (re-flown by the onboard RTN propagator) and ends
/// at most the mesh's loss below the record, one CSV row per record; the folder is left as it
/// was. `--repair` (planar records only) and an impossible spacecraft are refused with the
/// reason before any solve, and nothing changes.
#[test]
fn crosscheck_checks_an_inclined_run_and_refuses_to_repair_it() {
    use ground_core::generate::read_dataset_of;
    use shared::mission::SpatialFamily;
    let parent = scratch("crosscheck-inclined");
    let run = parent.join("run");
    let mission = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/missions/transfer-circular-inclined.toml");
    let out = ground(&[
        "data",
        "generate",
        "--scenario",
        text(&mission),
        "--count",
        "3",
        "--seed",
        "7",
        "--threads",
        "2",
        "--out",
        text(&run),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let dataset = read_dataset_of::<SpatialFamily>(&run.join("dataset.ltds")).unwrap();
    let converged: Vec<_> = dataset.records.iter().filter(|r| r.converged).collect();
    assert!(
        converged.len() >= 2 && converged.len() < dataset.records.len(),
        "{} of {} converged",
        converged.len(),
        dataset.records.len()
    );
    let before = snapshot(&run);

    for (args, needle) in [
        (
            &["data", "crosscheck", "--dataset", text(&run), "--repair"][..],
            "--repair re-solves planar records only",
        ),
        (
            &["data", "crosscheck", "--dataset", text(&run), "--thrust-n", "0"][..],
            "spacecraft:",
        ),
    ] {
        assert_refused(args, needle);
        assert_eq!(snapshot(&run), before, "{args:?} changed the run");
    }

    let csv = parent.join("crosscheck.csv");
    let out = ground(&["data", "crosscheck", "--dataset", text(&run), "--csv", text(&csv)]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        stdout.contains(&format!("{} records checked", converged.len())),
        "{stdout}"
    );
    let table = std::fs::read_to_string(&csv).unwrap();
    let mut lines = table.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), converged.len(), "{table}");
    for (row, record) in rows.iter().zip(&converged) {
        let number = |name: &str| row[column(name)].parse::<f64>().unwrap();
        assert_eq!(row[column("index")], record.index.to_string(), "{table}");
        assert_eq!(row[column("error")], "", "{table}");
        assert_eq!(number("indirect_final_mass"), record.final_mass);
        assert_eq!(number("final_eps"), record.final_eps);
        // 1 segment per 14-day step; the 3D direct solution converged and flies.
        assert_eq!(row[column("segments")], record.scenario.scenario.steps.to_string());
        assert_eq!(row[column("direct_converged")], "true", "{table}");
        assert!(
            number("onboard_violation") < ground_core::crosscheck::FLOWN_VIOLATION,
            "{table}"
        );
        assert_eq!(row[column("record_beaten")], "false", "{table}");
        let difference = number("direct_final_mass") - record.final_mass;
        println!(
            "inclined transfer 7 #{}: direct - indirect {difference:+.3e}",
            record.index
        );
        assert!((-1e-3..1e-6).contains(&difference), "#{}: {difference:e}", record.index);
    }
    assert_eq!(snapshot(&run), before, "crosscheck changed the run");
    let _ = std::fs::remove_dir_all(&parent);
}

/// `feasibility` solves a recovered draw as the run's other records were solved (its
/// `request.json`): a run whose request is corrupt is refused with the file's name before any
/// work, and nothing in it changes.
#[test]
fn feasibility_refuses_a_run_with_a_corrupt_request() {
    let run = finished_run();
    let parent = scratch("feasibility-request");
    let copy = parent.join("run");
    for (path, bytes) in snapshot(run) {
        let to = copy.join(&path);
        if run.join(&path).is_dir() {
            std::fs::create_dir_all(&to).unwrap();
        } else {
            std::fs::create_dir_all(to.parent().unwrap()).unwrap();
            std::fs::write(&to, bytes).unwrap();
        }
    }
    let _ = std::fs::remove_file(copy.join(".lock"));
    std::fs::write(copy.join("request.json"), "{ not json").unwrap();
    let before = snapshot(&copy);
    assert_refused(&["data", "feasibility", "--out", text(&copy)], "request.json");
    assert_eq!(snapshot(&copy), before, "the refused feasibility changed the run");
    let _ = std::fs::remove_dir_all(&parent);
}
