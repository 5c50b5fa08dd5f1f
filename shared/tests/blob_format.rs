//! The weight-blob format (docs/spec.md section 10): round trips, zero copy, and that every
//! corrupt, truncated, foreign or mis-shaped blob is refused with its own typed error, never a
//! panic.

use proptest::prelude::*;
use serde::Serialize;
use shared::blob::{
    decode, encode, encode_unchecked, encoded_len, f32_at, f32s, i32_at, Activation, AlignedBlob, ArrayKind, BlobError,
    BlobMission, FeatureLayout, LayerBlob, NetworkBlob, PayloadError, ProblemKind, Quantization, FORMAT_VERSION,
    HEADER_LEN, MAGIC, MAX_LAYERS, MAX_WIDTH, TRAILER_LEN, WEIGHT_ALIGN,
};

// ---------------------------------------------------------------- owned test networks

/// SplitMix64: a seeded generator so the "realistic" weights are reproducible.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [lo, hi).
    fn f32(&mut self, lo: f32, hi: f32) -> f32 {
        let u = (self.next() >> 40) as f32 / (1u64 << 24) as f32;
        lo + (hi - lo) * u
    }
}

fn le_f32(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}
fn le_i32(v: &[i32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

#[derive(Clone, Debug)]
struct OwnedLayer {
    inputs: u16,
    outputs: u16,
    activation: Activation,
    weights: Vec<u8>,
    bias: Vec<u8>,
    weight_scales: Vec<u8>,
    input_scale: f32,
}

#[derive(Clone, Debug)]
struct Owned {
    kind: ProblemKind,
    features: FeatureLayout,
    quantization: Quantization,
    provenance: String,
    layers: Vec<OwnedLayer>,
}

impl OwnedLayer {
    fn view(&self) -> LayerBlob<'_> {
        LayerBlob {
            inputs: self.inputs,
            outputs: self.outputs,
            activation: self.activation,
            padding: &[],
            weights: &self.weights,
            bias: &self.bias,
            weight_scales: &self.weight_scales,
            input_scale: self.input_scale,
        }
    }
}

impl Owned {
    fn view(&self) -> NetworkBlob<'_> {
        let mut layers = heapless::Vec::new();
        for l in &self.layers {
            layers.push(l.view()).expect("at most MAX_LAYERS layers");
        }
        // Padded as the encoder pads, so a decoded blob compares equal to its view.
        NetworkBlob {
            kind: self.kind,
            features: self.features,
            quantization: self.quantization,
            provenance: &self.provenance,
            layers,
            mission: BlobMission::THESIS,
        }
        .aligned()
        .expect("a padded copy of a view that fits MAX_LAYERS")
    }
}

/// A valid network of the given layer widths (`widths[0]` must be the feature count).
fn network(features: FeatureLayout, q: Quantization, widths: &[u16], seed: u64) -> Owned {
    let mut rng = Rng(seed);
    let n = widths.len() - 1;
    let layers = (0..n)
        .map(|l| {
            let (i, o) = (widths[l], widths[l + 1]);
            let count = usize::from(i) * usize::from(o);
            let activation = if l + 1 == n { Activation::Tanh } else { Activation::Relu };
            match q.of_layer(l, n) {
                Quantization::F32 => {
                    let w: Vec<f32> = (0..count).map(|_| rng.f32(-0.2, 0.2)).collect();
                    let b: Vec<f32> = (0..o).map(|_| rng.f32(-0.05, 0.05)).collect();
                    OwnedLayer {
                        inputs: i,
                        outputs: o,
                        activation,
                        weights: le_f32(&w),
                        bias: le_f32(&b),
                        weight_scales: Vec::new(),
                        input_scale: 1.0,
                    }
                }
                Quantization::Int8 => {
                    let w: Vec<u8> = (0..count).map(|_| (rng.next() % 255) as u8).collect();
                    let b: Vec<i32> = (0..o).map(|_| rng.next() as i32 / 4096).collect();
                    let s: Vec<f32> = (0..o).map(|_| rng.f32(1e-3, 1e-1)).collect();
                    OwnedLayer {
                        inputs: i,
                        outputs: o,
                        activation,
                        weights: w,
                        bias: le_i32(&b),
                        weight_scales: le_f32(&s),
                        input_scale: rng.f32(0.01, 0.1),
                    }
                }
            }
        })
        .collect();
    Owned {
        kind: features.problem(),
        features,
        quantization: q,
        provenance: format!("cfg=deadbeef run={seed} 2026-01-01"),
        layers,
    }
}

fn small(q: Quantization) -> Owned {
    network(FeatureLayout::TransferPolar10, q, &[10, 2, 4, 3], 7)
}

fn to_bytes(blob: &NetworkBlob<'_>) -> Vec<u8> {
    let mut out = vec![0u8; encoded_len(blob).unwrap()];
    let n = encode(blob, &mut out).unwrap();
    assert_eq!(n, out.len(), "encoded_len must be exact");
    out
}

fn to_bytes_unchecked(blob: &NetworkBlob<'_>) -> Vec<u8> {
    let mut out = vec![0u8; 1 << 20];
    let n = encode_unchecked(blob, &mut out).unwrap();
    out.truncate(n);
    out
}

