//! The C interface called as C calls it (raw pointers, lengths, codes), on real blobs: made by
//! the exporter's writer (`shared::quantize`), then altered byte by byte the ways a bad upload
//! or a bad memory would alter them. Each refusal must come back as its own code, with thrust
//! off in the command; each accepted step must be the onboard crate's command to the bit.

use std::ptr;

use lowthrust::*;
use onboard::dynamics::SpacecraftState;
use onboard::guidance::{rendezvous3_step, rendezvous_step, transfer3_step, transfer_step, TargetOrbit3};
use onboard::policy::{Rendezvous3Policy, RendezvousPolicy, Transfer3Policy, TransferPolicy};
use onboard::spatial::SpatialCraftState;
use shared::blob::{self, Activation, FeatureLayout, NetworkBlob, ProblemKind, FORMAT_VERSION, HEADER_LEN};
use shared::orbit::{CartesianState, OrbitShape, SpatialState};
use shared::quantize::{DenseWeights, MlpWeights};

const TRANSFER: [usize; 4] = [10, 256, 256, 3];
const RENDEZVOUS: [usize; 4] = [22, 256, 256, 3];
const TRANSFER3: [usize; 4] = [15, 256, 256, 4];
const RENDEZVOUS3: [usize; 4] = [30, 256, 256, 4];

/// Deterministic weights of roughly He scale, different per layer and seed.
fn network(kind: ProblemKind, sizes: &[usize], seed: u32) -> MlpWeights {
    let layers = sizes
        .windows(2)
        .enumerate()
        .map(|(l, w)| {
            let (inputs, outputs) = (w[0], w[1]);
            let scale = (6.0 / inputs as f32).sqrt();
            let phase = (seed * 7 + l as u32) as f32;
            DenseWeights {
                inputs,
                outputs,
                weights: (0..inputs * outputs)
                    .map(|k| scale * (0.7 * k as f32 + phase).sin())
                    .collect(),
                bias: (0..outputs).map(|j| 0.05 * (1.3 * j as f32 + phase).cos()).collect(),
                activation: if l + 2 == sizes.len() {
                    Activation::Tanh
                } else {
                    Activation::Relu
                },
            }
        })
        .collect();
    // The three-dimensional layout for its input count (15 or 30), else the planar one.
    let spatial = sizes[0] == FeatureLayout::of(kind, true).len();
    MlpWeights {
        features: FeatureLayout::of(kind, spatial),
        layers,
    }
}

/// Feature-like calibration vectors (O(1) values, a time to go up to 12).
fn calibration(inputs: usize) -> Vec<Vec<f32>> {
    let mut s = 0x2545_f491_4f6c_dd1d_u64;
    (0..256)
        .map(|_| {
            (0..inputs)
                .map(|i| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    let u = (s >> 40) as f32 / (1u64 << 24) as f32;
                    if i == inputs - 1 {
                        12.0 * u
                    } else {
                        2.0 * u - 1.0
                    }
                })
                .collect()
        })
        .collect()
}

fn f32_blob(kind: ProblemKind, sizes: &[usize]) -> Vec<u8> {
    network(kind, sizes, 1).f32_blob("abi test f32").unwrap()
}

fn int8_blob(kind: ProblemKind, sizes: &[usize]) -> Vec<u8> {
    let net = network(kind, sizes, 2);
    net.int8_blob(&calibration(sizes[0]), "abi test int8").unwrap().0
}

/// CRC-32 (ISO-HDLC, reflected, polynomial 0xEDB88320), as the blob trailer.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// A correctly framed blob (magic, version, length, CRC) around any payload.
fn framed(payload: &[u8]) -> Vec<u8> {
    let mut out = b"LTGB".to_vec();
    out.extend(FORMAT_VERSION.to_le_bytes());
    out.extend((payload.len() as u32).to_le_bytes());
    out.extend(payload);
    out.extend(crc32(payload).to_le_bytes());
    out
}

/// `good` decoded, altered by `edit`, and encoded again without the writer's checks, so the
/// framing is right and only the decoder's semantic checks can refuse it.
fn with_defect<'a>(good: &'a [u8], edit: impl FnOnce(&mut NetworkBlob<'a>)) -> Vec<u8> {
    let mut net = blob::decode(good).unwrap();
    edit(&mut net);
    // Padded again, so the defect is the only one (a shorter array moves the weights after it).
    let net = net.aligned().unwrap();
    let mut out = vec![0u8; good.len() + 4096];
    let n = blob::encode_unchecked(&net, &mut out).unwrap();
    out.truncate(n);
    out
}

fn load_transfer(bytes: &[u8]) -> (lt_status, lt_policy) {
    let mut policy = lt_policy::default();
    let status = unsafe { lt_transfer_load(&mut policy, bytes.as_ptr(), bytes.len()) };
    (status, policy)
}

fn load_rendezvous(bytes: &[u8]) -> (lt_status, lt_policy) {
    let mut policy = lt_policy::default();
    let status = unsafe { lt_rendezvous_load(&mut policy, bytes.as_ptr(), bytes.len()) };
    (status, policy)
}

const NAV: lt_navigation_state = lt_navigation_state {
    r: [1.0, 0.1],
    v: [-0.05, 1.0],
    m: 0.95,
};
const TARGET: lt_target_orbit = lt_target_orbit {
    a: 1.3,
    e: 0.05,
    omega: 0.4,
};
const BODY: lt_body_state = lt_body_state {
    r: [-0.4, 1.2],
    v: [-0.8, -0.3],
};

/// A command that is not thrust off, so a test sees that a failed step overwrote it.
const STALE: lt_thrust_command = lt_thrust_command {
    throttle: 0.5,
    alpha_r: 0.6,
    alpha_theta: 0.8,
};

fn transfer(
    policy: &lt_policy,
    nav: &lt_navigation_state,
    target: &lt_target_orbit,
    ttg: f64,
) -> (lt_status, lt_thrust_command) {
    let mut command = STALE;
    let status = unsafe { lt_transfer_step(policy, nav, target, ttg, &mut command) };
    (status, command)
}

fn rendezvous(
    policy: &lt_policy,
    nav: &lt_navigation_state,
    body: &lt_body_state,
    ttg: f64,
) -> (lt_status, lt_thrust_command) {
    let mut command = STALE;
    let status = unsafe { lt_rendezvous_step(policy, nav, body, ttg, &mut command) };
    (status, command)
}

fn bits(c: &lt_thrust_command) -> [u64; 3] {
    [c.throttle.to_bits(), c.alpha_r.to_bits(), c.alpha_theta.to_bits()]
}

fn assert_thrust_off(c: &lt_thrust_command) {
    assert_eq!(bits(c), bits(&THRUST_OFF));
}

/// Navigation states around a 1 -> 1.3 AU transfer: radii 0.8-1.6 AU, all angles, speeds off
/// circular, masses down to 0.6, times to go up to 12 t*.
fn states(n: usize) -> Vec<(lt_navigation_state, f64)> {
    (0..n)
        .map(|k| {
            let x = k as f64 / n as f64;
            let r = 0.8 + 0.8 * x;
            let theta = 37.0 * x;
            let speed = (1.0 + 0.2 * (5.0 * theta).sin()) / r.sqrt();
            let gamma = 0.1 * (3.0 * theta).cos();
            let (s, c) = theta.sin_cos();
            let (vr, vt) = (speed * gamma.sin(), speed * gamma.cos());
            let nav = lt_navigation_state {
                r: [r * c, r * s],
                v: [vr * c - vt * s, vr * s + vt * c],
                m: 1.0 - 0.4 * x,
            };
            (nav, 12.0 * (1.0 - x))
        })
        .collect()
}

