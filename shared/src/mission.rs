//! Mission families as data (docs/spec.md section 4): the central body and its canonical units,
//! the ranges the departure orbit and the target are drawn from, the time-of-flight rule and the
//! guidance cycle. The thesis's four distributions are presets ([`crate::scenario::ScenarioKind`]).

use core::fmt::{self, Write as _};

use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use crate::orbit::{OrbitElements, OrbitPlane, OrbitShape};
use crate::scenario::{ProblemKind, Range, Scenario, SpatialScenario};
use crate::units::{AU_M, MU_SUN_M3_S2, TIME_UNIT_S};

/// Seconds in a day: times of flight and cycles are given in days.
pub const DAY_S: f64 = 86_400.0;

/// The body every orbit of a family goes around, by its gravitational parameter and the length
/// unit its orbits are given in. Canonical units follow: length 1 unit, mu = 1.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CentralBody {
    /// Gravitational parameter, m^3/s^2.
    pub mu_m3_s2: f64,
    /// The canonical length unit, m: semi-major axes and the accuracy goal are in it.
    pub length_unit_m: f64,
}

impl CentralBody {
    /// The Sun with lengths in AU (IAU 2015 nominal mu, IAU 2012 AU): the thesis's units.
    pub const SUN: Self = Self {
        mu_m3_s2: MU_SUN_M3_S2,
        length_unit_m: AU_M,
    };
    /// The Earth (EGM96 mu) with lengths in its equatorial radius (WGS 84).
    pub const EARTH: Self = Self {
        mu_m3_s2: 3.986_004_418e14,
        length_unit_m: 6_378_137.0,
    };
    /// Mars (MRO120D mu) with lengths in its equatorial radius (IAU 2015).
    pub const MARS: Self = Self {
        mu_m3_s2: 4.282_837_362e13,
        length_unit_m: 3_396_190.0,
    };
    /// The presets by name, as configs write them.
    pub const PRESETS: [(&'static str, Self); 3] = [("sun", Self::SUN), ("earth", Self::EARTH), ("mars", Self::MARS)];

    /// The preset's name when the body is one.
    pub fn preset_name(&self) -> Option<&'static str> {
        Self::PRESETS
            .iter()
            .find(|(_, body)| body == self)
            .map(|(name, _)| *name)
    }

    /// The canonical units of the body. The Sun's time unit is the docs/spec.md section 1
    /// constant, one ulp from the formula sqrt(L^3 / mu), so that the thesis's scenarios keep
    /// their every bit.
    pub fn units(&self) -> Units {
        let time_s = if *self == Self::SUN {
            TIME_UNIT_S
        } else {
            let l = self.length_unit_m;
            libm::sqrt(l * l * l / self.mu_m3_s2)
        };
        Units {
            length_m: self.length_unit_m,
            time_s,
        }
    }
}

/// The Sun in AU, the thesis's body.
impl Default for CentralBody {
    fn default() -> Self {
        Self::SUN
    }
}

/// Canonical units: a length unit and the time unit that makes mu = 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Units {
    /// Length unit, m.
    pub length_m: f64,
    /// Time unit, s.
    pub time_s: f64,
}

impl Units {
    /// The thesis's units: AU and the Sun's time unit.
    pub const HELIOCENTRIC: Self = Self {
        length_m: AU_M,
        time_s: TIME_UNIT_S,
    };

    /// Velocity unit, m/s.
    pub fn velocity_m_s(&self) -> f64 {
        self.length_m / self.time_s
    }

    /// Acceleration unit, m/s^2.
    pub fn acceleration_m_s2(&self) -> f64 {
        self.length_m / (self.time_s * self.time_s)
    }

    /// Days to canonical time.
    pub fn days(&self, days: f64) -> f64 {
        days * DAY_S / self.time_s
    }

    /// Canonical time to days.
    pub fn to_days(&self, t: f64) -> f64 {
        t * self.time_s / DAY_S
    }
}

/// One uniform draw from `range`: 53 random bits of the next 64-bit word.
fn uniform(rng: &mut ChaCha8Rng, range: Range) -> f64 {
    let unit = (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
    range.lo + (range.hi - range.lo) * unit
}

/// The parameter ranges of one orbit of a family: the departure orbit, or the target. Angles in
/// radians, semi-major axes in the body's length unit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OrbitRanges {
    /// Semi-major axis (length units).
    pub a: Range,
    /// Eccentricity.
    pub e: Range,
    /// Argument of periapsis (rad).
    pub omega: Range,
    /// True anomaly at departure (rad): the spacecraft's on the departure orbit, the target
    /// body's on the target orbit (rendezvous; a transfer draws and ignores it).
    pub nu: Range,
}

