//! CCSDS Orbit Ephemeris Message (OEM) export of trajectory records (CCSDS 502.0-B-3, KVN text).
//!
//! # What is written
//! One OEM with one segment: `CCSDS_OEM_VERS = 2.0`, a header (comments, `CREATION_DATE` in UTC,
//! `ORIGINATOR`), one metadata block and one data line `epoch x y z vx vy vz` (km, km/s) per
//! ephemeris sample of the record (the thesis's 100 epochs). Version 2.0 is declared because
//! every keyword used here has the same meaning in OEM 2.0 and 3.0 (502.0-B-3 only added
//! optional header keywords we do not write) and 2.0 is the version every OEM reader in use
//! accepts (GMAT, FreeFlyer, STK and Orekit; Orekit also reads 3.0).
//!
//! # Frame: EME2000 centred on the Sun
//! The solutions live in the ecliptic plane of J2000, Sun-centred, with the planar x axis on the
//! J2000 mean equinox. An ecliptic frame is not among the ODM reference-frame values (ODM 2.0
//! annex A: EME2000, GCRF, GRC, ICRF, ITRF*, MCI, TDR, TEME, TOD; 502.0-B-3 defers to the SANA
//! registry) and the readers that matter refuse it: Orekit's `CelestialBodyFrame` has no
//! ecliptic entry, and STK's CCSDS frames for the Sun are EME2000, ICRF and Fixed. EME2000 is
//! the value every OEM reader accepts. So the planar state (z = 0) is rotated about +X by the
//! J2000 obliquity epsilon = 84381.448 arcsec into the mean equator and equinox of J2000 and
//! written with `REF_FRAME = EME2000`, `CENTER_NAME = SUN` (Orekit translates the frame to the
//! named centre). This is SPICE's `ECLIPJ2000 -> J2000` rotation (and GMAT's MJ2000Ec to
//! MJ2000Eq axes), so a user recovers the planar solution by rotating back. EME2000 rather than
//! ICRF because the obliquity 84381.448" is defined against the J2000 mean equator (ICRF
//! differs by the ~20 mas frame bias). The metadata comments say this in the file itself.
//!
//! # Other centres
//! A family around the Earth or Mars is solved in the planet's equatorial plane and written as
//! solved, without rotation ([`OemCentre`]): `CENTER_NAME = EARTH` with `REF_FRAME = EME2000`
//! (the J2000 mean equator and equinox), `CENTER_NAME = MARS` with `REF_FRAME = MCI` (Mars
//! Centred Inertial: the Mars equator, x on its ascending node on the ICRF equator; ODM annex A
//! and Orekit's `CelestialBodyFrame.MCI`). Lengths and times follow the family's units. A body
//! given only by its mu and length unit has no OEM name and is refused.
//!
//! # Time
//! `TIME_SYSTEM = TDB`: the canonical time of the dynamics is a dynamical time. The departure epoch
//! is a TDB calendar epoch given by the caller; sample `k` is at departure + t_k times the
//! family's time unit (`TIME_UNIT_S` around the Sun).
//! TDB has no leap seconds, so the calendar arithmetic is plain 86,400-s days: hifitime's
//! Gregorian calendar on TDB epochs, kept to the nanosecond ([`CalendarEpoch`], which parses and
//! formats the CCSDS text and rounds to the microsecond itself). Epochs are written to the
//! microsecond.
//!
//! # Thrust profile
//! OEM data lines carry no mass or thrust, so the profile goes alongside, twice, from one source
//! ([`thrust_rows`]): as `COMMENT THRUST ...` lines at the head of the data section (the only
//! place OEM allows comments there; one per state, same epochs) and as a companion CSV
//! ([`write_thrust_csv`], header [`THRUST_CSV_HEADER`]). Thrust directions are unit vectors in
//! the same EME2000 axes as the states; thrust = throttle * Tmax; mass in kg.
//!
//! # Why not the `ccsds-ndm` crate
//! `ccsds-ndm` 0.0.9 parses and writes OEM KVN and it builds here, but it is not used to write:
//! it depends on `fast-float` 0.2, which has open soundness advisories (RUSTSEC-2024-0379,
//! RUSTSEC-2025-0003) and no maintainer; it is a 0.0.x API; it needs rustc 1.88 (via `bon`);
//! and it does no epoch arithmetic, so a calendar (hifitime here) would be needed anyway. Its parser
//! also accepts any `REF_FRAME` and epochs outside START/STOP or out of order, which the strict
//! reader here refuses. It is used in the tests as an independent parser of what is written.
//!
//! Writing files is the caller's job: [`write_oem`] and [`write_thrust_csv`] validate the whole
//! record first and write nothing when they refuse it.

use std::fmt::{self, Write as _};
use std::io::Write;

use hifitime::{Duration, Epoch, TimeScale, Unit};
use shared::mission::CentralBody;
use shared::spacecraft::{Spacecraft, SpacecraftError};
use shared::units::{AU_M, TIME_UNIT_S, VELOCITY_UNIT_M_S};

use crate::generate::DatasetRecord;
use crate::solver::record::TrajectoryRecord;
use crate::solver::spatial::record::SpatialRecord;

/// One sample as the OEM writes it: inertial state and control in the dynamics' axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OemSample {
    /// Time since departure, t*.
    pub t: f64,
    /// Position, length units.
    pub r: [f64; 3],
    /// Velocity, velocity units.
    pub v: [f64; 3],
    /// Mass, fraction of m0.
    pub m: f64,
    /// Throttle in [0, 1].
    pub throttle: f64,
    /// Unit thrust direction.
    pub direction: [f64; 3],
}

/// What the OEM writer reads of a record beyond its figures ([`DatasetRecord::figures`]):
/// planar ([`TrajectoryRecord`], z = 0) or three-dimensional ([`SpatialRecord`]).
pub trait OemSource: DatasetRecord {
    /// The family's central body.
    fn body(&self) -> CentralBody;
    /// The family's label.
    fn family_label(&self) -> String;
    /// Seed of the draw.
    fn seed(&self) -> u64;
    /// The ephemeris samples.
    fn samples(&self) -> Vec<OemSample>;
}

impl OemSource for TrajectoryRecord {
    fn body(&self) -> CentralBody {
        self.family.body
    }

    fn family_label(&self) -> String {
        self.family.label().to_string()
    }

    fn seed(&self) -> u64 {
        self.seed
    }

