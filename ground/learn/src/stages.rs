//! A recipe's stages (`[[stage]]`, `ground run` after the relabelling rounds): each stage runs
//! more relabelling rounds under settings changed from the stage before, started from that
//! stage's learner, in its own folder. What a chain of hand-run commands did (`ground data
//! generate`, then `ground train dagger --from ... --relabels-from ...`), as one recipe:
//!
//! ```text
//! RUN/stages/NAME/config.toml                 the stage's config (the recipe's, with its changes)
//! RUN/stages/NAME/dataset/                    its own demonstrations, when it changes [generate]
//! RUN/stages/NAME/start-actor.safetensors     the actor it starts from (start = "best-actor")
//! RUN/stages/NAME/dagger/...                  its rounds (crate::dagger)
//! ```
//!
//! Each stage resumes as the rounds do: from the files in its folder alone.

use std::path::{Path, PathBuf};

use crate::config::{ExperimentConfig, Stage, StageStart};
use crate::dagger::{dagger, DaggerSummary};
use crate::dataset::demonstrations;
use crate::error::ExperimentError;
use crate::eval::load_agent;
use crate::model::obs_dim;
use ground_core::generate::Summary;

/// Where a stage's rounds start: the learner that the stage before (or the recipe's own
/// rounds) ended with.
#[derive(Debug, Clone)]
pub struct StageInput {
    /// The config it ran with.
    pub config: ExperimentConfig,
    /// Its run folder (relabels under `dagger/`).
    pub folder: PathBuf,
    /// Its best learner checkpoint.
    pub best: PathBuf,
    /// Its rounds, when it ran any.
    pub rounds: Option<DaggerSummary>,
    /// The demonstrations its buffer started from.
    pub dataset: Summary,
}

/// What one stage produced.
#[derive(Debug, Clone)]
pub struct StageSummary {
    /// The stage's name (its folder `RUN/stages/NAME`).
    pub name: String,
    /// Where its rounds started.
    pub start: StageStart,
    /// Whether its first rounds are the stage before's relabels.
    pub inherited_relabels: bool,
    /// The demonstrations it solved for itself (a changed `[generate]`).
    pub new_dataset: Option<Summary>,
    /// Its rounds.
    pub rounds: DaggerSummary,
}

impl StageSummary {
    /// One line on where the learner came from, for the model card.
    pub fn lineage_line(&self) -> String {
        let first = self.rounds.rows.first().map_or(0, |r| r.round);
        let last = self.rounds.rows.last().map_or(0, |r| r.round);
        let start = match self.start {
            StageStart::Best => "the stage before's best learner",
            StageStart::BestActor => "the stage before's best actor alone",
            StageStart::Last => "the stage before's last round",
        };
        let relabels = if self.inherited_relabels {
            format!(", its relabels kept as rounds 1-{first}")
        } else {
            String::new()
        };
        let data = self.new_dataset.as_ref().map_or(String::new(), |d| {
            format!(", on {} new demonstrations (seed {})", d.records, d.seed)
        });
        format!(
            "stage {}: rounds {}-{last} from {start}{relabels}{data}; best round {}",
            self.name,
            first + 1,
            self.rounds.best_round
        )
    }
}

/// Runs `stage` with `config` (the recipe's config with the stage's changes) in
/// `RUN/stages/NAME`, started from what `before` ended with. Returns its summary and what the
/// next stage starts from.
pub fn run_stage(
    stage: &Stage,
    config: &ExperimentConfig,
    run: &Path,
    before: &StageInput,
) -> Result<(StageSummary, StageInput), ExperimentError> {
    let folder = run.join("stages").join(&stage.name);
    std::fs::create_dir_all(&folder).map_err(|e| ExperimentError::Io(folder.clone(), e))?;
    let mut config = config.clone();
    // Its own demonstrations where it changes what they are; else the stage before's.
    let (dataset, new_dataset) = if config.generate != before.config.generate {
        let dir = folder.join("dataset");
        let (summary, _) = demonstrations(&config, &dir)?;
        config.pretrain.dataset = Some(std::path::absolute(&dir).unwrap_or(dir));
        (summary.clone(), Some(summary))
    } else {
        config.pretrain.dataset = before.config.pretrain.dataset.clone();
        (before.dataset.clone(), None)
    };
    let start = match stage.start {
        StageStart::Best => before.best.clone(),
        StageStart::BestActor => {
            let path = folder.join("start-actor.safetensors");
            if !path.exists() {
                let agent = load_agent(&before.config, obs_dim(&before.config), &before.best)?;
                agent.save_flown_actor(&path)?;
            }
            path
        }
        StageStart::Last => {
            let rounds = before.rounds.as_ref().ok_or_else(|| {
                ExperimentError::Mismatch(format!("stage {}: the stage before ran no rounds", stage.name))
            })?;
            let last = rounds.rows.last().map_or(0, |r| r.round);
            rounds.folder.join(format!("round-{last}.safetensors"))
        }
    };
    let relabels_from = stage.inherit_relabels.then_some(before.folder.as_path());
    let rounds = dagger(&config, &folder, &folder, &start, relabels_from)?;
    let next = StageInput {
        best: rounds.folder.join("best.safetensors"),
        config,
        folder,
        rounds: Some(rounds.clone()),
        dataset,
    };
    let summary = StageSummary {
        name: stage.name.clone(),
        start: stage.start,
        inherited_relabels: stage.inherit_relabels,
        new_dataset,
        rounds,
    };
    Ok((summary, next))
}
