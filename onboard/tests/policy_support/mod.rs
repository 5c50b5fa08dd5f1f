//! Shared test support for the policy tests (and the inference bench): a seeded generator,
//! an independent f64 reference MLP in PyTorch layout (`w[out][in]`), blob builders for both
//! precisions, the test-side int8 quantizer and the analytic int8 error bound.
#![allow(dead_code)]

use shared::blob::{self, Activation, FeatureLayout, LayerBlob, NetworkBlob, ProblemKind, Quantization};

/// SplitMix64: small, seeded, good enough for weights and inputs.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [-a, a).
    pub fn sym(&mut self, a: f64) -> f32 {
        ((2.0 * self.unit() - 1.0) * a) as f32
    }
}

/// One dense layer in PyTorch layout: `w[j][i]`, `b[j]`.
#[derive(Clone, Debug)]
pub struct RefLayer {
    pub w: Vec<Vec<f32>>,
    pub b: Vec<f32>,
}

impl RefLayer {
    pub fn inputs(&self) -> usize {
        self.w.first().map_or(0, Vec::len)
    }

    pub fn outputs(&self) -> usize {
        self.w.len()
    }

    /// `b + W x` in f64.
    pub fn pre(&self, x: &[f64]) -> Vec<f64> {
        self.w
            .iter()
            .zip(&self.b)
            .map(|(row, &b)| {
                let mut s = f64::from(b);
                for (&w, &xi) in row.iter().zip(x) {
                    s += f64::from(w) * xi;
                }
                s
            })
            .collect()
    }
}

/// An MLP with ReLU hidden layers and a tanh output, evaluated in f64.
#[derive(Clone, Debug)]
pub struct RefNet {
    pub layers: Vec<RefLayer>,
}

impl RefNet {
    /// PyTorch's default `nn.Linear` init: uniform in `±1/sqrt(inputs)` for weights and bias,
    /// scaled by `gain` (a trained actor has larger weights than at init).
    pub fn random(sizes: &[usize], gain: f64, rng: &mut Rng) -> Self {
        let layers = sizes
            .windows(2)
            .map(|s| {
                let (n_in, n_out) = (s[0], s[1]);
                let a = gain / (n_in as f64).sqrt();
                RefLayer {
                    w: (0..n_out).map(|_| (0..n_in).map(|_| rng.sym(a)).collect()).collect(),
                    b: (0..n_out).map(|_| rng.sym(a)).collect(),
                }
            })
            .collect();
        Self { layers }
    }

    /// Every layer's input (the activations) and the final output, in f64.
    pub fn trace(&self, x: &[f32]) -> (Vec<Vec<f64>>, Vec<f64>) {
        let mut a: Vec<f64> = x.iter().map(|&v| f64::from(v)).collect();
        let mut inputs = Vec::new();
        let n = self.layers.len();
        for (l, layer) in self.layers.iter().enumerate() {
            inputs.push(a.clone());
            let z = layer.pre(&a);
            a = if l + 1 == n {
                z.iter().map(|v| v.tanh()).collect()
            } else {
                z.iter().map(|v| v.max(0.0)).collect()
            };
        }
        (inputs, a)
    }

    pub fn forward(&self, x: &[f32]) -> Vec<f64> {
        self.trace(x).1
    }

    pub fn sizes(&self) -> Vec<usize> {
        let mut s = vec![self.layers[0].inputs()];
        s.extend(self.layers.iter().map(RefLayer::outputs));
        s
    }
}

/// Inputs like the polar features: mostly O(1), some larger.
pub fn random_input(n: usize, rng: &mut Rng) -> Vec<f32> {
    (0..n)
        .map(|i| if i % 5 == 0 { rng.sym(3.0) } else { rng.sym(1.0) })
        .collect()
}

/// Owned arrays of one blob layer.
#[derive(Clone, Debug)]
pub struct OwnedLayer {
    pub inputs: u16,
    pub outputs: u16,
    pub activation: Activation,
    pub weights: Vec<u8>,
    pub bias: Vec<u8>,
    pub weight_scales: Vec<u8>,
    pub input_scale: f32,
}

