//! The records of a dataset checked by a second method from a second start: the direct
//! transcription ([`crate::solver::direct`]) started on its own from tangential thrust, nothing
//! taken from the indirect solution, on the record's cost (its final eps).
//!
//! A piecewise-constant control is one of the controls the indirect method optimises over, so a
//! direct solution that flies (re-flown by the onboard propagator onto the target) and ends
//! heavier than the record proves that the record is not the optimum: it is a worse local
//! optimum. The converse is no proof: the direct method has local optima of its own, and its mesh
//! costs it a little propellant (about 6e-4 of the initial mass on 1 segment per step).
//!
//! A record so beaten is repaired ([`repair_record`]) from the direct solution that
//! beats it: that control leads the energy-optimal direct problem into its basin, whose
//! multipliers start the indirect homotopy again.

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;
use shared::spacecraft::CanonicalSpacecraft;

use crate::generate::{count_bar, DatasetRecord};
use crate::io::atomic_write;
use crate::solver::direct::{
    indirect_start_from, solve_direct_refined, DirectError, DirectGuess, DirectOptions, DirectSolution, CONTROL,
};
use crate::solver::record::TrajectoryRecord;
use crate::solver::shooting::TransferVector;
use crate::solver::spatial::direct::{
    solve_spatial_direct_refined, tangential_guess, SpatialDirectProblem, SpatialDirectSolution, CONTROL3,
};
use crate::solver::spatial::record::SpatialRecord;
use crate::solver::{solve_from_energy_start, SolveOptions};
use crate::spatial::SpatialGoal;

/// A direct solution re-flown by the onboard propagator within this terminal violation
/// (canonical units, about 15 km and 3 cm/s) reaches the target.
pub const FLOWN_VIOLATION: f64 = 1e-7;

/// What the check solves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CrossCheckSettings {
    /// Segments per 14-day step of the first mesh.
    pub segments_per_step: usize,
    /// Meshes after the first, each twice as fine and warm-started from the one before.
    pub refinements: usize,
    /// A direct final mass above the record's by more than this (fraction of the initial mass)
    /// marks the record a worse local optimum.
    pub margin: f64,
}

impl Default for CrossCheckSettings {
    fn default() -> Self {
        Self {
            // As many worse records found on 1,000 hard draws as on 2 per step, and one more,
            // at 0.4 times the cost (docs/results.md).
            segments_per_step: 1,
            refinements: 0,
            margin: 1e-3,
        }
    }
}

/// One record against the direct transcription on its finest mesh (`C` controls per segment: 3
/// in the plane, 4 in space).
#[derive(Debug, Clone, PartialEq)]
pub struct CrossCheck<const C: usize = CONTROL> {
    /// The record's scenario index.
    pub index: u64,
    /// The cost both methods optimise (the record's final homotopy parameter).
    pub final_eps: f64,
    /// Final masses, fractions of the initial mass.
    pub indirect_final_mass: f64,
    /// Final mass of the direct solution on the finest mesh, fraction of m0.
    pub direct_final_mass: f64,
    /// Segments of the finest mesh.
    pub segments: usize,
    /// Whether the direct solve converged on the finest mesh.
    pub direct_converged: bool,
    /// Terminal violation of the direct controls re-flown by the onboard propagator.
    pub onboard_violation: f64,
    /// SQP iterations over all meshes.
    pub iterations: u32,
    /// Wall time of the direct solves over all meshes, s.
    pub seconds: f64,
    /// The direct solution's controls (and nu_f): where [`repair_record`] starts.
    pub direct: DirectGuess<C>,
}

impl<const C: usize> CrossCheck<C> {
    /// The direct solution, converged or not (its last SQP iterate), is a trajectory that
    /// reaches the target: what a proof of a better record needs, optimal or not.
    pub fn direct_flies(&self) -> bool {
        self.onboard_violation < FLOWN_VIOLATION
    }

    /// The direct solution flies and ends heavier than the record by more than `margin`: the
    /// record is a worse local optimum.
    pub fn beats_record(&self, margin: f64) -> bool {
        self.direct_flies() && self.direct_final_mass > self.indirect_final_mass + margin
    }
}

