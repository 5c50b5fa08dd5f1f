//! From a blob written by the ground side (`shared::blob`) to commands flown by the onboard crate
//! in the SIL loop: the contract between the crates, end to end.

use firmware_sim::{fly_transfer, Dispersions};
use onboard::features::{decode_action, to_network_input, RewardWeights};
use onboard::integrator::Tolerances;
use onboard::policy::{PolicyError, RendezvousPolicy, TransferPolicy};
use shared::blob::{
    decode, encode_to_vec, f32_le_bytes, i32_le_bytes, i8_bytes, Activation, BlobError, FeatureLayout, LayerBlob,
    NetworkBlob, ProblemKind, Quantization,
};
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

/// Deterministic weights (xorshift), scaled like a PyTorch default init (+-1/sqrt(fan_in)).
fn weights(n: usize, fan_in: usize, seed: u64) -> Vec<f32> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let bound = 1.0 / (fan_in as f32).sqrt();
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            ((s >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0) * bound
        })
        .collect()
}

struct OwnedLayer {
    inputs: u16,
    outputs: u16,
    activation: Activation,
    weights: Vec<u8>,
    bias: Vec<u8>,
    scales: Vec<u8>,
    input_scale: f32,
}

/// Largest |input| of each layer over `inputs`, from a plain f32 forward pass: the int8
/// activation calibration the exporter will do on demonstration states.
fn calibrate(sizes: &[usize], seed: u64, inputs: &[Vec<f32>]) -> Vec<f32> {
    let mut max_abs = vec![0f32; sizes.len() - 1];
    for x0 in inputs {
        let mut x = x0.clone();
        for (l, w) in sizes.windows(2).enumerate() {
            let (n_in, n_out) = (w[0], w[1]);
            max_abs[l] = x.iter().fold(max_abs[l], |m, v| m.max(v.abs()));
            let wt = weights(n_in * n_out, n_in, seed + l as u64);
            let b = weights(n_out, n_in, seed + 100 + l as u64);
            x = (0..n_out)
                .map(|j| (b[j] + (0..n_in).map(|i| wt[j * n_in + i] * x[i]).sum::<f32>()).max(0.0))
                .collect();
        }
    }
    max_abs
}

fn calibration_inputs() -> Vec<Vec<f32>> {
    (0..200)
        .map(|index| {
            let s = ScenarioKind::TransferHard.draw(99, index);
            let state = onboard::dynamics::SpacecraftState::from_cartesian(&s.initial.cartesian(), 1.0);
            let f = onboard::features::transfer_features(&state, &s.target, s.time_of_flight()).unwrap();
            to_network_input(&f).to_vec()
        })
        .collect()
}

/// The f32 network in PyTorch layout [out][in], then the blob arrays per quantization.
fn network(sizes: &[usize], quantization: Quantization, seed: u64) -> Vec<OwnedLayer> {
    let calibration = match quantization {
        Quantization::Int8 => calibrate(sizes, seed, &calibration_inputs()),
        Quantization::F32 => Vec::new(),
    };
    let last = sizes.len() - 2;
    sizes
        .windows(2)
        .enumerate()
        .map(|(l, w)| {
            let (n_in, n_out) = (w[0], w[1]);
            let wt = weights(n_in * n_out, n_in, seed + l as u64); // [out][in]
            let b = weights(n_out, n_in, seed + 100 + l as u64);
            let activation = if l == last { Activation::Tanh } else { Activation::Relu };
            let (weights, bias, scales, input_scale) = match quantization {
                Quantization::F32 => {
                    let input_major: Vec<f32> = (0..n_in * n_out).map(|k| wt[(k % n_out) * n_in + k / n_out]).collect();
                    (f32_le_bytes(&input_major), f32_le_bytes(&b), Vec::new(), 1.0)
                }
                Quantization::Int8 => {
                    let input_scale = calibration[l] / 127.0;
                    let scales: Vec<f32> = (0..n_out)
                        .map(|j| wt[j * n_in..(j + 1) * n_in].iter().fold(0f32, |m, x| m.max(x.abs())) / 127.0)
                        .collect();
                    let q: Vec<i8> = (0..n_in * n_out)
                        .map(|k| (wt[k] / scales[k / n_in]).round() as i8)
                        .collect();
                    let bq: Vec<i32> = (0..n_out)
                        .map(|j| (b[j] / (input_scale * scales[j])).round() as i32)
                        .collect();
                    (i8_bytes(&q), i32_le_bytes(&bq), f32_le_bytes(&scales), input_scale)
                }
            };
            OwnedLayer {
                inputs: n_in as u16,
                outputs: n_out as u16,
                activation,
                weights,
                bias,
                scales,
                input_scale,
            }
        })
        .collect()
}

fn blob_bytes(
    layers: &[OwnedLayer],
    kind: ProblemKind,
    features: FeatureLayout,
    quantization: Quantization,
) -> Vec<u8> {
    let mut views = heapless::Vec::new();
    for l in layers {
        views
            .push(LayerBlob {
                inputs: l.inputs,
                outputs: l.outputs,
                activation: l.activation,
                weights: &l.weights,
                bias: &l.bias,
                weight_scales: &l.scales,
                input_scale: l.input_scale,
            })
            .unwrap();
    }
    let blob = NetworkBlob {
        kind,
        features,
        quantization,
        provenance: "integration test",
        layers: views,
    };
    encode_to_vec(&blob).unwrap()
}

