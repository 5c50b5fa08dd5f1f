//! Polar feature encoding, reward terms and action decoding (docs/spec.md sections 5 and 6).
//!
//! One implementation serves the ground environment and the flight code, so what the network
//! saw in training is exactly what it sees in flight.

use shared::orbit::{CartesianState, OrbitShape};

use crate::dynamics::{SpacecraftState, StateError, ThrustCommand};

/// Network inputs of the transfer policy.
pub const TRANSFER_FEATURES: usize = 10;
/// Network inputs of the rendezvous policy.
pub const RENDEZVOUS_FEATURES: usize = 22;
/// Network outputs: throttle and the two polar direction components, each in [-1, 1].
pub const ACTION_LEN: usize = 3;
/// Below this norm of (a1, a2) the direction is undefined and the thrust is off (docs/spec.md
/// section 5).
pub const MIN_DIRECTION_NORM: f64 = 1e-6;

/// Reward weights (thesis Eq. 4.7-4.8).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RewardWeights {
    /// w_p (1 / AU^2): how sharply the position term rewards closing the position gap.
    pub position: f64,
    /// w_v ((t* / AU)^2): how sharply the velocity term rewards closing the velocity gap.
    pub velocity: f64,
    /// w_u: the cost of throttle, a proxy for propellant.
    pub throttle: f64,
}

impl Default for RewardWeights {
    fn default() -> Self {
        Self {
            position: 0.2,
            velocity: 0.2,
            throttle: 0.02,
        }
    }
}

/// Distance to the target in position (AU) and velocity (AU/t*).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Residuals {
    /// Position residual (AU).
    pub position: f64,
    /// Velocity residual (AU / t*).
    pub velocity: f64,
}

/// Why features could not be computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FeatureError {
    /// The spacecraft state is unusable.
    State(StateError),
    /// The target orbit or body state is not finite or not a closed orbit.
    Target,
    /// Time to go is negative or not finite.
    TimeToGo,
}

impl core::fmt::Display for FeatureError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::State(e) => write!(f, "invalid spacecraft state: {e}"),
            Self::Target => {
                f.write_str("invalid target: orbit must be closed and finite, body state finite with r > 0")
            }
            Self::TimeToGo => f.write_str("time to go must be finite and >= 0"),
        }
    }
}

impl core::error::Error for FeatureError {}

fn check_common(state: &SpacecraftState, time_to_go: f64) -> Result<(), FeatureError> {
    state.validate().map_err(FeatureError::State)?;
    if !(time_to_go.is_finite() && time_to_go >= 0.0) {
        return Err(FeatureError::TimeToGo);
    }
    Ok(())
}

/// The 10 transfer features (docs/spec.md section 5):
/// `[r, cos theta, sin theta, v_r, v_theta, m, r_t, v_r_t, v_theta_t, t_tg]`, where the target
/// proxy is the polar state on the target orbit at the spacecraft's own polar angle.
pub fn transfer_features(
    state: &SpacecraftState,
    target: &OrbitShape,
    time_to_go: f64,
) -> Result<[f64; TRANSFER_FEATURES], FeatureError> {
    check_common(state, time_to_go)?;
    target.validate().map_err(|_| FeatureError::Target)?;
    let p = state.polar();
    let proxy = target.polar_at(p.theta - target.omega);
    Ok([
        p.r,
        libm::cos(p.theta),
        libm::sin(p.theta),
        p.v_r,
        p.v_theta,
        state.m,
        proxy.r,
        proxy.v_r,
        proxy.v_theta,
        time_to_go,
    ])
}

/// Residuals of a transfer state, read off its features (docs/spec.md section 5).
pub fn transfer_residuals(f: &[f64; TRANSFER_FEATURES]) -> Residuals {
    let [r, _, _, v_r, v_theta, _, r_t, v_r_t, v_theta_t, _] = *f;
    Residuals {
        position: (r_t - r).abs(),
        velocity: libm::hypot(v_r_t - v_r, v_theta_t - v_theta),
    }
}

