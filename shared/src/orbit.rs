//! Keplerian orbits in canonical units (docs/spec.md section 2): planar elements, polar and
//! Cartesian states, and the plane that puts a planar orbit into three dimensions. Angles are
//! radians here; the CLI takes degrees at the edge.

use serde::{Deserialize, Serialize};

/// Why orbit elements are unusable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OrbitError {
    /// Semi-major axis not finite or not positive.
    SemiMajorAxis,
    /// Eccentricity outside [0, 1) (only closed orbits are in scope) or not finite.
    Eccentricity,
    /// An angle is not finite.
    Angle,
}

impl core::fmt::Display for OrbitError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::SemiMajorAxis => "semi-major axis must be finite and > 0 AU",
            Self::Eccentricity => "eccentricity must be finite and in [0, 1)",
            Self::Angle => "angles must be finite",
        })
    }
}

impl core::error::Error for OrbitError {}

/// Shape and orientation of a closed planar orbit: semi-major axis a (AU), eccentricity e,
/// argument of periapsis omega (rad). A target orbit of a transfer is exactly this.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OrbitShape {
    /// Semi-major axis (AU), > 0.
    pub a: f64,
    /// Eccentricity, in [0, 1).
    pub e: f64,
    /// Argument of periapsis (rad): the polar angle of periapsis.
    pub omega: f64,
}

/// A point on an orbit: its shape plus the true anomaly nu (rad).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OrbitElements {
    /// The orbit.
    pub shape: OrbitShape,
    /// True anomaly (rad): the angle from periapsis, theta = omega + nu.
    pub nu: f64,
}

/// Polar state (docs/spec.md section 2): radius, polar angle, radial and transverse velocity.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PolarState {
    /// Distance from the Sun (AU).
    pub r: f64,
    /// Polar angle from the x axis (rad).
    pub theta: f64,
    /// Radial velocity (AU / t*), positive away from the Sun.
    pub v_r: f64,
    /// Transverse (along-track) velocity (AU / t*), positive prograde.
    pub v_theta: f64,
}

/// Cartesian position and velocity in the orbit plane.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CartesianState {
    /// Position (AU).
    pub r: [f64; 2],
    /// Velocity (AU / t*).
    pub v: [f64; 2],
}

/// Position and velocity in three dimensions, in an inertial frame of the central body
/// (canonical units; docs/spec.md section 3.6).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SpatialState {
    /// Position.
    pub r: [f64; 3],
    /// Velocity.
    pub v: [f64; 3],
}

/// a . b in three dimensions.
pub fn dot3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// |a| in three dimensions.
pub fn norm3(a: &[f64; 3]) -> f64 {
    libm::sqrt(dot3(a, a))
}

/// a x b.
pub fn cross3(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

impl SpatialState {
    /// The planar state embedded in three dimensions (z = 0).
    pub fn from_planar(c: &CartesianState) -> Self {
        Self {
            r: [c.r[0], c.r[1], 0.0],
            v: [c.v[0], c.v[1], 0.0],
        }
    }

    /// Whether every component is finite and the position is off the centre.
    pub fn is_valid(&self) -> bool {
        self.r.iter().chain(&self.v).all(|x| x.is_finite()) && norm3(&self.r) > 0.0
    }

    /// Distance from the centre.
    pub fn radius(&self) -> f64 {
        norm3(&self.r)
    }

    /// Specific orbital energy |v|^2 / 2 - 1 / |r| (mu = 1).
    pub fn energy(&self) -> f64 {
        0.5 * dot3(&self.v, &self.v) - 1.0 / norm3(&self.r)
    }

    /// Specific angular momentum r x v.
    pub fn angular_momentum(&self) -> [f64; 3] {
        cross3(&self.r, &self.v)
    }

    /// The local RTN frame as rows: radial r_hat, transverse t_hat = n_hat x r_hat, normal n_hat
    /// along the angular momentum; `None` at the centre or with the velocity along the radius
    /// (no orbit plane).
    pub fn rtn_frame(&self) -> Option<[[f64; 3]; 3]> {
        let rn = norm3(&self.r);
        let h = cross3(&self.r, &self.v);
        let hn = norm3(&h);
        if !(rn > 0.0 && hn > 0.0 && hn.is_finite()) {
            return None;
        }
        let r_hat = self.r.map(|x| x / rn);
        let n_hat = h.map(|x| x / hn);
        Some([r_hat, cross3(&n_hat, &r_hat), n_hat])
    }
}

/// The plane of an orbit in three dimensions: its inclination to the reference (xy) plane and
/// the right ascension of its ascending node (rad). A planar orbit's angles are measured in its
/// own plane from the node line; the plane turns them into the inertial frame by R3(-raan)
/// R1(-inclination), the classical elements' rotation (docs/spec.md section 4, inclined families).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OrbitPlane {
    /// Inclination to the xy-plane (rad), in [0, pi].
    pub inclination: f64,
    /// Right ascension of the ascending node (rad).
    pub raan: f64,
}

