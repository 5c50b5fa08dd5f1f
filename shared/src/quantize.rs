//! From trained weights to blobs (ground side, `std`): the f32 blob and the int8 blob with
//! per-output-channel symmetric weights and calibrated activation scales, in the layouts of
//! [`crate::blob`].
//!
//! The int8 scheme, as the onboard kernels read it:
//! - weight `w_ji` -> `q_ji = round(w_ji / s_j)` with `s_j = max_i |w_ji| / 127` (per output
//!   channel, symmetric, zero point 0);
//! - a layer's input `x_i` -> `round(x_i / a)` clamped to `[-L, L]` (`L` =
//!   [`ACTIVATION_LEVELS`], 16-bit activations), with `a` the largest `|x_i|` over the
//!   calibration inputs divided by `L` (so no calibration input clips);
//! - bias `b_j` -> `round(b_j / (a s_j))` as i32, the accumulator's unit.

use std::vec::Vec;

use crate::blob::{
    encode_to_vec, f32_le_bytes, i32_le_bytes, i8_bytes, Activation, BlobError, FeatureLayout, LayerBlob, NetworkBlob,
    ProblemKind, Quantization, ACTIVATION_LEVELS,
};

/// One dense layer as trained: PyTorch layout, `weights[j * inputs + i]` is `w_ji`.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseWeights {
    pub inputs: usize,
    pub outputs: usize,
    pub weights: Vec<f32>,
    pub bias: Vec<f32>,
    pub activation: Activation,
}

/// A trained actor mean network.
#[derive(Debug, Clone, PartialEq)]
pub struct MlpWeights {
    pub kind: ProblemKind,
    pub layers: Vec<DenseWeights>,
}

