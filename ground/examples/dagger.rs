//! Issue 4, an experiment (not yet a `ground` command): DAgger-style demonstrations. From a
//! trained checkpoint, repeat: fly the deterministic policy on fresh training scenarios, re-solve
//! the fuel-optimal transfer by the indirect method from states it visited (the rest of the
//! flight from there, `demo::Placement`), add those tuples to the demonstration buffer, and run
//! behaviour-cloning-regularised pretraining updates on the grown buffer. After every round the
//! policy is scored on the config's first Monte Carlo scenarios: the share within 0.01 AU and 0.01
//! of the target (the figure), the median miss and the mean final mass.
//!
//! cargo run --release -p lowthrust-ground --example dagger -- CONFIG CHECKPOINT OUT_DIR \
//!     [ROUNDS=2] [EPISODES=100] [UPDATES=10000] [MC=1000]
//! Writes OUT_DIR/round-R.safetensors and OUT_DIR/rounds.csv. EPISODES = 0 is the control: the
//! same updates on the original demonstrations alone.
use std::io::Write as _;
use std::path::Path;

use lowthrust_ground::config::ExperimentConfig;
use lowthrust_ground::demo::{default_tolerances, placed_demonstration, relabel};
use lowthrust_ground::env::batch::{draw_scenarios, evaluate_batched, summarize, EpisodeOutcome};
use lowthrust_ground::env::{Environment, Transfer, TransferEnv};
use lowthrust_ground::eval::within_accuracy_goal;
use lowthrust_ground::experiment::{demonstration_buffer, policy_batch, push_demonstrations};
use lowthrust_ground::sac::agent::Sac;
use lowthrust_ground::sac::replay::sampler;
use lowthrust_ground::solver::SolveOptions;
use rayon::prelude::*;
use shared::scenario::{ProblemKind, Scenario};

/// Where along each flown episode the policy's state is relabelled.
const FRACTIONS: [f64; 4] = [0.2, 0.4, 0.6, 0.8];

/// Issue 4's figure, the median miss (AU) and the mean final mass, over the completed episodes.
fn score(outcomes: &[EpisodeOutcome]) -> (f64, f64, f64) {
    let summary = summarize(outcomes);
    (
        within_accuracy_goal(outcomes),
        summary.terminal_position.p50,
        summary.final_mass.mean,
    )
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let config_path = Path::new(&args[0]);
    let config = ExperimentConfig::load(config_path).unwrap();
    let checkpoint = Path::new(&args[1]);
    let out = Path::new(&args[2]);
    let arg = |i: usize, default: u64| args.get(i).map_or(default, |s| s.parse().unwrap());
    let (rounds, episodes, updates, mc) = (arg(3, 2), arg(4, 100), arg(5, 10_000), arg(6, 1000));
    assert_eq!(config.scenario.problem(), ProblemKind::Transfer, "transfers only");
    std::fs::create_dir_all(out).unwrap();
    tch::set_num_threads(config.compute.threads);
    tch::manual_seed(config.seeds.train as i64);
    let mut agent = Sac::new(
        config.sac_for(true),
        <TransferEnv as Environment>::OBS,
        3,
        config.device(),
    );
    agent.load(checkpoint).unwrap();
    let config_dir = config_path.parent().unwrap_or(Path::new("."));
    let (mut buffer, records) = demonstration_buffer::<Transfer>(&config, config_dir).unwrap();
    println!("{records} demonstration records, {} tuples", buffer.len());
    let sc = config.env.spacecraft.canonical().unwrap();
    // Relabels end at the eps the config's demonstrations were generated with (smoothed
    // demonstrations clone better than bang-bang ones, session 4).
    let options = SolveOptions {
        final_eps: config.generate.final_eps,
        ..SolveOptions::default()
    };
    let tolerances = default_tolerances();
    let mc_scenarios = draw_scenarios(config.scenario, config.seeds.monte_carlo, mc);
    let evaluate = |agent: &Sac| {
        score(
            &evaluate_batched::<TransferEnv, _>(&config.env, &mc_scenarios, |o| policy_batch(agent, o), false).unwrap(),
        )
    };
    let mut csv = std::fs::File::create(out.join("rounds.csv")).unwrap();
    writeln!(csv, "round,relabels,relabels_converged,tuples_added,buffer,updates,within_0.01,median_miss_au,mean_final_mass,seconds").unwrap();
    let (within, median, mass) = evaluate(&agent);
    println!("round 0 (checkpoint): within 0.01 {within:.3}, median miss {median:.4} AU, final mass {mass:.4}");
    writeln!(csv, "0,0,0,0,{},0,{within},{median},{mass},0", buffer.len()).unwrap();
    let mut rng = sampler(config.seeds.train ^ 0xDA66E5);
    for round in 1..=rounds {
        let clock = std::time::Instant::now();
        // Fresh training scenarios each round (the training stream, past the ones RL saw first).
        let first = 1_000_000 * round;
        let scenarios: Vec<Scenario> = (first..first + episodes)
            .map(|i| config.scenario.draw(config.seeds.train, i))
            .collect();
        let flown =
            evaluate_batched::<TransferEnv, _>(&config.env, &scenarios, |o| policy_batch(&agent, o), true).unwrap();
        let jobs: Vec<(usize, u32)> = flown
            .iter()
            .filter(|o| o.completed)
            .flat_map(|o| {
                let n = scenarios[o.episode].steps;
                FRACTIONS.map(|f| (o.episode, ((f * n as f64).round() as u32).clamp(1, n - 1)))
            })
            .collect();
        let relabelled: Vec<_> = jobs
            .par_iter()
            .filter_map(|&(episode, k)| {
                let scenario = &scenarios[episode];
                let state = flown[episode].trajectory.as_ref()?[k as usize].state;
                let trace = (config.seeds.train, episode as u64);
                let (record, placement) = relabel(trace, scenario, &state, k, &sc, &options)?;
                if !record.converged {
                    return None;
                }
                placed_demonstration::<Transfer>(&record, &placement, &config.env, &tolerances).ok()
            })
            .collect();
        let mut added = 0;
        for demo in &relabelled {
            push_demonstrations(&mut buffer, &demo.transitions);
            added += demo.transitions.len();
        }
        println!(
            "round {round}: {} of {} relabels converged, {added} tuples added ({:.0} s)",
            relabelled.len(),
            jobs.len(),
            clock.elapsed().as_secs_f64()
        );
        for _ in 0..updates {
            agent.update(&buffer.sample(config.sac.batch_size, &mut rng));
        }
        agent.save(&out.join(format!("round-{round}.safetensors"))).unwrap();
        let (within, median, mass) = evaluate(&agent);
        let seconds = clock.elapsed().as_secs_f64();
        println!(
            "round {round}: within 0.01 {within:.3}, median miss {median:.4} AU, final mass {mass:.4} ({seconds:.0} s)"
        );
        writeln!(
            csv,
            "{round},{},{},{added},{},{updates},{within},{median},{mass},{seconds:.0}",
            jobs.len(),
            relabelled.len(),
            buffer.len()
        )
        .unwrap();
    }
}
