//! Stack high-water mark by painting: at boot the free RAM between the end of the statics and
//! the stack pointer is filled with a pattern; after the flight the lowest overwritten word
//! gives the deepest stack reached. The stack is what the 64 KiB RAM region (memory.x) leaves
//! above `.data` and `.bss`; cortex-m-rt starts it at the top of RAM.

const PAINT: u32 = 0xDEAD_BEEF;
/// Left unpainted below the live stack pointer while painting (the painter's own frame).
const GUARD: usize = 64;

extern "C" {
    /// End of `.bss`/`.uninit` (cortex-m-rt's link.x): the lowest address the stack may reach.
    static _stack_end: u32;
    /// Initial stack pointer: the top of RAM.
    static _stack_start: u32;
}

fn bounds() -> (usize, usize) {
    // Only the addresses of the linker symbols are taken, never their contents.
    (
        core::ptr::addr_of!(_stack_end) as usize,
        core::ptr::addr_of!(_stack_start) as usize,
    )
}

/// Bytes of RAM the stack may use.
pub fn reserved() -> usize {
    let (low, top) = bounds();
    top - low
}

/// Paints `[_stack_end, sp - GUARD)`. Called first thing in `main`, with no interrupts enabled.
#[inline(never)]
pub fn paint() {
    let (low, _) = bounds();
    let sp = cortex_m::register::msp::read() as usize;
    let mut p = low;
    while p + 4 <= sp.saturating_sub(GUARD) {
        // SAFETY: word-aligned RAM below the live stack pointer and above every static: no live
        // object is there (no heap, no interrupts), so the write clobbers nothing.
        unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
}

/// Deepest stack use since [`paint`], in bytes from the top of RAM.
pub fn high_water() -> usize {
    let (low, top) = bounds();
    let mut p = low;
    // SAFETY: reads of word-aligned RAM between the statics and the top of the stack.
    while p < top && unsafe { core::ptr::read_volatile(p as *const u32) } == PAINT {
        p += 4;
    }
    top - p
}
