//! Fixed-size MLP inference in f32 and int8, straight from a weight blob (SPEC section 10).
//!
//! The deployed actor mean heads are 10-256-256-3 (transfer) and 22-256-256-3 (rendezvous):
//! two ReLU hidden layers and a tanh output. Every size is a const generic, so activations live
//! on the stack as fixed arrays and nothing is allocated.
//!
//! **Zero copy.** A layer view ([`DenseF32`], [`DenseInt8`]) keeps the byte slices of its
//! [`LayerBlob`]; the weights are read in place (from flash on the flight computer) and never
//! copied to RAM. Constructors check every size against the const shape, so `forward` has no
//! failure path and cannot panic on any input.
//!
//! **Kernels** (no `unsafe`, no `core::arch`; vectorization is left to LLVM):
//! - f32 (weights input-major, `w[i * OUT + j]`): each input adds `x[i] * row_i` to the output
//!   vector (an axpy, which vectorizes without reassociating floating-point sums). Outputs are
//!   processed in tiles of [`F32_TILE`] whose accumulators stay in registers across all inputs;
//!   a layer narrower than a tile (the 3 action outputs) keeps 8 partial sums over interleaved
//!   inputs instead. A product and a sum are two roundings: Rust never contracts `a * b + c`
//!   into an FMA, and `f32::mul_add` needs `std`.
//! - int8 (weights output-major, `w[j * IN + i]`): the layer input is quantized once to i8
//!   (held widened to i16), then each output is an exact i32 dot product of i16-widened values
//!   (integer sums reassociate freely, so LLVM vectorizes them: `vpmovsxbw` + `vpmaddwd` on
//!   x86). [`DenseInt8::accumulate_lanes`] (x86 and other SIMD targets) keeps [`INT8_LANES`]
//!   independent lanes per row; [`DenseInt8::accumulate_rows`] (32-bit Arm, the Cortex-M4)
//!   runs [`INT8_ROWS`] rows per pass with one scalar accumulator each. The sum plus the i32
//!   bias is rescaled by `input_scale * weight_scale[j]`, the activation is applied in f32 and
//!   the result is quantized with the next layer's `input_scale`:
//!   `q = clamp(round(x / s), -127, 127)`, round half away from zero, computed without
//!   float-to-int casts so it vectorizes.
//!
//! **Non-finite inputs.** [`Mlp::forward`] never panics. If any input is NaN or infinite it
//! returns `[f32::NAN; OUT]` in both precisions, so a corrupt state cannot turn into a plausible
//! thrust command (the guidance step rejects non-finite states before inference anyway). Finite
//! inputs give finite outputs in `[-1, 1]`, except in f32 when an intermediate sum overflows
//! (inputs of order 1e30 and beyond): the output is then `±1` or NaN. The layer kernels
//! themselves are total: NaN propagates through the f32 kernel (the ReLU keeps NaN) and is
//! quantized to 0 by the int8 kernel (infinities saturate to ±127).

use core::fmt;

use shared::blob::{
    self, Activation, BlobError, FeatureLayout, LayerBlob, NetworkBlob, ProblemKind, Quantization, ACTIVATION_LEVELS,
};

/// Outputs per register tile of the f32 kernel (a multiple of 16, the AVX-512 lane count).
pub const F32_TILE: usize = 64;
/// Output rows computed per pass over the input by [`DenseInt8::accumulate_rows`].
pub const INT8_ROWS: usize = 4;
/// Independent i32 lanes of [`DenseInt8::accumulate_lanes`] (two AVX-512 registers).
pub const INT8_LANES: usize = 32;
/// Layers of an [`Mlp`].
pub const MLP_LAYERS: usize = 3;

/// Inputs and outputs of a dense layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LayerShape {
    pub inputs: usize,
    pub outputs: usize,
}

/// Which array of a layer has the wrong length.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LayerArray {
    Weights,
    Bias,
    WeightScales,
}

