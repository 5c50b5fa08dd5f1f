//! The Cortex-M4F kernels in `asm!`, for what stable Rust cannot express or LLVM does not
//! generate: the int8 pair kernel's Arm DSP instructions (`sxtb16`, `smlad`; stable Rust has
//! no intrinsics for them) and the f32 tile kernel, which keeps 16 accumulators in FPU
//! registers and loads the possibly unaligned blob weights through core registers (LLVM spills
//! the accumulators and moves every weight separately: 5.15 instructions per multiply-add,
//! against 2.7 here).
//!
//! The only module of `onboard` that allows `unsafe`. Each `unsafe` block is one `asm!`
//! statement whose SAFETY comment shows every memory access in bounds: the loops read only
//! through pointers taken from slices whose lengths are checked (by `from_layer`, and again
//! here, locally, before the `asm!`), for an iteration count derived from those lengths.
//! Both kernels compute exactly what the portable kernels compute (the same integers; the
//! same f32 products and sums in the same order per output), which `scripts/qemu-sil.sh`
//! checks bit for bit against the host.

use core::arch::asm;

use super::int8::{dot1_pairs, Acts};

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
    // extension, present on every target this module is compiled for, see `ARM_ASM`): no memory
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

/// `acc + x * w` rounded once (`vfma.f32`): the portable f32 kernel's fused multiply-add on
/// this target (`libm::fmaf` would emulate it in software, through soft-float f64). The
/// operands pass through core registers, because stable Rust cannot name FPU registers as
/// `asm!` operands here (the `sreg` class needs the unstable `vfp2` target feature).
#[inline(always)]
pub(super) fn fma(x: f32, w: f32, acc: f32) -> f32 {
    let sum: u32;
    // SAFETY: `s0`-`s2` are saved on entry and restored on exit by a balanced `vpush`/`vpop`
    // (12 bytes of stack, so not `nostack`); in between three `vmov`s from core registers, one
    // `vfma.f32` (VFPv4, present on every target this module is compiled for) and one `vmov`
    // back. No other memory is touched (`nomem` does not cover the stack push; the stack is
    // restored), only the declared output register is written, and the flags are not changed.
    // FPSCR's sticky exception bits may be set, as by any f32 arithmetic; the result depends only
    // on the inputs and the rounding mode, which nothing changes (`pure`).
    unsafe {
        asm!(
            "vpush {{s0-s2}}",
            "vmov s0, {a}",
            "vmov s1, {x}",
            "vmov s2, {w}",
            "vfma.f32 s0, s1, s2",
            "vmov {a}, s0",
            "vpop {{s0-s2}}",
            a = inout(reg) acc.to_bits() => sum,
            x = in(reg) x.to_bits(),
            w = in(reg) w.to_bits(),
            options(pure, nomem, preserves_flags),
        );
    }
    f32::from_bits(sum)
}

/// Outputs of the layer [`f32_narrow3`] runs: the 3 actions.
pub(super) const NARROW_OUTPUTS: usize = 3;
/// Its partial sums: 8 per output, partial `k` of output `j` at `3 k + j` (the layout of the
/// portable kernel's `[[f32; 3]; 8]`, flattened).
const NARROW_PARTIALS: usize = 8 * NARROW_OUTPUTS;

