//! Property tests over shapes: random weights and inputs, both precisions, against the
//! independent f64 reference (f32) and the derived int8 error bound.

mod policy_support;

use onboard::policy::{DenseF32, DenseInt8, Mlp};
use policy_support::{
    calibrate, f32_layer, f32_net, int8_bound, int8_layer, int8_net, quantize_net, random_input, QuantLayer, RefNet,
    Rng,
};
use proptest::prelude::*;
use shared::blob::{Activation, ProblemKind};

/// Whole networks go through the blob encoder and the loader, so their input count is a
/// feature-layout length (10 or 22); hidden and output sizes are free.
fn check_mlp<const IN: usize, const H1: usize, const H2: usize, const OUT: usize>(
    kind: ProblemKind,
    seed: u64,
    gain: f64,
) -> Result<(), TestCaseError> {
    let mut rng = Rng::new(seed);
    let net = RefNet::random(&[IN, H1, H2, OUT], gain, &mut rng);
    let inputs: Vec<Vec<f32>> = (0..8).map(|_| random_input(IN, &mut rng)).collect();

    let bytes = f32_net(&net, kind).encode();
    let policy = Mlp::<IN, H1, H2, OUT>::from_bytes(&bytes, kind).unwrap();
    for x in &inputs {
        let got = policy.forward(&x.clone().try_into().unwrap());
        for (g, w) in got.iter().zip(net.forward(x)) {
            prop_assert!((f64::from(*g) - w).abs() < 1e-5, "f32 {} vs {}", g, w);
        }
    }

    let calib: Vec<Vec<f32>> = (0..20).map(|_| random_input(IN, &mut rng)).collect();
    let quant = quantize_net(&net, &calibrate(&net, &calib));
    let bytes = int8_net(&net, &quant, kind).encode();
    let policy = Mlp::<IN, H1, H2, OUT>::from_bytes(&bytes, kind).unwrap();
    for x in &inputs {
        let got = policy.forward(&x.clone().try_into().unwrap());
        let bound = int8_bound(&net, &quant, x);
        for ((g, w), b) in got.iter().zip(net.forward(x)).zip(bound) {
            let e = (f64::from(*g) - w).abs();
            prop_assert!(e <= b, "int8 error {} above bound {}", e, b);
        }
    }
    Ok(())
}

fn check_f32_layer<const IN: usize, const OUT: usize>(seed: u64) -> Result<(), TestCaseError> {
    let mut rng = Rng::new(seed);
    let net = RefNet::random(&[IN, OUT], 2.0, &mut rng);
    let owned = f32_layer(&net.layers[0], Activation::Relu);
    let view = owned.view();
    let layer = DenseF32::<IN, OUT>::from_layer(&view).unwrap();
    let x: [f32; IN] = random_input(IN, &mut rng).try_into().unwrap();
    let xd: Vec<f64> = x.iter().map(|&v| f64::from(v)).collect();
    let got = layer.forward(&x);
    for (j, (g, w)) in got.iter().zip(net.layers[0].pre(&xd)).enumerate() {
        let mag: f64 = net.layers[0].w[j]
            .iter()
            .zip(&xd)
            .map(|(w, x)| (f64::from(*w) * x).abs())
            .sum::<f64>()
            + f64::from(net.layers[0].b[j]).abs();
        let tol = (IN as f64 + 1.0) * f64::from(f32::EPSILON) * mag;
        prop_assert!((f64::from(*g) - w).abs() <= tol, "{} vs {}", g, w);
    }
    Ok(())
}