    fn samples(&self) -> Vec<OemSample> {
        let z = |p: [f64; 2]| [p[0], p[1], 0.0];
        self.ephemeris
            .iter()
            .map(|s| OemSample {
                t: s.t,
                r: z(s.r),
                v: z(s.v),
                m: s.m,
                throttle: s.throttle,
                direction: z(s.direction),
            })
            .collect()
    }
}

impl OemSource for SpatialRecord {
    fn body(&self) -> CentralBody {
        self.family.family.body
    }

    fn family_label(&self) -> String {
        self.family.label().to_string()
    }

    fn seed(&self) -> u64 {
        self.seed
    }

    fn samples(&self) -> Vec<OemSample> {
        self.ephemeris
            .iter()
            .map(|s| OemSample {
                t: s.t,
                r: s.state.r,
                v: s.state.v,
                m: s.m,
                throttle: s.throttle,
                direction: s.direction,
            })
            .collect()
    }
}

/// `CCSDS_OEM_VERS` written.
pub const OEM_VERSION: &str = "2.0";
/// `CENTER_NAME` written.
pub const CENTER_NAME: &str = "SUN";
/// `REF_FRAME` written (see the module documentation for why).
pub const REF_FRAME: &str = "EME2000";
/// `TIME_SYSTEM` written.
pub const TIME_SYSTEM: &str = "TDB";
/// `INTERPOLATION` written.
pub const INTERPOLATION: &str = "HERMITE";
/// `INTERPOLATION_DEGREE` written. A low degree: switching thrust makes the acceleration
/// discontinuous, and high-degree polynomials ring across a switch.
pub const INTERPOLATION_DEGREE: u32 = 5;
/// Obliquity of the ecliptic at J2000 (IAU 1976), arcseconds: the rotation from the J2000
/// ecliptic to EME2000.
pub const OBLIQUITY_J2000_ARCSEC: f64 = 84_381.448;
/// Obliquity of the ecliptic at J2000, radians.
pub const OBLIQUITY_J2000_RAD: f64 = OBLIQUITY_J2000_ARCSEC / 3600.0 * (std::f64::consts::PI / 180.0);
/// Header row of the companion thrust CSV.
pub const THRUST_CSV_HEADER: &str = "epoch_iso,t_days,mass_kg,throttle,thrust_N,dir_x,dir_y,dir_z";
/// First word of the data-section comments that carry the thrust profile.
pub const THRUST_COMMENT_TAG: &str = "THRUST";
/// Longest KVN line the CCSDS ODM allows.
pub const MAX_LINE_LENGTH: usize = 254;

const KM_PER_AU: f64 = AU_M / 1000.0;
const KM_S_PER_VELOCITY_UNIT: f64 = VELOCITY_UNIT_M_S / 1000.0;

/// Where a family's trajectories are written: the OEM's centre and frame, the family's units in
/// km, km/s and s, and how the plane of the dynamics sits in the frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OemCentre {
    /// `CENTER_NAME`.
    pub center_name: &'static str,
    /// `REF_FRAME`.
    pub ref_frame: &'static str,
    /// km per canonical length unit.
    pub km_per_length: f64,
    /// km/s per canonical velocity unit.
    pub km_s_per_velocity: f64,
    /// s per canonical time unit.
    pub time_unit_s: f64,
    /// The plane of the dynamics is the J2000 ecliptic, rotated into EME2000 by the obliquity
    /// (the Sun); otherwise it is the frame's own x-y plane (a planet's equator).
    pub ecliptic: bool,
    /// Metadata comments that say so in the file.
    pub comments: [&'static str; 3],
}

impl OemCentre {
    /// The Sun: the J2000 ecliptic rotated into EME2000 (the module documentation says why).
    pub const SUN: Self = Self {
        center_name: CENTER_NAME,
        ref_frame: REF_FRAME,
        km_per_length: KM_PER_AU,
        km_s_per_velocity: KM_S_PER_VELOCITY_UNIT,
        time_unit_s: TIME_UNIT_S,
        ecliptic: true,
        comments: [
            "Sun point-mass dynamics solved in J2000 ecliptic axes (x axis on the J2000 mean",
            "equinox), rotated into EME2000 about +X by the J2000 obliquity 84381.448 arcsec (as SPICE",
            "ECLIPJ2000 -> J2000); rotated back, a planar solution lies in the ecliptic (z = 0).",
        ],
    };

    /// The centre of a family around `body`: the Sun, the Earth (its J2000 mean equator: EME2000
    /// as solved) or Mars (its equator: MCI, Mars Centred Inertial, as solved); a body given by
    /// its mu and length unit has no name to write.
    pub fn of(body: &CentralBody, family: &str) -> Result<Self, OemError> {
        let planet = |center_name, ref_frame, comments, body: &CentralBody| {
            let units = body.units();
            Self {
                center_name,
                ref_frame,
                km_per_length: units.length_m / 1000.0,
                km_s_per_velocity: units.velocity_m_s() / 1000.0,
                time_unit_s: units.time_s,
                ecliptic: false,
                comments,
            }
        };
        match *body {
            b if b == CentralBody::SUN => Ok(Self::SUN),
            b if b == CentralBody::EARTH => Ok(planet(
                "EARTH",
                "EME2000",
                [
                    "Earth point-mass dynamics solved about the J2000 mean equator (x axis on the J2000",
                    "mean equinox), written in EME2000 as solved: a planar solution lies in the equator",
                    "(z = 0), a three-dimensional one leaves it.",
                ],
                &b,
            )),
            b if b == CentralBody::MARS => Ok(planet(
                "MARS",
                "MCI",
                [
                    "Mars point-mass dynamics solved about the Mars equator (x axis on its ascending",
                    "node on the ICRF equator), written in MCI (Mars Centred Inertial) as solved: a",
                    "planar solution lies in the equator (z = 0), a three-dimensional one leaves it.",
                ],
                &b,
            )),
            _ => Err(OemError::UnnamedCentre(family.to_string())),
        }
    }

    /// The centre of a record's family.
    pub fn of_record(record: &impl OemSource) -> Result<Self, OemError> {
        Self::of(&record.body(), &record.family_label())
    }

    /// A vector of the dynamics in the frame's axes.
    pub fn to_frame(&self, v: [f64; 3]) -> [f64; 3] {
        if self.ecliptic {
            ecliptic_to_eme2000(v)
        } else {
            v
        }
    }

