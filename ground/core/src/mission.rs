//! Mission families as users write them (docs/missions.md): a preset's name, or a table of the
//! central body, the two orbits' ranges, the time of flight and the guidance cycle, read from a
//! config, a shared TOML file or a manifest, checked, and turned into a [`MissionFamily`].

use std::f64::consts::TAU;
use std::path::Path;

use serde::{Deserialize, Serialize};
use shared::mission::{
    CentralBody, Cycle, FamilyError, MissionFamily, OrbitRanges, PlaneRanges, SpatialFamily, StateDispersion,
    TimeOfFlight,
};
use shared::scenario::{ProblemKind, Range, ScenarioKind};

/// A family as written: a preset's name (`"transfer-circular"`), a mission file's path, or the
/// whole table.
// Read once per command: the size of the table is of no consequence.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum FamilySpec {
    /// One of the thesis's four distributions by name, or a mission file's path.
    Preset(String),
    /// Every field given.
    Table(FamilyTable),
}

/// A family field by field (docs/missions.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FamilyTable {
    /// `"transfer"` (any point of the target orbit) or `"rendezvous"` (meet the body on it).
    pub problem: ProblemName,
    /// The central body: `"sun"`, `"earth"`, `"mars"`, or its figures.
    pub body: BodySpec,
    /// The departure orbit's ranges.
    pub departure: OrbitSpec,
    /// The target orbit's ranges (its `nu`: the body's anomaly at departure, rendezvous only).
    pub target: OrbitSpec,
    /// `"longer-period"` (the thesis's rule), `{ days = D }` or `{ lo_days = A, hi_days = B }`.
    pub time_of_flight: TimeOfFlightSpec,
    /// `{ days = D }` or `{ count = N }` cycles over each flight.
    pub cycle: CycleSpec,
}

/// The problem, in lower case.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ProblemName {
    /// Free-anomaly transfer.
    Transfer,
    /// Rendezvous.
    Rendezvous,
}

/// A central body by preset name or by its figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum BodySpec {
    /// `"sun"` (lengths in AU), `"earth"` or `"mars"` (lengths in equatorial radii).
    Preset(String),
    /// mu (m^3/s^2) and the length unit (m).
    Figures {
        /// Gravitational parameter, m^3/s^2.
        mu_m3_s2: f64,
        /// Length unit, m.
        length_unit_m: f64,
    },
}

/// One orbit: its ranges (semi-major axis in length units, angles in radians; each a number,
/// fixed, or `[lo, hi]`), or one state on it (`state`; for a rendezvous's target `arrival`, the
/// body's state at the end of a fixed time of flight), which fixes every element.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OrbitSpec {
    /// Semi-major axis, length units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub a: Option<RangeSpec>,
    /// Eccentricity.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub e: Option<RangeSpec>,
    /// Argument of periapsis, rad (default: any, [0, 2 pi]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub omega: Option<RangeSpec>,
    /// True anomaly at departure, rad (default: any, [0, 2 pi]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nu: Option<RangeSpec>,
    /// Inclination of the orbit's plane, rad (default: 0, the reference plane).
    #[serde(default, skip_serializing_if = "RangeSpec::is_none_or_zero")]
    pub inclination: Option<RangeSpec>,
    /// Right ascension of the plane's ascending node, rad (default: 0).
    #[serde(default, skip_serializing_if = "RangeSpec::is_none_or_zero")]
    pub raan: Option<RangeSpec>,
    /// A state on the orbit (the departure's at t = 0; for a transfer's target, any), in the
    /// body's units or km and km/s: every element fixed by it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub state: Option<crate::spatial::StateSpec>,
    /// A rendezvous's target: the body's state at the arrival (the end of a fixed time of
    /// flight, rounded up to whole cycles of a cycle in days), in the body's units or km and km/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arrival: Option<crate::spatial::StateSpec>,
    /// The departure's dispersion: a Gaussian error on each inertial axis of the departure
    /// state (the departure only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dispersion: Option<DispersionSpec>,
}

/// A departure state's dispersion as written: the standard deviation of each position and
/// velocity component, in the body's units (`r`, `v`) or km and km/s (`r_km`, `v_km_s`); a
/// component not given is not dispersed.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DispersionSpec {
    /// Position, length units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub r: Option<f64>,
    /// Position, km.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub r_km: Option<f64>,
    /// Velocity, velocity units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub v: Option<f64>,
    /// Velocity, km/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub v_km_s: Option<f64>,
}

impl DispersionSpec {
    /// The dispersion in the body's units (checked by [`SpatialFamily::validate`]).
    fn dispersion(&self, units: &shared::mission::Units) -> Result<StateDispersion, MissionError> {
        let refuse = |why: &str| MissionError::Orbit {
            field: "departure.dispersion",
            why: why.to_string(),
        };
        let position = match (self.r, self.r_km) {
            (Some(_), Some(_)) => return Err(refuse("give the position's deviation once: r or r_km")),
            (r, km) => r.or(km.map(|x| x * 1e3 / units.length_m)).unwrap_or(0.0),
        };
        let velocity = match (self.v, self.v_km_s) {
            (Some(_), Some(_)) => return Err(refuse("give the velocity's deviation once: v or v_km_s")),
            (v, km_s) => v.or(km_s.map(|x| x * 1e3 / units.velocity_m_s())).unwrap_or(0.0),
        };
        Ok(StateDispersion { position, velocity })
    }

