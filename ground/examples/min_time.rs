//! Issue 3: the minimum time of flight of transfer draws (`solver::min_time`): for each chosen
//! draw, whether the energy-optimal problem could be continued from a longer time of flight down
//! to the draw's own (recovered), or the minimum-time extremal where that continuation stopped,
//! with tf_min / TOF, a fresh full-thrust propagation's terminal error and |H(tf)|.
//!
//! SEED=7 CASES=47,50,62 cargo run --release -p lowthrust-ground --example min_time
use std::time::Instant;

use lowthrust_ground::solver::min_time::{classify_transfer, reflown_extremal, Feasibility, DAYS_PER_TIME_UNIT};
use lowthrust_ground::solver::SolveOptions;
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn main() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let options = SolveOptions::default();
    let seed: u64 = std::env::var("SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(7);
    let cases: Vec<u64> = std::env::var("CASES")
        .unwrap_or_else(|_| "62".into())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    println!("index,tof_days,class,tf_min_days,ratio,stopped_at_ratio,terminal_err,h_tf,seconds,detail");
    for index in cases {
        let s = ScenarioKind::TransferHard.draw(seed, index);
        let tof = s.time_of_flight();
        let clock = Instant::now();
        let result = classify_transfer(&s, &sc, &options);
        let seconds = clock.elapsed().as_secs_f64();
        let days = |t: f64| t * DAYS_PER_TIME_UNIT;
        match result {
            Feasibility::Recovered { z } => {
                println!("{index},{:.1},recovered,,,,,,{seconds:.1},nu_f {:.4}", days(tof), z[5])
            }
            Feasibility::MinTime { tf_min, z, stopped_at } => {
                let (y, err, h) = reflown_extremal(&s, &sc, &z, &options.tolerances).unwrap();
                let class = if tf_min > tof {
                    "infeasible"
                } else {
                    "feasible-unsolved"
                };
                println!(
                    "{index},{:.1},{class},{:.1},{:.4},{:.4},{err:.1e},{h:.1e},{seconds:.1},m_f {:.4} z {:?}",
                    days(tof),
                    days(tf_min),
                    tf_min / tof,
                    stopped_at / tof,
                    y[4],
                    z.as_slice()
                );
            }
            Feasibility::Unknown(why) => println!("{index},{:.1},unknown,,,,,,{seconds:.1},{why}", days(tof)),
        }
    }
}
