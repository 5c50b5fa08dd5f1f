//! Writes a deterministic, seeded, untrained transfer actor (10-256-256-3, He-uniform) as an
//! f32 blob and an int8 blob, for the SIL and the Cortex-M4 image until trained blobs exist.
//!
//! `random_blob [--seed N] [--out DIR]` writes `DIR/transfer-f32.blob` and
//! `DIR/transfer-int8.blob` (defaults: seed 1, the current folder).
//!
//! The int8 blob is quantized as shared/src/blob.rs lays it out: per-output-channel symmetric
//! weights (`scale_j = max_i |w_ji| / 127`), each layer's input scale calibrated as
//! `max |activation| / 127` over random feature vectors of flight-like magnitude, biases in i32
//! units of `input_scale * scale_j`.

use std::path::PathBuf;
use std::process::ExitCode;

use shared::blob::{self, Activation, FeatureLayout, LayerBlob, NetworkBlob, ProblemKind, Quantization};

const SIZES: [usize; 4] = [10, 256, 256, 3];
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

/// A dense layer in PyTorch layout: `w[j][i]`, `b[j]`.
struct Layer {
    w: Vec<Vec<f32>>,
    b: Vec<f32>,
}

impl Layer {
    /// He-uniform weights (`±sqrt(6 / fan_in)`, for ReLU), biases `±1 / sqrt(fan_in)` as
    /// PyTorch's `nn.Linear` (non-zero, so the int8 bias rounding is exercised).
    fn he(n_in: usize, n_out: usize, rng: &mut Rng) -> Self {
        let a = (6.0 / n_in as f64).sqrt();
        let c = 1.0 / (n_in as f64).sqrt();
        Self {
            w: (0..n_out)
                .map(|_| (0..n_in).map(|_| rng.uniform(-a, a) as f32).collect())
                .collect(),
            b: (0..n_out).map(|_| rng.uniform(-c, c) as f32).collect(),
        }
    }

    fn inputs(&self) -> usize {
        self.w.first().map_or(0, Vec::len)
    }

    /// `b + W x` in f64.
    fn pre(&self, x: &[f64]) -> Vec<f64> {
        self.w
            .iter()
            .zip(&self.b)
            .map(|(row, &b)| f64::from(b) + row.iter().zip(x).map(|(&w, &xi)| f64::from(w) * xi).sum::<f64>())
            .collect()
    }
}

/// Every layer's input, evaluated in f64 (ReLU hidden layers).
fn layer_inputs(net: &[Layer], x: &[f64]) -> Vec<Vec<f64>> {
    let mut a = x.to_vec();
    let mut inputs = Vec::new();
    for layer in net {
        inputs.push(a.clone());
        a = layer.pre(&a).into_iter().map(|v| v.max(0.0)).collect();
    }
    inputs
}

