//! Dataset generation at scale: every scenario of a distribution solved by the
//! indirect method, in parallel, resumable, in disjoint reproducible shards. A planar family's
//! draws become planar records, an inclined family's three-dimensional ones ([`DatasetFamily`]).
//!
//! A run folder is held by one process at a time ([`RunLock`]) while it is written.
//!
//! Layout of an output folder:
//! - `manifest.json`: scenario, seed, count (a resumed run must match it, or ask for more
//!   scenarios of the same stream: it then extends the run);
//! - `request.json`: the final eps the records were solved to, their arrival margin and the
//!   spacecraft they were solved for (a resumed run must match them too);
//! - `records/NNNNNNNN.rec`: one checksummed record per scenario index, written atomically as
//!   soon as it is solved, so a killed run loses at most the cases in flight;
//! - `dataset.ltds` (or `dataset-I-of-N.ltds` for a shard): all records of the run, sorted;
//! - `summary.json`, `summary.csv`: convergence, timing, final-mass statistics, failures.

use std::fs;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::atomic::{AtomicUsize, Ordering};

use indicatif::ProgressBar;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use shared::mission::{MissionFamily, SpatialFamily};
use shared::scenario::{Scenario, ScenarioKind};
use shared::spacecraft::CanonicalSpacecraft;

use crate::crosscheck::{crosscheck_records, cut_record, repair_record, CrossCheck, CrossCheckSettings};
use crate::io::{atomic_write, decode_container, encode_container, ContainerError, LockError, RunLock};
use crate::mission::WrittenFamily;
use crate::progress;
use crate::solver::direct::DirectError;
use crate::solver::min_time::{classify_draw, Feasibility};
use crate::solver::record::{RecordFormat1, TrajectoryRecord};
use crate::solver::spatial::record::{solve_spatial_arriving_early, SpatialRecord};
use crate::solver::{solve_arriving_early, solve_from_energy_start, SolveOptions};

const RECORD_MAGIC: [u8; 4] = *b"LTRC";
const DATASET_MAGIC: [u8; 4] = *b"LTDS";
/// Records and datasets of inclined families: their own magic, so that a planar reader refuses
/// them as another kind of file.
const SPATIAL_RECORD_MAGIC: [u8; 4] = *b"LTR3";
const SPATIAL_DATASET_MAGIC: [u8; 4] = *b"LTD3";
/// Format 2: records carry their family and their scenario its cycle. Format 1 (the thesis's
/// families, 14-day cycles) is still read.
const FORMAT_VERSION: u16 = 2;
const FORMAT_1: u16 = 1;

/// Decodes a container of format 2, or of format 1 through its older layout `Old`.
fn decode_any_format<T: serde::de::DeserializeOwned, Old: serde::de::DeserializeOwned + Into<T>>(
    magic: [u8; 4],
    bytes: &[u8],
) -> Result<T, ContainerError> {
    match decode_container(magic, FORMAT_VERSION, bytes) {
        Err(ContainerError::UnsupportedVersion(FORMAT_1)) => {
            decode_container::<Old>(magic, FORMAT_1, bytes).map(Into::into)
        }
        decoded => decoded,
    }
}

/// What a dataset is drawn from: a family whose draws are solved into records of one kind,
/// planar ([`MissionFamily`], [`TrajectoryRecord`]) or inclined ([`SpatialFamily`],
/// [`SpatialRecord`]). Generation, resumption, sharding, merging and the summaries are the same
/// for both.
pub trait DatasetFamily: WrittenFamily + Copy + PartialEq + std::fmt::Debug + Send + Sync + 'static {
    /// The record one draw is solved into.
    type Record: DatasetRecord;
    /// Magic of a record file.
    const RECORD_MAGIC: [u8; 4];
    /// Magic of a dataset file.
    const DATASET_MAGIC: [u8; 4];
    /// The family's name for messages.
    fn name(&self) -> String;
    /// Solves draw `index` of stream `seed` (never fails: a failed solve is a record too).
    fn solve(&self, seed: u64, index: u64, spacecraft: &CanonicalSpacecraft, options: &SolveOptions) -> Self::Record;
    /// Whether `record` is draw `index` of stream `seed` of this family.
    fn drew(&self, record: &Self::Record, seed: u64, index: u64) -> bool;
    /// Decodes a record file (older formats included).
    fn decode_record(bytes: &[u8]) -> Result<Self::Record, ContainerError>;
    /// Decodes a dataset file (older formats included).
    fn decode_dataset(bytes: &[u8]) -> Result<DatasetFile<Self>, ContainerError>;
}

/// The figures the summaries read from a record.
pub trait DatasetRecord: Clone + Serialize + serde::de::DeserializeOwned + Send + Sync {
    /// The record's figures.
    fn figures(&self) -> RecordFigures<'_>;
    /// The record with its solve time zeroed: what two runs of one draw share, bit for bit.
    fn untimed(&self) -> Self;
}

/// One record's figures, whatever its kind.
#[derive(Debug, Clone, Copy)]
pub struct RecordFigures<'a> {
    /// Index of the draw.
    pub index: u64,
    /// Whether it converged.
    pub converged: bool,
    /// Final mass, fraction of m0 (NaN when not converged).
    pub final_mass: f64,
    /// Homotopy level reached.
    pub final_eps: f64,
    /// Largest terminal residual.
    pub residual: f64,
    /// Thrust arcs on the ephemeris grid.
    pub thrust_arcs: u32,
    /// Solve time, s.
    pub seconds: f64,
    /// Guidance cycles of the flight.
    pub steps: u32,
    /// Why it failed.
    pub failure: Option<&'a str>,
}

impl DatasetRecord for TrajectoryRecord {
    fn figures(&self) -> RecordFigures<'_> {
        RecordFigures {
            index: self.index,
            converged: self.converged,
            final_mass: self.final_mass,
            final_eps: self.final_eps,
            residual: self.residual,
            thrust_arcs: self.thrust_arcs,
            seconds: self.seconds,
            steps: self.scenario.steps,
            failure: self.failure.as_deref(),
        }
    }

    fn untimed(&self) -> Self {
        Self {
            seconds: 0.0,
            ..self.clone()
        }
    }
}

impl DatasetRecord for SpatialRecord {
    fn figures(&self) -> RecordFigures<'_> {
        RecordFigures {
            index: self.index,
            converged: self.converged,
            final_mass: self.final_mass,
            final_eps: self.final_eps,
            residual: self.residual,
            thrust_arcs: self.thrust_arcs,
            seconds: self.seconds,
            steps: self.scenario.scenario.steps,
            failure: self.failure.as_deref(),
        }
    }

    fn untimed(&self) -> Self {
        Self {
            seconds: 0.0,
            ..self.clone()
        }
    }
}

impl DatasetFamily for MissionFamily {
    type Record = TrajectoryRecord;
    const RECORD_MAGIC: [u8; 4] = RECORD_MAGIC;
    const DATASET_MAGIC: [u8; 4] = DATASET_MAGIC;

    fn name(&self) -> String {
        self.label().to_string()
    }

    fn solve(
        &self,
        seed: u64,
        index: u64,
        spacecraft: &CanonicalSpacecraft,
        options: &SolveOptions,
    ) -> TrajectoryRecord {
        let scenario = self.draw(seed, index);
        solve_arriving_early(*self, seed, index, &scenario, spacecraft, options)
    }

    fn drew(&self, record: &TrajectoryRecord, seed: u64, index: u64) -> bool {
        record.family == *self && record.seed == seed && record.index == index
    }

    fn decode_record(bytes: &[u8]) -> Result<TrajectoryRecord, ContainerError> {
        decode_any_format::<_, RecordFormat1>(RECORD_MAGIC, bytes)
    }

    fn decode_dataset(bytes: &[u8]) -> Result<DatasetFile, ContainerError> {
        decode_any_format::<_, DatasetFormat1>(DATASET_MAGIC, bytes)
    }
}

impl DatasetFamily for SpatialFamily {
    type Record = SpatialRecord;
    const RECORD_MAGIC: [u8; 4] = SPATIAL_RECORD_MAGIC;
    const DATASET_MAGIC: [u8; 4] = SPATIAL_DATASET_MAGIC;

    fn name(&self) -> String {
        self.label().to_string()
    }

    fn solve(&self, seed: u64, index: u64, spacecraft: &CanonicalSpacecraft, options: &SolveOptions) -> SpatialRecord {
        let scenario = self.draw(seed, index);
        solve_spatial_arriving_early(self, (seed, index), &scenario, spacecraft, options)
    }

