//! Issue 3 diagnostics: the energy-optimal start by continuation in the target alone
//! (`solver::continuation`) on chosen draws: where it stops, how long it takes, and the crude
//! delta-v ratio of `hard_feasibility` (needed estimate / available at full thrust), and where it
//! stops, the fraction of the flight at full thrust of the solution at 0.97 of that s.
//!
//! KIND=transfer-hard CASES=1,19,21 cargo run --release -p lowthrust-ground --example target_continuation
use std::time::Instant;

use lowthrust_ground::dataset::sample_at;
use lowthrust_ground::solver::pontryagin::OptimalControlParams;
use lowthrust_ground::solver::shooting::initial_state_costate;
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
    println!("index,a0,e0,af,ef,tof,dv_ratio,reached,seconds,full_thrust_fraction_near_stop");
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
        let seconds = clock.elapsed().as_secs_f64();
        // Near the stop: how much of the flight the energy-optimal solution spends at full
        // thrust (all of it: the intermediate target is at the edge of what the engine reaches
        // in the time of flight). The path is linear in s, so the path to the scenario at
        // 0.97 s* is the first 0.97 s* of this one.
        let full = if reached < 1.0 && reached > 0.0 {
            let near = continuation::intermediate(&s, 0.97 * reached);
            let z = match near.problem {
                ProblemKind::Transfer => continuation::transfer_start(&near, &sc, &options)
                    .ok()
                    .map(|z| [z[0], z[1], z[2], z[3], z[4]]),
                ProblemKind::Rendezvous => continuation::rendezvous_start(&near, &sc, &options)
                    .ok()
                    .map(|z| [z[0], z[1], z[2], z[3], z[4]]),
            };
            z.and_then(|z| {
                let params = OptimalControlParams {
                    spacecraft: sc,
                    eps: 1.0,
                };
                let times: Vec<f64> = (0..=200).map(|k| tof * k as f64 / 200.0).collect();
                let y0 = initial_state_costate(&near, &z);
                sample_at(&y0, &params, &times, &options.tolerances).ok()
            })
            .map_or(f64::NAN, |samples| {
                samples.iter().filter(|p| p.throttle > 0.99).count() as f64 / samples.len() as f64
            })
        } else {
            f64::NAN
        };
        println!(
            "{index},{:.3},{:.3},{:.3},{:.3},{tof:.2},{:.3},{reached:.3},{:.2},{full:.3}",
            o.a,
            o.e,
            t.a,
            t.e,
            estimate / available,
            seconds
        );
    }
}
