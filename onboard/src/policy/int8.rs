//! The int8 kernels: a dense layer's exact i32 dot products against 16-bit quantized
//! activations in three kernels giving the same integers ([`Int8Kernel`]) over the blob's row
//! pairs, and the requantization between layers ([`quantize`], [`quantize_relu`]) (see the
//! module doc of [`super`]).

use core::mem::MaybeUninit;

use shared::blob::{self, LayerBlob, ACTIVATION_LEVELS};

#[cfg(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"))]
use super::arm::{dot2_pairs, int8_relu_layer_fresh, pair_mac};
use super::{check_len, check_shape, f32_le, i32_le, relu, relu_to, LayerArray, PolicyError, ARM_ASM};

/// Output rows (two row pairs) computed per pass over the input by [`DenseInt8::accumulate_rows`]
/// and [`DenseInt8::accumulate_pairs`].
pub const INT8_ROWS: usize = 4;
/// Independent i32 lanes of [`DenseInt8::accumulate_lanes`] (two AVX-512 registers).
pub const INT8_LANES: usize = 32;

/// `round(v)`, half away from zero, saturating to the i32 range; NaN gives 0 (the Arm form
/// of the quantizer's rounding).
///
/// Truncate (Rust's `as`: round toward zero, saturating, NaN to 0; one `vcvt` on Arm), then
/// add the truncation of twice the fractional part, which is ±1 exactly when `|frac| >= 0.5`.
/// Exact: for `|v| < 2^31` the truncation `t` converts back to f32 exactly (either
/// `|t| < 2^24`, or `v` is already an integer and `t == v`), `v - t` is exact (Sterbenz: `t`
/// and `v` have the same sign and `|v| / 2 <= |t| <= |v|` once `|t| >= 1`; `v - 0 = v`
/// otherwise), and doubling a value below 1 is exact. For `|v| >= 2^31` (and ±inf) `t`
/// saturates and the correction has the same sign or is 0, so the saturating add (`qadd`)
/// keeps the saturated value.
#[inline(always)]
fn round_away(v: f32) -> i32 {
    let t = v as i32;
    let frac = v - t as f32;
    t.saturating_add((frac + frac) as i32)
}

/// [`quantize`] (`lo = -L`) and [`quantize_relu`] (`lo = 0`) on Arm: [`round_away`] of the
/// quotient, clamped on the integer (rounding and clamping commute for integer bounds; the
/// clamp to `0..=L` is one `usat`). About 10 instructions on the Cortex-M4F, where the
/// conversions are single `vcvt`s.
#[inline(always)]
fn quantize_trunc(x: f32, scale: f32, lo: i32) -> i16 {
    // lo..=L lies within the i16 range.
    round_away(x / scale).clamp(lo, i32::from(ACTIVATION_LEVELS)) as i16
}

/// `1.5 * 2^23`: adding it to a float of magnitude below `2^22` leaves the nearest integer
/// (ties to even) in the low mantissa bits.
const ROUND_MAGIC: f32 = 12_582_912.0;

/// [`quantize`] on other targets: branch-free and free of float-to-int casts (Rust's
/// saturating `as` does not vectorize well on x86): clamp, round to nearest even with
/// [`ROUND_MAGIC`], read the integer from the bits, then move exact ties away from zero.
#[inline(always)]
fn quantize_magic(x: f32, scale: f32) -> i16 {
    let v = x / scale;
    let levels = f32::from(ACTIVATION_LEVELS);
    let v = if v.is_nan() { 0.0 } else { v.clamp(-levels, levels) };
    let m = v + ROUND_MAGIC;
    // Both bit patterns lie in [2^23, 2^24) as floats, so their difference is the integer.
    let even = (m.to_bits() as i32).wrapping_sub(ROUND_MAGIC.to_bits() as i32);
    // Exact: `m - ROUND_MAGIC` is the rounded value and `v` is within 0.5 of it.
    let d = v - (m - ROUND_MAGIC);
    let q = even + i32::from(d == 0.5 && v > 0.0) - i32::from(d == -0.5 && v < 0.0);
    // |q| <= ACTIVATION_LEVELS.
    q as i16
}

