//! `ground model export`: a checkpoint's actor mean network to the onboard weight blobs, f32 and
//! int8, with what each costs in accuracy.
//!
//! - Calibration states (int8 activation scales): the demonstration tuples of the config's
//!   dataset, when it has one, and the states the trained policy visits on the periodic
//!   evaluation scenarios.
//! - Held-out states (the action error report): states the policy visits on scenarios of a
//!   stream used for neither training, evaluation nor calibration.
//! - Closed loop: both blobs fly the config's Monte Carlo scenarios in the ground environment
//!   through the onboard crate, so the int8 blob's mean reward is compared with the f32 one's.

use std::path::{Path, PathBuf};

use onboard::policy::{PolicyError, Rendezvous3Policy, RendezvousPolicy, Transfer3Policy, TransferPolicy};
use serde::{Deserialize, Serialize};
use shared::blob::{AlignedBlob, FeatureLayout, Quantization};
use shared::quantize::MlpWeights;

use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use crate::eval::load_agent;
use crate::phase::{family_of, policy_batch};
use crate::pretrain::load_demonstrations;
use crate::sac::agent::Sac;
use ground_core::demo::DemoGeometry;
use ground_core::env::batch::{evaluate, evaluate_batched, summarize, EpisodeOutcome, OutcomeSummary, Stats};
use ground_core::env::{ActionOf, Dimension, Geometry, MdpEnv, Problem, ScenarioOf};
use ground_core::io::atomic_write;

/// Stream offsets that keep the export's scenarios apart from training and evaluation.
const CALIBRATION_STREAM: u64 = 0x6361_6c69;
const HELD_OUT_STREAM: u64 = 0x686f_6c64;
/// Episodes flown for calibration states and for held-out states.
const STATE_EPISODES: u64 = 100;
/// Most demonstration states used for calibration.
const MAX_DEMONSTRATION_STATES: usize = 20_000;

