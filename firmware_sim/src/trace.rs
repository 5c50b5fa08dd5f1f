//! The SIL trace: one text format, and one set of flights per problem ([`TRANSFER_FLIGHTS`],
//! [`RENDEZVOUS_FLIGHTS`]), for the host run (`src/bin/sil_trace.rs`) and the Cortex-M4 image
//! (`m4/`), so the two runs can be diffed line by line (`scripts/qemu-sil.sh`). Every f64 is printed as its bit pattern in hex:
//! equal traces mean bit-identical flights, not flights that agree to printing precision.
//!
//! Lines (the image adds its measurements as lines starting with [`COMMENT`], which the diff
//! ignores):
//! - `blob f32|int8 bytes <n> provenance "<text>"` or `blob refused: <why>` (the typed load error);
//! - `flight <name> seed <seed> steps <n>` before each flight;
//! - `step <k> cmd <u> <ar> <at> applied <u> <ar> <at> missed <t> state <x> <y> <vx> <vy> <m>
//!   reward <r> guidance ok|<why>`, the command and the true state at the end of the step;
//! - `end steps <n> faults <n> reward <sum> final <x> <y> <vx> <vy> <m>` or `end error: <why>`.

use core::fmt::{self, Write};

use onboard::dynamics::{SpacecraftState, ThrustCommand};
use onboard::guidance::Guide;
use shared::blob::Quantization;
use shared::orbit::{OrbitElements, OrbitShape};
use shared::scenario::{ProblemKind, Scenario};
use shared::spacecraft::{Spacecraft, SpacecraftError};

use crate::{fly_observed, Controller, Dispersions, FlightSetup, FlightStep, FlightSummary, PlanarProblem, SilError};

/// First character of the lines a trace consumer must ignore (measurements, timings).
pub const COMMENT: char = '#';

/// One flight of the trace.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceFlight {
    /// The flight's name on its `flight` line.
    pub name: &'static str,
    /// What it flies.
    pub scenario: Scenario,
    /// The truth plant's dispersions.
    pub dispersions: Dispersions,
    /// Seed of the dispersions' draws.
    pub seed: u64,
}

impl TraceFlight {
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

/// The three flights of each problem: the nominal plant (the MDP itself), then the dispersed
/// plant of [`Dispersions::TYPICAL`], whose random draws (ChaCha, Gaussian by libm) must agree
/// too, then the nominal plant guided every 7 days over the same time of flight (a family's
/// cycle other than the thesis's).
const fn flights(names: [&'static str; 3], scenario: Scenario) -> [TraceFlight; 3] {
    let [nominal, dispersed, weekly] = names;
    [
        TraceFlight {
            name: nominal,
            scenario,
            dispersions: Dispersions::NONE,
            seed: 0,
        },
        TraceFlight {
            name: dispersed,
            scenario,
            dispersions: Dispersions::TYPICAL,
            seed: 20_261_121,
        },
        TraceFlight {
            name: weekly,
            scenario: Scenario {
                steps: 2 * scenario.steps,
                cycle: scenario.cycle / 2.0,
                ..scenario
            },
            dispersions: Dispersions::NONE,
            seed: 0,
        },
    ]
}

/// The transfer image's flights.
pub const TRANSFER_FLIGHTS: [TraceFlight; 3] = flights(["nominal", "dispersed", "weekly"], transfer());

/// The rendezvous image's flights (named apart, so a trace says which image wrote it).
pub const RENDEZVOUS_FLIGHTS: [TraceFlight; 3] = flights(
    ["rendezvous-nominal", "rendezvous-dispersed", "rendezvous-weekly"],
    rendezvous(),
);

/// The trace's flights of problem `P`.
pub fn flights_of<const N: usize, P: crate::Problem<N>>(_problem: P) -> &'static [TraceFlight; 3] {
    match P::KIND {
        ProblemKind::Transfer => &TRANSFER_FLIGHTS,
        ProblemKind::Rendezvous => &RENDEZVOUS_FLIGHTS,
    }
}

/// The header line: what `controller` made of `blob`, or why it refused it.
pub fn write_header<W: Write, const N: usize>(w: &mut W, blob: &[u8], controller: &Controller<'_, N>) -> fmt::Result {
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

fn write_command<W: Write>(w: &mut W, c: &ThrustCommand) -> fmt::Result {
    write!(w, "{} {} {}", Bits(c.throttle), Bits(c.alpha_r), Bits(c.alpha_theta))
}

fn write_state<W: Write>(w: &mut W, s: &SpacecraftState) -> fmt::Result {
    let [x, y] = s.r;
    let [vx, vy] = s.v;
    write!(w, "{} {} {} {} {}", Bits(x), Bits(y), Bits(vx), Bits(vy), Bits(s.m))
}

/// One `step` line.
pub fn write_step<W: Write, const N: usize>(w: &mut W, s: &FlightStep<N>) -> fmt::Result {
    write!(w, "step {} cmd ", s.index)?;
    write_command(w, &s.command)?;
    w.write_str(" applied ")?;
    write_command(w, &s.applied)?;
    write!(w, " missed {} state ", Bits(s.missed_thrust))?;
    write_state(w, &s.state)?;
    write!(w, " reward {} guidance ", Bits(s.reward))?;
    match &s.guidance_error {
        None => writeln!(w, "ok"),
        Some(e) => writeln!(w, "{e}"),
    }
}

/// The `end` line.
pub fn write_end<W: Write>(w: &mut W, result: &Result<FlightSummary, SilError>) -> fmt::Result {
    match result {
        Ok(s) => {
            write!(
                w,
                "end steps {} faults {} reward {} final ",
                s.steps,
                s.guidance_faults,
                Bits(s.total_reward)
            )?;
            write_state(w, &s.final_state)?;
            writeln!(w)
        }
        Err(e) => writeln!(w, "end error: {e}"),
    }
}

/// Flies `flight` as problem `P` with `actor`, writing its `flight`, `step` and `end` lines to
/// `w`. The outer error is a failed write; the inner result is the flight's.
pub fn fly<const N: usize, P: PlanarProblem<N>, A: Guide<N, P::Target>, W: Write>(
    w: &mut W,
    problem: P,
    actor: &A,
    flight: &TraceFlight,
) -> Result<Result<FlightSummary, SilError>, fmt::Error> {
    fly_observing(w, problem, actor, flight, |_| {})
}

/// [`fly`], each step also handed to `also` (after its line is written).
pub fn fly_observing<const N: usize, P: PlanarProblem<N>, A: Guide<N, P::Target>, W: Write>(
    w: &mut W,
    problem: P,
    actor: &A,
    flight: &TraceFlight,
    mut also: impl FnMut(&FlightStep<N>),
) -> Result<Result<FlightSummary, SilError>, fmt::Error> {
    writeln!(
        w,
        "flight {} seed {} steps {}",
        flight.name, flight.seed, flight.scenario.steps
    )?;
    let Ok(setup) = flight.setup() else {
        writeln!(w, "end error: invalid spacecraft")?;
        return Err(fmt::Error);
    };
    let mut written = Ok(());
    let result = fly_observed(problem, actor, &flight.scenario, &setup, flight.seed, |step| {
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
        assert_eq!(flights_of(crate::Transfer), &TRANSFER_FLIGHTS);
        assert_eq!(flights_of(crate::Rendezvous), &RENDEZVOUS_FLIGHTS);
    }
}