/// How long a scenario of the family flies.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum TimeOfFlight {
    /// The thesis's rule: the longer of the two orbits' periods, rounded up to whole cycles.
    LongerPeriod,
    /// A fixed time of flight, days (rounded up to whole cycles of a cycle given in days).
    Fixed {
        /// Days.
        days: f64,
    },
    /// A time of flight drawn uniformly from [lo, hi] days (rounded up likewise).
    Drawn {
        /// Shortest, days.
        lo_days: f64,
        /// Longest, days.
        hi_days: f64,
    },
}

/// The guidance cycle: how often the network is asked for a command, held until the next.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Cycle {
    /// A cycle of this many days; the time of flight is rounded up to whole cycles.
    Days(f64),
    /// This many equal cycles over each scenario's time of flight.
    Count(u32),
}

/// Most guidance cycles one flight may hold: beyond it a family is refused (a mistyped cycle).
pub const MAX_CYCLES: u32 = 10_000;
/// The band of semi-major axes, in length units, that keeps every feature well scaled for f32
/// and int8 (positions, velocities and times near 1).
pub const A_BAND: (f64, f64) = (1e-2, 1e2);

/// A distribution of scenarios: everything that poses one transfer or rendezvous but the seed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MissionFamily {
    /// Transfer (any point of the target orbit) or rendezvous (meet the body on it).
    pub problem: ProblemKind,
    /// The central body and the length unit.
    pub body: CentralBody,
    /// Where the spacecraft starts.
    pub departure: OrbitRanges,
    /// The target orbit and, for a rendezvous, the body's anomaly at departure.
    pub target: OrbitRanges,
    /// How long each flight lasts.
    pub time_of_flight: TimeOfFlight,
    /// The guidance cycle.
    pub cycle: Cycle,
}

/// Why a family cannot be posed: the field (as a config writes it) and what is wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FamilyError {
    /// The field, e.g. `departure.e`.
    pub field: &'static str,
    /// What is wrong with it.
    pub problem: &'static str,
}

impl fmt::Display for FamilyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.field, self.problem)
    }
}

impl core::error::Error for FamilyError {}

fn refuse(field: &'static str, problem: &'static str) -> Result<(), FamilyError> {
    Err(FamilyError { field, problem })
}

impl MissionFamily {
    /// Checks that every scenario of the family can be posed and flown: the first offending
    /// field, named as a config writes it.
    pub fn validate(&self) -> Result<(), FamilyError> {
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !positive(self.body.mu_m3_s2) {
            return refuse("body.mu_m3_s2", "the gravitational parameter must be finite and > 0");
        }
        if !positive(self.body.length_unit_m) {
            return refuse("body.length_unit_m", "the length unit must be finite and > 0");
        }
        let units = self.body.units();
        if !positive(units.time_s) {
            return refuse("body", "the time unit sqrt(L^3 / mu) is not a finite positive number");
        }
        for (ranges, fields) in [(&self.departure, DEPARTURE_FIELDS), (&self.target, TARGET_FIELDS)] {
            for (range, field) in [ranges.a, ranges.e, ranges.omega, ranges.nu].into_iter().zip(fields) {
                if !(range.lo.is_finite() && range.hi.is_finite()) {
                    return refuse(field, "bounds must be finite");
                }
                if range.lo > range.hi {
                    return refuse(field, "lo > hi");
                }
            }
            if ranges.a.lo <= 0.0 {
                return refuse(fields[0], "semi-major axes must be > 0");
            }
            if ranges.a.lo < A_BAND.0 || ranges.a.hi > A_BAND.1 {
                return refuse(
                    fields[0],
                    "semi-major axes must lie within 0.01 to 100 length units, or the features leave f32's \
                     well-scaled range: choose a length unit near the orbits' size",
                );
            }
            if ranges.e.lo < 0.0 || ranges.e.hi >= 1.0 {
                return refuse(fields[1], "eccentricities must lie in [0, 1)");
            }
        }
        let shortest_days = match self.time_of_flight {
            TimeOfFlight::LongerPeriod => {
                let a = libm::fmax(self.departure.a.lo, self.target.a.lo);
                units.to_days(2.0 * core::f64::consts::PI * a * libm::sqrt(a))
            }
            TimeOfFlight::Fixed { days } => {
                if !positive(days) {
                    return refuse("time_of_flight.days", "the time of flight must be finite and > 0 days");
                }
                days
            }
            TimeOfFlight::Drawn { lo_days, hi_days } => {
                if !(positive(lo_days) && positive(hi_days)) {
                    return refuse("time_of_flight.days", "times of flight must be finite and > 0 days");
                }
                if lo_days > hi_days {
                    return refuse("time_of_flight.days", "lo > hi");
                }
                lo_days
            }
        };
        match self.cycle {
            Cycle::Days(days) => {
                if !positive(days) {
                    return refuse("cycle.days", "the cycle must be finite and > 0 days");
                }
                if days > shortest_days {
                    return refuse(
                        "cycle.days",
                        "the cycle is longer than the shortest flight of the family",
                    );
                }
                let longest_days = match self.time_of_flight {
                    TimeOfFlight::LongerPeriod => {
                        let a = libm::fmax(self.departure.a.hi, self.target.a.hi);
                        units.to_days(2.0 * core::f64::consts::PI * a * libm::sqrt(a))
                    }
                    TimeOfFlight::Fixed { days } => days,
                    TimeOfFlight::Drawn { hi_days, .. } => hi_days,
                };
                if longest_days / days > f64::from(MAX_CYCLES) {
                    return refuse("cycle.days", "the longest flight would hold more than 10,000 cycles");
                }
            }
            Cycle::Count(n) => {
                if n == 0 {
                    return refuse("cycle.count", "a flight needs at least one cycle");
                }
                if n > MAX_CYCLES {
                    return refuse("cycle.count", "at most 10,000 cycles a flight");
                }
            }
        }
        Ok(())
    }

