//! The learning stack of the ground segment, on libtorch through `tch`: a Soft Actor-Critic
//! learner, its phases (pretraining on fuel-optimal demonstrations, RL, DAgger-style relabelling
//! rounds), the Monte Carlo evaluation, the export of the trained actor to the onboard weight
//! blobs (f32, int8), the software-in-the-loop (SIL) flights of those blobs, shipped models with
//! their cards, and the main job that runs them all into one run folder. Units are canonical
//! (AU, t* = sqrt(AU^3/mu_sun), m0 = 1) unless stated. The torch-free parts it builds on (solver,
//! datasets, environments, figures) are in `lowthrust-ground-core`.
//!
//! # Modules, in pipeline order
//!
//! - [`config`]: the experiment config (TOML) with every hyper-parameter, its defaults and checks.
//! - [`sac`]: the SAC learner: networks, Adam, replay buffer, interaction loop, checkpoints.
//! - [`cloning`]: the spacecraft's behaviour-cloning errors (on decoded thrust, not raw actions).
//! - [`run_folder`]: the run folder every stage writes into, and the checks that keep it one
//!   experiment's; [`error`]: what stops a stage.
//! - [`phase`]: what pretraining and RL share (evaluations, logs, checkpoints, resumption).
//! - [`pretrain`]: the demonstrations into the replay buffer, then N_pt updates.
//! - [`rl`]: SAC in the environment, vanilla or from the pretrained model.
//! - [`dagger`]: relabelling rounds: fly the policy, re-solve from visited states, retrain.
//! - [`stages`]: a recipe's stages: more rounds under changed settings, each from the last.
//! - [`eval`]: the Monte Carlo evaluation against baselines and the indirect optimum.
//! - [`export`]: a checkpoint's actor to the onboard f32 and int8 blobs, with their errors.
//! - [`sil`]: Monte Carlo of a blob in the SIL guidance loop against a dispersed plant.
//! - [`model`]: shipped models (actor, blobs, card), checked whenever opened.
//! - [`dataset`]: the demonstrations stage (the indirect method's solves into the run folder).
//! - [`ship`]: Monte Carlo, blobs, SIL and the model folder, for any checkpoint.
//! - [`report`]: the run's Markdown report.
//! - [`pipeline`]: the main job and the recipes (`ground run`): every stage, top to bottom.
//!
//! # Example
//!
//! The main job's embedded config, and a small SAC agent's deterministic action:
//!
//! ```
//! use learn::config::{ExperimentConfig, EMBEDDED_DEFAULT};
//! use learn::sac::{agent::Sac, SacConfig};
//!
//! let config = ExperimentConfig::from_toml(EMBEDDED_DEFAULT).unwrap();
//! config.validate().unwrap();
//! assert_eq!(config.family.label().as_str(), "transfer-circular");
//! assert_eq!(config.generate.count, 200); // demonstrations solved by the indirect method
//! assert_eq!(config.dagger.rounds, 12); // relabelling rounds, at most
//!
//! // An untrained agent at a tiny size: 10 transfer features in, 3 action components out.
//! let sac = SacConfig { hidden: vec![16, 16], ..SacConfig::default() };
//! let obs_dim = onboard::features::TRANSFER_FEATURES;
//! let agent = Sac::new(sac, obs_dim, 3, tch::Device::Cpu);
//! let action = agent.act(&vec![0.1; obs_dim], 1);
//! assert_eq!(action.len(), 3);
//! assert!(action.iter().all(|a| (-1.0..=1.0).contains(a)));
//! ```

#![deny(missing_docs)]

pub mod cloning;
pub mod config;
pub mod dagger;
pub mod dataset;
pub mod error;
pub mod eval;
pub mod export;
pub mod finetune;
pub mod model;
pub mod phase;
pub mod pipeline;
pub mod plan;
pub mod pretrain;
pub mod report;
pub mod rl;
pub mod run_folder;
pub mod sac;
pub mod ship;
pub mod sil;
pub mod stages;
