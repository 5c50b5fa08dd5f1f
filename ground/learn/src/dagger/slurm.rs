//! The relabels of a round solved as a Slurm array (`[compute.slurm]`): a request file beside
//! the round, one array task per share (`ground relabel-shard`, run by the array), answers
//! read back in order; the same results as solved here.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::relabel::{solve_job, RelabelJob, Solved};
use crate::config::{ExperimentConfig, SlurmConfig};
use crate::error::ExperimentError;
use crate::run_folder::write_file;
use ground_core::io::{checksum, decode_container, encode_container};

/// A batch of relabels for a Slurm array (`ground relabel-shard`): the run's config (its
/// scenarios, spacecraft, environment, final eps and arrival margin), the round's first training
/// scenario and
/// the relabels in order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RelabelRequest {
    /// The run's config as TOML.
    pub config: String,
    /// Index of the round's first training scenario (the round times 1,000,000).
    pub first: u64,
    /// The relabels, in order.
    pub jobs: Vec<RelabelJob>,
}

/// A task's answers: (relabel's position in the request, its tuples).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct RelabelShard {
    /// Checksum of the request file answered: a round run again reuses a task's answers only
    /// for the same request.
    request: u32,
    answers: Vec<(u64, Solved)>,
}

const REQUEST_MAGIC: [u8; 4] = *b"LTRQ";
// Version 2: a job's state of five or seven numbers; the answers' actions of three or four.
const REQUEST_VERSION: u16 = 2;
const SHARD_MAGIC: [u8; 4] = *b"LTRS";
const SHARD_VERSION: u16 = 3;

fn shard_file(request: &Path, task: u64, tasks: u64) -> PathBuf {
    request.with_extension(format!("{task}-of-{tasks}.ltrs"))
}

/// `ground relabel-shard`: solves the relabels `task`, `task + tasks`, ... of the request file
/// on this machine's cores and writes their answers beside it.
pub fn relabel_shard(request_path: &Path, task: u64, tasks: u64) -> Result<PathBuf, ExperimentError> {
    if tasks == 0 || task >= tasks {
        return Err(ExperimentError::Mismatch(format!(
            "shard {task}/{tasks}: the task must be below the task count"
        )));
    }
    let bytes = std::fs::read(request_path).map_err(|e| ExperimentError::Io(request_path.to_path_buf(), e))?;
    let request: RelabelRequest = decode_container(REQUEST_MAGIC, REQUEST_VERSION, &bytes)
        .map_err(|e| ExperimentError::Mismatch(format!("relabel request {}: {e}", request_path.display())))?;
    let config = ExperimentConfig::from_toml(&request.config)?;
    let mine: Vec<(u64, &RelabelJob)> = (task..request.jobs.len() as u64)
        .step_by(tasks as usize)
        .map(|i| (i, &request.jobs[i as usize]))
        .collect();
    let solve = |job: &RelabelJob| crate::with_flown_problem!(config, P => solve_job::<P>(&config, request.first, job));
    let answers = mine.par_iter().map(|&(i, job)| (i, solve(job))).collect();
    let out = shard_file(request_path, task, tasks);
    let shard = RelabelShard {
        request: checksum(&bytes),
        answers,
    };
    let bytes = encode_container(SHARD_MAGIC, SHARD_VERSION, &shard)
        .map_err(|e| ExperimentError::Io(out.clone(), std::io::Error::other(e.to_string())))?;
    write_file(&out, &bytes)?;
    Ok(out)
}