    /// Draws scenario number `index` of the stream `seed`. Each index has its own ChaCha8
    /// stream, so any shard of a dataset regenerates alone and identically.
    pub fn draw(&self, seed: u64, index: u64) -> Scenario {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(index);
        // Always nine draws in this order, whatever is fixed, so the layout never shifts; the
        // time of flight came last, after the thesis's eight.
        let mut uniform = |range: Range| uniform(&mut rng, range);
        let (d, t) = (&self.departure, &self.target);
        let initial = OrbitElements {
            shape: OrbitShape {
                a: uniform(d.a),
                e: uniform(d.e),
                omega: uniform(d.omega),
            },
            nu: uniform(d.nu),
        };
        let target = OrbitShape {
            a: uniform(t.a),
            e: uniform(t.e),
            omega: uniform(t.omega),
        };
        let target_nu0 = uniform(t.nu);
        let drawn_days = match self.time_of_flight {
            TimeOfFlight::Drawn { lo_days, hi_days } => uniform(Range {
                lo: lo_days,
                hi: hi_days,
            }),
            _ => 0.0,
        };
        let units = self.body.units();
        let time_of_flight = match self.time_of_flight {
            TimeOfFlight::LongerPeriod => libm::fmax(initial.shape.period(), target.period()),
            TimeOfFlight::Fixed { days } => units.days(days),
            TimeOfFlight::Drawn { .. } => units.days(drawn_days),
        };
        let (steps, cycle) = self.cycles_of(time_of_flight);
        Scenario {
            problem: self.problem,
            initial,
            target,
            target_nu0,
            steps,
            cycle,
        }
    }

    /// The cycles of a flight of `time_of_flight` (t*): their number and their length (t*).
    pub fn cycles_of(&self, time_of_flight: f64) -> (u32, f64) {
        match self.cycle {
            Cycle::Days(days) => {
                let cycle = self.body.units().days(days);
                (Scenario::cycles_covering(time_of_flight, cycle), cycle)
            }
            Cycle::Count(n) => (n, time_of_flight / f64::from(n)),
        }
    }

    /// The cycle's length (t*) when every flight of the family has the same one: a cycle in
    /// days, or a count of cycles over a fixed time of flight (the same bits as its
    /// scenarios' cycle); `None` for a count over flights of different lengths. What the
    /// onboard aids count.
    pub fn fixed_cycle(&self) -> Option<f64> {
        match (self.cycle, self.time_of_flight) {
            (Cycle::Days(days), _) => Some(self.body.units().days(days)),
            (Cycle::Count(_), TimeOfFlight::Fixed { days }) => Some(self.cycles_of(self.body.units().days(days)).1),
            (Cycle::Count(_), _) => None,
        }
    }

    /// A 32-bit fingerprint of every field (CRC-32C of its postcard encoding): two families
    /// with one fingerprint are equal for every practical purpose.
    pub fn fingerprint(&self) -> u32 {
        let mut buffer = [0u8; 256];
        let encoded = postcard::to_slice(self, &mut buffer).map(|b| &*b).unwrap_or(&[]);
        crc::Crc::<u32>::new(&crc::CRC_32_ISCSI).checksum(encoded)
    }

