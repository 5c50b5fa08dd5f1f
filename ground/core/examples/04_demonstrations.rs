//! A solved trajectory turned into MDP experience (`demo`), and flown back through the
//! environment (`env`). For every 14-day step k the demonstration holds (s_k, a_k, r_k, s_k+1,
//! done_k): the environment's observations of the optimal states, and as the action the
//! zero-order-hold equivalent of the optimal control over the step (its mean polar thrust
//! vector w, encoded as throttle |w| and direction w/|w|). The one-step mismatch is how far the
//! environment's own step from s_k under a_k lands from the optimal s_k+1: zero on coast steps
//! (exact Kepler), the hold error where the optimal throttle switches inside the step. The whole
//! action sequence is then replayed open loop from departure, where the mismatches accumulate.
//!
//! Run (the default is transfer-circular seed 7 draw 0, about a second):
//!
//! ```text
//! cargo run --release -p lowthrust-ground-core --example 04_demonstrations
//! cargo run --release -p lowthrust-ground-core --example 04_demonstrations -- --scenario rendezvous-hard --seed 1 --index 1
//! ```

use clap::Parser;
use ground_core::demo::{default_tolerances, record_demonstration};
use ground_core::env::{EnvConfig, Environment, MdpEnv, Planar, Problem, Rendezvous, Transfer};
use ground_core::solver::record::TrajectoryRecord;
use ground_core::solver::{solve_scenario, SolveOptions};
use onboard::dynamics::SpacecraftState;
use shared::scenario::{ProblemKind, ScenarioKind};
use shared::units::{AU_M, VELOCITY_UNIT_M_S};

/// Turn one solved draw into experience tuples and replay them in the environment.
#[derive(Parser, Debug)]
struct Args {
    /// Distribution of the draw (transfer-circular, transfer-hard, rendezvous-circular,
    /// rendezvous-hard).
    #[arg(long, default_value = "transfer-circular")]
    scenario: ScenarioKind,
    /// Seed of the draw.
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Index of the draw.
    #[arg(long, default_value_t = 0)]
    index: u64,
}

/// AU to km, AU/t* to m/s.
const KM: f64 = AU_M / 1e3;
const M_S: f64 = VELOCITY_UNIT_M_S;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    let config = EnvConfig::default();
    let spacecraft = config.spacecraft.canonical()?;
    let scenario = args.scenario.draw(args.seed, args.index);
    let record = solve_scenario(
        args.scenario,
        args.seed,
        args.index,
        &scenario,
        &spacecraft,
        &SolveOptions::default(),
    );
    println!(
        "{} seed {} #{}: a {:.4} -> {:.4} AU, {} steps; solved: converged {}, m_f {:.6}, {} arcs, {:.1} s",
        args.scenario.name(),
        args.seed,
        args.index,
        scenario.initial.shape.a,
        scenario.target.a,
        scenario.steps,
        record.converged,
        record.final_mass,
        record.thrust_arcs,
        record.seconds
    );
    if !record.converged {
        let why = record.failure.as_deref().unwrap_or("no reason given");
        return Err(format!("the draw did not converge ({why}): no demonstration").into());
    }
    match scenario.problem {
        ProblemKind::Transfer => demonstrate::<Transfer>(&record, &config),
        ProblemKind::Rendezvous => demonstrate::<Rendezvous>(&record, &config),
    }
}

