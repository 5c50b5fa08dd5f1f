//! The Cortex-M4F flight image (QEMU mps2-an386): the SIL guidance loop of `firmware_sim`
//! flying the trace's flights with the weight blob linked into flash, the trace and the
//! measurements written through semihosting.
//!
//! The image flies one problem, chosen at build time: transfers by default, rendezvous with the
//! `rendezvous` feature, and either in three dimensions with the `spatial` feature (the inclined
//! trace flights, a 4-output network; flight software is built for its mission, and one
//! network's code keeps the image small). The blob is refused at load if it is of another
//! version, problem, dimension or shape, truncated or altered: the typed error goes into the trace and the flights are flown in safe
//! mode (thrust off), then the image exits 0 as usual, since refusing is the correct behaviour.
//! It exits 1 only when the firmware itself fails (panic, fault, output error).
#![no_std]
#![no_main]
// As in onboard: a panic here would be a failed flight, so the linter refuses the ways to write one.
#![deny(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing,
    clippy::unreachable,
    clippy::todo,
    clippy::unimplemented
)]

mod counter;
#[cfg(feature = "profile")]
mod profile;
mod semi;
mod stack;

use core::fmt::Write;

use cortex_m_rt::{entry, exception, ExceptionFrame};
use firmware_sim::trace::{self, COMMENT};
use firmware_sim::Controller;

use counter::{Counted, Counter, INSTRUCTIONS_PER_TICK, MAX_SAMPLES};

/// The problem this image flies, and its network's input and output counts.
#[cfg(all(not(feature = "rendezvous"), not(feature = "spatial")))]
mod mission {
    pub use firmware_sim::Transfer as Flown;
    pub const FEATURES: usize = onboard::features::TRANSFER_FEATURES;
    pub const ACTIONS: usize = onboard::features::ACTION_LEN;
}
#[cfg(all(feature = "rendezvous", not(feature = "spatial")))]
mod mission {
    pub use firmware_sim::Rendezvous as Flown;
    pub const FEATURES: usize = onboard::features::RENDEZVOUS_FEATURES;
    pub const ACTIONS: usize = onboard::features::ACTION_LEN;
}
#[cfg(all(not(feature = "rendezvous"), feature = "spatial"))]
mod mission {
    pub use firmware_sim::Transfer3 as Flown;
    pub const FEATURES: usize = onboard::features::TRANSFER3_FEATURES;
    pub const ACTIONS: usize = onboard::features::ACTION3_LEN;
}
#[cfg(all(feature = "rendezvous", feature = "spatial"))]
mod mission {
    pub use firmware_sim::Rendezvous3 as Flown;
    pub const FEATURES: usize = onboard::features::RENDEZVOUS3_FEATURES;
    pub const ACTIONS: usize = onboard::features::ACTION3_LEN;
}
use mission::{Flown, ACTIONS, FEATURES};

/// The flight computer's controller of this image's problem.
type FlownController<'a> = Controller<'a, FEATURES, ACTIONS>;
/// The dimension this image flies in.
type FlownGeometry = <Flown as firmware_sim::Problem<FEATURES>>::Geometry;
/// The state the flight's navigation reports.
type FlownState = firmware_sim::StateOf<Flown, FEATURES>;
/// A trace flight of this image's problem.
type FlownFlight = trace::TraceFlight<firmware_sim::ScenarioOf<Flown, FEATURES>>;

/// Aligns the blob in flash (64 bytes: a cache line on parts that have one); the decoder does
/// not need it, since it reads every array byte-wise.
#[repr(C, align(64))]
struct Aligned<B: ?Sized>(B);

/// The weight blob named by `LOWTHRUST_BLOB` at build time (build.rs), in flash (.rodata).
static BLOB: &Aligned<[u8]> = &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/policy.blob")));

/// Length of the calibration loop: 2 * N instructions.
const CALIBRATION_LOOP: u32 = 1_000_000;
/// Back-to-back inferences of the repeated measurement (resolution 40 / 64 instructions).
const REPEATS: u32 = 64;
/// Cycles left in the measured lookahead cycle: at most 21 rollouts of 4 cycles (one
/// measurement stays well inside the SysTick's 2^24 ticks).
const LOOKAHEAD_CYCLES: u32 = 4;
/// Cycles left in the measured lookahead cycle under a rollout budget: a transfer's start.
const BUDGETED_CYCLES: u32 = 50;
/// The rollout budget of that measurement, in steps: 6 rollouts of 50 one-step cycles.
const ROLLOUT_BUDGET: u32 = 300;
/// Cycles left in the first measured terminal-targeting cycle: the default settings' most.
const TERMINAL_CYCLES: u32 = 8;

/// The first trace flight's navigation state with 1 ..= [`TERMINAL_CYCLES`] cycles to go.
type TerminalStates = [Option<FlownState>; TERMINAL_CYCLES as usize];