    fn drew(&self, record: &SpatialRecord, seed: u64, index: u64) -> bool {
        record.family == *self && record.seed == seed && record.index == index
    }

    fn decode_record(bytes: &[u8]) -> Result<SpatialRecord, ContainerError> {
        decode_container(SPATIAL_RECORD_MAGIC, FORMAT_VERSION, bytes)
    }

    fn decode_dataset(bytes: &[u8]) -> Result<DatasetFile<Self>, ContainerError> {
        decode_container(SPATIAL_DATASET_MAGIC, FORMAT_VERSION, bytes)
    }
}

/// Shard I of N: the indices i with i mod N == I. Disjoint, reproducible, and together all.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    /// I, in 0..N.
    pub index: u32,
    /// N, at least 1.
    pub count: u32,
}

impl Shard {
    /// Shard 0/1: every index.
    pub const WHOLE: Self = Self { index: 0, count: 1 };

    /// Whether scenario index `i` belongs to this shard.
    pub fn contains(&self, i: u64) -> bool {
        i % u64::from(self.count) == u64::from(self.index)
    }
}

/// Why a text is not a shard `I/N`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ShardError {
    /// No `/` in the text (given in full).
    #[error("shard must look like I/N, got '{0}'")]
    Form(String),
    /// I (given) is not an unsigned integer.
    #[error("bad shard index '{0}'")]
    Index(String),
    /// N (given) is not an unsigned integer.
    #[error("bad shard count '{0}'")]
    Count(String),
    /// N = 0 or I >= N.
    #[error("shard {index}/{count}: need 0 <= I < N")]
    OutOfRange {
        /// I.
        index: u32,
        /// N.
        count: u32,
    },
}

impl FromStr for Shard {
    type Err = ShardError;
    fn from_str(s: &str) -> Result<Self, ShardError> {
        let (i, n) = s.split_once('/').ok_or_else(|| ShardError::Form(s.to_string()))?;
        let index: u32 = i.trim().parse().map_err(|_| ShardError::Index(i.to_string()))?;
        let count: u32 = n.trim().parse().map_err(|_| ShardError::Count(n.to_string()))?;
        if count == 0 || index >= count {
            return Err(ShardError::OutOfRange { index, count });
        }
        Ok(Self { index, count })
    }
}

/// What a run generates; stored as `manifest.json` and checked on resume and merge.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(bound(serialize = "F: DatasetFamily", deserialize = "F: DatasetFamily"))]
pub struct Manifest<F = MissionFamily> {
    /// Family the scenarios are drawn from (`scenario` in manifest.json: a preset's name or the
    /// family's table).
    #[serde(rename = "scenario", with = "crate::mission::by_spec")]
    pub family: F,
    /// Seed of the draws: index i is `family.draw(seed, i)`.
    pub seed: u64,
    /// Number of scenarios: indices 0..count.
    pub count: u64,
}

/// The homotopy depth a run's records were solved to, their arrival margin and the spacecraft
/// they were solved for, stored as `request.json` beside the manifest: a run resumed with another
/// would mix records of two kinds, and a learner flying another spacecraft would learn from
/// optima that are not its own.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SolveRequest {
    /// The homotopy's last eps ([`SolveOptions::final_eps`]).
    pub final_eps: f64,
    /// [`SolveOptions::arrival_margin_steps`] (absent: 0, as before it existed).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub arrival_margin_steps: u32,
    /// The spacecraft, in the family's canonical units (absent: not recorded, a folder written
    /// before it was).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spacecraft: Option<CanonicalSpacecraft>,
}

/// For `skip_serializing_if`: a count of zero is the default, left out of what is written.
pub fn is_zero(n: &u32) -> bool {
    *n == 0
}

impl SolveRequest {
    fn of(options: &SolveOptions, spacecraft: &CanonicalSpacecraft) -> Self {
        Self {
            final_eps: options.final_eps,
            arrival_margin_steps: options.arrival_margin_steps,
            spacecraft: Some(*spacecraft),
        }
    }

    /// The default solve options with this request's final eps and margin.
    pub fn options(&self) -> SolveOptions {
        SolveOptions {
            final_eps: self.final_eps,
            arrival_margin_steps: self.arrival_margin_steps,
            ..SolveOptions::default()
        }
    }
}

/// A dataset file: the records of a run (a shard or a whole set).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(bound(serialize = "F: DatasetFamily", deserialize = "F: DatasetFamily"))]
pub struct DatasetFile<F: DatasetFamily = MissionFamily> {
    /// What the run generates.
    pub manifest: Manifest<F>,
    /// Which shard of it these records are.
    pub shard: Shard,
    /// The records, sorted by index.
    pub records: Vec<F::Record>,
}

impl<F: DatasetFamily> PartialEq for DatasetFile<F>
where
    F::Record: PartialEq,
{
    fn eq(&self, other: &Self) -> bool {
        self.manifest == other.manifest && self.shard == other.shard && self.records == other.records
    }
}

/// A dataset file of format 1.
#[derive(Deserialize)]
struct DatasetFormat1 {
    manifest: (ScenarioKind, u64, u64),
    shard: Shard,
    records: Vec<RecordFormat1>,
}

impl From<DatasetFormat1> for DatasetFile {
    fn from(old: DatasetFormat1) -> Self {
        let (kind, seed, count) = old.manifest;
        Self {
            manifest: Manifest {
                family: kind.family(),
                seed,
                count,
            },
            shard: old.shard,
            records: old.records.into_iter().map(Into::into).collect(),
        }
    }
}

/// Why a run, merge or dataset read failed.
#[derive(Debug, thiserror::Error)]
pub enum GenerateError {
    /// Reading or writing this file failed.
    #[error("{path}: {1}", path = .0.display())]
    Io(PathBuf, std::io::Error),
    /// The folder holds a run of another scenario, seed or count.
    #[error(
        "output folder holds {found}, not {wanted}: use another --out (a larger count of the same scenario and seed extends a run)"
    )]
    ManifestMismatch {
        /// The folder's manifest: family, seed and count.
        found: String,
        /// The run's.
        wanted: String,
    },
    /// The folder holds records solved to another final eps.
    #[error("output folder holds records solved to final eps {found}, not {wanted}: use another --out or --final-eps {found}")]
    FinalEpsMismatch {
        /// The folder's final eps.
        found: f64,
        /// The run's.
        wanted: f64,
    },
    /// The folder holds records solved with another arrival margin.
    #[error("output folder holds records solved to arrive {found} steps early, not {wanted}: use another --out or --arrival-margin {found}")]
    ArrivalMarginMismatch {
        /// The folder's margin, 14-day steps.
        found: u32,
        /// The run's.
        wanted: u32,
    },
    /// The folder holds records solved for another spacecraft.
    #[error(
        "{what} solved for another spacecraft ({found}), not {wanted}: {advice}",
        found = describe_spacecraft(found),
        wanted = describe_spacecraft(wanted)
    )]
    SpacecraftMismatch {
        /// What holds the records: an output folder or a dataset.
        what: String,
        /// The recorded spacecraft.
        found: CanonicalSpacecraft,
        /// This command's.
        wanted: CanonicalSpacecraft,
        /// What to do instead.
        advice: String,
    },
    /// Writing a solved record failed (a full disk): the run stopped solving there.
    #[error(
        "{path}: {source}: the run stopped at its first failed write ({unwritten} record(s) solved in flight not written); \
         the {written} records written stay, and the same command resumes from them",
        path = .path.display()
    )]
    RecordWrite {
        /// The record that could not be written.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
        /// Records solved but not written (the failed one and those in flight beside it).
        unwritten: usize,
        /// Records of the run on disk (resumed or written).
        written: usize,
    },
    /// This record, journal or dataset file fails its magic, version, checksum or decoding.
    #[error("{path}: {1}", path = .0.display())]
    Corrupt(PathBuf, ContainerError),
    /// Shards to merge disagree, overlap, or leave indices out.
    #[error("cannot merge: {0}")]
    Merge(String),
    /// A shard built by hand with N = 0 or I >= N ([`Shard::from_str`] refuses those).
    #[error(transparent)]
    InvalidShard(#[from] ShardError),
    /// A run of no scenario: its figures would all be NaN.
    #[error("count must be at least 1: a run of no scenario has nothing to solve")]
    EmptyCount,
    /// A shard with no index below the count: it would solve nothing.
    #[error(
        "shard {}/{} is empty: a count of {count} has indices 0 to {} only",
        .shard.index,
        .shard.count,
        .count.saturating_sub(1)
    )]
    EmptyShard {
        /// The shard asked for.
        shard: Shard,
        /// The run's scenario count.
        count: u64,
    },
    /// The homotopy's last eps must be in (0, 1].
    #[error("final eps must be in (0, 1], got {0}")]
    InvalidFinalEps(f64),
    /// The folder is held by another run (or could not be locked).
    #[error(transparent)]
    Lock(#[from] LockError),
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> GenerateError + '_ {
    move |e| GenerateError::Io(path.to_path_buf(), e)
}