    /// A vector in the frame's axes back in the axes of the dynamics.
    pub fn from_frame(&self, v: [f64; 3]) -> [f64; 3] {
        if self.ecliptic {
            eme2000_to_ecliptic(v)
        } else {
            v
        }
    }
}
/// Longest value accepted for OBJECT_NAME, OBJECT_ID and ORIGINATOR.
const MAX_NAME_LENGTH: usize = 80;

/// Why a record could not be exported, or an OEM text could not be read.
#[derive(Debug, thiserror::Error)]
pub enum OemError {
    /// The record's family goes around a body given by its mu and length unit: an OEM names
    /// its centre, and only the Sun, the Earth and Mars have names here.
    #[error(
        "an OEM names its centre: family {0} goes around a body given by mu and a length unit; the export writes Sun-, Earth- and Mars-centred families"
    )]
    UnnamedCentre(String),
    /// The record's solve did not converge; its samples are not a trajectory.
    #[error(fmt = fmt_not_converged)]
    NotConverged {
        /// The record's failure reason, if it has one.
        failure: Option<String>,
    },
    /// The record has no ephemeris samples.
    #[error("refusing to export a trajectory with no ephemeris samples")]
    NoSamples,
    /// Sample `index` has a NaN or infinite `field`.
    #[error("ephemeris sample {index}: {field} is not finite")]
    NonFinite {
        /// Position of the sample in the ephemeris.
        index: usize,
        /// Which quantity: time, position, velocity, mass, throttle or thrust direction.
        field: &'static str,
    },
    /// Sample `index` is not later than the one before it.
    #[error("ephemeris sample {index}: time is not later than the previous sample's")]
    TimeNotIncreasing {
        /// Position of the sample in the ephemeris.
        index: usize,
    },
    /// Sample `index` is finite but not physical (mass <= 0, throttle outside [0, 1]).
    #[error("ephemeris sample {index}: {reason}")]
    InvalidSample {
        /// Position of the sample in the ephemeris.
        index: usize,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// The spacecraft description is unusable.
    #[error("spacecraft: {0}")]
    Spacecraft(SpacecraftError),
    /// An option is not a valid OEM value.
    #[error("OEM option {field}: {reason}")]
    InvalidOption {
        /// The OEM keyword of the option (`"record"` when a written line would be too long).
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// A calendar epoch is malformed or out of range.
    #[error("epoch: {0}")]
    Epoch(String),
    /// The OEM text breaks the standard or departs from what [`write_oem`] writes.
    #[error("OEM line {line}: {message}")]
    Parse {
        /// 1-based line of the text; 0 for the thrust profile of [`OemEphemeris::thrust_profile`].
        line: usize,
        /// What is wrong there.
        message: String,
    },
    /// Writing to the output failed.
    #[error("writing OEM output: {0}")]
    Io(#[source] std::io::Error),
}

fn fmt_not_converged(failure: &Option<String>, f: &mut fmt::Formatter<'_>) -> fmt::Result {
    match failure {
        Some(why) => write!(f, "refusing to export an unconverged trajectory ({why})"),
        None => f.write_str("refusing to export an unconverged trajectory"),
    }
}

impl From<std::io::Error> for OemError {
    fn from(e: std::io::Error) -> Self {
        Self::Io(e)
    }
}

/// The time scale of every [`CalendarEpoch`]'s hifitime epoch. Only calendar readings and
/// differences are asked of it, never a conversion to another scale, so a UTC reading kept in it
/// (the creation date) stays the same reading.
const SCALE: TimeScale = TimeScale::TDB;

/// A calendar epoch in a uniform time scale (no leap seconds: TDB for ephemerides; the UTC
/// creation date is taken as its calendar reading), to the nanosecond, years 1 to 9999.
/// Displayed as ISO 8601 / CCSDS `YYYY-MM-DDThh:mm:ss.ffffff` (rounded to the microsecond).
///
/// The calendar arithmetic is hifitime's ([`Epoch`] in TDB); equality, order and hashing are
/// those of the exact nanosecond count since J2000 (hifitime's own `Ord` and `Hash` go through
/// TAI, which for TDB means its periodic TDB - TT series in floating point).
#[derive(Debug, Clone, Copy)]
pub struct CalendarEpoch {
    epoch: Epoch,
}

impl CalendarEpoch {
    /// J2000.0 as a TDB epoch, 2000-01-01T12:00:00 (hifitime's TDB reference epoch).
    pub const J2000: Self = Self {
        epoch: Epoch::from_duration(Duration::ZERO, SCALE),
    };

    /// An epoch from its calendar reading; `second` in [0, 60).
    pub fn from_calendar(
        year: i32,
        month: u32,
        day: u32,
        hour: u32,
        minute: u32,
        second: f64,
    ) -> Result<Self, OemError> {
        if !(1..=9999).contains(&year) {
            return Err(OemError::Epoch(format!("year {year} outside 1..=9999")));
        }
        let midnight = u8::try_from(month)
            .ok()
            .zip(u8::try_from(day).ok())
            .and_then(|(m, d)| Epoch::maybe_from_gregorian(year, m, d, 0, 0, 0, 0, SCALE).ok())
            .ok_or_else(|| OemError::Epoch(format!("no day {year:04}-{month:02}-{day:02}")))?;
        if hour > 23 || minute > 59 || !(0.0..60.0).contains(&second) {
            return Err(OemError::Epoch(format!(
                "no time of day {hour:02}:{minute:02}:{second}"
            )));
        }
        // Below 60 s, so the rounded product is far inside i128.
        let fraction = Duration::from_total_nanoseconds((second * 1e9).round() as i128);
        Self::checked(midnight + Unit::Hour * i64::from(hour) + Unit::Minute * i64::from(minute) + fraction)
    }

    /// The UTC calendar reading of a Unix time (seconds since 1970-01-01T00:00:00 UTC).
    pub fn from_unix_seconds(seconds: f64) -> Result<Self, OemError> {
        if !seconds.is_finite() {
            return Err(OemError::Epoch(format!("Unix time {seconds} is not finite")));
        }
        Self::checked(unix_origin() + Duration::from_total_nanoseconds((seconds * 1e9).round() as i128))
    }

    /// The current UTC calendar reading of the system clock (for `CREATION_DATE`).
    pub fn now_utc() -> Self {
        let since = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        Self {
            epoch: unix_origin() + Duration::from_total_nanoseconds(since.as_nanos() as i128),
        }
    }

    /// This epoch plus `seconds` (rounded to the nanosecond).
    pub fn plus_seconds(self, seconds: f64) -> Result<Self, OemError> {
        if !seconds.is_finite() || seconds.abs() > 1e12 {
            return Err(OemError::Epoch(format!(
                "time offset {seconds} s is not finite or out of range"
            )));
        }
        Self::checked(self.epoch + Duration::from_total_nanoseconds((seconds * 1e9).round() as i128))
    }

    /// Seconds from `earlier` to this epoch.
    pub fn seconds_since(self, earlier: Self) -> f64 {
        (self.nanos() - earlier.nanos()) as f64 * 1e-9
    }

    /// Parses `YYYY-MM-DDThh:mm:ss` with an optional fraction of 1 to 9 digits (what
    /// [`fmt::Display`] writes; no time-zone suffix, no day-of-year form).
    pub fn parse(text: &str) -> Result<Self, OemError> {
        let bad = || OemError::Epoch(format!("'{text}' is not YYYY-MM-DDThh:mm:ss[.f]"));
        let b = text.as_bytes();
        if b.len() < 19 || b[4] != b'-' || b[7] != b'-' || b[10] != b'T' || b[13] != b':' || b[16] != b':' {
            return Err(bad());
        }
        let digits = |range: std::ops::Range<usize>| -> Result<u32, OemError> {
            let part = &b[range];
            if part.iter().all(u8::is_ascii_digit) {
                Ok(part.iter().fold(0, |acc, d| acc * 10 + u32::from(d - b'0')))
            } else {
                Err(bad())
            }
        };
        let (year, month, day) = (digits(0..4)?, digits(5..7)?, digits(8..10)?);
        let (hour, minute, second) = (digits(11..13)?, digits(14..16)?, digits(17..19)?);
        let mut fraction_nanos = 0i128;
        if b.len() > 19 {
            let fraction = &b[20..];
            if b[19] != b'.' || fraction.is_empty() || fraction.len() > 9 || !fraction.iter().all(u8::is_ascii_digit) {
                return Err(bad());
            }
            let value = fraction.iter().fold(0i128, |acc, d| acc * 10 + i128::from(d - b'0'));
            fraction_nanos = value * 10i128.pow(9 - fraction.len() as u32);
        }
        let whole = Self::from_calendar(year as i32, month, day, hour, minute, f64::from(second))?;
        Self::checked(whole.epoch + Duration::from_total_nanoseconds(fraction_nanos))
    }

    /// Nanoseconds since J2000 (exact: the epoch is in [`SCALE`], no conversion).
    fn nanos(self) -> i128 {
        self.epoch.to_duration_in_time_scale(SCALE).total_nanoseconds()
    }

    fn checked(epoch: Epoch) -> Result<Self, OemError> {
        let (year, ..) = epoch.to_gregorian(SCALE);
        if (1..=9999).contains(&year) {
            Ok(Self { epoch })
        } else {
            Err(OemError::Epoch("outside years 1..=9999".into()))
        }
    }
}

/// 1970-01-01T00:00:00 read in [`SCALE`]: where the calendar reading of Unix time starts.
fn unix_origin() -> Epoch {
    Epoch::from_gregorian_at_midnight(1970, 1, 1, SCALE)
}

impl PartialEq for CalendarEpoch {
    fn eq(&self, other: &Self) -> bool {
        self.nanos() == other.nanos()
    }
}

impl Eq for CalendarEpoch {}

impl PartialOrd for CalendarEpoch {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for CalendarEpoch {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.nanos().cmp(&other.nanos())
    }
}

impl std::hash::Hash for CalendarEpoch {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.nanos().hash(state);
    }
}

impl fmt::Display for CalendarEpoch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Round to the microsecond first so a carry propagates into seconds, days and years.
        // By hand: hifitime's `Duration::round` truncates below its reference epoch (J2000 for
        // TDB). J2000 is a whole second, so rounding its offset rounds the time of day.
        let micros = (self.nanos() + 500).div_euclid(1000);
        let rounded = Epoch::from_duration(Duration::from_total_nanoseconds(micros * 1000), SCALE);
        let (year, month, day, hour, minute, second, nanos) = rounded.to_gregorian(SCALE);
        write!(
            f,
            "{year:04}-{month:02}-{day:02}T{hour:02}:{minute:02}:{second:02}.{:06}",
            nanos / 1000
        )
    }
}

