//! Export of trajectories and policies to formats other tools read.

pub mod oem;
