//! Universal-variable Kepler coast propagator (mu = 1, canonical units).
//!
//! Valid for elliptic, parabolic and hyperbolic states (Bate, Mueller and White, "Fundamentals
//! of Astrodynamics", Chapter 4; Vallado, "Fundamentals of Astrodynamics and Applications",
//! Algorithm 8). The universal anomaly chi solves the universal Kepler equation
//!
//!   F(chi) = sigma0 chi^2 C(z) + (1 - alpha r0) chi^3 S(z) + r0 chi - dt = 0,  z = alpha chi^2,
//!
//! with sigma0 = r0 . v0, alpha = 2/r0 - v0^2 = 1/a and the Stumpff functions C, S. F is
//! increasing (F' = r >= 0), so the Laguerre-Conway iteration used here is safeguarded by the
//! bracket of the root that every evaluation narrows (bisection when a step leaves it). Elliptic
//! coasts are first reduced modulo the period, so multi-revolution dt keep their accuracy.

use shared::orbit::{dot3, norm3, CartesianState, SpatialState};

/// Why a coast failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeplerError {
    /// A component of the state, or the coast duration, is NaN or infinite.
    NonFinite,
    /// The state is at the attracting centre (r = 0).
    ZeroRadius,
    /// The universal-anomaly iteration did not converge within its bound, or the result is not
    /// finite (a radial orbit through the centre, a hyperbolic coast so long that cosh overflows).
    NoConvergence,
}

impl core::fmt::Display for KeplerError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::NonFinite => "state or duration is NaN or infinite",
            Self::ZeroRadius => "state is at the attracting centre (r = 0)",
            Self::NoConvergence => "universal Kepler equation did not converge",
        })
    }
}

impl core::error::Error for KeplerError {}

/// Most iterations of the universal Kepler equation solver: room for a one-sided doubling walk
/// and a full bisection of f64's range after it (a near-parabolic hyperbola swinging through
/// periapsis took 101 to 120).
const MAX_ITERATIONS: u32 = 200;
/// Laguerre-Conway order parameter (the usual n = 5).
const LAGUERRE_N: f64 = 5.0;
/// Convergence: last correction below this fraction of |chi|.
const CHI_TOLERANCE: f64 = 1e-13;

/// Stumpff functions C(z) = (1 - cos sqrt z)/z and S(z) = (sqrt z - sin sqrt z)/sqrt(z)^3,
/// continued to z <= 0 with cosh/sinh; Taylor series for |z| < 4 (no cancellation near 0).
pub fn stumpff(z: f64) -> (f64, f64) {
    if z.abs() < 4.0 {
        // C = sum (-z)^k / (2k+2)!, S = sum (-z)^k / (2k+3)!; 17 terms reach 1e-29 at |z| = 4.
        let (mut c, mut s) = (0.0, 0.0);
        let (mut tc, mut ts) = (0.5, 1.0 / 6.0);
        let mut k = 0.0;
        for _ in 0..17 {
            c += tc;
            s += ts;
            k += 1.0;
            tc *= -z / ((2.0 * k + 1.0) * (2.0 * k + 2.0));
            ts *= -z / ((2.0 * k + 2.0) * (2.0 * k + 3.0));
        }
        (c, s)
    } else if z > 0.0 {
        let x = libm::sqrt(z);
        let half = libm::sin(0.5 * x);
        (2.0 * half * half / z, (x - libm::sin(x)) / (z * x))
    } else {
        let x = libm::sqrt(-z);
        let half = libm::sinh(0.5 * x);
        (2.0 * half * half / -z, (libm::sinh(x) - x) / (-z * x))
    }
}

/// The universal anomaly of a coast: `chi` after `dt` (reduced by whole periods on an ellipse)
/// from a state at distance `r0` with r . v = `sigma0` and |v|^2 = `v2`; the Lagrange
/// coefficients follow from it ([`Lagrange`]). Shared by the planar [`coast`] and the spatial
/// [`coast3`]: the scalars do not depend on the dimension.
struct UniversalAnomaly {
    chi: f64,
    /// chi^2, z = alpha chi^2 and the Stumpff functions at z.
    chi2: f64,
    z: f64,
    c: f64,
    s: f64,
    /// The time coasted after whole periods are taken out.
    dt: f64,
}

/// Lagrange coefficients: (f, g) of the position or (fdot, gdot) of the velocity.
struct Lagrange {
    f: f64,
    g: f64,
}

