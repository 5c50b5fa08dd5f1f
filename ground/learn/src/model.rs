//! A shipped controller (`models/NAME/`): the flown actor's weights, its onboard blobs and a
//! model card, bound together so that files that disagree are refused by whatever opens them.
//!
//! ```text
//! actor.safetensors    the flown actor alone (tensors actor.l0.*, actor.l1.*, actor.mean.*,
//!                      actor.log_std.*), with its CRC-32 in the safetensors metadata
//! transfer-f32.blob    the onboard blobs (`ground model export`), flown by `ground model sil`
//! transfer-int8.blob
//! actor.onnx           the actor's deterministic action as an ONNX model
//! card.json            the card for machines: config, commit, command, data, figures, and the
//!                      CRC-32C of every file above
//! card.md              the same for people
//! ```
//!
//! [`open_model`] checks every file against the card's CRC-32C and that the f32 blob holds
//! exactly the actor's weights (it re-encodes them; both checks are
//! `ground_core::model_files`', which the Python package runs too); `ground model evaluate --model` and `ground model sil
//! --model` fly only what passed.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use shared::blob::{ProblemKind, Quantization};

use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use crate::eval::{eccentricity_line, EccentricityBand, MonteCarloReport, SolvedShare};
use crate::export::{blob_file, ExportReport};
use crate::sac::agent::Sac;
use crate::sil::SilReport;
use ground_core::env::batch::OutcomeSummary;
use ground_core::generate::Summary;
use ground_core::io::atomic_write;
use ground_core::model_files::{lookahead_terms, verify_model_files, ModelFilesError};
use onboard::lookahead::LookaheadSettings;
use onboard::terminal::TerminalSettings;

pub use ground_core::model_files::{Aids, ACTOR_FILE, ONNX_FILE};
/// The card for machines.
pub const CARD_JSON: &str = "card.json";
/// The card for people.
pub const CARD_MD: &str = "card.md";
/// Version of the card's layout: 3 is sealed (`seal`, the CRC-32C of the rest of its content).
pub const CARD_FORMAT: u32 = 3;
/// The last layout without a seal, which the commands that write a card again accept.
const UNSEALED_CARD_FORMAT: u32 = 2;

/// Why a model folder was refused.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// A file of the folder could not be read or written.
    #[error("{}: {source}", .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// card.json does not parse or cannot be written, or its config is refused.
    #[error("{}: the card does not parse: {reason}", .path.display())]
    Card {
        /// The card.json file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A config's onboard aids ([`Aids`]) are refused.
    #[error("{}: no onboard aids to fly (the [sil] tables lookahead and terminal of a config): {reason}", .path.display())]
    Aids {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// card.md does not say what card.json says (edited by hand, or written by another writer).
    #[error("{}: does not say what card.json says (both are written by the card's writer)", .path.display())]
    MarkdownDisagrees {
        /// The card.md file.
        path: PathBuf,
    },
    /// card.json's content is not what its writer sealed: edited by hand after it was written.
    #[error(transparent)]
    CardEdited(ModelFilesError),
    /// The card is of another layout than [`CARD_FORMAT`].
    #[error(
        "{}: card format {found}, this version reads {CARD_FORMAT}{}",
        .path.display(),
        if *.found == UNSEALED_CARD_FORMAT {
            " (format 2 is not sealed: `ground model export --model DIR --onnx-only --out RUN` checks the folder's files and seals its card)"
        } else {
            ""
        }
    )]
    Format {
        /// The card.json file.
        path: PathBuf,
        /// The format it declares.
        found: u32,
    },
    /// A file's CRC-32C is not the one the card records: not the file the card describes.
    #[error("{}: CRC-32C {found}, the card says {recorded}: the file is not the one the card describes", .path.display())]
    Checksum {
        /// The file.
        path: PathBuf,
        /// Its CRC-32C (8 hex digits).
        found: String,
        /// The card's.
        recorded: String,
    },
    /// The f32 blob does not decode or is not the actor's weights encoded again.
    #[error("{}: the f32 blob does not hold the actor's weights", .path.display())]
    BlobDisagrees {
        /// The f32 blob.
        path: PathBuf,
    },
    /// A blob cannot be read or converted ([`upgrade_model`]).
    #[error("{}: {source}", .path.display())]
    Blob {
        /// The blob.
        path: PathBuf,
        /// Why it is refused.
        source: shared::blob::BlobError,
    },
    /// The card does not list a file every model has (the actor, either blob).
    #[error("model folder {}: {reason}", .dir.display())]
    Incomplete {
        /// The model folder.
        dir: PathBuf,
        /// What is missing.
        reason: String,
    },
    /// Reading or writing the actor, or exporting or flying the blobs, failed.
    #[error(transparent)]
    Experiment(#[from] Box<ExperimentError>),
}

/// Figures of a policy over a set of episodes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlightFigures {
    /// Episodes flown.
    pub episodes: usize,
    /// Of those, the ones that reached their terminal step.
    pub completed: usize,
    /// (tolerance, share of the completed episodes with |dr| (AU) and |dv| within it).
    pub within: Vec<(f64, f64)>,
    /// Median terminal position residual |dr| (AU).
    pub dr_p50: f64,
    /// 95th percentile of |dr| (AU).
    pub dr_p95: f64,
    /// Median terminal velocity residual |dv| (AU/t*).
    pub dv_p50: f64,
    /// 95th percentile of |dv| (AU/t*).
    pub dv_p95: f64,
    /// Mean final mass (fraction of m0).
    pub final_mass_mean: f64,
}

impl FlightFigures {
    fn of(report: &MonteCarloReport) -> Self {
        let p: &OutcomeSummary = &report.policy;
        Self {
            episodes: p.episodes,
            completed: p.completed,
            within: report.within_tolerances.clone(),
            dr_p50: p.terminal_position.p50,
            dr_p95: p.terminal_position.p95,
            dv_p50: p.terminal_velocity.p50,
            dv_p95: p.terminal_velocity.p95,
            final_mass_mean: p.final_mass.mean,
        }
    }

    /// The share within `tolerance`, if it was measured.
    pub fn share_within(&self, tolerance: f64) -> Option<f64> {
        self.within.iter().find(|(t, _)| *t == tolerance).map(|(_, s)| *s)
    }
}

