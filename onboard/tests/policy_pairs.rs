//! The int8 pair kernel (a row pair's i16 `256 b + a + 128` against two activations per
//! `smlad`, the high bytes by `sxtb16` into another, the first row recovered from both sums)
//! and the cheaper quantization, checked on the host: here the pair kernel runs its portable
//! emulation, the Cortex-M4 image runs the same steps in `asm!` (scripts/qemu-sil.sh compares
//! the two bit for bit). The lanes and rows kernels decode each byte instead: a second method.

mod policy_support;

use onboard::policy::{
    quantize, quantize_relu, DenseInt8, Int8Kernel, MlpLayers, RendezvousPolicy, TransferPolicy, INT8_KERNEL,
};
use policy_support::{calibrate, int8_layer, int8_net, quantize_net, random_input, QuantLayer, RefNet, Rng};
use shared::blob::{Activation, ProblemKind, ACTIVATION_LEVELS, MAX_INT8_INPUTS};

const KERNELS: [Int8Kernel; 3] = [Int8Kernel::Lanes, Int8Kernel::Rows, Int8Kernel::Pairs];

fn random_layer<const IN: usize, const OUT: usize>(rng: &mut Rng) -> (Vec<Vec<i8>>, Vec<i32>, QuantLayer) {
    let q: Vec<Vec<i8>> = (0..OUT)
        .map(|_| (0..IN).map(|_| rng.next_u64() as u8 as i8).collect())
        .collect();
    let bias: Vec<i32> = (0..OUT).map(|_| (rng.next_u64() as i32) >> 4).collect();
    let ql = QuantLayer {
        q: q.clone(),
        weight_scales: vec![0.01; OUT],
        bias: bias.clone(),
        input_scale: 0.02,
    };
    (q, bias, ql)
}

/// The pair kernel equals the exact dot product plus bias, on random i16 activations over the
/// full quantized range and random i8 weights, for widths that exercise the 8-input block, the
/// last `IN % 8` inputs (odd among them), a third pair and the odd last row.
fn check_pairs<const IN: usize, const OUT: usize>(seed: u64) {
    let mut rng = Rng::new(seed);
    let (q, bias, ql) = random_layer::<IN, OUT>(&mut rng);
    let owned = int8_layer(&ql, Activation::Relu);
    let view = owned.view();
    let layer = DenseInt8::<IN, OUT>::from_layer(&view).unwrap();
    let l = i32::from(ACTIVATION_LEVELS);
    for round in 0..20 {
        let x: [i16; IN] = core::array::from_fn(|i| match round {
            // The extremes, alternating in sign.
            0 => (if i % 2 == 0 { l } else { -l }) as i16,
            1 => -l as i16,
            _ => ((rng.next_u64() % (2 * l as u64 + 1)) as i32 - l) as i16,
        });
        let got = layer.accumulate_pairs(&x);
        for j in 0..OUT {
            let want: i64 = i64::from(bias[j]) + (0..IN).map(|i| i64::from(q[j][i]) * i64::from(x[i])).sum::<i64>();
            assert_eq!(i64::from(got[j]), want, "{IN}x{OUT} row {j} round {round}");
        }
        assert_eq!(layer.accumulate_lanes(&x), got);
        assert_eq!(layer.accumulate_rows(&x), got);
        assert_eq!(layer.accumulate(&x), got);
    }
}

#[test]
fn pair_kernel_equals_the_exact_dot_product() {
    check_pairs::<256, 256>(41);
    check_pairs::<10, 256>(42);
    check_pairs::<22, 256>(43);
    check_pairs::<256, 3>(44);
    check_pairs::<MAX_INT8_INPUTS, 5>(45);
    check_pairs::<1, 1>(46);
    check_pairs::<3, 2>(47);
    check_pairs::<4, 4>(48);
    check_pairs::<8, 9>(49);
    check_pairs::<12, 7>(50);
    check_pairs::<33, 9>(51);
    check_pairs::<64, 4>(52);
}

#[test]
fn pair_kernel_at_the_accumulator_limit() {
    // The largest sum: every weight -128 against -L at the widest int8 layer (2^31 - 2^16
    // before the bias), and the bias saturating at both ends.
    const IN: usize = MAX_INT8_INPUTS;
    const L: i16 = ACTIVATION_LEVELS;
    let ql = QuantLayer {
        q: vec![
            vec![-128; IN],
            vec![-128; IN],
            vec![127; IN],
            vec![-128; IN],
            vec![-128; IN],
        ],
        weight_scales: vec![1.0; 5],
        bias: vec![i32::MAX, i32::MIN, i32::MIN, 0, 65_535],
        input_scale: 1.0,
    };
    let owned = int8_layer(&ql, Activation::Relu);
    let view = owned.view();
    let layer = DenseInt8::<IN, 5>::from_layer(&view).unwrap();
    let top = 128 * i32::from(L) * IN as i32;
    let want = [i32::MAX, i32::MIN + top, i32::MIN, top, i32::MAX];
    assert_eq!(layer.accumulate_pairs(&[-L; IN]), want);
    assert_eq!(layer.accumulate_lanes(&[-L; IN]), want);
}

