//! One 14-day guidance step of the plant: thrusting (DOP853) and coasting (universal-variable
//! Kepler), plus the bare integrator on the 5-state system at rtol 1e-12.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use onboard::dynamics::{propagate, PolarHoldDynamics, SpacecraftState, ThrustCommand};
use onboard::integrator::{integrate, Tolerances};
use shared::spacecraft::Spacecraft;
use shared::units::STEP;

fn start() -> SpacecraftState {
    // 1 AU circular orbit, m = 1.
    let (s, c) = 0.3f64.sin_cos();
    SpacecraftState {
        r: [c, s],
        v: [-s, c],
        m: 1.0,
    }
}

const ALONG_TRACK: ThrustCommand = ThrustCommand {
    throttle: 1.0,
    alpha_r: 0.0,
    alpha_theta: 1.0,
};

fn bench(c: &mut Criterion) {
    let sc = Spacecraft::MSR_ERO.canonical().expect("valid spacecraft");
    let s0 = start();
    let tol = Tolerances::default();
    let strict = Tolerances {
        relative: 1e-12,
        absolute: 1e-12,
        ..Tolerances::default()
    };
    let system = PolarHoldDynamics {
        spacecraft: sc,
        command: ALONG_TRACK,
    };
    for (name, t) in [("default tolerances", &tol), ("rtol = atol = 1e-12", &strict)] {
        let (_, stats) = integrate(&system, 0.0, &s0.to_array(), STEP, t).expect("integrates");
        eprintln!(
            "14-day thrusting step, {name}: {} accepted + {} rejected steps, {} derivative evaluations",
            stats.accepted_steps, stats.rejected_steps, stats.derivative_evaluations
        );
    }

    c.bench_function("propagate 14 d thrusting (full throttle, along-track)", |b| {
        b.iter(|| propagate(black_box(&s0), black_box(&ALONG_TRACK), &sc, black_box(STEP), &tol))
    });
    c.bench_function("propagate 14 d coasting (throttle 0)", |b| {
        b.iter(|| {
            propagate(
                black_box(&s0),
                black_box(&ThrustCommand::OFF),
                &sc,
                black_box(STEP),
                &tol,
            )
        })
    });
    c.bench_function("integrate 5-state 14 d, rtol 1e-12", |b| {
        b.iter(|| {
            integrate(
                black_box(&system),
                0.0,
                black_box(&s0.to_array()),
                black_box(STEP),
                &strict,
            )
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