/// Header + payload + CRC built here with the crc crate directly, independent of the encoder.
fn frame(payload: &[u8]) -> Vec<u8> {
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(payload);
    let mut out = Vec::new();
    out.extend_from_slice(b"LTGB");
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(payload);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

fn within(inner: &[u8], outer: &[u8]) -> bool {
    let o = outer.as_ptr_range();
    let i = inner.as_ptr_range();
    o.start <= i.start && i.end <= o.end
}

fn assert_borrows_from(blob: &NetworkBlob<'_>, bytes: &[u8]) {
    assert!(within(blob.provenance.as_bytes(), bytes), "provenance copied");
    for l in &blob.layers {
        for a in [l.weights, l.bias, l.weight_scales] {
            if !a.is_empty() {
                assert!(within(a, bytes), "array copied, not borrowed");
            }
        }
    }
}

// ---------------------------------------------------------------- round trips

fn check_round_trip(owned: &Owned) {
    let blob = owned.view();
    let bytes = to_bytes(&blob);
    let back = decode(&bytes).unwrap();
    assert_eq!(back, blob);
    assert_borrows_from(&back, &bytes);
    // Unaligned start: arrays are read bytewise, so an odd offset must work just as well.
    let mut shifted = vec![0u8; 1];
    shifted.extend_from_slice(&bytes);
    let back = decode(&shifted[1..]).unwrap();
    assert_eq!(back, blob);
    assert_borrows_from(&back, &shifted[1..]);
}

#[test]
fn round_trip_realistic_f32_transfer_10_256_256_3() {
    let owned = network(FeatureLayout::TransferPolar10, Quantization::F32, &[10, 256, 256, 3], 1);
    check_round_trip(&owned);
    let bytes = to_bytes(&owned.view());
    let back = decode(&bytes).unwrap();
    let w = back.layers[1].weights;
    assert_eq!(w.len(), 256 * 256 * 4);
    let orig = &owned.layers[1].weights;
    for k in [0, 1, 777, 256 * 256 - 1] {
        assert_eq!(f32_at(w, k), f32_at(orig, k));
    }
}

#[test]
fn round_trip_realistic_int8_rendezvous_22_256_256_3() {
    let owned = network(
        FeatureLayout::RendezvousPolar22,
        Quantization::Int8,
        &[22, 256, 256, 3],
        2,
    );
    check_round_trip(&owned);
}

#[test]
fn encode_reports_a_short_buffer_and_writes_only_the_prefix_of_a_long_one() {
    let owned = small(Quantization::Int8);
    let blob = owned.view();
    let n = encoded_len(&blob).unwrap();
    let mut short = vec![0u8; n - 1];
    assert_eq!(
        encode(&blob, &mut short),
        Err(BlobError::BufferTooSmall {
            needed: n,
            available: n - 1
        })
    );
    let mut long = vec![0xAAu8; n + 5];
    assert_eq!(encode(&blob, &mut long), Ok(n));
    assert!(long[n..].iter().all(|&b| b == 0xAA));
    assert_eq!(decode(&long[..n]).unwrap(), blob);
}

#[test]
fn header_is_as_documented_and_the_trailer_is_the_standard_crc32() {
    // The CRC-32/ISO-HDLC check value: the trailer is the zlib/PNG crc32 any tool computes.
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
    assert_eq!(crc.checksum(b"123456789"), 0xCBF4_3926);

    let owned = small(Quantization::F32);
    let blob = owned.view();
    let bytes = to_bytes(&blob);
    let n = bytes.len();
    assert_eq!(&bytes[..4], &MAGIC);
    assert_eq!(&MAGIC, b"LTGB");
    assert_eq!(u16::from_le_bytes([bytes[4], bytes[5]]), FORMAT_VERSION);
    let len = u32::from_le_bytes(bytes[6..10].try_into().unwrap()) as usize;
    assert_eq!(len, n - HEADER_LEN - TRAILER_LEN);
    let payload = &bytes[HEADER_LEN..n - TRAILER_LEN];
    let mut expect = vec![0u8; len];
    assert_eq!(postcard::to_slice(&blob, &mut expect).unwrap().len(), len);
    assert_eq!(payload, &expect[..], "payload is plain postcard");
    assert_eq!(
        u32::from_le_bytes(bytes[n - 4..].try_into().unwrap()),
        crc.checksum(payload)
    );
    assert_eq!(frame(payload), bytes);
}

// ---------------------------------------------------------------- framing damage

#[test]
fn every_truncation_is_refused_as_truncated() {
    let bytes = to_bytes(&small(Quantization::Int8).view());
    let n = bytes.len();
    for len in 0..n {
        let needed = if len < HEADER_LEN + TRAILER_LEN {
            HEADER_LEN + TRAILER_LEN
        } else {
            n
        };
        assert_eq!(
            decode(&bytes[..len]),
            Err(BlobError::Truncated { needed, found: len }),
            "length {len}"
        );
    }
}

#[test]
fn appended_bytes_are_refused() {
    let mut bytes = to_bytes(&small(Quantization::F32).view());
    let n = bytes.len();
    for extra in 1..=3 {
        bytes.push(0);
        assert_eq!(
            decode(&bytes),
            Err(BlobError::TrailingBytes {
                expected: n,
                found: n + extra
            })
        );
    }
}

#[test]
fn every_single_bit_flip_is_refused_with_the_error_of_its_region() {
    for q in [Quantization::F32, Quantization::Int8] {
        let bytes = to_bytes(&small(q).view());
        let n = bytes.len();
        let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
        for byte in 0..n {
            for bit in 0..8 {
                let mut b = bytes.clone();
                b[byte] ^= 1 << bit;
                let got = decode(&b);
                let want = match byte {
                    0..=3 => BlobError::BadMagic {
                        found: b[..4].try_into().unwrap(),
                    },
                    4..=5 => BlobError::UnsupportedVersion {
                        found: FORMAT_VERSION ^ (1 << (bit + 8 * (byte - 4))),
                        supported: FORMAT_VERSION,
                    },
                    6..=9 => {
                        let declared = u32::from_le_bytes(b[6..10].try_into().unwrap()) as usize;
                        let total = declared + HEADER_LEN + TRAILER_LEN;
                        if total > n {
                            BlobError::Truncated {
                                needed: total,
                                found: n,
                            }
                        } else {
                            BlobError::TrailingBytes {
                                expected: total,
                                found: n,
                            }
                        }
                    }
                    _ => BlobError::CrcMismatch {
                        stored: u32::from_le_bytes(b[n - 4..].try_into().unwrap()),
                        computed: crc.checksum(&b[HEADER_LEN..n - TRAILER_LEN]),
                    },
                };
                assert_eq!(got, Err(want), "{q:?} byte {byte} bit {bit}");
            }
        }
    }
}

/// The payload ends with the mission: a mission written is read back; a payload without it
/// (version 3's) is refused, and so is a mission that cannot be flown.
#[test]
fn the_mission_is_carried_and_checked() {
    let owned = small(Quantization::Int8);
    let weekly = BlobMission {
        cycle: 0.12,
        length_unit_m: 1.0e11,
        time_unit_s: 4.0e6,
        family: 0xdead_beef,
    };
    let view = NetworkBlob {
        mission: weekly,
        ..owned.view()
    };
    let bytes = to_bytes(&view);
    let decoded = decode(&bytes).unwrap();
    assert_eq!(decoded.mission, weekly);
    assert_eq!(decoded, view);
    let mission_len = postcard::to_allocvec(&weekly).unwrap().len();
    let payload = &bytes[HEADER_LEN..bytes.len() - TRAILER_LEN];
    let old_payload = &payload[..payload.len() - mission_len];
    assert!(matches!(decode(&frame(old_payload)), Err(BlobError::Payload(_))));
    for bad in [
        BlobMission {
            cycle: f64::NAN,
            ..weekly
        },
        BlobMission { cycle: -1.0, ..weekly },
        BlobMission {
            length_unit_m: 0.0,
            ..weekly
        },
        BlobMission {
            time_unit_s: f64::INFINITY,
            ..weekly
        },
    ] {
        let view = NetworkBlob {
            mission: bad,
            ..owned.view()
        };
        assert_eq!(
            decode(&to_bytes_unchecked(&view.aligned().unwrap())),
            Err(BlobError::BadMission)
        );
        assert!(matches!(shared::blob::encode_to_vec(&view), Err(BlobError::BadMission)));
    }
}

#[test]
fn wrong_magic_and_other_versions_are_refused() {
    let bytes = to_bytes(&small(Quantization::F32).view());
    let mut b = bytes.clone();
    b[..4].copy_from_slice(b"LTGA");
    assert_eq!(decode(&b), Err(BlobError::BadMagic { found: *b"LTGA" }));
    // The CRC covers the payload only, so a version bump alone is what fires here.
    let mut b = bytes.clone();
    // Version 4 (int8 weights output-major) and the next one: refused, never misread.
    for version in [FORMAT_VERSION - 1, FORMAT_VERSION + 1] {
        b[4..6].copy_from_slice(&version.to_le_bytes());
        assert_eq!(
            decode(&b),
            Err(BlobError::UnsupportedVersion {
                found: version,
                supported: FORMAT_VERSION
            })
        );
    }
}

// ---------------------------------------------------------------- semantic defects

/// `validate`, `encode` and `decode` of a correctly framed blob all report `want`.
fn assert_refused(owned: &Owned, want: BlobError) {
    let blob = owned.view();
    assert_eq!(blob.validate(), Err(want), "validate");
    assert_eq!(encode(&blob, &mut vec![0u8; 1 << 20]), Err(want), "encode");
    assert_eq!(encoded_len(&blob), Err(want), "encoded_len");
    let bytes = to_bytes_unchecked(&blob);
    assert_eq!(decode(&bytes), Err(want), "decode");
}

#[test]
fn kind_and_feature_layout_must_agree() {
    let mut o = network(FeatureLayout::RendezvousPolar22, Quantization::F32, &[22, 8, 3], 3);
    o.kind = ProblemKind::Transfer;
    assert_refused(
        &o,
        BlobError::KindMismatch {
            kind: ProblemKind::Transfer,
            features: FeatureLayout::RendezvousPolar22,
        },
    );
    let mut o = small(Quantization::Int8);
    o.kind = ProblemKind::Rendezvous;
    assert_refused(
        &o,
        BlobError::KindMismatch {
            kind: ProblemKind::Rendezvous,
            features: FeatureLayout::TransferPolar10,
        },
    );
}

#[test]
fn no_layers_and_too_many_layers_are_refused() {
    let mut o = small(Quantization::F32);
    o.layers.clear();
    assert_refused(&o, BlobError::NoLayers);

    // Five layers cannot live in the heapless vector, so write the payload through a mirror
    // struct that serializes identically, and frame it by hand.
    #[derive(Serialize)]
    struct Wide<'a> {
        kind: ProblemKind,
        features: FeatureLayout,
        quantization: Quantization,
        provenance: &'a str,
        layers: &'a [LayerBlob<'a>],
        mission: BlobMission,
    }
    let o = network(
        FeatureLayout::TransferPolar10,
        Quantization::F32,
        &[10, 4, 4, 4, 3, 3],
        4,
    );
    let layers: Vec<LayerBlob<'_>> = o.layers.iter().map(|l| l.view()).collect();
    let wide = Wide {
        kind: o.kind,
        features: o.features,
        quantization: o.quantization,
        provenance: &o.provenance,
        layers: &layers,
        mission: BlobMission::THESIS,
    };
    let mut buf = vec![0u8; 1 << 16];
    let payload = postcard::to_slice(&wide, &mut buf).unwrap();
    // Sanity: with four layers the mirror is byte-identical to the real encoding.
    let mut o4 = o.clone();
    o4.layers.truncate(4);
    o4.layers[3].activation = Activation::Tanh;
    let aligned4 = o4.view();
    let layers4: Vec<LayerBlob<'_>> = aligned4.layers.iter().copied().collect();
    let four = Wide {
        layers: &layers4,
        ..wide
    };
    let mut buf4 = vec![0u8; 1 << 16];
    let p4 = postcard::to_slice(&four, &mut buf4).unwrap().to_vec();
    assert_eq!(to_bytes(&o4.view()), frame(&p4), "mirror matches NetworkBlob");
    assert_eq!(
        decode(&frame(payload)),
        Err(BlobError::TooManyLayers {
            found: 5,
            max: MAX_LAYERS
        })
    );
}