/// The narrow f32 kernel of a 3-output layer: `part[3 k + j] += x[i] * w[i][j]` (fused, one
/// `vfma.f32`) for the inputs `i = k, k + 8, k + 16, ...` in order, `k < 8`, `j < 3`: the
/// portable narrow kernel's partial sums (`f32.rs`), which the caller then adds to the bias in
/// order. The 24 partials stay in `s0`-`s23` for all inputs; per input one `vldr` of `x[i]`, three
/// `ldr` of its (possibly unaligned) weights, two `vmov` and three `vfma`: 9 instructions for 3
/// multiply-adds, against about 15 for the single [`fma`]s through core registers.
///
/// Returns `false`, touching nothing, unless `part` has the 24 partials, `x` has a multiple
/// `n >= 8` of 8 inputs and `weights` has `12 n` bytes; the caller then runs the portable kernel.
#[inline(never)]
pub(super) fn f32_narrow3(weights: &[u8], x: &[f32], part: &mut [f32]) -> bool {
    let n = x.len();
    if part.len() != NARROW_PARTIALS
        || n < 8
        || !n.is_multiple_of(8)
        || n.checked_mul(4 * NARROW_OUTPUTS).is_none_or(|len| weights.len() < len)
    {
        return false;
    }
    // SAFETY: memory accessed, all in bounds:
    // - `part`: `vldm`/`vstm` of `s0`-`s23` read and write its 24 f32 (96 bytes, its length
    //   checked above), through a pointer from a `&mut [f32]` (word-aligned, as `vldm`/`vstm`
    //   require).
    // - `x`: the loop runs `n / 8 >= 1` times (`subs`/`bne` at the bottom); iteration `t` reads
    //   the f32 at byte offsets `0, 4, ..., 28` from `px` = byte `32 t` of the `[f32]` by `vldr`
    //   (word-aligned: an f32 slice), so bytes `0..4 n` of `x`.
    // - weights: iteration `t` reads 4 bytes by `ldr` at offsets `0, 4, ..., 92` from `pw` = byte
    //   `96 t`, so bytes `0..12 n` of `weights`, whose length was checked above. `ldr` may be
    //   unaligned on the Cortex-M4 (unless `CCR.UNALIGN_TRP` is set; it is off at reset and nothing
    //   here sets it).
    // - the stack: `vpush`/`vpop` of `s0`-`s27` (112 bytes), balanced, so `sp` is restored.
    // Registers: every core register written is a declared operand; `s0`-`s27` are saved on entry
    // and restored on exit, so no FPU register changes as the compiler sees it. The flags (`subs`)
    // are clobbered; FPSCR's rounding mode is only read, its sticky exception bits may be set, as
    // by any f32 arithmetic.
    unsafe {
        asm!(
                "vpush {{s0-s27}}",
                "vldm {acc}, {{s0-s23}}",
                "2:",
                "vldr s24, [{px}, #0]",
                "ldr {r0}, [{pw}, #0]",
                "ldr {r1}, [{pw}, #4]",
                "ldr {r2}, [{pw}, #8]",
                "vmov s25, s26, {r0}, {r1}",
                "vmov s27, {r2}",
                "vfma.f32 s0, s24, s25",
                "vfma.f32 s1, s24, s26",
                "vfma.f32 s2, s24, s27",
                "vldr s24, [{px}, #4]",
                "ldr {r0}, [{pw}, #12]",
                "ldr {r1}, [{pw}, #16]",
                "ldr {r2}, [{pw}, #20]",
                "vmov s25, s26, {r0}, {r1}",
                "vmov s27, {r2}",
                "vfma.f32 s3, s24, s25",
                "vfma.f32 s4, s24, s26",
                "vfma.f32 s5, s24, s27",
                "vldr s24, [{px}, #8]",
                "ldr {r0}, [{pw}, #24]",
                "ldr {r1}, [{pw}, #28]",
                "ldr {r2}, [{pw}, #32]",
                "vmov s25, s26, {r0}, {r1}",
                "vmov s27, {r2}",
                "vfma.f32 s6, s24, s25",
                "vfma.f32 s7, s24, s26",
                "vfma.f32 s8, s24, s27",
                "vldr s24, [{px}, #12]",
                "ldr {r0}, [{pw}, #36]",
                "ldr {r1}, [{pw}, #40]",
                "ldr {r2}, [{pw}, #44]",
                "vmov s25, s26, {r0}, {r1}",
                "vmov s27, {r2}",
                "vfma.f32 s9, s24, s25",
                "vfma.f32 s10, s24, s26",
                "vfma.f32 s11, s24, s27",
                "vldr s24, [{px}, #16]",
                "ldr {r0}, [{pw}, #48]",
                "ldr {r1}, [{pw}, #52]",
                "ldr {r2}, [{pw}, #56]",
                "vmov s25, s26, {r0}, {r1}",
                "vmov s27, {r2}",
                "vfma.f32 s12, s24, s25",
                "vfma.f32 s13, s24, s26",
                "vfma.f32 s14, s24, s27",
                "vldr s24, [{px}, #20]",
                "ldr {r0}, [{pw}, #60]",
                "ldr {r1}, [{pw}, #64]",
                "ldr {r2}, [{pw}, #68]",
                "vmov s25, s26, {r0}, {r1}",
                "vmov s27, {r2}",
                "vfma.f32 s15, s24, s25",
                "vfma.f32 s16, s24, s26",
                "vfma.f32 s17, s24, s27",
                "vldr s24, [{px}, #24]",
                "ldr {r0}, [{pw}, #72]",
                "ldr {r1}, [{pw}, #76]",
                "ldr {r2}, [{pw}, #80]",
                "vmov s25, s26, {r0}, {r1}",
                "vmov s27, {r2}",
                "vfma.f32 s18, s24, s25",
                "vfma.f32 s19, s24, s26",
                "vfma.f32 s20, s24, s27",
                "vldr s24, [{px}, #28]",
                "ldr {r0}, [{pw}, #84]",
                "ldr {r1}, [{pw}, #88]",
                "ldr {r2}, [{pw}, #92]",
                "vmov s25, s26, {r0}, {r1}",
                "vmov s27, {r2}",
                "vfma.f32 s21, s24, s25",
                "vfma.f32 s22, s24, s26",
                "vfma.f32 s23, s24, s27",
                "add {px}, {px}, #32",
                "add {pw}, {pw}, #96",
                "subs {n}, {n}, #1",
                "bne 2b",
                "vstm {acc}, {{s0-s23}}",
                "vpop {{s0-s27}}",
            acc = in(reg) part.as_mut_ptr(),
            px = inout(reg) x.as_ptr() => _,
            pw = inout(reg) weights.as_ptr() => _,
            n = inout(reg) n >> 3 => _,
            r0 = out(reg) _,
            r1 = out(reg) _,
            r2 = out(reg) _,
        );
    }
    true
}

