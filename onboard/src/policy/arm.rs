//! The Cortex-M4F kernels in `asm!`, for what stable Rust cannot express or LLVM does not
//! generate: the int8 pair kernel's Arm DSP instructions (`smlad`, `sxtb16`; stable Rust has
//! no intrinsics for them) with multi-word loads (`ldm`, `ldrd`), and the f32 layer kernels,
//! which keep their accumulators in FPU registers and load 8 inputs or 16 weights at a time
//! (`vldm`; LLVM spills the accumulators and moves every weight separately: 5.15 instructions
//! per multiply-add, against 1.08 here). Both multi-word loads need word-aligned weights, which
//! the blob format provides for a blob stored word-aligned; otherwise they decline and the
//! portable loops run.
//!
//! The only module of `onboard` that allows `unsafe` besides `policy::x86`. Each `unsafe` block
//! is one `asm!` statement whose SAFETY comment shows every memory access in bounds (the loops
//! read only through pointers taken from slices whose lengths and alignment are checked, by
//! `from_layer` and again here, locally, before the `asm!`, for an iteration count derived
//! from those lengths), or a view of an array as possibly uninitialized and back once a kernel
//! has written all of it. Both kernels compute exactly what the portable kernels compute (the same
//! integers; the same f32 products and sums in the same order per output), which
//! `scripts/qemu-sil.sh` checks bit for bit against the host.

use core::arch::asm;
use core::mem::MaybeUninit;

use super::int8::{dot1_pair_words, Acts};

/// `(raw + lo(w) lo(x) + hi(w) hi(x), high + (lo(w) >> 8) lo(x) + (hi(w) >> 8) hi(x))`
/// (wrapping), `lo`/`hi` the signed halves of a word: a word of a row pair (two inputs, each
/// an i16 `256 b + a + 128`) against the word of the two activations. The portable `pair_mac`
/// in the parent module emulates exactly these three instructions.
///
/// `smlad r, w, x, r` adds both 16 x 16 products of the halves to `r`, modulo 2^32 (it sets the
/// sticky Q flag on a signed overflow, which nothing reads); `sxtb16 t, w, ror #8`
/// sign-extends bytes 1 and 3 of `w` to the halves of `t`: each half's high byte, which is
/// the half shifted right by 8 since its low byte is `a + 128` in `0..=255`.
#[inline(always)]
pub(super) fn pair_mac(raw: i32, high: i32, w: u32, x: u32) -> (i32, i32) {
    let (r, h): (i32, i32);
    // SAFETY: three register-to-register data-processing instructions of ARMv7E-M (the DSP
    // extension, present on every target this module is compiled for, see `ARM_ASM`): no memory
    // access (`nomem`), no stack use (`nostack`), only the named registers are written (the
    // scratch `t` is a declared output). They change only the Q flag, so `preserves_flags` is
    // not claimed. The result depends only on the inputs (`pure`).
    unsafe {
        asm!(
            "smlad {r}, {w}, {x}, {r}",
            "sxtb16 {t}, {w}, ror #8",
            "smlad {h}, {t}, {x}, {h}",
            r = inout(reg) raw => r,
            h = inout(reg) high => h,
            w = in(reg) w,
            x = in(reg) x,
            t = out(reg) _,
            options(pure, nomem, nostack),
        );
    }
    (r, h)
}

/// Inputs per repetition of [`dot2_pairs`]' unrolled block (`1 << PAIR_BLOCK_SHIFT`): four
/// activation words.
const PAIR_BLOCK_SHIFT: u32 = 3;
const PAIR_BLOCK_INPUTS: usize = 1 << PAIR_BLOCK_SHIFT;

/// Whether [`pair_block`]'s `ldrd` offsets to pair 1 (`2 IN` and `2 IN + 8`) fit the
/// instruction's immediate (at most 1020) for `inputs` inputs.
const fn pair_offsets_fit(inputs: usize) -> bool {
    2 * inputs + 8 <= 1020
}

/// One repetition of the pair kernel ([`dot2_pairs`], [`int8_relu_layer_fresh`]): 8 inputs
/// against two row pairs, 28 instructions for 32 multiply-adds. Registers: `r0` the activations
/// and `r1` pair 0's weights (both advanced by 16 bytes), pair 1's words at `[r1, #off0]` and
/// `[r1, #off1]` (`2 IN`, `2 IN + 8`), `r2`-`r5` the activation words, `r6`, `r7`, `r9`, `lr`
/// the weight words, `r8`/`r12` pair 0's raw and high sums, `r10`/`r11` pair 1's.
macro_rules! pair_block {
    () => {
        concat!(
            "ldmia r0!, {{r2, r3, r4, r5}}\n",
            "ldrd r6, r7, [r1, #{off0}]\n",
            "smlad r10, r6, r2, r10\n",
            "sxtb16 r6, r6, ror #8\n",
            "smlad r11, r6, r2, r11\n",
            "smlad r10, r7, r3, r10\n",
            "sxtb16 r7, r7, ror #8\n",
            "smlad r11, r7, r3, r11\n",
            "ldrd r6, r7, [r1, #{off1}]\n",
            "smlad r10, r6, r4, r10\n",
            "sxtb16 r6, r6, ror #8\n",
            "smlad r11, r6, r4, r11\n",
            "smlad r10, r7, r5, r10\n",
            "sxtb16 r7, r7, ror #8\n",
            "smlad r11, r7, r5, r11\n",
            "ldmia r1!, {{r6, r7, r9, lr}}\n",
            "smlad r8, r6, r2, r8\n",
            "sxtb16 r6, r6, ror #8\n",
            "smlad r12, r6, r2, r12\n",
            "smlad r8, r7, r3, r8\n",
            "sxtb16 r7, r7, ror #8\n",
            "smlad r12, r7, r3, r12\n",
            "smlad r8, r9, r4, r8\n",
            "sxtb16 r9, r9, ror #8\n",
            "smlad r12, r9, r4, r12\n",
            "smlad r8, lr, r5, r8\n",
            "sxtb16 lr, lr, ror #8\n",
            "smlad r12, lr, r5, r12\n",
        )
    };
}