#[test]
fn first_layer_must_take_the_feature_count() {
    let o = network(FeatureLayout::TransferPolar10, Quantization::F32, &[11, 4, 3], 5);
    assert_refused(
        &o,
        BlobError::InputMismatch {
            expected: 10,
            found: 11,
        },
    );
}

#[test]
fn three_dimensional_layouts_round_trip_with_four_action_outputs() {
    for (features, inputs, q) in [
        (FeatureLayout::TransferSpatial15, 15, Quantization::F32),
        (FeatureLayout::RendezvousSpatial30, 30, Quantization::Int8),
    ] {
        assert!(features.is_spatial() && features.actions() == 4 && features.len() == inputs);
        assert_eq!(FeatureLayout::of(features.problem(), true), features);
        let owned = network(features, q, &[inputs as u16, 256, 256, 4], 11);
        check_round_trip(&owned);
    }
    for features in [FeatureLayout::TransferPolar10, FeatureLayout::RendezvousPolar22] {
        assert!(!features.is_spatial() && features.actions() == 3);
        assert_eq!(FeatureLayout::of(features.problem(), false), features);
    }
}

#[test]
fn the_last_layer_must_give_the_layouts_action_count() {
    // A planar network with a fourth output, and a three-dimensional one with three.
    let o = network(FeatureLayout::TransferPolar10, Quantization::F32, &[10, 8, 4], 12);
    assert_refused(&o, BlobError::OutputMismatch { expected: 3, found: 4 });
    let o = network(
        FeatureLayout::RendezvousSpatial30,
        Quantization::Int8,
        &[30, 8, 8, 3],
        13,
    );
    assert_refused(&o, BlobError::OutputMismatch { expected: 4, found: 3 });
}

