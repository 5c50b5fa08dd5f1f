//! Cross-check of the indirect solver by the direct method (issue 3): for a few scenarios,
//! solves the indirect problem (`solve_scenario`) and the direct transcription on K, 2K, 4K, ...
//! segments (each mesh warm-started from the previous one, the first from tangential thrust),
//! and prints the final masses, their agreement, the mesh convergence and the run times.
//!
//! cargo run --release -p lowthrust-ground --example direct_crosscheck -- [segments-per-step] [levels] [case...]
//! cases: circular (1 -> 1.3 AU), hard:SEED:INDEX, rdv:SEED:INDEX (rendezvous-hard), rdvc:SEED:INDEX

use lowthrust_ground::dataset::{sample_at, TrajectoryRecord};
use lowthrust_ground::solver::direct::{solve_direct, DirectGuess, DirectOptions};
use lowthrust_ground::solver::pontryagin::OptimalControlParams;
use lowthrust_ground::solver::shooting::initial_state_costate;
use lowthrust_ground::solver::{solve_scenario, SolveOptions};
use shared::orbit::{OrbitElements, OrbitShape};
use shared::scenario::{Scenario, ScenarioKind};
use shared::spacecraft::CanonicalSpacecraft;
use shared::spacecraft::Spacecraft;

fn circular() -> (ScenarioKind, Scenario) {
    let initial = OrbitElements {
        shape: OrbitShape {
            a: 1.0,
            e: 1e-4,
            omega: 0.0,
        },
        nu: 0.0,
    };
    let target = OrbitShape {
        a: 1.3,
        e: 1e-4,
        omega: 0.0,
    };
    (ScenarioKind::TransferCircular, Scenario::transfer(initial, target))
}

fn parse(case: &str) -> (String, ScenarioKind, Scenario, u64, u64) {
    if case == "circular" {
        let (k, s) = circular();
        return (case.into(), k, s, 0, 0);
    }
    let parts: Vec<&str> = case.split(':').collect();
    let kind = match parts[0] {
        "hard" => ScenarioKind::TransferHard,
        "rdv" => ScenarioKind::RendezvousHard,
        "rdvc" => ScenarioKind::RendezvousCircular,
        "tc" => ScenarioKind::TransferCircular,
        other => panic!("unknown case {other}"),
    };
    let seed: u64 = parts[1].parse().unwrap();
    let index: u64 = parts[2].parse().unwrap();
    (case.into(), kind, kind.draw(seed, index), seed, index)
}

/// The indirect solution's control sampled at the segment midpoints (throttle u, polar
/// direction): a warm start for the cases where tangential thrust leads nowhere. The direct
/// solve then checks local optimality on its own mesh (and must move: the sampled control is
/// not feasible for the piecewise-constant transcription).
fn indirect_guess(rec: &TrajectoryRecord, sc: &CanonicalSpacecraft, segments: usize) -> DirectGuess {
    let tof = rec.scenario.time_of_flight();
    let h = tof / segments as f64;
    let times: Vec<f64> = (0..segments).map(|k| (k as f64 + 0.5) * h).collect();
    let params = OptimalControlParams {
        spacecraft: *sc,
        eps: rec.final_eps,
    };
    let y0 = initial_state_costate(&rec.scenario, &rec.costates);
    let samples = sample_at(&y0, &params, &times, &SolveOptions::default().tolerances).unwrap();
    DirectGuess {
        controls: samples
            .iter()
            .map(|s| {
                [
                    s.throttle * s.direction_polar[0],
                    s.throttle * s.direction_polar[1],
                    s.throttle,
                ]
            })
            .collect(),
        nu_f: rec.final_anomaly.unwrap_or(0.0),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let per_step: usize = args.first().map_or(4, |s| s.parse().unwrap());
    let levels: usize = args.get(1).map_or(3, |s| s.parse().unwrap());
    let verbose = std::env::var("DIRECT_VERBOSE").is_ok();
    let cases: Vec<String> = if args.len() > 2 {
        args[2..].to_vec()
    } else {
        vec!["circular".into()]
    };
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    for case in cases {
        let (name, kind, scenario, seed, index) = parse(&case);
        println!(
            "== {name}: a0 {:.4} e0 {:.4} -> af {:.4} ef {:.4}, {} steps (TOF {:.4})",
            scenario.initial.shape.a,
            scenario.initial.shape.e,
            scenario.target.a,
            scenario.target.e,
            scenario.steps,
            scenario.time_of_flight()
        );
        let rec = solve_scenario(kind, seed, index, &scenario, &sc, &SolveOptions::default());
        println!(
            "indirect: m_f {:.9} eps {:.3e} residual {:.1e} converged {} arcs {} ({:.1} s) {:?}",
            rec.final_mass, rec.final_eps, rec.residual, rec.converged, rec.thrust_arcs, rec.seconds, rec.failure
        );
        let options = DirectOptions {
            verbose,
            optimality: std::env::var("DIRECT_OPT").map_or(1e-9, |s| s.parse().unwrap()),
            ..DirectOptions::default()
        };
        let k0 = per_step * scenario.steps as usize;
        let tangential = if std::env::var("DIRECT_FROM_INDIRECT").is_ok() {
            println!("(warm start: the indirect solution's control, sampled per segment)");
            indirect_guess(&rec, &sc, k0)
        } else {
            DirectGuess::tangential(&scenario, &sc, k0, 0.5, &options.tolerances).unwrap()
        };
        let start_mass = 1.0
            - sc.thrust / sc.exhaust_speed * scenario.time_of_flight() / k0 as f64
                * tangential.controls.iter().map(|c| c[2]).sum::<f64>();
        println!("guess: m_f {start_mass:.9} on {k0} segments");
        // Same cost as the indirect solution (its final eps), then the fuel-optimal one (eps = 0),
        // the latter warm-started from the former's coarse solution.
        let mut coarse = None;
        for eps in [rec.final_eps, 0.0] {
            let mut guess = coarse.clone().unwrap_or_else(|| tangential.clone());
            let mut masses = Vec::new();
            for level in 0..levels {
                let sol = solve_direct(&scenario, &sc, &guess, eps, &options).unwrap();
                masses.push(sol.final_mass);
                let rel = (sol.final_mass - rec.final_mass) / rec.final_mass;
                println!(
                    "direct eps {eps:.3e} K={:5}: m_f {:.9} rel.diff {:+.2e} infeas {:.1e} onboard-infeas {:.1e} gap {:.1e} it {} conv {} ({:.1} s)",
                    sol.segments,
                    sol.final_mass,
                    rel,
                    sol.infeasibility,
                    sol.onboard_infeasibility,
                    sol.relaxation_gap,
                    sol.iterations,
                    sol.converged,
                    sol.seconds
                );
                let next = DirectGuess {
                    controls: sol.controls.clone(),
                    nu_f: sol.nu_f.unwrap_or(0.0),
                };
                if level == 0 && coarse.is_none() {
                    coarse = Some(next.clone());
                }
                guess = next.refined(2);
            }
            if masses.len() >= 3 {
                let n = masses.len();
                let (a, b, c) = (masses[n - 3], masses[n - 2], masses[n - 1]);
                let order = ((b - a) / (c - b)).abs().log2();
                let extrapolated = c + (c - b) / (2f64.powf(order) - 1.0);
                println!(
                    "mesh eps {eps:.3e}: observed order {order:.2}, Richardson m_f {extrapolated:.9} rel.diff {:+.2e}",
                    (extrapolated - rec.final_mass) / rec.final_mass
                );
            }
        }
    }
}