#[entry]
fn main() -> ! {
    stack::paint();
    let mut out = semi::Out::new();
    match run(&mut out) {
        Ok(()) => semi::exit(true),
        Err(core::fmt::Error) => semi::fail(format_args!("semihosting output failed")),
    }
}

fn run(out: &mut semi::Out) -> core::fmt::Result {
    let Some(peripherals) = cortex_m::Peripherals::take() else {
        semi::fail(format_args!("core peripherals already taken"))
    };
    let counter = Counter::start(peripherals.SYST);
    let blob: &'static [u8] = &BLOB.0;
    let controller = FlownController::load::<Flown>(blob);
    let counted = Counted::new(&controller, &counter);
    let terminal_states = fly(out, blob, &controller, &counted)?;
    // The flights' stack peak, before the measurements add their own frames.
    let flight_stack = stack::high_water();
    measure(out, &counter, &controller, &counted, &terminal_states)?;
    writeln!(
        out,
        "{COMMENT} stack: {} bytes reserved, high-water mark {flight_stack} bytes in flight, {} bytes with the \
         measurements",
        stack::reserved(),
        stack::high_water()
    )
}

/// The trace: header, then every flight. Not inlined, so its frames are the flights' own.
#[inline(never)]
fn fly(
    out: &mut semi::Out,
    blob: &[u8],
    controller: &FlownController<'_>,
    counted: &Counted<'_, FlownController<'_>, FEATURES>,
) -> Result<TerminalStates, core::fmt::Error> {
    trace::write_header(out, blob, controller)?;
    let mut terminal_states = [None; TERMINAL_CYCLES as usize];
    for (i, flight) in trace::flights_of(Flown).iter().enumerate() {
        let steps = <FlownGeometry as firmware_sim::Dimension>::plan(&flight.scenario).steps;
        // The flight's outcome is in its `end` line.
        let _flown = trace::fly_observing(out, Flown, counted, flight, |step| {
            // Where the first flight's navigation stands with 1 ..= TERMINAL_CYCLES to go.
            let to_go = steps.saturating_sub(step.index);
            let slot = to_go.checked_sub(1).and_then(|k| terminal_states.get_mut(k as usize));
            if let (0, Some(slot)) = (i, slot) {
                *slot = Some(step.navigation);
            }
        })?;
    }
    Ok(terminal_states)
}

/// The measurements, as comment lines (not compared with the host).
#[inline(never)]
fn measure(
    out: &mut semi::Out,
    counter: &Counter,
    controller: &FlownController<'_>,
    counted: &Counted<'_, FlownController<'_>, FEATURES>,
    terminal_states: &TerminalStates,
) -> core::fmt::Result {
    let (empty, looped) = counter::calibrate(counter, CALIBRATION_LOOP);
    writeln!(
        out,
        "{COMMENT} calibration: empty measurement {empty} ticks, counted loop of {} instructions {looped} ticks \
         ({INSTRUCTIONS_PER_TICK} instructions per tick expected)",
        2 * CALIBRATION_LOOP
    )?;
    let mut samples = [0u32; MAX_SAMPLES];
    let n = counted.samples(&mut samples);
    if let Some(ticks) = samples.get_mut(..n) {
        insertion_sort(ticks);
        if let (Some(min), Some(med), Some(max)) = (ticks.first(), ticks.get(n / 2), ticks.last()) {
            let i = |t: &u32| t.saturating_mul(INSTRUCTIONS_PER_TICK);
            writeln!(
                out,
                "{COMMENT} instructions per inference over the flights' {n} inferences: median {} min {} max {} \
                 (resolution {INSTRUCTIONS_PER_TICK})",
                i(med),
                i(min),
                i(max)
            )?;
        }
    }
    let Some(x) = counted.first_input() else {
        return Ok(());
    };
    let ticks = counter::repeated(controller, counter, &x, REPEATS);
    let total = u64::from(ticks) * u64::from(INSTRUCTIONS_PER_TICK);
    writeln!(
        out,
        "{COMMENT} instructions per inference, {REPEATS} back to back on the first step's features: {}.{:02} \
         (resolution {INSTRUCTIONS_PER_TICK}/{REPEATS})",
        total / u64::from(REPEATS),
        (total % u64::from(REPEATS)) * 100 / u64::from(REPEATS),
    )?;
    lookahead(out, counter, controller, LOOKAHEAD_CYCLES, 0)?;
    lookahead(out, counter, controller, BUDGETED_CYCLES, ROLLOUT_BUDGET)?;
    terminal(out, counter, controller, terminal_states)?;
    // Built only with `--features profile`: its standalone kernel copies cost ~40 KB of flash.
    #[cfg(feature = "profile")]
    if let Controller::Network(policy) = controller {
        profile::write(out, counter, policy, &x)?;
    }
    Ok(())
}

