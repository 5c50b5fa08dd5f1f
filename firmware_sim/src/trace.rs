//! The SIL trace: one text format, and one set of flights per problem ([`TRANSFER_FLIGHTS`],
//! [`RENDEZVOUS_FLIGHTS`], and on inclined orbits [`TRANSFER3_FLIGHTS`], [`RENDEZVOUS3_FLIGHTS`]),
//! for the host run (`src/bin/sil_trace.rs`) and the Cortex-M4 image (`m4/`), so the two runs can
//! be diffed line by line (`scripts/qemu-sil.sh`). Every f64 is printed as its bit pattern in
//! hex: equal traces mean bit-identical flights, not flights that agree to printing precision.
//!
//! Lines (the image adds its measurements as lines starting with [`COMMENT`], which the diff
//! ignores):
//! - `blob f32|int8 bytes <n> provenance "<text>"` or `blob refused: <why>` (the typed load error);
//! - `flight <name> seed <seed> steps <n>` before each flight;
//! - `step <k> cmd <u> <ar> <at> applied <u> <ar> <at> missed <t> state <x> <y> <vx> <vy> <m>
//!   reward <r> guidance ok|<why>`, the command and the true state at the end of the step (in
//!   three dimensions `cmd <u> <radial> <transverse> <normal>` and `state <x> <y> <z> <vx> <vy>
//!   <vz> <m>`, [`TraceGeometry`]);
//! - `end steps <n> faults <n> reward <sum> final <state>` or `end error: <why>`.

use core::fmt::{self, Write};

use onboard::dynamics::{SpacecraftState, ThrustCommand};
use onboard::features::{RENDEZVOUS3_FEATURES, RENDEZVOUS_FEATURES, TRANSFER3_FEATURES, TRANSFER_FEATURES};
use onboard::guidance::Guide;
use onboard::spatial::{RtnCommand, SpatialCraftState};
use shared::blob::Quantization;
use shared::orbit::{OrbitElements, OrbitPlane, OrbitShape};
use shared::scenario::{ProblemKind, Scenario, SpatialScenario};
use shared::spacecraft::{Spacecraft, SpacecraftError};

use crate::{
    fly_observed, Controller, Dimension, Dispersions, FlightGeometry, FlightSetup, FlightStep, FlightSummary, Planar,
    Problem, Rendezvous, Rendezvous3, ScenarioOf, SilError, Spatial, Transfer, Transfer3,
};

/// First character of the lines a trace consumer must ignore (measurements, timings).
pub const COMMENT: char = '#';

/// One flight of the trace, of a planar [`Scenario`] or (`S` = [`SpatialScenario`]) in three
/// dimensions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceFlight<S = Scenario> {
    /// The flight's name on its `flight` line.
    pub name: &'static str,
    /// What it flies.
    pub scenario: S,
    /// The truth plant's dispersions.
    pub dispersions: Dispersions,
    /// Seed of the dispersions' draws.
    pub seed: u64,
}

impl<S> TraceFlight<S> {
    /// The plant the flight flies, wherever it is flown (here, the C interface's replay): the
    /// thesis spacecraft, default tolerances and reward weights, the flight's dispersions.
    pub fn setup(&self) -> Result<FlightSetup, SpacecraftError> {
        Ok(FlightSetup::nominal(Spacecraft::MSR_ERO.canonical()?).dispersed(self.dispersions))
    }
}

/// A circular 1 AU -> 1.3 AU transfer (39 steps of 14 days) from nu = 0.3 rad.
const fn transfer() -> Scenario {
    Scenario {
        problem: ProblemKind::Transfer,
        initial: OrbitElements {
            shape: OrbitShape {
                a: 1.0,
                e: 0.0,
                omega: 0.0,
            },
            nu: 0.3,
        },
        target: OrbitShape {
            a: 1.3,
            e: 0.0,
            omega: 0.0,
        },
        target_nu0: 0.0,
        // Scenario::steps_for (docs/spec.md section 4): ceil(2 pi 1.3^1.5 / STEP); a test checks it.
        steps: 39,
        cycle: shared::units::STEP,
    }
}

