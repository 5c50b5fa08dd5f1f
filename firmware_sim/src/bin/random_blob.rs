//! Writes a deterministic, seeded, untrained transfer actor (10-256-256-3, He-uniform) as an
//! f32 blob and an int8 blob, for the SIL and the Cortex-M4 image when no trained blob is given.
//!
//! `random_blob [--seed N] [--out DIR] [--rendezvous] [--spatial]` writes
//! `DIR/transfer-f32.blob` and `DIR/transfer-int8.blob` (defaults: seed 1, the current folder);
//! `--rendezvous` writes a 22-256-256-3 `DIR/rendezvous-f32.blob` and `DIR/rendezvous-int8.blob`
//! instead (flown by the rendezvous image and the C interface's rendezvous step, refused by the
//! transfer image). `--spatial` writes the three-dimensional actor of the problem instead,
//! 15-256-256-4 (`transfer3-*.blob`) or 30-256-256-4 (`rendezvous3-*.blob`). The blobs come from
//! `shared::quantize`, the exporter's own writer; the int8 activation scales are calibrated on
//! random feature vectors of flight-like magnitude (in three dimensions, onboard's own features
//! of random inclined states).

use std::path::PathBuf;
use std::process::ExitCode;

use onboard::guidance::{SpatialTargetFeatures, TargetOrbit3};
use onboard::spatial::SpatialCraftState;
use shared::blob::{Activation, FeatureLayout, ProblemKind};
use shared::orbit::{CartesianState, OrbitPlane, OrbitShape, SpatialState};
use shared::quantize::{DenseWeights, MlpWeights};

const TRANSFER: [usize; 4] = [10, 256, 256, 3];
const RENDEZVOUS: [usize; 4] = [22, 256, 256, 3];
const TRANSFER3: [usize; 4] = [15, 256, 256, 4];
const RENDEZVOUS3: [usize; 4] = [30, 256, 256, 4];
/// Feature vectors the int8 input scales are calibrated on.
const CALIBRATION_SAMPLES: usize = 512;

/// SplitMix64: small and seeded; the blobs depend on nothing else.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi).
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        let u = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        lo + (hi - lo) * u
    }
}

/// He-uniform weights (`±sqrt(6 / fan_in)`, for ReLU) and biases `±1 / sqrt(fan_in)` as
/// PyTorch's `nn.Linear` (non-zero, so the int8 bias rounding is exercised).
fn he_layer(inputs: usize, outputs: usize, activation: Activation, rng: &mut Rng) -> DenseWeights {
    let a = (6.0 / inputs as f64).sqrt();
    let c = 1.0 / (inputs as f64).sqrt();
    DenseWeights {
        inputs,
        outputs,
        weights: (0..inputs * outputs).map(|_| rng.uniform(-a, a) as f32).collect(),
        bias: (0..outputs).map(|_| rng.uniform(-c, c) as f32).collect(),
        activation,
    }
}

/// Radius, polar angle and polar velocity of a near-circular orbit point of 0.8-1.8 AU.
fn orbit_point(rng: &mut Rng) -> (f64, f64, f64, f64) {
    let r = rng.uniform(0.8, 1.8);
    let theta = rng.uniform(0.0, std::f64::consts::TAU);
    (r, theta, rng.uniform(-0.2, 0.2), rng.uniform(0.7, 1.2) / r.sqrt())
}

/// Features of flight-like magnitude (docs/spec.md sections 5 and 6), mass 0.6-1, time to go up
/// to 12 t*. Transfer: radius 0.8-1.8 AU, unit direction, velocities of near-circular orbits,
/// the target proxy likewise. Rendezvous: spacecraft and body on such orbits, their polar and
/// Cartesian states and differences.
fn feature_sample(rng: &mut Rng, inputs: usize) -> Vec<f32> {
    if inputs == RENDEZVOUS[0] {
        return rendezvous_sample(rng);
    }
    let theta = rng.uniform(0.0, std::f64::consts::TAU);
    let r = rng.uniform(0.8, 1.8);
    let r_t = rng.uniform(0.8, 1.8);
    [
        r,
        theta.cos(),
        theta.sin(),
        rng.uniform(-0.2, 0.2),
        rng.uniform(0.7, 1.2) / r.sqrt(),
        rng.uniform(0.6, 1.0),
        r_t,
        rng.uniform(-0.2, 0.2),
        rng.uniform(0.7, 1.2) / r_t.sqrt(),
        rng.uniform(0.0, 12.0),
    ]
    .map(|v| v as f32)
    .to_vec()
}

/// The Cartesian state of a polar orbit point (radius, polar angle, radial and polar velocity).
fn cartesian((r, theta, v_r, v_theta): (f64, f64, f64, f64)) -> CartesianState {
    let (c, s) = (theta.cos(), theta.sin());
    CartesianState {
        r: [r * c, r * s],
        v: [v_r * c - v_theta * s, v_r * s + v_theta * c],
    }
}

/// A near-circular orbit point of 0.8-1.8 AU in a random plane inclined up to 5 degrees.
fn spatial_point(rng: &mut Rng) -> SpatialState {
    let point = cartesian(orbit_point(rng));
    plane(rng).embed(&point)
}

