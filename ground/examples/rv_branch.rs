//! Issue 3 session 6 diagnostics: rendezvous energy-optimal starts by continuation in the target
//! along paths that move the body's phase the shorter way round plus `turns` whole turns.
//!
//! SEED=7 CASES=5,31 TURNS=-1,0,1 cargo run --release -p lowthrust-ground --example rv_branch
use std::f64::consts::PI;
use std::time::Instant;

use lowthrust_ground::solver::{continuation, pontryagin, SolveOptions};
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn list<T: std::str::FromStr>(var: &str, default: &str) -> Vec<T> {
    std::env::var(var)
        .unwrap_or_else(|_| default.into())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect()
}

fn main() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let options = SolveOptions::default();
    let kind = match std::env::var("KIND").as_deref() {
        Ok("rendezvous-hard") => ScenarioKind::RendezvousHard,
        _ => ScenarioKind::RendezvousCircular,
    };
    let seed: u64 = std::env::var("SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(7);
    let turns: Vec<i32> = list("TURNS", "-1,0,1");
    for index in list::<u64>("CASES", "0") {
        let s = kind.draw(seed, index);
        let (o, t) = (s.initial.shape, s.target);
        let tof = s.time_of_flight();
        let (n0, nf) = (o.a.powf(-1.5), t.a.powf(-1.5));
        let theta0 = o.omega + s.initial.nu;
        let d0 = (t.omega + s.target_nu0 - theta0).rem_euclid(2.0 * PI);
        let d0 = if d0 > PI { d0 - 2.0 * PI } else { d0 };
        // Body's lead at arrival over a spacecraft drifting at the mean motion of the mean orbit.
        let lead = d0 + (nf - 0.5 * (n0 + nf)) * tof;
        println!(
            "#{index}: a {:.3} -> {:.3}, tof {tof:.2}, phase lead at t0 {:.1} deg, lead at tf over the mean drift {:.1} deg",
            o.a,
            t.a,
            d0.to_degrees(),
            lead.to_degrees()
        );
        for &k in &turns {
            let clock = Instant::now();
            let w = pontryagin::work_done();
            let r = continuation::rendezvous_start_turning(&s, &sc, &options, k);
            println!(
                "  turns {k:+}: {} in {:.2} s, {} k steps",
                match r {
                    Ok(z) => format!("reached s = 1, |z| {:.3}", z.norm()),
                    Err(s) => format!("stopped at s = {s:.3}"),
                },
                clock.elapsed().as_secs_f64(),
                (pontryagin::work_done() - w) / 1000
            );
        }
    }
}
