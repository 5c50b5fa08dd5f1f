//! What stops a stage: one error type for every stage of the learning stack.

use std::path::PathBuf;

use crate::config::ConfigError;
use crate::sac::agent::CheckpointError;
use ground_core::env::batch::EvalError;
use ground_core::env::EnvError;

/// Why a phase could not run or stopped.
#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    /// The config was refused, or its dataset or device is not there.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The trajectory dataset could not be read or gave no demonstration tuples.
    #[error("dataset: {0}")]
    Dataset(String),
    /// A checkpoint or actor file could not be read or written.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// A file of the run folder could not be read or written: its path and the I/O error.
    #[error("{}: {}", .0.display(), .1)]
    Io(PathBuf, std::io::Error),
    /// The evaluation episodes could not be flown.
    #[error("evaluation: {0}")]
    Evaluation(EvalError),
    /// A file in the run folder belongs to another experiment (problem, shapes).
    #[error("{0}")]
    Mismatch(String),
    /// The environment refused to start an episode.
    #[error("environment: {0}")]
    Environment(EnvError),
    /// The stage flies planar families only and the config's family is inclined.
    #[error("{stage} flies planar families only; family {family} has inclined orbits")]
    Inclined {
        /// The stage refused.
        stage: &'static str,
        /// The family's label.
        family: String,
    },
}

// Not `#[from]`: the message already carries the evaluation error, so it is no separate source.
impl From<EvalError> for ExperimentError {
    fn from(e: EvalError) -> Self {
        Self::Evaluation(e)
    }
}