#[test]
fn consecutive_layers_must_chain() {
    let mut o = network(FeatureLayout::TransferPolar10, Quantization::Int8, &[10, 4, 3], 6);
    // Layer 1 is self-consistent 5x3 but follows a 10x4 layer.
    let other = network(FeatureLayout::TransferPolar10, Quantization::Int8, &[10, 5, 3], 6);
    o.layers[1] = other.layers[1].clone();
    assert_refused(
        &o,
        BlobError::ChainBreak {
            layer: 1,
            expected: 4,
            found: 5,
        },
    );
}

#[test]
fn widths_must_be_between_one_and_max_width() {
    let mut o = network(FeatureLayout::TransferPolar10, Quantization::F32, &[10, 4, 3], 7);
    o.layers[0].outputs = 0;
    assert_refused(
        &o,
        BlobError::BadWidth {
            layer: 0,
            inputs: 10,
            outputs: 0,
        },
    );
    let wide = (MAX_WIDTH + 1) as u16;
    let o = network(FeatureLayout::TransferPolar10, Quantization::Int8, &[10, wide, 3], 7);
    assert_refused(
        &o,
        BlobError::BadWidth {
            layer: 0,
            inputs: 10,
            outputs: wide,
        },
    );
    // MAX_WIDTH itself is accepted.
    let o = network(
        FeatureLayout::TransferPolar10,
        Quantization::Int8,
        &[10, MAX_WIDTH as u16, 3],
        7,
    );
    check_round_trip(&o);
}

#[test]
fn array_lengths_must_match_shape_and_quantization() {
    let base = network(FeatureLayout::TransferPolar10, Quantization::F32, &[10, 4, 3], 8);
    let mut o = base.clone();
    o.layers[0].weights.pop();
    assert_refused(
        &o,
        BlobError::ArrayLength {
            layer: 0,
            array: ArrayKind::Weights,
            expected: 160,
            found: 159,
        },
    );
    let mut o = base.clone();
    o.layers[1].bias.extend_from_slice(&0f32.to_le_bytes());
    assert_refused(
        &o,
        BlobError::ArrayLength {
            layer: 1,
            array: ArrayKind::Bias,
            expected: 12,
            found: 16,
        },
    );
    let mut o = base.clone();
    o.layers[1].weight_scales = le_f32(&[1.0, 1.0, 1.0]);
    assert_refused(
        &o,
        BlobError::ArrayLength {
            layer: 1,
            array: ArrayKind::WeightScales,
            expected: 0,
            found: 12,
        },
    );
    // An F32 network declared Int8: its first and last layers are f32 there too, the hidden
    // layer's weights are 4x too long.
    let base = network(FeatureLayout::TransferPolar10, Quantization::F32, &[10, 4, 5, 3], 8);
    let mut o = base.clone();
    o.quantization = Quantization::Int8;
    assert_refused(
        &o,
        BlobError::ArrayLength {
            layer: 1,
            array: ArrayKind::Weights,
            expected: 20,
            found: 80,
        },
    );
    let int8 = network(FeatureLayout::TransferPolar10, Quantization::Int8, &[10, 4, 5, 3], 8);
    let mut o = int8.clone();
    o.layers[1].weight_scales.truncate(16);
    assert_refused(
        &o,
        BlobError::ArrayLength {
            layer: 1,
            array: ArrayKind::WeightScales,
            expected: 20,
            found: 16,
        },
    );
    // An Int8 network's first and last layers are stored in f32: int8-sized arrays there are
    // refused.
    for (layer, inputs, outputs) in [(0, 10, 4), (2, 5, 3)] {
        let mut o = int8.clone();
        o.layers[layer].weights.truncate(inputs * outputs);
        assert_refused(
            &o,
            BlobError::ArrayLength {
                layer,
                array: ArrayKind::Weights,
                expected: 4 * inputs * outputs,
                found: inputs * outputs,
            },
        );
    }
}

