//! Environment steps per second: one transfer and one rendezvous step (thrusting and coasting),
//! and whole episodes flown in parallel by the Monte Carlo driver.
//!
//! `cargo bench -p lowthrust-ground --bench env`; the per-step times print as criterion
//! figures, the parallel throughput as a line on stderr.

use std::hint::black_box;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, Criterion};
use ground_core::env::batch::{draw_scenarios, evaluate};
use ground_core::env::{EnvConfig, Environment, Planar, RendezvousEnv, TransferEnv};
use shared::scenario::ScenarioKind;

/// A fixed, thrusting action with a turning direction.
const THRUST: [f32; 3] = [0.4, 0.3, 0.9];
const COAST: [f32; 3] = [-1.0, 0.0, 1.0];

fn steps<E: Environment<Geometry = Planar>>(c: &mut Criterion, name: &str, kind: ScenarioKind) {
    let config = EnvConfig::default();
    let mut env = E::new(&config).expect("valid config");
    for (label, action) in [("thrusting", THRUST), ("coasting", COAST)] {
        c.bench_function(&format!("{name} step, {label}"), |b| {
            env.reset_drawn(kind, 1, 0).expect("valid scenario");
            b.iter(|| {
                if env.is_done() {
                    env.reset_drawn(kind, 1, 0).expect("valid scenario");
                }
                black_box(env.step(black_box(&action)).expect("steps"))
            })
        });
    }
}

fn throughput<E: Environment<Geometry = Planar>>(name: &str, kind: ScenarioKind, episodes: u64) {
    let scenarios = draw_scenarios(kind, 2, episodes);
    let config = EnvConfig::default();
    let start = Instant::now();
    let out = evaluate::<E, _>(&config, &scenarios, |_| THRUST, false).expect("runs");
    let secs = start.elapsed().as_secs_f64();
    let steps: u64 = out.iter().map(|o| u64::from(o.steps)).sum();
    eprintln!(
        "{name}: {episodes} episodes, {steps} thrusting steps in {secs:.2} s on {} threads: {:.0} steps/s",
        rayon::current_num_threads(),
        steps as f64 / secs
    );
}

fn bench(c: &mut Criterion) {
    steps::<TransferEnv>(c, "transfer", ScenarioKind::TransferHard);
    steps::<RendezvousEnv>(c, "rendezvous", ScenarioKind::RendezvousHard);
    throughput::<TransferEnv>("transfer-hard", ScenarioKind::TransferHard, 2000);
    throughput::<RendezvousEnv>("rendezvous-hard", ScenarioKind::RendezvousHard, 2000);
}

criterion_group!(benches, bench);
criterion_main!(benches);