    /// The name of the thesis preset the family equals, if any.
    pub fn preset_name(&self) -> Option<&'static str> {
        crate::scenario::ScenarioKind::ALL
            .into_iter()
            .find(|kind| kind.family() == *self)
            .map(|kind| kind.name())
    }

    /// A name for messages: the preset's, or `custom-XXXXXXXX` with the fingerprint.
    pub fn label(&self) -> FamilyLabel {
        let mut text = heapless::String::new();
        let _ = match self.preset_name() {
            Some(name) => text.push_str(name).map_err(|_| fmt::Error),
            None => write!(text, "custom-{:08x}", self.fingerprint()),
        };
        FamilyLabel(text)
    }
}

/// The ranges one orbit's plane is drawn from: inclination and node (rad).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlaneRanges {
    /// Inclination to the reference plane (rad), within [0, pi].
    pub inclination: Range,
    /// Right ascension of the ascending node (rad).
    pub raan: Range,
}

impl PlaneRanges {
    /// Always the reference plane: a planar family's.
    pub const REFERENCE: Self = Self {
        inclination: Range { lo: 0.0, hi: 0.0 },
        raan: Range { lo: 0.0, hi: 0.0 },
    };

    /// Planes inclined within `inclination` (rad) with any ascending node.
    pub const fn any_node(inclination: Range) -> Self {
        Self {
            inclination,
            raan: Range {
                lo: 0.0,
                hi: core::f64::consts::TAU,
            },
        }
    }
}

/// The departure state's dispersion about the one its orbit gives (docs/spec.md section 4): a
/// Gaussian error with this standard deviation on each inertial axis, in the body's length and
/// velocity units; zero for none. How a real mission's departure uncertainty becomes a family.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StateDispersion {
    /// Standard deviation of each position component (length units).
    pub position: f64,
    /// Standard deviation of each velocity component (velocity units).
    pub velocity: f64,
}

impl StateDispersion {
    /// No dispersion: every draw departs from its orbit's state exactly.
    pub const NONE: Self = Self {
        position: 0.0,
        velocity: 0.0,
    };

    /// The largest standard deviation accepted, in length and velocity units: a dispersion
    /// about one departure, not a second family (and every draw stays on a closed orbit).
    pub const MAX_SIGMA: f64 = 0.01;

    /// Whether it disperses anything.
    pub fn is_none(&self) -> bool {
        *self == Self::NONE
    }
}

/// A family in three dimensions (docs/spec.md section 4, inclined families): a [`MissionFamily`] whose orbits
/// each lie in a plane drawn from its own ranges. Every planar figure (the shapes, the
/// anomalies, the time of flight, the cycle) is the planar family's, measured in each orbit's
/// plane; with both planes fixed at the reference plane it is the planar family itself.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SpatialFamily {
    /// Everything in each orbit's own plane.
    pub family: MissionFamily,
    /// The departure orbit's plane.
    pub departure_plane: PlaneRanges,
    /// The target orbit's plane.
    pub target_plane: PlaneRanges,
    /// The departure state's dispersion ([`StateDispersion::NONE`]: none).
    pub departure_dispersion: StateDispersion,
}

/// Where the plane draws start in an index's stream, in 32-bit words: after the planar
/// family's nine draws, so that a scenario's planar figures are the planar family's.
const PLANE_WORDS: u128 = 18;
/// Where the departure dispersion's draws start: after the four plane draws.
const DISPERSION_WORDS: u128 = PLANE_WORDS + 8;

impl SpatialFamily {
    /// The planar family, in the reference plane.
    pub const fn planar(family: MissionFamily) -> Self {
        Self {
            family,
            departure_plane: PlaneRanges::REFERENCE,
            target_plane: PlaneRanges::REFERENCE,
            departure_dispersion: StateDispersion::NONE,
        }
    }

    /// The planar family departing in the reference plane, undispersed, towards a target whose
    /// plane is inclined within `inclination` (rad) with any ascending node: the inclined
    /// families (`configs/transfer-circular-inclined.toml` gives one as data).
    pub const fn inclined_target(family: MissionFamily, inclination: Range) -> Self {
        Self {
            target_plane: PlaneRanges::any_node(inclination),
            ..Self::planar(family)
        }
    }

    /// The planar family when both planes are fixed at the reference plane and the departure
    /// is not dispersed (a dispersed state leaves the plane).
    pub fn as_planar(&self) -> Option<MissionFamily> {
        (self.departure_plane == PlaneRanges::REFERENCE
            && self.target_plane == PlaneRanges::REFERENCE
            && self.departure_dispersion.is_none())
        .then_some(self.family)
    }