/// The direct problem of `record`'s scenario from tangential thrust at half throttle on
/// `settings`' meshes, for the record's final eps: one solution per mesh, coarsest first.
fn solve_alone(
    record: &TrajectoryRecord,
    spacecraft: &CanonicalSpacecraft,
    settings: &CrossCheckSettings,
    options: &DirectOptions,
) -> Result<Vec<DirectSolution>, DirectError> {
    let scenario = &record.scenario;
    let segments = settings.segments_per_step * scenario.steps as usize;
    let guess = DirectGuess::tangential(scenario, spacecraft, segments, 0.5, &options.tolerances)?;
    solve_direct_refined(
        scenario,
        spacecraft,
        guess,
        settings.refinements,
        record.final_eps,
        options,
    )
}

/// Checks `record` against the direct problem of its scenario solved on its own (`solve_alone`).
pub fn crosscheck_record(
    record: &TrajectoryRecord,
    spacecraft: &CanonicalSpacecraft,
    settings: &CrossCheckSettings,
    options: &DirectOptions,
) -> Result<CrossCheck, DirectError> {
    let solutions = solve_alone(record, spacecraft, settings, options)?;
    check_of(record.index, record.final_eps, record.final_mass, &solutions)
}

/// The check of a record (`index`, `final_eps`, `final_mass`) against its direct `solutions`,
/// coarsest first.
fn check_of<const N: usize, const C: usize>(
    index: u64,
    final_eps: f64,
    final_mass: f64,
    solutions: &[DirectSolution<N, C>],
) -> Result<CrossCheck<C>, DirectError> {
    let finest = solutions.last().ok_or(DirectError::Guess)?;
    Ok(CrossCheck {
        index,
        final_eps,
        indirect_final_mass: final_mass,
        direct_final_mass: finest.final_mass,
        segments: finest.segments,
        direct_converged: finest.converged,
        onboard_violation: finest.onboard_infeasibility,
        iterations: solutions.iter().map(|s| s.iterations).sum(),
        seconds: solutions.iter().map(|s| s.seconds).sum(),
        // A rendezvous has no final anomaly among its unknowns (nu_f is 0 and unused).
        direct: DirectGuess {
            controls: finest.controls.clone(),
            nu_f: finest.nu_f.unwrap_or(0.0),
        },
    })
}

/// The spatial direct problem of `record`'s scenario (each orbit in its plane) from tangential
/// thrust at half throttle on `settings`' meshes, for the record's final eps.
fn solve_spatial_alone(
    record: &SpatialRecord,
    spacecraft: &CanonicalSpacecraft,
    settings: &CrossCheckSettings,
    options: &DirectOptions,
) -> Result<Vec<SpatialDirectSolution>, DirectError> {
    let goal = SpatialGoal::of_scenario(&record.scenario, *spacecraft).map_err(|_| DirectError::Kepler)?;
    let problem = SpatialDirectProblem::of_goal(&goal);
    let segments = settings.segments_per_step * record.scenario.scenario.steps as usize;
    let guess = tangential_guess(&problem, segments, 0.5, &options.tolerances)?;
    solve_spatial_direct_refined(&problem, guess, settings.refinements, record.final_eps, options)
}

/// Checks a record of an inclined family against the spatial direct transcription solved on
/// its own, as [`crosscheck_record`] a planar one; the controls re-flown by
/// `onboard::spatial::propagate_rtn`.
pub fn crosscheck_spatial_record(
    record: &SpatialRecord,
    spacecraft: &CanonicalSpacecraft,
    settings: &CrossCheckSettings,
    options: &DirectOptions,
) -> Result<CrossCheck<CONTROL3>, DirectError> {
    let solutions = solve_spatial_alone(record, spacecraft, settings, options)?;
    check_of(record.index, record.final_eps, record.final_mass, &solutions)
}