impl OwnedLayer {
    pub fn view(&self) -> LayerBlob<'_> {
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

/// Owned content of a blob; `view()` borrows it as a [`NetworkBlob`].
#[derive(Clone, Debug)]
pub struct OwnedNet {
    pub kind: ProblemKind,
    pub features: FeatureLayout,
    pub quantization: Quantization,
    pub layers: Vec<OwnedLayer>,
}

impl OwnedNet {
    pub fn view(&self) -> NetworkBlob<'_> {
        let mut layers = heapless::Vec::new();
        for l in &self.layers {
            layers.push(l.view()).expect("at most MAX_LAYERS layers");
        }
        NetworkBlob {
            kind: self.kind,
            features: self.features,
            quantization: self.quantization,
            provenance: "policy tests",
            layers,
            mission: blob::BlobMission::THESIS,
        }
    }

    pub fn encode(&self) -> Vec<u8> {
        blob::encode_to_vec(&self.view()).expect("valid blob")
    }
}

/// The layout of `kind` whose network takes `inputs` (the three-dimensional one for 15 or 30
/// inputs, else the planar one).
pub fn features_for(kind: ProblemKind, inputs: usize) -> FeatureLayout {
    let spatial = FeatureLayout::of(kind, true);
    if inputs == spatial.len() {
        spatial
    } else {
        FeatureLayout::of(kind, false)
    }
}

fn activation(l: usize, n: usize) -> Activation {
    if l + 1 == n {
        Activation::Tanh
    } else {
        Activation::Relu
    }
}

/// f32 layer: weights LE in the blob's blocks of 8 outputs.
pub fn f32_layer(layer: &RefLayer, act: Activation) -> OwnedLayer {
    let (n_in, n_out) = (layer.inputs(), layer.outputs());
    let weights = shared::blob::f32_weight_bytes(&layer.w.concat(), n_in);
    OwnedLayer {
        inputs: n_in as u16,
        outputs: n_out as u16,
        activation: act,
        weights,
        bias: layer.b.iter().flat_map(|v| v.to_le_bytes()).collect(),
        weight_scales: Vec::new(),
        input_scale: 1.0,
    }
}

pub fn f32_net(net: &RefNet, kind: ProblemKind) -> OwnedNet {
    let n = net.layers.len();
    OwnedNet {
        kind,
        features: features_for(kind, net.layers.first().map_or(0, RefLayer::inputs)),
        quantization: Quantization::F32,
        layers: net
            .layers
            .iter()
            .enumerate()
            .map(|(l, layer)| f32_layer(layer, activation(l, n)))
            .collect(),
    }
}

/// The test's own int8 quantization of one layer.
#[derive(Clone, Debug)]
pub struct QuantLayer {
    /// `q[j][i]`.
    pub q: Vec<Vec<i8>>,
    pub weight_scales: Vec<f32>,
    pub bias: Vec<i32>,
    pub input_scale: f32,
}

/// `round(x / s)` half away from zero, clamped to [-127, 127], in f64 (weights).
pub fn quant_f64(x: f64, s: f64) -> i32 {
    (x / s).round().clamp(-127.0, 127.0) as i32
}

/// Activation levels of the int8 scheme (16-bit activations).
pub const LEVELS: f64 = shared::blob::ACTIVATION_LEVELS as f64;

/// `round(x / s)` half away from zero, clamped to [-LEVELS, LEVELS], in f64 (activations).
pub fn quant_act(x: f64, s: f64) -> i32 {
    (x / s).round().clamp(-LEVELS, LEVELS) as i32
}

/// Per-output-channel symmetric weight quantization (`scale_j = max_i |w_ji| / 127`), bias in
/// units of `input_scale * scale_j`.
pub fn quantize_layer(layer: &RefLayer, input_scale: f32) -> QuantLayer {
    let mut q = Vec::new();
    let mut weight_scales = Vec::new();
    let mut bias = Vec::new();
    for (row, &b) in layer.w.iter().zip(&layer.b) {
        let m = row.iter().fold(0.0f32, |m, w| m.max(w.abs()));
        let s = if m > 0.0 { m / 127.0 } else { 1.0 };
        q.push(
            row.iter()
                .map(|&w| quant_f64(f64::from(w), f64::from(s)) as i8)
                .collect(),
        );
        weight_scales.push(s);
        bias.push((f64::from(b) / (f64::from(input_scale) * f64::from(s))).round() as i32);
    }
    QuantLayer {
        q,
        weight_scales,
        bias,
        input_scale,
    }
}