    /// As written back: in the body's units, `None` for no dispersion.
    fn of(dispersion: &StateDispersion) -> Option<Self> {
        (!dispersion.is_none()).then_some(Self {
            r: Some(dispersion.position),
            v: Some(dispersion.velocity),
            ..Self::default()
        })
    }
}

/// A fixed value or a `[lo, hi]` range.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum RangeSpec {
    /// Always this value.
    Fixed(f64),
    /// Uniform over [lo, hi].
    Between([f64; 2]),
}

impl RangeSpec {
    fn full_turn() -> Self {
        Self::Between([0.0, TAU])
    }

    fn zero() -> Self {
        Self::Fixed(0.0)
    }

    fn is_none_or_zero(spec: &Option<Self>) -> bool {
        spec.is_none_or(|s| s.range() == Range { lo: 0.0, hi: 0.0 })
    }

    fn range(self) -> Range {
        match self {
            Self::Fixed(x) => Range { lo: x, hi: x },
            Self::Between([lo, hi]) => Range { lo, hi },
        }
    }

    fn of(range: Range) -> Self {
        if range.lo == range.hi {
            Self::Fixed(range.lo)
        } else {
            Self::Between([range.lo, range.hi])
        }
    }
}

impl OrbitSpec {
    /// The orbit's ranges and its plane's, from its elements or from the state given; `field`
    /// names it in refusals (`departure` or `target`). A rendezvous target's `arrival` needs
    /// `time_of_flight` (the fixed flight as flown, canonical): the body is coasted back from it
    /// to departure.
    fn ranges(
        &self,
        field: &'static str,
        body: &CentralBody,
        time_of_flight: Option<f64>,
        rendezvous_target: bool,
    ) -> Result<(OrbitRanges, PlaneRanges), MissionError> {
        let (state_field, arrival_field) = match field {
            "departure" => ("departure.state", "departure.arrival"),
            _ => ("target.state", "target.arrival"),
        };
        let refuse = |field: &'static str, why: &str| MissionError::Orbit {
            field,
            why: why.to_string(),
        };
        let elements_given = [self.a, self.e, self.omega, self.nu, self.inclination, self.raan]
            .iter()
            .any(Option::is_some);
        let units = body.units();
        let (state, at_arrival, which) = match (&self.state, &self.arrival) {
            (None, None) => {
                let (Some(a), Some(e)) = (self.a, self.e) else {
                    return Err(refuse(
                        field,
                        "give the orbit's elements (a and e at least) or a state on it (state)",
                    ));
                };
                let range = |spec: Option<RangeSpec>, default: fn() -> RangeSpec| spec.unwrap_or_else(default).range();
                return Ok((
                    OrbitRanges {
                        a: a.range(),
                        e: e.range(),
                        omega: range(self.omega, RangeSpec::full_turn),
                        nu: range(self.nu, RangeSpec::full_turn),
                    },
                    PlaneRanges {
                        inclination: range(self.inclination, RangeSpec::zero),
                        raan: range(self.raan, RangeSpec::zero),
                    },
                ));
            }
            (Some(_), Some(_)) => return Err(refuse(state_field, "give a state or an arrival, not both")),
            (Some(state), None) => (state, false, state_field),
            (None, Some(arrival)) => (arrival, true, arrival_field),
        };
        if elements_given {
            return Err(refuse(
                which,
                "a state fixes every element: give the state or the elements, not both",
            ));
        }
        if at_arrival && !rendezvous_target {
            return Err(refuse(
                which,
                "only a rendezvous's target has an arrival state (a transfer's target takes a state on its orbit)",
            ));
        }
        let state = state.state(which, &units).map_err(|e| refuse(which, &e.to_string()))?;
        let (mut elements, plane) = state.elements().ok_or_else(|| {
            refuse(
                which,
                "the state is on no closed orbit (unbound, or its velocity along its radius)",
            )
        })?;
        if at_arrival {
            let Some(tof) = time_of_flight else {
                return Err(refuse(
                    which,
                    "an arrival state needs a fixed time of flight ({ days = D })",
                ));
            };
            // The body's anomaly at departure: its in-plane state coasted back over the flight.
            let start = onboard::kepler::coast(&elements.cartesian(), -tof)
                .map_err(|e| refuse(which, &format!("the body cannot be coasted back to departure: {e:?}")))?;
            elements.nu = start
                .elements()
                .ok_or_else(|| refuse(which, "the body's orbit at departure is not closed"))?
                .nu;
        }
        let fixed = |x: f64| Range { lo: x, hi: x };
        Ok((
            OrbitRanges {
                a: fixed(elements.shape.a),
                e: fixed(elements.shape.e),
                omega: fixed(elements.shape.omega),
                nu: fixed(elements.nu),
            },
            PlaneRanges {
                inclination: fixed(plane.inclination),
                raan: fixed(plane.raan),
            },
        ))
    }
}

