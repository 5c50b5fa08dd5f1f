//! Mission families through the data path: the thesis presets solve to the records that format
//! 1 held (files written before families were data), a family written field by field like a
//! preset gives the preset's dataset, and a family of another body, time of flight and cycle
//! generates, resumes and is refused where another family's folder is.

use std::path::{Path, PathBuf};

use ground_core::generate::{generate, read_dataset, trajectory_difference, GenerateError, Manifest, Shard};
use ground_core::mission::{FamilySpec, FamilyTable};
use ground_core::solver::SolveOptions;
use shared::mission::{Cycle, MissionFamily, TimeOfFlight};
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lowthrust-family-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(name)
}

/// The thesis presets: 3 draws of seed 5, solved at the default settings by the build before
/// families were data (format 1), read and solved again now: the same scenarios and the same
/// solutions, bit for bit (solve times aside).
#[test]
fn presets_solve_to_the_records_of_format_one() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    for kind in [ScenarioKind::TransferCircular, ScenarioKind::RendezvousCircular] {
        let old = read_dataset(&fixture(&format!("{}-seed5-format1.ltds", kind.name()))).unwrap();
        assert_eq!(old.manifest.family, kind.family());
        assert_eq!(old.records.len(), 3);
        for r in &old.records {
            assert_eq!(
                r.scenario,
                kind.draw(5, r.index),
                "format-1 scenarios read with 14-day cycles"
            );
        }
        let out = temp_dir(kind.name());
        let manifest = Manifest {
            family: kind.family(),
            seed: 5,
            count: 3,
        };
        generate(manifest, Shard::WHOLE, &out, &sc, &SolveOptions::default(), false).unwrap();
        let new = read_dataset(&out.join("dataset.ltds")).unwrap();
        assert_eq!(trajectory_difference(&old, &new), None, "{}", kind.name());
        let _ = std::fs::remove_dir_all(&out);
    }
}

/// A family in a mission file, written field by field like transfer-hard, is transfer-hard: its
/// manifest names the preset and its dataset equals the preset's.
#[test]
fn a_family_given_field_by_field_like_a_preset_gives_the_presets_dataset() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let options = SolveOptions {
        final_eps: 0.3,
        ..SolveOptions::default()
    };
    let file = temp_dir("file.toml");
    std::fs::write(
        &file,
        toml::to_string(&FamilyTable::of(&ScenarioKind::TransferHard.family())).unwrap(),
    )
    .unwrap();
    let family = FamilySpec::from_argument(file.to_str().unwrap())
        .unwrap()
        .family()
        .unwrap();
    let (by_table, by_name) = (temp_dir("by-table"), temp_dir("by-name"));
    for (out, family) in [(&by_table, family), (&by_name, ScenarioKind::TransferHard.family())] {
        let manifest = Manifest {
            family,
            seed: 2,
            count: 3,
        };
        generate(manifest, Shard::WHOLE, out, &sc, &options, false).unwrap();
    }
    let (a, b) = (
        read_dataset(&by_table.join("dataset.ltds")).unwrap(),
        read_dataset(&by_name.join("dataset.ltds")).unwrap(),
    );
    assert_eq!(trajectory_difference(&a, &b), None);
    let manifest = std::fs::read_to_string(by_table.join("manifest.json")).unwrap();
    assert!(manifest.contains("\"scenario\": \"transfer-hard\""), "{manifest}");
    for dir in [&by_table, &by_name, &file] {
        let _ = std::fs::remove_dir_all(dir);
        let _ = std::fs::remove_file(dir);
    }
}

fn inward() -> MissionFamily {
    let text = r#"
problem = "transfer"
body = "sun"
departure = { a = [0.98, 1.02], e = [0.0, 0.01] }
target = { a = [0.70, 0.74], e = [0.0, 0.01] }
time_of_flight = { lo_days = 250.0, hi_days = 320.0 }
cycle = { days = 7.0 }
"#;
    FamilySpec::Table(toml::from_str(text).unwrap()).family().unwrap()
}