fn plane(rng: &mut Rng) -> OrbitPlane {
    OrbitPlane {
        inclination: rng.uniform(0.0, 5f64.to_radians()),
        raan: rng.uniform(0.0, std::f64::consts::TAU),
    }
}

/// Onboard's three-dimensional features of a random inclined state, mass 0.6-1, time to go up
/// to 12 t*, against a random inclined target orbit (transfer) or body (rendezvous).
fn spatial_sample(rng: &mut Rng, layout: FeatureLayout) -> Result<Vec<f32>, String> {
    let state = SpatialCraftState {
        orbit: spatial_point(rng),
        m: rng.uniform(0.6, 1.0),
    };
    let time_to_go = rng.uniform(0.0, 12.0);
    let features = if layout == FeatureLayout::RendezvousSpatial30 {
        spatial_point(rng).features(&state, time_to_go).map(|f| f.to_vec())
    } else {
        let target = TargetOrbit3 {
            shape: OrbitShape {
                a: rng.uniform(0.8, 1.8),
                e: rng.uniform(0.0, 0.1),
                omega: rng.uniform(0.0, std::f64::consts::TAU),
            },
            plane: plane(rng),
        };
        target.features(&state, time_to_go).map(|f| f.to_vec())
    };
    let features = features.map_err(|e| format!("calibration features: {e}"))?;
    Ok(features.into_iter().map(|v| v as f32).collect())
}

fn rendezvous_sample(rng: &mut Rng) -> Vec<f32> {
    let (craft, body) = (orbit_point(rng), orbit_point(rng));
    let (
        CartesianState { r: [x, y], v: [vx, vy] },
        CartesianState {
            r: [xt, yt],
            v: [vxt, vyt],
        },
    ) = (cartesian(craft), cartesian(body));
    let (dx, dy, dvx, dvy) = (xt - x, yt - y, vxt - vx, vyt - vy);
    [
        craft.0,
        craft.1.cos(),
        craft.1.sin(),
        body.0,
        body.1.cos(),
        body.1.sin(),
        x,
        y,
        vx,
        vy,
        xt,
        yt,
        vxt,
        vyt,
        dx,
        dy,
        dvx,
        dvy,
        dx.hypot(dy),
        dvx.hypot(dvy),
        rng.uniform(0.0, 12.0),
        rng.uniform(0.6, 1.0),
    ]
    .map(|v| v as f32)
    .to_vec()
}

fn run() -> Result<(), String> {
    let (mut seed, mut out, mut kind, mut spatial) = (1u64, PathBuf::from("."), ProblemKind::Transfer, false);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--rendezvous" => kind = ProblemKind::Rendezvous,
            "--spatial" => spatial = true,
            "--seed" | "--out" => {
                let v = args.next().ok_or(format!("{a} needs a value"))?;
                if a == "--seed" {
                    seed = v.parse().map_err(|e| format!("--seed {v}: {e}"))?;
                } else {
                    out = PathBuf::from(v);
                }
            }
            _ => {
                return Err(format!(
                    "usage: random_blob [--seed N] [--out DIR] [--rendezvous] [--spatial] (got {a})"
                ))
            }
        }
    }
    let features = FeatureLayout::of(kind, spatial);
    let (sizes, name) = match features {
        FeatureLayout::TransferPolar10 => (TRANSFER, "transfer"),
        FeatureLayout::RendezvousPolar22 => (RENDEZVOUS, "rendezvous"),
        FeatureLayout::TransferSpatial15 => (TRANSFER3, "transfer3"),
        FeatureLayout::RendezvousSpatial30 => (RENDEZVOUS3, "rendezvous3"),
    };
    let mut rng = Rng(seed);
    let layers = sizes
        .windows(2)
        .enumerate()
        .map(|(l, s)| {
            let activation = if l + 2 == sizes.len() {
                Activation::Tanh
            } else {
                Activation::Relu
            };
            he_layer(s[0], s[1], activation, &mut rng)
        })
        .collect();
    let net = MlpWeights { features, layers };
    let calibration: Vec<Vec<f32>> = (0..CALIBRATION_SAMPLES)
        .map(|_| {
            if spatial {
                spatial_sample(&mut rng, features)
            } else {
                Ok(feature_sample(&mut rng, sizes[0]))
            }
        })
        .collect::<Result<_, _>>()?;

    let shape = sizes.map(|n| n.to_string()).join("-");
    let provenance = format!("random_blob seed {seed}: untrained He-uniform {shape}, for SIL tests");
    let (int8_blob, _) = net.int8_blob(&calibration, &provenance).map_err(|e| e.to_string())?;
    let f32_blob = net.f32_blob(&provenance).map_err(|e| e.to_string())?;
    let blobs = [
        (format!("{name}-f32.blob"), f32_blob),
        (format!("{name}-int8.blob"), int8_blob),
    ];

    std::fs::create_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    for (name, bytes) in &blobs {
        let path = out.join(name);
        std::fs::write(&path, bytes).map_err(|e| format!("{}: {e}", path.display()))?;
        println!("{} ({} bytes)", path.display(), bytes.len());
    }
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("random_blob: {e}");
            ExitCode::FAILURE
        }
    }
}
