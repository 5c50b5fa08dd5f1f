//! The no_std contract between the ground trainer and the flight code: canonical units,
//! spacecraft and scenario types, and the versioned weight-blob format.
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]

pub mod blob;
pub mod orbit;
#[cfg(feature = "std")]
pub mod quantize;
pub mod scenario;
pub mod spacecraft;
pub mod units;