/// `clamp(round(x / scale), -L, L)` with `L` = [`ACTIVATION_LEVELS`], round half away from
/// zero, the quotient rounded to f32 first; NaN gives 0 (the int8 layers' input quantization).
///
/// Two exact implementations give the same integers for every `x` and `scale` (unit tests
/// compare them on every f32 of magnitude in `[2^-2, 2^2)`, around every tie up to the clamp,
/// and on random bit patterns): `quantize_trunc` on 32-bit Arm, `quantize_magic`
/// (vectorizes) elsewhere.
#[inline(always)]
pub fn quantize(x: f32, scale: f32) -> i16 {
    if cfg!(target_arch = "arm") {
        quantize_trunc(x, scale, -i32::from(ACTIVATION_LEVELS))
    } else {
        quantize_magic(x, scale)
    }
}

/// `quantize(relu(y), scale)` (ReLU keeping NaN, as the f32 kernel does) for a positive
/// `scale`. On Arm without the ReLU: a negative quotient rounds to a value `<= 0`, which the
/// clamp to `0..=L` maps to 0 just as ReLU's 0 would; `-0.0` and NaN give 0 either way, `+inf`
/// gives `L` either way.
#[inline(always)]
pub fn quantize_relu(y: f32, scale: f32) -> i16 {
    if cfg!(target_arch = "arm") {
        quantize_trunc(y, scale, 0)
    } else {
        quantize_magic(relu(y), scale)
    }
}

/// A dense int8 layer viewing its blob arrays in place.
///
/// `weights`: `IN * OUT` bytes in row pairs (`shared::blob::int8_weight_bytes`: rows `2p`,
/// `2p + 1` interleaved per input, the first offset by 128; an odd last row plain); `bias`:
/// `OUT` i32 LE in units of `input_scale * weight_scale[j]`; `weight_scales`: `OUT` f32 LE.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DenseInt8<'a, const IN: usize, const OUT: usize> {
    weights: &'a [u8],
    bias: &'a [u8],
    weight_scales: &'a [u8],
    input_scale: f32,
}

impl<'a, const IN: usize, const OUT: usize> DenseInt8<'a, IN, OUT> {
    /// Views an int8 layer; checks `inputs == IN`, `outputs == OUT`, the array lengths, that
    /// `input_scale` is finite and positive and that the weight scales are finite.
    /// The activation is not checked here (see [`Mlp::from_blob`](super::Mlp::from_blob)).
    /// Errors report layer 0.
    pub fn from_layer(layer: &LayerBlob<'a>) -> Result<Self, PolicyError> {
        check_shape::<IN, OUT>(layer)?;
        if IN > blob::MAX_INT8_INPUTS {
            return Err(PolicyError::TooWideForInt8 { layer: 0, inputs: IN });
        }
        check_len(LayerArray::Weights, layer.weights, IN.saturating_mul(OUT))?;
        check_len(LayerArray::Bias, layer.bias, OUT.saturating_mul(4))?;
        check_len(LayerArray::WeightScales, layer.weight_scales, OUT.saturating_mul(4))?;
        let s = layer.input_scale;
        let scales_ok = layer.weight_scales.chunks_exact(4).all(|c| f32_le(c).is_finite());
        if !(s.is_finite() && s > 0.0 && scales_ok) {
            return Err(PolicyError::BadScale { layer: 0 });
        }
        Ok(Self {
            weights: layer.weights,
            bias: layer.bias,
            weight_scales: layer.weight_scales,
            input_scale: s,
        })
    }

