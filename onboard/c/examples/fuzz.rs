//! Fuzzes the weight-blob loader and the C entry points: millions of seeded inputs (random
//! bytes, and bit flips, byte edits, truncations, extensions and splices of real blobs), each
//! given to `shared::blob::decode`, to the four policy loaders and to `lt_transfer_load`,
//! `lt_rendezvous_load` and their three-dimensional twins `lt_transfer3_load`,
//! `lt_rendezvous3_load`; every loaded policy is flown through `lt_*_step` with hostile
//! navigation inputs (now and then through the lookahead and terminal-targeting steps too,
//! `lt_transfer_lookahead_step`, `lt_transfer_terminal_step` and the three-dimensional
//! `lt_transfer3_*` and `lt_rendezvous3_*` ones, with hostile spacecraft and settings as well), and the C
//! entry points are called with null, misaligned and impossible arguments.
//!
//! ```text
//! cargo run --profile c-release -p lowthrust-onboard-c --example fuzz -- [--inputs N] [--seed S] [--threads T] [--replay I]
//! ```
//!
//! Built with the static library's profile (`panic = "abort"`), so a panic anywhere is a crash;
//! the panic hook names the input (seed and index) before the abort, and `--replay I` runs that
//! input alone. Exit status 0 only when every input passed every check:
//! - no crash (no panic, no out-of-bounds read: the loader views the bytes in place);
//! - **no altered blob accepted**: an input whose CRC was not recomputed after its bytes were
//!   changed is accepted by nothing unless it equals one of the real blobs byte for byte;
//! - the C loads and steps agree with the Rust functions they wrap (same code, same command bits);
//! - a refused load leaves the policy not loaded, a refused step commands thrust off, and an
//!   accepted step commands a finite throttle in [0, 1] along a unit direction;
//! - bad pointers and lengths get their own codes (null, misaligned policy, impossible length).
//!
//! Inputs whose CRC *is* recomputed after the edit reach the payload decoder and the semantic
//! checks behind the CRC (the part a corrupted flash page never reaches, but a wrong exporter
//! would); they may be accepted, and then they are flown. The generator is structured rather than
//! coverage-guided (cargo-fuzz's sanitizers need a nightly toolchain): every class of edit the
//! format can suffer is drawn in a fixed proportion, reproducibly from (seed, index).

use std::mem::MaybeUninit;
use std::process::ExitCode;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use lowthrust::{
    error::{guidance_error_code, policy_error_code},
    lt_body_state, lt_body_state3, lt_lookahead_defaults, lt_lookahead_report3, lt_lookahead_settings,
    lt_navigation_state, lt_navigation_state3, lt_policy, lt_policy_describe, lt_policy_info, lt_rendezvous3_load,
    lt_rendezvous3_lookahead_step, lt_rendezvous3_step, lt_rendezvous3_terminal_step, lt_rendezvous_load,
    lt_rendezvous_step, lt_rtn_command, lt_spacecraft, lt_status, lt_target_orbit, lt_target_orbit3,
    lt_terminal_defaults, lt_terminal_report3, lt_terminal_settings, lt_thrust_command, lt_transfer3_load,
    lt_transfer3_lookahead_step, lt_transfer3_step, lt_transfer3_terminal_step, lt_transfer_load,
    lt_transfer_lookahead_step, lt_transfer_step, lt_transfer_terminal_step, LT_ERR_BLOB_LENGTH,
    LT_ERR_INPUT_LOOKAHEAD, LT_ERR_INPUT_TERMINAL, LT_ERR_MISALIGNED_POLICY, LT_ERR_NOT_LOADED, LT_ERR_NULL_POINTER,
    LT_ERR_WRONG_POLICY_KIND, LT_OK, LT_PROBLEM_RENDEZVOUS, LT_PROBLEM_RENDEZVOUS3, LT_PROBLEM_TRANSFER,
    LT_PROBLEM_TRANSFER3, RTN_THRUST_OFF,
};
use onboard::dynamics::{SpacecraftState, ThrustCommand};
use onboard::guidance::{
    rendezvous3_step, rendezvous_step, transfer3_step, transfer_step, GuidanceError, TargetOrbit3,
};
use onboard::policy::{Rendezvous3Policy, RendezvousPolicy, Transfer3Policy, TransferPolicy};
use onboard::spatial::SpatialCraftState;
use shared::blob::{decode, Activation, FeatureLayout, ProblemKind, FORMAT_VERSION, HEADER_LEN, MAGIC, TRAILER_LEN};
use shared::orbit::{CartesianState, OrbitShape, SpatialState};
use shared::quantize::{DenseWeights, MlpWeights};
use shared::spacecraft::CanonicalSpacecraft;

const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// SplitMix64, seeded per input so any input is reproduced from (seed, index) alone.
struct Rng(u64);

impl Rng {
    fn for_input(seed: u64, index: u64) -> Self {
        let mut r = Rng(seed ^ index.wrapping_mul(0xD6E8_FEB8_6659_FD93));
        r.next_u64();
        r
    }

    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in 0..n (n > 0).
    fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }

    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }
}

/// A real blob the mutations start from.
struct Seed {
    name: String,
    bytes: Vec<u8>,
}

/// The real blobs: full-size transfer and rendezvous networks, planar and three-dimensional (the
/// shapes the controller flies, f32 and int8), and small networks of every layout and
/// quantization (decoded, then refused by the policies for their shape; cheap to checksum, so
/// most structural edits start from them).
fn corpus() -> Result<Vec<Seed>, String> {
    let mut rng = Rng(0x5EED);
    let shapes: [(&str, FeatureLayout, &[usize]); 10] = [
        (
            "transfer-10-256-256-3",
            FeatureLayout::TransferPolar10,
            &[10, 256, 256, 3],
        ),
        (
            "rendezvous-22-256-256-3",
            FeatureLayout::RendezvousPolar22,
            &[22, 256, 256, 3],
        ),
        (
            "transfer3-15-256-256-4",
            FeatureLayout::TransferSpatial15,
            &[15, 256, 256, 4],
        ),
        (
            "rendezvous3-30-256-256-4",
            FeatureLayout::RendezvousSpatial30,
            &[30, 256, 256, 4],
        ),
        ("transfer-10-4-5-3", FeatureLayout::TransferPolar10, &[10, 4, 5, 3]),
        ("rendezvous-22-3-3", FeatureLayout::RendezvousPolar22, &[22, 3, 3]),
        ("transfer-10-3", FeatureLayout::TransferPolar10, &[10, 3]),
        ("transfer-10-2-2-2-3", FeatureLayout::TransferPolar10, &[10, 2, 2, 2, 3]),
        ("transfer3-15-4-4", FeatureLayout::TransferSpatial15, &[15, 4, 4]),
        ("rendezvous3-30-3-4", FeatureLayout::RendezvousSpatial30, &[30, 3, 4]),
    ];
    let mut seeds = Vec::new();
    for (name, features, sizes) in shapes {
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(l, s)| {
                let bound = (6.0 / s[0] as f64).sqrt();
                DenseWeights {
                    inputs: s[0],
                    outputs: s[1],
                    weights: (0..s[0] * s[1]).map(|_| rng.uniform(-bound, bound) as f32).collect(),
                    bias: (0..s[1]).map(|_| rng.uniform(-0.1, 0.1) as f32).collect(),
                    activation: if l + 2 == sizes.len() {
                        Activation::Tanh
                    } else {
                        Activation::Relu
                    },
                }
            })
            .collect();
        let net = MlpWeights { features, layers };
        let calibration: Vec<Vec<f32>> = (0..64)
            .map(|_| (0..sizes[0]).map(|_| rng.uniform(-2.0, 2.0) as f32).collect())
            .collect();
        let provenance = format!("fuzz corpus {name}");
        let f32_blob = net.f32_blob(&provenance).map_err(|e| format!("{name} f32: {e}"))?;
        let (int8_blob, _) = net
            .int8_blob(&calibration, &provenance)
            .map_err(|e| format!("{name} int8: {e}"))?;
        seeds.push(Seed {
            name: format!("{name} f32"),
            bytes: f32_blob,
        });
        seeds.push(Seed {
            name: format!("{name} int8"),
            bytes: int8_blob,
        });
    }
    Ok(seeds)
}