/// Writes `value` as pretty JSON to `path`, atomically.
fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), GenerateError> {
    let json = serde_json::to_vec_pretty(value).map_err(|e| GenerateError::Io(path.to_path_buf(), e.into()))?;
    atomic_write(path, &json).map_err(io_err(path))
}

/// The JSON file `path`, if there is one.
fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<Option<T>, GenerateError> {
    if !path.exists() {
        return Ok(None);
    }
    let text = fs::read(path).map_err(io_err(path))?;
    let value = serde_json::from_slice(&text).map_err(|e| GenerateError::Io(path.to_path_buf(), e.into()))?;
    Ok(Some(value))
}

/// Aggregate figures of a record set (written as summary.json).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Family label ([`MissionFamily::label`]: a preset's name, or `custom-` and its fingerprint).
    pub scenario: String,
    /// Seed of the draws.
    pub seed: u64,
    /// Shard the figures cover.
    pub shard: Shard,
    /// Number of records.
    pub records: usize,
    /// Number of converged records.
    pub converged: usize,
    /// converged / records.
    pub convergence_rate: f64,
    /// Records classified infeasible (failure reason "infeasible: minimum time ..."), and
    /// converged / (records - infeasible).
    #[serde(default)]
    pub infeasible: usize,
    /// converged / (records - infeasible).
    #[serde(default)]
    pub feasible_convergence_rate: f64,
    /// Solve wall time per record: sum (CPU-seconds across threads), mean, median, max.
    pub seconds_sum: f64,
    /// Mean solve time per record, s.
    pub seconds_mean: f64,
    /// Median solve time per record, s.
    pub seconds_median: f64,
    /// Longest solve time, s.
    pub seconds_max: f64,
    /// Over converged records.
    pub final_mass_mean: f64,
    /// Standard deviation of the final mass (population), fraction of m0.
    pub final_mass_std: f64,
    /// Smallest final mass, fraction of m0.
    pub final_mass_min: f64,
    /// Largest final mass, fraction of m0.
    pub final_mass_max: f64,
    /// (index, reason) of every record that did not converge.
    pub failures: Vec<(u64, String)>,
}

