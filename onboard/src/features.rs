//! Feature encoding, reward terms and action decoding (docs/spec.md sections 5 and 6): polar for
//! planar flights, relative to the local RTN frame and the target's plane in three dimensions.
//!
//! One implementation serves the ground environment and the flight code, so what the network
//! saw in training is exactly what it sees in flight.

use shared::orbit::{cross3, dot3, norm3, CartesianState, OrbitPlane, OrbitShape, PolarState, SpatialState};

use crate::dynamics::{SpacecraftState, StateError, ThrustCommand};
use crate::spatial::{RtnCommand, SpatialCraftState};

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
    /// The spacecraft's velocity lies along its radius: no orbit plane, no RTN frame.
    NoOrbitPlane,
}

impl core::fmt::Display for FeatureError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::State(e) => write!(f, "invalid spacecraft state: {e}"),
            Self::Target => {
                f.write_str("invalid target: orbit must be closed and finite, body state finite with r > 0")
            }
            Self::TimeToGo => f.write_str("time to go must be finite and >= 0"),
            Self::NoOrbitPlane => f.write_str("the velocity lies along the radius: no orbit plane"),
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

/// Network inputs of the transfer policy in three dimensions.
pub const TRANSFER3_FEATURES: usize = 15;
/// Network inputs of the rendezvous policy in three dimensions.
pub const RENDEZVOUS3_FEATURES: usize = 30;
/// Network outputs in three dimensions: throttle and the three RTN direction components.
pub const ACTION3_LEN: usize = 4;

fn check_spatial(state: &SpatialCraftState, time_to_go: f64) -> Result<[[f64; 3]; 3], FeatureError> {
    state.validate().map_err(FeatureError::State)?;
    if !(time_to_go.is_finite() && time_to_go >= 0.0) {
        return Err(FeatureError::TimeToGo);
    }
    state.orbit.rtn_frame().ok_or(FeatureError::NoOrbitPlane)
}

/// The point of a target orbit (`shape` in `plane`) a spacecraft at `r` is measured against in
/// three dimensions: the orbit's point at the angle of r's projection on the orbit plane, and
/// the orbit's perifocal basis (P, Q, W).
fn target_proxy(shape: &OrbitShape, plane: &OrbitPlane, r: &[f64; 3]) -> (PolarState, SpatialState, [[f64; 3]; 3]) {
    let (p_hat, q_hat) = plane.perifocal(shape.omega);
    let w_hat = cross3(&p_hat, &q_hat);
    // The true anomaly of the projection: its angle from periapsis in the target plane.
    let nu = libm::atan2(dot3(r, &q_hat), dot3(r, &p_hat));
    let proxy = shape.polar_at(nu);
    let (sn, cn) = (libm::sin(nu), libm::cos(nu));
    let radial = combine(cn, &p_hat, sn, &q_hat);
    let transverse = combine(-sn, &p_hat, cn, &q_hat);
    let point = SpatialState {
        r: radial.map(|x| proxy.r * x),
        v: combine(proxy.v_r, &radial, proxy.v_theta, &transverse),
    };
    (proxy, point, [p_hat, q_hat, w_hat])
}

/// a x + b y.
fn combine(a: f64, x: &[f64; 3], b: f64, y: &[f64; 3]) -> [f64; 3] {
    [a * x[0] + b * y[0], a * x[1] + b * y[1], a * x[2] + b * y[2]]
}