    /// The weight bytes (borrowed from the blob).
    pub fn weights(&self) -> &'a [u8] {
        self.weights
    }

    /// The scale that quantizes this layer's input.
    pub fn input_scale(&self) -> f32 {
        self.input_scale
    }

    /// `x` quantized with this layer's input scale to i16 (values in `-L..=L`,
    /// `L` = [`ACTIVATION_LEVELS`]).
    pub fn quantize_input(&self, x: &[f32; IN]) -> [i16; IN] {
        let mut q = [0i16; IN];
        for (qi, &xi) in q.iter_mut().zip(x.iter()) {
            *qi = quantize(xi, self.input_scale);
        }
        q
    }

    /// `relu(y)` quantized like [`Self::quantize_input`] ([`quantize_relu`]), with the sum the
    /// pair kernel needs: the int8 layer after the f32 first layer takes its pre-activation.
    #[inline(always)]
    pub(super) fn quantize_relu_input(&self, y: &[f32; IN]) -> Acts<IN> {
        // Filled in place: moving a finished `[i16; 256]` into the struct is a 512-byte copy.
        let mut x = Acts { q: [0i16; IN], sum: 0 };
        let mut sum = 0i32;
        for (qi, &yi) in x.q.iter_mut().zip(y.iter()) {
            *qi = quantize_relu(yi, self.input_scale);
            sum = sum.wrapping_add(i32::from(*qi));
        }
        x.sum = sum;
        x
    }

    /// The integer accumulators `bias[j] + sum_i w[j][i] * xq[i]`, saturating at the bias add.
    /// For `xq` in `-L..=L` (what [`Self::quantize_input`] gives) the dot product is exact:
    /// at most [`blob::MAX_INT8_INPUTS`] products of magnitude `<= 128 L < 2^22` (`from_layer`
    /// refuses wider layers). Other i16 values wrap, never panic.
    ///
    /// Uses the target's kernel, [`INT8_KERNEL`]: [`Self::accumulate_lanes`] on x86 and other
    /// wide-SIMD targets, [`Self::accumulate_pairs`] on Arm with the DSP extension (the
    /// Cortex-M4F), [`Self::accumulate_rows`] on other 32-bit Arm. All three give the same
    /// integers.
    #[inline]
    pub fn accumulate(&self, xq: &[i16; IN]) -> [i32; OUT] {
        self.accumulate_for(&Acts::new(xq), INT8_KERNEL)
    }

    /// [`Self::accumulate`] with `kernel`.
    #[inline(always)]
    fn accumulate_for(&self, x: &Acts<IN>, kernel: Int8Kernel) -> [i32; OUT] {
        match kernel {
            Int8Kernel::Lanes => self.accumulate_lanes(&x.q),
            Int8Kernel::Rows => self.accumulate_rows(&x.q),
            Int8Kernel::Pairs => {
                let mut acc = [0i32; OUT];
                self.map_paired(x, &mut acc, |a, _| a);
                acc
            }
        }
    }

    /// [`Self::accumulate`] with the pair kernel.
    pub fn accumulate_pairs(&self, xq: &[i16; IN]) -> [i32; OUT] {
        self.accumulate_for(&Acts::new(xq), Int8Kernel::Pairs)
    }

    /// The pair kernel, with each output finished as soon as its rows are summed:
    /// `out[j] = f(acc[j], input_scale * ws[j])`, `acc[j]` the accumulator with the bias added
    /// (saturating). No accumulator array, no separate pass.
    ///
    /// Two row pairs ([`INT8_ROWS`] rows) per pass: per word of a pair (two inputs, each an i16
    /// `h = 256 b + a + 128`) and the word of the two activations, one `smlad` adds `h . x` to
    /// the pair's raw sum and one `sxtb16` (`ror #8`) + `smlad` adds `(h >> 8) . x = b . x` to
    /// its high sum ([`pair_mac`]); then row `2p + 1` is the high sum and row `2p` is
    /// [`unpair`]ed from both. The last `OUT % 4` rows take one pair and the odd plain row.
    #[inline(always)]
    fn map_paired<T>(&self, x: &Acts<IN>, out: &mut [T; OUT], f: impl Fn(i32, f32) -> T) {
        let s_in = self.input_scale;
        let finish = |a: i32, b: &[u8], w: &[u8]| f(a.saturating_add(i32_le(b)), s_in * f32_le(w));
        // Indexed rather than zipped iterators: the `asm!` block takes every core register, and
        // fewer live values around it mean fewer spills.
        let groups = OUT >> INT8_ROWS.trailing_zeros();
        for k in 0..groups {
            let (Some(block), Some(b), Some(w), Some(g)) = (
                self.weights.get(k * INT8_ROWS * IN..(k + 1) * INT8_ROWS * IN),
                self.bias.get(4 * INT8_ROWS * k..4 * INT8_ROWS * (k + 1)),
                self.weight_scales.get(4 * INT8_ROWS * k..4 * INT8_ROWS * (k + 1)),
                out.get_mut(INT8_ROWS * k..INT8_ROWS * (k + 1)),
            ) else {
                break;
            };
            let [raw0, high0, raw1, high1] = dot2_pairs(x, block);
            if let ([g0, g1, g2, g3], [b0, b1, b2, b3], [w0, w1, w2, w3]) =
                (g, b.as_chunks::<4>().0, w.as_chunks::<4>().0)
            {
                *g0 = finish(unpair(raw0, high0, x.sum), b0, w0);
                *g1 = finish(high0, b1, w1);
                *g2 = finish(unpair(raw1, high1, x.sum), b2, w2);
                *g3 = finish(high1, b3, w3);
            }
        }
        let done = INT8_ROWS * groups;
        let (Some(rest), Some(weights), Some(biases), Some(scales)) = (
            out.get_mut(done..),
            self.weights.get(done * IN..),
            self.bias.get(4 * done..),
            self.weight_scales.get(4 * done..),
        ) else {
            return;
        };
        // At most one more pair (`OUT % 4 >= 2`), then the odd row.
        let mut rows = rest.iter_mut().zip(biases.chunks_exact(4)).zip(scales.chunks_exact(4));
        let mut pairs = weights.chunks_exact(2 * IN);
        if let Some(pair) = pairs.next() {
            let (raw, high) = dot1_pair_words(&x.q, pair);
            if let Some(((o, b), w)) = rows.next() {
                *o = finish(unpair(raw, high, x.sum), b, w);
            }
            if let Some(((o, b), w)) = rows.next() {
                *o = finish(high, b, w);
            }
        }
        if let Some(((o, b), w)) = rows.next() {
            *o = finish(dot1(&x.q, pairs.remainder()), b, w);
        }
    }

    /// [`Self::accumulate`] decoding each byte of a pair (row `2p`'s minus 128, row `2p + 1`'s
    /// as i8) into [`INT8_LANES`] independent i32 lanes per row: a fixed-width block LLVM maps
    /// onto whole vector registers. On x86-64 with AVX2 (found at run time) the kernel of
    /// `policy/x86.rs` runs instead: four pairs per activation load, `vpmaddwd` of the pair's
    /// i16 and of their high bytes, the same integers.
    pub fn accumulate_lanes(&self, xq: &[i16; IN]) -> [i32; OUT] {
        let mut acc = [0i32; OUT];
        #[cfg(target_arch = "x86_64")]
        let done = super::x86::int8_dots(self.weights, xq, &mut acc);
        #[cfg(not(target_arch = "x86_64"))]
        let done = false;
        if !done {
            pairs_decoded(xq, self.weights, &mut acc);
        }
        for (a, c) in acc.iter_mut().zip(self.bias.chunks_exact(4)) {
            *a = a.saturating_add(i32_le(c));
        }
        acc
    }

    /// [`Self::accumulate`], two row pairs per pass with one scalar accumulator per row, each
    /// byte decoded as in [`Self::accumulate_lanes`], so every activation load serves four
    /// rows (the Cortex-M4 form without the DSP extension).
    pub fn accumulate_rows(&self, xq: &[i16; IN]) -> [i32; OUT] {
        let mut acc = [0i32; OUT];
        let mut blocks = self.weights.chunks_exact(INT8_ROWS * IN);
        let mut groups = acc.chunks_exact_mut(INT8_ROWS);
        for (g, block) in groups.by_ref().zip(blocks.by_ref()) {
            let (p0, p1) = block.split_at(2 * IN);
            for (a, s) in g.iter_mut().zip(dot2_pairs_decoded(xq, p0, p1)) {
                *a = s;
            }
        }
        pairs_decoded(xq, blocks.remainder(), groups.into_remainder());
        for (a, c) in acc.iter_mut().zip(self.bias.chunks_exact(4)) {
            *a = a.saturating_add(i32_le(c));
        }
        acc
    }

    /// The dequantized pre-activation `(bias[j] + sum_i w[j][i] xq[i]) * input_scale * ws[j]`.
    pub fn forward(&self, xq: &[i16; IN]) -> [f32; OUT] {
        self.forward_for(&Acts::new(xq), INT8_KERNEL)
    }

    /// `acc[j] * (input_scale * ws[j])`.
    #[inline(always)]
    fn dequantize(&self, acc: &[i32; OUT]) -> [f32; OUT] {
        let mut y = [0.0f32; OUT];
        for ((yj, &a), c) in y.iter_mut().zip(acc.iter()).zip(self.weight_scales.chunks_exact(4)) {
            *yj = a as f32 * (self.input_scale * f32_le(c));
        }
        y
    }

    /// [`Self::forward`] with `kernel`.
    #[inline(always)]
    fn forward_for(&self, x: &Acts<IN>, kernel: Int8Kernel) -> [f32; OUT] {
        if kernel == Int8Kernel::Pairs {
            let mut y = [0.0f32; OUT];
            self.map_paired(x, &mut y, |a, s| a as f32 * s);
            return y;
        }
        self.dequantize(&self.accumulate_for(x, kernel))
    }

    /// [`Self::forward_relu_into`] into an array not initialized yet, returned initialized: on
    /// the Cortex-M4F the whole-layer kernel (`arm::int8_relu_layer_fresh`, the pair kernel's
    /// integers and finish) writes it whole, so it is never zeroed first.
    #[inline(always)]
    pub(super) fn forward_relu_fresh<'y>(
        &self,
        x: &Acts<IN>,
        kernel: Int8Kernel,
        y: &'y mut MaybeUninit<[f32; OUT]>,
    ) -> &'y mut [f32; OUT] {
        #[cfg(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"))]
        if kernel == Int8Kernel::Pairs {
            return match int8_relu_layer_fresh(x, self.weights, self.bias, self.weight_scales, self.input_scale, y) {
                Ok(done) => done,
                Err(y) => self.relu_rows_fresh(x, y),
            };
        }
        let y = y.write([0.0f32; OUT]);
        self.forward_relu_into(x, kernel, y);
        y
    }

    /// Where the whole-layer kernel declines (a blob stored unaligned): the scalar rows kernel,
    /// the same integers. Not inlined, so that neither its arrays on the stack nor a second copy
    /// of the pair kernel's unrolled block in flash weigh on the flight path.
    #[cfg(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"))]
    #[inline(never)]
    fn relu_rows_fresh<'y>(&self, x: &Acts<IN>, y: &'y mut MaybeUninit<[f32; OUT]>) -> &'y mut [f32; OUT] {
        let y = y.write([0.0f32; OUT]);
        self.forward_relu_into(x, Int8Kernel::Rows, y);
        y
    }

    /// `relu` of [`Self::forward`] with `kernel` into `y` (every element overwritten): the
    /// hidden layer as the network flies it, the pair kernel applying the ReLU to each output
    /// as it is dequantized.
    #[inline(always)]
    pub(super) fn forward_relu_into(&self, x: &Acts<IN>, kernel: Int8Kernel, y: &mut [f32; OUT]) {
        if kernel == Int8Kernel::Pairs {
            // The ReLU's 0 from a register: as a constant, LLVM would load it from a literal
            // pool, which it places beyond reach of the load, mis-sizing the pair kernel's
            // `.rept` block (an assembler error).
            let zero = core::hint::black_box(0.0f32);
            self.map_paired(x, y, |a, s| relu_to(a as f32 * s, zero));
            return;
        }
        *y = self.dequantize(&self.accumulate_for(x, kernel));
        y.iter_mut().for_each(|v| *v = relu(*v));
    }
}

