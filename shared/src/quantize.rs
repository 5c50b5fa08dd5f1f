//! From trained weights to blobs (ground side, `std`): the f32 blob and the int8 blob with
//! per-output-channel symmetric weights and calibrated activation scales, in the layouts of
//! [`crate::blob`].
//!
//! The int8 scheme, as the onboard kernels read it:
//! - weight `w_ji` -> `q_ji`, integers in `[-127, 127]` times a per-output-channel scale `s_j`
//!   (symmetric, zero point 0), rounded one input after the other with each rounding error
//!   compensated on the inputs not yet rounded, through the calibration inputs' covariance
//!   (GPTQ, Frantar et al. 2022). Why: a trained first layer forms differences of nearly equal
//!   features (r_t - r) with weights of ~46; rounded independently, one step of such a weight
//!   swamps a small transfer's signal, while compensated the errors cancel along the shared part;
//! - a layer's input `x_i` -> `round(x_i / a)` clamped to `[-L, L]` (`L` =
//!   [`ACTIVATION_LEVELS`], 16-bit activations), with `a` the largest `|x_i|` over the
//!   calibration inputs divided by `L` (so no calibration input clips);
//! - bias `b_j` -> `round(b_j / (a s_j))` as i32, the accumulator's unit.

use std::vec::Vec;

use nalgebra::{DMatrix, DVector};

use crate::blob::{
    encode_to_vec, f32_le_bytes, f32_weight_bytes, i32_le_bytes, int8_weight_bytes, Activation, BlobError, BlobMission,
    FeatureLayout, LayerBlob, NetworkBlob, Quantization, ACTIVATION_LEVELS,
};

/// One dense layer as trained: PyTorch layout, `weights[j * inputs + i]` is `w_ji`.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseWeights {
    /// Input width.
    pub inputs: usize,
    /// Output width.
    pub outputs: usize,
    /// `outputs * inputs` weights, output-major (`weights[j * inputs + i]`).
    pub weights: Vec<f32>,
    /// `outputs` biases.
    pub bias: Vec<f32>,
    /// The non-linearity after the layer (ReLU hidden, tanh last).
    pub activation: Activation,
}

/// A trained actor mean network.
#[derive(Debug, Clone, PartialEq)]
pub struct MlpWeights {
    /// The network's input encoding (fixes its problem, inputs and action outputs).
    pub features: FeatureLayout,
    /// The dense layers, input to output.
    pub layers: Vec<DenseWeights>,
}

/// Why weights cannot become a blob.
#[derive(Debug, Clone, PartialEq)]
pub enum QuantizeError {
    /// An array length does not match the layer's shape.
    Shape {
        /// Index of the layer (from 0).
        layer: usize,
        /// Which array.
        what: &'static str,
    },
    /// A weight or bias is NaN or infinite.
    NonFinite {
        /// Index of the layer (from 0).
        layer: usize,
    },
    /// No calibration inputs, or one of the wrong length or not finite.
    Calibration(&'static str),
    /// The blob format refused the result (layer count, widths, chain).
    Blob(BlobError),
}

impl core::fmt::Display for QuantizeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Shape { layer, what } => write!(f, "layer {layer}: {what} has the wrong length"),
            Self::NonFinite { layer } => write!(f, "layer {layer}: non-finite weight or bias"),
            Self::Calibration(why) => write!(f, "int8 calibration: {why}"),
            Self::Blob(e) => write!(f, "{e}"),
        }
    }
}

impl core::error::Error for QuantizeError {}

/// The int8 quantization chosen for each layer, for reports.
#[derive(Debug, Clone, PartialEq)]
pub struct Int8Layer {
    /// Input scale `a` (the layer input's largest calibration magnitude / `ACTIVATION_LEVELS`).
    pub input_scale: f32,
    /// Per-output-channel weight scales `s_j`.
    pub weight_scales: Vec<f32>,
    /// The integer of each weight (its value is `q s`), `[out][in]`.
    pub weights: Vec<i8>,
    /// Bias in accumulator units.
    pub bias: Vec<i32>,
}

/// `round(x / s)` half away from zero, clamped to `[-127, 127]` (the onboard rounding).
fn quantize(x: f64, s: f64) -> i32 {
    (x / s).round().clamp(-127.0, 127.0) as i32
}

