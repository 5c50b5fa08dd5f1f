//! The ground side without PyTorch: fuel-optimal trajectories by the indirect method, datasets,
//! demonstrations, the MDP environments, figures and the CCSDS OEM export.
//!
//! Everything here builds and runs without libtorch; the learning stack (`lowthrust-learn`)
//! builds on it.

pub mod charts;
pub mod crosscheck;
pub mod demo;
pub mod env;
pub mod generate;
pub mod io;
pub mod oem;
pub mod plot;
pub mod progress;
pub mod solver;
