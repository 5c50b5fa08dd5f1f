//! The int8 kernels: a dense layer's exact i32 dot products against 16-bit quantized
//! activations in three kernels giving the same integers ([`Int8Kernel`]), the requantization
//! between layers ([`quantize`], [`quantize_relu`]) and the pair order of the Arm DSP kernel
//! (see the module doc of [`super`]).

use shared::blob::{self, LayerBlob, ACTIVATION_LEVELS};

#[cfg(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"))]
use super::arm::{dot4_pairs, pair_mac};
use super::{check_len, check_shape, f32_le, i32_le, relu, LayerArray, PolicyError, ARM_ASM};

/// Output rows computed per pass over the input by [`DenseInt8::accumulate_rows`].
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
/// `weights`: `IN * OUT` i8 output-major (`w[j * IN + i]`); `bias`: `OUT` i32 LE in units of
/// `input_scale * weight_scale[j]`; `weight_scales`: `OUT` f32 LE.
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

    /// `relu(y)` quantized like [`Self::quantize_input`] ([`quantize_relu`]), in `kernel`'s
    /// activation order: the int8 layer after the f32 first layer takes its pre-activation.
    #[inline(always)]
    pub(super) fn quantize_relu_input_for(&self, y: &[f32; IN], kernel: Int8Kernel) -> Acts<IN> {
        let mut q = Acts([0i16; IN]);
        for (qi, &yi) in q.0.iter_mut().zip(y.iter()) {
            *qi = quantize_relu(yi, self.input_scale);
        }
        if kernel == Int8Kernel::Pairs {
            to_pair_order(&mut q.0);
        }
        q
    }

    /// The integer accumulators `bias[j] + sum_i w[j][i] * xq[i]`, saturating at the bias add.
    /// For `xq` in `-L..=L` (what [`Self::quantize_input`] gives) the dot product is exact:
    /// at most [`blob::MAX_INT8_INPUTS`] products of magnitude `<= 128 L < 2^22` (`from_layer`
    /// refuses wider layers). Other i16 values wrap, never panic.
    ///
    /// Uses the target's kernel, [`INT8_KERNEL`]: [`Self::accumulate_lanes`] on x86 and other
    /// wide-SIMD targets, [`Self::accumulate_pairs`] on Arm with the DSP extension (the
    /// Cortex-M4F), [`Self::accumulate_rows`] on other 32-bit Arm, where [`INT8_LANES`]
    /// accumulators would not fit in registers. All three give the same integers.
    #[inline]
    pub fn accumulate(&self, xq: &[i16; IN]) -> [i32; OUT] {
        match INT8_KERNEL {
            Int8Kernel::Lanes => self.accumulate_lanes(xq),
            Int8Kernel::Rows => self.accumulate_rows(xq),
            Int8Kernel::Pairs => self.accumulate_pairs(xq),
        }
    }

    /// [`Self::accumulate`] with `kernel`, `xk` in that kernel's activation order.
    #[inline(always)]
    fn accumulate_for(&self, xk: &Acts<IN>, kernel: Int8Kernel) -> [i32; OUT] {
        match kernel {
            Int8Kernel::Lanes => self.accumulate_lanes(&xk.0),
            Int8Kernel::Rows => self.accumulate_rows(&xk.0),
            Int8Kernel::Pairs => self.accumulate_paired(xk),
        }
    }

    /// [`Self::accumulate`] with the pair kernel: `xq` is put in pair order
    /// ([`to_pair_order`]) and handed to it. In flight the activations are quantized straight
    /// into pair order, so this copy is only made here.
    pub fn accumulate_pairs(&self, xq: &[i16; IN]) -> [i32; OUT] {
        let mut xp = Acts(*xq);
        to_pair_order(&mut xp.0);
        self.accumulate_paired(&xp)
    }

    /// The pair kernel, `xp` in pair order (see [`Self::map_paired`]).
    fn accumulate_paired(&self, xp: &Acts<IN>) -> [i32; OUT] {
        let mut acc = [0i32; OUT];
        self.map_paired(xp, &mut acc, |a, _| a);
        acc
    }

    /// The pair kernel, `xp` in pair order, with each output finished as soon as its group of
    /// rows is summed: `out[j] = f(acc[j], input_scale * ws[j])`, `acc[j]` the accumulator
    /// with the bias added (saturating). No accumulator array, no separate pass.
    ///
    /// [`INT8_ROWS`] rows per pass; per group of 4 inputs, two words of activation pairs
    /// `(x0, x2)`, `(x1, x3)` shared by the rows, and per row one word of 4 weights split by
    /// `sxtb16` into the matching i16 pairs and multiply-accumulated two products at a time by
    /// `smlad` ([`pair_mac`]). The last `IN % 4` inputs (natural order) and `OUT % 4` rows take
    /// the scalar path.
    #[inline(always)]
    fn map_paired<T>(&self, xp: &Acts<IN>, out: &mut [T; OUT], f: impl Fn(i32, f32) -> T) {
        let s_in = self.input_scale;
        let finish = |a: i32, b: &[u8], w: &[u8]| f(a.saturating_add(i32_le(b)), s_in * f32_le(w));
        let mut blocks = self.weights.chunks_exact(INT8_ROWS * IN);
        let mut biases = self.bias.chunks_exact(4 * INT8_ROWS);
        let mut scales = self.weight_scales.chunks_exact(4 * INT8_ROWS);
        let mut groups = out.chunks_exact_mut(INT8_ROWS);
        for (((g, block), b), w) in groups
            .by_ref()
            .zip(blocks.by_ref())
            .zip(biases.by_ref())
            .zip(scales.by_ref())
        {
            let [a0, a1, a2, a3] = dot4_pairs(xp, block);
            if let ([g0, g1, g2, g3], [b0, b1, b2, b3], [w0, w1, w2, w3]) =
                (g, b.as_chunks::<4>().0, w.as_chunks::<4>().0)
            {
                *g0 = finish(a0, b0, w0);
                *g1 = finish(a1, b1, w1);
                *g2 = finish(a2, b2, w2);
                *g3 = finish(a3, b3, w3);
            }
        }
        let rest = blocks
            .remainder()
            .chunks_exact(IN)
            .zip(biases.remainder().chunks_exact(4))
            .zip(scales.remainder().chunks_exact(4));
        for (o, ((row, b), w)) in groups.into_remainder().iter_mut().zip(rest) {
            *o = finish(dot1_pairs(&xp.0, row), b, w);
        }
    }

    /// [`Self::accumulate`], one row at a time with [`INT8_LANES`] independent i32 lanes:
    /// a fixed-width block LLVM maps onto whole vector registers (`pmaddwd` with the baseline
    /// SSE2). On x86-64 with AVX2 (found at run time) the explicit kernel of `policy/x86.rs`
    /// runs instead: 8 rows per activation load, the same integers.
    pub fn accumulate_lanes(&self, xq: &[i16; IN]) -> [i32; OUT] {
        let mut acc = [0i32; OUT];
        #[cfg(target_arch = "x86_64")]
        if super::x86::int8_dots(self.weights, xq, &mut acc) {
            for (a, c) in acc.iter_mut().zip(self.bias.chunks_exact(4)) {
                *a = a.saturating_add(i32_le(c));
            }
            return acc;
        }
        for ((a, row), c) in acc
            .iter_mut()
            .zip(self.weights.chunks_exact(IN))
            .zip(self.bias.chunks_exact(4))
        {
            *a = dot_lanes(xq, row).saturating_add(i32_le(c));
        }
        acc
    }

    /// [`Self::accumulate`], [`INT8_ROWS`] rows per pass with one scalar accumulator each, so
    /// every activation load serves several rows (the Cortex-M4 form: `ldrsb` + `smlabb`).
    pub fn accumulate_rows(&self, xq: &[i16; IN]) -> [i32; OUT] {
        let mut acc = [0i32; OUT];
        let mut rows = self.weights.chunks_exact(IN);
        let mut groups = acc.chunks_exact_mut(INT8_ROWS);
        for g in groups.by_ref() {
            let (Some(r0), Some(r1), Some(r2), Some(r3)) = (rows.next(), rows.next(), rows.next(), rows.next()) else {
                break;
            };
            let sums = dot4(xq, r0, r1, r2, r3);
            for (a, s) in g.iter_mut().zip(sums) {
                *a = s;
            }
        }
        for (a, row) in groups.into_remainder().iter_mut().zip(rows) {
            *a = dot1(xq, row);
        }
        for (a, c) in acc.iter_mut().zip(self.bias.chunks_exact(4)) {
            *a = a.saturating_add(i32_le(c));
        }
        acc
    }

    /// The dequantized pre-activation `(bias[j] + sum_i w[j][i] xq[i]) * input_scale * ws[j]`.
    pub fn forward(&self, xq: &[i16; IN]) -> [f32; OUT] {
        self.dequantize(&self.accumulate(xq))
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

    /// [`Self::forward`], `xk` in `kernel`'s order.
    #[inline(always)]
    pub(super) fn forward_for(&self, xk: &Acts<IN>, kernel: Int8Kernel) -> [f32; OUT] {
        if kernel == Int8Kernel::Pairs {
            let mut y = [0.0f32; OUT];
            self.map_paired(xk, &mut y, |a, s| a as f32 * s);
            return y;
        }
        self.dequantize(&self.accumulate_for(xk, kernel))
    }
}