impl UniversalAnomaly {
    fn solve(r0: f64, sigma0: f64, v2: f64, dt: f64) -> Result<Self, KeplerError> {
        let alpha = 2.0 / r0 - v2;
        let beta = 1.0 - alpha * r0;

        // Elliptic: whole periods change nothing; keep |dt| <= P/2.
        let mut dt = dt;
        if alpha > 0.0 {
            let period = 2.0 * core::f64::consts::PI / (alpha * libm::sqrt(alpha));
            if period.is_finite() && dt.abs() > 0.5 * period {
                dt -= libm::round(dt / period) * period;
            }
        }

        // Initial guess (Vallado, Algorithm 8).
        let mut chi = if alpha * r0 > 1e-6 {
            alpha * dt
        } else if alpha * r0 < -1e-6 {
            let a = 1.0 / alpha;
            let s = if dt >= 0.0 { 1.0 } else { -1.0 };
            let arg = -2.0 * alpha * dt / (sigma0 + s * libm::sqrt(-a) * beta);
            let guess = s * libm::sqrt(-a) * libm::log(arg);
            if guess.is_finite() && guess * dt > 0.0 {
                guess
            } else {
                dt / r0
            }
        } else {
            dt / r0
        };

        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        let mut converged = false;
        for _ in 0..MAX_ITERATIONS {
            let chi2 = chi * chi;
            let z = alpha * chi2;
            let (c, s) = stumpff(z);
            let f = sigma0 * chi2 * c + beta * chi2 * chi * s + r0 * chi - dt;
            let df = sigma0 * chi * (1.0 - z * s) + beta * chi2 * c + r0;
            let ddf = sigma0 * (1.0 - z * c) + beta * chi * (1.0 - z * s);
            if f == 0.0 {
                converged = true;
                break;
            }
            // F is increasing: the sign of F says on which side of the root chi lies. An
            // overflowed F (huge |chi|) has the sign of chi.
            let positive = if f.is_finite() { f > 0.0 } else { chi > 0.0 };
            if positive {
                hi = hi.min(chi);
            } else {
                lo = lo.max(chi);
            }
            let root = libm::sqrt(
                ((LAGUERRE_N - 1.0) * (LAGUERRE_N - 1.0) * df * df - LAGUERRE_N * (LAGUERRE_N - 1.0) * f * ddf).abs(),
            );
            let den = if df >= 0.0 { df + root } else { df - root };
            let mut next = chi - LAGUERRE_N * f / den;
            // A Laguerre step below chi's resolution is converged: near the root F's rounding
            // can make the present point a bracket end, and bisecting from there would walk away
            // from the root. (An overflowed denominator gives a zero step that says nothing.)
            if next == chi && den.is_finite() {
                converged = true;
                break;
            }
            if !(next.is_finite() && lo < next && next < hi) {
                next = match (lo.is_finite(), hi.is_finite()) {
                    (true, true) => lo + 0.5 * (hi - lo),
                    // Only one side known: walk away from it, doubling.
                    (true, false) => lo + 2.0 * lo.abs().max(1.0),
                    (false, true) => hi - 2.0 * hi.abs().max(1.0),
                    (false, false) => break,
                };
            }
            let step = next - chi;
            chi = next;
            if step.abs() <= CHI_TOLERANCE * chi.abs() || next == lo || next == hi {
                converged = true;
                break;
            }
        }
        if !converged || !chi.is_finite() {
            return Err(KeplerError::NoConvergence);
        }
        let chi2 = chi * chi;
        let z = alpha * chi2;
        let (c, s) = stumpff(z);
        Ok(Self { chi, chi2, z, c, s, dt })
    }

    /// f and g: the new position is f r0 + g v0.
    fn position_coefficients(&self, r0: f64) -> Lagrange {
        Lagrange {
            f: 1.0 - self.chi2 * self.c / r0,
            g: self.dt - self.chi2 * self.chi * self.s,
        }
    }

    /// fdot and gdot at the new distance `r`: the new velocity is fdot r0 + gdot v0.
    fn velocity_coefficients(&self, r0: f64, r: f64) -> Lagrange {
        Lagrange {
            f: self.chi * (self.z * self.s - 1.0) / (r * r0),
            g: 1.0 - self.chi2 * self.c / r,
        }
    }
}

/// Coasts `state` (mu = 1) for `dt` (negative: backwards) on the exact two-body solution.
pub fn coast(state: &CartesianState, dt: f64) -> Result<CartesianState, KeplerError> {
    let [x, y] = state.r;
    let [vx, vy] = state.v;
    if ![x, y, vx, vy, dt].iter().all(|c| c.is_finite()) {
        return Err(KeplerError::NonFinite);
    }
    let r0 = libm::hypot(x, y);
    if r0 <= 0.0 {
        return Err(KeplerError::ZeroRadius);
    }
    if dt == 0.0 {
        return Ok(*state);
    }
    let sigma0 = x * vx + y * vy;
    let v2 = vx * vx + vy * vy;
    let anomaly = UniversalAnomaly::solve(r0, sigma0, v2, dt)?;
    let Lagrange { f, g } = anomaly.position_coefficients(r0);
    let r_new = [f * x + g * vx, f * y + g * vy];
    let r = libm::hypot(r_new[0], r_new[1]);
    let Lagrange { f: fdot, g: gdot } = anomaly.velocity_coefficients(r0, r);
    let v_new = [fdot * x + gdot * vx, fdot * y + gdot * vy];
    if r.is_nan() || r <= 0.0 || ![r_new[0], r_new[1], v_new[0], v_new[1]].iter().all(|v| v.is_finite()) {
        return Err(KeplerError::NoConvergence);
    }
    Ok(CartesianState { r: r_new, v: v_new })
}

/// [`coast`] in three dimensions.
pub fn coast3(state: &SpatialState, dt: f64) -> Result<SpatialState, KeplerError> {
    if !(state.r.iter().chain(&state.v).all(|c| c.is_finite()) && dt.is_finite()) {
        return Err(KeplerError::NonFinite);
    }
    let r0 = norm3(&state.r);
    if r0 <= 0.0 {
        return Err(KeplerError::ZeroRadius);
    }
    if dt == 0.0 {
        return Ok(*state);
    }
    let anomaly = UniversalAnomaly::solve(r0, dot3(&state.r, &state.v), dot3(&state.v, &state.v), dt)?;
    let Lagrange { f, g } = anomaly.position_coefficients(r0);
    let ([x, y, z], [vx, vy, vz]) = (state.r, state.v);
    let r_new = [f * x + g * vx, f * y + g * vy, f * z + g * vz];
    let r = norm3(&r_new);
    let Lagrange { f: fdot, g: gdot } = anomaly.velocity_coefficients(r0, r);
    let v_new = [fdot * x + gdot * vx, fdot * y + gdot * vy, fdot * z + gdot * vz];
    if r.is_nan() || r <= 0.0 || !r_new.iter().chain(&v_new).all(|v| v.is_finite()) {
        return Err(KeplerError::NoConvergence);
    }
    Ok(SpatialState { r: r_new, v: v_new })
}
