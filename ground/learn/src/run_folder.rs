//! The run folder every stage writes into, and what makes it one experiment's:
//!
//! ```text
//! RUN/config.toml                      the config that produced everything below
//! RUN/pretrain/{best,last}.safetensors the best (by evaluation) and latest learner state
//! RUN/pretrain/replay.ltrb             the demonstration buffer handed to RL
//! RUN/pretrain/{eval,updates}.csv      evaluation rows and loss averages, plus SVG plots
//! RUN/train-{scratch,pretrained}/...   the same for RL, plus state.json for resumption
//! RUN/dagger/...                       the relabelling rounds (crate::dagger)
//! RUN/mc, RUN/export, RUN/sil-*, RUN/model   Monte Carlo, blobs, SIL, the shipped model
//! ```
//!
//! Every file is written atomically; a refused stage writes nothing; an interrupted stage
//! resumes from its last checkpoint. The folder's lock (one process at a time) is taken by
//! the command line around a whole stage (`ground_core::io::RunLock`).

use std::path::Path;

use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use crate::sac::replay::ReplayBuffer;
use ground_core::io::{atomic_write, decode_container, encode_container};

const REPLAY_MAGIC: [u8; 4] = *b"LTRB";
const REPLAY_VERSION: u16 = 1;

/// Writes `bytes` to `path` atomically.
pub(crate) fn write_file(path: &Path, bytes: &[u8]) -> Result<(), ExperimentError> {
    atomic_write(path, bytes).map_err(|e| ExperimentError::Io(path.to_path_buf(), e))
}

pub(crate) fn save_replay(path: &Path, buffer: &ReplayBuffer) -> Result<(), ExperimentError> {
    let bytes = encode_container(REPLAY_MAGIC, REPLAY_VERSION, buffer)
        .map_err(|e| ExperimentError::Io(path.to_path_buf(), std::io::Error::other(e.to_string())))?;
    write_file(path, &bytes)
}

pub(crate) fn load_replay(path: &Path, obs_dim: usize, act_dim: usize) -> Result<ReplayBuffer, ExperimentError> {
    let bytes = std::fs::read(path).map_err(|e| ExperimentError::Io(path.to_path_buf(), e))?;
    let buffer: ReplayBuffer = decode_container(REPLAY_MAGIC, REPLAY_VERSION, &bytes)
        .map_err(|e| ExperimentError::Mismatch(format!("replay buffer {}: {e}", path.display())))?;
    if buffer.obs_dim() != obs_dim || buffer.act_dim() != act_dim {
        return Err(ExperimentError::Mismatch(format!(
            "replay buffer {} holds {}-feature observations and {}-component actions, this problem has {obs_dim} and {act_dim}",
            path.display(),
            buffer.obs_dim(),
            buffer.act_dim()
        )));
    }
    Ok(buffer)
}

/// Refuses a run folder that holds a run of another experiment (reads only).
pub fn check_run(config: &ExperimentConfig, run: &Path) -> Result<(), ExperimentError> {
    let path = run.join("config.toml");
    let Ok(existing) = std::fs::read_to_string(&path) else {
        return Ok(());
    };
    let previous = ExperimentConfig::from_toml(&existing)?;
    // What the folder's checkpoints and saved relabels depend on (an averaged actor is part of
    // the checkpoints).
    let same = |c: &ExperimentConfig| (c.relabel_problem(), c.sac.hidden.clone(), c.sac.actor_averaging > 0.0);
    if previous.family != config.family {
        return Err(ExperimentError::Mismatch(format!(
            "{} holds a run of scenario family {}, not {}: its checkpoints and relabels fly another family; use a new folder",
            run.display(),
            previous.family.label(),
            config.family.label()
        )));
    }
    if same(&previous) != same(config) {
        return Err(ExperimentError::Mismatch(format!(
            "{} holds a run of another experiment (scenario, network, seeds, actor averaging, final eps or arrival margin differ); use a new folder",
            run.display()
        )));
    }
    Ok(())
}

/// Writes the config next to the phase outputs, or refuses if the run folder holds another one.
/// Phases call it once their inputs have loaded, so a refused phase writes nothing.
pub fn prepare_run(config: &ExperimentConfig, run: &Path) -> Result<(), ExperimentError> {
    check_run(config, run)?;
    write_file(&run.join("config.toml"), config.to_toml().as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run folder continues under a config that only asks for more work, and refuses one whose
    /// checkpoints or relabels would mean something else.
    #[test]
    fn a_run_folder_refuses_a_config_of_another_experiment() {
        let run = std::env::temp_dir().join(format!("lowthrust-check-run-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&run);
        std::fs::create_dir_all(&run).unwrap();
        let base = "scenario = \"rendezvous-circular\"\n[generate]\nfinal_eps = 0.016\n";
        let config = |extra: &str| ExperimentConfig::from_toml(&format!("{base}{extra}")).unwrap();
        prepare_run(&config(""), &run).unwrap();
        assert!(check_run(&config("[pretrain]\nupdates = 123456\n"), &run).is_ok());
        for other in [
            "arrival_margin = 2\n",
            "[seeds]\ntrain = 99\n",
            "[sac]\nhidden = [64, 64]\n",
        ] {
            assert!(
                matches!(check_run(&config(other), &run), Err(ExperimentError::Mismatch(_))),
                "{other}"
            );
        }
        let other_eps =
            ExperimentConfig::from_toml("scenario = \"rendezvous-circular\"\n[generate]\nfinal_eps = 0.25\n").unwrap();
        assert!(matches!(check_run(&other_eps, &run), Err(ExperimentError::Mismatch(_))));
        // Another family: both named.
        let weekly = ExperimentConfig::from_toml(&format!(
            "[scenario]\nproblem = \"rendezvous\"\nbody = \"sun\"\ndeparture = {{ a = [1.0, 1.52], e = 1e-4, omega = 0.0 }}\n\
             target = {{ a = [1.0, 1.52], e = 1e-4, omega = 0.0 }}\ntime_of_flight = \"longer-period\"\ncycle = {{ days = 7.0 }}\n{}",
            base.trim_start_matches("scenario = \"rendezvous-circular\"\n")
        ))
        .unwrap();
        let refused = check_run(&weekly, &run).unwrap_err().to_string();
        assert!(
            refused.contains("rendezvous-circular") && refused.contains(weekly.family.label().as_str()),
            "{refused}"
        );
        std::fs::remove_dir_all(&run).unwrap();
    }
}
