//! Issue 3, opt-in after `ground generate`: classifies the transfer records of a finished
//! (whole) run that found no energy-optimal start by their minimum time of flight
//! (`generate::classify_run`): "infeasible: minimum time X d > TOF Y d ...", "feasible: ...", or
//! "feasibility unknown (...)", then rewrites the records, the dataset and the summaries
//! (summary.json gains the infeasible count and converged / (records - infeasible)).
//!
//! cargo run --release -p lowthrust-ground --example classify_infeasible -- OUT_DIR
use std::path::PathBuf;

use lowthrust_ground::generate::classify_run;
use lowthrust_ground::solver::SolveOptions;
use shared::spacecraft::Spacecraft;

fn main() {
    let out: PathBuf = std::env::args()
        .nth(1)
        .expect("usage: classify_infeasible OUT_DIR")
        .into();
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let summary = classify_run(&out, &sc, &SolveOptions::default()).unwrap_or_else(|e| panic!("{e}"));
    for (index, why) in &summary.failures {
        println!("#{index}: {why}");
    }
    println!(
        "{}: {} records, {} converged, {} infeasible, converged / feasible = {:.3}",
        summary.scenario, summary.records, summary.converged, summary.infeasible, summary.feasible_convergence_rate
    );
}