    /// Checks the planar family and both planes' ranges: the first offending field.
    pub fn validate(&self) -> Result<(), FamilyError> {
        self.family.validate()?;
        let planes = [
            (&self.departure_plane, DEPARTURE_PLANE_FIELDS),
            (&self.target_plane, TARGET_PLANE_FIELDS),
        ];
        for (plane, [inclination, raan]) in planes {
            for (range, field) in [(plane.inclination, inclination), (plane.raan, raan)] {
                if !(range.lo.is_finite() && range.hi.is_finite()) {
                    return refuse(field, "bounds must be finite");
                }
                if range.lo > range.hi {
                    return refuse(field, "lo > hi");
                }
            }
            if plane.inclination.lo < 0.0 || plane.inclination.hi > core::f64::consts::PI {
                return refuse(inclination, "inclinations must lie in [0, pi]");
            }
        }
        let dispersion = &self.departure_dispersion;
        for (sigma, field) in [
            (dispersion.position, "departure.dispersion.r"),
            (dispersion.velocity, "departure.dispersion.v"),
        ] {
            if !(sigma.is_finite() && (0.0..=StateDispersion::MAX_SIGMA).contains(&sigma)) {
                return refuse(
                    field,
                    "a standard deviation must be finite, >= 0 and at most 0.01 of the body's unit",
                );
            }
        }
        Ok(())
    }

    /// Draws scenario number `index` of the stream `seed`: the planar family's draw, each orbit
    /// put in a plane drawn after it from the same stream.
    pub fn draw(&self, seed: u64, index: u64) -> SpatialScenario {
        let scenario = self.family.draw(seed, index);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(index);
        rng.set_word_pos(PLANE_WORDS);
        let mut plane = |ranges: &PlaneRanges| OrbitPlane {
            inclination: uniform(&mut rng, ranges.inclination),
            raan: uniform(&mut rng, ranges.raan),
        };
        let drawn = SpatialScenario {
            initial_plane: plane(&self.departure_plane),
            target_plane: plane(&self.target_plane),
            scenario,
        };
        if self.departure_dispersion.is_none() {
            return drawn;
        }
        rng.set_word_pos(DISPERSION_WORDS);
        disperse(drawn, &self.departure_dispersion, &mut rng)
    }

    /// The planar family's fingerprint when it is planar; else the CRC-32C of the whole
    /// family's postcard encoding, the dispersion left out when there is none (so a family
    /// without one keeps the fingerprint it had before families could disperse).
    pub fn fingerprint(&self) -> u32 {
        if let Some(planar) = self.as_planar() {
            return planar.fingerprint();
        }
        let mut buffer = [0u8; 320];
        let encoded = if self.departure_dispersion.is_none() {
            postcard::to_slice(&(&self.family, &self.departure_plane, &self.target_plane), &mut buffer)
        } else {
            postcard::to_slice(self, &mut buffer)
        };
        crc::Crc::<u32>::new(&crc::CRC_32_ISCSI).checksum(encoded.map(|b| &*b).unwrap_or(&[]))
    }

    /// A name for messages: the planar family's, or `custom-XXXXXXXX` with the fingerprint.
    pub fn label(&self) -> FamilyLabel {
        if let Some(planar) = self.as_planar() {
            return planar.label();
        }
        let mut text = heapless::String::new();
        let _ = write!(text, "custom-{:08x}", self.fingerprint());
        FamilyLabel(text)
    }
}

/// `drawn` with its departure state moved by a Gaussian error of `dispersion` on each axis
/// (six normal deviates by Box-Muller from the stream, position then velocity), the orbit and
/// plane through the moved state in place of the drawn ones. A moved state on no closed orbit
/// (not reachable within [`StateDispersion::MAX_SIGMA`] of a bound orbit in practice) keeps the
/// drawn departure.
fn disperse(drawn: SpatialScenario, dispersion: &StateDispersion, rng: &mut ChaCha8Rng) -> SpatialScenario {
    let unit = Range { lo: 0.0, hi: 1.0 };
    let mut normals = [0.0; 6];
    for pair in normals.chunks_exact_mut(2) {
        // 1 - u lies in (0, 1]: its logarithm is finite.
        let radius = libm::sqrt(-2.0 * libm::log(1.0 - uniform(rng, unit)));
        let angle = core::f64::consts::TAU * uniform(rng, unit);
        pair[0] = radius * libm::cos(angle);
        pair[1] = radius * libm::sin(angle);
    }
    let mut state = drawn.departure();
    for axis in 0..3 {
        state.r[axis] += dispersion.position * normals[axis];
        state.v[axis] += dispersion.velocity * normals[3 + axis];
    }
    match state.elements() {
        Some((initial, initial_plane)) => SpatialScenario {
            initial_plane,
            scenario: Scenario {
                initial,
                ..drawn.scenario
            },
            ..drawn
        },
        None => drawn,
    }
}

