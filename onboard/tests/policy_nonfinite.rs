//! Non-finite and extreme inputs: no panic, and the documented outputs.

mod policy_support;

use onboard::policy::{DenseF32, MlpLayers, RendezvousPolicy, TransferPolicy};
use policy_support::{calibrate, f32_net, int8_net, quantize_net, random_input, RefNet, Rng};
use shared::blob::ProblemKind;

fn blobs(sizes: &[usize], kind: ProblemKind) -> (Vec<u8>, Vec<u8>) {
    let mut rng = Rng::new(41);
    let net = RefNet::random(sizes, 1.0, &mut rng);
    let calib: Vec<Vec<f32>> = (0..50).map(|_| random_input(sizes[0], &mut rng)).collect();
    let quant = quantize_net(&net, &calibrate(&net, &calib));
    (f32_net(&net, kind).encode(), int8_net(&net, &quant, kind).encode())
}

const BAD: [f32; 3] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];

#[test]
fn any_non_finite_input_gives_all_nan_in_both_precisions() {
    let (b32, b8) = blobs(&[10, 256, 256, 3], ProblemKind::Transfer);
    let mut rng = Rng::new(42);
    for bytes in [&b32, &b8] {
        let p = TransferPolicy::from_bytes(bytes, ProblemKind::Transfer).unwrap();
        for i in 0..10 {
            for bad in BAD {
                let mut x: [f32; 10] = random_input(10, &mut rng).try_into().unwrap();
                x[i] = bad;
                let y = p.forward(&x);
                assert!(y.iter().all(|v| v.is_nan()), "input {i} = {bad}: {y:?}");
            }
        }
        assert!(p.forward(&[f32::NAN; 10]).iter().all(|v| v.is_nan()));
    }
    let (b32, b8) = blobs(&[22, 256, 256, 3], ProblemKind::Rendezvous);
    for bytes in [&b32, &b8] {
        let p = RendezvousPolicy::from_bytes(bytes, ProblemKind::Rendezvous).unwrap();
        let mut x = [0.5f32; 22];
        x[21] = f32::NEG_INFINITY;
        assert!(p.forward(&x).iter().all(|v| v.is_nan()));
    }
}

#[test]
fn extreme_finite_inputs_do_not_panic() {
    let (b32, b8) = blobs(&[10, 256, 256, 3], ProblemKind::Transfer);
    let p32 = TransferPolicy::from_bytes(&b32, ProblemKind::Transfer).unwrap();
    let p8 = TransferPolicy::from_bytes(&b8, ProblemKind::Transfer).unwrap();
    for v in [f32::MAX, f32::MIN, 1e30, -1e30, f32::MIN_POSITIVE, 1e-45, 0.0, -0.0] {
        let x = [v; 10];
        // f32: a sum may overflow to inf (tanh gives ±1) or to inf - inf (NaN).
        assert!(p32.forward(&x).iter().all(|y| y.is_nan() || (-1.0..=1.0).contains(y)));
        // int8: inputs saturate at ±ACTIVATION_LEVELS steps, so the output is always finite.
        assert!(p8.forward(&x).iter().all(|y| (-1.0..=1.0).contains(y)));
    }
}

#[test]
fn layer_kernels_are_total_on_non_finite_values() {
    // Below the `Mlp` guard: NaN propagates through the f32 kernel and quantizes to 0 in int8.
    let (b32, b8) = blobs(&[10, 256, 256, 3], ProblemKind::Transfer);
    let p32 = TransferPolicy::from_bytes(&b32, ProblemKind::Transfer).unwrap();
    let MlpLayers::F32(l1, ..) = *p32.layers() else {
        panic!()
    };
    let l1: DenseF32<'_, 10, 256> = l1;
    let mut x = [0.1f32; 10];
    x[3] = f32::NAN;
    assert!(l1.forward(&x).iter().all(|v| v.is_nan()));
    x[3] = f32::INFINITY;
    assert!(l1.forward(&x).iter().all(|v| !v.is_finite()));

    let p8 = TransferPolicy::from_bytes(&b8, ProblemKind::Transfer).unwrap();
    let MlpLayers::Int8(_, l2, ..) = *p8.layers() else {
        panic!()
    };
    let mut h = [0.0f32; 256];
    h[..3].copy_from_slice(&[f32::NAN, f32::INFINITY, f32::NEG_INFINITY]);
    let q = l2.quantize_input(&h);
    assert_eq!(&q[..3], &[0, 32767, -32767]);
    assert!(l2.forward(&q).iter().all(|v| v.is_finite()));
}
