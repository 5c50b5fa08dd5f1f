//! Planar two-body dynamics with thrust and mass flow (docs/spec.md section 2), in canonical units.
//!
//! The thrust command is held constant over a guidance step **in the local polar frame**
//! (docs/spec.md section 5): the components (alpha_r, alpha_theta) stay fixed while the spacecraft
//! moves, so the inertial direction turns with the Sun line. Coasting arcs use the exact Kepler
//! solution; thrusting arcs the adaptive integrator.

use shared::orbit::{CartesianState, PolarState};
use shared::spacecraft::CanonicalSpacecraft;

use crate::integrator::{integrate, IntegrationError, OdeSystem, Tolerances};
use crate::kepler::{coast, KeplerError};

/// Number of state variables: x, y, vx, vy, m.
pub const STATE_LEN: usize = 5;

/// Spacecraft state: position and velocity in the ecliptic plane (AU, AU/t*) and mass (m0 units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpacecraftState {
    /// Position (AU).
    pub r: [f64; 2],
    /// Velocity (AU / t*).
    pub v: [f64; 2],
    /// Mass (m0 units: 1 at departure, falling as propellant is spent).
    pub m: f64,
}

/// Why a state cannot be propagated or encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StateError {
    /// A component is NaN or infinite.
    NonFinite,
    /// The spacecraft is at the Sun's centre (r = 0).
    ZeroRadius,
    /// The mass is zero or negative.
    NonPositiveMass,
}

/// A thrust command in the local polar frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThrustCommand {
    /// Throttle u in [0, 1].
    pub throttle: f64,
    /// Radial component of the unit thrust direction.
    pub alpha_r: f64,
    /// Along-track (transverse) component of the unit thrust direction.
    pub alpha_theta: f64,
}

/// Why a propagation was refused or failed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PropagationError {
    /// The state is unusable.
    State(StateError),
    /// Throttle outside [0, 1], non-finite, or a direction that is not a unit vector.
    Command,
    /// Spacecraft thrust or exhaust speed not finite and positive.
    Spacecraft,
    /// Duration not finite.
    Duration,
    /// The propellant would run out during the step (m would reach 0).
    MassDepleted,
    /// The adaptive integrator failed on a thrust arc.
    Integration(IntegrationError),
    /// The Kepler coast failed.
    Kepler(KeplerError),
    /// A thrusting step in three dimensions from a state whose velocity lies along its radius:
    /// the RTN frame the command is held in is undefined ([`crate::spatial`]).
    NoOrbitPlane,
}

impl core::fmt::Display for StateError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::NonFinite => "state has a NaN or infinite component",
            Self::ZeroRadius => "state is at the Sun's centre (r = 0)",
            Self::NonPositiveMass => "mass is zero or negative",
        })
    }
}

impl core::error::Error for StateError {}

impl core::fmt::Display for PropagationError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::State(e) => write!(f, "invalid state: {e}"),
            Self::Command => {
                f.write_str("invalid thrust command: throttle must be in [0, 1] and the direction a unit vector")
            }
            Self::Spacecraft => f.write_str("invalid spacecraft: thrust and exhaust speed must be finite and > 0"),
            Self::Duration => f.write_str("propagation duration must be finite"),
            Self::MassDepleted => f.write_str("propellant runs out during the step"),
            Self::Integration(e) => write!(f, "integration failed: {e}"),
            Self::Kepler(e) => write!(f, "Kepler coast failed: {e}"),
            Self::NoOrbitPlane => {
                f.write_str("the velocity lies along the radius: no orbit plane to hold the command in")
            }
        }
    }
}

impl core::error::Error for PropagationError {}

impl SpacecraftState {
    /// The state at departure from a point on an orbit, with m = 1.
    pub fn from_cartesian(c: &CartesianState, m: f64) -> Self {
        Self { r: c.r, v: c.v, m }
    }

    /// Position and velocity, without the mass.
    pub fn cartesian(&self) -> CartesianState {
        CartesianState { r: self.r, v: self.v }
    }

    /// The polar state (docs/spec.md section 2): r, theta, v_r, v_theta.
    pub fn polar(&self) -> PolarState {
        self.cartesian().to_polar()
    }

    /// Distance from the Sun (AU).
    pub fn radius(&self) -> f64 {
        libm::hypot(self.r[0], self.r[1])
    }

    /// Checks finiteness, r > 0 and m > 0.
    pub fn validate(&self) -> Result<(), StateError> {
        let [x, y] = self.r;
        let [vx, vy] = self.v;
        if ![x, y, vx, vy, self.m].iter().all(|c| c.is_finite()) {
            return Err(StateError::NonFinite);
        }
        if self.radius() <= 0.0 {
            return Err(StateError::ZeroRadius);
        }
        if self.m <= 0.0 {
            return Err(StateError::NonPositiveMass);
        }
        Ok(())
    }

    /// The integrator's state vector `[x, y, vx, vy, m]`.
    pub fn to_array(&self) -> [f64; STATE_LEN] {
        [self.r[0], self.r[1], self.v[0], self.v[1], self.m]
    }

    /// The state from the integrator's vector `[x, y, vx, vy, m]`.
    pub fn from_array(y: &[f64; STATE_LEN]) -> Self {
        let [x, yy, vx, vy, m] = *y;
        Self {
            r: [x, yy],
            v: [vx, vy],
            m,
        }
    }
}