/// The time of flight as written.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum TimeOfFlightSpec {
    /// `"longer-period"`.
    Rule(TimeOfFlightRule),
    /// `{ days = D }`.
    Fixed {
        /// Days.
        days: f64,
    },
    /// `{ lo_days = A, hi_days = B }`.
    Drawn {
        /// Shortest, days.
        lo_days: f64,
        /// Longest, days.
        hi_days: f64,
    },
}

/// The thesis's time-of-flight rule by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TimeOfFlightRule {
    /// The longer of the two periods, rounded up to whole cycles.
    LongerPeriod,
}

/// The guidance cycle as written.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum CycleSpec {
    /// `{ days = D }`.
    Days {
        /// Days.
        days: f64,
    },
    /// `{ count = N }` cycles over each flight.
    Count {
        /// Cycles a flight.
        count: u32,
    },
}

/// Why a written family is refused.
#[derive(Debug, thiserror::Error)]
pub enum MissionError {
    /// Not a preset's name.
    #[error("{0:?} is neither a scenario family preset (transfer-circular, transfer-hard, rendezvous-circular, rendezvous-hard) nor a mission file (docs/missions.md)")]
    UnknownPreset(String),
    /// Not a body preset's name.
    #[error("body: unknown central body {0:?}: give sun, earth, mars, or {{ mu_m3_s2 = ..., length_unit_m = ... }}")]
    UnknownBody(String),
    /// A field that cannot be posed.
    #[error("{0}")]
    Field(#[from] FamilyError),
    /// An orbit given by a state that cannot be posed.
    #[error("{field}: {why}")]
    Orbit {
        /// The orbit's field, e.g. `target.arrival`.
        field: &'static str,
        /// Why.
        why: String,
    },
    /// An inclined family given to a command that flies planar families only.
    #[error("family {0} has inclined orbits (inclination or node ranges other than 0): this command takes planar families; `ground data check-mission` and `generate` solve it in three dimensions (and `merge`, `compare`, `demos`, `oem` read its datasets)")]
    Inclined(String),
    /// A mission file that cannot be read.
    #[error("{path}: {why}")]
    File {
        /// The file.
        path: String,
        /// Why it cannot be read.
        why: String,
    },
}

impl FamilySpec {
    /// The family, checked; an inclined family is refused ([`MissionError::Inclined`]).
    pub fn family(&self) -> Result<MissionFamily, MissionError> {
        let spatial = self.spatial_family()?;
        spatial
            .as_planar()
            .ok_or_else(|| MissionError::Inclined(spatial.label().to_string()))
    }

    /// The family in three dimensions, checked: a planar one lies in the reference plane.
    pub fn spatial_family(&self) -> Result<SpatialFamily, MissionError> {
        let family = match self {
            Self::Preset(name) => match name.parse::<ScenarioKind>() {
                Ok(kind) => SpatialFamily::planar(kind.family()),
                Err(_) => match Self::from_argument(name)? {
                    Self::Table(table) => table.spatial_family()?,
                    Self::Preset(_) => return Err(MissionError::UnknownPreset(name.clone())),
                },
            },
            Self::Table(table) => table.spatial_family()?,
        };
        family.validate()?;
        Ok(family)
    }

    /// How a family is written: by its preset's name when it is one.
    pub fn of(family: &MissionFamily) -> Self {
        match family.preset_name() {
            Some(name) => Self::Preset(name.to_string()),
            None => Self::Table(FamilyTable::of(family)),
        }
    }