/// The 22 rendezvous features (docs/spec.md section 6):
/// `[r_i, cos th_i, sin th_i, r_t, cos th_t, sin th_t, x_i, y_i, vx_i, vy_i, x_t, y_t, vx_t, vy_t,
///   dx, dy, dvx, dvy, |dr|, |dv|, t_tg, m]` with dr = r_t - r_i, dv = v_t - v_i.
pub fn rendezvous_features(
    state: &SpacecraftState,
    target_body: &CartesianState,
    time_to_go: f64,
) -> Result<[f64; RENDEZVOUS_FEATURES], FeatureError> {
    check_common(state, time_to_go)?;
    let body = SpacecraftState::from_cartesian(target_body, 1.0);
    body.validate().map_err(|_| FeatureError::Target)?;
    let (pi, pt) = (state.polar(), body.polar());
    let dr = [target_body.r[0] - state.r[0], target_body.r[1] - state.r[1]];
    let dv = [target_body.v[0] - state.v[0], target_body.v[1] - state.v[1]];
    Ok([
        pi.r,
        libm::cos(pi.theta),
        libm::sin(pi.theta),
        pt.r,
        libm::cos(pt.theta),
        libm::sin(pt.theta),
        state.r[0],
        state.r[1],
        state.v[0],
        state.v[1],
        target_body.r[0],
        target_body.r[1],
        target_body.v[0],
        target_body.v[1],
        dr[0],
        dr[1],
        dv[0],
        dv[1],
        libm::hypot(dr[0], dr[1]),
        libm::hypot(dv[0], dv[1]),
        time_to_go,
        state.m,
    ])
}

/// Residuals of a rendezvous state, read off its features (docs/spec.md section 6).
pub fn rendezvous_residuals(f: &[f64; RENDEZVOUS_FEATURES]) -> Residuals {
    let [.., dr, dv, _, _] = *f;
    Residuals {
        position: dr,
        velocity: dv,
    }
}

/// Reward of one step, evaluated at the new state (thesis Eq. 4.7-4.8):
/// `(exp(-w_p dr^2) - 1) + (exp(-w_v dv^2) - 1) - w_u u`.
pub fn reward(residuals: &Residuals, throttle: f64, weights: &RewardWeights) -> f64 {
    let dr2 = residuals.position * residuals.position;
    let dv2 = residuals.velocity * residuals.velocity;
    libm::expm1(-weights.position * dr2) + libm::expm1(-weights.velocity * dv2) - weights.throttle * throttle
}

/// Action -> thrust command (docs/spec.md section 5): u = (a0 + 1) / 2, direction (a1, a2)
/// normalised, thrust off below [`MIN_DIRECTION_NORM`]. Components are clamped to [-1, 1]; a
/// non-finite action decodes to thrust off (a NaN never reaches the thrusters).
pub fn decode_action(action: &[f32; ACTION_LEN]) -> ThrustCommand {
    if !action.iter().all(|a| a.is_finite()) {
        return ThrustCommand::OFF;
    }
    let [a0, a1, a2] = action.map(|a| f64::from(a.clamp(-1.0, 1.0)));
    let norm = libm::hypot(a1, a2);
    if norm < MIN_DIRECTION_NORM {
        return ThrustCommand::OFF;
    }
    ThrustCommand {
        throttle: (a0 + 1.0) * 0.5,
        alpha_r: a1 / norm,
        alpha_theta: a2 / norm,
    }
}

/// The action that encodes a command: the inverse of [`decode_action`] on unit directions.
pub fn encode_action(command: &ThrustCommand) -> [f64; ACTION_LEN] {
    [2.0 * command.throttle - 1.0, command.alpha_r, command.alpha_theta]
}