fn demonstrate<P: Problem<Geometry = Planar>>(
    record: &TrajectoryRecord,
    config: &EnvConfig,
) -> Result<(), Box<dyn std::error::Error>> {
    let demo = record_demonstration::<P>(record, config, &default_tolerances())?;

    // One row per step; consecutive coast steps (thrust off, no mismatch) share a row.
    println!("\nexperience tuples and one-step mismatch (environment step from s_k under a_k vs optimal s_k+1):");
    println!(
        "  {:>7} {:>6} {:>6} {:>22} {:>8} {:>10} {:>9} {:>9}",
        "steps", "u_mean", "u_zoh", "action a_k", "r_k", "dr (km)", "dv (m/s)", "dm (kg)"
    );
    let kg = config.spacecraft.initial_mass_kg;
    // A shared row shows the sum of its rewards.
    let mut coast_from: Option<u32> = None;
    let mut coast_reward = 0.0;
    let pairs: Vec<_> = demo.transitions.iter().zip(&demo.mismatch).collect();
    for (i, (t, m)) in pairs.iter().enumerate() {
        let coast = m.mean_throttle == 0.0;
        if coast {
            coast_from.get_or_insert(t.step);
            coast_reward += t.reward;
            let next_coasts = pairs.get(i + 1).is_some_and(|(_, n)| n.mean_throttle == 0.0);
            if next_coasts {
                continue;
            }
        }
        let (steps, reward) = match coast_from.take() {
            Some(first) if coast => (format!("{first}-{}", t.step), std::mem::take(&mut coast_reward)),
            _ => (t.step.to_string(), t.reward),
        };
        let [a0, a1, a2] = t.action;
        println!(
            "  {steps:>7} {:>6.3} {:>6.3} {:>22} {:>8.4} {:>10.3} {:>9.4} {:>9.4}",
            m.mean_throttle,
            m.zoh_throttle,
            format!("({a0:+.3}, {a1:+.3}, {a2:+.3})"),
            reward,
            m.position * KM,
            m.velocity * M_S,
            m.mass * kg
        );
    }
    let worst = |f: fn(&ground_core::demo::StepMismatch) -> f64| demo.mismatch.iter().map(f).fold(0.0, f64::max);
    println!(
        "  largest: {:.3} km, {:.4} m/s, {:.4} kg over {} tuples; the unclipped f64 hold alone: {:.3} km",
        worst(|m| m.position) * KM,
        worst(|m| m.velocity) * M_S,
        worst(|m| m.mass) * kg,
        demo.transitions.len(),
        worst(|m| m.unclipped_position) * KM
    );

    // The actions replayed open loop from departure: no feedback corrects the per-step errors.
    let mut env = MdpEnv::<P>::new(config)?;
    env.reset(&record.scenario)?;
    let (mut replayed, mut demonstrated) = (0.0, 0.0);
    let mut last = None;
    for t in &demo.transitions {
        let step = env.step(&t.action)?;
        replayed += step.reward;
        demonstrated += t.reward;
        last = Some(step);
    }
    let last = last.ok_or("the demonstration has no steps")?;
    let flown_mass = last.info.state.m;
    println!(
        "\nopen-loop replay of the {} actions from departure:",
        demo.transitions.len()
    );
    println!("  {:<28} {:>14} {:>14}", "", "replayed", "optimal");
    println!(
        "  {:<28} {:>14.6} {:>14.6}",
        "final mass (m0)", flown_mass, record.final_mass
    );
    println!(
        "  {:<28} {:>14.4} {:>14.4}",
        "return (sum of rewards)", replayed, demonstrated
    );
    // The residuals of the optimal final state, by the environment's own definition.
    let optimal = record.steps.last().ok_or("the record has no step samples")?;
    let optimal_state = SpacecraftState {
        r: optimal.r,
        v: optimal.v,
        m: optimal.m,
    };
    let optimal_residuals = P::residuals(&P::features(&record.scenario, &optimal_state, record.scenario.steps)?);
    println!(
        "  {:<28} {:>14.1} {:>14.1e}",
        "final position residual (km)",
        last.info.residuals.position * KM,
        optimal_residuals.position * KM
    );
    println!(
        "  {:<28} {:>14.3} {:>14.1e}",
        "final velocity residual (m/s)",
        last.info.residuals.velocity * M_S,
        optimal_residuals.velocity * M_S
    );
    println!("  episode done after the last action: {}", last.done);
    Ok(())
}