/// Which integer kernel computes the int8 layers' dot products (all give the same integers).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Int8Kernel {
    /// [`DenseInt8::accumulate_lanes`]: wide SIMD (x86).
    Lanes,
    /// [`DenseInt8::accumulate_rows`]: scalar, several rows per pass (32-bit Arm without DSP).
    Rows,
    /// [`DenseInt8::accumulate_pairs`]: two i16 x i8 products per instruction (`smlad`) with the
    /// activations in pair order ([`to_pair_order`]); `asm!` on Arm with the DSP extension, a
    /// portable emulation of the same steps elsewhere (for tests).
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

/// Puts activations in the pair kernel's order, in place: in each whole group of 4,
/// `(x0, x1, x2, x3)` becomes `(x0, x2, x1, x3)`, so the group's two words are the pairs
/// `(x0, x2)` and `(x1, x3)` that `sxtb16` makes of a word of weights (bytes 0, 2 and 1, 3).
/// The last `len % 4` values stay. The order is its own inverse.
pub fn to_pair_order(x: &mut [i16]) {
    for g in x.chunks_exact_mut(4) {
        if let [_, b, c, _] = g {
            core::mem::swap(b, c);
        }
    }
}

/// Quantized activations in a kernel's order, aligned so that the pair kernel may load them two
/// words at a time (`ldrd` needs word alignment on the Cortex-M4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(C, align(8))]
pub(super) struct Acts<const N: usize>(pub(super) [i16; N]);

