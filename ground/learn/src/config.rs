//! The experiment config (TOML): every hyper-parameter of docs/spec.md section 8 plus the scenario, the
//! environment, the phases and the compute settings. Defaults equal the thesis; unknown keys and
//! impossible values are refused before any work starts.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use shared::blob::BlobMission;
use shared::mission::{MissionFamily, SpatialFamily};
use shared::spacecraft::SpacecraftError;

use crate::cloning::CloningTarget;
use crate::sac::agent::CloningLoss;
use crate::sac::SacConfig;
use ground_core::demo::RecordFilter;
use ground_core::env::EnvConfig;
use ground_core::solver::Fallbacks;
use onboard::lookahead::LookaheadSettings;
pub use onboard::terminal::TerminalSettings;

/// Evaluates `$body` with `$P` naming the [`ground_core::env::Problem`] the config's family is
/// flown by: the planar transfer or rendezvous, or for an inclined family their
/// three-dimensional twins.
#[macro_export]
macro_rules! with_flown_problem {
    ($config:expr, $P:ident => $body:expr) => {
        if $config.is_inclined() {
            ground_core::with_spatial_problem!($config.problem(), $P => $body)
        } else {
            ground_core::with_problem!($config.problem(), $P => $body)
        }
    };
}

/// A whole experiment as one TOML file: the scenario distribution, seeds, environment, learner,
/// the settings of every phase and the compute. Missing sections take their defaults (the
/// thesis's); unknown keys are refused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExperimentConfig {
    /// Scenario family (training, evaluation and Monte Carlo): a preset's name (docs/spec.md
    /// section 4), a mission file's path, or the table (docs/missions.md). Written back as the
    /// preset's name or the whole table, never as the path, so a run keeps its family.
    /// Inclined families (docs/spec.md section 4) are flown by the three-dimensional problems;
    /// a family in the reference plane is the planar family, written and fingerprinted as one.
    #[serde(rename = "scenario", with = "ground_core::mission::by_spec")]
    pub family: SpatialFamily,
    /// The name of the experiment's controller in its report and model card (letters, digits,
    /// `.`, `_`, `-`; default: the family's, a preset's name or `custom-` and its fingerprint).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Disjoint seeds of the training, evaluation and Monte Carlo scenario streams.
    #[serde(default)]
    pub seeds: Seeds,
    /// The environment (docs/spec.md section 5): spacecraft, reward, terminal-accuracy term and
    /// integrator settings.
    #[serde(default)]
    pub env: EnvConfig,
    /// The SAC hyper-parameters (docs/spec.md section 8); per phase see [`ExperimentConfig::sac_for`].
    #[serde(default)]
    pub sac: SacConfig,
    /// The trajectory dataset the main job (`ground run`) generates for pretraining.
    #[serde(default)]
    pub generate: GenerateConfig,
    /// Pretraining on the demonstrations (`ground train pretrain`).
    #[serde(default)]
    pub pretrain: PretrainConfig,
    /// The RL phase (`ground train rl`) and the periodic evaluations of both phases.
    #[serde(default)]
    pub train: TrainConfig,
    /// The Monte Carlo evaluation (`ground model evaluate`, and the main job).
    #[serde(default)]
    pub evaluate: EvaluateConfig,
    /// DAgger-style rounds of relabelled demonstrations (`ground train dagger`, transfers).
    #[serde(default)]
    pub dagger: DaggerConfig,
    /// Fine-tuning through the dynamics after the rounds (`ground train finetune`).
    #[serde(default, skip_serializing_if = "FinetuneConfig::is_off")]
    pub finetune: FinetuneConfig,
    /// The software-in-the-loop Monte Carlo of exported blobs.
    #[serde(default)]
    pub sil: SilConfig,
    /// Torch threads, device, and where relabels are solved.
    #[serde(default)]
    pub compute: ComputeConfig,
    /// Stages after the relabelling rounds (`ground run` only): each runs more rounds under
    /// settings changed from the stage before, started from that stage's learner; the last
    /// stage's best is what the run ships. A chain of runs written as one recipe.
    #[serde(default, rename = "stage", skip_serializing_if = "Vec::is_empty")]
    pub stages: Vec<Stage>,
}

/// What a stage's rounds start from: the learner the stage before it ended with.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StageStart {
    /// The stage before's best round, the whole learner (actor, critics, optimisers).
    #[default]
    Best,
    /// The stage before's best round, its flown actor alone: fresh critics and optimisers, as
    /// `ground train dagger --from model/actor.safetensors` (for `cloning_only` rounds, or a
    /// wider network: the actor is widened).
    BestActor,
    /// The stage before's last round, the whole learner (the rounds go on where they stopped).
    Last,
}

/// One stage of a recipe (`[[stage]]`): a name (its folder, `RUN/stages/NAME`), where its
/// rounds start, and the sections it changes, written as in the config (`generate = { ... }`,
/// `[stage.dagger]`); each change applies on top of the stage before. A changed `[generate]`
/// solves the stage its own demonstrations, which its rounds' buffer starts from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Stage {
    /// The stage's name: lower-case letters, digits and dashes.
    pub name: String,
    /// What its rounds start from (default `best`).
    #[serde(default)]
    pub start: StageStart,
    /// The stage before's completed rounds' relabels become this stage's first rounds (its
    /// `dagger.rounds` counts them), as `ground train dagger --relabels-from`: the problem they
    /// were solved for (scenario, seeds, final eps, arrival margin) must not change.
    #[serde(default)]
    pub inherit_relabels: bool,
    /// The sections changed, by name (one of [`Stage::CHANGEABLE`]).
    #[serde(flatten)]
    pub changes: toml::Table,
}

impl Stage {
    /// The sections a stage may change; the others (scenario, seeds, train, compute) hold for
    /// the whole recipe.
    pub const CHANGEABLE: [&'static str; 7] = ["env", "sac", "generate", "pretrain", "dagger", "evaluate", "sil"];
}

/// Disjoint seeds per phase, so evaluation never sees training scenarios.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Seeds {
    /// Training episodes' scenarios and the learner's random streams.
    pub train: u64,
    /// The fixed scenarios of the periodic evaluations (100 episodes).
    pub evaluation: u64,
    /// The Monte Carlo scenarios (docs/spec.md section 9).
    pub monte_carlo: u64,
}

impl Default for Seeds {
    fn default() -> Self {
        Self {
            train: 1,
            evaluation: 1_000_003,
            monte_carlo: 2_000_003,
        }
    }
}

/// The trajectory dataset the main job solves by the indirect method (`ground data generate` with
/// these settings): how many scenarios and to what homotopy depth.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GenerateConfig {
    /// Trajectories solved (the thesis: 1,000 circular, 10,000 hard).
    pub count: u64,
    /// Seed of the dataset's scenario draws (record i is scenario i of this seed; default 7).
    pub seed: u64,
    /// Final eps of the energy-to-fuel homotopy (docs/spec.md: below 1e-4).
    pub final_eps: f64,
    /// `ground run` checks every converged record against the direct transcription started on
    /// its own and re-solves those it beats onto the better optimum before pretraining
    /// (`ground data crosscheck --repair`; about 0.4 s a hard record on 2 cores). Off by default:
    /// on 300 transfer-circular records it found none to repair.
    pub crosscheck: bool,
    /// Demonstrations and relabels are solved to arrive this many guidance cycles before the end
    /// of the flight where that converges (then coasting with the target), on time otherwise
    /// (`ground_core::solver::solve_arriving_early`): a reserve for thrust lost late. 0: on time.
    pub arrival_margin: u32,
}

impl Default for GenerateConfig {
    fn default() -> Self {
        Self {
            count: 1_000,
            seed: 7,
            final_eps: ground_core::solver::shooting::FINAL_EPS,
            crosscheck: false,
            arrival_margin: 0,
        }
    }
}

impl GenerateConfig {
    /// The indirect method's settings for this config's solves: the demonstrations, the
    /// relabels and the plan's sample.
    pub fn solve_options(&self) -> ground_core::solver::SolveOptions {
        ground_core::solver::SolveOptions {
            final_eps: self.final_eps,
            arrival_margin_steps: self.arrival_margin,
            ..ground_core::solver::SolveOptions::default()
        }
    }
}

/// How the actor learns from demonstrations during pretraining.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PretrainMode {
    /// The thesis: plain SAC updates on the demonstration buffer.
    Sac,
    /// SAC plus a behaviour-cloning term on demonstrated actions (TD3+BC style), weight
    /// `behaviour_cloning`.
    BehaviourCloning,
}