#[test]
fn accepted_blobs_fly_the_onboard_commands_bit_for_bit() {
    for bytes in [
        f32_blob(ProblemKind::Transfer, &TRANSFER),
        int8_blob(ProblemKind::Transfer, &TRANSFER),
    ] {
        let (status, policy) = load_transfer(&bytes);
        assert_eq!(status, LT_OK);
        let rust = TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer).unwrap();
        let mut thrusting = 0;
        for (nav, ttg) in states(300) {
            let (status, command) = transfer(&policy, &nav, &TARGET, ttg);
            let expected = transfer_step(&rust, &SpacecraftState::from(nav), &OrbitShape::from(TARGET), ttg).unwrap();
            assert_eq!(status, LT_OK);
            assert_eq!(bits(&command), bits(&expected.into()));
            thrusting += usize::from(command.throttle > 0.0);
        }
        // The weights are not degenerate: most states thrust.
        assert!(thrusting > 100, "{thrusting}");
    }
    for bytes in [
        f32_blob(ProblemKind::Rendezvous, &RENDEZVOUS),
        int8_blob(ProblemKind::Rendezvous, &RENDEZVOUS),
    ] {
        let (status, policy) = load_rendezvous(&bytes);
        assert_eq!(status, LT_OK);
        let rust = RendezvousPolicy::from_bytes(&bytes, ProblemKind::Rendezvous).unwrap();
        for (nav, ttg) in states(100) {
            let (status, command) = rendezvous(&policy, &nav, &BODY, ttg);
            let expected =
                rendezvous_step(&rust, &SpacecraftState::from(nav), &CartesianState::from(BODY), ttg).unwrap();
            assert_eq!(status, LT_OK);
            assert_eq!(bits(&command), bits(&expected.into()));
        }
    }
}

const TARGET3: lt_target_orbit3 = lt_target_orbit3 {
    a: 1.3,
    e: 0.05,
    omega: 0.4,
    inclination: 0.06,
    raan: 1.1,
};
const BODY3: lt_body_state3 = lt_body_state3 {
    r: [-0.4, 1.2, 0.03],
    v: [-0.8, -0.3, 0.02],
};

/// [`states`] lifted out of the plane: heights and vertical speeds of a few hundredths.
fn states3(n: usize) -> Vec<(lt_navigation_state3, f64)> {
    states(n)
        .into_iter()
        .enumerate()
        .map(|(k, (nav, ttg))| {
            let phase = 0.37 * k as f64;
            let nav = lt_navigation_state3 {
                r: [nav.r[0], nav.r[1], 0.04 * phase.sin()],
                v: [nav.v[0], nav.v[1], 0.03 * phase.cos()],
                m: nav.m,
            };
            (nav, ttg)
        })
        .collect()
}

fn rtn_bits(c: &lt_rtn_command) -> [u64; 4] {
    [c.throttle, c.radial, c.transverse, c.normal].map(f64::to_bits)
}

const STALE3: lt_rtn_command = lt_rtn_command {
    throttle: 0.5,
    radial: 0.6,
    transverse: 0.0,
    normal: 0.8,
};

fn transfer3(
    policy: &lt_policy,
    nav: &lt_navigation_state3,
    target: &lt_target_orbit3,
    ttg: f64,
) -> (lt_status, lt_rtn_command) {
    let mut command = STALE3;
    let status = unsafe { lt_transfer3_step(policy, nav, target, ttg, &mut command) };
    (status, command)
}

fn rendezvous3(
    policy: &lt_policy,
    nav: &lt_navigation_state3,
    body: &lt_body_state3,
    ttg: f64,
) -> (lt_status, lt_rtn_command) {
    let mut command = STALE3;
    let status = unsafe { lt_rendezvous3_step(policy, nav, body, ttg, &mut command) };
    (status, command)
}

/// Three-dimensional blobs from C: loaded by their own loads, each step the onboard crate's RTN
/// command to the bit, described as 3D problems; the planar loads and steps refuse them, the 3D
/// steps refuse planar policies and refused inputs, each with its code and thrust off.
#[test]
fn three_dimensional_blobs_fly_the_onboard_rtn_commands_bit_for_bit() {
    let load = |f: unsafe extern "C" fn(*mut lt_policy, *const u8, usize) -> lt_status, bytes: &[u8]| {
        let mut policy = lt_policy::default();
        let status = unsafe { f(&mut policy, bytes.as_ptr(), bytes.len()) };
        (status, policy)
    };
    let describe = |policy: &lt_policy| {
        let mut info = lt_policy_info::default();
        assert_eq!(unsafe { lt_policy_describe(policy, &mut info) }, LT_OK);
        info.problem
    };
    for bytes in [
        f32_blob(ProblemKind::Transfer, &TRANSFER3),
        int8_blob(ProblemKind::Transfer, &TRANSFER3),
    ] {
        let (status, policy) = load(lt_transfer3_load, &bytes);
        assert_eq!(status, LT_OK);
        assert_eq!(describe(&policy), LT_PROBLEM_TRANSFER3);
        let rust = Transfer3Policy::from_bytes(&bytes, ProblemKind::Transfer).unwrap();
        let mut out_of_plane = 0;
        for (nav, ttg) in states3(300) {
            let (status, command) = transfer3(&policy, &nav, &TARGET3, ttg);
            let expected =
                transfer3_step(&rust, &SpatialCraftState::from(nav), &TargetOrbit3::from(TARGET3), ttg).unwrap();
            assert_eq!(status, LT_OK);
            assert_eq!(rtn_bits(&command), rtn_bits(&expected.into()));
            out_of_plane += usize::from(command.throttle > 0.0 && command.normal.abs() > 1e-3);
        }
        assert!(out_of_plane > 100, "{out_of_plane}");
        // Not a planar network: the planar load refuses it, the planar step does not fly it.
        assert_eq!(load(lt_transfer_load, &bytes).0, LT_ERR_WRONG_FEATURES);
        let (status, command) = transfer(&policy, &NAV, &TARGET, 1.0);
        assert_eq!(status, LT_ERR_WRONG_POLICY_KIND);
        assert_thrust_off(&command);
        let (status, command) = rendezvous3(&policy, &states3(1)[0].0, &BODY3, 1.0);
        assert_eq!(status, LT_ERR_WRONG_POLICY_KIND);
        assert_eq!(rtn_bits(&command), rtn_bits(&RTN_THRUST_OFF));
    }
    for bytes in [
        f32_blob(ProblemKind::Rendezvous, &RENDEZVOUS3),
        int8_blob(ProblemKind::Rendezvous, &RENDEZVOUS3),
    ] {
        let (status, policy) = load(lt_rendezvous3_load, &bytes);
        assert_eq!(status, LT_OK);
        assert_eq!(describe(&policy), LT_PROBLEM_RENDEZVOUS3);
        let rust = Rendezvous3Policy::from_bytes(&bytes, ProblemKind::Rendezvous).unwrap();
        for (nav, ttg) in states3(100) {
            let (status, command) = rendezvous3(&policy, &nav, &BODY3, ttg);
            let expected =
                rendezvous3_step(&rust, &SpatialCraftState::from(nav), &SpatialState::from(BODY3), ttg).unwrap();
            assert_eq!(status, LT_OK);
            assert_eq!(rtn_bits(&command), rtn_bits(&expected.into()));
        }
    }
    // A planar policy does not fly a 3D step; a 3D load refuses a planar blob.
    let planar = f32_blob(ProblemKind::Transfer, &TRANSFER);
    let (_, planar_policy) = load(lt_transfer_load, &planar);
    let (status, command) = transfer3(&planar_policy, &states3(1)[0].0, &TARGET3, 1.0);
    assert_eq!(status, LT_ERR_WRONG_POLICY_KIND);
    assert_eq!(rtn_bits(&command), rtn_bits(&RTN_THRUST_OFF));
    assert_eq!(load(lt_transfer3_load, &planar).0, LT_ERR_WRONG_FEATURES);
    // Refused inputs: their codes, thrust off; a null command is refused.
    let (_, policy) = load(lt_transfer3_load, &f32_blob(ProblemKind::Transfer, &TRANSFER3));
    let nav = states3(1)[0].0;
    let radial = lt_navigation_state3 {
        v: nav.r.map(|x| 0.5 * x),
        ..nav
    };
    let cases = [
        (radial, TARGET3, 1.0, LT_ERR_INPUT_NO_ORBIT_PLANE),
        (
            lt_navigation_state3 { m: -1.0, ..nav },
            TARGET3,
            1.0,
            LT_ERR_INPUT_NON_POSITIVE_MASS,
        ),
        (
            nav,
            lt_target_orbit3 {
                inclination: f64::NAN,
                ..TARGET3
            },
            1.0,
            LT_ERR_INPUT_TARGET,
        ),
        (nav, TARGET3, -1.0, LT_ERR_INPUT_TIME_TO_GO),
    ];
    for (n, t, ttg, code) in cases {
        let (status, command) = transfer3(&policy, &n, &t, ttg);
        assert_eq!(status, code, "{n:?} {t:?} {ttg}");
        assert_eq!(rtn_bits(&command), rtn_bits(&RTN_THRUST_OFF));
    }
    let status = unsafe { lt_transfer3_step(&policy, &nav, &TARGET3, 1.0, ptr::null_mut()) };
    assert_eq!(status, LT_ERR_NULL_POINTER);
    let mut command = STALE3;
    let status = unsafe { lt_rendezvous3_step(&policy, ptr::null(), &BODY3, 1.0, &mut command) };
    assert_eq!(status, LT_ERR_NULL_POINTER);
    assert_eq!(rtn_bits(&command), rtn_bits(&RTN_THRUST_OFF));
}