/// The model card: where the controller came from and what it does.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelCard {
    /// The card's layout version, [`CARD_FORMAT`] when written.
    pub format: u32,
    /// Name of the scenario distribution the controller was trained and measured on.
    pub scenario: String,
    /// The command that produced it and the commit it was built from.
    pub command: String,
    /// The commit ([`current_commit`]; `+modified` when the tree had uncommitted changes).
    pub commit: String,
    /// UTC date of the card.
    pub created: String,
    /// The experiment config (TOML).
    pub config: String,
    /// The demonstrations: records, converged, seed, final eps.
    pub demonstrations: (usize, usize, u64, f64),
    /// Relabelling rounds run, and the one kept (None without rounds).
    pub rounds: Option<(u64, u64)>,
    /// The Monte Carlo of the actor (the config's episodes, seed `monte_carlo_seed`).
    pub monte_carlo: FlightFigures,
    /// Seed of the Monte Carlo's scenario draws.
    pub monte_carlo_seed: u64,
    /// Propellant overspend against the indirect optimum: (scenarios, median, p95).
    pub overspend: Option<(usize, f64, f64)>,
    /// The blobs flown in the SIL loop with the config's dispersions: (blob file, figures).
    pub sil: Vec<(String, FlightFigures)>,
    /// Every file of the folder but the cards, with its CRC-32C (8 hex digits).
    pub files: BTreeMap<String, String>,
    /// When the blobs were exported again from the same actor ([`reexport_model`], after a blob
    /// format change): (command, commit, UTC date). The actor and its Monte Carlo are unchanged.
    #[serde(default)]
    pub reexported: Option<(String, String, String)>,
    /// The blob format of that export (absent: format 3, the format of every export before
    /// the field was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reexported_format: Option<u16>,
    /// Where the controller came from beyond the config (`ground model ship --note`).
    #[serde(default)]
    pub notes: Vec<String>,
    /// The goal's share on the Monte Carlo scenarios the indirect method solved.
    #[serde(default)]
    pub where_solved: Option<SolvedShare>,
    /// The goal's share by eccentricity (eccentric distributions only).
    #[serde(default)]
    pub by_eccentricity: Vec<EccentricityBand>,
    /// The controller flown with rollout lookahead (`[sil] lookahead` in the config): its nominal
    /// Monte Carlo; the SIL rows above are then flown with it too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lookahead: Option<LookaheadFigures>,
    /// The terminal targeting the SIL rows flew their last cycles with (`[sil] terminal`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub terminal: Option<TerminalSettings>,
    /// The controller flown with terminal targeting and no lookahead: its nominal Monte Carlo
    /// (with lookahead, `lookahead` holds it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub with_terminal: Option<FlownFigures>,
    /// The CRC-32C of the rest of the card's content (`ground_core::model_files::card_seal`),
    /// set when it is written: a card edited by hand is refused.
    #[serde(default)]
    pub seal: String,
}

impl ModelCard {
    /// The figures of the controller as it flies, with its onboard aids (the lookahead's, or
    /// terminal targeting's alone); None for a network flown alone.
    pub fn as_flown(&self) -> Option<&FlownFigures> {
        self.lookahead
            .as_ref()
            .map(|l| &l.flown)
            .or(self.with_terminal.as_ref())
    }
}

/// The f32 blob flown with its onboard aids on the Monte Carlo's scenarios, no dispersions: the
/// controller as it flies, where the card's Monte Carlo row is the network alone.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlownFigures {
    /// Figures of the nominal Monte Carlo flown with the aids.
    pub monte_carlo: FlightFigures,
    /// Propellant overspend against the indirect optimum: (scenarios, median, p95).
    pub overspend: Option<(usize, f64, f64)>,
    /// The goal's share on the scenarios the indirect method solved.
    pub where_solved: Option<SolvedShare>,
    /// The goal's share by eccentricity (eccentric distributions only).
    pub by_eccentricity: Vec<EccentricityBand>,
}

impl FlownFigures {
    /// The figures of a nominal SIL Monte Carlo.
    pub fn of(report: &SilReport) -> Self {
        let mc = &report.monte_carlo;
        Self {
            monte_carlo: FlightFigures::of(mc),
            overspend: mc.overspend.as_ref().map(|o| (o.count, o.p50, o.p95)),
            where_solved: mc.where_solved,
            by_eccentricity: mc.accuracy_by_eccentricity.clone(),
        }
    }
}

/// The f32 blob flown with rollout lookahead on the Monte Carlo's scenarios, no dispersions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LookaheadFigures {
    /// What the lookahead weighed.
    pub settings: LookaheadSettings,
    /// The nominal Monte Carlo flown with lookahead (and terminal targeting where the config
    /// flies it too).
    #[serde(flatten)]
    pub flown: FlownFigures,
}

impl LookaheadFigures {
    /// The figures of a nominal SIL Monte Carlo flown with lookahead (None without it).
    pub fn of(report: &SilReport) -> Option<Self> {
        Some(Self {
            settings: report.lookahead?,
            flown: FlownFigures::of(report),
        })
    }
}

/// The onboard aids a card's config flies, in words: "rollout lookahead", "terminal targeting
/// of the last K cycles", or both.
pub fn aids_flown(card: &ModelCard) -> String {
    let terminal = card
        .terminal
        .map(|t| format!("terminal targeting of the last {} cycles", t.cycles));
    match (card.lookahead.is_some(), terminal) {
        (true, Some(t)) => format!("rollout lookahead and {t}"),
        (true, None) => "rollout lookahead".into(),
        (false, Some(t)) => t,
        (false, None) => "the network alone".into(),
    }
}

/// `blob` flown with the config's onboard aids ([`aided_monte_carlo`](crate::sil::aided_monte_carlo),
/// under `run`): the card's figures of it, as [`aided_figures`] sorts them.
fn fly_aided(
    config: &ExperimentConfig,
    blob: &Path,
    run: &Path,
) -> Result<(Option<LookaheadFigures>, Option<FlownFigures>), ModelError> {
    let aided = crate::sil::aided_monte_carlo(config, blob, run, crate::eval::Optima::Solve(None))
        .map_err(|e| ModelError::Experiment(Box::new(e)))?;
    Ok(aided_figures(aided.as_ref()))
}