/// The scale that maps an activation of magnitude `m` to `ACTIVATION_LEVELS`, rounded up to
/// the next f32 if needed so it never clips; 1 for an input that is always 0.
fn activation_scale(m: f64) -> f32 {
    if m > 0.0 {
        let levels = f64::from(ACTIVATION_LEVELS);
        let a = (m / levels) as f32;
        if f64::from(a) * levels < m {
            a.next_up()
        } else {
            a
        }
    } else {
        1.0
    }
}

/// Candidate clipping of a row's scale: from the largest weight (no clipping) down to half.
const SCALE_FRACTIONS: [f32; 11] = [1.0, 0.95, 0.9, 0.85, 0.8, 0.75, 0.7, 0.65, 0.6, 0.55, 0.5];

/// Damping of the covariance before inversion, as a fraction of each input's own variance
/// (GPTQ damps by 1 % of the mean variance; per input keeps it scale-free: the features' variances
/// span 1e-2 (radius) to ~10 (time to go), and a mean-based damping would swamp the radius pair
/// whose cancellation matters). An input that never varies (a ReLU unit dead on every
/// calibration state) is damped by 1 so nothing divides by 0; its weight then carries no error.
const COVARIANCE_DAMPING: f64 = 0.01;

/// What [`quantize_row`] needs of a layer's calibration inputs: their covariance `C` (the bias
/// correction takes out the mean error, so `δwᵀ C δw` is the output error's variance) and the
/// upper Cholesky factor `U` of the damped inverse, `(C + λ)⁻¹ = Uᵀ U`.
struct InputStatistics {
    covariance: DMatrix<f64>,
    inverse_factor: DMatrix<f64>,
}

impl InputStatistics {
    fn new(covariance: DMatrix<f64>) -> Self {
        let n = covariance.nrows();
        let mut damped = covariance.clone();
        for i in 0..n {
            let variance = covariance[(i, i)];
            damped[(i, i)] += if variance > 0.0 {
                COVARIANCE_DAMPING * variance
            } else {
                1.0
            };
        }
        // Positive definite after damping, so both factorisations exist; the identity is the
        // fallback for a covariance too ill-conditioned to factor (plain rounding).
        let inverse_factor = damped
            .cholesky()
            .map(|c| c.inverse())
            .and_then(|inv| inv.cholesky())
            .map_or_else(|| DMatrix::identity(n, n), |c| c.l().transpose());
        Self {
            covariance,
            inverse_factor,
        }
    }
}

/// The integers of `row` at scale `s`: input by input, round, then spread the error over the
/// inputs not yet rounded so that the output error `δwᵀ C δw` stays small (GPTQ's update).
fn compensated_rounding(row: &[f32], s: f64, stats: &InputStatistics) -> Vec<i8> {
    let u = &stats.inverse_factor;
    let mut w: Vec<f64> = row.iter().map(|&v| f64::from(v)).collect();
    let mut q = Vec::with_capacity(row.len());
    for i in 0..w.len() {
        let qi = quantize(w[i], s);
        let error = (w[i] - f64::from(qi) * s) / u[(i, i)];
        for k in i + 1..w.len() {
            w[k] -= error * u[(i, k)];
        }
        q.push(qi as i8);
    }
    q
}

/// `δwᵀ C δw` of `row` quantized as `q` at scale `s`: the variance of the output error.
fn output_error(row: &[f32], q: &[i8], s: f64, covariance: &DMatrix<f64>) -> f64 {
    let d = DVector::from_iterator(
        row.len(),
        row.iter().zip(q).map(|(&w, &qi)| f64::from(qi) * s - f64::from(w)),
    );
    (d.transpose() * covariance * &d)[(0, 0)]
}

