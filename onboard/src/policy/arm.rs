//! The pair kernel's step in Arm DSP instructions (`sxtb16`, `smlad`), which stable Rust has
//! no intrinsics for. Register-only `asm!`: the weights and activations are loaded by safe
//! Rust from bounds-checked slices, so no `unsafe` block here reads or writes memory.

use core::arch::asm;

use super::{dot1_pairs, Acts};

/// `acc + w0 * lo(xe) + w2 * hi(xe) + w1 * lo(xo) + w3 * hi(xo)` (wrapping), `w0..w3` the
/// signed bytes of `w` (little endian), `lo`/`hi` the signed halves of a word; the portable
/// `pair_mac` in the parent module emulates exactly these four instructions.
///
/// `sxtb16 t, w` sign-extends bytes 0 and 2 of `w` to the halves of `t`; `ror #8` first takes
/// bytes 1 and 3. `smlad a, t, x, a` adds both 16 x 16 products of the halves to `a`, modulo
/// 2^32 (it sets the sticky Q flag on a signed overflow, which nothing reads).
#[inline(always)]
pub(super) fn pair_mac(acc: i32, w: u32, xe: u32, xo: u32) -> i32 {
    let sum: i32;
    // SAFETY: four register-to-register data-processing instructions of ARMv7E-M (the DSP
    // extension, present on every target this module is compiled for, see `DSP`): no memory
    // access (`nomem`), no stack use (`nostack`), only the named registers are written (the
    // scratch `t` is a declared output). They change only the Q flag, so `preserves_flags` is
    // not claimed. The result depends only on the inputs (`pure`).
    unsafe {
        asm!(
            "sxtb16 {t}, {w}",
            "smlad {a}, {t}, {xe}, {a}",
            "sxtb16 {t}, {w}, ror #8",
            "smlad {a}, {t}, {xo}, {a}",
            a = inout(reg) acc => sum,
            w = in(reg) w,
            xe = in(reg) xe,
            xo = in(reg) xo,
            t = out(reg) _,
            options(pure, nomem, nostack),
        );
    }
    sum
}

