//! The x86-64 kernels with AVX2 and FMA, chosen at run time by `cpuid` (the host SIL and
//! benchmarks run on whatever workstation or cluster node they land on, so the binary cannot
//! assume the instructions at compile time).
//!
//! - f32: exactly the portable kernel's fused multiply-adds in the same order per output
//!   (`policy/f32.rs`): 8 outputs per `vfmadd231ps`, the sum of one output never reassociated,
//!   so the results are the bits of the Cortex-M4F's `vfma.f32` and of `libm::fmaf`.
//! - int8: per row pair, 16 of its i16 (`256 b + a + 128`) per `vpmaddwd` against the i16
//!   activations and their high bytes (`vpsraw`) per another, 4 pairs sharing each activation
//!   load. Integer sums wrap identically in any order, so the accumulators are the portable
//!   kernels' and the Cortex-M4F's `smlad` ones, bit for bit.
//!
//! With the machine's `unsafe`: `cpuid`/`xgetbv` to detect the features, the `#[target_feature]`
//! kernel's call, and its unaligned loads and stores through raw pointers, whose bounds are
//! checked before the kernel is entered (see the SAFETY comments).

// `__cpuid` is a safe function in newer toolchains and an unsafe one in older.
#![allow(unused_unsafe)]

use core::arch::x86_64::{
    __cpuid, __cpuid_count, __m256i, _mm256_add_epi32, _mm256_castsi256_si128, _mm256_extracti128_si256,
    _mm256_fmadd_ps, _mm256_loadu_ps, _mm256_loadu_si256, _mm256_madd_epi16, _mm256_permutevar8x32_ps, _mm256_set1_ps,
    _mm256_setzero_ps, _mm256_setzero_si256, _mm256_srai_epi16, _mm256_storeu_ps, _mm_add_epi32, _mm_cvtsi128_si32,
    _mm_cvtss_f32, _mm_fmadd_ss, _mm_set_ss, _mm_shuffle_epi32, _xgetbv, CpuidResult,
};
use core::sync::atomic::{AtomicU8, Ordering};

use shared::blob::{f32_weight_index, F32_BLOCK};

use super::f32::SPLIT;
use super::F32_TILE;

/// Vectors of 8 outputs per register tile of [`F32_TILE`] outputs.
const VECTORS: usize = F32_TILE >> 3;

const UNKNOWN: u8 = 0;
const ABSENT: u8 = 1;
const PRESENT: u8 = 2;

/// Whether the CPU runs AVX2 and FMA and the OS saves the YMM registers (cached).
static AVX2_FMA: AtomicU8 = AtomicU8::new(UNKNOWN);

/// Whether [`dense`] runs the AVX2 + FMA kernel on this machine.
pub(super) fn has_avx2_fma() -> bool {
    match AVX2_FMA.load(Ordering::Relaxed) {
        PRESENT => true,
        ABSENT => false,
        _ => {
            let present = detect();
            AVX2_FMA.store(if present { PRESENT } else { ABSENT }, Ordering::Relaxed);
            present
        }
    }
}

/// `cpuid` leaf 1: FMA (ECX 12), OSXSAVE (ECX 27), AVX (ECX 28); leaf 7: AVX2 (EBX 5); then
/// XCR0 bits 1 and 2 (the OS saves XMM and YMM state), as `is_x86_feature_detected!` does.
fn detect() -> bool {
    // SAFETY: `cpuid` exists on every x86-64 CPU; leaves above the maximum are not queried.
    let CpuidResult { eax: max_leaf, .. } = unsafe { __cpuid(0) };
    if max_leaf < 7 {
        return false;
    }
    // SAFETY: as above, leaf 1 <= max_leaf.
    let leaf1 = unsafe { __cpuid(1) };
    let bit = |reg: u32, n: u32| reg & (1 << n) != 0;
    if !(bit(leaf1.ecx, 12) && bit(leaf1.ecx, 27) && bit(leaf1.ecx, 28)) {
        return false;
    }
    // SAFETY: as above, leaf 7 <= max_leaf.
    let leaf7 = unsafe { __cpuid_count(7, 0) };
    if !bit(leaf7.ebx, 5) {
        return false;
    }
    // SAFETY: OSXSAVE (checked above) means the OS enabled `xgetbv`; XCR0 always exists.
    let xcr0 = unsafe { read_xcr0() };
    xcr0 & 0b110 == 0b110
}