/// One output channel's symmetric int8 weights: among scales from the largest weight / 127 down
/// to half of it (clipping rare outliers), the one whose compensated rounding has the smallest
/// output error on the calibration inputs.
fn quantize_row(row: &[f32], stats: &InputStatistics) -> (f32, Vec<i8>) {
    let peak = row.iter().fold(0.0f32, |m, w| m.max(w.abs()));
    if peak == 0.0 {
        return (1.0, vec![0; row.len()]);
    }
    SCALE_FRACTIONS
        .iter()
        .map(|f| {
            let s = peak * f / 127.0;
            let q = compensated_rounding(row, f64::from(s), stats);
            let e = output_error(row, &q, f64::from(s), &stats.covariance);
            (s, q, e)
        })
        .fold(None, |best: Option<(f32, Vec<i8>, f64)>, c| match best {
            Some(b) if b.2 <= c.2 => Some(b),
            _ => Some(c),
        })
        .map(|(s, q, _)| (s, q))
        .expect("SCALE_FRACTIONS is not empty")
}

impl DenseWeights {
    /// `activation(W x + b)` in f64, the reference the blobs are measured against.
    pub fn forward(&self, x: &[f64]) -> Vec<f64> {
        self.weights
            .chunks_exact(self.inputs)
            .zip(&self.bias)
            .map(|(row, &b)| {
                let z = row.iter().zip(x).fold(f64::from(b), |s, (&w, &v)| s + f64::from(w) * v);
                match self.activation {
                    Activation::Relu => z.max(0.0),
                    Activation::Tanh => z.tanh(),
                }
            })
            .collect()
    }
}

impl MlpWeights {
    /// Checks every array against the layer shapes and that all values are finite.
    pub fn validate(&self) -> Result<(), QuantizeError> {
        for (layer, l) in self.layers.iter().enumerate() {
            if l.weights.len() != l.inputs * l.outputs {
                return Err(QuantizeError::Shape { layer, what: "weights" });
            }
            if l.bias.len() != l.outputs {
                return Err(QuantizeError::Shape { layer, what: "bias" });
            }
            if !l.weights.iter().chain(&l.bias).all(|v| v.is_finite()) {
                return Err(QuantizeError::NonFinite { layer });
            }
        }
        Ok(())
    }

    /// The network's output in f64 (the exact reference for both blobs).
    pub fn forward(&self, x: &[f32]) -> Vec<f64> {
        self.layers
            .iter()
            .fold(x.iter().map(|&v| f64::from(v)).collect(), |a, l| l.forward(&a))
    }

    /// The input of every layer for `x` (the calibration statistics).
    fn layer_inputs(&self, x: &[f32]) -> Vec<Vec<f64>> {
        let mut inputs = Vec::with_capacity(self.layers.len());
        let mut a: Vec<f64> = x.iter().map(|&v| f64::from(v)).collect();
        for l in &self.layers {
            let next = l.forward(&a);
            inputs.push(a);
            a = next;
        }
        inputs
    }

    fn encode(
        &self,
        quantization: Quantization,
        layers: &[OwnedArrays],
        provenance: &str,
        mission: BlobMission,
    ) -> Result<Vec<u8>, QuantizeError> {
        let mut views = heapless::Vec::new();
        for (l, a) in self.layers.iter().zip(layers) {
            let view = LayerBlob {
                inputs: width(l.inputs),
                outputs: width(l.outputs),
                activation: l.activation,
                padding: &[],
                weights: &a.weights,
                bias: &a.bias,
                weight_scales: &a.weight_scales,
                input_scale: a.input_scale,
            };
            views.push(view).map_err(|_| {
                QuantizeError::Blob(BlobError::TooManyLayers {
                    found: self.layers.len(),
                    max: crate::blob::MAX_LAYERS,
                })
            })?;
        }
        let net = NetworkBlob {
            kind: self.features.problem(),
            features: self.features,
            quantization,
            provenance,
            layers: views,
            mission,
        };
        encode_to_vec(&net).map_err(QuantizeError::Blob)
    }

    /// The f32 blob of a network of the thesis's mission ([`BlobMission::THESIS`]).
    pub fn f32_blob(&self, provenance: &str) -> Result<Vec<u8>, QuantizeError> {
        self.f32_blob_for(provenance, BlobMission::THESIS)
    }

    /// The f32 blob: weights in the blocks of 8 outputs the f32 kernel streams
    /// ([`crate::blob::f32_weight_index`]), flying `mission`.
    pub fn f32_blob_for(&self, provenance: &str, mission: BlobMission) -> Result<Vec<u8>, QuantizeError> {
        self.validate()?;
        let arrays: Vec<OwnedArrays> = self.layers.iter().map(f32_arrays).collect();
        self.encode(Quantization::F32, &arrays, provenance, mission)
    }