/// The card's figures of a nominal Monte Carlo flown with the onboard aids ([`aided_monte_carlo`]
/// (crate::sil::aided_monte_carlo)): (with lookahead, with terminal targeting alone).
fn aided_figures(report: Option<&SilReport>) -> (Option<LookaheadFigures>, Option<FlownFigures>) {
    match report {
        Some(r) if r.lookahead.is_some() => (LookaheadFigures::of(r), None),
        Some(r) if r.terminal.is_some() => (None, Some(FlownFigures::of(r))),
        _ => (None, None),
    }
}

fn crc_of(path: &Path) -> Result<String, ModelError> {
    ground_core::model_files::file_checksum(path).map_err(ModelError::from)
}

impl From<ModelFilesError> for ModelError {
    fn from(error: ModelFilesError) -> Self {
        match error {
            ModelFilesError::Io { path, source } => Self::Io { path, source },
            ModelFilesError::Checksum { path, found, recorded } => Self::Checksum { path, found, recorded },
            ModelFilesError::Incomplete { dir, missing } => Self::Incomplete {
                dir,
                reason: format!("the card lists no {missing}"),
            },
            ModelFilesError::BlobDisagrees { path } => Self::BlobDisagrees { path },
            ModelFilesError::Actor(e) => Self::Experiment(Box::new(ExperimentError::Mismatch(e.to_string()))),
            ModelFilesError::CardUnreadable { path, reason } => Self::Card { path, reason },
            edited @ ModelFilesError::CardEdited { .. } => Self::CardEdited(edited),
        }
    }
}

/// Writes the actor's ONNX model into the folder `dir` from its actor file (the provenance of
/// its f32 blob in the model's metadata) and returns the file's CRC-32C.
fn write_onnx(dir: &Path, kind: ProblemKind) -> Result<String, ModelError> {
    let f32_path = dir.join(blob_file(kind, Quantization::F32));
    let blob = std::fs::read(&f32_path).map_err(io(&f32_path))?;
    let (provenance, features) = shared::blob::decode(&blob)
        .map(|b| (b.provenance.to_string(), b.features))
        .map_err(|_| ModelError::BlobDisagrees { path: f32_path.clone() })?;
    let network =
        ground_core::actor_file::read_actor(&dir.join(ACTOR_FILE), features).map_err(ModelFilesError::from)?;
    let bytes = ground_core::onnx::actor_onnx(&network, &[("provenance", &provenance)])
        .map_err(|e| ModelError::Experiment(Box::new(ExperimentError::Mismatch(e.to_string()))))?;
    let path = dir.join(ONNX_FILE);
    atomic_write(&path, &bytes).map_err(io(&path))?;
    crc_of(&path)
}

/// `ground model export --model DIR --onnx-only`: adds the actor's ONNX model to a shipped
/// model folder and binds it in the card (the blobs, the actor and the figures untouched), and
/// writes card.md again from card.json (after a change of the card's layout for people). The
/// folder's files must match its card first.
pub fn add_onnx(dir: &Path) -> Result<ModelCard, ModelError> {
    let (mut card, config) = read_card(dir, Unsealed::Accepted)?;
    let kind = config.problem();
    verify_model_files(dir, config.feature_layout(), &card.files)?;
    let crc = write_onnx(dir, kind)?;
    card.files.insert(ONNX_FILE.to_string(), crc);
    write_cards(dir, &mut card)?;
    Ok(card)
}

/// How a card's note on SIL rows flown again by [`fly_aids`] begins.
const REFLOWN_NOTE: &str = "The SIL rows are the same blobs flown";

/// The onboard aids of the config file at `path` (TOML; `ground model export --model DIR --aids
/// CONFIG`, the model's recipe as a rule): its `[sil]` tables `lookahead` and `terminal`, their
/// keys checked; the rest of the file is not read.
pub fn read_aids(path: &Path) -> Result<Aids, ModelError> {
    let refused = |reason: String| ModelError::Aids {
        path: path.to_path_buf(),
        reason,
    };
    let text = std::fs::read_to_string(path).map_err(io(path))?;
    let mut file: toml::Table = toml::from_str(&text).map_err(|e| refused(e.to_string()))?;
    let Some(toml::Value::Table(mut sil)) = file.remove("sil") else {
        return Err(refused("it has no [sil] table".into()));
    };
    fn aid<T: serde::de::DeserializeOwned>(sil: &mut toml::Table, name: &str) -> Result<Option<T>, String> {
        sil.remove(name)
            .map(|table| {
                table
                    .try_into()
                    .map_err(|e: toml::de::Error| format!("sil.{name}: {e}"))
            })
            .transpose()
    }
    Ok(Aids {
        lookahead: aid(&mut sil, "lookahead").map_err(refused)?,
        terminal: aid(&mut sil, "terminal").map_err(refused)?,
    })
}

/// `ground model export --model DIR --terminal-cycles K --out RUN`: [`fly_aids`] with terminal
/// targeting over the last `K` cycles (its other settings the defaults; 0: without) and the
/// card's lookahead as it was.
pub fn fly_terminal(dir: &Path, run: &Path, cycles: u32) -> Result<(ModelCard, Vec<SilReport>), ModelError> {
    let (_, config) = read_card(dir, Unsealed::Refused)?;
    let aids = Aids {
        lookahead: config.sil.lookahead,
        terminal: (cycles > 0).then(|| TerminalSettings {
            cycles,
            ..TerminalSettings::default()
        }),
    };
    fly_aids(dir, run, &aids)
}

