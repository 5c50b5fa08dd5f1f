//! Ground-side library behind the `ground` command line.

pub mod dataset;
pub mod export;
pub mod solver;