/// Pretraining: gradient updates on the demonstration buffer alone, no environment interaction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PretrainConfig {
    /// Trajectory dataset (a `ground data generate` output: the folder or its .ltds file).
    pub dataset: Option<PathBuf>,
    /// Gradient updates with no environment interaction (N_pt).
    pub updates: u64,
    /// Gradient updates between evaluations, the best model kept (default 10,000; > 0).
    pub eval_every: u64,
    /// How the actor learns from the demonstrations (default `sac`, the thesis).
    pub mode: PretrainMode,
    /// Behaviour-cloning weight for `mode = "behaviour-cloning"` (and kept during RL if
    /// `train.keep_behaviour_cloning`).
    pub behaviour_cloning: f64,
    /// What the behaviour-cloning term compares: "action" (the raw actions, default) or
    /// "thrust" (the decoded thrust vectors) or "thrust-log-throttle" (plus the relative
    /// throttle error), see [`CloningTarget`].
    pub cloning_target: CloningTarget,
    /// Which trajectory records become demonstrations: "converged" (homotopy reached the final
    /// eps) or "all" (also those stopped at a larger eps, with that eps's smoothed control).
    pub records: RecordFilter,
}

impl Default for PretrainConfig {
    fn default() -> Self {
        Self {
            dataset: None,
            updates: 1_000_000,
            eval_every: 10_000,
            mode: PretrainMode::Sac,
            behaviour_cloning: 2.5,
            cloning_target: CloningTarget::Action,
            records: RecordFilter::Converged,
        }
    }
}

/// The RL phase (from scratch or from the pretrained model). Its `eval_episodes` also size the
/// pretraining evaluations.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Environment steps of RL (1 update per step after the warm-up).
    pub env_steps: u64,
    /// Environment steps between evaluations, the best model kept (default 10,000; > 0).
    pub eval_every: u64,
    /// Deterministic evaluation episodes each time.
    pub eval_episodes: u64,
    /// Environment steps between checkpoints of agent, replay buffer and loop state, for
    /// resumption (default 50,000; 0: at the end only).
    pub checkpoint_every: u64,
    /// Keep the behaviour-cloning term on the demonstrations still in the buffer during RL.
    pub keep_behaviour_cloning: bool,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            env_steps: 5_000_000,
            eval_every: 10_000,
            eval_episodes: 100,
            checkpoint_every: 50_000,
            keep_behaviour_cloning: false,
        }
    }
}

/// The Monte Carlo evaluation of the trained policy (docs/spec.md section 9).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvaluateConfig {
    /// Monte Carlo episodes (docs/spec.md section 9).
    pub episodes: u64,
    /// Scenarios of the Monte Carlo set also solved by the indirect method for the optimality
    /// gap (the first ones; 0 turns it off).
    pub optimality_gap_cases: u64,
}

impl Default for EvaluateConfig {
    fn default() -> Self {
        Self {
            episodes: 10_000,
            optimality_gap_cases: 32,
        }
    }
}

/// DAgger-style rounds (`ground train dagger`): fly the policy on fresh training scenarios, re-solve
/// the fuel-optimal rest of the flight from states it visited, add those tuples to the
/// demonstration buffer, then behaviour-cloning-regularised updates on the grown buffer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DaggerConfig {
    /// Rounds in all, at most (a finished run asked for more continues). 0: none, and `ground
    /// run` skips the stage.
    pub rounds: u64,
    /// Stop before the budget once a round scores at least this share within the goal on the
    /// scoring episodes (unset: every round of the budget).
    pub stop_at: Option<f64>,
    /// Stop once this many rounds in a row bring no new best score (unset: never): a plateau
    /// ends the rounds, and the report says so, instead of spending the rest of the budget.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub patience: Option<u64>,
    /// Training episodes relabelled per round (0: updates only, the control arm).
    pub episodes: u64,
    /// Episodes flown per round to choose the relabelled ones from: the `episodes` that miss
    /// the accuracy goal the most (max(dr / 0.01 AU, dv / 0.01)). Unset: the first `episodes`
    /// flown, every one relabelled.
    pub candidates: Option<u64>,
    /// Where along each flown episode its state is relabelled (fractions of the steps).
    pub fractions: Vec<f64>,
    /// Gradient updates per round.
    pub updates: u64,
    /// Deterministic episodes on the evaluation seed that score each round (the share
    /// within 0.01 AU and 0.01); the best round is kept.
    pub score_episodes: u64,
    /// Fly the candidates as the onboard f32 controller against the SIL's dispersed plant
    /// (`[sil.dispersions]`), so the relabelled states are those that navigation errors,
    /// thrust errors and missed thrust lead to. Each round is then also scored under the same
    /// dispersions, and that share picks the best round and meets `stop_at`.
    pub dispersed: bool,
    /// Update the actor alone on the cloning error of the demonstrations and relabels (no
    /// critic, no RL term): what rounds started from a shipped actor, without critics, run.
    pub cloning_only: bool,
    /// Relabel only flights whose earliest relabel re-solves: the flights are walked from the
    /// largest miss down, their earliest fraction solved first, until `episodes` of them
    /// converged; the other fractions are solved for those alone. For distributions with draws
    /// no control reaches in their time of flight (transfer-hard: about a quarter), which are
    /// otherwise the largest misses and re-solve to nothing.
    pub solvable_only: bool,
    /// Leave out flights that miss by more than this many times the accuracy goal (max(dr /
    /// 0.01 AU, dv / 0.01)); unset: none. On transfer-hard nearly all such flights are draws
    /// with no transfer in their time of flight, whose solves fail at the largest cost.
    pub max_miss: Option<f64>,
    /// Where a relabel goes when no multi-start guess converges: `"all"` (default: the
    /// continuation in the target, then the direct transcription's multipliers, as the
    /// demonstrations), `"continuation"` (without the direct transcription) or `"none"` (the
    /// relabel fails at once). On a rendezvous-circular round the direct transcription rescued
    /// no relabel for a fifth of the solve time, the continuation 15 of 472 for half of it; on
    /// transfer-hard the direct transcription none, the continuation 14 % (docs/results.md).
    #[serde(skip_serializing_if = "is_all_fallbacks")]
    pub fallbacks: Fallbacks,
}

/// Whether a relabel takes every fallback (the default, left out of a written config).
fn is_all_fallbacks(fallbacks: &Fallbacks) -> bool {
    *fallbacks == Fallbacks::All
}

impl Default for DaggerConfig {
    fn default() -> Self {
        // Measured (docs/history/learning.md): 100 episodes per round plateau near 54 %
        // within the goal, 200 still climb.
        Self {
            rounds: 0,
            stop_at: None,
            patience: None,
            episodes: 200,
            candidates: None,
            fractions: vec![0.2, 0.4, 0.6, 0.8],
            updates: 10_000,
            score_episodes: 1_000,
            dispersed: false,
            cloning_only: false,
            solvable_only: false,
            max_miss: None,
            fallbacks: Fallbacks::All,
        }
    }
}

/// Fine-tuning through the dynamics (`ground train finetune`, [`crate::finetune`]): the flown
/// actor stepped down the gradient of what its flights end with, each flight differentiated
/// end to end through the environment's propagator. Measured on transfer-circular
/// (docs/results.md): the miss and the propellant both fall.
///
/// A phase may be followed by another (`[finetune.then]`, its keys defaulting as these do)
/// started from this phase's best actor: first nominal flights, then dispersed ones, as one
/// recipe.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FinetuneConfig {
    /// Adam steps, each on a fresh batch of training flights. 0: none, and `ground run` skips
    /// the stage.
    pub steps: u64,
    /// Flights per step.
    pub flights: u64,
    /// Adam's learning rate.
    pub learning_rate: f64,
    /// The objective's weight of the propellant burned, per thousandth of the initial mass
    /// (a miss of the accuracy goal in position or velocity weighs 1).
    pub propellant_weight: f64,
    /// Steps between evaluations (each a checkpoint); the evaluation with the smallest mean
    /// objective is the phase's best.
    pub eval_every: u64,
    /// Flights of each evaluation (the evaluation stream's first scenarios).
    pub eval_episodes: u64,
    /// Fly the training and evaluation flights against the SIL's dispersed plant
    /// (`[sil.dispersions]`: navigation, thrust and pointing errors, missed thrust), the
    /// network seeing the navigation state, instead of the nominal environment.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub dispersed: bool,
    /// Cycles before the arrival at which the flights' miss is also counted, in the steps'
    /// objective and in the evaluations that pick the best (0: at the arrival only): the
    /// network learns to meet its target early and follow it, keeping the last cycles in
    /// reserve against thrust lost late. A flight of no more cycles than the margin is judged
    /// at its arrival only.
    #[serde(skip_serializing_if = "ground_core::generate::is_zero")]
    pub arrival_margin: u32,
    /// Torch threads of the phase, whatever `[compute] threads` says (1 by default): a step's
    /// sums run over every cycle of its flights, and its checkpoints depend on the thread count
    /// in their last bits, where the other stages' do not. A run reproduces a phase at the
    /// setting it was run at.
    #[serde(skip_serializing_if = "is_one")]
    pub threads: i32,
    /// The phase after this one, from its best actor (`RUN/finetune/then`); its best actor is
    /// then what the run ships.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub then: Option<Box<FinetuneConfig>>,
}