impl std::str::FromStr for CalendarEpoch {
    type Err = OemError;
    fn from_str(text: &str) -> Result<Self, OemError> {
        Self::parse(text)
    }
}

/// Rotates a vector from the J2000 ecliptic to EME2000 (about +X by the J2000 obliquity).
pub fn ecliptic_to_eme2000(v: [f64; 3]) -> [f64; 3] {
    let (s, c) = OBLIQUITY_J2000_RAD.sin_cos();
    [v[0], c * v[1] - s * v[2], s * v[1] + c * v[2]]
}

/// Rotates a vector from EME2000 to the J2000 ecliptic (inverse of [`ecliptic_to_eme2000`]).
pub fn eme2000_to_ecliptic(v: [f64; 3]) -> [f64; 3] {
    let (s, c) = OBLIQUITY_J2000_RAD.sin_cos();
    [v[0], c * v[1] + s * v[2], -s * v[1] + c * v[2]]
}

/// Export options: who and what the OEM describes, and when the flight starts.
#[derive(Debug, Clone, PartialEq)]
pub struct OemOptions {
    /// `OBJECT_NAME`, e.g. `MSR ERO`.
    pub object_name: String,
    /// `OBJECT_ID`: the international designator, or `UNKNOWN` (CCSDS recommendation) when the
    /// spacecraft has none.
    pub object_id: String,
    /// `ORIGINATOR`: creating agency or operator.
    pub originator: String,
    /// TDB epoch of t = 0 (departure).
    pub departure_epoch: CalendarEpoch,
    /// `CREATION_DATE`, UTC.
    pub creation_date: CalendarEpoch,
    /// Spacecraft the record was solved for (thrust and mass in SI).
    pub spacecraft: Spacecraft,
}

impl OemOptions {
    /// Options with the default spacecraft, `OBJECT_ID = UNKNOWN` and the current UTC time as
    /// the creation date.
    pub fn new(departure_epoch: CalendarEpoch) -> Self {
        Self {
            object_name: "LOWTHRUST SPACECRAFT".into(),
            object_id: "UNKNOWN".into(),
            originator: "LOWTHRUST-GROUND".into(),
            departure_epoch,
            creation_date: CalendarEpoch::now_utc(),
            spacecraft: Spacecraft::default(),
        }
    }