    /// A preset's name, or else the path of a mission file (TOML, the table at its top level).
    pub fn from_argument(text: &str) -> Result<Self, MissionError> {
        if text.parse::<ScenarioKind>().is_ok() {
            return Ok(Self::Preset(text.to_string()));
        }
        if !Path::new(text).is_file() {
            return Err(MissionError::UnknownPreset(text.to_string()));
        }
        read_mission_file(Path::new(text)).map(Self::Table)
    }
}

/// Reads a mission file: the table of [`FamilyTable`] at the top level.
pub fn read_mission_file(path: &Path) -> Result<FamilyTable, MissionError> {
    let file_error = |why: String| MissionError::File {
        path: path.display().to_string(),
        why,
    };
    let text = std::fs::read_to_string(path).map_err(|e| file_error(e.to_string()))?;
    toml::from_str(&text).map_err(|e| file_error(e.to_string()))
}

impl BodySpec {
    /// The body: a preset by its name, or the figures as given.
    pub fn body(&self) -> Result<CentralBody, MissionError> {
        match self {
            Self::Preset(name) => CentralBody::PRESETS
                .iter()
                .find(|(preset, _)| preset == name)
                .map(|(_, body)| *body)
                .ok_or_else(|| MissionError::UnknownBody(name.clone())),
            Self::Figures {
                mu_m3_s2,
                length_unit_m,
            } => Ok(CentralBody {
                mu_m3_s2: *mu_m3_s2,
                length_unit_m: *length_unit_m,
            }),
        }
    }
}

impl FamilyTable {
    fn spatial_family(&self) -> Result<SpatialFamily, MissionError> {
        let body = self.body.body()?;
        let cycle = match self.cycle {
            CycleSpec::Days { days } => Cycle::Days(days),
            CycleSpec::Count { count } => Cycle::Count(count),
        };
        // A fixed flight as flown: rounded up to whole cycles of a cycle in days.
        let time_of_flight = match (self.time_of_flight, cycle) {
            (TimeOfFlightSpec::Fixed { days }, Cycle::Days(cycle_days)) => {
                let (tof, cycle) = (body.units().days(days), body.units().days(cycle_days));
                Some(f64::from(shared::scenario::Scenario::cycles_covering(tof, cycle)) * cycle)
            }
            (TimeOfFlightSpec::Fixed { days }, Cycle::Count(_)) => Some(body.units().days(days)),
            _ => None,
        };
        let rendezvous = self.problem == ProblemName::Rendezvous;
        let (departure, departure_plane) = self.departure.ranges("departure", &body, None, false)?;
        let (target, target_plane) = self.target.ranges("target", &body, time_of_flight, rendezvous)?;
        if self.target.dispersion.is_some() {
            return Err(MissionError::Orbit {
                field: "target.dispersion",
                why: "only the departure is dispersed (the target is the goal the flight must meet)".to_string(),
            });
        }
        let departure_dispersion = match &self.departure.dispersion {
            Some(spec) => spec.dispersion(&body.units())?,
            None => StateDispersion::NONE,
        };
        Ok(SpatialFamily {
            family: MissionFamily {
                problem: match self.problem {
                    ProblemName::Transfer => ProblemKind::Transfer,
                    ProblemName::Rendezvous => ProblemKind::Rendezvous,
                },
                body,
                departure,
                target,
                time_of_flight: self.time_of_flight(),
                cycle,
            },
            departure_plane,
            target_plane,
            departure_dispersion,
        })
    }

    fn time_of_flight(&self) -> TimeOfFlight {
        match self.time_of_flight {
            TimeOfFlightSpec::Rule(TimeOfFlightRule::LongerPeriod) => TimeOfFlight::LongerPeriod,
            TimeOfFlightSpec::Fixed { days } => TimeOfFlight::Fixed { days },
            TimeOfFlightSpec::Drawn { lo_days, hi_days } => TimeOfFlight::Drawn { lo_days, hi_days },
        }
    }

    /// The table of a family in three dimensions: the planar table with each orbit's plane.
    pub fn of_spatial(family: &SpatialFamily) -> Self {
        let mut table = Self::of(&family.family);
        for (spec, plane) in [
            (&mut table.departure, &family.departure_plane),
            (&mut table.target, &family.target_plane),
        ] {
            spec.inclination = Some(RangeSpec::of(plane.inclination));
            spec.raan = Some(RangeSpec::of(plane.raan));
        }
        table.departure.dispersion = DispersionSpec::of(&family.departure_dispersion);
        table
    }

    /// The table of a family, field by field (bodies that are presets by name).
    pub fn of(family: &MissionFamily) -> Self {
        let orbit = |ranges: &OrbitRanges| OrbitSpec {
            a: Some(RangeSpec::of(ranges.a)),
            e: Some(RangeSpec::of(ranges.e)),
            omega: Some(RangeSpec::of(ranges.omega)),
            nu: Some(RangeSpec::of(ranges.nu)),
            ..OrbitSpec::default()
        };
        Self {
            problem: match family.problem {
                ProblemKind::Transfer => ProblemName::Transfer,
                ProblemKind::Rendezvous => ProblemName::Rendezvous,
            },
            body: match family.body.preset_name() {
                Some(name) => BodySpec::Preset(name.to_string()),
                None => BodySpec::Figures {
                    mu_m3_s2: family.body.mu_m3_s2,
                    length_unit_m: family.body.length_unit_m,
                },
            },
            departure: orbit(&family.departure),
            target: orbit(&family.target),
            time_of_flight: match family.time_of_flight {
                TimeOfFlight::LongerPeriod => TimeOfFlightSpec::Rule(TimeOfFlightRule::LongerPeriod),
                TimeOfFlight::Fixed { days } => TimeOfFlightSpec::Fixed { days },
                TimeOfFlight::Drawn { lo_days, hi_days } => TimeOfFlightSpec::Drawn { lo_days, hi_days },
            },
            cycle: match family.cycle {
                Cycle::Days(days) => CycleSpec::Days { days },
                Cycle::Count(count) => CycleSpec::Count { count },
            },
        }
    }
}

/// A family as files hold it: written as a [`FamilySpec`] in human-readable formats, as the plain
/// structure in binary ones, and checked when read.
pub trait WrittenFamily: Sized + Serialize + serde::de::DeserializeOwned {
    /// How the family is written.
    fn written(&self) -> FamilySpec;
    /// The family a written one gives, checked.
    fn read(spec: &FamilySpec) -> Result<Self, MissionError>;
    /// Checks the family (a binary file's, which carries no spec).
    fn check(&self) -> Result<(), FamilyError>;
}

impl WrittenFamily for MissionFamily {
    fn written(&self) -> FamilySpec {
        FamilySpec::of(self)
    }