/// The same orbits as a rendezvous with a body starting 40 degrees ahead of the spacecraft
/// (nu = 0.3 + 0.7 rad), so the flight has to phase as well as raise its orbit.
const fn rendezvous() -> Scenario {
    let transfer = transfer();
    Scenario {
        problem: ProblemKind::Rendezvous,
        target_nu0: 1.0,
        ..transfer
    }
}

/// The 1 AU -> 1.3 AU transfer of [`transfer`] to a target orbit inclined by 3 degrees, its
/// ascending node at 1 rad: the inclined preset's kind of draw.
const fn transfer3() -> SpatialScenario {
    SpatialScenario {
        scenario: transfer(),
        initial_plane: OrbitPlane::REFERENCE,
        target_plane: OrbitPlane {
            inclination: 3.0 * core::f64::consts::PI / 180.0,
            raan: 1.0,
        },
    }
}

/// The same orbits as a rendezvous with a body on the inclined orbit (the planar rendezvous's
/// anomaly, in its own plane).
const fn rendezvous3() -> SpatialScenario {
    SpatialScenario {
        scenario: rendezvous(),
        ..transfer3()
    }
}

/// The three flights of each problem: the nominal plant (the MDP itself), then the dispersed
/// plant of [`Dispersions::TYPICAL`], whose random draws (ChaCha, Gaussian by libm) must agree
/// too, then the nominal plant guided every 7 days over the same time of flight (a family's
/// cycle other than the thesis's).
const fn flights<S: Copy>(names: [&'static str; 3], scenario: S, weekly: S) -> [TraceFlight<S>; 3] {
    let [nominal_name, dispersed_name, weekly_name] = names;
    [
        TraceFlight {
            name: nominal_name,
            scenario,
            dispersions: Dispersions::NONE,
            seed: 0,
        },
        TraceFlight {
            name: dispersed_name,
            scenario,
            dispersions: Dispersions::TYPICAL,
            seed: 20_261_121,
        },
        TraceFlight {
            name: weekly_name,
            scenario: weekly,
            dispersions: Dispersions::NONE,
            seed: 0,
        },
    ]
}

/// `scenario` guided twice as often over the same time of flight.
const fn weekly(scenario: Scenario) -> Scenario {
    Scenario {
        steps: 2 * scenario.steps,
        cycle: scenario.cycle / 2.0,
        ..scenario
    }
}

/// `scenario` guided twice as often, in three dimensions.
const fn weekly3(scenario: SpatialScenario) -> SpatialScenario {
    SpatialScenario {
        scenario: weekly(scenario.scenario),
        ..scenario
    }
}

/// The transfer image's flights.
pub const TRANSFER_FLIGHTS: [TraceFlight; 3] =
    flights(["nominal", "dispersed", "weekly"], transfer(), weekly(transfer()));

/// The rendezvous image's flights (named apart, so a trace says which image wrote it).
pub const RENDEZVOUS_FLIGHTS: [TraceFlight; 3] = flights(
    ["rendezvous-nominal", "rendezvous-dispersed", "rendezvous-weekly"],
    rendezvous(),
    weekly(rendezvous()),
);

/// The three-dimensional transfer image's flights.
pub const TRANSFER3_FLIGHTS: [TraceFlight<SpatialScenario>; 3] = flights(
    ["inclined-nominal", "inclined-dispersed", "inclined-weekly"],
    transfer3(),
    weekly3(transfer3()),
);

/// The three-dimensional rendezvous image's flights.
pub const RENDEZVOUS3_FLIGHTS: [TraceFlight<SpatialScenario>; 3] = flights(
    [
        "inclined-rendezvous-nominal",
        "inclined-rendezvous-dispersed",
        "inclined-rendezvous-weekly",
    ],
    rendezvous3(),
    weekly3(rendezvous3()),
);

/// How a geometry's states and commands are written on `step` and `end` lines.
pub trait TraceGeometry: FlightGeometry {
    /// The command's numbers (throttle first).
    fn write_command<W: Write>(w: &mut W, c: &Self::Command) -> fmt::Result;
    /// The state's numbers (position, velocity, mass).
    fn write_state<W: Write>(w: &mut W, s: &Self::State) -> fmt::Result;
}

impl TraceGeometry for Planar {
    fn write_command<W: Write>(w: &mut W, c: &ThrustCommand) -> fmt::Result {
        write!(w, "{} {} {}", Bits(c.throttle), Bits(c.alpha_r), Bits(c.alpha_theta))
    }

    fn write_state<W: Write>(w: &mut W, s: &SpacecraftState) -> fmt::Result {
        let [x, y] = s.r;
        let [vx, vy] = s.v;
        write!(w, "{} {} {} {} {}", Bits(x), Bits(y), Bits(vx), Bits(vy), Bits(s.m))
    }
}

impl TraceGeometry for Spatial {
    fn write_command<W: Write>(w: &mut W, c: &RtnCommand) -> fmt::Result {
        write!(
            w,
            "{} {} {} {}",
            Bits(c.throttle),
            Bits(c.radial),
            Bits(c.transverse),
            Bits(c.normal)
        )
    }

    fn write_state<W: Write>(w: &mut W, s: &SpatialCraftState) -> fmt::Result {
        let [x, y, z] = s.orbit.r;
        let [vx, vy, vz] = s.orbit.v;
        write!(
            w,
            "{} {} {} {} {} {} {}",
            Bits(x),
            Bits(y),
            Bits(z),
            Bits(vx),
            Bits(vy),
            Bits(vz),
            Bits(s.m)
        )
    }
}

/// A problem the trace flies: its three flights, written in its geometry.
pub trait TraceProblem<const N: usize>: Problem<N, Geometry: TraceGeometry> {
    /// The trace's flights of this problem.
    const FLIGHTS: &'static [TraceFlight<ScenarioOf<Self, N>>; 3];
}

impl TraceProblem<TRANSFER_FEATURES> for Transfer {
    const FLIGHTS: &'static [TraceFlight; 3] = &TRANSFER_FLIGHTS;
}

impl TraceProblem<RENDEZVOUS_FEATURES> for Rendezvous {
    const FLIGHTS: &'static [TraceFlight; 3] = &RENDEZVOUS_FLIGHTS;
}

impl TraceProblem<TRANSFER3_FEATURES> for Transfer3 {
    const FLIGHTS: &'static [TraceFlight<SpatialScenario>; 3] = &TRANSFER3_FLIGHTS;
}

impl TraceProblem<RENDEZVOUS3_FEATURES> for Rendezvous3 {
    const FLIGHTS: &'static [TraceFlight<SpatialScenario>; 3] = &RENDEZVOUS3_FLIGHTS;
}

/// The trace's flights of problem `P`.
pub fn flights_of<const N: usize, P: TraceProblem<N>>(_problem: P) -> &'static [TraceFlight<ScenarioOf<P, N>>; 3] {
    P::FLIGHTS
}

