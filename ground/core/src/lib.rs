//! The ground side without PyTorch: fuel-optimal trajectories by the indirect method, datasets,
//! demonstrations, the MDP environments, figures and the CCSDS OEM export.
//!
//! Everything here builds and runs without libtorch; the learning stack (`lowthrust-learn`)
//! builds on it. The physics is planar heliocentric two-body motion with one low-thrust engine
//! (docs/spec.md), in canonical units throughout: lengths in AU, times in t* = sqrt(AU^3 /
//! mu_sun) (about 58.1 days), velocities in AU/t*, masses as fractions of the initial mass
//! m0 = 1, angles in radians.
//!
//! # Modules, in pipeline order
//!
//! - [`solver`]: the indirect fuel-optimal solver (Pontryagin's conditions, shooting, the
//!   energy-to-fuel homotopy, the near-circular and minimum-time paths, a direct cross-check
//!   method) that turns a scenario into a [`solver::record::TrajectoryRecord`].
//! - [`generate`]: datasets at scale: every draw of a scenario distribution solved in parallel,
//!   resumable, sharded, written as checksummed record files and summaries.
//! - [`demo`]: solved records turned into experience tuples (s, a, r, s', done) of the
//!   environments.
//! - [`env`](mod@env): the transfer and rendezvous Markov decision processes on the onboard
//!   dynamics, and batched Monte Carlo evaluation of a policy ([`env::batch`]).
//! - [`crosscheck`]: dataset records checked against the direct transcription, and repaired
//!   where it finds a heavier final mass.
//! - [`oem`]: CCSDS OEM (KVN) export of a record, with its thrust profile.
//! - [`actor_file`]: the learner's checked safetensors files read without PyTorch (a shipped
//!   actor's layers); [`onnx`]: an actor as an ONNX model; [`model_files`]: a shipped model
//!   folder's files checked against its card.
//! - [`plot`]: SVG figures of solved transfers: paths coloured by thrust, throttle along the
//!   homotopy.
//! - [`charts`]: SVG charts of the learning stack: learning curves, histograms, flown paths.
//! - [`io`]: atomic writes, the checksummed container format, the run-folder lock.
//! - [`progress`]: progress bars for a terminal or a log file.
//!
//! # Example
//!
//! A fuel-optimal transfer between the circles of 1.0 AU and 1.5 AU, solved by the indirect
//! method for the Mars Sample Return Earth Return Orbiter (1.33 N, Isp 3872 s, 3366 kg):
//!
//! ```
//! use ground_core::solver::{solve_scenario, SolveOptions};
//! use shared::orbit::{OrbitElements, OrbitShape};
//! use shared::scenario::{Scenario, ScenarioKind};
//! use shared::spacecraft::Spacecraft;
//!
//! let initial = OrbitElements {
//!     shape: OrbitShape { a: 1.0, e: 0.0, omega: 0.0 },
//!     nu: 0.0,
//! };
//! let target = OrbitShape { a: 1.5, e: 0.0, omega: 0.0 };
//! // Time of flight: the docs/spec.md section 4 rule, in whole 14-day steps.
//! let scenario = Scenario::transfer(initial, target);
//! let spacecraft = Spacecraft::MSR_ERO.canonical()?;
//!
//! let record = solve_scenario(
//!     ScenarioKind::TransferCircular, // a label of the record (seed 0, index 0)
//!     0,
//!     0,
//!     &scenario,
//!     &spacecraft,
//!     &SolveOptions::default(),
//! );
//! assert!(record.converged, "{:?}", record.failure);
//! // Final mass as a fraction of m0: some propellant spent, not all of it.
//! assert!(record.final_mass > 0.0 && record.final_mass < 1.0);
//! // One sample per 14-day step boundary, departure and arrival included.
//! assert_eq!(record.steps.len(), scenario.steps as usize + 1);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![deny(missing_docs)]

pub mod actor_file;
pub mod charts;
pub mod crosscheck;
pub mod demo;
pub mod env;
pub mod generate;
pub mod io;
pub mod mission;
pub mod model_files;
pub mod oem;
pub mod onnx;
pub mod plot;
pub mod progress;
pub mod solver;
pub mod spatial;
