//! Interim image: blob load, instruction-count calibration and a repeated inference.
#![no_std]
#![no_main]

mod counter;
mod semi;
mod stack;

use core::fmt::Write;

use cortex_m_rt::{entry, exception, ExceptionFrame};
use onboard::guidance::Actor;
use onboard::policy::TransferPolicy;
use shared::blob::ProblemKind;

use counter::{Counter, INSTRUCTIONS_PER_TICK};

#[repr(C, align(64))]
struct Aligned<B: ?Sized>(B);

static BLOB: &Aligned<[u8]> = &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/policy.blob")));

#[entry]
fn main() -> ! {
    stack::paint();
    let mut out = semi::Out::new();
    let Some(p) = cortex_m::Peripherals::take() else {
        semi::fail(format_args!("core peripherals already taken"))
    };
    let counter = Counter::start(p.SYST);
    let (empty, looped) = counter::calibrate(&counter, 1_000_000);
    let _ = writeln!(
        out,
        "# calibration empty {empty} ticks, 2000000 instructions {looped} ticks"
    );
    let policy = match TransferPolicy::from_bytes(&BLOB.0, ProblemKind::Transfer) {
        Ok(p) => p,
        Err(e) => semi::fail(format_args!("refused: {e}")),
    };
    let x = [1.0f32, 1.0, 0.0, 0.0, 1.0, 1.0, 1.5, 0.0, 0.8, 10.0];
    let reps = 64;
    let t = counter::repeated(&policy, &counter, &x, reps);
    let y = policy.act(&x);
    let _ = writeln!(
        out,
        "# inference {} instructions ({reps} reps {t} ticks) y {:?}",
        u64::from(t) * u64::from(INSTRUCTIONS_PER_TICK) / u64::from(reps),
        y
    );
    let _ = writeln!(
        out,
        "# stack reserved {} peak {}",
        stack::reserved(),
        stack::high_water()
    );
    semi::exit(true)
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    semi::fail(format_args!("hard fault at pc {:#010x}", frame.pc()))
}

#[exception]
unsafe fn DefaultHandler(irq: i16) {
    semi::fail(format_args!("unexpected exception {irq}"))
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
    semi::fail(format_args!("panic: {info}"))
}
