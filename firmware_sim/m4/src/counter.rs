//! Instruction counting on QEMU, from the SysTick.
//!
//! QEMU runs with `-icount shift=0`: virtual time advances exactly 1 ns per guest instruction
//! executed (instructions skipped by an IT block included), and timer registers read by MMIO see
//! the instruction count at that exact instruction. The SysTick, clocked by the CPU clock of
//! mps2-an386 (25 MHz in QEMU, 40 ns per tick), therefore counts one tick per
//! [`INSTRUCTIONS_PER_TICK`] instructions: one measurement resolves 40 instructions, a mean over
//! K back-to-back repetitions 40 / K. [`calibrate`] checks the ratio on a loop of known length.

use core::cell::Cell;
use core::hint::black_box;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use onboard::guidance::Actor;

/// The SysTick's 24-bit reload: the longest period, 2^24 ticks (671 M instructions).
const RELOAD: u32 = 0x00FF_FFFF;
/// 1 GHz of virtual time (one instruction per ns) over the 25 MHz SysTick clock.
pub const INSTRUCTIONS_PER_TICK: u32 = 40;

/// The free-running SysTick (no interrupt), counting down.
pub struct Counter {
    _syst: SYST,
}

impl Counter {
    pub fn start(mut syst: SYST) -> Self {
        syst.disable_interrupt();
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(RELOAD);
        syst.clear_current();
        syst.enable_counter();
        Self { _syst: syst }
    }

    #[inline(always)]
    pub fn now(&self) -> u32 {
        SYST::get_current()
    }

    /// Ticks from `start` to `end` (one wrap at most: intervals below 2^24 ticks).
    #[inline(always)]
    pub fn ticks(start: u32, end: u32) -> u32 {
        start.wrapping_sub(end) & RELOAD
    }
}

/// `2 * n` instructions exactly: `subs` + `bne` per iteration (the last `bne` falls through).
#[inline(always)]
fn counted_loop(n: u32) {
    // SAFETY: register-only arithmetic on a scratch register; no memory, no stack.
    unsafe {
        core::arch::asm!(
            "2:",
            "subs {0}, {0}, #1",
            "bne 2b",
            inout(reg) n => _,
            options(nomem, nostack),
        );
    }
}

/// Ticks of an empty measurement and of [`counted_loop`] of `2 * n` instructions.
pub fn calibrate(counter: &Counter, n: u32) -> (u32, u32) {
    let t0 = counter.now();
    let t1 = counter.now();
    let empty = Counter::ticks(t0, t1);
    let t0 = counter.now();
    counted_loop(n);
    let t1 = counter.now();
    (empty, Counter::ticks(t0, t1))
}

/// Most inferences recorded (the flight's guidance cycles).
pub const MAX_SAMPLES: usize = 128;

/// An actor on `N` features that counts the ticks of every inference of the actor it wraps.
pub struct Counted<'a, A, const N: usize> {
    inner: &'a A,
    counter: &'a Counter,
    samples: [Cell<u32>; MAX_SAMPLES],
    count: Cell<usize>,
    first_input: Cell<Option<[f32; N]>>,
}

impl<'a, A, const N: usize> Counted<'a, A, N> {
    pub fn new(inner: &'a A, counter: &'a Counter) -> Self {
        Self {
            inner,
            counter,
            samples: [const { Cell::new(0) }; MAX_SAMPLES],
            count: Cell::new(0),
            first_input: Cell::new(None),
        }
    }

    /// Ticks of the recorded inferences, in order (the first [`MAX_SAMPLES`]).
    pub fn samples(&self, out: &mut [u32; MAX_SAMPLES]) -> usize {
        let n = self.count.get().min(MAX_SAMPLES);
        for (o, s) in out.iter_mut().zip(self.samples.iter()).take(n) {
            *o = s.get();
        }
        n
    }

    /// The features of the first inference (what the repeated benchmark runs on).
    pub fn first_input(&self) -> Option<[f32; N]> {
        self.first_input.get()
    }
}

/// One inference between two SysTick reads. `black_box` on both sides keeps the work between
/// the reads: LLVM may move pure arithmetic across a volatile read, not across an opaque call.
#[inline(always)]
fn timed<const N: usize, const OUT: usize, A: Actor<N, OUT>>(
    inner: &A,
    counter: &Counter,
    x: &[f32; N],
) -> ([f32; OUT], u32) {
    let t0 = counter.now();
    let x = black_box(x);
    let y = black_box(inner.act(x));
    let t1 = counter.now();
    (y, Counter::ticks(t0, t1))
}

impl<const N: usize, const OUT: usize, A: Actor<N, OUT>> Actor<N, OUT> for Counted<'_, A, N> {
    fn act(&self, x: &[f32; N]) -> [f32; OUT] {
        let (y, ticks) = timed(self.inner, self.counter, x);
        let n = self.count.get();
        if let Some(slot) = self.samples.get(n) {
            slot.set(ticks);
        }
        if n == 0 {
            self.first_input.set(Some(*x));
        }
        self.count.set(n.saturating_add(1));
        y
    }
}

/// Ticks of `reps` back-to-back inferences on `x` (the sub-tick resolution of the mean).
pub fn repeated<const N: usize, const OUT: usize, A: Actor<N, OUT>>(
    inner: &A,
    counter: &Counter,
    x: &[f32; N],
    reps: u32,
) -> u32 {
    let t0 = counter.now();
    for _ in 0..reps {
        black_box(inner.act(black_box(x)));
    }
    let t1 = counter.now();
    Counter::ticks(t0, t1)
}