/// The onboard policy of any feature layout, so one code path measures them all.
#[derive(Debug, Clone, Copy)]
pub enum OnboardPolicy<'a> {
    /// A planar transfer blob.
    Transfer(TransferPolicy<'a>),
    /// A planar rendezvous blob.
    Rendezvous(RendezvousPolicy<'a>),
    /// A three-dimensional transfer blob.
    Transfer3(Transfer3Policy<'a>),
    /// A three-dimensional rendezvous blob.
    Rendezvous3(Rendezvous3Policy<'a>),
}

impl<'a> OnboardPolicy<'a> {
    /// Loads a blob of `features` (refused exactly as the flight computer refuses it).
    pub fn load(bytes: &'a [u8], features: FeatureLayout) -> Result<Self, PolicyError> {
        let kind = features.problem();
        Ok(match features {
            FeatureLayout::TransferPolar10 => Self::Transfer(TransferPolicy::from_bytes(bytes, kind)?),
            FeatureLayout::RendezvousPolar22 => Self::Rendezvous(RendezvousPolicy::from_bytes(bytes, kind)?),
            FeatureLayout::TransferSpatial15 => Self::Transfer3(Transfer3Policy::from_bytes(bytes, kind)?),
            FeatureLayout::RendezvousSpatial30 => Self::Rendezvous3(Rendezvous3Policy::from_bytes(bytes, kind)?),
        })
    }

    /// The onboard action (3 or 4 components); NaN for an input of the wrong length (never
    /// flown: the environment flies a non-finite action as thrust off).
    pub fn act(&self, x: &[f32]) -> Vec<f32> {
        fn forward<const IN: usize, const OUT: usize>(x: &[f32], f: impl Fn(&[f32; IN]) -> [f32; OUT]) -> Vec<f32> {
            x.try_into().map_or([f32::NAN; OUT], f).to_vec()
        }
        match self {
            Self::Transfer(p) => forward(x, |a| p.forward(a)),
            Self::Rendezvous(p) => forward(x, |a| p.forward(a)),
            Self::Transfer3(p) => forward(x, |a| p.forward(a)),
            Self::Rendezvous3(p) => forward(x, |a| p.forward(a)),
        }
    }

    /// The onboard action as geometry `G`'s action (thrust off for an input of the wrong length).
    pub fn action<G: Geometry>(&self, x: &[f32]) -> ActionOf<G> {
        ActionOf::<G>::try_from(&self.act(x)).unwrap_or_else(|_| G::zero_thrust_action())
    }
}

/// Action error of a blob against the trained (tch) actor on the held-out states: per state,
/// the largest of the three component errors.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BlobReport {
    /// Where the blob was written.
    pub file: PathBuf,
    /// `f32` or `int8`.
    pub quantization: String,
    /// The blob's size in bytes.
    pub bytes: usize,
    /// Per held-out state, the largest component error |a_blob - a_tch| (actions in [-1, 1]).
    pub action_error: Stats,
    /// The closed-loop Monte Carlo of this blob in the ground environment.
    pub closed_loop: OutcomeSummary,
}

/// What an export wrote and measured (`export.json`); [`ExportReport::failed_criteria`] judges it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ExportReport {
    /// The checkpoint or actor file exported.
    pub checkpoint: PathBuf,
    /// Name of the config's scenario distribution (e.g. `transfer-circular`).
    pub problem: String,
    /// States the int8 activation scales were calibrated on (visited and demonstrated).
    pub calibration_states: usize,
    /// Of those, states of demonstration tuples (0 without a dataset).
    pub demonstration_states: usize,
    /// Held-out states the action errors were measured on.
    pub held_out_states: usize,
    /// The f32 blob.
    pub f32: BlobReport,
    /// The int8 blob.
    pub int8: BlobReport,
    /// Closed-loop episodes flown per blob (the config's Monte Carlo scenarios).
    pub closed_loop_episodes: usize,
    /// |int8 mean reward - f32 mean reward| / |f32 mean reward| (the goal: at most 2 %).
    pub int8_reward_difference: f64,
    /// The actor's deterministic action as an ONNX model (`actor.onnx`, the f32 blob's weights).
    pub onnx: PathBuf,
    /// Both blobs meet the export's accuracy criteria: a script reading export.json alone tells
    /// a failed export (its blobs kept for study) from a good one.
    pub passed: bool,
    /// The criteria not met, in words with their figures ([`ExportReport::failed_criteria`]).
    pub failed: Vec<String>,
}

/// The f32 blob flies the trained actor: its largest action error on the held-out states.
pub const F32_MAX_ACTION_ERROR: f64 = 1e-4;
/// The int8 blob's closed-loop mean reward stays this close to the f32 blob's (relative).
pub const INT8_MAX_REWARD_DIFFERENCE: f64 = 0.02;

impl ExportReport {
    /// The export's accuracy criteria that are not met, in words with their figures (empty:
    /// both blobs pass).
    pub fn failed_criteria(&self) -> Vec<String> {
        let mut failed = Vec::new();
        let f32_error = self.f32.action_error.max;
        // A NaN error (non-finite actions) fails too.
        if f32_error.is_nan() || f32_error > F32_MAX_ACTION_ERROR {
            failed.push(format!(
                "the f32 blob's action error reaches {f32_error:.3e} against the trained actor (at most {F32_MAX_ACTION_ERROR:.0e})"
            ));
        }
        if self.int8_reward_difference.is_nan() || self.int8_reward_difference > INT8_MAX_REWARD_DIFFERENCE {
            failed.push(format!(
                "the int8 blob's closed-loop mean reward differs from the f32 blob's by {:.2} % (at most {:.0} %)",
                100.0 * self.int8_reward_difference,
                100.0 * INT8_MAX_REWARD_DIFFERENCE
            ));
        }
        failed
    }
}

/// The actor mean network of an agent (`l0`, `l1`, ..., `mean`; tanh on the output) whose
/// inputs are `features`.
pub fn actor_network(agent: &Sac, features: FeatureLayout) -> Result<MlpWeights, ExperimentError> {
    let tensors = agent
        .actor_weights()
        .into_iter()
        .map(|(name, (shape, values))| (name, (shape.iter().map(|&d| d as usize).collect(), values)))
        .collect();
    ground_core::actor_file::actor_layers(features, &tensors).map_err(ExperimentError::Mismatch)
}

pub use ground_core::model_files::blob_file;

/// `ground model export`: writes `transfer-f32.blob` / `transfer-int8.blob` (or `rendezvous-*`),
/// `actor.onnx` (the deterministic action, for onnxruntime and the like) and `export.json` into
/// `out`. `config_dir` resolves the config's relative dataset path.
pub fn export(
    config: &ExperimentConfig,
    config_dir: &Path,
    checkpoint: &Path,
    out: &Path,
) -> Result<ExportReport, ExperimentError> {
    crate::with_flown_problem!(config, P => export_for::<P>(config, config_dir, checkpoint, out))
}

/// Network inputs at every state of `episodes` (recorded trajectories).
fn visited_inputs<P: Problem>(
    scenarios: &[ScenarioOf<P::Geometry>],
    episodes: &[EpisodeOutcome<P::Geometry>],
) -> Vec<Vec<f32>> {
    let mut inputs = Vec::new();
    for o in episodes {
        let (Some(trajectory), Some(scenario)) = (&o.trajectory, scenarios.get(o.episode)) else {
            continue;
        };
        for point in trajectory {
            if point.step < P::Geometry::plan(scenario).steps {
                if let Ok(f) = P::features(scenario, &point.state, point.step) {
                    inputs.push(P::observation(&f).as_ref().to_vec());
                }
            }
        }
    }
    inputs
}

fn export_for<P: Problem>(
    config: &ExperimentConfig,
    config_dir: &Path,
    checkpoint: &Path,
    out: &Path,
) -> Result<ExportReport, ExperimentError>
where
    P::Geometry: DemoGeometry,
{
    let family = family_of::<P::Geometry>(config)?;
    let draw = |seed: u64, count: u64| -> Vec<ScenarioOf<P::Geometry>> {
        (0..count).map(|i| P::Geometry::draw(&family, seed, i)).collect()
    };
    std::fs::create_dir_all(out).map_err(|e| ExperimentError::Io(out.to_path_buf(), e))?;
    let agent = load_agent(config, P::OBS, checkpoint)?;
    let network = actor_network(&agent, P::LAYOUT)?;
    let fly_recorded = |seed: u64| -> Result<Vec<Vec<f32>>, ExperimentError> {
        let scenarios = draw(seed, STATE_EPISODES);
        let flown = evaluate_batched::<MdpEnv<P>, _>(&config.env, &scenarios, |o| policy_batch(&agent, o), true)?;
        Ok(visited_inputs::<P>(&scenarios, &flown))
    };
    let mut calibration = fly_recorded(config.seeds.evaluation ^ CALIBRATION_STREAM)?;
    let demonstration = demonstration_inputs::<P>(config, config_dir)?;
    let demonstration_states = demonstration.len();
    calibration.extend(demonstration);
    let held_out = fly_recorded(config.seeds.monte_carlo ^ HELD_OUT_STREAM)?;

    let provenance = format!(
        "{} actor from {} ({} updates)",
        config.family.label(),
        checkpoint.display(),
        agent.updates
    );
    let f32_bytes = network
        .f32_blob_for(&provenance, config.blob_mission())
        .map_err(|e| ExperimentError::Mismatch(format!("f32 export: {e}")))?;
    let (int8_bytes, _) = network
        .int8_blob_for(&calibration, &provenance, config.blob_mission())
        .map_err(|e| ExperimentError::Mismatch(format!("int8 export: {e}")))?;

    // The trained actor's deterministic actions on the held-out states (one batch).
    let reference: Vec<ActionOf<P::Geometry>> = policy_batch(&agent, &held_out);
    let scenarios = draw(config.seeds.monte_carlo, config.evaluate.episodes);
    let mut reports = Vec::new();
    for (quantization, bytes) in [(Quantization::F32, &f32_bytes), (Quantization::Int8, &int8_bytes)] {
        let aligned = AlignedBlob::new(bytes);
        let policy = OnboardPolicy::load(aligned.bytes(), P::LAYOUT)
            .map_err(|e| ExperimentError::Mismatch(format!("the exported blob does not load onboard: {e}")))?;
        let errors = held_out.iter().zip(&reference).map(|(x, r)| {
            let a = policy.act(x);
            a.iter()
                .zip(r.as_ref())
                .map(|(a, r)| f64::from((a - r).abs()))
                .fold(0.0, f64::max)
        });
        let flown = evaluate::<MdpEnv<P>, _>(
            &config.env,
            &scenarios,
            |o: &P::Obs| policy.action::<P::Geometry>(o.as_ref()),
            false,
        )?;
        let file = out.join(blob_file(P::KIND, quantization));
        atomic_write(&file, bytes).map_err(|e| ExperimentError::Io(file.clone(), e))?;
        reports.push(BlobReport {
            file,
            quantization: format!("{quantization:?}").to_lowercase(),
            bytes: bytes.len(),
            action_error: Stats::of(errors),
            closed_loop: summarize(&flown),
        });
    }
    let int8 = reports
        .pop()
        .ok_or_else(|| ExperimentError::Mismatch("no int8 report".into()))?;
    let f32 = reports
        .pop()
        .ok_or_else(|| ExperimentError::Mismatch("no f32 report".into()))?;
    let onnx = out.join(ground_core::model_files::ONNX_FILE);
    let onnx_bytes = ground_core::onnx::actor_onnx(&network, &[("provenance", &provenance)])
        .map_err(|e| ExperimentError::Mismatch(format!("ONNX export: {e}")))?;
    atomic_write(&onnx, &onnx_bytes).map_err(|e| ExperimentError::Io(onnx.clone(), e))?;
    let (rf, ri) = (f32.closed_loop.total_reward.mean, int8.closed_loop.total_reward.mean);
    let mut report = ExportReport {
        onnx,
        checkpoint: checkpoint.to_path_buf(),
        problem: config.family.label().to_string(),
        calibration_states: calibration.len(),
        demonstration_states,
        held_out_states: held_out.len(),
        closed_loop_episodes: scenarios.len(),
        int8_reward_difference: (ri - rf).abs() / rf.abs().max(f64::MIN_POSITIVE),
        f32,
        int8,
        passed: false,
        failed: Vec::new(),
    };
    report.failed = report.failed_criteria();
    report.passed = report.failed.is_empty();
    let path = out.join("export.json");
    atomic_write(&path, &serde_json::to_vec_pretty(&report).unwrap_or_default())
        .map_err(|e| ExperimentError::Io(path, e))?;
    Ok(report)
}

/// Observations of the config's demonstration tuples (none when the config names no dataset).
fn demonstration_inputs<P: Problem>(
    config: &ExperimentConfig,
    config_dir: &Path,
) -> Result<Vec<Vec<f32>>, ExperimentError>
where
    P::Geometry: DemoGeometry,
{
    if config.pretrain.dataset.is_none() {
        return Ok(Vec::new());
    }
    let (demos, _, _) = load_demonstrations::<P>(config, config_dir)?;
    Ok(demos
        .transitions
        .iter()
        .take(MAX_DEMONSTRATION_STATES)
        .map(|t| t.observation.as_ref().to_vec())
        .collect())
}

/// A one-paragraph summary of an export.
pub fn describe(report: &ExportReport) -> String {
    let line = |b: &BlobReport| {
        format!(
            "{:>4}: {:>7} bytes, action error vs tch max {:.2e} (p50 {:.2e}, p95 {:.2e}); closed loop reward {:.4}, |dr| p50 {:.4} AU",
            b.quantization,
            b.bytes,
            b.action_error.max,
            b.action_error.p50,
            b.action_error.p95,
            b.closed_loop.total_reward.mean,
            b.closed_loop.terminal_position.p50
        )
    };
    format!(
        "{} blobs from {} ({} calibration states, {} of them demonstrations; {} held-out states; {} closed-loop episodes)\n{}\n{}\nint8 mean reward differs from f32 by {:.2} % (the goal: at most 2 %)",
        report.problem,
        report.checkpoint.display(),
        report.calibration_states,
        report.demonstration_states,
        report.held_out_states,
        report.closed_loop_episodes,
        line(&report.f32),
        line(&report.int8),
        100.0 * report.int8_reward_difference
    )
}
