//! Flight code: no_std, no heap, no panics on any input.
//!
//! - [`dynamics`]: the planar two-body dynamics with thrust and mass flow (docs/spec.md section 2),
//!   and the 14-day zero-order-hold propagation the environment and the SIL plant use.
//! - [`integrator`]: an adaptive embedded Runge-Kutta integrator, generic over the state size
//!   so the ground solver reuses it for state + costate (+ sensitivity) propagation.
//! - [`kepler`]: the universal-variable Kepler coast propagator.
//! - [`features`]: polar feature encoding (docs/spec.md sections 5, 6), reward terms, action
//!   decoding.
//! - [`policy`]: fixed-size MLP inference in f32 and int8 straight from a weight blob.
//! - [`guidance`]: one guidance step: navigation state, target and time to go in, thrust out.
#![no_std]
// `unsafe` is denied everywhere but in `policy::arm`, the Cortex-M4F `asm!` kernels, the one
// module that allows it.
#![deny(unsafe_code)]
#![deny(missing_docs)]
// Panic-freedom is enforced by the linter, not hoped for: CI runs clippy with -D warnings.
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::unreachable,
        clippy::todo,
        clippy::unimplemented,
        clippy::integer_division,
        clippy::panic_in_result_fn
    )
)]

pub mod dynamics;
pub mod features;
pub mod guidance;
pub mod integrator;
pub mod kepler;
pub mod policy;