impl ThrustCommand {
    /// Thrust off.
    pub const OFF: Self = Self {
        throttle: 0.0,
        alpha_r: 0.0,
        alpha_theta: 1.0,
    };

    /// Checks throttle range and unit direction (to 1e-6, the decoding threshold).
    pub fn validate(&self) -> Result<(), PropagationError> {
        let finite = self.throttle.is_finite() && self.alpha_r.is_finite() && self.alpha_theta.is_finite();
        let norm = libm::hypot(self.alpha_r, self.alpha_theta);
        if !finite || !(0.0..=1.0).contains(&self.throttle) || (norm - 1.0).abs() > 1e-6 {
            return Err(PropagationError::Command);
        }
        Ok(())
    }

    /// Inertial unit direction at polar angle theta given by (cos theta, sin theta).
    pub fn inertial_direction(&self, cos_theta: f64, sin_theta: f64) -> [f64; 2] {
        [
            self.alpha_r * cos_theta - self.alpha_theta * sin_theta,
            self.alpha_r * sin_theta + self.alpha_theta * cos_theta,
        ]
    }
}

/// Gravitational plus thrust acceleration and mass flow (docs/spec.md section 2, Eq. 3.1).
///
/// Returned as (acceleration, dm/dt); shared by the polar-hold propagation here and by the
/// ground's optimal-control dynamics (which supply an inertial direction instead).
pub fn acceleration(
    r: [f64; 2],
    m: f64,
    throttle: f64,
    direction: [f64; 2],
    sc: &CanonicalSpacecraft,
) -> ([f64; 2], f64) {
    let r2 = r[0] * r[0] + r[1] * r[1];
    let inv_r3 = 1.0 / (r2 * libm::sqrt(r2));
    let thrust_acc = sc.thrust * throttle / m;
    (
        [
            -r[0] * inv_r3 + thrust_acc * direction[0],
            -r[1] * inv_r3 + thrust_acc * direction[1],
        ],
        -sc.thrust * throttle / sc.exhaust_speed,
    )
}

/// The ODE of a zero-order-hold step: a command fixed in the local polar frame.
#[derive(Debug, Clone, Copy)]
pub struct PolarHoldDynamics {
    /// Thrust and exhaust speed in canonical units.
    pub spacecraft: CanonicalSpacecraft,
    /// The command held in the polar frame over the step.
    pub command: ThrustCommand,
}

impl OdeSystem<STATE_LEN> for PolarHoldDynamics {
    fn derivatives(&self, _t: f64, y: &[f64; STATE_LEN], dydt: &mut [f64; STATE_LEN]) {
        let [x, yy, vx, vy, m] = *y;
        let r = libm::hypot(x, yy);
        let dir = self.command.inertial_direction(x / r, yy / r);
        let (acc, mdot) = acceleration([x, yy], m, self.command.throttle, dir, &self.spacecraft);
        *dydt = [vx, vy, acc[0], acc[1], mdot];
    }
}

/// The checks of a zero-order-hold step's spacecraft and duration (planar and [`crate::spatial`]).
pub(crate) fn check_step(spacecraft: &CanonicalSpacecraft, duration: f64) -> Result<(), PropagationError> {
    if !spacecraft.is_valid() {
        return Err(PropagationError::Spacecraft);
    }
    if !duration.is_finite() {
        return Err(PropagationError::Duration);
    }
    Ok(())
}

/// Refuses a step at `throttle` from mass `m` that would empty the tank: the mass is linear in
/// time for a constant throttle.
pub(crate) fn check_tank(
    m: f64,
    throttle: f64,
    spacecraft: &CanonicalSpacecraft,
    duration: f64,
) -> Result<(), PropagationError> {
    let final_mass = m - spacecraft.thrust * throttle * duration / spacecraft.exhaust_speed;
    if final_mass.is_nan() || final_mass <= 0.0 {
        return Err(PropagationError::MassDepleted);
    }
    Ok(())
}

/// Propagates `state` for `duration` (t*) under `command` held in the polar frame.
///
/// Zero throttle coasts on the exact Kepler solution; otherwise the adaptive integrator runs
/// with `tolerances`. Every input is checked first; nothing here panics.
pub fn propagate(
    state: &SpacecraftState,
    command: &ThrustCommand,
    spacecraft: &CanonicalSpacecraft,
    duration: f64,
    tolerances: &Tolerances,
) -> Result<SpacecraftState, PropagationError> {
    state.validate().map_err(PropagationError::State)?;
    command.validate()?;
    check_step(spacecraft, duration)?;
    if command.throttle == 0.0 {
        let end = coast(&state.cartesian(), duration).map_err(PropagationError::Kepler)?;
        return Ok(SpacecraftState::from_cartesian(&end, state.m));
    }
    check_tank(state.m, command.throttle, spacecraft, duration)?;
    let system = PolarHoldDynamics {
        spacecraft: *spacecraft,
        command: *command,
    };
    let (y, _stats) =
        integrate(&system, 0.0, &state.to_array(), duration, tolerances).map_err(PropagationError::Integration)?;
    let end = SpacecraftState::from_array(&y);
    end.validate().map_err(PropagationError::State)?;
    Ok(end)
}