/// Re-solves `record` from the direct solution of its `check` ([`crosscheck_record`]) when that
/// beats it ([`CrossCheck::beats_record`] by `margin`): the control, solved again at eps = 1
/// on the same mesh, gives the costates that start the indirect homotopy. The new record, with
/// the seconds of the re-solve added, when it converges and ends heavier than `record` by
/// `margin`; `None` otherwise, and for a record the direct solution does not beat.
/// Transfer-circular records are rarely repaired: their homotopy from such a start stalls
/// (measured on 8 of 8 draws; the generator solves them on a near-circular path instead).
pub fn repair_record(
    record: &TrajectoryRecord,
    check: &CrossCheck,
    spacecraft: &CanonicalSpacecraft,
    margin: f64,
    options: &SolveOptions,
) -> Option<TrajectoryRecord> {
    let clock = std::time::Instant::now();
    if !record.converged || check.index != record.index || !check.beats_record(margin) {
        return None;
    }
    let (costates, nu_f) = indirect_start_from(&record.scenario, spacecraft, &check.direct).ok()?;
    let mut start = TransferVector::zeros();
    start.fixed_rows_mut::<5>(0).copy_from_slice(&costates);
    start[5] = nu_f.unwrap_or(0.0);
    let repaired = solve_from_energy_start(
        record.family,
        record.seed,
        record.index,
        &record.scenario,
        spacecraft,
        options,
        start,
    );
    // Heavier by the margin too: a re-solve that lands back on the record's optimum is no repair.
    let better = repaired.converged && repaired.final_mass > record.final_mass + margin;
    better.then(|| TrajectoryRecord {
        seconds: record.seconds + clock.elapsed().as_secs_f64(),
        ..repaired
    })
}

/// The failure reason of a record cut as a worse local optimum starts with this.
pub const WORSE_OPTIMUM: &str = "worse local optimum:";

/// A record that a direct solution beats by the margin and whose re-solve from it
/// ([`repair_record`]) did not end heavier: proven not the optimum and not repaired, it is no
/// demonstration. It stays in the run, not converged, without its trajectory samples (so no
/// record filter takes it), with the evidence as its failure.
pub fn cut_record(record: &TrajectoryRecord, check: &CrossCheck) -> TrajectoryRecord {
    TrajectoryRecord {
        converged: false,
        failure: Some(format!(
            "{WORSE_OPTIMUM} the direct transcription ends at {:.4} of the initial mass, this record's \
             indirect solution at {:.4}; no re-solve from the direct solution ended heavier",
            check.direct_final_mass, record.final_mass
        )),
        ephemeris: Vec::new(),
        steps: Vec::new(),
        ..record.clone()
    }
}

/// A dataset record the check solves again by the direct transcription: a planar record
/// ([`crosscheck_record`], `C` = 3 controls per segment) or an inclined one
/// ([`crosscheck_spatial_record`], 4).
pub trait CrossCheckedRecord<const C: usize>: DatasetRecord {
    /// Checks the record against the direct transcription of its scenario solved on its own.
    fn crosscheck(
        &self,
        spacecraft: &CanonicalSpacecraft,
        settings: &CrossCheckSettings,
        options: &DirectOptions,
    ) -> Result<CrossCheck<C>, DirectError>;
}

impl CrossCheckedRecord<CONTROL> for TrajectoryRecord {
    fn crosscheck(
        &self,
        spacecraft: &CanonicalSpacecraft,
        settings: &CrossCheckSettings,
        options: &DirectOptions,
    ) -> Result<CrossCheck, DirectError> {
        crosscheck_record(self, spacecraft, settings, options)
    }
}

impl CrossCheckedRecord<CONTROL3> for SpatialRecord {
    fn crosscheck(
        &self,
        spacecraft: &CanonicalSpacecraft,
        settings: &CrossCheckSettings,
        options: &DirectOptions,
    ) -> Result<CrossCheck<CONTROL3>, DirectError> {
        crosscheck_spatial_record(self, spacecraft, settings, options)
    }
}