#[test]
fn hidden_layers_must_be_relu_and_the_output_tanh() {
    let base = network(FeatureLayout::TransferPolar10, Quantization::F32, &[10, 4, 4, 3], 9);
    let mut o = base.clone();
    o.layers[1].activation = Activation::Tanh;
    assert_refused(
        &o,
        BlobError::BadActivation {
            layer: 1,
            expected: Activation::Relu,
            found: Activation::Tanh,
        },
    );
    let mut o = base.clone();
    o.layers[2].activation = Activation::Relu;
    assert_refused(
        &o,
        BlobError::BadActivation {
            layer: 2,
            expected: Activation::Tanh,
            found: Activation::Relu,
        },
    );
}

#[test]
fn non_finite_f32_weights_and_biases_are_refused() {
    let base = network(FeatureLayout::TransferPolar10, Quantization::F32, &[10, 4, 3], 10);
    for (bad, array, layer, index) in [
        (f32::NAN, ArrayKind::Weights, 0, 17),
        (f32::INFINITY, ArrayKind::Bias, 1, 2),
        (f32::NEG_INFINITY, ArrayKind::Weights, 1, 0),
    ] {
        let mut o = base.clone();
        let l = &mut o.layers[layer];
        let arr = match array {
            ArrayKind::Weights => &mut l.weights,
            _ => &mut l.bias,
        };
        arr[index * 4..index * 4 + 4].copy_from_slice(&bad.to_le_bytes());
        assert_refused(&o, BlobError::NonFiniteWeight { layer, array, index });
    }
}

#[test]
fn scales_must_be_finite_and_positive() {
    let base = network(FeatureLayout::TransferPolar10, Quantization::Int8, &[10, 4, 4, 3], 11);
    for bad in [0.0f32, -0.5, f32::NAN, f32::INFINITY] {
        let mut o = base.clone();
        o.layers[1].weight_scales[8..12].copy_from_slice(&bad.to_le_bytes());
        assert_refused(
            &o,
            BlobError::BadScale {
                layer: 1,
                channel: Some(2),
                bits: bad.to_bits(),
            },
        );
        let mut o = base.clone();
        o.layers[0].input_scale = bad;
        assert_refused(
            &o,
            BlobError::BadScale {
                layer: 0,
                channel: None,
                bits: bad.to_bits(),
            },
        );
    }
}

#[test]
fn payload_decode_failures_and_leftovers_are_refused() {
    assert_eq!(
        decode(&frame(&[])),
        Err(BlobError::Payload(PayloadError::UnexpectedEnd))
    );
    // Kind discriminant 7 does not exist.
    assert_eq!(
        decode(&frame(&[7, 0, 0, 0, 0])),
        Err(BlobError::Payload(PayloadError::Invalid))
    );
    // Provenance of one byte 0xFF is not UTF-8.
    assert_eq!(
        decode(&frame(&[0, 0, 0, 1, 0xFF, 0])),
        Err(BlobError::Payload(PayloadError::BadUtf8))
    );
    // A valid network followed by one more payload byte, CRC recomputed over both.
    let bytes = to_bytes(&small(Quantization::F32).view());
    let mut payload = bytes[HEADER_LEN..bytes.len() - TRAILER_LEN].to_vec();
    payload.push(0);
    assert_eq!(
        decode(&frame(&payload)),
        Err(BlobError::PayloadNotConsumed { unused: 1 })
    );
}

// ---------------------------------------------------------------- errors and accessors

#[test]
fn errors_display_their_data_and_are_std_errors() {
    let cases: Vec<(BlobError, &[&str])> = vec![
        (BlobError::Truncated { needed: 99, found: 3 }, &["truncated", "99", "3"]),
        (
            BlobError::UnsupportedVersion { found: 2, supported: 1 },
            &["version 2", "1"],
        ),
        (
            BlobError::CrcMismatch {
                stored: 0xDEAD_BEEF,
                computed: 1,
            },
            &["0xdeadbeef", "0x00000001"],
        ),
        (
            BlobError::ChainBreak {
                layer: 2,
                expected: 256,
                found: 255,
            },
            &["layer 2", "256", "255"],
        ),
        (
            BlobError::BadScale {
                layer: 1,
                channel: Some(4),
                bits: (-2.5f32).to_bits(),
            },
            &["layer 1", "4", "-2.5"],
        ),
        (BlobError::BadMagic { found: *b"LTGA" }, &["magic", "LTGB"]),
    ];
    for (e, parts) in cases {
        let s = e.to_string();
        for p in parts {
            assert!(s.contains(p), "{s:?} lacks {p:?}");
        }
        let boxed: Box<dyn std::error::Error> = Box::new(e);
        assert_eq!(boxed.to_string(), s);
    }
}

