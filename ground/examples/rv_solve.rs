//! Issue 3 session 6: solves chosen draws end to end (`solve_scenario`) with the homotopy's work
//! budget and solve count overridable, and prints each record's outcome.
//!
//! KIND=rendezvous-circular SEED=7 CASES=33,60 HWORK=9000000 HSOLVES=120 cargo run --release -p lowthrust-ground --example rv_solve
use std::time::Instant;

use lowthrust_ground::solver::{solve_scenario, SolveOptions};
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn var<T: std::str::FromStr>(name: &str) -> Option<T> {
    std::env::var(name).ok().and_then(|s| s.parse().ok())
}

fn main() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let mut options = SolveOptions::default();
    if let Some(w) = var("HWORK") {
        options.max_homotopy_work = w;
    }
    if let Some(n) = var("HSOLVES") {
        options.max_homotopy_solves = n;
    }
    let kind = ScenarioKind::ALL
        .into_iter()
        .find(|k| Some(k.name()) == std::env::var("KIND").ok().as_deref())
        .unwrap_or(ScenarioKind::RendezvousCircular);
    let seed: u64 = var("SEED").unwrap_or(7);
    let cases = std::env::var("CASES").unwrap_or_else(|_| "0".into());
    for index in cases.split(',').filter_map(|s| s.trim().parse::<u64>().ok()) {
        let s = kind.draw(seed, index);
        let clock = Instant::now();
        let r = solve_scenario(kind, seed, index, &s, &sc, &options);
        println!(
            "#{index}: converged {} eps {:.3e} residual {:.2e} m_f {:.6} arcs {} in {:.2} s {}",
            r.converged,
            r.final_eps,
            r.residual,
            r.final_mass,
            r.thrust_arcs,
            clock.elapsed().as_secs_f64(),
            r.failure.unwrap_or_default()
        );
    }
}