/// XCR0, the state components the OS saves.
///
/// # Safety
/// The CPU must report OSXSAVE.
#[target_feature(enable = "xsave")]
unsafe fn read_xcr0() -> u64 {
    // SAFETY: the caller checked OSXSAVE; register 0 always exists.
    unsafe { _xgetbv(0) }
}

/// Whether the kernels can run: AVX2 and FMA present, and `weights` holds `IN * OUT` f32.
fn usable<const IN: usize, const OUT: usize>(weights: &[u8]) -> bool {
    let needed = IN.checked_mul(OUT).and_then(|n| n.checked_mul(4));
    needed.is_some_and(|n| weights.len() >= n) && has_avx2_fma()
}

/// `y += W x` (`y` holding the bias; `weights`: `IN * OUT` f32 LE in blocks of 8 outputs) for a
/// layer at least a tile wide, with AVX2 and FMA, in the portable kernel's order. Returns `false`,
/// touching nothing, for a narrower layer (see [`narrow_partials`]), if the machine lacks AVX2
/// or FMA, or if `weights` is short; the caller then runs the portable kernel.
#[inline]
pub(super) fn dense<const IN: usize, const OUT: usize>(weights: &[u8], x: &[f32; IN], y: &mut [f32; OUT]) -> bool {
    if OUT < F32_TILE || !usable::<IN, OUT>(weights) {
        return false;
    }
    // SAFETY: the CPU runs AVX2 and FMA and the OS saves YMM state, and `weights` holds the
    // `IN * OUT` f32 the kernel reads (`usable`).
    unsafe { wide(weights.as_ptr().cast(), x, y) };
    true
}

/// The narrow kernel's [`SPLIT`] partial sums (from 0) of a layer narrower than a block (its
/// weights plain input-major), with
/// AVX2 and FMA: `part[k][j]` fuses the inputs `k, k + 8, k + 16, ...` in order. Returns
/// `false`, touching nothing, where [`dense`] would.
#[inline]
pub(super) fn narrow_partials<const IN: usize, const OUT: usize>(
    weights: &[u8],
    x: &[f32; IN],
    part: &mut [[f32; OUT]; SPLIT],
) -> bool {
    if OUT >= F32_BLOCK || !usable::<IN, OUT>(weights) {
        return false;
    }
    // SAFETY: as in `dense`.
    unsafe { narrow(weights.as_ptr().cast(), x, part) };
    true
}

/// `acc + x * w` rounded once.
#[target_feature(enable = "fma")]
#[inline]
fn fma1(x: f32, w: f32, acc: f32) -> f32 {
    _mm_cvtss_f32(_mm_fmadd_ss(_mm_set_ss(x), _mm_set_ss(w), _mm_set_ss(acc)))
}

