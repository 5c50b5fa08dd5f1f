//! Datasets of an inclined family: the same generation as a planar family's (records written as
//! solved, resumed, sharded and merged to the same bytes), with records of the
//! three-dimensional solver whose samples are checked against the orbits they must join, and
//! folders and files of one kind refused by the other.

use std::path::PathBuf;

use ground_core::generate::{
    dataset_path, generate, holds_spatial_records, merge, read_dataset, read_dataset_of, trajectory_difference,
    GenerateError, Manifest, Shard,
};
use ground_core::solver::SolveOptions;
use shared::mission::SpatialFamily;
use shared::orbit::{cross3, dot3, norm3, OrbitPlane};
use shared::scenario::{Range, ScenarioKind};
use shared::spacecraft::Spacecraft;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lowthrust-spatial-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// Transfer-circular's orbits, the target inclined by 2 to 5 degrees with any node.
fn inclined() -> SpatialFamily {
    let inclination = Range {
        lo: 2f64.to_radians(),
        hi: 5f64.to_radians(),
    };
    SpatialFamily::inclined_target(ScenarioKind::TransferCircular.family(), inclination)
}

/// The unit normal of an orbit plane: (sin i sin raan, -sin i cos raan, cos i).
fn normal(plane: &OrbitPlane) -> [f64; 3] {
    let (si, ci) = plane.inclination.sin_cos();
    [si * plane.raan.sin(), -si * plane.raan.cos(), ci]
}