/// A custom family (inward, drawn time of flight, 7-day cycles) generates records whose step
/// samples sit on its cycle's grid and whose solutions meet their targets; its manifest holds
/// the table, a resumed run solves nothing again, and another family's run in the folder is
/// refused with both families named.
#[test]
fn a_custom_family_generates_resumes_and_refuses_another() {
    let family = inward();
    assert_eq!(
        family.time_of_flight,
        TimeOfFlight::Drawn {
            lo_days: 250.0,
            hi_days: 320.0
        }
    );
    assert_eq!(family.cycle, Cycle::Days(7.0));
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let options = SolveOptions {
        final_eps: 0.3,
        ..SolveOptions::default()
    };
    let out = temp_dir("inward");
    let manifest = Manifest {
        family,
        seed: 4,
        count: 3,
    };
    let summary = generate(manifest, Shard::WHOLE, &out, &sc, &options, false).unwrap();
    assert!(summary.converged >= 2, "{summary:?}");
    assert!(summary.scenario.starts_with("custom-"));
    let first = read_dataset(&out.join("dataset.ltds")).unwrap();
    let units = family.body.units();
    for r in first.records.iter().filter(|r| r.converged) {
        assert_eq!(r.family, family);
        assert_eq!(r.scenario, family.draw(4, r.index));
        let days = units.to_days(r.scenario.time_of_flight());
        assert!((250.0..327.0).contains(&days), "{days}");
        assert_eq!(r.steps.len(), r.scenario.steps as usize + 1);
        for (k, s) in r.steps.iter().enumerate() {
            assert_eq!(s.t, k as f64 * r.scenario.cycle);
        }
        // Arrived on the target orbit: radius within the orbit's range of radii.
        let last = r.steps.last().unwrap();
        let radius = last.r[0].hypot(last.r[1]);
        let (a, e) = (r.scenario.target.a, r.scenario.target.e);
        assert!(
            radius > a * (1.0 - e) - 1e-6 && radius < a * (1.0 + e) + 1e-6,
            "{radius}"
        );
    }
    let manifest_text = std::fs::read_to_string(out.join("manifest.json")).unwrap();
    assert!(manifest_text.contains("\"lo_days\": 250.0"), "{manifest_text}");
    // Resumed: every record is read back, none solved again.
    generate(manifest, Shard::WHOLE, &out, &sc, &options, false).unwrap();
    let again = read_dataset(&out.join("dataset.ltds")).unwrap();
    assert_eq!(again, first);
    // Another family in the same folder.
    let mut weekly_other = family;
    weekly_other.cycle = Cycle::Days(10.0);
    let other = Manifest {
        family: weekly_other,
        ..manifest
    };
    let refused = generate(other, Shard::WHOLE, &out, &sc, &options, false).unwrap_err();
    assert!(matches!(refused, GenerateError::ManifestMismatch { .. }));
    let text = refused.to_string();
    assert!(
        text.contains(family.label().as_str()) && text.contains(weekly_other.label().as_str()),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(&out);
}

/// An inclined family is solved in three dimensions: a plane change costs propellant, so each
/// draw of a family whose target is inclined by 3 degrees ends lighter than the same draw with
/// the target in the departure plane, which the planar solver solves. The shipped mission file
/// reads as such a family.
#[test]
fn an_inclined_family_is_checked_in_three_dimensions_and_costs_more_than_the_coplanar_one() {
    use ground_core::mission::check_family;
    use shared::mission::{PlaneRanges, SpatialFamily};
    use shared::scenario::Range;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/missions/transfer-circular-inclined.toml");
    let shipped = FamilySpec::from_argument(path.to_str().unwrap())
        .unwrap()
        .spatial_family()
        .unwrap();
    assert_eq!(
        shipped.family.departure,
        ScenarioKind::TransferCircular.family().departure
    );
    assert!((shipped.target_plane.inclination.hi - 5f64.to_radians()).abs() < 1e-15);
    assert!(FamilySpec::from_argument(path.to_str().unwrap())
        .unwrap()
        .family()
        .is_err());
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let options = SolveOptions::default();
    let three_degrees = Range {
        lo: 3f64.to_radians(),
        hi: 3f64.to_radians(),
    };
    for index in 0..2 {
        let inclined = SpatialFamily {
            target_plane: PlaneRanges {
                inclination: three_degrees,
                ..shipped.target_plane
            },
            ..shipped
        };
        let draw = |family: &SpatialFamily| {
            // One draw at a time: draw 0 of seed 100 + index.
            check_family(family, &sc, 1, 100 + index, &options)
        };
        let (tilted, flat) = (draw(&inclined), draw(&SpatialFamily::planar(shipped.family)));
        assert!(tilted.inclined && !flat.inclined);
        assert_eq!((tilted.converged, flat.converged), (1, 1), "{tilted:?} {flat:?}");
        assert!(
            tilted.final_mass_mean < flat.final_mass_mean - 1e-4,
            "{} vs {}",
            tilted.final_mass_mean,
            flat.final_mass_mean
        );
    }
}