/// Every kernel gives the same network output bit for bit, equal to the layers' public steps
/// composed in natural order (the f32 first layer, ReLU, quantize, accumulate, dequantize,
/// ReLU, the f32 output layer).
fn check_network<const IN: usize>(
    kind: ProblemKind,
    seed: u64,
    forward: impl Fn(&[u8], &[f32; IN], Int8Kernel) -> [f32; 3],
    layered: impl Fn(&[u8], &[f32; IN]) -> [f32; 3],
) {
    let mut rng = Rng::new(seed);
    let net = RefNet::random(&[IN, 256, 256, 3], 1.0, &mut rng);
    let calib: Vec<Vec<f32>> = (0..50).map(|_| random_input(IN, &mut rng)).collect();
    let bytes = int8_net(&net, &quantize_net(&net, &calibrate(&net, &calib)), kind).encode();
    for n in 0..100 {
        // Some inputs far outside the calibration range, so that activations saturate.
        let gain = if n % 10 == 9 { 1e3 } else { 1.0 };
        let x: [f32; IN] = core::array::from_fn(|_| rng.sym(gain));
        let want = layered(&bytes, &x);
        for k in KERNELS {
            let got = forward(&bytes, &x, k);
            assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "{k:?} input {n}");
        }
    }
}

fn relu(mut v: [f32; 256]) -> [f32; 256] {
    v.iter_mut().for_each(|e| {
        if *e < 0.0 {
            *e = 0.0
        }
    });
    v
}

#[test]
fn every_kernel_gives_the_same_network_output() {
    assert_eq!(
        INT8_KERNEL,
        if cfg!(target_arch = "x86_64") {
            Int8Kernel::Lanes
        } else {
            INT8_KERNEL
        }
    );
    check_network::<10>(
        ProblemKind::Transfer,
        61,
        |b, x, k| {
            TransferPolicy::from_bytes(b, ProblemKind::Transfer)
                .unwrap()
                .forward_with(x, k)
        },
        |b, x| {
            let p = TransferPolicy::from_bytes(b, ProblemKind::Transfer).unwrap();
            let MlpLayers::Int8(l1, l2, l3) = p.layers() else {
                panic!("not int8")
            };
            let q1 = l2.quantize_input(&relu(l1.forward(x)));
            let out = l3.forward(&relu(l2.forward(&q1))).map(libm::tanhf);
            assert_eq!(out.map(f32::to_bits), p.forward(x).map(f32::to_bits));
            out
        },
    );
    check_network::<22>(
        ProblemKind::Rendezvous,
        62,
        |b, x, k| {
            RendezvousPolicy::from_bytes(b, ProblemKind::Rendezvous)
                .unwrap()
                .forward_with(x, k)
        },
        |b, x| {
            let p = RendezvousPolicy::from_bytes(b, ProblemKind::Rendezvous).unwrap();
            let MlpLayers::Int8(l1, l2, l3) = p.layers() else {
                panic!("not int8")
            };
            let q1 = l2.quantize_input(&relu(l1.forward(x)));
            l3.forward(&relu(l2.forward(&q1))).map(libm::tanhf)
        },
    );
}

/// The fused ReLU + quantization of the hidden layers equals quantizing the ReLU, on specials
/// and random bit patterns (the two quantizer implementations, Arm's and the host's, are
/// compared with each other exhaustively near the rounding edges by the unit tests in
/// `policy.rs`).
#[test]
fn fused_relu_quantization_equals_quantizing_the_relu() {
    let mut rng = Rng::new(71);
    let scales = [1.0f32, 0.5, 0.013, 3.7e-3, 1e-30, 7.5e30, 1e-45];
    let special = [
        0.0f32,
        -0.0,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::MAX,
        f32::MIN,
        -0.5,
        0.5,
        -0.499_999_97,
        0.499_999_97,
        32_767.5,
        -32_767.5,
    ];
    let random = (0..200_000).map(|_| f32::from_bits(rng.next_u64() as u32));
    for x in special.into_iter().chain(random) {
        let relu = if x < 0.0 { 0.0 } else { x };
        for s in scales {
            assert_eq!(quantize_relu(x, s), quantize(relu, s), "x {x:e} scale {s:e}");
        }
    }
}