#[test]
fn an_inclined_family_generates_records_that_join_the_target_orbit_and_resume_and_merge_to_the_same_bytes() {
    let family = inclined();
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let options = SolveOptions::default();
    let manifest = Manifest {
        family,
        seed: 5,
        count: 4,
    };
    let whole = temp_dir("whole");
    let summary = generate(manifest, Shard::WHOLE, &whole, &sc, &options, false).unwrap();
    assert!(summary.converged >= 3, "{summary:?}");
    assert!(summary.scenario.starts_with("custom-"));
    let path = dataset_path(&whole, Shard::WHOLE);
    assert!(holds_spatial_records(&path).unwrap());
    // A planar reader refuses the file by its magic.
    assert!(matches!(read_dataset(&path), Err(GenerateError::Corrupt(..))));
    let first = read_dataset_of::<SpatialFamily>(&path).unwrap();
    for r in first.records.iter().filter(|r| r.converged) {
        assert_eq!(r.scenario, family.draw(5, r.index));
        assert_eq!(r.steps.len(), r.scenario.scenario.steps as usize + 1);
        let start = &r.steps[0];
        assert_eq!(start.state, r.scenario.departure());
        assert_eq!(start.m, 1.0);
        // Propellant only flows out, the throttle is a throttle, the direction a unit vector.
        for pair in r.ephemeris.windows(2) {
            assert!(pair[1].m <= pair[0].m + 1e-15);
        }
        for s in r.ephemeris.iter().chain(&r.steps) {
            assert!((0.0..=1.0).contains(&s.throttle));
            assert!((norm3(&s.direction) - 1.0).abs() < 1e-12);
        }
        // The arrival lies on the target orbit: its plane (the angular momentum along the
        // plane's normal), its energy -1 / (2 a) and its eccentricity, from the sampled state.
        let end = r.steps.last().unwrap().state;
        let h = cross3(&end.r, &end.v);
        let n = normal(&r.scenario.target_plane);
        let off_plane = norm3(&cross3(&h, &n)) / norm3(&h);
        assert!(off_plane < 1e-7 && dot3(&h, &n) > 0.0, "#{}: {off_plane:e}", r.index);
        let target = r.scenario.scenario.target;
        assert!((end.energy() + 0.5 / target.a).abs() < 1e-7, "#{}", r.index);
        // The solver's final mass, and the samples' propagated from sample to sample: the
        // same flight integrated on two grids (tolerances 1e-12).
        let dm = (r.final_mass - r.steps.last().unwrap().m).abs();
        assert!(dm < 1e-10, "#{}: {dm:e}", r.index);
        assert!(r.final_mass < 1.0 && r.final_mass > 0.5);
    }
    // Resumed: nothing solved again (the solve times too are the records'), the same bytes.
    let bytes = std::fs::read(&path).unwrap();
    generate(manifest, Shard::WHOLE, &whole, &sc, &options, false).unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), bytes);
    let again = read_dataset_of::<SpatialFamily>(&path).unwrap();
    assert_eq!(again, first);
    // Two shards, merged: the whole run's trajectories.
    let shards: Vec<PathBuf> = (0..2)
        .map(|i| {
            let out = temp_dir(&format!("shard{i}"));
            let shard = Shard { index: i, count: 2 };
            generate(manifest, shard, &out, &sc, &options, false).unwrap();
            dataset_path(&out, shard)
        })
        .collect();
    let merged = temp_dir("merged");
    merge(&shards, &merged).unwrap();
    let merged_file = read_dataset_of::<SpatialFamily>(&dataset_path(&merged, Shard::WHOLE)).unwrap();
    assert_eq!(trajectory_difference(&merged_file, &first), None);
    // A planar family's run refuses the inclined folder, with the reason.
    let planar = Manifest {
        family: ScenarioKind::TransferCircular.family(),
        seed: 5,
        count: 4,
    };
    let refused = generate(planar, Shard::WHOLE, &whole, &sc, &options, false).unwrap_err();
    assert!(refused.to_string().contains("inclined orbits"), "{refused}");
    // With an arrival margin the records end early, and the dataset says by how much.
    let margin = SolveOptions {
        arrival_margin_steps: 2,
        ..options
    };
    let early = temp_dir("margin");
    generate(manifest, Shard::WHOLE, &early, &sc, &margin, false).unwrap();
    let early_file = read_dataset_of::<SpatialFamily>(&dataset_path(&early, Shard::WHOLE)).unwrap();
    // Each solved to arrive 2 cycles early where that converges, on time otherwise.
    let shortfalls: Vec<u32> = early_file
        .records
        .iter()
        .zip(&first.records)
        .filter(|(a, _)| a.converged)
        .map(|(a, b)| b.scenario.scenario.steps - a.scenario.scenario.steps)
        .collect();
    assert!(
        shortfalls.contains(&2) && shortfalls.iter().all(|&d| d == 0 || d == 2),
        "{shortfalls:?}"
    );
    let loaded = <ground_core::env::Spatial as ground_core::demo::DemoGeometry>::load_dataset(&dataset_path(
        &early,
        Shard::WHOLE,
    ))
    .unwrap();
    assert_eq!(loaded.arrival_margin, 2);
    let _ = std::fs::remove_dir_all(early);
    for dir in [whole, merged]
        .into_iter()
        .chain(shards.iter().map(|p| p.parent().unwrap().to_path_buf()))
    {
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// The Earth–Mars family (its orbits given by the study's states) poses the very rendezvous of
/// the problem file given by the same states: the same departure, the body coasted back from
/// the arrival state and forward again to it, the same time of flight in 40 cycles, and the
/// same optimum. A state given beside elements, or an arrival for a transfer, is refused.
#[test]
fn the_earth_mars_family_poses_the_problem_files_rendezvous() {
    use ground_core::mission::FamilySpec;
    use ground_core::spatial::{SpatialGoal, SpatialProblemSpec};
    let configs = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/missions");
    let dispersed = FamilySpec::from_argument(configs.join("earth-mars.toml").to_str().unwrap())
        .unwrap()
        .spatial_family()
        .unwrap();
    // The mission file disperses the departure by the study's state uncertainty; without it, it
    // is the problem file's nominal.
    let family = shared::mission::SpatialFamily {
        departure_dispersion: shared::mission::StateDispersion::NONE,
        ..dispersed
    };
    let posed = SpatialProblemSpec::from_file(&configs.join("earth-mars-optimum.toml"))
        .unwrap()
        .pose()
        .unwrap();
    let sc = posed.spacecraft.canonical_in(&posed.units).unwrap();
    let draw = family.draw(0, 0);
    assert_eq!(draw.scenario.steps, 40);
    let (SpatialGoal::Rendezvous(ours), SpatialGoal::Rendezvous(theirs)) =
        (SpatialGoal::of_scenario(&draw, sc).unwrap(), posed.goal)
    else {
        panic!("both are rendezvous");
    };
    let gap = |a: &shared::orbit::SpatialState, b: &shared::orbit::SpatialState| {
        a.r.iter()
            .chain(&a.v)
            .zip(b.r.iter().chain(&b.v))
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
    };
    assert!(gap(&ours.departure, &theirs.departure) < 1e-14);
    // A dispersed draw departs within six sigmas of the nominal on each axis, and not on it.
    let moved = dispersed.draw(0, 0).departure();
    let sigma = dispersed.departure_dispersion;
    let nominal = draw.departure();
    for k in 0..3 {
        assert!((moved.r[k] - nominal.r[k]).abs() < 6.0 * sigma.position);
        assert!((moved.v[k] - nominal.v[k]).abs() < 6.0 * sigma.velocity);
    }
    assert!(gap(&moved, &nominal) > 0.0);
    assert!(
        gap(&ours.arrival, &theirs.arrival) < 1e-12,
        "{:e}",
        gap(&ours.arrival, &theirs.arrival)
    );
    assert!((ours.time_of_flight - theirs.time_of_flight).abs() < 1e-14);
    let options = SolveOptions::default();
    let (a, b) = (
        SpatialGoal::Rendezvous(ours)
            .solve(&options)
            .unwrap()
            .solution
            .final_mass,
        SpatialGoal::Rendezvous(theirs)
            .solve(&options)
            .unwrap()
            .solution
            .final_mass,
    );
    assert!((a - b).abs() < 1e-9 * b, "{a} vs {b}");
    assert!((a * 1000.0 - 603.556).abs() < 5e-4, "{a}");
    // One cycle early, two ways: the family's draw shortened by an arrival margin (the body
    // coasted forward from departure over 39 cycles) and the problem file's goal met a cycle
    // early (its arrival coasted back one): the same optimum.
    let margin = SolveOptions {
        arrival_margin_steps: 1,
        ..options
    };
    let early =
        ground_core::solver::spatial::record::solve_spatial_arriving_early(&family, (0, 0), &draw, &sc, &margin);
    assert!(
        early.converged && early.scenario.scenario.steps == 39,
        "{:?}",
        early.failure
    );
    let cycle = theirs.time_of_flight / 40.0;
    let b_early = SpatialGoal::Rendezvous(theirs)
        .arriving_early(cycle)
        .unwrap()
        .solve(&options)
        .unwrap()
        .solution
        .final_mass;
    assert!(
        (early.final_mass - b_early).abs() < 1e-8 * b_early,
        "{} vs {b_early}",
        early.final_mass
    );
    // Refusals, each naming its field.
    let text = std::fs::read_to_string(configs.join("earth-mars.toml")).unwrap();
    let refusal = |edit: &dyn Fn(&str) -> String| {
        let table: ground_core::mission::FamilyTable = toml::from_str(&edit(&text)).unwrap();
        FamilySpec::Table(table).spatial_family().unwrap_err().to_string()
    };
    let both = refusal(&|t| t.replace("departure = { state = {", "departure = { a = 1.0, state = {"));
    assert!(both.starts_with("departure.state:"), "{both}");
    let transfer = refusal(&|t| t.replace("problem = \"rendezvous\"", "problem = \"transfer\""));
    assert!(transfer.starts_with("target.arrival:"), "{transfer}");
    let drawn = refusal(&|t| t.replace("{ days = 348.79 }", "{ lo_days = 300.0, hi_days = 400.0 }"));
    assert!(drawn.contains("fixed time of flight"), "{drawn}");
    // A velocity along the radius: no orbit plane.
    let radial = refusal(&|t| {
        t.replace(
            "v = [0.32817739, -0.94271519, 0.00001456]",
            "v = [-0.94050597, -0.34501610, 0.00000655]",
        )
    });
    assert!(radial.starts_with("departure.state:"), "{radial}");
}

/// An arrival state with a cycle in days that does not divide the time of flight: the flight is
/// rounded up to whole cycles, and the body is where the arrival state puts it at the end of
/// the flight as flown.
#[test]
fn an_arrival_state_is_met_at_the_end_of_the_flight_as_flown() {
    use ground_core::mission::{FamilySpec, FamilyTable};
    use ground_core::spatial::SpatialGoal;
    let configs = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/missions");
    let text = std::fs::read_to_string(configs.join("earth-mars.toml"))
        .unwrap()
        .replace("cycle = { count = 40 }", "cycle = { days = 7.0 }");
    let table: FamilyTable = toml::from_str(&text).unwrap();
    let family = FamilySpec::Table(table).spatial_family().unwrap();
    let draw = family.draw(0, 0);
    // 348.79 days in 7-day cycles: 50 cycles, 350 days.
    assert_eq!(draw.scenario.steps, 50);
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let SpatialGoal::Rendezvous(goal) = SpatialGoal::of_scenario(&draw, sc).unwrap() else {
        panic!("a rendezvous");
    };
    let units = family.family.body.units();
    let km = |x: f64| x * units.length_m / 1e3;
    let km_s = |x: f64| x * units.velocity_m_s() / 1e3;
    let given = ([-1.727e8, 1.770e8, 7.949e6], [-16.427, -14.861, 0.092]);
    for k in 0..3 {
        assert!((km(goal.arrival.r[k]) - given.0[k]).abs() < 1e-3, "{:?}", goal.arrival);
        assert!((km_s(goal.arrival.v[k]) - given.1[k]).abs() < 1e-10);
    }
}