#[test]
fn element_accessors_read_le_and_refuse_out_of_range() {
    let f = le_f32(&[1.5, -2.0, 3.25]);
    // Read from an odd offset to prove alignment does not matter.
    let mut shifted = vec![0u8];
    shifted.extend_from_slice(&f);
    let f = &shifted[1..];
    assert_eq!(f32_at(f, 0), Some(1.5));
    assert_eq!(f32_at(f, 2), Some(3.25));
    assert_eq!(f32_at(f, 3), None);
    assert_eq!(f32_at(&f[..11], 2), None);
    assert_eq!(f32_at(f, usize::MAX), None);
    assert_eq!(f32_at(f, usize::MAX / 4 + 1), None);
    assert_eq!(f32s(&f[..11]).collect::<Vec<_>>(), vec![1.5, -2.0]);
    let i = le_i32(&[-7, i32::MAX]);
    assert_eq!(i32_at(&i, 0), Some(-7));
    assert_eq!(i32_at(&i, 1), Some(i32::MAX));
    assert_eq!(i32_at(&i, 2), None);
}

#[cfg(feature = "std")]
#[test]
fn std_helpers_match_the_no_std_path() {
    use shared::blob::{encode_to_vec, f32_le_bytes, i32_le_bytes, int8_weight_at, int8_weight_bytes};
    assert_eq!(f32_le_bytes(&[1.5, -2.0]), le_f32(&[1.5, -2.0]));
    assert_eq!(i32_le_bytes(&[-7, 9]), le_i32(&[-7, 9]));
    // Rows (-1, 127, -128) and (5, -6, 7), then the odd row (-128, 0, 127): the pair's first row
    // is offset by 128, the second and the odd row are plain i8.
    let w = [-1i8, 127, -128, 5, -6, 7, -128, 0, 127];
    let bytes = int8_weight_bytes(&w, 3);
    assert_eq!(bytes, vec![0x7F, 5, 0xFF, 0xFA, 0x00, 7, 0x80, 0x00, 0x7F]);
    for j in 0..3 {
        for i in 0..3 {
            assert_eq!(int8_weight_at(&bytes, 3, 3, j, i), Some(w[j * 3 + i]), "({j}, {i})");
        }
    }
    assert_eq!(int8_weight_at(&bytes, 3, 3, 3, 0), None);
    assert_eq!(int8_weight_at(&bytes, 3, 3, 0, 3), None);
    // Each i16 of a pair is 256 b + a + 128.
    let h = i16::from_le_bytes([bytes[2], bytes[3]]);
    assert_eq!(i32::from(h), 256 * -6 + 127 + 128);
    let owned = small(Quantization::Int8);
    assert_eq!(encode_to_vec(&owned.view()).unwrap(), to_bytes(&owned.view()));
    let mut bad = owned.clone();
    bad.layers.clear();
    assert_eq!(encode_to_vec(&bad.view()), Err(BlobError::NoLayers));
}

/// f32 weights in blocks of 8 outputs, the last `outputs % 8` in a narrower block: every weight
/// where `f32_weight_index` says, and each block one contiguous run per input.
#[cfg(feature = "std")]
#[test]
fn f32_weights_lie_in_blocks_of_eight_outputs() {
    use shared::blob::{f32_weight_bytes, f32_weight_index, F32_BLOCK};
    let (inputs, outputs) = (3, 19);
    let w: Vec<f32> = (0..inputs * outputs).map(|k| k as f32).collect();
    let stored: Vec<f32> = shared::blob::f32s(&f32_weight_bytes(&w, inputs)).collect();
    assert_eq!(stored.len(), inputs * outputs);
    for j in 0..outputs {
        for i in 0..inputs {
            assert_eq!(
                stored[f32_weight_index(inputs, outputs, j, i)],
                w[j * inputs + i],
                "({j}, {i})"
            );
        }
    }
    // Block 1 (outputs 8..16): input 2's weights are the 8 f32 from 3 * 8 + 2 * 8.
    let run: Vec<f32> = (8..16).map(|j| w[j * inputs + 2]).collect();
    assert_eq!(stored[inputs * F32_BLOCK + 2 * F32_BLOCK..][..8], run[..]);
    // The 3 last outputs: input-major after the 2 whole blocks.
    assert_eq!(f32_weight_index(inputs, outputs, 17, 1), inputs * 16 + 3 + 1);
    // Narrower than a block: plain input-major.
    assert_eq!(f32_weight_index(10, 3, 2, 4), 4 * 3 + 2);
}

