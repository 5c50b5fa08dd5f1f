//! Dispersions of the SIL truth plant: what flight software meets that the MDP does not.
//!
//! Each kind draws from its own ChaCha8 stream of the flight's seed, so switching one kind on
//! or off leaves the draws of the others unchanged, and a kind whose sigma is zero draws
//! nothing and changes nothing: with [`Dispersions::NONE`] the flight is bit-identical to the
//! undispersed MDP episode.

use onboard::dynamics::{SpacecraftState, ThrustCommand};
use onboard::spatial::{RtnCommand, SpatialCraftState};
use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};
use shared::mission::{Units, DAY_S};
use shared::orbit::{cross3, norm3};
use shared::units::{AU_M, VELOCITY_UNIT_M_S};

/// One Julian year, days.
const YEAR_DAYS: f64 = 365.25;

/// 1-sigma sizes of the dispersions, in the family's canonical units (its length and velocity
/// units: AU and v* around the Sun) unless said otherwise; the missed-thrust events in days and
/// per year, whatever the units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Dispersions {
    /// Navigation position error per axis (length units), drawn afresh each guidance cycle.
    pub navigation_position: f64,
    /// Navigation velocity error per axis (velocity units; around the Sun v*, about 29.8 km/s),
    /// each cycle.
    pub navigation_velocity: f64,
    /// Navigation mass error (fraction of the initial mass), each cycle.
    pub navigation_mass: f64,
    /// Thrust magnitude error (fraction), drawn once per flight: a thruster that is off
    /// nominal stays off nominal. Mass flow follows the actual thrust.
    pub thrust_magnitude: f64,
    /// Pointing error (rad) of the applied thrust direction, each cycle: in the plane the
    /// in-plane angle's sigma; in three dimensions the sigma of each of two perpendicular
    /// components (a cone about the command: off-axis angle RMS sigma sqrt 2).
    pub pointing: f64,
    /// Mean number of missed-thrust events per year of flight (Poisson arrivals, not tied to
    /// the guidance cycle: an event can start and end inside a cycle).
    pub missed_thrust_per_year: f64,
    /// Length of each missed-thrust event (days): thrust is off, whatever is commanded.
    pub missed_thrust_days: f64,
}

impl Dispersions {
    /// No dispersion: the plant flies exactly the MDP.
    pub const NONE: Self = Self {
        navigation_position: 0.0,
        navigation_velocity: 0.0,
        navigation_mass: 0.0,
        thrust_magnitude: 0.0,
        pointing: 0.0,
        missed_thrust_per_year: 0.0,
        missed_thrust_days: 0.0,
    };

    /// A moderate deep-space case around the Sun: 1,000 km and 0.1 m/s navigation, 2 % thrust,
    /// 1 deg pointing, two 7-day missed-thrust events per year ([`Self::typical_in`] the
    /// heliocentric units, bit for bit).
    pub const TYPICAL: Self = Self {
        navigation_position: 1.0e6 / AU_M,
        navigation_velocity: 0.1 / VELOCITY_UNIT_M_S,
        navigation_mass: 1e-3,
        thrust_magnitude: 0.02,
        pointing: 0.017_453_292_519_943_295,
        missed_thrust_per_year: 2.0,
        missed_thrust_days: 7.0,
    };

    /// The same physical sizes as [`Self::TYPICAL`] in another family's canonical units.
    pub fn typical_in(units: &Units) -> Self {
        Self {
            navigation_position: 1.0e6 / units.length_m,
            navigation_velocity: 0.1 / units.velocity_m_s(),
            ..Self::TYPICAL
        }
    }

    /// Why these dispersions cannot be flown, if they cannot.
    pub fn validate(&self) -> Result<(), DispersionError> {
        let all = [
            self.navigation_position,
            self.navigation_velocity,
            self.navigation_mass,
            self.thrust_magnitude,
            self.pointing,
            self.missed_thrust_per_year,
            self.missed_thrust_days,
        ];
        if all.iter().all(|v| v.is_finite() && *v >= 0.0) {
            Ok(())
        } else {
            Err(DispersionError)
        }
    }