    /// The int8 quantization of the layers an `Int8` blob stores in int8 (the hidden layers
    /// between the first and the last, [`Quantization::of_layer`]), activation scales calibrated
    /// on `calibration` (network inputs: demonstration and evaluation states), in order.
    pub fn quantize_int8(&self, calibration: &[Vec<f32>]) -> Result<Vec<Int8Layer>, QuantizeError> {
        self.validate()?;
        let n_in = self.layers.first().map_or(0, |l| l.inputs);
        if calibration.is_empty() {
            return Err(QuantizeError::Calibration("no calibration inputs"));
        }
        if calibration
            .iter()
            .any(|x| x.len() != n_in || !x.iter().all(|v| v.is_finite()))
        {
            return Err(QuantizeError::Calibration(
                "an input has the wrong length or is not finite",
            ));
        }
        // Per layer input: the largest magnitude (input scale) and the covariance (which
        // weight errors matter, and how they can cancel), over the calibration inputs through
        // the exact network.
        let mut largest = vec![0.0f64; self.layers.len()];
        let mut sums: Vec<DVector<f64>> = self.layers.iter().map(|l| DVector::zeros(l.inputs)).collect();
        let mut products: Vec<DMatrix<f64>> = self.layers.iter().map(|l| DMatrix::zeros(l.inputs, l.inputs)).collect();
        for x in calibration {
            for (((m, sum), product), a) in largest
                .iter_mut()
                .zip(&mut sums)
                .zip(&mut products)
                .zip(self.layer_inputs(x))
            {
                *m = a.iter().fold(*m, |m, v| m.max(v.abs()));
                let a = DVector::from_vec(a);
                *sum += &a;
                product.ger(1.0, &a, &a, 1.0);
            }
        }
        let count = calibration.len() as f64;
        let statistics: Vec<InputStatistics> = sums
            .into_iter()
            .zip(products)
            .map(|(sum, product)| {
                let mean = sum / count;
                InputStatistics::new(product / count - &mean * mean.transpose())
            })
            .collect();
        // The calibration inputs as the quantized network sees them, layer after layer.
        let mut flowing: Vec<Vec<f64>> = calibration
            .iter()
            .map(|x| x.iter().map(|&v| f64::from(v)).collect())
            .collect();
        let mut layers = Vec::with_capacity(self.layers.len());
        let count = self.layers.len();
        for (index, ((l, m), stats)) in self.layers.iter().zip(largest).zip(&statistics).enumerate() {
            if Quantization::Int8.of_layer(index, count) == Quantization::F32 {
                // A layer the blob keeps in f32: its outputs as the network computes them.
                flowing = flowing.iter().map(|x| l.forward(x)).collect();
                continue;
            }
            let input_scale = activation_scale(m);
            let a = f64::from(input_scale);
            let levels = f64::from(ACTIVATION_LEVELS);
            let quantized_inputs: Vec<Vec<f64>> = flowing
                .iter()
                .map(|x| x.iter().map(|v| (v / a).round().clamp(-levels, levels)).collect())
                .collect();
            let mut q = Int8Layer {
                input_scale,
                weight_scales: Vec::with_capacity(l.outputs),
                weights: Vec::with_capacity(l.weights.len()),
                bias: Vec::with_capacity(l.outputs),
            };
            for (row, &b) in l.weights.chunks_exact(l.inputs).zip(&l.bias) {
                let (s, q_row) = quantize_row(row, stats);
                // Bias correction: the rounding of the weights shifts each output by
                // sum_i (q_i s - w_i) x_i; its mean over the calibration inputs (as quantized
                // there) is taken out of the bias, so the quantized layer is unbiased.
                let shift = quantized_inputs
                    .iter()
                    .map(|xq| {
                        row.iter()
                            .zip(&q_row)
                            .zip(xq)
                            .map(|((&w, &qw), &x)| (f64::from(qw) * f64::from(s) - f64::from(w)) * x * a)
                            .sum::<f64>()
                    })
                    .sum::<f64>()
                    / calibration.len() as f64;
                let unit = a * f64::from(s);
                q.bias.push(
                    ((f64::from(b) - shift) / unit)
                        .round()
                        .clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32,
                );
                q.weight_scales.push(s);
                q.weights.extend(q_row);
            }
            // The next layer's inputs: this layer's output as the onboard kernel computes it.
            flowing = quantized_inputs
                .iter()
                .map(|xq| {
                    (0..l.outputs)
                        .map(|j| {
                            let acc = q.weights[j * l.inputs..(j + 1) * l.inputs]
                                .iter()
                                .zip(xq)
                                .map(|(&w, &x)| f64::from(w) * x)
                                .sum::<f64>()
                                + f64::from(q.bias[j]);
                            let z = acc * a * f64::from(q.weight_scales[j]);
                            match l.activation {
                                Activation::Relu => z.max(0.0),
                                Activation::Tanh => z.tanh(),
                            }
                        })
                        .collect()
                })
                .collect();
            layers.push(q);
        }
        Ok(layers)
    }

