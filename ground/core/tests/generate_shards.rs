//! Dataset generation: shards are disjoint and together identical to a single run, a restarted
//! run skips finished work, a corrupt record is solved again, mismatched folders are refused.

use std::path::PathBuf;

use ground_core::generate::{
    dataset_solve_request, generate, merge, read_dataset, trajectory_difference, GenerateError, Manifest, Shard,
};
use ground_core::solver::record::TrajectoryRecord;
use ground_core::solver::SolveOptions;
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lowthrust-gen-{name}-{}", std::process::id()));
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

fn without_timing(mut records: Vec<TrajectoryRecord>) -> Vec<TrajectoryRecord> {
    for r in &mut records {
        r.seconds = 0.0;
    }
    records
}

#[test]
fn shards_merge_into_the_single_run_and_restarts_resume() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let manifest = Manifest {
        family: ScenarioKind::TransferCircular.family(),
        seed: 9,
        count: 5,
    };
    let whole = temp_dir("whole");
    let summary = generate(manifest, Shard::WHOLE, &whole, &sc, &options(), false).unwrap();
    assert_eq!(summary.records, 5);
    let single = read_dataset(&whole.join("dataset.ltds")).unwrap();
    assert_eq!(
        single.records.iter().map(|r| r.index).collect::<Vec<_>>(),
        vec![0, 1, 2, 3, 4]
    );
    for r in &single.records {
        assert_eq!(r.scenario, ScenarioKind::TransferCircular.draw(9, r.index));
        if r.converged {
            assert!(r.residual < 1e-8 && r.ephemeris.len() == 100 && r.steps.len() == r.scenario.steps as usize + 1);
        }
    }

    let (a, b) = (temp_dir("shard0"), temp_dir("shard1"));
    generate(manifest, "0/2".parse().unwrap(), &a, &sc, &options(), false).unwrap();
    generate(manifest, "1/2".parse().unwrap(), &b, &sc, &options(), false).unwrap();
    let shard_a = read_dataset(&a.join("dataset-0-of-2.ltds")).unwrap();
    let shard_b = read_dataset(&b.join("dataset-1-of-2.ltds")).unwrap();
    assert_eq!(
        shard_a.records.iter().map(|r| r.index).collect::<Vec<_>>(),
        vec![0, 2, 4]
    );
    assert_eq!(shard_b.records.iter().map(|r| r.index).collect::<Vec<_>>(), vec![1, 3]);
    let merged_dir = temp_dir("merged");
    merge(
        &[a.join("dataset-0-of-2.ltds"), b.join("dataset-1-of-2.ltds")],
        &merged_dir,
    )
    .unwrap();
    let merged = read_dataset(&merged_dir.join("dataset.ltds")).unwrap();
    assert_eq!(
        without_timing(merged.records.clone()),
        without_timing(single.records.clone())
    );
    // `ground data compare`'s check: the same trajectories, solve times aside; one costate bit or
    // another seed is a difference.
    assert_eq!(trajectory_difference(&merged, &single), None);
    let mut altered = merged.clone();
    altered.records[3].seconds += 1.0;
    assert_eq!(trajectory_difference(&altered, &single), None);
    altered.records[3].residual = f64::from_bits(altered.records[3].residual.to_bits() ^ 1);
    assert!(trajectory_difference(&altered, &single).is_some_and(|d| d.contains("index 3")));
    // A failed record (NaN final mass, infinite residual) equals itself.
    let mut failed = merged.clone();
    failed.records[1].final_mass = f64::NAN;
    failed.records[1].residual = f64::INFINITY;
    assert_eq!(trajectory_difference(&failed, &failed.clone()), None);
    let mut reseeded = merged.clone();
    reseeded.manifest.seed += 1;
    assert!(trajectory_difference(&reseeded, &single).is_some());
    assert!(trajectory_difference(&shard_a, &single).is_some());
    // A shard alone is not a dataset.
    assert!(matches!(
        merge(&[a.join("dataset-0-of-2.ltds")], &temp_dir("partial")),
        Err(GenerateError::Merge(_))
    ));
    // The merged run says what its records were solved to, as the shards' runs do; a shard
    // solved to another final eps is refused, and nothing is written.
    let request = dataset_solve_request(&merged_dir.join("dataset.ltds"))
        .unwrap()
        .unwrap();
    assert_eq!(
        (request.final_eps, request.arrival_margin_steps),
        (options().final_eps, 0)
    );
    let deeper = temp_dir("shard1-deeper");
    let deeper_options = SolveOptions {
        final_eps: 0.25,
        ..SolveOptions::default()
    };
    generate(manifest, "1/2".parse().unwrap(), &deeper, &sc, &deeper_options, false).unwrap();
    let mixed = temp_dir("mixed");
    assert!(matches!(
        merge(&[a.join("dataset-0-of-2.ltds"), deeper.join("dataset-1-of-2.ltds")], &mixed),
        Err(GenerateError::Merge(reason)) if reason.contains("final eps")
    ));
    assert!(!mixed.exists(), "a refused merge created its folder");
    let _ = std::fs::remove_dir_all(&deeper);

    // Restart: every record is resumed, byte for byte the same set.
    let again = generate(manifest, Shard::WHOLE, &whole, &sc, &options(), false).unwrap();
    assert_eq!(again.records, 5);
    assert_eq!(
        read_dataset(&whole.join("dataset.ltds")).unwrap().records,
        single.records
    );
    // A corrupt record is solved again rather than half-read.
    let rec = whole.join("records").join("00000002.rec");
    let mut bytes = std::fs::read(&rec).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0xff;
    std::fs::write(&rec, &bytes).unwrap();
    generate(manifest, Shard::WHOLE, &whole, &sc, &options(), false).unwrap();
    let redone = read_dataset(&whole.join("dataset.ltds")).unwrap();
    assert_eq!(without_timing(redone.records), without_timing(single.records));
    // Another seed into the same folder is refused before any work.
    let other = Manifest { seed: 10, ..manifest };
    assert!(matches!(
        generate(other, Shard::WHOLE, &whole, &sc, &options(), false),
        Err(GenerateError::ManifestMismatch { .. })
    ));
    // A truncated dataset file is refused.
    let ds = whole.join("dataset.ltds");
    let bytes = std::fs::read(&ds).unwrap();
    std::fs::write(&ds, &bytes[..bytes.len() - 7]).unwrap();
    assert!(matches!(read_dataset(&ds), Err(GenerateError::Corrupt(..))));
    for d in [whole, a, b, merged_dir] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn a_run_asked_for_more_scenarios_extends_to_the_single_run_and_fewer_are_refused() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let small = Manifest {
        family: ScenarioKind::TransferCircular.family(),
        seed: 11,
        count: 2,
    };
    let large = Manifest { count: 4, ..small };
    let single_dir = temp_dir("extend-single");
    generate(large, Shard::WHOLE, &single_dir, &sc, &options(), false).unwrap();
    let single = read_dataset(&single_dir.join("dataset.ltds")).unwrap();

    let grown = temp_dir("extend-grown");
    let first = generate(small, Shard::WHOLE, &grown, &sc, &options(), false).unwrap();
    assert_eq!(first.records, 2);
    let second = generate(large, Shard::WHOLE, &grown, &sc, &options(), false).unwrap();
    assert_eq!(second.records, 4);
    let extended = read_dataset(&grown.join("dataset.ltds")).unwrap();
    assert_eq!(extended.manifest, large);
    assert_eq!(without_timing(extended.records), without_timing(single.records));
    let manifest: Manifest = serde_json::from_slice(&std::fs::read(grown.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest, large);

    // Fewer scenarios, or the same count of another stream, are another run.
    for other in [small, Manifest { seed: 12, ..large }] {
        assert!(matches!(
            generate(other, Shard::WHOLE, &grown, &sc, &options(), false),
            Err(GenerateError::ManifestMismatch { .. })
        ));
    }
    let _ = std::fs::remove_dir_all(&single_dir);
    let _ = std::fs::remove_dir_all(&grown);
}
