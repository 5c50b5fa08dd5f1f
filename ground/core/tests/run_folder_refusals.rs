//! Run folders under bad input: a request that cannot make a dataset, a folder of another run
//! and a folder held by another process are refused before anything is created or changed.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use ground_core::generate::{
    classify_run, generate, merge, write_outputs, DatasetFile, GenerateError, Manifest, Shard,
};
use ground_core::io::{LockError, RunLock};
use ground_core::solver::SolveOptions;
use shared::scenario::ScenarioKind;
use shared::spacecraft::{CanonicalSpacecraft, Spacecraft};

const MANIFEST: Manifest = Manifest {
    family: ScenarioKind::TransferCircular.family(),
    seed: 9,
    count: 1,
};

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lowthrust-refusal-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A short homotopy keeps the test quick; the machinery is the same at any final eps.
fn options() -> SolveOptions {
    SolveOptions {
        final_eps: 0.3,
        ..SolveOptions::default()
    }
}

fn spacecraft() -> CanonicalSpacecraft {
    Spacecraft::MSR_ERO.canonical().unwrap()
}

/// One finished whole run of [`MANIFEST`], shared by the tests that need real records.
fn finished_run() -> &'static Path {
    static RUN: OnceLock<PathBuf> = OnceLock::new();
    RUN.get_or_init(|| {
        let dir = temp_dir("finished");
        generate(MANIFEST, Shard::WHOLE, &dir, &spacecraft(), &options(), false).unwrap();
        dir
    })
}

/// Every file under `dir` with its bytes, sorted by path: equal snapshots mean nothing changed.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut files = Vec::new();
    let mut pending = vec![dir.to_path_buf()];
    while let Some(d) = pending.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                files.push((path.strip_prefix(dir).unwrap().to_path_buf(), Vec::new()));
                pending.push(path);
            } else {
                let bytes = std::fs::read(&path).unwrap();
                files.push((path.strip_prefix(dir).unwrap().to_path_buf(), bytes));
            }
        }
    }
    files.sort();
    files
}

fn write_manifest(dir: &Path, manifest: &Manifest) {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("manifest.json"), serde_json::to_vec_pretty(manifest).unwrap()).unwrap();
}

/// The name of a refusal's variant, to compare with the one a case expects.
fn variant(e: &GenerateError) -> &'static str {
    match e {
        GenerateError::EmptyCount => "EmptyCount",
        GenerateError::EmptyShard { .. } => "EmptyShard",
        GenerateError::InvalidShard(_) => "InvalidShard",
        GenerateError::InvalidFinalEps(_) => "InvalidFinalEps",
        _ => "another refusal",
    }
}

#[test]
fn impossible_requests_are_refused_before_the_folder_is_created() {
    let out = temp_dir("impossible");
    let zero_count = Manifest { count: 0, ..MANIFEST };
    let three = Manifest { count: 3, ..MANIFEST };
    let eps = |final_eps| SolveOptions { final_eps, ..options() };
    let shard = |index, count| Shard { index, count };
    let cases = [
        (zero_count, Shard::WHOLE, options(), "count", "EmptyCount"),
        (three, shard(5, 8), options(), "shard 5/8", "EmptyShard"),
        (three, shard(0, 0), options(), "shard 0/0", "InvalidShard"),
        (three, shard(2, 2), options(), "shard 2/2", "InvalidShard"),
        (MANIFEST, Shard::WHOLE, eps(0.0), "final eps", "InvalidFinalEps"),
        (MANIFEST, Shard::WHOLE, eps(f64::NAN), "final eps", "InvalidFinalEps"),
        (MANIFEST, Shard::WHOLE, eps(1.5), "final eps", "InvalidFinalEps"),
    ];
    for (manifest, shard, options, needle, expected) in cases {
        let err = generate(manifest, shard, &out, &spacecraft(), &options, false).expect_err(needle);
        assert_eq!(variant(&err), expected, "{needle}: {err:?}");
        assert!(err.to_string().contains(needle), "{needle}: {err}");
        assert!(!out.exists(), "{needle}: the refused run created {}", out.display());
    }
}

