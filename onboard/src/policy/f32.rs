//! The portable f32 kernel: a dense layer `y = b + W x` read in place from the blob, as
//! axpys over register tiles of [`F32_TILE`] outputs (see the module doc of [`super`]), each
//! product and sum one fused multiply-add ([`fma`]).

use core::mem::MaybeUninit;

use shared::blob::{f32_weight_index, LayerBlob, F32_BLOCK};

#[cfg(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"))]
use super::arm;
#[cfg(target_arch = "x86_64")]
use super::x86;
use super::{check_len, check_shape, f32_le, relu, LayerArray, PolicyError};

/// Outputs per register tile of the f32 kernel (a multiple of 16, the AVX-512 lane count).
pub const F32_TILE: usize = 64;

/// A dense f32 layer `y = b + W x` viewing its blob arrays in place.
///
/// `weights`: `IN * OUT` f32 LE in blocks of 8 outputs, input-major within
/// (`shared::blob::f32_weight_index`); `bias`: `OUT` f32 LE.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DenseF32<'a, const IN: usize, const OUT: usize> {
    weights: &'a [u8],
    bias: &'a [u8],
}

impl<'a, const IN: usize, const OUT: usize> DenseF32<'a, IN, OUT> {
    /// Views an f32 layer; checks `inputs == IN`, `outputs == OUT` and the array lengths.
    /// The activation is not checked here (see [`Mlp::from_blob`](super::Mlp::from_blob)).
    /// Errors report layer 0.
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
        self.forward_into(x, &mut y);
        y
    }

    /// [`Self::forward`] into `y` (every element overwritten): a network passes its own
    /// arrays, since on the Cortex-M4F each copy of a 256-wide vector costs over a thousand
    /// instructions.
    #[inline(always)]
    pub fn forward_into(&self, x: &[f32; IN], y: &mut [f32; OUT]) {
        self.layer_into(x, y, false);
    }

    /// `relu(b + W x)` into `y` (every element overwritten), `relu` the network's (NaN and
    /// `-0.0` kept): a hidden layer. The Cortex-M4F kernel applies it to each block while its
    /// outputs are still in registers.
    #[inline(always)]
    pub fn forward_relu_into(&self, x: &[f32; IN], y: &mut [f32; OUT]) {
        self.layer_into(x, y, true);
    }

    /// `b + W x`, or its `relu` with `relu_too`, into `y`: the Cortex-M4F kernel where it
    /// takes the layer, else the host's or the portable kernels.
    #[inline(always)]
    fn layer_into(&self, x: &[f32; IN], y: &mut [f32; OUT], relu_too: bool) {
        #[cfg(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"))]
        if self.machine_layer(x, y, relu_too) {
            return;
        }
        self.portable_into(x, y);
        if relu_too {
            y.iter_mut().for_each(|v| *v = relu(*v));
        }
    }

    /// [`Self::forward_into`] (with `relu`: [`Self::forward_relu_into`]) into an array not
    /// initialized yet, returned initialized: the Cortex-M4F kernel writes it whole, so it is
    /// never zeroed first.
    #[inline(always)]
    pub(super) fn forward_fresh<'y>(
        &self,
        x: &[f32; IN],
        y: &'y mut MaybeUninit<[f32; OUT]>,
        relu: bool,
    ) -> &'y mut [f32; OUT] {
        #[cfg(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"))]
        let y = match arm::f32_layer_fresh(self.weights, self.bias, x, y, relu) {
            Ok(done) => return done,
            Err(y) => y,
        };
        let y = y.write([0.0f32; OUT]);
        self.layer_into(x, y, relu);
        y
    }

    /// [`Self::forward_into`] by the host's kernels (x86-64) or the portable ones.
    #[inline(always)]
    fn portable_into(&self, x: &[f32; IN], y: &mut [f32; OUT]) {
        for (yj, c) in y.iter_mut().zip(self.bias.chunks_exact(4)) {
            *yj = f32_le(c);
        }
        #[cfg(target_arch = "x86_64")]
        if x86::dense(self.weights, x, y) {
            return;
        }
        if OUT < F32_BLOCK {
            axpy_narrow(self.weights, x, y);
        } else if cfg!(all(target_arch = "arm", target_os = "none", target_abi = "eabihf")) {
            // Only where `arm::f32_layer` declined (unaligned weights): compact rather than fast.
            axpy_tail::<IN, OUT>(self.weights, 0, x, y);
        } else {
            self.tiles(x, y);
        }
    }

    /// The layer's whole blocks of 8 outputs by one `asm!` block on the Cortex-M4F
    /// (`arm::f32_layer`, `policy/arm.rs`: bias, products and sums per output in the portable
    /// kernel's order, then `relu` with `relu_too`), then the last `OUT % 8` outputs by the portable
    /// loop: `false`, with `y` untouched, where it declines (a layer narrower than a block,
    /// unaligned weights).
    #[cfg(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"))]
    #[inline(always)]
    fn machine_layer(&self, x: &[f32; IN], y: &mut [f32; OUT], relu_too: bool) -> bool {
        let whole = OUT - OUT % F32_BLOCK;
        let (blocks, tail) = y.split_at_mut(whole);
        if !arm::f32_layer(self.weights, self.bias, x, blocks, relu_too) {
            return false;
        }
        for (yj, c) in tail.iter_mut().zip(self.bias.chunks_exact(4).skip(whole)) {
            *yj = f32_le(c);
        }
        axpy_tail::<IN, OUT>(self.weights, whole, x, tail);
        if relu_too {
            tail.iter_mut().for_each(|v| *v = relu(*v));
        }
        true
    }

    /// `y += W x` for a layer at least a block wide, in register tiles of [`F32_TILE`]
    /// outputs (the portable kernel: per input, the tile's 8 blocks of 8 contiguous weights),
    /// then the last `OUT % F32_TILE` outputs.
    #[inline(always)]
    fn tiles(&self, x: &[f32; IN], y: &mut [f32; OUT]) {
        let mut col = 0usize;
        let mut tiles = y.chunks_exact_mut(F32_TILE);
        for tile in tiles.by_ref() {
            let mut acc = [0.0f32; F32_TILE];
            for (a, &v) in acc.iter_mut().zip(tile.iter()) {
                *a = v;
            }
            for (i, &xi) in x.iter().enumerate() {
                for (b, block) in acc.chunks_exact_mut(F32_BLOCK).enumerate() {
                    let start = 4 * f32_weight_index(IN, OUT, col + F32_BLOCK * b, i);
                    if let Some(ws) = self.weights.get(start..start + 4 * F32_BLOCK) {
                        for (a, c) in block.iter_mut().zip(ws.chunks_exact(4)) {
                            *a = fma(xi, f32_le(c), *a);
                        }
                    }
                }
            }
            for (v, &a) in tile.iter_mut().zip(acc.iter()) {
                *v = a;
            }
            col += F32_TILE;
        }
        axpy_tail::<IN, OUT>(self.weights, col, x, tiles.into_remainder());
    }
}

