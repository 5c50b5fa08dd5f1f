//! Dispersions of the SIL truth plant: what flight software meets that the MDP does not.
//!
//! Each kind draws from its own ChaCha8 stream of the flight's seed, so switching one kind on
//! or off leaves the draws of the others unchanged, and a kind whose sigma is zero draws
//! nothing and changes nothing: with [`Dispersions::NONE`] the flight is bit-identical to the
//! undispersed MDP episode.

use onboard::dynamics::{SpacecraftState, ThrustCommand};
use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};
use shared::mission::{Units, DAY_S};
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
    /// Pointing error (rad) of the applied thrust direction, each cycle.
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
/// windows.
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
