//! From a blob written by the ground side (`shared::blob`) to commands flown by the onboard crate
//! in the SIL loop: the contract between the crates, end to end.

use firmware_sim::{
    fly, fly_observed, Controller, Dispersions, FlightSetup, FlightStep, PlanarProblem, Rendezvous, Transfer,
};
use ground_core::env::{EnvConfig, Environment, MdpEnv, Planar};
use onboard::features::{decode_action, to_network_input, RENDEZVOUS_FEATURES, TRANSFER_FEATURES};
use onboard::guidance::Actor;
use onboard::policy::{PolicyError, RendezvousPolicy, TransferPolicy};
use shared::blob::{
    decode, encode_to_vec, f32_le_bytes, f32_weight_bytes, i32_le_bytes, int8_weight_bytes, Activation, BlobError,
    FeatureLayout, LayerBlob, NetworkBlob, ProblemKind, Quantization, FORMAT_VERSION,
};
use shared::scenario::{Scenario, ScenarioKind};
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

/// Network inputs at the start of draws of the hard distribution of the network's problem
/// (told by its input count).
fn calibration_inputs(inputs: usize) -> Vec<Vec<f32>> {
    (0..200)
        .map(|index| {
            let rendezvous = inputs == RENDEZVOUS_FEATURES;
            let kind = if rendezvous {
                ScenarioKind::RendezvousHard
            } else {
                ScenarioKind::TransferHard
            };
            let s = kind.draw(99, index);
            let state = onboard::dynamics::SpacecraftState::from_cartesian(&s.initial.cartesian(), 1.0);
            if rendezvous {
                let body = s.target.cartesian_at(s.target_nu0);
                let f = onboard::features::rendezvous_features(&state, &body, s.time_of_flight()).unwrap();
                to_network_input(&f).to_vec()
            } else {
                let f = onboard::features::transfer_features(&state, &s.target, s.time_of_flight()).unwrap();
                to_network_input(&f).to_vec()
            }
        })
        .collect()
}

