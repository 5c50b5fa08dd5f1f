//! The no_std contract between the ground trainer and the flight code: canonical units,
//! spacecraft and scenario types, and the versioned weight-blob format.
//!
//! - [`units`]: canonical units (docs/spec.md section 1): 1 AU, mu_sun = 1, mass in units of the
//!   initial mass, and the 14-day guidance step.
//! - [`spacecraft`]: thrust, specific impulse and mass, a parameter of every run.
//! - [`orbit`]: planar Keplerian orbits, polar and Cartesian states (docs/spec.md section 2).
//! - [`scenario`]: transfer and rendezvous problems and their distributions (docs/spec.md
//!   section 4).
//! - [`blob`]: the weight blob that carries a trained actor to the flight computer
//!   (docs/spec.md section 10); decoding checks it and borrows its arrays in place.
//! - `quantize` (feature `std`, the ground side): trained weights to f32 and int8 blobs.
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod blob;
pub mod orbit;
#[cfg(feature = "std")]
pub mod quantize;
pub mod scenario;
pub mod spacecraft;
pub mod units;