/// How an input was made, and so what may be expected of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Class {
    /// Uniform random bytes of a random length.
    RandomBytes,
    /// A valid header and CRC around random payload bytes.
    RandomPayload,
    /// A real blob edited in place, its CRC left as it was.
    Altered,
    /// A real blob cut short or extended, its header left as it was.
    Resized,
    /// The head of one real blob joined to the tail of another.
    Spliced,
    /// A real blob edited, then its length and CRC recomputed: reaches the payload checks.
    Reframed,
    /// A real blob as it is.
    Original,
    /// Null, misaligned and impossible arguments to the C entry points.
    Arguments,
}

const CLASSES: [Class; 8] = [
    Class::RandomBytes,
    Class::RandomPayload,
    Class::Altered,
    Class::Resized,
    Class::Spliced,
    Class::Reframed,
    Class::Original,
    Class::Arguments,
];

/// Parts per 10,000 of each class; edits of the two full-size blobs (one CRC over ~270 KB
/// each) are kept to a few per cent of the inputs so ten million run in about a minute.
fn draw_class(rng: &mut Rng) -> Class {
    match rng.below(10_000) {
        0..=1_499 => Class::RandomBytes,
        1_500..=2_999 => Class::RandomPayload,
        3_000..=5_499 => Class::Altered,
        5_500..=6_499 => Class::Resized,
        6_500..=7_299 => Class::Spliced,
        7_300..=9_299 => Class::Reframed,
        9_300..=9_349 => Class::Original,
        _ => Class::Arguments,
    }
}

/// The full-size seeds (f32 and int8 of each flown layout) come first.
const FULL_SIZE_SEEDS: usize = 2 * LAYOUTS.len();

/// Every network layout the controller flies, in the corpus's order.
const LAYOUTS: [FeatureLayout; 4] = [
    FeatureLayout::TransferPolar10,
    FeatureLayout::RendezvousPolar22,
    FeatureLayout::TransferSpatial15,
    FeatureLayout::RendezvousSpatial30,
];

/// A seed blob: the full-size ones once in two hundred, the small ones otherwise.
fn draw_seed(rng: &mut Rng, seeds: &[Seed]) -> usize {
    if rng.chance(0.005) {
        rng.below(FULL_SIZE_SEEDS)
    } else {
        FULL_SIZE_SEEDS + rng.below(seeds.len() - FULL_SIZE_SEEDS)
    }
}

const INTERESTING: [u8; 8] = [0x00, 0x01, 0x7F, 0x80, 0xFF, 0xFE, 0x3F, 0xC0];

/// One to eight edits: bit flips, interesting bytes, random bytes, a float set to NaN / inf /
/// huge, a varint's continuation bit, inside `range` of `bytes`.
fn edit(rng: &mut Rng, bytes: &mut [u8], range: core::ops::Range<usize>) {
    if range.is_empty() {
        return;
    }
    for _ in 0..1 + rng.below(8) {
        let at = range.start + rng.below(range.len());
        match rng.below(5) {
            0 | 1 => bytes[at] ^= 1 << rng.below(8),
            2 => bytes[at] = INTERESTING[rng.below(INTERESTING.len())],
            3 => bytes[at] = rng.next_u64() as u8,
            _ => {
                let value: f32 = [f32::NAN, f32::INFINITY, -f32::INFINITY, 1.7e38, -0.0, 1e-45][rng.below(6)];
                for (k, b) in value.to_le_bytes().into_iter().enumerate() {
                    if let Some(slot) = bytes.get_mut(at + k) {
                        *slot = b;
                    }
                }
            }
        }
    }
}

/// Sets the header's length and the trailer's CRC to match the payload between them.
fn reframe(bytes: &mut [u8]) {
    if bytes.len() < HEADER_LEN + TRAILER_LEN {
        return;
    }
    let payload_len = bytes.len() - HEADER_LEN - TRAILER_LEN;
    bytes[6..10].copy_from_slice(&(payload_len as u32).to_le_bytes());
    let crc = CRC32.checksum(&bytes[HEADER_LEN..HEADER_LEN + payload_len]);
    let end = bytes.len();
    bytes[end - TRAILER_LEN..].copy_from_slice(&crc.to_le_bytes());
}

struct Input {
    class: Class,
    bytes: Vec<u8>,
}

fn generate(rng: &mut Rng, seeds: &[Seed], class: Class) -> Input {
    let bytes = match class {
        Class::RandomBytes => {
            let len = if rng.chance(0.5) {
                rng.below(32)
            } else {
                rng.below(2048)
            };
            let mut b: Vec<u8> = (0..len).map(|_| rng.next_u64() as u8).collect();
            // Half start with the magic, so the version and length checks are reached too.
            if len >= 4 && rng.chance(0.5) {
                b[..4].copy_from_slice(&MAGIC);
            }
            b
        }
        Class::RandomPayload => {
            let len = rng.below(512);
            let mut b = Vec::with_capacity(HEADER_LEN + len + TRAILER_LEN);
            b.extend_from_slice(&MAGIC);
            b.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
            b.extend_from_slice(&[0; 4]);
            // Payloads of small varints and tags are far likelier to parse some way than noise.
            b.extend((0..len).map(|_| {
                if rng.chance(0.6) {
                    rng.below(4) as u8
                } else {
                    rng.next_u64() as u8
                }
            }));
            b.extend_from_slice(&[0; 4]);
            reframe(&mut b);
            b
        }
        Class::Altered | Class::Reframed => {
            let mut b = seeds[draw_seed(rng, seeds)].bytes.clone();
            let len = b.len();
            // Header, payload start (tags, provenance, shapes) or anywhere, equally often.
            let range = match rng.below(3) {
                0 => 0..HEADER_LEN.min(len),
                1 => HEADER_LEN..(HEADER_LEN + 96).min(len),
                _ => 0..len,
            };
            edit(rng, &mut b, range);
            if class == Class::Reframed {
                // Also grow or shrink the payload sometimes, so lengths inside it disagree.
                if rng.chance(0.3) && len > HEADER_LEN + TRAILER_LEN + 1 {
                    let at = HEADER_LEN + rng.below(len - HEADER_LEN - TRAILER_LEN);
                    if rng.chance(0.5) {
                        b.remove(at);
                    } else {
                        b.insert(at, rng.next_u64() as u8);
                    }
                }
                reframe(&mut b);
            }
            b
        }
        Class::Resized => {
            let mut b = seeds[draw_seed(rng, seeds)].bytes.clone();
            if rng.chance(0.6) {
                let keep = if rng.chance(0.5) {
                    rng.below(b.len())
                } else {
                    b.len() - 1 - rng.below(b.len().min(16))
                };
                b.truncate(keep);
            } else {
                b.extend((0..1 + rng.below(16)).map(|_| rng.next_u64() as u8));
            }
            b
        }
        Class::Spliced => {
            let a = &seeds[draw_seed(rng, seeds)].bytes;
            let c = &seeds[draw_seed(rng, seeds)].bytes;
            let cut_a = rng.below(a.len() + 1);
            let cut_c = if rng.chance(0.5) {
                cut_a.min(c.len())
            } else {
                rng.below(c.len() + 1)
            };
            let mut b = a[..cut_a].to_vec();
            b.extend_from_slice(&c[cut_c..]);
            b
        }
        Class::Original => seeds[rng.below(seeds.len())].bytes.clone(),
        Class::Arguments => Vec::new(),
    };
    Input { class, bytes }
}