    /// The int8 blob (see [`Self::quantize_int8`]) and the quantization it holds.
    pub fn int8_blob(
        &self,
        calibration: &[Vec<f32>],
        provenance: &str,
    ) -> Result<(Vec<u8>, Vec<Int8Layer>), QuantizeError> {
        self.int8_blob_for(calibration, provenance, BlobMission::THESIS)
    }

    /// [`Self::int8_blob`] of a network flying `mission`.
    pub fn int8_blob_for(
        &self,
        calibration: &[Vec<f32>],
        provenance: &str,
        mission: BlobMission,
    ) -> Result<(Vec<u8>, Vec<Int8Layer>), QuantizeError> {
        let quant = self.quantize_int8(calibration)?;
        let mut int8 = quant.iter();
        let count = self.layers.len();
        let arrays: Vec<OwnedArrays> = self
            .layers
            .iter()
            .enumerate()
            .map(|(index, l)| {
                let stored = Quantization::Int8.of_layer(index, count);
                match (stored == Quantization::Int8).then(|| int8.next()).flatten() {
                    Some(q) => OwnedArrays {
                        weights: int8_weight_bytes(&q.weights, l.inputs),
                        bias: i32_le_bytes(&q.bias),
                        weight_scales: f32_le_bytes(&q.weight_scales),
                        input_scale: q.input_scale,
                    },
                    None => f32_arrays(l),
                }
            })
            .collect();
        let blob = self.encode(Quantization::Int8, &arrays, provenance, mission)?;
        Ok((blob, quant))
    }
}

struct OwnedArrays {
    weights: Vec<u8>,
    bias: Vec<u8>,
    weight_scales: Vec<u8>,
    input_scale: f32,
}

/// A layer's f32 arrays: the weights in the blocks the f32 kernel streams, the bias as is.
fn f32_arrays(l: &DenseWeights) -> OwnedArrays {
    OwnedArrays {
        weights: f32_weight_bytes(&l.weights, l.inputs),
        bias: f32_le_bytes(&l.bias),
        weight_scales: Vec::new(),
        input_scale: 1.0,
    }
}

