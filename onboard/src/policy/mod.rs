//! Fixed-size MLP inference in f32 and int8, straight from a weight blob (docs/spec.md section 10).
//!
//! The deployed actor mean heads are 10-256-256-3 (transfer) and 22-256-256-3 (rendezvous), in
//! three dimensions 15-256-256-4 and 30-256-256-4: two ReLU hidden layers and a tanh output. Every size is a const generic, so activations live
//! on the stack as fixed arrays and nothing is allocated.
//!
//! **Zero copy.** A layer view ([`DenseF32`], [`DenseInt8`]) keeps the byte slices of its
//! [`LayerBlob`]; the weights are read in place (from flash on the flight computer) and never
//! copied to RAM. Constructors check every size against the const shape, so `forward` has no
//! failure path and cannot panic on any input.
//!
//! **Kernels** (safe Rust vectorized by LLVM, except two `asm!` loops for the Cortex-M4F in
//! `policy/arm.rs`):
//! - f32 (weights input-major, `w[i * OUT + j]`): each input adds `x[i] * row_i` to the output
//!   vector (an axpy, which vectorizes without reassociating floating-point sums). Outputs are
//!   processed in tiles of [`F32_TILE`] whose accumulators stay in registers across all inputs;
//!   a layer narrower than a tile (the 3 action outputs) keeps 8 partial sums over interleaved
//!   inputs instead. Each product and sum is one fused multiply-add (a single rounding), on
//!   every target: `vfma.f32` on the Cortex-M4F, where the wide layers run in tiles of 16
//!   outputs held in `s0`-`s15` by an `asm!` loop; `vfmadd231ps` on x86-64 with AVX2 and FMA
//!   (detected at run time; tiles of 8 vectors of 8 outputs, `policy/x86.rs`); `libm::fmaf`
//!   elsewhere (a hardware `fmadd` on AArch64, exact software on a machine without FMA). The
//!   same fused operations in the same order per output give the same bits on every target.
//! - int8: the blob keeps the first and the output layer in f32 and the 256 x 256 hidden layer
//!   (95 % of the multiply-adds) in int8 ([`Quantization::of_layer`]). Its weights are stored in
//!   row pairs (`shared::blob::int8_weight_bytes`): per input, one i16 `256 b + a + 128` for
//!   the rows' weights `a`, `b`. Its input, the first layer's ReLU output, is quantized once to
//!   16-bit levels held in i16, then each output is an exact i32 dot product with the i8
//!   weights (integer sums reassociate freely, so every kernel gives the same integers). The
//!   target picks the kernel ([`INT8_KERNEL`]): [`DenseInt8::accumulate_lanes`] (x86 and other
//!   SIMD targets: each byte decoded, [`INT8_LANES`] independent lanes per row; with AVX2
//!   `vpmaddwd` of the pair's i16 and of their high bytes); [`DenseInt8::accumulate_pairs`]
//!   (Arm with the DSP extension, the Cortex-M4F: per word of a pair, `smlad` of the two i16
//!   against two activations, then `sxtb16 ror #8` + `smlad` for the second row, 4
//!   multiply-adds in 3 instructions; the first row is recovered exactly from both sums and the
//!   activations' sum); [`DenseInt8::accumulate_rows`] (other 32-bit Arm: scalar, each byte
//!   decoded, [`INT8_ROWS`] rows per pass).
//!   The sum plus the i32 bias is rescaled by `input_scale * weight_scale[j]` in f32, and the
//!   layer's input quantization is `q = clamp(round(x / s), -L, L)`, `L` =
//!   [`ACTIVATION_LEVELS`](shared::blob::ACTIVATION_LEVELS), round half away from zero
//!   ([`quantize`]; two exact implementations giving the same integers, one for Arm, one that
//!   vectorizes for the others).
//!
//! **Files.** This module holds the network shapes, the [`Mlp`] and its loading from a blob;
//! `policy/f32.rs` the f32 kernel ([`DenseF32`]), `policy/int8.rs` the int8 kernels and the
//! requantization ([`DenseInt8`], [`quantize`]), `policy/arm.rs` the Cortex-M4F `asm!` loops,
//! `policy/x86.rs` the x86-64 AVX2 + FMA f32 kernel.
//!
//! **Non-finite inputs.** [`Mlp::forward`] never panics. If any input is NaN or infinite it
//! returns `[f32::NAN; OUT]` in both precisions, so a corrupt state cannot turn into a plausible
//! thrust command (the guidance step rejects non-finite states before inference anyway). Finite
//! inputs give finite outputs in `[-1, 1]`, except in f32 when an intermediate sum overflows
//! (inputs of order 1e30 and beyond): the output is then `±1` or NaN. The layer kernels
//! themselves are total: NaN propagates through the f32 kernel (the ReLU keeps NaN) and is
//! quantized to 0 by the int8 kernel (infinities saturate to ±`L`).