/// The header line: what `controller` made of `blob`, or why it refused it.
pub fn write_header<W: Write, const N: usize, const OUT: usize>(
    w: &mut W,
    blob: &[u8],
    controller: &Controller<'_, N, OUT>,
) -> fmt::Result {
    match controller {
        Controller::Network(policy) => {
            let q = match policy.quantization() {
                Quantization::F32 => "f32",
                Quantization::Int8 => "int8",
            };
            // The policy keeps no provenance; the blob decoded once more has it.
            let provenance = shared::blob::decode(blob).map_or("", |net| net.provenance);
            writeln!(w, "blob {q} bytes {} provenance {provenance:?}", blob.len())
        }
        Controller::SafeMode(e) => writeln!(w, "blob refused: {e}"),
    }
}

struct Bits(f64);

impl fmt::Display for Bits {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:016x}", self.0.to_bits())
    }
}

/// One `step` line.
pub fn write_step<W: Write, const N: usize, G: TraceGeometry>(w: &mut W, s: &FlightStep<N, G>) -> fmt::Result {
    write!(w, "step {} cmd ", s.index)?;
    G::write_command(w, &s.command)?;
    w.write_str(" applied ")?;
    G::write_command(w, &s.applied)?;
    write!(w, " missed {} state ", Bits(s.missed_thrust))?;
    G::write_state(w, &s.state)?;
    write!(w, " reward {} guidance ", Bits(s.reward))?;
    match &s.guidance_error {
        None => writeln!(w, "ok"),
        Some(e) => writeln!(w, "{e}"),
    }
}