impl OrbitPlane {
    /// The xy-plane itself: planar orbits.
    pub const REFERENCE: Self = Self {
        inclination: 0.0,
        raan: 0.0,
    };

    /// Whether this is exactly the reference plane (both angles zero).
    pub fn is_reference(&self) -> bool {
        self.inclination == 0.0 && self.raan == 0.0
    }

    /// Checks that both angles are finite and the inclination in [0, pi].
    pub fn validate(&self) -> Result<(), OrbitError> {
        let inclined = self.inclination.is_finite() && (0.0..=core::f64::consts::PI).contains(&self.inclination);
        if !(inclined && self.raan.is_finite()) {
            return Err(OrbitError::Angle);
        }
        Ok(())
    }

    /// A vector of the orbit plane (x along the node line) in the inertial frame. The
    /// reference plane gives (x, y, 0) to the bit.
    pub fn to_inertial(&self, p: [f64; 2]) -> [f64; 3] {
        let (si, ci) = (libm::sin(self.inclination), libm::cos(self.inclination));
        let (sn, cn) = (libm::sin(self.raan), libm::cos(self.raan));
        let (x, y, z) = (p[0], p[1] * ci, p[1] * si);
        [x * cn - y * sn, x * sn + y * cn, z]
    }

    /// The perifocal unit vectors of an orbit of this plane whose argument of periapsis is
    /// `omega`: P towards periapsis, Q 90 degrees ahead.
    pub fn perifocal(&self, omega: f64) -> ([f64; 3], [f64; 3]) {
        let (so, co) = (libm::sin(omega), libm::cos(omega));
        (self.to_inertial([co, so]), self.to_inertial([-so, co]))
    }

    /// A state of the orbit plane in the inertial frame.
    pub fn embed(&self, c: &CartesianState) -> SpatialState {
        SpatialState {
            r: self.to_inertial(c.r),
            v: self.to_inertial(c.v),
        }
    }

    /// An inertial vector in the plane's coordinates (x along the node line), its component
    /// along the plane's normal dropped: the inverse of [`Self::to_inertial`] on the plane.
    pub fn to_plane(&self, p: [f64; 3]) -> [f64; 2] {
        let (si, ci) = (libm::sin(self.inclination), libm::cos(self.inclination));
        let (sn, cn) = (libm::sin(self.raan), libm::cos(self.raan));
        let (x, y) = (p[0] * cn + p[1] * sn, -p[0] * sn + p[1] * cn);
        [x, y * ci + p[2] * si]
    }

    /// The plane of the orbit through `state` (its angular momentum's direction); the node on
    /// the x-axis when the orbit lies in the reference plane. `None` without an orbit plane.
    pub fn of_state(state: &SpatialState) -> Option<Self> {
        Self::of_normal(&state.angular_momentum())
    }

    /// The plane whose normal (of any length) is `n`: the inclination by atan2, exact near the
    /// reference plane where acos of the normal's z loses half the digits; the node on the
    /// x-axis when the plane is the reference plane. `None` for a zero or non-finite normal.
    pub fn of_normal(n: &[f64; 3]) -> Option<Self> {
        let (across, length) = (libm::hypot(n[0], n[1]), norm3(n));
        if !(length > 0.0 && length.is_finite()) {
            return None;
        }
        let inclination = libm::atan2(across, n[2]);
        let raan = if across > 1e-15 * length {
            libm::atan2(n[0], -n[1])
        } else {
            0.0
        };
        Some(Self { inclination, raan })
    }
}