/// Checks the converged records among `records` (the first `limit` of them, all with `None`)
/// in parallel, in index order; a direct solve that fails outright is returned as its error.
/// Planar and inclined records alike ([`CrossCheckedRecord`]).
pub fn crosscheck_records<R: CrossCheckedRecord<C>, const C: usize>(
    records: &[R],
    limit: Option<usize>,
    spacecraft: &CanonicalSpacecraft,
    settings: &CrossCheckSettings,
    show_progress: bool,
) -> Vec<(u64, Result<CrossCheck<C>, DirectError>)> {
    let chosen: Vec<&R> = records
        .iter()
        .filter(|r| r.figures().converged)
        .take(limit.unwrap_or(usize::MAX))
        .collect();
    let bar = count_bar(chosen.len(), "records checked", show_progress);
    let beaten = AtomicUsize::new(0);
    let options = DirectOptions::default();
    let checks = chosen
        .par_iter()
        .map(|record| {
            let check = record.crosscheck(spacecraft, settings, &options);
            if matches!(&check, Ok(c) if c.beats_record(settings.margin)) {
                beaten.fetch_add(1, Ordering::Relaxed);
            }
            bar.set_message(format!("{} beaten", beaten.load(Ordering::Relaxed)));
            bar.inc(1);
            (record.figures().index, check)
        })
        .collect();
    bar.finish();
    checks
}

