//! Issue 4, the measurement a DAgger-style lever needs first: can the indirect solver relabel
//! the states a trained policy visits? Flies the checkpoint's deterministic policy on the
//! config's Monte Carlo scenarios (the same draws as `ground evaluate`), and at fractions of the
//! flight solves the fuel-optimal transfer from the visited state to the target orbit in the time
//! left. The state's mass m enters as a spacecraft of thrust T / m (acceleration T u / m, mass
//! flow in units of m: the same dynamics), so the relabelled final mass is m * m_f'.
//! Prints, per fraction: how many relabels converged, how many were infeasible by the solver's
//! own verdict, and the relabelled final mass against the policy's own and the optimum from
//! departure.
//!
//! cargo run --release -p lowthrust-ground --example relabel_visited -- CONFIG CHECKPOINT [EPISODES] [FRACTIONS]
use lowthrust_ground::config::ExperimentConfig;
use lowthrust_ground::demo::relabel;
use lowthrust_ground::env::batch::{draw_scenarios, evaluate_batched};
use lowthrust_ground::env::{Environment, TransferEnv};
use lowthrust_ground::eval::load_agent;
use lowthrust_ground::experiment::policy_batch;
use lowthrust_ground::solver::{solve_scenario, SolveOptions};
use rayon::prelude::*;
use shared::scenario::ProblemKind;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let config = ExperimentConfig::load(std::path::Path::new(&args[0])).unwrap();
    let checkpoint = std::path::PathBuf::from(&args[1]);
    let episodes: u64 = args.get(2).map_or(20, |s| s.parse().unwrap());
    let fractions: Vec<f64> = args
        .get(3)
        .map_or("0.25,0.5,0.75".into(), |s| s.clone())
        .split(',')
        .map(|f| f.parse().unwrap())
        .collect();
    assert_eq!(config.scenario.problem(), ProblemKind::Transfer, "transfers only");
    let sc = config.env.spacecraft.canonical().unwrap();
    let agent = load_agent(&config, <TransferEnv as Environment>::OBS, &checkpoint).unwrap();
    let scenarios = draw_scenarios(config.scenario, config.seeds.monte_carlo, episodes);
    let flown =
        evaluate_batched::<TransferEnv, _>(&config.env, &scenarios, |obs| policy_batch(&agent, obs), true).unwrap();
    let options = SolveOptions::default();
    // The optimum from departure, for the policy's overspend.
    let optimal: Vec<f64> = scenarios
        .par_iter()
        .enumerate()
        .map(|(i, s)| {
            let r = solve_scenario(config.scenario, config.seeds.monte_carlo, i as u64, s, &sc, &options);
            if r.converged {
                r.final_mass
            } else {
                f64::NAN
            }
        })
        .collect();
    println!("episode,fraction,step,steps,mass_at_step,policy_final_mass,policy_dr,optimal_final_mass,relabel_converged,relabel_final_mass,relabel_seconds,relabel_failure");
    for &fraction in &fractions {
        let rows: Vec<String> = flown
            .par_iter()
            .map(|outcome| {
                let scenario = &scenarios[outcome.episode];
                let trajectory = outcome.trajectory.as_ref().unwrap();
                let k = ((fraction * scenario.steps as f64).round() as u32).clamp(1, scenario.steps - 1);
                let state = trajectory[k as usize].state;
                let (rec, _) = relabel(
                    (config.seeds.monte_carlo, outcome.episode as u64),
                    scenario,
                    &state,
                    k,
                    &sc,
                    &options,
                )
                .expect("a bound state");
                format!(
                    "{},{fraction},{k},{},{:.6},{:.6},{:.5},{:.6},{},{:.6},{:.2},\"{}\"",
                    outcome.episode,
                    scenario.steps,
                    state.m,
                    outcome.final_mass,
                    outcome.terminal.position,
                    optimal[outcome.episode],
                    rec.converged,
                    state.m * rec.final_mass,
                    rec.seconds,
                    rec.failure.unwrap_or_default().chars().take(120).collect::<String>()
                )
            })
            .collect();
        for r in rows {
            println!("{r}");
        }
    }
}
