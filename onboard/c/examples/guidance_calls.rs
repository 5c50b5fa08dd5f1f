//! The Rust side of the C interface's bit-identity check (scripts/c-sil.sh): the guidance calls
//! the Rust SIL makes, as inputs for the C programs and as the output they must print.
//!
//! `guidance_calls BLOB OUT_DIR [--rendezvous] [--spatial]` writes
//! - `OUT_DIR/calls.bin`: every guidance call's inputs (navigation state, target, time to go) as
//!   f64 bit patterns, read by `replay.c` (the host program `fly.c` and the Cortex-M4F image);
//! - `OUT_DIR/expected.txt`: what `replay.c` must print, command bits or refusal code per call,
//!   computed here by the Rust crates without the C interface.
//!
//! The calls of `firmware_sim`'s trace flights of the problem (transfer by default, rendezvous
//! with `--rendezvous`, either in three dimensions on the inclined flights with `--spatial`;
//! `sil_trace`'s, the same scenarios, dispersions and seeds), recorded from the closed loop as it
//! flew with the blob's controller, then inputs guidance must refuse. Each recorded navigation
//! state is what the Rust controller was given, and the target what flight software gave it (the
//! orbit, or the body's state propagated by the Kepler coast); the next state follows from the
//! command through the plant. So a C-hosted controller that returns the same command bits on
//! every one of these inputs would have flown the same flights, bit for bit.
//!
//! Then the onboard aids on the first two flights (both of 14-day cycles): rollout lookahead
//! (`lt_*_lookahead_step`) on six of each flight's steps and terminal targeting
//! (`lt_*_terminal_step`) on its last five, with the settings of [`lookahead_settings`] and
//! [`terminal_settings`] and the flights' spacecraft; and both aids on every refused input.
//!
//! calls.bin (little-endian): `LTGC`, u32 format 3, u32 problem (the C interface's
//! `LT_PROBLEM_*`: 0 transfer, 1 rendezvous, 2 transfer in three dimensions, 3 rendezvous in
//! three dimensions), u32 call count; then the aids' 16 f64s: the spacecraft (thrust, exhaust
//! speed), the lookahead settings (goal position, goal velocity, accuracy floor, fuel weight,
//! thrust margin, cycle, max cycles, arrival margin, rollout budget) and the terminal settings
//! (goal position, goal velocity, cycle, cycles, iterations), counts as whole f64s; then per call
//! its f64s: the aid (0 the network's step, 1 lookahead, 2 terminal targeting), the navigation
//! state (x, y, vx, vy, m; in three dimensions x, y, z, vx, vy, vz, m), the target (a, e, omega, 0
//! for a transfer; the body's x, y, vx, vy for a rendezvous; in three dimensions a, e, omega,
//! inclination, raan, 0, or the body's x, y, z, vx, vy, vz), the time to go: 11 per planar call,
//! 15 in three dimensions. (Format 2 had neither the aids' values nor the aid of each call;
//! format 1 was the planar problems alone.)

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use firmware_sim::trace::{flights_of, TraceProblem};
use firmware_sim::{
    fly_observed, CommandOf, Controller, Dimension, FlightGeometry, Planar, Policy, Problem, Rendezvous, Rendezvous3,
    ScenarioOf, Spatial, StateOf, Transfer, Transfer3,
};
use lowthrust::{
    error_name, guidance_error_code, lt_rtn_command, lt_status, lt_thrust_command, policy_error_code,
    LT_ERR_NOT_LOADED, LT_OK, LT_PROBLEM_RENDEZVOUS, LT_PROBLEM_RENDEZVOUS3, LT_PROBLEM_TRANSFER, LT_PROBLEM_TRANSFER3,
    RTN_THRUST_OFF, THRUST_OFF, VERSION,
};
use onboard::dynamics::{SpacecraftState, ThrustCommand};
use onboard::features::{
    ACTION3_LEN, ACTION_LEN, RENDEZVOUS3_FEATURES, RENDEZVOUS_FEATURES, TRANSFER3_FEATURES, TRANSFER_FEATURES,
};
use onboard::guidance::{
    rendezvous3_step, rendezvous_step, transfer3_step, transfer_step, Aim, GuidanceError, Guide, TargetOrbit3,
};
use onboard::lookahead::{lookahead_step, LookaheadSettings};
use onboard::spatial::{RtnCommand, SpatialCraftState};
use onboard::terminal::{terminal_step, TerminalSettings};
use shared::blob::Quantization;
use shared::orbit::{CartesianState, OrbitShape, SpatialState};
use shared::scenario::{Scenario, SpatialScenario};
use shared::spacecraft::CanonicalSpacecraft;