/// Packs two i16 as the low and high halves of a word (a 32-bit load of two adjacent i16).
#[inline(always)]
fn pack(lo: i16, hi: i16) -> u32 {
    u32::from(lo as u16) | (u32::from(hi as u16) << 16)
}

/// A u32 from 4 little-endian bytes.
#[inline(always)]
fn u32_le(c: &[u8]) -> u32 {
    <[u8; 4]>::try_from(c).map_or(0, u32::from_le_bytes)
}

/// `acc + w0 * lo(xe) + w2 * hi(xe) + w1 * lo(xo) + w3 * hi(xo)` (wrapping), `w0..w3` the
/// signed bytes of `w` (little endian), `lo`/`hi` the signed halves of a word: the portable
/// emulation of `arm::pair_mac` (`policy/arm.rs`)'s `sxtb16` + `smlad` steps, for targets without them.
#[cfg(not(all(target_arch = "arm", target_os = "none", target_abi = "eabihf")))]
#[inline(always)]
fn pair_mac(acc: i32, w: u32, xe: u32, xo: u32) -> i32 {
    let [w0, w1, w2, w3] = w.to_le_bytes().map(|b| i32::from(b as i8));
    let lo = |p: u32| i32::from(p as u16 as i16);
    let hi = |p: u32| i32::from((p >> 16) as u16 as i16);
    // Each product is below 2^22 in magnitude, each pair below 2^23: only the sums wrap.
    acc.wrapping_add(w0 * lo(xe) + w2 * hi(xe))
        .wrapping_add(w1 * lo(xo) + w3 * hi(xo))
}

/// `i16`-widened product, exact in i32.
#[inline(always)]
fn mac(acc: i32, x: i16, w: u8) -> i32 {
    acc.wrapping_add(i32::from(x) * i32::from(i16::from(w as i8)))
}

/// Dot product over [`INT8_LANES`] independent lanes, then the remainder.
#[inline(always)]
fn dot_lanes(x: &[i16], w: &[u8]) -> i32 {
    let mut lanes = [0i32; INT8_LANES];
    let mut xc = x.chunks_exact(INT8_LANES);
    let mut wc = w.chunks_exact(INT8_LANES);
    for (xs, ws) in xc.by_ref().zip(wc.by_ref()) {
        for ((l, &a), &b) in lanes.iter_mut().zip(xs).zip(ws) {
            *l = mac(*l, a, b);
        }
    }
    let s = lanes.iter().fold(0i32, |s, &l| s.wrapping_add(l));
    dot1(xc.remainder(), wc.remainder()).wrapping_add(s)
}