/// A format-4 blob (f32 input-major, int8 output-major) or a format-3 one (the same without the
/// mission) upgraded is the present format's blob of the same network; a present blob comes
/// back as it is, and a damaged one is refused.
#[cfg(feature = "std")]
#[test]
fn format_4_blobs_upgrade_to_the_same_network() {
    use shared::blob::{encode_to_vec, f32_le_bytes, f32_weight_bytes, int8_weight_bytes, upgrade, FORMAT_3, FORMAT_4};
    let (n_in, hidden, n_out) = (10usize, 19usize, 3usize);
    let f = |n: usize, seed: f32| -> Vec<f32> { (0..n).map(|k| ((k as f32 + seed) * 0.37).sin()).collect() };
    let (w1, w3) = (f(n_in * hidden, 1.0), f(hidden * n_out, 3.0));
    let w2: Vec<i8> = (0..hidden * hidden).map(|k| (k * 37 % 256) as u8 as i8).collect();
    let transpose = |w: &[f32], inputs: usize, outputs: usize| -> Vec<f32> {
        (0..inputs * outputs)
            .map(|k| w[(k % outputs) * inputs + k / outputs])
            .collect()
    };
    let layers = |a: Vec<u8>, b: Vec<u8>, c: Vec<u8>| -> Owned {
        let mut o = small(Quantization::Int8);
        o.layers.truncate(0);
        for (inputs, outputs, weights, act) in [
            (n_in, hidden, a, Activation::Relu),
            (hidden, hidden, b, Activation::Relu),
            (hidden, n_out, c, Activation::Tanh),
        ] {
            let int8 = inputs == hidden && outputs == hidden;
            o.layers.push(OwnedLayer {
                inputs: inputs as u16,
                outputs: outputs as u16,
                activation: act,
                weights,
                bias: if int8 {
                    vec![0; 4 * outputs]
                } else {
                    f32_le_bytes(&vec![0.5; outputs])
                },
                weight_scales: if int8 {
                    f32_le_bytes(&vec![0.01; outputs])
                } else {
                    Vec::new()
                },
                input_scale: if int8 { 0.02 } else { 1.0 },
            });
        }
        o
    };
    let old = layers(
        f32_le_bytes(&transpose(&w1, n_in, hidden)),
        w2.iter().map(|&v| v as u8).collect(),
        f32_le_bytes(&transpose(&w3, hidden, n_out)),
    );
    let new = layers(
        f32_weight_bytes(&w1, n_in),
        int8_weight_bytes(&w2, hidden),
        f32_weight_bytes(&w3, hidden),
    );
    let mut old_bytes = encode_to_vec(&old.view()).unwrap();
    old_bytes[4..6].copy_from_slice(&FORMAT_4.to_le_bytes());
    // A format-4 blob is not read as the present format.
    assert!(matches!(
        decode(&old_bytes),
        Err(BlobError::UnsupportedVersion { found: 4, .. })
    ));
    let new_bytes = encode_to_vec(&new.view()).unwrap();
    assert_eq!(upgrade(&old_bytes).unwrap(), new_bytes);
    assert_eq!(upgrade(&new_bytes).unwrap(), new_bytes);
    let mut damaged = old_bytes.clone();
    let last = damaged.len() - 1;
    damaged[last] ^= 1;
    assert!(matches!(upgrade(&damaged), Err(BlobError::CrcMismatch { .. })));
    // Format 3: the same payload without the mission (the network flies the thesis's).
    assert_eq!(old.view().mission, BlobMission::THESIS);
    let mission_len = postcard::to_allocvec(&BlobMission::THESIS).unwrap().len();
    let payload = &old_bytes[HEADER_LEN..old_bytes.len() - TRAILER_LEN];
    let mut v3 = frame(&payload[..payload.len() - mission_len]);
    v3[4..6].copy_from_slice(&FORMAT_3.to_le_bytes());
    assert_eq!(upgrade(&v3).unwrap(), new_bytes);
    let mut damaged = v3.clone();
    damaged[HEADER_LEN + 3] ^= 1;
    assert!(matches!(upgrade(&damaged), Err(BlobError::CrcMismatch { .. })));
    assert!(matches!(upgrade(&v3[..v3.len() - 1]), Err(BlobError::Truncated { .. })));
}

// ---------------------------------------------------------------- properties

/// Whatever `decode` accepts validates, borrows from the input and re-encodes to itself.
fn check_decode_is_total(bytes: &[u8]) {
    if let Ok(blob) = decode(bytes) {
        assert_eq!(blob.validate(), Ok(()));
        assert_borrows_from(&blob, bytes);
        let again = to_bytes(&blob);
        assert_eq!(decode(&again).unwrap(), blob);
    }
}

fn valid_payload(q: Quantization) -> Vec<u8> {
    let bytes = to_bytes(&network(FeatureLayout::TransferPolar10, q, &[10, 2, 3], 12).view());
    bytes[HEADER_LEN..bytes.len() - TRAILER_LEN].to_vec()
}