/// calls.bin's format number.
const CALLS_FORMAT: u32 = 3;

/// How a recorded call is flown: the network's guidance step, or an onboard aid around it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Aid {
    Network,
    Lookahead,
    Terminal,
}

impl Aid {
    /// Its number in calls.bin.
    fn code(self) -> f64 {
        match self {
            Self::Network => 0.0,
            Self::Lookahead => 1.0,
            Self::Terminal => 2.0,
        }
    }

    /// What follows the call's number on its line (nothing for the network's step).
    fn word(self) -> &'static str {
        match self {
            Self::Network => "",
            Self::Lookahead => " lookahead",
            Self::Terminal => " terminal",
        }
    }
}

/// The lookahead of every calls file: a tenth of the thrust kept as margin, at most 60 rollout
/// steps a call (some 20 million Cortex-M4F instructions, so the image's run stays short).
fn lookahead_settings() -> LookaheadSettings {
    LookaheadSettings {
        thrust_margin: 0.1,
        rollout_budget: 60,
        ..LookaheadSettings::default()
    }
}

/// The terminal targeting of every calls file: the last 4 cycles solved.
fn terminal_settings() -> TerminalSettings {
    TerminalSettings {
        cycles: 4,
        ..TerminalSettings::default()
    }
}

/// The aids' values of calls.bin's header (see the module doc).
fn aid_values(spacecraft: &CanonicalSpacecraft) -> Vec<f64> {
    let (l, t) = (lookahead_settings(), terminal_settings());
    vec![
        spacecraft.thrust,
        spacecraft.exhaust_speed,
        l.goal_position,
        l.goal_velocity,
        l.accuracy_floor,
        l.fuel_weight,
        l.thrust_margin,
        l.cycle,
        f64::from(l.max_cycles),
        f64::from(l.arrival_margin),
        f64::from(l.rollout_budget),
        t.goal_position,
        t.goal_velocity,
        t.cycle,
        f64::from(t.cycles),
        f64::from(t.iterations),
    ]
}

/// How the calls of a geometry are written, and how its navigation states are made unusable.
trait CallGeometry: FlightGeometry {
    /// The C interface's command struct of the geometry.
    type CCommand: From<Self::Command>;
    /// What the C interface writes on a refused step.
    const REFUSED: Self::CCommand;

    /// The navigation state as calls.bin has it: position, velocity, mass.
    fn state_values(state: &Self::State) -> Vec<f64>;
    /// The command as replay.c prints it, throttle first.
    fn command_values(command: &Self::CCommand) -> Vec<f64>;
    /// `state` with mass `m`.
    fn with_mass(state: &Self::State, m: f64) -> Self::State;
    /// `state` moved to `x` on the x-axis.
    fn on_x_axis(state: &Self::State, x: f64) -> Self::State;
    /// `state` made unusable through what only this geometry has.
    fn unusable_here(state: &Self::State) -> Vec<Self::State>;
}

impl CallGeometry for Planar {
    type CCommand = lt_thrust_command;
    const REFUSED: lt_thrust_command = THRUST_OFF;

