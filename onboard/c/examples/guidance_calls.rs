//! The Rust side of the C interface's bit-identity check (scripts/c-sil.sh): the guidance calls
//! the Rust SIL makes, as inputs for the C programs and as the output they must print.
//!
//! `guidance_calls BLOB OUT_DIR [--rendezvous]` writes
//! - `OUT_DIR/calls.bin`: every guidance call's inputs (navigation state, target, time to go) as
//!   f64 bit patterns, read by `replay.c` (the host program `fly.c` and the Cortex-M4F image);
//! - `OUT_DIR/expected.txt`: what `replay.c` must print, command bits or refusal code per call,
//!   computed here by the Rust crates without the C interface.
//!
//! The calls of `firmware_sim`'s trace flights of the problem (transfer by default, rendezvous
//! with `--rendezvous`; `sil_trace`'s, the same scenarios, dispersions and seeds), recorded from
//! the closed loop as it flew with the blob's controller, then inputs guidance must refuse.
//! Each recorded navigation state is what the Rust controller was given, and the target what
//! flight software gave it (the orbit, or the body's state propagated by the Kepler coast); the
//! next state follows from the command through the plant. So a C-hosted controller that returns
//! the same command bits on every one of these inputs would have flown the same flights, bit for
//! bit.
//!
//! calls.bin (little-endian): `LTGC`, u32 format 1, u32 problem (0 transfer, 1 rendezvous),
//! u32 call count, then per call 10 f64: x, y, vx, vy, m; the target (a, e, omega, 0 for a
//! transfer; the body's x, y, vx, vy for a rendezvous); the time to go.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use firmware_sim::trace::{flights_of, RENDEZVOUS_FLIGHTS, TRANSFER_FLIGHTS};
use firmware_sim::{fly_observed, Controller, PlanarProblem, Problem};
use lowthrust::{
    error_name, guidance_error_code, lt_status, policy_error_code, LT_ERR_NOT_LOADED, LT_OK, THRUST_OFF, VERSION,
};
use onboard::dynamics::{SpacecraftState, ThrustCommand};
use onboard::guidance::{rendezvous_step, transfer_step, GuidanceError};
use onboard::policy::{RendezvousPolicy, TransferPolicy};
use shared::blob::{ProblemKind, Quantization};
use shared::orbit::{CartesianState, OrbitShape};
use shared::scenario::Scenario;

/// One guidance call: its inputs and what the Rust controller answered.
struct Call {
    navigation: SpacecraftState,
    /// a, e, omega, 0 (transfer) or x, y, vx, vy of the body (rendezvous).
    target: [f64; 4],
    time_to_go: f64,
    outcome: Result<ThrustCommand, lt_status>,
}

fn bits(x: f64) -> String {
    format!("{:016x}", x.to_bits())
}

fn command_bits(c: &lowthrust::lt_thrust_command) -> String {
    format!("{} {} {}", bits(c.throttle), bits(c.alpha_r), bits(c.alpha_theta))
}

fn name(code: lt_status) -> String {
    error_name(code as i32).to_string_lossy().into_owned()
}

fn outcome(result: Result<ThrustCommand, GuidanceError>) -> Result<ThrustCommand, lt_status> {
    result.map_err(|e| guidance_error_code(&e))
}

fn orbit_target(t: &OrbitShape) -> [f64; 4] {
    [t.a, t.e, t.omega, 0.0]
}

fn body_target(b: &CartesianState) -> [f64; 4] {
    [b.r[0], b.r[1], b.v[0], b.v[1]]
}

/// Inputs every guidance step must refuse (and one the network cannot answer), around `nav`.
fn refused_inputs(nav: SpacecraftState) -> Vec<(SpacecraftState, Option<f64>, f64)> {
    vec![
        (SpacecraftState { m: f64::NAN, ..nav }, None, 5.0),
        (SpacecraftState { r: [0.0, 0.0], ..nav }, None, 5.0),
        (SpacecraftState { m: -0.25, ..nav }, None, 5.0),
        // The target's first component made unusable: a negative semi-major axis, a body at r = 0.
        (nav, Some(-1.0), 5.0),
        (nav, None, -1.0),
        (nav, None, f64::INFINITY),
        // Finite in f64, infinite as the network's f32 input.
        (SpacecraftState { r: [1e39, 0.0], ..nav }, None, 5.0),
    ]
}