    fn validate(&self) -> Result<(), OemError> {
        for (field, value) in [
            ("OBJECT_NAME", &self.object_name),
            ("OBJECT_ID", &self.object_id),
            ("ORIGINATOR", &self.originator),
        ] {
            let reason = if value.trim().is_empty() {
                Some("must not be empty".to_string())
            } else if value.len() > MAX_NAME_LENGTH {
                Some(format!("longer than {MAX_NAME_LENGTH} characters"))
            } else if value.trim() != value.as_str() {
                Some("has leading or trailing white space".into())
            } else if !value.bytes().all(|b| (b' '..=b'~').contains(&b)) {
                Some("must be printable ASCII on one line".into())
            } else {
                None
            };
            if let Some(reason) = reason {
                return Err(OemError::InvalidOption { field, reason });
            }
        }
        self.spacecraft.canonical().map_err(OemError::Spacecraft)?;
        Ok(())
    }
}

/// One row of the thrust profile (CSV row / `COMMENT THRUST` line).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThrustRow {
    /// TDB epoch.
    pub epoch: CalendarEpoch,
    /// Days since departure.
    pub t_days: f64,
    /// Spacecraft mass, kg.
    pub mass_kg: f64,
    /// Throttle u in [0, 1].
    pub throttle: f64,
    /// u * Tmax, newtons.
    pub thrust_n: f64,
    /// Unit thrust direction in EME2000 (zero when the primer vector vanishes).
    pub direction: [f64; 3],
}

impl ThrustRow {
    /// The row's fields after the epoch, formatted with fixed precision (finite values only).
    fn fields(&self) -> [String; 7] {
        [
            fixed(self.t_days, 9),
            fixed(self.mass_kg, 6),
            fixed(self.throttle, 12),
            fixed(self.thrust_n, 12),
            fixed(self.direction[0], 12),
            fixed(self.direction[1], 12),
            fixed(self.direction[2], 12),
        ]
    }

    fn parse_fields(epoch: CalendarEpoch, fields: &[&str]) -> Option<Self> {
        let mut values = [0.0; 7];
        if fields.len() != values.len() {
            return None;
        }
        for (value, text) in values.iter_mut().zip(fields) {
            *value = parse_finite(text)?;
        }
        Some(Self {
            epoch,
            t_days: values[0],
            mass_kg: values[1],
            throttle: values[2],
            thrust_n: values[3],
            direction: [values[4], values[5], values[6]],
        })
    }
}

/// One state of the ephemeris as written: EME2000, Sun-centred.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OemState {
    /// TDB epoch.
    pub epoch: CalendarEpoch,
    /// Position (x, y, z), km.
    pub position_km: [f64; 3],
    /// Velocity (vx, vy, vz), km/s.
    pub velocity_km_s: [f64; 3],
}

impl OemState {
    /// The state back in canonical units and J2000 ecliptic axes: (r in AU, v in AU/t*).
    pub fn canonical_ecliptic(&self) -> ([f64; 3], [f64; 3]) {
        self.canonical_in(&OemCentre::SUN)
    }

    /// The state back in `centre`'s canonical units and the axes of its dynamics.
    pub fn canonical_in(&self, centre: &OemCentre) -> ([f64; 3], [f64; 3]) {
        let r = centre.from_frame(self.position_km).map(|x| x / centre.km_per_length);
        let v = centre
            .from_frame(self.velocity_km_s)
            .map(|x| x / centre.km_s_per_velocity);
        (r, v)
    }
}

/// The OEM metadata block.
#[derive(Debug, Clone, PartialEq)]
pub struct OemMetadata {
    /// Metadata `COMMENT` lines, without the keyword.
    pub comments: Vec<String>,
    /// `OBJECT_NAME`.
    pub object_name: String,
    /// `OBJECT_ID`.
    pub object_id: String,
    /// `CENTER_NAME`.
    pub center_name: String,
    /// `REF_FRAME`.
    pub ref_frame: String,
    /// `TIME_SYSTEM`.
    pub time_system: String,
    /// `START_TIME`.
    pub start_time: CalendarEpoch,
    /// `USEABLE_START_TIME`, if given.
    pub useable_start_time: Option<CalendarEpoch>,
    /// `USEABLE_STOP_TIME`, if given.
    pub useable_stop_time: Option<CalendarEpoch>,
    /// `STOP_TIME`.
    pub stop_time: CalendarEpoch,
    /// `INTERPOLATION`, if given.
    pub interpolation: Option<String>,
    /// `INTERPOLATION_DEGREE`, if given.
    pub interpolation_degree: Option<u32>,
}

/// A single-segment OEM as read by [`read_oem`].
#[derive(Debug, Clone, PartialEq)]
pub struct OemEphemeris {
    /// `CCSDS_OEM_VERS`.
    pub version: String,
    /// Header `COMMENT` lines, without the keyword.
    pub header_comments: Vec<String>,
    /// `CREATION_DATE`.
    pub creation_date: CalendarEpoch,
    /// `ORIGINATOR`.
    pub originator: String,
    /// The metadata block.
    pub metadata: OemMetadata,
    /// Comments at the head of the data section (including the thrust profile lines).
    pub data_comments: Vec<String>,
    /// The data lines, in epoch order.
    pub states: Vec<OemState>,
}

impl OemEphemeris {
    /// The thrust profile carried by the `COMMENT THRUST ...` lines (empty when there are none).
    /// A thrust line that does not parse is an error, as is a profile whose epochs differ from
    /// the states'.
    pub fn thrust_profile(&self) -> Result<Vec<ThrustRow>, OemError> {
        let mut rows = Vec::new();
        for (k, comment) in self.data_comments.iter().enumerate() {
            let mut words = comment.split_whitespace();
            if words.next() != Some(THRUST_COMMENT_TAG) {
                continue;
            }
            let bad = |message: String| OemError::Parse { line: 0, message };
            let Some(epoch_text) = words.next() else {
                // The column description line: "THRUST" followed by names, not an epoch.
                continue;
            };
            let Ok(epoch) = CalendarEpoch::parse(epoch_text) else {
                continue;
            };
            let fields: Vec<&str> = words.collect();
            let row = ThrustRow::parse_fields(epoch, &fields)
                .ok_or_else(|| bad(format!("data comment {k}: malformed thrust line '{comment}'")))?;
            rows.push(row);
        }
        if !rows.is_empty()
            && (rows.len() != self.states.len() || rows.iter().zip(&self.states).any(|(r, s)| r.epoch != s.epoch))
        {
            return Err(OemError::Parse {
                line: 0,
                message: "thrust profile epochs differ from the state epochs".into(),
            });
        }
        Ok(rows)
    }
}