    fn state_values(s: &SpacecraftState) -> Vec<f64> {
        vec![s.r[0], s.r[1], s.v[0], s.v[1], s.m]
    }

    fn command_values(c: &lt_thrust_command) -> Vec<f64> {
        vec![c.throttle, c.alpha_r, c.alpha_theta]
    }

    fn with_mass(s: &SpacecraftState, m: f64) -> SpacecraftState {
        SpacecraftState { m, ..*s }
    }

    fn on_x_axis(s: &SpacecraftState, x: f64) -> SpacecraftState {
        SpacecraftState { r: [x, 0.0], ..*s }
    }

    fn unusable_here(_: &SpacecraftState) -> Vec<SpacecraftState> {
        Vec::new()
    }
}

impl CallGeometry for Spatial {
    type CCommand = lt_rtn_command;
    const REFUSED: lt_rtn_command = RTN_THRUST_OFF;

    fn state_values(s: &SpatialCraftState) -> Vec<f64> {
        let SpatialState { r, v } = s.orbit;
        vec![r[0], r[1], r[2], v[0], v[1], v[2], s.m]
    }

    fn command_values(c: &lt_rtn_command) -> Vec<f64> {
        vec![c.throttle, c.radial, c.transverse, c.normal]
    }

    fn with_mass(s: &SpatialCraftState, m: f64) -> SpatialCraftState {
        SpatialCraftState { m, ..*s }
    }

    fn on_x_axis(s: &SpatialCraftState, x: f64) -> SpatialCraftState {
        let orbit = SpatialState {
            r: [x, 0.0, 0.0],
            ..s.orbit
        };
        SpatialCraftState { orbit, ..*s }
    }

    /// An out-of-plane position that is NaN, and a velocity along the radius (no orbit plane,
    /// which the RTN features need).
    fn unusable_here(s: &SpatialCraftState) -> Vec<SpatialCraftState> {
        let [x, y, _] = s.orbit.r;
        let z_nan = SpatialState {
            r: [x, y, f64::NAN],
            ..s.orbit
        };
        let radial_velocity = SpatialState {
            v: s.orbit.r,
            ..s.orbit
        };
        [z_nan, radial_velocity]
            .map(|orbit| SpatialCraftState { orbit, ..*s })
            .to_vec()
    }
}

/// A problem whose guidance calls are recorded: its number and name in the C interface, its
/// target as calls.bin has it, and the Rust guidance step the C step wraps, on `N` features
/// with `OUT` action outputs; the onboard aids fly its target.
trait RecordedProblem<const N: usize, const OUT: usize>:
    TraceProblem<N, Geometry: CallGeometry, Target: Aim<N, OUT, Geometry = <Self as Problem<N>>::Geometry>>
{
    /// calls.bin's problem number: the C interface's `LT_PROBLEM_*`.
    const CODE: u32;
    /// The problem's name on the `load` and `policy` lines, as replay.c prints it.
    const NAME: &'static str;

    /// The target as calls.bin has it.
    fn target_values(target: &Self::Target) -> Vec<f64>;
    /// The target at the scenario's epoch, as given (not propagated): the refused inputs' target.
    fn epoch_target(scenario: &ScenarioOf<Self, N>) -> Self::Target;
    /// `target` made unusable.
    fn unusable_targets(target: &Self::Target) -> Vec<Self::Target>;
    /// The guidance step of `onboard` that the C interface's step of the problem wraps.
    fn step(
        policy: &Policy<'_, N, OUT>,
        navigation: &StateOf<Self, N>,
        target: &Self::Target,
        time_to_go: f64,
    ) -> Result<CommandOf<Self, N>, GuidanceError>;
}

impl RecordedProblem<TRANSFER_FEATURES, ACTION_LEN> for Transfer {
    const CODE: u32 = LT_PROBLEM_TRANSFER;
    const NAME: &'static str = "transfer";

    fn target_values(t: &OrbitShape) -> Vec<f64> {
        vec![t.a, t.e, t.omega, 0.0]
    }