    fn read(spec: &FamilySpec) -> Result<Self, MissionError> {
        spec.family()
    }

    fn check(&self) -> Result<(), FamilyError> {
        self.validate()
    }
}

impl WrittenFamily for SpatialFamily {
    fn written(&self) -> FamilySpec {
        match self.as_planar() {
            Some(planar) => FamilySpec::of(&planar),
            None => FamilySpec::Table(FamilyTable::of_spatial(self)),
        }
    }

    fn read(spec: &FamilySpec) -> Result<Self, MissionError> {
        spec.spatial_family()
    }

    fn check(&self) -> Result<(), FamilyError> {
        self.validate()
    }
}

/// `#[serde(with = "...")]` for a family field ([`WrittenFamily`]): written as a [`FamilySpec`]
/// in human-readable formats (JSON, TOML: a preset by name), as the plain structure in binary
/// ones.
pub mod by_spec {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    use super::{FamilySpec, WrittenFamily};

    /// Serializes `family`.
    pub fn serialize<S: Serializer, F: WrittenFamily>(family: &F, serializer: S) -> Result<S::Ok, S::Error> {
        if serializer.is_human_readable() {
            family.written().serialize(serializer)
        } else {
            family.serialize(serializer)
        }
    }

    /// Deserializes a family, checked.
    pub fn deserialize<'de, D: Deserializer<'de>, F: WrittenFamily>(deserializer: D) -> Result<F, D::Error> {
        let family = if deserializer.is_human_readable() {
            F::read(&FamilySpec::deserialize(deserializer)?).map_err(serde::de::Error::custom)?
        } else {
            F::deserialize(deserializer)?
        };
        family.check().map_err(serde::de::Error::custom)?;
        Ok(family)
    }
}

/// What [`check_family`] found on a sample of a family's draws: enough to tell, before hours of
/// work, whether the family can be posed, solved and flown.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FamilyCheck {
    /// The family's label.
    pub family: String,
    /// Whether its orbits are inclined (solved and classified in three dimensions).
    pub inclined: bool,
    /// Canonical units: length (m), time (s), velocity (m/s).
    pub length_unit_m: f64,
    /// Time unit, s.
    pub time_unit_s: f64,
    /// Velocity unit, m/s.
    pub velocity_unit_m_s: f64,
    /// Draws solved.
    pub sample: usize,
    /// Shortest and longest time of flight of the sample, days.
    pub time_of_flight_days: [f64; 2],
    /// Fewest and most guidance cycles of the sample.
    pub cycles: [u32; 2],
    /// Length of a cycle, days: fewest and most (equal unless the cycle is a count).
    pub cycle_days: [f64; 2],
    /// Draws the indirect method solved.
    pub converged: usize,
    /// Unsolved draws whose minimum time of flight exceeds their time of flight.
    pub infeasible: usize,
    /// Unsolved draws shown feasible (a minimum time below their time of flight, or an
    /// energy-optimal solution at it).
    pub feasible_unsolved: usize,
    /// Unsolved draws neither method classified.
    pub unknown: usize,
    /// Mean final mass of the solved draws, fraction of m0.
    pub final_mass_mean: f64,
    /// Mean and longest solve time per draw, s (one thread).
    pub solve_seconds: [f64; 2],
    /// Propellant a flight at full thrust for the longest time of flight of the sample would
    /// burn, fraction of m0: at 1 or more the tank would empty before the flight ends.
    pub full_thrust_propellant: f64,
    /// Warnings: the tank, infeasible or unsolved draws.
    pub warnings: Vec<String>,
}

/// The mission a blob of `family` carries: the aids' cycle (0 for a count of
/// cycles), the family's units and fingerprint.
pub fn blob_mission(family: &SpatialFamily) -> shared::blob::BlobMission {
    let units = family.family.body.units();
    shared::blob::BlobMission {
        cycle: family.family.fixed_cycle().unwrap_or(0.0),
        length_unit_m: units.length_m,
        time_unit_s: units.time_s,
        family: family.fingerprint(),
    }
}

