//! The f32 kernel's floating-point arithmetic, checked bit for bit (`to_bits`) against std's
//! `f32::mul_add` (a correctly rounded fused multiply-add on every host).
//!
//! The host result must be bit-identical to the flight computer's (`vfma.f32`), so the kernel
//! may vectorize across outputs but never reassociate the sum of one output nor round a
//! product on its own:
//! - a layer at least one block of 8 outputs wide: `bias[j]`, then `acc = fma(x[i], w[i][j], acc)`
//!   for i = 0, 1, 2, ... in order (one rounding per input);
//! - a layer narrower than a block (the 3 or 4 action outputs): 8 partial sums from 0, partial `k`
//!   fusing inputs i = k, k + 8, k + 16, ... in order, then `bias[j] + p0 + p1 + ... + p7` in
//!   order.
//!
//! On x86-64 the kernel taken depends on the machine (AVX2 + FMA or portable); both are
//! checked against the same reference.

mod policy_support;

use onboard::policy::{DenseF32, TransferPolicy};
use policy_support::{f32_layer, f32_net, OwnedLayer, RefLayer, RefNet, Rng};
use shared::blob::{f32_weight_index, Activation, ProblemKind, F32_BLOCK};

/// Partial sums of the narrow kernel.
const SPLIT: usize = 8;

fn w_at(layer: &OwnedLayer, outputs: usize, i: usize, j: usize) -> f32 {
    let o = 4 * f32_weight_index(usize::from(layer.inputs), outputs, j, i);
    f32::from_le_bytes(layer.weights[o..o + 4].try_into().unwrap())
}

fn b_at(layer: &OwnedLayer, j: usize) -> f32 {
    f32::from_le_bytes(layer.bias[4 * j..4 * j + 4].try_into().unwrap())
}

/// Bias first, then inputs in order, each taken into the sum by `mac(x, w, acc)`.
fn sequential_by(layer: &OwnedLayer, x: &[f32], mac: impl Fn(f32, f32, f32) -> f32) -> Vec<f32> {
    let outputs = usize::from(layer.outputs);
    (0..outputs)
        .map(|j| {
            let mut acc = b_at(layer, j);
            for (i, &xi) in x.iter().enumerate() {
                acc = mac(xi, w_at(layer, outputs, i, j), acc);
            }
            acc
        })
        .collect()
}

/// Bias first, then one fused multiply-add per input in order: the contract for layers at least
/// a tile wide.
fn sequential(layer: &OwnedLayer, x: &[f32]) -> Vec<f32> {
    sequential_by(layer, x, f32::mul_add)
}

/// The narrow kernel's order: [`SPLIT`] interleaved partial sums, then bias + partials in order.
fn split(layer: &OwnedLayer, x: &[f32]) -> Vec<f32> {
    let outputs = usize::from(layer.outputs);
    (0..outputs)
        .map(|j| {
            let mut part = [0.0f32; SPLIT];
            for (i, &xi) in x.iter().enumerate() {
                part[i % SPLIT] = xi.mul_add(w_at(layer, outputs, i, j), part[i % SPLIT]);
            }
            let mut acc = b_at(layer, j);
            for p in part {
                acc += p;
            }
            acc
        })
        .collect()
}

/// The same sum split into two halves over the inputs: a reassociation the kernel must not do.
fn halves(layer: &OwnedLayer, x: &[f32]) -> Vec<f32> {
    let outputs = usize::from(layer.outputs);
    let mid = x.len() / 2;
    (0..outputs)
        .map(|j| {
            let (mut lo, mut hi) = (b_at(layer, j), 0.0f32);
            for (i, &xi) in x.iter().enumerate() {
                let w = w_at(layer, outputs, i, j);
                if i < mid {
                    lo = xi.mul_add(w, lo);
                } else {
                    hi = xi.mul_add(w, hi);
                }
            }
            lo + hi
        })
        .collect()
}

/// The sequential order with each product rounded before the sum (unfused): what the kernel
/// must not compute either.
fn unfused(layer: &OwnedLayer, x: &[f32]) -> Vec<f32> {
    sequential_by(layer, x, |x, w, acc| acc + x * w)
}