    fn epoch_target(s: &Scenario) -> OrbitShape {
        s.target
    }

    /// A negative semi-major axis.
    fn unusable_targets(t: &OrbitShape) -> Vec<OrbitShape> {
        vec![OrbitShape { a: -1.0, ..*t }]
    }

    fn step(
        policy: &Policy<'_, TRANSFER_FEATURES>,
        navigation: &SpacecraftState,
        target: &OrbitShape,
        time_to_go: f64,
    ) -> Result<ThrustCommand, GuidanceError> {
        transfer_step(policy, navigation, target, time_to_go)
    }
}

impl RecordedProblem<RENDEZVOUS_FEATURES, ACTION_LEN> for Rendezvous {
    const CODE: u32 = LT_PROBLEM_RENDEZVOUS;
    const NAME: &'static str = "rendezvous";

    fn target_values(b: &CartesianState) -> Vec<f64> {
        vec![b.r[0], b.r[1], b.v[0], b.v[1]]
    }

    fn epoch_target(s: &Scenario) -> CartesianState {
        s.target.cartesian_at(s.target_nu0)
    }

    /// The body at r = 0.
    fn unusable_targets(b: &CartesianState) -> Vec<CartesianState> {
        vec![CartesianState { r: [0.0, 0.0], ..*b }]
    }

    fn step(
        policy: &Policy<'_, RENDEZVOUS_FEATURES>,
        navigation: &SpacecraftState,
        body: &CartesianState,
        time_to_go: f64,
    ) -> Result<ThrustCommand, GuidanceError> {
        rendezvous_step(policy, navigation, body, time_to_go)
    }
}

impl RecordedProblem<TRANSFER3_FEATURES, ACTION3_LEN> for Transfer3 {
    const CODE: u32 = LT_PROBLEM_TRANSFER3;
    const NAME: &'static str = "transfer3";

    /// Padded to the rendezvous body's six values: one record length per geometry.
    fn target_values(t: &TargetOrbit3) -> Vec<f64> {
        vec![
            t.shape.a,
            t.shape.e,
            t.shape.omega,
            t.plane.inclination,
            t.plane.raan,
            0.0,
        ]
    }

    fn epoch_target(s: &SpatialScenario) -> TargetOrbit3 {
        TargetOrbit3 {
            shape: s.scenario.target,
            plane: s.target_plane,
        }
    }

    /// A negative semi-major axis, a non-finite inclination.
    fn unusable_targets(t: &TargetOrbit3) -> Vec<TargetOrbit3> {
        let hyperbolic = OrbitShape { a: -1.0, ..t.shape };
        let mut no_plane = *t;
        no_plane.plane.inclination = f64::NAN;
        vec![
            TargetOrbit3 {
                shape: hyperbolic,
                ..*t
            },
            no_plane,
        ]
    }

    fn step(
        policy: &Policy<'_, TRANSFER3_FEATURES, ACTION3_LEN>,
        navigation: &SpatialCraftState,
        target: &TargetOrbit3,
        time_to_go: f64,
    ) -> Result<RtnCommand, GuidanceError> {
        transfer3_step(policy, navigation, target, time_to_go)
    }
}

impl RecordedProblem<RENDEZVOUS3_FEATURES, ACTION3_LEN> for Rendezvous3 {
    const CODE: u32 = LT_PROBLEM_RENDEZVOUS3;
    const NAME: &'static str = "rendezvous3";

    fn target_values(b: &SpatialState) -> Vec<f64> {
        [b.r, b.v].concat()
    }

    /// The body at the epoch in its plane, as `Rendezvous3::target` coasts it from.
    fn epoch_target(s: &SpatialScenario) -> SpatialState {
        let plan = &s.scenario;
        s.target_plane.embed(&plan.target.cartesian_at(plan.target_nu0))
    }

