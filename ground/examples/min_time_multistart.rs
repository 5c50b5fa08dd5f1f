//! Issue 3: a second method for the minimum time of flight of transfer draws, to cross-check the
//! classification (`solver::min_time`): every extremal of the direct multi-start
//! (`multistart_extremals`: primer guesses at several final times, scaled to H = 0, no
//! energy-optimal problem involved), with tf / TOF, and the terminal error and |H(tf)| of a fresh
//! full-thrust propagation. A draw classified infeasible for which this finds tf < TOF is feasible.
//!
//! SEED=7 CASES=24,30 cargo run --release -p lowthrust-ground --example min_time_multistart
use std::time::Instant;

use lowthrust_ground::solver::min_time::{multistart_extremals, reflown_extremal, DAYS_PER_TIME_UNIT};
use lowthrust_ground::solver::SolveOptions;
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn main() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let tolerances = SolveOptions::default().tolerances;
    let seed: u64 = std::env::var("SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(7);
    let cases: Vec<u64> = std::env::var("CASES")
        .unwrap_or_else(|_| "24".into())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    println!("index,tof_days,extremals,tf_min_ratio,seconds,all (tf/TOF, terminal error, H(tf))");
    for index in cases {
        let s = ScenarioKind::TransferHard.draw(seed, index);
        let tof = s.time_of_flight();
        let clock = Instant::now();
        let found = multistart_extremals(&s, &sc, &tolerances);
        let seconds = clock.elapsed().as_secs_f64();
        let described: Vec<String> = found
            .iter()
            .map(|z| {
                let (_, err, h) = reflown_extremal(&s, &sc, z, &tolerances).unwrap();
                format!("{:.4} {err:.0e} {h:.0e}", z[4] / tof)
            })
            .collect();
        let smallest = found
            .first()
            .map_or(String::new(), |z| format!("{:.4} z {:?}", z[4] / tof, z.as_slice()));
        println!(
            "{index},{:.1},{},{smallest},{seconds:.1},{}",
            tof * DAYS_PER_TIME_UNIT,
            found.len(),
            described.join("; ")
        );
    }
}