/// The guidance calls of the trace flights of problem `P`, flown by `controller` (`target`: the
/// call's target components from the scenario and the step index, as flight software has them).
fn flight_calls<const N: usize, P: PlanarProblem<N>>(
    problem: P,
    controller: &Controller<'_, N>,
    target: impl Fn(&Scenario, u32) -> Result<[f64; 4], String>,
    out: &mut String,
) -> Result<Vec<Call>, String> {
    // A refused blob flies the SIL in safe mode; through the C interface every step of a policy
    // not loaded is refused with thrust off.
    let loaded = matches!(controller, Controller::Network(_));
    let mut calls = Vec::new();
    let mut first = 0;
    for flight in flights_of(problem) {
        let mut failed = None;
        // The trace flight itself, on the plant firmware_sim::trace::fly flies it on.
        let setup = flight.setup().map_err(|e| e.to_string())?;
        fly_observed(
            problem,
            controller,
            &flight.scenario,
            &setup,
            flight.seed,
            |step| match target(&flight.scenario, step.index) {
                Ok(target) => calls.push(Call {
                    navigation: step.navigation,
                    target,
                    // As fly_observed computes it.
                    time_to_go: flight.scenario.time_to_go(step.index),
                    outcome: match step.guidance_error {
                        _ if !loaded => Err(LT_ERR_NOT_LOADED),
                        None => Ok(step.command),
                        Some(e) => Err(guidance_error_code(&e)),
                    },
                }),
                Err(e) => failed = Some(e),
            },
        )
        .map_err(|e| format!("flight {}: {e}", flight.name))?;
        if let Some(e) = failed {
            return Err(format!("flight {}: target: {e}", flight.name));
        }
        writeln!(
            out,
            "# calls {first}..{}: flight {} seed {} (sil_trace's), one per step",
            calls.len(),
            flight.name,
            flight.seed
        )
        .map_err(|e| e.to_string())?;
        first = calls.len();
    }
    Ok(calls)
}

fn transfer_calls(blob: &[u8], out: &mut String) -> Result<Vec<Call>, String> {
    let controller = Controller::load_transfer(blob);
    let mut calls = flight_calls(
        firmware_sim::Transfer,
        &controller,
        |s, _| Ok(orbit_target(&s.target)),
        out,
    )?;
    let first = calls.len();
    let nominal = TRANSFER_FLIGHTS[0].scenario.target;
    let nav = calls.first().map(|c| c.navigation).ok_or("no flight steps")?;
    let policy = TransferPolicy::from_bytes(blob, ProblemKind::Transfer);
    for (navigation, first_target_component, time_to_go) in refused_inputs(nav) {
        let target = OrbitShape {
            a: first_target_component.unwrap_or(nominal.a),
            ..nominal
        };
        calls.push(Call {
            navigation,
            target: orbit_target(&target),
            time_to_go,
            outcome: match &policy {
                Ok(p) => outcome(transfer_step(p, &navigation, &target, time_to_go)),
                Err(_) => Err(LT_ERR_NOT_LOADED),
            },
        });
    }
    writeln!(out, "# calls {first}..{}: inputs guidance refuses", calls.len()).map_err(|e| e.to_string())?;
    Ok(calls)
}