    /// The body at r = 0.
    fn unusable_targets(b: &SpatialState) -> Vec<SpatialState> {
        vec![SpatialState { r: [0.0; 3], ..*b }]
    }

    fn step(
        policy: &Policy<'_, RENDEZVOUS3_FEATURES, ACTION3_LEN>,
        navigation: &SpatialCraftState,
        body: &SpatialState,
        time_to_go: f64,
    ) -> Result<RtnCommand, GuidanceError> {
        rendezvous3_step(policy, navigation, body, time_to_go)
    }
}

/// One guidance call of problem `P`: how it is flown, its inputs and what the Rust controller
/// answered: the command and, for an aid, the words of its report; or the refusal.
struct Call<const N: usize, P: TraceProblem<N>> {
    aid: Aid,
    navigation: StateOf<P, N>,
    target: P::Target,
    time_to_go: f64,
    outcome: Result<(CommandOf<P, N>, String), lt_status>,
}

fn bits(values: &[f64]) -> String {
    let words: Vec<String> = values.iter().map(|x| format!("{:016x}", x.to_bits())).collect();
    words.join(" ")
}

fn name(code: lt_status) -> String {
    error_name(code as i32).to_string_lossy().into_owned()
}

/// A command as replay.c prints it.
fn command_bits<G: CallGeometry>(command: &G::CCommand) -> String {
    bits(&G::command_values(command))
}

/// An aid's report as the C interface writes it: the lookahead's chosen candidate or terminal
/// targeting's solved flag, whether an arrival was predicted, the predicted values (the
/// lookahead's position, velocity, mass and cost; terminal targeting's misses of the network's
/// continuation and of the plan; NaN where none) and the network's own command.
struct AidReport<C> {
    flag: u32,
    predicted: bool,
    values: Vec<f64>,
    network: C,
}

impl<C> AidReport<C> {
    /// What a refused call of `aid` reports: nothing predicted, the network's command `off`.
    fn refused(aid: Aid, off: C) -> Self {
        let values = if aid == Aid::Terminal { 2 } else { 4 };
        Self {
            flag: 0,
            predicted: false,
            values: vec![f64::NAN; values],
            network: off,
        }
    }
}

/// The words after the command on an aid's line, as replay.c prints the C report: the
/// lookahead's `chosen N predicted VALID POSITION VELOCITY MASS COST network COMMAND`, terminal
/// targeting's `solved S predicted VALID NETWORK_MISS PLANNED_MISS network COMMAND`.
fn report_words<G: CallGeometry>(aid: Aid, report: &AidReport<G::CCommand>) -> String {
    let flag = if aid == Aid::Terminal { "solved" } else { "chosen" };
    format!(
        " {flag} {} predicted {} {} network {}",
        report.flag,
        u32::from(report.predicted),
        bits(&report.values),
        command_bits::<G>(&report.network)
    )
}

/// One call flown with `aid` on these inputs, with what the Rust crates answer.
fn aided_call<const N: usize, const OUT: usize, P: RecordedProblem<N, OUT>>(
    aid: Aid,
    controller: &Controller<'_, N, OUT>,
    (navigation, target, time_to_go): (StateOf<P, N>, P::Target, f64),
    spacecraft: &CanonicalSpacecraft,
) -> Call<N, P>
where
    for<'a> Policy<'a, N, OUT>: onboard::guidance::Actor<N, OUT>,
{
    Call {
        aid,
        navigation,
        target,
        time_to_go,
        outcome: aided::<N, OUT, P>(aid, controller, &navigation, &target, time_to_go, spacecraft),
    }
}