#[test]
fn a_folder_of_another_run_is_refused_and_left_unchanged() {
    let out = temp_dir("other-run");
    write_manifest(&out, &Manifest { seed: 10, ..MANIFEST });
    let before = snapshot(&out);
    let err = generate(MANIFEST, Shard::WHOLE, &out, &spacecraft(), &options(), false).unwrap_err();
    assert!(matches!(err, GenerateError::ManifestMismatch { .. }), "{err}");
    assert_eq!(snapshot(&out), before);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_folder_solved_to_another_final_eps_is_refused_and_left_unchanged() {
    // The finished run says how deep its records were solved.
    let request = std::fs::read_to_string(finished_run().join("request.json")).unwrap();
    assert!(request.contains("0.3"), "{request}");
    let out = temp_dir("other-eps");
    write_manifest(&out, &MANIFEST);
    std::fs::write(out.join("request.json"), r#"{ "final_eps": 0.5 }"#).unwrap();
    let before = snapshot(&out);
    let err = generate(MANIFEST, Shard::WHOLE, &out, &spacecraft(), &options(), false).unwrap_err();
    assert!(
        matches!(err, GenerateError::FinalEpsMismatch { found, wanted } if found == 0.5 && wanted == 0.3),
        "{err}"
    );
    assert!(err.to_string().contains("--final-eps 0.5"), "{err}");
    assert_eq!(snapshot(&out), before);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_folder_solved_with_another_arrival_margin_is_refused_and_left_unchanged() {
    // A run without a margin records none (its request.json reads as before the margin existed).
    let request = std::fs::read_to_string(finished_run().join("request.json")).unwrap();
    assert!(!request.contains("arrival_margin"), "{request}");
    let out = temp_dir("other-margin");
    write_manifest(&out, &MANIFEST);
    std::fs::write(
        out.join("request.json"),
        r#"{ "final_eps": 0.3, "arrival_margin_steps": 2 }"#,
    )
    .unwrap();
    let before = snapshot(&out);
    let err = generate(MANIFEST, Shard::WHOLE, &out, &spacecraft(), &options(), false).unwrap_err();
    assert!(
        matches!(err, GenerateError::ArrivalMarginMismatch { found: 2, wanted: 0 }),
        "{err}"
    );
    assert!(err.to_string().contains("--arrival-margin 2"), "{err}");
    assert_eq!(snapshot(&out), before);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_folder_solved_for_another_spacecraft_is_refused_and_left_unchanged() {
    // The finished run records the spacecraft its records were solved for.
    let request: serde_json::Value =
        serde_json::from_slice(&std::fs::read(finished_run().join("request.json")).unwrap()).unwrap();
    let recorded: CanonicalSpacecraft = serde_json::from_value(request["spacecraft"].clone()).unwrap();
    assert_eq!(recorded, spacecraft());
    // Resuming it for Zavoli and Federici's spacecraft (0.5 N, 2,000 s, 1,000 kg) is refused.
    let study = Spacecraft {
        max_thrust_n: 0.5,
        isp_s: 2000.0,
        initial_mass_kg: 1000.0,
    }
    .canonical()
    .unwrap();
    let out = temp_dir("other-spacecraft");
    write_manifest(&out, &MANIFEST);
    std::fs::write(out.join("request.json"), serde_json::to_vec(&request).unwrap()).unwrap();
    let before = snapshot(&out);
    let err = generate(MANIFEST, Shard::WHOLE, &out, &study, &options(), false).unwrap_err();
    assert!(
        matches!(err, GenerateError::SpacecraftMismatch { found, wanted, .. } if found == spacecraft() && wanted == study),
        "{err}"
    );
    assert!(err.to_string().contains("--thrust-n"), "{err}");
    assert_eq!(snapshot(&out), before);
    // The same folder resumes for its own spacecraft.
    generate(MANIFEST, Shard::WHOLE, &out, &spacecraft(), &options(), false).unwrap();
    let _ = std::fs::remove_dir_all(&out);
}

fn is_held(e: &GenerateError) -> bool {
    matches!(e, GenerateError::Lock(LockError::Held { .. }))
}

#[test]
fn a_held_folder_is_refused_by_generate_and_left_unchanged() {
    let out = temp_dir("held");
    write_manifest(&out, &MANIFEST);
    let held = RunLock::acquire(&out).unwrap();
    let before = snapshot(&out);
    let err = generate(MANIFEST, Shard::WHOLE, &out, &spacecraft(), &options(), false).unwrap_err();
    assert!(is_held(&err), "{err:?}");
    assert!(err.to_string().contains("in use"), "{err}");
    assert_eq!(snapshot(&out), before);
    drop(held);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn merge_refuses_a_held_folder_and_leaves_it_unchanged() {
    let input = [finished_run().join("dataset.ltds")];
    let out = temp_dir("merge-held");
    let held = RunLock::acquire(&out).unwrap();
    let before = snapshot(&out);
    let err = merge(&input, &out).unwrap_err();
    assert!(is_held(&err), "{err:?}");
    assert_eq!(snapshot(&out), before);
    drop(held);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn merge_refuses_a_folder_of_another_run_and_leaves_it_unchanged() {
    let input = [finished_run().join("dataset.ltds")];
    let out = temp_dir("merge-other-run");
    write_manifest(&out, &Manifest { seed: 10, ..MANIFEST });
    let before = snapshot(&out);
    let err = merge(&input, &out).unwrap_err();
    assert!(matches!(err, GenerateError::ManifestMismatch { .. }), "{err}");
    assert_eq!(snapshot(&out), before);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn merge_refuses_a_dataset_of_no_scenario_before_creating_the_folder() {
    let input_dir = temp_dir("merge-empty-input");
    std::fs::create_dir_all(&input_dir).unwrap();
    let empty = DatasetFile {
        manifest: Manifest { count: 0, ..MANIFEST },
        shard: Shard::WHOLE,
        records: Vec::new(),
    };
    write_outputs(&input_dir, &empty).unwrap();
    let out = temp_dir("merge-empty-out");
    let err = merge(&[input_dir.join("dataset.ltds")], &out).unwrap_err();
    assert!(matches!(err, GenerateError::EmptyCount), "{err}");
    assert!(!out.exists(), "the refused merge created {}", out.display());
    let _ = std::fs::remove_dir_all(&input_dir);
}

#[test]
fn classification_refuses_a_run_of_no_scenario_and_leaves_it_unchanged() {
    let run = temp_dir("classify-empty");
    write_manifest(&run, &Manifest { count: 0, ..MANIFEST });
    let before = snapshot(&run);
    let err = classify_run(&run, &spacecraft(), &options()).unwrap_err();
    assert!(matches!(err, GenerateError::EmptyCount), "{err}");
    assert_eq!(snapshot(&run), before);
    let _ = std::fs::remove_dir_all(&run);
}

#[test]
fn classification_refuses_a_held_run_and_leaves_it_unchanged() {
    let run = finished_run();
    let held = RunLock::acquire(run).unwrap();
    let before = snapshot(run);
    let err = classify_run(run, &spacecraft(), &options()).unwrap_err();
    assert!(is_held(&err), "{err:?}");
    assert_eq!(snapshot(run), before);
    drop(held);
}