fn check_int8_layer<const IN: usize, const OUT: usize>(seed: u64) -> Result<(), TestCaseError> {
    let mut rng = Rng::new(seed);
    let q: Vec<Vec<i8>> = (0..OUT)
        .map(|_| (0..IN).map(|_| rng.next_u64() as u8 as i8).collect())
        .collect();
    let bias: Vec<i32> = (0..OUT).map(|_| rng.next_u64() as i32 >> 8).collect();
    let ql = QuantLayer {
        q: q.clone(),
        weight_scales: vec![0.5; OUT],
        bias: bias.clone(),
        input_scale: 0.25,
    };
    let owned = int8_layer(&ql, Activation::Relu);
    let view = owned.view();
    let layer = DenseInt8::<IN, OUT>::from_layer(&view).unwrap();
    let x: [i16; IN] = core::array::from_fn(|_| ((rng.next_u64() % 65535) as i32 - 32767) as i16);
    let acc = layer.accumulate(&x);
    prop_assert_eq!(layer.accumulate_lanes(&x), acc);
    prop_assert_eq!(layer.accumulate_rows(&x), acc);
    prop_assert_eq!(layer.accumulate_pairs(&x), acc);
    for j in 0..OUT {
        let want = i64::from(bias[j]) + (0..IN).map(|i| i64::from(q[j][i]) * i64::from(x[i])).sum::<i64>();
        prop_assert_eq!(i64::from(acc[j]), want);
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn small_mlps_match_reference(seed in any::<u64>(), gain in 0.5f64..3.0) {
        check_mlp::<15, 5, 4, 4>(ProblemKind::Transfer, seed, gain)?;
        check_mlp::<30, 9, 6, 4>(ProblemKind::Rendezvous, seed, gain)?;
        check_mlp::<22, 16, 8, 3>(ProblemKind::Rendezvous, seed, gain)?;
        check_mlp::<10, 70, 130, 3>(ProblemKind::Transfer, seed, gain)?;
    }

    #[test]
    fn layers_of_any_shape_match_reference(seed in any::<u64>()) {
        check_f32_layer::<3, 5>(seed)?;
        check_f32_layer::<7, 16>(seed)?;
        check_f32_layer::<5, 4>(seed)?;
        check_f32_layer::<16, 8>(seed)?;
        check_f32_layer::<8, 3>(seed)?;
        check_f32_layer::<33, 129>(seed)?;
        check_int8_layer::<3, 5>(seed)?;
        check_int8_layer::<7, 16>(seed)?;
        check_int8_layer::<5, 4>(seed)?;
        check_int8_layer::<16, 8>(seed)?;
        check_int8_layer::<8, 3>(seed)?;
        check_int8_layer::<33, 129>(seed)?;
        check_int8_layer::<70, 6>(seed)?;
    }

    #[test]
    fn any_input_gives_an_output_in_range_or_nan(
        seed in any::<u64>(),
        x in prop::array::uniform10(prop::num::f32::ANY),
    ) {
        let mut rng = Rng::new(seed);
        let net = RefNet::random(&[10, 16, 8, 3], 1.0, &mut rng);
        let calib: Vec<Vec<f32>> = (0..20).map(|_| random_input(10, &mut rng)).collect();
        let quant = quantize_net(&net, &calibrate(&net, &calib));
        let b32 = f32_net(&net, ProblemKind::Transfer).encode();
        let b8 = int8_net(&net, &quant, ProblemKind::Transfer).encode();
        let p32 = Mlp::<10, 16, 8, 3>::from_bytes(&b32, ProblemKind::Transfer).unwrap();
        let p8 = Mlp::<10, 16, 8, 3>::from_bytes(&b8, ProblemKind::Transfer).unwrap();
        let finite = x.iter().all(|v| v.is_finite());
        for y in [p32.forward(&x), p8.forward(&x)] {
            if finite {
                prop_assert!(y.iter().all(|v| v.is_nan() || (-1.0..=1.0).contains(v)));
            } else {
                prop_assert!(y.iter().all(|v| v.is_nan()));
            }
        }
        // int8 never overflows: every finite input gives a finite output.
        if finite {
            prop_assert!(p8.forward(&x).iter().all(|v| v.is_finite()));
        }
    }
}
