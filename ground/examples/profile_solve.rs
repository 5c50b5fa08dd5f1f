//! Where the time of one solve goes: multi-start at eps = 1 vs the homotopy.
use std::time::Instant;

use lowthrust_ground::solver::pontryagin::OptimalControlParams;
use lowthrust_ground::solver::shooting::{solve_transfer, solve_transfer_homotopy, FINAL_EPS};
use lowthrust_ground::solver::{transfer_guesses, SolveOptions};
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn main() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let opts = SolveOptions::default();
    for index in 0..6 {
        if std::env::var("FULL").is_ok() {
            let kind = if std::env::var("HARD").is_ok() {
                ScenarioKind::TransferHard
            } else {
                ScenarioKind::TransferCircular
            };
            let scenario = kind.draw(7, index);
            let r = lowthrust_ground::solver::solve_scenario(kind, 7, index, &scenario, &sc, &opts);
            println!(
                "case {index}: conv {} eps {:.2e} m {:.5} optima {} {:.2}s {:?}",
                r.converged, r.final_eps, r.final_mass, r.distinct_energy_optima, r.seconds, r.failure
            );
            continue;
        }
        let kind = if std::env::var("HARD").is_ok() {
            ScenarioKind::TransferHard
        } else {
            ScenarioKind::TransferCircular
        };
        let scenario = kind.draw(7, index);
        let t = Instant::now();
        let mut first = None;
        let mut ok = 0;
        for (k, z0) in transfer_guesses(&scenario).iter().enumerate() {
            let t1 = Instant::now();
            let p = OptimalControlParams {
                spacecraft: sc,
                eps: 1.0,
            };
            let o = solve_transfer(&scenario, &p, z0, &opts.tolerances, &opts.newton).unwrap();
            if o.converged {
                ok += 1;
                first.get_or_insert(o.z);
            }
            println!(
                "  guess {k}: conv {} it {} {:?}",
                o.converged,
                o.iterations,
                t1.elapsed()
            );
        }
        println!(
            "case {index}: a0 {:.3} af {:.3} steps {}: multistart {ok}/20 in {:?}",
            scenario.initial.shape.a,
            scenario.target.a,
            scenario.steps,
            t.elapsed()
        );
        if let Some(z) = first {
            let t = Instant::now();
            let levels =
                solve_transfer_homotopy(&scenario, &sc, &z, &opts.tolerances, &opts.newton, FINAL_EPS, 60).unwrap();
            let last = levels.iter().rev().find(|l| l.outcome.converged).map(|l| l.eps);
            println!("  homotopy to {:?} in {:?}", last, t.elapsed());
        }
    }
}
