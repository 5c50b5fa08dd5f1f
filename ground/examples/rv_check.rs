//! Issue 3 session 6: re-checks the converged records of a rendezvous dataset file: a fresh plain
//! propagation of each record's costates against the five terminal conditions, and the fraction
//! of the flight on the throttle ramp at the record's eps.
//!
//! cargo run --release -p lowthrust-ground --example rv_check -- DIR/dataset.ltds [DIR2/dataset.ltds]
use lowthrust_ground::generate::read_dataset;
use lowthrust_ground::solver::pontryagin::{ramp_fraction, OptimalControlParams};
use lowthrust_ground::solver::shooting::{
    initial_state_costate, RendezvousShooting, RendezvousVector, ShootingProblem,
};
use lowthrust_ground::solver::SolveOptions;
use shared::spacecraft::Spacecraft;

fn main() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let tolerances = SolveOptions::default().tolerances;
    for path in std::env::args().skip(1) {
        let file = read_dataset(std::path::Path::new(&path)).unwrap();
        let (mut worst, mut ramps) = (0.0f64, Vec::new());
        for r in file.records.iter().filter(|r| r.converged) {
            let z = RendezvousVector::from_column_slice(&r.costates);
            let problem = RendezvousShooting {
                scenario: &r.scenario,
                spacecraft: sc,
            };
            let f = problem.residual_only(r.final_eps, &z, &tolerances).unwrap().amax();
            let params = OptimalControlParams {
                spacecraft: sc,
                eps: r.final_eps,
            };
            let y0 = initial_state_costate(&r.scenario, &r.costates);
            let ramp = ramp_fraction(&params, &y0, r.scenario.time_of_flight(), &tolerances).unwrap();
            worst = worst.max(f);
            ramps.push((ramp, r.index));
            if std::env::var_os("ALL").is_some() {
                println!(
                    "#{} residual {f:.2e} ramp {ramp:.4} m_f {:.6} arcs {}",
                    r.index, r.final_mass, r.thrust_arcs
                );
            }
        }
        ramps.sort_by(|a, b| a.0.total_cmp(&b.0));
        let n = ramps.len();
        println!(
            "{path}: {n} converged, largest fresh residual {worst:.2e}, ramp fraction median {:.4}, largest {:?}",
            ramps[n / 2].0,
            &ramps[n.saturating_sub(5)..]
        );
    }
}
