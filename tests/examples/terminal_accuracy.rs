//! Terminal targeting measured: a shipped model's f32 blob flown in the SIL loop on the first
//! `COUNT` Monte Carlo scenarios (seed 2000003), alone and with `onboard::terminal` over its last
//! `CYCLES` cycles, nominal or with the typical dispersions; prints the share within 0.01,
//! 0.005, 0.001 and 0.0001 AU (and of the velocity unit), the median residuals and the mean
//! final mass of each.
//!
//! `cargo run --release -p lowthrust-tests --example terminal_accuracy -- MODEL KIND COUNT CYCLES [dispersed]`
//! e.g. `-- models/transfer-circular transfer-circular 1000 3`.

use firmware_sim::{fly, with_flight_problem, Controller, Dispersions, FlightSetup, Problem};
use onboard::guidance::Guide;
use onboard::terminal::{Terminal, TerminalSettings};
use shared::blob::AlignedBlob;
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [model, kind, count, cycles, rest @ ..] = args.as_slice() else {
        return Err("usage: MODEL KIND COUNT CYCLES [dispersed]".into());
    };
    let kind: ScenarioKind = kind.parse().map_err(|_| "unknown scenario")?;
    let count: u64 = count.parse()?;
    let cycles: u32 = cycles.parse()?;
    let dispersed = rest.first().is_some_and(|a| a == "dispersed");
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
        ..TerminalSettings::default()
    };
    with_flight_problem!(kind.problem(), N, P => {
        let controller = Controller::<N>::load::<P>(blob.bytes());
        let terminal = Terminal { actor: &controller, spacecraft, settings, lookahead: None };
        report("network alone", kind, count, &setup, &controller, P::default());
        report(&format!("terminal targeting, last {cycles} cycles"), kind, count, &setup, &terminal, P::default());
    });
    Ok(())
}

fn report<const N: usize, P: Problem<N> + Send + Sync, G: Guide<N, P::Target> + Sync>(
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