#[inline(always)]
fn dot1(x: &[i16], w: &[u8]) -> i32 {
    x.iter().zip(w.iter()).fold(0i32, |s, (&a, &b)| mac(s, a, b))
}

/// Four rows against one activation vector, two inputs per step (each activation load serves
/// eight multiply-accumulates), then the odd input if any.
#[inline(always)]
fn dot4(x: &[i16], r0: &[u8], r1: &[u8], r2: &[u8], r3: &[u8]) -> [i32; 4] {
    let mut s = [0i32; 4];
    let pairs = x
        .chunks_exact(2)
        .zip(r0.chunks_exact(2))
        .zip(r1.chunks_exact(2))
        .zip(r2.chunks_exact(2))
        .zip(r3.chunks_exact(2));
    for ((((xs, w0), w1), w2), w3) in pairs {
        if let ([a, b], [p0, q0], [p1, q1], [p2, q2], [p3, q3]) = (xs, w0, w1, w2, w3) {
            let [s0, s1, s2, s3] = s;
            s = [
                mac(mac(s0, *a, *p0), *b, *q0),
                mac(mac(s1, *a, *p1), *b, *q1),
                mac(mac(s2, *a, *p2), *b, *q2),
                mac(mac(s3, *a, *p3), *b, *q3),
            ];
        }
    }
    if x.len() % 2 == 1 {
        if let Some(a) = x.last() {
            for (sk, r) in s.iter_mut().zip([r0, r1, r2, r3]) {
                if let Some(w) = r.last() {
                    *sk = mac(*sk, *a, *w);
                }
            }
        }
    }
    s
}

/// Four rows (`block`: `4 * IN` bytes, rows at stride `IN`) against activations in pair order:
/// per group of 4 inputs, two activation words shared by the rows and one weight word per row;
/// then the last `IN % 4` inputs. The portable form of `arm::dot4_pairs` (`policy/arm.rs`).
#[cfg(not(all(target_arch = "arm", target_os = "none", target_abi = "eabihf")))]
#[inline(always)]
fn dot4_pairs<const IN: usize>(xp: &Acts<IN>, block: &[u8]) -> [i32; 4] {
    let mut rows = block.chunks_exact(IN);
    let (Some(r0), Some(r1), Some(r2), Some(r3)) = (rows.next(), rows.next(), rows.next(), rows.next()) else {
        return [0; 4];
    };
    let xp = &xp.0;
    let mut s = [0i32; 4];
    let (c0, c1, c2, c3) = (
        r0.chunks_exact(4),
        r1.chunks_exact(4),
        r2.chunks_exact(4),
        r3.chunks_exact(4),
    );
    let xg = xp.chunks_exact(4);
    let tails = [c0.remainder(), c1.remainder(), c2.remainder(), c3.remainder()];
    let x_tail = xg.remainder();
    for ((((xs, w0), w1), w2), w3) in xg.zip(c0).zip(c1).zip(c2).zip(c3) {
        if let [a, b, c, d] = xs {
            let (xe, xo) = (pack(*a, *b), pack(*c, *d));
            let [s0, s1, s2, s3] = s;
            s = [
                pair_mac(s0, u32_le(w0), xe, xo),
                pair_mac(s1, u32_le(w1), xe, xo),
                pair_mac(s2, u32_le(w2), xe, xo),
                pair_mac(s3, u32_le(w3), xe, xo),
            ];
        }
    }
    for (sk, t) in s.iter_mut().zip(tails) {
        *sk = sk.wrapping_add(dot1(x_tail, t));
    }
    s
}

/// One row against activations in pair order (the `OUT % 4` last rows).
#[inline(always)]
pub(super) fn dot1_pairs(xp: &[i16], row: &[u8]) -> i32 {
    let mut s = 0i32;
    let wg = row.chunks_exact(4);
    let xg = xp.chunks_exact(4);
    let tail = dot1(xg.remainder(), wg.remainder());
    for (xs, w) in xg.zip(wg) {
        if let [a, b, c, d] = xs {
            s = pair_mac(s, u32_le(w), pack(*a, *b), pack(*c, *d));
        }
    }
    s.wrapping_add(tail)
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