    /// True when nothing is dispersed.
    pub fn is_none(&self) -> bool {
        *self == Self::NONE
    }
}

impl Default for Dispersions {
    fn default() -> Self {
        Self::NONE
    }
}

/// A dispersion size that is negative or not finite.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DispersionError;

impl core::fmt::Display for DispersionError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("dispersion sizes must be finite and >= 0")
    }
}

/// Standard normal draws (Box-Muller; libm, so identical on the host and the Cortex-M4), one
/// ChaCha8 stream of a seed each.
#[derive(Clone)]
pub struct Normal(ChaCha8Rng);

impl Normal {
    /// The draws of stream `stream` of `seed`.
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(stream);
        Self(rng)
    }

    /// Uniform in (0, 1]: 53 random bits, never 0 so the logarithm is finite.
    pub fn unit(&mut self) -> f64 {
        ((self.0.next_u64() >> 11) as f64 + 1.0) * (1.0 / (1u64 << 53) as f64)
    }

    /// A standard normal draw.
    pub fn sample(&mut self) -> f64 {
        let (u1, u2) = (self.unit(), self.unit());
        libm::sqrt(-2.0 * libm::log(u1)) * libm::cos(core::f64::consts::TAU * u2)
    }

    /// Exponential with the given mean.
    fn exponential(&mut self, mean: f64) -> f64 {
        -mean * libm::log(self.unit())
    }
}

/// The dispersion state of one flight: random streams, the thruster's bias, the missed-thrust
/// windows. A clone taken at a cycle's start replays that cycle's draws exactly, whatever state
/// and command it is then flown with (the draws depend on neither).
#[derive(Clone)]
pub struct DispersedPlant {
    dispersions: Dispersions,
    navigation: Normal,
    pointing: Normal,
    missed: Normal,
    /// Actual thrust over nominal, fixed for the flight.
    thrust_factor: f64,
    /// One day and one year in the family's canonical time units.
    day: f64,
    year: f64,
    /// Next missed-thrust event: start and end (canonical time since departure).
    window: (f64, f64),
}

impl DispersedPlant {
    /// The plant of one flight in canonical units whose time unit is `time_unit_s` seconds: its
    /// thrust factor and first missed-thrust event drawn from `seed` (the same seed draws the
    /// same flight on any machine, the Cortex-M4F included).
    pub fn new(dispersions: &Dispersions, time_unit_s: f64, seed: u64) -> Self {
        let mut thrust = Normal::new(seed, 1);
        let thrust_factor = if dispersions.thrust_magnitude > 0.0 {
            (1.0 + dispersions.thrust_magnitude * thrust.sample()).max(0.0)
        } else {
            1.0
        };
        let mut plant = Self {
            dispersions: *dispersions,
            navigation: Normal::new(seed, 2),
            pointing: Normal::new(seed, 3),
            missed: Normal::new(seed, 4),
            thrust_factor,
            day: DAY_S / time_unit_s,
            year: YEAR_DAYS * DAY_S / time_unit_s,
            window: (f64::INFINITY, f64::INFINITY),
        };
        plant.window = plant.next_window(0.0);
        plant
    }

    /// Actual thrust over nominal for this flight.
    pub fn thrust_factor(&self) -> f64 {
        self.thrust_factor
    }

    fn next_window(&mut self, after: f64) -> (f64, f64) {
        let d = &self.dispersions;
        if d.missed_thrust_per_year > 0.0 && d.missed_thrust_days > 0.0 {
            let start = after + self.missed.exponential(self.year / d.missed_thrust_per_year);
            (start, start + d.missed_thrust_days * self.day)
        } else {
            (f64::INFINITY, f64::INFINITY)
        }
    }