/// What the Rust crates answer to one call flown with `aid`: the command and its report's words.
fn aided<const N: usize, const OUT: usize, P: RecordedProblem<N, OUT>>(
    aid: Aid,
    controller: &Controller<'_, N, OUT>,
    navigation: &StateOf<P, N>,
    target: &P::Target,
    time_to_go: f64,
    spacecraft: &CanonicalSpacecraft,
) -> Result<(CommandOf<P, N>, String), lt_status>
where
    for<'a> Policy<'a, N, OUT>: onboard::guidance::Actor<N, OUT>,
{
    // Through the C interface every step of a policy not loaded is refused with thrust off.
    let Controller::Network(policy) = controller else {
        return Err(LT_ERR_NOT_LOADED);
    };
    let code = |e: GuidanceError| guidance_error_code(&e);
    let words = |report| report_words::<P::Geometry>(aid, &report);
    match aid {
        Aid::Network => P::step(policy, navigation, target, time_to_go)
            .map(|c| (c, String::new()))
            .map_err(code),
        Aid::Lookahead => {
            let settings = lookahead_settings();
            let d = lookahead_step(policy, navigation, target, time_to_go, spacecraft, &settings).map_err(code)?;
            let p = d.predicted;
            let report = AidReport {
                flag: u32::try_from(d.chosen).unwrap_or(u32::MAX),
                predicted: p.is_some(),
                values: p.map_or(vec![f64::NAN; 4], |p| {
                    vec![p.residuals.position, p.residuals.velocity, p.mass, p.cost]
                }),
                network: d.network.into(),
            };
            Ok((d.command, words(report)))
        }
        Aid::Terminal => {
            let settings = terminal_settings();
            let d = terminal_step(policy, navigation, target, time_to_go, spacecraft, &settings).map_err(code)?;
            let report = AidReport {
                flag: u32::from(d.solved),
                predicted: d.network_miss.is_some(),
                values: [d.network_miss, d.planned_miss].map(|m| m.unwrap_or(f64::NAN)).to_vec(),
                network: d.network.into(),
            };
            Ok((d.command, words(report)))
        }
    }
}

/// Inputs every guidance step of `P` must refuse (and one the network cannot answer), around
/// `navigation` and `target`: navigation state, target, time to go.
fn refused_inputs<const N: usize, const OUT: usize, P: RecordedProblem<N, OUT>>(
    navigation: StateOf<P, N>,
    target: P::Target,
) -> Vec<(StateOf<P, N>, P::Target, f64)> {
    let with_state = |s| (s, target, 5.0);
    let mut inputs = vec![
        with_state(P::Geometry::with_mass(&navigation, f64::NAN)),
        with_state(P::Geometry::on_x_axis(&navigation, 0.0)),
        with_state(P::Geometry::with_mass(&navigation, -0.25)),
    ];
    inputs.extend(P::unusable_targets(&target).into_iter().map(|t| (navigation, t, 5.0)));
    inputs.extend([(navigation, target, -1.0), (navigation, target, f64::INFINITY)]);
    // Finite in f64, infinite as the network's f32 input.
    inputs.push(with_state(P::Geometry::on_x_axis(&navigation, 1e39)));
    inputs.extend(P::Geometry::unusable_here(&navigation).into_iter().map(with_state));
    inputs
}

/// The positions in a flight of `steps` calls that the aids fly: lookahead on six spread over
/// the flight (the first, a third, two thirds, then 6, 3 and 1 cycles before the arrival),
/// terminal targeting on the last five (4 of them within its 4 cycles).
fn aided_steps(steps: usize) -> Vec<(Aid, usize)> {
    let lookahead = [
        0,
        steps / 3,
        2 * steps / 3,
        steps.saturating_sub(6),
        steps.saturating_sub(3),
        steps.saturating_sub(1),
    ];
    let mut picked: Vec<(Aid, usize)> = lookahead.into_iter().map(|k| (Aid::Lookahead, k)).collect();
    picked.extend((steps.saturating_sub(5)..steps).map(|k| (Aid::Terminal, k)));
    picked
}

