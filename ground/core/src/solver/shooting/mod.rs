//! Single shooting for the free-anomaly transfer (docs/spec.md section 3): the residual of the terminal
//! conditions and its exact Jacobian, and a damped Newton iteration on them.
//!
//! - `problem`: the shooting problems ([`ShootingProblem`]): the transfer with its final
//!   anomaly free ([`TransferShooting`]) or pinned ([`PinnedAnomalyTransfer`]) and the
//!   rendezvous ([`RendezvousShooting`]), their unknowns, residuals and exact Jacobians.
//! - `newton`: the damped Newton iteration with its Levenberg-Marquardt fallback.
//! - `homotopy`: the energy-to-fuel continuation in eps down to [`FINAL_EPS`].

mod homotopy;
mod newton;
mod problem;

#[cfg(test)]
mod fixtures;

pub use homotopy::{
    continue_eps, homotopy, homotopy_schedule, homotopy_tangent, predict, solve_transfer_homotopy, HomotopyLevel,
    FINAL_EPS,
};
pub use newton::{newton, solve_transfer, NewtonOutcome, NewtonSettings, Progress};
pub use problem::{
    body_at, initial_state_costate, orbit_state, transfer_residual, transfer_residual_at, transfer_residual_only,
    transfer_residual_only_at, PinnedAnomalyTransfer, RendezvousAtTime, RendezvousShooting, RendezvousVector,
    ShootingProblem, TransferJacobian, TransferShooting, TransferVector, RENDEZVOUS_UNKNOWNS, TRANSFER_UNKNOWNS,
};
