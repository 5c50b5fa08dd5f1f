//! How well an actor imitates demonstrations it learnt from against ones it never saw: the
//! thrust vector it commands on every demonstration state against the demonstrated one
//! (`onboard::features::decode_action` of both), by steps to go. A fit error much smaller on the
//! learnt draws than on new ones says the data limits the controller; equal errors say the
//! network (or its training) does.
//!
//! ```text
//! cargo run --release -p lowthrust-learn --example cloning_fit -- CONFIG ACTOR DATASET...
//! cargo run --release -p lowthrust-learn --example cloning_fit -- CONFIG --train 512,512 40000 OUT_ACTOR TRAIN_DATASET DATASET...
//! ```
//! With `--train`, a fresh actor of the given hidden widths is cloned (the actor alone, the
//! config's cloning error, batch and learning rate) on TRAIN_DATASET for the given updates, its
//! fit reported on every dataset each quarter of the way, and the flown actor saved to OUT_ACTOR.

use std::path::{Path, PathBuf};

use ground_core::demo::Transition;
use ground_core::env::Transfer;
use learn::config::ExperimentConfig;
use learn::eval::load_agent;
use learn::phase::policy_batch;
use learn::pretrain::{demonstration_buffer, load_demonstrations};
use learn::sac::agent::Sac;
use learn::sac::replay::sampler;
use onboard::features::decode_action;
use shared::scenario::ProblemKind;

/// Steps-to-go bands: the last 3 steps, 3-10, 10-20, more.
const BANDS: [(f64, f64); 4] = [(0.0, 3.0), (3.0, 10.0), (10.0, 20.0), (20.0, 1e9)];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let usage = "usage: cloning_fit CONFIG (ACTOR | --train HIDDEN UPDATES OUT_ACTOR) DATASET...";
    let (config_path, rest) = args[1..].split_first().ok_or(usage)?;
    let mut config = ExperimentConfig::load(Path::new(config_path))?;
    if config.problem() != ProblemKind::Transfer {
        return Err("a transfer config is needed (the diagnostic flies the 10-feature transfer MDP)".into());
    }
    let demos = |config: &mut ExperimentConfig, dataset: &str| {
        config.pretrain.dataset = Some(PathBuf::from(dataset));
        load_demonstrations::<Transfer>(config, Path::new(".")).map(|(d, _, records)| (d.transitions, records))
    };
    match rest {
        [flag, hidden, updates, out, datasets @ ..] if flag == "--train" && !datasets.is_empty() => {
            config.sac.hidden = hidden.split(',').map(str::parse).collect::<Result<_, _>>()?;
            let updates: u64 = updates.parse()?;
            let sets: Vec<(String, Vec<Transition<[f32; 10]>>)> = datasets
                .iter()
                .map(|d| demos(&mut config, d).map(|(t, _)| (d.clone(), t)))
                .collect::<Result<_, _>>()?;
            config.pretrain.dataset = Some(PathBuf::from(&datasets[0]));
            let (buffer, _) = demonstration_buffer::<Transfer>(&config, Path::new("."))?;
            tch::set_num_threads(config.compute.threads);
            tch::manual_seed(config.seeds.train as i64);
            let mut agent =
                Sac::with_cloning_loss(config.sac_for(true), 10, 3, config.device()?, config.cloning_loss());
            let mut rng = sampler(config.seeds.train);
            let clock = std::time::Instant::now();
            for quarter in 1..=4 {
                for _ in 0..updates / 4 {
                    agent.cloning_update(&buffer.sample(config.sac.batch_size, &mut rng));
                }
                println!(
                    "hidden {hidden}, {} updates ({:.0} s):",
                    quarter * (updates / 4),
                    clock.elapsed().as_secs_f64()
                );
                for (name, transitions) in &sets {
                    report(&agent, name, transitions);
                }
            }
            agent.save_flown_actor(Path::new(out))?;
        }
        [actor, datasets @ ..] if !datasets.is_empty() => {
            let agent = load_agent(&config, 10, Path::new(actor))?;
            for dataset in datasets {
                let (transitions, _) = demos(&mut config, dataset)?;
                report(&agent, dataset, &transitions);
            }
        }
        _ => return Err(usage.into()),
    }
    Ok(())
}

/// One line: tuples, mean |dT|^2, |dT| p50 / p90, then mean |dT|^2 by steps-to-go band.
fn report(agent: &Sac, name: &str, transitions: &[Transition<[f32; 10]>]) {
    let obs: Vec<[f32; 10]> = transitions.iter().map(|t| t.observation).collect();
    let flown: Vec<[f32; 3]> = obs.chunks(4096).flat_map(|c| policy_batch(agent, c)).collect();
    let thrust = |a: &[f32; 3]| {
        let c = decode_action(a);
        [c.throttle * c.alpha_r, c.throttle * c.alpha_theta]
    };
    let mut errors: Vec<(f64, f64)> = transitions
        .iter()
        .zip(&flown)
        .map(|(t, a)| {
            let (p, d) = (thrust(a), thrust(&t.action));
            let e2 = (p[0] - d[0]).powi(2) + (p[1] - d[1]).powi(2);
            (f64::from(t.observation[9]) / shared::units::STEP, e2)
        })
        .collect();
    let mean = |v: &mut dyn Iterator<Item = f64>| {
        let (sum, n) = v.fold((0.0, 0usize), |(s, n), e| (s + e, n + 1));
        sum / n.max(1) as f64
    };
    let bands: Vec<String> = BANDS
        .iter()
        .map(|&(lo, hi)| {
            let mut band = errors
                .iter()
                .filter(|e| e.0 >= lo - 1e-6 && e.0 < hi - 1e-6)
                .map(|e| e.1);
            format!("{:.2e}", mean(&mut band))
        })
        .collect();
    let all = mean(&mut errors.iter().map(|e| e.1));
    errors.sort_by(|a, b| a.1.total_cmp(&b.1));
    let quantile = |q: f64| errors[((errors.len() - 1) as f64 * q) as usize].1.sqrt();
    println!(
        "  {name}: {} tuples, mean |dT|^2 {all:.3e}, |dT| p50 {:.4} p90 {:.4}; by steps to go <3, 3-10, 10-20, >20: {}",
        errors.len(),
        quantile(0.5),
        quantile(0.9),
        bands.join(", ")
    );
}