/// The wide layer: register tiles of [`F32_TILE`] outputs (8 vectors of 8, each a block of the
/// weights, one contiguous vector per input), each accumulated over the inputs in order, then
/// vectors of 8 (whole blocks) and single outputs (the narrower last block) for the last
/// `OUT % 64`.
///
/// # Safety
/// AVX2 and FMA present; `w` points to `IN * OUT` readable f32 (any alignment).
#[target_feature(enable = "avx2,fma")]
unsafe fn wide<const IN: usize, const OUT: usize>(w: *const f32, x: &[f32; IN], y: &mut [f32; OUT]) {
    let y = y.as_mut_ptr();
    let mut col = 0;
    while col + F32_TILE <= OUT {
        let mut acc = [_mm256_setzero_ps(); VECTORS];
        // SAFETY (every pointer below): output `col + 8 v + l < OUT` of `y`; weight
        // `f32_weight_index(IN, OUT, col + 8 v, i) + l = IN (col + 8 v) + 8 i + l < IN * OUT` of
        // `w` (a whole block: `col + 8 v + 8 <= OUT`), for `i < IN`, `v < VECTORS`, `l < 8`.
        for (v, a) in acc.iter_mut().enumerate() {
            // SAFETY: in bounds, by the SAFETY comment above.
            *a = unsafe { _mm256_loadu_ps(y.add(col + 8 * v)) };
        }
        for (i, &xi) in x.iter().enumerate() {
            let xv = _mm256_set1_ps(xi);
            for (v, a) in acc.iter_mut().enumerate() {
                // SAFETY: in bounds, by the SAFETY comment above.
                let run = unsafe { w.add(f32_weight_index(IN, OUT, col + 8 * v, i)) };
                // SAFETY: in bounds, by the SAFETY comment above.
                *a = _mm256_fmadd_ps(xv, unsafe { _mm256_loadu_ps(run) }, *a);
            }
        }
        for (v, a) in acc.iter().enumerate() {
            // SAFETY: in bounds, by the SAFETY comment above.
            unsafe { _mm256_storeu_ps(y.add(col + 8 * v), *a) };
        }
        col += F32_TILE;
    }
    while col + F32_BLOCK <= OUT {
        // SAFETY: as above with one vector.
        let mut a = unsafe { _mm256_loadu_ps(y.add(col)) };
        for (i, &xi) in x.iter().enumerate() {
            // SAFETY: in bounds, by the SAFETY comment above.
            let run = unsafe { w.add(f32_weight_index(IN, OUT, col, i)) };
            // SAFETY: in bounds, by the SAFETY comment above.
            a = _mm256_fmadd_ps(_mm256_set1_ps(xi), unsafe { _mm256_loadu_ps(run) }, a);
        }
        // SAFETY: in bounds, by the SAFETY comment above.
        unsafe { _mm256_storeu_ps(y.add(col), a) };
        col += F32_BLOCK;
    }
    while col < OUT {
        // SAFETY: output `col < OUT`, weight `f32_weight_index(IN, OUT, col, i) < IN * OUT`.
        let mut a = unsafe { *y.add(col) };
        for (i, &xi) in x.iter().enumerate() {
            // SAFETY: in bounds, by the SAFETY comment above.
            a = fma1(
                xi,
                unsafe { w.add(f32_weight_index(IN, OUT, col, i)).read_unaligned() },
                a,
            );
        }
        // SAFETY: in bounds, by the SAFETY comment above.
        unsafe { *y.add(col) = a };
        col += 1;
    }
}