/// `acc + x * w` rounded once: the fused multiply-add of every f32 kernel, on every target
/// (`vfma.f32` on the Cortex-M4F, `vfmadd` on x86-64 with FMA, `fmadd` on AArch64, exact in
/// software elsewhere), so that the host and the flight computer compute the same bits.
#[inline(always)]
fn fma(x: f32, w: f32, acc: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"))]
    {
        arm::fma(x, w, acc)
    }
    #[cfg(not(all(target_arch = "arm", target_os = "none", target_abi = "eabihf")))]
    {
        libm::fmaf(x, w, acc)
    }
}

/// Independent partial sums (over interleaved inputs) of the narrow-output kernels, so the
/// additions into one output are not a single long latency chain.
pub(super) const SPLIT: usize = 8;

/// `y += W x` for a layer narrower than a block (the 3 or 4 action outputs): [`SPLIT`] partial sums
/// of the whole (const-size) output vector over interleaved inputs, by the target's own kernel
/// where it has one for the layer, then added to `y` in order.
#[inline(always)]
fn axpy_narrow<const IN: usize, const OUT: usize>(weights: &[u8], x: &[f32; IN], y: &mut [f32; OUT]) {
    let mut part = [[0.0f32; OUT]; SPLIT];
    if !machine_partials(weights, x, &mut part) {
        portable_partials(weights, x, &mut part);
    }
    add_partials(&part, y);
}

/// [`portable_partials`] by the target's own kernel: `false`, touching nothing, where it has
/// none for the layer.
#[inline(always)]
#[allow(unused_variables)] // on targets without a narrow kernel
fn machine_partials<const IN: usize, const OUT: usize>(
    weights: &[u8],
    x: &[f32; IN],
    part: &mut [[f32; OUT]; SPLIT],
) -> bool {
    #[cfg(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"))]
    {
        match OUT {
            arm::NARROW_OUTPUTS => arm::f32_narrow3(weights, x, part.as_flattened_mut()),
            arm::NARROW4_OUTPUTS => arm::f32_narrow4(weights, x, part.as_flattened_mut()),
            _ => false,
        }
    }
    #[cfg(target_arch = "x86_64")]
    {
        x86::narrow_partials(weights, x, part)
    }
    #[cfg(not(any(
        all(target_arch = "arm", target_os = "none", target_abi = "eabihf"),
        target_arch = "x86_64"
    )))]
    {
        false
    }
}