/// Two row pairs (`block`: at least `4 * IN` bytes, pair 1 at byte `2 * IN`) against the
/// activations: `[raw0, high0, raw1, high1]`, the raw and high sums of each pair ([`pair_mac`]).
///
/// Per 8 inputs one `ldmia` loads the 4 activation words; two `ldrd` (at the fixed offset
/// `2 * IN`) load pair 1's 4 words and one `ldmia` pair 0's, each word followed by
/// [`pair_mac`]'s 3 instructions (the `sxtb16` overwrites the word it came from): 28
/// instructions for 32 multiply-adds. The block repeats `IN / 8` times (`.rept`), with no loop
/// counter: the 14 allocatable core registers hold the two pointers, the 4 activation words,
/// the 4 weight words and the 4 sums.
///
/// `ldm`/`ldrd` need word-aligned addresses: the blob format aligns the weight arrays and
/// `2 * IN` bytes keep pair 1 aligned; `Acts` is 8-aligned. An unaligned block, a width whose
/// offset does not fit `ldrd`'s immediate (`2 IN + 8 <= 1020`) and the last `IN % 8` inputs
/// take [`dot1_pair_words`] (the same integers).
#[inline(always)]
pub(super) fn dot2_pairs<const IN: usize>(x: &Acts<IN>, block: &[u8]) -> [i32; 4] {
    let Some(block) = block.get(..4 * IN) else {
        // Unreachable: `map_paired` passes `chunks_exact(4 * IN)` blocks.
        return [0; 4];
    };
    let fits = IN.is_multiple_of(2) && pair_offsets_fit(IN) && (block.as_ptr() as usize).is_multiple_of(4);
    let blocks = if fits { IN >> PAIR_BLOCK_SHIFT } else { 0 };
    let [mut raw0, mut high0, mut raw1, mut high1] = [0i32; 4];
    if blocks > 0 {
        // SAFETY: the block below repeats `IN / 8 = blocks >= 1` times and reads only through
        // `r0` and `r1`:
        // - `r0` starts at `x.q`, an `[i16; IN]` (`2 * IN` bytes) at the start of the 8-aligned
        //   `Acts`; each repetition's `ldmia` reads 16 bytes and advances it by 16: bytes
        //   `0..16 * blocks <= 2 * IN` of `x.q`, word-aligned.
        // - `r1` starts at `block`, word-aligned and of `4 * IN` bytes (both checked above). In
        //   repetition `h` (from 0) it is at `16 h`: the two `ldrd` read bytes `2 IN + 16 h ..
        //   2 IN + 16 h + 16` (pair 1's words for inputs `8 h .. 8 h + 8`) and the `ldmia` bytes
        //   `16 h .. 16 h + 16` (pair 0's), then advances `r1` by 16. With `16 blocks <= 2 IN`
        //   every read lies in `block`'s `4 * IN` bytes; every address is word-aligned (`block`
        //   is, and `IN` is even, so `2 IN` is a multiple of 4: both checked above) and the
        //   offsets `2 IN`, `2 IN + 8 <= 1020` fit `ldrd`'s immediate (checked above).
        // - the stack: `push`/`pop` of `r6`, `r7` (8 bytes), balanced, so `sp` is restored. The two
        //   registers, which Rust cannot name as operands (LLVM may keep its base and frame
        //   pointers there), hold weight words inside the block and get their values back
        //   before it ends; every operand is pinned to another register, so none is in them.
        // Nothing else is written to memory, and every other register written is a declared
        // output; the flags are clobbered (Q).
        unsafe {
            asm!(
                "push {{r6, r7}}",
                ".rept {reps}",
                pair_block!(),
                ".endr",
                "pop {{r6, r7}}",
                // Every other allocatable core register, named (`asm!` cannot name pinned
                // operands in the template), so none lands in r6 or r7: r0 the activations,
                // r1 pair 0's weights, r2-r5 the activation words, r6, r7, r9, lr the weight
                // words, r8, r12 pair 0's raw and high sums, r10, r11 pair 1's.
                inout("r0") x.q.as_ptr() => _,
                inout("r1") block.as_ptr() => _,
                out("r2") _,
                out("r3") _,
                out("r4") _,
                out("r5") _,
                inout("r8") raw0,
                out("r9") _,
                inout("r10") raw1,
                inout("r11") high1,
                inout("r12") high0,
                out("lr") _,
                reps = const IN >> PAIR_BLOCK_SHIFT,
                off0 = const 2 * IN,
                off1 = const 2 * IN + 8,
                options(pure, readonly),
            );
        }
    }
    // The inputs the block leaves (all of them for a block it declines).
    let done = PAIR_BLOCK_INPUTS * blocks;
    if done == IN {
        return [raw0, high0, raw1, high1];
    }
    let (p0, p1) = block.split_at(2 * IN);
    // `block` is `4 * IN` bytes: `p1` is pair 1's `2 * IN`.
    let (Some(x_rest), Some(w0), Some(w1)) = (x.q.get(done..), p0.get(2 * done..), p1.get(2 * done..)) else {
        return [raw0, high0, raw1, high1];
    };
    let (r0, h0) = dot1_pair_words(x_rest, w0);
    let (r1, h1) = dot1_pair_words(x_rest, w1);
    [
        raw0.wrapping_add(r0),
        high0.wrapping_add(h0),
        raw1.wrapping_add(r1),
        high1.wrapping_add(h1),
    ]
}

