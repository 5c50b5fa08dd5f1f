//! The no_std contract between the ground trainer and the flight code: canonical units,
//! spacecraft and scenario types, and the versioned weight-blob format.
//!
//! - [`units`]: canonical units (docs/spec.md section 1): 1 AU, mu_sun = 1, mass in units of the
//!   initial mass, and the 14-day guidance step.
//! - [`spacecraft`]: thrust, specific impulse and mass, a parameter of every run.
//! - [`orbit`]: planar Keplerian orbits, polar and Cartesian states (docs/spec.md section 2).
//! - [`mission`]: mission families as data: central body and units, orbit ranges, time of
//!   flight, guidance cycle (docs/spec.md section 4).
//! - [`scenario`]: transfer and rendezvous problems and the thesis's four distributions
//!   (docs/spec.md section 4).
//! - [`blob`]: the weight blob that carries a trained actor to the flight computer
//!   (docs/spec.md section 10); decoding checks it and borrows its arrays in place.
//! - `quantize` (feature `std`, the ground side): trained weights to f32 and int8 blobs.
//!
//! # Example: a network's blob, from the ground to the flight computer
//!
//! The ground exports a trained actor mean head as a blob; the flight computer checks it
//! (magic, version, length, CRC-32, structure) and reads its arrays where they lie, without
//! copying or allocating. A tiny 10-4-4-3 transfer network:
//!
//! ```
//! use shared::blob::{self, Activation, BlobError, FeatureLayout, Quantization};
//! use shared::quantize::{DenseWeights, MlpWeights};
//! use shared::scenario::ProblemKind;
//!
//! // Ground (std): weights in PyTorch's layout, w[j * inputs + i].
//! let dense = |inputs: usize, outputs: usize, activation| DenseWeights {
//!     inputs,
//!     outputs,
//!     weights: (0..inputs * outputs).map(|k| 0.5 * (0.37 * k as f32).sin()).collect(),
//!     bias: vec![0.25; outputs],
//!     activation,
//! };
//! let network = MlpWeights {
//!     features: FeatureLayout::TransferPolar10,
//!     layers: vec![
//!         dense(10, 4, Activation::Relu),
//!         dense(4, 4, Activation::Relu),
//!         dense(4, 3, Activation::Tanh),
//!     ],
//! };
//! let bytes = network.f32_blob("doc example")?;
//!
//! // Flight (no_std, no heap): decode in place.
//! let decoded = blob::decode(&bytes)?;
//! assert_eq!(decoded.kind, ProblemKind::Transfer);
//! assert_eq!(decoded.quantization, Quantization::F32);
//! assert_eq!(decoded.features.len(), 10);
//! assert_eq!(decoded.layers.len(), 3);
//! assert_eq!(blob::f32_at(decoded.layers[0].bias, 3), Some(0.25));
//! // The f32 weights are stored input-major: element i * outputs + j is w[j][i], so element
//! // 1 * 4 + 2 is w[2][1], PyTorch's element 2 * 10 + 1.
//! assert_eq!(blob::f32_at(decoded.layers[0].weights, 6), Some(0.5 * (0.37 * 21.0f32).sin()));
//!
//! // A flipped bit anywhere in the payload is refused with a typed error, never a panic.
//! let mut corrupt = bytes.clone();
//! corrupt[blob::HEADER_LEN + 5] ^= 0x01;
//! assert!(matches!(blob::decode(&corrupt), Err(BlobError::CrcMismatch { .. })));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod blob;
pub mod decimal;
pub mod mission;
pub mod orbit;
#[cfg(feature = "std")]
pub mod quantize;
pub mod scenario;
pub mod spacecraft;
pub mod units;