/// Why a blob cannot be used as a policy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PolicyError {
    /// The bytes are not a valid blob.
    Blob(BlobError),
    /// The blob is for the other problem.
    WrongKind { expected: ProblemKind, found: ProblemKind },
    /// The blob's feature layout does not have the network's input count.
    WrongFeatures {
        expected_inputs: usize,
        found: FeatureLayout,
    },
    /// The network does not have [`MLP_LAYERS`] layers.
    WrongLayerCount { expected: usize, found: usize },
    /// A layer's declared size differs from the compiled network's (`layer` counts from 0).
    WrongShape {
        layer: usize,
        expected: LayerShape,
        found: LayerShape,
    },
    /// A layer's array has the wrong number of bytes for its declared size and quantization.
    WrongArrayLength {
        layer: usize,
        array: LayerArray,
        expected: usize,
        found: usize,
    },
    /// A layer's activation is not the contract's (ReLU hidden, tanh output).
    WrongActivation {
        layer: usize,
        expected: Activation,
        found: Activation,
    },
    /// An int8 layer's input scale is not finite and positive, or a weight scale is not finite.
    BadScale { layer: usize },
    /// An int8 layer has more inputs than its i32 accumulator sums exactly
    /// ([`blob::MAX_INT8_INPUTS`]).
    TooWideForInt8 { layer: usize, inputs: usize },
}

impl PolicyError {
    /// The same error, reported for layer `layer`.
    fn at_layer(self, layer: usize) -> Self {
        match self {
            Self::WrongShape { expected, found, .. } => Self::WrongShape { layer, expected, found },
            Self::WrongArrayLength {
                array, expected, found, ..
            } => Self::WrongArrayLength {
                layer,
                array,
                expected,
                found,
            },
            Self::WrongActivation { expected, found, .. } => Self::WrongActivation { layer, expected, found },
            Self::BadScale { .. } => Self::BadScale { layer },
            Self::TooWideForInt8 { inputs, .. } => Self::TooWideForInt8 { layer, inputs },
            other => other,
        }
    }
}

impl From<BlobError> for PolicyError {
    fn from(e: BlobError) -> Self {
        Self::Blob(e)
    }
}

impl fmt::Display for PolicyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Blob(e) => write!(f, "invalid weight blob: {e}"),
            Self::WrongKind { expected, found } => {
                write!(f, "blob is for {found:?}, expected {expected:?}")
            }
            Self::WrongFeatures { expected_inputs, found } => write!(
                f,
                "feature layout {found:?} has {} inputs, network expects {expected_inputs}",
                found.len()
            ),
            Self::WrongLayerCount { expected, found } => {
                write!(f, "network has {found} layers, expected {expected}")
            }
            Self::WrongShape { layer, expected, found } => write!(
                f,
                "layer {layer} is {}x{}, expected {}x{}",
                found.inputs, found.outputs, expected.inputs, expected.outputs
            ),
            Self::WrongArrayLength {
                layer,
                array,
                expected,
                found,
            } => write!(f, "layer {layer} {array:?} has {found} bytes, expected {expected}"),
            Self::WrongActivation { layer, expected, found } => {
                write!(f, "layer {layer} activation is {found:?}, expected {expected:?}")
            }
            Self::BadScale { layer } => write!(f, "layer {layer} has an invalid scale"),
            Self::TooWideForInt8 { layer, inputs } => write!(
                f,
                "int8 layer {layer} has {inputs} inputs, more than the {} an i32 accumulator sums exactly",
                blob::MAX_INT8_INPUTS
            ),
        }
    }
}

fn check_shape<const IN: usize, const OUT: usize>(layer: &LayerBlob<'_>) -> Result<(), PolicyError> {
    let found = LayerShape {
        inputs: usize::from(layer.inputs),
        outputs: usize::from(layer.outputs),
    };
    let expected = LayerShape {
        inputs: IN,
        outputs: OUT,
    };
    // A zero width is refused even if the blob declares it, so no kernel ever runs on one.
    if found == expected && IN > 0 && OUT > 0 {
        Ok(())
    } else {
        Err(PolicyError::WrongShape {
            layer: 0,
            expected,
            found,
        })
    }
}

fn check_len(array: LayerArray, bytes: &[u8], expected: usize) -> Result<(), PolicyError> {
    if bytes.len() == expected {
        Ok(())
    } else {
        Err(PolicyError::WrongArrayLength {
            layer: 0,
            array,
            expected,
            found: bytes.len(),
        })
    }
}

/// An f32 from 4 little-endian bytes (a plain load once inlined; 0 for a short chunk, which the
/// `chunks_exact(4)` callers never produce).
#[inline(always)]
fn f32_le(c: &[u8]) -> f32 {
    <[u8; 4]>::try_from(c).map_or(0.0, f32::from_le_bytes)
}

/// An i32 from 4 little-endian bytes.
#[inline(always)]
fn i32_le(c: &[u8]) -> i32 {
    <[u8; 4]>::try_from(c).map_or(0, i32::from_le_bytes)
}

/// ReLU that keeps NaN (`max(x, 0)` would turn it into 0).
#[inline(always)]
fn relu(x: f32) -> f32 {
    if x < 0.0 {
        0.0
    } else {
        x
    }
}