#[test]
fn describe_says_what_the_policy_flies() {
    let cases = [
        (
            f32_blob(ProblemKind::Transfer, &TRANSFER),
            LT_PROBLEM_TRANSFER,
            LT_QUANTIZATION_F32,
        ),
        (
            int8_blob(ProblemKind::Transfer, &TRANSFER),
            LT_PROBLEM_TRANSFER,
            LT_QUANTIZATION_INT8,
        ),
        (
            int8_blob(ProblemKind::Rendezvous, &RENDEZVOUS),
            LT_PROBLEM_RENDEZVOUS,
            LT_QUANTIZATION_INT8,
        ),
    ];
    for (bytes, problem, quantization) in cases {
        let (status, policy) = if problem == LT_PROBLEM_TRANSFER {
            load_transfer(&bytes)
        } else {
            load_rendezvous(&bytes)
        };
        assert_eq!(status, LT_OK);
        let mut info = lt_policy_info {
            problem: 99,
            quantization: 99,
            ..Default::default()
        };
        assert_eq!(unsafe { lt_policy_describe(&policy, &mut info) }, LT_OK);
        // Written for the thesis's mission: 14-day cycles, AU, the Sun's time unit.
        let thesis = blob::BlobMission::THESIS;
        let expected = lt_policy_info {
            problem,
            quantization,
            cycle: thesis.cycle,
            length_unit_m: thesis.length_unit_m,
            time_unit_s: thesis.time_unit_s,
            family: 0,
        };
        assert_eq!(info, expected);
    }
    // Another mission's blob tells flight software its cycle, units and family.
    let weekly = blob::BlobMission {
        cycle: 7.0 * 86_400.0 / 806.811,
        length_unit_m: 6_378_137.0,
        time_unit_s: 806.811,
        family: 0x85d4_97c4,
    };
    let bytes = network(ProblemKind::Transfer, &TRANSFER, 1)
        .f32_blob_for("abi test mission", weekly)
        .unwrap();
    let (status, policy) = load_transfer(&bytes);
    assert_eq!(status, LT_OK);
    let mut info = lt_policy_info::default();
    assert_eq!(unsafe { lt_policy_describe(&policy, &mut info) }, LT_OK);
    assert_eq!(
        (info.cycle, info.length_unit_m, info.time_unit_s, info.family),
        (weekly.cycle, weekly.length_unit_m, weekly.time_unit_s, weekly.family)
    );
    let mut info = lt_policy_info {
        problem: 99,
        quantization: 99,
        ..Default::default()
    };
    assert_eq!(
        unsafe { lt_policy_describe(&lt_policy::default(), &mut info) },
        LT_ERR_NOT_LOADED
    );
    assert_eq!(
        unsafe { lt_policy_describe(ptr::null(), &mut info) },
        LT_ERR_NULL_POINTER
    );
    let (_, policy) = load_transfer(&f32_blob(ProblemKind::Transfer, &TRANSFER));
    assert_eq!(
        unsafe { lt_policy_describe(&policy, ptr::null_mut()) },
        LT_ERR_NULL_POINTER
    );
}

#[test]
fn damaged_bytes_are_refused_each_with_its_own_code() {
    let good = int8_blob(ProblemKind::Transfer, &TRANSFER);
    let n = good.len();
    let mut flipped = good.clone();
    flipped[n / 2] ^= 0xff;
    let mut bad_magic = good.clone();
    bad_magic[0] = b'X';
    let mut next_version = good.clone();
    next_version[4..6].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
    let mut trailing = good.clone();
    trailing.push(0);
    let payload = &good[HEADER_LEN..n - 4];
    let mut longer_payload = payload.to_vec();
    longer_payload.push(0);
    // The first payload byte is the problem kind's enum tag: 9 names no problem.
    let mut unknown_kind = payload.to_vec();
    unknown_kind[0] = 9;
    let cases: [(&str, &[u8], lt_status); 9] = [
        ("one payload byte flipped", &flipped, LT_ERR_BLOB_CRC_MISMATCH),
        ("the last 1000 bytes cut", &good[..n - 1000], LT_ERR_BLOB_TRUNCATED),
        ("the header alone", &good[..HEADER_LEN], LT_ERR_BLOB_TRUNCATED),
        (
            "the next format version",
            &next_version,
            LT_ERR_BLOB_UNSUPPORTED_VERSION,
        ),
        ("another magic", &bad_magic, LT_ERR_BLOB_BAD_MAGIC),
        ("a byte after the trailer", &trailing, LT_ERR_BLOB_TRAILING_BYTES),
        (
            "a byte after the network",
            &framed(&longer_payload),
            LT_ERR_BLOB_PAYLOAD_NOT_CONSUMED,
        ),
        ("an unknown problem tag", &framed(&unknown_kind), LT_ERR_BLOB_PAYLOAD),
        ("no bytes", &[], LT_ERR_BLOB_TRUNCATED),
    ];
    for (what, bytes, code) in cases {
        assert_eq!(load_transfer(bytes).0, code, "{what}");
    }
}