/// Row `2p`'s dot product from its pair's sums: `raw = sum_i (256 b_i + a_i + 128) x_i` and
/// `high = sum_i b_i x_i`, so `sum_i a_i x_i = raw - 256 high - 128 sum_i x_i`. Wrapping, and
/// exact: the true value fits in i32 (see [`DenseInt8::accumulate`]), so it is what the
/// arithmetic modulo 2^32 gives.
#[inline(always)]
pub(super) fn unpair(raw: i32, high: i32, sum: i32) -> i32 {
    raw.wrapping_sub(high.wrapping_mul(256))
        .wrapping_sub(sum.wrapping_mul(128))
}

/// Which integer kernel computes the int8 layers' dot products (all give the same integers).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Int8Kernel {
    /// [`DenseInt8::accumulate_lanes`]: wide SIMD (x86).
    Lanes,
    /// [`DenseInt8::accumulate_rows`]: scalar, several rows per pass (32-bit Arm without DSP).
    Rows,
    /// [`DenseInt8::accumulate_pairs`]: a pair's two rows from two i16 x i16 sums (`smlad`);
    /// `asm!` on Arm with the DSP extension, a portable emulation of the same steps elsewhere
    /// (for tests).
    Pairs,
}

/// The kernel [`Mlp::forward`](super::Mlp::forward) and [`DenseInt8::accumulate`] use on this
/// target.
pub const INT8_KERNEL: Int8Kernel = if ARM_ASM {
    Int8Kernel::Pairs
} else if cfg!(target_arch = "arm") {
    Int8Kernel::Rows
} else {
    Int8Kernel::Lanes
};

