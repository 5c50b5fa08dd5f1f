//! Issue 3 diagnostics: the energy-optimal start by continuation in the target alone
//! (`solver::continuation`) on chosen draws: where it stops, how long it takes, and the crude
//! delta-v ratio of `hard_feasibility` (needed estimate / available at full thrust).
//!
//! KIND=transfer-hard CASES=1,19,21 cargo run --release -p lowthrust-ground --example target_continuation
use std::time::Instant;

use lowthrust_ground::solver::{continuation, SolveOptions};
use shared::scenario::{ProblemKind, ScenarioKind};
use shared::spacecraft::Spacecraft;

fn main() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let mut options = SolveOptions::default();
    if let Some(w) = std::env::var("WORK").ok().and_then(|s| s.parse().ok()) {
        options.max_start_work = w;
    }
    let kind = match std::env::var("KIND").as_deref() {
        Ok("rendezvous-circular") => ScenarioKind::RendezvousCircular,
        _ => ScenarioKind::TransferHard,
    };
    let cases: Vec<u64> = std::env::var("CASES")
        .unwrap_or_else(|_| "0".into())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    println!("index,a0,e0,af,ef,tof,dv_ratio,reached,seconds");
    for index in cases {
        let s = kind.draw(7, index);
        let (o, t) = (s.initial.shape, s.target);
        let tof = s.time_of_flight();
        let available = sc.exhaust_speed * (1.0 / (1.0 - (sc.thrust * tof / sc.exhaust_speed).min(0.999))).ln();
        let h = |a: f64, e: f64| (a * (1.0 - e * e)).sqrt();
        let v_peri = |a: f64, e: f64| ((1.0 + e) / (a * (1.0 - e))).sqrt();
        let v_max = v_peri(o.a, o.e).max(v_peri(t.a, t.e));
        let r_max = (o.a * (1.0 + o.e)).max(t.a * (1.0 + t.e));
        let estimate = ((0.5 / o.a - 0.5 / t.a).abs() / v_max).max((h(t.a, t.e) - h(o.a, o.e)).abs() / r_max);
        let clock = Instant::now();
        let reached = match s.problem {
            ProblemKind::Transfer => continuation::transfer_start(&s, &sc, &options).map(|_| 1.0),
            ProblemKind::Rendezvous => continuation::rendezvous_start(&s, &sc, &options).map(|_| 1.0),
        };
        let reached = reached.unwrap_or_else(|s| s);
        println!(
            "{index},{:.3},{:.3},{:.3},{:.3},{tof:.2},{:.3},{reached:.3},{:.2}",
            o.a,
            o.e,
            t.a,
            t.e,
            estimate / available,
            clock.elapsed().as_secs_f64()
        );
    }
}
