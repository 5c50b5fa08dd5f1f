//! Loading: every mismatch between a blob and the compiled network is refused with the
//! matching typed error; accepted blobs are used in place (zero copy).

mod policy_support;

use onboard::policy::{
    DenseF32, DenseInt8, LayerArray, LayerShape, MlpLayers, PolicyError, Rendezvous3Policy, RendezvousPolicy,
    TransferPolicy, MLP_LAYERS,
};
use policy_support::{calibrate, f32_net, int8_net, quantize_net, random_input, OwnedNet, RefNet, Rng};
use shared::blob::{self, Activation, BlobError, FeatureLayout, ProblemKind};

fn f32_owned(sizes: &[usize], kind: ProblemKind, seed: u64) -> OwnedNet {
    let mut rng = Rng::new(seed);
    f32_net(&RefNet::random(sizes, 1.0, &mut rng), kind)
}

fn int8_owned(sizes: &[usize], kind: ProblemKind, seed: u64) -> OwnedNet {
    let mut rng = Rng::new(seed);
    let net = RefNet::random(sizes, 1.0, &mut rng);
    let calib: Vec<Vec<f32>> = (0..20).map(|_| random_input(sizes[0], &mut rng)).collect();
    int8_net(&net, &quantize_net(&net, &calibrate(&net, &calib)), kind)
}

fn shape(inputs: usize, outputs: usize) -> LayerShape {
    LayerShape { inputs, outputs }
}

#[test]
fn accepts_both_deployed_shapes_in_both_precisions() {
    for owned in [
        f32_owned(&[10, 256, 256, 3], ProblemKind::Transfer, 1),
        int8_owned(&[10, 256, 256, 3], ProblemKind::Transfer, 1),
    ] {
        let bytes = owned.encode();
        let p = TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer).unwrap();
        assert_eq!(p.kind(), ProblemKind::Transfer);
        assert_eq!(p.features(), FeatureLayout::TransferPolar10);
        assert_eq!(p.quantization(), owned.quantization);
    }
    for owned in [
        f32_owned(&[22, 256, 256, 3], ProblemKind::Rendezvous, 2),
        int8_owned(&[22, 256, 256, 3], ProblemKind::Rendezvous, 2),
    ] {
        let bytes = owned.encode();
        let p = RendezvousPolicy::from_bytes(&bytes, ProblemKind::Rendezvous).unwrap();
        assert_eq!(p.kind(), ProblemKind::Rendezvous);
        assert_eq!(p.quantization(), owned.quantization);
    }
}

#[test]
fn wrong_kind_is_refused() {
    let bytes = f32_owned(&[22, 256, 256, 3], ProblemKind::Rendezvous, 3).encode();
    assert_eq!(
        TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer),
        Err(PolicyError::WrongKind {
            expected: ProblemKind::Transfer,
            found: ProblemKind::Rendezvous
        })
    );
    // The right network type but the wrong expectation.
    assert_eq!(
        RendezvousPolicy::from_bytes(&bytes, ProblemKind::Transfer),
        Err(PolicyError::WrongKind {
            expected: ProblemKind::Transfer,
            found: ProblemKind::Rendezvous
        })
    );
}

#[test]
fn wrong_input_count_is_refused() {
    // A transfer blob (10 features) loaded as a 22-input network.
    let bytes = f32_owned(&[10, 256, 256, 3], ProblemKind::Transfer, 4).encode();
    assert_eq!(
        RendezvousPolicy::from_bytes(&bytes, ProblemKind::Transfer),
        Err(PolicyError::WrongFeatures {
            expected_inputs: 22,
            found: FeatureLayout::TransferPolar10
        })
    );
    // A decoded blob whose first layer does not take the feature count (the decoder refuses
    // to produce one, so it is built directly).
    let owned = f32_owned(&[11, 256, 256, 3], ProblemKind::Transfer, 5);
    assert_eq!(
        TransferPolicy::from_blob(&owned.view(), ProblemKind::Transfer),
        Err(PolicyError::WrongShape {
            layer: 0,
            expected: shape(10, 256),
            found: shape(11, 256)
        })
    );
}

#[test]
fn wrong_hidden_size_is_refused() {
    let bytes = f32_owned(&[10, 128, 256, 3], ProblemKind::Transfer, 6).encode();
    assert_eq!(
        TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer),
        Err(PolicyError::WrongShape {
            layer: 0,
            expected: shape(10, 256),
            found: shape(10, 128)
        })
    );
    let bytes = int8_owned(&[10, 256, 64, 3], ProblemKind::Transfer, 7).encode();
    assert_eq!(
        TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer),
        Err(PolicyError::WrongShape {
            layer: 1,
            expected: shape(256, 256),
            found: shape(256, 64)
        })
    );
}

