//! Issue 3: the direct transcription as a feasibility witness and a start for the indirect
//! solver. For each transfer-hard draw: the direct problem at eps = 1 on the real TOF (from
//! tangential thrust); when it converges, its multipliers give the initial costates, which seed
//! the indirect homotopy (`solve_transfer_from_start`).
//!
//! cargo run --release -p lowthrust-ground --example direct_start -- SEED:INDEX...
use lowthrust_ground::solver::direct::{solve_direct, DirectGuess, DirectOptions};
use lowthrust_ground::solver::shooting::TransferVector;
use lowthrust_ground::solver::{solve_transfer_from_start, SolveOptions};
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn main() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let per_step: usize = std::env::var("PER_STEP").map_or(2, |s| s.parse().unwrap());
    for case in std::env::args().skip(1) {
        let (seed, index) = case.split_once(':').expect("SEED:INDEX");
        let (seed, index): (u64, u64) = (seed.parse().unwrap(), index.parse().unwrap());
        let kind = ScenarioKind::TransferHard;
        let scenario = kind.draw(seed, index);
        let options = DirectOptions {
            verbose: std::env::var("DIRECT_VERBOSE").is_ok(),
            ..DirectOptions::default()
        };
        let guess = DirectGuess::tangential(
            &scenario,
            &sc,
            per_step * scenario.steps as usize,
            0.5,
            &options.tolerances,
        )
        .unwrap();
        let direct = solve_direct(&scenario, &sc, &guess, 1.0, &options).unwrap();
        println!(
            "{seed}:{index} direct eps 1 K={} converged {} m_f {:.6} onboard-infeas {:.1e} ({:.1} s) lambda0 {:?}",
            direct.segments,
            direct.converged,
            direct.final_mass,
            direct.onboard_infeasibility,
            direct.seconds,
            direct.initial_costates
        );
        let Some(l) = direct.initial_costates else { continue };
        let z = TransferVector::from_column_slice(&[l[0], l[1], l[2], l[3], l[4], direct.nu_f.unwrap()]);
        let rec = solve_transfer_from_start(kind, seed, index, &scenario, &sc, &SolveOptions::default(), z);
        println!(
            "   indirect from it: converged {} m_f {:.6} eps {:.2e} residual {:.1e} arcs {} ({:.1} s) costates {:?} {:?}",
            rec.converged, rec.final_mass, rec.final_eps, rec.residual, rec.thrust_arcs, rec.seconds, rec.costates, rec.failure
        );
    }
}