/// The narrow layer's partial sums (fewer outputs than a tile, the 3 actions): partial `k`
/// over inputs `k, k + 8, k + 16, ...` in order. A block of 8 inputs is 8 rows of `OUT`
/// weights, `OUT` contiguous vectors; lane `m` of the block holds row `m / OUT`, output
/// `m % OUT`, which is where partial `k = m / OUT` of output `j = m % OUT` lies in `part`
/// flattened. So one accumulator vector per position in the block keeps the `OUT * 8` partial
/// sums, and the inputs are spread to the lanes by `vpermps`.
///
/// # Safety
/// AVX2 and FMA present; `w` points to `IN * OUT` readable f32 (any alignment).
#[target_feature(enable = "avx2,fma")]
unsafe fn narrow<const IN: usize, const OUT: usize>(w: *const f32, x: &[f32; IN], part: &mut [[f32; OUT]; SPLIT]) {
    const { assert!(SPLIT == 8, "the lanes of a vector are the partial sums") };
    // Lane `l` of vector `v` takes input `(8 v + l) / OUT` of the block.
    let mut spread = [_mm256_setzero_si256(); OUT];
    let (mut row, mut col) = (0i32, 0usize);
    for s in spread.iter_mut() {
        let mut lanes = [0i32; 8];
        for lane in lanes.iter_mut() {
            *lane = row;
            col += 1;
            if col == OUT {
                col = 0;
                row += 1;
            }
        }
        // SAFETY: 8 i32 from an `[i32; 8]`.
        *s = unsafe { _mm256_loadu_si256(lanes.as_ptr().cast()) };
    }
    let mut acc = [_mm256_setzero_ps(); OUT];
    let blocks = IN >> 3;
    for b in 0..blocks {
        // SAFETY: inputs `8 b .. 8 b + 8 <= IN` of `x`; weights `8 b OUT + 8 v + l < 8 (b + 1)
        // OUT <= IN * OUT` for `v < OUT`, `l < 8`.
        let xb = unsafe { _mm256_loadu_ps(x.as_ptr().add(SPLIT * b)) };
        // SAFETY: in bounds, by the SAFETY comment above.
        let block = unsafe { w.add(SPLIT * b * OUT) };
        for (v, (a, s)) in acc.iter_mut().zip(spread.iter()).enumerate() {
            let xs = _mm256_permutevar8x32_ps(xb, *s);
            // SAFETY: in bounds, by the SAFETY comment above.
            *a = _mm256_fmadd_ps(xs, unsafe { _mm256_loadu_ps(block.add(8 * v)) }, *a);
        }
    }
    for (lanes, a) in part.as_flattened_mut().chunks_exact_mut(8).zip(acc.iter()) {
        // SAFETY: 8 f32 into a chunk of 8 (`part` flattened is `8 OUT` long: `OUT` chunks).
        unsafe { _mm256_storeu_ps(lanes.as_mut_ptr(), *a) };
    }
    // The last `IN % 8` inputs, input `8 blocks + r` into partial `r`.
    let first = SPLIT * blocks;
    for (r, (p, &xi)) in part.iter_mut().zip(x.iter().skip(first)).enumerate() {
        for (j, pj) in p.iter_mut().enumerate() {
            // SAFETY: weight `(first + r) * OUT + j < IN * OUT`.
            *pj = fma1(xi, unsafe { w.add((first + r) * OUT + j).read_unaligned() }, *pj);
        }
    }
}

/// Row pairs of the int8 kernel that share each activation load.
const INT8_PAIRS: usize = 4;

/// The int8 layer's dot products `acc[j] = sum_i w[j][i] x[i]` (wrapping; `weights`: `OUT`
/// rows of `IN` in the blob's row pairs) with AVX2. Returns `false`, touching nothing, if the
/// machine lacks AVX2 or `weights` is short; the caller then runs the portable kernel.
#[inline]
pub(super) fn int8_dots<const IN: usize, const OUT: usize>(
    weights: &[u8],
    x: &[i16; IN],
    acc: &mut [i32; OUT],
) -> bool {
    let fits = IN.checked_mul(OUT).is_some_and(|n| weights.len() >= n);
    if !(fits && has_avx2_fma()) {
        return false;
    }
    // SAFETY: the CPU runs AVX2 and the OS saves YMM state, and `weights` holds the `IN * OUT`
    // bytes the kernel reads.
    unsafe { int8_pairs(weights.as_ptr(), x, acc) };
    true
}

/// The sum of a vector's 8 i32 lanes (wrapping).
#[target_feature(enable = "avx2")]
#[inline]
fn lane_sum(v: __m256i) -> i32 {
    let s = _mm_add_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
    let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b01_00_11_10>(s));
    let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b10_11_00_01>(s));
    _mm_cvtsi128_si32(s)
}

