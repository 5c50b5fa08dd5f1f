//! A dataset run on a full disk: the first record it cannot write stops it with the reason, it
//! leaves no temporary file behind, and the same command resumes once there is room.
//!
//! A file size limit (RLIMIT_FSIZE, with SIGXFSZ ignored so a write past it fails with EFBIG)
//! stands in for the full disk: the run's small JSON files fit under it, a record does not. The
//! limit holds for the whole process, so this file has one test.

use std::path::Path;

use ground_core::generate::{generate, GenerateError, Manifest, Shard};
use ground_core::solver::SolveOptions;
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

/// Every file under `dir` (relative paths).
fn files(dir: &Path) -> Vec<String> {
    let mut found = Vec::new();
    let mut pending = vec![dir.to_path_buf()];
    while let Some(d) = pending.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                pending.push(path);
            } else {
                found.push(path.strip_prefix(dir).unwrap().to_string_lossy().into_owned());
            }
        }
    }
    found.sort();
    found
}

fn set_file_size_limit(bytes: libc::rlim_t) {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: plain POSIX calls on a local struct; SIGXFSZ ignored makes an oversize write fail
    // with EFBIG instead of ending the process.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
        assert_eq!(libc::getrlimit(libc::RLIMIT_FSIZE, &mut limit), 0);
        limit.rlim_cur = bytes.min(limit.rlim_max);
        assert_eq!(libc::setrlimit(libc::RLIMIT_FSIZE, &limit), 0);
    }
}

#[test]
fn a_full_disk_stops_the_run_at_its_first_failed_write_and_leaves_no_temporaries() {
    let dir = std::env::temp_dir().join(format!("lowthrust-full-disk-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let manifest = Manifest {
        family: ScenarioKind::TransferCircular.family(),
        seed: 17,
        count: 4,
    };
    let spacecraft = Spacecraft::MSR_ERO.canonical().unwrap();
    let options = SolveOptions {
        final_eps: 0.3,
        ..SolveOptions::default()
    };
    // One worker: the run solves one record at a time, so exactly one is solved and lost.
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    set_file_size_limit(4096);
    let stopped = pool.install(|| generate(manifest, Shard::WHOLE, &dir, &spacecraft, &options, false));
    set_file_size_limit(libc::RLIM_INFINITY);
    match stopped {
        Err(GenerateError::RecordWrite {
            path,
            source,
            unwritten,
            written,
        }) => {
            assert_eq!(path, dir.join("records").join("00000000.rec"));
            assert_eq!(source.raw_os_error(), Some(libc::EFBIG));
            assert_eq!(
                (unwritten, written),
                (1, 0),
                "the run went on solving after its failed write"
            );
        }
        other => panic!("not stopped at the failed write: {other:?}"),
    }
    assert_eq!(
        files(&dir),
        [".lock", "manifest.json", "request.json"],
        "a failed write left a part behind"
    );
    // With room again, the same command finishes the run and leaves only its own files.
    let summary = generate(manifest, Shard::WHOLE, &dir, &spacecraft, &options, false).unwrap();
    assert_eq!(summary.records, 4);
    let left = files(&dir);
    assert!(left.iter().all(|f| !f.ends_with(".tmp")), "temporaries left: {left:?}");
    assert_eq!(left.iter().filter(|f| f.starts_with("records/")).count(), 4);
    std::fs::remove_dir_all(&dir).unwrap();
}