/// The checks as CSV, one row per record (an outright failure has its reason and no figures),
/// written atomically.
pub fn write_crosscheck_csv<const C: usize>(
    path: &Path,
    checks: &[(u64, Result<CrossCheck<C>, DirectError>)],
    margin: f64,
) -> std::io::Result<()> {
    let mut csv = String::from(
        "index,final_eps,indirect_final_mass,direct_final_mass,difference,segments,direct_converged,onboard_violation,record_beaten,iterations,seconds,error\n",
    );
    for (index, check) in checks {
        match check {
            Ok(c) => csv.push_str(&format!(
                "{},{:e},{},{},{:e},{},{},{:e},{},{},{},\n",
                c.index,
                c.final_eps,
                c.indirect_final_mass,
                c.direct_final_mass,
                c.direct_final_mass - c.indirect_final_mass,
                c.segments,
                c.direct_converged,
                c.onboard_violation,
                c.beats_record(margin),
                c.iterations,
                c.seconds
            )),
            Err(e) => csv.push_str(&format!("{index},,,,,,,,,,,\"{}\"\n", e.to_string().replace('"', "'"))),
        }
    }
    atomic_write(path, csv.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::{solve_scenario, SolveOptions};
    use shared::scenario::ScenarioKind;
    use shared::spacecraft::Spacecraft;

    /// A transfer-circular record against the direct transcription, and the same record with
    /// its final mass lowered by 0.01 (what a worse local optimum looks like): the direct
    /// solution flies, ends at most the mesh's loss below the true record, beats the lowered one
    /// and not the true one. An unconverged record is not checked.
    #[test]
    fn the_direct_solution_beats_a_worse_record_and_not_the_optimum() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let kind = ScenarioKind::TransferCircular;
        let record = solve_scenario(kind, 7, 3, &kind.draw(7, 3), &sc, &SolveOptions::default());
        assert!(record.converged, "{:?}", record.failure);
        let worse = TrajectoryRecord {
            index: 4,
            final_mass: record.final_mass - 0.01,
            ..record.clone()
        };
        let unconverged = TrajectoryRecord {
            index: 5,
            converged: false,
            ..record.clone()
        };
        let settings = CrossCheckSettings::default();
        let checks = crosscheck_records(&[record.clone(), worse, unconverged], None, &sc, &settings, false);
        assert_eq!(checks.iter().map(|(i, _)| *i).collect::<Vec<_>>(), [3, 4]);
        let true_check = checks[0].1.as_ref().unwrap();
        let worse_check = checks[1].1.as_ref().unwrap();
        assert!(true_check.direct_flies(), "{true_check:?}");
        let difference = true_check.direct_final_mass - true_check.indirect_final_mass;
        assert!((-1e-3..1e-6).contains(&difference), "{true_check:?}");
        assert!(!true_check.beats_record(settings.margin));
        assert!(worse_check.beats_record(settings.margin), "{worse_check:?}");

        let dir = std::env::temp_dir().join(format!("lowthrust-crosscheck-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("crosscheck.csv");
        write_crosscheck_csv(&path, &checks, settings.margin).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let beaten: Vec<&str> = text.lines().skip(1).map(|l| l.split(',').nth(8).unwrap()).collect();
        assert_eq!(beaten, ["false", "true"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A record of the inclined transfer family against the spatial direct transcription from
    /// its own start, and the same record with its final mass lowered by 0.01: the direct
    /// solution flies (re-flown by the onboard RTN propagator), ends at most the mesh's loss below
    /// the true record, beats the lowered one and not the true one.
    #[test]
    fn an_inclined_record_is_checked_by_the_spatial_direct_transcription() {
        use crate::mission::FamilySpec;
        use crate::solver::spatial::record::solve_spatial_draw;
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/missions/transfer-circular-inclined.toml");
        let family = FamilySpec::from_argument(path.to_str().unwrap())
            .unwrap()
            .spatial_family()
            .unwrap();
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let record = solve_spatial_draw(&family, 7, 3, &sc, &SolveOptions::default());
        assert!(record.converged, "{:?}", record.failure);
        let settings = CrossCheckSettings::default();
        let options = DirectOptions::default();
        let check = crosscheck_spatial_record(&record, &sc, &settings, &options).unwrap();
        assert!(check.direct_flies() && check.direct_converged, "{check:?}");
        let difference = check.direct_final_mass - check.indirect_final_mass;
        assert!((-1e-3..1e-6).contains(&difference), "{check:?}");
        assert!(!check.beats_record(settings.margin));
        let worse = SpatialRecord {
            final_mass: record.final_mass - 0.01,
            ..record
        };
        let worse_check = crosscheck_spatial_record(&worse, &sc, &settings, &options).unwrap();
        assert!(worse_check.beats_record(settings.margin), "{worse_check:?}");
    }

    /// Solves draw `index` of `seed`, checks that the direct transcription beats its record and
    /// that the record re-solved from it converges just above the direct solution (by less
    /// than the mesh's cost: a continuous control does a little better). The record and the
    /// repaired one.
    fn repaired_just_above_the_direct_solution(
        kind: ScenarioKind,
        seed: u64,
        index: u64,
    ) -> (TrajectoryRecord, TrajectoryRecord) {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let record = solve_scenario(
            kind,
            seed,
            index,
            &kind.draw(seed, index),
            &sc,
            &SolveOptions::default(),
        );
        assert!(record.converged, "{:?}", record.failure);
        let settings = CrossCheckSettings::default();
        let check = crosscheck_record(&record, &sc, &settings, &DirectOptions::default()).unwrap();
        assert!(check.beats_record(settings.margin), "{check:?}");
        let repaired = repair_record(&record, &check, &sc, settings.margin, &SolveOptions::default()).unwrap();
        assert!(repaired.converged && repaired.residual < 1e-8);
        let above_direct = repaired.final_mass - check.direct_final_mass;
        assert!(
            (0.0..1e-3).contains(&above_direct),
            "{} vs {}",
            repaired.final_mass,
            check.direct_final_mass
        );
        (record, repaired)
    }

    /// Transfer-hard seed 8 #76: the multi-start's record is a worse local optimum (0.7496 of
    /// the initial mass); the direct transcription from tangential thrust ends at 0.7761 (1
    /// segment per step) and the record re-solved from it at 0.7764, just above the direct one
    /// (its mesh costs a little). A record the direct solution does not beat is left alone.
    #[test]
    fn a_worse_local_optimum_is_repaired_from_the_direct_solution() {
        let (record, repaired) = repaired_just_above_the_direct_solution(ScenarioKind::TransferHard, 8, 76);
        assert!(repaired.final_mass > record.final_mass + 0.02);
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let settings = CrossCheckSettings::default();
        let again = crosscheck_record(&repaired, &sc, &settings, &DirectOptions::default()).unwrap();
        assert_eq!(
            repair_record(&repaired, &again, &sc, settings.margin, &SolveOptions::default()),
            None
        );
    }

    /// A rendezvous likewise: rendezvous-circular seed 7 #85, whose record (0.5698) is far below
    /// what the direct transcription reaches (0.7375), is re-solved onto the better optimum
    /// (0.7379), with the body met: the record converges, its residual small.
    #[test]
    fn a_worse_rendezvous_record_is_repaired_too() {
        let (_, repaired) = repaired_just_above_the_direct_solution(ScenarioKind::RendezvousCircular, 7, 85);
        assert!(repaired.final_anomaly.is_none());
    }
}