fn shape() -> impl Strategy<Value = (FeatureLayout, Quantization, Vec<u16>, u64)> {
    (
        prop_oneof![
            Just(FeatureLayout::TransferPolar10),
            Just(FeatureLayout::RendezvousPolar22),
            Just(FeatureLayout::TransferSpatial15),
            Just(FeatureLayout::RendezvousSpatial30)
        ],
        prop_oneof![Just(Quantization::F32), Just(Quantization::Int8)],
        prop::collection::vec(1u16..=64, 0..=3),
        any::<u64>(),
    )
        .prop_map(|(f, q, mut outs, seed)| {
            // Hidden widths of any size, the last layer the layout's action count.
            outs.insert(0, f.len() as u16);
            outs.push(f.actions() as u16);
            (f, q, outs, seed)
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn decode_never_panics_on_arbitrary_bytes(bytes in prop::collection::vec(any::<u8>(), 0..256)) {
        check_decode_is_total(&bytes);
    }

    #[test]
    fn decode_never_panics_on_framed_random_payloads(payload in prop::collection::vec(any::<u8>(), 0..256)) {
        // Valid header and CRC: the postcard decoder and the validator are what is exercised.
        let framed = frame(&payload);
        let got = decode(&framed);
        let framing_error = matches!(
            got,
            Err(BlobError::CrcMismatch { .. }
                | BlobError::BadMagic { .. }
                | BlobError::Truncated { .. }
                | BlobError::TrailingBytes { .. })
        );
        prop_assert!(!framing_error, "framing refused a well-framed blob: {:?}", got);
        check_decode_is_total(&framed);
    }

    #[test]
    fn decode_never_panics_on_mutated_valid_payloads(
        int8 in any::<bool>(),
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..4),
        cut in any::<prop::sample::Index>(),
        do_cut in any::<bool>(),
    ) {
        // Near-valid payloads, re-framed with a correct CRC, reach the semantic checks.
        let q = if int8 { Quantization::Int8 } else { Quantization::F32 };
        let mut payload = valid_payload(q);
        for (i, v) in edits {
            let k = i.index(payload.len());
            payload[k] = v;
        }
        if do_cut {
            payload.truncate(cut.index(payload.len()));
        }
        check_decode_is_total(&frame(&payload));
    }

    #[test]
    fn random_valid_shapes_round_trip((features, q, widths, seed) in shape()) {
        let owned = network(features, q, &widths, seed);
        let blob = owned.view();
        prop_assert_eq!(blob.validate(), Ok(()));
        let bytes = to_bytes(&blob);
        let back = decode(&bytes).unwrap();
        prop_assert_eq!(&back, &blob);
        assert_borrows_from(&back, &bytes);
    }
}

// ---------------------------------------------------------------- alignment

#[test]
fn every_weight_array_starts_word_aligned_from_the_blob_start() {
    // Provenance lengths 0..2 WEIGHT_ALIGN shift everything after them through every residue.
    for q in [Quantization::F32, Quantization::Int8] {
        for extra in 0..2 * WEIGHT_ALIGN as u64 {
            let mut o = network(FeatureLayout::TransferPolar10, q, &[10, 7, 5, 3], 20 + extra);
            o.provenance.push_str(&"x".repeat(extra as usize));
            let bytes = to_bytes(&o.view());
            let back = decode(&bytes).unwrap();
            for (l, layer) in back.layers.iter().enumerate() {
                let offset = layer.weights.as_ptr() as usize - bytes.as_ptr() as usize;
                assert_eq!(offset % WEIGHT_ALIGN, 0, "{q:?} +{extra}: layer {l} at byte {offset}");
                assert!(layer.padding.len() < WEIGHT_ALIGN && layer.padding.iter().all(|&b| b == 0));
            }
            // Placed on a 64-byte boundary, every weight array is on a cache line.
            let aligned = AlignedBlob::new(&bytes);
            assert_eq!(aligned.bytes(), &bytes[..]);
            assert_eq!(aligned.bytes().as_ptr() as usize % WEIGHT_ALIGN, 0);
            for layer in decode(aligned.bytes()).unwrap().layers.iter() {
                assert_eq!(layer.weights.as_ptr() as usize % 64, 0);
            }
        }
    }
}

#[test]
fn padding_that_misaligns_the_weights_or_is_not_zero_is_refused() {
    // A provenance that leaves layer 0 some padding, so there are bytes to dirty.
    let o = (0..WEIGHT_ALIGN)
        .map(|extra| {
            let mut o = small(Quantization::F32);
            o.provenance.push_str(&"x".repeat(extra));
            o
        })
        .find(|o| !o.view().layers[0].padding.is_empty())
        .expect("one of WEIGHT_ALIGN provenance lengths pads layer 0");
    let good = o.view();
    let pad = good.layers[0].padding.len();
    let bytes = to_bytes(&good);
    let offset = decode(&bytes).unwrap().layers[0].weights.as_ptr() as usize - bytes.as_ptr() as usize;
    let refused = |blob: &NetworkBlob<'_>| decode(&to_bytes_unchecked(blob)).map(|_| ());
    // Other padding bytes than zero: refused, though the weights stay aligned.
    let ones = [1u8; 2 * WEIGHT_ALIGN];
    let mut dirty = good.clone();
    dirty.layers[0].padding = &ones[..pad];
    assert_eq!(
        refused(&dirty),
        Err(BlobError::BadPadding {
            layer: 0,
            len: pad,
            weights_offset: offset
        })
    );
    // One byte less: the weights move off the boundary.
    let zeros = [0u8; 2 * WEIGHT_ALIGN];
    let mut short = good.clone();
    short.layers[0].padding = &zeros[..pad - 1];
    assert_eq!(
        refused(&short),
        Err(BlobError::BadPadding {
            layer: 0,
            len: pad - 1,
            weights_offset: offset - 1
        })
    );
    // WEIGHT_ALIGN more: aligned again, but longer than any alignment needs.
    let mut long = good.clone();
    long.layers[0].padding = &zeros[..pad + WEIGHT_ALIGN];
    assert_eq!(
        refused(&long),
        Err(BlobError::BadPadding {
            layer: 0,
            len: pad + WEIGHT_ALIGN,
            weights_offset: offset + WEIGHT_ALIGN
        })
    );
    // The encoder itself ignores a view's padding: the dirty view encodes to the good blob.
    assert_eq!(to_bytes(&dirty), bytes);
}

#[test]
fn an_overlong_padding_length_is_refused() {
    // postcard reads a varint written in more bytes than it needs. The first layer's padding
    // length written in two bytes, with one padding byte fewer, leaves the weights aligned where
    // they were: a blob the encoder never writes, which decoded to another network value than
    // its own re-encoding (found by the mutation property below).
    let bytes = to_bytes(&network(FeatureLayout::TransferPolar10, Quantization::F32, &[10, 2, 3], 12).view());
    let blob = decode(&bytes).unwrap();
    let pad = blob.layers[0].padding.len();
    assert!(pad > 1);
    // The length's one byte sits just before the padding it counts.
    let at = blob.layers[0].padding.as_ptr() as usize - bytes.as_ptr() as usize - 1;
    assert_eq!(usize::from(bytes[at]), pad);
    let mut payload = bytes[HEADER_LEN..bytes.len() - TRAILER_LEN].to_vec();
    payload[at - HEADER_LEN] = (pad as u8 - 1) | 0x80;
    let framed = frame(&payload);
    let got = decode(&framed);
    assert!(
        matches!(got, Err(BlobError::BadPadding { layer: 0, len, .. }) if len == pad - 1),
        "{got:?}"
    );
}