/// Quantized activations and their sum (wrapping), aligned so that the pair kernel may load
/// them several words at a time (`ldm` needs word alignment on the Cortex-M4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(C, align(8))]
pub(super) struct Acts<const N: usize> {
    /// The levels, in input order.
    pub(super) q: [i16; N],
    /// Their sum, which [`unpair`] needs.
    pub(super) sum: i32,
}

impl<const N: usize> Acts<N> {
    fn new(q: &[i16; N]) -> Self {
        Self {
            q: *q,
            sum: q.iter().fold(0i32, |s, &v| s.wrapping_add(i32::from(v))),
        }
    }
}

/// A u32 from 4 little-endian bytes.
#[inline(always)]
fn u32_le(c: &[u8]) -> u32 {
    <[u8; 4]>::try_from(c).map_or(0, u32::from_le_bytes)
}

/// Packs two i16 as the low and high halves of a word (a 32-bit load of two adjacent i16).
#[inline(always)]
fn pack(lo: i16, hi: i16) -> u32 {
    u32::from(lo as u16) | (u32::from(hi as u16) << 16)
}

/// `(raw + lo(w) lo(x) + hi(w) hi(x), high + (lo(w) >> 8) lo(x) + (hi(w) >> 8) hi(x))`
/// (wrapping), `lo`/`hi` the signed halves of a word: a word of a pair (two inputs) against
/// the word of their activations. The portable emulation of `arm::pair_mac` (`policy/arm.rs`),
/// whose `smlad`, `sxtb16 ror #8`, `smlad` compute exactly this.
#[cfg(not(all(target_arch = "arm", target_os = "none", target_abi = "eabihf")))]
#[inline(always)]
fn pair_mac(raw: i32, high: i32, w: u32, x: u32) -> (i32, i32) {
    let lo = |p: u32| i32::from(p as u16 as i16);
    let hi = |p: u32| i32::from((p >> 16) as u16 as i16);
    // Each product is below 2^30 in magnitude, each pair's sum below 2^31: only the sums wrap.
    let raw = raw.wrapping_add(lo(w) * lo(x) + hi(w) * hi(x));
    let high = high.wrapping_add((lo(w) >> 8) * lo(x) + (hi(w) >> 8) * hi(x));
    (raw, high)
}