#[test]
fn wrong_output_count_is_refused() {
    // The blob itself refuses a last layer that is not its layout's action count.
    for owned in [
        f32_owned(&[22, 256, 256, 2], ProblemKind::Rendezvous, 8),
        int8_owned(&[22, 256, 256, 4], ProblemKind::Rendezvous, 9),
    ] {
        let found = owned.layers[2].outputs;
        assert_eq!(
            blob::encode_to_vec(&owned.view()),
            Err(BlobError::OutputMismatch { expected: 3, found })
        );
    }
    // A three-dimensional network (30 inputs, 4 outputs) is not a planar policy, nor the reverse.
    let spatial = int8_owned(&[30, 256, 256, 4], ProblemKind::Rendezvous, 9);
    assert_eq!(spatial.features, FeatureLayout::RendezvousSpatial30);
    let bytes = spatial.encode();
    assert!(Rendezvous3Policy::from_bytes(&bytes, ProblemKind::Rendezvous).is_ok());
    assert_eq!(
        RendezvousPolicy::from_bytes(&bytes, ProblemKind::Rendezvous),
        Err(PolicyError::WrongFeatures {
            expected_inputs: 22,
            found: FeatureLayout::RendezvousSpatial30
        })
    );
    let planar = f32_owned(&[22, 256, 256, 3], ProblemKind::Rendezvous, 8).encode();
    assert_eq!(
        Rendezvous3Policy::from_bytes(&planar, ProblemKind::Rendezvous),
        Err(PolicyError::WrongFeatures {
            expected_inputs: 30,
            found: FeatureLayout::RendezvousPolar22
        })
    );
}

#[test]
fn wrong_layer_count_is_refused() {
    for (sizes, found) in [
        (&[10, 256, 256, 256, 3][..], 4),
        (&[10, 256, 3][..], 2),
        (&[10, 3][..], 1),
    ] {
        let bytes = f32_owned(sizes, ProblemKind::Transfer, 10).encode();
        assert_eq!(
            TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer),
            Err(PolicyError::WrongLayerCount {
                expected: MLP_LAYERS,
                found
            })
        );
    }
}

#[test]
fn corrupt_bytes_are_refused_with_the_blob_error() {
    let mut bytes = f32_owned(&[10, 256, 256, 3], ProblemKind::Transfer, 11).encode();
    let n = bytes.len();
    bytes[n / 2] ^= 0x40;
    assert!(matches!(
        TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer),
        Err(PolicyError::Blob(BlobError::CrcMismatch { .. }))
    ));
    assert!(matches!(
        TransferPolicy::from_bytes(&bytes[..n - 1], ProblemKind::Transfer),
        Err(PolicyError::Blob(BlobError::Truncated { .. }))
    ));
    assert!(matches!(
        TransferPolicy::from_bytes(&[], ProblemKind::Transfer),
        Err(PolicyError::Blob(_))
    ));
}

#[test]
fn inconsistent_hand_built_blobs_are_refused() {
    // Array lengths, scales and activations, which `decode` also checks, are checked again
    // by the loader for blobs built in memory.
    let good = f32_owned(&[10, 256, 256, 3], ProblemKind::Transfer, 12);

    let mut bad = good.clone();
    bad.layers[1].bias.pop();
    assert_eq!(
        TransferPolicy::from_blob(&bad.view(), ProblemKind::Transfer),
        Err(PolicyError::WrongArrayLength {
            layer: 1,
            array: LayerArray::Bias,
            expected: 256 * 4,
            found: 256 * 4 - 1
        })
    );

    let mut bad = good.clone();
    bad.layers[2].weights.truncate(100);
    assert_eq!(
        TransferPolicy::from_blob(&bad.view(), ProblemKind::Transfer),
        Err(PolicyError::WrongArrayLength {
            layer: 2,
            array: LayerArray::Weights,
            expected: 256 * 3 * 4,
            found: 100
        })
    );

    let mut bad = good.clone();
    bad.layers[0].activation = Activation::Tanh;
    assert_eq!(
        TransferPolicy::from_blob(&bad.view(), ProblemKind::Transfer),
        Err(PolicyError::WrongActivation {
            layer: 0,
            expected: Activation::Relu,
            found: Activation::Tanh
        })
    );

    // An f32 network declared int8: its first layer is f32 there too, the second's weight
    // array is 4x too long.
    let mut bad = good.clone();
    bad.quantization = shared::blob::Quantization::Int8;
    assert_eq!(
        TransferPolicy::from_blob(&bad.view(), ProblemKind::Transfer),
        Err(PolicyError::WrongArrayLength {
            layer: 1,
            array: LayerArray::Weights,
            expected: 256 * 256,
            found: 256 * 256 * 4
        })
    );

    let good8 = int8_owned(&[10, 256, 256, 3], ProblemKind::Transfer, 13);
    for s in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        let mut bad = good8.clone();
        bad.layers[1].input_scale = s;
        assert_eq!(
            TransferPolicy::from_blob(&bad.view(), ProblemKind::Transfer),
            Err(PolicyError::BadScale { layer: 1 })
        );
    }
    let mut bad = good8.clone();
    bad.layers[1].weight_scales[0..4].copy_from_slice(&f32::NAN.to_le_bytes());
    assert_eq!(
        TransferPolicy::from_blob(&bad.view(), ProblemKind::Transfer),
        Err(PolicyError::BadScale { layer: 1 })
    );
}