/// A count that must be at least 1, refused with its key named.
fn positive(name: &str, v: u64) -> Result<(), ConfigError> {
    if v == 0 {
        Err(ConfigError::Invalid(format!("{name} must be positive")))
    } else {
        Ok(())
    }
}

impl FinetuneConfig {
    /// No fine-tuning (the default), so configs without the section stay as they were written.
    pub fn is_off(&self) -> bool {
        self.steps == 0 && self.then.is_none()
    }

    /// This phase and those after it, in the order they run.
    pub fn phases(&self) -> impl Iterator<Item = &FinetuneConfig> {
        std::iter::successors(Some(self), |phase| phase.then.as_deref())
    }

    /// Each phase's settings as checked in [`ExperimentConfig::validate`], `at` naming the
    /// section.
    fn validate(&self, at: &str) -> Result<(), ConfigError> {
        positive(&format!("{at}.flights"), self.flights)?;
        positive(&format!("{at}.eval_every"), self.eval_every)?;
        positive(&format!("{at}.eval_episodes"), self.eval_episodes)?;
        if self.threads < 1 {
            return Err(ConfigError::Invalid(format!(
                "{at}.threads must be at least 1, got {}",
                self.threads
            )));
        }
        if !(self.learning_rate.is_finite() && self.learning_rate > 0.0) {
            return Err(ConfigError::Invalid(format!(
                "{at}.learning_rate must be finite and > 0, got {}",
                self.learning_rate
            )));
        }
        if !(self.propellant_weight.is_finite() && self.propellant_weight >= 0.0) {
            return Err(ConfigError::Invalid(format!(
                "{at}.propellant_weight must be a finite weight >= 0, got {}",
                self.propellant_weight
            )));
        }
        if let Some(then) = &self.then {
            if self.steps == 0 || then.steps == 0 {
                return Err(ConfigError::Invalid(format!(
                    "{at}.then: each phase of a chained fine-tuning needs steps > 0 ({at}.steps = {}, {at}.then.steps = {})",
                    self.steps, then.steps
                )));
            }
            then.validate(&format!("{at}.then"))?;
        }
        Ok(())
    }
}

impl Default for FinetuneConfig {
    fn default() -> Self {
        Self {
            steps: 0,
            flights: 64,
            learning_rate: 1e-5,
            propellant_weight: 0.03,
            eval_every: 25,
            eval_episodes: 500,
            dispersed: false,
            arrival_margin: 0,
            threads: 1,
            then: None,
        }
    }
}

fn is_one(threads: &i32) -> bool {
    *threads == 1
}

/// The software-in-the-loop Monte Carlo (`ground model sil`, and the main job after export).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SilConfig {
    /// Dispersed flights per blob (on the first scenarios of the Monte Carlo stream).
    pub episodes: u64,
    /// 1-sigma dispersions of the truth plant, in the family's canonical units (default: the
    /// typical sizes, `Dispersions::typical_in` the family's units; `Dispersions::TYPICAL`
    /// around the Sun; see `firmware_sim::dispersion`).
    pub dispersions: firmware_sim::Dispersions,
    /// Fly the blob with rollout lookahead (`onboard::lookahead::LookaheadSettings`, its
    /// fields by name, each defaulted; the rollouts take `rollout_steps` fixed steps a cycle, 1
    /// by default, or with 0 `[env.integrator]`'s adaptive tolerances) instead of alone
    /// (unset). In a TOML config: `lookahead = { accuracy_floor = 0.5, fuel_weight = 5.0,
    /// thrust_margin = 0.05 }`, or `ground model sil --lookahead` for the defaults.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lookahead: Option<LookaheadSettings>,
    /// Fly the blob's last cycles with terminal targeting (`onboard::terminal::TerminalSettings`:
    /// `cycles`, `iterations`, `rollout_steps`, each defaulted; rollouts as the lookahead's),
    /// the cycles before as without it (the network, or with `lookahead`). In a TOML config:
    /// `terminal = { cycles = 8 }`, or `ground model sil --terminal 8`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub terminal: Option<TerminalSettings>,
}

impl Default for SilConfig {
    fn default() -> Self {
        Self {
            episodes: 1_000,
            dispersions: firmware_sim::Dispersions::TYPICAL,
            lookahead: None,
            terminal: None,
        }
    }
}

/// Where the learner computes: torch threads, CPU or CUDA, and optionally a Slurm job array for
/// the relabel solves.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ComputeConfig {
    /// Torch intra-op threads of every stage but fine-tuning (`[finetune] threads`): 1 is
    /// fastest on 2 cores with anything else running, 2 when the run has them to itself.
    pub threads: i32,
    /// "cpu" or "cuda".
    pub device: String,
    /// Solve the relabelling rounds' relabels as a Slurm job array instead of on this machine's
    /// cores (unset). The relabels are the same either way.
    pub slurm: Option<SlurmConfig>,
}

impl Default for ComputeConfig {
    fn default() -> Self {
        Self {
            threads: 1,
            device: "cpu".into(),
            slurm: None,
        }
    }
}

/// A Slurm job array for the relabel solves (`[compute.slurm]`): each batch of a round's
/// relabels is written to a request file, `sbatch --wait --array` runs `ground relabel-shard`
/// on it in `tasks` tasks (relabel i in task i mod tasks), and the round reads their results
/// back in the relabels' order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SlurmConfig {
    /// Array tasks per batch.
    pub tasks: u64,
    /// The submission program.
    #[serde(default = "default_sbatch")]
    pub sbatch: String,
    /// More `sbatch` options, e.g. `["--partition=short", "--cpus-per-task=8"]`; a task solves
    /// its relabels on `SLURM_CPUS_PER_TASK` threads.
    #[serde(default)]
    pub options: Vec<String>,
    /// The `ground` binary the tasks run, where the compute nodes see it under another path
    /// (default: the binary running the rounds).
    #[serde(default)]
    pub ground: Option<PathBuf>,
}

fn default_sbatch() -> String {
    "sbatch".into()
}

/// Why a config was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The config file could not be read: its path and the I/O error.
    #[error("cannot read config {}: {}", .0.display(), .1)]
    Read(PathBuf, std::io::Error),
    /// The text is not a config: TOML syntax, an unknown key, a wrong type or an unknown
    /// scenario name (the parser's message).
    #[error("config does not parse: {0}")]
    Parse(String),
    /// A value is out of range or contradicts another (the message names the key); also a
    /// missing dataset file or a CUDA device that is not there.
    #[error("config is invalid: {0}")]
    Invalid(String),
}

/// The small default experiment of the main job, embedded in the binary.
pub const EMBEDDED_DEFAULT: &str = include_str!("../../../configs/quick.toml");