#[test]
fn well_framed_blobs_with_defects_are_refused_each_with_its_own_code() {
    let f32_good = f32_blob(ProblemKind::Transfer, &TRANSFER);
    let int8_good = int8_blob(ProblemKind::Transfer, &TRANSFER);
    let nan_bias: Vec<u8> = (0..256)
        .flat_map(|j| if j == 7 { f32::NAN } else { 0.0 }.to_le_bytes())
        .collect();
    let cases: Vec<(&str, Vec<u8>, lt_status)> = vec![
        (
            "kind and features disagree",
            with_defect(&f32_good, |n| n.kind = ProblemKind::Rendezvous),
            LT_ERR_BLOB_KIND_MISMATCH,
        ),
        (
            "no layers",
            with_defect(&f32_good, |n| n.layers.clear()),
            LT_ERR_BLOB_NO_LAYERS,
        ),
        (
            "first layer of 11 inputs",
            with_defect(&f32_good, |n| n.layers[0].inputs = 11),
            LT_ERR_BLOB_INPUT_MISMATCH,
        ),
        (
            "layers that do not chain",
            with_defect(&f32_good, |n| n.layers[1].inputs = 255),
            LT_ERR_BLOB_CHAIN_BREAK,
        ),
        (
            "a layer of no outputs",
            with_defect(&f32_good, |n| n.layers[2].outputs = 0),
            LT_ERR_BLOB_BAD_WIDTH,
        ),
        (
            "a bias one value short",
            with_defect(&f32_good, |n| n.layers[0].bias = &n.layers[0].bias[4..]),
            LT_ERR_BLOB_ARRAY_LENGTH,
        ),
        (
            "a tanh hidden layer",
            with_defect(&f32_good, |n| n.layers[0].activation = Activation::Tanh),
            LT_ERR_BLOB_BAD_ACTIVATION,
        ),
        (
            "a negative input scale",
            with_defect(&int8_good, |n| n.layers[1].input_scale = -1.0),
            LT_ERR_BLOB_BAD_SCALE,
        ),
        (
            "a NaN bias",
            with_defect(&f32_good, |n| n.layers[1].bias = &nan_bias),
            LT_ERR_BLOB_NON_FINITE_WEIGHT,
        ),
        (
            "a rendezvous network",
            int8_blob(ProblemKind::Rendezvous, &RENDEZVOUS),
            LT_ERR_WRONG_PROBLEM,
        ),
        (
            "two layers",
            f32_blob(ProblemKind::Transfer, &[10, 256, 3]),
            LT_ERR_WRONG_LAYER_COUNT,
        ),
        (
            "64-wide hidden layers",
            f32_blob(ProblemKind::Transfer, &[10, 64, 64, 3]),
            LT_ERR_WRONG_SHAPE,
        ),
    ];
    for (what, bytes, code) in &cases {
        assert_eq!(load_transfer(bytes).0, *code, "{what}");
    }
    // And the other way round: a transfer network is not a rendezvous policy.
    assert_eq!(load_rendezvous(&f32_good).0, LT_ERR_WRONG_PROBLEM);
    assert_eq!(
        load_rendezvous(&with_defect(&f32_good, |n| n.features = FeatureLayout::RendezvousPolar22)).0,
        LT_ERR_BLOB_KIND_MISMATCH
    );
}

#[test]
fn null_pointers_impossible_lengths_and_misaligned_storage_are_refused() {
    let good = f32_blob(ProblemKind::Transfer, &TRANSFER);
    let mut policy = lt_policy::default();
    unsafe {
        assert_eq!(
            lt_transfer_load(ptr::null_mut(), good.as_ptr(), good.len()),
            LT_ERR_NULL_POINTER
        );
        assert_eq!(
            lt_transfer_load(&mut policy, ptr::null(), good.len()),
            LT_ERR_NULL_POINTER
        );
        assert_eq!(lt_rendezvous_load(&mut policy, ptr::null(), 0), LT_ERR_NULL_POINTER);
        assert_eq!(
            lt_transfer_load(&mut policy, good.as_ptr(), usize::MAX),
            LT_ERR_BLOB_LENGTH
        );
        // An address near the top whose length would wrap: refused before anything is read.
        let near_top = (usize::MAX - 15) as *const u8;
        assert_eq!(lt_transfer_load(&mut policy, near_top, 64), LT_ERR_BLOB_LENGTH);
        // Short lengths of a good blob.
        for len in [0, 1, 13, 14, good.len() - 1] {
            assert_eq!(
                lt_transfer_load(&mut policy, good.as_ptr(), len),
                LT_ERR_BLOB_TRUNCATED,
                "{len}"
            );
        }
    }
    // Storage 4 bytes off its alignment.
    let mut words = vec![0u64; LT_POLICY_STORAGE_WORDS + 1];
    let misaligned = unsafe { words.as_mut_ptr().cast::<u8>().add(4) }.cast::<lt_policy>();
    assert_eq!(
        unsafe { lt_transfer_load(misaligned, good.as_ptr(), good.len()) },
        LT_ERR_MISALIGNED_POLICY
    );
    let mut command = STALE;
    assert_eq!(
        unsafe { lt_transfer_step(misaligned, &NAV, &TARGET, 1.0, &mut command) },
        LT_ERR_MISALIGNED_POLICY
    );
    assert_thrust_off(&command);

    let (status, policy) = load_transfer(&good);
    assert_eq!(status, LT_OK);
    let mut command = STALE;
    unsafe {
        assert_eq!(
            lt_transfer_step(ptr::null(), &NAV, &TARGET, 1.0, &mut command),
            LT_ERR_NULL_POINTER
        );
        assert_thrust_off(&command);
        command = STALE;
        assert_eq!(
            lt_transfer_step(&policy, ptr::null(), &TARGET, 1.0, &mut command),
            LT_ERR_NULL_POINTER
        );
        assert_thrust_off(&command);
        command = STALE;
        assert_eq!(
            lt_transfer_step(&policy, &NAV, ptr::null(), 1.0, &mut command),
            LT_ERR_NULL_POINTER
        );
        assert_thrust_off(&command);
        // No command to write: still a code, and nothing written anywhere.
        assert_eq!(
            lt_transfer_step(&policy, &NAV, &TARGET, 1.0, ptr::null_mut()),
            LT_ERR_NULL_POINTER
        );
        command = STALE;
        assert_eq!(
            lt_rendezvous_step(&policy, &NAV, ptr::null(), 1.0, &mut command),
            LT_ERR_NULL_POINTER
        );
        assert_thrust_off(&command);
        assert_eq!(lt_version(ptr::null_mut()), LT_ERR_NULL_POINTER);
    }
}

#[test]
fn unaligned_inputs_and_outputs_are_accepted() {
    let good = int8_blob(ProblemKind::Transfer, &TRANSFER);
    let (_, policy) = load_transfer(&good);
    let (_, expected) = transfer(&policy, &NAV, &TARGET, 3.0);
    // Inputs and output 1 byte off their alignment inside byte buffers.
    let mut nav = [0u8; size_of::<lt_navigation_state>() + 1];
    let mut target = [0u8; size_of::<lt_target_orbit>() + 1];
    let mut out = [0u8; size_of::<lt_thrust_command>() + 1];
    unsafe {
        ptr::write_unaligned(nav.as_mut_ptr().add(1).cast(), NAV);
        ptr::write_unaligned(target.as_mut_ptr().add(1).cast(), TARGET);
        let status = lt_transfer_step(
            &policy,
            nav.as_ptr().add(1).cast(),
            target.as_ptr().add(1).cast(),
            3.0,
            out.as_mut_ptr().add(1).cast(),
        );
        assert_eq!(status, LT_OK);
        let command: lt_thrust_command = ptr::read_unaligned(out.as_ptr().add(1).cast());
        assert_eq!(bits(&command), bits(&expected));
    }
}

#[test]
fn a_policy_not_loaded_or_of_the_other_kind_flies_thrust_off() {
    let (status, command) = transfer(&lt_policy::default(), &NAV, &TARGET, 1.0);
    assert_eq!(status, LT_ERR_NOT_LOADED);
    assert_thrust_off(&command);

    // A refused load after a good one: the old network no longer flies.
    let good = f32_blob(ProblemKind::Transfer, &TRANSFER);
    let (_, mut policy) = load_transfer(&good);
    assert_eq!(transfer(&policy, &NAV, &TARGET, 1.0).0, LT_OK);
    let mut flipped = good.clone();
    flipped[good.len() / 3] ^= 1;
    assert_eq!(
        unsafe { lt_transfer_load(&mut policy, flipped.as_ptr(), flipped.len()) },
        LT_ERR_BLOB_CRC_MISMATCH
    );
    let (status, command) = transfer(&policy, &NAV, &TARGET, 1.0);
    assert_eq!(status, LT_ERR_NOT_LOADED);
    assert_thrust_off(&command);

    // A rendezvous policy cannot fly a transfer step, nor the reverse.
    let (_, rendezvous_policy) = load_rendezvous(&int8_blob(ProblemKind::Rendezvous, &RENDEZVOUS));
    let (status, command) = transfer(&rendezvous_policy, &NAV, &TARGET, 1.0);
    assert_eq!(status, LT_ERR_WRONG_POLICY_KIND);
    assert_thrust_off(&command);
    let (_, transfer_policy) = load_transfer(&good);
    let (status, command) = rendezvous(&transfer_policy, &NAV, &BODY, 1.0);
    assert_eq!(status, LT_ERR_WRONG_POLICY_KIND);
    assert_thrust_off(&command);
    // A loaded policy is plain data: a copy flies the same.
    let copy: lt_policy = unsafe { ptr::read(&transfer_policy) };
    assert_eq!(
        transfer(&copy, &NAV, &TARGET, 1.0),
        transfer(&transfer_policy, &NAV, &TARGET, 1.0)
    );
}