/// The guidance calls of the trace flights of problem `P`, flown by `controller`, then the
/// inputs it must refuse, then the aids' calls; a comment line per group to `out`.
fn problem_calls<const N: usize, const OUT: usize, P: RecordedProblem<N, OUT>>(
    problem: P,
    controller: &Controller<'_, N, OUT>,
    spacecraft: &CanonicalSpacecraft,
    out: &mut String,
) -> Result<Vec<Call<N, P>>, String>
where
    for<'a> Controller<'a, N, OUT>: Guide<N, P::Target, P::Geometry>,
    for<'a> Policy<'a, N, OUT>: onboard::guidance::Actor<N, OUT>,
{
    let loaded = matches!(controller, Controller::Network(_));
    let mut calls = Vec::new();
    let mut first = 0;
    let mut flights = Vec::new();
    for flight in flights_of(problem) {
        let mut failed = None;
        // The trace flight itself, on the plant firmware_sim::trace::fly flies it on.
        let setup = flight.setup().map_err(|e| e.to_string())?;
        let plan = P::Geometry::plan(&flight.scenario);
        fly_observed(problem, controller, &flight.scenario, &setup, flight.seed, |step| {
            match P::target(&flight.scenario, step.index) {
                Ok(target) => calls.push(Call {
                    aid: Aid::Network,
                    navigation: step.navigation,
                    target,
                    // As fly_observed computes it.
                    time_to_go: plan.time_to_go(step.index),
                    // A refused blob flies the SIL in safe mode; through the C interface every
                    // step of a policy not loaded is refused with thrust off.
                    outcome: match step.guidance_error {
                        _ if !loaded => Err(LT_ERR_NOT_LOADED),
                        None => Ok((step.command, String::new())),
                        Some(e) => Err(guidance_error_code(&e)),
                    },
                }),
                Err(e) => failed = Some(e),
            }
        })
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
        flights.push((flight.name, first..calls.len()));
        first = calls.len();
    }

    let navigation = calls.first().map(|c| c.navigation).ok_or("no flight steps")?;
    let target = P::epoch_target(&flights_of(problem)[0].scenario);
    let refused = refused_inputs::<N, OUT, P>(navigation, target);
    for &inputs in &refused {
        calls.push(aided_call::<N, OUT, P>(Aid::Network, controller, inputs, spacecraft));
    }
    writeln!(out, "# calls {first}..{}: inputs guidance refuses", calls.len()).map_err(|e| e.to_string())?;

    // The aids on the flights of 14-day cycles (their settings' cycle), then on every refused input.
    for (name, steps) in flights.iter().take(2) {
        first = calls.len();
        for (aid, k) in aided_steps(steps.len()) {
            let Some(step) = calls.get(steps.start + k) else {
                continue;
            };
            let inputs = (step.navigation, step.target, step.time_to_go);
            calls.push(aided_call::<N, OUT, P>(aid, controller, inputs, spacecraft));
        }
        writeln!(
            out,
            "# calls {first}..{}: flight {name}'s steps with lookahead, then its last with terminal targeting",
            calls.len()
        )
        .map_err(|e| e.to_string())?;
    }
    first = calls.len();
    for aid in [Aid::Lookahead, Aid::Terminal] {
        for &inputs in &refused {
            calls.push(aided_call::<N, OUT, P>(aid, controller, inputs, spacecraft));
        }
    }
    writeln!(
        out,
        "# calls {first}..{}: the inputs guidance refuses, with lookahead then terminal targeting",
        calls.len()
    )
    .map_err(|e| e.to_string())?;
    Ok(calls)
}