/// Why weights cannot become a blob.
#[derive(Debug, Clone, PartialEq)]
pub enum QuantizeError {
    /// An array length does not match the layer's shape.
    Shape { layer: usize, what: &'static str },
    /// A weight or bias is NaN or infinite.
    NonFinite { layer: usize },
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

impl std::error::Error for QuantizeError {}

/// The int8 quantization chosen for each layer, for reports.
#[derive(Debug, Clone, PartialEq)]
pub struct Int8Layer {
    /// Input scale `a` (the layer input's largest calibration magnitude / `ACTIVATION_LEVELS`).
    pub input_scale: f32,
    /// Per-output-channel weight scales `s_j`.
    pub weight_scales: Vec<f32>,
    /// `round(w / s)` per weight, `[out][in]`.
    pub weights: Vec<i8>,
    /// Bias in accumulator units.
    pub bias: Vec<i32>,
}

fn features_of(kind: ProblemKind) -> FeatureLayout {
    match kind {
        ProblemKind::Transfer => FeatureLayout::TransferPolar10,
        ProblemKind::Rendezvous => FeatureLayout::RendezvousPolar22,
    }
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

/// One output channel's symmetric int8 weights: the scale (the largest weight / 127, or a
/// clipped one) that minimises the expected output error `sum_i E[x_i^2] (w_i - s q_i)^2`,
/// so weights that meet large inputs are kept precise at the cost of clipping rare outliers.
fn quantize_row(row: &[f32], input_mean_square: &[f64]) -> (f32, Vec<i8>) {
    let peak = row.iter().fold(0.0f32, |m, w| m.max(w.abs()));
    if peak == 0.0 {
        return (1.0, vec![0; row.len()]);
    }
    let error = |s: f32| -> f64 {
        row.iter()
            .zip(input_mean_square)
            .map(|(&w, &ms)| {
                let d = f64::from(quantize(f64::from(w), f64::from(s))) * f64::from(s) - f64::from(w);
                ms * d * d
            })
            .sum()
    };
    let best = SCALE_FRACTIONS
        .iter()
        .map(|f| peak * f / 127.0)
        .fold((peak / 127.0, f64::INFINITY), |(bs, be), s| {
            let e = error(s);
            if e < be {
                (s, e)
            } else {
                (bs, be)
            }
        })
        .0;
    (
        best,
        row.iter()
            .map(|&w| quantize(f64::from(w), f64::from(best)) as i8)
            .collect(),
    )
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
    ) -> Result<Vec<u8>, QuantizeError> {
        let mut views = heapless::Vec::new();
        for (l, a) in self.layers.iter().zip(layers) {
            let view = LayerBlob {
                inputs: width(l.inputs),
                outputs: width(l.outputs),
                activation: l.activation,
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
            kind: self.kind,
            features: features_of(self.kind),
            quantization,
            provenance,
            layers: views,
        };
        encode_to_vec(&net).map_err(QuantizeError::Blob)
    }

    /// The f32 blob: weights transposed to the input-major layout the f32 kernel streams.
    pub fn f32_blob(&self, provenance: &str) -> Result<Vec<u8>, QuantizeError> {
        self.validate()?;
        let arrays: Vec<OwnedArrays> = self
            .layers
            .iter()
            .map(|l| {
                let mut transposed = Vec::with_capacity(l.weights.len());
                for i in 0..l.inputs {
                    transposed.extend((0..l.outputs).map(|j| l.weights[j * l.inputs + i]));
                }
                OwnedArrays {
                    weights: f32_le_bytes(&transposed),
                    bias: f32_le_bytes(&l.bias),
                    weight_scales: Vec::new(),
                    input_scale: 1.0,
                }
            })
            .collect();
        self.encode(Quantization::F32, &arrays, provenance)
    }

    /// The int8 quantization of every layer, activation scales calibrated on `calibration`
    /// (network inputs: demonstration and evaluation states).
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
        // Per layer input: the largest magnitude (input scale) and each component's mean
        // square (which weights matter), over the calibration inputs through the exact network.
        let mut largest = vec![0.0f64; self.layers.len()];
        let mut mean_square: Vec<Vec<f64>> = self.layers.iter().map(|l| vec![0.0; l.inputs]).collect();
        for x in calibration {
            for ((m, ms), a) in largest.iter_mut().zip(&mut mean_square).zip(self.layer_inputs(x)) {
                *m = a.iter().fold(*m, |m, v| m.max(v.abs()));
                for (s, v) in ms.iter_mut().zip(&a) {
                    *s += v * v / calibration.len() as f64;
                }
            }
        }
        // The calibration inputs as the quantized network sees them, layer after layer.
        let mut flowing: Vec<Vec<f64>> = calibration
            .iter()
            .map(|x| x.iter().map(|&v| f64::from(v)).collect())
            .collect();
        let mut layers = Vec::with_capacity(self.layers.len());
        for ((l, m), ms) in self.layers.iter().zip(largest).zip(&mean_square) {
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
                let (s, q_row) = quantize_row(row, ms);
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
        let quant = self.quantize_int8(calibration)?;
        let arrays: Vec<OwnedArrays> = quant
            .iter()
            .map(|q| OwnedArrays {
                weights: i8_bytes(&q.weights),
                bias: i32_le_bytes(&q.bias),
                weight_scales: f32_le_bytes(&q.weight_scales),
                input_scale: q.input_scale,
            })
            .collect();
        let blob = self.encode(Quantization::Int8, &arrays, provenance)?;
        Ok((blob, quant))
    }
}

struct OwnedArrays {
    weights: Vec<u8>,
    bias: Vec<u8>,
    weight_scales: Vec<u8>,
    input_scale: f32,
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
            kind: ProblemKind::Transfer,
            layers: vec![
                layer(10, 6, Activation::Relu, 1.0),
                layer(6, 5, Activation::Relu, 2.0),
                layer(5, 3, Activation::Tanh, 3.0),
            ],
        }
    }

    #[test]
    fn the_f32_blob_holds_the_weights_transposed_and_the_bias_as_is() {
        let net = tiny();
        let bytes = net.f32_blob("test").unwrap();
        let blob = decode(&bytes).unwrap();
        assert_eq!(blob.quantization, Quantization::F32);
        assert_eq!(blob.provenance, "test");
        for (l, b) in net.layers.iter().zip(&blob.layers) {
            let w: Vec<f32> = f32s(b.weights).collect();
            for j in 0..l.outputs {
                for i in 0..l.inputs {
                    assert_eq!(w[i * l.outputs + j], l.weights[j * l.inputs + i]);
                }
            }
            assert_eq!(f32s(b.bias).collect::<Vec<_>>(), l.bias);
        }
    }

    #[test]
    fn int8_scales_bound_the_rounding_and_calibration_never_clips() {
        let net = tiny();
        let calib: Vec<Vec<f32>> = (0..50)
            .map(|k| (0..10).map(|i| ((k * 10 + i) as f32 * 0.7).sin() * 2.0).collect())
            .collect();
        let quant = net.quantize_int8(&calib).unwrap();
        for (l, q) in net.layers.iter().zip(&quant) {
            for j in 0..l.outputs {
                let s = q.weight_scales[j];
                let row = &l.weights[j * l.inputs..(j + 1) * l.inputs];
                let peak = row.iter().fold(0.0f32, |m, w| m.max(w.abs()));
                // The scale lies between half and all of the largest weight / 127; every weight
                // is within s/2 of its value, or clipped to +-127 steps.
                assert!(s <= peak / 127.0 * 1.0001 && s >= peak / 127.0 * 0.4999, "{s} {peak}");
                for (i, &w) in row.iter().enumerate() {
                    let qw = q.weights[j * l.inputs + i];
                    let back = f32::from(qw) * s;
                    assert!((back - w).abs() <= s / 2.0 * 1.0001 || (qw.unsigned_abs() == 127 && w.abs() > back.abs()));
                }
            }
        }
        // Bias correction: on the calibration inputs (layer 0 sees them as they are), the
        // quantized layer's mean pre-activation equals the exact weights' on the same
        // quantized inputs, to the bias's rounding (half a unit).
        let (l, q) = (&net.layers[0], &quant[0]);
        let a = f64::from(q.input_scale);
        for j in 0..l.outputs {
            let unit = a * f64::from(q.weight_scales[j]);
            let (mut quantized, mut exact) = (0.0, 0.0);
            for x in &calib {
                for (i, &v) in x.iter().enumerate() {
                    let xq = (f64::from(v) / a).round() * a;
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
            for (a, q) in net.layer_inputs(x).iter().zip(&quant) {
                assert!(a
                    .iter()
                    .all(|v| v.abs() / f64::from(q.input_scale) <= f64::from(ACTIVATION_LEVELS)));
            }
        }
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