#[test]
fn refused_guidance_inputs_give_their_codes_and_thrust_off() {
    let (_, policy) = load_transfer(&int8_blob(ProblemKind::Transfer, &TRANSFER));
    let nav = |edit: fn(&mut lt_navigation_state)| {
        let mut n = NAV;
        edit(&mut n);
        n
    };
    let cases = [
        (nav(|n| n.v[1] = f64::NAN), TARGET, 1.0, LT_ERR_INPUT_NON_FINITE_STATE),
        (nav(|n| n.r = [0.0, 0.0]), TARGET, 1.0, LT_ERR_INPUT_ZERO_RADIUS),
        (nav(|n| n.m = 0.0), TARGET, 1.0, LT_ERR_INPUT_NON_POSITIVE_MASS),
        (NAV, lt_target_orbit { e: 1.5, ..TARGET }, 1.0, LT_ERR_INPUT_TARGET),
        (NAV, TARGET, -1.0, LT_ERR_INPUT_TIME_TO_GO),
        (NAV, TARGET, f64::INFINITY, LT_ERR_INPUT_TIME_TO_GO),
        // Finite in f64, infinite once narrowed to the network's f32: no action to fly.
        (nav(|n| n.r = [1e39, 0.0]), TARGET, 1.0, LT_ERR_NON_FINITE_ACTION),
    ];
    for (n, t, ttg, code) in cases {
        let (status, command) = transfer(&policy, &n, &t, ttg);
        assert_eq!(status, code, "{n:?} {t:?} {ttg}");
        assert_thrust_off(&command);
    }
    let (_, policy) = load_rendezvous(&f32_blob(ProblemKind::Rendezvous, &RENDEZVOUS));
    let at_sun = lt_body_state { r: [0.0, 0.0], ..BODY };
    let (status, command) = rendezvous(&policy, &NAV, &at_sun, 1.0);
    assert_eq!(status, LT_ERR_INPUT_TARGET);
    assert_thrust_off(&command);
}

#[test]
fn version_and_error_names_reach_c() {
    let mut v = lt_version_info {
        major: 9,
        minor: 9,
        patch: 9,
        blob_format_version: 9,
    };
    assert_eq!(unsafe { lt_version(&mut v) }, LT_OK);
    assert_eq!(v.blob_format_version, FORMAT_VERSION);
    let crate_version = format!("{}.{}.{}", v.major, v.minor, v.patch);
    assert_eq!(crate_version, env!("CARGO_PKG_VERSION"));
    let name = |code: i32| {
        unsafe { std::ffi::CStr::from_ptr(lt_error_name(code)) }
            .to_str()
            .unwrap()
    };
    assert_eq!(name(LT_OK as i32), "ok");
    assert_eq!(name(LT_ERR_BLOB_UNSUPPORTED_VERSION as i32), "blob_unsupported_version");
    assert_eq!(name(-1000), "unknown");
}

/// The MSR/ERO spacecraft of the scenarios, as the C caller passes it.
fn spacecraft() -> lt_spacecraft {
    let c = shared::spacecraft::Spacecraft::MSR_ERO.canonical().unwrap();
    lt_spacecraft {
        thrust: c.thrust,
        exhaust_speed: c.exhaust_speed,
    }
}

fn defaults() -> lt_lookahead_settings {
    let mut s = lt_lookahead_settings {
        goal_position: 0.0,
        goal_velocity: 0.0,
        accuracy_floor: 0.0,
        fuel_weight: 0.0,
        max_cycles: 0,
        thrust_margin: 1.0,
        arrival_margin: u32::MAX,
        rollout_budget: u32::MAX,
        cycle: 0.0,
    };
    assert_eq!(unsafe { lt_lookahead_defaults(&mut s) }, LT_OK);
    s
}

#[test]
fn lookahead_steps_are_the_onboard_lookahead_bit_for_bit_and_refuse_unusable_settings() {
    use onboard::lookahead::{lookahead_step, LookaheadSettings};
    let settings = defaults();
    let d = LookaheadSettings::default();
    assert_eq!(
        (
            settings.goal_position,
            settings.goal_velocity,
            settings.accuracy_floor,
            settings.fuel_weight,
            settings.max_cycles,
            settings.arrival_margin,
            settings.rollout_budget,
            settings.cycle
        ),
        (
            d.goal_position,
            d.goal_velocity,
            d.accuracy_floor,
            d.fuel_weight,
            d.max_cycles,
            d.arrival_margin,
            d.rollout_budget,
            d.cycle
        )
    );
    let sc = spacecraft();
    let canonical = shared::spacecraft::Spacecraft::MSR_ERO.canonical().unwrap();
    let bytes = f32_blob(ProblemKind::Transfer, &TRANSFER);
    let (status, policy) = load_transfer(&bytes);
    assert_eq!(status, LT_OK);
    let rust = TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer).unwrap();
    let mut changed = 0;
    // A few cycles before the arrival (rollouts of 1 to 4 cycles, the last one partial).
    for (k, (nav, _)) in states(8).into_iter().enumerate() {
        let ttg = 0.2408 * (0.5 + k as f64 / 2.0);
        // Every other cycle judged a cycle early; every third on a budget of 5 rollout cycles.
        let margin = (k % 2) as u32;
        let budget = if k.is_multiple_of(3) { 5 } else { 0 };
        let settings = lt_lookahead_settings {
            arrival_margin: margin,
            rollout_budget: budget,
            ..settings
        };
        let d = LookaheadSettings {
            arrival_margin: margin,
            rollout_budget: budget,
            ..d
        };
        let mut command = STALE;
        let mut report = std::mem::MaybeUninit::<lt_lookahead_report>::uninit();
        let status = unsafe {
            lt_transfer_lookahead_step(
                &policy,
                &nav,
                &TARGET,
                ttg,
                &sc,
                &settings,
                &mut command,
                report.as_mut_ptr(),
            )
        };
        assert_eq!(status, LT_OK);
        let report = unsafe { report.assume_init() };
        let expected = lookahead_step(
            &rust,
            &SpacecraftState::from(nav),
            &OrbitShape::from(TARGET),
            ttg,
            &canonical,
            &d,
        )
        .unwrap();
        assert_eq!(bits(&command), bits(&expected.command.into()));
        assert_eq!(bits(&report.network), bits(&expected.network.into()));
        assert_eq!(report.chosen as usize, expected.chosen);
        let p = expected.predicted.unwrap();
        assert_eq!(report.predicted_valid, 1);
        assert_eq!(
            [
                report.predicted_position,
                report.predicted_velocity,
                report.predicted_mass,
                report.predicted_cost
            ]
            .map(f64::to_bits),
            [p.residuals.position, p.residuals.velocity, p.mass, p.cost].map(f64::to_bits)
        );
        changed += usize::from(report.chosen != 0);
        // The report is optional.
        let mut again = STALE;
        let status = unsafe {
            lt_transfer_lookahead_step(&policy, &nav, &TARGET, ttg, &sc, &settings, &mut again, ptr::null_mut())
        };
        assert_eq!((status, bits(&again)), (LT_OK, bits(&command)));
    }
    // These made-up weights are far from any optimum: the lookahead overrides them somewhere.
    assert!(changed > 0);
    // Unusable settings or spacecraft: their own code, thrust off, nothing predicted.
    let nav = states(1)[0].0;
    for (spacecraft, settings) in [
        (lt_spacecraft { thrust: f64::NAN, ..sc }, defaults()),
        (
            lt_spacecraft {
                exhaust_speed: 0.0,
                ..sc
            },
            defaults(),
        ),
        (
            sc,
            lt_lookahead_settings {
                accuracy_floor: 0.0,
                ..defaults()
            },
        ),
        (
            sc,
            lt_lookahead_settings {
                fuel_weight: -1.0,
                ..defaults()
            },
        ),
        (
            sc,
            lt_lookahead_settings {
                goal_velocity: f64::INFINITY,
                ..defaults()
            },
        ),
    ] {
        let mut command = STALE;
        let mut report = std::mem::MaybeUninit::<lt_lookahead_report>::uninit();
        let status = unsafe {
            lt_transfer_lookahead_step(
                &policy,
                &nav,
                &TARGET,
                1.0,
                &spacecraft,
                &settings,
                &mut command,
                report.as_mut_ptr(),
            )
        };
        assert_eq!(status, LT_ERR_INPUT_LOOKAHEAD);
        assert_thrust_off(&command);
        assert_eq!(unsafe { report.assume_init() }.predicted_valid, 0);
    }
    // Null inputs, the other problem's policy.
    let mut command = STALE;
    let status = unsafe {
        lt_transfer_lookahead_step(
            &policy,
            &nav,
            &TARGET,
            1.0,
            ptr::null(),
            &settings,
            &mut command,
            ptr::null_mut(),
        )
    };
    assert_eq!(status, LT_ERR_NULL_POINTER);
    assert_thrust_off(&command);
    let status = unsafe {
        lt_rendezvous_lookahead_step(&policy, &nav, &BODY, 1.0, &sc, &settings, &mut command, ptr::null_mut())
    };
    assert_eq!(status, LT_ERR_WRONG_POLICY_KIND);
    assert_eq!(unsafe { lt_lookahead_defaults(ptr::null_mut()) }, LT_ERR_NULL_POINTER);
    // A rendezvous policy: the onboard lookahead's command, bit for bit.
    let bytes = int8_blob(ProblemKind::Rendezvous, &RENDEZVOUS);
    let (status, policy) = load_rendezvous(&bytes);
    assert_eq!(status, LT_OK);
    let rust = RendezvousPolicy::from_bytes(&bytes, ProblemKind::Rendezvous).unwrap();
    for (nav, _) in states(3) {
        let mut command = STALE;
        let status = unsafe {
            lt_rendezvous_lookahead_step(&policy, &nav, &BODY, 0.6, &sc, &settings, &mut command, ptr::null_mut())
        };
        assert_eq!(status, LT_OK);
        let expected = lookahead_step(
            &rust,
            &SpacecraftState::from(nav),
            &CartesianState::from(BODY),
            0.6,
            &canonical,
            &d,
        )
        .unwrap();
        assert_eq!(bits(&command), bits(&expected.command.into()));
    }
}