/// Why a blob carrying `mission` cannot fly `family` (None: it can), both named. A blob of
/// fingerprint 0 (made before blobs carried their mission) flies any family of the thesis's
/// units and 14-day cycles.
pub fn blob_refusal(family: &SpatialFamily, mission: &shared::blob::BlobMission) -> Option<String> {
    use shared::blob::BlobMission;
    let ours = blob_mission(family);
    if mission.family == 0 {
        let thesis = BlobMission {
            family: ours.family,
            ..BlobMission::THESIS
        };
        return (thesis != ours).then(|| {
            format!(
                "the blob flies the thesis's 14-day heliocentric cycles (mission fingerprint 0), and family {} has another cycle or body",
                family.label()
            )
        });
    }
    (mission.family != ours.family).then(|| {
        let theirs = ScenarioKind::ALL
            .into_iter()
            .find(|kind| kind.family().fingerprint() == mission.family)
            .map_or_else(
                || format!("custom-{:08x}", mission.family),
                |kind| kind.name().to_string(),
            );
        format!(
            "the blob was trained for family {theirs}, not {}: fly it with its own config",
            family.label()
        )
    })
}

/// The check as the lines the commands print (units, times, the solved share, solve times, the
/// tank, the warnings).
pub fn check_lines(c: &FamilyCheck) -> Vec<String> {
    let mut lines = vec![
        format!(
            "family {}: units {:.6e} m, {:.6e} s, {:.6e} m/s",
            c.family, c.length_unit_m, c.time_unit_s, c.velocity_unit_m_s
        ),
        format!(
            "{} draws: time of flight {:.1} to {:.1} days, {} to {} cycles of {:.3} to {:.3} days",
            c.sample,
            c.time_of_flight_days[0],
            c.time_of_flight_days[1],
            c.cycles[0],
            c.cycles[1],
            c.cycle_days[0],
            c.cycle_days[1]
        ),
        format!(
            "solved {} of {} ({:.0} %), mean final mass {:.4}; unsolved: {} infeasible, {} feasible, {} unclassified",
            c.converged,
            c.sample,
            100.0 * c.converged as f64 / c.sample as f64,
            c.final_mass_mean,
            c.infeasible,
            c.feasible_unsolved,
            c.unknown
        ),
        format!(
            "solve time per draw: mean {:.2} s, longest {:.2} s",
            c.solve_seconds[0], c.solve_seconds[1]
        ),
        format!(
            "full thrust over the longest flight burns {:.3} of the initial mass",
            c.full_thrust_propellant
        ),
    ];
    lines.extend(c.warnings.iter().map(|w| format!("warning: {w}")));
    lines
}