/// Four rows (`block`: at least `4 * IN` bytes, row `k` at byte `k * IN`) against the
/// activations `xp` in pair order: the pair kernel's inner loop, 8 inputs of 4 rows (32
/// multiply-accumulates) in 44 instructions. Per group of 4 inputs one `ldrd` loads the two
/// activation words `(x0, x2)`, `(x1, x3)`, and per row one `ldr` loads the 4 weights (any
/// alignment: the Cortex-M4 allows unaligned `ldr`), then [`pair_mac`]'s four instructions.
/// Whole groups the loop leaves (at most one) and the last `IN % 4` inputs run in Rust.
#[inline(always)]
pub(super) fn dot4_pairs<const IN: usize>(xp: &Acts<IN>, block: &[u8]) -> [i32; 4] {
    // The row offsets are `ldr` immediates (12 bits): true for every int8 layer
    // (`MAX_INT8_INPUTS` = 512), checked at compile time for each instantiated width.
    const { assert!(3 * IN <= 4095, "int8 layer too wide for the pair kernel's offsets") };
    let Some(block) = block.get(..4 * IN) else {
        // Unreachable: `accumulate_paired` passes `chunks_exact(4 * IN)` blocks.
        return [0; 4];
    };
    // Loop iterations, 8 inputs (two groups of 4) each: `IN / 8`.
    let iterations = IN >> 3;
    let [mut a0, mut a1, mut a2, mut a3] = [0i32; 4];
    if iterations > 0 {
        // SAFETY: the loop runs `iterations >= 1` times (`subs`/`bne` at the bottom) and reads
        // only through `px` and `pw`:
        // - `px` starts at `xp.0`, an `[i16; IN]` (`2 * IN` bytes) aligned to 8 (`Acts` is
        //   `repr(align(8))`), and each `ldrd` reads 8 bytes at `px` and advances it by 8, two
        //   per iteration: bytes `0..16 * iterations <= 2 * IN` of `xp.0`, each load at a
        //   multiple of 8 from the start, so word-aligned as `ldrd` requires.
        // - `pw` starts at `block`, checked above to have `4 * IN` bytes; each half-iteration
        //   reads 4 bytes at `pw + k * IN` for rows `k = 1, 2, 3` and at `pw` for row 0 (the
        //   post-indexed load then advances `pw` by 4). After `h` half-iterations `pw` is at
        //   `4 * h`, and `4 * h + 4 <= 8 * iterations <= IN`, so row `k` reads bytes
        //   `k * IN .. k * IN + 8 * iterations`, within row `k`'s `IN` bytes of `block`.
        // Nothing is written to memory (`readonly`), the stack is untouched (`nostack`), and
        // every register written is a declared output; the flags are clobbered (`subs`, Q).
        unsafe {
            asm!(
                "2:",
                "ldrd {xe}, {xo}, [{px}], #8",
                "ldr {w}, [{pw}, #{r1}]",
                "sxtb16 {t}, {w}",
                "smlad {a1}, {t}, {xe}, {a1}",
                "sxtb16 {t}, {w}, ror #8",
                "smlad {a1}, {t}, {xo}, {a1}",
                "ldr {w}, [{pw}, #{r2}]",
                "sxtb16 {t}, {w}",
                "smlad {a2}, {t}, {xe}, {a2}",
                "sxtb16 {t}, {w}, ror #8",
                "smlad {a2}, {t}, {xo}, {a2}",
                "ldr {w}, [{pw}, #{r3}]",
                "sxtb16 {t}, {w}",
                "smlad {a3}, {t}, {xe}, {a3}",
                "sxtb16 {t}, {w}, ror #8",
                "smlad {a3}, {t}, {xo}, {a3}",
                "ldr {w}, [{pw}], #4",
                "sxtb16 {t}, {w}",
                "smlad {a0}, {t}, {xe}, {a0}",
                "sxtb16 {t}, {w}, ror #8",
                "smlad {a0}, {t}, {xo}, {a0}",
                "ldrd {xe}, {xo}, [{px}], #8",
                "ldr {w}, [{pw}, #{r1}]",
                "sxtb16 {t}, {w}",
                "smlad {a1}, {t}, {xe}, {a1}",
                "sxtb16 {t}, {w}, ror #8",
                "smlad {a1}, {t}, {xo}, {a1}",
                "ldr {w}, [{pw}, #{r2}]",
                "sxtb16 {t}, {w}",
                "smlad {a2}, {t}, {xe}, {a2}",
                "sxtb16 {t}, {w}, ror #8",
                "smlad {a2}, {t}, {xo}, {a2}",
                "ldr {w}, [{pw}, #{r3}]",
                "sxtb16 {t}, {w}",
                "smlad {a3}, {t}, {xe}, {a3}",
                "sxtb16 {t}, {w}, ror #8",
                "smlad {a3}, {t}, {xo}, {a3}",
                "ldr {w}, [{pw}], #4",
                "sxtb16 {t}, {w}",
                "smlad {a0}, {t}, {xe}, {a0}",
                "sxtb16 {t}, {w}, ror #8",
                "smlad {a0}, {t}, {xo}, {a0}",
                "subs {n}, {n}, #1",
                "bne 2b",
                px = inout(reg) xp.0.as_ptr() => _,
                pw = inout(reg) block.as_ptr() => _,
                n = inout(reg) iterations => _,
                a0 = inout(reg) a0,
                a1 = inout(reg) a1,
                a2 = inout(reg) a2,
                a3 = inout(reg) a3,
                xe = out(reg) _,
                xo = out(reg) _,
                w = out(reg) _,
                t = out(reg) _,
                r1 = const IN,
                r2 = const 2 * IN,
                r3 = const 3 * IN,
                options(pure, readonly, nostack),
            );
        }
    }
    // The group the loop leaves when `IN / 4` is odd, then the last `IN % 4` inputs.
    let done = 8 * iterations;
    let mut s = [a0, a1, a2, a3];
    let rows = block.chunks_exact(IN);
    let (Some(x_rest), true) = (xp.0.get(done..), done <= IN) else {
        return s;
    };
    for (sk, row) in s.iter_mut().zip(rows) {
        if let Some(w_rest) = row.get(done..) {
            *sk = sk.wrapping_add(dot1_pairs(x_rest, w_rest));
        }
    }
    s
}