fn terminal_defaults() -> lt_terminal_settings {
    let mut s = lt_terminal_settings {
        goal_position: 0.0,
        goal_velocity: 0.0,
        cycles: 0,
        iterations: 0,
        cycle: 0.0,
    };
    assert_eq!(unsafe { lt_terminal_defaults(&mut s) }, LT_OK);
    s
}

/// The C terminal-targeting steps command the onboard `terminal_step`'s bits, report its
/// decision, and refuse unusable settings with their own code and thrust off.
#[test]
fn terminal_steps_are_the_onboard_terminal_targeting_bit_for_bit_and_refuse_unusable_settings() {
    use onboard::terminal::{terminal_step, TerminalSettings};
    let settings = terminal_defaults();
    let d = TerminalSettings::default();
    assert_eq!(
        (
            settings.goal_position,
            settings.goal_velocity,
            settings.cycles,
            settings.iterations,
            settings.cycle
        ),
        (d.goal_position, d.goal_velocity, d.cycles, d.iterations, d.cycle)
    );
    let sc = spacecraft();
    let canonical = shared::spacecraft::Spacecraft::MSR_ERO.canonical().unwrap();
    let bytes = f32_blob(ProblemKind::Transfer, &TRANSFER);
    let (status, policy) = load_transfer(&bytes);
    assert_eq!(status, LT_OK);
    let rust = TransferPolicy::from_bytes(&bytes, ProblemKind::Transfer).unwrap();
    let mut solved = 0;
    // Cycles to go from half of one to four and a half: inside the last 3 and outside.
    for (k, (nav, _)) in states(8).into_iter().enumerate() {
        let ttg = 0.2408 * (0.5 + k as f64 / 2.0);
        let mut command = STALE;
        let mut report = std::mem::MaybeUninit::<lt_terminal_report>::uninit();
        let status = unsafe {
            lt_transfer_terminal_step(
                &policy,
                &nav,
                &TARGET,
                ttg,
                &sc,
                &settings,
                &mut command,
                report.as_mut_ptr(),
            )
        };
        assert_eq!(status, LT_OK);
        let report = unsafe { report.assume_init() };
        let expected = terminal_step(
            &rust,
            &SpacecraftState::from(nav),
            &OrbitShape::from(TARGET),
            ttg,
            &canonical,
            &d,
        )
        .unwrap();
        assert_eq!(bits(&command), bits(&expected.command.into()));
        assert_eq!(bits(&report.network), bits(&expected.network.into()));
        assert_eq!(report.solved, u32::from(expected.solved));
        assert_eq!(report.predicted_valid, u32::from(expected.network_miss.is_some()));
        assert_eq!(
            report.network_miss.to_bits(),
            expected.network_miss.unwrap_or(f64::NAN).to_bits()
        );
        solved += report.solved;
        let mut again = STALE;
        let status = unsafe {
            lt_transfer_terminal_step(&policy, &nav, &TARGET, ttg, &sc, &settings, &mut again, ptr::null_mut())
        };
        assert_eq!((status, bits(&again)), (LT_OK, bits(&command)));
    }
    // Made-up weights miss: inside the last cycles a plan is solved somewhere.
    assert!(solved > 0);
    let nav = states(1)[0].0;
    for (spacecraft, settings) in [
        (lt_spacecraft { thrust: f64::NAN, ..sc }, terminal_defaults()),
        (
            sc,
            lt_terminal_settings {
                cycles: 0,
                ..terminal_defaults()
            },
        ),
        (
            sc,
            lt_terminal_settings {
                cycles: 9,
                ..terminal_defaults()
            },
        ),
        (
            sc,
            lt_terminal_settings {
                iterations: 0,
                ..terminal_defaults()
            },
        ),
        (
            sc,
            lt_terminal_settings {
                goal_position: f64::NAN,
                ..terminal_defaults()
            },
        ),
    ] {
        let mut command = STALE;
        let mut report = std::mem::MaybeUninit::<lt_terminal_report>::uninit();
        let status = unsafe {
            lt_transfer_terminal_step(
                &policy,
                &nav,
                &TARGET,
                0.5,
                &spacecraft,
                &settings,
                &mut command,
                report.as_mut_ptr(),
            )
        };
        assert_eq!(status, LT_ERR_INPUT_TERMINAL);
        assert_thrust_off(&command);
        let report = unsafe { report.assume_init() };
        assert_eq!((report.solved, report.predicted_valid), (0, 0));
    }
    let mut command = STALE;
    let status = unsafe {
        lt_rendezvous_terminal_step(&policy, &nav, &BODY, 0.5, &sc, &settings, &mut command, ptr::null_mut())
    };
    assert_eq!(status, LT_ERR_WRONG_POLICY_KIND);
    assert_thrust_off(&command);
    assert_eq!(unsafe { lt_terminal_defaults(ptr::null_mut()) }, LT_ERR_NULL_POINTER);
    // A rendezvous policy: the onboard terminal targeting's command, bit for bit.
    let bytes = int8_blob(ProblemKind::Rendezvous, &RENDEZVOUS);
    let (status, policy) = load_rendezvous(&bytes);
    assert_eq!(status, LT_OK);
    let rust = RendezvousPolicy::from_bytes(&bytes, ProblemKind::Rendezvous).unwrap();
    for (nav, _) in states(3) {
        let mut command = STALE;
        let status = unsafe {
            lt_rendezvous_terminal_step(&policy, &nav, &BODY, 0.6, &sc, &settings, &mut command, ptr::null_mut())
        };
        assert_eq!(status, LT_OK);
        let expected = terminal_step(
            &rust,
            &SpacecraftState::from(nav),
            &CartesianState::from(BODY),
            0.6,
            &canonical,
            &d,
        )
        .unwrap();
        assert_eq!(bits(&command), bits(&expected.command.into()));
    }
}