/// Product of a level and a stored byte, exact in i32.
#[inline(always)]
fn mac(acc: i32, x: i16, w: i32) -> i32 {
    acc.wrapping_add(i32::from(x) * w)
}

/// The two weights of a pair at one input: `(a, b)` from the bytes `(a + 128, b)`.
#[inline(always)]
fn decode_pair(lo: u8, hi: u8) -> (i32, i32) {
    (i32::from(lo) - 128, i32::from(hi as i8))
}

/// A plain i8 row against the activations (the odd last row).
#[inline(always)]
fn dot1(x: &[i16], w: &[u8]) -> i32 {
    x.iter()
        .zip(w.iter())
        .fold(0i32, |s, (&a, &b)| mac(s, a, i32::from(b as i8)))
}

/// A pair's two rows, decoded byte by byte, over [`INT8_LANES`] independent lanes each, then
/// the remainder.
#[inline(always)]
fn dot_pair_lanes(x: &[i16], pair: &[u8]) -> (i32, i32) {
    let mut la = [0i32; INT8_LANES];
    let mut lb = [0i32; INT8_LANES];
    let mut xc = x.chunks_exact(INT8_LANES);
    let mut wc = pair.chunks_exact(2 * INT8_LANES);
    for (xs, ws) in xc.by_ref().zip(wc.by_ref()) {
        for (((a, b), &xi), w) in la.iter_mut().zip(lb.iter_mut()).zip(xs).zip(ws.chunks_exact(2)) {
            if let [lo, hi] = w {
                let (wa, wb) = decode_pair(*lo, *hi);
                *a = mac(*a, xi, wa);
                *b = mac(*b, xi, wb);
            }
        }
    }
    let (mut a, mut b) = (
        la.iter().fold(0i32, |s, &l| s.wrapping_add(l)),
        lb.iter().fold(0i32, |s, &l| s.wrapping_add(l)),
    );
    for (&xi, w) in xc.remainder().iter().zip(wc.remainder().chunks_exact(2)) {
        if let [lo, hi] = w {
            let (wa, wb) = decode_pair(*lo, *hi);
            a = mac(a, xi, wa);
            b = mac(b, xi, wb);
        }
    }
    (a, b)
}