fn transfer_blob(quantization: Quantization) -> Vec<u8> {
    let layers = network(&[10, 256, 256, 3], quantization, 11);
    blob_bytes(
        &layers,
        ProblemKind::Transfer,
        FeatureLayout::TransferPolar10,
        quantization,
    )
}

#[test]
fn a_ground_blob_flies_in_the_sil_loop_with_the_commands_the_network_computes() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    for quantization in [Quantization::F32, Quantization::Int8] {
        let bytes = transfer_blob(quantization);
        let policy = TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer).unwrap();
        assert_eq!(policy.quantization(), quantization);
        for index in 0..3 {
            let scenario = ScenarioKind::TransferCircular.draw(2026, index);
            let flight = fly_transfer(
                &policy,
                &scenario,
                &sc,
                &Tolerances::default(),
                &RewardWeights::default(),
                &Dispersions::NONE,
                0,
            )
            .unwrap();
            assert_eq!(flight.steps.len(), scenario.steps as usize);
            for step in &flight.steps {
                // The command flown is the network's action on the features of that step.
                let expect = decode_action(&policy.forward(&to_network_input(&step.features)));
                assert_eq!(step.command, expect);
                assert!(step.guidance_error.is_none());
            }
            // Mass follows the throttle history exactly (constant thrust within each step).
            let burned: f64 = flight.steps.iter().map(|s| s.command.throttle).sum::<f64>() * shared::units::STEP;
            let expect_mass = 1.0 - sc.thrust * burned / sc.exhaust_speed;
            assert!((flight.final_state().m - expect_mass).abs() < 1e-12);
        }
    }
}

#[test]
fn int8_and_f32_blobs_of_one_network_agree_closely() {
    let f32_bytes = transfer_blob(Quantization::F32);
    let i8_bytes = transfer_blob(Quantization::Int8);
    let p32 = TransferPolicy::from_bytes(&f32_bytes, ProblemKind::Transfer).unwrap();
    let p8 = TransferPolicy::from_bytes(&i8_bytes, ProblemKind::Transfer).unwrap();
    let mut worst = 0f32;
    for index in 0..50 {
        let s = ScenarioKind::TransferHard.draw(5, index);
        let state = onboard::dynamics::SpacecraftState::from_cartesian(&s.initial.cartesian(), 1.0);
        let f = onboard::features::transfer_features(&state, &s.target, s.time_of_flight()).unwrap();
        let x = to_network_input(&f);
        let (a, b) = (p32.forward(&x), p8.forward(&x));
        for (u, v) in a.iter().zip(&b) {
            worst = worst.max((u - v).abs());
        }
    }
    // Per-channel int8 of a 10-256-256-3 net with calibrated activations: a few percent of the
    // [-1, 1] action range at most (these 50 states are not the calibration states).
    assert!(worst < 0.05, "worst action difference {worst}");
}

#[test]
fn the_onboard_loader_refuses_what_does_not_fit() {
    let bytes = transfer_blob(Quantization::F32);
    // A transfer blob is not a rendezvous policy (wrong kind before any shape check).
    assert!(matches!(
        RendezvousPolicy::from_bytes(&bytes, ProblemKind::Rendezvous),
        Err(PolicyError::WrongKind { .. })
    ));
    // A rendezvous blob of the right layout decodes but does not load as a transfer policy.
    let rdv = network(&[22, 256, 256, 3], Quantization::F32, 3);
    let rdv_bytes = blob_bytes(
        &rdv,
        ProblemKind::Rendezvous,
        FeatureLayout::RendezvousPolar22,
        Quantization::F32,
    );
    assert!(decode(&rdv_bytes).is_ok());
    assert!(RendezvousPolicy::from_bytes(&rdv_bytes, ProblemKind::Rendezvous).is_ok());
    assert_eq!(
        TransferPolicy::from_bytes(&rdv_bytes, ProblemKind::Transfer).err(),
        Some(PolicyError::WrongKind {
            expected: ProblemKind::Transfer,
            found: ProblemKind::Rendezvous
        })
    );
    // A wrong hidden width is a shape error, not a crash.
    let small = network(&[10, 64, 64, 3], Quantization::F32, 4);
    let small_bytes = blob_bytes(
        &small,
        ProblemKind::Transfer,
        FeatureLayout::TransferPolar10,
        Quantization::F32,
    );
    assert!(matches!(
        TransferPolicy::from_bytes(&small_bytes, ProblemKind::Transfer),
        Err(PolicyError::WrongShape { .. })
    ));
    // A flipped bit anywhere in the payload is caught by the CRC before anything flies.
    let mut corrupt = bytes.clone();
    let mid = corrupt.len() / 2;
    corrupt[mid] ^= 0x10;
    assert!(matches!(
        TransferPolicy::from_bytes(&corrupt, ProblemKind::Transfer),
        Err(PolicyError::Blob(BlobError::CrcMismatch { .. }))
    ));
}
