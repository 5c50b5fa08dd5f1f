//! The learning stack on libtorch (through `tch`): SAC, experiments (pretraining, RL,
//! DAgger-style relabelling rounds), Monte Carlo evaluation, export of onboard blobs from
//! checkpoints, shipped models with their cards, the SIL driver and the main job.
//!
//! The torch-free parts it builds on (solver, datasets, environments, figures) are in
//! `lowthrust-ground-core`.

pub mod cloning;
pub mod config;
pub mod dagger;
pub mod eval;
pub mod experiment;
pub mod export;
pub mod model;
pub mod pipeline;
pub mod sac;
pub mod sil;
