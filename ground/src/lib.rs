//! Ground-side library behind the `ground` command line.

pub mod charts;
pub mod config;
pub mod dagger;
pub mod dataset;
pub mod demo;
pub mod env;
pub mod eval;
pub mod experiment;
pub mod export;
pub mod generate;
pub mod io;
pub mod pipeline;
pub mod plot;
pub mod sac;
pub mod sil;
pub mod solver;