/// A hostile navigation value: mostly flight-like, sometimes NaN, infinite, zero, negative or huge.
fn hostile(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    if rng.chance(0.85) {
        rng.uniform(lo, hi)
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
            f64::MIN_POSITIVE,
            5e-324,
        ][rng.below(10)]
    }
}

fn navigation(rng: &mut Rng) -> lt_navigation_state {
    let theta = rng.uniform(0.0, std::f64::consts::TAU);
    let r = hostile(rng, 0.3, 2.0);
    lt_navigation_state {
        r: [r * theta.cos(), r * theta.sin()],
        v: [hostile(rng, -1.5, 1.5), hostile(rng, -1.5, 1.5)],
        m: hostile(rng, 0.2, 1.0),
    }
}

/// Checks one command against its code: an error commands thrust off; success a finite
/// throttle in [0, 1] and a unit direction.
fn check_command(code: lt_status, c: &lt_thrust_command) -> Result<(), String> {
    if code != LT_OK {
        return if c.throttle.to_bits() == 0 {
            Ok(())
        } else {
            Err(format!("refused step ({code:?}) commanded throttle {}", c.throttle))
        };
    }
    let norm = c.alpha_r.hypot(c.alpha_theta);
    if !(0.0..=1.0).contains(&c.throttle) || !c.throttle.is_finite() || (norm - 1.0).abs() > 1e-6 {
        return Err(format!("accepted step commanded {c:?}"));
    }
    Ok(())
}

fn same_command(a: &lt_thrust_command, b: &lt_thrust_command) -> bool {
    a.throttle.to_bits() == b.throttle.to_bits()
        && a.alpha_r.to_bits() == b.alpha_r.to_bits()
        && a.alpha_theta.to_bits() == b.alpha_theta.to_bits()
}

/// Does the C call's outcome (`code`, `command`) equal the Rust step's: its command bit for bit,
/// or its error's code?
fn agrees_with_rust(code: lt_status, command: &lt_thrust_command, rust: &Result<ThrustCommand, GuidanceError>) -> bool {
    match rust {
        Ok(c) => code == LT_OK && same_command(command, &lt_thrust_command::from(*c)),
        Err(e) => code == guidance_error_code(e),
    }
}

/// The Rust transfer policy the aids' calls are checked against.
fn loaded_transfer<'a>(
    actor: &'a Option<Result<TransferPolicy<'_>, onboard::policy::PolicyError>>,
) -> Result<&'a TransferPolicy<'a>, String> {
    actor
        .as_ref()
        .ok_or("no transfer policy")?
        .as_ref()
        .map_err(|e| format!("Rust refused: {e}"))
}

/// Flies a loaded policy through a few hostile cycles and checks each command against the Rust
/// guidance step it wraps.
fn fly(rng: &mut Rng, policy: &lt_policy, kind: ProblemKind, bytes: &[u8]) -> Result<(), String> {
    let mut info = lt_policy_info {
        problem: 99,
        quantization: 99,
        ..Default::default()
    };
    // SAFETY: both pointers are valid references.
    let code = unsafe { lt_policy_describe(policy, &mut info) };
    let problem = match kind {
        ProblemKind::Transfer => LT_PROBLEM_TRANSFER,
        ProblemKind::Rendezvous => LT_PROBLEM_RENDEZVOUS,
    };
    if code != LT_OK || info.problem != problem {
        return Err(format!("describe of a loaded {kind:?} policy gave {code:?} / {info:?}"));
    }
    // The Rust policy of this kind only: each parse checksums the whole blob.
    let transfer_actor = (kind == ProblemKind::Transfer).then(|| TransferPolicy::from_bytes(bytes, kind));
    let rendezvous_actor = (kind == ProblemKind::Rendezvous).then(|| RendezvousPolicy::from_bytes(bytes, kind));
    for _ in 0..3 {
        let nav = navigation(rng);
        let time_to_go = hostile(rng, 0.0, 12.0);
        let mut command = lt_thrust_command {
            throttle: f64::NAN,
            alpha_r: f64::NAN,
            alpha_theta: f64::NAN,
        };
        let state: SpacecraftState = nav.into();
        let (code, rust) = match kind {
            ProblemKind::Transfer => {
                let target = lt_target_orbit {
                    a: hostile(rng, 0.5, 2.0),
                    e: hostile(rng, 0.0, 0.9),
                    omega: hostile(rng, -4.0, 4.0),
                };
                // SAFETY: every pointer is a valid reference.
                let code = unsafe { lt_transfer_step(policy, &nav, &target, time_to_go, &mut command) };
                let actor = transfer_actor
                    .ok_or("no transfer policy")?
                    .map_err(|e| format!("Rust refused: {e}"))?;
                let shape: OrbitShape = target.into();
                (code, transfer_step(&actor, &state, &shape, time_to_go))
            }
            ProblemKind::Rendezvous => {
                let body = lt_body_state {
                    r: [hostile(rng, -2.0, 2.0), hostile(rng, -2.0, 2.0)],
                    v: [hostile(rng, -1.5, 1.5), hostile(rng, -1.5, 1.5)],
                };
                // SAFETY: every pointer is a valid reference.
                let code = unsafe { lt_rendezvous_step(policy, &nav, &body, time_to_go, &mut command) };
                let actor = rendezvous_actor
                    .ok_or("no rendezvous policy")?
                    .map_err(|e| format!("Rust refused: {e}"))?;
                let body: CartesianState = body.into();
                (code, rendezvous_step(&actor, &state, &body, time_to_go))
            }
        };
        check_command(code, &command)?;
        if !agrees_with_rust(code, &command, &rust) {
            return Err(format!("C step gave {code:?} {command:?}, Rust {rust:?}"));
        }
        // Rarely (a lookahead cycle costs up to 21 x 200 rollout cycles), the same state through
        // the lookahead with hostile spacecraft and settings.
        if kind == ProblemKind::Transfer && rng.chance(0.002) {
            lookahead(rng, policy, &transfer_actor, &nav, time_to_go)?;
        }
        // As rarely, through terminal targeting with hostile spacecraft and settings.
        if kind == ProblemKind::Transfer && rng.chance(0.002) {
            terminal(rng, policy, &transfer_actor, &nav, time_to_go)?;
        }
        // The other kind's step on this policy is refused, with thrust off.
        let code = match kind {
            ProblemKind::Transfer => {
                let body = lt_body_state {
                    r: [1.0, 0.0],
                    v: [0.0, 1.0],
                };
                // SAFETY: every pointer is a valid reference.
                unsafe { lt_rendezvous_step(policy, &nav, &body, time_to_go, &mut command) }
            }
            ProblemKind::Rendezvous => {
                let target = lt_target_orbit {
                    a: 1.5,
                    e: 0.0,
                    omega: 0.0,
                };
                // SAFETY: every pointer is a valid reference.
                unsafe { lt_transfer_step(policy, &nav, &target, time_to_go, &mut command) }
            }
        };
        if code != LT_ERR_WRONG_POLICY_KIND {
            return Err(format!("the other kind's step on a {kind:?} policy gave {code:?}"));
        }
        check_command(code, &command)?;
    }
    Ok(())
}