use core::fmt;
use core::mem::MaybeUninit;

use shared::blob::{
    self, Activation, BlobError, BlobMission, FeatureLayout, LayerBlob, NetworkBlob, ProblemKind, Quantization,
};

mod f32;
mod int8;

pub use self::f32::{DenseF32, F32_TILE};
pub use int8::{quantize, quantize_relu, DenseInt8, Int8Kernel, INT8_KERNEL, INT8_LANES, INT8_ROWS};

/// Whether this target runs the `asm!` kernels of `policy/arm.rs`: the int8 pair kernel (DSP
/// extension: `sxtb16`, `smlad`) and the f32 tile kernel (FPU: `vfma.f32`). Arm target
/// features are unstable in Rust, so on stable `target_feature = "dsp"` is never set; the
/// bare-metal hard-float Arm targets stand in for it: `thumbv7em-none-eabihf` (Cortex-M4F and
/// M7F: ARMv7E-M has DSP by definition, hard float has the FPU), and the v7-R, v8-R and v7-A
/// ones (DSP is part of their A32/T32). The exception, `thumbv8m.main-none-eabihf` (DSP
/// optional, off in the target), fails to assemble the kernel: a build error, never a wrong
/// instruction.
const ARM_ASM: bool = cfg!(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"));

#[cfg(all(target_arch = "arm", target_os = "none", target_abi = "eabihf"))]
#[allow(unsafe_code)]
mod arm;

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86;

/// Layers of an [`Mlp`].
pub const MLP_LAYERS: usize = 3;

/// Inputs and outputs of a dense layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LayerShape {
    /// Inputs of the layer.
    pub inputs: usize,
    /// Outputs of the layer.
    pub outputs: usize,
}

/// Which array of a layer has the wrong length.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LayerArray {
    /// The weight matrix.
    Weights,
    /// The bias vector.
    Bias,
    /// The int8 per-output-channel weight scales.
    WeightScales,
}

/// Why a blob cannot be used as a policy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PolicyError {
    /// The bytes are not a valid blob.
    Blob(BlobError),
    /// The blob is for the other problem.
    WrongKind {
        /// The problem the caller flies.
        expected: ProblemKind,
        /// The blob's problem.
        found: ProblemKind,
    },
    /// The blob's feature layout does not have the network's input count.
    WrongFeatures {
        /// Inputs of the compiled network.
        expected_inputs: usize,
        /// The blob's feature layout.
        found: FeatureLayout,
    },
    /// The network does not have [`MLP_LAYERS`] layers.
    WrongLayerCount {
        /// [`MLP_LAYERS`].
        expected: usize,
        /// Layers in the blob.
        found: usize,
    },
    /// A layer's declared size differs from the compiled network's (`layer` counts from 0).
    WrongShape {
        /// Index of the layer (from 0).
        layer: usize,
        /// The compiled network's layer shape.
        expected: LayerShape,
        /// The blob's layer shape.
        found: LayerShape,
    },
    /// A layer's array has the wrong number of bytes for its declared size and quantization.
    WrongArrayLength {
        /// Index of the layer (from 0).
        layer: usize,
        /// Which array.
        array: LayerArray,
        /// Bytes the shape and quantization need.
        expected: usize,
        /// Bytes in the blob.
        found: usize,
    },
    /// A layer's activation is not the contract's (ReLU hidden, tanh output).
    WrongActivation {
        /// Index of the layer (from 0).
        layer: usize,
        /// The contract's activation there.
        expected: Activation,
        /// The blob's activation.
        found: Activation,
    },
    /// An int8 layer's input scale is not finite and positive, or a weight scale is not finite.
    BadScale {
        /// Index of the layer (from 0).
        layer: usize,
    },
    /// An int8 layer has more inputs than its i32 accumulator sums exactly
    /// ([`blob::MAX_INT8_INPUTS`]).
    TooWideForInt8 {
        /// Index of the layer (from 0).
        layer: usize,
        /// Its inputs.
        inputs: usize,
    },
}