/// [`MissionFamily::label`]: a short name that displays.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FamilyLabel(heapless::String<24>);

impl FamilyLabel {
    /// The label's text.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl fmt::Display for FamilyLabel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

const DEPARTURE_FIELDS: [&str; 4] = ["departure.a", "departure.e", "departure.omega", "departure.nu"];
const TARGET_FIELDS: [&str; 4] = ["target.a", "target.e", "target.omega", "target.nu"];
const DEPARTURE_PLANE_FIELDS: [&str; 2] = ["departure.inclination", "departure.raan"];
const TARGET_PLANE_FIELDS: [&str; 2] = ["target.inclination", "target.raan"];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::ScenarioKind;
    use crate::units::{ACCELERATION_UNIT_M_S2, STEP, VELOCITY_UNIT_M_S};

    fn inward() -> MissionFamily {
        let narrow = |lo: f64, hi: f64| Range { lo, hi };
        MissionFamily {
            problem: ProblemKind::Rendezvous,
            body: CentralBody::SUN,
            departure: OrbitRanges {
                a: narrow(0.95, 1.05),
                e: narrow(0.0, 0.02),
                omega: narrow(0.0, core::f64::consts::TAU),
                nu: narrow(0.0, core::f64::consts::TAU),
            },
            target: OrbitRanges {
                a: narrow(0.7, 0.74),
                e: narrow(0.0, 0.01),
                omega: narrow(0.0, core::f64::consts::TAU),
                nu: narrow(0.0, core::f64::consts::TAU),
            },
            time_of_flight: TimeOfFlight::Drawn {
                lo_days: 250.0,
                hi_days: 400.0,
            },
            cycle: Cycle::Days(7.0),
        }
    }

    #[test]
    fn the_suns_units_are_the_thesis_constants_and_others_follow_the_formula() {
        let sun = CentralBody::SUN.units();
        assert_eq!(sun, Units::HELIOCENTRIC);
        assert_eq!(sun.velocity_m_s(), VELOCITY_UNIT_M_S);
        assert_eq!(sun.acceleration_m_s2(), ACCELERATION_UNIT_M_S2);
        assert_eq!(sun.days(14.0), STEP);
        // A circular orbit at the Earth's radius: 84.49 minutes (the textbook figure).
        let earth = CentralBody::EARTH.units();
        let period_min = 2.0 * core::f64::consts::PI * earth.time_s / 60.0;
        assert!((period_min - 84.49).abs() < 0.01, "{period_min}");
        // Low Mars orbit at one radius: about 100.2 minutes.
        let mars = CentralBody::MARS.units();
        let period_min = 2.0 * core::f64::consts::PI * mars.time_s / 60.0;
        assert!((period_min - 100.2).abs() < 0.2, "{period_min}");
        assert_eq!(CentralBody::EARTH.preset_name(), Some("earth"));
    }

    #[test]
    fn presets_validate_and_are_named_and_a_custom_family_is_labelled_by_fingerprint() {
        for kind in ScenarioKind::ALL {
            let family = kind.family();
            assert_eq!(family.validate(), Ok(()));
            assert_eq!(family.label().as_str(), kind.name());
        }
        let family = inward();
        assert_eq!(family.validate(), Ok(()));
        let label = family.label();
        assert!(
            label.as_str().starts_with("custom-") && label.as_str().len() == 15,
            "{label}"
        );
        let mut other = family;
        other.cycle = Cycle::Days(7.5);
        assert_ne!(other.fingerprint(), family.fingerprint());
    }