impl ExperimentConfig {
    /// Parses a TOML config and [`validates`](ExperimentConfig::validate) it; absent sections and
    /// keys take their defaults.
    pub fn from_toml(text: &str) -> Result<Self, ConfigError> {
        let table: toml::Table = toml::from_str(text).map_err(|e| ConfigError::Parse(e.to_string()))?;
        let mut config: Self = table
            .clone()
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::Parse(e.to_string()))?;
        // The spacecraft flies in the family's canonical units, and so do the default dispersions:
        // the typical physical sizes in the family's length and velocity units.
        config.env.body = config.family.family.body;
        let dispersions_given = table.get("sil").and_then(|sil| sil.get("dispersions")).is_some();
        if !dispersions_given {
            config.sil.dispersions = firmware_sim::Dispersions::typical_in(&config.family.family.body.units());
        }
        config.validate()?;
        Ok(config)
    }

    /// Reads and parses the config file at `path` ([`ExperimentConfig::from_toml`]); a mission
    /// file named by `scenario` is found beside the config (its path relative to the config's
    /// folder) and read into it.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Read(path.to_path_buf(), e))?;
        let mut table: toml::Table = toml::from_str(&text).map_err(|e| ConfigError::Parse(e.to_string()))?;
        let mission = match table.get("scenario") {
            Some(toml::Value::String(name)) if name.parse::<shared::scenario::ScenarioKind>().is_err() => {
                Some(path.parent().unwrap_or(Path::new(".")).join(name))
            }
            _ => None,
        };
        let Some(mission) = mission.filter(|m| m.is_file()) else {
            return Self::from_toml(&text);
        };
        let family = ground_core::mission::read_mission_file(&mission)
            .map_err(|e| ConfigError::Invalid(format!("scenario: {e}")))?;
        let value = toml::Value::try_from(family).map_err(|e| ConfigError::Parse(e.to_string()))?;
        table.insert("scenario".into(), value);
        Self::from_toml(&toml::to_string(&table).map_err(|e| ConfigError::Parse(e.to_string()))?)
    }

    /// The config as TOML with every value written out (defaults included); it parses back to an
    /// equal config. Written beside a run's outputs as `RUN/config.toml`.
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_default()
    }

    /// The onboard lookahead the SIL flies (`[sil] lookahead`), cycles of the family's length;
    /// rollouts asking for the adaptive integrator (`rollout_steps = 0`) run at the
    /// environment's tolerances.
    pub fn lookahead_settings(&self) -> Option<LookaheadSettings> {
        self.sil.lookahead.map(|settings| LookaheadSettings {
            tolerances: self.env.integrator.tolerances(),
            cycle: self.aid_cycle().unwrap_or(f64::NAN),
            ..settings
        })
    }

    /// The terminal targeting the SIL flies (`[sil] terminal`), cycles of the family's length;
    /// rollouts asking for the adaptive integrator (`rollout_steps = 0`) run at the
    /// environment's tolerances.
    pub fn terminal_settings(&self) -> Option<TerminalSettings> {
        self.sil.terminal.map(|settings| TerminalSettings {
            tolerances: self.env.integrator.tolerances(),
            cycle: self.aid_cycle().unwrap_or(f64::NAN),
            ..settings
        })
    }

    /// Transfer or rendezvous.
    pub fn problem(&self) -> shared::scenario::ProblemKind {
        self.family.family.problem
    }

    /// Components of the guidance action: throttle and the thrust direction, in the plane or
    /// in three dimensions.
    pub fn action_dim(&self) -> usize {
        if self.is_inclined() {
            onboard::features::ACTION3_LEN
        } else {
            onboard::features::ACTION_LEN
        }
    }

    /// Whether the family's orbits are inclined (flown in three dimensions).
    pub fn is_inclined(&self) -> bool {
        self.family.as_planar().is_none()
    }

    /// The family for a stage that flies planar families only; an inclined one refused with the
    /// stage named.
    pub fn planar_family(&self, stage: &'static str) -> Result<MissionFamily, crate::error::ExperimentError> {
        self.family
            .as_planar()
            .ok_or_else(|| crate::error::ExperimentError::Inclined {
                stage,
                family: self.family.label().to_string(),
            })
    }

    /// The feature layout of this config's networks: its problem's, planar or (an inclined
    /// family) three-dimensional.
    pub fn feature_layout(&self) -> shared::blob::FeatureLayout {
        shared::blob::FeatureLayout::of(self.problem(), self.is_inclined())
    }

    /// The mission a blob of this config carries:
    /// [`ground_core::mission::blob_mission`] of its family.
    pub fn blob_mission(&self) -> BlobMission {
        ground_core::mission::blob_mission(&self.family)
    }

    /// Why a blob carrying `mission` cannot fly this config's family (None: it can):
    /// [`ground_core::mission::blob_refusal`].
    pub fn mission_refusal(&self, mission: &BlobMission) -> Option<String> {
        ground_core::mission::blob_refusal(&self.family, mission)
    }

    /// The cycle (t*) the onboard aids count: the family's, when it has one length for every
    /// flight (a cycle in days; the same bits as its scenarios').
    fn aid_cycle(&self) -> Option<f64> {
        self.family.family.fixed_cycle()
    }

    /// The labels the config's learners write into their checkpoints and check when they load
    /// one (`Sac::labels`): the mission family, by label and fingerprint, so that a checkpoint
    /// of another family is refused with both named.
    pub fn learner_labels(&self) -> std::collections::BTreeMap<String, String> {
        let family = format!("{} ({:08x})", self.family.label(), self.family.fingerprint());
        std::collections::BTreeMap::from([("family".to_string(), family)])
    }

    /// The controller's name: [`Self::name`], or the family's label.
    pub fn display_name(&self) -> String {
        self.name.clone().unwrap_or_else(|| self.family.label().to_string())
    }

    /// Every check that needs no file system access.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if let Some(name) = &self.name {
            let allowed = |c: char| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-');
            if name.is_empty() || name.len() > 64 || !name.chars().all(allowed) {
                return Err(ConfigError::Invalid(format!(
                    "name = {name:?}: 1 to 64 letters, digits, '.', '_' or '-'"
                )));
            }
        }
        self.sac.validate().map_err(|e| ConfigError::Invalid(e.to_string()))?;
        self.sil
            .dispersions
            .validate()
            .map_err(|e| ConfigError::Invalid(format!("sil.dispersions: {e}")))?;
        if let Some(lookahead) = self.lookahead_settings() {
            lookahead
                .validate()
                .map_err(|e| ConfigError::Invalid(format!("sil.lookahead: {e}")))?;
        }
        if self.aid_cycle().is_none() && (self.sil.lookahead.is_some() || self.sil.terminal.is_some()) {
            return Err(ConfigError::Invalid(format!(
                "sil.lookahead / sil.terminal: the onboard aids count cycles of one length, and family {} \
                 cuts flights of different lengths into a count of cycles each: give its cycle in days, or fly \
                 its network alone",
                self.family.label()
            )));
        }
        if self.terminal_settings().is_some_and(|t| t.validate().is_err()) {
            return Err(ConfigError::Invalid(format!(
                "sil.terminal: cycles must be 1 to {}, iterations 1 to {}",
                onboard::terminal::MAX_CYCLES,
                onboard::terminal::MAX_ITERATIONS
            )));
        }
        let craft = &self.env.spacecraft;
        self.env.canonical_spacecraft().map_err(|e| {
            let (key, value) = match e {
                SpacecraftError::Thrust => ("max_thrust_n", craft.max_thrust_n),
                SpacecraftError::SpecificImpulse => ("isp_s", craft.isp_s),
                SpacecraftError::Mass => ("initial_mass_kg", craft.initial_mass_kg),
            };
            ConfigError::Invalid(format!("env.spacecraft.{key} = {value}: {e}"))
        })?;
        if let Some(slurm) = &self.compute.slurm {
            if !(1..=10_000).contains(&slurm.tasks) {
                return Err(ConfigError::Invalid(format!(
                    "compute.slurm.tasks must be 1 to 10000, not {}",
                    slurm.tasks
                )));
            }
            if slurm.sbatch.trim().is_empty() {
                return Err(ConfigError::Invalid("compute.slurm.sbatch is empty".into()));
            }
        }
        positive("pretrain.updates", self.pretrain.updates)?;
        positive("train.env_steps", self.train.env_steps)?;
        positive("pretrain.eval_every", self.pretrain.eval_every)?;
        positive("train.eval_every", self.train.eval_every)?;
        positive("train.eval_episodes", self.train.eval_episodes)?;
        positive("evaluate.episodes", self.evaluate.episodes)?;
        positive("sil.episodes", self.sil.episodes)?;
        if !(self.pretrain.behaviour_cloning.is_finite() && self.pretrain.behaviour_cloning >= 0.0) {
            return Err(ConfigError::Invalid(format!(
                "pretrain.behaviour_cloning must be a finite weight >= 0, got {}",
                self.pretrain.behaviour_cloning
            )));
        }
        if self.pretrain.cloning_target != CloningTarget::Action && self.pretrain.mode != PretrainMode::BehaviourCloning
        {
            return Err(ConfigError::Invalid(
                "pretrain.cloning_target applies to mode = \"behaviour-cloning\" only".into(),
            ));
        }
        positive("generate.count", self.generate.count)?;
        if let Some(candidates) = self.dagger.candidates {
            // 1e6: the stride between rounds' scenario streams (dagger::ROUND_STRIDE).
            if candidates < self.dagger.episodes || candidates > 1_000_000 {
                return Err(ConfigError::Invalid(
                    "dagger.candidates must be between dagger.episodes and 1,000,000".into(),
                ));
            }
        }
        positive("dagger.updates", self.dagger.updates)?;
        if self.dagger.max_miss.is_some_and(|m| !(m.is_finite() && m >= 1.0)) {
            return Err(ConfigError::Invalid(
                "dagger.max_miss must be a finite multiple of the accuracy goal, at least 1".into(),
            ));
        }
        if let Some(goal) = self.dagger.stop_at {
            if !(goal > 0.0 && goal <= 1.0) {
                return Err(ConfigError::Invalid("dagger.stop_at must be a share in (0, 1]".into()));
            }
            if self.dagger.rounds == 0 {
                return Err(ConfigError::Invalid(
                    "dagger.stop_at is set but dagger.rounds is 0: no round could reach it".into(),
                ));
            }
        }
        if let Some(patience) = self.dagger.patience {
            positive("dagger.patience", patience)?;
        }
        positive("dagger.score_episodes", self.dagger.score_episodes)?;
        self.finetune.validate("finetune")?;
        if self.dagger.fractions.is_empty() || !self.dagger.fractions.iter().all(|f| *f > 0.0 && *f < 1.0) {
            return Err(ConfigError::Invalid(
                "dagger.fractions must be a non-empty list of values in (0, 1)".into(),
            ));
        }
        if !(self.generate.final_eps > 0.0 && self.generate.final_eps <= 1.0) {
            return Err(ConfigError::Invalid("generate.final_eps must be in (0, 1]".into()));
        }
        if !self.stages.is_empty() {
            self.staged()?;
        }
        if self.compute.threads < 1 {
            return Err(ConfigError::Invalid("compute.threads must be at least 1".into()));
        }
        if !matches!(self.compute.device.as_str(), "cpu" | "cuda") {
            return Err(ConfigError::Invalid(format!(
                "compute.device must be \"cpu\" or \"cuda\", got {:?}",
                self.compute.device
            )));
        }
        Ok(())
    }

    /// The config each stage runs with, in order: the stage's changes applied on top of the
    /// config of the stage before (the first: this config), with no stages of its own.
    pub fn staged(&self) -> Result<Vec<ExperimentConfig>, ConfigError> {
        let mut before = ExperimentConfig {
            stages: Vec::new(),
            ..self.clone()
        };
        let mut configs = Vec::with_capacity(self.stages.len());
        for (i, stage) in self.stages.iter().enumerate() {
            let at = format!("stage {} ({})", i + 1, stage.name);
            let invalid = |reason: String| ConfigError::Invalid(format!("{at}: {reason}"));
            let named = !stage.name.is_empty()
                && stage
                    .name
                    .bytes()
                    .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-');
            if !named {
                return Err(invalid(
                    "a stage's name is lower-case letters, digits and dashes".into(),
                ));
            }
            if self.stages[..i].iter().any(|s| s.name == stage.name) {
                return Err(invalid("another stage has this name".into()));
            }
            if let Some(key) = stage.changes.keys().find(|k| !Stage::CHANGEABLE.contains(&k.as_str())) {
                return Err(invalid(format!(
                    "`{key}` cannot change in a stage; a stage changes {}",
                    Stage::CHANGEABLE.join(", ")
                )));
            }
            let mut table = toml::Table::try_from(&before).map_err(|e| invalid(e.to_string()))?;
            merge_tables(&mut table, &stage.changes);
            let config: ExperimentConfig = table.try_into().map_err(|e: toml::de::Error| invalid(e.to_string()))?;
            config.validate().map_err(|e| invalid(e.to_string()))?;
            if config.dagger.rounds == 0 {
                return Err(invalid("dagger.rounds is 0: a stage runs relabelling rounds".into()));
            }
            let rounds_before = before.dagger.rounds > 0;
            if stage.start == StageStart::Last && !rounds_before {
                return Err(invalid(
                    "start = \"last\" needs relabelling rounds in the stage before".into(),
                ));
            }
            if stage.inherit_relabels {
                if !rounds_before {
                    return Err(invalid(
                        "inherit_relabels needs relabelling rounds in the stage before".into(),
                    ));
                }
                if config.relabel_problem() != before.relabel_problem() {
                    return Err(invalid(
                        "inherit_relabels: the relabels were solved for another problem (final eps or arrival margin changed)"
                            .into(),
                    ));
                }
                if config.dagger.rounds <= before.dagger.rounds {
                    return Err(invalid(format!(
                        "dagger.rounds ({}) counts the {} inherited rounds: no round of its own would run",
                        config.dagger.rounds, before.dagger.rounds
                    )));
                }
            }
            let learner = |c: &ExperimentConfig| (c.sac.hidden.clone(), c.sac.actor_averaging > 0.0);
            if stage.start != StageStart::BestActor && learner(&config) != learner(&before) {
                return Err(invalid(
                    "sac.hidden or actor averaging changes: start = \"best-actor\" (the actor, widened) is the only learner that fits"
                        .into(),
                ));
            }
            configs.push(config.clone());
            before = config;
        }
        Ok(configs)
    }

    /// The config the recipe's shipped learner was trained and is flown with: its last stage's,
    /// or itself without stages.
    pub fn flown(&self) -> Result<ExperimentConfig, ConfigError> {
        Ok(self.staged()?.pop().unwrap_or_else(|| self.clone()))
    }

    /// The pretraining dataset file, checked to exist (relative paths are taken from `base`).
    pub fn dataset_file(&self, base: &Path) -> Result<PathBuf, ConfigError> {
        let path = self
            .pretrain
            .dataset
            .as_ref()
            .ok_or_else(|| ConfigError::Invalid("pretrain.dataset is not set".into()))?;
        let path = if path.is_relative() {
            base.join(path)
        } else {
            path.clone()
        };
        let file = if path.is_dir() { path.join("dataset.ltds") } else { path };
        if !file.is_file() {
            return Err(ConfigError::Invalid(format!(
                "pretrain.dataset {} does not exist",
                file.display()
            )));
        }
        Ok(file)
    }

    /// What a run's saved relabels depend on: the scenarios a round flies (scenario and seeds)
    /// and what they are solved to (final eps, arrival margin).
    pub fn relabel_problem(&self) -> (SpatialFamily, Seeds, f64, u32) {
        (
            self.family,
            self.seeds,
            self.generate.final_eps,
            self.generate.arrival_margin,
        )
    }

    /// The SAC settings of a phase: behaviour cloning on in `behaviour-cloning` pretraining
    /// (and in RL if asked), off otherwise.
    pub fn sac_for(&self, pretraining: bool) -> SacConfig {
        let bc = match self.pretrain.mode {
            PretrainMode::BehaviourCloning if pretraining || self.train.keep_behaviour_cloning => {
                self.pretrain.behaviour_cloning
            }
            _ => 0.0,
        };
        SacConfig {
            behaviour_cloning: bc,
            ..self.sac.clone()
        }
    }

    /// The behaviour-cloning error of the agents this experiment trains (`pretrain.cloning_target`,
    /// in pretraining and, when kept, in RL).
    pub fn cloning_loss(&self) -> Box<dyn CloningLoss> {
        self.pretrain.cloning_target.loss(self.action_dim())
    }

    /// The device the learner runs on. CUDA where there is none is refused, not replaced by the
    /// CPU: a job sized for a GPU would take days here. Asked by the commands that train or fly
    /// a network before they start, not by `validate`, so a run folder, model card or relabel
    /// request of a GPU run still reads on a machine without one.
    pub fn device(&self) -> Result<tch::Device, ConfigError> {
        if self.compute.device == "cuda" {
            crate::sac::cuda_device().map_err(|reason| {
                ConfigError::Invalid(format!(
                    "compute.device = \"cuda\": {reason}; set compute.device = \"cpu\""
                ))
            })
        } else {
            Ok(tch::Device::Cpu)
        }
    }
}