/// [`fly`] in three dimensions: a loaded 3D policy through a few hostile cycles, each command
/// checked against the Rust step it wraps; the planar step refuses it.
fn fly3(rng: &mut Rng, policy: &lt_policy, features: FeatureLayout, bytes: &[u8]) -> Result<(), String> {
    let mut info = lt_policy_info::default();
    // SAFETY: both pointers are valid references.
    let code = unsafe { lt_policy_describe(policy, &mut info) };
    let transfer = features == FeatureLayout::TransferSpatial15;
    let problem = if transfer {
        LT_PROBLEM_TRANSFER3
    } else {
        LT_PROBLEM_RENDEZVOUS3
    };
    if code != LT_OK || info.problem != problem {
        return Err(format!(
            "describe of a loaded {features:?} policy gave {code:?} / {info:?}"
        ));
    }
    let kind = features.problem();
    for _ in 0..3 {
        let planar = navigation(rng);
        let nav = lt_navigation_state3 {
            r: [planar.r[0], planar.r[1], hostile(rng, -0.2, 0.2)],
            v: [planar.v[0], planar.v[1], hostile(rng, -0.2, 0.2)],
            m: planar.m,
        };
        let time_to_go = hostile(rng, 0.0, 12.0);
        let mut command = lt_rtn_command {
            throttle: f64::NAN,
            radial: f64::NAN,
            transverse: f64::NAN,
            normal: f64::NAN,
        };
        let state: SpatialCraftState = nav.into();
        let (code, rust) = if transfer {
            let target = lt_target_orbit3 {
                a: hostile(rng, 0.5, 2.0),
                e: hostile(rng, 0.0, 0.9),
                omega: hostile(rng, -4.0, 4.0),
                inclination: hostile(rng, 0.0, 3.2),
                raan: hostile(rng, -7.0, 7.0),
            };
            if rng.chance(AID3_CHANCE) {
                aid3(rng, policy, bytes, kind, &nav, Target3::Orbit(target), time_to_go)?;
            }
            // SAFETY: every pointer is a valid reference.
            let code = unsafe { lt_transfer3_step(policy, &nav, &target, time_to_go, &mut command) };
            let actor = Transfer3Policy::from_bytes(bytes, kind).map_err(|e| format!("Rust refused: {e}"))?;
            (code, transfer3_step(&actor, &state, &target.into(), time_to_go))
        } else {
            let body = lt_body_state3 {
                r: [
                    hostile(rng, -2.0, 2.0),
                    hostile(rng, -2.0, 2.0),
                    hostile(rng, -0.2, 0.2),
                ],
                v: [
                    hostile(rng, -1.5, 1.5),
                    hostile(rng, -1.5, 1.5),
                    hostile(rng, -0.2, 0.2),
                ],
            };
            if rng.chance(AID3_CHANCE) {
                aid3(rng, policy, bytes, kind, &nav, Target3::Body(body), time_to_go)?;
            }
            // SAFETY: every pointer is a valid reference.
            let code = unsafe { lt_rendezvous3_step(policy, &nav, &body, time_to_go, &mut command) };
            let actor = Rendezvous3Policy::from_bytes(bytes, kind).map_err(|e| format!("Rust refused: {e}"))?;
            (
                code,
                rendezvous3_step(&actor, &state, &SpatialState::from(body), time_to_go),
            )
        };
        let bits = |c: &lt_rtn_command| [c.throttle, c.radial, c.transverse, c.normal].map(f64::to_bits);
        let agrees = match &rust {
            Ok(c) => code == LT_OK && bits(&command) == bits(&lt_rtn_command::from(*c)),
            Err(e) => code == guidance_error_code(e) && bits(&command) == bits(&RTN_THRUST_OFF),
        };
        if !agrees {
            return Err(format!("3D C step gave {code:?} {command:?}, Rust {rust:?}"));
        }
        if code == LT_OK {
            let norm = (command.radial.powi(2) + command.transverse.powi(2) + command.normal.powi(2)).sqrt();
            if !(0.0..=1.0).contains(&command.throttle) || (norm - 1.0).abs() > 1e-6 {
                return Err(format!("accepted 3D step commanded {command:?}"));
            }
        }
        // The planar step on this policy is refused, with thrust off.
        let mut planar_command = lt_thrust_command {
            throttle: 1.0,
            alpha_r: 0.0,
            alpha_theta: 1.0,
        };
        let target = lt_target_orbit {
            a: 1.5,
            e: 0.0,
            omega: 0.0,
        };
        // SAFETY: every pointer is a valid reference.
        let code = unsafe { lt_transfer_step(policy, &planar, &target, time_to_go, &mut planar_command) };
        if code != LT_ERR_WRONG_POLICY_KIND {
            return Err(format!("the planar step on a {features:?} policy gave {code:?}"));
        }
        check_command(code, &planar_command)?;
    }
    Ok(())
}

/// How often a fuzzed 3D step also flies an onboard aid (a cycle costs up to thousands of
/// propagations).
const AID3_CHANCE: f64 = 0.003;

/// What a three-dimensional aid cycle aims at.
#[derive(Clone, Copy)]
enum Target3 {
    Orbit(lt_target_orbit3),
    Body(lt_body_state3),
}

/// One aid's settings, as C gets them and as the Rust aid reads them.
enum AidSettings {
    Lookahead(lt_lookahead_settings, onboard::lookahead::LookaheadSettings),
    Terminal(lt_terminal_settings, onboard::terminal::TerminalSettings),
}

/// A three-dimensional aid step of the C interface towards a target struct `T`, with settings
/// struct `S` and report struct `R`.
type CAid3<T, S, R> = unsafe extern "C" fn(
    *const lt_policy,
    *const lt_navigation_state3,
    *const T,
    f64,
    *const lt_spacecraft,
    *const S,
    *mut lt_rtn_command,
    *mut R,
) -> lt_status;

