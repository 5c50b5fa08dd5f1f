//! `lowthrust._lowthrust`: the project's Rust crates from Python. The Python package
//! (`python/lowthrust`) wraps it into Gymnasium environments; this module holds what runs in
//! Rust:
//!
//! - [`env`]: the transfer and rendezvous MDPs, planar or (inclined families) three-dimensional
//!   (`Env`, and `VecEnv` stepping many episodes per call in parallel), exactly
//!   `ground_core::env`'s.
//! - [`solver`]: the scenario draws, the indirect method (`solve`), dataset generation and
//!   reading a dataset as numpy arrays.
//!
//! Every failure is a `lowthrust.LowThrustError` (a `ValueError`) with the Rust error's
//! message; nothing here panics on any input.

use pyo3::prelude::*;

mod env;
mod model;
mod solver;

pyo3::create_exception!(
    _lowthrust,
    LowThrustError,
    pyo3::exceptions::PyValueError,
    "A refused input or a failed computation in the Rust crates; the message says why."
);

/// A Rust error as a Python exception.
pub(crate) fn refused(error: impl std::fmt::Display) -> PyErr {
    LowThrustError::new_err(error.to_string())
}

/// A scenario family's spec: a preset's name, a mission file's path, or a mission table as TOML
/// text (docs/missions.md).
fn family_spec(text: &str) -> PyResult<ground_core::mission::FamilySpec> {
    use ground_core::mission::{FamilySpec, FamilyTable};
    if text.contains('=') {
        let table: FamilyTable = toml::from_str(text).map_err(|e| refused(format!("mission table: {e}")))?;
        Ok(FamilySpec::Table(table))
    } else {
        FamilySpec::from_argument(text).map_err(refused)
    }
}

/// A scenario family, planar or inclined (`inclination`, `raan` in the mission table), checked.
pub(crate) fn spatial_scenario_family(text: &str) -> PyResult<shared::mission::SpatialFamily> {
    family_spec(text)?.spatial_family().map_err(refused)
}

#[pymodule]
fn _lowthrust(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("LowThrustError", m.py().get_type::<LowThrustError>())?;
    m.add(
        "SCENARIOS",
        shared::scenario::ScenarioKind::ALL.map(|k| k.name()).to_vec(),
    )?;
    m.add("STEP", shared::units::STEP)?;
    m.add("TIME_UNIT_S", shared::units::TIME_UNIT_S)?;
    m.add("AU_M", shared::units::AU_M)?;
    env::register(m)?;
    solver::register(m)?;
    model::register(m)?;
    Ok(())
}
