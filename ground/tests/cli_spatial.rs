//! The three-dimensional indirect method from the outside: `ground data solve-3d` solves a
//! problem file and writes its optimum and trajectory, a bad problem file is refused with its
//! field named and nothing written, and `ground data check-3d` compares planar draws.

use std::path::{Path, PathBuf};
use std::process::Command;

fn ground(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_ground")).args(args).output().unwrap()
}

fn temp(name: &str) -> PathBuf {
    let path = std::env::temp_dir().join(format!("lowthrust-cli-3d-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&path);
    let _ = std::fs::remove_file(&path);
    path
}

fn earth_mars() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/missions/earth-mars-optimum.toml")
}

#[test]
fn solve_3d_writes_the_optimum_and_its_trajectory() {
    let out_dir = temp("earth-mars");
    let out = ground(&[
        "data",
        "solve-3d",
        "--problem",
        earth_mars().to_str().unwrap(),
        "--json",
        "--out",
        out_dir.to_str().unwrap(),
        "--missed-thrust",
        "8",
        "--plot",
        out_dir.join("optimum.svg").to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let printed: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // Eight cycles of 43.6 days, each lost in turn: the last is the arrival burn's.
    let cases = printed["missed_thrust"].as_array().unwrap();
    assert_eq!(cases.len(), 8);
    assert!(cases[7]["failure"].as_str().unwrap().contains("no time left"));
    let missed_csv = std::fs::read_to_string(out_dir.join("missed-thrust.csv")).unwrap();
    assert_eq!(missed_csv.lines().count(), 9);
    let svg = std::fs::read_to_string(out_dir.join("optimum.svg")).unwrap();
    assert!(
        svg.starts_with("<svg") && svg.contains("extra propellant"),
        "{}",
        &svg[..80.min(svg.len())]
    );
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("optimum.json")).unwrap()).unwrap();
    assert_eq!(printed["final_mass_kg"], written["final_mass_kg"]);
    let mass = printed["final_mass_kg"].as_f64().unwrap();
    let propellant = printed["propellant_kg"].as_f64().unwrap();
    assert!((mass + propellant - 1000.0).abs() < 1e-9 && mass > 600.23, "{printed}");
    assert!(printed["residual"].as_f64().unwrap() <= 1e-8);
    // The trajectory starts at the departure and ends at the arrival state of the file (km).
    let csv = std::fs::read_to_string(out_dir.join("trajectory.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 401);
    let last = rows.last().unwrap();
    assert!((last[0] - 348.79).abs() < 1e-9);
    for (got, want) in last[1..4].iter().zip([-1.727e8, 1.770e8, 7.949e6]) {
        assert!((got - want).abs() < 2.0, "arrival position {got} km against {want}");
    }
    assert!((last[7] - mass).abs() < 1e-9);
    let _ = std::fs::remove_dir_all(&out_dir);
    let out = ground(&[
        "data",
        "solve-3d",
        "--problem",
        earth_mars().to_str().unwrap(),
        "--missed-thrust",
        "0",
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--missed-thrust"));
    // Margins that leave nothing to fly are refused by name.
    for (flag, value) in [
        ("--thrust-margin", "0.6"),
        ("--thrust-margin", "NaN"),
        ("--arrival-margin", "40"),
    ] {
        let out = ground(&[
            "data",
            "solve-3d",
            "--problem",
            earth_mars().to_str().unwrap(),
            "--missed-thrust",
            "40",
            flag,
            value,
        ]);
        assert!(!out.status.success(), "{flag} {value}");
        assert!(String::from_utf8_lossy(&out.stderr).contains(flag), "{flag} {value}");
    }
}

#[test]
fn a_bad_problem_file_is_refused_with_its_field_named_and_nothing_written() {
    let file = temp("bad.toml");
    let text = std::fs::read_to_string(earth_mars())
        .unwrap()
        .replace("v_km_s = [-16.427, -14.861, 0.092]", "");
    std::fs::write(&file, text).unwrap();
    let out_dir = temp("bad-out");
    let out = ground(&[
        "data",
        "solve-3d",
        "--problem",
        file.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("arrival") && err.contains("velocity"), "{err}");
    assert!(!out_dir.exists());
    let _ = std::fs::remove_file(&file);
}

#[test]
fn check_3d_compares_planar_draws() {
    let out = ground(&[
        "data",
        "check-3d",
        "--scenario",
        "rendezvous-circular",
        "--seed",
        "7",
        "--count",
        "4",
        "--json",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["draws"], 4);
    assert!(v["both_solved"].as_u64().unwrap() >= 3, "{v}");
    assert!(v["worst_relative_difference"].as_f64().unwrap() < 1e-8);
    let out = ground(&[
        "data",
        "check-3d",
        "--scenario",
        "transfer-hard",
        "--seed",
        "7",
        "--count",
        "2",
        "--json",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["both_solved"].as_u64().unwrap() >= 1, "{v}");
}

#[test]
fn solve_3d_solves_an_inclined_transfer_to_a_target_orbit() {
    let file = temp("inclined.toml");
    std::fs::write(
        &file,
        "time_of_flight_days = 686.0\n[spacecraft]\nmax_thrust_n = 1.33\nisp_s = 3872.0\ninitial_mass_kg = 3366.0\n\
         [departure]\nr = [1.0, 0.0, 0.0]\nv = [0.0, 1.0, 0.0]\n\
         [target_orbit]\na = 1.3\ne = 0.0001\ninclination_deg = 5.0\n",
    )
    .unwrap();
    let out = ground(&["data", "solve-3d", "--problem", file.to_str().unwrap(), "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(
        v["residual"].as_f64().unwrap() <= 1e-8 && v["final_anomaly_deg"].is_number(),
        "{v}"
    );
    // Both goals at once are refused.
    let both = std::fs::read_to_string(&file).unwrap() + "[arrival]\nr = [0.0, 1.3, 0.0]\nv = [-0.87, 0.0, 0.0]\n";
    std::fs::write(&file, both).unwrap();
    let out = ground(&["data", "solve-3d", "--problem", file.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("either [arrival]"));
    let _ = std::fs::remove_file(&file);
}

/// `generate` solves for the spacecraft it is given and records it: Zavoli and Federici's
/// Earth–Mars family with their spacecraft ends near their optimum's mass (603.556 kg of
/// 1,000, the departure dispersed by 1 km and 50 m/s), and the commands that read the dataset or
/// resume its folder with another spacecraft (the thesis's, the default) refuse it.
#[test]
fn generate_solves_for_the_given_spacecraft_and_readers_refuse_another() {
    let out_dir = temp("spacecraft");
    let family = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/missions/earth-mars.toml");
    let study = ["--thrust-n", "0.5", "--isp-s", "2000", "--mass-kg", "1000"];
    let generate = |craft: &[&str]| {
        let mut args = vec![
            "data",
            "generate",
            "--scenario",
            family.to_str().unwrap(),
            "--count",
            "2",
            "--threads",
            "1",
            "--final-eps",
            "0.004",
            "--out",
            out_dir.to_str().unwrap(),
        ];
        args.extend_from_slice(craft);
        ground(&args)
    };
    let out = generate(&study);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["converged"], 2, "{summary}");
    let mass = summary["final_mass_mean"].as_f64().unwrap();
    // Within 0.005 (the homotopy stops at eps 0.004, the departures are dispersed); the thesis's
    // spacecraft ends near 0.70 on this family.
    assert!(
        (mass - 0.603556).abs() < 5e-3,
        "final mass {mass}, the study's optimum 0.603556"
    );
    let request: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("request.json")).unwrap()).unwrap();
    assert!(request["spacecraft"]["thrust"].as_f64().unwrap() > 0.0, "{request}");

    let files = |dir: &Path| {
        let mut names: Vec<_> = std::fs::read_dir(dir.join("records"))
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        names.sort();
        names
    };
    let before = (files(&out_dir), std::fs::read(out_dir.join("request.json")).unwrap());
    // Resumed for the default spacecraft: refused, the folder as it was.
    let resumed = generate(&[]);
    assert!(!resumed.status.success());
    let why = String::from_utf8_lossy(&resumed.stderr);
    assert!(
        why.contains("another spacecraft") && why.contains("--thrust-n"),
        "{why}"
    );
    assert_eq!(
        (files(&out_dir), std::fs::read(out_dir.join("request.json")).unwrap()),
        before
    );
    // Read for the default spacecraft: refused; for the study's: checked.
    let demos = |craft: &[&str]| {
        let mut args = vec!["data", "demos", "--dataset", out_dir.to_str().unwrap()];
        args.extend_from_slice(craft);
        ground(&args)
    };
    let refused = demos(&[]);
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("another spacecraft"));
    let checked = demos(&study);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stderr));
    let _ = std::fs::remove_dir_all(&out_dir);
}