impl SpatialState {
    /// The orbit through the state: its plane, and its elements measured in that plane from the
    /// node line. `None` without an orbit plane or on an unbound orbit.
    pub fn elements(&self) -> Option<(OrbitElements, OrbitPlane)> {
        let plane = OrbitPlane::of_state(self)?;
        let flat = CartesianState {
            r: plane.to_plane(self.r),
            v: plane.to_plane(self.v),
        };
        Some((flat.elements()?, plane))
    }
}

impl OrbitShape {
    /// Checks that the shape describes a closed orbit.
    pub fn validate(&self) -> Result<(), OrbitError> {
        if !(self.a.is_finite() && self.a > 0.0) {
            return Err(OrbitError::SemiMajorAxis);
        }
        if !(self.e.is_finite() && (0.0..1.0).contains(&self.e)) {
            return Err(OrbitError::Eccentricity);
        }
        if !self.omega.is_finite() {
            return Err(OrbitError::Angle);
        }
        Ok(())
    }

    /// Semi-latus rectum p = a (1 - e^2).
    pub fn semi_latus_rectum(&self) -> f64 {
        self.a * (1.0 - self.e * self.e)
    }

    /// Orbital period 2 pi a^(3/2) in t*.
    pub fn period(&self) -> f64 {
        2.0 * core::f64::consts::PI * self.a * libm::sqrt(self.a)
    }

    /// Polar state at true anomaly nu.
    pub fn polar_at(&self, nu: f64) -> PolarState {
        let p = self.semi_latus_rectum();
        let (s, c) = (libm::sin(nu), libm::cos(nu));
        let k = libm::sqrt(1.0 / p);
        PolarState {
            r: p / (1.0 + self.e * c),
            theta: self.omega + nu,
            v_r: k * self.e * s,
            v_theta: k * (1.0 + self.e * c),
        }
    }

    /// Derivative of the polar radius and velocities with respect to nu at nu (theta' = 1).
    /// Used by the transversality condition of free-anomaly transfers.
    pub fn polar_derivative_at(&self, nu: f64) -> PolarState {
        let p = self.semi_latus_rectum();
        let (s, c) = (libm::sin(nu), libm::cos(nu));
        let k = libm::sqrt(1.0 / p);
        let den = 1.0 + self.e * c;
        PolarState {
            r: p * self.e * s / (den * den),
            theta: 1.0,
            v_r: k * self.e * c,
            v_theta: -k * self.e * s,
        }
    }

    /// Cartesian state at true anomaly nu.
    pub fn cartesian_at(&self, nu: f64) -> CartesianState {
        self.polar_at(nu).to_cartesian()
    }
}

impl OrbitElements {
    /// Checks the shape and the anomaly.
    pub fn validate(&self) -> Result<(), OrbitError> {
        self.shape.validate()?;
        if !self.nu.is_finite() {
            return Err(OrbitError::Angle);
        }
        Ok(())
    }

    /// The polar state at this point of the orbit (docs/spec.md section 2).
    pub fn polar(&self) -> PolarState {
        self.shape.polar_at(self.nu)
    }

    /// The Cartesian state at this point of the orbit.
    pub fn cartesian(&self) -> CartesianState {
        self.shape.cartesian_at(self.nu)
    }
}

impl PolarState {
    /// Cartesian state from the polar one (docs/spec.md section 2 relations inverted).
    pub fn to_cartesian(&self) -> CartesianState {
        let (s, c) = (libm::sin(self.theta), libm::cos(self.theta));
        CartesianState {
            r: [self.r * c, self.r * s],
            v: [self.v_r * c - self.v_theta * s, self.v_r * s + self.v_theta * c],
        }
    }
}

impl CartesianState {
    /// Polar state (docs/spec.md section 2). The angle is atan2(y, x) in (-pi, pi].
    pub fn to_polar(&self) -> PolarState {
        let [x, y] = self.r;
        let [vx, vy] = self.v;
        let r = libm::hypot(x, y);
        PolarState {
            r,
            theta: libm::atan2(y, x),
            v_r: (x * vx + y * vy) / r,
            v_theta: (x * vy - y * vx) / r,
        }
    }