/// The f32 network in PyTorch layout [out][in], then the blob arrays per quantization.
fn network(sizes: &[usize], quantization: Quantization, seed: u64) -> Vec<OwnedLayer> {
    let calibration = match quantization {
        Quantization::Int8 => calibrate(sizes, seed, &calibration_inputs(sizes[0])),
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
            let (weights, bias, scales, input_scale) = match quantization.of_layer(l, sizes.len() - 1) {
                Quantization::F32 => (f32_weight_bytes(&wt, n_in), f32_le_bytes(&b), Vec::new(), 1.0),
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
                    (
                        int8_weight_bytes(&q, n_in),
                        i32_le_bytes(&bq),
                        f32_le_bytes(&scales),
                        input_scale,
                    )
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
                padding: &[],
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
        mission: shared::blob::BlobMission::THESIS,
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

fn rendezvous_blob(quantization: Quantization) -> Vec<u8> {
    let layers = network(&[22, 256, 256, 3], quantization, 17);
    blob_bytes(
        &layers,
        ProblemKind::Rendezvous,
        FeatureLayout::RendezvousPolar22,
        quantization,
    )
}

/// Flies `scenario` in the SIL without dispersions and through the ground environment of the
/// same problem, the environment's actions from `actor` on its observations, and requires the
/// same episode bit for bit: observation, command, state, reward and residuals at every step.
fn sil_is_the_environment<const N: usize, P, E>(problem: P, actor: &impl Actor<N>, scenario: &Scenario)
where
    P: PlanarProblem<N>,
    E: Environment<Obs = [f32; N], Geometry = Planar>,
{
    let config = EnvConfig::default();
    let spacecraft = config.spacecraft.canonical().unwrap();
    let mut steps: Vec<FlightStep<N>> = Vec::new();
    let setup = FlightSetup {
        spacecraft,
        tolerances: config.integrator.tolerances(),
        weights: config.reward.weights(),
        dispersions: Dispersions::NONE,
        time_unit_s: shared::units::TIME_UNIT_S,
    };
    let summary = fly_observed(problem, actor, scenario, &setup, 0, |k| steps.push(*k)).unwrap();
    assert_eq!(summary.steps, scenario.steps);
    let mut env = E::new(&config).unwrap();
    let mut obs = env.reset(scenario).unwrap();
    let mut total = 0.0;
    for k in &steps {
        assert_eq!(obs, to_network_input(&k.features), "observation at step {}", k.index);
        let step = env.step(&actor.act(&obs)).unwrap();
        assert_eq!(step.info.command, k.command, "command at step {}", k.index);
        assert!(k.guidance_error.is_none());
        assert_eq!(step.info.state, k.state, "state after step {}", k.index);
        assert_eq!(step.info.residuals, k.residuals, "residuals after step {}", k.index);
        assert_eq!(step.reward.to_bits(), k.reward.to_bits(), "reward of step {}", k.index);
        assert_eq!(step.done, k.index + 1 == scenario.steps);
        total += step.reward;
        obs = step.observation;
    }
    assert_eq!(total.to_bits(), summary.total_reward.to_bits());
}

#[test]
fn without_dispersions_the_sil_flies_the_ground_environments_episodes() {
    for quantization in [Quantization::F32, Quantization::Int8] {
        let bytes = transfer_blob(quantization);
        let transfer = Controller::load_transfer(&bytes);
        assert!(matches!(transfer, Controller::Network(_)));
        let bytes = rendezvous_blob(quantization);
        let rendezvous = Controller::load_rendezvous(&bytes);
        assert!(matches!(rendezvous, Controller::Network(_)));
        for index in 0..3 {
            let scenario = ScenarioKind::TransferCircular.draw(2026, index);
            sil_is_the_environment::<TRANSFER_FEATURES, _, MdpEnv<ground_core::env::Transfer>>(
                Transfer, &transfer, &scenario,
            );
            for kind in [ScenarioKind::RendezvousCircular, ScenarioKind::RendezvousHard] {
                let scenario = kind.draw(2026, index);
                sil_is_the_environment::<RENDEZVOUS_FEATURES, _, MdpEnv<ground_core::env::Rendezvous>>(
                    Rendezvous,
                    &rendezvous,
                    &scenario,
                );
            }
        }
    }
}

/// The blob's refused variants: one payload byte flipped, the last 1,000 bytes cut, the next
/// format version (as scripts/qemu-sil.sh makes them).
fn spoiled(bytes: &[u8]) -> [(&'static str, Vec<u8>); 3] {
    let mut altered = bytes.to_vec();
    let mid = altered.len() / 2;
    altered[mid] ^= 0xff;
    let mut version = bytes.to_vec();
    version[4..6].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
    [
        ("altered", altered),
        ("truncated", bytes[..bytes.len() - 1000].to_vec()),
        ("version", version),
    ]
}

#[test]
fn the_sil_controller_refuses_bad_blobs_of_either_problem_and_flies_them_thrust_off() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let dispersed = FlightSetup::nominal(sc).dispersed(Dispersions::TYPICAL);
    for quantization in [Quantization::F32, Quantization::Int8] {
        let (transfer, rendezvous) = (transfer_blob(quantization), rendezvous_blob(quantization));
        let t = ScenarioKind::TransferCircular.draw(7, 0);
        let r = ScenarioKind::RendezvousCircular.draw(7, 0);
        // Each refusal is typed; the flight goes on in safe mode, thrust off, dispersions and all.
        let bad = spoiled(&rendezvous);
        let mut refused: Vec<_> = bad
            .iter()
            .map(|(what, bytes)| (*what, Controller::load_rendezvous(bytes)))
            .collect();
        refused.push(("transfer blob", Controller::load_rendezvous(&transfer)));
        for (what, controller) in &refused {
            let Controller::SafeMode(error) = controller else {
                panic!("{what}: a rendezvous blob {what} was loaded");
            };
            match *what {
                "altered" => assert!(matches!(error, PolicyError::Blob(BlobError::CrcMismatch { .. }))),
                "transfer blob" => assert_eq!(
                    *error,
                    PolicyError::WrongKind {
                        expected: ProblemKind::Rendezvous,
                        found: ProblemKind::Transfer
                    }
                ),
                _ => assert!(matches!(error, PolicyError::Blob(_)), "{what}: {error:?}"),
            }
            let flight = fly(Rendezvous, controller, &r, &dispersed, 3).unwrap();
            assert_eq!(flight.steps.len(), r.steps as usize);
            assert!(flight
                .steps
                .iter()
                .all(|k| k.command.throttle == 0.0 && k.applied.throttle == 0.0));
            assert_eq!(flight.final_state().m, 1.0, "{what}");
        }
        // And the same for a transfer controller.
        let bad = spoiled(&transfer);
        let mut refused: Vec<_> = bad
            .iter()
            .map(|(what, bytes)| (*what, Controller::load_transfer(bytes)))
            .collect();
        refused.push(("rendezvous blob", Controller::load_transfer(&rendezvous)));
        for (what, controller) in &refused {
            assert!(matches!(controller, Controller::SafeMode(_)), "{what}");
            let flight = fly(Transfer, controller, &t, &dispersed, 3).unwrap();
            assert!(flight.steps.iter().all(|k| k.command.throttle == 0.0), "{what}");
            assert_eq!(flight.final_state().m, 1.0, "{what}");
        }
    }
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
            let flight = fly(Transfer, &policy, &scenario, &FlightSetup::nominal(sc), 0).unwrap();
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

/// A family of `kind`'s orbits with the target's plane inclined 1 to 5 degrees, any node.
fn inclined(kind: ScenarioKind) -> shared::mission::SpatialFamily {
    let inclination = shared::scenario::Range {
        lo: 1f64.to_radians(),
        hi: 5f64.to_radians(),
    };
    shared::mission::SpatialFamily::inclined_target(kind.family(), inclination)
}

/// A three-dimensional network of `inputs` features and 4 actions, as the ground exports it:
/// the f32 blob, and the int8 blob calibrated on `calibration`.
fn spatial_blobs(features: FeatureLayout, seed: u64, calibration: &[Vec<f32>]) -> [Vec<u8>; 2] {
    use shared::quantize::{DenseWeights, MlpWeights};
    let sizes = [features.len(), 256, 256, features.actions()];
    let layers = sizes
        .windows(2)
        .enumerate()
        .map(|(l, w)| DenseWeights {
            inputs: w[0],
            outputs: w[1],
            weights: weights(w[0] * w[1], w[0], seed + l as u64),
            bias: weights(w[1], w[0], seed + 100 + l as u64),
            activation: if l == 2 { Activation::Tanh } else { Activation::Relu },
        })
        .collect();
    let network = MlpWeights { features, layers };
    let f32_blob = network.f32_blob("integration test").unwrap();
    let (int8_blob, _) = network.int8_blob(calibration, "integration test").unwrap();
    [f32_blob, int8_blob]
}

/// [`sil_is_the_environment`] in three dimensions: the SIL's RTN loop and the 3D environment fly
/// the same episode bit for bit.
fn spatial_sil_is_the_environment<const N: usize, P, E>(
    problem: P,
    actor: &impl Actor<N, 4>,
    scenario: &shared::scenario::SpatialScenario,
) where
    P: firmware_sim::Problem<N, Geometry = firmware_sim::Spatial>,
    P::Target: onboard::guidance::SpatialTargetFeatures<N>,
    E: Environment<Obs = [f32; N], Geometry = ground_core::env::Spatial>,
{
    let config = EnvConfig::default();
    let setup = FlightSetup::nominal(config.spacecraft.canonical().unwrap());
    let flight = firmware_sim::fly(problem, actor, scenario, &setup, 0).unwrap();
    assert_eq!(flight.summary.steps, scenario.scenario.steps);
    let mut env = E::new(&config).unwrap();
    let mut obs = env.reset(scenario).unwrap();
    let mut thrusting = 0;
    for k in &flight.steps {
        assert_eq!(obs, to_network_input(&k.features), "observation at step {}", k.index);
        let step = env.step(&actor.act(&obs)).unwrap();
        assert_eq!(step.info.command, k.command, "command at step {}", k.index);
        assert!(k.guidance_error.is_none());
        assert_eq!(step.info.state, k.state, "state after step {}", k.index);
        assert_eq!(step.info.residuals, k.residuals, "residuals after step {}", k.index);
        assert_eq!(
            step.info.base_reward.to_bits(),
            k.reward.to_bits(),
            "reward of step {}",
            k.index
        );
        thrusting += usize::from(k.command.throttle > 0.0 && k.command.normal.abs() > 1e-3);
        obs = step.observation;
    }
    assert!(
        thrusting > 0,
        "the network never thrusted out of the plane: the test shows little"
    );
}

#[test]
fn without_dispersions_the_3d_sil_flies_the_ground_environments_episodes() {
    use firmware_sim::{Rendezvous3, Transfer3};
    use ground_core::env::{Rendezvous3 as Rendezvous3Mdp, Transfer3 as Transfer3Mdp};
    use onboard::features::{ACTION3_LEN, RENDEZVOUS3_FEATURES, TRANSFER3_FEATURES};
    let transfers = inclined(ScenarioKind::TransferCircular);
    let rendezvous = inclined(ScenarioKind::RendezvousCircular);
    // Calibration: the features at departure of other draws.
    let at_departure = |family: &shared::mission::SpatialFamily, rendezvous: bool| -> Vec<Vec<f32>> {
        (0..100)
            .map(|i| {
                let s = family.draw(99, i);
                let state = onboard::spatial::SpatialCraftState {
                    orbit: s.departure(),
                    m: 1.0,
                };
                let ttg = s.scenario.time_of_flight();
                if rendezvous {
                    let body = s
                        .target_plane
                        .embed(&s.scenario.target.cartesian_at(s.scenario.target_nu0));
                    to_network_input(&onboard::features::rendezvous3_features(&state, &body, ttg).unwrap()).to_vec()
                } else {
                    let f = onboard::features::transfer3_features(&state, &s.scenario.target, &s.target_plane, ttg);
                    to_network_input(&f.unwrap()).to_vec()
                }
            })
            .collect()
    };
    let transfer_blobs = spatial_blobs(FeatureLayout::TransferSpatial15, 23, &at_departure(&transfers, false));
    let rendezvous_blobs = spatial_blobs(FeatureLayout::RendezvousSpatial30, 29, &at_departure(&rendezvous, true));
    for (t, r) in transfer_blobs.iter().zip(&rendezvous_blobs) {
        let transfer = Controller::<TRANSFER3_FEATURES, ACTION3_LEN>::load::<Transfer3>(t);
        assert!(matches!(transfer, Controller::Network(_)));
        let rendezvous_controller = Controller::<RENDEZVOUS3_FEATURES, ACTION3_LEN>::load::<Rendezvous3>(r);
        assert!(matches!(rendezvous_controller, Controller::Network(_)));
        // The planar loop refuses a 3D blob: safe mode.
        assert!(matches!(Controller::load_transfer(t), Controller::SafeMode(_)));
        for index in 0..2 {
            spatial_sil_is_the_environment::<TRANSFER3_FEATURES, _, MdpEnv<Transfer3Mdp>>(
                Transfer3,
                &transfer,
                &transfers.draw(2026, index),
            );
            spatial_sil_is_the_environment::<RENDEZVOUS3_FEATURES, _, MdpEnv<Rendezvous3Mdp>>(
                Rendezvous3,
                &rendezvous_controller,
                &rendezvous.draw(2026, index),
            );
        }
    }
}