/// Checks a record can be exported: converged, non-empty, finite, time strictly increasing,
/// positive mass, throttle in [0, 1].
pub fn validate_record(record: &impl OemSource) -> Result<(), OemError> {
    OemCentre::of_record(record)?;
    let figures = record.figures();
    if !figures.converged {
        return Err(OemError::NotConverged {
            failure: figures.failure.map(str::to_string),
        });
    }
    let samples = record.samples();
    if samples.is_empty() {
        return Err(OemError::NoSamples);
    }
    for (index, s) in samples.iter().enumerate() {
        let fields: [(&'static str, &[f64]); 6] = [
            ("time", &[s.t]),
            ("position", &s.r),
            ("velocity", &s.v),
            ("mass", &[s.m]),
            ("throttle", &[s.throttle]),
            ("thrust direction", &s.direction),
        ];
        if let Some((field, _)) = fields.iter().find(|(_, xs)| xs.iter().any(|x| !x.is_finite())) {
            return Err(OemError::NonFinite { index, field });
        }
        if s.m <= 0.0 {
            return Err(OemError::InvalidSample {
                index,
                reason: "mass is not positive",
            });
        }
        if !(0.0..=1.0).contains(&s.throttle) {
            return Err(OemError::InvalidSample {
                index,
                reason: "throttle is outside [0, 1]",
            });
        }
        if index > 0 && s.t <= samples[index - 1].t {
            return Err(OemError::TimeNotIncreasing { index });
        }
    }
    Ok(())
}

/// Epochs of the record's ephemeris samples, checked strictly increasing as written (to the
/// microsecond).
fn sample_epochs(
    samples: &[OemSample],
    departure: CalendarEpoch,
    centre: &OemCentre,
) -> Result<Vec<CalendarEpoch>, OemError> {
    let mut epochs = Vec::with_capacity(samples.len());
    let mut previous: Option<String> = None;
    for (index, s) in samples.iter().enumerate() {
        let epoch = departure.plus_seconds(s.t * centre.time_unit_s)?;
        let text = epoch.to_string();
        if previous.as_ref().is_some_and(|p| *p >= text) {
            return Err(OemError::TimeNotIncreasing { index });
        }
        previous = Some(text);
        epochs.push(epoch);
    }
    Ok(epochs)
}

/// The thrust profile of a record: one row per ephemeris sample.
pub fn thrust_rows(record: &impl OemSource, options: &OemOptions) -> Result<Vec<ThrustRow>, OemError> {
    validate_record(record)?;
    options.validate()?;
    let centre = OemCentre::of_record(record)?;
    let samples = record.samples();
    let epochs = sample_epochs(&samples, options.departure_epoch, &centre)?;
    let sc = &options.spacecraft;
    Ok(samples
        .iter()
        .zip(epochs)
        .map(|(s, epoch)| ThrustRow {
            epoch,
            t_days: s.t * centre.time_unit_s / 86_400.0,
            mass_kg: s.m * sc.initial_mass_kg,
            throttle: s.throttle,
            thrust_n: s.throttle * sc.max_thrust_n,
            direction: centre.to_frame(s.direction),
        })
        .collect())
}

/// Renders the OEM of a record as text (what [`write_oem`] writes).
pub fn oem_string(record: &impl OemSource, options: &OemOptions) -> Result<String, OemError> {
    let rows = thrust_rows(record, options)?;
    let centre = OemCentre::of_record(record)?;
    let figures = record.figures();
    let (final_eps, residual, thrust_arcs, final_mass) = (
        figures.final_eps,
        figures.residual,
        figures.thrust_arcs,
        figures.final_mass,
    );
    let (seed, index) = (record.seed(), figures.index);
    let sc = &options.spacecraft;
    let n = rows.len();
    let (first, last) = (rows[0].epoch, rows[n - 1].epoch);
    let mut text = String::with_capacity(400 * n + 4096);
    // Writing into a String cannot fail.
    let mut line = |s: &str| {
        text.push_str(s);
        text.push('\n');
    };
    line(&format!("CCSDS_OEM_VERS = {OEM_VERSION}"));
    line(&format!(
        "COMMENT Fuel-optimal low-thrust trajectory about the {} (indirect method), lowthrust-ground {}",
        centre.center_name.to_lowercase(),
        env!("CARGO_PKG_VERSION")
    ));
    line(&format!(
        "COMMENT Scenario {} seed {seed} index {index}; final eps {final_eps:e}; terminal residual {residual:e}; thrust arcs {thrust_arcs}",
        record.family_label(),
    ));
    line(&format!(
        "COMMENT Spacecraft Tmax {} N, Isp {} s, initial mass {} kg; final mass {:.6} kg",
        sc.max_thrust_n,
        sc.isp_s,
        sc.initial_mass_kg,
        final_mass * sc.initial_mass_kg
    ));
    line(&format!("CREATION_DATE = {}", options.creation_date));
    line(&format!("ORIGINATOR = {}", options.originator));
    line("");
    line("META_START");
    for comment in centre.comments {
        line(&format!("COMMENT {comment}"));
    }
    line(&format!("OBJECT_NAME = {}", options.object_name));
    line(&format!("OBJECT_ID = {}", options.object_id));
    line(&format!("CENTER_NAME = {}", centre.center_name));
    line(&format!("REF_FRAME = {}", centre.ref_frame));
    line(&format!("TIME_SYSTEM = {TIME_SYSTEM}"));
    line(&format!("START_TIME = {first}"));
    line(&format!("USEABLE_START_TIME = {first}"));
    line(&format!("USEABLE_STOP_TIME = {last}"));
    line(&format!("STOP_TIME = {last}"));
    if n > INTERPOLATION_DEGREE as usize {
        line(&format!("INTERPOLATION = {INTERPOLATION}"));
        line(&format!("INTERPOLATION_DEGREE = {INTERPOLATION_DEGREE}"));
    }
    line("META_STOP");
    line("");
    line(&format!(
        "COMMENT {THRUST_COMMENT_TAG} profile, one line per state below: {THRUST_COMMENT_TAG} epoch t_days mass_kg throttle"
    ));
    line("COMMENT thrust_N dir_x dir_y dir_z; thrust_N = throttle * Tmax; dir = unit thrust direction in EME2000.");
    for row in &rows {
        line(&format!(
            "COMMENT {THRUST_COMMENT_TAG} {} {}",
            row.epoch,
            row.fields().join(" ")
        ));
    }
    for (s, row) in record.samples().iter().zip(&rows) {
        let r = centre.to_frame(s.r).map(|x| x * centre.km_per_length);
        let v = centre.to_frame(s.v).map(|x| x * centre.km_s_per_velocity);
        // Millimetre and nanometre-per-second resolution (position near the limit of f64).
        let (r, v) = (r.map(|x| fixed(x, 6)), v.map(|x| fixed(x, 12)));
        line(&format!(
            "{} {} {} {} {} {} {}",
            row.epoch, r[0], r[1], r[2], v[0], v[1], v[2]
        ));
    }
    if let Some((k, _)) = text.lines().enumerate().find(|(_, l)| l.len() > MAX_LINE_LENGTH) {
        return Err(OemError::InvalidOption {
            field: "record",
            reason: format!("OEM line {} would exceed {MAX_LINE_LENGTH} characters", k + 1),
        });
    }
    Ok(text)
}

/// Writes the OEM of a converged record. Nothing is written when the record or the options are
/// refused.
pub fn write_oem<W: Write>(record: &impl OemSource, options: &OemOptions, out: &mut W) -> Result<(), OemError> {
    let text = oem_string(record, options)?;
    out.write_all(text.as_bytes())?;
    Ok(())
}

/// Writes the companion thrust CSV: header [`THRUST_CSV_HEADER`], one row per ephemeris sample
/// (same epochs as the OEM). Nothing is written when the record or the options are refused.
pub fn write_thrust_csv<W: Write>(record: &impl OemSource, options: &OemOptions, out: &mut W) -> Result<(), OemError> {
    let rows = thrust_rows(record, options)?;
    let mut text = String::with_capacity(160 * (rows.len() + 1));
    text.push_str(THRUST_CSV_HEADER);
    text.push('\n');
    for row in &rows {
        let _ = writeln!(text, "{},{}", row.epoch, row.fields().join(","));
    }
    out.write_all(text.as_bytes())?;
    Ok(())
}

/// `x` with `decimals` fixed decimals, without the sign of a value that rounds to zero.
fn fixed(x: f64, decimals: usize) -> String {
    let text = format!("{x:.decimals$}");
    match text.strip_prefix('-') {
        Some(magnitude) if magnitude.bytes().all(|b| b == b'0' || b == b'.') => magnitude.to_string(),
        _ => text,
    }
}

fn parse_finite(text: &str) -> Option<f64> {
    text.parse::<f64>().ok().filter(|x| x.is_finite())
}

/// Metadata keywords in the order the standard fixes, with whether each is obligatory.
const METADATA_KEYS: [(&str, bool); 12] = [
    ("OBJECT_NAME", true),
    ("OBJECT_ID", true),
    ("CENTER_NAME", true),
    ("REF_FRAME", true),
    ("REF_FRAME_EPOCH", false),
    ("TIME_SYSTEM", true),
    ("START_TIME", true),
    ("USEABLE_START_TIME", false),
    ("USEABLE_STOP_TIME", false),
    ("STOP_TIME", true),
    ("INTERPOLATION", false),
    ("INTERPOLATION_DEGREE", false),
];

/// Reads an OEM strictly: one segment, KVN keywords in the standard's order with no unknown or
/// repeated ones, obligatory keywords present, comments only where OEM allows them, data lines
/// of exactly 7 finite fields (no accelerations, no covariance), epochs strictly increasing and
/// inside START_TIME..STOP_TIME, USEABLE times inside those.
pub fn read_oem(text: &str) -> Result<OemEphemeris, OemError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty())
        .peekable();
    let err = |line: usize, message: String| OemError::Parse { line, message };
    let key_value = |line: usize, l: &str| -> Result<(String, String), OemError> {
        let (k, v) = l
            .split_once('=')
            .ok_or_else(|| err(line, format!("expected KEYWORD = value, found '{l}'")))?;
        let (k, v) = (k.trim(), v.trim());
        if k.is_empty()
            || !k
                .bytes()
                .all(|b| b.is_ascii_uppercase() || b.is_ascii_digit() || b == b'_')
        {
            return Err(err(line, format!("bad keyword '{k}'")));
        }
        if v.is_empty() {
            return Err(err(line, format!("{k} has no value")));
        }
        Ok((k.to_string(), v.to_string()))
    };
    let comment = |l: &str| -> Option<String> {
        l.strip_prefix("COMMENT")
            .filter(|rest| rest.is_empty() || rest.starts_with([' ', '\t']))
            .map(|rest| rest.trim().to_string())
    };
    let epoch_at = |line: usize, v: &str| CalendarEpoch::parse(v).map_err(|e| err(line, e.to_string()));

    // Header.
    let (line, first) = lines.next().ok_or_else(|| err(0, "empty text".into()))?;
    let (k, version) = key_value(line, first)?;
    if k != "CCSDS_OEM_VERS" {
        return Err(err(
            line,
            format!("the first keyword must be CCSDS_OEM_VERS, found {k}"),
        ));
    }
    if !["1.0", "2.0", "3.0"].contains(&version.as_str()) {
        return Err(err(line, format!("unsupported CCSDS_OEM_VERS {version}")));
    }
    let mut header_comments = Vec::new();
    while let Some(c) = lines.peek().and_then(|(_, l)| comment(l)) {
        header_comments.push(c);
        lines.next();
    }
    let mut expect = |key: &str| -> Result<(usize, String), OemError> {
        let (line, l) = lines.next().ok_or_else(|| err(0, format!("missing {key}")))?;
        let (k, v) = key_value(line, l)?;
        if k != key {
            return Err(err(line, format!("expected {key}, found {k}")));
        }
        Ok((line, v))
    };
    let (line, creation) = expect("CREATION_DATE")?;
    let creation_date = epoch_at(line, &creation)?;
    let (_, originator) = expect("ORIGINATOR")?;
    let (line, l) = lines.next().ok_or_else(|| err(0, "missing META_START".into()))?;
    if l != "META_START" {
        return Err(err(line, format!("expected META_START, found '{l}'")));
    }

    // Metadata.
    let mut meta_comments = Vec::new();
    while let Some(c) = lines.peek().and_then(|(_, l)| comment(l)) {
        meta_comments.push(c);
        lines.next();
    }
    let mut values: [Option<(usize, String)>; METADATA_KEYS.len()] = Default::default();
    let mut position = 0;
    let meta_stop_line = loop {
        let (line, l) = lines.next().ok_or_else(|| err(0, "missing META_STOP".into()))?;
        if l == "META_STOP" {
            break line;
        }
        if comment(l).is_some() {
            return Err(err(line, "COMMENT is allowed only at the start of the metadata".into()));
        }
        let (k, v) = key_value(line, l)?;
        let index = METADATA_KEYS
            .iter()
            .position(|(key, _)| *key == k)
            .ok_or_else(|| err(line, format!("unknown metadata keyword {k}")))?;
        if index < position || values[index].is_some() {
            return Err(err(line, format!("{k} repeated or out of the standard's order")));
        }
        position = index;
        values[index] = Some((line, v));
    };
    for ((key, obligatory), value) in METADATA_KEYS.iter().zip(&values) {
        if *obligatory && value.is_none() {
            return Err(err(meta_stop_line, format!("missing obligatory metadata {key}")));
        }
    }
    let take = |key: &str| {
        let index = METADATA_KEYS.iter().position(|(k, _)| *k == key);
        index.and_then(|i| values[i].clone())
    };
    let text_of = |key: &str| take(key).map(|(_, v)| v).unwrap_or_default();
    let epoch_of = |key: &str| take(key).map(|(line, v)| epoch_at(line, &v)).transpose();
    if take("REF_FRAME_EPOCH").is_some() {
        return Err(err(meta_stop_line, "REF_FRAME_EPOCH is not supported".into()));
    }
    let interpolation_degree = take("INTERPOLATION_DEGREE")
        .map(|(line, v)| {
            v.parse::<u32>()
                .ok()
                .filter(|d| *d > 0)
                .ok_or_else(|| err(line, format!("INTERPOLATION_DEGREE {v} is not a positive integer")))
        })
        .transpose()?;
    let interpolation = take("INTERPOLATION").map(|(_, v)| v);
    if interpolation.is_some() != interpolation_degree.is_some() {
        return Err(err(
            meta_stop_line,
            "INTERPOLATION and INTERPOLATION_DEGREE go together".into(),
        ));
    }
    // START_TIME and STOP_TIME are obligatory, checked above.
    let (Some(start_time), Some(stop_time)) = (epoch_of("START_TIME")?, epoch_of("STOP_TIME")?) else {
        return Err(err(meta_stop_line, "missing START_TIME or STOP_TIME".into()));
    };
    let metadata = OemMetadata {
        comments: meta_comments,
        object_name: text_of("OBJECT_NAME"),
        object_id: text_of("OBJECT_ID"),
        center_name: text_of("CENTER_NAME"),
        ref_frame: text_of("REF_FRAME"),
        time_system: text_of("TIME_SYSTEM"),
        start_time,
        useable_start_time: epoch_of("USEABLE_START_TIME")?,
        useable_stop_time: epoch_of("USEABLE_STOP_TIME")?,
        stop_time,
        interpolation,
        interpolation_degree,
    };

    // Data.
    let mut data_comments = Vec::new();
    let mut states: Vec<OemState> = Vec::new();
    for (line, l) in lines {
        if let Some(c) = comment(l) {
            if !states.is_empty() {
                return Err(err(line, "COMMENT is allowed only before the first data line".into()));
            }
            data_comments.push(c);
            continue;
        }
        if l == "META_START" {
            return Err(err(line, "more than one segment".into()));
        }
        if l.starts_with("COVARIANCE_START") {
            return Err(err(line, "covariance data is not supported".into()));
        }
        let fields: Vec<&str> = l.split_whitespace().collect();
        if fields.len() != 7 {
            return Err(err(line, format!("a data line has 7 fields, found {}", fields.len())));
        }
        let epoch = epoch_at(line, fields[0])?;
        let mut x = [0.0; 6];
        for (value, text) in x.iter_mut().zip(&fields[1..]) {
            *value = parse_finite(text).ok_or_else(|| err(line, format!("'{text}' is not a finite number")))?;
        }
        if states.last().is_some_and(|p| p.epoch >= epoch) {
            return Err(err(line, "epochs must increase strictly".into()));
        }
        if epoch < metadata.start_time || epoch > metadata.stop_time {
            return Err(err(line, "epoch outside START_TIME..STOP_TIME".into()));
        }
        states.push(OemState {
            epoch,
            position_km: [x[0], x[1], x[2]],
            velocity_km_s: [x[3], x[4], x[5]],
        });
    }
    if states.is_empty() {
        return Err(err(0, "no ephemeris data lines".into()));
    }
    let start = metadata.useable_start_time.unwrap_or(metadata.start_time);
    let stop = metadata.useable_stop_time.unwrap_or(metadata.stop_time);
    if metadata.start_time > metadata.stop_time
        || start < metadata.start_time
        || stop > metadata.stop_time
        || start > stop
    {
        return Err(err(meta_stop_line, "START/USEABLE/STOP times are inconsistent".into()));
    }
    Ok(OemEphemeris {
        version,
        header_comments,
        creation_date,
        originator,
        metadata,
        data_comments,
        states,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rounding to the microsecond is to the nearest (ties later) on both sides of J2000, the
    /// reference of hifitime's TDB durations, where its own `Duration::round` would move
    /// earlier epochs towards J2000 instead.
    #[test]
    fn epochs_round_to_the_nearest_microsecond_before_j2000_too() {
        for (text, shown) in [
            ("1999-12-31T23:59:59.9999993", "1999-12-31T23:59:59.999999"),
            ("2000-01-01T00:00:00.0000013", "2000-01-01T00:00:00.000001"),
            ("2000-01-01T11:59:59.9999995", "2000-01-01T12:00:00.000000"),
            ("1899-12-31T23:59:59.9999995", "1900-01-01T00:00:00.000000"),
            ("0001-01-01T00:00:00.0000004", "0001-01-01T00:00:00.000000"),
            ("2030-01-01T00:00:00.0000013", "2030-01-01T00:00:00.000001"),
        ] {
            assert_eq!(CalendarEpoch::parse(text).unwrap().to_string(), shown, "{text}");
        }
        // Order and equality are those of the exact nanosecond count.
        let a = CalendarEpoch::parse("1987-03-04T05:06:07.123456789").unwrap();
        let b = a.plus_seconds(1e-9).unwrap();
        assert!(a < b && a != b && b.plus_seconds(-1e-9).unwrap() == a);
        assert_eq!(b.seconds_since(a), 1e-9);
    }
}