/// Hostile three-dimensional inputs (NaN, infinities, zeros, huge and tiny values among
/// flight-like ones) through both 3D steps: no panic, and each outcome is the Rust step's (its
/// command to the bit, or its error's code with thrust off); an accepted command has a throttle
/// in [0, 1] and a unit direction.
#[test]
fn hostile_three_dimensional_inputs_fly_as_the_rust_steps_or_thrust_off() {
    let mut s = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    let mut hostile = |lo: f64, hi: f64| {
        let u = (next() >> 11) as f64 / (1u64 << 53) as f64;
        if next() % 100 < 85 {
            lo + (hi - lo) * u
        } else {
            [
                f64::NAN,
                f64::INFINITY,
                -f64::INFINITY,
                0.0,
                -0.0,
                -1.0,
                1e300,
                -1e300,
                5e-324,
            ][(next() % 9) as usize]
        }
    };
    let transfer_bytes = int8_blob(ProblemKind::Transfer, &TRANSFER3);
    let rendezvous_bytes = f32_blob(ProblemKind::Rendezvous, &RENDEZVOUS3);
    let mut policy = lt_policy::default();
    assert_eq!(
        unsafe { lt_transfer3_load(&mut policy, transfer_bytes.as_ptr(), transfer_bytes.len()) },
        LT_OK
    );
    let mut rendezvous_policy = lt_policy::default();
    assert_eq!(
        unsafe {
            lt_rendezvous3_load(
                &mut rendezvous_policy,
                rendezvous_bytes.as_ptr(),
                rendezvous_bytes.len(),
            )
        },
        LT_OK
    );
    let transfer_rust = Transfer3Policy::from_bytes(&transfer_bytes, ProblemKind::Transfer).unwrap();
    let rendezvous_rust = Rendezvous3Policy::from_bytes(&rendezvous_bytes, ProblemKind::Rendezvous).unwrap();
    let check = |code: lt_status, command: &lt_rtn_command, rust: Result<onboard::spatial::RtnCommand, _>| match rust {
        Ok(c) => {
            assert_eq!((code, rtn_bits(command)), (LT_OK, rtn_bits(&c.into())));
            let norm = (command.radial.powi(2) + command.transverse.powi(2) + command.normal.powi(2)).sqrt();
            assert!(
                (0.0..=1.0).contains(&command.throttle) && (norm - 1.0).abs() <= 1e-6,
                "{command:?}"
            );
        }
        Err(e) => {
            assert_eq!(code, lowthrust::error::guidance_error_code(&e));
            assert_eq!(rtn_bits(command), rtn_bits(&RTN_THRUST_OFF));
        }
    };
    let (mut accepted, mut refused) = (0, 0);
    for _ in 0..20_000 {
        let nav = lt_navigation_state3 {
            r: [hostile(-2.0, 2.0), hostile(-2.0, 2.0), hostile(-0.2, 0.2)],
            v: [hostile(-1.5, 1.5), hostile(-1.5, 1.5), hostile(-0.2, 0.2)],
            m: hostile(0.2, 1.0),
        };
        let ttg = hostile(0.0, 12.0);
        let target = lt_target_orbit3 {
            a: hostile(0.5, 2.0),
            e: hostile(0.0, 0.9),
            omega: hostile(-4.0, 4.0),
            inclination: hostile(0.0, 3.2),
            raan: hostile(-7.0, 7.0),
        };
        let (code, command) = transfer3(&policy, &nav, &target, ttg);
        let rust = transfer3_step(&transfer_rust, &nav.into(), &target.into(), ttg);
        if rust.is_ok() {
            accepted += 1;
        } else {
            refused += 1;
        }
        check(code, &command, rust);
        let body = lt_body_state3 {
            r: [hostile(-2.0, 2.0), hostile(-2.0, 2.0), hostile(-0.2, 0.2)],
            v: [hostile(-1.5, 1.5), hostile(-1.5, 1.5), hostile(-0.2, 0.2)],
        };
        let (code, command) = rendezvous3(&rendezvous_policy, &nav, &body, ttg);
        check(
            code,
            &command,
            rendezvous3_step(&rendezvous_rust, &nav.into(), &body.into(), ttg),
        );
    }
    // Both outcomes are exercised.
    assert!(
        accepted > 1000 && refused > 1000,
        "{accepted} accepted, {refused} refused"
    );
}