/// Draws `sample` scenarios of `family` (seed `seed`), solves each by the indirect method (the
/// planar one for draws in the reference plane, the three-dimensional one otherwise),
/// classifies the unsolved draws by their minimum time of flight (in the same dimension), and gathers the units,
/// the times and the tank's reach ([`FamilyCheck`]). Parallel over the draws (rayon).
pub fn check_family(
    family: &SpatialFamily,
    spacecraft: &shared::spacecraft::CanonicalSpacecraft,
    sample: u64,
    seed: u64,
    options: &crate::solver::SolveOptions,
) -> FamilyCheck {
    use rayon::prelude::*;

    use crate::solver::min_time::classify_draw;
    use crate::solver::solve_scenario;
    use crate::solver::spatial::min_time::classify_spatial_draw;

    let units = family.family.body.units();
    let solved: Vec<_> = (0..sample)
        .into_par_iter()
        .map(|index| {
            let drawn = family.draw(seed, index);
            let scenario = drawn.scenario;
            if !drawn.is_planar() {
                let record =
                    crate::solver::spatial::record::solve_spatial_draw(family, seed, index, spacecraft, options);
                let outcome = Outcome {
                    final_mass: record.converged.then_some(record.final_mass),
                    seconds: record.seconds,
                };
                let verdict = outcome
                    .final_mass
                    .is_none()
                    .then(|| Verdict::of(&classify_spatial_draw(&drawn, spacecraft, options), &scenario));
                return (scenario, outcome, verdict);
            }
            let record = solve_scenario(family.family, seed, index, &scenario, spacecraft, options);
            let verdict =
                (!record.converged).then(|| Verdict::of(&classify_draw(&scenario, spacecraft, options), &scenario));
            let outcome = Outcome {
                final_mass: record.converged.then_some(record.final_mass),
                seconds: record.seconds,
            };
            (scenario, outcome, verdict)
        })
        .collect();
    let count = |v: Verdict| solved.iter().filter(|(_, _, found)| *found == Some(v)).count();
    let tofs: Vec<f64> = solved.iter().map(|(s, ..)| units.to_days(s.time_of_flight())).collect();
    let cycles: Vec<u32> = solved.iter().map(|(s, ..)| s.steps).collect();
    let cycle_days: Vec<f64> = solved.iter().map(|(s, ..)| units.to_days(s.cycle)).collect();
    let masses: Vec<f64> = solved.iter().filter_map(|(_, r, _)| r.final_mass).collect();
    let seconds: Vec<f64> = solved.iter().map(|(_, r, _)| r.seconds).collect();
    let extent = |v: &[f64]| {
        [
            v.iter().copied().fold(f64::INFINITY, f64::min),
            v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        ]
    };
    let mean = |v: &[f64]| {
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    let longest = solved.iter().map(|(s, ..)| s.time_of_flight()).fold(0.0, f64::max);
    let full_thrust_propellant = spacecraft.thrust * longest / spacecraft.exhaust_speed;
    let mut check = FamilyCheck {
        family: family.label().to_string(),
        inclined: family.as_planar().is_none(),
        length_unit_m: units.length_m,
        time_unit_s: units.time_s,
        velocity_unit_m_s: units.velocity_m_s(),
        sample: solved.len(),
        time_of_flight_days: extent(&tofs),
        cycles: [
            cycles.iter().copied().min().unwrap_or(0),
            cycles.iter().copied().max().unwrap_or(0),
        ],
        cycle_days: extent(&cycle_days),
        converged: masses.len(),
        infeasible: count(Verdict::Infeasible),
        feasible_unsolved: count(Verdict::Feasible),
        unknown: count(Verdict::Unknown),
        final_mass_mean: mean(&masses),
        solve_seconds: [mean(&seconds), extent(&seconds)[1]],
        full_thrust_propellant,
        warnings: Vec::new(),
    };
    if full_thrust_propellant >= 1.0 {
        check.warnings.push(format!(
            "at full thrust the tank empties after {:.0} days, before the longest flight of the sample ({:.0} days) ends",
            units.to_days(spacecraft.exhaust_speed / spacecraft.thrust),
            check.time_of_flight_days[1]
        ));
    }
    if check.infeasible > 0 {
        check.warnings.push(format!(
            "{} of {} draws are infeasible at their time of flight: lengthen it or raise the thrust",
            check.infeasible, check.sample
        ));
    }
    if check.feasible_unsolved + check.unknown > 0 {
        check.warnings.push(format!(
            "{} feasible or unclassified draws were not solved: their demonstrations will be missing",
            check.feasible_unsolved + check.unknown
        ));
    }
    check
}

/// What one draw's solve gave: its final mass when solved, and its time.
struct Outcome {
    final_mass: Option<f64>,
    seconds: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Verdict {
    Infeasible,
    Feasible,
    Unknown,
}

impl Verdict {
    /// An unsolved draw's verdict from its classification, in either dimension.
    fn of<Z, S>(found: &crate::solver::min_time::Feasibility<Z, S>, scenario: &shared::scenario::Scenario) -> Self {
        use crate::solver::min_time::Feasibility;
        match found {
            Feasibility::MinTime { tf_min, .. } if *tf_min > scenario.time_of_flight() => Self::Infeasible,
            Feasibility::Unknown(_) => Self::Unknown,
            _ => Self::Feasible,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const INWARD: &str = r#"
problem = "rendezvous"
body = "sun"
departure = { a = [0.95, 1.05], e = [0.0, 0.02] }
target = { a = [0.70, 0.74], e = [0.0, 0.01] }
time_of_flight = { lo_days = 250.0, hi_days = 400.0 }
cycle = { days = 7.0 }
"#;

    #[test]
    fn a_table_written_field_by_field_like_a_preset_is_that_preset() {
        for kind in ScenarioKind::ALL {
            let table = FamilyTable::of(&kind.family());
            let text = toml::to_string(&table).unwrap();
            let read: FamilyTable = toml::from_str(&text).unwrap();
            let family = FamilySpec::Table(read).family().unwrap();
            assert_eq!(family, kind.family(), "{text}");
            assert_eq!(family.draw(11, 4), kind.draw(11, 4));
            assert_eq!(FamilySpec::of(&family), FamilySpec::Preset(kind.name().into()));
        }
    }

    #[test]
    fn a_mission_file_reads_and_round_trips_through_json() {
        let table: FamilyTable = toml::from_str(INWARD).unwrap();
        let family = FamilySpec::Table(table).family().unwrap();
        assert_eq!(family.problem, ProblemKind::Rendezvous);
        assert_eq!(family.cycle, Cycle::Days(7.0));
        assert_eq!(family.departure.omega, Range { lo: 0.0, hi: TAU });
        #[derive(Serialize, Deserialize)]
        struct Holder {
            #[serde(with = "by_spec")]
            family: MissionFamily,
        }
        let json = serde_json::to_string(&Holder { family }).unwrap();
        let back: Holder = serde_json::from_str(&json).unwrap();
        assert_eq!(back.family, family);
        let preset = serde_json::to_string(&Holder {
            family: ScenarioKind::TransferHard.family(),
        })
        .unwrap();
        assert_eq!(preset, r#"{"family":"transfer-hard"}"#);
        let binary = postcard::to_stdvec(&Holder { family }).unwrap();
        assert_eq!(postcard::from_bytes::<Holder>(&binary).unwrap().family, family);
    }

    #[test]
    fn an_inclined_table_is_a_spatial_family_and_planar_commands_refuse_it() {
        let text = INWARD.replace(
            "target = { a = [0.70, 0.74], e = [0.0, 0.01] }",
            "target = { a = [0.70, 0.74], e = [0.0, 0.01], inclination = [0.0, 0.06], raan = [0.0, 6.283185307179586] }",
        );
        let table: FamilyTable = toml::from_str(&text).unwrap();
        let spatial = FamilySpec::Table(table.clone()).spatial_family().unwrap();
        assert_eq!(spatial.target_plane.inclination, Range { lo: 0.0, hi: 0.06 });
        assert_eq!(spatial.target_plane.raan, Range { lo: 0.0, hi: TAU });
        assert_eq!(spatial.departure_plane, PlaneRanges::REFERENCE);
        let planar: FamilyTable = toml::from_str(INWARD).unwrap();
        assert_eq!(spatial.family, FamilySpec::Table(planar.clone()).family().unwrap());
        let refusal = FamilySpec::Table(table).family().unwrap_err();
        assert!(matches!(refusal, MissionError::Inclined(ref label) if label.starts_with("custom-")));
        // A planar table is its own spatial family, and its written form has no plane fields.
        let flat = FamilySpec::Table(planar).spatial_family().unwrap();
        assert_eq!(flat.as_planar(), Some(flat.family));
        assert!(!toml::to_string(&FamilyTable::of(&flat.family))
            .unwrap()
            .contains("inclination"));
        let bad = text.replace("inclination = [0.0, 0.06]", "inclination = [0.0, 4.0]");
        let table: FamilyTable = toml::from_str(&bad).unwrap();
        let refusal = FamilySpec::Table(table).spatial_family().unwrap_err().to_string();
        assert!(refusal.starts_with("target.inclination:"), "{refusal}");
    }

    #[test]
    fn a_dispersed_departure_reads_in_km_writes_back_in_body_units_and_only_the_departure_takes_one() {
        let dispersed = |dispersion: &str| {
            INWARD.replace(
                "departure = { a = [0.95, 1.05], e = [0.0, 0.02] }",
                &format!("departure = {{ a = [0.95, 1.05], e = [0.0, 0.02], dispersion = {dispersion} }}"),
            )
        };
        let text = dispersed("{ r_km = 1.0, v_km_s = 0.05 }");
        let table: FamilyTable = toml::from_str(&text).unwrap();
        let family = FamilySpec::Table(table.clone()).spatial_family().unwrap();
        let units = family.family.body.units();
        let sigma = family.departure_dispersion;
        assert!((sigma.position * units.length_m - 1e3).abs() < 1e-9, "{sigma:?}");
        assert!((sigma.velocity * units.velocity_m_s() - 50.0).abs() < 1e-9, "{sigma:?}");
        // A dispersed departure leaves the plane: planar commands refuse it.
        assert!(matches!(
            FamilySpec::Table(table).family(),
            Err(MissionError::Inclined(_))
        ));
        // Written back (in the body's units) it reads as the same family, fingerprint and all.
        let written = toml::to_string(&FamilyTable::of_spatial(&family)).unwrap();
        let back: FamilyTable = toml::from_str(&written).unwrap();
        let back = FamilySpec::Table(back).spatial_family().unwrap();
        assert_eq!(back, family, "{written}");
        assert_eq!(back.fingerprint(), family.fingerprint());
        let refusal = |text: &str| {
            let table: FamilyTable = toml::from_str(text).unwrap();
            FamilySpec::Table(table).spatial_family().unwrap_err().to_string()
        };
        let twice = refusal(&dispersed("{ r = 1e-8, r_km = 1.0 }"));
        assert!(twice.starts_with("departure.dispersion:"), "{twice}");
        let too_wide = refusal(&dispersed("{ v = 0.5 }"));
        assert!(too_wide.starts_with("departure.dispersion.v:"), "{too_wide}");
        let target = refusal(&INWARD.replace(
            "target = { a = [0.70, 0.74], e = [0.0, 0.01] }",
            "target = { a = [0.70, 0.74], e = [0.0, 0.01], dispersion = { r = 1e-8 } }",
        ));
        assert!(target.starts_with("target.dispersion:"), "{target}");
    }

    #[test]
    fn bad_tables_are_refused_with_the_field() {
        let refusal = |edit: &str| {
            let text = INWARD.replace("e = [0.0, 0.01]", edit);
            match toml::from_str::<FamilyTable>(&text) {
                Ok(table) => FamilySpec::Table(table).family().unwrap_err().to_string(),
                Err(e) => e.to_string(),
            }
        };
        assert!(
            refusal("e = [0.0, 1.2]").starts_with("target.e:"),
            "{}",
            refusal("e = [0.0, 1.2]")
        );
        assert!(refusal("e = [0.3, 0.1]").contains("target.e: lo > hi"));
        assert!(refusal("e = 0.0, color = 3").contains("unknown field"));
        let body = INWARD.replace("\"sun\"", "\"pluto\"");
        let table: FamilyTable = toml::from_str(&body).unwrap();
        assert!(FamilySpec::Table(table)
            .family()
            .unwrap_err()
            .to_string()
            .contains("pluto"));
        assert!(matches!(
            FamilySpec::Preset("transfer-easy".into()).family(),
            Err(MissionError::UnknownPreset(_))
        ));
    }
}