/// Weights and inputs spread over several orders of magnitude, so that a different summation
/// order changes low bits of most outputs.
fn rough_layer(n_in: usize, n_out: usize, rng: &mut Rng) -> RefLayer {
    let v = |rng: &mut Rng| rng.sym(1.0) * 2f32.powi((rng.next_u64() % 13) as i32 - 6);
    RefLayer {
        w: (0..n_out).map(|_| (0..n_in).map(|_| v(rng)).collect()).collect(),
        b: (0..n_out).map(|_| v(rng)).collect(),
    }
}

fn rough_input(n: usize, rng: &mut Rng) -> Vec<f32> {
    (0..n)
        .map(|_| rng.sym(4.0) * 2f32.powi((rng.next_u64() % 9) as i32 - 4))
        .collect()
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Compares `DenseF32::<IN, OUT>::forward` bit for bit with the order of its width; returns
/// how many outputs the reassociated `halves` sum and the unfused sum get wrong (the check's
/// sensitivity).
fn check<const IN: usize, const OUT: usize>(seed: u64, trials: usize) -> (usize, usize) {
    let mut rng = Rng::new(seed);
    let owned = f32_layer(&rough_layer(IN, OUT, &mut rng), Activation::Relu);
    let view = owned.view();
    let layer = DenseF32::<IN, OUT>::from_layer(&view).unwrap();
    let (mut reordered, mut rounded) = (0, 0);
    for t in 0..trials {
        let x: [f32; IN] = rough_input(IN, &mut rng).try_into().unwrap();
        let got = layer.forward(&x);
        let want = if OUT >= F32_BLOCK {
            sequential(&owned, &x)
        } else {
            split(&owned, &x)
        };
        assert_eq!(
            bits(&got),
            bits(&want),
            "{IN}x{OUT} trial {t}: not the contract's summation order"
        );
        reordered += bits(&halves(&owned, &x))
            .iter()
            .zip(bits(&want))
            .filter(|(a, b)| **a != *b)
            .count();
        if OUT >= F32_BLOCK {
            rounded += bits(&unfused(&owned, &x))
                .iter()
                .zip(bits(&want))
                .filter(|(a, b)| **a != *b)
                .count();
        }
    }
    (reordered, rounded)
}

#[test]
fn wide_layers_sum_bias_then_inputs_in_order() {
    // The deployed hidden layers, then whole tiles plus a remainder and a single tile.
    let sensitive = [
        check::<256, 256>(11, 20),
        check::<10, 256>(12, 50),
        check::<22, 256>(13, 50),
        check::<70, 130>(14, 50),
        check::<33, 64>(15, 50),
        check::<5, 200>(16, 50),
    ];
    // A reassociated or unfused sum must differ somewhere, or the bit comparison above proves
    // nothing.
    for (k, (reordered, rounded)) in sensitive.iter().enumerate() {
        assert!(*reordered > 0, "case {k}: test data cannot tell summation orders apart");
        assert!(*rounded > 0, "case {k}: test data cannot tell fused from unfused");
    }
}

#[test]
fn narrow_layers_keep_their_interleaved_partial_sums() {
    check::<256, 3>(21, 50);
    check::<22, 3>(22, 50);
    check::<13, 5>(23, 50);
    check::<1, 1>(24, 10);
}

#[test]
fn transfer_policy_matches_sequential_layers_bit_for_bit() {
    let mut rng = Rng::new(31);
    let net = RefNet::random(&[10, 256, 256, 3], 3.0, &mut rng);
    let owned = f32_net(&net, ProblemKind::Transfer);
    let bytes = owned.encode();
    let policy = TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer).unwrap();
    let relu = |v: Vec<f32>| v.into_iter().map(|a| if a < 0.0 { 0.0 } else { a }).collect::<Vec<_>>();
    for _ in 0..50 {
        let x = rough_input(10, &mut rng);
        let h1 = relu(sequential(&owned.layers[0], &x));
        let h2 = relu(sequential(&owned.layers[1], &h1));
        let want: Vec<f32> = split(&owned.layers[2], &h2).into_iter().map(libm::tanhf).collect();
        let got = policy.forward(&x.clone().try_into().unwrap());
        assert_eq!(bits(&got), bits(&want));
    }
}