/// The three-dimensional aids from C: each step the onboard lookahead's and terminal
/// targeting's RTN command and decision to the bit, for a transfer and a rendezvous policy
/// (f32 and int8); a planar policy, unusable settings and null inputs refused with their codes,
/// thrust off and nothing predicted.
#[test]
fn three_dimensional_aids_are_the_onboard_aids_bit_for_bit() {
    use onboard::lookahead::{lookahead_step, LookaheadSettings};
    use onboard::terminal::{terminal_step, TerminalSettings};
    let load = |f: unsafe extern "C" fn(*mut lt_policy, *const u8, usize) -> lt_status, bytes: &[u8]| {
        let mut policy = lt_policy::default();
        assert_eq!(unsafe { f(&mut policy, bytes.as_ptr(), bytes.len()) }, LT_OK);
        policy
    };
    let (sc, canonical) = (
        spacecraft(),
        shared::spacecraft::Spacecraft::MSR_ERO.canonical().unwrap(),
    );
    // Every other cycle on a budget of 5 rollout cycles, so the prefix is flown through C too.
    let lookahead = |k: usize| lt_lookahead_settings {
        rollout_budget: if k.is_multiple_of(2) { 5 } else { 0 },
        ..defaults()
    };
    let rust_lookahead = |k: usize| LookaheadSettings {
        rollout_budget: if k.is_multiple_of(2) { 5 } else { 0 },
        ..LookaheadSettings::default()
    };
    let terminal = lt_terminal_settings {
        cycles: 3,
        ..terminal_defaults()
    };
    let rust_terminal = TerminalSettings {
        cycles: 3,
        ..TerminalSettings::default()
    };
    let prediction_bits = |r: &lt_lookahead_report3| {
        [
            r.predicted_position,
            r.predicted_velocity,
            r.predicted_mass,
            r.predicted_cost,
        ]
        .map(f64::to_bits)
    };
    let (mut overridden, mut solved) = (0, 0);
    for quantized in [false, true] {
        let blob = |kind, sizes: &[usize]| {
            if quantized {
                int8_blob(kind, sizes)
            } else {
                f32_blob(kind, sizes)
            }
        };
        let transfer_bytes = blob(ProblemKind::Transfer, &TRANSFER3);
        let rendezvous_bytes = blob(ProblemKind::Rendezvous, &RENDEZVOUS3);
        let transfer_policy = load(lt_transfer3_load, &transfer_bytes);
        let rendezvous_policy = load(lt_rendezvous3_load, &rendezvous_bytes);
        let transfer_rust = Transfer3Policy::from_bytes(&transfer_bytes, ProblemKind::Transfer).unwrap();
        let rendezvous_rust = Rendezvous3Policy::from_bytes(&rendezvous_bytes, ProblemKind::Rendezvous).unwrap();
        for (k, (nav, _)) in states3(6).into_iter().enumerate() {
            // 1 to 3.5 cycles to go: the terminal plans and partial last cycles.
            let ttg = 0.2408 * (1.0 + k as f64 / 2.0);
            let state = SpatialCraftState::from(nav);
            // Lookahead, transfer then rendezvous.
            let mut command = STALE3;
            let mut report = std::mem::MaybeUninit::<lt_lookahead_report3>::uninit();
            let status = unsafe {
                lt_transfer3_lookahead_step(
                    &transfer_policy,
                    &nav,
                    &TARGET3,
                    ttg,
                    &sc,
                    &lookahead(k),
                    &mut command,
                    report.as_mut_ptr(),
                )
            };
            let report = unsafe { report.assume_init() };
            let expected = lookahead_step(
                &transfer_rust,
                &state,
                &TargetOrbit3::from(TARGET3),
                ttg,
                &canonical,
                &rust_lookahead(k),
            )
            .unwrap();
            assert_eq!(status, LT_OK);
            assert_eq!(rtn_bits(&command), rtn_bits(&expected.command.into()));
            assert_eq!(rtn_bits(&report.network), rtn_bits(&expected.network.into()));
            assert_eq!(report.chosen as usize, expected.chosen);
            let p = expected.predicted.unwrap();
            assert_eq!(report.predicted_valid, 1);
            assert_eq!(
                prediction_bits(&report),
                [p.residuals.position, p.residuals.velocity, p.mass, p.cost].map(f64::to_bits)
            );
            overridden += usize::from(report.chosen != 0);
            let mut command = STALE3;
            let status = unsafe {
                lt_rendezvous3_lookahead_step(
                    &rendezvous_policy,
                    &nav,
                    &BODY3,
                    ttg,
                    &sc,
                    &lookahead(k),
                    &mut command,
                    ptr::null_mut(),
                )
            };
            let expected = lookahead_step(
                &rendezvous_rust,
                &state,
                &SpatialState::from(BODY3),
                ttg,
                &canonical,
                &rust_lookahead(k),
            )
            .unwrap();
            assert_eq!(
                (status, rtn_bits(&command)),
                (LT_OK, rtn_bits(&expected.command.into()))
            );
            // Terminal targeting, transfer then rendezvous.
            let mut command = STALE3;
            let mut report = std::mem::MaybeUninit::<lt_terminal_report3>::uninit();
            let status = unsafe {
                lt_transfer3_terminal_step(
                    &transfer_policy,
                    &nav,
                    &TARGET3,
                    ttg,
                    &sc,
                    &terminal,
                    &mut command,
                    report.as_mut_ptr(),
                )
            };
            let report = unsafe { report.assume_init() };
            let expected = terminal_step(
                &transfer_rust,
                &state,
                &TargetOrbit3::from(TARGET3),
                ttg,
                &canonical,
                &rust_terminal,
            )
            .unwrap();
            assert_eq!(status, LT_OK);
            assert_eq!(rtn_bits(&command), rtn_bits(&expected.command.into()));
            assert_eq!(rtn_bits(&report.network), rtn_bits(&expected.network.into()));
            assert_eq!(report.solved, u32::from(expected.solved));
            assert_eq!(report.predicted_valid, u32::from(expected.network_miss.is_some()));
            assert_eq!(
                [report.network_miss, report.planned_miss].map(f64::to_bits),
                [expected.network_miss, expected.planned_miss].map(|m| m.unwrap_or(f64::NAN).to_bits())
            );
            solved += usize::from(expected.solved);
            let mut command = STALE3;
            let status = unsafe {
                lt_rendezvous3_terminal_step(
                    &rendezvous_policy,
                    &nav,
                    &BODY3,
                    ttg,
                    &sc,
                    &terminal,
                    &mut command,
                    ptr::null_mut(),
                )
            };
            let expected = terminal_step(
                &rendezvous_rust,
                &state,
                &SpatialState::from(BODY3),
                ttg,
                &canonical,
                &rust_terminal,
            )
            .unwrap();
            assert_eq!(
                (status, rtn_bits(&command)),
                (LT_OK, rtn_bits(&expected.command.into()))
            );
        }
    }
    // These made-up weights are far from any optimum: both aids override them somewhere.
    assert!(overridden > 0 && solved > 0, "{overridden} {solved}");

    // Refusals: a planar policy, unusable settings, null inputs; thrust off, nothing predicted.
    let planar_bytes = f32_blob(ProblemKind::Transfer, &TRANSFER);
    let (status, planar) = load_transfer(&planar_bytes);
    assert_eq!(status, LT_OK);
    let spatial_bytes = f32_blob(ProblemKind::Transfer, &TRANSFER3);
    let spatial = load(lt_transfer3_load, &spatial_bytes);
    let nav = states3(1)[0].0;
    let unusable_lookahead = lt_lookahead_settings {
        accuracy_floor: 0.0,
        ..defaults()
    };
    let unusable_terminal = lt_terminal_settings {
        cycles: 0,
        ..terminal_defaults()
    };
    let cases: [(
        &lt_policy,
        *const lt_spacecraft,
        &lt_lookahead_settings,
        &lt_terminal_settings,
        lt_status,
    ); 3] = [
        (&planar, &sc, &defaults(), &terminal, LT_ERR_WRONG_POLICY_KIND),
        (
            &spatial,
            &sc,
            &unusable_lookahead,
            &unusable_terminal,
            LT_ERR_INPUT_LOOKAHEAD,
        ),
        (&spatial, ptr::null(), &defaults(), &terminal, LT_ERR_NULL_POINTER),
    ];
    for (policy, spacecraft, lookahead, terminal, code) in cases {
        let mut command = STALE3;
        let mut report = std::mem::MaybeUninit::<lt_lookahead_report3>::uninit();
        let status = unsafe {
            lt_transfer3_lookahead_step(
                policy,
                &nav,
                &TARGET3,
                1.0,
                spacecraft,
                lookahead,
                &mut command,
                report.as_mut_ptr(),
            )
        };
        assert_eq!(status, code);
        assert_eq!(rtn_bits(&command), rtn_bits(&RTN_THRUST_OFF));
        let report = unsafe { report.assume_init() };
        assert_eq!((report.predicted_valid, report.chosen), (0, 0));
        let mut command = STALE3;
        let mut report = std::mem::MaybeUninit::<lt_terminal_report3>::uninit();
        let status = unsafe {
            lt_rendezvous3_terminal_step(
                policy,
                &nav,
                &BODY3,
                1.0,
                spacecraft,
                terminal,
                &mut command,
                report.as_mut_ptr(),
            )
        };
        // The rendezvous step refuses the spatial transfer policy after checking its inputs.
        let expected = match code {
            LT_ERR_INPUT_LOOKAHEAD => LT_ERR_INPUT_TERMINAL,
            other => other,
        };
        assert_eq!(status, expected);
        assert_eq!(rtn_bits(&command), rtn_bits(&RTN_THRUST_OFF));
        let report = unsafe { report.assume_init() };
        assert_eq!((report.predicted_valid, report.solved), (0, 0));
        assert!(report.planned_miss.is_nan());
    }
    // With usable inputs, the other problem's 3D policy is the wrong kind.
    let mut command = STALE3;
    let status = unsafe {
        lt_rendezvous3_lookahead_step(
            &spatial,
            &nav,
            &BODY3,
            1.0,
            &sc,
            &defaults(),
            &mut command,
            ptr::null_mut(),
        )
    };
    assert_eq!(status, LT_ERR_WRONG_POLICY_KIND);
    assert_eq!(rtn_bits(&command), rtn_bits(&RTN_THRUST_OFF));
}