/// Outputs per tile of [`f32_tile`]: its accumulators fill `s0`-`s15`.
pub(super) const F32_ARM_TILE: usize = 16;

/// `acc[k] += x[i] * w[i][col + k]` for `i = 0, 1, 2, ...` in order, `k < 16` (`w` the layer's
/// input-major f32 LE weights, rows of `OUT` values): per output the same fused multiply-adds
/// in the same order as the portable f32 kernel (one `vfma.f32`: rounded once). Two inputs per iteration: one `vldmia` loads both, and each of their 16 weights
/// takes an `ldr` (the blob's f32 arrays need not be word-aligned, and the Cortex-M4 allows
/// unaligned `ldr` but not unaligned `vldr`/`vldm`), half a `vmov` (two core registers to two
/// FPU registers) and a `vfma`: 85 instructions for 32 multiply-accumulates.
///
/// Returns `false`, touching nothing, unless `x` has an even number `n >= 2` of inputs, the
/// tile lies within a row of `stride` bytes (`4 * (col + 16) <= stride`) and `weights` has
/// `n * stride` bytes; the caller then runs the portable kernel. Not inlined: one copy serves
/// every layer and tile (a call per tile of 16 outputs costs a few instructions; inlined
/// into the loop over tiles it added 18 KB to the image's flash).
#[inline(never)]
pub(super) fn f32_tile(weights: &[u8], stride: usize, col: usize, x: &[f32], acc: &mut [f32; F32_ARM_TILE]) -> bool {
    let n = x.len();
    let fits = col
        .checked_add(F32_ARM_TILE)
        .and_then(|end| end.checked_mul(4))
        .is_some_and(|end| end <= stride);
    if n < 2 || !n.is_multiple_of(2) || !fits || n.checked_mul(stride).is_none_or(|len| weights.len() < len) {
        return false;
    }
    let Some(tile) = weights.get(4 * col..) else {
        return false;
    };
    // SAFETY: memory accessed, all in bounds:
    // - `acc`: `vldm`/`vstm` of `s0`-`s15` read and write its 16 f32 (64 bytes), through a
    //   pointer from a `&mut [f32; 16]` (word-aligned, as `vldm`/`vstm` require).
    // - `x`: the loop runs `n / 2 >= 1` times (`subs`/`bne` at the bottom); each `vldmia` reads
    //   two f32 at `px` and advances it by 8 bytes: bytes `0..4 n` of the `[f32]` (word-aligned).
    // - weights: in iteration `t`, `pw` is at byte `2 t * stride` of `tile` and `pv` at
    //   `(2 t + 1) * stride`, and each `ldr` reads 4 bytes at offset 0..=60 from them: bytes
    //   `4 col + i * stride + 4 k .. + 4` of `weights` for input `i < n` and `k < 16`, whose
    //   end `4 (col + 16) + (n - 1) * stride <= n * stride <= weights.len()` (both checked
    //   above). `ldr` may be unaligned on the Cortex-M4 (unless the
    //   `CCR.UNALIGN_TRP` trap is enabled; it is off at reset and nothing here enables it).
    // - the stack: `vpush`/`vpop` of `s0`-`s19` (80 bytes), balanced, so `sp` is restored.
    // Registers: every core register written is a declared operand; `s0`-`s19` are saved on
    // entry and restored on exit, so no FPU register changes as the compiler sees it (Rust
    // cannot name FPU registers as `asm!` operands on stable for this target). The flags
    // (`subs`) are clobbered; FPSCR's rounding mode is only read, its sticky exception bits
    // may be set, as by any f32 arithmetic.
    unsafe {
        asm!(
                "vpush {{s0-s19}}",
                "vldm {acc}, {{s0-s15}}",
                "2:",
                "vldmia {px}!, {{s16, s17}}",
                "ldr {r0}, [{pw}]",
                "ldr {r1}, [{pw}, #4]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s0, s16, s18",
                "vfma.f32 s1, s16, s19",
                "ldr {r0}, [{pw}, #8]",
                "ldr {r1}, [{pw}, #12]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s2, s16, s18",
                "vfma.f32 s3, s16, s19",
                "ldr {r0}, [{pw}, #16]",
                "ldr {r1}, [{pw}, #20]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s4, s16, s18",
                "vfma.f32 s5, s16, s19",
                "ldr {r0}, [{pw}, #24]",
                "ldr {r1}, [{pw}, #28]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s6, s16, s18",
                "vfma.f32 s7, s16, s19",
                "ldr {r0}, [{pw}, #32]",
                "ldr {r1}, [{pw}, #36]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s8, s16, s18",
                "vfma.f32 s9, s16, s19",
                "ldr {r0}, [{pw}, #40]",
                "ldr {r1}, [{pw}, #44]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s10, s16, s18",
                "vfma.f32 s11, s16, s19",
                "ldr {r0}, [{pw}, #48]",
                "ldr {r1}, [{pw}, #52]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s12, s16, s18",
                "vfma.f32 s13, s16, s19",
                "ldr {r0}, [{pw}, #56]",
                "ldr {r1}, [{pw}, #60]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s14, s16, s18",
                "vfma.f32 s15, s16, s19",
                "ldr {r0}, [{pv}]",
                "ldr {r1}, [{pv}, #4]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s0, s17, s18",
                "vfma.f32 s1, s17, s19",
                "ldr {r0}, [{pv}, #8]",
                "ldr {r1}, [{pv}, #12]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s2, s17, s18",
                "vfma.f32 s3, s17, s19",
                "ldr {r0}, [{pv}, #16]",
                "ldr {r1}, [{pv}, #20]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s4, s17, s18",
                "vfma.f32 s5, s17, s19",
                "ldr {r0}, [{pv}, #24]",
                "ldr {r1}, [{pv}, #28]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s6, s17, s18",
                "vfma.f32 s7, s17, s19",
                "ldr {r0}, [{pv}, #32]",
                "ldr {r1}, [{pv}, #36]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s8, s17, s18",
                "vfma.f32 s9, s17, s19",
                "ldr {r0}, [{pv}, #40]",
                "ldr {r1}, [{pv}, #44]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s10, s17, s18",
                "vfma.f32 s11, s17, s19",
                "ldr {r0}, [{pv}, #48]",
                "ldr {r1}, [{pv}, #52]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s12, s17, s18",
                "vfma.f32 s13, s17, s19",
                "ldr {r0}, [{pv}, #56]",
                "ldr {r1}, [{pv}, #60]",
                "vmov s18, s19, {r0}, {r1}",
                "vfma.f32 s14, s17, s18",
                "vfma.f32 s15, s17, s19",
                "add {pw}, {pw}, {step}",
                "add {pv}, {pv}, {step}",
                "subs {n}, {n}, #1",
                "bne 2b",
                "vstm {acc}, {{s0-s15}}",
                "vpop {{s0-s19}}",
            acc = in(reg) acc.as_mut_ptr(),
            px = inout(reg) x.as_ptr() => _,
            pw = inout(reg) tile.as_ptr() => _,
            pv = inout(reg) tile.as_ptr().wrapping_add(stride) => _,
            step = in(reg) 2 * stride,
            n = inout(reg) n >> 1 => _,
            r0 = out(reg) _,
            r1 = out(reg) _,
        );
    }
    true
}
