//! Two-body dynamics with thrust and mass flow in three dimensions (docs/spec.md section 3.6),
//! in canonical units.
//!
//! The thrust command is held constant over a guidance step **in the local RTN frame**, the
//! three-dimensional counterpart of [`crate::dynamics`]'s polar frame: radial r_hat, normal
//! n_hat = (r x v)/|r x v| along the orbit's angular momentum, transverse t_hat = n_hat x r_hat.
//! On a prograde planar orbit (n_hat = +z) the radial and transverse components are the polar
//! frame's (alpha_r, alpha_theta). Coasting arcs use the exact Kepler solution; thrusting arcs the
//! adaptive integrator. Nothing here panics or allocates.

use shared::orbit::{norm3, SpatialState};
use shared::spacecraft::CanonicalSpacecraft;

use crate::dynamics::{check_step, check_tank, PropagationError, StateError};
use crate::integrator::{integrate, OdeSystem, Tolerances};
use crate::kepler::coast3;

/// Number of state variables: x, y, z, vx, vy, vz, m.
pub const SPATIAL_STATE_LEN: usize = 7;

/// Spacecraft state in three dimensions: position, velocity and mass (m0 units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpatialCraftState {
    /// Position and velocity.
    pub orbit: SpatialState,
    /// Mass (m0 units: 1 at departure).
    pub m: f64,
}

/// A thrust command in the local RTN frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RtnCommand {
    /// Throttle u in [0, 1].
    pub throttle: f64,
    /// Radial component of the unit thrust direction.
    pub radial: f64,
    /// Transverse component (in the orbit plane, ahead of the radius).
    pub transverse: f64,
    /// Normal component (along the angular momentum).
    pub normal: f64,
}

impl SpatialCraftState {
    /// Checks finiteness, r > 0 and m > 0.
    pub fn validate(&self) -> Result<(), StateError> {
        let o = &self.orbit;
        if !(o.r.iter().chain(&o.v).all(|c| c.is_finite()) && self.m.is_finite()) {
            return Err(StateError::NonFinite);
        }
        if o.radius() <= 0.0 {
            return Err(StateError::ZeroRadius);
        }
        if self.m <= 0.0 {
            return Err(StateError::NonPositiveMass);
        }
        Ok(())
    }

    /// The integrator's vector `[x, y, z, vx, vy, vz, m]`.
    pub fn to_array(&self) -> [f64; SPATIAL_STATE_LEN] {
        let (r, v) = (self.orbit.r, self.orbit.v);
        [r[0], r[1], r[2], v[0], v[1], v[2], self.m]
    }

    /// The state from the integrator's vector.
    pub fn from_array(y: &[f64; SPATIAL_STATE_LEN]) -> Self {
        let [x, yy, z, vx, vy, vz, m] = *y;
        Self {
            orbit: SpatialState {
                r: [x, yy, z],
                v: [vx, vy, vz],
            },
            m,
        }
    }
}

impl RtnCommand {
    /// Thrust off.
    pub const OFF: Self = Self {
        throttle: 0.0,
        radial: 0.0,
        transverse: 1.0,
        normal: 0.0,
    };

    /// Checks throttle range and unit direction (to 1e-6, as the planar command).
    pub fn validate(&self) -> Result<(), PropagationError> {
        let parts = [self.throttle, self.radial, self.transverse, self.normal];
        let norm = norm3(&[self.radial, self.transverse, self.normal]);
        if !parts.iter().all(|c| c.is_finite()) || !(0.0..=1.0).contains(&self.throttle) || (norm - 1.0).abs() > 1e-6 {
            return Err(PropagationError::Command);
        }
        Ok(())
    }

    /// The inertial unit direction at `orbit`, or `None` where the RTN frame is undefined (the
    /// velocity along the radius: no orbit plane).
    pub fn inertial_direction(&self, orbit: &SpatialState) -> Option<[f64; 3]> {
        let [[r0, r1, r2], [t0, t1, t2], [n0, n1, n2]] = orbit.rtn_frame()?;
        let (a, b, c) = (self.radial, self.transverse, self.normal);
        Some([
            a * r0 + b * t0 + c * n0,
            a * r1 + b * t1 + c * n1,
            a * r2 + b * t2 + c * n2,
        ])
    }
}

/// The ODE of a zero-order-hold step: a command fixed in the local RTN frame.
#[derive(Debug, Clone, Copy)]
pub struct RtnHoldDynamics {
    /// Thrust and exhaust speed in canonical units.
    pub spacecraft: CanonicalSpacecraft,
    /// The command held in the RTN frame over the step.
    pub command: RtnCommand,
}

impl OdeSystem<SPATIAL_STATE_LEN> for RtnHoldDynamics {
    fn derivatives(&self, _t: f64, y: &[f64; SPATIAL_STATE_LEN], dydt: &mut [f64; SPATIAL_STATE_LEN]) {
        let state = SpatialCraftState::from_array(y);
        let r = state.orbit.r;
        let r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
        let inv_r3 = 1.0 / (r2 * libm::sqrt(r2));
        // Where the frame is undefined the derivatives turn non-finite and the integrator stops
        // with its typed error.
        let dir = self.command.inertial_direction(&state.orbit).unwrap_or([f64::NAN; 3]);
        let thrust_acc = self.spacecraft.thrust * self.command.throttle / state.m;
        let v = state.orbit.v;
        *dydt = [
            v[0],
            v[1],
            v[2],
            -r[0] * inv_r3 + thrust_acc * dir[0],
            -r[1] * inv_r3 + thrust_acc * dir[1],
            -r[2] * inv_r3 + thrust_acc * dir[2],
            -self.spacecraft.thrust * self.command.throttle / self.spacecraft.exhaust_speed,
        ];
    }
}

/// Propagates `state` for `duration` (t*) under `command` held in the RTN frame.
///
/// Zero throttle coasts on the exact Kepler solution; otherwise the adaptive integrator runs
/// with `tolerances`. Every input is checked first: a thrusting step from a state with no orbit
/// plane (velocity along the radius) is [`PropagationError::NoOrbitPlane`].
pub fn propagate_rtn(
    state: &SpatialCraftState,
    command: &RtnCommand,
    spacecraft: &CanonicalSpacecraft,
    duration: f64,
    tolerances: &Tolerances,
) -> Result<SpatialCraftState, PropagationError> {
    state.validate().map_err(PropagationError::State)?;
    command.validate()?;
    check_step(spacecraft, duration)?;
    if command.throttle == 0.0 {
        let end = coast3(&state.orbit, duration).map_err(PropagationError::Kepler)?;
        return Ok(SpatialCraftState { orbit: end, m: state.m });
    }
    if command.inertial_direction(&state.orbit).is_none() {
        return Err(PropagationError::NoOrbitPlane);
    }
    check_tank(state.m, command.throttle, spacecraft, duration)?;
    let system = RtnHoldDynamics {
        spacecraft: *spacecraft,
        command: *command,
    };
    let (y, _stats) =
        integrate(&system, 0.0, &state.to_array(), duration, tolerances).map_err(PropagationError::Integration)?;
    let end = SpatialCraftState::from_array(&y);
    end.validate().map_err(PropagationError::State)?;
    Ok(end)
}