/// The C steps of both aids towards one kind of target.
struct CAids3<T> {
    lookahead: CAid3<T, lt_lookahead_settings, lt_lookahead_report3>,
    terminal: CAid3<T, lt_terminal_settings, lt_terminal_report3>,
}

/// The inputs of one three-dimensional aid cycle, whatever its target.
struct AidCall3<'a> {
    settings: AidSettings,
    /// The settings and the spacecraft are valid: the Rust aid is flown too (C must refuse the rest).
    usable: bool,
    policy: &'a lt_policy,
    nav: &'a lt_navigation_state3,
    time_to_go: f64,
    spacecraft: lt_spacecraft,
}

/// Flies `call`'s aid through C (the report null) and, when usable, through the Rust crate with
/// `actor` towards `target` (as the Rust aid reads `c_target`): the C code and the Rust result.
fn both_aids3<const N: usize, T, A, R>(
    call: &AidCall3,
    c_aids: CAids3<T>,
    c_target: &T,
    target: &R,
    actor: &A,
    command: &mut lt_rtn_command,
) -> (lt_status, Option<Result<onboard::spatial::RtnCommand, GuidanceError>>)
where
    A: onboard::guidance::Actor<N, { onboard::features::ACTION3_LEN }>,
    R: onboard::guidance::Aim<N, { onboard::features::ACTION3_LEN }, Geometry = onboard::geometry::Spatial>,
{
    use onboard::lookahead::lookahead_step;
    use onboard::terminal::terminal_step;
    use std::ptr::null_mut;
    let AidCall3 {
        usable,
        policy,
        nav,
        time_to_go,
        ..
    } = *call;
    let state = SpatialCraftState::from(*nav);
    let (spacecraft, sc) = (&call.spacecraft, CanonicalSpacecraft::from(call.spacecraft));
    // SAFETY (both calls): every pointer is a valid reference; the report may be null.
    match &call.settings {
        AidSettings::Lookahead(c, rust) => (
            unsafe { (c_aids.lookahead)(policy, nav, c_target, time_to_go, spacecraft, c, command, null_mut()) },
            usable.then(|| lookahead_step(actor, &state, target, time_to_go, &sc, rust).map(|d| d.command)),
        ),
        AidSettings::Terminal(c, rust) => (
            unsafe { (c_aids.terminal)(policy, nav, c_target, time_to_go, spacecraft, c, command, null_mut()) },
            usable.then(|| terminal_step(actor, &state, target, time_to_go, &sc, rust).map(|d| d.command)),
        ),
    }
}

/// One three-dimensional aid cycle, lookahead or terminal targeting at random, with hostile
/// spacecraft and settings: the C call commands the Rust aid's bits, or refuses unusable inputs
/// with its code and thrust off.
fn aid3(
    rng: &mut Rng,
    policy: &lt_policy,
    bytes: &[u8],
    kind: ProblemKind,
    nav: &lt_navigation_state3,
    target: Target3,
    time_to_go: f64,
) -> Result<(), String> {
    let (spacecraft, _) = hostile_aid_inputs(rng)?;
    let (settings, time_to_go, usable, unusable_code) = if rng.chance(0.5) {
        let (c, rust) = hostile_lookahead_settings(rng)?;
        let usable = rust.validate().is_ok();
        (
            AidSettings::Lookahead(c, rust),
            time_to_go.min(12.0),
            usable,
            LT_ERR_INPUT_LOOKAHEAD,
        )
    } else {
        let (c, rust) = hostile_terminal_settings(rng)?;
        let usable = rust.validate().is_ok();
        let time_to_go = if rng.chance(0.5) {
            time_to_go.min(1.0)
        } else {
            time_to_go
        };
        (
            AidSettings::Terminal(c, rust),
            time_to_go,
            usable,
            LT_ERR_INPUT_TERMINAL,
        )
    };
    let call = AidCall3 {
        settings,
        usable: usable && CanonicalSpacecraft::from(spacecraft).is_valid(),
        policy,
        nav,
        time_to_go,
        spacecraft,
    };
    let mut command = lt_rtn_command {
        throttle: f64::NAN,
        radial: f64::NAN,
        transverse: f64::NAN,
        normal: f64::NAN,
    };
    let refused = |e: String| format!("Rust refused: {e}");
    let (code, rust) = match target {
        Target3::Orbit(orbit) => {
            let actor = Transfer3Policy::from_bytes(bytes, kind).map_err(|e| refused(e.to_string()))?;
            let c_aids = CAids3 {
                lookahead: lt_transfer3_lookahead_step,
                terminal: lt_transfer3_terminal_step,
            };
            both_aids3(&call, c_aids, &orbit, &TargetOrbit3::from(orbit), &actor, &mut command)
        }
        Target3::Body(body) => {
            let actor = Rendezvous3Policy::from_bytes(bytes, kind).map_err(|e| refused(e.to_string()))?;
            let c_aids = CAids3 {
                lookahead: lt_rendezvous3_lookahead_step,
                terminal: lt_rendezvous3_terminal_step,
            };
            both_aids3(&call, c_aids, &body, &SpatialState::from(body), &actor, &mut command)
        }
    };
    let bits = |c: &lt_rtn_command| [c.throttle, c.radial, c.transverse, c.normal].map(f64::to_bits);
    let agrees = match &rust {
        None => code == unusable_code && bits(&command) == bits(&RTN_THRUST_OFF),
        Some(Ok(c)) => code == LT_OK && bits(&command) == bits(&lt_rtn_command::from(*c)),
        Some(Err(e)) => code == guidance_error_code(e) && bits(&command) == bits(&RTN_THRUST_OFF),
    };
    if agrees {
        Ok(())
    } else {
        Err(format!("3D C aid gave {code:?} {command:?}, Rust {rust:?}"))
    }
}

/// Hostile lookahead settings, as C gets them and as the Rust lookahead reads them.
fn hostile_lookahead_settings(
    rng: &mut Rng,
) -> Result<(lt_lookahead_settings, onboard::lookahead::LookaheadSettings), String> {
    let mut settings = MaybeUninit::<lt_lookahead_settings>::uninit();
    // SAFETY: a valid pointer to writable storage.
    if unsafe { lt_lookahead_defaults(settings.as_mut_ptr()) } != LT_OK {
        return Err("lt_lookahead_defaults failed".into());
    }
    // SAFETY: written by lt_lookahead_defaults.
    let mut settings = unsafe { settings.assume_init() };
    settings.accuracy_floor = hostile(rng, 0.1, 1.0);
    settings.fuel_weight = hostile(rng, 0.0, 10.0);
    settings.max_cycles = [0, 1, 3, 12, 200, u32::MAX][rng.below(6)];
    settings.thrust_margin = if rng.chance(0.5) { 0.0 } else { hostile(rng, 0.0, 0.2) };
    settings.arrival_margin = [0, 0, 1, 2, u32::MAX][rng.below(5)];
    settings.rollout_budget = [0, 0, 1, 7, 60, u32::MAX][rng.below(6)];
    let rust = onboard::lookahead::LookaheadSettings {
        goal_position: settings.goal_position,
        goal_velocity: settings.goal_velocity,
        accuracy_floor: settings.accuracy_floor,
        fuel_weight: settings.fuel_weight,
        max_cycles: settings.max_cycles,
        thrust_margin: settings.thrust_margin,
        arrival_margin: settings.arrival_margin,
        rollout_budget: settings.rollout_budget,
        ..onboard::lookahead::LookaheadSettings::default()
    };
    Ok((settings, rust))
}