    /// What the navigation system reports for the true state.
    pub fn navigate(&mut self, truth: &SpacecraftState) -> SpacecraftState {
        let d = self.dispersions;
        let mut nav = *truth;
        if d.navigation_position > 0.0 {
            nav.r = nav.r.map(|x| x + d.navigation_position * self.navigation.sample());
        }
        if d.navigation_velocity > 0.0 {
            nav.v = nav.v.map(|x| x + d.navigation_velocity * self.navigation.sample());
        }
        if d.navigation_mass > 0.0 {
            nav.m += d.navigation_mass * self.navigation.sample();
        }
        nav
    }

    /// The command the thruster actually follows over a cycle (pointing error applied).
    pub fn point(&mut self, command: &ThrustCommand) -> ThrustCommand {
        if self.dispersions.pointing > 0.0 {
            let angle = self.dispersions.pointing * self.pointing.sample();
            let (s, c) = (libm::sin(angle), libm::cos(angle));
            ThrustCommand {
                alpha_r: c * command.alpha_r - s * command.alpha_theta,
                alpha_theta: s * command.alpha_r + c * command.alpha_theta,
                ..*command
            }
        } else {
            *command
        }
    }

    /// What the navigation system reports for the true state in three dimensions: every axis
    /// of position and velocity, and the mass, dispersed as [`Self::navigate`] does in the plane.
    pub fn navigate3(&mut self, truth: &SpatialCraftState) -> SpatialCraftState {
        let d = self.dispersions;
        let mut nav = *truth;
        if d.navigation_position > 0.0 {
            nav.orbit.r = nav
                .orbit
                .r
                .map(|x| x + d.navigation_position * self.navigation.sample());
        }
        if d.navigation_velocity > 0.0 {
            nav.orbit.v = nav
                .orbit
                .v
                .map(|x| x + d.navigation_velocity * self.navigation.sample());
        }
        if d.navigation_mass > 0.0 {
            nav.m += d.navigation_mass * self.navigation.sample();
        }
        nav
    }

    /// The RTN command the thruster follows over a cycle: the direction turned by a pointing
    /// error drawn in a cone about it (two perpendicular components, each with the pointing
    /// sigma, so the off-axis angle is Rayleigh-distributed and its azimuth uniform), the unit
    /// length kept.
    pub fn point3(&mut self, command: &RtnCommand) -> RtnCommand {
        if self.dispersions.pointing <= 0.0 {
            return *command;
        }
        let (ex, ey) = (
            self.dispersions.pointing * self.pointing.sample(),
            self.dispersions.pointing * self.pointing.sample(),
        );
        let d = [command.radial, command.transverse, command.normal];
        // Two unit vectors perpendicular to d: across the RTN axis d is least along, then d x u.
        let axis = if libm::fabs(d[0]) <= libm::fabs(d[1]) && libm::fabs(d[0]) <= libm::fabs(d[2]) {
            [1.0, 0.0, 0.0]
        } else if libm::fabs(d[1]) <= libm::fabs(d[2]) {
            [0.0, 1.0, 0.0]
        } else {
            [0.0, 0.0, 1.0]
        };
        let across = cross3(&d, &axis);
        let length = norm3(&across);
        if length.is_nan() || length <= 0.0 {
            return *command;
        }
        let u = across.map(|x| x / length);
        let w = cross3(&d, &u);
        let angle = libm::hypot(ex, ey);
        if angle.is_nan() || angle <= 0.0 {
            return *command;
        }
        let (s, c) = (libm::sin(angle), libm::cos(angle));
        let ([d0, d1, d2], [u0, u1, u2], [w0, w1, w2]) = (d, u, w);
        let turned = [
            c * d0 + s * (ex * u0 + ey * w0) / angle,
            c * d1 + s * (ex * u1 + ey * w1) / angle,
            c * d2 + s * (ex * u2 + ey * w2) / angle,
        ];
        // Renormalized: the rounding of the rotation stays off the unit length.
        let [t0, t1, t2] = turned;
        let n = norm3(&turned);
        RtnCommand {
            radial: t0 / n,
            transverse: t1 / n,
            normal: t2 / n,
            ..*command
        }
    }

