//! From trained weights to blobs (ground side, `std`): the f32 blob and the int8 blob with
//! per-output-channel symmetric weights and calibrated activation scales, in the layouts of
//! [`crate::blob`].
//!
//! The int8 scheme, as the onboard kernels read it:
//! - weight `w_ji` -> `q_ji = round(w_ji / s_j)` with `s_j = max_i |w_ji| / 127` (per output
//!   channel, symmetric, zero point 0);
//! - a layer's input `x_i` -> `round(x_i / a)` clamped to `[-127, 127]`, with `a` the largest
//!   `|x_i|` over the calibration inputs divided by 127 (so no calibration input clips);
//! - bias `b_j` -> `round(b_j / (a s_j))` as i32, the accumulator's unit.

use std::vec::Vec;

use crate::blob::{
    encode_to_vec, f32_le_bytes, i32_le_bytes, i8_bytes, Activation, BlobError, FeatureLayout, LayerBlob, NetworkBlob,
    ProblemKind, Quantization,
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
    /// Input scale `a` (the layer input's largest calibration magnitude / 127).
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
        let mut largest = vec![0.0f64; self.layers.len()];
        for x in calibration {
            for (m, a) in largest.iter_mut().zip(self.layer_inputs(x)) {
                *m = a.iter().fold(*m, |m, v| m.max(v.abs()));
            }
        }
        Ok(self
            .layers
            .iter()
            .zip(largest)
            .map(|(l, m)| {
                // A layer whose input is always 0 gets scale 1: any scale quantizes 0 exactly.
                let input_scale = if m > 0.0 {
                    // Rounded up to the next f32 if needed, so the largest input maps to <= 127.
                    let a = (m / 127.0) as f32;
                    if f64::from(a) * 127.0 < m {
                        a.next_up()
                    } else {
                        a
                    }
                } else {
                    1.0
                };
                let mut weights = Vec::with_capacity(l.weights.len());
                let mut weight_scales = Vec::with_capacity(l.outputs);
                let mut bias = Vec::with_capacity(l.outputs);
                for (row, &b) in l.weights.chunks_exact(l.inputs).zip(&l.bias) {
                    let peak = row.iter().fold(0.0f32, |m, w| m.max(w.abs()));
                    let s = if peak > 0.0 { peak / 127.0 } else { 1.0 };
                    weights.extend(row.iter().map(|&w| quantize(f64::from(w), f64::from(s)) as i8));
                    weight_scales.push(s);
                    let unit = f64::from(input_scale) * f64::from(s);
                    bias.push(
                        (f64::from(b) / unit)
                            .round()
                            .clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32,
                    );
                }
                Int8Layer {
                    input_scale,
                    weight_scales,
                    weights,
                    bias,
                }
            })
            .collect())
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
                // The largest weight of each row maps to +-127; every weight within s/2.
                let q_row = &q.weights[j * l.inputs..(j + 1) * l.inputs];
                assert_eq!(q_row.iter().map(|v| v.unsigned_abs()).max(), Some(127));
                for (i, &w) in row.iter().enumerate() {
                    let back = f32::from(q.weights[j * l.inputs + i]) * s;
                    assert!((back - w).abs() <= s / 2.0 * 1.0001);
                }
                let b_back = f64::from(q.bias[j]) * f64::from(q.input_scale) * f64::from(s);
                assert!((b_back - f64::from(l.bias[j])).abs() <= f64::from(q.input_scale * s) / 2.0 * 1.0001);
            }
        }
        // Every calibration input of every layer fits in 127 steps of its scale.
        for x in &calib {
            for (a, q) in net.layer_inputs(x).iter().zip(&quant) {
                assert!(a.iter().all(|v| v.abs() / f64::from(q.input_scale) <= 127.0));
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
