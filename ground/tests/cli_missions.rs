//! Mission files from the outside: `ground data check-mission` reports a family's units, times,
//! solved share and tank on a sample, a family that cannot be posed is refused before any work
//! with its field named, and `generate` takes the file where a preset's name goes.

use std::path::{Path, PathBuf};
use std::process::Command;

fn ground(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_ground")).args(args).output().unwrap()
}

fn venus_inward() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/missions/venus-inward.toml")
}

fn temp(name: &str) -> PathBuf {
    let path = std::env::temp_dir().join(format!("lowthrust-cli-mission-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&path);
    let _ = std::fs::remove_file(&path);
    path
}

#[test]
fn check_mission_reports_the_family_on_a_sample() {
    let file = venus_inward();
    let out = ground(&[
        "data",
        "check-mission",
        "--scenario",
        file.to_str().unwrap(),
        "--sample",
        "4",
        "--threads",
        "1",
        "--json",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["family"].as_str().unwrap().starts_with("custom-"));
    assert_eq!(v["sample"], 4);
    assert_eq!(v["length_unit_m"], 149_597_870_700.0);
    // 250 to 320 days drawn, rounded up to whole 7-day cycles.
    let tof = v["time_of_flight_days"].as_array().unwrap();
    let (lo, hi) = (tof[0].as_f64().unwrap(), tof[1].as_f64().unwrap());
    assert!(250.0 <= lo && lo <= hi && hi < 327.0, "{tof:?}");
    assert_eq!(v["cycle_days"][0].as_f64().unwrap(), 7.0);
    let converged = v["converged"].as_u64().unwrap();
    let others = ["infeasible", "feasible_unsolved", "unknown"].map(|k| v[k].as_u64().unwrap());
    assert_eq!(converged + others.iter().sum::<u64>(), 4);
    assert!(converged >= 3, "{v}");
    // The thesis spacecraft at full thrust for the longest flight: T t / c of the initial mass.
    let burned = v["full_thrust_propellant"].as_f64().unwrap();
    let sc = shared::spacecraft::Spacecraft::MSR_ERO.canonical().unwrap();
    let expected = sc.thrust * hi * 86_400.0 / shared::units::TIME_UNIT_S / sc.exhaust_speed;
    assert!((burned - expected).abs() < 1e-9 * expected, "{burned} {expected}");
    assert!(v["warnings"].as_array().unwrap().is_empty());
    // A spacecraft whose tank empties before the flight ends is warned of.
    let out = ground(&[
        "data",
        "check-mission",
        "--scenario",
        file.to_str().unwrap(),
        "--sample",
        "2",
        "--thrust-n",
        "5",
        "--isp-s",
        "1000",
        "--mass-kg",
        "600",
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("warning: at full thrust the tank empties"), "{text}");
}

#[test]
fn a_family_that_cannot_be_posed_is_refused_before_any_work_with_its_field() {
    let text = std::fs::read_to_string(venus_inward()).unwrap();
    for (edit, needle) in [
        (
            text.replace("a = [0.70, 0.74]", "a = [0.74, 0.70]"),
            "target.a: lo > hi",
        ),
        (
            text.replace("a = [0.98, 1.02], e = [0.0, 0.01]", "a = [0.98, 1.02], e = [0.0, 1.0]"),
            "departure.e",
        ),
        (text.replace("days = 7.0", "days = 400.0"), "cycle.days"),
        (text.replace("days = 7.0", "days = -1.0"), "cycle.days"),
        (text.replace("\"sun\"", "\"vulcan\""), "vulcan"),
        (text.replace("lo_days = 250.0", "lo_days = 0.0"), "time_of_flight.days"),
        (text.replace("problem = \"transfer\"", "problem = \"flyby\""), "flyby"),
    ] {
        assert_ne!(edit, text, "{needle}: the edit did not apply");
        let file = temp("bad.toml");
        std::fs::write(&file, &edit).unwrap();
        let out_dir = temp("bad-run");
        let out = ground(&[
            "data",
            "generate",
            "--scenario",
            file.to_str().unwrap(),
            "--count",
            "2",
            "--out",
            out_dir.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(needle), "{needle}: {err}");
        assert!(!out_dir.exists(), "a refused command left {}", out_dir.display());
        let _ = std::fs::remove_file(&file);
    }
}

#[test]
fn generate_takes_a_mission_file_and_records_its_family() {
    let out_dir = temp("venus");
    let file = venus_inward();
    let out = ground(&[
        "data",
        "generate",
        "--scenario",
        file.to_str().unwrap(),
        "--count",
        "2",
        "--threads",
        "1",
        "--final-eps",
        "0.3",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["scenario"]["cycle"]["days"], 7.0);
    assert_eq!(manifest["scenario"]["body"], "sun");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap()).unwrap();
    assert!(summary["scenario"].as_str().unwrap().starts_with("custom-"));
    let _ = std::fs::remove_dir_all(&out_dir);
}

/// `ground run --plan` runs nothing: it projects each stage of a recipe from the unit costs it
/// measured, and the dataset's projection is its count of solves at the measured solve time.
#[cfg(feature = "learn")]
#[test]
fn a_recipe_plan_counts_its_stages_and_writes_nothing() {
    // venus-inward's recipe with fine-tuning after its stage: a nominal phase, then a
    // dispersed one.
    let configs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
    let recipe = std::fs::read_to_string(configs.join("venus-inward.toml")).unwrap();
    let mission = configs.join("missions/venus-inward.toml");
    let out = temp("plan");
    let config = out.with_extension("toml");
    std::fs::write(
        &config,
        format!(
            "{}\n[finetune]\nsteps = 300\nflights = 64\n[finetune.then]\nsteps = 100\nflights = 8\ndispersed = true\n",
            recipe.replace(
                "\"missions/venus-inward.toml\"",
                &format!("{:?}", mission.to_str().unwrap())
            )
        ),
    )
    .unwrap();
    let run = ground(&[
        "run",
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--plan",
        "--sample",
        "2",
        "--json",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(!out.exists(), "the plan wrote its run folder");
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let stages: Vec<&str> = v["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["stage"].as_str().unwrap())
        .collect();
    assert_eq!(
        stages,
        [
            "dataset",
            "pretraining",
            "RL",
            "relabelling",
            "dispersed: rounds",
            "fine-tuning",
            "fine-tuning, then",
            "Monte Carlo",
            "export and SIL"
        ]
    );
    let costs = &v["costs"];
    let solve = costs["solve_s"].as_f64().unwrap();
    let threads = costs["solver_threads"].as_f64().unwrap();
    let dataset = v["stages"][0]["seconds"].as_f64().unwrap();
    assert!((dataset - 1000.0 * solve / threads).abs() <= 1e-9 * dataset, "{v}");
    // Pretraining is its updates at the measured update time, plus its 9 evaluations' episodes;
    // RL its steps and its updates after the 1,000 warm-up steps.
    let pretrain_update = costs["pretrain_update_s"].as_f64().unwrap();
    let episode = costs["episode_s"].as_f64().unwrap();
    let pretraining = v["stages"][1]["seconds"].as_f64().unwrap();
    let expected = 40_000.0 * pretrain_update + 900.0 * episode;
    assert!((pretraining - expected).abs() <= 1e-9 * expected, "{v}");
    let (update, step) = (
        costs["update_s"].as_f64().unwrap(),
        costs["env_step_s"].as_f64().unwrap(),
    );
    let rl = v["stages"][2]["seconds"].as_f64().unwrap();
    let expected = 60_000.0 * step + 59_000.0 * update;
    assert!(update > 0.0 && (rl - expected).abs() <= 1e-9 * expected, "{v}");
    let total: f64 = v["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["seconds"].as_f64().unwrap())
        .sum();
    assert!((v["total_seconds"].as_f64().unwrap() - total).abs() <= 1e-9 * total);
    assert_eq!(v["rounds"], 10);
    // The `[[stage]]` "dispersed" runs rounds to 24, the first 10 the relabels of the rounds
    // before (it inherits them: loaded, not run), each of its own the recipe's round with its
    // 1,000 scoring episodes flown again against the dispersed plant.
    let round = v["round_seconds"].as_f64().unwrap();
    let relabelling = v["stages"][3]["seconds"].as_f64().unwrap();
    assert!((relabelling - 10.0 * round).abs() <= 1e-9 * relabelling, "{v}");
    let dispersed_round = round + 1000.0 * episode;
    let dispersed = v["stages"][4]["seconds"].as_f64().unwrap();
    assert!((dispersed - 14.0 * dispersed_round).abs() <= 1e-9 * dispersed, "{v}");
    // The shortest recipe: one round in each stage that runs rounds.
    let shortest = total - 9.0 * round - 13.0 * dispersed_round;
    let one_round = v["total_one_round_seconds"].as_f64().unwrap();
    assert!((one_round - shortest).abs() <= 1e-9 * total, "{v}");
    // Fine-tuning: its steps' flights at the measured flight, and 13 evaluations of 500 episodes.
    let flight = costs["finetune_flight_s"].as_f64().unwrap();
    let fine = v["stages"][5]["seconds"].as_f64().unwrap();
    let expected = 300.0 * 64.0 * flight + 13.0 * 500.0 * episode;
    assert!(flight > 0.0 && (fine - expected).abs() <= 1e-9 * expected, "{v}");
    // The dispersed phase: its flights at the measured dispersed flight, 5 evaluations.
    let dispersed_flight = costs["finetune_dispersed_flight_s"].as_f64().unwrap();
    let then = v["stages"][6]["seconds"].as_f64().unwrap();
    let expected = 100.0 * 8.0 * dispersed_flight + 5.0 * 500.0 * episode;
    assert!(
        dispersed_flight > 0.0 && (then - expected).abs() <= 1e-9 * expected,
        "{v}"
    );
    let _ = std::fs::remove_file(&config);
}

/// An inclined mission file: `check-mission` and `generate` solve its draws in three dimensions,
/// and a planar command refuses it by name.
#[test]
fn an_inclined_family_is_checked_in_three_dimensions_and_refused_by_planar_commands() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/missions/transfer-circular-inclined.toml");
    let out = ground(&[
        "data",
        "check-mission",
        "--scenario",
        file.to_str().unwrap(),
        "--sample",
        "2",
        "--seed",
        "3",
        "--json",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["inclined"], true);
    assert_eq!(v["sample"], 2);
    assert_eq!(v["converged"], 2, "{v}");
    // Generation takes it: records of the three-dimensional solver.
    let dir = temp("inclined-generate");
    let out = ground(&[
        "data",
        "generate",
        "--scenario",
        file.to_str().unwrap(),
        "--count",
        "2",
        "--seed",
        "3",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let dataset = dir.join("dataset.ltds");
    assert!(ground_core::generate::holds_spatial_records(&dataset).unwrap());
    // The first solved trajectory is drawn, projected on the xy-plane, with z against time.
    let svg = std::fs::read_to_string(dir.join("trajectories.svg")).unwrap();
    assert!(svg.contains("Fuel-optimal transfer") && svg.contains("z [million km]"));
    // The planar solver refuses it by name, before any work.
    let out = ground(&["data", "solve", "--scenario", file.to_str().unwrap(), "--index", "0"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("inclined orbits"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