/// `acc[j]` = row `j`'s dot product for the rows of `weights` (whole pairs, then the odd plain
/// row), each pair by [`dot_pair_lanes`]: the lanes kernel's whole layer, the rows kernel's last
/// `OUT % 4` rows.
#[inline(always)]
fn pairs_decoded<const IN: usize>(xq: &[i16; IN], weights: &[u8], acc: &mut [i32]) {
    let mut pairs = weights.chunks_exact(2 * IN);
    let mut rows = acc.chunks_exact_mut(2);
    for (r, pair) in rows.by_ref().zip(pairs.by_ref()) {
        if let [a, b] = r {
            (*a, *b) = dot_pair_lanes(xq, pair);
        }
    }
    for a in rows.into_remainder() {
        *a = dot1(xq, pairs.remainder());
    }
}

/// Two pairs (four rows), decoded byte by byte, one scalar accumulator per row.
#[inline(always)]
fn dot2_pairs_decoded(x: &[i16], p0: &[u8], p1: &[u8]) -> [i32; 4] {
    let mut s = [0i32; 4];
    for ((&xi, w0), w1) in x.iter().zip(p0.chunks_exact(2)).zip(p1.chunks_exact(2)) {
        if let ([l0, h0], [l1, h1]) = (w0, w1) {
            let (a0, b0) = decode_pair(*l0, *h0);
            let (a1, b1) = decode_pair(*l1, *h1);
            let [s0, s1, s2, s3] = s;
            s = [mac(s0, xi, a0), mac(s1, xi, b0), mac(s2, xi, a1), mac(s3, xi, b1)];
        }
    }
    s
}