impl PolicyError {
    /// The same error, reported for layer `layer`.
    fn at_layer(self, layer: usize) -> Self {
        match self {
            Self::WrongShape { expected, found, .. } => Self::WrongShape { layer, expected, found },
            Self::WrongArrayLength {
                array, expected, found, ..
            } => Self::WrongArrayLength {
                layer,
                array,
                expected,
                found,
            },
            Self::WrongActivation { expected, found, .. } => Self::WrongActivation { layer, expected, found },
            Self::BadScale { .. } => Self::BadScale { layer },
            Self::TooWideForInt8 { inputs, .. } => Self::TooWideForInt8 { layer, inputs },
            other => other,
        }
    }
}

impl From<BlobError> for PolicyError {
    fn from(e: BlobError) -> Self {
        Self::Blob(e)
    }
}

impl fmt::Display for PolicyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Blob(e) => write!(f, "invalid weight blob: {e}"),
            Self::WrongKind { expected, found } => {
                write!(f, "blob is for {found:?}, expected {expected:?}")
            }
            Self::WrongFeatures { expected_inputs, found } => write!(
                f,
                "feature layout {found:?} has {} inputs, network expects {expected_inputs}",
                found.len()
            ),
            Self::WrongLayerCount { expected, found } => {
                write!(f, "network has {found} layers, expected {expected}")
            }
            Self::WrongShape { layer, expected, found } => write!(
                f,
                "layer {layer} is {}x{}, expected {}x{}",
                found.inputs, found.outputs, expected.inputs, expected.outputs
            ),
            Self::WrongArrayLength {
                layer,
                array,
                expected,
                found,
            } => write!(f, "layer {layer} {array:?} has {found} bytes, expected {expected}"),
            Self::WrongActivation { layer, expected, found } => {
                write!(f, "layer {layer} activation is {found:?}, expected {expected:?}")
            }
            Self::BadScale { layer } => write!(f, "layer {layer} has an invalid scale"),
            Self::TooWideForInt8 { layer, inputs } => write!(
                f,
                "int8 layer {layer} has {inputs} inputs, more than the {} an i32 accumulator sums exactly",
                blob::MAX_INT8_INPUTS
            ),
        }
    }
}

impl core::error::Error for PolicyError {}

fn check_shape<const IN: usize, const OUT: usize>(layer: &LayerBlob<'_>) -> Result<(), PolicyError> {
    let found = LayerShape {
        inputs: usize::from(layer.inputs),
        outputs: usize::from(layer.outputs),
    };
    let expected = LayerShape {
        inputs: IN,
        outputs: OUT,
    };
    // A zero width is refused even if the blob declares it, so no kernel ever runs on one.
    if found == expected && IN > 0 && OUT > 0 {
        Ok(())
    } else {
        Err(PolicyError::WrongShape {
            layer: 0,
            expected,
            found,
        })
    }
}

fn check_len(array: LayerArray, bytes: &[u8], expected: usize) -> Result<(), PolicyError> {
    if bytes.len() == expected {
        Ok(())
    } else {
        Err(PolicyError::WrongArrayLength {
            layer: 0,
            array,
            expected,
            found: bytes.len(),
        })
    }
}