/// The first trace flight, its target and the nominal spacecraft: what the onboard aids'
/// measurements fly.
fn first_flight() -> Option<(
    &'static FlownFlight,
    <Flown as firmware_sim::Problem<FEATURES>>::Target,
    shared::spacecraft::CanonicalSpacecraft,
)> {
    use firmware_sim::Problem;
    let flight = trace::flights_of(Flown).first()?;
    let target = <Flown as Problem<FEATURES>>::target(&flight.scenario, 0).ok()?;
    let spacecraft = shared::spacecraft::Spacecraft::MSR_ERO.canonical().ok()?;
    Some((flight, target, spacecraft))
}

/// One guidance cycle with rollout lookahead (`onboard::lookahead`) from the first flight's
/// start, `cycles` cycles before the arrival, with a rollout budget (0: none): its instructions,
/// whole and per step propagated (at one step a cycle, an inference and a 14-day propagation).
#[inline(never)]
fn lookahead(
    out: &mut semi::Out,
    counter: &Counter,
    controller: &FlownController<'_>,
    cycles: u32,
    rollout_budget: u32,
) -> core::fmt::Result {
    use firmware_sim::Dimension;
    use onboard::lookahead::{lookahead_step, LookaheadSettings, CANDIDATES};

    let Some((flight, target, spacecraft)) = first_flight() else {
        return writeln!(out, "{COMMENT} lookahead: no flight, target or spacecraft");
    };
    let state = FlownGeometry::departure(&flight.scenario);
    let time_to_go = f64::from(cycles) * shared::units::STEP;
    let settings = LookaheadSettings {
        rollout_budget,
        ..LookaheadSettings::default()
    };
    let start = counter.now();
    let decision = lookahead_step(controller, &state, &target, time_to_go, &spacecraft, &settings);
    let ticks = Counter::ticks(start, counter.now());
    let (flown, steps) = decision.map_or((0, 0), |d| (d.rollouts, d.steps));
    let total = u64::from(ticks) * u64::from(INSTRUCTIONS_PER_TICK);
    writeln!(
        out,
        "{COMMENT} instructions per lookahead cycle, {cycles} cycles to go, rollout budget {rollout_budget} steps \
         ({flown} of {CANDIDATES} candidates flown, {steps} steps propagated): {total}, {} per step; chosen \
         candidate {}",
        total / u64::from(steps.max(1)),
        decision.map_or(-1, |d| d.chosen as i64)
    )
}

/// Terminal targeting (`onboard::terminal`, default settings) over the last
/// [`TERMINAL_CYCLES`] cycles of the first trace flight, from where its navigation stood: each
/// cycle's instructions, the cycles its rollouts propagated and so the instructions per
/// propagated cycle, and the settings' bound (their most propagated cycles at that cost).
#[inline(never)]
fn terminal(
    out: &mut semi::Out,
    counter: &Counter,
    controller: &FlownController<'_>,
    states: &TerminalStates,
) -> core::fmt::Result {
    use onboard::terminal::{terminal_step, TerminalSettings};

    let Some((_, target, spacecraft)) = first_flight() else {
        return writeln!(out, "{COMMENT} terminal targeting: no flight, target or spacecraft");
    };
    let settings = TerminalSettings::default();
    for (to_go, state) in (1..TERMINAL_CYCLES + 1).zip(states.iter()).rev() {
        let Some(state) = state else {
            continue;
        };
        let time_to_go = f64::from(to_go) * shared::units::STEP;
        let start = counter.now();
        let decision = terminal_step(controller, state, &target, time_to_go, &spacecraft, &settings);
        let total = u64::from(Counter::ticks(start, counter.now())) * u64::from(INSTRUCTIONS_PER_TICK);
        let cycles = decision.map_or(0, |d| d.rollout_cycles);
        let per_cycle = total / u64::from(cycles.max(1));
        let bound = settings.most_rollout_cycles::<FlownGeometry>(to_go);
        writeln!(
            out,
            "{COMMENT} instructions per terminal-targeting cycle, {to_go} cycle(s) to go: {total} ({cycles} \
             propagated cycles, {per_cycle} each; the settings' most, {bound} cycles: {})",
            u64::from(bound) * per_cycle
        )?;
    }
    Ok(())
}

/// Sorts the (at most [`MAX_SAMPLES`]) tick counts for their median: a few lines instead of
/// the several KiB of flash `sort_unstable` links in.
fn insertion_sort(v: &mut [u32]) {
    for i in 1..v.len() {
        let mut j = i;
        while j > 0 && v.get(j - 1) > v.get(j) {
            v.swap(j - 1, j);
            j -= 1;
        }
    }
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    semi::fail(format_args!("hard fault at pc {:#010x}", frame.pc()))
}

#[exception]
unsafe fn DefaultHandler(irq: i16) {
    semi::fail(format_args!("unexpected exception {irq}"))
}

/// Where it panicked, not the message: formatting any panic site's message would link core's
/// float formatting (some 20 KiB of flash) for asserts the flight code never reaches.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
    match info.location() {
        Some(at) => semi::fail(format_args!("panic at {}:{}", at.file(), at.line())),
        None => semi::fail(format_args!("panic")),
    }
}