fn difference(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The 15 transfer features in three dimensions (docs/spec.md section 5.1):
/// `[r, v_r, v_t, m, r_hat.P, r_hat.Q, r_p, v_r_p, v_t_p, W.r_hat, W.t_hat, W.n_hat, |dr|, |dv|,
/// t_tg]`: the spacecraft's radius, radial and transverse speed (its own RTN frame) and mass;
/// its direction in the target's perifocal frame (P to periapsis, Q ahead, W the target plane's
/// normal); the target orbit's point at the angle of the spacecraft's projection on the target
/// plane (radius, radial and transverse speed); the target plane's normal in the spacecraft's
/// RTN frame; the distance and speed difference to that point; the time to go. In one plane
/// they are the planar features' quantities and residuals.
pub fn transfer3_features(
    state: &SpatialCraftState,
    target: &OrbitShape,
    plane: &OrbitPlane,
    time_to_go: f64,
) -> Result<[f64; TRANSFER3_FEATURES], FeatureError> {
    transfer3_features_and_point(state, target, plane, time_to_go).map(|(features, _)| features)
}

/// The components of the transfer's miss in three dimensions, checked as its features are:
/// the target orbit's point that [`transfer3_features`] measures `state` against, less the
/// state, position then velocity (their lengths are the residuals).
pub(crate) fn transfer3_miss(
    state: &SpatialCraftState,
    target: &OrbitShape,
    plane: &OrbitPlane,
) -> Result<[f64; 6], FeatureError> {
    let (_, point) = transfer3_features_and_point(state, target, plane, 0.0)?;
    let o = &state.orbit;
    let (dr, dv) = (difference(&point.r, &o.r), difference(&point.v, &o.v));
    Ok([dr[0], dr[1], dr[2], dv[0], dv[1], dv[2]])
}

/// [`transfer3_features`] and the target orbit's point they measure the state against.
fn transfer3_features_and_point(
    state: &SpatialCraftState,
    target: &OrbitShape,
    plane: &OrbitPlane,
    time_to_go: f64,
) -> Result<([f64; TRANSFER3_FEATURES], SpatialState), FeatureError> {
    let [r_hat, t_hat, n_hat] = check_spatial(state, time_to_go)?;
    target.validate().map_err(|_| FeatureError::Target)?;
    plane.validate().map_err(|_| FeatureError::Target)?;
    let o = &state.orbit;
    let (proxy, point, [p_hat, q_hat, w_hat]) = target_proxy(target, plane, &o.r);
    let features = finite([
        o.radius(),
        dot3(&o.v, &r_hat),
        dot3(&o.v, &t_hat),
        state.m,
        dot3(&r_hat, &p_hat),
        dot3(&r_hat, &q_hat),
        proxy.r,
        proxy.v_r,
        proxy.v_theta,
        dot3(&w_hat, &r_hat),
        dot3(&w_hat, &t_hat),
        dot3(&w_hat, &n_hat),
        norm3(&difference(&point.r, &o.r)),
        norm3(&difference(&point.v, &o.v)),
        time_to_go,
    ])?;
    Ok((features, point))
}

/// Features whose every component is finite: a finite state so large that a norm overflows
/// is refused rather than flown on infinities.
fn finite<const N: usize>(features: [f64; N]) -> Result<[f64; N], FeatureError> {
    if features.iter().all(|x| x.is_finite()) {
        Ok(features)
    } else {
        Err(FeatureError::State(StateError::NonFinite))
    }
}

/// Residuals of a transfer state in three dimensions, read off its features.
pub fn transfer3_residuals(f: &[f64; TRANSFER3_FEATURES]) -> Residuals {
    Residuals {
        position: f[12],
        velocity: f[13],
    }
}

/// The 30 rendezvous features in three dimensions (docs/spec.md section 6.1): the planar
/// layout with three components, `[r_i, r_hat_i (3), r_t, r_hat_t (3), r_i (3), v_i (3), r_t (3),
/// v_t (3), dr (3), dv (3), |dr|, |dv|, t_tg, m]` with dr = r_t - r_i, dv = v_t - v_i.
pub fn rendezvous3_features(
    state: &SpatialCraftState,
    target_body: &SpatialState,
    time_to_go: f64,
) -> Result<[f64; RENDEZVOUS3_FEATURES], FeatureError> {
    check_spatial(state, time_to_go)?;
    if !target_body.is_valid() {
        return Err(FeatureError::Target);
    }
    let (o, b) = (&state.orbit, target_body);
    let (ri, rt) = (o.radius(), b.radius());
    let (dr, dv) = (difference(&b.r, &o.r), difference(&b.v, &o.v));
    let (ui, ut) = (o.r.map(|x| x / ri), b.r.map(|x| x / rt));
    finite([
        ri,
        ui[0],
        ui[1],
        ui[2],
        rt,
        ut[0],
        ut[1],
        ut[2],
        o.r[0],
        o.r[1],
        o.r[2],
        o.v[0],
        o.v[1],
        o.v[2],
        b.r[0],
        b.r[1],
        b.r[2],
        b.v[0],
        b.v[1],
        b.v[2],
        dr[0],
        dr[1],
        dr[2],
        dv[0],
        dv[1],
        dv[2],
        norm3(&dr),
        norm3(&dv),
        time_to_go,
        state.m,
    ])
}

/// Residuals of a rendezvous state in three dimensions, read off its features.
pub fn rendezvous3_residuals(f: &[f64; RENDEZVOUS3_FEATURES]) -> Residuals {
    Residuals {
        position: f[26],
        velocity: f[27],
    }
}

/// Action -> RTN command in three dimensions: u = (a0 + 1) / 2, direction (a1, a2, a3) in the
/// RTN frame normalised, thrust off below [`MIN_DIRECTION_NORM`]; components clamped to
/// [-1, 1], a non-finite action decodes to thrust off.
pub fn decode_action3(action: &[f32; ACTION3_LEN]) -> RtnCommand {
    if !action.iter().all(|a| a.is_finite()) {
        return RtnCommand::OFF;
    }
    let [a0, a1, a2, a3] = action.map(|a| f64::from(a.clamp(-1.0, 1.0)));
    let norm = norm3(&[a1, a2, a3]);
    if norm < MIN_DIRECTION_NORM {
        return RtnCommand::OFF;
    }
    RtnCommand {
        throttle: (a0 + 1.0) * 0.5,
        radial: a1 / norm,
        transverse: a2 / norm,
        normal: a3 / norm,
    }
}

/// The action that encodes an RTN command: the inverse of [`decode_action3`] on unit directions.
pub fn encode_action3(command: &RtnCommand) -> [f64; ACTION3_LEN] {
    [
        2.0 * command.throttle - 1.0,
        command.radial,
        command.transverse,
        command.normal,
    ]
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

#[cfg(test)]
mod spatial_tests {
    use super::*;

    fn spatial(planar: &SpacecraftState) -> SpatialCraftState {
        SpatialCraftState {
            orbit: SpatialState::from_planar(&planar.cartesian()),
            m: planar.m,
        }
    }

    fn turned(state: &SpatialCraftState, phi: f64) -> SpatialCraftState {
        let (s, c) = (libm::sin(phi), libm::cos(phi));
        let z = |p: [f64; 3]| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
        SpatialCraftState {
            orbit: SpatialState {
                r: z(state.orbit.r),
                v: z(state.orbit.v),
            },
            m: state.m,
        }
    }

    const TARGET: OrbitShape = OrbitShape {
        a: 1.4,
        e: 0.3,
        omega: 0.8,
    };

    #[test]
    fn in_one_plane_the_transfer_features_are_the_planar_ones() {
        let own = OrbitShape {
            a: 1.1,
            e: 0.2,
            omega: -0.4,
        };
        for k in 0..12 {
            let planar = SpacecraftState::from_cartesian(&own.cartesian_at(0.5 * f64::from(k)), 0.9);
            let f = transfer_features(&planar, &TARGET, 2.5).unwrap();
            let g = transfer3_features(&spatial(&planar), &TARGET, &OrbitPlane::REFERENCE, 2.5).unwrap();
            let theta = libm::atan2(f[2], f[1]);
            let res = transfer_residuals(&f);
            let expect = [
                f[0],
                f[3],
                f[4],
                f[5],
                libm::cos(theta - TARGET.omega),
                libm::sin(theta - TARGET.omega),
                f[6],
                f[7],
                f[8],
                0.0,
                0.0,
                1.0,
                res.position,
                res.velocity,
                f[9],
            ];
            for (i, (a, b)) in g.iter().zip(expect).enumerate() {
                assert!((a - b).abs() < 1e-13, "#{k} feature {i}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn on_an_inclined_target_orbit_the_residuals_vanish_and_turning_about_z_changes_nothing() {
        let plane = OrbitPlane {
            inclination: 0.3,
            raan: 1.1,
        };
        for k in 0..12 {
            let nu = 0.5 * f64::from(k) - 3.0;
            let on = SpatialCraftState {
                orbit: plane.embed(&TARGET.cartesian_at(nu)),
                m: 0.7,
            };
            let f = transfer3_features(&on, &TARGET, &plane, 1.0).unwrap();
            let res = transfer3_residuals(&f);
            assert!(res.position < 1e-14 && res.velocity < 1e-14, "{res:?}");
            // The target plane is the spacecraft's: its normal is n_hat.
            assert!((f[11] - 1.0).abs() < 1e-14 && f[9].abs() < 1e-14 && f[10].abs() < 1e-14);
            assert!((f[4] - libm::cos(nu)).abs() < 1e-13 && (f[5] - libm::sin(nu)).abs() < 1e-13);
            // Off the orbit, turned about z with the target's node: the same features.
            let off = SpatialCraftState {
                orbit: OrbitPlane::REFERENCE.embed(
                    &OrbitShape {
                        a: 1.0,
                        e: 0.1,
                        omega: 0.2,
                    }
                    .cartesian_at(nu),
                ),
                m: 0.7,
            };
            let a = transfer3_features(&off, &TARGET, &plane, 1.0).unwrap();
            let phi = 0.9;
            let moved = OrbitPlane {
                raan: plane.raan + phi,
                ..plane
            };
            let b = transfer3_features(&turned(&off, phi), &TARGET, &moved, 1.0).unwrap();
            assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-13), "{a:?}\n{b:?}");
            // Out of the target plane by its inclination: the normal seen tilted by 0.3 rad.
            assert!((a[11] - libm::cos(0.3)).abs() < 1e-13, "{}", a[11]);
            assert!(a[12] > 0.0 && a[13] > 0.0);
        }
    }

    #[test]
    fn in_one_plane_the_rendezvous_features_are_the_planar_ones_with_zero_z() {
        let own = OrbitShape {
            a: 1.0,
            e: 0.05,
            omega: 0.3,
        };
        let planar = SpacecraftState::from_cartesian(&own.cartesian_at(1.3), 0.85);
        let body = TARGET.cartesian_at(2.2);
        let f = rendezvous_features(&planar, &body, 4.0).unwrap();
        let g = rendezvous3_features(&spatial(&planar), &SpatialState::from_planar(&body), 4.0).unwrap();
        // Where each planar feature sits among the spatial ones (z components and the like 0).
        let at = [
            0, 1, 2, 4, 5, 6, 8, 9, 11, 12, 14, 15, 17, 18, 20, 21, 23, 24, 26, 27, 28, 29,
        ];
        for (i, &j) in at.iter().enumerate() {
            assert!((f[i] - g[j]).abs() < 1e-15, "feature {i} -> {j}: {} vs {}", f[i], g[j]);
        }
        for j in [3, 7, 10, 13, 16, 19, 22, 25] {
            assert_eq!(g[j], 0.0, "{j}");
        }
        let (a, b) = (rendezvous_residuals(&f), rendezvous3_residuals(&g));
        assert!((a.position - b.position).abs() < 1e-15 && (a.velocity - b.velocity).abs() < 1e-15);
    }

    #[test]
    fn three_dimensional_actions_decode_to_unit_rtn_directions_and_bad_inputs_are_refused() {
        let command = decode_action3(&[0.2, 0.3, -0.4, 0.5]);
        let n = libm::sqrt(0.09 + 0.16 + 0.25);
        assert!((command.throttle - 0.6).abs() < 1e-7);
        assert!((command.radial - 0.3 / n).abs() < 1e-7 && (command.normal - 0.5 / n).abs() < 1e-7);
        assert!(command.validate().is_ok());
        // Encoded and narrowed to f32 again: the same command to f32's precision.
        let again = decode_action3(&encode_action3(&command).map(|x| x as f32));
        let parts = |c: &RtnCommand| [c.throttle, c.radial, c.transverse, c.normal];
        assert!(parts(&again)
            .iter()
            .zip(parts(&command))
            .all(|(a, b)| (a - b).abs() < 1e-7));
        assert_eq!(decode_action3(&[1.0, f32::NAN, 0.0, 0.0]), RtnCommand::OFF);
        assert_eq!(decode_action3(&[1.0, 0.0, 1e-9, 0.0]), RtnCommand::OFF);
        // Out of range: clamped, still a unit direction.
        let clamped = decode_action3(&[3.0, 0.0, 0.0, -7.0]);
        assert_eq!((clamped.throttle, clamped.normal), (1.0, -1.0));
        let flat = SpacecraftState::from_cartesian(&TARGET.cartesian_at(0.0), 1.0);
        let good = spatial(&flat);
        let radial = SpatialCraftState {
            orbit: SpatialState {
                r: [1.0, 0.0, 0.0],
                v: [0.5, 0.0, 0.0],
            },
            m: 1.0,
        };
        let plane = OrbitPlane::REFERENCE;
        assert_eq!(
            transfer3_features(&radial, &TARGET, &plane, 1.0),
            Err(FeatureError::NoOrbitPlane)
        );
        assert_eq!(
            transfer3_features(&good, &TARGET, &plane, -1.0),
            Err(FeatureError::TimeToGo)
        );
        let tilted = OrbitPlane {
            inclination: 4.0,
            raan: 0.0,
        };
        assert_eq!(
            transfer3_features(&good, &TARGET, &tilted, 1.0),
            Err(FeatureError::Target)
        );
        // Finite but so far out that the norms overflow: refused, not flown on infinities.
        let far = SpatialCraftState {
            orbit: SpatialState {
                r: [1e160, 0.0, 0.0],
                v: [0.0, 1e-150, 0.0],
            },
            m: 1.0,
        };
        assert_eq!(
            transfer3_features(&far, &TARGET, &plane, 1.0),
            Err(FeatureError::State(StateError::NonFinite))
        );
        assert_eq!(
            rendezvous3_features(&far, &good.orbit, 1.0),
            Err(FeatureError::State(StateError::NonFinite))
        );
        let mut nan = good;
        nan.orbit.v[2] = f64::NAN;
        assert!(matches!(
            rendezvous3_features(&nan, &good.orbit, 1.0),
            Err(FeatureError::State(_))
        ));
        assert_eq!(
            rendezvous3_features(
                &good,
                &SpatialState {
                    r: [0.0; 3],
                    v: [0.0; 3]
                },
                1.0
            ),
            Err(FeatureError::Target)
        );
    }
}