    /// Specific orbital energy v^2/2 - 1/r (mu = 1).
    pub fn energy(&self) -> f64 {
        let [vx, vy] = self.v;
        0.5 * (vx * vx + vy * vy) - 1.0 / libm::hypot(self.r[0], self.r[1])
    }

    /// Specific angular momentum (z component).
    pub fn angular_momentum(&self) -> f64 {
        self.r[0] * self.v[1] - self.r[1] * self.v[0]
    }

    /// Osculating elements of a bound orbit, or `None` for a hyperbolic/parabolic or degenerate state.
    pub fn elements(&self) -> Option<OrbitElements> {
        let energy = self.energy();
        let h = self.angular_momentum();
        let r = libm::hypot(self.r[0], self.r[1]);
        if energy.is_nan() || energy >= 0.0 || !r.is_finite() || r <= 0.0 {
            return None;
        }
        let a = -0.5 / energy;
        // Eccentricity vector e = (v x h) - r_hat, planar.
        let ex = self.v[1] * h - self.r[0] / r;
        let ey = -self.v[0] * h - self.r[1] / r;
        let e = libm::hypot(ex, ey);
        let omega = if e > 0.0 { libm::atan2(ey, ex) } else { 0.0 };
        let theta = libm::atan2(self.r[1], self.r[0]);
        let nu = theta - omega;
        Some(OrbitElements {
            shape: OrbitShape { a, e, omega },
            nu,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polar_cartesian_round_trip_and_vis_viva() {
        let shape = OrbitShape {
            a: 1.3,
            e: 0.4,
            omega: 0.7,
        };
        for k in 0..12 {
            let nu = -3.0 + 0.5 * k as f64;
            let cart = shape.cartesian_at(nu);
            // vis-viva: v^2 = 2/r - 1/a
            let v2 = cart.v[0] * cart.v[0] + cart.v[1] * cart.v[1];
            let r = libm::hypot(cart.r[0], cart.r[1]);
            assert!((v2 - (2.0 / r - 1.0 / shape.a)).abs() < 1e-14);
            let back = cart.elements().unwrap();
            assert!((back.shape.a - shape.a).abs() < 1e-12);
            assert!((back.shape.e - shape.e).abs() < 1e-12);
            let d = libm::remainder(back.shape.omega - shape.omega, 2.0 * core::f64::consts::PI);
            assert!(d.abs() < 1e-12);
            let polar = cart.to_polar();
            let direct = shape.polar_at(nu);
            assert!((polar.r - direct.r).abs() < 1e-14);
            assert!((polar.v_r - direct.v_r).abs() < 1e-14);
            assert!((polar.v_theta - direct.v_theta).abs() < 1e-14);
        }
    }

    #[test]
    fn derivative_with_respect_to_anomaly_matches_finite_differences() {
        let shape = OrbitShape {
            a: 0.8,
            e: 0.6,
            omega: -1.0,
        };
        let h = 1e-6;
        for k in 0..8 {
            let nu = 0.8 * k as f64;
            let d = shape.polar_derivative_at(nu);
            let (p, m) = (shape.polar_at(nu + h), shape.polar_at(nu - h));
            assert!((d.r - (p.r - m.r) / (2.0 * h)).abs() < 1e-8);
            assert!((d.v_r - (p.v_r - m.v_r) / (2.0 * h)).abs() < 1e-8);
            assert!((d.v_theta - (p.v_theta - m.v_theta) / (2.0 * h)).abs() < 1e-8);
        }
    }

    #[test]
    fn a_plane_turns_the_orbit_to_its_classical_normal_and_node() {
        let shape = OrbitShape {
            a: 1.2,
            e: 0.3,
            omega: 0.9,
        };
        let plane = OrbitPlane {
            inclination: 0.4,
            raan: 2.1,
        };
        // The normal of an orbit of inclination i and node raan: (sin i sin raan, -sin i cos raan, cos i).
        let (si, ci) = (libm::sin(0.4), libm::cos(0.4));
        let normal = [si * libm::sin(2.1), -si * libm::cos(2.1), ci];
        for k in 0..16 {
            let nu = 0.4 * k as f64;
            let flat = shape.cartesian_at(nu);
            let state = plane.embed(&flat);
            let h = state.angular_momentum();
            let hn = norm3(&h);
            assert!((hn - (flat.r[0] * flat.v[1] - flat.r[1] * flat.v[0])).abs() < 1e-14);
            assert!(h.iter().zip(&normal).all(|(a, b)| (a / hn - b).abs() < 1e-14));
            assert!((state.energy() - flat.energy()).abs() < 1e-14);
            // The argument of latitude omega + nu is the angle from the ascending node.
            let u = shape.omega + nu;
            assert!((state.r[2] - norm3(&state.r) * si * libm::sin(u)).abs() < 1e-14);
        }
        // The ascending node: where the orbit crosses z = 0 upward, at (cos raan, sin raan, 0).
        let node = plane.to_inertial([1.0, 0.0]);
        assert!((node[0] - libm::cos(2.1)).abs() < 1e-15 && (node[1] - libm::sin(2.1)).abs() < 1e-15);
        assert_eq!(node[2], 0.0);
        // The reference plane keeps the planar state to the bit.
        let flat = shape.cartesian_at(1.7);
        assert_eq!(OrbitPlane::REFERENCE.embed(&flat), SpatialState::from_planar(&flat));
        assert_eq!(plane.validate(), Ok(()));
        assert_eq!(
            OrbitPlane {
                inclination: -0.1,
                ..plane
            }
            .validate(),
            Err(OrbitError::Angle)
        );
        assert_eq!(
            OrbitPlane {
                inclination: 3.2,
                ..plane
            }
            .validate(),
            Err(OrbitError::Angle)
        );
        assert_eq!(
            OrbitPlane {
                raan: f64::NAN,
                ..plane
            }
            .validate(),
            Err(OrbitError::Angle)
        );
    }

    #[test]
    fn the_elements_of_a_state_put_it_back_where_it_was() {
        let shapes = [(1.3, 0.2, 0.7), (0.8, 0.6, -2.0), (1.0, 1e-4, 0.0)];
        let planes = [(0.4, 2.1), (0.0, 0.0), (1.4, -1.0), (3.0, 0.5), (1e-9, 0.3)];
        for (a, e, omega) in shapes {
            for (inclination, raan) in planes {
                let shape = OrbitShape { a, e, omega };
                let plane = OrbitPlane { inclination, raan };
                for nu in [0.3, 2.0, -2.5] {
                    let state = plane.embed(&shape.cartesian_at(nu));
                    let (el, found) = state.elements().unwrap();
                    let back = found.embed(&el.cartesian());
                    let gap = back.r.iter().chain(&back.v).zip(state.r.iter().chain(&state.v));
                    assert!(gap.map(|(x, y)| (x - y).abs()).fold(0.0, f64::max) < 1e-13);
                    assert!((el.shape.a - a).abs() < 1e-12 && (el.shape.e - e).abs() < 1e-12);
                    assert!((found.inclination - inclination).abs() < 1e-12);
                }
            }
        }
        let radial = SpatialState {
            r: [1.0, 0.0, 0.0],
            v: [0.3, 0.0, 0.0],
        };
        assert_eq!(radial.elements(), None);
    }

    #[test]
    fn refuses_open_or_non_finite_orbits() {
        let ok = OrbitShape {
            a: 1.0,
            e: 0.1,
            omega: 0.0,
        };
        assert_eq!(ok.validate(), Ok(()));
        assert_eq!(OrbitShape { a: 0.0, ..ok }.validate(), Err(OrbitError::SemiMajorAxis));
        assert_eq!(OrbitShape { e: 1.0, ..ok }.validate(), Err(OrbitError::Eccentricity));
        assert_eq!(OrbitShape { e: -0.1, ..ok }.validate(), Err(OrbitError::Eccentricity));
        assert_eq!(OrbitShape { omega: f64::NAN, ..ok }.validate(), Err(OrbitError::Angle));
        let el = OrbitElements {
            shape: ok,
            nu: f64::INFINITY,
        };
        assert_eq!(el.validate(), Err(OrbitError::Angle));
    }
}