/// Input scales calibrated as `max |activation| / LEVELS` of each layer's input over `calib`.
pub fn calibrate(net: &RefNet, calib: &[Vec<f32>]) -> Vec<f32> {
    let mut m = vec![0.0f64; net.layers.len()];
    for x in calib {
        let (inputs, _) = net.trace(x);
        for (ml, a) in m.iter_mut().zip(&inputs) {
            *ml = a.iter().fold(*ml, |acc, v| acc.max(v.abs()));
        }
    }
    m.iter()
        .map(|&v| if v > 0.0 { (v / LEVELS) as f32 } else { 1.0 })
        .collect()
}

/// Whether an int8 blob stores layer `l` of `n` in int8 (`Quantization::of_layer`).
pub fn is_int8(l: usize, n: usize) -> bool {
    Quantization::Int8.of_layer(l, n) == Quantization::Int8
}

/// The int8 layers of an int8 blob, in order: the hidden layers between the first and the last,
/// which the blob keeps in f32 (`Quantization::of_layer`). `input_scales` has one scale per
/// layer (those of the f32 layers unused).
pub fn quantize_net(net: &RefNet, input_scales: &[f32]) -> Vec<QuantLayer> {
    let n = net.layers.len();
    net.layers
        .iter()
        .zip(input_scales)
        .enumerate()
        .filter(|&(l, _)| is_int8(l, n))
        .map(|(_, (layer, &s))| quantize_layer(layer, s))
        .collect()
}

/// int8 layer: weights in the blob's row pairs, i32 bias, f32 scales.
pub fn int8_layer(q: &QuantLayer, act: Activation) -> OwnedLayer {
    OwnedLayer {
        inputs: q.q[0].len() as u16,
        outputs: q.q.len() as u16,
        activation: act,
        weights: shared::blob::int8_weight_bytes(&q.q.concat(), q.q[0].len()),
        bias: q.bias.iter().flat_map(|v| v.to_le_bytes()).collect(),
        weight_scales: q.weight_scales.iter().flat_map(|v| v.to_le_bytes()).collect(),
        input_scale: q.input_scale,
    }
}

/// The int8 blob of `net`: its first and last layers in f32, the int8 layers `quant` (from
/// [`quantize_net`]) between them.
pub fn int8_net(net: &RefNet, quant: &[QuantLayer], kind: ProblemKind) -> OwnedNet {
    let n = net.layers.len();
    let mut int8 = quant.iter();
    OwnedNet {
        kind,
        features: features_for(kind, net.layers.first().map_or(0, RefLayer::inputs)),
        quantization: Quantization::Int8,
        layers: net
            .layers
            .iter()
            .enumerate()
            .map(|(l, layer)| match is_int8(l, n).then(|| int8.next()).flatten() {
                Some(q) => int8_layer(q, activation(l, n)),
                None => f32_layer(layer, activation(l, n)),
            })
            .collect(),
    }
}

/// Worst-case error of quantizing (with scale `s`) a value of magnitude at most `m`: the value
/// itself if it rounds to 0, half a step, or the clipped excess beyond LEVELS steps.
fn quant_err(m: f64, s: f64) -> f64 {
    if m <= (LEVELS + 0.5) * s {
        m.min(s / 2.0)
    } else {
        m - LEVELS * s
    }
}