/// `ground model export --model DIR --aids CONFIG --out RUN`: the shipped blobs, unchanged, flown
/// in the SIL loop with the onboard `aids`, which the card then records: its config's `[sil]`
/// lookahead and terminal tables, its SIL rows and its nominal Monte Carlo with the aids (flown
/// under `RUN`) and a note of the command. The actor, the blobs and the Monte Carlo stay as they
/// are. The folder's files must match its card first.
pub fn fly_aids(dir: &Path, run: &Path, aids: &Aids) -> Result<(ModelCard, Vec<SilReport>), ModelError> {
    let (mut card, mut config) = read_card(dir, Unsealed::Refused)?;
    let kind = config.problem();
    verify_model_files(dir, config.feature_layout(), &card.files)?;
    let experiment = |e: ExperimentError| ModelError::Experiment(Box::new(e));
    config.sil.lookahead = aids.lookahead;
    config.sil.terminal = aids.terminal;
    config.validate().map_err(|e| experiment(e.into()))?;
    let blob = |q| dir.join(blob_file(kind, q));
    let sil = crate::sil::sil_of_blobs(&config, &blob(Quantization::F32), &blob(Quantization::Int8), run)
        .map_err(experiment)?
        .to_vec();
    card.sil = sil_figures(&sil);
    card.terminal = config.terminal_settings();
    (card.lookahead, card.with_terminal) = fly_aided(&config, &blob(Quantization::F32), run)?;
    card.config = portable_config(&config);
    // The rows are flown once more: an earlier such note no longer describes them.
    card.notes.retain(|note| !note.starts_with(REFLOWN_NOTE));
    card.notes.push(format!(
        "{REFLOWN_NOTE} {}, by `{}` at commit `{}` on {}; the actor, the blobs and the Monte Carlo are unchanged.",
        aids.describe(),
        portable_command(),
        current_commit(),
        utc_date()
    ));
    write_cards(dir, &mut card)?;
    Ok((card, sil))
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ModelError + '_ {
    move |source| ModelError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The commit of the working tree the command runs in ("unknown" outside a git checkout;
/// "+modified" when it has uncommitted changes).
pub fn current_commit() -> String {
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    match git(&["rev-parse", "--short=12", "HEAD"]) {
        Some(commit) => match git(&["status", "--porcelain", "--untracked-files=no"]) {
            Some(changes) if !changes.is_empty() => format!("{commit}+modified"),
            _ => commit,
        },
        None => "unknown".into(),
    }
}

/// What [`write_model`] is given: the run's stages' results.
pub struct ModelSources<'a> {
    /// The run's config.
    pub config: &'a ExperimentConfig,
    /// The commit the run was built from ([`current_commit`] when it started).
    pub commit: &'a str,
    /// The checkpoint whose flown actor is shipped.
    pub checkpoint: &'a Path,
    /// The demonstration dataset's summary.
    pub dataset: &'a Summary,
    /// Relabelling rounds run and the one kept (None without rounds).
    pub rounds: Option<(u64, u64)>,
    /// The Monte Carlo of the checkpoint.
    pub monte_carlo: &'a MonteCarloReport,
    /// The export whose blobs are shipped.
    pub export: &'a ExportReport,
    /// The blobs' SIL Monte Carlos with the config's dispersions.
    pub sil: &'a [SilReport],
    /// The nominal Monte Carlo of the f32 blob with the onboard aids, when the config flies
    /// any ([`aided_monte_carlo`](crate::sil::aided_monte_carlo)).
    pub aided: Option<&'a SilReport>,
    /// Lines for the card on where the controller came from beyond the config (e.g. the
    /// shipped actor its rounds started from).
    pub notes: &'a [String],
}

/// Writes the model folder `dir` (created; files replaced atomically): the flown actor, the
/// export's blobs, and the cards.
pub fn write_model(dir: &Path, sources: &ModelSources) -> Result<ModelCard, ModelError> {
    let config = sources.config;
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let agent = crate::eval::load_agent(config, obs_dim(config), sources.checkpoint)
        .map_err(|e| ModelError::Experiment(Box::new(e)))?;
    agent
        .save_flown_actor(&dir.join(ACTOR_FILE))
        .map_err(|e| ModelError::Experiment(Box::new(e.into())))?;
    let mut files = BTreeMap::new();
    files.insert(ACTOR_FILE.to_string(), crc_of(&dir.join(ACTOR_FILE))?);
    for blob in [
        &sources.export.f32.file,
        &sources.export.int8.file,
        &sources.export.onnx,
    ] {
        let name = blob
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let bytes = std::fs::read(blob).map_err(io(blob))?;
        let target = dir.join(&name);
        atomic_write(&target, &bytes).map_err(io(&target))?;
        files.insert(name, crc_of(&target)?);
    }
    let mc = sources.monte_carlo;
    let (lookahead, with_terminal) = aided_figures(sources.aided);
    let mut card = ModelCard {
        format: CARD_FORMAT,
        scenario: config.display_name(),
        command: portable_command(),
        commit: sources.commit.to_string(),
        created: utc_date(),
        config: portable_config(config),
        demonstrations: (
            sources.dataset.records,
            sources.dataset.converged,
            sources.dataset.seed,
            config.generate.final_eps,
        ),
        rounds: sources.rounds,
        monte_carlo: FlightFigures::of(mc),
        monte_carlo_seed: mc.seed,
        overspend: mc.overspend.as_ref().map(|o| (o.count, o.p50, o.p95)),
        sil: sil_figures(sources.sil),
        files,
        reexported: None,
        reexported_format: None,
        notes: sources.notes.to_vec(),
        where_solved: mc.where_solved,
        by_eccentricity: mc.accuracy_by_eccentricity.clone(),
        lookahead,
        terminal: config.terminal_settings(),
        with_terminal,
        seal: String::new(),
    };
    write_cards(dir, &mut card)?;
    Ok(card)
}

/// The card's SIL rows: (blob file name, figures) per report.
fn sil_figures(sil: &[SilReport]) -> Vec<(String, FlightFigures)> {
    sil.iter()
        .map(|r| {
            let name = r
                .blob
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            (name, FlightFigures::of(&r.monte_carlo))
        })
        .collect()
}

/// Writes card.json and card.md, then opens the folder with every reader's checks.
fn write_cards(dir: &Path, card: &mut ModelCard) -> Result<(), ModelError> {
    let unwritable = |e: serde_json::Error| ModelError::Card {
        path: dir.join(CARD_JSON),
        reason: e.to_string(),
    };
    card.format = CARD_FORMAT;
    card.seal = String::new();
    card.seal = serde_json::to_string_pretty(&*card)
        .and_then(|unsealed| ground_core::model_files::seal_of_text(&unsealed))
        .map_err(unwritable)?;
    let json = serde_json::to_string_pretty(&*card).map_err(unwritable)?;
    atomic_write(&dir.join(CARD_JSON), json.as_bytes()).map_err(io(&dir.join(CARD_JSON)))?;
    atomic_write(&dir.join(CARD_MD), card_markdown(card).as_bytes()).map_err(io(&dir.join(CARD_MD)))?;
    open_model(dir)?;
    Ok(())
}

/// What [`reexport_model`] did.
pub struct Reexport {
    /// The card as rewritten.
    pub card: ModelCard,
    /// The new export (under `run/export`).
    pub export: ExportReport,
    /// The new blobs' SIL Monte Carlos (transfers only; empty for rendezvous).
    pub sil: Vec<SilReport>,
}

/// `ground model export --model DIR`: exports the blobs of a shipped model again from its actor with
/// its card's config (after a blob format change; the actor, and so its Monte Carlo, stay as
/// they are), flies them in the SIL loop, and replaces the blobs and the card's SIL figures and
/// file checksums. The export and SIL Monte Carlos are written under `run`. The folder's files
/// other than the blobs must still match the card; its blobs may be of an older format.
pub fn reexport_model(dir: &Path, run: &Path) -> Result<Reexport, ModelError> {
    // Before the folder changes, which would mark the tree modified.
    let commit = current_commit();
    let (mut card, config) = read_card(dir, Unsealed::Accepted)?;
    let actor = dir.join(ACTOR_FILE);
    let recorded = card.files.get(ACTOR_FILE).cloned().unwrap_or_default();
    let found = crc_of(&actor)?;
    if found != recorded {
        return Err(ModelError::Checksum {
            path: actor,
            found,
            recorded,
        });
    }
    let experiment = |e: ExperimentError| ModelError::Experiment(Box::new(e));
    // The card's paths are relative to the folder the producing command ran in: the repository.
    let export = crate::export::export(&config, Path::new("."), &actor, &run.join("export")).map_err(experiment)?;
    let sil = install_blobs(
        dir,
        &mut card,
        &config,
        [&export.f32.file, &export.int8.file],
        &[&export.onnx],
        run,
        commit,
    )?;
    Ok(Reexport { card, export, sil })
}

/// The last steps of [`reexport_model`] and [`upgrade_model`]: flies the new blobs (the SIL
/// Monte Carlos of both, the card's aids with the f32 one) under `run`, then copies them and
/// `others` into the folder `dir` under their file names and writes the card again with their
/// checksums, the new figures and `commit`. The folder changes only once every flight is done.
fn install_blobs(
    dir: &Path,
    card: &mut ModelCard,
    config: &ExperimentConfig,
    [f32_blob, int8_blob]: [&Path; 2],
    others: &[&Path],
    run: &Path,
    commit: String,
) -> Result<Vec<SilReport>, ModelError> {
    let experiment = |e: ExperimentError| ModelError::Experiment(Box::new(e));
    let sil = crate::sil::sil_of_blobs(config, f32_blob, int8_blob, run)
        .map_err(experiment)?
        .to_vec();
    (card.lookahead, card.with_terminal) = fly_aided(config, f32_blob, run)?;
    for file in [f32_blob, int8_blob].iter().chain(others) {
        let name = file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let bytes = std::fs::read(file).map_err(io(file))?;
        let target = dir.join(&name);
        atomic_write(&target, &bytes).map_err(io(&target))?;
        card.files.insert(name, crc_of(&target)?);
    }
    card.sil = sil_figures(&sil);
    card.reexported = Some((portable_command(), commit, utc_date()));
    card.reexported_format = Some(shared::blob::FORMAT_VERSION);
    write_cards(dir, card)?;
    Ok(sil)
}

/// `ground model export --model DIR --upgrade`: converts the folder's blobs of an older format
/// (3 or 4) to the present one (the same network bit for bit, its weights laid out anew:
/// [`shared::blob::upgrade`]), flies them in the SIL loop, and
/// replaces the blobs and the card's SIL figures and file checksums, as [`reexport_model`]
/// does. Unlike a re-export it needs neither the pretraining dataset the int8 scales were
/// calibrated on nor a new calibration: the int8 network stays the one the card measured. The
/// folder's files must match its card; blobs already of the present format are kept as they
/// are. The converted blobs and the SIL runs are written under `run`.
pub fn upgrade_model(dir: &Path, run: &Path) -> Result<(ModelCard, Vec<SilReport>), ModelError> {
    // Before the folder changes, which would mark the tree modified.
    let commit = current_commit();
    let (mut card, config) = read_card(dir, Unsealed::Accepted)?;
    ground_core::model_files::verify_checksums(dir, &card.files)?;
    let kind = config.problem();
    let upgraded = run.join("upgrade");
    std::fs::create_dir_all(&upgraded).map_err(io(&upgraded))?;
    let convert = |quantization| -> Result<PathBuf, ModelError> {
        let name = blob_file(kind, quantization);
        let path = dir.join(&name);
        let bytes = std::fs::read(&path).map_err(io(&path))?;
        let new = shared::blob::upgrade(&bytes).map_err(|source| ModelError::Blob {
            path: path.clone(),
            source,
        })?;
        let target = upgraded.join(&name);
        atomic_write(&target, &new).map_err(io(&target))?;
        Ok(target)
    };
    let (f32_blob, int8_blob) = (convert(Quantization::F32)?, convert(Quantization::Int8)?);
    let sil = install_blobs(dir, &mut card, &config, [&f32_blob, &int8_blob], &[], run, commit)?;
    Ok((card, sil))
}

/// The running command as a user reruns it from the repository: `ground` for the binary's
/// path, and arguments under the working folder relative to it, each quoted for a POSIX shell
/// where it needs it (a `--note` of several words). A card never records where the machine
/// that made it keeps its files.
fn portable_command() -> String {
    let mut args = std::env::args();
    let program = args.next().map(|p| {
        let name = Path::new(&p).file_stem().map(|n| n.to_string_lossy().into_owned());
        name.unwrap_or(p)
    });
    let words: Vec<String> = program
        .into_iter()
        .chain(args.map(|a| portable_path(Path::new(&a)).to_string_lossy().into_owned()))
        .collect();
    shell_words(&words)
}

/// Words joined into one POSIX shell command line that splits back into the same words: a
/// word of only safe characters as it is, any other in single quotes (a quote inside as `'\''`).
pub(crate) fn shell_words(words: &[String]) -> String {
    let safe = |c: char| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c);
    words
        .iter()
        .map(|w| {
            if !w.is_empty() && w.chars().all(safe) {
                w.clone()
            } else {
                format!("'{}'", w.replace('\'', "'\\''"))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// The config as the card records it: the pretraining dataset relative to the working folder
/// when it lies under it.
fn portable_config(config: &ExperimentConfig) -> String {
    let mut config = config.clone();
    if let Some(dataset) = &config.pretrain.dataset {
        config.pretrain.dataset = Some(portable_path(dataset));
    }
    config.to_toml()
}

/// `path` relative to the working folder when it is an absolute path under it, with `a/..`
/// steps folded; any other path as given.
fn portable_path(path: &Path) -> PathBuf {
    let Ok(cwd) = std::env::current_dir() else {
        return path.to_path_buf();
    };
    let Ok(relative) = path.strip_prefix(&cwd) else {
        return path.to_path_buf();
    };
    let mut folded = PathBuf::new();
    for part in relative.components() {
        match part {
            std::path::Component::ParentDir if folded.file_name().is_some() => {
                folded.pop();
            }
            other => folded.push(other),
        }
    }
    folded
}

/// Today's UTC date, YYYY-MM-DD (the calendar reading `ground data oem` stamps its files with).
fn utc_date() -> String {
    let now = ground_core::oem::CalendarEpoch::now_utc().to_string();
    now.split('T').next().unwrap_or(&now).to_string()
}

/// A model folder that passed [`open_model`]'s checks.
#[derive(Debug, Clone)]
pub struct ShippedModel {
    /// The model folder.
    pub dir: PathBuf,
    /// Its card.
    pub card: ModelCard,
    /// The card's config (the one the controller was trained and measured with).
    pub config: ExperimentConfig,
}

impl ShippedModel {
    /// The actor file, `DIR/actor.safetensors`.
    pub fn actor(&self) -> PathBuf {
        self.dir.join(ACTOR_FILE)
    }

    /// The blob of `quantization`.
    pub fn blob(&self, quantization: Quantization) -> PathBuf {
        self.dir.join(blob_file(self.config.problem(), quantization))
    }
}

/// Opens the model folder `dir`: the card parses and is of this format, its config is valid,
/// every file it lists is there with its CRC-32C, both blobs are listed, and the f32 blob holds
/// exactly the actor's weights.
pub fn open_model(dir: &Path) -> Result<ShippedModel, ModelError> {
    let (card, config) = read_card(dir, Unsealed::Refused)?;
    verify_model_files(dir, config.feature_layout(), &card.files)?;
    // card.md is what people read: it must say what card.json, the bound record, says.
    let md = dir.join(CARD_MD);
    let written = std::fs::read_to_string(&md).map_err(io(&md))?;
    if written != card_markdown(&card) {
        return Err(ModelError::MarkdownDisagrees { path: md });
    }
    Ok(ShippedModel {
        dir: dir.to_path_buf(),
        card,
        config,
    })
}

/// Whether a card of the last unsealed layout is read (by the commands that check the folder's
/// files and write the card again, sealed).
#[derive(Clone, Copy, PartialEq)]
enum Unsealed {
    Accepted,
    Refused,
}

/// The card of the model folder `dir` and its config: of this format and sealed (or, where
/// `unsealed` accepts it, of the last unsealed format), parsed, its config valid.
fn read_card(dir: &Path, unsealed: Unsealed) -> Result<(ModelCard, ExperimentConfig), ModelError> {
    let card_path = dir.join(CARD_JSON);
    let text = std::fs::read_to_string(&card_path).map_err(io(&card_path))?;
    let unreadable = |reason: String| ModelError::Card {
        path: card_path.clone(),
        reason,
    };
    let value: serde_json::Value = serde_json::from_str(&text).map_err(|e| unreadable(e.to_string()))?;
    let format = value.get("format").and_then(serde_json::Value::as_u64).unwrap_or(0);
    let value = match format {
        f if f == u64::from(CARD_FORMAT) => ground_core::model_files::read_sealed_card(&card_path, &text)?,
        f if f == u64::from(UNSEALED_CARD_FORMAT) && unsealed == Unsealed::Accepted => value,
        _ => {
            return Err(ModelError::Format {
                path: card_path,
                found: u32::try_from(format).unwrap_or(u32::MAX),
            })
        }
    };
    let card: ModelCard = serde_json::from_value(value).map_err(|e| unreadable(e.to_string()))?;
    let config = ExperimentConfig::from_toml(&card.config).map_err(|e| ModelError::Card {
        path: dir.join(CARD_JSON),
        reason: format!("its config: {e}"),
    })?;
    Ok((card, config))
}

/// An agent flying the actor of an actor file.
pub fn load_actor(config: &ExperimentConfig, path: &Path) -> Result<Sac, ModelError> {
    crate::eval::load_agent(config, obs_dim(config), path).map_err(|e| ModelError::Experiment(Box::new(e)))
}

/// The network inputs of the problem the config's family is flown by.
pub(crate) fn obs_dim(config: &ExperimentConfig) -> usize {
    use ground_core::env::Problem;
    crate::with_flown_problem!(config, P => P::OBS)
}

/// The shares within each of `thresholds` (the table's columns), `–` where `f` has none (a card
/// older than a threshold: its Monte Carlo then has fewer than its later SIL rows).
fn figures_row(name: &str, f: &FlightFigures, thresholds: &[f64]) -> String {
    let shares: Vec<String> = thresholds
        .iter()
        .map(|t| {
            f.within
                .iter()
                .find(|(u, _)| u == t)
                .map_or_else(|| "–".to_owned(), |(_, s)| format!("{:.1} %", 100.0 * s))
        })
        .collect();
    format!(
        "| {name} | {}/{} | {} | {:.4} / {:.4} | {:.4} / {:.4} | {:.4} |\n",
        f.completed,
        f.episodes,
        shares.join(" | "),
        f.dr_p50,
        f.dr_p95,
        f.dv_p50,
        f.dv_p95,
        f.final_mass_mean
    )
}

/// The card's lines on a Monte Carlo against the indirect optimum: overspend, the share where
/// solved, by eccentricity band (each when measured).
fn against_the_optimum(
    s: &mut String,
    overspend: Option<(usize, f64, f64)>,
    where_solved: Option<SolvedShare>,
    by_eccentricity: &[EccentricityBand],
) {
    if let Some((count, median, p95)) = overspend {
        let _ = writeln!(
            s,
            "\nPropellant against the indirect optimum on {count} Monte Carlo scenarios: overspend median {:.2} %, p95 {:.1} %.",
            100.0 * median,
            100.0 * p95
        );
    }
    if let Some(w) = where_solved {
        let _ = writeln!(
            s,
            "\nOn the {} of the first {} Monte Carlo scenarios that the indirect method solved (shown feasible): {:.1} % within the goal; {} unsolved ones flown within it.",
            w.solved,
            w.scenarios,
            100.0 * w.within_goal,
            w.unsolved_within_goal
        );
    }
    if !by_eccentricity.is_empty() {
        let _ = writeln!(s, "\nBy the larger eccentricity of the two orbits:\n");
        for band in by_eccentricity {
            let _ = writeln!(s, "- {}", eccentricity_line(band));
        }
    }
}

/// The Gymnasium id of a model's environment (the Python package's): a preset's own, else the
/// id that flies any mission family.
fn environment_id(scenario: &str) -> String {
    if scenario.parse::<shared::scenario::ScenarioKind>().is_err() {
        return "lowthrust/Mission-v0".to_string();
    }
    let camel: String = scenario
        .split('-')
        .map(|w| {
            let mut c = w.chars();
            c.next().map_or(String::new(), |f| f.to_uppercase().chain(c).collect())
        })
        .collect();
    format!("lowthrust/{camel}-v0")
}

/// The card's front matter in the YAML a model hub reads (Hugging Face's model card metadata):
/// tags, and a `model-index` with the Monte Carlo's share within each tolerance, the overspend,
/// the SIL and the lookahead figures as metrics.
fn front_matter(card: &ModelCard) -> String {
    let mut s = String::from("---\nlibrary_name: lowthrust\nlicense: mit\ntags:\n- reinforcement-learning\n- spacecraft-guidance\n- low-thrust\n- onnx\nmodel-index:\n");
    let _ = writeln!(s, "- name: {}\n  results:", card.scenario);
    let environment = environment_id(&card.scenario);
    let mut result = |name: &str, metrics: &[(String, String, f64)]| {
        let _ = writeln!(
            s,
            "  - task:\n      type: reinforcement-learning\n      name: low-thrust guidance\n    dataset:\n      type: {environment}\n      name: \"{name}\"\n    metrics:"
        );
        for (kind, label, value) in metrics {
            let _ = writeln!(s, "    - type: {kind}\n      name: \"{label}\"\n      value: {value}");
        }
    };
    let shares = |figures: &FlightFigures, what: &str| -> Vec<(String, String, f64)> {
        figures
            .within
            .iter()
            .map(|(t, share)| {
                (
                    format!("within_{t}"),
                    format!("{what}: share within {t} AU and {t} of the velocity unit"),
                    *share,
                )
            })
            .collect()
    };
    let mut mc = shares(&card.monte_carlo, "Monte Carlo");
    if let Some((_, median, p95)) = card.overspend {
        mc.push((
            "overspend_median".into(),
            "propellant overspend against the indirect optimum, median".into(),
            median,
        ));
        mc.push((
            "overspend_p95".into(),
            "propellant overspend against the indirect optimum, p95".into(),
            p95,
        ));
    }
    result(
        &format!(
            "{} Monte Carlo, {} episodes, seed {}",
            card.scenario, card.monte_carlo.episodes, card.monte_carlo_seed
        ),
        &mc,
    );
    for (blob, figures) in &card.sil {
        result(
            &format!("{blob} in the SIL, {} dispersed flights", figures.episodes),
            &shares(figures, "SIL with dispersions"),
        );
    }
    if let Some(lookahead) = &card.lookahead {
        let mc = &lookahead.flown.monte_carlo;
        result(
            &format!("f32 blob with {}, {} nominal flights", aids_flown(card), mc.episodes),
            &shares(mc, "with lookahead"),
        );
    }
    if let Some(flown) = &card.with_terminal {
        let mc = &flown.monte_carlo;
        result(
            &format!("f32 blob with terminal targeting, {} nominal flights", mc.episodes),
            &shares(mc, "with terminal targeting"),
        );
    }
    s.push_str("---\n\n");
    s
}

/// The card for people, opening with the metadata a model hub reads (a YAML front matter).
pub fn card_markdown(card: &ModelCard) -> String {
    let mut s = front_matter(card);
    let _ = writeln!(s, "# Model card: {}\n", card.scenario);
    let _ = writeln!(
        s,
        "Produced on {} by `{}` at commit `{}`. The files are bound by their CRC-32C in [card.json](card.json), which is sealed by the CRC-32C of its own content; `ground model evaluate --model` and `ground model sil --model` refuse a folder whose files disagree or whose card was edited.\n",
        card.created, card.command, card.commit
    );
    if let Some((command, commit, date)) = &card.reexported {
        let _ = writeln!(
            s,
            "Blobs exported again from the same actor on {date} by `{command}` at commit `{commit}` (blob format {}); the SIL figures are theirs.\n",
            card.reexported_format.unwrap_or(3)
        );
    }
    for note in &card.notes {
        let _ = writeln!(s, "{note}\n");
    }
    let (records, converged, seed, eps) = card.demonstrations;
    let _ = writeln!(
        s,
        "**Data**: {records} {} trajectories by the indirect method (seed {seed}, final eps {eps}), {converged} converged.{}\n",
        card.scenario,
        card.rounds
            .map_or(String::new(), |(run, kept)| format!(" Then {run} relabelling rounds; round {kept} is shipped."))
    );
    // Every threshold any row of the card has, widest first.
    let mut thresholds: Vec<f64> = std::iter::once(&card.monte_carlo)
        .chain(card.sil.iter().map(|(_, f)| f))
        .chain(card.lookahead.iter().map(|l| &l.flown.monte_carlo))
        .chain(card.with_terminal.iter().map(|f| &f.monte_carlo))
        .flat_map(|f| f.within.iter().map(|(t, _)| *t))
        .collect();
    thresholds.sort_by(|a, b| b.total_cmp(a));
    thresholds.dedup();
    let tolerances: Vec<String> = thresholds.iter().map(|t| format!("within {t}")).collect();
    let _ = writeln!(
        s,
        "## Figures\n\nMonte Carlo seed {}; SIL: the blobs flown by the onboard guidance loop against the dispersed plant of the config's `[sil]`{}.\n",
        card.monte_carlo_seed,
        card.terminal.map_or(String::new(), |t| format!(
            ", their last {} cycles with terminal targeting (`onboard::terminal`: the remaining commands solved for the arrival each cycle)",
            t.cycles
        ))
    );
    let _ = writeln!(
        s,
        "| flown | completed | {} | dr p50 / p95 (AU) | dv p50 / p95 | final mass |",
        tolerances.join(" | ")
    );
    let _ = writeln!(s, "|---|---|{}---|---|---|", "---|".repeat(tolerances.len()));
    s.push_str(&figures_row("actor, Monte Carlo", &card.monte_carlo, &thresholds));
    for (blob, f) in &card.sil {
        s.push_str(&figures_row(&format!("{blob}, SIL"), f, &thresholds));
    }
    against_the_optimum(&mut s, card.overspend, card.where_solved, &card.by_eccentricity);
    let flown_section = |s: &mut String, heading: &str, row: &str, f: &FlownFigures| {
        let _ = writeln!(
            s,
            "{heading} The f32 blob on the Monte Carlo's scenarios without dispersions:\n"
        );
        let _ = writeln!(
            s,
            "| flown | completed | {} | dr p50 / p95 (AU) | dv p50 / p95 | final mass |",
            tolerances.join(" | ")
        );
        let _ = writeln!(s, "|---|---|{}---|---|---|", "---|".repeat(tolerances.len()));
        s.push_str(&figures_row(row, &f.monte_carlo, &thresholds));
        against_the_optimum(s, f.overspend, f.where_solved, &f.by_eccentricity);
    };
    if let Some(l) = &card.lookahead {
        let terms: String = lookahead_terms(&l.settings).iter().map(|t| format!(", {t}")).collect();
        let heading = format!(
            "\n## With rollout lookahead\n\nFlown with `onboard::lookahead` (accuracy floor {}, fuel weight {}{terms}; the SIL rows above fly with it too).",
            l.settings.accuracy_floor, l.settings.fuel_weight
        );
        let row = format!("f32 blob with {}, no dispersions", aids_flown(card));
        flown_section(&mut s, &heading, &row, &l.flown);
    }
    if let (Some(f), Some(t)) = (&card.with_terminal, card.terminal) {
        let heading = format!(
            "\n## As flown: with terminal targeting\n\nThe Monte Carlo row above is the network alone; onboard, the last {} cycles fly with terminal targeting, as the SIL rows do.",
            t.cycles
        );
        flown_section(&mut s, &heading, "f32 blob with terminal targeting, no dispersions", f);
    }
    let _ = writeln!(s, "\n## Files\n");
    for (name, crc) in &card.files {
        let _ = writeln!(s, "- [{name}]({name}) (CRC-32C {crc})");
    }
    let _ = writeln!(s, "\n## Config\n\n```toml\n{}```", card.config);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_card_records_paths_under_the_working_folder_relative_to_it() {
        let cwd = std::env::current_dir().unwrap();
        let under = cwd.join("configs").join("..").join("runs").join("tc").join("dataset");
        assert_eq!(portable_path(&under), Path::new("runs/tc/dataset"));
        // Relative paths, flags and paths elsewhere are kept as given.
        for kept in ["runs/tc", "--out", "/elsewhere/runs/tc"] {
            assert_eq!(portable_path(Path::new(kept)), Path::new(kept));
        }
        let mut config = ExperimentConfig::from_toml(crate::config::EMBEDDED_DEFAULT).unwrap();
        config.pretrain.dataset = Some(under);
        let text = portable_config(&config);
        assert!(text.contains("dataset = \"runs/tc/dataset\""), "{text}");
        assert!(!text.contains(&*cwd.to_string_lossy()), "{text}");
    }

    #[test]
    fn a_recorded_command_splits_back_into_its_words_in_a_shell() {
        let words: Vec<String> = [
            "ground",
            "model",
            "ship",
            "--note",
            "Fine-tuned (step 275 kept): the actor's \"best\" $HOME `x` \\ *",
            "",
            "--out",
            "runs/a b",
        ]
        .iter()
        .map(|w| w.to_string())
        .collect();
        let line = super::shell_words(&words);
        assert!(line.starts_with("ground model ship --note '"), "{line}");
        // The shell's own split, one word a line (no word here holds a newline).
        let out = std::process::Command::new("sh")
            .arg("-c")
            .arg(format!("for w in {line}; do printf '%s\\n' \"$w\"; done"))
            .output()
            .unwrap();
        assert!(out.status.success());
        let split: Vec<String> = String::from_utf8(out.stdout)
            .unwrap()
            .lines()
            .map(str::to_string)
            .collect();
        assert_eq!(split, words);
    }

    /// A card whose Monte Carlo has fewer thresholds than its SIL rows (measured before the
    /// 0.0001 column existed) still renders tables whose every row has its header's cells, the
    /// missing share shown as a dash, and each SIL share under its own threshold.
    #[test]
    fn every_row_of_a_cards_tables_has_its_headers_cells() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/transfer-hard/card.json");
        let mut card: ModelCard = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        card.monte_carlo.within.truncate(2);
        let (_, sil) = card.sil.first().cloned().unwrap();
        assert!(sil.within.len() > card.monte_carlo.within.len());
        let md = card_markdown(&card);
        let mut header_cells = None;
        for line in md.lines().filter(|l| l.starts_with('|')) {
            let cells = line.matches('|').count();
            if line.starts_with("| flown |") {
                assert!(line.contains("within 0.0001"), "{line}");
                header_cells = Some(cells);
            } else if line.starts_with("| actor, Monte Carlo |") || line.contains(", SIL |") {
                assert_eq!(Some(cells), header_cells, "{line}");
            }
        }
        let mc_row = md.lines().find(|l| l.starts_with("| actor, Monte Carlo |")).unwrap();
        assert_eq!(mc_row.split('|').filter(|c| c.trim() == "–").count(), 2, "{mc_row}");
        let sil_row = md.lines().find(|l| l.contains(", SIL |")).unwrap();
        let last = sil.within.last().unwrap();
        let cells: Vec<&str> = sil_row.split('|').map(str::trim).collect();
        // `| name | completed | shares |`: split on '|', the shares start at index 3.
        assert_eq!(
            cells[2 + sil.within.len()],
            format!("{:.1} %", 100.0 * last.1),
            "{sil_row}"
        );
    }
}
