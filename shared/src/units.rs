//! Canonical units (docs/spec.md section 1): length 1 AU, mu_sun = 1, mass m0.
//!
//! Everything inside the flight code and every network feature is canonical; SI only appears
//! at the edges (spacecraft parameters, reports).

/// Length unit: 1 AU in metres (IAU 2012 Resolution B2).
pub const AU_M: f64 = 149_597_870_700.0;
/// Sun's gravitational parameter, m^3/s^2 (IAU 2015 nominal / DE430).
pub const MU_SUN_M3_S2: f64 = 1.327_124_400_18e20;
/// Standard gravity for specific impulse, m/s^2.
pub const G0_M_S2: f64 = 9.806_65;
/// Time unit t* = sqrt(AU^3 / mu_sun), seconds. Checked against that formula in the tests.
pub const TIME_UNIT_S: f64 = 5_022_642.891_366_036;
/// Velocity unit v* = AU / t*, m/s.
pub const VELOCITY_UNIT_M_S: f64 = AU_M / TIME_UNIT_S;
/// Acceleration unit AU / t*^2, m/s^2.
pub const ACCELERATION_UNIT_M_S2: f64 = AU_M / (TIME_UNIT_S * TIME_UNIT_S);
/// Canonical gravitational parameter of the Sun.
pub const MU: f64 = 1.0;

/// One environment (guidance) step: 14 days in seconds.
pub const STEP_SECONDS: f64 = 14.0 * 86_400.0;
/// One environment step in canonical time units (about 0.24082939).
pub const STEP: f64 = STEP_SECONDS / TIME_UNIT_S;
/// A Julian year in canonical time units (about 6.2830666).
pub const YEAR: f64 = 365.25 * 86_400.0 / TIME_UNIT_S;

/// Seconds to canonical time.
pub fn seconds_to_canonical(seconds: f64) -> f64 {
    seconds / TIME_UNIT_S
}

/// Canonical time to days.
pub fn canonical_to_days(t: f64) -> f64 {
    t * TIME_UNIT_S / 86_400.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_unit_matches_definition() {
        let t = libm::sqrt(AU_M * AU_M * AU_M / MU_SUN_M3_S2);
        assert!((t - TIME_UNIT_S).abs() / t < 1e-15, "t* = {t}");
        // docs/spec.md section 1 figures, to the digits printed there.
        assert!((TIME_UNIT_S - 5_022_642.89).abs() < 0.01);
        assert!((VELOCITY_UNIT_M_S - 29_784.69).abs() < 0.01);
        assert!((STEP - 0.240_829_39).abs() < 1e-8);
        assert!((YEAR - 6.283_066_6).abs() < 1e-6);
    }

    #[test]
    fn a_circular_orbit_at_one_au_takes_a_year() {
        // Period 2 pi in canonical units must be one sidereal year (365.256 d) within the
        // Earth/Sun mass ratio (~3e-6) that the heliocentric mu ignores.
        let days = canonical_to_days(2.0 * core::f64::consts::PI);
        assert!((days - 365.256_363).abs() < 365.26 * 4e-6, "{days}");
    }
}