/// Aggregate figures of `records`, a run's (or a shard's) records; NaN where no record counts.
pub fn summarize<F: DatasetFamily>(manifest: &Manifest<F>, shard: Shard, records: &[F::Record]) -> Summary {
    let records: Vec<RecordFigures> = records.iter().map(DatasetRecord::figures).collect();
    let mut seconds: Vec<f64> = records.iter().map(|r| r.seconds).collect();
    seconds.sort_by(f64::total_cmp);
    let masses: Vec<f64> = records.iter().filter(|r| r.converged).map(|r| r.final_mass).collect();
    let n = records.len().max(1) as f64;
    let mean = |v: &[f64]| {
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    let m_mean = mean(&masses);
    let m_var = mean(&masses.iter().map(|m| (m - m_mean).powi(2)).collect::<Vec<_>>());
    let infeasible = records
        .iter()
        .filter(|r| !r.converged && r.failure.is_some_and(|f| f.starts_with(INFEASIBLE)))
        .count();
    Summary {
        scenario: manifest.family.name(),
        seed: manifest.seed,
        shard,
        records: records.len(),
        converged: masses.len(),
        convergence_rate: masses.len() as f64 / n,
        infeasible,
        feasible_convergence_rate: masses.len() as f64 / (records.len() - infeasible).max(1) as f64,
        seconds_sum: seconds.iter().sum(),
        seconds_mean: mean(&seconds),
        seconds_median: seconds.get(seconds.len() / 2).copied().unwrap_or(f64::NAN),
        seconds_max: seconds.last().copied().unwrap_or(f64::NAN),
        final_mass_mean: m_mean,
        final_mass_std: m_var.sqrt(),
        final_mass_min: masses.iter().copied().fold(f64::NAN, f64::min),
        final_mass_max: masses.iter().copied().fold(f64::NAN, f64::max),
        failures: records
            .iter()
            .filter(|r| !r.converged)
            .map(|r| (r.index, r.failure.unwrap_or("unknown").to_string()))
            .collect(),
    }
}

/// The failure reason of a draw shown infeasible starts with this.
pub const INFEASIBLE: &str = "infeasible:";

/// A transfer or rendezvous that found no energy-optimal start: its minimum time of flight
/// decides whether it is infeasible (tf_min > TOF) or a solver failure (see `solver::min_time`);
/// the reason is prefixed with the verdict and the record's `seconds` include the
/// classification. A draw whose energy-optimal start the classification recovers is solved from
/// it, and a converged solution replaces the record. Other records are left as they are. Returns
/// whether the record changed.
pub fn classify_failure(
    record: &mut TrajectoryRecord,
    scenario: &Scenario,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> bool {
    let Some(why) = record.failure.clone() else {
        return false;
    };
    if record.converged || !why.starts_with("no energy-optimal start") {
        return false;
    }
    let clock = std::time::Instant::now();
    let tof = scenario.time_of_flight();
    let units = record.family.body.units();
    let days = |t: f64| units.to_days(t);
    let verdict = match classify_draw(scenario, spacecraft, options) {
        Feasibility::MinTime { tf_min, .. } if tf_min > tof => format!(
            "{INFEASIBLE} minimum time {:.1} d > TOF {:.1} d (ratio {:.3}, local minimum-time extremal)",
            days(tf_min),
            days(tof),
            tf_min / tof
        ),
        Feasibility::MinTime { tf_min, .. } => format!(
            "feasible: minimum time {:.1} d <= TOF {:.1} d (ratio {:.3})",
            days(tf_min),
            days(tof),
            tf_min / tof
        ),
        Feasibility::Recovered { z } => {
            // The homotopy from the recovered start: a converged record replaces the failure.
            let solved = solve_from_energy_start(
                record.family,
                record.seed,
                record.index,
                scenario,
                spacecraft,
                options,
                z,
            );
            if solved.converged {
                let seconds = record.seconds + clock.elapsed().as_secs_f64();
                *record = TrajectoryRecord { seconds, ..solved };
                return true;
            }
            format!(
                "feasible: energy-optimal solution found by continuation in the time of flight, its homotopy failed ({})",
                solved.failure.as_deref().unwrap_or("")
            )
        }
        Feasibility::Unknown(w) => format!("feasibility unknown ({w})"),
    };
    record.failure = Some(format!("{verdict}; {why}"));
    record.seconds += clock.elapsed().as_secs_f64();
    true
}

/// Opt-in after a (whole) run in `out`: classifies every record without an energy-optimal
/// start by its minimum time of flight ([`classify_failure`], seconds to minutes of work per
/// record, in parallel), rewrites those records and the dataset and summaries, whose
/// `infeasible` count and `feasible_convergence_rate` then reflect it. Converged records are not
/// touched; records classified before are kept as they are. `out` is held for the whole work.
pub fn classify_run(
    out: &Path,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> Result<Summary, GenerateError> {
    let (_held, manifest, records) = hold_whole_run(out)?;
    let results: Vec<Result<TrajectoryRecord, GenerateError>> = records
        .into_par_iter()
        .map(|mut record| {
            let index = record.index;
            let path = record_path(out, index);
            let scenario = manifest.family.draw(manifest.seed, index);
            if classify_failure(&mut record, &scenario, spacecraft, options) {
                write_record(&path, &record)?;
            }
            Ok(record)
        })
        .collect();
    let records = results.into_iter().collect::<Result<Vec<_>, _>>()?;
    write_outputs(
        out,
        &DatasetFile {
            manifest,
            shard: Shard::WHOLE,
            records,
        },
    )
}

/// What [`crosscheck_run`] found and did.
#[derive(Debug)]
pub struct CrossCheckRun {
    /// Every converged record of the run as it was, against the direct transcription.
    pub checks: Vec<(u64, Result<CrossCheck, DirectError>)>,
    /// The records replaced: index, final mass before and after.
    pub repaired: Vec<(u64, f64, f64)>,
    /// The beaten records whose re-solve did not end heavier, cut ([`cut_record`]): index, the
    /// record's final mass and the direct solution's.
    pub cut: Vec<(u64, f64, f64)>,
    /// The dataset's summary after the repairs and cuts (`None` without `repair`).
    pub summary: Option<Summary>,
}

/// Opt-in after a (whole) run in `out`: checks every converged record against the direct
/// transcription started on its own ([`crosscheck_records`]). With `repair`, every record a
/// direct solution beats is re-solved from it ([`repair_record`]); a converged result heavier
/// by the margin replaces the record, and a record its re-solve does not lift is cut from the
/// demonstrations ([`cut_record`]); the dataset and summaries are rewritten. `out` is held for
/// the whole work; nothing is written without `repair`.
pub fn crosscheck_run(
    out: &Path,
    spacecraft: &CanonicalSpacecraft,
    settings: &CrossCheckSettings,
    options: &SolveOptions,
    repair: bool,
    show_progress: bool,
) -> Result<CrossCheckRun, GenerateError> {
    let mut planned = plan_crosscheck(out, spacecraft, settings, options, repair, show_progress)?;
    if repair {
        planned.run.summary = Some(rewrite_records(
            out,
            planned.manifest,
            planned.records,
            planned.rewrites,
        )?);
    }
    Ok(planned.run)
}

/// A run held and checked, with the records its repairs would rewrite.
struct PlannedCrossCheck {
    _held: RunLock,
    manifest: Manifest,
    records: Vec<TrajectoryRecord>,
    run: CrossCheckRun,
    rewrites: Vec<TrajectoryRecord>,
}

/// The checks of [`crosscheck_run`] and, with `repair`, the repaired or cut records, written
/// nowhere yet.
fn plan_crosscheck(
    out: &Path,
    spacecraft: &CanonicalSpacecraft,
    settings: &CrossCheckSettings,
    options: &SolveOptions,
    repair: bool,
    show_progress: bool,
) -> Result<PlannedCrossCheck, GenerateError> {
    let (held, manifest, records) = hold_whole_run(out)?;
    // A repair re-solves to the records' own final eps: another would be another demonstration.
    check_solve_request(out, options, Some(spacecraft))?;
    let checks = crosscheck_records(&records, None, spacecraft, settings, show_progress);
    let mut run = CrossCheckRun {
        checks,
        repaired: Vec::new(),
        cut: Vec::new(),
        summary: None,
    };
    let mut rewrites = Vec::new();
    if repair {
        // Records are in index order from 0 (hold_whole_run): a check's index is its position.
        let beaten: Vec<&CrossCheck> = run
            .checks
            .iter()
            .filter_map(|(_, c)| c.as_ref().ok())
            .filter(|c| c.beats_record(settings.margin))
            .collect();
        let repairs: Vec<Option<TrajectoryRecord>> = beaten
            .par_iter()
            .map(|c| repair_record(&records[c.index as usize], c, spacecraft, settings.margin, options))
            .collect();
        for (check, repair) in beaten.iter().zip(repairs) {
            let old = &records[check.index as usize];
            rewrites.push(match repair {
                Some(new) => {
                    run.repaired.push((new.index, old.final_mass, new.final_mass));
                    new
                }
                None => {
                    run.cut.push((old.index, old.final_mass, check.direct_final_mass));
                    cut_record(old, check)
                }
            });
        }
    }
    Ok(PlannedCrossCheck {
        _held: held,
        manifest,
        records,
        run,
        rewrites,
    })
}

/// Writes `rewrites` over their records (in `records` too, index order from 0), then the
/// dataset and summaries of the whole run.
fn rewrite_records(
    out: &Path,
    manifest: Manifest,
    mut records: Vec<TrajectoryRecord>,
    rewrites: Vec<TrajectoryRecord>,
) -> Result<Summary, GenerateError> {
    for new in rewrites {
        write_record(&record_path(out, new.index), &new)?;
        let index = new.index as usize;
        records[index] = new;
    }
    write_outputs(
        out,
        &DatasetFile {
            manifest,
            shard: Shard::WHOLE,
            records,
        },
    )
}

/// What a run's check against the direct transcription found and repaired, kept as
/// `crosscheck.json` in the run folder ([`crosscheck_once`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CrossCheckSummary {
    /// Records in the run when it was checked: a run extended since is checked again.
    pub count: u64,
    /// Converged records checked.
    pub checked: u64,
    /// Of those, how many direct solutions reached the target (re-flown by the onboard
    /// propagator).
    pub direct_reached: u64,
    /// Records a direct solution beat by more than the margin: worse local optima.
    pub beaten: u64,
    /// The records replaced: index, final mass before and after.
    pub repaired: Vec<(u64, f64, f64)>,
    /// The beaten records not repaired, cut from the demonstrations: index, the record's final
    /// mass and the direct solution's.
    #[serde(default)]
    pub cut: Vec<(u64, f64, f64)>,
}

/// The findings of a [`crosscheck_once`] and the records they rewrite, written before the
/// first rewrite: a stop among the rewrites is finished from it with the same findings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct CrossCheckJournal {
    summary: CrossCheckSummary,
    rewrites: Vec<TrajectoryRecord>,
}

#[derive(Deserialize)]
struct JournalFormat1 {
    summary: CrossCheckSummary,
    rewrites: Vec<RecordFormat1>,
}

impl From<JournalFormat1> for CrossCheckJournal {
    fn from(old: JournalFormat1) -> Self {
        Self {
            summary: old.summary,
            rewrites: old.rewrites.into_iter().map(Into::into).collect(),
        }
    }
}

const JOURNAL_MAGIC: [u8; 4] = *b"LTCJ";
const JOURNAL_FILE: &str = "crosscheck-journal.ltcj";

/// [`crosscheck_run`] with repair, once per run: the first call checks and repairs the run in
/// `out` and saves what it found as `crosscheck.json`; a later call on the same run (same
/// count) returns that file and solves nothing, so a resumed recipe does not repeat the work.
/// The findings and the records to rewrite are journalled before the first rewrite, so a stop
/// among the rewrites is finished from the journal with the findings of the uninterrupted run.
/// With the findings comes the summary of the dataset this call rewrote (`None` when it read
/// the findings back).
pub fn crosscheck_once(
    out: &Path,
    spacecraft: &CanonicalSpacecraft,
    settings: &CrossCheckSettings,
    options: &SolveOptions,
    show_progress: bool,
) -> Result<(CrossCheckSummary, Option<Summary>), GenerateError> {
    crosscheck_once_stopping(out, spacecraft, settings, options, show_progress, false)
}

/// [`crosscheck_once`]; with `stop_after_journal` (tests) it returns once the journal is
/// written, as a run stopped before its first rewrite would.
fn crosscheck_once_stopping(
    out: &Path,
    spacecraft: &CanonicalSpacecraft,
    settings: &CrossCheckSettings,
    options: &SolveOptions,
    show_progress: bool,
    stop_after_journal: bool,
) -> Result<(CrossCheckSummary, Option<Summary>), GenerateError> {
    let path = out.join("crosscheck.json");
    let journal_path = out.join(JOURNAL_FILE);
    let manifest = require_manifest(out)?;
    if let Some(done) = read_json::<CrossCheckSummary>(&path)? {
        if done.count == manifest.count {
            return Ok((done, None));
        }
    }
    let journal = if journal_path.exists() {
        let bytes = fs::read(&journal_path).map_err(io_err(&journal_path))?;
        let journal: CrossCheckJournal = decode_any_format::<_, JournalFormat1>(JOURNAL_MAGIC, &bytes)
            .map_err(|e| GenerateError::Corrupt(journal_path.clone(), e))?;
        // A journal of the run before it was extended is stale: the extended run is checked.
        (journal.summary.count == manifest.count).then_some(journal)
    } else {
        None
    };
    let (summary, rewritten) = match journal {
        Some(journal) => {
            let (_held, manifest, records) = hold_whole_run(out)?;
            let rewritten = rewrite_records(out, manifest, records, journal.rewrites)?;
            (journal.summary, rewritten)
        }
        None => {
            let planned = plan_crosscheck(out, spacecraft, settings, options, true, show_progress)?;
            let run = &planned.run;
            let checks: Vec<&CrossCheck> = run.checks.iter().filter_map(|(_, c)| c.as_ref().ok()).collect();
            let summary = CrossCheckSummary {
                count: manifest.count,
                checked: run.checks.len() as u64,
                direct_reached: checks.iter().filter(|c| c.direct_flies()).count() as u64,
                beaten: checks.iter().filter(|c| c.beats_record(settings.margin)).count() as u64,
                repaired: run.repaired.clone(),
                cut: run.cut.clone(),
            };
            let journal = CrossCheckJournal {
                summary,
                rewrites: planned.rewrites,
            };
            let bytes = encode_container(JOURNAL_MAGIC, FORMAT_VERSION, &journal)
                .map_err(|e| GenerateError::Corrupt(journal_path.clone(), e))?;
            atomic_write(&journal_path, &bytes).map_err(io_err(&journal_path))?;
            if stop_after_journal {
                return Ok((journal.summary, None));
            }
            let rewritten = rewrite_records(out, planned.manifest, planned.records, journal.rewrites)?;
            (journal.summary, rewritten)
        }
    };
    write_json(&path, &summary)?;
    fs::remove_file(&journal_path).map_err(io_err(&journal_path))?;
    Ok((summary, Some(rewritten)))
}

/// The manifest of the run in `out` (its family, seed and count, without reading a record); a
/// folder without one is no `generate` run.
pub fn require_manifest(out: &Path) -> Result<Manifest, GenerateError> {
    read_manifest(out)?.ok_or_else(|| {
        GenerateError::Io(
            out.join("manifest.json"),
            std::io::Error::new(std::io::ErrorKind::NotFound, "no manifest: not a generate run"),
        )
    })
}

/// Holds the whole run in `out` and reads its manifest and every record, in index order. The
/// manifest is read first, so a folder that holds no run is refused and left as it was; every
/// record is read before any work, so a missing or corrupt one (a shard's folder, an unfinished
/// run) refuses the run before minutes of work and any rewrite.
fn hold_whole_run(out: &Path) -> Result<(RunLock, Manifest, Vec<TrajectoryRecord>), GenerateError> {
    let manifest = require_manifest(out)?;
    if manifest.count == 0 {
        return Err(GenerateError::EmptyCount);
    }
    let held = RunLock::acquire(out)?;
    let records = (0..manifest.count)
        .map(|index| read_record(&record_path(out, index)))
        .collect::<Result<Vec<_>, _>>()?;
    Ok((held, manifest, records))
}

/// A bar over `len` items with their count, a message and the time left ("{len} {what}, ...");
/// hidden without `show`, written as log lines where stderr is no terminal ([`progress::bar`]).
pub(crate) fn count_bar(len: usize, what: &str, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    progress::bar(
        len as u64,
        &format!("{{bar:40}} {{pos}}/{{len}} {what}, {{msg}} [{{elapsed_precise}} < {{eta_precise}}]"),
    )
}

fn record_path(out: &Path, index: u64) -> PathBuf {
    out.join("records").join(format!("{index:08}.rec"))
}

/// Writes one planar record, checksummed, atomically.
fn write_record(path: &Path, record: &TrajectoryRecord) -> Result<(), GenerateError> {
    write_record_of::<MissionFamily>(path, record)
}

/// Writes one record of family kind `F`, checksummed, atomically.
fn write_record_of<F: DatasetFamily>(path: &Path, record: &F::Record) -> Result<(), GenerateError> {
    let bytes = encode_container(F::RECORD_MAGIC, FORMAT_VERSION, record)
        .map_err(|e| GenerateError::Corrupt(path.to_path_buf(), e))?;
    atomic_write(path, &bytes).map_err(io_err(path))
}

fn read_record(path: &Path) -> Result<TrajectoryRecord, GenerateError> {
    read_record_of::<MissionFamily>(path)
}

fn read_record_of<F: DatasetFamily>(path: &Path) -> Result<F::Record, GenerateError> {
    let bytes = fs::read(path).map_err(io_err(path))?;
    F::decode_record(&bytes).map_err(|e| GenerateError::Corrupt(path.to_path_buf(), e))
}

/// Reads a dataset file, refusing anything corrupt or of another format.
/// Where two datasets differ in what was solved (the solve times aside, which no two runs
/// share): `None` when they hold the same manifest, shard and records, bit for bit.
pub fn trajectory_difference<F: DatasetFamily>(a: &DatasetFile<F>, b: &DatasetFile<F>) -> Option<String> {
    if a.manifest != b.manifest {
        return Some(format!("manifests differ: {:?} and {:?}", a.manifest, b.manifest));
    }
    if a.shard != b.shard {
        return Some(format!("shards differ: {:?} and {:?}", a.shard, b.shard));
    }
    if a.records.len() != b.records.len() {
        return Some(format!("{} and {} records", a.records.len(), b.records.len()));
    }
    // Compared as their encodings: a failed record's NaN final mass is equal to itself bit for
    // bit, never by `==`.
    let untimed = |r: &F::Record| postcard::to_allocvec(&r.untimed()).ok();
    a.records.iter().zip(&b.records).find_map(|(ra, rb)| {
        let (ea, eb) = (untimed(ra), untimed(rb));
        (ea.is_none() || ea != eb).then(|| {
            format!(
                "records of index {} and {} differ",
                ra.figures().index,
                rb.figures().index
            )
        })
    })
}

/// Reads and checks a planar dataset file (`dataset.ltds` or a shard's).
pub fn read_dataset(path: &Path) -> Result<DatasetFile, GenerateError> {
    read_dataset_of::<MissionFamily>(path)
}

/// Reads and checks a dataset file of family kind `F`.
pub fn read_dataset_of<F: DatasetFamily>(path: &Path) -> Result<DatasetFile<F>, GenerateError> {
    let bytes = fs::read(path).map_err(io_err(path))?;
    F::decode_dataset(&bytes).map_err(|e| GenerateError::Corrupt(path.to_path_buf(), e))
}

/// Whether a dataset or record file holds an inclined family's records (by its magic); a file
/// of neither kind reads as planar, and the planar reader refuses it.
pub fn holds_spatial_records(path: &Path) -> Result<bool, GenerateError> {
    use std::io::Read;
    let mut magic = [0u8; 4];
    let read = fs::File::open(path).and_then(|mut f| f.read_exact(&mut magic));
    match read {
        Ok(()) => Ok(magic == SPATIAL_DATASET_MAGIC || magic == SPATIAL_RECORD_MAGIC),
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(false),
        Err(e) => Err(GenerateError::Io(path.to_path_buf(), e)),
    }
}

/// Where the dataset file of a run (whole or shard) lives in its output folder.
pub fn dataset_path(out: &Path, shard: Shard) -> PathBuf {
    if shard == Shard::WHOLE {
        out.join("dataset.ltds")
    } else {
        out.join(format!("dataset-{}-of-{}.ltds", shard.index, shard.count))
    }
}

/// Writes the dataset file and the summaries of a record set into `out`.
pub fn write_outputs<F: DatasetFamily>(out: &Path, file: &DatasetFile<F>) -> Result<Summary, GenerateError> {
    let path = dataset_path(out, file.shard);
    let bytes = encode_container(F::DATASET_MAGIC, FORMAT_VERSION, file)
        .map_err(|e| GenerateError::Corrupt(path.clone(), e))?;
    atomic_write(&path, &bytes).map_err(io_err(&path))?;
    let summary = summarize(&file.manifest, file.shard, &file.records);
    write_json(&out.join("summary.json"), &summary)?;
    let mut csv = String::from("index,converged,final_mass,final_eps,residual,thrust_arcs,seconds,steps,failure\n");
    for r in file.records.iter().map(DatasetRecord::figures) {
        csv.push_str(&format!(
            "{},{},{},{},{},{},{},{},\"{}\"\n",
            r.index,
            r.converged,
            r.final_mass,
            r.final_eps,
            r.residual,
            r.thrust_arcs,
            r.seconds,
            r.steps,
            r.failure.unwrap_or("").replace('"', "'")
        ));
    }
    let path = out.join("summary.csv");
    atomic_write(&path, csv.as_bytes()).map_err(io_err(&path))?;
    Ok(summary)
}

/// Refuses a request that cannot make a dataset: no scenario, an invalid or empty shard, or a
/// final eps outside (0, 1]. Cheap and read-only, so callers check before creating anything.
pub fn check_request<F: DatasetFamily>(
    manifest: &Manifest<F>,
    shard: Shard,
    options: &SolveOptions,
) -> Result<(), GenerateError> {
    if shard.count == 0 || shard.index >= shard.count {
        return Err(ShardError::OutOfRange {
            index: shard.index,
            count: shard.count,
        }
        .into());
    }
    if manifest.count == 0 {
        return Err(GenerateError::EmptyCount);
    }
    if u64::from(shard.index) >= manifest.count {
        return Err(GenerateError::EmptyShard {
            shard,
            count: manifest.count,
        });
    }
    let eps = options.final_eps;
    if !(eps.is_finite() && eps > 0.0 && eps <= 1.0) {
        return Err(GenerateError::InvalidFinalEps(eps));
    }
    Ok(())
}

/// The manifest of the run in `out`, if the folder holds one.
fn read_manifest<F: DatasetFamily>(out: &Path) -> Result<Option<Manifest<F>>, GenerateError> {
    read_json(&out.join("manifest.json"))
}

impl<F: DatasetFamily> Manifest<F> {
    fn describe(&self) -> String {
        format!("{} seed {} count {}", self.family.name(), self.seed, self.count)
    }
}

/// Refuses a folder that holds a run of another manifest; says whether it holds one of `wanted`.
fn check_manifest<F: DatasetFamily>(out: &Path, wanted: &Manifest<F>) -> Result<bool, GenerateError> {
    match read_manifest::<F>(out)? {
        Some(found) if found != *wanted => Err(GenerateError::ManifestMismatch {
            found: found.describe(),
            wanted: wanted.describe(),
        }),
        Some(_) => Ok(true),
        None => Ok(false),
    }
}

/// As [`check_manifest`], but a run of the same scenario and seed with fewer scenarios is taken
/// too: draws are per index, so its records are the first ones of the larger run, which extends
/// it. Says whether the folder holds a manifest equal to `wanted` (if not, it is written).
fn check_manifest_or_fewer<F: DatasetFamily>(out: &Path, wanted: &Manifest<F>) -> Result<bool, GenerateError> {
    match read_manifest::<F>(out)? {
        Some(found) if found.family == wanted.family && found.seed == wanted.seed && found.count < wanted.count => {
            Ok(false)
        }
        _ => check_manifest(out, wanted),
    }
}

/// What the records of a dataset file were solved to: the `request.json` of its run folder
/// (the file's folder); `None` for a folder written before it existed.
pub fn dataset_solve_request(dataset_file: &Path) -> Result<Option<SolveRequest>, GenerateError> {
    let folder = dataset_file.parent().unwrap_or(Path::new("."));
    read_json(&folder.join("request.json"))
}

/// The solve options a run's records were solved with (`request.json`; the defaults for a
/// folder written before it existed), for work that solves more of them (repairs).
pub fn run_solve_options(out: &Path) -> Result<SolveOptions, GenerateError> {
    let found = read_json::<SolveRequest>(&out.join("request.json"))?;
    Ok(found.map_or_else(SolveOptions::default, |r| r.options()))
}

/// A canonical spacecraft as an error message names it.
fn describe_spacecraft(craft: &CanonicalSpacecraft) -> String {
    format!(
        "thrust over initial mass {:.6e}, exhaust speed {:.6} in the family's canonical units",
        craft.thrust, craft.exhaust_speed
    )
}

/// Refuses records recorded as solved for `found`, a spacecraft other than `wanted` (records that
/// do not record theirs, `None`, are taken as they are); `what` names where they are, `advice`
/// what to do.
pub fn check_spacecraft(
    found: Option<CanonicalSpacecraft>,
    wanted: &CanonicalSpacecraft,
    what: impl FnOnce() -> String,
    advice: impl Into<String>,
) -> Result<(), GenerateError> {
    match found {
        Some(found) if found != *wanted => Err(GenerateError::SpacecraftMismatch {
            what: what(),
            found,
            wanted: *wanted,
            advice: advice.into(),
        }),
        _ => Ok(()),
    }
}

/// Refuses the records of the dataset file `file` when its run recorded them as solved for a
/// spacecraft other than `wanted` (a command that reads a dataset and is given a spacecraft).
pub fn check_dataset_spacecraft(file: &Path, wanted: &CanonicalSpacecraft) -> Result<(), GenerateError> {
    check_spacecraft(
        dataset_solve_request(file)?.and_then(|r| r.spacecraft),
        wanted,
        || format!("dataset {} holds records", file.display()),
        "give the spacecraft it was solved with (--thrust-n, --isp-s, --mass-kg)",
    )
}

/// Refuses a folder whose records were solved to another final eps or arrival margin, or for
/// another spacecraft; says whether it records a request. A folder without `request.json`
/// (written before it existed) is taken as it is.
fn check_solve_request(
    out: &Path,
    options: &SolveOptions,
    spacecraft: Option<&CanonicalSpacecraft>,
) -> Result<bool, GenerateError> {
    let Some(found) = read_json::<SolveRequest>(&out.join("request.json"))? else {
        return Ok(false);
    };
    if let Some(wanted) = spacecraft {
        check_spacecraft(
            found.spacecraft,
            wanted,
            || format!("output folder {} holds records", out.display()),
            "use another --out, or give the spacecraft it was solved with (--thrust-n, --isp-s, --mass-kg)",
        )?;
    }
    if found.final_eps != options.final_eps {
        return Err(GenerateError::FinalEpsMismatch {
            found: found.final_eps,
            wanted: options.final_eps,
        });
    }
    if found.arrival_margin_steps != options.arrival_margin_steps {
        return Err(GenerateError::ArrivalMarginMismatch {
            found: found.arrival_margin_steps,
            wanted: options.arrival_margin_steps,
        });
    }
    Ok(true)
}

/// Generates (or resumes) the records of `shard` of the dataset `manifest` into `out`, held
/// for the whole run: [`hold_run`], then [`generate_in`].
pub fn generate<F: DatasetFamily>(
    manifest: Manifest<F>,
    shard: Shard,
    out: &Path,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
    show_progress: bool,
) -> Result<Summary, GenerateError> {
    let run = hold_run(manifest, shard, out, spacecraft, options)?;
    generate_in(&run, manifest, shard, spacecraft, options, show_progress)
}

/// Holds `out` (created if missing) for a run of `manifest`, or refuses. The request and a
/// manifest already in `out` are checked first, so a refused run creates no folder and leaves
/// an existing one as it was; a folder held by another run is refused ([`LockError::Held`]).
pub fn hold_run<F: DatasetFamily>(
    manifest: Manifest<F>,
    shard: Shard,
    out: &Path,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
) -> Result<RunLock, GenerateError> {
    check_request(&manifest, shard, options)?;
    check_manifest_or_fewer(out, &manifest)?;
    check_solve_request(out, options, Some(spacecraft))?;
    Ok(RunLock::acquire(out)?)
}

/// Generates (or resumes) the records of `shard` of the dataset `manifest` into the folder
/// `run` holds (see [`hold_run`]); the caller may write more into it before letting it go.
pub fn generate_in<F: DatasetFamily>(
    run: &RunLock,
    manifest: Manifest<F>,
    shard: Shard,
    spacecraft: &CanonicalSpacecraft,
    options: &SolveOptions,
    show_progress: bool,
) -> Result<Summary, GenerateError> {
    let out = run.dir();
    check_request(&manifest, shard, options)?;
    // Checked again under the hold: another run may have written its manifest meanwhile.
    let has_manifest = check_manifest_or_fewer(out, &manifest)?;
    let has_request = check_solve_request(out, options, Some(spacecraft))?;
    fs::create_dir_all(out.join("records")).map_err(io_err(out))?;
    if !has_manifest {
        write_json(&out.join("manifest.json"), &manifest)?;
    }
    if !has_request {
        write_json(&out.join("request.json"), &SolveRequest::of(options, spacecraft))?;
    }
    let indices: Vec<u64> = (0..manifest.count).filter(|&i| shard.contains(i)).collect();
    let bar = count_bar(indices.len(), "solved", show_progress);
    let resumed = AtomicUsize::new(0);
    let converged = AtomicUsize::new(0);
    let (written, unwritten) = (AtomicUsize::new(0), AtomicUsize::new(0));
    // Collected into a Result, the parallel loop takes no new index after the first error: a
    // failed write (a full disk) stops the run instead of solving records it cannot keep.
    let results: Result<Vec<F::Record>, GenerateError> = indices
        .par_iter()
        .map(|&index| {
            let path = record_path(out, index);
            // Resume: a readable record of this run is kept; a corrupt one is solved again.
            if let Ok(r) = read_record_of::<F>(&path) {
                if manifest.family.drew(&r, manifest.seed, index) {
                    resumed.fetch_add(1, Ordering::Relaxed);
                    bar.inc(1);
                    return Ok(r);
                }
            }
            let record = manifest.family.solve(manifest.seed, index, spacecraft, options);
            write_record_of::<F>(&path, &record).inspect_err(|_| {
                unwritten.fetch_add(1, Ordering::Relaxed);
            })?;
            written.fetch_add(1, Ordering::Relaxed);
            if record.figures().converged {
                converged.fetch_add(1, Ordering::Relaxed);
            }
            bar.set_message(format!("{} converged", converged.load(Ordering::Relaxed)));
            bar.inc(1);
            Ok(record)
        })
        .collect();
    bar.finish();
    let mut records = results.map_err(|e| match e {
        GenerateError::Io(path, source) if path.starts_with(out.join("records")) => GenerateError::RecordWrite {
            path,
            source,
            unwritten: unwritten.load(Ordering::Relaxed),
            written: written.load(Ordering::Relaxed) + resumed.load(Ordering::Relaxed),
        },
        other => other,
    })?;
    records.sort_by_key(|r| r.figures().index);
    if show_progress {
        eprintln!(
            "{} records resumed from an earlier run",
            resumed.load(Ordering::Relaxed)
        );
    }
    write_outputs(
        out,
        &DatasetFile {
            manifest,
            shard,
            records,
        },
    )
}

/// Combines shard dataset files into one dataset in `out`: all must come from one manifest,
/// be disjoint, and together cover every index. `out` is held while it is written, and refused
/// if it holds a run of another manifest.
pub fn merge(inputs: &[PathBuf], out: &Path) -> Result<Summary, GenerateError> {
    match inputs.first().map(|p| holds_spatial_records(p)).transpose()? {
        Some(true) => merge_of::<SpatialFamily>(inputs, out),
        _ => merge_of::<MissionFamily>(inputs, out),
    }
}

/// [`merge`] of datasets of family kind `F`.
fn merge_of<F: DatasetFamily>(inputs: &[PathBuf], out: &Path) -> Result<Summary, GenerateError> {
    let mut files = Vec::new();
    for p in inputs {
        files.push(read_dataset_of::<F>(p)?);
    }
    let Some(first) = files.first() else {
        return Err(GenerateError::Merge("no input files".into()));
    };
    let manifest = first.manifest;
    // Records of another final eps or arrival margin would make one dataset of two kinds.
    let requests = inputs
        .iter()
        .map(|p| dataset_solve_request(p))
        .collect::<Result<Vec<_>, _>>()?;
    if requests.windows(2).any(|w| w[0] != w[1]) {
        return Err(GenerateError::Merge(
            "inputs were solved to different final eps or arrival margins, or for different spacecraft (their request.json)".into(),
        ));
    }
    let request = requests.into_iter().next().flatten();
    let mut records = Vec::new();
    for f in files {
        if f.manifest != manifest {
            return Err(GenerateError::Merge(
                "inputs come from different scenarios, seeds or counts".into(),
            ));
        }
        records.extend(f.records);
    }
    records.sort_by_key(|r| r.figures().index);
    for (expected, r) in (0..manifest.count).zip(&records) {
        if r.figures().index != expected {
            return Err(GenerateError::Merge(format!(
                "index {expected} is missing or duplicated"
            )));
        }
    }
    if records.len() as u64 != manifest.count {
        return Err(GenerateError::Merge(format!(
            "{} records for a count of {}",
            records.len(),
            manifest.count
        )));
    }
    if manifest.count == 0 {
        return Err(GenerateError::EmptyCount);
    }
    // The dataset of another run in `out` is not overwritten; checked before the hold creates
    // the folder and again under it.
    check_manifest(out, &manifest)?;
    let held = RunLock::acquire(out)?;
    check_manifest(out, &manifest)?;
    if let Some(request) = &request {
        check_solve_request(held.dir(), &request.options(), request.spacecraft.as_ref())?;
        write_json(&held.dir().join("request.json"), request)?;
    }
    write_outputs(
        held.dir(),
        &DatasetFile {
            manifest,
            shard: Shard::WHOLE,
            records,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_parse_and_partition_the_indices() {
        assert_eq!("2/5".parse::<Shard>(), Ok(Shard { index: 2, count: 5 }));
        for bad in ["5/5", "1/0", "a/2", "3", "-1/2"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
        let shards: Vec<Shard> = (0..4).map(|i| Shard { index: i, count: 4 }).collect();
        for i in 0..1000u64 {
            assert_eq!(shards.iter().filter(|s| s.contains(i)).count(), 1);
        }
    }

    /// The summary counts the records classified infeasible and leaves them out of the
    /// converged / feasible ratio; a record that was not classified is not counted.
    #[test]
    fn the_summary_counts_infeasible_records() {
        let manifest = Manifest {
            family: ScenarioKind::TransferHard.family(),
            seed: 7,
            count: 4,
        };
        let record = |index: u64, converged: bool, failure: Option<&str>| TrajectoryRecord {
            family: manifest.family,
            seed: 7,
            index,
            scenario: manifest.family.draw(7, index),
            converged,
            failure: failure.map(String::from),
            costates: [0.0; 5],
            final_anomaly: None,
            final_eps: 1.0,
            final_mass: 0.8,
            thrust_arcs: 1,
            residual: 0.0,
            seconds: 1.0,
            ephemeris: Vec::new(),
            steps: Vec::new(),
            distinct_energy_optima: 1,
        };
        let records = [
            record(0, true, None),
            record(
                1,
                false,
                Some("infeasible: minimum time 400.0 d > TOF 300.0 d (ratio 1.333)"),
            ),
            record(2, false, Some("feasibility unknown (...); no energy-optimal start")),
            record(3, true, None),
        ];
        let s = summarize(&manifest, Shard::WHOLE, &records);
        assert_eq!((s.converged, s.infeasible), (2, 1));
        assert!((s.convergence_rate - 0.5).abs() < 1e-15);
        assert!((s.feasible_convergence_rate - 2.0 / 3.0).abs() < 1e-15);
    }

    /// A failed rendezvous is classified like a transfer: rendezvous-circular seed 7 #127, which
    /// the generator fails (its direct transcription stops with every segment at full throttle),
    /// is recorded infeasible with its minimum time (1.124 TOF), the old reason kept after it.
    #[test]
    fn a_failed_rendezvous_is_recorded_infeasible_with_its_minimum_time() {
        let kind = ScenarioKind::RendezvousCircular;
        let sc = shared::spacecraft::Spacecraft::MSR_ERO.canonical().unwrap();
        let options = SolveOptions::default();
        let scenario = kind.draw(7, 127);
        let mut record = crate::solver::solve_scenario(kind, 7, 127, &scenario, &sc, &options);
        let why = record.failure.clone().expect("the generator fails this draw");
        assert!(why.starts_with("no energy-optimal start"), "{why}");
        assert!(classify_failure(&mut record, &scenario, &sc, &options));
        let verdict = record.failure.as_deref().unwrap();
        assert!(
            verdict.starts_with(INFEASIBLE) && verdict.contains("(ratio 1.12") && verdict.ends_with(&why),
            "{verdict}"
        );
        assert!(!record.converged);
    }

    /// A run whose record is made a worse local optimum (its final mass lowered by 0.01, as a
    /// record from another start would be): the check flags it, the repair re-solves it from the
    /// direct solution and puts back the optimum (the record as solved, its seconds aside), and
    /// the dataset and summary follow. A second pass finds nothing to repair.
    /// A one-draw transfer-hard run (seed 7) in a fresh folder named `name`, whose record is then
    /// made a worse local optimum (its final mass lowered by 0.01, as a record from another start
    /// would be): the folder, its manifest, the record as solved and the worse one.
    struct WorseRecordRun {
        out: PathBuf,
        sc: CanonicalSpacecraft,
        manifest: Manifest,
        options: SolveOptions,
        optimum: TrajectoryRecord,
        worse: TrajectoryRecord,
    }

    fn worse_record_run(name: &str) -> WorseRecordRun {
        use shared::spacecraft::Spacecraft;
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let out = std::env::temp_dir().join(format!("lowthrust-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&out);
        let manifest = Manifest {
            family: ScenarioKind::TransferHard.family(),
            seed: 7,
            count: 1,
        };
        let options = SolveOptions::default();
        generate(manifest, Shard::WHOLE, &out, &sc, &options, false).unwrap();
        let optimum = read_record(&record_path(&out, 0)).unwrap();
        assert!(optimum.converged);
        let worse = TrajectoryRecord {
            final_mass: optimum.final_mass - 0.01,
            ..optimum.clone()
        };
        write_record(&record_path(&out, 0), &worse).unwrap();
        WorseRecordRun {
            out,
            sc,
            manifest,
            options,
            optimum,
            worse,
        }
    }

    /// A repair solves to the run's own final eps: the options of its request are what
    /// `run_solve_options` gives, and other options are refused before any record is touched.
    #[test]
    fn crosscheck_repairs_solve_to_the_runs_own_final_eps() {
        let WorseRecordRun {
            out,
            sc,
            manifest,
            options,
            worse,
            ..
        } = worse_record_run("repair-eps");
        let smoothed_out = out.with_extension("smoothed");
        let smoothed = SolveOptions {
            final_eps: 0.25,
            ..SolveOptions::default()
        };
        generate(manifest, Shard::WHOLE, &smoothed_out, &sc, &smoothed, false).unwrap();
        assert_eq!(run_solve_options(&smoothed_out).unwrap().final_eps, 0.25);
        assert_eq!(run_solve_options(&out).unwrap().final_eps, options.final_eps);
        std::fs::remove_dir_all(&smoothed_out).unwrap();
        let other = SolveOptions {
            final_eps: options.final_eps * 4.0,
            ..options
        };
        let refused = crosscheck_run(&out, &sc, &CrossCheckSettings::default(), &other, true, false);
        assert!(
            matches!(refused, Err(GenerateError::FinalEpsMismatch { .. })),
            "{refused:?}"
        );
        assert_eq!(
            read_record(&record_path(&out, 0)).unwrap(),
            worse,
            "a refused repair touched a record"
        );
        std::fs::remove_dir_all(&out).unwrap();
    }

    #[test]
    fn crosscheck_run_repairs_a_worse_record_and_rewrites_the_dataset() {
        let WorseRecordRun {
            out,
            sc,
            options,
            optimum,
            worse,
            ..
        } = worse_record_run("repair");
        let settings = CrossCheckSettings::default();
        let run = crosscheck_run(&out, &sc, &settings, &options, true, false).unwrap();
        assert!(
            matches!(&run.checks[0].1, Ok(c) if c.beats_record(settings.margin)),
            "{:?}",
            run.checks
        );
        assert_eq!(run.repaired.len(), 1, "{:?}", run.repaired);
        let (index, before, after) = run.repaired[0];
        assert_eq!((index, before), (0, worse.final_mass));
        assert!(
            (after - optimum.final_mass).abs() < 1e-9,
            "{after} vs {}",
            optimum.final_mass
        );
        let repaired = read_record(&record_path(&out, 0)).unwrap();
        assert_eq!(repaired.final_mass, after);
        assert!(repaired.seconds > worse.seconds);
        let dataset = read_dataset(&dataset_path(&out, Shard::WHOLE)).unwrap();
        assert_eq!(dataset.records[0].final_mass, after);
        assert_eq!(run.summary.unwrap().converged, 1);

        let again = crosscheck_run(&out, &sc, &settings, &options, true, false).unwrap();
        assert!(again.repaired.is_empty());
        fs::remove_dir_all(&out).unwrap();
    }

    /// A worse record whose re-solve fails (here: no homotopy budget) is cut: it stays in the
    /// run, not converged, without samples (no record filter takes it as a demonstration), with
    /// the direct solution's final mass as evidence; the dataset counts it as a failure.
    #[test]
    fn crosscheck_run_cuts_a_worse_record_that_its_re_solve_does_not_lift() {
        use crate::crosscheck::WORSE_OPTIMUM;
        use crate::demo::RecordFilter;
        let WorseRecordRun {
            out,
            sc,
            options,
            worse,
            ..
        } = worse_record_run("cut");
        let starved = SolveOptions {
            max_homotopy_solves: 0,
            max_homotopy_work: 1,
            max_transfer_homotopy_work: 1,
            ..options
        };
        let settings = CrossCheckSettings::default();
        let run = crosscheck_run(&out, &sc, &settings, &starved, true, false).unwrap();
        let Ok(check) = &run.checks[0].1 else {
            panic!("{:?}", run.checks)
        };
        assert!(check.beats_record(settings.margin));
        assert!(run.repaired.is_empty(), "{:?}", run.repaired);
        assert_eq!(run.cut, vec![(0, worse.final_mass, check.direct_final_mass)]);
        let cut = read_record(&record_path(&out, 0)).unwrap();
        assert!(!cut.converged);
        assert!(
            cut.failure.as_deref().is_some_and(|f| f.starts_with(WORSE_OPTIMUM)),
            "{:?}",
            cut.failure
        );
        assert!(!RecordFilter::Converged.accepts(&cut) && !RecordFilter::All.accepts(&cut));
        assert_eq!((cut.final_mass, cut.scenario), (worse.final_mass, worse.scenario));
        let dataset = read_dataset(&dataset_path(&out, Shard::WHOLE)).unwrap();
        assert_eq!(dataset.records[0], cut);
        let summary = run.summary.unwrap();
        assert_eq!((summary.converged, summary.failures.len()), (0, 1));
        // Nothing converged is left to check.
        let again = crosscheck_run(&out, &sc, &settings, &options, true, false).unwrap();
        assert!(again.checks.is_empty() && again.cut.is_empty());
        fs::remove_dir_all(&out).unwrap();
    }

    /// The recipe's stage checks a run once: the summary is kept, a second call on the same run
    /// returns it and touches nothing (a record made worse since stays as it is), and a run
    /// extended since is checked again.
    /// A recipe stopped after its cross-check's findings, before the records were rewritten,
    /// ends as the uninterrupted one: the same findings and the same dataset.
    #[test]
    fn a_crosscheck_stopped_before_its_rewrites_finishes_as_an_uninterrupted_one() {
        let settings = CrossCheckSettings::default();
        let whole = worse_record_run("check-whole");
        let (uninterrupted, _) = crosscheck_once(&whole.out, &whole.sc, &settings, &whole.options, false).unwrap();
        let stopped = worse_record_run("check-stopped");
        let (journalled, rewritten) =
            crosscheck_once_stopping(&stopped.out, &stopped.sc, &settings, &stopped.options, false, true).unwrap();
        assert!(rewritten.is_none());
        assert_eq!(journalled, uninterrupted);
        assert_eq!(
            read_record(&record_path(&stopped.out, 0)).unwrap(),
            stopped.worse,
            "rewritten before the stop"
        );
        assert!(stopped.out.join(JOURNAL_FILE).is_file());
        // Resumed with options that would solve nothing: the journal, not a new check, finishes it.
        let starved = SolveOptions {
            max_homotopy_solves: 0,
            max_homotopy_work: 1,
            max_transfer_homotopy_work: 1,
            ..stopped.options
        };
        let (resumed, rewritten) = crosscheck_once(&stopped.out, &stopped.sc, &settings, &starved, false).unwrap();
        assert_eq!(resumed, uninterrupted);
        assert!(rewritten.is_some());
        assert!(!stopped.out.join(JOURNAL_FILE).exists());
        let without_timing = |out: &Path| {
            let mut records = read_dataset(&dataset_path(out, Shard::WHOLE)).unwrap().records;
            records.iter_mut().for_each(|r| r.seconds = 0.0);
            records
        };
        assert_eq!(without_timing(&stopped.out), without_timing(&whole.out));
        for out in [whole.out, stopped.out] {
            fs::remove_dir_all(out).unwrap();
        }
    }

    #[test]
    fn crosscheck_once_keeps_its_findings_and_checks_an_extended_run_again() {
        let WorseRecordRun {
            out,
            sc,
            manifest,
            options,
            optimum,
            worse,
        } = worse_record_run("check-once");
        let settings = CrossCheckSettings::default();

        let (first, rewritten) = crosscheck_once(&out, &sc, &settings, &options, false).unwrap();
        // The repaired dataset's summary comes back with it.
        let dataset = read_dataset(&dataset_path(&out, Shard::WHOLE)).unwrap();
        assert_eq!(
            rewritten.map(|r| r.final_mass_mean),
            Some(dataset.records[0].final_mass)
        );
        assert_eq!((first.count, first.checked, first.beaten), (1, 1, 1), "{first:?}");
        assert_eq!(first.repaired.len(), 1);
        assert!((first.repaired[0].2 - optimum.final_mass).abs() < 1e-9);
        let saved: CrossCheckSummary = read_json(&out.join("crosscheck.json")).unwrap().unwrap();
        assert_eq!(saved, first);

        write_record(&record_path(&out, 0), &worse).unwrap();
        let (second, rewritten) = crosscheck_once(&out, &sc, &settings, &options, false).unwrap();
        assert_eq!(second, first);
        assert!(rewritten.is_none(), "nothing was rewritten");
        assert_eq!(read_record(&record_path(&out, 0)).unwrap().final_mass, worse.final_mass);

        let extended = Manifest { count: 2, ..manifest };
        generate(extended, Shard::WHOLE, &out, &sc, &options, false).unwrap();
        let (third, _) = crosscheck_once(&out, &sc, &settings, &options, false).unwrap();
        assert_eq!(third.count, 2);
        assert!(third.repaired.iter().any(|r| r.0 == 0), "{third:?}");
        assert!((read_record(&record_path(&out, 0)).unwrap().final_mass - optimum.final_mass).abs() < 1e-9);
        fs::remove_dir_all(&out).unwrap();
    }
}