#[test]
fn weights_are_used_in_place() {
    let owned = f32_owned(&[10, 256, 256, 3], ProblemKind::Transfer, 14);
    let bytes = owned.encode();
    let range = bytes.as_ptr_range();
    let p = TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer).unwrap();
    let MlpLayers::F32(l1, l2, l3) = p.layers() else {
        panic!("f32 blob gave an int8 policy")
    };
    for w in [l1.weights(), l2.weights(), l3.weights(), l2.bias()] {
        assert!(range.contains(&w.as_ptr()));
        assert!(w.as_ptr_range().end <= range.end);
    }
    assert_eq!(l2.weights().len(), 256 * 256 * 4);

    let owned = int8_owned(&[22, 256, 256, 3], ProblemKind::Rendezvous, 15);
    let bytes = owned.encode();
    let range = bytes.as_ptr_range();
    let p = RendezvousPolicy::from_bytes(&bytes, ProblemKind::Rendezvous).unwrap();
    let MlpLayers::Int8(l1, l2, l3) = p.layers() else {
        panic!("int8 blob gave an f32 policy")
    };
    for w in [l1.weights(), l2.weights(), l3.weights()] {
        assert!(range.contains(&w.as_ptr()));
        assert!(w.as_ptr_range().end <= range.end);
    }
    assert_eq!(l2.weights().len(), 256 * 256);
    // The policy itself is a handful of slices, not a copy of the weights.
    assert!(core::mem::size_of::<RendezvousPolicy<'_>>() < 256);
}

#[test]
fn layer_views_check_their_const_shape() {
    let owned = f32_owned(&[10, 256, 256, 3], ProblemKind::Transfer, 16);
    let view = owned.view();
    assert!(DenseF32::<10, 256>::from_layer(&view.layers[0]).is_ok());
    assert_eq!(
        DenseF32::<10, 255>::from_layer(&view.layers[0]),
        Err(PolicyError::WrongShape {
            layer: 0,
            expected: shape(10, 255),
            found: shape(10, 256)
        })
    );
    // Zero widths are refused even when the blob agrees, so no kernel runs on them.
    let empty = policy_support::OwnedLayer {
        inputs: 0,
        outputs: 3,
        activation: Activation::Tanh,
        weights: Vec::new(),
        bias: vec![0; 12],
        weight_scales: Vec::new(),
        input_scale: 1.0,
    };
    assert_eq!(
        DenseF32::<0, 3>::from_layer(&empty.view()),
        Err(PolicyError::WrongShape {
            layer: 0,
            expected: shape(0, 3),
            found: shape(0, 3)
        })
    );
    assert!(DenseInt8::<0, 3>::from_layer(&empty.view()).is_err());
    // An f32 layer is not an int8 layer.
    assert!(matches!(
        DenseInt8::<10, 256>::from_layer(&view.layers[0]),
        Err(PolicyError::WrongArrayLength { .. })
    ));
}

#[test]
fn errors_display_their_details() {
    let e = PolicyError::WrongShape {
        layer: 2,
        expected: shape(256, 3),
        found: shape(256, 4),
    };
    assert_eq!(e.to_string(), "layer 2 is 256x4, expected 256x3");
    let e = PolicyError::WrongKind {
        expected: ProblemKind::Transfer,
        found: ProblemKind::Rendezvous,
    };
    assert_eq!(e.to_string(), "blob is for Rendezvous, expected Transfer");
    let e = PolicyError::WrongLayerCount { expected: 3, found: 4 };
    assert_eq!(e.to_string(), "network has 4 layers, expected 3");
    let e = PolicyError::from(BlobError::NoLayers);
    assert!(e.to_string().starts_with("invalid weight blob: "));
}