/// A rigorous per-output bound on `|int8 output - exact output|` for input `x`, derived from
/// the scales: at each layer the input error `d_i` (rounding `s/2`, or clipping) and the weight
/// rounding (`scale_j / 2` per weight) and bias rounding (`s * scale_j / 2`) propagate as
///
/// `e_j <= sum_i (scale_j/2) (|a_i| + d_i) + sum_i |w_ji| d_i + s scale_j / 2`,
///
/// with `a` the exact activations; ReLU and tanh are 1-Lipschitz (and flatter: a ReLU input
/// below `-e` gives exactly 0, tanh's slope is `sech^2`). A small relative slack
/// covers the f32 arithmetic of the dequantization.
pub fn int8_bound(net: &RefNet, quant: &[QuantLayer], x: &[f32]) -> Vec<f64> {
    let (inputs, _) = net.trace(x);
    let n = net.layers.len();
    // Error of the layer input against the exact activation: 0 for the network input.
    let mut prev_err: Vec<f64> = vec![0.0; x.len()];
    let mut int8 = quant.iter();
    let mut out = Vec::new();
    for (l, layer) in net.layers.iter().enumerate() {
        let a = &inputs[l];
        let z = layer.pre(a);
        let e: Vec<f64> = match is_int8(l, n).then(|| int8.next()).flatten() {
            Some(q) => {
                let s = f64::from(q.input_scale);
                // Quantized input error vs the exact activation.
                let d: Vec<f64> = a
                    .iter()
                    .zip(&prev_err)
                    .map(|(&ai, &ei)| ei + quant_err(ai.abs() + ei, s) + 1e-6 * (ai.abs() + ei))
                    .collect();
                layer
                    .w
                    .iter()
                    .zip(&q.weight_scales)
                    .zip(&z)
                    .map(|((row, &sj), &zj)| {
                        let sj = f64::from(sj);
                        // Bias rounding, then weight rounding on the (perturbed) input, then the
                        // input error through the exact weights.
                        let mut ej = s * sj / 2.0;
                        for ((&w, &ai), &di) in row.iter().zip(a).zip(&d) {
                            ej += sj / 2.0 * (ai.abs() + di) + f64::from(w).abs() * di;
                        }
                        // f32 arithmetic of the dequantization.
                        ej + 1e-5 * (zj.abs() + ej) + 1e-6
                    })
                    .collect()
            }
            None => layer
                .w
                .iter()
                .zip(&layer.b)
                .map(|(row, &b)| {
                    // An f32 layer: the input error through the exact weights, plus one rounding
                    // per fused multiply-add, each at most 2^-24 of a running sum bounded by the
                    // sum of magnitudes (with slack).
                    let mut through = 0.0;
                    let mut magnitude = f64::from(b).abs();
                    for ((&w, &ai), &ei) in row.iter().zip(a).zip(&prev_err) {
                        through += f64::from(w).abs() * ei;
                        magnitude += f64::from(w).abs() * (ai.abs() + ei);
                    }
                    through + magnitude * (row.len() + 1) as f64 * 2f64.powi(-23)
                })
                .collect(),
        };
        if l + 1 == n {
            // tanh is 1-Lipschitz, and flatter away from 0: its slope on [z - e, z + e] is at
            // most sech^2 of the point nearest 0. Outputs differ by at most 2 anyway.
            out = e
                .iter()
                .zip(&z)
                .map(|(&ej, &zj)| {
                    let c = (zj.abs() - ej).max(0.0);
                    (ej / c.cosh().powi(2) + 1e-6).min(2.0)
                })
                .collect();
        } else {
            // ReLU is 1-Lipschitz, and an output that is negative by more than its error
            // bound is 0 in both networks.
            prev_err = e
                .iter()
                .zip(&z)
                .map(|(&ej, &zj)| if zj >= 0.0 { ej } else { (zj + ej).max(0.0) })
                .collect();
        }
    }
    out
}

/// The int8 scheme emulated in f64 by the test (round half away from zero, clamp to ±LEVELS);
/// the f32 layers are exact here (f64), as the blob's f32 layers nearly are.
pub fn int8_emulate(net: &RefNet, quant: &[QuantLayer], x: &[f32]) -> Vec<f64> {
    let n = net.layers.len();
    let mut int8 = quant.iter();
    let mut a: Vec<f64> = x.iter().map(|&v| f64::from(v)).collect();
    for (l, layer) in net.layers.iter().enumerate() {
        let z: Vec<f64> = match is_int8(l, n).then(|| int8.next()).flatten() {
            Some(q) => {
                let s = f64::from(q.input_scale);
                let xq: Vec<i64> = a.iter().map(|&v| i64::from(quant_act(v, s))).collect();
                q.q.iter()
                    .zip(&q.bias)
                    .zip(&q.weight_scales)
                    .map(|((row, &b), &sj)| {
                        let acc: i64 =
                            i64::from(b) + row.iter().zip(&xq).map(|(&w, &xi)| i64::from(w) * xi).sum::<i64>();
                        acc as f64 * s * f64::from(sj)
                    })
                    .collect()
            }
            None => layer.pre(&a),
        };
        a = if l + 1 == n {
            z.iter().map(|v| v.tanh()).collect()
        } else {
            z.iter().map(|v| v.max(0.0)).collect()
        };
    }
    a
}