fn rendezvous_calls(blob: &[u8], out: &mut String) -> Result<Vec<Call>, String> {
    let policy = RendezvousPolicy::from_bytes(blob, ProblemKind::Rendezvous);
    let controller = Controller::load_rendezvous(blob);
    let body_at = |s: &Scenario, index: u32| {
        firmware_sim::Rendezvous::target(s, index)
            .map(|b| body_target(&b))
            .map_err(|e| e.to_string())
    };
    let mut calls = flight_calls(firmware_sim::Rendezvous, &controller, body_at, out)?;
    let body0 = RENDEZVOUS_FLIGHTS[0]
        .scenario
        .target
        .cartesian_at(RENDEZVOUS_FLIGHTS[0].scenario.target_nu0);
    let step = |navigation: SpacecraftState, body: CartesianState, time_to_go: f64| Call {
        navigation,
        target: body_target(&body),
        time_to_go,
        outcome: match &policy {
            Ok(p) => outcome(rendezvous_step(p, &navigation, &body, time_to_go)),
            Err(_) => Err(LT_ERR_NOT_LOADED),
        },
    };
    let first = calls.len();
    let nav = calls.first().map(|c| c.navigation).ok_or("no steps")?;
    for (navigation, first_target_component, time_to_go) in refused_inputs(nav) {
        let body = CartesianState {
            r: match first_target_component {
                Some(_) => [0.0, 0.0],
                None => body0.r,
            },
            ..body0
        };
        calls.push(step(navigation, body, time_to_go));
    }
    writeln!(out, "# calls {first}..{}: inputs guidance refuses", calls.len()).map_err(|e| e.to_string())?;
    Ok(calls)
}

fn run() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (blob_path, out_dir, kind) = match args.as_slice() {
        [b, o] => (b, o, ProblemKind::Transfer),
        [b, o, flag] if flag == "--rendezvous" => (b, o, ProblemKind::Rendezvous),
        _ => return Err("usage: guidance_calls BLOB OUT_DIR [--rendezvous]".into()),
    };
    let blob = std::fs::read(blob_path).map_err(|e| format!("{blob_path}: {e}"))?;
    let out_dir = PathBuf::from(out_dir);
    std::fs::create_dir_all(&out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;

    let mut expected = String::new();
    let w = |e: std::fmt::Error| e.to_string();
    writeln!(
        expected,
        "lowthrust {}.{}.{} blob format {}",
        VERSION.major, VERSION.minor, VERSION.patch, VERSION.blob_format_version
    )
    .map_err(w)?;
    let (problem, load, problem_code) = match kind {
        ProblemKind::Transfer => {
            let p = TransferPolicy::from_bytes(&blob, kind);
            ("transfer", p.map(|p| p.quantization()), 0u32)
        }
        ProblemKind::Rendezvous => {
            let p = RendezvousPolicy::from_bytes(&blob, kind);
            ("rendezvous", p.map(|p| p.quantization()), 1u32)
        }
    };
    let load_code = load.as_ref().map_or_else(policy_error_code, |_| LT_OK);
    writeln!(expected, "load {problem} {} {}", load_code as i32, name(load_code)).map_err(w)?;
    if let Ok(q) = load {
        let q = match q {
            Quantization::F32 => "f32",
            Quantization::Int8 => "int8",
        };
        writeln!(expected, "policy {problem} {q}").map_err(w)?;
    }
    let calls = match kind {
        ProblemKind::Transfer => transfer_calls(&blob, &mut expected)?,
        ProblemKind::Rendezvous => rendezvous_calls(&blob, &mut expected)?,
    };

    let mut records = b"LTGC".to_vec();
    records.extend(1u32.to_le_bytes());
    records.extend(problem_code.to_le_bytes());
    records.extend(u32::try_from(calls.len()).map_err(|e| e.to_string())?.to_le_bytes());
    for (i, call) in calls.iter().enumerate() {
        let n = call.navigation;
        let values = [n.r[0], n.r[1], n.v[0], n.v[1], n.m]
            .into_iter()
            .chain(call.target)
            .chain([call.time_to_go]);
        for v in values {
            records.extend(v.to_le_bytes());
        }
        match call.outcome {
            Ok(c) => writeln!(expected, "call {i} cmd {}", command_bits(&c.into())),
            Err(code) => writeln!(
                expected,
                "call {i} refused {} {} cmd {}",
                code as i32,
                name(code),
                command_bits(&THRUST_OFF)
            ),
        }
        .map_err(w)?;
    }
    writeln!(expected, "end {} calls", calls.len()).map_err(w)?;

    for (file, bytes) in [("calls.bin", records), ("expected.txt", expected.into_bytes())] {
        let path = out_dir.join(file);
        std::fs::write(&path, bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("guidance_calls: {e}");
            ExitCode::FAILURE
        }
    }
}