/// `1.5 * 2^23`: adding it to a float of magnitude below `2^22` leaves the nearest integer
/// (ties to even) in the low mantissa bits.
const ROUND_MAGIC: f32 = 12_582_912.0;

/// `clamp(round(x / scale), -L, L)` with `L` = [`ACTIVATION_LEVELS`], round half away from
/// zero; NaN gives 0.
///
/// Branch-free and free of float-to-int casts (Rust's saturating `as` does not vectorize):
/// round to nearest even with [`ROUND_MAGIC`], read the integer from the bits, then move exact
/// ties away from zero.
#[inline(always)]
fn quantize(x: f32, scale: f32) -> i16 {
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

/// A dense f32 layer `y = b + W x` viewing its blob arrays in place.
///
/// `weights`: `IN * OUT` f32 LE input-major (`w[i * OUT + j]`); `bias`: `OUT` f32 LE.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DenseF32<'a, const IN: usize, const OUT: usize> {
    weights: &'a [u8],
    bias: &'a [u8],
}

impl<'a, const IN: usize, const OUT: usize> DenseF32<'a, IN, OUT> {
    /// Views an f32 layer; checks `inputs == IN`, `outputs == OUT` and the array lengths.
    /// The activation is not checked here (see [`Mlp::from_blob`]). Errors report layer 0.
    pub fn from_layer(layer: &LayerBlob<'a>) -> Result<Self, PolicyError> {
        check_shape::<IN, OUT>(layer)?;
        check_len(
            LayerArray::Weights,
            layer.weights,
            IN.saturating_mul(OUT).saturating_mul(4),
        )?;
        check_len(LayerArray::Bias, layer.bias, OUT.saturating_mul(4))?;
        check_len(LayerArray::WeightScales, layer.weight_scales, 0)?;
        Ok(Self {
            weights: layer.weights,
            bias: layer.bias,
        })
    }

    /// The weight bytes (borrowed from the blob).
    pub fn weights(&self) -> &'a [u8] {
        self.weights
    }

    /// The bias bytes (borrowed from the blob).
    pub fn bias(&self) -> &'a [u8] {
        self.bias
    }

    /// The pre-activation `b + W x`.
    pub fn forward(&self, x: &[f32; IN]) -> [f32; OUT] {
        let mut y = [0.0f32; OUT];
        for (yj, c) in y.iter_mut().zip(self.bias.chunks_exact(4)) {
            *yj = f32_le(c);
        }
        if OUT < F32_TILE {
            axpy_narrow(self.weights, x, &mut y);
            return y;
        }
        let row_bytes = OUT * 4;
        let mut col = 0usize;
        let mut tiles = y.chunks_exact_mut(F32_TILE);
        for tile in tiles.by_ref() {
            let mut acc = [0.0f32; F32_TILE];
            for (a, &v) in acc.iter_mut().zip(tile.iter()) {
                *a = v;
            }
            let seg = col * 4..(col + F32_TILE) * 4;
            for (row, &xi) in self.weights.chunks_exact(row_bytes).zip(x.iter()) {
                if let Some(ws) = row.get(seg.clone()) {
                    for (a, c) in acc.iter_mut().zip(ws.chunks_exact(4)) {
                        *a += xi * f32_le(c);
                    }
                }
            }
            for (v, &a) in tile.iter_mut().zip(acc.iter()) {
                *v = a;
            }
            col += F32_TILE;
        }
        let tail = tiles.into_remainder();
        if !tail.is_empty() {
            axpy_tail(self.weights, row_bytes, col, x, tail);
        }
        y
    }
}

/// Independent partial sums (over interleaved inputs) of the narrow-output kernels, so the
/// additions into one output are not a single long latency chain.
const SPLIT: usize = 8;

/// `y += W x` for a layer narrower than a tile (the 3 action outputs): [`SPLIT`] partial sums
/// of the whole (const-size) output vector over interleaved inputs.
#[inline(always)]
fn axpy_narrow<const IN: usize, const OUT: usize>(weights: &[u8], x: &[f32; IN], y: &mut [f32; OUT]) {
    let row_bytes = OUT * 4;
    let mut part = [[0.0f32; OUT]; SPLIT];
    let mut w = weights.chunks_exact(SPLIT * row_bytes);
    let mut xs = x.chunks_exact(SPLIT);
    for (wb, xb) in w.by_ref().zip(xs.by_ref()) {
        for ((p, row), &xi) in part.iter_mut().zip(wb.chunks_exact(row_bytes)).zip(xb) {
            for (a, c) in p.iter_mut().zip(row.chunks_exact(4)) {
                *a += xi * f32_le(c);
            }
        }
    }
    let rest = w.remainder().chunks_exact(row_bytes).zip(xs.remainder());
    for (p, (row, &xi)) in part.iter_mut().zip(rest) {
        for (a, c) in p.iter_mut().zip(row.chunks_exact(4)) {
            *a += xi * f32_le(c);
        }
    }
    for p in part.iter() {
        for (v, &a) in y.iter_mut().zip(p.iter()) {
            *v += a;
        }
    }
}

