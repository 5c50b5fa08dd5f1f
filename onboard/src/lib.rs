//! Flight code: no_std, no heap, no panics on any input.
//!
//! - [`dynamics`]: the planar two-body dynamics with thrust and mass flow (docs/spec.md section 2),
//!   and the 14-day zero-order-hold propagation the environment and the SIL plant use.
//! - [`integrator`]: an adaptive embedded Runge-Kutta integrator, generic over the state size
//!   so the ground solver reuses it for state + costate (+ sensitivity) propagation.
//! - [`kepler`]: the universal-variable Kepler coast propagator, planar and in three dimensions.
//! - [`spatial`]: the two-body dynamics with thrust in three dimensions, the command held in the
//!   local RTN frame (docs/spec.md section 3.6).
//! - [`features`]: polar feature encoding (docs/spec.md sections 5, 6), reward terms, action
//!   decoding.
//! - [`policy`]: fixed-size MLP inference in f32 and int8 straight from a weight blob.
//! - [`guidance`]: one guidance step: navigation state, target and time to go in, thrust out.
//! - [`lookahead`]: the network's command improved by rollouts to the arrival with the onboard
//!   propagator.
//!
//! # Example: load a blob, fly one guidance step
//!
//! The weight blob comes from the ground (here made on the spot with `shared`'s `std` side, from
//! made-up weights of the deployed 10-256-256-3 shape); the flight computer views it in place as
//! a [`policy::TransferPolicy`], computes one command from the navigation state and holds it in
//! the local polar frame for one 14-day step.
//!
//! ```
//! use onboard::dynamics::{propagate, SpacecraftState};
//! use onboard::guidance::transfer_step;
//! use onboard::integrator::Tolerances;
//! use onboard::policy::TransferPolicy;
//! use shared::blob::{Activation, FeatureLayout, ProblemKind};
//! use shared::orbit::OrbitShape;
//! use shared::quantize::{DenseWeights, MlpWeights};
//! use shared::spacecraft::Spacecraft;
//! use shared::units::STEP;
//!
//! // Ground: an actor mean head (PyTorch layout) exported as an f32 blob.
//! let dense = |inputs: usize, outputs: usize, activation| DenseWeights {
//!     inputs,
//!     outputs,
//!     weights: (0..inputs * outputs).map(|k| 0.1 * (0.7 * k as f32).sin()).collect(),
//!     bias: vec![0.05; outputs],
//!     activation,
//! };
//! let network = MlpWeights {
//!     features: FeatureLayout::TransferPolar10,
//!     layers: vec![
//!         dense(10, 256, Activation::Relu),
//!         dense(256, 256, Activation::Relu),
//!         dense(256, 3, Activation::Tanh),
//!     ],
//! };
//! let blob = network.f32_blob("doc example")?;
//!
//! // Flight: check the blob and view its weights in place (a refused blob means thrust off).
//! let policy = TransferPolicy::from_bytes(&blob, ProblemKind::Transfer)?;
//!
//! // Earth's orbit to Mars's, 300 days to go; the state is in canonical units (AU, AU/t*, m0).
//! let navigation = SpacecraftState { r: [1.0, 0.0], v: [0.0, 1.0], m: 1.0 };
//! let mars = OrbitShape { a: 1.524, e: 0.0, omega: 0.0 };
//! let time_to_go = 300.0 / 14.0 * STEP;
//! let command = transfer_step(&policy, &navigation, &mars, time_to_go)?;
//! assert!((0.0..=1.0).contains(&command.throttle));
//! assert!(command.validate().is_ok()); // a unit direction, or thrust off
//!
//! // The command held in the polar frame for one step. These weights thrust (throttle 0.58),
//! // so propellant is spent: m falls by T u dt / c.
//! let spacecraft = Spacecraft::MSR_ERO.canonical()?;
//! let next = propagate(&navigation, &command, &spacecraft, STEP, &Tolerances::default())?;
//! let spent = spacecraft.thrust * command.throttle * STEP / spacecraft.exhaust_speed;
//! assert!((navigation.m - next.m - spent).abs() < 1e-12);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![no_std]
// `unsafe` is denied everywhere but in `policy::arm`, the Cortex-M4F `asm!` kernels, and
// `policy::x86`, the x86-64 AVX2 + FMA kernel: the two modules that allow it.
#![deny(unsafe_code)]
#![deny(missing_docs)]
#![deny(clippy::undocumented_unsafe_blocks)]
// Panic-freedom is enforced by the linter, not hoped for: CI runs clippy with -D warnings.
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::unreachable,
        clippy::integer_division,
        clippy::panic_in_result_fn
    )
)]

pub mod dynamics;
pub mod features;
pub mod geometry;
pub mod guidance;
pub mod integrator;
pub mod kepler;
pub mod lookahead;
pub mod policy;
pub mod spatial;
pub mod terminal;