/// Hostile terminal-targeting settings, as C gets them and as the Rust step reads them.
fn hostile_terminal_settings(
    rng: &mut Rng,
) -> Result<(lt_terminal_settings, onboard::terminal::TerminalSettings), String> {
    let mut settings = MaybeUninit::<lt_terminal_settings>::uninit();
    // SAFETY: a valid pointer to writable storage.
    if unsafe { lt_terminal_defaults(settings.as_mut_ptr()) } != LT_OK {
        return Err("lt_terminal_defaults failed".into());
    }
    // SAFETY: written by lt_terminal_defaults.
    let mut settings = unsafe { settings.assume_init() };
    settings.cycles = [0, 1, 2, 3, 4, 5, u32::MAX][rng.below(7)];
    settings.iterations = [0, 1, 8, 64, 65, u32::MAX][rng.below(6)];
    settings.goal_position = if rng.chance(0.8) { 0.01 } else { hostile(rng, 0.0, 0.1) };
    let rust = onboard::terminal::TerminalSettings {
        goal_position: settings.goal_position,
        goal_velocity: settings.goal_velocity,
        cycles: settings.cycles,
        iterations: settings.iterations,
        ..onboard::terminal::TerminalSettings::default()
    };
    Ok((settings, rust))
}

/// The spacecraft (now and then a hostile thrust) and target orbit an onboard aid's cycle is
/// fuzzed with.
fn hostile_aid_inputs(rng: &mut Rng) -> Result<(lt_spacecraft, lt_target_orbit), String> {
    let canonical = shared::spacecraft::Spacecraft::MSR_ERO
        .canonical()
        .map_err(|e| format!("{e:?}"))?;
    let spacecraft = lt_spacecraft {
        thrust: if rng.chance(0.9) {
            canonical.thrust
        } else {
            hostile(rng, 0.0, 1.0)
        },
        exhaust_speed: canonical.exhaust_speed,
    };
    let target = lt_target_orbit {
        a: hostile(rng, 0.5, 2.0),
        e: hostile(rng, 0.0, 0.9),
        omega: hostile(rng, -4.0, 4.0),
    };
    Ok((spacecraft, target))
}

/// One transfer lookahead cycle with hostile spacecraft and settings: the C call agrees with
/// the Rust lookahead it wraps, refuses unusable spacecraft or settings with its code and thrust
/// off, and commands a valid command otherwise.
fn lookahead(
    rng: &mut Rng,
    policy: &lt_policy,
    actor: &Option<Result<TransferPolicy<'_>, onboard::policy::PolicyError>>,
    nav: &lt_navigation_state,
    time_to_go: f64,
) -> Result<(), String> {
    use onboard::lookahead::lookahead_step;
    let (settings, rust_settings) = hostile_lookahead_settings(rng)?;
    let (spacecraft, target) = hostile_aid_inputs(rng)?;
    // At most 12 t* ahead (50 cycles): a hostile huge time to go flies the network unexamined.
    let time_to_go = time_to_go.min(12.0);
    let mut command = lt_thrust_command {
        throttle: f64::NAN,
        alpha_r: f64::NAN,
        alpha_theta: f64::NAN,
    };
    // SAFETY: every pointer is a valid reference; the report may be null.
    let code = unsafe {
        lt_transfer_lookahead_step(
            policy,
            nav,
            &target,
            time_to_go,
            &spacecraft,
            &settings,
            &mut command,
            std::ptr::null_mut(),
        )
    };
    check_command(code, &command)?;
    let rust_spacecraft = CanonicalSpacecraft::from(spacecraft);
    if !rust_spacecraft.is_valid() || rust_settings.validate().is_err() {
        return if code == LT_ERR_INPUT_LOOKAHEAD {
            Ok(())
        } else {
            Err(format!("unusable lookahead inputs gave {code:?}"))
        };
    }
    let actor = loaded_transfer(actor)?;
    let state: SpacecraftState = (*nav).into();
    let rust = lookahead_step(
        actor,
        &state,
        &OrbitShape::from(target),
        time_to_go,
        &rust_spacecraft,
        &rust_settings,
    );
    if agrees_with_rust(code, &command, &rust.map(|d| d.command)) {
        Ok(())
    } else {
        Err(format!("C lookahead gave {code:?} {command:?}, Rust {rust:?}"))
    }
}

/// One transfer terminal-targeting cycle with hostile spacecraft and settings: the C call
/// agrees with the Rust step it wraps, refuses unusable spacecraft or settings with its code and
/// thrust off, and commands a valid command otherwise.
fn terminal(
    rng: &mut Rng,
    policy: &lt_policy,
    actor: &Option<Result<TransferPolicy<'_>, onboard::policy::PolicyError>>,
    nav: &lt_navigation_state,
    time_to_go: f64,
) -> Result<(), String> {
    use onboard::terminal::terminal_step;
    let (settings, rust_settings) = hostile_terminal_settings(rng)?;
    let (spacecraft, target) = hostile_aid_inputs(rng)?;
    // Within the last cycles as often as not (a huge time to go flies the network unexamined).
    let time_to_go = if rng.chance(0.5) {
        time_to_go.min(1.0)
    } else {
        time_to_go
    };
    let mut command = lt_thrust_command {
        throttle: f64::NAN,
        alpha_r: f64::NAN,
        alpha_theta: f64::NAN,
    };
    // SAFETY: every pointer is a valid reference; the report may be null.
    let code = unsafe {
        lt_transfer_terminal_step(
            policy,
            nav,
            &target,
            time_to_go,
            &spacecraft,
            &settings,
            &mut command,
            std::ptr::null_mut(),
        )
    };
    check_command(code, &command)?;
    let rust_spacecraft = CanonicalSpacecraft::from(spacecraft);
    if !rust_spacecraft.is_valid() || rust_settings.validate().is_err() {
        return if code == LT_ERR_INPUT_TERMINAL {
            Ok(())
        } else {
            Err(format!("unusable terminal-targeting inputs gave {code:?}"))
        };
    }
    let actor = loaded_transfer(actor)?;
    let state: SpacecraftState = (*nav).into();
    let rust = terminal_step(
        actor,
        &state,
        &OrbitShape::from(target),
        time_to_go,
        &rust_spacecraft,
        &rust_settings,
    );
    if agrees_with_rust(code, &command, &rust.map(|d| d.command)) {
        Ok(())
    } else {
        Err(format!("C terminal targeting gave {code:?} {command:?}, Rust {rust:?}"))
    }
}

/// What one input did.
#[derive(Default)]
struct Tally {
    inputs: [u64; CLASSES.len()],
    accepted: [u64; CLASSES.len()],
    codes: std::collections::BTreeMap<i32, u64>,
}