    #[test]
    fn draws_honour_the_two_orbits_ranges_the_drawn_time_and_the_cycle() {
        let family = inward();
        let units = family.body.units();
        for index in 0..300 {
            let s = family.draw(3, index);
            assert_eq!(s, family.draw(3, index));
            assert!(s.validate().is_ok());
            assert!((0.95..=1.05).contains(&s.initial.shape.a) && (0.7..=0.74).contains(&s.target.a));
            assert_eq!(s.cycle, units.days(7.0));
            // The drawn time rounded up to whole 7-day cycles.
            let days = units.to_days(s.time_of_flight());
            assert!((250.0..407.0).contains(&days), "{days}");
            assert!(units.to_days(f64::from(s.steps - 1) * s.cycle) < 400.0);
        }
        let mut counted = family;
        counted.cycle = Cycle::Count(40);
        let (a, b) = (family.draw(3, 9), counted.draw(3, 9));
        assert_eq!(b.steps, 40);
        assert!(
            (b.time_of_flight() - a.time_of_flight()).abs() <= a.cycle,
            "same drawn time"
        );
        assert_eq!(a.initial, b.initial);
        // A count of cycles has one length only over a fixed flight: the aids' cycle is then
        // the draws' own, bit for bit.
        assert_eq!(counted.fixed_cycle(), None);
        counted.time_of_flight = TimeOfFlight::Fixed { days: 348.79 };
        let fixed = counted.draw(3, 9);
        assert_eq!(counted.fixed_cycle().map(f64::to_bits), Some(fixed.cycle.to_bits()));
        assert_eq!(fixed.steps, 40);
        assert_eq!(family.fixed_cycle(), Some(units.days(7.0)));
    }

    fn inclined() -> SpatialFamily {
        let inclination = Range {
            lo: 0.0,
            hi: 5f64.to_radians(),
        };
        SpatialFamily::inclined_target(ScenarioKind::TransferCircular.family(), inclination)
    }

    #[test]
    fn a_spatial_family_keeps_the_planar_draws_and_draws_its_planes_within_their_ranges() {
        let planar = SpatialFamily::planar(inward());
        assert_eq!(planar.as_planar(), Some(inward()));
        assert_eq!(planar.fingerprint(), inward().fingerprint());
        assert_eq!(planar.label(), inward().label());
        assert!(planar.draw(3, 5).is_planar());
        let family = inclined();
        assert_eq!(family.validate(), Ok(()));
        assert_eq!(family.as_planar(), None);
        assert_ne!(family.fingerprint(), family.family.fingerprint());
        assert!(family.label().as_str().starts_with("custom-"));
        let n = 2000;
        let mut sum = 0.0;
        for index in 0..n {
            let s = family.draw(11, index);
            assert_eq!(s, family.draw(11, index));
            assert_ne!(s.target_plane, family.draw(11, index + 1).target_plane);
            // The planes come after the planar figures, which stay the planar family's.
            assert_eq!(s.scenario, family.family.draw(11, index));
            assert_eq!(s.initial_plane, OrbitPlane::REFERENCE);
            let i = s.target_plane.inclination;
            assert!(
                (0.0..=5f64.to_radians()).contains(&i) && (0.0..=core::f64::consts::TAU).contains(&s.target_plane.raan)
            );
            assert!(s.validate().is_ok());
            sum += i;
        }
        // Uniform on [0, 5 deg]: the mean within 5 standard errors of 2.5 deg.
        let mean = sum / n as f64;
        let sd = 5f64.to_radians() / libm::sqrt(12.0 * n as f64);
        assert!((mean - 2.5f64.to_radians()).abs() < 5.0 * sd, "{mean}");
        let field = |edit: &dyn Fn(&mut SpatialFamily)| {
            let mut family = inclined();
            edit(&mut family);
            family.validate().map_err(|e| e.field)
        };
        assert_eq!(
            field(&|f| f.target_plane.inclination.hi = 3.2),
            Err("target.inclination")
        );
        assert_eq!(
            field(&|f| f.departure_plane.inclination.lo = -0.1),
            Err("departure.inclination")
        );
        assert_eq!(field(&|f| f.departure_plane.raan.hi = f64::NAN), Err("departure.raan"));
        assert_eq!(
            field(&|f| f.target_plane.raan = Range { lo: 1.0, hi: 0.5 }),
            Err("target.raan")
        );
        assert_eq!(field(&|f| f.family.cycle = Cycle::Count(0)), Err("cycle.count"));
    }