/// A width as the format stores it; one too large saturates and the format's own width check
/// refuses it with its typed error.
fn width(n: usize) -> u16 {
    u16::try_from(n).unwrap_or(u16::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::blob::{decode, f32s};

    fn tiny() -> MlpWeights {
        let layer = |inputs: usize, outputs: usize, activation, seed: f32| DenseWeights {
            inputs,
            outputs,
            weights: (0..inputs * outputs)
                .map(|k| ((k as f32 + seed) * 0.37).sin())
                .collect(),
            bias: (0..outputs).map(|k| ((k as f32 - seed) * 0.11).cos() * 0.1).collect(),
            activation,
        };
        MlpWeights {
            features: FeatureLayout::TransferPolar10,
            layers: vec![
                layer(10, 6, Activation::Relu, 1.0),
                layer(6, 5, Activation::Relu, 2.0),
                layer(5, 3, Activation::Tanh, 3.0),
            ],
        }
    }

    #[test]
    fn the_f32_blob_holds_the_weights_in_blocks_and_the_bias_as_is() {
        let net = tiny();
        let bytes = net.f32_blob("test").unwrap();
        let blob = decode(&bytes).unwrap();
        assert_eq!(blob.quantization, Quantization::F32);
        assert_eq!(blob.provenance, "test");
        for (l, b) in net.layers.iter().zip(&blob.layers) {
            let w: Vec<f32> = f32s(b.weights).collect();
            for j in 0..l.outputs {
                for i in 0..l.inputs {
                    let k = crate::blob::f32_weight_index(l.inputs, l.outputs, j, i);
                    assert_eq!(w[k], l.weights[j * l.inputs + i]);
                }
            }
            assert_eq!(f32s(b.bias).collect::<Vec<_>>(), l.bias);
        }
    }

    #[test]
    fn the_int8_blob_holds_the_quantized_weights_in_row_pairs() {
        let net = tiny();
        let calib: Vec<Vec<f32>> = (0..20)
            .map(|k| (0..10).map(|i| ((k * 10 + i) as f32 * 0.3).cos()).collect())
            .collect();
        let (bytes, quant) = net.int8_blob(&calib, "test").unwrap();
        let blob = decode(&bytes).unwrap();
        let (l, b, q) = (&net.layers[1], &blob.layers[1], &quant[0]);
        assert_eq!(b.weights.len(), l.inputs * l.outputs);
        // Odd outputs (5): two pairs and a plain last row.
        assert_eq!(l.outputs % 2, 1);
        for j in 0..l.outputs {
            for i in 0..l.inputs {
                let stored = crate::blob::int8_weight_at(b.weights, l.inputs, l.outputs, j, i);
                assert_eq!(stored, Some(q.weights[j * l.inputs + i]), "({j}, {i})");
            }
        }
    }

    #[test]
    fn int8_scales_bound_the_rounding_and_calibration_never_clips() {
        let net = tiny();
        let calib: Vec<Vec<f32>> = (0..50)
            .map(|k| (0..10).map(|i| ((k * 10 + i) as f32 * 0.7).sin() * 2.0).collect())
            .collect();
        let quant = net.quantize_int8(&calib).unwrap();
        assert_eq!(quant.len(), net.layers.len() - 2, "the first and last layers stay f32");
        for (l, q) in net.layers[1..].iter().zip(&quant) {
            for j in 0..l.outputs {
                let s = q.weight_scales[j];
                let row = &l.weights[j * l.inputs..(j + 1) * l.inputs];
                let peak = row.iter().fold(0.0f32, |m, w| m.max(w.abs()));
                // The scale lies between half and all of the largest weight / 127.
                assert!(s <= peak / 127.0 * 1.0001 && s >= peak / 127.0 * 0.4999, "{s} {peak}");
            }
        }
        // Bias correction: on the calibration inputs (layer 1 sees the f32 first layer's
        // outputs, exact here), the quantized layer's mean pre-activation equals the exact
        // weights' on the same quantized inputs, to the bias's rounding (half a unit).
        let (l, q) = (&net.layers[1], &quant[0]);
        let a = f64::from(q.input_scale);
        let hidden: Vec<Vec<f64>> = calib.iter().map(|x| net.layer_inputs(x).swap_remove(1)).collect();
        for j in 0..l.outputs {
            let unit = a * f64::from(q.weight_scales[j]);
            let (mut quantized, mut exact) = (0.0, 0.0);
            for x in &hidden {
                for (i, &v) in x.iter().enumerate() {
                    let xq = (v / a).round() * a;
                    quantized += f64::from(q.weights[j * l.inputs + i]) * f64::from(q.weight_scales[j]) * xq;
                    exact += f64::from(l.weights[j * l.inputs + i]) * xq;
                }
            }
            let n = calib.len() as f64;
            let mean_q = quantized / n + f64::from(q.bias[j]) * unit;
            let mean_exact = exact / n + f64::from(l.bias[j]);
            assert!(
                (mean_q - mean_exact).abs() <= unit / 2.0 * 1.001 + 1e-12,
                "{mean_q} {mean_exact}"
            );
        }
        // Every calibration input of every layer fits in ACTIVATION_LEVELS steps of its scale.
        for x in &calib {
            for (a, q) in net.layer_inputs(x)[1..].iter().zip(&quant) {
                assert!(a
                    .iter()
                    .all(|v| v.abs() / f64::from(q.input_scale) <= f64::from(ACTIVATION_LEVELS)));
            }
        }
    }

    /// Output errors of a one-row layer quantized as `q` at scale `s` over `inputs`, with the
    /// mean taken out (the bias correction's share): (rms error).
    fn rms_centred_error(row: &[f32], q: &[i8], s: f32, inputs: &[Vec<f32>]) -> f64 {
        let errors: Vec<f64> = inputs
            .iter()
            .map(|x| {
                row.iter()
                    .zip(q)
                    .zip(x)
                    .map(|((&w, &qi), &v)| (f64::from(qi) * f64::from(s) - f64::from(w)) * f64::from(v))
                    .sum()
            })
            .collect();
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt()
    }

    #[test]
    fn compensated_rounding_keeps_the_difference_of_nearly_equal_inputs() {
        // The trained first layer's case: output = w (r_t - r) + a small term, with r in
        // [1, 1.52], r_t - r a few thousandths of an AU and |w| ~ 46; the row's largest weight
        // (on an input that barely varies) sets the step, 52 / 127, and both rounding errors
        // of the pair have the same sign, so they add.
        let row: Vec<f32> = vec![-45.63, 45.70, 52.0];
        let inputs: Vec<Vec<f32>> = (0..400)
            .map(|k| {
                let r = 1.0 + 0.52 * ((k as f32 * 0.618_034).fract());
                let gap = 0.004 * ((k as f32 * 1.7).sin());
                vec![r, r + gap, 0.02 + 0.01 * (k as f32 * 0.3).cos()]
            })
            .collect();
        // An f32 identity first layer (the inputs are positive, so its ReLU keeps them), the
        // row under test as the int8 hidden layer, and an f32 output layer.
        let net = MlpWeights {
            features: FeatureLayout::TransferPolar10,
            layers: vec![
                DenseWeights {
                    inputs: 3,
                    outputs: 3,
                    weights: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                    bias: vec![0.0; 3],
                    activation: Activation::Relu,
                },
                DenseWeights {
                    inputs: 3,
                    outputs: 1,
                    weights: row.clone(),
                    bias: vec![0.1],
                    activation: Activation::Relu,
                },
                DenseWeights {
                    inputs: 1,
                    outputs: 1,
                    weights: vec![1.0],
                    bias: vec![0.0],
                    activation: Activation::Tanh,
                },
            ],
        };
        let q = &net.quantize_int8(&inputs).unwrap()[0];
        let s = q.weight_scales[0];
        // The signal: the output's spread from the difference term alone.
        let signal = rms_centred_error(&[-45.7, 45.7, 0.0], &[0; 3], 1.0, &inputs);
        let compensated = rms_centred_error(&row, &q.weights, s, &inputs);
        // Independent reference: each weight rounded to its nearest step at the same scale.
        let nearest: Vec<i8> = row
            .iter()
            .map(|&w| (w / s).round().clamp(-127.0, 127.0) as i8)
            .collect();
        let plain = rms_centred_error(&row, &nearest, s, &inputs);
        assert!(
            plain > 0.15 * signal,
            "the case must be hard for plain rounding: {plain} vs {signal}"
        );
        // Compensated, what is left is the pair's sum (0.07) against the step (0.41): the best
        // integers give |0.07| std(r) ~ 0.01.
        assert!(
            compensated < 0.1 * signal && compensated < 0.3 * plain,
            "compensated {compensated}, plain {plain}, signal {signal}"
        );
    }

    #[test]
    fn bad_weights_and_calibrations_are_refused() {
        let mut net = tiny();
        assert_eq!(
            net.quantize_int8(&[]).unwrap_err(),
            QuantizeError::Calibration("no calibration inputs")
        );
        assert!(matches!(
            net.quantize_int8(&[vec![0.0; 9]]),
            Err(QuantizeError::Calibration(_))
        ));
        net.layers[1].bias.pop();
        assert_eq!(
            net.f32_blob("x").unwrap_err(),
            QuantizeError::Shape { layer: 1, what: "bias" }
        );
        let mut net = tiny();
        net.layers[2].weights[0] = f32::NAN;
        assert_eq!(net.f32_blob("x").unwrap_err(), QuantizeError::NonFinite { layer: 2 });
    }
}
