//! Ground-side library behind the `ground` command line.

pub mod solver;