/// Narrows features to the network's precision.
pub fn to_network_input<const N: usize>(features: &[f64; N]) -> [f32; N] {
    features.map(|x| x as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f64::consts::PI;

    fn on_orbit(shape: &OrbitShape, nu: f64) -> SpacecraftState {
        SpacecraftState::from_cartesian(&shape.cartesian_at(nu), 0.8)
    }

    #[test]
    fn on_the_target_orbit_residuals_and_reward_vanish() {
        let target = OrbitShape {
            a: 1.2,
            e: 0.3,
            omega: 0.9,
        };
        for k in 0..16 {
            let nu = -PI + 0.4 * f64::from(k);
            let f = transfer_features(&on_orbit(&target, nu), &target, 3.0).unwrap();
            let res = transfer_residuals(&f);
            assert!(res.position < 1e-14 && res.velocity < 1e-14, "{res:?} at nu {nu}");
            // Round-off of 1e-16 in the residuals enters the reward squared.
            assert!(reward(&res, 0.0, &RewardWeights::default()).abs() < 1e-28);
        }
    }

    #[test]
    fn transfer_proxy_matches_hand_computed_cases() {
        // Spacecraft on a 1 AU circle at theta = 90 deg, target circle at 1.5 AU: proxy is the
        // circular state there: r_t = 1.5, v_r_t = 0, v_theta_t = 1/sqrt(1.5).
        let earth = OrbitShape {
            a: 1.0,
            e: 0.0,
            omega: 0.0,
        };
        let mars = OrbitShape {
            a: 1.5,
            e: 0.0,
            omega: 0.0,
        };
        let f = transfer_features(&on_orbit(&earth, PI / 2.0), &mars, 2.0).unwrap();
        let expect = [1.0, 0.0, 1.0, 0.0, 1.0, 0.8, 1.5, 0.0, 1.0 / libm::sqrt(1.5), 2.0];
        for (got, want) in f.iter().zip(expect) {
            assert!((got - want).abs() < 1e-15, "{f:?}");
        }
        // Eccentric target, omega = 30 deg, spacecraft at theta = 120 deg: nu_t = 90 deg, so
        // r_t = p, v_r_t = e / sqrt(p), v_theta_t = 1 / sqrt(p).
        let target = OrbitShape {
            a: 1.0,
            e: 0.5,
            omega: PI / 6.0,
        };
        let sc_orbit = OrbitShape {
            a: 1.3,
            e: 0.0,
            omega: 0.0,
        };
        let f = transfer_features(&on_orbit(&sc_orbit, 2.0 * PI / 3.0), &target, 0.0).unwrap();
        let p = 0.75;
        assert!((f[6] - p).abs() < 1e-14);
        assert!((f[7] - 0.5 / libm::sqrt(p)).abs() < 1e-14);
        assert!((f[8] - 1.0 / libm::sqrt(p)).abs() < 1e-14);
        let res = transfer_residuals(&f);
        assert!((res.position - (1.3 - 0.75)).abs() < 1e-14);
        let dv = libm::hypot(0.5 / libm::sqrt(p), 1.0 / libm::sqrt(p) - 1.0 / libm::sqrt(1.3));
        assert!((res.velocity - dv).abs() < 1e-14);
        let r = reward(&res, 0.5, &RewardWeights::default());
        let want = (libm::exp(-0.2 * 0.55 * 0.55) - 1.0) + (libm::exp(-0.2 * dv * dv) - 1.0) - 0.01;
        assert!((r - want).abs() < 1e-15);
    }

    #[test]
    fn rendezvous_layout_element_by_element() {
        let sc = SpacecraftState {
            r: [0.6, -0.8],
            v: [0.3, 0.9],
            m: 0.7,
        };
        let body = CartesianState {
            r: [0.0, 1.5],
            v: [-0.8, 0.1],
        };
        let f = rendezvous_features(&sc, &body, 4.5).unwrap();
        let expect = [
            1.0,
            0.6,
            -0.8, // r_i, cos, sin
            1.5,
            0.0,
            1.0, // r_t, cos, sin
            0.6,
            -0.8,
            0.3,
            0.9, // r_i, v_i
            0.0,
            1.5,
            -0.8,
            0.1, // r_t, v_t
            -0.6,
            2.3,
            -1.1,
            -0.8, // dr, dv
            libm::hypot(0.6, 2.3),
            libm::hypot(1.1, 0.8),
            4.5,
            0.7,
        ];
        assert_eq!(f.len(), expect.len());
        for (i, (got, want)) in f.iter().zip(expect).enumerate() {
            assert!((got - want).abs() < 1e-15, "feature {i}: {got} vs {want}");
        }
        let res = rendezvous_residuals(&f);
        assert_eq!((res.position, res.velocity), (f[18], f[19]));
        // At the body with its velocity the residuals and the zero-throttle reward vanish.
        let at_body = SpacecraftState::from_cartesian(&body, 0.5);
        let f = rendezvous_features(&at_body, &body, 0.0).unwrap();
        assert_eq!(reward(&rendezvous_residuals(&f), 0.0, &RewardWeights::default()), 0.0);
    }

    #[test]
    fn action_decoding_follows_the_spec() {
        let c = decode_action(&[1.0, 0.0, 1.0]);
        assert_eq!((c.throttle, c.alpha_r, c.alpha_theta), (1.0, 0.0, 1.0));
        let c = decode_action(&[0.0, 3.0, -4.0]); // clamped to (1, -1) then normalised
        assert!((c.throttle - 0.5).abs() < 1e-15);
        assert!((c.alpha_r - libm::sqrt(0.5)).abs() < 1e-7 && (c.alpha_theta + libm::sqrt(0.5)).abs() < 1e-7);
        assert_eq!(decode_action(&[1.0, 1e-7, -1e-7]), ThrustCommand::OFF);
        assert_eq!(decode_action(&[f32::NAN, 0.5, 0.5]), ThrustCommand::OFF);
        assert_eq!(decode_action(&[0.5, f32::INFINITY, 0.5]), ThrustCommand::OFF);
        let c = decode_action(&[-0.2, 0.6, 0.8]);
        let back = encode_action(&c);
        assert!((back[0] + 0.2).abs() < 1e-7 && (back[1] - 0.6).abs() < 1e-7 && (back[2] - 0.8).abs() < 1e-7);
    }

    #[test]
    fn bad_inputs_give_typed_errors() {
        let ok = SpacecraftState {
            r: [1.0, 0.0],
            v: [0.0, 1.0],
            m: 1.0,
        };
        let target = OrbitShape {
            a: 1.5,
            e: 0.0,
            omega: 0.0,
        };
        let nan = SpacecraftState { m: f64::NAN, ..ok };
        assert_eq!(
            transfer_features(&nan, &target, 1.0),
            Err(FeatureError::State(StateError::NonFinite))
        );
        let at_sun = SpacecraftState { r: [0.0, 0.0], ..ok };
        assert_eq!(
            transfer_features(&at_sun, &target, 1.0),
            Err(FeatureError::State(StateError::ZeroRadius))
        );
        let empty = SpacecraftState { m: 0.0, ..ok };
        assert_eq!(
            transfer_features(&empty, &target, 1.0),
            Err(FeatureError::State(StateError::NonPositiveMass))
        );
        assert_eq!(transfer_features(&ok, &target, -1.0), Err(FeatureError::TimeToGo));
        assert_eq!(transfer_features(&ok, &target, f64::NAN), Err(FeatureError::TimeToGo));
        let open = OrbitShape { e: 1.2, ..target };
        assert_eq!(transfer_features(&ok, &open, 1.0), Err(FeatureError::Target));
        let body = CartesianState {
            r: [f64::INFINITY, 0.0],
            v: [0.0, 1.0],
        };
        assert_eq!(rendezvous_features(&ok, &body, 1.0), Err(FeatureError::Target));
    }
}
