//! Terminal targeting measured: a shipped model's f32 blob flown in the SIL loop on the first
//! `COUNT` Monte Carlo scenarios (seed 2000003), alone and with `onboard::terminal` over its last
//! `CYCLES` cycles, nominal or with the typical dispersions; prints the share within 0.01,
//! 0.005, 0.001 and 0.0001 AU (and of the velocity unit), the median residuals and the mean
//! final mass of each, and the rollouts terminal targeting propagated per cycle by cycles to go
//! (its work: multiply by the Cortex-M4F's instructions per rollout cycle).
//!
//! `cargo run --release -p lowthrust-tests --example terminal_accuracy -- MODEL KIND COUNT CYCLES [ITERATIONS] [dispersed]`
//! e.g. `-- models/transfer-circular transfer-circular 1000 3`.

use std::sync::Mutex;

use firmware_sim::{fly, with_flight_problem, Controller, Dispersions, FlightSetup, Planar, PlanarProblem};
use onboard::dynamics::{SpacecraftState, ThrustCommand};
use onboard::guidance::{cycles_left, Actor, GuidanceError, Guide, TargetFeatures};
use onboard::terminal::{terminal_step, Terminal, TerminalSettings};
use shared::blob::AlignedBlob;
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [model, kind, count, cycles, rest @ ..] = args.as_slice() else {
        return Err("usage: MODEL KIND COUNT CYCLES [ITERATIONS] [dispersed]".into());
    };
    let kind: ScenarioKind = kind.parse().map_err(|_| "unknown scenario")?;
    let count: u64 = count.parse()?;
    let cycles: u32 = cycles.parse()?;
    let dispersed = rest.iter().any(|a| a == "dispersed");
    let iterations = match rest.iter().find(|a| *a != "dispersed") {
        Some(n) => n.parse()?,
        None => TerminalSettings::default().iterations,
    };
    let problem = match kind.problem() {
        shared::blob::ProblemKind::Transfer => "transfer",
        shared::blob::ProblemKind::Rendezvous => "rendezvous",
    };
    let bytes = std::fs::read(format!("{model}/{problem}-f32.blob"))?;
    let blob = AlignedBlob::new(&bytes);
    let spacecraft = Spacecraft::MSR_ERO.canonical().map_err(|e| format!("{e:?}"))?;
    let setup = FlightSetup::nominal(spacecraft).dispersed(if dispersed {
        Dispersions::TYPICAL
    } else {
        Dispersions::NONE
    });
    let settings = TerminalSettings {
        cycles,
        iterations,
        ..TerminalSettings::default()
    };
    with_flight_problem!(kind.problem(), N, P => {
        let controller = Controller::<N>::load::<P>(blob.bytes());
        let terminal = Terminal { actor: &controller, spacecraft, settings, lookahead: None };
        report("network alone", kind, count, &setup, &controller, P::default());
        let counted = Counted { terminal, rollouts: Mutex::new(Vec::new()) };
        report(
            &format!("terminal targeting, last {cycles} cycles, {iterations} iterations"),
            kind,
            count,
            &setup,
            &counted,
            P::default(),
        );
        counted.print();
    });
    Ok(())
}

fn report<const N: usize, P: PlanarProblem<N> + Send + Sync, G: Guide<N, P::Target> + Sync>(
    name: &str,
    kind: ScenarioKind,
    count: u64,
    setup: &FlightSetup,
    guide: &G,
    problem: P,
) {
    let start = std::time::Instant::now();
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get() as u64);
    let ends: Vec<(f64, f64, f64)> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|t| {
                s.spawn(move || {
                    (t..count)
                        .step_by(threads as usize)
                        .filter_map(|i| {
                            let scenario = kind.draw(2_000_003, i);
                            let flight = fly(problem, guide, &scenario, setup, 2_000_003 + i).ok()?;
                            let r = flight.final_residuals()?;
                            Some((r.position, r.velocity, flight.final_state().m))
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles.into_iter().flat_map(|h| h.join().unwrap_or_default()).collect()
    });
    let n = ends.len() as f64;
    let share = |t: f64| ends.iter().filter(|(dr, dv, _)| *dr < t && *dv < t).count() as f64 / n;
    let median = |f: fn(&(f64, f64, f64)) -> f64| {
        let mut v: Vec<f64> = ends.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    println!(
        "{name}: {} flights, within 0.01 {:.1} %, 0.005 {:.1} %, 0.001 {:.1} %, 0.0001 {:.1} %; dr p50 {:.2e} AU, dv p50 {:.2e}; final mass {:.5}; {:.1} s",
        ends.len(),
        100.0 * share(0.01),
        100.0 * share(0.005),
        100.0 * share(0.001),
        100.0 * share(0.0001),
        median(|e| e.0),
        median(|e| e.1),
        ends.iter().map(|e| e.2).sum::<f64>() / n,
        start.elapsed().as_secs_f64()
    );
}

/// Terminal targeting that keeps each terminal cycle's (cycles to go, propagated cycles).
struct Counted<A> {
    terminal: Terminal<A>,
    rollouts: Mutex<Vec<(u32, u32)>>,
}

impl<const N: usize, T: TargetFeatures<N>, A: Actor<N>> Guide<N, T> for Counted<A> {
    fn command(
        &self,
        navigation: &SpacecraftState,
        target: &T,
        time_to_go: f64,
    ) -> Result<ThrustCommand, GuidanceError> {
        let Terminal {
            actor,
            spacecraft,
            settings,
            ..
        } = &self.terminal;
        let decision = terminal_step(actor, navigation, target, time_to_go, spacecraft, settings)?;
        if decision.rollout_cycles > 0 {
            if let Ok(mut kept) = self.rollouts.lock() {
                kept.push((
                    cycles_left(time_to_go, shared::units::STEP) as u32,
                    decision.rollout_cycles,
                ));
            }
        }
        Ok(decision.command)
    }
}

impl<A> Counted<A> {
    fn print(&self) {
        let Ok(kept) = self.rollouts.lock() else {
            return;
        };
        for k in 1..=self.terminal.settings.cycles {
            let mut n: Vec<u32> = kept.iter().filter(|(c, _)| *c == k).map(|(_, r)| *r).collect();
            n.sort_unstable();
            if let (Some(max), false) = (n.last(), n.is_empty()) {
                let at = |q: f64| n[((n.len() - 1) as f64 * q) as usize];
                println!(
                    "  {k} cycle(s) to go: {} cycles, propagated cycles p50 {} p99 {} max {max} (bound {})",
                    n.len(),
                    at(0.5),
                    at(0.99),
                    self.terminal.settings.most_rollout_cycles::<Planar>(k)
                );
            }
        }
    }
}