/// Transfer features of flight-like magnitude (SPEC section 5): radius 0.8-1.8 AU, unit
/// direction, velocities of near-circular orbits, mass 0.6-1, time to go up to 12 t*.
fn feature_sample(rng: &mut Rng) -> Vec<f64> {
    let theta = rng.uniform(0.0, std::f64::consts::TAU);
    let r = rng.uniform(0.8, 1.8);
    let r_t = rng.uniform(0.8, 1.8);
    vec![
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
}

fn activation(l: usize) -> Activation {
    if l + 1 == SIZES.len() - 1 {
        Activation::Tanh
    } else {
        Activation::Relu
    }
}

/// Arrays of one blob layer.
struct Arrays {
    weights: Vec<u8>,
    bias: Vec<u8>,
    weight_scales: Vec<u8>,
    input_scale: f32,
}

/// f32: weights input-major (`w[i * outputs + j]`).
fn f32_arrays(layer: &Layer) -> Arrays {
    let mut w = Vec::with_capacity(layer.inputs() * layer.w.len());
    for i in 0..layer.inputs() {
        w.extend(layer.w.iter().map(|row| row[i]));
    }
    Arrays {
        weights: blob::f32_le_bytes(&w),
        bias: blob::f32_le_bytes(&layer.b),
        weight_scales: Vec::new(),
        input_scale: 1.0,
    }
}

/// `round(x / s)` half away from zero, clamped to ±127.
fn quant(x: f64, s: f64) -> i8 {
    (x / s).round().clamp(-127.0, 127.0) as i8
}

/// int8: weights output-major, per-channel symmetric scales, i32 bias.
fn int8_arrays(layer: &Layer, input_scale: f32) -> Arrays {
    let (mut q, mut scales, mut bias) = (Vec::new(), Vec::new(), Vec::new());
    for (row, &b) in layer.w.iter().zip(&layer.b) {
        let m = row.iter().fold(0.0f32, |m, w| m.max(w.abs()));
        let s = if m > 0.0 { m / 127.0 } else { 1.0 };
        q.extend(row.iter().map(|&w| quant(f64::from(w), f64::from(s))));
        scales.push(s);
        bias.push((f64::from(b) / (f64::from(input_scale) * f64::from(s))).round() as i32);
    }
    Arrays {
        weights: blob::i8_bytes(&q),
        bias: blob::i32_le_bytes(&bias),
        weight_scales: blob::f32_le_bytes(&scales),
        input_scale,
    }
}

fn encode(quantization: Quantization, arrays: &[Arrays], provenance: &str) -> Result<Vec<u8>, String> {
    let mut net = NetworkBlob {
        kind: ProblemKind::Transfer,
        features: FeatureLayout::TransferPolar10,
        quantization,
        provenance,
        // heapless is not a dependency here: the field's type names it.
        layers: Default::default(),
    };
    for (l, a) in arrays.iter().enumerate() {
        let layer = LayerBlob {
            inputs: SIZES[l] as u16,
            outputs: SIZES[l + 1] as u16,
            activation: activation(l),
            weights: &a.weights,
            bias: &a.bias,
            weight_scales: &a.weight_scales,
            input_scale: a.input_scale,
        };
        net.layers.push(layer).map_err(|_| "too many layers".to_string())?;
    }
    blob::encode_to_vec(&net).map_err(|e| e.to_string())
}

fn run() -> Result<(), String> {
    let (mut seed, mut out) = (1u64, PathBuf::from("."));
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match (a.as_str(), args.next()) {
            ("--seed", Some(v)) => seed = v.parse().map_err(|e| format!("--seed {v}: {e}"))?,
            ("--out", Some(v)) => out = PathBuf::from(v),
            _ => return Err(format!("usage: random_blob [--seed N] [--out DIR] (got {a})")),
        }
    }
    let mut rng = Rng(seed);
    let net: Vec<Layer> = SIZES.windows(2).map(|s| Layer::he(s[0], s[1], &mut rng)).collect();

    let mut max_abs = vec![0.0f64; net.len()];
    for _ in 0..CALIBRATION_SAMPLES {
        for (m, a) in max_abs.iter_mut().zip(layer_inputs(&net, &feature_sample(&mut rng))) {
            *m = a.iter().fold(*m, |acc, v| acc.max(v.abs()));
        }
    }
    let input_scales: Vec<f32> = max_abs
        .iter()
        .map(|&m| if m > 0.0 { (m / 127.0) as f32 } else { 1.0 })
        .collect();

    let provenance = format!("random_blob seed {seed}: untrained He-uniform 10-256-256-3, for SIL tests");
    let f32_blob = encode(
        Quantization::F32,
        &net.iter().map(f32_arrays).collect::<Vec<_>>(),
        &provenance,
    )?;
    let int8: Vec<Arrays> = net.iter().zip(&input_scales).map(|(l, &s)| int8_arrays(l, s)).collect();
    let int8_blob = encode(Quantization::Int8, &int8, &provenance)?;

    std::fs::create_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    for (name, bytes) in [("transfer-f32.blob", &f32_blob), ("transfer-int8.blob", &int8_blob)] {
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