/// `changes` written over `table`: tables merged key by key, any other value replaced.
fn merge_tables(table: &mut toml::Table, changes: &toml::Table) {
    for (key, value) in changes {
        match (table.get_mut(key), value) {
            (Some(toml::Value::Table(inner)), toml::Value::Table(change)) => merge_tables(inner, change),
            _ => {
                table.insert(key.clone(), value.clone());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_equal_the_thesis() {
        let c = ExperimentConfig::from_toml("scenario = \"transfer-circular\"").unwrap();
        assert_eq!(
            c.family.family,
            shared::scenario::ScenarioKind::TransferCircular.family()
        );
        assert_eq!(c.sac.learning_rate, 3e-4);
        assert_eq!(c.sac.discount, 0.99);
        assert_eq!(c.sac.replay_capacity, 1_000_000);
        assert_eq!(c.sac.hidden, vec![256, 256]);
        assert_eq!(c.sac.batch_size, 256);
        assert_eq!(c.sac.target_smoothing, 0.005);
        assert_eq!(c.sac.warmup_steps, 50_000);
        assert_eq!(c.sac.initial_log_temperature, 0.0);
        assert_eq!(c.sac.target_entropy, None);
        assert_eq!(c.pretrain.eval_every, 10_000);
        assert_eq!(c.train.eval_episodes, 100);
        assert_eq!(c.evaluate.episodes, 10_000);
        assert_eq!(c.pretrain.mode, PretrainMode::Sac);
    }

    #[test]
    fn unknown_keys_and_impossible_values_are_refused() {
        let bad = [
            "scenario = \"transfer-circular\"\nsurprise = 1",
            "scenario = \"transfer-circular\"\n[sac]\nlearnig_rate = 1e-3",
            "scenario = \"transfer-circular\"\n[sac]\ndiscount = 1.5",
            "scenario = \"transfer-circular\"\n[sac]\nhidden = []",
            "scenario = \"transfer-circular\"\n[compute]\ndevice = \"tpu\"",
            "scenario = \"warp-drive\"",
            "[sac]\nbatch_size = 4",
            "scenario = \"transfer-circular\"\n[dagger]\nfractions = [0.5, 1.0]",
            "scenario = \"transfer-circular\"\n[dagger]\nfractions = []",
            "scenario = \"transfer-circular\"\n[dagger]\nupdates = 0",
            "scenario = \"transfer-circular\"\n[dagger]\nepisodes = 200\ncandidates = 100",
            "scenario = \"transfer-circular\"\n[dagger]\nstop_at = 0.95",
            "scenario = \"transfer-circular\"\n[dagger]\nrounds = 5\nstop_at = 1.5",
            "scenario = \"transfer-circular\"\n[dagger]\nmax_miss = 0.5",
            "scenario = \"transfer-circular\"\n[dagger]\nmax_miss = nan",
            "scenario = \"transfer-circular\"\n[sil]\nepisodes = 0",
            "scenario = \"transfer-circular\"\n[sil]\nlookahead = { accuracy_floor = 0.0 }",
            "scenario = \"transfer-circular\"\n[sil]\nlookahead = { fuel_weight = -1.0 }",
            "scenario = \"transfer-circular\"\n[sil]\nlookahead = { thrust_margin = 1.0 }",
            "scenario = \"transfer-circular\"\n[sil]\nterminal = { cycles = 0 }",
            "scenario = \"transfer-circular\"\nname = \"two words\"",
            "scenario = \"transfer-circular\"\nname = \"\"",
            "scenario = \"transfer-circular\"\n[sil]\nterminal = { cycles = 9 }",
            "scenario = \"transfer-circular\"\n[sil]\nterminal = { iterations = 0 }",
            "scenario = \"transfer-circular\"\n[sil]\nterminal = { goal_position = 1.0 }",
            "scenario = \"transfer-circular\"\n[sil]\nterminal = { rollout_steps = 33 }",
            "scenario = \"transfer-circular\"\n[sil]\nlookahead = { rollout_steps = 33 }",
            "scenario = \"transfer-circular\"\n[generate]\ncount = 0",
            "scenario = \"transfer-circular\"\n[pretrain]\nupdates = 0",
            "scenario = \"transfer-circular\"\n[dagger]\nrounds = 5\npatience = 0",
            "scenario = \"transfer-circular\"\n[train]\nenv_steps = 0",
        ];
        for text in bad {
            assert!(ExperimentConfig::from_toml(text).is_err(), "accepted: {text}");
        }
        // A refusal names the key and the value.
        let err = ExperimentConfig::from_toml(
            "scenario = \"transfer-circular\"\n[env.spacecraft]\nmax_thrust_n = -1.0\nisp_s = 3872.0\ninitial_mass_kg = 3366.0",
        )
        .unwrap_err();
        assert_eq!(
            err.to_string(),
            "config is invalid: env.spacecraft.max_thrust_n = -1: maximum thrust must be finite and > 0 N"
        );
        let err = ExperimentConfig::from_toml("scenario = \"transfer-circular\"\n[pretrain]\nbehaviour_cloning = nan")
            .unwrap_err();
        assert_eq!(
            err.to_string(),
            "config is invalid: pretrain.behaviour_cloning must be a finite weight >= 0, got NaN"
        );
        // The learner's own checks keep their messages.
        let err = ExperimentConfig::from_toml("scenario = \"transfer-circular\"\n[sac]\ndiscount = 1.5").unwrap_err();
        assert_eq!(
            err.to_string(),
            "config is invalid: sac.discount must be in [0, 1), got 1.5"
        );
        let err = ExperimentConfig::from_toml(
            "scenario = \"transfer-circular\"\n[sac]\ninitial_log_temperature = 1.0\nmax_log_temperature = 0.0",
        )
        .unwrap_err();
        assert_eq!(
            err.to_string(),
            "config is invalid: sac.initial_log_temperature (1) is above sac.max_log_temperature (Some(0.0))"
        );
    }

    /// A family as a mission file's path or as a table: the config holds the family, is written
    /// back with the whole table (a run keeps its family if the file changes), flies the
    /// spacecraft in the family's units, and refuses what the family cannot fly.
    #[test]
    fn a_mission_family_reads_from_a_file_or_a_table_and_is_written_whole() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let file = root.join("configs/missions/venus-inward.toml");
        let by_file = ExperimentConfig::from_toml(&format!(
            "scenario = {:?}\n[sil.dispersions]\nmissed_thrust_per_year = 0.0",
            file.display()
        ))
        .unwrap();
        assert_eq!(by_file.family.family.cycle, shared::mission::Cycle::Days(7.0));
        let written = by_file.to_toml();
        assert!(
            written.contains("[scenario]") && written.contains("lo_days = 250.0"),
            "{written}"
        );
        assert_eq!(ExperimentConfig::from_toml(&written).unwrap(), by_file);
        // Around the Earth the spacecraft's canonical thrust is in Earth units.
        let table = std::fs::read_to_string(&file)
            .unwrap()
            .replace("\"sun\"", "\"earth\"")
            .replace("departure = { a = [0.98, 1.02]", "departure = { a = [1.5, 1.6]");
        let table = table.replace("target = { a = [0.70, 0.74]", "target = { a = [1.7, 1.8]");
        let table = table
            .replace("{ lo_days = 250.0, hi_days = 320.0 }", "{ days = 30.0 }")
            .replace("days = 7.0", "days = 0.5");
        let mut toml: toml::Table = toml::from_str(&table).unwrap();
        let mut config = toml::Table::new();
        config.insert("scenario".into(), toml::Value::Table(std::mem::take(&mut toml)));
        let around_earth = ExperimentConfig::from_toml(&toml::to_string(&config).unwrap()).unwrap();
        let thrust = around_earth.env.canonical_spacecraft().unwrap().thrust;
        let units = shared::mission::CentralBody::EARTH.units();
        let expected = 1.33 / 3366.0 / units.acceleration_m_s2();
        assert!((thrust - expected).abs() <= 1e-15 * expected, "{thrust} {expected}");
        // The default dispersions are the typical physical sizes in the family's units: 1,000 km
        // and 0.1 m/s around the Earth, the thesis's constants around the Sun.
        let earth = around_earth.sil.dispersions;
        assert!(
            (earth.navigation_position * units.length_m - 1.0e6).abs() < 1e-6,
            "{earth:?}"
        );
        assert!(
            (earth.navigation_velocity * units.velocity_m_s() - 0.1).abs() < 1e-12,
            "{earth:?}"
        );
        assert_eq!(earth.missed_thrust_days, 7.0);
        assert_eq!(by_file.sil.dispersions.missed_thrust_per_year, 0.0);
        let sun = ExperimentConfig::from_toml(&format!("scenario = {:?}", file.display())).unwrap();
        assert_eq!(sun.sil.dispersions, firmware_sim::Dispersions::TYPICAL);
        // Written out and read back, they stay (the table is given then).
        assert_eq!(
            ExperimentConfig::from_toml(&around_earth.to_toml()).unwrap(),
            around_earth
        );
        // The onboard aids count the family's cycles, of one length.
        let aid = ExperimentConfig::from_toml(&format!(
            "scenario = {:?}\n[sil]\nterminal = {{ cycles = 2 }}",
            file.display()
        ))
        .unwrap();
        let weekly = aid.terminal_settings().unwrap().cycle;
        assert_eq!(weekly, aid.family.family.draw(1, 0).cycle);
        assert_eq!(weekly, 7.0 * 86_400.0 / shared::units::TIME_UNIT_S);
        let mut counted: toml::Table = toml::from_str(&written).unwrap();
        counted["scenario"]["cycle"] = toml::Value::Table(toml::from_str("count = 40").unwrap());
        counted["sil"].as_table_mut().unwrap().insert(
            "terminal".into(),
            toml::Value::Table(toml::from_str("cycles = 2").unwrap()),
        );
        let refused = ExperimentConfig::from_toml(&toml::to_string(&counted).unwrap())
            .unwrap_err()
            .to_string();
        assert!(
            refused.contains("sil.lookahead / sil.terminal") && refused.contains("custom-"),
            "{refused}"
        );
        // A count over a fixed flight is one length: the aids fly it, at the draws' own cycle.
        counted["scenario"]["time_of_flight"] = toml::Value::Table(toml::from_str("days = 300.0").unwrap());
        let fixed = ExperimentConfig::from_toml(&toml::to_string(&counted).unwrap()).unwrap();
        let cycle = fixed.terminal_settings().unwrap().cycle;
        assert_eq!(cycle.to_bits(), fixed.family.draw(1, 0).scenario.cycle.to_bits());
        assert_eq!(cycle, 7.5 * 86_400.0 / shared::units::TIME_UNIT_S);

        let bad = ExperimentConfig::from_toml("scenario = { problem = \"transfer\", body = \"sun\" }").unwrap_err();
        assert!(bad.to_string().contains("config does not parse"), "{bad}");
    }

    /// A blob flies its own family: the config's mission is accepted, a blob of fingerprint 0
    /// (the thesis's) only by families of the thesis's units and cycle, another family's refused with
    /// both named.
    #[test]
    fn a_blob_of_another_family_is_refused_with_both_named() {
        let preset = ExperimentConfig::from_toml("scenario = \"transfer-circular\"").unwrap();
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let weekly = ExperimentConfig::load(&root.join("configs/venus-inward.toml")).unwrap();
        assert_eq!(preset.mission_refusal(&preset.blob_mission()), None);
        assert_eq!(weekly.mission_refusal(&weekly.blob_mission()), None);
        assert_eq!(preset.mission_refusal(&BlobMission::THESIS), None);
        let old = weekly.mission_refusal(&BlobMission::THESIS).unwrap();
        assert!(
            old.contains("fingerprint 0") && old.contains(weekly.family.label().as_str()),
            "{old}"
        );
        let other = preset.mission_refusal(&weekly.blob_mission()).unwrap();
        assert!(
            other.contains(weekly.family.label().as_str()) && other.contains("transfer-circular"),
            "{other}"
        );
        let hard = ExperimentConfig::from_toml("scenario = \"transfer-hard\"").unwrap();
        let named = hard.mission_refusal(&preset.blob_mission()).unwrap();
        assert!(named.contains("family transfer-circular, not transfer-hard"), "{named}");
        // The mission's cycle is the aids' and the scenarios' own.
        assert_eq!(weekly.blob_mission().cycle, weekly.family.family.draw(1, 2).cycle);
    }

    /// `[sil] terminal` reads its settings by name and takes the environment's integrator
    /// tolerances for adaptive rollouts, as the lookahead does.
    #[test]
    fn terminal_targeting_reads_its_cycles_and_flies_with_the_environments_integrator() {
        let c = ExperimentConfig::from_toml(
            "scenario = \"transfer-circular\"\n[env.integrator]\nrelative = 1e-10\n[sil]\nterminal = { cycles = 2 }",
        )
        .unwrap();
        let t = c.terminal_settings().unwrap();
        assert_eq!((t.cycles, t.iterations), (2, TerminalSettings::default().iterations));
        assert_eq!(t.tolerances, c.env.integrator.tolerances());
        assert_eq!(ExperimentConfig::from_toml(&c.to_toml()).unwrap(), c);
        assert!(ExperimentConfig::from_toml("scenario = \"transfer-circular\"")
            .unwrap()
            .terminal_settings()
            .is_none());
    }

    #[test]
    fn round_trips_through_toml_and_the_embedded_default_parses() {
        let c = ExperimentConfig::from_toml(EMBEDDED_DEFAULT).unwrap();
        assert_eq!(ExperimentConfig::from_toml(&c.to_toml()).unwrap(), c);
    }

    /// The relabels' fallbacks read by name, default to every fallback, are left out of a
    /// written config at the default (run folders and cards written before keep their text) and
    /// round-trip otherwise; an unknown name is refused.
    #[test]
    fn relabel_fallbacks_read_by_name_and_round_trip() {
        let base = "scenario = \"rendezvous-circular\"\n";
        let plain = ExperimentConfig::from_toml(base).unwrap();
        assert_eq!(plain.dagger.fallbacks, Fallbacks::All);
        assert!(!plain.to_toml().contains("fallbacks"));
        for (name, fallbacks) in [("continuation", Fallbacks::Continuation), ("none", Fallbacks::None)] {
            let c = ExperimentConfig::from_toml(&format!("{base}[dagger]\nfallbacks = \"{name}\"\n")).unwrap();
            assert_eq!(c.dagger.fallbacks, fallbacks);
            assert!(c.to_toml().contains(&format!("fallbacks = \"{name}\"")));
            assert_eq!(ExperimentConfig::from_toml(&c.to_toml()).unwrap(), c);
        }
        let err = ExperimentConfig::from_toml(&format!("{base}[dagger]\nfallbacks = \"some\"\n")).unwrap_err();
        assert!(err.to_string().contains("some"), "{err}");
    }

    /// A fine-tuning phase's own torch threads: 1 unless set, written only when set, each
    /// phase its own, and a count below 1 refused with the phase named.
    #[test]
    fn finetuning_threads_default_to_one_per_phase_and_round_trip() {
        let base = "scenario = \"rendezvous-circular\"\n[compute]\nthreads = 2\n";
        let plain = ExperimentConfig::from_toml(&format!("{base}[finetune]\nsteps = 10\n")).unwrap();
        assert_eq!((plain.compute.threads, plain.finetune.threads), (2, 1));
        // Only [compute]'s: the phase's default is not written.
        assert_eq!(plain.to_toml().matches("threads").count(), 1);
        let text = format!("{base}[finetune]\nsteps = 10\nthreads = 2\n[finetune.then]\nsteps = 5\n");
        let c = ExperimentConfig::from_toml(&text).unwrap();
        let threads: Vec<i32> = c.finetune.phases().map(|p| p.threads).collect();
        assert_eq!(threads, [2, 1]);
        assert_eq!(ExperimentConfig::from_toml(&c.to_toml()).unwrap(), c);
        let err = ExperimentConfig::from_toml(&format!(
            "{base}[finetune]\nsteps = 10\n[finetune.then]\nsteps = 5\nthreads = 0\n"
        ))
        .unwrap_err();
        assert!(err.to_string().contains("finetune.then.threads"), "{err}");
    }

    /// A chained fine-tuning (`[finetune.then]`): its phases in order, each with its own keys'
    /// defaults, round-tripping through the run folder's TOML; a phase of no steps in a chain,
    /// or a bad key of the later phase, is refused with the phase named.
    #[test]
    fn chained_finetuning_phases_parse_in_order_and_bad_ones_are_refused() {
        let base = "scenario = \"rendezvous-circular\"\n";
        let text = format!(
            "{base}[finetune]\nsteps = 1200\n[finetune.then]\nsteps = 2000\nlearning_rate = 3e-5\ndispersed = true\n"
        );
        let c = ExperimentConfig::from_toml(&text).unwrap();
        let phases: Vec<(u64, f64, bool)> = c
            .finetune
            .phases()
            .map(|p| (p.steps, p.learning_rate, p.dispersed))
            .collect();
        let default = FinetuneConfig::default().learning_rate;
        assert_eq!(phases, [(1200, default, false), (2000, 3e-5, true)]);
        assert_eq!(ExperimentConfig::from_toml(&c.to_toml()).unwrap(), c);
        for (bad, needle) in [
            ("[finetune.then]\nsteps = 5\n", "finetune.then: each phase"),
            (
                "[finetune]\nsteps = 5\n[finetune.then]\nsteps = 0\n",
                "finetune.then: each phase",
            ),
            (
                "[finetune]\nsteps = 5\n[finetune.then]\nsteps = 5\nlearning_rate = -1.0\n",
                "finetune.then.learning_rate",
            ),
            (
                "[finetune]\nsteps = 5\n[finetune.then]\nsteps = 5\n[finetune.then.then]\nsteps = 1\nflights = 0\n",
                "finetune.then.then.flights",
            ),
        ] {
            let err = ExperimentConfig::from_toml(&format!("{base}{bad}"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(needle), "{bad}: {err}");
        }
    }

    /// configs/ holds recipes a user runs: each parses, validates, opens with a header saying
    /// what it is for and the command that runs it, and names no path of one machine.
    #[test]
    fn every_shipped_config_parses_validates_and_says_what_it_is_for() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        let mut count = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                ExperimentConfig::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                let text = std::fs::read_to_string(&path).unwrap();
                let header: Vec<&str> = text.lines().take_while(|l| l.starts_with('#')).collect();
                assert!(header.len() >= 2, "{}: no header comment", path.display());
                assert!(
                    header.iter().any(|l| l.contains("ground ")),
                    "{}: the header names no command",
                    path.display()
                );
                for machine_path in ["/work/", "/tmp/", "/home/", "/root/"] {
                    assert!(!text.contains(machine_path), "{}: {machine_path}", path.display());
                }
                count += 1;
            }
        }
        // The main job, one recipe per shipped model and a few studies (at most 5), not history.
        let models = std::fs::read_dir(dir.join("../models"))
            .unwrap()
            .filter(|e| e.as_ref().unwrap().path().is_dir())
            .count();
        assert!(
            (3..=models + 6).contains(&count),
            "configs/ holds {count} configs for {models} shipped models"
        );
    }

    /// A recipe's stages: each applies its changes on top of the stage before, round-trips
    /// through the run folder's TOML, and a stage that could not run is refused at parse time
    /// with the stage named.
    #[test]
    fn stages_change_the_config_stage_by_stage_and_impossible_ones_are_refused() {
        let base = "scenario = \"transfer-hard\"\n[generate]\ncount = 50\n[dagger]\nrounds = 4\nfractions = [0.5]\n";
        let text = format!(
            "{base}\n[[stage]]\nname = \"margin\"\nstart = \"best-actor\"\ngenerate = {{ arrival_margin = 2 }}\n\
             [stage.dagger]\nrounds = 6\ncloning_only = true\n\n[[stage]]\nname = \"near\"\nstart = \"last\"\n\
             inherit_relabels = true\ndagger = {{ rounds = 9, max_miss = 10.0 }}\nsil = {{ lookahead = {{ accuracy_floor = 0.5 }} }}\n"
        );
        let recipe = ExperimentConfig::from_toml(&text).unwrap();
        assert_eq!(ExperimentConfig::from_toml(&recipe.to_toml()).unwrap(), recipe);
        let staged = recipe.staged().unwrap();
        assert_eq!(staged.len(), 2);
        let (margin, near) = (&staged[0], &staged[1]);
        // Changed keys change; the rest of a changed section and the other sections carry over.
        assert_eq!((margin.generate.arrival_margin, margin.generate.count), (2, 50));
        assert_eq!((margin.dagger.rounds, margin.dagger.cloning_only), (6, true));
        assert_eq!(margin.dagger.fractions, vec![0.5]);
        assert!(margin.stages.is_empty() && margin.sil.lookahead.is_none());
        assert_eq!((near.dagger.rounds, near.dagger.max_miss), (9, Some(10.0)));
        assert!(near.dagger.cloning_only, "a change holds for the stages after it");
        assert_eq!(near.generate, margin.generate);
        assert_eq!(near.sil.lookahead.map(|l| l.accuracy_floor), Some(0.5));
        assert_eq!(recipe.flown().unwrap(), *near);
        let plain = ExperimentConfig::from_toml(base).unwrap();
        assert_eq!(plain.flown().unwrap(), plain);

        let refused = [
            ("seeds = { train = 5 }", "cannot change in a stage"),
            ("dagger = { rounds = 0 }", "dagger.rounds is 0"),
            ("dagger = { rounds = 9, max_miss = 0.5 }", "dagger.max_miss"),
            ("dagger = { rounds = 9, surprise = 1 }", "unknown field"),
            (
                "inherit_relabels = true\ngenerate = { arrival_margin = 1 }\ndagger = { rounds = 9 }",
                "another problem",
            ),
            ("inherit_relabels = true\ndagger = { rounds = 4 }", "inherited rounds"),
            ("sac = { hidden = [512, 512] }\ndagger = { rounds = 9 }", "best-actor"),
        ];
        for (stage, reason) in refused {
            let text = format!("{base}\n[[stage]]\nname = \"x\"\n{stage}\n");
            match ExperimentConfig::from_toml(&text) {
                Err(ConfigError::Invalid(message)) | Err(ConfigError::Parse(message)) => {
                    assert!(
                        message.contains(reason) && message.contains("stage 1 (x)"),
                        "{stage}: {message}"
                    )
                }
                Ok(_) => panic!("accepted: {stage}"),
                Err(e) => panic!("{stage}: {e}"),
            }
        }
        // A wider network from the stage before's actor alone is a stage that fits.
        let wider =
            format!("{base}\n[[stage]]\nname = \"wide\"\nstart = \"best-actor\"\nsac = {{ hidden = [512, 512] }}\n");
        assert_eq!(
            ExperimentConfig::from_toml(&wider).unwrap().flown().unwrap().sac.hidden,
            vec![512, 512]
        );
        let no_rounds =
            "scenario = \"transfer-hard\"\n[[stage]]\nname = \"y\"\nstart = \"last\"\ndagger = { rounds = 2 }\n";
        assert!(ExperimentConfig::from_toml(no_rounds).is_err());
        for name in ["", "Upper", "a/b", "x\n[[stage]]\nname = \"x\""] {
            let text = format!("{base}\n[[stage]]\nname = \"{name}\"\ndagger = {{ rounds = 9 }}\n");
            assert!(ExperimentConfig::from_toml(&text).is_err(), "name {name:?} accepted");
        }
    }

    #[test]
    fn cuda_is_refused_where_libtorch_finds_no_cuda_device_and_the_config_still_reads() {
        // A stored config of a GPU run parses anywhere; only asking for its device is refused.
        let c = ExperimentConfig::from_toml("scenario = \"transfer-circular\"\n[compute]\ndevice = \"cuda\"").unwrap();
        // libtorch's own answer, after the CUDA library has been given every chance to load.
        let _ = crate::sac::cuda_device();
        if tch::Cuda::is_available() {
            assert_eq!(c.device().unwrap(), tch::Device::Cuda(0));
        } else {
            match c.device() {
                Err(ConfigError::Invalid(reason)) => assert!(reason.contains("compute.device = \"cuda\""), "{reason}"),
                other => panic!("a CUDA config on a machine without CUDA gave {other:?}"),
            }
        }
        let cpu = ExperimentConfig::from_toml("scenario = \"transfer-circular\"").unwrap();
        assert_eq!(cpu.device().unwrap(), tch::Device::Cpu);
    }

    #[test]
    fn a_missing_dataset_is_refused() {
        let c = ExperimentConfig::from_toml(
            "scenario = \"transfer-circular\"\n[pretrain]\ndataset = \"/nonexistent/dataset\"",
        )
        .unwrap();
        assert!(matches!(c.dataset_file(Path::new(".")), Err(ConfigError::Invalid(_))));
    }
}