/// Gives `bytes` to every loader, checks they agree and what may be accepted, flies what loads.
fn check_blob(rng: &mut Rng, input: &Input, seeds: &[Seed], tally: &mut Tally) -> Result<(), String> {
    let bytes = input.bytes.as_slice();
    let decoded = decode(bytes);
    let mut accepted_any = decoded.is_ok();
    for (index, features) in LAYOUTS.into_iter().enumerate() {
        let kind = features.problem();
        let rust = match features {
            FeatureLayout::TransferPolar10 => TransferPolicy::from_bytes(bytes, kind).map(|_| ()),
            FeatureLayout::RendezvousPolar22 => RendezvousPolicy::from_bytes(bytes, kind).map(|_| ()),
            FeatureLayout::TransferSpatial15 => Transfer3Policy::from_bytes(bytes, kind).map(|_| ()),
            FeatureLayout::RendezvousSpatial30 => Rendezvous3Policy::from_bytes(bytes, kind).map(|_| ()),
        };
        let load = |policy: &mut lt_policy, ptr: *const u8, len: usize| {
            // SAFETY: the caller passes a valid reference and `len` readable bytes at `ptr`.
            unsafe {
                match features {
                    FeatureLayout::TransferPolar10 => lt_transfer_load(policy, ptr, len),
                    FeatureLayout::RendezvousPolar22 => lt_rendezvous_load(policy, ptr, len),
                    FeatureLayout::TransferSpatial15 => lt_transfer3_load(policy, ptr, len),
                    FeatureLayout::RendezvousSpatial30 => lt_rendezvous3_load(policy, ptr, len),
                }
            }
        };
        // A policy that held a network before: a refused load must leave it not loaded.
        let mut policy = lt_policy::default();
        let seed_blob = &seeds[2 * index].bytes;
        // Rarely: each preload checksums a full-size blob.
        let preload = rng.chance(0.001);
        if preload {
            let code = load(&mut policy, seed_blob.as_ptr(), seed_blob.len());
            if code != LT_OK {
                return Err(format!("the real {features:?} blob was refused: {code:?}"));
            }
        }
        // An empty input is passed as a dangling, non-null pointer, as C would pass an empty array.
        let ptr = if bytes.is_empty() {
            std::ptr::NonNull::<u8>::dangling().as_ptr().cast_const()
        } else {
            bytes.as_ptr()
        };
        // `ptr` is valid for `bytes.len()` bytes, which outlive the policy's use here.
        let code = load(&mut policy, ptr, bytes.len());
        *tally.codes.entry(code as i32).or_default() += 1;
        match &rust {
            Ok(()) if code == LT_OK => {
                accepted_any = true;
                if decoded.is_err() {
                    return Err("a policy loaded from bytes the decoder refuses".into());
                }
                if features.is_spatial() {
                    fly3(rng, &policy, features, bytes)?;
                } else {
                    fly(rng, &policy, kind, bytes)?;
                }
            }
            Err(e) if code == policy_error_code(e) => {
                let mut info = lt_policy_info {
                    problem: 0,
                    quantization: 0,
                    ..Default::default()
                };
                // SAFETY: both pointers are valid references.
                let described = unsafe { lt_policy_describe(&policy, &mut info) };
                let mut command = lt_thrust_command {
                    throttle: 1.0,
                    alpha_r: 0.0,
                    alpha_theta: 1.0,
                };
                let nav = navigation(rng);
                let target = lt_target_orbit {
                    a: 1.5,
                    e: 0.0,
                    omega: 0.0,
                };
                // SAFETY: every pointer is a valid reference.
                let stepped = unsafe { lt_transfer_step(&policy, &nav, &target, 1.0, &mut command) };
                if described != LT_ERR_NOT_LOADED || stepped != LT_ERR_NOT_LOADED || command.throttle.to_bits() != 0 {
                    return Err(format!(
                        "after a refused load (preloaded: {preload}) describe gave {described:?}, a step {stepped:?} with throttle {}",
                        command.throttle
                    ));
                }
            }
            _ => return Err(format!("C load gave {code:?}, Rust {rust:?}")),
        }
    }
    if accepted_any {
        let class = CLASSES.iter().position(|c| *c == input.class).unwrap_or(0);
        tally.accepted[class] += 1;
        let is_real = seeds.iter().any(|s| s.bytes == bytes);
        let may_differ = matches!(input.class, Class::Reframed | Class::RandomPayload);
        if !is_real && !may_differ {
            return Err(format!("an altered blob ({:?}) was accepted", input.class));
        }
        if input.class == Class::Original && !is_real {
            return Err("an original is not in the corpus".into());
        }
    } else if input.class == Class::Original {
        return Err("a real blob was refused by the decoder and both loaders".into());
    }
    Ok(())
}

/// Null, misaligned and impossible arguments get their own codes; nothing is written through
/// a null pointer, and a step's command is thrust off whenever it is refused.
fn check_arguments(rng: &mut Rng, seeds: &[Seed]) -> Result<(), String> {
    let blob = &seeds[rng.below(seeds.len())].bytes;
    let mut storage = [MaybeUninit::<lt_policy>::zeroed(), MaybeUninit::zeroed()];
    let base = storage.as_mut_ptr().cast::<u8>();
    let offset = 1 + rng.below(7);
    // SAFETY: within the two-policy buffer.
    let misaligned = unsafe { base.add(offset) }.cast::<lt_policy>();
    let aligned = base.cast::<lt_policy>();
    let len_cases = [usize::MAX, isize::MAX as usize + 1, usize::MAX - 3];
    let huge = len_cases[rng.below(len_cases.len())];
    let transfer = rng.chance(0.5);
    let load = |policy: *mut lt_policy, ptr: *const u8, len: usize| -> lt_status {
        // SAFETY: the load checks null, alignment and an impossible length before reading;
        // otherwise ptr/len describe `blob` and policy points into `storage`.
        unsafe {
            if transfer {
                lt_transfer_load(policy, ptr, len)
            } else {
                lt_rendezvous_load(policy, ptr, len)
            }
        }
    };
    let cases = [
        (
            "null policy",
            load(std::ptr::null_mut(), blob.as_ptr(), blob.len()),
            LT_ERR_NULL_POINTER,
        ),
        (
            "null blob",
            load(aligned, std::ptr::null(), blob.len()),
            LT_ERR_NULL_POINTER,
        ),
        (
            "null empty blob",
            load(aligned, std::ptr::null(), 0),
            LT_ERR_NULL_POINTER,
        ),
        (
            "misaligned policy",
            load(misaligned, blob.as_ptr(), blob.len()),
            LT_ERR_MISALIGNED_POLICY,
        ),
        (
            "impossible length",
            load(aligned, blob.as_ptr(), huge),
            LT_ERR_BLOB_LENGTH,
        ),
    ];
    for (what, got, want) in cases {
        if got != want {
            return Err(format!("{what}: {got:?}, expected {want:?}"));
        }
    }
    // Steps with null inputs or output: refused; the output, when there is one, is thrust off.
    let nav = navigation(rng);
    let target = lt_target_orbit {
        a: 1.5,
        e: 0.0,
        omega: 0.0,
    };
    let body = lt_body_state {
        r: [1.5, 0.0],
        v: [0.0, 0.8],
    };
    let mut command = lt_thrust_command {
        throttle: 1.0,
        alpha_r: 0.0,
        alpha_theta: 1.0,
    };
    let which = rng.below(4);
    let policy_ptr: *const lt_policy = if rng.chance(0.5) {
        std::ptr::null()
    } else {
        misaligned.cast_const()
    };
    // SAFETY: each non-null pointer is a valid reference; the functions check the null ones and
    // the misaligned policy before reading.
    let code = unsafe {
        match which {
            0 => lt_transfer_step(policy_ptr, &nav, &target, 1.0, &mut command),
            1 => lt_rendezvous_step(policy_ptr, &nav, &body, 1.0, &mut command),
            2 => lt_transfer_step(aligned, std::ptr::null(), &target, 1.0, &mut command),
            _ => lt_rendezvous_step(aligned, &nav, std::ptr::null(), 1.0, &mut command),
        }
    };
    let want = if which < 2 && !policy_ptr.is_null() {
        LT_ERR_MISALIGNED_POLICY
    } else if which < 2 {
        LT_ERR_NULL_POINTER
    } else {
        // A zeroed policy is not loaded, checked before the null input.
        LT_ERR_NOT_LOADED
    };
    if code != want || command.throttle.to_bits() != 0 {
        return Err(format!(
            "step case {which}: {code:?} throttle {}, expected {want:?} and thrust off",
            command.throttle
        ));
    }
    // SAFETY: a null command pointer is checked; the other pointers are valid references.
    let code = unsafe { lt_transfer_step(aligned, &nav, &target, 1.0, std::ptr::null_mut()) };
    if code != LT_ERR_NULL_POINTER {
        return Err(format!("null command: {code:?}"));
    }
    // SAFETY: a null info pointer is checked first.
    let code = unsafe { lt_policy_describe(aligned, std::ptr::null_mut()) };
    if code != LT_ERR_NULL_POINTER {
        return Err(format!("null info: {code:?}"));
    }
    Ok(())
}