/// `part[k][j] = fma(x[i], w[i][j], part[k][j])` for the inputs `i = k, k + 8, k + 16, ...` in
/// order: the narrow kernel's partial sums (from 0) in the portable kernel.
#[inline(always)]
fn portable_partials<const IN: usize, const OUT: usize>(weights: &[u8], x: &[f32; IN], part: &mut [[f32; OUT]; SPLIT]) {
    let row_bytes = OUT * 4;
    let mut w = weights.chunks_exact(SPLIT * row_bytes);
    let mut xs = x.chunks_exact(SPLIT);
    for (wb, xb) in w.by_ref().zip(xs.by_ref()) {
        for ((p, row), &xi) in part.iter_mut().zip(wb.chunks_exact(row_bytes)).zip(xb) {
            for (a, c) in p.iter_mut().zip(row.chunks_exact(4)) {
                *a = fma(xi, f32_le(c), *a);
            }
        }
    }
    let rest = w.remainder().chunks_exact(row_bytes).zip(xs.remainder());
    for (p, (row, &xi)) in part.iter_mut().zip(rest) {
        for (a, c) in p.iter_mut().zip(row.chunks_exact(4)) {
            *a = fma(xi, f32_le(c), *a);
        }
    }
}

/// `y += p0 + p1 + ... + p7`, one partial at a time, in order.
#[inline(always)]
fn add_partials<const OUT: usize>(part: &[[f32; OUT]; SPLIT], y: &mut [f32; OUT]) {
    for p in part.iter() {
        for (v, &a) in y.iter_mut().zip(p.iter()) {
            *v += a;
        }
    }
}

/// `y[k] += sum_i x[i] * w[i][col + k]`, inputs in order, for outputs `col..col + y.len()`
/// wherever their blocks lie: the last outputs of a layer that are not a whole tile (odd
/// widths only; the deployed 256 is a whole number of tiles), or a block a kernel declined.
fn axpy_tail<const IN: usize, const OUT: usize>(weights: &[u8], col: usize, x: &[f32; IN], y: &mut [f32]) {
    for (i, &xi) in x.iter().enumerate() {
        for (k, v) in y.iter_mut().enumerate() {
            let start = 4 * f32_weight_index(IN, OUT, col + k, i);
            if let Some(c) = weights.get(start..start + 4) {
                *v = fma(xi, f32_le(c), *v);
            }
        }
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    extern crate std;
    use std::vec::Vec;

    use super::*;

    /// f32 LE bytes of values spread over several binades (xorshift), so that any other
    /// rounding or order changes low bits.
    fn rough(n: usize, seed: &mut u64) -> Vec<u8> {
        (0..n)
            .flat_map(|_| {
                *seed ^= *seed << 13;
                *seed ^= *seed >> 7;
                *seed ^= *seed << 17;
                let unit = (*seed >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0;
                (unit * 2f32.powi((*seed % 11) as i32 - 5)).to_le_bytes()
            })
            .collect()
    }

    fn same_bits<const IN: usize, const OUT: usize>(seed: u64) {
        let mut s = seed | 1;
        // One byte in, so the f32 arrays are not word-aligned, as in a blob.
        let mut weights = std::vec![0u8];
        weights.extend(rough(IN * OUT, &mut s));
        let bias = rough(OUT, &mut s);
        let layer = DenseF32::<IN, OUT> {
            weights: &weights[1..],
            bias: &bias,
        };
        for _ in 0..20 {
            let x: [f32; IN] = core::array::from_fn(|i| f32_le(&rough(1, &mut s)) * (1 + i % 3) as f32);
            let fast = layer.forward(&x);
            let mut portable: [f32; OUT] = core::array::from_fn(|j| f32_le(&bias[4 * j..4 * j + 4]));
            if OUT < F32_BLOCK {
                let mut part = [[0.0f32; OUT]; SPLIT];
                portable_partials(layer.weights, &x, &mut part);
                add_partials(&part, &mut portable);
            } else {
                layer.tiles(&x, &mut portable);
            }
            assert_eq!(fast.map(f32::to_bits), portable.map(f32::to_bits), "{IN}x{OUT}");
        }
    }

    /// Whichever kernel this machine takes (AVX2 + FMA when it has them), the portable one
    /// (the flight computer's order and rounding, `libm::fmaf`) gives the same bits.
    #[test]
    fn the_machine_kernel_gives_the_portable_kernels_bits() {
        same_bits::<10, 256>(1);
        same_bits::<256, 256>(2);
        same_bits::<256, 3>(3);
        same_bits::<22, 256>(4);
        same_bits::<70, 130>(5);
        same_bits::<13, 5>(6);
        same_bits::<5, 63>(7);
        same_bits::<1, 1>(8);
    }
}