/// Rows per group of [`int8_relu_layer_fresh`]: two row pairs.
const INT8_GROUP_ROWS: usize = 4;

/// The int8 hidden layer with its ReLU, whole, into an array not initialized yet: for every
/// row `j`, `relu((acc[j] + bias[j]) as f32 * (input_scale * ws[j]))`, `acc[j]` the row's exact
/// dot product and the bias added saturating (`qadd`), the products rounded as f32 (`vmul`)
/// and the ReLU the portable `relu_to` (`vcmp` with 0, `vmrs`, `vmovmi` from a zero: NaN and
/// `-0.0` kept): what `DenseInt8::map_paired` computes with the same closure, bit for bit.
///
/// One `asm!` block runs the whole layer. Per group of 4 rows (two row pairs of `block`s of
/// `4 IN` bytes, as [`dot2_pairs`] reads them): the loop state (bias, scale and output pointers,
/// groups left) pushed, the 4 sums cleared, [`pair_block`] `IN / 8` times, the state popped;
/// then the activations' sum read where the pointer stopped (`Acts::sum` follows the levels),
/// both pairs unpaired (`raw - 256 high - 128 sum`, wrapping), the biases by unaligned `ldr`
/// (the arrays follow postcard length prefixes), the 4 outputs converted, scaled, ReLU'd in
/// `s0`-`s3` and stored by one `vstmia`: 61 instructions a group around its kernel, against
/// about 95 when each group was a call from Rust (and about 330 once a layer to zero the array).
///
/// Returns `Ok` with the array written whole, or `Err` with it untouched unless: `IN` is a
/// multiple of 8 with `2 IN + 8 <= 1020` (`ldrd`'s offset), `OUT` a multiple of 4, `weights`
/// word-aligned with the `OUT IN` bytes of the groups, `bias` and `scales` the `4 OUT` bytes of
/// their i32 and f32; the caller then runs the portable kernels.
#[inline(never)]
pub(super) fn int8_relu_layer_fresh<'y, const IN: usize, const OUT: usize>(
    x: &Acts<IN>,
    weights: &[u8],
    bias: &[u8],
    scales: &[u8],
    input_scale: f32,
    y: &'y mut MaybeUninit<[f32; OUT]>,
) -> Result<&'y mut [f32; OUT], &'y mut MaybeUninit<[f32; OUT]>> {
    let groups = OUT >> INT8_GROUP_ROWS.trailing_zeros();
    let fits = IN >= PAIR_BLOCK_INPUTS
        && IN.is_multiple_of(PAIR_BLOCK_INPUTS)
        && pair_offsets_fit(IN)
        && groups > 0
        && OUT.is_multiple_of(INT8_GROUP_ROWS)
        && weights.len() >= OUT * IN
        && (weights.as_ptr() as usize).is_multiple_of(4)
        && bias.len() >= 4 * OUT
        && scales.len() >= 4 * OUT;
    if !fits {
        return Err(y);
    }
    // SAFETY: memory accessed, all in bounds:
    // - `x`: the 8-aligned `Acts<IN>`, `IN` even, so its `sum` (i32) is at byte `2 IN`. Each
    //   group starts `r0` at `x.q`; the `IN / 8` repetitions' `ldmia` read 16 bytes each,
    //   leaving `r0` at `x.q + 2 IN`: bytes `0..2 IN` of the levels, word-aligned. The `ldr` of
    //   the sum reads bytes `2 IN..2 IN + 4`, inside `Acts`, and `subw` puts `r0` back at `x.q`.
    // - `weights`: `r1` starts at `weights` (word-aligned, `OUT IN` bytes: checked above). Group
    //   `g` (from 0) starts it at `4 IN g`; repetition `h` reads bytes `16 h .. 16 h + 16` past
    //   that by `ldmia` (pair 0's) and `2 IN + 16 h .. 2 IN + 16 h + 16` by two `ldrd` (pair 1's),
    //   then advances `r1` by 16; after the `IN / 8` repetitions `addw` skips pair 1's `2 IN`
    //   bytes, to the next group's `4 IN (g + 1)`. The last group reads up to `4 IN groups = OUT
    //   IN` bytes, every address word-aligned (`IN` a multiple of 8), every offset within
    //   `ldrd`'s `1020` (checked above).
    // - `bias` and `scales`: `r2` and `r3` advance by each word read, 4 per group by `ldr`
    //   (unaligned allowed on the Cortex-M4 unless `CCR.UNALIGN_TRP` is set; it is off at reset
    //   and nothing here sets it): bytes `0..16 groups = 4 OUT` of each (checked above).
    // - `y`: `r4` starts at the array (f32-aligned) and `vstmia` stores 16 bytes a group,
    //   advancing it: bytes `0..4 OUT`, the whole array, so every element is initialized when
    //   the block ends (the loop runs `groups >= 1` times, `subs`/`bne` at its bottom).
    // - the stack: `push`/`pop` of `r6`, `r7` and `vpush`/`vpop` of `d0`-`d4` around the block,
    //   and of `r2`-`r5` around each group's kernel, all balanced, so `sp` is restored. `r6` and
    //   `r7`, which Rust cannot name as operands (LLVM may keep its base and frame pointers
    //   there), get their values back before the block ends; every operand is pinned to another
    //   register, so none is in them.
    // Registers: every other core register written is a declared output; the flags are
    // clobbered (`subs`, `vmrs`, the Q flag of `smlad` and `qadd`); `s0`-`s9` are saved on entry
    // and restored on exit, so no FPU register changes as the compiler sees it. FPSCR's
    // rounding mode is only read, its sticky exception bits may be set, as by any f32
    // arithmetic.
    unsafe {
        asm!(
            "push {{r6, r7}}",
            "vpush {{d0-d4}}",
            "vmov s9, r8",
            "movs r6, #0",
            "vmov s8, r6",
            "2:",
            "push {{r2, r3, r4, r5}}",
            "mov r8, #0",
            "mov r10, #0",
            "mov r11, #0",
            "mov r12, #0",
            ".rept {reps}",
            pair_block!(),
            ".endr",
            "pop {{r2, r3, r4, r5}}",
            "ldr r6, [r0]",
            "subw r0, r0, #{off0}",
            "addw r1, r1, #{off0}",
            "sub r8, r8, r12, lsl #8",
            "sub r8, r8, r6, lsl #7",
            "sub r10, r10, r11, lsl #8",
            "sub r10, r10, r6, lsl #7",
            "ldr r6, [r2], #4",
            "qadd r8, r8, r6",
            "ldr r6, [r2], #4",
            "qadd r12, r12, r6",
            "ldr r6, [r2], #4",
            "qadd r10, r10, r6",
            "ldr r6, [r2], #4",
            "qadd r11, r11, r6",
            "vmov s0, s1, r8, r12",
            "vmov s2, s3, r10, r11",
            "vcvt.f32.s32 s0, s0",
            "vcvt.f32.s32 s1, s1",
            "vcvt.f32.s32 s2, s2",
            "vcvt.f32.s32 s3, s3",
            "ldr r6, [r3], #4",
            "ldr r7, [r3], #4",
            "vmov s4, s5, r6, r7",
            "ldr r6, [r3], #4",
            "ldr r7, [r3], #4",
            "vmov s6, s7, r6, r7",
            "vmul.f32 s4, s9, s4",
            "vmul.f32 s5, s9, s5",
            "vmul.f32 s6, s9, s6",
            "vmul.f32 s7, s9, s7",
            "vmul.f32 s0, s0, s4",
            "vmul.f32 s1, s1, s5",
            "vmul.f32 s2, s2, s6",
            "vmul.f32 s3, s3, s7",
            ".irp acc, s0, s1, s2, s3",
            "vcmp.f32 \\acc, #0",
            "vmrs APSR_nzcv, fpscr",
            "it mi",
            "vmovmi.f32 \\acc, s8",
            ".endr",
            "vstmia r4!, {{s0-s3}}",
            "subs r5, r5, #1",
            "bne.w 2b",
            "vpop {{d0-d4}}",
            "pop {{r6, r7}}",
            inout("r0") x.q.as_ptr() => _,
            inout("r1") weights.as_ptr() => _,
            inout("r2") bias.as_ptr() => _,
            inout("r3") scales.as_ptr() => _,
            inout("r4") y.as_mut_ptr().cast::<f32>() => _,
            inout("r5") groups => _,
            inout("r8") input_scale.to_bits() => _,
            out("r9") _,
            out("r10") _,
            out("r11") _,
            out("r12") _,
            out("lr") _,
            reps = const IN >> PAIR_BLOCK_SHIFT,
            off0 = const 2 * IN,
            off1 = const 2 * IN + 8,
        );
    }
    // SAFETY: the block stored all `OUT / 4` groups of 4 f32 (see above): every element is
    // initialized.
    Ok(unsafe { y.assume_init_mut() })
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
/// order. The 24 partials stay in `s0`-`s23` for all inputs; per two inputs one `vldmia` of
/// them into `s24`-`s25`, one `vldmia` of their 6 weights into `s26`-`s31` and 6 `vfma`:
/// 34 instructions for 24 multiply-adds per group of 8 inputs, with the loop's `subs`/`bne`.
///
/// Returns `false`, touching nothing, unless `part` has the 24 partials, `x` has a multiple
/// `n >= 8` of 8 inputs and `weights` has `12 n` bytes at a word-aligned address (rows of 3 f32
/// keep every row aligned); the caller then runs the portable kernel.
#[inline(never)]
pub(super) fn f32_narrow3(weights: &[u8], x: &[f32], part: &mut [f32]) -> bool {
    let n = x.len();
    if part.len() != NARROW_PARTIALS
        || n < 8
        || !n.is_multiple_of(8)
        || n.checked_mul(4 * NARROW_OUTPUTS).is_none_or(|len| weights.len() < len)
        || !(weights.as_ptr() as usize).is_multiple_of(4)
    {
        return false;
    }
    // SAFETY: memory accessed, all in bounds:
    // - `part`: `vldm`/`vstm` of `s0`-`s23` read and write its 24 f32 (96 bytes, its length
    //   checked above), through a pointer from a `&mut [f32]` (word-aligned, as `vldm`/`vstm`
    //   require).
    // - `x`: the loop runs `n / 8 >= 1` times (`subs`/`bne` at the bottom); each iteration's four
    //   `vldmia` read 8 bytes each at `px`, advancing it by what they read: bytes `0..4 n` of
    //   the `[f32]` (word-aligned).
    // - weights: each iteration's four `vldmia` read 24 bytes each at `pw`, advancing it by what
    //   they read: bytes `0..12 n` of `weights`, whose length and alignment were checked above.
    // - the stack: `vpush`/`vpop` of `d0`-`d15` (`s0`-`s31`, 128 bytes), balanced, so `sp` is
    //   restored.
    // Registers: every core register written is a declared operand; `s0`-`s31` are saved on
    // entry and restored on exit, so no FPU register changes as the compiler sees it. The flags
    // (`subs`) are clobbered; FPSCR's rounding mode is only read, its sticky exception bits may
    // be set, as by any f32 arithmetic.
    unsafe {
        asm!(
                "vpush {{d0-d15}}",
                "vldm {acc}, {{s0-s23}}",
                "2:",
                "vldmia {px}!, {{s24-s25}}",
                "vldmia {pw}!, {{s26-s31}}",
                "vfma.f32 s0, s24, s26",
                "vfma.f32 s1, s24, s27",
                "vfma.f32 s2, s24, s28",
                "vfma.f32 s3, s25, s29",
                "vfma.f32 s4, s25, s30",
                "vfma.f32 s5, s25, s31",
                "vldmia {px}!, {{s24-s25}}",
                "vldmia {pw}!, {{s26-s31}}",
                "vfma.f32 s6, s24, s26",
                "vfma.f32 s7, s24, s27",
                "vfma.f32 s8, s24, s28",
                "vfma.f32 s9, s25, s29",
                "vfma.f32 s10, s25, s30",
                "vfma.f32 s11, s25, s31",
                "vldmia {px}!, {{s24-s25}}",
                "vldmia {pw}!, {{s26-s31}}",
                "vfma.f32 s12, s24, s26",
                "vfma.f32 s13, s24, s27",
                "vfma.f32 s14, s24, s28",
                "vfma.f32 s15, s25, s29",
                "vfma.f32 s16, s25, s30",
                "vfma.f32 s17, s25, s31",
                "vldmia {px}!, {{s24-s25}}",
                "vldmia {pw}!, {{s26-s31}}",
                "vfma.f32 s18, s24, s26",
                "vfma.f32 s19, s24, s27",
                "vfma.f32 s20, s24, s28",
                "vfma.f32 s21, s25, s29",
                "vfma.f32 s22, s25, s30",
                "vfma.f32 s23, s25, s31",
                "subs {n}, {n}, #1",
                "bne 2b",
                "vstm {acc}, {{s0-s23}}",
                "vpop {{d0-d15}}",
            acc = in(reg) part.as_mut_ptr(),
            px = inout(reg) x.as_ptr() => _,
            pw = inout(reg) weights.as_ptr() => _,
            n = inout(reg) n >> 3 => _,
        );
    }
    true
}

/// Outputs of the layer [`f32_narrow4`] runs: the 4 actions of the three-dimensional problems.
pub(super) const NARROW4_OUTPUTS: usize = 4;

/// The narrow f32 kernel of a 4-output layer: `part[4 k + j] += x[i] * w[i][j]` (fused, one
/// `vfma.f32`) for the inputs `i = k, k + 8, k + 16, ...` in order, `k < 8`, `j < 4`: the
/// portable narrow kernel's partial sums (`f32.rs`), which the caller then adds to the bias in
/// order. The 32 partials would fill every FPU register, so two passes keep 16 each in
/// `s0`-`s15`: partials `k < 4` over the first 4 inputs of every group of 8, then `k >= 4` over
/// the last 4. Per group and pass one `vldmia` of the 4 inputs into `s20`-`s23`, per input one
/// `vldmia` of its 4 weights into `s16`-`s19` and 4 `vfma`, then two `add`s to the next group:
/// 24 instructions for 16 multiply-adds, against about 15 each for single [`fma`]s through core
/// registers.
///
/// Returns `false`, touching nothing, unless `part` has the 32 partials, `x` has a multiple
/// `n >= 8` of 8 inputs and `weights` has `16 n` bytes at a word-aligned address (rows of 4 f32
/// keep every row aligned); the caller then runs the portable kernel.
#[inline(never)]
pub(super) fn f32_narrow4(weights: &[u8], x: &[f32], part: &mut [f32]) -> bool {
    let n = x.len();
    if part.len() != 8 * NARROW4_OUTPUTS
        || n < 8
        || !n.is_multiple_of(8)
        || n.checked_mul(4 * NARROW4_OUTPUTS).is_none_or(|len| weights.len() < len)
        || !(weights.as_ptr() as usize).is_multiple_of(4)
    {
        return false;
    }
    // Each pass's first input and first weight: input 4 pass, byte 64 pass (both there: n >= 8).
    let (Some(x1), Some(w1)) = (x.get(4..), weights.get(64..)) else {
        return false;
    };
    // Pass 0, then pass 1.
    for (partials, (xs, ws)) in part.chunks_exact_mut(16).zip([(x, weights), (x1, w1)]) {
        // SAFETY: memory accessed, all in bounds:
        // - `partials`: `vldm`/`vstm` of `s0`-`s15` read and write its 16 f32 (64 bytes, a
        //   `chunks_exact_mut(16)` chunk of `part`, whose length is checked above), word-aligned.
        // - `x`: the loop runs `n / 8 >= 1` times (`subs`/`bne` at the bottom); iteration `t`
        //   reads 16 bytes by `vldmia` at `px` = byte `32 t` of `xs` (input `4 pass + 8 t`, so up
        //   to input `4 pass + 8 t + 3 < n`), word-aligned (an f32 slice).
        // - weights: iteration `t` reads 4 times 16 bytes by `vldmia` from `pw` = byte `128 t` of
        //   `ws` (byte `64 pass + 128 t` of `weights`), so up to byte `64 pass + 128 t + 64 <=
        //   16 n` of `weights` (`t < n / 8`, `pass <= 1`), whose length and alignment were
        //   checked above.
        // - the stack: `vpush`/`vpop` of `d0`-`d11` (`s0`-`s23`, 96 bytes), balanced, so `sp` is
        //   restored.
        // Registers: every core register written is a declared operand; `s0`-`s23` are saved on
        // entry and restored on exit, so no FPU register changes as the compiler sees it. The
        // flags (`subs`) are clobbered; FPSCR's rounding mode is only read, its sticky exception
        // bits may be set, as by any f32 arithmetic.
        unsafe {
            asm!(
                "vpush {{d0-d11}}",
                "vldm {acc}, {{s0-s15}}",
                "2:",
                "vldmia {px}, {{s20-s23}}",
                "vldmia {pw}!, {{s16-s19}}",
                "vfma.f32 s0, s20, s16",
                "vfma.f32 s1, s20, s17",
                "vfma.f32 s2, s20, s18",
                "vfma.f32 s3, s20, s19",
                "vldmia {pw}!, {{s16-s19}}",
                "vfma.f32 s4, s21, s16",
                "vfma.f32 s5, s21, s17",
                "vfma.f32 s6, s21, s18",
                "vfma.f32 s7, s21, s19",
                "vldmia {pw}!, {{s16-s19}}",
                "vfma.f32 s8, s22, s16",
                "vfma.f32 s9, s22, s17",
                "vfma.f32 s10, s22, s18",
                "vfma.f32 s11, s22, s19",
                "vldmia {pw}!, {{s16-s19}}",
                "vfma.f32 s12, s23, s16",
                "vfma.f32 s13, s23, s17",
                "vfma.f32 s14, s23, s18",
                "vfma.f32 s15, s23, s19",
                "add {px}, {px}, #32",
                "add {pw}, {pw}, #64",
                "subs {n}, {n}, #1",
                "bne 2b",
                "vstm {acc}, {{s0-s15}}",
                "vpop {{d0-d11}}",
                acc = in(reg) partials.as_mut_ptr(),
                px = inout(reg) xs.as_ptr() => _,
                pw = inout(reg) ws.as_ptr() => _,
                n = inout(reg) n >> 3 => _,
            );
        }
    }
    true
}

/// One group of [`f32_layer`]: 8 inputs into `s24`-`s31`, then 4 times the weights of two
/// inputs into `s8`-`s23` and their 16 `vfma` into `s0`-`s7` (69 instructions, 64 MACs).
macro_rules! f32_block_group {
    () => {
        concat!(
            "vldmia {px}!, {{s24-s31}}\n",
            "vldmia {pw}!, {{s8-s23}}\n",
            "vfma.f32 s0, s24, s8\n",
            "vfma.f32 s1, s24, s9\n",
            "vfma.f32 s2, s24, s10\n",
            "vfma.f32 s3, s24, s11\n",
            "vfma.f32 s4, s24, s12\n",
            "vfma.f32 s5, s24, s13\n",
            "vfma.f32 s6, s24, s14\n",
            "vfma.f32 s7, s24, s15\n",
            "vfma.f32 s0, s25, s16\n",
            "vfma.f32 s1, s25, s17\n",
            "vfma.f32 s2, s25, s18\n",
            "vfma.f32 s3, s25, s19\n",
            "vfma.f32 s4, s25, s20\n",
            "vfma.f32 s5, s25, s21\n",
            "vfma.f32 s6, s25, s22\n",
            "vfma.f32 s7, s25, s23\n",
            "vldmia {pw}!, {{s8-s23}}\n",
            "vfma.f32 s0, s26, s8\n",
            "vfma.f32 s1, s26, s9\n",
            "vfma.f32 s2, s26, s10\n",
            "vfma.f32 s3, s26, s11\n",
            "vfma.f32 s4, s26, s12\n",
            "vfma.f32 s5, s26, s13\n",
            "vfma.f32 s6, s26, s14\n",
            "vfma.f32 s7, s26, s15\n",
            "vfma.f32 s0, s27, s16\n",
            "vfma.f32 s1, s27, s17\n",
            "vfma.f32 s2, s27, s18\n",
            "vfma.f32 s3, s27, s19\n",
            "vfma.f32 s4, s27, s20\n",
            "vfma.f32 s5, s27, s21\n",
            "vfma.f32 s6, s27, s22\n",
            "vfma.f32 s7, s27, s23\n",
            "vldmia {pw}!, {{s8-s23}}\n",
            "vfma.f32 s0, s28, s8\n",
            "vfma.f32 s1, s28, s9\n",
            "vfma.f32 s2, s28, s10\n",
            "vfma.f32 s3, s28, s11\n",
            "vfma.f32 s4, s28, s12\n",
            "vfma.f32 s5, s28, s13\n",
            "vfma.f32 s6, s28, s14\n",
            "vfma.f32 s7, s28, s15\n",
            "vfma.f32 s0, s29, s16\n",
            "vfma.f32 s1, s29, s17\n",
            "vfma.f32 s2, s29, s18\n",
            "vfma.f32 s3, s29, s19\n",
            "vfma.f32 s4, s29, s20\n",
            "vfma.f32 s5, s29, s21\n",
            "vfma.f32 s6, s29, s22\n",
            "vfma.f32 s7, s29, s23\n",
            "vldmia {pw}!, {{s8-s23}}\n",
            "vfma.f32 s0, s30, s8\n",
            "vfma.f32 s1, s30, s9\n",
            "vfma.f32 s2, s30, s10\n",
            "vfma.f32 s3, s30, s11\n",
            "vfma.f32 s4, s30, s12\n",
            "vfma.f32 s5, s30, s13\n",
            "vfma.f32 s6, s30, s14\n",
            "vfma.f32 s7, s30, s15\n",
            "vfma.f32 s0, s31, s16\n",
            "vfma.f32 s1, s31, s17\n",
            "vfma.f32 s2, s31, s18\n",
            "vfma.f32 s3, s31, s19\n",
            "vfma.f32 s4, s31, s20\n",
            "vfma.f32 s5, s31, s21\n",
            "vfma.f32 s6, s31, s22\n",
            "vfma.f32 s7, s31, s23\n",
        )
    };
}

/// Outputs per block of [`f32_layer`]: its accumulators fill `s0`-`s7`.
const F32_ARM_BLOCK: usize = shared::blob::F32_BLOCK;

/// `y[8 c + k] = bias[8 c + k] + x[0] w[0][8 c + k] + x[1] w[1][8 c + k] + ...`, the products
/// and sums in that order, for the `y.len() / 8` whole blocks `c` of an f32 layer (`weights`:
/// blocks of `IN` runs of 8 f32 LE, input-major: `shared::blob::f32_weight_index`; `bias`: f32
/// LE), each fused multiply-add one `vfma.f32` (rounded once): per output the same operations in
/// the same order as the portable f32 kernel.
///
/// One `asm!` block runs the whole layer, so nothing is spent per block outside it. Per block:
/// the 8 biases by 8 `ldr` (the bias array follows its length prefix, so it may be unaligned)
/// and 4 `vmov` into the accumulators `s0`-`s7`, which stay there for all inputs; eight inputs
/// at a time are loaded into `s24`-`s31` by one `vldmia`, and the weights of two inputs at a
/// time into `s8`-`s23` by another, each followed by 16 `vfma`: 69 instructions for 64
/// multiply-adds (1.08 each). A loop takes 32 inputs per pass (4 groups, then `subs`/`bne`:
/// 278 instructions for 256 multiply-adds; left out by `.if` below 32 inputs), then the last
/// `(IN % 32) / 8` groups and the last `IN % 8` inputs one at a time (10 for 8) unrolled by
/// `.rept` over the const `IN`; with `relu`, each output `v` becomes `0` where `v < 0` (`vcmp`
/// with 0, `vmrs`, `vmovmi` from a zero: NaN and `-0.0` kept, as the portable `relu`; a
/// run-time flag, so that the hidden layer and an int8 network's first layer, which leaves the
/// ReLU to its quantization, share one copy); one `vstmia` stores the block's outputs.
/// Unrolling all of a 256-input layer would save 16 instructions a block for 8.9 KiB of flash
/// in every image, f32 or int8 (whose blob may be either).
///
/// `vldm` needs word-aligned addresses: the blob format puts every weight array at a multiple
/// of 64 bytes from the blob's start and a block's `32 IN` bytes keep the next one aligned, so
/// the weights of a blob stored at a word-aligned address (the image's flash, or a C caller's
/// aligned buffer) are. Returns `false`, touching nothing, unless `weights` holds the whole
/// blocks' `32 IN` bytes each at a word-aligned address and `bias` their `32` bytes each; the
/// caller then runs the portable kernel. The kernel is not inlined: one copy per input width
/// serves every layer of that width.
#[inline(always)]
pub(super) fn f32_layer<const IN: usize>(
    weights: &[u8],
    bias: &[u8],
    x: &[f32; IN],
    y: &mut [f32],
    relu: bool,
) -> bool {
    // SAFETY: `MaybeUninit<f32>` has the layout of `f32`, and `f32_layer_uninit` writes only
    // f32 values into the view, so `y` holds initialized f32 whatever it does.
    let y = unsafe { &mut *(core::ptr::from_mut(y) as *mut [MaybeUninit<f32>]) };
    f32_layer_uninit(weights, bias, x, y, relu)
}

/// [`f32_layer`] into an array that is not initialized yet (so never zeroed first: about 330
/// instructions for 256 outputs), which the kernel writes whole: `Ok` with the array, or
/// `Err` with it untouched where the kernel declines or `OUT` is not a whole number of blocks.
#[inline(always)]
pub(super) fn f32_layer_fresh<'y, const IN: usize, const OUT: usize>(
    weights: &[u8],
    bias: &[u8],
    x: &[f32; IN],
    y: &'y mut MaybeUninit<[f32; OUT]>,
    relu: bool,
) -> Result<&'y mut [f32; OUT], &'y mut MaybeUninit<[f32; OUT]>> {
    if !OUT.is_multiple_of(F32_ARM_BLOCK) {
        return Err(y);
    }
    // SAFETY: `[f32; OUT]` and `[MaybeUninit<f32>; OUT]` have the same layout, and any bytes
    // are a valid `MaybeUninit<f32>`.
    let view = unsafe { &mut *y.as_mut_ptr().cast::<[MaybeUninit<f32>; OUT]>() };
    if !f32_layer_uninit(weights, bias, x, view, relu) {
        return Err(y);
    }
    // SAFETY: the kernel returned `true`, so its `vstmia` stored all `OUT / 8` blocks of 8 f32:
    // every element is initialized.
    Ok(unsafe { y.assume_init_mut() })
}