/// Solves `jobs` as a Slurm array: writes the request `DIR/relabel-TAG.ltrq`, runs `sbatch
/// --wait --array` on it, reads every task's answers back in the request's order and removes
/// the request and answer files. A task that failed or answered nothing fails the round and the
/// answers of the others are kept: the round run again (the same request) submits only the
/// tasks without answers.
pub(crate) fn solve_on_slurm(
    config: &ExperimentConfig,
    slurm: &SlurmConfig,
    dir: &Path,
    tag: &str,
    first: u64,
    jobs: Vec<RelabelJob>,
) -> Result<Vec<Solved>, ExperimentError> {
    if jobs.is_empty() {
        return Ok(Vec::new());
    }
    let count = jobs.len();
    let request_path = std::path::absolute(dir.join(format!("relabel-{tag}.ltrq")))
        .map_err(|e| ExperimentError::Io(dir.to_path_buf(), e))?;
    let request = RelabelRequest {
        config: config.to_toml(),
        first,
        jobs,
    };
    let bytes = encode_container(REQUEST_MAGIC, REQUEST_VERSION, &request)
        .map_err(|e| ExperimentError::Io(request_path.clone(), std::io::Error::other(e.to_string())))?;
    write_file(&request_path, &bytes)?;
    let request_sum = checksum(&bytes);
    let tasks = slurm.tasks.min(count as u64);
    let answered = |task: u64| -> Result<RelabelShard, String> {
        let path = shard_file(&request_path, task, tasks);
        let bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        let shard: RelabelShard = decode_container(SHARD_MAGIC, SHARD_VERSION, &bytes)
            .map_err(|e| format!("relabel answers {}: {e}", path.display()))?;
        if shard.request != request_sum {
            return Err(format!("relabel answers {} are for another request", path.display()));
        }
        Ok(shard)
    };
    // Answers a stopped round left for this request are read once and kept; the array solves
    // the others, whose answers are read after it.
    let mut shards: Vec<Option<RelabelShard>> = (0..tasks).map(|task| answered(task).ok()).collect();
    let missing: Vec<u64> = (0..tasks).filter(|&task| shards[task as usize].is_none()).collect();
    if !missing.is_empty() {
        submit_relabel_array(slurm, &request_path, tasks, &missing)?;
        for &task in &missing {
            shards[task as usize] = Some(answered(task).map_err(ExperimentError::Mismatch)?);
        }
    }
    let mut solved: Vec<Option<Solved>> = vec![None; count];
    for shard in shards.into_iter().flatten() {
        for (i, answer) in shard.answers {
            if let Some(slot) = solved.get_mut(i as usize) {
                *slot = Some(answer);
            }
        }
    }
    let solved: Vec<Solved> = solved.into_iter().collect::<Option<_>>().ok_or_else(|| {
        ExperimentError::Mismatch(format!(
            "the relabel array left relabels of {} unanswered",
            request_path.display()
        ))
    })?;
    for task in 0..tasks {
        let _ = std::fs::remove_file(shard_file(&request_path, task, tasks));
        let _ = std::fs::remove_file(request_path.with_extension(format!("slurm-{task}.out")));
    }
    let _ = std::fs::remove_file(&request_path);
    Ok(solved)
}

/// Runs `sbatch --wait` on the array tasks `which` (of `tasks`) of a relabel request.
fn submit_relabel_array(
    slurm: &SlurmConfig,
    request_path: &Path,
    tasks: u64,
    which: &[u64],
) -> Result<(), ExperimentError> {
    let ground = match &slurm.ground {
        Some(path) => path.clone(),
        None => std::env::current_exe().map_err(|e| ExperimentError::Io(PathBuf::from("ground"), e))?,
    };
    // Quoted as a card's command is: the batch script runs the line in a POSIX shell.
    let quoted = |p: &Path| -> Result<String, ExperimentError> {
        let text = p.to_str().ok_or_else(|| {
            ExperimentError::Mismatch(format!(
                "{}: a Slurm task cannot be given a path that is not UTF-8",
                p.display()
            ))
        })?;
        Ok(crate::model::shell_words(&[text.to_string()]))
    };
    let command = format!(
        "{} relabel-shard --request {} --shard \"$SLURM_ARRAY_TASK_ID/{tasks}\"",
        quoted(&ground)?,
        quoted(request_path)?
    );
    // Slurm's array syntax: a range for every task, else the list.
    let array = if which.len() as u64 == tasks {
        format!("0-{}", tasks - 1)
    } else {
        which.iter().map(u64::to_string).collect::<Vec<_>>().join(",")
    };
    let log = request_path.with_extension("slurm-%a.out");
    let status = std::process::Command::new(&slurm.sbatch)
        .arg("--wait")
        .arg("--job-name=lowthrust-relabel")
        .arg(format!("--array={array}"))
        .arg(format!("--output={}", log.display()))
        .args(&slurm.options)
        .arg("--wrap")
        .arg(&command)
        .stdout(std::process::Stdio::null())
        .status()
        .map_err(|e| ExperimentError::Io(PathBuf::from(&slurm.sbatch), e))?;
    if !status.success() {
        return Err(ExperimentError::Mismatch(format!(
            "the relabel array ({}) ended with {status}: see {}; the tasks that answered are kept, and \
             the same command submits only the others",
            slurm.sbatch,
            log.display()
        )));
    }
    Ok(())
}
