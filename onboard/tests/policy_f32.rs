//! f32 inference against an independent f64 reference (PyTorch `[out][in]` layout, plain loops).

mod policy_support;

use onboard::policy::{DenseF32, Rendezvous3Policy, RendezvousPolicy, Transfer3Policy, TransferPolicy};
use policy_support::{f32_layer, f32_net, random_input, RefNet, Rng};
use shared::blob::{Activation, ProblemKind, Quantization};

/// Max |policy - reference| over `n` random inputs.
fn max_err_f32<const IN: usize, const OUT: usize>(
    forward: impl Fn(&[f32; IN]) -> [f32; OUT],
    net: &RefNet,
    n: usize,
    rng: &mut Rng,
) -> f64 {
    let mut worst = 0.0f64;
    for _ in 0..n {
        let x: [f32; IN] = random_input(IN, rng).try_into().unwrap();
        let got = forward(&x);
        let want = net.forward(&x);
        for (g, w) in got.iter().zip(&want) {
            assert!(g.is_finite());
            worst = worst.max((f64::from(*g) - w).abs());
        }
    }
    worst
}

#[test]
fn transfer_f32_matches_f64_reference() {
    let mut rng = Rng::new(1);
    // gain 3: outputs spread over the tanh range rather than all near 0.
    let net = RefNet::random(&[10, 256, 256, 3], 3.0, &mut rng);
    let bytes = f32_net(&net, ProblemKind::Transfer).encode();
    let policy = TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer).unwrap();
    assert_eq!(policy.quantization(), Quantization::F32);
    let err = max_err_f32(|x| policy.forward(x), &net, 300, &mut rng);
    println!("transfer f32: max |f32 - f64 reference| = {err:e}");
    assert!(err < 1e-5, "error {err}");
}

#[test]
fn rendezvous_f32_matches_f64_reference() {
    let mut rng = Rng::new(2);
    let net = RefNet::random(&[22, 256, 256, 3], 3.0, &mut rng);
    let bytes = f32_net(&net, ProblemKind::Rendezvous).encode();
    let policy = RendezvousPolicy::from_bytes(&bytes, ProblemKind::Rendezvous).unwrap();
    let err = max_err_f32(|x| policy.forward(x), &net, 300, &mut rng);
    println!("rendezvous f32: max |f32 - f64 reference| = {err:e}");
    assert!(err < 1e-5, "error {err}");
}

#[test]
fn three_dimensional_f32_policies_match_f64_reference() {
    // 15-256-256-4 and 30-256-256-4: throttle and an RTN direction.
    let mut rng = Rng::new(3);
    let net = RefNet::random(&[15, 256, 256, 4], 3.0, &mut rng);
    let bytes = f32_net(&net, ProblemKind::Transfer).encode();
    let policy = Transfer3Policy::from_bytes(&bytes, ProblemKind::Transfer).unwrap();
    let err = max_err_f32(|x| policy.forward(x), &net, 300, &mut rng);
    assert!(err < 1e-5, "transfer error {err}");
    let net = RefNet::random(&[30, 256, 256, 4], 3.0, &mut rng);
    let bytes = f32_net(&net, ProblemKind::Rendezvous).encode();
    let policy = Rendezvous3Policy::from_bytes(&bytes, ProblemKind::Rendezvous).unwrap();
    let err = max_err_f32(|x| policy.forward(x), &net, 300, &mut rng);
    assert!(err < 1e-5, "rendezvous error {err}");
}

#[test]
fn outputs_span_the_tanh_range() {
    // Guards the comparisons above against a degenerate network whose outputs are all ~0.
    let mut rng = Rng::new(1);
    let net = RefNet::random(&[10, 256, 256, 3], 3.0, &mut rng);
    let bytes = f32_net(&net, ProblemKind::Transfer).encode();
    let policy = TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer).unwrap();
    let (mut lo, mut hi) = (0.0f32, 0.0f32);
    for _ in 0..300 {
        let x: [f32; 10] = random_input(10, &mut rng).try_into().unwrap();
        for v in policy.forward(&x) {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    assert!(lo < -0.5 && hi > 0.5, "outputs in [{lo}, {hi}]");
}

/// Pre-activation of a layer with full register tiles and a remainder (70 = 64 + 6,
/// 130 = 2 * 64 + 2) and a wide one (256 = 4 tiles), relative to the reference.
fn check_layer<const IN: usize, const OUT: usize>(seed: u64) {
    let mut rng = Rng::new(seed);
    let net = RefNet::random(&[IN, OUT], 1.0, &mut rng);
    let owned = f32_layer(&net.layers[0], Activation::Relu);
    let view = owned.view();
    let layer = DenseF32::<IN, OUT>::from_layer(&view).unwrap();
    for _ in 0..50 {
        let x: [f32; IN] = random_input(IN, &mut rng).try_into().unwrap();
        let xd: Vec<f64> = x.iter().map(|&v| f64::from(v)).collect();
        let want = net.layers[0].pre(&xd);
        let got = layer.forward(&x);
        for (j, (g, w)) in got.iter().zip(&want).enumerate() {
            // f32 accumulation of IN terms: error well below IN * eps * sum |w x|.
            let scale: f64 = net.layers[0].w[j]
                .iter()
                .zip(&xd)
                .map(|(w, x)| (f64::from(*w) * x).abs())
                .sum::<f64>()
                + f64::from(net.layers[0].b[j]).abs();
            let tol = (IN as f64 + 1.0) * f64::from(f32::EPSILON) * scale;
            assert!((f64::from(*g) - w).abs() <= tol, "{IN}x{OUT} output {j}: {g} vs {w}");
        }
    }
}

#[test]
fn f32_layer_tiles_and_remainders_match_reference() {
    check_layer::<7, 70>(3);
    check_layer::<70, 130>(4);
    check_layer::<256, 256>(5);
    check_layer::<256, 3>(6);
    check_layer::<1, 1>(7);
}
