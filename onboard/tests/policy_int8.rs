//! int8 inference: exact integer kernel, quantization semantics, and the end-to-end error
//! against the f32 network's f64 reference within a bound derived from the scales.

mod policy_support;

use onboard::policy::{DenseInt8, Rendezvous3Policy, RendezvousPolicy, Transfer3Policy, TransferPolicy};
use policy_support::{
    calibrate, int8_bound, int8_emulate, int8_layer, int8_net, quantize_layer, quantize_net, random_input, RefNet, Rng,
};
use shared::blob::{Activation, ProblemKind, Quantization};

/// Error statistics of an int8 policy against the exact (f64) output of its f32 network.
struct Stats {
    max_err: f64,
    median_err: f64,
    median_bound: f64,
    max_bound: f64,
    /// Median over all outputs of bound / error.
    median_ratio: f64,
    /// Share of outputs whose bound is below 2 (the trivial bound for tanh outputs).
    informative: f64,
}

/// Builds an int8 policy from a random f32 network (PyTorch init times `gain`), calibrates the
/// activation scales on 200 random inputs, and checks `n` fresh inputs against the derived bound.
fn run_int8<const IN: usize, const OUT: usize>(
    kind: ProblemKind,
    seed: u64,
    gain: f64,
    n: usize,
    forward: impl Fn(&[u8], &[f32; IN]) -> [f32; OUT],
) -> Stats {
    let mut rng = Rng::new(seed);
    let net = RefNet::random(&[IN, 256, 256, OUT], gain, &mut rng);
    let calib: Vec<Vec<f32>> = (0..200).map(|_| random_input(IN, &mut rng)).collect();
    let scales = calibrate(&net, &calib);
    let quant = quantize_net(&net, &scales);
    let bytes = int8_net(&net, &quant, kind).encode();
    let mut errs = Vec::new();
    let mut bounds = Vec::new();
    let mut ratios = Vec::new();
    for _ in 0..n {
        let x = random_input(IN, &mut rng);
        let xa: [f32; IN] = x.clone().try_into().unwrap();
        let got = forward(&bytes, &xa);
        let want = net.forward(&x);
        let emulated = int8_emulate(&net, &quant, &x);
        let bound = int8_bound(&net, &quant, &x);
        for (((g, w), b), e8) in got.iter().zip(&want).zip(&bound).zip(&emulated) {
            // The kernel is the int8 scheme (f32 rounding aside: at 16-bit activations an f32
            // quotient next to a rounding tie can move one activation by one level)...
            assert!((f64::from(*g) - e8).abs() < 1e-4, "kernel {g} vs emulation {e8}");
            // ...and the scheme's error is within the bound derived from the scales.
            let e = (f64::from(*g) - w).abs();
            assert!(e <= *b, "int8 error {e} above the derived bound {b}");
            errs.push(e);
            bounds.push(*b);
            ratios.push(b / e.max(1e-12));
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let informative = bounds.iter().filter(|&&b| b < 2.0).count() as f64 / bounds.len() as f64;
    Stats {
        max_err: errs.iter().copied().fold(0.0, f64::max),
        median_err: median(&mut errs),
        max_bound: bounds.iter().copied().fold(0.0, f64::max),
        median_bound: median(&mut bounds),
        median_ratio: median(&mut ratios),
        informative,
    }
}

fn report(name: &str, s: &Stats) {
    println!(
        "{name} int8 vs exact: max error {:.3e}, median error {:.3e}; derived bound: median \
         {:.3e}, max {:.3e}; median bound/error per output {:.0}; bound < 2 for {:.0}% of outputs",
        s.max_err,
        s.median_err,
        s.median_bound,
        s.max_bound,
        s.median_ratio,
        100.0 * s.informative
    );
    // Sound (checked per output in run_int8), informative, and not 1000x above what is seen:
    // a worst case over 256-term sums of errors that in practice partly cancel.
    assert!(s.informative > 0.9, "bound vacuous");
    assert!(s.max_err * 1000.0 > s.max_bound, "bound 1000x the observed error");
    assert!(s.max_err > 0.0);
}

#[test]
fn transfer_int8_within_derived_bound() {
    let s = run_int8::<10, 3>(ProblemKind::Transfer, 11, 1.0, 300, |bytes, x| {
        let p = TransferPolicy::from_bytes(bytes, ProblemKind::Transfer).unwrap();
        assert_eq!(p.quantization(), Quantization::Int8);
        p.forward(x)
    });
    report("transfer (gain 1)", &s);
    // With PyTorch-scale weights the int8 actor is within a few percent of full scale.
    assert!(s.max_err < 0.05);
}

#[test]
fn rendezvous_int8_within_derived_bound() {
    let s = run_int8::<22, 3>(ProblemKind::Rendezvous, 12, 1.0, 300, |bytes, x| {
        RendezvousPolicy::from_bytes(bytes, ProblemKind::Rendezvous)
            .unwrap()
            .forward(x)
    });
    report("rendezvous (gain 1)", &s);
}

#[test]
fn three_dimensional_int8_policies_within_derived_bound() {
    let s = run_int8::<15, 4>(ProblemKind::Transfer, 13, 1.0, 300, |bytes, x| {
        Transfer3Policy::from_bytes(bytes, ProblemKind::Transfer)
            .unwrap()
            .forward(x)
    });
    report("transfer 3D (gain 1)", &s);
    let s = run_int8::<30, 4>(ProblemKind::Rendezvous, 14, 1.0, 300, |bytes, x| {
        Rendezvous3Policy::from_bytes(bytes, ProblemKind::Rendezvous)
            .unwrap()
            .forward(x)
    });
    report("rendezvous 3D (gain 1)", &s);
}

/// The integer accumulators equal the exact i64 dot product plus bias, for widths that
/// exercise the 4-row groups and their remainder.
fn check_accumulate<const IN: usize, const OUT: usize>(seed: u64) {
    let mut rng = Rng::new(seed);
    let q: Vec<Vec<i8>> = (0..OUT)
        .map(|_| (0..IN).map(|_| (rng.next_u64() % 256) as u8 as i8).collect())
        .collect();
    let bias: Vec<i32> = (0..OUT)
        .map(|_| (rng.next_u64() % 2_000_001) as i32 - 1_000_000)
        .collect();
    let ql = policy_support::QuantLayer {
        q: q.clone(),
        weight_scales: vec![0.01; OUT],
        bias: bias.clone(),
        input_scale: 0.02,
    };
    let owned = int8_layer(&ql, Activation::Relu);
    let view = owned.view();
    let layer = DenseInt8::<IN, OUT>::from_layer(&view).unwrap();
    for _ in 0..20 {
        let x: [i16; IN] = core::array::from_fn(|_| ((rng.next_u64() % 65535) as i32 - 32767) as i16);
        let got = layer.accumulate(&x);
        // Both kernel forms (the target picks one) give the same exact sums.
        assert_eq!(layer.accumulate_lanes(&x), got);
        assert_eq!(layer.accumulate_rows(&x), got);
        assert_eq!(layer.accumulate_pairs(&x), got);
        for j in 0..OUT {
            let want: i64 = i64::from(bias[j]) + (0..IN).map(|i| i64::from(q[j][i]) * i64::from(x[i])).sum::<i64>();
            assert_eq!(i64::from(got[j]), want, "{IN}x{OUT} row {j}");
        }
        // Dequantization: (acc) * input_scale * weight_scale.
        let y = layer.forward(&x);
        for j in 0..OUT {
            let want = got[j] as f32 * (0.02f32 * 0.01f32);
            assert_eq!(y[j], want);
        }
    }
}

#[test]
fn int8_accumulators_are_exact() {
    check_accumulate::<256, 256>(21);
    check_accumulate::<10, 7>(22);
    check_accumulate::<22, 3>(23);
    check_accumulate::<1, 1>(24);
    check_accumulate::<512, 5>(25);
    check_accumulate::<33, 9>(26);
    check_accumulate::<64, 4>(27);
}

#[test]
fn extreme_weights_and_inputs_do_not_overflow() {
    // All weights -128 against inputs -L at the widest int8 layer: the largest sum; bias at
    // the i32 extremes saturates rather than wrapping.
    const IN: usize = shared::blob::MAX_INT8_INPUTS;
    const L: i16 = shared::blob::ACTIVATION_LEVELS;
    let ql = policy_support::QuantLayer {
        q: vec![vec![-128; IN], vec![-128; IN]],
        weight_scales: vec![1.0; 2],
        bias: vec![i32::MAX, i32::MIN],
        input_scale: 1.0,
    };
    let owned = int8_layer(&ql, Activation::Relu);
    let view = owned.view();
    let layer = DenseInt8::<IN, 2>::from_layer(&view).unwrap();
    let want = [i32::MAX, i32::MIN + 128 * i32::from(L) * IN as i32];
    assert_eq!(layer.accumulate_lanes(&[-L; IN]), want);
    assert_eq!(layer.accumulate_rows(&[-L; IN]), want);
    assert_eq!(layer.accumulate_pairs(&[-L; IN]), want);
}

#[test]
fn input_quantization_rounds_half_away_and_clamps() {
    let mut rng = Rng::new(31);
    let net = RefNet::random(&[6, 2], 1.0, &mut rng);
    let ql = quantize_layer(&net.layers[0], 0.5);
    let owned = int8_layer(&ql, Activation::Relu);
    let view = owned.view();
    let layer = DenseInt8::<6, 2>::from_layer(&view).unwrap();
    assert_eq!(layer.input_scale(), 0.5);
    let q = layer.quantize_input(&[0.25, -0.25, 0.74, 1e6, -1e6, f32::NAN]);
    assert_eq!(q, [1, -1, 1, 32767, -32767, 0]);
    let q = layer.quantize_input(&[0.2499, -0.7501, 63.5, -63.75, f32::INFINITY, 16383.75]);
    assert_eq!(q, [0, -2, 127, -128, 32767, 32767]);
}

/// The next f32 toward +inf (`f32::next_up` needs Rust 1.86; the MSRV is 1.85).
fn next_up(t: f32) -> f32 {
    if t == 0.0 {
        f32::from_bits(1)
    } else if t > 0.0 {
        f32::from_bits(t.to_bits() + 1)
    } else {
        f32::from_bits(t.to_bits() - 1)
    }
}

#[test]
fn input_quantization_matches_f64_rounding() {
    // round(x / s) half away from zero, clamped, against f64 on random values, exact ties
    // (k / 2 steps) and values next to ties.
    let mut rng = Rng::new(32);
    let net = RefNet::random(&[16, 1], 1.0, &mut rng);
    for scale in [1.0f32, 0.5, 0.013, 3.7e-3, 0.25] {
        let ql = quantize_layer(&net.layers[0], scale);
        let owned = int8_layer(&ql, Activation::Relu);
        let view = owned.view();
        let layer = DenseInt8::<16, 1>::from_layer(&view).unwrap();
        for round in 0..2000 {
            let x: [f32; 16] = core::array::from_fn(|k| match round % 3 {
                0 => rng.sym(40_000.0 * f64::from(scale)),
                1 => (((rng.next_u64() % 600) as i32 - 300) as f32 * 0.5) * scale,
                _ => {
                    let t = (((rng.next_u64() % 600) as i32 - 300) as f32 * 0.5) * scale;
                    if k % 2 == 0 {
                        next_up(t)
                    } else {
                        -next_up(-t)
                    }
                }
            });
            let q = layer.quantize_input(&x);
            for (&qi, &xi) in q.iter().zip(&x) {
                // The kernel divides in f32, so round the f32 quotient.
                let want = f64::from(xi / scale).round().clamp(-32767.0, 32767.0) as i16;
                assert_eq!(qi, want, "x {xi} scale {scale}");
            }
        }
    }
}