    #[test]
    fn a_dispersed_departure_moves_each_axis_by_its_gaussian_and_nothing_else() {
        let nominal = SpatialFamily::planar(ScenarioKind::RendezvousCircular.family());
        let dispersion = StateDispersion {
            position: 1e-3,
            velocity: 2e-3,
        };
        let dispersed = SpatialFamily {
            departure_dispersion: dispersion,
            ..nominal
        };
        assert!(dispersed.validate().is_ok());
        assert_eq!(dispersed.as_planar(), None, "a dispersed state leaves the plane");
        assert_ne!(dispersed.fingerprint(), nominal.fingerprint());
        let n = 4000;
        let (mut sum, mut squares) = ([0.0f64; 6], [0.0f64; 6]);
        let mut cross = 0.0;
        for index in 0..n {
            let (a, b) = (nominal.draw(5, index), dispersed.draw(5, index));
            assert_eq!(b, dispersed.draw(5, index));
            assert!(b.validate().is_ok());
            // The target, its anomaly, the flight and its cycles are the undispersed draw's.
            assert_eq!(
                (
                    b.scenario.target,
                    b.scenario.target_nu0,
                    b.scenario.steps,
                    b.target_plane
                ),
                (
                    a.scenario.target,
                    a.scenario.target_nu0,
                    a.scenario.steps,
                    a.target_plane
                )
            );
            let (from, to) = (a.departure(), b.departure());
            let errors: [f64; 6] = core::array::from_fn(|k| {
                let (d, sigma) = if k < 3 {
                    (to.r[k] - from.r[k], dispersion.position)
                } else {
                    (to.v[k - 3] - from.v[k - 3], dispersion.velocity)
                };
                d / sigma
            });
            for k in 0..6 {
                sum[k] += errors[k];
                squares[k] += errors[k] * errors[k];
            }
            cross += errors[0] * errors[3];
        }
        let n = n as f64;
        for k in 0..6 {
            let (mean, variance) = (sum[k] / n, squares[k] / n - (sum[k] / n).powi(2));
            // Standard normal deviates: mean within 4 standard errors, variance within 10 %.
            assert!(mean.abs() < 4.0 / n.sqrt(), "axis {k}: mean {mean}");
            assert!((variance - 1.0).abs() < 0.1, "axis {k}: variance {variance}");
        }
        assert!(
            (cross / n).abs() < 4.0 / n.sqrt(),
            "position and velocity errors correlated"
        );
        for (bad, field) in [
            (
                StateDispersion {
                    position: -1e-9,
                    ..dispersion
                },
                "departure.dispersion.r",
            ),
            (
                StateDispersion {
                    velocity: f64::NAN,
                    ..dispersion
                },
                "departure.dispersion.v",
            ),
            (
                StateDispersion {
                    velocity: 0.02,
                    ..dispersion
                },
                "departure.dispersion.v",
            ),
        ] {
            let family = SpatialFamily {
                departure_dispersion: bad,
                ..nominal
            };
            assert_eq!(family.validate().map_err(|e| e.field), Err(field));
        }
    }

    #[test]
    fn a_family_that_cannot_be_posed_is_refused_with_its_field() {
        let field = |edit: &dyn Fn(&mut MissionFamily)| {
            let mut family = inward();
            edit(&mut family);
            family.validate().map_err(|e| e.field)
        };
        assert_eq!(
            field(&|f| f.departure.a = Range { lo: 1.2, hi: 1.1 }),
            Err("departure.a")
        );
        assert_eq!(field(&|f| f.target.e = Range { lo: 0.0, hi: 1.0 }), Err("target.e"));
        assert_eq!(field(&|f| f.target.a = Range { lo: -1.0, hi: 1.0 }), Err("target.a"));
        assert_eq!(field(&|f| f.target.a = Range { lo: 0.5, hi: 500.0 }), Err("target.a"));
        assert_eq!(field(&|f| f.departure.omega.hi = f64::NAN), Err("departure.omega"));
        assert_eq!(field(&|f| f.body.mu_m3_s2 = 0.0), Err("body.mu_m3_s2"));
        assert_eq!(field(&|f| f.body.length_unit_m = -3.0), Err("body.length_unit_m"));
        assert_eq!(field(&|f| f.cycle = Cycle::Days(0.0)), Err("cycle.days"));
        assert_eq!(field(&|f| f.cycle = Cycle::Days(300.0)), Err("cycle.days"));
        assert_eq!(field(&|f| f.cycle = Cycle::Days(1e-4)), Err("cycle.days"));
        assert_eq!(field(&|f| f.cycle = Cycle::Count(0)), Err("cycle.count"));
        assert_eq!(
            field(&|f| f.time_of_flight = TimeOfFlight::Fixed { days: -5.0 }),
            Err("time_of_flight.days")
        );
        assert_eq!(
            field(&|f| f.time_of_flight = TimeOfFlight::Drawn {
                lo_days: 300.0,
                hi_days: 200.0
            }),
            Err("time_of_flight.days")
        );
        // The thesis rule: a 14-day cycle fits every period of 0.39 AU and up; 100 days does not.
        let mut hard = ScenarioKind::TransferHard.family();
        hard.cycle = Cycle::Days(100.0);
        assert_eq!(hard.validate().map_err(|e| e.field), Err("cycle.days"));
    }
}
