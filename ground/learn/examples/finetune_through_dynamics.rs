//! Fine-tunes a transfer actor through the dynamics ([`learn::finetune`]) and reports the
//! evaluation flights' share within the goal, final mass and objective every few steps.
//!
//! `cargo run --release -p lowthrust-learn --example finetune_through_dynamics -- CONFIG ACTOR
//! OUT STEPS BATCH LEARNING_RATE PROPELLANT_WEIGHT`: ACTOR an actor file (a model's
//! `actor.safetensors`), OUT the fine-tuned actor written.

use std::path::Path;

use ground_core::env::batch::evaluate_batched;
use ground_core::env::{Geometry, MdpEnv, Problem, Transfer};
use learn::config::ExperimentConfig;
use learn::eval::{meets, ACCURACY_GOAL};
use learn::finetune::{finetune_step, Objective};
use learn::phase::policy_batch;
use learn::sac::agent::Sac;

/// Fine-tuning flights come from the training stream past any round's scenarios.
const FIRST: u64 = 1 << 40;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let [_, config, actor, out, steps, batch, lr, weight] = &args[..] else {
        eprintln!("usage: CONFIG ACTOR OUT STEPS BATCH LEARNING_RATE PROPELLANT_WEIGHT");
        std::process::exit(2);
    };
    let mut config = ExperimentConfig::load(Path::new(config)).expect("config");
    config.sac.actor_averaging = 0.0;
    config.sac.learning_rate = lr.parse().expect("learning rate");
    tch::set_num_threads(1);
    tch::manual_seed(0);
    let mut agent = Sac::new(config.sac.clone(), Transfer::OBS, 3, tch::Device::Cpu);
    agent.start_from_actor(Path::new(actor)).expect("actor");
    let objective = Objective {
        position_goal: ACCURACY_GOAL,
        velocity_goal: ACCURACY_GOAL,
        propellant_weight: weight.parse().expect("weight"),
    };
    let (steps, batch): (u64, u64) = (steps.parse().expect("steps"), batch.parse().expect("batch"));
    let family = learn::phase::family_of::<<Transfer as Problem>::Geometry>(&config).expect("family");
    let evaluation: Vec<_> = (0..500)
        .map(|i| <Transfer as Problem>::Geometry::draw(&family, config.seeds.evaluation, i))
        .collect();
    let report = |agent: &Sac, step: u64| {
        let outcomes =
            evaluate_batched::<MdpEnv<Transfer>, _>(&config.env, &evaluation, |o| policy_batch(agent, o), false)
                .expect("evaluation");
        let n = outcomes.len() as f64;
        let within = outcomes.iter().filter(|o| meets(o, ACCURACY_GOAL)).count() as f64 / n;
        let mass = outcomes.iter().map(|o| o.final_mass).sum::<f64>() / n;
        let value = outcomes
            .iter()
            .map(|o| objective.value(&o.terminal, o.final_mass))
            .sum::<f64>()
            / n;
        let mut dr: Vec<f64> = outcomes.iter().map(|o| o.terminal.position).collect();
        dr.sort_by(f64::total_cmp);
        println!(
            "step {step}: evaluation within the goal {:.1} %, final mass {mass:.5}, objective {value:.4}, dr p50 {:.4}",
            100.0 * within,
            dr[dr.len() / 2]
        );
    };
    report(&agent, 0);
    let clock = std::time::Instant::now();
    for step in 1..=steps {
        let r = finetune_step::<Transfer>(&config, &mut agent, FIRST + step * batch, batch, &objective).expect("step");
        if step % 10 == 0 || step == steps {
            println!(
                "  batch objective {:.4} ({} flights), {:.1} s a step",
                r.objective,
                r.flights,
                clock.elapsed().as_secs_f64() / step as f64
            );
            report(&agent, step);
            agent.save_flown_actor(Path::new(out)).expect("save");
        }
    }
}