/// [`f32_layer`] on a view that may be uninitialized: it writes the whole blocks' outputs, never
/// reads them.
#[inline(never)]
fn f32_layer_uninit<const IN: usize>(
    weights: &[u8],
    bias: &[u8],
    x: &[f32; IN],
    y: &mut [MaybeUninit<f32>],
    relu: bool,
) -> bool {
    // Whole blocks of 8 (a shift: the crate denies integer division).
    let blocks = y.len() >> F32_ARM_BLOCK.trailing_zeros();
    let Some(weight_bytes) = blocks.checked_mul(4 * F32_ARM_BLOCK * IN) else {
        return false;
    };
    let (Some(weights), Some(bias)) = (weights.get(..weight_bytes), bias.get(..4 * F32_ARM_BLOCK * blocks)) else {
        return false;
    };
    if IN == 0 || blocks == 0 || !(weights.as_ptr() as usize).is_multiple_of(4) {
        return false;
    }
    // SAFETY: memory accessed, all in bounds:
    // - `y`: block `c` (the outer loop runs `blocks >= 1` times, `subs`/`bne` at its bottom)
    //   stores its 8 f32 by `vstmia` at `py`, which starts at `y` (word-aligned, an f32 slice)
    //   and advances by the 32 bytes stored: bytes `0..32 blocks <= 4 y.len()` of `y`.
    // - `bias`: block `c` reads 8 words by `ldr` at `pb`, which starts at `bias` and advances by
    //   each word read: bytes `0..32 blocks` of `bias`, which holds them (checked above). `ldr`
    //   may be unaligned on the Cortex-M4 (unless `CCR.UNALIGN_TRP` is set; it is off at reset
    //   and nothing here sets it).
    // - `x`: each block starts `px` at `x` again; the loop's `IN / 32` passes read 32 f32 each
    //   (4 groups), the `(IN % 32) / 8` groups' `vldmia` 8 f32 each and the `IN % 8` singles'
    //   one each, at `px`, advancing it by what they read: bytes `0..4 IN` of the `[f32; IN]`
    //   (word-aligned). The inner loop runs `IN >> 5` times (its count set by `movw`), and is
    //   left out when that is 0 (`.if`).
    // - weights: `pw` starts at `weights`, word-aligned (checked above); each group's four
    //   `vldmia` read 64 bytes each and each single's one 32 bytes, advancing `pw` by what they
    //   read: `32 IN` bytes a block, so bytes `0..32 IN blocks` of `weights` (checked above),
    //   each block's start word-aligned.
    // - the stack: `vpush`/`vpop` of `d0`-`d15` (`s0`-`s31`, 128 bytes), balanced, so `sp` is
    //   restored.
    // Registers: every core register written is a declared operand (`relu` is only read; `px`
    // and `n` also carry each block's bias words to the FPU before they take their own values);
    // the flags are clobbered (`cmp`, `subs`); `s0`-`s31` are saved on entry and restored on exit, so no FPU register
    // changes as the compiler sees it (Rust cannot name FPU registers as `asm!` operands on
    // stable for this target). FPSCR's rounding mode is only read, its sticky exception bits
    // may be set, as by any f32 arithmetic (so not `preserves_flags`).
    unsafe {
        asm!(
                "vpush {{d0-d15}}",
                "2:",
                "ldr {n}, [{pb}], #4",
                "ldr {px}, [{pb}], #4",
                "vmov s0, s1, {n}, {px}",
                "ldr {n}, [{pb}], #4",
                "ldr {px}, [{pb}], #4",
                "vmov s2, s3, {n}, {px}",
                "ldr {n}, [{pb}], #4",
                "ldr {px}, [{pb}], #4",
                "vmov s4, s5, {n}, {px}",
                "ldr {n}, [{pb}], #4",
                "ldr {px}, [{pb}], #4",
                "vmov s6, s7, {n}, {px}",
                "mov {px}, {x}",
                ".if {loops}",
                "movw {n}, #{loops}",
                "3:",
                ".rept 4",
                f32_block_group!(),
                ".endr",
                "subs {n}, {n}, #1",
                "bne.w 3b",
                ".endif",
                ".rept {groups}",
                f32_block_group!(),
                ".endr",
                ".rept {singles}",
                "vldmia {px}!, {{s24}}",
                "vldmia {pw}!, {{s8-s15}}",
                "vfma.f32 s0, s24, s8",
                "vfma.f32 s1, s24, s9",
                "vfma.f32 s2, s24, s10",
                "vfma.f32 s3, s24, s11",
                "vfma.f32 s4, s24, s12",
                "vfma.f32 s5, s24, s13",
                "vfma.f32 s6, s24, s14",
                "vfma.f32 s7, s24, s15",
                ".endr",
                "cmp {relu}, #0",
                "beq 4f",
                "mov {n}, #0",
                "vmov s8, {n}",
                ".irp acc, s0, s1, s2, s3, s4, s5, s6, s7",
                "vcmp.f32 \\acc, #0",
                "vmrs APSR_nzcv, fpscr",
                "it mi",
                "vmovmi.f32 \\acc, s8",
                ".endr",
                "4:",
                "vstmia {py}!, {{s0-s7}}",
                "subs {blocks}, {blocks}, #1",
                "bne.w 2b",
                "vpop {{d0-d15}}",
            x = in(reg) x.as_ptr(),
            px = out(reg) _,
            n = out(reg) _,
            pb = inout(reg) bias.as_ptr() => _,
            pw = inout(reg) weights.as_ptr() => _,
            py = inout(reg) y.as_mut_ptr() => _,
            blocks = inout(reg) blocks => _,
            loops = const IN >> 5,
            groups = const (IN >> 3) & 3,
            singles = const IN & 7,
            relu = in(reg) u32::from(relu),
        );
    }
    true
}