    /// The next segment of the cycle that starts at `cycle_start` (canonical time since
    /// departure): from `tau` (time into the cycle) to the returned end (at most `length`),
    /// thrust is on throughout (`true`) or off throughout. The end is always after `tau`:
    /// all comparisons are made in cycle time, so rounding cannot stall the plant.
    pub fn segment(&mut self, cycle_start: f64, tau: f64, length: f64) -> (f64, bool) {
        // Events that ended by now are consumed; back-to-back ones chain.
        while self.window.1 - cycle_start <= tau {
            self.window = self.next_window(self.window.1);
        }
        let (start, end) = (self.window.0 - cycle_start, self.window.1 - cycle_start);
        if start <= tau {
            (end.min(length), false)
        } else {
            (start.min(length), true)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::mission::CentralBody;
    use shared::units::TIME_UNIT_S;

    /// The missed-thrust events are drawn in days and years: a family whose time unit is ten
    /// times shorter sees the same events at ten times the canonical times, each lasting the
    /// given days in its own units.
    #[test]
    fn missed_thrust_events_are_timed_in_days_whatever_the_time_unit() {
        let d = Dispersions {
            missed_thrust_per_year: 3.0,
            missed_thrust_days: 5.0,
            ..Dispersions::NONE
        };
        let mut sun = DispersedPlant::new(&d, TIME_UNIT_S, 21);
        let mut fast = DispersedPlant::new(&d, TIME_UNIT_S / 10.0, 21);
        let mut after = (0.0, 0.0);
        for _ in 0..5 {
            // Thrust is on until the next event starts, then off until it ends.
            let (start_sun, on) = sun.segment(0.0, after.0, f64::INFINITY);
            let (start_fast, _) = fast.segment(0.0, after.1, f64::INFINITY);
            assert!(on);
            assert!(
                (start_fast / start_sun - 10.0).abs() < 1e-12,
                "{start_sun} {start_fast}"
            );
            let (end_sun, on) = sun.segment(0.0, start_sun, f64::INFINITY);
            let (end_fast, _) = fast.segment(0.0, start_fast, f64::INFINITY);
            assert!(!on);
            let days = |t: f64, unit: f64| t * unit / 86_400.0;
            assert!((days(end_sun - start_sun, TIME_UNIT_S) - 5.0).abs() < 1e-9);
            assert!((days(end_fast - start_fast, TIME_UNIT_S / 10.0) - 5.0).abs() < 1e-9);
            after = (end_sun, end_fast);
        }
    }

    /// The pointing cone in three dimensions: the applied direction stays a unit vector, its
    /// angle to the command has the Rayleigh law of two axes of sigma each (mean square 2 sigma^2,
    /// mean sigma sqrt(pi / 2)), its azimuth about the command is uniform (no preferred side),
    /// and the throttle is untouched; with no pointing error the command is returned as it is.
    #[test]
    fn the_three_dimensional_pointing_error_is_a_cone_about_the_command() {
        let sigma = 0.02;
        let d = Dispersions {
            pointing: sigma,
            ..Dispersions::NONE
        };
        let mut plant = DispersedPlant::new(&d, TIME_UNIT_S, 5);
        let n = 20_000;
        let (mut square, mut mean, mut sides) = (0.0, 0.0, [0usize; 4]);
        for k in 0..n {
            // Commands along every RTN axis and between them.
            let raw = [(k % 3) as f64 - 1.0, 0.5 + (k % 5) as f64 * 0.1, (k % 7) as f64 - 3.0];
            let norm = norm3(&raw);
            let command = RtnCommand {
                throttle: 0.7,
                radial: raw[0] / norm,
                transverse: raw[1] / norm,
                normal: raw[2] / norm,
            };
            let applied = plant.point3(&command);
            assert_eq!(applied.throttle, 0.7);
            let (a, c) = (
                [applied.radial, applied.transverse, applied.normal],
                [command.radial, command.transverse, command.normal],
            );
            assert!((norm3(&a) - 1.0).abs() < 1e-12);
            let angle = libm::atan2(
                norm3(&cross3(&c, &a)),
                a.iter().zip(&c).map(|(x, y)| x * y).sum::<f64>(),
            );
            square += angle * angle;
            mean += angle;
            // The side of the offset in a fixed frame about the command.
            let offset: [f64; 3] = core::array::from_fn(|i| a[i] - c[i]);
            let u = cross3(&c, &[0.3, -0.8, 0.52]);
            let w = cross3(&c, &u);
            let (x, y) = (
                offset.iter().zip(&u).map(|(p, q)| p * q).sum::<f64>(),
                offset.iter().zip(&w).map(|(p, q)| p * q).sum::<f64>(),
            );
            sides[usize::from(x > 0.0) + 2 * usize::from(y > 0.0)] += 1;
        }
        let (square, mean) = (square / n as f64, mean / n as f64);
        // Sampling errors: about 1 % of the mean square, 0.5 % of the mean at 20,000 draws.
        assert!((square / (2.0 * sigma * sigma) - 1.0).abs() < 0.04, "{square}");
        assert!(
            (mean / (sigma * (core::f64::consts::PI / 2.0).sqrt()) - 1.0).abs() < 0.02,
            "{mean}"
        );
        for side in sides {
            assert!((side as f64 / n as f64 - 0.25).abs() < 0.015, "{sides:?}");
        }
        let mut exact = DispersedPlant::new(&Dispersions::NONE, TIME_UNIT_S, 5);
        let command = RtnCommand {
            throttle: 1.0,
            radial: 0.6,
            transverse: 0.0,
            normal: 0.8,
        };
        assert_eq!(exact.point3(&command), command);
    }

    /// Navigation in three dimensions disperses every axis with its sigma and leaves the truth
    /// as it is without navigation error.
    #[test]
    fn three_dimensional_navigation_errors_every_axis() {
        let d = Dispersions {
            navigation_position: 1e-3,
            navigation_velocity: 2e-4,
            navigation_mass: 1e-3,
            ..Dispersions::NONE
        };
        let truth = SpatialCraftState {
            orbit: shared::orbit::SpatialState {
                r: [1.0, 0.2, 0.05],
                v: [-0.1, 0.95, 0.03],
            },
            m: 0.9,
        };
        let mut plant = DispersedPlant::new(&d, TIME_UNIT_S, 8);
        let n = 5_000;
        let mut squares = [0.0; 7];
        for _ in 0..n {
            let nav = plant.navigate3(&truth);
            for ((square, a), b) in squares.iter_mut().zip(nav.to_array()).zip(truth.to_array()) {
                *square += (a - b) * (a - b);
            }
        }
        let sigmas = [1e-3, 1e-3, 1e-3, 2e-4, 2e-4, 2e-4, 1e-3];
        for (axis, (square, sigma)) in squares.iter().zip(sigmas).enumerate() {
            let rms = (square / n as f64).sqrt();
            assert!((rms / sigma - 1.0).abs() < 0.05, "axis {axis}: {rms}");
        }
        let mut exact = DispersedPlant::new(&Dispersions::NONE, TIME_UNIT_S, 8);
        assert_eq!(exact.navigate3(&truth), truth);
    }

    /// The typical sizes in the Sun's units are the heliocentric constants bit for bit, and in
    /// the Earth's the same 1,000 km and 0.1 m/s.
    #[test]
    fn typical_dispersions_are_the_same_physical_sizes_in_any_units() {
        assert_eq!(Dispersions::typical_in(&CentralBody::SUN.units()), Dispersions::TYPICAL);
        let earth = CentralBody::EARTH.units();
        let typical = Dispersions::typical_in(&earth);
        assert!((typical.navigation_position * earth.length_m - 1.0e6).abs() < 1e-6);
        assert!((typical.navigation_velocity * earth.velocity_m_s() - 0.1).abs() < 1e-12);
        assert_eq!(typical.pointing, Dispersions::TYPICAL.pointing);
        assert_eq!(typical.missed_thrust_days, 7.0);
    }
}