/// An f32 from 4 little-endian bytes (a plain load once inlined; 0 for a short chunk, which the
/// `chunks_exact(4)` callers never produce).
#[inline(always)]
fn f32_le(c: &[u8]) -> f32 {
    <[u8; 4]>::try_from(c).map_or(0.0, f32::from_le_bytes)
}

/// An i32 from 4 little-endian bytes.
#[inline(always)]
fn i32_le(c: &[u8]) -> i32 {
    <[u8; 4]>::try_from(c).map_or(0, i32::from_le_bytes)
}

/// ReLU that keeps NaN (`max(x, 0)` would turn it into 0).
#[inline(always)]
fn relu(x: f32) -> f32 {
    relu_to(x, 0.0)
}

/// [`relu`] with its 0 passed in (`zero` is `+0.0`), for code that must not load it as a
/// constant (see `int8::DenseInt8::forward_relu_into`).
#[inline(always)]
fn relu_to(x: f32, zero: f32) -> f32 {
    if x < 0.0 {
        zero
    } else {
        x
    }
}

/// The three layers of an [`Mlp`], in one precision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MlpLayers<'a, const IN: usize, const H1: usize, const H2: usize, const OUT: usize> {
    /// f32 weights read in place: host and Cortex-M4F give the same bits.
    F32(DenseF32<'a, IN, H1>, DenseF32<'a, H1, H2>, DenseF32<'a, H2, OUT>),
    /// An int8 hidden layer with 16-bit activations between f32 first and output layers
    /// ([`Quantization::of_layer`]): about a third of the f32 flash, integer dot products for
    /// 95 % of the multiply-adds.
    Int8(DenseF32<'a, IN, H1>, DenseInt8<'a, H1, H2>, DenseF32<'a, H2, OUT>),
}

/// An `IN`-`H1`-`H2`-`OUT` actor mean network: ReLU, ReLU, tanh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mlp<'a, const IN: usize, const H1: usize, const H2: usize, const OUT: usize> {
    kind: ProblemKind,
    features: FeatureLayout,
    mission: BlobMission,
    layers: MlpLayers<'a, IN, H1, H2, OUT>,
}

/// The transfer actor, 10-256-256-3.
pub type TransferPolicy<'a> = Mlp<'a, 10, 256, 256, 3>;
/// The rendezvous actor, 22-256-256-3.
pub type RendezvousPolicy<'a> = Mlp<'a, 22, 256, 256, 3>;
/// The three-dimensional transfer actor, 15-256-256-4 (throttle and an RTN direction).
pub type Transfer3Policy<'a> = Mlp<'a, 15, 256, 256, 4>;
/// The three-dimensional rendezvous actor, 30-256-256-4.
pub type Rendezvous3Policy<'a> = Mlp<'a, 30, 256, 256, 4>;

fn check_activation(layer: &LayerBlob<'_>, index: usize, expected: Activation) -> Result<(), PolicyError> {
    if layer.activation == expected {
        Ok(())
    } else {
        Err(PolicyError::WrongActivation {
            layer: index,
            expected,
            found: layer.activation,
        })
    }
}

impl<'a, const IN: usize, const H1: usize, const H2: usize, const OUT: usize> Mlp<'a, IN, H1, H2, OUT> {
    /// Decodes a blob (magic, version, CRC, structure) and builds the policy from it, checking
    /// it is for `expected` and has exactly this shape. The weights stay in `bytes`.
    pub fn from_bytes(bytes: &'a [u8], expected: ProblemKind) -> Result<Self, PolicyError> {
        let net = blob::decode(bytes)?;
        Self::from_blob(&net, expected)
    }