/// `y[k] += sum_i x[i] * w[i][col + k]` for the last `y.len() < F32_TILE` outputs of a layer
/// wider than a tile (odd widths only; the deployed 256 is a whole number of tiles).
fn axpy_tail<const IN: usize>(weights: &[u8], row_bytes: usize, col: usize, x: &[f32; IN], y: &mut [f32]) {
    let seg = col * 4..(col + y.len()) * 4;
    for (row, &xi) in weights.chunks_exact(row_bytes).zip(x.iter()) {
        if let Some(ws) = row.get(seg.clone()) {
            for (v, c) in y.iter_mut().zip(ws.chunks_exact(4)) {
                *v += xi * f32_le(c);
            }
        }
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
    /// The activation is not checked here (see [`Mlp::from_blob`]). Errors report layer 0.
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

    /// The integer accumulators `bias[j] + sum_i w[j][i] * xq[i]`, saturating at the bias add.
    /// For `xq` in `-L..=L` (what [`Self::quantize_input`] gives) the dot product is exact:
    /// at most [`blob::MAX_INT8_INPUTS`] products of magnitude `<= 128 L < 2^22` (`from_layer`
    /// refuses wider layers). Other i16 values wrap, never panic.
    ///
    /// Uses [`Self::accumulate_lanes`] on x86 and other wide-SIMD targets, and
    /// [`Self::accumulate_rows`] on 32-bit Arm (the Cortex-M4), where
    /// [`INT8_LANES`] accumulators would not fit in registers.
    #[inline]
    pub fn accumulate(&self, xq: &[i16; IN]) -> [i32; OUT] {
        if cfg!(target_arch = "arm") {
            self.accumulate_rows(xq)
        } else {
            self.accumulate_lanes(xq)
        }
    }

    /// [`Self::accumulate`], one row at a time with [`INT8_LANES`] independent i32 lanes:
    /// a fixed-width block LLVM maps onto whole vector registers (`vpmovsxbw` + `vpmaddwd`
    /// on AVX-512, the activations held in registers across rows).
    pub fn accumulate_lanes(&self, xq: &[i16; IN]) -> [i32; OUT] {
        let mut acc = [0i32; OUT];
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
        let acc = self.accumulate(xq);
        let mut y = [0.0f32; OUT];
        for ((yj, &a), c) in y.iter_mut().zip(acc.iter()).zip(self.weight_scales.chunks_exact(4)) {
            *yj = a as f32 * (self.input_scale * f32_le(c));
        }
        y
    }

    /// ReLU of the pre-activation, quantized with the next layer's input scale.
    fn forward_relu_quantized(&self, xq: &[i16; IN], next_scale: f32) -> [i16; OUT] {
        let y = self.forward(xq);
        let mut q = [0i16; OUT];
        for (qj, &v) in q.iter_mut().zip(y.iter()) {
            *qj = quantize(relu(v), next_scale);
        }
        q
    }
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

/// The three layers of an [`Mlp`], in one precision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MlpLayers<'a, const IN: usize, const H1: usize, const H2: usize, const OUT: usize> {
    F32(DenseF32<'a, IN, H1>, DenseF32<'a, H1, H2>, DenseF32<'a, H2, OUT>),
    Int8(DenseInt8<'a, IN, H1>, DenseInt8<'a, H1, H2>, DenseInt8<'a, H2, OUT>),
}

/// An `IN`-`H1`-`H2`-`OUT` actor mean network: ReLU, ReLU, tanh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mlp<'a, const IN: usize, const H1: usize, const H2: usize, const OUT: usize> {
    kind: ProblemKind,
    features: FeatureLayout,
    layers: MlpLayers<'a, IN, H1, H2, OUT>,
}

/// The transfer actor, 10-256-256-3.
pub type TransferPolicy<'a> = Mlp<'a, 10, 256, 256, 3>;
/// The rendezvous actor, 22-256-256-3.
pub type RendezvousPolicy<'a> = Mlp<'a, 22, 256, 256, 3>;

fn check_activation(layer: &LayerBlob<'_>, index: usize, expected: Activation) -> Result<(), PolicyError> {
    if layer.activation == expected {
        Ok(())
    } else {
        Err(PolicyError::WrongActivation {
            layer: index,
            expected,
            found: layer.activation,
        })
    }
}

impl<'a, const IN: usize, const H1: usize, const H2: usize, const OUT: usize> Mlp<'a, IN, H1, H2, OUT> {
    /// Decodes a blob (magic, version, CRC, structure) and builds the policy from it, checking
    /// it is for `expected` and has exactly this shape. The weights stay in `bytes`.
    pub fn from_bytes(bytes: &'a [u8], expected: ProblemKind) -> Result<Self, PolicyError> {
        let net = blob::decode(bytes)?;
        Self::from_blob(&net, expected)
    }

    /// Builds the policy from a decoded blob: checks the problem kind, that the feature layout
    /// has `IN` inputs, three layers of sizes `IN`-`H1`-`H2`-`OUT` with ReLU, ReLU, tanh, and
    /// every array length for the blob's quantization.
    pub fn from_blob(net: &NetworkBlob<'a>, expected: ProblemKind) -> Result<Self, PolicyError> {
        if net.kind != expected {
            return Err(PolicyError::WrongKind {
                expected,
                found: net.kind,
            });
        }
        if net.features.len() != IN || net.features.problem() != expected {
            return Err(PolicyError::WrongFeatures {
                expected_inputs: IN,
                found: net.features,
            });
        }
        let [l1, l2, l3] = net.layers.as_slice() else {
            return Err(PolicyError::WrongLayerCount {
                expected: MLP_LAYERS,
                found: net.layers.len(),
            });
        };
        check_activation(l1, 0, Activation::Relu)?;
        check_activation(l2, 1, Activation::Relu)?;
        check_activation(l3, 2, Activation::Tanh)?;
        let layers = match net.quantization {
            Quantization::F32 => MlpLayers::F32(
                DenseF32::from_layer(l1).map_err(|e| e.at_layer(0))?,
                DenseF32::from_layer(l2).map_err(|e| e.at_layer(1))?,
                DenseF32::from_layer(l3).map_err(|e| e.at_layer(2))?,
            ),
            Quantization::Int8 => MlpLayers::Int8(
                DenseInt8::from_layer(l1).map_err(|e| e.at_layer(0))?,
                DenseInt8::from_layer(l2).map_err(|e| e.at_layer(1))?,
                DenseInt8::from_layer(l3).map_err(|e| e.at_layer(2))?,
            ),
        };
        Ok(Self {
            kind: net.kind,
            features: net.features,
            layers,
        })
    }

    /// The problem this policy flies.
    pub fn kind(&self) -> ProblemKind {
        self.kind
    }

    /// The input encoding.
    pub fn features(&self) -> FeatureLayout {
        self.features
    }

    /// How the weights are stored.
    pub fn quantization(&self) -> Quantization {
        match self.layers {
            MlpLayers::F32(..) => Quantization::F32,
            MlpLayers::Int8(..) => Quantization::Int8,
        }
    }

    /// The layer views.
    pub fn layers(&self) -> &MlpLayers<'a, IN, H1, H2, OUT> {
        &self.layers
    }

    /// The action mean in `[-1, 1]^OUT`: `tanh(L3(relu(L2(relu(L1(x))))))`.
    ///
    /// Never panics. Any non-finite input gives `[f32::NAN; OUT]` (see the module doc).
    pub fn forward(&self, input: &[f32; IN]) -> [f32; OUT] {
        if !input.iter().all(|v| v.is_finite()) {
            return [f32::NAN; OUT];
        }
        let pre = match &self.layers {
            MlpLayers::F32(a, b, c) => {
                let mut h1 = a.forward(input);
                h1.iter_mut().for_each(|v| *v = relu(*v));
                let mut h2 = b.forward(&h1);
                h2.iter_mut().for_each(|v| *v = relu(*v));
                c.forward(&h2)
            }
            MlpLayers::Int8(a, b, c) => {
                let q0 = a.quantize_input(input);
                let q1 = a.forward_relu_quantized(&q0, b.input_scale);
                let q2 = b.forward_relu_quantized(&q1, c.input_scale);
                c.forward(&q2)
            }
        };
        let mut out = [0.0f32; OUT];
        for (o, &v) in out.iter_mut().zip(pre.iter()) {
            *o = libm::tanhf(v);
        }
        out
    }
}