/// `K` pairs from pair `p`: each pair's raw sum `sum_i h_i x_i` and high sum
/// `sum_i (h_i >> 8) x_i`, `h_i` the pair's i16 at input `i`, 16 inputs per `vpmaddwd`.
///
/// # Safety
/// AVX2 present; `w` points to the `IN * OUT` bytes of an int8 layer with at least `p + K`
/// row pairs (`2 (p + K) <= OUT`).
#[target_feature(enable = "avx2")]
unsafe fn pair_sums<const IN: usize, const K: usize>(w: *const u8, p: usize, x: &[i16; IN]) -> [(i32, i32); K] {
    let blocks = IN >> 4;
    let mut raw = [_mm256_setzero_si256(); K];
    let mut high = [_mm256_setzero_si256(); K];
    for b in 0..blocks {
        // SAFETY: inputs `16 b .. 16 b + 16 <= IN` of `x`.
        let xv = unsafe { _mm256_loadu_si256(x.as_ptr().add(16 * b).cast()) };
        for (r, (raw, high)) in raw.iter_mut().zip(high.iter_mut()).enumerate() {
            // SAFETY: bytes `2 IN (p + r) + 32 b .. + 32 <= 2 IN (p + r + 1) <= IN OUT` of `w`.
            let hv = unsafe { _mm256_loadu_si256(w.add(2 * IN * (p + r) + 32 * b).cast()) };
            *raw = _mm256_add_epi32(*raw, _mm256_madd_epi16(hv, xv));
            *high = _mm256_add_epi32(*high, _mm256_madd_epi16(_mm256_srai_epi16::<8>(hv), xv));
        }
    }
    let mut out = [(0i32, 0i32); K];
    for (r, (o, (raw, high))) in out.iter_mut().zip(raw.iter().zip(&high)).enumerate() {
        let (mut rs, mut hs) = (lane_sum(*raw), lane_sum(*high));
        for (i, &xi) in x.iter().enumerate().skip(blocks << 4) {
            // SAFETY: bytes `2 IN (p + r) + 2 i .. + 2 < 2 IN (p + r + 1)` of `w` (`i < IN`).
            let h = i32::from(i16::from_le_bytes(unsafe {
                [*w.add(2 * IN * (p + r) + 2 * i), *w.add(2 * IN * (p + r) + 2 * i + 1)]
            }));
            rs = rs.wrapping_add(h * i32::from(xi));
            hs = hs.wrapping_add((h >> 8) * i32::from(xi));
        }
        *o = (rs, hs);
    }
    out
}

/// [`int8_dots`]' kernel: [`INT8_PAIRS`] row pairs at a time, then one pair at a time, then
/// the odd plain row; row `2p` [`unpair`](super::int8::unpair)ed from its pair's sums.
///
/// # Safety
/// AVX2 present; `w` points to `IN * OUT` readable bytes (any alignment).
#[target_feature(enable = "avx2")]
unsafe fn int8_pairs<const IN: usize, const OUT: usize>(w: *const u8, x: &[i16; IN], acc: &mut [i32; OUT]) {
    let sum = x.iter().fold(0i32, |s, &v| s.wrapping_add(i32::from(v)));
    let pairs = OUT >> 1;
    let mut p = 0;
    let mut put = |p: usize, (raw, high): (i32, i32)| {
        if let Some([a, b]) = acc.get_mut(2 * p..2 * p + 2) {
            *a = super::int8::unpair(raw, high, sum);
            *b = high;
        }
    };
    while p + INT8_PAIRS <= pairs {
        // SAFETY: `2 (p + INT8_PAIRS) <= OUT`, and the caller's guarantees.
        for (r, s) in unsafe { pair_sums::<IN, INT8_PAIRS>(w, p, x) }.into_iter().enumerate() {
            put(p + r, s);
        }
        p += INT8_PAIRS;
    }
    while p < pairs {
        // SAFETY: `2 (p + 1) <= OUT`, and the caller's guarantees.
        let [s] = unsafe { pair_sums::<IN, 1>(w, p, x) };
        put(p, s);
        p += 1;
    }
    if OUT % 2 == 1 {
        let mut s = 0i32;
        for (i, &xi) in x.iter().enumerate() {
            // SAFETY: byte `(OUT - 1) IN + i < OUT IN` of `w`: the odd last row, plain i8.
            let wi = unsafe { *w.add((OUT - 1) * IN + i) } as i8;
            s = s.wrapping_add(i32::from(xi) * i32::from(wi));
        }
        if let Some(a) = acc.last_mut() {
            *a = s;
        }
    }
}