    /// Builds the policy from a decoded blob: checks the problem kind, that the feature layout
    /// has `IN` inputs, three layers of sizes `IN`-`H1`-`H2`-`OUT` with ReLU, ReLU, tanh, and
    /// every array length for the blob's quantization.
    pub fn from_blob(net: &NetworkBlob<'a>, expected: ProblemKind) -> Result<Self, PolicyError> {
        if net.kind != expected {
            return Err(PolicyError::WrongKind {
                expected,
                found: net.kind,
            });
        }
        if net.features.len() != IN || net.features.problem() != expected {
            return Err(PolicyError::WrongFeatures {
                expected_inputs: IN,
                found: net.features,
            });
        }
        let [l1, l2, l3] = net.layers.as_slice() else {
            return Err(PolicyError::WrongLayerCount {
                expected: MLP_LAYERS,
                found: net.layers.len(),
            });
        };
        check_activation(l1, 0, Activation::Relu)?;
        check_activation(l2, 1, Activation::Relu)?;
        check_activation(l3, 2, Activation::Tanh)?;
        let layers = match net.quantization {
            Quantization::F32 => MlpLayers::F32(
                DenseF32::from_layer(l1).map_err(|e| e.at_layer(0))?,
                DenseF32::from_layer(l2).map_err(|e| e.at_layer(1))?,
                DenseF32::from_layer(l3).map_err(|e| e.at_layer(2))?,
            ),
            Quantization::Int8 => MlpLayers::Int8(
                DenseF32::from_layer(l1).map_err(|e| e.at_layer(0))?,
                DenseInt8::from_layer(l2).map_err(|e| e.at_layer(1))?,
                DenseF32::from_layer(l3).map_err(|e| e.at_layer(2))?,
            ),
        };
        Ok(Self {
            kind: net.kind,
            features: net.features,
            mission: net.mission,
            layers,
        })
    }

    /// The mission the blob carries: its guidance cycle, canonical units and family.
    pub fn mission(&self) -> BlobMission {
        self.mission
    }

    /// The problem this policy flies.
    pub fn kind(&self) -> ProblemKind {
        self.kind
    }

    /// The input encoding.
    pub fn features(&self) -> FeatureLayout {
        self.features
    }

    /// How the weights are stored.
    pub fn quantization(&self) -> Quantization {
        match self.layers {
            MlpLayers::F32(..) => Quantization::F32,
            MlpLayers::Int8(..) => Quantization::Int8,
        }
    }

    /// The layer views.
    pub fn layers(&self) -> &MlpLayers<'a, IN, H1, H2, OUT> {
        &self.layers
    }

    /// The action mean in `[-1, 1]^OUT`: `tanh(L3(relu(L2(relu(L1(x))))))`.
    ///
    /// Never panics. Any non-finite input gives `[f32::NAN; OUT]` (see the module doc).
    pub fn forward(&self, input: &[f32; IN]) -> [f32; OUT] {
        self.forward_with(input, INT8_KERNEL)
    }

    /// [`Self::forward`] with the given int8 kernel (ignored by an f32 network); every kernel
    /// gives the same result bit for bit, on every target.
    #[inline(always)]
    pub fn forward_with(&self, input: &[f32; IN], kernel: Int8Kernel) -> [f32; OUT] {
        if !input.iter().all(|v| v.is_finite()) {
            return [f32::NAN; OUT];
        }
        let pre = match &self.layers {
            MlpLayers::F32(a, b, c) => {
                let mut h1 = MaybeUninit::uninit();
                let h1 = a.forward_fresh(input, &mut h1, true);
                let mut h2 = MaybeUninit::uninit();
                let h2 = b.forward_fresh(h1, &mut h2, true);
                c.forward(h2)
            }
            MlpLayers::Int8(a, b, c) => {
                let mut h1 = MaybeUninit::uninit();
                // The ReLU is left to the quantization (`quantize_relu`).
                let q1 = b.quantize_relu_input(a.forward_fresh(input, &mut h1, false));
                let mut h2 = MaybeUninit::uninit();
                c.forward(b.forward_relu_fresh(&q1, kernel, &mut h2))
            }
        };
        let mut out = [0.0f32; OUT];
        for (o, &v) in out.iter_mut().zip(pre.iter()) {
            *o = libm::tanhf(v);
        }
        out
    }
}