/// calls.bin and expected.txt of `blob` loaded and flown as problem `P`.
fn record<const N: usize, const OUT: usize, P: RecordedProblem<N, OUT>>(
    problem: P,
    blob: &[u8],
) -> Result<(Vec<u8>, String), String>
where
    for<'a> Controller<'a, N, OUT>: Guide<N, P::Target, P::Geometry>,
    for<'a> Policy<'a, N, OUT>: onboard::guidance::Actor<N, OUT>,
{
    let w = |e: std::fmt::Error| e.to_string();
    let mut expected = String::new();
    writeln!(
        expected,
        "lowthrust {}.{}.{} blob format {}",
        VERSION.major, VERSION.minor, VERSION.patch, VERSION.blob_format_version
    )
    .map_err(w)?;
    let controller = Controller::<N, OUT>::load::<P>(blob);
    let load_code = match &controller {
        Controller::Network(_) => LT_OK,
        Controller::SafeMode(e) => policy_error_code(e),
    };
    writeln!(expected, "load {} {} {}", P::NAME, load_code as i32, name(load_code)).map_err(w)?;
    if let Controller::Network(policy) = &controller {
        let q = match policy.quantization() {
            Quantization::F32 => "f32",
            Quantization::Int8 => "int8",
        };
        writeln!(expected, "policy {} {q}", P::NAME).map_err(w)?;
    }
    // The aids' rollouts fly the flights' spacecraft as designed.
    let spacecraft = flights_of(problem)[0].setup().map_err(|e| e.to_string())?.spacecraft;
    let calls = problem_calls(problem, &controller, &spacecraft, &mut expected)?;

    let mut records = b"LTGC".to_vec();
    records.extend(CALLS_FORMAT.to_le_bytes());
    records.extend(P::CODE.to_le_bytes());
    records.extend(u32::try_from(calls.len()).map_err(|e| e.to_string())?.to_le_bytes());
    for v in aid_values(&spacecraft) {
        records.extend(v.to_le_bytes());
    }
    for (i, call) in calls.iter().enumerate() {
        let values = [
            vec![call.aid.code()],
            P::Geometry::state_values(&call.navigation),
            P::target_values(&call.target),
            vec![call.time_to_go],
        ];
        for v in values.concat() {
            records.extend(v.to_le_bytes());
        }
        let word = call.aid.word();
        match &call.outcome {
            Ok((c, report)) => writeln!(
                expected,
                "call {i}{word} cmd {}{report}",
                command_bits::<P::Geometry>(&(*c).into())
            ),
            Err(code) => writeln!(
                expected,
                "call {i}{word} refused {} {} cmd {}{}",
                *code as i32,
                name(*code),
                command_bits::<P::Geometry>(&P::Geometry::REFUSED),
                match call.aid {
                    Aid::Network => String::new(),
                    aid => report_words::<P::Geometry>(aid, &AidReport::refused(aid, P::Geometry::REFUSED)),
                }
            ),
        }
        .map_err(w)?;
    }
    writeln!(expected, "end {} calls", calls.len()).map_err(w)?;
    Ok((records, expected))
}

fn run() -> Result<(), String> {
    let usage = "usage: guidance_calls BLOB OUT_DIR [--rendezvous] [--spatial]";
    let mut args = std::env::args().skip(1);
    let (Some(blob_path), Some(out_dir)) = (args.next(), args.next()) else {
        return Err(usage.into());
    };
    let (mut rendezvous, mut spatial) = (false, false);
    for a in args {
        match a.as_str() {
            "--rendezvous" => rendezvous = true,
            "--spatial" => spatial = true,
            _ => return Err(format!("unknown argument {a}; {usage}")),
        }
    }
    let blob = std::fs::read(&blob_path).map_err(|e| format!("{blob_path}: {e}"))?;
    let out_dir = PathBuf::from(out_dir);
    std::fs::create_dir_all(&out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;

    let (records, expected) = match (rendezvous, spatial) {
        (false, false) => record::<_, ACTION_LEN, _>(Transfer, &blob)?,
        (true, false) => record::<_, ACTION_LEN, _>(Rendezvous, &blob)?,
        (false, true) => record::<_, ACTION3_LEN, _>(Transfer3, &blob)?,
        (true, true) => record::<_, ACTION3_LEN, _>(Rendezvous3, &blob)?,
    };
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