fn run_input(seed: u64, index: u64, seeds: &[Seed], tally: &mut Tally) -> Result<(), String> {
    let mut rng = Rng::for_input(seed, index);
    let class = draw_class(&mut rng);
    let position = CLASSES.iter().position(|c| *c == class).unwrap_or(0);
    tally.inputs[position] += 1;
    if class == Class::Arguments {
        return check_arguments(&mut rng, seeds);
    }
    let input = generate(&mut rng, seeds, class);
    check_blob(&mut rng, &input, seeds, tally)
}

std::thread_local! {
    static CURRENT: std::cell::Cell<Option<(u64, u64)>> = const { std::cell::Cell::new(None) };
}

struct Args {
    inputs: u64,
    seed: u64,
    threads: usize,
    replay: Option<u64>,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        inputs: 10_000_000,
        seed: 1,
        threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        replay: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().ok_or(format!("{flag} needs a value"))?;
        let number = || value.parse::<u64>().map_err(|e| format!("{flag} {value}: {e}"));
        match flag.as_str() {
            "--inputs" => args.inputs = number()?,
            "--seed" => args.seed = number()?,
            "--threads" => args.threads = usize::try_from(number()?).map_err(|e| e.to_string())?,
            "--replay" => args.replay = Some(number()?),
            _ => return Err(format!("unknown argument {flag}")),
        }
    }
    if args.inputs == 0 || args.threads == 0 {
        return Err("--inputs and --threads must be at least 1".into());
    }
    Ok(args)
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("fuzz: {e}\nusage: fuzz [--inputs N] [--seed S] [--threads T] [--replay I]");
            return ExitCode::from(2);
        }
    };
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if let Some((seed, index)) = CURRENT.with(|c| c.get()) {
            eprintln!("fuzz: CRASH on input {index} of seed {seed}: replay with --seed {seed} --replay {index}");
        }
        default_hook(info);
    }));
    let seeds = match corpus() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("fuzz: could not build the corpus: {e}");
            return ExitCode::FAILURE;
        }
    };
    let (first, count) = match args.replay {
        Some(i) => (i, 1),
        None => (0, args.inputs),
    };
    let seed = args.seed;
    let started = Instant::now();
    let done = AtomicU64::new(0);
    let failures: Mutex<Vec<(u64, String)>> = Mutex::new(Vec::new());
    let total = Mutex::new(Tally::default());
    let threads = (args.threads as u64).min(count);
    std::thread::scope(|scope| {
        for t in 0..threads {
            let (seeds, done, failures, total) = (&seeds, &done, &failures, &total);
            scope.spawn(move || {
                let mut tally = Tally::default();
                // Interleaved, so every thread gets the same mix whatever the count.
                for index in (first + t..first + count).step_by(threads as usize) {
                    CURRENT.with(|c| c.set(Some((seed, index))));
                    if let Err(why) = run_input(seed, index, seeds, &mut tally) {
                        let mut f = failures.lock().unwrap_or_else(|p| p.into_inner());
                        f.push((index, why));
                    }
                    let n = done.fetch_add(1, Ordering::Relaxed) + 1;
                    if n % 1_000_000 == 0 {
                        eprintln!("fuzz: {n} inputs, {:.0} s", started.elapsed().as_secs_f64());
                    }
                }
                let mut t = total.lock().unwrap_or_else(|p| p.into_inner());
                for k in 0..CLASSES.len() {
                    t.inputs[k] += tally.inputs[k];
                    t.accepted[k] += tally.accepted[k];
                }
                for (code, n) in tally.codes {
                    *t.codes.entry(code).or_default() += n;
                }
            });
        }
    });
    let elapsed = started.elapsed().as_secs_f64();
    let tally = total.into_inner().unwrap_or_else(|p| p.into_inner());
    let failures = failures.into_inner().unwrap_or_else(|p| p.into_inner());
    let n = count;
    println!(
        "fuzz: {n} inputs (seed {}) in {elapsed:.1} s on {} threads, {:.0} per second; corpus: {}",
        seed,
        threads,
        n as f64 / elapsed,
        seeds.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", ")
    );
    for (k, class) in CLASSES.iter().enumerate() {
        println!(
            "  {:<14} {:>10} inputs, {:>8} accepted by a loader",
            format!("{class:?}"),
            tally.inputs[k],
            tally.accepted[k]
        );
    }
    let codes: Vec<String> = tally.codes.iter().map(|(c, n)| format!("{c}: {n}")).collect();
    println!("  load codes seen ({}): {}", codes.len(), codes.join(", "));
    if failures.is_empty() {
        println!("fuzz: no crash, no altered blob accepted, C and Rust agree on every input");
        ExitCode::SUCCESS
    } else {
        for (index, why) in failures.iter().take(20) {
            eprintln!("fuzz: FAIL input {index} (--seed {} --replay {index}): {why}", seed);
        }
        eprintln!("fuzz: {} of {n} inputs failed", failures.len());
        ExitCode::FAILURE
    }
}