/// One pair's raw and high sums over all inputs, a word (two inputs) at a time with
/// [`pair_mac`], then the odd input if any.
#[inline(always)]
pub(super) fn dot1_pair_words(x: &[i16], pair: &[u8]) -> (i32, i32) {
    let (mut raw, mut high) = (0i32, 0i32);
    let xg = x.chunks_exact(2);
    let wg = pair.chunks_exact(4);
    let (x_tail, w_tail) = (xg.remainder(), wg.remainder());
    for (xs, w) in xg.zip(wg) {
        if let [a, b] = xs {
            (raw, high) = pair_mac(raw, high, u32_le(w), pack(*a, *b));
        }
    }
    if let ([xi], [lo, hi]) = (x_tail, w_tail) {
        let h = i32::from(i16::from_le_bytes([*lo, *hi]));
        raw = mac(raw, *xi, h);
        high = mac(high, *xi, h >> 8);
    }
    (raw, high)
}

/// Two pairs (`block`: `4 * IN` bytes, pair 1 at byte `2 * IN`): `[raw0, high0, raw1, high1]`.
/// The portable form of `arm::dot2_pairs` (`policy/arm.rs`).
#[cfg(not(all(target_arch = "arm", target_os = "none", target_abi = "eabihf")))]
#[inline(always)]
fn dot2_pairs<const IN: usize>(x: &Acts<IN>, block: &[u8]) -> [i32; 4] {
    let (p0, p1) = block.split_at(block.len().min(2 * IN));
    let p1 = p1.get(..2 * IN).unwrap_or(p1);
    let (raw0, high0) = dot1_pair_words(&x.q, p0);
    let (raw1, high1) = dot1_pair_words(&x.q, p1);
    [raw0, high0, raw1, high1]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both quantizers and both ReLU forms at one point.
    fn check(x: f32, scale: f32) {
        let want = quantize_magic(x, scale);
        let l = i32::from(ACTIVATION_LEVELS);
        assert_eq!(
            quantize_trunc(x, scale, -l),
            want,
            "x {x:e} ({:#010x}) scale {scale:e}",
            x.to_bits()
        );
        assert_eq!(
            quantize_trunc(x, scale, 0),
            quantize_magic(relu(x), scale),
            "relu: x {x:e} ({:#010x}) scale {scale:e}",
            x.to_bits()
        );
    }

    #[test]
    fn quantizers_agree_on_every_float_near_the_rounding_edges() {
        // Every f32 of magnitude in [2^-2, 2^2), both signs, at scale 1 (exact quotient):
        // the largest float below 0.5, every tie and its neighbours below 4.
        for bits in 0.25f32.to_bits()..4.0f32.to_bits() {
            let x = f32::from_bits(bits);
            check(x, 1.0);
            check(-x, 1.0);
        }
    }

    #[test]
    fn quantizers_agree_around_ties_extremes_and_random_values() {
        // Ties and their neighbours (4 ulps each way) for every half-integer past the clamp.
        let mut k = 0.5f32;
        while k < 34_000.0 {
            for t in [k, -k] {
                let (mut up, mut down) = (t, t);
                for _ in 0..5 {
                    check(up, 1.0);
                    check(down, 1.0);
                    up = f32::from_bits(up.to_bits() + 1);
                    down = f32::from_bits(down.to_bits() - 1);
                }
            }
            k += 0.5;
        }
        let scales = [
            1.0f32,
            0.5,
            0.013,
            3.7e-3,
            0.25,
            1e-30,
            7.5e30,
            f32::MIN_POSITIVE,
            1e-45,
        ];
        let special = [
            0.0f32,
            -0.0,
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            f32::MIN,
            f32::MIN_POSITIVE,
            1e-45,
            2_147_483_520.0,
            2_147_483_648.0,
            -2_147_483_648.0,
            -2_147_483_904.0,
            16_777_217.0,
            8_388_607.5,
            32_766.5,
            32_767.5,
            -32_767.5,
            0.499_999_97,
            -0.499_999_97,
        ];
        for &x in &special {
            for &s in &scales {
                check(x, s);
            }
        }
        // Random bit patterns (NaNs, infinities, subnormals) at every scale (SplitMix64).
        let mut state = 0x5eed_u64;
        let mut next = || {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        for _ in 0..400_000 {
            let x = f32::from_bits(next() as u32);
            for &s in &scales {
                check(x, s);
            }
        }
    }
}