/// The `end` line.
pub fn write_end<W: Write, G: TraceGeometry>(w: &mut W, result: &Result<FlightSummary<G>, SilError>) -> fmt::Result {
    match result {
        Ok(s) => {
            write!(
                w,
                "end steps {} faults {} reward {} final ",
                s.steps,
                s.guidance_faults,
                Bits(s.total_reward)
            )?;
            G::write_state(w, &s.final_state)?;
            writeln!(w)
        }
        Err(e) => writeln!(w, "end error: {e}"),
    }
}

/// Flies `flight` as problem `P` with `guide`, writing its `flight`, `step` and `end` lines to
/// `w`. The outer error is a failed write; the inner result is the flight's.
pub fn fly<const N: usize, P: TraceProblem<N>, A: Guide<N, P::Target, P::Geometry>, W: Write>(
    w: &mut W,
    problem: P,
    guide: &A,
    flight: &TraceFlight<ScenarioOf<P, N>>,
) -> Result<Result<FlightSummary<P::Geometry>, SilError>, fmt::Error> {
    fly_observing(w, problem, guide, flight, |_| {})
}

/// [`fly`], each step also handed to `also` (after its line is written).
pub fn fly_observing<const N: usize, P: TraceProblem<N>, A: Guide<N, P::Target, P::Geometry>, W: Write>(
    w: &mut W,
    problem: P,
    guide: &A,
    flight: &TraceFlight<ScenarioOf<P, N>>,
    mut also: impl FnMut(&FlightStep<N, P::Geometry>),
) -> Result<Result<FlightSummary<P::Geometry>, SilError>, fmt::Error> {
    writeln!(
        w,
        "flight {} seed {} steps {}",
        flight.name,
        flight.seed,
        P::Geometry::plan(&flight.scenario).steps
    )?;
    let Ok(setup) = flight.setup() else {
        writeln!(w, "end error: invalid spacecraft")?;
        return Err(fmt::Error);
    };
    let mut written = Ok(());
    let result = fly_observed(problem, guide, &flight.scenario, &setup, flight.seed, |step| {
        if written.is_ok() {
            written = write_step(w, step);
        }
        also(step);
    });
    written?;
    write_end(w, &result)?;
    Ok(result)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_trace_scenarios_have_the_spec_time_of_flight() {
        let s = transfer();
        assert_eq!(s, Scenario::transfer(s.initial, s.target));
        let r = rendezvous();
        assert_eq!(r.steps, Scenario::steps_for(&r.initial.shape, &r.target));
        assert_eq!((r.initial, r.target), (s.initial, s.target));
        assert!(r.validate().is_ok());
    }

    #[test]
    fn each_problem_has_its_own_flights() {
        assert!(TRANSFER_FLIGHTS
            .iter()
            .all(|f| f.scenario.problem == ProblemKind::Transfer));
        assert!(RENDEZVOUS_FLIGHTS
            .iter()
            .all(|f| f.scenario.problem == ProblemKind::Rendezvous));
        assert!(TRANSFER3_FLIGHTS
            .iter()
            .all(|f| f.scenario.scenario.problem == ProblemKind::Transfer && !f.scenario.is_planar()));
        assert!(RENDEZVOUS3_FLIGHTS
            .iter()
            .all(|f| f.scenario.scenario.problem == ProblemKind::Rendezvous && !f.scenario.is_planar()));
        assert_eq!(flights_of(Transfer), &TRANSFER_FLIGHTS);
        assert_eq!(flights_of(Rendezvous), &RENDEZVOUS_FLIGHTS);
        assert_eq!(flights_of(Transfer3), &TRANSFER3_FLIGHTS);
        assert_eq!(flights_of(Rendezvous3), &RENDEZVOUS3_FLIGHTS);
    }

    /// A fixed action of `OUT` components, whatever the features.
    struct Constant<const OUT: usize>([f32; OUT]);

    impl<const N: usize, const OUT: usize> onboard::guidance::Actor<N, OUT> for Constant<OUT> {
        fn act(&self, _features: &[f32; N]) -> [f32; OUT] {
            self.0
        }
    }

    /// The numbers after `word` on a line, read back from their bit patterns.
    fn numbers_after(line: &str, word: &str, count: usize) -> Vec<f64> {
        let words: Vec<&str> = line.split(' ').collect();
        let at = words
            .iter()
            .position(|w| *w == word)
            .unwrap_or_else(|| panic!("no {word} in {line}"));
        words[at + 1..at + 1 + count]
            .iter()
            .map(|w| f64::from_bits(u64::from_str_radix(w, 16).unwrap()))
            .collect()
    }

    /// The trace of every flight of `P` read back equals the recorded flights, number for number
    /// (so the host/QEMU diff compares the whole state and command), with no number left over.
    fn trace_reads_back<const N: usize, P: TraceProblem<N>, A: Guide<N, P::Target, P::Geometry>>(
        problem: P,
        actor: &A,
        state: impl Fn(&<P::Geometry as Dimension>::State) -> Vec<f64>,
        command: impl Fn(&<P::Geometry as Dimension>::Command) -> Vec<f64>,
    ) {
        for flight in flights_of(problem) {
            let mut text = String::new();
            let mut steps = Vec::new();
            let summary = fly_observing(&mut text, problem, actor, flight, |s| steps.push(*s))
                .unwrap()
                .unwrap();
            let lines: Vec<&str> = text.lines().collect();
            assert_eq!(lines.len(), steps.len() + 2, "{}", flight.name);
            assert!(lines[0].starts_with(&format!("flight {} ", flight.name)));
            for (line, step) in lines[1..].iter().zip(&steps) {
                let (s, c) = (state(&step.state), command(&step.command));
                assert_eq!(numbers_after(line, "cmd", c.len()), c);
                assert_eq!(numbers_after(line, "applied", c.len()), command(&step.applied));
                assert_eq!(numbers_after(line, "state", s.len()), s);
                // The state is the last group before the reward.
                assert_eq!(line.split(' ').nth_back(3), Some("reward"));
                let words = line.split(' ').count();
                assert_eq!(words, 2 + 2 * (1 + c.len()) + 2 + 1 + s.len() + 4, "{line}");
            }
            let end = lines.last().unwrap();
            assert_eq!(
                numbers_after(end, "final", state(&summary.final_state).len()),
                state(&summary.final_state)
            );
            assert_eq!(end.split(' ').count(), 8 + state(&summary.final_state).len(), "{end}");
        }
    }

    #[test]
    fn the_trace_carries_every_number_of_the_flight_in_both_dimensions() {
        let planar_state = |s: &SpacecraftState| vec![s.r[0], s.r[1], s.v[0], s.v[1], s.m];
        let planar_command = |c: &ThrustCommand| vec![c.throttle, c.alpha_r, c.alpha_theta];
        let spatial_state = |s: &SpatialCraftState| {
            let (r, v) = (s.orbit.r, s.orbit.v);
            vec![r[0], r[1], r[2], v[0], v[1], v[2], s.m]
        };
        let spatial_command = |c: &RtnCommand| vec![c.throttle, c.radial, c.transverse, c.normal];
        let planar = Constant([0.2, 0.3, 0.9]);
        let spatial = Constant([0.2, 0.1, 0.9, 0.4]);
        trace_reads_back(Transfer, &planar, planar_state, planar_command);
        trace_reads_back(Rendezvous, &planar, planar_state, planar_command);
        trace_reads_back(Transfer3, &spatial, spatial_state, spatial_command);
        trace_reads_back(Rendezvous3, &spatial, spatial_state, spatial_command);
    }

    #[test]
    fn the_inclined_flights_are_the_planar_ones_turned_out_of_the_plane() {
        for (planar, inclined) in TRANSFER_FLIGHTS
            .iter()
            .zip(&TRANSFER3_FLIGHTS)
            .chain(RENDEZVOUS_FLIGHTS.iter().zip(&RENDEZVOUS3_FLIGHTS))
        {
            assert_eq!(inclined.scenario.scenario, planar.scenario);
            assert_eq!((inclined.dispersions, inclined.seed), (planar.dispersions, planar.seed));
            assert!(inclined.scenario.validate().is_ok());
            assert!((inclined.scenario.target_plane.inclination.to_degrees() - 3.0).abs() < 1e-12);
        }
    }
}
